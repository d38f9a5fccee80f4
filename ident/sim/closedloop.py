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
steps shared with the virtual rig (:mod:`ident.sim.virtual_rig`), the FIR simulator
(:mod:`ident.identify.fir`) and the planner's screening and sweeps.

:func:`simulate_batch` returns every setup's channels; :func:`simulate_batch_metrics`
returns only the spec's metrics, each setup's computed by the thread that simulated it
right after its loop (the planner's predictions).
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Mapping

import numba as _nb
import numpy as np

from ident.data.channels import (CORNERS, RIG_INPUTS, SHOCK_FORCES, SHOCK_VELOCITIES,
                                 WHEELLOADER_INPUTS, corner_table, kind_of)
from ident.data.drive import FIR_HALF_LENGTH, check_drive_inputs, resample_bandlimited
from ident.models.lti import (hold_coefficients, join_inputs, lag_coefficients,
                              lag_hold_coefficients, unstable_growth_rate)
from ident.sim.loop_kernels import (ELEMENT_MAX_ITERATIONS, HISTOGRAM_COUNTERS, Elements,
                                    LoopDrive, MetricFilters, ModalLoop, RigModes, ShockSetups,
                                    ThirdLoop, histogram_add, loop_batch, loop_metrics_worker,
                                    loop_serial, rig_kernel)
from ident.sim.loop_third import UNREACHED_CONTACT_M, pack_third, third_channel
from ident.sim.metric_kernels import derived_metric_map
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
    "pack_bump_stops",
    "corner_values",
    "ELEMENT_STATS",
    "DIVERGED_VALUE",
    "histogram_edges",
    "velocity_histogram_counts",
]

log = logging.getLogger(__name__)

#: A simulated setup's shock forces [N] or metrics (SI) beyond this, or not finite, mean the
#: loop diverged (refused, naming the setups): no car's shock force or metric comes near
#: it (tire forces and shock forces are 1e2-1e5 N), while an unstable discretization (a
#: very stiff damper at a coarse step) grows past it within a fraction of a drive.
DIVERGED_VALUE = 1e9


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
    element_rows : dict
        Filled by the simulator with bump stops or lift-off: the rig-input part of the
        shock travels and tire forces on the internal grid, (n_fine, 8), by their rows
        (computed once per response, shared by every call given it).
    """

    v_fine: np.ndarray
    y: np.ndarray
    u_fine: np.ndarray
    fs_hz: float
    oversample: int
    n_samples: int
    plant_name: str
    output_names: tuple = ()
    element_rows: dict = field(default_factory=dict, repr=False)


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
    modes = RigModes(*split(np.asarray(mr.B).T), *split(phi), *split(g1), *split(g0), *split(gm),
                     *split(phiL), np.ascontiguousarray(C.real.T, dtype=float),
                     np.ascontiguousarray(-C.imag.T, dtype=float),
                     np.ascontiguousarray(np.asarray(mr.D, dtype=float).T))
    rig_kernel(np.ascontiguousarray(u_fine, dtype=float), modes, r, L, n_chunks, v, yT)
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
        table = corner_table(setup, name="setup", where=where, what="shock models")
        missing = [c for c in CORNERS if c not in table]
        if missing:
            raise ValueError(f"{where}: a setup needs exactly the corners {list(CORNERS)}; "
                             f"missing {missing}")
        models = [table[c] for c in CORNERS]
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
    # each distinct shock model (by identity: a crate's setups reuse a few models) is packed
    # once, then gathered per setup and corner (the same arrays as packing every entry)
    first = {}
    models = []
    idx = np.empty((S, 4), dtype=np.int64)
    for s, row in enumerate(setups):
        for c, mdl in enumerate(row):
            j = first.get(id(mdl))
            if j is None:
                j = first[id(mdl)] = len(models)
                models.append(mdl)
            idx[s, c] = j
    pwls = [m.to_pwl() for m in models]
    K = max(p.v_knots_m_s.size for p in pwls)
    ukv = np.zeros((len(models), K))
    ukf = np.zeros((len(models), K))
    unk = np.zeros(len(models), dtype=np.int64)
    for j, p in enumerate(pwls):
        k = p.v_knots_m_s.size
        ukv[j, :k] = p.v_knots_m_s
        ukf[j, :k] = p.f_knots_n
        ukv[j, k:] = p.v_knots_m_s[-1]
        ukf[j, k:] = p.f_knots_n[-1]
        unk[j] = k
    kv, kf, nk = ukv[idx], ukf[idx], unk[idx]
    slo = np.array([p.slope_below for p in pwls], dtype=float)[idx]
    shi = np.array([p.slope_above for p in pwls], dtype=float)[idx]
    lag = np.array([m.lag_s for m in models], dtype=float)[idx]
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
        ``oversample``, ``plant``, ``drive`` (and ``bump_stops``, ``static_corner_load_n``
        when given).
    elements : dict of str -> ndarray, shape (n_setups,)
        With bump stops or static loads only (:data:`ELEMENT_STATS`):
        ``bump_stop_contact_share_XX`` (share of samples with the travel beyond contact,
        corners with a bump stop), ``tire_contact_min_XX`` [N] (smallest contact force
        ``static + tire_force``) and ``tire_liftoff_share_XX`` (share of samples at zero
        contact), corners with a static load.
    """

    channels: dict
    fs_hz: float
    setups: tuple
    newton_iterations: np.ndarray
    settings: dict
    elements: dict = field(default_factory=dict)

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
                        settings=self.settings,
                        elements={k: float(v[i]) for k, v in self.elements.items()})


@dataclass(frozen=True, eq=False)
class Response:
    """Closed-loop response of one setup to one drive (see :class:`BatchResponse`)."""

    channels: dict
    fs_hz: float
    setup: tuple
    newton_iterations: int
    settings: dict
    elements: dict = field(default_factory=dict)

    @property
    def time_s(self):
        """Sample times [s], shape (n_samples,)."""
        n = next(iter(self.channels.values())).shape[-1]
        return np.arange(n) / self.fs_hz


def simulate_batch(plant, drive, setups, *, oversample=4, outputs=None, rig=None,
                   bump_stops=None, static_corner_load_n=None, third=None):
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
    bump_stops : sequence, optional
        One entry per setup: the setup's bump stops, a mapping corner -> stop or 4 stops
        (LF, RF, LR, RR), a stop ``None`` (none at that corner) or ``(contact_travel_m,
        travel_table_m, force_table_n)`` (:func:`pack_bump_stops`). The corner's force
        into the car is then the shock's plus the stop's at the shock travel;
        ``shock_force_XX`` stays the shock's. Needs the plant's ``shock_travel_XX``.
        ``None`` (default): today's loop, the same numbers.
    static_corner_load_n : array_like, shape (4,) or mapping, optional
        Static tire load per corner [N] (:func:`corner_values`; a corner left out or
        ``None`` has no lift-off): the contact force ``static + tire_force`` is kept at
        or above zero, the pad following the tire while it is off (lift-off). Needs the
        plant's ``tire_force_XX``. ``None`` (default): today's loop.
    third : sequence, optional
        One entry per setup: its third elements ``(dampers, springs)`` (sequences of
        :class:`ident.sim.loop_third.ThirdDamper` and
        :class:`~ident.sim.loop_third.ThirdSpring`) or ``None`` (issue 38). The channels
        then also hold, per element of the batch, ``<kind>_velocity_<axle>`` and
        ``<kind>_travel_<axle>`` (its motion, ``m @ v`` and ``m @ x``), per damper
        ``<kind>_force_<axle>`` (its own force), per heave spring
        ``heave_spring_force_<axle>`` and per corner bump stop ``bump_stop_force_XX``; the
        elements' values ``heave_spring_contact_share_<axle>`` (and the corners'
        ``bump_stop_contact_share_XX``). Needs the plant's ``shock_travel_XX``; not with
        `static_corner_load_n`. ``None`` (default): today's loop, the same numbers.

    Returns
    -------
    BatchResponse

    Raises
    ------
    ValueError
        On a malformed setup, an unknown output, or if Newton's method does
        not converge (an unstable or ill-posed loop); on malformed bump stops or static
        loads, or a plant without the channels they need.

    Notes
    -----
    Bump stops and lift-off are solved within each internal step with the shocks
    (:func:`ident.sim.loop_kernels.loop_one`): the travel, the stop's force, the
    contact force and the shock forces agree at the step (implicit). The pad correction
    of lift-off enters the model through its wheelloader inputs (the rig part's wheelloader
    columns joined to the shock part, :func:`ident.models.lti.join_inputs`), so the tire
    force, accelerations and every state see it; the ride heights, measured from the real
    pad, do not take its direct feedthrough.
    """
    loop = _loop_setup(plant, drive, setups, oversample, outputs, rig, "simulate_batch")
    if third is not None:
        return _third_response(plant, drive, loop, bump_stops, static_corner_load_n, third,
                               "simulate_batch")
    if bump_stops is None and static_corner_load_n is None:
        return _batch_response(plant, drive, loop)
    return _element_response(plant, drive, loop, bump_stops, static_corner_load_n,
                             "simulate_batch")


def _batch_response(plant, drive, loop):
    """:func:`simulate_batch` of the checked inputs `loop` (:func:`_loop_setup`)."""
    S, N = len(loop.models), loop.rig.n_samples
    y = np.empty((S, len(loop.names), N))
    F = np.empty((S, N, 4))  # (setup, sample, corner): written per sample in the kernel
    iters = np.zeros(S, dtype=np.int64)
    _run_loop(loop.plant, loop, loop.cout, (y, F, iters, None, None, None, None))
    _check_converged(plant, iters, F)
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
        ``oversample``, ``plant``, ``drive`` (and ``bump_stops``, ``static_corner_load_n``
        when given, as :attr:`BatchResponse.settings`).
    histogram_counts : ndarray, shape (n_setups, 4, n_bins + 3), or None
        With ``histogram_bins``: per setup and corner (LF, RF, LR, RR), the output samples
        of the shock velocity in each bin of :func:`histogram_edges` (the open end bins
        first and last), then the samples with ``|v| < knee``, ``v > 0`` (bump) and ``v <
        0`` (rebound) (:func:`velocity_histogram_counts`); None without.
    n_samples : int
        Output samples per setup (the counts' total per corner).
    """

    metrics: object
    setups: tuple
    newton_iterations: np.ndarray
    settings: dict
    histogram_counts: np.ndarray | None = None
    n_samples: int = 0


def histogram_edges(width_m_s, limit_m_s):
    """The edges of a shock-velocity histogram: bins of `width_m_s` from ``-limit_m_s`` to
    ``+limit_m_s``, and an open bin at each end.

    Parameters
    ----------
    width_m_s, limit_m_s : float
        Bin width and the largest inner edge [m/s]; ``2 limit / width`` must be a whole
        number (to 1e-9), so that 0 is an edge when it is even.

    Returns
    -------
    ndarray, shape (n_bins + 1,)
        The edges [m/s], ``-inf`` and ``+inf`` first and last (the open bins).

    Raises
    ------
    ValueError
        If the width or limit is not positive and finite or the bins do not fit.

    Examples
    --------
    >>> histogram_edges(0.1, 0.2).tolist()
    [-inf, -0.2, -0.1, 0.0, 0.1, 0.2, inf]
    """
    width, limit = float(width_m_s), float(limit_m_s)
    if not (np.isfinite(width) and np.isfinite(limit) and width > 0 and limit > 0):
        raise ValueError(f"histogram bins: width {width_m_s!r} and limit {limit_m_s!r} m/s must "
                         "be finite and > 0 (e.g. 0.025 m/s bins over +-0.25 m/s)")
    n = 2.0 * limit / width
    n_inner = int(round(n))
    if n_inner < 1 or abs(n - n_inner) > 1e-9 * max(n, 1.0):
        raise ValueError(f"histogram bins: 2 x limit {limit:g} m/s is not a whole number of "
                         f"bins of width {width:g} m/s; make the limit a multiple of half the "
                         "width (e.g. 0.025 m/s bins over +-0.25 m/s)")
    inner = width * (np.arange(n_inner + 1) - n_inner / 2)  # symmetric, 0 exactly if even
    return np.concatenate([[-np.inf], inner, [np.inf]])


def _histogram_spec(histogram_bins_, where):
    """``(spec, n_bins)`` of the kernels from ``(width_m_s, limit_m_s, knee_m_s)``."""
    try:
        width, limit, knee = (float(x) for x in histogram_bins_)
    except (TypeError, ValueError):
        raise TypeError(f"{where}: histogram_bins must be (width_m_s, limit_m_s, knee_m_s), "
                        f"got {histogram_bins_!r}") from None
    edges = histogram_edges(width, limit)
    if not (np.isfinite(knee) and knee >= 0):
        raise ValueError(f"{where}: the histogram's knee {knee!r} m/s must be finite and >= 0")
    return np.array([-limit, 1.0 / width, knee]), edges.size - 1


def velocity_histogram_counts(v_m_s, histogram_bins_):
    """The counts of :attr:`BatchMetrics.histogram_counts` of given velocity samples.

    Parameters
    ----------
    v_m_s : array_like, shape (..., n_samples)
        Shock velocities [m/s], compression positive.
    histogram_bins_ : (float, float, float)
        ``(width_m_s, limit_m_s, knee_m_s)``, as :func:`simulate_batch_metrics`'.

    Returns
    -------
    ndarray, shape (..., n_bins + 3)
        Samples per bin of :func:`histogram_edges` (the open end bins first and last), then
        the samples with ``|v| < knee``, ``v > 0`` and ``v < 0``: the same arithmetic as
        the closed loop's (:func:`ident.sim.loop_kernels.histogram_add`), so the same
        counts for the same samples. NaN samples are left out.
    """
    spec, n_bins = _histogram_spec(histogram_bins_, "velocity_histogram_counts")
    v = np.asarray(v_m_s, dtype=float)
    out = np.zeros(v.shape[:-1] + (n_bins + HISTOGRAM_COUNTERS,))
    flat_v = v.reshape(-1, v.shape[-1])
    flat = out.reshape(-1, out.shape[-1])
    for i in range(flat_v.shape[0]):
        row = flat_v[i]
        histogram_add(np.ascontiguousarray(row[np.isfinite(row)]), spec[0], spec[1], spec[2],
                      flat[i])
    return out


def simulate_batch_metrics(plant, drive, setups, *, oversample=4, outputs=None, rig=None,
                           band_hz=(1.0, 20.0), order=4, static_loads_n=None, split_hz=None,
                           bump_stops=None, static_corner_load_n=None, histogram_bins=None,
                           third=None):
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
    bump_stops, static_corner_load_n
        As :func:`simulate_batch` (`bump_stops` one entry per setup). The metrics then
        also hold :attr:`BatchResponse.elements`' values (:data:`ELEMENT_STATS`, after
        the band-passed ones): ``bump_stop_contact_share_XX`` for every corner with a
        stop in any setup, ``tire_contact_min_XX`` [N] and ``tire_liftoff_share_XX`` for
        every corner with a static load. `static_loads_n` (normalized tire forces) and
        `static_corner_load_n` (lift-off) are the same car's numbers, given separately.
        ``None`` (default): today's path, the same numbers.
    histogram_bins : (float, float, float), optional
        ``(width_m_s, limit_m_s, knee_m_s)``: also count each setup's shock velocities at
        the output samples (those the metrics use: the whole record) into a histogram of
        :func:`histogram_edges` bins and below the knee, in bump and in rebound
        (:attr:`BatchMetrics.histogram_counts`), in the same pass. The metrics are the
        same bits with or without (tested). None (default): no histogram, no cost.
    third : sequence, optional
        As :func:`simulate_batch` (one entry per setup). The metrics then also hold, per
        element of the batch, ``<kind>_travel_rms_<axle>`` and ``<kind>_velocity_rms_<axle>``
        (band-passed as the others) and ``heave_spring_contact_share_<axle>`` per heave
        spring. ``None`` (default): today's path, the same numbers.

    Returns
    -------
    BatchMetrics

    Raises
    ------
    ValueError
        As :func:`simulate_batch` and :func:`ident.sim.metrics.compute_metrics`.
    """
    where = "simulate_batch_metrics"
    hist_spec, n_bins = (None, 0) if histogram_bins is None else _histogram_spec(histogram_bins,
                                                                                 where)
    loop = _loop_setup(plant, drive, setups, oversample, outputs, rig, where)
    th = None
    if third is not None:
        th = _third_args(plant, loop, bump_stops, static_corner_load_n, third, where)
        loop = replace(loop, names=th.names, cout=th.cout, y_rig=th.y_rig)
    plan = metric_plan(loop.names, loop.rig.fs_hz, band_hz=band_hz, order=order,
                       static_loads_n=static_loads_n, split_hz=split_hz)
    el = None
    if th is None and (bump_stops is not None or static_corner_load_n is not None):
        el = _element_args(plant, loop, bump_stops, static_corner_load_n, where)
    filters = [plan.filter(b) for b in plan.bands.values()]
    S, N = len(loop.models), loop.rig.n_samples
    if not plan.names or N <= filters[0][1]:
        # no metric, or a record too short for the filter: the two steps (the second
        # raises the filter's error, naming the channel)
        if th is not None:
            batch = _third_response(plant, drive, loop, bump_stops, static_corner_load_n,
                                    third, where, th=th)
        elif el is None:
            batch = _batch_response(plant, drive, loop)
        else:
            batch = _element_response(plant, drive, loop, bump_stops, static_corner_load_n,
                                      where)
        met = compute_metrics(batch.channels, fs=batch.fs_hz, band_hz=band_hz, order=order,
                              static_loads_n=static_loads_n, split_hz=split_hz)
        if batch.elements:
            met = replace(met, values={**met.values, **batch.elements})
        counts = None
        if hist_spec is not None:
            v = np.stack([batch.channels[c] for c in SHOCK_VELOCITIES], axis=1)
            counts = velocity_histogram_counts(v, histogram_bins)
        return BatchMetrics(metrics=met, setups=batch.setups,
                            newton_iterations=batch.newton_iterations, settings=batch.settings,
                            histogram_counts=counts, n_samples=N)
    # the metrics' signals as the product's rows: a channel's row of the output matrix,
    # the mean of two rows for a ride height of two corners; the shock velocities are the
    # loop's own (appended after the rows)
    Cout, y_rig = (loop.cout if el is None else el.cout), loop.y_rig
    names, derived, dmap, dw = _derived_metrics(plan.names, th)
    cols, rig_cols, lanes = [], [], []
    tf_rows = np.full(4, -1, dtype=np.int64)
    for name in names:
        chans = METRIC_CHANNELS[name]
        if len(chans) == 1 and chans[0] in SHOCK_VELOCITIES:
            lanes.append(-1 - SHOCK_VELOCITIES.index(chans[0]))
            continue
        idx = [loop.names.index(c) for c in chans]
        cols.append(Cout[:, idx].mean(axis=1))
        rig_cols.append(y_rig[:, idx].mean(axis=1))
        lanes.append(len(cols) - 1)
        if len(chans) == 1 and chans[0].startswith("tire_force_"):
            tf_rows[CORNERS.index(chans[0][-2:])] = len(cols) - 1
    p_red = len(cols)
    ia = np.array([i if i >= 0 else p_red + (-1 - i) for i in lanes], dtype=np.int64)
    c_red = np.ascontiguousarray(np.stack(cols, axis=1) if cols else np.zeros((Cout.shape[0], 0)))
    y_rig_red = np.ascontiguousarray(np.stack(rig_cols, axis=1) if rig_cols
                                     else np.zeros((N, 0)))
    sos = np.ascontiguousarray(np.stack([f[0] for f in filters]), dtype=float)
    zi = np.ascontiguousarray(np.stack([f[2] for f in filters]), dtype=float)
    out = np.empty((S, len(filters), len(names) + len(derived)))
    iters = np.zeros(S, dtype=np.int64)
    metrics = MetricFilters(ia, sos, zi, int(filters[0][1]), dmap, dw)
    drive_args = LoopDrive(loop.rig.v_fine, loop.oversample, y_rig_red, c_red)
    counts = None if hist_spec is None else np.zeros((S, 4, n_bins + HISTOGRAM_COUNTERS))
    if th is not None:
        tstats = np.zeros((S, th.n_springs))
        _run_workers(S, (loop.plant, loop.shocks, drive_args, metrics, out, iters, None, None,
                         hist_spec, counts, th.kernel, tstats))
    elif el is None:
        _run_workers(S, (loop.plant, loop.shocks, drive_args, metrics, out, iters, None, None,
                         hist_spec, counts, None, None))
    else:
        stats = np.zeros((S, 3, 4))
        _run_workers(S, (el.plant, loop.shocks, drive_args, metrics, out, iters,
                         el.kernel_elements(tf_rows), stats, hist_spec, counts, None, None))
    _check_converged(plant, iters, out)
    rms = {name + suffix: out[:, b, i] for b, suffix in enumerate(plan.bands)
           for i, name in enumerate(names + derived)}
    met = plan.assemble(rms)
    settings = loop.settings(drive)
    if el is not None:
        met = replace(met, values={**met.values, **el.values(stats, N)})
        settings = el.settings(loop, drive)
    if th is not None:
        met = replace(met, values={**met.values, **th.values(tstats, N)})
        settings = th.settings(loop, drive)
    return BatchMetrics(metrics=met, setups=tuple(tuple(m) for m in loop.models),
                        newton_iterations=iters, settings=settings, histogram_counts=counts,
                        n_samples=N)


def _derived_metrics(names, th):
    """Split the fused metrics `names` into filtered ones and derived ones (issue 38): a third
    element's travel (velocity) is ``m @ x`` of the corners' shock travels (velocities), so
    with those corners' metrics filtered its band-passed signal is the same combination of
    theirs (the band-pass is linear): its metric is formed from them
    (:func:`ident.sim.metric_kernels.setup_metric_rms`) instead of a lane of the filter of
    its own. Returns ``(filtered names, derived names, dmap, dw)``."""
    none = (list(names), [], np.zeros((0, 7), dtype=np.int64), np.zeros((0, 4)))
    if th is None or not th.motions:
        return none
    parts = {}
    for name in names:
        chans = METRIC_CHANNELS[name]
        if len(chans) != 1 or chans[0] not in th.motions:
            continue
        what, row = th.motions[chans[0]]
        src = [f"shock_{what}_rms_{CORNERS[c]}" for c in range(4) if row[c] != 0.0]
        if src and all(m in names for m in src):
            parts[name] = (src, [float(row[c]) for c in range(4) if row[c] != 0.0])
    derived = list(parts)
    while True:  # until every derived metric's sources share a block of the final order
        base = [n for n in names if n not in derived]
        dmap, dw, kept = derived_metric_map(
            [[base.index(m) for m in parts[d][0]] for d in derived],
            [parts[d][1] for d in derived], len(base))
        if len(kept) == len(derived):
            break
        derived = [derived[i] for i in kept]
    return base, derived, dmap, dw


def _run_workers(n_setups, args):
    """Run the fused metrics worker (:func:`ident.sim.loop_kernels.loop_metrics_worker`) on
    ``min(n_setups, numba's threads)`` threads: worker ``w`` of ``n`` takes the setups ``w,
    w + n, ...``."""
    worker = loop_metrics_worker
    n_workers = min(n_setups, int(_nb.config.NUMBA_NUM_THREADS))
    if n_workers == 1:
        worker(0, 1, *args)
        return
    # threads, not a parallel kernel: the worker releases the GIL, compiles in a third of
    # the time a prange kernel of it takes, and starts no OpenMP pool (a process forked
    # after one cannot use it)
    with ThreadPoolExecutor(n_workers) as pool:
        for job in [pool.submit(worker, w, n_workers, *args) for w in range(n_workers)]:
            job.result()


@dataclass(frozen=True, eq=False)
class _Loop:
    """The compiled loop's inputs for a plant, drive and setups (see :func:`_loop_setup`)."""

    models: list
    rig: RigResponse
    names: list
    plant: ModalLoop  # the kernels' plant (ident.sim.loop_kernels)
    shocks: ShockSetups
    cout: np.ndarray  # the outputs' coefficients on [Re x, Im x, dF], shape (2 n + 4, p)
    y_rig: np.ndarray
    oversample: int
    plant_name: str

    def settings(self, drive):
        return {"oversample": self.oversample, "plant": self.plant_name,
                "drive": getattr(drive, "name", None) if drive is not None else None}


def _loop_setup(plant, drive, setups, oversample, outputs, rig, where):
    """Check the inputs of a batch simulation and build the kernels' arguments (the
    plant's :class:`~ident.sim.loop_kernels.ModalLoop`, the setups'
    :class:`~ident.sim.loop_kernels.ShockSetups` and the output matrix)."""
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
    vi = plant.velocity_idx
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
    shocks = ShockSetups(*packed)
    modal, Cout, _ = _modal_args(plant.shock, vi, oi, h)
    return _Loop(models=models, rig=rig, names=names,
                 plant=ModalLoop(*modal, _writable(plant.cbar_n_s_m)), shocks=shocks,
                 cout=Cout, y_rig=y_rig, oversample=r, plant_name=plant.name)


def _run_loop(kernel_plant, loop, cout, tail):
    """Run the batch loop (one setup: :func:`ident.sim.loop_kernels.loop_serial`, else
    :func:`ident.sim.loop_kernels.loop_batch`) of `loop` with the plant `kernel_plant`, the
    output rows `cout` and ``tail = (y_out, F_out, iters, elements, stats, third, tstats)``."""
    args = (kernel_plant, loop.shocks, LoopDrive(loop.rig.v_fine, loop.oversample, loop.y_rig,
                                                 cout)) + tuple(tail)
    if len(loop.models) == 1:
        # not through _run_parallel: setting the chunk size starts numba's thread pool,
        # and a process forked after that (the demo's warm-up workers) cannot use it
        loop_serial(*args)
    else:
        _run_parallel(loop_batch, *args)


def _split(a):
    """Real and imaginary parts of `a` as contiguous float arrays."""
    a = np.asarray(a)
    return np.ascontiguousarray(a.real, dtype=float), np.ascontiguousarray(a.imag, dtype=float)


def _modal_args(ms, vi, oi, h, *, erows=(), w_out=None):
    """The modal loop's arguments of the kernels from the shock part `ms` of a plant.

    Parameters
    ----------
    ms : ident.models.lti.ModalSystem
        Inputs ``dF`` (4), then with lift-off the 4 pad corrections ``w``.
    vi, oi : ndarray of int
        Rows of the shock velocities and of the outputs.
    h : float
        Internal step [s].
    erows : sequence of int
        Rows of the elements' channels (travel, tire force), returned padded.
    w_out : ndarray, shape (p, 4), optional
        Feedthrough of ``w`` to the outputs (with lift-off).

    Returns
    -------
    modal : tuple
        ``phi, g1, g0, gm, B.T, Cv`` split in real and imaginary parts, then ``Deff``.
    Cout : ndarray, shape (2 n + 4 (+ 4), p)
        The output rows' coefficients on ``[Re x, Im x, dF (, w)]``.
    extra : tuple
        ``(Bw.T, Ce)`` split (padded as the modes), and the elements' effective
        feedthroughs ``g1``-weighted (:func:`_element_feedthrough`); empty without
        `erows`.
    """
    phi, g1, g0, gm = hold_coefficients(ms.lam, h)
    Bf = np.ascontiguousarray(ms.B[:, :4])
    Cv = np.ascontiguousarray(ms.C[vi])
    Deff = np.real(Cv @ (g1[:, None] * Bf)) + ms.D[vi][:, :4]
    nw = ms.B.shape[1] - 4
    Bw = np.ascontiguousarray(ms.B[:, 4:])
    Ce = np.ascontiguousarray(ms.C[list(erows)])
    feed = ()
    if len(erows):
        def eff(C, D, B):
            return np.ascontiguousarray(np.real(C @ (g1[:, None] * B)) + D)

        Dv_w = eff(Cv, ms.D[vi][:, 4:], Bw) if nw else np.zeros((4, 4))
        De_f = eff(Ce, ms.D[list(erows)][:, :4], Bf)
        De_w = eff(Ce, ms.D[list(erows)][:, 4:], Bw) if nw else np.zeros((8, 4))
        feed = (De_f[:4], De_w[:4], Dv_w, De_f[4:], De_w[4:])
    Cy = ms.C[oi]
    # zero modes up to a multiple of _MODE_PAD: exact zeros in every sum, whole vectors
    n_pad = -len(phi) % _MODE_PAD
    if n_pad:
        def pad(a, axis):
            w = [(0, 0)] * a.ndim
            w[axis] = (0, n_pad)
            return np.pad(a, w)

        phi, g1, g0, gm = (pad(a, 0) for a in (phi, g1, g0, gm))
        Bf, Cv, Cy, Bw, Ce = pad(Bf, 0), pad(Cv, 1), pad(Cy, 1), pad(Bw, 0), pad(Ce, 1)
    # the output rows' coefficients on [Re x, Im x, dF]: Re(Cy x) + Dy dF in one product
    rows = [Cy.real.T, -Cy.imag.T, np.asarray(ms.D[oi][:, :4], dtype=float).T]
    if nw:
        rows.append(np.asarray(w_out, dtype=float).T)
    Cout = np.ascontiguousarray(np.concatenate(rows), dtype=float)
    modal = (*_split(phi), *_split(g1), *_split(g0), *_split(gm), *_split(Bf.T), *_split(Cv),
             np.ascontiguousarray(Deff))
    extra = (*_split(Bw.T if nw else np.zeros((0, len(phi)))), *_split(Ce)) + feed if len(erows) \
        else ()
    return modal, Cout, extra


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


def _check_converged(plant, iters, values=None):
    """Refuse setups whose step solve failed (``iters < 0``) or whose response diverged:
    `values` (setup first: forces or metrics, SI) not finite or beyond
    :data:`DIVERGED_VALUE`, as an unstable discretization gives with every step's solve
    converged (a very stiff damper at a coarse step)."""
    if np.any(iters < 0):
        bad = np.flatnonzero(iters < 0).tolist()
        raise ValueError(f"closed loop of plant {plant.name!r}: Newton's method did not converge "
                         f"for setups {bad}; the shock loop is ill-posed (check the shock curves "
                         "and the model's stability, or raise oversample)")
    if values is None:
        return
    v = np.reshape(values, (len(iters), -1))
    ok = np.all(np.isfinite(v), axis=1) & (np.max(np.abs(v), axis=1, initial=0.0)
                                           < DIVERGED_VALUE)
    if not np.all(ok):
        bad = np.flatnonzero(~ok).tolist()
        growth = unstable_growth_rate(plant)
        why = (f"the model itself is unstable (a mode grows at {growth:.3g} 1/s), which no "
               "oversample cures; identify it again (longer or more runs), check its fit"
               if growth > 0.0 else f"forces or metrics not finite or beyond {DIVERGED_VALUE:g}"
               " in SI units: the loop's time step is too coarse for their shocks (a very stiff "
               "damper); raise oversample")
        raise ValueError(f"closed loop of plant {plant.name!r}: the response diverged for setups "
                         f"{bad} ({why})")



def simulate(plant, drive, setup, *, oversample=4, outputs=None, rig=None, stop_tables=None,
             static_corner_load_n=None, third=None):
    """Simulate one shock setup on a plant and a drive in closed loop.

    Same as :func:`simulate_batch` with one setup; returns a :class:`Response`.
    `stop_tables` is the setup's bump stops in the loop's form (a mapping corner -> stop
    or 4 stops: :func:`simulate_batch`'s ``bump_stops`` entry of one setup), not a list;
    `third` the setup's ``(dampers, springs)`` (:func:`simulate_batch`'s ``third`` entry).
    """
    return simulate_batch(plant, drive, [setup], oversample=oversample, outputs=outputs,
                          rig=rig, bump_stops=None if stop_tables is None else [stop_tables],
                          static_corner_load_n=static_corner_load_n,
                          third=None if third is None else [third]).response(0)


# ----------------------------------------------------------------------------------------------
# bump stops and tire lift-off (issue 25)
# ----------------------------------------------------------------------------------------------

#: The per-corner summaries of :attr:`BatchResponse.elements`, by prefix.
ELEMENT_STATS = ("bump_stop_contact_share", "tire_liftoff_share", "tire_contact_min")


def corner_values(values, where, what):
    """Per-corner values LF, RF, LR, RR from a mapping (a corner left out or ``None``: none)
    or a sequence of 4; returns a list of 4 (entries ``None`` where none).

    Raises
    ------
    ValueError
        On an unknown corner or a sequence not of 4.
    """
    if not isinstance(values, Mapping):
        values = list(values)
    table = corner_table(values, name=what, where=where, sequence=True)
    return [table.get(c) for c in CORNERS]


def _check_stop(stop, where):
    """A bump stop ``(contact_travel_m, travel_m, force_n)`` as checked float arrays."""
    try:
        s0, x, f = stop
    except (TypeError, ValueError):
        raise TypeError(f"{where}: a bump stop is (contact_travel_m, travel_table_m, "
                        f"force_table_n), got {type(stop).__name__}") from None
    s0 = float(s0)
    x = np.asarray(x, dtype=float).ravel()
    f = np.asarray(f, dtype=float).ravel()
    if not np.isfinite(s0) or s0 < 0:
        raise ValueError(f"{where}: contact travel {s0!r} m must be >= 0 (the gap less the "
                         "packer, from the car at rest)")
    if x.size < 2 or x.size != f.size or not (np.all(np.isfinite(x)) and np.all(np.isfinite(f))):
        raise ValueError(f"{where}: travel and force tables need the same number (>= 2) of "
                         f"finite values, got {x.size} and {f.size}")
    if x[0] != 0 or f[0] != 0:
        raise ValueError(f"{where}: the tables start at travel 0 with force 0 (contact), got "
                         f"({x[0]!r}, {f[0]!r})")
    if np.any(np.diff(x) <= 0):
        raise ValueError(f"{where}: the travel table must increase strictly")
    if np.any(np.diff(f) < 0):
        raise ValueError(f"{where}: the force table falls with travel; a bump stop's force "
                         "must not decrease")
    return s0, x, f


def pack_bump_stops(per_setup, where="bump_stops"):
    """Pack the setups' bump stops into the arrays of the compiled loop.

    Parameters
    ----------
    per_setup : sequence
        One entry per setup: a mapping corner -> stop or 4 stops (LF, RF, LR, RR), or
        ``None`` (no bump stops). A stop is ``None`` or ``(contact_travel_m,
        travel_table_m, force_table_n)``: the shock travel from the car at rest at
        which the stop touches (its gap less the packer) [m], and its force [N] at
        travels beyond contact [m] (strictly increasing from 0; force from 0,
        non-decreasing), extended beyond the table with its last slope.
    where : str
        Names the argument in error messages.

    Returns
    -------
    on : ndarray of int, shape (n_setups, 4)
    s0 : ndarray, shape (n_setups, 4)
        Contact travel [m].
    bx, bf : ndarray, shape (n_setups, 4, n_points)
        Tables [m], [N], padded with their last point.
    bn : ndarray of int, shape (n_setups, 4)
        Points per table.
    bslope : ndarray, shape (n_setups, 4)
        Slope beyond the table [N/m].

    Raises
    ------
    ValueError, TypeError
        On a malformed stop (named by setup and corner).
    """
    S = len(per_setup)
    rows = []
    for i, stops in enumerate(per_setup):
        if stops is None:
            rows.append([None] * 4)
            continue
        vals = corner_values(stops, f"{where}: setup {i}", "bump stops")
        rows.append([None if st is None else _check_stop(st, f"{where}: setup {i} {c}")
                     for c, st in zip(CORNERS, vals)])
    K = max([2] + [st[1].size for row in rows for st in row if st is not None])
    on = np.zeros((S, 4), dtype=np.int64)
    s0 = np.zeros((S, 4))
    bx = np.zeros((S, 4, K))
    bf = np.zeros((S, 4, K))
    bn = np.full((S, 4), 2, dtype=np.int64)
    bx[:, :, 1:] = 1.0
    bslope = np.zeros((S, 4))
    for i, row in enumerate(rows):
        for c, st in enumerate(row):
            if st is None:
                continue
            a, x, f = st
            on[i, c] = 1
            s0[i, c] = a
            bx[i, c, :x.size], bx[i, c, x.size:] = x, x[-1]
            bf[i, c, :x.size], bf[i, c, x.size:] = f, f[-1]
            bn[i, c] = x.size
            bslope[i, c] = (f[-1] - f[-2]) / (x[-1] - x[-2])
    return on, s0, bx, bf, bn, bslope


def _static_loads(static_corner_load_n, where):
    """``(on, static)`` (4,) from the static loads (None: none)."""
    on = np.zeros(4, dtype=np.int64)
    static = np.zeros(4)
    if static_corner_load_n is None:
        return on, static
    for c, (name, val) in enumerate(zip(CORNERS, corner_values(
            static_corner_load_n, where, "static_corner_load_n"))):
        if val is None:
            continue
        val = float(val)
        if not np.isfinite(val) or val <= 0:
            raise ValueError(f"{where}: static_corner_load_n at {name} is {val!r} N; give the "
                             "tire's positive static load (the car at rest on the rig)")
        on[c] = 1
        static[c] = val
    return on, static


def _corner_rows(plant, kind, where, why):
    """Rows of ``<kind>_XX`` in the plant's outputs."""
    names = [f"{kind}_{c}" for c in CORNERS]
    missing = [n for n in names if n not in plant.output_names]
    if missing:
        raise ValueError(f"{where}: {why} needs the plant's outputs {missing}; plant "
                         f"{plant.name!r} has none of them (identify it with those channels)")
    return [plant.output_names.index(n) for n in names]


def _physical_same_step(extra):
    """The travel's same-step weights with the sign physics gives them (issue 25).

    A force in compression cannot add compression within the step: ``Dt[c, c] <= 0`` (the
    physical GT car: -0.045 / 600 kN/m at oversample 2; models identified from clean
    sessions: -0.03 to -0.07). The travel rows from ``dF`` have no feedthrough, and an
    identified model's weight over one internal step is the fit's behaviour far outside
    the fitted band: a model identified from a session whose stops and lift-off were not
    declared had +0.3 to +2.4 (x 1 / 600 kN/m), which makes the step's bump-stop equation
    ``G = g(s_free + Dt G)`` have no root (a loop gain above 1 within the step: "Newton's
    method did not converge"). Such a corner's same-step travel weights (``Dt`` and
    ``Dtw`` rows) are set to 0: its stop is evaluated at the travel from the state
    (explicit there; 5.1e-4 of the metrics at oversample 2 on the physical car, against
    4.7e-4 implicit). Rows of physical sign are kept as they are (the same numbers).
    """
    if not extra:
        return extra
    *head, Dt, Dtw, Dvw, Dcf, Dcw = extra
    bad = np.diag(Dt) > 0.0
    if bad.any():
        Dt, Dtw = Dt.copy(), Dtw.copy()
        Dt[bad] = 0.0
        Dtw[bad] = 0.0
    return (*head, Dt, Dtw, Dvw, Dcf, Dcw)


@dataclass(frozen=True, eq=False)
class _Elements:
    """The elements' kernel arguments for a batch (:func:`_element_args`).

    ``plant`` and ``cout`` replace the plain loop's (with lift-off the shock part has the
    wheelloader inputs joined, and ``cout`` the ``w`` rows); ``args`` are the fields of
    :class:`ident.sim.loop_kernels.Elements` but ``tf_rows`` and ``max_iter``; ``on``
    (n_setups, 4) and ``lo_on`` (4,) say where there are stops and static loads."""

    plant: ModalLoop
    cout: np.ndarray
    args: dict
    on: np.ndarray
    lo_on: np.ndarray
    static: np.ndarray

    def kernel_elements(self, tf_rows):
        """The kernels' :class:`ident.sim.loop_kernels.Elements` with the tire-force output
        columns `tf_rows`."""
        return Elements(tf_rows=tf_rows, max_iter=self.max_iter, **self.args)

    @property
    def max_iter(self):
        return ELEMENT_MAX_ITERATIONS if _ELEMENT_IMPLICIT else 1

    def settings(self, loop, drive):
        """The batch's settings with the elements'."""
        return dict(loop.settings(drive), bump_stops=bool(self.on.any()),
                    static_corner_load_n=None if not self.lo_on.any() else self.static.tolist())

    def values(self, stats, n_samples):
        """:attr:`BatchResponse.elements` from the kernels' ``stats`` (n_setups, 3, 4)."""
        elements = {}
        for c, corner in enumerate(CORNERS):
            if self.on[:, c].any():
                elements[f"bump_stop_contact_share_{corner}"] = stats[:, 0, c] / max(n_samples, 1)
            if self.lo_on[c]:
                elements[f"tire_liftoff_share_{corner}"] = stats[:, 1, c] / max(n_samples, 1)
                elements[f"tire_contact_min_{corner}"] = np.maximum(stats[:, 2, c], 0.0)
        return elements


def _element_args(plant, loop, bump_stops, static_corner_load_n, where):
    """Check the bump stops (one entry per setup) and static loads and build the elements'
    kernel arguments for the batch `loop` (:func:`_loop_setup`): an :class:`_Elements`."""
    S = len(loop.models)
    if bump_stops is None:
        bump_stops = [None] * S
    bump_stops = list(bump_stops)
    if len(bump_stops) != S:
        raise ValueError(f"{where}: bump_stops has {len(bump_stops)} entries for {S} setups; "
                         "give one per setup (None: none)")
    on, s0, bx, bf, bn, bslope = pack_bump_stops(bump_stops, f"{where}: bump_stops")
    lo_on, static = _static_loads(static_corner_load_n, where)
    any_bs, any_lo = bool(on.any()), bool(lo_on.any())
    h = 1.0 / (loop.rig.fs_hz * loop.oversample)
    vi = plant.velocity_idx
    oi = np.array([plant.output_names.index(o) for o in loop.names], dtype=int)
    # the element rows: travel (needed with bump stops), tire force (with lift-off); a
    # plant without one of them is refused only when it is needed
    ti = _corner_rows(plant, "shock_travel", where, "bump_stops") if any_bs else list(vi)
    fi = _corner_rows(plant, "tire_force", where, "static_corner_load_n") if any_lo else list(vi)
    erows = np.array(list(ti) + list(fi), dtype=int)
    ms = plant.shock
    w_out = None
    if any_lo:
        wl = [RIG_INPUTS.index(c) for c in WHEELLOADER_INPUTS]
        ms = join_inputs(ms, plant.rig.select(inputs=wl).pruned())
        # the pad correction's direct path: into the tire force and accelerations, not into
        # the ride heights (measured from the real pad)
        w_out = np.array(ms.D[oi][:, 4:], dtype=float)
        w_out[[kind_of(n) == "ride_height" for n in loop.names]] = 0.0
    modal, Cout, extra = _modal_args(ms, vi, oi, h, erows=erows, w_out=w_out)
    extra = _physical_same_step(extra)
    # the element rows' rig-input part on the internal grid
    key = tuple(int(i) for i in erows)
    e_rig = loop.rig.element_rows.get(key)
    if e_rig is None:
        mr = plant.rig.select(outputs=np.concatenate([vi, erows])).pruned()
        _, e_y = _rig_outputs(mr, h, loop.rig.u_fine, 1)
        e_rig = loop.rig.element_rows[key] = np.ascontiguousarray(e_y.T)
    Bwr, Bwi, Cer, Cei, Dt, Dtw, Dvw, Dcf, Dcw = extra
    args = dict(Bwr=Bwr, Bwi=Bwi, Cer=Cer, Cei=Cei, e_rig=e_rig, Dt=Dt, Dtw=Dtw, Dvw=Dvw, Dcf=Dcf,
                Dcw=Dcw, bs_on=on, s0=s0, bx=bx, bf=bf, bn=bn, bslope=bslope,
                lo_on=np.repeat(lo_on[None], S, axis=0),
                static=np.repeat(static[None], S, axis=0))
    return _Elements(plant=ModalLoop(*modal, loop.plant.cbar), cout=Cout, args=args, on=on,
                     lo_on=lo_on, static=static)


def _element_response(plant, drive, loop, bump_stops, static_corner_load_n, where):
    """:func:`simulate_batch` with bump stops and/or static loads (the elements' kernels)."""
    S, N = len(loop.models), loop.rig.n_samples
    el = _element_args(plant, loop, bump_stops, static_corner_load_n, where)
    tf_rows = np.array([loop.names.index(f"tire_force_{c}") if f"tire_force_{c}" in loop.names
                        else -1 for c in CORNERS], dtype=np.int64)
    y = np.empty((S, len(loop.names), N))
    F = np.empty((S, N, 4))
    iters = np.zeros(S, dtype=np.int64)
    stats = np.zeros((S, 3, 4))
    _run_loop(el.plant, loop, el.cout, (y, F, iters, el.kernel_elements(tf_rows), stats, None,
                                        None))
    _check_converged(plant, iters, F)
    channels = {name: y[:, j, :] for j, name in enumerate(loop.names)}
    for c, name in enumerate(SHOCK_FORCES):
        channels[name] = F[:, :, c]
    return BatchResponse(channels=channels, fs_hz=loop.rig.fs_hz,
                         setups=tuple(tuple(m) for m in loop.models), newton_iterations=iters,
                         settings=el.settings(loop, drive), elements=el.values(stats, N))


#: Solve bump stops and lift-off within the step (True); False evaluates the bump stop at
#: the travel extrapolated from the state (one solve per step): kept to measure the
#: difference (tests and the issue-25 notes), not an option.
_ELEMENT_IMPLICIT = True


# ----------------------------------------------------------------------------------------------
# third elements: heave and roll dampers, heave springs (issue 38)
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class _Third:
    """The third elements' kernel arguments for a batch (:func:`_third_args`): the kernels'
    :class:`~ident.sim.loop_kernels.ThirdLoop` and the outputs with the elements' motions
    appended (``names``, ``cout``, ``y_rig``)."""

    kernel: ThirdLoop
    names: list
    cout: np.ndarray
    y_rig: np.ndarray
    dampers: tuple
    spring_names: tuple  # the F_out columns after the dampers': heave springs, corner stops
    motions: dict = field(default_factory=dict)  # element channel -> ("travel"|"velocity", row)

    @property
    def n_springs(self):
        return len(self.spring_names)

    def settings(self, loop, drive):
        return dict(loop.settings(drive), third=True,
                    bump_stops=any(n.startswith("bump_stop") for n in self.spring_names))

    def values(self, tstats, n_samples):
        """The springs' contact shares from the kernels' counts (n_setups, ns)."""
        out = {}
        for j, name in enumerate(self.spring_names):
            key = name.replace("_force_", "_contact_share_")
            out[key] = tstats[:, j] / max(n_samples, 1)
        return out

    def force_channels(self):
        """The names of ``F_out``'s columns after the 4 shocks'."""
        return [third_channel(e, "force") for e in self.dampers] + list(self.spring_names)


def _third_args(plant, loop, bump_stops, static_corner_load_n, third, where):
    """Check the setups' third elements (one entry per setup) and the corners' bump stops and
    build the kernels' arguments for the batch `loop` (:func:`_loop_setup`): a
    :class:`_Third`. The corners' bump stops become springs on unit rows."""
    S = len(loop.models)
    third = list(third)
    if len(third) != S:
        raise ValueError(f"{where}: third has {len(third)} entries for {S} setups; give one "
                         "per setup (None: none)")
    if static_corner_load_n is not None:
        raise ValueError(f"{where}: tire lift-off (static_corner_load_n) is not solved together "
                         "with third elements; leave static_corner_load_n out for a car with "
                         "third elements")
    h = 1.0 / (loop.rig.fs_hz * loop.oversample)
    pack = pack_third(third, h, where=f"{where}: third")
    ti = _corner_rows(plant, "shock_travel", where, "third elements")
    vi = list(plant.velocity_idx)
    # the springs: heave springs, then the corners' bump stops on unit rows
    on, s0c, bxc, bfc, bnc, bslc = pack_bump_stops(
        [None] * S if bump_stops is None else list(bump_stops), f"{where}: bump_stops")
    if len(on) != S:
        raise ValueError(f"{where}: bump_stops has {len(on)} entries for {S} setups; give one "
                         "per setup (None: none)")
    corners = [c for c in range(4) if on[:, c].any()]
    spring_names = tuple(third_channel(e, "spring_force") for e in pack.springs) + tuple(
        f"bump_stop_force_{CORNERS[c]}" for c in corners)
    ns = len(spring_names)
    tables = []
    for i in range(S):
        row = []
        for e, ct in zip(pack.springs, pack.spring_contacts[i]):
            row.append(None if ct is None else _check_stop(ct, f"{where}: third: setup {i} "
                                                               f"{e} spring"))
        for c in corners:
            row.append((s0c[i, c], bxc[i, c, :bnc[i, c]], bfc[i, c, :bnc[i, c]]) if on[i, c]
                       else None)
        tables.append(row)
    P = max([2] + [t[1].size for row in tables for t in row if t is not None])
    s0 = np.full((S, ns), UNREACHED_CONTACT_M)
    bx = np.zeros((S, ns, P))
    bf = np.zeros((S, ns, P))
    bn = np.full((S, ns), 2, dtype=np.int64)
    bx[:, :, 1:] = 1.0
    bslope = np.zeros((S, ns))
    for i, row in enumerate(tables):
        for j, t in enumerate(row):
            if t is None:
                continue
            a, x, f = t
            s0[i, j] = a
            bx[i, j, :x.size], bx[i, j, x.size:] = x, x[-1]
            bf[i, j, :x.size], bf[i, j, x.size:] = f, f[-1]
            bn[i, j] = x.size
            bslope[i, j] = (f[-1] - f[-2]) / (x[-1] - x[-2])
    srows = np.concatenate([pack.spring_rows, np.eye(4)[corners]]).reshape(ns, 4)
    scorner = np.array([-1] * len(pack.springs) + corners, dtype=np.int64)
    # the travel rows (padded as the modes), their same-step response and rig part
    erows = np.array(ti + ti, dtype=int)
    oi = np.array([plant.output_names.index(o) for o in loop.names], dtype=int)
    _, _, extra = _modal_args(plant.shock, vi, oi, h, erows=erows)
    extra = _physical_same_step(extra)
    _, _, Cer, Cei, Dt = extra[:5]
    key = tuple(int(i) for i in erows)
    e_rig = loop.rig.element_rows.get(key)
    if e_rig is None:
        mr = plant.rig.select(outputs=np.concatenate([vi, erows])).pruned()
        _, e_y = _rig_outputs(mr, h, loop.rig.u_fine, 1)
        e_rig = loop.rig.element_rows[key] = np.ascontiguousarray(e_y.T)
    t_rig = np.ascontiguousarray(e_rig[:, :4])
    drows, kv, kf, nk, slo, shi, alpha, b0, b1, bm = pack.damper_args
    kernel = ThirdLoop(np.ascontiguousarray(Cer[:4].T), np.ascontiguousarray(Cei[:4].T), t_rig,
                       np.ascontiguousarray(Dt), drows, np.ascontiguousarray(srows), scorner,
                       kv, kf, nk, slo, shi, alpha, b0, b1, bm, s0, bx, bf, bn, bslope)
    # the elements' motions as outputs: their rows over the velocity and travel outputs
    _, Cvt, _ = _modal_args(plant.shock, vi, np.array(vi + ti, dtype=int), h)
    r = loop.oversample
    v_rig_out = loop.rig.v_fine[::r][:loop.y_rig.shape[0]]
    t_rig_out = t_rig[::r][:loop.y_rig.shape[0]]
    names, cols, rig_cols, motions = list(loop.names), [], [], {}
    for e, row in zip(pack.elements, pack.rows):
        for what, C_, y_ in (("velocity", Cvt[:, :4], v_rig_out), ("travel", Cvt[:, 4:],
                                                                   t_rig_out)):
            name = third_channel(e, what)
            if name in names:
                continue
            names.append(name)
            motions[name] = (what, np.asarray(row, dtype=float))
            cols.append(C_ @ row)
            rig_cols.append(y_ @ row)
    cout = np.ascontiguousarray(np.concatenate([loop.cout, np.stack(cols, axis=1)], axis=1)
                                if cols else loop.cout)
    y_rig = np.ascontiguousarray(np.concatenate([loop.y_rig, np.stack(rig_cols, axis=1)], axis=1)
                                 if cols else loop.y_rig)
    return _Third(kernel=kernel, names=names, cout=cout, y_rig=y_rig, dampers=pack.dampers,
                  spring_names=spring_names, motions=motions)


def _third_response(plant, drive, loop, bump_stops, static_corner_load_n, third, where, th=None):
    """:func:`simulate_batch` with third elements (the kernels' third path)."""
    if th is None:
        th = _third_args(plant, loop, bump_stops, static_corner_load_n, third, where)
        loop = replace(loop, names=th.names, cout=th.cout, y_rig=th.y_rig)
    S, N = len(loop.models), loop.rig.n_samples
    nF = 4 + len(th.dampers) + th.n_springs
    y = np.empty((S, len(loop.names), N))
    F = np.empty((S, N, nF))
    iters = np.zeros(S, dtype=np.int64)
    tstats = np.zeros((S, th.n_springs))
    _run_loop(loop.plant, loop, loop.cout, (y, F, iters, None, None, th.kernel, tstats))
    _check_converged(plant, iters, F)
    channels = {name: y[:, j, :] for j, name in enumerate(loop.names)}
    for c, name in enumerate(list(SHOCK_FORCES) + th.force_channels()):
        channels[name] = F[:, :, c]
    return BatchResponse(channels=channels, fs_hz=loop.rig.fs_hz,
                         setups=tuple(tuple(m) for m in loop.models), newton_iterations=iters,
                         settings=th.settings(loop, drive), elements=th.values(tstats, N))
