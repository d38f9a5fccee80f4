"""MTS RPC III time-history files (``.rsp``, ``.tim``, ``.drv``), through ``rpc3-file``.

RPC III is the format of MTS rig controllers and of RPC Pro: a header of
512-byte blocks holding 128-byte ``KEY VALUE`` records (``FORMAT``,
``NUM_HEADER_BLOCKS``, ``NUM_PARAMS``, ``CHANNELS``, ``DELTA_T``,
``PTS_PER_FRAME``, ``PTS_PER_GROUP``, ``FRAMES``, ``DATA_TYPE``,
``DESC.CHAN_n``, ``UNITS.CHAN_n``, ``SCALE.CHAN_n`` ...), then the channels'
samples demultiplexed in groups. ``DATA_TYPE`` is ``SHORT_INTEGER`` (16-bit
integers, value = integer * ``SCALE.CHAN_n``) or ``FLOATING_POINT`` (32-bit
floats).

The file I/O is the ``rpc3-file`` package's (``import rpc3``, version
1.0.0rc6); this module adds what shockplan needs around it:

- :func:`read_rpc3` reads every channel (``DESC.CHAN_n`` is its name,
  ``UNITS.CHAN_n`` its unit) and rebuilds the exact ``SHORT_INTEGER`` values
  in float64 (the package returns float32: ``rint(value / SCALE)`` recovers
  the integer exactly, since float32's error is below 0.002 of a step);
- :func:`write_rpc3` writes atomically under any suffix (the package appends
  ``.rpc`` to ``.tim`` and ``.drv`` names, so it writes a temporary ``.rsp``
  that is renamed into place), and writes every number of the header with a
  decimal point (the package reads ``1e-05`` back as a string and fails).

Accuracy of a round trip (measured in ``tests/test_formats.py``):

- ``SHORT_INTEGER``: each channel is scaled so that its largest absolute value
  is ``INT_FULL_SCALE = 32752``; a value is off by at most half a step,
  ``max|x| / 65504`` (1.53e-5 of the channel's peak);
- ``FLOATING_POINT``: float32, at most ``2**-24`` (6.0e-8) of each value.

Files without a ``SAMPLES`` key (older MTS files) are read whole: ``FRAMES *
PTS_PER_FRAME`` samples (the package's heuristic that strips repeated values
at the end is not used: a drive that ends at rest would lose samples).
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import rpc3

from ident.data.files import atomic_path
from ident.errors import SessionError
from ident.data.formats.record import RawRecord, as_float_samples, check_file, logged_warnings

__all__ = ["RPC3_DATA_TYPES", "RPC3_TIME_TYPES", "INT_FULL_SCALE", "read_rpc3", "write_rpc3"]

logger = logging.getLogger(__name__)

#: Values of the header's ``DATA_TYPE`` that can be written.
RPC3_DATA_TYPES = ("SHORT_INTEGER", "FLOATING_POINT")
#: Values of the header's ``TIME_TYPE`` that can be written (a rig response or a drive).
RPC3_TIME_TYPES = ("RESPONSE", "DRIVE")
#: The integer full scale of ``SHORT_INTEGER`` data (MTS's 2**15 - 16).
INT_FULL_SCALE = 32752
#: Samples per group (and per frame) of written files: a power of 2, as MTS writes.
_PTS_PER_GROUP = 1024
#: Longest channel name or unit written: the header's value field is 96 bytes.
_MAX_VALUE_CHARS = 95


@contextmanager
def _no_progress_bar():
    """Silence rpc3-file's tqdm bar (its module switch ``progressbar``) during a call."""
    saved = rpc3.rpc3.progressbar
    rpc3.rpc3.progressbar = False
    try:
        yield
    finally:
        rpc3.rpc3.progressbar = saved


def _rpc_number(x):
    """Format a float for the header with a decimal point (``1e-05`` -> ``1.0e-05``).

    The shortest repr that round-trips, so the file holds exactly the float used.
    """
    s = repr(float(x))
    if "." not in s and "e" in s:
        mantissa, _, exponent = s.partition("e")
        s = f"{mantissa}.0e{exponent}"
    return s


def read_rpc3(path, *, channels=None, where=None):
    """Read an RPC III time-history file.

    Parameters
    ----------
    path : str or os.PathLike
        An RPC III file (``.rsp``, ``.tim``, ``.drv`` or any suffix).
    channels : iterable of str, optional
        Names (``DESC.CHAN_n``) of the channels to return (default all);
        names the file lacks are left out (the caller reports them, with
        ``available``).
    where : str, optional
        How to name the file in messages (default ``"file <path>"``).

    Returns
    -------
    RawRecord
        Values in the file's units (float64; ``SHORT_INTEGER`` values exactly
        integer * ``SCALE.CHAN_n``), times ``k * DELTA_T`` [s], the units
        ``UNITS.CHAN_n`` and the header parameters in ``header``.

    Raises
    ------
    SessionError
        If the file is missing or empty, is not an RPC III file (the message
        says what it looks like: ``check --format``), or its header is
        malformed or incomplete (e.g. no ``DELTA_T`` or a missing
        ``UNITS.CHAN_n``), or a requested name is held by two channels.
    """
    path = check_file(path, "rpc3", where=where)
    where = f"file {path}" if where is None else where
    try:
        with logged_warnings(where), _no_progress_bar():
            chans, params = rpc3.read(str(path), strip=False)
    except KeyError as exc:
        raise SessionError(
            f"{where}: the RPC III header lacks the key {exc.args[0]!r} (rpc3-file needs "
            "DESC, UNITS, SCALE, LOWER_LIMIT and UPPER_LIMIT for every channel); re-export "
            "the file with a complete header"
        ) from exc
    except (rpc3.FileFormatError, ValueError, TypeError, IndexError) as exc:
        raise SessionError(
            f"{where}: cannot read the RPC III file ({type(exc).__name__}: {exc}); check "
            "that it is a complete binary RPC III time history"
        ) from exc
    except OSError as exc:
        raise SessionError(f"{where}: cannot read the file ({exc}); check its permissions") \
            from exc

    names = [str(ch.name) for ch in chans]
    wanted = names if channels is None else [c for c in dict.fromkeys(channels) if c in names]
    short = params.get("DATA_TYPE", "SHORT_INTEGER") == "SHORT_INTEGER"
    dt = float(params["DELTA_T"])
    data, times, units = {}, {}, {}
    for name in wanted:
        idx = [i for i, n in enumerate(names) if n == name]
        if len(idx) > 1:
            raise SessionError(
                f"{where}: channels {[i + 1 for i in idx]} are all named {name!r} "
                "(DESC.CHAN_n); give the channels unique names in the export"
            )
        ch = chans[idx[0]]
        x = as_float_samples(ch.data, where=where, name=name)
        if short:
            step = float(ch.resolution)
            x = np.rint(x / step) * step
        data[name] = x
        times[name] = np.arange(x.size) * dt
        units[name] = str(ch.unit).strip()
    logger.debug("%s: RPC III, %d channel(s), %s, DELTA_T %g s", where, len(names),
                 params.get("DATA_TYPE"), dt)
    return RawRecord(path=path, format="rpc3", channels=data, time_s=times, units=units,
                     available=tuple(names), header=dict(params))


def _check_text(value, *, what, error):
    if not isinstance(value, str) or not value.strip():
        raise error(f"RPC III {what} {value!r} must be a non-empty string")
    try:
        value.encode("latin-1")
    except UnicodeEncodeError:
        raise error(f"RPC III {what} {value!r} has characters outside Latin-1; rename it") \
            from None
    if len(value) > _MAX_VALUE_CHARS:
        raise error(f"RPC III {what} {value[:20]!r}... is {len(value)} characters long; the "
                    f"header holds at most {_MAX_VALUE_CHARS}: shorten it")
    return value


def write_rpc3(path, channels, *, fs_hz, units, data_type="SHORT_INTEGER",
               time_type="RESPONSE", overwrite=False, error=ValueError):
    """Write channels as an RPC III time-history file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Output file, any suffix (``.rsp`` for responses, ``.drv`` for drives).
    channels : mapping of str to array_like, shape (n_samples,)
        Channel name (``DESC.CHAN_n``) -> values in the file's units, in
        file order.
    fs_hz : float
        Sample rate [Hz]; ``DELTA_T = 1 / fs_hz``.
    units : mapping of str to str
        Channel name -> unit string (``UNITS.CHAN_n``), e.g. ``"mm"``.
    data_type : {"SHORT_INTEGER", "FLOATING_POINT"}
        ``SHORT_INTEGER`` (what RPC III V5 programs and MTS controllers play)
        quantizes each channel to 16 bits, full scale its largest absolute
        value; ``FLOATING_POINT`` writes float32.
    time_type : {"RESPONSE", "DRIVE"}
        The header's ``TIME_TYPE``.
    overwrite : bool
        Replace an existing file.
    error : type
        Exception class raised on bad arguments (a ``ValueError`` subclass).

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    ValueError (or `error`)
        If there are no channels, a name or unit is empty, not Latin-1 or
        longer than 95 characters, a channel lacks a unit, the channels differ
        in length or have fewer than 2 samples or NaN/inf values, `fs_hz` is not
        positive, or `data_type` / `time_type` is unknown.
    FileExistsError
        If `path` exists and `overwrite` is false.

    Notes
    -----
    Written header: ``FORMAT BINARY``, ``FILE_TYPE TIME_HISTORY``,
    ``TIME_TYPE``, ``CHANNELS``, ``DELTA_T``, ``PTS_PER_FRAME`` =
    ``PTS_PER_GROUP`` = 1024, ``FRAMES``, ``SAMPLES``, ``DATA_TYPE``,
    ``INT_FULL_SCALE 32752`` and per channel ``DESC``, ``UNITS``, ``SCALE``,
    ``LOWER_LIMIT``, ``UPPER_LIMIT``, ``MAP``. The last group is padded with
    the channel's last value (``SAMPLES`` gives the true length).
    """
    if data_type not in RPC3_DATA_TYPES:
        raise error(f"data_type {data_type!r} is not one of {', '.join(RPC3_DATA_TYPES)}")
    if time_type not in RPC3_TIME_TYPES:
        raise error(f"time_type {time_type!r} is not one of {', '.join(RPC3_TIME_TYPES)}")
    if isinstance(fs_hz, bool) or not isinstance(fs_hz, (int, float, np.floating)) \
            or not math.isfinite(fs_hz) or fs_hz <= 0:
        raise error(f"fs_hz = {fs_hz!r} must be a positive number of Hz")
    if not isinstance(channels, Mapping) or not channels:
        raise error("channels must be a non-empty mapping name -> samples")
    if not isinstance(units, Mapping):
        raise error("units must be a mapping channel name -> unit string")
    dt = 1.0 / float(fs_hz)
    arrays, n = {}, None
    for name, values in channels.items():
        _check_text(name, what="channel name", error=error)
        if name not in units:
            raise error(f"RPC III channel {name!r} has no unit; give units[{name!r}]")
        _check_text(units[name], what=f"unit of channel {name!r}", error=error)
        x = np.asarray(values, dtype=np.float64)
        if x.ndim != 1 or x.size < 2:
            raise error(f"RPC III channel {name!r} must be one-dimensional with at least 2 "
                        f"samples, got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise error(f"RPC III channel {name!r} has NaN/inf values; fill or cut them")
        if n is not None and x.size != n:
            raise error(f"RPC III channel {name!r} has {x.size} samples, the first channel "
                        f"{n}; give every channel the same length")
        n = x.size
        arrays[name] = x

    short = data_type == "SHORT_INTEGER"
    extra = {"TIME_TYPE": time_type, "DELTA_T": _rpc_number(dt)}
    lib_channels = []
    for i, (name, x) in enumerate(arrays.items(), start=1):
        peak = float(np.max(np.abs(x)))
        scale = peak / INT_FULL_SCALE if short and peak > 0 else 1.0
        extra[f"SCALE.CHAN_{i}"] = _rpc_number(scale)
        extra[f"LOWER_LIMIT.CHAN_{i}"] = _rpc_number(x.min())
        extra[f"UPPER_LIMIT.CHAN_{i}"] = _rpc_number(x.max())
        lib_channels.append(rpc3.Channel(name, units[name], dt=dt, data=x))

    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        # rpc3-file appends ".rpc" unless the name ends in .rpc/.rpc3/.rsp
        lib_path = tmp.with_name(tmp.name + ".rsp")
        try:
            with _no_progress_bar():
                rpc3.write(str(lib_path), lib_channels, datatype=int if short else float,
                           pts_per_group=_PTS_PER_GROUP, overwrite=True, extra_params=extra)
            os.replace(lib_path, tmp)
        finally:
            lib_path.unlink(missing_ok=True)
    logger.info("wrote RPC III %s: %d channel(s) x %d samples at %g Hz, %s", path,
                len(arrays), n, fs_hz, data_type)
    return path
