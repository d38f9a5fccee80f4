"""The inputs the README's examples need: ``docs/formats.md``'s examples and the files
:func:`planner.demo.write_demo_inputs` writes, each read by its reader as is."""

import dataclasses
import functools
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from ident.data.channels import ALL_CHANNELS, CORNERS, RIG_INPUTS, TRACK_CHANNELS
from ident.dyno.raw import read_dyno_map
from ident.data.formats.channel_map import apply_channel_map, read_channel_map
from ident.data.units import to_si
from ident.errors import AeroModelError, BumpStopError, DynoError, SessionError
from ident.models.aero import read_aero_model
from ident.models.bumpstops import read_bump_stops
from ident.models.library import read_shock_library
from ident.models.vehicle import EXAMPLE_VEHICLE_PATH, example_vehicle, read_vehicle
from ident.sim.virtual_rig import default_plan, simulate_session
from planner.demo import DEMO_INPUT_FILES, DEMO_LIBRARY_PATH, write_demo_inputs
from planner.errors import PlannerError
from planner.objective import default_objective, read_objective
from planner.optimize.constraints import (check_constraints, default_constraints,
                                          read_curve_constraints)
from planner.optimize.space import SYMMETRIES, curve_space
from planner.rig_spec import read_rig
from planner.whatif import read_perturbations

ROOT = Path(__file__).resolve().parents[1]
FORMATS_MD = ROOT / "docs" / "formats.md"
README = ROOT / "README.md"

#: The reader of each format, by the info string of its ```toml block in docs/formats.md,
#: with the error family it raises.
READERS = {
    "objective": (read_objective, PlannerError),
    "constraints": (read_curve_constraints, PlannerError),
    "whatif": (read_perturbations, PlannerError),
    "rig": (read_rig, PlannerError),
    "channel-map": (read_channel_map, SessionError),
    "bump-stops": (read_bump_stops, BumpStopError),
    "dyno-map": (read_dyno_map, DynoError),
    "track-map": (functools.partial(read_channel_map, allowed=ALL_CHANNELS + TRACK_CHANNELS),
                  SessionError),
    "aero": (read_aero_model, AeroModelError),
}
#: A shock's force read back from an imperial file: SI -> imperial text -> SI, shortest
#: round-trip float text each way, so a few ulps.
RTOL_ROUND_TRIP = 1e-12
#: Velocities [m/s] the crate's curves are compared at: both sides, past every knee.
V_CHECK_M_S = np.linspace(-1.0, 1.0, 81)

_FENCE = re.compile(r"^```toml(?P<info>[^\n]*)\n(?P<body>.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def _toml_blocks(text):
    """``(tag, body)`` of every ```toml block: the tag is the info string's second word."""
    out = []
    for m in _FENCE.finditer(text):
        words = m["info"].split()
        out.append((words[0] if words else "", m["body"]))
    return out


FORMAT_BLOCKS = _toml_blocks(FORMATS_MD.read_text(encoding="utf-8"))


# ----------------------------------------------------------------------------------------------
# docs/formats.md
# ----------------------------------------------------------------------------------------------

def test_formats_doc_has_one_tagged_example_per_format():
    tags = [tag for tag, _ in FORMAT_BLOCKS]
    untagged = [tag for tag in tags if tag not in READERS]
    assert not untagged, (f"docs/formats.md: ```toml block(s) tagged {untagged}; tag each with "
                          f"its format, one of {sorted(READERS)}, so the test reads it")
    assert sorted(set(tags)) == sorted(READERS), f"formats without an example: " \
        f"{sorted(set(READERS) - set(tags))}"


def test_readme_links_formats_doc():
    assert "docs/formats.md" in README.read_text(encoding="utf-8")


def _check_objective(obj):
    assert obj.name == "grip first, travel limited" and obj.baseline == "B20"
    assert obj.total_weight == pytest.approx(1.0)
    assert dict(obj.limits["shock_travel_rms_LR"]) == {"max_ratio": 1.25, "max": 0.02}


def _check_constraints(cons):
    # imperial in the file: 225 lbf/(in/s), 2250 lbf, 2 in/s
    np.testing.assert_allclose(cons.bump_low_slope[1], to_si(225.0, "damping", "imperial"))
    np.testing.assert_allclose(cons.max_force_n, to_si(2250.0, "force", "imperial"))
    assert cons.rebound_high_slope[1] == np.inf and cons.digressive
    assert cons.ratio == pytest.approx((0.0508, 1.0, 3.0))
    assert (cons.adjust_reference, cons.adjust_range) == ("DM", 0.3)
    check_constraints(curve_space(), cons, read_shock_library(DEMO_LIBRARY_PATH))


def _check_whatif(ps):
    kinds = [f.kind for f in ps.factors]
    if kinds == ["click", "fade"]:  # the adjustable shocks' example
        assert ps.factors[0].adjusters == ("ls",) and ps.factors[0].levels == (-1, 0, 1)
        assert ps.factors[1].part == "low-speed" and ps.factors[1].targets == ("id:TTX",)
        assert len(ps.perturbations) == 1 + 3 + 2
        return
    assert kinds == ["shock_scale", "shock_lag", "spring_rate", "arb_rate", "drive_scale",
                     "drive_window"]
    rear = ps.factors[2]
    np.testing.assert_allclose(rear.baseline_rate, to_si(588.0, "stiffness", "imperial"))
    # "add" rates are in the file's units (lbf/in)
    np.testing.assert_allclose(ps.factors[3].levels, to_si(np.array([-100.0, 100.0]),
                                                           "stiffness", "imperial"))
    # nominal + 4 corners x 2 + 1 + 2 + 2 + 1 + 1
    assert len(ps.perturbations) == 1 + 8 + 1 + 2 + 2 + 1 + 1


def _check_rig(rig):
    assert (rig.name, rig.swap_min, rig.run_overhead_min) == ("8-post, two mechanics", 4.5, 2.0)


def _check_channel_map(cmap):
    assert cmap.channels["shock_velocity_LF"].gain_si == pytest.approx(-0.0254)
    assert cmap.channels["aero_roll"].units == "kN*m"
    raw = {s.source: np.array([4.0]) for s in cmap.channels.values()}
    x = apply_channel_map(cmap, raw)
    np.testing.assert_allclose(x["tire_force_LF"], [500.0])  # 0.5 kN/unit x (4 - 3)


def _check_bump_stops(stops):
    # imperial in the file: 0.3 in, 180 lbf at 0.2 in beyond contact
    assert stops.ids == ("BS-F", "BS-R")
    np.testing.assert_allclose(stops["BS-F"].gap_m, to_si(0.3, "displacement", "imperial"))
    np.testing.assert_allclose(stops["BS-F"].force(to_si(0.5, "displacement", "imperial")),
                               to_si(180.0, "force", "imperial"))


def _check_dyno_map(dmap):
    assert list(dmap.columns) == ["time", "force", "displacement", "temperature"]
    force, disp = dmap.columns["force"], dmap.columns["displacement"]
    np.testing.assert_allclose(force.convert([10.0]), -to_si(10.0, "force", "imperial"))
    np.testing.assert_allclose(disp.convert([3.0]), to_si(1.0, "displacement", "imperial"))
    np.testing.assert_allclose(dmap.columns["temperature"].convert([212.0]), 100.0)


def _check_track_map(cmap):
    assert cmap.time == "Time" and set(cmap.channels) >= {
        f"shock_travel_{c}" for c in CORNERS} | {"speed"}
    np.testing.assert_allclose(cmap.channels["speed"].to_si([36.0]), [10.0])
    np.testing.assert_allclose(cmap.channels["shock_travel_LF"].to_si([35.0]), [0.010])
    np.testing.assert_allclose(cmap.channels["shock_travel_LR"].to_si([10.0]), [-0.010])


def _check_aero(model):
    if model.kind == "constant":
        assert model.loads(55.0).downforce_n == pytest.approx(5200.0)
    elif model.kind == "speed_table":
        assert model.loads(50.0).downforce_n == pytest.approx(4350.0)
    else:  # imperial: the middle node at 150 mph
        got = model.loads(to_si(2640.0, "velocity", "imperial"),
                          ride_height_front_m=to_si(2.0, "displacement", "imperial"),
                          ride_height_rear_m=to_si(3.2, "displacement", "imperial"))
        np.testing.assert_allclose(got.downforce_n, to_si(1240.0, "force", "imperial"))


CHECKS = {"objective": _check_objective, "constraints": _check_constraints,
          "whatif": _check_whatif, "rig": _check_rig, "channel-map": _check_channel_map,
          "bump-stops": _check_bump_stops, "dyno-map": _check_dyno_map,
          "track-map": _check_track_map, "aero": _check_aero}


@pytest.mark.parametrize("tag, body", FORMAT_BLOCKS,
                         ids=[f"{j}-{tag}" for j, (tag, _) in enumerate(FORMAT_BLOCKS)])
def test_formats_doc_example_reads(tag, body, tmp_path):
    reader, _ = READERS[tag]
    path = tmp_path / f"{tag}.toml"
    path.write_text(body, encoding="utf-8")
    result = reader(path)
    CHECKS[tag](result)


@pytest.mark.parametrize("tag, body", FORMAT_BLOCKS,
                         ids=[f"{j}-{tag}" for j, (tag, _) in enumerate(FORMAT_BLOCKS)])
def test_formats_doc_example_with_a_typo_is_refused(tag, body, tmp_path):
    # the readers are strict, so the read above checks every key of the example
    reader, error = READERS[tag]
    first, rest = body.split("\n", 1)
    path = tmp_path / f"{tag}.toml"
    path.write_text(f"{first}\nnmae = \"typo\"\n{rest}", encoding="utf-8")
    with pytest.raises(error, match="nmae"):
        reader(path)


# ----------------------------------------------------------------------------------------------
# the demo's inputs
# ----------------------------------------------------------------------------------------------

def _same_crate(got, want):
    assert list(got) == list(want)
    for sid in want:
        a, b = got[sid], want[sid]
        assert (type(a), a.count, a.description) == (type(b), b.count, b.description), sid
        np.testing.assert_allclose(a.lag_s, b.lag_s, rtol=RTOL_ROUND_TRIP, err_msg=sid)
        np.testing.assert_allclose(a.force(V_CHECK_M_S), b.force(V_CHECK_M_S),
                                   rtol=RTOL_ROUND_TRIP, atol=1e-9, err_msg=sid)


@pytest.mark.parametrize("units", ["imperial", "SI"])
def test_demo_inputs_read_back(units, tmp_path):
    paths = write_demo_inputs(tmp_path, units=units)
    assert list(paths) == list(DEMO_INPUT_FILES)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(DEMO_INPUT_FILES)  # nothing else
    # the crate: the built-in one, in the demo's units
    assert tomllib.loads(paths["crate.toml"].read_text())["units"] == units
    _same_crate(read_shock_library(paths["crate.toml"]), read_shock_library(DEMO_LIBRARY_PATH))
    # the car: the paper's
    assert paths["car.toml"].read_bytes() == EXAMPLE_VEHICLE_PATH.read_bytes()
    car, paper = read_vehicle(paths["car.toml"]), example_vehicle()
    for f in dataclasses.fields(paper):
        np.testing.assert_array_equal(getattr(car, f.name), getattr(paper, f.name), f.name)
    # the objective: the default
    assert read_objective(paths["objective.toml"]) == default_objective()
    # the constraints: within 6 % of the defaults (round numbers), and feasible
    cons = read_curve_constraints(paths["constraints.toml"])
    ref = default_constraints()
    for key in ("bump_low_slope", "bump_high_slope", "rebound_low_slope", "rebound_high_slope",
                "max_force_n"):
        np.testing.assert_allclose(getattr(cons, key), getattr(ref, key), rtol=0.06, err_msg=key)
    assert cons.ratio[1:] == (1.0, 3.0)
    crate = read_shock_library(paths["crate.toml"])
    for symmetry in SYMMETRIES:
        check_constraints(curve_space(symmetry=symmetry), cons, crate)
    # the what-if: the README's example
    ps = read_perturbations(paths["whatif.toml"])
    assert ps.design == "monte-carlo" and len(ps.perturbations) == 51
    readme = [tomllib.loads(body) for _, body in _toml_blocks(README.read_text(encoding="utf-8"))
              if "shockplan-whatif/1" in body]
    assert readme == [tomllib.loads(paths["whatif.toml"].read_text())]
    # the channel map: every channel to itself, SI, sign 1
    cmap = read_channel_map(paths["rig_map.toml"])
    assert list(cmap.channels) == list(ALL_CHANNELS)
    for c, spec in cmap.channels.items():
        assert (spec.source, spec.sign, spec.gain_si, spec.offset) == (c, 1, 1.0, 0.0), c


def test_demo_rig_map_maps_the_demo_session_as_is(tmp_path):
    # the demo's session, cut to one 2 s run: its channels through the map are unchanged
    plan = default_plan()
    plan = dataclasses.replace(plan, runs=(dataclasses.replace(plan.runs[0], duration_s=2.0),))
    run = simulate_session(plan, example_vehicle(), progress=False).runs[0]
    paths = write_demo_inputs(tmp_path, units=plan.units, channels=run.channels)
    x = apply_channel_map(read_channel_map(paths["rig_map.toml"]), run.channels)
    assert list(x) == list(run.channels)
    for c in run.channels:
        np.testing.assert_array_equal(x[c], run.channels[c], c)


def test_demo_inputs_refuse_existing_files_before_writing(tmp_path):
    (tmp_path / "whatif.toml").write_text("mine")
    with pytest.raises(FileExistsError, match="whatif.toml"):
        write_demo_inputs(tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ["whatif.toml"]  # nothing written
    assert (tmp_path / "whatif.toml").read_text() == "mine"
    write_demo_inputs(tmp_path, overwrite=True)
    assert read_perturbations(tmp_path / "whatif.toml").design == "monte-carlo"


@pytest.mark.parametrize("kwargs, match", [
    ({"units": "metric"}, "unknown unit system"),
    ({"channels": ()}, "not canonical"),
    ({"channels": ("wheelloader_LF", "tyre_force_LF")}, "tyre_force_LF"),
])
def test_demo_inputs_bad_arguments(kwargs, match, tmp_path):
    with pytest.raises(ValueError, match=match):
        write_demo_inputs(tmp_path, **kwargs)
    assert not any(tmp_path.iterdir())


def test_demo_rig_map_of_a_4_post_session(tmp_path):
    channels = [c for c in ALL_CHANNELS if c not in RIG_INPUTS[:3]]
    cmap = read_channel_map(write_demo_inputs(tmp_path, channels=channels)["rig_map.toml"])
    assert list(cmap.channels) == channels
