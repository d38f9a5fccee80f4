"""Tests of ident.sim.third_loop and the virtual rig with third elements: the truth checks
(no elements: the plain loop's numbers; a heave damper in pure heave and a roll damper in
pure roll: corner dampers of ``c mr^2 / 2``), the known answers (a heave spring's gap, a
roll damper idle in pure heave, a heave element idle in pure roll, static equilibrium
unchanged by a damper) and a plan with elements written to a session and read back."""

import logging
from dataclasses import replace

import numpy as np
import pytest

from ident.data.channels import CORNERS, RIG_INPUTS
from ident.data.drive import Drive
from ident.data.session import read_session, write_session
from ident.data.third import element_row
from ident.errors import SessionError
from ident.models.bumpstops import BumpStop
from ident.models.shocks import LinearShock
from ident.models.vehicle import build_full_car, example_vehicle
from ident.sim.closedloop import simulate
from ident.sim.third_loop import ThirdDamper, ThirdSpring, simulate_third
from ident.sim.virtual_rig import read_rig_plan, simulate_session

#: Two loops with the same discretization, solved by Newton's method to 1e-7 N: the same
#: numbers to rounding (measured 5e-15 of the RMS on a 20 s noise drive).
RTOL_SAME_LOOP = 1e-9
FS_HZ = 800.0  # the internal grid (the virtual rig's 100 Hz x 8)
DURATION_S = 6.0


def _drive(rng, *, heave=True, roll=False, aero=True):
    """A band-limited noise drive: the same at left and right wheelloaders (`heave`), or
    opposite (`roll`), zero aero moments; ``aero`` a heave force."""
    n = int(DURATION_S * FS_HZ)
    t = np.arange(n) / FS_HZ
    taper = np.minimum(1.0, np.minimum(t, t[-1] - t) / 0.5)
    def noise(scale):
        x = np.convolve(rng.standard_normal(n), np.hanning(24), mode="same")
        return scale * taper * x / np.std(x)
    front, rear = noise(0.004), noise(0.004)
    sign = -1.0 if roll else 1.0
    ch = {"aero_heave": noise(300.0) if aero and heave else np.zeros(n),
          "aero_roll": np.zeros(n), "aero_pitch": np.zeros(n),
          "wheelloader_LF": front, "wheelloader_RF": sign * front,
          "wheelloader_LR": rear, "wheelloader_RR": sign * rear}
    return Drive(name="test", fs_hz=FS_HZ, channels=ch)


@pytest.fixture(scope="module")
def car():
    return build_full_car(example_vehicle())


def _plant(car, models):
    return car.loop_plant(np.array([m.equivalent_damping(0.1) for m in models]))


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.sqrt(np.mean(b ** 2))


def test_without_elements_it_is_the_plain_loop(car):
    rng = np.random.default_rng(1)
    drive = _drive(rng, roll=False)
    shocks = [LinearShock("a", 3000.0), LinearShock("b", 2500.0, lag_s=0.004),
              LinearShock("c", 3500.0), LinearShock("d", 2000.0)]
    plant = _plant(car, shocks)
    plain = simulate(plant, drive, shocks, oversample=1)
    third = simulate_third(plant, drive, shocks)
    for name, x in plain.channels.items():
        assert _rel(third.channels[name], x) < RTOL_SAME_LOOP, name


@pytest.mark.parametrize("element", ["heave_front", "roll_rear"])
def test_element_in_its_own_motion_is_corner_dampers_of_c_mr2_over_2(car, element):
    """In pure heave (roll) of a symmetric car a heave (roll) damper ``c`` through ``mr``
    gives each corner of its axle ``c mr^2 / 2``: its force maps to the corners as the
    motion ratio says."""
    rng = np.random.default_rng(2)
    drive = _drive(rng, roll=element.startswith("roll"), aero=False)
    mr, c = 1.3, 4000.0
    base = [LinearShock("s", 3000.0)] * 4
    plant = _plant(car, base)
    got = simulate_third(plant, drive, base, dampers=[
        ThirdDamper(element, element_row(element, mr), LinearShock("h", c))])
    axle = (0, 1) if element.endswith("front") else (2, 3)
    equal = [LinearShock("s", 3000.0 + (c * mr ** 2 / 2 if i in axle else 0.0))
             for i in range(4)]
    want = simulate(plant, drive, equal, oversample=1)
    for name in ("shock_velocity_LF", "tire_force_LR", "ride_height_RF", "shock_travel_RR"):
        assert _rel(got.channels[name], want.channels[name]) < 1e-8, name
    kind, ax = element.split("_")
    # the element's force: its curve at its own velocity (no lag)
    assert np.allclose(got.channels[f"{kind}_force_{ax}"],
                       c * got.channels[f"{kind}_velocity_{ax}"], rtol=0, atol=1e-9)


@pytest.mark.parametrize("element, roll", [("roll_front", False), ("heave_rear", True)])
def test_element_idle_in_the_other_motion(car, element, roll):
    """A roll damper does not act in pure heave, a heave element not in pure roll."""
    rng = np.random.default_rng(3)
    drive = _drive(rng, roll=roll, aero=False)
    base = [LinearShock("s", 3000.0)] * 4
    plant = _plant(car, base)
    got = simulate_third(plant, drive, base, dampers=[
        ThirdDamper(element, element_row(element, 1.0), LinearShock("h", 5000.0))])
    want = simulate(plant, drive, base, oversample=1)
    kind, ax = element.split("_")
    scale = np.sqrt(np.mean(want.channels["shock_velocity_LF"] ** 2))
    assert np.max(np.abs(got.channels[f"{kind}_velocity_{ax}"])) < 1e-9 * scale
    assert _rel(got.channels["tire_force_LF"], want.channels["tire_force_LF"]) < 1e-8


def test_heave_spring_exerts_nothing_until_its_gap_closes(car):
    rng = np.random.default_rng(4)
    drive = _drive(rng, aero=True)
    base = [LinearShock("s", 3000.0)] * 4
    plant = _plant(car, base)
    gap, packer = 0.004, 0.001
    stop = BumpStop(id="HS", gap_m=gap, travel_m=[0.0, 0.01], force_n=[0.0, 5000.0])
    got = simulate_third(plant, drive, base, springs=[
        ThirdSpring("heave_front", element_row("heave_front", 1.0),
                    (gap - packer, stop.travel_m, stop.force_n))])
    travel = got.channels["shock_travel_LF"] / 2 + got.channels["shock_travel_RF"] / 2
    force = got.channels["heave_spring_force_front"]
    closed = travel > gap - packer
    assert closed.any() and (~closed).any()  # the drive closes it at times, not always
    assert np.all(force[~closed] == 0.0)
    assert np.allclose(force[closed], 5000.0 / 0.01 * (travel[closed] - (gap - packer)),
                       rtol=1e-9)
    plain = simulate(plant, drive, base, oversample=1)
    assert _rel(got.channels["tire_force_LF"], plain.channels["tire_force_LF"]) > 1e-3


def test_static_equilibrium_unchanged_by_a_damper(car):
    """A constant aero load held: the car settles where it would without the heave
    damper (a damper has no force at rest)."""
    n = int(4.0 * FS_HZ)
    t = np.arange(n) / FS_HZ
    ramp = np.clip(t / 0.5, 0.0, 1.0)
    ch = {c: np.zeros(n) for c in RIG_INPUTS}
    ch["aero_heave"] = -2000.0 * ramp
    drive = Drive(name="step", fs_hz=FS_HZ, channels=ch)
    base = [LinearShock("s", 3000.0)] * 4
    plant = _plant(car, base)
    with_damper = simulate_third(plant, drive, base, dampers=[
        ThirdDamper("heave_front", element_row("heave_front", 1.0),
                    LinearShock("h", 20000.0, lag_s=0.004))])
    plain = simulate(plant, drive, base, oversample=1)
    for c in CORNERS:
        a = with_damper.channels[f"ride_height_{c}"][-1]
        b = plain.channels[f"ride_height_{c}"][-1]
        assert a == pytest.approx(b, rel=1e-6), c
        assert abs(b) > 1e-4  # the load moved the car


SHOCKS = """\
units = "SI"
[[shock]]
id = "B20"
kind = "linear"
damping = 3502.5
[[shock]]
id = "H1"
kind = "table"
velocity = [-0.5, 0.0, 0.5]
force = [-3000.0, 0.0, 2000.0]
lag = 0.003
[[shock]]
id = "R2"
kind = "linear"
damping = 1500.0
"""
STOPS = """\
units = "SI"
[[bump_stop]]
id = "HS-F"
gap = 0.002
travel = [0.0, 0.01]
force = [0.0, 8000.0]
"""
PLAN = """\
format = "rig-plan/1"
name = "prototype"
units = "SI"
shock_library = "shocks.toml"
bump_stop_library = "bumpstops.toml"
third_elements = { heave_front = 1.0, roll_front = 0.8 }
fs_hz = 100.0
duration_s = 8.0
oversample = 4
noise = 0.01
[drive]
kind = "noise"
taper_s = 0.5
[[run]]
name = "baseline"
setup = { LF = "B20", RF = "B20", LR = "B20", RR = "B20" }
role = "baseline"
third = { heave_front = "H1", roll_front = "R2" }
heave_springs = { front = "HS-F" }
heave_packers = { front = 0.001 }
[[run]]
name = "no-heave-damper"
setup = { LF = "B20", RF = "B20", LR = "B20", RR = "B20" }
role = "swap"
third = { heave_front = "none" }
"""


def _plan(tmp_path, text=PLAN):
    (tmp_path / "shocks.toml").write_text(SHOCKS)
    (tmp_path / "bumpstops.toml").write_text(STOPS)
    (tmp_path / "plan.toml").write_text(text)
    return read_rig_plan(tmp_path / "plan.toml")


def test_a_plan_with_elements_writes_the_spec_session(tmp_path, caplog):
    plan = _plan(tmp_path)
    session = simulate_session(plan)
    base, other = session.runs
    assert session.third_elements.motion_ratios == {"heave_front": 1.0, "roll_front": 0.8}
    assert base.third.dampers["heave_front"] == "H1"
    assert base.third.heave_springs["front"] == "HS-F"
    assert base.third.heave_packers_m["front"] == pytest.approx(0.001)
    assert other.third.dampers["heave_front"] is None
    for run in session.runs:
        for name in ("heave_velocity_front", "heave_travel_front", "heave_force_front",
                     "heave_spring_force_front", "roll_velocity_front", "roll_travel_front",
                     "roll_force_front"):
            assert name in run.channels, (run.name, name)
        assert "heave_force_rear" not in run.channels
    # the unfitted damper's load cell reads noise about 0 only
    assert np.std(other.channels["heave_force_front"]) < 0.05 * np.std(
        base.channels["heave_force_front"])
    with caplog.at_level(logging.INFO, logger="ident.data.session"):
        back = read_session(write_session(session, tmp_path / "session"))
    assert back.third_elements == session.third_elements
    assert [r.third for r in back.runs] == [r.third for r in session.runs]
    assert any("predictions put them in the loop" in r.getMessage() for r in caplog.records)


def test_plan_refusals(tmp_path):
    with pytest.raises(SessionError, match=r"run 'baseline'.*third roll_rear = 'R2' but the "
                                           "session does not declare roll_rear"):
        _plan(tmp_path, PLAN.replace('roll_front = "R2" }', 'roll_rear = "R2" }'))
    with pytest.raises(SessionError, match=r"third heave_front = 'X9' is not in the shock "
                                           "library shocks.toml"):
        _plan(tmp_path, PLAN.replace('heave_front = "H1"', 'heave_front = "X9"'))
    with pytest.raises(SessionError, match="third_elements heave_front = -1.0 is not a motion"):
        _plan(tmp_path, PLAN.replace("heave_front = 1.0", "heave_front = -1.0"))
    with pytest.raises(SessionError, match=r"heave_packers front.*gap"):
        _plan(tmp_path, PLAN.replace("front = 0.001", "front = 0.003"))


def test_without_elements_the_plan_runs_as_before(tmp_path):
    """The truth check: a plan without third elements gives the session of before, to the
    bit (the plain loop; the elements' path is never entered)."""
    text = PLAN.replace("third_elements = { heave_front = 1.0, roll_front = 0.8 }\n", "")
    text = "\n".join(line for line in text.splitlines()
                     if not line.startswith(("third", "heave_")))
    plan = _plan(tmp_path, text)
    a = simulate_session(plan)
    b = simulate_session(replace(plan, third_elements={}))
    assert not a.third_elements and not b.third_elements
    for ra, rb in zip(a.runs, b.runs):
        assert list(ra.channels) == list(rb.channels)
        for name in ra.channels:
            assert np.array_equal(ra.channels[name], rb.channels[name]), name


def test_the_vehicle_may_declare_the_elements(tmp_path):
    """A plan without ``third_elements`` takes the vehicle TOML's (its geometry); the
    vehicle file round-trips them and refuses a motion ratio that is not positive."""
    from ident.errors import VehicleError
    from ident.models.vehicle import read_vehicle, write_vehicle

    car = example_vehicle().replace(third_elements={"heave_front": 1.0, "roll_front": 0.8})
    write_vehicle(car, tmp_path / "car.toml")
    back = read_vehicle(tmp_path / "car.toml")
    assert back.third_elements == {"heave_front": 1.0, "roll_front": 0.8}
    text = (tmp_path / "car.toml").read_text().replace("roll_front = 0.8", "roll_front = 0.0")
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(VehicleError, match=r"bad.toml: third_elements roll_front = 0.0 is not a "
                                           "motion ratio; give a number > 0"):
        read_vehicle(tmp_path / "bad.toml")
    plan = _plan(tmp_path, PLAN.replace(
        "third_elements = { heave_front = 1.0, roll_front = 0.8 }\n", ""))
    session = simulate_session(plan, back)
    assert session.third_elements.motion_ratios == back.third_elements
    assert "roll_force_front" in session.runs[0].channels
    with pytest.raises(SessionError, match="does not declare roll_front"):
        simulate_session(plan, example_vehicle().replace(third_elements={"heave_front": 1.0}))


def test_a_lagged_table_heave_damper_applies_its_lagged_curve(car, tmp_path):
    """Dampers of any kind with lag: the element's force is its curve at its own velocity
    behind the lag ``tau dF/dt + F = f(v)``, discretized as every shock's."""
    from scipy.signal import lfilter

    from ident.models.library import read_shock_library
    from ident.models.lti import lag_hold_coefficients

    (tmp_path / "shocks.toml").write_text(SHOCKS)
    h1 = read_shock_library(tmp_path / "shocks.toml")["H1"]
    rng = np.random.default_rng(5)
    drive = _drive(rng)
    base = [LinearShock("s", 3000.0)] * 4
    plant = _plant(car, base)
    got = simulate_third(plant, drive, base, dampers=[
        ThirdDamper("heave_rear", element_row("heave_rear", 1.2), h1)])
    v = got.channels["heave_velocity_rear"]
    alpha, b0, b1, bm = (float(a) for a in lag_hold_coefficients(h1.lag_s, 1.0 / FS_HZ))
    want = lfilter([b0, b1, bm], [1.0, -alpha], h1.to_pwl().force(v))
    force = got.channels["heave_force_rear"]
    assert np.max(np.abs(force - want)) < 1e-9 * np.max(np.abs(want))
    assert np.max(np.abs(force - h1.to_pwl().force(v))) > 0.01 * np.max(np.abs(want))
