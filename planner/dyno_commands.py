"""``shockplan dyno table`` and ``shockplan dyno check``: the commands (a thin layer).

Each command is a call into :mod:`planner.dyno.check` (compute) and
:mod:`planner.report.dyno` (files); this module prints the summaries, as the command
line does. Its options are in :mod:`planner.dyno_args` (light, for the parser built on
every start); :func:`add_table_parser` and :func:`add_check_parser` here add them with
these commands, for callers that do not mind importing the commands.
"""

from __future__ import annotations

import logging

from ident.data.files import check_output
from ident.data.units import UNIT_LABELS
from ident.models import adjustable
from ident.models.library import read_shock_library
from ident.models.shocks import format_number
from planner import dyno_args
from planner.dyno.check import check_dyno_library, dyno_curve, library_units
from planner.report.dyno import write_dyno_check, write_dyno_curve

__all__ = ["cmd_dyno_table", "cmd_dyno_check", "add_table_parser", "add_check_parser"]


class _DropWarnings(logging.Filter):
    """Drops warnings (the check prints each finding itself)."""

    def filter(self, record):
        return record.levelno != logging.WARNING


def cmd_dyno_table(args):
    """``shockplan dyno table``: a library shock's curve at a setting, as a CSV.

    Parameters
    ----------
    args : argparse.Namespace
        ``library``, ``shock``, ``velocity`` (list of float or None), ``units`` (None:
        the library's), ``out``, ``overwrite``.

    Returns
    -------
    int
        0.
    """
    check_output(args.out, overwrite=args.overwrite)
    units = args.units or library_units(args.library)
    library = read_shock_library(args.library)
    curve = dyno_curve(library, args.shock, velocities=args.velocity, units=units)
    path = write_dyno_curve(curve, args.out, overwrite=args.overwrite)
    v_unit = UNIT_LABELS[units]["velocity"]
    v = curve.velocity
    print(f"{curve.shock}: {v.size} velocit{'y' if v.size == 1 else 'ies'} from {format_number(v[0])} to "
          f"{format_number(v[-1])} {v_unit} ({curve.grid}); wrote {path} ({units})")
    ext = curve.extrapolated
    if ext.any():
        reb, bump = curve.measured_m_s
        print(f"note: {int(ext.sum())} velocit{'y is' if ext.sum() == 1 else 'ies are'} "
              f"beyond the dyno's measured speeds (rebound {format_number(reb)}, bump "
              f"{format_number(bump)} m/s): the curve there is extrapolated with its end "
              "slopes")
    return 0


def cmd_dyno_check(args):
    """``shockplan dyno check``: every adjustable shock against its dyno sheets.

    Parameters
    ----------
    args : argparse.Namespace
        ``library``, ``out``, ``units`` (None: the library's), ``overwrite``.

    Returns
    -------
    int
        0 without errors, 1 when any error is found (the files are written either way).
    """
    check_output(args.out, overwrite=args.overwrite, folder=True)
    # the click model logs its sheets' warnings when built; they are printed below
    quiet = logging.getLogger(adjustable.__name__)
    drop = _DropWarnings()
    quiet.addFilter(drop)
    try:
        check = check_dyno_library(args.library)
    finally:
        quiet.removeFilter(drop)
    units = args.units or check.units
    files = write_dyno_check(check, args.out, units=units, overwrite=args.overwrite)
    for s in check.shocks:
        if s.worst is not None and not s.worst.empty:
            k = s.worst["worst_error_pct"].abs().idxmax()
            w = s.worst.loc[k]
            state = (f"model worst error {w['worst_error_pct']:+.2f} % at {w['setting']} "
                     f"({w['row']})")
        else:
            state = "no model"
        print(f"{s.id}: {len(s.curves)} measured setting(s), {state}; {len(s.errors)} "
              f"error(s), {len(s.warnings)} warning(s)")
        for f in s.findings:
            print(f"  {f.severity}: {f.message}")
    if check.library_error:
        print(f"the library cannot be read: {check.library_error}")
    if not check.shocks:
        print(f"{args.library}: no adjustable shocks to check")
    print(f"{check.n_errors} error(s), {check.n_warnings} warning(s); wrote {len(files)} "
          f"file(s) to {args.out} ({units}): {files['summary']}")
    return 0 if check.ok else 1


def add_table_parser(subparsers):
    """Add ``table`` with :func:`cmd_dyno_table` (:func:`planner.dyno_args.add_table_parser`)."""
    return dyno_args.add_table_parser(subparsers, cmd_dyno_table)


def add_check_parser(subparsers):
    """Add ``check`` with :func:`cmd_dyno_check` (:func:`planner.dyno_args.add_check_parser`)."""
    return dyno_args.add_check_parser(subparsers, cmd_dyno_check)
