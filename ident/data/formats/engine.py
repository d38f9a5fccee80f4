"""The engine behind every format: read a file, map it, check it, import it into a session."""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ident.data.channels import AERO_INPUTS, CORNERS, RIG_INPUTS, WHEELLOADER_INPUTS
from ident.data.files import did_you_mean, round_file_numbers
from ident.errors import SessionError
from ident.data.formats.record import FORMAT_NAMES, FORMATS
from ident.data.formats.channel_map import ChannelMap, read_channel_map
from ident.data.formats.mdf import read_mdf
from ident.data.formats.rpc3 import read_rpc3
from ident.data.formats.tdms import read_tdms
from ident.data.runs import RTOL_TIME_STEP, RunTable
from ident.data.session import (
    MANIFEST_NAME,
    RUN_ROLES,
    Run,
    append_runs,
    make_session,
    read_session,
    write_session,
)
from ident.models.library import ShockLibrary, read_shock_library
from ident.data.timebase import uniform_time_base
from ident.data.units import check_units

__all__ = ["READERS", "read_raw", "read_mapped_raw", "check_time_base", "mapped_channel_si",
           "read_run", "import_runs", "parse_setup", "as_channel_map", "missing_source_error",
           "mapped_time_base"]

logger = logging.getLogger(__name__)

#: The reader of each format: ``reader(path, *, channels=None, where=None) -> RawRecord``.
READERS = {"rpc3": read_rpc3, "mdf": read_mdf, "tdms": read_tdms}
#: Longest list of a file's channels quoted in a message.
_MAX_LISTED = 30


def _check_format(format):
    if format not in FORMATS:
        raise SessionError(
            f"unknown format {format!r}; use one of {', '.join(FORMATS)} "
            "(RPC III, MDF, TDMS)"
        )
    return format


def as_channel_map(channel_map):
    """Return `channel_map` as a :class:`ChannelMap` (read it if it is a path).

    Raises
    ------
    TypeError
        If it is neither a ChannelMap nor a path.
    SessionError
        If the file is not a valid channel map (:func:`read_channel_map`).
    """
    if isinstance(channel_map, ChannelMap):
        return channel_map
    if isinstance(channel_map, (str, os.PathLike)):
        return read_channel_map(channel_map)
    raise TypeError(f"channel_map must be a ChannelMap or the path of a channel-map TOML "
                    f"file, got {type(channel_map).__name__}")


def _listing(names):
    names = list(names)
    if len(names) <= _MAX_LISTED:
        return repr(names)
    return f"{names[:_MAX_LISTED]!r} and {len(names) - _MAX_LISTED} more"


def missing_source_error(absent, available, *, where, map_where, noun="channel",
                         candidates=None, error=SessionError):
    """The error for mapped sources a file lacks: the first named, with a did-you-mean.

    One sentence for every reader of mapped files (rig runs, track logs): the missing
    source, the canonical channel it was mapped to and by which map, how many more are
    missing, and the file's own names (the first 30).

    Parameters
    ----------
    absent : sequence of (str, str)
        ``(canonical, source)`` of each mapped source the file lacks, the first reported.
    available : sequence of str
        The file's channel (or column) names, as listed in the message.
    where, map_where : str
        The file and the map, as named in messages.
    noun : str
        What the file's names are (``"channel"``, ``"column"``).
    candidates : sequence of str, optional
        The names a typo is matched against (default: `available`).
    error : type
        The exception class returned.

    Returns
    -------
    Exception
        An instance of `error`, for the caller to raise.
    """
    canonical, source = absent[0]
    more = f", {len(absent)} mapped {noun}s are missing" if len(absent) > 1 else ""
    hint = did_you_mean(source, available if candidates is None else candidates, cutoff=0.6)
    return error(
        f"{where}: has no {noun} {source!r}{hint} (mapped to {canonical} by "
        f"{map_where}{more}); the file has {_listing(available)}: fix the map's source names "
        "or check the file"
    )


def read_raw(path, *, format, channels=None, where=None):
    """Read a rig data file of the given format, as stored (no map).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    format : {"rpc3", "mdf", "tdms"}
        Its format.
    channels : iterable of str, optional
        Source channel names to read (default all).
    where : str, optional
        How to name the file in messages.

    Returns
    -------
    RawRecord

    Raises
    ------
    SessionError
        If `format` is unknown, or the reader refuses the file (missing, not
        of that format, damaged).
    """
    return READERS[_check_format(format)](path, channels=channels, where=where)


def mapped_time_base(raw, cmap, *, where, reference=None, error=SessionError):
    """Return the times [s] the mapped channels are read on, and the channel they came from.

    The map's ``time`` channel if it names one, else the file's own time base of the
    `reference` channel's source.

    Parameters
    ----------
    raw : RawRecord
        The file's channels (:func:`read_mapped_raw`).
    cmap : ChannelMap
        The map.
    where : str
        The file, as named in messages.
    reference : str, optional
        The canonical channel whose time base is taken when the map names no ``time``
        (default: the map's first channel).
    error : type
        The exception class raised.

    Returns
    -------
    times : ndarray, shape (n_samples,)
        As stored in the file [s].
    source : str
        The file's channel the times belong to.

    Raises
    ------
    SessionError
        (or `error`) If the channel has no time base in the file.
    """
    if cmap.time is not None:
        return raw.channels[cmap.time], cmap.time
    canonical = next(iter(cmap.channels)) if reference is None else reference
    source = cmap.channels[canonical].source
    t = raw.time_s.get(source)
    if t is None:
        raise error(
            f"{where}: channel {source!r} ({canonical}) has no time base in the "
            f"file (no waveform properties); name the channel holding time in seconds "
            f"with time = \"...\" at the top of {cmap.where}"
        )
    return t, source


def read_mapped_raw(path, *, format, channel_map, where=None):
    """Read the channels a channel map names from a rig data file, checked against the map.

    The first half of :func:`read_run`, shared with the track-log reader
    (:mod:`ident.data.tracklog`): the file is read and the map's sources looked up; nothing
    about lengths, times or values is checked here.

    Parameters
    ----------
    path : str or os.PathLike
        An RPC III, MDF or TDMS file.
    format : {"rpc3", "mdf", "tdms"}
        The file's format; a file of another format is refused.
    channel_map : ChannelMap or str or os.PathLike
        The map, or its TOML file.
    where : str, optional
        How to name the file in messages (default ``"file <path>"``).

    Returns
    -------
    RawRecord
        The map's source channels (and its ``time`` channel) as stored: raw values, each
        with its own times [s] (or ``None``) and the unit the file gives it.

    Raises
    ------
    SessionError
        One sentence naming the file and the channel, if: `format` is unknown; the file
        is missing, empty, of another format or damaged; the file lacks a mapped source
        channel (did you mean, and the list of the channels it has); the file gives a
        source channel a known unit other than the map's.
    """
    fmt = _check_format(format)
    cmap = as_channel_map(channel_map)
    path = Path(path)
    where = f"file {path}" if where is None else where
    needed = list(cmap.sources.values()) + ([cmap.time] if cmap.time else [])
    raw = READERS[fmt](path, channels=needed, where=where)

    if not raw.available:
        raise SessionError(
            f"{where}: holds no data channels (an empty {FORMAT_NAMES[fmt]} file, or a "
            "damaged one); check the export"
        )
    absent = [(c, s.source) for c, s in cmap.channels.items() if s.source not in raw.channels]
    if cmap.time is not None and cmap.time not in raw.channels:
        absent.insert(0, ("time", cmap.time))
    if absent:
        names = list(raw.available)
        if fmt == "tdms":  # a bare channel name is accepted too
            names += [a.partition("/")[2] for a in raw.available]
        raise missing_source_error(absent, list(raw.available), where=where,
                                   map_where=cmap.where, candidates=names)
    for spec in cmap.channels.values():
        spec.check_file_unit(raw.units.get(spec.source, ""), where=where)
    return raw


def check_time_base(t, *, source, where, error=SessionError, resample_hz=None):
    """Check sample times and give their uniform time base (a logger's jitter resampled).

    Parameters
    ----------
    t : ndarray, shape (n_samples,)
        Sample times [s], at least 2.
    source : str
        The channel the times belong to (named in messages).
    where : str
        How to name the file in messages.
    error : type
        The exception raised.
    resample_hz : float, optional
        The rate [Hz] of a uniform base to resample onto (``--resample``; band-limited,
        anti-aliased when going down). Default: the times' own rate.

    Returns
    -------
    ident.data.timebase.TimeBase
        Uniform as written, or the uniform base jittered times are resampled onto, or
        the one at `resample_hz` (:func:`ident.data.timebase.uniform_time_base`; said in
        a warning).

    Raises
    ------
    error
        If a time is NaN/inf, the times are not strictly increasing, or a step differs
        from the median step by more than :data:`ident.data.timebase.JITTER_RTOL` of it
        (a gap or a changed rate, named at its time).
    """
    if not np.all(np.isfinite(t)):
        raise error(f"{where}: the time of {source!r} has NaN/inf values; check the export")
    base = uniform_time_base(t, where=f"{where}: the time of {source!r}", error=error,
                             row_offset=1, row_label="sample", resample_hz=resample_hz)
    if base.resampled:
        logger.warning(base.describe(where))
    return base


def mapped_channel_si(spec, raw_values, t, *, where):
    """Convert one mapped channel to SI with shockplan's sign, refusing NaN/inf values.

    Parameters
    ----------
    spec : ChannelSpec
        The channel's entry of the map.
    raw_values : array_like, shape (n_samples,)
        Its values as stored in the file.
    t : ndarray, shape (n_samples,)
        Its sample times [s] (to name the first bad sample).
    where : str
        How to name the file in messages.

    Returns
    -------
    ndarray, shape (n_samples,)
        ``spec.to_si(raw_values)``, float64, read-only.

    Raises
    ------
    SessionError
        If a converted value is NaN/inf (the message gives the time of the first).
    """
    x = spec.to_si(raw_values)
    bad = ~np.isfinite(x)
    if bad.any():
        i = int(np.argmax(bad))
        raise SessionError(
            f"{where}: channel {spec.source!r} ({spec.canonical}) has {int(bad.sum())} "
            f"NaN/inf value(s) from t={t[i]:.6g} s; fill or cut the run"
        )
    x.flags.writeable = False
    return x


def read_run(path, *, format, channel_map, required=(), where=None, resample_hz=None):
    """Read one rig data file into SI canonical channels, through a channel map.

    Parameters
    ----------
    path : str or os.PathLike
        An RPC III, MDF or TDMS file.
    format : {"rpc3", "mdf", "tdms"}
        The file's format (``--format``); a file of another format is refused.
    channel_map : ChannelMap or str or os.PathLike
        The map, or its TOML file (:mod:`ident.data.formats.channel_map`).
    required : iterable of str
        Canonical channels the map must map (e.g. the 7 rig inputs for a
        session run); checked before the file is read.
    where : str, optional
        How to name the file in messages (default ``"file <path>"``).
    resample_hz : float, optional
        Resample the run onto a uniform base at this rate [Hz] (``--resample``;
        band-limited, anti-aliased when going down; :func:`check_time_base`), said in
        a logged warning. Default: the file's rate.

    Returns
    -------
    ident.data.runs.RunTable
        ``time_s`` [s] (the file's time base), ``channels`` (every mapped
        channel, SI, shockplan's signs, read-only, in
        :data:`ident.data.channels.ALL_CHANNELS` order), ``fs_hz`` and ``path``.

    Raises
    ------
    SessionError
        One sentence naming the file and the channel, if: `format` is unknown;
        the map lacks a `required` channel; the file is missing, empty, of
        another format or damaged; the file lacks a mapped source channel (the
        message lists the channels it has); the file gives a source channel a
        known unit other than the map's; a channel has no time base and the
        map names no ``time``; the mapped channels differ in length or time
        base; time is not strictly increasing and uniform (relative tolerance
        :data:`ident.data.runs.RTOL_TIME_STEP`); a value is NaN/inf; fewer than
        2 samples.
    """
    fmt = _check_format(format)
    cmap = as_channel_map(channel_map)
    path = Path(path)
    where = f"file {path}" if where is None else where
    missing = [c for c in required if c not in cmap.channels]
    if missing:
        raise SessionError(
            f"{cmap.where}: maps no source for the required channel(s) {missing} (a "
            "session run needs the 4 wheelloaders, and all 3 aero channels on a rig with aero "
            "actuators); add a [channels.<name>] table for each"
        )
    raw = read_mapped_raw(path, format=fmt, channel_map=cmap, where=where)

    t_raw, t_source = mapped_time_base(raw, cmap, where=where)
    t = np.asarray(t_raw, dtype=np.float64)
    n = t.size
    for canonical, spec in cmap.channels.items():
        m = raw.channels[spec.source].size
        if m != n:
            raise SessionError(
                f"{where}: channel {spec.source!r} ({canonical}) has {m} samples but "
                f"{t_source!r} has {n}; map channels of one acquisition rate (resample in "
                "the export)"
            )
    if n < 2:
        raise SessionError(f"{where}: has {n} sample(s); a run needs at least 2")
    base = check_time_base(t, source=t_source, where=where, resample_hz=resample_hz)
    typical = 1.0 / (base.fs_hz if base.native is None else base.native.fs_hz)
    for canonical, spec in cmap.channels.items():
        tc = raw.time_s.get(spec.source)
        if cmap.time is None and tc is not None and \
                np.max(np.abs(tc - t)) > RTOL_TIME_STEP * typical:
            raise SessionError(
                f"{where}: channel {spec.source!r} ({canonical}) is sampled at other times "
                f"than {t_source!r} (they differ by up to {np.max(np.abs(tc - t)):.3g} s); "
                "map channels of one acquisition (one time base)"
            )

    channels = {canonical: base.resample(mapped_channel_si(spec, raw.channels[spec.source], t,
                                                           where=where))
                for canonical, spec in cmap.channels.items()}
    t = np.array(base.time_s)
    t.flags.writeable = False
    logger.info("%s: %d channel(s) x %d samples at %.6g Hz (%s)", where, len(channels),
                t.size, base.fs_hz, FORMAT_NAMES[fmt])
    return RunTable(time_s=t, channels=channels, fs_hz=base.fs_hz, path=path)


def parse_setup(setup, *, shocks=None, where="setup"):
    """Return a setup as ``{corner: shock id}``, checked against a library.

    Parameters
    ----------
    setup : mapping of str to str, or str, or sequence of str
        ``{"LF": id, "RF": id, "LR": id, "RR": id}``, or four ids in
        ``LF, RF, LR, RR`` order as ``"B20,B20,N8,B20"`` (``--setup``) or a
        sequence.
    shocks : ShockLibrary, optional
        Library the ids must be in.
    where : str
        Start of the error message.

    Returns
    -------
    dict of str to str
        In :data:`ident.data.channels.CORNERS` order.

    Raises
    ------
    SessionError
        If a corner is unknown or missing, there are not four ids, or an id
        is not in `shocks` (the message lists the library's ids).
    TypeError
        If `setup` is of another type.

    Examples
    --------
    >>> parse_setup("B20, B20, N8, B20")
    {'LF': 'B20', 'RF': 'B20', 'LR': 'N8', 'RR': 'B20'}
    """
    if isinstance(setup, str):
        setup = [s.strip() for s in setup.split(",")]
    if isinstance(setup, Mapping):
        unknown = [c for c in setup if c not in CORNERS]
        missing = [c for c in CORNERS if c not in setup]
        if unknown or missing:
            raise SessionError(
                f"{where}: {dict(setup)!r} must name exactly the corners {list(CORNERS)} "
                f"(unknown {unknown}, missing {missing})"
            )
        out = {c: setup[c] for c in CORNERS}
    elif isinstance(setup, Sequence):
        if len(setup) != len(CORNERS):
            raise SessionError(
                f"{where}: {list(setup)!r} has {len(setup)} shock id(s); give four, in "
                f"the order {','.join(CORNERS)} (e.g. B20,B20,N8,B20)"
            )
        out = dict(zip(CORNERS, setup))
    else:
        raise TypeError(f"{where}: must be a mapping corner -> shock id or 4 ids "
                        f"'LF,RF,LR,RR', got {type(setup).__name__}")
    for corner, sid in out.items():
        if not isinstance(sid, str) or not sid:
            raise SessionError(f"{where}: {corner} = {sid!r} must be a shock id")
        if shocks is not None and sid not in shocks:
            lib = f" {shocks.source}" if getattr(shocks, "source", None) else ""
            raise SessionError(
                f"{where}: {corner} = {sid!r} is not in the shock library{lib} (ids: "
                f"{', '.join(shocks)}); fix the id or add the shock to the library"
            )
    return out


def _library(shocks, *, where):
    if isinstance(shocks, ShockLibrary):
        return shocks
    if isinstance(shocks, (str, os.PathLike)):
        return read_shock_library(shocks)
    if isinstance(shocks, Mapping):
        return ShockLibrary(shocks)
    raise TypeError(f"{where}: shocks must be a ShockLibrary or the path of a shocks TOML "
                    f"file, got {type(shocks).__name__}")


def _check_same_shocks(given, session, setup, *, where):
    """With an existing session, a given library must agree with its shocks."""
    for sid in dict.fromkeys(setup.values()):
        if sid not in given:
            continue
        if sid not in session.shocks:
            raise SessionError(
                f"{where}: shock {sid!r} is not in the session's {session.shock_library_file}; "
                "a session keeps one shock library: add the shock to it by hand, then import"
            )
        # as the session's file holds them (TOML floats to 13 significant digits)
        if (round_file_numbers(given[sid].to_toml_dict())
                != round_file_numbers(session.shocks[sid].to_toml_dict())):
            raise SessionError(
                f"{where}: shock {sid!r} of the given library differs from the one in the "
                f"session's {session.shock_library_file}; give the new shock another id and "
                "add it there"
            )


def import_runs(session_dir, files, *, format, channel_map, setup, role="other",
                names=None, shocks=None, units=None, session_name=None,
                run_format="csv", resample_hz=None):
    """Import rig data files (RPC III, MDF, TDMS) as runs of a rig session folder.

    Every file becomes one run with the same `setup` and `role`. If
    `session_dir` holds no session yet, one is created (then `shocks` is
    required); otherwise the runs are appended to it.

    Parameters
    ----------
    session_dir : str or os.PathLike
        The session folder (``--out``).
    files : sequence of str or os.PathLike
        The rig data files, one run each.
    format : {"rpc3", "mdf", "tdms"}
        The files' format (``--format``).
    channel_map : ChannelMap or str or os.PathLike
        The channel map or its TOML file (``--map``); it must map the 7 rig
        inputs, or only the 4 wheelloaders for a 4-post rig (no aero actuators).
    setup : mapping of str to str, or str
        Corner -> shock id, or ``"LF,RF,LR,RR"`` ids (``--setup``); the ids
        must be in the session's shock library.
    role : {"baseline", "swap", "validation", "other"}
        The runs' role.
    names : sequence of str, optional
        Run names, one per file (default: each file's name without suffix).
    shocks : ShockLibrary or str or os.PathLike, optional
        The shock library (or its TOML file): required to create a session;
        with an existing session, shocks the setup names must be the same as in
        the session's library (or be omitted).
    units : {"SI", "imperial"}, optional
        Unit system of a new session's files (default SI); with an existing
        session, omit it or give the session's.
    session_name : str, optional
        Name of a new session (default: the folder's name).
    run_format : {"csv", "parquet"}
        File format of the new run files.
    resample_hz : float, optional
        Resample every file onto a uniform base at this rate [Hz] before it is written
        (``--resample``: files logged at another rate than the session's; band-limited,
        anti-aliased when going down; :func:`read_run`). Default: each file's rate.

    Returns
    -------
    ident.data.session.Session
        The session as read back from `session_dir`.

    Raises
    ------
    SessionError
        On an unknown format or role, a bad channel map or one that misses a
        rig input, a file the map cannot read (:func:`read_run`, every message
        naming the file and channel), a run name that already exists or
        repeats, a setup naming an unknown shock, a `shocks` library that
        disagrees with an existing session's, `units` other than an existing
        session's, a missing `shocks` for a new session, or a folder that
        exists but holds no session. Nothing is written then.
    TypeError
        If `files`, `setup`, `shocks` or `channel_map` is of a wrong type.

    Notes
    -----
    Writing is atomic: a new session is built in a temporary folder and
    renamed into place (:func:`ident.data.session.write_session`); runs are appended
    with :func:`ident.data.session.append_runs`, which keeps everything already in
    the folder byte for byte. All files are read and checked before anything
    is written.
    """
    fmt = _check_format(format)
    cmap = as_channel_map(channel_map)
    if isinstance(files, (str, os.PathLike)):
        files = [files]
    files = [Path(f) for f in files]
    if not files:
        raise SessionError("import: no files given; name at least one rig data file")
    if names is None:
        names = [f.stem for f in files]
    elif isinstance(names, str) or len(names) != len(files):
        raise SessionError(
            f"import: {len(files)} file(s) but names {names!r}; give one run name per file"
        )
    if role not in RUN_ROLES:
        raise SessionError(f"import: role {role!r} is not one of {', '.join(RUN_ROLES)}; fix "
                           "or omit it (default 'other')")
    repeated = sorted({n for n in names if list(names).count(n) > 1})
    if repeated:
        raise SessionError(
            f"import: run name {repeated[0]!r} is given to several files; give each file "
            "its own run name (names=..., --names on the command line)"
        )
    folder = Path(session_dir)
    where = f"session {folder}"
    if (folder / MANIFEST_NAME).is_file():
        session = read_session(folder)
        library = session.shocks
        setup = parse_setup(setup, shocks=library, where=f"{where}: setup")
        if shocks is not None:
            _check_same_shocks(_library(shocks, where=where), session, setup, where=where)
        if units is not None and check_units(units, where="units",
                                             error=SessionError) != session.units:
            raise SessionError(
                f"{where}: the session is in {session.units} units, so new runs are "
                f"written in {session.units}; omit units or pass {session.units!r}"
            )
        clash = [n for n in names if n in session.run_names]
        if clash:
            raise SessionError(
                f"{where}: run {clash[0]!r} already exists in the session; import the file "
                "under another name (names=..., --names on the command line)"
            )
    else:
        if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
            raise SessionError(
                f"{where}: exists but holds no {MANIFEST_NAME}; give the folder of an "
                "existing session to append to, or a new (or empty) folder"
            )
        if shocks is None:
            raise SessionError(
                f"{where}: no session there yet, and a new session needs its shock library; "
                "pass shocks (--shocks SHOCKS.toml)"
            )
        session = None
        library = _library(shocks, where=where)
        setup = parse_setup(setup, shocks=library, where=f"{where}: setup")
        units = "SI" if units is None else check_units(units, where="units",
                                                        error=SessionError)

    # a map without aero channels reads a 4-post rig's files; one with any reads all three
    rig_inputs = (RIG_INPUTS if any(c in cmap.channels for c in AERO_INPUTS)
                  else WHEELLOADER_INPUTS)
    runs = []
    for name, file in zip(names, files):
        table = read_run(file, format=fmt, channel_map=cmap, required=rig_inputs,
                         resample_hz=resample_hz)
        runs.append(Run(name=name, file=f"runs/{name}.{run_format}", setup=setup, role=role,
                        time_s=table.time_s, channels=table.channels, fs_hz=table.fs_hz))

    if session is not None:
        return append_runs(folder, runs, run_format=run_format)
    new = make_session(session_name or folder.resolve().name, runs, library, units=units)
    write_session(new, folder, units=units, run_format=run_format)
    return read_session(folder)
