"""Closed-loop simulation of a linear vehicle model with nonlinear shock absorbers.

This is the one simulator of the project: the virtual rig runs the physical
full-car model through it, the planner runs identified models through it.

The linear part is a :class:`~ident.models.lti.LoopPlant`: an LTI system with inputs
``[u_rig (7), dF (4)]`` and outputs ``y`` (the shock velocities among them),
written around a baseline linear damping ``c_bar`` (Eq. 20 of the seed paper):
the applied shock force of corner ``i`` is ``F_i = c_bar_i v_i + dF_i``. Each
shock is a static force-velocity curve ``f`` (piecewise linear) behind a
first-order lag ``tau dF/dt + F = f(v)``.

Notes
-----
Discretization. The plant is held in modal form (one complex state per
conjugate pole pair or real pole) and every mode is discretized *exactly* for
inputs that follow the parabola through the last three samples (a quadratic
hold, :func:`ident.models.lti.hold_coefficients`)::

    x[k+1] = exp(lam h) x[k] + g1 (B u[k+1]) + g0 (B u[k]) + gm (B u[k-1])

so the state at step ``k+1`` depends on the input at ``k+1``: with the shocks
in the loop this is an algebraic loop ``v[k] = v_free[k] + D_eff dF(v[k])``.
It is solved at every step by Newton's method on the 4 shock equations (never
broken by a one-sample delay). The lag is discretized the same way. The only
approximation is the hold of ``dF`` (and of the rig inputs) between internal
samples: its error falls as ``h^3`` (a first-order hold's as ``h^2``; its
``sinc^2`` droop alone costs 1 % of a tire-force RMS at 2 internal steps per
100 Hz sample, the quadratic hold 0.07 %). ``oversample`` refines the internal
step; rig inputs are refined onto the internal grid by band-limited
(polyphase) interpolation, since rig signals are samples of continuous signals.

The rig-input part of the response does not depend on the shocks: it is
computed once per drive (:func:`rig_response`) and shared by all setups.

The plant types and the discretization live in :mod:`ident.models.lti`
(:class:`~ident.models.lti.LoopPlant`, :class:`~ident.models.lti.ModalSystem`,
:func:`~ident.models.lti.modal_form` and the hold coefficients are the simulator's
inputs), the compiled kernels in :mod:`ident.sim.loop_kernels`; this module checks the inputs, builds the kernels'
arguments and returns the results. :func:`refine_input`, :func:`drive_array`,
:func:`check_oversample`, :func:`setup_models` and :func:`pack_setups` are the input
steps shared with the virtual rig (:mod:`ident.sim.rig`), the FIR simulator
(:mod:`ident.identify.fir`) and the planner's screening and sweeps.

:func:`simulate_batch` returns every setup's channels; :func:`simulate_batch_metrics`
returns only the spec's metrics, each setup's computed by the thread that simulated it
right after its loop (the planner's predictions).
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Mapping

import numba as _nb
import numpy as np

from ident.data.channels import CORNERS, RIG_INPUTS, SHOCK_FORCES, SHOCK_VELOCITIES
from ident.data.drive import FIR_HALF_LENGTH, check_drive_inputs, resample_bandlimited
from ident.models.lti import hold_coefficients, lag_coefficients, lag_hold_coefficients
from ident.sim.loop_kernels import loop_batch, loop_metrics_worker, loop_serial, rig_kernel
from ident.sim.metrics import METRIC_CHANNELS, compute_metrics, metric_plan

__all__ = [
    "RigResponse",
    "Response",
    "BatchResponse",
    "BatchMetrics",
    "rig_response",
    "simulate",
    "simulate_batch",
    "simulate_batch_metrics",
    "refine_input",
    "drive_array",
    "check_oversample",
    "setup_models",
    "pack_setups",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class RigResponse:
    """The part of a plant's response driven by the rig inputs alone (``dF = 0``).

    Computed once per drive and shared by every setup. Only what the loop and
    the outputs need is kept (the outputs are accumulated step by step and the
    modal states never stored), so memory does not grow with the model's order.

    Attributes
    ----------
    v_fine : ndarray, shape (n_fine, 4)
        Shock velocities on the internal grid.
    y : ndarray, shape (n_outputs, n_samples)
        The outputs ``output_names`` at the drive's samples.
    u_fine : ndarray, shape (n_fine, 7)
        Rig inputs refined onto the internal grid.
    fs_hz : float
        The drive's sample rate [Hz].
    oversample : int
        Internal steps per drive sample.
    n_samples : int
    plant_name : str
    output_names : tuple of str
        The plant outputs in ``y``.
    """

    v_fine: np.ndarray
    y: np.ndarray
    u_fine: np.ndarray
    fs_hz: float
    oversample: int
    n_samples: int
    plant_name: str
    output_names: tuple = ()


def refine_input(u, r):
    """Band-limited interpolation of (N, m) drive samples onto r sub-steps: (N-1)*r + 1 rows.

    The simulator's internal grid (:func:`rig_response`; the virtual rig and the FIR
    simulator refine onto the same grid).

    Rig signals are samples of continuous, band-limited signals (not piecewise
    linear between samples), so the hold assumption of the discretization is
    applied on the fine grid only, where its error is ``sinc^2(f / (r fs))``.
    The record is extended by its end values over the filter's length first,
    so a drive that starts or ends at an offset does not ring there.
    """
    if r == 1:
        return np.ascontiguousarray(u, dtype=float)
    pad = FIR_HALF_LENGTH + 1
    up = resample_bandlimited(np.pad(u, ((pad, pad), (0, 0)), mode="edge"), r, 1, axis=0)
    return np.ascontiguousarray(up[pad * r: pad * r + (u.shape[0] - 1) * r + 1])


def drive_array(drive):
    """The drive's samples and rate: ``(u, fs_hz)``, `u` of shape (n_samples, 7) float.

    Raises
    ------
    TypeError
        If `drive` is not an :class:`ident.data.drive.Drive` (has no ``as_array``).
    """
    if hasattr(drive, "as_array"):
        return np.asarray(drive.as_array(), dtype=float), float(drive.fs_hz)
    raise TypeError(f"drive must be an ident.data.drive.Drive, got {type(drive).__name__}")


def rig_response(plant, drive, *, oversample=4, outputs=None):
    """Compute the setup-independent, rig-input part of the response.

    Parameters
    ----------
    plant : ident.models.lti.LoopPlant
    drive : ident.data.drive.Drive
    oversample : int
        Internal steps per drive sample (>= 1).
    outputs : sequence of str, optional
        Plant outputs to compute (default all); modes that none of them (nor a
        shock velocity) reads are skipped.

    Returns
    -------
    RigResponse

    Raises
    ------
    ident.errors.DriveError
        If the drive has nonzero content on a rig input the plant does not
        have (an aero drive on a 4-post model); the message names the drive file.
    """
    r = check_oversample(oversample)
    names = _check_outputs(plant, outputs)
    u, fs = drive_array(drive)
    if plant.rig_inputs != RIG_INPUTS:
        check_drive_inputs(drive, plant.rig_inputs, model=plant.name)
    u_fine = refine_input(u, r)
    h = 1.0 / (fs * r)
    vi = plant.velocity_idx
    oi = np.array([plant.output_names.index(o) for o in names], dtype=int)
    mr = plant.rig.select(outputs=np.concatenate([vi, oi])).pruned()
    v_fine, y = _rig_outputs(mr, h, u_fine, r)
    return RigResponse(v_fine=np.ascontiguousarray(v_fine), y=y, u_fine=u_fine, fs_hz=fs,
                       oversample=r, n_samples=u.shape[0], plant_name=plant.name,
                       output_names=tuple(names))


#: Internal steps per time chunk of :func:`rig_kernel`. Fixed (not the thread count), so the
#: result does not depend on how many threads run it; a record of at most one chunk runs
#: serially with no superposition pass. 8,192: a 120 s drive at 100 Hz and oversample 2
#: (24,000 steps, 68 rig modes) in 3 chunks on 2 cores takes 0.028 s against 0.032 s serial.
_RIG_CHUNK = 1 << 13


def _rig_outputs(mr, h, u_fine, r):
    """Outputs of the modal system `mr` (rows: 4 shock velocities, then the outputs asked for)
    driven by `u_fine` on the internal grid: ``v_fine`` (n_fine, 4) on every step and ``y``
    (n_outputs, n_samples) on every `r`-th step, zero initial state.

    One compiled pass (:func:`rig_kernel`): each mode's input ``b_i . u[k]`` and its hold
    recursion (``scipy.signal.lfilter([g1, g0, gm], [1, -phi], .)``'s transposed direct
    form II) are formed step by step
    and ``Re(C x) + D u`` is accumulated at once, so the modal states on the internal grid
    (complex, modes x n_fine) are never stored. Parallel over time chunks of
    ``_RIG_CHUNK`` steps: a first pass runs every chunk from rest for its end state, the
    chunk start states follow by superposition (zero-input propagation over a chunk is
    ``z0 <- phi^(L-1) (phi z0 + z1)``, ``z1 <- 0``), and a second pass forms the outputs.
    """
    N, m = u_fine.shape
    p = mr.C.shape[0]
    n_out = (N - 1) // r + 1
    v = np.empty((N, 4))
    yT = np.empty((n_out, p - 4))  # sample-major, the layout the shock loop reads
    y = yT.T
    if N == 0:
        return v, y
    phi, g1, g0, gm = hold_coefficients(mr.lam, h)
    L = _RIG_CHUNK
    n_chunks = max(1, -(-N // L))
    # superposition factor of a full chunk: phi^(L-1) from the poles, not by repeated products
    phiL = np.exp(np.asarray(mr.lam, dtype=complex) * (h * (L - 1)))

    def split(a):
        a = np.asarray(a)
        return (np.ascontiguousarray(a.real, dtype=float),
                np.ascontiguousarray(a.imag, dtype=float))

    C = mr.C
    rig_kernel(np.ascontiguousarray(u_fine, dtype=float), *split(np.asarray(mr.B).T), *split(phi),
               *split(g1), *split(g0), *split(gm), *split(phiL),
               np.ascontiguousarray(C.real.T, dtype=float),
               np.ascontiguousarray(-C.imag.T, dtype=float),
               np.ascontiguousarray(np.asarray(mr.D, dtype=float).T), r, L, n_chunks, v, yT)
    return v, y


def _check_outputs(plant, outputs):
    """The output names asked for (default all), checked against the plant."""
    names = list(plant.output_names) if outputs is None else list(outputs)
    unknown = [o for o in names if o not in plant.output_names]
    if unknown:
        raise ValueError(f"unknown outputs {unknown}; the plant has {list(plant.output_names)}")
    return names


def check_oversample(oversample):
    """`oversample` (internal steps per drive sample) as an int, checked.

    Raises
    ------
    ValueError
        If it is not a positive integer (a bool is not).
    """
    if isinstance(oversample, bool) or not isinstance(oversample, (int, np.integer)) or oversample < 1:
        raise ValueError(f"oversample must be a positive integer, got {oversample!r}")
    return int(oversample)


#: The shock loop's modes are padded with zero modes to a multiple of this (AVX2: 4 doubles
#: per vector), so its mode loops run in whole vectors with no scalar remainder. A zero
#: mode adds exact zeros: the same numbers. 11 modes as 12: 7-10 % less time per setup.
_MODE_PAD = 4


# ----------------------------------------------------------------------------------------------
# setups
# ----------------------------------------------------------------------------------------------

def _writable(a):
    """A writable float copy: numba compiles a kernel once per argument type, and a frozen
    plant's read-only arrays are another type; one specialization serves every plant."""
    return np.array(a, dtype=float)


def setup_models(setup, where):
    """Return the 4 shock models (LF, RF, LR, RR) of a setup.

    Parameters
    ----------
    setup : mapping or sequence
        Corner -> shock model, or 4 shock models in the order LF, RF, LR, RR.
    where : str
        Names the setup in error messages.

    Raises
    ------
    ValueError
        If the corners are not exactly LF, RF, LR, RR.
    TypeError
        If a corner is not a shock model (``to_pwl`` and ``lag_s``).
    """
    if isinstance(setup, Mapping):
        missing = [c for c in CORNERS if c not in setup]
        extra = [c for c in setup if c not in CORNERS]
        if missing or extra:
            raise ValueError(f"{where}: a setup needs exactly the corners {list(CORNERS)}; "
                             f"missing {missing}, unknown {extra}")
        models = [setup[c] for c in CORNERS]
    else:
        models = list(setup)
        if len(models) != 4:
            raise ValueError(f"{where}: a setup needs 4 shock models (LF, RF, LR, RR), "
                             f"got {len(models)}")
    for c, mdl in zip(CORNERS, models):
        if not hasattr(mdl, "to_pwl") or not hasattr(mdl, "lag_s"):
            raise TypeError(f"{where}: corner {c} is {type(mdl).__name__}, not a shock model "
                            "(ident.models.shocks.ShockModel); resolve shock ids with the library first")
    return models


def pack_setups(setups, h, *, hold="quadratic"):
    """Pack setups into padded arrays for the compiled loop.

    Parameters
    ----------
    setups : sequence of sequences of 4 shock models
        As returned by :func:`setup_models`, one per setup.
    h : float
        Internal step [s] (the lag's discretization).
    hold : {"quadratic", "linear"}
        The lag's hold.

    Returns
    -------
    tuple of ndarray
        ``kv, kf`` (n_setups, 4, n_knots) knot velocities [m/s] and forces [N] of each
        curve, padded with its last knot; ``nk`` (n_setups, 4) knots per curve; ``slo,
        shi`` (n_setups, 4) end slopes [N/(m/s)]; then the lag coefficients of
        :func:`ident.models.lti.lag_hold_coefficients` (``alpha, b0, b1, bm``), or with
        ``hold="linear"`` of :func:`ident.models.lti.lag_coefficients` (``alpha, b0, b1``), each
        (n_setups, 4).
    """
    S = len(setups)
    pwls = [[m.to_pwl() for m in models] for models in setups]
    K = max(p.v_knots_m_s.size for row in pwls for p in row)
    kv = np.zeros((S, 4, K))
    kf = np.zeros((S, 4, K))
    nk = np.zeros((S, 4), dtype=np.int64)
    slo = np.zeros((S, 4))
    shi = np.zeros((S, 4))
    lag = np.zeros((S, 4))
    for s, (row, models) in enumerate(zip(pwls, setups)):
        for c, (p, mdl) in enumerate(zip(row, models)):
            k = p.v_knots_m_s.size
            kv[s, c, :k] = p.v_knots_m_s
            kf[s, c, :k] = p.f_knots_n
            kv[s, c, k:] = p.v_knots_m_s[-1]
            kf[s, c, k:] = p.f_knots_n[-1]
            nk[s, c] = k
            slo[s, c] = p.slope_below
            shi[s, c] = p.slope_above
            lag[s, c] = mdl.lag_s
    if hold == "linear":
        return (kv, kf, nk, slo, shi) + tuple(lag_coefficients(lag, h))
    return (kv, kf, nk, slo, shi) + tuple(lag_hold_coefficients(lag, h))


# ----------------------------------------------------------------------------------------------
# results and public functions
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class BatchResponse:
    """Closed-loop responses of several setups to one drive.

    Attributes
    ----------
    channels : dict of str -> ndarray, shape (n_setups, n_samples)
        Every plant output plus ``shock_force_XX`` (the applied force), SI,
        at the drive's sample rate.
    fs_hz : float
    setups : tuple
        The setups as given (tuples of 4 shock models).
    newton_iterations : ndarray of int, shape (n_setups,)
        Largest Newton iteration count per setup.
    settings : dict
        ``oversample``, ``plant``, ``drive``.
    """

    channels: dict
    fs_hz: float
    setups: tuple
    newton_iterations: np.ndarray
    settings: dict

    @property
    def n_setups(self):
        """Number of setups."""
        return len(self.setups)

    @property
    def time_s(self):
        """Sample times [s], shape (n_samples,)."""
        n = next(iter(self.channels.values())).shape[-1]
        return np.arange(n) / self.fs_hz

    def response(self, i):
        """The :class:`Response` of setup `i`."""
        return Response(channels={k: v[i] for k, v in self.channels.items()}, fs_hz=self.fs_hz,
                        setup=self.setups[i], newton_iterations=int(self.newton_iterations[i]),
                        settings=self.settings)


@dataclass(frozen=True, eq=False)
class Response:
    """Closed-loop response of one setup to one drive (see :class:`BatchResponse`)."""

    channels: dict
    fs_hz: float
    setup: tuple
    newton_iterations: int
    settings: dict

    @property
    def time_s(self):
        """Sample times [s], shape (n_samples,)."""
        n = next(iter(self.channels.values())).shape[-1]
        return np.arange(n) / self.fs_hz


def simulate_batch(plant, drive, setups, *, oversample=4, outputs=None, rig=None):
    """Simulate several shock setups on one plant and drive, in closed loop.

    Parameters
    ----------
    plant : ident.models.lti.LoopPlant
    drive : ident.data.drive.Drive
        The 7 rig inputs, SI (a 4-post drive: aero inputs zero).
    setups : sequence of setups
        Each a mapping corner -> shock model or a sequence of 4 shock models
        (LF, RF, LR, RR) with ``to_pwl()`` and ``lag_s`` (:mod:`ident.models.shocks`).
    oversample : int, default 4
        Internal steps per drive sample.
    outputs : sequence of str, optional
        Plant outputs to return (default all); ``shock_force_XX`` are always
        returned.
    rig : RigResponse, optional
        A precomputed :func:`rig_response` of this plant, drive and
        oversampling (reuse it across calls).

    Returns
    -------
    BatchResponse

    Raises
    ------
    ValueError
        On a malformed setup, an unknown output, or if Newton's method does
        not converge (an unstable or ill-posed loop).
    """
    loop = _loop_setup(plant, drive, setups, oversample, outputs, rig, "simulate_batch")
    return _batch_response(plant, drive, loop)


def _batch_response(plant, drive, loop):
    """:func:`simulate_batch` of the checked inputs `loop` (:func:`_loop_setup`)."""
    S, N = len(loop.models), loop.rig.n_samples
    y = np.empty((S, len(loop.names), N))
    F = np.empty((S, N, 4))  # (setup, sample, corner): written per sample in the kernel
    iters = np.zeros(S, dtype=np.int64)
    if S == 1:
        # not through _run_parallel: setting the chunk size starts numba's thread pool,
        # and a process forked after that (the demo's warm-up workers) cannot use it
        loop_serial(*loop.args, loop.y_rig, y, F, iters)
    else:
        _run_parallel(loop_batch, *loop.args, loop.y_rig, y, F, iters)
    _check_converged(plant, iters)
    channels = {name: y[:, j, :] for j, name in enumerate(loop.names)}
    for c, name in enumerate(SHOCK_FORCES):
        channels[name] = F[:, :, c]
    return BatchResponse(channels=channels, fs_hz=loop.rig.fs_hz,
                         setups=tuple(tuple(m) for m in loop.models), newton_iterations=iters,
                         settings=loop.settings(drive))


@dataclass(frozen=True, eq=False)
class BatchMetrics:
    """The spec's metrics of several setups' closed-loop responses to one drive.

    Attributes
    ----------
    metrics : ident.sim.metrics.Metrics
        One value per setup for every metric, shape (n_setups,), SI.
    setups : tuple
        The setups as given (tuples of 4 shock models).
    newton_iterations : ndarray of int, shape (n_setups,)
        Largest Newton iteration count per setup.
    settings : dict
        ``oversample``, ``plant``, ``drive``.
    """

    metrics: object
    setups: tuple
    newton_iterations: np.ndarray
    settings: dict


def simulate_batch_metrics(plant, drive, setups, *, oversample=4, outputs=None, rig=None,
                           band_hz=(1.0, 20.0), order=4, static_loads_n=None, split_hz=None):
    """The metrics of several shock setups in closed loop, without keeping their responses.

    The numbers of :func:`ident.sim.metrics.compute_metrics` on the channels of
    :func:`simulate_batch` to rounding (tested), in one compiled pass: each setup's metrics
    are computed by the thread that simulated it, right after, while its outputs are in
    the cache (a batch's responses are written to memory and read back otherwise: 1.5 MB
    per setup of a 120 s drive). Only the metrics' signals are formed: a ride height pair
    as one output of averaged coefficients, the shock velocities as the loop solved them
    (the velocity outputs are the same quantity), so 10 of the 16 outputs of a full set
    go through the output product; hence rounding differences (about 1e-15 relative),
    not the last bit. A setup's numbers do not depend on the batch it is in (the same
    bits alone or among others, so chunked and distributed runs agree).

    Parameters
    ----------
    plant, drive, setups, oversample, outputs, rig
        As :func:`simulate_batch`; the metrics are those of `outputs` (default all).
    band_hz, order, static_loads_n, split_hz
        As :func:`ident.sim.metrics.compute_metrics`.

    Returns
    -------
    BatchMetrics

    Raises
    ------
    ValueError
        As :func:`simulate_batch` and :func:`ident.sim.metrics.compute_metrics`.
    """
    loop = _loop_setup(plant, drive, setups, oversample, outputs, rig, "simulate_batch_metrics")
    plan = metric_plan(loop.names, loop.rig.fs_hz, band_hz=band_hz, order=order,
                       static_loads_n=static_loads_n, split_hz=split_hz)
    filters = [plan.filter(b) for b in plan.bands.values()]
    S, N = len(loop.models), loop.rig.n_samples
    if not plan.names or N <= filters[0][1]:
        # no metric, or a record too short for the filter: the two steps (the second
        # raises the filter's error, naming the channel)
        batch = _batch_response(plant, drive, loop)
        met = compute_metrics(batch.channels, fs=batch.fs_hz, band_hz=band_hz, order=order,
                              static_loads_n=static_loads_n, split_hz=split_hz)
        return BatchMetrics(metrics=met, setups=batch.setups,
                            newton_iterations=batch.newton_iterations, settings=batch.settings)
    # the metrics' signals as the product's rows: a channel's row of the output matrix,
    # the mean of two rows for a ride height of two corners; the shock velocities are the
    # loop's own (appended after the rows)
    Cout, y_rig = loop.cout, loop.y_rig
    cols, rig_cols, lanes = [], [], []
    for name in plan.names:
        chans = METRIC_CHANNELS[name]
        if len(chans) == 1 and chans[0] in SHOCK_VELOCITIES:
            lanes.append(-1 - SHOCK_VELOCITIES.index(chans[0]))
            continue
        idx = [loop.names.index(c) for c in chans]
        cols.append(Cout[:, idx].mean(axis=1))
        rig_cols.append(y_rig[:, idx].mean(axis=1))
        lanes.append(len(cols) - 1)
    p_red = len(cols)
    ia = np.array([i if i >= 0 else p_red + (-1 - i) for i in lanes], dtype=np.int64)
    c_red = np.ascontiguousarray(np.stack(cols, axis=1) if cols else np.zeros((Cout.shape[0], 0)))
    y_rig_red = np.ascontiguousarray(np.stack(rig_cols, axis=1) if rig_cols
                                     else np.zeros((N, 0)))
    sos = np.ascontiguousarray(np.stack([f[0] for f in filters]), dtype=float)
    zi = np.ascontiguousarray(np.stack([f[2] for f in filters]), dtype=float)
    out = np.empty((S, len(filters), len(plan.names)))
    iters = np.zeros(S, dtype=np.int64)
    n_workers = min(S, int(_nb.config.NUMBA_NUM_THREADS))
    args = (*loop.args[:-1], c_red, y_rig_red, N, ia, sos, zi, int(filters[0][1]), out,
            iters)
    if n_workers == 1:
        loop_metrics_worker(0, 1, *args)
    else:
        # threads, not a parallel kernel: the worker releases the GIL, compiles in a third of
        # the time a prange kernel of it takes, and starts no OpenMP pool (a process forked
        # after one cannot use it)
        with ThreadPoolExecutor(n_workers) as pool:
            for job in [pool.submit(loop_metrics_worker, w, n_workers, *args)
                        for w in range(n_workers)]:
                job.result()
    _check_converged(plant, iters)
    rms = {name + suffix: out[:, b, i] for b, suffix in enumerate(plan.bands)
           for i, name in enumerate(plan.names)}
    return BatchMetrics(metrics=plan.assemble(rms), setups=tuple(tuple(m) for m in loop.models),
                        newton_iterations=iters, settings=loop.settings(drive))


@dataclass(frozen=True, eq=False)
class _Loop:
    """The compiled loop's inputs for a plant, drive and setups (see :func:`_loop_setup`)."""

    models: list
    rig: RigResponse
    names: list
    args: tuple
    y_rig: np.ndarray
    oversample: int
    plant_name: str

    @property
    def cout(self):
        """The output rows' coefficients on ``[Re x, Im x, dF]``, shape (2 n + 4, p): the
        kernels' last argument (the fused metrics path passes reduced rows in its place)."""
        return self.args[-1]

    def settings(self, drive):
        return {"oversample": self.oversample, "plant": self.plant_name,
                "drive": getattr(drive, "name", None) if drive is not None else None}


def _loop_setup(plant, drive, setups, oversample, outputs, rig, where):
    """Check the inputs of a batch simulation and build the kernels' arguments up to the
    outputs (``args``: the modal loop, the setups' curves, ``r`` and the output matrix)."""
    r = check_oversample(oversample)
    models = [setup_models(s, f"setup {i}") for i, s in enumerate(setups)]
    if not models:
        raise ValueError(f"{where}: no setups given")
    if rig is None:
        rig = rig_response(plant, drive, oversample=r, outputs=outputs)
    elif rig.oversample != r or rig.plant_name != plant.name:
        raise ValueError(f"{where}: the given rig response was computed for another plant "
                         "or oversampling; recompute it with rig_response()")
    fs = rig.fs_hz
    h = 1.0 / (fs * r)
    ms = plant.shock
    vi = plant.velocity_idx
    phi, g1, g0, gm = hold_coefficients(ms.lam, h)
    Bf = np.ascontiguousarray(ms.B)
    Cv = np.ascontiguousarray(ms.C[vi])
    Deff = np.real(Cv @ (g1[:, None] * Bf)) + ms.D[vi]
    names = _check_outputs(plant, outputs)
    missing = [o for o in names if o not in rig.output_names]
    if missing:
        raise ValueError(f"{where}: the given rig response lacks outputs {missing}; "
                         "compute it with rig_response(..., outputs=...) including them")
    oi = np.array([plant.output_names.index(o) for o in names], dtype=int)
    if tuple(names) == tuple(rig.output_names):
        y_rig = np.ascontiguousarray(rig.y.T)  # (N, p): no copy of rig_response's own layout
    else:
        y_rig = np.ascontiguousarray(rig.y[[rig.output_names.index(o) for o in names]].T)
    packed = pack_setups(models, h)

    def split(a):
        a = np.asarray(a)
        return np.ascontiguousarray(a.real, dtype=float), np.ascontiguousarray(a.imag, dtype=float)

    Cy = ms.C[oi]
    # zero modes up to a multiple of _MODE_PAD: exact zeros in every sum, whole vectors
    n_pad = -len(phi) % _MODE_PAD
    if n_pad:
        def pad(a, axis):
            w = [(0, 0)] * a.ndim
            w[axis] = (0, n_pad)
            return np.pad(a, w)

        phi, g1, g0, gm = (pad(a, 0) for a in (phi, g1, g0, gm))
        Bf, Cv, Cy = pad(Bf, 0), pad(Cv, 1), pad(Cy, 1)
    # the output rows' coefficients on [Re x, Im x, dF]: Re(Cy x) + Dy dF in one product
    Cout = np.ascontiguousarray(np.concatenate([Cy.real.T, -Cy.imag.T,
                                                np.asarray(ms.D[oi], dtype=float).T]),
                                dtype=float)
    args = (*split(phi), *split(g1), *split(g0), *split(gm), *split(Bf.T), *split(Cv),
            np.ascontiguousarray(Deff), rig.v_fine, _writable(plant.cbar_n_s_m), *packed, r,
            Cout)
    return _Loop(models=models, rig=rig, names=names, args=args, y_rig=y_rig, oversample=r,
                 plant_name=plant.name)


def _run_parallel(kernel, *args):
    """Run a setup-parallel kernel handing out one setup at a time to whichever thread is
    free: setups differ in cost (a digressive curve's zero crossings change segments), and
    equal shares per thread wait for the slower one. Set from Python: inside a kernel it
    would keep numba from caching it."""
    old_chunk = _nb.set_parallel_chunksize(1)
    try:
        kernel(*args)
    finally:
        _nb.set_parallel_chunksize(old_chunk)


def _check_converged(plant, iters):
    if np.any(iters < 0):
        bad = np.flatnonzero(iters < 0).tolist()
        raise ValueError(f"closed loop of plant {plant.name!r}: Newton's method did not converge "
                         f"for setups {bad}; the shock loop is ill-posed (check the shock curves "
                         "and the model's stability, or raise oversample)")


def simulate(plant, drive, setup, *, oversample=4, outputs=None, rig=None):
    """Simulate one shock setup on a plant and a drive in closed loop.

    Same as :func:`simulate_batch` with one setup; returns a :class:`Response`.
    """
    return simulate_batch(plant, drive, [setup], oversample=oversample, outputs=outputs,
                          rig=rig).response(0)
