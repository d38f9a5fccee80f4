"""The real car: accuracy with and without declaring its elements, against the share of time they act.

A GT-like car (1,350 kg, springs 280/320 kN/m at the wheel, tires 380/400 kN/m) runs the
seed paper's plan on the virtual rig (5 runs of ``--run-s``, 2 % sensor noise, the
paper's noise drive scaled to the car: 6 mm peak at the wheelloaders). Two sweeps:

1. Bump stops: progressive stops (100-600 kN/m over 15 mm) at every corner, the front
   gap ``--gaps`` (mm from rest; the rear 1.5 mm more), so that the front stops are
   touched from never to 10+ % of the time on the validation drive. Per gap the session
   is identified twice: declared (the session as the rig wrote it: its bump-stop library
   and each run's stops) and undeclared (the same channels rebuilt with
   ``ident.data.session.make_session`` without the stops: the paper's linear car; its
   identification's diagnosis is kept). Both predict a crate of setups (5 x 5 digressive
   shocks front/rear, each without and with 2 mm front packers, and the session's
   baseline) on a 60 s track drive with aero; the undeclared model cannot express packers
   and predicts the linear car. The truth is the known car with the declared elements.
2. Lift-off: the same car on its static tire loads, no stops; the session (moment
   multiples 0.2: the rig's tires hardly lift) identified with its static loads declared
   and without, predicting the 25 shock setups on validation drives of ``--roughness``
   (the road's roughness coefficient [m^3]) where the tires leave the ground from never
   to several % of the time. The truth is the known car with lift-off. The lift-off
   share error is the largest over setups and corners (the undeclared model predicts
   none: its error is the known car's share).

Per case: the known car's active share on the baseline (front contact share of ``LF``;
the largest lift-off share over the corners), the median and max relative error of the
spec's metrics (``ident.sim.metrics.METRIC_NAMES``) over the setups, the Spearman
correlation of the default objective's scores, whether the best setup is the same, and
the findings of the undeclared identification's diagnosis (corner, kind, share range
over the runs).

Writes ``real_car.csv`` (one row per case and declared / undeclared) and
``real_car.png`` (error against active share, both sweeps).

    python studies/real_car.py --out DIR [--gaps 10 7 5.5 4.5 3.5] [--run-s 400]

The default (5 gaps, 3 roughness levels, 400 s runs, 51 setups: 12 identifications) takes
about 8 minutes on a loaded 2-core machine; ``--quick`` (gaps 10 and 3.5 mm, roughness
64e-6, 200 s runs, 10 setups) about 2.5.
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

from ident.data.channels import CORNERS
from ident.data.drive import make_track_drive
from ident.data.session import make_session
from ident.identify.pipeline import identify_session
from ident.models.bumpstops import BumpStop, BumpStopLibrary
from ident.models.library import ShockLibrary
from ident.models.shocks import DigressiveShock
from ident.models.vehicle import VehicleParams
from ident.sim.metrics import METRIC_NAMES
from ident.sim.virtual_rig import default_plan, simulate_session
from planner.objective import score_setups
from planner.predict import predict_setups
from planner.options import ElementOptions
from planner.setups import Setup

log = logging.getLogger("studies.real_car")

#: The bump stops' force table: travel beyond contact [m] -> force [N] (progressive,
#: 100-600 kN/m over 15 mm; the table of the end-to-end tests).
STOP_TABLE = ([0.0, 0.002, 0.005, 0.010, 0.015], [0.0, 200.0, 1000.0, 3500.0, 6500.0])
#: The rear stops' gap beyond the front's [m].
REAR_EXTRA_GAP_M = 0.0015
#: The front packers of the crate's packer setups [m].
PACKER_M = 0.002
#: The identification drive scaled to the car: peak wheelloader [m], and the roll and
#: pitch moments of the bump-stop sessions and of the lift-off session (multiples of the
#: chassis stiffness per degree; 0.2: the tires hardly lift on the rig).
DRIVE_PEAK_M = 0.006
STOP_MOMENT_MULTIPLE = 0.5
LIFTOFF_MOMENT_MULTIPLE = 0.2
#: The validation drive: 60 s track at 100 Hz with aero, and the bump-stop sweep's
#: roughness [m^3].
DRIVE_S = 60.0
STOP_ROUGHNESS_M3 = 16e-6
AERO = {"aero_heave": 1500.0, "aero_pitch": 800.0, "aero_roll": 300.0}
#: Sensor noise of the sessions (fraction of each response channel's RMS).
NOISE = 0.02
#: Runs of ``--quick`` [s]: at 100 s this car's identification is 1.5-2 % off (median)
#: declared or not, and the comparison is noise; at 200 s 0.2-0.3 %.
QUICK_RUN_S = 200.0


def real_vehicle():
    """The GT-like car of the bump-stop and lift-off tests (tests/conftest.py
    ``bumpstop_vehicle``)."""
    return VehicleParams(name="gt", track_front_m=1.65, track_rear_m=1.60, a_m=1.30, b_m=1.35,
                         sprung_mass_kg=1180.0, roll_inertia_kg_m2=420.0,
                         pitch_inertia_kg_m2=1650.0, unsprung_mass_kg=[42.0, 42.0, 43.0, 43.0],
                         spring_rate_n_m=[280e3, 280e3, 320e3, 320e3],
                         tire_rate_n_m=[380e3, 380e3, 400e3, 400e3],
                         damping_n_s_m=[9000.0] * 4)


def gt_crate():
    """Five digressive shocks, 0.6-1.5 times a GT damper (``G0.60`` .. ``G1.50``)."""
    return [DigressiveShock(f"G{s:.2f}", bump_low_n_s_m=9000 * s, bump_knee_m_s=0.08,
                            bump_high_n_s_m=3500 * s, rebound_low_n_s_m=14000 * s,
                            rebound_knee_m_s=0.08, rebound_high_n_s_m=5000 * s, lag_s=0.002)
            for s in (0.6, 0.8, 1.0, 1.25, 1.5)]


def stop_library(front_gap_m):
    """Front stops ``BS-F`` at `front_gap_m`, rear ``BS-R`` 1.5 mm further, one table."""
    return BumpStopLibrary([BumpStop("BS-F", front_gap_m, *STOP_TABLE),
                            BumpStop("BS-R", front_gap_m + REAR_EXTRA_GAP_M, *STOP_TABLE)])


def pick(items, n):
    """`n` items spread evenly over `items` (all of them if `n` is None or larger)."""
    if n is None or n >= len(items):
        return list(items)
    idx = np.unique(np.linspace(0, len(items) - 1, n).round().astype(int))
    return [items[i] for i in idx]


def crate_setups(baseline_ids, *, packers, n=None):
    """The crate's setups: front/rear shock pairs (and with 2 mm front packers), then the
    session's baseline (named ``baseline``)."""
    crate = gt_crate()
    setups = []
    for f in crate:
        for r in crate:
            ids = {"LF": f.id, "RF": f.id, "LR": r.id, "RR": r.id}
            setups.append(Setup(f"{f.id}/{r.id}", ids))
            if packers:
                setups.append(Setup(f"{f.id}/{r.id} p2", ids,
                                    packers_m={"LF": PACKER_M, "RF": PACKER_M}))
    return pick(setups, n) + [Setup("baseline", dict(baseline_ids))]


def validation_drive(vehicle, roughness_m3):
    """The 60 s track drive with aero of the end-to-end tests."""
    return make_track_drive(duration_s=DRIVE_S, fs_hz=100.0, seed=3, roughness_m3=roughness_m3,
                            wheelbase_m=vehicle.a_m + vehicle.b_m,
                            track_width_m=vehicle.track_front_m, aero=AERO)


def rig_session(vehicle, *, run_s, stops=None, static=None, moment_multiple):
    """The paper's plan on the virtual rig with the car's elements (stops at every corner
    when `stops` is given; lift-off with `static` loads), everything declared."""
    plan = default_plan()
    base = {"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": "BS-R"} if stops else None
    runs = tuple(replace(r, duration_s=run_s, bump_stops=base) for r in plan.runs)
    drive = dict(plan.drive, peak_wheelloader_m=DRIVE_PEAK_M,
                 roll_moment_multiple=moment_multiple, pitch_moment_multiple=moment_multiple)
    plan = replace(plan, runs=runs, noise=NOISE, drive=drive, bump_stops=stops,
                   static_corner_load_n=static)
    return simulate_session(plan, vehicle)


def undeclared(session):
    """The same session without its bump stops, packers and static loads (the linear car)."""
    runs = [replace(r, bump_stops=None, packers_m=None) for r in session.runs]
    return make_session(session.name, runs, session.shocks)


def identify(session, *, diagnose):
    """``identify_session`` with its warnings silenced; returns (model, seconds)."""
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(session, diagnose=diagnose)
    return model, time.perf_counter() - t0


def predict(model, drive, setups, library, **kw):
    """``predict_setups`` with its coverage warnings silenced: the table."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return predict_setups(model, drive, setups, library, **kw).table


def compare(truth, pred):
    """Median and max relative error of the spec's metrics [%], the Spearman correlation
    of the default objective's scores and whether the best setup is the same."""
    m = list(METRIC_NAMES)
    err = np.abs(pred[m].to_numpy(float) / truth[m].to_numpy(float) - 1.0)
    st = score_setups(truth[m], baseline="baseline").table["score"]
    sp = score_setups(pred.loc[truth.index, m], baseline="baseline").table["score"]
    return {"median_error_pct": 100 * float(np.median(err)),
            "max_error_pct": 100 * float(err.max()),
            "worst_metric": m[int(np.argmax(err.max(axis=0)))],
            "spearman": float(spearmanr(st, sp).statistic),
            "same_best": bool(st.idxmin() == sp.idxmin())}


def findings_text(model):
    """The undeclared identification's diagnosis in one line: ``corner kind share range``."""
    if model.diagnosis is None:
        return ""
    groups = model.diagnosis.groups()
    if not groups:
        return "none"
    parts = []
    for g in groups:
        share = ("" if not np.isfinite(g["share_max"]) else
                 f" {100 * g['share_min']:.1f}-{100 * g['share_max']:.1f} %")
        parts.append(f"{g['corner']} {g['kind']}{share} ({len(g['runs'])} runs)")
    return "; ".join(parts)


def share_error(truth, pred, prefix):
    """The largest absolute error of the `prefix` share columns over setups and corners
    (a model without them predicts zero)."""
    cols = [f"{prefix}_{c}" for c in CORNERS if f"{prefix}_{c}" in truth]
    p = (pred.loc[truth.index, cols].to_numpy(float) if all(c in pred for c in cols)
         else np.zeros((len(truth), len(cols))))
    return float(np.abs(p - truth[cols].to_numpy(float)).max())


def bump_stop_cases(vehicle, gap_m, *, run_s, n_setups):
    """One front gap: the session with the stops, identified declared and undeclared,
    predicted against the known car. Returns two rows."""
    stops = stop_library(gap_m)
    t0 = time.perf_counter()
    session = rig_session(vehicle, run_s=run_s, stops=stops,
                          moment_multiple=STOP_MOMENT_MULTIPLE)
    sim_s = time.perf_counter() - t0
    declared, t_dec = identify(session, diagnose=False)
    plain, t_und = identify(undeclared(session), diagnose=True)
    lib = ShockLibrary.from_models(gt_crate() + list(session.shocks.values()))
    setups = crate_setups(session.runs[0].setup, packers=True, n=n_setups)
    drive = validation_drive(vehicle, STOP_ROUGHNESS_M3)
    truth = predict(vehicle, drive, setups, lib,
                    elements=ElementOptions(use_model=declared.elements))
    share = float(truth.loc["baseline", "bump_stop_contact_share_LF"])
    # the undeclared model knows no stops: the packers are beyond what it can express
    linear = [Setup(s.name, dict(s.shocks)) for s in setups]
    rows = []
    for is_declared, model, sset, t_id in ((True, declared, setups, t_dec),
                                           (False, plain, linear, t_und)):
        pred = predict(model, drive, sset, lib)
        rows.append({"kind": "bump stops", "front_gap_mm": 1e3 * gap_m,
                     "roughness_m3": STOP_ROUGHNESS_M3, "active_share": share,
                     "declared": is_declared, **compare(truth, pred),
                     "contact_share_error": share_error(truth, pred, "bump_stop_contact_share"),
                     "liftoff_share_error": np.nan,
                     "findings": "" if is_declared else findings_text(model),
                     "n_setups": len(setups), "run_s": run_s, "simulate_s": sim_s,
                     "identify_s": t_id})
    return rows


def liftoff_cases(vehicle, roughness, *, run_s, n_setups):
    """The lift-off sweep: one session on the car's static loads, identified declared and
    undeclared, predicted on drives of each `roughness` [m^3]. Returns two rows per level."""
    static = vehicle.static_corner_load_n
    t0 = time.perf_counter()
    session = rig_session(vehicle, run_s=run_s, static=static,
                          moment_multiple=LIFTOFF_MOMENT_MULTIPLE)
    sim_s = time.perf_counter() - t0
    declared, t_dec = identify(session, diagnose=False)
    plain, t_und = identify(undeclared(session), diagnose=True)
    lib = ShockLibrary.from_models(gt_crate() + list(session.shocks.values()))
    setups = crate_setups(session.runs[0].setup, packers=False, n=n_setups)
    found = findings_text(plain)
    rows = []
    for rough in roughness:
        drive = validation_drive(vehicle, rough)
        truth = predict(vehicle, drive, setups, lib,
                        elements=ElementOptions(static_corner_load_n=static))
        share = float(truth.loc["baseline", [f"tire_liftoff_share_{c}" for c in CORNERS]].max())
        for is_declared, model, t_id in ((True, declared, t_dec), (False, plain, t_und)):
            pred = predict(model, drive, setups, lib)
            rows.append({"kind": "lift-off", "front_gap_mm": np.nan, "roughness_m3": rough,
                         "active_share": share, "declared": is_declared,
                         **compare(truth, pred), "contact_share_error": np.nan,
                         "liftoff_share_error": share_error(truth, pred, "tire_liftoff_share"),
                         "findings": "" if is_declared else found,
                         "n_setups": len(setups), "run_s": run_s, "simulate_s": sim_s,
                         "identify_s": t_id})
    return rows


def plot(table, path):
    """Median and max metric error against the active share, declared or not, per sweep."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), constrained_layout=True)
    for ax, (kind, xlabel) in zip(axes, (("bump stops", "front bump-stop contact [% of time]"),
                                         ("lift-off", "largest tire lift-off [% of time]"))):
        part = table[table["kind"] == kind].sort_values("active_share")
        for is_declared, color in ((True, "C0"), (False, "C3")):
            grp = part[part["declared"] == is_declared]
            word = "declared" if is_declared else "not declared"
            x = 100 * grp["active_share"]
            ax.plot(x, grp["median_error_pct"], "o-", color=color, label=f"{word}: median")
            ax.plot(x, grp["max_error_pct"], "s--", color=color, label=f"{word}: max")
        ax.axhline(0.2, color="grey", lw=0.8, ls=":")
        ax.axhline(1.0, color="grey", lw=0.8, ls="-.")
        ax.set(xlabel=xlabel, ylabel="metric error vs known car [%]", yscale="log",
               title=f"{kind}: declared or not (bars 0.2 % median, 1 % max)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    """Run the study; returns 0."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--gaps", type=float, nargs="*", default=[10.0, 7.0, 5.5, 4.5, 3.5],
                   help="front bump-stop gaps [mm] (the rear 1.5 mm more)")
    p.add_argument("--roughness", type=float, nargs="*", default=[16e-6, 32e-6, 64e-6],
                   help="validation drives' roughness of the lift-off sweep [m^3]")
    p.add_argument("--run-s", type=float, default=400.0, help="length of every run [s]")
    p.add_argument("--setups", type=int, default=None,
                   help="crate setups besides the baseline (default all: 50 with packers)")
    p.add_argument("--quick", action="store_true",
                   help="gaps 10 and 3.5 mm, roughness 64e-6, 200 s runs, 10 setups (options "
                        "given as well win)")
    args = p.parse_args(argv)
    if args.quick:
        p.set_defaults(gaps=[10.0, 3.5], roughness=[64e-6], run_s=QUICK_RUN_S, setups=10)
        args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vehicle = real_vehicle()
    rows = []
    for gap in args.gaps:
        for row in bump_stop_cases(vehicle, 1e-3 * gap, run_s=args.run_s,
                                   n_setups=args.setups):
            rows.append(row)
            log.info("bump stops %.1f mm (contact %.1f %%), %s: median %.3f %%, max %.3f %%, "
                     "Spearman %.4f, same best %s; %s", gap, 100 * row["active_share"],
                     "declared" if row["declared"] else "undeclared", row["median_error_pct"],
                     row["max_error_pct"], row["spearman"], row["same_best"], row["findings"])
    if args.roughness:
        for row in liftoff_cases(vehicle, args.roughness, run_s=args.run_s,
                                 n_setups=args.setups):
            rows.append(row)
            log.info("lift-off %.3g m^3 (%.1f %%), %s: median %.3f %%, max %.3f %%, Spearman "
                     "%.4f, same best %s, share error %.4f; %s", row["roughness_m3"],
                     100 * row["active_share"],
                     "declared" if row["declared"] else "undeclared", row["median_error_pct"],
                     row["max_error_pct"], row["spearman"], row["same_best"],
                     row["liftoff_share_error"], row["findings"])
    table = pd.DataFrame(rows)
    table.to_csv(out / "real_car.csv", index=False, float_format="%.6g")
    plot(table, out / "real_car.png")
    log.info("wrote %s and %s", out / "real_car.csv", out / "real_car.png")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
