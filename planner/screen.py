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

Third elements (heave and roll elements per axle, issue 38): each element's damper is
linearized as a shock at its own velocity RMS and adds ``m c(w) m^T`` (``m`` its row over
the corners) to ``Delta_c``, which becomes a (block-diagonal) dense 4x4; a heave spring is
linearized as a bump stop on the element's travel. The same formulas hold with ``W = H_ys
Delta_c K``; a separate kernel runs them (:mod:`planner.screen_third_kernels`), and a car
without third elements keeps the plain kernels and their numbers
(:func:`screen_setups`' ``third``, :func:`resolve_third`, :class:`ThirdChoices`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from types import SimpleNamespace

import numba as nb
import numpy as np
import pandas as pd
from scipy import signal
from scipy.special import erfc
from tqdm.auto import tqdm

from ident.data.channels import CORNERS, RIG_INPUTS, SHOCK_VELOCITIES
from ident.data.drive import check_drive_inputs
from ident.data.third import THIRD_ELEMENTS, element_axle
from ident.models.shocks import LinearShock
from ident.identify.model import LOOP_REDUCE_RTOL
from ident.sim.closedloop import corner_values, pack_bump_stops
from ident.sim.metrics import METRIC_NAMES
from planner.errors import PlannerError
from planner.elements import model_setup_third
from planner.options import ElementOptions, ScreenOptions, as_options
from planner.plant import as_loop_plant
from planner.predict import Predictions, prepare_drive, resolve_setups
from planner.screen_kernels import (
    STOP_ROWS,
    BandData,
    IterSettings,
    ScreenOutputs,
    ShockTables,
    StopTables,
    TravelData,
    band_operands,
    gaussian_pwl,
    metric_blocks,
    metric_form,
    padded_bands,
    screen_batch,
    screen_batch_scalar,
)
from planner.screen_third_kernels import (
    THIRD_BLOCK_BANDS,
    ThirdBands,
    ThirdOutputs,
    screen_batch_third,
)

__all__ = [
    "LIFTOFF_LINEAR_LIMIT",
    "TIRE_CONTACT_MIN_SIGMAS",
    "WEAK_AGREEMENT_SPEARMAN",
    "DISAGREE_SCORE_GAP",
    "DriveBands",
    "F_MIN_HZ",
    "ElementOperands",
    "ScreenOperands",
    "ThirdChoices",
    "describe_agreement",
    "drive_bands",
    "drive_spectrum",
    "element_metric_rows",
    "element_operands",
    "metric_rows",
    "resolve_third",
    "screen_operands",
    "screen_packed",
    "screen_packed_elements",
    "screen_response",
    "screen_setups",
    "third_bands",
    "tire_force_statistics",
]

log = logging.getLogger(__name__)

#: Spearman rank correlation (screening against time-domain scores) below which the two
#: are said to agree only weakly on the order: at 0.8 about one pair in ten is swapped.
WEAK_AGREEMENT_SPEARMAN = 0.8
#: Share by which the time domain's best may score better than screening's best (both in the
#: time domain) for a differing best to be the expected near-tie, not a disagreement.
DISAGREE_SCORE_GAP = 0.01


def describe_agreement(agreement, *, what="ranking"):
    """One sentence on how far screening and the time domain agree, for where results are read.

    Screening is the linearized pre-selection: it chooses which setups to simulate. The time
    domain (the nonlinear shocks) decides, so its result is the one to use. When the best
    setups score close together, screening's best and the time domain's differ often and
    harmlessly; the sentence says so, and calls the disagreement out (``DISAGREE``) only when
    the time domain's best was outside the setups screening chose to simulate, or scores
    better than screening's best by more than :data:`DISAGREE_SCORE_GAP` in the time domain.

    Parameters
    ----------
    agreement : Mapping
        ``spearman`` (float, NaN with fewer than 3 setups), ``n`` (int, setups in both)
        and ``same_best`` (bool); optionally ``screening_best`` and ``time_best`` (setup
        names), ``time_best_screening_rank`` (int, screening's rank of the time domain's
        best), ``top`` (int, the setups screening chose to simulate), ``score_gap``
        (float, screening's best's time-domain score over the time domain's best's, less
        1) and ``polished`` (bool, the time domain's best is a click setting the click
        polish found), as :class:`planner.rank.Ranking`, :class:`planner.sweep.Sweep` and
        a screening what-if (``settings["agreement"]``) hold them. Without the gap and the
        rank, a differing best is called out.
    what : str or None
        What the time domain decides (``"ranking"``), said at the end; None: nothing.

    Returns
    -------
    str
        E.g. ``"screening and the time domain agree: the same best setup, Spearman 0.91
        over 41 setups; the ranking is the time domain's"``; a differing best setup names
        both and says which to trust.

    Examples
    --------
    >>> describe_agreement({"spearman": 0.52, "n": 50, "same_best": False,
    ...                     "screening_best": "A", "time_best": "B"}, what=None)
    "screening and the time domain DISAGREE on the best setup: screening's best 'A' is not the time domain's 'B' (Spearman 0.52 over 50 setups); the time domain's is the one to use"
    >>> describe_agreement({"spearman": 0.93, "n": 45, "same_best": False,
    ...                     "screening_best": "A", "time_best": "B", "top": 40,
    ...                     "time_best_screening_rank": 3, "score_gap": 0.002})
    "screening's best 'A' is not the time domain's 'B' (screening's #3), but 'B' scores only 0.2 % better in the time domain: expected when the best setups score this close (Spearman 0.93 over 45 setups); use the ranking: it is the time domain's, and screening is only the linearized pre-selection of what to simulate"
    """
    rho, n = float(agreement.get("spearman", float("nan"))), int(agreement.get("n", 0))
    corr = (f"Spearman {rho:.2f} over {n} setups" if np.isfinite(rho) else
            f"{n} setup(s), too few for a rank correlation")
    tail = "" if what is None else f"; the {what} is the time domain's"
    use = ("; the time domain's is the one to use" if what is None else
           f"; use the {what}: it is the time domain's, and screening is only the linearized "
           "pre-selection of what to simulate")
    if not agreement.get("same_best", True):
        sb, tb = agreement.get("screening_best"), agreement.get("time_best")
        names = f"screening's best '{sb}' is not the time domain's '{tb}'" if sb and tb else ""
        rank, top = agreement.get("time_best_screening_rank"), agreement.get("top")
        gap = agreement.get("score_gap")
        known = rank is not None and top is not None and gap is not None and np.isfinite(gap)
        if names and agreement.get("polished"):
            return (f"{names}, a neighbouring click setting the click polish found: expected, "
                    f"screening orders neighbouring settings less well ({corr}){use}")
        outside = known and not 1 <= rank <= top
        if names and known and not outside and gap <= DISAGREE_SCORE_GAP:
            return (f"{names} (screening's #{int(rank)}), but '{tb}' scores only "
                    f"{100 * max(gap, 0.0):.2g} % better in the time domain: expected when the "
                    f"best setups score this close ({corr}){use}")
        why = []
        if outside:
            why.append(f"'{tb}' was screening's #{int(rank)}, outside the {int(top)} it chose "
                       "to simulate" if rank >= 1 else f"'{tb}' was not among those screened")
        if known and gap > DISAGREE_SCORE_GAP:
            why.append(f"'{tb}' scores {100 * gap:.3g} % better in the time domain")
        said = f": {names}" if names else ""
        said += f"; {' and '.join(why)}" if why else ""
        return (f"screening and the time domain DISAGREE on the best setup{said} ({corr})"
                + use + ("" if not why or what is None else
                         "; screening's linearization misjudges these setups"))
    if np.isfinite(rho) and rho < WEAK_AGREEMENT_SPEARMAN:
        return (f"screening and the time domain agree on the best setup but only weakly on the "
                f"order ({corr}){tail}")
    return f"screening and the time domain agree: the same best setup, {corr}{tail}"


#: Lowest band edge of the screening's bands [Hz] (:func:`drive_spectrum`'s default).
F_MIN_HZ = 0.2


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


def drive_spectrum(drive, *, n_bands=96, f_min_hz=F_MIN_HZ, nperseg=None, weight=None):
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
    f, Pxy = _line_spectrum(drive, nperseg)
    return _band_sums(f, Pxy, drive.fs_hz, n_bands, f_min_hz, weight)


def _line_spectrum(drive, nperseg):
    """The drive's cross-spectral matrix line by line: ``(f_hz (n_f,), Pxy (7, 7, n_f))``."""
    u = drive.as_array() - drive.as_array().mean(axis=0)
    fs = drive.fs_hz
    if nperseg is None:
        nperseg = int(min(u.shape[0], 2 ** round(np.log2(10 * fs))))
    return signal.csd(u.T[:, None, :], u.T[None, :, :], fs=fs, window="hann",
                      nperseg=nperseg, axis=-1)  # (7, 7, n_f): conj(X_i) X_j


def _band_sums(f, Pxy, fs, n_bands, f_min_hz, weight):
    """:func:`drive_spectrum`'s bands from the line spectrum (the lines added in line order)."""
    df = f[1] - f[0]
    edges = np.geomspace(f_min_hz, fs / 2, n_bands + 1)
    band = np.searchsorted(edges, f, side="right") - 1
    ok = np.flatnonzero((band >= 0) & (band < n_bands))
    S = np.zeros((n_bands, 7, 7), dtype=complex)
    fc = np.zeros(n_bands)
    wsum = np.zeros(n_bands)
    tot = np.real(np.einsum("iif->f", Pxy))
    wf = np.ones(f.size) if weight is None else np.asarray(weight(f), dtype=float)
    # unbuffered in-place adds in line order: the sums of a loop over the lines, bit for bit
    np.add.at(S, band[ok], np.moveaxis(Pxy[:, :, ok], -1, 0) * (df * wf[ok])[:, None, None])
    np.add.at(fc, band[ok], f[ok] * tot[ok])
    np.add.at(wsum, band[ok], tot[ok])
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

    lines = _line_spectrum(drive, None)  # one cross-spectral matrix for both weightings
    f, S = _band_sums(*lines, drive.fs_hz, n_bands, F_MIN_HZ, None)
    _, SB = _band_sums(*lines, drive.fs_hz, n_bands, F_MIN_HZ, b4)
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


def element_metric_rows(output_names, elements):
    """The third elements' metrics as linear combinations of plant outputs.

    An element's travel (velocity) is its row over the corners' shock travels
    (velocities), so its band-passed RMS is a metric like the others.

    Parameters
    ----------
    output_names : sequence of str
        Must hold ``shock_travel_XX`` and ``shock_velocity_XX``.
    elements : mapping of str to array_like, shape (4,)
        Declared element (``heave_front`` ...) -> its row
        (:func:`ident.data.third.element_row`).

    Returns
    -------
    names : list of str
        Per element ``<kind>_travel_rms_<axle>`` then ``<kind>_velocity_rms_<axle>``
        (``heave_travel_rms_front``, ...), in the order of `elements`.
    L : ndarray, shape (n_metrics, n_outputs)

    Raises
    ------
    PlannerError
        If the outputs lack the corners' shock travels or velocities.
    """
    outs = list(output_names)
    ti = _corner_rows(outs, "shock_travel", "third elements")
    vi = _corner_rows(outs, "shock_velocity", "third elements")
    names, rows = [], []
    for e, row in elements.items():
        kind, axle = e.split("_")
        for what, idx in (("travel", ti), ("velocity", vi)):
            r = np.zeros(len(outs))
            r[idx] = np.asarray(row, dtype=float)
            names.append(f"{kind}_{what}_rms_{axle}")
            rows.append(r)
    return names, np.array(rows).reshape(len(rows), len(outs))


def screen_operands(H, output_names, cbar_n_s_m, bands, *, elements=None):
    """The setup-independent operands of the screening (see :class:`ScreenOperands`).

    Parameters
    ----------
    H : ndarray of complex, shape (n_out, 11, n_bands)
        The model's response at ``bands.f_hz``, inputs rig (7) then dF (4).
    output_names : sequence of str
        Must hold the 4 shock velocities.
    cbar_n_s_m : ndarray, shape (4,)
    bands : DriveBands
    elements : mapping of str to array_like, optional
        Third elements (name -> row): their metrics (:func:`element_metric_rows`) follow
        the spec's. None (default): the spec's metrics only.

    Returns
    -------
    ScreenOperands
    """
    outs = list(output_names)
    vi = np.array([outs.index(v) for v in SHOCK_VELOCITIES])
    names, L = metric_rows(SimpleNamespace(output_names=outs))
    if elements:
        more, L_more = element_metric_rows(outs, elements)
        names, L = list(names) + more, np.vstack([L, L_more])
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


#: The screening's estimate of the smallest contact force (``tire_contact_min_XX``): the
#: Gaussian contact force's mean less this many standard deviations, floored at zero. 3.5:
#: the expected minimum of a Gaussian record of a few thousand independent samples (a
#: 60-120 s drive whose tire force has a 10-20 Hz bandwidth: sqrt(2 ln N) = 3.3-3.6).
TIRE_CONTACT_MIN_SIGMAS = 3.5
#: Lift-off share (0-1) above which the screening's Gaussian lift-off estimate is said to
#: need the time domain (logged): lift-off clips the contact force on one side, which no
#: linearization represents; below ~1 % its effect on the metrics is small and the
#: screening leaves the metrics linear.
LIFTOFF_LINEAR_LIMIT = 0.01


@dataclass(frozen=True, eq=False)
class ElementOperands:
    """What screening with bump stops or static loads needs of the model beyond
    :class:`ScreenOperands` (:func:`element_operands`; setup-independent).

    Attributes
    ----------
    jinv : ndarray, shape (n_blocks * 16,)
        ``-1 / w`` per band [s/rad] (padded with zeros, :func:`planner.screen_kernels.padded_bands`):
        the travel ``s = v / (j w)`` the stops' equivalent stiffness acts on.
    w2inv : ndarray, shape (n_bands,)
        ``1 / w^2`` per band: the travel power from the velocity power.
    travel_gain_m_n : ndarray, shape (4, 4)
        Static shock travel per unit dF [m/N] (the model's ``shock_travel_XX`` rows at 0 Hz).
    travel_static_m : ndarray, shape (4,)
        Static shock travel of the drive's mean rig inputs [m].
    travel_rms0_m : ndarray, shape (4,)
        Starting travel RMS of the fixed point (no shock force) [m].
    tire : tuple or None
        With static loads: ``(gain, static, Hts, Qt, d0t)``, the tire forces' static gain
        from dF (4, 4) [N/N], static tire force of the drive's mean (4,) [N], their
        response to dF per band (n_bands, 4, 4), the unweighted cross power of the shock
        velocities and tire forces from the rig (n_bands, 4, 4) and the tire forces' power
        with dF = 0 (n_bands, 4).
    """

    jinv: np.ndarray
    w2inv: np.ndarray
    travel_gain_m_n: np.ndarray
    travel_static_m: np.ndarray
    travel_rms0_m: np.ndarray
    tire: tuple | None


def _corner_rows(output_names, kind, why):
    """Rows of ``<kind>_XX`` (4) in the outputs, or a PlannerError naming what needs them."""
    outs = list(output_names)
    names = [f"{kind}_{c}" for c in CORNERS]
    missing = [n for n in names if n not in outs]
    if missing:
        raise PlannerError(f"screen_setups: {why} needs the model's outputs {missing}; identify "
                           f"the model with those channels (or screen without {why})")
    return [outs.index(n) for n in names]


def element_operands(plant, drive, bands, ops, *, travel=True, tire=False):
    """The setup-independent operands of the elements (see :class:`ElementOperands`).

    Parameters
    ----------
    plant : LoopPlant
        With ``shock_travel_XX`` outputs (and ``tire_force_XX`` with `tire`).
    drive : ident.data.drive.Drive
        At the model's rate (its mean rig inputs set the static travel).
    bands : DriveBands
    ops : ScreenOperands
        Of the same plant and bands.
    travel : bool
        The travel's operands (bump stops); False: zeros (static loads alone).
    tire : bool
        Also the tire forces' operands (static loads: lift-off estimates).

    Returns
    -------
    ElementOperands

    Raises
    ------
    PlannerError
        If the plant lacks the travel (or tire-force) outputs.
    """
    ti = _corner_rows(plant.output_names, "shock_travel", "bump_stops") if travel else None
    H0 = np.real(plant.frequency_response(np.array([0.0]))[:, :, 0])  # (p, 11)
    u_mean = drive.as_array().mean(axis=0)
    w = ops.w
    w2inv = 1.0 / w ** 2
    sigs0 = np.sqrt(np.maximum(np.real(np.einsum("faa,f->a", ops.P, w2inv)), 1e-18))
    tire_ops = None
    if tire:
        fi = _corner_rows(plant.output_names, "tire_force", "static_corner_load_n")
        H = plant.frequency_response(bands.f_hz)
        outs = list(plant.output_names)
        vi = [outs.index(v) for v in SHOCK_VELOCITIES]
        St = np.transpose(bands.S, (0, 2, 1))
        Hvr = np.transpose(H[vi, :7], (2, 0, 1))
        Htr = np.transpose(H[fi, :7], (2, 0, 1))
        Hts = np.ascontiguousarray(np.transpose(H[fi, 7:], (2, 0, 1)))
        Qt = Hvr @ St @ np.conj(np.transpose(Htr, (0, 2, 1)))
        d0t = np.real(np.einsum("fmi,fij,fmj->fm", Htr, St, np.conj(Htr)))
        tire_ops = (H0[fi, 7:11], H0[fi, :7] @ u_mean, Hts, Qt, d0t)
    if travel:
        gain, still = np.ascontiguousarray(H0[ti, 7:11]), H0[ti, :7] @ u_mean
    else:
        gain, still = np.zeros((4, 4)), np.zeros(4)
    return ElementOperands(jinv=padded_bands(-1.0 / w), w2inv=w2inv, travel_gain_m_n=gain,
                           travel_static_m=still, travel_rms0_m=sigs0, tire=tire_ops)


def tire_force_statistics(ops, eops, lag, elements):
    """Mean and standard deviation of the tire forces at the screening's linearization.

    Parameters
    ----------
    ops : ScreenOperands
    eops : ElementOperands
        With ``tire`` (:func:`element_operands` with ``tire=True``).
    lag : ndarray, shape (n_setups, 4)
        Shock lags [s].
    elements : ndarray, shape (n_setups, 6, 4)
        The kernels' element rows (:func:`screen_packed_elements`), with the shocks' mean
        forces filled in where the kernel left them (setups without a stop).

    Returns
    -------
    mean, std : ndarray, shape (n_setups, 4)
        Tire force [N] (the model's sign: added to the static load it is the contact
        force), over the whole band of the drive (not the metric band).
    """
    gain, static, Hts, Qt, d0t = eops.tire
    w = ops.w
    keq, ceq = elements[:, 2], elements[:, 4]
    mean = static[None, :] + (elements[:, 5] + elements[:, 3]) @ gain.T
    var = np.zeros_like(mean)
    eye = np.eye(4)
    for a in range(0, lag.shape[0], 256):  # bounded memory: 256 setups x bands x 4 x 4
        sl = slice(a, a + 256)
        D = (ceq[sl, None, :] / (1.0 + 1j * w[None, :, None] * lag[sl, None, :])
             - ops.cbar[None, None, :] + 1j * keq[sl, None, :] * eops.jinv[None, :w.size, None])
        K = np.linalg.inv(eye - ops.Hvs[None] * D[:, :, None, :])
        W = Hts[None] @ (D[..., :, None] * K)  # (n, nf, 4 tires, 4 corners)
        pw = (d0t[None] + 2.0 * np.real(np.einsum("nfab,fba->nfa", W, Qt))
              + np.real(np.einsum("nfab,fbc,nfac->nfa", W, ops.P, np.conj(W))))
        var[sl] = pw.sum(axis=1)
    return mean, np.sqrt(np.maximum(var, 0.0))


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
    return _run_packed(ops, None, ShockTables(kv, kf, nk, slo, shi, lag), None, max_iter,
                       tol)[:3]


def screen_packed_elements(ops, eops, kv, kf, nk, slo, shi, lag, stops, *, max_iter=30,
                           tol=1e-5):
    """:func:`screen_packed` with bump stops (the stops' stochastic linearization).

    Parameters
    ----------
    ops : ScreenOperands
    eops : ElementOperands
        Of the same model and drive (:func:`element_operands`).
    kv, kf, nk, slo, shi, lag
        As :func:`screen_packed`.
    stops : tuple or None
        The setups' bump stops packed by :func:`ident.sim.closedloop.pack_bump_stops`
        (``on, s0, bx, bf, bn, bslope``); None: none (the numbers of :func:`screen_packed`).
    max_iter, tol
        As :func:`screen_setups`; the tolerance holds for the travel RMS too.

    Returns
    -------
    metrics, sigma, iterations
        As :func:`screen_packed`.
    elements : ndarray, shape (n_setups, 6, 4)
        Per setup and corner the rows of :data:`planner.screen_kernels.STOP_ROWS`: the
        linearized travel RMS [m] and mean travel [m] (zero in setups without a stop), the
        stops' equivalent stiffness ``E[g'(s)]`` [N/m] and mean force ``E[g(s)]`` [N], the
        shocks' equivalent damping [N s/m] and mean force [N] (the latter zero in setups
        without a stop).
    """
    return _run_packed(ops, eops, ShockTables(kv, kf, nk, slo, shi, lag), stops, max_iter,
                       tol)


def _no_stops(n):
    """Packed bump stops of n setups without any (the kernels' arguments)."""
    return (np.zeros((n, 4), dtype=np.int64), np.zeros((n, 4)), np.zeros((n, 4, 2)),
            np.zeros((n, 4, 2)), np.full((n, 4), 2, dtype=np.int64), np.zeros((n, 4)))


def _run_packed(ops, eops, shocks, stops, max_iter, tol):
    """The kernels on packed setups (``shocks``: :class:`~planner.screen_kernels.ShockTables`,
    ``stops``: as :func:`screen_packed_elements`): (metrics, sigma, iterations, elements)."""
    n = shocks.kv.shape[0]
    out = ScreenOutputs(metrics=np.zeros((n, len(ops.metric_names))), sigma=np.zeros((n, 4)),
                        iterations=np.zeros(n, dtype=np.int64),
                        elements=np.zeros((n, len(STOP_ROWS), 4)))
    if not n:
        return tuple(out)
    if stops is None:
        stops = _no_stops(n)
    if eops is None:
        if np.any(stops[0]):
            raise TypeError("screen_packed_elements: bump stops need the element operands "
                            "(eops = element_operands(...))")
        travel = TravelData(jinv=padded_bands(np.zeros(ops.w.size)), w2inv=np.zeros(ops.w.size),
                            gain=np.zeros((4, 4)), static=np.zeros(4), rms0=np.zeros(4))
    else:
        travel = TravelData(jinv=eops.jinv, w2inv=eops.w2inv, gain=eops.travel_gain_m_n,
                            static=eops.travel_static_m, rms0=eops.travel_rms0_m)
    stops = StopTables(*(np.ascontiguousarray(a) for a in stops))
    settings = IterSettings(max_iter=int(max_iter), tol=float(tol))
    F = metric_form(ops)
    Fp = np.zeros(F.shape[:2] + (-(-F.shape[2] // 4) * 4,))  # metrics padded with zeros
    Fp[:, :, :F.shape[2]] = F
    # writable copies: a read-only array (a frozen plant's c_bar) is another numba type,
    # which would compile the kernel a second time
    Fq, d0q = metric_blocks(F, ops.d0)
    plant = BandData(w=ops.w, Hvs=ops.Hvs, P=ops.P, PB=ops.PB, blocks=band_operands(ops), F=Fp,
                     d0=ops.d0, cbar=np.array(ops.cbar, dtype=float), sig0=ops.sig0, Fq=Fq,
                     d0q=d0q, wpad=padded_bands(ops.w))
    if n < _VECTOR_MIN_SETUPS:
        screen_batch_scalar(plant, shocks, stops, travel, settings, out)
    else:
        screen_batch(plant, shocks, stops, travel, settings, out,
                     min(n, 4 * nb.get_num_threads()))
    return tuple(out)


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
        # each distinct shock packed once, no lag discretization (the screening uses none)
        kv, kf, nk, slo, shi, lag = _pack_rows(chunk, h)
        b = a + len(chunk)
        out[a:b], sig[a:b], iters[a:b] = screen_packed(ops, kv, kf, nk, slo, shi, lag,
                                                       max_iter=max_iter, tol=tol)
    return list(ops.metric_names), out, sig, iters


def screen_setups(model, drive, setups, library, *, band_hz=(1.0, 20.0), screen=ScreenOptions(),
                  reduce_rtol=LOOP_REDUCE_RTOL, progress=False, bump_stops=None,
                  static_corner_load_n=None, third=None):
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
    screen : planner.options.ScreenOptions
        ``n_bands`` (log-spaced frequency bands of the integration), ``max_iter`` and
        ``tol`` (fixed-point iterations on the shock-velocity RMS and their relative
        tolerance), ``chunk_size`` (setups per compiled batch, bounds memory).
    reduce_rtol : float or None
        See :func:`planner.plant.as_loop_plant`.
    bump_stops : sequence, optional
        One entry per setup, in the closed loop's form
        (:func:`ident.sim.closedloop.simulate_batch`, ``bump_stops=``): None, or 4 (or a
        mapping corner ->) None or ``(contact_travel_m, travel_table_m, force_table_n)``
        (:func:`ident.models.bumpstops.contact_tables` builds one setup's). Each stop is
        linearized with the shocks (see Notes). Needs the model's ``shock_travel_XX``.
        None (default): today's screening, the same numbers.
    static_corner_load_n : array_like, shape (4,) or mapping, optional
        Static tire load per corner [N] (a corner left out or None: none): adds the
        Gaussian lift-off estimates (see Notes). The metrics are not changed by it. Needs
        the model's ``tire_force_XX``.
    third : ThirdChoices, optional
        The setups' third elements (heave and roll elements per axle), each linearized
        with the shocks (see Notes). None (default): the model's own
        (:func:`resolve_third` of ``model.third``), and for a car without third elements
        (or a plant) none: today's screening, the same numbers.

    Returns
    -------
    planner.predict.Predictions
        ``settings["kind"] == "screening"``; diagnostics hold the linearized
        shock-velocity RMS per setup and corner and the iteration counts. With bump stops
        the table adds ``bump_stop_contact_share_XX`` (0-1; for every corner where any
        setup has a stop, 0 where a setup has none) and the diagnostics the linearized
        travel (``shock_travel_rms_linearized``, ``shock_travel_mean`` [m]) and the stops'
        ``bump_stop_stiffness_eq`` [N/m] and ``bump_stop_force_mean`` [N], each (n_setups,
        4); with static loads ``tire_liftoff_share_XX`` (0-1) and ``tire_contact_min_XX``
        [N] for the corners given.

    Raises
    ------
    PlannerError
        If bump stops or static loads are given for a model without the outputs they
        need, or their count does not match the setups.
    ValueError, TypeError
        On a malformed bump stop or static load (named by setup and corner).

    Notes
    -----
    Bump stops (issue 25): with the travel ``s ~ N(mu_s, sigma_s^2)`` per corner, a stop
    of force ``g(s)`` (zero up to the contact travel ``s0``, then its table extended with
    its last slope) is replaced by its equivalent stiffness ``k_eq = E[g'(s)]`` on the
    travel and its mean force ``E[g(s)]`` (both in closed form over the table's segments,
    :func:`planner.screen_kernels.gaussian_pwl`). The mean force, with the shocks' mean
    force at their Gaussian velocity, moves the static point: ``mu_s`` solves
    ``mu_s = s_drive + H_s(0) (E[f_shock] + E[g(s)])`` (``H_s(0)``: the model's static
    travel gain from the corner forces). The fluctuating part feeds back as
    ``dF = (c_eq(w) - c_bar) v + k_eq v / (j w)``; ``sigma_s`` is the RMS of ``v / (j w)``
    and is iterated with the shock-velocity RMS. ``bump_stop_contact_share_XX`` is the
    Gaussian ``P(s > s0)``. The travel the stops act on is the velocity's integral: exact
    for a physical model; an identified model's own travel rows (which the time domain
    uses, and the travel metrics here) differ from it by its fit error.

    Third elements (issue 38): every damper and spring acts through a row ``m`` over the
    corners (a corner's own: a unit row; a heave or roll element:
    :func:`ident.data.third.element_row`). Each element's damper is linearized as a
    corner shock is, at its own velocity RMS ``sqrt(m P_v m^T)`` (``P_v`` the corners'
    velocity power), and adds ``m c(w) m^T`` to the loop correction, which becomes a
    dense 4x4; a heave spring is linearized as a bump stop on the element's travel
    ``m @ s`` (mean and RMS from the corners'), adding ``m k_eq m^T / (j w)``. The table
    adds per declared element ``<kind>_travel_rms_<axle>`` and
    ``<kind>_velocity_rms_<axle>`` (band-passed as the other metrics) and
    ``heave_spring_contact_share_<axle>`` (where a setup has a heave spring); the
    diagnostics ``third_velocity_rms_linearized`` and ``third_damping_eq`` (n_setups,
    n_elements) and with springs their travel and stiffness. Exact for linear lag-free
    elements, as for the shocks.

    Lift-off has no useful linearization (a one-sided clip of the contact force): the
    metrics stay linear and, with static loads, ``tire_liftoff_share_XX`` is the Gaussian
    ``P(static + tire_force < 0)`` (mean and RMS of the tire force over the drive's whole
    band at the linearization) and ``tire_contact_min_XX`` the Gaussian estimate
    ``max(static + mean - TIRE_CONTACT_MIN_SIGMAS std, 0)``. Above about 1 %
    (:data:`LIFTOFF_LINEAR_LIMIT`, logged) the lift-off changes the metrics: use the time
    domain (:func:`planner.predict.predict_setups`).
    """
    screen = as_options(screen, ScreenOptions, "screen", "screen_setups")
    n_bands, max_iter, tol, chunk_size = (screen.n_bands, screen.max_iter, screen.tol,
                                          screen.chunk_size)
    plant = as_loop_plant(model, reduce_rtol=reduce_rtol)
    drive = prepare_drive(drive, getattr(model, "fs_hz", None))
    check_drive_inputs(drive, getattr(plant, "rig_inputs", RIG_INPUTS), model=plant.name)
    models = resolve_setups(setups, library)
    if third is None:
        third = resolve_third(setups, model, library)
    bands = drive_bands(drive, band_hz=band_hz, n_bands=n_bands)
    H = plant.frequency_response(bands.f_hz)  # (p_all, 11, nf)
    if third is not None:
        return _screen_third(plant, drive, setups, models, bands, H, third, bump_stops,
                             static_corner_load_n, band_hz=band_hz, max_iter=max_iter,
                             tol=tol, chunk_size=chunk_size, progress=progress)
    if bump_stops is None and static_corner_load_n is None:
        names, out, sig, iters = screen_response(H, plant.output_names, plant.cbar_n_s_m,
                                                 bands, models, max_iter=max_iter, tol=tol,
                                                 chunk_size=chunk_size, progress=progress)
        return screening_predictions(plant, drive, setups, names, out, sig, iters,
                                     band_hz=band_hz, n_bands=bands.f_hz.size,
                                     max_iter=max_iter, tol=tol)
    return _screen_elements(plant, drive, setups, models, bands, H, bump_stops,
                            static_corner_load_n, band_hz=band_hz, max_iter=max_iter, tol=tol,
                            chunk_size=chunk_size, progress=progress)


@dataclass(frozen=True, eq=False)
class ThirdChoices:
    """The third elements (heave and roll elements per axle) of a list of setups, resolved
    for the screening (:func:`resolve_third`, or built by hand for a plant).

    Attributes
    ----------
    elements : tuple of str
        The car's declared elements (:data:`ident.data.third.THIRD_ELEMENTS` order): each
        gets its metrics (:func:`element_metric_rows`), fitted or not.
    rows : ndarray, shape (n_elements, 4)
        Their rows over the corners (:func:`ident.data.third.element_row`).
    dampers : tuple
        Per setup, a tuple over `elements` of the damper's shock model (in the element's
        own velocity and force) or None (none fitted).
    springs : tuple
        Per setup, a tuple over `elements` of the heave spring's contact table
        ``(contact_travel_m, travel_m, force_n)`` (gap less packer, on the element's
        travel; :func:`ident.models.bumpstops.contact_tables`) or None (none; always None
        for a roll element).
    columns : dict of str to list, optional
        The setups' choices as the setups CSV names its columns (``heave_front`` -> damper
        ids, ``heave_spring_front`` -> spring ids; ``"none"`` where none), for a caller's
        table (the screening's table does not hold them: its columns past the corners'
        ids are numbers).
    """

    elements: tuple
    rows: np.ndarray
    dampers: tuple
    springs: tuple
    columns: dict | None = None

    def __post_init__(self):
        n = len(self.elements)
        if len(set(self.elements)) != n or not set(self.elements) <= set(THIRD_ELEMENTS):
            raise ValueError(f"ThirdChoices: elements {list(self.elements)}; give each of "
                             f"{list(THIRD_ELEMENTS)} at most once")
        rows = np.asarray(self.rows, dtype=float)
        if rows.shape != (n, 4):
            raise ValueError(f"ThirdChoices: rows must have shape ({n}, 4) for elements "
                             f"{list(self.elements)}, got {rows.shape}; give each element's "
                             "element_row")
        for e, row in zip(self.elements, rows):
            other = (2, 3) if element_axle(e) == "front" else (0, 1)
            if np.any(row[list(other)] != 0.0):
                raise ValueError(f"ThirdChoices: the row of {e} {row.tolist()} reaches the "
                                 "other axle's corners; an element acts on its own axle "
                                 "(give ident.data.third.element_row)")
        object.__setattr__(self, "rows", rows)
        if len(self.dampers) != len(self.springs):
            raise ValueError(f"ThirdChoices: {len(self.dampers)} setups of dampers but "
                             f"{len(self.springs)} of springs; give one entry per setup in each")
        for what, per_setup in (("dampers", self.dampers), ("springs", self.springs)):
            for i, entry in enumerate(per_setup):
                if len(entry) != n:
                    raise ValueError(f"ThirdChoices: {what}[{i}] has {len(entry)} entries for "
                                     f"{n} elements {list(self.elements)}; give one per "
                                     "element (None: none)")


def resolve_third(setups, model, library):
    """The third elements of setups on a model that carries them, for the screening.

    A setup's ``third`` (element -> damper id or None) and ``heave_springs`` (axle ->
    heave spring id or None) choose; an element or axle the setup does not name keeps the
    model's baseline (``model.third.baseline``, with its packers).

    Parameters
    ----------
    setups : sequence of planner.setups.Setup
    model : VehicleModel or any
        ``model.third`` (:class:`ident.data.third.CarThird`) declares the elements; the
        heave springs are ids in ``model.elements.bump_stops``.
    library : ShockLibrary or mapping
        The shocks: the corners' and the third elements' dampers.

    Returns
    -------
    ThirdChoices or None
        None for a model without third elements (no ``third``, or none declared).

    Raises
    ------
    PlannerError
        On a damper id not in the library or a heave spring id not in the model's
        bump-stop library (naming the setup and the element), or a packer thicker than
        its spring's gap.
    """
    if getattr(model, "third", None) is None or not model.third.elements:
        return None
    return third_choices(model_setup_third(setups, model, library, ElementOptions(),
                                           where="screening"))


def third_choices(resolved):
    """The screening's form of third elements resolved for the loop.

    Parameters
    ----------
    resolved : planner.elements.SetupThird or None
        :func:`planner.elements.setup_third` (or :func:`~planner.elements.model_setup_third`)
        of the setups: one resolution of ids serves the time domain and the screening.

    Returns
    -------
    ThirdChoices or None
        None for None.
    """
    if resolved is None:
        return None
    names = tuple(resolved.car.elements.elements)
    rows = np.array([resolved.car.elements.row(e) for e in names])
    dampers, springs = [], []
    for d_list, s_list in resolved.entries:
        dm = {d.name: d.model for d in d_list}
        sp = {sp.name: sp.contact for sp in s_list}
        dampers.append(tuple(dm.get(e) for e in names))
        springs.append(tuple(sp.get(e) if e.startswith("heave") else None for e in names))
    table = resolved.columns(list(range(len(resolved.entries))))
    return ThirdChoices(names, rows, tuple(dampers), tuple(springs),
                        columns={c: table[c].tolist() for c in table.columns})


_THIRD_SLOTS = len(THIRD_ELEMENTS)


def _slots(third):
    """The kernel's slot of each of the choices' elements (ndarray of int, (n_elements,))."""
    return np.array([THIRD_ELEMENTS.index(e) for e in third.elements], dtype=np.int64)


def _slot_rows(third):
    """The 4 slots' rows (4, 4): each element's row in its slot, zero rows elsewhere."""
    rows = np.zeros((_THIRD_SLOTS, 4))
    rows[_slots(third)] = third.rows
    return rows


def _pack_rows(models, h):
    """:func:`ident.sim.closedloop.pack_setups`'s curves for rows of any length (the corners'
    shocks then the elements' dampers): ``kv, kf, nk, slo, shi, lag``, each distinct model
    packed once."""
    del h  # the screening uses no lag discretization
    n, nr = len(models), len(models[0])
    first, uniq = {}, []
    idx = np.empty((n, nr), dtype=np.int64)
    for s, row in enumerate(models):
        for r, mdl in enumerate(row):
            j = first.get(id(mdl))
            if j is None:
                j = first[id(mdl)] = len(uniq)
                uniq.append(mdl)
            idx[s, r] = j
    pwls = [m.to_pwl() for m in uniq]
    K = max(p.v_knots_m_s.size for p in pwls)
    ukv, ukf = np.zeros((len(uniq), K)), np.zeros((len(uniq), K))
    unk = np.zeros(len(uniq), dtype=np.int64)
    for j, p in enumerate(pwls):
        k = p.v_knots_m_s.size
        ukv[j, :k], ukf[j, :k] = p.v_knots_m_s, p.f_knots_n
        ukv[j, k:], ukf[j, k:] = p.v_knots_m_s[-1], p.f_knots_n[-1]
        unk[j] = k
    uslo = np.array([p.slope_below for p in pwls])
    ushi = np.array([p.slope_above for p in pwls])
    ulag = np.array([float(m.lag_s) for m in uniq])
    return ShockTables(ukv[idx], ukf[idx], unk[idx], uslo[idx], ushi[idx], ulag[idx])


def _pack_third(models, third, bump_stops, h):
    """The kernel's per-row tables (:class:`~planner.screen_kernels.ShockTables`,
    :class:`~planner.screen_kernels.StopTables`, rows: the 4 corners then the 4 element
    slots): the corners' shocks and bump stops, the elements' dampers (a zero curve where
    none, and in the unused slots) and heave springs (off where none)."""
    n = len(models)
    zero = LinearShock("none", 0.0)
    slots = _slots(third)

    def in_slots(entries, empty):
        out = [empty] * _THIRD_SLOTS
        for k, x in zip(slots, entries):
            out[k] = empty if x is None else x
        return tuple(out)

    shocks = _pack_rows([tuple(m) + in_slots(dr, zero) for m, dr in zip(models, third.dampers)],
                        h)
    corner = _pack_stops_shared([None] * n if bump_stops is None else list(bump_stops))
    # the element slots' springs packed as 4 "corners"
    first, unique = {}, []  # each distinct set of springs packed once (as the corners')
    index = np.empty(n, dtype=np.int64)
    for i, sp in enumerate(third.springs):
        key = tuple(map(id, sp))
        j = first.get(key)
        if j is None:
            j = first[key] = len(unique)
            unique.append(in_slots(sp, None))
        index[i] = j
    spring = tuple(a[index] for a in pack_bump_stops(
        unique, "screen_setups: third elements' heave springs"))
    width = max(corner[2].shape[2], spring[2].shape[2])
    stops = []
    for a, b in zip(corner, spring):
        if a.ndim == 3:
            a, b = _pad_points(a, width), _pad_points(b, width)
        stops.append(np.ascontiguousarray(np.concatenate([a, b], axis=1)))
    return shocks, StopTables(*stops)


def _pad_points(x, width):
    """A stop table (n, rows, k) padded with its last point to ``width`` points."""
    if x.shape[2] == width:
        return x
    return np.concatenate([x, np.repeat(x[:, :, -1:], width - x.shape[2], axis=2)], axis=2)


def third_bands(ops, eops, rows):
    """The third kernel's band data (:class:`~planner.screen_third_kernels.ThirdBands`).

    Parameters
    ----------
    ops : ScreenOperands
    eops : ElementOperands or None
        The travel's operands (None: no spring anywhere, zeros).
    rows : ndarray, shape (8, 4)
        The corners' unit rows, then the 4 element slots' (zero rows where none).
    """
    nf = ops.w.size

    def entries(A):
        return np.ascontiguousarray(A.reshape(nf, 16).T)

    F = metric_form(ops)
    rows = np.ascontiguousarray(rows, dtype=float)
    outer = np.einsum("ra,rb->rab", rows, rows).reshape(-1, 16)
    Ptot = np.real(ops.P.sum(axis=0))
    sig0 = np.sqrt(np.maximum(np.einsum("ra,ab,rb->r", rows, Ptot, rows), 1e-18))
    w2inv = 1.0 / ops.w ** 2
    Pw = np.real(np.einsum("fab,f->ab", ops.P, w2inv))
    rms0 = np.sqrt(np.maximum(np.einsum("ra,ab,rb->r", rows, Pw, rows), 1e-18))
    if eops is None:
        gain, static = np.zeros((4, 4)), np.zeros(4)
    else:
        gain, static = eops.travel_gain_m_n, eops.travel_static_m
    H, P = entries(ops.Hvs), entries(ops.P)
    bk = THIRD_BLOCK_BANDS
    nblk = -(-nf // bk)
    PB = entries(ops.PB)
    x = np.zeros((97, nblk * bk))
    x[:16, :nf], x[16:32, :nf] = H.real, H.imag
    x[32:48, :nf], x[48:64, :nf] = P.real, P.imag
    x[64, :nf] = -1.0 / ops.w
    x[65:81, :nf], x[81:, :nf] = PB.real, PB.imag
    blocks = np.ascontiguousarray(x.reshape(97, nblk, bk).transpose(1, 0, 2)).reshape(-1)
    return ThirdBands(w=np.array(ops.w, dtype=float), H=H, P=P, PB=PB,
                      blocks=blocks, F=np.ascontiguousarray(F),
                      d0=np.ascontiguousarray(ops.d0), cbar=np.array(ops.cbar, dtype=float),
                      rows=rows, outer=np.ascontiguousarray(outer), sig0=sig0,
                      jinv=-1.0 / ops.w, w2inv=w2inv, gain=np.array(gain, dtype=float),
                      static=np.array(static, dtype=float), rms0=rms0)


def _third_delta(ops, bd, shocks, elem, sl):
    """Delta per setup and band (n, n_bands, 4, 4) at the linearization (the kernel's)."""
    w = ops.w
    ceq, keq = elem[sl, 4], elem[sl, 2]  # (n, rows)
    g = (ceq[:, None, :] / (1.0 + 1j * w[None, :, None] * shocks.lag[sl, None, :])
         + 1j * keq[:, None, :] * bd.jinv[None, :, None])  # (n, nf, rows)
    D = np.einsum("nfr,rab->nfab", g, bd.outer.reshape(-1, 4, 4))
    D -= np.diag(bd.cbar)[None, None]
    return D


def _third_tire_statistics(ops, eops, bd, shocks, elem):
    """:func:`tire_force_statistics` with the loop correction dense (third elements)."""
    gain, static, Hts, Qt, d0t = eops.tire
    n = elem.shape[0]
    forces = (elem[:, 5] + elem[:, 3]) @ bd.rows  # (n, 4): the corners' mean forces
    mean = static[None, :] + forces @ gain.T
    var = np.zeros_like(mean)
    eye = np.eye(4)
    for a in range(0, n, 256):
        sl = slice(a, a + 256)
        D = _third_delta(ops, bd, shocks, elem, sl)
        K = np.linalg.inv(eye - ops.Hvs[None] @ D)
        W = Hts[None] @ (D @ K)
        pw = (d0t[None] + 2.0 * np.real(np.einsum("nfab,fba->nfa", W, Qt))
              + np.real(np.einsum("nfab,fbc,nfac->nfa", W, ops.P, np.conj(W))))
        var[sl] = pw.sum(axis=1)
    return mean, np.sqrt(np.maximum(var, 0.0))


def _screen_third(plant, drive, setups, models, bands, H, third, bump_stops,
                  static_corner_load_n, *, band_hz, max_iter, tol, chunk_size, progress):
    """:func:`screen_setups` with third elements (the corners' bump stops and static loads
    as :func:`_screen_elements` takes them)."""
    n = len(models)
    if not isinstance(third, ThirdChoices):
        raise TypeError(f"screen_setups: third must be a planner.screen.ThirdChoices (see "
                        f"resolve_third), got {type(third).__name__}")
    if len(third.dampers) != n:
        raise PlannerError(f"screen_setups: third has {len(third.dampers)} setups for {n} "
                           "setups; resolve it from the same setups (resolve_third)")
    if bump_stops is not None and len(bump_stops) != n:
        raise PlannerError(f"screen_setups: bump_stops has {len(bump_stops)} entries for {n} "
                           "setups; give one per setup (None: none)")
    lo_on, static = (np.zeros(4, bool), np.zeros(4)) if static_corner_load_n is None else \
        _static_loads(static_corner_load_n)
    ne = len(third.elements)
    ops = screen_operands(H, plant.output_names, plant.cbar_n_s_m, bands,
                          elements=dict(zip(third.elements, third.rows)))
    h = 1.0 / bands.fs_hz
    shocks, stops = _pack_third(models, third, bump_stops, h)
    any_spring = bool(stops.on.any())
    eops = None
    if any_spring or lo_on.any():
        eops = element_operands(plant, drive, bands, ops, travel=any_spring,
                                tire=bool(lo_on.any()))
    rows = np.vstack([np.eye(4), _slot_rows(third)])
    bd = third_bands(ops, eops, rows)
    nr = rows.shape[0]
    out = ThirdOutputs(metrics=np.zeros((n, len(ops.metric_names))), sigma=np.zeros((n, nr)),
                       iterations=np.zeros(n, dtype=np.int64),
                       elements=np.zeros((n, len(STOP_ROWS), nr)))
    settings = IterSettings(max_iter=int(max_iter), tol=float(tol))
    starts = range(0, n, chunk_size)
    if progress:
        starts = tqdm(starts, desc="screen", unit="chunk")
    for a in starts:
        b = min(a + chunk_size, n)
        part = ThirdOutputs(*(x[a:b] for x in out))
        screen_batch_third(bd, ShockTables(*(np.ascontiguousarray(x[a:b]) for x in shocks)),
                           StopTables(*(np.ascontiguousarray(x[a:b]) for x in stops)),
                           settings, part, max(1, min(b - a, 4 * nb.get_num_threads())))
    used = np.r_[0:4, 4 + _slots(third)]  # the corners, then the elements in their order
    out = ThirdOutputs(out.metrics, out.sigma[:, used], out.iterations,
                       out.elements[:, :, used])
    shocks = ShockTables(*(x[:, used] for x in shocks))
    stops = StopTables(*(x[:, used] for x in stops))
    nr = 4 + ne
    bd = bd._replace(rows=bd.rows[used], outer=bd.outer[used])
    elem = out.elements
    if lo_on.any():  # the dampers' mean forces where the kernel had no spring
        for i in np.flatnonzero(~stops.on.any(axis=1)):
            for r in range(nr):
                elem[i, 5, r] = gaussian_pwl(0.0, out.sigma[i, r], 0.0, shocks.kv[i, r],
                                             shocks.kf[i, r], shocks.nk[i, r],
                                             shocks.slo[i, r], shocks.shi[i, r])[0]
    pred = screening_predictions(plant, drive, setups, list(ops.metric_names), out.metrics,
                                 out.sigma[:, :4], out.iterations, band_hz=band_hz,
                                 n_bands=bands.f_hz.size, max_iter=max_iter, tol=tol)
    table, diag = pred.table, dict(pred.diagnostics)
    extra = {}
    on = stops.on.astype(bool)
    if any_spring:
        z = (stops.s0 - elem[:, 1]) / np.maximum(elem[:, 0], 1e-15)
        share = np.where(on, 0.5 * erfc(z / np.sqrt(2.0)), 0.0)
        for c, corner in enumerate(CORNERS):
            if on[:, c].any():
                extra[f"bump_stop_contact_share_{corner}"] = share[:, c]
        for j, e in enumerate(third.elements):
            if on[:, 4 + j].any():
                extra[f"heave_spring_contact_share_{element_axle(e)}"] = share[:, 4 + j]
        diag.update(shock_travel_rms_linearized=elem[:, 0, :4], shock_travel_mean=elem[:, 1, :4],
                    bump_stop_stiffness_eq=elem[:, 2, :4], bump_stop_force_mean=elem[:, 3, :4],
                    third_travel_rms_linearized=elem[:, 0, 4:], third_travel_mean=elem[:, 1, 4:],
                    heave_spring_stiffness_eq=elem[:, 2, 4:],
                    heave_spring_force_mean=elem[:, 3, 4:])
    diag.update(third_elements=tuple(third.elements),
                third_velocity_rms_linearized=out.sigma[:, 4:],
                third_damping_eq=elem[:, 4, 4:])
    if lo_on.any():
        mean, std = _third_tire_statistics(ops, eops, bd, shocks, elem)
        extra.update(_liftoff_columns(static, mean, std, lo_on))
    if extra:
        table = pd.concat([table, pd.DataFrame(extra, index=table.index)], axis=1)
    settings = dict(pred.settings, bump_stops=bool(on[:, :4].any()),
                    static_corner_load_n=static.tolist() if lo_on.any() else None,
                    third_elements=list(third.elements))
    return Predictions(table=table, setups=pred.setups, settings=settings, diagnostics=diag)


def _static_loads(static_corner_load_n):
    """``(on (4,) bool, static (4,))`` from the static loads, checked."""
    vals = corner_values(static_corner_load_n, "screen_setups", "static_corner_load_n")
    on = np.array([v is not None for v in vals])
    static = np.array([np.nan if v is None else float(v) for v in vals])
    for c, ok, val in zip(CORNERS, on, static):
        if ok and not (np.isfinite(val) and val > 0):
            raise PlannerError(f"screen_setups: static_corner_load_n at {c} is {val!r} N; give "
                               "the tire's positive static load (the car at rest on the rig)")
    return on, np.where(on, static, 0.0)


def _pack_stops_shared(per_setup):
    """:func:`ident.sim.closedloop.pack_bump_stops` of the setups' stops, each distinct entry
    (by identity: a sweep repeats a few stop sets over many setups) checked and packed once:
    packing is ~0.2 ms per setup, more than its screening."""
    first = {}
    index = np.empty(len(per_setup), dtype=np.int64)
    unique = []
    for i, entry in enumerate(per_setup):
        j = first.get(id(entry))
        if j is None:
            j = first[id(entry)] = len(unique)
            unique.append(entry)
        index[i] = j
    packed = pack_bump_stops(unique, "screen_setups: bump_stops")
    return tuple(np.ascontiguousarray(a[index]) for a in packed)


def _screen_elements(plant, drive, setups, models, bands, H, bump_stops, static_corner_load_n,
                     *, band_hz, max_iter, tol, chunk_size, progress):
    """:func:`screen_setups` with bump stops and/or static loads."""
    n = len(models)
    if bump_stops is not None and len(bump_stops) != n:
        raise PlannerError(f"screen_setups: bump_stops has {len(bump_stops)} entries for {n} "
                           "setups; give one per setup (None: none)")
    stops = _pack_stops_shared([None] * n if bump_stops is None else list(bump_stops))
    any_stop = bool(stops[0].any())
    lo_on, static = (np.zeros(4, bool), np.zeros(4)) if static_corner_load_n is None else \
        _static_loads(static_corner_load_n)
    ops = screen_operands(H, plant.output_names, plant.cbar_n_s_m, bands)
    eops = None
    if any_stop or lo_on.any():
        eops = element_operands(plant, drive, bands, ops, travel=any_stop,
                                tire=bool(lo_on.any()))
    h = 1.0 / bands.fs_hz
    p = len(ops.metric_names)
    out, sig = np.zeros((n, p)), np.zeros((n, 4))
    iters = np.zeros(n, dtype=np.int64)
    trav = np.zeros((n, len(STOP_ROWS), 4))
    lag = np.zeros((n, 4))
    starts = range(0, n, chunk_size)
    if progress:
        starts = tqdm(starts, desc="screen", unit="chunk")
    for a in starts:
        chunk = models[a:a + chunk_size]
        b = a + len(chunk)
        kv, kf, nk, slo, shi, lag[a:b] = _pack_rows(chunk, h)
        out[a:b], sig[a:b], iters[a:b], trav[a:b] = _run_packed(
            ops, eops, ShockTables(kv, kf, nk, slo, shi, lag[a:b]),
            tuple(x[a:b] for x in stops), max_iter, tol)
        if lo_on.any():
            for i in range(a, b):  # the shocks' mean force where the kernel had no stop
                if not stops[0][i].any():
                    for c in range(4):
                        trav[i, 5, c] = gaussian_pwl(0.0, sig[i, c], 0.0, kv[i - a, c],
                                                     kf[i - a, c], nk[i - a, c],
                                                     slo[i - a, c], shi[i - a, c])[0]
    pred = screening_predictions(plant, drive, setups, list(ops.metric_names), out, sig, iters,
                                 band_hz=band_hz, n_bands=bands.f_hz.size, max_iter=max_iter,
                                 tol=tol)
    table, diag = pred.table, dict(pred.diagnostics)
    extra = {}
    if any_stop:
        on = stops[0].astype(bool)
        s0 = stops[1]
        z = (s0 - trav[:, 1]) / np.maximum(trav[:, 0], 1e-15)
        share = np.where(on, 0.5 * erfc(z / np.sqrt(2.0)), 0.0)
        for c, corner in enumerate(CORNERS):
            if on[:, c].any():
                extra[f"bump_stop_contact_share_{corner}"] = share[:, c]
        diag.update(shock_travel_rms_linearized=trav[:, 0], shock_travel_mean=trav[:, 1],
                    bump_stop_stiffness_eq=trav[:, 2], bump_stop_force_mean=trav[:, 3])
    if lo_on.any():
        mean, std = tire_force_statistics(ops, eops, lag, trav)
        extra.update(_liftoff_columns(static, mean, std, lo_on))
    if extra:
        table = pd.concat([table, pd.DataFrame(extra, index=table.index)], axis=1)
    settings = dict(pred.settings, bump_stops=any_stop,
                    static_corner_load_n=static.tolist() if lo_on.any() else None)
    return Predictions(table=table, setups=pred.setups, settings=settings, diagnostics=diag)


def _liftoff_columns(static, mean, std, lo_on):
    """The Gaussian lift-off estimates' columns (``tire_liftoff_share_XX``,
    ``tire_contact_min_XX``) of the corners with a static load, from the tire forces' mean
    and standard deviation per setup [N], shape (S, 4); warns where lift-off is large."""
    contact = static[None, :] + mean
    lift = 0.5 * erfc(contact / np.maximum(std, 1e-12) / np.sqrt(2.0))
    cmin = np.maximum(contact - TIRE_CONTACT_MIN_SIGMAS * std, 0.0)
    columns = {}
    for c, corner in enumerate(CORNERS):
        if lo_on[c]:
            columns[f"tire_liftoff_share_{corner}"] = lift[:, c]
            columns[f"tire_contact_min_{corner}"] = cmin[:, c]
    worst = float(np.max(lift[:, lo_on]))
    if worst > LIFTOFF_LINEAR_LIMIT:
        log.warning("screening: a Gaussian lift-off share of %.1f %% (above %.0f %%): "
                    "lift-off changes the metrics there, which the screening leaves "
                    "linear; predict those setups in the time domain", 100 * worst,
                    100 * LIFTOFF_LINEAR_LIMIT)
    return columns


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
