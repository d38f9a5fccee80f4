"""Raw shock-dyno time series to dyno-sheet rows (``shockplan dyno import``).

A shock dyno strokes a damper sinusoidally, in blocks of cycles at increasing peak
velocity, and logs time, force and displacement (and often the oil temperature) at its
rate. This module turns such files into the rows of a dyno sheet (the spec's "Adjustable
shocks"): per block, the force at the block's peak velocity in bump and in rebound, at the
adjuster settings the run was made at.

**Reading.** A CSV (or Parquet) file with the canonical columns ``time`` [s], ``force``
[N], ``displacement`` [m] and optional ``temperature`` [deg C] (a ``units`` column
holding ``imperial``, or the marker line ``# units: imperial``, makes them in and lbf)
needs no map. Any other file needs a dyno map (TOML)::

    format = "dyno-map/1"
    name = "Roehrig EMX, CSV export"       # optional

    [columns.time]
    source = "Time (ms)"                   # the column's name in the file
    units = "ms"                           # s, ms, us

    [columns.force]
    source = "Load"
    units = "lbf"                          # N, kN, lbf
    sign = -1                              # required: -1 if the dyno logs tension positive
    offset = 0.0                           # optional: raw value at zero, subtracted first
    scale = 1.0                            # optional: a calibration gain

    [columns.displacement]
    source = "Position"
    units = "in"                           # m, cm, mm, in
    sign = 1                               # required: +1 if compression is positive

    [columns.temperature]                  # optional
    source = "Shock Temp"
    units = "degF"                         # degC, degF, K

converted as ``x = sign * factor(units) * scale * (raw - offset)`` (the rig channel map's
formula, :mod:`ident.data.formats.channel_map`; temperature without a sign, converted to
deg C). The map's parser is this module's own: importing the rig formats would load
their readers (pandas, scipy: 2 s) on the command line's start-up.

**Refused**, with the file, the column and the fix (:class:`~ident.errors.DynoError`): a
missing column (displacement above all: velocity alone has no stroke to find cycles in),
NaN or non-numeric values, a flat-lined force or displacement, time that is not
increasing or not uniform, fewer than ``min_cycles`` cycles at any peak velocity, and a
point whose force has the wrong sign once the gas force is removed (a sign in the map).

**The analysis** (:func:`analyze_dyno_run`), per file:

1. *Cycles*: the displacement's extremes (velocity zero crossings), found between
   crossings of mid-stroke with a hysteresis of a quarter of the half-stroke, so that
   noise never splits a stroke; a cycle runs from full extension through full
   compression back to full extension (a bump then a rebound half). An extreme at the
   very start or end of the file counts when the shaft is at rest there.
2. *Velocity*: a Savitzky-Golay derivative (cubic, per cycle over a window of
   :data:`DIFF_WINDOW_SHARE` of the cycle's period). It is the derivative of a local
   least-squares cubic, exact for the sine's low-order Taylor terms (bias below 1e-4 at a
   tenth of a period) while its noise gain is ``sqrt(12 / (N (N^2 - 1)))`` per sample
   against ``sqrt(2)`` for a finite difference: for a 0.1-period window of a 4 s cycle
   at 1 kHz (N = 401), about 20 000 times less displacement noise in the velocity. The
   force's derivative (to remove the lag at the peaks) is taken the same way.
3. *Blocks*: consecutive cycles whose peak velocities agree within :data:`BLOCK_RTOL`;
   blocks of fewer than ``min_cycles`` cycles (the taper between speeds, a warm-up
   stroke) are left out.
4. *Gas force and lag*, one least-squares fit over every cycle of the file::

       lag * dF/dt + F = g(v)          (F the measured force, g(0) the gas force)

   ``g`` piecewise linear in velocity (hat functions on :data:`N_KNOTS` knots per side at
   quantiles of |v|, one at 0); for a given lag each hat's response through the lag is a
   first-order filter, so the fit is linear in ``g`` and the lag a bounded 1-D search
   (no derivative of the force, which a window would smear where the curve kinks). The
   lag's effect is odd in time about every velocity peak, ``g`` even, so they separate.
   The gas force is ``g(0)`` (a passive curve passes through 0); the lag is reported as
   the hysteresis.
5. *Sheet points*: per block and side, the force with the lag and the gas force removed,
   ``F + lag dF/dt - gas``, regressed linearly on velocity over the samples within
   :data:`PEAK_WINDOW` of each half-cycle's peak, pooled over the block's cycles, and
   evaluated at the block's mean peak velocity. At the velocity peak the acceleration is
   zero, so neither inertia nor the lag moves the point to first order.
6. *The averaged loop*: every cycle resampled on :data:`LOOP_POINTS` phases and averaged
   (force with the gas removed, lag kept): the force-velocity loop of the block.

**Temperature**: per block and per file, the mean; files of one import share their
settings, so a spread of their temperatures over :data:`TEMPERATURE_DRIFT_C` is warned
of (logged, and kept in :attr:`DynoImport.warnings`).

**The sheet** (:func:`write_dyno_sheet`): columns ``velocity, force`` (signed,
compression positive), one column per adjuster (the settings, in the order given),
``temperature`` (deg C, when logged), ``cycles``, ``lag`` [s], ``source`` (the file's
name) and ``units`` (``SI`` or ``imperial`` on every row). A sheet of the earlier
layout, its first line ``# units: SI`` (or imperial), is still read and appended to.

Examples
--------
>>> parse_settings("ls=6, hs=2.5")
{'ls': 6.0, 'hs': 2.5}
>>> m = make_dyno_map({"time": {"source": "t", "units": "ms"},
...                    "force": {"source": "F", "units": "lbf", "sign": -1},
...                    "displacement": {"source": "x", "units": "mm", "sign": 1}})
>>> round(m.columns["force"].gain_si, 6), m.columns["time"].gain_si
(-4.448222, 0.001)
"""

from __future__ import annotations

import csv
import io
import logging
import math
import numbers
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from ident.data.files import (UNITS_COLUMN, atomic_write_text, check_can_write, csv_preamble,
                              did_you_mean, read_csv_table, read_toml, read_units_marker)
from ident.data.timebase import nominal_rate, uniform_time_base
from ident.data.units import TO_SI, UNIT_LABELS, check_units, format_quantity, from_si
from ident.errors import DynoError

__all__ = [
    "DYNO_MAP_FORMAT",
    "DYNO_COLUMNS",
    "DYNO_UNITS",
    "SHEET_COLUMNS",
    "MIN_CYCLES",
    "PEAK_WINDOW",
    "BLOCK_RTOL",
    "DIFF_WINDOW_SHARE",
    "N_KNOTS",
    "LOOP_POINTS",
    "LAG_MAX_S",
    "TIME_GRID_SHARE",
    "TIME_QUANTA",
    "time_resolution",
    "TEMPERATURE_DRIFT_C",
    "DynoColumn",
    "DynoMap",
    "DynoBlock",
    "DynoRun",
    "DynoImport",
    "make_dyno_map",
    "read_dyno_map",
    "read_dyno_raw",
    "parse_settings",
    "analyze_dyno_run",
    "import_dyno_runs",
    "write_dyno_sheet",
]

logger = logging.getLogger(__name__)

#: Value of a dyno map's ``format`` key.
DYNO_MAP_FORMAT = "dyno-map/1"
#: The canonical columns of a raw dyno file: name -> (quantity, required).
DYNO_COLUMNS = MappingProxyType({"time": ("time", True), "force": ("force", True),
                                 "displacement": ("displacement", True),
                                 "temperature": ("temperature", False)})
#: Units a dyno map accepts per quantity: unit -> factor to SI (temperature: to deg C,
#: ``(factor, offset)`` with ``T_c = factor * (value - offset)``).
DYNO_UNITS = MappingProxyType({
    "time": MappingProxyType({"s": 1.0, "ms": 1e-3, "us": 1e-6}),
    "force": MappingProxyType({"N": 1.0, "kN": 1e3, "lbf": TO_SI["force"]}),
    "displacement": MappingProxyType({"m": 1.0, "cm": 1e-2, "mm": 1e-3,
                                      "in": TO_SI["displacement"]}),
    "temperature": MappingProxyType({"degC": (1.0, 0.0), "degF": (5.0 / 9.0, 32.0),
                                     "K": (1.0, 273.15)}),
})
_UNIT_ALIASES = {"sec": "s", "msec": "ms", "µs": "us", "inch": "in", "inches": "in",
                 "C": "degC", "°C": "degC", "deg C": "degC", "degc": "degC",
                 "F": "degF", "°F": "degF", "deg F": "degF", "degf": "degF"}
#: The sheet's fixed columns around the adjusters: before them, and after them.
SHEET_COLUMNS = (("velocity", "force"), ("temperature", "cycles", "lag", "source"))
_RESERVED = frozenset(SHEET_COLUMNS[0] + SHEET_COLUMNS[1] + ("bump_force", "rebound_force"))

#: Cycles a peak-velocity block needs to count: dyno practice averages 3-5; 2 is the
#: fewest whose mean says anything about the cycle-to-cycle spread.
MIN_CYCLES = 2
#: Samples within this share of a half-cycle's peak |v| make its peak point: +-11 deg of
#: phase of a sine, 6 % of the cycle, where the force is within 2 % of its peak value.
PEAK_WINDOW = 0.02
#: Consecutive cycles whose peak velocities differ by less than this share are one
#: block: programs step speeds by 25 % or more, a cycle's own scatter is below 1 %.
BLOCK_RTOL = 0.1
#: Savitzky-Golay window as a share of the cycle's period (see the module docstring).
DIFF_WINDOW_SHARE = 0.1
_DIFF_ORDER = 3
#: Knots per side of the least-squares curve ``g(v)`` of the gas and lag fit.
N_KNOTS = 24
#: Samples of the least-squares fit at most (evenly strided): the fit is a few unknowns.
_FIT_MAX_ROWS = 20_000
#: Upper bound [s] of the lag search: damper lags are 1-10 ms.
LAG_MAX_S = 0.05
#: Phases per cycle of the averaged loop.
LOOP_POINTS = 180
#: A time sample further than this share of the sample interval from the uniform grid
#: (fitted by least squares) makes time non-uniform: a dropped sample is off by one
#: interval; times printed with 4 decimals at 2048 Hz are off by at most 0.1 of one.
TIME_GRID_SHARE = 0.25
#: Resolutions a PC's time stamps are commonly rounded to [s] (:func:`time_resolution`).
TIME_QUANTA = (1e-3, 1e-4, 1e-5, 1e-6)
#: Hysteresis of the stroke detection, a share of the half-stroke.
_STROKE_HYSTERESIS = 0.25
#: An extreme at the very start or end of a file counts when it is as deep as the
#: nearest extreme of its kind within this share of the stroke (a turn at rest, not a file
#: cut mid-stroke: cut at 30 deg from a turn, a sine is 7 % of the stroke short of it).
_EDGE_TURN_SHARE = 0.02
#: Spread of the files' mean oil temperatures [deg C] (one import: one setting) that is
#: warned of. Damping oil's viscosity falls 2-3 %/deg C; low-speed (partly laminar) force
#: follows it by 0.5-1 %/deg C, so 3 deg C moves it by up to the 2 % the import resolves.
TEMPERATURE_DRIFT_C = 3.0
#: Points of one import closer in velocity than this share are one point of the curve
#: (:meth:`DynoImport.points`): repeated runs at one setting.
_MERGE_RTOL = 0.01
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]*$")
_TOP_KEYS = ("format", "name", "columns")
_ENTRY_KEYS = {"time": ("source", "units", "scale", "offset"),
               "force": ("source", "units", "sign", "scale", "offset"),
               "displacement": ("source", "units", "sign", "scale", "offset"),
               "temperature": ("source", "units", "scale", "offset")}


def _num(x):
    return f"{float(x):.6g}"


# --------------------------------------------------------------------------------------
# the map
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DynoColumn:
    """Where one canonical dyno column is in a file and how to convert it.

    Attributes
    ----------
    canonical : str
        ``time``, ``force``, ``displacement`` or ``temperature``.
    source : str
        The column's name in the file.
    units : str
        The unit of ``scale * (raw - offset)`` (:data:`DYNO_UNITS`).
    sign : int
        +1 or -1 (compression positive after it); 1 for time and temperature.
    scale : float
        Calibration gain (default 1).
    offset : float
        Raw value at zero, in the file's numbers (default 0).

    Notes
    -----
    ``x = sign * factor(units) * scale * (raw - offset)`` in SI; temperature in deg C.
    """

    canonical: str
    source: str
    units: str
    sign: int = 1
    scale: float = 1.0
    offset: float = 0.0

    @property
    def gain_si(self):
        """float: SI value of one raw unit (not for temperature)."""
        return self.sign * DYNO_UNITS[self.canonical][self.units] * self.scale

    def convert(self, raw):
        """Convert raw values, shape (n,), to SI (deg C for temperature), float64."""
        x = self.scale * (np.asarray(raw, dtype=np.float64) - self.offset)
        if self.canonical == "temperature":
            factor, zero = DYNO_UNITS["temperature"][self.units]
            return factor * (x - zero)
        return self.sign * DYNO_UNITS[self.canonical][self.units] * x


@dataclass(frozen=True)
class DynoMap:
    """A checked dyno map: canonical column -> :class:`DynoColumn`.

    Attributes
    ----------
    columns : mapping of str to DynoColumn
        Read-only: ``time``, ``force``, ``displacement`` and maybe ``temperature``.
    name : str
        Shown in messages.
    path : pathlib.Path or None
        The file it was read from.
    """

    columns: Mapping = field(default_factory=dict)
    name: str = "dyno map"
    path: Path | None = None

    def __post_init__(self):
        ordered = {c: self.columns[c] for c in DYNO_COLUMNS if c in self.columns}
        object.__setattr__(self, "columns", MappingProxyType(ordered))

    @property
    def where(self):
        """str: How the map is named in messages."""
        return f"dyno map {self.path}" if self.path is not None else self.name


def _normalize_unit(units, quantity):
    if not isinstance(units, str):
        return None
    u = units.strip()
    u = _UNIT_ALIASES.get(u, u)
    return u if u in DYNO_UNITS[quantity] else None


def _map_number(value, *, where, key, nonzero=False):
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or \
            not math.isfinite(float(value)) or (nonzero and float(value) == 0.0):
        need = "a finite non-zero number" if nonzero else "a finite number"
        raise DynoError(f"{where}: {key} = {value!r} must be {need}; write it without quotes")
    return float(value)


def _column_from_table(canonical, table, *, where):
    entry = f"{where}: [columns.{canonical}]"
    if canonical not in DYNO_COLUMNS:
        raise DynoError(f"{entry}: {canonical!r} is not a dyno column"
                        f"{did_you_mean(canonical, DYNO_COLUMNS, cutoff=0.6)}; the columns are "
                        f"{', '.join(DYNO_COLUMNS)}")
    if not isinstance(table, Mapping):
        raise DynoError(f"{entry}: must be a table with source and units, got {table!r}")
    keys = _ENTRY_KEYS[canonical]
    for key in table:
        if key not in keys:
            extra = " (time and temperature have no sign)" if key == "sign" else ""
            raise DynoError(f"{entry}: unknown key {key!r}{did_you_mean(key, keys)}{extra}; "
                            f"the keys are {', '.join(keys)}")
    required = ("source", "units", "sign") if "sign" in keys else ("source", "units")
    for key in required:
        if key not in table:
            why = (" (+1 if the dyno logs compression positive, -1 if the opposite)"
                   if key == "sign" else "")
            raise DynoError(f"{entry}: missing {key!r}{why}; give {', '.join(required)}")
    source = table["source"]
    if not isinstance(source, str) or not source.strip():
        raise DynoError(f"{entry}: source = {source!r} must be the column's name in the file")
    units = _normalize_unit(table["units"], canonical)
    if units is None:
        accepted = ", ".join(repr(u) for u in DYNO_UNITS[canonical])
        raise DynoError(f"{entry}: units = {table['units']!r} is not a {canonical} unit; use "
                        f"one of {accepted}")
    sign = table.get("sign", 1)
    if isinstance(sign, bool) or not isinstance(sign, numbers.Real) or sign not in (1, -1):
        raise DynoError(f"{entry}: sign = {sign!r} must be 1 or -1 (-1 if the dyno's "
                        "convention is the opposite of compression positive)")
    return DynoColumn(canonical=canonical, source=source, units=units, sign=int(sign),
                      scale=_map_number(table.get("scale", 1.0), where=entry, key="scale",
                                        nonzero=True),
                      offset=_map_number(table.get("offset", 0.0), where=entry, key="offset"))


def make_dyno_map(columns, *, name="dyno map", path=None):
    """Build a checked :class:`DynoMap` from plain tables (as in the TOML file).

    Parameters
    ----------
    columns : mapping of str to mapping
        Canonical column -> ``{"source", "units", "sign" (force and displacement),
        "scale", "offset"}``.
    name : str
        The map's name in messages.
    path : str or os.PathLike, optional
        The file the tables came from.

    Returns
    -------
    DynoMap

    Raises
    ------
    DynoError
        An unknown column or key, a missing ``time``, ``force`` or ``displacement``
        entry or key, a unit not of the column's quantity, a sign not +-1, a zero scale,
        or two columns with one source.
    """
    path = None if path is None else Path(path)
    where = f"dyno map {path}" if path is not None else str(name)
    if not isinstance(columns, Mapping):
        raise DynoError(f"{where}: [columns] must be a table of [columns.<name>] tables")
    cols = {c: _column_from_table(c, t, where=where) for c, t in columns.items()}
    for canonical, (_, required) in DYNO_COLUMNS.items():
        if required and canonical not in cols:
            raise DynoError(f"{where}: no [columns.{canonical}]; a dyno map names the file's "
                            f"time, force and displacement columns (the import needs the "
                            f"displacement to find the strokes)")
    seen = {}
    for c, col in cols.items():
        if col.source in seen:
            raise DynoError(f"{where}: [columns.{c}] source {col.source!r} is already the "
                            f"source of {seen[col.source]!r}; each file column holds one")
        seen[col.source] = c
    return DynoMap(columns=cols, name=str(name), path=path)


def read_dyno_map(path):
    """Read and check a dyno-map TOML file (format in the module docstring).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    DynoMap
        ``name`` defaults to the file's name.

    Raises
    ------
    DynoError
        A missing or malformed file, a ``format`` other than ``"dyno-map/1"``, an unknown
        top-level key, or an entry refused by :func:`make_dyno_map`.
    """
    path = Path(path)
    doc = read_toml(path, error=DynoError, what="dyno map")
    where = f"dyno map {path}"
    fmt = doc.get("format")
    if fmt != DYNO_MAP_FORMAT:
        got = "no 'format' key" if fmt is None else f"format {fmt!r}"
        raise DynoError(f"{where}: {got}; a dyno map starts with format = "
                        f"\"{DYNO_MAP_FORMAT}\"")
    for key in doc:
        if key not in _TOP_KEYS:
            raise DynoError(f"{where}: unknown top-level key {key!r}"
                            f"{did_you_mean(key, _TOP_KEYS)}; the keys are "
                            f"{', '.join(_TOP_KEYS)} and the [columns.<name>] tables")
    name = doc.get("name", path.name)
    if not isinstance(name, str):
        raise DynoError(f"{where}: name = {name!r} must be a string")
    return make_dyno_map(doc.get("columns", {}), name=name, path=path)


# --------------------------------------------------------------------------------------
# reading a raw file
# --------------------------------------------------------------------------------------


def _default_map(units, where):
    """The map of a file with canonical columns in `units` (the file's marker)."""
    imperial = units == "imperial"
    cols = {"time": DynoColumn("time", "time", "s"),
            "force": DynoColumn("force", "force", "lbf" if imperial else "N"),
            "displacement": DynoColumn("displacement", "displacement",
                                       "in" if imperial else "m"),
            "temperature": DynoColumn("temperature", "temperature", "degC")}
    return DynoMap(columns=cols, name=f"{where} (canonical columns, {units})")


def _read_table(path, where):
    """The file's table (pandas) and its unit marker."""
    # pandas is imported here, not at the top, to keep it off the command line's start-up
    import pandas as pd

    if path.suffix.lower() in (".parquet", ".pq"):
        try:
            return pd.read_parquet(path), read_units_marker(path, where=where, error=DynoError)
        except (OSError, ValueError) as exc:
            if isinstance(exc, DynoError):
                raise
            raise DynoError(f"{where}: cannot read the Parquet file ({exc}); check the "
                            "file") from None
    return read_csv_table(path, where=where, error=DynoError)


def _raw_columns(path, dyno_map):
    """``(SI columns, source names, where)`` of a raw dyno file."""
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise DynoError(f"{where}: raw dyno file not found; check the path")
    frame, marker = _read_table(path, where)
    names = {str(c).strip(): c for c in frame.columns}
    if dyno_map is None:
        cmap = _default_map(marker or "SI", where)
        lower = {k.lower(): k for k in names}
        names = {c: names[lower[c]] for c in DYNO_COLUMNS if c in lower}
        how = ("give the file canonical columns time [s], force [N], displacement [m] "
               "(temperature [deg C] optional), or a dyno map (--map) naming its columns")
    else:
        if not isinstance(dyno_map, DynoMap):
            dyno_map = read_dyno_map(dyno_map)
        cmap = dyno_map
        how = f"fix source in [columns.<name>] of {cmap.where}"
    out, sources = {}, {}
    for canonical, col in cmap.columns.items():
        if col.source not in names:
            if dyno_map is None and not DYNO_COLUMNS[canonical][1]:
                continue
            what = (" (velocity alone is not enough: the import finds the strokes and "
                    "differentiates the displacement itself)" if canonical == "displacement"
                    else "")
            raise DynoError(f"{where}: no column {col.source!r} ({canonical}){what}; the file "
                            f"has {list(map(str, frame.columns))}"
                            f"{did_you_mean(col.source, names, cutoff=0.6)}; {how}")
        raw = frame[names[col.source]]
        values = _numeric(raw, where=where, column=col.source, canonical=canonical)
        out[canonical] = col.convert(values)
        sources[canonical] = col.source
    return out, sources, where


def _numeric(raw, *, where, column, canonical):
    import pandas as pd  # off the start-up path, as in _read_table

    num = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(num))
    if bad.size:
        r = int(bad[0])
        raise DynoError(f"{where}: column {column!r} ({canonical}) has {bad.size} NaN, empty "
                        f"or non-numeric value(s), the first at data row {r + 1} "
                        f"({raw.iloc[r]!r}); fill or cut those rows")
    return num


def _check_columns(cols, sources, where):
    """Refuse NaNs, flat-lined force or displacement, and bad time (SI columns)."""
    n = cols["time"].size
    for canonical, x in cols.items():
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            raise DynoError(f"{where}: column {sources[canonical]!r} ({canonical}) has "
                            f"{bad.size} NaN or infinite value(s), the first at data row "
                            f"{bad[0] + 1}; fill or cut those rows")
    if n < 4 * (_DIFF_ORDER + 2):
        raise DynoError(f"{where}: only {n} samples; a dyno run has thousands (several "
                        "cycles at the dyno's rate); check the export")
    for canonical in ("force", "displacement"):
        x = cols[canonical]
        if np.ptp(x) <= 1e-12 * max(1.0, float(np.max(np.abs(x)))):
            raise DynoError(f"{where}: column {sources[canonical]!r} ({canonical}) is flat "
                            f"(the same value {_num(x[0])} in all {n} samples): the channel is "
                            "dead or not the one logged; check the sensor, or the source in "
                            "the dyno map")
    t = cols["time"]
    dt = np.diff(t)
    # a PC's time stamps, rounded to whole milliseconds (or 0.1 ms ...), of a uniform clock:
    # each stamp is within half a quantum of the grid, so a step may differ by a quantum
    i = np.arange(n, dtype=float)
    slope, icpt = np.polyfit(i, t, 1)
    quantum = time_resolution(t)
    if quantum and abs(slope / quantum - round(slope / quantum)) < 0.01:
        quantum = 0.0  # the interval is whole quanta: the stamps are exact, nothing rounded
    med = float(np.median(dt))
    bad = np.flatnonzero(dt < 0 if quantum >= med else dt <= 0)
    if bad.size:
        j = int(bad[0])
        raise DynoError(f"{where}: column {sources['time']!r} (time) is not increasing at data "
                        f"row {j + 2} ({_num(t[j])} then {_num(t[j + 1])} s); export one run "
                        "per file, sorted by time, without repeated samples")
    if med <= 0:
        raise DynoError(f"{where}: column {sources['time']!r} (time) repeats most stamps (its "
                        f"resolution {_num(quantum)} s is coarser than the sample interval): "
                        "export time with more decimals")
    bad = np.flatnonzero(np.abs(dt - med) > TIME_GRID_SHARE * med + quantum)
    if bad.size:  # a step: a dropped or repeated sample
        j = int(bad[0]) + 1
        raise DynoError(f"{where}: column {sources['time']!r} (time) is not uniformly sampled: "
                        f"data row {j + 1} (t = {_num(t[j])} s) comes {_num(dt[j - 1])} s after "
                        f"the row before, the file's interval is {_num(med)} s (dropped or "
                        "repeated samples, or a changed rate); export at one constant rate")
    off = np.abs(t - (icpt + slope * i))
    bad = np.flatnonzero(off > TIME_GRID_SHARE * slope + 0.5 * quantum)
    if bad.size:  # a drift
        j = int(bad[0])
        raise DynoError(f"{where}: column {sources['time']!r} (time) is not uniformly sampled: "
                        f"data row {j + 1} (t = {_num(t[j])} s) is {off[j] / slope:.2g} sample "
                        f"intervals off the {_num(1.0 / slope)} Hz grid (dropped or repeated "
                        "samples, or a changed rate); export at one constant rate")
    if np.any(off > TIME_GRID_SHARE * slope):
        logger.warning("%s: time stamps rounded to %s s (steps of %s-%s s): taken as the "
                       "uniform %s Hz grid they round", where, _num(quantum), _num(dt.min()),
                       _num(dt.max()), _num(nominal_rate(1.0 / slope)))


def time_resolution(time_s):
    """The resolution a file's time stamps are rounded to [s], or 0 for full precision.

    Parameters
    ----------
    time_s : ndarray, shape (n,)

    Returns
    -------
    float
        The coarsest of 1 ms, 0.1 ms, 10 us, 1 us that every stamp is a whole multiple of
        (within float rounding); 0.0 if none.

    Examples
    --------
    >>> time_resolution(np.round(np.arange(10) / 512.0, 3)), time_resolution(np.arange(3) / 3)
    (0.001, 0.0)
    """
    t = np.asarray(time_s, dtype=float)
    for quantum in TIME_QUANTA:
        k = np.round(t / quantum)
        if np.all(np.abs(t - k * quantum) <= 1e-9 * quantum + 4 * np.spacing(np.abs(t))):
            return quantum
    return 0.0


def _on_rate(cols, where, resample_hz):
    """Checked columns on a uniform base at `resample_hz` [Hz] (``--resample``), said in a
    warning; as they are without it. The samples are taken on the uniform clock their
    stamps round (the stamps' least-squares line, at the nominal rate of
    :func:`ident.data.timebase.nominal_rate`), then resampled
    (:func:`ident.data.timebase.uniform_time_base`: band-limited, anti-aliased when going
    down)."""
    if resample_hz is None:
        return cols
    t = cols["time"]
    i = np.arange(t.size, dtype=float)
    slope, icpt = np.polyfit(i, t, 1)
    base = uniform_time_base(icpt + i / nominal_rate(1.0 / slope), where=where, error=DynoError,
                             resample_hz=resample_hz)
    if not base.resampled:
        return cols
    logger.warning(base.describe(where))
    return {c: base.time_s if c == "time" else base.resample(x) for c, x in cols.items()}


def read_dyno_raw(path, *, dyno_map=None, resample_hz=None):
    """Read a raw dyno file into checked SI columns.

    Parameters
    ----------
    path : str or os.PathLike
        A CSV (header row after optional ``#`` lines) or Parquet file.
    dyno_map : DynoMap or path, optional
        The file's columns, units and signs; without it the file has the canonical
        columns in SI (or in imperial units with a ``units`` column holding
        ``imperial``, or the marker line ``# units: imperial``).
    resample_hz : float, optional
        Resample the run onto a uniform base at this rate [Hz] (``--resample``;
        band-limited, anti-aliased when going down), said in a logged warning. Default:
        the file's rate.

    Returns
    -------
    pandas.DataFrame, shape (n_samples, 3 or 4)
        Columns ``time`` [s], ``force`` [N], ``displacement`` [m], compression positive,
        and ``temperature`` [deg C] where the file has it.

    Raises
    ------
    DynoError
        A missing file or column, NaN or non-numeric values, a flat-lined force or
        displacement, time not increasing or not uniform.
    """
    import pandas as pd  # off the start-up path, as in _read_table

    cols, sources, where = _raw_columns(path, dyno_map)
    _check_columns(cols, sources, where)
    return pd.DataFrame(_on_rate(cols, where, resample_hz))


def parse_settings(text):
    """Parse adjuster settings ``"ls=6,hs=2"`` into ``{"ls": 6.0, "hs": 2.0}``.

    Parameters
    ----------
    text : str
        Comma-separated ``name=value`` pairs (empty: no adjusters).

    Returns
    -------
    dict of str to float
        In the order given.

    Raises
    ------
    DynoError
        A pair without ``=``, a bad name (letters, digits, ``_``, ``-``; not a sheet
        column), a value that is not a finite number, or a name given twice.
    """
    out = {}
    for part in (p.strip() for p in str(text).split(",")):
        if not part:
            continue
        name, sep, value = (s.strip() for s in part.partition("="))
        if not sep:
            raise DynoError(f"settings: {part!r} is not name=value; write e.g. ls=6,hs=2")
        if name in out:
            raise DynoError(f"settings: adjuster {name!r} is given twice; give each once")
        out[_check_adjuster(name, "settings")] = _check_setting(name, value, "settings")
    return out


def _check_adjuster(name, where):
    if not isinstance(name, str) or not _NAME.match(name) or name.lower() in _RESERVED:
        raise DynoError(f"{where}: {name!r} is not an adjuster name; use letters, digits, _ "
                        f"and - (not {', '.join(sorted(_RESERVED))}), e.g. ls or hs")
    return name


def _check_setting(name, value, where):
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    if isinstance(value, bool) or not math.isfinite(x):
        raise DynoError(f"{where}: adjuster {name!r} = {value!r} is not a finite number; give "
                        "its setting in clicks or turns, e.g. ls=6")
    return x


# --------------------------------------------------------------------------------------
# the analysis
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DynoBlock:
    """One peak-velocity block of a dyno run: its sheet points and averaged loop.

    Attributes
    ----------
    bump_velocity_m_s, rebound_velocity_m_s : float
        Mean peak velocity [m/s] of the block's bump and rebound half-cycles, magnitudes.
    bump_force_n, rebound_force_n : float
        Force [N] at those velocities, magnitudes, the gas force and the lag removed.
    cycles : int
        Cycles averaged.
    temperature_c : float or None
        Mean oil temperature [deg C] over the block.
    loop_velocity_m_s, loop_force_n : ndarray, shape (LOOP_POINTS,)
        The averaged loop: velocity [m/s] and force [N] (gas removed, lag kept) at
        evenly spaced phases from full extension, over the block's cycles.
    """

    bump_velocity_m_s: float
    bump_force_n: float
    rebound_velocity_m_s: float
    rebound_force_n: float
    cycles: int
    temperature_c: float | None
    loop_velocity_m_s: np.ndarray = field(repr=False)
    loop_force_n: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class DynoRun:
    """The analysis of one raw dyno file (:func:`analyze_dyno_run`).

    Attributes
    ----------
    source : str
        The file's name (the sheet's ``source``).
    fs_hz : float
        Sample rate [Hz].
    n_samples : int
    cycles : int
        Cycles found in the whole file (blocks' and left-out ones).
    blocks : tuple of DynoBlock
        In program order.
    gas_force_n : float
        The gas-force offset [N] removed (compression positive).
    lag_s : float
        The lag estimate [s] (the hysteresis), >= 0.
    fit_rms_n : float
        RMS residual [N] of the gas and lag fit (noise plus what the model misses).
    temperature_c : float or None
        Mean oil temperature [deg C] over the blocks' cycles.
    temperature_rise_c : float or None
        Last block's mean temperature minus the first's [deg C].
    settings : dict
        The analysis settings (peak_window, min_cycles, block_rtol, diff_window_share).
    """

    source: str
    fs_hz: float
    n_samples: int
    cycles: int
    blocks: tuple
    gas_force_n: float
    lag_s: float
    fit_rms_n: float
    temperature_c: float | None
    temperature_rise_c: float | None
    settings: Mapping = field(default_factory=dict, repr=False)

    def points(self):
        """The run's sheet points, sorted by velocity.

        Returns
        -------
        velocity_m_s, force_n : ndarray, shape (2 * n_blocks,)
            Signed (rebound negative), compression positive.
        """
        v = [b.bump_velocity_m_s for b in self.blocks] + \
            [-b.rebound_velocity_m_s for b in self.blocks]
        f = [b.bump_force_n for b in self.blocks] + [-b.rebound_force_n for b in self.blocks]
        order = np.argsort(v)
        return np.asarray(v)[order], np.asarray(f)[order]


@dataclass(frozen=True)
class DynoImport:
    """Raw dyno files at one setting turned into dyno-sheet rows (:func:`import_dyno_runs`).

    Attributes
    ----------
    settings : mapping of str to float
        The adjusters' settings of every file, in the order given (read-only).
    runs : tuple of DynoRun
        One per file, in the order given.
    warnings : tuple of str
        Warnings (temperature drift), also logged.
    map_name : str or None
        The dyno map used (None: canonical columns).
    options : mapping
        The analysis options used (min_cycles, peak_window, temperature_drift_c).
    """

    settings: Mapping
    runs: tuple
    warnings: tuple = ()
    map_name: str | None = None
    options: Mapping = field(default_factory=dict)

    def points(self):
        """The curve at this setting: every run's points, repeats merged.

        Points closer in velocity than 1 % (the same block of repeated runs) are
        averaged.

        Returns
        -------
        velocity_m_s, force_n : ndarray, shape (n_points,)
            Signed, sorted by velocity, compression positive.
        """
        v = np.concatenate([r.points()[0] for r in self.runs])
        f = np.concatenate([r.points()[1] for r in self.runs])
        order = np.argsort(v)
        v, f = v[order], f[order]
        groups = np.concatenate([[0], np.cumsum(np.abs(np.diff(v)) >
                                                _MERGE_RTOL * np.abs(v[1:]))])
        count = np.bincount(groups)
        return np.bincount(groups, v) / count, np.bincount(groups, f) / count

    def report(self, *, units="SI"):
        """The import for a terminal: one block of lines per file, then the warnings.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Velocity and force units of the report.

        Returns
        -------
        str
        """
        lab = UNIT_LABELS[units]
        settings = ",".join(f"{k}={v:g}" for k, v in self.settings.items()) or "(no adjusters)"
        lines = [f"dyno import at {settings}: {len(self.runs)} file(s)"]
        for run in self.runs:
            speeds = [b.bump_velocity_m_s for b in run.blocks]
            temp = ("no temperature" if run.temperature_c is None else
                    f"temperature {run.temperature_c:.1f} deg C (rise "
                    f"{run.temperature_rise_c:+.1f})")
            lines.append(
                f"  {run.source}: {run.cycles} cycles, {len(run.blocks)} speeds "
                f"{from_si(min(speeds), 'velocity', units):.4g}-"
                f"{from_si(max(speeds), 'velocity', units):.4g} {lab['velocity']}, gas force "
                f"{from_si(run.gas_force_n, 'force', units):.4g} {lab['force']} (removed), lag "
                f"{run.lag_s * 1e3:.2f} ms, {temp}")
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def sheet(self, units="SI"):
        """The sheet rows as a table in `units` (what :func:`write_dyno_sheet` writes).

        Parameters
        ----------
        units : {"SI", "imperial"}
            Velocity m/s or in/s, force N or lbf; temperature deg C and lag s always.

        Returns
        -------
        pandas.DataFrame
            Columns ``velocity, force``, the adjusters, ``temperature`` (when any run
            has it), ``cycles``, ``lag``, ``source``; per run, rows sorted by velocity.
        """
        import pandas as pd  # off the start-up path, as in _read_table

        units = check_units(units, where="units", error=DynoError)
        with_temp = any(r.temperature_c is not None for r in self.runs)
        rows = []
        for run in self.runs:
            for b in run.blocks:
                for sign, v, f in ((-1.0, b.rebound_velocity_m_s, b.rebound_force_n),
                                   (1.0, b.bump_velocity_m_s, b.bump_force_n)):
                    row = {"velocity": from_si(sign * v, "velocity", units),
                           "force": from_si(sign * f, "force", units), **self.settings}
                    if with_temp:
                        row["temperature"] = b.temperature_c
                    row.update(cycles=b.cycles, lag=run.lag_s, source=run.source)
                    rows.append(row)
        frame = pd.DataFrame(rows, columns=self.columns)
        key = {r.source: j for j, r in enumerate(self.runs)}
        frame["_run"] = frame["source"].map(key)
        frame = frame.sort_values(["_run", "velocity"], kind="stable").drop(columns="_run")
        return frame.reset_index(drop=True)

    @property
    def columns(self):
        """list of str: The sheet's columns (see :meth:`sheet`)."""
        tail = [c for c in SHEET_COLUMNS[1] if c != "temperature"
                or any(r.temperature_c is not None for r in self.runs)]
        return [*SHEET_COLUMNS[0], *self.settings, *tail]


def _odd_window(n_samples):
    w = max(_DIFF_ORDER + 2, int(round(n_samples)))
    return w if w % 2 else w + 1


def _episodes(x):
    """Runs of samples above (+1) / below (-1) mid-stroke beyond the hysteresis band:
    ``[(state, first, last), ...]`` alternating."""
    lo, hi = float(np.min(x)), float(np.max(x))
    mid, band = 0.5 * (lo + hi), _STROKE_HYSTERESIS * 0.5 * (hi - lo)
    s = np.where(x > mid + band, 1, np.where(x < mid - band, -1, 0))
    nz = np.flatnonzero(s)
    if nz.size == 0:
        return []
    lab = s[nz]
    cut = np.flatnonzero(np.diff(lab) != 0)
    starts = np.concatenate([[0], cut + 1])
    ends = np.concatenate([cut, [nz.size - 1]])
    return [(int(lab[a]), int(nz[a]), int(nz[b])) for a, b in zip(starts, ends)]


def _extremes(x):
    """Indices of the displacement's alternating extremes, and their kinds (+1 max, -1 min).

    An episode's extreme lies between its neighbours' ends. The first and last episodes
    reach the file's edge: an extreme at the very edge counts only when it is a turn, as
    deep as the nearest extreme of its kind (within :data:`_EDGE_TURN_SHARE` of the
    stroke), not a file cut mid-stroke."""
    eps = _episodes(x)
    n = x.size
    found = []
    for j, (state, _, _) in enumerate(eps):
        a = eps[j - 1][2] + 1 if j > 0 else 0
        b = eps[j + 1][1] - 1 if j + 1 < len(eps) else n - 1
        seg = x[a:b + 1]
        e = a + int(np.argmax(seg) if state > 0 else np.argmin(seg))
        at_edge = (j == 0 and e - a < 3) or (j + 1 == len(eps) and b - e < 3)
        found.append((e, state, at_edge))
    inner = [(e, k) for e, k, edge in found if not edge]
    stroke = float(np.ptp(x))
    idx, kind = [], []
    for e, k, edge in found:
        if edge:
            same = [i for i, kk in inner if kk == k]
            if not same:
                continue
            ref = min(same, key=lambda i: abs(i - e))
            if abs(float(x[e]) - float(x[ref])) > _EDGE_TURN_SHARE * stroke:
                continue
        idx.append(e)
        kind.append(k)
    return np.asarray(idx, dtype=int), np.asarray(kind, dtype=int)


def _derivatives(x, f, starts, ends, fs):
    """Savitzky-Golay velocity and force derivative over each cycle [starts, ends].

    A cycle's window reaches into a neighbouring cycle only when the two have the same
    period and stroke (within :data:`BLOCK_RTOL`): where a program changes speed the
    acceleration steps, and a window across the step would bend the velocity near 0
    (by 1 % of the peak velocity at a 25 % step, measured), so there the cycle's own
    samples are fitted (one-sided at its end)."""
    from scipy.signal import savgol_filter  # off the start-up path, as pandas

    n = x.size
    v = np.full(n, np.nan)
    fdot = np.full(n, np.nan)
    period = (ends - starts).astype(float)
    stroke = np.array([np.ptp(x[a:b + 1]) for a, b in zip(starts, ends)])

    def same(j, k):
        return (0 <= k < starts.size and ends[min(j, k)] == starts[max(j, k)]
                and abs(period[k] / period[j] - 1.0) <= BLOCK_RTOL
                and abs(stroke[k] / stroke[j] - 1.0) <= BLOCK_RTOL)

    for j, (a, b) in enumerate(zip(starts, ends)):
        w = _odd_window(DIFF_WINDOW_SHARE * (b - a))
        lo = max(0, a - w) if same(j, j - 1) else a
        hi = min(n, b + w + 1) if same(j, j + 1) else b + 1
        if hi - lo < w:
            w = _odd_window(hi - lo - 2)
        seg = slice(lo, hi)
        keep = slice(a - lo, b + 1 - lo)
        v[a:b + 1] = savgol_filter(x[seg], w, _DIFF_ORDER, deriv=1, delta=1.0 / fs)[keep]
        fdot[a:b + 1] = savgol_filter(f[seg], w, _DIFF_ORDER, deriv=1, delta=1.0 / fs)[keep]
    return v, fdot


def _hat_basis(v, knots):
    """Hat functions on `knots` at `v`: shape (v.size, knots.size), rows summing to 1."""
    j = np.clip(np.searchsorted(knots, v) - 1, 0, knots.size - 2)
    w = np.clip((v - knots[j]) / (knots[j + 1] - knots[j]), 0.0, 1.0)
    basis = np.zeros((v.size, knots.size))
    rows = np.arange(v.size)
    basis[rows, j] = 1.0 - w
    basis[rows, j + 1] = w
    return basis


def _lag_filter(u, lag_s, dt):
    """``lag * dF/dt + F = u`` along the last axis, u linear between samples (first-order
    hold, exact for such u), starting at rest (``F = u`` at the first sample)."""
    from scipy.signal import lfilter  # off the start-up path, as pandas

    if lag_s <= 0.0:
        return u
    a = math.exp(-dt / lag_s)
    b0 = 1.0 - lag_s / dt * (1.0 - a)
    b1 = (1.0 - a) - b0
    y, _ = lfilter([b0, b1], [1.0, -a], u, axis=-1, zi=(1.0 - b0) * u[..., :1])
    return y


def _gas_and_lag(v, f, rows, fs, vmax):
    """The gas force and the lag: least squares ``F = L_lag[g(v)]``.

    `v`, `f`: shape (n,), contiguous samples; `rows`: those fitted. ``g`` is linear in
    its hat-function coefficients, so for a given lag the fit is linear least squares;
    the lag is a bounded 1-D search of its residual. Returns (gas = g(0), lag, rms)."""
    from scipy.optimize import minimize_scalar  # off the start-up path, as pandas

    sel = np.flatnonzero(rows)
    sel = sel[::max(1, sel.size // _FIT_MAX_ROWS)]
    # knots at quantiles of |v|: as many samples between any two, so that no coefficient
    # rests on a handful of noisy samples (a sine crosses low speeds fastest)
    pos = np.quantile(np.abs(v[sel]), np.arange(1, N_KNOTS + 1) / N_KNOTS)
    pos[-1] = 1.001 * vmax
    pos = np.unique(pos[pos > 0])
    knots = np.concatenate([-pos[::-1], [0.0], pos])
    basis = np.ascontiguousarray(_hat_basis(v, knots).T)  # (knots, samples): filtered fast
    target = f[sel]

    def fit(lag):
        # normal equations (a few unknowns, many rows: 20x faster than lstsq); a knot
        # without samples is held at 0 by the tiny ridge
        a = _lag_filter(basis, lag, 1.0 / fs)[:, sel]
        gram = a @ a.T
        gram[np.diag_indices_from(gram)] += 1e-12 * np.trace(gram) / gram.shape[0]
        coef = np.linalg.solve(gram, a @ target)
        resid = target - coef @ a
        return coef, float(resid @ resid)

    res = minimize_scalar(lambda lag: fit(lag)[1], bounds=(0.0, LAG_MAX_S), method="bounded",
                          options={"xatol": 1e-5})
    lag = float(res.x) if res.fun < fit(0.0)[1] else 0.0
    coef, sse = fit(lag)
    if lag > 0.99 * LAG_MAX_S:
        logger.warning("lag estimate at the search's bound %.3g s: the loop's hysteresis is "
                       "not a first-order lag (friction, inertia or a loose mount?)", LAG_MAX_S)
    return float(coef[pos.size]), lag, math.sqrt(sse / sel.size)


def _peak_point(v, u, halves, sign):
    """Force at the mean peak |v| of the half-cycles [(a, b), ...] of one side."""
    vs, us, peaks = [], [], []
    for a, b in halves:
        seg = sign * v[a:b + 1]
        peak = float(np.max(seg))
        keep = seg >= (1.0 - PEAK_WINDOW) * peak
        vs.append(seg[keep])
        us.append(sign * u[a:b + 1][keep])
        peaks.append(peak)
    vs, us = np.concatenate(vs), np.concatenate(us)
    vp = float(np.mean(peaks))
    if vs.size >= 3 and np.ptp(vs) > 0:
        slope, icpt = np.polyfit(vs - vp, us, 1)
        return vp, float(icpt)
    return vp, float(np.mean(us))


def _loop(v, fg, starts, ends):
    phase = np.linspace(0.0, 1.0, LOOP_POINTS, endpoint=False)
    lv, lf = [], []
    for a, b in zip(starts, ends):
        s = a + phase * (b - a)
        grid = np.arange(a, b + 1)
        lv.append(np.interp(s, grid, v[a:b + 1]))
        lf.append(np.interp(s, grid, fg[a:b + 1]))
    return np.mean(lv, axis=0), np.mean(lf, axis=0)


def analyze_dyno_run(frame, *, source="dyno run", min_cycles=MIN_CYCLES):
    """Analyze one dyno run: cycles, blocks, gas force, lag and sheet points.

    Parameters
    ----------
    frame : pandas.DataFrame
        SI columns ``time`` [s], ``force`` [N], ``displacement`` [m] (compression
        positive) and optional ``temperature`` [deg C] (:func:`read_dyno_raw`,
        :func:`ident.dyno.virtual.simulate_dyno_run`).
    source : str
        The run's name in messages and in the sheet.
    min_cycles : int
        Cycles a peak-velocity block needs to count (>= 1).

    Returns
    -------
    DynoRun

    Raises
    ------
    DynoError
        A missing column, NaNs, a flat-lined channel, bad time (as :func:`read_dyno_raw`),
        fewer than `min_cycles` cycles at every peak velocity, or a point whose force
        has the wrong sign once the gas force is removed.

    Notes
    -----
    The steps are those of the module docstring; SI throughout.
    """
    missing = [c for c, (_, req) in DYNO_COLUMNS.items() if req and c not in frame.columns]
    if missing:
        raise DynoError(f"{source}: no column {missing[0]!r}; the run needs time [s], force "
                        "[N] and displacement [m]")
    cols = {c: np.asarray(frame[c], dtype=float) for c in DYNO_COLUMNS if c in frame.columns}
    _check_columns(cols, {c: c for c in cols}, source)
    return _analyze(cols, {c: c for c in cols}, source, int(min_cycles))


def _analyze(cols, sources, where, min_cycles):
    t, f, x = cols["time"], cols["force"], cols["displacement"]
    temp = cols.get("temperature")
    fs = (t.size - 1) / (t[-1] - t[0])
    idx, kind = _extremes(x)
    # a cycle: full extension (min) -> full compression (max) -> full extension
    mins = np.flatnonzero(kind < 0)
    cyc = [(idx[j], idx[j + 1], idx[j + 2]) for j in mins if j + 2 < idx.size]
    need = (f"; a dyno run needs at least {min_cycles} whole strokes (full extension, "
            "compression and back) at each peak velocity: log longer, or check that "
            f"{sources['displacement']!r} is the shaft's position")
    if len(cyc) < min_cycles:
        raise DynoError(f"{where}: too few cycles: {len(cyc)} whole cycle(s) in column "
                        f"{sources['displacement']!r} (displacement){need}")
    starts = np.array([c[0] for c in cyc])
    ends = np.array([c[2] for c in cyc])
    v, fdot = _derivatives(x, f, starts, ends, fs)
    peak_b = np.array([np.max(v[a:m + 1]) for a, m, _ in cyc])
    peak_r = np.array([-np.min(v[m:b + 1]) for _, m, b in cyc])
    speed = 0.5 * (peak_b + peak_r)
    groups, cur = [], [0]
    for j in range(1, len(cyc)):
        if abs(speed[j] / np.mean(speed[cur]) - 1.0) <= BLOCK_RTOL:
            cur.append(j)
        else:
            groups.append(cur)
            cur = [j]
    groups.append(cur)
    kept = [g for g in groups if len(g) >= min_cycles]
    if not kept:
        raise DynoError(f"{where}: too few cycles: {len(cyc)} cycle(s) at {len(groups)} peak "
                        f"velocities, none with {min_cycles} in a row{need}")
    dropped = len(groups) - len(kept)
    if dropped:
        logger.info("%s: %d peak-velocity group(s) of fewer than %d cycles left out "
                    "(transitions)", where, dropped, min_cycles)
    span = slice(starts[0], ends[-1] + 1)
    rows = np.zeros(t.size, dtype=bool)
    for g in kept:
        rows[starts[g[0]]:ends[g[-1]] + 1] = True
    used = np.flatnonzero(rows)
    vmax = float(np.max(np.abs(v[used])))
    gas, lag, rms = _gas_and_lag(v[span], f[span], rows[span], fs, vmax)
    u = f + lag * fdot - gas
    blocks = []
    for g in kept:
        bump = [(cyc[j][0], cyc[j][1]) for j in g]
        reb = [(cyc[j][1], cyc[j][2]) for j in g]
        vb, fb = _peak_point(v, u, bump, 1.0)
        vr, fr = _peak_point(v, u, reb, -1.0)
        for side, vel, force in (("bump", vb, fb), ("rebound", vr, fr)):
            if force <= 0:
                raise DynoError(
                    f"{where}: the {side} force at {format_quantity(vel, 'velocity')} is "
                    f"{format_quantity(-force, 'force')} "
                    f"{'in rebound' if side == 'bump' else 'in compression'} once the gas "
                    f"force ({format_quantity(gas, 'force')}) is removed: not passive; check "
                    "the signs of "
                    f"{sources['force']!r} and {sources['displacement']!r} (compression "
                    "positive) in the dyno map")
        lv, lf = _loop(v, f - gas, starts[g], ends[g])
        tb = None if temp is None else float(np.mean(temp[starts[g[0]]:ends[g[-1]] + 1]))
        blocks.append(DynoBlock(vb, fb, vr, fr, len(g), tb, lv, lf))
    t_mean = None if temp is None else float(np.mean(temp[used]))
    rise = None if temp is None else blocks[-1].temperature_c - blocks[0].temperature_c
    run = DynoRun(source=where, fs_hz=float(fs), n_samples=int(t.size), cycles=len(cyc),
                  blocks=tuple(blocks), gas_force_n=gas, lag_s=lag, fit_rms_n=rms,
                  temperature_c=t_mean, temperature_rise_c=rise,
                  settings=MappingProxyType({"min_cycles": min_cycles,
                                             "peak_window": PEAK_WINDOW,
                                             "block_rtol": BLOCK_RTOL,
                                             "diff_window_share": DIFF_WINDOW_SHARE}))
    logger.info("%s: %d cycles, %d blocks %s-%s, gas %s, lag %.3g s", where,
                len(cyc), len(blocks), format_quantity(blocks[0].bump_velocity_m_s, "velocity"),
                format_quantity(blocks[-1].bump_velocity_m_s, "velocity"),
                format_quantity(gas, "force", digits=4), lag)
    return run


def import_dyno_runs(paths, *, settings, dyno_map=None, min_cycles=MIN_CYCLES,
                     temperature_drift_c=TEMPERATURE_DRIFT_C, resample_hz=None):
    """Turn raw dyno files, all at one setting, into dyno-sheet rows.

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        Raw dyno files (CSV or Parquet), one run each.
    settings : dict of str to float
        The adjusters' settings of the runs, in the sheet's column order (``{}`` for a
        shock without adjusters).
    dyno_map : DynoMap or path, optional
        The files' columns (default: canonical columns, see :func:`read_dyno_raw`).
    min_cycles : int
        Cycles a peak-velocity block needs to count.
    temperature_drift_c : float
        Spread of the runs' mean temperatures [deg C] warned of.
    resample_hz : float, optional
        Resample every run onto a uniform base at this rate [Hz] (``--resample``,
        :func:`read_dyno_raw`). Default: each file's rate.

    Returns
    -------
    DynoImport

    Raises
    ------
    DynoError
        No files, a file given twice, a bad setting or map, or a file refused by
        :func:`read_dyno_raw` or :func:`analyze_dyno_run` (the message names it).
    """
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    if not paths:
        raise DynoError("dyno import: no raw files given; give one or more CSV or Parquet "
                        "files")
    names = [p.name for p in paths]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DynoError(f"dyno import: file name {dup[0]!r} is given twice; each run's file "
                        "name is its source in the sheet, so give each file once")
    if not isinstance(settings, Mapping):
        raise DynoError(f"dyno import: settings must be a mapping such as {{'ls': 6.0}}, got "
                        f"{type(settings).__name__}")
    clean = {_check_adjuster(k, "settings"): _check_setting(k, s, "settings")
             for k, s in settings.items()}
    if dyno_map is not None and not isinstance(dyno_map, DynoMap):
        dyno_map = read_dyno_map(dyno_map)
    runs = []
    for p in paths:
        cols, sources, where = _raw_columns(p, dyno_map)
        _check_columns(cols, sources, where)
        run = _analyze(_on_rate(cols, where, resample_hz), sources, where, int(min_cycles))
        runs.append(_renamed(run, p.name))
    warnings = []
    temps = [(r.source, r.temperature_c) for r in runs if r.temperature_c is not None]
    if len(temps) > 1:
        lo, hi = min(temps, key=lambda s: s[1]), max(temps, key=lambda s: s[1])
        if hi[1] - lo[1] > temperature_drift_c:
            msg = (f"temperature drift at {_settings_text(clean)}: the runs' mean oil "
                   f"temperatures span {lo[1]:.1f} deg C ({lo[0]}) to {hi[1]:.1f} deg C "
                   f"({hi[0]}), more than {temperature_drift_c:g} deg C; the damping force "
                   "changes with it: let the damper settle between runs, or keep only the "
                   "runs at the temperature of use")
            logger.warning(msg)
            warnings.append(msg)
    return DynoImport(settings=MappingProxyType(clean), runs=tuple(runs),
                      warnings=tuple(warnings),
                      map_name=None if dyno_map is None else dyno_map.where,
                      options=MappingProxyType({"min_cycles": int(min_cycles),
                                                "peak_window": PEAK_WINDOW,
                                                "temperature_drift_c":
                                                    float(temperature_drift_c)}))


def _renamed(run, source):
    fields = {k: getattr(run, k) for k in run.__dataclass_fields__}
    fields["source"] = source
    return DynoRun(**fields)


def _settings_text(settings):
    return ",".join(f"{k}={_num(v)}" for k, v in settings.items()) or "the shock's one setting"


# --------------------------------------------------------------------------------------
# the sheet
# --------------------------------------------------------------------------------------


def _row_text(frame, columns):
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    for rec in frame.to_dict("records"):
        row = []
        for c in columns:
            value = rec[c]
            if c in ("source", UNITS_COLUMN):
                row.append(str(value))
            elif c == "cycles":
                row.append(str(int(value)))
            elif value is None or (isinstance(value, float) and math.isnan(value)):
                row.append("")
            else:
                row.append(_num(value))
        writer.writerow(row)
    return buf.getvalue()


def write_dyno_sheet(result, path, *, units="SI", append=False, overwrite=False):
    """Write (or append to) a dyno sheet CSV, atomically.

    Parameters
    ----------
    result : DynoImport
    path : str or os.PathLike
        The sheet.
    units : {"SI", "imperial"}
        Velocity m/s or in/s, force N or lbf (temperature deg C, lag s always). When
        appending it must be the existing sheet's (its ``units`` column or ``# units:``
        line, else SI).
    append : bool
        Add the rows to an existing sheet with the same columns, keeping every byte of
        it (a missing sheet is created).
    overwrite : bool
        Replace an existing sheet (without `append`).

    Returns
    -------
    tuple of str
        Warnings (also logged): with `append`, earlier rows at the same settings whose
        temperatures differ from these by more than the import's drift threshold.

    Raises
    ------
    FileExistsError
        If the sheet exists and neither `append` nor `overwrite` is given.
    DynoError
        When appending: a sheet in other units, or with other columns (the message
        names the missing and the extra ones).
    """
    if not isinstance(result, DynoImport):
        raise TypeError(f"result must be a DynoImport, got {type(result).__name__}")
    path = Path(path)
    units = check_units(units, where=f"{path}: units", error=DynoError)
    frame = result.sheet(units)
    columns = result.columns
    if not (append and path.exists()):
        check_can_write(path, overwrite=overwrite or append)
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow([*columns, UNITS_COLUMN])
        rows = _row_text(frame.assign(**{UNITS_COLUMN: units}), [*columns, UNITS_COLUMN])
        atomic_write_text(path, f"{buf.getvalue()}{rows}")
        logger.info("wrote %d dyno-sheet rows to %s", len(frame), path)
        return ()
    text = path.read_text(encoding="utf-8-sig")
    lines = text.splitlines()
    _, n = csv_preamble(lines, where=str(path), error=DynoError)
    # the marker line (an earlier sheet) or the units column, checked against each other
    marked = read_units_marker(path, error=DynoError) or "SI"
    if marked != units:
        raise DynoError(f"{path}: the sheet is in {marked} units but the rows to append are "
                        f"in {units}; append in {marked} (--units {marked})")
    if n >= len(lines):
        raise DynoError(f"{path}: has no header row; append to a dyno sheet written by "
                        "'shockplan dyno import', or write a new one")
    header = [c.strip() for c in next(csv.reader([lines[n]]))]
    header_data = [c for c in header if c != UNITS_COLUMN]  # a units column: this sheet's
    if sorted(header_data) != sorted(columns):
        missing = [c for c in columns if c not in header]
        extra = [c for c in header_data if c not in columns]
        raise DynoError(f"{path}: its columns {header} are not those of the rows to append "
                        f"{columns} (missing {missing}, extra {extra}); append runs with the "
                        "same adjusters (--settings) and temperature channel, or write a new "
                        "sheet")
    warnings = _drift_against(path, result, header, marked)
    sep = "" if text.endswith("\n") else "\n"
    rows = _row_text(frame.assign(**{UNITS_COLUMN: units}), header)  # the sheet's layout
    atomic_write_text(path, f"{text}{sep}{rows}", overwrite=True)
    logger.info("appended %d dyno-sheet rows to %s", len(frame), path)
    return warnings


def _drift_against(path, result, header, units):
    """Warnings for earlier rows of the sheet at the same settings and another temperature."""
    if "temperature" not in header or not result.settings:
        return ()
    old, _ = read_csv_table(path, where=str(path), error=DynoError)
    old.columns = [str(c).strip() for c in old.columns]
    same = np.ones(len(old), dtype=bool)
    for k, s in result.settings.items():
        same &= np.isclose(np.asarray(old[k], dtype=float), s)
    temps = np.asarray(old["temperature"], dtype=float)[same]
    temps = temps[np.isfinite(temps)]
    new = [b.temperature_c for r in result.runs for b in r.blocks if b.temperature_c is not None]
    if temps.size == 0 or not new:
        return ()
    lo, hi = min(temps.min(), min(new)), max(temps.max(), max(new))
    limit = result.options.get("temperature_drift_c", TEMPERATURE_DRIFT_C)
    if hi - lo <= limit:
        return ()
    msg = (f"{path}: temperature drift at {_settings_text(result.settings)}: the sheet's rows "
           f"at these settings and the new ones span {lo:.1f} to {hi:.1f} deg C, more than "
           f"{limit:g} deg C; compare runs at one temperature")
    logger.warning(msg)
    return (msg,)
