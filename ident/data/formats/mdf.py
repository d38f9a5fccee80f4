"""ASAM MDF measurement files (``.mf4``, ``.mdf``, ``.dat``), through ``asammdf``.

An MDF file holds channel groups, each with a master (time) channel and data
channels that carry their name, unit and conversion to physical values.
:func:`read_mdf` returns each requested data channel's physical values with
its own timestamps [s] and unit; the master channels are not listed as data
channels.

A channel name must be unique in the file to be mapped (asammdf would
otherwise need a group and index): the error names the groups that hold it.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from asammdf import MDF

from ident.errors import SessionError
from ident.data.formats.record import RawRecord, as_float_samples, check_file, logged_warnings

__all__ = ["read_mdf"]

logger = logging.getLogger(__name__)


def _index(mdf):
    """Return ``{name: [(group, index), ...]}`` of the data (non-master) channels."""
    index = {}
    for g, group in enumerate(mdf.groups):
        master = mdf.masters_db.get(g)
        for i, ch in enumerate(group.channels):
            if i != master:
                index.setdefault(ch.name, []).append((g, i))
    return index


def read_mdf(path, *, channels=None, where=None):
    """Read the channels of an MDF (3 or 4) file.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    channels : iterable of str, optional
        Names of the channels to return (default all data channels); names
        the file lacks are left out (the caller reports them, with
        ``available``). Only these are decoded.
    where : str, optional
        How to name the file in messages (default ``"file <path>"``).

    Returns
    -------
    RawRecord
        Physical values (float64) with each channel's timestamps [s] and unit;
        ``header`` holds the MDF ``version``.

    Raises
    ------
    SessionError
        If the file is missing or empty, is not an MDF file (the message says
        what it looks like: ``check --format``), cannot be decoded (truncated,
        corrupt), a requested name is held by channels of several groups, or a
        requested channel is not numeric (e.g. text or a structure).
    """
    path = check_file(path, "mdf", where=where)
    where = f"file {path}" if where is None else where
    data, times, units = {}, {}, {}
    try:
        with logged_warnings(where), MDF(path) as mdf:
            version = str(mdf.version)
            index = _index(mdf)
            wanted = list(index) if channels is None else [
                c for c in dict.fromkeys(channels) if c in index]
            for name in wanted:
                locations = index[name]
                if len(locations) > 1:
                    groups = sorted({g for g, _ in locations})
                    raise SessionError(
                        f"{where}: channel {name!r} is in {len(locations)} places (channel "
                        f"groups {groups}); give it a unique name in the export so the map "
                        "can name it"
                    )
                group, idx = locations[0]
                sig = mdf.get(name, group=group, index=idx)
                data[name] = as_float_samples(sig.samples, where=where, name=name)
                times[name] = np.asarray(sig.timestamps, dtype=np.float64)
                units[name] = str(sig.unit or "").strip()
    except SessionError:
        raise
    except Exception as exc:  # asammdf raises many types on a damaged file: name it
        raise SessionError(
            f"{where}: cannot read the MDF file ({type(exc).__name__}: {exc}); check that it "
            "is a complete MDF file (finalized, not truncated)"
        ) from exc
    logger.debug("%s: MDF %s, %d data channel(s)", where, version, len(index))
    return RawRecord(path=Path(path), format="mdf", channels=data, time_s=times, units=units,
                     available=tuple(index), header={"version": version})
