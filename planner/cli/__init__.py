"""The ``shockplan`` command line: a thin layer over :mod:`ident` and :mod:`planner`.

Every command is a call into the library; the command line parses arguments, prints the
results' summaries and turns the project's errors into one-line messages. One module per
command (:data:`COMMANDS`, in the order ``shockplan --help`` lists them), each with a light
``add_parser(subparsers)`` and a ``run(args)`` that imports the library when it runs, so
that ``shockplan --help`` stays fast; what they share (the spelling-checking parser, units,
element and try options, output checks) is in :mod:`planner.cli.common`.

One vocabulary across commands (issue 23): ``--units`` takes ``SI`` or ``imperial`` in
any case and passes the canonical name on; a command that reads drive files defaults it
to the drive file's own unit system (its ``units`` column, or an earlier file's
``# units:`` line), else SI, and writes its
outputs in it; ``-q`` and ``-v`` go before or after the
command; options are spelled out in full, and a misspelled option or command ends with
exit status 2 and one line naming the nearest valid one; every option's help states its
default and, for a physical quantity, its unit.
"""

from __future__ import annotations

import logging
import sys

from ident import interrupts
from ident.data.units import display_units
from planner.cli import (demo, drive, dyno, export_drive, identify, optimize, plan, predict,
                         rank, rig, rigfiles, sweep, vehicle, whatif)
from planner.cli.common import (FLAGS_ANYWHERE, Parser, VersionAction, add_flags_anywhere,
                                one_line)

__all__ = ["main", "build_parser", "COMMANDS"]

#: The command modules, in the order of ``shockplan --help``: each adds its parser
#: (``add_parser(subparsers)``, setting ``func``) and runs it (``run(args)``).
COMMANDS = (demo, rig, identify, predict, rank, optimize, plan, whatif, sweep, rigfiles,
            export_drive, vehicle, dyno, drive)


def build_parser():
    """Build the argument parser (exposed for documentation and tests)."""
    p = Parser(
        prog="shockplan",
        description="Shock-absorber selection planner for 7-post, 8-post and 4-post shaker "
        "rigs.")
    for short, long, text in FLAGS_ANYWHERE:
        p.add_argument(short, long, action="store_true", help=text)
    p.add_argument("--version", action=VersionAction)
    sub = p.add_subparsers(dest="command", required=True,
                           help="the command ('shockplan COMMAND --help' for its options)")
    for command in COMMANDS:
        command.add_parser(sub)
    add_flags_anywhere(p)
    return p


def main(argv=None):
    """Entry point of the ``shockplan`` program; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    interrupts.install()  # a Ctrl-C swallowed by C code still stops the command
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        with display_units("SI"):  # until the command knows the project's unit system
            return args.func(args)
    except (ValueError, TypeError, FileExistsError, FileNotFoundError) as exc:
        print(f"shockplan: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:  # e.g. a disk that filled up or a folder made read-only meanwhile
        if exc.errno is None:  # raised here with a full message (e.g. a read-only --out)
            print(f"shockplan: error: {one_line(exc)}", file=sys.stderr)
        else:
            where = f"{exc.filename}: " if exc.filename else ""
            print(f"shockplan: error: {where}{exc.strerror or exc}; check the path and its "
                  "permissions", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # pragma: no cover
        print("shockplan: interrupted", file=sys.stderr)
        return 130
