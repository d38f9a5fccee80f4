"""Adjustable shocks (clickers): a curve per click setting, from dyno sheets.

A race damper's low- and high-speed, bump and rebound adjusters change its
force-velocity curve. The shock dyno measures the curve at a few settings, often one
adjuster swept with the others held. :class:`AdjustableShock` is one entry of a shock
library (``kind = "adjustable"`` in ``shocks.toml``, spec "Adjustable shocks") holding
those measured points and a **click model** that gives the curve at any setting inside
the adjusters' ranges; :meth:`AdjustableShock.at` returns it as a
:class:`~ident.models.shocks.TableShock` whose id is the setting's canonical name
``"TTX@ls=6,hs=2"`` (:func:`format_shock_name`, :func:`parse_shock_name`).

The click model
---------------
On a fixed velocity grid per side (bump, rebound), the log of the force magnitude is a
constant plus one shape function per adjuster::

    log|F(v_k; s)| = c_k + sum_a g_{a,k}(s_a)

``g_{a,k}`` is a monotone cubic (PCHIP) through its values at the settings the dyno
measured for that adjuster (its knots), held flat beyond the first and last knot. The
knot values are fitted per velocity by bounded least squares, with every step between
neighbouring knots constrained to the sign that makes the force rise towards
``stiffer``. Why this form (see also ``docs/DESIGN.md``):

- *What dynos record*: a sweep of one adjuster with the others held fits it exactly
  (as many unknowns as curves); a full or partial grid is fitted in least squares.
- *How adjusters act*: each shape function is its own curve over velocity, so a
  low-speed adjuster moves the low-speed forces and the knee, a high-speed one the
  high-speed slope, with no assumed shape.
- *Non-linear in clicks*: PCHIP follows the measured spacing (bleed adjusters act
  mostly in their first clicks) without overshoot.
- *Passive and monotone by construction*: a magnitude ``exp(...) > 0`` with the sign of
  the velocity, through (0, 0); monotone knot values give a monotone PCHIP, and a sum of
  functions each monotone in one adjuster is monotone in every adjuster.
- *Multiplicative*: adjusters scale force (orifice areas in series and parallel), which
  the log form keeps; additive forces would let two soft settings go negative.

Checks on the measured data (:func:`check_dyno_points`), each naming the file, the row,
the shock, the adjuster and the setting: a force of the wrong sign (refused); a curve
that gets softer towards ``stiffer`` than its neighbour setting of the same adjuster by
more than :data:`MONOTONE_RTOL` (refused: a digitization or setting error); by less (a
warning: fitted flat); settings outside the declared range (refused).

SI inside: velocity [m/s], force [N]; settings in the adjusters' own units (clicks or
turns).

Examples
--------
>>> import numpy as np
>>> v = np.array([-0.5, -0.1, 0.1, 0.5])
>>> rows = []
>>> for ls in (0, 10, 20):
...     for vi in v:
...         rows.append((vi, np.sign(vi) * (3000 * abs(vi)) * (1.5 - ls / 40), ls))
>>> pts = DynoPoints.from_rows(rows, ("ls",))
>>> ttx = AdjustableShock("TTX", {"ls": (0, 20)}, pts, default={"ls": 10},
...                       stiffer={"ls": "lower"})
>>> round(float(ttx.at({"ls": 10}).force(0.1)), 3)
375.0
>>> ttx.at({"ls": 5}).id
'TTX@ls=5'
"""

from __future__ import annotations

import logging
import math
import numbers
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd
from scipy.interpolate import PchipInterpolator
from scipy.optimize import lsq_linear

from ident.data.files import did_you_mean, read_csv_table
from ident.data.units import format_quantity, from_si, to_si
from ident.errors import ShockModelError
from ident.models.shocks import SHOCK_FITS, TableShock, format_number, is_real_number

__all__ = [
    "MONOTONE_RTOL",
    "POINT_CROSSING_RTOL",
    "CROSSING_WARN_RTOL",
    "RESOLUTION_SHARE",
    "force_resolution",
    "SETTING_ATOL",
    "DynoPoints",
    "DynoFinding",
    "AdjustableShock",
    "parse_shock_name",
    "format_shock_name",
    "read_dyno_sheets",
    "check_dyno_points",
]

logger = logging.getLogger(__name__)

#: Relative force drop (towards ``stiffer``, between neighbour settings of one
#: adjuster at the same velocity) tolerated as dyno repeatability: about 1-2 % run to
#: run on a warm damper. A crossing whose MEDIAN drop over the speeds both curves
#: measured exceeds it is systematic (a curve softer than its neighbour, a setting
#: written wrong) and refused; where an adjuster does not act (``hs`` below the knee) the
#: curves coincide and single points cross by noise alone, which the median ignores.
MONOTONE_RTOL = 0.02
#: A single point this much softer than its neighbour setting is a digitization slip
#: (a misplaced decimal, a row from another curve) and refused: 5 standard deviations
#: of the difference of two points with 1.4 % noise each.
POINT_CROSSING_RTOL = 0.10
#: Crossings smaller than this are dyno noise and not reported (0.5 %: the import's
#: point error); larger ones within the limits above are warnings, fitted flat.
CROSSING_WARN_RTOL = 0.005
#: A dyno's force resolution by default, as a share of the sheet's force range (its largest
#: minus its smallest force): a crossing smaller than the resolution in newtons is noise
#: however large it is relatively (a few newtons near zero velocity), fitted through with a
#: warning naming its rows. A sheet may state its dyno's resolution (``force_resolution``).
RESOLUTION_SHARE = 0.02
#: Absolute tolerance on settings (clicks or turns): range ends and step grid.
SETTING_ATOL = 1e-9
#: Points per side of the model's velocity grid at most (measured velocities thinned).
MAX_GRID_POINTS = 24
#: Velocities closer than this relative gap count as one grid velocity.
GRID_MERGE_RTOL = 0.02
#: Extra sheet columns that are kept as information, not as adjusters.
SHEET_INFO_COLUMNS = ("temperature", "cycles", "lag", "source")
STIFFER_CHOICES = ("lower", "higher")


def _err(msg):
    return ShockModelError(msg)


# ----------------------------------------------------------------------------
# names
# ----------------------------------------------------------------------------


def parse_shock_name(name, *, where=""):
    """Split a shock name into its base id and its settings.

    Parameters
    ----------
    name : str
        ``"B20"`` or ``"TTX@ls=6,hs=2"`` (spec "Adjustable shocks").
    where : str
        Prefix of error messages (who asks).

    Returns
    -------
    base : str
    settings : dict of str to float
        Empty for a plain id; in the order written.

    Raises
    ------
    ShockModelError
        On an empty base, a setting without ``=``, a value that is not a number, or an
        adjuster given twice.

    Examples
    --------
    >>> parse_shock_name("TTX@ls=6,hs=2.5")
    ('TTX', {'ls': 6.0, 'hs': 2.5})
    >>> parse_shock_name("B20")
    ('B20', {})
    """
    if not isinstance(name, str):
        raise TypeError(f"{where + ': ' if where else ''}shock name must be a string, got "
                        f"{type(name).__name__}")
    base, sep, rest = name.partition("@")
    base = base.strip()
    pre = f"{where}: " if where else ""
    if not sep:
        return base, {}
    if not base:
        raise _err(f"{pre}shock {name!r} has no id before '@'; write ID@adjuster=setting,...")
    settings = {}
    for part in rest.split(","):
        key, eq, value = part.partition("=")
        key = key.strip()
        if not eq or not key:
            raise _err(f"{pre}shock {name!r}: setting {part.strip()!r} is not "
                       "adjuster=value; write e.g. TTX@ls=6,hs=2")
        try:
            x = float(value)
        except ValueError:
            raise _err(f"{pre}shock {name!r}: adjuster {key!r} has setting {value.strip()!r}, "
                       "not a number; write clicks or turns as a number") from None
        if not math.isfinite(x):
            raise _err(f"{pre}shock {name!r}: adjuster {key!r} setting {value.strip()!r} is "
                       "not finite; give a number in the adjuster's range")
        if key in settings:
            raise _err(f"{pre}shock {name!r}: adjuster {key!r} is given twice; give each "
                       "adjuster once")
        settings[key] = x
    return base, settings


def format_shock_name(base, settings, order=None):
    """The canonical name of a setting, ``"TTX@ls=6,hs=2"``.

    Parameters
    ----------
    base : str
        The adjustable shock's id.
    settings : dict of str to float
        Every adjuster's setting (an empty dict gives `base`).
    order : sequence of str, optional
        Adjuster order (default: the dict's).

    Returns
    -------
    str

    Examples
    --------
    >>> format_shock_name("TTX", {"hs": 2.0, "ls": 6.0}, order=("ls", "hs"))
    'TTX@ls=6,hs=2'
    """
    keys = list(order) if order is not None else list(settings)
    if not keys:
        return base
    return base + "@" + ",".join(f"{k}={format_number(settings[k])}" for k in keys)


# ----------------------------------------------------------------------------
# measured points
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class DynoPoints:
    """Measured dyno points of one adjustable shock, in SI.

    Parameters
    ----------
    velocity_m_s : ndarray, shape (N,)
        Velocity [m/s], compression positive (0 rows are dropped on read).
    force_n : ndarray, shape (N,)
        Force [N], compression positive.
    settings : ndarray, shape (N, A)
        Each row's setting of each adjuster (clicks or turns).
    adjusters : tuple of str, length A
        The adjuster names (columns of `settings`).
    rows : tuple of str, length N
        Where each point came from, ``"sheet.csv row 12"`` (for messages).
    sources : tuple of str
        The sheet files (absolute paths) the points were read from, if any.
    """

    velocity_m_s: np.ndarray
    force_n: np.ndarray
    settings: np.ndarray
    adjusters: tuple
    rows: tuple = ()
    sources: tuple = ()

    def __post_init__(self):
        v = np.asarray(self.velocity_m_s, dtype=float).ravel()
        f = np.asarray(self.force_n, dtype=float).ravel()
        s = np.asarray(self.settings, dtype=float).reshape(v.size, len(self.adjusters))
        if f.size != v.size:
            raise _err("dyno points: velocity and force lengths differ; give one force per "
                       "velocity")
        rows = tuple(self.rows) or tuple(f"point {j + 1}" for j in range(v.size))
        for name, arr in (("velocity", v), ("force", f), ("settings", s)):
            bad = np.flatnonzero(~np.isfinite(np.atleast_2d(arr.T).T.reshape(v.size, -1)
                                              ).any(axis=1)) if arr.size else []
            if len(bad):
                raise _err(f"{rows[bad[0]]}: {name} is not finite; fill or remove the row")
        for arr in (v, f, s):
            arr.flags.writeable = False
        object.__setattr__(self, "velocity_m_s", v)
        object.__setattr__(self, "force_n", f)
        object.__setattr__(self, "settings", s)
        object.__setattr__(self, "adjusters", tuple(self.adjusters))
        object.__setattr__(self, "rows", rows)
        object.__setattr__(self, "sources", tuple(str(p) for p in self.sources))

    @classmethod
    def from_rows(cls, rows, adjusters):
        """Build from ``(velocity, force, setting_1, ..., setting_A)`` tuples in SI."""
        arr = np.asarray(rows, dtype=float).reshape(-1, 2 + len(adjusters))
        return cls(arr[:, 0], arr[:, 1], arr[:, 2:], tuple(adjusters))

    def curves(self):
        """Group the points by setting.

        Returns
        -------
        list of (setting tuple, index array)
            In the order the settings first appear.
        """
        keys = [tuple(r) for r in self.settings]
        order, groups = [], {}
        for j, k in enumerate(keys):
            if k not in groups:
                groups[k] = []
                order.append(k)
            groups[k].append(j)
        return [(k, np.asarray(groups[k], dtype=np.intp)) for k in order]

    def to_frame(self):
        """The points as a DataFrame: ``velocity, force`` then one column per adjuster."""
        df = pd.DataFrame({"velocity": self.velocity_m_s, "force": self.force_n})
        for j, a in enumerate(self.adjusters):
            df[a] = self.settings[:, j]
        return df


def read_dyno_sheets(paths, adjusters, *, units="SI", where=""):
    """Read dyno sheets (CSV) into :class:`DynoPoints` in SI.

    Parameters
    ----------
    paths : sequence of path
        The sheets: columns ``velocity, force`` (signed) or ``velocity, bump_force,
        rebound_force`` (magnitudes), one column per adjuster, and optionally
        ``temperature``, ``cycles``, ``lag``, ``source`` (kept as information).
    adjusters : sequence of str
        The shock's adjusters; every one must have a column.
    units : {"SI", "imperial"}
        The library file's unit system (velocity in/s and force lbf in imperial). A
        sheet's own (its ``units`` column, or a ``# units:`` line) must agree.
    where : str
        Who reads (the library entry), first in messages.

    Returns
    -------
    DynoPoints

    Raises
    ------
    ShockModelError
        On a missing file or column, an unknown column, a non-numeric value, a
        negative magnitude, or a unit marker that disagrees with the library.
    """
    pre = f"{where}: " if where else ""
    vs, fs, ss, labels = [], [], [], []
    for p in paths:
        p = Path(p)
        if not p.is_file():
            raise _err(f"{pre}dyno sheet {p} not found; check the 'dyno' path (relative to "
                       "the library file)")
        df, marker = read_csv_table(p, where=str(p), error=ShockModelError)
        if marker is not None and marker != units:
            raise _err(f"{p}: the sheet says it is in {marker} units (its 'units' column or "
                       f"'# units:' line) but the library is {units}; convert the sheet or "
                       f"set units = \"{marker}\" in the library")
        cols = {str(c).strip(): c for c in df.columns}
        lower = {k.lower(): k for k in cols}
        known = {"velocity", "force", "bump_force", "rebound_force", *SHEET_INFO_COLUMNS,
                 *adjusters}
        for c in cols:
            if c not in known and c.lower() not in known:
                raise _err(f"{p}: column {c!r} is neither velocity/force, an adjuster of "
                           f"{where or 'the shock'} {list(adjusters)} nor one of "
                           f"{list(SHEET_INFO_COLUMNS)}{did_you_mean(c, sorted(known))}; "
                           "rename or remove it")
        for a in adjusters:
            if a not in cols:
                raise _err(f"{p}: no column for adjuster {a!r} (columns: {list(cols)}); add "
                           "the setting at which each row was measured")

        def column(name, quantity=None):
            raw = df[cols.get(name, cols.get(lower.get(name, name), name))]
            num = pd.to_numeric(raw, errors="coerce")
            bad = np.flatnonzero(num.isna().to_numpy())
            if bad.size:
                r = int(bad[0])
                raise _err(f"{p}: column {name!r} row {r + 1} is {raw.iloc[r]!r}, not a "
                           "number; fill or remove that row")
            x = num.to_numpy(dtype=float)
            return np.asarray(to_si(x, quantity, units), dtype=float) if quantity else x

        if "velocity" not in lower:
            raise _err(f"{p}: no column 'velocity'; give velocity, force (signed) or "
                       "velocity, bump_force, rebound_force (magnitudes)")
        v = column("velocity", "velocity")
        settings = np.column_stack([column(a) for a in adjusters]) if adjusters else \
            np.zeros((v.size, 0))
        rows = [f"{p} row {r + 1}" for r in range(v.size)]
        if "force" in lower:
            f = column("force", "force")
            keep = v != 0
            vs.append(v[keep])
            fs.append(f[keep])
            ss.append(settings[keep])
            labels += [r for r, k in zip(rows, keep) if k]
        elif "bump_force" in lower and "rebound_force" in lower:
            fb, fr = column("bump_force", "force"), column("rebound_force", "force")
            for name, arr in (("bump_force", fb), ("rebound_force", fr), ("velocity", v)):
                neg = np.flatnonzero(arr < 0)
                if neg.size:
                    raise _err(f"{p}: column {name!r} row {neg[0] + 1} is negative "
                               f"({format_number(arr[neg[0]])}) in the magnitude layout; "
                               "give magnitudes, or use signed velocity, force columns")
            keep = v > 0
            vs += [v[keep], -v[keep]]
            fs += [fb[keep], -fr[keep]]
            ss += [settings[keep], settings[keep]]
            kept = [r for r, k in zip(rows, keep) if k]
            labels += [r + " (bump)" for r in kept] + [r + " (rebound)" for r in kept]
        else:
            raise _err(f"{p}: no force column; give 'force' (signed) or 'bump_force' and "
                       "'rebound_force' (magnitudes)")
    if not vs or sum(x.size for x in vs) == 0:
        raise _err(f"{pre}the dyno sheets hold no points; give at least one curve")
    return DynoPoints(np.concatenate(vs), np.concatenate(fs), np.concatenate(ss),
                      tuple(adjusters), tuple(labels),
                      tuple(str(Path(p).resolve()) for p in paths))


# ----------------------------------------------------------------------------
# checks
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class DynoFinding:
    """One problem found in an adjustable shock's dyno points.

    Attributes
    ----------
    severity : {"error", "warning"}
    shock, adjuster : str
        The shock id and the adjuster ("" when not about one adjuster).
    setting : str
        The setting concerned (canonical name).
    row : str
        The file and row (``"ttx.csv row 12"``).
    message : str
        One line with the fix.
    """

    severity: str
    shock: str
    adjuster: str
    setting: str
    row: str
    message: str


def _curve_on(v_side, f_side, grid):
    """Force magnitude of one side's measured curve on `grid` (> 0) [N].

    Linear through (0, 0) and the points; beyond the last point, linear with the
    last segment's slope (floored at 0).
    """
    order = np.argsort(v_side)
    v = np.concatenate([[0.0], v_side[order]])
    f = np.concatenate([[0.0], f_side[order]])
    out = np.interp(grid, v, f)
    beyond = grid > v[-1]
    if np.any(beyond):
        slope = max((f[-1] - f[-2]) / (v[-1] - v[-2]), 0.0) if v.size > 2 else f[-1] / v[-1]
        out[beyond] = f[-1] + slope * (grid[beyond] - v[-1])
    return out


def _side_grid(speeds):
    """A velocity grid [m/s] (> 0) from the measured speeds of one side."""
    u = np.unique(np.round(speeds, 12))
    u = u[u > 0]
    keep = [u[0]]
    for x in u[1:]:
        if x > keep[-1] * (1 + GRID_MERGE_RTOL):
            keep.append(x)
    g = np.asarray(keep)
    if g.size > MAX_GRID_POINTS:
        g = np.geomspace(g[0], g[-1], MAX_GRID_POINTS)
    return g


def force_resolution(points, resolution_n=None):
    """The force [N] below which two curves' difference is the dyno's noise.

    Parameters
    ----------
    points : DynoPoints
    resolution_n : float, optional
        The dyno's resolution as stated (the library's ``force_resolution``) [N].

    Returns
    -------
    float
        `resolution_n`, or :data:`RESOLUTION_SHARE` of the points' force range.
    """
    if resolution_n is not None:
        return float(resolution_n)
    f = np.asarray(points.force_n, dtype=float)
    return RESOLUTION_SHARE * float(np.ptp(f)) if f.size else 0.0


def check_dyno_points(points, *, shock, adjusters, stiffer, rtol=MONOTONE_RTOL,
                      resolution_n=None):
    """Check an adjustable shock's measured points; return every finding.

    Parameters
    ----------
    points : DynoPoints
    shock : str
        The shock's id (for messages).
    adjusters : dict of str to (float, float)
        Each adjuster's range.
    stiffer : dict of str to {"lower", "higher"}
        Which end of each range is stiffer.
    rtol : float
        Relative force drop towards `stiffer` tolerated (:data:`MONOTONE_RTOL`).
    resolution_n : float, optional
        The dyno's force resolution [N] (:func:`force_resolution`: default
        :data:`RESOLUTION_SHARE` of the sheet's force range). A crossing counts only where
        the force drop exceeds it as well as the relative limits.

    Returns
    -------
    list of DynoFinding
        Errors: a force whose sign differs from its velocity's; a setting outside its
        range; a curve softer than its neighbour setting (same other settings) towards
        `stiffer` by more than `rtol` at the median of the speeds both measured, or at one
        speed by more than :data:`POINT_CROSSING_RTOL`, by more than the resolution (a
        crossing). Warnings: smaller crossings above :data:`CROSSING_WARN_RTOL` (fitted
        flat), and crossings within the resolution (noise near zero velocity, fitted
        through), each naming the rows.
    """
    out = []
    names = tuple(adjusters)
    v, f, s = points.velocity_m_s, points.force_n, points.settings
    atol_n = force_resolution(points, resolution_n)

    def setting_name(row):
        return format_shock_name(shock, dict(zip(names, row)), names)

    bad = np.flatnonzero(v * f < 0)
    for j in bad:
        out.append(DynoFinding(
            "error", shock, "", setting_name(s[j]), points.rows[j],
            f"{points.rows[j]}: force {format_quantity(f[j], 'force', digits=6)} at velocity "
            f"{format_quantity(v[j], 'velocity', digits=6)} has the wrong sign (compression positive: force takes "
            "the sign of the velocity); fix the digitized value or its sign"))
    for a, name in enumerate(names):
        lo, hi = adjusters[name]
        off = np.flatnonzero((s[:, a] < lo - SETTING_ATOL) | (s[:, a] > hi + SETTING_ATOL))
        for j in off[:5]:
            out.append(DynoFinding(
                "error", shock, name, setting_name(s[j]), points.rows[j],
                f"{points.rows[j]}: adjuster {name!r} setting {format_number(s[j, a])} is "
                f"outside its range [{format_number(lo)}, {format_number(hi)}]; fix the "
                "setting or widen the range in the library"))
    good = v * f >= 0
    curves = [(k, idx[good[idx]]) for k, idx in points.curves()]
    for side, sign in (("bump", 1.0), ("rebound", -1.0)):
        for a, name in enumerate(names):
            up = 1.0 if stiffer[name] == "higher" else -1.0
            groups = {}
            for key, idx in curves:
                other = key[:a] + key[a + 1:]
                groups.setdefault(other, []).append((key[a], key, idx))
            for members in groups.values():
                members.sort(key=lambda m: up * m[0])   # softest first
                for (xs, ks, ia), (xh, kh, ib) in zip(members, members[1:]):
                    va = sign * v[ia]
                    vb = sign * v[ib]
                    va_ok, vb_ok = va > 0, vb > 0
                    if not va_ok.any() or not vb_ok.any():
                        continue
                    top = min(va[va_ok].max(), vb[vb_ok].max())
                    grid = np.unique(np.concatenate([va[va_ok], vb[vb_ok]]))
                    grid = grid[grid <= top * (1 + 1e-12)]
                    if grid.size == 0:
                        continue
                    fa = _curve_on(va[va_ok], sign * f[ia][va_ok], grid)
                    fb = _curve_on(vb[vb_ok], sign * f[ib][vb_ok], grid)
                    drop = (fa - fb) / np.maximum(np.abs(fa), 1e-9)
                    noise = (drop > CROSSING_WARN_RTOL) & (fa - fb <= atol_n)
                    noise_finding = None
                    if noise.any():  # within the dyno's resolution: fitted through
                        rows = sorted({points.rows[ib[np.argmin(np.abs(vb - g))]]
                                       for g in grid[noise]})
                        shown = ", ".join(rows[:4]) + (f" and {len(rows) - 4} more"
                                                       if len(rows) > 4 else "")
                        noise_finding = DynoFinding(
                            "warning", shock, name, setting_name(kh), rows[0],
                            f"{shown}: at {side} up to "
                            f"{format_quantity(grid[noise].max(), 'velocity', digits=4)} "
                            f"the curve at {setting_name(kh)} crosses the one at "
                            f"{setting_name(ks)} by at most "
                            f"{format_quantity(float((fa - fb)[noise].max()), 'force')}, within "
                            f"the dyno's resolution ({format_quantity(atol_n, 'force')}): "
                            "noise, fitted "
                            "through")
                    drop = np.where(fa - fb > atol_n, drop, 0.0)
                    k = int(np.argmax(drop))
                    median = float(np.median(drop))
                    error = median > rtol or drop[k] > POINT_CROSSING_RTOL
                    if noise_finding is not None and not error:
                        out.append(noise_finding)
                    if drop[k] <= CROSSING_WARN_RTOL:
                        continue
                    near = ib[np.argmin(np.abs(vb - grid[k]))]
                    msg = (f"{points.rows[near]}: at {side} "
                           f"{format_quantity(grid[k], 'velocity', digits=4)} the "
                           f"curve at {setting_name(kh)} is {100 * drop[k]:.1f} % softer than at "
                           f"{setting_name(ks)}, but {name!r} is stiffer towards "
                           f"{stiffer[name]} settings (the curves cross)")
                    if error:
                        why = (f"; {100 * median:.1f} % softer at the median speed"
                               if median > rtol else "")
                        out.append(DynoFinding(
                            "error", shock, name, setting_name(kh), points.rows[near],
                            msg + why + "; fix the digitized forces or the settings columns, "
                            f"or 'stiffer' for {name!r}"))
                    else:
                        out.append(DynoFinding(
                            "warning", shock, name, setting_name(kh), points.rows[near],
                            msg + f", within dyno repeatability ({100 * rtol:.0f} % at the "
                            "median speed): fitted flat"))
    return out


# ----------------------------------------------------------------------------
# the adjustable shock
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class AdjustableShock:
    """A shock whose curve depends on its adjusters' settings (spec "Adjustable shocks").

    Parameters
    ----------
    id : str
        The library id (no ``@``).
    adjusters : dict of str to (float, float)
        Each adjuster's range ``(lo, hi)`` of settings (clicks or turns), in order.
    points : DynoPoints
        The measured points (SI), with one settings column per adjuster.
    default : dict of str to float, keyword-only
        The setting an adjuster takes when a name leaves it out (default: the middle
        of its range, rounded to its step).
    stiffer : dict of str to {"lower", "higher"}, keyword-only
        Which end of each range is stiffer (default "lower": clicks from closed).
    step : dict of str to float, keyword-only
        Each adjuster's resolution (1 click, 0.25 turn). Given, a setting must lie on
        ``lo + n step``; absent, any value in range is allowed and
        :meth:`settings_grid` steps by 1.
    lag_s, description, count, fits, dyno_files, sheet_units
        As for every shock (``dyno_files``: the sheet paths as written in the
        library, relative to it; ``sheet_units``: their unit system).
    force_resolution_n : float, keyword-only, optional
        The dyno's force resolution [N] (the library's ``force_resolution``); default
        :data:`RESOLUTION_SHARE` of the sheets' force range. Crossings within it are noise.

    Raises
    ------
    ShockModelError
        On an invalid range, default, stiffer or step, or dyno points with errors
        (:func:`check_dyno_points`), or adjusters that never vary independently.
    """

    kind: ClassVar[str] = "adjustable"

    id: str
    adjusters: dict
    points: DynoPoints
    default: dict = field(default=None, kw_only=True)
    stiffer: dict = field(default=None, kw_only=True)
    step: dict = field(default=None, kw_only=True)
    lag_s: float = field(default=0.0, kw_only=True)
    description: str = field(default="", kw_only=True)
    count: int | None = field(default=None, kw_only=True)
    fits: str | None = field(default=None, kw_only=True)
    dyno_files: tuple = field(default=(), kw_only=True)
    sheet_units: str = field(default="SI", kw_only=True)
    force_resolution_n: float | None = field(default=None, kw_only=True)

    def __post_init__(self):
        who = f"shock {self.id!r}"
        if not isinstance(self.id, str) or not self.id.strip() or "@" in self.id \
                or self.id != self.id.strip():
            raise _err(f"{who}: id must be a non-empty string without '@' or surrounding "
                       "whitespace; rename the shock")
        if not isinstance(self.adjusters, dict) or not self.adjusters:
            raise _err(f"{who}: adjusters must be a table {{name = [lo, hi]}} with at least "
                       "one adjuster; e.g. adjusters = { ls = [0, 25], hs = [0, 4.25] }")
        ranges = {}
        for name, rng in self.adjusters.items():
            if not isinstance(name, str) or not name.isidentifier():
                raise _err(f"{who}: adjuster name {name!r} must be a word (letters, digits, "
                           "_); rename it")
            if (not isinstance(rng, (list, tuple)) or len(rng) != 2
                    or not all(is_real_number(x) for x in rng)
                    or not float(rng[0]) < float(rng[1])):
                raise _err(f"{who}: adjuster {name!r} range {rng!r} must be [lo, hi] numbers "
                           "with lo < hi; write e.g. ls = [0, 25]")
            ranges[name] = (float(rng[0]), float(rng[1]))
        object.__setattr__(self, "adjusters", ranges)
        names = tuple(ranges)

        def per_adjuster(table, key):
            """`table` (stiffer, step, default) as a dict, refusing unknown adjusters."""
            out = dict(table or {})
            for k in out:
                if k not in ranges:
                    raise _err(f"{who}: {key} names unknown adjuster {k!r}"
                               f"{did_you_mean(k, names)}; adjusters are {list(names)}")
            return out

        stiffer = per_adjuster(self.stiffer, "stiffer")
        for k in names:
            stiffer.setdefault(k, "lower")
            if stiffer[k] not in STIFFER_CHOICES:
                raise _err(f"{who}: stiffer.{k} is {stiffer[k]!r}; write \"lower\" or "
                           "\"higher\" (the end of the range that is stiffer)")
        object.__setattr__(self, "stiffer", stiffer)
        step = per_adjuster(self.step, "step")
        for k, x in step.items():
            if not is_real_number(x) or not float(x) > 0:
                raise _err(f"{who}: step.{k} = {x!r} must be a number > 0 (clicks or turns "
                           "per setting)")
            step[k] = float(x)
        object.__setattr__(self, "step", step)
        default = per_adjuster(self.default, "default")
        for k in names:
            if k not in default:
                lo, hi = ranges[k]
                st = step.get(k, 1.0)
                default[k] = lo + st * math.floor((hi - lo) / 2 / st + 0.5)
        object.__setattr__(self, "default", {k: self._check_setting(k, default[k], "default")
                                             for k in names})
        if not isinstance(self.points, DynoPoints):
            raise TypeError(f"{who}: points must be DynoPoints (read_dyno_sheets builds them)")
        if self.points.adjusters != names:
            raise _err(f"{who}: the dyno points have adjusters {list(self.points.adjusters)} "
                       f"but the shock declares {list(names)}; give one column per adjuster")
        lag = self.lag_s
        if not is_real_number(lag) or not float(lag) >= 0 or not math.isfinite(float(lag)):
            raise _err(f"{who}: lag {lag!r} must be a number >= 0 [s]")
        object.__setattr__(self, "lag_s", float(lag))
        if self.count is not None and (not isinstance(self.count, (numbers.Integral,))
                                       or isinstance(self.count, bool) or self.count < 0):
            raise _err(f"{who}: count {self.count!r} must be an integer >= 0 (the units the "
                       "team has), or left out for unlimited")
        if self.fits is not None and self.fits not in SHOCK_FITS:
            raise _err(f"{who}: fits {self.fits!r} is not a use; give one of "
                       f"{list(SHOCK_FITS)}, or leave it out for any use")
        object.__setattr__(self, "dyno_files", tuple(str(p) for p in self.dyno_files))
        res = self.force_resolution_n
        if res is not None and (not is_real_number(res) or not 0 < float(res) < math.inf):
            raise _err(f"{who}: force_resolution {res!r} must be a number > 0 [N] (the "
                       "dyno's force resolution), or left out for 2 % of the sheet's range")
        findings = check_dyno_points(self.points, shock=self.id, adjusters=ranges,
                                     stiffer=stiffer, resolution_n=res)
        errors = [x for x in findings if x.severity == "error"]
        if errors:
            more = f" (and {len(errors) - 1} more problem(s))" if len(errors) > 1 else ""
            raise _err(f"shock {self.id!r}: {errors[0].message}{more}")
        for x in findings:
            logger.warning("shock %r: %s", self.id, x.message)
        object.__setattr__(self, "_findings", tuple(findings))
        object.__setattr__(self, "_model", self._fit())
        object.__setattr__(self, "_cache", {})

    # -- settings ----------------------------------------------------------

    @property
    def names(self):
        """tuple of str: the adjusters, in order."""
        return tuple(self.adjusters)

    @property
    def findings(self):
        """tuple of DynoFinding: the warnings found in the dyno points."""
        return self._findings

    def _check_setting(self, name, value, what="setting", where=""):
        pre = f"{where}: " if where else ""
        if not is_real_number(value):
            raise _err(f"{pre}shock {self.id!r}: adjuster {name!r} {what} {value!r} is not a "
                       "number; give clicks or turns")
        x = float(value)
        lo, hi = self.adjusters[name]
        if not (lo - SETTING_ATOL <= x <= hi + SETTING_ATOL):
            raise _err(f"{pre}shock {self.id!r}: adjuster {name!r} {what} {format_number(x)} "
                       f"is outside its range [{format_number(lo)}, {format_number(hi)}]; "
                       "give a setting inside the range")
        st = (self.step or {}).get(name)
        if st:
            n = (x - lo) / st
            if abs(n - round(n)) > 1e-6:
                raise _err(f"{pre}shock {self.id!r}: adjuster {name!r} {what} "
                           f"{format_number(x)} is not on its steps of {format_number(st)} "
                           f"from {format_number(lo)}; give a whole number of steps")
            x = lo + round(n) * st
        return min(max(x, lo), hi)

    def resolve(self, settings=None, *, where=""):
        """Every adjuster's setting: the given ones checked, the rest their default.

        Parameters
        ----------
        settings : dict of str to float, optional
        where : str
            Who asks (e.g. the setups file and row), first in messages.

        Returns
        -------
        dict of str to float
            In the adjusters' order.

        Raises
        ------
        ShockModelError
            On an unknown adjuster, or a setting out of range or off its steps.
        """
        settings = dict(settings or {})
        pre = f"{where}: " if where else ""
        for k in settings:
            if k not in self.adjusters:
                raise _err(f"{pre}shock {self.id!r} has no adjuster {k!r}"
                           f"{did_you_mean(k, self.names)}; its adjusters are "
                           f"{list(self.names)}")
        return {k: (self._check_setting(k, settings[k], where=where) if k in settings
                    else self.default[k]) for k in self.names}

    def name(self, settings=None):
        """The canonical name of a setting (every adjuster written)."""
        return format_shock_name(self.id, self.resolve(settings), self.names)

    def settings_grid(self, step=None, *, fixed=None):
        """Every setting on a grid of each adjuster's range.

        Parameters
        ----------
        step : float or dict of str to float, optional
            Settings per step (default: the adjuster's ``step``, else 1). A larger
            step (e.g. 2 clicks) thins the grid; the range's ends are always in.
        fixed : dict of str to float, optional
            Adjusters held at a setting (not enumerated).

        Returns
        -------
        list of dict
            Settings, the first adjuster varying slowest.
        """
        held = {}
        if fixed:
            full = self.resolve(fixed)
            held = {k: full[k] for k in fixed}
        axes = []
        for k in self.names:
            if k in held:
                axes.append([held[k]])
                continue
            lo, hi = self.adjusters[k]
            st = step.get(k) if isinstance(step, dict) else step
            st = float(st or self.step.get(k, 1.0))
            base = self.step.get(k)
            if st <= 0 or (base and abs(st / base - round(st / base)) > 1e-9):
                raise _err(f"shock {self.id!r}: step {format_number(st)} for adjuster {k!r} is "
                           f"not a positive multiple of its resolution "
                           f"{format_number(base or 1.0)}; give a whole number of steps")
            n = int(math.floor((hi - lo) / st + 1e-9))
            vals = [lo + j * st for j in range(n + 1)]
            if hi - vals[-1] > SETTING_ATOL:
                vals.append(hi)
            axes.append(vals)
        grids = np.meshgrid(*axes, indexing="ij")
        flat = [g.ravel() for g in grids]
        out = [{k: float(flat[a][j]) for a, k in enumerate(self.names)}
               for j in range(flat[0].size)]
        return out

    # -- the click model -------------------------------------------------

    def _fit(self):
        """Fit the click model (see the module docstring)."""
        pts = self.points
        names = self.names
        curves = [(key, idx) for key, idx in pts.curves()]
        knots = [np.unique(pts.settings[:, a]) for a in range(len(names))]
        cols = []   # (adjuster index, knot step index)
        for a, kn in enumerate(knots):
            cols += [(a, j) for j in range(kn.size - 1)]
        X = np.zeros((len(curves), 1 + len(cols)))
        X[:, 0] = 1.0
        for r, (key, _) in enumerate(curves):
            for c, (a, j) in enumerate(cols):
                # knot index of this curve's setting; steps 0..J-1 are on
                J = int(np.searchsorted(knots[a], key[a]))
                X[r, 1 + c] = 1.0 if j < J else 0.0
        rank = np.linalg.matrix_rank(X) if X.size else 0
        if rank < X.shape[1]:
            raise _err(f"shock {self.id!r}: the dyno curves do not separate the adjusters "
                       f"({len(curves)} curve(s) at settings "
                       f"{[format_shock_name(self.id, dict(zip(names, k)), names) for k, _ in curves]}"
                       "); measure a sweep of each adjuster with the others held")
        lower = np.full(X.shape[1], -np.inf)
        upper = np.full(X.shape[1], np.inf)
        for c, (a, j) in enumerate(cols):
            if self.stiffer[names[a]] == "higher":
                lower[1 + c] = 0.0
            else:
                upper[1 + c] = 0.0
        sides = {}
        for side, sign in (("bump", 1.0), ("rebound", -1.0)):
            speeds = sign * pts.velocity_m_s
            ok = speeds > 0
            if not ok.any():
                raise _err(f"shock {self.id!r}: the dyno sheets have no {side} points; "
                           f"measure both bump and rebound")
            grid = _side_grid(speeds[ok])
            Y = np.empty((len(curves), grid.size))
            for r, (key, idx) in enumerate(curves):
                sel = idx[ok[idx]]
                if sel.size == 0:
                    raise _err(f"shock {self.id!r}: the curve at "
                               f"{format_shock_name(self.id, dict(zip(names, key)), names)} "
                               f"has no {side} points; measure both sides at every setting")
                mag = _curve_on(speeds[sel], sign * pts.force_n[sel], grid)
                Y[r] = np.log(np.maximum(mag, 1e-6))
            theta = np.empty((X.shape[1], grid.size))
            if X.shape[1] == len(curves) and np.all(lower == -np.inf) and \
                    np.all(upper == np.inf):  # pragma: no cover - steps always bounded
                theta = np.linalg.solve(X, Y)
            else:
                for k in range(grid.size):
                    theta[:, k] = lsq_linear(X, Y[:, k], bounds=(lower, upper),
                                             method="bvls").x
            shapes = []
            c0 = 1
            for a, kn in enumerate(knots):
                m = kn.size - 1
                vals = np.vstack([np.zeros((1, grid.size)),
                                  np.cumsum(theta[c0:c0 + m], axis=0)]) if m else \
                    np.zeros((1, grid.size))
                c0 += m
                shapes.append((kn, PchipInterpolator(kn, vals, axis=0) if kn.size > 1
                               else None, vals))
            residual = Y - X @ theta
            sides[side] = {"grid": grid, "c": theta[0], "shapes": shapes,
                           "residual": residual}
        return sides

    def log_force(self, settings):
        """Log force magnitudes on the model's grids at a full setting (internal use)."""
        out = {}
        for side, m in self._model.items():
            y = m["c"].copy()
            for a, (kn, interp, vals) in enumerate(m["shapes"]):
                if interp is None:
                    continue
                x = min(max(settings[self.names[a]], kn[0]), kn[-1])
                y = y + interp(x)
            out[side] = y
        return out

    def curve(self, settings=None):
        """The curve at a setting: velocity [m/s] and force [N] knots, shape (K,) each.

        Parameters
        ----------
        settings : dict of str to float, optional
            Adjusters left out take their default.

        Returns
        -------
        velocity_m_s, force_n : ndarray
            Strictly increasing velocities through 0, compression positive.
        """
        s = self.resolve(settings)
        y = self.log_force(s)
        gb, gr = self._model["bump"]["grid"], self._model["rebound"]["grid"]
        fb, fr = np.exp(y["bump"]), np.exp(y["rebound"])
        # passive ends: the extension beyond the last point never slopes down
        for arr in (fb, fr):
            if arr.size > 1 and arr[-1] < arr[-2]:
                arr[-1] = arr[-2]
        v = np.concatenate([-gr[::-1], [0.0], gb])
        f = np.concatenate([-fr[::-1], [0.0], fb])
        return v, f

    def at(self, settings=None, *, where=""):
        """The concrete shock at a setting, a :class:`TableShock` (cached).

        Parameters
        ----------
        settings : dict of str to float, optional
            Adjusters left out take their default.
        where : str
            Who asks, first in error messages.

        Returns
        -------
        TableShock
            Id: the canonical name (``"TTX@ls=6,hs=2"``); the lag and inventory count
            of this shock.
        """
        s = self.resolve(settings, where=where)
        key = tuple(s[k] for k in self.names)
        hit = self._cache.get(key)
        if hit is None:
            v, f = self.curve(s)
            hit = TableShock(format_shock_name(self.id, s, self.names), v, f,
                             lag_s=self.lag_s, count=self.count, fits=self.fits,
                             description=self.description)
            self._cache[key] = hit
        return hit

    def default_shock(self):
        """The default setting as a :class:`TableShock` with this shock's plain id."""
        hit = self._cache.get("__default__")
        if hit is None:
            v, f = self.curve(None)
            hit = TableShock(self.id, v, f, lag_s=self.lag_s, count=self.count,
                             fits=self.fits, description=self.description)
            self._cache["__default__"] = hit
        return hit

    def fit_table(self):
        """The model against every measured point.

        Returns
        -------
        pandas.DataFrame
            One row per point: ``setting``, ``velocity`` [m/s], ``force_measured``,
            ``force_model`` [N], ``error_pct`` (model less measured, % of measured),
            ``row`` (file and row).
        """
        pts = self.points
        rows = []
        for key, idx in pts.curves():
            s = dict(zip(self.names, key))
            shock = self.at(s)
            fm = shock.force(pts.velocity_m_s[idx])
            for j, fj in zip(idx, np.atleast_1d(fm)):
                meas = pts.force_n[j]
                rows.append({"setting": shock.id, "velocity": pts.velocity_m_s[j],
                             "force_measured": meas, "force_model": float(fj),
                             "error_pct": 100.0 * (fj - meas) / abs(meas) if meas else 0.0,
                             "row": pts.rows[j]})
        return pd.DataFrame(rows)

    def to_toml_dict(self, units="SI"):
        """This shock as one ``[[shock]]`` table (the sheets are referenced, not copied).

        Parameters
        ----------
        units : {"SI", "imperial"}
            The unit system of ``force_resolution`` (settings are unit-free and the
            points stay in their sheets).
        """
        out = {"id": self.id, "kind": self.kind}
        if self.description:
            out["description"] = self.description
        out["adjusters"] = {k: [_num(lo), _num(hi)] for k, (lo, hi) in self.adjusters.items()}
        out["default"] = {k: _num(x) for k, x in self.default.items()}
        out["stiffer"] = dict(self.stiffer)
        if self.step:
            out["step"] = {k: _num(x) for k, x in self.step.items()}
        files = list(self.dyno_files)
        out["dyno"] = files[0] if len(files) == 1 else files
        if self.lag_s:
            out["lag"] = float(self.lag_s)
        if self.count is not None:
            out["count"] = int(self.count)
        if self.fits is not None:
            out["fits"] = self.fits
        if self.force_resolution_n is not None:
            out["force_resolution"] = float(from_si(self.force_resolution_n, "force", units))
        return out

    def __repr__(self):
        return (f"AdjustableShock(id={self.id!r}, adjusters={self.adjusters!r}, "
                f"default={self.default!r}, {self.points.velocity_m_s.size} points)")


def _num(x):
    x = float(x)
    return int(x) if x.is_integer() else x
