"""Benchmark of the virtual rig: the default paper plan through the closed-loop engine.

Run::

    python benchmarks/bench_rig.py [--repeat N] [--ref-seconds S]

Prints, one figure per line:

1. the engine: the first call of ``ident.sim.virtual_rig.simulate_session(default_plan(),
   example_vehicle())`` (imports numba and compiles the JIT or loads it from the
   cache), then the median, min and max wall time of ``--repeat`` further calls:
   the whole plan (5 runs x 800 s at 100 Hz, oversample 8, nonlinear digressive
   swap shocks with a 4 ms lag), in memory; then, separately, the time to write
   that session to a temporary folder as CSV (I/O, not simulation);
2. a straightforward reference: ``scipy.integrate.solve_ivp`` (RK45) on the same
   continuous closed loop (the physical full-car state of
   ``build_full_car(...).A/B`` with the 4 shock forces as inputs, plus one lag
   state ``tau dF/dt + F = f(v)`` per shock with a lag; ``F = f(v)`` for
   ``tau = 0``), rig inputs interpolated linearly between drive samples, for the
   baseline and the swap-LF run over the first ``--ref-seconds`` of the drive;
   its time scaled to the whole plan and the ratio reference / engine;
3. like-for-like accuracy on that segment: ``ident.sim.closedloop.simulate`` on the
   same plant, drive segment and setup (as ``ident.sim.virtual_rig`` does it) against the
   reference, as relative RMS differences. The script first checks how the
   engine refines the drive onto its internal grid (``rig_response().u_fine``);
   if that is not linear interpolation, the comparison is not like-for-like in
   the inputs, and it is repeated with the reference fed the engine's own
   refined inputs (piecewise linear on the internal grid), which isolates the
   closed-loop integration error. Both are printed; nothing is tuned;
4. peak memory (``ru_maxrss``, and the ``tracemalloc`` peak of one
   ``simulate_session`` call);
5. ``target: whole plan < 5 s: PASS/FAIL`` (on the median).

The reference is RK45, the default of ``solve_ivp``: the loop is not stiff at
the accuracy needed (fastest pole about -250 rad/s from the 4 ms lag, while
the 30 Hz drive and its kinks every 10 ms limit the step to below 1 ms anyway),
and RK45 was faster than LSODA on this problem (about 5.6 s against 6.5 s for
20 s of the swap-LF run when this script was written). ``rtol = 1e-6`` with an
absolute tolerance of 1e-6 of each state's typical size (:data:`ATOL_BY_KIND`);
a DOP853 run at ``rtol = 1e-9`` changed the printed differences by less than
0.001 percentage points, so they are the engine's, not the reference's.

This is a script, not part of the package: it prints. It writes nothing in the
repository (the session goes to a temporary folder that is removed); numba may
update its own cache in ``ident/__pycache__``.
"""

from __future__ import annotations

import argparse
import gc
import os
import resource
import statistics
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

# benchmark the working tree this script lives in, installed or not
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ident.data.channels import CORNERS  # noqa: E402
from ident.sim.virtual_rig import NOMINAL_V_RMS_M_S, default_plan, make_plan_drive, simulate_session  # noqa: E402
from ident.data.session import write_session  # noqa: E402
from ident.models.vehicle import build_full_car, example_vehicle  # noqa: E402
from _common import drive_segment, rel_rms  # noqa: E402
from _common import engine_version as _engine_version  # noqa: E402
from _common import jit_source as _jit_source, mib as _mib  # noqa: E402

#: The issue's target for the whole default plan, in memory [s].
TARGET_S = 5.0
#: Relative tolerance of the reference integration.
REF_RTOL = 1e-6
#: Absolute tolerance of the reference per kind of state: 1e-6 of a typical size
#: (1 cm / 10 mrad of displacement, 0.1 m/s of velocity, 100 N of lagged force).
ATOL_BY_KIND = {"displacement": 1e-8, "velocity": 1e-7, "force": 1e-4}
#: Like-for-like accuracy the engine should reach against the reference: the
#: relative RMS difference should be "well below 1 %".
ACCURACY_LIMIT = 0.01
#: Channels compared between engine and reference.
COMPARED = ("shock_velocity_LF", "tire_force_LF", "ride_height_LF")








def _run_plan():
    return simulate_session(default_plan(), example_vehicle())


# ---------------------------------------------------------------------------------------
# 1. the engine
# ---------------------------------------------------------------------------------------

def time_engine(repeat):
    """Time the first call and `repeat` further calls of the whole plan.

    Returns
    -------
    first_s : float
    times_s : list of float, length `repeat`
    session : ident.data.session.Session
        The last session (for the I/O timing).
    """
    t0 = time.perf_counter()
    session = _run_plan()
    first_s = time.perf_counter() - t0
    times_s = []
    for _ in range(repeat):
        del session
        gc.collect()
        t0 = time.perf_counter()
        session = _run_plan()
        times_s.append(time.perf_counter() - t0)
    return first_s, times_s, session


def time_write(session):
    """Time ``write_session`` of `session` as CSV into a temporary folder [s]."""
    with tempfile.TemporaryDirectory(prefix="bench_rig_") as tmp:
        t0 = time.perf_counter()
        write_session(session, Path(tmp) / "session", run_format="csv")
        elapsed = time.perf_counter() - t0
        size = sum(p.stat().st_size for p in Path(tmp).rglob("*") if p.is_file())
    return elapsed, size


def tracemalloc_peak():
    """Peak traced memory of one ``simulate_session`` call [bytes]."""
    gc.collect()
    tracemalloc.start()
    try:
        session = _run_plan()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    del session
    return peak


# ---------------------------------------------------------------------------------------
# 2. the reference: solve_ivp on the same continuous closed loop
# ---------------------------------------------------------------------------------------



def reference_run(model, shocks, u, fs_u_hz, fs_out_hz):
    """Integrate the continuous closed loop with ``solve_ivp`` (RK45).

    State: the physical full-car state ``x`` (displacements then velocities) and
    one lagged force per shock with ``lag_s > 0``. Shock ``i`` applies
    ``F_i = f_i(v_i)`` if it has no lag, else its lag state, where
    ``v = C_v x`` (no feedthrough) and ``lag * dF/dt + F = f(v)``. The rig
    inputs are piecewise linear between the rows of `u`.

    Parameters
    ----------
    model : ident.models.vehicle.FullCarModel
    shocks : sequence of 4 ident.models.shocks.ShockModel
        LF, RF, LR, RR.
    u : ndarray, shape (n_u, 7)
        Rig inputs (``RIG_INPUTS`` order, SI) at ``k / fs_u_hz``.
    fs_u_hz : float
        Rate of `u` [Hz]; an integer multiple of `fs_out_hz`.
    fs_out_hz : float
        Rate of the returned outputs [Hz].

    Returns
    -------
    elapsed_s : float
        Wall time of ``solve_ivp`` alone.
    nfev : int
        Right-hand-side evaluations.
    outputs : dict of str -> ndarray, shape (n_out,)
        Every model output at ``k / fs_out_hz`` over the span of `u`.
    """
    A = np.ascontiguousarray(model.A)
    Bu = np.ascontiguousarray(model.B[:, :7])
    Bf = np.ascontiguousarray(model.B[:, 7:])
    names = list(model.output_names)
    vi = [names.index(f"shock_velocity_{c}") for c in CORNERS]
    Cv = np.ascontiguousarray(model.C[vi])
    if np.any(model.D[vi] != 0):
        raise ValueError("the reference assumes no feedthrough to the shock velocities")
    nx = A.shape[0]
    lag = np.array([s.lag_s for s in shocks])
    lagged = np.flatnonzero(lag > 0)
    static = np.flatnonzero(lag == 0)
    tau = lag[lagged]
    U = np.ascontiguousarray(u, dtype=float)
    dU = np.diff(U, axis=0)
    k_last = U.shape[0] - 2
    step = int(round(fs_u_hz / fs_out_hz))

    def rhs(t, s):
        x = s[:nx]
        p = t * fs_u_hz
        k = min(int(p), k_last)
        u_t = U[k] + (p - k) * dU[k]
        v = Cv @ x
        F = np.empty(4)
        for i in static:
            F[i] = shocks[i].force(v[i])
        ds = np.empty_like(s)
        for j, i in enumerate(lagged):
            F[i] = s[nx + j]
            ds[nx + j] = (shocks[i].force(v[i]) - s[nx + j]) / tau[j]
        ds[:nx] = A @ x + Bu @ u_t + Bf @ F
        return ds

    half = nx // 2
    atol = np.concatenate([np.full(half, ATOL_BY_KIND["displacement"]),
                           np.full(nx - half, ATOL_BY_KIND["velocity"]),
                           np.full(lagged.size, ATOL_BY_KIND["force"])])
    U_out = U[::step]
    t_eval = np.arange(U_out.shape[0]) / fs_out_hz
    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), np.zeros(nx + lagged.size), method="RK45",
                    t_eval=t_eval, rtol=REF_RTOL, atol=atol)
    elapsed = time.perf_counter() - t0
    if not sol.success:
        raise RuntimeError(f"reference solve_ivp failed: {sol.message}")
    X = sol.y[:nx]
    V = Cv @ X
    F = np.empty((4, t_eval.size))
    for i in static:
        F[i] = shocks[i].force(V[i])
    for j, i in enumerate(lagged):
        F[i] = sol.y[nx + j]
    Y = model.C @ X + model.D[:, :7] @ U_out.T + model.D[:, 7:] @ F
    return elapsed, int(sol.nfev), dict(zip(names, Y))


def loop_damping(shocks):
    """Baseline damping of the loop plant, as ``ident.sim.virtual_rig`` chooses it [N/(m/s)], shape (4,)."""
    return np.array([float(s.equivalent_damping(NOMINAL_V_RMS_M_S)) for s in shocks])


def engine_inputs(model, shocks, drive, oversample):
    """The rig inputs as the engine sees them on its internal grid, shape (n_fine, 7).

    ``ident.sim.closedloop.rig_response(...).u_fine``: the engine's discretization is
    exact for inputs piecewise linear between these rows.
    """
    from ident.sim.closedloop import rig_response

    plant = model.loop_plant(loop_damping(shocks))
    return rig_response(plant, drive, oversample=oversample).u_fine


def engine_run(model, shocks, drive, oversample):
    """``ident.sim.closedloop.simulate`` as ``ident.sim.virtual_rig`` calls it (baseline damping at the nominal RMS)."""
    from ident.sim.closedloop import simulate

    return simulate(model.loop_plant(loop_damping(shocks)), drive, list(shocks),
                     oversample=oversample)




# ---------------------------------------------------------------------------------------
# main
# ---------------------------------------------------------------------------------------

def _linear_fine(u, r):
    """Linear interpolation of (N, 7) samples onto r sub-steps: (N-1)*r + 1 rows."""
    t = np.arange((u.shape[0] - 1) * r + 1) / r
    return np.column_stack([np.interp(t, np.arange(u.shape[0]), u[:, j])
                            for j in range(u.shape[1])])


def _accuracy(label, plan, model, seg, ref_outputs, runs, *, verdict=True):
    """Print the engine-vs-reference lines; return the largest relative RMS difference."""
    worst = 0.0
    for pr in runs:
        shocks, y_ref = ref_outputs[pr.name]
        resp = engine_run(model, shocks, seg, plan.oversample)
        for ch in COMPARED:
            e = rel_rms(resp.channels[ch], y_ref[ch])
            worst = max(worst, e)
            print(f"accuracy ({label}): run {pr.name!r}, {ch}, relative RMS difference "
                  f"engine vs reference: {100 * e:.3f} %")
    if verdict:
        ok = "OK" if worst < ACCURACY_LIMIT else "NOT OK"
        print(f"accuracy ({label}): largest relative RMS difference {100 * worst:.3f} % "
              f"(limit {100 * ACCURACY_LIMIT:g} %): {ok}")
    else:
        print(f"accuracy ({label}): largest relative RMS difference {100 * worst:.3f} % "
              "(a different input model, not an engine error: no verdict)")
    return worst


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3,
                        help="timed calls of the whole plan after the first (default 3)")
    parser.add_argument("--ref-seconds", type=float, default=20.0,
                        help="seconds of drive the solve_ivp reference integrates (default 20)")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    if not args.ref_seconds > 0:
        parser.error("--ref-seconds must be > 0")

    plan = default_plan()
    vehicle = example_vehicle()
    total_s = sum(r.duration_s for r in plan.runs)
    if args.ref_seconds > min(r.duration_s for r in plan.runs):
        parser.error(f"--ref-seconds must not exceed a run's duration "
                     f"({min(r.duration_s for r in plan.runs):g} s)")
    print(f"engine version: {_engine_version()}")
    print(f"machine: {os.cpu_count()} CPUs, 1-min load average before the run: "
          f"{os.getloadavg()[0]:.2f} (timings are only comparable on an idle machine)")
    print(f"plan: {plan.name!r}, {len(plan.runs)} runs, {total_s:g} s of drive at "
          f"{plan.fs_hz:g} Hz, oversample {plan.oversample}")

    # 1. engine --------------------------------------------------------------------------
    first_s, times_s, session = time_engine(args.repeat)
    median_s = statistics.median(times_s)
    print(f"engine: JIT warm-up, first call (numba import + {_jit_source('loop_serial')}): "
          f"{first_s:.2f} s")
    print(f"engine: whole plan in memory, median of {args.repeat}: {median_s:.2f} s")
    print(f"engine: whole plan in memory, min of {args.repeat}: {min(times_s):.2f} s")
    print(f"engine: whole plan in memory, max of {args.repeat}: {max(times_s):.2f} s")
    print(f"memory: ru_maxrss after the engine runs: "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    write_s, size = time_write(session)
    print(f"I/O, not simulation: write_session as CSV to a temp folder: {write_s:.2f} s "
          f"({_mib(size):.0f} MiB written)")
    del session
    peak = tracemalloc_peak()
    print(f"memory: tracemalloc peak of one simulate_session call: {_mib(peak):.0f} MiB")

    # 2. reference ------------------------------------------------------------------------
    model = build_full_car(vehicle)
    by_name = {r.name: r for r in plan.runs}
    compared = [by_name["baseline"], by_name["swap-LF"]]
    drive = make_plan_drive(plan, vehicle, seed=by_name["swap-LF"].seed,
                            duration_s=by_name["swap-LF"].duration_s)
    seg = drive_segment(drive, args.ref_seconds)
    u_seg = seg.as_array()
    setups = {pr.name: [plan.shocks[pr.setup[c]] for c in CORNERS] for pr in compared}
    ref_time, ref_linear = {}, {}
    for pr in compared:
        elapsed, nfev, y = reference_run(model, setups[pr.name], u_seg, seg.fs_hz, seg.fs_hz)
        ref_time[pr.name] = elapsed
        ref_linear[pr.name] = (setups[pr.name], y)
        print(f"reference: solve_ivp RK45 rtol={REF_RTOL:g}, run {pr.name!r}, "
              f"{args.ref_seconds:g} s of drive: {elapsed:.2f} s ({nfev} RHS evaluations)")
    # the whole plan: runs with a lagged shock cost like swap-LF, the others like the baseline
    plan_ref_s = 0.0
    for pr in plan.runs:
        has_lag = any(plan.shocks[pr.setup[c]].lag_s > 0 for c in CORNERS)
        plan_ref_s += ref_time["swap-LF" if has_lag else "baseline"] / args.ref_seconds \
            * pr.duration_s
    print(f"reference: whole plan scaled ({total_s:g} s of drive): {plan_ref_s:.0f} s")
    print(f"ratio reference / engine (median): {plan_ref_s / median_s:.0f}x")

    # 3. accuracy -------------------------------------------------------------------------
    # the reference interpolates the drive linearly; does the engine?
    r = plan.oversample
    u_fine = engine_inputs(model, setups["swap-LF"], seg, r)
    lin = _linear_fine(u_seg, r)
    dev = max(rel_rms(u_fine[:, j], lin[:, j]) for j in range(lin.shape[1])
              if np.any(lin[:, j]))
    linear = dev < 1e-9
    print(f"engine: rig inputs on its internal grid vs linear interpolation of the drive, "
          f"largest relative RMS difference: {100 * dev:.3f} % "
          f"({'linear, as the reference' if linear else 'NOT linear: not like-for-like'})")
    # like for like: the reference is fed the engine's own (band-limited) inputs, so the
    # comparison isolates the closed-loop integration error
    ref_engine_u = {}
    for pr in compared:
        u_eng = engine_inputs(model, setups[pr.name], seg, r)
        _, _, y = reference_run(model, setups[pr.name], u_eng, seg.fs_hz * r, seg.fs_hz)
        ref_engine_u[pr.name] = (setups[pr.name], y)
    _accuracy("like for like: reference fed the engine's refined inputs", plan, model, seg,
              ref_engine_u, compared)
    if not linear:
        # the engine treats drive samples as a band-limited signal (a rig samples continuous
        # signals); straight-line interpolation between samples is another input model
        _accuracy("input model: reference with straight-line drive interpolation", plan, model,
                  seg, ref_linear, compared, verdict=False)

    # 4./5. memory and target -----------------------------------------------------------------
    print(f"memory: ru_maxrss at the end of the script: "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    verdict = "PASS" if median_s < TARGET_S else "FAIL"
    print(f"target: whole plan < {TARGET_S:g} s (median): {verdict}")


if __name__ == "__main__":
    main()
