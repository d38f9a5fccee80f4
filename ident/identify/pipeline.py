"""The identification pipeline: a rig session or a conditioned FRF to a :class:`VehicleModel`.

:func:`identify_session` runs the three stages on a rig session: the FRF estimate
(:func:`ident.identify.frf.estimate_frf`), its conditioning
(:func:`ident.identify.condition.condition_frf`) and :func:`fit_model`, which fits a
transfer function to every input/output pair of the conditioned FRF (seed paper:
``invfreqs`` per pair, :mod:`ident.identify.fit`; here also a common-pole vector fit),
each pair's order chosen against its data's noise (:func:`pair_noise_level`), its poles
bounded and its residues refitted, and returns an
:class:`ident.identify.model.VehicleModel`.

Notes
-----
The per-pair fits run on forked worker processes (:func:`_map_pairs`); each pair's fit
is deterministic and the results come back in order, so the model does not depend on
the number of processes. Meanwhile :func:`identify_session` cross-validates the FRF in
this process (:func:`ident.identify.crossval.cross_validate_frf`: it adds to the FRF only
what the fits do not read), so both cores stay busy through the two.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import logging
import multiprocessing
import os
import warnings

import numpy as np
from scipy import signal, sparse
from scipy.optimize import lsq_linear

from ident.data.channels import CORNERS
from ident.interrupts import quiet_worker
from ident.data.session import STATIC_OFFSET_SHARE, make_session
from ident.data.third import CarThird
from ident.errors import FitWarning, LowCoherenceWarning
from ident.identify import fit as fitmod
from ident.identify.condition import condition_frf, conditioned_standard_error
from ident.identify.coverage import session_coverage
from ident.identify.crossval import cross_validate_frf
from ident.identify.diagnose import NEAR_ZERO_CONTACT, diagnose_session, rest_levels
from ident.identify.frf import (
    DF_INPUTS,
    Frf,
    bump_stop_force,
    estimate_frf,
    shock_force_deviation,
)
from ident.identify.instruments import session_instruments
from ident.identify.thirdforce import third_element_force
from ident.identify.model import VehicleModel, has_feedthrough
from ident.identify.shockcheck import check_shock_library
from ident.models.bumpstops import CarElements

__all__ = [
    "fit_model",
    "identify_session",
    "liftoff_samples",
    "pad_corrected_session",
    "session_elements",
    "session_third",
    "LIFTOFF_PASSES",
    "PAD_RESPONSE_S",
    "pair_noise_level",
    "PAPER_WEIGHTS",
    "ORDER_FLOOR",
    "NOISE_FLOOR_FACTOR",
    "ZERO_FIT_NOISE",
    "ZETA_MIN",
    "DERIVATIVE_KINDS",
    "VF_ORDER_MARGIN",
    "COHERENCE_MIN",
    "IV_COHERENCE_MIN",
    "FrfOptions",
]

log = logging.getLogger(__name__)

@dataclasses.dataclass(frozen=True)
class FrfOptions:
    """Options of :func:`identify_session`'s non-parametric stage (the FRF and its
    conditioning) that travel together.

    Attributes
    ----------
    instruments : bool or None
        Estimate the FRF with instrumental variables (:mod:`ident.identify.instruments`:
        the shock-force inputs again from the shock travels, free of the velocity and force
        sensors' noise), which removes the errors-in-variables bias of the noisy ``dF``
        inputs at the price of more scatter. None (default, "auto"): on for sessions that
        declare third elements and record every corner's shock travel (the elements'
        linear part puts the velocity sensors' noise in every run's inputs), off otherwise,
        so a plain session identifies as before
        (:func:`ident.identify.instruments.session_instruments`). ``shockplan identify
        --instruments auto|on|off``.
    smooth_width_hz, smooth_domain : optional
        :func:`ident.identify.condition.condition_frf`'s smoothing (None: its defaults).
    """

    instruments: bool | None = None
    smooth_width_hz: float | None = None
    smooth_domain: str | None = None


#: Default ``coherence_min`` of :func:`identify_session` (the paper's band-end gate).
COHERENCE_MIN = 0.9
#: Default ``coherence_min`` with the instruments on (:mod:`ident.identify.instruments`):
#: the IV estimate's partial coherence carries its larger scatter, so the 0.9 gate replaced
#: unbiased band ends with residual fits. Prototype-like car, 8 x 400 s, 2 % noise, two
#: noise realizations, median metric error track / rig drive: IV with 0.9 0.18-0.29 % /
#: 0.23-0.30 %, with 0.01 0.14-0.15 % / 0.17-0.24 % (least squares: 0.24-0.29 % /
#: 0.27-0.33 % with 0.9, 0.19-0.23 % / 0.31-0.48 % with 0.01). Conditioning still holds
#: every line to its standard error (smoothing).
IV_COHERENCE_MIN = 0.01

#: Default fit weights (seed paper): 1 in 0.5-10 Hz, 0.5 in 10-20 Hz, 0 elsewhere.
PAPER_WEIGHTS = ((0.5, 10.0, 1.0), (10.0, 20.0, 0.5))
#: Order selection stops at this fit error in any case (the rounding of a good fit).
ORDER_FLOOR = 1e-3
#: Order selection stops once the fit error is within this factor of the conditioned FRF's
#: relative noise (:func:`pair_noise_level`): a higher order would fit noise (discrepancy
#: principle; the noise estimate of a smoothed FRF is approximate, hence the margin). On the
#: paper's plan with 2 % noise, the fits' errors sit at a median 1.24 times the noise level.
NOISE_FLOOR_FACTOR = 1.5
#: A pair whose conditioned FRF's relative noise is at least this has a response power below
#: its noise power (``E|h|^2 = |H|^2 + sigma^2``, so ``sigma^2 / E|h|^2 >= 1/2``): it is fitted
#: as zero (the paper: "replaced by a small or zero frequency response").
ZERO_FIT_NOISE = 0.7


def _band_weight(f_hz, spec):
    w = np.zeros(f_hz.size)
    for lo, hi, val in spec:
        w[(f_hz >= lo) & (f_hz <= hi)] = val
    return w


def fit_model(frf, *, method="invfreqs", orders="auto", weighting="paper", band_hz=(0.5, 20.0),
              max_order=10, n_poles_vf=None, df_fit_hz=0.1, name=None, units="SI", n_jobs=None):
    """Fit a rational model to every input/output pair of a conditioned FRF.

    Parameters
    ----------
    frf : Frf
        Conditioned FRF (:func:`ident.identify.condition.condition_frf`).
    method : {"invfreqs", "vf"}
        ``invfreqs``: a transfer function per pair (output-error Gauss-Newton
        from a Levi / Sanathanan-Koerner start, as MATLAB's ``invfreqs``).
        ``vf``: vector fitting with one set of poles common to all pairs.
    orders : "auto", int or dict
        Denominator order per pair: ``"auto"`` picks the smallest order 2..
        `max_order` whose fit error stops improving; an int for all pairs; a
        dict ``{(output, input): order}`` overriding ``auto``.
    weighting : {"paper", "coherence", "relative"}
        ``paper``: 1 in 0.5-10 Hz, 0.5 in 10-20 Hz on the absolute error (as
        ``invfreqs``). ``coherence``: the paper weights times the partial
        coherence. ``relative``: the paper weights on the relative error, with
        the magnitude floored at 40 dB below the pair's peak (low-magnitude
        regions then count as much as high ones down to that floor).
    band_hz : (float, float)
        Frequencies used by the fit [Hz].
    n_poles_vf : int, optional
        Number of poles for ``vf`` (default: the smallest even number whose fits
        reach the data's noise, plus ``VF_ORDER_MARGIN``, up to ``2 * max_order``;
        see ``_fit_vf``).
    df_fit_hz : float
        Frequency spacing of the points used by the fit [Hz]: the conditioned
        FRF is smooth over its 0.6 Hz smoothing width, so thinning the Welch
        grid to about 0.1 Hz loses nothing and makes the fits 4x cheaper.
    n_jobs : int, optional
        Processes for the per-pair fits (``invfreqs``); default every core.
        The model is the same whatever the number.

    Returns
    -------
    VehicleModel
    """
    model, _ = _fit_model(frf, method=method, orders=orders, weighting=weighting,
                          band_hz=band_hz, max_order=max_order, n_poles_vf=n_poles_vf,
                          df_fit_hz=df_fit_hz, name=name, units=units, n_jobs=n_jobs)
    return model


def _fit_model(frf, *, method, orders, weighting, band_hz, max_order, n_poles_vf, df_fit_hz,
               name, units, n_jobs, meanwhile=None):
    """:func:`fit_model`, and ``meanwhile()`` called in this process while the workers fit
    the pairs (None: nothing); returns ``(model, meanwhile's result)``."""
    if not isinstance(frf, Frf):
        raise TypeError(f"fit_model needs an Frf, got {type(frf).__name__}")
    if method not in ("invfreqs", "vf"):
        raise ValueError(f"method must be 'invfreqs' or 'vf', got {method!r}")
    if weighting not in ("paper", "coherence", "relative"):
        raise ValueError(f"weighting must be 'paper', 'coherence' or 'relative', got {weighting!r}")
    f = frf.f_hz
    step = max(1, int(round(df_fit_hz / (f[1] - f[0]))))
    sel = np.flatnonzero((f >= band_hz[0]) & (f <= band_hz[1]))[::step]
    fb = f[sel]
    w0 = _band_weight(fb, [(max(lo, band_hz[0]), min(hi, band_hz[1]), v) for lo, hi, v in PAPER_WEIGHTS])
    if not np.any(w0 > 0):
        w0 = np.ones(fb.size)
    p, m = len(frf.output_names), len(frf.input_names)
    Hb = frf.H[:, :, sel]
    W = np.broadcast_to(w0, Hb.shape).copy()
    if weighting == "coherence":
        W *= np.clip(frf.partial_coherence[:, :, sel], 0, 1)
    elif weighting == "relative":
        peak = np.abs(np.where(W > 0, Hb, 0)).max(axis=-1, keepdims=True)
        W /= np.maximum(np.abs(Hb), 0.01 * np.maximum(peak, 1e-300)) ** 2
    settings = {"method": method, "orders": orders if isinstance(orders, (str, int)) else "dict",
                "weighting": weighting, "band_hz": tuple(band_hz), "max_order": max_order,
                "df_fit_hz": float(fb[1] - fb[0]) if fb.size > 1 else None}
    nmax = 2 * max_order
    poles = np.full((p, m, nmax), np.nan, dtype=complex)
    residues = np.full((p, m, nmax), np.nan, dtype=complex)
    direct = np.zeros((p, m))
    n_poles = np.zeros((p, m), dtype=int)
    order = np.zeros((p, m), dtype=int)
    err = np.zeros((p, m))
    from threadpoolctl import threadpool_limits

    f_max = 10.0 * band_hz[1]
    f_min = band_hz[0] / 5.0
    n_regularized = 0
    noise = pair_noise_level(frf, sel, W)
    zero = noise >= ZERO_FIT_NOISE
    n_short = 0
    if method == "invfreqs":
        tasks = []
        for o in range(p):
            for i in range(m):
                key = (frf.output_names[o], frf.input_names[i])
                if isinstance(orders, dict) and key in orders:
                    order_i = int(orders[key])
                elif isinstance(orders, (int, np.integer)) and not isinstance(orders, bool):
                    order_i = int(orders)
                else:
                    order_i = None  # auto
                if zero[o, i] and order_i is None:
                    # nothing above the noise: a fit would make up dynamics (order 0)
                    err[o, i] = 1.0
                    continue
                tasks.append((o, i, has_feedthrough(*key), order_i,
                              max(ORDER_FLOOR, NOISE_FLOOR_FACTOR * noise[o, i]),
                              _is_derivative(key[0])))
        common = (fb, Hb, W, max_order, f_max, f_min)
        results, aside = _map_pairs(_fit_pairs, common, tasks, n_jobs, meanwhile)
        messages = []
        for (o, i, *_), (pk, rk, dk, n_den, e, changed, msgs) in zip(tasks, results):
            n_regularized += changed
            _store(pk, rk, dk, o, i, poles, residues, direct, n_poles)
            order[o, i] = n_den
            err[o, i] = e
            if msgs:
                n_short += 1
                messages += msgs
        if messages:
            warnings.warn(f"{n_short} pair fits stay above their data's noise level and needed "
                          f"attention (e.g. {messages[0]}); compare their fit errors with "
                          "'noise_level' in the model's summary (VehicleModel.summary(); "
                          "shockplan identify writes it beside the model as "
                          "<name>_summary.csv)", FitWarning, stacklevel=2)
    else:
        aside = None if meanwhile is None else meanwhile()
        with threadpool_limits(1):
            vf = _fit_vf(fitmod, fb, Hb, W, frf, n_poles_vf, max_order)
        settings["n_poles_vf"] = int(len(vf.poles))
        for o in range(p):
            for i in range(m):
                ft = has_feedthrough(frf.output_names[o], frf.input_names[i])
                pk, rk, dk, changed = _regularize(vf.poles, fb, Hb[o, i], W[o, i], ft, f_max,
                                                  f_min_hz=f_min,
                                                  zero_dc=_is_derivative(frf.output_names[o]))
                n_regularized += changed
                _store(pk, rk, dk, o, i, poles, residues, direct, n_poles)
                order[o, i] = len(vf.poles)
                err[o, i] = _fit_error(pk, rk, dk, fb, Hb[o, i], W[o, i])
    settings["zeta_min"] = ZETA_MIN
    settings["pole_f_max_hz"] = f_max
    settings["pole_f_min_hz"] = f_min
    settings["n_pairs_regularized"] = int(n_regularized)
    settings["noise_floor_factor"] = NOISE_FLOOR_FACTOR
    settings["zero_fit_noise"] = ZERO_FIT_NOISE
    zeroed = [[frf.output_names[o], frf.input_names[i]] for o, i in zip(*np.nonzero(zero))
              if method == "invfreqs" and not (isinstance(orders, dict) and
                                               (frf.output_names[o], frf.input_names[i]) in orders)]
    settings["zero_pairs"] = zeroed
    if zeroed:
        warnings.warn(f"{len(zeroed)} pair(s) have no response above the noise (e.g. "
                      f"{zeroed[0][0]} from {zeroed[0][1]}: relative noise of the conditioned "
                      f"FRF >= {ZERO_FIT_NOISE}); fitted as zero (order 0) instead of making up "
                      "dynamics; see 'status' in the model's summary (VehicleModel.summary(); "
                      "shockplan identify writes it beside the model as <name>_summary.csv)",
                      LowCoherenceWarning,
                      stacklevel=2)
    keep = max(1, int(n_poles.max()))
    model = VehicleModel(name=name or "identified model", input_names=tuple(frf.input_names),
                         output_names=tuple(frf.output_names), poles=poles[:, :, :keep],
                         residues=residues[:, :, :keep], direct=direct, n_poles=n_poles,
                         order=order, fit_error=err, cbar_n_s_m=np.asarray(frf.cbar_n_s_m, float),
                         fs_hz=frf.fs_hz, units=units, frf=frf, settings=settings,
                         noise_level=noise)
    return model, aside


def pair_noise_level(frf, sel=None, weight=None):
    """Relative noise of each pair's conditioned FRF over the fitted lines.

    ``sqrt(sum w sigma^2 / sum w |H|^2)`` with ``sigma`` the conditioned
    estimate's standard error (:func:`ident.identify.condition.conditioned_standard_error`)
    and ``w`` the fit weights: the fit error a fit to the noise-free response
    would have against these data.

    Parameters
    ----------
    frf : Frf
    sel : ndarray of int, optional
        Frequency indices (default all).
    weight : ndarray, shape (n_out, n_in, len(sel)), optional
        Default 1.

    Returns
    -------
    ndarray, shape (n_out, n_in)
        0 for noise-free data; ``inf`` where the coherence is 0 throughout.
    """
    sel = np.arange(frf.f_hz.size) if sel is None else np.asarray(sel)
    sig = conditioned_standard_error(frf)[:, :, sel]
    H = frf.H[:, :, sel]
    w = np.ones(H.shape) if weight is None else np.broadcast_to(weight, H.shape)
    with np.errstate(invalid="ignore", over="ignore"):
        num = np.sum(w * np.where(np.isfinite(sig), sig, np.abs(H)) ** 2, axis=-1)
        den = np.sum(w * np.abs(H) ** 2, axis=-1)
        return np.where(den > 0, np.sqrt(num / np.where(den > 0, den, 1.0)), np.inf)


#: Smallest damping ratio kept for an identified pole: car modes on a rig are damped well
#: above 2 %; lighter poles in a fit are artifacts of noisy FRF regions (a pole and a zero
#: nearly cancelling) that would ring in a closed-loop simulation.
ZETA_MIN = 0.02


#: Output kinds that are time derivatives of a displacement: a static input gives them zero
#: response, so their fits are constrained to zero DC gain.
DERIVATIVE_KINDS = ("shock_velocity", "chassis_accel", "wheel_accel")


def _regularize(pl, fb, h, w, feedthrough, f_max_hz, zeta_min=ZETA_MIN, f_min_hz=None,
                zero_dc=False):
    """Bound a fit's poles and refit residues.

    Damping >= zeta_min, ``2 pi f_min <= |p| <= 2 pi f_max``: outside the fitted
    band a per-pair fit is unconstrained, and a very slow pole (time constants
    of minutes) or a very fast one would dominate the model's out-of-band
    behaviour (its gramians, the closed loop's drift) while adding nothing in
    band.

    Parameters
    ----------
    pl : ndarray of complex
        The fit's poles (conjugates included or not; only Im >= 0 are used).
    fb, h, w : ndarray
        Frequencies [Hz], data and weights of the fit.
    feedthrough : bool
        Whether the pair has a direct term.
    zero_dc : bool
        Constrain the DC gain to zero (outputs that are derivatives: the fit
        band starts at 0.5 Hz, and a road drive's large low-frequency
        displacement would otherwise meet a spurious static gain).

    Returns
    -------
    poles, residues : ndarray of complex (one per pair or real pole), d : float, changed : bool
    """
    pl = np.asarray(pl, dtype=complex)
    tol = 1e-9 * np.maximum(np.abs(pl), 1e-300)
    pl = pl[(pl.imag > tol) | (np.abs(pl.imag) <= tol)]
    real = np.abs(pl.imag) <= 1e-9 * np.maximum(np.abs(pl), 1e-300)
    lo = 0.0 if f_min_hz is None else 2 * np.pi * f_min_hz
    mag = np.clip(np.abs(pl), lo, 2 * np.pi * f_max_hz)
    zeta = np.where(real, 1.0, np.clip(-pl.real / np.maximum(np.abs(pl), 1e-300), zeta_min, 1.0))
    new = np.where(real, -np.clip(np.abs(pl.real), lo, 2 * np.pi * f_max_hz),
                   -zeta * mag + 1j * mag * np.sqrt(np.maximum(1 - zeta**2, 0.0)))
    changed = bool(np.any(np.abs(new - pl) > 1e-9 * np.abs(pl)))
    s = 2j * np.pi * fb
    cols = []
    for p, rl in zip(new, real):
        if rl:
            cols.append(1.0 / (s - p.real))
        else:
            cols.append(1.0 / (s - p) + 1.0 / (s - np.conj(p)))
            cols.append(1j / (s - p) - 1j / (s - np.conj(p)))
    if feedthrough:
        cols.append(np.ones_like(s))
    X = np.column_stack(cols)
    sw = np.sqrt(np.maximum(w, 0))
    A = np.vstack([(X * sw[:, None]).real, (X * sw[:, None]).imag])
    b = np.concatenate([(h * sw).real, (h * sw).imag])
    if zero_dc:
        row = []
        for p, rl in zip(new, real):
            if rl:
                row.append(-1.0 / p.real)
            else:
                row += [np.real(-1.0 / p - 1.0 / np.conj(p)), np.real(-1j / p + 1j / np.conj(p))]
        if feedthrough:
            row.append(1.0)
        row = np.array(row)
        big = 1e8 * max(np.abs(A).max(), 1e-300) / max(np.abs(row).max(), 1e-300)
        A = np.vstack([A, big * row])
        b = np.concatenate([b, [0.0]])
        changed = True
    scale = np.maximum(np.abs(A).max(axis=0), 1e-300)
    coef = np.linalg.lstsq(A / scale, b, rcond=None)[0] / scale
    res, k = [], 0
    for rl in real:
        if rl:
            res.append(complex(coef[k]))
            k += 1
        else:
            res.append(coef[k] + 1j * coef[k + 1])
            k += 2
    d = float(coef[k]) if feedthrough else 0.0
    return new, np.array(res, dtype=complex), d, changed


def _store(pole_list, res_list, d, o, i, poles, residues, direct, n_poles):
    """Keep one pole of each conjugate pair (Im > 0) and the real poles."""
    pl = np.asarray(pole_list, dtype=complex)
    rl = np.asarray(res_list, dtype=complex)
    tol = 1e-9 * np.maximum(np.abs(pl), 1e-300)
    keep = (pl.imag > tol) | (np.abs(pl.imag) <= tol)
    pk, rk = pl[keep], rl[keep]
    real = np.abs(pk.imag) <= tol[keep]
    pk = np.where(real, pk.real, pk)
    rk = np.where(real, rk.real, rk)
    k = pk.size
    poles[o, i, :k] = pk
    residues[o, i, :k] = rk
    direct[o, i] = float(np.real(d))
    n_poles[o, i] = k


def _is_derivative(output):
    return output.rpartition("_")[0] in DERIVATIVE_KINDS


def _fit_error(pk, rk, d, fb, h, w):
    """Relative weighted error of a pole-residue fit (as TfFit.fit_error)."""
    s = 2j * np.pi * fb[:, None]
    real = (pk.imag == 0)[None, :]
    terms = rk / (s - pk) + np.where(real, 0.0, np.conj(rk) / (s - np.conj(pk)))
    fit = terms.sum(axis=1) + d
    return float(np.sqrt(np.sum(w * np.abs(h - fit) ** 2) / max(np.sum(w * np.abs(h) ** 2), 1e-300)))


def _fit_pairs(common, tasks):
    """Fit a batch of pairs (a worker of :func:`fit_model`).

    Parameters
    ----------
    common : tuple
        ``(fb, Hb, W, max_order, f_max, f_min)``.
    tasks : list of tuple
        ``(o, i, feedthrough, order or None for auto, floor, zero_dc)``.

    Returns
    -------
    list of tuple
        Per task ``(poles, residues, direct, order, fit_error, regularized, messages)``;
        ``messages`` are the fit's warnings, kept only where the fit error stays above
        `floor` (a fit within its data's noise needs no word about how it got there).
    """
    from threadpoolctl import threadpool_limits

    fb, Hb, W, max_order, f_max, f_min = common
    out = []
    with threadpool_limits(1):  # single-threaded BLAS: many small problems (3-4x faster)
        for o, i, ft, n_fixed, floor, zero_dc in tasks:
            rel = 0 if ft else -1
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", FitWarning)
                if n_fixed is None:
                    # choose the order with the linear (Sanathanan-Koerner) fits, stopping where
                    # the fit reaches the data's noise, then refine that order alone with the
                    # output-error Gauss-Newton
                    sk, _ = fitmod.select_order(fb, Hb[o, i], weight=W[o, i],
                                                orders=range(2, max_order + 1), relative_num=rel,
                                                method="sk", floor=floor)
                    n = len(sk.poles)
                else:
                    n = n_fixed
                tf = fitmod.fit_tf(fb, Hb[o, i], weight=W[o, i], n_den=n, n_num=n + rel)
            pk, rk, dk, changed = _regularize(tf.poles, fb, Hb[o, i], W[o, i], ft, f_max,
                                              f_min_hz=f_min, zero_dc=zero_dc)
            e = _fit_error(pk, rk, dk, fb, Hb[o, i], W[o, i])
            msgs = [str(w.message) for w in caught if issubclass(w.category, FitWarning)]
            out.append((pk, rk, dk, len(tf.poles), e, changed, msgs if e > floor else []))
    return out


#: Batches of pair fits per worker process in :func:`_map_pairs` (the model does not depend
#: on it; more batches balance the load better at a little pickling cost per batch).
_BATCHES_PER_PROCESS = 16


def _map_pairs(func, common, tasks, n_jobs, meanwhile=None):
    """``func(common, batch)`` over batches of `tasks`, on up to `n_jobs` processes; returns
    ``(results, meanwhile())``: `meanwhile` (None: nothing) is called in this process while
    the workers run (without workers: before the batches).

    Results come back in the order of `tasks`, and each pair's fit is deterministic, so the
    model does not depend on the number of processes. Workers are forked (POSIX; elsewhere the
    fits run in this process): a fork server or spawned workers would re-run an unguarded
    script's top level. The workers only run numpy and scipy with one BLAS thread, so the
    parent's thread pools (numba's OpenMP, BLAS) are never used in a child.
    """
    n = (os.cpu_count() or 1) if n_jobs is None else int(n_jobs)
    n = max(1, min(n, len(tasks)))
    if n == 1 or "fork" not in multiprocessing.get_all_start_methods():
        aside = None if meanwhile is None else meanwhile()
        return func(common, tasks), aside
    # about _BATCHES_PER_PROCESS batches per process: the pairs' costs differ by 10x, and
    # small batches handed out in turn keep both cores busy to the end
    size = max(1, -(-len(tasks) // (_BATCHES_PER_PROCESS * n)))
    batches = [tasks[k:k + size] for k in range(0, len(tasks), size)]
    ctx = multiprocessing.get_context("fork")
    # Ctrl-C reaches every process of the command: the workers end at once without a
    # traceback, and this process stops, cancelling the batches not started; a worker also
    # ends if this process dies, however it dies (quiet_worker)
    pool = concurrent.futures.ProcessPoolExecutor(max_workers=n, mp_context=ctx,
                                                  initializer=quiet_worker,
                                                  initargs=(os.getpid(),))
    try:
        # every batch is submitted (the workers forked) before `meanwhile` runs here
        futures = [pool.submit(func, common, batch) for batch in batches]
        aside = None if meanwhile is None else meanwhile()
        parts = [fut.result() for fut in futures]
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return [r for part in parts for r in part], aside


#: ``vf``: poles added to the order at which the common-pole fit first reaches its data's noise
#: (:func:`_fit_vf`). On a noisy car with a flexible chassis (8 modes, 2 % noise) the noise is
#: reached at 12 poles, where two of the four heavily damped hop modes share a pole pair: the fit
#: is as close to the data, but the model closed around other shocks is not (closed-loop metric
#: error median/max 0.13 %/0.57 % at 12 poles, 0.09 %/0.48 % at 16, invfreqs 0.09 %/0.44 %).
VF_ORDER_MARGIN = 4


def _fit_vf(fitmod, fb, Hb, W, frf, n_poles_vf, max_order):
    """Common-pole vector fit, its order chosen against the data's noise.

    Every pair is scaled to unit peak, and its weights in the fit are the fit weights `W`
    times ``(ORDER_FLOOR / max(sigma_rel, ORDER_FLOOR))^2`` with ``sigma_rel`` the conditioned
    estimate's standard error over the pair's peak: each line counts by its signal-to-noise
    ratio, so noise-dominated pairs and lines (weak cross paths, band edges) no longer place
    common poles for every pair (with unit weights the relocation put lightly damped poles at
    0.8-1.5 Hz, under the car's first mode, into all 308 pairs of a noisy car). Noise-free data
    keep the weights `W`. The order is the smallest even one whose fit errors (weights `W`,
    relative) reach ``max(ORDER_FLOOR, NOISE_FLOOR_FACTOR * noise)`` within 10 % in RMS over
    the pairs, or stop improving by 10 %, plus :data:`VF_ORDER_MARGIN` poles (the residues of
    every pair are refitted with `W` afterwards, by :func:`_regularize`).
    """
    sel = np.searchsorted(frf.f_hz, fb)
    peak = np.maximum(np.abs(Hb).max(axis=-1, keepdims=True), 1e-300)
    Hs = Hb / peak
    sig = conditioned_standard_error(frf)[:, :, sel] / peak
    sig = np.where(np.isfinite(sig), sig, 1.0)
    Wr = W * (ORDER_FLOOR / np.maximum(sig, ORDER_FLOOR)) ** 2
    if n_poles_vf is not None:
        vf = fitmod.fit_common_poles(fb, Hs, weight=Wr, n_poles=int(n_poles_vf))
    else:
        target = np.maximum(ORDER_FLOOR, NOISE_FLOOR_FACTOR * pair_noise_level(frf, sel, W))
        den = np.maximum(np.sum(W * np.abs(Hs) ** 2, axis=-1), 1e-300)
        s = 2j * np.pi * fb
        n_max = 2 * max_order
        chosen, prev = n_max, np.inf
        for n in range(4, n_max + 1, 2):
            cand = fitmod.fit_common_poles(fb, Hs, weight=Wr, n_poles=n)
            fit = np.einsum("kom,kf->omf", cand.residues,
                            1.0 / (s[None, :] - cand.poles[:, None])) + cand.direct[..., None]
            err = np.sqrt(np.sum(W * np.abs(Hs - fit) ** 2, axis=-1) / den)
            e = float(np.sqrt(np.mean(np.maximum(err / target, 1.0) ** 2)))
            if e <= 1.1 or e > (1 - 0.1) * prev:
                chosen = min(n + VF_ORDER_MARGIN if e <= 1.1 else n - 2 + VF_ORDER_MARGIN, n_max)
                break
            prev = e
        vf = fitmod.fit_common_poles(fb, Hs, weight=Wr, n_poles=chosen)
    return dataclasses.replace(vf, residues=vf.residues * peak[None, :, :, 0],
                               direct=vf.direct * peak[:, :, 0])


def identify_session(session, *, estimator="lpm", frf_method="global", cbar_n_s_m=None,
                     nperseg=None,
                     coherence_min=None, frf_options=None,
                     fit_method="invfreqs",
                     orders="auto", weighting="paper", band_hz=(0.5, 20.0), max_order=10,
                     diagnose=True, check_shocks=True, cross_validate=True):
    """Identify a vehicle model from a rig session: estimate, condition, fit, check.

    Parameters
    ----------
    session : ident.data.session.Session
    estimator : {"lpm", "welch"}
        FRF estimator (:func:`ident.identify.frf.estimate_frf`): the local polynomial
        method (default; free of the transient leakage that makes Welch H1
        estimates of weak paths noisy) or the paper's Welch H1.
    frf_method : {"global", "sequential"}
        :func:`ident.identify.frf.estimate_frf` (``sequential`` needs ``estimator="welch"``).
    cbar_n_s_m, nperseg
        :func:`ident.identify.frf.estimate_frf`.
    coherence_min : float, optional
        :func:`ident.identify.condition.condition_frf`'s band-end gate; default
        :data:`COHERENCE_MIN` (0.9, the paper's), or :data:`IV_COHERENCE_MIN` with the
        instruments on (``frf_options.instruments``).
    frf_options : FrfOptions, optional
        The FRF estimate's instruments and the conditioning's smoothing (default
        ``FrfOptions()``: instruments "auto", the smoothing's defaults).
    fit_method, orders, weighting, band_hz, max_order
        :func:`fit_model`.
    diagnose : bool
        Check the session against the model (:func:`ident.identify.diagnose.
        diagnose_session`: bump stops, lift-off, the runs re-simulated on the model,
        amplitude dependence), log a warning per finding and keep the result as the
        model's ``diagnosis`` (:class:`ident.identify.diagnose.Diagnosis`, saved with the
        model). It builds the model's loop plant (kept with the model) and adds about
        5-8 % to the time. False: skip it (``diagnosis`` None).
    check_shocks : bool
        Where the runs log ``shock_force_XX``, compare the measured forces with the
        library's curves (:func:`ident.identify.shockcheck.check_shock_library`: the scale
        per shock, a warning logged per shock that is off) and keep the per-shock summary
        as the model's ``shock_check`` (:class:`~ident.identify.shockcheck.
        ShockLibraryCheck` without the per-run rows). The model's numbers do not
        depend on it. False, or a session without the force channels: None.
    cross_validate : bool
        Measure the FRF estimate's error on the session's own time blocks
        (:func:`ident.identify.crossval.cross_validate_frf`: the FRF of each time block
        of every run, their scatter) and keep it with the FRF
        (``model.frf.cv_deviation`` and ``settings["cross_validation"]``): the planner's
        intervals take their random part's size from it. The model's numbers do not
        depend on it.
    Returns
    -------
    VehicleModel
        ``settings["session"]`` names the session and its runs; ``settings["coverage"]``
        what it covered (:func:`ident.identify.coverage.session_coverage`: the planner warns
        when a prediction goes beyond it); ``settings["elements"]``
        (:attr:`VehicleModel.elements`) holds the bump stops and static loads the
        session declares (:func:`session_elements`), when it declares any. The declared
        stops' force is part of the corners' force input
        (:func:`ident.identify.frf.bump_stop_force`), so the model is the car without them.
        With static loads declared and tires that leave the pads
        (:func:`liftoff_samples`), the wheelloader inputs are corrected where the pad
        lost the tire (:func:`pad_corrected_session`, :data:`LIFTOFF_PASSES` times, each on
        a model of the tire forces fitted to the session as corrected so far), and the
        model's ``liftoff`` records the lifted samples and corrections per run.
        A session that declares third elements (heave and roll elements per axle) has
        their force in the corners' force inputs too
        (:func:`ident.identify.thirdforce.third_element_force`: measured, or from their
        curves and heave springs), so the model is the car without them, and
        ``settings["third"]`` (:attr:`VehicleModel.third`) holds what it declared
        (:func:`session_third`).
    """
    opts = FrfOptions() if frf_options is None else frf_options
    if not isinstance(opts, FrfOptions):
        raise TypeError(f"frf_options must be an ident.identify.pipeline.FrfOptions, got "
                        f"{type(opts).__name__}: build one, e.g. FrfOptions(instruments=False)")
    smooth_width_hz = opts.smooth_width_hz
    cond = {} if opts.smooth_domain is None else {"smooth_domain": opts.smooth_domain}
    iv = session_instruments(session, opts.instruments, estimator=estimator)
    if coherence_min is None:
        coherence_min = IV_COHERENCE_MIN if iv else COHERENCE_MIN
    measured = session
    lifted = liftoff_samples(session)
    liftoff = None
    if lifted is not None:
        # the tires left the pads: the pad corrections that keep the contact at zero,
        # estimated on the tire forces of a model of the session as corrected so far
        tires = [f"tire_force_{c}" for c in CORNERS]
        passes = []
        for _ in range(LIFTOFF_PASSES):
            pre = estimate_frf(session, method=frf_method, cbar_n_s_m=cbar_n_s_m,
                               nperseg=nperseg, estimator=estimator, outputs=tires,
                               instruments=iv)
            pre = condition_frf(pre, coherence_min=coherence_min,
                                smooth_width_hz=smooth_width_hz, **cond)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                tire_model = fit_model(pre, method=fit_method, orders=orders,
                                       weighting=weighting, band_hz=band_hz,
                                       max_order=max_order)
            session, info = pad_corrected_session(measured, tire_model, lifted)
            passes.append(info)
        liftoff = {"passes": LIFTOFF_PASSES, "near_zero_contact": NEAR_ZERO_CONTACT,
                   "pad_response_s": PAD_RESPONSE_S, "runs": passes[-1]}
    frf = estimate_frf(session, method=frf_method, cbar_n_s_m=cbar_n_s_m, nperseg=nperseg,
                       estimator=estimator, instruments=iv)
    frf = condition_frf(frf, coherence_min=coherence_min, smooth_width_hz=smooth_width_hz,
                        **cond)
    # the cross-validation reads the session and the FRF and only adds to the FRF what the
    # fits do not use (its deviations and noise bias, settings["cross_validation"]): it runs
    # here while the worker processes fit the pairs, and its FRF replaces the fitted one
    corrected = session
    validate = (lambda: cross_validate_frf(corrected, frf)) if cross_validate else None
    session = measured
    model, validated = _fit_model(frf, method=fit_method, orders=orders, weighting=weighting,
                                  band_hz=band_hz, max_order=max_order, n_poles_vf=None,
                                  df_fit_hz=0.1, name=session.name, units=session.units,
                                  n_jobs=None, meanwhile=validate)
    if validated is not None:
        model = dataclasses.replace(model, frf=validated)
    settings = dict(model.settings, session=session.name,
                    runs=[r.name for r in session.runs], frf_method=frf_method,
                    estimator=estimator)
    settings["coverage"] = session_coverage(session).to_dict()
    elements = session_elements(session)
    if elements is not None:
        settings["elements"] = elements.to_dict()
    third = session_third(session)
    if third is not None:
        settings["third"] = third.to_dict()
    model = model.with_results(settings=settings, liftoff=liftoff)
    if diagnose:
        model = model.with_results(diagnosis=diagnose_session(session, model))
    if check_shocks:
        check = check_shock_library(session)
        if len(check):  # the per-shock summary, without the per-run rows
            model = model.with_results(shock_check=dataclasses.replace(
                check, series=check.series.iloc[:0]))
    return model


def session_elements(session):
    """The bump stops and static loads a session declares, as a model keeps them.

    The baseline's stops and packers are those of the first run with role ``baseline``,
    else of the first run of the most common setup (as
    :func:`ident.identify.frf.baseline_damping` picks its runs).

    Parameters
    ----------
    session : ident.data.session.Session

    Returns
    -------
    ident.models.bumpstops.CarElements or None
        None when the session declares neither a bump-stop library nor static loads.
    """
    library = getattr(session, "bump_stops", None)
    static = getattr(session, "static_corner_load_n", None)
    if library is None and static is None:
        return None
    run = _baseline_run(session)
    return CarElements(library, dict(run.bump_stops) if library is not None else {},
                       dict(run.packers_m) if library is not None else {}, static)


def _baseline_run(session):
    """The first run with role ``baseline``, else the first of the most common setup."""
    runs = list(session.runs)
    base = [r for r in runs if r.role == "baseline"]
    if not base:
        setups = [tuple(r.setup[c] for c in CORNERS) for r in runs]
        common = max(set(setups), key=setups.count)
        base = [r for r, s in zip(runs, setups) if s == common]
    return base[0]


def session_third(session):
    """The third elements a session declares, as a model keeps them (``VehicleModel.third``).

    The baseline's dampers, heave springs and packers are those of the baseline run picked
    as :func:`session_elements` picks it (the first run with role ``baseline``, else the
    first run of the most common corner setup).

    Parameters
    ----------
    session : ident.data.session.Session

    Returns
    -------
    ident.data.third.CarThird or None
        None when the session declares no third elements (``third_elements``).
    """
    elements = getattr(session, "third_elements", None)
    if not elements:
        return None
    return CarThird(elements, _baseline_run(session).third)


#: Passes of the lift-off correction (:func:`identify_session`): each fits a model of the
#: tire forces to the session as corrected so far and corrects the pads again. GT-like car,
#: 5 runs of 400 s, 2 % noise, tires off the pads 1-4 % of the time: nothing done, median /
#: max metric error 8.7 % / 8,000 % (a rear travel); 1 pass 1.36 % / 4.7 %; 2 passes
#: 0.88 % / 5.5 % (12 setups; the same session without lift-off: 0.08 % / 0.29 %).
LIFTOFF_PASSES = 2
#: Length of the tire forces' impulse responses to a pad correction [s] that the
#: correction's least squares uses (the car's slowest modes have decayed by then).
PAD_RESPONSE_S = 1.0


def liftoff_samples(session, *, margin=NEAR_ZERO_CONTACT):
    """The samples of each run at which a tire is off its pad (contact near zero).

    Contact is ``static + tire_force`` (the tire force measured from the car at rest,
    :func:`ident.identify.diagnose.rest_levels`), or the channel itself where it carries
    the static load (its mean above :data:`ident.data.session.STATIC_OFFSET_SHARE` of the
    load); a sample is lifted where it is below `margin` of the static load (the
    acquisition filter rings around zero at the edges).

    Parameters
    ----------
    session : ident.data.session.Session
    margin : float
        Share of the static load under which the contact counts as zero.

    Returns
    -------
    dict of str to ndarray of bool, shape (4, n_samples), or None
        Run -> lifted samples per corner (LF, RF, LR, RR); None without static loads, a
        tire-force channel, or any lifted sample.
    """
    static = getattr(session, "static_corner_load_n", None)
    if static is None:
        return None
    out, any_lift = {}, False
    for run in session.runs:
        if not all(f"tire_force_{c}" in run.channels for c in CORNERS):
            return None
        levels, _ = rest_levels(run)
        lifted = np.zeros((4, run.n_samples), dtype=bool)
        for i, c in enumerate(CORNERS):
            x = run.channels[f"tire_force_{c}"]
            load = float(static[i])
            contact = x if abs(np.mean(x)) > STATIC_OFFSET_SHARE * load else (
                load + x - levels[f"tire_force_{c}"])
            lifted[i] = contact < margin * load
        any_lift |= bool(lifted.any())
        out[run.name] = lifted
    return out if any_lift else None


def pad_corrected_session(session, tire_model, lifted):
    """The session with each lifted tire's pad input corrected: the pad as the tire saw it.

    While a tire is off its pad the car is driven as if the pad followed the tire (the
    closed loop's lift-off, :func:`ident.sim.closedloop.simulate`): wheelloader ``+ w``,
    ``w >= 0`` only at the lifted samples (and one on either side, for the acquisition
    filter). ``w`` is the non-negative least-squares solution that makes `tire_model`'s
    tire forces (all inputs, measured; impulse responses over :data:`PAD_RESPONSE_S`)
    match the measured ones, with a free offset per tire force (the channels are taken
    about their means, which hold the correction's mean). The corner's ride height, measured from the real pad, is
    moved by ``-w`` to the corrected pad.

    Parameters
    ----------
    session : ident.data.session.Session
        As measured.
    tire_model : ident.identify.model.VehicleModel
        A model with the outputs ``tire_force_XX`` (identified from the session).
    lifted : dict of str to ndarray of bool, shape (4, n_samples)
        :func:`liftoff_samples`.

    Returns
    -------
    corrected : ident.data.session.Session
    info : dict
        Run -> ``lifted_samples`` (corner -> count), ``pad_correction_max_m`` (corner ->
        largest ``w``), ``residual_rms_n`` (the tire forces' misfit on the rows the
        correction sees, before and after).
    """
    fs = session.fs_hz
    n_taps = max(2, round(PAD_RESPONSE_S * fs))
    nfft = int(2 ** np.ceil(np.log2(4 * n_taps)))
    outs = [tire_model.output_names.index(f"tire_force_{c}") for c in CORNERS]
    H = tire_model.frequency_response(np.fft.rfftfreq(nfft, 1.0 / fs))[outs]
    h = np.fft.irfft(H, n=nfft, axis=-1)[..., :n_taps]  # (4, n_in, taps)
    names = list(tire_model.input_names)
    wl = [names.index(f"wheelloader_{c}") for c in CORNERS]
    rig = [n for n in names if n not in DF_INPUTS]
    cbar = tire_model.cbar_n_s_m
    runs, info = [], {}
    for run in session.runs:
        lift = lifted[run.name]
        n = run.n_samples
        _, dF = shock_force_deviation(run, session.shocks, cbar)
        G, _ = bump_stop_force(run, getattr(session, "bump_stops", None))
        third = getattr(session, "third_elements", None)
        T = None if not third or not run.third else third_element_force(
            run, third, session.shocks, getattr(session, "bump_stops", None),
            levels=rest_levels(run)[0])[0]
        if T is not None:
            G = T if G is None else G + T
        if G is not None:
            dF = dF + G - G.mean(axis=1, keepdims=True)
        X = np.vstack([np.vstack([run.dynamic(c) for c in rig]), dF])
        Y = np.vstack([run.dynamic(f"tire_force_{c}") for c in CORNERS])
        pred = np.array([sum(signal.oaconvolve(X[i], h[o, i])[:n] for i in range(len(names)))
                         for o in range(4)])
        support = [np.flatnonzero(np.convolve(lift[j], np.ones(3), "same") > 0)
                   for j in range(4)]
        cols = [(j, t) for j in range(4) for t in support[j]]
        w = np.zeros((4, n))
        entry = {"lifted_samples": {c: int(lift[j].sum()) for j, c in enumerate(CORNERS)}}
        if cols:
            rows, cl, vals = [], [], []
            for k, (j, t) in enumerate(cols):
                m = min(n_taps, n - t)
                for o in range(4):
                    rows.append(o * n + t + np.arange(m))
                    cl.append(np.full(m, k))
                    vals.append(h[o, wl[j], :m])
            rows = np.concatenate(rows)
            used = np.unique(rows)
            # and an offset per tire force: the channels' means hold the mean correction
            rows = np.concatenate([rows, used])
            cl.append(len(cols) + used // n)
            vals.append(np.ones(used.size))
            A = sparse.csr_matrix((np.concatenate(vals), (rows, np.concatenate(cl))),
                                  shape=(4 * n, len(cols) + 4))[used]
            b = (Y - pred).reshape(-1)[used]
            lower = np.r_[np.zeros(len(cols)), np.full(4, -np.inf)]
            sol = lsq_linear(A, b, bounds=(lower, np.inf), lsmr_tol="auto", max_iter=200).x
            for k, (j, t) in enumerate(cols):
                w[j, t] = sol[k]
            entry["residual_rms_n"] = [float(np.sqrt(np.mean(b ** 2))),
                                       float(np.sqrt(np.mean((b - A @ sol) ** 2)))]
        entry["pad_correction_max_m"] = {c: float(w[j].max()) for j, c in enumerate(CORNERS)}
        channels = dict(run.channels)
        for j, c in enumerate(CORNERS):
            channels[f"wheelloader_{c}"] = run.channels[f"wheelloader_{c}"] + w[j]
            if f"ride_height_{c}" in channels:
                channels[f"ride_height_{c}"] = run.channels[f"ride_height_{c}"] - w[j]
        runs.append(dataclasses.replace(run, channels=channels))
        info[run.name] = entry
        log.info("run %s: tires off the pads at %s samples; pad corrections up to %s mm",
                 run.name, entry["lifted_samples"],
                 {c: round(v * 1e3, 2) for c, v in entry["pad_correction_max_m"].items()})
    corrected = make_session(session.name, runs, session.shocks, units=session.units,
                             bump_stops=getattr(session, "bump_stops", None),
                             static_corner_load_n=session.static_corner_load_n,
                             third_elements=getattr(session, "third_elements", None) or None)
    return corrected, info
