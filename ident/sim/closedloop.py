"""Closed-loop simulation of a linear vehicle model with nonlinear shock absorbers.

This is the one simulator of the project: the virtual rig runs the physical
full-car model through it, the planner runs identified models through it.

The linear part is a :class:`LoopPlant`: an LTI system with inputs
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
hold, :func:`hold_coefficients`)::

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

:func:`simulate_batch` returns every setup's channels; :func:`simulate_batch_metrics`
returns only the spec's metrics, each setup's computed by the thread that simulated it
right after its loop (the planner's predictions).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ident.data.channels import CORNERS, RIG_INPUTS, SHOCK_FORCES, SHOCK_VELOCITIES, WHEELLOADER_INPUTS
from ident.data.drive import check_drive_inputs

__all__ = [
    "ModalSystem",
    "LoopPlant",
    "RigResponse",
    "Response",
    "BatchResponse",
    "BatchMetrics",
    "modal_form",
    "foh_coefficients",
    "hold_coefficients",
    "lag_hold_coefficients",
    "lag_coefficients",
    "rig_response",
    "simulate",
    "simulate_batch",
    "simulate_batch_metrics",
]

log = logging.getLogger(__name__)

_REAL_TOL = 1e-9  # |Im(lam)| / |lam| below which a pole is taken as real


@dataclass(frozen=True, eq=False)
class ModalSystem:
    """A continuous-time LTI system in diagonal (modal) form.

    ``x' = diag(lam) x + B u``, ``y = Re(C x) + D u``. A complex conjugate pole
    pair is held as one complex state (the one with positive imaginary part)
    whose output coefficients carry the factor 2; a real pole is a state with
    real coefficients.

    Attributes
    ----------
    lam : ndarray of complex, shape (n,)
        Poles [rad/s].
    B : ndarray of complex, shape (n, m)
    C : ndarray of complex, shape (p, n)
    D : ndarray of float, shape (p, m)
    """

    lam: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    @property
    def n_states(self):
        """Number of modal states (pairs count once)."""
        return self.lam.size

    def frequency_response(self, f_hz):
        """Frequency response ``H[output, input, frequency]``, shape (p, m, n_f).

        Uses ``Re(C x)`` with the conjugate pair restored exactly:
        ``H = (C diag(1/(s-lam)) B + conj(C) diag(1/(s-conj(lam))) conj(B)) / 2 + D``
        for the modal states (real poles give the same formula).
        """
        s = 2j * np.pi * np.atleast_1d(np.asarray(f_hz, dtype=float))
        r1 = 1.0 / (s[None, :] - self.lam[:, None])  # (n, nf)
        r2 = 1.0 / (s[None, :] - np.conj(self.lam)[:, None])
        H = 0.5 * (np.einsum("pn,nf,nm->pmf", self.C, r1, self.B)
                   + np.einsum("pn,nf,nm->pmf", np.conj(self.C), r2, np.conj(self.B)))
        return H + self.D[:, :, None]

    def to_real(self):
        """Real block-diagonal (modal) state-space matrices ``(A, B, C, D)``.

        A complex mode ``lam = s + j w`` with coefficients ``b``, ``c`` becomes
        the 2x2 block ``[[s, -w], [w, s]]`` on ``[Re x, Im x]`` with inputs
        ``[Re b; Im b]`` and outputs ``[Re c, -Im c]``; a real mode stays one state.
        Well conditioned (no polynomial expansion, no eigenvector matrix).
        """
        real = self.lam.imag == 0
        n = int(real.sum() + 2 * (~real).sum())
        m, p = self.B.shape[1], self.C.shape[0]
        A = np.zeros((n, n))
        B = np.zeros((n, m))
        C = np.zeros((p, n))
        k = 0
        for i, lam in enumerate(self.lam):
            if real[i]:
                A[k, k] = lam.real
                B[k] = self.B[i].real
                C[:, k] = self.C[:, i].real
                k += 1
            else:
                A[k:k + 2, k:k + 2] = [[lam.real, -lam.imag], [lam.imag, lam.real]]
                B[k], B[k + 1] = self.B[i].real, self.B[i].imag
                C[:, k], C[:, k + 1] = self.C[:, i].real, -self.C[:, i].imag
                k += 2
        return A, B, C, self.D.copy()

    def pruned(self, rtol=1e-13):
        """Drop modes that no input drives or no output reads.

        Scale-aware: each input column of B and each output row of C is
        normalized by its own largest entry first (outputs in different units,
        e.g. N and m, must not prune each other).
        """
        if self.lam.size == 0:
            return self
        Bn = np.abs(self.B) / np.maximum(np.abs(self.B).max(axis=0, keepdims=True), 1e-300)
        Cn = np.abs(self.C) / np.maximum(np.abs(self.C).max(axis=1, keepdims=True), 1e-300)
        keep = (Bn.max(axis=1) > rtol) & (Cn.max(axis=0) > rtol)
        return ModalSystem(self.lam[keep], self.B[keep], self.C[:, keep], self.D)

    def select(self, outputs=None, inputs=None):
        """Return the subsystem of some outputs and inputs (index arrays)."""
        C, D, B = self.C, self.D, self.B
        if outputs is not None:
            C, D = C[outputs], D[outputs]
        if inputs is not None:
            B, D = B[:, inputs], D[:, inputs]
        return ModalSystem(self.lam, B, C, D)


def modal_form(A, B, C, D, *, max_condition=1e10):
    """Convert a real state-space system to :class:`ModalSystem`.

    Parameters
    ----------
    A, B, C, D : array_like
        Real matrices of shapes (n, n), (n, m), (p, n), (p, m).
    max_condition : float
        Largest accepted condition number of the eigenvector matrix.

    Returns
    -------
    ModalSystem

    Raises
    ------
    ValueError
        If ``A`` is (nearly) defective: its eigenvectors are too ill
        conditioned for a modal realization.
    """
    A, B, C, D = (np.asarray(x, dtype=float) for x in (A, B, C, D))
    lam, V = np.linalg.eig(A)
    lam, V = lam.astype(complex), V.astype(complex)  # eig returns real arrays for real spectra
    cond = np.linalg.cond(V)
    if not np.isfinite(cond) or cond > max_condition:
        raise ValueError(
            f"modal_form: the state matrix is nearly defective (eigenvector condition number "
            f"{cond:.3g} > {max_condition:.3g}); perturb repeated poles or use another realization"
        )
    Bm = np.linalg.solve(V, B)
    Cm = C @ V
    keep, scale = [], []
    for i, li in enumerate(lam):
        if abs(li.imag) <= _REAL_TOL * max(abs(li), 1e-300):
            keep.append(i)
            scale.append(1.0)
        elif li.imag > 0:
            keep.append(i)
            scale.append(2.0)
    keep = np.array(keep, dtype=int)
    scale = np.array(scale)
    lam_k = lam[keep].copy()
    real = scale == 1.0
    lam_k[real] = lam_k[real].real
    Bk = Bm[keep]
    Ck = Cm[:, keep] * scale[None, :]
    # real modes: make the coefficients real (eigenvector of a real pole is real up to a phase)
    for j in np.flatnonzero(real):
        ph = np.exp(-1j * np.angle(Bk[j][np.argmax(np.abs(Bk[j]))])) if np.any(Bk[j]) else 1.0
        Bk[j] *= ph
        Ck[:, j] /= ph
    order = np.lexsort((lam_k.imag, lam_k.real))
    return ModalSystem(lam=lam_k[order], B=Bk[order], C=Ck[:, order], D=D.copy())


def foh_coefficients(lam, h):
    """Exact first-order-hold discretization coefficients of modes ``x' = lam x + u``.

    ``lam`` [rad/s] and ``h`` [s] as in :func:`hold_coefficients` (the quadratic hold the
    simulator uses); the first-order hold is kept as the textbook reference.

    Returns
    -------
    phi, g0, g1 : ndarray of complex, shape (n,)
        ``x[k+1] = phi x[k] + g0 u[k] + g1 u[k+1]`` for ``u`` linear over the step.
    """
    z = np.asarray(lam, dtype=complex) * h
    p1, p2, _ = _phi_functions(z)
    return np.exp(z), (p1 - p2) * h, p2 * h


def _phi_functions(z):
    """``phi_1..phi_3(z) = (e^z - sum_{j<n} z^j / j!) / z^n`` (series for small |z|)."""
    small = np.abs(z) < 1e-2
    zs = np.where(small, 1.0, z)
    em1 = np.expm1(zs)
    p1 = np.where(small, 1 + z / 2 + z**2 / 6 + z**3 / 24 + z**4 / 120, em1 / zs)
    p2 = np.where(small, 1 / 2 + z / 6 + z**2 / 24 + z**3 / 120 + z**4 / 720, (em1 - zs) / zs**2)
    p3 = np.where(small, 1 / 6 + z / 24 + z**2 / 120 + z**3 / 720 + z**4 / 5040,
                  (em1 - zs - zs**2 / 2) / zs**3)
    return p1, p2, p3


def hold_coefficients(lam, h):
    """Exact discretization of modes ``x' = lam x + u`` for a quadratic hold.

    Over the step ``[t_k, t_k+1]`` the input is the parabola through
    ``u[k-1], u[k], u[k+1]``, integrated exactly:
    ``x[k+1] = phi x[k] + g1 u[k+1] + g0 u[k] + gm u[k-1]``. The local error is
    ``O(h^4)`` (``O(h^3)`` globally) against the first-order hold's ``O(h^3)``
    (``O(h^2)``): on a rig drive sampled at 100 Hz the first-order hold's droop
    ``sinc^2(f h)`` alone costs 1 % of a tire-force RMS at 2 internal steps per
    sample. Only ``g1`` multiplies the unknown newest input, so the shock loop
    stays a 4x4 algebraic equation per step. A mode much faster than the step
    follows its input exactly at the samples (as with the first-order hold).

    Parameters
    ----------
    lam : array_like of complex, shape (n,)
        Continuous poles [rad/s].
    h : float
        Step [s].

    Returns
    -------
    phi, g1, g0, gm : ndarray of complex, shape (n,)

    Examples
    --------
    A parabola is integrated exactly: ``x' = -x + t^2`` from ``x(0) = 0``.

    >>> phi, g1, g0, gm = hold_coefficients([-1.0], 0.1)
    >>> t = np.arange(-1, 11) * 0.1
    >>> x = 0.0
    >>> for k in range(1, 11):
    ...     x = phi[0] * x + g1[0] * t[k + 1]**2 + g0[0] * t[k]**2 + gm[0] * t[k - 1]**2
    >>> exact = 1.0**2 - 2 * 1.0 + 2 - 2 * np.exp(-1.0)
    >>> bool(abs(x.real - exact) < 1e-12)
    True
    """
    lam = np.asarray(lam, dtype=complex)
    z = lam * h
    p1, p2, p3 = _phi_functions(z)
    # int_0^h e^{lam (h - t)} t^n dt = n! h^(n+1) phi_(n+1)(z); parabola through t = -h, 0, h
    g1 = h * (p2 / 2 + p3)
    g0 = h * (p1 - 2 * p3)
    gm = h * (p3 - p2 / 2)
    return np.exp(z), g1, g0, gm


def lag_hold_coefficients(lag_s, h):
    """Quadratic-hold discretization of the shock lag ``tau F' + F = f`` (see
    :func:`hold_coefficients`).

    Returns ``(alpha, b0, b1, bm)`` such that
    ``F[k] = alpha F[k-1] + b0 f[k] + b1 f[k-1] + bm f[k-2]``; ``tau = 0`` gives
    ``F = f``.
    """
    tau = np.asarray(lag_s, dtype=float)
    pos = tau > 0
    ts = np.where(pos, tau, 1.0)
    phi, g1, g0, gm = hold_coefficients(-1.0 / ts, h)
    alpha = np.where(pos, phi.real, 0.0)
    b0 = np.where(pos, g1.real / ts, 1.0)
    b1 = np.where(pos, g0.real / ts, 0.0)
    bm = np.where(pos, gm.real / ts, 0.0)
    return alpha, b0, b1, bm


def lag_coefficients(lag_s, h):
    """First-order-hold discretization of the shock lag ``tau F' + F = f``.

    Returns ``(alpha, b0, b1)`` such that ``F[k] = alpha F[k-1] + b1 f[k-1] + b0 f[k]``,
    exact when ``f(v(t))`` is linear over the step; ``tau = 0`` gives ``F = f``.
    """
    tau = np.asarray(lag_s, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        alpha = np.where(tau > 0, np.exp(-h / np.where(tau > 0, tau, 1.0)), 0.0)
        r = np.where(tau > 0, tau / h * (1 - alpha), 0.0)
    b0 = 1 - r
    b1 = r - alpha
    return alpha, b0, b1


@dataclass(frozen=True, eq=False)
class LoopPlant:
    """A linear vehicle model ready for the closed loop with shocks (Eq. 20).

    The response is ``y = H~rig u_rig + H~shocks dF``: two modal systems, one
    driven by the 7 rig inputs (simulated once per drive) and one by the 4
    shock-force deviations (stepped in the shock loop, so it should be
    compact). They may share poles (the physical model) or not (an identified
    model fitted pair by pair).

    Attributes
    ----------
    rig : ModalSystem
        Inputs ``RIG_INPUTS`` (7), outputs ``output_names``; the columns of
        inputs not in `rig_inputs` are zero.
    shock : ModalSystem
        Inputs ``dF_LF..dF_RR`` (4), outputs ``output_names``.
    output_names : tuple of str
        Canonical channel names; must contain the 4 ``shock_velocity_XX``.
    cbar_n_s_m : ndarray, shape (4,)
        Baseline linear damping the model is written around [N/(m/s)].
    name : str
    rig_inputs : tuple of str
        The rig inputs the model has (default all 7): a model identified on a
        4-post rig has the 4 wheelloaders only, and :func:`rig_response`
        refuses a drive with nonzero content on the others
        (:func:`ident.data.drive.check_drive_inputs`).
    """

    rig: ModalSystem
    shock: ModalSystem
    output_names: tuple
    cbar_n_s_m: np.ndarray
    name: str = "plant"
    rig_inputs: tuple = RIG_INPUTS
    velocity_idx: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        missing = [v for v in SHOCK_VELOCITIES if v not in self.output_names]
        if missing:
            raise ValueError(f"plant {self.name!r}: outputs lack {missing}; the shock loop needs "
                             "the 4 shock velocities")
        p = len(self.output_names)
        for part, m in ((self.rig, 7), (self.shock, 4)):
            if part.B.shape[1] != m or part.C.shape[0] != p:
                raise ValueError(f"plant {self.name!r}: a part has {part.B.shape[1]} inputs and "
                                 f"{part.C.shape[0]} outputs; expected {m} and {p}")
        rig_inputs = tuple(self.rig_inputs)
        if (any(c not in RIG_INPUTS for c in rig_inputs)
                or any(w not in rig_inputs for w in WHEELLOADER_INPUTS)):
            raise ValueError(f"plant {self.name!r}: rig_inputs {list(rig_inputs)} must be rig "
                             f"inputs of {list(RIG_INPUTS)} including the 4 wheelloaders")
        object.__setattr__(self, "rig_inputs", tuple(c for c in RIG_INPUTS if c in rig_inputs))
        cbar = np.asarray(self.cbar_n_s_m, dtype=float).reshape(4)
        object.__setattr__(self, "cbar_n_s_m", cbar)
        idx = np.array([self.output_names.index(v) for v in SHOCK_VELOCITIES])
        object.__setattr__(self, "velocity_idx", idx)

    @classmethod
    def from_state_space(cls, A, B, C, D, output_names, cbar_n_s_m, *, name="plant"):
        """Build from real state-space matrices with inputs ``[u_rig (7), dF (4)]``."""
        md = modal_form(A, B, C, D)
        return cls(md.select(inputs=slice(0, 7)).pruned(), md.select(inputs=slice(7, 11)).pruned(),
                   tuple(output_names), np.asarray(cbar_n_s_m, float), name=name)

    def frequency_response(self, f_hz):
        """``H[output, input, frequency]`` with inputs rig (7) then dF (4), shape (p, 11, n_f)."""
        return np.concatenate([self.rig.frequency_response(f_hz),
                               self.shock.frequency_response(f_hz)], axis=1)


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


def _refine(u, r):
    """Band-limited interpolation of (N, m) drive samples onto r sub-steps: (N-1)*r + 1 rows.

    Rig signals are samples of continuous, band-limited signals (not piecewise
    linear between samples), so the hold assumption of the discretization is
    applied on the fine grid only, where its error is ``sinc^2(f / (r fs))``.
    The record is extended by its end values over the filter's length first,
    so a drive that starts or ends at an offset does not ring there.
    """
    if r == 1:
        return np.ascontiguousarray(u, dtype=float)
    from ident.data.drive import _FIR_HALF_LENGTH, resample_bandlimited

    pad = _FIR_HALF_LENGTH + 1
    up = resample_bandlimited(np.pad(u, ((pad, pad), (0, 0)), mode="edge"), r, 1, axis=0)
    return np.ascontiguousarray(up[pad * r: pad * r + (u.shape[0] - 1) * r + 1])


def _drive_array(drive):
    if hasattr(drive, "as_array"):
        return np.asarray(drive.as_array(), dtype=float), float(drive.fs_hz)
    raise TypeError(f"drive must be an ident.data.drive.Drive, got {type(drive).__name__}")


def rig_response(plant, drive, *, oversample=4, outputs=None):
    """Compute the setup-independent, rig-input part of the response.

    Parameters
    ----------
    plant : LoopPlant
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
    r = _check_oversample(oversample)
    names = _check_outputs(plant, outputs)
    u, fs = _drive_array(drive)
    if plant.rig_inputs != RIG_INPUTS:
        check_drive_inputs(drive, plant.rig_inputs, model=plant.name)
    u_fine = _refine(u, r)
    h = 1.0 / (fs * r)
    vi = plant.velocity_idx
    oi = np.array([plant.output_names.index(o) for o in names], dtype=int)
    mr = plant.rig.select(outputs=np.concatenate([vi, oi])).pruned()
    v_fine, y = _rig_outputs(mr, h, u_fine, r)
    return RigResponse(v_fine=np.ascontiguousarray(v_fine), y=y, u_fine=u_fine, fs_hz=fs,
                       oversample=r, n_samples=u.shape[0], plant_name=plant.name,
                       output_names=tuple(names))


#: Internal steps per time chunk of :func:`_rig_kernel`. Fixed (not the thread count), so the
#: result does not depend on how many threads run it; a record of at most one chunk runs
#: serially with no superposition pass. 8,192: a 120 s drive at 100 Hz and oversample 2
#: (24,000 steps, 68 rig modes) in 3 chunks on 2 cores takes 0.028 s against 0.032 s serial.
_RIG_CHUNK = 1 << 13


def _rig_outputs(mr, h, u_fine, r):
    """Outputs of the modal system `mr` (rows: 4 shock velocities, then the outputs asked for)
    driven by `u_fine` on the internal grid: ``v_fine`` (n_fine, 4) on every step and ``y``
    (n_outputs, n_samples) on every `r`-th step, zero initial state.

    One compiled pass (:func:`_rig_kernel`): each mode's input ``b_i . u[k]`` and its hold
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
    _rig_kernel(np.ascontiguousarray(u_fine, dtype=float), *split(np.asarray(mr.B).T), *split(phi),
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


def _check_oversample(oversample):
    if isinstance(oversample, bool) or not isinstance(oversample, (int, np.integer)) or oversample < 1:
        raise ValueError(f"oversample must be a positive integer, got {oversample!r}")
    return int(oversample)


# ----------------------------------------------------------------------------------------------
# the compiled loop
# ----------------------------------------------------------------------------------------------

import numba as _nb  # noqa: E402

from ident.sim.metrics import _LANES as _METRIC_LANES  # noqa: E402
from ident.sim.metrics import _PW_LEVELS as _METRIC_PW_LEVELS  # noqa: E402
from ident.sim.metrics import _setup_metric_rms  # noqa: E402


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _rig_chunk(u, BrT, BiT, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, CrT, CmiT, DT, r, z, k0, k1,
               v, y, outputs):
    """Steps ``k0 <= k < k1`` of :func:`_rig_kernel` from the states ``z`` (4, n): rows
    ``Re z0, Im z0, Re z1, Im z1`` of the transposed direct form II per mode, updated in
    place. With `outputs` False only the states are run (the chunk end states).

    Each step is three loops over 1-D rows, so that numba's loop vectorizer takes them:
    the modes' inputs ``b_i . u[k]`` (over the modes, one input after the other), the
    modes' hold recursions, and the outputs (over the outputs, one mode after the other).
    Every sum keeps its order: the numbers of a loop over modes with the sums inside.
    """
    n = pr.size
    m = u.shape[1]
    p = CrT.shape[1]
    z0r = z[0]
    z0i = z[1]
    z1r = z[2]
    z1i = z[3]
    acc = np.empty(p)
    ar = np.empty(n)
    ai = np.empty(n)
    xr = np.empty(n)
    xi = np.empty(n)
    phase = k0 % r
    for k in range(k0, k1):
        q = p if phase == 0 else 4  # the outputs on every r-th step, the velocities on all
        for i in range(n):
            ar[i] = 0.0
            ai[i] = 0.0
        for j in range(m):  # the modes' inputs b_i . u[k]
            uj = u[k, j]
            brj = BrT[j]
            bij = BiT[j]
            for i in range(n):
                ar[i] += brj[i] * uj
                ai[i] += bij[i] * uj
        for i in range(n):
            a = ar[i]
            b = ai[i]
            # x = g1 w + z0; z0 <- g0 w + phi x + z1; z1 <- gm w (lfilter's recurrence)
            x_r = g1r[i] * a - g1i[i] * b + z0r[i]
            x_i = g1r[i] * b + g1i[i] * a + z0i[i]
            z0r[i] = g0r[i] * a - g0i[i] * b + (pr[i] * x_r - pi[i] * x_i) + z1r[i]
            z0i[i] = g0r[i] * b + g0i[i] * a + (pr[i] * x_i + pi[i] * x_r) + z1i[i]
            z1r[i] = gmr[i] * a - gmi[i] * b
            z1i[i] = gmr[i] * b + gmi[i] * a
            xr[i] = x_r
            xi[i] = x_i
        if outputs:
            for o in range(q):
                acc[o] = 0.0
            for j in range(m):
                uj = u[k, j]
                dj = DT[j]
                for o in range(q):
                    acc[o] += dj[o] * uj
            for i in range(n):  # Re(C[o, i] x)
                x_r = xr[i]
                x_i = xi[i]
                cr = CrT[i]
                ci = CmiT[i]
                for o in range(q):
                    acc[o] += cr[o] * x_r + ci[o] * x_i
            for o in range(4):
                v[k, o] = acc[o]
            if phase == 0:
                kk = k // r
                for o in range(4, p):
                    y[kk, o - 4] = acc[o]
        phase += 1
        if phase == r:
            phase = 0


@_nb.njit(cache=True, error_model="numpy", parallel=True, nogil=True)
def _rig_kernel(u, BrT, BiT, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, pLr, pLi, CrT, CmiT, DT, r,
                L, n_chunks, v, y):
    """Kernel of :func:`_rig_outputs`, parallel over time chunks of `L` steps.

    ``u`` (N, m) inputs; ``B.T`` (m, n) split in real and imaginary parts; the hold
    coefficients per mode; ``pL = phi^(L-1)``; ``CrT = Re(C).T``, ``CmiT = -Im(C).T`` (n, p)
    and ``DT = D.T`` (m, p), whose first 4 columns (the shock velocities) go to ``v`` (N, 4)
    on every step and the rest to ``y`` (n_out, p - 4) on every r-th step.
    """
    N = u.shape[0]
    n = pr.size
    S = np.zeros((n_chunks, 4, n))  # chunk start states
    if n_chunks > 1:
        E = np.zeros((n_chunks, 4, n))  # chunk end states from rest
        for c in _nb.prange(n_chunks - 1):
            _rig_chunk(u, BrT, BiT, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, CrT, CmiT, DT, r, E[c],
                       c * L, (c + 1) * L, v, y, False)
        for c in range(1, n_chunks):
            for i in range(n):
                # the previous start state propagated over a chunk without input, plus the
                # previous chunk's own response from rest
                qr = pr[i] * S[c - 1, 0, i] - pi[i] * S[c - 1, 1, i] + S[c - 1, 2, i]
                qi = pr[i] * S[c - 1, 1, i] + pi[i] * S[c - 1, 0, i] + S[c - 1, 3, i]
                S[c, 0, i] = E[c - 1, 0, i] + (pLr[i] * qr - pLi[i] * qi)
                S[c, 1, i] = E[c - 1, 1, i] + (pLr[i] * qi + pLi[i] * qr)
                S[c, 2, i] = E[c - 1, 2, i]
                S[c, 3, i] = E[c - 1, 3, i]
    for c in _nb.prange(n_chunks):
        _rig_chunk(u, BrT, BiT, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, CrT, CmiT, DT, r, S[c],
                   c * L, min(N, (c + 1) * L), v, y, True)


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _segment_line(seg, kv, kf, c, nk, slo, shi):
    """Slope and intercept of segment `seg` of row `c` (0: below the knots, nk: above, else
    between knots seg-1 and seg): f = a + s v on it."""
    if seg <= 0:
        return slo, kf[c, 0] - slo * kv[c, 0]
    if seg >= nk:
        return shi, kf[c, nk - 1] - shi * kv[c, nk - 1]
    s = (kf[c, seg] - kf[c, seg - 1]) / (kv[c, seg] - kv[c, seg - 1])
    return s, kf[c, seg - 1] - s * kv[c, seg - 1]


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _segment_of(v, kv, c, nk, guess):
    """Segment index of v on row `c` (as _pwl), checking the guessed segment and its two
    neighbours first (a binary search otherwise)."""
    if guess <= 0:
        if v <= kv[c, 0]:
            return 0
    elif guess >= nk:
        if v >= kv[c, nk - 1]:
            return nk
    elif kv[c, guess - 1] < v < kv[c, guess]:
        return guess
    # a neighbouring segment, the usual move in one step (strict bounds: a velocity on a
    # knot is left to the search below, which decides it; the same index either way)
    up = guess + 1
    if 1 <= up <= nk - 1 and kv[c, up - 1] < v < kv[c, up]:
        return up
    dn = guess - 1
    if 1 <= dn <= nk - 1 and kv[c, dn - 1] < v < kv[c, dn]:
        return dn
    if v <= kv[c, 0]:
        return 0
    if v >= kv[c, nk - 1]:
        return nk
    lo = 0
    hi = nk - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if kv[c, mid] <= v:
            lo = mid
        else:
            hi = mid
    return hi


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _pwl(v, kv, kf, c, nk, slo, shi):
    """Force, slope and segment index of the piecewise-linear curve of row `c` of the knot
    arrays (linear end extensions). Rows are indexed in place: no array views are made in
    the shock loop's inner steps."""
    seg = _segment_of(v, kv, c, nk, -1)
    s, a = _segment_line(seg, kv, kf, c, nk, slo, shi)
    return a + s * v, s, seg


@_nb.njit(cache=True, error_model="numpy")
def _solver_state(kv, nk):
    """Fresh per-setup state of :func:`_shock_step`: ``v, vfree, c0, fv, sv, seg, av, vnew,
    res, J, Jinv, state`` (velocities at rest, each shock on the segment holding 0)."""
    m = 4
    seg = np.zeros(m, dtype=np.int64)
    for c in range(m):
        seg[c] = _segment_of(0.0, kv, c, nk[c], 0)
    return (np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m), seg, np.zeros(m),
            np.zeros(m), np.zeros(m), np.zeros((m, m)), np.zeros((m, m)),
            np.zeros(1, dtype=np.int64))


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _invert_small(J, Jinv, m):
    """Jinv <- inverse of J (Gauss-Jordan with partial pivoting); J is overwritten.

    Real or complex (numba specializes per dtype); inlined, so the screening's per-band
    solve (:mod:`planner.screen`) costs no call.
    """
    for i in range(m):
        for j in range(m):
            Jinv[i, j] = 1.0 if i == j else 0.0
    for c in range(m):
        p = c
        big = abs(J[c, c])
        for i in range(c + 1, m):
            if abs(J[i, c]) > big:
                big = abs(J[i, c])
                p = i
        if p != c:
            for j in range(m):
                t = J[c, j]
                J[c, j] = J[p, j]
                J[p, j] = t
                t = Jinv[c, j]
                Jinv[c, j] = Jinv[p, j]
                Jinv[p, j] = t
        d = 1.0 / J[c, c]
        for j in range(m):
            J[c, j] *= d
            Jinv[c, j] *= d
        for i in range(m):
            if i != c:
                fct = J[i, c]
                if fct != 0.0:
                    for j in range(m):
                        J[i, j] -= fct * J[c, j]
                        Jinv[i, j] -= fct * Jinv[c, j]


#: Segment-change passes tried with rank-1 updates of the cached inverse (and of the
#: solution) before the full solve (with its damped Newton fallback) takes over.
_FAST_ITERATIONS = 6
#: Rank-1 updates of the cached inverse before it is recomputed from scratch.
_MAX_RANK1_UPDATES = 64


#: Smallest velocity scale of the damped Newton iteration's convergence test [m/s]: a step
#: below 1e-12 of it (1e-15 m/s) ends the iteration. At rest the solution sits on a knot
#: (every curve has one at 0), where half steps of 1e-20 m/s can cycle between segments.
_V_SCALE_MIN_M_S = 1e-3


@_nb.njit(cache=True, error_model="numpy")
def _shock_step(vfree, c0, Deff, cbar, b0, kv, kf, nk, slo, shi, v, fv, sv, seg, av, vnew, res,
                J, Jinv, state):
    """Solve one step of the shock loop in place; return the iteration count (-1: failed).

    Solves ``v = vfree + Deff (c0 + b0 f(v) - cbar v)`` for the 4 shock velocities and
    leaves ``f(v)`` in `fv`. `seg`, `Jinv` and ``state[0]`` (0: `Jinv` invalid; k >= 1:
    valid for `seg`, k - 1 rank-1 updates since it was computed) carry over between steps.
    Shared by the modal and the FIR simulators; the modal time loop first tries the
    common cases inline (every shock on its segment, or segment changes by rank-1 updates
    of the cached inverse) and calls this for the rest. Not inlined: an inlined body with
    many array arguments costs more in reference counting than the solve.
    """
    m = 4
    # Solve v = vfree + Deff (c0 + b0 f(v) - cbar v). f is piecewise linear, so on a
    # fixed set of segments (f = a + s v) this is linear: J v = vfree + Deff (c0 + b0 a)
    # with J = I - Deff diag(b0 s - cbar). Assume the last step's segments, solve with
    # the cached inverse, and accept when v stays on them (exact); otherwise move to
    # the new segments (a Newton step) and repeat. Damped Newton if segments cycle.
    it = 0
    while True:
        if state[0] == 0:
            for c in range(m):
                sl_c, a_c = _segment_line(seg[c], kv, kf, c, nk[c], slo[c], shi[c])
                sv[c] = sl_c
                av[c] = a_c
            for c in range(m):
                for j in range(m):
                    J[c, j] = -Deff[c, j] * (b0[j] * sv[j] - cbar[j])
                J[c, c] += 1.0
            _invert_small(J, Jinv, m)
            state[0] = 1
        for c in range(m):
            acc = vfree[c]
            for j in range(m):
                acc += Deff[c, j] * (c0[j] + b0[j] * av[j])
            res[c] = acc
        same = True
        for c in range(m):
            acc = 0.0
            for j in range(m):
                acc += Jinv[c, j] * res[j]
            vnew[c] = acc
        for c in range(m):
            s2 = _segment_of(vnew[c], kv, c, nk[c], seg[c])
            if s2 != seg[c]:
                same = False
                seg[c] = s2
        it += 1
        if same:
            for c in range(m):
                v[c] = vnew[c]
            break
        state[0] = 0
        if it >= 12:
            # segments cycle at a kink: damped Newton from the last accepted v
            itn = 0
            while True:
                for c in range(m):
                    fv[c], sv[c], seg[c] = _pwl(v[c], kv, kf, c, nk[c], slo[c], shi[c])
                for c in range(m):
                    acc = 0.0
                    for j in range(m):
                        acc += Deff[c, j] * (c0[j] + b0[j] * fv[j] - cbar[j] * v[j])
                        J[c, j] = -Deff[c, j] * (b0[j] * sv[j] - cbar[j])
                    res[c] = vfree[c] + acc - v[c]
                    J[c, c] += 1.0
                # Newton step J d = res; Jinv is scratch here (state[0] is reset below)
                _invert_small(J, Jinv, m)
                for c in range(m):
                    acc = 0.0
                    for j in range(m):
                        acc += Jinv[c, j] * res[j]
                    vnew[c] = acc
                step = 0.0
                scale = _V_SCALE_MIN_M_S
                for c in range(m):
                    v[c] += 0.5 * vnew[c]
                    step = max(step, abs(vnew[c]))
                    scale = max(scale, abs(v[c]))
                itn += 1
                if step <= 1e-12 * scale:
                    break
                if itn >= 200:
                    return -1
            it += itn
            state[0] = 0
            break
    if state[0] >= 1:  # accepted on the cached segments: f is their line there
        for c in range(m):
            fv[c] = av[c] + sv[c] * v[c]
        return it
    for c in range(m):
        fv[c], sl_c, s3 = _pwl(v[c], kv, kf, c, nk[c], slo[c], shi[c])
        if s3 != seg[c]:
            seg[c] = s3
    return it


#: Output samples gathered before one matrix product writes them (the loop's states are
#: buffered so the outputs cost a BLAS product per block, not a scalar sum per sample).
#: 128 with one product of ``[Re x, Im x, dF]``: 0.65 ms less per setup (12,000 samples,
#: 11 modes, 16 outputs) than three products of 64 samples (``Re x``, ``Im x``, ``dF``).
_OUT_BLOCK = 128


@_nb.njit(cache=True, error_model="numpy")
def _loop_one(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar,
              kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy, y_rig, y_out, F_out, v_row):
    """Time loop of one setup on the internal grid.

    The modal states are held as separate real and imaginary arrays (the mode loops
    vectorize). At every r-th step (an output sample) the states and ``dF`` are buffered
    as rows ``[Re x, Im x, dF]``; every :data:`_OUT_BLOCK` samples the outputs
    ``y_rig + Re(Cy x) + Dy dF`` are written by one matrix product with ``Cy`` (2 n + 4,
    p) ``= [Re(Cy).T; -Im(Cy).T; Dy.T]``, and the applied shock forces per sample. With
    ``v_row >= 0`` the shock velocities the loop solved for go to the rows ``v_row ..
    v_row + 3`` of `y_out` (they equal the velocity outputs: ``v = v_free + Deff dF``).
    Returns the largest Newton iteration count (-1: no convergence).
    """
    n = pr.size
    m = 4
    p = Cy.shape[1]
    N = v_rig.shape[0]
    n_out = y_out.shape[1]
    xr = np.zeros(n)
    xi = np.zeros(n)
    bdr = np.zeros(n)  # B dF of the last step
    bdi = np.zeros(n)
    bpr = np.zeros(n)  # B dF of the step before
    bpi = np.zeros(n)
    St = np.zeros((_OUT_BLOCK, 2 * n + m))  # output samples' [Re x, Im x, dF]
    dF_prev = np.zeros(m)
    F_prev = np.zeros(m)
    f_prev = np.zeros(m)
    f_prev2 = np.zeros(m)
    v, vfree, c0, fv, sv, seg, av, vnew, res, J, Jinv, state = _solver_state(kv, nk)
    # every segment's line (slope, intercept) once, for the segment changes below
    lines_s = np.empty((m, kv.shape[1] + 1))
    lines_a = np.empty((m, kv.shape[1] + 1))
    for c in range(m):
        for sg in range(nk[c] + 1):
            lines_s[c, sg], lines_a[c, sg] = _segment_line(sg, kv, kf, c, nk[c], slo[c], shi[c])
    worst = 0
    failed = False
    col = 0
    kk0 = 0
    phase = 0  # k % r
    for k in range(N):
        # predictor: x[k] without the unknown g1 * B dF[k] term, and v_free from it
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        for i in range(n):
            tr = (pr[i] * xr[i] - pi[i] * xi[i] + g0r[i] * bdr[i] - g0i[i] * bdi[i]
                  + gmr[i] * bpr[i] - gmi[i] * bpi[i])
            ti = (pr[i] * xi[i] + pi[i] * xr[i] + g0r[i] * bdi[i] + g0i[i] * bdr[i]
                  + gmr[i] * bpi[i] + gmi[i] * bpr[i])
            xr[i] = tr
            xi[i] = ti
        # the velocities in a loop of their own: the update above has no loop-carried
        # chain and vectorizes; fused with these sums (strict FP order) it ran scalar.
        # Same sums in the same order as before, so the same rounding.
        for i in range(n):
            tr = xr[i]
            ti = xi[i]
            a0 += Cvr[0, i] * tr - Cvi[0, i] * ti
            a1 += Cvr[1, i] * tr - Cvi[1, i] * ti
            a2 += Cvr[2, i] * tr - Cvi[2, i] * ti
            a3 += Cvr[3, i] * tr - Cvi[3, i] * ti
        vfree[0] = v_rig[k, 0] + a0
        vfree[1] = v_rig[k, 1] + a1
        vfree[2] = v_rig[k, 2] + a2
        vfree[3] = v_rig[k, 3] + a3
        for c in range(m):
            c0[c] = alpha[c] * F_prev[c] + b1[c] * f_prev[c] + bm[c] * f_prev2[c]
        # the common cases inline: every shock on its segment, or segment changes (a zero
        # crossing of a digressive shock, a knee) by Sherman-Morrison updates of the cached
        # inverse of J = I - Deff diag(b0 s - cbar); the rest in _shock_step. One solve per
        # step: a segment change of shock c is a rank-1 change of J and of the right-hand
        # side along d = Deff[:, c], so the new solution is the last one plus
        # J'^-1 d (= Jinv d / den) times the force change the new line makes at v_c.
        it = 0
        if state[0] >= 1:
            for c in range(m):
                acc = vfree[c]
                for j in range(m):
                    acc += Deff[c, j] * (c0[j] + b0[j] * av[j])
                res[c] = acc
            for c in range(m):
                acc = 0.0
                for j in range(m):
                    acc += Jinv[c, j] * res[j]
                vnew[c] = acc
            for it_ in range(1, _FAST_ITERATIONS + 1):
                same = True
                for c in range(m):
                    s2 = _segment_of(vnew[c], kv, c, nk[c], seg[c])
                    if s2 == seg[c]:
                        continue
                    same = False
                    sl2 = lines_s[c, s2]
                    a2 = lines_a[c, s2]
                    dsl = sl2 - sv[c]
                    # the force change at vnew[c] that the new line makes, through shock c
                    dfc = b0[c] * ((a2 - av[c]) + dsl * vnew[c])
                    for r_ in range(m):  # u = Jinv Deff[:, c]
                        acc = 0.0
                        for j in range(m):
                            acc += Jinv[r_, j] * Deff[j, c]
                        res[r_] = acc
                    dsc = b0[c] * dsl
                    den = 1.0 - dsc * res[c]
                    if abs(den) < 1e-8:
                        seg[c] = s2
                        av[c] = a2
                        state[0] = 0
                        break
                    # the solution on the new segments (Sherman-Morrison: J'^-1 d = u / den)
                    g = dfc / den
                    for r_ in range(m):
                        vnew[r_] += res[r_] * g
                    seg[c] = s2
                    av[c] = a2
                    if dsl != 0.0:
                        q = dsc / den
                        for j in range(m):
                            J[0, j] = Jinv[c, j] * q
                        for r_ in range(m):
                            for j in range(m):
                                Jinv[r_, j] += res[r_] * J[0, j]
                        sv[c] = sl2
                        state[0] += 1
                if same:
                    for c in range(m):
                        v[c] = vnew[c]
                        fv[c] = av[c] + sv[c] * vnew[c]
                    it = it_
                    if state[0] > _MAX_RANK1_UPDATES:
                        state[0] = 0
                    break
                if state[0] == 0 or state[0] > _MAX_RANK1_UPDATES:
                    state[0] = 0
                    break
        if it == 0:
            it = _shock_step(vfree, c0, Deff, cbar, b0, kv, kf, nk, slo, shi, v, fv, sv, seg, av,
                             vnew, res, J, Jinv, state)
        if it < 0:
            failed = True
            it = 80
        if it > worst:
            worst = it
        for c in range(m):
            F = c0[c] + b0[c] * fv[c]
            F_prev[c] = F
            f_prev2[c] = f_prev[c]
            f_prev[c] = fv[c]
            dF_prev[c] = F - cbar[c] * v[c]
        # corrector: complete x[k] with g1 * B dF[k]
        d0 = dF_prev[0]
        d1 = dF_prev[1]
        d2 = dF_prev[2]
        d3 = dF_prev[3]
        for i in range(n):
            ur = Br[0, i] * d0 + Br[1, i] * d1 + Br[2, i] * d2 + Br[3, i] * d3
            ui = Bi[0, i] * d0 + Bi[1, i] * d1 + Bi[2, i] * d2 + Bi[3, i] * d3
            bpr[i] = bdr[i]
            bpi[i] = bdi[i]
            bdr[i] = ur
            bdi[i] = ui
            xr[i] += g1r[i] * ur - g1i[i] * ui
            xi[i] += g1r[i] * ui + g1i[i] * ur
        # an output sample every r-th step (a counter: no integer division per step)
        if phase == 0:
            kk = k // r
            for c in range(m):
                F_out[kk, c] = F_prev[c]
                St[col, 2 * n + c] = dF_prev[c]
            if v_row >= 0:
                for c in range(m):
                    y_out[v_row + c, kk] = v[c]
            for i in range(n):
                St[col, i] = xr[i]
                St[col, n + i] = xi[i]
            col += 1
            if col == _OUT_BLOCK or kk == n_out - 1:
                Y = np.dot(St[:col], Cy)  # (col, p)
                for j in range(col):
                    for o in range(p):
                        y_out[o, kk0 + j] = y_rig[kk0 + j, o] + Y[j, o]
                kk0 += col
                col = 0
        phase += 1
        if phase == r:
            phase = 0
    return -1 if failed else worst


@_nb.njit(cache=True, error_model="numpy", parallel=True)
def _loop_batch(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar,
                kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy, y_rig, y_out, F_out, iters):
    for s in _nb.prange(kv.shape[0]):
        iters[s] = _loop_one(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff,
                             v_rig, cbar, kv[s], kf[s], nk[s], slo[s], shi[s], alpha[s], b0[s],
                             b1[s], bm[s], r, Cy, y_rig, y_out[s], F_out[s], -1)
    return


@_nb.njit(cache=True, error_model="numpy", nogil=True)
def _loop_serial(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar,
                 kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy, y_rig, y_out, F_out, iters):
    """:func:`_loop_batch` one setup after the other (the same `_loop_one`, the same numbers).

    A single setup gains nothing from the parallel loop, and this kernel compiles in about
    60 % of its time: the virtual rig (one setup per run) uses it, so a fresh machine's first
    ``rig simulate`` or demo waits for the smaller compilation only (the demo compiles the
    parallel kernel meanwhile in a worker). It releases the GIL (as :func:`_rig_kernel`
    does): the virtual rig runs its runs on threads.
    """
    for s in range(kv.shape[0]):
        iters[s] = _loop_one(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff,
                             v_rig, cbar, kv[s], kf[s], nk[s], slo[s], shi[s], alpha[s], b0[s],
                             b1[s], bm[s], r, Cy, y_rig, y_out[s], F_out[s], -1)
    return


@_nb.njit(cache=True, error_model="numpy", nogil=True)
def _loop_metrics_worker(w, n_workers, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi,
                         Deff, v_rig, cbar, kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy,
                         y_rig, n_out, ia, sos, zi, padlen, out, iters):
    """Worker `w` of `n_workers` of :func:`simulate_batch_metrics`: the setups ``w, w +
    n_workers, ...`` (interleaved, so that each worker gets a mix of cheap and costly
    setups), each simulated by :func:`_loop_one` and its metrics computed right after
    (:func:`ident.sim.metrics._setup_metric_rms`, per band: ``sos`` (n_bands, n_sections, 6),
    ``zi`` (n_bands, n_sections, 2)) into ``out`` (n_setups, n_bands, n_metrics).

    The outputs ``Cy`` (2 n + 4, p) are the metrics' signals (a ride height pair as one
    row of averaged coefficients); the shock velocities come from the loop's own solve
    (rows p .. p + 3 of the setup's buffer), not from the product. The worker keeps one
    setup's outputs and the metric's scratch (about 2 MB for 12,000 samples): nothing of
    size (setups x samples) is written. It releases the GIL: the workers are threads.
    """
    p = Cy.shape[1]
    L = _METRIC_LANES
    ns = sos.shape[1]
    S = kv.shape[0]
    # the outputs, then the 4 shock velocities. Channel-major, as simulate_batch's: the
    # loop kernel is then the one-setup loop's compiled code (sample-major rows were about
    # 4 % faster but compile the loop once more, 4 s on a fresh machine's first demo)
    y = np.empty((p + 4, n_out))
    F = np.empty((n_out, 4))
    buf = np.empty((n_out + 2 * padlen, L))
    z0 = np.empty((ns, L))
    z1 = np.empty((ns, L))
    stack = np.empty((_METRIC_PW_LEVELS, 10, L))
    sums = np.empty(L)
    for s in range(w, S, n_workers):
        iters[s] = _loop_one(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff,
                             v_rig, cbar, kv[s], kf[s], nk[s], slo[s], shi[s], alpha[s], b0[s],
                             b1[s], bm[s], r, Cy, y_rig, y, F, p)
        for b in range(sos.shape[0]):
            _setup_metric_rms(y, ia, sos[b], zi[b], padlen, out[s, b], buf, z0, z1, stack, sums)
    return


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


def _setup_models(setup, where):
    """Return the 4 shock models (LF, RF, LR, RR) of a setup."""
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


def _pack_setups(setups, h, *, hold="quadratic"):
    """Pack setups into padded arrays for the compiled loop.

    The lag coefficients are those of :func:`lag_hold_coefficients` (``alpha, b0,
    b1, bm``), or with ``hold="linear"`` of :func:`lag_coefficients` (``alpha, b0, b1``).
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
    plant : LoopPlant
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
        _loop_serial(*loop.args, loop.y_rig, y, F, iters)
    else:
        _run_parallel(_loop_batch, *loop.args, loop.y_rig, y, F, iters)
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
    from ident.sim.metrics import _METRIC_CHANNELS, _metric_plan, compute_metrics

    loop = _loop_setup(plant, drive, setups, oversample, outputs, rig, "simulate_batch_metrics")
    plan = _metric_plan(loop.names, loop.rig.fs_hz, band_hz=band_hz, order=order,
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
        chans = _METRIC_CHANNELS[name]
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
        _loop_metrics_worker(0, 1, *args)
    else:
        # threads, not a parallel kernel: the worker releases the GIL, compiles in a third of
        # the time a prange kernel of it takes, and starts no OpenMP pool (a process forked
        # after one cannot use it)
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(n_workers) as pool:
            for job in [pool.submit(_loop_metrics_worker, w, n_workers, *args)
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
    r = _check_oversample(oversample)
    models = [_setup_models(s, f"setup {i}") for i, s in enumerate(setups)]
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
    packed = _pack_setups(models, h)

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
