"""The optimizer's global stage: linear and two-slope curves per corner group, verified.

:func:`scan_curves` searches, per corner group, curves a shock builder valves:

1. *linear* (``F = c v``, the group's lag) on a grid of rates: screened by the
   frequency-domain screening (:func:`planner.screen.screen_response`,
   thousands of setups a second), the full grid with one or two groups,
   coordinate by coordinate from the best uniform rate with more;
2. *two-slope* (digressive) from the best linear point: a low-speed slope
   around the linear rate, a knee at an inner knot, a high-speed slope a
   fraction of it, rebound a factor of bump; screened coordinate by
   coordinate (two passes over the groups);
3. the screening's best few of each kind, and the best linear point's grid
   neighbours, *verified* in the time domain (:func:`time_domain_scores`,
   i.e. :func:`planner.predict.predict_setups`).

Every candidate is a point of the optimizer's curve space meeting its linear
constraints (``A x <= b``; beyond the last knot a linear candidate's slope is
lowered as far as the force cap and the high-speed bound ask). The best
verified candidate starts IPOPT and is a floor under its result:
:func:`planner.optimize.optimize_curves` returns the best verified of the
scan's best and IPOPT's, so it is never worse in the time domain than the
best curve of the scan.

Why verify: the screening sorts the coarse landscape well (Spearman 0.998
against the time domain on an 8 x 8 linear grid of the GT-like car of issue
24) but cannot resolve its top to better than about 0.2 %, and it biases
linear against two-slope candidates by about that much; the verified
shortlist, which always holds the best linear point, does.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ident.data.channels import CORNERS
from ident.data.units import UNIT_LABELS, check_units, from_si
from ident.models.library import ShockLibrary
from ident.models.shocks import LinearShock
from ident.sim.closedloop import ELEMENT_STATS, rig_response, simulate_batch
from ident.sim.metrics import THIRD_METRIC_NAMES, compute_metrics
from planner.objective import score_setups
from planner.optimize.constraints import MAX_FORCE_VELOCITY_M_S
from planner.options import ElementOptions, LoopOptions
from planner.predict import (
    METRIC_OUTPUTS,
    as_loop_plant,
    predict_setups,
    resolve_setups,
)
from planner.screen import drive_bands, screen_response

__all__ = [
    "SCAN_GRID_RATIOS",
    "SCAN_VERIFY",
    "TWO_SLOPE_RATES",
    "TWO_SLOPE_RATIOS",
    "REBOUND_FACTORS",
    "ScanOptions",
    "ScanResult",
    "curve_words",
    "element_predictions",
    "is_element_metric",
    "linear_objective",
    "scan_curves",
    "time_domain_scores",
]

#: Damping rates of the linear scan, as ratios to the plant's mean reference damping
#: ``cbar``: 0.15 to 4 times, 25 log-spaced (ratio 1.15 between neighbours). The paper
#: car's best linear rate and the GT-like car's (10,800 / 11,800 N s/m) lie well inside.
SCAN_GRID_RATIOS = np.geomspace(0.15, 4.0, 25)
#: Screening's best candidates of each kind (linear, two-slope) verified in the time domain
#: (91 setups/s on a 60 s drive against 9,800 linear or 580 two-slope screened).
SCAN_VERIFY = 8
#: Two-slope candidates: low-speed slopes as ratios to the group's best linear rate.
TWO_SLOPE_RATES = (0.7, 0.85, 1.0, 1.2, 1.45, 1.75)
#: Two-slope candidates: high-speed over low-speed slope (a digressive piston's 0.1-0.3 and
#: milder; the defaults' least ratio is 0.15).
TWO_SLOPE_RATIOS = (0.6, 0.35, 0.2)
#: Two-slope candidates: rebound slope over bump slope.
REBOUND_FACTORS = (0.8, 1.0, 1.25)


@dataclass(frozen=True, eq=False)
class ScanOptions:
    """The scan's grid and its verification (:func:`scan_curves`).

    Parameters
    ----------
    grid_n_s_m : array_like, optional
        Linear rates per group [N s/m]; default ``cbar * SCAN_GRID_RATIOS``.
    n_verify : int
        Screening's best candidates of each kind verified in the time domain.
    two_slope : bool
        Also scan two-slope curves (not in a linear space).
    """

    grid_n_s_m: object = None
    n_verify: int = SCAN_VERIFY
    two_slope: bool = True


@dataclass(frozen=True, eq=False)
class ScanResult:
    """The result of :func:`scan_curves`.

    Attributes
    ----------
    x : ndarray, shape (n_vars,)
        The best verified candidate, a decision vector of the curve space.
    curves : list of PiecewiseLinear
        Its curves, one per group.
    rates_n_s_m : ndarray, shape (n_groups,)
        The best verified linear rate per group [N s/m].
    score : float
        The best verified candidate's (time-domain) score, aggregated over the drives.
    feasible : bool
        Whether it meets the objective's limits (time domain).
    linear_score : float
        The best verified linear candidate's score.
    grid_n_s_m : ndarray, shape (n_rates,)
        The linear rates scanned per group [N s/m].
    table : pandas.DataFrame
        The verified shortlist, best first: ``kind`` (``linear`` or
        ``two-slope``), a column ``curve_<group>`` per group (the curve in
        words), ``screening`` (its aggregated screening score), ``score``,
        ``score_<drive>`` and ``feasible`` (time domain).
    points : list of ndarray
        The decision vectors of `table`'s rows.
    keys : list of tuple
        The best candidate's curve per group, as :func:`curve_words` reads it.
    n_candidates : int
        Candidates tried.
    n_screened : int
        Of those, the ones meeting the curve constraints, screened.
    screen_s, verify_s : float
        Wall time of the screening and of the time-domain verification [s].
    """

    x: np.ndarray
    curves: list
    rates_n_s_m: np.ndarray
    score: float
    feasible: bool
    linear_score: float
    grid_n_s_m: np.ndarray
    table: pd.DataFrame
    points: list
    keys: list
    n_candidates: int
    n_screened: int
    screen_s: float
    verify_s: float

    def summary(self):
        """dict: the scan in plain numbers, for a result's settings."""
        best = self.table.iloc[0]
        return {"grid_n_s_m": [float(self.grid_n_s_m[0]), float(self.grid_n_s_m[-1]),
                               self.grid_n_s_m.size],
                "best": str(best["kind"]),
                # the best curves in words, per unit system (the report's units)
                "curves": {u: [curve_words(k, units=u) for k in self.keys]
                           for u in ("SI", "imperial")},
                "rates_n_s_m": self.rates_n_s_m.tolist(), "score": self.score,
                "linear_score": self.linear_score,
                "feasible": self.feasible, "n_candidates": self.n_candidates,
                "n_screened": self.n_screened, "n_verified": len(self.table),
                "screen_s": self.screen_s, "verify_s": self.verify_s}


def is_element_metric(name):
    """bool: `name` is a closed-loop element statistic (``tire_liftoff_share_XX``,
    ``tire_contact_min_XX``, ``bump_stop_contact_share_XX``,
    :data:`ident.sim.closedloop.ELEMENT_STATS`), which only the time domain gives."""
    return any(name == f"{k}_{c}" for k in ELEMENT_STATS for c in CORNERS)


def linear_objective(objective):
    """The objective without its limits on element statistics (:func:`is_element_metric`)
    and on third elements' motions (``heave_travel_rms_front``, ...,
    :data:`ident.sim.metrics.THIRD_METRIC_NAMES`): the one the screening (frequency domain,
    no elements) ranks by; the objective itself when it has none."""
    def verified_only(m):
        return is_element_metric(m) or m in THIRD_METRIC_NAMES

    if not any(verified_only(m) for m in objective.limits):
        return objective
    return replace(objective, limits={m: dict(v) for m, v in objective.limits.items()
                                      if not verified_only(m)})


def element_predictions(model, drive, setups, library, bump_stops, *, oversample=2,
                        static_corner_load_n=None, chunk_size=32, third=None,
                        setup_third=None):
    """The spec's metrics of setups with the car's elements, in the time domain.

    :func:`ident.sim.closedloop.simulate_batch` with ``bump_stops=`` and
    ``static_corner_load_n=``, then :func:`ident.sim.metrics.compute_metrics` on its
    channels, with the elements' statistics (``bump_stop_contact_share_XX``,
    ``tire_liftoff_share_XX``, ``tire_contact_min_XX``) as extra columns: the table
    :func:`planner.predict.predict_setups` gives without elements.

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
    drive : ident.data.drive.Drive
        Prepared (:func:`planner.predict.prepare_drive`).
    setups : sequence of planner.setups.Setup
    library : ident.models.library.ShockLibrary
    bump_stops : list
        Per setup the stops in the loop's form (4 of None or ``(contact_travel_m,
        travel_table_m, force_table_n)``), or None.
    oversample : int
    static_corner_load_n : array_like, shape (4,), optional
        Static tire loads [N]: lift-off in the loop.
    chunk_size : int
        Setups per simulated batch (their responses are kept until their metrics are).
    third : tuple, optional
        The car's third elements (issue 38) for every setup: one ``(dampers, springs)``
        entry (:meth:`planner.elements.SetupThird.loop_third`); the table then adds the
        elements' motion metrics (``heave_travel_rms_front``, ...,
        :data:`ident.sim.metrics.THIRD_METRIC_NAMES`).
    setup_third : list, optional
        Per setup its own ``(dampers, springs)`` entry, or None for `third` (e.g. the
        optimum with its free third dampers' curves).

    Returns
    -------
    pandas.DataFrame
        One row per setup (its name), the shock ids and the metrics (SI).
    """
    plant = as_loop_plant(model)
    models = resolve_setups(setups, library)
    outputs = [o for o in METRIC_OUTPUTS if o in plant.output_names]
    rig = rig_response(plant, drive, oversample=oversample, outputs=outputs)
    rows = []
    for a in range(0, len(models), chunk_size):
        batch = simulate_batch(plant, drive, models[a:a + chunk_size], oversample=oversample,
                               outputs=outputs, rig=rig,
                               bump_stops=list(bump_stops[a:a + chunk_size]),
                               static_corner_load_n=static_corner_load_n,
                               third=None if third is None
                               else [third if own is None else own for own in
                                     (setup_third or [None] * len(models))[a:a + chunk_size]])
        met = compute_metrics(batch.channels, fs=batch.fs_hz)
        cols = {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in met.values.items()}
        cols.update({k: np.asarray(v, dtype=float) for k, v in batch.elements.items()})
        rows.append(pd.DataFrame(cols))
    table = pd.concat(rows, ignore_index=True)
    ids = pd.DataFrame([s.ids() for s in setups], columns=list(CORNERS))
    table = pd.concat([ids, table], axis=1)
    table.index = pd.Index([s.name for s in setups], name="setup")
    return table


def time_domain_scores(model, drives, setups, library, objective, baseline, weights,
                       oversample, aggregate, *, bump_stops=None, setup_stops=None,
                       static_corner_load_n=None, third=None, setup_third=None):
    """Verified scores of setups: :func:`planner.predict.predict_setups` per drive, scored
    against the baseline, aggregated over the drives.

    With the car's elements (`bump_stops`, `static_corner_load_n`) the setups are
    simulated with them (:func:`element_predictions`); without, the numbers of
    :func:`planner.predict.predict_setups`.

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
    drives : list of ident.data.drive.Drive
        Prepared (:func:`planner.predict.prepare_drive`).
    setups : sequence of planner.setups.Setup
    library : ident.models.library.ShockLibrary
        Holds every shock of `setups` and of `baseline`.
    objective : planner.objective.Objective
    baseline : planner.setups.Setup
    weights : ndarray, shape (n_drives,)
    oversample : int
    aggregate : {"sum", "worst"}
        Weighted sum of the drives' scores, or the worst.
    bump_stops : sequence of 4, optional
        The car's stops in the loop's form, for every setup not in `setup_stops`.
    setup_stops : dict of str -> sequence of 4, optional
        A setup's own stops by its name (e.g. the optimum with its chosen packers).
    static_corner_load_n : array_like, shape (4,), optional
        Static tire loads [N]: lift-off in the loop.
    third : tuple, optional
        The car's third elements, one ``(dampers, springs)`` entry every setup is simulated
        with (:func:`element_predictions`).
    setup_third : dict of str -> tuple, optional
        A setup's own third elements by its name (the optimum with its free third dampers).

    Returns
    -------
    table : pandas.DataFrame
        One row per setup (the baseline first): ``score``, ``score_<drive>``, ``feasible``.
    metrics : dict of str -> pandas.DataFrame
        Per drive, the predicted metrics (SI).
    """
    cand = [baseline] + [s for s in setups if s.name != baseline.name]
    per, metrics, feasible = [], {}, None
    elements = (bump_stops is not None or setup_stops or static_corner_load_n is not None
                or third is not None)
    own = dict(setup_stops or {})
    for d in drives:
        if elements:
            table = element_predictions(model, d, cand, library,
                                        [own.get(s.name, bump_stops) for s in cand],
                                        oversample=oversample,
                                        static_corner_load_n=static_corner_load_n,
                                        third=third,
                                        setup_third=None if not setup_third else
                                        [setup_third.get(s.name) for s in cand])
        else:
            table = predict_setups(model, d, cand, library,
                                   loop=LoopOptions(oversample=oversample),
                                   elements=ElementOptions(use_model=False)).table
        metrics[d.name] = table
        sc = score_setups(table, objective, baseline=baseline.name).table
        per.append(sc["score"])
        feasible = sc["feasible"] if feasible is None else (feasible & sc["feasible"])
    S = pd.concat(per, axis=1)
    S.columns = [f"score_{d.name}" for d in drives]
    agg = S.to_numpy() @ np.asarray(weights) if aggregate == "sum" else S.to_numpy().max(axis=1)
    out = S.copy()
    out.insert(0, "score", agg)
    out["feasible"] = feasible.to_numpy()
    return out, metrics


def scan_curves(model, plant, drives, library, space, constraints, A_lin, b_lin, baseline,
                objective, weights, aggregate, *, scan=ScanOptions(), oversample=2,
                elements=None):
    """The best linear and two-slope curves per corner group: screened, verified.

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
        The model the verification simulates (as given to the optimizer).
    plant : LoopPlant
        Its loop plant (:func:`planner.plant.as_loop_plant`), screened.
    drives : list of ident.data.drive.Drive
        Prepared.
    library : ident.models.library.ShockLibrary
        Holds the baseline's shocks.
    space : CurveSpace
        The curves (knots, groups, lags) the candidates are points of.
    constraints : CurveConstraints
        Its high-speed slope bounds and force cap shape the linear candidates
        beyond the last knot.
    A_lin : ndarray, shape (n_rows, n_vars)
    b_lin : ndarray, shape (n_rows,)
        The linear constraints on the decision variables: only candidates
        with ``A_lin x <= b_lin`` are screened.
    baseline : planner.setups.Setup
    objective : planner.objective.Objective
    weights : ndarray, shape (n_drives,)
    aggregate : {"sum", "worst"}
    scan : ScanOptions
        The grid (``grid_n_s_m``), the candidates verified (``n_verify``), whether
        two-slope curves are scanned (``two_slope``).
    oversample : int
    elements : mapping, optional
        The car's elements, :func:`time_domain_scores`' keyword arguments ``bump_stops``
        (the car's stops in the loop's form), ``static_corner_load_n`` and ``third`` (the
        car's third elements, one ``(dampers, springs)`` entry, the baseline's): the
        verification simulates every candidate with them; the screening (frequency domain)
        sees the car without them and ranks by the objective without its limits on
        element statistics (:func:`linear_objective`).

    Returns
    -------
    ScanResult or None
        None if no candidate meets the constraints.
    """
    t0 = time.perf_counter()
    if not isinstance(scan, ScanOptions):
        raise TypeError(f"scan_curves: scan must be a ScanOptions, got {type(scan).__name__}")
    grid_n_s_m, n_verify, two_slope = scan.grid_n_s_m, scan.n_verify, scan.two_slope
    screen_obj = linear_objective(objective)
    G = len(space.groups)
    cbar = float(np.mean(plant.cbar_n_s_m))
    grid = cbar * SCAN_GRID_RATIOS if grid_n_s_m is None else np.asarray(grid_n_s_m, float)
    base_models = tuple(baseline.resolve(library))
    bands = [drive_bands(d) for d in drives]
    Hs = [plant.frequency_response(b.f_hz) for b in bands]
    tol = 1e-9 * (1 + np.abs(b_lin))
    nv = space.n_group_vars

    # a group's candidate: key -> (its decision variables, its shock model, words)
    group_cand = {}

    def cand_of(g, key):
        if (g, key) not in group_cand:
            if space.linear:
                xg = np.array([key[1]])
            elif key[0] == "linear":
                xg = _two_slope_point(space, constraints, key[1], None, 1.0, 1.0)
            else:
                xg = _two_slope_point(space, constraints, *key[1:])
            if key[0] == "linear":
                shock = LinearShock("c", key[1], lag_s=space.lag_s[g])
            else:
                xs = np.zeros(space.n_vars)
                xs[g * nv:(g + 1) * nv] = xg
                shock = list(space.shocks(xs, prefix="SCAN").values())[g]
            group_cand[(g, key)] = (xg, shock, curve_words(key))
        return group_cand[(g, key)]

    def point(cand):
        return np.concatenate([cand_of(g, k)[0] for g, k in enumerate(cand)])

    admit, screened = {}, {}

    def admissible(cands):
        out = []
        for c in dict.fromkeys(cands):
            if c not in admit:
                admit[c] = bool(np.all(A_lin @ point(c) <= b_lin + tol))
            if admit[c]:
                out.append(c)
        return out

    def screen(cands):
        """Aggregated screening score of every candidate (a tuple of group keys), cached."""
        todo = [c for c in dict.fromkeys(cands) if c not in screened]
        if todo:
            models = [tuple(cand_of(space.group_of(k), c[space.group_of(k)])[1]
                            for k in CORNERS) for c in todo]
            per = []
            for b, H in zip(bands, Hs):
                names, met, _, _ = screen_response(H, plant.output_names, plant.cbar_n_s_m, b,
                                                   models + [base_models])
                t = pd.DataFrame(met, columns=names)
                t.index = [f"s{k}" for k in range(len(todo))] + ["baseline"]
                sc = score_setups(t, screen_obj, baseline="baseline").table
                per.append(sc["score"].where(sc["feasible"], np.inf).to_numpy()[:-1])
            per = np.array(per)
            agg = (np.asarray(weights) @ per if aggregate == "sum" else per.max(axis=0))
            for c, sc_ in zip(todo, agg):
                screened[c] = float(sc_)
        return np.array([screened[c] for c in cands])

    def best_of(cands):
        cands = admissible(cands)
        if not cands:
            return None
        return cands[int(np.argmin(screen(cands)))]

    # 1. linear: the full grid for one or two groups, else coordinate-wise
    lin = [("linear", float(c)) for c in grid]
    if G <= 2:
        mesh = np.meshgrid(*([np.arange(grid.size)] * G), indexing="ij")
        best = best_of([tuple(lin[int(m.flat[k])] for m in mesh) for k in range(mesh[0].size)])
    else:
        best = best_of([(c,) * G for c in lin])
        for _ in range(2 if best is not None else 0):
            for g in range(G):
                best = best_of([best[:g] + (c,) + best[g + 1:] for c in lin]) or best
    if best is None:
        return None
    lin_pool = [c for c in screened if admit.get(c)]
    best_lin = best

    # 2. two-slope from the best linear point, coordinate-wise (two passes)
    two_pool = []
    if two_slope and not space.linear and len(space.v_knots_m_s) >= 5:
        n_b = int(np.sum(space.v_knots_m_s > 0))
        knees = range(1, max(n_b - 1, 1))
        for _ in range(2):
            for g in range(G):
                c_lin = best_lin[g][1]
                keys = [("two-slope", c_lin * a, k, r, q) for a in TWO_SLOPE_RATES
                        for k in knees for r in TWO_SLOPE_RATIOS for q in REBOUND_FACTORS]
                keys += [("two-slope", c_lin * a, None, 1.0, q) for a in TWO_SLOPE_RATES
                         for q in REBOUND_FACTORS]
                best = best_of([best[:g] + (k,) + best[g + 1:] for k in keys]) or best
        two_pool = [c for c in screened if admit.get(c) and c not in set(lin_pool)]
    screen_s = time.perf_counter() - t0

    # 3. verify the screening's best of each kind in the time domain
    t1 = time.perf_counter()
    n = max(int(n_verify), 1)
    order = (sorted(lin_pool, key=lambda c: (screened[c], str(c)))[:n]
             + sorted(two_pool, key=lambda c: (screened[c], str(c)))[:n])
    lib_models, setups = [], []
    for k, c in enumerate(order):
        shocks = space.shocks(point(c), prefix=f"SCAN{k}")
        lib_models += list(shocks.values())
        setups.append(space.setup(shocks, name=f"scan{k}"))
    lib = ShockLibrary(lib_models + [m for m in library.values()
                                     if m.id not in {s.id for s in lib_models}])
    table, _ = time_domain_scores(model, drives, setups, lib, objective, baseline, weights,
                                  oversample, aggregate, **dict(elements or {}))
    table = table.loc[[s.name for s in setups]]
    for g, (name, _) in reversed(list(enumerate(space.groups))):
        table.insert(0, f"curve_{name}", [curve_words(c[g]) for c in order])
    table.insert(0, "kind", ["linear" if all(k[0] == "linear" for k in c) else "two-slope"
                             for c in order])
    table.insert(1 + G, "screening", [screened[c] for c in order])
    table["_order"] = range(len(order))
    # best: feasible first, then the score
    table = table.assign(_rank=~table["feasible"]).sort_values(
        ["_rank", "score"], kind="stable").drop(columns="_rank")
    points = [point(order[i]) for i in table["_order"]]
    best_keys = order[int(table["_order"].iloc[0])]
    lin_rows = table[table["kind"] == "linear"]
    best_lin_row = order[int(lin_rows["_order"].iloc[0])]
    table = table.drop(columns="_order")
    table.index = [f"scan{k}" for k in range(len(table))]
    best = table.iloc[0]
    verify_s = time.perf_counter() - t1
    return ScanResult(x=points[0], curves=space.curves(points[0]),
                      rates_n_s_m=np.array([k[1] for k in best_lin_row]),
                      score=float(best["score"]), feasible=bool(best["feasible"]),
                      linear_score=float(lin_rows["score"].iloc[0]), grid_n_s_m=grid,
                      table=table, points=points, keys=list(best_keys),
                      n_candidates=len(admit),
                      n_screened=len(screened), screen_s=screen_s, verify_s=verify_s)


def _two_slope_point(space, constraints, slope, knee, ratio, rebound_factor):
    """One group's decision variables of a two-slope curve.

    Bump: `slope` [N/(m/s)] from 0 to the bump knot of index `knee` (1-based
    from 0; None: every knot), then ``ratio * slope``; rebound the same times
    `rebound_factor`. Beyond the last knot a side's slope continues, lowered as
    far as the constraints' high-speed bound and force cap ask."""
    v, z = space.v_knots_m_s, space.zero_index
    n_b, n_r = v.size - 1 - z, z
    out = {}
    for side, n, fac in (("bump", n_b, 1.0), ("rebound", n_r, rebound_factor)):
        segs = [fac * slope * (1.0 if knee is None or j < knee else ratio) for j in range(n)]
        knots = np.abs(v[z + 1:]) if side == "bump" else np.abs(v[:z][::-1])
        f_last = float(np.sum(np.array(segs) * np.diff(np.concatenate([[0.0], knots]))))
        out[side] = segs + [_extension_slope(space, constraints, f_last, segs[-1], side)]
    return _slopes_point(space, out["bump"], out["rebound"])


def _slopes_point(space, bump, rebound):
    """One group's decision variables of the curve with the given segment slopes: `bump`
    and `rebound` hold a slope [N/(m/s)] per segment from 0 outward and one for the
    extension beyond the last knot (positive numbers)."""
    v, z = space.v_knots_m_s, space.zero_index
    f = np.zeros(v.size)
    for j in range(z + 1, v.size):
        f[j] = f[j - 1] + bump[j - z - 1] * (v[j] - v[j - 1])
    for j in range(z - 1, -1, -1):
        f[j] = f[j + 1] - rebound[z - 1 - j] * (v[j + 1] - v[j])
    return np.concatenate([np.delete(f, z), [rebound[-1], bump[-1]]])


def _extension_slope(space, constraints, f_last, slope, side):
    """The slope beyond the last knot of a side continuing `slope`, lowered as far as the
    high-speed bound and the force cap (at ``MAX_FORCE_VELOCITY_M_S``) ask."""
    v = space.v_knots_m_s
    v_last = v[-1] if side == "bump" else -v[0]
    s = slope
    high = getattr(constraints, f"{side}_high_slope")
    if high is not None:
        s = min(s, high[1])
    reach = max(MAX_FORCE_VELOCITY_M_S, v_last)
    if constraints.max_force_n is not None and reach > v_last:
        s = min(s, (constraints.max_force_n - abs(f_last)) / (reach - v_last))
    return max(s, 0.0 if high is None else high[0])


def curve_words(key, units="SI"):
    """A scan candidate's curve in words, its slopes in `units`.

    Parameters
    ----------
    key : sequence
        ``("linear", rate)`` or ``("two-slope", slope, knee, ratio, rebound
        factor)``, slopes [N s/m], knee a bump knot's index (None: no knee).
    units : {"SI", "imperial"}

    Returns
    -------
    str

    Examples
    --------
    >>> curve_words(("two-slope", 9294.0, 2, 0.35, 1.25))
    '9294 N s/m, 0.35x beyond knot 2, rebound 1.25x'
    >>> curve_words(("linear", 8756.3), units="imperial")
    'linear 50 lbf/(in/s)'
    """
    units = check_units(units, where="units")
    unit = "N s/m" if units == "SI" else UNIT_LABELS[units]["damping"]

    def rate(c):
        return f"{from_si(float(c), 'damping', units):.0f} {unit}"

    if key[0] == "linear":
        return f"linear {rate(key[1])}"
    _, slope, knee, ratio, q = key
    if knee is None:
        return f"linear {rate(slope)}, rebound {q:g}x"
    return f"{rate(slope)}, {ratio:g}x beyond knot {knee}, rebound {q:g}x"
