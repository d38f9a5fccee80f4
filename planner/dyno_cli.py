"""The ``shockplan dyno`` commands: raw dyno runs to sheets, curves at a setting, checks.

``shockplan dyno import RAW.csv [RAW.csv ...] --map MAP.toml --settings ls=6,hs=2 --out
SHEET.csv [--append] [--units SI|imperial]`` turns raw dyno time series into dyno-sheet
rows (:func:`ident.dyno.raw.import_dyno_runs`,
:func:`ident.dyno.raw.write_dyno_sheet`) and prints a short report per file.

Each sub-command is one entry of :data:`SUBCOMMANDS` (name -> the function that adds its
parser); ``table`` and ``check`` (:mod:`planner.dyno_args`, run by
:mod:`planner.dyno_commands`) are added by :func:`add_parser` from the functions it is given. :func:`add_parser` is called once by
:func:`planner.cli.build_parser`.
"""

from __future__ import annotations

import logging

from ident.dyno.raw import import_dyno_runs, parse_settings, write_dyno_sheet
from ident.data.files import check_output, read_units_marker
from ident.data.units import UNIT_LABELS, UNIT_SYSTEMS, from_si
from ident.errors import DynoError
from planner.dyno_args import add_check_parser, add_table_parser

__all__ = ["add_parser", "cmd_dyno_import", "format_import_report", "SUBCOMMANDS"]

log = logging.getLogger("shockplan")


def _unit_system(text):
    """``--units`` in any case as its canonical name (other text unchanged, for argparse's
    ``choices`` to refuse)."""
    for name in UNIT_SYSTEMS:
        if text.strip().lower() == name.lower():
            return name
    return text


def format_import_report(result, *, units="SI"):
    """The report of a dyno import: one block of lines per file, then the warnings.

    Parameters
    ----------
    result : ident.dyno.raw.DynoImport
    units : {"SI", "imperial"}
        Velocity and force units of the report.

    Returns
    -------
    str
    """
    lab = UNIT_LABELS[units]
    settings = ",".join(f"{k}={v:g}" for k, v in result.settings.items()) or "(no adjusters)"
    lines = [f"dyno import at {settings}: {len(result.runs)} file(s)"]
    for run in result.runs:
        speeds = [b.bump_velocity_m_s for b in run.blocks]
        temp = ("no temperature" if run.temperature_c is None else
                f"temperature {run.temperature_c:.1f} deg C (rise {run.temperature_rise_c:+.1f})")
        lines.append(
            f"  {run.source}: {run.cycles} cycles, {len(run.blocks)} speeds "
            f"{from_si(min(speeds), 'velocity', units):.4g}-"
            f"{from_si(max(speeds), 'velocity', units):.4g} {lab['velocity']}, gas force "
            f"{from_si(run.gas_force_n, 'force', units):.4g} {lab['force']} (removed), lag "
            f"{run.lag_s * 1e3:.2f} ms, {temp}")
    lines += [f"  warning: {w}" for w in result.warnings]
    return "\n".join(lines)


def cmd_dyno_import(args):
    """``shockplan dyno import``: raw dyno files -> dyno-sheet rows."""
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
    result = import_dyno_runs(args.raw, settings=settings, dyno_map=args.map)
    warnings = write_dyno_sheet(result, args.out, units=units, append=args.append,
                                overwrite=args.overwrite)
    print(format_import_report(result, units=units))
    for w in warnings:
        print(f"  warning: {w}")
    n_rows = sum(2 * len(r.blocks) for r in result.runs)
    print(f"{'appended' if args.append else 'wrote'} {n_rows} rows to {args.out} ({units})")
    return 0


def _add_import(dyno_sub):
    imp = dyno_sub.add_parser("import", help="raw dyno time series (time, force, displacement) "
                              "to dyno-sheet rows at one setting")
    imp.add_argument("raw", nargs="+", metavar="RAW", help="raw dyno files (CSV or Parquet), "
                     "one run each, all at the same settings")
    imp.add_argument("--map", metavar="MAP.toml", help="dyno map: the files' time, force, "
                     "displacement (and temperature) columns, units, signs, offsets (default: "
                     "columns time [s], force [N], displacement [m], temperature [deg C], or "
                     "in and lbf with a '# units: imperial' line)")
    imp.add_argument("--settings", metavar="NAME=VALUE,...", default="",
                     help="the adjusters' settings of the runs, e.g. ls=6,hs=2 (clicks or "
                     "turns; one sheet column each, in this order) (default: none, a shock "
                     "without adjusters)")
    imp.add_argument("--out", required=True, metavar="SHEET.csv", help="the dyno sheet to write")
    imp.add_argument("--append", action="store_true", help="add the rows to an existing sheet "
                     "with the same columns, keeping its rows (default: a new sheet)")
    imp.add_argument("--units", type=_unit_system, choices=list(UNIT_SYSTEMS), default=None,
                     help="units of the sheet's velocity and force: SI (m/s, N) or imperial "
                     "(in/s, lbf), in any case (default: the sheet's own when appending, "
                     "else SI)")
    imp.add_argument("--overwrite", action="store_true", help="replace an existing sheet")
    imp.set_defaults(func=cmd_dyno_import)
    return imp


#: The ``dyno`` sub-commands: name -> function adding its parser to the sub-parsers
#: action (and setting ``func``).
SUBCOMMANDS = {"import": _add_import}


def add_parser(subparsers, *, table=None, check=None):
    """Add the ``dyno`` command and its sub-commands to `subparsers`.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The top-level parser's commands (``build_parser``'s ``sub``).
    table, check : callable, optional
        The functions run by ``dyno table`` and ``dyno check``
        (:mod:`planner.dyno_commands`; the command line passes wrappers that import them
        when run, so that building the parser stays light).

    Returns
    -------
    argparse.ArgumentParser
        The ``dyno`` parser.
    """
    dyno = subparsers.add_parser("dyno", help="shock dyno data: raw runs to dyno sheets")
    dyno_sub = dyno.add_subparsers(dest="dyno_command", required=True,
                                   help="the dyno command")
    for add in SUBCOMMANDS.values():
        add(dyno_sub)
    if table is not None:
        add_table_parser(dyno_sub, table)
    if check is not None:
        add_check_parser(dyno_sub, check)
    return dyno

