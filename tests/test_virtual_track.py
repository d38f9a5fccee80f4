"""ident.sim.virtual_track: the virtual track (a road at a varying speed, aero loads from the speed)
and its logger."""

import numpy as np
import pytest

from ident.data.channels import AERO_INPUTS, CORNERS, WHEELLOADER_INPUTS
from ident.errors import DriveError
from ident.models.aero import AeroModel
from ident.models.vehicle import build_full_car
from ident.sim.closedloop import simulate
from ident.sim.virtual_track import (POT_OFFSET_M, STATIC_RIDE_HEIGHT_M, log_track_run,
                             make_speed_trace, make_track_run)
from planner.setups import Setup

#: The rear wheels read their side's profile one wheelbase later: at a varying speed the
#: delay is the time the car takes to cover the wheelbase, found to the sample by the
#: cross-correlation on a 200 Hz run (the decimation filter is zero phase).
DELAY_TOL_S = 0.01
#: Logged noise is 2 % of each channel's RMS: the measured standard deviation of logged
#: minus true is within 5 % of that (12,000 samples: 1.3 % sampling error, 4 sigma).
NOISE_RTOL = 0.05


@pytest.fixture(scope="module")
def aero(paper_vehicle):
    return AeroModel(name="test", kind="constant", cg_to_front_axle_m=paper_vehicle.a_m,
                     cg_to_rear_axle_m=paper_vehicle.b_m, reference_speed_m_s=60.0,
                     downforce_n=3000.0, balance=0.45)


@pytest.fixture(scope="module")
def run(paper_vehicle, aero):
    return make_track_run(duration_s=60.0, fs_hz=200.0, seed=4,
                          wheelbase_m=paper_vehicle.a_m + paper_vehicle.b_m,
                          track_width_m=paper_vehicle.track_front_m, aero=aero)


def test_speed_trace_spans_its_range_smoothly():
    v = make_speed_trace(duration_s=300.0, fs_hz=50.0, seed=1, speed_range_m_s=(30.0, 70.0))
    assert v.min() == pytest.approx(30.0) and v.max() == pytest.approx(70.0)
    assert np.abs(np.diff(v)).max() * 50.0 < 20.0          # < 2 g of acceleration
    with pytest.raises(DriveError, match="speed_range_m_s"):
        make_speed_trace(duration_s=10.0, fs_hz=50.0, seed=1, speed_range_m_s=(50.0, 40.0))


def test_rear_follows_front_by_the_wheelbase(run, paper_vehicle):
    """Known answer: the rear wheels see the front's road one wheelbase later, so their
    signal lags by wheelbase / speed."""
    fs = run.drive.fs_hz
    v = float(np.mean(run.speed_m_s[2000:4000]))
    want = (paper_vehicle.a_m + paper_vehicle.b_m) / v
    f = run.drive.channels["wheelloader_LF"][2000:4000]
    r = run.drive.channels["wheelloader_LR"][2000:4000]
    lags = np.arange(0, int(0.2 * fs))
    corr = [np.dot(f[: f.size - k], r[k:]) for k in lags]
    assert abs(lags[int(np.argmax(corr))] / fs - want) < DELAY_TOL_S + np.ptp(
        run.speed_m_s[2000:4000]) / v * want


def test_aero_loads_follow_the_speed(run, aero):
    """The drive holds the loads' dynamic part; their mean is the static preload."""
    loads = aero.loads(run.speed_m_s)
    mid = slice(400, run.drive.n_samples - 400)     # outside the fades
    pre = run.settings["aero_preload"]
    for a in AERO_INPUTS:
        assert pre[a] == pytest.approx(np.mean(loads.channels[a]))
        np.testing.assert_allclose(run.drive.channels[a][mid] + pre[a], loads.channels[a][mid],
                                   atol=1e-9 * abs(pre["aero_heave"]))
    assert pre["aero_heave"] < 0                    # downforce pushes down


def test_run_starts_and_ends_at_rest(run):
    for c in run.drive.rig_inputs:
        x = run.drive.channels[c]
        assert abs(x[0]) <= 1e-3 * np.abs(x).max() and abs(x[-1]) <= 1e-3 * np.abs(x).max()


def test_no_aero_is_a_four_post_drive(paper_vehicle):
    r = make_track_run(duration_s=20.0, fs_hz=100.0, seed=2)
    assert r.drive.rig_inputs == WHEELLOADER_INPUTS


def test_ride_height_map_refused(paper_vehicle):
    rh = AeroModel(name="map", kind="ride_height_map", cg_to_front_axle_m=1.0,
                   cg_to_rear_axle_m=1.5, reference_speed_m_s=50.0,
                   ride_height_front_grid_m=np.array([0.03, 0.06]),
                   ride_height_rear_grid_m=np.array([0.05, 0.08]),
                   downforce_n=np.full((2, 2), 3000.0), balance=0.45)
    with pytest.raises(DriveError, match="needs ride heights"):
        make_track_run(duration_s=20.0, fs_hz=100.0, seed=2, aero=rh)


@pytest.mark.parametrize("kw, message", [
    ({"duration_s": 0.0}, "duration_s"), ({"fs_hz": float("nan")}, "fs_hz"),
    ({"taper_s": -1.0}, "taper_s"), ({"oversample": 2.5}, "oversample"),
    ({"oversample": 0}, "oversample"), ({"duration_s": 0.001}, "at least 2")])
def test_bad_run_arguments_refused(kw, message):
    args = dict(duration_s=20.0, fs_hz=100.0, seed=2) | kw
    with pytest.raises(DriveError, match=message):
        make_track_run(**args)


def test_logger_records_the_car_with_noise_and_offsets(run, paper_vehicle, demo_library):
    car = build_full_car(paper_vehicle).loop_plant()
    shocks = Setup("t", {c: "DM" for c in CORNERS}).resolve(demo_library)
    log = log_track_run(car, run, shocks, noise=0.02, seed=1,
                        kinds=("shock_travel", "ride_height", "wheel_accel"))
    true = simulate(car, run.drive, shocks, oversample=4,
                    outputs=[f"{k}_{c}" for k in ("shock_travel", "ride_height")
                             for c in CORNERS]).channels
    assert log.fs_hz == run.drive.fs_hz and "speed" in log.channels
    assert "wheel_accel_LF" in log.channels and "chassis_accel_LF" not in log.channels
    for j, c in enumerate(CORNERS):
        d = log.channels[f"shock_travel_{c}"] - true[f"shock_travel_{c}"]
        assert np.mean(d) == pytest.approx(POT_OFFSET_M[j], abs=1e-4)
        y = true[f"shock_travel_{c}"]
        assert np.std(d) == pytest.approx(0.02 * np.std(y), rel=NOISE_RTOL)
        h = log.channels[f"ride_height_{c}"] - true[f"ride_height_{c}"]
        assert np.mean(h) == pytest.approx(STATIC_RIDE_HEIGHT_M[j // 2], abs=1e-4)
    keep = np.array([i for i, o in enumerate(car.output_names) if o != "ride_height_LF"])
    lacking = car.__class__(car.rig.select(outputs=keep), car.shock.select(outputs=keep),
                            tuple(car.output_names[i] for i in keep), car.cbar_n_s_m)
    with pytest.raises(DriveError, match="no output"):
        log_track_run(lacking, run, shocks, kinds=("ride_height",))
