"""The experiment design: :func:`design_experiment` and its result :class:`ExperimentPlan`.

Part of :mod:`planner.design` (see its docstring).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ident.data.channels import CORNERS, RIG_INPUTS
from ident.data.third import CarThird, RunThird
from ident.identify.model import VehicleModel
from ident.models.vehicle import FullCarModel, VehicleParams, build_full_car
from ident.sim.virtual_rig import loop_damping
from planner.elements import corner_shock_ids, setup_third
from planner.errors import PlannerError
from planner.options import ElementOptions
from planner.objective import default_objective, score_setups
from planner.rig_spec import RigSpec, default_rig
from planner.screen import screen_setups
from planner.setups import Setup, enumerate_setups, resolve_baseline
from planner.design.candidates import (CandidateOptions, candidate_runs, full_names, setup_key,
                                       validation_candidates)
from planner.design.information import (
    CRITERIA,
    InformationOptions,
    candidate_information,
    criterion_value,
    decision_weight_matrices,
    drive_maker,
    hermitian,
    session_information,
)
from planner.design.solve import (
    fit_budget,
    greedy_design,
    relaxed_design,
    sequence_cost,
    swap_order,
)
from planner.design.schedule import (
    ScheduleOptions,
    criterion_curve,
    criterion_shares,
    plan_rationale,
    run_predictions,
    schedule_runs,
)

__all__ = [
    "ExperimentPlan",
    "design_experiment",
]

log = logging.getLogger(__name__)


#: A band whose scaled total information has an eigenvalue below this is not identifiable.
_RANK_TOL = 1e-8
#: Designs on less time when the baseline repeats' swaps overrun the budget, at most.
_REPEAT_ATTEMPTS = 8


@dataclass(frozen=True, eq=False)
class ExperimentPlan:
    """The result of :func:`design_experiment`.

    Attributes
    ----------
    runs : tuple of PlannedRun
    drives : dict of str -> ident.data.drive.Drive
        Every drive the runs play, by name.
    library : ShockLibrary
        The crate.
    baseline : planner.setups.Setup
    criterion : str
    budget_min, total_min : float
        The budget and the ordered plan's rig time [min].
    values : dict
        The criterion: ``prior`` (the session's), ``relaxed`` (the relaxed
        optimum on the design bands), ``plan`` (the rounded plan on every
        band), ``greedy`` (the cvxpy-free greedy plan of the same budget).
    relaxed : pandas.DataFrame
        Per candidate: the relaxed number of runs and its cost.
    predictions : pandas.DataFrame
        Per run: the key metrics predicted for it (SI), with ``_lo``/``_hi``
        intervals for an identified model.
    curve : pandas.DataFrame
        The criterion after each run against the rig time so far.
    solver : dict
        cvxpy's status, solver, times.
    rig : planner.rig_spec.RigSpec
    settings : dict
    rationale : tuple of str
        Why the plan chose its runs, a line per purpose (identification, validation,
        baseline repeats); the CLI prints it and the run sheet's legend ends with it.
    third : ident.data.third.CarThird or None
        The car's third elements (issue 38): the runs' ``Setup.third`` keys change the
        baseline's dampers; the rig plan writes each run's ``third``.
    bump_stops : ident.models.bumpstops.BumpStopLibrary or None
        The library of the third elements' heave springs (when the baseline fits any): the
        rig plan's ``bump_stop_library``, written with it.
    """

    runs: tuple
    drives: dict
    library: object
    baseline: object
    criterion: str
    budget_min: float
    total_min: float
    values: dict
    relaxed: pd.DataFrame
    predictions: pd.DataFrame
    curve: pd.DataFrame
    solver: dict
    rig: RigSpec
    settings: dict = field(default_factory=dict)
    rationale: tuple = ()
    third: object = None
    bump_stops: object = None

    def table(self):
        """The runs as a DataFrame (one row per run, in rig order); with adjustable shocks
        in the crate, a ``change`` column holds :attr:`PlannedRun.change`."""
        rows = []
        for r in self.runs:
            row = {"run": r.number, "name": r.name, "purpose": r.purpose,
                   "start_min": r.start_min, "duration_s": r.duration_s, "drive": r.drive,
                   "kind": r.kind}
            row.update(dict(zip(CORNERS, r.setup.ids())))
            row["changed"] = " ".join(r.changed)
            if self.library.adjustable_ids:
                row["change"] = r.change
            row.update({"swap_min": r.swap_min, "share": r.share})
            rows.append(row)
        return pd.DataFrame(rows).set_index("run")


def _plant_and_vehicle(model, baseline, library):
    """The loop plant, the vehicle (known models) and the model's FRF (identified ones)."""
    if isinstance(model, VehicleModel):
        return model.loop_plant(), None, model
    if isinstance(model, VehicleParams):
        model = build_full_car(model)
    if isinstance(model, FullCarModel):
        cbar = loop_damping(baseline.resolve(library))
        return model.loop_plant(cbar), model.params, None
    raise TypeError(f"model must be an identified VehicleModel (with the session), a "
                    f"VehicleParams or a FullCarModel, got {type(model).__name__}")


def _heave_spring_library(car, candidates, model):
    """The library of the car's baseline heave springs (`candidates`' or the model's), or
    None when it fits none."""
    if car is None or not any(car.baseline.heave_springs.values()):
        return None
    if candidates.bump_stops is not None:
        return candidates.bump_stops
    return getattr(getattr(model, "elements", None), "bump_stops", None)


def _third_dampers(setups, car, library):
    """The setups' third dampers (:func:`planner.elements.setup_third` without the heave
    springs, which the design's linearized information leaves out), or None."""
    if car is None:
        return None
    dampers = CarThird(car.elements, RunThird(dampers=dict(car.baseline.dampers)))
    bare = [s if not s.heave_springs else Setup(s.name, dict(s.shocks), third=s.third)
            for s in setups]
    return setup_third(bare, dampers, library, where="design")


def design_experiment(model, library, *, budget_min, criterion="d", session=None,
                      objective=None, baseline=None, drives=None, rig=None,
                      candidates=CandidateOptions(), information=InformationOptions(),
                      schedule=ScheduleOptions(), top=10):
    """Choose the next rig runs within a budget, order them, and predict them.

    Parameters
    ----------
    model : VehicleModel, VehicleParams or FullCarModel
        An identified model with the `session` it came from (between runs), or
        the known physical model (before rig day).
    library : ShockLibrary
        The crate.
    budget_min : float
        Rig time [min], runs, swaps and overheads included.
    criterion : {"d", "a", "decision"}
    session : ident.data.session.Session, optional
        The runs recorded so far (their information is the prior).
    objective : planner.objective.Objective, optional
        For the decision criterion, validation runs and predictions; default
        :func:`planner.objective.default_objective`.
    baseline : Setup, str or 4 str, optional
        The car's setup at the start and the reference of swaps; default the
        session's baseline run's setup, else the crate's first shock.
    drives : sequence of ident.data.drive.Drive, optional
        The team's drives (e.g. a track's): the contenders of the decision
        criterion are ranked on the first, validation runs play it. Default a
        120 s track-like drive.
    rig : planner.rig_spec.RigSpec, optional
        Default :func:`planner.rig_spec.default_rig`.
    candidates : CandidateOptions
        The candidate runs (:func:`candidate_runs`): ``kinds``, ``durations_s``,
        ``shocks``, ``n_shocks``, ``click_levels``.
    information : InformationOptions
        ``n_bands`` (log-spaced bands over ``band_hz`` the criterion sums over),
        ``n_design_bands`` (groups of adjacent bands in the relaxed problem), ``band_hz``
        [Hz], ``noise`` (output noise as a fraction of each output's RMS, white; a known
        model).
    schedule : ScheduleOptions
        ``baseline_every`` (repeat the baseline, shortest duration, after every this many
        runs; 0: never, to catch drift), ``n_validation`` (validation runs of the current
        best setups on the team's drive, at the plan's end: their durations and changes
        spend the budget, and the identification runs before them must meet Eq. 17 on
        their own), ``seed`` (seeds of the planned drives),
        ``date`` (for the run sheet's header).
    top : int
        Contenders of the decision criterion.

    Returns
    -------
    ExperimentPlan

    Raises
    ------
    PlannerError
        On a budget shorter than one run, an unknown criterion, drive kind,
        shock id or baseline, a crate with which no plan meets Eq. 17 (naming
        the corners and the fix), a budget too short for any identifying
        plan, or one that cannot hold both the validation runs and identification runs
        that meet Eq. 17 (naming the budget that would).
    """
    for value, cls, name in ((candidates, CandidateOptions, "candidates"),
                             (information, InformationOptions, "information"),
                             (schedule, ScheduleOptions, "schedule")):
        if not isinstance(value, cls):
            raise TypeError(f"design: {name} must be a {cls.__name__}, got "
                            f"{type(value).__name__}; e.g. {name}={cls.__name__}()")
    kinds, durations_s, shocks, n_shocks, click_levels = (
        candidates.kinds, candidates.durations_s, candidates.shocks, candidates.n_shocks,
        candidates.click_levels)
    n_bands, n_design_bands, band_hz, noise = (information.n_bands, information.n_design_bands,
                                               information.band_hz, information.noise)
    baseline_every, n_validation, seed, date = (schedule.baseline_every, schedule.n_validation,
                                                schedule.seed, schedule.date)
    if criterion not in CRITERIA:
        raise PlannerError(f"criterion {criterion!r} is not one of {list(CRITERIA)}")
    if not (isinstance(budget_min, (int, float)) and math.isfinite(budget_min)
            and budget_min > 0):
        raise PlannerError(f"budget_min must be a positive number of minutes, got "
                           f"{budget_min!r}")
    rig = default_rig() if rig is None else rig
    objective = default_objective() if objective is None else objective
    if baseline is None and session is not None:
        base_run = next((r for r in session.runs if r.role == "baseline"), session.runs[0])
        baseline = [base_run.setup[c] for c in CORNERS]
    base = resolve_baseline(library.ids[0] if baseline is None else baseline, library)
    base = full_names(base, library)  # adjustable shocks named with every adjuster
    plant, vehicle, ident_model = _plant_and_vehicle(model, base, library)
    if ident_model is not None and session is None:
        raise PlannerError("an identified model needs the session it came from (its runs are "
                           "the prior information); pass session=")
    if session is not None and tuple(session.rig_inputs) != tuple(RIG_INPUTS):
        where = getattr(session, "path", None) or getattr(session, "name", "session")
        raise PlannerError(
            f"{where}: a session without aero channels (a 4-post rig: rig inputs "
            f"{list(session.rig_inputs)}) cannot be planned from yet: the design's information "
            f"is for the 7-post rig's 11 inputs; plan before rig day from the vehicle TOML "
            f"(--vehicle) instead")
    t0 = time.perf_counter()
    make = drive_maker(vehicle, session)
    edges = np.geomspace(band_hz[0], band_hz[1], n_bands + 1)
    f_c = np.sqrt(edges[:-1] * edges[1:])
    if drives is None:
        drives = [make("track", 120.0, seed + 777, "validation-track")]
    drives = list(drives)
    car3 = candidates.third if candidates.third is not None else getattr(model, "third", None)
    car3 = car3 if car3 is not None and car3.elements else None
    # validation runs: the current best setups on the team's drive, at the plan's end
    val_setups = []
    if n_validation:
        corner = corner_shock_ids(library, car3, candidates.third_dampers)
        pool = list(enumerate_setups(library, **({} if corner is None else {
            "shocks": corner})))
        sc = screen_setups(plant, drives[0], [base] + [s for s in pool if s != base], library)
        ranked = score_setups(sc.table, objective, baseline=base.name).table.sort_values("rank")
        names = [n for n in ranked.index if n != base.name][:n_validation]
        by = {s.name: s for s in pool}
        val_setups = [full_names(by[n], library) for n in names]
    cands = candidate_runs(library, base, rig=rig, kinds=kinds, durations_s=durations_s,
                           shocks=shocks, n_shocks=n_shocks, c_bar=plant.cbar_n_s_m,
                           click_levels=click_levels, third=car3,
                           third_dampers=candidates.third_dampers)
    # the validation setups are identification candidates too: the car is in them anyway,
    # so an identification run there costs its duration and no swap of its own
    cands += validation_candidates(val_setups, cands, base, rig, kinds, durations_s)
    cheapest = min(c.cost_min for c in cands)
    if budget_min < cheapest:
        raise PlannerError(f"a budget of {budget_min:g} min is shorter than one run (the "
                           f"cheapest candidate, {cands[0].name}, takes {cheapest:.3g} min); "
                           "give more time or shorter durations_s")
    setups = list(dict.fromkeys(c.setup for c in cands))
    ref_drives = {k: make(k, 120.0, seed + 1000 + j, f"reference {k}")
                  for j, k in enumerate(kinds)}
    info, powers = candidate_information(plant, setups, list(kinds), ref_drives, library,
                                         edges, f_c, third=_third_dampers(setups, car3, library))
    M0 = (session_information(session, plant.cbar_n_s_m, edges) if session is not None
          else np.zeros((n_bands, 11, 11), dtype=complex))
    s_index = {s: i for i, s in enumerate(setups)}
    k_index = {k: j for j, k in enumerate(kinds)}
    Mc = np.stack([c.duration_s * info[s_index[c.setup], k_index[c.kind]] for c in cands])
    val_info = None
    if val_setups:
        vi, _ = candidate_information(plant, val_setups, ["validation"],
                                      {"validation": drives[0]}, library, edges, f_c,
                                      third=_third_dampers(val_setups, car3, library))
        val_info = drives[0].duration_s * vi[:, 0]

    # scaling: unit diagonal of the whole candidate set's information per band
    total = hermitian(M0 + Mc.sum(axis=0))
    dg = np.sqrt(np.maximum(np.real(np.einsum("kii->ki", total)), 1e-300))
    D = 1.0 / dg  # (nb, 11)

    def scale(M):
        return M * D[..., :, None] * D[..., None, :]

    Mc_s, M0_s = scale(Mc), scale(M0)
    M_val = scale(val_info).sum(axis=0) if val_info is not None else 0.0
    _check_identifiable(scale(total), base, cands, library, plant, f_c)

    W_s = None
    if criterion == "decision":
        W_s = scale(decision_weight_matrices(plant, ident_model, library, base, objective,
                                             drives[0], f_c, edges, M0, powers[0], noise,
                                             top))
    # the rig time: the validation runs close the plan and their changes from the run before
    # count (the greedy's `tail`), the baseline repeats are reserved; the identification runs
    # must identify on their own (Eq. 17), without the validation runs' information
    tail = [(val_setups[k], drives[0].duration_s) for k in swap_order(val_setups, base, rig)]
    short = min(durations_s) / 60 + rig.run_overhead_min
    reserve = short * max(1, int(6 // baseline_every)) if baseline_every else 0.0
    budget_id = budget_min - reserve
    val_min = sequence_cost([], cands, base, rig, tail)
    cost = np.array([sequence_cost([c], cands, base, rig, tail) - val_min
                     for c in range(len(cands))])  # each run's own rig time, before the tail
    if budget_id - val_min < cost.min() - 1e-9:
        if val_setups:
            _refuse_validation(budget_min, reserve, val_min, cands, base, rig, tail)
        raise PlannerError(f"the baseline repeats leave {budget_id:.3g} min of {budget_min:g} "
                           "for identification, less than one run; give more time or repeat "
                           "the baseline less often")
    groups = np.array_split(np.arange(n_bands), n_design_bands)
    relaxed, val_relaxed, status, solve_s = relaxed_design(
        Mc_s, M0_s, cost, budget_id - val_min, criterion, W_s, groups)
    t_greedy = time.perf_counter()
    greedy_ref = greedy_design(Mc_s, M0_s, cands, base, rig, budget_id, criterion, W_s,
                               tail=tail)
    greedy_s = time.perf_counter() - t_greedy
    # rounding: the relaxed counts rounded and fitted to the budget, then filled greedily;
    # the greedy is myopic (a two-corner swap can block the all-four one an identifying plan
    # needs), so it also starts from every one-run core that varies all four corners (or
    # sets up a validation run), and the identifying plan with the best criterion wins
    end = tail[0][0] if tail else None
    starts = [[]]
    if relaxed is not None:
        counts = np.floor(relaxed + 0.5).astype(int)
        start = [c for c in np.flatnonzero(counts) for _ in range(counts[c])]
        order = swap_order([cands[c].setup for c in start], base, rig, end)
        starts.append(fit_budget([start[k] for k in order], Mc_s, M0_s, cands, base, rig,
                                 budget_id, criterion, W_s, tail))
    else:
        log.warning("design: the relaxed problem's status is %r; greedy designs stand in",
                    status)
    val_ids = {setup_key(s) for s in val_setups}
    cores = [c for c, cand in enumerate(cands)
             if (len(cand.changed) == 4 or setup_key(cand.setup) in val_ids)
             and cand.duration_s == min(durations_s)]

    def select(budget_id):
        """The identifying plan with the best criterion of every start within `budget_id`:
        (identifies, sequence, its information)."""
        best = None
        for st0 in starts + [[c] for c in cores]:
            st = fit_budget(st0, Mc_s, M0_s, cands, base, rig, budget_id, criterion, W_s, tail)
            if st0 and not st:  # a start that does not fit: the empty one stands for it
                continue
            seq = greedy_design(Mc_s, M0_s, cands, base, rig, budget_id, criterion, W_s,
                                start=st, tail=tail)
            # the fill may have left swaps
            order = swap_order([cands[c].setup for c in seq], base, rig, end)
            seq = fit_budget([seq[k] for k in order], Mc_s, M0_s, cands, base, rig, budget_id,
                             criterion, W_s, tail)
            seq = greedy_design(Mc_s, M0_s, cands, base, rig, budget_id, criterion, W_s,
                                start=seq, tail=tail)
            M = M0_s + sum((Mc_s[c] for c in seq), np.zeros_like(M0_s))
            key = (_identifies(M), criterion_value(M, criterion, W_s))
            if best is None or key > best[0]:
                best = (key, seq, M)
        return best[0][0], best[1], best[2]

    # the baseline repeats go between the identification runs, and going to the baseline and
    # back is rig time too: when the scheduled plan overruns, the identification budget is
    # bisected for the most that fits
    lo, hi, b_id, found = val_min + float(cost.min()), budget_id, budget_id, None
    for attempt in range(_REPEAT_ATTEMPTS):
        identifies, seq, id_M = select(b_id)
        if attempt == 0:
            if not seq:
                raise PlannerError(f"a budget of {budget_min:g} min buys no run that adds "
                                   "information; give more time")
            if not identifies and val_setups:
                _refuse_validation(budget_min, reserve, val_min, cands, base, rig, tail)
            _check_plan_identifiable(id_M, budget_min, cands, rig)
        scheduled = schedule_runs(seq, cands, val_setups, base, rig, make, drives[0],
                                  baseline_every, min(durations_s), seed, Mc_s, val_info, scale)
        end_min = scheduled[0][-1].start_min + scheduled[0][-1].duration_s / 60
        fits = end_min <= budget_min + 1e-9
        log.debug("design: %.1f min for identification: %d runs, %s, the schedule ends at "
                  "%.1f min", b_id, len(seq), "identifying" if identifies else
                  "not identifying", end_min)
        if seq and identifies and fits:
            found = (seq, id_M, scheduled)
            if attempt == 0:
                break
        if fits or not identifies:  # it fits, or needs more time to identify: try more
            lo = b_id
        else:
            hi = b_id
        b_id = (lo + hi) / 2
    if found is None:
        raise PlannerError(
            f"a budget of {budget_min:g} min cannot hold identification runs that separate "
            f"every corner's shock path with a baseline repeat after every {baseline_every} "
            "run(s) (each repeat swaps the baseline in and out again); repeat the baseline "
            "less often (--baseline-every) or give more time")
    seq, id_M, (runs, drives_out, infos) = found
    preds = run_predictions(model, ident_model, runs, drives_out, library, objective,
                            None if car3 is None else ElementOptions(
                                third=car3, bump_stops=candidates.bump_stops))
    runs = criterion_shares(runs, infos, M0_s, criterion, W_s)
    curve = criterion_curve(runs, infos, M0_s, criterion, W_s)
    values = {"prior": criterion_value(M0_s, criterion, W_s) if session is not None else None,
              "relaxed": (criterion_value(M0_s + np.einsum("c,ckij->kij", relaxed, Mc_s),
                                          criterion, W_s) if relaxed is not None else None),
              "relaxed_design_bands": val_relaxed,
              "plan": float(curve["criterion"].iloc[-1]),
              "greedy": criterion_value(M0_s + M_val + sum((Mc_s[c] for c in greedy_ref),
                                                           np.zeros_like(M0_s)), criterion, W_s),
              "greedy_min": sequence_cost(greedy_ref, cands, base, rig, tail)}
    chosen = np.bincount(np.asarray(seq, dtype=int), minlength=len(cands))
    relaxed_df = pd.DataFrame({"candidate": [c.name for c in cands],
                               "runs": relaxed if relaxed is not None else np.nan,
                               "cost_min": cost, "chosen": chosen}).set_index("candidate")
    total_min = runs[-1].start_min + runs[-1].duration_s / 60 if runs else 0.0
    solver = {"status": status, "solver": "CLARABEL", "solve_s": solve_s, "greedy_s": greedy_s,
              "design_s": time.perf_counter() - t0, "n_candidates": len(cands),
              "n_bands": n_bands, "n_design_bands": n_design_bands}
    settings = {"car": getattr(vehicle, "name", None) or getattr(ident_model, "name", "model"),
                "rig": rig.name, "date": date, "crate": library.source,
                "objective": objective.name, "budget_min": budget_min,
                "kinds": list(kinds), "durations_s": list(durations_s), "noise": noise,
                "baseline_every": baseline_every, "n_validation": n_validation,
                "session": getattr(session, "name", None), "band_hz": tuple(band_hz)}
    return ExperimentPlan(runs=tuple(runs), drives=drives_out, library=library, baseline=base,
                          criterion=criterion, budget_min=float(budget_min),
                          total_min=float(total_min), values=values, relaxed=relaxed_df,
                          predictions=preds, curve=curve, solver=solver, rig=rig,
                          settings=settings,
                          rationale=plan_rationale(runs, base, session=session is not None),
                          third=car3, bump_stops=_heave_spring_library(car3, candidates, model))


def _check_identifiable(total_s, base, cands, library, plant, f_c):
    """Refuse a candidate set (with the prior) that cannot identify all 11 inputs (Eq. 17)."""
    lam = np.linalg.eigvalsh(hermitian(total_s))
    bad = lam[:, 0] < _RANK_TOL * np.maximum(lam[:, -1], 1e-300)
    if not bad.any():
        return
    diag = np.real(np.einsum("kii->ki", total_s))
    dead = [c for i, c in enumerate(CORNERS) if np.all(diag[:, 7 + i] < _RANK_TOL)]
    if dead:
        why = (f"corner(s) {dead}: no candidate run changes the shock force there (every crate "
               f"shock at those corners acts like the baseline's linear rate "
               f"{np.round(plant.cbar_n_s_m, 1).tolist()} N/(m/s), so dF = 0)")
    else:
        why = (f"at {np.round(f_c[bad][:3], 2).tolist()} Hz the shock forces of every "
               "candidate are the same linear function of the rig inputs")
    raise PlannerError(
        f"no plan from this crate can identify the shock inputs (seed paper Eq. 17): {why}; add "
        "to the crate a shock whose damping clearly differs from the baseline's (or a "
        "nonlinear one), or give a session whose runs already swap those corners")


def _refuse_validation(budget, reserve, val_min, cands, base, rig, tail):
    """Refuse a budget that cannot hold both the validation runs and identifying runs."""
    short = min(c.duration_s for c in cands)
    base0 = [c for c, cand in enumerate(cands) if not cand.changed and cand.duration_s == short]
    need = min((sequence_cost(base0[:1] + [c], cands, base, rig, tail) for c, cand
                in enumerate(cands) if len(cand.changed) == 4 and cand.duration_s == short),
               default=float("nan")) + reserve
    more = (f"give a budget of {math.ceil(need - 1e-9):d} min or more (--budget-min: the "
            "baseline and a four-corner swap besides the validation runs)"
            if math.isfinite(need) else "give more time")
    repeats = f" and {reserve:.3g} min of baseline repeats" if reserve else ""
    raise PlannerError(
        f"a budget of {budget:g} min cannot hold both the {len(tail)} validation run(s) "
        f"({val_min:.3g} min with their swaps{repeats}) and identification runs that separate "
        "every corner's shock path (seed paper Eq. 17: the shock forces must vary apart from "
        "the rig inputs, so the identification runs need other shocks than the baseline's at "
        "every corner; the validation runs, on the team's drive, do not stand in for them); "
        f"{more}, or fewer validation runs (--validate)")


def _identifies(M):
    """Whether scaled information matrices have full rank in every band."""
    lam = np.linalg.eigvalsh(hermitian(M))
    return bool(np.all(lam[:, 0] >= _RANK_TOL * np.maximum(lam[:, -1], 1e-300)))


def _check_plan_identifiable(plan_M, budget, cands, rig):
    if _identifies(plan_M):
        return
    short = min(c.duration_s for c in cands) / 60 + rig.run_overhead_min
    need = 2 * short + 4 * rig.swap_min
    if budget < need:
        raise PlannerError(
            f"a budget of {budget:g} min cannot buy runs that identify all 11 inputs (Eq. 17: "
            f"the shock forces must vary apart from the rig inputs at every corner); the "
            f"baseline and one run with all four corners swapped take about {need:.0f} min "
            f"with this rig (swap {rig.swap_min:g} min a corner); give more time")
    # the time is there: the runs themselves do not separate the shock forces
    raise PlannerError(
        f"the runs a budget of {budget:g} min buys (the baseline and a four-corner swap take "
        f"about {need:.0f} min) still do not identify all 11 inputs at every band (Eq. 17): "
        "the crate's shocks give shock forces that do not vary apart from the rig inputs "
        "(shocks too alike, or a drive that saturates them: check the drive's units and "
        "level); add a shock unlike the baseline to the crate, or check the drive")
