"""The optimizer's option objects: the curve space asked for, and the solve.

:func:`planner.optimize.optimize_curves` takes the data, the objective and its constraints,
and these keyword-only objects besides the planner's (:mod:`planner.options`):
:class:`CurveOptions` (the curves: corner groups, knots, linear or not, lags) and
:class:`SolverOptions` (IPOPT's iterations and starts, the compile, the verification's
extras). Their defaults are the optimizer's defaults.

Examples
--------
>>> CurveOptions(symmetry="all").knots_m_s
'quantiles'
>>> SolverOptions(max_iter=10).n_starts
2
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.optimize.click_search import CLICK_RADIUS
from planner.optimize.knots import QUANTILE_KNOTS

__all__ = ["CurveOptions", "SolverOptions"]

@dataclass(frozen=True, eq=False)
class CurveOptions:
    """The force-velocity curves the optimizer searches.

    Parameters
    ----------
    symmetry : {"left-right", "all", "none"}
        Corner groups (:func:`~planner.optimize.space.curve_space`): a curve per axle,
        one for every corner, or one per corner.
    knots_m_s : "quantiles" or sequence of float
        ``"quantiles"`` (default): per side on the quantiles ``KNOT_QUANTILES`` of the
        baseline's shock speeds on the drives, every corner pooled
        (:func:`planner.optimize.knots.velocity_knots`), the last at their 99 %; or bump
        knot velocities [m/s] (rebound mirrors them), e.g. ``DEFAULT_KNOTS_M_S``.
    linear : bool
        One damping rate per group (the known-answer case).
    lag_s : float or sequence of float, optional
        The optimal shocks' lag [s]; default per group the mean lag of the baseline's
        shocks at its corners.
    free_third : sequence of str
        Third dampers (``heave_front``, ``heave_rear``, ``roll_front``, ``roll_rear``) of a
        car with third elements whose curves are optimized with the corner curves (issue
        38): a curve per element on the corner curves' knots, in the element's own velocity
        and force, its lag the baseline damper's (:data:`planner.optimize.core.THIRD_ENVELOPE`
        bounds it). Default none: the car's baseline third dampers, fixed.

    Notes
    -----
    The symmetry and the knots are checked with the problem (:func:`optimize_curves`
    raises :class:`planner.errors.PlannerError` on an unknown one).
    """

    symmetry: str = "left-right"
    knots_m_s: object = QUANTILE_KNOTS
    linear: bool = False
    lag_s: object = None
    free_third: tuple = ()


@dataclass(frozen=True)
class SolverOptions:
    """IPOPT's solve of the curve problem and what the optimizer verifies after it.

    Parameters
    ----------
    max_iter : int
        IPOPT iterations (of the first start).
    n_starts : int
        IPOPT starts: the scan's best verified curve, then the best verified curve of the
        other kind (linear or two-slope) with :data:`planner.optimize.core.MULTI_START_ITER`
        iterations; every start's result is verified.
    jit : bool, optional
        Compile the loop to C (default: when a C compiler is found).
    stationarity : bool
        Report the effect of moving each knot force by +-5 % (time domain).
    n_closest : int
        Crate setups nearest the optimum to simulate and report.
    click_radius : int or None
        With adjustable shocks in the crate: the click search's moves, +-1..`click_radius`
        steps of one adjuster (:func:`planner.optimize.click_search.search_clicks`); None: no
        click search.

    Raises
    ------
    TypeError
        If `max_iter`, `n_starts` or `n_closest` is not an integer.
    """

    max_iter: int = 80
    n_starts: int = 2
    jit: bool | None = None
    stationarity: bool = True
    n_closest: int = 5
    click_radius: int | None = CLICK_RADIUS

    def __post_init__(self):
        for name in ("max_iter", "n_starts", "n_closest"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise TypeError(f"SolverOptions: {name}={value!r} must be an integer")
