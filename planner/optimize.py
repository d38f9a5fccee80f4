"""The best damper curve per corner group: a nonlinear program over force-velocity curves.

``optimize_curves(model, drives, library, ...)`` finds, for each corner group
(left-right symmetric by default), the piecewise-linear force-velocity curve
that minimizes the objective of :mod:`planner.objective` (baseline-normalized
metrics, limits as constraints) on one or several drives, subject to linear
constraints that make the curve buildable. It then maps the optimum to the
crate: the crate's setups nearest to the optimal curves, simulated, and the
crate's best, so the gap between them prices a new shock.

Formulation
-----------
Decision variables, per group: the forces ``F_j`` at fixed velocity knots
(rebound ``-v_K < ... < -v_1 < 0 < v_1 < ... < v_K`` bump, default ``v`` =
0.025, 0.05, 0.1, 0.25, 0.5 m/s), with ``F(0) = 0``, and the slopes beyond the
outer knots. Between knots the curve is linear; the lag of each group is fixed
(the baseline's shock's, or given). With ``linear=True`` a group's variable
is one damping rate (``F_j = c v_j``): the known-answer case.

The closed loop is that of :mod:`ident.sim.closedloop`, written in casadi as a
discrete recursion (a fold, single shooting) over the drive's samples:

- the rig part of the model's :class:`~ident.sim.closedloop.LoopPlant` is
  simulated once per drive (:func:`ident.sim.closedloop.rig_response`);
- the shock part's modes are stepped with the same quadratic-hold
  coefficients (:func:`ident.sim.closedloop.hold_coefficients`) and the lag with
  :func:`ident.sim.closedloop.lag_hold_coefficients`, ``oversample`` sub-steps per
  sample;
- the algebraic loop ``v = v_free + D_eff dF(v)`` is solved at every sub-step
  by Newton's method on the 4 shock velocities (3 iterations from ``v_free``;
  with piecewise-linear curves it is exact once the segments are found, and
  ``D_eff`` is small), never broken by a delay;
- each metric channel passes the metric filter's power response ``|B|^4``
  (the 1-20 Hz Butterworth twice, forward) and its mean is removed exactly
  (``sum (z - m s)^2`` with ``s`` the filter's step response): within 0.001 %
  of ``sosfiltfilt``'s RMS on a 120 s track drive.

Gradients come by automatic differentiation (casadi's reverse mode through the
recursion). A sample's step is an MX function calling two SX functions, the
loop's sub-step (``oversample`` times) and the metrics' filters and sums
(once); the step and its adjoint are compiled to C when a C compiler is found
(5-7 s of compilation, once per machine and problem: :func:`jit_cache_dir`),
and the recursion over the samples is a tower of folds (:func:`_fold_chain`)
that casadi's virtual machine runs, calling them. IPOPT solves the problem with
a limited-memory Hessian; metrics and their Jacobian are computed once per
iterate and shared by the objective and the constraints. The start is the best
linear damping per group by frequency-domain screening (:mod:`planner.screen`),
projected onto the constraints.

Every result is verified by :func:`planner.predict.predict_setups`, the
time-domain simulator the rest of shockplan trusts, and that figure is the one
reported. A solver failure is reported with IPOPT's status and the best
verified iterate (:class:`OptimizeWarning`), never silently.

Constraints
-----------
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
constraints is refused before solving, naming the constraints that conflict.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd
from scipy import optimize as sopt
from scipy import signal

from ident.data.files import read_toml
from ident.data.channels import CORNERS
from ident.sim.closedloop import hold_coefficients, lag_hold_coefficients, rig_response
from ident.errors import ShockplanWarning
from planner.errors import PlannerError
from ident.sim.metrics import METRIC_NAMES
from ident.models.shocks import PiecewiseLinear, ShockLibrary, TableShock
from ident.data.units import check_units, to_si

__all__ = [
    "CurveSpace",
    "CurveConstraints",
    "CurveOptimum",
    "OptimizeWarning",
    "SYMMETRIES",
    "DEFAULT_KNOTS_M_S",
    "CONSTRAINTS_FORMAT",
    "curve_space",
    "default_constraints",
    "read_curve_constraints",
    "check_constraints",
    "optimize_curves",
    "compile_curves",
    "curve_distance",
    "curve_table",
    "curves_figure",
    "write_optimum",
    "BUILDER_VELOCITIES_M_S",
    "BUILDER_VELOCITIES_IN_S",
]

log = logging.getLogger(__name__)

#: Bump knot velocities [m/s] (rebound mirrors them).
DEFAULT_KNOTS_M_S = (0.025, 0.05, 0.1, 0.25, 0.5)
#: Corner groups of each symmetry: (group name, corners).
SYMMETRIES = {
    "left-right": (("front", ("LF", "RF")), ("rear", ("LR", "RR"))),
    "axle": (("all", CORNERS),),
    "none": tuple((c, (c,)) for c in CORNERS),
}
#: The ``format`` of curve-constraints files.
CONSTRAINTS_FORMAT = "curve-constraints/1"
#: The maximum force holds at the knots and at this velocity [m/s] (the extensions' reach).
MAX_FORCE_VELOCITY_M_S = 1.0
#: Newton iterations of the shock loop per sub-step in the casadi recursion.
NEWTON_ITERATIONS = 3
#: IPOPT stops as converged ("acceptable") once the objective's relative change stays below
#: this for 5 iterations: 1e-5 of a score is far below the model's accuracy (~1e-3), and
#: the piecewise-linear curves' kinks make the last digits of a tighter tolerance costly.
ACCEPTABLE_CHANGE = 1e-5
#: IPOPT statuses that count as solved.
_SOLVED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


class OptimizeWarning(ShockplanWarning):
    """The optimizer stopped without converging; the best verified iterate is returned."""


# ----------------------------------------------------------------------------------------------
# the curve space
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CurveSpace:
    """The curves the optimizer chooses from.

    Attributes
    ----------
    groups : tuple of (str, tuple of str)
        Group name and its corners; every corner in exactly one group.
    v_knots_m_s : ndarray, shape (K,)
        All knot velocities [m/s], rebound (negative) to bump, 0 included.
    linear : bool
        One damping rate per group instead of knot forces.
    lag_s : tuple of float
        The lag of each group [s].
    symmetry : str
    """

    groups: tuple
    v_knots_m_s: np.ndarray
    linear: bool
    lag_s: tuple
    symmetry: str

    @property
    def zero_index(self):
        """int: index of the knot at v = 0."""
        return int(np.flatnonzero(self.v_knots_m_s == 0.0)[0])

    @property
    def n_group_vars(self):
        """int: decision variables per group."""
        return 1 if self.linear else self.v_knots_m_s.size - 1 + 2

    @property
    def n_vars(self):
        """int: decision variables in all."""
        return self.n_group_vars * len(self.groups)

    @property
    def n_params(self):
        """int: curve parameters per group (knot forces incl. F(0), two end slopes)."""
        return self.v_knots_m_s.size + 2

    def expansion(self):
        """The linear map ``T`` from decision variables to curve parameters.

        Returns
        -------
        ndarray, shape (n_groups * n_params, n_vars)
            Per group: the forces at every knot [N] (0 at v = 0), the slope
            below the first knot and above the last [N/(m/s)].
        """
        K, nv, npar = self.v_knots_m_s.size, self.n_group_vars, self.n_params
        Tg = np.zeros((npar, nv))
        if self.linear:
            Tg[:K, 0] = self.v_knots_m_s
            Tg[K:, 0] = 1.0
        else:
            free = [j for j in range(K) if j != self.zero_index]
            for col, j in enumerate(free):
                Tg[j, col] = 1.0
            Tg[K, K - 1] = 1.0
            Tg[K + 1, K] = 1.0
        G = len(self.groups)
        T = np.zeros((G * npar, G * nv))
        for g in range(G):
            T[g * npar:(g + 1) * npar, g * nv:(g + 1) * nv] = Tg
        return T

    def params(self, x):
        """Curve parameters of decision vector `x`, shape (n_groups, n_params)."""
        return (self.expansion() @ np.asarray(x, dtype=float)).reshape(len(self.groups), -1)

    def curves(self, x):
        """The piecewise-linear curve of every group, a list of PiecewiseLinear."""
        K = self.v_knots_m_s.size
        return [PiecewiseLinear(self.v_knots_m_s, p[:K], p[K], p[K + 1]) for p in self.params(x)]

    def group_of(self, corner):
        """Index of the group that holds `corner`."""
        for g, (_, corners) in enumerate(self.groups):
            if corner in corners:
                return g
        raise PlannerError(f"corner {corner!r} is in no group")  # pragma: no cover

    def from_curves(self, pwls):
        """Decision vector whose curves interpolate the given ones at the knots.

        Parameters
        ----------
        pwls : sequence of PiecewiseLinear, one per group
        """
        x = []
        for p in pwls:
            f = p.force(self.v_knots_m_s)
            if self.linear:
                v = self.v_knots_m_s
                x.append(float(np.dot(f, v) / np.dot(v, v)))
            else:
                x += [f[j] for j in range(f.size) if j != self.zero_index]
                x += [float(p.slope(self.v_knots_m_s[0] - 1.0)),
                      float(p.slope(self.v_knots_m_s[-1] + 1.0))]
        return np.array(x, dtype=float)


def curve_space(*, symmetry="left-right", knots_m_s=DEFAULT_KNOTS_M_S, rebound_knots_m_s=None,
                linear=False, lag_s=0.0):
    """Build the curves the optimizer chooses from.

    Parameters
    ----------
    symmetry : {"left-right", "axle", "none"}
        ``left-right``: a curve per axle, the same left and right (LF = RF,
        LR = RR); ``axle``: one curve at every corner; ``none``: four curves.
    knots_m_s : sequence of float
        Bump knot velocities [m/s], positive and increasing.
    rebound_knots_m_s : sequence of float, optional
        Rebound knot speeds [m/s] (positive numbers, mirrored); default the
        bump knots.
    linear : bool
        One damping rate per group.
    lag_s : float or sequence of float
        Lag per group [s].

    Returns
    -------
    CurveSpace

    Raises
    ------
    PlannerError
        On an unknown symmetry or knots that are not positive and strictly
        increasing.
    """
    if symmetry not in SYMMETRIES:
        raise PlannerError(f"symmetry {symmetry!r} is not one of {list(SYMMETRIES)}")
    groups = SYMMETRIES[symmetry]
    bump = _knots(knots_m_s, "knots_m_s")
    reb = bump if rebound_knots_m_s is None else _knots(rebound_knots_m_s, "rebound_knots_m_s")
    v = np.concatenate([-reb[::-1], [0.0], bump])
    lags = np.broadcast_to(np.asarray(lag_s, dtype=float), (len(groups),))
    if np.any(~np.isfinite(lags)) or np.any(lags < 0):
        raise PlannerError(f"lag_s must be >= 0 [s], got {lag_s!r}")
    return CurveSpace(groups=groups, v_knots_m_s=v, linear=bool(linear),
                      lag_s=tuple(float(x) for x in lags), symmetry=symmetry)


def _knots(values, name):
    try:
        k = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise PlannerError(f"{name} must be a list of velocities [m/s], got {values!r}") from None
    if k.size < 1 or np.any(~np.isfinite(k)) or np.any(k <= 0) or np.any(np.diff(k) <= 0):
        raise PlannerError(f"{name} must be positive, strictly increasing velocities [m/s], "
                           f"got {k.tolist()}")
    return k


# ----------------------------------------------------------------------------------------------
# constraints
# ----------------------------------------------------------------------------------------------

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
    import difflib

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


def _constraint_rows(space, cons, library):
    """Linear constraints ``A p <= b`` on the curve parameters, by named family.

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
    families = _constraint_rows(space, constraints, library)
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


# ----------------------------------------------------------------------------------------------
# the closed loop in casadi
# ----------------------------------------------------------------------------------------------

def _pwl_sx(v, p, vk):
    """Force and slope of a piecewise-linear curve at `v` (SX), parameters `p` (knot forces,
    slope below, slope above) and knots `vk`."""
    K = vk.size
    f = p[0] + p[K] * (v - vk[0])
    s = p[K]
    for j in range(K - 1):
        sj = (p[j + 1] - p[j]) / (vk[j + 1] - vk[j])
        on = v >= vk[j]
        f = ca.if_else(on, p[j] + sj * (v - vk[j]), f)
        s = ca.if_else(on, sj, s)
    on = v >= vk[-1]
    f = ca.if_else(on, p[K - 1] + p[K + 1] * (v - vk[-1]), f)
    s = ca.if_else(on, p[K + 1], s)
    return f, s


class _LoopModel:
    """The closed loop of one plant and drive as a casadi recursion (module notes)."""

    def __init__(self, plant, drive, space, metric_rows, oversample, jit, *, inputs=True):
        """`inputs` False: build (and compile) the step functions only, for the drive's
        sample rate; the rig response and the recursion's inputs are left out."""
        self.space = space
        r = int(oversample)
        names, L = metric_rows
        outs = [plant.output_names[o] for o in np.flatnonzero(np.any(L != 0, axis=0))]
        Lm = L[:, [plant.output_names.index(o) for o in outs]]
        ms = plant.shock
        vi = plant.velocity_idx
        oi = [plant.output_names.index(o) for o in outs]
        h = 1.0 / (drive.fs_hz * r)
        phi, g1, g0, gm = hold_coefficients(ms.lam, h)
        n = ms.lam.size
        B, Cv, Dv = ms.B, ms.C[vi], ms.D[vi]
        Cm = Lm @ ms.C[oi]  # metric rows of the shock part
        Dm = Lm @ ms.D[oi]
        Deff = np.real(Cv @ (g1[:, None] * B)) + Dv
        cbar = np.asarray(plant.cbar_n_s_m, dtype=float)
        lag = np.array([space.lag_s[space.group_of(c)] for c in CORNERS])
        alpha, b0, b1, bm = (np.asarray(a, dtype=float) for a in lag_hold_coefficients(lag, h))
        nm = Lm.shape[0]
        sos = signal.butter(4, (1.0, 20.0), "bandpass", fs=drive.fs_hz, output="sos")
        sos = np.vstack([sos, sos])  # |B|^4: the power response of filtfilt
        ns = sos.shape[0]
        G, npar = len(space.groups), space.n_params
        vk = space.v_knots_m_s
        grp = [space.group_of(c) for c in CORNERS]

        # state: modes (re, im), dF[k-1], dF[k-2], F[k-1], f[k-1], f[k-2] (the loop part),
        # filter states, sums (z^2, z s, y) per metric, then the curve parameters (carried,
        # constant). A step is an MX function calling two SX functions: the loop's sub-step
        # (r times) and the metrics' outputs, filters and sums (once)
        n_loop = 2 * n + 20
        nx = n_loop + 2 * ns * nm + 3 * nm
        S = ca.SX.sym("s", n_loop)
        Pc = ca.SX.sym("p", G * npar)
        xr, xi = S[:n], S[n:2 * n]
        dF1, dF2, F1, f1, f2 = (S[2 * n + 4 * k:2 * n + 4 * k + 4] for k in range(5))
        Br, Bi = ca.DM(B.real), ca.DM(B.imag)
        Cvr, Cvi = ca.DM(Cv.real), ca.DM(Cv.imag)
        De = ca.DM(Deff)
        pg = [Pc[g * npar:(g + 1) * npar] for g in range(G)]

        def cmul(ar, ai, br, bi):
            return ar * br - ai * bi, ar * bi + ai * br

        # the loop's sub-step: (loop state, the rig part's shock velocities, curves) -> state
        vr = ca.SX.sym("v", 4)
        t1r, t1i = cmul(g0.real, g0.imag, Br @ dF1, Bi @ dF1)
        t2r, t2i = cmul(gm.real, gm.imag, Br @ dF2, Bi @ dF2)
        ar, ai = cmul(phi.real, phi.imag, xr, xi)
        xpr, xpi = ar + t1r + t2r, ai + t1i + t2i
        vfree = vr + Cvr @ xpr - Cvi @ xpi
        c0 = alpha * F1 + b1 * f1 + bm * f2
        v = vfree
        for _ in range(NEWTON_ITERATIONS):
            fs = [_pwl_sx(v[c], pg[grp[c]], vk) for c in range(4)]
            fv = ca.vertcat(*[a for a, _ in fs])
            sl = ca.vertcat(*[s for _, s in fs])
            res = v - vfree - De @ (c0 + b0 * fv - cbar * v)
            J = ca.DM.eye(4) - De @ ca.diag(b0 * sl - cbar)
            v = v - ca.solve(J, res)
        fv = ca.vertcat(*[_pwl_sx(v[c], pg[grp[c]], vk)[0] for c in range(4)])
        F = c0 + b0 * fv
        dF = F - cbar * v
        t0r, t0i = cmul(g1.real, g1.imag, Br @ dF, Bi @ dF)
        substep = ca.Function("substep", [S, vr, Pc],
                              [ca.vertcat(xpr + t0r, xpi + t0i, dF, dF1, F, fv, f1)])

        # the metrics' part: (loop state, filter states, sums, the rig part's metric rows and
        # the filter's step response) -> (filter states, sums)
        zf, sums = ca.SX.sym("z", 2 * ns * nm), ca.SX.sym("sums", 3 * nm)
        uy = ca.SX.sym("uy", nm + 1)
        y = uy[:nm] + ca.DM(Cm.real) @ xr - ca.DM(Cm.imag) @ xi + ca.DM(Dm) @ dF1
        sig, newz = y, []
        for k in range(ns):
            b_, a_ = sos[k, :3], sos[k, 3:]
            z1 = zf[2 * k * nm:(2 * k + 1) * nm]
            z2 = zf[(2 * k + 1) * nm:(2 * k + 2) * nm]
            out = b_[0] * sig + z1
            newz += [b_[1] * sig - a_[1] * out + z2, b_[2] * sig - a_[2] * out]
            sig = out
        sk = uy[nm]
        new_sums = ca.vertcat(sums[:nm] + sig**2, sums[nm:2 * nm] + sig * sk, sums[2 * nm:] + y)
        outputs = ca.Function("outputs", [S, zf, sums, uy], [ca.vertcat(*newz, new_sums)])

        XP, U = ca.MX.sym("x", nx + G * npar), ca.MX.sym("u", 4 * r + nm + 1)
        P = XP[nx:]

        def body(nsub):
            s = XP[:n_loop]
            for k in range(nsub):
                s = substep(s, U[4 * k:4 * k + 4], P)
            rest = outputs(s, XP[n_loop:n_loop + 2 * ns * nm], XP[n_loop + 2 * ns * nm:nx],
                           U[4 * r:])
            return ca.Function(f"step{nsub}", [XP, U], [ca.vertcat(s, rest, P)])

        key = _step_key(ms, h, r, lag, vk, grp, Cm, Dm, Deff, cbar, bool(jit))
        if key not in _STEP_CACHE:
            first, step = body(1), body(r)
            # instructions of the symbolic step (not of a library)
            n_instructions = r * substep.n_instructions() + outputs.n_instructions()
            if jit:  # the first step runs once per sweep: it is not worth its compile
                step = _compiled_steps((step,))[0]
            # casadi keeps derivative functions only while something holds them: hold the
            # adjoints with the steps, so a second solve reuses them
            _STEP_CACHE[key] = (first, step, first.reverse(1), step.reverse(1), n_instructions)
        first, step = _STEP_CACHE[key][:2]
        self.n_instructions = _STEP_CACHE[key][-1]
        if not inputs:
            return
        rig = rig_response(plant, drive, oversample=r, outputs=outs)
        N = rig.n_samples
        step_resp = signal.sosfilt(sos, np.ones(N))
        # inputs per sample: the r fine shock velocities of the rig part ending at the sample
        # (the first sample: its own), the metric rows of the rig part, the step response
        v_fine = rig.v_fine
        Uin = np.zeros((4 * r + nm + 1, N))
        Uin[:4, 0] = v_fine[0]
        for k in range(r):
            Uin[4 * k:4 * k + 4, 1:] = v_fine[k + 1::r][:N - 1].T
        Uin[4 * r:4 * r + nm] = Lm @ rig.y
        Uin[-1] = step_resp
        self.N, self.nm, self.names = N, nm, list(names)
        self._first, self._step, self._U = first, step, Uin
        self._nx, self._G, self._npar = nx, G, npar

    def metrics(self, P):
        """Symbolic metrics (MX, shape (nm,)) of curve parameters `P` (MX)."""
        x0 = ca.vertcat(ca.DM.zeros(self._nx), P)
        x1 = self._first(x0, ca.DM(self._U[:, 0]))
        x_last = _fold_chain(self._step, self.N - 1)(x1, ca.DM(self._U[:, 1:]))
        sums = x_last[self._nx - 3 * self.nm:self._nx]
        nm, N = self.nm, self.N
        zz, zs, ysum = sums[:nm], sums[nm:2 * nm], sums[2 * nm:]
        mean = ysum / N
        ss = float(np.sum(self._U[-1] ** 2))
        power = (zz - 2 * mean * zs + mean**2 * ss) / N
        return ca.sqrt(ca.fmax(power, 1e-300))


#: Steps per level of the optimizer's recursion (:func:`_fold_chain`).
FOLD_BASE = 32


def _fold_chain(step, n_steps, base=FOLD_BASE):
    """``step`` applied `n_steps` times, feeding its state back: ``(x0, U) -> x_n``.

    ``step`` maps (x, u) -> x; ``U`` holds the inputs column by column, shape
    (n_u, n_steps). The chain is a tower of functions, level ``i`` folding
    ``base**i`` steps as `base` calls of level ``i - 1``, and the top calls
    each level as often as that digit of `n_steps` in base `base`. It builds
    in milliseconds for any length (casadi's ``mapaccum`` took 0.3-13 s to
    build for 10^4 steps, depending on the length's remainders), keeps only
    the final state (the metrics' sums need no trajectory), and its adjoint
    recomputes each level's states from the level's input (checkpointing),
    so memory grows with ``base`` times the levels, not with `n_steps`. The
    arithmetic of every step, and of every adjoint step, is the same as a
    loop's.

    Returns
    -------
    casadi.Function
    """
    nx, nu = step.size1_in(0), step.size1_in(1)
    levels = [step]
    while base ** len(levels) <= n_steps:
        inner, k = levels[-1], base ** (len(levels) - 1)
        x, U = ca.MX.sym("x", nx), ca.MX.sym("U", nu, k * base)
        y = x
        for j in range(base):
            y = inner(y, U[:, j * k:(j + 1) * k])
        levels.append(ca.Function(f"fold{k * base}", [x, U], [y]))
    x, U = ca.MX.sym("x", nx), ca.MX.sym("U", nu, n_steps)
    y, pos = x, 0
    for i in range(len(levels) - 1, -1, -1):
        k = base ** i
        while n_steps - pos >= k:
            y = levels[i](y, U[:, pos:pos + k])
            pos += k
    return ca.Function(f"fold{n_steps}", [x, U], [y])


#: Compiled step functions by model, step, lags, knots, groups and metric rows: a second
#: optimization of the same problem (another drive, other constraints) compiles nothing.
_STEP_CACHE = {}
_JIT_DIR = []


def _step_key(ms, *parts):
    """A hashable key of the shock part's modes and the step's settings."""
    import hashlib

    h = hashlib.sha1()
    for a in (ms.lam, ms.B, ms.C, ms.D) + parts:
        a = np.atleast_1d(np.asarray(a))
        h.update(str((a.shape, a.dtype.str)).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _jit_dir():
    """The process's folder for compiled code (removed at exit): the fallback when the
    machine's cache folder (:func:`jit_cache_dir`) cannot be written."""
    import atexit

    if not _JIT_DIR:
        path = tempfile.mkdtemp(prefix="shockplan-jit-")
        _JIT_DIR.append(path)
        atexit.register(shutil.rmtree, path, ignore_errors=True)
    return _JIT_DIR[0]


#: Compiled step libraries kept in the cache folder; the least recently used beyond this
#: are removed when a new one is written.
JIT_CACHE_MAX_FILES = 64
#: C compiler flags of the step functions (-O1: most of -O2's speed on this code at a
#: fraction of its compile time; -O0 compiles in 40 % of the time but its adjoint runs slower).
JIT_FLAGS = ("-O1", "-fPIC")


def jit_cache_dir():
    """The folder of compiled step functions kept between runs.

    ``$SHOCKPLAN_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/shockplan`` (default
    ``~/.cache/shockplan``), with a subfolder per casadi version. A library is
    named by a hash of its generated C source and the compiler flags, so a
    changed model, drive grid, curve space or shockplan version compiles anew
    and a stale file is never used. Safe to delete at any time.

    Returns
    -------
    pathlib.Path
    """
    root = os.environ.get("SHOCKPLAN_CACHE_DIR")
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"),
                                                                 ".cache")
        root = os.path.join(base, "shockplan")
    return Path(root) / f"jit-casadi-{ca.__version__}"


def _compiler():
    return shutil.which("cc") or shutil.which("gcc")


def _compiled_steps(fns):
    """The step functions `fns` and their adjoints as one compiled shared library.

    The C source (each function and its ``reverse(1)``, which casadi's
    ``external`` finds by name) is generated and hashed; the library is
    compiled only when the cache (:func:`jit_cache_dir`) has no library of that
    hash, atomically (a temporary name, then a rename), so concurrent
    processes never load a half-written file. On a cache folder that cannot
    be written the process's temporary folder is used; if the compiler fails,
    the functions run uncompiled in casadi's virtual machine (slower, the same
    results) with a warning.

    Returns
    -------
    tuple of casadi.Function
    """
    import hashlib

    # one C file per function (each step and its adjoint), compiled to objects side by side
    # on the cores, then linked into one library: the adjoints' code is the bulk
    funcs = [g for f in fns for g in (f, f.reverse(1))]
    sources = []
    for g in funcs:
        cg = ca.CodeGenerator(f"{g.name()}.c", {"with_header": False})
        cg.add(g)
        sources.append(cg.dump())
    cc = _compiler()
    digest = hashlib.sha256("\0".join([*sources, cc or "", *JIT_FLAGS]).encode()).hexdigest()
    name = f"steps-{digest[:24]}.so"
    folder = jit_cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".probe-{os.getpid()}"
        probe.touch()
        probe.unlink()
    except OSError:
        log.info("compiled-step cache %s cannot be written; compiling into a temporary "
                 "folder", folder)
        folder = Path(_jit_dir())
    lib = folder / name
    if lib.exists():
        try:
            os.utime(lib)  # least recently used goes first
        except OSError:
            pass
    else:
        t0 = time.perf_counter()
        stem = folder / f".{name}.{os.getpid()}"
        files_c = [Path(f"{stem}.{k}.c") for k in range(len(sources))]
        files_o = [Path(f"{stem}.{k}.o") for k in range(len(sources))]
        tmp_so = Path(f"{stem}.tmp")
        try:
            for path, src in zip(files_c, sources):
                path.write_text(src)
            order = sorted(range(len(sources)), key=lambda k: -len(sources[k]))
            _run_parallel([[cc, *JIT_FLAGS, "-c", str(files_c[k]), "-o", str(files_o[k])]
                           for k in order], os.cpu_count() or 1)
            _run_parallel([[cc, "-shared", *map(str, files_o), "-o", str(tmp_so), "-lm"]], 1)
            os.replace(tmp_so, lib)
        except (OSError, TypeError) as exc:
            warnings.warn(f"compiling the optimizer's step functions failed ({exc}); they run "
                          "uncompiled (slower, same results)", RuntimeWarning, stacklevel=3)
            return tuple(fns)
        finally:
            for t in (*files_c, *files_o, tmp_so):
                t.unlink(missing_ok=True)
        log.info("compiled the optimizer's step functions in %.1f s: %s",
                 time.perf_counter() - t0, lib)
        _prune_cache(folder)
    return tuple(ca.external(f.name(), str(lib)) for f in fns)


def _run_parallel(commands, n_jobs):
    """Run compiler `commands`, up to `n_jobs` at once; raise OSError on the first failure."""
    import subprocess

    running, pending = [], list(commands)
    try:
        while pending or running:
            while pending and len(running) < max(1, n_jobs):
                running.append(subprocess.Popen(pending.pop(0), stdout=subprocess.PIPE,
                                                stderr=subprocess.PIPE, text=True))
            proc = running.pop(0)
            _, err = proc.communicate()
            if proc.returncode != 0:
                raise OSError((err or "").strip()[-400:] or f"exit {proc.returncode}")
    finally:
        for proc in running:
            proc.kill()
            proc.wait()


def _prune_cache(folder):
    """Remove the least recently used libraries beyond :data:`JIT_CACHE_MAX_FILES`."""
    try:
        libs = sorted(folder.glob("steps-*.so"), key=lambda p: p.stat().st_mtime)
        for old in libs[:max(0, len(libs) - JIT_CACHE_MAX_FILES)]:
            old.unlink(missing_ok=True)
    except OSError:
        pass


class _Evaluator:
    """The combinations ``z = C m`` of all drives' metrics (the scores and the limited
    metrics) and their gradients, cached per decision vector.

    The step functions are compiled (when jitted); the recursion runs in casadi's virtual
    machine, calling them. A row's gradient comes by reverse mode, one adjoint sweep (the
    compiled step's adjoint), so the cost of the gradients grows with the rows the problem
    holds, not with the decision variables.
    """

    def __init__(self, models, T, scale, C):  # noqa: N803 (matrices)
        x = ca.MX.sym("x", T.shape[1])
        seed = ca.MX.sym("seed", C.shape[0])
        P = ca.DM(T) @ (scale * x)
        m = ca.vertcat(*[mdl.metrics(P) for mdl in models])
        z = ca.DM(C) @ m
        self.f = ca.Function("scores", [x], [z])
        self.g = ca.Function("scores_adj", [x, seed], [z, ca.jtimes(z, x, seed, True)])
        self.n_x, self.n_z = T.shape[1], C.shape[0]
        self._x = None
        self._z = None
        self._grad = {}
        self.n_eval = 0
        self.n_grad = 0
        self.eval_s = 0.0
        self.grad_s = 0.0

    def _at(self, x):
        x = np.asarray(x, dtype=float)
        if self._x is None or not np.array_equal(x, self._x):
            self._x, self._z, self._grad = x.copy(), None, {}
        return x

    def value(self, x):
        """``z`` at `x`, shape (n_z,)."""
        x = self._at(x)
        if self._z is None:
            t0 = time.perf_counter()
            self._z = np.array(self.f(x)).ravel()
            self.eval_s += time.perf_counter() - t0
            self.n_eval += 1
        return self._z

    def gradients(self, x, rows):
        """The gradients of rows `rows` of ``z`` at `x`, shape (len(rows), n_x)."""
        x = self._at(x)
        out = np.empty((len(rows), self.n_x))
        for k, j in enumerate(rows):
            if j not in self._grad:
                seed = np.zeros(self.n_z)
                seed[j] = 1.0
                t0 = time.perf_counter()
                z, gr = self.g(x, seed)
                self.grad_s += time.perf_counter() - t0
                self.n_grad += 1
                self._z = np.array(z).ravel()
                self._grad[j] = np.array(gr).ravel()
            out[k] = self._grad[j]
        return out


class _MetricsCallback(ca.Callback):
    """casadi Callback: x -> rows `rows` of ``z`` (:class:`_Evaluator`), with their Jacobian."""

    def __init__(self, ev, rows):
        ca.Callback.__init__(self)
        self.ev, self.rows = ev, list(rows)
        self.construct("scores_cb", {})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.ev.n_x, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(len(self.rows), 1)

    def eval(self, arg):
        return [ca.DM(self.ev.value(np.array(arg[0]).ravel())[self.rows])]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        ev, rows = self.ev, self.rows

        class _Jac(ca.Callback):
            def __init__(self):
                ca.Callback.__init__(self)
                self.construct(name, {})

            def get_n_in(self):
                return 2

            def get_n_out(self):
                return 1

            def get_sparsity_in(self, i):
                return ca.Sparsity.dense(ev.n_x, 1) if i == 0 else ca.Sparsity(len(rows), 1)

            def get_sparsity_out(self, i):
                return ca.Sparsity.dense(len(rows), ev.n_x)

            def eval(self, arg):
                return [ca.DM(ev.gradients(np.array(arg[0]).ravel(), rows))]

        self._jac = _Jac()  # keep a reference alive
        return self._jac


class _Iterations(ca.Callback):
    """IPOPT iteration callback: history, progress, the best feasible iterate."""

    def __init__(self, n_x, n_g, progress):
        ca.Callback.__init__(self)
        self.n_x, self.n_g = n_x, n_g
        self.history = []
        self.t0 = time.perf_counter()
        self.bar = None
        if progress:
            from tqdm.auto import tqdm

            self.bar = tqdm(desc="optimize", unit="it")
        self.construct("iterations", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        n = ca.nlpsol_out(i)
        if n in ("f",):
            return ca.Sparsity.dense(1)
        if n in ("x", "lam_x"):
            return ca.Sparsity.dense(self.n_x)
        if n in ("g", "lam_g"):
            return ca.Sparsity.dense(self.n_g)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        d = {ca.nlpsol_out(i): arg[i] for i in range(ca.nlpsol_n_out())}
        self.history.append({"iteration": len(self.history), "objective": float(d["f"]),
                             "x": np.array(d["x"]).ravel().copy(),
                             "time_s": time.perf_counter() - self.t0})
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(objective=f"{float(d['f']):.5f}")
        return [0]

    def close(self):
        if self.bar is not None:
            self.bar.close()


# ----------------------------------------------------------------------------------------------
# the optimization
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CurveOptimum:
    """The result of :func:`optimize_curves`.

    Attributes
    ----------
    x : ndarray, shape (n_vars,)
        The optimal decision vector (knot forces [N] and end slopes [N/(m/s)],
        or damping rates).
    curves : list of PiecewiseLinear
        The optimal curve of every group (``space.groups``).
    shocks : ShockLibrary
        The optimal shocks (table kind, with the group's lag), ids ``OPT-<group>``.
    setup : planner.setups.Setup
        The optimum as a setup (named ``optimum``).
    table : pandas.DataFrame
        Verified in the time domain (:func:`planner.predict.predict_setups`),
        one row per setup: the optimum, the baseline, the crate's best and
        the crate setups closest to the optimum, with ``kind``, the shock ids,
        ``score`` (aggregated over the drives), ``score_<drive>``,
        ``feasible``, ``distance`` (to the optimal curves, weighted by the
        optimum's shock velocities).
    metrics : dict of str -> pandas.DataFrame
        Per drive, the metrics (SI) of the setups of `table`.
    crate_best : str
        The crate's best feasible setup (time domain).
    gap : float
        ``1 - score(optimum) / score(crate best)``: what building the optimal
        shocks gains over the best the crate can do (> 0 when the optimum is
        better).
    velocity_m_s : dict of str -> ndarray
        The optimum's shock velocity samples per corner on the first drive.
    stationarity : pandas.DataFrame or None
        Each knot force moved by +-5 % within the constraints: the score's
        relative change (a gain is negative).
    history : pandas.DataFrame
        IPOPT's iterations: objective, primal and dual infeasibility, time.
    solver : dict
        ``status``, ``success``, ``iterations``, ``n_eval`` (forward sweeps),
        ``build_s`` (the loop built and compiled), ``solve_s``, ``eval_s``, ``grad_s``,
        ``n_grad`` (adjoint sweeps), ``jit``,
        ``objective`` (the optimizer's own), ``verified_score``.
    space : CurveSpace
    constraints : CurveConstraints
    objective : planner.objective.Objective
    baseline : planner.setups.Setup
    settings : dict
    """

    x: np.ndarray
    curves: list
    shocks: ShockLibrary
    setup: object
    table: pd.DataFrame
    metrics: dict
    crate_best: str
    gap: float
    velocity_m_s: dict
    stationarity: pd.DataFrame | None
    history: pd.DataFrame
    solver: dict
    space: CurveSpace
    constraints: CurveConstraints
    objective: object
    baseline: object
    settings: dict = field(default_factory=dict)

    @property
    def score(self):
        """float: the optimum's verified (time-domain) score."""
        return float(self.table.loc["optimum", "score"])

    def verdict(self):
        """One sentence: how the optimum compares with the crate's best (time domain)."""
        best = float(self.table.loc[self.crate_best, "score"])
        if self.gap >= 0:
            return (f"the optimum ({self.score:.4f}) is {100 * self.gap:.2f} % better than the "
                    f"crate's best {self.crate_best} ({best:.4f})")
        return (f"the crate's best {self.crate_best} ({best:.4f}) beats the optimum "
                f"({self.score:.4f}) by {-100 * self.gap:.2f} %: the constraints keep the "
                "curves from what the crate already does; relax them")


def _valid(space, x):
    """`x` with the curves' validity exact: an interior-point solution meets its constraints
    to the solver's tolerance (a slope of -5e-5 N/(m/s) is not passive for a shock model).
    Knot forces are made non-decreasing through F(0) = 0 with the sign of their velocity,
    end slopes >= 0; changes are of the order of the tolerance."""
    if space.linear:
        return np.maximum(np.asarray(x, dtype=float), 0.0)
    K, z = space.v_knots_m_s.size, space.zero_index
    out = []
    for p in space.params(x):
        f = p[:K].copy()
        f[z] = 0.0
        f[z + 1:] = np.maximum.accumulate(np.maximum(f[z + 1:], 0.0))
        f[:z] = -np.maximum.accumulate(np.maximum(-f[:z][::-1], 0.0))[::-1]
        out.append(PiecewiseLinear(space.v_knots_m_s, f, max(p[K], 0.0), max(p[K + 1], 0.0)))
    return space.from_curves(out)


def _optimal_shocks(space, x, *, prefix="OPT"):
    """Table shocks of the curves of `x` (the end slopes kept by one extra point a side)."""
    models = []
    for (name, _), pwl, lag in zip(space.groups, space.curves(_valid(space, x)), space.lag_s):
        v, f = pwl.v_knots_m_s, pwl.f_knots_n
        ext = 0.5
        vv = np.concatenate([[v[0] - ext], v, [v[-1] + ext]])
        ff = np.concatenate([[f[0] - pwl.slope_below * ext], f, [f[-1] + pwl.slope_above * ext]])
        models.append(TableShock(f"{prefix}-{name}", vv, ff, lag_s=lag,
                                 description=f"optimal {name} curve (shockplan optimize)"))
    return ShockLibrary(models)


def _setup_of(space, shocks, name="optimum"):
    from planner.setups import Setup

    ids = {c: shocks.ids[space.group_of(c)] for c in CORNERS}
    return Setup(name, ids)


def _resolve_baseline(baseline, library, objective):
    from planner.setups import Setup

    if isinstance(baseline, Setup):
        baseline.resolve(library)
        return baseline
    if baseline is None:
        baseline = library.ids[0]
    if isinstance(baseline, str):
        ids = [s.strip() for s in baseline.split(",")]
    else:
        ids = list(baseline)
    if len(ids) == 1:
        ids = ids * 4
    if len(ids) != 4:
        raise PlannerError(f"baseline {baseline!r}: give one shock id (every corner) or four "
                           "(LF, RF, LR, RR)")
    setup = Setup("baseline", dict(zip(CORNERS, ids)))
    setup.resolve(library)
    return setup


def _check_objective(objective):
    from planner.objective import Objective, default_objective

    objective = default_objective() if objective is None else objective
    if not isinstance(objective, Objective):
        raise TypeError(f"objective must be a planner.objective.Objective, got "
                        f"{type(objective).__name__}")
    other = [m for m in objective.metrics if m not in METRIC_NAMES]
    if other:
        raise PlannerError(f"objective {objective.name!r}: optimize works on the spec's metrics "
                           f"{list(METRIC_NAMES)}; {other} are not among them (normalized and "
                           "band-split metrics are for ranking)")
    return objective


def _drive_list(drives, fs_hz):
    from ident.data.drive import Drive
    from planner.predict import prepare_drive

    if isinstance(drives, Drive):
        drives = [drives]
    drives = list(drives)
    if not drives:
        raise PlannerError("optimize needs at least one drive")
    out = [prepare_drive(d, fs_hz, where=f"drive {getattr(d, 'name', k)!r}")
           for k, d in enumerate(drives)]
    names = [d.name for d in out]
    if len(set(names)) < len(names):
        out = [replace(d, name=f"{d.name} #{k + 1}") for k, d in enumerate(out)]
    return out


def _jit_available():
    return shutil.which("cc") is not None or shutil.which("gcc") is not None


def _scan_start(plant, drives, library, space, baseline, objective, m_base, weights):
    """Best linear damping per group by screening (frequency domain): the start point."""
    from ident.models.shocks import LinearShock
    from planner.objective import score_setups
    from planner.screen import drive_bands, screen_response

    cbar = float(np.mean(plant.cbar_n_s_m))
    rates = cbar * np.geomspace(0.15, 4.0, 25)
    base_models = baseline.resolve(library)
    G = len(space.groups)
    bands = [drive_bands(d) for d in drives]
    Hs = [plant.frequency_response(b.f_hz) for b in bands]

    def scores(choices):  # choices: list of per-group rates arrays -> aggregated scores
        models = []
        for combo in choices:
            models.append(tuple(LinearShock("c", combo[space.group_of(c)],
                                            lag_s=space.lag_s[space.group_of(c)])
                                for c in CORNERS))
        total = 0.0
        for w, b, H, mb in zip(weights, bands, Hs, m_base):
            names, met, _, _ = screen_response(H, plant.output_names, plant.cbar_n_s_m, b,
                                               models + [tuple(base_models)])
            t = pd.DataFrame(met, columns=names)
            t.index = [f"s{k}" for k in range(len(models))] + ["baseline"]
            total = total + w * score_setups(t, objective, baseline="baseline").table[
                "score"].to_numpy()[:-1]
        return total

    best = np.full(G, cbar)
    s = scores([np.full(G, c) for c in rates])
    best[:] = rates[int(np.argmin(s))]
    for _ in range(2):  # coordinate refinement, group by group
        for g in range(G):
            trial = [np.where(np.arange(G) == g, c, best) for c in rates]
            best[g] = rates[int(np.argmin(scores(trial)))]
    return best


def _project(x0, A, b):
    """The point nearest `x0` (scaled least squares) with ``A x <= b``."""
    if np.all(A @ x0 <= b + 1e-9 * np.maximum(np.abs(b), 1)):
        return x0
    scale = np.maximum(np.abs(x0), 1.0)
    res = sopt.minimize(lambda y: 0.5 * np.sum((y - x0 / scale) ** 2), x0 / scale,
                        jac=lambda y: y - x0 / scale, method="SLSQP",
                        constraints=[{"type": "ineq", "fun": lambda y: b - A @ (y * scale),
                                      "jac": lambda y: -A * scale[None, :]}],
                        options={"maxiter": 500, "ftol": 1e-12})
    return res.x * scale


def _time_domain_scores(model, drives, setups, library, objective, baseline, weights,
                        oversample, aggregate):
    """Verified scores: predict_setups per drive, scored against the baseline, aggregated."""
    from planner.objective import score_setups
    from planner.predict import predict_setups

    cand = [baseline] + [s for s in setups if s.name != baseline.name]
    per, metrics, feasible = [], {}, None
    for d in drives:
        pred = predict_setups(model, d, cand, library, oversample=oversample)
        metrics[d.name] = pred.table
        sc = score_setups(pred.table, objective, baseline=baseline.name).table
        per.append(sc["score"])
        feasible = sc["feasible"] if feasible is None else (feasible & sc["feasible"])
    S = pd.concat(per, axis=1)
    S.columns = [f"score_{d.name}" for d in drives]
    agg = S.to_numpy() @ np.asarray(weights) if aggregate == "sum" else S.to_numpy().max(axis=1)
    out = S.copy()
    out.insert(0, "score", agg)
    out["feasible"] = feasible.to_numpy()
    return out, metrics


def optimize_curves(model, drives, library, *, objective=None, baseline=None,
                    symmetry="left-right", knots_m_s=DEFAULT_KNOTS_M_S, linear=False,
                    constraints=None, lag_s=None, drive_weights=None, aggregate="sum",
                    robust=False, oversample=2, max_iter=80, n_closest=5, jit=None,
                    stationarity=True, progress=False):
    """The best force-velocity curve per corner group (see the module docstring).

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
        Identified or known; both go through the same loop.
    drives : ident.data.drive.Drive or sequence of Drive
    library : ident.models.shocks.ShockLibrary
        The crate: the baseline and the setups the optimum is mapped to.
    objective : planner.objective.Objective, optional
        Default :func:`planner.objective.default_objective`; the spec's
        metrics only.
    baseline : Setup, str or sequence of 4 str, optional
        The setup the objective normalizes against: a Setup, a shock id (every
        corner) or four ids (LF, RF, LR, RR); default the crate's first shock
        at every corner.
    symmetry : {"left-right", "axle", "none"}
        Corner groups (:func:`curve_space`).
    knots_m_s : sequence of float
        Bump knot velocities [m/s] (rebound mirrors them).
    linear : bool
        One damping rate per group (the known-answer case).
    constraints : CurveConstraints, optional
        Default :func:`default_constraints`.
    lag_s : float, optional
        The optimal shocks' lag [s]; default per group the mean lag of the
        baseline's shocks at its corners.
    drive_weights : sequence of float, optional
        Per drive (default equal), for ``aggregate="sum"``.
    aggregate : {"sum", "worst"}
        Weighted sum of the drives' scores, or the worst drive's (epigraph).
    robust : bool
        Hold the objective's limits with the model's uncertainty: each
        limited metric times the upper bound of its 95 % interval
        (:func:`planner.uncertainty.prediction_uncertainty` at the start
        point; identified models only). The score of a weighted sum of
        metrics is unbiased under the zero-mean model errors, so its expected
        value is its nominal value to first order: only the limits need it.
    oversample : int
        Sub-steps per sample in the optimizer's loop and in the verification.
    max_iter : int
        IPOPT iterations.
    n_closest : int
        Crate setups nearest the optimum to simulate and report.
    jit : bool, optional
        Compile the loop to C (default: when a C compiler is found).
    stationarity : bool
        Report the effect of moving each knot force by +-5 % (time domain).
    progress : bool

    Returns
    -------
    CurveOptimum

    Raises
    ------
    PlannerError
        On constraints no curve meets (naming them), an objective with
        metrics other than the spec's, an unknown baseline shock, a bad
        symmetry, aggregate or weights; drive errors as :mod:`planner.predict`.
    TypeError
        If the objective is not an Objective.

    Warns
    -----
    OptimizeWarning
        If IPOPT does not converge; the best verified iterate is returned and
        ``solver["success"]`` is False.
    """
    t_start = time.perf_counter()
    objective = _check_objective(objective)
    if aggregate not in ("sum", "worst"):
        raise PlannerError(f"aggregate must be 'sum' or 'worst', got {aggregate!r}")
    plant, drives, base, space, rows = _problem(model, drives, library, objective, baseline,
                                                symmetry, knots_m_s, linear, lag_s)
    need = rows[0]
    if drive_weights is None:
        weights = np.full(len(drives), 1.0 / len(drives))
    else:
        weights = np.asarray(drive_weights, dtype=float).ravel()
        if weights.size != len(drives) or np.any(~np.isfinite(weights)) or np.any(weights < 0) \
                or not weights.sum() > 0:
            raise PlannerError(f"drive_weights {list(np.atleast_1d(drive_weights))} must be "
                               f"{len(drives)} numbers >= 0, not all 0")
        weights = weights / weights.sum()
    constraints = default_constraints() if constraints is None else constraints
    if not isinstance(constraints, CurveConstraints):
        raise TypeError(f"constraints must be CurveConstraints (read_curve_constraints), got "
                        f"{type(constraints).__name__}")
    check_constraints(space, constraints, library)
    families = _constraint_rows(space, constraints, library)
    T = space.expansion()
    A_lin = np.vstack([a for _, a, _ in families]) @ T
    b_lin = np.concatenate([b for _, _, b in families])

    # the baseline's (verified) values per drive of the metrics the objective needs
    from planner.predict import predict_setups

    m_base = [predict_setups(model, d, [base], library, oversample=oversample).table.loc[
        base.name, need].to_numpy(float) for d in drives]

    # start: the best linear damping per group (screening), projected onto the constraints
    rates = _scan_start(plant, drives, library, space, base, objective, m_base, weights)
    start_curves = [PiecewiseLinear([0.0], [0.0], c, c) for c in rates]
    x0 = _project(space.from_curves(start_curves), A_lin, b_lin)

    # scaling of the decision variables: forces by c_bar |v|, slopes by c_bar
    cbar = float(np.mean(plant.cbar_n_s_m))
    if space.linear:
        scale = np.full(space.n_vars, cbar)
    else:
        vk = np.delete(space.v_knots_m_s, space.zero_index)
        per = np.concatenate([cbar * np.maximum(np.abs(vk), 0.05), [cbar, cbar]])
        scale = np.tile(per, len(space.groups))

    jit = _jit_available() if jit is None else bool(jit)
    # the rows the problem needs of the metrics: a score per drive, each limit per drive
    tight = np.ones(len(need))
    if robust:
        tight = _robust_factors(model, drives, library, space, x0, base, need)
    C, kinds = _score_rows(objective, need, m_base, tight)
    t_build = time.perf_counter()
    models_cl = [_LoopModel(plant, d, space, rows, oversample, jit) for d in drives]
    ev = _Evaluator(models_cl, T, scale, C)
    build_s = time.perf_counter() - t_build
    x_opt, solver, history = _solve(ev, space, kinds, weights, aggregate, A_lin, b_lin,
                                    x0 / scale, scale, max_iter, progress)
    solver.update(build_s=build_s, eval_s=ev.eval_s, grad_s=ev.grad_s, n_eval=ev.n_eval,
                  n_grad=ev.n_grad, jit=jit, step_instructions=models_cl[0].n_instructions)
    return _finish(model, plant, drives, library, space, constraints, objective, base, weights,
                   aggregate, oversample, x_opt, solver, history, n_closest, stationarity,
                   A_lin, b_lin, t_start, {"knots_m_s": list(map(float, knots_m_s)),
                                           "robust": bool(robust), "max_iter": max_iter,
                                           "x_start": x0.tolist(), "start_rates": rates.tolist(),
                                           "limit_factors": tight.tolist()})


def _problem(model, drives, library, objective, baseline, symmetry, knots_m_s, linear, lag_s):
    """The loop plant, drives, baseline setup, curve space and metric rows (names, rows of
    the plant's outputs) of an optimization, checked (see :func:`optimize_curves`)."""
    from planner.predict import as_loop_plant
    from planner.screen import metric_rows

    plant = as_loop_plant(model)
    drives = _drive_list(drives, getattr(model, "fs_hz", None))
    base = _resolve_baseline(baseline, library, objective)
    base_models = base.resolve(library)
    groups = SYMMETRIES.get(symmetry)
    if groups is None:
        raise PlannerError(f"symmetry {symmetry!r} is not one of {list(SYMMETRIES)}")
    if lag_s is None:
        lag_s = [float(np.mean([base_models[CORNERS.index(c)].lag_s for c in corners]))
                 for _, corners in groups]
    space = curve_space(symmetry=symmetry, knots_m_s=knots_m_s, linear=linear, lag_s=lag_s)
    names_all, L_all = metric_rows(plant)
    need = [m for m in objective.metrics if m in names_all]
    missing = [m for m in objective.metrics if m not in names_all]
    if missing:
        raise PlannerError(f"the model has no outputs for {missing}; its outputs are "
                           f"{list(plant.output_names)}")
    return plant, drives, base, space, (need, L_all[[names_all.index(m) for m in need]])


def compile_curves(model, drives, library, *, objective=None, baseline=None,
                   symmetry="left-right", knots_m_s=DEFAULT_KNOTS_M_S, linear=False,
                   lag_s=None, oversample=2):
    """Compile the optimizer's step functions of a problem ahead of :func:`optimize_curves`.

    The C compile of the closed loop's step and its adjoint (10-30 s on a
    fresh machine; nothing once cached) is what a first optimization waits
    for. Called with the same arguments as :func:`optimize_curves` (these
    are the ones the compiled code depends on; the drive matters only by its
    sample rate), e.g. in a worker while other work runs, it leaves the
    library in :func:`jit_cache_dir`, where the optimization then finds it.

    Parameters
    ----------
    model, drives, library, objective, baseline, symmetry, knots_m_s, linear, lag_s, oversample
        As :func:`optimize_curves`.

    Returns
    -------
    bool
        True if the steps are compiled (or were cached), False if no C
        compiler is found (the optimization then runs them uncompiled).

    Raises
    ------
    PlannerError, TypeError
        As :func:`optimize_curves`.
    """
    objective = _check_objective(objective)
    plant, drives, _, space, rows = _problem(model, drives, library, objective, baseline,
                                             symmetry, knots_m_s, linear, lag_s)
    if not _jit_available():
        return False
    for d in drives:
        _LoopModel(plant, d, space, rows, oversample, True, inputs=False)
    return True


def _score_rows(objective, need, m_base, tight):
    """The linear combinations of all drives' metrics the problem uses.

    Rows: the score of every drive (``sum w m / m_base``), then every limit of every
    drive as ``tight * m / bound`` (<= 1).

    Returns
    -------
    C : ndarray, shape (n_rows, n_drives * n_metrics)
    kinds : list of (str, int)
        ``("score", drive)`` or ``("limit", drive)`` per row.
    """
    nd, nm = len(m_base), len(need)
    w = np.array([objective.weights.get(m, 0.0) for m in need])
    rows, kinds = [], []
    for d in range(nd):
        r = np.zeros(nd * nm)
        r[d * nm:(d + 1) * nm] = w / m_base[d]
        rows.append(r)
        kinds.append(("score", d))
    for d in range(nd):
        for k, metric in enumerate(need):
            lim = objective.limits.get(metric)
            if not lim:
                continue
            bound = min(lim.get("max_ratio", np.inf) * m_base[d][k], lim.get("max", np.inf))
            r = np.zeros(nd * nm)
            r[d * nm + k] = tight[k] / bound
            rows.append(r)
            kinds.append(("limit", d))
    return np.array(rows), kinds


def _solve(ev, space, kinds, weights, aggregate, A_lin, b_lin, xs0, scale, max_iter, progress):
    """IPOPT on the scaled decision variables; returns (x, solver dict, history DataFrame).

    The objective's limits enter as constraints when they bind: first those within 5 % of
    their bound at the start, then, after each solve, any the solution violates (a warm
    start from it). A limit row costs an adjoint sweep per iterate, so rows that never bind
    are left out.
    """
    score_rows = [j for j, (kind, _) in enumerate(kinds) if kind == "score"]
    limit_rows = [j for j, (kind, _) in enumerate(kinds) if kind == "limit"]
    z0 = ev.value(xs0)
    active = [j for j in limit_rows if z0[j] > 0.95]
    x_start, histories, info, total_its = xs0, [], None, 0
    t0 = time.perf_counter()
    for _ in range(len(limit_rows) + 1):
        xs_opt, info, hist = _ipopt(ev, space, score_rows, active, weights, aggregate, A_lin,
                                    b_lin, x_start, scale, max_iter - total_its, progress)
        histories.append(hist)
        total_its += info["iterations"]
        z = ev.value(xs_opt)
        late = [j for j in limit_rows if j not in active and z[j] > 1.0 + 1e-6]
        if not late or total_its >= max_iter:
            break
        active += late
        x_start = xs_opt
    hist = pd.concat(histories, ignore_index=True)
    hist.insert(0, "iteration", np.arange(len(hist)))
    info.update(iterations=total_its, solve_s=time.perf_counter() - t0,
                active_limits=len(active), limits=len(limit_rows),
                iterates=[x for h in histories for x in h.attrs["iterates"]])
    return xs_opt * scale, info, hist


def _ipopt(ev, space, score_rows, limit_rows, weights, aggregate, A_lin, b_lin, xs0, scale,
           max_iter, progress):
    """One IPOPT solve with the given score and limit rows of ``z``."""
    cb = _MetricsCallback(ev, score_rows + limit_rows)
    xs = ca.MX.sym("xs", space.n_vars)
    z = cb(xs)
    scores = [z[k] for k in range(len(score_rows))]
    g, lbg, ubg = [], [], []
    # linear constraints on the scaled variables, rows normalized
    As = A_lin * scale[None, :]
    rn = np.maximum(np.abs(As).max(axis=1), 1e-300)
    g.append(ca.DM(As / rn[:, None]) @ xs)
    lbg.append(np.full(As.shape[0], -np.inf))
    ubg.append(b_lin / rn)
    for k in range(len(limit_rows)):
        g.append(z[len(score_rows) + k])
        lbg.append([-np.inf])
        ubg.append([1.0])
    if aggregate == "sum":
        f = sum(float(wd) * sd for wd, sd in zip(weights, scores))
        x_all, x_start = xs, xs0
    else:
        t = ca.MX.sym("t")
        f = t
        for sd in scores:
            g.append(sd - t)
            lbg.append([-np.inf])
            ubg.append([0.0])
        x_all = ca.vertcat(xs, t)
        x_start = np.concatenate([xs0, [float(np.max(ev.value(xs0)[score_rows]))]])
    G = ca.vertcat(*g)
    it_cb = _Iterations(x_all.shape[0], G.shape[0], progress)
    opts = {"ipopt.hessian_approximation": "limited-memory", "ipopt.max_iter": int(max_iter),
            "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-3, "ipopt.acceptable_iter": 5,
            "ipopt.acceptable_obj_change_tol": ACCEPTABLE_CHANGE, "ipopt.print_level": 0,
            "print_time": False, "ipopt.sb": "yes", "iteration_callback": it_cb,
            "ipopt.mu_strategy": "adaptive"}
    solver = ca.nlpsol("curves", "ipopt", {"x": x_all, "f": f, "g": G}, opts)
    try:
        sol = solver(x0=x_start, lbg=np.concatenate(lbg), ubg=np.concatenate(ubg))
    finally:
        it_cb.close()
    stats = solver.stats()
    its = stats.get("iterations", {})
    hist = pd.DataFrame({"objective": [h["objective"] for h in it_cb.history],
                         "time_s": [h["time_s"] for h in it_cb.history]})
    for key in ("inf_pr", "inf_du"):
        if key in its and len(its[key]) == len(hist):
            hist[key] = its[key]
    hist.attrs["iterates"] = [(h["x"][:space.n_vars] * scale, h["objective"])
                              for h in it_cb.history]
    info = {"status": stats.get("return_status", "unknown"),
            "success": stats.get("return_status") in _SOLVED,
            "iterations": int(stats.get("iter_count", len(hist))),
            "objective": float(sol["f"])}
    return np.array(sol["x"]).ravel()[:space.n_vars], info, hist


def _robust_factors(model, drives, library, space, x, base, need):
    """Upper 95 % bound over the nominal of each limited metric at `x` (identified models)."""
    from planner.uncertainty import prediction_uncertainty

    if getattr(model, "frf", None) is None:
        raise PlannerError("robust=True needs an identified model (with its FRF): a known "
                           "model has no estimation error")
    shocks = _optimal_shocks(space, x)
    lib = ShockLibrary(list(shocks.values()) + list(library.values()))
    unc = prediction_uncertainty(model, drives[0], [_setup_of(space, shocks)], lib)
    hi = unc.ratio_hi.iloc[0]
    return np.array([max(float(hi.get(m, 1.0)), 1.0) for m in need])


def curve_distance(pwl_a, pwl_b, v_samples):
    """RMS difference of two curves over velocity samples, relative to the second's RMS force.

    Parameters
    ----------
    pwl_a, pwl_b : PiecewiseLinear
    v_samples : ndarray
        Shock velocities [m/s] (the distribution the curves are compared over).

    Returns
    -------
    float
    """
    fa, fb = pwl_a.force(v_samples), pwl_b.force(v_samples)
    return float(np.sqrt(np.mean((fa - fb) ** 2) / max(np.mean(fb**2), 1e-300)))


def _finish(model, plant, drives, library, space, constraints, objective, base, weights,
            aggregate, oversample, x_opt, solver, history, n_closest, stationarity, A_lin,
            b_lin, t_start, settings):
    from ident.sim.closedloop import simulate
    from planner.setups import enumerate_setups

    # verify the optimum and the best feasible iterate; keep the better verified one
    cands = [x_opt]
    feas = [(f, x) for x, f in solver.pop("iterates")
            if np.all(A_lin @ x <= b_lin + 1e-6 * (1 + np.abs(b_lin)))]
    if feas:
        cands.append(min(feas, key=lambda fx: fx[0])[1])
    verified = []
    for k, x in enumerate(cands):
        shocks = _optimal_shocks(space, x)
        lib = ShockLibrary(list(shocks.values()) + list(library.values()))
        setup = _setup_of(space, shocks)
        sc, _ = _time_domain_scores(model, drives, [setup], lib, objective, base, weights,
                                    oversample, aggregate)
        verified.append((float(sc.loc["optimum", "score"]), bool(sc.loc["optimum", "feasible"]),
                         k))
    ok = [v for v in verified if v[1]] or verified
    best_k = min(ok)[2]
    x_opt = _valid(space, cands[best_k])
    shocks = _optimal_shocks(space, x_opt)
    lib = ShockLibrary(list(shocks.values()) + list(library.values()))
    setup = _setup_of(space, shocks)
    if not solver["success"]:
        warnings.warn(f"optimize: IPOPT stopped with status {solver['status']!r} after "
                      f"{solver['iterations']} iterations; the best verified iterate is "
                      "returned (score "
                      f"{min(ok)[0]:.4f}): raise max_iter, or check the constraints",
                      OptimizeWarning, stacklevel=3)

    # the optimum's shock velocities (first drive): the distribution the crate is compared over
    resp = simulate(plant, drives[0], setup.resolve(lib), oversample=oversample)
    vel = {c: np.asarray(resp.channels[f"shock_velocity_{c}"]) for c in CORNERS}
    # the crate: every setup of the same symmetry, by distance to the optimal curves
    sym, axles = {"left-right": ("left-right", "independent"), "axle": ("left-right", "same"),
                  "none": ("none", "independent")}[space.symmetry]
    crate = list(enumerate_setups(library, symmetry=sym, axles=axles))
    if base.name not in {s.name for s in crate}:
        crate.append(base)
    opt_pwl = {c: space.curves(x_opt)[space.group_of(c)] for c in CORNERS}
    dist_id = {(c, sid): curve_distance(library[sid].to_pwl(), opt_pwl[c], vel[c])
               for c in CORNERS for sid in library.ids}
    dist = np.array([math.sqrt(np.mean([dist_id[(c, s.shocks[c])] ** 2 for c in CORNERS]))
                     for s in crate])
    order = np.argsort(dist, kind="stable")
    closest = [crate[i] for i in order[:n_closest]]
    best_name, crate_scores = _crate_best(model, drives, library, crate, objective, base,
                                          weights, oversample, aggregate)
    by_name = {s.name: s for s in crate}
    listed = [setup, base] + [by_name[best_name]] + closest
    uniq, seen = [], set()
    for s in listed:
        if s.name not in seen:
            uniq.append(s)
            seen.add(s.name)
    table, metrics = _time_domain_scores(model, drives, uniq, lib, objective, base, weights,
                                         oversample, aggregate)
    table = table.loc[[s.name for s in uniq]]
    kinds = {setup.name: "optimum", base.name: "baseline"}
    kinds.setdefault(best_name, "crate best")
    for s in closest:
        kinds.setdefault(s.name, "closest")
    table.insert(0, "kind", [kinds[n] for n in table.index])
    ids = pd.DataFrame([s.ids() for s in uniq], columns=list(CORNERS), index=table.index)
    table = pd.concat([table.iloc[:, :1], ids, table.iloc[:, 1:]], axis=1)
    dmap = dict(zip([s.name for s in crate], dist))
    table["distance"] = [0.0 if n == setup.name else dmap.get(n, np.nan) for n in table.index]
    table.index.name = "setup"
    gap = 1.0 - table.loc[setup.name, "score"] / table.loc[best_name, "score"]
    solver["verified_score"] = float(table.loc[setup.name, "score"])
    stat = None
    if stationarity and not space.linear:
        stat = _stationarity(model, drives, lib, space, x_opt, A_lin, b_lin, objective, base,
                             weights, oversample, aggregate, solver["verified_score"])
    settings.update(oversample=oversample, aggregate=aggregate, weights=weights.tolist(),
                    drives=[d.name for d in drives], symmetry=space.symmetry,
                    linear=space.linear, lag_s=list(space.lag_s), total_s=None,
                    crate_scores=crate_scores)
    settings["total_s"] = time.perf_counter() - t_start
    return CurveOptimum(x=np.asarray(x_opt), curves=space.curves(x_opt), shocks=shocks,
                        setup=setup, table=table, metrics=metrics, crate_best=best_name,
                        gap=float(gap), velocity_m_s=vel, stationarity=stat, history=history,
                        solver=solver, space=space, constraints=constraints,
                        objective=objective, baseline=base, settings=settings)


def _crate_best(model, drives, library, crate, objective, base, weights, oversample, aggregate,
                top=20):
    """The crate's best feasible setup: screened on every drive, the best `top` verified."""
    from planner.objective import score_setups
    from planner.screen import screen_setups

    total = None
    for w, d in zip(weights, drives):
        sc = screen_setups(model, d, crate, library).table
        s = score_setups(sc, objective, baseline=base.name).table
        v = s["score"].where(s["feasible"], np.inf)
        total = w * v if total is None else (total + w * v if aggregate == "sum"
                                             else np.maximum(total, v))
    order = total.sort_values(kind="stable").index.tolist()
    cand = [s for s in crate if s.name in set(order[:top])]
    table, _ = _time_domain_scores(model, drives, cand, library, objective, base, weights,
                                   oversample, aggregate)
    feas = table[table["feasible"]]
    pick = feas if len(feas) else table
    return str(pick["score"].idxmin()), {n: float(v) for n, v in pick["score"].items()}


def _stationarity(model, drives, lib, space, x, A, b, objective, base, weights, oversample,
                  aggregate, score):
    """Each decision variable moved by +-5 % (within the linear constraints), verified."""
    from planner.setups import Setup

    rows, setups, extra = [], [], []
    # a move is within the constraints if it violates none more than the optimum does (an
    # interior-point solution meets its constraints to the solver's tolerance)
    slack = np.maximum(A @ x - b, 0.0) + 1e-9 * (1 + np.abs(b))
    for j in range(space.n_vars):
        for sgn in (-1.0, 1.0):
            xt = x.copy()
            xt[j] *= 1.0 + 0.05 * sgn
            if not np.all(A @ xt - b <= slack) or xt[j] == x[j]:
                continue
            shocks = _optimal_shocks(space, xt, prefix=f"S{j}{'m' if sgn < 0 else 'p'}")
            extra += list(shocks.values())
            setups.append(Setup(f"var{j}{'-' if sgn < 0 else '+'}",
                                {c: shocks.ids[space.group_of(c)] for c in CORNERS}))
            rows.append((j, sgn))
    if not setups:
        return pd.DataFrame(columns=["variable", "change", "score", "relative_change"])
    lib2 = ShockLibrary(list(lib.values()) + extra)
    table, _ = _time_domain_scores(model, drives, setups, lib2, objective, base, weights,
                                   oversample, aggregate)
    out = pd.DataFrame({"variable": [j for j, _ in rows], "change": [0.05 * s for _, s in rows],
                        "score": table.loc[[s.name for s in setups], "score"].to_numpy(),
                        "feasible": table.loc[[s.name for s in setups], "feasible"].to_numpy()})
    out["relative_change"] = out["score"] / score - 1.0
    return out


# ----------------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------------

#: Velocities of the shock builder's force table [m/s] and [in/s].
BUILDER_VELOCITIES_M_S = (0.0125, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.25, 0.35, 0.5, 0.75, 1.0)
BUILDER_VELOCITIES_IN_S = (0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0, 40.0)


def curve_table(optimum, *, units="SI"):
    """The optimal curves as a force table for a shock builder.

    Parameters
    ----------
    optimum : CurveOptimum
    units : {"SI", "imperial"}
        SI: force [N] at :data:`BUILDER_VELOCITIES_M_S` [m/s]; imperial: [lbf]
        at :data:`BUILDER_VELOCITIES_IN_S` [in/s]; bump (compression) positive,
        rebound rows negative.

    Returns
    -------
    pandas.DataFrame
        Index: velocity; one column per optimal shock.
    """
    from ident.data.units import from_si

    units = check_units(units, where="units", error=PlannerError)
    vel = np.asarray(BUILDER_VELOCITIES_M_S if units == "SI" else BUILDER_VELOCITIES_IN_S)
    v = np.concatenate([-vel[::-1], vel])
    v_si = to_si(v, "velocity", units)
    cols = {sid: from_si(m.force(v_si), "force", units) for sid, m in optimum.shocks.items()}
    label = "velocity [m/s]" if units == "SI" else "velocity [in/s]"
    out = pd.DataFrame(cols, index=pd.Index(v, name=label))
    return out.rename(columns=lambda c: f"{c} [{'N' if units == 'SI' else 'lbf'}]")


def curves_figure(optimum, library):
    """The optimal curves against the crate's, with the optimum's shock-velocity histograms.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    G = len(optimum.space.groups)
    fig = Figure(figsize=(5.5 * G, 4.6), layout="constrained")
    axes = fig.subplots(1, G, squeeze=False)[0]
    v = np.linspace(-0.6, 0.6, 241)
    for ax, (name, corners), pwl in zip(axes, optimum.space.groups, optimum.curves):
        samples = np.concatenate([optimum.velocity_m_s[c] for c in corners])
        hist = ax.twinx()
        hist.hist(samples, bins=np.linspace(-0.6, 0.6, 61), color="#d9e6f2", density=True)
        hist.set_yticks([])
        ax.set_zorder(hist.get_zorder() + 1)
        ax.patch.set_visible(False)
        for k, m in enumerate(library.values()):
            ax.plot(v, m.force(v), color="0.7", lw=0.8, label="crate" if k == 0 else None)
        for sid in set(optimum.table.loc[optimum.crate_best, list(corners)]):
            ax.plot(v, library[sid].force(v), color="tab:orange", lw=1.6,
                    label=f"crate best ({sid})")
        ax.plot(v, pwl.force(v), color="tab:blue", lw=2.2, label=f"optimum ({name})")
        ax.plot(pwl.v_knots_m_s, pwl.f_knots_n, "o", color="tab:blue", ms=4)
        ax.axhline(0, color="0.5", lw=0.6)
        ax.axvline(0, color="0.5", lw=0.6)
        ax.set(xlabel="shock velocity [m/s] (compression +)", ylabel="force [N]",
               title=f"{name}: {', '.join(corners)}", xlim=(-0.6, 0.6))
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(f"optimal curves (score {optimum.score:.4f}) and the crate; shaded: the "
                 "optimum's shock velocities", fontsize=10)
    return fig


def _setups_sheet(optimum, units):
    from planner.report import ranking_to_units

    first = next(iter(optimum.metrics))
    met = optimum.metrics[first].loc[optimum.table.index]
    metric_cols = [c for c in met.columns if c in METRIC_NAMES]
    t = optimum.table.copy()
    t = pd.concat([t, ranking_to_units(met[metric_cols], units)], axis=1)
    return t.reset_index()


def write_optimum(optimum, library, out_dir, *, units="SI", overwrite=False):
    """Write an optimum's files into a folder (built aside, then moved into place).

    Files: ``optimal_shocks.toml`` (the optimal shocks, table kind with lag, and the
    crate's, so the setups file reads against it), ``optimal_setup.csv`` (the optimum,
    then the crate setups closest to it), ``optimize.xlsx`` (force tables for the shock
    builder in SI and imperial, the setups side by side, the solver's report),
    ``curves.png`` and ``convergence.csv``.

    Parameters
    ----------
    optimum : CurveOptimum
    library : ShockLibrary
        The crate.
    out_dir : str or path
    units : {"SI", "imperial"}
        Units of the shock library and the metrics.
    overwrite : bool
        Replace an existing folder.

    Returns
    -------
    dict of str -> pathlib.Path

    Raises
    ------
    FileExistsError
        If `out_dir` exists and is not empty, and `overwrite` is false (checked first).
    """
    from openpyxl import Workbook
    from openpyxl.styles import Font

    from ident.data.files import atomic_dir
    from ident.models.shocks import write_shock_library
    from planner.setups import write_setups

    units = check_units(units, where="units", error=PlannerError)
    out = Path(out_dir)
    names = {"shocks": "optimal_shocks.toml", "setups": "optimal_setup.csv",
             "xlsx": "optimize.xlsx", "curves": "curves.png", "convergence": "convergence.csv"}
    with atomic_dir(out, overwrite=overwrite) as work:
        lib = ShockLibrary(list(optimum.shocks.values())
                           + [m for m in library.values() if m.id not in optimum.shocks])
        write_shock_library(lib, work / names["shocks"], units=units)
        closest = [s for s in _table_setups(optimum) if s.name != optimum.setup.name
                   and optimum.table.loc[s.name, "kind"] == "closest"]
        write_setups([optimum.setup] + closest, work / names["setups"])
        wb = Workbook()
        ws = wb.active
        ws.title = "curves SI"
        for title, u in (("curves SI", "SI"), ("curves imperial", "imperial")):
            sheet = ws if title == "curves SI" else wb.create_sheet(title)
            tab = curve_table(optimum, units=u).round(1).reset_index()
            sheet.append(list(tab.columns))
            for row in tab.itertuples(index=False):
                sheet.append([float(x) for x in row])
            for cell in sheet[1]:
                cell.font = Font(bold=True)
            sheet.freeze_panes = "B2"
        ss = wb.create_sheet("setups")
        tab = _setups_sheet(optimum, units)
        ss.append(list(tab.columns))
        for row in tab.itertuples(index=False):
            ss.append([x.item() if hasattr(x, "item") else x for x in row])
        for cell in ss[1]:
            cell.font = Font(bold=True)
        ss.freeze_panes = "B2"
        rep = wb.create_sheet("solver")
        s = optimum.solver
        for key, value in (("optimum score (time domain)", optimum.score),
                           ("crate best", optimum.crate_best),
                           ("crate best score", float(optimum.table.loc[optimum.crate_best,
                                                                         "score"])),
                           ("gain over the crate best", f"{100 * optimum.gap:.2f} %"),
                           ("IPOPT status", s["status"]), ("iterations", s["iterations"]),
                           ("closed-loop evaluations", s["n_eval"]),
                           ("adjoint sweeps", s["n_grad"]), ("compiled (jit)", s["jit"]),
                           ("symmetry", optimum.space.symmetry),
                           ("objective", optimum.objective.name),
                           ("baseline", "/".join(optimum.baseline.ids())),
                           ("drives", ", ".join(optimum.settings["drives"])),
                           ("units", units)):
            rep.append([key, value])
        if optimum.stationarity is not None and len(optimum.stationarity):
            rep.append(["largest gain of a +-5 % knot move",
                        f"{-100 * min(0.0, optimum.stationarity.relative_change.min()):.3f} %"])
        rep.column_dimensions["A"].width = 34
        rep.column_dimensions["B"].width = 40
        wb.save(work / names["xlsx"])
        fig = curves_figure(optimum, library)
        fig.savefig(work / names["curves"], dpi=110)
        # wall times are logged, not written: a rerun writes the same bytes
        optimum.history.drop(columns=["time_s"], errors="ignore").to_csv(
            work / names["convergence"], index=False, float_format="%.9g")
    return {k: out / v for k, v in names.items()}


def _table_setups(optimum):
    from planner.setups import Setup

    return [Setup(n, dict(zip(CORNERS, (optimum.table.loc[n, c] for c in CORNERS))))
            for n in optimum.table.index]
