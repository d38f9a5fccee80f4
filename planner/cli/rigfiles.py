"""``shockplan import``: real rig files (RPC III, MDF4, TDMS) appended to a session."""

from __future__ import annotations

from planner.cli.common import add_resample, add_units, check_out

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``import`` to `subparsers`."""
    imp = subparsers.add_parser("import", help="append real rig files (RPC III, MDF4, TDMS) "
                                "to a session")
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
    add_units(imp, "units of a new session's run files", default=None,
              default_text="SI for a new session, the session's when appending")
    add_resample(imp, "every file (e.g. to the session's rate)")
    imp.set_defaults(func=run)
    return imp


def run(args):
    """``shockplan import``: real rig files (RPC III, MDF4, TDMS) appended to a session."""
    from ident.data.formats import import_runs

    check_out(args, folder=True, overwrite=True)  # appending to a session is the point
    names = None if args.names is None else [n.strip() for n in args.names.split(",")]
    session = import_runs(args.out, args.files, format=args.format, channel_map=args.map,
                          setup=args.setup, role=args.role, names=names, shocks=args.shocks,
                          units=args.units, resample_hz=args.resample)
    added = len(args.files)
    print(f"imported {added} run(s) into session '{session.name}' at {args.out}: now "
          f"{len(session.runs)} runs at {session.fs_hz:g} Hz ({session.units})")
    return 0
