"""Uncertainty of predicted metrics: the identification's random error and the model's
systematic errors.

An identified model's prediction departs from the truth for five reasons, each
estimated here and combined into one interval per setup and metric:

1. **Random error of the FRF estimate** (sensor noise, finite records, what the
   estimator's error model misses), its size measured by the session's own
   cross-validation where the model has it (below). Each
   line of the conditioned FRF has a complex standard error ``sigma``
   (:func:`ident.identify.condition.conditioned_standard_error`: the estimator's own
   variance, reduced by the smoothing), and the errors of neighbouring lines
   are correlated over the smoothing width. A Monte Carlo draw perturbs every
   pair at the screening's band centres by complex Gaussian relative errors
   ``e`` of that size and that correlation (the autocorrelation of the
   conditioning's smoothing filter), *zero-mean in power*::

       H_d = H (1 + e) / sqrt(1 + E|e|^2),   E|H_d|^2 = |H|^2

   so that the draws spread around the prediction instead of drifting above
   it where the error is large (``E|H (1 + e)|^2 = |H|^2 (1 + E|e|^2)``). Every
   setup is screened on every draw (:mod:`planner.screen`); the draws'
   quantiles, relative to the unperturbed screening, give the random part.
2. **Fit error**: the screening of the fitted model (unreduced) against that
   of the conditioned FRF it was fitted to, within the fit's band (outside it
   the FRF is extrapolated by residual fits, the model is not). The random
   draws perturb the fitted model's response, so the nominal of the random
   part is the model's own screening.
3. **Loop reduction**: the screening of the reduced loop plant the time
   domain runs against the unreduced one.
4. **Time discretization**: the time-domain prediction at the given
   oversampling against twice that (the quadratic hold's error falls as
   ``h^3``, so the error at ``h`` is ``8/7`` of the difference).

**The random part's size from the session's own cross-validation (issue 37).** The
draws above are at the FRF's *stated* standard error, a model of its error (white noise,
independent lines, a linear car) whose mismatch depends on the car and the session: a
factor fitted to a family of cars (:func:`random_error_scale`) covered 68-73 % on the
paper's car and 99.8 % on a GT car. Identification now measures the error on the
session itself (:mod:`ident.identify.crossval`): the FRF of each time block of every run
(its two halves), each half's deviation from the blocks' mean scaled to the full
estimate (``Frf.cv_deviation``). Here the model's response is perturbed by each
deviation and every setup screened (:func:`cross_validation_deviations`); the draws'
spread about the nominal is then scaled so that its mean square per metric matches the
cross-validation's (:func:`cross_validated_scale`; one realization per metric, so not
below the measured-over-stated ratio of the FRF's lines, ``ratio_all``), times
:data:`CV_LENGTH_FACTOR` (the halves' error is between sqrt(2) and 1 times the full
data's), recorded as ``random_scale`` with ``random_error = "cross-validation"``. The draws keep their shape (their correlation
over frequency, shared by all setups), the cross-validation sets their size, with its
own correlations between pairs and over frequency. A model without it (an older model
file) gets the formula, and says so in the log.

5. **The estimate's bias from the noise on its dF inputs** (errors in variables: ``dF``
   is computed from the measured force and velocity), the same in every time block so
   not in the cross-validation, measured at identification by adding the sensors' noise
   once more (:func:`ident.identify.crossval.noise_bias`, ``Frf.noise_bias``): the term
   ``input_noise``, the model's screening against that of the model with the bias taken
   out.

The systematic parts (2-4) are signed relative errors per setup and metric;
each widens the interval on both sides, added in quadrature to the random
part's half-widths (their signs are estimates, not certainties): the upper
bound ``hi_r + sqrt(u^2 + sum d^2) - u`` with ``u = max(hi_r - 1, 0)``, the
lower likewise. A measured bias (5, :data:`SIGNED_TERMS`) keeps its sign: the interval
then extends toward it linearly (it holds the interval with the bias taken out). The fraction
of draws in which two setups swap order tells whether the model resolves
their order (:func:`unresolved_pairs` with ``max_flip``).

**Scores and their differences** (:func:`score_errors`, :func:`score_intervals`,
:func:`difference_interval`): every draw's metric ratios scale the predicted metrics and
the objective scores them again, so each setup has a score per draw; two setups predicted
by the same model share most of its error, so the *per-draw difference* of their scores
spreads much less than either score. The systematic terms enter a score as its signed
shift when every setup's metrics move by that term (``S(m (1 + d_k)) - S(m)``), and a
difference as the difference of the two setups' shifts (alike errors cancel), each term
added in quadrature to the random half-widths as above. A setup is *tied* with another
where the interval of their difference contains 0. Only :class:`ScoreErrors` reaches the
intervals: another error model (e.g. one calibrated on the session's own
cross-validation) replaces the draws by giving its own per-draw scores and systematic
shifts.

Measured on the virtual rig (paper's plan with 5 % response and 1.25 % input
noise, 41 setups on a 120 s track drive): the old intervals (Bendat-Piersol
magnitude error on uncorrelated lines, no systematic terms) covered 28 % of
the known model's metrics; see ``docs/DESIGN.md`` for the figures now.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from ident.data.drive import check_drive_inputs
from ident.identify.condition import (
    conditioned_error_kernel,
    conditioned_standard_error,
)
from ident.identify.frf import embed_inputs
from planner.objective import score_setups
from planner.options import ElementOptions, LoopOptions, UncertaintyOptions, as_options
from planner.plant import FrfPlant, interpolate
from planner.predict import predict_setups, prepare_drive, resolve_setups
from planner.screen import drive_bands, screen_response

__all__ = [
    "CV_LENGTH_FACTOR",
    "LIGHT_DAMPING_ZETA",
    "MAX_RELATIVE_ERROR",
    "RANDOM_ERROR_SCALE",
    "REFERENCE_RUN_S",
    "SCORE_INTERVAL_COLUMNS",
    "SIGNED_TERMS",
    "SYSTEMATIC_TERMS",
    "FrfPlant",  # from planner.plant
    "ScoreErrors",
    "Uncertainty",
    "combine_terms",
    "difference_interval",
    "cross_validated_scale",
    "cross_validation_deviations",
    "error_correlation",
    "frf_relative_error",
    "interpolate",  # from planner.plant
    "light_modes",
    "noise_bias_deviation",
    "prediction_uncertainty",
    "random_error_scale",
    "run_length_scale",
    "score_errors",
    "score_intervals",
    "unresolved_pairs",
]

log = logging.getLogger(__name__)

#: Relative error assigned where the coherence is ~0 (the estimate carries no information).
MAX_RELATIVE_ERROR = 1.0
#: The random part's scale: the FRF's standard errors are multiplied by
#: ``RANDOM_ERROR_SCALE * sqrt(max(T, REFERENCE_RUN_S) / REFERENCE_RUN_S)``, ``T`` the session's
#: run length (:func:`random_error_scale`). Fitted by ``studies/interval_calibration.py``
#: for 95 % pooled coverage of the known model's metrics on 6 calibration cars (the paper's,
#: the tests' generalized car and 4 more; 3 identifications each at their own run length,
#: 150-800 s, and 3 at 120 s; 33 identifications without a lightly damped mode, 20 setups x 14
#: metrics each). Held out (mean over 3 identifications): GT-like 300 s 95.5 %, compact
#: 250 s 95.2 %, soft heavy 600 s 94.6 %, stiff light 800 s 92.5 %; the same cars at 120 s
#: runs 57.5 % (GT-like: its twist mode under-resolved, an identification failure), 87.1 %,
#: 95.1 %, 89.0 %. One identification's coverage is a sample of about 14 independent errors
#: (an identification's metric error is shared by all setups): its standard deviation is
#: about 5 % (single identifications ranged 78-100 %). Before issue 24 this was 1.5 at every
#: run length (tuned on one 800 s case at 5 % noise): 99 % at 120-300 s, 82 % on the stiff
#: light car at 800 s.
RANDOM_ERROR_SCALE = 0.98
#: Run length [s] up to which the random part's scale is :data:`RANDOM_ERROR_SCALE`. Beyond
#: it the scale grows as ``sqrt(T)``: the conditioned FRF's standard error falls as the
#: smoothing averages more lines (``~ 1 / sqrt(T)``), the metric errors did not (the swap
#: runs' nonlinear residual and the fit do not average out), so the random part keeps its
#: width at longer runs. Cars needed scales of 0.7-1.5 at 120-300 s and 1.3-2.6 at 400-800 s.
REFERENCE_RUN_S = 150.0
#: A mode of an identified model this lightly damped or less is "lightly damped": the fit
#: clips its poles' damping ratios at :data:`ident.identify.pipeline.ZETA_MIN` (0.02), so a
#: mode of the car at or below 0.02 shows as poles at 0.02; the margin to 0.025 is for the
#: clipping's round-off. The cars of ``studies/interval_calibration.py`` (every one with tire
#: damping) have their least damped mode in the metric band at 0.05 or more.
LIGHT_DAMPING_ZETA = 0.025
#: A pole counts for a pair where its own resonance peak, ``|r| / (zeta w_n)``, is at least
#: this fraction of the pair's largest response in the band (the fit's small noise poles do
#: not count).
LIGHT_MODE_MIN_PEAK = 0.1
#: A lightly damped mode is reported where at least this share of the model's fitted pairs
#: (and at least 3) have such a pole within :data:`LIGHT_MODE_CLUSTER_HZ` of each other: the
#: light car of issue 24 (twist mode at 13 Hz, no tire damping) had it in 149 pair-poles; the
#: normal cars had at most 2 stray poles, at 1-2 Hz.
LIGHT_MODE_MIN_SHARE = 0.05
#: Poles closer than this [Hz] are one mode.
LIGHT_MODE_CLUSTER_HZ = 0.5
#: The cross-validation measures the error of an estimate from half the data; the full
#: estimate's error lies between that over 2 (an error that falls as 1 / T: noise) and
#: the same (one that does not fall: the swap runs' nonlinear residual, the drive's
#: transients; issue 24 found the metric errors stop falling beyond 150-300 s). Neither
#: is known for a session, so the variance is taken at the geometric middle: the half
#: data's over sqrt(2), the random part's width 2^(1/4) times the jackknife's. A 95 %
#: interval then covers 98 % at one extreme and 90 % at the other (1.96 standard
#: deviations times 2^(+-1/4)).
CV_LENGTH_FACTOR = 2.0 ** 0.25
#: The systematic error terms of an interval, in :attr:`Uncertainty.components`.
SYSTEMATIC_TERMS = ("fit", "reduction", "discretization", "input_noise")
#: Systematic terms that are measured biases, sign included (the same in repeated
#: identifications): an interval extends toward them linearly (it holds the prediction's
#: interval and the same interval with the bias taken out) instead of in quadrature.
SIGNED_TERMS = ("input_noise",)
#: The columns :func:`score_intervals` gives a ranking table (``docs/formats.md``).
SCORE_INTERVAL_COLUMNS = ("score_lo", "score_hi", "diff_best_lo", "diff_best_hi",
                          "diff_baseline_lo", "diff_baseline_hi", "verdict",
                          "verdict_baseline")
#: The quadratic hold's error falls as h^3: the error at h is 8/7 of (P(h) - P(h/2)).
_RICHARDSON_H3 = 8.0 / 7.0


def run_length_scale(run_s):
    """The random part's scale for runs of `run_s` seconds (:data:`RANDOM_ERROR_SCALE`).

    Parameters
    ----------
    run_s : float or None
        Run length [s]; None (unknown) gives :data:`RANDOM_ERROR_SCALE`.

    Returns
    -------
    float

    Examples
    --------
    >>> round(run_length_scale(600.0) / run_length_scale(100.0), 12)
    2.0
    """
    if run_s is None:
        return RANDOM_ERROR_SCALE
    return RANDOM_ERROR_SCALE * float(np.sqrt(max(float(run_s), REFERENCE_RUN_S) / REFERENCE_RUN_S))


def cross_validation_deviations(frf, f_hz):
    """The session's cross-validation deviations of an FRF at `f_hz`, or None.

    ``frf.cv_deviation`` (written by identification,
    :func:`ident.identify.crossval.cross_validate_frf`): each time block's relative
    deviation from the blocks' mean, scaled to the full estimate's error, interpolated
    at `f_hz` and embedded in the 11 inputs of the screening.

    Parameters
    ----------
    frf : ident.identify.frf.Frf
    f_hz : ndarray, shape (n,)
        Frequencies [Hz].

    Returns
    -------
    ndarray of complex, shape (n_blocks, n_out, 11, n), or None
        None where the FRF has none (a model file from before issue 37, or identified
        with ``cross_validate=False``): the intervals then take
        :func:`random_error_scale`.
    """
    dev = getattr(frf, "cv_deviation", None)
    cv = (getattr(frf, "settings", None) or {}).get("cross_validation") or {}
    if dev is None or "f_hz" not in cv:
        return None
    grid = np.asarray(cv["f_hz"], dtype=float)
    if dev.shape[1:3] != frf.H.shape[:2] or dev.shape[-1] != grid.size:
        log.warning("the model's cross-validation does not match its FRF (%s against %s); "
                    "the intervals take the calibrated formula", dev.shape, frf.H.shape)
        return None
    f = np.clip(np.asarray(f_hz, dtype=float), grid[0], grid[-1])  # the end values beyond
    return embed_inputs(interpolate(grid, dev.astype(complex), f), frf.input_names, axis=2)


def noise_bias_deviation(frf, f_hz):
    """The FRF's measured bias from the noise on its shock-force inputs at `f_hz`, or None.

    ``frf.noise_bias`` (written by identification, :func:`ident.identify.crossval.
    noise_bias`): the relative bias ``b`` of the estimate (``H = H_true (1 + b)``),
    interpolated at `f_hz` and embedded in the 11 inputs of the screening.

    Parameters
    ----------
    frf : ident.identify.frf.Frf
    f_hz : ndarray, shape (n,)
        Frequencies [Hz].

    Returns
    -------
    ndarray of complex, shape (n_out, 11, n), or None
        None where the FRF has none (a model file from before it, a session without
        measured shock forces, or identified with ``cross_validate=False``).
    """
    b = getattr(frf, "noise_bias", None)
    cv = (getattr(frf, "settings", None) or {}).get("cross_validation") or {}
    if b is None or "f_hz" not in cv:
        return None
    grid = np.asarray(cv["f_hz"], dtype=float)
    if b.shape[:2] != frf.H.shape[:2] or b.shape[-1] != grid.size:
        log.warning("the model's noise bias does not match its FRF (%s against %s); "
                    "the intervals leave it out", b.shape, frf.H.shape)
        return None
    f = np.clip(np.asarray(f_hz, dtype=float), grid[0], grid[-1])
    return embed_inputs(interpolate(grid, b.astype(complex), f), frf.input_names)


def cross_validated_scale(cv_deviations, draw_deviations):
    """The factor on the random draws that makes them as large as the cross-validation's.

    Per metric, the mean square of the cross-validation's relative metric deviations
    (over blocks and setups) over that of the draws' (over draws and setups); the
    factor is the root of their mean over the metrics (each metric's error is shared by
    the setups, so a metric is about one degree of freedom per block).

    Parameters
    ----------
    cv_deviations : ndarray, shape (n_blocks, n_setups, n_metrics)
        ``metric(H (1 + e_k)) / metric(H) - 1`` of every block's deviation ``e_k``.
    draw_deviations : ndarray, shape (n_draws, n_setups, n_metrics)
        The same of the random draws at the FRF's stated standard error.

    Returns
    -------
    float
        NaN where no metric has draws that spread.

    Examples
    --------
    >>> cv = np.array([[[0.02, 0.01]], [[-0.02, -0.01]]])
    >>> d = np.array([[[0.01, 0.005]], [[-0.01, -0.005]]])
    >>> float(cross_validated_scale(cv, d))
    2.0
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        num = np.nanmean(np.asarray(cv_deviations, dtype=float) ** 2, axis=(0, 1))
        den = np.nanmean(np.asarray(draw_deviations, dtype=float) ** 2, axis=(0, 1))
        r = num / den
    r = r[np.isfinite(r) & (den > 0)]
    return float(np.sqrt(np.mean(r))) if r.size else float("nan")


def random_error_scale(frf):
    """The factor on an FRF's standard errors in the random part of the intervals.

    :func:`run_length_scale` of the session's run length (the median over its
    runs, from the LPM estimate's ``resolution_hz``, one over each run's
    length). A Welch FRF does not record its runs' length and gets
    :data:`RANDOM_ERROR_SCALE` (the calibration is of the default LPM).

    Parameters
    ----------
    frf : ident.identify.frf.Frf

    Returns
    -------
    float
    """
    res = (getattr(frf, "settings", None) or {}).get("resolution_hz")
    if not res:
        return run_length_scale(None)
    return run_length_scale(float(np.median(1.0 / np.asarray(res, dtype=float))))


@dataclass(frozen=True, eq=False)
class Uncertainty:
    """Intervals of predicted metrics (see the module docstring).

    Attributes
    ----------
    ratio_lo, ratio_hi : pandas.DataFrame
        Per setup (rows) and metric (columns): the interval's bounds divided
        by the prediction (multiply a prediction by them to get its interval),
        random and systematic parts combined.
    draws : ndarray, shape (n_draws, n_setups, n_metrics)
        Metric ratios of every Monte Carlo draw (the random part).
    metric_names : list of str
    components : dict of str -> pandas.DataFrame
        The signed relative systematic errors per setup and metric that were
        estimated (keys from :data:`SYSTEMATIC_TERMS`), and ``random_lo`` /
        ``random_hi``: the random part's bounds as ratios.
    settings : dict
    """

    ratio_lo: pd.DataFrame
    ratio_hi: pd.DataFrame
    draws: np.ndarray
    metric_names: list
    components: dict = field(default_factory=dict)
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
    """Relative standard error of every conditioned FRF line, shape (n_out, n_in, n_f).

    ``sigma / |H|`` with ``sigma`` the complex standard error of the
    conditioned estimate (:func:`ident.identify.condition.conditioned_standard_error`:
    ``E|H_est - H|^2 = sigma^2``; the error of ``|H|`` and of the phase are
    each ``sigma / sqrt(2)``), capped at :data:`MAX_RELATIVE_ERROR`. Lines
    replaced in conditioning (residual fits) take the median error of the
    pair's measured lines.
    """
    sigma = conditioned_standard_error(frf)
    mag = np.abs(frf.H)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(mag > 0, sigma / np.where(mag > 0, mag, 1.0), np.inf)
    eps = np.minimum(np.nan_to_num(rel, nan=np.inf), MAX_RELATIVE_ERROR)
    if frf.replaced is not None:
        meas = np.where(frf.replaced, np.nan, eps)
        med = np.nanmedian(np.where(np.all(np.isnan(meas), axis=-1, keepdims=True), eps, meas),
                           axis=-1, keepdims=True)
        eps = np.where(frf.replaced, med, eps)
    return eps


def error_correlation(frf, f_hz):
    """Correlation of the conditioned FRF's errors between frequencies, shape (n, n).

    ``rho(f_i - f_j)`` from :func:`ident.identify.condition.conditioned_error_kernel`:
    the raw estimate's errors, correlated over its estimation window, then
    smoothed by the conditioning.

    Parameters
    ----------
    frf : Frf
    f_hz : ndarray, shape (n,)
        Frequencies [Hz].

    Returns
    -------
    ndarray, shape (n, n)
    """
    f = np.asarray(f_hz, dtype=float)
    _, lag_hz, acf = conditioned_error_kernel(frf)
    return np.interp(np.abs(f[:, None] - f[None, :]), lag_hz, acf, right=0.0)


def _correlated_factor(C):
    """A factor ``L`` with ``L L^T = C`` for a (possibly semidefinite) correlation matrix."""
    w, V = np.linalg.eigh((C + C.T) / 2)
    return V * np.sqrt(np.clip(w, 0.0, None))


def prediction_uncertainty(model, drive, setups, library, *, draws=UncertaintyOptions(),
                           loop=LoopOptions(), n_bands=96, predictions=None,
                           elements=ElementOptions()):
    """Intervals of setups' metrics from the identification's random and systematic errors.

    Parameters
    ----------
    model : ident.identify.model.VehicleModel
        Must carry its conditioned FRF (``model.frf``).
    drive : ident.data.drive.Drive
    setups : sequence of planner.setups.Setup
    library : ident.models.library.ShockLibrary
    draws : planner.options.UncertaintyOptions
        ``n_draws`` Monte Carlo draws of the random part (at least 2), their ``seed``,
        the interval's ``quantiles`` (default a 95 % interval), ``random_scale`` (factor
        on the FRF's standard errors in the random part; default: measured by the
        session's cross-validation where the model has it
        (:func:`cross_validated_scale`), else :func:`random_error_scale` of the model's
        FRF, the formula fitted to a family of cars).
    loop : planner.options.LoopOptions
        The loop of `predictions` (its ``oversample``) and the metric band ``band_hz``
        [Hz].
    n_bands : int
        Screening bands.
    predictions : planner.predict.Predictions, optional
        The time-domain predictions the intervals are for (with `loop`): given, the
        discretization error is estimated by simulating the setups once more at twice
        the oversampling; without, that term is left out.
    elements : planner.options.ElementOptions
        The real car's elements of `predictions`, for the finer simulation of the
        discretization term; default the model's. The random and fit terms come from
        the screening of the shocks (the stops' share of them is left out).

    Returns
    -------
    Uncertainty

    Raises
    ------
    ValueError
        If the model has no FRF (a known physical model has no estimation
        error) or `n_draws` is below 2.
    """
    draws = as_options(draws, UncertaintyOptions, "draws", "prediction_uncertainty")
    loop = as_options(loop, LoopOptions, "loop", "prediction_uncertainty")
    n_draws, seed, quantiles = draws.n_draws, draws.seed, draws.quantiles
    random_scale, band_hz = draws.random_scale, loop.band_hz
    frf = getattr(model, "frf", None)
    if frf is None:
        raise ValueError("prediction_uncertainty needs an identified model with its FRF "
                         "(model.frf); a known model has no estimation error")
    if n_draws < 2:
        raise ValueError(f"n_draws must be at least 2, got {n_draws}")
    models = resolve_setups(setups, library)
    drive = prepare_drive(drive, getattr(model, "fs_hz", None))
    rig_inputs = tuple(n for n in frf.input_names if not n.startswith("dF_"))
    check_drive_inputs(drive, rig_inputs, model=getattr(model, "name", None))
    bands = drive_bands(drive, band_hz=band_hz, n_bands=n_bands)
    fb = bands.f_hz
    outs, cbar = frf.output_names, frf.cbar_n_s_m

    def screen(H):
        return screen_response(H, outs, cbar, bands, models)[1]

    # (p, 11, nb): a 4-post model's FRF (8 inputs) gets zero aero columns
    Hc = embed_inputs(interpolate(frf.f_hz, frf.H, fb), frf.input_names)
    fitted = hasattr(model, "loop_plant")
    if fitted:
        # the draws perturb the model's own response (the nominal is the model's screening);
        # the fit term compares it with the FRF it was fitted to, where it was fitted: outside
        # the fit band the FRF holds residual-fit extrapolations (a track drive's large road
        # power below 0.5 Hz met them: a 30 % "fit error" on a model within 0.05 %)
        order = [list(model.loop_plant().output_names).index(o) for o in outs]
        H_full = model.loop_plant(reduce_rtol=None).frequency_response(fb)[order]
        H_red = model.loop_plant().frequency_response(fb)[order]
        lo_f, hi_f = (model.settings or {}).get("band_hz", (0.5, 20.0))
        inside = (fb >= lo_f) & (fb <= hi_f)
        H_nom = H_full
    else:
        H_nom = Hc
    names, base, _, _ = screen_response(H_nom, outs, cbar, bands, models)
    cv = cross_validation_deviations(frf, fb) if random_scale is None else None
    if cv is not None:
        scale = 1.0  # the draws at the stated error, then scaled to the measured one
    else:
        if random_scale is None:
            log.info("%s has no cross-validation (a model file from before it): the random "
                     "part's size from the formula fitted to a family of cars",
                     getattr(model, "name", "the model"))
        scale = random_error_scale(frf) if random_scale is None else float(random_scale)
        if not np.isfinite(scale) or scale < 0:
            raise ValueError(f"random_scale must be a finite number >= 0, got {random_scale!r}")
    rel = np.minimum(scale * embed_inputs(
        interpolate(frf.f_hz, frf_relative_error(frf), fb), frf.input_names),
        MAX_RELATIVE_ERROR)
    norm = 1.0 / np.sqrt(1.0 + rel**2)  # zero-mean in power
    Lf = _correlated_factor(error_correlation(frf, fb))
    rng = np.random.default_rng(seed)
    draws = np.empty((n_draws, len(models), len(names)))
    with np.errstate(divide="ignore", invalid="ignore"):
        for d in range(n_draws):
            z = (Lf @ rng.standard_normal((fb.size, rel[..., 0].size))
                 + 1j * (Lf @ rng.standard_normal((fb.size, rel[..., 0].size)))) / np.sqrt(2)
            e = rel * np.moveaxis(z, 0, -1).reshape(rel.shape)
            draws[d] = screen(H_nom * (1 + e) * norm) / base
        if cv is not None:
            cv_dev = np.stack([screen(H_nom * (1 + e)) / base - 1 for e in cv])
            # one realization per metric can fall low by chance: not below the ratio the
            # FRF's lines measure (thousands of them), the same error at the line level
            line = float(((frf.settings or {}).get("cross_validation") or {})
                         .get("ratio_all", 0.0) or 0.0)
            kappa = CV_LENGTH_FACTOR * np.nanmax([cross_validated_scale(cv_dev, draws - 1),
                                                  line])
            if np.isfinite(kappa):
                draws = 1 + kappa * (draws - 1)
                scale = kappa
    index = pd.Index([s.name for s in setups], name="setup")

    def frame(a):
        return pd.DataFrame(a, index=index, columns=names)

    lo_r = np.nanquantile(draws, quantiles[0], axis=0)
    hi_r = np.nanquantile(draws, quantiles[1], axis=0)
    components = {"random_lo": frame(lo_r), "random_hi": frame(hi_r)}
    if fitted:
        measured = screen(np.where(inside, Hc, H_full))
        red = screen(H_red)
        with np.errstate(divide="ignore", invalid="ignore"):
            components["fit"] = frame(base / measured - 1)
            components["reduction"] = frame(red / base - 1)
    bias = noise_bias_deviation(frf, fb)
    if bias is not None:
        # the estimate's bias from the noise on its dF inputs (errors in variables: the
        # same in every time block, so not in the cross-validation): the model against
        # the same model with the bias taken out, H (1 - b) ~ H / (1 + b)
        with np.errstate(divide="ignore", invalid="ignore"):
            components["input_noise"] = frame(base / screen(H_nom * (1 - bias)) - 1)
    if predictions is not None:
        finer = predict_setups(model, drive, setups, library,
                               loop=replace(loop, oversample=2 * loop.oversample),
                               elements=elements, check_coverage=False)
        p1 = predictions.table.loc[index, names].to_numpy()
        p2 = finer.table.loc[index, names].to_numpy()
        with np.errstate(divide="ignore", invalid="ignore"):
            components["discretization"] = frame(_RICHARDSON_H3 * (p1 - p2) / p1)
    lo, hi = combine_terms(lo_r, hi_r, {k: components[k].to_numpy() for k in SYSTEMATIC_TERMS
                                        if k in components and k not in SIGNED_TERMS},
                           signed={k: components[k].to_numpy() for k in SIGNED_TERMS
                                   if k in components})
    light = light_modes(model, band_hz=band_hz)
    if len(light):
        log.warning("%s has lightly damped modes in the metric band (%s): its FRF is biased "
                    "there and the intervals do not carry that error (they covered 61 %% on "
                    "such a car); add damping to the test car's model or do not trust them",
                    getattr(model, "name", "the model"),
                    ", ".join(f"{r.f_hz:.1f} Hz, zeta {r.zeta:.3f}" for r in light.itertuples()))
    settings = {"n_draws": n_draws, "seed": seed, "quantiles": tuple(quantiles),
                "random_scale": scale,
                "random_error": ("cross-validation" if cv is not None else
                                 "formula" if random_scale is None else "given"),
                "light_modes": [{"f_hz": round(r.f_hz, 2), "zeta": round(r.zeta, 4),
                                 "pairs": r.pairs} for r in light.itertuples()],
                "n_averages": frf.n_averages,
                "smooth_width_hz": (frf.settings.get("conditioning") or {}).get("smooth_width_hz"),
                "terms": ["random"] + [k for k in SYSTEMATIC_TERMS if k in components],
                "oversample": loop.oversample if predictions is not None else None}
    return Uncertainty(ratio_lo=frame(lo), ratio_hi=frame(hi), draws=draws, metric_names=names,
                       components=components, settings=settings)


def light_modes(model, *, band_hz=(1.0, 20.0), max_zeta=LIGHT_DAMPING_ZETA,
                min_peak=LIGHT_MODE_MIN_PEAK, min_share=LIGHT_MODE_MIN_SHARE):
    """Lightly damped modes of an identified model in a band: where its intervals fail.

    A car with a nearly undamped mode in the metric band (a chassis twist with no
    tire damping, say) is identified with a large error that no term of the
    intervals carries: its FRF is biased around the resonance (too few lines
    across the peak for the estimator and the smoothing), and the intervals,
    built from the FRF's variance and the fit to that same FRF, do not see the
    bias (issue 24: 61 % coverage on such a car, tire forces 13-17 % off). This
    finds such modes in the fitted model so that the intervals can say so.

    Parameters
    ----------
    model : ident.identify.model.VehicleModel
        Any object without ``poles`` (a known model) has none.
    band_hz : (float, float)
        The metric band [Hz].
    max_zeta : float
        Damping ratio at or below which a mode is lightly damped.
    min_peak : float
        A pole counts for a pair where ``|r| / (zeta w_n)`` is at least this
        fraction of the pair's largest response in the band.
    min_share : float
        Share of the fitted pairs (and at least 3) that must have such a pole
        near the same frequency.

    Returns
    -------
    pandas.DataFrame
        One row per mode: ``f_hz`` (median natural frequency of its poles [Hz]),
        ``zeta`` (median damping ratio), ``pairs`` (number of pairs with it);
        empty when there is none.
    """
    empty = pd.DataFrame({"f_hz": [], "zeta": [], "pairs": []})
    poles = getattr(model, "poles", None)
    if poles is None or getattr(model, "n_poles", None) is None:
        return empty
    valid = np.arange(poles.shape[-1]) < model.n_poles[..., None]
    out, inp, _ = np.nonzero(valid)
    p, r = poles[valid], model.residues[valid]
    with np.errstate(divide="ignore", invalid="ignore"):
        wn = np.abs(p)
        zeta = -p.real / wn
        f = wn / (2 * np.pi)
        grid = np.geomspace(band_hz[0], band_hz[1], 200)
        top = np.abs(model.frequency_response(grid)).max(axis=-1)  # (n_out, n_in)
        peak = np.abs(r) / (zeta * wn) / top[out, inp]
    sel = ((p.imag != 0) & (f >= band_hz[0]) & (f <= band_hz[1]) & (zeta <= max_zeta)
           & (peak >= min_peak))
    if not sel.any():
        return empty
    fitted = int(np.count_nonzero(np.asarray(model.order) > 0))
    need = max(3, min_share * fitted)
    order = np.argsort(f[sel])
    fs, zs, pair = f[sel][order], zeta[sel][order], (out[sel] * poles.shape[1] + inp[sel])[order]
    rows = []
    for grp in np.split(np.arange(fs.size), np.nonzero(np.diff(fs) > LIGHT_MODE_CLUSTER_HZ)[0] + 1):
        n = np.unique(pair[grp]).size
        if n >= need:
            rows.append({"f_hz": float(np.median(fs[grp])), "zeta": float(np.median(zs[grp])),
                         "pairs": int(n)})
    return pd.DataFrame(rows) if rows else empty


def combine_terms(random_lo, random_hi, systematic, *, random_factor=1.0, signed=None):
    """An interval's bounds from its random part and its systematic terms.

    The random part's bounds (ratios to the prediction) are first stretched
    about 1 by `random_factor`; each systematic term then widens both sides,
    in quadrature with the random half-widths: the upper bound
    ``hi_r + sqrt(u^2 + sum d^2) - u`` with ``u = max(hi_r - 1, 0)``, the lower
    likewise (the terms' signs are estimates, not certainties).

    Parameters
    ----------
    random_lo, random_hi : array_like, shape (...)
        The random part's bounds as ratios to the prediction (``random_lo <= 1 <=
        random_hi`` usually).
    systematic : mapping of str to array_like, shape (...)
        Signed relative systematic errors (NaN counts as 0).
    random_factor : float
        Stretch of the random part about 1: bounds ``1 - f (1 - lo)`` and
        ``1 + f (hi - 1)``. For the small relative errors of a metric this is
        the random part at ``f`` times the FRF's errors (a draw's metric is
        linear in its FRF error to first order); :mod:`studies.interval_calibration`
        fits the calibrated scale this way.
    signed : mapping of str to array_like, shape (...), optional
        Measured biases ``d`` (the prediction over the truth, less 1; NaN counts as 0):
        the interval is widened toward the truth they point to, linearly, after the
        quadrature: ``lo - max(d, 0)`` and ``hi - min(d, 0)`` (it holds the interval
        and the same interval with the biases taken out).

    Returns
    -------
    lo, hi : ndarray, shape (...)
        The interval's bounds as ratios to the prediction.

    Examples
    --------
    >>> lo, hi = combine_terms([0.99], [1.01], {"fit": [0.0075]})
    >>> [round(float(lo[0]), 6), round(float(hi[0]), 6)]
    [0.9875, 1.0125]
    """
    lo_r, hi_r = np.asarray(random_lo, dtype=float), np.asarray(random_hi, dtype=float)
    if random_factor != 1.0:  # (bounds kept exact at 1)
        lo_r, hi_r = 1.0 - random_factor * (1.0 - lo_r), 1.0 + random_factor * (hi_r - 1.0)
    sys2 = sum((np.nan_to_num(np.asarray(d, dtype=float)) ** 2 for d in systematic.values()),
               np.zeros(np.broadcast(lo_r, hi_r).shape))
    up, down = np.maximum(hi_r - 1.0, 0.0), np.maximum(1.0 - lo_r, 0.0)
    lo, hi = lo_r - (np.sqrt(down**2 + sys2) - down), hi_r + np.sqrt(up**2 + sys2) - up
    if signed:
        bias = sum((np.nan_to_num(np.asarray(d, dtype=float)) for d in signed.values()),
                   np.zeros(lo.shape))
        lo, hi = lo - np.maximum(bias, 0.0), hi - np.minimum(bias, 0.0)
    return lo, hi


@dataclass(frozen=True, eq=False)
class ScoreErrors:
    """The objective's score of every setup: nominal, per draw, and its systematic shifts.

    What :func:`score_intervals` and :func:`difference_interval` read: any error model that
    gives per-draw scores (draws of the same error shared by all setups, so that their
    per-draw differences carry what the setups share) and signed systematic shifts per
    setup can stand in for the Monte Carlo draws of :func:`prediction_uncertainty`.

    Attributes
    ----------
    nominal : pandas.Series
        The score of every setup (index: setup names), lower is better.
    draws : pandas.DataFrame
        Per setup (rows, as `nominal`) the score in every draw (columns), shape
        (n_setups, n_draws).
    systematic : pandas.DataFrame
        Per setup (rows) and systematic term (columns, e.g. :data:`SYSTEMATIC_TERMS`) the
        signed shift of its score the term estimates (0 where a term is unknown).
    quantiles : (float, float)
        The interval's quantiles (default a 95 % interval).
    feasible : pandas.Series
        Per setup, whether it meets the objective's limits (nominally).
    baseline : str
        The setup the scores are ratios to.
    """

    nominal: pd.Series
    draws: pd.DataFrame
    systematic: pd.DataFrame
    quantiles: tuple = (0.025, 0.975)
    feasible: pd.Series = None
    baseline: str = None


def score_errors(scores, uncertainty, objective, *, baseline=None):
    """Score every setup in every draw of `uncertainty` and by its systematic terms.

    Each draw's metric ratios (:attr:`Uncertainty.draws`) scale the given
    (time-domain) metrics of every setup, the baseline's included, and the
    objective scores the draw's table; each systematic term ``d`` of
    :attr:`Uncertainty.components` (signed relative errors per setup and metric)
    scales them by ``1 + d`` (NaN: 0) and the shift of each setup's score from
    the nominal one is that term's systematic score error.

    Parameters
    ----------
    scores : pandas.DataFrame
        Predicted metrics (SI) with the setups as index, including the baseline;
        every setup must be one of `uncertainty`'s.
    uncertainty : Uncertainty
    objective : planner.objective.Objective
    baseline : str, optional
        As :func:`planner.objective.score_setups`.

    Returns
    -------
    ScoreErrors
        Rows in the order of `scores`.

    Raises
    ------
    KeyError
        If a setup of `scores` has no draws in `uncertainty`.
    """
    nominal = score_setups(scores, objective, baseline=baseline)
    names = [m for m in uncertainty.metric_names if m in scores.columns]
    cols = [uncertainty.metric_names.index(m) for m in names]
    missing = [s for s in scores.index if s not in uncertainty.ratio_lo.index]
    if missing:
        raise KeyError(f"score_errors: setups {missing[:5]} have no draws in the uncertainty; "
                       "compute prediction_uncertainty for the same setups")
    idx = [uncertainty.ratio_lo.index.get_loc(s) for s in scores.index]
    values = scores[names].to_numpy(dtype=float)
    draw_scores = []
    for d in range(uncertainty.draws.shape[0]):
        t = scores.copy()
        t[names] = values * uncertainty.draws[d][idx][:, cols]
        draw_scores.append(score_setups(t, objective, baseline=baseline).table["score"]
                           .to_numpy())
    draws = pd.DataFrame(np.column_stack(draw_scores) if draw_scores else
                         np.empty((len(scores), 0)), index=scores.index)
    shifts = {}
    for k in SYSTEMATIC_TERMS:
        comp = uncertainty.components.get(k)
        if comp is None:
            continue
        d = np.nan_to_num(comp.reindex(index=scores.index, columns=names).to_numpy(dtype=float))
        t = scores.copy()
        t[names] = values * (1.0 + d)
        shifts[k] = (score_setups(t, objective, baseline=baseline).table["score"]
                     - nominal.table["score"]).to_numpy()
    quantiles = tuple((uncertainty.settings or {}).get("quantiles", (0.025, 0.975)))
    table = nominal.table
    return ScoreErrors(nominal=table["score"].rename("score"), draws=draws,
                       systematic=pd.DataFrame(shifts, index=scores.index),
                       quantiles=quantiles,
                       feasible=table["feasible"].astype(bool) if "feasible" in table
                       else pd.Series(True, index=scores.index),
                       baseline=nominal.baseline)


def difference_interval(errors, a, b):
    """The interval of the score of `a` minus that of `b` (`b`: None, the score itself).

    The random part is the quantiles of the per-draw differences (the error the two
    setups share cancels); the systematic terms widen it, each as the difference of the
    two setups' signed shifts (alike errors cancel), added in quadrature to the random
    half-widths as :func:`combine_terms` does.

    Parameters
    ----------
    errors : ScoreErrors
    a : str or sequence of str
        Setups (rows of `errors`).
    b : str or None
        The setup subtracted; None: the interval of `a`'s score.

    Returns
    -------
    lo, hi : ndarray, shape (len(a),) (floats for one name)
        The bounds; NaN where a score is not finite.

    Examples
    --------
    >>> e = ScoreErrors(nominal=pd.Series([1.0, 1.1], index=["a", "b"]),
    ...                 draws=pd.DataFrame([[0.9, 1.0, 1.1], [1.0, 1.1, 1.2]], index=["a", "b"]),
    ...                 systematic=pd.DataFrame({"fit": [0.01, 0.01]}, index=["a", "b"]),
    ...                 quantiles=(0.0, 1.0))
    >>> [round(float(v), 12) for v in difference_interval(e, "b", "a")]
    [0.1, 0.1]
    """
    one = isinstance(a, str)
    names = [a] if one else list(a)
    nom = errors.nominal.loc[names].to_numpy(dtype=float)
    D = errors.draws.loc[names].to_numpy(dtype=float)
    sysm = errors.systematic.loc[names].to_numpy(dtype=float)
    if b is not None:
        nom = nom - float(errors.nominal.loc[b])
        D = D - errors.draws.loc[[b]].to_numpy(dtype=float)
        sysm = sysm - errors.systematic.loc[[b]].to_numpy(dtype=float)
    q0, q1 = errors.quantiles
    with np.errstate(invalid="ignore"):
        if D.shape[1]:
            lo_r, hi_r = np.nanquantile(D, q0, axis=1), np.nanquantile(D, q1, axis=1)
        else:
            lo_r, hi_r = nom.copy(), nom.copy()
        # combine_terms works on ratios about 1: the bounds as offsets from the nominal
        cols = list(errors.systematic.columns)
        lo, hi = combine_terms(1.0 + lo_r - nom, 1.0 + hi_r - nom,
                               {k: sysm[:, j] for j, k in enumerate(cols)
                                if k not in SIGNED_TERMS},
                               signed={k: sysm[:, j] for j, k in enumerate(cols)
                                       if k in SIGNED_TERMS})
    lo, hi = lo - 1.0 + nom, hi - 1.0 + nom
    bad = ~np.isfinite(nom)
    lo[bad], hi[bad] = np.nan, np.nan
    return (float(lo[0]), float(hi[0])) if one else (lo, hi)


def _verdict(lo, hi, *, same, feasible, names):
    """better / tied / worse of a difference interval (``same``: the reference's word)."""
    if same:
        return names[0]
    if not feasible:
        return "infeasible"
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "tied"
    if lo > 0:
        return "worse"
    if hi < 0:
        return "better"
    return "tied"


def score_intervals(errors, *, best=None, baseline=None):
    """The intervals of every setup's score and of its differences from the best and the
    baseline, and its verdicts.

    Parameters
    ----------
    errors : ScoreErrors
        From :func:`score_errors` (or another error model).
    best : str, optional
        The setup the differences are from; default the best feasible setup by nominal
        score (the lowest score when none is feasible).
    baseline : str, optional
        Default ``errors.baseline``; without one the baseline's columns are NaN.

    Returns
    -------
    pandas.DataFrame
        Index as `errors`, columns :data:`SCORE_INTERVAL_COLUMNS`: ``score_lo``,
        ``score_hi`` (the score's interval), ``diff_best_lo``, ``diff_best_hi`` (of the
        score minus the best's), ``diff_baseline_lo``, ``diff_baseline_hi`` (minus the
        baseline's), ``verdict`` (``best`` for the best, ``infeasible`` for a setup outside
        the limits, ``tied`` where the difference's interval contains 0, ``worse`` above
        it, ``better`` below it), ``verdict_baseline`` (``baseline``, ``infeasible``,
        ``better``, ``tied``, ``worse`` likewise against the baseline).

    Examples
    --------
    >>> e = ScoreErrors(nominal=pd.Series([0.9, 0.91, 1.0], index=["a", "b", "base"]),
    ...                 draws=pd.DataFrame([[0.88, 0.92], [0.9, 0.92], [1.0, 1.0]],
    ...                                    index=["a", "b", "base"]),
    ...                 systematic=pd.DataFrame(index=["a", "b", "base"]),
    ...                 quantiles=(0.0, 1.0), baseline="base")
    >>> score_intervals(e)[["verdict", "verdict_baseline"]].to_numpy().tolist()
    [['best', 'better'], ['tied', 'better'], ['worse', 'baseline']]
    """
    names = list(errors.nominal.index)
    feasible = (errors.feasible if errors.feasible is not None
                else pd.Series(True, index=names)).reindex(names).fillna(False).astype(bool)
    if best is None:
        pool = errors.nominal[feasible] if feasible.any() else errors.nominal
        best = pool.astype(float).idxmin()
    baseline = errors.baseline if baseline is None else baseline
    out = pd.DataFrame(index=errors.nominal.index)
    out["score_lo"], out["score_hi"] = difference_interval(errors, names, None)
    out["diff_best_lo"], out["diff_best_hi"] = difference_interval(errors, names, best)
    if baseline is not None:
        out["diff_baseline_lo"], out["diff_baseline_hi"] = difference_interval(
            errors, names, baseline)
    else:
        out["diff_baseline_lo"] = out["diff_baseline_hi"] = np.nan
    out["verdict"] = [
        _verdict(lo, hi, same=n == best, feasible=feasible[n], names=("best",))
        for n, lo, hi in zip(names, out["diff_best_lo"], out["diff_best_hi"])]
    out["verdict_baseline"] = [
        "" if baseline is None else
        _verdict(lo, hi, same=n == baseline, feasible=feasible[n], names=("baseline",))
        for n, lo, hi in zip(names, out["diff_baseline_lo"], out["diff_baseline_hi"])]
    return out


def unresolved_pairs(scores, uncertainty, objective, *, baseline=None, max_flip=None, top=None,
                     errors=None):
    """Setup pairs whose objective order the model does not resolve.

    By default a pair is unresolved where the interval of its score difference
    (:func:`difference_interval`: the per-draw differences and the difference of
    the systematic shifts) contains 0. With `max_flip`, the draws' order alone
    decides: each draw's metric ratios scale the given (time-domain) metrics,
    the objective is re-scored per draw, and a pair whose order flips in more
    than `max_flip` of the draws is unresolved (no systematic terms).

    Parameters
    ----------
    scores : pandas.DataFrame
        Predicted metrics (SI) with the setups as index, including the baseline.
    uncertainty : Uncertainty
    objective : planner.objective.Objective
    baseline : str, optional
    max_flip : float, optional
        Share of the draws (e.g. 0.05); default None: the difference intervals decide.
    top : int, optional
        Only pairs among the `top` best setups.
    errors : ScoreErrors, optional
        :func:`score_errors` of the same arguments, if already computed.

    Returns
    -------
    dict
        Setup name -> list of setup names it is not resolved from.
    """
    if errors is None:
        errors = score_errors(scores, uncertainty, objective, baseline=baseline)
    nominal = score_setups(scores, objective, baseline=baseline).table
    order = nominal.sort_values("rank").index.tolist()
    if top is not None:
        order = order[:top]
    S = errors.draws.loc[order].to_numpy()  # (n_top, n_draws)
    nom = errors.nominal.loc[order].to_numpy(dtype=float)
    out = {s: [] for s in order}
    for a in range(len(order)):
        if max_flip is None and a + 1 < len(order):
            lo, hi = difference_interval(errors, order[a + 1:], order[a])
        for j, b in enumerate(range(a + 1, len(order))):
            if not (np.isfinite(nom[a]) and np.isfinite(nom[b])) or nom[a] == nom[b]:
                continue
            if max_flip is None:
                unresolved = lo[j] <= 0.0 <= hi[j]
            else:
                unresolved = np.mean(np.sign(S[a] - S[b]) != np.sign(nom[a] - nom[b])) > max_flip
            if unresolved:
                out[order[a]].append(order[b])
                out[order[b]].append(order[a])
    return out
