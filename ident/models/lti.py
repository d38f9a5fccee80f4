"""Linear time-invariant systems in modal form, their exact discretization, and reduction.

The types every linear vehicle model is held in, whether physical
(:mod:`ident.models.vehicle`) or identified (:mod:`ident.identify.model`):

- :class:`ModalSystem`: ``x' = diag(lam) x + B u``, ``y = Re(C x) + D u``, one complex
  state per conjugate pole pair; :func:`modal_form` makes one from real state-space
  matrices;
- :class:`LoopPlant`: a vehicle model ready for the closed loop with shocks (Eq. 20 of the
  seed paper), two modal systems (rig inputs, shock-force deviations) written around a
  baseline linear damping. The simulator (:mod:`ident.sim.closedloop`) steps it;
- the exact discretization of modes for the holds the simulator uses
  (:func:`hold_coefficients`, the quadratic hold; :func:`foh_coefficients`, the
  first-order hold) and of the shocks' first-order lag (:func:`lag_hold_coefficients`,
  :func:`lag_coefficients`);
- :func:`balanced_reduce`: balanced truncation of a stable modal system to a relative
  error bound, with the gramians in closed form from the modal form.

Notes
-----
A conjugate pole pair is held once (the pole with positive imaginary part) and its output
coefficients carry the factor 2, so ``Re(C x)`` restores the pair exactly; a real pole is a
state with real coefficients.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lapack

from ident.data.channels import RIG_INPUTS, SHOCK_VELOCITIES, WHEELLOADER_INPUTS
from ident.errors import IdentificationError

__all__ = [
    "ModalSystem",
    "LoopPlant",
    "modal_form",
    "foh_coefficients",
    "hold_coefficients",
    "lag_hold_coefficients",
    "lag_coefficients",
    "balanced_reduce",
    "join_inputs",
    "GRAM_FACTOR_RTOL",
    "UNSTABLE_REL_TOL",
    "unstable_growth_rate",
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
        4-post rig has the 4 wheelloaders only, and
        :func:`ident.sim.closedloop.rig_response` refuses a drive with nonzero
        content on the others (:func:`ident.data.drive.check_drive_inputs`).
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


def _mode_gram(lam, X):
    """``int_0^inf g(t) g(t)^T dt`` of the real coordinates of modes ``z_i(t) = X_i e^(lam_i t)``.

    Parameters
    ----------
    lam : ndarray of complex, shape (n,)
        Stable poles [rad/s] (real modes with ``Im lam == 0`` and real rows of `X`).
    X : ndarray of complex, shape (n, k)
        One row per mode.

    Returns
    -------
    ndarray, shape (n, 2, n, 2)
        ``G[i, a, j, b]`` pairs coordinate ``a`` of mode ``i`` with coordinate ``b`` of mode
        ``j`` (0: ``Re z``, 1: ``Im z``), summed over the columns of `X`.

    Notes
    -----
    With ``M1 = int z z^H = -(X X^H) / (lam_i + conj lam_j)`` and
    ``M2 = int z z^T = -(X X^T) / (lam_i + lam_j)`` (the ``int`` over ``t`` and summed
    over the columns of `X`): ``int Re z Re z^T = Re(M1 + M2) / 2``,
    ``int Im z Im z^T = Re(M1 - M2) / 2``, ``int Re z Im z^T = Im(M2 - M1) / 2`` and
    ``int Im z Re z^T = Im(M1 + M2) / 2``. A real mode (real pole and row) has
    ``Im z = 0``, and its ``Re`` entries come out right from the same formulas.
    """
    m1 = -(X @ np.conj(X).T) / (lam[:, None] + np.conj(lam)[None, :])
    m2 = -(X @ X.T) / (lam[:, None] + lam[None, :])
    n = lam.size
    G = np.empty((n, 2, n, 2))
    G[:, 0, :, 0] = (m1.real + m2.real) / 2
    G[:, 1, :, 1] = (m1.real - m2.real) / 2
    G[:, 0, :, 1] = (m2.imag - m1.imag) / 2
    G[:, 1, :, 0] = (m2.imag + m1.imag) / 2
    return G


def _modal_gramians(modal, Bs, Cs):
    """Controllability and observability gramians of a stable modal system, real coordinates.

    Closed form from the modal form, O(n^2) instead of the O(n^3) of a Lyapunov solver:
    in the coordinates of :meth:`ModalSystem.to_real` (``[Re x, Im x]`` per complex mode,
    ``x`` per real mode) ``P = int x x^T`` for impulses ``x_i = B_i e^(lam_i t)``, and ``Q``
    the same for the output trajectories of unit initial states: ``Re(c_i e^(lam_i t))``
    from ``Re x_i`` and ``-Im(c_i e^(lam_i t))`` from ``Im x_i`` (:func:`_mode_gram`).

    Parameters
    ----------
    modal : ModalSystem
        Stable; its poles.
    Bs : ndarray of complex, shape (n, m)
    Cs : ndarray of complex, shape (p, n)

    Returns
    -------
    P, Q : ndarray, shape (n_real, n_real)
        ``n_real`` counts a complex mode twice.
    """
    lam = np.asarray(modal.lam, dtype=complex)
    real = lam.imag == 0
    # real modes: real coefficients, as to_real() takes them
    Bs = np.where(real[:, None], np.real(Bs), Bs)
    Cs = np.where(real[None, :], np.real(Cs), Cs)
    keep = np.stack([np.ones(lam.size, bool), ~real], axis=1).ravel()  # [Re, Im] per mode
    n2 = 2 * lam.size
    P = _mode_gram(lam, Bs).reshape(n2, n2)[np.ix_(keep, keep)]
    G = _mode_gram(lam, Cs.T)
    G[:, 0, :, 1] *= -1  # the Im coordinate reads -Im(c x)
    G[:, 1, :, 0] *= -1
    Q = G.reshape(n2, n2)[np.ix_(keep, keep)]
    return P, Q


#: Pivoted-Cholesky stopping tolerance of the gramian factors (:func:`_gram_factor`),
#: relative to the largest diagonal entry: the rounding level of the gramians themselves.
GRAM_FACTOR_RTOL = float(np.finfo(float).eps)


def _gram_factor(M):
    """A low-rank factor ``L`` with ``M ~= L L^T`` of a symmetric positive semidefinite gramian.

    Pivoted Cholesky (LAPACK ``dpstrf``), stopped where the largest remaining diagonal
    entry falls below :data:`GRAM_FACTOR_RTOL` times the largest: the remainder is
    positive semidefinite, so its norm is at most its trace, at the gramians' rounding
    level. The gramians of an identified model have low numerical rank (the paper
    session's rig part: about 350 and 590 of 1534), so this costs ``O(n^2 r)`` against
    the ``O(n^3)`` of an eigendecomposition (a tenth of the time), and the Hankel
    singular values then come from an ``r_q x r_p`` product.

    Parameters
    ----------
    M : ndarray, shape (n, n)
        Only the lower triangle is read.

    Returns
    -------
    ndarray, shape (n, r)
        ``r = 0`` for a zero matrix.
    """
    n = M.shape[0]
    top = float(np.max(np.diag(M), initial=0.0))
    if not top > 0:
        return np.zeros((n, 0))
    c, piv, rank, info = lapack.dpstrf(M, lower=1, tol=GRAM_FACTOR_RTOL * top)
    if info < 0:
        raise ValueError(f"dpstrf: argument {-info} is invalid")
    L = np.zeros((n, rank))
    L[piv - 1] = np.tril(c[:, :rank])
    return L


def balanced_reduce(modal, *, rtol=1e-4):
    """Balanced truncation of a stable modal system to a relative error bound.

    Outputs and inputs are scaled by their peak gains first, so the bound
    ``2 * sum(truncated Hankel singular values) <= rtol * largest`` is relative
    per channel. The gramians come in closed form from the modal form
    (:func:`_modal_gramians`), their square-root factors from a pivoted Cholesky
    stopped at their rounding level (:func:`_gram_factor`: low rank, so the
    singular value decomposition is of an ``r_q x r_p`` matrix). Returns a
    :class:`ModalSystem`.
    """
    if np.any(modal.lam.real >= 0):
        raise IdentificationError("balanced_reduce needs a stable system; reflect unstable poles first")
    f = np.geomspace(0.3, 30, 60)
    H = modal.frequency_response(f)
    so = np.maximum(np.abs(H).max(axis=(1, 2)), 1e-300)  # per output
    si = np.maximum(np.abs(H / so[:, None, None]).max(axis=(0, 2)), 1e-300)  # per input
    Bsc = modal.B * si[None, :]
    Csc = modal.C / so[:, None]
    P, Q = _modal_gramians(modal, Bsc, Csc)
    scaled = type(modal)(modal.lam, Bsc, Csc, modal.D)
    A, Bs, Cs, _ = scaled.to_real()

    Lp, Lq = _gram_factor(P), _gram_factor(Q)
    if Lp.shape[1] == 0 or Lq.shape[1] == 0:  # nothing reaches the outputs
        return ModalSystem(np.zeros(0, complex), np.zeros((0, modal.B.shape[1]), complex),
                           np.zeros((modal.C.shape[0], 0), complex), modal.D)
    U, sv, Vt = np.linalg.svd(Lq.T @ Lp, full_matrices=False)
    tail = np.concatenate([2 * np.cumsum(sv[::-1])[::-1], [0.0]])  # tail[k] = 2 sum(sv[k:])
    r = int(np.argmax(tail <= rtol * sv[0]))
    r = max(1, min(r, sv.size))
    s = 1.0 / np.sqrt(sv[:r])
    Tm = (Lp @ Vt[:r].T) * s[None, :]
    Tim = (U[:, :r].T @ Lq.T) * s[:, None]
    Ar, Br, Cr = Tim @ A @ Tm, (Tim @ Bs) / si[None, :], so[:, None] * (Cs @ Tm)
    red = modal_form(Ar, Br, Cr, modal.D)
    log.info("balanced truncation: %d -> %d states (bound %.2g)", A.shape[0], r, tail[r] / sv[0])
    return red



def join_inputs(a, b, *, rtol=1e-9):
    """One modal system with the inputs of `a` then those of `b` (the same outputs).

    A mode of `b` with a pole and an output column equal to a mode of `a` (to `rtol`) is
    that mode (its input rows are joined): the two parts of a physical model's
    :class:`LoopPlant` come from one modal form and share their modes. Other modes of `b`
    are appended (an identified model's parts fitted separately: the joined system then
    has the modes of both).

    Parameters
    ----------
    a, b : ModalSystem
        With the same number of outputs.
    rtol : float
        Relative tolerance of the pole and output-column match.

    Returns
    -------
    ModalSystem
        Modes of `a` first, in their order (then the appended modes of `b`); inputs
        ``[a's, b's]``; ``D = [a.D, b.D]``.
    """
    if a.C.shape[0] != b.C.shape[0]:
        raise ValueError(f"join_inputs: the systems have {a.C.shape[0]} and {b.C.shape[0]} "
                         "outputs; give systems of the same outputs")
    na, ma, mb = a.lam.size, a.B.shape[1], b.B.shape[1]
    used = np.zeros(na, dtype=bool)
    where = np.full(b.lam.size, -1)
    for j, lam in enumerate(b.lam):
        cj = b.C[:, j]
        scale = max(np.abs(cj).max(initial=0.0), 1e-300)
        for i in np.flatnonzero(~used & (np.abs(a.lam - lam) <= rtol * max(abs(lam), 1e-300))):
            if np.abs(a.C[:, i] - cj).max(initial=0.0) <= rtol * scale:
                where[j] = i
                used[i] = True
                break
    extra = np.flatnonzero(where < 0)
    where[extra] = na + np.arange(extra.size)
    n = na + extra.size
    lam = np.concatenate([a.lam, b.lam[extra]])
    B = np.zeros((n, ma + mb), dtype=complex)
    B[:na, :ma] = a.B
    B[where, ma:] = b.B
    C = np.concatenate([a.C, b.C[:, extra]], axis=1)
    return ModalSystem(lam, B, C, np.concatenate([a.D, b.D], axis=1))


#: A pole counts as unstable when its real part exceeds this share of its size (round-off
#: of an identified pole on the imaginary axis is not a growing mode).
UNSTABLE_REL_TOL = 1e-9
def unstable_growth_rate(plant):
    """The largest growth rate of the plant's shock loop with the baseline damping in [1/s].

    Parameters
    ----------
    plant : ident.models.lti.LoopPlant
        A plant (an object without a modal shock part gives 0).

    Returns
    -------
    float
        ``max Re(lam)`` of the shock part's continuous poles where positive (beyond round-off
        relative to the pole's size), else 0.0: a positive value means the model diverges
        whatever the shocks' step.
    """
    lam = getattr(getattr(plant, "shock", None), "lam", None)
    if lam is None or np.size(lam) == 0:
        return 0.0
    lam = np.asarray(lam, dtype=complex)
    grow = lam.real - UNSTABLE_REL_TOL * np.abs(lam)
    return float(max(np.max(lam.real[grow > 0.0], initial=0.0), 0.0))
