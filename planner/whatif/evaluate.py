"""What-if evaluation: every setup under every condition, scored against the baseline there.

:func:`evaluate_whatif` groups the conditions by plant and drive (one simulation call per
group), evaluates each group's setups in this process or, cut into chunks of setups, as
tasks of a :mod:`planner.runner` runner on Dask, scores every condition with the
objective against the baseline setup in that condition, and returns a :class:`WhatIf`
with the long table, the robust ranks (:func:`planner.whatif.robust.robust_table`) and
the conditions. How a condition changes the plant, drive and shocks is in
:mod:`planner.whatif.conditions`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy.stats import spearmanr
from threadpoolctl import threadpool_info, threadpool_limits
from tqdm.auto import tqdm

from ident.data.channels import CORNERS
from ident.data.drive import Drive
from ident.models.library import ShockLibrary
from planner.errors import PlannerError
from planner.objective import Objective, default_objective, score_setups
from planner.elements import (ELEMENT_COLUMNS, THIRD_COLUMNS, loop_arguments,
                              model_setup_elements, model_setup_third)
from planner.options import ElementOptions, LoopOptions, RunOptions, as_options
from planner.plant import as_loop_plant
from planner.predict import predict_setups, prepare_drive
from planner.runner import KERNEL_LOCK, SCHEDULER_NONE, start_runner
from planner.screen import describe_agreement, screen_setups
from planner.setups import resolve_baseline
from planner.text import format_table
from planner.whatif.click_factors import ADJUSTER_KINDS, check_adjuster_factors, tolerance_table
from planner.whatif.conditions import (
    ShockVariants,
    StopVariants,
    condition_drive,
    condition_effect,
    condition_notes,
    condition_plant,
    condition_setups,
    drive_key,
    known_params,
    plant_key,
)
from planner.whatif.robust import FRAGILE_SHARE, RANK_TOLERANCE, robust_table
from planner.whatif.spec import THIRD_FACTOR_KINDS, PerturbationSet

__all__ = [
    "TASKS_PER_THREAD",
    "MIN_TASK_EVALUATIONS",
    "WhatIf",
    "evaluate_whatif",
]

# the name of the module before it became a package: ``shockplan -v`` prints it
log = logging.getLogger("planner.whatif")

#: On a cluster: tasks per worker thread at least (condition groups cut into chunks), so
#: that none idles at the end.
TASKS_PER_THREAD = 4
#: On a cluster: fewest evaluations (setup x condition) a task is cut to, per method (a
#: task redoes the drive's rig response, about 0.1 s, or the screening operands).
MIN_TASK_EVALUATIONS = {"time": 32, "screening": 2000}


# ----------------------------------------------------------------------------------------------
# evaluation
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class WhatIf:
    """The result of :func:`evaluate_whatif`.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per (drive, perturbation, setup): ``drive``, ``perturbation``,
        ``setup``, the shock ids, the metrics (SI), ``score``, ``score_<group>``,
        ``feasible``, ``violations``, ``rank`` (within the condition),
        ``score_change`` and ``rank_change`` against the same setup's nominal condition
        (the first drive, no perturbation), and ``<metric>_change_pct``.
    robust : pandas.DataFrame
        One row per setup, best mean score first: ``nominal_rank``, ``nominal_score``,
        ``mean_score``, ``worst_score``, ``mean_rank``, ``best_rank``, ``worst_rank``,
        ``best_share`` (share of conditions it ranks first), ``moved_share`` (share of
        conditions its rank moves more than ``rank_tolerance`` places),
        ``feasible_share``, ``fragile``, ``rank_mean_score``, ``rank_worst_score``.
    perturbations : PerturbationSet
    conditions : pandas.DataFrame
        One row per condition (``drive``, ``perturbation``) with the factor values.
    baseline : str
    objective : planner.objective.Objective
    tolerance : pandas.DataFrame or None
        With ``click`` or ``fade`` factors: per setup, factor and quantity (score, rank,
        metric) the nominal, lowest, highest and worst value and the spread over the
        nominal condition and the factor's conditions on the first drive
        (:func:`planner.whatif.click_factors.tolerance_table`); None without such factors.
    settings : dict
        ``method``, ``oversample``, ``band_hz``, ``rank_tolerance``, ``fragile_share``,
        ``n_evaluations``, ``elapsed_s``, ``model``, ``drives``; with click factors
        ``clipped`` (how many rows have a click clipped at a range end) and ``notes``;
        where it ran:
        ``scheduler`` (``"none"``, ``"local"``, ``"address"`` or ``"client"``),
        ``address``, ``n_workers`` and ``n_tasks`` (neither these nor the timings are
        written to the files).
    """

    table: pd.DataFrame
    robust: pd.DataFrame
    perturbations: PerturbationSet
    conditions: pd.DataFrame
    baseline: str
    objective: object
    settings: dict = field(default_factory=dict)
    tolerance: pd.DataFrame | None = None

    @property
    def fragile(self):
        """Names of the setups whose rank is fragile, in robust order."""
        return list(self.robust.index[self.robust["fragile"]])

    def summary(self, n=10):
        """The study for a terminal: its size and time, the baseline, the nominal
        condition's check in the time domain (screening), the robust ranking's best `n`
        setups, the fragile ranks and the notes.

        Parameters
        ----------
        n : int
            Setups in the table.

        Returns
        -------
        str
        """
        st = self.settings
        rob = self.robust
        lines = [f"{st['n_setups']} setups x {st['n_conditions']} conditions "
                 f"({self.perturbations.design}, {st['method']}): {st['n_evaluations']} "
                 f"evaluations in {st['elapsed_s']:.1f} s"
                 + (f" on Dask ({st['scheduler']}, {st['n_workers']} worker(s))"
                    if st.get("scheduler", "none") != "none" else "")
                 + f"; baseline '{self.baseline}'"]
        if "agreement" in st:
            agree = st["agreement"]
            lines.append("nominal condition checked in the time domain: "
                         + describe_agreement(agree, what=None)
                         + ("" if agree["same_best"] else
                            " (--method time, the reference)"))
        rows = []
        for name, r in rob.head(n).iterrows():
            rows.append((name, int(r["nominal_rank"]), f"{r['mean_score']:.4f}",
                         f"{r['worst_score']:.4f}",
                         f"{int(r['best_rank'])}-{int(r['worst_rank'])}",
                         f"{100 * r['moved_share']:.0f} %", "FRAGILE" if r["fragile"] else "-"))
        lines.append(format_table(rows, ["setup", "nominal", "mean score", "worst score",
                                         "ranks", "moved", "rank"]))
        fr = self.fragile
        lines.append(f"fragile ranks: {', '.join(fr)}" if fr else
                     f"no fragile ranks (rank moved > {st['rank_tolerance']} places in more "
                     f"than {100 * st['fragile_share']:.0f} % of conditions)")
        lines += [f"note: {note}" for note in st.get("notes", ())]  # clicks clipped, ...
        return "\n".join(lines)

    def condition(self, perturbation="nominal", drive=None):
        """The rows of one condition (default the nominal one), indexed by setup."""
        d = self.settings["drives"][0] if drive is None else drive
        t = self.table[(self.table["perturbation"] == perturbation) & (self.table["drive"] == d)]
        if t.empty:
            raise PlannerError(f"no condition ({d!r}, {perturbation!r}); conditions are "
                               f"{self.conditions.index.tolist()[:5]}...")
        return t.set_index("setup")


def _as_drives(drives):
    if isinstance(drives, Drive):
        return [drives]
    drives = list(drives)
    if not drives or not all(isinstance(d, Drive) for d in drives):
        raise TypeError("drives must be an ident.data.drive.Drive or a non-empty sequence of them")
    names = [d.name for d in drives]
    if len(set(names)) != len(names):
        raise PlannerError(f"the drives' names {names} repeat; give each drive its own name")
    return drives


def _evaluate_group(plant, drive, setups, library, method, loop, elements):
    """Metrics of one condition group's setups (a list of condition setups), SI.

    Returns
    -------
    pandas.DataFrame
        :func:`planner.predict.predict_setups`' (``method="time"``) or
        :func:`planner.screen.screen_setups`' table: one row per setup, in order.
    """
    if method == "time":
        return predict_setups(plant, drive, setups, library, loop=loop,
                              elements=elements).table
    elem = model_setup_elements(setups, plant, elements)
    return screen_setups(plant, drive, setups, library, band_hz=loop.band_hz,
                         **loop_arguments(elem)).table


def _nominal_agreement(plant, drive, setups, library, objective, baseline, nominal, metrics,
                       loop, elements):
    """Screening's nominal scores against the time domain's on the same setups.

    Returns
    -------
    dict
        ``spearman`` (NaN for fewer than 3 setups), ``n``, ``same_best``,
        ``screening_best``, ``time_best``, ``time_best_screening_rank``, ``top`` (every
        setup) and ``score_gap``: what :func:`planner.screen.describe_agreement` reads.
    """
    td = predict_setups(plant, drive, setups, library, loop=loop, elements=elements).table
    td_score = score_setups(td[metrics], objective, baseline=baseline).table["score"]
    scr_score = nominal.loc[td_score.index, "score"]
    rho = (float(spearmanr(scr_score, td_score).statistic) if len(td_score) > 2
           else float("nan"))
    time_best, screening_best = td_score.idxmin(), scr_score.idxmin()
    return {"spearman": rho, "n": int(len(td_score)), "same_best": bool(time_best == screening_best),
            "time_best": time_best, "screening_best": screening_best,
            # every setup is checked: how far the bests differ tells a near-tie from a miss
            "time_best_screening_rank": int((scr_score < scr_score[time_best]).sum()) + 1,
            "top": int(len(td_score)),
            "score_gap": float(td_score[screening_best] / td_score[time_best] - 1.0)}


def _group_setups(setups, members, effects, variants, resolved=None, stop_variants=None,
                  third=None):
    """The setups of a condition group: every setup under every member condition."""
    cond_setups = []
    for (dj, pj) in members:
        cond_setups += condition_setups(setups, effects[pj], variants, f"{dj}:{pj}", resolved,
                                        stop_variants, third)
    return cond_setups


def _check_third_factors(factors, car, method, src):
    """Refuse third-element factors the car or the method cannot take (one line each)."""
    for f in factors:
        if f.kind not in THIRD_FACTOR_KINDS:
            continue
        where = f"{src}: factor {f.name!r} (kind {f.kind!r})"
        if car is None or not car.elements:
            raise PlannerError(f"{where} changes a third element but the model has none; "
                               "remove the factor, or use a model identified from a session "
                               "that declares third_elements (or give ElementOptions.third)")
        declared = car.elements.elements
        for t in f.targets:
            element = t if f.kind in ("third_scale", "third_lag") else f"heave_{t}"
            if element not in declared:
                key = "elements" if f.kind in ("third_scale", "third_lag") else "axles"
                raise PlannerError(f"{where}: key {key!r} names {t!r} but the car declares no "
                                   f"{element} (it has {list(declared)}); choose among those")
        if method != "time":
            raise PlannerError(f"{where}: the what-if's screening leaves third elements out; "
                               "use method = 'time' (--method time)")


def _group_table(pred_table, by_name, drives, perturbations, third_columns=None):
    """A group's rows of the what-if table from its metrics table (names carry the tags)."""
    t = pred_table.copy()
    t.insert(0, "setup", [n.split("\x1f")[0] for n in t.index])
    tag = [n.split("\x1f")[1] for n in t.index]
    t.insert(0, "perturbation", [perturbations.perturbations[int(x.split(":")[1])].name
                                 for x in tag])
    t.insert(0, "drive", [drives[int(x.split(":")[0])].name for x in tag])
    # the table's shock ids: the setup's own (the variants are internal)
    for i, c in enumerate(CORNERS):
        t[c] = [by_name[n].ids()[i] for n in t["setup"]]
    if third_columns is not None:  # the third elements' too (a scaled damper is a variant)
        for c in third_columns.columns:
            if c in t.columns:
                t[c] = third_columns.loc[t["setup"], c].to_numpy()
    t["_order"] = [int(x.split(":")[0]) * 10**7 + int(x.split(":")[1]) for x in tag]
    return t


def _blas_threads():
    """This process's BLAS thread count per library prefix (``threadpoolctl``)."""
    return {i["prefix"]: int(i["num_threads"]) for i in threadpool_info()
            if i.get("user_api") == "blas"}


def _whatif_task(plant, drive, effect, where, setups, library, extra, method, loop, blas,
                 elements):
    """Metrics of a chunk of a condition group's setups (a task on a Dask worker).

    Parameters
    ----------
    plant : ident.models.lti.LoopPlant
        The condition's plant (built by the client).
    drive : ident.data.drive.Drive
        The prepared nominal drive; the condition's drive is derived here
        (:func:`planner.whatif.conditions.condition_drive`: a window, channel scales,
        elementwise).
    effect : planner.whatif.conditions.ConditionEffect
    where : str
        The condition's name for error messages.
    setups : list of planner.setups.Setup, shape (n,)
        Condition setups (names ``"<setup>\\x1f<drive>:<perturbation>"``).
    library : ident.models.library.ShockLibrary
        The crate.
    extra : list of ident.models.shocks.ShockModel
        The scaled or lagged shocks `setups` use.
    method, loop
        As :func:`evaluate_whatif`.
    blas : dict of str -> int
        The client's BLAS threads per library: the screening operands' products differ
        in the last bits with the BLAS thread count, so the worker uses the client's (a
        Dask worker process starts with one).
    elements : planner.options.ElementOptions
        The real car's elements (the model's fixed: :meth:`ElementOptions.for_model`).

    Returns
    -------
    pandas.DataFrame, shape (n, 4 + n_metrics)
        The metrics only (no time histories).
    """
    lib = ShockLibrary(library.entries() + list(extra), source=library.source) \
        if extra else library
    with KERNEL_LOCK:
        drive = condition_drive(drive, effect, where)
        with threadpool_limits(limits=blas):
            return _evaluate_group(plant, drive, setups, lib, method, loop, elements)


class _LazyTasks:
    """Task arguments built when the runner submits them (bounded memory on the client)."""

    def __init__(self, specs, make):
        self.specs = specs
        self.make = make

    def __len__(self):
        return len(self.specs)

    def __iter__(self):
        return (self.make(*spec) for spec in self.specs)


def _is_serial(scheduler, client):
    """True when `scheduler`/`client` ask for this process only (the default)."""
    return client is None and (scheduler is None or (
        isinstance(scheduler, str) and scheduler.strip().lower() in SCHEDULER_NONE))


def _task_specs(sizes, chunk):
    """``(group, start, stop)`` of every task: each group cut into near-equal chunks."""
    specs = []
    for g, n in enumerate(sizes):
        step = math.ceil(n / math.ceil(n / chunk))
        specs += [(g, a, min(a + step, n)) for a in range(0, n, step)]
    return specs


def evaluate_whatif(model, drives, setups, library, perturbations, *, objective=None,
                    baseline=None, method="time", loop=LoopOptions(),
                    nominal_spring_rates_n_m=None, rank_tolerance=RANK_TOLERANCE,
                    fragile_share=FRAGILE_SHARE, elements=ElementOptions(), run=RunOptions(),
                    progress=False):
    """Evaluate every setup under every perturbation of a what-if design.

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
        Identified or known. Spring and anti-roll bar changes act on any (exactly: a
        feedback through the shock travel on identified models, the parameters on known
        ones); vehicle-parameter changes need a known model.
    drives : ident.data.drive.Drive or sequence of Drive
        Every condition is evaluated on every drive; the first is the nominal one.
    setups : sequence of planner.setups.Setup
        The setups (e.g. the top of a ranking); the baseline is added if missing.
    library : ident.models.library.ShockLibrary
    perturbations : PerturbationSet
    objective : planner.objective.Objective, optional
        Default :func:`planner.objective.default_objective`.
    baseline : str or Setup, optional
        The setup scores are normalized by, in each condition, read by
        :func:`planner.setups.resolve_baseline` (a setup, a listed setup's name, one
        shock id or four ``"LF,RF,LR,RR"``); default the objective's, else the first
        setup.
    method : {"time", "screening"}
        ``time``: the nonlinear shocks in the time domain (:func:`planner.predict.
        predict_setups`, the reference); ``screening``: frequency-domain screening
        (:func:`planner.screen.screen_setups`), about 100x faster, for large sweeps.
    loop : planner.options.LoopOptions
        The time-domain loop (``oversample``: internal steps per sample) and the metric
        band ``band_hz`` [Hz] (the screening's too).
    nominal_spring_rates_n_m : array_like, shape (4,), optional
        The identified car's spring wheel rates [N/m], if known: a change that would
        make one negative is refused.
    rank_tolerance, fragile_share : int, float
        See the module docstring (fragile ranks).
    elements : planner.options.ElementOptions
        The real car's elements, as :func:`planner.predict.predict_setups` (default: the
        model's). ``packer`` and ``bump_stop`` factors change each setup's resolved
        packers and stops (:func:`planner.whatif.conditions.condition_setups`).
    run : planner.options.RunOptions
        Where the condition groups are evaluated: ``scheduler`` None or ``"none"``
        (default) in this process, one group after the other; ``"local"`` on a new
        :class:`dask.distributed.LocalCluster` (``n_workers``, default one per core,
        closed at the end; ``processes``: workers as processes, default, or threads); or
        a scheduler address (``"tcp://host:8786"``). Checked before any work: an unknown
        value or an unreachable address raises at once. ``client``: an existing client to
        use instead (not closed). ``chunk_size``: evaluations (setup x condition) per
        task at most on a cluster; default the groups cut so that every worker thread
        gets about four tasks (at least :data:`MIN_TASK_EVALUATIONS` evaluations a task).
        Ignored in this process.
    progress : bool
        Show a progress bar over the condition groups (over the tasks on a cluster).

    Returns
    -------
    WhatIf
        ``settings["scheduler"]`` says where it ran (``"none"``, ``"local"``,
        ``"address"`` or ``"client"``).

    Raises
    ------
    PlannerError
        On a bad option, a bad perturbation for the model, an unknown scheduler or an
        unreachable one (raised before any work).
    TypeError
        On arguments of the wrong type.

    Notes
    -----
    On a cluster the tables are the one-process tables bit for bit, whatever the
    workers, the chunk size or the order tasks finish in: the plants are built here as in
    one process, every setup is simulated on its own (a chunk of a group gives the rows
    of the whole group), the workers compute the drive's rig response with this
    process's BLAS thread count (its last bits depend on it) and the rows are put back
    in group order. Workers
    on other machines must run the same library builds on the same kind of CPU. Memory:
    a task sends back its metrics table only (no time histories); at most
    ``2 * threads + 1`` tasks are in flight, and their arguments are built as they are
    submitted.
    """
    t_start = time.perf_counter()
    loop = as_options(loop, LoopOptions, "loop", "whatif")
    elements = as_options(elements, ElementOptions, "elements", "whatif")
    run = as_options(run, RunOptions, "run", "whatif")
    if elements.has_choices:
        raise PlannerError("whatif: evaluates the setups given; enumerate bump-stop and "
                           "packer choices with planner.elements.vary_elements first")
    oversample, band_hz, chunk_size = loop.oversample, loop.band_hz, run.chunk_size
    scheduler, client = run.scheduler, run.client
    if not isinstance(perturbations, PerturbationSet):
        raise TypeError("perturbations must be a PerturbationSet (read_perturbations or "
                        f"perturbation_set), got {type(perturbations).__name__}")
    if method not in ("time", "screening"):
        raise PlannerError(f"method {method!r} is unknown; use 'time' or 'screening'")
    if chunk_size is not None and (isinstance(chunk_size, bool)
                                   or not isinstance(chunk_size, (int, np.integer))
                                   or chunk_size < 1):
        raise PlannerError(f"chunk_size={chunk_size!r} must be a positive integer "
                           "(evaluations per task), e.g. 64, or None for the default")
    drives = _as_drives(drives)
    if len(drives) > 1 and any(f.kind == "drive_file" for f in perturbations.factors):
        raise PlannerError("a drive_file factor replaces the drive; give one drive with it")
    objective = default_objective() if objective is None else objective
    if not isinstance(objective, Objective):
        raise TypeError(f"objective must be a planner.objective.Objective, got "
                        f"{type(objective).__name__}")
    setups = list(setups)
    if not setups:
        raise PlannerError("no setups for the what-if; give a setups CSV or a ranking")
    for s in setups:
        s.resolve(library)
    base = resolve_baseline(baseline, library, setups=setups, default=objective.baseline)
    if base.name not in {s.name for s in setups}:
        setups = [base] + setups
    resolved = model_setup_elements(setups, model, elements)
    src = perturbations.settings.get("source") or "what-if"
    _check_third_factors(perturbations.factors, elements.car_third(model), method, src)
    third = (model_setup_third(setups, model, library, elements, where="whatif")
             if any(f.kind in THIRD_FACTOR_KINDS for f in perturbations.factors) else None)
    third_columns = None if third is None else third.columns([s.name for s in setups])
    ekw = elements.for_model(model)  # the workers get the condition's plant only
    names = [s.name for s in setups]
    if len(set(names)) != len(names):
        raise PlannerError("setup names repeat; give each setup its own name")
    adjusting = any(f.kind in ADJUSTER_KINDS for f in perturbations.factors)
    notes = (check_adjuster_factors(perturbations.factors, setups, library,
                                    perturbations.settings.get("source") or "what-if")
             if adjusting else [])
    # the scheduler before any work: a wrong address fails here
    runner = None
    if not _is_serial(scheduler, client):
        runner = start_runner(scheduler, client, run.n_workers, run.processes, "whatif")
    try:
        fs = getattr(model, "fs_hz", None)
        drives = [prepare_drive(d, fs, where=f"drive {d.name!r}") for d in drives]
        base_plant = as_loop_plant(model)
        params = known_params(model)
        if params is not None:  # the known model around its own nominal damping, built once
            base_plant = as_loop_plant(params)
        # group conditions by (plant, drive): one simulation call per group
        effects = [condition_effect(p, perturbations.factors)
                   for p in perturbations.perturbations]
        groups = {}
        for di, d in enumerate(drives):
            for pi, (p, e) in enumerate(zip(perturbations.perturbations, effects)):
                groups.setdefault((plant_key(e), di, drive_key(e)), []).append((di, pi))
        plants, tables = {}, []
        variants = ShockVariants(library)
        stop_variants = StopVariants(elements.library(model))

        def group_ekw():
            """The elements with the stops moved so far (packer changes)."""
            if not stop_variants.extra:
                return ekw
            return replace(ekw, bump_stops=stop_variants.full_library())
        by_name = {s.name: s for s in setups}

        def condition(pkey, members):
            """The plant (built once per key, here) and the name of a group's condition."""
            e0 = effects[members[0][1]]
            where = f"{src}: condition {perturbations.perturbations[members[0][1]].name!r}"
            if pkey not in plants:
                plants[pkey] = condition_plant(model, base_plant, e0, where,
                                               nominal_spring_rates_n_m)
            return plants[pkey], e0, where

        n_eval = 0
        if runner is None:  # this process, one group after the other
            items = list(groups.items())
            if progress:
                items = tqdm(items, desc="what-if", unit="group")
            for (pkey, di, _), members in items:
                plant, e0, where = condition(pkey, members)
                drive = condition_drive(drives[di], e0, where)
                cond_setups = _group_setups(setups, members, effects, variants, resolved,
                                            stop_variants, third)
                lib = variants.full_library()
                pred_table = _evaluate_group(plant, drive, cond_setups, lib, method,
                                             loop, group_ekw())
                n_eval += len(cond_setups)
                tables.append(_group_table(pred_table, by_name, drives, perturbations,
                                           third_columns))
            kind, address, workers, n_tasks = "none", None, 1, len(groups)
        else:
            keys = list(groups)
            sizes = [len(groups[k]) * len(setups) for k in keys]
            chunk = int(chunk_size) if chunk_size is not None else max(
                MIN_TASK_EVALUATIONS[method],
                math.ceil(sum(sizes) / (TASKS_PER_THREAD * runner.n_threads)))
            specs = _task_specs(sizes, chunk)
            drive_refs = [runner.scatter(d) for d in drives]
            lib_ref = runner.scatter(library)
            blas = _blas_threads()
            loop_w = replace(loop, band_hz=tuple(band_hz))
            current = {}  # the group being submitted: its condition setups

            def make(g, a, b):
                pkey, di, _ = keys[g]
                members = groups[keys[g]]
                plant, e0, where = condition(pkey, members)
                if current.get("g") != g:
                    current.clear()
                    current.update(g=g, setups=_group_setups(setups, members, effects,
                                                             variants, resolved, stop_variants,
                                                             third))
                chunk_setups = current["setups"][a:b]
                extra = list({sid: variants.extra[sid] for s in chunk_setups
                              for sid in (*s.ids(), *(s.third or {}).values())
                              if sid in variants.extra}.values())
                return (plant, drive_refs[di], e0, where, chunk_setups, lib_ref, extra,
                        method, loop_w, blas, group_ekw())

            log.info("what-if: %d condition groups, %d evaluations in %d tasks (%s, %d "
                     "worker(s))", len(keys), sum(sizes), len(specs), runner.kind,
                     runner.n_workers)
            parts = [None] * len(specs)
            for j, res in runner.map_unordered(_whatif_task, _LazyTasks(specs, make),
                                               progress, "what-if"):
                parts[j] = res
            for g in range(len(keys)):  # the groups' rows, in group order, as one process
                got = [parts[j] for j, spec in enumerate(specs) if spec[0] == g]
                pred_table = got[0] if len(got) == 1 else pd.concat(got)
                n_eval += len(pred_table)
                tables.append(_group_table(pred_table, by_name, drives, perturbations,
                                           third_columns))
            parts = None
            kind, address, workers, n_tasks = (runner.kind, runner.address, runner.n_workers,
                                               len(specs))
    finally:
        if runner is not None:
            runner.close()
    table = pd.concat(tables).sort_values("_order", kind="stable").drop(columns="_order")
    table = table.reset_index(drop=True)
    metrics = [c for c in table.columns if c not in ("drive", "perturbation", "setup") + CORNERS
               and c not in ELEMENT_COLUMNS and c not in THIRD_COLUMNS]
    n_clipped = 0
    if any(f.kind == "click" for f in perturbations.factors):
        # the clicks clipped at a range end, per (perturbation, setup), said in the table
        clip = {}
        for p, e in zip(perturbations.perturbations, effects):
            for n, text in condition_notes(setups, e, variants).items():
                clip[(p.name, n)] = text
        table["clipped"] = [clip.get((p, n), "") for p, n in
                            zip(table["perturbation"], table["setup"])]
        n_clipped = int((table["clipped"] != "").sum())
        if n_clipped:
            notes.append(f"{n_clipped} of {len(table)} evaluations have a click clipped at the "
                         "end of an adjuster's range (the table's 'clipped' column)")
            log.warning("what-if: %s", notes[-1])
    # score each condition against the baseline in that condition
    scored = []
    for _, cond in table.groupby(["drive", "perturbation"], sort=False):
        sc = score_setups(cond.set_index("setup")[metrics], objective, baseline=base.name).table
        scored.append(pd.concat([cond.reset_index(drop=True),
                                 sc.reset_index(drop=True)], axis=1))
    table = pd.concat(scored, ignore_index=True)
    nominal = table[(table["drive"] == drives[0].name)
                    & (table["perturbation"] == "nominal")].set_index("setup")
    table["score_change"] = table["score"].to_numpy() - nominal.loc[table["setup"], "score"].to_numpy()
    table["rank_change"] = table["rank"].to_numpy() - nominal.loc[table["setup"], "rank"].to_numpy()
    for m in metrics:
        ref = nominal.loc[table["setup"], m].to_numpy(dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            table[f"{m}_change_pct"] = 100.0 * (table[m].to_numpy(dtype=float) / ref - 1.0)
    agreement = None
    if method == "screening":  # the decision checked where it is made: the time domain
        agreement = _nominal_agreement(base_plant, drives[0], setups, library, objective,
                                       base.name, nominal, metrics, loop, ekw)
    robust = robust_table(table, names, rank_tolerance, fragile_share)
    ptab = perturbations.table()
    conditions = pd.concat([ptab.assign(drive=d.name) for d in drives]).reset_index()
    conditions = conditions.set_index(["drive", "perturbation"])
    elapsed = time.perf_counter() - t_start
    settings = {"method": method, "oversample": oversample, "band_hz": tuple(band_hz),
                "rank_tolerance": int(rank_tolerance), "fragile_share": float(fragile_share),
                "n_evaluations": int(n_eval), "n_conditions": int(len(conditions)),
                "n_setups": len(setups), "elapsed_s": elapsed,
                "evaluations_per_s": n_eval / elapsed if elapsed > 0 else float("nan"),
                "model": getattr(base_plant, "name", None), "drives": [d.name for d in drives],
                "design": perturbations.design, "source": perturbations.settings.get("source"),
                "scheduler": kind, "address": address, "n_workers": int(workers),
                "n_tasks": int(n_tasks)}
    if adjusting:
        settings["clipped"] = n_clipped
        settings["notes"] = list(notes)
    if agreement is not None:
        settings["agreement"] = agreement
        log.info("what-if by screening, nominal condition checked in the time domain: "
                 "Spearman %.3f over %d setups, same best: %s", agreement["spearman"],
                 agreement["n"], agreement["same_best"])
    log.info("what-if: %d setups x %d conditions (%d evaluations, %s, scheduler %s) in %.1f s",
             len(setups), len(conditions), n_eval, method, kind, elapsed)
    tolerance = (tolerance_table(table, perturbations, drives[0].name) if adjusting
                 else None)
    return WhatIf(table=table, robust=robust, perturbations=perturbations, conditions=conditions,
                  baseline=base.name, objective=objective, settings=settings,
                  tolerance=tolerance)
