"""``shockplan demo``: the main job end to end on the built-in example."""

from __future__ import annotations

from pathlib import Path

from planner.cli.common import check_out, show_progress

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``demo`` to `subparsers` (the top level's commands)."""
    demo = subparsers.add_parser("demo", help="run the whole job on the built-in example car")
    demo.add_argument("--out", default="shockplan-demo",
                      help="output folder (default %(default)s)")
    demo.add_argument("--overwrite", action="store_true",
                      help="replace an existing output folder")
    demo.set_defaults(func=run)
    return demo


def run(args):
    """``shockplan demo``: the main job end to end on the built-in example."""
    from planner.demo import run_demo

    check_out(args, folder=True)
    summary = run_demo(Path(args.out), overwrite=args.overwrite, progress=show_progress(args))
    print(summary)
    return 0
