"""Tests of planner.uncertainty: the Bendat-Piersol random error, the FRF plant, Monte Carlo
intervals on an FRF of known coherence, and unresolved setup pairs."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from ident.identify.frf import MODEL_INPUTS, Frf
from ident.identify.model import VehicleModel
from planner.objective import Objective
from planner.screen import screen_setups
from planner.setups import enumerate_setups
from planner.uncertainty import (
    CV_LENGTH_FACTOR,
    LIGHT_DAMPING_ZETA,
    MAX_RELATIVE_ERROR,
    RANDOM_ERROR_SCALE,
    SCORE_INTERVAL_COLUMNS,
    FrfPlant,
    ScoreErrors,
    Uncertainty,
    combine_terms,
    cross_validated_scale,
    cross_validation_deviations,
    difference_interval,
    frf_relative_error,
    light_modes,
    noise_bias_deviation,
    prediction_uncertainty,
    random_error_scale,
    score_errors,
    score_intervals,
    unresolved_pairs,
)
from planner.options import LoopOptions, UncertaintyOptions

N_AVERAGES = 51  # the paper's 5 runs of 800 s in Welch blocks: 51 averages, 11 inputs
# For small errors the draws are a linear function of the perturbation, which scales with the
# relative error: interval widths scale with it. Second-order terms (|e|^2 against e) leave a
# spread of the width ratio over setups and metrics that grows with the error (1.5 x the
# complex standard error per line):
# coherence 0.99 -> 0.9 (2.4 -> 7.9 % a line): measured 1.5 % worst, 0.37 % median;
# coherence 0.9 -> 0.5 (7.9 -> 24 % a line): measured 5.1 % worst, 1.3 % median.
RTOL_WIDTH_SCALING_SMALL = 0.025
RTOL_WIDTH_SCALING_LARGE = 0.075
# Linear interpolation of a response that is itself linear in frequency: round-off only.
RTOL_EXACT = 1e-12
# The FRF plant samples the known car's response every 0.05 Hz and interpolates linearly
# at the band centres: the curvature near the 1.5 Hz body and 15 Hz wheel-hop resonances
# moves the screened metrics by < 0.1 % (measured 0.034 %).
RTOL_FRF_PLANT = 0.005
# mean of 400 squared ratios that spread by ~3 %: known to ~0.3 %
ATOL_MEAN_POWER = 0.006


def _frf(plant, g2, *, n_averages=N_AVERAGES, df=0.05, replaced=None):
    """An Frf holding `plant`'s exact response on a 0-50 Hz grid, with partial coherence `g2`
    (a number or an array broadcast to (n_out, 11, n_f))."""
    f = np.arange(0.0, 50.0 + df / 2, df)
    H = plant.frequency_response(f)
    pc = np.broadcast_to(np.asarray(g2, dtype=float), H.shape).copy()
    return Frf(f_hz=f, H=H, input_names=MODEL_INPUTS, output_names=plant.output_names,
               multiple_coherence=np.ones((H.shape[0], f.size)), partial_coherence=pc,
               input_condition=np.ones(f.size), independent_fraction=np.ones((11, f.size)),
               flagged=np.zeros((11, f.size), dtype=bool), n_averages=n_averages,
               cbar_n_s_m=plant.cbar_n_s_m, fs_hz=100.0,
               settings={"conditioning": {"smooth_width_hz": 0.6}}, replaced=replaced)


def _coherence_frf(g2, n_averages=N_AVERAGES, replaced=None):
    """A minimal stand-in for an unsmoothed Frf: just what frf_relative_error reads (1 output,
    11 inputs, H = 2)."""
    pc = np.asarray(g2, dtype=float).reshape(1, 1, -1) * np.ones((1, 11, 1))
    return SimpleNamespace(partial_coherence=pc, n_averages=n_averages, H=np.full(pc.shape, 2.0),
                           input_names=MODEL_INPUTS, replaced=replaced, settings={}, sigma=None,
                           f_hz=np.arange(pc.shape[-1], dtype=float))


@pytest.fixture(scope="module")
def known_plant(paper_model):
    """The paper car's loop plant (around its nominal damping)."""
    return paper_model.loop_plant()


@pytest.fixture(scope="module")
def few_setups(demo_library, baseline_setup):
    """The baseline and 6 symmetric setups spread over the crate."""
    return [baseline_setup] + list(enumerate_setups(demo_library)[::20])


# ---------------------------------------------------------------- random error


def test_relative_error_known_answers():
    """``sigma / |H|`` of the (here unsmoothed) estimate: ``sqrt((1 - g2) / (g2 nu))`` with
    nu = 51 averages - 11 inputs = 40, by hand: g2 = 0.5 -> sqrt(1/40); 0.9 -> sqrt(0.1/36);
    0.99 -> sqrt(0.01/39.6); 0.2 -> sqrt(0.8/8); perfect coherence -> 0; none -> the cap (1)."""
    eps = frf_relative_error(_coherence_frf([0.5, 0.9, 0.99, 0.2, 1.0, 0.0]))
    expected = [np.sqrt(1 / 40), np.sqrt(0.1 / 36), np.sqrt(0.01 / 39.6), np.sqrt(0.1), 0.0, 1.0]
    assert eps.shape == (1, 11, 6)
    for k in range(11):
        assert_allclose(eps[0, k], expected, rtol=RTOL_EXACT, atol=0)
    assert MAX_RELATIVE_ERROR == 1.0


def test_relative_error_few_averages_and_cap():
    """Fewer averages than inputs count as one degree of freedom: g2 = 0.5 -> 1 (the cap);
    g2 = 0.9 -> sqrt(0.1 / 0.9) = 0.333; more averages, less error, as 1 / sqrt(nu)."""
    eps = frf_relative_error(_coherence_frf([0.5, 0.3, 0.9], n_averages=5))
    assert_allclose(eps[0, 0], [1.0, 1.0, 1 / 3], rtol=RTOL_EXACT)
    e40 = frf_relative_error(_coherence_frf([0.9], n_averages=51))[0, 0, 0]
    e160 = frf_relative_error(_coherence_frf([0.9], n_averages=171))[0, 0, 0]
    assert e160 == pytest.approx(e40 / 2, rel=RTOL_EXACT)


def test_relative_error_falls_with_coherence():
    """The error falls strictly as the coherence rises (below the cap)."""
    g2 = np.linspace(0.05, 1.0, 40)
    eps = frf_relative_error(_coherence_frf(g2))[0, 0]
    assert np.all(np.diff(eps[eps < MAX_RELATIVE_ERROR]) < 0)


def test_relative_error_of_a_conditioned_frf_is_its_sigma():
    """A conditioned FRF carries its standard error (``Frf.sigma``): that is what counts."""
    frf = _coherence_frf([0.5, 0.9])
    frf.sigma = np.full((1, 11, 2), 0.02)
    assert_allclose(frf_relative_error(frf), 0.02 / np.abs(frf.H), rtol=RTOL_EXACT)


def test_replaced_lines_take_the_median_of_measured_lines():
    """Lines replaced in conditioning get the median error of the pair's measured lines; a
    pair replaced everywhere keeps the median of its own lines."""
    g2 = np.array([0.5, 0.9, 0.99, 0.1, 0.2])
    replaced = np.zeros((1, 11, 5), dtype=bool)
    replaced[0, 0, 3:] = True  # input 0: the last two lines replaced
    replaced[0, 1, :] = True  # input 1: every line replaced
    eps = frf_relative_error(_coherence_frf(g2, replaced=replaced))
    plain = frf_relative_error(_coherence_frf(g2))
    measured = plain[0, 0, :3]
    assert_allclose(eps[0, 0], np.r_[measured, np.median(measured), np.median(measured)],
                    rtol=RTOL_EXACT)
    assert eps[0, 0, 3] == pytest.approx(np.sqrt(0.1 / 36), rel=RTOL_EXACT)  # the 0.9 line
    assert_allclose(eps[0, 1], np.median(plain[0, 1]), rtol=RTOL_EXACT)
    assert_array_equal(eps[0, 2:], plain[0, 2:])


# ---------------------------------------------------------------- FRF plant


def test_frf_plant_interpolates_linearly():
    """A response linear in frequency is reproduced exactly between and beyond the grid
    lines (the end segments extend); the shock velocities are found by name."""
    from ident.data.channels import SHOCK_VELOCITIES

    rng = np.random.default_rng(4)
    names = ("ride_height_LF",) + SHOCK_VELOCITIES
    a = rng.standard_normal((5, 11)) + 1j * rng.standard_normal((5, 11))
    b = rng.standard_normal((5, 11)) + 1j * rng.standard_normal((5, 11))
    grid = np.array([0.0, 0.7, 1.0, 3.5, 10.0])
    H = a[..., None] + b[..., None] * grid
    plant = FrfPlant(grid, H, names, np.full(4, 3000.0), name="lin")
    f = np.array([0.0, 0.3, 0.7, 2.2, 9.99, 10.0, 12.0])
    assert_allclose(plant.frequency_response(f), a[..., None] + b[..., None] * f,
                    rtol=RTOL_EXACT)
    assert plant.velocity_idx.tolist() == [1, 2, 3, 4]
    assert plant.cbar_n_s_m.dtype == float and plant.name == "lin"
    with pytest.raises(ValueError):
        FrfPlant(grid, H, names[:-1] + ("tire_force_RR",), np.full(4, 3000.0))


def test_screening_an_frf_plant_matches_the_state_space_plant(known_plant, track_drive,
                                                              demo_library, few_setups):
    """The FRF plant of the known car screens like the car itself (the same model, sampled)."""
    frf = _frf(known_plant, 1.0)
    a = screen_setups(FrfPlant(frf.f_hz, frf.H, frf.output_names, frf.cbar_n_s_m), track_drive,
                      few_setups, demo_library)
    b = screen_setups(known_plant, track_drive, few_setups, demo_library)
    names = a.metric_names
    assert names == b.metric_names
    assert_allclose(a.table[names].to_numpy(float), b.table[names].to_numpy(float),
                    rtol=RTOL_FRF_PLANT)


# ---------------------------------------------------------------- Monte Carlo intervals


def _unc(plant, g2, drive, setups, library, **kw):
    return prediction_uncertainty(SimpleNamespace(frf=_frf(plant, g2)), drive, setups, library,
                                  draws=UncertaintyOptions(**{"n_draws": 20, "seed": 1, **kw}))


def test_perfect_coherence_gives_no_spread(known_plant, track_drive, demo_library,
                                           few_setups):
    """Coherence 1 is no random error: every draw reproduces the nominal prediction."""
    u = _unc(known_plant, 1.0, track_drive, few_setups, demo_library, n_draws=3)
    assert u.draws.shape == (3, len(few_setups), 14)
    assert np.all(u.draws == 1.0)
    assert np.all(u.ratio_lo.to_numpy() == 1.0) and np.all(u.ratio_hi.to_numpy() == 1.0)


def test_lower_coherence_widens_intervals_as_the_random_error(known_plant, track_drive,
                                                              demo_library, few_setups):
    """Same draws (seed), lower coherence: every interval is wider, by the ratio of the
    relative errors, eps(0.9) / eps(0.99) = sqrt(0.1 / 0.9 * 0.99 / 0.01) = 3.3166
    and eps(0.5) / eps(0.9) = 3."""
    w = {}
    for g2 in (0.99, 0.9, 0.5):
        u = _unc(known_plant, g2, track_drive, few_setups, demo_library)
        w[g2] = (u.ratio_hi - u.ratio_lo).to_numpy()
        # the intervals contain the point prediction
        assert np.all(u.ratio_lo.to_numpy() < 1.0) and np.all(u.ratio_hi.to_numpy() > 1.0)
    assert np.all(w[0.99] > 0)
    assert np.all(w[0.9] > w[0.99]) and np.all(w[0.5] > w[0.9])
    assert_allclose(w[0.9] / w[0.99], np.sqrt(0.1 / 0.9 * 0.99 / 0.01),
                    rtol=RTOL_WIDTH_SCALING_SMALL)
    assert_allclose(w[0.5] / w[0.9], 3.0, rtol=RTOL_WIDTH_SCALING_LARGE)


def test_intervals_seed_quantiles_and_settings(known_plant, track_drive, demo_library,
                                               few_setups):
    """Same seed, same draws; another seed, other draws; the bounds are the draws' quantiles;
    intervals() scales a table's metrics by them, matching rows by setup name."""
    u = _unc(known_plant, 0.9, track_drive, few_setups, demo_library, n_draws=6,
             quantiles=(0.0, 1.0))
    again = _unc(known_plant, 0.9, track_drive, few_setups, demo_library, n_draws=6,
                 quantiles=(0.0, 1.0))
    other = _unc(known_plant, 0.9, track_drive, few_setups, demo_library, n_draws=6, seed=2)
    assert_array_equal(u.draws, again.draws)
    assert not np.allclose(u.draws, other.draws)
    assert_array_equal(u.ratio_lo.to_numpy(), u.draws.min(axis=0))
    assert_array_equal(u.ratio_hi.to_numpy(), u.draws.max(axis=0))
    assert list(u.ratio_lo.index) == [s.name for s in few_setups]
    assert u.settings == {"n_draws": 6, "seed": 1, "quantiles": (0.0, 1.0),
                          "n_averages": N_AVERAGES, "smooth_width_hz": 0.6,
                          "terms": ["random"], "oversample": None,
                          "random_scale": RANDOM_ERROR_SCALE, "random_error": "formula",
                          "light_modes": []}
    assert set(u.components) == {"random_lo", "random_hi"}
    pred = screen_setups(known_plant, track_drive, few_setups, demo_library).table.iloc[::-1]
    t = u.intervals(pred)
    for m in u.metric_names:
        assert_allclose(t[f"{m}_lo"], pred[m] * u.ratio_lo.loc[pred.index, m], rtol=RTOL_EXACT)
        assert_allclose(t[f"{m}_hi"], pred[m] * u.ratio_hi.loc[pred.index, m], rtol=RTOL_EXACT)
    assert "tire_force_rms_LF_lo" not in pred.columns  # the input table is left alone


def test_draws_are_zero_mean_in_power(known_plant, track_drive, demo_library, baseline_setup):
    """``H (1 + e) / sqrt(1 + E|e|^2)``: a metric that is one pair's power (one rig input
    driven, the baseline's shocks at c_bar: no loop) keeps its mean over the draws, even where
    the error is large (the old ``H (1 + e)`` drifted up by the error's variance: +4 % where it
    hit its cap). Metrics of several correlated inputs lose a little of their cross-power."""
    from dataclasses import replace

    from ident.models.library import ShockLibrary
    from ident.models.shocks import LinearShock

    one = replace(track_drive, channels={c: (x if c == "wheelloader_LF" else np.zeros_like(x))
                                         for c, x in track_drive.channels.items()})
    lib = ShockLibrary([LinearShock("B20", float(known_plant.cbar_n_s_m[0]))])
    u = _unc(known_plant, 0.05, one, [baseline_setup], lib, n_draws=400)
    k = u.metric_names.index("tire_force_rms_LF")
    power = np.mean(u.draws[:, 0, k] ** 2)
    assert np.std(u.draws[:, 0, k]) > 0.02  # a large error: the old drift would be ~+2 %
    assert power == pytest.approx(1.0, abs=ATOL_MEAN_POWER)


def test_error_correlation_follows_the_smoothing(known_plant):
    """Errors of lines closer than the smoothing width are correlated, farther ones are not;
    the matrix is a correlation matrix."""
    from planner.uncertainty import error_correlation

    f = np.array([2.0, 2.05, 2.3, 3.0, 8.0])
    C = error_correlation(_frf(known_plant, 0.9), f)
    assert_allclose(np.diag(C), 1.0)
    assert_allclose(C, C.T)
    assert C[0, 1] > 0.9 and C[0, 3] < 0.1 and abs(C[0, 4]) < 1e-3
    assert np.linalg.eigvalsh(C).min() > -1e-9


def test_systematic_terms_of_an_identified_model(identified_model, track_drive, demo_library,
                                                 few_setups):
    """An identified model's intervals add its fit, loop-reduction and time-discretization
    errors to the random part, in quadrature; the discretization term is 8/7 of the change
    from oversample 2 to 4 (the quadratic hold's error falls as h^3)."""
    from planner.predict import predict_setups

    p2 = predict_setups(identified_model, track_drive, few_setups, demo_library,
                        loop=LoopOptions(oversample=2))
    p4 = predict_setups(identified_model, track_drive, few_setups, demo_library,
                        loop=LoopOptions(oversample=4))
    u = prediction_uncertainty(identified_model, track_drive, few_setups, demo_library,
                               draws=UncertaintyOptions(n_draws=8), loop=LoopOptions(oversample=2),
                               predictions=p2)
    names = u.metric_names
    assert u.settings["terms"] == ["random", "fit", "reduction", "discretization"]
    disc = 8 / 7 * (p2.table[names] - p4.table[names]) / p2.table[names]
    assert_allclose(u.components["discretization"].to_numpy(), disc.to_numpy(), rtol=1e-9)
    lo_r, hi_r = u.components["random_lo"].to_numpy(), u.components["random_hi"].to_numpy()
    sys2 = sum(u.components[k].to_numpy() ** 2 for k in ("fit", "reduction", "discretization"))
    up, down = np.maximum(hi_r - 1, 0), np.maximum(1 - lo_r, 0)
    assert_allclose(u.ratio_hi.to_numpy(), hi_r + np.sqrt(up**2 + sys2) - up, rtol=1e-12)
    assert_allclose(u.ratio_lo.to_numpy(), lo_r - np.sqrt(down**2 + sys2) + down, rtol=1e-12)
    assert np.all(u.ratio_lo.to_numpy() < 1) and np.all(u.ratio_hi.to_numpy() > 1)
    assert np.all(np.abs(u.components["reduction"].to_numpy()) < 1e-3)  # the reduction bound


def test_prediction_uncertainty_bad_inputs(paper_model, known_plant, track_drive, demo_library,
                                           few_setups):
    """A model without an FRF, and fewer than 2 draws, are refused (documented)."""
    with pytest.raises(ValueError, match="needs an identified model with its FRF"):
        prediction_uncertainty(paper_model, track_drive, few_setups, demo_library)
    with pytest.raises(ValueError, match="n_draws must be at least 2, got 1"):
        prediction_uncertainty(SimpleNamespace(frf=_frf(known_plant, 0.9)), track_drive,
                               few_setups, demo_library, draws=UncertaintyOptions(n_draws=1))


# ---------------------------------------------------------------- calibration and light modes
def test_combine_terms_stretches_the_random_part_and_adds_systematic_in_quadrature():
    lo_r, hi_r = np.array([0.99, 0.995, 1.001]), np.array([1.02, 1.004, 1.01])
    fit, disc = np.array([0.003, np.nan, -0.004]), np.array([0.0004, 0.0, 0.0003])
    lo, hi = combine_terms(lo_r, hi_r, {"fit": fit, "discretization": disc})
    sys2 = np.nan_to_num(fit) ** 2 + disc**2
    up, down = np.maximum(hi_r - 1, 0), np.maximum(1 - lo_r, 0)
    assert_allclose(hi, hi_r + np.sqrt(up**2 + sys2) - up, rtol=RTOL_EXACT)
    assert_allclose(lo, lo_r - np.sqrt(down**2 + sys2) + down, rtol=RTOL_EXACT)
    # without systematic terms the factor stretches the bounds about 1
    lo2, hi2 = combine_terms(lo_r, hi_r, {}, random_factor=2.0)
    assert_allclose(lo2, 1 - 2 * (1 - lo_r), rtol=RTOL_EXACT)
    assert_allclose(hi2, 1 + 2 * (hi_r - 1), rtol=RTOL_EXACT)
    # a factor of 0 leaves the systematic half-widths alone
    lo0, hi0 = combine_terms(lo_r, hi_r, {"fit": fit}, random_factor=0.0)
    assert_allclose(hi0 - 1, np.abs(np.nan_to_num(fit)), atol=1e-15)
    assert_allclose(1 - lo0, np.abs(np.nan_to_num(fit)), atol=1e-15)


def test_random_scale_option_and_its_default(known_plant, track_drive, demo_library,
                                             few_setups):
    """The random part's scale defaults to random_error_scale of the FRF and is recorded;
    twice the scale gives (for small errors) twice the random half-widths; a negative or
    non-finite scale is refused."""
    frf = _frf(known_plant, 0.99)
    model = SimpleNamespace(frf=frf)
    u = _unc(known_plant, 0.99, track_drive, few_setups, demo_library)
    assert u.settings["random_scale"] == random_error_scale(frf)
    assert u.settings["light_modes"] == []
    u1 = prediction_uncertainty(model, track_drive, few_setups, demo_library,
                                draws=UncertaintyOptions(n_draws=20, random_scale=1.0))
    u2 = prediction_uncertainty(model, track_drive, few_setups, demo_library,
                                draws=UncertaintyOptions(n_draws=20, random_scale=2.0))
    assert u1.settings["random_scale"] == 1.0
    w1 = (u1.ratio_hi - u1.ratio_lo).to_numpy()
    w2 = (u2.ratio_hi - u2.ratio_lo).to_numpy()
    assert_allclose(w2 / w1, 2.0, rtol=RTOL_WIDTH_SCALING_SMALL)
    for bad in (-1.0, np.nan):
        with pytest.raises(ValueError, match="random_scale must be a finite number >= 0"):
            prediction_uncertainty(model, track_drive, few_setups, demo_library,
                                   draws=UncertaintyOptions(n_draws=2, random_scale=bad))


def _cv_frf(frf, deviation):
    """`frf` with a cross-validation of constant relative `deviation` per block (shape (K,)
    broadcast over pairs) on a 0.1-50 Hz grid."""
    grid = np.geomspace(0.1, 50.0, 40)
    dev = (np.asarray(deviation, dtype=complex)[:, None, None, None]
           * np.ones(frf.H.shape[:2] + (grid.size,))).astype(np.complex64)
    return replace(frf, cv_deviation=dev, settings=dict(
        frf.settings, cross_validation={"blocks": dev.shape[0], "f_hz": grid.tolist()}))


def test_random_part_sized_by_the_cross_validation(known_plant, track_drive, demo_library,
                                                   few_setups):
    """A model with the session's cross-validation takes the random part's size from it
    (recorded as random_error "cross-validation"): twice the blocks' deviations, twice the
    random half-widths and the scale; never below the FRF lines' measured ratio; without it (an older model file) the formula; a given
    random_scale wins over both; a cross-validation of the wrong shape falls back to the
    formula."""
    frf = _frf(known_plant, 0.99)
    opts = UncertaintyOptions(n_draws=20)

    def unc(f, draws=opts):
        return prediction_uncertainty(SimpleNamespace(frf=f), track_drive, few_setups,
                                      demo_library, draws=draws)

    u1 = unc(_cv_frf(frf, [0.01, -0.01]))
    u2 = unc(_cv_frf(frf, [0.02, -0.02]))
    assert u1.settings["random_error"] == "cross-validation"
    assert u2.settings["random_scale"] == pytest.approx(2 * u1.settings["random_scale"],
                                                        rel=RTOL_WIDTH_SCALING_SMALL)
    w1 = (u1.ratio_hi - u1.ratio_lo).to_numpy()
    w2 = (u2.ratio_hi - u2.ratio_lo).to_numpy()
    assert_allclose(w2 / w1, 2.0, rtol=RTOL_WIDTH_SCALING_SMALL)
    floor = _cv_frf(frf, [0.01, -0.01])
    floor = replace(floor, settings=dict(floor.settings, cross_validation=dict(
        floor.settings["cross_validation"], ratio_all=50.0)))
    assert unc(floor).settings["random_scale"] == pytest.approx(50.0 * CV_LENGTH_FACTOR,
                                                                rel=RTOL_EXACT)
    old = unc(frf)
    assert old.settings["random_error"] == "formula"
    assert old.settings["random_scale"] == random_error_scale(frf)
    given = unc(_cv_frf(frf, [0.01, -0.01]), UncertaintyOptions(n_draws=20, random_scale=1.0))
    assert given.settings["random_error"] == "given" and given.settings["random_scale"] == 1.0
    bad = _cv_frf(frf, [0.01, -0.01])
    bad = replace(bad, cv_deviation=bad.cv_deviation[:, :1])
    assert cross_validation_deviations(bad, [1.0, 2.0]) is None
    assert cross_validation_deviations(frf, [1.0, 2.0]) is None


def test_noise_bias_is_a_signed_systematic_term(known_plant, track_drive, demo_library,
                                                few_setups):
    """A model whose FRF carries its measured noise bias gets the systematic term
    input_noise: zero for a zero bias; for an estimate biased low on every pair (b < 0:
    the bias-corrected response is larger) the model's metrics are below the corrected
    ones in every setup (the term is negative) and the interval wider than without it; a
    bias of the wrong shape is left out."""
    frf = _cv_frf(_frf(known_plant, 0.99), [0.01, -0.01])
    grid = np.asarray(frf.settings["cross_validation"]["f_hz"])
    opts = UncertaintyOptions(n_draws=8)

    def unc(b):
        f = replace(frf, noise_bias=None if b is None else
                    (b * np.ones(frf.H.shape[:2] + (grid.size,))).astype(np.complex64))
        return prediction_uncertainty(SimpleNamespace(frf=f), track_drive, few_setups,
                                      demo_library, draws=opts)

    none, zero, low = unc(None), unc(0.0), unc(-0.02)
    assert "input_noise" not in none.components and "input_noise" not in none.settings["terms"]
    assert zero.settings["terms"][-1] == "input_noise"
    assert_allclose(zero.components["input_noise"].to_numpy(), 0.0, atol=RTOL_EXACT)
    assert_allclose(zero.ratio_hi.to_numpy(), none.ratio_hi.to_numpy(), rtol=RTOL_EXACT)
    term = low.components["input_noise"].to_numpy()
    assert np.all(term < 0)
    assert np.all((low.ratio_hi - low.ratio_lo).to_numpy() > (none.ratio_hi
                                                              - none.ratio_lo).to_numpy())
    bad = replace(frf, noise_bias=np.zeros((1, 1, grid.size), np.complex64))
    assert noise_bias_deviation(bad, [1.0, 2.0]) is None
    assert noise_bias_deviation(frf, [1.0, 2.0]) is None


def test_cross_validated_scale_pools_metrics_and_skips_silent_ones():
    """Per metric mean square ratio, then the root of their mean: metrics with ratios 1 and 9
    give sqrt(5); a metric whose draws do not spread does not count."""
    cv = np.array([[[0.01, 0.03, 0.5]], [[-0.01, -0.03, 0.5]]])
    d = np.array([[[0.01, 0.01, 0.0]], [[-0.01, -0.01, 0.0]]])
    assert cross_validated_scale(cv, d) == pytest.approx(np.sqrt(5.0), rel=RTOL_EXACT)
    assert CV_LENGTH_FACTOR == pytest.approx(2 ** 0.25, rel=RTOL_EXACT)
    assert np.isnan(cross_validated_scale(cv[..., 2:], d[..., 2:]))


def _modal_model(zeta, f_hz=13.0, n_out=4, light_pairs=None):
    """A VehicleModel whose pairs are one mode of damping ratio `zeta` at `f_hz` (``light_pairs``
    of them; the others a mode at zeta 0.3 and 3 Hz), residues that make each pair's peak 1."""
    n_in = 11
    shape = (n_out, n_in, 1)
    light = np.zeros((n_out, n_in), dtype=bool)
    light.flat[:light.size if light_pairs is None else light_pairs] = True
    z = np.where(light, zeta, 0.3)[..., None]
    wn = 2 * np.pi * np.where(light, f_hz, 3.0)[..., None]
    p = -z * wn + 1j * wn * np.sqrt(1 - z**2)
    r = (z * wn) * np.ones(shape) / 2  # |r| / (zeta wn) = 1/2 against a peak of about 1
    return VehicleModel(name="modal", input_names=MODEL_INPUTS,
                        output_names=tuple(f"out{i}" for i in range(n_out)), poles=p,
                        residues=r.astype(complex), direct=np.zeros((n_out, n_in)),
                        n_poles=np.ones((n_out, n_in), dtype=int),
                        order=np.full((n_out, n_in), 2), fit_error=np.zeros((n_out, n_in)),
                        cbar_n_s_m=np.full(4, 5000.0), fs_hz=100.0)


def test_light_modes_finds_a_lightly_damped_mode_shared_by_the_pairs():
    found = light_modes(_modal_model(0.02))
    assert len(found) == 1
    row = found.iloc[0]
    assert row["f_hz"] == pytest.approx(13.0, rel=1e-9)
    assert row["zeta"] == pytest.approx(0.02, rel=1e-9)
    assert row["pairs"] == 44
    assert LIGHT_DAMPING_ZETA > 0.02  # the fit's floor ZETA_MIN counts as light


def test_light_modes_ignores_damped_modes_stray_poles_and_other_bands(identified_model):
    assert light_modes(_modal_model(0.05)).empty            # damped enough
    assert light_modes(_modal_model(0.02, light_pairs=2)).empty   # 2 of 44 pairs: stray poles
    assert light_modes(_modal_model(0.02, f_hz=25.0)).empty       # outside the metric band
    assert len(light_modes(_modal_model(0.02, f_hz=25.0), band_hz=(1.0, 30.0))) == 1
    assert light_modes(SimpleNamespace(frf=None)).empty           # no poles: nothing to say
    assert light_modes(identified_model).empty                    # the paper car's model


def test_light_modes_are_warned_and_recorded(known_plant, track_drive, demo_library, few_setups,
                                             monkeypatch, caplog):
    """prediction_uncertainty warns about a lightly damped mode and records it in settings."""
    import planner.uncertainty as unc

    mode = pd.DataFrame({"f_hz": [13.06], "zeta": [0.02], "pairs": [232]})
    monkeypatch.setattr(unc, "light_modes", lambda model, band_hz: mode)
    with caplog.at_level("WARNING", logger="planner.uncertainty"):
        u = _unc(known_plant, 0.99, track_drive, few_setups, demo_library)
    assert u.settings["light_modes"] == [{"f_hz": 13.06, "zeta": 0.02, "pairs": 232}]
    assert "lightly damped modes in the metric band (13.1 Hz, zeta 0.020)" in caplog.text


# ---------------------------------------------------------------- unresolved pairs


def _pairs_case(rng, n_draws=200, noise=0.02):
    """Metrics (one weighted metric) of a baseline and four setups: close_a and close_b 0.5 %
    apart, far well below, and the Monte Carlo ratios: 2 % noise on every non-baseline setup."""
    names = ["tire_force_rms_LF", "shock_travel_rms_LF"]
    setups = ["baseline", "close_a", "close_b", "far", "worse"]
    values = np.array([[100.0, 0.01], [90.0, 0.01], [90.5, 0.01], [50.0, 0.01], [130.0, 0.01]])
    scores = pd.DataFrame(values, index=setups, columns=names)
    draws = 1.0 + noise * rng.standard_normal((n_draws, len(setups), len(names)))
    draws[:, 0, :] = 1.0
    ratio = pd.DataFrame(np.ones((len(setups), len(names))), index=setups, columns=names)
    unc = Uncertainty(ratio_lo=ratio, ratio_hi=ratio, draws=draws, metric_names=names)
    return scores, unc


OBJ_ONE = Objective("one metric", {"tire_force_rms_LF": 1.0})


def test_close_setups_are_unresolved_far_ones_are_not(rng):
    """Two setups 0.5 % apart under 2 % noise swap in about 40 % of the draws: unresolved;
    setups 10 % or more apart (> 3.5 standard deviations of the difference) are resolved."""
    scores, unc = _pairs_case(rng)
    pairs = unresolved_pairs(scores, unc, OBJ_ONE, baseline="baseline")
    assert set(pairs) == set(scores.index)
    assert pairs["close_a"] == ["close_b"] and pairs["close_b"] == ["close_a"]
    assert pairs["far"] == [] and pairs["worse"] == [] and pairs["baseline"] == []


def test_unresolved_threshold_and_top(rng):
    """A pair swapping in a known fraction of the draws is flagged above max_flip only;
    `top` keeps pairs among the best setups."""
    names = ["tire_force_rms_LF"]
    setups = ["baseline", "a", "b", "c"]
    scores = pd.DataFrame([[100.0], [80.0], [81.0], [95.0]], index=setups, columns=names)
    draws = np.ones((20, 4, 1))
    draws[:3, 1, 0] = 1.05  # a = 84 > b = 81 in 3 of 20 draws: 15 %
    draws[:2, 3, 0] = 0.8  # c = 76 < a, b in 2 of 20 draws: 10 % (a: 84 in 2 of those)
    ratio = pd.DataFrame(np.ones((4, 1)), index=setups, columns=names)
    unc = Uncertainty(ratio_lo=ratio, ratio_hi=ratio, draws=draws, metric_names=names)
    strict = unresolved_pairs(scores, unc, OBJ_ONE, baseline="baseline", max_flip=0.05)
    assert strict == {"a": ["b", "c"], "b": ["a", "c"], "c": ["a", "b"], "baseline": []}
    loose = unresolved_pairs(scores, unc, OBJ_ONE, baseline="baseline", max_flip=0.12)
    assert loose == {"a": ["b"], "b": ["a"], "c": [], "baseline": []}
    assert unresolved_pairs(scores, unc, OBJ_ONE, baseline="baseline", max_flip=0.2) == {
        s: [] for s in ["a", "b", "c", "baseline"]}
    top2 = unresolved_pairs(scores, unc, OBJ_ONE, baseline="baseline", top=2)
    assert top2 == {"a": ["b"], "b": ["a"]}


def test_unresolved_pairs_match_rows_by_name(rng):
    """The scores' rows may come in another order than the draws' setups."""
    scores, unc = _pairs_case(rng)
    shuffled = scores.iloc[[3, 0, 4, 2, 1]]
    assert unresolved_pairs(shuffled, unc, OBJ_ONE, baseline="baseline") == unresolved_pairs(
        scores, unc, OBJ_ONE, baseline="baseline")


# ---------------------------------------------------------------- coverage on held-out cars
def _held_out_cars():
    """The held-out cars of studies/interval_calibration.py (none of them in the calibration):
    name -> (vehicle, noise, run length [s], validation drive)."""
    from ident.data.drive import make_noise_drive, make_track_drive
    from ident.models.vehicle import example_gt_vehicle, example_vehicle

    paper = example_vehicle()

    def car(name, mass_kg, springs_n_m, torsion=None, tire_damping=None):
        r = mass_kg / paper.sprung_mass_kg
        return paper.replace(name=name, sprung_mass_kg=mass_kg,
                             roll_inertia_kg_m2=paper.roll_inertia_kg_m2 * r,
                             pitch_inertia_kg_m2=paper.pitch_inertia_kg_m2 * r,
                             spring_rate_n_m=np.repeat(np.asarray(springs_n_m, dtype=float), 2),
                             torsion_stiffness_n_m_rad=torsion,
                             tire_damping_n_s_m=None if tire_damping is None
                             else np.full(4, tire_damping))

    gt = example_gt_vehicle()

    def track(v, speed):
        return make_track_drive(duration_s=HELD_OUT_DRIVE_S, fs_hz=100.0, seed=24, speed_m_s=speed,
                                wheelbase_m=v.a_m + v.b_m, track_width_m=v.track_front_m)

    noise = make_noise_drive(duration_s=HELD_OUT_DRIVE_S, fs_hz=100.0, seed=24, f_max_hz=25.0,
                             peak={**{f"wheelloader_{c}": 0.0254 for c in ("LF", "RF", "LR", "RR")},
                                   "aero_heave": 2224.0})
    compact = car("compact", 950.0, (250e3, 220e3), 3.5e5, 900.0)
    soft = car("soft heavy", 1500.0, (100e3, 120e3))
    stiff = car("stiff light", 900.0, (300e3, 340e3), 1.5e5, 1000.0)
    return {"GT-like": (gt, 0.02, 300.0, track(gt, 50.0)),
            "compact": (compact, 0.04, 250.0, track(compact, 60.0)),
            "soft heavy": (soft, 0.01, 600.0, noise),
            "stiff light": (stiff, 0.015, 800.0, track(stiff, 35.0))}


#: The held-out check's size: one identification per car (every run's seed 101) of the
#: paper's plan at the car's run length in the study, only the outputs the metrics need, 20
#: setups on a 60 s drive: about 75 s of CI (two seeds took 150 s). Measured: GT-like 98.2 %,
#: compact 96.4 %, soft heavy 96.1 %, stiff light 88.2 % (pooled 94.7 %); seed 102 gave 98.9,
#: 98.6, 95.7 and 91.8 %.
HELD_OUT_SEEDS = (101,)
HELD_OUT_DRIVE_S = 60.0
#: Pooled over the 4 held-out cars, the coverage must be in the issue's 90-98 %. One
#: identification's coverage is a sample of about 14 independent metric errors (its error is
#: shared by all setups), so a single car's has a standard deviation of about 5 %: the
#: per-car 90-98 % of issue 24 is checked by the study as the mean over 3 identifications
#: (docs/DESIGN.md); pooling 4 cars brings the standard deviation to about 2.5 %.
HELD_OUT_POOLED = (0.90, 0.98)
#: No single identification below this (2 standard deviations of one realization under 95 %).
HELD_OUT_SINGLE_MIN = 0.85


@pytest.fixture(scope="module")
def held_out_coverage(demo_library):
    """Per held-out car and seed: the share of the known model's metrics inside rank's 95 %
    intervals (the package's calibrated scale)."""
    import warnings
    from dataclasses import replace

    from ident.identify.condition import condition_frf
    from ident.identify.frf import estimate_frf
    from ident.identify.pipeline import fit_model
    from ident.models.vehicle import build_full_car
    from ident.sim.metrics import METRIC_NAMES
    from ident.sim.virtual_rig import default_plan, simulate_session
    from planner.predict import METRIC_OUTPUTS, predict_setups
    from planner.setups import Setup

    pool = enumerate_setups(demo_library)
    idx = np.unique(np.linspace(0, len(pool) - 1, 19).round().astype(int))
    setups = [Setup("baseline", {c: "DM" for c in ("LF", "RF", "LR", "RR")})] + [pool[i] for i in idx]
    out = {}
    for name, (car, noise, run_s, drive) in _held_out_cars().items():
        for seed in HELD_OUT_SEEDS:
            plan = default_plan()
            plan = replace(plan, noise=noise, input_noise=noise / 4,
                           runs=tuple(replace(r, duration_s=run_s, seed=seed)
                                      for r in plan.runs))
            session = simulate_session(plan, car)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model = fit_model(condition_frf(estimate_frf(session,
                                                             outputs=list(METRIC_OUTPUTS))))
            pred = predict_setups(model, drive, setups, demo_library)
            unc = prediction_uncertainty(model, drive, setups, demo_library, predictions=pred)
            t = unc.intervals(pred.table)
            known = predict_setups(build_full_car(car).loop_plant(model.cbar_n_s_m), drive,
                                   setups, demo_library).table.loc[t.index]
            names = [m for m in METRIC_NAMES if m in t]
            out[name, seed] = float(np.mean([(known[m] >= t[f"{m}_lo"]) & (known[m] <= t[f"{m}_hi"])
                                             for m in names]))
    return out


@pytest.mark.slow
@pytest.mark.heavy
def test_intervals_cover_95_percent_on_held_out_cars(held_out_coverage):
    """Issue 24: rank's 95 % intervals, calibrated on other cars, cover 90-98 % of the known
    model's metrics on the held-out cars (pooled), and no car falls far out of it."""
    pooled = np.mean(list(held_out_coverage.values()))
    assert HELD_OUT_POOLED[0] <= pooled <= HELD_OUT_POOLED[1], held_out_coverage
    assert min(held_out_coverage.values()) >= HELD_OUT_SINGLE_MIN, held_out_coverage


# ---------------------------------------------------------------- sized by the session itself
#: The CI check of issue 37 item 1 (the intervals' random part sized by the session's own
#: cross-validation): one held-out car of ``studies/interval_calibration_cv.py``, "light
#: 100 s" (900 kg, springs 120 / 110 kN/m, rigid chassis, 3 % noise, 5 runs of 100 s, 7-post,
#: 100 Hz, never used to choose anything), one identification (seed 301), 20 setups on a 60 s
#: track at 40 m/s. One identification's coverage is about 14 independent errors (standard
#: deviation about 5 %): below 85 % is broken, not bad luck (2 standard deviations under 95 %).
CV_CAR_MIN_COVERAGE = 0.85
#: Intervals that are right in size are about 2.9 times the median error wide (1.96 / 0.674
#: for Gaussian errors); the formula's were 5 times on the GT car (issue 37). Above 8, they
#: are too wide to be the session's own error.
CV_CAR_MAX_WIDTH_RATIO = 8.0
#: Of the 19 differences from the best (shared errors: few independent ones), at least this
#: share inside their intervals.
CV_CAR_MIN_DIFFERENCE_COVERAGE = 0.75


def _held_out_car(name):
    """Cars of ``studies/interval_calibration_cv.py``'s held-out family: (vehicle, noise, run
    length [s], sample rate [Hz], track speed [m/s])."""
    from ident.models.vehicle import example_gt_vehicle, example_vehicle

    if name == "GT 4-post":
        return example_gt_vehicle(), 0.02, 400.0, 100.0, 50.0

    p = example_vehicle()

    def car(label, mass_kg, springs_n_m, torsion=None, tire_damping=None):
        r = mass_kg / p.sprung_mass_kg
        return p.replace(name=label, sprung_mass_kg=mass_kg,
                         roll_inertia_kg_m2=p.roll_inertia_kg_m2 * r,
                         pitch_inertia_kg_m2=p.pitch_inertia_kg_m2 * r,
                         spring_rate_n_m=np.repeat(np.asarray(springs_n_m, dtype=float), 2),
                         torsion_stiffness_n_m_rad=torsion,
                         tire_damping_n_s_m=None if tire_damping is None
                         else np.full(4, tire_damping))

    return {"light 100 s": (car("light", 900.0, (120e3, 110e3)), 0.03, 100.0, 100.0, 40.0),
            "heavy twist 200 Hz": (car("heavy twist", 1450.0, (280e3, 250e3), 2.0e5, 900.0),
                                   0.01, 250.0, 200.0, 60.0)}[name]


#: Held-out cars on another rig than the paper plan's 7-post, with more runs: (rig, runs).
#: The study's 8-run plan adds a second baseline and two diagonal swaps.
HELD_OUT_RIGS = {"GT 4-post": ("4-post", 8)}


def _check_held_out_car(name, demo_library, *, differences=True):
    """Identify a held-out car with the defaults (seed 301), predict 20 setups on a 60 s
    track, and check its intervals against the known car (the CV_CAR_* bounds; those of
    the differences from the best with `differences`)."""
    import warnings
    from dataclasses import replace as dc_replace

    from ident.data.drive import make_track_drive
    from ident.identify.pipeline import identify_session
    from ident.models.vehicle import build_full_car
    from ident.sim.metrics import METRIC_NAMES
    from ident.sim.virtual_rig import default_plan, simulate_session
    from planner.objective import default_objective, score_setups
    from planner.predict import predict_setups, prepare_drive
    from planner.setups import Setup

    car, noise, run_s, fs_hz, speed = _held_out_car(name)
    plan = default_plan()
    runs = [dc_replace(r, duration_s=run_s, seed=301) for r in plan.runs]
    rig, n_runs = HELD_OUT_RIGS.get(name, (plan.rig, len(runs)))
    if n_runs > len(runs):
        from ident.sim.virtual_rig import PlanRun

        base, soft = runs[0].setup, runs[1].setup["LF"]
        runs += [PlanRun("baseline-2", dict(base), "baseline", 301, run_s),
                 PlanRun("swap-LF-RR", {**base, "LF": soft, "RR": soft}, "swap", 301, run_s),
                 PlanRun("swap-RF-LR", {**base, "RF": soft, "LR": soft}, "swap", 301,
                         run_s)][:n_runs - len(runs)]
    plan = dc_replace(plan, noise=noise, input_noise=noise / 4, fs_hz=fs_hz, rig=rig,
                      runs=tuple(runs))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(simulate_session(plan, car), diagnose=False, check_shocks=False)
    drive = make_track_drive(duration_s=60.0, fs_hz=100.0, seed=24, speed_m_s=speed,
                             wheelbase_m=car.a_m + car.b_m, track_width_m=car.track_front_m)
    pool = enumerate_setups(demo_library)
    idx = np.unique(np.linspace(0, len(pool) - 1, 19).round().astype(int))
    setups = [Setup("baseline", {c: "DM" for c in ("LF", "RF", "LR", "RR")})] + [pool[i] for i in idx]
    pred = predict_setups(model, drive, setups, demo_library)
    unc = prediction_uncertainty(model, drive, setups, demo_library, predictions=pred)
    assert unc.settings["random_error"] == "cross-validation"
    # the known car on the drive the model predicts on (resampled to a 200 Hz model's rate)
    known = predict_setups(build_full_car(car).loop_plant(model.cbar_n_s_m),
                           prepare_drive(drive, model.fs_hz), setups,
                           demo_library).table.loc[pred.table.index]
    names = [m for m in METRIC_NAMES if m in pred.table]
    P, K = pred.table[names].to_numpy(), known[names].to_numpy()
    lo, hi = P * unc.ratio_lo[names].to_numpy(), P * unc.ratio_hi[names].to_numpy()
    assert np.mean((K >= lo) & (K <= hi)) >= CV_CAR_MIN_COVERAGE
    half = np.median((unc.ratio_hi - unc.ratio_lo)[names].to_numpy() / 2)
    assert 0 < half <= CV_CAR_MAX_WIDTH_RATIO * np.median(np.abs(P / K - 1))
    obj = default_objective()
    table = score_intervals(score_errors(pred.table, unc, obj, baseline="baseline"))
    true = score_setups(known, obj, baseline="baseline").table
    best = table.index[table["verdict"] == "best"][0]
    d = (true["score"] - true.loc[best, "score"]).drop(index=best)
    t = table.drop(index=best)
    if differences:
        assert np.mean((t["diff_best_lo"] <= d) & (d <= t["diff_best_hi"])) >= \
            CV_CAR_MIN_DIFFERENCE_COVERAGE
    assert table.loc[true["score"][true["feasible"]].idxmin(), "verdict"] in ("best", "tied")


def test_cross_validated_intervals_cover_a_held_out_car(demo_library):
    """Issue 37: on a car held out of any choice of the method, identified with the defaults
    (cross-validation on), rank's 95 % intervals cover the known car's metrics, are not
    wider than the error calls for, hold most true differences from the best, and the true
    best is called best or tied (the light car: 5 runs of 100 s; measured 91.8 %)."""
    _check_held_out_car("light 100 s", demo_library)


@pytest.mark.slow
@pytest.mark.heavy
def test_cross_validated_intervals_cover_a_second_held_out_car(demo_library):
    """The same on the heavy car with a chassis twist, 200 Hz, 5 runs of 250 s (about a
    minute of CPU). Its intervals were 0.8 % wide for errors of 0.05 % while the halves of
    the cross-validation were cut plainly (their LPM window twice as wide in Hz as the full
    estimate's: docs/DESIGN.md, "The 200 Hz cars"); the rotated halves size them."""
    _check_held_out_car("heavy twist 200 Hz", demo_library)


@pytest.mark.slow
@pytest.mark.heavy
def test_cross_validated_intervals_cover_the_held_out_car_on_a_4_post_rig(demo_library):
    """The same on the GT car on a 4-post rig (8 runs of 400 s, 2 % noise; the study's 90.4 %
    on this identification, 94.6 % over two). Its differences from the best are not
    checked: the model's differences are 1-2 % (relative) smaller than the true ones on the
    GT cars, which no term carries yet (the study: 21 % on this identification, 95 % on the
    next; docs/DESIGN.md, "The 200 Hz cars")."""
    _check_held_out_car("GT 4-post", demo_library, differences=False)


# ---------------------------------------------------------------- intervals of differences
#: Quantiles (0, 1): the intervals are the draws' extremes, so known answers are exact.
ALL_DRAWS = (0.0, 1.0)
# A sum of a few products of exact decimals: round-off only.
ATOL_KNOWN = 1e-12


def _shared_case(n_draws=41):
    """Baseline 100, a 90, b 91 and c 90.2 (one weighted metric): a and b share one relative
    error f_d = 0.9..1.1 in every draw; c has f_d and its own +-1 % besides."""
    names = ["tire_force_rms_LF"]
    setups = ["baseline", "a", "b", "c"]
    scores = pd.DataFrame([[100.0], [90.0], [91.0], [90.2]], index=setups, columns=names)
    f = np.linspace(0.9, 1.1, n_draws)
    s = np.where(np.arange(n_draws) % 2 == 0, 1.0, -1.0)
    draws = np.ones((n_draws, 4, 1))
    draws[:, 1, 0] = draws[:, 2, 0] = f
    draws[:, 3, 0] = f * (1 + 0.01 * s)
    ratio = pd.DataFrame(np.ones((4, 1)), index=setups, columns=names)
    fit = pd.DataFrame([[0.0], [0.01], [0.01], [0.01]], index=setups, columns=names)
    return scores, ratio, draws, fit


def test_difference_intervals_known_answer():
    """With a shared error the per-draw difference b - a is exactly 0.01 f_d: its interval
    is [0.009, 0.011] while a's score spans [0.81, 0.99]; alike systematic terms (+1 % on
    both) enter the difference as their difference (0.0001), the score whole (0.009)."""
    scores, ratio, draws, fit = _shared_case()
    unc = Uncertainty(ratio_lo=ratio, ratio_hi=ratio, draws=draws, metric_names=list(ratio),
                      components={"fit": fit}, settings={"quantiles": ALL_DRAWS})
    err = score_errors(scores, unc, OBJ_ONE, baseline="baseline")
    assert_allclose(err.systematic["fit"].to_numpy(), [0.0, 0.009, 0.0091, 0.00902],
                    atol=ATOL_KNOWN)
    t = score_intervals(err, baseline="baseline")

    def widen(half, d):
        return np.sqrt(half**2 + d**2) - half

    assert_allclose(t.loc["a", ["score_lo", "score_hi"]].to_numpy(float),
                    [0.81 - widen(0.09, 0.009), 0.99 + widen(0.09, 0.009)], atol=ATOL_KNOWN)
    assert_allclose(t.loc["b", ["diff_best_lo", "diff_best_hi"]].to_numpy(float),
                    [0.009 - widen(0.001, 0.0001), 0.011 + widen(0.001, 0.0001)],
                    atol=ATOL_KNOWN)
    assert_allclose(t.loc["a", ["diff_best_lo", "diff_best_hi"]].to_numpy(float), [0, 0],
                    atol=ATOL_KNOWN)
    # against the baseline (no error of its own): a - baseline = 0.9 f_d - 1
    assert_allclose(t.loc["a", ["diff_baseline_lo", "diff_baseline_hi"]].to_numpy(float),
                    [-0.19 - widen(0.09, 0.009), -0.01 + widen(0.09, 0.009)], atol=ATOL_KNOWN)
    assert t["verdict"].tolist() == ["worse", "best", "worse", "tied"]
    # b - baseline reaches 0.91 * 1.1 - 1 = +0.001, c 0.902 * 1.1 * 1.01 - 1 = +0.002: tied
    assert t["verdict_baseline"].tolist() == ["baseline", "better", "tied", "tied"]
    assert list(t.columns) == list(SCORE_INTERVAL_COLUMNS)
    # the single-pair form and the unresolved pairs agree with the table
    assert_allclose(difference_interval(err, "b", "a"),
                    t.loc["b", ["diff_best_lo", "diff_best_hi"]].to_numpy(float))
    pairs = unresolved_pairs(scores, unc, OBJ_ONE, baseline="baseline", errors=err)
    # c's own +-1 % (0.9 below b to 0.1 above it) leaves it tied with a, b and the baseline
    assert {k: set(v) for k, v in pairs.items()} == {
        "a": {"c"}, "b": {"c", "baseline"}, "c": {"a", "b", "baseline"},
        "baseline": {"b", "c"}}


def test_alike_systematic_errors_cancel_in_the_difference():
    """Two setups 1 % apart with the same +-3 % systematic error and no random one: their
    difference's interval stays within 0.05 % of the nominal (resolved), while the
    quadrature sum of their values' errors would span +-4 % (unresolved)."""
    names = ["tire_force_rms_LF"]
    setups = ["baseline", "a", "b"]
    scores = pd.DataFrame([[100.0], [90.0], [90.9]], index=setups, columns=names)
    draws = np.ones((5, 3, 1))
    ratio = pd.DataFrame(np.ones((3, 1)), index=setups, columns=names)
    fit = pd.DataFrame([[0.0], [0.03], [0.03]], index=setups, columns=names)
    unc = Uncertainty(ratio_lo=ratio, ratio_hi=ratio, draws=draws, metric_names=names,
                      components={"fit": fit})
    t = score_intervals(score_errors(scores, unc, OBJ_ONE, baseline="baseline"))
    lo, hi = t.loc["b", ["diff_best_lo", "diff_best_hi"]]
    assert 0.009 - 0.0005 < lo < 0.009 < hi < 0.009 + 0.0005
    assert t.loc["b", "verdict"] == "worse"
    assert t.loc["b", "score_hi"] - t.loc["b", "score_lo"] == pytest.approx(2 * 0.03 * 0.909)


def test_difference_interval_is_narrower_when_errors_are_shared(rng):
    """20 setups whose draws share a 3 % error and have 0.5 % of their own: every
    difference's interval from the best is narrower than the setup's score interval (and
    than the best's); with independent 3 % errors instead it is wider."""
    n_draws, n = 200, 20
    names = ["tire_force_rms_LF"]
    setups = ["baseline"] + [f"s{k}" for k in range(n)]
    values = np.r_[100.0, 80.0 + np.arange(n)]
    scores = pd.DataFrame(values[:, None], index=setups, columns=names)
    ratio = pd.DataFrame(np.ones((n + 1, 1)), index=setups, columns=names)
    shared = 1 + 0.03 * rng.standard_normal((n_draws, 1, 1))
    own = 1 + 0.005 * rng.standard_normal((n_draws, n + 1, 1))
    for draws, narrower in ((shared * own, True),
                            (1 + 0.03 * rng.standard_normal((n_draws, n + 1, 1)), False)):
        draws[:, 0, :] = 1.0
        unc = Uncertainty(ratio_lo=ratio, ratio_hi=ratio, draws=draws, metric_names=names,
                          settings={"quantiles": (0.025, 0.975)})
        t = score_intervals(score_errors(scores, unc, OBJ_ONE, baseline="baseline"))
        others = t.drop(index=["s0", "baseline"])  # the baseline scores 1 in every draw
        diff_w = (others["diff_best_hi"] - others["diff_best_lo"]).to_numpy()
        value_w = (others["score_hi"] - others["score_lo"]).to_numpy()
        assert np.all((diff_w < value_w) == narrower)


def test_score_intervals_best_is_feasible_and_infeasible_setups_say_so():
    """The best is the best feasible setup; an infeasible one is called so, whatever its
    interval."""
    idx = ["a", "b", "base"]
    err = ScoreErrors(nominal=pd.Series([0.8, 0.9, 1.0], index=idx),
                      draws=pd.DataFrame([[0.8, 0.8], [0.9, 0.9], [1.0, 1.0]], index=idx),
                      systematic=pd.DataFrame(index=idx),
                      feasible=pd.Series([False, True, True], index=idx), baseline="base")
    t = score_intervals(err)
    assert t["verdict"].tolist() == ["infeasible", "best", "worse"]
    assert t["verdict_baseline"].tolist() == ["infeasible", "better", "baseline"]
    assert t.loc["a", "diff_best_lo"] == pytest.approx(-0.1)
