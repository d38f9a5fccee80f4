"""Tests of ident.data.third and the sessions' third elements (the spec's optional section
"Third elements: heave and roll elements per axle"): the geometry, the typed keys, the
round trip through a session folder and every refusal's message."""

import logging
import tomllib
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import tomli_w

from ident.data.channels import CORNERS, RIG_INPUTS, THIRD_CHANNELS, quantity_of
from ident.data.session import Run, make_session, read_session, write_session
from ident.data.third import (AXLES, THIRD_ELEMENTS, RunThird, ThirdElements, check_run_third,
                              check_third_elements, element_row)
from ident.errors import SessionError
from ident.models.bumpstops import BumpStop, BumpStopLibrary
from ident.models.library import read_shock_library

FS_HZ = 100.0
N_SAMPLES = 120
#: CSV round trip of floats written with full precision (shortest repr): exact to rounding.
RTOL_ROUND_TRIP = 1e-12
SHOCKS_TOML = """\
units = "SI"

[[shock]]
id = "B20"
kind = "linear"
damping = 3502.5

[[shock]]
id = "H1"
kind = "table"
velocity = [-0.5, 0.0, 0.5]
force = [-2000.0, 0.0, 1500.0]
lag = 0.003

[[shock]]
id = "R2"
kind = "linear"
damping = 900.0
"""
MOTION_RATIOS = {"heave_front": 1.0, "heave_rear": 1.2, "roll_front": 0.8}
THIRD = {"heave_front": "H1", "heave_rear": "H1", "roll_front": "R2"}


@pytest.fixture
def shocks(tmp_path):
    path = tmp_path / "library.toml"
    path.write_text(SHOCKS_TOML)
    return read_shock_library(path)


@pytest.fixture
def springs():
    return BumpStopLibrary([
        BumpStop(id="HS-F", gap_m=0.004, travel_m=[0.0, 0.01], force_n=[0.0, 2000.0]),
        BumpStop(id="HS-R", gap_m=0.0, travel_m=[0.0, 0.01], force_n=[0.0, 3000.0])])


def _run(rng, name, third):
    time_s = np.arange(N_SAMPLES) / FS_HZ
    channels = {c: rng.standard_normal(N_SAMPLES) for c in RIG_INPUTS + THIRD_CHANNELS[:4]}
    return Run(name=name, file=f"runs/{name}.csv", setup=dict.fromkeys(CORNERS, "B20"),
               role="baseline", time_s=time_s, channels=channels, fs_hz=FS_HZ, third=third)


@pytest.fixture
def session(shocks, springs):
    rng = np.random.default_rng(38)
    third = RunThird(dampers={**dict.fromkeys(THIRD_ELEMENTS), **THIRD},
                     heave_springs={"front": "HS-F", "rear": "HS-R"},
                     heave_packers_m={"front": 0.002, "rear": 0.0})
    return make_session("prototype", [_run(rng, "baseline-1", third), _run(rng, "plain", None)],
                        shocks, bump_stops=springs, third_elements=MOTION_RATIOS)


# --------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------


def test_element_rows_follow_the_spec_table():
    """Travel ``mr (x_L + x_R) / 2`` (heave) and ``mr (x_L - x_R) / 2`` (roll); force ``mr F /
    2`` at both corners (heave), ``+-mr F / 2`` (roll)."""
    x = np.array([0.010, 0.004, -0.002, 0.006])  # corner shock travels [m]
    assert element_row("heave_front", 1.2) @ x == pytest.approx(1.2 * (0.010 + 0.004) / 2)
    assert element_row("roll_front", 0.8) @ x == pytest.approx(0.8 * (0.010 - 0.004) / 2)
    assert element_row("heave_rear", 1.0) @ x == pytest.approx((-0.002 + 0.006) / 2)
    assert element_row("roll_rear", 2.0) @ x == pytest.approx(-0.002 - 0.006)
    force = 1000.0  # the element's own force [N]
    assert (element_row("heave_front", 1.2) * force).tolist() == [600.0, 600.0, 0.0, 0.0]
    assert (element_row("roll_rear", 0.8) * force).tolist() == [0.0, 0.0, 400.0, -400.0]


def test_roll_element_sees_no_pure_heave_and_heave_no_pure_roll():
    heave = np.array([1.0, 1.0, 1.0, 1.0])
    roll = np.array([1.0, -1.0, 1.0, -1.0])
    for axle in AXLES:
        assert element_row(f"roll_{axle}", 0.7) @ heave == 0.0
        assert element_row(f"heave_{axle}", 0.7) @ roll == 0.0


def test_third_channels_have_quantities():
    assert quantity_of("heave_velocity_front") == "velocity"
    assert quantity_of("roll_travel_rear") == "displacement"
    assert quantity_of("heave_spring_force_rear") == "force"
    assert len(THIRD_CHANNELS) == 14


# --------------------------------------------------------------------------------------
# sessions
# --------------------------------------------------------------------------------------


def test_make_session_types_the_keys(session):
    assert session.third_elements == ThirdElements(MOTION_RATIOS)
    assert session.third_elements.elements == ("heave_front", "heave_rear", "roll_front")
    base, plain = session.runs
    assert base.third.dampers == {**dict.fromkeys(THIRD_ELEMENTS), **THIRD}
    assert base.third.heave_springs == {"front": "HS-F", "rear": "HS-R"}
    assert base.third.heave_packers_m == {"front": 0.002, "rear": 0.0}
    assert not plain.third and plain.third == RunThird()


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_round_trip(session, tmp_path, units, caplog):
    folder = write_session(session, tmp_path / "s", units=units)
    doc = tomllib.loads((folder / "session.toml").read_text())
    assert doc["third_elements"] == MOTION_RATIOS
    assert doc["run"][0]["third"] == THIRD
    assert "third" not in doc["run"][1]
    with caplog.at_level(logging.INFO, logger="ident.data.session"):
        back = read_session(folder)
    said = [r for r in caplog.records if "third elements" in r.getMessage()]
    assert len(said) == 1 and "predictions put them in the loop" in said[0].getMessage()
    assert said[0].levelno == logging.INFO and "heave_front" in said[0].getMessage()
    assert back.third_elements == session.third_elements
    for a, b in zip(session.runs, back.runs):
        assert a.third.dampers == b.third.dampers
        assert a.third.heave_springs == b.third.heave_springs
        for axle in AXLES:
            assert b.third.heave_packers_m[axle] == pytest.approx(
                a.third.heave_packers_m[axle], rel=RTOL_ROUND_TRIP)
        for c in THIRD_CHANNELS[:4]:
            np.testing.assert_allclose(b.channels[c], a.channels[c], rtol=RTOL_ROUND_TRIP)


def test_a_plain_session_is_not_warned(shocks, tmp_path, caplog):
    rng = np.random.default_rng(1)
    s = make_session("plain", [_run(rng, "a", None)], shocks)
    with caplog.at_level(logging.WARNING, logger="ident.data.session"):
        back = read_session(write_session(s, tmp_path / "s"))
    assert not back.third_elements
    assert not any("third" in r.getMessage() for r in caplog.records)
    assert "third_elements" not in (tmp_path / "s" / "session.toml").read_text()


def _edit(folder, edit):
    path = folder / "session.toml"
    doc = tomllib.loads(path.read_text())
    edit(doc)
    path.write_text(tomli_w.dumps(doc))
    return folder


@pytest.mark.parametrize("edit, match", [
    (lambda d: d["run"][0]["third"].update(heave_front="NOPE"),
     r"run 'baseline-1'.*third heave_front = 'NOPE' is not in the shock library shocks.toml.*"
     r"add the damper"),
    (lambda d: d["third_elements"].update(heave_front=0.0),
     r"session.toml: third_elements heave_front = 0.0 is not a motion ratio; give a number > 0"),
    (lambda d: d["third_elements"].update(roll_front=-1.0),
     r"third_elements roll_front = -1.0 is not a motion ratio"),
    (lambda d: d["third_elements"].pop("roll_front"),
     r"run 'baseline-1'.*third roll_front = 'R2' but the session does not declare roll_front; "
     r"add it with its motion ratio to the manifest's third_elements"),
    (lambda d: d["run"][1].update(third={"roll_rear": "R2"}),
     r"run 'plain'.*does not declare roll_rear"),
    (lambda d: d["run"][0]["heave_packers"].update(front=0.005),
     r"heave_packers front.*gap"),
    (lambda d: d["run"][0]["third"].update(heave_frnt="H1"),
     r"third 'heave_frnt' is not a third element \(did you mean 'heave_front'\?\)"),
    (lambda d: d["run"][0]["heave_springs"].update(middle="HS-F"),
     r"heave_springs 'middle' is not an axle"),
    (lambda d: d["run"][0]["heave_springs"].update(front="HS-X"),
     r"heave_springs front.*HS-X"),
    (lambda d: d.update(third={"heave_front": "H1"}),
     r"'third' is a key of a run"),
    (lambda d: d["run"][0].update(third_elements={"heave_front": 1.0}),
     r"'third_elements' is a key of the session"),
])
def test_refusals_name_file_field_and_fix(session, tmp_path, edit, match):
    folder = _edit(write_session(session, tmp_path / "s"), edit)
    with pytest.raises(SessionError, match=match):
        read_session(folder)


def test_heave_spring_needs_a_declared_heave_element_and_library(shocks, springs):
    elements = check_third_elements({"roll_front": 1.0}, "session.toml")
    with pytest.raises(SessionError, match="heave_springs front = 'HS-F' but the session does "
                                           "not declare heave_front"):
        check_run_third(None, {"front": "HS-F"}, None, elements=elements, shocks=shocks,
                        bump_stops=springs, where="run 'a'")
    elements = check_third_elements({"heave_front": 1.0}, "session.toml")
    with pytest.raises(SessionError, match="no bump-stop library"):
        check_run_third(None, {"front": "HS-F"}, None, elements=elements, shocks=shocks,
                        bump_stops=None, where="run 'a'")
    with pytest.raises(SessionError, match="heave_packers rear = 0.001 but the run has no "
                                           "heave spring rear"):
        check_run_third(None, None, {"rear": 0.001}, elements=elements, shocks=shocks,
                        bump_stops=springs, where="run 'a'")
    got = check_run_third({"heave_front": "none"}, {"front": "None"}, None, elements=elements,
                          shocks=shocks, bump_stops=springs, where="run 'a'")
    assert got == RunThird()


# --------------------------------------------------------------------------------------
# setups CSVs
# --------------------------------------------------------------------------------------


def test_setups_csv_third_columns_round_trip(shocks, springs, tmp_path, caplog):
    from planner.setups import Setup
    from planner.setups.csv_io import read_setups, write_setups

    setups = [Setup("base", dict.fromkeys(CORNERS, "B20")),
              Setup("soft-heave", dict.fromkeys(CORNERS, "B20"),
                    third={"heave_front": "R2", "roll_front": "none"},
                    heave_springs={"front": "HS-F"}),
              Setup("no-spring", dict.fromkeys(CORNERS, "B20"), heave_springs={"front": None})]
    path = write_setups(setups, tmp_path / "setups.csv")
    header = path.read_text().splitlines()[0]
    assert header == "setup,LF,RF,LR,RR,heave_front,roll_front,heave_spring_front,units"
    with caplog.at_level(logging.WARNING, logger="planner.setups.csv_io"):
        back = read_setups(path, shocks, springs)
    assert not caplog.records  # the predictions vary them (issue 38): no warning
    assert back == tuple(setups)
    assert back[1].third == {"heave_front": "R2", "roll_front": None}
    assert back[0].third is None and back[2].heave_springs == {"front": None}
    import pickle  # the setups travel to worker processes
    assert pickle.loads(pickle.dumps(back[1])) == back[1]
    assert "third={'heave_front': 'R2'" in repr(back[1])


@pytest.mark.parametrize("column, value, match", [
    ("heave_rear", "X9", r"setups.csv: line 2 \(setup 'a'\): column 'heave_rear': unknown "
                         r"shock id 'X9'"),
    ("heave_spring_front", "HS-X", r"setups.csv: line 2 \(setup 'a'\): column "
                                   r"'heave_spring_front'.*HS-X"),
])
def test_setups_csv_third_refusals(shocks, springs, tmp_path, column, value, match):
    from planner.errors import PlannerError
    from planner.setups.csv_io import read_setups

    path = tmp_path / "setups.csv"
    path.write_text(f"setup,LF,RF,LR,RR,{column}\na,B20,B20,B20,B20,{value}\n")
    with pytest.raises(PlannerError, match=match):
        read_setups(path, shocks, springs)


def test_append_runs_keeps_and_checks_the_elements(session, tmp_path):
    from ident.data.session import append_runs

    folder = write_session(session, tmp_path / "s")
    rng = np.random.default_rng(7)
    third = RunThird(dampers={**dict.fromkeys(THIRD_ELEMENTS), "heave_front": "R2"})
    back = append_runs(folder, [_run(rng, "more", third)])
    assert back.run("more").third.dampers["heave_front"] == "R2"
    assert back.third_elements == session.third_elements
    bad = RunThird(dampers={**dict.fromkeys(THIRD_ELEMENTS), "roll_rear": "R2"})
    with pytest.raises(SessionError, match="does not declare roll_rear"):
        append_runs(folder, [_run(rng, "bad", bad)])
