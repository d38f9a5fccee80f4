"""The curves the optimizer chooses from: corner groups, velocity knots, the parametrization.

A :class:`CurveSpace` maps the decision variables of
:func:`planner.optimize.optimize_curves` (per corner group, the forces at fixed
velocity knots and the slopes beyond the outer knots, or one damping rate) to
piecewise-linear force-velocity curves and back; :func:`curve_space` builds one
for a symmetry (:data:`SYMMETRIES`) and knots.

>>> sp = curve_space(knots_m_s=(0.1, 0.3))
>>> sp.v_knots_m_s.tolist()
[-0.3, -0.1, 0.0, 0.1, 0.3]
>>> [name for name, _ in sp.groups], sp.n_vars
(['front', 'rear'], 12)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ident.data.channels import CORNERS
from ident.models.library import ShockLibrary
from ident.models.shocks import PiecewiseLinear, TableShock
from planner.errors import PlannerError
from planner.setups import Setup

__all__ = [
    "CurveSpace",
    "SYMMETRIES",
    "DEFAULT_KNOTS_M_S",
    "curve_space",
    "symmetry_groups",
]

#: Bump knot velocities [m/s] (rebound mirrors them).
DEFAULT_KNOTS_M_S = (0.025, 0.05, 0.1, 0.25, 0.5)
#: Corner groups of each symmetry: (group name, corners).
SYMMETRIES = {
    "left-right": (("front", ("LF", "RF")), ("rear", ("LR", "RR"))),
    "all": (("all", CORNERS),),
    "none": tuple((c, (c,)) for c in CORNERS),
}


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
    v_range_m_s : (float, float) or None
        The shock speeds [m/s] below which the car spends most of its time
        (by default 99 %: :data:`planner.optimize.knots.RANGE_QUANTILE`),
        rebound then bump: the velocity range the buildable constraints
        hold in (:func:`planner.optimize.constraints.constraint_rows`).
        None: every segment.
    """

    groups: tuple
    v_knots_m_s: np.ndarray
    linear: bool
    lag_s: tuple
    symmetry: str
    v_range_m_s: tuple | None = None

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

    def valid(self, x):
        """`x` with the curves' validity exact.

        An interior-point solution meets its constraints to the solver's
        tolerance (a slope of -5e-5 N/(m/s) is not passive for a shock
        model). Knot forces are made non-decreasing through F(0) = 0 with the
        sign of their velocity, end slopes >= 0; changes are of the order of
        the tolerance.
        """
        if self.linear:
            return np.maximum(np.asarray(x, dtype=float), 0.0)
        K, z = self.v_knots_m_s.size, self.zero_index
        out = []
        for p in self.params(x):
            f = p[:K].copy()
            f[z] = 0.0
            f[z + 1:] = np.maximum.accumulate(np.maximum(f[z + 1:], 0.0))
            f[:z] = -np.maximum.accumulate(np.maximum(-f[:z][::-1], 0.0))[::-1]
            out.append(PiecewiseLinear(self.v_knots_m_s, f, max(p[K], 0.0), max(p[K + 1], 0.0)))
        return self.from_curves(out)

    def shocks(self, x, *, prefix="OPT"):
        """Table shocks of the curves of `x`, ids ``<prefix>-<group>``.

        The end slopes are kept by one extra point a side (0.5 m/s beyond the
        outer knots); each group's lag.

        Returns
        -------
        ShockLibrary
        """
        models = []
        for (name, _), pwl, lag in zip(self.groups, self.curves(self.valid(x)), self.lag_s):
            v, f = pwl.v_knots_m_s, pwl.f_knots_n
            ext = 0.5
            vv = np.concatenate([[v[0] - ext], v, [v[-1] + ext]])
            ff = np.concatenate([[f[0] - pwl.slope_below * ext], f,
                                 [f[-1] + pwl.slope_above * ext]])
            models.append(TableShock(f"{prefix}-{name}", vv, ff, lag_s=lag,
                                     description=f"optimal {name} curve (shockplan optimize)"))
        return ShockLibrary(models)

    def setup(self, shocks, name="optimum"):
        """The setup that puts each group's shock of `shocks` (one per group, in
        group order, as :meth:`shocks` returns) on the group's corners."""
        return Setup(name, {c: shocks.ids[self.group_of(c)] for c in CORNERS})

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
                linear=False, lag_s=0.0, v_range_m_s=None):
    """Build the curves the optimizer chooses from.

    Parameters
    ----------
    symmetry : {"left-right", "all", "none"}
        ``left-right``: a curve per axle, the same left and right (LF = RF,
        LR = RR); ``all``: one curve at every corner; ``none``: four curves.
    knots_m_s : sequence of float
        Bump knot velocities [m/s], positive and increasing.
    rebound_knots_m_s : sequence of float, optional
        Rebound knot speeds [m/s] (positive numbers, mirrored); default the
        bump knots.
    linear : bool
        One damping rate per group.
    lag_s : float or sequence of float
        Lag per group [s].
    v_range_m_s : (float, float), optional
        Rebound and bump speeds [m/s] (positive) below which the buildable
        constraints hold (:attr:`CurveSpace.v_range_m_s`); default every
        segment.

    Returns
    -------
    CurveSpace

    Raises
    ------
    PlannerError
        On an unknown symmetry (``"axle"`` is now ``"all"``) or knots that are
        not positive and strictly increasing.
    """
    groups = symmetry_groups(symmetry)
    bump = _knots(knots_m_s, "knots_m_s")
    reb = bump if rebound_knots_m_s is None else _knots(rebound_knots_m_s, "rebound_knots_m_s")
    v = np.concatenate([-reb[::-1], [0.0], bump])
    lags = np.broadcast_to(np.asarray(lag_s, dtype=float), (len(groups),))
    if np.any(~np.isfinite(lags)) or np.any(lags < 0):
        raise PlannerError(f"lag_s must be >= 0 [s], got {lag_s!r}")
    if v_range_m_s is not None:
        rng = np.asarray(v_range_m_s, dtype=float).ravel()
        if rng.size != 2 or np.any(~np.isfinite(rng)) or np.any(rng <= 0):
            raise PlannerError(f"v_range_m_s must be two positive speeds [m/s] (rebound, bump), "
                               f"got {v_range_m_s!r}")
        v_range_m_s = (float(rng[0]), float(rng[1]))
    return CurveSpace(groups=groups, v_knots_m_s=v, linear=bool(linear),
                      lag_s=tuple(float(x) for x in lags), symmetry=symmetry,
                      v_range_m_s=v_range_m_s)


def symmetry_groups(symmetry):
    """The corner groups of a symmetry (:data:`SYMMETRIES`).

    Parameters
    ----------
    symmetry : {"left-right", "all", "none"}

    Returns
    -------
    tuple of (str, tuple of str)
        Group name and its corners.

    Raises
    ------
    PlannerError
        On an unknown symmetry; on ``"axle"``, the old name of ``"all"`` (an
        axle is a pair of corners in :mod:`planner.setups`), naming the new one.

    Examples
    --------
    >>> symmetry_groups("left-right")
    (('front', ('LF', 'RF')), ('rear', ('LR', 'RR')))
    >>> symmetry_groups("all")
    (('all', ('LF', 'RF', 'LR', 'RR')),)
    """
    if symmetry not in SYMMETRIES:
        if symmetry == "axle":
            raise PlannerError("symmetry 'axle' is not a symmetry of optimize: use 'all' (one "
                               "curve for every corner)")
        raise PlannerError(f"symmetry {symmetry!r} is not one of {list(SYMMETRIES)}")
    return SYMMETRIES[symmetry]


def _knots(values, name):
    try:
        k = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise PlannerError(f"{name} must be a list of velocities [m/s], got {values!r}") from None
    if k.size < 1 or np.any(~np.isfinite(k)) or np.any(k <= 0) or np.any(np.diff(k) <= 0):
        raise PlannerError(f"{name} must be positive, strictly increasing velocities [m/s], "
                           f"got {k.tolist()}")
    return k
