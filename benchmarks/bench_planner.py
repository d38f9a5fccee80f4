"""Benchmark of the planner: time-domain prediction, screening and ranking memory.

Run::

    python benchmarks/bench_planner.py [--repeat N] [--ref-seconds S] [--ref-setups K]
                                       [--ref-screen-setups M] [--accuracy-setups A]
                                       [--memory-setups P] [--sweep-setups W]
                                       [--elements-repeat E] [--elements-only]
                                       [--histograms-only] [--time-domain-only]
                                       [--screening-only]

Two models, each reported: the known paper car
(``ident.models.vehicle.build_full_car(example_vehicle())``) and a model identified from
the paper session (``ident.sim.virtual_rig.simulate_session()`` then
``ident.identify.pipeline.identify_session``, built once and not timed). The identified one
is the product's case. One drive: ``ident.data.drive.make_track_drive(duration_s=120,
fs_hz=100, seed=1, ...)`` with the paper car's wheelbase and track. Shocks: the
built-in crate ``planner/examples/library.toml``; setups from
``planner.setups.enumerate_setups`` with its defaults (left/right symmetric) and
with ``symmetry="none", max_setups=None`` (every corner free); both respect the
crate's inventory (two shock kinds exist twice only), so there are slightly fewer
than 11^2 and 11^4.

Prints, one figure per line, each timing with the machine's 1-minute load average
at that moment:

1. time-domain prediction: one warm-up call (numba: compile or cache load), then
   per model and for ``oversample`` 4 and 2 (the default) the median, min and max
   wall time of ``--repeat`` calls of ``planner.predict.predict_setups(model, drive,
   setups, library, oversample=...)`` on all symmetric setups, as setups per second:
   with the model object as given (as ``rank_setups`` calls it: each call turns it
   into a :class:`ident.models.lti.LoopPlant`, a balanced truncation for an
   identified model) and with a LoopPlant built beforehand. Every call also
   computes the setup-independent rig response. Both are also timed alone (the first
   also with BLAS limited to one thread by ``threadpoolctl``: on a busy 2-core
   machine multithreaded BLAS can be many times slower). This
   process's ``ru_maxrss`` after the timed calls (it includes the identification);
2. accuracy of oversample 2 and 4: the metrics of ``--accuracy-setups`` setups
   against ``oversample=16`` (max and median relative difference over setups and
   metrics), since throughput trades against it; ``ru_maxrss`` after the
   oversample-16 run (the engine keeps the rig part's modal states on the internal
   grid, which grows with the oversampling and the model's rig modes);
3. a straightforward time-domain reference: for ``--ref-setups`` setups, one at a
   time, ``scipy.integrate.solve_ivp`` (RK45, ``rtol=1e-6``, ``atol`` 1e-6 of each
   state's RMS from a first loose pass) on the same closed loop as the engine (the
   model's LoopPlant: its shock part in real modal form, the nonlinear shock curves,
   one lag state per lagged shock, ``dF = F - c_bar v``) over the first
   ``--ref-seconds`` of the drive, scaled to 120 s. The setup-independent rig
   contribution (``v_rig``, ``y_rig``) is taken from the engine's ``rig_response``
   on a 16x grid, linearly interpolated, and not charged to the reference (the
   engine computes it once per call too): this favours the reference. Printed:
   reference setups/s, the ratio engine / reference, and the engine
   (``oversample=16``) against the reference on that segment (relative RMS
   difference), which shows that both simulate the same loop;
4. screening: ``planner.screen.screen_setups(model, drive, setups, library)`` on the
   symmetric setups and on every-corner-free setups, as setups per second: with the
   model object as given (each call builds its LoopPlant) and with a LoopPlant
   built beforehand. Reference: the same stochastic linearization (same bands,
   same secant-accelerated fixed point on the shock-velocity RMS, same tolerance)
   in plain numpy, a Python loop over setups and over frequency bands with one
   4x4 ``numpy.linalg.solve`` per band and iteration, for ``--ref-screen-setups``
   setups; its setup-independent part is computed once and not charged; the ratio
   engine / reference and the largest relative difference of the metrics; the same ratio
   in CPU time (all threads; one more engine call, every corner free, model as given),
   which a loaded machine distorts less than the wall times;
5. memory of ranking ``--memory-setups`` (default 100,000) screened setups: in a
   child process started at the beginning, while this one is small (on Linux a
   forked process's ``ru_maxrss`` includes its parent's high-water mark, so a child
   started after the identification and the predictions would report theirs), the
   identified model is handed over in a temporary file, the every-corner-free
   setups are cycled (renamed) up to that count, then ``screen_setups`` and
   ``planner.objective.score_setups`` with ``default_objective()`` and the
   baseline the setup with B20 at every corner; the ``tracemalloc`` peak of that
   screening + scoring and the child's ``ru_maxrss`` (which also counts the
   imports and the model);
   Then a crate sweep: one ``predict_setups`` call on the first ``--sweep-setups``
   (default 2,000) every-corner-free setups, where the drive's rig part is shared by
   many setups as in a real sweep (one call, so the load is printed with it);
6. the real car's elements (issue 25): the GT-like car
   (``build_full_car(example_gt_vehicle())``) on its own track drives (120 s at 100 Hz, the
   car's wheelbase and track, 1.5 kN of aero heave), the symmetric setups through
   ``ident.sim.closedloop.simulate_batch_metrics`` (oversample 2, the metric outputs, the
   rig response in every call as ``predict_setups`` does) without and with bump stops
   (progressive, 100-600 kN/m, contact at ``STOP_GAPS_M`` from rest: touched 4-8 % of the
   time at the front), and on a rougher drive without and with the car's static loads
   (lift-off); calls alternate between the two, ``--elements-repeat`` times; printed: the
   median wall and CPU times (all threads) of each, the ratio of the CPU times (the
   issue's target: at most 1.3x with bump stops; the wall time of a loaded shared machine
   carries the other processes' load) and the contact and lift-off shares over the setups. ``--elements-only`` runs this part
   alone;
7. the shock-velocity histograms (issue 39): the known paper car's symmetric setups through
   ``simulate_batch_metrics`` without and with ``histogram_bins`` (the default 22 bins),
   alternating, ``--elements-repeat`` times: setups per second of each (wall) and the ratio
   of the CPU times. ``--histograms-only`` runs this part alone;
   ``--time-domain-only`` runs parts 1-3 alone on the identified model (issue 40);
   ``--screening-only`` part 4 alone on the identified model (issue 40);
8. ``target: ...: PASS/FAIL`` lines: time-domain >= 200 setups/s (oversample 2,
   the default; on the symmetric setups, one call per 119 setups, and on the sweep) and screening >= 10,000 setups/s (every-corner-free setups), each
   for each model given as is (the product's path); peak memory < 2 GB (the
   child's ``ru_maxrss``, the larger and all-inclusive figure); time-domain prediction with
   bump stops at most 1.3x the time without them.

This is a script, not part of the package: it prints. It writes only a temporary
model file for the child process (removed at the end); numba may update its own
cache in ``ident/__pycache__`` and ``planner/__pycache__``.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
from scipy import signal
from scipy.integrate import solve_ivp
from threadpoolctl import threadpool_limits

# benchmark the working tree this script lives in, installed or not
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ident.data.channels import CORNERS  # noqa: E402
from ident.sim.closedloop import rig_response, simulate, simulate_batch_metrics  # noqa: E402
from ident.data.drive import make_track_drive  # noqa: E402
from ident.models.library import read_shock_library  # noqa: E402
from ident.models.vehicle import build_full_car, example_gt_vehicle, example_vehicle  # noqa: E402
from planner.objective import default_objective, score_setups  # noqa: E402
from planner.plant import as_loop_plant
from planner.predict import METRIC_OUTPUTS, predict_setups  # noqa: E402
from planner.screen import drive_spectrum, metric_rows, screen_setups  # noqa: E402
from planner.setups import Setup, enumerate_setups  # noqa: E402
from _common import drive_segment, rel_rms  # noqa: E402
from _common import engine_version as _engine_version  # noqa: E402
from _common import jit_source as _jit_source, load as _load, mib as _mib  # noqa: E402
from planner.options import LoopOptions

LIBRARY_PATH = ROOT / "planner" / "examples" / "library.toml"
DRIVE_S = 120.0
FS_HZ = 100.0
DRIVE_SEED = 1
#: Oversampling factors timed, the default last; and the accuracy reference.
OVERSAMPLES = (4, 2)
OVERSAMPLE_DEFAULT = 2
OVERSAMPLE_FINE = 16
#: The issue's targets.
TARGET_TIME_SETUPS_S = 200.0
TARGET_SCREEN_SETUPS_S = 10_000.0
TARGET_MEMORY_BYTES = 2 * 2**30
TARGET_ELEMENT_RATIO = 1.3
#: Screening with bump stops (their stochastic linearization) against without, same setups.
TARGET_ELEMENT_SCREEN_RATIO = 1.5
#: The elements' case (issue 25): a progressive bump stop (100, 267, 500, 600 kN/m over 15 mm
#: beyond contact), touching at these shock travels from rest (front, rear) [m]: on the
#: roughness-16e-6 drive with the B20 baseline the front is beyond 5 mm about 6 % of the time
#: without stops (quantiles measured); the lift-off drive is twice as rough (the rear tires
#: leave the pads 1-3 % of the time at the car's static loads).
STOP_TRAVEL_M = (0.0, 0.002, 0.005, 0.010, 0.015)
STOP_FORCE_N = (0.0, 200.0, 1000.0, 3500.0, 6500.0)
STOP_GAPS_M = (0.005, 0.006)
ELEMENT_ROUGHNESS_M3 = {"bump stops": 16e-6, "static loads": 32e-6}
ELEMENT_AERO = {"aero_heave": 1500.0, "aero_pitch": 800.0, "aero_roll": 300.0}
#: Reference integration tolerance (as bench_rig.py) and the loose first pass that
#: measures each state's size for the absolute tolerance.
REF_RTOL = 1e-6
REF_ATOL_OF_RMS = 1e-6
SCALE_PASS_RTOL = 1e-3
#: Channels compared between engine and time-domain reference.
COMPARED = ("shock_velocity_LF", "tire_force_LF", "ride_height_LF")
#: Screening settings (screen_setups' defaults), mirrored by the reference.
BAND_HZ = (1.0, 20.0)
N_BANDS = 96
MAX_ITER = 30
TOL = 1e-5






def _maxrss_bytes():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024






def _time(fn, repeat):
    """Wall times and the 1-min load after each of `repeat` calls; the last result."""
    times, loads, out = [], [], None
    for _ in range(repeat):
        out = None
        gc.collect()
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
        loads.append(os.getloadavg()[0])
    return times, loads, out


def _rate_line(label, n, times, loads):
    """Print setups/s from the median time; return that rate."""
    med = statistics.median(times)
    rate = n / med
    print(f"{label}: {rate:,.0f} setups/s ({n} setups, median {med:.3f} s of {len(times)}, "
          f"min {min(times):.3f}, max {max(times):.3f}; 1-min load after each: "
          + ", ".join(f"{x:.2f}" for x in loads) + ")")
    return rate


def _spread_idx(n_items, k, *, skip_ends=False):
    """k indices spread evenly over range(n_items) (optionally away from both ends)."""
    if skip_ends:
        return np.linspace(0, n_items - 1, k + 2).round().astype(int)[1:-1].tolist()
    return np.unique(np.linspace(0, n_items - 1, k).round().astype(int)).tolist()




# ---------------------------------------------------------------------------------------
# time-domain reference: solve_ivp on the plant's closed loop, one setup at a time
# ---------------------------------------------------------------------------------------

def rig_part(plant, seg, r):
    """The setup-independent rig contribution on an r-times finer grid (engine's rig_response).

    Returns
    -------
    v_rig : ndarray, shape (4, n_fine)
        Shock velocities from the rig inputs alone.
    y_rig : ndarray, shape (p, n_samples)
        Every plant output from the rig inputs alone, at the drive's samples.
    fs_fine : float
    """
    rr = rig_response(plant, seg, oversample=r)
    v_rig = rr.v_fine.T
    y_rig = rr.y
    return v_rig, y_rig, seg.fs_hz * r


def reference_closed_loop(plant, shocks, v_rig, y_rig, fs_fine, fs_out, *, rtol, atol):
    """Integrate the shock loop of a LoopPlant with ``solve_ivp`` (RK45).

    State: the plant's shock part in real modal form ``x`` (``x' = A x + B dF``)
    and one force per lagged shock (``tau F' + F = f(v)``). ``v = v_rig(t) + C_v x``
    (the shock velocities have no feedthrough from ``dF``), ``F_i = f_i(v_i)`` for a
    shock without lag, ``dF = F - c_bar v``. ``v_rig`` is linear between its samples.

    Returns
    -------
    elapsed_s : float
        Wall time of ``solve_ivp`` alone.
    nfev : int
    y : ndarray, shape (p, n_out)
        Every plant output at ``k / fs_out``.
    state_rms : ndarray
        RMS of every ODE state over the output samples.
    """
    A, B, C, D = plant.shock.to_real()
    vi = plant.velocity_idx
    if np.any(D[vi] != 0):
        raise ValueError("the reference assumes no feedthrough from dF to the shock velocities")
    A, B, Cv = (np.ascontiguousarray(M) for M in (A, B, C[vi]))
    nx = A.shape[0]
    cbar = plant.cbar_n_s_m
    lag = np.array([s.lag_s for s in shocks])
    lagged = np.flatnonzero(lag > 0)
    static = np.flatnonzero(lag == 0)
    tau = lag[lagged]
    dV = np.diff(v_rig, axis=1)
    k_last = v_rig.shape[1] - 2

    def velocities(t, x):
        p = t * fs_fine
        k = min(int(p), k_last)
        return v_rig[:, k] + (p - k) * dV[:, k] + Cv @ x

    def rhs(t, s):
        x = s[:nx]
        v = velocities(t, x)
        F = np.empty(4)
        ds = np.empty_like(s)
        for i in static:
            F[i] = shocks[i].force(v[i])
        for j, i in enumerate(lagged):
            F[i] = s[nx + j]
            ds[nx + j] = (shocks[i].force(v[i]) - s[nx + j]) / tau[j]
        ds[:nx] = A @ x + B @ (F - cbar * v)
        return ds

    n_out = y_rig.shape[1]
    t_eval = np.arange(n_out) / fs_out
    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), np.zeros(nx + lagged.size), method="RK45",
                    t_eval=t_eval, rtol=rtol, atol=atol)
    elapsed = time.perf_counter() - t0
    if not sol.success:
        raise RuntimeError(f"reference solve_ivp failed: {sol.message}")
    X = sol.y[:nx]
    V = np.column_stack([velocities(t, X[:, k]) for k, t in enumerate(t_eval)])
    F = np.empty((4, n_out))
    for i in static:
        F[i] = shocks[i].force(V[i])
    for j, i in enumerate(lagged):
        F[i] = sol.y[nx + j]
    dF = F - cbar[:, None] * V
    y = y_rig + C @ X + D @ dF
    return elapsed, int(sol.nfev), y, np.sqrt(np.mean(sol.y**2, axis=1))




# ---------------------------------------------------------------------------------------
# screening reference: plain numpy, one setup and one band at a time
# ---------------------------------------------------------------------------------------

def screening_inputs(plant, drive):
    """The setup-independent arrays of the screening (as ``screen_setups`` builds them)."""
    names, L = metric_rows(plant)
    sos = signal.butter(4, BAND_HZ, "bandpass", fs=drive.fs_hz, output="sos")

    def b4(f_hz):
        return np.abs(signal.sosfreqz(sos, worN=f_hz, fs=drive.fs_hz)[1]) ** 4

    f, S = drive_spectrum(drive, n_bands=N_BANDS)
    _, SB = drive_spectrum(drive, n_bands=N_BANDS, weight=b4)
    keep = np.any(np.abs(S) > 0, axis=(1, 2))
    f, S, SB = f[keep], S[keep], SB[keep]
    H = plant.frequency_response(f)
    vi = plant.velocity_idx
    Hvr = np.transpose(H[vi, :7], (2, 0, 1))                    # (nf, 4, 7)
    Hvs = np.transpose(H[vi, 7:], (2, 0, 1))                    # (nf, 4, 4)
    Hyr = np.einsum("mo,oif->fmi", L, H[:, :7])                 # (nf, p, 7)
    Hys = np.einsum("mo,oif->fmi", L, H[:, 7:])                 # (nf, p, 4)
    St, SBt = np.transpose(S, (0, 2, 1)), np.transpose(SB, (0, 2, 1))
    HvrH = np.conj(np.transpose(Hvr, (0, 2, 1)))
    return {"names": names, "w": 2 * np.pi * f, "Hvs": Hvs, "Hys": Hys,
            "P": Hvr @ St @ HvrH, "PB": Hvr @ SBt @ HvrH,
            "QB": Hvr @ SBt @ np.conj(np.transpose(Hyr, (0, 2, 1))),
            "d0": np.real(np.einsum("fmi,fij,fmj->fm", Hyr, SBt, np.conj(Hyr))),
            "cbar": plant.cbar_n_s_m}


def screen_reference_one(shocks, pre):
    """Metrics (RMS) of one setup by stochastic linearization, plain numpy per band."""
    w, Hvs, Hys, P, PB, QB, d0, cbar = (pre[k] for k in ("w", "Hvs", "Hys", "P", "PB", "QB",
                                                         "d0", "cbar"))
    lag = np.array([s.lag_s for s in shocks])
    eye = np.eye(4)
    sig = np.sqrt(np.maximum(np.real(np.einsum("faa->a", P)), 1e-18))
    s_prev, h_prev = np.zeros(4), np.zeros(4)

    def ceq(sigma):
        return np.array([float(s.equivalent_damping(max(x, 1e-9))) for s, x in zip(shocks, sigma)])

    for it in range(MAX_ITER):
        c = ceq(sig)
        svv = np.zeros(4)
        for k in range(w.size):
            d = c / (1.0 + 1j * w[k] * lag) - cbar
            K = np.linalg.solve(eye - Hvs[k] * d[None, :], eye)     # (I - H_vs diag(d))^-1
            svv += np.real(np.einsum("ca,ab,cb->c", K, P[k], np.conj(K)))
        new = np.sqrt(np.maximum(svv, 0.0))
        change = float(np.max(np.abs(new - sig) / np.maximum(sig, 1e-12)))
        h = new - sig
        nxt = np.where(new > 0, new, 0.5 * sig)
        if it > 0:  # secant step on h(sigma) = g(sigma) - sigma, safeguarded to a factor 2
            for i in range(4):
                dh, ds = h[i] - h_prev[i], sig[i] - s_prev[i]
                if dh != 0.0 and ds != 0.0:
                    cand = sig[i] - h[i] * ds / dh
                    if 0.5 * sig[i] < cand < 2.0 * sig[i]:
                        nxt[i] = cand
        s_prev, h_prev, sig = sig, h, nxt
        if change < TOL:
            break
    c = ceq(sig)
    power = np.zeros(d0.shape[1])
    for k in range(w.size):
        d = c / (1.0 + 1j * w[k] * lag) - cbar
        K = np.linalg.solve(eye - Hvs[k] * d[None, :], eye)
        W = (Hys[k] * d[None, :]) @ K                                 # (p, 4)
        power += (d0[k] + 2.0 * np.real(np.einsum("pb,bp->p", W, QB[k]))
                  + np.real(np.einsum("pa,ab,pb->p", W, PB[k], np.conj(W))))
    return np.sqrt(np.maximum(power, 0.0))


# ---------------------------------------------------------------------------------------
# memory child
# ---------------------------------------------------------------------------------------

def _make_drive(vehicle):
    return make_track_drive(duration_s=DRIVE_S, fs_hz=FS_HZ, seed=DRIVE_SEED,
                            wheelbase_m=vehicle.a_m + vehicle.b_m,
                            track_width_m=vehicle.track_front_m, name="bench track")


def memory_child(n_setups):
    """Read a model path from stdin, screen and score `n_setups` setups; print lines and JSON.

    Started before the parent grows (see :func:`start_memory_child`): on Linux a
    process's ``ru_maxrss`` includes the high-water mark of the process it was
    forked from, so a child forked late would report the parent's peak.
    """
    from ident.identify.model import load_model

    line = sys.stdin.readline().strip()
    if not line:
        return  # the parent gave up
    warnings.simplefilter("ignore")
    model = load_model(line)
    library = read_shock_library(LIBRARY_PATH)
    drive = _make_drive(example_vehicle())
    base = enumerate_setups(library, symmetry="none", max_setups=None)
    tracemalloc.start()
    setups = list(base)
    rep = 1
    while len(setups) < n_setups:
        setups.extend(Setup(f"{s.name} #{rep}", dict(s.shocks)) for s in base)
        rep += 1
    del setups[n_setups:]
    held = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    rss0 = _maxrss_bytes()
    baseline = "/".join(["B20"] * 4)
    print(f"memory: {len(setups):,} setups: the {len(base):,} every-corner-free setups and "
          f"renamed copies ({rep} rounds, the last cut); the copies hold {_mib(held):.0f} MiB "
          "(traced)")
    gc.collect()
    tracemalloc.start()
    try:
        t0 = time.perf_counter()
        screened = screen_setups(model, drive, setups, library)
        scores = score_setups(screened.table, default_objective(), baseline=baseline)
        elapsed = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    rss = _maxrss_bytes()
    n_feasible = int(scores.table["feasible"].sum())
    print(f"memory: screen_setups + score_setups (identified model as given, baseline "
          f"{baseline!r}) of {len(setups):,} setups: tracemalloc peak {_mib(peak):.0f} MiB "
          f"({elapsed:.1f} s under tracemalloc, not a timing figure; {_load()}; "
          f"{n_feasible:,} feasible)")
    print(f"memory: child process ru_maxrss {_mib(rss):.0f} MiB (imports, model, drive, setups "
          f"and the screening + scoring; before screening: {_mib(rss0):.0f} MiB)")
    print(json.dumps({"peak": peak, "rss": rss, "n": len(setups)}))


def start_memory_child(n_setups):
    """Start the memory child now, while this process is small; it waits for a model path."""
    return subprocess.Popen([sys.executable, __file__, "--memory-child",
                             "--memory-setups", str(n_setups)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def run_memory_child(proc, model):
    """Hand `model` (saved to a temporary file) to the waiting child; print its lines."""
    with tempfile.TemporaryDirectory(prefix="bench_planner_") as tmp:
        path = Path(tmp) / "model.npz"
        model.save(path)
        out, err = proc.communicate(str(path) + "\n")
    if proc.returncode != 0:
        print(out, end="")
        print(err, end="", file=sys.stderr)
        raise RuntimeError("the memory child process failed")
    lines = out.strip().splitlines()
    for line in lines[:-1]:
        print(line)
    return json.loads(lines[-1])


# ---------------------------------------------------------------------------------------
# per model
# ---------------------------------------------------------------------------------------

def bench_time_domain(label, model, drive, setups, library, args):
    """Time-domain throughput, accuracy vs oversample 16, and the solve_ivp reference."""
    t0 = time.perf_counter()
    plant = as_loop_plant(model)
    t_plant = time.perf_counter() - t0
    rates, prebuilt, tables = {}, {}, {}
    for ov in OVERSAMPLES:
        times, loads, pred = _time(lambda: predict_setups(model, drive, setups, library,
                                                          loop=LoopOptions(oversample=ov)),
                                                          args.repeat)
        rates[ov] = _rate_line(f"time domain [{label}]: predict_setups, model as given, "
                               f"oversample {ov}", len(setups), times, loads)
        times, loads, pred = _time(lambda: predict_setups(plant, drive, setups, library,
                                                          loop=LoopOptions(oversample=ov)),
                                                          args.repeat)
        prebuilt[ov] = _rate_line(f"time domain [{label}]: predict_setups, prebuilt LoopPlant, "
                                  f"oversample {ov}", len(setups), times, loads)
        tables[ov] = pred.table
    free = list(enumerate_setups(library, symmetry="none", max_setups=None))
    sweep = free[:args.sweep_setups]
    t0 = time.perf_counter()
    predict_setups(model, drive, sweep, library, loop=LoopOptions(oversample=OVERSAMPLE_DEFAULT))
    dt = time.perf_counter() - t0
    rates["sweep"] = len(sweep) / dt
    print(f"time domain [{label}]: crate sweep, predict_setups on {len(sweep):,} "
          f"every-corner-free setups, oversample {OVERSAMPLE_DEFAULT}, one call: {dt:.2f} s, "
          f"{rates['sweep']:,.1f} setups/s ({_load()})")
    with threadpool_limits(1):
        t0 = time.perf_counter()
        as_loop_plant(model)
        t_plant_1 = time.perf_counter() - t0
    t0 = time.perf_counter()
    rig_response(plant, drive, oversample=OVERSAMPLE_DEFAULT)
    t_rig = time.perf_counter() - t0
    print(f"time domain [{label}]: setup-independent work in every call: model -> LoopPlant "
          f"{t_plant:.2f} s (with BLAS limited to 1 thread: {t_plant_1:.2f} s), rig_response "
          f"(oversample {OVERSAMPLE_DEFAULT}) {t_rig:.2f} s ({_load()}); plant: "
          f"{plant.shock.n_states} shock-loop modes, {plant.rig.n_states} rig modes")
    print(f"memory: this process's ru_maxrss after the timed predictions [{label}]: "
          f"{_mib(_maxrss_bytes()):.0f} MiB (high-water mark since the start, identification "
          "included)")

    # accuracy against oversample 16
    idx = _spread_idx(len(setups), args.accuracy_setups)
    few = [setups[i] for i in idx]
    fine = predict_setups(plant, drive, few, library,
                          loop=LoopOptions(oversample=OVERSAMPLE_FINE)).table
    print(f"memory: this process's ru_maxrss after predicting {len(few)} setups at oversample "
          f"{OVERSAMPLE_FINE} [{label}]: {_mib(_maxrss_bytes()):.0f} MiB")
    metrics = [c for c in fine.columns if c not in CORNERS]
    ref = fine[metrics].to_numpy(dtype=float)
    for ov in OVERSAMPLES:
        got = tables[ov].loc[[s.name for s in few], metrics].to_numpy(dtype=float)
        err = np.abs(got - ref) / np.abs(ref)
        print(f"accuracy [{label}]: oversample {ov} vs {OVERSAMPLE_FINE}, {len(few)} setups x "
              f"{len(metrics)} metrics: max relative difference {100 * err.max():.3f} %, "
              f"median {100 * np.median(err):.4f} %")

    # reference: solve_ivp, one setup at a time, on a segment
    seg = drive_segment(drive, args.ref_seconds)
    v_rig, y_rig, fs_fine = rig_part(plant, seg, OVERSAMPLE_FINE)
    ref_times, worst = [], 0.0
    for i in _spread_idx(len(setups), args.ref_setups, skip_ends=True):
        s = setups[i]
        shocks = s.resolve(library)
        # loose first pass: each state's size, for the absolute tolerance
        _, _, _, rms = reference_closed_loop(plant, shocks, v_rig, y_rig, fs_fine, seg.fs_hz,
                                             rtol=SCALE_PASS_RTOL, atol=1e-12)
        atol = REF_ATOL_OF_RMS * np.maximum(rms, 1e-6 * max(rms.max(), 1e-30))
        el, nfev, y, _ = reference_closed_loop(plant, shocks, v_rig, y_rig, fs_fine, seg.fs_hz,
                                               rtol=REF_RTOL, atol=atol)
        ref_times.append(el)
        print(f"reference [{label}]: solve_ivp RK45 rtol={REF_RTOL:g}, setup {s.name!r}, "
              f"{args.ref_seconds:g} s of drive: {el:.2f} s ({nfev} RHS evaluations; {_load()})")
        eng = simulate(plant, seg, shocks, oversample=OVERSAMPLE_FINE)
        for ch in COMPARED:
            o = plant.output_names.index(ch)
            worst = max(worst, rel_rms(eng.channels[ch], y[o]))
    per_setup_ref = statistics.mean(ref_times) * DRIVE_S / args.ref_seconds
    ref_rate = 1.0 / per_setup_ref
    print(f"reference [{label}]: scaled to {DRIVE_S:g} s: {per_setup_ref:.1f} s per setup = "
          f"{ref_rate:.4f} setups/s (the shared rig contribution not charged)")
    for ov in OVERSAMPLES:
        print(f"ratio engine / reference throughput [{label}], oversample {ov}: "
              f"{rates[ov] / ref_rate:,.0f}x (prebuilt LoopPlant: {prebuilt[ov] / ref_rate:,.0f}x)")
    print(f"reference [{label}]: engine (oversample {OVERSAMPLE_FINE}) vs reference on the "
          f"segment, largest relative RMS difference over {list(COMPARED)}: {100 * worst:.3f} %")
    return rates, plant


def bench_screening(label, model, plant, drive, sym, free, library, args):
    """Screening throughput (model as given and prebuilt plant) and the numpy reference."""
    rate = {}
    for what, m in (("model as given", model), ("prebuilt LoopPlant", plant)):
        for name, ss in (("symmetric", sym), ("every corner free", free)):
            times, loads, out = _time(lambda: screen_setups(m, drive, ss, library), args.repeat)
            rate[(what, name)] = _rate_line(f"screening [{label}]: {name}, {what}", len(ss),
                                            times, loads)
    engine = out.table  # prebuilt plant, every corner free
    # CPU time (all threads) of one more call, model as given: on a loaded machine the wall
    # time of the 2-thread engine and of the 1-thread reference suffer differently
    c0 = time.process_time()
    screen_setups(model, drive, free, library)
    cpu_engine = time.process_time() - c0
    pre = screening_inputs(plant, drive)
    idx = _spread_idx(len(free), args.ref_screen_setups)
    t0, c0 = time.perf_counter(), time.process_time()
    ref = np.array([screen_reference_one(free[i].resolve(library), pre) for i in idx])
    el, cpu_ref = time.perf_counter() - t0, time.process_time() - c0
    ref_rate = len(idx) / el
    print(f"reference [{label}]: numpy screening, {len(idx)} setups one by one, "
          f"{pre['w'].size} bands: {el:.2f} s = {ref_rate:.1f} setups/s ({_load()})")
    print(f"cpu time [{label}]: screening every corner free (model as given) "
          f"{1e6 * cpu_engine / len(free):.1f} us per setup, reference "
          f"{1e6 * cpu_ref / len(idx):,.0f} us per setup: ratio "
          f"{(cpu_ref / len(idx)) / (cpu_engine / len(free)):,.0f}x")
    got = engine.iloc[idx][pre["names"]].to_numpy(dtype=float)
    diff = float(np.max(np.abs(got - ref) / np.abs(ref)))
    print(f"reference [{label}]: engine vs numpy screening metrics, largest relative "
          f"difference: {diff:.2e}")
    key = ("model as given", "every corner free")
    print(f"ratio engine / reference screening throughput [{label}] (every corner free, model as "
          f"given): {rate[key] / ref_rate:,.0f}x; with a prebuilt LoopPlant: "
          f"{rate[('prebuilt LoopPlant', 'every corner free')] / ref_rate:,.0f}x")
    return rate[key]


# ---------------------------------------------------------------------------------------
# the real car's elements: bump stops and lift-off against the plain loop
# ---------------------------------------------------------------------------------------

def bench_elements(library, sym, args):
    """Time-domain prediction with bump stops (and with static loads) against without them
    on the GT-like car; returns the ratios ``{"bump stops": r, "static loads": r}``."""
    vehicle = example_gt_vehicle()
    plant = as_loop_plant(build_full_car(vehicle))
    models = [s.resolve(library) for s in sym]
    outputs = [o for o in METRIC_OUTPUTS if o in plant.output_names]
    stops = {c: (STOP_GAPS_M[0] if c[1] == "F" else STOP_GAPS_M[1], STOP_TRAVEL_M, STOP_FORCE_N)
             for c in CORNERS}
    cases = {"bump stops": {"bump_stops": [stops] * len(models)},
             "static loads": {"static_corner_load_n": vehicle.static_corner_load_n}}
    ratios = {}
    for case, kw in cases.items():
        drive = make_track_drive(duration_s=DRIVE_S, fs_hz=FS_HZ, seed=DRIVE_SEED,
                                 roughness_m3=ELEMENT_ROUGHNESS_M3[case],
                                 wheelbase_m=vehicle.a_m + vehicle.b_m,
                                 track_width_m=vehicle.track_front_m, aero=ELEMENT_AERO,
                                 name="GT track")

        def run(kw, drive=drive):
            rig = rig_response(plant, drive, oversample=OVERSAMPLE_DEFAULT, outputs=outputs)
            return simulate_batch_metrics(plant, drive, models, oversample=OVERSAMPLE_DEFAULT,
                                          outputs=outputs, rig=rig, **kw)

        run({})  # warm-up: numba's compile or cache load of both workers
        t0 = time.perf_counter()
        run(kw)
        t_warm = time.perf_counter() - t0
        times = {"without": [], "with": []}
        cpu = {"without": [], "with": []}
        loads = []
        out = None
        for _ in range(args.elements_repeat):
            for what, k in (("without", {}), ("with", kw)):
                gc.collect()
                c0 = time.process_time()
                t0 = time.perf_counter()
                res = run(k)
                times[what].append(time.perf_counter() - t0)
                cpu[what].append(time.process_time() - c0)
                if what == "with":
                    out = res
            loads.append(os.getloadavg()[0])
        med = {w: statistics.median(t) for w, t in times.items()}
        med_cpu = {w: statistics.median(t) for w, t in cpu.items()}
        ratios[case] = med_cpu["with"] / med_cpu["without"]
        vals = out.metrics.values
        key = "bump_stop_contact_share" if case == "bump stops" else "tire_liftoff_share"
        shares = ", ".join(f"{c} {100 * np.median(vals[f'{key}_{c}']):.1f} % "
                           f"({100 * np.min(vals[f'{key}_{c}']):.1f}-"
                           f"{100 * np.max(vals[f'{key}_{c}']):.1f})" for c in CORNERS)
        print(f"elements [GT-like car, {case}]: simulate_batch_metrics of {len(models)} "
              f"symmetric setups, oversample {OVERSAMPLE_DEFAULT}, {DRIVE_S:g} s drive "
              f"(roughness {ELEMENT_ROUGHNESS_M3[case]:g} m^3; rig response in each call), "
              f"medians of {args.elements_repeat} alternating calls: wall without "
              f"{med['without']:.3f} s, with {med['with']:.3f} s ({med['with'] / med['without']:.3f}x); "
              f"CPU time (all threads) without {med_cpu['without']:.3f} s, with "
              f"{med_cpu['with']:.3f} s; wall without: "
              + ", ".join(f"{t:.3f}" for t in times["without"]) + "; with: "
              + ", ".join(f"{t:.3f}" for t in times["with"])
              + "; 1-min load after each pair: " + ", ".join(f"{x:.2f}" for x in loads)
              + f"; warm-up {t_warm:.1f} s")
        print(f"elements [GT-like car, {case}]: ratio with / without {ratios[case]:.3f}x "
              f"(CPU time: on a shared machine the wall time carries the other processes' "
              f"load); {key} median (min-max) over the setups: {shares}")
    # the screening with the stops linearized (equivalent stiffness) against without
    drive = make_track_drive(duration_s=DRIVE_S, fs_hz=FS_HZ, seed=DRIVE_SEED,
                             roughness_m3=ELEMENT_ROUGHNESS_M3["bump stops"],
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m, aero=ELEMENT_AERO,
                             name="GT track")
    many = (sym * max(1, 2000 // max(len(sym), 1)))[:2000]
    many = [Setup(f"s{k}", dict(s.shocks)) for k, s in enumerate(many)]
    kw = {"bump_stops": [stops] * len(many)}
    screen_setups(plant, drive, many[:8], library)  # warm-up: compile or cache load
    screen_setups(plant, drive, many[:8], library, bump_stops=kw["bump_stops"][:8])
    cpu = {"without": [], "with": []}
    for _ in range(args.elements_repeat):
        for what, k in (("without", {}), ("with", kw)):
            gc.collect()
            c0 = time.process_time()
            screen_setups(plant, drive, many, library, **k)
            cpu[what].append(time.process_time() - c0)
    med = {w: statistics.median(t) for w, t in cpu.items()}
    ratios["screening"] = med["with"] / med["without"]
    print(f"elements [GT-like car, screening]: screen_setups of {len(many)} setups, medians of "
          f"{args.elements_repeat} alternating calls, CPU time without {med['without']:.3f} s, "
          f"with bump stops {med['with']:.3f} s: ratio {ratios['screening']:.3f}x")
    return ratios


def bench_histograms(library, sym, args):
    """Time-domain prediction with the shock-velocity histograms counted (issue 39) against
    without, on the paper car and the benchmark's drive; returns the ratio of CPU times."""
    from planner.options import HistogramOptions

    vehicle = example_vehicle()
    plant = as_loop_plant(build_full_car(vehicle))
    drive = _make_drive(vehicle)
    models = [s.resolve(library) for s in sym]
    outputs = [o for o in METRIC_OUTPUTS if o in plant.output_names]
    bins = HistogramOptions().bins

    def run(kw):
        rig = rig_response(plant, drive, oversample=OVERSAMPLE_DEFAULT, outputs=outputs)
        return simulate_batch_metrics(plant, drive, models, oversample=OVERSAMPLE_DEFAULT,
                                      outputs=outputs, rig=rig, **kw)

    t0 = time.perf_counter()
    run({})
    run({"histogram_bins": bins})  # warm-up: numba's compile or cache load of both workers
    t_warm = time.perf_counter() - t0
    wall = {"without": [], "with": []}
    cpu = {"without": [], "with": []}
    for _ in range(args.elements_repeat):
        for what, kw in (("without", {}), ("with", {"histogram_bins": bins})):
            gc.collect()
            c0 = time.process_time()
            t0 = time.perf_counter()
            run(kw)
            wall[what].append(time.perf_counter() - t0)
            cpu[what].append(time.process_time() - c0)
    med = {w: statistics.median(t) for w, t in wall.items()}
    med_cpu = {w: statistics.median(t) for w, t in cpu.items()}
    ratio = med_cpu["with"] / med_cpu["without"]
    print(f"histograms [known paper car]: simulate_batch_metrics of {len(models)} symmetric "
          f"setups, oversample {OVERSAMPLE_DEFAULT}, {DRIVE_S:g} s drive, "
          f"{HistogramOptions().n_bins} bins; medians of {args.elements_repeat} alternating "
          f"calls: without {len(models) / med['without']:,.1f} setups/s (wall "
          f"{med['without']:.3f} s, CPU {med_cpu['without']:.3f} s), with histograms "
          f"{len(models) / med['with']:,.1f} setups/s (wall {med['with']:.3f} s, CPU "
          f"{med_cpu['with']:.3f} s): CPU ratio {ratio:.3f}x; {_load()}; warm-up "
          f"{t_warm:.1f} s")
    return ratio


# ---------------------------------------------------------------------------------------
# main
# ---------------------------------------------------------------------------------------

def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=2,
                        help="timed calls of each prediction and screening (default 2)")
    parser.add_argument("--ref-seconds", type=float, default=10.0,
                        help="seconds of drive the solve_ivp reference integrates (default 10)")
    parser.add_argument("--ref-setups", type=int, default=2,
                        help="setups the solve_ivp reference runs, per model (default 2)")
    parser.add_argument("--ref-screen-setups", type=int, default=20,
                        help="setups the numpy screening reference runs, per model (default 20)")
    parser.add_argument("--accuracy-setups", type=int, default=4,
                        help="setups compared with oversample 16 (default 4)")
    parser.add_argument("--sweep-setups", type=int, default=2000,
                        help="every-corner-free setups of the crate-sweep timing (default 2000)")
    parser.add_argument("--memory-setups", type=int, default=100_000,
                        help="setups screened and scored for the memory figure (default 100000)")
    parser.add_argument("--elements-repeat", type=int, default=3,
                        help="timed calls with and without the elements (default 3)")
    parser.add_argument("--elements-only", action="store_true",
                        help="run only the elements' part (bump stops, lift-off)")
    parser.add_argument("--histograms-only", action="store_true",
                        help="time only the predictions with and without the shock-velocity "
                        "histograms (issue 39)")
    parser.add_argument("--time-domain-only", action="store_true",
                        help="run only the time-domain part on the identified model (issue 40): "
                        "throughput, accuracy against oversample 16, the solve_ivp reference")
    parser.add_argument("--screening-only", action="store_true",
                        help="run only the screening part on the identified model (issue 40 "
                        "item 2): throughput and the numpy reference")
    parser.add_argument("--memory-child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_child:
        memory_child(args.memory_setups)
        return
    for name in ("repeat", "ref_setups", "ref_screen_setups", "accuracy_setups",
                 "memory_setups", "elements_repeat"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")
    if not 0 < args.ref_seconds <= DRIVE_S:
        parser.error(f"--ref-seconds must be in (0, {DRIVE_S:g}]")
    if args.elements_only:
        library = read_shock_library(LIBRARY_PATH)
        print(f"engine version: {_engine_version()}; {_load()}")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ratios = bench_elements(library, list(enumerate_setups(library)), args)
        _element_targets(ratios)
        return
    if args.histograms_only:
        library = read_shock_library(LIBRARY_PATH)
        print(f"engine version: {_engine_version()}; {_load()}")
        bench_histograms(library, list(enumerate_setups(library)), args)
        return

    if args.time_domain_only:
        _time_domain_only(args)
        return
    if args.screening_only:
        _screening_only(args)
        return
    child = start_memory_child(args.memory_setups)  # before this process grows
    try:
        _main(args, child)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()


def _main(args, child):
    print(f"engine version: {_engine_version()}")
    print(f"machine: {os.cpu_count()} CPUs, 1-min load average before the run: "
          f"{os.getloadavg()[0]:.2f} (timings are only comparable on an idle machine)")
    vehicle = example_vehicle()
    library = read_shock_library(LIBRARY_PATH)
    drive = _make_drive(vehicle)
    sym = list(enumerate_setups(library))
    free = list(enumerate_setups(library, symmetry="none", max_setups=None))
    print(f"inputs: {len(library)} shocks ({LIBRARY_PATH.relative_to(ROOT)}); drive "
          f"make_track_drive {DRIVE_S:g} s at {FS_HZ:g} Hz, seed {DRIVE_SEED}; "
          f"{len(sym)} symmetric setups, {len(free):,} every-corner-free setups "
          "(the crate's inventory respected)")

    # the models (not timed)
    from ident.identify.pipeline import identify_session
    from ident.sim.virtual_rig import simulate_session

    car = build_full_car(vehicle)
    # warm-up before the virtual rig below, which runs the same compiled shock loop
    t0 = time.perf_counter()
    predict_setups(car, drive, sym[:2], library, loop=LoopOptions(oversample=OVERSAMPLES[0]))
    print(f"warm-up: first predict_setups call, 2 setups (numba {_jit_source()}): "
          f"{time.perf_counter() - t0:.2f} s")
    t0 = time.perf_counter()
    screen_setups(car, drive, sym[:2], library)
    print(f"warm-up: first screen_setups call, 2 setups (numba cache load or compile): "
          f"{time.perf_counter() - t0:.2f} s")
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        identified = identify_session(simulate_session())
    gc.collect()
    print(f"models: known paper car (build_full_car); identified model from the paper session "
          f"(simulate_session + identify_session, {time.perf_counter() - t0:.0f} s, NOT timed)")

    models = (("known car", car), ("identified", identified))
    td_rate, sc_rate = {}, {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for label, model in models:
            rates, plant = bench_time_domain(label, model, drive, sym, library, args)
            td_rate[label] = (rates[OVERSAMPLE_DEFAULT], rates["sweep"])
            sc_rate[label] = bench_screening(label, model, plant, drive, sym, free, library, args)
            del plant
            gc.collect()

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        element_ratios = bench_elements(library, sym, args)
    bench_histograms(library, sym, args)

    mem = run_memory_child(child, identified)

    for label, _ in models:
        for what, r in zip((f"{len(sym)} symmetric setups per call",
                            f"sweep of {args.sweep_setups:,} setups"), td_rate[label]):
            print(f"target: time-domain prediction >= {TARGET_TIME_SETUPS_S:g} setups/s "
                  f"[{label}, oversample {OVERSAMPLE_DEFAULT}, {what}]: {r:,.1f} setups/s: "
                  f"{'PASS' if r >= TARGET_TIME_SETUPS_S else 'FAIL'}")
    for label, _ in models:
        r = sc_rate[label]
        print(f"target: screening >= {TARGET_SCREEN_SETUPS_S:,.0f} setups/s [{label}, "
              f"{len(free):,} setups, model as given]: {r:,.0f} setups/s: "
              f"{'PASS' if r >= TARGET_SCREEN_SETUPS_S else 'FAIL'}")
    worst = max(mem["rss"], mem["peak"])
    print(f"target: peak memory of screening + scoring {mem['n']:,} setups < "
          f"{_mib(TARGET_MEMORY_BYTES) / 1024:g} GB (child ru_maxrss {_mib(mem['rss']):.0f} MiB, "
          f"tracemalloc peak {_mib(mem['peak']):.0f} MiB; {_load()} at the end): "
          f"{'PASS' if worst < TARGET_MEMORY_BYTES else 'FAIL'}")
    _element_targets(element_ratios)


def _time_domain_only(args):
    """The time-domain part alone, on the identified model (``--time-domain-only``)."""
    from ident.identify.pipeline import identify_session
    from ident.sim.virtual_rig import simulate_session

    print(f"engine version: {_engine_version()}; {_load()}")
    vehicle = example_vehicle()
    library = read_shock_library(LIBRARY_PATH)
    drive = _make_drive(vehicle)
    sym = list(enumerate_setups(library))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        identified = identify_session(simulate_session())
        t0 = time.perf_counter()
        predict_setups(identified, drive, sym[:2], library,
                       loop=LoopOptions(oversample=OVERSAMPLE_DEFAULT))
        print(f"warm-up: first predict_setups call, 2 setups (numba {_jit_source()}): "
              f"{time.perf_counter() - t0:.2f} s")
        rates, _ = bench_time_domain("identified", identified, drive, sym, library, args)
    print(f"time domain [identified, oversample {OVERSAMPLE_DEFAULT}]: "
          f"{rates[OVERSAMPLE_DEFAULT]:,.1f} setups/s; sweep {rates['sweep']:,.1f} setups/s "
          f"({_load()} at the end)")


def _screening_only(args):
    """The screening part alone, on the identified model (``--screening-only``)."""
    from ident.identify.pipeline import identify_session
    from ident.sim.virtual_rig import simulate_session

    print(f"engine version: {_engine_version()}; {_load()}")
    vehicle = example_vehicle()
    library = read_shock_library(LIBRARY_PATH)
    drive = _make_drive(vehicle)
    sym = list(enumerate_setups(library))
    free = list(enumerate_setups(library, symmetry="none", max_setups=None))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        identified = identify_session(simulate_session())
        t0 = time.perf_counter()
        screen_setups(identified, drive, free[:2], library)
        screen_setups(identified, drive, free, library)
        print(f"warm-up: first screen_setups calls, 2 and {len(free):,} setups (numba cache "
              f"load or compile): {time.perf_counter() - t0:.2f} s")
        rate = bench_screening("identified", identified, as_loop_plant(identified), drive, sym,
                               free, library, args)
    print(f"screening [identified, every corner free]: {rate:,.0f} setups/s ({_load()} at the "
          "end)")


def _element_targets(ratios):
    r = ratios["bump stops"]
    print(f"target: time-domain prediction with bump stops <= {TARGET_ELEMENT_RATIO:g}x the "
          f"time without [GT-like car, simulate_batch_metrics, CPU time]: {r:.3f}x: "
          f"{'PASS' if r <= TARGET_ELEMENT_RATIO else 'FAIL'} (static loads, lift-off: "
          f"{ratios['static loads']:.3f}x, no target)")
    r = ratios["screening"]
    print(f"target: screening with bump stops <= {TARGET_ELEMENT_SCREEN_RATIO:g}x the time "
          f"without [GT-like car, screen_setups, CPU time]: {r:.3f}x: "
          f"{'PASS' if r <= TARGET_ELEMENT_SCREEN_RATIO else 'FAIL'}")


if __name__ == "__main__":
    main()
