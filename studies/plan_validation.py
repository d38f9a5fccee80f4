"""Rig-day plans with validation runs: identification runs with swaps against ones without.

Issue 36 (item 7): ``shockplan plan --validate 2`` spent its identification on runs of the
baseline alone and the rest of its budget on the validation runs' swaps. Do identification
runs without a swap predict as well as ones with swaps? The seed paper's Eqs. 21-24 say
no: with the same (linear) shocks in every run the shock forces are linear functions of
the rig inputs and their paths cannot be told apart from the rig inputs' (the input
matrix has rank 7, not 11). This study measures it on a car the design was not tuned on
(:func:`held_out_vehicle`: heavier, other springs and tires, tire damping, an offset
centre of gravity) at sensor noise:

- ``designed``: :func:`planner.design.design_experiment` with validation runs, as
  ``shockplan plan --validate N`` makes it (the identification runs vary every corner's
  shock; the validation runs' swaps count as rig time);
- ``no swap``: the same plan with every identification run on the baseline (the same
  drives and durations, the same validation runs): the plan ``plan --validate`` made
  before the fix;
- ``no validation``: the design without validation runs on the same budget (reference).

Each plan is written (``plan.toml``), read back and run on the virtual rig with the
held-out car, identified with ``identify_session``'s defaults, and the identified model
predicts a spread of crate setups on a track drive against the known car: median and
maximum metric error, Spearman of the scores, the same best setup; and the fit errors of
the shock-force paths (the ``dF`` inputs) the identification reports.

Writes ``plan_validation.csv`` (one row per plan) and ``plan_validation_runs.csv`` (the
plans' runs).

    python studies/plan_validation.py --out DIR [--budget-min 60] [--validate 2]
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
from ident.identify.pipeline import identify_session
from ident.models.library import read_shock_library
from ident.models.vehicle import build_full_car, example_vehicle
from ident.sim.metrics import METRIC_NAMES
from ident.sim.virtual_rig import read_rig_plan, simulate_session
from planner.demo import DEMO_LIBRARY_PATH
from planner.design import (CandidateOptions, InformationOptions, ScheduleOptions,
                            design_experiment)
from planner.objective import default_objective, score_setups
from planner.predict import predict_setups
from planner.setups import Setup, enumerate_setups
from planner.testplan import write_plan

log = logging.getLogger("studies.plan_validation")

CORNERS = ("LF", "RF", "LR", "RR")
BASELINE = "B20"


def held_out_vehicle():
    """A car the design was not tuned on: the paper's car 20 % heavier (inertias alike),
    softer front and stiffer rear springs, other tires and unsprung masses, tire damping
    and the centre of gravity 2 cm to the left."""
    p = example_vehicle()
    mass = 1.2 * p.sprung_mass_kg
    r = mass / p.sprung_mass_kg
    return p.replace(name="held-out", sprung_mass_kg=mass,
                     roll_inertia_kg_m2=1.1 * r * p.roll_inertia_kg_m2,
                     pitch_inertia_kg_m2=r * p.pitch_inertia_kg_m2,
                     unsprung_mass_kg=np.array([52.0, 52.0, 60.0, 60.0]),
                     spring_rate_n_m=np.array([170e3, 170e3, 140e3, 140e3]),
                     tire_rate_n_m=np.array([400e3, 400e3, 430e3, 430e3]),
                     tire_damping_n_s_m=np.full(4, 600.0), cg_lateral_offset_m=0.02)


def study_setups(library, n):
    """The all-B20 baseline and `n` setups spread over the symmetric enumeration."""
    pool = enumerate_setups(library)
    idx = np.unique(np.linspace(0, len(pool) - 1, n).round().astype(int))
    return [Setup("baseline", dict.fromkeys(CORNERS, BASELINE))] + [pool[i] for i in idx]


def without_swaps(rig_plan):
    """The rig plan with every run that is not a validation run on the baseline's shocks."""
    base = dict.fromkeys(CORNERS, BASELINE)
    runs = tuple(r if r.role == "validation" else replace(r, setup=dict(base))
                 for r in rig_plan.runs)
    return replace(rig_plan, runs=runs, name=f"{rig_plan.name} (no swap)")


def shock_path_errors(model):
    """Median and maximum fit error of the shock-force paths (inputs ``dF_*``)."""
    t = model.summary()
    e = t.loc[t["input"].str.startswith("dF_"), "fit_error"].to_numpy()
    return float(np.median(e)), float(e.max())


def evaluate(label, rig_plan, *, vehicle, noise, drive, setups, library):
    """Simulate `rig_plan` on `vehicle` at `noise`, identify, predict, compare with the truth."""
    rig_plan = replace(rig_plan, noise=noise, input_noise=noise / 4)
    t0 = time.perf_counter()
    session = simulate_session(rig_plan, vehicle)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(session)
    identify_s = time.perf_counter() - t0
    truth = build_full_car(vehicle).loop_plant(model.cbar_n_s_m)
    a = predict_setups(model, drive, setups, library).table
    b = predict_setups(truth, drive, setups, library).table
    names = [m for m in METRIC_NAMES if m in a]
    err = np.abs(a[names].to_numpy() / b[names].to_numpy() - 1)
    obj = default_objective()
    sa = score_setups(a, obj, baseline="baseline").table
    sb = score_setups(b, obj, baseline="baseline").table
    med_fit, max_fit = shock_path_errors(model)
    swapped = sorted({c for r in rig_plan.runs if r.role != "validation" for c in CORNERS
                      if r.setup[c] != BASELINE})
    return {"plan": label, "runs": len(rig_plan.runs),
            "identification_corners_swapped": " ".join(swapped) or "-",
            "run_time_min": sum(r.duration_s for r in rig_plan.runs) / 60.0,
            "noise": noise, "shock_path_fit_error_median": med_fit,
            "shock_path_fit_error_max": max_fit,
            "median_error_pct": 100 * float(np.median(err)),
            "max_error_pct": 100 * float(err.max()),
            "worst_metric": names[int(np.argmax(err.max(axis=0)))],
            "spearman": float(spearmanr(sa["score"], sb["score"]).statistic),
            "best": sa["rank"].idxmin(), "true_best": sb["rank"].idxmin(),
            "same_best": bool(sa["rank"].idxmin() == sb["rank"].idxmin()),
            "identify_s": identify_s}


def design(vehicle, library, *, budget_min, n_validation, drive, quick, seed=0):
    """The plan ``shockplan plan --vehicle CAR --budget-min B --validate N`` makes (`quick`:
    one drive kind, short runs, 24 bands)."""
    kw = {}
    if quick:
        kw = {"candidates": CandidateOptions(kinds=("noise",), durations_s=(60.0, 120.0)),
              "information": InformationOptions(n_bands=24, n_design_bands=4)}
    return design_experiment(vehicle, library, budget_min=budget_min, baseline=BASELINE,
                             drives=[drive],
                             schedule=ScheduleOptions(n_validation=n_validation, seed=seed),
                             **kw)


def main(argv=None):
    """Run the study; returns (table, plans' runs)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--budget-min", type=float, default=60.0, help="rig time [min]")
    p.add_argument("--validate", type=int, default=2, help="validation runs")
    p.add_argument("--noise", type=float, default=0.02,
                   help="response noise (fraction of RMS); the inputs get a quarter")
    p.add_argument("--drive-s", type=float, default=60.0,
                   help="the team's track drive [s] (validation runs and predictions)")
    p.add_argument("--setups", type=int, default=20, help="setups besides the baseline")
    p.add_argument("--quick", action="store_true",
                   help="a small design (one drive kind, 60-120 s runs, 24 bands)")
    p.add_argument("--no-reference", action="store_true",
                   help="leave out the plan without validation runs")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name in ("ident", "planner"):
        logging.getLogger(name).setLevel(logging.WARNING)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vehicle = held_out_vehicle()
    library = read_shock_library(DEMO_LIBRARY_PATH)
    drive = make_track_drive(duration_s=args.drive_s, fs_hz=100.0, seed=7,
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m, name="study track")
    setups = study_setups(library, args.setups)
    plans = [("designed", design(vehicle, library, budget_min=args.budget_min,
                                 n_validation=args.validate, drive=drive, quick=args.quick))]
    if not args.no_reference:
        plans.append(("no validation", design(vehicle, library, budget_min=args.budget_min,
                                              n_validation=0, drive=drive, quick=args.quick)))
    rows, run_rows = [], []
    with tempfile.TemporaryDirectory() as work:
        cases = []
        for label, plan in plans:
            log.info("%s: %s", label, " ".join(plan.rationale))
            rig_plan = read_rig_plan(write_plan(plan, Path(work) / label)["plan"])
            cases.append((label, rig_plan, plan.total_min))
            if label == "designed":
                cases.append(("no swap", without_swaps(rig_plan), plan.total_min))
        for label, rig_plan, total_min in cases:
            row = evaluate(label, rig_plan, vehicle=vehicle, noise=args.noise, drive=drive,
                           setups=setups, library=library)
            row["rig_time_min"] = total_min
            log.info("%s: %d runs, corners swapped for identification %s: shock paths' fit "
                     "error median %.4f, max %.4f; metrics median %.3f %%, max %.3f %%, "
                     "Spearman %.4f, best %s (true %s)", label, row["runs"],
                     row["identification_corners_swapped"],
                     row["shock_path_fit_error_median"], row["shock_path_fit_error_max"],
                     row["median_error_pct"], row["max_error_pct"], row["spearman"],
                     row["best"], row["true_best"])
            rows.append(row)
            run_rows += [{"plan": label, "run": r.name, "role": r.role,
                          **{c: r.setup[c] for c in CORNERS}, "duration_s": r.duration_s}
                         for r in rig_plan.runs]
    table = pd.DataFrame(rows)
    runs = pd.DataFrame(run_rows)
    table.to_csv(out / "plan_validation.csv", index=False, float_format="%.6g")
    runs.to_csv(out / "plan_validation_runs.csv", index=False, float_format="%.6g")
    log.info("wrote %s and %s", out / "plan_validation.csv", out / "plan_validation_runs.csv")
    return table, runs


if __name__ == "__main__":
    main(sys.argv[1:])
    sys.exit(0)
