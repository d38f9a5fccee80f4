"""The ``shockplan drive`` commands: drives from track data (issue 27).

``shockplan drive from-track LOG [LOG ...] --model MODEL --shocks CRATE.toml --setup
LF,RF,LR,RR --out DRIVE.csv`` builds the rig drive that reproduces track logs on a model;
``shockplan drive iterate TARGET --drive DRIVE.csv --session SESSION --run NAME --model MODEL
--shocks CRATE.toml --out NEW.csv`` corrects a drive by what the rig recorded playing it;
``shockplan drive section DRIVE.csv --section NAME=START:STOP --out DIR`` cuts laps and
named windows into drives of their own; ``shockplan drive resample DRIVE.csv --fs HZ --out
NEW.csv`` resamples a drive to another rate (e.g. an MTS playout rate before
``export-drive``).

Each command is a thin call into :mod:`planner.trackdrive` and :mod:`planner.report.
trackdrive`: it reads the files, checks every output path before any computation, runs,
writes atomically, and prints a short summary. The library is imported when a command
runs, so that ``shockplan --help`` stays fast.
"""

from __future__ import annotations

import difflib
from pathlib import Path

from ident.data.files import check_output
from ident.data.units import UNIT_SYSTEMS, set_display_units
from planner.cli.common import (add_command_group, add_histogram_option, add_resample,
                                histogram_options, log, run_subcommand, section_windows,
                                unit_system)

__all__ = ["add_parser", "run", "run_from_track", "run_iterate", "run_section", "run_resample",
           "report_folder", "section_path", "LOG_FORMATS", "SUBCOMMANDS"]

#: The track-log formats ``--format`` names (default: by the file's extension).
LOG_FORMATS = ("csv", "parquet", "mdf", "tdms", "rpc3")


def _common(p, *, logs_help):
    p.add_argument("logs", nargs="+", metavar="LOG", help=logs_help)
    p.add_argument("--model", required=True, metavar="MODEL",
                   help="identified model (.npz), a vehicle TOML (the known physical model) or "
                   "'paper'")
    p.add_argument("--shocks", required=True, metavar="CRATE.toml",
                   help="shock library holding the setup's shocks")
    p.add_argument("--map", metavar="MAP.toml", default=None,
                   help="channel map of the logs' channels to the canonical log channels "
                   "(names, units, signs, offsets; default: none, the logs' columns are "
                   "canonical names: time, shock_travel_XX, ride_height_XX, speed ...)")
    p.add_argument("--format", choices=list(LOG_FORMATS), default=None,
                   help="the logs' format (default: by each file's extension)")
    p.add_argument("--units", type=unit_system, choices=list(UNIT_SYSTEMS), default=None,
                   help="unit system of canonical-name CSV/Parquet logs and of the outputs: SI "
                   "or imperial, in any case (default: the first log's 'units' column, "
                   "else SI)")
    add_resample(p, "every track log (logs of different rates)")
    p.add_argument("--rig", metavar="RIG.toml", default=None,
                   help="rig TOML whose [limits] the drive respects (wheelloader displacement, "
                   "velocity, acceleration; aero loads) (default: no limits)")
    p.add_argument("--limit-action", choices=["clip", "scale"], default="clip",
                   help="where the drive exceeds the rig's limits: clip it there (smoothly, "
                   "with a warning) or scale the whole drive down (default: %(default)s)")
    p.add_argument("--regularization", type=float, default=0.03, metavar="ALPHA",
                   help="relative regularization of the inverse: directions the rig moves the "
                   "targets less than ALPHA times its best one are not inverted "
                   "(default: %(default)s)")
    p.add_argument("--band", metavar="LOW,HIGH", default=None,
                   help="band the drive reproduces [Hz]; iterate: the one from-track used "
                   "(default: 0.5 to 30 Hz, the top lowered to the sample rate / 2.5)")
    p.add_argument("--taper", type=float, default=1.0, metavar="S",
                   help="fade-in and fade-out of each log [s]; iterate: the one from-track "
                   "used (default: %(default)s)")
    p.add_argument("--report", metavar="DIR", default=None,
                   help="folder of the report: residuals, reach, PSD overlays, convergence, "
                   "the target (default: DRIVE_report/ beside the drive)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing drive and report (default: refuse)")


def _add_from_track(sub):
    p = sub.add_parser("from-track", help="the rig drive that reproduces track logs on a model "
                       "(drive iteration through the nonlinear shocks)")
    _common(p, logs_help="track logs (CSV, Parquet, MDF4, TDMS or RPC III), played one after "
            "the other")
    p.add_argument("--setup", required=True, metavar="LF,RF,LR,RR",
                   help="the shocks the car ran at the track: one id (every corner) or four "
                   "(setting names such as TTX@ls=6,hs=2 too)")
    p.add_argument("--aero", metavar="AERO.toml", default=None,
                   help="the team's downforce and balance model (aero loads from the logged "
                   "speed) (default: none)")
    p.add_argument("--aero-source", choices=["auto", "model", "logged", "none"], default="auto",
                   help="the drive's aero loads: the aero model, the logs' aero_heave/roll/"
                   "pitch channels, or none (a 4-post rig); auto takes the model if given, "
                   "else logged loads if every log has them (default: %(default)s)")
    p.add_argument("--targets", metavar="KIND,...", default=None,
                   help="the channels to reproduce, kinds (shock_travel, ride_height, "
                   "wheel_accel, chassis_accel) or channels (default: every logged one the "
                   "model has)")
    p.add_argument("--max-iter", type=int, default=20, metavar="N",
                   help="most time-domain iterations after the plain inverse (default: "
                   "%(default)s)")
    p.add_argument("--tol", type=float, default=0.01,
                   help="stop when an iteration lowers the residual by less than this share "
                   "of itself, twice (default: %(default)s)")
    p.add_argument("--section", action="append", metavar="NAME=START:STOP", default=None,
                   help="also write this time window [s] as a drive of its own, "
                   "DRIVE_NAME.csv (repeatable; default: none)")
    p.add_argument("--laps", metavar="T0,T1,...", default=None,
                   help="lap-start times [s]: also write each lap as DRIVE_lapN.csv "
                   "(default: none)")
    p.add_argument("--out", required=True, metavar="DRIVE.csv", help="the drive file to write")
    add_histogram_option(p)
    p.set_defaults(func=run)
    return p


def _add_iterate(sub):
    p = sub.add_parser("iterate", help="correct a drive by the response the rig recorded "
                       "playing it (one rig iteration)")
    _common(p, logs_help="the target: the report's target.csv of 'drive from-track', or "
            "the track logs")
    p.add_argument("--drive", required=True, metavar="DRIVE.csv",
                   help="the drive the rig played")
    p.add_argument("--session", required=True, metavar="SESSION_DIR",
                   help="the rig session holding the run recorded while playing it")
    p.add_argument("--run", required=True, metavar="NAME", help="that run's name")
    p.add_argument("--setup", metavar="LF,RF,LR,RR", default=None,
                   help="the shocks on the car during the run (default: the run's setup)")
    p.add_argument("--gain", type=float, default=0.7,
                   help="step of the correction, 0 to 2 (default: %(default)s)")
    p.add_argument("--out", required=True, metavar="NEW.csv", help="the corrected drive to write")
    p.set_defaults(func=run)
    return p


def _add_section(sub):
    p = sub.add_parser("section", help="laps or named time windows of a drive as drives of "
                       "their own")
    p.add_argument("drive", metavar="DRIVE.csv", help="the drive")
    p.add_argument("--section", action="append", metavar="NAME=START:STOP", default=None,
                   help="a time window [s] (repeatable; default: none, give --laps)")
    p.add_argument("--laps", metavar="T0,T1,...", default=None,
                   help="lap-start times [s]: one drive per lap (default: none)")
    p.add_argument("--units", type=unit_system, choices=list(UNIT_SYSTEMS), default=None,
                   help="unit system of the drive and the sections: SI or imperial (default: "
                   "the drive file's 'units' column, else SI)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder of the section drives (DRIVE_NAME.csv each)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace existing section files (default: refuse)")
    p.set_defaults(func=run)
    return p


def _add_resample(sub):
    p = sub.add_parser("resample", help="a drive at another sample rate (band-limited), e.g. "
                       "an MTS playout rate for export-drive")
    p.add_argument("drive", metavar="DRIVE.csv", help="the drive (CSV or Parquet)")
    p.add_argument("--fs", required=True, type=float, metavar="HZ",
                   help="the new sample rate [Hz]; its ratio to the drive's must be a "
                   "fraction up/down with down <= 1000 (e.g. 200 -> 512 Hz)")
    p.add_argument("--units", type=unit_system, choices=list(UNIT_SYSTEMS), default=None,
                   help="unit system of the drive and the resampled drive: SI or imperial "
                   "(default: the drive file's 'units' column, else SI)")
    p.add_argument("--out", required=True, metavar="NEW.csv",
                   help="the resampled drive to write (.csv or .parquet)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing file (default: refuse)")
    p.set_defaults(func=run)
    return p


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


def _band(text):
    from planner.errors import PlannerError

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
    from ident.data.tracklog import read_track_log

    logs = [read_track_log(p, channel_map=args.map, units=args.units, format=args.format,
                           resample_hz=args.resample)
            for p in args.logs]
    if args.units is None:
        args.units = logs[0].settings.get("units") or "SI"
    set_display_units(args.units)  # the run's messages, report and plots in them
    return logs


def _model_rate(model):
    return getattr(model, "fs_hz", None)


def _limits(args):
    from planner.rig_spec import read_rig

    if args.rig is None:
        return None
    rig = read_rig(args.rig)
    if rig.limits is None:
        log.warning("--rig %s has no [limits] table: the drive is not limited", args.rig)
    return rig.limits


def _setup(text, library, where="--setup", name="track"):
    from planner.setups import resolve_baseline

    return resolve_baseline(text, library, name=name, where=where)


def _print_result(result, units):
    import numpy as np

    from ident.data.channels import CORNERS, quantity_of
    from ident.data.units import format_quantity

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
        print("aero loads: their mean is the aeroloaders' static preload, set before the drive "
              "plays (the drive holds the rest): heave "
              f"{format_quantity(mean['aero_heave'], 'force', units, digits=4)}, pitch "
              f"{format_quantity(mean['aero_pitch'], 'moment', units, digits=4)}, roll "
              f"{format_quantity(mean['aero_roll'], 'moment', units, digits=4)}")
    reach = result.reach["unreachable_share"]
    rows = []
    for c in per.index:
        q = quantity_of(c)
        rms = h[(h["iteration"] == result.settings["best_iteration"]) &
                (h["channel"] == c)]["residual_rms"].iloc[0]
        rows.append(f"  {c:<20} residual {100 * per[c]:6.2f} %  "
                    f"({format_quantity(rms, q, units, small=True)} RMS), "
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


def run_from_track(args):
    """``shockplan drive from-track``: track logs -> the rig drive that reproduces them."""
    from ident.data.drive import write_drive
    from ident.models.aero import read_aero_model
    from ident.models.library import read_shock_library
    from planner.predict import as_loop_plant, load_any_model
    from planner.report.trackdrive import write_drive_report
    from planner.trackdrive import build_track_drive, check_sections, cut_sections, make_target

    where = "drive from-track"
    out, report = _outputs(args)
    sections = section_windows(args, where)
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
    hist = _track_histograms(args, model, result, logs, setup, library)
    write_drive(result.drive, out, units=units, overwrite=args.overwrite)
    write_drive_report(result, report, units=units, overwrite=args.overwrite, histograms=hist)
    _print_result(result, units)
    if hist is not None:
        print(_histogram_line(hist, units))
    written = [str(out), f"{report}/"]
    for d, (name, _, _) in zip(section_drives, sections):
        path = section_path(out, name)
        write_drive(d, path, units=units, overwrite=args.overwrite)
        written.append(str(path))
    print(f"wrote {', '.join(written)} ({units})")
    return 0


def _track_histograms(args, model, result, logs, setup, library):
    """The logged shock-velocity histogram per corner beside the one the drive reproduces on
    the model with the track setup (:mod:`planner.histograms`): a ShockHistograms of the
    rows ``logged`` and ``reproduced``, or None (``--histogram-bins none``)."""
    from planner.histograms import ShockHistograms, logged_histograms
    from planner.options import LoopOptions
    from planner.predict import predict_setups
    from planner.setups import Setup

    opts = histogram_options(args)
    if opts is None:
        return None
    logged = logged_histograms(logs, opts, name="logged")
    track = Setup("reproduced", dict(setup.shocks), bump_stops=setup.bump_stops,
                  packers_m=setup.packers_m)
    again = predict_setups(model, result.drive, [track], library,
                           loop=LoopOptions(histograms=opts), check_coverage=False)
    return ShockHistograms.concat([logged, again.histograms])


def _histogram_line(hist, units):
    """The terminal's line of the logged and reproduced histograms."""
    from ident.data.channels import CORNERS
    from planner.histograms import histogram_distance

    d = histogram_distance(hist.select(["reproduced"]), hist.select(["logged"])).iloc[0]
    low = hist.low_speed_share
    return ("shock-velocity histograms, logged vs reproduced on the model (histograms.csv in "
            "the report): total-variation distance "
            + ", ".join(f"{c} {d[f'histogram_distance_{c}']:.3f}" for c in CORNERS)
            + "; share below the knee "
            + ", ".join(f"{c} {low[0, j]:.2f}/{low[1, j]:.2f}" for j, c in enumerate(CORNERS)))


def _run_of(session, name, where):
    from planner.errors import PlannerError

    names = [r.name for r in session.runs]
    if name not in names:
        close = difflib.get_close_matches(name, names, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise PlannerError(f"{where}: --run {name!r}{hint} is not a run of session "
                           f"'{session.name}'; its runs are {', '.join(names)}")
    return session.runs[names.index(name)]


def run_iterate(args):
    """``shockplan drive iterate``: a drive corrected by the response the rig recorded."""
    import numpy as np

    from ident.data.channels import CORNERS
    from ident.data.drive import read_drive, write_drive
    from ident.data.session import read_session
    from ident.models.library import read_shock_library
    from planner.predict import as_loop_plant, load_any_model
    from planner.report.trackdrive import write_drive_report
    from planner.setups import Setup
    from planner.trackdrive import make_target, update_drive

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


def run_section(args):
    """``shockplan drive section``: laps and named windows of a drive as drive files."""
    from ident.data.drive import read_drive, write_drive
    from planner.errors import PlannerError
    from planner.trackdrive import cut_sections

    where = "drive section"
    sections = section_windows(args, where)
    if not sections:
        raise PlannerError(f"{where}: give --section NAME=START:STOP or --laps T0,T1,...")
    drive = read_drive(args.drive, units=args.units)
    units = args.units or drive.settings.get("units", "SI")
    set_display_units(units)
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


def run_resample(args):
    """``shockplan drive resample``: a drive at another sample rate
    (:func:`ident.data.drive.resample_drive`), written in the drive file's units."""
    from ident.data.drive import read_drive, resample_drive, write_drive

    out = Path(args.out)
    check_output(out, overwrite=args.overwrite)
    drive = read_drive(args.drive, units=args.units)
    units = args.units or drive.settings.get("units", "SI")
    set_display_units(units)
    new = resample_drive(drive, args.fs)
    write_drive(new, out, units=units, overwrite=args.overwrite)
    s = new.settings
    how = ("a copy: the rates are equal" if s["resample_up"] == s["resample_down"] else
           f"x {s['resample_up']}/{s['resample_down']}, band-limited"
           + (f": content above {0.5 * new.fs_hz:g} Hz removed" if new.fs_hz < drive.fs_hz
              else ""))
    print(f"resampled drive '{drive.name}' from {drive.fs_hz:g} Hz to {new.fs_hz:g} Hz ({how}); "
          f"{new.duration_s:g} s, {new.n_samples} samples")
    print(f"wrote {out} ({units})")
    return 0


#: The ``drive`` sub-commands: name -> (function adding its parser, function running it).
SUBCOMMANDS = {"from-track": (_add_from_track, run_from_track),
               "iterate": (_add_iterate, run_iterate), "section": (_add_section, run_section),
               "resample": (_add_resample, run_resample)}


def add_parser(subparsers):
    """Add the ``drive`` command and its sub-commands to `subparsers`.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The top-level parser's commands.

    Returns
    -------
    argparse.ArgumentParser
    """
    return add_command_group(subparsers, "drive", SUBCOMMANDS,
                             help="rig drives from track data: build, iterate on the rig, cut "
                             "sections, resample", dest="drive_command",
                             dest_help="the drive command")


def run(args):
    """Run the ``drive`` sub-command `args` names; returns the exit status."""
    return run_subcommand(SUBCOMMANDS, args, "drive_command")
