"""Identification accuracy against rig time: the paper's plan, designed plans, random plans.

Rig time is what a plan costs on the rig: every run's duration plus the swap
time of every corner whose shock changes from the run before (6 min a corner,
``planner.rig_spec.default_rig``), starting from the plan's first setup. For each
plan the virtual rig runs it on the paper's car (with sensor noise, by default
2 % of each response channel's RMS and 0.5 % on the rig inputs), shockplan
identifies the session with its defaults, and the identified model predicts a
spread of setups of the built-in crate on a track drive; the predictions are
compared with the known model's (the same simulator, the true car).

The plans:

- ``paper``: the seed paper's plan (a baseline and four single-corner swaps, the
  same drive in every run) at several run lengths;
- ``designed``: ``shockplan plan`` (D-optimal, cvxpy) for several rig-time budgets,
  before rig day from the known car;
- ``random``: runs of 120 s of setups drawn at random from the crate (one to four
  corners swapped from the baseline, every corner swapped at least once), until
  the same budgets are spent.

Writes ``rig_time.csv`` (one row per plan) and ``rig_time.png`` (median and
maximum metric error against rig time).

    python studies/rig_time.py --out DIR [--paper-run-s 800 200] [--budgets 30 60]
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import spearmanr

from ident.data.drive import make_track_drive
from ident.sim.metrics import METRIC_NAMES
from ident.identify.pipeline import identify_session
from ident.sim.virtual_rig import PlanRun, default_plan, read_rig_plan, simulate_session
from ident.models.library import read_shock_library
from ident.models.vehicle import build_full_car, example_vehicle
from planner.demo import DEMO_LIBRARY_PATH
from planner.design import design_experiment
from planner.objective import default_objective, score_setups
from planner.predict import predict_setups
from planner.rig_spec import default_rig
from planner.setups import Setup, enumerate_setups
from planner.testplan import write_plan
from planner.design import ScheduleOptions

log = logging.getLogger("studies.rig_time")

CORNERS = ("LF", "RF", "LR", "RR")
BASELINE = "B20"


def rig_time_min(runs, swap_min):
    """A plan's rig time [min]: run durations plus `swap_min` per changed corner."""
    total, prev = 0.0, runs[0].setup
    for r in runs:
        total += r.duration_s / 60.0 + swap_min * sum(prev[c] != r.setup[c] for c in CORNERS)
        prev = r.setup
    return total


def study_setups(library, n):
    """The all-B20 baseline and `n` setups spread over the symmetric enumeration."""
    pool = enumerate_setups(library)
    idx = np.unique(np.linspace(0, len(pool) - 1, n).round().astype(int))
    return [Setup("baseline", dict.fromkeys(CORNERS, BASELINE))] + [pool[i] for i in idx]


def paper_plan(run_s):
    """The paper's plan with every run `run_s` long."""
    plan = default_plan()
    return replace(plan, runs=tuple(replace(r, duration_s=run_s) for r in plan.runs))


def designed_plan(vehicle, library, budget_min, seed, work):
    """``shockplan plan`` for `budget_min`, written and read back as the rig plays it."""
    plan = design_experiment(vehicle, library, budget_min=budget_min, baseline=BASELINE,
                             schedule=ScheduleOptions(seed=seed))
    files = write_plan(plan, Path(work) / f"designed-{budget_min:g}")
    return read_rig_plan(files["plan"])


def random_plan(library, budget_min, swap_min, rng, run_s=120.0):
    """Random crate setups, `run_s` each, from the baseline until `budget_min` is spent;
    drawn again until every corner's shock is swapped at least once (Eq. 17)."""
    ids = [i for i in library.ids if i != BASELINE]
    template = default_plan()
    for _ in range(1000):
        runs = [PlanRun("run01-baseline", dict.fromkeys(CORNERS, BASELINE), "baseline",
                        int(rng.integers(1 << 30)), run_s)]
        while True:
            n = int(rng.integers(1, 5))
            corners = rng.choice(CORNERS, size=n, replace=False)
            setup = dict.fromkeys(CORNERS, BASELINE)
            for c in corners:
                setup[c] = str(rng.choice(ids))
            cand = runs + [PlanRun(f"run{len(runs) + 1:02d}-random", setup, "swap",
                                   int(rng.integers(1 << 30)), run_s)]
            if rig_time_min(cand, swap_min) > budget_min:
                break
            runs = cand
        if all(any(r.setup[c] != BASELINE for r in runs) for c in CORNERS):
            return replace(template, name=f"random {budget_min:g} min", shocks=library,
                           runs=tuple(runs))
    raise RuntimeError(f"no random plan of {budget_min} min swaps every corner")


def run_case(kind, label, rig_plan, *, noise, vehicle, drive, setups, library, swap_min):
    """One plan: simulate with noise, identify, predict, compare with the known model."""
    rig_plan = replace(rig_plan, noise=noise, input_noise=noise / 4)
    t0 = time.perf_counter()
    session = simulate_session(rig_plan, vehicle)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(session)
    t1 = time.perf_counter()
    truth = build_full_car(vehicle).loop_plant(model.cbar_n_s_m)
    a = predict_setups(model, drive, setups, library).table
    b = predict_setups(truth, drive, setups, library).table
    names = [m for m in METRIC_NAMES if m in a]
    err = np.abs(a[names].to_numpy() / b[names].to_numpy() - 1)
    obj = default_objective()
    sa = score_setups(a, obj, baseline="baseline").table
    sb = score_setups(b, obj, baseline="baseline").table
    return {"plan": kind, "case": label, "runs": len(rig_plan.runs),
            "run_time_min": sum(r.duration_s for r in rig_plan.runs) / 60.0,
            "rig_time_min": rig_time_min(rig_plan.runs, swap_min), "noise": noise,
            "median_error_pct": 100 * float(np.median(err)),
            "max_error_pct": 100 * float(err.max()),
            "worst_metric": names[int(np.argmax(err.max(axis=0)))],
            "spearman": float(spearmanr(sa["score"], sb["score"]).statistic),
            "same_best": bool(sa["rank"].idxmin() == sb["rank"].idxmin()),
            "identify_s": t1 - t0}


def plot(table, path):
    """Median and maximum metric error against rig time, one marker per plan kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for kind, marker in (("paper", "o"), ("designed", "s"), ("random", "^")):
        t = table[table["plan"] == kind].sort_values("rig_time_min")
        if t.empty:
            continue
        for ax, col in zip(axes, ("median_error_pct", "max_error_pct")):
            ax.plot(t["rig_time_min"], t[col], marker=marker, label=kind)
    for ax, what in zip(axes, ("median", "maximum")):
        ax.set_xlabel("rig time [min] (runs + 6 min per corner swap)")
        ax.set_ylabel(f"{what} metric error [%]")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle("Identification accuracy against rig time")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None):
    """Run the study; returns the table."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--paper-run-s", type=float, nargs="*", default=[800.0, 200.0],
                   help="run lengths of the paper's plan [s]")
    p.add_argument("--budgets", type=float, nargs="*", default=[30.0, 60.0],
                   help="rig-time budgets of the designed and random plans [min]")
    p.add_argument("--random-seeds", type=int, default=1, help="random plans per budget")
    p.add_argument("--noise", type=float, default=0.02,
                   help="response noise (fraction of RMS); the inputs get a quarter")
    p.add_argument("--drive-s", type=float, default=60.0, help="validation drive [s]")
    p.add_argument("--setups", type=int, default=20, help="setups besides the baseline")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name in ("ident", "planner"):
        logging.getLogger(name).setLevel(logging.WARNING)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vehicle = example_vehicle()
    library = read_shock_library(DEMO_LIBRARY_PATH)
    swap_min = default_rig().swap_min
    drive = make_track_drive(duration_s=args.drive_s, fs_hz=100.0, seed=7,
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m, name="study track")
    setups = study_setups(library, args.setups)
    rng = np.random.default_rng(2009)
    cases = [("paper", f"{s:g} s runs", paper_plan(s)) for s in args.paper_run_s]
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for b in args.budgets:
            cases.append(("designed", f"{b:g} min", designed_plan(vehicle, library, b, 0, work)))
            for k in range(args.random_seeds):
                cases.append(("random", f"{b:g} min #{k + 1}",
                              random_plan(library, b, swap_min, rng)))
        for kind, label, rig_plan in cases:
            row = run_case(kind, label, rig_plan, noise=args.noise, vehicle=vehicle,
                           drive=drive, setups=setups, library=library, swap_min=swap_min)
            log.info("%s %s: %d runs, %.1f min rig time: median %.3f %%, max %.3f %%, "
                     "Spearman %.4f", kind, label, row["runs"], row["rig_time_min"],
                     row["median_error_pct"], row["max_error_pct"], row["spearman"])
            rows.append(row)
    table = pd.DataFrame(rows)
    table.to_csv(out / "rig_time.csv", index=False, float_format="%.6g")
    plot(table, out / "rig_time.png")
    log.info("wrote %s and %s", out / "rig_time.csv", out / "rig_time.png")
    return table


if __name__ == "__main__":
    main(sys.argv[1:])
    sys.exit(0)
