"""Fits of shock models to dyno data (peak force against peak velocity).

:func:`fit_shock_to_dyno` reads a dyno export (a CSV file or a DataFrame, signed or
bump/rebound columns, SI or imperial) and fits a :class:`~ident.models.shocks.TableShock`
(the measured points) or a :class:`~ident.models.shocks.DigressiveShock` (low slope,
knee and high slope per side, by non-negative least squares), refusing data that are
not passive.
"""

from __future__ import annotations

import logging
import math
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar, nnls

from ident.data.files import read_csv_table
from ident.data.units import UNIT_LABELS, from_si, to_si
from ident.errors import FitWarning, ShockModelError
from ident.models.shocks import (PASSIVITY_RTOL, DigressiveShock, PiecewiseLinear, TableShock,
                                 check_shock_units, format_number)

__all__ = ["fit_shock_to_dyno"]

logger = logging.getLogger(__name__)


def _dyno_points(data, units, where):
    """Return signed (velocity [m/s], force [N], row labels) from dyno data."""
    if isinstance(data, pd.DataFrame):
        df = data
    elif isinstance(data, (str, Path)):
        p = Path(data)
        if not p.is_file():
            raise ShockModelError(f"{where}: dyno file not found; check the path")
        # leading '#' comment lines (a unit marker '# units: ...') are skipped
        df, _ = read_csv_table(p, where=where, error=ShockModelError)
    else:
        raise TypeError(f"dyno data must be a CSV path or a pandas DataFrame, got "
                        f"{type(data).__name__}")
    cols = {str(c).strip().lower(): c for c in df.columns}

    def column(name, quantity):
        raw = df[cols[name]]
        num = pd.to_numeric(raw, errors="coerce")
        bad = np.flatnonzero(num.isna().to_numpy())
        if bad.size:
            r = int(bad[0])
            raise ShockModelError(f"{where}: column {cols[name]!r} has {bad.size} missing or "
                                  f"non-numeric value(s), the first at data row {r + 1} "
                                  f"({raw.iloc[r]!r}); fill or remove those rows")
        return np.asarray(to_si(num.to_numpy(dtype=float), quantity, units), dtype=float)

    if "velocity" not in cols:
        raise ShockModelError(f"{where}: no column 'velocity' (columns: "
                              f"{[str(c) for c in df.columns]}); give columns velocity, force "
                              "or velocity, bump_force, rebound_force")
    if len(df) == 0:
        raise ShockModelError(f"{where}: no data rows; give at least one measured point")
    has_signed = "force" in cols
    has_split = "bump_force" in cols or "rebound_force" in cols
    if has_signed and has_split:
        raise ShockModelError(f"{where}: has both a 'force' column and 'bump_force'/"
                              "'rebound_force' columns; keep one layout")
    v = column("velocity", "velocity")
    rows = np.arange(1, len(df) + 1)
    if has_signed:
        f = column("force", "force")
        return v, f, rows, ("velocity", "force")
    for name in ("bump_force", "rebound_force"):
        if name not in cols:
            raise ShockModelError(f"{where}: no column {name!r} (columns: "
                                  f"{[str(c) for c in df.columns]}); give columns velocity, "
                                  "bump_force, rebound_force, or velocity, force (signed)")
    fb = column("bump_force", "force")
    fr = column("rebound_force", "force")
    neg = np.flatnonzero(v < 0)
    if neg.size:
        raise ShockModelError(f"{where}: column {cols['velocity']!r} has a negative value at "
                              f"data row {neg[0] + 1} while bump_force/rebound_force are "
                              "given; give velocity magnitudes, or use signed columns "
                              "velocity, force")
    for name, arr in (("bump_force", fb), ("rebound_force", fr)):
        neg = np.flatnonzero(arr < 0)
        if neg.size:
            raise ShockModelError(f"{where}: column {cols[name]!r} has a negative value at "
                                  f"data row {neg[0] + 1}; give force magnitudes (positive) "
                                  "as the dyno reports them")
    return (np.concatenate([v, -v]), np.concatenate([fb, -fr]), np.concatenate([rows, rows]),
            ("velocity", "bump_force/rebound_force"))


def _check_dyno_passive(v, f, rows, colnames, where, units):
    wrong = np.flatnonzero(v * f < 0)
    if wrong.size:
        j = int(wrong[0])
        raise ShockModelError(
            f"{where}: column {colnames[1]!r} data row {rows[j]}: force "
            f"{format_number(from_si(f[j], 'force', units))} {UNIT_LABELS[units]['force']} "
            f"at velocity {format_number(from_si(v[j], 'velocity', units))} "
            f"{UNIT_LABELS[units]['velocity']} has the "
            "wrong sign (not passive); check the sign convention (compression positive)")
    tol = PASSIVITY_RTOL * float(np.max(np.abs(f)))
    zero = np.flatnonzero((v == 0) & (np.abs(f) > tol))
    if zero.size:
        j = int(zero[0])
        raise ShockModelError(
            f"{where}: column {colnames[1]!r} data row {rows[j]}: force "
            f"{format_number(from_si(f[j], 'force', units))} {UNIT_LABELS[units]['force']} at zero "
            "velocity (not passive); subtract the gas or static force first")


def _fit_table(v, f, where, units, colnames):
    keep = v != 0
    v, f = v[keep], f[keep]
    if v.size == 0:
        raise ShockModelError(f"{where}: column {colnames[0]!r} has no non-zero velocity; "
                              "give measured points away from 0")
    uv, inv = np.unique(v, return_inverse=True)
    uf = np.bincount(inv, weights=f) / np.bincount(inv)
    vk = np.concatenate([uv[uv < 0], [0.0], uv[uv > 0]])
    fk = np.concatenate([uf[uv < 0], [0.0], uf[uv > 0]])
    for side, present in (("rebound", np.any(uv < 0)), ("bump", np.any(uv > 0))):
        if not present:
            warnings.warn(f"{where}: no {side} points; the {side} side of the table is the "
                          "linear extension of the other side's first segment through (0, 0); "
                          f"measure {side} points to model it", FitWarning, stacklevel=3)
    pwl = PiecewiseLinear(vk, fk, 0.0, 0.0)
    slopes = pwl.segment_slopes[1:-1]
    for end, s, pts in (("lowest", slopes[0], (0, 1)), ("highest", slopes[-1], (-2, -1))):
        if s < 0:
            va, vb = (from_si(vk[i], "velocity", units) for i in pts)
            raise ShockModelError(
                f"{where}: column {colnames[1]!r}: the force decreases in magnitude between "
                f"velocities {format_number(va)} and {format_number(vb)} "
                f"{UNIT_LABELS[units]['velocity']} (the "
                f"{end} two points), so the table's linear extension would not be passive; "
                "remove the outlier or fit kind='digressive'")
    return vk, fk, uv.size


def _fit_side(u, g, where, side):
    """Fit ``g = a min(u, k) + b max(u - k, 0)`` with a, b >= 0 and a knee k.

    Returns ``(a, k, b, sse)``.
    """
    uniq = np.unique(u)
    if uniq.size < 3:
        raise ShockModelError(f"{where}: the {side} side has {uniq.size} distinct non-zero "
                              "velocities; a digressive fit needs at least 3 per side; measure "
                              "more points or use kind='table'")
    lo, hi = float(uniq[0]), float(uniq[-2])

    def solve(k):
        a_mat = np.column_stack([np.minimum(u, k), np.maximum(u - k, 0.0)])
        x, rnorm = nnls(a_mat, g)
        return x, rnorm * rnorm

    grid = np.unique(np.concatenate([np.linspace(lo, hi, 65), uniq[:-1]]))
    sse = np.array([solve(k)[1] for k in grid])
    j = int(np.argmin(sse))
    k_best, sse_best = float(grid[j]), float(sse[j])
    a_lo, a_hi = float(grid[max(j - 1, 0)]), float(grid[min(j + 1, grid.size - 1)])
    if a_hi > a_lo:
        res = minimize_scalar(lambda k: solve(k)[1], bounds=(a_lo, a_hi), method="bounded",
                              options={"xatol": 1e-10 * hi})
        if res.fun <= sse_best:
            k_best, sse_best = float(res.x), float(res.fun)
    (a, b), sse_best = solve(k_best)
    if k_best <= lo * (1 + 1e-6) or k_best >= hi * (1 - 1e-6):
        warnings.warn(f"{where}: the {side} knee is at the edge of the measured velocities "
                      f"({format_number(k_best)} m/s); the knee is poorly determined, measure more "
                      "points around it", FitWarning, stacklevel=3)
    return float(a), k_best, float(b), float(sse_best)


def fit_shock_to_dyno(data, *, id, kind="table", units="SI", lag_s=0.0, where=None):
    """Fit a shock model to dyno data (peak force vs peak velocity).

    Parameters
    ----------
    data : str, path or pandas.DataFrame
        A CSV file (with a header row) or a DataFrame, in one of two layouts:
        (a) columns ``velocity``, ``force``: signed, compression positive,
        rebound rows negative; (b) columns ``velocity``, ``bump_force``,
        ``rebound_force``: velocity magnitudes and force magnitudes (all >= 0)
        as dynos report them. Column names are matched case-insensitively.
    id : str
        The id of the fitted shock.
    kind : {"table", "digressive"}
        ``"table"``: the measured points (duplicate velocities averaged) plus
        the (0, 0) knot. ``"digressive"``: least-squares low slope, knee and
        high slope per side (knee by a bounded 1-D search, slopes >= 0 by
        non-negative linear least squares given the knee).
    units : {"SI", "imperial"}
        Unit system of the data (velocity m/s or in/s, force N or lbf).
    lag_s : float
        Lag [s] of the returned model.
    where : str, optional
        Name of the data in messages; default the file path or
        ``"dyno DataFrame"``.

    Returns
    -------
    TableShock or DigressiveShock
        The fitted model in SI; its ``description`` says what it was fitted to.

    Raises
    ------
    ShockModelError
        If a column is missing or non-numeric, the data are not passive (a
        force of the wrong sign, a non-zero force at zero velocity, a table
        whose end slope is negative), a side has too few points for the
        digressive fit, or `kind` or `units` is unknown.
    TypeError
        If `data` is neither a path nor a DataFrame.

    Warns
    -----
    FitWarning
        A table with no points on one side; a digressive knee at the edge of
        the measured velocities.
    """
    if where is None:
        where = "dyno DataFrame" if isinstance(data, pd.DataFrame) else str(data)
    if kind not in ("table", "digressive"):
        raise ShockModelError(f"{where}: unknown fit kind {kind!r}; use 'table' or "
                              "'digressive'")
    units = check_shock_units(units, f"{where}: units")
    v, f, rows, colnames = _dyno_points(data, units, where)
    _check_dyno_passive(v, f, rows, colnames, where, units)
    n = v.size
    if kind == "table":
        vk, fk, n_unique = _fit_table(v, f, where, units, colnames)
        model = TableShock(id, vk, fk, lag_s=lag_s,
                           description=f"table fitted to dyno data {where} ({n} points, "
                                       f"{n_unique} distinct velocities)")
        logger.info("fitted table shock %r to %s: %d knots", id, where, vk.size)
        return model
    params = {}
    sse_total = 0.0
    for side, mask, sign in (("bump", v > 0, 1.0), ("rebound", v < 0, -1.0)):
        a, k, b, sse = _fit_side(sign * v[mask], sign * f[mask], where, side)
        params.update({f"{side}_low_n_s_m": a, f"{side}_knee_m_s": k,
                       f"{side}_high_n_s_m": b})
        sse_total += sse
    # points at v = 0 have f = 0 (checked) and the model gives 0 there: no residual
    rms = math.sqrt(sse_total / n)
    model = DigressiveShock(id, **params, lag_s=lag_s,
                            description=f"digressive fitted to dyno data {where} ({n} points, "
                                        f"RMS residual {rms:.4g} N)")
    logger.info("fitted digressive shock %r to %s: RMS residual %.4g N over %d points",
                id, where, rms, n)
    return model
