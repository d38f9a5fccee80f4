"""The curve optimization: the problem, the start, the solve, the crate mapping, the verification.

:func:`optimize_curves` checks the problem (model, drives, baseline,
objective, curve space), starts from the best linear damping per group of a
scan (:mod:`planner.optimize.scan`: screened, the best few verified), solves
(:mod:`planner.optimize.solve`) through the casadi loop
(:mod:`planner.optimize.loop`), verifies the optimum, the best feasible
iterate and the scan's best in the time domain
(:func:`planner.predict.predict_setups`) and keeps the best, and maps the
optimum to the crate (the nearest setups and the crate's best).
:func:`compile_curves` compiles a problem's step functions ahead.

With the real car's elements (issue 25): bump stops in the optimizer's loop
and in every verification, packers as decision variables per corner group
(IPOPT's variables after the curves', bounded), and static loads for lift-off
in the verification (the objective's limits on ``tire_liftoff_share_XX`` and
``tire_contact_min_XX`` are held there; IPOPT's loop has no lift-off).

With third elements (issue 38): the car's heave and roll dampers and heave springs in
IPOPT's loop and every verification; free third dampers (``CurveOptions.free_third``) as
curve groups after the corner curves' variables, heave packers among the packers.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy import optimize as sopt

from ident.data.channels import CORNERS
from ident.data.drive import Drive
from ident.data.third import HEAVE_ELEMENTS
from ident.models.bumpstops import BumpStop, check_packer
from ident.models.library import ShockLibrary
from ident.sim.closedloop import corner_values, simulate
from ident.sim.metrics import METRIC_NAMES, THIRD_METRIC_NAMES
from planner.elements import model_setup_elements
from planner.options import ElementOptions, LoopOptions, as_options
from planner.errors import PlannerError
from planner.objective import Objective, default_objective, score_setups
from planner.optimize.cache import jit_available
from planner.optimize.click_search import ClickResult, curve_distance, search_clicks
from planner.optimize.constraints import (
    ENVELOPE_FACTOR,
    MAX_FORCE_VELOCITY_M_S,
    MIN_SLOPE_RATIO,
    CurveConstraints,
    check_constraints,
    constraint_envelope,
    constraint_rows,
    default_constraints,
)
from planner.optimize.knots import (
    QUANTILE_KNOTS,
    shock_speeds,
    velocity_knots,
    velocity_range,
)
from planner.optimize.loop import LoopModel
from planner.optimize.options import CurveOptions, SolverOptions
from planner.optimize.scan import (
    ScanOptions,
    element_predictions,
    is_element_metric,
    linear_objective,
    scan_curves,
    time_domain_scores,
)
from planner.optimize.solve import Evaluator, OptimizeWarning, solve_problem
from planner.optimize.third import check_free_third, crate_choices, optimize_third
from planner.optimize.space import CurveSpace, curve_space, symmetry_groups
from planner.plant import as_loop_plant
from planner.predict import predict_setups, prepare_drive
from planner.screen import metric_rows, screen_setups
from planner.setups import Setup, enumerate_setups, resolve_baseline
from planner.uncertainty import prediction_uncertainty

__all__ = [
    "KNOT_UPDATE_RTOL",
    "THIRD_ENVELOPE",
    "MULTI_START_ITER",
    "PACKER_SCALE_M",
    "CurveOptimum",
    "optimize_curves",
    "compile_curves",
    "curve_distance",
    "score_rows",
]


#: The knots on the quantiles move onto the scan's best curve's shock speeds when one of them,
#: or the velocity range, moves by more than this relative amount (a knot a tenth off its
#: quantile still splits the samples about as intended).
KNOT_UPDATE_RTOL = 0.1
#: IPOPT iterations of each further start (``n_starts > 1``): the first start has
#: ``max_iter``; a further one refines a different shape (about 0.5 s an iteration on a 120 s
#: drive), so the call stays within 1.5 times a single start's time (bench_optimize).
MULTI_START_ITER = 10
#: Scale of a packer decision variable [m] in IPOPT (1 mm: the curves' variables are scaled
#: to order 1 as well).
PACKER_SCALE_M = 1e-3


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
        ``status``, ``success`` (converged or acceptable), ``converged`` (IPOPT's
        tolerance met), ``acceptable`` (stopped at IPOPT's acceptable level: an
        :class:`OptimizeWarning` gives ``reason``), ``source`` (``"ipopt"``,
        ``"iterate"`` or ``"scan"``: which verified candidate is the optimum),
        ``candidates`` (their verified scores), ``iterations``, ``n_eval`` (forward sweeps),
        ``build_s`` (the loop built and compiled), ``solve_s``, ``eval_s``, ``grad_s``,
        ``n_grad`` (adjoint sweeps), ``jit``,
        ``objective`` (the optimizer's own), ``verified_score``.
    space : CurveSpace
    constraints : CurveConstraints
    objective : planner.objective.Objective
    baseline : planner.setups.Setup
    packers_m : dict of str -> float
        The chosen packer [m] per group given in ``packers`` (empty without).
    bump_stops : tuple or None
        The optimum's bump stops in the loop's form (the car's, shortened by the chosen
        packers), as its verification simulated them; None without stops.
    settings : dict
        The call's settings and what the run decided: ``knots_m_s`` and
        ``rebound_knots_m_s`` (the knots used [m/s]), ``v_range_m_s`` (the
        baseline's 99 % shock speeds, rebound and bump), ``scan``
        (:meth:`ScanResult.summary`), ``envelope_n`` (``lo`` and ``hi``, the
        least and greatest force [N] the constraints allow at each group's
        knots, :func:`~planner.optimize.constraints.constraint_envelope`), and with
        the car's elements ``bump_stops`` (True), ``packers`` (the bounds [m] per group)
        and ``static_corner_load_n`` [N] ...
    clicks : planner.optimize.click_search.ClickResult or None
        With adjustable shocks in the crate: each one's best settings per corner group
        (a neighbourhood search from the settings nearest the optimum's curves, verified
        in the time domain, :func:`planner.optimize.click_search.search_clicks`), the gain over
        the crate's best fixed setup and the gap to the optimum; their setups are rows of
        `table` of kind ``"clicks"``. None without adjustables (or ``click_radius=None``).
    third_curves : dict of str -> PiecewiseLinear
        The optimal curve of every free third damper (``CurveOptions.free_third``, in the
        element's own velocity and force; its shock ``OPT-<element>`` in `shocks`, named by
        the optimum's ``third``); empty without.
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
    packers_m: dict = field(default_factory=dict)
    bump_stops: tuple | None = None
    clicks: ClickResult | None = None
    third_curves: dict = field(default_factory=dict)

    @property
    def score(self):
        """float: the optimum's verified (time-domain) score."""
        return float(self.table.loc["optimum", "score"])

    def verdict(self):
        """One sentence: how the optimum compares with the crate's best (time domain), and
        whether IPOPT converged."""
        best = float(self.table.loc[self.crate_best, "score"])
        note = ""
        if self.solver.get("acceptable"):
            note = " (IPOPT stopped at an acceptable level, not converged)"
        if self.gap >= 0:
            return (f"the optimum ({self.score:.4f}) is {100 * self.gap:.2f} % better than the "
                    f"crate's best {self.crate_best} ({best:.4f}){note}")
        return (f"the crate's best {self.crate_best} ({best:.4f}) beats the optimum "
                f"({self.score:.4f}) by {-100 * self.gap:.2f} %: the constraints keep the "
                f"curves from what the crate already does; relax them{note}")


@dataclass(frozen=True, eq=False)
class _Elements:
    """The car's elements of an optimization (checked): its stops in the loop's form, the
    packer variables (groups, bounds [m], per corner the variable's index), the static
    loads and the third elements (:class:`OptimizeThird`, the baseline's, every verification's).
    Inactive (all None): the optimization without elements, unchanged."""

    stops: list | None = None
    groups: tuple = ()
    bounds: tuple = ()
    index: list | None = None
    static: list | None = None
    third: OptimizeThird | None = None
    # free third dampers (issue 38): their curve space (groups without corners, the corner
    # curves' knots), start and linear constraints; their variables come after the corner
    # curves', before the packers
    third_space: CurveSpace | None = None
    third_start: np.ndarray | None = None
    third_A: np.ndarray | None = None
    third_b: np.ndarray | None = None
    # per heave spring of the car's entry, the index of its packer variable (or None)
    third_index: list | None = None

    @property
    def active(self):
        return self.stops is not None or self.static is not None or self.third is not None

    @property
    def loop_third(self):
        """The loop's ``(dampers, springs)`` of the car's third elements, or None."""
        return None if self.third is None else self.third.entry

    @property
    def free_third(self):
        """tuple of str: the third dampers whose curves are free."""
        return () if self.third_space is None else tuple(n for n, _ in self.third_space.groups)

    @property
    def n_third(self):
        """int: the free third dampers' decision variables."""
        return 0 if self.third_space is None else self.third_space.n_vars

    @property
    def n_packers(self):
        return len(self.groups)

    @property
    def start(self):
        """The packers' start: the stops as given (0) where the bounds allow, [m]."""
        return np.array([min(max(0.0, lo), hi) for lo, hi in self.bounds])

    def stops_at(self, p):
        """The stops with the tail `p` (free third dampers' variables, then packers [m]) in
        the loop's form."""
        if self.stops is None or not self.n_packers:
            return self.stops
        p = np.asarray(p, dtype=float)[self.n_third:]
        return [None if st is None else
                (st[0] - (float(p[self.index[c]]) if self.index[c] is not None else 0.0),
                 st[1], st[2]) for c, st in enumerate(self.stops)]

    def rows(self, A, b):
        """The linear constraints `A`, `b` of the curves with the free third dampers' and
        the packers' bounds."""
        if self.n_third:
            A = np.block([[A, np.zeros((A.shape[0], self.n_third))],
                          [np.zeros((self.third_A.shape[0], A.shape[1])), self.third_A]])
            b = np.concatenate([b, self.third_b])
        k = self.n_packers
        if not k:
            return A, b
        lo = np.array([a for a, _ in self.bounds])
        hi = np.array([h for _, h in self.bounds])
        A2 = np.block([[A, np.zeros((A.shape[0], k))],
                       [np.zeros((k, A.shape[1])), np.eye(k)],
                       [np.zeros((k, A.shape[1])), -np.eye(k)]])
        return A2, np.concatenate([b, hi, -lo])

    def extend(self, x):
        """A curve vector with the free third dampers' start (the baseline's curves) and the
        packers' start appended."""
        if self.n_third:
            x = np.concatenate([x, self.third_start])
        return np.concatenate([x, self.start]) if self.n_packers else x

    def clip(self, p):
        """The tail `p` made valid: the free third curves' (:meth:`CurveSpace.valid`), the
        packers within their bounds."""
        p = np.asarray(p, dtype=float)
        head = self.third_space.valid(p[:self.n_third]) if self.n_third else p[:0]
        return np.concatenate([head, [min(max(float(v), lo), hi) for v, (lo, hi)
                                      in zip(p[self.n_third:], self.bounds)]])

    def third_shocks(self, p):
        """The free third dampers' shocks of tail `p` (ids ``OPT-<element>``), or None."""
        if not self.n_third:
            return None
        return self.third_space.shocks(np.asarray(p, dtype=float)[:self.n_third])

    @property
    def own_third(self):
        """bool: the optimum's third elements differ from the baseline's (free dampers or
        heave packers)."""
        return bool(self.n_third) or any(k is not None for k in self.third_index or ())

    def third_at(self, p):
        """The loop's ``(dampers, springs)`` with the free third dampers' curves and the
        heave packers of tail `p`; the car's baseline entry without them."""
        if not self.own_third:
            return self.loop_third
        dampers, springs = self.third.entry
        if self.n_third:
            shocks = self.third_shocks(p)
            models = {e: shocks[f"OPT-{e}"] for e in self.free_third}
            dampers = tuple(replace(d, model=models[d.name]) if d.name in models else d
                            for d in dampers)
        pk = np.asarray(p, dtype=float)[self.n_third:]
        springs = tuple(sp if k is None else replace(sp, contact=(
            sp.contact[0] - float(pk[k]), sp.contact[1], sp.contact[2]))
            for sp, k in zip(springs, self.third_index or [None] * len(springs)))
        return dampers, springs

    def setup_with_third(self, setup, p):
        """`setup` naming the free third dampers' shocks (its ``third`` column)."""
        if not self.n_third:
            return setup
        return Setup(setup.name, setup.shocks, third={e: f"OPT-{e}" for e in self.free_third})

    def loop_args(self):
        """:class:`LoopModel`'s element arguments."""
        return {"bump_stops": self.stops, "packer_index": self.index,
                "third": self.loop_third, "free_third": self.free_third,
                "third_packer_index": self.third_index}

    def verify(self, p, names):
        """``time_domain_scores``' element arguments: setups `names` with the tail `p` (free
        third dampers' curves, packers), the others with the car's stops and baseline."""
        if not self.active:
            return {}
        own = None if self.stops is None else {n: self.stops_at(p) for n in names}
        out = {"bump_stops": self.stops, "setup_stops": own,
               "static_corner_load_n": self.static, "third": self.loop_third}
        if self.own_third:
            entry = self.third_at(p)
            out["setup_third"] = {n: entry for n in names}
        return out


#: The free third dampers' curves (issue 38): passive, increasing, digressive, no segment in
#: the velocity range flatter than :data:`planner.optimize.constraints.MIN_SLOPE_RATIO` times
#: its side's first (the corner defaults' shape), their forces at the knots in the velocity
#: range within these factors of the baseline damper's (the crate envelope's factors,
#: :data:`planner.optimize.constraints.ENVELOPE_FACTOR`, around the one damper the car fits
#: there), and at most the upper factor times its largest force at 1 m/s everywhere (the
#: corner defaults' slopes and force cap are a corner shock's, not a heave damper's).
THIRD_ENVELOPE = ENVELOPE_FACTOR


def _values(shocks):
    return [] if shocks is None else list(shocks.values())


def _with_free_third(elements, space, free):
    """`elements` with the free third dampers' curve space (the corner curves' knots and
    velocity range), start (the baseline dampers' curves) and constraints
    (:data:`THIRD_ENVELOPE`)."""
    dampers = {d.name: d.model for d in elements.third.entry[0]}
    tspace = CurveSpace(groups=tuple((e, ()) for e in free), v_knots_m_s=space.v_knots_m_s,
                        linear=space.linear,
                        lag_s=tuple(float(getattr(dampers[e], "lag_s", 0.0) or 0.0)
                                    for e in free),
                        symmetry=space.symmetry, v_range_m_s=space.v_range_m_s)
    start = tspace.from_curves([dampers[e].to_pwl() for e in free])
    blocks, bs = [], []
    for e in free:
        one = CurveSpace(groups=((e, ()),), v_knots_m_s=space.v_knots_m_s, linear=space.linear,
                         lag_s=(0.0,), symmetry=space.symmetry, v_range_m_s=space.v_range_m_s)
        own = ShockLibrary([dampers[e]])
        f1 = np.abs(np.asarray(dampers[e].to_pwl().force(
            np.array([-MAX_FORCE_VELOCITY_M_S, MAX_FORCE_VELOCITY_M_S])), dtype=float))
        cons = CurveConstraints(envelope_factor=THIRD_ENVELOPE, digressive=True,
                                min_slope_ratio=MIN_SLOPE_RATIO,
                                max_force_n=float(THIRD_ENVELOPE[1] * max(f1.max(), 1.0)))
        A, b = _linear_rows(one, cons, own)
        blocks.append(A)
        bs.append(b)
    nv = tspace.n_group_vars
    A3 = np.zeros((sum(a.shape[0] for a in blocks), nv * len(free)))
    r = 0
    for k, a in enumerate(blocks):
        A3[r:r + a.shape[0], k * nv:(k + 1) * nv] = a
        r += a.shape[0]
    return replace(elements, third_space=tspace, third_start=start, third_A=A3,
                   third_b=np.concatenate(bs))


def _elements(plant, space, bump_stops, packers, static_corner_load_n, objective, third=None):
    """The checked elements of :func:`optimize_curves` (:class:`_Elements`)."""
    where = "optimize"
    if third is not None and static_corner_load_n is not None:
        raise PlannerError(f"{where}: tire lift-off (static_corner_load_n) is not simulated "
                           f"together with third elements ({', '.join(third.names)}); leave "
                           "static_corner_load_n out (ElementOptions, or the CarElements "
                           "given as ElementOptions.use_model) for a car with third elements")
    stops = None
    if bump_stops is not None:
        vals = corner_values(bump_stops, f"{where}: stop_tables", "bump stops")
        stops = []
        for c, st in zip(CORNERS, vals):
            if st is None:
                stops.append(None)
                continue
            try:
                s0, x, f = st
            except (TypeError, ValueError):
                raise TypeError(f"{where}: stop_tables at {c}: a stop is (contact_travel_m, "
                                f"travel_table_m, force_table_n) or None, got "
                                f"{type(st).__name__}") from None
            # the stop checks itself (a table that falls, a negative gap: BumpStopError)
            stop = BumpStop(c, float(s0), x, f)
            stops.append((stop.gap_m, stop.travel_m, stop.force_n))
        if all(st is None for st in stops):
            stops = None
        else:
            names = [f"shock_travel_{c}" for c in CORNERS]
            missing = [n for n in names if n not in plant.output_names]
            if missing:
                raise PlannerError(f"{where}: bump_stops need the model's outputs {missing}; "
                                   f"model {plant.name!r} has none of them: identify it with "
                                   "the shock travel channels, or leave bump_stops out")
    groups, bounds, index = [], [], None
    packers = dict(packers or {})
    heave = {k: packers.pop(k) for k in list(packers) if k in HEAVE_ELEMENTS}
    if packers:
        if stops is None:
            raise PlannerError(f"{where}: packers {dict(packers)} given without bump stops; "
                               "give stop_tables (the car's stops), or leave packers out")
        known = {name: corners for name, corners in space.groups}
        index = [None] * 4
        for name, bound in dict(packers).items():
            if name not in known:
                raise PlannerError(f"{where}: packers: unknown group {name!r}; with symmetry "
                                   f"{space.symmetry!r} the groups are {list(known)}")
            lo, hi = _packer_bounds(name, bound, where)
            for c in known[name]:
                k = CORNERS.index(c)
                if stops[k] is None:
                    raise PlannerError(f"{where}: packers[{name!r}]: corner {c} has no bump "
                                       "stop; give its stop in stop_tables, or leave the "
                                       "group's packers out")
                stop = BumpStop(c, stops[k][0], stops[k][1], stops[k][2])
                for v in (lo, hi):  # a packer thicker than the gap is refused here
                    check_packer(stop, v, f"{where}: packers[{name!r}] at {c}",
                                 error=PlannerError)
                index[k] = len(groups)
            groups.append(name)
            bounds.append((lo, hi))
    third_index = None
    if heave:
        third_index = _heave_packers(heave, third, groups, bounds, where)
    static = None
    if static_corner_load_n is not None:
        vals = corner_values(static_corner_load_n, f"{where}: static_corner_load_n",
                             "static_corner_load_n")
        static = [None if v is None else float(v) for v in vals]
    need_static = [m for m in objective.limits if is_element_metric(m)
                   and not m.startswith("bump_stop") and static is None]
    need_stops = [m for m in objective.limits if m.startswith("bump_stop_contact")
                  and stops is None]
    if need_static or need_stops:
        raise PlannerError(f"{where}: objective {objective.name!r} limits "
                           f"{need_static + need_stops}, which only a loop with the car's "
                           "elements gives; give static_corner_load_n (lift-off, contact) "
                           "or stop_tables (contact share)")
    return _Elements(stops=stops, groups=tuple(groups), bounds=tuple(bounds), index=index,
                     static=static, third=third, third_index=third_index)


def _packer_bounds(name, bound, where):
    try:
        lo, hi = (float(v) for v in bound)
    except (TypeError, ValueError):
        raise PlannerError(f"{where}: packers[{name!r}] = {bound!r}; give the bounds "
                           "(min_m, max_m), e.g. (0.0, 0.006)") from None
    if not lo <= hi:
        raise PlannerError(f"{where}: packers[{name!r}]: the lower bound {lo!r} m is above the "
                           f"upper {hi!r} m")
    return lo, hi


def _heave_packers(heave, third, groups, bounds, where):
    """The heave springs' packer variables (``packers["heave_front"]``, ...): appended to
    `groups` and `bounds`; returns per heave spring of the car's entry its variable's index
    (or None)."""
    springs = () if third is None else third.entry[1]
    fitted = {sp.name: sp for sp in springs if sp.contact is not None}
    index = [None] * len(springs)
    for name, bound in heave.items():
        if name not in fitted:
            raise PlannerError(f"{where}: packers[{name!r}]: the car's baseline fits no heave "
                               f"spring there (it fits {sorted(fitted) or 'none'}); give the "
                               "car's heave springs (model.third, ElementOptions.third), or "
                               "leave that packer out")
        lo, hi = _packer_bounds(name, bound, where)
        gap = float(fitted[name].contact[0])
        if lo < 0 or hi > gap:
            raise PlannerError(f"{where}: packers[{name!r}] = ({lo:g}, {hi:g}) m: a heave "
                               f"packer is 0 .. the spring's gap left ({gap:g} m, the baseline's "
                               "packer in); narrow the bounds")
        index[[sp.name for sp in springs].index(name)] = len(groups)
        groups.append(name)
        bounds.append((lo, hi))
    return index


def _check_objective(objective):
    objective = default_objective() if objective is None else objective
    if not isinstance(objective, Objective):
        raise TypeError(f"objective must be a planner.objective.Objective, got "
                        f"{type(objective).__name__}")
    # element statistics (lift-off, contact) and third elements' motions as limits only: held
    # in the verification
    other = [m for m in objective.metrics if m not in METRIC_NAMES
             and not ((is_element_metric(m) or m in THIRD_METRIC_NAMES)
                      and m not in objective.weights)]
    if other:
        raise PlannerError(f"objective {objective.name!r}: optimize works on the spec's metrics "
                           f"{list(METRIC_NAMES)}; {other} are not among them (normalized and "
                           "band-split metrics are for ranking; element statistics and third "
                           "elements' motions only as limits)")
    return objective


def _drive_list(drives, fs_hz):
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


def optimize_curves(model, drives, library, *, objective=None, baseline=None,
                    curves=CurveOptions(), constraints=None, drive_weights=None,
                    aggregate="sum", robust=False, loop=LoopOptions(), solver=SolverOptions(),
                    elements=ElementOptions(), stop_tables=None, packers=None, progress=False):
    """The best force-velocity curve per corner group (see the module docstring).

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
        Identified or known; both go through the same loop.
    drives : ident.data.drive.Drive or sequence of Drive
    library : ident.models.library.ShockLibrary
        The crate: the baseline and the setups the optimum is mapped to.
    objective : planner.objective.Objective, optional
        Default :func:`planner.objective.default_objective`; the spec's
        metrics only.
    baseline : Setup, str or sequence of 4 str, optional
        The setup the objective normalizes against, read by
        :func:`planner.setups.resolve_baseline`: a Setup, a shock id (every
        corner) or four ids ``"LF,RF,LR,RR"``; default the crate's first shock
        at every corner.
    curves : planner.optimize.options.CurveOptions
        The curves: ``symmetry`` (corner groups,
        :func:`~planner.optimize.space.curve_space`), ``knots_m_s`` (``"quantiles"``,
        the default, or bump knot velocities [m/s]; the knots used are in
        ``settings["knots_m_s"]`` and ``settings["rebound_knots_m_s"]``, the velocity
        range of the constraints, the baseline's 99 % speeds, in
        ``settings["v_range_m_s"]``), ``linear`` (one damping rate per group: the
        known-answer case), ``lag_s`` (the optimal shocks' lag [s]; default per group the
        mean lag of the baseline's shocks at its corners), ``free_third`` (a car with third
        elements: the third dampers whose curves are optimized too, e.g.
        ``("heave_front", "heave_rear")``: a curve each on the corner curves' knots in the
        element's own velocity and force, the baseline damper's lag, bounded by
        :data:`THIRD_ENVELOPE`; ``OPT-<element>`` in the result's shocks, named by the
        optimum's ``third``, :attr:`CurveOptimum.third_curves`).
    constraints : CurveConstraints, optional
        Default :func:`default_constraints`.
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
    loop : planner.options.LoopOptions
        ``oversample``: sub-steps per sample in the optimizer's loop and in the
        verification (the verification's loop otherwise as :func:`predict_setups`).
    solver : planner.optimize.options.SolverOptions
        ``max_iter`` (IPOPT iterations of the first start), ``n_starts`` (the scan's best
        verified curve, then the best verified curve of the other kind, linear or
        two-slope, with :data:`MULTI_START_ITER` iterations; every start's result is
        verified), ``jit`` (compile the loop to C; default when a C compiler is found),
        ``stationarity`` (report the effect of moving each knot force by +-5 %, time
        domain), ``n_closest`` (crate setups nearest the optimum to simulate and report),
        ``click_radius`` (with adjustable shocks in the crate: the click search's moves,
        +-1..``click_radius`` steps of one adjuster, ``clicks`` of the result,
        :func:`planner.optimize.click_search.search_clicks`; None: no click search).
    elements : planner.options.ElementOptions
        The car's elements when `stop_tables` and ``elements.static_corner_load_n`` are
        not given: the model's own (``use_model=True``, an identified model of a session
        that declared them, ``model.elements``: the baseline's stops and packers, the
        static loads, :func:`planner.elements.model_setup_elements`; ``bump_stops`` a
        library replacing the model's); ``use_model=False``: the car without them.
        ``static_corner_load_n`` (shape (4,) [N]): the verification simulates tire
        lift-off, and the objective may limit ``tire_liftoff_share_XX`` and
        ``tire_contact_min_XX`` (the verification holds such limits; IPOPT's loop has no
        lift-off).
    stop_tables : sequence of 4 or mapping, optional
        The car's bump stops in the loop's form (per corner None or
        ``(contact_travel_m, travel_table_m, force_table_n)``,
        :func:`ident.models.bumpstops.contact_tables`), instead of the model's. The
        optimizer's loop adds each corner's stop force at the model's ``shock_travel_XX``
        (its kinks rounded, :data:`planner.optimize.loop.STOP_SMOOTHING_M`; solved with
        the shocks within the step), and every verification simulates with them; the
        screening of the scan sees the car without them. Default: the model's (see
        `elements`), else none (the loop unchanged).
    packers : mapping of str -> (float, float), optional
        Packers as decision variables: per corner group (``space.groups`` of the
        symmetry, e.g. ``{"front": (0.0, 0.006), "rear": (0.0, 0.006)}``) the bounds [m]
        of a packer that shortens the contact travel of the stops at the group's
        corners (``s0 - packer``). IPOPT starts from the stops as given (0, within the
        bounds); the chosen packers are ``packers_m`` of the result and the optimum is
        verified with them (the baseline and the crate with the stops as given). A car with
        heave springs: ``"heave_front"`` / ``"heave_rear"`` bound a packer added to the
        baseline's at that heave spring (0 .. the gap left), in IPOPT's loop and the
        optimum's verification alike.
    progress : bool

    Returns
    -------
    CurveOptimum

    Raises
    ------
    PlannerError
        On packers thicker than a stop's contact travel, for a group without stops or
        without bump stops, bump stops on a model without ``shock_travel_XX``;
        on constraints no curve meets (naming them), an objective with
        metrics other than the spec's, an unknown baseline shock, a bad
        symmetry, aggregate or weights; drive errors as :mod:`planner.predict`.
    TypeError
        If the objective is not an Objective.

    Warns
    -----
    OptimizeWarning
        If IPOPT does not converge; the best verified candidate is returned and
        ``solver["success"]`` is False. If it stops at its acceptable level
        (``solver["acceptable"]``), with the reason (``solver["reason"]``).
    """
    t_start = time.perf_counter()
    curves = as_options(curves, CurveOptions, "curves", "optimize")
    loop = as_options(loop, LoopOptions, "loop", "optimize")
    solver = as_options(solver, SolverOptions, "solver", "optimize")
    elements = as_options(elements, ElementOptions, "elements", "optimize")
    symmetry, knots_m_s, linear, lag_s = (curves.symmetry, curves.knots_m_s, curves.linear,
                                          curves.lag_s)
    oversample, max_iter, n_starts, jit = (loop.oversample, solver.max_iter, solver.n_starts,
                                           solver.jit)
    n_closest, stationarity, click_radius = (solver.n_closest, solver.stationarity,
                                             solver.click_radius)
    objective = _check_objective(objective)
    if aggregate not in ("sum", "worst"):
        raise PlannerError(f"aggregate must be 'sum' or 'worst', got {aggregate!r}")
    if click_radius is not None and not (isinstance(click_radius, int)
                                         and not isinstance(click_radius, bool)
                                         and click_radius >= 1):
        raise PlannerError(f"click_radius must be an integer >= 1 (clicks per move) or None, "
                           f"got {click_radius!r}")
    plant, drives, base, space, rows, third = _problem(model, drives, library, objective,
                                                       baseline, symmetry, knots_m_s, linear,
                                                       lag_s, oversample, elements=elements)
    need = rows[0]
    weights = _weights(drive_weights, drives)
    constraints = _check_constraints_arg(constraints)
    elements, free_third = _car_elements(model, library, plant, space, base, objective, third,
                                         elements, stop_tables, packers, curves.free_third,
                                         where="optimize")
    # the baseline's (verified) values per drive of the metrics the objective needs
    if elements.active:
        m_base = [element_predictions(model, d, [base], library, [elements.stops],
                                      oversample=oversample,
                                      static_corner_load_n=elements.static,
                                      third=elements.loop_third).loc[
            base.name, need].to_numpy(float) for d in drives]
    else:
        m_base = [predict_setups(model, d, [base], library,
                                 loop=LoopOptions(oversample=oversample),
                                 elements=ElementOptions(use_model=False)).table.loc[
            base.name, need].to_numpy(float) for d in drives]

    # the global stage (the knots moved once onto the scan's best curve's speeds)
    space, A_lin, b_lin, scan, x0, knot_log = _start(
        model, plant, drives, library, space, constraints, base, objective, weights, aggregate,
        oversample, _quantile_knots(knots_m_s), elements)
    if free_third:
        elements = _with_free_third(elements, space, free_third)

    # scaling of the decision variables: forces by c_bar |v|, slopes by c_bar
    cbar = float(np.mean(plant.cbar_n_s_m))
    if space.linear:
        scale = np.full(space.n_vars, cbar)
    else:
        vk = np.delete(space.v_knots_m_s, space.zero_index)
        per = np.concatenate([cbar * np.maximum(np.abs(vk), 0.05), [cbar, cbar]])
        scale = np.tile(per, len(space.groups))

    jit = jit_available() if jit is None else bool(jit)
    # the rows the problem needs of the metrics: a score per drive, each limit per drive
    tight = np.ones(len(need))
    if robust:
        tight = _robust_factors(model, drives, library, space, x0, base, need)
    C, kinds = score_rows(objective, need, m_base, tight)
    t_build = time.perf_counter()
    models_cl = [LoopModel(plant, d, space, rows, oversample, jit, **elements.loop_args())
                 for d in drives]
    T = space.expansion()
    A_opt, b_opt = elements.rows(A_lin, b_lin)
    if elements.n_third:  # the free third dampers' variables after the corner curves'
        T3 = elements.third_space.expansion()
        T = np.block([[T, np.zeros((T.shape[0], T3.shape[1]))],
                      [np.zeros((T3.shape[0], T.shape[1])), T3]])
        scale = np.concatenate([scale, np.tile(scale[:space.n_group_vars],
                                               len(elements.free_third))])
    if elements.n_packers:  # the packers after the curves' variables
        k = elements.n_packers
        T = np.block([[T, np.zeros((T.shape[0], k))], [np.zeros((k, T.shape[1])), np.eye(k)]])
        scale = np.concatenate([scale, np.full(k, PACKER_SCALE_M)])
    x0 = elements.extend(x0)
    ev = Evaluator(models_cl, T, scale, C)
    build_s = time.perf_counter() - t_build
    x_opt, solver, history = solve_problem(ev, space, kinds, weights, aggregate, A_opt,
                                           b_opt, x0 / scale, scale, max_iter, progress)
    # multi-start: from the best verified scan curve of the other kind (linear or two-slope),
    # a short solve; its result and best iterate join the verification
    extra, starts = [], [{"start": "scan best", "iterations": solver["iterations"],
                          "status": solver["status"], "objective": solver["objective"]}]
    others = _other_starts(scan, n_starts - 1)
    if others:
        history = history.assign(start=1)
    for label, xs in others:
        xs = elements.extend(xs)
        x_k, solver_k, hist_k = solve_problem(ev, space, kinds, weights, aggregate, A_opt,
                                              b_opt, xs / scale, scale,
                                              min(max_iter, MULTI_START_ITER), progress)
        extra.append((f"start {len(starts) + 1}", x_k))
        solver["iterates"] += solver_k.pop("iterates")
        starts.append({"start": label, "iterations": solver_k["iterations"],
                       "status": solver_k["status"], "objective": solver_k["objective"]})
        hist_k = hist_k.assign(start=len(starts))
        history.attrs, hist_k.attrs = {}, {}  # (the iterates, already taken)
        history = pd.concat([history, hist_k], ignore_index=True)
    solver["starts"] = starts
    solver.update(build_s=build_s, eval_s=ev.eval_s, grad_s=ev.grad_s, n_eval=ev.n_eval,
                  n_grad=ev.n_grad, jit=jit, step_instructions=models_cl[0].n_instructions)
    return _finish(model, plant, drives, library, space, constraints, objective, base, weights,
                   aggregate, oversample, x_opt, solver, history, n_closest, stationarity,
                   A_lin, b_lin, t_start, {"n_starts": len(starts), "knots_m_s": _bump_knots(space), "knot_update": knot_log,
                                           "rebound_knots_m_s": _bump_knots(space, -1),
                                           "v_range_m_s": list(space.v_range_m_s),
                                           "knots": ("quantiles" if _quantile_knots(knots_m_s)
                                                     else "fixed"),
                                           "robust": bool(robust), "max_iter": max_iter,
                                           "x_start": x0[:space.n_vars].tolist(),
                                           "limit_factors": tight.tolist(),
                                           "scan": None if scan is None else scan.summary()},
                   scan=scan, extra=extra, elements=elements, click_radius=click_radius)


def _other_starts(scan, n):
    """Up to `n` further IPOPT starts: the scan's best verified curves of a kind other than
    its best's (linear or two-slope), best first; (label, decision vector)."""
    if scan is None or n <= 0:
        return []
    kinds, feasible = list(scan.table["kind"]), list(scan.table["feasible"])
    out, seen = [], {kinds[0]}
    for k, ok, x in zip(kinds, feasible, scan.points):
        if k not in seen and ok and len(out) < n:
            out.append((f"scan's best {k}", x))
            seen.add(k)
    return out


def _weights(drive_weights, drives):
    """The drives' weights, summing to 1, checked."""
    if drive_weights is None:
        return np.full(len(drives), 1.0 / len(drives))
    weights = np.asarray(drive_weights, dtype=float).ravel()
    if weights.size != len(drives) or np.any(~np.isfinite(weights)) or np.any(weights < 0) \
            or not weights.sum() > 0:
        raise PlannerError(f"drive_weights {list(np.atleast_1d(drive_weights))} must be "
                           f"{len(drives)} numbers >= 0, not all 0")
    return weights / weights.sum()


def _check_constraints_arg(constraints):
    constraints = default_constraints() if constraints is None else constraints
    if not isinstance(constraints, CurveConstraints):
        raise TypeError(f"constraints must be CurveConstraints (read_curve_constraints), got "
                        f"{type(constraints).__name__}")
    return constraints


def _linear_rows(space, constraints, library):
    """The curve constraints on the decision variables, ``A x <= b``, checked."""
    check_constraints(space, constraints, library)
    families = constraint_rows(space, constraints, library)
    T = space.expansion()
    return (np.vstack([a for _, a, _ in families]) @ T,
            np.concatenate([b for _, _, b in families]))


def _start(model, plant, drives, library, space, constraints, base, objective, weights,
           aggregate, oversample, quantile_knots, elements=_Elements()):
    """The global stage: IPOPT's curve space, constraints, scan and start.

    The scan (:func:`planner.optimize.scan.scan_curves`) screens linear and
    two-slope curves per group and verifies the best; the best is IPOPT's
    start and a floor under its result. With knots on the quantiles, they were
    placed on the baseline's shock speeds; they are moved once onto the speeds
    of the scan's best curve (the curve the optimum starts from) when a knot or
    the velocity range moves by more than :data:`KNOT_UPDATE_RTOL`, and the
    scan is run again on the new knots; the better verified scan is kept with
    its space. No candidate meeting the constraints: the best screened
    uniform rate, projected onto them.

    Returns
    -------
    space, A_lin, b_lin, scan, x0, knot_log
    """
    A_lin, b_lin = _linear_rows(space, constraints, library)
    # the scan's candidates verified with the packers' start (the stops as given)
    el = {} if not elements.active else {"elements": {
        "bump_stops": elements.stops_at(elements.start),
        "static_corner_load_n": elements.static, "third": elements.loop_third}}
    scan = scan_curves(model, plant, drives, library, space, constraints, A_lin, b_lin, base,
                       objective, weights, aggregate, oversample=oversample, **el)
    log = {"baseline_knots_m_s": _bump_knots(space),
           "baseline_rebound_knots_m_s": _bump_knots(space, -1),
           "baseline_v_range_m_s": list(space.v_range_m_s), "moved": 0.0, "updated": False}
    if scan is not None and quantile_knots and not space.linear:
        shocks = space.shocks(scan.x, prefix="SCANBEST")
        lib = ShockLibrary(list(shocks.values()) + list(library.values()))
        speeds = shock_speeds(plant, drives, space.setup(shocks), lib, oversample=oversample,
                              third=elements.loop_third)
        bump, reb = velocity_knots(speeds)
        rng = velocity_range(speeds)
        old = np.concatenate([_bump_knots(space), _bump_knots(space, -1), space.v_range_m_s])
        new = np.concatenate([bump, reb, rng])
        log["moved"] = float(np.max(np.abs(new / old - 1.0))) if new.size == old.size else 1.0
        if log["moved"] > KNOT_UPDATE_RTOL:
            space1 = curve_space(symmetry=space.symmetry, knots_m_s=bump, rebound_knots_m_s=reb,
                                 linear=False, lag_s=space.lag_s, v_range_m_s=rng)
            try:
                A1, b1 = _linear_rows(space1, constraints, library)
            except PlannerError:
                A1 = None  # the new knots conflict with the constraints: keep the first
            scan1 = None if A1 is None else scan_curves(
                model, plant, drives, library, space1, constraints, A1, b1, base, objective,
                weights, aggregate, oversample=oversample, **el)
            if scan1 is not None and (scan1.feasible, -scan1.score) >= (scan.feasible,
                                                                        -scan.score):
                space, A_lin, b_lin, scan = space1, A1, b1, scan1
                log["updated"] = True
    if scan is not None:
        return space, A_lin, b_lin, scan, scan.x, log
    free = np.zeros((0, space.n_vars)), np.zeros(0)
    scan_any = scan_curves(model, plant, drives, library, space, constraints, *free, base,
                           objective, weights, aggregate,
                           scan=ScanOptions(n_verify=1, two_slope=False),
                           oversample=oversample, **el)
    return space, A_lin, b_lin, None, _project(scan_any.x, A_lin, b_lin), log


def _quantile_knots(knots_m_s):
    return isinstance(knots_m_s, str) and knots_m_s == QUANTILE_KNOTS


def _bump_knots(space, side=1):
    v = side * space.v_knots_m_s
    return sorted(float(x) for x in v[v > 0])


def _problem(model, drives, library, objective, baseline, symmetry, knots_m_s, linear, lag_s,
             oversample=2, elements=None):
    """The loop plant, drives, baseline setup, curve space, metric rows (names, rows of
    the plant's outputs) and the car's third elements (:class:`OptimizeThird` or None, with
    `elements`) of an optimization, checked (see :func:`optimize_curves`)."""
    plant = as_loop_plant(model)
    drives = _drive_list(drives, getattr(model, "fs_hz", None))
    # the commands' one baseline syntax; none given: the crate's first shock at every corner
    base = resolve_baseline(library.ids[0] if baseline is None else baseline, library)
    base_models = base.resolve(library)
    third = None if elements is None else optimize_third(model, base, library, elements)
    groups = symmetry_groups(symmetry)
    if lag_s is None:
        lag_s = [float(np.mean([base_models[CORNERS.index(c)].lag_s for c in corners]))
                 for _, corners in groups]
    if isinstance(knots_m_s, str) and not _quantile_knots(knots_m_s):
        raise PlannerError(f"knots_m_s must be velocities [m/s] or {QUANTILE_KNOTS!r} (on "
                           f"the baseline's shock speeds), got {knots_m_s!r}")
    # the baseline's shock speeds: the velocity range the buildable constraints hold in, and
    # the knots on their quantiles
    speeds = shock_speeds(plant, drives, base, library, oversample=oversample,
                          third=None if third is None else third.entry)
    rebound_knots = None
    if _quantile_knots(knots_m_s):
        knots_m_s, rebound_knots = velocity_knots(speeds)
    space = curve_space(symmetry=symmetry, knots_m_s=knots_m_s, rebound_knots_m_s=rebound_knots,
                        linear=linear, lag_s=lag_s, v_range_m_s=velocity_range(speeds))
    names_all, L_all = metric_rows(plant)
    if third is not None:  # the limited motions of the car's third elements: rows too
        names_all, L_all = _third_metric_rows(plant, third, objective, names_all, L_all)
    need = [m for m in objective.metrics if m in names_all]
    missing = [m for m in objective.metrics if m not in names_all and not is_element_metric(m)
               and m not in THIRD_METRIC_NAMES]
    declared = () if third is None else third.names
    undeclared = [m for m in objective.limits if m in THIRD_METRIC_NAMES
                  and f"{m.split('_')[0]}_{m.rpartition('_')[2]}" not in declared]
    if undeclared:
        raise PlannerError(f"optimize: objective {objective.name!r} limits {undeclared}, the "
                           f"motion of third elements the car does not declare (it has "
                           f"{list(declared)}); drop the limits from the objective file, or "
                           "give the car's third elements (model.third, ElementOptions.third)")
    if missing:
        raise PlannerError(f"the model has no outputs for {missing}; its outputs are "
                           f"{list(plant.output_names)}")
    return plant, drives, base, space, (need, L_all[[names_all.index(m) for m in need]]), third


def _third_metric_rows(plant, third, objective, names, L):
    """`names`, `L` with a row per limited motion of a declared third element
    (``heave_travel_rms_front`` ...: the element's row over the plant's ``shock_travel_XX`` or
    ``shock_velocity_XX``, as the time domain forms its channel), so IPOPT's loop holds the
    limit too; unchanged without such limits or without those outputs."""
    names, rows = list(names), [L]
    outs = list(plant.output_names)
    for m in objective.limits:
        if m not in THIRD_METRIC_NAMES:
            continue
        kind, what, _, axle = m.split("_")
        element = f"{kind}_{axle}"
        chans = [f"shock_{what}_{c}" for c in CORNERS]
        if element not in third.names or not all(c in outs for c in chans):
            continue
        row = np.zeros((1, len(outs)))
        row[0, [outs.index(c) for c in chans]] = third.car.elements.row(element)
        names.append(m)
        rows.append(row)
    return names, np.vstack(rows)


def _car_elements(model, library, plant, space, base, objective, third, elements,
                  stop_tables, packers, free_third, *, where):
    """The car's elements of an optimization as its loop holds them (:class:`_Elements`) and
    its free third dampers, checked: the stops and static loads (the model's own unless
    given), the third elements with the crate's third-element choices, the refusals
    (`where` names the caller in them)."""
    stops, static = stop_tables, elements.static_corner_load_n
    if elements.use_model is not False and stops is None and static is None:
        own = model_setup_elements([base], model, elements, where=where)
        if own is not None:
            stops, static = own.tables[0], own.static_corner_load_n
    free = check_free_third(free_third, third)
    if elements.vary_bump_stops or elements.vary_packers_m:
        raise PlannerError(f"{where}: bump-stop and packer choices (vary_bump_stops, "
                           "vary_packers_m) are not searched; free the packers instead "
                           "(packers=..., --packers GROUP=LO:HI), or rank the choices "
                           "(shockplan rank --try-bump-stops / --try-packers)")
    choices = crate_choices(third, library, elements.vary_third, free)
    if choices:
        third = replace(third, choices=choices)
    return _elements(plant, space, stops, packers, static, objective, third), free


def compile_curves(model, drives, library, *, objective=None, baseline=None,
                   curves=CurveOptions(), constraints=None, drive_weights=None,
                   aggregate="sum", loop=LoopOptions(), elements=ElementOptions(),
                   stop_tables=None, packers=None):
    """Compile the optimizer's step functions of a problem ahead of :func:`optimize_curves`.

    The C compile of the closed loop's step and its adjoint (10-30 s on a
    fresh machine; nothing once cached) is what a first optimization waits
    for. Called with the same arguments as :func:`optimize_curves` (these
    are the ones the compiled code depends on; the drive matters by its
    sample rate and, with ``knots_m_s="quantiles"``, by the baseline's shock
    speeds on it), e.g. in a worker while other work runs, it leaves the
    library in :func:`jit_cache_dir`, where the optimization then finds it.
    With knots on the quantiles (the default) it runs the optimization's global
    stage as :func:`optimize_curves` does (the scan, and the knots moved onto
    its best curve's speeds, ``settings["knot_update"]``) and compiles the
    problem on the knots the optimization will use; that stage screens
    (numba's OpenMP pool), so run it in a spawned process, not one forked from
    a process that used the pool. With given knots it compiles at once and
    runs no screening.

    Parameters
    ----------
    model, drives, library, objective, baseline, curves, constraints, drive_weights
        As :func:`optimize_curves` (``curves.free_third``: the free third dampers' curve
        groups are compiled in).
    aggregate, loop
        As :func:`optimize_curves`.
    elements : planner.options.ElementOptions
        As :func:`optimize_curves`: the car's elements (the model's own by default); a car
        with third elements has them compiled in (its heave and roll dampers and heave
        springs, the baseline's, as the optimization's loop holds them; the knots on the
        baseline's shock speeds with them).
    stop_tables, packers
        As :func:`optimize_curves` (the stops and packer variables, the heave packers'
        too, are compiled in; without `stop_tables` the model's stops, as `elements` says).

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
    curves = as_options(curves, CurveOptions, "curves", "compile_curves")
    oversample = as_options(loop, LoopOptions, "loop", "compile_curves").oversample
    elements = as_options(elements, ElementOptions, "elements", "compile_curves")
    if aggregate not in ("sum", "worst"):
        raise PlannerError(f"aggregate must be 'sum' or 'worst', got {aggregate!r}")
    # the problem as optimize_curves builds it (keep the two in step: the compiled code's
    # hash must be the optimization's); the car's elements as optimize_curves takes them
    # (its refusals too); the static loads only to refuse what it refuses (IPOPT's loop
    # has no lift-off)
    plant, drives, base, space, rows, third = _problem(
        model, drives, library, objective, baseline, curves.symmetry, curves.knots_m_s,
        curves.linear, curves.lag_s, oversample, elements=elements)
    elements, free_third = _car_elements(model, library, plant, space, base, objective, third,
                                         elements, stop_tables, packers, curves.free_third,
                                         where="compile_curves")
    if not jit_available():
        return False
    if _quantile_knots(curves.knots_m_s) and not space.linear:
        # the knots the optimization compiles on come out of its global stage
        space = _start(model, plant, drives, library, space,
                       _check_constraints_arg(constraints), base, objective,
                       _weights(drive_weights, drives), aggregate, oversample, True,
                       elements)[0]
    if free_third:
        elements = _with_free_third(elements, space, free_third)
    for d in drives:
        LoopModel(plant, d, space, rows, oversample, True, inputs=False,
                  **elements.loop_args())
    return True


def score_rows(objective, need, m_base, tight):
    """The linear combinations of all drives' metrics the problem uses.

    Rows: the score of every drive (``sum w m / m_base``), then every limit of every
    drive as ``tight * m / bound`` (<= 1).

    Parameters
    ----------
    objective : planner.objective.Objective
    need : list of str
        The metrics the objective needs, in the order of the loop's metric rows.
    m_base : list of ndarray, shape (n_metrics,)
        The baseline's values of `need` per drive.
    tight : ndarray, shape (n_metrics,)
        Factors on the limited metrics (1, or the robust upper bounds).

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


def _robust_factors(model, drives, library, space, x, base, need):
    """Upper 95 % bound over the nominal of each limited metric at `x` (identified models)."""
    if getattr(model, "frf", None) is None:
        raise PlannerError("robust=True needs an identified model (with its FRF): a known "
                           "model has no estimation error")
    shocks = space.shocks(x)
    lib = ShockLibrary(list(shocks.values()) + list(library.values()))
    unc = prediction_uncertainty(model, drives[0], [space.setup(shocks)], lib)
    hi = unc.ratio_hi.iloc[0]
    return np.array([max(float(hi.get(m, 1.0)), 1.0) for m in need])


def _finish(model, plant, drives, library, space, constraints, objective, base, weights,
            aggregate, oversample, x_opt, solver, history, n_closest, stationarity, A_lin,
            b_lin, t_start, settings, scan=None, extra=(), elements=_Elements(),
            click_radius=None):
    # verify the optimum, the other starts' results, the best feasible iterate and the scan's
    # best curve (the floor: the result is never worse than it in the time domain); keep the
    # best verified
    cands, sources = [x_opt], ["ipopt"]
    for src, x in extra:
        cands.append(x)
        sources.append(src)
    A_it, b_it = elements.rows(A_lin, b_lin)
    feas = [(f, x) for x, f in solver.pop("iterates")
            if np.all(A_it @ x <= b_it + 1e-6 * (1 + np.abs(b_it)))]
    if feas:
        cands.append(min(feas, key=lambda fx: fx[0])[1])
        sources.append("iterate")
    if scan is not None and not settings.get("robust"):
        # (robust limits are tightened by the model's intervals, which the scan does not
        # hold: there the scan's curve is only the start)
        cands.append(elements.extend(scan.x))
        sources.append("scan")
    n = space.n_vars
    verified = []
    for k, x in enumerate(cands):
        shocks = space.shocks(x[:n])
        tail = elements.clip(x[n:])
        lib = ShockLibrary(list(shocks.values()) + _values(elements.third_shocks(tail))
                           + list(library.values()))
        setup = elements.setup_with_third(space.setup(shocks), tail)
        try:
            sc, _ = time_domain_scores(model, drives, [setup], lib, objective, base, weights,
                                        oversample, aggregate,
                                        **elements.verify(tail, [setup.name]))
        except ValueError as exc:
            # the time-domain loop cannot solve this candidate's steps (Newton's method did
            # not converge: IPOPT's loop, a fixed number of iterations, does not see it): it
            # is not a result
            if not any(v[0] < np.inf for v in verified) and k == len(cands) - 1:
                raise
            solver.setdefault("unverifiable", {})[sources[k]] = str(exc)
            verified.append((np.inf, False, k))
            continue
        verified.append((float(sc.loc["optimum", "score"]), bool(sc.loc["optimum", "feasible"]),
                         k))
    ok = [v for v in verified if v[1]] or [v for v in verified if v[0] < np.inf]
    best_k = min(ok)[2]
    solver["source"] = sources[best_k]
    solver["candidates"] = {src: v[0] for src, v in zip(sources, verified)}
    x_opt = space.valid(cands[best_k][:n])
    p_opt = elements.clip(cands[best_k][n:])
    stops_opt = elements.stops_at(p_opt)
    shocks = space.shocks(x_opt)
    setup = elements.setup_with_third(space.setup(shocks), p_opt)
    # the optimal shocks: the corner groups', then the free third dampers'
    shocks = ShockLibrary(list(shocks.values()) + _values(elements.third_shocks(p_opt)))
    # (the crate's entries: its adjustables keep their settings; its fixed shocks as values)
    lib = ShockLibrary(list(shocks.values()) + library.entries())
    if not solver["success"]:
        warnings.warn(f"optimize: IPOPT stopped with status {solver['status']!r} after "
                      f"{solver['iterations']} iterations; the best verified iterate is "
                      "returned (score "
                      f"{min(ok)[0]:.4f}): raise max_iter, or check the constraints",
                      OptimizeWarning, stacklevel=3)
    elif solver.get("acceptable"):
        warnings.warn(f"optimize: IPOPT stopped at an acceptable level, not converged "
                      f"({solver['reason']}); the best verified of its results, its best "
                      f"iterate and the scan's best curve is returned ({sources[best_k]}, "
                      f"score {min(ok)[0]:.4f}): check the curves, or raise max_iter",
                      OptimizeWarning, stacklevel=3)
    if solver.get("unverifiable"):
        warnings.warn(f"optimize: the time-domain loop could not simulate "
                      f"{', '.join(solver['unverifiable'])} (Newton's method did not converge "
                      f"at oversample {oversample}: curves too steep for the loop's step); the "
                      f"best verified of the others is returned ({sources[best_k]}): raise "
                      "--oversample, or bound the curves' slopes (curve constraints)",
                      OptimizeWarning, stacklevel=3)

    # the optimum's shock velocities (first drive): the distribution the crate is compared over
    resp = simulate(plant, drives[0], setup.resolve(lib), oversample=oversample,
                    stop_tables=stops_opt, static_corner_load_n=elements.static,
                    third=elements.third_at(p_opt))
    vel = {c: np.asarray(resp.channels[f"shock_velocity_{c}"]) for c in CORNERS}
    # the crate: every setup of the same symmetry, by distance to the optimal curves
    sym, axles = {"left-right": ("left-right", "independent"), "all": ("left-right", "same"),
                  "none": ("none", "independent")}[space.symmetry]
    # (a car's heave and roll dampers stay off its corners)
    corner_ids = None if elements.third is None else elements.third.corner_ids(library)
    crate = list(enumerate_setups(library, symmetry=sym, axles=axles, shocks=corner_ids))
    if base.name not in {s.name for s in crate}:
        crate.append(base)
    opt_pwl = {c: space.curves(x_opt)[space.group_of(c)] for c in CORNERS}
    listed_ids = list(library.ids) if corner_ids is None else \
        list(dict.fromkeys(corner_ids + list(base.ids())))
    dist_id = {(c, sid): curve_distance(library[sid].to_pwl(), opt_pwl[c], vel[c])
               for c in CORNERS for sid in listed_ids}
    dist = np.array([math.sqrt(np.mean([dist_id[(c, s.shocks[c])] ** 2 for c in CORNERS]))
                     for s in crate])
    order = np.argsort(dist, kind="stable")
    closest = [crate[i] for i in order[:n_closest]]
    # (with third-element choices, every crate setup with each: the crate's best is searched
    # over them too; a variant's distance is its corners')
    crate_own, plain = {}, None
    if elements.third is not None and elements.third.choices:
        plain = {s.name for s in crate}
        crate, crate_own, parent = elements.third.crate(crate, library)
        dist = dist[parent]
    best_name, crate_scores = _crate_best(model, drives, library, crate, objective, base,
                                          weights, oversample, aggregate,
                                          elements=_with_own_third(elements.verify(p_opt, ()),
                                                                   crate_own),
                                          third=elements.third, plain=plain)
    by_name = {s.name: s for s in crate}
    searches, skipped, t_clicks = [], {}, time.perf_counter()
    if click_radius is not None and library.adjustable_ids:
        searches, skipped = _click_search(model, drives, library, space, objective, base,
                                          weights, oversample, aggregate, opt_pwl, vel,
                                          by_name[best_name], click_radius,
                                          elements.verify(p_opt, ()))
    listed = [setup, base] + [by_name[best_name]] + [s.setup for s in searches] + closest
    uniq, seen = [], set()
    for s in listed:
        if s.name not in seen:
            uniq.append(s)
            seen.add(s.name)
    table, metrics = time_domain_scores(model, drives, uniq, lib, objective, base, weights,
                                         oversample, aggregate,
                                         **_with_own_third(elements.verify(p_opt, [setup.name]),
                                                           crate_own))
    table = table.loc[[s.name for s in uniq]]
    kinds = {setup.name: "optimum", base.name: "baseline"}
    kinds.setdefault(best_name, "crate best")
    for s in searches:
        kinds.setdefault(s.setup.name, "clicks")
    for s in closest:
        kinds.setdefault(s.name, "closest")
    table.insert(0, "kind", [kinds[n] for n in table.index])
    ids = pd.DataFrame([s.ids() for s in uniq], columns=list(CORNERS), index=table.index)
    if elements.third is not None:  # the third dampers' ids (the baseline's but the optimum's
        car = elements.third.car  # and a crate variant's)
        for e in car.elements.elements:
            ids[e] = [(s.third or {}).get(e, car.baseline.dampers.get(e)) for s in uniq]
            if crate_own:
                ids[e] = [v if v is not None or e not in (s.third or {}) else "none"
                          for v, s in zip(ids[e], uniq)]
        if any(s.heave_springs for s in uniq):  # a crate variant's heave springs
            for e in car.elements.elements:
                if e in HEAVE_ELEMENTS:
                    a = e.rpartition("_")[2]
                    ids[f"heave_spring_{a}"] = [
                        (s.heave_springs or {}).get(a, car.baseline.heave_springs.get(a))
                        or "none" for s in uniq]
    table = pd.concat([table.iloc[:, :1], ids, table.iloc[:, 1:]], axis=1)
    dmap = dict(zip([s.name for s in crate], dist))
    table["distance"] = [0.0 if n == setup.name else dmap.get(n, np.nan) for n in table.index]
    table.index.name = "setup"
    gap = 1.0 - table.loc[setup.name, "score"] / table.loc[best_name, "score"]
    clicks = None
    if searches or skipped:
        clicks = ClickResult(searches=tuple(searches), skipped=skipped, crate_best=best_name,
                             crate_best_score=float(table.loc[best_name, "score"]),
                             optimum_score=float(table.loc[setup.name, "score"]),
                             radius=click_radius,
                             settings={"search_s": time.perf_counter() - t_clicks,
                                       "n_simulated": sum(s.n_simulated for s in searches)})
    solver["verified_score"] = float(table.loc[setup.name, "score"])
    stat = None
    if stationarity and not space.linear:
        stat = _stationarity(model, drives, lib, space, x_opt, A_lin, b_lin, objective, base,
                             weights, oversample, aggregate, solver["verified_score"],
                             elements=elements, packers_m=p_opt)
    settings.update(oversample=oversample, aggregate=aggregate, weights=weights.tolist(),
                    drives=[d.name for d in drives], symmetry=space.symmetry,
                    linear=space.linear, lag_s=list(space.lag_s), total_s=None,
                    crate_scores=crate_scores)
    if not space.linear:
        lo, hi = constraint_envelope(space, constraints, library)
        settings["envelope_n"] = {"lo": lo.tolist(), "hi": hi.tolist()}
    if elements.third is not None:
        settings["third"] = elements.third.car.to_dict()
        settings["free_third"] = list(elements.free_third)
        if elements.third.choices:
            settings["crate_third"] = {k: [v or "none" for v in vals]
                                       for k, vals in elements.third.choices.items()}
    if elements.active:
        settings.update(bump_stops=elements.stops is not None,
                        packers={g: list(b) for g, b in zip(elements.groups, elements.bounds)},
                        static_corner_load_n=elements.static)
    settings["total_s"] = time.perf_counter() - t_start
    return CurveOptimum(x=np.asarray(x_opt), curves=space.curves(x_opt), shocks=shocks,
                        third_curves=({} if not elements.n_third else dict(zip(
                            elements.free_third,
                            elements.third_space.curves(p_opt[:elements.n_third])))),
                        setup=setup, table=table, metrics=metrics, crate_best=best_name,
                        gap=float(gap), velocity_m_s=vel, stationarity=stat, history=history,
                        solver=solver, space=space, constraints=constraints,
                        objective=objective, baseline=base, settings=settings,
                        packers_m={g: float(v) for g, v in
                                   zip(elements.groups, p_opt[elements.n_third:])},
                        bump_stops=None if stops_opt is None else tuple(stops_opt),
                        clicks=clicks)


def _with_own_third(args, own):
    """``time_domain_scores``' element arguments `args` with the crate setups' own third
    elements `own` (name -> ``(dampers, springs)``) added to ``setup_third``."""
    if not own:
        return args
    return dict(args, setup_third={**own, **(args.get("setup_third") or {})})


def _click_search(model, drives, library, space, objective, base, weights, oversample,
                  aggregate, opt_pwl, vel, crate_best, radius, element_args):
    """The crate's adjustables' best settings per group (:func:`search_clicks`): started from
    the settings nearest the optimum's curves and nearest the crate best's, verified as the
    crate is (the car's stops as given)."""

    def score(setups):
        t, _ = time_domain_scores(model, drives, setups, library, objective, base, weights,
                                  oversample, aggregate, **element_args)
        return {s.name: (bool(t.loc[s.name, "feasible"]), float(t.loc[s.name, "score"]))
                for s in setups}

    targets = {"optimum": opt_pwl,
               "crate best": {c: library[crate_best.shocks[c]].to_pwl() for c in CORNERS}}
    return search_clicks(library, space.groups, targets, vel, score, radius=radius)


def _crate_best(model, drives, library, crate, objective, base, weights, oversample, aggregate,
                top=20, elements=None, third=None, plain=None):
    """The crate's best feasible setup: screened on every drive (with the car's third
    elements, :class:`OptimizeThird`, if any), the best `top` verified (with the car's `elements`,
    ``time_domain_scores``' arguments, if any). `plain`: the names of the crate's setups
    with the car's own third elements (a crate with third-element variants): their best
    `top` are verified too, so the variants' best is never worse than theirs."""
    total = None
    screen_obj = linear_objective(objective)
    screen_third = None if third is None else third.screening(crate, library)
    for w, d in zip(weights, drives):
        sc = screen_setups(model, d, crate, library, third=screen_third).table
        s = score_setups(sc, screen_obj, baseline=base.name).table
        v = s["score"].where(s["feasible"], np.inf)
        total = w * v if total is None else (total + w * v if aggregate == "sum"
                                             else np.maximum(total, v))
    order = total.sort_values(kind="stable").index.tolist()
    pick = set(order[:top])
    if plain is not None:
        pick |= set([n for n in order if n in plain][:top])
    cand = [s for s in crate if s.name in pick]
    table, _ = time_domain_scores(model, drives, cand, library, objective, base, weights,
                                   oversample, aggregate, **(elements or {}))
    feas = table[table["feasible"]]
    pick = feas if len(feas) else table
    return str(pick["score"].idxmin()), {n: float(v) for n, v in pick["score"].items()}


def _stationarity(model, drives, lib, space, x, A, b, objective, base, weights, oversample,
                  aggregate, score, elements=_Elements(), packers_m=()):
    """Each curve variable moved by +-5 % (within the linear constraints), verified (with
    the optimum's packers)."""
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
            shocks = space.shocks(xt, prefix=f"S{j}{'m' if sgn < 0 else 'p'}")
            extra += list(shocks.values())
            setups.append(Setup(f"var{j}{'-' if sgn < 0 else '+'}",
                                {c: shocks.ids[space.group_of(c)] for c in CORNERS}))
            rows.append((j, sgn))
    if not setups:
        return pd.DataFrame(columns=["variable", "change", "score", "relative_change"])
    lib2 = ShockLibrary(list(lib.values()) + extra)
    table, _ = time_domain_scores(model, drives, setups, lib2, objective, base, weights,
                                   oversample, aggregate,
                                   **elements.verify(packers_m, [s.name for s in setups]))
    out = pd.DataFrame({"variable": [j for j, _ in rows], "change": [0.05 * s for _, s in rows],
                        "score": table.loc[[s.name for s in setups], "score"].to_numpy(),
                        "feasible": table.loc[[s.name for s in setups], "feasible"].to_numpy()})
    out["relative_change"] = out["score"] / score - 1.0
    return out
