"""The parsers of ``shockplan drive``: drives from track data (issue 27).

``shockplan drive from-track LOG [LOG ...] --model MODEL --shocks CRATE.toml --setup
LF,RF,LR,RR --out DRIVE.csv`` builds the rig drive that reproduces track logs on a model;
``shockplan drive iterate TARGET --drive DRIVE.csv --session SESSION --run NAME --model MODEL
--shocks CRATE.toml --out NEW.csv`` corrects a drive by what the rig recorded playing it;
``shockplan drive section DRIVE.csv --section NAME=START:STOP --out DIR`` cuts laps and
named windows into drives of their own.

This module only builds the parsers (light imports, so that ``shockplan --help`` stays
fast); the commands run in :mod:`planner.drive_commands`, reached through the function
:func:`add_parser` is given.
"""

from __future__ import annotations

from ident.data.units import UNIT_SYSTEMS
from planner.dyno_args import unit_system

__all__ = ["add_parser", "LOG_FORMATS"]

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
                   "or imperial, in any case (default: the first log's '# units:' line, "
                   "else SI)")
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


def _add_from_track(sub, func):
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
    p.set_defaults(func=func)
    return p


def _add_iterate(sub, func):
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
    p.set_defaults(func=func)
    return p


def _add_section(sub, func):
    p = sub.add_parser("section", help="laps or named time windows of a drive as drives of "
                       "their own")
    p.add_argument("drive", metavar="DRIVE.csv", help="the drive")
    p.add_argument("--section", action="append", metavar="NAME=START:STOP", default=None,
                   help="a time window [s] (repeatable; default: none, give --laps)")
    p.add_argument("--laps", metavar="T0,T1,...", default=None,
                   help="lap-start times [s]: one drive per lap (default: none)")
    p.add_argument("--units", type=unit_system, choices=list(UNIT_SYSTEMS), default=None,
                   help="unit system of the drive and the sections: SI or imperial (default: "
                   "the drive file's '# units:' line, else SI)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder of the section drives (DRIVE_NAME.csv each)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace existing section files (default: refuse)")
    p.set_defaults(func=func)
    return p


def add_parser(subparsers, func):
    """Add the ``drive`` command and its sub-commands to `subparsers`.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The top-level parser's commands.
    func : callable
        Run with the parsed arguments for every ``drive`` sub-command (the command line
        passes a wrapper that imports :mod:`planner.drive_commands` when run).

    Returns
    -------
    argparse.ArgumentParser
    """
    drive = subparsers.add_parser("drive", help="rig drives from track data: build, iterate "
                                  "on the rig, cut sections")
    sub = drive.add_subparsers(dest="drive_command", required=True, help="the drive command")
    _add_from_track(sub, func)
    _add_iterate(sub, func)
    _add_section(sub, func)
    return drive
