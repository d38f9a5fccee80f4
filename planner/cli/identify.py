"""``shockplan identify``: rig session -> identified vehicle model (with its noise report)."""

from __future__ import annotations

import logging
from pathlib import Path

from ident.data.files import atomic_path, check_output
from planner.cli.common import add_resample, check_out, int_at_least
from planner.text import format_table

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``identify`` to `subparsers`."""
    ident_p = subparsers.add_parser("identify", help="identify a vehicle model from a rig session")
    ident_p.add_argument("session", help="rig session folder (or its session.toml)")
    ident_p.add_argument("--out", required=True, help="model file to write (.npz); its "
                         "per-pair summary goes beside it as <name>_summary.csv")
    ident_p.add_argument("--method", choices=["invfreqs", "vf"], default="invfreqs",
                         help="per-pair rational fits (invfreqs, default) or common-pole "
                         "vector fitting (vf)")
    ident_p.add_argument("--estimator", choices=["lpm", "welch"], default="lpm",
                         help="FRF estimator: local polynomial method (lpm, default, "
                         "leakage-free) or the paper's Welch H1 (welch)")
    ident_p.add_argument("--frf-method", choices=["global", "sequential"], default="global",
                         help="least squares over all runs (global, Eq. 23, default) or "
                         "sequential (Eqs. 25-28; needs --estimator welch)")
    ident_p.add_argument("--nperseg", type=int, help="FRF block length [samples]: Welch's "
                         "block, and the frequency grid fs/nperseg of both estimators "
                         "(default: the power of two nearest the shortest run's samples / 20, "
                         "4096 for 800 s at 100 Hz)")
    ident_p.add_argument("--coherence-min", type=float, default=None,
                         help="coherence (0 to 1) below which band ends are replaced "
                         "(default 0.9, or 0.01 with the instruments on: --instruments)")
    ident_p.add_argument("--instruments", choices=["auto", "on", "off"], default="auto",
                         help="estimate with instrumental variables (the shock-force inputs "
                         "again from the shock travels: no errors-in-variables bias from the "
                         "velocity and force sensors' noise, more scatter); auto (default): on "
                         "for sessions that declare third elements and record every corner's "
                         "shock travel, off otherwise")
    ident_p.add_argument("--max-order", type=int_at_least(2), default=10, metavar="N",
                         help="highest denominator order (poles) a pair's fit may take "
                         "(default %(default)s; raise it when identify warns that a pair "
                         "took the highest order)")
    ident_p.add_argument("--plots", help="folder for FRF-vs-fit plots (PNG) (default: no plots)")
    ident_p.add_argument("--mat", help="also export the model to this MATLAB .mat file "
                         "(default: no export)")
    ident_p.add_argument("--all-pairs", action="store_true", help="print every pair's summary "
                         "(default: the 12 pairs with the largest fit error)")
    ident_p.add_argument("--no-diagnosis", action="store_true", help="skip the check of the "
                         "session against the model (bump stops, lift-off, the runs "
                         "re-simulated on the model; about 5-8 %% of the time)")
    ident_p.add_argument("--no-cross-validation", action="store_true", help="skip the FRF "
                         "estimates on the two halves of every run (about 15 %% of the time): "
                         "rank's intervals then take the older formula instead of the "
                         "session's own error")
    add_resample(ident_p, "every run")
    ident_p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    ident_p.set_defaults(func=run)
    return ident_p


def run(args):
    """``shockplan identify``: rig session -> identified vehicle model."""
    import warnings

    from ident.data.session import read_session
    from ident.data.units import format_significant, from_si, set_display_units, unit_label
    from ident.identify.thirdforce import describe_third
    from ident.identify.model import summary_path, write_model_summary
    from ident.identify.pipeline import FrfOptions, identify_session
    from planner.noise import with_noise_report

    check_out(args)
    check_output(summary_path(args.out), overwrite=args.overwrite, what="the model's summary")
    if args.mat:
        check_output(args.mat, overwrite=args.overwrite, what="--mat")
    if args.plots:
        check_output(args.plots, overwrite=True, folder=True, what="--plots")
    out = Path(args.out)
    session = read_session(args.session, resample_hz=args.resample)
    set_display_units(session.units)  # the session's unit system in every line printed
    diagnose_log = logging.getLogger("ident.identify.diagnose")
    shocks_log = logging.getLogger("ident.identify.shockcheck")
    level, shocks_level = diagnose_log.level, shocks_log.level
    diagnose_log.setLevel(logging.ERROR)  # its findings are printed below, once
    shocks_log.setLevel(logging.ERROR)  # so are the shock library's
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            model = identify_session(session, estimator=args.estimator,
                                     frf_method=args.frf_method, nperseg=args.nperseg,
                                     coherence_min=args.coherence_min, fit_method=args.method,
                                     max_order=args.max_order, diagnose=not args.no_diagnosis,
                                     cross_validate=not args.no_cross_validation,
                                     frf_options=FrfOptions(instruments={
                                         "auto": None, "on": True,
                                         "off": False}[args.instruments]))
    finally:
        diagnose_log.setLevel(level)
        shocks_log.setLevel(shocks_level)
    # the model with its noise report (planner.noise.identify_with_noise's model; its
    # warnings, if any, are not the identification's)
    model = with_noise_report(model, session)
    # the model and its summary appear together or not at all: both are written in full
    # to temporary files beside their targets, then put in place one right after the other
    summary_file = summary_path(out)
    with atomic_path(out, overwrite=args.overwrite) as tmp_model, \
            atomic_path(summary_file, overwrite=args.overwrite) as tmp_summary:
        model.save(tmp_model, overwrite=True)
        write_model_summary(model, tmp_summary, units=session.units, overwrite=True)
    table = model.summary()
    iv = (", instrumental variables: dF from the shock travels"
          if model.frf.settings.get("instruments") else "")
    print(f"identified '{session.name}' ({len(session.runs)} runs, {session.fs_hz:g} Hz, "
          f"estimator {model.frf.settings.get('estimator')}{iv}) with {args.method}: "
          f"{len(table)} pairs")
    rows = [(r.output, r.input, r.order, f"{r.fit_error:.4f}", f"{r.median_coherence:.3f}")
            for r in table.itertuples()]
    if not args.all_pairs:
        worst = table.sort_values("fit_error", ascending=False).head(12)
        rows = [(r.output, r.input, r.order, f"{r.fit_error:.4f}", f"{r.median_coherence:.3f}")
                for r in worst.itertuples()]
        print("the 12 pairs with the largest fit error (--all-pairs for every pair):")
    print(format_table(rows, ["output", "input", "order", "fit error", "median coh 0.5-20 Hz"]))
    c_bar = ", ".join(format_significant(from_si(c, "damping", session.units), 3)
                      for c in model.cbar_n_s_m)
    print(f"median fit error {table.fit_error.median():.4f}, orders "
          f"{int(table.order.min())}..{int(table.order.max())}; c_bar "
          f"{c_bar} {unit_label('damping', session.units)}")
    print("\n".join(model.noise.lines(table)))
    corner_elements = model.elements is not None and (
        model.third is None or model.elements.static_corner_load_n is not None
        or any(v is not None for v in model.elements.baseline_stops.values()))
    if corner_elements:  # what the session declared: in the loop of predictions
        lift = model.liftoff
        print(f"real car: {model.elements.describe()}; the bump stops' force is in the "
              "corners' force inputs (the linear model is free of it), and predictions put "
              "the stops and static loads in the loop"
              + ("" if not lift else "; samples where a tire left its pad were corrected "
                 "(pad corrections, settings['liftoff'])"))
    if model.third is not None:  # heave and roll elements: out of the linear model
        print(f"{describe_third(model.third)}; their force is in the corners' force inputs "
              "(the linear model is free of them; heave springs are entries of the bump-stop "
              "library); the model keeps them (VehicleModel.third)")
    print("diagnosis: skipped (--no-diagnosis)" if model.diagnosis is None else
          "\n".join(model.diagnosis.summary_lines()))
    if model.shock_check is not None:  # the session's shock forces against the library
        print("\n".join(model.shock_check.lines()))
    for w in caught:
        print(f"warning: {w.message}")
    print(f"wrote model {out} and its per-pair summary {summary_file}")
    if args.mat:
        model.export_mat(args.mat, overwrite=args.overwrite)
        print(f"wrote MATLAB export {args.mat}")
    if args.plots:
        from ident.identify.plots import write_frf_plots

        paths = write_frf_plots(model, args.plots, units=session.units)
        print(f"wrote {len(paths)} FRF plots to {args.plots}")
    return 0
