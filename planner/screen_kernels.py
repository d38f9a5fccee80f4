"""Compiled kernels of the frequency-domain screening: numba, one caller (:mod:`planner.screen`).

The per-setup work of :func:`planner.screen.screen_packed`: the fixed point on the
shock-velocity RMS (the stochastic linearization, see :mod:`planner.screen`), the
band features of the loop correction at it, and the metrics as a linear form of
those features. Two kernels give the same numbers bit for bit:

- :func:`screen_batch`, vectorized over bands (straight-line 4x4 complex algebra
  per band, laid out by :func:`band_operands`), for large batches;
- :func:`screen_batch_scalar`, one band after the other, which compiles in a
  fraction of the time, for small ones.

:func:`metric_form` builds the setup-independent linear form both apply (:func:`metric_blocks`
lays it out for the vectorized kernel's metrics pass, generated code). Both kernels take
their arguments grouped in named tuples, packed by :mod:`planner.screen`:
:class:`BandData` (the plant's band data), :class:`ShockTables` and :class:`StopTables`
(the setups' shocks and bump stops), :class:`TravelData` (the stops' setup-independent
operands), :class:`IterSettings` (the fixed point's) and :class:`ScreenOutputs` (written in
place); the two share the fixed point's start, step and finish (:func:`_start`,
:func:`_step`, :func:`_finish`) and differ only in their band loops. These public names
serve :mod:`planner.screen`, their one caller; everything else here is private to the
kernels. The straight-line band inverse, :func:`_band_inverse`,
is generated code: its block is written by :mod:`planner.screen_codegen`
(``python -m planner.screen_codegen --write``) and checked by ``tests/test_screen.py``.

numba caches the compiled kernels per source file (``cache=True``): editing this
file recompiles them on first use (the vectorized kernel takes 30-40 s).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

__all__ = [
    "STOP_ROWS",
    "BandData",
    "IterSettings",
    "ScreenOutputs",
    "ShockTables",
    "StopTables",
    "TravelData",
    "band_operands",
    "gaussian_pwl",
    "metric_blocks",
    "metric_form",
    "padded_bands",
    "screen_batch",
    "solve4",
    "screen_batch_scalar",
]

_SQRT2 = math.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
#: Rows of the kernels' per-setup element output ``trav`` (n_setups, len(STOP_ROWS), 4):
#: the linearized travel RMS [m], the mean travel [m], the bump stops' equivalent
#: stiffness [N/m] and mean force [N], the shocks' equivalent damping [N s/m] and mean
#: force [N]. In a setup without any stop the travel rows and the shocks' mean force are
#: zero (not computed); the stops' rows are zero at a corner without one.
STOP_ROWS = ("travel_rms", "travel_mean", "stop_stiffness", "stop_force_mean",
             "shock_damping", "shock_force_mean")
#: Newton iterations on the mean travel (:func:`_stop_means`) and their tolerance [m]: the
#: mean travel solves a smooth monotone 4x4 system, converged in 3-6 steps from the last
#: iterate's mean.
_MEAN_MAX_ITER = 50
_MEAN_TOL_M = 1e-12
#: Rows of a setup's state ``st`` (_NST, 4) in the kernels: the fixed point on the velocity
#: RMS (its iterate [m/s], the equivalent damping [N s/m], the band sum of the velocity
#: power [(m/s)^2], the secant's last iterate and residual) and the elements' part (the
#: travel RMS [m], the stops' k_eq [N/m] and mean force [N], the mean travel [m], the
#: shocks' mean force [N], the travel RMS's secant state, the band sum of the travel power
#: [m^2], and a Newton step's scratch).
(_ST_SIG, _ST_CEQ, _ST_SVV, _ST_SPREV, _ST_HPREV, _ST_SIGS, _ST_KEQ, _ST_EG, _ST_MU, _ST_EF,
 _ST_SSPREV, _ST_HSPREV, _ST_SSS, _ST_R) = range(14)
_NST = 14


class BandData(NamedTuple):
    """The plant's band data: what the kernels need of the model and drive (no setup changes it).

    Packed once per call by :mod:`planner.screen` from its
    :class:`~planner.screen.ScreenOperands`. Each kernel reads the loop's operands in its
    own layout: :func:`screen_batch` in ``blocks``, :func:`screen_batch_scalar` in ``Hvs``,
    ``P``, ``PB``.

    Attributes
    ----------
    w : ndarray, shape (n_bands,)
        Band centres [rad/s].
    Hvs : ndarray of complex, shape (n_bands, 4, 4)
        Shock velocities per unit shock force change dF [m/s per N].
    P, PB : ndarray of complex, shape (n_bands, 4, 4)
        Band power of the shock velocities from the rig inputs [(m/s)^2], unweighted and
        weighted by the metric filter.
    blocks : ndarray, shape (n_blocks * 96 * 16,)
        ``-Hvs``, ``P`` and ``PB`` in blocks of 16 bands (:func:`band_operands`).
    F : ndarray, shape (n_bands, 48, n_padded)
        The metrics' band power as a linear form of the band features
        (:func:`metric_form`), the metrics padded with zero columns to a multiple of 4.
    d0 : ndarray, shape (n_bands, n_metrics)
        Weighted metric power with the shock loop open (dF = 0) [SI unit of the metric,
        squared].
    Fq, d0q : ndarray, shape (n_groups, n_blocks * 48 * 3 * 16) and (n_groups, n_blocks * 3 * 16)
        ``F`` and ``d0`` in the layout of :func:`screen_batch`'s metrics pass
        (:func:`metric_blocks`).
    wpad : ndarray, shape (n_blocks * 16,)
        ``w`` padded with zeros to whole blocks (:func:`padded_bands`).
    cbar : ndarray, shape (4,)
        The plant's built-in damping [N s/m] (writable: a read-only array is another numba
        type, which would compile the kernels again).
    sig0 : ndarray, shape (4,)
        Starting shock-velocity RMS of the fixed point [m/s].
    """

    w: np.ndarray
    Hvs: np.ndarray
    P: np.ndarray
    PB: np.ndarray
    blocks: np.ndarray
    F: np.ndarray
    d0: np.ndarray
    cbar: np.ndarray
    sig0: np.ndarray
    Fq: np.ndarray
    d0q: np.ndarray
    wpad: np.ndarray


class ShockTables(NamedTuple):
    """The setups' shocks as packed curves (:func:`ident.sim.closedloop.pack_setups`).

    The batch kernels take every setup's (the shapes below); the per-setup ones one row of
    each (the leading axis dropped).

    Attributes
    ----------
    kv, kf : ndarray, shape (n_setups, 4, n_knots)
        Knot velocities [m/s] and forces [N] per setup and corner, padded past ``nk``
        (padding never read).
    nk : ndarray of int, shape (n_setups, 4)
        Knots in use.
    slo, shi : ndarray, shape (n_setups, 4)
        Slopes below the first and above the last knot [N s/m].
    lag : ndarray, shape (n_setups, 4)
        Shock lags [s].
    """

    kv: np.ndarray
    kf: np.ndarray
    nk: np.ndarray
    slo: np.ndarray
    shi: np.ndarray
    lag: np.ndarray


class TravelData(NamedTuple):
    """What the bump stops need of the model and drive (setup-independent; zeros without any
    stop), from :class:`planner.screen.ElementOperands`.

    Attributes
    ----------
    jinv : ndarray, shape (n_blocks * 16,)
        ``-1 / w`` per band [s/rad], padded with zeros to whole blocks (:func:`padded_bands`):
        the travel ``s = v / (j w)`` the stops' equivalent stiffness acts on.
    w2inv : ndarray, shape (n_bands,)
        ``1 / w^2`` per band [s^2/rad^2]: the travel power from the velocity power.
    gain : ndarray, shape (4, 4)
        Static shock travel per unit dF [m/N].
    static : ndarray, shape (4,)
        Static shock travel of the drive's mean rig inputs [m].
    rms0 : ndarray, shape (4,)
        Starting travel RMS of the fixed point [m].
    """

    jinv: np.ndarray
    w2inv: np.ndarray
    gain: np.ndarray
    static: np.ndarray
    rms0: np.ndarray


class StopTables(NamedTuple):
    """The setups' bump stops as :func:`ident.sim.closedloop.pack_bump_stops` packs them.

    The batch kernels take every setup's (the shapes below); the per-setup ones one row of
    each (the leading axis dropped).

    Attributes
    ----------
    on : ndarray of int, shape (n_setups, 4)
        Nonzero where a corner has a stop.
    s0 : ndarray, shape (n_setups, 4)
        Contact travel [m].
    bx, bf : ndarray, shape (n_setups, 4, n_points)
        The stop's table: travel beyond contact [m] and force [N], padded with the last point.
    bn : ndarray of int, shape (n_setups, 4)
        Points in use.
    bslope : ndarray, shape (n_setups, 4)
        Slope beyond the table [N/m].
    """

    on: np.ndarray
    s0: np.ndarray
    bx: np.ndarray
    bf: np.ndarray
    bn: np.ndarray
    bslope: np.ndarray


class IterSettings(NamedTuple):
    """The fixed point's settings.

    Attributes
    ----------
    max_iter : int
        Iterations at most.
    tol : float
        Relative change of every RMS (velocity, and travel with stops) below which it stops.
    """

    max_iter: int
    tol: float


class ScreenOutputs(NamedTuple):
    """The kernels' outputs, written in place (allocated by the caller, zeros).

    Attributes
    ----------
    metrics : ndarray, shape (n_setups, n_metrics)
        The metrics [SI].
    sigma : ndarray, shape (n_setups, 4)
        Linearized shock-velocity RMS [m/s].
    iterations : ndarray of int, shape (n_setups,)
        Fixed-point iterations taken.
    elements : ndarray, shape (n_setups, len(STOP_ROWS), 4)
        The element rows (:data:`STOP_ROWS`).
    """

    metrics: np.ndarray
    sigma: np.ndarray
    iterations: np.ndarray
    elements: np.ndarray


@nb.njit(cache=True, error_model="numpy")
def solve4(J, r):
    """r <- J^-1 r (4x4 real, Gauss elimination with partial pivoting; J destroyed).

    Parameters
    ----------
    J : ndarray, shape (4, 4)
        The matrix; overwritten.
    r : ndarray, shape (4,)
        The right-hand side; overwritten with the solution.
    """
    for c in range(4):
        p = c
        for i in range(c + 1, 4):
            if abs(J[i, c]) > abs(J[p, c]):
                p = i
        if p != c:
            for j in range(4):
                t = J[c, j]
                J[c, j] = J[p, j]
                J[p, j] = t
            t = r[c]
            r[c] = r[p]
            r[p] = t
        for i in range(c + 1, 4):
            m = J[i, c] / J[c, c]
            for j in range(c, 4):
                J[i, j] -= m * J[c, j]
            r[i] -= m * r[c]
    for c in range(3, -1, -1):
        acc = r[c]
        for j in range(c + 1, 4):
            acc -= J[c, j] * r[j]
        r[c] = acc / J[c, c]


@nb.njit(cache=True, error_model="numpy")
def gaussian_pwl(mu, sig, x0, x, f, n, slo, shi):
    """Gaussian expectations of a piecewise-linear function and of its slope, in closed form.

    Parameters
    ----------
    mu, sig : float
        Mean and standard deviation of ``X ~ N(mu, sig^2)`` (``sig`` floored at 1e-15).
    x0 : float
        Offset of the knots (a bump stop's contact travel; 0 for a shock curve).
    x, f : ndarray, shape (>= n,)
        Knots ``x0 + x[i]`` (strictly increasing) and values ``f[i]``, ``i < n`` (n >= 1).
    n : int
        Knots in use.
    slo, shi : float
        Slopes below the first and above the last knot.

    Returns
    -------
    (float, float)
        ``E[g(X)]`` and ``E[g'(X)]``: per segment ``[a, b]`` with ``g = f_i + k_i (X - a)``,
        ``f_i dPhi + k_i sig (phi(alpha) - phi(beta) - alpha dPhi)`` and ``k_i dPhi``
        (``alpha, beta`` the standardized ends, ``dPhi`` the segment's probability).

    Examples
    --------
    >>> import numpy as np
    >>> e, k = gaussian_pwl(0.0, 1.0, 0.0, np.array([0.0]), np.array([0.0]), 1, 0.0, 1.0)
    >>> round(e, 12), k  # E[max(X, 0)] = 1 / sqrt(2 pi); P(X > 0) = 1/2
    (0.398942280401, 0.5)
    """
    if not sig > 1e-15:
        sig = 1e-15
    a = (x0 + x[0] - mu) / sig
    Pa = 0.5 * math.erfc(-a / _SQRT2)
    pa = _INV_SQRT_2PI * math.exp(-0.5 * a * a)
    # below the first knot: g = f0 + slo (X - x_0); int_-inf^a (z - a) phi = -phi(a) - a Phi(a)
    eg = f[0] * Pa + slo * sig * (-pa - a * Pa)
    ek = slo * Pa
    for i in range(n - 1):
        b = (x0 + x[i + 1] - mu) / sig
        Pb = 0.5 * math.erfc(-b / _SQRT2)
        pb = _INV_SQRT_2PI * math.exp(-0.5 * b * b)
        k = (f[i + 1] - f[i]) / (x[i + 1] - x[i])
        dP = Pb - Pa
        eg += f[i] * dP + k * sig * (pa - pb - a * dP)
        ek += k * dP
        a, Pa, pa = b, Pb, pb
    Qa = 0.5 * math.erfc(a / _SQRT2)  # the upper tail without cancellation
    eg += f[n - 1] * Qa + shi * sig * (pa - a * Qa)
    ek += shi * Qa
    return eg, ek


@nb.njit(cache=True, error_model="numpy")
def _stop_means(st, shock, stop, travel, J):
    """The mean travel and the bump stops' linearization at the current RMS (in place).

    The mean travel ``mu`` solves ``mu = mu_rig + Hs0 (E[f_shock(v)] + E[g(s)])`` (the
    static point moved by the mean forces: the shocks' at the zero-mean Gaussian velocity,
    the stops' at ``s ~ N(mu, sigs^2)``) by Newton's method from the given ``mu`` (Jacobian
    ``I - Hs0 diag(k_eq)``: k_eq >= 0 and Hs0 a compliance, so the system is monotone);
    then ``keq = E[g'(s)]`` and ``eg = E[g(s)]`` at the solution (zero without a stop), ``ef``
    the shocks' mean forces. st: the setup's state (rows ``_ST_*``), shock and stop: one
    setup's :class:`ShockTables` and :class:`StopTables`, travel: :class:`TravelData`;
    J (4, 4) is scratch (and the state's row ``r``).
    """
    sigv, sigs, keq, eg, mu, ef, r = (st[_ST_SIG], st[_ST_SIGS], st[_ST_KEQ], st[_ST_EG],
                                      st[_ST_MU], st[_ST_EF], st[_ST_R])
    kv, kf, nk, slo, shi = shock.kv, shock.kf, shock.nk, shock.slo, shock.shi
    son, s0, bx, bf, bn, bslope = stop.on, stop.s0, stop.bx, stop.bf, stop.bn, stop.bslope
    Hs0, mu_rig = travel.gain, travel.static
    for c in range(4):
        ef[c] = gaussian_pwl(0.0, sigv[c], 0.0, kv[c], kf[c], nk[c], slo[c], shi[c])[0]
    for _ in range(_MEAN_MAX_ITER):
        for c in range(4):
            if son[c]:
                eg[c], keq[c] = gaussian_pwl(mu[c], sigs[c], s0[c], bx[c], bf[c], bn[c], 0.0,
                                             bslope[c])
            else:
                eg[c] = 0.0
                keq[c] = 0.0
        step = 0.0
        for a in range(4):
            acc = mu_rig[a]
            for b in range(4):
                acc += Hs0[a, b] * (ef[b] + eg[b])
                J[a, b] = -Hs0[a, b] * keq[b]
            J[a, a] += 1.0
            r[a] = acc - mu[a]  # mu_new - mu = J^-1 r
        solve4(J, r)  # r <- J^-1 r
        for c in range(4):
            mu[c] += r[c]
            step = max(step, abs(r[c]))
        if step < _MEAN_TOL_M:
            break
    for c in range(4):
        if son[c]:
            eg[c], keq[c] = gaussian_pwl(mu[c], sigs[c], s0[c], bx[c], bf[c], bn[c], 0.0,
                                         bslope[c])


@nb.njit(cache=True, error_model="numpy")
def _secant(sig, new, s_prev, h_prev, c, it):
    """The fixed point's step on one RMS (``sig[c]`` <- next), as the shocks' inline code:
    ``new = g(sig)``, a secant step on ``h = g(sig) - sig`` once two iterates exist
    (safeguarded to a factor 2). Returns the relative change."""
    change = abs(new - sig[c]) / max(sig[c], 1e-12)
    hc = new - sig[c]
    nxt = new if new > 0 else 0.5 * sig[c]
    if it > 0:
        dh = hc - h_prev[c]
        ds = sig[c] - s_prev[c]
        if dh != 0.0 and ds != 0.0:
            cand = sig[c] - hc * ds / dh
            if 0.5 * sig[c] < cand < 2.0 * sig[c]:
                nxt = cand
    s_prev[c] = sig[c]
    h_prev[c] = hc
    sig[c] = nxt
    return change


@nb.njit(cache=True, error_model="numpy", inline="always")
def _ceq(sig, kv, kf, nk, slo, shi):
    """Equivalent damping of a PWL curve for a zero-mean Gaussian velocity of RMS sig."""
    if sig <= 0.0:
        sig = 1e-9
    acc = 0.0
    lo_cdf = 0.0
    for seg in range(nk + 1):
        if seg < nk:
            hi_cdf = 0.5 * (1.0 + math.erf(kv[seg] / (sig * _SQRT2)))
        else:
            hi_cdf = 1.0
        if seg == 0:
            s = slo
        elif seg == nk:
            s = shi
        else:
            s = (kf[seg] - kf[seg - 1]) / (kv[seg] - kv[seg - 1])
        acc += s * (hi_cdf - lo_cdf)
        lo_cdf = hi_cdf
    return acc


#: Index pairs (a, b), a < b, of the upper triangle of a 4x4 Hermitian matrix, in the order
#: the packed operands (:func:`metric_form`) and the kernel agree on.
_PAIRS_A = np.array([0, 0, 0, 1, 1, 2])
_PAIRS_B = np.array([1, 2, 3, 2, 3, 3])
#: Features of one band's loop correction that a metric's band power is linear in: the
#: real diagonal of R = E PB E^H (4), the real and imaginary parts of its upper triangle
#: (6 + 6) and of E = diag(D) K (16 + 16).
_NFEAT = 48
#: Bands per block of the fixed point's band loop (:func:`_screen_one`): a compile-time
#: stride, so that LLVM sees the operands of a block at constant offsets and vectorizes the
#: loop (16: its minimum trip count for a loop with run-time alias checks).
_BK = 16
#: Setups whose metrics are taken together (:func:`_metrics_of`: one pass over F per group).
_GROUP = 8
#: Metrics per group of the metrics' pass (:func:`_metrics_of`, :func:`metric_blocks`).
_MQ = 3


@nb.njit(cache=True, error_model="numpy", inline="always")
def _loop_inverse(Hv, D, A, perm):
    """A <- (I - Hv diag(D))^-1 for one band (4x4, in place Gauss-Jordan, partial pivoting).

    Hv (4, 4) are the velocity responses to dF, D the shocks' linearized damping minus
    c_bar (complex, with the lag); perm (4,) is scratch. A screen-local routine rather than
    ``ident.sim.loop_kernels.invert_small``: in place (64 complex multiply-adds instead of 128:
    the identity's zeros and ones are never multiplied) and pivots chosen by ``|z|^2``
    (no ``hypot``), but the same pivots and the same floating-point operations on the
    entries that matter, so the inverse is bit for bit the general routine's. That matters:
    the fixed point's secant step amplifies any round-off change (see :func:`_screen_one`).
    """
    for a in range(4):
        for b in range(4):
            A[a, b] = -Hv[a, b] * D[b]
        A[a, a] += 1.0
    for c in range(4):
        p = c
        big = A[c, c].real * A[c, c].real + A[c, c].imag * A[c, c].imag
        for i in range(c + 1, 4):
            m2 = A[i, c].real * A[i, c].real + A[i, c].imag * A[i, c].imag
            if m2 > big:
                big = m2
                p = i
        perm[c] = p
        if p != c:
            for j in range(4):
                t = A[c, j]
                A[c, j] = A[p, j]
                A[p, j] = t
        d = 1.0 / A[c, c]
        A[c, c] = 1.0
        for j in range(4):
            A[c, j] *= d
        for i in range(4):
            if i != c:
                f = A[i, c]
                A[i, c] = 0.0
                for j in range(4):
                    A[i, j] -= f * A[c, j]
    # the row interchanges become column interchanges of the inverse, undone in reverse
    for c in range(3, -1, -1):
        p = perm[c]
        if p != c:
            for i in range(4):
                t = A[i, c]
                A[i, c] = A[i, p]
                A[i, p] = t


@nb.njit(cache=True, error_model="numpy", inline="always")
def _recip(z):
    """``1.0 / z`` as numba's complex division computes it (CPython's algorithm): both
    branches' operations computed, one selected, so that the band loop around it has no
    branches (and vectorizes). A zero z gives NaN instead of raising ZeroDivisionError."""
    br = z.real
    bi = z.imag
    cond = abs(br) >= abs(bi)
    num = bi if cond else br
    den = br if cond else bi
    ratio = num / den
    dn1 = br + bi * ratio
    dn2 = br * ratio + bi
    re1 = 1.0 + 0.0 * ratio
    re2 = 1.0 * ratio + 0.0
    im1 = 0.0 - 1.0 * ratio
    im2 = 0.0 * ratio - 1.0
    denom = dn1 if cond else dn2
    re = re1 if cond else re2
    im = im1 if cond else im2
    return complex(re / denom, im / denom)


@nb.njit(cache=True, error_model="numpy", inline="always")
def _over_roll(x, cond, ratio, denom):
    """``x / roll`` (x real) as numba's complex division computes it, with the divisor's
    branch, ``ratio`` and ``denom`` precomputed (:func:`_screen_one`); no branches."""
    re1 = x + 0.0 * ratio
    re2 = x * ratio + 0.0
    im1 = 0.0 - x * ratio
    im2 = 0.0 * ratio - x
    re = re1 if cond else re2
    im = im1 if cond else im2
    return complex(re / denom, im / denom)


# BEGIN GENERATED CODE by planner.screen_codegen (python -m planner.screen_codegen --write)
@nb.njit(cache=True, error_model="numpy", inline="always")
def _band_inverse(h, d0, d1, d2, d3):
    """K = (I - Hv diag(D))^-1 of band k, straight-line (Gauss-Jordan, partial pivoting).

    Generated code (:mod:`planner.screen_codegen`): the same operations, in the same order, as
    :func:`_loop_inverse` (pivots by ``|z|^2``, row interchanges, in-place elimination,
    column interchanges undone in reverse), with the 16 entries held in scalars and the
    row and column interchanges written as selects, so that a loop over bands around it
    has no branches and no scratch memory and LLVM vectorizes it over bands. h: the 16
    entries of ``-Hv`` (row-major), loaded by :func:`_screen_one` (scalars only: an array
    passed to an inlined function costs reference counting, which stops vectorization).
    """
    a00 = h[0] * d0
    a01 = h[1] * d1
    a02 = h[2] * d2
    a03 = h[3] * d3
    a00 = complex(a00.real + 1.0, a00.imag + 0.0)
    a10 = h[4] * d0
    a11 = h[5] * d1
    a12 = h[6] * d2
    a13 = h[7] * d3
    a11 = complex(a11.real + 1.0, a11.imag + 0.0)
    a20 = h[8] * d0
    a21 = h[9] * d1
    a22 = h[10] * d2
    a23 = h[11] * d3
    a22 = complex(a22.real + 1.0, a22.imag + 0.0)
    a30 = h[12] * d0
    a31 = h[13] * d1
    a32 = h[14] * d2
    a33 = h[15] * d3
    a33 = complex(a33.real + 1.0, a33.imag + 0.0)
    # column 0
    big = a00.real * a00.real + a00.imag * a00.imag
    p0 = 0
    m2 = a10.real * a10.real + a10.imag * a10.imag
    up = m2 > big
    big = m2 if up else big
    p0 = 1 if up else p0
    m2 = a20.real * a20.real + a20.imag * a20.imag
    up = m2 > big
    big = m2 if up else big
    p0 = 2 if up else p0
    m2 = a30.real * a30.real + a30.imag * a30.imag
    up = m2 > big
    big = m2 if up else big
    p0 = 3 if up else p0
    s = p0 == 1
    t = a00
    a00 = a10 if s else a00
    a10 = t if s else a10
    t = a01
    a01 = a11 if s else a01
    a11 = t if s else a11
    t = a02
    a02 = a12 if s else a02
    a12 = t if s else a12
    t = a03
    a03 = a13 if s else a03
    a13 = t if s else a13
    s = p0 == 2
    t = a00
    a00 = a20 if s else a00
    a20 = t if s else a20
    t = a01
    a01 = a21 if s else a01
    a21 = t if s else a21
    t = a02
    a02 = a22 if s else a02
    a22 = t if s else a22
    t = a03
    a03 = a23 if s else a03
    a23 = t if s else a23
    s = p0 == 3
    t = a00
    a00 = a30 if s else a00
    a30 = t if s else a30
    t = a01
    a01 = a31 if s else a01
    a31 = t if s else a31
    t = a02
    a02 = a32 if s else a02
    a32 = t if s else a32
    t = a03
    a03 = a33 if s else a03
    a33 = t if s else a33
    dd = _recip(a00)
    a00 = 1.0 + 0j
    a00 = a00 * dd
    a01 = a01 * dd
    a02 = a02 * dd
    a03 = a03 * dd
    f = a10
    a10 = 0j
    a10 = a10 - f * a00
    a11 = a11 - f * a01
    a12 = a12 - f * a02
    a13 = a13 - f * a03
    f = a20
    a20 = 0j
    a20 = a20 - f * a00
    a21 = a21 - f * a01
    a22 = a22 - f * a02
    a23 = a23 - f * a03
    f = a30
    a30 = 0j
    a30 = a30 - f * a00
    a31 = a31 - f * a01
    a32 = a32 - f * a02
    a33 = a33 - f * a03
    # column 1
    big = a11.real * a11.real + a11.imag * a11.imag
    p1 = 1
    m2 = a21.real * a21.real + a21.imag * a21.imag
    up = m2 > big
    big = m2 if up else big
    p1 = 2 if up else p1
    m2 = a31.real * a31.real + a31.imag * a31.imag
    up = m2 > big
    big = m2 if up else big
    p1 = 3 if up else p1
    s = p1 == 2
    t = a10
    a10 = a20 if s else a10
    a20 = t if s else a20
    t = a11
    a11 = a21 if s else a11
    a21 = t if s else a21
    t = a12
    a12 = a22 if s else a12
    a22 = t if s else a22
    t = a13
    a13 = a23 if s else a13
    a23 = t if s else a23
    s = p1 == 3
    t = a10
    a10 = a30 if s else a10
    a30 = t if s else a30
    t = a11
    a11 = a31 if s else a11
    a31 = t if s else a31
    t = a12
    a12 = a32 if s else a12
    a32 = t if s else a32
    t = a13
    a13 = a33 if s else a13
    a33 = t if s else a33
    dd = _recip(a11)
    a11 = 1.0 + 0j
    a10 = a10 * dd
    a11 = a11 * dd
    a12 = a12 * dd
    a13 = a13 * dd
    f = a01
    a01 = 0j
    a00 = a00 - f * a10
    a01 = a01 - f * a11
    a02 = a02 - f * a12
    a03 = a03 - f * a13
    f = a21
    a21 = 0j
    a20 = a20 - f * a10
    a21 = a21 - f * a11
    a22 = a22 - f * a12
    a23 = a23 - f * a13
    f = a31
    a31 = 0j
    a30 = a30 - f * a10
    a31 = a31 - f * a11
    a32 = a32 - f * a12
    a33 = a33 - f * a13
    # column 2
    big = a22.real * a22.real + a22.imag * a22.imag
    p2 = 2
    m2 = a32.real * a32.real + a32.imag * a32.imag
    up = m2 > big
    big = m2 if up else big
    p2 = 3 if up else p2
    s = p2 == 3
    t = a20
    a20 = a30 if s else a20
    a30 = t if s else a30
    t = a21
    a21 = a31 if s else a21
    a31 = t if s else a31
    t = a22
    a22 = a32 if s else a22
    a32 = t if s else a32
    t = a23
    a23 = a33 if s else a23
    a33 = t if s else a33
    dd = _recip(a22)
    a22 = 1.0 + 0j
    a20 = a20 * dd
    a21 = a21 * dd
    a22 = a22 * dd
    a23 = a23 * dd
    f = a02
    a02 = 0j
    a00 = a00 - f * a20
    a01 = a01 - f * a21
    a02 = a02 - f * a22
    a03 = a03 - f * a23
    f = a12
    a12 = 0j
    a10 = a10 - f * a20
    a11 = a11 - f * a21
    a12 = a12 - f * a22
    a13 = a13 - f * a23
    f = a32
    a32 = 0j
    a30 = a30 - f * a20
    a31 = a31 - f * a21
    a32 = a32 - f * a22
    a33 = a33 - f * a23
    # column 3 (its pivot is the last row: nothing to compare)
    dd = _recip(a33)
    a33 = 1.0 + 0j
    a30 = a30 * dd
    a31 = a31 * dd
    a32 = a32 * dd
    a33 = a33 * dd
    f = a03
    a03 = 0j
    a00 = a00 - f * a30
    a01 = a01 - f * a31
    a02 = a02 - f * a32
    a03 = a03 - f * a33
    f = a13
    a13 = 0j
    a10 = a10 - f * a30
    a11 = a11 - f * a31
    a12 = a12 - f * a32
    a13 = a13 - f * a33
    f = a23
    a23 = 0j
    a20 = a20 - f * a30
    a21 = a21 - f * a31
    a22 = a22 - f * a32
    a23 = a23 - f * a33
    # the row interchanges become column interchanges of the inverse, undone in reverse
    s = p2 == 3
    t = a02
    a02 = a03 if s else a02
    a03 = t if s else a03
    t = a12
    a12 = a13 if s else a12
    a13 = t if s else a13
    t = a22
    a22 = a23 if s else a22
    a23 = t if s else a23
    t = a32
    a32 = a33 if s else a32
    a33 = t if s else a33
    s = p1 == 2
    t = a01
    a01 = a02 if s else a01
    a02 = t if s else a02
    t = a11
    a11 = a12 if s else a11
    a12 = t if s else a12
    t = a21
    a21 = a22 if s else a21
    a22 = t if s else a22
    t = a31
    a31 = a32 if s else a31
    a32 = t if s else a32
    s = p1 == 3
    t = a01
    a01 = a03 if s else a01
    a03 = t if s else a03
    t = a11
    a11 = a13 if s else a11
    a13 = t if s else a13
    t = a21
    a21 = a23 if s else a21
    a23 = t if s else a23
    t = a31
    a31 = a33 if s else a31
    a33 = t if s else a33
    s = p0 == 1
    t = a00
    a00 = a01 if s else a00
    a01 = t if s else a01
    t = a10
    a10 = a11 if s else a10
    a11 = t if s else a11
    t = a20
    a20 = a21 if s else a20
    a21 = t if s else a21
    t = a30
    a30 = a31 if s else a30
    a31 = t if s else a31
    s = p0 == 2
    t = a00
    a00 = a02 if s else a00
    a02 = t if s else a02
    t = a10
    a10 = a12 if s else a10
    a12 = t if s else a12
    t = a20
    a20 = a22 if s else a20
    a22 = t if s else a22
    t = a30
    a30 = a32 if s else a30
    a32 = t if s else a32
    s = p0 == 3
    t = a00
    a00 = a03 if s else a00
    a03 = t if s else a03
    t = a10
    a10 = a13 if s else a10
    a13 = t if s else a13
    t = a20
    a20 = a23 if s else a20
    a23 = t if s else a23
    t = a30
    a30 = a33 if s else a30
    a33 = t if s else a33
    return (a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23, a30, a31, a32, a33)
# END GENERATED CODE by planner.screen_codegen


@nb.njit(cache=True, error_model="numpy", inline="always")
def _band_svv(a0, a1, a2, a3, P):
    """``sum_ab Re(K_ca P_ab conj(K_cb))`` for one row (a0..a3) of K in band k, in the
    order of the reference (a outer, b inner), written out; P: its 16 entries (row-major)."""
    acc = 0.0
    acc += (a0 * P[0] * np.conj(a0)).real
    acc += (a0 * P[1] * np.conj(a1)).real
    acc += (a0 * P[2] * np.conj(a2)).real
    acc += (a0 * P[3] * np.conj(a3)).real
    acc += (a1 * P[4] * np.conj(a0)).real
    acc += (a1 * P[5] * np.conj(a1)).real
    acc += (a1 * P[6] * np.conj(a2)).real
    acc += (a1 * P[7] * np.conj(a3)).real
    acc += (a2 * P[8] * np.conj(a0)).real
    acc += (a2 * P[9] * np.conj(a1)).real
    acc += (a2 * P[10] * np.conj(a2)).real
    acc += (a2 * P[11] * np.conj(a3)).real
    acc += (a3 * P[12] * np.conj(a0)).real
    acc += (a3 * P[13] * np.conj(a1)).real
    acc += (a3 * P[14] * np.conj(a2)).real
    acc += (a3 * P[15] * np.conj(a3)).real
    return acc


@nb.njit(cache=True, error_model="numpy", inline="always")
def _band_features(e, pb):
    """The first 16 features of one band (see ``_NFEAT``): the real diagonal of
    ``R = E PB E^H`` and the real and imaginary parts of its upper triangle, with
    ``T = E PB``; e, pb: the 16 entries (row-major) of E and PB. The operations of the
    reference pass, written out (straight-line, vectorized over bands by the caller)."""
    t00 = 0j
    t00 += e[0] * pb[0]
    t00 += e[1] * pb[4]
    t00 += e[2] * pb[8]
    t00 += e[3] * pb[12]
    t01 = 0j
    t01 += e[0] * pb[1]
    t01 += e[1] * pb[5]
    t01 += e[2] * pb[9]
    t01 += e[3] * pb[13]
    t02 = 0j
    t02 += e[0] * pb[2]
    t02 += e[1] * pb[6]
    t02 += e[2] * pb[10]
    t02 += e[3] * pb[14]
    t03 = 0j
    t03 += e[0] * pb[3]
    t03 += e[1] * pb[7]
    t03 += e[2] * pb[11]
    t03 += e[3] * pb[15]
    t10 = 0j
    t10 += e[4] * pb[0]
    t10 += e[5] * pb[4]
    t10 += e[6] * pb[8]
    t10 += e[7] * pb[12]
    t11 = 0j
    t11 += e[4] * pb[1]
    t11 += e[5] * pb[5]
    t11 += e[6] * pb[9]
    t11 += e[7] * pb[13]
    t12 = 0j
    t12 += e[4] * pb[2]
    t12 += e[5] * pb[6]
    t12 += e[6] * pb[10]
    t12 += e[7] * pb[14]
    t13 = 0j
    t13 += e[4] * pb[3]
    t13 += e[5] * pb[7]
    t13 += e[6] * pb[11]
    t13 += e[7] * pb[15]
    t20 = 0j
    t20 += e[8] * pb[0]
    t20 += e[9] * pb[4]
    t20 += e[10] * pb[8]
    t20 += e[11] * pb[12]
    t21 = 0j
    t21 += e[8] * pb[1]
    t21 += e[9] * pb[5]
    t21 += e[10] * pb[9]
    t21 += e[11] * pb[13]
    t22 = 0j
    t22 += e[8] * pb[2]
    t22 += e[9] * pb[6]
    t22 += e[10] * pb[10]
    t22 += e[11] * pb[14]
    t23 = 0j
    t23 += e[8] * pb[3]
    t23 += e[9] * pb[7]
    t23 += e[10] * pb[11]
    t23 += e[11] * pb[15]
    t30 = 0j
    t30 += e[12] * pb[0]
    t30 += e[13] * pb[4]
    t30 += e[14] * pb[8]
    t30 += e[15] * pb[12]
    t31 = 0j
    t31 += e[12] * pb[1]
    t31 += e[13] * pb[5]
    t31 += e[14] * pb[9]
    t31 += e[15] * pb[13]
    t32 = 0j
    t32 += e[12] * pb[2]
    t32 += e[13] * pb[6]
    t32 += e[14] * pb[10]
    t32 += e[15] * pb[14]
    t33 = 0j
    t33 += e[12] * pb[3]
    t33 += e[13] * pb[7]
    t33 += e[14] * pb[11]
    t33 += e[15] * pb[15]
    r0 = 0.0
    r0 += t00.real * e[0].real + t00.imag * e[0].imag
    r0 += t01.real * e[1].real + t01.imag * e[1].imag
    r0 += t02.real * e[2].real + t02.imag * e[2].imag
    r0 += t03.real * e[3].real + t03.imag * e[3].imag
    r1 = 0.0
    r1 += t10.real * e[4].real + t10.imag * e[4].imag
    r1 += t11.real * e[5].real + t11.imag * e[5].imag
    r1 += t12.real * e[6].real + t12.imag * e[6].imag
    r1 += t13.real * e[7].real + t13.imag * e[7].imag
    r2 = 0.0
    r2 += t20.real * e[8].real + t20.imag * e[8].imag
    r2 += t21.real * e[9].real + t21.imag * e[9].imag
    r2 += t22.real * e[10].real + t22.imag * e[10].imag
    r2 += t23.real * e[11].real + t23.imag * e[11].imag
    r3 = 0.0
    r3 += t30.real * e[12].real + t30.imag * e[12].imag
    r3 += t31.real * e[13].real + t31.imag * e[13].imag
    r3 += t32.real * e[14].real + t32.imag * e[14].imag
    r3 += t33.real * e[15].real + t33.imag * e[15].imag
    z0 = 0j
    z0 += t00 * np.conj(e[4])
    z0 += t01 * np.conj(e[5])
    z0 += t02 * np.conj(e[6])
    z0 += t03 * np.conj(e[7])
    z1 = 0j
    z1 += t00 * np.conj(e[8])
    z1 += t01 * np.conj(e[9])
    z1 += t02 * np.conj(e[10])
    z1 += t03 * np.conj(e[11])
    z2 = 0j
    z2 += t00 * np.conj(e[12])
    z2 += t01 * np.conj(e[13])
    z2 += t02 * np.conj(e[14])
    z2 += t03 * np.conj(e[15])
    z3 = 0j
    z3 += t10 * np.conj(e[8])
    z3 += t11 * np.conj(e[9])
    z3 += t12 * np.conj(e[10])
    z3 += t13 * np.conj(e[11])
    z4 = 0j
    z4 += t10 * np.conj(e[12])
    z4 += t11 * np.conj(e[13])
    z4 += t12 * np.conj(e[14])
    z4 += t13 * np.conj(e[15])
    z5 = 0j
    z5 += t20 * np.conj(e[12])
    z5 += t21 * np.conj(e[13])
    z5 += t22 * np.conj(e[14])
    z5 += t23 * np.conj(e[15])
    return (r0, r1, r2, r3, z0.real, z1.real, z2.real, z3.real, z4.real, z5.real,
            z0.imag, z1.imag, z2.imag, z3.imag, z4.imag, z5.imag)


@nb.njit(cache=True, error_model="numpy")
def _shock_row(shocks, s):
    """Setup s's :class:`ShockTables` (views)."""
    return ShockTables(shocks.kv[s], shocks.kf[s], shocks.nk[s], shocks.slo[s], shocks.shi[s],
                       shocks.lag[s])


@nb.njit(cache=True, error_model="numpy")
def _stop_row(stops, s):
    """Setup s's :class:`StopTables` (views)."""
    return StopTables(stops.on[s], stops.s0[s], stops.bx[s], stops.bf[s], stops.bn[s],
                      stops.bslope[s])


@nb.njit(cache=True, error_model="numpy")
def _start(st, sig0, stop, travel):
    """Start a setup's fixed point (state ``st``, rows ``_ST_*``, in place): the velocity
    RMS at ``sig0``, the elements' part at the travel's static point; True when a corner
    has a stop."""
    sig, s_prev, h_prev = st[_ST_SIG], st[_ST_SPREV], st[_ST_HPREV]
    for c in range(4):
        sig[c] = sig0[c]
        s_prev[c] = 0.0
        h_prev[c] = 0.0
    sigs, keq, eg, mu, ef, ss_prev, hs_prev = (st[_ST_SIGS], st[_ST_KEQ], st[_ST_EG],
                                               st[_ST_MU], st[_ST_EF], st[_ST_SSPREV],
                                               st[_ST_HSPREV])
    any_stop = False
    for c in range(4):
        any_stop = any_stop or stop.on[c] != 0
        sigs[c] = travel.rms0[c]
        mu[c] = travel.static[c]
        keq[c] = 0.0
        eg[c] = 0.0
        ef[c] = 0.0
        ss_prev[c] = 0.0
        hs_prev[c] = 0.0
    return any_stop


@nb.njit(cache=True, error_model="numpy")
def _damping(st, shock):
    """The shocks' equivalent damping at the velocity RMS (row ``ceq`` of ``st``)."""
    sig, ceq = st[_ST_SIG], st[_ST_CEQ]
    for c in range(4):
        ceq[c] = _ceq(sig[c], shock.kv[c], shock.kf[c], shock.nk[c], shock.slo[c],
                      shock.shi[c])


@nb.njit(cache=True, error_model="numpy")
def _step(st, any_stop, it):
    """Iteration ``it``'s step of the fixed point ``sigma = g(sigma)`` per corner from the
    band sums (rows ``svv``, ``sss`` of ``st``): :func:`_secant` on the velocity RMS, and on
    the travel RMS with a stop. Returns the largest relative change."""
    sig, svv, s_prev, h_prev = st[_ST_SIG], st[_ST_SVV], st[_ST_SPREV], st[_ST_HPREV]
    change = 0.0
    for c in range(4):
        change = max(change, _secant(sig, math.sqrt(max(svv[c], 0.0)), s_prev, h_prev, c, it))
    if any_stop:
        sigs, sss, ss_prev, hs_prev = st[_ST_SIGS], st[_ST_SSS], st[_ST_SSPREV], st[_ST_HSPREV]
        for c in range(4):
            change = max(change, _secant(sigs, math.sqrt(max(sss[c], 0.0)), ss_prev,
                                         hs_prev, c, it))
    return change


@nb.njit(cache=True, error_model="numpy")
def _finish(any_stop, st, shock, stop, travel, Jm, sig_out, trav_out):
    """The shocks' damping and the stops' linearization at the converged RMS; the velocity
    RMS into ``sig_out`` (4,), the element rows (:data:`STOP_ROWS`) into ``trav_out``."""
    _damping(st, shock)
    for c in range(4):
        sig_out[c] = st[_ST_SIG, c]
    if any_stop:
        _stop_means(st, shock, stop, travel, Jm)
    for c in range(4):
        trav_out[0, c] = st[_ST_SIGS, c] if any_stop else 0.0
        trav_out[1, c] = st[_ST_MU, c] if any_stop else 0.0
        trav_out[2, c] = st[_ST_KEQ, c]
        trav_out[3, c] = st[_ST_EG, c]
        trav_out[4, c] = st[_ST_CEQ, c]
        trav_out[5, c] = st[_ST_EF, c]


@nb.njit(cache=True, error_model="numpy")
def _screen_one(plant, shock, stop, travel, settings, sig_out, trav_out, V, scratch):
    """Screen one setup: the fixed point on the shock-velocity RMS, then its band features.

    plant: :class:`BandData` (``blocks`` read), shock and stop: the setup's
    :class:`ShockTables` and :class:`StopTables` rows, travel: :class:`TravelData`,
    settings: :class:`IterSettings`; ``sig_out`` (4,) receives the velocity RMS, ``trav_out``
    (len(STOP_ROWS), 4) the element rows (:data:`STOP_ROWS`). Returns the iterations taken.

    The fixed point's arithmetic (the loop inverse and the order of the sum
    ``svv[c] = sum_ab Re(K_ca P_ab conj(K_cb))``) is kept as written: the secant step divides
    differences of nearly equal residuals, so a reordered sum (e.g. using P Hermitian) moves
    sigma by up to ~1e-9 relative on some setups. Only where the values live changed: the
    per-band work (:func:`_band_inverse`, :func:`_band_svv`) is straight-line code on scalars
    in a loop over the bands of a block (``_BK`` bands, operands laid out by
    :func:`band_operands`) that LLVM vectorizes over bands (each lane the same operations,
    no fastmath); the bands' sums are then added to ``svv`` in band order. The final pass
    writes the 48 features (``_NFEAT``) of ``E = diag(D) K`` and ``R = E PB E^H`` per band
    into V (vectorized the same way); the metrics are a setup-independent linear form of
    them (:func:`_metrics_of`).

    V (n_blocks * _NFEAT * _BK; out: feature i of band b _BK + j at (b _NFEAT + i) _BK + j)
    and ``scratch = (roll (n_blocks * 12 * _BK), acc (n_blocks * 4 * _BK), st (_NST, 4),
    Jm (4, 4))`` are allocated once per chunk of setups (:func:`screen_batch`); ``st`` holds
    the setup's state (rows ``_ST_*``).

    Bump stops (``stop.on`` (4,) nonzero where a corner has one): the fixed point runs on the
    travel RMS as well (``sigs``, from ``travel.rms0``: the velocity power over ``w^2``,
    ``w2inv``), the mean travel solved at each iterate (:func:`_stop_means`), and each
    corner's loop gain takes ``+ k_eq / (j w)`` (``jinv``: ``-1 / w`` per band in the blocks'
    layout, zero on padding). Without a stop ``k_eq`` is zero and the added
    ``complex(0.0, -0.0)`` leaves every value as it was (bit for bit).
    """
    w, ops, cbar = plant.w, plant.blocks, plant.cbar
    jinv, w2inv = travel.jinv, travel.w2inv
    lag = shock.lag
    max_iter, tol = settings
    roll, acc, st, Jm = scratch
    nf = w.size
    nblk = (nf + _BK - 1) // _BK
    # the lag's roll-off 1 + j w tau per band and corner, the same in every iteration: its
    # complex division's branch and divisor parts (numba's, CPython's algorithm) once per
    # setup, by block: rows c (branch), 4 + c (ratio), 8 + c (denominator); padding bands
    # get a harmless 1
    # (``1.0 + 1j * w * tau`` is exactly ``complex(1.0, w * tau)``; both branches computed
    # and one selected, so that LLVM vectorizes the loop over bands; ``wpad`` is w padded
    # with zeros, giving the padding's harmless 1)
    wpad = plant.wpad
    for blk in range(nblk):
        for c in range(4):
            r = blk * 12 * _BK + c * _BK
            lc = lag[c]
            for j in range(_BK):
                br = 1.0
                bi = wpad[blk * _BK + j] * lc
                cond = abs(br) >= abs(bi)
                num = bi if cond else br
                den = br if cond else bi
                ratio = num / den
                dn1 = br + bi * ratio
                dn2 = br * ratio + bi
                roll[r + j] = 1.0 if cond else 0.0
                roll[r + 4 * _BK + j] = ratio
                roll[r + 8 * _BK + j] = dn1 if cond else dn2
    cb0, cb1, cb2, cb3 = cbar[0], cbar[1], cbar[2], cbar[3]
    ceq, svv, keq, sss = st[_ST_CEQ], st[_ST_SVV], st[_ST_KEQ], st[_ST_SSS]
    any_stop = _start(st, plant.sig0, stop, travel)
    it = 0
    for it in range(max_iter):
        _damping(st, shock)
        for c in range(4):
            svv[c] = 0.0
        if any_stop:
            _stop_means(st, shock, stop, travel, Jm)
        e0, e1, e2, e3 = ceq[0], ceq[1], ceq[2], ceq[3]
        k0, k1, k2, k3 = keq[0], keq[1], keq[2], keq[3]
        for blk in range(nblk):
            ob = blk * 96 * _BK
            rb = blk * 12 * _BK
            ab = blk * 4 * _BK
            jb = blk * _BK
            for j in range(_BK):  # vectorized over bands: no branches, no stores but acc
                r = rb + j
                jk = jinv[jb + j]  # -1 / w: the stop's k_eq on the travel v / (j w)
                D0 = _over_roll(e0, roll[r] > 0.5, roll[r + 4 * _BK], roll[r + 8 * _BK]) - cb0
                D0 = D0 + complex(0.0, k0 * jk)
                r += _BK
                D1 = _over_roll(e1, roll[r] > 0.5, roll[r + 4 * _BK], roll[r + 8 * _BK]) - cb1
                D1 = D1 + complex(0.0, k1 * jk)
                r += _BK
                D2 = _over_roll(e2, roll[r] > 0.5, roll[r + 4 * _BK], roll[r + 8 * _BK]) - cb2
                D2 = D2 + complex(0.0, k2 * jk)
                r += _BK
                D3 = _over_roll(e3, roll[r] > 0.5, roll[r + 4 * _BK], roll[r + 8 * _BK]) - cb3
                D3 = D3 + complex(0.0, k3 * jk)
                o = ob + j
                h = (complex(ops[o + 0 * _BK], ops[o + 16 * _BK]),
                     complex(ops[o + 1 * _BK], ops[o + 17 * _BK]),
                     complex(ops[o + 2 * _BK], ops[o + 18 * _BK]),
                     complex(ops[o + 3 * _BK], ops[o + 19 * _BK]),
                     complex(ops[o + 4 * _BK], ops[o + 20 * _BK]),
                     complex(ops[o + 5 * _BK], ops[o + 21 * _BK]),
                     complex(ops[o + 6 * _BK], ops[o + 22 * _BK]),
                     complex(ops[o + 7 * _BK], ops[o + 23 * _BK]),
                     complex(ops[o + 8 * _BK], ops[o + 24 * _BK]),
                     complex(ops[o + 9 * _BK], ops[o + 25 * _BK]),
                     complex(ops[o + 10 * _BK], ops[o + 26 * _BK]),
                     complex(ops[o + 11 * _BK], ops[o + 27 * _BK]),
                     complex(ops[o + 12 * _BK], ops[o + 28 * _BK]),
                     complex(ops[o + 13 * _BK], ops[o + 29 * _BK]),
                     complex(ops[o + 14 * _BK], ops[o + 30 * _BK]),
                     complex(ops[o + 15 * _BK], ops[o + 31 * _BK]))
                (a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23, a30, a31, a32,
                 a33) = _band_inverse(h, D0, D1, D2, D3)
                P = (complex(ops[o + 32 * _BK], ops[o + 48 * _BK]),
                     complex(ops[o + 33 * _BK], ops[o + 49 * _BK]),
                     complex(ops[o + 34 * _BK], ops[o + 50 * _BK]),
                     complex(ops[o + 35 * _BK], ops[o + 51 * _BK]),
                     complex(ops[o + 36 * _BK], ops[o + 52 * _BK]),
                     complex(ops[o + 37 * _BK], ops[o + 53 * _BK]),
                     complex(ops[o + 38 * _BK], ops[o + 54 * _BK]),
                     complex(ops[o + 39 * _BK], ops[o + 55 * _BK]),
                     complex(ops[o + 40 * _BK], ops[o + 56 * _BK]),
                     complex(ops[o + 41 * _BK], ops[o + 57 * _BK]),
                     complex(ops[o + 42 * _BK], ops[o + 58 * _BK]),
                     complex(ops[o + 43 * _BK], ops[o + 59 * _BK]),
                     complex(ops[o + 44 * _BK], ops[o + 60 * _BK]),
                     complex(ops[o + 45 * _BK], ops[o + 61 * _BK]),
                     complex(ops[o + 46 * _BK], ops[o + 62 * _BK]),
                     complex(ops[o + 47 * _BK], ops[o + 63 * _BK]))
                acc[ab + j] = _band_svv(a00, a01, a02, a03, P)
                acc[ab + _BK + j] = _band_svv(a10, a11, a12, a13, P)
                acc[ab + 2 * _BK + j] = _band_svv(a20, a21, a22, a23, P)
                acc[ab + 3 * _BK + j] = _band_svv(a30, a31, a32, a33, P)
        for k in range(nf):  # in band order, as the reference adds them
            ab = (k // _BK) * 4 * _BK + k % _BK
            for c in range(4):
                svv[c] += acc[ab + c * _BK]
        if any_stop:
            for c in range(4):
                sss[c] = 0.0
            for k in range(nf):
                ab = (k // _BK) * 4 * _BK + k % _BK
                for c in range(4):
                    sss[c] += acc[ab + c * _BK] * w2inv[k]
        if _step(st, any_stop, it) < tol:
            break
    _finish(any_stop, st, shock, stop, travel, Jm, sig_out, trav_out)
    e0, e1, e2, e3 = ceq[0], ceq[1], ceq[2], ceq[3]
    k0, k1, k2, k3 = keq[0], keq[1], keq[2], keq[3]
    # the features v of every band (see _NFEAT), vectorized over bands like the fixed point,
    # into V by block: band blk * _BK + j, feature i at (blk * _NFEAT + i) * _BK + j
    for blk in range(nblk):
        ob = blk * 96 * _BK
        rb = blk * 12 * _BK
        vb = blk * _NFEAT * _BK
        jb = blk * _BK
        for j in range(_BK):
            r = rb + j
            jk = jinv[jb + j]  # -1 / w: the stop's k_eq on the travel v / (j w)
            D0 = _over_roll(e0, roll[r] > 0.5, roll[r + 4 * _BK], roll[r + 8 * _BK]) - cb0
            D0 = D0 + complex(0.0, k0 * jk)
            r += _BK
            D1 = _over_roll(e1, roll[r] > 0.5, roll[r + 4 * _BK], roll[r + 8 * _BK]) - cb1
            D1 = D1 + complex(0.0, k1 * jk)
            r += _BK
            D2 = _over_roll(e2, roll[r] > 0.5, roll[r + 4 * _BK], roll[r + 8 * _BK]) - cb2
            D2 = D2 + complex(0.0, k2 * jk)
            r += _BK
            D3 = _over_roll(e3, roll[r] > 0.5, roll[r + 4 * _BK], roll[r + 8 * _BK]) - cb3
            D3 = D3 + complex(0.0, k3 * jk)
            o = ob + j
            h = (complex(ops[o + 0 * _BK], ops[o + 16 * _BK]),
                 complex(ops[o + 1 * _BK], ops[o + 17 * _BK]),
                 complex(ops[o + 2 * _BK], ops[o + 18 * _BK]),
                 complex(ops[o + 3 * _BK], ops[o + 19 * _BK]),
                 complex(ops[o + 4 * _BK], ops[o + 20 * _BK]),
                 complex(ops[o + 5 * _BK], ops[o + 21 * _BK]),
                 complex(ops[o + 6 * _BK], ops[o + 22 * _BK]),
                 complex(ops[o + 7 * _BK], ops[o + 23 * _BK]),
                 complex(ops[o + 8 * _BK], ops[o + 24 * _BK]),
                 complex(ops[o + 9 * _BK], ops[o + 25 * _BK]),
                 complex(ops[o + 10 * _BK], ops[o + 26 * _BK]),
                 complex(ops[o + 11 * _BK], ops[o + 27 * _BK]),
                 complex(ops[o + 12 * _BK], ops[o + 28 * _BK]),
                 complex(ops[o + 13 * _BK], ops[o + 29 * _BK]),
                 complex(ops[o + 14 * _BK], ops[o + 30 * _BK]),
                 complex(ops[o + 15 * _BK], ops[o + 31 * _BK]))
            K = _band_inverse(h, D0, D1, D2, D3)
            # E = diag(D) K
            e = (D0 * K[0], D0 * K[1], D0 * K[2], D0 * K[3], D1 * K[4], D1 * K[5], D1 * K[6],
                 D1 * K[7], D2 * K[8], D2 * K[9], D2 * K[10], D2 * K[11], D3 * K[12],
                 D3 * K[13], D3 * K[14], D3 * K[15])
            pb = (complex(ops[o + 64 * _BK], ops[o + 80 * _BK]),
                  complex(ops[o + 65 * _BK], ops[o + 81 * _BK]),
                  complex(ops[o + 66 * _BK], ops[o + 82 * _BK]),
                  complex(ops[o + 67 * _BK], ops[o + 83 * _BK]),
                  complex(ops[o + 68 * _BK], ops[o + 84 * _BK]),
                  complex(ops[o + 69 * _BK], ops[o + 85 * _BK]),
                  complex(ops[o + 70 * _BK], ops[o + 86 * _BK]),
                  complex(ops[o + 71 * _BK], ops[o + 87 * _BK]),
                  complex(ops[o + 72 * _BK], ops[o + 88 * _BK]),
                  complex(ops[o + 73 * _BK], ops[o + 89 * _BK]),
                  complex(ops[o + 74 * _BK], ops[o + 90 * _BK]),
                  complex(ops[o + 75 * _BK], ops[o + 91 * _BK]),
                  complex(ops[o + 76 * _BK], ops[o + 92 * _BK]),
                  complex(ops[o + 77 * _BK], ops[o + 93 * _BK]),
                  complex(ops[o + 78 * _BK], ops[o + 94 * _BK]),
                  complex(ops[o + 79 * _BK], ops[o + 95 * _BK]))
            f = _band_features(e, pb)
            o = vb + j  # feature i at o + i * _BK
            V[o + 0 * _BK] = f[0]
            V[o + 1 * _BK] = f[1]
            V[o + 2 * _BK] = f[2]
            V[o + 3 * _BK] = f[3]
            V[o + 4 * _BK] = f[4]
            V[o + 5 * _BK] = f[5]
            V[o + 6 * _BK] = f[6]
            V[o + 7 * _BK] = f[7]
            V[o + 8 * _BK] = f[8]
            V[o + 9 * _BK] = f[9]
            V[o + 10 * _BK] = f[10]
            V[o + 11 * _BK] = f[11]
            V[o + 12 * _BK] = f[12]
            V[o + 13 * _BK] = f[13]
            V[o + 14 * _BK] = f[14]
            V[o + 15 * _BK] = f[15]
            V[o + 16 * _BK] = e[0].real
            V[o + 32 * _BK] = e[0].imag
            V[o + 17 * _BK] = e[1].real
            V[o + 33 * _BK] = e[1].imag
            V[o + 18 * _BK] = e[2].real
            V[o + 34 * _BK] = e[2].imag
            V[o + 19 * _BK] = e[3].real
            V[o + 35 * _BK] = e[3].imag
            V[o + 20 * _BK] = e[4].real
            V[o + 36 * _BK] = e[4].imag
            V[o + 21 * _BK] = e[5].real
            V[o + 37 * _BK] = e[5].imag
            V[o + 22 * _BK] = e[6].real
            V[o + 38 * _BK] = e[6].imag
            V[o + 23 * _BK] = e[7].real
            V[o + 39 * _BK] = e[7].imag
            V[o + 24 * _BK] = e[8].real
            V[o + 40 * _BK] = e[8].imag
            V[o + 25 * _BK] = e[9].real
            V[o + 41 * _BK] = e[9].imag
            V[o + 26 * _BK] = e[10].real
            V[o + 42 * _BK] = e[10].imag
            V[o + 27 * _BK] = e[11].real
            V[o + 43 * _BK] = e[11].imag
            V[o + 28 * _BK] = e[12].real
            V[o + 44 * _BK] = e[12].imag
            V[o + 29 * _BK] = e[13].real
            V[o + 45 * _BK] = e[13].imag
            V[o + 30 * _BK] = e[14].real
            V[o + 46 * _BK] = e[14].imag
            V[o + 31 * _BK] = e[15].real
            V[o + 47 * _BK] = e[15].imag
    return it + 1


# BEGIN GENERATED METRICS by planner.screen_codegen (python -m planner.screen_codegen --write)
@nb.njit(cache=True, error_model="numpy")
def _metrics_of(Fq, d0q, V, G, out, PW, nf):
    """The metrics of G setups from their band features V[g] (:func:`_screen_one`).

    Each metric's band power is d0 plus a fixed linear form of the band's features (F, from
    the operands), summed over bands, in the reference's order per setup: ``pw = d0[k]``,
    ``pw += F[k, i] v_i`` for i in order, then the band powers added in band order. Laid
    out by :func:`metric_blocks` (Fq, d0q: ``_MQ`` metrics per group, bands in blocks of
    ``_BK`` as V), each group's band powers are straight-line code over the 48 features in
    a loop over the bands of a block that LLVM vectorizes over bands (the ``_MQ`` sums held
    in registers, no fastmath); a block's coefficients (18 kB) are shared by the G setups
    while in cache. PW (G, n_blocks * _MQ * _BK) is scratch; nf the bands in use.
    Generated code (:mod:`planner.screen_codegen`)."""
    nblk = PW.shape[1] // (_MQ * _BK)
    p = out.shape[1]
    for q in range(Fq.shape[0]):
        fq = Fq[q]
        dq = d0q[q]
        for blk in range(nblk):
            fb = blk * _NFEAT * _MQ * _BK
            vb = blk * _NFEAT * _BK
            db = blk * _MQ * _BK
            for g in range(G):
                v = V[g]
                pw = PW[g]
                for j in range(_BK):  # vectorized over bands
                    a0 = dq[db + j]
                    a1 = dq[db + 1 * _BK + j]
                    a2 = dq[db + 2 * _BK + j]
                    x = fb + j
                    y = vb + j
                    u = v[y]
                    a0 += fq[x] * u
                    a1 += fq[x + 1 * _BK] * u
                    a2 += fq[x + 2 * _BK] * u
                    u = v[y + 1 * _BK]
                    a0 += fq[x + 3 * _BK] * u
                    a1 += fq[x + 4 * _BK] * u
                    a2 += fq[x + 5 * _BK] * u
                    u = v[y + 2 * _BK]
                    a0 += fq[x + 6 * _BK] * u
                    a1 += fq[x + 7 * _BK] * u
                    a2 += fq[x + 8 * _BK] * u
                    u = v[y + 3 * _BK]
                    a0 += fq[x + 9 * _BK] * u
                    a1 += fq[x + 10 * _BK] * u
                    a2 += fq[x + 11 * _BK] * u
                    u = v[y + 4 * _BK]
                    a0 += fq[x + 12 * _BK] * u
                    a1 += fq[x + 13 * _BK] * u
                    a2 += fq[x + 14 * _BK] * u
                    u = v[y + 5 * _BK]
                    a0 += fq[x + 15 * _BK] * u
                    a1 += fq[x + 16 * _BK] * u
                    a2 += fq[x + 17 * _BK] * u
                    u = v[y + 6 * _BK]
                    a0 += fq[x + 18 * _BK] * u
                    a1 += fq[x + 19 * _BK] * u
                    a2 += fq[x + 20 * _BK] * u
                    u = v[y + 7 * _BK]
                    a0 += fq[x + 21 * _BK] * u
                    a1 += fq[x + 22 * _BK] * u
                    a2 += fq[x + 23 * _BK] * u
                    u = v[y + 8 * _BK]
                    a0 += fq[x + 24 * _BK] * u
                    a1 += fq[x + 25 * _BK] * u
                    a2 += fq[x + 26 * _BK] * u
                    u = v[y + 9 * _BK]
                    a0 += fq[x + 27 * _BK] * u
                    a1 += fq[x + 28 * _BK] * u
                    a2 += fq[x + 29 * _BK] * u
                    u = v[y + 10 * _BK]
                    a0 += fq[x + 30 * _BK] * u
                    a1 += fq[x + 31 * _BK] * u
                    a2 += fq[x + 32 * _BK] * u
                    u = v[y + 11 * _BK]
                    a0 += fq[x + 33 * _BK] * u
                    a1 += fq[x + 34 * _BK] * u
                    a2 += fq[x + 35 * _BK] * u
                    u = v[y + 12 * _BK]
                    a0 += fq[x + 36 * _BK] * u
                    a1 += fq[x + 37 * _BK] * u
                    a2 += fq[x + 38 * _BK] * u
                    u = v[y + 13 * _BK]
                    a0 += fq[x + 39 * _BK] * u
                    a1 += fq[x + 40 * _BK] * u
                    a2 += fq[x + 41 * _BK] * u
                    u = v[y + 14 * _BK]
                    a0 += fq[x + 42 * _BK] * u
                    a1 += fq[x + 43 * _BK] * u
                    a2 += fq[x + 44 * _BK] * u
                    u = v[y + 15 * _BK]
                    a0 += fq[x + 45 * _BK] * u
                    a1 += fq[x + 46 * _BK] * u
                    a2 += fq[x + 47 * _BK] * u
                    u = v[y + 16 * _BK]
                    a0 += fq[x + 48 * _BK] * u
                    a1 += fq[x + 49 * _BK] * u
                    a2 += fq[x + 50 * _BK] * u
                    u = v[y + 17 * _BK]
                    a0 += fq[x + 51 * _BK] * u
                    a1 += fq[x + 52 * _BK] * u
                    a2 += fq[x + 53 * _BK] * u
                    u = v[y + 18 * _BK]
                    a0 += fq[x + 54 * _BK] * u
                    a1 += fq[x + 55 * _BK] * u
                    a2 += fq[x + 56 * _BK] * u
                    u = v[y + 19 * _BK]
                    a0 += fq[x + 57 * _BK] * u
                    a1 += fq[x + 58 * _BK] * u
                    a2 += fq[x + 59 * _BK] * u
                    u = v[y + 20 * _BK]
                    a0 += fq[x + 60 * _BK] * u
                    a1 += fq[x + 61 * _BK] * u
                    a2 += fq[x + 62 * _BK] * u
                    u = v[y + 21 * _BK]
                    a0 += fq[x + 63 * _BK] * u
                    a1 += fq[x + 64 * _BK] * u
                    a2 += fq[x + 65 * _BK] * u
                    u = v[y + 22 * _BK]
                    a0 += fq[x + 66 * _BK] * u
                    a1 += fq[x + 67 * _BK] * u
                    a2 += fq[x + 68 * _BK] * u
                    u = v[y + 23 * _BK]
                    a0 += fq[x + 69 * _BK] * u
                    a1 += fq[x + 70 * _BK] * u
                    a2 += fq[x + 71 * _BK] * u
                    u = v[y + 24 * _BK]
                    a0 += fq[x + 72 * _BK] * u
                    a1 += fq[x + 73 * _BK] * u
                    a2 += fq[x + 74 * _BK] * u
                    u = v[y + 25 * _BK]
                    a0 += fq[x + 75 * _BK] * u
                    a1 += fq[x + 76 * _BK] * u
                    a2 += fq[x + 77 * _BK] * u
                    u = v[y + 26 * _BK]
                    a0 += fq[x + 78 * _BK] * u
                    a1 += fq[x + 79 * _BK] * u
                    a2 += fq[x + 80 * _BK] * u
                    u = v[y + 27 * _BK]
                    a0 += fq[x + 81 * _BK] * u
                    a1 += fq[x + 82 * _BK] * u
                    a2 += fq[x + 83 * _BK] * u
                    u = v[y + 28 * _BK]
                    a0 += fq[x + 84 * _BK] * u
                    a1 += fq[x + 85 * _BK] * u
                    a2 += fq[x + 86 * _BK] * u
                    u = v[y + 29 * _BK]
                    a0 += fq[x + 87 * _BK] * u
                    a1 += fq[x + 88 * _BK] * u
                    a2 += fq[x + 89 * _BK] * u
                    u = v[y + 30 * _BK]
                    a0 += fq[x + 90 * _BK] * u
                    a1 += fq[x + 91 * _BK] * u
                    a2 += fq[x + 92 * _BK] * u
                    u = v[y + 31 * _BK]
                    a0 += fq[x + 93 * _BK] * u
                    a1 += fq[x + 94 * _BK] * u
                    a2 += fq[x + 95 * _BK] * u
                    u = v[y + 32 * _BK]
                    a0 += fq[x + 96 * _BK] * u
                    a1 += fq[x + 97 * _BK] * u
                    a2 += fq[x + 98 * _BK] * u
                    u = v[y + 33 * _BK]
                    a0 += fq[x + 99 * _BK] * u
                    a1 += fq[x + 100 * _BK] * u
                    a2 += fq[x + 101 * _BK] * u
                    u = v[y + 34 * _BK]
                    a0 += fq[x + 102 * _BK] * u
                    a1 += fq[x + 103 * _BK] * u
                    a2 += fq[x + 104 * _BK] * u
                    u = v[y + 35 * _BK]
                    a0 += fq[x + 105 * _BK] * u
                    a1 += fq[x + 106 * _BK] * u
                    a2 += fq[x + 107 * _BK] * u
                    u = v[y + 36 * _BK]
                    a0 += fq[x + 108 * _BK] * u
                    a1 += fq[x + 109 * _BK] * u
                    a2 += fq[x + 110 * _BK] * u
                    u = v[y + 37 * _BK]
                    a0 += fq[x + 111 * _BK] * u
                    a1 += fq[x + 112 * _BK] * u
                    a2 += fq[x + 113 * _BK] * u
                    u = v[y + 38 * _BK]
                    a0 += fq[x + 114 * _BK] * u
                    a1 += fq[x + 115 * _BK] * u
                    a2 += fq[x + 116 * _BK] * u
                    u = v[y + 39 * _BK]
                    a0 += fq[x + 117 * _BK] * u
                    a1 += fq[x + 118 * _BK] * u
                    a2 += fq[x + 119 * _BK] * u
                    u = v[y + 40 * _BK]
                    a0 += fq[x + 120 * _BK] * u
                    a1 += fq[x + 121 * _BK] * u
                    a2 += fq[x + 122 * _BK] * u
                    u = v[y + 41 * _BK]
                    a0 += fq[x + 123 * _BK] * u
                    a1 += fq[x + 124 * _BK] * u
                    a2 += fq[x + 125 * _BK] * u
                    u = v[y + 42 * _BK]
                    a0 += fq[x + 126 * _BK] * u
                    a1 += fq[x + 127 * _BK] * u
                    a2 += fq[x + 128 * _BK] * u
                    u = v[y + 43 * _BK]
                    a0 += fq[x + 129 * _BK] * u
                    a1 += fq[x + 130 * _BK] * u
                    a2 += fq[x + 131 * _BK] * u
                    u = v[y + 44 * _BK]
                    a0 += fq[x + 132 * _BK] * u
                    a1 += fq[x + 133 * _BK] * u
                    a2 += fq[x + 134 * _BK] * u
                    u = v[y + 45 * _BK]
                    a0 += fq[x + 135 * _BK] * u
                    a1 += fq[x + 136 * _BK] * u
                    a2 += fq[x + 137 * _BK] * u
                    u = v[y + 46 * _BK]
                    a0 += fq[x + 138 * _BK] * u
                    a1 += fq[x + 139 * _BK] * u
                    a2 += fq[x + 140 * _BK] * u
                    u = v[y + 47 * _BK]
                    a0 += fq[x + 141 * _BK] * u
                    a1 += fq[x + 142 * _BK] * u
                    a2 += fq[x + 143 * _BK] * u
                    pw[db + j] = a0
                    pw[db + 1 * _BK + j] = a1
                    pw[db + 2 * _BK + j] = a2
        for g in range(G):  # each metric's band powers added in band order
            pw = PW[g]
            t0 = 0.0
            t1 = 0.0
            t2 = 0.0
            for k in range(nf):
                x = (k // _BK) * _MQ * _BK + k % _BK
                t0 += pw[x]
                t1 += pw[x + 1 * _BK]
                t2 += pw[x + 2 * _BK]
            o = _MQ * q
            out[g, o] = math.sqrt(max(t0, 0.0))
            if o + 1 < p:
                out[g, o + 1] = math.sqrt(max(t1, 0.0))
            if o + 2 < p:
                out[g, o + 2] = math.sqrt(max(t2, 0.0))
# END GENERATED METRICS by planner.screen_codegen


@nb.njit(cache=True, error_model="numpy", parallel=True)
def screen_batch(plant, shocks, stops, travel, settings, out, n_chunks):
    """Screen setups, vectorized over bands, in n_chunks chunks in parallel.

    Parameters
    ----------
    plant : BandData
        The plant's band data (``blocks`` read, not ``Hvs``, ``P``, ``PB``).
    shocks : ShockTables
        The setups' shocks (n_setups rows).
    stops : StopTables
        The setups' bump stops (zeros where none).
    travel : TravelData
        The stops' operands (zeros without any stop).
    settings : IterSettings
    out : ScreenOutputs
        Written in place.
    n_chunks : int
        Chunks of setups run in parallel (scratch allocated once per chunk).
    """
    n = shocks.kv.shape[0]
    nf = plant.w.size
    nblk = (nf + _BK - 1) // _BK
    Fq, d0q = plant.Fq, plant.d0q
    # the outputs one name per statement, outside the prange body: numba 0.68's parallel
    # loops silently drop the stores ``out.iterations[s] = ...`` in the body and
    # ``iters[s] = ...`` after ``metrics, sigma, iters, elements = out`` or after
    # ``metrics, sigma, iters, elements = out.metrics, ..., out.elements``
    metrics = out.metrics
    sigma = out.sigma
    iters = out.iterations
    elements = out.elements
    for ch in nb.prange(n_chunks):
        # scratch once per chunk of setups
        roll = np.empty(nblk * 12 * _BK)
        acc = np.empty(nblk * 4 * _BK)
        V = np.empty((_GROUP, nblk * _NFEAT * _BK))
        PW = np.empty((_GROUP, nblk * _MQ * _BK))
        st = np.empty((_NST, 4))
        Jm = np.empty((4, 4))
        scratch = (roll, acc, st, Jm)
        stop = (ch + 1) * n // n_chunks
        for first in range(ch * n // n_chunks, stop, _GROUP):
            G = min(_GROUP, stop - first)
            for g in range(G):
                s = first + g
                iters[s] = _screen_one(plant, _shock_row(shocks, s), _stop_row(stops, s), travel,
                                       settings, sigma[s], elements[s], V[g], scratch)
            _metrics_of(Fq, d0q, V, G, metrics[first:first + G], PW, nf)


@nb.njit(cache=True, error_model="numpy")
def _screen_one_scalar(plant, shock, stop, travel, settings, out, sig_out, trav_out):
    """Screen one setup, one band after the other (the scalar kernel).

    The arguments as :func:`_screen_one` takes them (``plant``'s ``Hvs``, ``P``, ``PB`` read,
    not ``blocks``), ``out`` (n_metrics,) receiving the metrics. Returns the iterations taken.

    The same operations in the same order as :func:`_screen_one`, which runs them on four
    bands at once: the same numbers bit for bit (tested). It compiles in about 6 s against
    the vectorized kernel's 30-40 s (numba's front end on that kernel's straight-line band
    code), so small batches (:data:`planner.screen._VECTOR_MIN_SETUPS`) use it: a fresh
    machine's first ``rank`` or demo waits for the small compilation only.

    The fixed point's arithmetic (the loop inverse and the order of the sum
    ``svv[c] = sum_ab Re(K_ca P_ab conj(K_cb))``) is kept as written: the secant step divides
    differences of nearly equal residuals, so a reordered sum (e.g. using P Hermitian) moves
    sigma by up to ~1e-9 relative on some setups. The final pass is rewritten: each metric's
    band power is ``d0`` plus a setup-independent linear form ``F`` (:func:`metric_form`) of
    the 48 features of ``E = diag(D) K`` and ``R = E PB E^H``.

    Bump stops as in :func:`_screen_one` (``jinv`` read in band order);
    without a stop the loop gain is left as it was (no term added).
    """
    w, Hvs, P, PB, F, d0, cbar = (plant.w, plant.Hvs, plant.P, plant.PB, plant.F, plant.d0,
                                  plant.cbar)
    jinv, w2inv = travel.jinv, travel.w2inv
    max_iter, tol = settings
    lag = shock.lag
    nf = w.size
    p = d0.shape[1]
    K = np.empty((4, 4), dtype=np.complex128)
    T = np.empty((4, 4), dtype=np.complex128)
    perm = np.empty(4, dtype=np.int64)
    D = np.empty(4, dtype=np.complex128)
    # the lag's roll-off 1 / (1 + j w tau) per band and corner: the same in every iteration
    roll = np.empty((nf, 4), dtype=np.complex128)
    for k in range(nf):
        for c in range(4):
            roll[k, c] = 1.0 + 1j * w[k] * lag[c]
    v = np.empty(_NFEAT)
    pw = np.empty(p)
    st = np.zeros((_NST, 4))
    Jm = np.empty((4, 4))
    ceq, svv, keq, sss = st[_ST_CEQ], st[_ST_SVV], st[_ST_KEQ], st[_ST_SSS]
    any_stop = _start(st, plant.sig0, stop, travel)
    it = 0
    for it in range(max_iter):
        _damping(st, shock)
        for c in range(4):
            svv[c] = 0.0
            sss[c] = 0.0
        if any_stop:
            _stop_means(st, shock, stop, travel, Jm)
        for k in range(nf):
            for c in range(4):
                D[c] = ceq[c] / roll[k, c] - cbar[c]
                if any_stop:
                    D[c] = D[c] + complex(0.0, keq[c] * jinv[k])
            _loop_inverse(Hvs[k], D, K, perm)
            for c in range(4):
                acc = 0.0
                for a in range(4):
                    for b in range(4):
                        acc += (K[c, a] * P[k, a, b] * np.conj(K[c, b])).real
                svv[c] += acc
                sss[c] += acc * w2inv[k]
        if _step(st, any_stop, it) < tol:
            break
    _finish(any_stop, st, shock, stop, travel, Jm, sig_out, trav_out)
    for o in range(p):
        out[o] = 0.0
    for k in range(nf):
        for c in range(4):
            D[c] = ceq[c] / roll[k, c] - cbar[c]
            if any_stop:
                D[c] = D[c] + complex(0.0, keq[c] * jinv[k])
        _loop_inverse(Hvs[k], D, K, perm)
        # E = diag(D) K, in place of K
        for a in range(4):
            for b in range(4):
                K[a, b] = D[a] * K[a, b]
        # T = E PB, then R = T E^H (Hermitian: the diagonal and the upper triangle)
        for a in range(4):
            for b in range(4):
                acc = 0j
                for c in range(4):
                    acc += K[a, c] * PB[k, c, b]
                T[a, b] = acc
        for a in range(4):
            acc = 0.0
            for c in range(4):
                acc += T[a, c].real * K[a, c].real + T[a, c].imag * K[a, c].imag
            v[a] = acc
        q = 0
        for a in range(3):  # a < b in the order of _PAIRS_A, _PAIRS_B
            for b in range(a + 1, 4):
                acc = 0j
                for c in range(4):
                    acc += T[a, c] * np.conj(K[b, c])
                v[4 + q] = acc.real
                v[10 + q] = acc.imag
                q += 1
        for a in range(4):
            for b in range(4):
                v[16 + 4 * a + b] = K[a, b].real
                v[32 + 4 * a + b] = K[a, b].imag
        # each metric's band power is d0 plus a fixed linear form of v (F, from the
        # operands): the loop over metrics innermost, contiguous in F
        for o in range(p):
            pw[o] = d0[k, o]
        for j in range(_NFEAT):
            vj = v[j]
            for o in range(p):
                pw[o] += F[k, j, o] * vj
        for o in range(p):
            out[o] += pw[o]
    for o in range(p):
        out[o] = math.sqrt(max(out[o], 0.0))
    return it + 1


@nb.njit(cache=True, error_model="numpy", parallel=True)
def screen_batch_scalar(plant, shocks, stops, travel, settings, out):
    """Screen setups one band after the other (:func:`_screen_one_scalar`), in parallel over
    setups: the numbers of :func:`screen_batch` bit for bit.

    Parameters
    ----------
    plant : BandData
        The plant's band data (``Hvs``, ``P``, ``PB`` read, not ``blocks``).
    shocks, stops, travel, settings, out
        As :func:`screen_batch`.
    """
    # one name per statement, outside the prange body (see screen_batch)
    metrics = out.metrics
    sigma = out.sigma
    iters = out.iterations
    elements = out.elements
    for s in nb.prange(shocks.kv.shape[0]):
        # prange's index is unsigned: an int64 row index, as screen_batch's, so that
        # _shock_row and _stop_row compile (and are cached) once, not once per index type
        i = np.int64(s)
        iters[i] = _screen_one_scalar(plant, _shock_row(shocks, i), _stop_row(stops, i), travel,
                                      settings, metrics[i], sigma[i], elements[i])


def band_operands(ops):
    """The fixed point's per-band operands in the layout of :func:`_screen_one`'s band loop.

    Returns
    -------
    ndarray, shape (n_blocks * 96 * _BK,)
        Block ``b`` of ``_BK`` bands holds at ``(96 b + m) _BK + j`` (band ``b _BK + j``):
        for m < 16 the real part of entry m (row-major) of ``-Hvs``, for 16 <= m < 32 its
        imaginary part, then the same of ``P`` (32 <= m < 64) and ``PB`` (64 <= m < 96).
        Bands past the last are zero (their loop inverse is the identity; never summed).
    """
    nf = ops.w.size
    nblk = -(-nf // _BK)
    x = np.zeros((96, nblk * _BK))
    nhv = -ops.Hvs.reshape(nf, 16).T
    P = ops.P.reshape(nf, 16).T
    x[:16, :nf] = nhv.real
    x[16:32, :nf] = nhv.imag
    x[32:48, :nf] = P.real
    x[48:64, :nf] = P.imag
    PB = ops.PB.reshape(nf, 16).T
    x[64:80, :nf] = PB.real
    x[80:, :nf] = PB.imag
    return np.ascontiguousarray(x.reshape(96, nblk, _BK).transpose(1, 0, 2)).reshape(-1)


def padded_bands(x):
    """A per-band vector (n_bands,) padded with zeros to whole blocks of bands, as the
    kernels read per-band rows (``jinv``: band k at k, padding never summed)."""
    x = np.asarray(x, dtype=float)
    out = np.zeros(-(-x.size // _BK) * _BK)
    out[:x.size] = x
    return out


def metric_form(ops):
    """The metrics' band powers as a linear form of the kernel's per-band features.

    Parameters
    ----------
    ops : ScreenOperands

    Returns
    -------
    F : ndarray, shape (n_bands, 48, n_metrics)
        A metric's band power is ``d0[k, o] + F[k, :, o] . v`` with v the features of the
        setup's loop correction in band k (see ``_NFEAT``). With ``h = H_ys[k, o]``,
        ``W = h E``: ``W P_B W^H = h R h^H`` takes ``|h_a|^2`` (diagonal of R),
        ``2 Re(h_a conj(h_b))`` and ``-2 Im(h_a conj(h_b))`` (upper triangle of R, ``a < b``
        in the order of ``_PAIRS_A``/``_PAIRS_B``), and ``2 Re(W Q) = 2 Re sum_ab E_ab h_a
        Q_bo`` takes ``2 Re(h_a Q_bo)`` and ``-2 Im(h_a Q_bo)``. Setup-independent: built
        once per call of :func:`planner.screen.screen_packed`, it takes the per-metric work out
        of the kernels.
    """
    Hys, QB = ops.Hys, ops.QB
    nf, p = Hys.shape[0], Hys.shape[1]
    F = np.empty((nf, _NFEAT, p))
    h = np.transpose(Hys, (0, 2, 1))  # (nf, 4, p)
    F[:, :4] = np.abs(h) ** 2
    g = 2.0 * h[:, _PAIRS_A] * np.conj(h[:, _PAIRS_B])  # (nf, 6, p)
    F[:, 4:10] = g.real
    F[:, 10:16] = -g.imag
    y = 2.0 * h[:, :, None, :] * QB[:, None, :, :]  # (nf, a, b, p): 2 h_a Q_bo
    F[:, 16:32] = y.real.reshape(nf, 16, p)
    F[:, 32:48] = -y.imag.reshape(nf, 16, p)
    return F


def metric_blocks(F, d0):
    """The metrics' linear form in the layout of :func:`screen_batch`'s metrics pass.

    Parameters
    ----------
    F : ndarray, shape (n_bands, 48, >= n_metrics)
        :func:`metric_form` (columns past ``n_metrics`` ignored).
    d0 : ndarray, shape (n_bands, n_metrics)
        Weighted metric power with the shock loop open.

    Returns
    -------
    Fq : ndarray, shape (n_groups, n_blocks * 48 * _MQ * _BK)
        Metric ``_MQ q + r``'s coefficient of feature i in band ``blk _BK + j`` at
        ``[q, ((blk 48 + i) _MQ + r) _BK + j]``: a group of ``_MQ`` metrics, bands in blocks
        of ``_BK`` as the features V (:func:`_screen_one`). Zero past the last metric and band.
    d0q : ndarray, shape (n_groups, n_blocks * _MQ * _BK)
        ``d0`` likewise at ``[q, (blk _MQ + r) _BK + j]``.
    """
    nf, p = d0.shape
    nblk = -(-nf // _BK)
    nq = -(-p // _MQ)
    Fp = np.zeros((nblk * _BK, _NFEAT, nq * _MQ))
    Fp[:nf, :, :p] = F[:, :, :p]
    Fq = Fp.reshape(nblk, _BK, _NFEAT, nq, _MQ).transpose(3, 0, 2, 4, 1)
    dp = np.zeros((nblk * _BK, nq * _MQ))
    dp[:nf, :p] = d0
    d0q = dp.reshape(nblk, _BK, nq, _MQ).transpose(2, 0, 3, 1)
    return (np.ascontiguousarray(Fq).reshape(nq, -1), np.ascontiguousarray(d0q).reshape(nq, -1))
