"""Drives as RPC III files, the files an MTS rig controller plays.

:func:`export_drive_rpc3` writes an :class:`ident.data.drive.Drive` (SI inside) as
an RPC III drive file (``TIME_TYPE DRIVE``); :func:`read_drive_rpc3` reads one
back into a Drive.

Channel names and units
-----------------------
An MTS controller maps a drive file's channel to the station channel whose
name equals the channel's descriptor (``DESC.CHAN_n``), and converts the
values from the channel's unit descriptor (``UNITS.CHAN_n``) when it is a unit
of that channel's dimension. So:

- with a ``channel_map`` (the rig's map, :mod:`ident.data.formats.channel_map`),
  each mapped rig input is written under its ``source`` name, in the map's
  ``units`` with its ``sign``, ``scale`` and ``offset`` inverted: the file
  holds what the rig's own files hold. Rig inputs the map does not map are
  left out (a 4-post rig has no aero actuators); they must be all zero;
- without a map, the channels are named by their canonical names
  (``wheelloader_LF`` ...), in :data:`ident.data.channels.RIG_INPUTS` order, in
  the unit set `units`: ``"SI"`` writes wheel-pad displacements in **mm**
  (the length unit of MTS's metric unit sets), ``aero_heave`` in N and the
  aero moments in N*m; ``"imperial"`` writes in, lbf and lbf*in.

Data type
---------
``SHORT_INTEGER`` by default: RPC III V5 programs and MTS controllers play
16-bit drives (``FLOATING_POINT`` is not supported by RPC III V5.0x). Each
channel's full scale is its peak, so a sample is off by at most half a step,
``peak / 65504`` (1.53e-5 of the peak; 0.39 um on a 25.4 mm wheel-pad peak).

Sample rate
-----------
The file keeps the drive's rate. MTS time-history playout supports a fixed
set of file rates (e.g. 102.4, 128, 204.8, 256, 409.6, 512, 1024, 2048 Hz,
depending on the controller's system rate); a drive at another rate is
written with a logged warning (:func:`playout_rate_advice`): resample it first with
``shockplan drive resample DRIVE --fs 512 --out NEW.csv`` (in Python
:func:`ident.data.drive.resample_drive`; e.g. 100 Hz -> 512 Hz).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ident.data.channels import AERO_INPUTS, RIG_INPUTS, WHEELLOADER_INPUTS, quantity_of
from ident.data.drive import Drive
from ident.errors import DriveError, SessionError
from ident.data.formats.engine import as_channel_map, read_run
from ident.data.formats.channel_map import ChannelMap, unit_factor
from ident.data.formats.rpc3 import RPC3_DATA_TYPES, read_rpc3, write_rpc3
from ident.data.units import check_units

__all__ = ["DRIVE_UNITS", "MTS_PLAYOUT_RATES_HZ", "export_drive_rpc3", "read_drive_rpc3",
           "playout_rate_advice"]

logger = logging.getLogger(__name__)

#: Unit written per quantity of a rig input, per unit set (without a channel map).
DRIVE_UNITS = {
    "SI": {"displacement": "mm", "force": "N", "moment": "N*m"},
    "imperial": {"displacement": "in", "force": "lbf", "moment": "lbf*in"},
}
#: File rates MTS time-history playout supports (at some system rate) [Hz].
MTS_PLAYOUT_RATES_HZ = (102.4, 128.0, 204.8, 256.0, 409.6, 512.0, 1024.0, 2048.0)


def playout_rate_advice(fs_hz):
    """What to do with a drive at `fs_hz` [Hz], not an MTS playout rate: the command that
    resamples it to the nearest playout rate at or above it (the highest one, above them all).

    Examples
    --------
    >>> playout_rate_advice(200.0)  # doctest: +NORMALIZE_WHITESPACE
    '200 Hz is not an MTS playout rate (102.4, 128, 204.8, 256, 409.6, 512, 1024, 2048 Hz);
    if the controller refuses the file, resample the drive first: shockplan drive resample
    DRIVE --fs 204.8 --out NEW.csv (in Python: ident.data.drive.resample_drive)'
    """
    up = [r for r in MTS_PLAYOUT_RATES_HZ if r >= fs_hz]
    target = up[0] if up else MTS_PLAYOUT_RATES_HZ[-1]
    return (f"{fs_hz:g} Hz is not an MTS playout rate "
            f"({', '.join(f'{r:g}' for r in MTS_PLAYOUT_RATES_HZ)} Hz); if the controller "
            f"refuses the file, resample the drive first: shockplan drive resample DRIVE --fs "
            f"{target:g} --out NEW.csv (in Python: ident.data.drive.resample_drive)")


def export_drive_rpc3(drive, path, *, units=None, channel_map=None,
                      data_type="SHORT_INTEGER", overwrite=False):
    """Write a drive as an RPC III drive file, atomically.

    Parameters
    ----------
    drive : ident.data.drive.Drive
        The drive (SI).
    path : str or os.PathLike
        Output file, usually ``.drv`` (any suffix is kept as given).
    units : {"SI", "imperial"}, optional
        Unit set without a channel map (default ``"SI"``: mm, N, N*m); not
        allowed with a map (the map's units are used).
    channel_map : ChannelMap or str or os.PathLike, optional
        The rig's channel map (or its TOML file): names, units and signs of
        the controller's channels.
    data_type : {"SHORT_INTEGER", "FLOATING_POINT"}
        RPC III data type (see the module docstring).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    TypeError
        If `drive` is not a Drive.
    DriveError
        If `units` is unknown or given with a map; the map leaves out a rig
        input the drive moves (non-zero) or maps none; `data_type` is unknown;
        a channel name or unit does not fit the RPC III header (Latin-1, at most
        95 characters).
    SessionError
        If the channel-map file is invalid.
    FileExistsError
        If `path` exists and `overwrite` is false.

    Examples
    --------
    >>> import os, tempfile
    >>> from ident.data.drive import make_noise_drive
    >>> drive = make_noise_drive(duration_s=4.0, fs_hz=128.0, seed=1,
    ...                          peak={"wheelloader_LF": 0.0254})
    >>> p = export_drive_rpc3(drive, os.path.join(tempfile.mkdtemp(), "noise.drv"))
    >>> back = read_drive_rpc3(p)
    >>> bool(abs(back.channels["wheelloader_LF"] - drive.channels["wheelloader_LF"]).max()
    ...      <= 0.0254 / 65504)
    True
    """
    if not isinstance(drive, Drive):
        raise TypeError(f"export_drive_rpc3: drive must be a Drive, got {type(drive).__name__}")
    where = f"drive {drive.name!r} -> {path}"
    if data_type not in RPC3_DATA_TYPES:
        raise DriveError(f"{where}: data_type {data_type!r} is not one of "
                         f"{', '.join(RPC3_DATA_TYPES)}")
    values, file_units = {}, {}
    if channel_map is None:
        unit_set = DRIVE_UNITS[check_units("SI" if units is None else units,
                                           where=f"{where}: units", error=DriveError)]
        for c in drive.rig_inputs:  # a 4-post drive: the wheelloaders only
            u = unit_set[quantity_of(c)]
            values[c] = drive.channels[c] / unit_factor(u, quantity_of(c))
            file_units[c] = u
    else:
        if units is not None:
            raise DriveError(f"{where}: units={units!r} and a channel map were both given; "
                             "the map's units are written, so omit units")
        cmap = as_channel_map(channel_map)
        for c in RIG_INPUTS:
            spec = cmap.channels.get(c)
            if spec is None:
                if np.any(drive.channels[c] != 0.0):
                    raise DriveError(
                        f"{where}: {cmap.where} maps no source for {c!r}, which this drive "
                        f"moves (peak {np.max(np.abs(drive.channels[c])):.6g} SI); add "
                        f"[channels.{c}] to the map, or zero that input"
                    )
                logger.info("%s: %s is all zero and not in the map; left out", where, c)
                continue
            values[spec.source] = spec.from_si(drive.channels[c])
            file_units[spec.source] = spec.units
        if not values:
            raise DriveError(f"{where}: {cmap.where} maps none of the rig inputs "
                             f"{list(RIG_INPUTS)}; map the rig's actuator channels")
    if not any(np.isclose(drive.fs_hz, r, rtol=1e-9) for r in MTS_PLAYOUT_RATES_HZ):
        logger.warning("%s: %s", where, playout_rate_advice(drive.fs_hz))
    return write_rpc3(path, values, fs_hz=drive.fs_hz, units=file_units,
                      data_type=data_type, time_type="DRIVE", overwrite=overwrite,
                      error=DriveError)


def read_drive_rpc3(path, *, channel_map=None, name=None):
    """Read an RPC III drive file into a Drive (SI).

    Parameters
    ----------
    path : str or os.PathLike
        The RPC III file.
    channel_map : ChannelMap or str or os.PathLike, optional
        The rig's channel map: its rig inputs are read through it (other
        channels of the map are ignored). Without a map the channels must be
        named by the canonical rig-input names, with a unit each
        (``UNITS.CHAN_n``) of the input's quantity.
    name : str, optional
        Drive name (default the file name without suffix).

    Returns
    -------
    ident.data.drive.Drive
        Rig inputs the file does not hold (the map does not map) are all zero;
        ``settings`` records the file, the map and the inputs set to zero.

    Raises
    ------
    DriveError
        If the file is missing, not an RPC III file or damaged; holds no
        wheelloader channel (without a map: the message lists what it has);
        a channel's unit is not one of its quantity's; a mapped channel is
        missing or fails the checks of :func:`ident.data.formats.read_run`.
    """
    path = Path(path)
    where = f"drive file {path}"
    cmap = None
    try:
        if channel_map is not None:
            cmap = as_channel_map(channel_map)
            inputs = {c: s for c, s in cmap.channels.items() if c in RIG_INPUTS}
            if not inputs:
                raise DriveError(f"{where}: {cmap.where} maps none of the rig inputs "
                                 f"{list(RIG_INPUTS)}; map the drive's channels")
            sub = ChannelMap(channels=inputs, time=None, name=cmap.name, path=cmap.path)
            table = read_run(path, format="rpc3", channel_map=sub, where=where)
            fs_hz, found = table.fs_hz, dict(table.channels)
        else:
            raw = read_rpc3(path, channels=RIG_INPUTS, where=where)
            if not any(c in raw.channels for c in WHEELLOADER_INPUTS):
                raise DriveError(
                    f"{where}: has no channel named like a rig input ({list(RIG_INPUTS)}); it "
                    f"has {list(raw.available)}: read it with the rig's channel map"
                )
            found = {}
            for c, x in raw.channels.items():
                factor = unit_factor(raw.units[c], quantity_of(c),
                                     where=f"{where}: channel {c!r}")
                found[c] = x * factor
            fs_hz = 1.0 / float(raw.header["DELTA_T"])
    except SessionError as exc:
        raise DriveError(str(exc)) from exc
    n = len(next(iter(found.values())))
    zero = [c for c in RIG_INPUTS if c not in found]
    if zero:
        logger.info("%s: no %s in the file; set to zero", where, zero)
    # a file without aero channels is a 4-post drive (its Drive has the wheelloaders only)
    keep = RIG_INPUTS if any(c in found for c in AERO_INPUTS) else WHEELLOADER_INPUTS
    channels = {c: found.get(c, np.zeros(n)) for c in keep}
    settings = {"kind": "file", "path": str(path), "format": "rpc3",
                "channel_map": None if cmap is None else cmap.where, "zero_inputs": zero}
    return Drive(name=name or path.stem, fs_hz=fs_hz, channels=channels, settings=settings)
