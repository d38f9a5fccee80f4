"""Intervals sized by the session's own cross-validation, on cars held out of any calibration.

Issue 37 item 1. The intervals of :mod:`planner.uncertainty` take their random part's
size from the session's own cross-validation (:mod:`ident.identify.crossval`, stored in
the model by identification) instead of a formula fitted to a family of cars. This
study checks, on cars held out of any calibration (``HELD_OUT``), against the known car:

1. the 95 % intervals of every metric of every setup (coverage of the known car's values);
2. the 95 % intervals of the score differences from the best and from the baseline
   (coverage of the true differences);
3. the verdict "tied with the best": over random subsets of the setups (each with the
   baseline), the share where the true best of the subset is the one called best, or one
   called tied (or better);
4. the noise-free paper session: every interval wider than zero.

Per car (each its own mass, stiffness, chassis, sensor noise 0-3 %, run length 100-800 s,
4- or 7-post, 100 or 200 Hz): ``--seeds`` identifications (every run's seed set to the
identification's: a new drive and noise realization), ``--setups`` setups of the crate
predicted in the time domain on a track drive, intervals as ``shockplan rank`` gives them
(``prediction_uncertainty`` with the default options, ``score_errors`` with the default
objective), and the known car's metrics (``build_full_car(car).loop_plant``).
``DEVELOPMENT`` holds the cars any choice of the method was tried on (the calibration
cars of ``studies/interval_calibration.py``); ``HELD_OUT`` was run once, at the end.

Writes into ``--out``: ``cv_cases.csv`` (one row per identification), ``cv_cars.csv``
(per car, the mean over its identifications), ``cases/*.npz`` (the arrays of each
identification; reused when present, so that an interrupted run resumes) and
``cases/*_model.npz`` (the identified models: delete the arrays to compute the intervals
anew on the same identifications; a model identified before the noise bias was measured
gets it measured on its session, simulated again, and is saved with it).

    python studies/interval_calibration_cv.py --out DIR [--family held-out] [--seeds 2]

``--recompute-cv`` measures the kept models' cross-validation again on their sessions
(simulated again; the noise bias kept), as identification now does (the rotated halves of
``ident.identify.crossval.split_session``); delete the cases' arrays (not the models) first.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from ident.data.drive import make_track_drive
from ident.identify.crossval import cross_validate_frf, noise_bias
from ident.identify.model import load_model
from ident.identify.pipeline import identify_session
from ident.models.library import read_shock_library
from ident.models.vehicle import build_full_car, example_gt_vehicle, example_vehicle
from ident.sim.metrics import METRIC_NAMES
from ident.sim.virtual_rig import PlanRun, default_plan, simulate_session
from planner.demo import DEMO_LIBRARY_PATH
from planner.objective import default_objective, score_setups
from planner.predict import predict_setups, prepare_drive
from planner.setups import Setup, enumerate_setups
from planner.options import UncertaintyOptions
from planner.uncertainty import (
    SIGNED_TERMS,
    SYSTEMATIC_TERMS,
    ScoreErrors,
    combine_terms,
    prediction_uncertainty,
    random_error_scale,
    score_errors,
    score_intervals,
)

log = logging.getLogger("studies.interval_calibration_cv")

#: The crate's shock of the baseline setup.
BASELINE_SHOCK = "DM"
#: Identification seeds: the k-th identification of a car sets every run's seed to this + k.
SEED0 = 301
#: Random subsets of the setups for the verdict's check, per identification, and their size.
SUBSETS, SUBSET_SIZE = 200, 6
#: The target band of the 95 % intervals' coverage.
COVERAGE_BAND = (0.90, 0.98)


def _car(name, mass_kg, springs_n_m, *, torsion=None, tire_damping=None, **kw):
    """The paper's car with its sprung mass (inertias alike), springs, torsion, tire damping."""
    p = example_vehicle()
    r = mass_kg / p.sprung_mass_kg
    return p.replace(name=name, sprung_mass_kg=mass_kg,
                     roll_inertia_kg_m2=p.roll_inertia_kg_m2 * r,
                     pitch_inertia_kg_m2=p.pitch_inertia_kg_m2 * r,
                     spring_rate_n_m=np.repeat(np.asarray(springs_n_m, dtype=float), 2),
                     torsion_stiffness_n_m_rad=torsion,
                     tire_damping_n_s_m=None if tire_damping is None else np.full(4, tire_damping),
                     **kw)


def _spec(vehicle, *, role, noise, run_s, runs=5, fs_hz=100.0, rig="7-post", speed_m_s=50.0):
    return {"vehicle": vehicle, "role": role, "noise": noise, "run_s": run_s, "runs": runs,
            "fs_hz": fs_hz, "rig": rig, "speed_m_s": speed_m_s}


def car_family():
    """The study's cars: name -> spec (vehicle, role, noise, run_s, runs, fs_hz, rig,
    speed_m_s of the validation drive)."""
    dev, held = "development", "held-out"
    gt = example_gt_vehicle()
    return {
        # development: the cars any choice was tried on (interval_calibration's calibration)
        "dev paper 300 s": _spec(example_vehicle(), role=dev, noise=0.02, run_s=300.0),
        "dev light soft": _spec(_car("light soft", 850.0, (110e3, 130e3), torsion=1.0e5,
                                     tire_damping=600.0), role=dev, noise=0.05, run_s=150.0,
                                speed_m_s=30.0),
        "dev rear stiff": _spec(_car("rear stiff", 1250.0, (150e3, 300e3), torsion=2.5e5,
                                     tire_damping=500.0, cg_lateral_offset_m=0.03), role=dev,
                                noise=0.03, run_s=400.0, speed_m_s=40.0),
        # held out: run once, at the end
        "paper noise-free": _spec(example_vehicle(), role=held, noise=0.0, run_s=800.0),
        "paper 2 %": _spec(example_vehicle(), role=held, noise=0.02, run_s=800.0),
        "GT flexible 200 Hz": _spec(gt, role=held, noise=0.02, run_s=400.0, runs=8,
                                    fs_hz=200.0),
        "GT 4-post": _spec(gt, role=held, noise=0.02, run_s=400.0, runs=8, rig="4-post"),
        "light 100 s": _spec(_car("light", 900.0, (120e3, 110e3)), role=held, noise=0.03,
                             run_s=100.0, speed_m_s=40.0),
        "heavy twist 200 Hz": _spec(_car("heavy twist", 1450.0, (280e3, 250e3), torsion=2.0e5,
                                         tire_damping=900.0), role=held, noise=0.01,
                                    run_s=250.0, fs_hz=200.0, speed_m_s=60.0),
    }


def study_plan(spec, seed):
    """The paper's plan at the car's noise, run length, rate and rig; 8 runs add a second
    baseline and two diagonal swaps."""
    plan = default_plan()
    runs = [replace(r, duration_s=spec["run_s"], seed=seed) for r in plan.runs]
    if spec["runs"] > len(runs):
        base = runs[0].setup
        soft = runs[1].setup["LF"]
        extra = [PlanRun("baseline-2", dict(base), "baseline", seed, spec["run_s"]),
                 PlanRun("swap-LF-RR", {**base, "LF": soft, "RR": soft}, "swap", seed,
                         spec["run_s"]),
                 PlanRun("swap-RF-LR", {**base, "RF": soft, "LR": soft}, "swap", seed,
                         spec["run_s"])]
        runs += extra[:spec["runs"] - len(runs)]
    return replace(plan, noise=spec["noise"], input_noise=spec["noise"] / 4,
                   fs_hz=spec["fs_hz"], rig=spec["rig"], runs=tuple(runs))


def study_setups(library, n):
    """The all-DM baseline and `n` setups spread over the symmetric enumeration."""
    pool = enumerate_setups(library)
    idx = np.unique(np.linspace(0, len(pool) - 1, n).round().astype(int))
    return ([Setup("baseline", {c: BASELINE_SHOCK for c in ("LF", "RF", "LR", "RR")})]
            + [pool[i] for i in idx])


def run_case(name, spec, k, *, drive_s, n_setups, cache, formula=False, recompute_cv=False):
    """Identify car `name` with seed index `k`; the arrays of its intervals and truth
    (`formula`: the intervals of before, ``random_error_scale``, on the same model;
    `recompute_cv`: a kept model's cross-validation measured again on its session,
    simulated again, as identification now does; its noise bias kept)."""
    stem = f"{name.replace(' ', '_').replace('%', 'pct')}_seed{SEED0 + k}"
    path = cache / f"{stem}{'_formula' if formula else ''}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            return {key: z[key] for key in z.files}
    library = read_shock_library(DEMO_LIBRARY_PATH)
    vehicle = spec["vehicle"]
    model_path = cache / f"{stem}_model.npz"
    t0 = time.perf_counter()
    if model_path.is_file():  # the identification of an earlier run (the intervals anew)
        model = load_model(model_path)
        t1 = t2 = time.perf_counter()
        if recompute_cv and model.frf.cv_deviation is not None:
            session = simulate_session(study_plan(spec, SEED0 + k), vehicle)
            t1 = time.perf_counter()
            frf = replace(cross_validate_frf(session, model.frf, noise=False),
                          noise_bias=model.frf.noise_bias)
            frf.settings["cross_validation"]["noise_bias"] = frf.noise_bias is not None
            model = replace(model, frf=frf)
            t2 = time.perf_counter()
            model.save(model_path, overwrite=True)
        elif model.frf.noise_bias is None and model.frf.cv_deviation is not None:
            # identified before the noise bias was measured: measure it on the same session
            # (seeded: simulated again) as identification now does, and keep it
            session = simulate_session(study_plan(spec, SEED0 + k), vehicle)
            t1 = time.perf_counter()
            grid = np.asarray(model.frf.settings["cross_validation"]["f_hz"], dtype=float)
            frf = replace(model.frf, noise_bias=noise_bias(session, model.frf, grid))
            frf.settings["cross_validation"]["noise_bias"] = frf.noise_bias is not None
            model = replace(model, frf=frf)
            t2 = time.perf_counter()
            model.save(model_path, overwrite=True)
    else:
        session = simulate_session(study_plan(spec, SEED0 + k), vehicle)
        t1 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = identify_session(session)
        t2 = time.perf_counter()
        model_path.parent.mkdir(parents=True, exist_ok=True)
        model.save(model_path)
    drive = make_track_drive(duration_s=drive_s, fs_hz=100.0, seed=24,
                             speed_m_s=spec["speed_m_s"], wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m,
                             name=f"track {spec['speed_m_s']:g} m/s")
    setups = study_setups(library, n_setups)
    pred = predict_setups(model, drive, setups, library)
    draws = (UncertaintyOptions(random_scale=random_error_scale(model.frf)) if formula
             else UncertaintyOptions())
    unc = prediction_uncertainty(model, drive, setups, library, predictions=pred, draws=draws)
    t3 = time.perf_counter()
    # the known car on the drive the model predicts on (a 100 Hz drive is resampled to a
    # 200 Hz model's rate: the input's representation alone moved the shock velocities'
    # metrics by 0.4 %, the model not at fault)
    truth = predict_setups(build_full_car(vehicle).loop_plant(model.cbar_n_s_m),
                           prepare_drive(drive, model.fs_hz), setups, library).table
    names = [m for m in METRIC_NAMES if m in pred.table]
    idx = pred.table.index
    obj = default_objective()
    err = score_errors(pred.table, unc, obj, baseline="baseline")
    true_scores = score_setups(truth.loc[idx], obj, baseline="baseline").table
    cv = (model.frf.settings or {}).get("cross_validation") or {}
    out = {"P": pred.table.loc[idx, names].to_numpy(), "K": truth.loc[idx, names].to_numpy(),
           "lo": unc.ratio_lo.loc[idx, names].to_numpy(),
           "hi": unc.ratio_hi.loc[idx, names].to_numpy(),
           "random_lo": unc.components["random_lo"].loc[idx, names].to_numpy(),
           "random_hi": unc.components["random_hi"].loc[idx, names].to_numpy(),
           "score": err.nominal.loc[idx].to_numpy(), "score_draws": err.draws.loc[idx].to_numpy(),
           "score_systematic": err.systematic.loc[idx].to_numpy(),
           "feasible": err.feasible.loc[idx].to_numpy(),
           "true_score": true_scores["score"].loc[idx].to_numpy(),
           "true_feasible": true_scores["feasible"].loc[idx].to_numpy(),
           "ratio_all": float(cv.get("ratio_all", np.nan)),
           "random_scale": float(unc.settings["random_scale"]),
           "quantiles": np.asarray(unc.settings["quantiles"], dtype=float),
           "simulate_s": t1 - t0, "identify_s": t2 - t1, "intervals_s": t3 - t2}
    for term in SYSTEMATIC_TERMS:
        if term in unc.components:
            out[term] = unc.components[term].loc[idx, names].to_numpy()
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **out)
    return out


def case_errors(case):
    """The case's :class:`planner.uncertainty.ScoreErrors` (setup names s0, s1, ...)."""
    n = case["score"].size
    names = [f"s{i}" for i in range(n)]
    terms = [t for t in SYSTEMATIC_TERMS if t in case]  # score_errors' order of the shifts
    return ScoreErrors(nominal=pd.Series(case["score"], index=names),
                       draws=pd.DataFrame(case["score_draws"], index=names),
                       systematic=pd.DataFrame(case["score_systematic"], index=names,
                                               columns=terms),
                       quantiles=tuple(case["quantiles"]),
                       feasible=pd.Series(case["feasible"].astype(bool), index=names),
                       baseline="s0")


def evaluate(case, rng):
    """One identification's row: coverages, widths, errors, the verdict's record."""
    P, K = case["P"], case["K"]
    # the bounds from the stored parts, as prediction_uncertainty combines them
    lo, hi = combine_terms(case["random_lo"], case["random_hi"],
                           {t: case[t] for t in SYSTEMATIC_TERMS
                            if t in case and t not in SIGNED_TERMS},
                           signed={t: case[t] for t in SIGNED_TERMS if t in case})
    inside = (K >= P * lo) & (K <= P * hi)
    errors = case_errors(case)
    names = list(errors.nominal.index)
    table = score_intervals(errors)
    true = pd.Series(case["true_score"], index=names)
    best = table.index[table["verdict"] == "best"][0]
    d_best = (true - true[best]).drop(index=best)
    t_b = table.drop(index=best)
    cov_best = np.mean((t_b["diff_best_lo"] <= d_best) & (d_best <= t_b["diff_best_hi"]))
    d_base = (true - true["s0"]).drop(index="s0")
    t_0 = table.drop(index="s0")
    cov_base = np.mean((t_0["diff_baseline_lo"] <= d_base) & (d_base <= t_0["diff_baseline_hi"]))
    feas_true = pd.Series(case["true_feasible"].astype(bool), index=names)
    right, tied = [], []
    for _ in range(SUBSETS):
        sub = ["s0"] + list(rng.choice(names[1:], SUBSET_SIZE - 1, replace=False))
        e = ScoreErrors(nominal=errors.nominal.loc[sub], draws=errors.draws.loc[sub],
                        systematic=errors.systematic.loc[sub], quantiles=errors.quantiles,
                        feasible=errors.feasible.loc[sub], baseline="s0")
        v = score_intervals(e)["verdict"]
        pool = true.loc[sub][feas_true.loc[sub]] if feas_true.loc[sub].any() else true.loc[sub]
        right.append(v[pool.idxmin()] in ("best", "tied", "better"))
        tied.append(int(np.sum(v == "tied")))
    return {"coverage": float(np.mean(inside)),
            "median_half_width_pct": 100 * float(np.median((hi - lo) / 2)),
            "median_error_pct": 100 * float(np.median(np.abs(P / K - 1))),
            "min_half_width_pct": 100 * float(np.min((hi - lo) / 2)),
            "diff_best_coverage": float(cov_best), "diff_baseline_coverage": float(cov_base),
            "verdict_right": float(np.mean(right)), "tied_per_subset": float(np.mean(tied)),
            "random_scale": float(case["random_scale"]), "cv_ratio": float(case["ratio_all"]),
            "identify_s": float(case["identify_s"]), "intervals_s": float(case["intervals_s"])}


def main(argv=None):
    """Run the study; returns 0."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--family", choices=("development", "held-out", "all"), default="held-out")
    p.add_argument("--cars", nargs="+", default=None, help="car names (default the family's)")
    p.add_argument("--seeds", type=int, default=2, help="identifications per car")
    p.add_argument("--first-seed", type=int, default=0,
                   help="index of the first identification (its runs' seed is 301 + it)")
    p.add_argument("--drive-s", type=float, default=60.0, help="validation drive [s]")
    p.add_argument("--setups", type=int, default=19, help="setups besides the baseline")
    p.add_argument("--formula", action="store_true",
                   help="the intervals of before (random_error_scale's formula) on the same "
                        "identifications, for A/B")
    p.add_argument("--recompute-cv", action="store_true",
                   help="measure the kept models' cross-validation again (their sessions "
                        "simulated again; delete the cases' arrays first)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for noisy in ("planner", "ident"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    family = car_family()
    names = args.cars or [n for n, s in family.items()
                          if args.family == "all" or s["role"] == args.family]
    unknown = [n for n in names if n not in family]
    if unknown:
        p.error(f"--cars: unknown {unknown}; the family is {list(family)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    rng = np.random.default_rng(37)
    for n in names:
        for k in range(args.first_seed, args.first_seed + args.seeds):
            t0 = time.perf_counter()
            case = run_case(n, family[n], k, drive_s=args.drive_s, n_setups=args.setups,
                            cache=out / "cases", formula=args.formula,
                            recompute_cv=args.recompute_cv)
            spec = family[n]
            row = {"car": n, "seed": SEED0 + k, "role": spec["role"], "noise": spec["noise"],
                   "run_s": spec["run_s"], "runs": spec["runs"], "fs_hz": spec["fs_hz"],
                   "rig": spec["rig"], **evaluate(case, rng)}
            rows.append(row)
            log.info("%s seed %d (%.0f s): %s", n, SEED0 + k, time.perf_counter() - t0,
                     {key: round(v, 4) for key, v in row.items() if isinstance(v, float)})
            pd.DataFrame(rows).to_csv(out / "cv_cases.csv", index=False, float_format="%.6g")
    table = pd.DataFrame(rows)
    cars = table.groupby("car", sort=False).agg(
        role=("role", "first"), noise=("noise", "first"), run_s=("run_s", "first"),
        runs=("runs", "first"), fs_hz=("fs_hz", "first"), rig=("rig", "first"),
        seeds=("seed", "size"), coverage=("coverage", "mean"),
        coverage_min=("coverage", "min"), coverage_max=("coverage", "max"),
        diff_best_coverage=("diff_best_coverage", "mean"),
        diff_baseline_coverage=("diff_baseline_coverage", "mean"),
        verdict_right=("verdict_right", "mean"),
        median_half_width_pct=("median_half_width_pct", "median"),
        median_error_pct=("median_error_pct", "median"),
        min_half_width_pct=("min_half_width_pct", "min"),
        cv_ratio=("cv_ratio", "median"), identify_s=("identify_s", "median")).reset_index()
    cars.to_csv(out / "cv_cars.csv", index=False, float_format="%.6g")
    log.info("per car (mean over identifications):\n%s", cars.to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
