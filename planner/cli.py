"""The ``shockplan`` command line: a thin layer over :mod:`ident` and :mod:`planner`.

Every command is a call into the library; this module parses arguments,
prints summaries and turns the project's errors into one-line messages.

One vocabulary across commands (issue 23): ``--units`` takes ``SI`` or ``imperial`` in
any case and passes the canonical name on; a command that reads drive files defaults it
to the drive file's own unit system (its ``# units:`` line), else SI, and writes its
outputs in it; ``-q`` and ``-v`` go before or after the
command; options are spelled out in full, and a misspelled option or command ends with
exit status 2 and one line naming the nearest valid one; every option's help states its
default and, for a physical quantity, its unit.
"""

from __future__ import annotations

import argparse
import difflib
import logging
import re
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from ident import interrupts
from ident.data.files import check_output
from ident.data.channels import RIG_KINDS
from ident.data.units import UNIT_SYSTEMS
from planner.drive_args import add_parser as add_drive_parser
from planner.dyno_args import unit_system
from planner.dyno_cli import add_parser as add_dyno_parser

__all__ = ["main", "build_parser", "noise_report"]

log = logging.getLogger("shockplan")


def _fmt_table(rows, headers):
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(headers)]
    line = "  ".join(str(h).rjust(w) for h, w in zip(headers, widths))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(str(c).rjust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(out)


def _check_out(args, *, folder=False, overwrite=None):
    """Check ``--out`` before any computation: exists (without --overwrite), read-only folder."""
    check_output(args.out, overwrite=args.overwrite if overwrite is None else overwrite,
                 folder=folder)


def _warn_inventory(setups, library):
    """Log a warning for every setup that needs more units of a shock than the crate's count."""
    from planner.setups import inventory_shortfall

    for s in setups:
        short = inventory_shortfall(s, library)
        if short:
            log.warning("setup %r: %s", s.name, short)


def _baseline_arg(args, library, setups=None):
    """``--baseline`` read by :func:`planner.setups.resolve_baseline` (None when not given):
    a listed setup's name, one shock id (every corner) or four ``LF,RF,LR,RR``; a setup
    built from ids is named ``baseline``."""
    from planner.setups import resolve_baseline

    if not args.baseline:
        return None
    return resolve_baseline(args.baseline, library, setups=setups or (), where="--baseline")


def _load_vehicle(path):
    from ident.models.vehicle import example_vehicle, read_vehicle

    return example_vehicle() if path is None else read_vehicle(path)


def cmd_rig_simulate(args):
    """``shockplan rig simulate``: run a rig plan on the virtual rig, write a session."""

    from ident.sim.rig import default_plan, read_rig_plan, simulate_session
    from ident.data.session import write_session

    _check_out(args, folder=True)
    plan = default_plan() if args.plan is None else read_rig_plan(args.plan)
    if args.duration is not None:
        played = [r.name for r in plan.runs if r.drive is not None]
        if played:
            raise ValueError(
                f"--duration {args.duration:g}: the plan's run(s) {', '.join(played[:3])}"
                f"{' ...' if len(played) > 3 else ''} play drive files, whose length is the "
                "file's; --duration sets only generated drives: leave it out, or give a plan "
                "without drive files")
        plan = replace(plan, runs=tuple(replace(r, duration_s=args.duration) for r in plan.runs))
    if args.noise is not None:
        plan = replace(plan, noise=args.noise)
    if args.input_noise is not None:
        plan = replace(plan, input_noise=args.input_noise)
    if args.rig is not None:
        plan = replace(plan, rig=args.rig)
    vehicle = _load_vehicle(args.vehicle)
    out = Path(args.out)
    session = simulate_session(plan, vehicle, progress=not args.quiet)
    write_session(session, out, units=args.units or plan.units, run_format=args.format,
                  overwrite=args.overwrite)
    counts = [r.n_samples for r in session.runs]
    samples = (f"{counts[0]} samples each" if len(set(counts)) == 1 else
               f"{min(counts)}-{max(counts)} samples per run ({sum(counts)} in all)")
    real = []  # the real car of the plan (issue 25), said only when the plan has it
    if session.bump_stops is not None:
        fitted = sum(any(r.bump_stops.values()) for r in session.runs)
        real.append(f"bump stops on {fitted} of {len(session.runs)} runs")
    if session.static_corner_load_n is not None:
        real.append("static corner loads (the tires may lift off)")
    print(f"wrote rig session '{session.name}' to {out}: {len(session.runs)} runs, "
          f"{samples} at {session.fs_hz:g} Hz, vehicle '{vehicle.name}', "
          f"{plan.rig} rig ({len(session.rig_inputs)} rig inputs)"
          + "".join(f"; {x}" for x in real))
    return 0


def cmd_vehicle_modes(args):
    """``shockplan vehicle modes``: natural frequencies of a vehicle."""
    from ident.data.units import to_si
    from ident.models.vehicle import modal_summary

    vehicle = _load_vehicle(args.vehicle)
    damping = None
    if args.damping is not None:
        damping = to_si(args.damping, "damping", args.units)
    s = modal_summary(vehicle, damping_n_s_m=damping)
    rows = [(lab, f"{f0:.3f}", f"{u:.3f}", f"{d:.3f}", f"{z:.3f}")
            for lab, f0, u, d, z in zip(s.labels, s.no_damping_hz, s.natural_hz, s.damped_hz,
                                        s.damping_ratio)]
    print(f"vehicle '{vehicle.name}', shocks {s.damping_n_s_m[0]:.1f} N/(m/s)")
    print(_fmt_table(rows, ["mode", "no-damping Hz", "natural Hz", "damped Hz", "zeta"]))
    print("no-damping: springs and tires alone (the ride-rate hand calculation); natural and "
          "damped: the modes with these shocks, |s|/2pi and Im(s)/2pi (damped = natural * "
          "sqrt(1 - zeta^2)); shock damping couples chassis and wheels, so natural differs from "
          "no-damping")
    return 0


def _load_any_model(path):
    """An identified model (.npz), a vehicle TOML (the known physical model) or 'paper'."""
    from planner.predict import load_any_model

    return load_any_model(path)


def cmd_identify(args):
    """``shockplan identify``: rig session -> identified vehicle model."""
    import warnings

    from ident.data.session import read_session
    from ident.identify.model import summary_path, write_model_summary
    from ident.identify.pipeline import identify_session

    _check_out(args)
    check_output(summary_path(args.out), overwrite=args.overwrite, what="the model's summary")
    if args.mat:
        check_output(args.mat, overwrite=args.overwrite, what="--mat")
    if args.plots:
        check_output(args.plots, overwrite=True, folder=True, what="--plots")
    out = Path(args.out)
    session = read_session(args.session)
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
                                     max_order=args.max_order, diagnose=not args.no_diagnosis)
    finally:
        diagnose_log.setLevel(level)
        shocks_log.setLevel(shocks_level)
    noise = noise_report(model, session)
    # the noise report built the loop plant; the copy keeps it, and save stores it
    model = model.with_settings(dict(model.settings, noise=noise))
    model.save(out, overwrite=args.overwrite)
    summary_file = write_model_summary(model, summary_path(out), units=session.units,
                                       overwrite=args.overwrite)
    table = model.summary()
    print(f"identified '{session.name}' ({len(session.runs)} runs, {session.fs_hz:g} Hz, "
          f"estimator {model.frf.settings.get('estimator')}) with {args.method}: "
          f"{len(table)} pairs")
    rows = [(r.output, r.input, r.order, f"{r.fit_error:.4f}", f"{r.median_coherence:.3f}")
            for r in table.itertuples()]
    if not args.all_pairs:
        worst = table.sort_values("fit_error", ascending=False).head(12)
        rows = [(r.output, r.input, r.order, f"{r.fit_error:.4f}", f"{r.median_coherence:.3f}")
                for r in worst.itertuples()]
        print("the 12 pairs with the largest fit error (--all-pairs for every pair):")
    print(_fmt_table(rows, ["output", "input", "order", "fit error", "median coh 0.5-20 Hz"]))
    print(f"median fit error {table.fit_error.median():.4f}, orders "
          f"{int(table.order.min())}..{int(table.order.max())}; c_bar "
          f"{', '.join(f'{c:.0f}' for c in model.cbar_n_s_m)} N/(m/s)")
    print(_noise_summary(table, noise))
    if model.elements is not None:  # what the session declared: in the loop of predictions
        lift = model.settings.get("liftoff")
        print(f"real car: {model.elements.describe()}; the bump stops' force is in the "
              "corners' force inputs (the linear model is free of it), and predictions put "
              "the stops and static loads in the loop"
              + ("" if not lift else "; samples where a tire left its pad were corrected "
                 "(pad corrections, settings['liftoff'])"))
    print(_diagnosis_summary(model))
    if "shock_check" in model.settings:  # the session's shock forces against the library
        from ident.identify.shockcheck import ShockLibraryCheck

        print("\n".join(ShockLibraryCheck.from_dict(model.settings["shock_check"]).lines()))
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


def noise_report(model, session, *, n_draws=20, seed=0):
    """How much the identified model rests on noise: per pair (the model's summary) and in
    metrics.

    The expected metric error is the random part of :func:`planner.uncertainty.
    prediction_uncertainty` (95 %) for the session's own first baseline run: its
    recorded rig inputs as the drive and its shocks as the setup.

    Returns
    -------
    dict
        ``noise_limited_pairs``, ``zero_pairs`` (counts), ``expected_metric_error_pct``
        (metric -> half-width of the 95 % interval [%]), ``reference`` (run and setup).
    """
    from ident.data.channels import CORNERS
    from ident.data.drive import Drive
    from planner.setups import Setup
    from planner.uncertainty import prediction_uncertainty

    table = model.summary()
    base = next((r for r in session.runs if r.role == "baseline"), session.runs[0])
    drive = Drive(name=f"run {base.name}", fs_hz=session.fs_hz,
                  channels={c: base.dynamic(c) for c in session.rig_inputs})
    setup = Setup("reference", {c: base.setup[c] for c in CORNERS})
    unc = prediction_uncertainty(model, drive, [setup], session.shocks, n_draws=n_draws,
                                 seed=seed)
    lo, hi = unc.components["random_lo"].iloc[0], unc.components["random_hi"].iloc[0]
    half = {m: 100 * float(max(hi[m] - 1, 1 - lo[m])) for m in unc.metric_names}
    return {"noise_limited_pairs": int((table.status == "noise-limited").sum()),
            "zero_pairs": int((table.status == "zero").sum()),
            "expected_metric_error_pct": half,
            "reference": {"run": base.name, "setup": "/".join(setup.ids())}}


def _noise_summary(table, noise):
    """Lines for the terminal: pairs resting on noise and the metric error to expect."""
    half = noise["expected_metric_error_pct"]
    worst = max(half, key=half.get)
    lines = [f"noise: {noise['noise_limited_pairs']} pairs noise-limited (relative noise of the "
             f"conditioned FRF >= 10 %), {noise['zero_pairs']} fitted as zero (nothing above "
             "the noise); expected metric error from the identification's random error "
             f"(95 %, the session's run '{noise['reference']['run']}'): median "
             f"{np.median(list(half.values())):.3f} %, max {half[worst]:.3f} % ({worst})"]
    banded = table[table.noise_bands_hz != ""].sort_values("noise_level", ascending=False)
    if len(banded):
        lines.append(f"{len(banded)} pairs have bands resting on noise (within 40 dB of their "
                     "peak), e.g.:")
        lines += [f"  {r.output} <- {r.input}: {r.noise_bands_hz} Hz"
                  for r in banded.head(3).itertuples()]
    return "\n".join(lines)


def _diagnosis_summary(model):
    """Lines for the terminal: what the session shows that the linear model cannot see."""
    from ident.identify.diagnose import Diagnosis

    doc = model.settings.get("diagnosis")
    if doc is None:
        return "diagnosis: skipped (--no-diagnosis)"
    diag = Diagnosis.from_dict(doc)
    amplitude = diag.settings.get("amplitude", "")
    if not len(diag):
        return ("diagnosis: nothing the linear model cannot see (bump stops, lift-off, the "
                "runs re-simulated on the model against their noise; amplitude dependence "
                f"{amplitude})")
    groups = diag.groups()
    lines = [(f"diagnosis: {len(groups)} finding(s) the linear model cannot see (per corner "
              f"over the runs; {len(diag)} per run and corner in the model's settings; "
              f"amplitude dependence {amplitude}):")]
    lines += [f"  warning: {line}" if not line.startswith("    ") else f"  {line}"
              for line in diag.lines()]
    return "\n".join(lines)


def _read_inputs(args):
    from ident.data.drive import read_drive
    from ident.models.library import read_shock_library

    model = _load_any_model(args.model)
    drive = read_drive(args.drive, units=args.units)
    _output_units(args, [drive])
    library = read_shock_library(args.shocks)
    return model, drive, library


def _output_units(args, drives):
    """The unit system of the outputs, set as ``args.units``: ``--units`` if given, else the
    first drive file's (its ``# units:`` line; the spec: predictions in the drive file's
    units), else SI."""
    if args.units is None:
        args.units = drives[0].settings.get("units", "SI") if drives else "SI"
    return args.units


def cmd_predict(args):
    """``shockplan predict``: metrics of every setup of a setups CSV (spec's predictions CSV)."""
    from planner.predict import predict_setups
    from planner.report import write_predictions_csv
    from planner.setups import read_setups

    _check_out(args)
    model, drive, library = _read_inputs(args)
    stops = _bump_stop_library(args, model)
    setups = read_setups(args.setups, library, stops, units=args.units)
    _warn_inventory(setups, library)
    pred = predict_setups(model, drive, setups, library, oversample=args.oversample,
                          static_loads_n=None, progress=not args.quiet, bump_stops=stops,
                          elements=not args.no_elements)
    write_predictions_csv(pred.table, args.out, units=args.units, overwrite=args.overwrite)
    print(f"predicted {len(setups)} setups on drive '{drive.name}' ({drive.duration_s:g} s): "
          f"wrote {args.out} ({args.units})")
    for line in _element_lines(pred.settings.get("elements"), pred.table):
        print(line)
    return 0


def _bump_stop_library(args, model):
    """``--bump-stops FILE`` read (it replaces the model's library), else None."""
    from ident.models.bumpstops import read_bump_stops

    path = getattr(args, "bump_stops", None)
    return None if path is None else read_bump_stops(path)


def _element_lines(settings, table):
    """What the loop held besides the shocks, and the largest shares of time in it."""
    if not settings:
        return []
    lines = []
    shares = [c for c in table.columns if c.startswith("bump_stop_contact_share_")]
    if shares:
        worst = table[shares].max()
        lines.append("bump stops in the loop (library: " + str(settings.get("library"))
                     + "); largest share of time in contact: "
                     + ", ".join(f"{c[-2:]} {100 * v:.1f} %" for c, v in worst.items()))
    lifts = [c for c in table.columns if c.startswith("tire_liftoff_share_")]
    if lifts:
        worst = table[lifts].max()
        lines.append("static corner loads in the loop (tire lift-off); largest share of time "
                     "off the pad: " + ", ".join(f"{c[-2:]} {100 * v:.2f} %"
                                                for c, v in worst.items()))
    return lines


def _parse_fixed(items):
    fixed = {}
    for item in items or ():
        corner, sep, sid = item.partition("=")
        if not sep:
            raise ValueError(f"--fixed {item!r}: write CORNER=SHOCK_ID, e.g. --fixed LF=B20")
        fixed[corner.strip()] = sid.strip()
    return fixed


def cmd_rank(args):
    """``shockplan rank``: rank setups (screen, simulate the best, score) and write a report."""
    from planner.objective import default_objective, read_objective
    from planner.clicks import MAX_CLICK_SETUPS, clicks_option, split_shock_ids
    from planner.rank import rank_setups
    from planner.report import write_ranking
    from planner.setups import read_setups

    _check_out(args, folder=True)
    model, drive, library = _read_inputs(args)
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    setups, constraints = None, None
    clicks = clicks_option(args)
    stops = _bump_stop_library(args, model)
    if args.setups:
        setups = read_setups(args.setups, library, stops, units=args.units)
    else:
        constraints = {"symmetry": args.symmetry, "axles": args.axles,
                       "fixed": _parse_fixed(args.fixed) or None}
        if clicks is not None:  # screened, then the best --simulate in the time domain
            constraints.update(clicks=clicks, max_setups=MAX_CLICK_SETUPS)
        if args.only:
            constraints["shocks"] = split_shock_ids(args.only)
    baseline = _baseline_arg(args, library, setups)
    variations = _element_choices(args)
    out = Path(args.out)
    ranking = rank_setups(model, drive, library, setups=setups, constraints=constraints,
                          objective=objective, baseline=baseline, top=args.simulate,
                          oversample=args.oversample, uncertainty=not args.no_uncertainty,
                          scheduler=args.scheduler, n_workers=args.workers,
                          progress=not args.quiet, bump_stops=stops,
                          elements=not args.no_elements, **variations)
    files = write_ranking(ranking.table, out, units=args.units, objective=objective,
                          baseline=ranking.baseline, overwrite=args.overwrite)
    write_ranking_screening = out / "screening.csv"
    from planner.report import write_predictions_csv

    write_predictions_csv(ranking.screening, write_ranking_screening, units=args.units,
                          overwrite=args.overwrite)
    print(_ranking_summary(ranking, args.units))
    print("wrote " + ", ".join(str(p) for p in list(files.values()) + [write_ranking_screening]))
    return 0


def _add_element_options(parser):
    """``--bump-stops FILE`` and ``--no-elements`` (the real car's elements)."""
    parser.add_argument("--bump-stops", metavar="FILE",
                        help="bump-stop library TOML (bumpstops.toml) naming the stops of the "
                        "setups' bump_stop_XX columns and of bump_stop factors (default: the "
                        "model's, from its session)")
    parser.add_argument("--no-elements", action="store_true",
                        help="leave the model's bump stops and static loads (tire lift-off) "
                        "out of the loop (default: in the loop when the session declared "
                        "them)")


def _packer_bounds(args):
    """``--packers GROUP=LO:HI`` as :func:`planner.optimize.optimize_curves`' ``packers``."""
    from planner.elements import parse_length

    out = {}
    for item in getattr(args, "packers", None) or ():
        group, sep, span = item.partition("=")
        lo, sep2, hi = span.partition(":")
        if not sep or not sep2 or not group.strip():
            raise ValueError(f"--packers {item!r}: write GROUP=LO:HI with GROUP a corner group "
                             "of the symmetry (front, rear; a corner with --symmetry none), "
                             "e.g. --packers front=0:4mm")
        unit = re.search(r"[a-z]+$", hi.strip().lower())
        if unit and not re.search(r"[a-z]+$", lo.strip().lower()):
            lo = lo.strip() + unit.group(0)  # 2:4mm is 2 mm to 4 mm
        out[group.strip()] = tuple(parse_length(x, units=args.units, where="--packers")
                                   for x in (lo, hi))
    return out or None


def _add_try_options(parser):
    """``--try-bump-stops`` and ``--try-packers`` (bump stops and packers as setup columns)."""
    parser.add_argument("--try-bump-stops", action="append", metavar="GROUP=ID,ID",
                        help="rank every setup with each of these bump stops at GROUP "
                        "(front, rear, all or a corner; 'none' for none); repeatable "
                        "(default: the setups' own)")
    parser.add_argument("--try-packers", action="append", metavar="GROUP=L,L",
                        help="rank every setup with each of these packers at GROUP, in "
                        "the drive's units or with a unit (0,2mm,4mm); repeatable "
                        "(default: the setups' own)")


def _element_choices(args):
    """``--try-bump-stops GROUP=ID,ID`` and ``--try-packers GROUP=L,L`` as
    :func:`planner.elements.vary_elements`' arguments."""
    from planner.elements import parse_length

    out = {}
    for opt, key in (("try_bump_stops", "vary_bump_stops"), ("try_packers", "vary_packers_m")):
        items = getattr(args, opt, None) or ()
        flag = "--" + opt.replace("_", "-")
        for item in items:
            group, sep, values = item.partition("=")
            vals = [v.strip() for v in values.split(",") if v.strip()]
            if not sep or not group.strip() or not vals:
                raise ValueError(f"{flag} {item!r}: write GROUP=A,B with GROUP front, rear, "
                                 "all or a corner, e.g. " + ("--try-bump-stops front=BS-F,BS-F2"
                                                              if key == "vary_bump_stops" else
                                                              "--try-packers front=0,2mm,4mm"))
            if key == "vary_packers_m":
                vals = [parse_length(v, units=args.units or "SI", where=flag) for v in vals]
            out.setdefault(key, {})[group.strip()] = vals
    return out


def _polish_line(polish):
    """The click polish's line of a ranking summary (none without adjustable settings)."""
    if not polish:
        return []
    moved = f"; it moved the best from {polish['start']}" if polish["moved"] else ""
    return [f"click polish: {polish['simulated']} neighbouring setting(s) simulated in "
            f"{polish['rounds']} round(s){moved}"]


def _ranking_summary(ranking, units, n=5):
    from planner.screen import describe_agreement

    t = ranking.table
    lines = [f"screened {len(ranking.screening)} setups, simulated {len(t)} in the time domain; "
             f"screening vs time-domain Spearman {ranking.agreement['spearman']:.3f}",
             describe_agreement(ranking.agreement, what="ranking"),
             *_polish_line(ranking.settings.get("click_polish")),
             f"baseline '{ranking.baseline}' scores {ranking.objective.total_weight:.3f}; best:"]
    rows = []
    for name, r in t.head(n).iterrows():
        rows.append((int(r["rank"]), name, f"{r['score']:.4f}",
                     "yes" if r.get("feasible", True) else "no", r.get("unresolved", "") or "-"))
    lines.append(_fmt_table(rows, ["rank", "setup", "score", "feasible", "not resolved from"]))
    return "\n".join(lines)


def cmd_sweep(args):
    """``shockplan sweep``: screen a large enumeration on several drives/models (Dask), simulate
    the best share, rank; writes ranking.csv, one CSV per case and sweep.toml."""
    from ident.data.drive import read_drive
    from ident.models.library import read_shock_library
    from planner.objective import default_objective, read_objective
    from planner.report.sweep import write_sweep
    from planner.clicks import clicks_option, split_shock_ids
    from planner.setups import read_setups
    from planner.sweep import sweep_setups

    _check_out(args, folder=True)
    models = {m: _load_any_model(m) for m in dict.fromkeys(args.model)}
    drives = {d: read_drive(d, units=args.units) for d in dict.fromkeys(args.drive)}
    _output_units(args, list(drives.values()))
    library = read_shock_library(args.shocks)
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    setups, constraints = None, None
    clicks = clicks_option(args)
    if args.setups:
        setups = read_setups(args.setups, library)
    else:
        constraints = {"symmetry": args.symmetry, "axles": args.axles,
                       "fixed": _parse_fixed(args.fixed) or None,
                       "respect_inventory": not args.ignore_inventory, "clicks": clicks}
        if args.only:
            constraints["shocks"] = split_shock_ids(args.only)
    baseline = _baseline_arg(args, library, setups)
    scheduler = args.scheduler
    result = sweep_setups(models, drives, library, setups=setups, constraints=constraints,
                          objective=objective, baseline=baseline, top_share=args.simulate_share,
                          top=args.simulate, combine=args.combine, chunk_size=args.chunk_size,
                          oversample=args.oversample, scheduler=scheduler,
                          n_workers=args.workers, progress=not args.quiet,
                          bump_stops=_bump_stop_library(args, None),
                          elements=not args.no_elements, **_element_choices(args))
    written = write_sweep(result, args.out, units=args.units, overwrite=args.overwrite)
    print(_sweep_summary(result))
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def _sweep_summary(result, n=5):
    from planner.screen import describe_agreement

    st, t = result.settings, result.table
    sec = st["seconds"]
    lines = [f"screened {st['n_screened']:,} setups x {len(st['cases'])} case(s) in "
             f"{sec['screen']:.1f} s ({st['screen_setups_per_s']:,.0f} setup-cases/s, "
             f"scheduler {st['scheduler']}, {st['n_workers']} worker(s)); simulated {len(t)} in "
             f"{sec['simulate']:.1f} s ({st['simulate_setups_per_s']:,.0f} setup-cases/s)",
             describe_agreement(result.agreement, what="ranking"),
             f"baseline '{result.baseline}'; {st['combine']} of the cases' scores; best:"]
    rows = [(int(r["rank"]), name, f"{r['score']:.4f}", int(r["screening_rank"]),
             "yes" if r["feasible"] else "no") for name, r in t.head(n).iterrows()]
    lines.append(_fmt_table(rows, ["rank", "setup", "score", "screening rank", "feasible"]))
    return "\n".join(lines)


def cmd_optimize(args):
    """``shockplan optimize``: the best damper curve per corner group, mapped to the crate."""
    import warnings

    from ident.data.drive import read_drive
    from ident.models.library import read_shock_library
    from ident.data.units import from_si
    from planner.objective import default_objective, read_objective
    from planner.optimize import (
        DEFAULT_KNOTS_M_S,
        QUANTILE_KNOTS,
        optimize_curves,
        read_curve_constraints,
        write_optimum,
    )
    from planner.report.optimize import STATIONARY_FLAT, click_summary

    out = Path(args.out)
    _check_out(args, folder=True)
    model = _load_any_model(args.model)
    drives = [read_drive(d, units=args.units) for d in args.drive]
    _output_units(args, drives)
    library = read_shock_library(args.shocks)
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    constraints = None if args.constraints is None else read_curve_constraints(args.constraints)
    weights = None
    if args.drive_weights:
        try:
            weights = [float(w) for w in args.drive_weights.split(",")]
        except ValueError:
            raise ValueError(f"--drive-weights {args.drive_weights!r}: give numbers separated "
                             "by commas, one per --drive") from None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        opt = optimize_curves(model, drives, library, objective=objective,
                              baseline=args.baseline, symmetry=args.symmetry,
                              constraints=constraints, drive_weights=weights,
                              aggregate="worst" if args.worst_case else "sum",
                              robust=args.robust, oversample=args.oversample,
                              max_iter=args.max_iter, n_starts=args.starts,
                              progress=not args.quiet,
                              knots_m_s=(QUANTILE_KNOTS if args.knots == "quantiles"
                                         else DEFAULT_KNOTS_M_S),
                              elements=not args.no_elements,
                              bump_stop_library=_bump_stop_library(args, model),
                              packers=_packer_bounds(args), click_radius=args.click_radius)
    files = write_optimum(opt, library, out, units=args.units, overwrite=args.overwrite)
    t = opt.table
    s = opt.solver
    lines = [f"optimized {len(opt.curves)} curve(s) ({opt.space.symmetry}) on "
             f"{len(drives)} drive(s): IPOPT {s['status']} after {s['iterations']} iterations, "
             f"{s['n_eval']} closed-loop evaluations, {s['build_s'] + s['solve_s']:.1f} s",
             f"verified in the time domain (baseline {t.loc[opt.baseline.name, 'score']:.4f}): "
             f"{opt.verdict()}"]
    if opt.bump_stops is not None:
        lines.append("bump stops in the loop and the verification"
                     + (", packers chosen: " + ", ".join(
                         f"{g} {from_si(p, 'displacement', args.units):.4g} "
                         f"{'in' if args.units == 'imperial' else 'm'}"
                         for g, p in opt.packers_m.items()) if opt.packers_m else ""))
    scan = opt.settings.get("scan")
    if scan:
        source = {"scan": "the scan's best curve",
                  "iterate": "IPOPT's best feasible iterate"}.get(s.get("source"),
                                                                   "IPOPT's solution")
        lines.append(f"scan: {scan['n_screened']} linear and two-slope setups screened, "
                     f"{scan['n_verified']} verified, best linear {scan['linear_score']:.4f}, "
                     f"best {scan['best']} {scan['score']:.4f} "
                     f"({scan['screen_s'] + scan['verify_s']:.1f} s); the optimum is {source}")
    close = t[t["kind"] == "closest"]
    if len(close):
        lines.append("closest crate setups: " + ", ".join(
            f"{n} ({r['score']:.4f}, distance {r['distance']:.2f})" for n, r in close.iterrows()))
    if opt.stationarity is not None and len(opt.stationarity):
        st = opt.stationarity
        change = float(st.relative_change.min())
        # a move that changes the score by less than the model's accuracy says nothing
        flat = st.groupby("variable")["relative_change"].apply(
            lambda r: bool(np.all(np.abs(r) < STATIONARY_FLAT)))
        note = ""
        if flat.any():
            note = (f"; {int(flat.sum())} of {len(flat)} variables change it by less than "
                    f"{100 * STATIONARY_FLAT:g} % either way (flat: the score hardly depends "
                    "on them)")
        lines.append("stationarity: every knot force moved by +-5 % " + (
            f"worsens the score (by {100 * change:.4f} % at least)" if change >= 0 else
            f"improves the score by at most {-100 * change:.4f} %") + note)
    ref = (0.05, 0.1, 0.25)  # m/s
    for sid, m in opt.shocks.items():
        vals = ", ".join(
            f"{from_si(m.force(v), 'force', args.units):.0f}/"
            f"{from_si(m.force(-v), 'force', args.units):.0f}" for v in ref)
        unit_v = "m/s" if args.units == "SI" else "in/s"
        vs = "/".join(f"{from_si(v, 'velocity', args.units):.3g}" for v in ref)
        lines.append(f"{sid}: bump/rebound force at {vs} {unit_v}: {vals} "
                     f"{'N' if args.units == 'SI' else 'lbf'}")
    lines += click_summary(opt)
    for w in caught:
        lines.append(f"warning: {w.message}")
    lines.append("wrote " + ", ".join(str(p) for p in files.values()))
    print("\n".join(lines))
    return 0


def cmd_plan(args):
    """``shockplan plan``: the next rig runs (optimal experiment design) and the run sheet."""
    from ident.data.drive import read_drive
    from ident.identify.model import load_model
    from ident.data.session import read_session
    from ident.models.library import read_shock_library
    from planner.design import design_experiment
    from planner.objective import default_objective, read_objective
    from planner.rig import read_rig
    from planner.testplan import write_plan

    out = Path(args.out)
    _check_out(args, folder=True)
    if (args.vehicle is None) == (args.model is None):
        raise ValueError("give either --vehicle (before rig day: the known car, a vehicle TOML "
                         "or 'paper') or --model with --session (between runs)")
    session = None
    if args.model is not None:
        if args.session is None:
            raise ValueError("--model needs --session: the runs the model was identified from "
                             "are the plan's prior information")
        model = load_model(args.model)
        session = read_session(args.session)
    else:
        model = _load_vehicle(None if args.vehicle == "paper" else args.vehicle)
    library = read_shock_library(args.shocks)
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    drives = [read_drive(d, units=args.units) for d in args.drive] if args.drive else None
    _output_units(args, drives)
    rig = read_rig(args.rig_costs) if args.rig_costs else None
    plan = design_experiment(model, library, budget_min=args.budget_min,
                             criterion=args.criterion, session=session, objective=objective,
                             baseline=args.baseline, drives=drives, rig=rig,
                             baseline_every=args.baseline_every, n_validation=args.validate)
    files = write_plan(plan, out, units=args.units, overwrite=args.overwrite)
    t = plan.table()
    rows = [(n, r["name"], f"{r['start_min']:.1f}", f"{r['duration_s'] / 60:.1f}", r["purpose"],
             "/".join(r[c] for c in ("LF", "RF", "LR", "RR")), r["changed"] or "-",
             f"{100 * r['share']:.0f} %") for n, r in t.iterrows()]
    print(f"planned {len(t)} runs in {plan.total_min:.1f} of {plan.budget_min:g} min "
          f"(criterion {plan.criterion}; cvxpy {plan.solver['status']} in "
          f"{plan.solver['solve_s']:.1f} s; {plan.solver['n_candidates']} candidate runs)")
    print(_fmt_table(rows, ["run", "name", "start min", "min", "purpose", "LF/RF/LR/RR",
                            "changed", "share"]))
    print("wrote " + ", ".join(str(p) for p in files.values()))
    return 0


def cmd_import(args):
    """``shockplan import``: real rig files (RPC III, MDF4, TDMS) appended to a session."""
    from ident.data.formats import import_runs

    _check_out(args, folder=True, overwrite=True)  # appending to a session is the point
    names = None if args.names is None else [n.strip() for n in args.names.split(",")]
    session = import_runs(args.out, args.files, format=args.format, channel_map=args.map,
                          setup=args.setup, role=args.role, names=names, shocks=args.shocks,
                          units=args.units)
    added = len(args.files)
    print(f"imported {added} run(s) into session '{session.name}' at {args.out}: now "
          f"{len(session.runs)} runs at {session.fs_hz:g} Hz ({session.units})")
    return 0


def cmd_export_drive(args):
    """``shockplan export-drive``: a drive file written as the RPC III file a rig plays."""
    from ident.data.drive import read_drive
    from ident.data.formats import export_drive_rpc3

    _check_out(args)
    drive = read_drive(args.drive, units=args.units)
    path = export_drive_rpc3(drive, args.out, channel_map=args.map, overwrite=args.overwrite)
    print(f"wrote drive '{drive.name}' ({drive.duration_s:g} s at {drive.fs_hz:g} Hz) as RPC III "
          f"to {path}")
    return 0


def cmd_whatif(args):
    """``shockplan whatif``: every setup under every perturbation; robust ranking, files."""
    from ident.data.drive import read_drive
    from ident.models.library import read_shock_library
    from planner.objective import default_objective, read_objective
    from planner.setups import read_ranking_baseline, read_setups
    from planner.whatif import (FRAGILE_SHARE, RANK_TOLERANCE, evaluate_whatif,
                                read_perturbations, write_whatif)

    out = Path(args.out)
    _check_out(args, folder=True)
    model = _load_any_model(args.model)
    library = read_shock_library(args.shocks)
    drives = [read_drive(d, units=args.units) for d in args.drive]
    _output_units(args, drives)
    perturbations = read_perturbations(args.perturb)
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    stops = _bump_stop_library(args, model)
    if args.setups:
        setups = read_setups(args.setups, library, stops, units=args.units)
    else:
        if args.top < 1:
            raise ValueError(f"--top must be at least 1, got {args.top}")
        ranked = read_setups(args.ranking, library, stops, units=args.units)
        setups = ranked[: args.top]
    baseline = _baseline_arg(args, library, setups)
    if baseline is None and args.ranking:
        # the ranking's own baseline (not its best setup), added if beyond --top
        name = read_ranking_baseline(args.ranking)
        if name is not None:
            baseline = next((s for s in ranked if s.name == name), None)
    if baseline is None and objective.baseline is None:
        first = setups[0].name
        print(f"baseline: '{first}', the first setup of {args.setups or args.ranking} "
              "(give --baseline to score against another)")
    result = evaluate_whatif(
        model, drives, setups, library, perturbations, objective=objective, baseline=baseline,
        method=args.method, oversample=args.oversample,
        rank_tolerance=RANK_TOLERANCE if args.rank_tolerance is None else args.rank_tolerance,
        fragile_share=FRAGILE_SHARE if args.fragile_share is None else args.fragile_share,
        scheduler=args.scheduler, n_workers=args.workers, progress=not args.quiet,
        bump_stops=stops, elements=not args.no_elements)
    files = write_whatif(result, out, units=args.units, overwrite=args.overwrite)
    print(_whatif_summary(result))
    print(f"wrote {len(files)} files to {out}: " + ", ".join(sorted(files)[:6])
          + (" ..." if len(files) > 6 else ""))
    return 0


def _whatif_summary(result, n=10):
    st = result.settings
    rob = result.robust
    lines = [f"{st['n_setups']} setups x {st['n_conditions']} conditions "
             f"({result.perturbations.design}, {st['method']}): {st['n_evaluations']} "
             f"evaluations in {st['elapsed_s']:.1f} s"
             + (f" on Dask ({st['scheduler']}, {st['n_workers']} worker(s))"
                if st.get("scheduler", "none") != "none" else "")
             + f"; baseline '{result.baseline}'"]
    if "agreement" in st:
        from planner.screen import describe_agreement

        agree = st["agreement"]
        lines.append("nominal condition checked in the time domain: "
                     + describe_agreement(agree, what=None)
                     + ("" if agree["same_best"] else
                        "; decide with --method time, the reference"))
    rows = []
    for name, r in rob.head(n).iterrows():
        rows.append((name, int(r["nominal_rank"]), f"{r['mean_score']:.4f}",
                     f"{r['worst_score']:.4f}", f"{int(r['best_rank'])}-{int(r['worst_rank'])}",
                     f"{100 * r['moved_share']:.0f} %", "FRAGILE" if r["fragile"] else "-"))
    lines.append(_fmt_table(rows, ["setup", "nominal", "mean score", "worst score", "ranks",
                                   "moved", "rank"]))
    fr = result.fragile
    lines.append(f"fragile ranks: {', '.join(fr)}" if fr else
                 f"no fragile ranks (rank moved > {st['rank_tolerance']} places in more than "
                 f"{100 * st['fragile_share']:.0f} % of conditions)")
    lines += [f"note: {note}" for note in st.get("notes", ())]  # clicks clipped, ...
    return "\n".join(lines)


def cmd_demo(args):
    """``shockplan demo``: the main job end to end on the built-in example."""
    from planner.demo import run_demo

    _check_out(args, folder=True)
    summary = run_demo(Path(args.out), overwrite=args.overwrite, progress=not args.quiet)
    print(summary)
    return 0


def cmd_drive(args):
    """``shockplan drive from-track|iterate|section`` (:mod:`planner.drive_commands`)."""
    from planner.drive_commands import run_drive_command

    return run_drive_command(args)


def cmd_dyno_table(args):
    """``shockplan dyno table`` (:func:`planner.dyno_commands.cmd_dyno_table`)."""
    from planner.dyno_commands import cmd_dyno_table as run

    return run(args)


def cmd_dyno_check(args):
    """``shockplan dyno check`` (:func:`planner.dyno_commands.cmd_dyno_check`)."""
    from planner.dyno_commands import cmd_dyno_check as run

    return run(args)


#: difflib similarity a misspelled option or command must reach for the nearest valid one to
#: be named: stricter than difflib's 0.6, as :func:`ident.data.files.did_you_mean`, so that
#: an option of a command written before it ('--units') is not taken for '--quiet'.
TYPO_CUTOFF = 0.75

#: Options renamed so that one name means one thing in every command (issue 23):
#: ``{command: {old: (new, what the new one means)}}``. The old spelling is refused with
#: the new one named, never taken silently.
RENAMED_OPTIONS = {
    "rank": {"--top": ("--simulate", "the number of setups simulated in the time domain; "
                       "--top is whatif's: the number of setups taken from a ranking")},
    "sweep": {"--top": ("--simulate", "the number of setups simulated in the time domain"),
              "--top-share": ("--simulate-share", "the share of setups simulated in the "
                              "time domain")},
    "plan": {"--rig": ("--rig-costs", "the rig TOML of swap and run times; --rig is the rig "
                       "kind of 'rig simulate'")},
}

#: What argparse takes for a negative number (a value, not an option).
_NEGATIVE_NUMBER = re.compile(r"^-\d+$|^-\d*\.\d+$")

#: The flags taken before or after any command (issue 23): short, long, help.
_FLAGS_ANYWHERE = (("-v", "--verbose",
                    "log progress details (default: warnings only); before or after the command"),
                   ("-q", "--quiet",
                    "no progress bars (default: shown); before or after the command"))


def _int_at_least(low):
    """An argparse type: an integer >= `low`, refused before any work with the bound named."""
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {value}")
        return value
    return parse


def _share(text):
    """An argparse type: a share in (0, 1] (e.g. 0.01 for the best 1 %)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number in (0, 1], got {text!r}") from None
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], e.g. 0.01 for the best 1 %, got "
                                         f"{value:g}")
    return value


#: ``--units`` default of the commands that read one drive file / several (issue 23): the
#: file's unit marker, else SI; a given ``--units`` that contradicts the marker is an error.
_UNITS_OF_DRIVE = "the drive file's own, from its '# units:' line, else SI"
_UNITS_OF_DRIVES = ("each drive file's own, from its '# units:' line, else SI; the outputs "
                    "in the first drive's")


def _add_units(parser, what, *, default="SI", default_text="SI"):
    """Add ``--units`` (``SI`` or ``imperial``, any case) to `parser`."""
    parser.add_argument("--units", type=unit_system, choices=list(UNIT_SYSTEMS),
                        default=default, help=f"{what}: SI or imperial, in any case (default: "
                        f"{default_text})")


def _subcommands(parser):
    """The subparsers action of `parser` (its commands), or None."""
    return next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)),
                None)


def _option_owners(option, commands):
    """The commands under `commands` (``rank``, ``rig simulate``) that take `option`."""
    owners = []
    for name, parser in commands.choices.items():
        inner = _subcommands(parser)
        if inner is not None:
            owners += [f"{name} {o}" for o in _option_owners(option, inner)]
        elif option in parser._option_string_actions:
            owners.append(name)
    return owners


def _looks_like_option(arg):
    """Whether argparse takes `arg` for an option (not a value such as ``-0.5``)."""
    return len(arg) > 1 and arg[0] == "-" and " " not in arg and not _NEGATIVE_NUMBER.match(arg)


class _Parser(argparse.ArgumentParser):
    """An argument parser that takes options only spelled out in full, and answers a
    misspelled option or command with the nearest valid one of that command (issue 23).

    Abbreviations (``--shock`` for ``--shocks``) are refused: one that works today
    breaks or changes meaning when an option with the same beginning is added. An
    unknown option or command ends the program with exit status 2 and one line, before
    argparse's own checks (so a misspelled ``--shocks`` is named, not reported missing).
    """

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def parse_known_args(self, args=None, namespace=None):
        """:meth:`argparse.ArgumentParser.parse_known_args`, after refusing a misspelled
        option or command of this parser."""
        args = sys.argv[1:] if args is None else list(args)
        self._check_spelling(args)
        return super().parse_known_args(args, namespace)

    def _check_spelling(self, args):
        """Refuse the first unknown option or command of `args` (up to this parser's
        command: the rest is the command's parser's to check)."""
        commands = _subcommands(self)
        is_value = False
        for arg in args:
            if is_value:
                is_value = False
                continue
            if arg == "--":
                return
            if not _looks_like_option(arg):
                if commands is None:
                    continue
                if arg not in commands.choices:
                    close = difflib.get_close_matches(arg, list(commands.choices), n=3,
                                                      cutoff=TYPO_CUTOFF)
                    hint = (f"did you mean {' or '.join(close)}?" if close else
                            f"the commands are {', '.join(commands.choices)}")
                    self._fail(f"unknown command {arg!r}; {hint}")
                return
            name = arg.split("=", 1)[0] if arg.startswith("--") else arg
            action = self._option_string_actions.get(name)
            if action is None and not arg.startswith("--"):
                action = self._option_string_actions.get(arg[:2])  # grouped flags: -qv
            if action is None:
                self._unknown_option(name, commands)
            # an option's value before the command is not the command
            is_value = (commands is not None and action.nargs != 0
                        and arg in self._option_string_actions)

    def _unknown_option(self, name, commands):
        said = f"unrecognized option {name!r}"
        renamed = RENAMED_OPTIONS.get(self.prog.split(" ", 1)[-1], {}).get(name)
        if renamed is not None:
            self._fail(f"{said}: it was renamed {renamed[0]} ({renamed[1]})")
        owners = [] if commands is None else _option_owners(name, commands)
        if owners:
            self._fail(f"{said}: it is an option of {', '.join(owners)}; write it after the "
                       "command")
        longs = {o.lstrip("-"): o for o in self._option_string_actions if o.startswith("--")}
        stem = name.lstrip("-")
        # an abbreviation's full spellings first, then the misspellings' nearest
        close = [o for o in longs if stem and o.startswith(stem)]
        close += [o for o in difflib.get_close_matches(stem, list(longs), n=3,
                                                        cutoff=TYPO_CUTOFF) if o not in close]
        close = close[:3]
        if close:
            self._fail(f"{said}; did you mean {' or '.join(longs[c] for c in close)}?")
        self._fail(f"{said}; see '{self.prog} --help' for the options")

    def _fail(self, message):
        """Exit with status 2 and one line (no usage: the line says what to write)."""
        self.exit(2, f"{self.prog}: error: {message}\n")


def _add_flags_anywhere(parser):
    """Give every command (and its commands) the top level's ``-v`` and ``-q``, so that
    ``shockplan rank ... -q`` works as ``shockplan -q rank ...``. A command's copy sets the
    flag only when given (default SUPPRESS): it never resets the top level's."""
    commands = _subcommands(parser)
    for sub in () if commands is None else commands.choices.values():
        for short, long, text in _FLAGS_ANYWHERE:
            sub.add_argument(short, long, action="store_true", default=argparse.SUPPRESS,
                             help=text)
        _add_flags_anywhere(sub)


_MODEL_HELP = "identified model (.npz), a vehicle TOML (the known physical model) or 'paper'"
_OBJECTIVE_HELP = "objective TOML (default: the built-in 'grip and platform')"


def build_parser():
    """Build the argument parser (exposed for documentation and tests)."""
    from planner.clicks import add_click_arguments

    p = _Parser(
        prog="shockplan",
        description="Shock-absorber selection planner for 7-post, 8-post and 4-post shaker "
        "rigs.")
    for short, long, text in _FLAGS_ANYWHERE:
        p.add_argument(short, long, action="store_true", help=text)
    sub = p.add_subparsers(dest="command", required=True,
                           help="the command ('shockplan COMMAND --help' for its options)")

    demo = sub.add_parser("demo", help="run the whole job on the built-in example car")
    demo.add_argument("--out", default="shockplan-demo", help="output folder (default %(default)s)")
    demo.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    demo.set_defaults(func=cmd_demo)

    rig = sub.add_parser("rig", help="the virtual rig")
    rig_sub = rig.add_subparsers(dest="rig_command", required=True, help="the rig command")
    sim = rig_sub.add_parser("simulate", help="simulate a rig plan and write a rig session")
    sim.add_argument("--plan", help="rig plan TOML (default: the built-in plan, the paper's "
                     "identification experiment: 5 runs of 800 s at 100 Hz, imperial, 7-post)")
    sim.add_argument("--vehicle", help="vehicle TOML (default: the paper's Table 1 car)")
    sim.add_argument("--out", required=True, help="session folder to write")
    _add_units(sim, "units of the written session", default=None,
               default_text="the plan's 'units'; imperial for the built-in plan")
    sim.add_argument("--format", choices=["csv", "parquet"], default="csv",
                     help="run file format (default %(default)s)")
    sim.add_argument("--duration", type=float, help="every run's duration [s] (default: the "
                     "plan's; 800 s in the built-in plan)")
    sim.add_argument("--noise", type=float, help="measurement noise of the response channels, "
                     "a fraction of each channel's RMS (default: the plan's 'noise'; 0 in the "
                     "built-in plan)")
    sim.add_argument("--input-noise", type=float, help="measurement noise of the recorded rig "
                     "inputs, a fraction of each input's RMS (default: the plan's "
                     "'input_noise'; 0 in the built-in plan)")
    sim.add_argument("--rig", choices=list(RIG_KINDS), help="the rig kind (default: the plan's "
                     "'rig'; 7-post for the built-in plan and for a plan that names none): "
                     "'7-post' and '8-post' have aero actuators; '4-post' has none and writes "
                     "runs without aero channels")
    sim.add_argument("--overwrite", action="store_true", help="replace an existing session folder")
    sim.set_defaults(func=cmd_rig_simulate)

    ident_p = sub.add_parser("identify", help="identify a vehicle model from a rig session")
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
    ident_p.add_argument("--coherence-min", type=float, default=0.9,
                         help="coherence (0 to 1) below which band ends are replaced "
                         "(default %(default)s)")
    ident_p.add_argument("--max-order", type=_int_at_least(2), default=10, metavar="N",
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
    ident_p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    ident_p.set_defaults(func=cmd_identify)

    for name, helptext, func in (("predict", "predict every setup of a setups CSV", cmd_predict),
                                 ("rank", "rank shock setups and write a report", cmd_rank)):
        sp = sub.add_parser(name, help=helptext)
        sp.add_argument("--model", required=True, help=_MODEL_HELP)
        sp.add_argument("--drive", required=True, help="drive file (CSV or Parquet)")
        sp.add_argument("--shocks", required=True, help="shock library TOML")
        _add_units(sp, "unit system of the drive file and of the outputs", default=None,
                   default_text=_UNITS_OF_DRIVE)
        sp.add_argument("--oversample", type=int, default=2,
                        help="internal steps per sample of the shock loop (default %(default)s)")
        sp.add_argument("--out", required=True, help="predictions CSV" if name == "predict"
                        else "output folder")
        sp.add_argument("--overwrite", action="store_true", help="replace existing outputs")
        _add_element_options(sp)
        if name == "predict":
            sp.add_argument("--setups", required=True, help="setups CSV")
        else:
            sp.add_argument("--setups", help="setups CSV (default: enumerate from the library)")
            sp.add_argument("--symmetry", choices=["left-right", "all", "none"],
                            default="left-right",
                            help="enumeration: one shock per axle (left-right, default), one "
                            "for every corner (all), or one per corner (none)")
            sp.add_argument("--axles", choices=["independent", "same"], default="independent",
                            help="enumeration: the rear corners' shocks chosen on their own "
                            "(independent, default) or the front corners' (same)")
            sp.add_argument("--fixed", action="append", metavar="CORNER=ID",
                            help="fix a corner's shock (repeatable; default: none fixed)")
            sp.add_argument("--only", help="comma-separated shock ids to consider (default: "
                            "every shock of the library)")
            add_click_arguments(sp)
            sp.add_argument("--baseline", help="baseline: a setup of --setups by name, one "
                            "shock id (all corners) or four LF,RF,LR,RR (default: the first "
                            "setup)")
            sp.add_argument("--objective", help=_OBJECTIVE_HELP)
            sp.add_argument("--simulate", type=_int_at_least(1), default=40, metavar="N",
                            help="the best N setups by screening simulated in the time "
                            "domain (default %(default)s; the baseline and a spread of the "
                            "others are checked besides)")
            _add_try_options(sp)
            sp.add_argument("--no-uncertainty", action="store_true",
                            help="skip the Monte Carlo intervals (default: computed)")
            sp.add_argument("--scheduler", metavar="ADDRESS|local",
                            help="screen on Dask: a scheduler address (tcp://host:8786) or "
                            "'local' for a cluster on this machine (default: this process; "
                            "the same ranking either way)")
            sp.add_argument("--workers", type=int,
                            help="workers of a local cluster (default: cores)")
        sp.set_defaults(func=func)

    opt = sub.add_parser("optimize", help="the best damper curve per corner group, mapped to "
                         "the crate")
    opt.add_argument("--model", required=True, help=_MODEL_HELP)
    opt.add_argument("--drive", required=True, action="append",
                     help="drive file (CSV or Parquet); repeat for several drives")
    opt.add_argument("--shocks", required=True, help="the crate: shock library TOML")
    opt.add_argument("--objective", help=_OBJECTIVE_HELP)
    opt.add_argument("--baseline", help="baseline shock id(s): one for all corners or "
                     "LF,RF,LR,RR (default: the crate's first shock)")
    opt.add_argument("--symmetry", choices=["left-right", "all", "none"], default="left-right",
                     help="a curve per axle (left-right, default), one for every corner (all), "
                          "or one per corner (none)")
    opt.add_argument("--constraints", help="curve constraints TOML (default: buildable race "
                     "shock bounds)")
    opt.add_argument("--drive-weights", help="weights of the drives, comma-separated, one per "
                     "--drive (default: equal)")
    opt.add_argument("--worst-case", action="store_true",
                     help="minimize the worst drive's score instead of the weighted sum "
                     "(default: the weighted sum)")
    opt.add_argument("--robust", action="store_true", help="hold the objective's limits "
                     "with the identified model's 95 %% intervals (default: nominal limits)")
    _add_units(opt, "unit system of the drive files and outputs", default=None,
               default_text=_UNITS_OF_DRIVES)
    opt.add_argument("--oversample", type=int, default=2,
                     help="internal steps per sample (default %(default)s)")
    opt.add_argument("--max-iter", type=int, default=80, help="IPOPT iterations "
                     "(default %(default)s)")
    opt.add_argument("--starts", type=_int_at_least(1), default=2,
                     help="IPOPT starts: the scan's best curve, then the best of the other "
                     "kind (linear or two-slope), 10 iterations (default %(default)s)")
    opt.add_argument("--knots", choices=["quantiles", "fixed"], default="quantiles",
                     help="velocity knots of the curves: on the quantiles 25, 50, 75, 90, 99 %% "
                     "of the baseline's shock speeds on the drives, per side (quantiles, "
                     "default), or fixed at 0.025, 0.05, 0.1, 0.25, 0.5 m/s (fixed)")
    _add_element_options(opt)
    opt.add_argument("--packers", action="append", metavar="GROUP=LO:HI",
                     help="optimize the packers of a corner group too, between LO and HI (the "
                     "drive's units or with a unit: front=0:4mm); needs bump stops (the "
                     "model's, or --bump-stops); repeatable (default: packers as the "
                     "baseline's)")
    opt.add_argument("--click-radius", type=_int_at_least(1), default=2, metavar="K",
                     help="adjustable shocks: the click search moves one adjuster by 1..K "
                     "steps (default %(default)s)")
    opt.add_argument("--out", required=True, help="output folder")
    opt.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    opt.set_defaults(func=cmd_optimize)

    pl = sub.add_parser("plan", help="the next rig runs (optimal experiment design) and the "
                        "rig-day run sheet")
    pl.add_argument("--vehicle", help="before rig day: the known car, a vehicle TOML or "
                    "'paper' (give this or --model)")
    pl.add_argument("--model", help="between runs: the model identified so far (.npz; give "
                    "this and --session, or --vehicle)")
    pl.add_argument("--session", help="the session the model came from (with --model)")
    pl.add_argument("--shocks", required=True, help="the crate: shock library TOML")
    pl.add_argument("--budget-min", type=float, required=True,
                    help="rig time for the plan [min], swaps included")
    pl.add_argument("--criterion", choices=["d", "a", "decision"], default="d",
                    help="D-optimal (d, default), A-optimal (a), or the ranking's decisions "
                    "(decision)")
    pl.add_argument("--objective", help="objective TOML for the decision criterion and the "
                    "predictions (default: the built-in 'grip and platform')")
    pl.add_argument("--drive", action="append", help="the team's drive for the decision "
                    "criterion and the validation runs; repeatable (default: a 120 s "
                    "synthetic track drive of the car)")
    pl.add_argument("--rig-costs", metavar="RIG.toml", help="the rig's time costs (rig TOML, "
                    "docs/formats.md): swap_min, run_overhead_min [min], click_change_s [s] "
                    "(default: 6 min a changed corner, 20 s an adjuster turned, no overhead)")
    pl.add_argument("--baseline", help="the car's setup at the start: one shock id or "
                    "LF,RF,LR,RR (default: the session's baseline, or the crate's first shock)")
    pl.add_argument("--validate", type=int, default=0,
                    help="validation runs of the current best setups on --drive (default "
                    "%(default)s)")
    pl.add_argument("--baseline-every", type=int, default=0,
                    help="repeat the baseline after every this many runs, for drift (default "
                    "%(default)s: never)")
    _add_units(pl, "units of the drive files read and written", default=None,
               default_text=_UNITS_OF_DRIVES + ", SI without --drive")
    pl.add_argument("--out", required=True, help="output folder")
    pl.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    pl.set_defaults(func=cmd_plan)

    wi = sub.add_parser("whatif", help="what-if study: setups under spring, shock, drive and "
                        "vehicle changes; robust ranking")
    wi.add_argument("--model", required=True, help=_MODEL_HELP)
    wi.add_argument("--drive", required=True, action="append",
                    help="drive file (CSV or Parquet); repeat for several drives")
    wi.add_argument("--shocks", required=True, help="the crate: shock library TOML")
    wi.add_argument("--perturb", required=True, help="perturbation TOML "
                    "(format = \"shockplan-whatif/1\")")
    src = wi.add_mutually_exclusive_group(required=True)
    src.add_argument("--setups", help="setups CSV (give this or --ranking)")
    src.add_argument("--ranking", help="a ranking CSV (shockplan rank's ranking.csv): its top "
                     "--top setups (give this or --setups)")
    wi.add_argument("--top", type=int, default=10,
                    help="setups taken from --ranking (default %(default)s)")
    wi.add_argument("--objective", help=_OBJECTIVE_HELP)
    wi.add_argument("--baseline", help="baseline: a setup name, one shock id (all corners) "
                    "or four LF,RF,LR,RR (default: with --ranking the ranking's baseline, "
                    "with --setups the first setup)")
    wi.add_argument("--method", choices=["time", "screening"], default="time",
                    help="time domain (time, default, the reference) or frequency-domain "
                    "screening (screening)")
    wi.add_argument("--rank-tolerance", type=int, default=None,
                    help="places a rank may move before it counts as moved (default 1)")
    wi.add_argument("--fragile-share", type=float, default=None,
                    help="share of conditions with a moved rank that makes it fragile "
                    "(default 0.1)")
    _add_units(wi, "units of the drive files and outputs", default=None,
               default_text=_UNITS_OF_DRIVES)
    wi.add_argument("--oversample", type=int, default=2,
                    help="internal steps per sample (default %(default)s)")
    wi.add_argument("--scheduler", metavar="ADDRESS|local",
                    help="evaluate on Dask: a scheduler address (tcp://host:8786) or 'local' "
                    "for a cluster on this machine (default: this process; the same files "
                    "either way)")
    wi.add_argument("--workers", type=int, help="workers of a local cluster (default: cores)")
    _add_element_options(wi)
    wi.add_argument("--out", required=True, help="output folder")
    wi.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    wi.set_defaults(func=cmd_whatif)

    sw = sub.add_parser("sweep", help="screen a large enumeration of setups on several drives "
                        "and models (on a Dask cluster), simulate and rank the best share")
    sw.add_argument("--model", required=True, action="append",
                    help="identified model (.npz), a vehicle TOML or 'paper' (repeatable)")
    sw.add_argument("--drive", required=True, action="append",
                    help="drive file (CSV or Parquet; repeatable)")
    sw.add_argument("--shocks", required=True, help="the crate: shock library TOML")
    _add_units(sw, "unit system of the drive files and of the outputs", default=None,
               default_text=_UNITS_OF_DRIVES)
    sw.add_argument("--setups", help="setups CSV (default: enumerate from the library)")
    sw.add_argument("--symmetry", choices=["left-right", "all", "none"], default="none",
                    help="enumeration: one shock per axle (left-right), one for every corner "
                    "(all) or one per corner (default %(default)s: every 4-corner combination)")
    sw.add_argument("--axles", choices=["independent", "same"], default="independent",
                    help="enumeration: the rear corners' shocks chosen on their own "
                    "(independent, default) or the front corners' (same)")
    sw.add_argument("--fixed", action="append", metavar="CORNER=ID",
                    help="fix a corner's shock (repeatable; default: none fixed)")
    sw.add_argument("--only", help="comma-separated shock ids to consider (default: every "
                    "shock of the library)")
    add_click_arguments(sw)
    sw.add_argument("--ignore-inventory", action="store_true",
                    help="enumerate setups beyond the crate's counts, ranked infeasible "
                    "(default: only setups the crate can build)")
    sw.add_argument("--baseline", help="baseline: a setup of --setups by name, one shock id "
                    "(all corners) or four LF,RF,LR,RR (default: the first setup)")
    sw.add_argument("--objective", help=_OBJECTIVE_HELP)
    sw.add_argument("--simulate-share", type=_share, default=0.01, metavar="SHARE",
                    help="share of the screened setups simulated in the time domain, the best "
                    "by screening (default %(default)s)")
    sw.add_argument("--simulate", type=_int_at_least(1), metavar="N",
                    help="simulate the best N in the time domain instead of --simulate-share "
                    "(default: --simulate-share)")
    sw.add_argument("--combine", choices=["mean", "worst"], default="mean",
                    help="a setup's score over the cases (default %(default)s)")
    sw.add_argument("--chunk-size", type=int, default=20000,
                    help="setups per screening task (default %(default)s)")
    sw.add_argument("--scheduler", default="local", metavar="ADDRESS|local|none",
                    help="a Dask scheduler address (tcp://host:8786), 'local' for a cluster on "
                    "this machine (default) or 'none' for one process")
    sw.add_argument("--workers", type=int, help="workers of a local cluster (default: cores)")
    sw.add_argument("--oversample", type=int, default=2,
                    help="internal steps per sample of the shock loop (default %(default)s)")
    _add_element_options(sw)
    _add_try_options(sw)
    sw.add_argument("--out", required=True, help="output folder")
    sw.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    sw.set_defaults(func=cmd_sweep)

    imp = sub.add_parser("import", help="append real rig files (RPC III, MDF4, TDMS) to a "
                         "session")
    imp.add_argument("files", nargs="+", help="the rig's files, one run each")
    imp.add_argument("--format", required=True, choices=["rpc3", "mdf", "tdms"],
                     help="the files' format: RPC III (rpc3), MDF4 (mdf) or TDMS (tdms)")
    imp.add_argument("--map", required=True, help="channel-map TOML: canonical channel -> the "
                     "file's channel, units, sign, scale, offset")
    imp.add_argument("--setup", required=True, help="the runs' shocks: LF,RF,LR,RR ids")
    imp.add_argument("--out", required=True, help="session folder (created, or appended to)")
    imp.add_argument("--shocks", help="shock library TOML (needed for a new session; default: "
                     "the session's)")
    imp.add_argument("--role", default="other",
                     choices=["baseline", "swap", "validation", "other"],
                     help="the runs' role in the session (default %(default)s)")
    imp.add_argument("--names", help="run names, comma-separated (default: the file names)")
    _add_units(imp, "units of a new session's run files", default=None,
               default_text="SI for a new session, the session's when appending")
    imp.set_defaults(func=cmd_import)

    exp = sub.add_parser("export-drive", help="write a drive file as the RPC III file a rig "
                         "controller plays")
    exp.add_argument("drive", help="drive file (CSV or Parquet)")
    exp.add_argument("--format", required=True, choices=["rpc3"],
                     help="the file format written: RPC III (rpc3)")
    exp.add_argument("--map", help="the rig's channel map (channel names, units, signs); "
                     "default canonical names in mm, N, N*m")
    _add_units(exp, "units of the drive file", default=None, default_text=_UNITS_OF_DRIVE)
    exp.add_argument("--out", required=True, help="RPC III file to write (.drv, .rsp, .tim)")
    exp.add_argument("--overwrite", action="store_true", help="replace an existing file")
    exp.set_defaults(func=cmd_export_drive)

    veh = sub.add_parser("vehicle", help="vehicle model tools")
    veh_sub = veh.add_subparsers(dest="vehicle_command", required=True,
                                 help="the vehicle command")
    modes = veh_sub.add_parser("modes", help="natural frequencies of a vehicle")
    modes.add_argument("--vehicle", help="vehicle TOML (default: the paper's Table 1 car)")
    modes.add_argument("--damping", type=float, help="linear shock damping of every corner for "
                       "the damped modes [N/(m/s), or lbf/(in/s) with --units imperial] "
                       "(default: the vehicle's own)")
    _add_units(modes, "units of --damping")
    modes.set_defaults(func=cmd_vehicle_modes)

    add_dyno_parser(sub, table=cmd_dyno_table, check=cmd_dyno_check)
    add_drive_parser(sub, cmd_drive)

    _add_flags_anywhere(p)
    return p


def _one_line(exc):
    """The message of `exc` on one line (a bare errno error gets its file named)."""
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc)
    return " ".join(text.split())


def main(argv=None):
    """Entry point of the ``shockplan`` program; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    interrupts.install()  # a Ctrl-C swallowed by C code still stops the command
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except (ValueError, TypeError, FileExistsError, FileNotFoundError) as exc:
        print(f"shockplan: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:  # e.g. a disk that filled up or a folder made read-only meanwhile
        if exc.errno is None:  # raised here with a full message (e.g. a read-only --out)
            print(f"shockplan: error: {_one_line(exc)}", file=sys.stderr)
        else:
            where = f"{exc.filename}: " if exc.filename else ""
            print(f"shockplan: error: {where}{exc.strerror or exc}; check the path and its "
                  "permissions", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # pragma: no cover
        print("shockplan: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
