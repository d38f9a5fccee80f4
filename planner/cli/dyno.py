"""The ``shockplan dyno`` commands: raw dyno runs to sheets, curves at a setting, checks.

``shockplan dyno import RAW.csv [RAW.csv ...] --map MAP.toml --settings ls=6,hs=2 --out
SHEET.csv [--append] [--units SI|imperial]`` turns raw dyno time series into dyno-sheet
rows (:func:`ident.dyno.raw.import_dyno_runs`,
:func:`ident.dyno.raw.write_dyno_sheet`) and prints a short report per file
(:meth:`ident.dyno.raw.DynoImport.report`); ``dyno table`` writes a library shock's
curve at a setting (:func:`planner.dyno.check.dyno_curve`); ``dyno check`` checks every
adjustable shock of a library against its dyno sheets
(:func:`planner.dyno.check.check_dyno_library`, :mod:`planner.report.dyno`).

Each sub-command is one entry of :data:`SUBCOMMANDS` (name -> the function that adds its
parser and the one that runs it); :func:`run` runs the one the arguments name.
"""

from __future__ import annotations

import argparse
import logging

from ident.data.files import check_output
from ident.data.units import UNIT_LABELS, UNIT_SYSTEMS, from_si, set_display_units
from planner.cli.common import add_command_group, add_resample, run_subcommand, unit_system

__all__ = ["add_parser", "run", "run_import", "run_table", "run_check", "parse_velocities",
           "SUBCOMMANDS"]


def parse_velocities(text):
    """``--velocity V,V,...`` as a list of floats (argparse type).

    Raises
    ------
    argparse.ArgumentTypeError
        On an empty list or an item that is not a finite number.

    Examples
    --------
    >>> parse_velocities("-0.5, 0.1,0.25")
    [-0.5, 0.1, 0.25]
    """
    items = [x.strip() for x in str(text).split(",")]
    if not any(items):
        raise argparse.ArgumentTypeError("give velocities as V,V,... e.g. "
                                         "--velocity=-0.5,-0.1,0.1,0.5")
    out = []
    for x in items:
        try:
            v = float(x)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{x!r} is not a number; give velocities as "
                                             "V,V,... e.g. --velocity=-0.5,-0.1,0.1,0.5"
                                             ) from None
        if v != v or v in (float("inf"), float("-inf")):
            raise argparse.ArgumentTypeError(f"{x!r} is not a finite velocity")
        out.append(v)
    return out


class _DropWarnings(logging.Filter):
    """Drops warnings (the check prints each finding itself)."""

    def filter(self, record):
        return record.levelno != logging.WARNING


def run_import(args):
    """``shockplan dyno import``: raw dyno files -> dyno-sheet rows."""
    from ident.dyno.raw import import_dyno_runs, parse_settings, write_dyno_sheet
    from ident.data.files import read_units_marker
    from ident.errors import DynoError

    settings = parse_settings(args.settings or "")
    if args.append and args.overwrite:
        raise DynoError("--append and --overwrite: give one (append keeps the sheet's rows, "
                        "overwrite replaces them)")
    if not args.append:
        check_output(args.out, overwrite=args.overwrite)
    units = args.units
    if args.append and units is None:
        try:
            units = read_units_marker(args.out, error=DynoError)
        except DynoError:
            units = None  # a missing sheet: created; write_dyno_sheet names other problems
    units = units or "SI"
    set_display_units(units)
    result = import_dyno_runs(args.raw, settings=settings, dyno_map=args.map,
                              resample_hz=args.resample)
    warnings = write_dyno_sheet(result, args.out, units=units, append=args.append,
                                overwrite=args.overwrite)
    print(result.report(units=units))
    for w in warnings:
        print(f"  warning: {w}")
    n_rows = sum(2 * len(r.blocks) for r in result.runs)
    print(f"{'appended' if args.append else 'wrote'} {n_rows} rows to {args.out} ({units})")
    return 0


def run_table(args):
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
    from ident.models.library import read_shock_library
    from ident.models.shocks import format_number
    from planner.dyno.check import dyno_curve, library_units
    from planner.report.dyno import write_dyno_curve

    check_output(args.out, overwrite=args.overwrite)
    units = args.units or library_units(args.library)
    set_display_units(units)
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
              f"beyond the dyno's measured speeds (rebound "
              f"{format_number(from_si(reb, 'velocity', units))}, bump "
              f"{format_number(from_si(bump, 'velocity', units))} {v_unit}): the curve there "
              "is extrapolated with its end slopes")
    return 0


def run_check(args):
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
    from ident.models import adjustable
    from planner.dyno.check import check_dyno_library, library_units
    from planner.report.dyno import write_dyno_check

    check_output(args.out, overwrite=args.overwrite, folder=True)
    try:  # the findings in the library's unit system (or --units)
        set_display_units(args.units or library_units(args.library))
    except (ValueError, OSError):
        pass  # a library that cannot be read: the check says why
    # the click model logs its sheets' warnings when built; they are printed below
    quiet = logging.getLogger(adjustable.__name__)
    drop = _DropWarnings()
    quiet.addFilter(drop)
    try:
        check = check_dyno_library(args.library)
    finally:
        quiet.removeFilter(drop)
    units = args.units or check.units
    set_display_units(units)
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


def _add_import(dyno_sub):
    """Add ``import`` to the ``dyno`` command's `dyno_sub`."""
    imp = dyno_sub.add_parser("import", help="raw dyno time series (time, force, displacement) "
                              "to dyno-sheet rows at one setting")
    imp.add_argument("raw", nargs="+", metavar="RAW", help="raw dyno files (CSV or Parquet), "
                     "one run each, all at the same settings")
    imp.add_argument("--map", metavar="MAP.toml", help="dyno map: the files' time, force, "
                     "displacement (and temperature) columns, units, signs, offsets (default: "
                     "columns time [s], force [N], displacement [m], temperature [deg C], or "
                     "in and lbf with a 'units' column holding imperial)")
    imp.add_argument("--settings", metavar="NAME=VALUE,...", default="",
                     help="the adjusters' settings of the runs, e.g. ls=6,hs=2 (clicks or "
                     "turns; one sheet column each, in this order) (default: none, a shock "
                     "without adjusters)")
    imp.add_argument("--out", required=True, metavar="SHEET.csv", help="the dyno sheet to write")
    imp.add_argument("--append", action="store_true", help="add the rows to an existing sheet "
                     "with the same columns, keeping its rows (default: a new sheet)")
    imp.add_argument("--units", type=unit_system, choices=list(UNIT_SYSTEMS), default=None,
                     help="units of the sheet's velocity and force: SI (m/s, N) or imperial "
                     "(in/s, lbf), in any case (default: the sheet's own when appending, "
                     "else SI)")
    add_resample(imp, "every raw file")
    imp.add_argument("--overwrite", action="store_true", help="replace an existing sheet")
    imp.set_defaults(func=run)
    return imp


def _add_table(subparsers):
    """Add ``table`` (``shockplan dyno table``) to `subparsers`.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``dyno`` command's sub-commands.

    Returns
    -------
    argparse.ArgumentParser
    """
    p = subparsers.add_parser(
        "table", help="write a library shock's curve at a setting as velocity, force (what a "
        "shock builder reads)")
    p.add_argument("library", metavar="LIB.toml", help="shock library")
    p.add_argument("--shock", required=True, help="the shock: a fixed id, or an adjustable "
                   "shock's setting such as TTX@ls=10,hs=2 (adjusters left out take their "
                   "default)")
    p.add_argument("--velocity", type=parse_velocities, help="velocities V,V,... "
                   "[m/s, or in/s with --units imperial], compression positive; sorted; "
                   "negative first needs '=': --velocity=-0.5,-0.1,0.1,0.5 (default: an "
                   "adjustable or table shock's own knots, i.e. an adjustable shock's "
                   "measured dyno speeds of each side and 0; for a linear or digressive "
                   "shock 0.0125-1 m/s or 0.5-40 in/s, each side and 0)")
    p.add_argument("--units", type=unit_system, choices=list(UNIT_SYSTEMS), default=None,
                   help="units of --velocity and of the table: SI or imperial, in any case "
                   "(default: the library's 'units')")
    p.add_argument("--out", required=True, help="CSV to write (velocity, force, units)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    p.set_defaults(func=run)
    return p


def _add_check(subparsers):
    """Add ``check`` (``shockplan dyno check``) to `subparsers`.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``dyno`` command's sub-commands.

    Returns
    -------
    argparse.ArgumentParser
    """
    p = subparsers.add_parser(
        "check", help="check every adjustable shock of a library against its dyno sheets: "
        "the model's error per setting, plots, wrong-sign forces and crossing curves (exit "
        "status 1 on an error)")
    p.add_argument("library", metavar="LIB.toml", help="shock library")
    p.add_argument("--out", required=True, help="folder to write: summary.md, findings.csv, "
                   "and per adjustable shock <id>.fit.csv, <id>.worst.csv, <id>.curves.png")
    p.add_argument("--units", type=unit_system, choices=list(UNIT_SYSTEMS), default=None,
                   help="units of the files and plots: SI or imperial, in any case "
                   "(default: the library's 'units')")
    p.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    p.set_defaults(func=run)
    return p


#: The ``dyno`` sub-commands: name -> (function adding its parser, function running it).
SUBCOMMANDS = {"import": (_add_import, run_import), "table": (_add_table, run_table),
               "check": (_add_check, run_check)}


def add_parser(subparsers):
    """Add the ``dyno`` command and its sub-commands to `subparsers`.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The top-level parser's commands.

    Returns
    -------
    argparse.ArgumentParser
        The ``dyno`` parser.
    """
    return add_command_group(subparsers, "dyno", SUBCOMMANDS,
                             help="shock dyno data: raw runs to dyno sheets",
                             dest="dyno_command", dest_help="the dyno command")


def run(args):
    """Run the ``dyno`` sub-command `args` names; returns the exit status."""
    return run_subcommand(SUBCOMMANDS, args, "dyno_command")
