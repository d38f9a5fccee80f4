"""The ``shockplan drive`` commands: from-track, iterate, section (issue 27).

Each command is a thin call into :mod:`planner.trackdrive` and :mod:`planner.report.
trackdrive`: it reads the files, checks every output path before any computation, runs,
writes atomically, and prints a short summary. The parsers are in :mod:`planner.drive_args`.
"""

from __future__ import annotations

import difflib
import logging
from pathlib import Path

import numpy as np

from ident.data.channels import CORNERS, quantity_of
from ident.data.drive import read_drive, write_drive
from ident.data.files import check_output
from ident.data.session import read_session
from ident.data.tracklog import read_track_log
from ident.data.units import UNIT_LABELS, from_si
from ident.models.aero import read_aero_model
from ident.models.library import read_shock_library
from planner.errors import PlannerError
from planner.plant import as_loop_plant
from planner.predict import load_any_model
from planner.report.trackdrive import write_drive_report
from planner.rig_spec import read_rig
from planner.setups import Setup, resolve_baseline
from planner.trackdrive import (build_track_drive, check_sections, cut_sections, lap_sections,
                                make_target, parse_sections, update_drive)

__all__ = ["run_drive_command", "cmd_from_track", "cmd_iterate", "cmd_section",
           "report_folder", "section_path"]

log = logging.getLogger("shockplan")


def report_folder(args):
    """The report folder: ``--report``, else ``<drive stem>_report`` beside the drive."""
    if args.report:
        return Path(args.report)
    out = Path(args.out)
    return out.with_name(f"{out.stem}_report")


def section_path(out, name):
    """The file of section `name` of drive file `out`: ``<stem>_<name><suffix>``."""
    out = Path(out)
    return out.with_name(f"{out.stem}_{name}{out.suffix or '.csv'}")


def _sections(args, where):
    sections = parse_sections(args.section, where="--section")
    if args.laps:
        laps = lap_sections(str(args.laps).split(","), where="--laps")
        clash = {n for n, _, _ in laps} & {n for n, _, _ in sections}
        if clash:
            raise PlannerError(f"{where}: --section names {sorted(clash)} clash with the laps' "
                               "names; rename them")
        sections += laps
    return sections


def _band(text):
    if text is None:
        return None
    parts = str(text).split(",")
    try:
        band = tuple(float(p) for p in parts)
    except ValueError:
        band = ()
    if len(band) != 2:
        raise PlannerError(f"--band {text!r}: write LOW,HIGH in Hz, e.g. 0.5,30")
    return band


def _targets(text):
    return None if text is None else [t.strip() for t in str(text).split(",") if t.strip()]


def _read_logs(args):
    logs = [read_track_log(p, channel_map=args.map, units=args.units, format=args.format)
            for p in args.logs]
    if args.units is None:
        args.units = logs[0].settings.get("units") or "SI"
    return logs


def _model_rate(model):
    return getattr(model, "fs_hz", None)


def _limits(args):
    if args.rig is None:
        return None
    rig = read_rig(args.rig)
    if rig.limits is None:
        log.warning("--rig %s has no [limits] table: the drive is not limited", args.rig)
    return rig.limits


def _setup(text, library, where="--setup", name="track"):
    return resolve_baseline(text, library, name=name, where=where)


def _print_result(result, units):
    t = result.target
    h = result.history
    per = result.residual_share
    iters = int(h["iteration"].max())
    print(f"drive '{result.drive.name}': {result.drive.duration_s:g} s at "
          f"{result.drive.fs_hz:g} Hz, band {t.band_hz[0]:g}-{t.band_hz[1]:g} Hz, setup "
          + ",".join(result.settings["setup"][c] for c in CORNERS))
    if result.settings.get("stopped") != "rig iteration":
        first = h[(h["iteration"] == 1) & (h["channel"] == "all")]["residual_share"].iloc[0]
        best = h[(h["iteration"] == result.settings["best_iteration"]) &
                 (h["channel"] == "all")]["residual_share"].iloc[0]
        print(f"residual (RMS over target RMS, 1-20 Hz): plain inverse {100 * first:.2f} %, "
              f"after {iters} iteration(s) {100 * best:.2f} % (best: iteration "
              f"{result.settings['best_iteration']}, {result.settings['stopped']})")
    preload = t.settings.get("aero_preload") or []
    if preload:
        mean = {k: float(np.mean([p[k] for p in preload])) for k in preload[0]}
        lab = UNIT_LABELS[units]
        print("aero loads: their mean is the aeroloaders' static preload, set before the drive "
              f"plays (the drive holds the rest): heave "
              f"{float(from_si(mean['aero_heave'], 'force', units)):.5g} {lab['force']}, pitch "
              f"{float(from_si(mean['aero_pitch'], 'moment', units)):.5g} {lab['moment']}, roll "
              f"{float(from_si(mean['aero_roll'], 'moment', units)):.5g} {lab['moment']}")
    reach = result.reach["unreachable_share"]
    rows = []
    for c in per.index:
        q = quantity_of(c)
        rms = h[(h["iteration"] == result.settings["best_iteration"]) &
                (h["channel"] == c)]["residual_rms"].iloc[0]
        rows.append(f"  {c:<20} residual {100 * per[c]:6.2f} %  "
                    f"({float(from_si(rms, q, units)):.4g} {UNIT_LABELS[units][q]} RMS), "
                    f"out of reach {100 * reach[c]:5.2f} %")
    print("\n".join(rows))
    lim = result.limits
    if lim is not None and len(lim.report):
        hit = lim.report[lim.report["exceeded"]]
        if len(hit):
            print(f"  rig limits: {len(hit)} channel limit(s) exceeded and "
                  f"{'scaled' if lim.action == 'scale' else 'clipped'} "
                  f"({', '.join(f'{c} {q}' for c, q in zip(hit['channel'], hit['quantity']))});"
                  " see the report's limits.csv")


def _outputs(args):
    """The drive file and the report folder, checked before any work."""
    out, report = Path(args.out), report_folder(args)
    check_output(out, overwrite=args.overwrite)
    check_output(report, overwrite=args.overwrite, folder=True, what="the report folder")
    return out, report


def cmd_from_track(args):
    """``shockplan drive from-track``: track logs -> the rig drive that reproduces them."""
    where = "drive from-track"
    out, report = _outputs(args)
    sections = _sections(args, where)
    for name, _, _ in sections:
        check_output(section_path(out, name), overwrite=args.overwrite,
                     what=f"section {name!r}'s drive")
    band = _band(args.band)
    model = load_any_model(args.model)
    library = read_shock_library(args.shocks)
    setup = _setup(args.setup, library)
    logs = _read_logs(args)
    aero = None if args.aero is None else read_aero_model(args.aero)
    limits = _limits(args)
    plant = as_loop_plant(model)
    target = make_target(logs, model_outputs=plant.output_names, rig_inputs=plant.rig_inputs,
                         fs_hz=_model_rate(model), band_hz=band, aero=aero,
                         aero_source=args.aero_source, targets=_targets(args.targets),
                         taper_s=args.taper, name=out.stem, where=where)
    check_sections(sections, n_samples=target.n_samples, fs_hz=target.fs_hz,
                   of=f"the logs ({len(logs)} of them)" if len(logs) > 1 else "the log",
                   where=where)
    result = build_track_drive(model, target, setup, library, alpha=args.regularization,
                               max_iter=args.max_iter, tol=args.tol, limits=limits,
                               limit_action=args.limit_action, name=out.stem, where=where)
    units = args.units
    section_drives = cut_sections(result.drive, sections, where=where)
    write_drive(result.drive, out, units=units, overwrite=args.overwrite)
    write_drive_report(result, report, units=units, overwrite=args.overwrite)
    _print_result(result, units)
    written = [str(out), f"{report}/"]
    for d, (name, _, _) in zip(section_drives, sections):
        path = section_path(out, name)
        write_drive(d, path, units=units, overwrite=args.overwrite)
        written.append(str(path))
    print(f"wrote {', '.join(written)} ({units})")
    return 0


def _run_of(session, name, where):
    names = [r.name for r in session.runs]
    if name not in names:
        close = difflib.get_close_matches(name, names, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise PlannerError(f"{where}: --run {name!r}{hint} is not a run of session "
                           f"'{session.name}'; its runs are {', '.join(names)}")
    return session.runs[names.index(name)]


def cmd_iterate(args):
    """``shockplan drive iterate``: a drive corrected by the response the rig recorded."""
    where = "drive iterate"
    out, report = _outputs(args)
    model = load_any_model(args.model)
    library = read_shock_library(args.shocks)
    logs = _read_logs(args)
    drive = read_drive(args.drive, units=args.units)
    session = read_session(args.session)
    run = _run_of(session, args.run, where)
    if args.setup is None:
        setup = Setup("run", {c: run.setup[c] for c in CORNERS})
        setup.resolve(library)  # an id the crate lacks: named now
    else:
        setup = _setup(args.setup, library, name="run")
    limits = _limits(args)
    plant = as_loop_plant(model)
    target = make_target(logs, model_outputs=plant.output_names, rig_inputs=plant.rig_inputs,
                         fs_hz=drive.fs_hz, band_hz=_band(args.band), aero_source="none",
                         taper_s=args.taper, name=out.stem, where=where)
    result = update_drive(model, drive, target, run, setup, library, gain=args.gain,
                          alpha=args.regularization, limits=limits,
                          limit_action=args.limit_action, where=where)
    units = args.units
    write_drive(result.drive, out, units=units, overwrite=args.overwrite)
    write_drive_report(result, report, units=units, overwrite=args.overwrite)
    share = result.residual_share
    print(f"run '{run.name}' against the target (RMS over target RMS, 1-20 Hz): "
          f"{100 * float(np.sqrt(np.mean(np.square(share)))):.2f} % over {len(share)} "
          "channels; the drive corrected with gain " f"{args.gain:g}")
    _print_result(result, units)
    print(f"wrote {out}, {report}/ ({units})")
    return 0


def cmd_section(args):
    """``shockplan drive section``: laps and named windows of a drive as drive files."""
    where = "drive section"
    sections = _sections(args, where)
    if not sections:
        raise PlannerError(f"{where}: give --section NAME=START:STOP or --laps T0,T1,...")
    drive = read_drive(args.drive, units=args.units)
    units = args.units or drive.settings.get("units", "SI")
    folder = Path(args.out)
    base = folder / f"{Path(args.drive).stem}.csv"     # sections are CSV drives
    paths = [section_path(base, name) for name, _, _ in sections]
    for p in paths:
        check_output(p, overwrite=args.overwrite)
    for d, p in zip(cut_sections(drive, sections, where=where), paths):
        write_drive(d, p, units=units, overwrite=args.overwrite)
    print(f"wrote {len(paths)} section drive(s) of '{drive.name}' to {folder}/: "
          + ", ".join(p.name for p in paths) + f" ({units})")
    return 0


#: The sub-commands by name.
_COMMANDS = {"from-track": cmd_from_track, "iterate": cmd_iterate, "section": cmd_section}


def run_drive_command(args):
    """Run the ``drive`` sub-command `args` names; returns the exit status."""
    return _COMMANDS[args.drive_command](args)
