"""``shockplan export-drive``: a drive file written as the RPC III file a rig plays."""

from __future__ import annotations

from planner.cli.common import UNITS_OF_DRIVE, add_units, check_out

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``export-drive`` to `subparsers`."""
    exp = subparsers.add_parser("export-drive", help="write a drive file as the RPC III file "
                                "a rig controller plays")
    exp.add_argument("drive", help="drive file (CSV or Parquet)")
    exp.add_argument("--format", required=True, choices=["rpc3"],
                     help="the file format written: RPC III (rpc3)")
    exp.add_argument("--map", help="the rig's channel map (channel names, units, signs); "
                     "default canonical names in mm, N, N*m")
    add_units(exp, "units of the drive file", default=None, default_text=UNITS_OF_DRIVE)
    exp.add_argument("--out", required=True, help="RPC III file to write (.drv, .rsp, .tim)")
    exp.add_argument("--overwrite", action="store_true", help="replace an existing file")
    exp.set_defaults(func=run)
    return exp


def run(args):
    """``shockplan export-drive``: a drive file written as the RPC III file a rig plays."""
    from ident.data.drive import read_drive
    from ident.data.formats import export_drive_rpc3

    check_out(args)
    drive = read_drive(args.drive, units=args.units)
    path = export_drive_rpc3(drive, args.out, channel_map=args.map, overwrite=args.overwrite)
    print(f"wrote drive '{drive.name}' ({drive.duration_s:g} s at {drive.fs_hz:g} Hz) as RPC III "
          f"to {path}")
    return 0
