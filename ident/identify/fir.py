"""Nonparametric reference model: the identified FRF as FIR filters in the shock loop.

The planner predicts setups with a fitted (parametric) model. To tell fit error
from everything else, :func:`fir_from_frf` turns the estimated FRF itself into
impulse responses (FIR filters) at the FRF's sample rate, and
:func:`simulate_fir_batch` runs them in the same closed loop with the same exact
nonlinear shocks as :func:`ident.sim.closedloop.simulate_batch`, returning the same
:class:`ident.sim.closedloop.BatchResponse`.

Notes
-----
**Conventions.** ``H[o, i, k]`` is the continuous-time frequency response at
``f_k = k fs / n`` (the Welch grid, ``n = nperseg``, ``k = 0 .. n/2``). Rig
signals are samples of band-limited continuous signals, so the response at the
sample instants is the convolution of the input *samples* with the
band-limited discrete equivalent
``h[m] = (1/fs) int_{-fs/2}^{fs/2} H(f) exp(2j pi f m / fs) df``: no hold
(zero- or first-order) is assumed between samples, and the FIR's DTFT is
``H`` on the whole band (up to the kept window: for the paper car within
0.03 % below 0.8 ``fs / 2``; the last part of the band feels the truncated
pre-ringing and the Nyquist bin, which a real FIR makes real). Its samples
on the Welch grid give ``h`` by an inverse real FFT of length ``n``
(``numpy.fft.irfft``: the DC and Nyquist bins enter through their real
parts), aliased with period ``n / fs`` (41 s for the
paper's 4096 samples at 100 Hz; vehicle responses die out long before).

**Causality.** The band-limited equivalent of a causal system is not causal
when the continuous impulse response jumps at ``t = 0`` (relative degree one,
e.g. shock velocity per shock force, or per wheel-pad displacement through a
tire damper): a Gibbs pre-ringing ``~ (-1)^m / (pi^2 |m|)`` of the jump at
negative sample times ``m``, which the inverse FFT wraps to the end of the
period. It carries 1-3 % of such a pair's energy but is worth a relative
error of about ``0.44 f / fs`` in band (4 % at 10 Hz and 100 Hz), so it is
kept: a plant holds ``n_acausal`` taps of negative time ahead of the causal
ones (tap ``l`` is time ``(l - n_acausal) / fs``). The responses to known
signals (the rig inputs; the shock-force deviations once the loop is solved)
are plain two-sided convolutions.

**The shock loop.** The shock force is a nonlinear function of the shock
velocity; sampled at the data rate its harmonics above ``fs / 2`` alias into
the band (a digressive shock with a knee at 2 in/s crosses it in a few ms).
For the paper car with such shocks at 100 Hz this costs up to 3.8 % in RMS
metrics at the data rate, 1 % at 2x, 0.3 % at 4x and 0.1 % at 8x (against
the modal simulator at 16x). The loop therefore runs on a grid
``oversample`` times finer, like :func:`ident.sim.closedloop.simulate_batch`: the
shock-velocity responses to ``dF`` are interpolated band-limited onto it (the
plant does not respond above ``fs / 2``, where the FRF says nothing), the rig
part of the shock velocities likewise, and the shock-force deviations are
decimated back (zero-phase low-pass, :func:`ident.data.drive.resample_bandlimited`)
before the outputs are formed; the shock forces returned are the fine grid's
values at the output instants, as in ``simulate_batch``. At every fine step the
first ``loop_s`` of the velocity responses act directly (their tap 0 through
the algebraic loop, solved exactly as :func:`ident.sim.loop_kernels.loop_one` does: the
curve is piecewise linear, the lag is discretized with
:func:`ident.models.lti.lag_coefficients`); the rest, i.e. the older taps and
the anticausal ones, acts through the ``dF`` of the previous pass, and passes
repeat until ``dF`` changes by less than ``tol`` (a fixed point of the
two-sided discrete model; about a decade per pass).
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, field

import numba as _nb
import numpy as np
from scipy import signal

from ident.data.channels import CORNERS, SHOCK_FORCES, SHOCK_VELOCITIES
from ident.data.drive import FIR_HALF_LENGTH, resample_bandlimited
from ident.errors import FitWarning
from ident.sim.closedloop import (BatchResponse, check_oversample, drive_array, pack_setups,
                                  refine_input, setup_models)
from ident.sim.loop_kernels import ShockCurves, shock_step, solver_state
from ident.identify.frf import MODEL_INPUTS, Frf

__all__ = ["FirPlant", "fir_from_frf", "simulate_fir_batch"]

log = logging.getLogger(__name__)

#: A significant pair with more than this fraction of its impulse-response energy
#: outside the kept window (or removed by the tapers) warns.
MAX_DISCARDED_FRACTION = 1e-2
#: A pair is significant when its energy is at least this fraction of the largest
#: energy among the same output's pairs with inputs of the same quantity.
SIGNIFICANT_ENERGY = 1e-4
#: Most passes of the shock loop before giving up on the fixed point.
MAX_PASSES = 30
#: Two sample rates closer than this (relative) are the same.
RTOL_RATE = 1e-9
#: Zero taps added on each side before the band-limited interpolation of a FIR.
_INTERP_PAD = 32

# inputs of the same physical quantity (for "significant"): forces, moments, displacements
_INPUT_GROUPS = (("aero_heave",) + tuple(f"dF_{c}" for c in CORNERS),
                 ("aero_roll", "aero_pitch"),
                 tuple(f"wheelloader_{c}" for c in CORNERS))


@dataclass(frozen=True, eq=False)
class FirPlant:
    """A vehicle model as FIR filters (impulse responses) around a baseline damping.

    Attributes
    ----------
    h_rig : ndarray, shape (n_out, 7, n_taps)
        Impulse responses from the rig inputs (:data:`ident.data.channels.RIG_INPUTS`)
        [output SI per input SI] at ``fs_hz``; tap ``l`` is time
        ``(l - n_acausal) / fs_hz``.
    h_shock : ndarray, shape (n_out, 4, n_taps)
        Impulse responses from the shock-force deviations ``dF_LF .. dF_RR``
        [output SI per N], same taps.
    fs_hz : float
        Sample rate [Hz] (the FRF's); drives must have it.
    output_names : tuple of str
        Canonical output channels; must contain the 4 ``shock_velocity_XX``.
    cbar_n_s_m : ndarray, shape (4,)
        Baseline damping the shock inputs are written around [N/(m/s)].
    name : str
    settings : dict
        ``n_acausal`` (taps ahead of time 0, default 0) and, from
        :func:`fir_from_frf`: ``length_s``, ``taper_s``, ``acausal_s``,
        ``acausal_taper_s``, ``nperseg``, ``discarded_fraction`` (n_out, 11),
        ``acausal_fraction`` (n_out, 11), ``source`` (the FRF's settings).
    velocity_idx : ndarray of int, shape (4,)
        Indices of ``shock_velocity_LF .. RR`` in ``output_names``.

    Raises
    ------
    ValueError
        If the shock velocities are missing, the shapes disagree, ``fs_hz``
        is not positive or ``n_acausal`` leaves no causal tap.
    """

    h_rig: np.ndarray
    h_shock: np.ndarray
    fs_hz: float
    output_names: tuple
    cbar_n_s_m: np.ndarray
    name: str = "fir"
    settings: dict = field(default_factory=dict)
    velocity_idx: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        names = tuple(self.output_names)
        object.__setattr__(self, "output_names", names)
        missing = [v for v in SHOCK_VELOCITIES if v not in names]
        if missing:
            raise ValueError(f"FIR plant {self.name!r}: outputs lack {missing}; the shock loop "
                             "needs the 4 shock velocities")
        h_rig = np.array(self.h_rig, dtype=float)
        h_shock = np.array(self.h_shock, dtype=float)
        p = len(names)
        if h_rig.ndim != 3 or h_rig.shape[:2] != (p, 7) or h_shock.shape != (p, 4, h_rig.shape[2]):
            raise ValueError(f"FIR plant {self.name!r}: h_rig {h_rig.shape} and h_shock "
                             f"{h_shock.shape} must be ({p}, 7, n_taps) and ({p}, 4, n_taps) "
                             f"for {p} outputs")
        settings = dict(self.settings)
        n_ac = settings.get("n_acausal", 0)
        if isinstance(n_ac, bool) or not isinstance(n_ac, (int, np.integer)) \
                or not 0 <= n_ac <= h_rig.shape[2] - 2:
            raise ValueError(f"FIR plant {self.name!r}: settings['n_acausal'] = {n_ac!r} must be "
                             f"an integer in [0, n_taps - 2 = {h_rig.shape[2] - 2}]")
        settings["n_acausal"] = int(n_ac)
        fs = self.fs_hz
        if isinstance(fs, bool) or not isinstance(fs, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(fs) and fs > 0):
            raise ValueError(f"FIR plant {self.name!r}: fs_hz must be a positive number, "
                             f"got {fs!r}")
        for a in (h_rig, h_shock):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"FIR plant {self.name!r}: the impulse responses hold "
                                 "NaN or inf")
            a.flags.writeable = False
        object.__setattr__(self, "h_rig", h_rig)
        object.__setattr__(self, "h_shock", h_shock)
        object.__setattr__(self, "fs_hz", float(fs))
        object.__setattr__(self, "cbar_n_s_m",
                           np.asarray(self.cbar_n_s_m, dtype=float).reshape(4).copy())
        object.__setattr__(self, "settings", settings)
        object.__setattr__(self, "velocity_idx",
                           np.array([names.index(v) for v in SHOCK_VELOCITIES]))

    @property
    def n_acausal(self):
        """int: Taps ahead of time zero."""
        return self.settings["n_acausal"]

    @property
    def n_taps(self):
        """int: Length of every impulse response (anticausal and causal taps)."""
        return self.h_rig.shape[2]

    def frequency_response(self, f_hz):
        """Frequency response of the FIR filters (their DTFT).

        Parameters
        ----------
        f_hz : array_like, shape (n_f,)
            Frequencies [Hz].

        Returns
        -------
        ndarray of complex, shape (n_out, 11, n_f)
            ``H[output, input, frequency]`` with inputs rig (7) then dF (4)
            (:data:`ident.identify.frf.MODEL_INPUTS`):
            ``sum_l h[l] exp(-2j pi f t_l)``, ``t_l = (l - n_acausal) / fs_hz``.
        """
        f = np.atleast_1d(np.asarray(f_hz, dtype=float))
        t = (np.arange(self.n_taps) - self.n_acausal) / self.fs_hz
        phase = 2 * np.pi * t[:, None] * f[None, :]  # (n_taps, n_f)
        c, s = np.cos(phase), np.sin(phase)
        return np.concatenate([self.h_rig @ c - 1j * (self.h_rig @ s),
                               self.h_shock @ c - 1j * (self.h_shock @ s)], axis=1)


# ----------------------------------------------------------------------------------------------
# FRF -> FIR
# ----------------------------------------------------------------------------------------------

def _half_cosine(n_keep, n_taper):
    """n_keep ones whose last n_taper fall as a half cosine (from just below 1 to just above 0)."""
    w = np.ones(n_keep)
    if n_taper > 0:
        i = np.arange(1, n_taper + 1)
        w[n_keep - n_taper:] = 0.5 * (1 + np.cos(np.pi * i / (n_taper + 1)))
    return w


def _check_seconds(value, name, where):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value < 0:
        raise ValueError(f"{where}: {name} must be a finite number of seconds >= 0, "
                         f"got {value!r}")
    return float(value)


def _check_frf(frf):
    if not isinstance(frf, Frf):
        raise TypeError(f"fir_from_frf: frf must be an ident.identify.frf.Frf, got {type(frf).__name__}")
    if tuple(frf.input_names) != MODEL_INPUTS:
        raise ValueError(f"fir_from_frf: the FRF's inputs must be {list(MODEL_INPUTS)} (rig "
                         f"inputs then dF), got {list(frf.input_names)}")
    n = frf.settings.get("nperseg")
    fs = float(frf.fs_hz)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 4 or n % 2:
        raise ValueError(f"fir_from_frf: the FRF's settings['nperseg'] must be an even block "
                         f"length >= 4, got {n!r}")
    n = int(n)
    grid = np.arange(n // 2 + 1) * fs / n
    f = np.asarray(frf.f_hz, dtype=float)
    if f.shape != grid.shape or not np.allclose(f, grid, rtol=1e-9, atol=1e-9 * fs):
        raise ValueError(f"fir_from_frf: the FRF must be on the full Welch grid k*fs/nperseg, "
                         f"k = 0..{n // 2} ({n // 2 + 1} frequencies, 0 to {fs / 2:g} Hz); got "
                         f"{f.size} frequencies (do not cut the band)")
    H = np.asarray(frf.H)
    if H.shape != (len(frf.output_names), 11, f.size):
        raise ValueError(f"fir_from_frf: H has shape {H.shape}, expected "
                         f"({len(frf.output_names)}, 11, {f.size})")
    bad = ~np.isfinite(H)
    if bad.any():
        o, i, k = np.argwhere(bad)[0]
        raise ValueError(f"fir_from_frf: H has {int(bad.sum())} non-finite value(s) (first: "
                         f"{frf.output_names[o]} / {MODEL_INPUTS[i]} at {f[k]:g} Hz); condition "
                         "the FRF first (ident.identify.condition.condition_frf)")
    return n, fs, H


def fir_from_frf(frf, *, length_s=4.0, taper_s=1.0, acausal_s=0.5, acausal_taper_s=None,
                 name=None):
    """Turn an FRF on the Welch grid into FIR filters (impulse responses).

    Parameters
    ----------
    frf : ident.identify.frf.Frf
        Inputs :data:`ident.identify.frf.MODEL_INPUTS`, on the full Welch grid
        ``k fs / nperseg`` (``k = 0 .. nperseg/2``, DC and Nyquist included;
        ``settings["nperseg"]``), finite everywhere (e.g. conditioned), with
        the 4 shock velocities among the outputs.
    length_s : float
        Causal length kept [s]: ``round(length_s fs)`` taps from time 0,
        2 .. ``nperseg / 2`` of them.
    taper_s : float
        Half-cosine taper over the last `taper_s` of the causal part [s]
        (0: cut square); at most `length_s`.
    acausal_s : float
        Negative-time length kept [s] (0: a causal plant; see the module
        notes for why the default keeps some); at most half the block.
    acausal_taper_s : float, optional
        Half-cosine taper over the earliest `acausal_taper_s` of it [s];
        default half of `acausal_s`.
    name : str, optional
        Plant name (default ``"fir-"`` plus the FRF's method).

    Returns
    -------
    FirPlant
        Taps ``h[(l - n_acausal) mod nperseg]`` of ``irfft(H, nperseg)`` times
        the tapers. ``settings["discarded_fraction"]`` (n_out, 11) is each
        pair's energy fraction not kept: outside the window (the periodic
        tail, earlier negative times) or removed by the tapers;
        ``settings["acausal_fraction"]`` its energy at the kept negative times.

    Raises
    ------
    TypeError
        If `frf` is not an :class:`ident.identify.frf.Frf`.
    ValueError
        If the FRF's inputs, grid or values are unusable (the message says
        why), or a length is negative or does not fit in the block.

    Warns
    -----
    FitWarning
        If a significant pair (energy at least :data:`SIGNIFICANT_ENERGY` of
        the largest among its output's pairs with inputs of the same
        quantity) loses more than :data:`MAX_DISCARDED_FRACTION` of its
        energy: lengthen `length_s` (a slowly decaying response) or
        `acausal_s`, or check the FRF for noise.

    Notes
    -----
    See the module notes for the conventions (band-limited equivalent, no
    hold assumption) and the anticausal part.

    Examples
    --------
    A pure gain becomes one tap at time 0:

    >>> from ident.identify.frf import Frf, MODEL_INPUTS
    >>> n, fs = 64, 100.0
    >>> names = ("shock_velocity_LF", "shock_velocity_RF", "shock_velocity_LR",
    ...          "shock_velocity_RR")
    >>> H = np.zeros((4, 11, n // 2 + 1), complex)
    >>> H[0, 3] = 0.5
    >>> frf = Frf(np.arange(n // 2 + 1) * fs / n, H, MODEL_INPUTS, names, None, None, None,
    ...           None, None, 1, np.zeros(4), fs, {"nperseg": n})
    >>> plant = fir_from_frf(frf, length_s=0.2, taper_s=0.0, acausal_s=0.0)
    >>> plant.h_rig[0, 3, :3].tolist()
    [0.5, 0.0, 0.0]
    """
    where = "fir_from_frf"
    n, fs, H = _check_frf(frf)
    length_s = _check_seconds(length_s, "length_s", where)
    taper_s = _check_seconds(taper_s, "taper_s", where)
    acausal_s = _check_seconds(acausal_s, "acausal_s", where)
    acausal_taper_s = acausal_s / 2 if acausal_taper_s is None else \
        _check_seconds(acausal_taper_s, "acausal_taper_s", where)
    L = int(round(length_s * fs))
    La = int(round(acausal_s * fs))
    if not 2 <= L <= n // 2:
        raise ValueError(f"{where}: length_s={length_s:g} s gives {L} taps at {fs:g} Hz; it must "
                         f"give 2 .. nperseg/2 = {n // 2} ({2 / fs:g} .. {n / 2 / fs:g} s)")
    if La > n // 2 - 1:
        raise ValueError(f"{where}: acausal_s={acausal_s:g} s gives {La} taps; at most "
                         f"nperseg/2 - 1 = {n // 2 - 1} ({(n // 2 - 1) / fs:g} s)")
    nt = int(round(taper_s * fs))
    nta = int(round(acausal_taper_s * fs))
    if nt > L:
        raise ValueError(f"{where}: taper_s={taper_s:g} s is longer than length_s={length_s:g} s")
    if nta > La:
        raise ValueError(f"{where}: acausal_taper_s={acausal_taper_s:g} s is longer than "
                         f"acausal_s={acausal_s:g} s")

    h_full = np.fft.irfft(H, n, axis=-1)  # (p, 11, n), periodic, negative times at the end
    energy = np.sum(h_full**2, axis=-1)
    h = np.roll(h_full, La, axis=-1)[..., :La + L]  # times -La .. L-1
    w = np.concatenate([_half_cosine(La, nta)[::-1], _half_cosine(L, nt)])
    kept = h * w
    with np.errstate(invalid="ignore", divide="ignore"):
        # |h_full - kept|^2: energy outside the window plus what the tapers removed
        lost = energy - np.sum(h**2, axis=-1) + np.sum((h - kept) ** 2, axis=-1)
        discarded = np.where(energy > 0, np.clip(lost / energy, 0.0, 1.0), 0.0)
        acausal = np.where(energy > 0, np.sum(kept[..., :La] ** 2, axis=-1) / energy, 0.0)
    significant = np.zeros(energy.shape, dtype=bool)
    for group in _INPUT_GROUPS:
        cols = [MODEL_INPUTS.index(g) for g in group]
        e = energy[:, cols]
        significant[:, cols] = (e > 0) & (e >= SIGNIFICANT_ENERGY * e.max(axis=1, keepdims=True))
    bad = significant & (discarded > MAX_DISCARDED_FRACTION)
    if bad.any():
        worst = np.argsort(-np.where(bad, discarded, -1.0), axis=None)[:3]
        pairs = [f"{frf.output_names[o]} / {MODEL_INPUTS[i]} ({100 * discarded[o, i]:.2g} %)"
                 for o, i in zip(*np.unravel_index(worst, bad.shape))]
        warnings.warn(
            f"{where}: {int(bad.sum())} significant pair(s) lose more than "
            f"{100 * MAX_DISCARDED_FRACTION:g} % of their impulse-response energy outside "
            f"-{La / fs:g} .. {L / fs:g} s or to the tapers, worst {', '.join(pairs)}; lengthen "
            "length_s or acausal_s, or check the FRF for noise", FitWarning, stacklevel=2)
    settings = {"length_s": L / fs, "taper_s": nt / fs, "acausal_s": La / fs,
                "acausal_taper_s": nta / fs, "n_acausal": La, "nperseg": n,
                "discarded_fraction": discarded, "acausal_fraction": acausal,
                "source": dict(frf.settings)}
    if name is None:
        name = f"fir-{frf.settings.get('method', 'frf')}"
    return FirPlant(h_rig=kept[:, :7], h_shock=kept[:, 7:], fs_hz=fs,
                    output_names=tuple(frf.output_names), cbar_n_s_m=frf.cbar_n_s_m,
                    name=name, settings=settings)


# ----------------------------------------------------------------------------------------------
# the compiled shock loop
# ----------------------------------------------------------------------------------------------

@_nb.njit(cache=True, fastmath={"reassoc", "contract"})
def _history(hrev, dfh, k, out):
    """out[c] = sum_j sum_q hrev[c, j, q] dfh[j, k + q]: the past dF through the taps.

    Reassociated (and on slices, not offset indices) so that the dot products vectorize.
    """
    n = hrev.shape[2]
    for c in range(4):
        acc = 0.0
        for j in range(4):
            hj = hrev[c, j]
            dj = dfh[j, k:k + n]
            s = 0.0
            for q in range(n):
                s += hj[q] * dj[q]
            acc += s
        out[c] = acc


@_nb.njit(cache=True, error_model="numpy")
def _fir_loop_one(hrev, D0, v_free, cbar, kv, kf, nk, slo, shi, alpha, b0, b1, r, dfh, F_out):
    """Shock loop of one setup with the taps 0 .. Lm of the velocity responses.

    ``hrev[c, j, q] = h_vs[c, j, Lm - q]`` (taps Lm .. 1, reversed), ``D0`` tap 0;
    ``v_free`` (4, N) is the velocity without these taps' dF part. ``dfh[j, Lm + k]``
    receives ``dF_k`` (the first Lm entries stay zero: no history); ``F_out[k // r]``
    (N_out, 4) the applied forces of every r-th step. Returns the largest iteration
    count (-1: no convergence).
    """
    m = 4
    N = v_free.shape[1]
    Lm = hrev.shape[2]
    F_prev = np.zeros(m)
    f_prev = np.zeros(m)
    hist = np.zeros(m)
    curves = ShockCurves(kv, kf, nk, slo, shi)
    st = solver_state(curves)
    v = st.v
    vfree = st.vfree
    c0 = st.c0
    fv = st.fv
    worst = 0
    failed = False
    for k in range(N):
        # free response: the rest plus the past dF through taps 1 .. Lm
        _history(hrev, dfh, k, hist)
        for c in range(m):
            vfree[c] = v_free[c, k] + hist[c]
            c0[c] = alpha[c] * F_prev[c] + b1[c] * f_prev[c]
        # v = vfree + D0 (c0 + b0 f(v) - cbar v): the modal simulator's step with Deff = D0
        it = shock_step(vfree, c0, D0, cbar, b0, curves, st)
        if it < 0:
            failed = True
            it = 80
        if it > worst:
            worst = it
        for c in range(m):
            F = c0[c] + b0[c] * fv[c]
            F_prev[c] = F
            f_prev[c] = fv[c]
            dfh[c, Lm + k] = F - cbar[c] * v[c]
            if k % r == 0:
                F_out[k // r, c] = F
    return -1 if failed else worst


@_nb.njit(cache=True, error_model="numpy", parallel=True)
def _fir_loop_batch(hrev, D0, v_free, cbar, kv, kf, nk, slo, shi, alpha, b0, b1, r, dfh, F_out,
                    iters):
    for s in _nb.prange(kv.shape[0]):
        iters[s] = _fir_loop_one(hrev, D0, v_free[s], cbar, kv[s], kf[s], nk[s], slo[s], shi[s],
                                 alpha[s], b0[s], b1[s], r, dfh[s], F_out[s])


# ----------------------------------------------------------------------------------------------
# simulation
# ----------------------------------------------------------------------------------------------

def _convolve(x, h, n_acausal, n):
    """Two-sided FIR filtering along the last axis with zero input outside x.

    ``y[k] = sum_l h[l] x[k - l + n_acausal]`` for ``k = 0 .. n-1`` (tap
    ``n_acausal`` is time 0); leading axes broadcast (``scipy.signal.oaconvolve``).
    """
    y = signal.oaconvolve(x, h, mode="full", axes=-1)
    out = y[..., n_acausal:n_acausal + n]
    if out.shape[-1] < n:  # fewer causal taps than the record needs: zeros beyond
        out = np.concatenate([out, np.zeros(out.shape[:-1] + (n - out.shape[-1],))], axis=-1)
    return out


def _fine_responses(h, n_acausal, r):
    """Band-limited interpolation of impulse responses onto a grid r times finer.

    The fine-rate equivalent of a response band-limited to ``fs / 2``:
    ``h_f[r m] = h[m] / r`` and no content above ``fs / 2``. Returns the fine
    taps and their count ahead of time 0.
    """
    if r == 1:
        return np.array(h), n_acausal
    pad = _INTERP_PAD
    M = h.shape[-1] + 2 * pad
    hp = np.zeros(h.shape[:-1] + (M,))
    hp[..., pad:pad + h.shape[-1]] = h
    hf = signal.resample(hp, r * M, axis=-1) / r
    return hf, r * (pad + n_acausal)


def _decimate(x, r):
    """Zero-phase band-limited decimation by r along the last axis: (n - 1) r + 1 -> n samples.

    Sample ``k`` of the result is at input sample ``k r``. The record is zero
    before its start (no history) and extended by its last value after its end.
    """
    if r == 1:
        return x
    n = (x.shape[-1] - 1) // r + 1
    pad = (FIR_HALF_LENGTH + 1) * r
    widths = [(0, 0)] * (x.ndim - 1)
    xp = np.pad(x, widths + [(pad, 0)])
    xp = np.pad(xp, widths + [(0, pad)], mode="edge")
    y = resample_bandlimited(xp, 1, r, axis=-1)
    return y[..., pad // r: pad // r + n]


def simulate_fir_batch(plant, drive, setups, *, oversample=4, outputs=None, loop_s=1.0,
                       tol=1e-5):
    """Simulate several shock setups on a FIR plant and a drive, in closed loop.

    The nonparametric counterpart of :func:`ident.sim.closedloop.simulate_batch`:
    same setups, same result type and channel conventions, the same exact
    shock models (piecewise-linear curve; lag discretized with
    :func:`ident.models.lti.lag_coefficients`), the same algebraic-loop solve;
    convolutions with the plant's impulse responses replace the modal states.

    Parameters
    ----------
    plant : FirPlant
    drive : ident.data.drive.Drive
        The 7 rig inputs, SI, at the plant's rate ``plant.fs_hz``.
    setups : sequence of setups
        Each a mapping corner -> shock model or a sequence of 4 shock models
        (LF, RF, LR, RR) (:mod:`ident.models.shocks`).
    oversample : int, default 4
        Shock-loop steps per drive sample (see the module notes: 1 aliases
        the shock force's harmonics, several percent in RMS metrics with a
        digressive shock; 4 is within about 0.3 %).
    outputs : sequence of str, optional
        Plant outputs to return (default all); ``shock_force_XX`` are always
        returned.
    loop_s : float, default 1.0
        Span of the shock-velocity responses applied inside the time loop
        [s]; the rest enters through the passes (shorter: cheaper passes,
        more of them).
    tol : float, default 1e-5
        The passes stop when no setup's ``dF`` changes by more than `tol`
        times the largest applied shock force (per corner).

    Returns
    -------
    ident.sim.closedloop.BatchResponse
        ``channels`` of shape (n_setups, n_samples); ``newton_iterations``
        the largest solve iteration count per setup over all passes;
        ``settings`` with ``kind = "fir"``, ``plant``, ``drive``,
        ``oversample``, ``loop_s``, ``passes`` and ``change`` (the last
        pass's relative change of dF).

    Raises
    ------
    TypeError
        If `plant` is not a :class:`FirPlant` or `drive` not a drive.
    ValueError
        If the drive's rate differs from the plant's (resample it with
        :func:`ident.data.drive.resample_drive`), on a malformed setup, an unknown
        output, a bad option, or if the shock loop does not converge.

    Notes
    -----
    Per fine step and pass the loop costs ``16 loop_s fs oversample``
    multiply-adds; the rig part, the passes' remainder and the outputs are
    FFT convolutions (``scipy.signal.oaconvolve``) over the whole record, with
    zero input before its first sample.
    """
    where = "simulate_fir_batch"
    if not isinstance(plant, FirPlant):
        raise TypeError(f"{where}: plant must be a FirPlant, got {type(plant).__name__}")
    r = check_oversample(oversample)
    loop_s = _check_seconds(loop_s, "loop_s", where)
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0 < tol < 1:
        raise ValueError(f"{where}: tol must be a number in (0, 1), got {tol!r}")
    u, fs = drive_array(drive)
    if not math.isclose(fs, plant.fs_hz, rel_tol=RTOL_RATE):
        raise ValueError(f"{where}: drive {getattr(drive, 'name', '?')!r} is sampled at {fs:g} Hz "
                         f"but FIR plant {plant.name!r} at {plant.fs_hz:g} Hz; resample the drive "
                         f"with ident.data.drive.resample_drive(drive, {plant.fs_hz:g})")
    models = [setup_models(s, f"setup {i}") for i, s in enumerate(setups)]
    if not models:
        raise ValueError(f"{where}: no setups given")
    names = list(plant.output_names) if outputs is None else list(outputs)
    unknown = [o for o in names if o not in plant.output_names]
    if unknown:
        raise ValueError(f"unknown outputs {unknown}; the plant has {list(plant.output_names)}")
    oi = np.array([plant.output_names.index(o) for o in names], dtype=int)
    vi = plant.velocity_idx
    na = plant.n_acausal
    N = u.shape[0]
    S = len(models)

    # rig part, once per drive: y_rig[o] = sum_j h_rig[o, j] * u_j
    need = np.union1d(oi, vi)
    y_rig = np.zeros((len(plant.output_names), N))
    y_rig[need] = _convolve(u.T[None], plant.h_rig[need], na, N).sum(axis=1)

    # the shock loop on the fine grid
    h_vs, naf = _fine_responses(plant.h_shock[vi], na, r)  # (4, 4, n_fine_taps)
    n_near = max(1, min(int(round(loop_s * fs * r)), h_vs.shape[-1] - naf))
    D0 = np.ascontiguousarray(h_vs[:, :, naf])
    hrev = np.ascontiguousarray(h_vs[:, :, naf + n_near - 1:naf:-1])  # taps n_near-1 .. 1
    h_rest = h_vs.copy()
    h_rest[:, :, naf:naf + n_near] = 0.0
    Lm = hrev.shape[2]
    v_rig = np.ascontiguousarray(refine_input(np.ascontiguousarray(y_rig[vi].T), r).T)  # (4, Nf)
    Nf = v_rig.shape[1]
    kv, kf, nk, slo, shi, alpha, b0, b1 = pack_setups(models, 1.0 / (fs * r), hold="linear")
    v_free = np.empty((S, 4, Nf))
    v_free[:] = v_rig
    dfh = np.zeros((S, 4, Lm + Nf))
    F = np.empty((S, N, 4))
    iters = np.zeros(S, dtype=np.int64)
    worst = np.zeros(S, dtype=np.int64)
    rest = bool(np.any(h_rest))
    change, passes, dF_last = 0.0, 0, None
    cbar = np.array(plant.cbar_n_s_m, dtype=float)  # writable: one numba specialization
    while True:
        dfh[:, :, :Lm] = 0.0
        _fir_loop_batch(hrev, D0, v_free, cbar, kv, kf, nk, slo, shi, alpha, b0, b1, r, dfh, F,
                        iters)
        passes += 1
        if np.any(iters < 0):
            bad = np.flatnonzero(iters < 0).tolist()
            raise ValueError(f"closed loop of FIR plant {plant.name!r}: the shock-loop solve did "
                             f"not converge for setups {bad}; the loop is ill-posed (check the "
                             "shock curves and the plant's direct term)")
        worst = np.maximum(worst, iters)
        dF = dfh[:, :, Lm:]
        if not rest:
            break
        if dF_last is not None:
            scale = np.abs(F).max(axis=1)  # (S, 4): the applied force's range
            diff = np.abs(dF - dF_last).max(axis=-1)
            change = float(np.max(np.where(scale > 0, diff / np.where(scale > 0, scale, 1.0),
                                           0.0)))
            log.debug("FIR loop of %r, pass %d: relative dF change %.3g", plant.name, passes,
                      change)
            if not np.isfinite(change):
                raise ValueError(f"closed loop of FIR plant {plant.name!r}: the passes diverged "
                                 "(non-finite shock forces); the loop with this plant is unstable")
            if change <= tol:
                break
            if passes >= MAX_PASSES:
                warnings.warn(f"{where}: the passes of the shock loop stopped after {passes} "
                              f"with a relative dF change of {change:.2g} > tol={tol:g}; the "
                              "result is not converged (raise loop_s)", FitWarning,
                              stacklevel=2)
                break
        dF_last = dF.copy()
        # the rest of the responses (older and anticausal taps) through the last pass's dF
        v_free[:] = v_rig
        for j in range(4):
            v_free += _convolve(dF_last[:, None, j, :], h_rest[None, :, j, :], naf, Nf)

    # outputs from the band-limited dF at the drive's rate
    dF_out = _decimate(np.ascontiguousarray(dfh[:, :, Lm:]), r)  # (S, 4, N)
    y = np.array(np.broadcast_to(y_rig[oi], (S, len(names), N)))
    hs = plant.h_shock[oi]
    for j in range(4):
        y += _convolve(dF_out[:, None, j, :], hs[None, :, j, :], na, N)
    channels = {nm: y[:, k, :] for k, nm in enumerate(names)}
    for c, nm in enumerate(SHOCK_FORCES):
        channels[nm] = np.ascontiguousarray(F[:, :, c])
    settings = {"kind": "fir", "plant": plant.name, "drive": getattr(drive, "name", None),
                "oversample": r, "loop_s": n_near / (fs * r), "passes": passes,
                "change": change}
    return BatchResponse(channels=channels, fs_hz=fs, setups=tuple(tuple(m) for m in models),
                         newton_iterations=worst, settings=settings)
