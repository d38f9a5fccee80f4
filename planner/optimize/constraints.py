"""Linear constraints that make a damper curve buildable, and the curve-constraints file.

Always: ``F(0) = 0``; passive (``F v >= 0``); increasing (each segment's and
extension's slope >= 0). From a constraints TOML (``format =
"curve-constraints/1"``, units ``SI`` or ``imperial``), or the defaults of
:func:`default_constraints`::

    [bump]                                  # v > 0; [rebound] likewise (v < 0)
    low_speed_slope = [500.0, 40000.0]      # N/(m/s): 0 .. first knot
    high_speed_slope = [0.0, 15000.0]       # N/(m/s): beyond the last knot
    [shape]
    digressive = true                       # slopes do not grow away from 0
    rebound_bump_ratio = { velocity = 0.1, min = 1.0, max = 3.0 }
    max_force = 8000.0                      # N, |F| at every knot and at 1 m/s
    [adjustment]                            # an adjustable shock's reach
    reference = "DM"                        # a crate shock
    range = 0.3                             # force within +-30 % of the reference's

The objective's limits (e.g. ``shock_travel_rms_XX <= 1.25 x baseline``) hold
as nonlinear constraints on every drive. An infeasible set of linear
constraints is refused before solving, naming the constraints that conflict
(:func:`check_constraints`).
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import optimize as sopt

from ident.data.files import read_toml
from ident.data.units import check_units, to_si
from planner.errors import PlannerError

__all__ = [
    "CurveConstraints",
    "CONSTRAINTS_FORMAT",
    "MAX_FORCE_VELOCITY_M_S",
    "default_constraints",
    "read_curve_constraints",
    "check_constraints",
    "constraint_rows",
]

#: The ``format`` of curve-constraints files.
CONSTRAINTS_FORMAT = "curve-constraints/1"
#: The maximum force holds at the knots and at this velocity [m/s] (the extensions' reach).
MAX_FORCE_VELOCITY_M_S = 1.0


@dataclass(frozen=True)
class CurveConstraints:
    """Linear constraints that make a curve buildable (see the module docstring), SI.

    Attributes
    ----------
    bump_low_slope, bump_high_slope, rebound_low_slope, rebound_high_slope : (float, float) or None
        Bounds on the slope [N/(m/s)] from 0 to the first knot (low) and beyond
        the last (high), per side.
    digressive : bool
    ratio : (float, float, float) or None
        ``(velocity [m/s], min, max)`` of ``|F(-v)| / F(v)``.
    max_force_n : float or None
    adjust_reference : str or None
        A crate shock id; with `adjust_range`, every knot force within
        ``(1 +- range)`` times the reference's force there.
    adjust_range : float or None
    source : str or None
    """

    bump_low_slope: tuple | None = None
    bump_high_slope: tuple | None = None
    rebound_low_slope: tuple | None = None
    rebound_high_slope: tuple | None = None
    digressive: bool = False
    ratio: tuple | None = None
    max_force_n: float | None = None
    adjust_reference: str | None = None
    adjust_range: float | None = None
    source: str | None = None


def default_constraints():
    """Constraints a race shock can be built to, when none are given.

    Low-speed slopes 500 to 40,000 N/(m/s) (about 3 to 230 lbf/(in/s)),
    high-speed slopes 0 to 15,000 N/(m/s), at most 10 kN (2,250 lbf); not
    digressive by force, no ratio. Passive and increasing always hold.
    """
    return CurveConstraints(bump_low_slope=(500.0, 40000.0), bump_high_slope=(0.0, 15000.0),
                            rebound_low_slope=(500.0, 40000.0),
                            rebound_high_slope=(0.0, 15000.0), max_force_n=10000.0)


_CONSTRAINT_KEYS = {"format", "units", "bump", "rebound", "shape", "adjustment"}
_SIDE_KEYS = {"low_speed_slope", "high_speed_slope"}
_SHAPE_KEYS = {"digressive", "rebound_bump_ratio", "max_force"}


def read_curve_constraints(path):
    """Read a curve-constraints TOML file (see the module docstring).

    Returns
    -------
    CurveConstraints
        In SI; keys the file does not give are unconstrained (passive and
        increasing always hold).

    Raises
    ------
    PlannerError
        On a missing or malformed file, an unknown key (with the valid ones),
        a wrong ``format`` or ``units``, or a bound that is not a pair of
        numbers ``[min, max]`` with ``0 <= min <= max``; the message names the
        file and the key.
    """
    path = Path(path)
    where = str(path)
    doc = read_toml(path, error=PlannerError, what="curve constraints file")
    _unknown_keys(doc, _CONSTRAINT_KEYS, where)
    fmt = doc.get("format", CONSTRAINTS_FORMAT)
    if fmt != CONSTRAINTS_FORMAT:
        raise PlannerError(f"{where}: 'format' is {fmt!r}; write format = "
                           f"\"{CONSTRAINTS_FORMAT}\"")
    units = check_units(doc.get("units", "SI"), where=f"{where}: 'units'", error=PlannerError)
    out = {}
    for side in ("bump", "rebound"):
        tab = doc.get(side, {})
        if not isinstance(tab, dict):
            raise PlannerError(f"{where}: [{side}] must be a table")
        _unknown_keys(tab, _SIDE_KEYS, f"{where}: [{side}]")
        for key, attr in (("low_speed_slope", "low"), ("high_speed_slope", "high")):
            if key in tab:
                out[f"{side}_{attr}_slope"] = _bounds(tab[key], f"{where}: [{side}] {key}",
                                                      "damping", units)
    shape = doc.get("shape", {})
    if not isinstance(shape, dict):
        raise PlannerError(f"{where}: [shape] must be a table")
    _unknown_keys(shape, _SHAPE_KEYS, f"{where}: [shape]")
    if "digressive" in shape:
        if not isinstance(shape["digressive"], bool):
            raise PlannerError(f"{where}: [shape] digressive must be true or false")
        out["digressive"] = shape["digressive"]
    if "rebound_bump_ratio" in shape:
        r = shape["rebound_bump_ratio"]
        w = f"{where}: [shape] rebound_bump_ratio"
        if not isinstance(r, dict) or set(r) != {"velocity", "min", "max"}:
            raise PlannerError(f"{w} must be {{ velocity = ..., min = ..., max = ... }}")
        v = _positive(r["velocity"], f"{w}.velocity")
        lo, hi = _bounds([r["min"], r["max"]], w, None, units)
        out["ratio"] = (to_si(v, "velocity", units), lo, hi)
    if "max_force" in shape:
        out["max_force_n"] = to_si(_positive(shape["max_force"], f"{where}: [shape] max_force"),
                                   "force", units)
    adj = doc.get("adjustment")
    if adj is not None:
        w = f"{where}: [adjustment]"
        if not isinstance(adj, dict) or set(adj) != {"reference", "range"}:
            raise PlannerError(f"{w} must hold reference = \"<shock id>\" and range = "
                               "<fraction>")
        if not isinstance(adj["reference"], str) or not adj["reference"]:
            raise PlannerError(f"{w}: reference must be a shock id")
        rng = _positive(adj["range"], f"{w} range")
        out["adjust_reference"], out["adjust_range"] = adj["reference"], rng
    return CurveConstraints(**out, source=where)


def _unknown_keys(table, known, where):
    for key in table:
        if key not in known:
            close = difflib.get_close_matches(str(key), sorted(known), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise PlannerError(f"{where}: unknown key {key!r}{hint}; valid keys are "
                               f"{sorted(known)}")


def _positive(value, where):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value > 0):
        raise PlannerError(f"{where} = {value!r} must be a positive number")
    return float(value)


def _bounds(value, where, quantity, units):
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
        raise PlannerError(f"{where} = {value!r} must be [min, max], two numbers")
    lo, hi = (float(v) for v in value)
    if not (math.isfinite(lo) and lo >= 0 and (hi >= lo or math.isinf(hi))):
        raise PlannerError(f"{where} = {value!r} must have 0 <= min <= max")
    if quantity is not None:
        lo, hi = to_si(lo, quantity, units), to_si(hi, quantity, units)
    return lo, hi


def constraint_rows(space, cons, library):
    """Linear constraints ``A p <= b`` on the curve parameters, by named family.

    Parameters
    ----------
    space : planner.optimize.space.CurveSpace
    cons : CurveConstraints
    library : ShockLibrary or None
        Needed for an adjustment range around a crate shock.

    Returns
    -------
    list of (str, ndarray (n_rows, n_params_all), ndarray (n_rows,))
    """
    v = space.v_knots_m_s
    K, npar, G = v.size, space.n_params, len(space.groups)
    z = space.zero_index
    fam = {}

    def add(name, g, coef, rhs):
        row = np.zeros(G * npar)
        for j, c in coef.items():
            row[g * npar + j] = c
        fam.setdefault(name, []).append((row, rhs))

    def seg(j):  # slope of segment j..j+1 as coefficients on forces
        d = v[j + 1] - v[j]
        return {j + 1: 1.0 / d, j: -1.0 / d}

    below, above = K, K + 1
    for g in range(G):
        add("F(0) = 0", g, {z: 1.0}, 0.0)
        add("F(0) = 0", g, {z: -1.0}, 0.0)
        for j in range(K):
            if v[j] > 0:
                add("passive", g, {j: -1.0}, 0.0)
            elif v[j] < 0:
                add("passive", g, {j: 1.0}, 0.0)
        for j in range(K - 1):
            add("increasing", g, {k: -c for k, c in seg(j).items()}, 0.0)
        add("increasing", g, {below: -1.0}, 0.0)
        add("increasing", g, {above: -1.0}, 0.0)
        sides = (("bump", z, z + 1, above, 1), ("rebound", z, z - 1, below, -1))
        for side, j0, j1, ext, sgn in sides:
            low = getattr(cons, f"{side}_low_slope")
            if low is not None:
                # slope of the segment from 0 to the first knot of that side
                s = {j1: 1.0 / (v[j1] - v[j0]), j0: -1.0 / (v[j1] - v[j0])}
                add(f"{side} low-speed slope >= {low[0]:g} N/(m/s)", g,
                    {k: -c for k, c in s.items()}, -low[0])
                if math.isfinite(low[1]):
                    add(f"{side} low-speed slope <= {low[1]:g} N/(m/s)", g, s, low[1])
            high = getattr(cons, f"{side}_high_slope")
            if high is not None:
                add(f"{side} high-speed slope >= {high[0]:g} N/(m/s)", g, {ext: -1.0}, -high[0])
                if math.isfinite(high[1]):
                    add(f"{side} high-speed slope <= {high[1]:g} N/(m/s)", g, {ext: 1.0}, high[1])
        if cons.digressive:
            # slopes do not grow away from 0: bump segment j+1 <= j, rebound j-1 <= j
            for a, b in [(j + 1, j) for j in range(z, K - 2)] + [(j - 1, j) for j in range(1, z)]:
                add("digressive", g, _combine(seg(a), seg(b), -1.0), 0.0)
            add("digressive", g, _combine({above: 1.0}, seg(K - 2), -1.0), 0.0)
            add("digressive", g, _combine({below: 1.0}, seg(0), -1.0), 0.0)
        if cons.ratio is not None:
            vr, lo, hi = cons.ratio
            cb, cr = _interp_coef(v, vr), _interp_coef(v, -vr)
            # -F(-vr) >= lo F(vr)  ->  lo F(vr) + F(-vr) <= 0
            coef = {k: lo * c for k, c in cb.items()}
            for k, c in cr.items():
                coef[k] = coef.get(k, 0.0) + c
            add(f"rebound/bump ratio >= {lo:g} at {vr:g} m/s", g, coef, 0.0)
            coef = {k: -hi * c for k, c in cb.items()}
            for k, c in cr.items():
                coef[k] = coef.get(k, 0.0) - c
            add(f"rebound/bump ratio <= {hi:g} at {vr:g} m/s", g, coef, 0.0)
        if cons.max_force_n is not None:
            name = f"max force {cons.max_force_n:g} N"
            for j in range(K):
                add(name, g, {j: 1.0}, cons.max_force_n)
                add(name, g, {j: -1.0}, cons.max_force_n)
            vmax = max(MAX_FORCE_VELOCITY_M_S, v[-1], -v[0])
            add(name, g, {K - 1: 1.0, above: vmax - v[-1]}, cons.max_force_n)
            add(name, g, {0: -1.0, below: vmax + v[0]}, cons.max_force_n)
        if cons.adjust_reference is not None:
            ref = library.get(cons.adjust_reference, where="curve constraints [adjustment]")
            pwl = ref.to_pwl()
            name = (f"adjustment range +-{100 * cons.adjust_range:g} % of "
                    f"{cons.adjust_reference!r}")
            a = cons.adjust_range
            for j in range(K):
                if j == z:
                    continue
                fr = float(pwl.force(v[j]))
                lo_f, hi_f = sorted((fr * (1 - a), fr * (1 + a)))
                add(name, g, {j: 1.0}, hi_f)
                add(name, g, {j: -1.0}, -lo_f)
            for idx, vv in ((above, v[-1] + 1.0), (below, v[0] - 1.0)):
                sr = float(pwl.slope(vv))
                add(name, g, {idx: 1.0}, sr * (1 + a))
                add(name, g, {idx: -1.0}, -sr * (1 - a))
    return [(name, np.array([r for r, _ in rows]), np.array([b for _, b in rows]))
            for name, rows in fam.items()]


def _combine(a, b, wb):
    """Coefficient dict ``a + wb * b``."""
    out = dict(a)
    for k, c in b.items():
        out[k] = out.get(k, 0.0) + wb * c
    return out


def _interp_coef(v, x):
    """Coefficients on the knot forces of the linear interpolation at `x` (inside the knots)."""
    j = int(np.clip(np.searchsorted(v, x) - 1, 0, v.size - 2))
    t = (x - v[j]) / (v[j + 1] - v[j])
    return {j: 1.0 - t, j + 1: t}


def _feasible(space, families):
    """A decision vector satisfying the families' constraints, or None (LP, HiGHS)."""
    T = space.expansion()
    if not families:
        return np.zeros(space.n_vars)
    A = np.vstack([a for _, a, _ in families]) @ T
    b = np.concatenate([b for _, _, b in families])
    scale = np.maximum(np.abs(A).max(axis=1), 1e-300)
    res = sopt.linprog(np.zeros(space.n_vars), A_ub=A / scale[:, None], b_ub=b / scale,
                       bounds=[(None, None)] * space.n_vars, method="highs")
    return res.x if res.status == 0 else None


def check_constraints(space, constraints, library=None):
    """Refuse a set of linear constraints no curve can meet, naming the conflicting ones.

    Parameters
    ----------
    space : CurveSpace
    constraints : CurveConstraints
    library : ShockLibrary, optional
        Needed for an adjustment range around a crate shock.

    Returns
    -------
    ndarray, shape (n_vars,)
        A feasible decision vector.

    Raises
    ------
    PlannerError
        If infeasible: the message names a smallest set of constraint families
        that cannot hold together (a deletion filter over the families).
    """
    families = constraint_rows(space, constraints, library)
    x = _feasible(space, families)
    if x is not None:
        return x
    keep = list(families)
    for fam in list(families):
        trial = [f for f in keep if f is not fam]
        if _feasible(space, trial) is None:
            keep = trial
    names = [name for name, _, _ in keep]
    src = f" ({constraints.source})" if constraints.source else ""
    raise PlannerError(
        f"curve constraints{src} cannot all hold: {'; '.join(names)} conflict on the knots "
        f"{np.round(space.v_knots_m_s, 4).tolist()} m/s; relax one of them")
