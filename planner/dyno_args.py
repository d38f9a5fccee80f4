"""The options of ``shockplan dyno table`` and ``shockplan dyno check``.

Light on purpose: the command line builds its parser on every start (``shockplan
--help``), so this module imports nothing heavy; the commands themselves are in
:mod:`planner.dyno_commands`, which the caller passes in as `func` (the command line
wraps them in functions that import them when run).
"""

from __future__ import annotations

import argparse

from ident.data.units import UNIT_SYSTEMS

__all__ = ["add_table_parser", "add_check_parser", "parse_velocities", "unit_system"]


def unit_system(text):
    """``--units`` in any case as its canonical name ("SI" or "imperial"); other text
    unchanged, for argparse's ``choices`` to refuse with the valid names."""
    for name in UNIT_SYSTEMS:
        if text.strip().lower() == name.lower():
            return name
    return text


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


def add_table_parser(subparsers, func):
    """Add ``table`` (``shockplan dyno table``) to `subparsers`.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``dyno`` command's sub-commands.
    func : callable
        Runs the command: ``func(args) -> int`` (exit status), set as ``func``.

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
    p.add_argument("--out", required=True, help="CSV to write (velocity, force; first line "
                   "'# units: ...')")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    p.set_defaults(func=func)
    return p


def add_check_parser(subparsers, func):
    """Add ``check`` (``shockplan dyno check``) to `subparsers`.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``dyno`` command's sub-commands.
    func : callable
        Runs the command: ``func(args) -> int`` (0 without errors, 1 with), set as
        ``func``.

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
    p.set_defaults(func=func)
    return p
