"""Benchmark of experiment design: ``planner.design.design_experiment`` on the paper car.

Run::

    python benchmarks/bench_design.py [--budget-min 35] [--n-shocks 4]

Prints, one figure per line, each timing with the machine's 1-minute load
average at that moment:

1. the problem: the known paper car before rig day, the built-in crate, the
   default candidates (the baseline and swaps at one corner, a diagonal, an axle
   and all four corners of ``--n-shocks`` crate shocks, noise and multisine drives
   of 120, 300 and 600 s: about 200 candidate runs), 96 frequency bands, the
   budget;
2. for the D-optimal and the decision criteria: the wall time of
   ``design_experiment`` (information, cvxpy relaxation, rounding, order,
   predictions), the cvxpy solve alone, the criterion of the plan, and the plan;
3. the cvxpy-free greedy reference of the same budget (the same sequence-aware
   greedy, from nothing): its time and criterion value, and the ratio of the
   design's time to the greedy's;
4. ``target: design < 20 s: PASS/FAIL`` (each criterion).

This is a script, not part of the package: it prints and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

# benchmark the working tree this script lives in, installed or not
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ident.models.library import read_shock_library  # noqa: E402
from ident.models.vehicle import example_vehicle  # noqa: E402
from planner.demo import DEMO_LIBRARY_PATH  # noqa: E402
from planner.design import design_experiment  # noqa: E402
from _common import engine_version, load  # noqa: E402
from planner.design import CandidateOptions

#: The issue's target for one design (about 200 candidates, 96 bands) [s].
TARGET_S = 20.0


def main(argv=None):
    """Run the benchmark and print its figures."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--budget-min", type=float, default=35.0, help="rig time [min]")
    p.add_argument("--n-shocks", type=int, default=4, help="crate shocks swapped in")
    args = p.parse_args(argv)
    vehicle = example_vehicle()
    library = read_shock_library(DEMO_LIBRARY_PATH)
    print(f"shockplan {engine_version()}")
    verdicts = []
    for criterion in ("d", "decision"):
        t0 = time.perf_counter()
        plan = design_experiment(vehicle, library, budget_min=args.budget_min,
                                 criterion=criterion, baseline="B20",
                                 candidates=CandidateOptions(n_shocks=args.n_shocks))
        wall = time.perf_counter() - t0
        s, v = plan.solver, plan.values
        if criterion == "d":
            print(f"problem: paper car before rig day, {s['n_candidates']} candidate runs, "
                  f"{s['n_bands']} bands ({s['n_design_bands']} in the relaxation), budget "
                  f"{args.budget_min:g} min")
        print(f"design ({criterion}): {wall:.1f} s wall ({load()}); cvxpy {s['status']} "
              f"{s['solve_s']:.1f} s; plan {len(plan.runs)} runs, {plan.total_min:.1f} min, "
              f"criterion {v['plan']:.4g} (relaxed bound {v['relaxed']:.4g})")
        print("  runs: " + "; ".join(f"{r.name} {r.duration_s:g}s {r.kind}" for r in plan.runs))
        print(f"greedy reference ({criterion}, no cvxpy): {s['greedy_s']:.2f} s; criterion "
              f"{v['greedy']:.4g} in {v['greedy_min']:.1f} min; design / greedy time "
              f"{wall / max(s['greedy_s'], 1e-9):.0f}x; criterion gain of the design "
              f"{v['plan'] - v['greedy']:+.4g}")
        verdicts.append((criterion, wall))
    for criterion, wall in verdicts:
        print(f"target: design ({criterion}) < {TARGET_S:g} s: "
              f"{'PASS' if wall < TARGET_S else 'FAIL'} ({wall:.1f} s)")


if __name__ == "__main__":
    main()
