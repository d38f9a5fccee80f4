"""Tests of the closed loop with third elements (ident.sim.closedloop ``third=``,
ident.sim.loop_kernels.ThirdLoop, ident.sim.loop_third): equivalence with the virtual
rig's truth simulator (ident.sim.third_loop.simulate_third) for setups with lagged heave
and roll dampers, a gapped heave spring in contact and a corner bump stop; a batch equals
its setups one by one; the fused metrics equal the metrics of the full outputs; refusals."""

import sys
from pathlib import Path

import numpy as np
import pytest

from ident.data.third import element_row
from ident.models.bumpstops import BumpStop
from ident.models.shocks import DigressiveShock, LinearShock
from ident.models.vehicle import build_full_car, example_vehicle
from ident.sim.closedloop import simulate, simulate_batch, simulate_batch_metrics
from ident.sim.loop_third import ThirdDamper, ThirdSpring, pack_third
from ident.sim.metrics import THIRD_METRIC_NAMES, compute_metrics
from ident.sim.loop_kernels import THIRD_SEGMENT_PASSES
from ident.sim.third_loop import simulate_third

sys.path.insert(0, str(Path(__file__).parent))
from test_third_loop import _drive  # noqa: E402  (the truth tests' drive)

#: The fast loop and the truth simulator have the same discretization and solve every step
#: to the same root (the fast loop exactly on the final segments, the truth by Newton to
#: 1e-7 N): the same numbers to rounding (measured 2e-14 of a channel's RMS at most).
RTOL_TRUTH = 1e-9
#: A stiff heave damper's loop at oversample 2 against oversample 4 (the same drive): the
#: per-step solve is exact at both, what differs is the discretization of the 200 Hz grid
#: against the 400 Hz one, larger for the stiff element's fast mode (measured 3e-4 to 3.6e-3
#: on the channels' RMS; 6e-5 to 4.5e-4 with the soft heave dampers of the cases above).
RTOL_OVERSAMPLE_RMS = 1e-2
#: The fused metrics against compute_metrics on the full outputs: the same sums in another
#: order (the metric rows are products of averaged coefficients), rounding only.
RTOL_FUSED = 1e-10


@pytest.fixture(scope="module")
def car():
    return build_full_car(example_vehicle())


def _plant(car, models):
    return car.loop_plant(np.array([m.equivalent_damping(0.1) for m in models]))


def _rel(a, b):
    return np.max(np.abs(a - b)) / max(np.sqrt(np.mean(b ** 2)), 1e-30)


def _digressive(name, scale=1.0, lag_s=0.0):
    return DigressiveShock(name, bump_low_n_s_m=6000.0 * scale, bump_knee_m_s=0.03,
                           bump_high_n_s_m=1500.0 * scale, rebound_low_n_s_m=9000.0 * scale,
                           rebound_knee_m_s=0.04, rebound_high_n_s_m=2500.0 * scale,
                           lag_s=lag_s)


HS = BumpStop(id="HS", gap_m=0.004, travel_m=[0.0, 0.005, 0.01], force_n=[0.0, 2000.0, 6000.0])


def _setups():
    """Setups ``(shocks, dampers, springs, stop_tables)``: lagged heave and roll dampers with
    a gapped heave spring in contact; digressive dampers front and rear with a packed heave
    spring and a corner bump stop; a heave spring alone."""
    hf, rf, hr = (element_row("heave_front", 1.0), element_row("roll_front", 0.8),
                  element_row("heave_rear", 1.2))
    base = [LinearShock("s", 3000.0), LinearShock("s2", 2800.0, lag_s=0.003),
            LinearShock("s", 3000.0), LinearShock("s", 3200.0)]
    dig = [_digressive("d"), _digressive("d", 1.1, lag_s=0.002), _digressive("d", 0.9),
           _digressive("d")]
    stop = (0.006, np.array([0.0, 0.004, 0.008]), np.array([0.0, 800.0, 4000.0]))
    return [
        (base, [ThirdDamper("heave_front", hf, LinearShock("h", 8000.0, lag_s=0.004)),
                ThirdDamper("roll_front", rf, LinearShock("r", 3000.0, lag_s=0.002))],
         [ThirdSpring("heave_front", hf, (0.003, HS.travel_m, HS.force_n))], None),
        (dig, [ThirdDamper("heave_front", hf, _digressive("h", 2.0, lag_s=0.003)),
               ThirdDamper("heave_rear", hr, _digressive("hr", 1.5))],
         [ThirdSpring("heave_front", hf, (0.002, HS.travel_m, HS.force_n)),
          ThirdSpring("heave_rear", hr, (0.0, HS.travel_m, HS.force_n))],
         [stop, None, None, stop]),
        (base, [], [ThirdSpring("heave_front", hf, (0.001, HS.travel_m, HS.force_n))], None),
    ]


@pytest.fixture(scope="module")
def drive():
    return _drive(np.random.default_rng(4), aero=True)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_equals_the_truth_simulator(car, drive, k):
    shocks, dampers, springs, stops = _setups()[k]
    plant = _plant(car, shocks)
    want = simulate_third(plant, drive, shocks, dampers=dampers, springs=springs,
                          stop_tables=stops)
    got = simulate(plant, drive, shocks, oversample=1, stop_tables=stops,
                   third=(dampers, springs))
    for name, x in want.channels.items():
        assert _rel(got.channels[name], x) < RTOL_TRUTH, name
    # the heave springs are in contact at times, not always (the gap matters)
    for s in springs:
        share = got.elements[f"heave_spring_contact_share_{s.name.split('_')[1]}"]
        assert 0.0 < share < 1.0
        force = got.channels[f"heave_spring_force_{s.name.split('_')[1]}"]
        assert np.all((force > 0) | (force == 0))


def test_batch_is_its_setups_and_fused_metrics_are_the_outputs_metrics(car, drive):
    cases = _setups()
    shocks = [c[0] for c in cases] + [cases[0][0]]
    third = [(c[1], c[2]) for c in cases] + [None]
    stops = [c[3] for c in cases] + [None]
    plant = _plant(car, cases[0][0])
    batch = simulate_batch(plant, drive, shocks, oversample=1, bump_stops=stops, third=third)
    for i in (1, 3):
        one = simulate(plant, drive, shocks[i], oversample=1, stop_tables=stops[i],
                       third=third[i])
        for name, x in one.channels.items():
            # the same loop; the output product has the batch's element columns (another
            # width, another BLAS blocking): rounding
            assert _rel(batch.channels[name][i], x) < RTOL_FUSED, name
    # a setup without third elements: the plain loop's numbers (its stops none either)
    plain = simulate(plant, drive, shocks[3], oversample=1)
    for name, x in plain.channels.items():
        assert _rel(batch.channels[name][3], x) < RTOL_TRUTH, name
    assert np.all(batch.channels["roll_force_front"][3] == 0.0)
    fused = simulate_batch_metrics(plant, drive, shocks, oversample=1, bump_stops=stops,
                                   third=third)
    full = compute_metrics(batch.channels, fs=batch.fs_hz)
    names = set(fused.metrics.values) & set(THIRD_METRIC_NAMES)
    assert names == {"heave_travel_rms_front", "heave_velocity_rms_front",
                     "heave_travel_rms_rear", "heave_velocity_rms_rear",
                     "roll_travel_rms_front", "roll_velocity_rms_front"}
    for name, x in full.values.items():
        np.testing.assert_allclose(fused.metrics.values[name], x, rtol=RTOL_FUSED,
                                   err_msg=name)
    for name, x in batch.elements.items():
        np.testing.assert_array_equal(fused.metrics.values[name], x, err_msg=name)
    assert np.all(fused.metrics.values["bump_stop_contact_share_LF"][1] > 0)


def _stiff_heave():
    """Digressive heave dampers front and rear with 100 kN s/m low-speed bump (a stiff
    optimum's kind, issue 38): at a 200 Hz step the segment passes cycle at their knees."""
    def dig(name):
        return DigressiveShock(name, bump_low_n_s_m=1e5, bump_knee_m_s=0.02,
                               bump_high_n_s_m=1e4, rebound_low_n_s_m=1e5 / 3,
                               rebound_knee_m_s=0.03, rebound_high_n_s_m=1e4)
    return [ThirdDamper("heave_front", element_row("heave_front", 1.0), dig("hf")),
            ThirdDamper("heave_rear", element_row("heave_rear", 1.2), dig("hr"))]


def _drive_at(fs_hz):
    """The truth tests' drive's kind on a coarser grid (the step of the failing case)."""
    base = _drive(np.random.default_rng(4), aero=True)
    n = int(base.n_samples * fs_hz / base.fs_hz)
    t = np.arange(n) / fs_hz
    tb = np.arange(base.n_samples) / base.fs_hz
    ch = {k: np.interp(t, tb, x) for k, x in base.channels.items()}
    return type(base)(name="coarse", fs_hz=fs_hz, channels=ch)


def test_a_stiff_heave_damper_converges_and_equals_the_truth(car):
    # the segment passes cycle (the Newton fallback solves the step; before its
    # backtracking it did not converge, nor did the truth's Newton): on a 200 Hz grid the
    # fast loop equals the truth, and at oversample 2 the loop is close to oversample 4
    shocks = [LinearShock("s", 3000.0)] * 4
    dampers = _stiff_heave()
    plant = _plant(car, shocks)
    fine = _drive_at(200.0)
    want = simulate_third(plant, fine, shocks, dampers=dampers)
    got = simulate(plant, fine, shocks, oversample=1, third=(dampers, []))
    assert got.newton_iterations > THIRD_SEGMENT_PASSES  # the fallback ran
    for name, x in want.channels.items():
        if np.any(x):
            assert _rel(got.channels[name], x) < RTOL_TRUTH, name
    coarse = _drive_at(100.0)
    two = simulate(plant, coarse, shocks, oversample=2, third=(dampers, []))
    four = simulate(plant, coarse, shocks, oversample=4, third=(dampers, []))
    for name in ("shock_travel_LF", "shock_velocity_RR", "heave_velocity_front",
                 "heave_force_rear", "tire_force_LF"):
        rms2, rms4 = (np.sqrt(np.mean(r.channels[name] ** 2)) for r in (two, four))
        assert abs(rms2 / rms4 - 1.0) < RTOL_OVERSAMPLE_RMS, name


def test_a_diverging_loop_is_refused_naming_the_setup(car):
    # a linear heave damper of 300 kN s/m makes the discretization unstable at a 200 Hz step
    # (every step's solve converges; the response grows without bound): refused with the fix,
    # in the full response and the fused metrics alike; 100 kN s/m at that step is bounded
    shocks = [LinearShock("s", 3000.0)] * 4
    plant = _plant(car, shocks)
    coarse = _drive_at(100.0)

    def heave(c):
        return ([ThirdDamper("heave_front", element_row("heave_front", 1.0),
                             LinearShock("h", c))], [])

    ok = simulate(plant, coarse, shocks, oversample=2, third=heave(1e5))
    assert np.all(np.isfinite(ok.channels["heave_force_front"]))
    with pytest.raises(ValueError, match=r"diverged for setups \[0\] \(forces.*raise oversample"):
        simulate(plant, coarse, shocks, oversample=2, third=heave(3e5))
    with pytest.raises(ValueError, match=r"diverged for setups \[1\]"):
        simulate_batch_metrics(plant, coarse, [shocks, shocks], oversample=2,
                               third=[heave(1e5), heave(3e5)])


def test_refusals(car, drive):
    shocks, dampers, springs, _ = _setups()[0]
    plant = _plant(car, shocks)
    with pytest.raises(ValueError, match="static_corner_load_n"):
        simulate(plant, drive, shocks, oversample=1, third=(dampers, springs),
                 static_corner_load_n=[3000.0] * 4)
    moved = [ThirdDamper("heave_front", element_row("heave_front", 1.1), dampers[0].model)]
    with pytest.raises(ValueError, match="another row"):
        pack_third([(dampers, springs), (moved, [])], 1e-3)
    with pytest.raises(ValueError, match="unknown third spring"):
        pack_third([([], [ThirdSpring("roll_front", element_row("roll_front", 1.0), None)])],
                   1e-3)
    bad = [ThirdSpring("heave_front", element_row("heave_front", 1.0), (-0.001, [0, 1], [0, 1]))]
    with pytest.raises(ValueError, match="contact travel"):
        simulate(plant, drive, shocks, oversample=1, third=([], bad))


def test_fused_motion_metrics_without_the_corners_metrics(car, drive):
    # an element's motion metrics are formed from the corners' band-passed travels and
    # velocities when those are metrics too (the front heave travel here), and are filtered
    # lanes of their own otherwise (the velocities and the rear: their corners not output)
    cases = _setups()
    shocks = [c[0] for c in cases[:2]]
    third = [(c[1], c[2]) for c in cases[:2]]
    stops = [c[3] for c in cases[:2]]
    plant = _plant(car, cases[0][0])
    outputs = ["tire_force_LF", "shock_travel_LF", "shock_travel_RF"]
    batch = simulate_batch(plant, drive, shocks, oversample=1, bump_stops=stops, third=third,
                           outputs=outputs)
    fused = simulate_batch_metrics(plant, drive, shocks, oversample=1, bump_stops=stops,
                                   third=third, outputs=outputs)
    full = compute_metrics(batch.channels, fs=batch.fs_hz)
    assert {"heave_travel_rms_front", "heave_velocity_rms_rear"} <= set(full.values)
    for name, x in full.values.items():
        np.testing.assert_allclose(fused.metrics.values[name], x, rtol=RTOL_FUSED,
                                   err_msg=name)
