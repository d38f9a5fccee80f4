"""Rational transfer-function fits to frequency responses (seed paper, Eqs. 29-30).

Two fitters share one numerical core:

* :func:`fit_tf` fits one input/output pair with ``H(s) = B(s) / A(s)`` as
  MATLAB's ``invfreqs`` in its iterative mode: a linearized (Levi)
  equation-error start, a few Sanathanan-Koerner (SK) iterations, then a
  damped Gauss-Newton (or Levenberg-Marquardt) search on the output error
  ``J = sum_k w_k |h_k - B(s_k)/A(s_k)|^2`` (Eq. 30). :func:`select_order`
  picks the denominator order.
* :func:`fit_common_poles` fits a whole MIMO response with one common set of
  poles by relaxed vector fitting (Gustavsen and Semlyen 1999, Gustavsen 2006).

Results are pole-residue forms ``H(s) = sum_k r_k / (s - p_k) + d`` (the
polynomial coefficients of :class:`TfFit` are a convenience only), and
:func:`tf_fits_to_modal` / :meth:`VfFit.to_modal` turn them into the
:class:`ident.models.lti.ModalSystem` the simulator runs.

Notes
-----
Conventions. ``s = j 2 pi f`` with ``f`` in Hz; poles are in rad/s; a
model's units are those of the data (SI output per SI input). Polynomials
are highest power first. Complex poles come in conjugate pairs, each pole
listed with its residue; the pair with ``Im p > 0`` comes first.

Conditioning. Nothing is expanded in powers of the unscaled ``s``: the
fitters work in the normalized variable ``s / w0`` with ``w0 = 2 pi f0`` and
``f0`` the geometric mean of the lowest and highest weighted frequency, on
data divided by its weighted RMS. The denominator is held as a product of
real second-order sections ``s^2 + a1 s + a0`` (and one first-order section
``s + a`` for an odd order); the numerator as real coefficients of the
section partial fractions ``1/Q``, ``s/Q`` (plus a constant for a direct
term). That basis stays well conditioned at any order, including sections
with two real or nearly repeated roots. Only the Levi start uses powers of
``s / w0``, with column scaling. Least squares are solved on the real
stacked system (real and imaginary parts) by an SVD with column scaling.

Stages of :func:`fit_tf`.

1. Levi: ``min sum w |h A - B|^2`` over the polynomial coefficients.
2. Sanathanan-Koerner: ``min sum w |h A_k - B_k|^2 / |A_{k-1}|^2``, solved in
   the barycentric form ``A_k / A_{k-1} = 1 + sum c_j phi_j(s)`` with
   ``phi_j`` the section basis of ``A_{k-1}``; the new poles are the zeros
   of that function (eigenvalues of a real state-space realization). This is
   the non-relaxed pole relocation of vector fitting. The SK iterations are
   run from the Levi poles and, for robustness, also from vector-fitting
   starting poles (log-spaced, lightly damped); the iterate with the lowest
   output error starts stage 3.
3. Output error: Gauss-Newton on the section coefficients with the numerator
   eliminated by linear least squares (variable projection, Kaufman's
   Jacobian; same minimizer as Gauss-Newton on all coefficients, better
   conditioned). Steps are halved until ``J`` decreases (``invfreqs``'s damped
   Gauss-Newton); after 10 halvings without a decrease (a poorly determined
   direction of an over-parametrized model) the iteration takes a
   Levenberg-Marquardt step instead. ``method="levenberg-marquardt"`` uses
   Marquardt damping throughout.

With ``stable=True`` unstable poles are reflected, ``p -> -conj(p)`` (same
magnitude response on the imaginary axis), after every stage and at every
trial step; the numerator is always refitted for the denominator it goes
with. Poles are kept within 1000 times the highest fitted frequency (a pole
far beyond the band acts there as a constant; Gauss-Newton would otherwise
push it to infinity to mimic a missing direct term). Poles closer than
1e-5 (relative) are moved apart to that separation, symmetrically, before
the partial fractions are formed (a note says so); for a double pole this
changes the model only in second order.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field

import numpy as np

try:  # numpy's own LAPACK ufuncs, behind np.linalg.lstsq and np.linalg.eigvals
    from numpy.linalg import _umath_linalg as _lapack
except ImportError:  # pragma: no cover - another numpy layout: the public functions
    _lapack = None

from ident.errors import FitWarning, IdentificationError
from ident.models.lti import ModalSystem

__all__ = [
    "TfFit",
    "VfFit",
    "fit_tf",
    "select_order",
    "fit_common_poles",
    "tf_fits_to_modal",
]

log = logging.getLogger(__name__)

#: |Im p| / |p| below which a computed pole is taken as real.
_REAL_RTOL = 1e-12
#: Poles closer than this (relative) are moved apart to this separation for the
#: partial-fraction form (the numerator is refitted after it); see _split_repeated.
_REPEAT_RTOL = 1e-5
#: Singular values below this fraction of the largest are dropped in least squares.
_RCOND = 1e-13
#: A fit error below this is at the rounding floor: the fit has converged.
_ERROR_FLOOR = 1e-13
#: Largest number of step halvings per Gauss-Newton iteration (then Levenberg-Marquardt).
_MAX_HALVINGS = 10
#: Largest Levenberg-Marquardt damping (relative to the scaled normal matrix).
_MAX_DAMPING = 1e10
#: Gauss-Newton has converged after this many iterations in a row that each lower J by
#: less than _STALL_FACTOR * tol (relative): the fit error has settled.
_STALL_ITER = 3
_STALL_FACTOR = 100.0
#: Poles are kept within this multiple of the highest fitted frequency (a pole far beyond
#: the band only adds a constant there; letting it run off to infinity breaks the arithmetic).
_POLE_BOUND = 1e3
#: Damping of the vector-fitting starting poles: p = -w/100 +- j w (Gustavsen).
_VF_START_DAMPING = 0.01
#: Vector fitting has settled when a relocation changes the fit error by less than this (relative).
_VF_SETTLED = 1e-6
#: Vector fitting stops after this many relocations without a better fit (the best is kept).
_VF_PATIENCE = 5

_METHODS = ("gauss-newton", "levenberg-marquardt", "sk")


# ----------------------------------------------------------------------------------------------
# results
# ----------------------------------------------------------------------------------------------


def _pole_residue_response(f_hz, poles, residues, direct):
    """``sum_k r_k / (s - p_k) + d`` at ``s = j 2 pi f``; residues (n, ...) broadcast."""
    s = 2j * np.pi * np.atleast_1d(np.asarray(f_hz, dtype=float))
    terms = 1.0 / (s[None, :] - poles[:, None])  # (n, n_f)
    return np.tensordot(residues, terms, axes=([0], [0])) + np.asarray(direct)[..., None]


@dataclass(frozen=True, eq=False)
class TfFit:
    """A rational transfer function fitted to one frequency response.

    ``H(s) = sum_k residues[k] / (s - poles[k]) + direct = num(s) / den(s)``
    with ``s = j 2 pi f``.

    Attributes
    ----------
    num : ndarray, shape (n_num + 1,)
        Numerator coefficients in ``s`` [rad/s], highest power first. A
        convenience: for high orders the coefficients span many decades;
        evaluate with :meth:`evaluate` (pole-residue form) instead.
    den : ndarray, shape (n_den + 1,)
        Monic denominator coefficients in ``s``, highest power first.
    poles : ndarray of complex, shape (n_den,)
        Poles [rad/s]; conjugate pairs adjacent (``Im > 0`` first), sorted by
        magnitude; distinct (see ``notes``).
    residues : ndarray of complex, shape (n_den,)
        Residue of each pole [data units * rad/s]; conjugate for conjugate poles.
    direct : float
        Direct term ``H(inf)`` [data units]; 0 when ``n_num < n_den``.
    fit_error : float
        Relative weighted error ``sqrt(sum w |h - fit|^2 / sum w |h|^2)``.
    iterations : int
        Output-error (Gauss-Newton / Levenberg-Marquardt) iterations done.
    converged : bool
        Whether the output-error search met its tolerance (always True for
        ``method="sk"``).
    history : tuple of float
        Fit error after every iterate: the start, each SK iteration, each
        output-error iteration.
    stages : tuple of str
        Stage of each ``history`` entry (``"levi"``, ``"log-spaced"``,
        ``"sk"``, ``"gn"``, ``"lm"``).
    settings : dict
        The arguments and the scalings used (``f0_hz``, ``h_scale``, ``start``).
    notes : tuple of str
        Modifications made to the model (reflected or split poles).
    """

    num: np.ndarray
    den: np.ndarray
    poles: np.ndarray
    residues: np.ndarray
    direct: float
    fit_error: float
    iterations: int
    converged: bool
    history: tuple
    stages: tuple
    settings: dict = field(default_factory=dict)
    notes: tuple = ()

    @property
    def n_den(self):
        """Denominator order (number of poles)."""
        return int(self.poles.size)

    def evaluate(self, f_hz):
        """Frequency response of the fit.

        Parameters
        ----------
        f_hz : array_like, shape (n_f,)
            Frequencies [Hz].

        Returns
        -------
        ndarray of complex, shape (n_f,)
        """
        return _pole_residue_response(f_hz, self.poles, self.residues, self.direct)

    def to_modal(self):
        """The fit as a one-input, one-output :class:`ident.models.lti.ModalSystem`."""
        return tf_fits_to_modal({(0, 0): self}, 1, 1)


@dataclass(frozen=True, eq=False)
class VfFit:
    """A common-pole rational fit of a MIMO frequency response.

    ``H[o, i](s) = sum_k residues[k, o, i] / (s - poles[k]) + direct[o, i]``
    with ``s = j 2 pi f``.

    Attributes
    ----------
    poles : ndarray of complex, shape (n,)
        Common poles [rad/s]; conjugate pairs adjacent (``Im > 0`` first).
    residues : ndarray of complex, shape (n, n_out, n_in)
        Residues [data units * rad/s].
    direct : ndarray of float, shape (n_out, n_in)
        Direct terms [data units] (zero when fitted with ``direct=False``).
    fit_error : ndarray of float, shape (n_out, n_in)
        Relative weighted error of each pair,
        ``sqrt(sum w |h - fit|^2 / sum w |h|^2)`` (0 for an all-zero pair).
    fit_error_total : float
        RMS over the pairs of ``fit_error`` (every pair counts equally).
    iterations : int
        Pole relocations done.
    converged : bool
        Whether the pole relocation settled before ``n_iter``.
    history : tuple of float
        ``fit_error_total`` after the start and after every relocation.
    settings : dict
    notes : tuple of str
    """

    poles: np.ndarray
    residues: np.ndarray
    direct: np.ndarray
    fit_error: np.ndarray
    fit_error_total: float
    iterations: int
    converged: bool
    history: tuple
    settings: dict = field(default_factory=dict)
    notes: tuple = ()

    def evaluate(self, f_hz):
        """Frequency response of the fit, shape (n_out, n_in, n_f).

        Parameters
        ----------
        f_hz : array_like, shape (n_f,)
            Frequencies [Hz].
        """
        return _pole_residue_response(f_hz, self.poles, self.residues, self.direct)

    def to_modal(self):
        """The fit as an :class:`ident.models.lti.ModalSystem`.

        Returns
        -------
        ModalSystem
            ``n_modes * n_in`` states, ``n_modes`` = number of pairs plus
            number of real poles: each input drives its own copy of the
            modes (``B`` one-hot per input column), read by all outputs with
            ``C = 2 * residue`` (pairs) or ``residue`` (real poles). Not
            minimal when residue matrices have low rank; exact.
        """
        lam, res = _modal_states(self.poles, self.residues)  # (n_s,), (n_s, p, m)
        n_s = lam.size
        p, m = self.direct.shape
        B = np.zeros((n_s * m, m), dtype=complex)
        C = np.zeros((p, n_s * m), dtype=complex)
        for i in range(m):
            sl = slice(i * n_s, (i + 1) * n_s)
            B[sl, i] = 1.0
            C[:, sl] = res[:, :, i].T
        return ModalSystem(lam=np.tile(lam, m), B=B, C=C, D=np.array(self.direct, dtype=float))


def _modal_states(poles, residues):
    """One state per conjugate pair (Im > 0, C = 2 r) or real pole (C = Re r)."""
    poles = np.asarray(poles, dtype=complex)
    residues = np.asarray(residues, dtype=complex)
    tol = _REAL_RTOL * np.maximum(np.abs(poles), 1e-300)
    real = np.abs(poles.imag) <= tol
    keep = real | (poles.imag > 0)
    lam = np.where(real, poles.real + 0j, poles)[keep]
    shape = (-1,) + (1,) * (residues.ndim - 1)
    c = np.where(real.reshape(shape), residues.real + 0j, 2.0 * residues)[keep]
    return lam, c


def tf_fits_to_modal(fits, n_out, n_in):
    """Assemble per-pair transfer-function fits into one modal system.

    Parameters
    ----------
    fits : dict
        ``{(output index, input index): TfFit}``; missing pairs are zero.
    n_out, n_in : int
        Number of outputs and inputs of the system.

    Returns
    -------
    ident.models.lti.ModalSystem
        The union of every pair's poles: one state per conjugate pair
        (``Im > 0``) or real pole of each pair, driven by the pair's input
        (``B = 1``) and read by the pair's output (``C = 2 * residue`` for a
        pair, the real residue for a real pole); ``D[o, i]`` the pair's direct
        term. ``frequency_response`` equals the fits' ``evaluate``.

    Raises
    ------
    TypeError
        If a value is not a :class:`TfFit`.
    ValueError
        If a key is not a valid ``(output, input)`` index pair.
    """
    n_out, n_in = _check_count(n_out, "n_out"), _check_count(n_in, "n_in")
    lam, Bs, Cs = [], [], []
    D = np.zeros((n_out, n_in))
    for key in sorted(fits):
        fit = fits[key]
        if not isinstance(fit, TfFit):
            raise TypeError(f"tf_fits_to_modal: fits[{key!r}] must be a TfFit, got "
                            f"{type(fit).__name__}")
        if (not isinstance(key, tuple) or len(key) != 2
                or not all(isinstance(k, (int, np.integer)) for k in key)
                or not (0 <= key[0] < n_out and 0 <= key[1] < n_in)):
            raise ValueError(f"tf_fits_to_modal: key {key!r} is not an (output, input) index pair "
                             f"within ({n_out}, {n_in}); use integer indices")
        o, i = int(key[0]), int(key[1])
        lk, ck = _modal_states(fit.poles, fit.residues)
        for l_, c_ in zip(lk, ck):
            lam.append(l_)
            b = np.zeros(n_in, dtype=complex)
            b[i] = 1.0
            c = np.zeros(n_out, dtype=complex)
            c[o] = c_
            Bs.append(b)
            Cs.append(c)
        D[o, i] = fit.direct
    n = len(lam)
    B = np.array(Bs, dtype=complex).reshape(n, n_in)
    C = np.array(Cs, dtype=complex).reshape(n, n_out).T
    return ModalSystem(lam=np.array(lam, dtype=complex), B=B, C=np.ascontiguousarray(C), D=D)


def _check_count(n, name):
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"{name} must be a positive integer, got {n!r}")
    return int(n)


# ----------------------------------------------------------------------------------------------
# numerical core: denominators as real sections in s/w0
# ----------------------------------------------------------------------------------------------
#
# A denominator is (quad, lin): quad (nq, 2) rows (a1, a0) of s^2 + a1 s + a0, lin (nl,) with
# nl in {0, 1}, the a of s + a. The section basis of a denominator is, per quad section,
# 1/Q and s/Q, then 1/(s + a): n functions. All in the normalized variable.


def _stack(z):
    """Real stacked form of a complex array along the first axis."""
    return np.concatenate([z.real, z.imag], axis=0)


def _column_norms(A):
    """Euclidean norms of a real matrix's columns: ``np.linalg.norm(A, axis=0)``'s own
    arithmetic (the same numbers, bit for bit) without its checks, a few microseconds a call
    over some 10^5 calls per identification."""
    return np.sqrt(np.add.reduce(A * A, axis=0))


def _lstsq(A, b, rcond=_RCOND):
    """Column-scaled SVD least squares; returns x and an orthonormal basis of range(A)."""
    norms = _column_norms(A)
    norms = np.where(norms > 0, norms, 1.0)
    U, sv, Vt = np.linalg.svd(A / norms, full_matrices=False)
    keep = sv > rcond * sv[0] if sv.size and sv[0] > 0 else np.zeros(sv.size, bool)
    U, sv, Vt = U[:, keep], sv[keep], Vt[keep]
    x = (Vt.T @ ((U.T @ b) / (sv if b.ndim == 1 else sv[:, None])))
    x = x / (norms if b.ndim == 1 else norms[:, None])
    return x, U


def _lstsq_x(A, b, rcond=_RCOND):
    """:func:`_lstsq`'s solution alone, by LAPACK's ``gelsd`` (no range basis: about 1.3x
    faster). The same column scaling and relative singular-value cut-off."""
    norms = _column_norms(A)
    norms = np.where(norms > 0, norms, 1.0)
    x = _gelsd(A / norms, b, rcond)
    return x / (norms if b.ndim == 1 else norms[:, None])


def _lstsq_error(err, flag):
    raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")


def _eigvals_error(err, flag):
    raise np.linalg.LinAlgError("Eigenvalues did not converge")


def _gelsd(A, b, rcond):
    """``np.linalg.lstsq(A, b, rcond=rcond)[0]`` for a real tall `A` (m > n) and real `b`:
    numpy's own ``gelsd`` ufunc called as ``lstsq`` calls it (the same numbers, bit for bit)
    without its argument handling, some 10 us a call over some 10^5 calls per
    identification."""
    if _lapack is None or A.dtype != np.float64 or b.dtype != np.float64:
        return np.linalg.lstsq(A, b, rcond=rcond)[0]
    with np.errstate(call=_lstsq_error, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        x = _lapack.lstsq(A, b[:, None] if b.ndim == 1 else b, rcond, signature="ddd->ddid")[0]
    return x[:, 0] if b.ndim == 1 else x


def _eigvals(a):
    """``np.linalg.eigvals(a)`` of a real square matrix (real where every eigenvalue is) by
    numpy's own ufunc, without its argument handling; the same numbers and errors."""
    if _lapack is None or a.dtype != np.float64:
        return np.linalg.eigvals(a)
    if not np.isfinite(a).all():
        raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
    with np.errstate(call=_eigvals_error, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        w = _lapack.eigvals(a, signature="d->D")
    return w.real.copy() if not w.imag.any() else w


def _section_roots(a1, a0):
    """Roots of s^2 + a1 s + a0 (the one with Im > 0 first for a complex pair)."""
    disc = a1 * a1 - 4.0 * a0
    if disc < 0:
        re, im = -0.5 * a1, 0.5 * np.sqrt(-disc)
        return complex(re, im), complex(re, -im)
    q = -0.5 * (a1 + np.copysign(np.sqrt(disc), a1))
    if q == 0.0:
        return 0j, 0j
    return complex(q), complex(a0 / q)


def _poles(quad, lin):
    out = []
    for a1, a0 in quad:
        out.extend(_section_roots(a1, a0))
    out.extend(complex(-a) for a in lin)
    return np.array(out, dtype=complex)


def _sections(poles):
    """Real sections from a conjugate-closed pole set (real poles paired neighbour-wise)."""
    poles = np.asarray(poles, dtype=complex)
    tol = _REAL_RTOL * np.maximum(np.abs(poles), 1e-300)
    real = np.abs(poles.imag) <= tol
    upper = poles[(~real) & (poles.imag > 0)]
    lower = poles[(~real) & (poles.imag < 0)]
    if upper.size != lower.size:
        raise FloatingPointError("pole set is not closed under conjugation")
    quad = [(-2.0 * p.real, abs(p) ** 2) for p in upper]
    r = np.sort(poles[real].real)
    for k in range(0, r.size - 1, 2):
        quad.append((-(r[k] + r[k + 1]), r[k] * r[k + 1]))
    lin = [-r[-1]] if r.size % 2 else []
    return np.array(quad, dtype=float).reshape(-1, 2), np.array(lin, dtype=float)


def _reflect(quad, lin):
    """Reflect unstable sections' roots to the left half-plane: (quad, lin, reflected poles)."""
    quad, lin = quad.copy(), lin.copy()
    flipped = []
    for k, (a1, a0) in enumerate(quad):
        if a1 >= 0 and a0 >= 0:
            continue
        r1, r2 = _section_roots(a1, a0)
        flipped.extend(p for p in (r1, r2) if p.real > 0)
        if a1 * a1 - 4 * a0 < 0:
            quad[k] = (abs(a1), a0)
        else:
            x1, x2 = abs(r1.real), abs(r2.real)
            quad[k] = (x1 + x2, x1 * x2)
    for k, a in enumerate(lin):
        if a < 0:
            flipped.append(complex(-a))
            lin[k] = -a
    return quad, lin, flipped


def _basis(s, quad, lin):
    """Section basis, shape (n_f, n): 1/Q_k, s/Q_k per quad section, then 1/(s + a)."""
    nq = len(quad)
    out = np.empty((s.size, 2 * nq + len(lin)), dtype=complex)
    if nq:
        quad = np.asarray(quad, dtype=float)
        sc = s[:, None]
        q = 1.0 / (sc * sc + quad[:, 0] * sc + quad[:, 1])
        out[:, 0:2 * nq:2] = q
        out[:, 1:2 * nq:2] = sc * q
    if len(lin):
        out[:, 2 * nq:] = 1.0 / (s[:, None] + np.asarray(lin, dtype=float))
    return out


def _section_polys(quad, lin):
    """Numerator polynomials P_j (length n, highest first) of the basis: phi_j = P_j / A."""
    factors = [np.array([1.0, a1, a0]) for a1, a0 in quad] + [np.array([1.0, a]) for a in lin]
    n = 2 * len(quad) + len(lin)
    polys = []
    for k in range(len(factors)):
        other = np.array([1.0])
        for j, fac in enumerate(factors):
            if j != k:
                other = np.convolve(other, fac)  # np.polymul without its poly1d overhead
        these = [other, np.append(other, 0.0)] if k < len(quad) else [other]
        for p in these:
            polys.append(np.concatenate([np.zeros(n - p.size), p]))
    return np.array(polys).reshape(-1, n), factors


def _model_space(s, quad, lin, n_num, phi=None):
    """Real-coefficient basis M (n_f, q) of {N/A : deg N <= n_num} and its map T to section coefs.

    The section coefficients (n, plus the direct term when n_num == n) are ``T @ x``
    for model coefficients ``x``. phi: the section basis (:func:`_basis`) if computed.
    """
    if phi is None:
        phi = _basis(s, quad, lin)
    n = phi.shape[1]
    if n_num == n:
        return np.hstack([phi, np.ones((s.size, 1))]), np.eye(n + 1)
    if n_num == n - 1:
        return phi, np.eye(n)
    polys, _ = _section_polys(quad, lin)
    G = polys[:, : n - 1 - n_num].T  # leading coefficients that must vanish, (d-1, n)
    _, sv, Vt = np.linalg.svd(G)
    rank = int(np.sum(sv > 1e-12 * max(sv[0], 1e-300))) if sv.size else 0
    Z = Vt[rank:].T
    return phi @ Z, Z


class _Problem:
    """Normalized data of one scalar fit: s (n_f,), y (n_f,), sqrt weights (n_f,)."""

    def __init__(self, s, y, sw, n_num, stable):
        self.s, self.y, self.sw = s, y, sw
        self.n_num, self.stable = n_num, stable
        self.bound = _POLE_BOUND * float(np.max(np.abs(s)))
        self.b = _stack(sw * y)
        self.norm2 = float(self.b @ self.b)
        self._space_key, self._space = None, None

    def space(self, quad, lin):
        """``(M, T, phi)``: :func:`_model_space` and :func:`_basis` of a denominator, kept for
        the latest one (a Sanathanan-Koerner iterate's output error and its next step use the
        same denominator: computed once, the same arrays)."""
        key = (np.asarray(quad, dtype=float).tobytes(), np.asarray(lin, dtype=float).tobytes(),
               len(quad))
        if self._space_key != key:
            phi = _basis(self.s, quad, lin)
            M, T = _model_space(self.s, quad, lin, self.n_num, phi)
            self._space_key, self._space = key, (M, T, phi)
        return self._space

    def project(self, quad, lin):
        """Best numerator for a denominator.

        Returns (J, model (n_f,), section coefficients, orthonormal basis of the weighted
        model space (2 n_f, q), weighted real residual (2 n_f,)).
        """
        M, T, _ = self.space(quad, lin)
        A = _stack(self.sw[:, None] * M)
        x, U = _lstsq(A, self.b)
        model = M @ x
        r = self.b - A @ x
        return float(r @ r), model, T @ x, U, r

    def cost(self, quad, lin):
        """``J`` of the best numerator for a denominator (:meth:`project`'s first value)."""
        M, _, _ = self.space(quad, lin)
        A = _stack(self.sw[:, None] * M)
        r = self.b - A @ _lstsq_x(A, self.b)
        return float(r @ r)

    def error(self, cost):
        return float(np.sqrt(max(cost, 0.0) / self.norm2))


def _levi(s, y, sw, n_den, n_num):
    """Levi's linearized fit: poles of A from min sum w |h A - B|^2 (A monic), normalized s."""
    pa = s[:, None] ** np.arange(n_den)
    pb = s[:, None] ** np.arange(n_num + 1)
    A = sw[:, None] * np.hstack([-y[:, None] * pa, pb])
    x = _lstsq_x(_stack(A), _stack(sw * y * s**n_den))
    a = x[:n_den]
    return np.roots(np.concatenate([[1.0], a[::-1]]))


def _log_spaced_poles(n, w_lo, w_hi):
    """Vector-fitting starting poles: pairs -w/100 +- j w log-spaced over the band, one real."""
    n_pairs = n // 2
    w = np.geomspace(w_lo, w_hi, n_pairs) if n_pairs > 1 else np.array([np.sqrt(w_lo * w_hi)])
    p = []
    for wk in w[:n_pairs]:
        p += [complex(-_VF_START_DAMPING * wk, wk), complex(-_VF_START_DAMPING * wk, -wk)]
    if n % 2:
        p.append(complex(-np.sqrt(w_lo * w_hi)))
    return np.array(p, dtype=complex)


def _realization(quad, lin):
    """Real (A, b) with phi(s) = (sI - A)^-1 b row-selected: the basis functions' states."""
    n = 2 * len(quad) + len(lin)
    A = np.zeros((n, n))
    b = np.zeros(n)
    k = 0
    for a1, a0 in quad:
        A[k, k + 1] = 1.0
        A[k + 1, k] = -a0
        A[k + 1, k + 1] = -a1
        b[k + 1] = 1.0  # x_k = 1/Q, x_{k+1} = s/Q
        k += 2
    for a in lin:
        A[k, k] = -a
        b[k] = 1.0
        k += 1
    return A, b


def _sigma_zeros(quad, lin, c, d=1.0):
    """Zeros of d + sum_j c_j phi_j(s): eigenvalues of A - b c^T / d."""
    A, b = _realization(quad, lin)
    return _eigvals(A - np.outer(b, c) / d)


def _sk_step(prob, quad, lin):
    """One Sanathanan-Koerner iteration in barycentric form: the new poles."""
    M, _, phi = prob.space(quad, lin)
    A = prob.sw[:, None] * np.hstack([M, -prob.y[:, None] * phi])
    x = _lstsq_x(_stack(A), prob.b)
    c = x[M.shape[1]:]
    return _sigma_zeros(quad, lin, c)


def _jacobian(prob, quad, lin, model, U):
    """Kaufman variable-projection Jacobian of the weighted residual (up to sign), (2 n_f, n)."""
    s = prob.s
    cols = []
    for a1, a0 in quad:
        q = 1.0 / (s * s + a1 * s + a0)
        cols += [-model * s * q, -model * q]  # d/da1, d/da0 with the numerator fixed
    for a in lin:
        cols.append(-model / (s + a))
    D = _stack(prob.sw[:, None] * np.array(cols).T)
    return D - U @ (U.T @ D)


def _theta(quad, lin):
    return np.concatenate([quad.ravel(), lin])


def _untheta(theta, nq):
    return theta[: 2 * nq].reshape(nq, 2).copy(), theta[2 * nq:].copy()


def _output_error(prob, quad, lin, *, method, max_iter, tol, history, stages):
    """Damped Gauss-Newton / Levenberg-Marquardt on the section coefficients (variable projection).

    Gauss-Newton halves its step up to ``_MAX_HALVINGS`` times; if that finds no decrease
    (a poorly determined direction of an over-parametrized model), the iteration falls back
    to Levenberg-Marquardt steps of growing damping. Converged: the step predicts a relative
    decrease of ``J`` below ``tol``, or ``J`` fell by less than ``_STALL_FACTOR * tol``
    (relative) in each of the last ``_STALL_ITER`` iterations (a flat valley: the fit has
    settled while poorly determined parameters drift), or no damping finds a decrease (a
    minimum to rounding).

    Returns (quad, lin, iterations, converged, reflected poles of accepted steps).
    """
    nq = quad.shape[0]
    cost, model, _, U, r = prob.project(quad, lin)
    reflected = []
    lam = 1e-3
    label = "gn" if method == "gauss-newton" else "lm"
    stall = 0
    for it in range(1, max_iter + 1):
        if prob.error(cost) <= _ERROR_FLOOR:
            return quad, lin, it - 1, True, reflected
        J = _jacobian(prob, quad, lin, model, U)
        theta = _theta(quad, lin)
        delta, _ = _lstsq(J, r)
        pred = float(r @ r - np.sum((r - J @ delta) ** 2))
        if pred <= tol * cost:
            return quad, lin, it - 1, True, reflected
        trial = None
        if method == "gauss-newton":
            t = 1.0
            for _ in range(_MAX_HALVINGS):
                trial = _try_step(prob, theta + t * delta, nq, cost)
                if trial is not None:
                    break
                t *= 0.5
            lam = 1e-3
        if trial is None:
            norms = _column_norms(J)
            norms = np.where(norms > 0, norms, 1.0)
            Jr = np.concatenate([r, np.zeros(theta.size)])
            while lam <= _MAX_DAMPING:
                step, _ = _lstsq(np.vstack([J, np.sqrt(lam) * np.diag(norms)]), Jr)
                trial = _try_step(prob, theta + step, nq, cost)
                if trial is not None:
                    lam = max(lam / 10.0, 1e-12)
                    break
                lam *= 10.0
        if trial is None:
            # neither the Gauss-Newton step nor a short gradient step decreases J
            return quad, lin, it - 1, True, reflected
        new_cost, quad, lin, model, U, r, flipped = trial
        stall = stall + 1 if cost - new_cost <= _STALL_FACTOR * tol * cost else 0
        cost = new_cost
        reflected = reflected + flipped if flipped else reflected
        history.append(prob.error(cost))
        stages.append(label)
        if stall >= _STALL_ITER:
            return quad, lin, it, True, reflected
    return quad, lin, max_iter, False, reflected


def _try_step(prob, theta, nq, cost_now):
    """Evaluate a trial step; None unless it is admissible and decreases J below cost_now."""
    if not np.all(np.abs(theta) <= 4.0 * prob.bound**2):  # also rejects nan
        return None
    quad, lin = _untheta(theta, nq)
    flipped = []
    if prob.stable:
        quad, lin, flipped = _reflect(quad, lin)
    if not (np.all(np.isfinite(quad)) and np.all(np.isfinite(lin))):
        return None
    if np.any(np.abs(_poles(quad, lin)) > prob.bound):
        return None
    cost, model, _, U, r = prob.project(quad, lin)
    if not cost < cost_now:  # also rejects nan
        return None
    return cost, quad, lin, model, U, r, flipped


def _clip(p, bound):
    """Pull poles beyond ``bound`` back to that radius (same angle)."""
    mag = np.abs(p)
    return np.where(mag > bound, p * (bound / np.maximum(mag, 1e-300)), p)


def _split_repeated(quad, lin):
    """Separate (nearly) repeated poles so that partial fractions exist: (quad, lin, notes).

    Two poles closer than ``_REPEAT_RTOL`` (relative) are moved symmetrically about their
    mean to that separation. For a double pole the denominator changes only in second
    order (``(s - m)^2 - d^2``), and the numerator is refitted afterwards; the residues
    grow like ``1 / d``, so ``d ~ eps^(1/3)`` balances model change and cancellation.
    """
    quad, lin = quad.copy(), lin.copy()
    notes = []
    half = 0.5 * _REPEAT_RTOL
    for k, (a1, a0) in enumerate(quad):  # within a section: widen about the mean
        r1, r2 = _section_roots(a1, a0)
        mag = max(abs(r1), abs(r2), 1e-300)
        if abs(r1 - r2) < _REPEAT_RTOL * mag:
            m, d = -0.5 * a1, half * mag
            quad[k] = (a1, m * m + d * d) if a1 * a1 - 4 * a0 < 0 else (a1, m * m - d * d)
            notes.append(f"repeated pole {complex(m, 0) if r1.imag == 0 else r1:.6g} "
                         f"(normalized) split to a relative separation {_REPEAT_RTOL:g}")
    for _ in range(8):  # across sections: scale the two sections apart
        p = _poles(quad, lin)
        owner = np.concatenate([np.repeat(np.arange(len(quad)), 2),
                                len(quad) + np.arange(len(lin))]).astype(int)
        close = [(i, j) for i in range(p.size) for j in range(i + 1, p.size)
                 if owner[i] != owner[j]
                 and abs(p[i] - p[j]) < _REPEAT_RTOL * max(abs(p[i]), 1e-300)]
        if not close:
            break
        i, j = close[0]
        sep_plus = abs(p[i] * (1 + half) - p[j] * (1 - half))
        sep_minus = abs(p[i] * (1 - half) - p[j] * (1 + half))
        sign = 1.0 if sep_plus >= sep_minus else -1.0
        for k, fct in ((owner[i], 1 + sign * half), (owner[j], 1 - sign * half)):
            if k < len(quad):
                quad[k] = (quad[k, 0] * fct, quad[k, 1] * fct * fct)
            else:
                lin[k - len(quad)] *= fct
        notes.append(f"repeated pole {p[i]:.6g} (normalized) in two sections split to a relative "
                     f"separation {_REPEAT_RTOL:g}")
    return quad, lin, notes


def _section_residues(quad, lin, coef):
    """Residues (aligned with _poles) of sum (b s + c)/Q + e/(s + a); coefs (c, b, ..., e)."""
    out = []
    for k, (a1, a0) in enumerate(quad):
        c, b = coef[2 * k], coef[2 * k + 1]
        p1, p2 = _section_roots(a1, a0)
        r1 = (b * p1 + c) / (p1 - p2)
        if p1.imag > 0:
            out += [r1, np.conj(r1)]
        else:
            out += [r1, (b * p2 + c) / (p2 - p1)]
    nq = 2 * len(quad)
    out += [complex(coef[nq + k]) for k in range(len(lin))]
    return np.array(out, dtype=complex)


def _order_poles(p, r):
    """Sort by magnitude, conjugate pairs adjacent with Im > 0 first; residues along."""
    key = np.lexsort((-p.imag, np.round(np.abs(p), 12)))
    return p[key], r[..., key] if r.ndim == 1 else r[key]


# ----------------------------------------------------------------------------------------------
# input checks
# ----------------------------------------------------------------------------------------------


def _check_order(n, name, lo):
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < lo:
        raise ValueError(f"{name} must be an integer >= {lo}, got {n!r}")
    return int(n)


def _check_frequencies(f_hz, where):
    f = np.asarray(f_hz)
    if f.dtype.kind == "c":
        raise TypeError(f"{where}: f_hz must be real frequencies [Hz], got complex values")
    f = f.astype(float)
    if f.ndim != 1 or f.size < 1:
        raise ValueError(f"{where}: f_hz must be a 1-D array of frequencies [Hz], got shape "
                         f"{f.shape}")
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError(f"{where}: f_hz must be finite and >= 0 Hz; check the frequency axis")
    return f


def _check_weight(weight, shape, where):
    if weight is None:
        return np.ones(shape)
    w = np.asarray(weight, dtype=float)
    try:
        w = np.broadcast_to(w, shape)
    except ValueError:
        raise ValueError(f"{where}: weight has shape {w.shape}, expected {shape} or one value "
                         "per frequency") from None
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"{where}: weights must be finite and >= 0; set unwanted frequencies to 0")
    return w


def _normalization(f_used, where):
    pos = f_used[f_used > 0]
    if pos.size == 0:
        raise IdentificationError(f"{where}: no positive frequency has a positive weight; "
                                  "give weight to the band to be fitted")
    return float(np.sqrt(pos.min() * pos.max()))


# ----------------------------------------------------------------------------------------------
# fit_tf
# ----------------------------------------------------------------------------------------------


#: Stages 1-2 of the latest fits (:func:`_sk_stages`), by their inputs: order selection
#: (:func:`select_order`) runs them at each order, and the pipeline's final output-error fit
#: at the chosen order runs the very same ones again; they are deterministic, so the second
#: run is taken from here (the same numbers, bit for bit). Bounded: cleared past
#: ``_SK_MEMO_SIZE`` entries.
_SK_MEMO = {}
_SK_MEMO_SIZE = 16


def _sk_stages(prob, s, f_u, h_u, w_u, f0, n_den, n_num, sk_iter, stable):
    """Stages 1-2 of :func:`fit_tf` (the starts and their Sanathanan-Koerner iterations): the
    iterate of the lowest output error, as a dict (``cost, quad, lin, flipped, start, hist,
    stg``; not to be mutated: it may be shared through ``_SK_MEMO``)."""
    key = (n_den, n_num, bool(stable), sk_iter, f_u.tobytes(), h_u.tobytes(), w_u.tobytes())
    hit = _SK_MEMO.get(key)
    if hit is not None:
        return hit
    starts = []
    try:
        p_levi = _levi(s, prob.y, prob.sw, n_den, n_num)
        if np.all(np.isfinite(p_levi)):
            starts.append(("levi", p_levi))
    except np.linalg.LinAlgError:
        pass
    starts.append(("log-spaced", _log_spaced_poles(n_den, f_u[f_u > 0].min() / f0,
                                                   f_u.max() / f0)))
    best = None
    for name, p0 in starts:
        hist, stg = [], []
        p = p0
        for k in range(sk_iter + 1):
            if k > 0:
                try:
                    p = _sk_step(prob, quad, lin)
                except (np.linalg.LinAlgError, FloatingPointError):
                    break
                if not np.all(np.isfinite(p)):
                    break
            try:
                quad, lin = _sections(_clip(p, prob.bound))
            except FloatingPointError:
                break
            flipped = []
            if stable:
                quad, lin, flipped = _reflect(quad, lin)
            cost = prob.cost(quad, lin)
            hist.append(prob.error(cost))
            stg.append(name if k == 0 else "sk")
            if best is None or cost < best["cost"]:
                best = {"cost": cost, "quad": quad, "lin": lin, "flipped": flipped, "start": name,
                        "hist": list(hist), "stg": list(stg)}
            # SK has settled: at the rounding floor, or the output error no longer changes
            if hist[-1] <= _ERROR_FLOOR or (k > 0 and abs(hist[-2] - hist[-1]) <= 1e-9 * hist[-1]):
                break
    if len(_SK_MEMO) >= _SK_MEMO_SIZE:
        _SK_MEMO.clear()
    _SK_MEMO[key] = best
    return best


def fit_tf(f_hz, h, *, weight=None, n_den, n_num, method="gauss-newton", max_iter=30, tol=1e-8,
           stable=True, sk_iter=6):
    """Fit ``H(s) = B(s) / A(s)`` to a frequency response (``invfreqs`` with iterations).

    Minimizes the output error ``J = sum_k w_k |h_k - B(s_k)/A(s_k)|^2``
    (seed paper Eq. 30) with ``A`` monic of order `n_den` and ``B`` of order
    `n_num`; see the module notes for the stages and the scaling.

    Parameters
    ----------
    f_hz : array_like, shape (n_f,)
        Frequencies [Hz], >= 0, any order.
    h : array_like of complex, shape (n_f,)
        Frequency response [output units per input unit]. May be non-finite
        where the weight is 0.
    weight : array_like, shape (n_f,), optional
        Weights ``w_k >= 0`` of the squared errors (default 1). Frequencies of
        weight 0 are ignored.
    n_den : int
        Denominator order (number of poles), >= 1.
    n_num : int
        Numerator order, ``0 <= n_num <= n_den``; ``n_num = n_den`` gives a
        direct term.
    method : {"gauss-newton", "levenberg-marquardt", "sk"}
        Output-error search after the SK iterations (damped Gauss-Newton with
        step halving as ``invfreqs``, or Levenberg-Marquardt); ``"sk"`` stops
        after the SK iterations (best iterate by output error).
    max_iter : int
        Most output-error iterations.
    tol : float
        Convergence: the Gauss-Newton step predicts a relative decrease of
        ``J`` below `tol` (a scaled gradient test), or three successive
        iterations each lower ``J`` by less than ``100 * tol`` (relative; the
        fit has settled in a flat valley of an over-parametrized model), or no
        damped step lowers ``J`` (a minimum to rounding).
    stable : bool
        Reflect unstable poles into the left half-plane (see Notes).
    sk_iter : int
        Sanathanan-Koerner iterations from each start.

    Returns
    -------
    TfFit

    Raises
    ------
    ValueError
        On a bad order, shape, weight or method, or non-finite data where the
        weight is positive.
    IdentificationError
        If fewer real equations than parameters have positive weight, or the
        data are zero there.

    Warns
    -----
    FitWarning
        If unstable poles had to be reflected, or the output-error search did
        not converge in `max_iter` iterations (the best iterate is returned,
        ``converged=False``).

    Notes
    -----
    A reflected pole keeps its magnitude response and loses its phase: a fit
    that needs it cannot match the phase with stable poles (a time delay, a
    sign error or too high an order are the usual causes). The warning lists
    the poles that had to be reflected in the stage that produced the result.

    Examples
    --------
    >>> import numpy as np
    >>> f = np.linspace(0.5, 20.0, 400)
    >>> s = 2j * np.pi * f
    >>> wn = 2 * np.pi * 3.0
    >>> h = 1e-3 * s / (s**2 + 0.2 * wn * s + wn**2)
    >>> fit = fit_tf(f, h, n_den=2, n_num=1)
    >>> bool(fit.fit_error < 1e-10), np.round(np.abs(fit.poles) / (2 * np.pi), 6)
    (True, array([3., 3.]))
    """
    where = "fit_tf"
    f = _check_frequencies(f_hz, where)
    h = np.asarray(h)
    if h.shape != f.shape:
        raise ValueError(f"{where}: h has shape {h.shape}, expected {f.shape} (one value per "
                         "frequency)")
    h = h.astype(complex)
    n_den = _check_order(n_den, "n_den", 1)
    n_num = _check_order(n_num, "n_num", 0)
    if n_num > n_den:
        raise ValueError(f"{where}: n_num={n_num} > n_den={n_den}; an improper transfer function "
                         "cannot be fitted, lower n_num")
    if method not in _METHODS:
        raise ValueError(f"{where}: method must be one of {_METHODS}, got {method!r}")
    max_iter = _check_order(max_iter, "max_iter", 0)
    sk_iter = _check_order(sk_iter, "sk_iter", 0)
    if not tol > 0:
        raise ValueError(f"{where}: tol must be positive, got {tol!r}")
    w = _check_weight(weight, f.shape, where)
    used = w > 0
    if not np.all(np.isfinite(h[used])):
        bad = np.flatnonzero(used & ~np.isfinite(h))
        raise ValueError(f"{where}: h is not finite at {bad.size} weighted frequencies (first "
                         f"{f[bad[0]]:g} Hz); give them weight 0")
    n_par = n_den + n_num + 1
    if 2 * int(np.sum(used & (f > 0))) + int(np.sum(used & (f == 0))) < n_par:
        raise IdentificationError(
            f"{where}: {int(used.sum())} weighted frequencies give fewer real equations than the "
            f"{n_par} parameters of an order {n_den}/{n_num} model; lower the orders or widen "
            "the band")
    f_u, h_u, w_u = f[used], h[used], w[used]
    f0 = _normalization(f_u, where)
    scale = float(np.sqrt(np.sum(w_u * np.abs(h_u) ** 2) / np.sum(w_u)))
    if not scale > 0:
        raise IdentificationError(f"{where}: h is zero at every weighted frequency; there is "
                                  "nothing to fit (drop the pair or model it as zero)")
    s = 1j * f_u / f0
    prob = _Problem(s, h_u / scale, np.sqrt(w_u), n_num, stable)

    # stages 1-2: starts and SK iterations; keep the iterate with the lowest output error
    best = _sk_stages(prob, s, f_u, h_u, w_u, f0, n_den, n_num, sk_iter, stable)
    quad, lin = best["quad"], best["lin"]
    history, stages = list(best["hist"]), list(best["stg"])
    reflected = list(best["flipped"])

    # stage 3: output error
    n_flips = 0
    if method == "sk":
        iterations, converged = 0, True
    else:
        quad, lin, iterations, converged, flipped = _output_error(
            prob, quad, lin, method=method, max_iter=max_iter, tol=tol, history=history,
            stages=stages)
        n_flips = len(flipped)

    # partial fractions (distinct poles), unscaling
    quad, lin, notes = _split_repeated(quad, lin)
    _, _, coef, _, _ = prob.project(quad, lin)
    p_n = _poles(quad, lin)
    r_n = _section_residues(quad, lin, coef)
    d_n = float(coef[-1]) if n_num == n_den else 0.0
    w0 = 2 * np.pi * f0
    poles, residues = _order_poles(p_n * w0, r_n * (scale * w0))
    direct = scale * d_n
    num, den = _polynomials(quad, lin, coef, n_num, w0, scale)
    fit_h = _pole_residue_response(f_u, poles, residues, direct)
    fit_error = float(np.sqrt(np.sum(w_u * np.abs(h_u - fit_h) ** 2)
                              / np.sum(w_u * np.abs(h_u) ** 2)))

    if reflected or n_flips:
        upper = [p for p in reflected if p.imag >= 0]
        desc = ", ".join(_describe_pole(p * w0) for p in upper[:6])
        if len(upper) > 6:
            desc += f" and {len(upper) - 6} more"
        if n_flips:
            desc += ("; " if desc else "") + (f"{n_flips} poles crossed into the right half-plane "
                                              f"during the {method} search")
        notes.append(f"unstable poles reflected: {desc}")
        warnings.warn(f"{where}: unstable poles reflected: {desc} (order {n_den}/{n_num}, fit "
                      f"error {fit_error:.3g}); the data call for poles in the right half-plane: "
                      "check the FRF's phase (delay, sign), or lower the order",
                      FitWarning, stacklevel=2)
    if not converged:
        warnings.warn(f"{where}: the {method} search did not converge in {max_iter} iterations "
                      f"(order {n_den}/{n_num}, fit error {fit_error:.3g}); the best iterate is "
                      "returned: raise max_iter, or check the order (select_order) and the weights",
                      FitWarning, stacklevel=2)
    settings = {"n_den": n_den, "n_num": n_num, "method": method, "max_iter": max_iter, "tol": tol,
                "stable": stable, "sk_iter": sk_iter, "f0_hz": f0, "h_scale": scale,
                "start": best["start"], "n_used": int(used.sum())}
    return TfFit(num=num, den=den, poles=poles, residues=residues, direct=float(direct),
                 fit_error=fit_error, iterations=int(iterations), converged=bool(converged),
                 history=tuple(float(e) for e in history), stages=tuple(stages),
                 settings=settings, notes=tuple(notes))


def _describe_pole(p):
    wn = abs(p)
    zeta = -p.real / wn if wn > 0 else 0.0
    return f"{wn / (2 * np.pi):.4g} Hz (damping ratio {zeta:.3g})"


def _polynomials(quad, lin, coef, n_num, w0, scale):
    """num, den in unscaled s from the normalized sections (for display and export)."""
    polys, factors = _section_polys(quad, lin)
    n = polys.shape[1]
    den_n = np.array([1.0])
    for fac in factors:
        den_n = np.convolve(den_n, fac)  # np.polymul of monic factors, without poly1d
    num_n = np.concatenate([[0.0], coef[:n] @ polys]) if n else np.zeros(1)
    if coef.size > n:
        num_n = num_n + coef[n] * den_n
    num_n = num_n[n - n_num:]  # the dropped leading coefficients are zero by construction
    den = den_n * w0 ** np.arange(n + 1)
    num = scale * w0**n * num_n * w0 ** (-np.arange(n_num, -1, -1.0))
    return num, den


# ----------------------------------------------------------------------------------------------
# order selection
# ----------------------------------------------------------------------------------------------


def select_order(f_hz, h, *, weight=None, orders=range(2, 11), relative_num=-1, improvement=0.1,
                 floor=1e-3, method="gauss-newton", max_iter=30, stable=True, stop_early=True):
    """Fit several denominator orders and pick the smallest adequate one.

    Parameters
    ----------
    f_hz, h, weight
        As :func:`fit_tf`.
    orders : iterable of int
        Denominator orders to try.
    relative_num : int
        ``n_num = n_den + relative_num``: 0 with a direct term (tire forces,
        ride heights near a wheel loader), -1 strictly proper (the default),
        -2 for a relative degree 2.
    improvement : float
        Fraction of the fit error a higher order must remove to be worth it.
    floor : float
        A fit error at or below this is good enough.
    method, max_iter, stable
        As :func:`fit_tf`.
    stop_early : bool
        Stop fitting higher orders once the choice can no longer change: an
        order reached `floor` and every lower order is already beaten by more
        than `improvement` (the selected fit is the same as with
        ``stop_early=False``, which fits every order; only the table is
        shorter).

    Returns
    -------
    fit : TfFit
        The selected fit (its FitWarnings are re-emitted; those of the other
        orders are not).
    table : list of (int, float)
        ``(order, fit_error)`` for every order fitted (``nan`` if it failed),
        ascending.

    Raises
    ------
    ValueError
        On bad orders (empty, or giving a numerator order outside 0..n_den).

    Warns
    -----
    FitWarning
        If the highest order was selected without reaching `floor` (more
        poles may be needed), plus the selected fit's own warnings.

    Notes
    -----
    Rule: the selected order is the smallest order ``n`` with
    ``fit_error(n) <= floor``, or else the smallest ``n`` that no higher
    order tried improves by more than `improvement`:
    ``min over m > n of fit_error(m) >= (1 - improvement) fit_error(n)``.
    Looking at all higher orders, not just the next one, lets an order that
    adds a useless real pole (odd orders on a system of pole pairs) not stop
    the search.
    """
    where = "select_order"
    try:
        orders = sorted({int(o) for o in orders})
    except TypeError:
        raise TypeError(f"{where}: orders must be an iterable of integers, "
                        f"got {orders!r}") from None
    if not orders or orders[0] < 1:
        raise ValueError(f"{where}: orders must be a non-empty set of integers >= 1, got {orders}")
    if isinstance(relative_num, bool) or not isinstance(relative_num, (int, np.integer)) \
            or relative_num > 0 or orders[0] + relative_num < 0:
        raise ValueError(f"{where}: relative_num={relative_num!r} must be an integer <= 0 with "
                         f"n_den + relative_num >= 0 for every order (smallest {orders[0]})")
    if not 0 <= improvement < 1:
        raise ValueError(f"{where}: improvement must be in [0, 1), got {improvement!r}")
    fits, caught, table = {}, {}, []
    last_error = None
    for n in orders:
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            try:
                fits[n] = fit_tf(f_hz, h, weight=weight, n_den=n, n_num=n + relative_num,
                                 method=method, max_iter=max_iter, stable=stable)
            except IdentificationError as exc:  # e.g. too few frequencies for the high orders
                fits[n], last_error = None, exc
        caught[n] = rec
        table.append((n, fits[n].fit_error if fits[n] is not None else float("nan")))
        if stop_early and _order_settled(table, floor, improvement):
            break
    errors = {n: e for n, e in table if np.isfinite(e)}
    if not errors:
        raise last_error
    ok = sorted(errors)
    chosen = ok[-1]
    for k, n in enumerate(ok):
        higher = [errors[m] for m in ok[k + 1:]]
        if errors[n] <= floor or not higher or min(higher) >= (1 - improvement) * errors[n]:
            chosen = n
            break
    for rec in caught[chosen]:
        warnings.warn_explicit(rec.message, rec.category, rec.filename, rec.lineno)
    if chosen == ok[-1] and len(ok) > 1 and errors[chosen] > floor:
        warnings.warn(f"{where}: the highest order tried ({chosen}) was selected with fit error "
                      f"{errors[chosen]:.3g}; the data may need more poles: raise the highest order "
                      "(max_order; shockplan identify --max-order)",
                      FitWarning, stacklevel=2)
    return fits[chosen], table


def _order_settled(table, floor, improvement):
    """True when no higher order can change :func:`select_order`'s choice.

    The last order fitted reached `floor`, so the choice is it or a lower order; a lower
    order ``m`` is chosen only if no higher order improves it by more than `improvement`,
    which an order already fitted above ``m`` may have settled (then ``m`` is out whatever
    comes later). Once every lower order is out, the last one is the choice.
    """
    n, e_n = table[-1]
    if not e_n <= floor:  # also nan
        return False
    for k, (m, e_m) in enumerate(table[:-1]):
        if not np.isfinite(e_m):
            continue
        if e_m <= floor:
            return True  # m (or a lower order) is the choice already
        higher = [e for _, e in table[k + 1:] if np.isfinite(e)]
        if not min(higher) < (1 - improvement) * e_m:
            return False  # m is still in: it depends on the orders not fitted yet
    return True


# ----------------------------------------------------------------------------------------------
# vector fitting
# ----------------------------------------------------------------------------------------------


def fit_common_poles(f_hz, H, *, weight=None, n_poles, n_iter=20, direct=True, stable=True):
    """Vector fitting: one set of poles for every pair of a MIMO frequency response.

    Relaxed vector fitting (Gustavsen and Semlyen 1999; Gustavsen 2006):
    starting poles ``-w/100 +- j w`` log-spaced over the band (one real pole
    for an odd count), `n_iter` pole relocations on all pairs together, then
    the residues of every pair by linear least squares.

    Parameters
    ----------
    f_hz : array_like, shape (n_f,)
        Frequencies [Hz].
    H : array_like of complex, shape (n_out, n_in, n_f)
        Frequency response ``H[output, input, frequency]``. May be non-finite
        where the weight is 0.
    weight : array_like, shape (n_f,) or (n_out, n_in, n_f), optional
        Weights of the squared errors (default 1).
    n_poles : int
        Number of common poles (>= 1).
    n_iter : int
        Most pole relocations. Stops earlier when a relocation changes the
        fit error by less than 1e-6 (relative; ``converged=True``) or after
        5 relocations without a better fit (noisy data make the poles
        oscillate); the best relocation is kept.
    direct : bool
        Fit a direct term ``D``.
    stable : bool
        Flip unstable poles after every relocation.

    Returns
    -------
    VfFit

    Raises
    ------
    ValueError
        On bad shapes, weights or counts, or non-finite data where the weight
        is positive.
    IdentificationError
        If there are fewer weighted equations than parameters, or all data are zero.

    Notes
    -----
    Every pair is divided by its weighted RMS for the pole relocation, so all
    pairs count equally whatever their units (``fit_error_total`` is the RMS
    of the relative pair errors). The relocation solves for the weight
    function ``sigma(s) = d + sum c_j phi_j(s)`` after eliminating each
    pair's residues by a QR factorization, with Gustavsen's relaxation row
    ``Re sum_k sigma(s_k) = n_f``; if ``|d|`` comes out below 1e-8 the
    non-relaxed form (``d = 1``) is used for that iteration.
    """
    where = "fit_common_poles"
    f = _check_frequencies(f_hz, where)
    H = np.asarray(H)
    if H.ndim != 3 or H.shape[2] != f.size:
        raise ValueError(f"{where}: H has shape {H.shape}, expected (n_out, n_in, {f.size}) "
                         "(output, input, frequency)")
    H = H.astype(complex)
    p_out, m_in, _ = H.shape
    n_poles = _check_order(n_poles, "n_poles", 1)
    n_iter = _check_order(n_iter, "n_iter", 0)
    common_weight = weight is None or np.ndim(weight) <= 1
    W = _check_weight(weight, H.shape, where)
    used_f = np.any(W > 0, axis=(0, 1))
    if not np.all(np.isfinite(H[W > 0])):
        raise ValueError(f"{where}: H is not finite at some weighted points; give them weight 0")
    f_u = f[used_f]
    W = W[:, :, used_f]
    Hd = np.where(W > 0, H[:, :, used_f], 0.0)
    n_eq = 2 * int(np.sum(W > 0))
    n_par = n_poles + p_out * m_in * (n_poles + int(direct))
    if f_u.size == 0 or n_eq < n_par:
        raise IdentificationError(f"{where}: {n_eq} weighted real equations for {n_par} "
                                  "parameters; use fewer poles or more frequencies")
    f0 = _normalization(f_u, where)
    s = 1j * f_u / f0
    sw = np.sqrt(W)
    norm2 = np.sum(W * np.abs(Hd) ** 2, axis=-1)  # (p, m)
    scale = np.sqrt(norm2 / np.maximum(np.sum(W, axis=-1), 1e-300))
    if not np.any(scale > 0):
        raise IdentificationError(f"{where}: H is zero at every weighted frequency; nothing to fit")
    scale = np.where(scale > 0, scale, 1.0)
    Y = Hd / scale[:, :, None]
    pairs = [(o, i) for o in range(p_out) for i in range(m_in) if norm2[o, i] > 0]

    def residue_fit(quad, lin):
        """Residues (section coefficients) and relative errors of every pair for given poles."""
        phi = _basis(s, quad, lin)
        M = np.hstack([phi, np.ones((s.size, 1))]) if direct else phi
        coefs = np.zeros((p_out, m_in, M.shape[1]))
        err2 = np.zeros((p_out, m_in))
        groups = [pairs] if common_weight else [[pr] for pr in pairs]
        for group in groups:  # one factorization per distinct weight
            o0, i0 = group[0]
            A = _stack(sw[o0, i0][:, None] * M)
            b = np.stack([_stack(sw[o, i] * Y[o, i]) for o, i in group], axis=1)
            x, _ = _lstsq(A, b)
            rr = b - A @ x
            for k, (o, i) in enumerate(group):
                coefs[o, i] = x[:, k]
                err2[o, i] = rr[:, k] @ rr[:, k] / (b[:, k] @ b[:, k])
        return coefs, np.sqrt(err2)

    quad, lin = _sections(_log_spaced_poles(n_poles, f_u[f_u > 0].min() / f0, f_u.max() / f0))
    coefs, errs = residue_fit(quad, lin)
    history = [float(np.sqrt(np.mean(errs**2)))]
    best = (history[0], quad, lin, coefs, errs)
    flipped_any = []
    converged = False
    it = since_best = 0
    for it in range(1, n_iter + 1):
        try:
            p_new = _vf_relocate(s, Y, sw, pairs, quad, lin, direct)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(p_new)):
            break
        quad, lin = _sections(p_new)
        if stable:
            quad, lin, fl = _reflect(quad, lin)
            flipped_any += fl
        coefs, errs = residue_fit(quad, lin)
        e = float(np.sqrt(np.mean(errs**2)))
        history.append(e)
        if e < best[0]:
            best = (e, quad, lin, coefs, errs)
            since_best = 0
        else:
            since_best += 1
        if e <= _ERROR_FLOOR or abs(history[-2] - e) <= _VF_SETTLED * e:
            converged = True
            break
        if since_best >= _VF_PATIENCE:  # oscillating (noisy data, flipped poles): keep the best
            break
    _, quad, lin, _, _ = best
    quad, lin, notes = _split_repeated(quad, lin)
    coefs, errs = residue_fit(quad, lin)
    n = n_poles
    p_n = _poles(quad, lin)
    w0 = 2 * np.pi * f0
    res = np.zeros((n, p_out, m_in), dtype=complex)
    D = np.zeros((p_out, m_in))
    for o, i in pairs:
        res[:, o, i] = _section_residues(quad, lin, coefs[o, i]) * scale[o, i] * w0
        if direct:
            D[o, i] = coefs[o, i, n] * scale[o, i]
    poles, res = _order_poles(p_n * w0, res)
    fit_H = _pole_residue_response(f_u, poles, res, D)
    num = np.sum(W * np.abs(Hd - fit_H) ** 2, axis=-1)
    fit_error = np.where(norm2 > 0, np.sqrt(num / np.where(norm2 > 0, norm2, 1.0)), 0.0)
    if flipped_any:
        notes.append(f"{len(flipped_any)} unstable poles flipped during the pole relocation")
    settings = {"n_poles": n_poles, "n_iter": n_iter, "direct": direct, "stable": stable,
                "f0_hz": f0, "pair_scale": scale.copy(), "n_used": int(f_u.size)}
    return VfFit(poles=poles, residues=res, direct=D, fit_error=fit_error,
                 fit_error_total=float(np.sqrt(np.mean(fit_error**2))), iterations=it,
                 converged=converged, history=tuple(history), settings=settings, notes=tuple(notes))


def _vf_relocate(s, Y, sw, pairs, quad, lin, direct):
    """One relaxed pole relocation of vector fitting: the new poles (normalized)."""
    phi = _basis(s, quad, lin)
    n = phi.shape[1]
    M = np.hstack([phi, np.ones((s.size, 1))]) if direct else phi
    q1 = M.shape[1]

    def reduced(o, i):
        """Rows of the pair's equations with its residues eliminated (QR), for [c, d]."""
        w = sw[o, i][:, None]
        y = Y[o, i][:, None]
        return np.linalg.qr(_stack(np.hstack([w * M, -w * y * phi, -w * y])), mode="r")[q1:, q1:]

    R = [reduced(o, i) for o, i in pairs]
    total = np.sqrt(sum(float(np.sum((sw[o, i] * np.abs(Y[o, i])) ** 2)) for o, i in pairs))
    row_scale = total / s.size
    relax = row_scale * np.concatenate([np.sum(phi, axis=0).real, [s.size]])
    A_all = np.vstack(R + [relax[None, :]])
    b_all = np.zeros(A_all.shape[0])
    b_all[-1] = row_scale * s.size
    x, _ = _lstsq(A_all, b_all)
    if abs(x[-1]) >= 1e-8:
        return _sigma_zeros(quad, lin, x[:n], x[-1])
    # non-relaxed: sigma = 1 + sum c phi; the d column goes to the right-hand side. The
    # triangular rows of [c, d] give those of [c | -d] directly (same QR, last column moved).
    A_nr = np.vstack([r[:n, :n] for r in R])
    b_nr = np.concatenate([-r[:n, n] for r in R])
    x, _ = _lstsq(A_nr, b_nr)
    return _sigma_zeros(quad, lin, x, 1.0)
