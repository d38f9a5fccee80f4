"""Linear constraints that make a damper curve buildable, and the curve-constraints file.

Always: ``F(0) = 0``; passive (``F v >= 0``); increasing (each segment's and
extension's slope >= 0). From a constraints TOML (``format =
"curve-constraints/1"``, units ``SI`` or ``imperial``), or the defaults of
:func:`default_constraints`::

    [bump]                                  # v > 0; [rebound] likewise (v < 0)
    low_speed_slope = [500.0, 40000.0]      # N/(m/s): 0 .. first knot
    high_speed_slope = [0.0, 15000.0]       # N/(m/s): beyond the last knot
    segment_slope = [1000.0, 40000.0]       # N/(m/s): every segment in the velocity range
    [shape]
    digressive = true                       # slopes do not grow away from 0
    min_slope_ratio = 0.15                  # no segment in the range flatter than this
                                            # times its side's first segment
    crate_envelope = [0.333, 3.0]           # knot forces (segments in the range) within these
                                            # factors of the crate's weakest / strongest
    rebound_bump_ratio = { velocity = 0.1, min = 1.0, max = 3.0 }
    max_force = 8000.0                      # N, |F| at every knot and at 1 m/s

The *velocity range* is where the car spends most of its time: the optimizer
sets it from the baseline's shock speeds on the drives (their 99 % quantile
per side, :attr:`planner.optimize.space.CurveSpace.v_range_m_s`); a segment is
in it when it starts below that speed. Beyond it, the curve is what a blow-off
valve makes of it: bounded only by ``high_speed_slope`` and ``max_force``.
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
    "crate_envelope",
    "constraint_envelope",
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
    bump_segment_slope, rebound_segment_slope : (float, float) or None
        Bounds on the slope [N/(m/s)] of every segment that starts inside the
        velocity range (the space's ``v_range_m_s``; every segment if it has
        none), per side.
    min_slope_ratio : float or None
        Every segment inside the velocity range at least this times the slope
        of its side's first segment: no flat segment where the car lives.
    envelope_factor : (float, float) or None
        ``(lo, hi)``: the force at the ends of the segments in the velocity
        range (the knots up to the first beyond it) between ``lo`` times the crate's weakest shock there and ``hi`` times
        its strongest (:func:`crate_envelope`).
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
    bump_segment_slope: tuple | None = None
    rebound_segment_slope: tuple | None = None
    min_slope_ratio: float | None = None
    envelope_factor: tuple | None = None
    digressive: bool = False
    ratio: tuple | None = None
    max_force_n: float | None = None
    adjust_reference: str | None = None
    adjust_range: float | None = None
    source: str | None = None


#: Default slope bounds of every segment in the velocity range [N/(m/s)] (5.7 to 228
#: lbf/(in/s)): docs/DESIGN.md, "Buildable by default".
SEGMENT_SLOPE_N_S_M = (1000.0, 40000.0)
#: Default least slope of a segment in the range relative to its side's first segment.
MIN_SLOPE_RATIO = 0.15
#: Default factors on the crate's envelope (weakest, strongest) at the knots in the range.
ENVELOPE_FACTOR = (1.0 / 3.0, 3.0)


def default_constraints():
    """Constraints a shock builder would valve to, when none are given.

    Inside the velocity range the car spends 99 % of its time in (see the
    module docstring): every segment's slope 1,000 to 40,000 N/(m/s) (about
    5.7 to 230 lbf/(in/s)) and at least 0.15 times its side's first segment's
    (no flat segment), knot forces within 1/3 of the crate's weakest and 3
    times its strongest shock; everywhere digressive or linear (slopes do not
    grow away from 0), the low-speed slope 500 to 40,000 N/(m/s), beyond the
    last knot 0 to 15,000 N/(m/s), at most 10 kN (2,250 lbf) at every knot and
    at 1 m/s. Passive and increasing always hold. The reasons are in
    docs/DESIGN.md ("Buildable by default").
    """
    return CurveConstraints(bump_low_slope=(500.0, 40000.0), bump_high_slope=(0.0, 15000.0),
                            rebound_low_slope=(500.0, 40000.0),
                            rebound_high_slope=(0.0, 15000.0),
                            bump_segment_slope=SEGMENT_SLOPE_N_S_M,
                            rebound_segment_slope=SEGMENT_SLOPE_N_S_M,
                            min_slope_ratio=MIN_SLOPE_RATIO, envelope_factor=ENVELOPE_FACTOR,
                            digressive=True, max_force_n=10000.0)


_CONSTRAINT_KEYS = {"format", "units", "bump", "rebound", "shape", "adjustment"}
_SIDE_KEYS = {"low_speed_slope", "high_speed_slope", "segment_slope"}
_SHAPE_KEYS = {"digressive", "rebound_bump_ratio", "max_force", "min_slope_ratio",
               "crate_envelope"}


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
        for key, attr in (("low_speed_slope", "low"), ("high_speed_slope", "high"),
                          ("segment_slope", "segment")):
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
    if "min_slope_ratio" in shape:
        r = _positive(shape["min_slope_ratio"], f"{where}: [shape] min_slope_ratio")
        if r > 1:
            raise PlannerError(f"{where}: [shape] min_slope_ratio = {r:g} must be at most 1 "
                               "(a segment's least slope relative to its side's first)")
        out["min_slope_ratio"] = r
    if "crate_envelope" in shape:
        lo, hi = _bounds(shape["crate_envelope"], f"{where}: [shape] crate_envelope", None,
                         units)
        if not 0 < lo <= 1 <= hi:
            raise PlannerError(f"{where}: [shape] crate_envelope = {[lo, hi]} must be "
                               "[lo, hi] with 0 < lo <= 1 <= hi (factors on the crate's "
                               "weakest and strongest force)")
        out["envelope_factor"] = (lo, hi)
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
        rng = space.v_range_m_s
        for side, sgn, rs in (("bump", 1, 1), ("rebound", -1, 0)):
            # the segments of the side that start inside the velocity range, from 0 out
            segs = list(range(z, K - 1)) if sgn > 0 else list(range(z - 1, -1, -1))
            inside = [j for j in segs if rng is None
                      or abs(v[j if sgn > 0 else j + 1]) < rng[rs] * (1 - 1e-9)]
            bnd = getattr(cons, f"{side}_segment_slope")
            if bnd is not None:
                for j in inside:
                    name = (f"{side} slope in the velocity range within "
                            f"[{bnd[0]:g}, {bnd[1]:g}] N/(m/s)")
                    add(name, g, {k: -c for k, c in seg(j).items()}, -bnd[0])
                    if math.isfinite(bnd[1]):
                        add(name, g, seg(j), bnd[1])
            if cons.min_slope_ratio is not None and len(inside) > 1:
                r = cons.min_slope_ratio
                for j in inside[1:]:
                    # r * slope(first) - slope(j) <= 0
                    add(f"{side} slopes in the velocity range >= {r:g} x the first", g,
                        _combine({k: r * c for k, c in seg(inside[0]).items()}, seg(j), -1.0),
                        0.0)
            if cons.envelope_factor is not None and library is not None and len(library):
                lo_f, hi_f = cons.envelope_factor
                knots = [j + 1 if sgn > 0 else j for j in inside]
                weak, strong = crate_envelope(library, v[knots])
                name = (f"{side} forces in the velocity range within [{lo_f:.3g}, {hi_f:.3g}] "
                        "x the crate's envelope")
                for j, fw, fs in zip(knots, weak, strong):
                    add(name, g, {j: -float(sgn)}, -lo_f * fw)
                    add(name, g, {j: float(sgn)}, hi_f * fs)
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


def crate_envelope(library, v_m_s):
    """The weakest and strongest force of a crate's shocks at velocities.

    Parameters
    ----------
    library : ShockLibrary
    v_m_s : array_like, shape (n,)
        Velocities [m/s] (rebound negative).

    Returns
    -------
    weak, strong : ndarray, shape (n,)
        The least and greatest ``|F(v)|`` [N] over the crate's shocks (their
        steady curves).
    """
    v = np.asarray(v_m_s, dtype=float).ravel()
    F = np.abs(np.array([np.asarray(m.to_pwl().force(v), dtype=float) for m in library.values()]))
    return F.min(axis=0), F.max(axis=0)


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


def constraint_envelope(space, constraints, library=None):
    """The least and greatest force the constraints allow at every knot, per group.

    Each bound is a linear program over all the constraints (HiGHS), so it
    shows what the constraints together leave open, not one family's bound.

    Parameters
    ----------
    space : CurveSpace
    constraints : CurveConstraints
    library : ShockLibrary, optional
        Needed for the crate envelope and an adjustment range.

    Returns
    -------
    lo, hi : ndarray, shape (n_groups, n_knots)
        Force [N] at ``space.v_knots_m_s``; ``-inf`` / ``inf`` where
        unbounded, NaN if the constraints cannot hold.
    """
    families = constraint_rows(space, constraints, library)
    T = space.expansion()
    A = np.vstack([a for _, a, _ in families]) @ T
    b = np.concatenate([b for _, _, b in families])
    scale = np.maximum(np.abs(A).max(axis=1), 1e-300)
    A, b = A / scale[:, None], b / scale
    G, K, npar = len(space.groups), space.v_knots_m_s.size, space.n_params
    lo, hi = np.full((G, K), np.nan), np.full((G, K), np.nan)
    for g in range(G):
        for j in range(K):
            c = T[g * npar + j]
            for sgn, out in ((1.0, lo), (-1.0, hi)):
                if not np.any(c):
                    out[g, j] = 0.0
                    continue
                res = sopt.linprog(sgn * c, A_ub=A, b_ub=b, bounds=[(None, None)] * space.n_vars,
                                   method="highs")
                if res.status == 0:
                    out[g, j] = float(c @ res.x)
                elif res.status == 3:
                    out[g, j] = -sgn * np.inf
    return lo, hi
