"""The session's own cross-validation of its FRF estimate: how wrong the estimate is.

The standard error an FRF estimator states (:func:`ident.identify.condition.
conditioned_standard_error`) is a model of its error: white measurement noise,
independent lines, a linear car. What departs from that model (the swap runs'
nonlinear residual, the drive's transients, correlated noise, the smoothing's
bias on a steep flank) is not in it, and how large it is depends on the car and
the session. This module measures it on the session itself:

1. Every run is cut into ``blocks`` contiguous time blocks; block ``k`` of the
   session holds piece ``(k + r) % blocks`` of run ``r`` (the same swaps, a different
   stretch of the drive and of the noise; rotated over the runs so that a drive
   repeated in every run is not repeated within a block: :func:`split_session`).
2. The FRF is estimated and conditioned on each block with the settings of the
   full estimate (:func:`block_frfs`), and each block's estimate is put on the
   full estimate's frequency grid.
   Each block's relative deviation from the blocks' mean, scaled to the full
   estimate (:func:`block_deviations`), is kept with the FRF
   (``Frf.cv_deviation``, on :data:`CV_GRID` frequencies): the planner perturbs
   the model's response by each and screens every setup, which measures the
   metrics' error directly, its correlations between pairs and over
   frequency included (:mod:`planner.uncertainty`).
3. The blocks' estimates scatter about each other by their error; the full
   estimate averages ``K`` of them, so its error variance is the blocks' sample
   variance over ``K`` (the jackknife of the mean)::

       var_cv(f) = 1 / (K (K - 1)) sum_k |H_k(f) - mean_k H_k(f)|^2

   and the ratio of this measured variance to the stated one, pooled over lines,
   says by how much the stated standard error is to be trusted
   (:func:`cross_validation_ratio`).

Pooling: one block split gives one realization per line, and neighbouring lines
of a conditioned FRF are correlated over the smoothing width (0.6 Hz by
default), so a ratio per pair and line would be noise. The ratio is therefore
modelled as a product: per pair (pooled over the band's lines) times per
frequency band (pooled over the pairs), divided by the overall ratio
(``r[o, i, b] = r_pair[o, i] r_band[b] / r_all``), each a root-mean-square
ratio of relative errors (``|dH|^2 / |H|^2`` against ``sigma^2 / |H|^2``), so that
no pair's scale dominates. Lines the conditioning replaced by residual fits
(no measurement) do not count.

Why rotated. The LPM's local window is a number of DFT lines, set by how many distinct
realizations of each input the runs hold (:func:`ident.identify.frf.estimate_frf`). Cut
in plain halves, a session whose runs repeat one drive (the paper's plan) gives blocks
that repeat one drive too: the same number of lines, each twice as wide, so the blocks'
window was twice as wide in Hz as the full estimate's, and the local polynomials' misfit
at the body modes (an error of the window that grows steeply with its width) made the
halves scatter far more than the full estimate errs: on the heavy car at 200 Hz (modes at
3-4.5 Hz, 5 x 250 s) each half was 7-14 % off the true FRF there (rig columns, rms) where
the full estimate was 2 %, and the full estimate at a twice-as-wide window 5.5 %; the
metric-level factor came out at 3.6-9.6 on the two stiff 200 Hz cars (the same at
100 Hz: not the rate). Rotated, a block holds two stretches of the drive, its default
window is about half as many lines of twice the width, and its halves were 2.5-2.8 % off,
their difference 1.4 % (the full estimate 2.0 %).

Assumptions: the error of the estimate from ``K`` blocks is the mean of the
blocks' errors (an estimator's variance falls as one over the record length;
the LPM's does), the blocks' errors are independent (blocks much longer than
the car's impulse response: seconds against tens of milliseconds), and the
error that is common to all blocks (a bias of the estimator, the same in each
block) is not seen here: :mod:`planner.uncertainty` carries the fit's and the
smoothing's bias as systematic terms, and one such bias is measured here too: that of
the noise on the shock-force inputs (:func:`noise_bias`: the ``dF`` inputs are computed
from the measured force and velocity, so their sensors' noise is noise on inputs, which
biases the estimate; measured by adding that noise once more, as simulation-extrapolation
does).
"""

from __future__ import annotations

import dataclasses
import logging
import warnings

import numpy as np

from ident.data.channels import CORNERS
from ident.identify.condition import condition_frf
from ident.identify.frf import estimate_frf, shock_force_deviation

__all__ = [
    "CV_BLOCKS",
    "CV_BAND_EDGES_HZ",
    "CV_GRID",
    "block_deviations",
    "block_frfs",
    "cross_validate_frf",
    "cross_validation_ratio",
    "noise_bias",
    "noise_records",
    "noisier_sessions",
    "sensor_noise",
    "split_session",
]

log = logging.getLogger(__name__)

#: A noise record below this fraction of the corner's force (RMS) is round-off: a session
#: without sensor noise, which has no noise bias to measure.
ROUND_OFF = 1e-9
#: Seed of the noise added to measure the noise bias (:func:`noisier_sessions`).
NOISE_SEED = 20240
#: Time blocks of the cross-validation: two halves of every run (the two estimates together
#: cost about one full estimate). Shorter blocks estimate differently, not only noisier: the
#: LPM's local window is a number of lines, so it is ``K`` times wider in Hz on a block of
#: ``T / K`` (and the conditioning replaces more of the poorly coherent lines); with four
#: quarters of 150 s runs the blocks' scatter was 13 times the full estimate's error in the
#: metrics (two halves: 1.7 times).
CV_BLOCKS = 2
#: The deviations are kept on this many log-spaced frequencies (the screening's 96 bands
#: sample the metric band about as densely), from :data:`CV_GRID_HZ`'s low end to its high
#: end or the Nyquist frequency.
CV_GRID = 240
#: The range of the kept deviations [Hz].
CV_GRID_HZ = (0.1, 50.0)
#: Edges of the frequency bands the ratio is pooled in [Hz] (about one octave each over
#: the fit band; below and above the ends the end bands' ratios hold).
CV_BAND_EDGES_HZ = (0.5, 1.0, 2.0, 4.0, 8.0, 14.0, 20.0)
#: A pooled ratio is not trusted below this many measured lines (NaN: the fallback).
MIN_LINES = 8


def split_session(session, blocks=CV_BLOCKS, *, rotate=True):
    """Cut every run of `session` into `blocks` contiguous time blocks.

    Parameters
    ----------
    session : ident.data.session.Session
    blocks : int
        Number of blocks (at least 2).
    rotate : bool
        Block ``k`` holds stretch ``(k + r) % blocks`` of run ``r`` (default), so that a
        drive repeated in every run (the paper's plan) is not repeated within a block:
        the block then has ``blocks`` distinct realizations of it, and its LPM's default
        half-width (:func:`ident.identify.frf.estimate_frf`, a number of the block's DFT
        lines, set by the distinct realizations) is about ``1 / blocks`` of the full
        estimate's, so its local window is as wide in Hz as the full estimate's. Without
        the rotation (False: stretch ``k`` of every run) the block's window is ``blocks``
        times wider in Hz and the local polynomials' misfit at the body modes, which grows
        steeply with the window, made the halves' scatter 4-6 times the full estimate's
        error in the metrics of stiff cars (modes at 3-4.5 Hz): module notes.

    Returns
    -------
    list of ident.data.session.Session
        ``blocks`` sessions of the same run names, setups and libraries, each run of
        ``n // blocks`` samples; every stretch of every run is in exactly one block.
    """
    if blocks < 2:
        raise ValueError(f"blocks must be at least 2, got {blocks}")
    out = []
    for k in range(blocks):
        runs = []
        for r, run in enumerate(session.runs):
            n = run.n_samples // blocks
            j = (k + r) % blocks if rotate else k
            sl = slice(j * n, (j + 1) * n)
            runs.append(dataclasses.replace(
                run, time_s=run.time_s[sl], channels={c: v[sl] for c, v in run.channels.items()}))
        out.append(dataclasses.replace(session, runs=tuple(runs)))
    return out


def _on_grid(f_src, H, f_dst):
    """Complex `H` (..., n_src) interpolated linearly onto `f_dst`."""
    flat = H.reshape(-1, H.shape[-1])
    re = np.array([np.interp(f_dst, f_src, h.real) for h in flat])
    im = np.array([np.interp(f_dst, f_src, h.imag) for h in flat])
    return (re + 1j * im).reshape(H.shape[:-1] + (f_dst.size,))


def block_frfs(session, frf, *, blocks=CV_BLOCKS):
    """The conditioned FRF of every time block, on the full estimate's grid.

    Parameters
    ----------
    session : ident.data.session.Session
        The session `frf` was estimated from (as estimated: with any pad corrections).
    frf : ident.identify.frf.Frf
        The full, conditioned estimate; its estimator, method, baseline damping,
        outputs and conditioning settings are reused.
    blocks : int

    Returns
    -------
    ndarray of complex, shape (blocks, n_out, n_in, n_f)
        ``H_k`` on ``frf.f_hz``.
    """
    return np.stack([_estimate_like(sub, frf) for sub in split_session(session, blocks)])


def _estimate_like(session, frf):
    """The conditioned FRF of `session` with `frf`'s settings, on ``frf.f_hz``."""
    s = frf.settings or {}
    cond = dict(s.get("conditioning") or {})
    cond.pop("poor_pairs", None)
    est = {"estimator": s.get("estimator", "lpm"), "method": s.get("method", "global"),
           "cbar_n_s_m": frf.cbar_n_s_m, "outputs": list(frf.output_names)}
    if s.get("instruments"):
        est["instruments"] = True
    if est["estimator"] == "lpm":
        for key, name in (("lpm_degree", "lpm_degree"), ("lpm_coherence_dof",
                                                         "lpm_coherence_dof")):
            if s.get(key) is not None:
                est[name] = s[key]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fk = condition_frf(estimate_frf(session, **est), **cond)
    return _on_grid(fk.f_hz, fk.H, frf.f_hz)


def block_deviations(frf, H_blocks, f_hz):
    """Each block's relative deviation from the blocks' mean, scaled to the full estimate.

    ``e_k = (H_k - mean_j H_j) / (sqrt(K - 1) H)``: over the ``K`` blocks, the mean of
    ``|e_k|^2`` is the jackknife variance of the full estimate relative to its value, so
    that ``H (1 + e_k)`` is a draw of the full estimate's error as measured (its
    correlations over frequency and between pairs included).

    Parameters
    ----------
    frf : ident.identify.frf.Frf
    H_blocks : ndarray of complex, shape (K, n_out, n_in, n_f)
        :func:`block_frfs`.
    f_hz : ndarray, shape (n,)
        Frequencies to keep them at [Hz] (linear interpolation).

    Returns
    -------
    ndarray of complex64, shape (K, n_out, n_in, n)
        0 where ``H`` is 0.
    """
    K = H_blocks.shape[0]
    H = frf.H
    with np.errstate(invalid="ignore", divide="ignore"):
        e = np.where(np.abs(H) > 0, (H_blocks - H_blocks.mean(axis=0))
                     / (np.sqrt(K - 1) * np.where(np.abs(H) > 0, H, 1.0)), 0.0)
    return np.stack([_on_grid(frf.f_hz, ek, np.asarray(f_hz, dtype=float))
                     for ek in e]).astype(np.complex64)


def cross_validate_frf(session, frf, *, blocks=CV_BLOCKS, noise=True):
    """The session's cross-validation of its conditioned FRF, kept with the FRF.

    Parameters
    ----------
    session : ident.data.session.Session
        The session `frf` was estimated from.
    frf : ident.identify.frf.Frf
        Conditioned.
    blocks : int
    noise : bool
        Also measure the bias from the noise on the shock-force inputs
        (:func:`noise_bias`, two more estimates of the FRF), which no time block sees.

    Returns
    -------
    ident.identify.frf.Frf
        `frf` with ``cv_deviation`` (:func:`block_deviations` on ``CV_GRID``
        log-spaced frequencies), ``noise_bias`` (:func:`noise_bias` on the same
        frequencies, or None) and ``settings["cross_validation"]``
        (:func:`cross_validation_ratio`, plus ``f_hz``: the deviations' frequencies, and
        ``noise_bias``: whether it was measured).
    """
    H_blocks = block_frfs(session, frf, blocks=blocks)
    hi = min(CV_GRID_HZ[1], float(frf.f_hz[-1]))
    lo = max(CV_GRID_HZ[0], float(frf.f_hz[1]))
    grid = np.geomspace(lo, hi, CV_GRID)
    doc = cross_validation_ratio(frf, H_blocks)
    doc["f_hz"] = [float(f) for f in np.round(grid, 6)]
    bias = noise_bias(session, frf, grid) if noise else None
    doc["noise_bias"] = bias is not None
    return dataclasses.replace(frf, settings=dict(frf.settings, cross_validation=doc),
                               cv_deviation=block_deviations(frf, H_blocks, grid),
                               noise_bias=bias)


def _pooled(num, den, axis):
    """Root of the summed ratio of `num` to `den` (NaN where too few lines)."""
    n = np.sum(np.isfinite(num) & np.isfinite(den), axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.sqrt(np.nansum(num, axis=axis) / np.nansum(den, axis=axis))
    return np.where(n >= MIN_LINES, r, np.nan)


def cross_validation_ratio(frf, H_blocks, *, band_edges_hz=CV_BAND_EDGES_HZ):
    """Measured over stated standard error of the full estimate, per pair and band.

    Parameters
    ----------
    frf : ident.identify.frf.Frf
        The full conditioned estimate (with ``sigma``).
    H_blocks : ndarray of complex, shape (K, n_out, n_in, n_f)
        :func:`block_frfs`.
    band_edges_hz : sequence of float
        Edges of the pooling bands [Hz].

    Returns
    -------
    dict
        JSON-ready: ``blocks`` (K), ``band_edges_hz``, ``ratio`` (nested lists, shape
        (n_out, n_in, n_bands): the factor on ``frf.sigma`` that gives the measured
        error, NaN-free: a pair or band without enough measured lines takes the
        overall ratio), ``ratio_all`` (the overall ratio), ``ratio_pair`` (n_out,
        n_in) and ``ratio_band`` (n_bands).
    """
    K = H_blocks.shape[0]
    mag2 = np.abs(frf.H) ** 2
    spread = np.sum(np.abs(H_blocks - H_blocks.mean(axis=0)) ** 2, axis=0) / (K * (K - 1))
    sigma = frf.sigma
    if sigma is None:
        raise ValueError("cross_validation_ratio needs a conditioned FRF (frf.sigma); condition "
                         "it with ident.identify.condition.condition_frf first")
    edges = np.asarray(band_edges_hz, dtype=float)
    f = frf.f_hz
    inside = (f >= edges[0]) & (f <= edges[-1])
    ok = inside & (mag2 > 0)
    if frf.replaced is not None:
        ok = ok & ~frf.replaced
    else:
        ok = np.broadcast_to(ok, mag2.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        num = np.where(ok, spread / mag2, np.nan)
        den = np.where(ok, sigma**2 / mag2, np.nan)
    r_all = _pooled(num.ravel(), den.ravel(), axis=0)
    r_all = float(r_all) if np.isfinite(r_all) else 1.0
    r_pair = _pooled(num, den, axis=-1)
    band = np.clip(np.searchsorted(edges, f, side="right") - 1, 0, edges.size - 2)
    r_band = np.array([_pooled(num[..., band == b].ravel(), den[..., band == b].ravel(), axis=0)
                       for b in range(edges.size - 1)])
    r_pair = np.where(np.isfinite(r_pair), r_pair, r_all)
    r_band = np.where(np.isfinite(r_band), r_band, r_all)
    ratio = r_pair[..., None] * r_band / r_all
    log.info("cross-validation (%d blocks): measured / stated standard error %.2f overall, "
             "%.2f-%.2f over bands", K, r_all, np.min(r_band), np.max(r_band))
    return {"blocks": int(K), "band_edges_hz": [float(e) for e in edges],
            "ratio": np.round(ratio, 4).tolist(), "ratio_all": round(r_all, 4),
            "ratio_pair": np.round(r_pair, 4).tolist(),
            "ratio_band": np.round(r_band, 4).tolist()}


def noise_records(session, cbar_n_s_m):
    """Per corner, a record of the noise on its shock-force deviation ``dF``.

    Where a run's shock at a corner is linear at ``c_bar`` (the baseline's), ``dF`` is
    exactly 0 (:func:`ident.identify.frf.shock_force_deviation`) and the measured
    ``F - c_bar v`` is what the sensors add to it (their noise, and the real shock's
    departure from its nominal curve): the error the ``dF`` inputs carry where the
    shock is swapped, measured on the session itself.

    Parameters
    ----------
    session : ident.data.session.Session
    cbar_n_s_m : array_like, shape (4,)

    Returns
    -------
    dict
        Corner -> ndarray (n,) [N], the runs' records end to end (means removed); a
        corner is missing where no run has its force measured (``shock_force_XX``) at a
        ``c_bar``-linear shock.
    """
    cbar = np.asarray(cbar_n_s_m, dtype=float)
    rec = {c: [] for c in CORNERS}
    for run in session.runs:
        _, dF = shock_force_deviation(run, session.shocks, cbar)
        for i, c in enumerate(CORNERS):
            if f"shock_force_{c}" in run.channels and not np.any(dF[i]):
                rec[c].append(run.dynamic(f"shock_force_{c}")
                              - cbar[i] * run.dynamic(f"shock_velocity_{c}"))
    return {c: np.concatenate(r) for c, r in rec.items() if r}


def sensor_noise(session, cbar_n_s_m):
    """Per corner, the white noise of its shock velocity and force sensors.

    Where ``dF`` is 0 (the shock is the baseline's, linear at ``c_bar``) the measured
    ``e = F - c_bar v`` is the sensors' noise, ``n_F - c_bar n_v``
    (:func:`noise_records`), and the measured velocity holds ``n_v``: so
    ``E[e v] = -c_bar var(n_v)`` and ``var(e) = var(n_F) + c_bar^2 var(n_v)``, taken on
    first differences (white noise assumed: a sensor's floor; the signal, mostly at low
    frequencies, then scatters the covariance much less).

    Parameters
    ----------
    session : ident.data.session.Session
    cbar_n_s_m : array_like, shape (4,)

    Returns
    -------
    dict
        Corner -> ``(sigma_v_m_s, sigma_f_n)``, standard deviations of the velocity's and
        the force's noise per sample [m/s], [N]; a corner is missing where no run has its
        force measured at a ``c_bar``-linear shock.
    """
    cbar = np.asarray(cbar_n_s_m, dtype=float)
    ev = {c: [0.0, 0.0, 0] for c in CORNERS}  # sum e v, sum e^2, samples
    for run in session.runs:
        _, dF = shock_force_deviation(run, session.shocks, cbar)
        for i, c in enumerate(CORNERS):
            if f"shock_force_{c}" in run.channels and not np.any(dF[i]):
                # first differences: white noise keeps its variance (twice it), the
                # drive's low-frequency signal mostly goes (its scatter in e v with it)
                v = np.diff(run.dynamic(f"shock_velocity_{c}"))
                e = np.diff(run.dynamic(f"shock_force_{c}")) - cbar[i] * v
                ev[c][0] += float(e @ v) / 2
                ev[c][1] += float(e @ e) / 2
                ev[c][2] += e.size
    out = {}
    for i, c in enumerate(CORNERS):
        sev, see, n = ev[c]
        if n:
            var_v = max(-sev / n / cbar[i], 0.0)
            var_f = max(see / n - cbar[i] ** 2 * var_v, 0.0)
            out[c] = (float(np.sqrt(var_v)), float(np.sqrt(var_f)))
    return out


def noisier_sessions(session, cbar_n_s_m, *, seed=NOISE_SEED):
    """Two copies of `session` whose swapped corners' sensors carry their noise once more.

    At every corner of a run whose ``dF`` is not 0 and whose force is measured, the
    velocity and the force (``shock_velocity_XX``, ``shock_force_XX``) get white Gaussian
    noise of the sensors' own size (:func:`sensor_noise`): ``+n`` in the first copy and
    ``-n`` in the second. The velocity's noise enters both an output of the FRF and its
    ``dF`` input (``-c_bar n_v``), as the sensor's own noise does.

    Parameters
    ----------
    session : ident.data.session.Session
    cbar_n_s_m : array_like, shape (4,)
    seed : int
        Of the added noise.

    Returns
    -------
    tuple of two ident.data.session.Session, or None
        None where no corner can be given any (no measured force at a ``c_bar``-linear
        shock, no swapped corner with a measured force, or noise-free sensors).
    """
    cbar = np.asarray(cbar_n_s_m, dtype=float)
    sigma = sensor_noise(session, cbar)
    rng = np.random.default_rng(seed)
    plus, minus, added = [], [], 0
    for run in session.runs:
        _, dF = shock_force_deviation(run, session.shocks, cbar)
        ch_p, ch_m = dict(run.channels), dict(run.channels)
        for i, c in enumerate(CORNERS):
            fname, vname = f"shock_force_{c}", f"shock_velocity_{c}"
            if not np.any(dF[i]) or fname not in run.channels or c not in sigma:
                continue
            s_v, s_f = sigma[c]
            F = run.dynamic(fname)
            if s_v + s_f <= ROUND_OFF * (np.std(F) + cbar[i] * np.std(run.dynamic(vname))):
                continue  # noise-free sensors: nothing to add
            for name, s in ((vname, s_v), (fname, s_f)):
                n = s * rng.standard_normal(run.n_samples)
                ch_p[name] = run.channels[name] + n
                ch_m[name] = run.channels[name] - n
            added += 1
        plus.append(dataclasses.replace(run, channels=ch_p))
        minus.append(dataclasses.replace(run, channels=ch_m))
    if not added:
        return None
    return (dataclasses.replace(session, runs=tuple(plus)),
            dataclasses.replace(session, runs=tuple(minus)))


def noise_bias(session, frf, f_hz):
    """The bias of the FRF from the noise on its shock-force inputs, measured by adding it.

    The ``dF`` inputs are computed from measured forces and velocities, so their sensors'
    noise is noise on *inputs* (errors in variables): it biases the estimate (toward
    zero, and through whatever the regression shares with them) the same way in every
    time block, which the cross-validation cannot see. Its size is measured as in
    simulation-extrapolation: the FRF is estimated again (with `frf`'s settings) with the
    swapped corners' forces carrying the noise once more, ``+n`` and ``-n``
    (:func:`noise_records`: the session's own ``F - c_bar v`` where ``dF`` is 0). To first
    order the bias grows with the noise's variance, so the mean of the two estimates less
    ``H`` is the bias of ``H`` itself, and the terms odd in the added noise (its random
    error) cancel between ``+n`` and ``-n``.

    Parameters
    ----------
    session : ident.data.session.Session
        The session `frf` was estimated from.
    frf : ident.identify.frf.Frf
        Conditioned.
    f_hz : ndarray, shape (n,)
        Frequencies to keep it at [Hz].

    Returns
    -------
    ndarray of complex64, shape (n_out, n_in, n) or None
        ``(mean(H+, H-) - H) / H``: the relative bias of the estimate (0 where ``H`` is
        0); None where the session has no measured force at a ``c_bar``-linear shock
        (nothing to measure the noise by) or no swapped corner with a measured force.
    """
    pair = noisier_sessions(session, frf.cbar_n_s_m)
    if pair is None:
        log.info("noise bias: no measured shock force at a c_bar-linear shock, no swapped "
                 "corner with one, or no noise on them: not measured")
        return None
    H2 = 0.5 * (_estimate_like(pair[0], frf) + _estimate_like(pair[1], frf))
    H = frf.H
    with np.errstate(invalid="ignore", divide="ignore"):
        b = np.where(np.abs(H) > 0, (H2 - H) / np.where(np.abs(H) > 0, H, 1.0), 0.0)
    b = np.where(np.isfinite(b), b, 0.0)
    return _on_grid(frf.f_hz, b, np.asarray(f_hz, dtype=float)).astype(np.complex64)
