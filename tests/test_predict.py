"""Tests of planner.predict: time-domain prediction of setups on identified and known models."""

import numpy as np
import pytest
from scipy.stats import spearmanr

from ident.data.channels import CORNERS
from planner.errors import PlannerError
from ident.sim.metrics import METRIC_NAMES
from planner.objective import default_objective, score_setups
from planner.predict import predict_setups
from planner.setups import Setup, enumerate_setups
from ident.models.vehicle import build_full_car

# issue: identified vs known model predictions within 0.5 % median and 2 % max, ranks agree
RTOL_ID_MEDIAN = 0.005
RTOL_ID_MAX = 0.02
SPEARMAN_MIN = 0.98
# generalized car (torsion, unequal half-tracks), 2 % noise, track drive: 1 % median, 3 % max
RTOL_GEN_MEDIAN = 0.01
RTOL_GEN_MAX = 0.03
# issue 10: the 95 % intervals of rank cover at least 90 % of the known model's metrics on the
# generalized car with 2 % noise. One identification (800 s runs, 17 setups x 14 metrics here):
# its coverage is a sample of about 14 independent errors, standard deviation about 5 %. Issue
# 24 calibrated the random part across cars (planner.uncertainty.RANDOM_ERROR_SCALE): at 800 s
# runs this car is over-covered, 99.4 % as the mean of 3 identifications in
# studies/interval_calibration.py (the stiff light car at 800 s: 92.5 %), and 100 % here
# (94 % before the recalibration), so the upper bound is 1; the 90-98 % per car is the study's.
COVERAGE_RANGE = (0.90, 1.0)
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
    from ident.data.drive import resample_drive

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


@pytest.fixture(scope="module")
def generalized_case(paper_vehicle, paper_plan, demo_library, baseline_setup):
    """A car that is not the 7-DOF model: chassis torsion, unequal half-tracks and tire
    damping, with 2 % measurement noise, identified; a track-like drive, 16 setups and the
    known car's loop plant."""
    import warnings
    from dataclasses import replace

    from ident.data.drive import make_track_drive
    from ident.identify.pipeline import identify_session
    from ident.models.vehicle import build_full_car, modal_summary
    from ident.sim.virtual_rig import simulate_session

    car = paper_vehicle.replace(torsion_stiffness_n_m_rad=3.0e5, cg_lateral_offset_m=0.04,
                                track_rear_m=1.70, tire_damping_n_s_m=np.full(4, 800.0))
    assert "twist" in modal_summary(car).labels and car.has_tire_damping
    session = simulate_session(replace(paper_plan, noise=0.02), car)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(session)
    drive = make_track_drive(duration_s=90.0, fs_hz=100.0, seed=11,
                             wheelbase_m=car.a_m + car.b_m, track_width_m=car.track_front_m)
    truth = build_full_car(car).loop_plant(model.cbar_n_s_m)
    return model, truth, drive, _setups(demo_library, baseline_setup, 16)


@pytest.mark.slow
@pytest.mark.heavy
def test_generalized_car_with_noise(generalized_case, demo_library):
    """The generalized car with 2 % noise, validated on a track-like drive. (Its noise-free
    twin was dropped for CI time, issue 26: the noisy case holds the same bars, and the
    noise-free accuracy of the method is held by tests/test_model.py's truth round trips.)"""
    model, truth, drive, setups = generalized_case
    err, sa, sb = _compare(model, truth, drive, setups, demo_library)
    assert np.median(err) < RTOL_GEN_MEDIAN
    assert err.max() < RTOL_GEN_MAX


@pytest.mark.slow
@pytest.mark.heavy
def test_generalized_car_with_noise_interval_coverage(generalized_case, demo_library):
    """Issue 10/37: rank's 95 % intervals cover 90-98 % of the known model's metrics (88 %
    while the cross-validation's halves were cut plainly; at least 90 % with the rotated halves:
    docs/DESIGN.md, "The 200 Hz cars")."""
    import warnings

    from planner.rank import rank_setups

    model, truth, drive, setups = generalized_case
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

    from ident.data.drive import make_track_drive
    from ident.identify.pipeline import identify_session
    from ident.sim.virtual_rig import simulate_session

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


# issue 12: a 4-post session (no aero channels) identifies, and predicts like the known model
# (driven with zero aero loads) within 0.5 % median / 2 % max on 20 setups of the crate.
# Measured with 100 s runs on the 60 s track drive: 0.005 % median, 0.027 % max.
RTOL_4POST_MEDIAN = 0.005
RTOL_4POST_MAX = 0.02
N_4POST_SETUPS = 20
# the known model on a drive without aero columns and on the same drive with zero aero columns:
# the same arithmetic on the same numbers
RTOL_SAME_DRIVE = 1e-12


def _four_post_drive(drive, path):
    """`drive`'s wheelloaders written as a 4-post drive file (no aero columns), read back."""
    from ident.data.channels import WHEELLOADER_INPUTS
    from ident.data.drive import Drive, read_drive, write_drive

    write_drive(Drive(f"{drive.name} 4-post", drive.fs_hz,
                      {c: drive.channels[c] for c in WHEELLOADER_INPUTS}), path)
    return read_drive(path)


def test_four_post_session_identifies_and_predicts(four_post_session, four_post_model,
                                                   paper_model, track_drive, demo_library,
                                                   baseline_setup, tmp_path):
    import pandas as pd

    from ident.data.channels import AERO_INPUTS, WHEELLOADER_INPUTS
    from ident.identify.frf import DF_INPUTS
    from planner.noise import noise_report

    assert four_post_session.rig_inputs == WHEELLOADER_INPUTS
    assert not any(c in r.channels for r in four_post_session.runs for c in AERO_INPUTS)
    # Eq. 17 with 4 + 4 inputs
    assert four_post_model.input_names == WHEELLOADER_INPUTS + DF_INPUTS
    assert four_post_model.rig_inputs == WHEELLOADER_INPUTS
    assert four_post_model.frf.H.shape[1] == 8
    plant = four_post_model.loop_plant()
    assert plant.rig_inputs == WHEELLOADER_INPUTS and plant.rig.B.shape[1] == 7
    assert not plant.rig.B[:, :3].any() and not plant.rig.D[:, :3].any()
    # the model file keeps the plant with its rig inputs
    from ident.identify.model import load_model

    back = load_model(four_post_model.save(tmp_path / "4post.npz")).loop_plant()
    assert back.rig_inputs == WHEELLOADER_INPUTS
    np.testing.assert_array_equal(back.rig.B, plant.rig.B)

    # a 4-post drive file has no aero columns and reads
    path = tmp_path / "track-4-post.csv"
    drive = _four_post_drive(track_drive, path)
    assert not set(AERO_INPUTS) & set(pd.read_csv(path).columns)
    assert drive.rig_inputs == WHEELLOADER_INPUTS and not drive.as_array()[:, :3].any()

    setups = _setups(demo_library, baseline_setup, N_4POST_SETUPS - 1)
    assert len(setups) == N_4POST_SETUPS
    truth = paper_model.loop_plant(four_post_model.cbar_n_s_m)
    err, sa, sb = _compare(four_post_model, truth, drive, setups, demo_library)
    assert np.median(err) < RTOL_4POST_MEDIAN, np.median(err)
    assert err.max() < RTOL_4POST_MAX, err.max()
    assert sa["rank"].idxmin() == sb["rank"].idxmin()

    # the known model takes any drive: without aero columns as with zero ones
    a = predict_setups(truth, drive, setups[:3], demo_library).table
    b = predict_setups(truth, track_drive, setups[:3], demo_library).table
    names = [m for m in METRIC_NAMES if m in a]
    np.testing.assert_allclose(a[names], b[names], rtol=RTOL_SAME_DRIVE)
    # the identify command's noise report (intervals through the 8-input FRF)
    report = noise_report(four_post_model, four_post_session, n_draws=4)
    assert np.all(np.isfinite(list(report.expected_metric_error_pct.values())))


def test_four_post_model_refuses_an_aero_drive(four_post_model, validation_drive, track_drive,
                                               demo_library, baseline_setup, tmp_path):
    import re

    from ident.data.channels import RIG_INPUTS, WHEELLOADER_INPUTS
    from ident.data.drive import read_drive, write_drive
    from ident.errors import DriveError
    from ident.identify.model import load_model
    from planner.screen import screen_setups

    path = tmp_path / "aero-drive.csv"
    write_drive(validation_drive, path)
    drive = read_drive(path)
    match = (rf"^drive file {re.escape(str(path))}: has nonzero content on \['aero_heave', "
             r"'aero_roll', 'aero_pitch'\], but model '.*' has no such rig input .*\['wheelloader_LF'"
             r".*remove those columns from the drive \(or zero them\)")
    for predict in (predict_setups, screen_setups):
        with pytest.raises(DriveError, match=match):
            predict(four_post_model, drive, [baseline_setup], demo_library)
    # a drive whose aero columns are all zero asks nothing of the missing inputs: accepted
    assert track_drive.rig_inputs == RIG_INPUTS and not track_drive.as_array()[:, :3].any()
    pred = predict_setups(four_post_model, track_drive, [baseline_setup], demo_library)
    assert np.all(np.isfinite(pred.table[pred.metric_names].to_numpy()))
    # saved and loaded, the model keeps its rig inputs (and refuses the drive again)
    back = load_model(four_post_model.save(tmp_path / "four-post.npz"))
    assert back.rig_inputs == WHEELLOADER_INPUTS
    with pytest.raises(DriveError, match=match):
        predict_setups(back, drive, [baseline_setup], demo_library)


def test_noise_report_is_kept_with_the_model(four_post_model, four_post_session, tmp_path):
    """The identify command's model: the identified model plus its noise report, a typed
    field (not a setting) saved and loaded with the model."""
    from ident.identify.model import RESULT_KEYS, NoiseReport, load_model
    from planner.noise import noise_report, with_noise_report

    model = with_noise_report(four_post_model, four_post_session, n_draws=4)
    assert isinstance(model.noise, NoiseReport)
    assert model.noise == noise_report(four_post_model, four_post_session, n_draws=4)
    assert model.settings == four_post_model.settings
    assert not set(RESULT_KEYS) & set(model.settings)
    back = load_model(model.save(tmp_path / "m.npz"))
    assert back.noise == model.noise and list(back.settings) == list(model.settings)
    assert list(back.file_settings()) == list(model.file_settings())
    assert list(model.file_settings())[-1] == "noise"
    assert back.diagnosis is not None and back.shock_check is not None
    with pytest.raises(TypeError, match="new VehicleModel"):
        model.with_results(poles=model.poles)


@pytest.mark.parametrize("units, said", [("SI", "RMS travel 25.5 mm predicted, 20 mm covered"),
                                          ("imperial",
                                           "RMS travel 1 in predicted, 0.787 in covered")])
def test_outside_session_warning_is_in_the_projects_units(caplog, units, said):
    """Issue 36: the warning of predictions beyond the session's coverage spoke mm in an
    imperial project; it speaks the run's unit system (set by the command line)."""
    import logging
    from types import SimpleNamespace

    import pandas as pd

    from ident.data.units import display_units
    from ident.identify.coverage import Coverage
    from planner.predict import warn_outside_session

    cov = Coverage(travel_rms_m=np.full(4, 0.020), velocity_rms_m_s=np.full(4, 1.0),
                   travel_max_m=np.full(4, 0.05), contact_min_n=None, runs=5)
    model = SimpleNamespace(settings={"coverage": cov.to_dict()})
    table = pd.DataFrame({**{f"shock_travel_rms_{c}": [0.010] for c in CORNERS},
                          **{f"shock_velocity_rms_{c}": [0.1] for c in CORNERS}}, index=["A"])
    table.loc["A", "shock_travel_rms_LR"] = 0.0255
    with display_units(units), caplog.at_level(logging.WARNING, logger="planner.predict"):
        frame = warn_outside_session(model, table)
    assert frame["what"].tolist() == ["travel"]
    assert said in caplog.text and "setup 'A' at LR" in caplog.text
