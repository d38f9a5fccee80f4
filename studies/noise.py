"""Identification accuracy against sensor noise: the paper's plan and a plan with a drive per run.

For each noise level (a fraction of each response channel's RMS over the
session; the recorded rig inputs get a quarter of it), the virtual rig runs
the seed paper's identification plan on the paper's car, shockplan identifies
it with its defaults, and the identified model predicts a spread of setups of
the built-in crate on a track drive. Each prediction is compared with the
known model's (the same simulator, the true car), and the 95 % intervals of
``rank`` are checked against the known model's metrics.

Two plans: the paper's (the same drive in every run, as the paper and most rig
days do) and the same plan with a different drive seed per run.

Missing shock-force channels: many rigs record shock velocity (or travel) but no
load cell on the shock. The spec then computes the force from the run's shock
model and the measured velocity, so the shock library stands in for the load
cell. At the ``--missing-levels`` noise levels the paper's plan is identified
again with every ``shock_force`` channel removed, once with the shock library
exact and once with every shock in it ``--library-error`` off (a dyno curve 4 %
high, say) while the car ran the true shocks.

Writes ``noise.csv`` (one row per plan, shock-force case and level) and ``noise.png``.

    python studies/noise.py --out DIR [--levels 0 0.02 0.05] [--run-s 800]

The defaults take about 5 minutes on a 2-core machine (8 identifications of
800 s sessions); ``--levels 0 0.005 0.01 0.02 0.05`` is the full table (about 8).
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
from scipy.stats import spearmanr

from ident.data.drive import make_track_drive
from ident.sim.metrics import METRIC_NAMES
from ident.identify.pipeline import identify_session
from ident.sim.virtual_rig import default_plan, simulate_session
from ident.models.library import ShockLibrary, read_shock_library
from ident.models.vehicle import build_full_car, example_vehicle
from planner.demo import DEMO_LIBRARY_PATH
from planner.objective import default_objective, score_setups
from planner.predict import predict_setups
from planner.rank import rank_setups
from planner.setups import Setup, enumerate_setups

log = logging.getLogger("studies.noise")

PLANS = ("paper", "drive-per-run")


def study_setups(library, n):
    """The all-B20 baseline and `n` setups spread over the symmetric enumeration."""
    pool = enumerate_setups(library)
    idx = np.unique(np.linspace(0, len(pool) - 1, n).round().astype(int))
    return [Setup("baseline", {c: "B20" for c in ("LF", "RF", "LR", "RR")})] + [pool[i] for i in idx]


FORCE_CASES = ("measured", "missing", "missing, library off")


def without_shock_forces(session, force_scale=1.0):
    """The session with every ``shock_force`` channel removed and its shock library's
    forces multiplied by `force_scale` (the library then stands in for the load cells)."""
    runs = tuple(replace(r, channels={k: v for k, v in r.channels.items()
                                      if not k.startswith("shock_force_")})
                 for r in session.runs)
    shocks = ShockLibrary([m.scaled(force_scale) for m in session.shocks.values()])
    return replace(session, runs=runs, shocks=shocks)


def run_case(plan_kind, level, *, run_s, drive, setups, library, vehicle, forces="measured",
             library_error=0.04):
    """One plan, noise level and shock-force case: identify, predict, compare with the
    known model."""
    plan = default_plan()
    runs = tuple(replace(r, duration_s=run_s, seed=r.seed + (i if plan_kind != "paper" else 0))
                 for i, r in enumerate(plan.runs))
    plan = replace(plan, runs=runs, noise=level, input_noise=level / 4)
    t0 = time.perf_counter()
    session = simulate_session(plan, vehicle)
    if forces != "measured":
        session = without_shock_forces(session, 1.0 + (library_error if forces ==
                                                         "missing, library off" else 0.0))
    t1 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(session)
    t2 = time.perf_counter()
    truth = build_full_car(vehicle).loop_plant(model.cbar_n_s_m)
    a = predict_setups(model, drive, setups, library).table
    b = predict_setups(truth, drive, setups, library).table
    names = [m for m in METRIC_NAMES if m in a]
    err = np.abs(a[names].to_numpy() / b[names].to_numpy() - 1)
    obj = default_objective()
    sa = score_setups(a, obj, baseline="baseline").table
    sb = score_setups(b, obj, baseline="baseline").table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ranking = rank_setups(model, drive, library, setups=setups, baseline="baseline",
                              top=len(setups), n_check=0)
    t = ranking.table
    truth_t = b.loc[t.index]
    inside = np.array([((truth_t[n] >= t[f"{n}_lo"]) & (truth_t[n] <= t[f"{n}_hi"])).to_numpy()
                       for n in names])
    summary = model.summary()
    return {"plan": plan_kind, "shock_forces": forces,
            "library_error": library_error if forces == "missing, library off" else 0.0,
            "noise": level, "input_noise": level / 4, "run_s": run_s,
            "median_error_pct": 100 * float(np.median(err)),
            "max_error_pct": 100 * float(err.max()),
            "worst_metric": names[int(np.argmax(err.max(axis=0)))],
            "spearman": float(spearmanr(sa["score"], sb["score"]).statistic),
            "same_best": bool(sa["rank"].idxmin() == sb["rank"].idxmin()),
            "interval_coverage_pct": 100 * float(inside.mean()),
            "median_fit_error": float(summary.fit_error.median()),
            "zero_pairs": int((summary.status == "zero").sum()),
            "lpm_half_width": model.frf.settings.get("lpm_half_width"),
            "simulate_s": t1 - t0, "identify_s": t2 - t1}


def plot(table, path):
    """Median and max metric error against noise, one line per plan."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    missing = table[table["shock_forces"] != "measured"]
    for (forces, err), grp in missing.groupby(["shock_forces", "library_error"]):
        label = f"paper, forces {forces}" + (f" {100 * err:+.0f} %" if err else "")
        axes[0].plot(100 * grp["noise"], grp["max_error_pct"], "x", ms=9, mew=2,
                     label=f"{label}: max")
        axes[1].plot(100 * grp["noise"], grp["interval_coverage_pct"], "x", ms=9, mew=2,
                     label=label)
    for plan_kind, grp in table[table["shock_forces"] == "measured"].groupby("plan"):
        x = 100 * grp["noise"]
        axes[0].plot(x, grp["median_error_pct"], "o-", label=f"{plan_kind}: median")
        axes[0].plot(x, grp["max_error_pct"], "s--", label=f"{plan_kind}: max")
        axes[1].plot(x, grp["interval_coverage_pct"], "o-", label=plan_kind)
    axes[0].set(xlabel="sensor noise [% of channel RMS]", ylabel="metric error vs known model [%]",
                title="identified model, defaults", yscale="log")
    axes[1].axhline(95, color="grey", lw=0.8)
    axes[1].set(xlabel="sensor noise [% of channel RMS]", ylabel="coverage [%]",
                title="95 % intervals of rank", ylim=(50, 101))
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    """Run the study; returns the table."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.02, 0.05],
                   help="response noise levels (fraction of RMS); inputs get a quarter")
    p.add_argument("--plans", nargs="*", choices=PLANS, default=list(PLANS),
                   help="plans identified at every level (none: only the missing-force cases)")
    p.add_argument("--run-s", type=float, default=800.0, help="length of every run [s]")
    p.add_argument("--drive-s", type=float, default=120.0, help="validation drive [s]")
    p.add_argument("--setups", type=int, default=40, help="setups besides the baseline")
    p.add_argument("--missing-levels", type=float, nargs="*", default=[0.02],
                   help="noise levels of the paper plan identified without shock-force channels")
    p.add_argument("--force-cases", nargs="*", choices=FORCE_CASES[1:],
                   default=list(FORCE_CASES[1:]), help="shock-force cases at --missing-levels")
    p.add_argument("--library-error", type=float, default=0.04,
                   help="force error of the library standing in for the load cells")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vehicle = example_vehicle()
    library = read_shock_library(DEMO_LIBRARY_PATH)
    drive = make_track_drive(duration_s=args.drive_s, fs_hz=100.0, seed=7,
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m, name="study track")
    setups = study_setups(library, args.setups)
    rows = []
    for plan_kind in args.plans:
        for level in args.levels:
            row = run_case(plan_kind, level, run_s=args.run_s, drive=drive, setups=setups,
                           library=library, vehicle=vehicle)
            log.info("%s, noise %.3g: median %.3f %%, max %.3f %%, Spearman %.4f, coverage "
                     "%.0f %%", plan_kind, level, row["median_error_pct"], row["max_error_pct"],
                     row["spearman"], row["interval_coverage_pct"])
            rows.append(row)
    for level in args.missing_levels:
        for forces in args.force_cases:
            row = run_case("paper", level, run_s=args.run_s, drive=drive, setups=setups,
                           library=library, vehicle=vehicle, forces=forces,
                           library_error=args.library_error)
            log.info("paper, shock forces %s, noise %.3g: median %.3f %%, max %.3f %%, "
                     "Spearman %.4f, coverage %.0f %%", forces, level,
                     row["median_error_pct"], row["max_error_pct"], row["spearman"],
                     row["interval_coverage_pct"])
            rows.append(row)
    table = pd.DataFrame(rows)
    table.to_csv(out / "noise.csv", index=False, float_format="%.6g")
    plot(table, out / "noise.png")
    log.info("wrote %s and %s", out / "noise.csv", out / "noise.png")
    return table


if __name__ == "__main__":
    main(sys.argv[1:])
    sys.exit(0)
