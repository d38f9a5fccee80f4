"""Benchmark of what-if studies: ``planner.whatif.evaluate_whatif`` against a per-case loop.

Run::

    python benchmarks/bench_whatif.py [--draws 50] [--setups 10] [--drive-s 120] \
        [--workers N] [--no-cluster]

The problem: the paper car's loop plant (built from the known model, used as an
identified model is: springs act through the shock-travel feedback), the
built-in crate, a track drive at 100 Hz, ``--setups`` crate setups plus the
baseline. Prints, one figure per line, each timing with the machine's 1-minute
load average at that moment:

1. shock tolerance ±5 % per corner, independent, Monte Carlo over ``--draws``
   draws (plus the nominal condition): ``evaluate_whatif`` in the time domain
   and with screening, evaluations (setup x condition) per second;
2. the per-case reference, in the same run: one ``predict_setups`` (or
   ``screen_setups``) call per condition, each with a library holding the
   condition's scaled shocks, as a user would script it; its rate, the ratio
   engine / reference, and the largest metric difference between the two (the
   same simulator: it must be ~0);
3. front and rear spring rates ±10 % one at a time (4 conditions): the engine,
   and the reference (``stiffened_plant`` + ``predict_setups`` per condition);
4. the same tolerance what-if on a ``LocalCluster`` (``evaluate_whatif(scheduler=
   "local")``: ``--workers`` worker processes, default one per core, started once before
   the clock; the figure is a warm run), in the same run, next to the one-process time:
   its rate, the speed ratio and whether the tables are identical (they must be);
   ``--no-cluster`` skips it;
5. ``target: time domain >= 100 evaluations/s, screening >= 1000/s``.

This is a script, not part of the package: it prints and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

# benchmark the working tree this script lives in, installed or not
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ident.data.drive import make_track_drive  # noqa: E402
from ident.sim.metrics import METRIC_NAMES  # noqa: E402
from ident.models.library import ShockLibrary, read_shock_library  # noqa: E402
from ident.models.vehicle import build_full_car, example_vehicle  # noqa: E402
from planner.demo import DEMO_LIBRARY_PATH  # noqa: E402
from planner.predict import predict_setups  # noqa: E402
from planner.screen import screen_setups  # noqa: E402
from planner.setups import Setup, enumerate_setups  # noqa: E402
from planner.runner import start_runner  # noqa: E402
from planner.whatif import (  # noqa: E402
    Factor,
    evaluate_whatif,
    perturbation_set,
    stiffened_plant,
)
from _common import engine_version, load  # noqa: E402
from planner.options import RunOptions

CORNERS = ("LF", "RF", "LR", "RR")
#: Evaluations (setup x condition) per second on the 2-core machine.
TARGET_TIME_PER_S = 100.0
TARGET_SCREEN_PER_S = 1000.0


def scaled_setups(setups, library, scales):
    """The setups with each corner's shock scaled by ``scales[corner]``, and the library
    holding those scaled shocks (the reference's way: one library per condition)."""
    models, out = {}, []
    for s in setups:
        ids = {}
        for c in CORNERS:
            sid = f"{s.shocks[c]}*{scales[c]:.12g}"
            if sid not in models:
                models[sid] = library[s.shocks[c]].scaled(scales[c], id=sid)
            ids[c] = sid
        out.append(Setup(s.name, ids))
    return out, ShockLibrary(list(models.values()))


def reference_tolerance(plant, drive, setups, library, pset, method):
    """One predict/screen call per condition; returns the metrics per condition."""
    tables = []
    for pert in pset.perturbations:
        vals = pert.values.get("shock tolerance", (1.0,) * 4)
        ss, lib = scaled_setups(setups, library, dict(zip(CORNERS, vals)))
        run = predict_setups if method == "time" else screen_setups
        tables.append(run(plant, drive, ss, lib).table)
    return tables


def reference_springs(plant, drive, setups, library, pset, k_n_m):
    """``stiffened_plant`` + ``predict_setups`` per condition."""
    tables = []
    for pert in pset.perturbations:
        dk = np.zeros(4)
        for name, idx in (("front springs", (0, 1)), ("rear springs", (2, 3))):
            if name in pert.values:
                dk[list(idx)] = (np.asarray(pert.values[name]) - 1.0) * k_n_m[list(idx)]
        p = stiffened_plant(plant, spring_n_m=dk) if np.any(dk) else plant
        tables.append(predict_setups(p, drive, setups, library).table)
    return tables


def largest_difference(result, tables, pset, setups, baseline):
    """Largest relative metric difference, engine against reference, over all cases."""
    worst = 0.0
    t = result.table
    for pert, ref in zip(pset.perturbations, tables):
        sub = t[t["perturbation"] == pert.name].set_index("setup")
        names = [m for m in METRIC_NAMES if m in ref and m in sub]
        for s in [baseline] + list(setups):
            a = sub.loc[s.name, names].to_numpy(float)
            b = ref.loc[s.name, names].to_numpy(float)
            worst = max(worst, float(np.max(np.abs(a / b - 1))))
    return worst


def warm(plant, drive, setups, library):
    """Import the engine and load its compiled kernels (on every cluster worker)."""
    predict_setups(plant, drive, setups, library)
    screen_setups(plant, drive, setups, library)


def main(argv=None):
    """Run the benchmark and print its figures."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--draws", type=int, default=50, help="Monte Carlo draws")
    p.add_argument("--setups", type=int, default=10, help="crate setups (plus the baseline)")
    p.add_argument("--drive-s", type=float, default=120.0, help="track drive [s]")
    p.add_argument("--workers", type=int, help="LocalCluster workers (default: cores)")
    p.add_argument("--no-cluster", action="store_true", help="skip the LocalCluster figure")
    args = p.parse_args(argv)
    vehicle = example_vehicle()
    library = read_shock_library(DEMO_LIBRARY_PATH)
    plant = build_full_car(vehicle).loop_plant()
    drive = make_track_drive(duration_s=args.drive_s, fs_hz=100.0, seed=7,
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m, name="bench track")
    pool = [s for s in enumerate_setups(library) if set(s.shocks.values()) != {"B20"}]
    idx = np.unique(np.linspace(0, len(pool) - 1, args.setups).round().astype(int))
    setups = [pool[i] for i in idx]
    base = Setup("baseline", dict.fromkeys(CORNERS, "B20"))
    everything = [base] + setups
    print(f"shockplan {engine_version()}")
    print(f"problem: paper car loop plant, {len(everything)} setups, {args.drive_s:g} s "
          f"track at 100 Hz, shock tolerance U(0.95, 1.05) per corner x {args.draws} draws")
    # warm-up: the compiled loop and the screening code paths
    predict_setups(plant, drive, everything[:2], library)
    screen_setups(plant, drive, everything[:2], library)

    tol = Factor("shock tolerance", "shock_scale", targets=CORNERS, independent=True,
                 distribution=("uniform", 0.95, 1.05))
    pset = perturbation_set([tol], design="monte-carlo", n_draws=args.draws, seed=1)
    runner = None
    if not args.no_cluster:  # the LocalCluster of scheduler="local", started and warmed once
        t0 = time.perf_counter()
        runner = start_runner("local", None, args.workers, True)
        runner.everywhere(warm, plant, drive, everything[:2], library)
        print(f"LocalCluster: {runner.n_workers} worker processes started and warmed in "
              f"{time.perf_counter() - t0:.1f} s")
    rates = {}
    try:
        for method in ("time", "screening"):
            t0 = time.perf_counter()
            res = evaluate_whatif(plant, drive, setups, library, pset, baseline=base,
                                  method=method)
            eng = time.perf_counter() - t0
            n = res.settings["n_evaluations"]
            t0 = time.perf_counter()
            ref_tables = reference_tolerance(plant, drive, everything, library, pset, method)
            ref = time.perf_counter() - t0
            diff = largest_difference(res, ref_tables, pset, setups, base)
            rates[method] = n / eng
            print(f"tolerance, {method}: {n} evaluations in {eng:.2f} s = {n / eng:.0f}/s "
                  f"({load()}); per-condition reference {ref:.2f} s = {n / ref:.0f}/s; "
                  f"engine / reference speed {ref / eng:.2f}x; largest metric difference "
                  f"{diff:.2e}")
            if runner is not None:
                t0 = time.perf_counter()
                dres = evaluate_whatif(plant, drive, setups, library, pset, baseline=base,
                                       method=method, run=RunOptions(client=runner.client))
                dt = time.perf_counter() - t0
                same = all(getattr(res, k).equals(getattr(dres, k))
                           for k in ("table", "robust", "conditions"))
                print(f"tolerance, {method}, LocalCluster ({runner.n_workers} workers, "
                      f"{dres.settings['n_tasks']} tasks): {n} evaluations in {dt:.2f} s = "
                      f"{n / dt:.0f}/s ({load()}); one process {eng:.2f} s; cluster / one "
                      f"process speed {eng / dt:.2f}x; tables identical: {same}")
    finally:
        if runner is not None:
            runner.close()

    k = np.asarray(vehicle.spring_rate_n_m, float)
    springs = [Factor(f"{axle} springs", "spring_rate", targets=tg, change="scale",
                      levels=(0.9, 1.1), baseline_rate=k[list(ix)])
               for axle, tg, ix in (("front", ("LF", "RF"), (0, 1)),
                                    ("rear", ("LR", "RR"), (2, 3)))]
    sset = perturbation_set(springs)
    t0 = time.perf_counter()
    res = evaluate_whatif(plant, drive, setups, library, sset, baseline=base)
    eng = time.perf_counter() - t0
    n = res.settings["n_evaluations"]
    t0 = time.perf_counter()
    ref_tables = reference_springs(plant, drive, everything, library, sset, k)
    ref = time.perf_counter() - t0
    diff = largest_difference(res, ref_tables, sset, setups, base)
    print(f"springs ±10 % one at a time, time: {n} evaluations in {eng:.2f} s = "
          f"{n / eng:.0f}/s ({load()}); per-condition reference {ref:.2f} s; engine / "
          f"reference speed {ref / eng:.2f}x; largest metric difference {diff:.2e}")
    for method, target in (("time", TARGET_TIME_PER_S), ("screening", TARGET_SCREEN_PER_S)):
        print(f"target: {method} >= {target:g} evaluations/s: "
              f"{'PASS' if rates[method] >= target else 'FAIL'} ({rates[method]:.0f}/s)")


if __name__ == "__main__":
    main()
