"""NI TDMS files (``.tdms``), through ``npTDMS``.

A TDMS file holds groups of channels. A channel is named ``"Group/Channel"``,
or by its bare name when no other group has a channel of that name. Its time
base is its waveform properties (``wf_increment`` [s] and
``wf_start_offset`` [s], as LabVIEW and DAQmx write them); a channel without
them has no time of its own, and the channel map must then name the channel
holding time in seconds (top-level ``time = "Group/Time"``). The unit is the
``unit_string`` property.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from nptdms import TdmsFile

from ident.errors import SessionError
from ident.data.formats.record import RawRecord, as_float_samples, check_file, logged_warnings

__all__ = ["read_tdms"]

logger = logging.getLogger(__name__)


def read_tdms(path, *, channels=None, where=None):
    """Read the channels of a TDMS file.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.tdms`` file (not its ``.tdms_index``).
    channels : iterable of str, optional
        Channels to return, as ``"Group/Channel"`` or a bare channel name
        unique in the file (default all, under ``"Group/Channel"``); names the
        file lacks are left out (the caller reports them, with ``available``).
        Only these are read.
    where : str, optional
        How to name the file in messages (default ``"file <path>"``).

    Returns
    -------
    RawRecord
        Values (float64) under the names asked for; times from the waveform
        properties (``wf_start_offset + k * wf_increment`` [s], the offset 0 if
        absent) or ``None``;
        units from ``unit_string``; ``available`` lists ``"Group/Channel"``
        names; ``header`` the file's properties.

    Raises
    ------
    SessionError
        If the file is missing or empty, is not a TDMS file (the message says
        what it looks like: ``check --format``), cannot be decoded, a bare
        name is in several groups, or a requested channel is not numeric
        (e.g. timestamps or strings).
    """
    path = check_file(path, "tdms", where=where)
    where = f"file {path}" if where is None else where
    data, times, units = {}, {}, {}
    try:
        with logged_warnings(where), TdmsFile.open(path) as tdms:
            index, bare = {}, {}
            for group in tdms.groups():
                for ch in group.channels():
                    qualified = f"{group.name}/{ch.name}"
                    index[qualified] = ch
                    bare.setdefault(ch.name, []).append(qualified)
            header = {k: str(v) for k, v in tdms.properties.items()}
            for name in (list(index) if channels is None else dict.fromkeys(channels)):
                if name in index:
                    ch = index[name]
                elif name in bare:
                    if len(bare[name]) > 1:
                        raise SessionError(
                            f"{where}: channel name {name!r} is in several groups "
                            f"({bare[name]}); name it as 'Group/Channel' in the map"
                        )
                    ch = index[bare[name][0]]
                else:
                    continue
                data[name] = as_float_samples(ch[:], where=where, name=name)
                props = ch.properties
                times[name] = None
                if "wf_increment" in props:
                    times[name] = (float(props.get("wf_start_offset", 0.0))
                                   + np.arange(data[name].size) * float(props["wf_increment"]))
                units[name] = str(props.get("unit_string", "")).strip()
    except SessionError:
        raise
    except Exception as exc:  # npTDMS raises many types on a damaged file: name it
        raise SessionError(
            f"{where}: cannot read the TDMS file ({type(exc).__name__}: {exc}); check that "
            "it is a complete TDMS file (not truncated)"
        ) from exc
    logger.debug("%s: TDMS, %d channel(s)", where, len(index))
    return RawRecord(path=Path(path), format="tdms", channels=data, time_s=times, units=units,
                     available=tuple(index), header=header)
