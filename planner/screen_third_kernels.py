"""Compiled kernel of the screening with third elements: numba, one caller (:mod:`planner.screen`).

The screening's fixed point (:mod:`planner.screen`) with the loop correction no longer
diagonal: every damper and spring acts through a row ``r`` over the corners (a corner's
own shock or bump stop: a unit row; a heave or roll element:
:func:`ident.data.third.element_row`), so with the dampers' equivalent damping ``c_r(w)``
(lag as a first-order roll-off) and the springs' equivalent stiffness ``k_r``::

    Delta(w) = -diag(c_bar) + sum_r (c_r(w) + k_r / (j w)) r r^T        (4 x 4, dense)

and ``K = (I - H_vs Delta)^-1``. Each row's velocity power is ``r K P K^H r^T`` (its RMS
the next iterate of its linearization), its travel power the same over ``w^2``; the
metrics are the linear form of :func:`planner.screen_kernels.metric_form` of the features
of ``E = Delta K`` (which holds for any E, diagonal or not).

The elements sit in four fixed slots (heave front, heave rear, roll front, roll rear), each
acting within its axle, so ``Delta`` is block diagonal. The band work of an iteration
(:func:`_band_power`: ``Delta``, ``K`` and ``V = K P K^H``) and of the final pass
(:func:`_band_features`: the 48 features of ``E = Delta K``) is straight-line code on
scalars in a loop over the bands of a block of 16, the operands at constant offsets in two
arrays (:class:`ThirdBands` ``blocks`` and the setup's roll-offs), so that LLVM vectorizes
it over bands as the plain kernel's; the 4x4 inverse by cofactors (:func:`inverse_cofactor`:
no pivoting, so no branches; the return difference ``I - H_vs Delta`` of a stable loop is
far from singular, tested against ``numpy.linalg.inv``); the bands' sums taken in band
order afterwards. The two band loops are generated code
(:func:`planner.screen_codegen.third_band_source`; ``python -m planner.screen_codegen
--write``). A car without third elements never comes here (the plain kernels,
:mod:`planner.screen_kernels`).

The fixed point couples the rows (a heave damper's velocity is its corners'), which the
plain kernels' per-row secant does not see: here it converged in 7.1 iterations on average
against the plain screening's 5.1 (``benchmarks/bench_third_screen.py``'s setups). So each
iteration's next iterate is Anderson's (:func:`_anderson`: depth 3, on the log RMS of all
the rows together), the secant's kept where Anderson's would move a row by more than a
factor 2: 5.7 iterations, and nearer the converged fixed point at the same tolerance. The
rows' powers are quadratic forms of the bands' sums of V (:func:`_row_powers`), and the mean
travel takes two Newton steps per iteration (converging along with the RMS; the full Newton
after the loop).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from planner.screen_kernels import gaussian_pwl, solve4

__all__ = [
    "THIRD_BLOCK_BANDS",
    "ThirdBands",
    "ThirdOutputs",
    "screen_batch_third",
    "inverse_cofactor",
]

_SQRT2 = math.sqrt(2.0)
#: Newton iterations on the mean travel and their tolerance [m] (as the plain kernels').
_MEAN_MAX_ITER = 50
_MEAN_TOL_M = 1e-12
#: Newton steps on the mean travel per iteration of the fixed point (the mean travel
#: converges along with the RMS; after the loop the full Newton, :data:`_MEAN_MAX_ITER`).
_MEAN_LOOP_ITER = 2
#: Depth of the Anderson acceleration of the fixed point (:func:`_anderson`): the last
#: differences of iterates and residuals it fits.
_AA_DEPTH = 3
#: Features of a band's loop correction the metrics are a linear form of (as
#: :func:`planner.screen_kernels.metric_form` lays them out).
_NFEAT = 48
#: Bands per block of the iteration's band loop (:func:`_band_power`; as the plain kernels').
THIRD_BLOCK_BANDS = 16
_BK = THIRD_BLOCK_BANDS
#: Operand rows per block (:func:`planner.screen.third_bands`): ``H_vs`` real and imaginary
#: (16 + 16), ``P`` (16 + 16), ``-1 / w``, ``PB`` (16 + 16).
_NOPS = 97


class ThirdBands(NamedTuple):
    """The plant's band data and the rows, entry-major (setup-independent).

    Attributes
    ----------
    w : ndarray, shape (n_bands,)
        Band centres [rad/s].
    H, P, PB : ndarray of complex, shape (16, n_bands)
        Entry ``4 a + b`` of ``H_vs``, ``P`` and ``PB`` per band (row-major entries).
    blocks : ndarray, shape (n_blocks * 97 * 16,)
        ``H_vs``, ``P``, ``-1 / w`` and ``PB`` in blocks of 16 bands for :func:`_band_power`
        and :func:`_band_features`: band ``16 b + j``'s row m at ``(97 b + m) 16 + j`` (rows
        0-15 the real parts of ``H_vs``'s entries, 16-31 their imaginary parts, 32-63 the
        same of ``P``, 64 ``-1 / w``, 65-96 ``PB``'s; zero past the last band).
    F : ndarray, shape (n_bands, 48, n_metrics)
        :func:`planner.screen_kernels.metric_form`.
    d0 : ndarray, shape (n_bands, n_metrics)
    cbar : ndarray, shape (4,)
    rows : ndarray, shape (8, 4)
        The rows: the 4 corners (unit rows) then the 4 element slots (zero rows where no
        element: a zero row has no velocity, travel or force).
    outer : ndarray, shape (n_rows, 16)
        ``r r^T`` of each row (row-major entries).
    sig0 : ndarray, shape (n_rows,)
        Starting velocity RMS per row [m/s].
    jinv : ndarray, shape (n_bands,)
        ``-1 / w`` [s/rad].
    w2inv : ndarray, shape (n_bands,)
        ``1 / w^2``.
    gain : ndarray, shape (4, 4)
        Static corner travel per unit corner force [m/N].
    static : ndarray, shape (4,)
        Static corner travel of the drive's mean [m].
    rms0 : ndarray, shape (n_rows,)
        Starting travel RMS per row [m].
    """

    w: np.ndarray
    H: np.ndarray
    P: np.ndarray
    PB: np.ndarray
    blocks: np.ndarray
    F: np.ndarray
    d0: np.ndarray
    cbar: np.ndarray
    rows: np.ndarray
    outer: np.ndarray
    sig0: np.ndarray
    jinv: np.ndarray
    w2inv: np.ndarray
    gain: np.ndarray
    static: np.ndarray
    rms0: np.ndarray


class ThirdOutputs(NamedTuple):
    """The kernel's outputs, written in place.

    Attributes
    ----------
    metrics : ndarray, shape (n_setups, n_metrics)
    sigma : ndarray, shape (n_setups, n_rows)
        Linearized velocity RMS per row [m/s].
    iterations : ndarray of int, shape (n_setups,)
    elements : ndarray, shape (n_setups, 6, n_rows)
        Per row the rows of :data:`planner.screen_kernels.STOP_ROWS` (travel RMS and mean
        [m], spring k_eq [N/m] and mean force [N], damper c_eq [N s/m] and mean force [N]);
        the travel rows zero in a setup without any spring.
    """

    metrics: np.ndarray
    sigma: np.ndarray
    iterations: np.ndarray
    elements: np.ndarray


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


@nb.njit(cache=True, error_model="numpy", inline="always")
def _inv4(a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23, a30, a31, a32, a33):
    """The inverse of a 4x4 complex matrix by cofactors (2x2 minors of the row pairs),
    straight-line: no branches (the reciprocal of the determinant in real arithmetic)."""
    s0 = a00 * a11 - a10 * a01
    s1 = a00 * a12 - a10 * a02
    s2 = a00 * a13 - a10 * a03
    s3 = a01 * a12 - a11 * a02
    s4 = a01 * a13 - a11 * a03
    s5 = a02 * a13 - a12 * a03
    c5 = a22 * a33 - a32 * a23
    c4 = a21 * a33 - a31 * a23
    c3 = a21 * a32 - a31 * a22
    c2 = a20 * a33 - a30 * a23
    c1 = a20 * a32 - a30 * a22
    c0 = a20 * a31 - a30 * a21
    det = s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0
    m2 = det.real * det.real + det.imag * det.imag
    r = complex(det.real / m2, -det.imag / m2)
    b00 = (a11 * c5 - a12 * c4 + a13 * c3) * r
    b01 = (-a01 * c5 + a02 * c4 - a03 * c3) * r
    b02 = (a31 * s5 - a32 * s4 + a33 * s3) * r
    b03 = (-a21 * s5 + a22 * s4 - a23 * s3) * r
    b10 = (-a10 * c5 + a12 * c2 - a13 * c1) * r
    b11 = (a00 * c5 - a02 * c2 + a03 * c1) * r
    b12 = (-a30 * s5 + a32 * s2 - a33 * s1) * r
    b13 = (a20 * s5 - a22 * s2 + a23 * s1) * r
    b20 = (a10 * c4 - a11 * c2 + a13 * c0) * r
    b21 = (-a00 * c4 + a01 * c2 - a03 * c0) * r
    b22 = (a30 * s4 - a31 * s2 + a33 * s0) * r
    b23 = (-a20 * s4 + a21 * s2 - a23 * s0) * r
    b30 = (-a10 * c3 + a11 * c1 - a12 * c0) * r
    b31 = (a00 * c3 - a01 * c1 + a02 * c0) * r
    b32 = (-a30 * s3 + a31 * s1 - a32 * s0) * r
    b33 = (a20 * s3 - a21 * s1 + a22 * s0) * r
    return (b00, b01, b02, b03, b10, b11, b12, b13, b20, b21, b22, b23, b30, b31, b32, b33)


@nb.njit(cache=True, error_model="numpy")
def inverse_cofactor(A):
    """The kernel's 4x4 inverse of each matrix of A (n, 4, 4) complex (for the tests).

    Returns
    -------
    ndarray of complex, shape (n, 4, 4)
    """
    out = np.empty_like(A)
    for i in range(A.shape[0]):
        b = _inv4(A[i, 0, 0], A[i, 0, 1], A[i, 0, 2], A[i, 0, 3], A[i, 1, 0], A[i, 1, 1],
                  A[i, 1, 2], A[i, 1, 3], A[i, 2, 0], A[i, 2, 1], A[i, 2, 2], A[i, 2, 3],
                  A[i, 3, 0], A[i, 3, 1], A[i, 3, 2], A[i, 3, 3])
        for j in range(16):
            out[i, j // 4, j % 4] = b[j]
    return out


# BEGIN GENERATED CODE by planner.screen_codegen (third elements)
@nb.njit(cache=True, error_model="numpy")
def _band_power(bd, ceq, keq, rinv, V):
    """One iteration's band work, fused and written out: per band ``Delta`` (the corners'
    damping on the diagonal, the 4 element slots by their outer products: heave front, heave
    rear, roll front, roll rear, each within its axle, so Delta is block diagonal and the
    cross-axle terms are left out), ``A = I - H_vs Delta``, ``K = A^-1`` (:func:`_inv4`) and
    ``V = K P K^H`` (its real diagonal and the real parts of its upper triangle) into V
    (``10 _BK`` per block of bands: entry q of band ``blk _BK + j`` at ``(10 blk + q) _BK +
    j``). Straight-line code on scalars in a loop over the bands of a block (no branches, no
    scratch memory, the operands at constant offsets in two arrays: LLVM vectorizes it over
    bands, as the plain kernel's band loop); ceq, keq: the dampers' ``c_eq`` and springs'
    ``k_eq`` over the 8 rows (the 4 corners, the 4 element slots: zero rows where no
    element); rinv: the setup's roll-offs ``1 / (1 + j w tau)`` per row in blocks
    (:func:`_screen_third_one`). Generated code (:mod:`planner.screen_codegen`)."""
    ops, outer, cbar = bd.blocks, bd.outer, bd.cbar
    nblk = (bd.w.size + _BK - 1) // _BK
    c0 = ceq[0]
    q0 = keq[0]
    c1 = ceq[1]
    q1 = keq[1]
    c2 = ceq[2]
    q2 = keq[2]
    c3 = ceq[3]
    q3 = keq[3]
    c4 = ceq[4]
    q4 = keq[4]
    c5 = ceq[5]
    q5 = keq[5]
    c6 = ceq[6]
    q6 = keq[6]
    c7 = ceq[7]
    q7 = keq[7]
    cb0 = cbar[0]
    cb1 = cbar[1]
    cb2 = cbar[2]
    cb3 = cbar[3]
    o0_0 = outer[4, 0]
    o0_1 = outer[4, 1]
    o0_4 = outer[4, 4]
    o0_5 = outer[4, 5]
    o1_10 = outer[5, 10]
    o1_11 = outer[5, 11]
    o1_14 = outer[5, 14]
    o1_15 = outer[5, 15]
    o2_0 = outer[6, 0]
    o2_1 = outer[6, 1]
    o2_4 = outer[6, 4]
    o2_5 = outer[6, 5]
    o3_10 = outer[7, 10]
    o3_11 = outer[7, 11]
    o3_14 = outer[7, 14]
    o3_15 = outer[7, 15]
    for blk in range(nblk):
        ob = blk * _NOPS * _BK
        rb = blk * 16 * _BK
        vb = blk * 10 * _BK
        for j in range(_BK):
            o = ob + j
            r = rb + j
            jk = ops[o + 64 * _BK]
            g0 = c0 * complex(rinv[r + 0 * _BK], rinv[r + 8 * _BK]) - cb0 + complex(0.0, q0 * jk)
            g1 = c1 * complex(rinv[r + 1 * _BK], rinv[r + 9 * _BK]) - cb1 + complex(0.0, q1 * jk)
            g2 = c2 * complex(rinv[r + 2 * _BK], rinv[r + 10 * _BK]) - cb2 + complex(0.0, q2 * jk)
            g3 = c3 * complex(rinv[r + 3 * _BK], rinv[r + 11 * _BK]) - cb3 + complex(0.0, q3 * jk)
            e0 = c4 * complex(rinv[r + 4 * _BK], rinv[r + 12 * _BK]) + complex(0.0, q4 * jk)
            e1 = c5 * complex(rinv[r + 5 * _BK], rinv[r + 13 * _BK]) + complex(0.0, q5 * jk)
            e2 = c6 * complex(rinv[r + 6 * _BK], rinv[r + 14 * _BK]) + complex(0.0, q6 * jk)
            e3 = c7 * complex(rinv[r + 7 * _BK], rinv[r + 15 * _BK]) + complex(0.0, q7 * jk)
            d00 = g0 + o0_0 * e0 + o2_0 * e2
            d01 = o0_1 * e0 + o2_1 * e2
            d10 = o0_4 * e0 + o2_4 * e2
            d11 = g1 + o0_5 * e0 + o2_5 * e2
            d22 = g2 + o1_10 * e1 + o3_10 * e3
            d23 = o1_11 * e1 + o3_11 * e3
            d32 = o1_14 * e1 + o3_14 * e3
            d33 = g3 + o1_15 * e1 + o3_15 * e3
            h00 = complex(ops[o + 0 * _BK], ops[o + 16 * _BK])
            h01 = complex(ops[o + 1 * _BK], ops[o + 17 * _BK])
            h02 = complex(ops[o + 2 * _BK], ops[o + 18 * _BK])
            h03 = complex(ops[o + 3 * _BK], ops[o + 19 * _BK])
            h10 = complex(ops[o + 4 * _BK], ops[o + 20 * _BK])
            h11 = complex(ops[o + 5 * _BK], ops[o + 21 * _BK])
            h12 = complex(ops[o + 6 * _BK], ops[o + 22 * _BK])
            h13 = complex(ops[o + 7 * _BK], ops[o + 23 * _BK])
            h20 = complex(ops[o + 8 * _BK], ops[o + 24 * _BK])
            h21 = complex(ops[o + 9 * _BK], ops[o + 25 * _BK])
            h22 = complex(ops[o + 10 * _BK], ops[o + 26 * _BK])
            h23 = complex(ops[o + 11 * _BK], ops[o + 27 * _BK])
            h30 = complex(ops[o + 12 * _BK], ops[o + 28 * _BK])
            h31 = complex(ops[o + 13 * _BK], ops[o + 29 * _BK])
            h32 = complex(ops[o + 14 * _BK], ops[o + 30 * _BK])
            h33 = complex(ops[o + 15 * _BK], ops[o + 31 * _BK])
            a00 = 1.0 - (h00 * d00 + h01 * d10)
            a01 = -(h00 * d01 + h01 * d11)
            a02 = -(h02 * d22 + h03 * d32)
            a03 = -(h02 * d23 + h03 * d33)
            a10 = -(h10 * d00 + h11 * d10)
            a11 = 1.0 - (h10 * d01 + h11 * d11)
            a12 = -(h12 * d22 + h13 * d32)
            a13 = -(h12 * d23 + h13 * d33)
            a20 = -(h20 * d00 + h21 * d10)
            a21 = -(h20 * d01 + h21 * d11)
            a22 = 1.0 - (h22 * d22 + h23 * d32)
            a23 = -(h22 * d23 + h23 * d33)
            a30 = -(h30 * d00 + h31 * d10)
            a31 = -(h30 * d01 + h31 * d11)
            a32 = -(h32 * d22 + h33 * d32)
            a33 = 1.0 - (h32 * d23 + h33 * d33)
            (k00, k01, k02, k03, k10, k11, k12, k13, k20, k21, k22, k23, k30, k31, k32, k33) = \
                _inv4(a00, a01, a02, a03, a10, a11, a12, a13,
                      a20, a21, a22, a23, a30, a31, a32, a33)
            p00 = complex(ops[o + 32 * _BK], ops[o + 48 * _BK])
            p01 = complex(ops[o + 33 * _BK], ops[o + 49 * _BK])
            p02 = complex(ops[o + 34 * _BK], ops[o + 50 * _BK])
            p03 = complex(ops[o + 35 * _BK], ops[o + 51 * _BK])
            p10 = complex(ops[o + 36 * _BK], ops[o + 52 * _BK])
            p11 = complex(ops[o + 37 * _BK], ops[o + 53 * _BK])
            p12 = complex(ops[o + 38 * _BK], ops[o + 54 * _BK])
            p13 = complex(ops[o + 39 * _BK], ops[o + 55 * _BK])
            p20 = complex(ops[o + 40 * _BK], ops[o + 56 * _BK])
            p21 = complex(ops[o + 41 * _BK], ops[o + 57 * _BK])
            p22 = complex(ops[o + 42 * _BK], ops[o + 58 * _BK])
            p23 = complex(ops[o + 43 * _BK], ops[o + 59 * _BK])
            p30 = complex(ops[o + 44 * _BK], ops[o + 60 * _BK])
            p31 = complex(ops[o + 45 * _BK], ops[o + 61 * _BK])
            p32 = complex(ops[o + 46 * _BK], ops[o + 62 * _BK])
            p33 = complex(ops[o + 47 * _BK], ops[o + 63 * _BK])
            t00 = k00 * p00 + k01 * p10 + k02 * p20 + k03 * p30
            t01 = k00 * p01 + k01 * p11 + k02 * p21 + k03 * p31
            t02 = k00 * p02 + k01 * p12 + k02 * p22 + k03 * p32
            t03 = k00 * p03 + k01 * p13 + k02 * p23 + k03 * p33
            t10 = k10 * p00 + k11 * p10 + k12 * p20 + k13 * p30
            t11 = k10 * p01 + k11 * p11 + k12 * p21 + k13 * p31
            t12 = k10 * p02 + k11 * p12 + k12 * p22 + k13 * p32
            t13 = k10 * p03 + k11 * p13 + k12 * p23 + k13 * p33
            t20 = k20 * p00 + k21 * p10 + k22 * p20 + k23 * p30
            t21 = k20 * p01 + k21 * p11 + k22 * p21 + k23 * p31
            t22 = k20 * p02 + k21 * p12 + k22 * p22 + k23 * p32
            t23 = k20 * p03 + k21 * p13 + k22 * p23 + k23 * p33
            t30 = k30 * p00 + k31 * p10 + k32 * p20 + k33 * p30
            t31 = k30 * p01 + k31 * p11 + k32 * p21 + k33 * p31
            t32 = k30 * p02 + k31 * p12 + k32 * p22 + k33 * p32
            t33 = k30 * p03 + k31 * p13 + k32 * p23 + k33 * p33
            V[vb + j + 0 * _BK] = (t00.real * k00.real + t00.imag * k00.imag + t01.real * k01.real
                + t01.imag * k01.imag + t02.real * k02.real + t02.imag * k02.imag
                + t03.real * k03.real + t03.imag * k03.imag)
            V[vb + j + 1 * _BK] = (t10.real * k10.real + t10.imag * k10.imag + t11.real * k11.real
                + t11.imag * k11.imag + t12.real * k12.real + t12.imag * k12.imag
                + t13.real * k13.real + t13.imag * k13.imag)
            V[vb + j + 2 * _BK] = (t20.real * k20.real + t20.imag * k20.imag + t21.real * k21.real
                + t21.imag * k21.imag + t22.real * k22.real + t22.imag * k22.imag
                + t23.real * k23.real + t23.imag * k23.imag)
            V[vb + j + 3 * _BK] = (t30.real * k30.real + t30.imag * k30.imag + t31.real * k31.real
                + t31.imag * k31.imag + t32.real * k32.real + t32.imag * k32.imag
                + t33.real * k33.real + t33.imag * k33.imag)
            V[vb + j + 4 * _BK] = (t00.real * k10.real + t00.imag * k10.imag + t01.real * k11.real
                + t01.imag * k11.imag + t02.real * k12.real + t02.imag * k12.imag
                + t03.real * k13.real + t03.imag * k13.imag)
            V[vb + j + 5 * _BK] = (t00.real * k20.real + t00.imag * k20.imag + t01.real * k21.real
                + t01.imag * k21.imag + t02.real * k22.real + t02.imag * k22.imag
                + t03.real * k23.real + t03.imag * k23.imag)
            V[vb + j + 6 * _BK] = (t00.real * k30.real + t00.imag * k30.imag + t01.real * k31.real
                + t01.imag * k31.imag + t02.real * k32.real + t02.imag * k32.imag
                + t03.real * k33.real + t03.imag * k33.imag)
            V[vb + j + 7 * _BK] = (t10.real * k20.real + t10.imag * k20.imag + t11.real * k21.real
                + t11.imag * k21.imag + t12.real * k22.real + t12.imag * k22.imag
                + t13.real * k23.real + t13.imag * k23.imag)
            V[vb + j + 8 * _BK] = (t10.real * k30.real + t10.imag * k30.imag + t11.real * k31.real
                + t11.imag * k31.imag + t12.real * k32.real + t12.imag * k32.imag
                + t13.real * k33.real + t13.imag * k33.imag)
            V[vb + j + 9 * _BK] = (t20.real * k30.real + t20.imag * k30.imag + t21.real * k31.real
                + t21.imag * k31.imag + t22.real * k32.real + t22.imag * k32.imag
                + t23.real * k33.real + t23.imag * k33.imag)


@nb.njit(cache=True, error_model="numpy")
def _band_features(bd, ceq, keq, rinv, V):
    """The final pass's band work, fused and written out: per band ``Delta``, ``K`` as in
    :func:`_band_power`, then ``E = Delta K`` and the 48 features of ``E`` and ``R = E PB
    E^H`` (the diagonal of R, the real and imaginary parts of its upper triangle and of E,
    as :func:`planner.screen_kernels.metric_form` orders them) into V (``_NFEAT _BK`` per
    block: feature i of band ``blk _BK + j`` at ``(_NFEAT blk + i) _BK + j``). Straight-line,
    vectorized over bands as :func:`_band_power`. Generated code
    (:mod:`planner.screen_codegen`)."""
    ops, outer, cbar = bd.blocks, bd.outer, bd.cbar
    nblk = (bd.w.size + _BK - 1) // _BK
    c0 = ceq[0]
    q0 = keq[0]
    c1 = ceq[1]
    q1 = keq[1]
    c2 = ceq[2]
    q2 = keq[2]
    c3 = ceq[3]
    q3 = keq[3]
    c4 = ceq[4]
    q4 = keq[4]
    c5 = ceq[5]
    q5 = keq[5]
    c6 = ceq[6]
    q6 = keq[6]
    c7 = ceq[7]
    q7 = keq[7]
    cb0 = cbar[0]
    cb1 = cbar[1]
    cb2 = cbar[2]
    cb3 = cbar[3]
    o0_0 = outer[4, 0]
    o0_1 = outer[4, 1]
    o0_4 = outer[4, 4]
    o0_5 = outer[4, 5]
    o1_10 = outer[5, 10]
    o1_11 = outer[5, 11]
    o1_14 = outer[5, 14]
    o1_15 = outer[5, 15]
    o2_0 = outer[6, 0]
    o2_1 = outer[6, 1]
    o2_4 = outer[6, 4]
    o2_5 = outer[6, 5]
    o3_10 = outer[7, 10]
    o3_11 = outer[7, 11]
    o3_14 = outer[7, 14]
    o3_15 = outer[7, 15]
    for blk in range(nblk):
        ob = blk * _NOPS * _BK
        rb = blk * 16 * _BK
        vb = blk * _NFEAT * _BK
        for j in range(_BK):
            o = ob + j
            r = rb + j
            jk = ops[o + 64 * _BK]
            g0 = c0 * complex(rinv[r + 0 * _BK], rinv[r + 8 * _BK]) - cb0 + complex(0.0, q0 * jk)
            g1 = c1 * complex(rinv[r + 1 * _BK], rinv[r + 9 * _BK]) - cb1 + complex(0.0, q1 * jk)
            g2 = c2 * complex(rinv[r + 2 * _BK], rinv[r + 10 * _BK]) - cb2 + complex(0.0, q2 * jk)
            g3 = c3 * complex(rinv[r + 3 * _BK], rinv[r + 11 * _BK]) - cb3 + complex(0.0, q3 * jk)
            e0 = c4 * complex(rinv[r + 4 * _BK], rinv[r + 12 * _BK]) + complex(0.0, q4 * jk)
            e1 = c5 * complex(rinv[r + 5 * _BK], rinv[r + 13 * _BK]) + complex(0.0, q5 * jk)
            e2 = c6 * complex(rinv[r + 6 * _BK], rinv[r + 14 * _BK]) + complex(0.0, q6 * jk)
            e3 = c7 * complex(rinv[r + 7 * _BK], rinv[r + 15 * _BK]) + complex(0.0, q7 * jk)
            d00 = g0 + o0_0 * e0 + o2_0 * e2
            d01 = o0_1 * e0 + o2_1 * e2
            d10 = o0_4 * e0 + o2_4 * e2
            d11 = g1 + o0_5 * e0 + o2_5 * e2
            d22 = g2 + o1_10 * e1 + o3_10 * e3
            d23 = o1_11 * e1 + o3_11 * e3
            d32 = o1_14 * e1 + o3_14 * e3
            d33 = g3 + o1_15 * e1 + o3_15 * e3
            h00 = complex(ops[o + 0 * _BK], ops[o + 16 * _BK])
            h01 = complex(ops[o + 1 * _BK], ops[o + 17 * _BK])
            h02 = complex(ops[o + 2 * _BK], ops[o + 18 * _BK])
            h03 = complex(ops[o + 3 * _BK], ops[o + 19 * _BK])
            h10 = complex(ops[o + 4 * _BK], ops[o + 20 * _BK])
            h11 = complex(ops[o + 5 * _BK], ops[o + 21 * _BK])
            h12 = complex(ops[o + 6 * _BK], ops[o + 22 * _BK])
            h13 = complex(ops[o + 7 * _BK], ops[o + 23 * _BK])
            h20 = complex(ops[o + 8 * _BK], ops[o + 24 * _BK])
            h21 = complex(ops[o + 9 * _BK], ops[o + 25 * _BK])
            h22 = complex(ops[o + 10 * _BK], ops[o + 26 * _BK])
            h23 = complex(ops[o + 11 * _BK], ops[o + 27 * _BK])
            h30 = complex(ops[o + 12 * _BK], ops[o + 28 * _BK])
            h31 = complex(ops[o + 13 * _BK], ops[o + 29 * _BK])
            h32 = complex(ops[o + 14 * _BK], ops[o + 30 * _BK])
            h33 = complex(ops[o + 15 * _BK], ops[o + 31 * _BK])
            a00 = 1.0 - (h00 * d00 + h01 * d10)
            a01 = -(h00 * d01 + h01 * d11)
            a02 = -(h02 * d22 + h03 * d32)
            a03 = -(h02 * d23 + h03 * d33)
            a10 = -(h10 * d00 + h11 * d10)
            a11 = 1.0 - (h10 * d01 + h11 * d11)
            a12 = -(h12 * d22 + h13 * d32)
            a13 = -(h12 * d23 + h13 * d33)
            a20 = -(h20 * d00 + h21 * d10)
            a21 = -(h20 * d01 + h21 * d11)
            a22 = 1.0 - (h22 * d22 + h23 * d32)
            a23 = -(h22 * d23 + h23 * d33)
            a30 = -(h30 * d00 + h31 * d10)
            a31 = -(h30 * d01 + h31 * d11)
            a32 = -(h32 * d22 + h33 * d32)
            a33 = 1.0 - (h32 * d23 + h33 * d33)
            (k00, k01, k02, k03, k10, k11, k12, k13, k20, k21, k22, k23, k30, k31, k32, k33) = \
                _inv4(a00, a01, a02, a03, a10, a11, a12, a13,
                      a20, a21, a22, a23, a30, a31, a32, a33)
            pb00 = complex(ops[o + 65 * _BK], ops[o + 81 * _BK])
            pb01 = complex(ops[o + 66 * _BK], ops[o + 82 * _BK])
            pb02 = complex(ops[o + 67 * _BK], ops[o + 83 * _BK])
            pb03 = complex(ops[o + 68 * _BK], ops[o + 84 * _BK])
            pb10 = complex(ops[o + 69 * _BK], ops[o + 85 * _BK])
            pb11 = complex(ops[o + 70 * _BK], ops[o + 86 * _BK])
            pb12 = complex(ops[o + 71 * _BK], ops[o + 87 * _BK])
            pb13 = complex(ops[o + 72 * _BK], ops[o + 88 * _BK])
            pb20 = complex(ops[o + 73 * _BK], ops[o + 89 * _BK])
            pb21 = complex(ops[o + 74 * _BK], ops[o + 90 * _BK])
            pb22 = complex(ops[o + 75 * _BK], ops[o + 91 * _BK])
            pb23 = complex(ops[o + 76 * _BK], ops[o + 92 * _BK])
            pb30 = complex(ops[o + 77 * _BK], ops[o + 93 * _BK])
            pb31 = complex(ops[o + 78 * _BK], ops[o + 94 * _BK])
            pb32 = complex(ops[o + 79 * _BK], ops[o + 95 * _BK])
            pb33 = complex(ops[o + 80 * _BK], ops[o + 96 * _BK])
            x00 = d00 * k00 + d01 * k10
            x01 = d00 * k01 + d01 * k11
            x02 = d00 * k02 + d01 * k12
            x03 = d00 * k03 + d01 * k13
            x10 = d10 * k00 + d11 * k10
            x11 = d10 * k01 + d11 * k11
            x12 = d10 * k02 + d11 * k12
            x13 = d10 * k03 + d11 * k13
            x20 = d22 * k20 + d23 * k30
            x21 = d22 * k21 + d23 * k31
            x22 = d22 * k22 + d23 * k32
            x23 = d22 * k23 + d23 * k33
            x30 = d32 * k20 + d33 * k30
            x31 = d32 * k21 + d33 * k31
            x32 = d32 * k22 + d33 * k32
            x33 = d32 * k23 + d33 * k33
            t00 = x00 * pb00 + x01 * pb10 + x02 * pb20 + x03 * pb30
            t01 = x00 * pb01 + x01 * pb11 + x02 * pb21 + x03 * pb31
            t02 = x00 * pb02 + x01 * pb12 + x02 * pb22 + x03 * pb32
            t03 = x00 * pb03 + x01 * pb13 + x02 * pb23 + x03 * pb33
            t10 = x10 * pb00 + x11 * pb10 + x12 * pb20 + x13 * pb30
            t11 = x10 * pb01 + x11 * pb11 + x12 * pb21 + x13 * pb31
            t12 = x10 * pb02 + x11 * pb12 + x12 * pb22 + x13 * pb32
            t13 = x10 * pb03 + x11 * pb13 + x12 * pb23 + x13 * pb33
            t20 = x20 * pb00 + x21 * pb10 + x22 * pb20 + x23 * pb30
            t21 = x20 * pb01 + x21 * pb11 + x22 * pb21 + x23 * pb31
            t22 = x20 * pb02 + x21 * pb12 + x22 * pb22 + x23 * pb32
            t23 = x20 * pb03 + x21 * pb13 + x22 * pb23 + x23 * pb33
            t30 = x30 * pb00 + x31 * pb10 + x32 * pb20 + x33 * pb30
            t31 = x30 * pb01 + x31 * pb11 + x32 * pb21 + x33 * pb31
            t32 = x30 * pb02 + x31 * pb12 + x32 * pb22 + x33 * pb32
            t33 = x30 * pb03 + x31 * pb13 + x32 * pb23 + x33 * pb33
            V[vb + j + 0 * _BK] = (t00.real * x00.real + t00.imag * x00.imag + t01.real * x01.real
                + t01.imag * x01.imag + t02.real * x02.real + t02.imag * x02.imag
                + t03.real * x03.real + t03.imag * x03.imag)
            V[vb + j + 1 * _BK] = (t10.real * x10.real + t10.imag * x10.imag + t11.real * x11.real
                + t11.imag * x11.imag + t12.real * x12.real + t12.imag * x12.imag
                + t13.real * x13.real + t13.imag * x13.imag)
            V[vb + j + 2 * _BK] = (t20.real * x20.real + t20.imag * x20.imag + t21.real * x21.real
                + t21.imag * x21.imag + t22.real * x22.real + t22.imag * x22.imag
                + t23.real * x23.real + t23.imag * x23.imag)
            V[vb + j + 3 * _BK] = (t30.real * x30.real + t30.imag * x30.imag + t31.real * x31.real
                + t31.imag * x31.imag + t32.real * x32.real + t32.imag * x32.imag
                + t33.real * x33.real + t33.imag * x33.imag)
            z0 = t00 * np.conj(x10) + t01 * np.conj(x11) + t02 * np.conj(x12) + t03 * np.conj(x13)
            z1 = t00 * np.conj(x20) + t01 * np.conj(x21) + t02 * np.conj(x22) + t03 * np.conj(x23)
            z2 = t00 * np.conj(x30) + t01 * np.conj(x31) + t02 * np.conj(x32) + t03 * np.conj(x33)
            z3 = t10 * np.conj(x20) + t11 * np.conj(x21) + t12 * np.conj(x22) + t13 * np.conj(x23)
            z4 = t10 * np.conj(x30) + t11 * np.conj(x31) + t12 * np.conj(x32) + t13 * np.conj(x33)
            z5 = t20 * np.conj(x30) + t21 * np.conj(x31) + t22 * np.conj(x32) + t23 * np.conj(x33)
            V[vb + j + 4 * _BK] = z0.real
            V[vb + j + 10 * _BK] = z0.imag
            V[vb + j + 5 * _BK] = z1.real
            V[vb + j + 11 * _BK] = z1.imag
            V[vb + j + 6 * _BK] = z2.real
            V[vb + j + 12 * _BK] = z2.imag
            V[vb + j + 7 * _BK] = z3.real
            V[vb + j + 13 * _BK] = z3.imag
            V[vb + j + 8 * _BK] = z4.real
            V[vb + j + 14 * _BK] = z4.imag
            V[vb + j + 9 * _BK] = z5.real
            V[vb + j + 15 * _BK] = z5.imag
            V[vb + j + 16 * _BK] = x00.real
            V[vb + j + 32 * _BK] = x00.imag
            V[vb + j + 17 * _BK] = x01.real
            V[vb + j + 33 * _BK] = x01.imag
            V[vb + j + 18 * _BK] = x02.real
            V[vb + j + 34 * _BK] = x02.imag
            V[vb + j + 19 * _BK] = x03.real
            V[vb + j + 35 * _BK] = x03.imag
            V[vb + j + 20 * _BK] = x10.real
            V[vb + j + 36 * _BK] = x10.imag
            V[vb + j + 21 * _BK] = x11.real
            V[vb + j + 37 * _BK] = x11.imag
            V[vb + j + 22 * _BK] = x12.real
            V[vb + j + 38 * _BK] = x12.imag
            V[vb + j + 23 * _BK] = x13.real
            V[vb + j + 39 * _BK] = x13.imag
            V[vb + j + 24 * _BK] = x20.real
            V[vb + j + 40 * _BK] = x20.imag
            V[vb + j + 25 * _BK] = x21.real
            V[vb + j + 41 * _BK] = x21.imag
            V[vb + j + 26 * _BK] = x22.real
            V[vb + j + 42 * _BK] = x22.imag
            V[vb + j + 27 * _BK] = x23.real
            V[vb + j + 43 * _BK] = x23.imag
            V[vb + j + 28 * _BK] = x30.real
            V[vb + j + 44 * _BK] = x30.imag
            V[vb + j + 29 * _BK] = x31.real
            V[vb + j + 45 * _BK] = x31.imag
            V[vb + j + 30 * _BK] = x32.real
            V[vb + j + 46 * _BK] = x32.imag
            V[vb + j + 31 * _BK] = x33.real
            V[vb + j + 47 * _BK] = x33.imag
# END GENERATED CODE by planner.screen_codegen (third elements)


@nb.njit(cache=True, error_model="numpy")
def _row_powers(rows, V, w2inv, vsum, svv, sss):
    """Every row's velocity and travel power summed over the bands, ``r (sum_k V_k) r^T`` and
    ``r (sum_k V_k / w_k^2) r^T`` (the row's form is linear in V: the bands' sums of V's 10
    entries first, in band order, then one quadratic form per row); vsum: scratch (20,)."""
    nf = w2inv.size
    for q in range(20):
        vsum[q] = 0.0
    nblk = (nf + _BK - 1) // _BK
    for blk in range(nblk):
        vb = blk * 10 * _BK
        nj = min(_BK, nf - blk * _BK)
        for q in range(10):
            a1 = 0.0
            a2 = 0.0
            for j in range(nj):
                v = V[vb + q * _BK + j]
                a1 += v
                a2 += v * w2inv[blk * _BK + j]
            vsum[q] += a1
            vsum[10 + q] += a2
    for r in range(rows.shape[0]):
        svv[r] = _row_power(rows[r], vsum, 0, 1)
        sss[r] = _row_power(rows[r], vsum, 10, 1)


@nb.njit(cache=True, error_model="numpy")
def _row_power(r, V, o, step):
    """``r V r^T`` of a band (r real (4,); V from :func:`_band_power`, the band's entries at
    ``o + q step``)."""
    acc = (r[0] * r[0] * V[o] + r[1] * r[1] * V[o + step] + r[2] * r[2] * V[o + 2 * step]
           + r[3] * r[3] * V[o + 3 * step])
    acc += 2.0 * (r[0] * r[1] * V[o + 4 * step] + r[0] * r[2] * V[o + 5 * step]
                  + r[0] * r[3] * V[o + 6 * step] + r[1] * r[2] * V[o + 7 * step]
                  + r[1] * r[3] * V[o + 8 * step] + r[2] * r[3] * V[o + 9 * step])
    return acc


@nb.njit(cache=True, error_model="numpy")
def _secant(sig, new, s_prev, h_prev, c, it):
    """The fixed point's safeguarded secant step on ``sig[c]`` (as the plain kernels')."""
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


@nb.njit(cache=True, error_model="numpy")
def _record(sig, sigs, svv, sss, live, any_spring, hist, it):
    """Store iteration ``it``'s iterate and residual in log space (``y = log sigma``,
    ``f = log g(sigma) - y`` over the velocity RMS rows then the travel RMS rows; zero where a
    row is dead) into hist's ring (rows ``2 (it % (D + 1))`` and the next, D = _AA_DEPTH).
    Returns False when a residual is not finite (a zero power): no acceleration then, and
    the history restarts (hist's last row counts the stored iterates)."""
    nr = sig.size
    slot = 2 * (it % (_AA_DEPTH + 1))
    y, f = hist[slot], hist[slot + 1]
    for r in range(nr):
        y[r] = 0.0
        f[r] = 0.0
        y[nr + r] = 0.0
        f[nr + r] = 0.0
        if not live[r]:
            continue
        if svv[r] <= 0.0 or sig[r] <= 0.0:
            hist[-1, 0] = 0.0
            return False
        y[r] = math.log(sig[r])
        f[r] = 0.5 * math.log(svv[r]) - y[r]
        if any_spring:
            if sss[r] <= 0.0 or sigs[r] <= 0.0:
                hist[-1, 0] = 0.0
                return False
            y[nr + r] = math.log(sigs[r])
            f[nr + r] = 0.5 * math.log(sss[r]) - y[nr + r]
    hist[-1, 0] = min(hist[-1, 0] + 1.0, _AA_DEPTH + 1.0) if it > 0 else 1.0
    return True


@nb.njit(cache=True, error_model="numpy")
def _anderson(sig, sigs, live, any_spring, hist, it, lsq):
    """Anderson acceleration of the fixed point over all the rows together (the rows are
    coupled through the elements, which the per-row secant does not see): with the last
    ``m <= _AA_DEPTH`` differences of the log iterates ``dY`` and residuals ``dF``
    (:func:`_record`), ``gamma = argmin |f_k - dF gamma|`` (normal equations, lsq: scratch
    (D, D + 1)) and ``y = y_k + f_k - (dY + dF) gamma``. Replaces the secant's next iterate
    (sig, sigs) only where every row stays within a factor 2 of the current one (as the
    secant's safeguard); otherwise the secant's stands."""
    nr = sig.size
    npt = int(hist[-1, 0])
    m = npt - 1
    if m < 1:
        return
    d1 = _AA_DEPTH + 1
    k = 2 * (it % d1)
    yk, fk = hist[k], hist[k + 1]
    n = 2 * nr
    # normal equations of dF (columns i: f_{it-i} - f_{it-i-1}, i = 0..m-1)
    for i in range(m):
        a = 2 * ((it - i) % d1)
        b = 2 * ((it - i - 1) % d1)
        for j in range(i, m):
            c = 2 * ((it - j) % d1)
            e = 2 * ((it - j - 1) % d1)
            acc = 0.0
            for q in range(n):
                acc += (hist[a + 1, q] - hist[b + 1, q]) * (hist[c + 1, q] - hist[e + 1, q])
            lsq[i, j] = acc
            lsq[j, i] = acc
        acc = 0.0
        for q in range(n):
            acc += (hist[a + 1, q] - hist[b + 1, q]) * fk[q]
        lsq[i, m] = acc
    # Cholesky-free Gauss elimination with a relative ridge (m <= 3, symmetric PSD)
    ridge = 0.0
    for i in range(m):
        ridge += lsq[i, i]
    if ridge <= 0.0:
        return
    ridge *= 1e-10
    for i in range(m):
        lsq[i, i] += ridge
    for c in range(m):
        piv = lsq[c, c]
        if piv <= 0.0:
            return
        for i in range(c + 1, m):
            t = lsq[i, c] / piv
            for j in range(c, m + 1):
                lsq[i, j] -= t * lsq[c, j]
    for c in range(m - 1, -1, -1):
        acc = lsq[c, m]
        for j in range(c + 1, m):
            acc -= lsq[c, j] * lsq[j, m]
        lsq[c, m] = acc / lsq[c, c]
    lim = math.log(2.0)
    for q in range(n):
        r = q % nr
        if not live[r] or (q >= nr and not any_spring):
            continue
        yn = yk[q] + fk[q]
        for i in range(m):
            a = 2 * ((it - i) % d1)
            b = 2 * ((it - i - 1) % d1)
            yn -= lsq[i, m] * (hist[a, q] - hist[b, q] + hist[a + 1, q] - hist[b + 1, q])
        if not abs(yn - yk[q]) < lim:
            return
    for q in range(n):
        r = q % nr
        if not live[r] or (q >= nr and not any_spring):
            continue
        yn = yk[q] + fk[q]
        for i in range(m):
            a = 2 * ((it - i) % d1)
            b = 2 * ((it - i - 1) % d1)
            yn -= lsq[i, m] * (hist[a, q] - hist[b, q] + hist[a + 1, q] - hist[b + 1, q])
        if q < nr:
            sig[r] = math.exp(yn)
        else:
            sigs[r] = math.exp(yn)


@nb.njit(cache=True, error_model="numpy")
def _dampers(shocks, s, sig, live, means, ceq, ef):
    """The dampers' equivalent damping ``ceq`` at their velocity RMS (and with ``means`` their
    mean force ``ef``: both from one pass, :func:`planner.screen_kernels.gaussian_pwl`'s
    ``E[f(v)]`` and ``E[f'(v)]``, which is the Gaussian equivalent damping), in place."""
    kv, kf, nk, slo, shi = shocks.kv, shocks.kf, shocks.nk, shocks.slo, shocks.shi
    for r in range(sig.size):
        if not live[r]:
            continue
        if means:
            ef[r], ceq[r] = gaussian_pwl(0.0, sig[r], 0.0, kv[s, r], kf[s, r], nk[s, r],
                                         slo[s, r], shi[s, r])
        else:
            ceq[r] = _ceq(sig[r], kv[s, r], kf[s, r], nk[s, r], slo[s, r], shi[s, r])


@nb.njit(cache=True, error_model="numpy")
def _means(bd, s, kv, kf, nk, slo, shi, on, s0, bx, bf, bn, bslope, sig, sigs, mu, keq, eg,
           ef, live, scratch, max_newton):
    """Mean corner travel ``mu`` (4) solving ``mu = static + gain sum_r r (ef_r + eg_r)``
    (Newton), the springs' ``keq``, ``eg`` at their travel ``N(r mu, sigs^2)`` (in place),
    given the dampers' mean forces ``ef`` at their zero-mean velocity (:func:`_dampers`);
    scratch: ``(J (4, 4), res (4,), force (4,), Ks (4, 4))``."""
    nr = bd.rows.shape[0]
    rows, gain, static = bd.rows, bd.gain, bd.static
    J, res, force, Ks = scratch
    for _ in range(max_newton):
        for r in range(nr):
            if on[s, r]:
                m = rows[r, 0] * mu[0] + rows[r, 1] * mu[1] + rows[r, 2] * mu[2] + \
                    rows[r, 3] * mu[3]
                eg[r], keq[r] = gaussian_pwl(m, sigs[r], s0[s, r], bx[s, r], bf[s, r],
                                             bn[s, r], 0.0, bslope[s, r])
            else:
                eg[r] = 0.0
                keq[r] = 0.0
        for a in range(4):
            fa = 0.0
            for r in range(nr):
                fa += rows[r, a] * (ef[r] + eg[r])
            force[a] = fa
        for c in range(4):  # the springs' stiffness at the corners, sum_r keq_r r r^T
            for b in range(4):
                kc = 0.0
                for r in range(nr):
                    kc += keq[r] * rows[r, c] * rows[r, b]
                Ks[c, b] = kc
        for a in range(4):
            acc = static[a]
            for b in range(4):
                acc += gain[a, b] * force[b]
            for b in range(4):  # J = I - gain Ks
                jab = 0.0
                for c in range(4):
                    jab += gain[a, c] * Ks[c, b]
                J[a, b] = -jab
            J[a, a] += 1.0
            res[a] = acc - mu[a]
        solve4(J, res)
        big = 0.0
        for a in range(4):
            mu[a] += res[a]
            big = max(big, abs(res[a]))
        if big < _MEAN_TOL_M:
            break
    for r in range(nr):
        if on[s, r]:
            m = rows[r, 0] * mu[0] + rows[r, 1] * mu[1] + rows[r, 2] * mu[2] + rows[r, 3] * mu[3]
            eg[r], keq[r] = gaussian_pwl(m, sigs[r], s0[s, r], bx[s, r], bf[s, r], bn[s, r],
                                         0.0, bslope[s, r])


@nb.njit(cache=True, error_model="numpy")
def _screen_third_one(bd, shocks, stops, s, max_iter, tol, out_m, sig, elem, scratch):
    """Screen setup s: the fixed point on every row's velocity (and travel) RMS, then the
    metrics. Returns the iterations taken. scratch: :func:`_scratch`'s (one per chunk of
    setups: allocating per setup costs more than a setup's band work)."""
    kv, kf, nk, slo, shi, lag = shocks
    on, s0, bx, bf, bn, bslope = stops
    rblk, V, st, live, solve, hist, lsq, vsum = scratch
    nf = bd.w.size
    nr = bd.rows.shape[0]
    w, rows = bd.w, bd.rows
    # the roll-offs 1 / (1 + j w tau) in blocks: rows r (real), 8 + r (imaginary); an unused
    # slot's stay zero (its damping is zero)
    for r in range(nr):
        if not live[r]:
            continue
        for k in range(nf):
            z = 1.0 / (1.0 + 1j * w[k] * lag[s, r])
            o = (k // _BK) * 16 * _BK + k % _BK
            rblk[o + r * _BK] = z.real
            rblk[o + (8 + r) * _BK] = z.imag
    st[:, :] = 0.0
    ceq, keq, eg, ef, sigs, sp, hp, ssp, hsp, svv, sss, mu = (
        st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7], st[8], st[9], st[10], st[11])
    any_spring = False
    for r in range(nr):
        sig[r] = bd.sig0[r]
        sigs[r] = bd.rms0[r]
        any_spring = any_spring or on[s, r] != 0
    for a in range(4):
        mu[a] = bd.static[a]
    it = 0
    for it in range(max_iter):
        _dampers(shocks, s, sig, live, any_spring, ceq, ef)
        if any_spring:
            _means(bd, s, kv, kf, nk, slo, shi, on, s0, bx, bf, bn, bslope, sig, sigs, mu,
                   keq, eg, ef, live, solve, _MEAN_LOOP_ITER)
        _band_power(bd, ceq, keq, rblk, V)
        _row_powers(rows, V, bd.w2inv, vsum, svv, sss)
        ok = _record(sig, sigs, svv, sss, live, any_spring, hist, it)
        change = 0.0
        for r in range(nr):
            if live[r]:
                change = max(change, _secant(sig, math.sqrt(max(svv[r], 0.0)), sp, hp, r, it))
        if any_spring:
            for r in range(nr):
                if live[r]:
                    change = max(change, _secant(sigs, math.sqrt(max(sss[r], 0.0)), ssp, hsp,
                                                 r, it))
        if change < tol:
            break
        if ok:
            _anderson(sig, sigs, live, any_spring, hist, it, lsq)
    _dampers(shocks, s, sig, live, any_spring, ceq, ef)
    if any_spring:
        _means(bd, s, kv, kf, nk, slo, shi, on, s0, bx, bf, bn, bslope, sig, sigs, mu, keq, eg,
               ef, live, solve, _MEAN_MAX_ITER)
    for r in range(nr):
        m = rows[r, 0] * mu[0] + rows[r, 1] * mu[1] + rows[r, 2] * mu[2] + rows[r, 3] * mu[3]
        elem[0, r] = sigs[r] if any_spring else 0.0
        elem[1, r] = m if any_spring else 0.0
        elem[2, r] = keq[r]
        elem[3, r] = eg[r]
        elem[4, r] = ceq[r]
        elem[5, r] = ef[r] if any_spring else 0.0
    _band_features(bd, ceq, keq, rblk, V)
    _metrics_of(bd, V, out_m)
    return it + 1


@nb.njit(cache=True, error_model="numpy")
def _metrics_of(bd, V, out):
    """The metrics from the band features (:func:`_band_features`): each metric's band power
    is ``d0`` plus the linear form F of the band's features, summed over bands."""
    F, d0 = bd.F, bd.d0
    nf = bd.w.size
    p = d0.shape[1]
    pw = np.empty(p)
    for o in range(p):
        out[o] = 0.0
    for k in range(nf):
        vb = (k // _BK) * _NFEAT * _BK + k % _BK
        for o in range(p):
            pw[o] = d0[k, o]
        for i in range(_NFEAT):
            vi = V[vb + i * _BK]
            for o in range(p):
                pw[o] += F[k, i, o] * vi
        for o in range(p):
            out[o] += pw[o]
    for o in range(p):
        out[o] = math.sqrt(max(out[o], 0.0))


@nb.njit(cache=True, error_model="numpy", parallel=True)
def screen_batch_third(bd, shocks, stops, settings, out, n_chunks):
    """Screen setups with third elements, in parallel over setups.

    Parameters
    ----------
    bd : ThirdBands
    shocks : planner.screen_kernels.ShockTables
        Per setup and row (n_setups, n_rows, ...): the corners' shocks, then the elements'
        dampers (a zero curve where an element has none).
    stops : planner.screen_kernels.StopTables
        Per setup and row: the corners' bump stops, then the heave springs (off where none).
    settings : planner.screen_kernels.IterSettings
    out : ThirdOutputs
        Written in place.
    n_chunks : int
        Chunks of setups run in parallel (scratch allocated once per chunk).
    """
    metrics = out.metrics
    sigma = out.sigma
    iters = out.iterations
    elements = out.elements
    max_iter, tol = settings
    n = shocks.kv.shape[0]
    for ch in nb.prange(n_chunks):
        scratch = _scratch(bd)
        for s in range(ch * n // n_chunks, (ch + 1) * n // n_chunks):
            iters[s] = _screen_third_one(bd, shocks, stops, s, max_iter, tol, metrics[s],
                                         sigma[s], elements[s], scratch)


@nb.njit(cache=True, error_model="numpy")
def _scratch(bd):
    """A chunk's scratch for :func:`_screen_third_one`: the roll-offs in blocks, the band
    features, the state (rows: ceq, keq, eg, ef, travel RMS, the two secants' states, the
    band sums, the mean travel), the rows' liveness (a zero row: an unused slot) and the
    mean travel's Newton scratch."""
    nf = bd.w.size
    nr = bd.rows.shape[0]
    nblk = (nf + _BK - 1) // _BK
    live = np.zeros(nr, dtype=np.bool_)
    for r in range(nr):
        live[r] = (bd.rows[r, 0] != 0.0 or bd.rows[r, 1] != 0.0 or bd.rows[r, 2] != 0.0
                   or bd.rows[r, 3] != 0.0)
    return (np.zeros(nblk * 16 * _BK), np.zeros(nblk * _NFEAT * _BK),
            np.zeros((12, max(nr, 4))), live,
            (np.empty((4, 4)), np.empty(4), np.empty(4), np.empty((4, 4))),
            np.zeros((2 * (_AA_DEPTH + 1) + 1, 2 * nr)), np.zeros((_AA_DEPTH, _AA_DEPTH + 1)), np.zeros(20))
