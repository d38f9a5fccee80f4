"""Track logs: what a car's data logger recorded on track, read as SI under canonical names.

A track log is the input of issue 27's drives from track data: the suspension signals a
logger records on a lap, from which the rig drive that reproduces the lap is built. This
module reads one (:func:`read_track_log`), writes one (:func:`write_track_log`) and cuts
a window out of one (:func:`track_section`); the result is a :class:`TrackLog`, checked
once here so that everything downstream can trust it.

Channels
--------
Canonical names (:data:`TRACK_LOG_CHANNELS`), SI inside, the rig-session spec's signs:

========================  ==========  ====================================================
channel                   unit (SI)   meaning
========================  ==========  ====================================================
``time``                  s           sample times (a column of the file, not a channel)
``shock_travel_XX``       m           suspension deflection, compression positive;
                                      required at all four corners
``ride_height_XX``        m           chassis corner height above the ground, up positive
``wheel_accel_XX``        m/s^2       wheel (upright) vertical acceleration, up positive
``chassis_accel_XX``      m/s^2       chassis corner vertical acceleration, up positive
``speed``                 m/s         the car's speed
``aero_heave``            N           logged aero load: vertical force at the CG, up
``aero_roll``             N*m         roll moment, positive raises the left side
``aero_pitch``            N*m         pitch moment, positive raises the rear
========================  ==========  ====================================================

``XX`` is a corner (``LF``, ``RF``, ``LR``, ``RR``). The three aero channels come all three
or not at all. Values may carry static offsets (potentiometers are never zeroed, ride
heights are absolute): nothing here removes them.

Files
-----
- **CSV or Parquet with canonical column names**: a ``time`` column [s] and the channels
  above; other columns are ignored (logged at debug level). Units: the file's unit marker
  (a CSV's ``units`` column or ``# units: imperial`` line, a Parquet file's metadata
  ``units``, :mod:`ident.data.files`), else `units` (``--units``), else SI; a marker and a `units`
  that disagree are refused. Imperial means in, in/s, in/s^2, lbf, lbf*in (the spec's
  table; ``speed`` in in/s).
- **CSV or Parquet with the logger's own column names**, through a channel map: the
  ``format = "channel-map/1"`` TOML of ``shockplan import``
  (:mod:`ident.data.formats.channel_map`), one ``[channels.<canonical>]`` table per
  channel with ``source``, ``units``, ``sign``, optional ``scale`` and ``offset``
  (``x_si = sign * factor(units) * scale * (raw - offset)``), and an optional top-level
  ``time`` naming the time column (default ``time``). The map gives every channel's
  unit: `units` is not used.
- **MDF4 / MDF3** (``.mf4``, ``.mdf``), **TDMS** (``.tdms``) and **RPC III** (``.rsp``,
  ``.tim``, ``.drv``) files, through a channel map and the readers of
  :mod:`ident.data.formats`.

The format is `format` (``"csv"``, ``"parquet"``, ``"rpc3"``, ``"mdf"``, ``"tdms"``), else
the file's suffix (:data:`SUFFIX_FORMATS`), else its first bytes
(:func:`ident.data.formats.sniff_format`).

Mixed rates
-----------
Loggers sample channels at different rates (potentiometers at 500 Hz, the speed at
20 Hz). In an MDF, TDMS or RPC III file whose mapped channels carry their own time bases,
the time base of ``shock_travel_LF`` is the log's: it must be uniform; a channel on
another base, sampled no faster, is interpolated linearly onto it (its name is recorded
in ``settings["resampled"]`` and logged at info level). The channel must cover the
travel's time span to within one of its own sample intervals (beyond its first and last
samples, their values hold). A channel sampled faster than the travel (by more than
:data:`RTOL_SAME_RATE`, 1 %) is refused: picking its samples would alias what lies above
the travel's Nyquist frequency into the log. A map's ``time``
channel gives every channel one time base instead (all of one length).

Refusals
--------
Every refusal is one :class:`~ident.errors.TrackLogError` (a
:class:`~ident.errors.SessionError`) sentence naming the file, the channel and the fix: a
missing file or an unknown format; no shock travel at some corners; NaN/inf values (with
the time of the first); time not strictly increasing or not uniform; fewer than 2
samples; only some of the three aero channels; a unit marker contradicting `units`; a map
naming a source the file lacks (did you mean); a map channel that is not a track-log
channel; a channel of another rate that is faster than the travel or does not cover it.

Examples
--------
>>> import os, tempfile
>>> t = np.arange(1000) / 500.0
>>> travel = {f"shock_travel_{c}": 0.01 * np.sin(2 * np.pi * 2.0 * t) for c in CORNERS}
>>> lap = TrackLog(name="lap", fs_hz=500.0, channels={**travel, "speed": 50.0 + t})
>>> path = write_track_log(lap, os.path.join(tempfile.mkdtemp(), "lap.csv"), units="imperial")
>>> back = read_track_log(path)
>>> back.n_samples, round(back.fs_hz, 9), back.settings["units"], round(back.duration_s, 9)
(1000, 500.0, 'imperial', 2.0)
>>> round(float(back.channels["speed"][500]), 12)  # written in in/s, read back in m/s
51.0
>>> window = track_section(back, 0.5, 1.5)
>>> window.n_samples, window.settings["t0_s"], float(window.time_s[-1])
(500, 0.5, 0.998)
"""

from __future__ import annotations

import logging
import math
import numbers
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident.data.channels import (AERO_INPUTS, ALL_CHANNELS, CORNERS, TRACK_CHANNELS,
                                 missing_aero, quantity_of)
from ident.data.files import did_you_mean, resolve_units, write_table_file
from ident.data.formats.channel_map import ChannelMap, read_channel_map
from ident.data.formats.engine import (check_time_base, mapped_channel_si, mapped_time_base,
                                      missing_source_error, read_mapped_raw)
from ident.data.formats.record import FORMAT_NAMES, sniff_format
from ident.data.runs import (RTOL_TIME_STEP, check_columns, frozen_array,
                             read_table_columns)
from ident.data.units import check_units, from_si
from ident.data.timebase import TimeRecord
from ident.errors import SessionError, TrackLogError

__all__ = [
    "TRACK_LOG_RESPONSES",
    "TRACK_LOG_CHANNELS",
    "TRACK_LOG_FORMATS",
    "SUFFIX_FORMATS",
    "RTOL_SECTION_SAMPLE",
    "RTOL_SAME_RATE",
    "TrackLog",
    "read_track_log",
    "write_track_log",
    "track_section",
]

logger = logging.getLogger(__name__)

#: The response kinds a track log may hold, each at the four corners.
_RESPONSE_KINDS = ("shock_travel", "ride_height", "wheel_accel", "chassis_accel")
#: The response channels a log may hold: ``shock_travel_XX``, ``ride_height_XX``,
#: ``wheel_accel_XX``, ``chassis_accel_XX`` (``XX`` in :data:`ident.data.channels.CORNERS`).
TRACK_LOG_RESPONSES = tuple(f"{k}_{c}" for k in _RESPONSE_KINDS for c in CORNERS)
#: Every channel a log may hold, in the order of :attr:`TrackLog.channels`: the responses,
#: ``speed``, then the logged aero loads.
TRACK_LOG_CHANNELS = TRACK_LOG_RESPONSES + TRACK_CHANNELS + AERO_INPUTS
#: The file formats a log is read from (values of ``format``).
TRACK_LOG_FORMATS = ("csv", "parquet", "rpc3", "mdf", "tdms")
#: The format of each known file suffix (lower case); other suffixes are sniffed.
SUFFIX_FORMATS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".mf4": "mdf",
                  ".mdf": "mdf", ".mf4z": "mdf", ".tdms": "tdms", ".rsp": "rpc3",
                  ".tim": "rpc3", ".drv": "rpc3"}
#: A window's bound within this fraction of a sample interval of a sample's time counts as
#: that time (:func:`track_section`): ``1.1`` s at 200 Hz is sample 220, although
#: ``1.1 * 200`` is ``220.00000000000003`` in floating point.
RTOL_SECTION_SAMPLE = 1e-6

#: A channel on its own time base counts as sampled faster than the travel (and is refused)
#: when its mean rate exceeds the travel's by more than this fraction: the buses of one
#: logger drift by parts per thousand, and content within 1 % above the travel's Nyquist
#: frequency is a negligible part of any channel.
RTOL_SAME_RATE = 0.01

_TRAVELS = tuple(f"shock_travel_{c}" for c in CORNERS)
_TIME = "time"
#: What ``sniff_format`` answers -> the log format it means.
_SNIFFED = {"mdf": "mdf", "zip": "mdf", "tdms": "tdms", "rpc3": "rpc3", "parquet": "parquet",
            "text": "csv"}
_LOG_CHANNELS_TEXT = ("shock_travel_XX, ride_height_XX, wheel_accel_XX, chassis_accel_XX, "
                      "speed, aero_heave, aero_roll and aero_pitch")


# --------------------------------------------------------------------------------------
# The log
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False, repr=False)
class TrackLog(TimeRecord):
    """The channels a car's data logger recorded on track, in SI on one uniform time base.

    Attributes
    ----------
    name : str
        The log's name (default when read: the file name without its suffix).
    fs_hz : float
        Sample rate [Hz]; sample ``k`` is at ``k / fs_hz`` from the first.
    channels : dict of str to ndarray, shape (n_samples,)
        Canonical channel (:data:`TRACK_LOG_CHANNELS`) -> samples in SI with shockplan's
        signs (float64, read-only), in that order: ``shock_travel_XX`` at all four corners
        [m], optionally ``ride_height_XX`` [m], ``wheel_accel_XX`` and
        ``chassis_accel_XX`` [m/s^2], ``speed`` [m/s], and ``aero_heave`` [N],
        ``aero_roll`` and ``aero_pitch`` [N*m] (all three or none).
    settings : dict
        How the log was read (a copy is kept): ``source`` (the file, str), ``format``
        (``"csv"``, ``"parquet"``, ``"rpc3"``, ``"mdf"``, ``"tdms"``), ``units`` (the unit
        system of a file with canonical names; ``None`` when a channel map gave every
        channel's unit), ``map`` (the channel map's file, its name for a map built in
        memory, or ``None``), ``t0_s`` (the time of the first sample in the file [s]),
        ``resampled`` (the channels interpolated onto the travel's time base, list of
        str); a section adds ``section_s`` (its window in the log it was cut from [s]).

    Raises
    ------
    TrackLogError
        On construction, if the name is empty, `fs_hz` is not a positive number, a
        channel is unknown, a shock travel is missing, only some of the three aero
        channels are given, a channel is not numeric or not one-dimensional, the
        channels differ in length, a value is NaN/inf, or there are fewer than 2 samples.

    Notes
    -----
    Signs (the rig-session spec): shock travel compression positive; ride height,
    accelerations and ``aero_heave`` up positive; ``aero_roll`` raises the left side,
    ``aero_pitch`` the rear.
    """

    name: str
    fs_hz: float
    channels: dict
    settings: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise TrackLogError(f"track log name must be a non-empty string, got "
                                f"{self.name!r}; name the log")
        where = f"track log {self.name!r}"
        fs = self.fs_hz
        if isinstance(fs, bool) or not isinstance(fs, numbers.Real) or \
                not math.isfinite(fs) or fs <= 0:
            raise TrackLogError(f"{where}: fs_hz = {fs!r} must be a positive sample rate [Hz]")
        if not isinstance(self.channels, Mapping):
            raise TrackLogError(f"{where}: channels must be a mapping of canonical channel "
                                f"-> samples, got {type(self.channels).__name__}")
        unknown = [c for c in self.channels if c not in TRACK_LOG_CHANNELS]
        if unknown:
            hint = did_you_mean(unknown[0], TRACK_LOG_CHANNELS)
            raise TrackLogError(f"{where}: unknown channel(s) {unknown}{hint}; a track log "
                                f"holds {_LOG_CHANNELS_TEXT} (XX a corner)")
        missing = [c for c in _TRAVELS if c not in self.channels]
        if missing:
            raise TrackLogError(f"{where}: no shock travel at {_corners(missing)}; a track log "
                                "holds shock_travel_XX at all four corners")
        partial = missing_aero(self.channels)
        if partial:
            raise TrackLogError(f"{where}: has aero loads but not {partial}; give all three "
                                "of aero_heave, aero_roll, aero_pitch or none")
        channels, n = {}, None
        for c in TRACK_LOG_CHANNELS:
            if c not in self.channels:
                continue
            try:
                x = frozen_array(self.channels[c])
            except (TypeError, ValueError):
                raise TrackLogError(f"{where}: channel {c!r} is not numeric; give float "
                                    "samples") from None
            if x.ndim != 1:
                raise TrackLogError(f"{where}: channel {c!r} must be one-dimensional "
                                    f"(n_samples,), got shape {x.shape}")
            if n is not None and x.size != n:
                raise TrackLogError(f"{where}: channel {c!r} has {x.size} samples but "
                                    f"shock_travel_LF has {n}; give every channel the same "
                                    "number of samples")
            n = x.size
            bad = ~np.isfinite(x)
            if bad.any():
                raise TrackLogError(
                    f"{where}: channel {c!r} has {int(bad.sum())} NaN/inf value(s) from "
                    f"t={np.argmax(bad) / fs:.6g} s; fill or cut the log")
            channels[c] = x
        if n < 2:
            raise TrackLogError(f"{where}: has {n} sample(s); a track log needs at least 2")
        object.__setattr__(self, "fs_hz", float(fs))
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "settings", dict(self.settings))

    def __repr__(self):
        return (f"TrackLog(name={self.name!r}, fs_hz={self.fs_hz:g}, "
                f"n_samples={self.n_samples}, duration_s={self.duration_s:g}, "
                f"channels={list(self.channels)})")


def _corners(channels):
    return ", ".join(c.rpartition("_")[2] for c in channels)


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------


def _log_format(path, format, *, where):
    """The log's format: `format` if given, else from the suffix, else from the bytes."""
    if format is not None:
        fmt = format.strip().lower() if isinstance(format, str) else format
        if fmt not in TRACK_LOG_FORMATS:
            hint = did_you_mean(fmt, TRACK_LOG_FORMATS, cutoff=0.6)
            raise TrackLogError(f"{where}: unknown format {format!r}{hint}; give one of "
                                f"{', '.join(TRACK_LOG_FORMATS)} (--format)")
    if not path.exists():
        raise TrackLogError(f"{where}: file not found; check the path")
    if not path.is_file():
        raise TrackLogError(f"{where}: is not a file; give the path of a track log file")
    if format is not None:
        return fmt
    suffix = path.suffix.lower()
    if suffix in SUFFIX_FORMATS:
        return SUFFIX_FORMATS[suffix]
    kind = sniff_format(path)
    if kind in _SNIFFED:
        return _SNIFFED[kind]
    seen = ("it is empty" if kind == "empty" else
            f"its first bytes look like {kind or 'nothing known'}")
    raise TrackLogError(
        f"{where}: unknown format (suffix {path.suffix!r}, and {seen}); give the format "
        f"with format= (--format), one of {', '.join(TRACK_LOG_FORMATS)}, or use a file of "
        "one of those")


def _log_map(channel_map, *, where):
    """The channel map as a :class:`ChannelMap` that fits a track log (checked)."""
    if isinstance(channel_map, ChannelMap):
        cmap = channel_map
    elif isinstance(channel_map, (str, os.PathLike)):
        cmap = read_channel_map(channel_map, allowed=ALL_CHANNELS + TRACK_CHANNELS)
    else:
        raise TypeError(f"{where}: channel_map must be a ChannelMap or the path of a "
                        f"channel-map TOML file, got {type(channel_map).__name__}")
    other = [c for c in cmap.channels if c not in TRACK_LOG_CHANNELS]
    if other:
        raise TrackLogError(
            f"{cmap.where}: [channels.{other[0]}] maps {other[0]!r}, which is not a track-log "
            f"channel (reading {where}); a track log's channels are {_LOG_CHANNELS_TEXT}: "
            "remove the table from the map for track logs")
    missing = [c for c in _TRAVELS if c not in cmap.channels]
    if missing:
        tables = ", ".join(f"[channels.{c}]" for c in missing)
        raise TrackLogError(
            f"{cmap.where}: maps no shock travel at {_corners(missing)} (reading {where}); a "
            f"track log needs shock travel at all four corners: add {tables} naming the "
            "logger's damper-travel channels")
    partial = missing_aero(cmap.channels)
    if partial:
        raise TrackLogError(
            f"{cmap.where}: maps some aero loads but not {partial} (reading {where}); the "
            "aero loads come all three (aero_heave, aero_roll, aero_pitch) or none: map the "
            "missing ones or remove the others")
    return cmap


def _read_table(path, fmt, cmap, units, *, where, resample_hz=None):
    """Read a CSV or Parquet log: (times [s], SI channels, units read in or None)."""
    columns, marker = read_table_columns(path, where=where, kind=fmt)
    if cmap is None:
        if _TIME not in columns:
            raise TrackLogError(
                f"{where}: no 'time' column; name the column of sample times [s] 'time', or "
                "read the log through a channel map whose top-level time = \"...\" names it")
        missing = [c for c in _TRAVELS if c not in columns]
        if missing:
            names = ", ".join(missing)
            raise TrackLogError(
                f"{where}: no shock travel at {_corners(missing)} (no column {names}); name "
                "the columns shock_travel_XX, or map the logger's columns with "
                "[channels.shock_travel_XX] tables in a channel map (channel_map=, --map)")
        partial = missing_aero(columns)
        if partial:
            raise TrackLogError(
                f"{where}: has aero-load columns but not {partial}; the aero loads come all "
                "three (aero_heave, aero_roll, aero_pitch) or none: add the missing columns "
                "or remove the others")
        units = resolve_units(marker, units, where=where, given_as="--units",
                              error=TrackLogError)
        t, channels, _ = check_columns(columns, where=where, units=units, channel_map={},
                                       required=_TRAVELS, names=TRACK_LOG_CHANNELS,
                                       resample_hz=resample_hz)
        return t, channels, units

    time_column = cmap.time or _TIME
    absent = [(c, s.source) for c, s in cmap.channels.items() if s.source not in columns]
    if time_column not in columns:
        if cmap.time is None:
            raise TrackLogError(
                f"{where}: no 'time' column; name the time column with time = \"...\" at the "
                f"top of {cmap.where} (or call it 'time' in the file)")
        absent.insert(0, (_TIME, cmap.time))
    if absent:
        raise missing_source_error(absent, list(columns), where=where, map_where=cmap.where,
                                   noun="column", error=TrackLogError)
    sources = {_TIME: time_column, **cmap.sources}
    t, raw, _ = check_columns(columns, where=where, units="SI", channel_map=sources,
                              required=tuple(cmap.channels), names=tuple(cmap.channels),
                              resample_hz=resample_hz)
    channels = {c: mapped_channel_si(spec, raw[c], t, where=where)
                for c, spec in cmap.channels.items()}
    return t, channels, None


def _onto(t, typical, tc, x, *, canonical, source, reference, where):
    """Interpolate one channel (times `tc`, SI values `x`) linearly onto times `t`."""
    m = tc.size
    if m < 2:
        raise TrackLogError(
            f"{where}: channel {source!r} ({canonical}) has {m} sample(s) on its own time "
            "base, too few to interpolate onto the travel's; check the export or leave the "
            "channel out of the map")
    bad = ~(np.diff(tc) > 0) | ~np.isfinite(tc[1:])
    if bad.any() or not math.isfinite(tc[0]):
        i = int(np.argmax(bad)) if bad.any() else 0
        raise TrackLogError(
            f"{where}: the time of {source!r} ({canonical}) is not finite and strictly "
            f"increasing at sample {i + 1} (t={tc[i]:.9g} s then {tc[min(i + 1, m - 1)]:.9g} "
            "s); check the export")
    step = (tc[-1] - tc[0]) / (m - 1)
    if step < typical * (1.0 - RTOL_SAME_RATE):
        raise TrackLogError(
            f"{where}: channel {source!r} ({canonical}) is sampled faster ({1 / step:.6g} Hz) "
            f"than the shock travel {reference!r} ({1 / typical:.6g} Hz), the log's time "
            "base; its samples cannot be picked without aliasing: export it at the travel's "
            "rate (low-pass filtered) or leave it out of the map")
    slack = step + RTOL_TIME_STEP * typical
    if tc[0] > t[0] + slack or tc[-1] < t[-1] - slack:
        raise TrackLogError(
            f"{where}: channel {source!r} ({canonical}) covers t={tc[0]:.6g}..{tc[-1]:.6g} s "
            f"but the shock travel {reference!r} covers t={t[0]:.6g}..{t[-1]:.6g} s; a "
            "channel must cover the travel's span (to within one of its own samples): cut "
            "the log to the common span in the export or leave the channel out of the map")
    y = np.interp(t, tc, x)
    y.flags.writeable = False
    return y


def _read_file(path, fmt, cmap, *, where, resample_hz=None):
    """Read an MDF, TDMS or RPC III log: (times [s], SI channels, resampled channels)."""
    if cmap is None:
        raise TrackLogError(
            f"{where}: {FORMAT_NAMES[fmt]} files are read through a channel map; give one "
            "(channel_map=, --map MAP.toml) with a [channels.shock_travel_XX] table per corner "
            "naming the logger's channels")
    raw = read_mapped_raw(path, format=fmt, channel_map=cmap, where=where)
    t, reference = mapped_time_base(raw, cmap, where=where, reference=_TRAVELS[0],
                                    error=TrackLogError)
    t = np.asarray(t, dtype=np.float64)
    if cmap.time is not None:
        for canonical, spec in cmap.channels.items():
            m = raw.channels[spec.source].size
            if m != t.size:
                raise TrackLogError(
                    f"{where}: channel {spec.source!r} ({canonical}) has {m} samples but the "
                    f"map's time channel {cmap.time!r} has {t.size}; with time = \"...\" in "
                    f"{cmap.where} every channel is of that one acquisition: remove time to "
                    "use each channel's own time base")
    if t.size < 2:
        raise TrackLogError(f"{where}: has {t.size} sample(s) of {reference!r}; a track log "
                            "needs at least 2")
    base = check_time_base(t, source=reference, where=where, error=TrackLogError,
                           resample_hz=resample_hz)
    typical = float(np.median(np.diff(t)))

    channels, resampled = {}, []
    for canonical, spec in cmap.channels.items():
        x_raw = raw.channels[spec.source]
        if cmap.time is not None:
            channels[canonical] = base.resample(mapped_channel_si(spec, x_raw, t, where=where))
            continue
        tc, _ = mapped_time_base(raw, cmap, where=where, reference=canonical,
                                 error=TrackLogError)
        tc = np.asarray(tc, dtype=np.float64)
        if tc.size == t.size and np.max(np.abs(tc - t)) <= RTOL_TIME_STEP * typical:
            channels[canonical] = base.resample(mapped_channel_si(spec, x_raw, t, where=where))
            continue
        x = mapped_channel_si(spec, x_raw, tc, where=where)
        channels[canonical] = _onto(base.time_s, typical, tc, x, canonical=canonical,
                                    source=spec.source, reference=reference, where=where)
        resampled.append(canonical)
    if resampled:
        logger.info("%s: %s interpolated linearly onto the time base of %r (%.6g Hz)", where,
                    ", ".join(resampled), reference, base.fs_hz)
    return base.time_s, channels, resampled


def read_track_log(path, *, channel_map=None, units=None, format=None, name=None,
                   resample_hz=None):
    """Read a track log: a data logger's file, as SI canonical channels on one time base.

    Parameters
    ----------
    path : str or os.PathLike
        The log: CSV (header row after any ``#`` comment lines) or Parquet, with canonical
        column names or read through `channel_map`; or an MDF, TDMS or RPC III file read
        through `channel_map` (the module docstring lists the channels and formats).
    channel_map : ChannelMap or str or os.PathLike, optional
        The channel map (``format = "channel-map/1"``, as ``shockplan import``) or its
        TOML file, naming the logger's channel for each canonical channel, with its unit,
        sign, scale and offset; ``speed`` may be mapped. Required for MDF, TDMS and RPC
        III files. With a map, only the mapped channels (and time) are read.
    units : {"SI", "imperial"}, optional
        Unit system of a file with canonical names (``--units``). Default: the file's unit
        marker, else SI; given, it must agree with the marker. Not used with a map (the
        map gives every channel's unit).
    format : {"csv", "parquet", "rpc3", "mdf", "tdms"}, optional
        The file's format (default: from its suffix, :data:`SUFFIX_FORMATS`, else its
        first bytes).
    name : str, optional
        The log's name (default: the file name without its suffix).
    resample_hz : float, optional
        Resample the log onto a uniform base at this rate [Hz] (``--resample``, e.g. the
        model's rate; band-limited, anti-aliased when going down:
        :func:`ident.data.timebase.uniform_time_base`), said in a logged warning; recorded
        as ``settings["resample_hz"]``. Default: the logger's rate (jittered time stamps
        resampled onto it).

    Returns
    -------
    TrackLog
        SI channels, each shape (n_samples,), on the uniform time base of the file's
        ``time`` (or of ``shock_travel_LF`` in an MDF, TDMS or RPC III file, the other
        channels interpolated onto it where they have their own), time restarting at 0;
        ``settings`` records the file, format, units, map, the first sample's time in the
        file and the channels interpolated.

    Raises
    ------
    TrackLogError
        One sentence naming the file, the channel and the fix, if: `format` is unknown, or
        the file is missing or of no known format; the log has no shock travel at some
        corner (the message names the corners); a value is NaN/inf (with the time of the
        first) or not numeric; time is not strictly increasing or not uniform (relative
        tolerance :data:`ident.data.runs.RTOL_TIME_STEP`); fewer than 2 samples; only
        some of the three aero channels; the unit marker contradicts `units`; the map
        names a source the file lacks (did you mean), maps a channel a track log does not
        hold, or is not a valid channel map; an MDF, TDMS or RPC III file comes without a
        map; a channel on another time base is sampled faster than the travel or does not
        cover its span.
    TypeError
        If `channel_map` is neither a ChannelMap nor a path.

    Examples
    --------
    >>> import os, tempfile
    >>> folder = tempfile.mkdtemp()
    >>> csv = os.path.join(folder, "lap.csv")
    >>> rows = "".join(f"{k / 100},{k + 1},{k + 1},{-k - 1},{-k - 1},{40 + k}\\n" for k in range(4))
    >>> _ = open(csv, "w").write("Time,PotLF,PotRF,PotLR,PotRR,GPS Speed\\n" + rows)
    >>> cmap = os.path.join(folder, "logger.toml")
    >>> _ = open(cmap, "w").write('format = "channel-map/1"\\ntime = "Time"\\n' + "".join(
    ...     f'[channels.shock_travel_{c}]\\nsource = "Pot{c}"\\nunits = "mm"\\n'
    ...     f'sign = {1 if c[1] == "F" else -1}\\n' for c in CORNERS)
    ...     + '[channels.speed]\\nsource = "GPS Speed"\\nunits = "m/s"\\nsign = 1\\n')
    >>> log = read_track_log(csv, channel_map=cmap)
    >>> round(log.fs_hz, 9), [float(v) for v in log.channels["shock_travel_RR"]]
    (100.0, [0.001, 0.002, 0.003, 0.004])
    >>> list(log.channels)[-1], log.settings["units"]
    ('speed', None)
    """
    path = Path(path)
    where = f"track log {path}"
    try:
        fmt = _log_format(path, format, where=where)
        cmap = None if channel_map is None else _log_map(channel_map, where=where)
        if units is not None:
            units = check_units(units, where=f"{where}: --units", error=TrackLogError)
            if cmap is not None:
                logger.info("%s: units=%r not used: the channel map %s gives every "
                            "channel's unit", where, units, cmap.where)
        if fmt in ("csv", "parquet"):
            t, channels, units = _read_table(path, fmt, cmap, units, where=where,
                                             resample_hz=resample_hz)
            resampled = []
        else:
            t, channels, resampled = _read_file(path, fmt, cmap, where=where,
                                                resample_hz=resample_hz)
            units = None
    except TrackLogError:
        raise
    except SessionError as exc:  # the shared engines' refusals, as this family's
        raise TrackLogError(str(exc)) from None
    n = t.size
    fs_hz = float((n - 1) / (t[-1] - t[0]))
    if cmap is None:
        map_setting = None
    else:
        map_setting = str(cmap.path) if cmap.path is not None else cmap.name
    settings = {"source": str(path), "format": fmt, "units": units, "map": map_setting,
                "t0_s": float(t[0]), "resampled": resampled}
    if resample_hz is not None:
        fs_hz = float(resample_hz)  # exactly the rate asked for, not its rounded estimate
        settings["resample_hz"] = fs_hz
    log = TrackLog(name=name or path.stem, fs_hz=fs_hz, channels=channels, settings=settings)
    logger.info("%s: %d channel(s) x %d samples at %.6g Hz (%s)", where, len(log.channels),
                n, fs_hz, fmt)
    return log


# --------------------------------------------------------------------------------------
# Writing and sections
# --------------------------------------------------------------------------------------


def write_track_log(log, path, *, units="SI", overwrite=False):
    """Write a track log as a canonical CSV or Parquet file, atomically.

    Parameters
    ----------
    log : TrackLog
        The log.
    path : str or os.PathLike
        The file: ``.csv``, or ``.parquet`` / ``.pq`` for Parquet.
    units : {"SI", "imperial"}
        Unit system of the written values (converted from SI by each channel's quantity;
        ``speed`` in in/s when imperial).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    TypeError
        If `log` is not a :class:`TrackLog`.
    TrackLogError
        If the suffix is not a table's or `units` is not a unit system.
    FileExistsError
        If `path` exists and `overwrite` is false.

    Notes
    -----
    The columns are ``time`` [s] then the log's channels, under canonical names. ``time``
    is ``settings["t0_s"] + k / fs_hz``: a written section keeps its times in the log it
    was cut from. The file says its unit system (a CSV's last column ``units``, a
    Parquet file's metadata ``units``), so :func:`read_track_log` reads it back without
    being told: values equal to float64 rounding (1e-12 relative) in imperial, bit for
    bit in SI.
    """
    # pandas only where a table is made, as in ident.data.runs (importing the package
    # stays light)
    import pandas as pd

    if not isinstance(log, TrackLog):
        raise TypeError(f"write_track_log: log must be a TrackLog, got {type(log).__name__}")
    path = Path(path)
    kind = SUFFIX_FORMATS.get(path.suffix.lower())
    if kind not in ("csv", "parquet"):
        raise TrackLogError(f"{path}: a track log is written as CSV (.csv) or Parquet "
                            f"(.parquet), not {path.suffix!r}; change the file name")
    units = check_units(units, where=f"{path}: units", error=TrackLogError)
    t0 = float(log.settings.get("t0_s", 0.0))
    frame = pd.DataFrame({_TIME: t0 + log.time_s,
                          **{c: from_si(x, quantity_of(c), units)
                             for c, x in log.channels.items()}})
    write_table_file(frame, path, kind=kind, units=units, overwrite=overwrite)
    logger.info("wrote track log %r to %s (%s, %d samples)", log.name, path, units,
                log.n_samples)
    return path


def _seconds(value, what, *, where):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{where}: {what} must be a number of seconds, got "
                        f"{type(value).__name__}")
    if not math.isfinite(value):
        raise TrackLogError(f"{where}: {what} = {value!r} must be a finite time [s]")
    return float(value)


def track_section(log, start_s, stop_s, *, name=None):
    """Cut a window out of a track log: the samples with ``start_s <= t < stop_s``.

    Parameters
    ----------
    log : TrackLog
        The log.
    start_s, stop_s : float
        The window [s], in time from the log's first sample (``log.time_s``, 0-based),
        ``0 <= start_s < stop_s <= log.duration_s``. A bound within
        :data:`RTOL_SECTION_SAMPLE` of a sample interval of a sample's time is that time.
    name : str, optional
        The section's name (default ``"<log name>_<start>-<stop>s"``).

    Returns
    -------
    TrackLog
        The window's samples of every channel (copies), the log's rate; ``settings`` as the
        log's with ``t0_s`` the window's first sample's time in the file and ``section_s``
        the window ``[start_s, stop_s]``.

    Raises
    ------
    TypeError
        If `log` is not a TrackLog or a bound is not a number.
    TrackLogError
        If the window is not inside the log (a bound below 0 or beyond its duration,
        or ``start_s >= stop_s``) or holds fewer than 2 samples; the message names the
        log and the window.

    Examples
    --------
    >>> lap = TrackLog(name="lap", fs_hz=10.0,
    ...                channels={f"shock_travel_{c}": np.arange(20.0) for c in CORNERS})
    >>> part = track_section(lap, 0.5, 1.0)
    >>> part.name, part.channels["shock_travel_LF"].tolist()
    ('lap_0.5-1s', [5.0, 6.0, 7.0, 8.0, 9.0])
    """
    if not isinstance(log, TrackLog):
        raise TypeError(f"track_section: log must be a TrackLog, got {type(log).__name__}")
    where = f"track log {log.name!r}"
    start = _seconds(start_s, "start_s", where=where)
    stop = _seconds(stop_s, "stop_s", where=where)
    fs, duration = log.fs_hz, log.duration_s
    slack = RTOL_SECTION_SAMPLE / fs
    window = f"the window {start:g}..{stop:g} s"
    if start < -slack or stop > duration + slack or start >= stop:
        raise TrackLogError(
            f"{where}: {window} is not inside the log's 0..{duration:g} s; give "
            f"0 <= start_s < stop_s <= {duration:g} (seconds from the log's first sample)")
    k0 = max(0, math.ceil(start * fs - RTOL_SECTION_SAMPLE))
    k1 = min(log.n_samples, math.ceil(stop * fs - RTOL_SECTION_SAMPLE))
    if k1 - k0 < 2:
        raise TrackLogError(
            f"{where}: {window} holds {max(k1 - k0, 0)} sample(s) at {fs:g} Hz; give a window "
            f"of at least 2 samples ({2 / fs:g} s)")
    settings = dict(log.settings)
    settings["t0_s"] = float(settings.get("t0_s", 0.0)) + k0 / fs
    settings["section_s"] = [start, stop]
    return TrackLog(name=name or f"{log.name}_{start:g}-{stop:g}s", fs_hz=fs,
                    channels={c: x[k0:k1] for c, x in log.channels.items()},
                    settings=settings)
