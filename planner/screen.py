"""Fast screening of shock setups in the frequency domain (stochastic linearization).

Each shock is replaced by its equivalent linear damping at the shock velocity
it will see, ``c_eq(sigma_v)`` (the Gaussian stochastic linearization of its
force-velocity curve, :meth:`ident.shocks.ShockModel.equivalent_damping`), with
its lag as a first-order roll-off: ``c(omega) = c_eq / (1 + j omega tau)``.
The velocity RMS comes from the linear closed-loop response to the drive's
cross-spectral matrix, so the two are iterated to consistency. The metrics are
then the band-pass-weighted integrals of the output spectra.

Everything that does not depend on the setup is computed once per drive: the
drive's spectral matrix aggregated into log-spaced frequency bands and pushed
through the rig part of the model (``P = H_vr S H_vr^H`` and friends). Per
setup and band only 4x4 complex algebra remains, compiled with numba and run
in parallel over setups.

Notes
-----
With ``dF = Delta_c v`` and ``Delta_c = diag(c(omega) - c_bar)``, the shock
velocities are ``v = K H_vr u`` with ``K = (I - H_vs Delta_c)^-1``, and an output
``y = H_yr u + H_ys Delta_c K H_vr u``. With ``W = H_ys Delta_c K`` the output
power in a band is ``diag(H_yr S H_yr^H) + 2 Re diag(W Q) + diag(W P W^H)`` with
``P = H_vr S H_vr^H`` and ``Q = H_vr S H_yr^H``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from types import SimpleNamespace

import numba as nb
import numpy as np
import pandas as pd
from scipy import signal
from tqdm.auto import tqdm

from ident.channels import CORNERS, RIG_INPUTS, SHOCK_VELOCITIES
from ident.drive import check_drive_inputs
from ident.model import LOOP_REDUCE_RTOL

__all__ = ["screen_setups", "screen_response", "DriveBands", "drive_bands", "drive_spectrum",
           "metric_rows", "ScreenOperands", "screen_operands", "screen_packed"]

log = logging.getLogger(__name__)

_SQRT2 = math.sqrt(2.0)


def metric_rows(plant):
    """Linear combinations of plant outputs that the spec's metrics are taken of.

    Returns
    -------
    names : list of str
        Metric names (ident.metrics), in spec order, those the plant supports.
    L : ndarray, shape (n_metrics, n_outputs)
    """
    from ident.metrics import METRIC_NAMES

    outs = list(plant.output_names)
    names, rows = [], []
    for name in METRIC_NAMES:
        row = np.zeros(len(outs))
        if name.startswith("ride_height_rms_"):
            axle = ("LF", "RF") if name.endswith("front") else ("LR", "RR")
            chans = [f"ride_height_{c}" for c in axle]
            if not all(c in outs for c in chans):
                continue
            for c in chans:
                row[outs.index(c)] = 0.5
        else:
            chan = name.replace("_rms", "")
            if chan not in outs:
                continue
            row[outs.index(chan)] = 1.0
        names.append(name)
        rows.append(row)
    return names, np.array(rows)


def drive_spectrum(drive, *, n_bands=96, f_min_hz=0.2, nperseg=None, weight=None):
    """The drive's cross-spectral matrix aggregated into log-spaced bands.

    Parameters
    ----------
    drive : ident.drive.Drive
    n_bands : int
        Number of log-spaced bands from `f_min_hz` to the Nyquist frequency.
    f_min_hz : float
        Lowest band edge [Hz].
    nperseg : int, optional
        Welch block length; default about 10 s of samples (0.1 Hz resolution).
    weight : callable, optional
        ``weight(f_hz) -> ndarray``: a power weight applied line by line before
        the lines are summed into bands (e.g. the metric filter's ``|B|^4``, so
        that its steep edges are integrated exactly, not at band centres).

    Returns
    -------
    f_hz : ndarray, shape (n_bands,)
        Power-weighted centre frequency of each band [Hz].
    S : ndarray of complex, shape (n_bands, 7, 7)
        Power of the rig inputs in each band (one-sided, integrated over the
        band, so ``trace`` sums to the inputs' variances): ``S[k, i, j]`` is the
        band's cross-power ``E[conj(U_i) U_j]``... in scipy's convention
        ``csd(x_i, x_j)``.
    """
    u = drive.as_array() - drive.as_array().mean(axis=0)
    fs = drive.fs_hz
    if nperseg is None:
        nperseg = int(min(u.shape[0], 2 ** round(np.log2(10 * fs))))
    f, Pxy = signal.csd(u.T[:, None, :], u.T[None, :, :], fs=fs, window="hann",
                        nperseg=nperseg, axis=-1)  # (7, 7, n_f): conj(X_i) X_j
    df = f[1] - f[0]
    edges = np.geomspace(f_min_hz, fs / 2, n_bands + 1)
    band = np.searchsorted(edges, f, side="right") - 1
    ok = (band >= 0) & (band < n_bands)
    S = np.zeros((n_bands, 7, 7), dtype=complex)
    fc = np.zeros(n_bands)
    wsum = np.zeros(n_bands)
    tot = np.real(np.einsum("iif->f", Pxy))
    wf = np.ones(f.size) if weight is None else np.asarray(weight(f), dtype=float)
    for k in np.flatnonzero(ok):
        S[band[k]] += Pxy[:, :, k] * (df * wf[k])
        fc[band[k]] += f[k] * tot[k]
        wsum[band[k]] += tot[k]
    empty = wsum <= 0
    fc[~empty] /= wsum[~empty]
    fc[empty] = np.sqrt(edges[:-1] * edges[1:])[empty]
    return fc, S


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
#: the packed operands (:func:`_metric_form`) and the kernel agree on.
_PAIRS_A = np.array([0, 0, 0, 1, 1, 2])
_PAIRS_B = np.array([1, 2, 3, 2, 3, 3])
#: Features of one band's loop correction that a metric's band power is linear in: the
#: real diagonal of R = E PB E^H (4), the real and imaginary parts of its upper triangle
#: (6 + 6) and of E = diag(D) K (16 + 16).
_NFEAT = 48


@nb.njit(cache=True, error_model="numpy", inline="always")
def _loop_inverse(Hv, D, A, perm):
    """A <- (I - Hv diag(D))^-1 for one band (4x4, in place Gauss-Jordan, partial pivoting).

    Hv (4, 4) are the velocity responses to dF, D the shocks' linearized damping minus
    c_bar (complex, with the lag); perm (4,) is scratch. A screen-local routine rather than
    ``ident.closedloop._invert_small``: in place (64 complex multiply-adds instead of 128:
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


@nb.njit(cache=True, error_model="numpy")
def _screen_one(w, Hvs, P, PB, F, d0, cbar, sig0, kv, kf, nk, slo, shi, lag,
                max_iter, tol, out, sig_out):
    """Screen one setup: the fixed point on the shock-velocity RMS, then the metrics.

    The fixed point's arithmetic (the loop inverse and the order of the sum
    ``svv[c] = sum_ab Re(K_ca P_ab conj(K_cb))``) is kept as written: the secant step divides
    differences of nearly equal residuals, so a reordered sum (e.g. using P Hermitian) moves
    sigma by up to ~1e-9 relative on some setups. The final pass is rewritten: each metric's
    band power is ``d0`` plus a setup-independent linear form ``F`` (:func:`_metric_form`) of
    the 48 features of ``E = diag(D) K`` and ``R = E PB E^H``.
    """
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
    ceq = np.zeros(4)
    sig = sig0.copy()
    svv = np.zeros(4)
    s_prev = np.zeros(4)
    h_prev = np.zeros(4)
    it = 0
    for it in range(max_iter):
        for c in range(4):
            ceq[c] = _ceq(sig[c], kv[c], kf[c], nk[c], slo[c], shi[c])
            svv[c] = 0.0
        for k in range(nf):
            for c in range(4):
                D[c] = ceq[c] / roll[k, c] - cbar[c]
            _loop_inverse(Hvs[k], D, K, perm)
            for c in range(4):
                acc = 0.0
                for a in range(4):
                    for b in range(4):
                        acc += (K[c, a] * P[k, a, b] * np.conj(K[c, b])).real
                svv[c] += acc
        # fixed point sigma = g(sigma) per corner, accelerated by a secant step on
        # h = g(sigma) - sigma once two iterates exist (safeguarded to a factor 2)
        change = 0.0
        for c in range(4):
            new = math.sqrt(max(svv[c], 0.0))
            change = max(change, abs(new - sig[c]) / max(sig[c], 1e-12))
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
        if change < tol:
            break
    for c in range(4):
        ceq[c] = _ceq(sig[c], kv[c], kf[c], nk[c], slo[c], shi[c])
        sig_out[c] = sig[c]
    for o in range(p):
        out[o] = 0.0
    for k in range(nf):
        for c in range(4):
            D[c] = ceq[c] / roll[k, c] - cbar[c]
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
def _screen_batch(w, Hvs, P, PB, F, d0, cbar, sig0, kv, kf, nk, slo, shi, lag,
                  max_iter, tol, out, sig_out, iters):
    for s in nb.prange(kv.shape[0]):
        iters[s] = _screen_one(w, Hvs, P, PB, F, d0, cbar, sig0, kv[s], kf[s], nk[s],
                               slo[s], shi[s], lag[s], max_iter, tol, out[s], sig_out[s])


def _metric_form(ops):
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
        once per call of :func:`screen_packed`, it takes the per-metric work out of the
        kernel.
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


@dataclass(frozen=True, eq=False)
class DriveBands:
    """A drive's rig-input spectra in log-spaced bands, as the screening integrates them.

    Computed once per drive (:func:`drive_bands`) and shared by every screening
    of any model on that drive.

    Attributes
    ----------
    f_hz : ndarray, shape (n_bands,)
        Power-weighted band centres [Hz] (empty bands dropped).
    S, SB : ndarray of complex, shape (n_bands, 7, 7)
        Band power of the rig inputs (:func:`drive_spectrum`), unweighted and
        weighted by the metric filter's ``|B|^4``.
    fs_hz : float
        The drive's sample rate [Hz].
    band_hz : (float, float)
        Metric band [Hz].
    drive_name : str
    """

    f_hz: np.ndarray
    S: np.ndarray
    SB: np.ndarray
    fs_hz: float
    band_hz: tuple
    drive_name: str


def drive_bands(drive, *, band_hz=(1.0, 20.0), n_bands=96):
    """The band spectra of a drive for screening (see :class:`DriveBands`).

    Parameters
    ----------
    drive : ident.drive.Drive
        At the rate the metrics are taken at.
    band_hz : (float, float)
        Metric band [Hz]: the metric filter's power response ``|B(f)|^4``
        (Butterworth order 4, forward and backward) weights ``SB``.
    n_bands : int
        Log-spaced bands (:func:`drive_spectrum`).

    Returns
    -------
    DriveBands
    """
    sos = signal.butter(4, band_hz, "bandpass", fs=drive.fs_hz, output="sos")

    def b4(f_hz):  # power response of the metric filter applied forward and backward
        return np.abs(signal.sosfreqz(sos, worN=f_hz, fs=drive.fs_hz)[1]) ** 4

    f, S = drive_spectrum(drive, n_bands=n_bands)
    _, SB = drive_spectrum(drive, n_bands=n_bands, weight=b4)
    keep = np.any(np.abs(S) > 0, axis=(1, 2))
    return DriveBands(f_hz=f[keep], S=S[keep], SB=SB[keep], fs_hz=float(drive.fs_hz),
                      band_hz=tuple(band_hz), drive_name=drive.name)


@dataclass(frozen=True, eq=False)
class ScreenOperands:
    """Everything the screening of one model on one drive needs that no setup changes.

    Built by :func:`screen_operands` from the model's response at the band centres;
    small (a few hundred kB), picklable, so it is built once per (model, drive) and
    shipped to the workers of a sweep (:mod:`planner.sweep`) instead of the model.

    Attributes
    ----------
    w : ndarray, shape (n_bands,)
        Band centres [rad/s].
    Hvs : ndarray of complex, shape (n_bands, 4, 4)
        Shock velocities per unit shock force change dF.
    Hys : ndarray of complex, shape (n_bands, n_metrics, 4)
        Metric outputs per unit dF.
    P, PB : ndarray of complex, shape (n_bands, 4, 4)
        Shock-velocity power from the rig inputs, unweighted and metric-filter weighted.
    QB : ndarray of complex, shape (n_bands, 4, n_metrics)
        Weighted cross power of shock velocities and metric outputs.
    d0 : ndarray, shape (n_bands, n_metrics)
        Weighted metric power of the open shock loop (``dF = 0``).
    cbar : ndarray, shape (4,)
        The plant's built-in damping [N s/m].
    sig0 : ndarray, shape (4,)
        Starting shock-velocity RMS of the fixed point [m/s].
    metric_names : tuple of str
    """

    w: np.ndarray
    Hvs: np.ndarray
    Hys: np.ndarray
    P: np.ndarray
    PB: np.ndarray
    QB: np.ndarray
    d0: np.ndarray
    cbar: np.ndarray
    sig0: np.ndarray
    metric_names: tuple


def screen_operands(H, output_names, cbar_n_s_m, bands):
    """The setup-independent operands of the screening (see :class:`ScreenOperands`).

    Parameters
    ----------
    H : ndarray of complex, shape (n_out, 11, n_bands)
        The model's response at ``bands.f_hz``, inputs rig (7) then dF (4).
    output_names : sequence of str
        Must hold the 4 shock velocities.
    cbar_n_s_m : ndarray, shape (4,)
    bands : DriveBands

    Returns
    -------
    ScreenOperands
    """
    outs = list(output_names)
    vi = np.array([outs.index(v) for v in SHOCK_VELOCITIES])
    names, L = metric_rows(SimpleNamespace(output_names=outs))
    w = 2 * np.pi * bands.f_hz
    Hvr = np.transpose(H[vi, :7], (2, 0, 1))  # (nf, 4, 7)
    Hvs = np.ascontiguousarray(np.transpose(H[vi, 7:], (2, 0, 1)))  # (nf, 4, 4)
    Hyr = np.einsum("mo,oif->fmi", L, H[:, :7])  # (nf, p, 7)
    Hys = np.ascontiguousarray(np.einsum("mo,oif->fmi", L, H[:, 7:]))  # (nf, p, 4)
    # S[k, i, j] = sum conj(U_i) U_j: the power of y = H u is H S^T H^H
    St = np.transpose(bands.S, (0, 2, 1))
    SBt = np.transpose(bands.SB, (0, 2, 1))
    HvrH = np.conj(np.transpose(Hvr, (0, 2, 1)))
    P = np.ascontiguousarray(Hvr @ St @ HvrH)  # velocity power per band (linearization)
    PB = np.ascontiguousarray(Hvr @ SBt @ HvrH)  # the same, metric-filter weighted
    QB = np.ascontiguousarray(Hvr @ SBt @ np.conj(np.transpose(Hyr, (0, 2, 1))))  # (nf, 4, p)
    d0 = np.ascontiguousarray(np.real(np.einsum("fmi,fij,fmj->fm", Hyr, SBt, np.conj(Hyr))))
    sig0 = np.sqrt(np.maximum(np.real(np.einsum("faa->a", P)), 1e-18))
    return ScreenOperands(w=w, Hvs=Hvs, Hys=Hys, P=P, PB=PB, QB=QB, d0=d0,
                          cbar=np.asarray(cbar_n_s_m, dtype=float), sig0=sig0,
                          metric_names=tuple(names))


def screen_packed(ops, kv, kf, nk, slo, shi, lag, *, max_iter=30, tol=1e-5):
    """Screen setups given as packed shock curves (the compiled kernel, no chunking).

    Parameters
    ----------
    ops : ScreenOperands
    kv, kf : ndarray, shape (n_setups, 4, n_knots)
        Knot velocities [m/s] and forces [N] per setup and corner, padded past
        ``nk`` (padding is never read).
    nk : ndarray of int, shape (n_setups, 4)
        Knots in use.
    slo, shi : ndarray, shape (n_setups, 4)
        Slopes below the first and above the last knot [N s/m].
    lag : ndarray, shape (n_setups, 4)
        Shock lags [s].
    max_iter, tol
        As :func:`screen_setups`.

    Returns
    -------
    metrics : ndarray, shape (n_setups, n_metrics)
    sigma : ndarray, shape (n_setups, 4)
    iterations : ndarray of int, shape (n_setups,)

    Notes
    -----
    Every setup is computed on its own, from the same operands, so a setup's
    results do not depend on which other setups share the call (bit for bit):
    chunking and the order of chunks change nothing.
    """
    n = kv.shape[0]
    out = np.zeros((n, len(ops.metric_names)))
    sig = np.zeros((n, 4))
    iters = np.zeros(n, dtype=np.int64)
    if n:
        # writable copies: a read-only array (a frozen plant's c_bar) is another numba type,
        # which would compile the kernel a second time
        _screen_batch(ops.w, ops.Hvs, ops.P, ops.PB, _metric_form(ops), ops.d0,
                      np.array(ops.cbar, dtype=float),
                      ops.sig0, kv, kf, nk, slo, shi, lag, int(max_iter), float(tol), out, sig,
                      iters)
    return out, sig, iters


def screen_response(H, output_names, cbar_n_s_m, bands, models, *, max_iter=30, tol=1e-5,
                    chunk_size=20000, progress=False):
    """Screen setups on a frequency response given at the band centres (the engine).

    Parameters
    ----------
    H : ndarray of complex, shape (n_out, 11, n_bands)
        The model's response at ``bands.f_hz``, inputs rig (7) then dF (4).
    output_names : sequence of str
        Must hold the 4 shock velocities.
    cbar_n_s_m : ndarray, shape (4,)
    bands : DriveBands
    models : list of 4-tuples of shock models
    max_iter, tol, chunk_size, progress
        As :func:`screen_setups`.

    Returns
    -------
    names : list of str
        Metric names.
    metrics : ndarray, shape (n_setups, n_metrics)
        SI.
    sigma : ndarray, shape (n_setups, 4)
        Linearized shock-velocity RMS [m/s].
    iterations : ndarray of int, shape (n_setups,)
    """
    from ident.closedloop import _pack_setups

    ops = screen_operands(H, output_names, cbar_n_s_m, bands)
    h = 1.0 / bands.fs_hz
    out = np.zeros((len(models), len(ops.metric_names)))
    sig = np.zeros((len(models), 4))
    iters = np.zeros(len(models), dtype=np.int64)
    starts = range(0, len(models), chunk_size)
    if progress:
        starts = tqdm(starts, desc="screen", unit="chunk")
    for a in starts:
        chunk = models[a:a + chunk_size]
        kv, kf, nk, slo, shi, *_ = _pack_setups(chunk, h)
        lag = np.array([[m.lag_s for m in row] for row in chunk])
        b = a + len(chunk)
        out[a:b], sig[a:b], iters[a:b] = screen_packed(ops, kv, kf, nk, slo, shi, lag,
                                                       max_iter=max_iter, tol=tol)
    return list(ops.metric_names), out, sig, iters


def screen_setups(model, drive, setups, library, *, band_hz=(1.0, 20.0), n_bands=96,
                  max_iter=30, tol=1e-5, reduce_rtol=LOOP_REDUCE_RTOL, chunk_size=20000,
                  progress=False):
    """Predict setups' metrics fast, with each shock linearized (see the module docstring).

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
    drive : ident.drive.Drive
    setups : sequence of planner.setups.Setup
    library : ident.shocks.ShockLibrary
    band_hz : (float, float)
        Metric band [Hz]; the metric filter's power response ``|B(f)|^4``
        (Butterworth order 4, applied forward and backward) weights the bands.
    n_bands : int
        Log-spaced frequency bands of the integration.
    max_iter, tol : int, float
        Fixed-point iterations on the shock-velocity RMS and their relative
        tolerance.
    chunk_size : int
        Setups per compiled batch (bounds memory).

    Returns
    -------
    planner.predict.Predictions
        ``settings["kind"] == "screening"``; diagnostics hold the linearized
        shock-velocity RMS per setup and corner and the iteration counts.
    """
    from planner.predict import as_loop_plant, prepare_drive, resolve_setups

    plant = as_loop_plant(model, reduce_rtol=reduce_rtol)
    drive = prepare_drive(drive, getattr(model, "fs_hz", None))
    check_drive_inputs(drive, getattr(plant, "rig_inputs", RIG_INPUTS), model=plant.name)
    models = resolve_setups(setups, library)
    bands = drive_bands(drive, band_hz=band_hz, n_bands=n_bands)
    H = plant.frequency_response(bands.f_hz)  # (p_all, 11, nf)
    names, out, sig, iters = screen_response(H, plant.output_names, plant.cbar_n_s_m, bands,
                                             models, max_iter=max_iter, tol=tol,
                                             chunk_size=chunk_size, progress=progress)
    return screening_predictions(plant, drive, setups, names, out, sig, iters, band_hz=band_hz,
                                 n_bands=bands.f_hz.size, max_iter=max_iter, tol=tol)


def screening_predictions(plant, drive, setups, names, out, sig, iters, *, band_hz, n_bands,
                          max_iter, tol):
    """The screening's :class:`planner.predict.Predictions` from the kernel's arrays (shared
    by :func:`screen_setups` and :func:`planner.sweep.screen_setups_on`)."""
    from planner.predict import Predictions

    if np.any(iters >= max_iter):
        log.warning("screening: %d setups did not reach the tolerance in %d iterations",
                    int(np.sum(iters >= max_iter)), max_iter)
    ids = pd.DataFrame([s.ids() for s in setups], columns=list(CORNERS))
    table = pd.concat([ids, pd.DataFrame(out, columns=names)], axis=1)
    table.index = pd.Index([s.name for s in setups], name="setup")
    settings = {"kind": "screening", "model": plant.name, "drive": drive.name,
                "band_hz": tuple(band_hz), "n_bands": int(n_bands), "fs_hz": drive.fs_hz,
                "tol": tol, "max_iter": max_iter}
    return Predictions(table=table, setups=tuple(setups), settings=settings,
                       diagnostics={"shock_velocity_rms_linearized": sig, "iterations": iters})
