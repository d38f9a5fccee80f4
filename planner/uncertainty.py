"""Uncertainty of predicted metrics from the identification's random error.

The random error of an H1 estimate at one frequency line follows from its
coherence and the number of averages (Bendat and Piersol): the normalized
error of ``|H|`` (and the phase error in radians) is about

    eps = sqrt((1 - g2) / (2 n_d g2))

with ``g2`` the partial coherence of the pair and ``n_d`` the number of Welch
blocks (less the number of inputs). A Monte Carlo draw perturbs every pair of
the conditioned FRF by complex Gaussian relative errors of that size, smoothed
along frequency by the same filter the conditioning used (so errors are
correlated over the smoothing width, as the smoothed estimate's are), and
predicts every setup with the fast frequency-domain screening
(:mod:`planner.screen`) on the perturbed FRF. The spread of the draws, relative
to the unperturbed screening prediction, gives each metric an interval; the
fraction of draws in which two setups swap order tells whether the model
resolves their order.

This covers the estimation noise of the rig data, not model-structure errors
(nonlinearity of the car, fit bias); the fit error of each pair is reported
with the model.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import signal

from ident.channels import SHOCK_VELOCITIES

__all__ = ["Uncertainty", "FrfPlant", "frf_relative_error", "prediction_uncertainty",
           "unresolved_pairs"]

log = logging.getLogger(__name__)

#: Relative error assigned where the coherence is ~0 (the estimate carries no information).
MAX_RELATIVE_ERROR = 1.0


class FrfPlant:
    """A plant given by a frequency response on a grid (for frequency-domain screening).

    Parameters
    ----------
    f_hz : ndarray, shape (n_f,)
    H : ndarray of complex, shape (n_out, 11, n_f)
        Inputs rig (7) then dF (4).
    output_names : sequence of str
    cbar_n_s_m : ndarray, shape (4,)
    name : str
    """

    def __init__(self, f_hz, H, output_names, cbar_n_s_m, name="frf"):
        self.f_hz = np.asarray(f_hz, dtype=float)
        self.H = H
        self.output_names = tuple(output_names)
        self.cbar_n_s_m = np.asarray(cbar_n_s_m, dtype=float)
        self.name = name
        self.velocity_idx = np.array([self.output_names.index(v) for v in SHOCK_VELOCITIES])

    def frequency_response(self, f_hz):
        """Linear interpolation of the real and imaginary parts, shape (n_out, 11, n_f)."""
        f = np.asarray(f_hz, dtype=float)
        idx = np.clip(np.searchsorted(self.f_hz, f) - 1, 0, self.f_hz.size - 2)
        t = (f - self.f_hz[idx]) / (self.f_hz[idx + 1] - self.f_hz[idx])
        return self.H[..., idx] * (1 - t) + self.H[..., idx + 1] * t


@dataclass(frozen=True, eq=False)
class Uncertainty:
    """Monte Carlo uncertainty of predicted metrics.

    Attributes
    ----------
    ratio_lo, ratio_hi : pandas.DataFrame
        Per setup (rows) and metric (columns): lower and upper quantiles of the
        draws divided by the unperturbed prediction (multiply a prediction by
        them to get its interval).
    draws : ndarray, shape (n_draws, n_setups, n_metrics)
        Metric ratios of every draw.
    metric_names : list of str
    settings : dict
    """

    ratio_lo: pd.DataFrame
    ratio_hi: pd.DataFrame
    draws: np.ndarray
    metric_names: list
    settings: dict = field(default_factory=dict)

    def intervals(self, table):
        """Add ``<metric>_lo`` and ``<metric>_hi`` columns to a predictions table (SI)."""
        out = table.copy()
        for m in self.metric_names:
            if m in out:
                out[f"{m}_lo"] = out[m] * self.ratio_lo[m].reindex(out.index).to_numpy()
                out[f"{m}_hi"] = out[m] * self.ratio_hi[m].reindex(out.index).to_numpy()
        return out


def frf_relative_error(frf):
    """Random relative error of every FRF line, shape (n_out, n_in, n_f).

    ``sqrt((1 - g2) / (2 n_d g2))`` with the partial coherence ``g2`` and
    ``n_d = n_averages - n_inputs`` (at least 1), capped at
    :data:`MAX_RELATIVE_ERROR`. Lines replaced in conditioning take the
    median error of the pair's measured lines.
    """
    g2 = np.clip(frf.partial_coherence, 1e-12, 1.0)
    n_d = max(frf.n_averages - len(frf.input_names), 1)
    eps = np.minimum(np.sqrt((1 - g2) / (2 * n_d * g2)), MAX_RELATIVE_ERROR)
    if frf.replaced is not None:
        meas = np.where(frf.replaced, np.nan, eps)
        med = np.nanmedian(np.where(np.all(np.isnan(meas), axis=-1, keepdims=True), eps, meas),
                           axis=-1, keepdims=True)
        eps = np.where(frf.replaced, med, eps)
    return eps


def prediction_uncertainty(model, drive, setups, library, *, n_draws=40, seed=0,
                           quantiles=(0.025, 0.975), band_hz=(1.0, 20.0), n_bands=96):
    """Monte Carlo intervals of setups' metrics from the FRF's random error.

    Parameters
    ----------
    model : ident.model.VehicleModel
        Must carry its conditioned FRF (``model.frf``).
    drive : ident.drive.Drive
    setups : sequence of planner.setups.Setup
    library : ident.shocks.ShockLibrary
    n_draws : int
    seed : int
    quantiles : (float, float)
        Interval bounds (default a 95 % interval).

    Returns
    -------
    Uncertainty

    Raises
    ------
    ValueError
        If the model has no FRF (a known physical model has no estimation error).
    """
    from planner.screen import screen_setups

    frf = getattr(model, "frf", None)
    if frf is None:
        raise ValueError("prediction_uncertainty needs an identified model with its FRF "
                         "(model.frf); a known model has no estimation error")
    if n_draws < 2:
        raise ValueError(f"n_draws must be at least 2, got {n_draws}")
    eps = frf_relative_error(frf)
    width = frf.settings.get("conditioning", {}).get("smooth_width_hz", 0.6)
    df = frf.f_hz[1] - frf.f_hz[0]
    wn = min(2 * df / width, 0.99)
    sos = signal.butter(4, wn, output="sos")
    # white noise smoothed by filtfilt loses variance: rescale so the smoothed error keeps
    # the per-line variance reduced by the number of lines averaged (the smoothed
    # estimate's error), i.e. divide by sqrt(lines per width)
    probe = signal.sosfiltfilt(sos, np.random.default_rng(1).standard_normal(200_000))
    gain = 1.0 / probe.std()
    per_width = np.sqrt(max(width / df, 1.0))
    nominal = screen_setups(FrfPlant(frf.f_hz, frf.H, frf.output_names, frf.cbar_n_s_m),
                            drive, setups, library, band_hz=band_hz, n_bands=n_bands)
    names = nominal.metric_names
    base = nominal.table[names].to_numpy()
    rng = np.random.default_rng(seed)
    draws = np.empty((n_draws, len(setups), len(names)))
    for d in range(n_draws):
        z = rng.standard_normal(eps.shape) + 1j * rng.standard_normal(eps.shape)
        z = signal.sosfiltfilt(sos, z.real, axis=-1) + 1j * signal.sosfiltfilt(sos, z.imag, axis=-1)
        e = z * gain / np.sqrt(2) * eps / per_width
        plant = FrfPlant(frf.f_hz, frf.H * (1 + e), frf.output_names, frf.cbar_n_s_m)
        pred = screen_setups(plant, drive, setups, library, band_hz=band_hz, n_bands=n_bands)
        draws[d] = pred.table[names].to_numpy() / base
    lo = np.quantile(draws, quantiles[0], axis=0)
    hi = np.quantile(draws, quantiles[1], axis=0)
    index = nominal.table.index
    return Uncertainty(ratio_lo=pd.DataFrame(lo, index=index, columns=names),
                       ratio_hi=pd.DataFrame(hi, index=index, columns=names), draws=draws,
                       metric_names=names,
                       settings={"n_draws": n_draws, "seed": seed, "quantiles": tuple(quantiles),
                                 "n_averages": frf.n_averages, "smooth_width_hz": width})


def unresolved_pairs(scores, uncertainty, objective, *, baseline=None, max_flip=0.05, top=None):
    """Setup pairs whose objective order the model does not resolve.

    Each draw's metric ratios scale the given (time-domain) metrics; the
    objective is re-scored per draw, and a pair whose order flips in more than
    `max_flip` of the draws is unresolved.

    Parameters
    ----------
    scores : pandas.DataFrame
        Predicted metrics (SI) with the setups as index, including the baseline.
    uncertainty : Uncertainty
    objective : planner.objective.Objective
    baseline : str, optional
    max_flip : float
    top : int, optional
        Only pairs among the `top` best setups.

    Returns
    -------
    dict
        Setup name -> list of setup names it is not resolved from.
    """
    from planner.objective import score_setups

    nominal = score_setups(scores, objective, baseline=baseline).table
    order = nominal.sort_values("rank").index.tolist()
    if top is not None:
        order = order[:top]
    names = uncertainty.metric_names
    idx = [uncertainty.ratio_lo.index.get_loc(s) for s in scores.index]
    draw_scores = []
    for d in range(uncertainty.draws.shape[0]):
        t = scores.copy()
        t[names] = scores[names].to_numpy() * uncertainty.draws[d][idx]
        draw_scores.append(score_setups(t, objective, baseline=baseline).table["score"])
    S = pd.concat(draw_scores, axis=1).loc[order].to_numpy()  # (n_top, n_draws)
    nom = nominal.loc[order, "score"].to_numpy()
    out = {s: [] for s in order}
    for a in range(len(order)):
        for b in range(a + 1, len(order)):
            if not (np.isfinite(nom[a]) and np.isfinite(nom[b])) or nom[a] == nom[b]:
                continue
            flips = np.mean(np.sign(S[a] - S[b]) != np.sign(nom[a] - nom[b]))
            if flips > max_flip:
                out[order[a]].append(order[b])
                out[order[b]].append(order[a])
    return out
