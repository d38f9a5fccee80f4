"""Fast screening of shock setups in the frequency domain (stochastic linearization).

Each shock is replaced by its equivalent linear damping at the shock velocity
it will see, ``c_eq(sigma_v)`` (the Gaussian stochastic linearization of its
force-velocity curve, :meth:`ident.models.shocks.ShockModel.equivalent_damping`), with
its lag as a first-order roll-off: ``c(omega) = c_eq / (1 + j omega tau)``.
The velocity RMS comes from the linear closed-loop response to the drive's
cross-spectral matrix, so the two are iterated to consistency. The metrics are
then the band-pass-weighted integrals of the output spectra.

Everything that does not depend on the setup is computed once per drive: the
drive's spectral matrix aggregated into log-spaced frequency bands and pushed
through the rig part of the model (``P = H_vr S H_vr^H`` and friends). Per
setup and band only 4x4 complex algebra remains, compiled with numba and run
in parallel over setups (the kernels: :mod:`planner.screen_kernels`).

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
from dataclasses import dataclass
from types import SimpleNamespace

import numba as nb
import numpy as np
import pandas as pd
from scipy import signal
from tqdm.auto import tqdm

from ident.data.channels import CORNERS, RIG_INPUTS, SHOCK_VELOCITIES
from ident.data.drive import check_drive_inputs
from ident.identify.model import LOOP_REDUCE_RTOL
from ident.sim.closedloop import pack_setups
from ident.sim.metrics import METRIC_NAMES
from planner.predict import Predictions, as_loop_plant, prepare_drive, resolve_setups
from planner.screen_kernels import band_operands, metric_form, screen_batch, screen_batch_scalar

__all__ = ["screen_setups", "screen_response", "describe_agreement", "WEAK_AGREEMENT_SPEARMAN", "DriveBands", "drive_bands", "drive_spectrum",
           "metric_rows", "ScreenOperands", "screen_operands", "screen_packed"]

log = logging.getLogger(__name__)

#: Spearman rank correlation (screening against time-domain scores) below which the two
#: are said to agree only weakly on the order: at 0.8 about one pair in ten is swapped.
WEAK_AGREEMENT_SPEARMAN = 0.8


def describe_agreement(agreement, *, what="ranking"):
    """One sentence on how far screening and the time domain agree, for where results are read.

    Parameters
    ----------
    agreement : Mapping
        ``spearman`` (float, NaN with fewer than 3 setups), ``n`` (int, setups in both)
        and ``same_best`` (bool); optionally ``screening_best`` and ``time_best`` (setup
        names), as :class:`planner.rank.Ranking`, :class:`planner.sweep.Sweep` and a
        screening what-if (``settings["agreement"]``) hold them.
    what : str or None
        What the time domain decides (``"ranking"``), said at the end; None: nothing.

    Returns
    -------
    str
        E.g. ``"screening and the time domain agree: the same best setup, Spearman 0.91
        over 41 setups; the ranking is the time domain's"``; a disagreement on the best
        setup names both and says which to trust.

    Examples
    --------
    >>> describe_agreement({"spearman": 0.52, "n": 50, "same_best": False,
    ...                     "screening_best": "A", "time_best": "B"}, what=None)
    "screening and the time domain DISAGREE on the best setup: screening's best 'A' is not the time domain's 'B' (Spearman 0.52 over 50 setups)"
    """
    rho, n = float(agreement.get("spearman", float("nan"))), int(agreement.get("n", 0))
    corr = (f"Spearman {rho:.2f} over {n} setups" if np.isfinite(rho) else
            f"{n} setup(s), too few for a rank correlation")
    tail = "" if what is None else f"; the {what} is the time domain's"
    if not agreement.get("same_best", True):
        names = ""
        if agreement.get("screening_best") and agreement.get("time_best"):
            names = (f": screening's best '{agreement['screening_best']}' is not the time "
                     f"domain's '{agreement['time_best']}'")
        return (f"screening and the time domain DISAGREE on the best setup{names} ({corr})"
                + ("" if what is None else
                   f": the {what} is the time domain's; screening only chose what to simulate"))
    if np.isfinite(rho) and rho < WEAK_AGREEMENT_SPEARMAN:
        return (f"screening and the time domain agree on the best setup but only weakly on the "
                f"order ({corr}){tail}")
    return f"screening and the time domain agree: the same best setup, {corr}{tail}"


def metric_rows(plant):
    """Linear combinations of plant outputs that the spec's metrics are taken of.

    Returns
    -------
    names : list of str
        Metric names (ident.sim.metrics), in spec order, those the plant supports.
    L : ndarray, shape (n_metrics, n_outputs)
    """
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
    drive : ident.data.drive.Drive
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
    drive : ident.data.drive.Drive
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


#: Batches of fewer setups are screened by the scalar kernel
#: (:func:`planner.screen_kernels.screen_batch_scalar`: the same numbers, about 2.4x slower
#: per setup, but compiled in 6 s instead of 30-40 s): at 8,000 setups/s a batch below this
#: takes under 0.3 s, less than the vectorized kernel's compilation costs a fresh machine.
_VECTOR_MIN_SETUPS = 2000


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
        F = metric_form(ops)
        if n < _VECTOR_MIN_SETUPS:
            screen_batch_scalar(ops.w, ops.Hvs, ops.P, ops.PB, F, ops.d0,
                                np.array(ops.cbar, dtype=float), ops.sig0, kv, kf, nk, slo,
                                shi, lag, int(max_iter), float(tol), out, sig, iters)
            return out, sig, iters
        Fp = np.zeros(F.shape[:2] + (-(-F.shape[2] // 4) * 4,))  # metrics padded with zeros
        Fp[:, :, :F.shape[2]] = F
        screen_batch(ops.w, band_operands(ops), Fp, ops.d0,
                     np.array(ops.cbar, dtype=float),
                     ops.sig0, kv, kf, nk, slo, shi, lag, int(max_iter), float(tol), out, sig,
                     iters, min(n, 4 * nb.get_num_threads()))
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
        kv, kf, nk, slo, shi, *_ = pack_setups(chunk, h)
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
    drive : ident.data.drive.Drive
    setups : sequence of planner.setups.Setup
    library : ident.models.library.ShockLibrary
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
