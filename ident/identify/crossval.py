"""The session's own cross-validation of its FRF estimate: how wrong the estimate is.

The standard error an FRF estimator states (:func:`ident.identify.condition.
conditioned_standard_error`) is a model of its error: white measurement noise,
independent lines, a linear car. What departs from that model (the swap runs'
nonlinear residual, the drive's transients, correlated noise, the smoothing's
bias on a steep flank) is not in it, and how large it is depends on the car and
the session. This module measures it on the session itself:

1. Every run is cut into ``blocks`` contiguous time blocks; block ``k`` of the
   session holds piece ``k`` of every run (the same swaps, a different stretch of
   the drive and of the noise).
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

Assumptions: the error of the estimate from ``K`` blocks is the mean of the
blocks' errors (an estimator's variance falls as one over the record length;
the LPM's does), the blocks' errors are independent (blocks much longer than
the car's impulse response: seconds against tens of milliseconds), and the
error that is common to all blocks (a bias of the estimator, the same in each
block) is not seen here: :mod:`planner.uncertainty` carries the fit's and the
smoothing's bias as systematic terms.
"""

from __future__ import annotations

import dataclasses
import logging
import warnings

import numpy as np

from ident.identify.condition import condition_frf
from ident.identify.frf import estimate_frf

__all__ = [
    "CV_BLOCKS",
    "CV_BAND_EDGES_HZ",
    "CV_GRID",
    "block_deviations",
    "block_frfs",
    "cross_validate_frf",
    "cross_validation_ratio",
    "split_session",
]

log = logging.getLogger(__name__)

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


def split_session(session, blocks=CV_BLOCKS):
    """Cut every run of `session` into `blocks` contiguous time blocks.

    Parameters
    ----------
    session : ident.data.session.Session
    blocks : int
        Number of blocks (at least 2).

    Returns
    -------
    list of ident.data.session.Session
        ``blocks`` sessions; session ``k`` holds the ``k``-th stretch of every run
        (the same run names, setups and libraries), of ``n // blocks`` samples.
    """
    if blocks < 2:
        raise ValueError(f"blocks must be at least 2, got {blocks}")
    out = []
    for k in range(blocks):
        runs = []
        for run in session.runs:
            n = run.n_samples // blocks
            sl = slice(k * n, (k + 1) * n)
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
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for sub in split_session(session, blocks):
            fk = condition_frf(estimate_frf(sub, **est), **cond)
            out.append(_on_grid(fk.f_hz, fk.H, frf.f_hz))
    return np.stack(out)


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


def cross_validate_frf(session, frf, *, blocks=CV_BLOCKS):
    """The session's cross-validation of its conditioned FRF, kept with the FRF.

    Parameters
    ----------
    session : ident.data.session.Session
        The session `frf` was estimated from.
    frf : ident.identify.frf.Frf
        Conditioned.
    blocks : int

    Returns
    -------
    ident.identify.frf.Frf
        `frf` with ``cv_deviation`` (:func:`block_deviations` on ``CV_GRID``
        log-spaced frequencies) and ``settings["cross_validation"]``
        (:func:`cross_validation_ratio`, plus ``f_hz``: the deviations' frequencies).
    """
    H_blocks = block_frfs(session, frf, blocks=blocks)
    hi = min(CV_GRID_HZ[1], float(frf.f_hz[-1]))
    lo = max(CV_GRID_HZ[0], float(frf.f_hz[1]))
    grid = np.geomspace(lo, hi, CV_GRID)
    doc = cross_validation_ratio(frf, H_blocks)
    doc["f_hz"] = [float(f) for f in np.round(grid, 6)]
    return dataclasses.replace(frf, settings=dict(frf.settings, cross_validation=doc),
                               cv_deviation=block_deviations(frf, H_blocks, grid))


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
