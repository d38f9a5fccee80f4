"""Tests of planner.predict: time-domain prediction of setups on identified and known models."""

import numpy as np
import pytest
from scipy.stats import spearmanr

from ident.channels import CORNERS
from ident.errors import PlannerError
from ident.metrics import METRIC_NAMES
from planner.objective import default_objective, score_setups
from planner.predict import predict_setups
from planner.setups import Setup, enumerate_setups
from ident.vehicle import build_full_car

# issue: identified vs known model predictions within 0.5 % median and 2 % max, ranks agree
RTOL_ID_MEDIAN = 0.005
RTOL_ID_MAX = 0.02
SPEARMAN_MIN = 0.98
# generalized car (torsion, unequal half-tracks), 2 % noise, track drive: 1 % median, 3 % max
RTOL_GEN_MEDIAN = 0.01
RTOL_GEN_MAX = 0.03
# issue 10: the 95 % intervals of rank cover 90-98 % of the known model's metrics on the
# generalized car with 2 % noise (measured 94 % over 41 setups x 14 metrics; 17 x 14 here)
COVERAGE_RANGE = (0.90, 0.98)
# issue 8: the paper's plan (one drive in every run) with 2 % response and 0.5 % input noise,
# 40+ setups: 0.2 % median, 1 % max, Spearman >= 0.995, the same best setup. Measured with
# 200 s runs (the CI version): 0.10 % / 0.41 %, Spearman 0.9995; 800 s: 0.07 % / 0.29 %
RTOL_NOISY_PAPER_MEDIAN = 0.002
RTOL_NOISY_PAPER_MAX = 0.01
SPEARMAN_NOISY_PAPER = 0.995


def _setups(library, baseline, n):
    pool = enumerate_setups(library)
    idx = np.unique(np.linspace(0, len(pool) - 1, n).round().astype(int))
    return [baseline] + [pool[i] for i in idx]


def _compare(model_a, model_b, drive, setups, library):
    a = predict_setups(model_a, drive, setups, library)
    b = predict_setups(model_b, drive, setups, library)
    names = [m for m in METRIC_NAMES if m in a.table]
    err = np.abs(a.table[names].to_numpy() / b.table[names].to_numpy() - 1)
    obj = default_objective()
    sa = score_setups(a.table, obj, baseline="baseline").table
    sb = score_setups(b.table, obj, baseline="baseline").table
    return err, sa, sb


def test_identified_matches_known_on_library_setups(identified_model, paper_model,
                                                    validation_drive, demo_library,
                                                    baseline_setup):
    """On a drive within the identified excitation (the paper's drive, another seed)."""
    setups = _setups(demo_library, baseline_setup, 24)
    err, sa, sb = _compare(identified_model, paper_model.loop_plant(identified_model.cbar_n_s_m),
                           validation_drive, setups, demo_library)
    assert np.median(err) < RTOL_ID_MEDIAN
    assert err.max() < RTOL_ID_MAX
    assert spearmanr(sa["score"], sb["score"]).statistic >= SPEARMAN_MIN
    assert sa["rank"].idxmin() == sb["rank"].idxmin()


def test_table_layout_and_units(paper_model, track_drive, demo_library, baseline_setup):
    p = predict_setups(paper_model, track_drive, [baseline_setup], demo_library)
    assert list(p.table.columns[:4]) == list(CORNERS)
    assert p.table.index.tolist() == ["baseline"]
    assert set(METRIC_NAMES) <= set(p.table.columns)
    assert p.settings["kind"] == "time" and p.diagnostics["newton_iterations"].max() > 0
    # a tire-force RMS of a few hundred newtons on a smooth track
    assert 50 < p.table["tire_force_rms_LF"].iloc[0] < 5000


def test_drive_at_another_rate_is_resampled(paper_model, track_drive, demo_library,
                                            baseline_setup, caplog):
    from ident.drive import resample_drive

    fast = resample_drive(track_drive, 200.0)
    a = predict_setups(paper_model, track_drive, [baseline_setup], demo_library)
    b = predict_setups(paper_model, fast, [baseline_setup], demo_library)
    assert b.settings["fs_hz"] == 200.0  # the known model has no data rate: kept
    np.testing.assert_allclose(b.table["tire_force_rms_LF"], a.table["tire_force_rms_LF"],
                               rtol=0.01)


def test_bad_setups(paper_model, track_drive, demo_library):
    bad = Setup("bad", {"LF": "B20", "RF": "B20", "LR": "B20", "RR": "Z99"})
    with pytest.raises(PlannerError, match="Z99"):
        predict_setups(paper_model, track_drive, [bad], demo_library)
    with pytest.raises(PlannerError, match="no setups"):
        predict_setups(paper_model, track_drive, [], demo_library)
    with pytest.raises(TypeError, match="model"):
        predict_setups(object(), track_drive, [bad], demo_library)


@pytest.mark.slow
@pytest.mark.parametrize("noise", [0.0, 0.02])
def test_generalized_car_with_noise(paper_vehicle, paper_plan, demo_library, baseline_setup,
                                    noise):
    """A car that is not the 7-DOF model: chassis torsion, unequal half-tracks and tire
    damping, with and without 2 % measurement noise, identified and validated on a track-like
    drive."""
    import warnings
    from dataclasses import replace

    from ident.drive import make_track_drive
    from ident.model import identify_session
    from ident.rig import simulate_session
    from ident.vehicle import build_full_car, modal_summary

    car = paper_vehicle.replace(torsion_stiffness_n_m_rad=3.0e5, cg_lateral_offset_m=0.04,
                                track_rear_m=1.70, tire_damping_n_s_m=np.full(4, 800.0))
    assert "twist" in modal_summary(car).labels and car.has_tire_damping
    session = simulate_session(replace(paper_plan, noise=noise), car)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(session)
    drive = make_track_drive(duration_s=90.0, fs_hz=100.0, seed=11,
                             wheelbase_m=car.a_m + car.b_m, track_width_m=car.track_front_m)
    truth = build_full_car(car).loop_plant(model.cbar_n_s_m)
    setups = _setups(demo_library, baseline_setup, 16)
    err, sa, sb = _compare(model, truth, drive, setups, demo_library)
    assert np.median(err) < RTOL_GEN_MEDIAN
    assert err.max() < RTOL_GEN_MAX
    if noise:
        # issue 10: rank's 95 % intervals cover 90-98 % of the known model's metrics
        from planner.rank import rank_setups

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ranking = rank_setups(model, drive, demo_library, setups=setups,
                                  baseline="baseline", top=len(setups), n_check=0)
        t = ranking.table
        known = predict_setups(truth, drive, setups, demo_library).table.loc[t.index]
        names = [m for m in METRIC_NAMES if m in t]
        inside = np.array([(known[m] >= t[f"{m}_lo"]) & (known[m] <= t[f"{m}_hi"])
                           for m in names])
        assert COVERAGE_RANGE[0] <= inside.mean() <= COVERAGE_RANGE[1], inside.mean()


@pytest.mark.slow
def test_noisy_session_of_the_papers_plan(paper_vehicle, paper_plan, demo_library,
                                          baseline_setup):
    """The paper's plan (the same drive in every run, a linear baseline) with noisy sensors,
    identified with the defaults: the case whose default estimator once failed (6 % median,
    21.5 % max)."""
    import warnings
    from dataclasses import replace

    from ident.drive import make_track_drive
    from ident.model import identify_session
    from ident.rig import simulate_session

    runs = tuple(replace(r, duration_s=200.0) for r in paper_plan.runs)
    session = simulate_session(replace(paper_plan, runs=runs, noise=0.02, input_noise=0.005))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(session)
    assert model.frf.settings["lpm_half_width"] == 24
    drive = make_track_drive(duration_s=60.0, fs_hz=100.0, seed=7,
                             wheelbase_m=paper_vehicle.a_m + paper_vehicle.b_m,
                             track_width_m=paper_vehicle.track_front_m)
    truth = build_full_car(paper_vehicle).loop_plant(model.cbar_n_s_m)
    setups = _setups(demo_library, baseline_setup, 40)
    assert len(setups) >= 41
    err, sa, sb = _compare(model, truth, drive, setups, demo_library)
    assert np.median(err) < RTOL_NOISY_PAPER_MEDIAN
    assert err.max() < RTOL_NOISY_PAPER_MAX
    assert spearmanr(sa["score"], sb["score"]).statistic >= SPEARMAN_NOISY_PAPER
    assert sa["rank"].idxmin() == sb["rank"].idxmin()
