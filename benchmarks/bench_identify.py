"""Benchmark of identification: the paper session through
``ident.identify.pipeline.identify_session``.

Run::

    python benchmarks/bench_identify.py [--repeat N] [--ref-outputs K]

Prints, one figure per line, each timing with the machine's 1-minute load
average at that moment:

1. the session: the seed paper's experiment (5 runs x 800 s at 100 Hz, every
   channel of the spec) built once in memory with ``ident.sim.virtual_rig.simulate_session()``.
   Building it is *not* part of any timing below;
2. the engine: the median, min and max wall time of ``--repeat`` calls of
   ``ident.identify.pipeline.identify_session(session)`` (FRF estimate, conditioning,
   per-pair rational fits, all defaults);
3. its stages, each timed separately (median of ``--repeat``):
   ``ident.identify.frf.estimate_frf`` (with its default estimator, as ``identify_session``
   calls it; if that is not the paper's Welch H1, ``estimator="welch"`` is timed
   too, as the like-for-like engine for the reference below),
   ``ident.identify.condition.condition_frf``,
   ``ident.identify.pipeline.fit_model`` (the default ``invfreqs`` method), and
   ``model.loop_plant()`` (the realization the planner simulates: a balanced
   truncation, about 0.4 s since session 5; not part of ``identify_session``;
   ``shockplan identify`` builds it once and stores it in the model file, so the
   planner's commands load it),
   and once more with BLAS limited to one thread (``threadpoolctl``; on a busy
   2-core machine multithreaded BLAS can be many times slower); for comparison
   ``fit_model(frf, method="vf")`` (common-pole vector fitting);
4. peak memory of one ``identify_session`` call: the ``tracemalloc`` peak (memory
   allocated through Python and numpy during the call) and ``ru_maxrss`` (the
   process's resident high-water mark, which includes the session itself);
5. a straightforward reference for the FRF stage: for every run, the 11 x 11
   input spectral matrix (7 rig inputs and the 4 shock-force deviations
   ``dF = F - c_bar v``, with the engine's ``c_bar``) from 121
   ``scipy.signal.csd`` calls, then per output the 11 cross spectra and the
   output's autospectrum (``csd``/``welch`` per run) and a
   ``numpy.linalg.solve`` per frequency (the H1 normal equations, Eq. 15) plus
   the multiple coherence. Same window, block length and overlap as the engine.
   It is run for ``--ref-outputs`` outputs (default 3) and the per-output part
   scaled to all outputs (the input matrix is built once and shared, which
   favours the reference); the ratio reference / engine ``estimate_frf`` with
   ``estimator="welch"`` (like for like) and, if the default estimator differs,
   against the default one (a cost comparison only); and the largest relative
   difference between the reference and the engine's Welch estimate in 0.5-20 Hz
   (they solve the same equations, so it should be at round-off level);
6. ``target: identify < 8 s: PASS/FAIL`` (on the median; issue 40: with the speed
   probe at or below 0.5 s).

This is a script, not part of the package: it prints and writes nothing.
Warnings raised by identification (fit and coherence warnings) are counted and
summarized in one line, not repeated per call.
"""

from __future__ import annotations

import argparse
import gc
import os
import statistics
import sys
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
from scipy import signal

# benchmark the working tree this script lives in, installed or not
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ident.data.channels import CORNERS, RIG_INPUTS  # noqa: E402
from ident.identify.condition import condition_frf  # noqa: E402
from ident.identify.frf import estimate_frf  # noqa: E402
from ident.identify.pipeline import fit_model, identify_session  # noqa: E402
from ident.sim.virtual_rig import simulate_session  # noqa: E402
from _common import engine_version as _engine_version  # noqa: E402
from _common import load as _load, maxrss_mib as _maxrss_mib, mib as _mib  # noqa: E402

#: Issue 40's target for ``identify_session`` on the paper session [s] (speed probe <= 0.5 s).
TARGET_S = 8.0
#: Outputs the FRF reference is run for (the first ``--ref-outputs`` of them).
REF_OUTPUTS = ("shock_velocity_LF", "tire_force_LF", "ride_height_LF", "ride_height_RR",
               "shock_travel_RF")
#: Band in which the reference and the engine FRF are compared [Hz].
COMPARE_BAND_HZ = (0.5, 20.0)










class _Caught:
    """Collect the warnings of all timed calls (category name -> count)."""

    def __init__(self):
        self.counts = {}

    def add(self, records):
        for w in records:
            name = w.category.__name__
            self.counts[name] = self.counts.get(name, 0) + 1


def _timed(fn, caught):
    """Call fn() with warnings recorded; return (seconds, result, load after)."""
    gc.collect()
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        out = fn()
        elapsed = time.perf_counter() - t0
    caught.add(rec)
    return elapsed, out, os.getloadavg()[0]


def _single_thread(fn):
    """Call fn() with BLAS/OpenMP pools limited to one thread."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        return fn()


def _spread(label, times, loads, unit="s"):
    med = statistics.median(times)
    print(f"{label}, median of {len(times)}: {med:.2f} {unit} "
          f"(min {min(times):.2f}, max {max(times):.2f}; 1-min load after each: "
          + ", ".join(f"{x:.2f}" for x in loads) + ")")
    return med


# ---------------------------------------------------------------------------------------
# the reference: per-output scipy.signal.csd loop
# ---------------------------------------------------------------------------------------

def _run_inputs(run, cbar):
    """The 11 model inputs of a run (7 rig inputs, 4 dF = F - c_bar v), shape (11, n)."""
    rows = [run.dynamic(c) for c in RIG_INPUTS]
    for i, c in enumerate(CORNERS):
        rows.append(run.dynamic(f"shock_force_{c}") - cbar[i] * run.dynamic(f"shock_velocity_{c}"))
    return np.vstack(rows)


def reference_frf(session, outputs, cbar, settings):
    """H1 estimate with one ``scipy.signal.csd`` call per spectrum and a solve per frequency.

    Parameters
    ----------
    session : ident.data.session.Session
        Every run must hold ``shock_force_XX`` (the virtual rig writes them).
    outputs : sequence of str
    cbar : ndarray, shape (4,)
        Baseline damping [N/(m/s)] (the engine's, so that the inputs are the same).
    settings : dict
        The engine's ``window``, ``nperseg``, ``noverlap``.

    Returns
    -------
    t_inputs_s : float
        Time to build the 11 x 11 input spectral matrix over all runs.
    t_outputs_s : list of float
        Time per output (cross spectra, autospectrum, solves, coherence).
    f : ndarray, shape (n_f,)
    H : ndarray of complex, shape (len(outputs), 11, n_f)
    coh : ndarray, shape (len(outputs), n_f)
        Multiple coherence.
    """
    kw = dict(fs=session.fs_hz, window=settings["window"], nperseg=settings["nperseg"],
              noverlap=settings["noverlap"], detrend="constant")
    m = 4 + len(RIG_INPUTS)
    t0 = time.perf_counter()
    inputs, weights = [], []
    Suu = None
    for run in session.runs:
        u = _run_inputs(run, cbar)
        # csd averages the blocks of a run; weight each run by its block count so
        # that runs of different lengths count as in a pooled sum (here all are equal)
        n_blocks = 1 + (u.shape[1] - kw["nperseg"]) // (kw["nperseg"] - kw["noverlap"])
        for i in range(m):
            for j in range(m):
                f, Pij = signal.csd(u[i], u[j], **kw)
                if Suu is None:
                    Suu = np.zeros((m, m, f.size), dtype=complex)
                Suu[i, j] += n_blocks * Pij
        inputs.append(u)
        weights.append(n_blocks)
    t_inputs = time.perf_counter() - t0
    H = np.empty((len(outputs), m, f.size), dtype=complex)
    coh = np.empty((len(outputs), f.size))
    t_outputs = []
    for o, name in enumerate(outputs):
        t0 = time.perf_counter()
        Suy = np.zeros((m, f.size), dtype=complex)
        Syy = np.zeros(f.size)
        for run, u, n_blocks in zip(session.runs, inputs, weights):
            y = run.dynamic(name)
            for i in range(m):
                Suy[i] += n_blocks * signal.csd(u[i], y, **kw)[1]  # conj(U_i) Y
            Syy += n_blocks * signal.welch(y, **kw)[1]
        for k in range(f.size):
            H[o, :, k] = np.linalg.solve(Suu[:, :, k], Suy[:, k])  # S_uu H^T = S_uy
        with np.errstate(invalid="ignore", divide="ignore"):
            coh[o] = np.where(Syy > 0, np.real(np.sum(np.conj(Suy) * H[o], axis=0)) / Syy, 0.0)
        t_outputs.append(time.perf_counter() - t0)
    return t_inputs, t_outputs, f, H, coh


# ---------------------------------------------------------------------------------------
# main
# ---------------------------------------------------------------------------------------

def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=2,
                        help="timed calls of identify_session and of each stage (default 2)")
    parser.add_argument("--ref-outputs", type=int, default=3,
                        help=f"outputs the csd reference is run for, scaled to all (default 3, "
                             f"at most {len(REF_OUTPUTS)})")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    if not 1 <= args.ref_outputs <= len(REF_OUTPUTS):
        parser.error(f"--ref-outputs must be in 1..{len(REF_OUTPUTS)}")

    print(f"engine version: {_engine_version()}")
    print(f"machine: {os.cpu_count()} CPUs, 1-min load average before the run: "
          f"{os.getloadavg()[0]:.2f} (timings are only comparable on an idle machine)")

    # 1. the session (not timed) ------------------------------------------------------------
    t0 = time.perf_counter()
    session = simulate_session()
    build_s = time.perf_counter() - t0
    n_ch = len(session.runs[0].channels)
    total_s = sum(r.n_samples for r in session.runs) / session.fs_hz
    nbytes = sum(np.asarray(v).nbytes for r in session.runs for v in r.channels.values())
    print(f"session: {session.name!r} built once in memory with ident.sim.virtual_rig.simulate_session() "
          f"in {build_s:.1f} s (NOT part of any timing below): {len(session.runs)} runs, "
          f"{total_s:g} s of data at {session.fs_hz:g} Hz, {n_ch} channels per run, "
          f"{_mib(nbytes):.0f} MiB of samples")

    # 2. the engine -------------------------------------------------------------------------
    caught = _Caught()
    times, loads = [], []
    model = None
    for _ in range(args.repeat):
        model = None
        gc.collect()
        t, model, ld = _timed(lambda: identify_session(session), caught)
        times.append(t)
        loads.append(ld)
    ident_s = _spread("engine: identify_session(session), all defaults", times, loads)
    print(f"engine: identified model: {len(model.output_names)} outputs x "
          f"{len(model.input_names)} inputs = {model.order.size} pairs, "
          f"{int(model.n_poles.sum())} stored poles, median fit error "
          f"{float(np.median(model.fit_error)):.4f}, FRF settings "
          f"{ {k: model.frf.settings.get(k) for k in ('method', 'estimator', 'nperseg')} }")

    # 3. the stages ---------------------------------------------------------------------------
    default_estimator = model.frf.settings.get("estimator", "welch")
    welch_differs = default_estimator != "welch"
    stage_times = {k: [] for k in ("estimate_frf", "estimate_frf welch", "condition_frf",
                                   "fit_model", "loop_plant", "fit_model vf")}
    stage_loads = {k: [] for k in stage_times}
    frf = cond = None
    for _ in range(args.repeat):
        t, frf, ld = _timed(lambda: estimate_frf(session), caught)
        stage_times["estimate_frf"].append(t)
        stage_loads["estimate_frf"].append(ld)
        if welch_differs:
            t, frf_welch, ld = _timed(lambda: estimate_frf(session, estimator="welch"), caught)
            stage_times["estimate_frf welch"].append(t)
            stage_loads["estimate_frf welch"].append(ld)
        else:
            frf_welch = frf
        t, cond, ld = _timed(lambda: condition_frf(frf), caught)
        stage_times["condition_frf"].append(t)
        stage_loads["condition_frf"].append(ld)
        t, fitted, ld = _timed(lambda: fit_model(cond, name=session.name), caught)
        stage_times["fit_model"].append(t)
        stage_loads["fit_model"].append(ld)
        t, plant, ld = _timed(lambda: fitted.loop_plant(), caught)
        stage_times["loop_plant"].append(t)
        stage_loads["loop_plant"].append(ld)
        t, vf, ld = _timed(lambda: fit_model(cond, method="vf", name=session.name), caught)
        stage_times["fit_model vf"].append(t)
        stage_loads["fit_model vf"].append(ld)
    med = {}
    med["estimate_frf"] = _spread(f"stage: ident.identify.frf.estimate_frf (default estimator "
                                  f"{default_estimator!r})", stage_times["estimate_frf"],
                                  stage_loads["estimate_frf"])
    if welch_differs:
        med["estimate_frf welch"] = _spread(
            "comparison: estimate_frf(session, estimator='welch') (the paper's H1, not used by "
            "identify_session)", stage_times["estimate_frf welch"],
            stage_loads["estimate_frf welch"])
    else:
        med["estimate_frf welch"] = med["estimate_frf"]
    med["condition_frf"] = _spread("stage: ident.identify.condition.condition_frf",
                                   stage_times["condition_frf"], stage_loads["condition_frf"])
    med["fit_model"] = _spread("stage: ident.identify.pipeline.fit_model (invfreqs, default)",
                               stage_times["fit_model"], stage_loads["fit_model"])
    three = med["estimate_frf"] + med["condition_frf"] + med["fit_model"]
    print(f"stage: sum of the three stages of identify_session: {three:.2f} s "
          f"(identify_session median {ident_s:.2f} s)")
    _spread("stage: model.loop_plant() (not in identify_session; balanced truncation of the "
            "shock part)", stage_times["loop_plant"], stage_loads["loop_plant"])
    print(f"stage: loop_plant sizes: rig part {plant.rig.n_states} modal states, shock part "
          f"{plant.shock.n_states} (after reduction)")
    t1, _, ld = _timed(lambda: _single_thread(fitted.loop_plant), caught)
    print(f"comparison: model.loop_plant() with BLAS limited to 1 thread (threadpoolctl), one "
          f"call: {t1:.2f} s (1-min load after: {ld:.2f})")
    vf_s = _spread("comparison: fit_model(frf, method='vf')", stage_times["fit_model vf"],
                   stage_loads["fit_model vf"])
    print(f"comparison: vf fit: {vf.settings.get('n_poles_vf')} common poles, median fit error "
          f"{float(np.median(vf.fit_error)):.4f} "
          f"(invfreqs {float(np.median(fitted.fit_error)):.4f}); "
          f"invfreqs / vf time: {med['fit_model'] / vf_s:.1f}x")
    if caught.counts:
        print("warnings raised by the timed calls (all calls together): "
              + ", ".join(f"{k} x{v}" for k, v in sorted(caught.counts.items())))
    del fitted, vf, plant, cond

    # 4. memory -------------------------------------------------------------------------------
    model = None
    gc.collect()
    tracemalloc.start()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            model = identify_session(session)
            traced_s = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    print(f"memory: tracemalloc peak of one identify_session call: {_mib(peak):.0f} MiB "
          f"(that call took {traced_s:.1f} s under tracemalloc, not a timing figure)")
    print(f"memory: ru_maxrss of the process so far (session, engine calls): "
          f"{_maxrss_mib():.0f} MiB")

    # 5. reference ------------------------------------------------------------------------------
    outs = REF_OUTPUTS[:args.ref_outputs]
    frf = frf_welch  # the reference is a Welch H1: compare it with the engine's Welch H1
    t_in, t_out, f_ref, H_ref, coh_ref = reference_frf(session, outs, frf.cbar_n_s_m, frf.settings)
    p = len(frf.output_names)
    per_output = statistics.mean(t_out)
    ref_total = t_in + per_output * p
    print(f"reference: scipy.signal.csd, 11x11 input spectral matrix over {len(session.runs)} "
          f"runs ({len(session.runs) * 121} csd calls): {t_in:.2f} s ({_load()})")
    print(f"reference: per output (11 csd + 1 welch per run, {f_ref.size} solves): "
          f"{per_output:.2f} s, mean of {len(outs)} outputs {list(outs)} ({_load()})")
    print(f"reference: scaled to all {p} outputs: {ref_total:.1f} s")
    print(f"ratio reference / engine estimate_frf, like for like (estimator 'welch', median "
          f"{med['estimate_frf welch']:.2f} s): {ref_total / med['estimate_frf welch']:.1f}x")
    if welch_differs:
        print(f"ratio reference / engine estimate_frf as identify_session runs it (estimator "
              f"{default_estimator!r}, median {med['estimate_frf']:.2f} s; a different estimator, "
              f"so a cost comparison only): {ref_total / med['estimate_frf']:.1f}x")
    band = (frf.f_hz >= COMPARE_BAND_HZ[0]) & (frf.f_hz <= COMPARE_BAND_HZ[1])
    if not np.allclose(f_ref, frf.f_hz):
        print("reference: frequency grids differ from the engine's; no comparison")
    else:
        worst_h, worst_c = 0.0, 0.0
        for o, name in enumerate(outs):
            oi = frf.output_names.index(name)
            He = frf.H[oi][:, band]
            Hr = H_ref[o][:, band]
            scale = np.maximum(np.abs(He).max(axis=1, keepdims=True), 1e-300)
            worst_h = max(worst_h, float(np.max(np.abs(Hr - He) / scale)))
            worst_c = max(worst_c, float(np.max(np.abs(coh_ref[o][band]
                                                       - frf.multiple_coherence[oi][band]))))
        print(f"reference vs engine (estimator 'welch'), "
              f"{COMPARE_BAND_HZ[0]:g}-{COMPARE_BAND_HZ[1]:g} Hz, "
              f"{len(outs)} outputs x 11 inputs: largest |H_ref - H_engine| / max|H_engine| per "
              f"pair: {worst_h:.2e}; largest multiple-coherence difference: {worst_c:.2e}")

    # 6. target ---------------------------------------------------------------------------------
    print(f"memory: ru_maxrss at the end of the script: {_maxrss_mib():.0f} MiB")
    verdict = "PASS" if ident_s < TARGET_S else "FAIL"
    print(f"target: identify < {TARGET_S:g} s (identify_session median {ident_s:.2f} s, "
          f"{_load()} at the end): {verdict}")


if __name__ == "__main__":
    main()
