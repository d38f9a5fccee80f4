"""A shock's curve as a table, and an adjustable shock's model checked against its dyno.

Two computations behind ``shockplan dyno table`` and ``shockplan dyno check`` (issue 26):

- :func:`dyno_curve`: the curve of one library shock (a fixed id, or an adjustable
  shock's setting ``"TTX@ls=10,hs=2"``) at chosen velocities, a :class:`DynoCurve`; what a
  shock builder or another tool reads.
- :func:`check_dyno_library`: every adjustable shock of a library file, its click model
  against its measured points (:meth:`~ident.models.adjustable.AdjustableShock.fit_table`)
  and the checks of its dyno sheets
  (:func:`~ident.models.adjustable.check_dyno_points`), a :class:`DynoCheck`. A library
  whose adjustable entry has an error cannot be read
  (:func:`~ident.models.library.read_shock_library` raises on the first problem); the
  check reads each entry's sheets on its own and reports every finding, with the row.

The files and figures are written by :mod:`planner.report.dyno`. SI inside: velocity
[m/s], force [N], compression positive; settings in clicks or turns.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ident.data.files import read_toml
from ident.data.units import check_units, from_si, round_significant, to_si
from ident.errors import ShockModelError
from ident.models.adjustable import (MONOTONE_RTOL, AdjustableShock, DynoFinding,
                                     check_dyno_points, format_shock_name,
                                     read_dyno_sheets)
from ident.models.library import read_shock_library
from ident.models.shocks import TableShock, check_shock_units, format_number, is_real_number
from planner.errors import PlannerError

__all__ = [
    "BUILDER_GRID",
    "MODEL_LINE_POINTS",
    "FORCE_DECIMALS",
    "VELOCITY_DIGITS",
    "DynoCurve",
    "SettingCurve",
    "ShockCheck",
    "DynoCheck",
    "library_units",
    "default_velocities",
    "dyno_curve",
    "check_dyno_library",
]

logger = logging.getLogger(__name__)

#: The velocities [display units] of a curve without measured points (a linear or
#: digressive shock), per unit system: the shock builder's usual table, each side and 0
#: (the same speeds as the optimizer's force table).
BUILDER_GRID = {
    "SI": (0.0125, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.25, 0.35, 0.5, 0.75, 1.0),
    "imperial": (0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0, 40.0),
}
#: Points per side of a model line in the check's figures.
MODEL_LINE_POINTS = 60
#: Decimals of a curve table's forces [N or lbf]: 0.1 N or 0.1 lbf, below any shock dyno's
#: resolution (a few newtons), so that the table holds what the numbers mean.
FORCE_DECIMALS = 1
#: Significant digits of a curve table's velocities taken from measured speeds (table
#: knots, converted from SI): 4, finer than a dyno's speed control (about 0.5 %).
VELOCITY_DIGITS = 4


# ----------------------------------------------------------------------------
# dyno table
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class DynoCurve:
    """One shock's curve at chosen velocities.

    Attributes
    ----------
    shock : str
        The shock's name: a fixed id, or an adjustable shock's canonical setting name
        (every adjuster written, ``"TTX@ls=10,hs=2"``).
    units : {"SI", "imperial"}
        The unit system of `velocity` and `force`.
    velocity, force : ndarray, shape (K,)
        Velocity [m/s or in/s], increasing (as given, or measured speeds to
        :data:`VELOCITY_DIGITS` significant digits), and force [N or lbf] to
        :data:`FORCE_DECIMALS` decimals, compression positive.
    velocity_m_s, force_n : ndarray, shape (K,)
        The same in SI.
    grid : str
        Where the velocities came from: ``"given"``, ``"measured speeds"`` (an adjustable
        shock: the speeds of its dyno sheets, each side), ``"table knots"`` (a table
        shock) or ``"builder grid"`` (:data:`BUILDER_GRID`).
    measured_m_s : (float, float) or None
        An adjustable shock's highest measured rebound and bump speeds [m/s] (> 0);
        beyond them the curve is extrapolated.
    """

    shock: str
    units: str
    velocity: np.ndarray
    force: np.ndarray
    velocity_m_s: np.ndarray
    force_n: np.ndarray
    grid: str
    measured_m_s: tuple | None = None

    @property
    def extrapolated(self):
        """ndarray of bool, shape (K,): velocities beyond an adjustable shock's measured
        speeds (all False for a fixed shock)."""
        if self.measured_m_s is None:
            return np.zeros(self.velocity_m_s.shape, dtype=bool)
        reb, bump = self.measured_m_s
        tol = 1e-9
        return (self.velocity_m_s > bump * (1 + tol)) | (self.velocity_m_s < -reb * (1 + tol))

    def to_frame(self):
        """The curve as a DataFrame: ``velocity, force`` in :attr:`units`."""
        return pd.DataFrame({"velocity": self.velocity, "force": self.force})


def library_units(path):
    """The unit system of a library file, its top-level ``units`` ("SI" when absent).

    Raises
    ------
    ShockModelError
        If the file is missing or not TOML, or its ``units`` is not a unit system.
    """
    doc = read_toml(path, error=ShockModelError, what="shock library")
    return check_shock_units(doc.get("units", "SI"), f"{path}: key 'units'")


def _measured_range(adjustable):
    v = adjustable.points.velocity_m_s
    return (float(-v[v < 0].min()) if np.any(v < 0) else 0.0,
            float(v[v > 0].max()) if np.any(v > 0) else 0.0)


def default_velocities(model, *, units="SI"):
    """The velocities of a curve table when none are given.

    Parameters
    ----------
    model : ShockModel or AdjustableShock
        The shock; an adjustable one at the setting the table is for (its
        :meth:`~ident.models.adjustable.AdjustableShock.at` result) is a
        :class:`~ident.models.shocks.TableShock` whose knots are the measured speeds.
    units : {"SI", "imperial"}
        The unit system of the result.

    Returns
    -------
    velocity : ndarray, shape (K,)
        Increasing, through 0, both sides [m/s or in/s].
    grid : str
        ``"table knots"`` (a table shock, or an adjustable shock's setting: its knots are
        the measured dyno speeds of each side, merged within 2 %) or ``"builder grid"``
        (:data:`BUILDER_GRID`, a linear or digressive shock).

    Notes
    -----
    A table's knots give the curve exactly: it is linear between them.
    """
    units = check_units(units, error=PlannerError)
    if isinstance(model, AdjustableShock):
        model = model.default_shock()
    if isinstance(model, TableShock):
        return np.asarray(from_si(model.velocity_m_s, "velocity", units), dtype=float), \
            "table knots"
    g = np.asarray(BUILDER_GRID[units], dtype=float)
    return np.concatenate([-g[::-1], [0.0], g]), "builder grid"


def dyno_curve(library, name, *, velocities=None, units="SI", where="--shock"):
    """The curve of a library shock at a setting, as a table.

    Parameters
    ----------
    library : ShockLibrary
    name : str
        A fixed shock's id, an adjustable shock's setting name (``"TTX@ls=10,hs=2"``;
        adjusters left out take their default) or an adjustable id alone (its default
        setting).
    velocities : array_like, shape (K,), optional
        Velocities in `units` [m/s or in/s], compression positive; sorted, duplicates
        dropped. Default: :func:`default_velocities` (an adjustable shock: its measured
        speeds, each side, and 0).
    units : {"SI", "imperial"}
        The unit system of `velocities` and of the result.
    where : str
        Who names the shock, first in error messages.

    Returns
    -------
    DynoCurve

    Raises
    ------
    ShockModelError
        On an unknown shock, adjuster or a setting out of range or off its steps.
    PlannerError
        On velocities that are empty or not finite.

    Examples
    --------
    >>> from ident.models.library import ShockLibrary
    >>> from ident.models.shocks import LinearShock
    >>> lib = ShockLibrary([LinearShock("B20", 3500.0)])
    >>> dyno_curve(lib, "B20", velocities=[0.2, -0.1]).force.tolist()
    [-350.0, 700.0]
    """
    units = check_units(units, error=PlannerError)
    if not isinstance(name, str) or not name.strip():
        raise PlannerError(f"{where}: give a shock id or a setting name such as "
                           "TTX@ls=10,hs=2")
    name = name.strip()
    base = library.base_id(name)
    if base not in library.ids:
        library.get(name, where=where)   # raises naming the known ids
    entry = library.entry(base)
    measured = None
    if isinstance(entry, AdjustableShock):
        canonical = library.canonical_name(name, where=where) if "@" in name else entry.name()
        model = library.get(canonical, where=where)
        measured = _measured_range(entry)
    else:
        model = library.get(name, where=where)
        canonical = model.id
    if velocities is None:
        v, grid = default_velocities(model, units=units)
        v = np.unique(round_significant(v, VELOCITY_DIGITS))
    else:
        v = np.asarray(velocities, dtype=float).ravel()
        if v.size == 0:
            raise PlannerError(f"{where} {canonical}: no velocities; give --velocity V,V,... "
                               f"or leave it out for the default grid")
        if not np.all(np.isfinite(v)):
            raise PlannerError(f"{where} {canonical}: velocity {v[~np.isfinite(v)][0]!r} is "
                               "not finite; give finite numbers")
        v, grid = np.unique(v), "given"
    v_si = np.asarray(to_si(v, "velocity", units), dtype=float)
    f_si = np.asarray(model.force(v_si), dtype=float)
    f = np.round(np.asarray(from_si(f_si, "force", units), dtype=float), FORCE_DECIMALS) + 0.0
    for arr in (v, f, v_si, f_si):
        arr.flags.writeable = False
    return DynoCurve(canonical, units, v, f, v_si, f_si, grid, measured)


# ----------------------------------------------------------------------------
# dyno check
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SettingCurve:
    """One measured setting of an adjustable shock, for the check's figures.

    Attributes
    ----------
    name : str
        The setting's canonical name.
    settings : dict of str to float
    velocity_m_s, force_n : ndarray, shape (N,)
        The measured points [m/s], [N].
    rows : tuple of str
        Each point's file and row.
    flags : tuple of tuple of (str, str), length N
        Per point, the ``(severity, adjuster)`` of each finding that names its row
        (``adjuster`` is "" for a finding about the point itself, such as a wrong sign).
    model_v_m_s, model_f_n : ndarray, shape (M,) or None
        The model's curve at this setting over the measured speeds (None when the model
        could not be built).
    """

    name: str
    settings: dict
    velocity_m_s: np.ndarray
    force_n: np.ndarray
    rows: tuple
    flags: tuple
    model_v_m_s: np.ndarray | None
    model_f_n: np.ndarray | None


@dataclass(frozen=True, eq=False)
class ShockCheck:
    """One adjustable shock checked against its dyno sheets.

    Attributes
    ----------
    id : str
    entry : str
        The library entry, ``"shocks.toml: [[shock]] #2 ('TTX')"``.
    adjusters : tuple of str
    stiffer : dict of str to str
    findings : tuple of DynoFinding
        Every error and warning, each naming its row (an error that is not about one
        row, such as a missing sheet, has ``row == ""``).
    curves : tuple of SettingCurve
        The measured settings, in the sheets' order (empty when the sheets could not be
        read).
    panels : tuple of (str, tuple of int)
        The figure's panels: a title (``"ls sweep at hs=2"``) and the indices of
        :attr:`curves` drawn in it; one panel per adjuster sweep, the remaining settings
        together.
    fit : pandas.DataFrame or None
        :meth:`~ident.models.adjustable.AdjustableShock.fit_table` (None when the model
        could not be built): ``setting, velocity, force_measured, force_model,
        error_pct, row``.
    worst : pandas.DataFrame or None
        Per setting: ``setting, points, worst_error_pct`` (signed, the largest in
        magnitude), ``rms_error_pct``, ``velocity`` and ``row`` of the worst point.
    shock : AdjustableShock or None
        The model (None when it could not be built).
    """

    id: str
    entry: str
    adjusters: tuple
    stiffer: dict
    findings: tuple
    curves: tuple = ()
    panels: tuple = ()
    fit: pd.DataFrame | None = None
    worst: pd.DataFrame | None = None
    shock: AdjustableShock | None = None

    @property
    def errors(self):
        """tuple of DynoFinding: the errors."""
        return tuple(f for f in self.findings if f.severity == "error")

    @property
    def warnings(self):
        """tuple of DynoFinding: the warnings."""
        return tuple(f for f in self.findings if f.severity == "warning")


@dataclass(frozen=True, eq=False)
class DynoCheck:
    """Every adjustable shock of a library file checked against its dyno sheets.

    Attributes
    ----------
    library : str
        The library file.
    units : {"SI", "imperial"}
        The library's unit system.
    library_error : str
        Why :func:`~ident.models.library.read_shock_library` refuses the file ("" when
        it reads): what every other command would say.
    shocks : tuple of ShockCheck
        The adjustable entries, in file order.
    fixed : tuple of str
        The ids of the fixed shocks (not checked here).
    settings : dict
        What produced the check (``monotone_rtol``).
    """

    library: str
    units: str
    library_error: str
    shocks: tuple
    fixed: tuple = ()
    settings: dict = field(default_factory=dict)

    @property
    def n_errors(self):
        """int: errors over every shock, plus 1 if the library is refused for a reason no
        shock's finding explains."""
        n = sum(len(s.errors) for s in self.shocks)
        return n if n or not self.library_error else 1

    @property
    def n_warnings(self):
        """int: warnings over every shock."""
        return sum(len(s.warnings) for s in self.shocks)

    @property
    def ok(self):
        """bool: no error."""
        return self.n_errors == 0


def _entry_error(shock_id, message):
    return DynoFinding("error", shock_id, "", "", "", message)


def _worst_per_setting(fit):
    rows = []
    for name, grp in fit.groupby("setting", sort=False):
        e = grp["error_pct"].to_numpy()
        k = int(np.argmax(np.abs(e)))
        rows.append({"setting": name, "points": int(e.size), "worst_error_pct": float(e[k]),
                     "rms_error_pct": float(np.sqrt(np.mean(e ** 2))),
                     "velocity": float(grp["velocity"].iloc[k]), "row": grp["row"].iloc[k]})
    return pd.DataFrame(rows, columns=["setting", "points", "worst_error_pct",
                                       "rms_error_pct", "velocity", "row"])


def _panels(keys, names):
    """One panel per adjuster sweep (settings differing in that adjuster only)."""
    panels, used = [], set()
    for a, name in enumerate(names):
        groups = {}
        for j, key in enumerate(keys):
            groups.setdefault(key[:a] + key[a + 1:], []).append(j)
        for held, members in groups.items():
            if len(members) < 2:
                continue
            members.sort(key=lambda j: keys[j][a])
            others = [n for n in names if n != name]
            at = ",".join(f"{n}={format_number(x)}" for n, x in zip(others, held))
            panels.append((f"{name} sweep" + (f" at {at}" if at else ""), tuple(members)))
            used.update(members)
    rest = tuple(j for j in range(len(keys)) if j not in used)
    if rest:
        panels.append(("other settings" if panels else "measured settings", rest))
    return tuple(panels)


def _model_line(shock, settings, v_meas):
    v = np.asarray(v_meas, dtype=float)
    lo = float(-v[v < 0].min()) if np.any(v < 0) else 0.0
    hi = float(v[v > 0].max()) if np.any(v > 0) else 0.0
    n = MODEL_LINE_POINTS
    grid = np.concatenate([-np.linspace(lo, 0.0, n, endpoint=False), [0.0],
                           np.linspace(0.0, hi, n + 1)[1:]])
    grid = np.unique(grid)
    return grid, np.asarray(shock.at(settings).force(grid), dtype=float)


def _shock_check(shock_id, entry, names, stiffer, points, findings, shock):
    """Assemble one :class:`ShockCheck` (the model's fit when `shock` is given)."""
    by_row = {}
    for f in findings:
        if f.row:
            by_row.setdefault(f.row, []).append((f.severity, f.adjuster))
    curves = []
    keys = []
    for key, idx in points.curves():
        s = dict(zip(names, (float(x) for x in key)))
        rows = tuple(points.rows[j] for j in idx)
        flags = tuple(tuple(by_row.get(r, ())) for r in rows)
        mv = mf = None
        if shock is not None:
            mv, mf = _model_line(shock, s, points.velocity_m_s[idx])
        curves.append(SettingCurve(format_shock_name(shock_id, s, names), s,
                                   points.velocity_m_s[idx], points.force_n[idx], rows,
                                   flags, mv, mf))
        keys.append(tuple(key))
    fit = worst = None
    if shock is not None:
        fit = shock.fit_table()
        worst = _worst_per_setting(fit)
    return ShockCheck(shock_id, entry, tuple(names), dict(stiffer), tuple(findings),
                      tuple(curves), _panels(keys, names), fit, worst, shock)


def _check_entry(table, units, library_path, index):
    """Check one ``kind = "adjustable"`` table on its own: every finding, no raise."""
    raw_id = table.get("id")
    shock_id = raw_id if isinstance(raw_id, str) else f"#{index}"
    entry = f"{library_path}: [[shock]] #{index} ({shock_id!r})"
    adjusters = table.get("adjusters")
    if not isinstance(adjusters, dict) or not adjusters:
        return ShockCheck(shock_id, entry, (), {}, (_entry_error(
            shock_id, f"{entry}: key 'adjusters' must be a table {{ls = [lo, hi], ...}}; "
            "see the spec's 'Adjustable shocks'"),))
    names = tuple(adjusters)
    ranges, problems = {}, []
    for name, rng in adjusters.items():
        try:
            lo, hi = (float(x) for x in rng)
            if not lo < hi:
                raise ValueError
            ranges[name] = (lo, hi)
        except (TypeError, ValueError):
            problems.append(_entry_error(shock_id, f"{entry}: key 'adjusters.{name}' must be "
                                         f"[lo, hi] numbers with lo < hi, got {rng!r}"))
    stiffer = table.get("stiffer") if isinstance(table.get("stiffer"), dict) else {}
    stiffer = {n: stiffer.get(n, "lower") for n in names}
    bad = [n for n, x in stiffer.items() if x not in ("lower", "higher")]
    for n in bad:
        problems.append(_entry_error(shock_id, f"{entry}: key 'stiffer.{n}' is "
                                     f"{stiffer[n]!r}; write \"lower\" or \"higher\""))
    dyno = table.get("dyno")
    files = [dyno] if isinstance(dyno, str) else dyno
    if not isinstance(files, list) or not files or not all(isinstance(f, str) for f in files):
        problems.append(_entry_error(shock_id, f"{entry}: key 'dyno' must be a file name or "
                                     f"a list of them, got {dyno!r}"))
        return ShockCheck(shock_id, entry, names, stiffer, tuple(problems))
    base = Path(library_path).parent
    try:
        points = read_dyno_sheets([base / f for f in files], names, units=units, where=entry)
    except ShockModelError as exc:
        return ShockCheck(shock_id, entry, names, stiffer,
                          tuple(problems) + (_entry_error(shock_id, str(exc)),))
    findings = list(problems)
    resolution = table.get("force_resolution")
    resolution_n = (to_si(float(resolution), "force", units) if is_real_number(resolution)
                    and float(resolution) > 0 else None)
    if len(ranges) == len(names) and not bad:
        findings += check_dyno_points(points, shock=shock_id, adjusters=ranges,
                                      stiffer=stiffer, resolution_n=resolution_n)
    shock = None
    if not any(f.severity == "error" for f in findings):
        try:
            kwargs = {k: table[k] for k in ("default", "step", "description", "count")
                      if k in table}
            if "lag" in table:
                kwargs["lag_s"] = table["lag"]
            shock = AdjustableShock(shock_id, ranges, points, stiffer=stiffer,
                                    dyno_files=tuple(files), sheet_units=units,
                                    force_resolution_n=resolution_n, **kwargs)
        except (ShockModelError, TypeError) as exc:
            findings.append(_entry_error(shock_id, f"{entry}: {exc}"))
    return _shock_check(shock_id, entry, names, stiffer, points, findings, shock)


def check_dyno_library(path):
    """Check every adjustable shock of a library file against its dyno sheets.

    Parameters
    ----------
    path : str or path
        The shock library (``shocks.toml``).

    Returns
    -------
    DynoCheck
        Per adjustable shock: every finding of
        :func:`~ident.models.adjustable.check_dyno_points` (wrong-sign forces, curves
        softer towards ``stiffer``, settings out of range), each with its row, and a
        problem reading the entry or its sheets; where the model builds, its fit against
        every measured point and the worst error per setting.

    Raises
    ------
    ShockModelError
        If the file is missing or not TOML, or has no ``[[shock]]`` tables (nothing to
        check); a problem in one entry is a finding, not an exception.
    """
    path = Path(path)
    doc = read_toml(path, error=ShockModelError, what="shock library")
    units = check_shock_units(doc.get("units", "SI"), f"{path}: key 'units'")
    tables = doc.get("shock")
    if not isinstance(tables, list) or not tables:
        raise ShockModelError(f"{path}: no [[shock]] tables; add at least one shock")
    library_error = ""
    library = None
    try:
        library = read_shock_library(path)
    except ShockModelError as exc:
        library_error = str(exc)
    checks, fixed = [], []
    for j, table in enumerate(tables):
        if not isinstance(table, dict):
            continue
        if table.get("kind") != AdjustableShock.kind:
            if isinstance(table.get("id"), str):
                fixed.append(table["id"])
            continue
        sid = table.get("id")
        if library is not None and isinstance(sid, str) and sid in library.adjustable_ids:
            shock = library.adjustable(sid)
            findings = check_dyno_points(shock.points, shock=shock.id,
                                         adjusters=shock.adjusters, stiffer=shock.stiffer,
                                         resolution_n=shock.force_resolution_n)
            checks.append(_shock_check(
                shock.id, f"{path}: [[shock]] #{j + 1} ({sid!r})", shock.names,
                shock.stiffer, shock.points, findings, shock))
        else:
            checks.append(_check_entry(table, units, path, j + 1))
    logger.debug("%s: checked %d adjustable shock(s): %d finding(s)", path, len(checks),
                 sum(len(c.findings) for c in checks))
    return DynoCheck(str(path), units, library_error, tuple(checks), tuple(fixed),
                     {"monotone_rtol": MONOTONE_RTOL})
