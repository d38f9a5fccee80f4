"""Real rig data formats: RPC III, MDF and TDMS files in and out of rig sessions.

Rig acquisitions write their own formats: MTS controllers and RPC Pro write
RPC III time histories (``.rsp``, ``.tim``, ``.drv``), vehicle data loggers
ASAM MDF (``.mf4``), NI systems TDMS (``.tdms``). Each is read with the library
made for it (``rpc3-file``, ``asammdf``, ``npTDMS``) by a reader that returns
the file's channels as stored (:class:`RawRecord`); a channel map
(:mod:`ident.data.formats.channel_map`) names, per canonical channel, the file's
channel, its unit, scale, offset and sign; one engine (:func:`read_run`) checks
and converts a file to SI canonical channels; :func:`import_runs` appends files
as runs to a rig session folder; :func:`export_drive_rpc3` writes a drive as
the RPC III file a rig controller plays.

Command-line use (thin calls)::

    shockplan import --format rpc3 --map MAP.toml FILES... --setup B20,B20,N8,B20 --out SESSION
        -> import_runs(SESSION, FILES, format=..., channel_map=MAP, setup="B20,B20,N8,B20",
                       role=..., names=..., shocks=..., units=...)
    shockplan export-drive DRIVE.csv --format rpc3 --out FILE.drv
        -> export_drive_rpc3(ident.data.drive.read_drive(DRIVE.csv, units=...), FILE.drv, ...)

Errors on user input are :class:`~ident.errors.SessionError` (files, maps,
sessions) and :class:`~ident.errors.DriveError` (drives), one sentence each
naming the file, the channel and the fix.

Examples
--------
>>> FORMATS
('rpc3', 'mdf', 'tdms')
>>> parse_setup("B20,B20,N8,B20")["LR"]
'N8'
"""

from ident.data.formats.engine import (
    READERS,
    as_channel_map,
    check_time_base,
    import_runs,
    mapped_channel_si,
    parse_setup,
    read_mapped_raw,
    read_raw,
    read_run,
)
from ident.data.formats.record import FORMAT_NAMES, FORMATS, RawRecord, sniff_format
from ident.data.formats.channel_map import (
    CHANNEL_MAP_FORMAT,
    UNIT_FACTORS,
    ChannelMap,
    ChannelSpec,
    apply_channel_map,
    make_channel_map,
    read_channel_map,
)
from ident.data.formats.drives import DRIVE_UNITS, export_drive_rpc3, read_drive_rpc3
from ident.data.formats.mdf import read_mdf
from ident.data.formats.rpc3 import read_rpc3, write_rpc3
from ident.data.formats.tdms import read_tdms

__all__ = [
    "FORMATS",
    "FORMAT_NAMES",
    "READERS",
    "CHANNEL_MAP_FORMAT",
    "UNIT_FACTORS",
    "DRIVE_UNITS",
    "RawRecord",
    "ChannelSpec",
    "ChannelMap",
    "read_channel_map",
    "make_channel_map",
    "apply_channel_map",
    "as_channel_map",
    "sniff_format",
    "read_raw",
    "read_mapped_raw",
    "check_time_base",
    "mapped_channel_si",
    "read_rpc3",
    "read_mdf",
    "read_tdms",
    "write_rpc3",
    "read_run",
    "parse_setup",
    "import_runs",
    "export_drive_rpc3",
    "read_drive_rpc3",
]
