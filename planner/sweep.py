"""Sweeps: screen very large sets of setups on several models and drives, in chunks, on one
process or a Dask cluster, then simulate the best in the time domain and rank them.

``sweep_setups(models, drives, library, ...)`` is :func:`planner.rank.rank_setups` made for
enumerations of hundreds of thousands of setups (every 4-corner combination of a 30-shock
crate: 30^4 = 810,000) times several drives and models:

1. The setups are a :class:`planner.setups.SetupSpace` (:func:`planner.setups.setup_space`,
   re-exported here): the one enumeration that :func:`planner.setups.enumerate_setups`
   decodes (same order, same inventory filter, same names), decoded here lazily, chunk by
   chunk, from integer codes; no :class:`~planner.setups.Setup`
   object exists but for the setups finally simulated. A given list of setups works too.
2. Every (model, drive) pair, a *case*, is prepared once: the model's loop plant, the drive
   at the model's rate and the screening operands (:func:`planner.screen.screen_operands`).
   The baseline setup is screened per case; its metrics normalize the objective in that
   case (like :mod:`planner.whatif`).
3. Chunks of the space are screened (:func:`planner.screen.screen_packed`, the compiled
   kernel of :func:`~planner.screen.screen_setups`) in every case and scored; a setup's
   sweep score is the mean (or the worst) of its case scores, and it is feasible when it
   is feasible in every case and the crate's ``count`` can build it. A chunk sends back
   every setup's score and feasibility (17 bytes a setup) and the metrics of its best
   ``n_top`` setups only; the driver keeps the best ``n_top`` of all chunks so far.
4. The best ``top_share`` (1 %) of the screened setups and the baseline are simulated in
   every case with :func:`planner.predict.predict_setups`, scored with the objective
   (:func:`planner.objective.score_setups`, as ``rank_setups`` does) and ranked.

Where it runs (``scheduler``): ``"local"`` (default) starts a
:class:`dask.distributed.LocalCluster` of worker processes, one per core, each with one
compiled-kernel thread; an address (``"tcp://host:8786"``) joins a running scheduler;
``"none"`` runs everything in this process. The cases, the library and the space are
scattered to the workers once; a task names only a range of the space. The same runner
(:func:`planner.runner.start_runner`) serves ``rank --scheduler`` (:func:`screen_setups_on`) and ``whatif
--scheduler`` (:func:`planner.whatif.evaluate_whatif`, a task per chunk of a condition
group).

Determinism
-----------
The results do not depend on the scheduler, the number of workers, the chunk size or the
order in which chunks finish, bit for bit:

- the screening kernel computes every setup on its own from the same operands (built once,
  in this process, and shipped), and the scores are elementwise sums in a fixed order (no
  BLAS reduction whose blocking could depend on the chunk length);
- setups are ordered by the total order (infeasible after feasible, NaN scores last, score,
  then enumeration index), so the best ``n_top`` of a union does not depend on how the
  union was formed, and chunk results are stored by chunk number, not arrival;
- the time-domain stage simulates the same fixed groups of setups in every mode, and every
  setup's simulation is independent of the others in its group.

The sweep's screening scores agree with ``rank_setups``' (``score_setups``) to round-off
(:data:`RTOL_SCORE_ROUNDOFF`), not bit for bit: ``score_setups`` sums with a matrix product.

A car with third elements (issue 38) is screened as ``rank_setups`` screens it: each chunk's
setups, with every element choice (:class:`VariantSpace`), decoded and screened by
:func:`planner.screen.screen_setups` with the car's elements; the rest is the same.

Examples
--------
>>> from ident.models.library import ShockLibrary
>>> from ident.models.shocks import LinearShock
>>> lib = ShockLibrary.from_models([LinearShock(f"S{k}", 1000.0 * k) for k in range(1, 31)])
>>> space = setup_space(lib, symmetry="none")
>>> len(space), space.names([0, 1, 809_999])
(810000, ['S1/S1/S1/S1', 'S1/S1/S1/S2', 'S30/S30/S30/S30'])
>>> index, codes = space.chunk(30, 32)   # candidates 30 and 31, decoded on demand
>>> index.tolist(), codes.tolist()
([30, 31], [[0, 0, 1, 0], [0, 0, 1, 1]])
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy.stats import spearmanr
from threadpoolctl import threadpool_limits

from ident.data.channels import CORNERS, RIG_INPUTS
from ident.data.drive import Drive, check_drive_inputs
from ident.identify.model import LOOP_REDUCE_RTOL
from ident.sim.closedloop import pack_setups
from planner.errors import PlannerError
from planner.objective import (Objective, default_objective, mark_inventory, ranking_order,
                               ranking_position, score_setups, time_domain_metrics)
from planner.elements import (ELEMENT_COLUMNS, THIRD_COLUMNS, corner_shock_ids,
                              distinct_setups, loop_arguments, model_setup_elements,
                              model_setup_third, vary_elements, vary_third)
from planner.histograms import ShockHistograms
from planner.options import (ElementOptions, HistogramOptions, LoopOptions, RunOptions,
                             ScreenOptions, as_options)
from planner.plant import as_loop_plant
from planner.predict import predict_setups, prepare_drive, resolve_setups
from planner.runner import KERNEL_LOCK, start_runner
from planner.screen import (describe_agreement, drive_bands, screen_operands, screen_packed,
                            screen_setups, screening_predictions, third_choices)
from planner.click_settings import base_id
from planner.setups import Setup, SetupSpace, resolve_baseline, setup_space
from planner.text import format_table

__all__ = [
    "COMBINE_MODES",
    "RTOL_SCORE_ROUNDOFF",
    "SweepResult",
    "VariantSpace",
    "sweep_setups",
    "screen_setups_on",
]

log = logging.getLogger(__name__)

#: How case scores combine into a setup's sweep score.
COMBINE_MODES = ("mean", "worst")
#: Relative difference of a sweep's screening score from ``score_setups``' for the same
#: metrics: the same weighted sum, summed in another order (round-off only).
RTOL_SCORE_ROUNDOFF = 1e-13
#: Default setups per screening chunk: about 10 MB of packed curves and 1-3 s of work.
DEFAULT_CHUNK_SIZE = 20_000
#: Default setups per time-domain task (the rig response, about 0.1 s, is redone per task).
DEFAULT_SIMULATE_CHUNK = 128
#: Setups per task of :func:`screen_setups_on` by default.
SCREEN_ON_CHUNK_SIZE = 5000
#: Screening tasks per worker thread at least (smaller chunks than `chunk_size` if need be).
TASKS_PER_THREAD = 4
#: Smallest screening chunk made to spread the work (the kernel's per-call overhead).
MIN_CHUNK_SIZE = 1000


# ----------------------------------------------------------------------------------------------
# what is shipped to the workers
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _ShockTable:
    """Every shock of a space packed once (the kernel's curve arrays, by code): the library's
    and the setting names of adjustable shocks (one curve each)."""

    kv: np.ndarray  # (n_shocks, n_knots)
    kf: np.ndarray
    nk: np.ndarray  # (n_shocks,)
    slo: np.ndarray
    shi: np.ndarray
    lag: np.ndarray
    count: np.ndarray  # (n_shocks,), -1 = unlimited
    base: np.ndarray | None = None  # (n_shocks,) code of each one's base id (settings share)

    @classmethod
    def of(cls, library, ids=None):
        ids = list(library) if ids is None else list(ids)
        models = [library[sid] for sid in ids]
        pwls = [m.to_pwl() for m in models]
        K = max(p.v_knots_m_s.size for p in pwls)
        n = len(models)
        kv, kf = np.zeros((n, K)), np.zeros((n, K))
        nk = np.zeros(n, dtype=np.int64)
        for j, p in enumerate(pwls):  # padded like ident.sim.closedloop.pack_setups
            k = p.v_knots_m_s.size
            kv[j, :k], kf[j, :k] = p.v_knots_m_s, p.f_knots_n
            kv[j, k:], kf[j, k:] = p.v_knots_m_s[-1], p.f_knots_n[-1]
            nk[j] = k
        count = np.array([-1 if getattr(m, "count", None) is None else int(m.count)
                          for m in models], dtype=np.int64)
        bases = [base_id(sid) for sid in ids]
        base = None if bases == ids else np.array([ids.index(b) if b in ids else len(ids)
                                                   for b in bases], dtype=np.intp)
        return cls(kv=kv, kf=kf, nk=nk, slo=np.array([p.slope_below for p in pwls]),
                   shi=np.array([p.slope_above for p in pwls]),
                   lag=np.array([m.lag_s for m in models]), count=count, base=base)

    def pack(self, codes):
        """Kernel arrays of setups given as codes, shape (n, 4)."""
        return (self.kv[codes], self.kf[codes], self.nk[codes], self.slo[codes],
                self.shi[codes], self.lag[codes])

    def buildable(self, codes):
        """True where the crate's counts can build the setup."""
        ok = np.ones(codes.shape[0], dtype=bool)
        if self.base is not None:  # an adjustable's settings count as units of one damper
            by_base = self.base[codes]
            for b in np.unique(self.base[self.count >= 0]):
                ok &= (by_base == b).sum(axis=1) <= self.count[self.base == b][0]
            return ok
        for code in np.flatnonzero(self.count >= 0):
            ok &= (codes == code).sum(axis=1) <= self.count[code]
        return ok


@dataclass(frozen=True, eq=False)
class _Scoring:
    """The objective as elementwise arithmetic on screening metrics, per case."""

    metric_idx: np.ndarray  # (n_weighted,) columns of the weighted metrics
    weights: np.ndarray  # (n_weighted,)
    limits: tuple  # (column, max_ratio or nan, max or nan)
    base: np.ndarray  # (n_cases, n_metrics) baseline's screening metrics
    combine: str

    def case_scores(self, k, M):
        """Score and feasibility of metrics M (n, n_metrics) in case k."""
        base = self.base[k]
        score = np.zeros(M.shape[0])
        for j, w in zip(self.metric_idx, self.weights):
            score += w * (M[:, j] / base[j])
        ok = np.ones(M.shape[0], dtype=bool)
        for j, max_ratio, max_abs in self.limits:
            v = M[:, j]
            ok &= ~np.isnan(v)
            if not np.isnan(max_ratio):
                ok &= v / base[j] <= max_ratio
            if not np.isnan(max_abs):
                ok &= v <= max_abs
        return score, ok

    def combined(self, case_scores):
        """The sweep score from the cases' scores (list of (n,) arrays, case order)."""
        out = case_scores[0].copy()
        for s in case_scores[1:]:  # elementwise, in case order: the same bits in any chunk
            out = out + s if self.combine == "mean" else np.maximum(out, s)  # NaN stays NaN
        if self.combine == "mean" and len(case_scores) > 1:
            out /= len(case_scores)
        return out


def _screen_codes(ops, shocks, codes, max_iter, tol):
    with KERNEL_LOCK:
        return screen_packed(ops, *shocks.pack(codes), max_iter=max_iter, tol=tol)


def _screen_chunk(ops_list, shocks, space, scoring, start, stop, n_top, max_iter, tol):
    """Screen and score candidates ``start <= i < stop`` in every case (a task)."""
    index, codes = space.chunk(start, stop)
    metrics, case_scores = [], []
    feasible = shocks.buildable(codes)
    not_converged = 0
    for k, ops in enumerate(ops_list):
        M, _, iters = _screen_codes(ops, shocks, codes, max_iter, tol)
        not_converged += int(np.sum(iters >= max_iter))
        s, ok = scoring.case_scores(k, M)
        metrics.append(M)
        case_scores.append(s)
        feasible &= ok
    return _chunk_result(start, index, metrics, case_scores, feasible, not_converged, scoring,
                         n_top, len(ops_list[0].metric_names))


@dataclass(frozen=True, eq=False)
class VariantSpace:
    """A :class:`~planner.setups.SetupSpace` whose every setup comes with each of a list of
    element variants (bump stops, packers, third elements), as :func:`planner.rank.rank_setups`
    enumerates them: candidate ``i * n + v`` is the space's setup ``i`` with variant ``v``
    (variant 0: the setup as it is, the car's own elements), the order of
    :func:`planner.elements.vary_elements` then :func:`planner.elements.vary_third`.

    Attributes
    ----------
    base : SetupSpace
        The shock setups.
    variants : tuple of planner.setups.Setup
        The variants as setups named ``"T"`` plus the choices (``"T heave_front=H2"``): a
        candidate's name is its shock setup's followed by that suffix, its elements the
        variant's; variants that resolve to the same elements are dropped before.
    """

    base: SetupSpace
    variants: tuple

    @property
    def n_variants(self):
        """Variants per shock setup."""
        return len(self.variants)

    @property
    def shock_ids(self):
        """Code ``j`` is ``shock_ids[j]`` (the base space's)."""
        return self.base.shock_ids

    @property
    def listed_names(self):
        """None: the names are generated (a base space from a list names its shock setups)."""
        return None

    def __len__(self):
        """Number of candidates: the base space's times the variants."""
        return len(self.base) * self.n_variants

    def chunk(self, start, stop):
        """Decode candidates ``start <= i < stop``: ``(index, codes)`` as
        :meth:`SetupSpace.chunk` (the codes of each candidate's shocks)."""
        n = self.n_variants
        start, stop = max(int(start), 0), min(int(stop), len(self))
        bidx, codes = self.base.chunk(start // n, -(-stop // n))
        idx = (bidx[:, None] * n + np.arange(n)).ravel()
        codes = np.repeat(codes, n, axis=0)
        keep = (idx >= start) & (idx < stop)
        return idx[keep], codes[keep]

    def first(self, *, chunk_size=20_000):
        """The first candidate the inventory keeps (None if none)."""
        first = self.base.first(chunk_size=chunk_size)
        return None if first is None else first * self.n_variants

    def ids(self, index):
        """Shock ids of candidates (list of tuples ``LF RF LR RR``)."""
        return self.base.ids(np.asarray(index, dtype=np.int64) // self.n_variants)

    def find(self, ids):
        """The candidate index of shock ids with the car's own elements (variant 0)."""
        idx = self.base.find(ids)
        return None if idx is None else idx * self.n_variants

    def names(self, index):
        """Names of candidates: the shock setup's, then the variant's choices."""
        return [s.name for s in self.setups(index)]

    def setups(self, index):
        """The :class:`~planner.setups.Setup` objects of candidates, with their elements."""
        index = np.asarray(index, dtype=np.int64)
        out = []
        for s, v in zip(self.base.setups(index // self.n_variants), index % self.n_variants):
            t = self.variants[int(v)]
            out.append(s if v == 0 else Setup(s.name + t.name[1:], dict(s.shocks),
                                              bump_stops=t.bump_stops, packers_m=t.packers_m,
                                              third=t.third, heave_springs=t.heave_springs))
        return tuple(out)


def _variant_templates(base, elements, model, library):
    """The element variants (:class:`VariantSpace`'s) of `elements`' choices on `model`: the
    choices enumerated on one setup as rank does, repeats dropped."""
    lib = elements.library(model)
    t = Setup("T", dict(base.shocks))
    got = vary_elements([t], bump_stops=elements.vary_bump_stops,
                        packers_m=elements.vary_packers_m, library=lib,
                        where="sweep: the bump-stop and packer choices "
                        "(--try-bump-stops, --try-packers)")
    if elements.vary_third:
        got = vary_third(got, elements.vary_third, car=elements.car_third(model),
                         where="sweep: the third-element choices (--try-heave, --try-roll, "
                         "--try-heave-spring)")
    plain = elements.without_choices()
    elem = model_setup_elements(got, model, plain, where="sweep")
    third = model_setup_third(got, model, library, plain, where="sweep")
    return tuple(distinct_setups(got, elem, third)[0])


@dataclass(frozen=True, eq=False)
class _ThirdCase:
    """A case of a car with third elements: what :func:`planner.screen.screen_setups` needs to
    screen setups with the car's elements, as rank does (shipped to the workers)."""

    plant: object
    drive: Drive
    elements: ElementOptions  # the model's fixed (for_model), no choices
    band_hz: tuple
    screen: ScreenOptions
    reduce_rtol: object
    metric_names: tuple = ()


def _screen_third_setups(case, setups, library):
    """Screening metrics (n, n_metrics) in ``case.metric_names`` order and iteration counts
    of setups on a case with third elements (rank's screening: the setups' bump stops, static
    loads and third elements linearized with the shocks)."""
    elem = model_setup_elements(setups, case.plant, case.elements, where="sweep")
    third = model_setup_third(setups, case.plant, library, case.elements, where="sweep")
    with KERNEL_LOCK:
        pred = screen_setups(case.plant, case.drive, setups, library, band_hz=case.band_hz,
                             screen=case.screen, reduce_rtol=case.reduce_rtol,
                             third=third_choices(third), **loop_arguments(elem))
    names = list(case.metric_names) or [c for c in pred.table.columns if c not in CORNERS]
    return (pred.table[names].to_numpy(dtype=float), names,
            np.asarray(pred.diagnostics["iterations"]))


def _screen_third_chunk(cases, shocks, space, scoring, library, start, stop, n_top, max_iter):
    """:func:`_screen_chunk` for cases with third elements (a task)."""
    index, codes = space.chunk(start, stop)
    metrics, case_scores = [], []
    feasible = shocks.buildable(codes)
    not_converged = 0
    setups = space.setups(index) if index.size else ()
    for k, case in enumerate(cases):
        if index.size:
            M, _, iters = _screen_third_setups(case, setups, library)
        else:
            M, iters = np.zeros((0, len(case.metric_names))), np.zeros(0, dtype=np.int64)
        not_converged += int(np.sum(iters >= max_iter))
        s, ok = scoring.case_scores(k, M)
        metrics.append(M)
        case_scores.append(s)
        feasible &= ok
    return _chunk_result(start, index, metrics, case_scores, feasible, not_converged, scoring,
                         n_top, len(cases[0].metric_names))


def _chunk_result(start, index, metrics, case_scores, feasible, not_converged, scoring, n_top,
                  n_metrics):
    """A screened chunk's summary: its scores and feasibility, its best `n_top` candidates'
    indices and metrics (``(n_top, n_cases, n_metrics)``) and the count not converged."""
    score = scoring.combined(case_scores) if index.size else np.zeros(0)
    best = ranking_order(feasible, score, index)[:n_top]
    top_metrics = np.stack([M[best] for M in metrics], axis=1) if index.size \
        else np.zeros((0, len(metrics), n_metrics))
    return {"start": start, "index": index, "score": score, "feasible": feasible,
            "top_index": index[best], "top_metrics": top_metrics,
            "not_converged": not_converged}


def _screen_packed_chunk(ops, packed, max_iter, tol):
    """Screen a packed chunk of setups (a task of :func:`screen_setups_on`)."""
    with KERNEL_LOCK:
        return screen_packed(ops, *packed, max_iter=max_iter, tol=tol)


def screen_setups_on(model, drive, setups, library, *, band_hz=(1.0, 20.0),
                     screen=ScreenOptions(), reduce_rtol=LOOP_REDUCE_RTOL, run=RunOptions(),
                     progress=False):
    """:func:`planner.screen.screen_setups` with the chunks screened on a Dask cluster.

    The operands are built once here and scattered; each task screens one chunk of packed
    setups with the same compiled kernel, so the metrics are bit for bit those of
    ``screen_setups`` whatever the scheduler, the workers or the chunk size (every setup
    is computed on its own). ``rank --scheduler`` uses it.

    Parameters
    ----------
    model, drive, setups, library, band_hz, screen, reduce_rtol
        As :func:`planner.screen.screen_setups` (``screen.chunk_size`` is not used: a
        task's setups are one compiled batch).
    run : planner.options.RunOptions
        Where it runs, as :func:`sweep_setups` (default ``"local"``: a LocalCluster, one
        worker per core); ``run.chunk_size`` setups per task (default 5000).
    progress : bool

    Returns
    -------
    planner.predict.Predictions
        As ``screen_setups`` returns; ``settings["scheduler"]`` names where it ran.
    """
    screen = as_options(screen, ScreenOptions, "screen", "screen_setups_on")
    run = as_options(run, RunOptions, "run", "screen_setups_on")
    n_bands, max_iter, tol = screen.n_bands, screen.max_iter, screen.tol
    chunk_size = SCREEN_ON_CHUNK_SIZE if run.chunk_size is None else run.chunk_size
    if int(chunk_size) < 1:
        raise PlannerError(f"chunk_size must be at least 1, got {chunk_size}")
    setups = list(setups)
    models = resolve_setups(setups, library)
    # a wrong address fails first
    runner = start_runner(run.scheduler, run.client, run.n_workers, run.processes, "rank")
    try:
        plant, drive, ops = _prepare_case("rank", model, drive, band_hz, n_bands, reduce_rtol)
        h = 1.0 / drive.fs_hz  # as screen_response: the bands are of the drive at this rate
        ops_ref = runner.scatter(ops)
        args = []
        for a in range(0, len(models), int(chunk_size)):
            chunk = models[a:a + int(chunk_size)]
            kv, kf, nk, slo, shi, *_ = pack_setups(chunk, h)
            lag = np.array([[m.lag_s for m in row] for row in chunk])
            args.append((ops_ref, (kv, kf, nk, slo, shi, lag), max_iter, tol))
        parts = [None] * len(args)
        for j, res in runner.map_unordered(_screen_packed_chunk, args, progress, "screen"):
            parts[j] = res
        kind = runner.kind
    finally:
        runner.close()
    out = np.concatenate([p[0] for p in parts])
    sig = np.concatenate([p[1] for p in parts])
    iters = np.concatenate([p[2] for p in parts])
    pred = screening_predictions(plant, drive, setups, list(ops.metric_names), out, sig, iters,
                                 band_hz=band_hz, n_bands=n_bands, max_iter=max_iter, tol=tol)
    pred.settings["scheduler"] = kind
    return pred


def _warm(ops, shocks, codes, plant, drive, setups, library, loop, elements):
    """Import the engine and load both compiled kernels (from numba's cache) on a worker."""
    _screen_codes(ops, shocks, codes, 30, 1e-5)
    _simulate_chunk(plant, drive, setups, library, loop, elements)


def _warm_third(case, setups, library, plant, drive, loop, elements):
    """:func:`_warm` for cases with third elements."""
    _screen_third_setups(case, setups, library)
    _simulate_chunk(plant, drive, setups, library, loop, elements)


def _simulate_chunk(plant, drive, setups, library, loop, elements):
    """Time-domain metrics of a group of setups on one case (a task).

    BLAS runs on one thread, as in a Dask worker (which sets ``OPENBLAS_NUM_THREADS=1``):
    the drive's rig response differs in the last bits with the BLAS thread count.
    """
    with KERNEL_LOCK, threadpool_limits(1):
        pred = predict_setups(plant, drive, setups, library, loop=loop, elements=elements)
    return pred.table, pred.histograms


def _element_variants(sim, elements, model, library):
    """The simulated setups with every bump-stop, packer and third-element choice of
    `elements` (an ElementOptions), and each one's parent (the index of its shock setup in
    `sim`); the same setups without choices."""
    if not elements.has_choices:
        return sim, np.arange(len(sim))
    lib = elements.library(model)
    out, parent = [], []
    for i, s in enumerate(sim):
        got = vary_elements([s], bump_stops=elements.vary_bump_stops,
                            packers_m=elements.vary_packers_m, library=lib,
                            where="sweep: the bump-stop and packer choices "
                            "(--try-bump-stops, --try-packers)")
        if elements.vary_third:
            if elements.car_third(model) is None:
                raise PlannerError("sweep: third-element choices (--try-heave, --try-roll, "
                                   "--try-heave-spring) on a model without third elements; "
                                   "drop them, or use a model identified from a session that "
                                   "declares third_elements")
            got = vary_third(got, elements.vary_third, car=elements.car_third(model),
                             where="sweep: the third-element choices (--try-heave, "
                             "--try-roll, --try-heave-spring)")
        out += got
        parent += [i] * len(got)
    plain = elements.without_choices()
    elem = model_setup_elements(out, model, plain)
    third = model_setup_third(out, model, library, plain, where="sweep")
    if elem is not None or third is not None:
        out, keep = distinct_setups(out, elem, third)
        parent = [parent[k] for k in keep]
    return out, np.asarray(parent, dtype=np.intp)


# ----------------------------------------------------------------------------------------------
# result
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SweepResult:
    """The result of :func:`sweep_setups`.

    Attributes
    ----------
    table : pandas.DataFrame
        The setups simulated in the time domain (the best ``n_top`` by screening, and the
        baseline), best first, indexed by setup name: ``LF RF LR RR``, ``score`` (the
        sweep score: mean or worst of the case scores, lower is better), ``feasible``
        (in every case, and buildable from the crate), ``violations`` (``"[case] ..."``
        joined by ``"; "``), ``rank``, ``screening_score``, ``screening_rank`` (among all
        screened setups), then ``score@<case>`` per case.
    cases : dict of str -> pandas.DataFrame
        Per case label, the time-domain table of the simulated setups as
        :func:`planner.rank.rank_setups` gives it (metrics SI, ``score``,
        ``score_<group>``, ``feasible``, ``violations``, ``rank`` within the case).
    screening_top : dict of str -> pandas.DataFrame
        Per case, the screening metrics and scores of the same setups.
    screening_index : ndarray of int64, shape (n_screened,)
        Candidate index (in :attr:`space`) of every screened setup, increasing.
    screening_score : ndarray, shape (n_screened,)
        Every screened setup's sweep screening score.
    screening_feasible : ndarray of bool, shape (n_screened,)
    space : SetupSpace or VariantSpace
        Names and shock ids of any candidate index (a :class:`VariantSpace` for a car with
        third elements: every setup with each element choice).
    baseline : str
    objective : planner.objective.Objective
    agreement : dict
        ``spearman`` between screening and time-domain sweep scores over the simulated
        setups (near the top the scores are close: a low value says little), ``n``,
        ``same_best``, ``time_best``, ``screening_best``, ``time_best_screening_rank``
        (-1: not among the swept setups), ``top`` and ``score_gap``
        (:func:`planner.screen.describe_agreement`).
    settings : dict
        ``cases`` (the labels, models outer, drives inner), ``models`` and ``drives``
        (their names: the mapping's keys, else the objects' ``name``; the case files'
        names come from them, :func:`planner.report.sweep_files.case_file_names`),
        ``combine``, ``n_candidates``, ``n_screened``, ``n_top``, ``top_share``,
        ``chunk_size``, ``scheduler`` (kind), ``address``, ``n_workers``,
        ``seconds`` (prepare, screen, simulate), ``screen_setups_per_s`` (setups x cases)
        and ``simulate_setups_per_s`` (setups x cases).
    histograms : dict of str -> planner.histograms.ShockHistograms
        Per case label, the simulated setups' shock-velocity histograms in :attr:`table`'s
        order (with ``loop.histograms``; empty without).
    """

    table: pd.DataFrame
    cases: dict
    screening_top: dict
    screening_index: np.ndarray
    screening_score: np.ndarray
    screening_feasible: np.ndarray
    space: SetupSpace
    baseline: str
    objective: object
    agreement: dict
    settings: dict = field(default_factory=dict)
    histograms: dict = field(default_factory=dict)

    @property
    def best(self):
        """Name of the best setup (the top row)."""
        return self.table.index[0]

    def summary(self, n=5):
        """The sweep for a terminal: screened and simulated with their speeds, how screening
        and the time domain agree, the baseline, and the best `n` setups.

        Parameters
        ----------
        n : int
            Setups in the table.

        Returns
        -------
        str
        """
        st, t = self.settings, self.table
        sec = st["seconds"]
        lines = [f"screened {st['n_screened']:,} setups x {len(st['cases'])} case(s) in "
                 f"{sec['screen']:.1f} s ({st['screen_setups_per_s']:,.0f} setup-cases/s, "
                 f"scheduler {st['scheduler']}, {st['n_workers']} worker(s)); simulated "
                 f"{len(t)} in {sec['simulate']:.1f} s ({st['simulate_setups_per_s']:,.0f} "
                 "setup-cases/s)",
                 describe_agreement(self.agreement, what="ranking"),
                 f"baseline '{self.baseline}'; {st['combine']} of the cases' scores; best:"]
        rows = [(int(r["rank"]), name, f"{r['score']:.4f}", int(r["screening_rank"]),
                 "yes" if r["feasible"] else "no") for name, r in t.head(n).iterrows()]
        lines.append(format_table(rows, ["rank", "setup", "score", "screening rank",
                                         "feasible"]))
        return "\n".join(lines)

    def screening_order(self, n=None):
        """Candidate indices of the screened setups, best first.

        Parameters
        ----------
        n : int, optional
            Only the best `n`.

        Returns
        -------
        ndarray of int64
        """
        order = ranking_order(self.screening_feasible, self.screening_score, self.screening_index)
        return self.screening_index[order[:n] if n is not None else order]


# ----------------------------------------------------------------------------------------------
# the sweep
# ----------------------------------------------------------------------------------------------


def _as_list(x, what, kind=None):
    if isinstance(x, Mapping):
        return list(x.items())
    if kind is not None and isinstance(x, kind):
        return [(None, x)]
    if isinstance(x, Sequence) and not isinstance(x, (str, bytes)):
        if not x:
            raise PlannerError(f"sweep: no {what} given; give at least one")
        return [(None, v) for v in x]
    return [(None, x)]


def _prepare_case(label, model, drive, band_hz, n_bands, reduce_rtol):
    """The plant, the drive at the model's rate and the screening operands of one case."""
    plant = as_loop_plant(model, reduce_rtol=reduce_rtol)
    drive = prepare_drive(drive, getattr(model, "fs_hz", None), where=f"case {label!r}: drive")
    check_drive_inputs(drive, getattr(plant, "rig_inputs", RIG_INPUTS), model=plant.name)
    bands = drive_bands(drive, band_hz=band_hz, n_bands=n_bands)
    H = plant.frequency_response(bands.f_hz)
    ops = screen_operands(H, plant.output_names, plant.cbar_n_s_m, bands)
    return plant, drive, ops


def _baseline_name(given):
    """The name of a baseline built from shock ids: ``all-<id>`` (one id) or the four ids
    joined by ``/`` (the enumeration's default name of that setup)."""
    return f"all-{given[0]}" if len(given) == 1 else "/".join(given)


def _baseline_setup(space, library, objective, baseline):
    """The baseline Setup and its candidate index (None when not in the space)."""

    def find(ids):
        idx = space.find(ids)
        return None if idx is None else space.setups([idx])[0]

    listed = space.setups(range(len(space))) if space.listed_names is not None else ()
    base = resolve_baseline(baseline, library, setups=listed, default=objective.baseline,
                            find=find, name=_baseline_name, where="sweep")
    if base is None:  # an enumeration and no baseline named: its first buildable setup
        first = space.first()
        if first is None:
            raise PlannerError("sweep: no setup of the enumeration fits the inventory; raise "
                               "the counts, choose other shocks or pass "
                               "respect_inventory=False")
        return space.setups([first])[0], first
    if space.listed_names is not None and base.name in space.listed_names:
        return base, space.listed_names.index(base.name)
    return base, space.find(base.ids())


def _scoring(objective, ops_list, base_metrics, combine):
    """The objective's weights and limits as column indices; checks the baseline's values."""
    names = list(ops_list[0].metric_names)
    for k, ops in enumerate(ops_list):
        if list(ops.metric_names) != names:
            raise PlannerError(f"sweep: case {k} has the screening metrics {ops.metric_names}, "
                               f"case 0 {tuple(names)}; sweep models with the same outputs")
    for k in range(len(ops_list)):  # score_setups checks the metrics and the baseline
        score_setups(pd.DataFrame(base_metrics[k][None, :], columns=names, index=["baseline"]),
                     objective, baseline="baseline")
    col = {m: j for j, m in enumerate(names)}
    limits = tuple((col[m], float(spec.get("max_ratio", np.nan)), float(spec.get("max", np.nan)))
                   for m, spec in objective.limits.items())
    return _Scoring(metric_idx=np.array([col[m] for m in objective.weights], dtype=np.intp),
                    weights=np.array(list(objective.weights.values()), dtype=float),
                    limits=limits, base=np.asarray(base_metrics, dtype=float), combine=combine)


def _check_options(top_share, top, chunk_size, simulate_chunk, combine):
    if combine not in COMBINE_MODES:
        raise PlannerError(f"sweep: combine={combine!r} is unknown; use one of "
                           f"{list(COMBINE_MODES)}")
    if top is None and not (isinstance(top_share, (int, float)) and 0 < top_share <= 1):
        raise PlannerError(f"sweep: top_share={top_share!r} must be in (0, 1], e.g. 0.01 for "
                           "the best 1 %")
    if top is not None and (isinstance(top, bool) or not isinstance(top, (int, np.integer))
                            or top < 1):
        raise PlannerError(f"sweep: top={top!r} must be a positive integer")
    for name, v in (("chunk_size", chunk_size), ("simulate_chunk", simulate_chunk)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise PlannerError(f"sweep: {name}={v!r} must be a positive integer")


def _names(items, kind):
    """The name of every model or drive: its mapping key, else its ``name``, else
    ``model<i>`` / ``drive<i>``."""
    return tuple(str(key if key is not None else (getattr(x, "name", None) or f"{kind}{i}"))
                 for i, (key, x) in enumerate(items))


def _case_labels(model_names, drive_names):
    """A label per case, models outer: the drive's name (one model), the model's (one
    drive) or ``"model | drive"``; numbered when two would be the same."""
    labels = []
    for m in model_names:
        for d in drive_names:
            if len(model_names) == 1:
                labels.append(d)
            elif len(drive_names) == 1:
                labels.append(m)
            else:
                labels.append(f"{m} | {d}")
    if len(set(labels)) != len(labels):
        labels = [f"{j}: {lab}" for j, lab in enumerate(labels)]
    return labels


def sweep_setups(models, drives, library, *, setups=None, constraints=None, objective=None,
                 baseline=None, top_share=0.01, top=None, combine="mean", loop=LoopOptions(),
                 screen=ScreenOptions(), elements=ElementOptions(), run=RunOptions(),
                 progress=True):
    """Screen a large set of setups on several models and drives, simulate and rank the best.

    Parameters
    ----------
    models : model, sequence of models, or mapping name -> model
        Each a VehicleModel, FullCarModel, VehicleParams or LoopPlant.
    drives : ident.data.drive.Drive, sequence of drives, or mapping name -> drive
        Every model is swept on every drive: ``len(models) * len(drives)`` cases.
    library : ident.models.library.ShockLibrary
    setups : sequence of planner.setups.Setup, optional
        The candidates; default the enumeration of `constraints`.
    constraints : dict, optional
        Keyword arguments of :func:`setup_space` (those of
        :func:`planner.setups.enumerate_setups` but ``max_setups``); default every
        left-right symmetric setup. ``{"symmetry": "none"}`` gives every 4-corner
        combination.
    objective : planner.objective.Objective, optional
        Default :func:`planner.objective.default_objective`; normalized per case by the
        baseline in that case.
    baseline : Setup, str, optional
        As :func:`planner.setups.resolve_baseline`: a Setup, a listed setup's name, a
        shock id (at every corner, named ``"all-<id>"``) or four ids ``"LF,RF,LR,RR"``
        (named ``"LF/RF/LR/RR"``); default the objective's baseline, else the first
        setup. A baseline with the shocks of a swept setup is that setup. It is
        simulated always.
    top_share : float
        Share of the screened setups simulated in the time domain (at least one).
    top : int, optional
        Simulate this many instead of `top_share`.
    combine : {"mean", "worst"}
        A setup's sweep score: the mean or the largest of its case scores.
    loop : planner.options.LoopOptions
        The time domain, as :func:`planner.predict.predict_setups`; its ``band_hz`` and
        ``reduce_rtol`` also the screening's.
    screen : planner.options.ScreenOptions
        The screening's ``n_bands``, ``max_iter``, ``tol``, as
        :func:`planner.screen.screen_setups` (its ``chunk_size`` is not used: see `run`).
    elements : planner.options.ElementOptions
        The real car's elements in the time domain, as
        :func:`planner.predict.predict_setups` (default: each model's own, e.g. an
        identified model's bump stops and static loads). The screening stage ranks the
        shocks without them (its codes are shocks only); the time domain decides. Its
        choices ``vary_bump_stops``, ``vary_packers_m`` (per group,
        :func:`planner.elements.vary_elements`): every simulated setup (the screening's
        best and the baseline) is simulated with each combination too, and ranked with
        them; a variant's screening score is its shocks'. A car with third elements
        (``model.third`` or ``third``) is screened as :func:`planner.rank.rank_setups`
        screens it: every shock setup with each combination of the choices (also
        ``vary_third``: ``--try-heave``, ...) is a candidate (:class:`VariantSpace`),
        screened with the car's elements linearized
        (:func:`planner.screen.screen_setups`, ``third=``); its heave and roll dampers are
        not enumerated at the corners (:func:`planner.elements.corner_shock_ids`).
    run : planner.options.RunOptions
        Where it runs: ``scheduler`` ``"local"`` (default): a new
        :class:`dask.distributed.LocalCluster` (``n_workers``, default one per core,
        closed at the end); a scheduler address (``"tcp://host:8786"``); or ``"none"``
        for this process only; ``client`` an existing client to use instead (not
        closed); ``processes`` LocalCluster workers as processes (default) or threads of
        this process; ``chunk_size`` candidates per screening task at most (default
        :data:`DEFAULT_CHUNK_SIZE`; bounds a task's memory: under 1 kB a setup; smaller
        when needed to give every worker thread at least :data:`TASKS_PER_THREAD` tasks,
        but not below :data:`MIN_CHUNK_SIZE`); ``simulate_chunk`` setups per time-domain
        task (default :data:`DEFAULT_SIMULATE_CHUNK`).
    progress : bool
        Progress bars (tqdm) over the tasks.

    Returns
    -------
    SweepResult

    Raises
    ------
    PlannerError
        On bad options, an unreachable scheduler, a baseline not found, metrics the
        objective needs missing, or as :func:`setup_space`.
    TypeError
        On a model, drive or objective of the wrong type.

    Notes
    -----
    The results do not depend on the scheduler, the workers, the chunk sizes or the order the
    tasks finish in (see the module docstring). Memory: the driver keeps 17 bytes per
    screened setup and the metrics of ``2 * n_top`` setups; a task holds one chunk.
    """
    t0 = time.perf_counter()
    objective = default_objective() if objective is None else objective
    if not isinstance(objective, Objective):
        raise TypeError(f"sweep: objective must be a planner.objective.Objective (read one "
                        f"with read_objective), got {type(objective).__name__}")
    loop = as_options(loop, LoopOptions, "loop", "sweep")
    hist_metrics = time_domain_metrics(objective)
    if hist_metrics and loop.histograms is None:
        loop = replace(loop, histograms=HistogramOptions())
    screen_objective = objective.without_metrics(hist_metrics)
    if screen_objective is None or any(m.startswith("histogram_distance_")
                                       for m in hist_metrics):
        raise PlannerError(f"sweep: objective {objective.name!r} uses {list(hist_metrics)}; "
                           "the sweep takes no target histogram, and its screening needs a "
                           "weighted RMS metric: remove histogram_distance_XX and weight at "
                           "least one RMS metric")
    screen = as_options(screen, ScreenOptions, "screen", "sweep")
    elements = as_options(elements, ElementOptions, "elements", "sweep")
    run = as_options(run, RunOptions, "run", "sweep")
    oversample, band_hz, reduce_rtol = loop.oversample, loop.band_hz, loop.reduce_rtol
    n_bands, max_iter, tol = screen.n_bands, screen.max_iter, screen.tol
    chunk_size = DEFAULT_CHUNK_SIZE if run.chunk_size is None else run.chunk_size
    simulate_chunk = DEFAULT_SIMULATE_CHUNK if run.simulate_chunk is None else run.simulate_chunk
    _check_options(top_share, top, chunk_size, simulate_chunk, combine)
    if setups is not None and constraints:
        raise PlannerError("sweep: give either setups or constraints, not both")
    named = [st.name for st in setups or () if st.bump_stops is not None
             or st.packers_m is not None or st.third is not None
             or st.heave_springs is not None]
    if named:
        raise PlannerError(f"sweep: setup {named[0]!r} names bump stops, packers or third "
                           "elements; the sweep enumerates shocks (its setups are shock "
                           "codes): give the choices as vary_bump_stops / vary_packers_m / "
                           "vary_third (shockplan sweep --try-bump-stops, --try-packers, "
                           "--try-heave, ...), or rank these setups with shockplan rank "
                           "--setups")
    constraints = dict(constraints or {})
    model_list = _as_list(models, "models")
    thirds = [elements.car_third(m) for _, m in model_list]
    has_third = [c is not None and bool(c.elements) for c in thirds]
    if any(has_third) and not all(has_third):
        raise PlannerError("sweep: some models carry third elements and some do not; sweep "
                           "the cars with third elements and the others separately")
    if setups is None and constraints.get("shocks") is None:
        # a car's heave and roll dampers (and those the crate marks) stay off its corners;
        # with third elements its screening is rank's: every shock setup with each element
        # choice, the elements linearized with the shocks
        corner = corner_shock_ids(library, thirds[0] if all(has_third) else None,
                                  elements.vary_third)
        if corner is not None:
            constraints["shocks"] = corner
    space = setup_space(library, setups=setups, **constraints, where="sweep")
    drive_list = _as_list(drives, "drives", Drive)
    model_names, drive_names = _names(model_list, "model"), _names(drive_list, "drive")
    labels = _case_labels(model_names, drive_names)
    base, base_idx = _baseline_setup(space, library, objective, baseline)
    third_cases = None
    if all(has_third):  # every setup with each variant; rank's screening, per case
        space = VariantSpace(space, _variant_templates(base, elements, model_list[0][1],
                                                       library))
        base_idx = None if base_idx is None else base_idx * space.n_variants
        screen_opts = ScreenOptions(n_bands=n_bands, max_iter=max_iter, tol=tol)
        third_cases = []
    # the scheduler first: a wrong address fails before any work
    runner = start_runner(run.scheduler, run.client, run.n_workers, run.processes)
    try:
        # 1. the cases, once, here
        cases = []
        k = 0
        for _, model in model_list:
            for _, drive in drive_list:
                cases.append(_prepare_case(labels[k], model, drive, band_hz, n_bands, reduce_rtol))
                if third_cases is not None:
                    third_cases.append(_ThirdCase(
                        cases[-1][0], cases[-1][1], elements.without_choices().for_model(model),
                        tuple(band_hz), screen_opts, reduce_rtol))
                k += 1
        shocks = _ShockTable.of(library, space.shock_ids)
        code_of = {sid: j for j, sid in enumerate(space.shock_ids)}
        base_codes = np.array([[code_of[sid] for sid in base.ids()]], dtype=np.intp)
        if third_cases is None:
            base_metrics = [_screen_codes(ops, shocks, base_codes, max_iter, tol)[0][0]
                            for _, _, ops in cases]
            metric_names = list(cases[0][2].metric_names)
            scoring = _scoring(screen_objective, [ops for _, _, ops in cases], base_metrics,
                               combine)
        else:
            base_metrics = []
            for j, case in enumerate(third_cases):
                M, names, _ = _screen_third_setups(case, [base], library)
                base_metrics.append(M[0])
                third_cases[j] = replace(case, metric_names=tuple(names))
            metric_names = list(third_cases[0].metric_names)
            scoring = _scoring(screen_objective, [c for c in third_cases], base_metrics,
                               combine)
        n_cand = len(space)
        n_top_max = int(top) if top is not None else max(1, math.ceil(top_share * n_cand))
        # every worker imports the engine and loads its kernels before the clock starts
        plant0, drive0, ops0 = cases[0]
        # each case's elements with its model's fixed (the workers get only its plant)
        ekws = [elements.without_choices().for_model(model)
                for _, model in model_list for _ in drive_list]
        loop_w = replace(loop, band_hz=tuple(band_hz))
        if third_cases is None:
            runner.everywhere(_warm, ops0, shocks, base_codes, plant0, drive0, [base], library,
                              loop_w, ekws[0])
        else:
            runner.everywhere(_warm_third, third_cases[0], [base], library, plant0, drive0,
                              loop_w, ekws[0])
        t_prep = time.perf_counter() - t0
        # 2. screening, chunk by chunk
        t1 = time.perf_counter()
        if third_cases is None:
            ops_ref = runner.scatter([ops for _, _, ops in cases])
        else:
            ops_ref, lib_ref = runner.scatter(third_cases), runner.scatter(library)
        shocks_ref, space_ref, scoring_ref = (runner.scatter(x) for x in (shocks, space, scoring))
        # at least TASKS_PER_THREAD tasks a worker thread, so that none idles at the end
        chunk = int(min(chunk_size, max(MIN_CHUNK_SIZE, math.ceil(
            n_cand / (TASKS_PER_THREAD * runner.n_threads)))))
        starts = list(range(0, n_cand, chunk))
        if third_cases is None:
            task = _screen_chunk
            args = [(ops_ref, shocks_ref, space_ref, scoring_ref, a, min(a + chunk, n_cand),
                     n_top_max, max_iter, tol) for a in starts]
        else:
            task = _screen_third_chunk
            args = [(ops_ref, shocks_ref, space_ref, scoring_ref, lib_ref, a,
                     min(a + chunk, n_cand), n_top_max, max_iter) for a in starts]
        log.info("sweep: screening %d candidate setups x %d case(s) in %d chunks (%s)",
                 n_cand, len(cases), len(starts), runner.kind)
        parts = [None] * len(starts)
        top_idx = np.zeros(0, dtype=np.int64)
        top_met = np.zeros((0, len(cases), len(metric_names)))
        top_score = np.zeros(0)
        top_feas = np.zeros(0, dtype=bool)
        not_converged = 0
        for j, res in runner.map_unordered(task, args, progress, "sweep: screen"):
            parts[j] = (res["index"], res["score"], res["feasible"])
            not_converged += res["not_converged"]
            pos = np.searchsorted(res["index"], res["top_index"])
            top_idx = np.concatenate([top_idx, res["top_index"]])
            top_met = np.concatenate([top_met, res["top_metrics"]])
            top_score = np.concatenate([top_score, res["score"][pos]])
            top_feas = np.concatenate([top_feas, res["feasible"][pos]])
            keep = ranking_order(top_feas, top_score, top_idx)[:n_top_max]
            top_idx, top_met = top_idx[keep], top_met[keep]
            top_score, top_feas = top_score[keep], top_feas[keep]
        index = np.concatenate([p[0] for p in parts])
        score = np.concatenate([p[1] for p in parts])
        feasible = np.concatenate([p[2] for p in parts])
        t_screen = time.perf_counter() - t1
        n_scr = int(index.size)
        if not n_scr:
            raise PlannerError("sweep: no setup of the enumeration fits the inventory; raise "
                               "the counts, choose other shocks or pass "
                               "respect_inventory=False")
        if not_converged:
            log.warning("sweep: screening: %d setup-cases did not reach the tolerance in %d "
                        "iterations", not_converged, max_iter)
        n_top = int(top) if top is not None else max(1, math.ceil(top_share * n_scr))
        n_top = min(n_top, n_scr)
        top_idx, top_met, top_score = top_idx[:n_top], top_met[:n_top], top_score[:n_top]
        log.info("sweep: screened %d setups x %d case(s) in %.1f s (%.0f setup-cases/s)",
                 n_scr, len(cases), t_screen, n_scr * len(cases) / max(t_screen, 1e-9))
        # 3. the time domain on the best and the baseline
        t2 = time.perf_counter()
        sim = list(space.setups(top_idx))
        if base_idx is None or base_idx not in set(top_idx.tolist()):
            if base.name in {s.name for s in sim}:
                raise PlannerError(f"sweep: baseline {base.name!r} has the name of a swept "
                                   "setup with other shocks; rename the baseline")
            sim.append(base)
        sim0 = sim
        if third_cases is None:
            sim, parent = _element_variants(sim0, elements, model_list[0][1], library)
        else:  # the variants were screened as candidates
            parent = np.arange(len(sim0))
        plant_refs = [runner.scatter(p) for p, _, _ in cases]
        drive_refs = [runner.scatter(d) for _, d, _ in cases]
        lib_ref = runner.scatter(library)
        groups = [sim[a:a + simulate_chunk] for a in range(0, len(sim), simulate_chunk)]
        targs = [(plant_refs[k], drive_refs[k], g, lib_ref, loop_w, ekws[k])
                 for k in range(len(cases)) for g in groups]
        tparts = [None] * len(targs)
        for j, res in runner.map_unordered(_simulate_chunk, targs, progress,
                                           "sweep: simulate"):
            tparts[j] = res
        t_sim = time.perf_counter() - t2
    finally:
        runner.close()
    # 4. scores per case, combined, ranked
    names = [s.name for s in sim]
    names0 = [s.name for s in sim0]
    case_tables, screen_tables = {}, {}
    case_hists = {}
    for k, label in enumerate(labels):
        part = tparts[k * len(groups):(k + 1) * len(groups)]
        td = pd.concat([t for t, _ in part])
        if loop.histograms is not None:
            case_hists[label] = ShockHistograms.concat([h for _, h in part])
        sc = score_setups(td, objective, baseline=base.name).table
        case_tables[label] = pd.concat([td, mark_inventory(sc, sim, library)], axis=1)
        rows = np.vstack([top_met[:, k], base_metrics[k][None, :]])[:len(sim0)]
        st = pd.DataFrame(rows, columns=metric_names, index=pd.Index(names0, name="setup"))
        st.insert(0, "LF", [s.ids()[0] for s in sim0])
        for c, col in enumerate(CORNERS[1:], start=1):
            st.insert(c, col, [s.ids()[c] for s in sim0])
        screen_tables[label] = pd.concat(
            [st, score_setups(st, screen_objective, baseline=base.name).table], axis=1)
    case_scores = [case_tables[lab]["score"].to_numpy(dtype=float) for lab in labels]
    comb = scoring.combined(case_scores)
    feas = np.logical_and.reduce([case_tables[lab]["feasible"].to_numpy(dtype=bool)
                                  for lab in labels])
    viol = []
    for r in range(len(sim)):
        texts = [f"[{lab}] {case_tables[lab]['violations'].iloc[r]}" for lab in labels
                 if case_tables[lab]["violations"].iloc[r]]
        viol.append("; ".join(texts) if len(labels) > 1 else
                    (case_tables[labels[0]]["violations"].iloc[r]))
    order = ranking_order(feas, comb, np.arange(len(sim)))
    rank = np.empty(len(sim), dtype=np.int64)
    rank[order] = np.arange(1, len(sim) + 1)
    # screening score and rank of every simulated setup among all screened
    scr_score = np.append(top_score, [np.nan] * (len(sim0) - n_top))
    scr_rank = np.arange(1, n_top + 1).tolist()
    if len(sim0) > n_top:  # the baseline, below the top
        if base_idx is not None:
            at = int(np.searchsorted(index, base_idx))
            scr_score[-1] = score[at]
            scr_rank.append(ranking_position(at, feasible, score, index))
        else:
            scr_rank.append(-1)  # not among the swept setups
    scr_score = np.asarray(scr_score, dtype=float)[parent]
    scr_rank = np.asarray(scr_rank, dtype=np.int64)[parent]
    table = pd.DataFrame({c: [s.ids()[j] for s in sim] for j, c in enumerate(CORNERS)},
                         index=pd.Index(names, name="setup"))
    elem_cols = [c for c in ELEMENT_COLUMNS + THIRD_COLUMNS
                 if c in case_tables[labels[0]].columns]
    for c in elem_cols:
        table[c] = case_tables[labels[0]][c].to_numpy()
    table["score"] = comb
    table["feasible"] = feas
    table["violations"] = viol
    table["rank"] = rank
    table["screening_score"] = scr_score
    table["screening_rank"] = np.array(scr_rank, dtype=np.int64)
    for lab, s in zip(labels, case_scores):
        table[f"score@{lab}"] = s
    table = table.sort_values("rank", kind="stable")
    both = np.isfinite(table["screening_score"]) & np.isfinite(table["score"])
    rho = float(spearmanr(table.loc[both, "screening_score"], table.loc[both, "score"]).statistic) \
        if both.sum() > 2 else float("nan")
    best_scr = table["screening_rank"].where(table["screening_rank"] > 0).idxmin()
    agreement = {"spearman": rho, "n": int(len(table)),
                 "same_best": bool(table.index[0] == best_scr),
                 "time_best": table.index[0], "screening_best": best_scr,
                 # how far they differ: describe_agreement tells a near-tie from a miss
                 "time_best_screening_rank": int(table["screening_rank"].iloc[0]),
                 "top": int(n_top),
                 "score_gap": float(table.loc[best_scr, "score"] / table["score"].iloc[0] - 1.0)}
    seconds = {"prepare": t_prep, "screen": t_screen, "simulate": t_sim}
    settings = {"cases": tuple(labels), "models": model_names, "drives": drive_names,
                "combine": combine, "n_candidates": n_cand,
                "n_screened": n_scr, "n_top": n_top, "top_share": top_share,
                "chunk_size": chunk, "simulate_chunk": int(simulate_chunk),
                "scheduler": runner.kind, "address": runner.address,
                "n_workers": runner.n_workers, "oversample": oversample,
                "band_hz": tuple(band_hz), "seconds": seconds,
                "screen_setups_per_s": n_scr * len(cases) / max(t_screen, 1e-9),
                "simulate_setups_per_s": len(sim) * len(cases) / max(t_sim, 1e-9)}
    if elements.has_choices:
        settings["elements"] = {"vary_bump_stops": elements.vary_bump_stops,
                                "vary_packers_m": elements.vary_packers_m,
                                "vary_third": elements.vary_third,
                                "n_simulated": len(sim)}
    log.info("sweep: simulated %d setups x %d case(s) in %.1f s; best %r", len(sim),
             len(cases), t_sim, table.index[0])
    case_hists = {lab: h.select(list(table.index)) for lab, h in case_hists.items()}
    return SweepResult(table=table, cases=case_tables, screening_top=screen_tables,
                       screening_index=index, screening_score=score,
                       screening_feasible=feasible, space=space, baseline=base.name,
                       objective=objective, agreement=agreement, settings=settings,
                       histograms=case_hists)
