"""Run tables: one file of rig signals, read and written as SI under canonical names.

A run table is a CSV file with a header row or a Parquet file: a ``time`` column
in seconds and one column per channel. :func:`read_run_table` reads one (a run of
a rig session, or a standalone drive file) and :func:`write_run_table` writes
one; both go through one checking engine (:func:`check_columns`): channel names
mapped to canonical ones, required channels present, numeric and finite values,
strictly increasing and uniformly sampled time, units converted to SI.

The engine and its helpers are public because the session manifest
(:mod:`ident.data.session`) checks in-memory runs with the same engine
(:func:`in_memory_columns`, :func:`check_columns`) and appends run files under a
session's column names (:func:`write_mapped_run_table`).

Notes
-----
Inside the package every value is SI and every channel has its canonical name
(:mod:`ident.data.channels`). Files may be in ``"imperial"`` units and may name
their columns differently (a ``{canonical: column}`` channel map, the session
manifest's ``[channels]`` table). A written file says its unit system: a CSV's last
column ``units`` (``SI`` or ``imperial`` on every row; the earlier layout's first line
``# units: ...`` is still read), a Parquet file's schema metadata ``units``
(:mod:`ident.data.files`); a read file's marker decides its units when the caller gives
none, and contradicts them with an error (:func:`ident.data.files.resolve_units`).
"""

from __future__ import annotations

import csv
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ident.data.channels import (ALL_CHANNELS, RIG_INPUTS, THIRD_CHANNELS, WHEELLOADER_INPUTS,
                                 missing_aero, quantity_of)
from ident.data.files import (UNITS_COLUMN, csv_preamble, read_csv_after, read_units_marker,
                              resolve_units, units_of_column, write_table_file)
from ident.data.timebase import uniform_time_base
from ident.data.units import check_units, from_si, to_si
from ident.errors import SessionError

__all__ = [
    "RTOL_TIME_STEP",
    "RunTable",
    "read_run_table",
    "write_run_table",
    "write_mapped_run_table",
    "check_columns",
    "read_table_columns",
    "check_channel_map",
    "check_session_units",
    "in_memory_columns",
    "frozen_array",
]

logger = logging.getLogger(__name__)

#: Largest accepted deviation of a time step from the mean step, relative to the step;
#: also the relative tolerance on equal sample rates across the runs of a session.
RTOL_TIME_STEP = 1e-6

_TIME = "time"
#: Every channel a run file may hold: the spec's channels and the third elements'.
_CANONICAL = frozenset(ALL_CHANNELS + THIRD_CHANNELS)


# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RunTable:
    """A checked table of signals read from one run (or drive) file.

    Attributes
    ----------
    time_s : ndarray, shape (n_samples,)
        Sample times [s], strictly increasing and uniformly sampled (read-only).
    channels : dict of str to ndarray, shape (n_samples,)
        Canonical channel name -> samples in SI units (float64, read-only), in
        :data:`ident.data.channels.ALL_CHANNELS` order.
    fs_hz : float
        Sample rate [Hz], derived from `time_s`.
    path : pathlib.Path
        The file the table was read from.
    units : {"SI", "imperial"}
        The unit system the file was read in.
    file_units : {"SI", "imperial"} or None
        The unit system the file says it is in (its unit marker), or None.
    """

    time_s: np.ndarray
    channels: dict
    fs_hz: float
    path: Path
    units: str = "SI"
    file_units: str | None = None


# --------------------------------------------------------------------------------------
# The checking engine for tables of signals
# --------------------------------------------------------------------------------------


def frozen_array(x):
    """Return a read-only float64 array that no one else can modify.

    Parameters
    ----------
    x : array_like
        The values; an array this function made (read-only float64 owning its
        data) is returned as is, anything else is copied.

    Returns
    -------
    ndarray
        Read-only float64 (the arrays of :class:`RunTable` and
        :class:`ident.data.session.Run`).
    """
    if (isinstance(x, np.ndarray) and x.dtype == np.float64 and not x.flags.writeable
            and x.base is None):
        return x  # already read-only and owning its data (made here): no second copy
    a = np.array(x, dtype=np.float64)  # a copy: the caller's array stays writable
    a.flags.writeable = False
    return a


def check_channel_map(channel_map, *, where):
    """Validate a ``{canonical: column}`` mapping; return it as a plain dict.

    Parameters
    ----------
    channel_map : mapping of str to str or None
        Canonical channel name (or ``time``) -> file column; ``None`` is no mapping.
    where : str
        Prefix of the error messages (file, manifest).

    Returns
    -------
    dict of str to str

    Raises
    ------
    SessionError
        If it is not a mapping, maps a name that is not canonical, a column is not
        a non-empty string, or two channels share a column.
    """
    if channel_map is None:
        return {}
    if not isinstance(channel_map, Mapping):
        raise SessionError(
            f"{where}: [channels] must be a table of canonical name = \"your column\", "
            f"got {type(channel_map).__name__}"
        )
    seen = {}
    for canonical, column in channel_map.items():
        if canonical != _TIME and canonical not in _CANONICAL:
            raise SessionError(
                f"{where}: [channels] maps {canonical!r}, which is not a canonical "
                f"channel; keys are canonical names ('time', the rig inputs "
                f"{list(RIG_INPUTS)} or '<kind>_<corner>' such as 'tire_force_LF'), "
                "values are your column names"
            )
        if not isinstance(column, str) or not column:
            raise SessionError(
                f"{where}: [channels] {canonical} = {column!r}: the value must be the "
                "column name (a non-empty string) that holds this channel in the run files"
            )
        if column in seen:
            raise SessionError(
                f"{where}: [channels] maps both {seen[column]!r} and {canonical!r} to "
                f"column {column!r}; each column can hold only one channel"
            )
        seen[column] = canonical
    return dict(channel_map)


def _label(canonical, column):
    return f"{column!r}" if column == canonical else f"{column!r} ({canonical})"


def _is_number(value):
    if isinstance(value, (bool, np.bool_)):
        return False
    try:
        float(value)
    except (TypeError, ValueError):
        return False
    return True


def _as_numeric(values, *, label, where, time=None):
    """Return `values` as float64, or raise naming the first non-numeric entry."""
    a = np.asarray(values)
    if a.ndim != 1:
        raise SessionError(
            f"{where}: column {label} must be one-dimensional (one value per sample), "
            f"got shape {a.shape}"
        )
    if a.dtype.kind in "iuf":
        return a.astype(np.float64, copy=False)
    for i, v in enumerate(a):
        if not _is_number(v):
            at = "" if time is None else f", t={time[i]:.6g} s"
            shown = v.item() if isinstance(v, np.generic) else v
            raise SessionError(
                f"{where}: column {label} is not numeric (data row {i + 1}{at}: "
                f"{shown!r}); export plain numbers"
            )
    return a.astype(np.float64)


def _seconds(values):
    """A datetime or timedelta time column as float seconds (from its first sample).

    Parquet (and pandas) keep timestamps as datetime64; read as numbers they would be
    nanoseconds since 1970. Other columns are returned unchanged.
    """
    a = np.asarray(values)
    if a.dtype.kind == "O" and a.size and hasattr(a[0], "to_datetime64"):
        import pandas as pd

        a = pd.to_datetime(pd.Series(a), utc=True).dt.tz_localize(None).to_numpy()
    if a.dtype.kind == "M" and a.size:
        return (a - a[0]) / np.timedelta64(1, "s")
    if a.dtype.kind == "m":
        return a / np.timedelta64(1, "s")
    return values


def check_columns(columns, *, where, units, channel_map, required, names=None,
                  resample_hz=None):
    """The checking engine: map, check and convert a table of raw columns.

    Parameters
    ----------
    columns : mapping of str to array_like, shape (n_rows,)
        Column name (as in the file) -> raw values in `units`.
    where : str
        Prefix of every error message (file, run).
    units : {"SI", "imperial"}
        Unit system of the values.
    channel_map : dict of str to str
        Checked ``{canonical: column}`` mapping (may be empty).
    required : iterable of str
        Canonical channels that must be present.
    names : sequence of str, optional
        The canonical channels the table may hold (default
        :data:`ident.data.channels.ALL_CHANNELS`); other columns are ignored (logged at
        debug level). A track log reads its own
        (:data:`ident.data.tracklog.TRACK_LOG_CHANNELS`, ``speed`` among them).
    resample_hz : float, optional
        Resample the table onto a uniform base at this rate [Hz] (band-limited,
        anti-aliased when going down; :func:`ident.data.timebase.uniform_time_base`), said
        in a logged warning. Default: the file's own rate (jittered time stamps resampled
        onto it).

    Returns
    -------
    time_s : ndarray, shape (n_samples,)
    channels : dict of str to ndarray, shape (n_samples,)
        SI, read-only, in the order of `names`.
    fs_hz : float

    Raises
    ------
    SessionError
        As :func:`read_run_table` for the data: fewer than 2 rows, no ``time``, a
        missing required channel, a non-numeric or NaN/inf value, time not
        strictly increasing and uniform, or a value that overflows in SI.
    """
    names = ALL_CHANNELS + THIRD_CHANNELS if names is None else tuple(names)
    source = {c: channel_map.get(c, c) for c in (_TIME,) + names}
    by_column = {col: c for c, col in source.items()}
    present = {}  # canonical -> column
    for col in columns:
        if col in by_column:
            present[by_column[col]] = col
        else:
            logger.debug("%s: column %r is not a canonical channel; ignored", where, col)

    first = next(iter(columns.values()), ())
    n_rows = np.shape(first)[0] if np.ndim(first) >= 1 else 0
    if n_rows < 2:
        raise SessionError(
            f"{where}: has {n_rows} data row(s); a run needs at least 2 samples"
        )
    if _TIME not in present:
        hint = (f" (mapped to column {source[_TIME]!r} by [channels])"
                if source[_TIME] != _TIME else "")
        raise SessionError(
            f"{where}: no 'time' column{hint}; add a column 'time' in seconds or map "
            "your time column in the manifest's [channels] table (time = \"your column\")"
        )
    # rig inputs (the wheelloaders required): the aero channels come all three or none (4-post)
    partial = missing_aero(present) if set(WHEELLOADER_INPUTS) <= set(required) else []
    required = tuple(c for c in partial if c not in required) + tuple(required)
    missing = [c for c in required if c not in present]
    if missing:
        names = ", ".join(_label(c, source[c]) for c in missing)
        four_post = (" (a 4-post run, without aero actuators, has no aero channels at all)"
                     if partial else "")
        raise SessionError(
            f"{where}: missing required channel(s) {names}; add the column(s) or, if "
            "your export names them differently, map them in the manifest's [channels] "
            f"table (canonical = \"your column\"){four_post}"
        )

    t = _as_numeric(_seconds(columns[present[_TIME]]), label=_label(_TIME, present[_TIME]),
                    where=where)
    bad = ~np.isfinite(t)
    if bad.any():
        i = int(np.argmax(bad))
        raise SessionError(
            f"{where}: column {_label(_TIME, present[_TIME])} has {int(bad.sum())} "
            f"NaN/inf value(s), the first at data row {i + 1}; fill or cut the run"
        )
    base = uniform_time_base(t, where=where, error=SessionError, resample_hz=resample_hz)
    if base.resampled:  # a logger's jittered time stamps, or a rate asked for
        logger.warning(base.describe(where))
    t = base.time_s

    channels = {}
    for canonical in names:
        if canonical not in present:
            continue
        col = present[canonical]
        label = _label(canonical, col)
        x = _as_numeric(columns[col], label=label, where=where, time=base.raw_time_s)
        bad = ~np.isfinite(x)
        if bad.any():
            t0 = base.raw_time_s[int(np.argmax(bad))]
            raise SessionError(
                f"{where}: column {label} has {int(bad.sum())} NaN/inf value(s) from "
                f"t={t0:.6g} s; fill or cut the run"
            )
        with np.errstate(over="ignore"):
            si = to_si(x, quantity_of(canonical), units)
        bad = ~np.isfinite(si)
        if bad.any():  # finite in the file, beyond float64 in SI (e.g. 1e308 in)
            i = int(np.argmax(bad))
            raise SessionError(
                f"{where}: column {label} has {int(bad.sum())} value(s) that overflow when "
                f"converted from {units} to SI, the first {x[i]:.6g} at "
                f"t={base.raw_time_s[i]:.6g} s; "
                "fix or cut the run (a logger's overflow or fill value?)"
            )
        channels[canonical] = frozen_array(base.resample(si))
    return frozen_array(t), channels, base.fs_hz


def check_session_units(units, *, where):
    """Return the unit system `units` checked, raising :class:`SessionError` if unknown.

    Parameters
    ----------
    units : {"SI", "imperial"}
        The unit system name.
    where : str
        Prefix of the error message.

    Returns
    -------
    str

    Raises
    ------
    SessionError
        If `units` is not a unit system (:func:`ident.data.units.check_units`).
    """
    try:
        return check_units(units, where=where)
    except ValueError as exc:
        raise SessionError(str(exc)) from None


def _check_required(required, *, where):
    required = tuple(required)
    unknown = [c for c in required if c not in _CANONICAL]
    if unknown:
        raise SessionError(
            f"{where}: required channel(s) {unknown} are not canonical channels; "
            f"see ident.data.channels.ALL_CHANNELS"
        )
    return required


# --------------------------------------------------------------------------------------
# Run tables (files)
# --------------------------------------------------------------------------------------


def _file_kind(path, *, where):
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return "csv"
    if suffix in (".parquet", ".pq"):
        return "parquet"
    raise SessionError(
        f"{where}: unsupported file type {path.suffix!r}; run files are CSV (.csv, with "
        "a header row) or Parquet (.parquet)"
    )


def read_table_columns(path, *, where, kind=None):
    """Read a CSV or Parquet file into ``{column: 1-D ndarray}`` and its unit marker.

    A CSV's leading ``#`` comment and blank lines (the earlier layout's unit marker line
    among them) are skipped; its ``units`` column (the unit system on every row, what
    shockplan writes) gives the unit system and is not returned.

    Parameters
    ----------
    path : pathlib.Path
        An existing file.
    where : str
        How to name the file in messages.
    kind : {"csv", "parquet"}, optional
        The file's format (default: from its suffix, ``.csv``, ``.parquet`` or ``.pq``).

    Returns
    -------
    columns : dict of str to ndarray, shape (n_rows,)
        Column name (stripped of spaces) -> values as read, in file order.
    units : {"SI", "imperial"} or None
        The file's unit marker (a CSV's ``units`` column or marker line, a Parquet file's
        metadata: :mod:`ident.data.files`), or None.

    Raises
    ------
    SessionError
        If the suffix is not a table's (without `kind`), the file is empty or cannot be
        read as that format, its marker is invalid (a ``units`` column with more than one
        value, or one that disagrees with the marker line), or two columns share a name.
    """
    import pandas as pd
    import pyarrow

    path = Path(path)
    kind = _file_kind(path, where=where) if kind is None else kind
    try:
        if kind == "csv":
            with open(path, newline="", encoding="utf-8-sig") as fh:
                marker, n_skip = csv_preamble(fh, where=where, error=SessionError)
            with open(path, newline="", encoding="utf-8-sig") as fh:
                for _ in range(n_skip):  # as lines: a quote in a comment opens no field
                    fh.readline()
                header = next(csv.reader(fh), None)
            if not header:
                raise SessionError(
                    f"{where}: the file is empty; a run file has a header row and one "
                    "row per sample"
                )
            frame = read_csv_after(path, n_skip)
            names = [h.strip() for h in header]
        else:
            frame = pd.read_parquet(path)
            names = [str(c).strip() for c in frame.columns]
            marker = read_units_marker(path, where=where, error=SessionError, kind=kind)
    except SessionError:
        raise
    except (OSError, ValueError, UnicodeDecodeError, pyarrow.ArrowException) as exc:
        raise SessionError(
            f"{where}: cannot read the file as {kind.upper()} ({type(exc).__name__}: "
            f"{exc}); check that it is a valid, non-empty {kind.upper()} file"
        ) from None
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise SessionError(
            f"{where}: duplicated column name(s) {dupes}; give every column a unique name"
        )
    if len(names) != frame.shape[1]:  # pragma: no cover - pandas always agrees
        raise SessionError(f"{where}: could not parse the header row; check the file")
    if kind == "csv" and UNITS_COLUMN in names:
        marker = units_of_column(frame.iloc[:, names.index(UNITS_COLUMN)], marker=marker,
                                 where=where, error=SessionError)
    return {name: frame.iloc[:, j].to_numpy() for j, name in enumerate(names)
            if not (kind == "csv" and name == UNITS_COLUMN)}, marker


def read_run_table(path, *, units=None, channel_map=None, required=(), where=None,
                   units_from="units", units_fix=None, resample_hz=None):
    """Read, check and convert one run (or drive) file to SI and canonical names.

    Parameters
    ----------
    path : str or os.PathLike
        A CSV file with a header row (``.csv``), after any leading ``#`` comment lines,
        or a Parquet file (``.parquet``).
    units : {"SI", "imperial"}, optional
        Unit system of the values in the file; each channel is converted to SI by
        its quantity (:func:`ident.data.channels.quantity_of`); ``time`` is in seconds.
        Default: the file's unit marker (a ``units`` column or a ``# units: ...`` line,
        Parquet metadata ``units``),
        else SI. Given, it must agree with the marker.
    channel_map : mapping of str to str, optional
        ``{canonical name: file column}`` for exports whose names differ (the
        manifest's ``[channels]`` table). ``time`` may be mapped too.
    required : iterable of str
        Canonical channels that must be present (e.g. ``ident.data.channels.RIG_INPUTS``).
        When it holds the four wheelloaders, the aero channels must be all three
        or none (a 4-post run): ``ident.data.channels.WHEELLOADER_INPUTS`` reads runs
        of either rig.
    where : str, optional
        How to name the file in error messages (default: the path), e.g.
        ``"run 'swap-LF' (runs/swap-LF.csv)"``.
    units_from : str
        How to name the source of `units` when it contradicts the file's marker (e.g.
        ``"the manifest's units"``).
    units_fix : str, optional
        The fix that message ends with (default: :func:`ident.data.files.resolve_units`'s).
    resample_hz : float, optional
        Resample the run onto a uniform base at this rate [Hz] (``--resample``;
        band-limited, anti-aliased when going down), said in a logged warning. Default:
        the file's rate.

    Returns
    -------
    RunTable
        Times [s], shape (n_samples,); SI channels, each shape (n_samples,); the
        sample rate [Hz]; the unit system read in and the file's marker. Columns that
        are not canonical channels are ignored (logged at debug level).

    Raises
    ------
    SessionError
        If the file is missing, unreadable or empty, of an unsupported type, has
        fewer than 2 rows, duplicated column names, no ``time``, misses a
        required channel, holds a non-numeric or NaN/inf value in a used column,
        or its time is not strictly increasing and uniformly sampled (relative
        step tolerance :data:`RTOL_TIME_STEP`); if its unit marker is invalid or
        contradicts `units`; or if `units`, `channel_map` or `required` is invalid.

    Examples
    --------
    >>> import tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "run.csv")
    >>> _ = open(p, "w").write("time,aero_heave,Note\\n0.0,1.0,a\\n0.01,2.0,b\\n")
    >>> table = read_run_table(p, units="imperial")
    >>> table.fs_hz, list(table.channels), float(table.channels["aero_heave"][1])
    (100.0, ['aero_heave'], 8.896443230521)
    """
    path = Path(path)
    where = str(path) if where is None else where
    if units is not None:
        units = check_session_units(units, where=f"{where}: units")
    channel_map = check_channel_map(channel_map, where=where)
    required = _check_required(required, where=where)
    if not path.exists():
        at = "" if where == str(path) else f" ({path})"
        raise SessionError(f"{where}: file not found{at}; check the path")
    if not path.is_file():
        raise SessionError(f"{where}: {path} is not a file; give the path of a run file")
    columns, marker = read_table_columns(path, where=where)
    units = resolve_units(marker, units, where=where, given_as=units_from, fix=units_fix,
                          error=SessionError)
    time_s, channels, fs_hz = check_columns(
        columns, where=where, units=units, channel_map=channel_map, required=required,
        resample_hz=resample_hz)
    return RunTable(time_s=time_s, channels=channels, fs_hz=fs_hz, path=path, units=units,
                    file_units=marker)


def in_memory_columns(time_s, channels, *, where):
    """Build the engine's column table from in-memory SI data (canonical names only).

    Parameters
    ----------
    time_s : array_like, shape (n_samples,)
        Sample times [s].
    channels : mapping of str to array_like, shape (n_samples,)
        Canonical channel name -> samples in SI units.
    where : str
        Prefix of the error messages (file, run).

    Returns
    -------
    dict of str to array_like
        ``time`` then the channels, ready for :func:`check_columns` (with
        ``units="SI"`` and no channel map).

    Raises
    ------
    SessionError
        If a channel name is not canonical or a shape differs from `time_s`.
    """
    channels = dict(channels)
    unknown = [c for c in channels if c not in _CANONICAL]
    if unknown:
        raise SessionError(
            f"{where}: unknown channel name(s) {unknown}; use canonical names "
            "(ident.data.channels.ALL_CHANNELS)"
        )
    if np.ndim(time_s) != 1:
        raise SessionError(
            f"{where}: time_s must be one-dimensional, got shape {np.shape(time_s)}"
        )
    n = np.shape(time_s)[0]
    for c, x in channels.items():
        if np.shape(x) != (n,):
            raise SessionError(
                f"{where}: channel {c!r} has shape {np.shape(x)}; expected ({n},) like time_s"
            )
    return {_TIME: time_s, **channels}


def write_run_table(path, time_s, channels, *, units="SI", overwrite=False, float_dtype="float64"):
    """Write a table of signals as a CSV or Parquet run file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Output file; ``.csv`` or ``.parquet`` chooses the format.
    time_s : array_like, shape (n_samples,)
        Sample times [s], strictly increasing and uniform.
    channels : mapping of str to array_like, shape (n_samples,)
        Canonical channel name -> samples in SI units.
    units : {"SI", "imperial"}
        Unit system of the written values (converted from SI by each channel's
        quantity).
    overwrite : bool
        Replace an existing file.
    float_dtype : {"float64", "float32"}
        The type a Parquet file stores the channels in (``time`` is always 64-bit;
        :func:`ident.data.files.write_parquet_frame`); a CSV takes only ``"float64"``.

    Notes
    -----
    Columns are ``time``, the rig inputs, then the responses, in
    :data:`ident.data.channels.ALL_CHANNELS` order. CSV floats are written with full
    precision (shortest repr that round-trips). The file says its unit system: a CSV's
    last column is ``units`` (``SI`` or ``imperial`` on every row), a Parquet file has
    the schema metadata ``units``. The data are checked by the same
    engine as :func:`read_run_table`, so a written file always reads back.

    Raises
    ------
    SessionError
        If a channel name is not canonical, a shape differs from `time_s`, or the
        data fail the run-file checks (NaN/inf, non-uniform time, < 2 samples).
    ValueError
        If `units` or the file type is invalid.
    FileExistsError
        If `path` exists and `overwrite` is false.
    """
    import pandas as pd

    path = Path(path)
    where = str(path)
    kind = _file_kind(path, where=where)
    units = check_session_units(units, where=f"{where}: units")
    columns = in_memory_columns(time_s, channels, where=where)
    t, si, _ = check_columns(columns, where=where, units="SI", channel_map={},
                              required=())
    frame = pd.DataFrame(
        {_TIME: t, **{c: from_si(x, quantity_of(c), units) for c, x in si.items()}}
    )
    write_table_file(frame, path, kind=kind, units=units, overwrite=overwrite,
                     float_dtype=float_dtype)


# --------------------------------------------------------------------------------------
# Run files under a session's column names
# --------------------------------------------------------------------------------------


def write_mapped_run_table(path, time_s, channels, *, units, channel_map):
    """Write a run file whose columns are named by a session's ``[channels]`` map.

    As :func:`write_run_table` (same checks, never overwrites), but a canonical
    channel (or ``time``) that `channel_map` maps is written under its column name,
    so that the session's manifest reads the file.
    """
    import pandas as pd

    path = Path(path)
    where = str(path)
    kind = _file_kind(path, where=where)
    columns = in_memory_columns(time_s, channels, where=where)
    t, si, _ = check_columns(columns, where=where, units="SI", channel_map={},
                              required=())
    data = {channel_map.get(_TIME, _TIME): t}
    for c, x in si.items():
        column = channel_map.get(c, c)
        if column in data:
            raise SessionError(
                f"{where}: the session's [channels] table makes column {column!r} hold "
                f"two channels; fix the manifest's [channels] table"
            )
        data[column] = from_si(x, quantity_of(c), units)
    frame = pd.DataFrame(data)
    write_table_file(frame, path, kind=kind, units=units, overwrite=False)
