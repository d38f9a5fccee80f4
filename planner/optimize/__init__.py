"""The best damper curve per corner group: a nonlinear program over force-velocity curves.

``optimize_curves(model, drives, library, ...)`` finds, for each corner group
(left-right symmetric by default), the piecewise-linear force-velocity curve
that minimizes the objective of :mod:`planner.objective` (baseline-normalized
metrics, limits as constraints) on one or several drives, subject to linear
constraints that make the curve buildable. It then maps the optimum to the
crate: the crate's setups nearest to the optimal curves, simulated, and the
crate's best, so the gap between them prices a new shock. With adjustable shocks
in the crate, each one's best settings per corner group
(:mod:`planner.optimize.click_search`: from the settings nearest the optimum, a
neighbourhood search in clicks verified in the time domain), their gain over the
best fixed setup and the gap to the optimum (what a custom valving adds).

Formulation
-----------
Decision variables, per group: the forces ``F_j`` at fixed velocity knots
(rebound ``-v_K < ... < -v_1 < 0 < v_1 < ... < v_K`` bump, default ``v`` =
0.025, 0.05, 0.1, 0.25, 0.5 m/s), with ``F(0) = 0``, and the slopes beyond the
outer knots. Between knots the curve is linear; the lag of each group is fixed
(the baseline's shock's, or given). With ``linear=True`` a group's variable
is one damping rate (``F_j = c v_j``): the known-answer case. The groups are
those of a symmetry: ``left-right`` (a curve per axle), ``all`` (one curve
for every corner) or ``none`` (a curve per corner).

The closed loop is that of :mod:`ident.sim.closedloop`, written in casadi as a
discrete recursion over the drive's samples (:mod:`planner.optimize.loop`).
Gradients come by automatic differentiation (casadi's reverse mode through the
recursion). The loop's step and its adjoint are compiled to C when a C
compiler is found (5-7 s of compilation, once per machine and problem:
:func:`jit_cache_dir`). IPOPT solves the problem with a limited-memory
Hessian; metrics and their Jacobian are computed once per iterate and shared
by the objective and the constraints. The start is the best curve of a scan
of linear and two-slope curves per group (:mod:`planner.optimize.scan`:
screened by :mod:`planner.screen`, the best few of each kind verified in the
time domain), among the curves that meet the constraints; the result is the
best verified of IPOPT's solution, its best feasible iterate and that curve,
so it is never worse than the scan's best. A stop at IPOPT's acceptable level
is reported as not converged.

Every result is verified by :func:`planner.predict.predict_setups`, the
time-domain simulator the rest of shockplan trusts, and that figure is the one
reported. A solver failure is reported with IPOPT's status and the best
verified iterate (:class:`OptimizeWarning`), never silently.

Modules
-------
- :mod:`~planner.optimize.space`: the curve space (groups, knots, the
  parametrization);
- :mod:`~planner.optimize.knots`: velocity knots on the quantiles of the
  baseline's shock speeds (``knots_m_s="quantiles"``);
- :mod:`~planner.optimize.constraints`: the buildability constraints, their
  file (``format = "curve-constraints/1"``) and the check that refuses a set
  no curve can meet, naming the constraints that conflict;
- :mod:`~planner.optimize.loop`: the closed loop in casadi (the sub-step, the
  Newton iterations, the metric filters, the fold over the samples);
- :mod:`~planner.optimize.cache`: the compiled step functions on disk;
- :mod:`~planner.optimize.scan`: the global stage, linear curves per group screened
  on a grid and the best verified in the time domain (IPOPT's start and a floor
  under the result);
- :mod:`~planner.optimize.solve`: the metrics' evaluator and IPOPT;
- :mod:`~planner.optimize.click_search`: the click search of the crate's adjustable
  shocks (:func:`search_clicks`) and :func:`curve_distance`;
- :mod:`~planner.optimize.third`: a car's third elements in the optimization (the
  baseline's, the free third dampers' check, the crate's third-element choices);
- :mod:`~planner.optimize.options`: the optimizer's option objects (:class:`CurveOptions`,
  :class:`SolverOptions`);
- :mod:`~planner.optimize.core`: :func:`optimize_curves` and
  :func:`compile_curves`, the crate mapping and the verification.

The files (``optimize.xlsx``, ``curves.png``, ``convergence.csv``, the optimal
shocks and setups) are written by :mod:`planner.report.optimize`; its public
names are re-exported here.
"""

from planner.optimize.cache import JIT_CACHE_MAX_FILES, JIT_FLAGS, jit_cache_dir
from planner.optimize.click_search import CLICK_RADIUS, ClickResult, ClickSearch, search_clicks
from planner.optimize.constraints import (
    CONSTRAINTS_FORMAT,
    MAX_FORCE_VELOCITY_M_S,
    CurveConstraints,
    check_constraints,
    default_constraints,
    read_curve_constraints,
)
from planner.optimize.core import CurveOptimum, compile_curves, curve_distance, optimize_curves
from planner.optimize.knots import KNOT_QUANTILES, QUANTILE_KNOTS, velocity_knots
from planner.optimize.loop import FOLD_BASE, NEWTON_ITERATIONS
from planner.optimize.options import CurveOptions, SolverOptions
from planner.optimize.scan import ScanOptions, ScanResult, scan_curves
from planner.optimize.solve import ACCEPTABLE_CHANGE, OptimizeWarning
from planner.optimize.space import DEFAULT_KNOTS_M_S, SYMMETRIES, CurveSpace, curve_space
from planner.report.optimize import (
    BUILDER_VELOCITIES_IN_S,
    BUILDER_VELOCITIES_M_S,
    click_summary,
    click_table,
    curve_table,
    curves_figure,
    write_optimum,
)

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
    "ScanResult",
    "ScanOptions",
    "scan_curves",
    "CurveOptions",
    "SolverOptions",
    "velocity_knots",
    "KNOT_QUANTILES",
    "QUANTILE_KNOTS",
    "compile_curves",
    "curve_distance",
    "CLICK_RADIUS",
    "ClickResult",
    "ClickSearch",
    "search_clicks",
    "click_summary",
    "click_table",
    "curve_table",
    "curves_figure",
    "write_optimum",
    "BUILDER_VELOCITIES_M_S",
    "BUILDER_VELOCITIES_IN_S",
    "MAX_FORCE_VELOCITY_M_S",
    "NEWTON_ITERATIONS",
    "ACCEPTABLE_CHANGE",
    "FOLD_BASE",
    "JIT_CACHE_MAX_FILES",
    "JIT_FLAGS",
    "jit_cache_dir",
]
