"""Tests of ident.models.aero: the downforce and balance model and its TOML file."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import tomli_w
from numpy.testing import assert_allclose, assert_array_equal

from ident.errors import AeroModelError
from ident.models.aero import (
    AERO_CHANNELS,
    AERO_FORMAT,
    AERO_KINDS,
    AeroLoads,
    AeroModel,
    aero_model_from_dict,
    read_aero_model,
    write_aero_model,
)

IN_M = 0.0254  # in -> m, by definition
LBF_N = 4.4482216152605  # lbf -> N, by definition
RTOL_EXACT = 1e-12  # a handful of float64 operations on numbers of ~1e3
ATOL_FORCE_N = 1e-9  # the same, absolute, where the answer is 0 N
ATOL_MOMENT_NM = 1e-9  # a*D_f - b*D_r cancelling on ~1e4 N*m
RTOL_UNITS = 1e-12  # one SI <-> imperial factor plus float text written with repr
ATOL_CORNER_M = 1e-15  # corner displacements of ~1e-3 m solved from a 3x3 system

A_M, B_M = 1.2, 1.4  # CG to front and rear axle
STATIC_BALANCE = B_M / (A_M + B_M)
TRACK_M = 1.6

CONSTANT = {"format": AERO_FORMAT, "units": "SI", "name": "low drag", "kind": "constant",
            "cg_to_front_axle": A_M, "cg_to_rear_axle": B_M, "reference_speed": 50.0,
            "downforce": 4000.0, "balance": 0.45}
TABLE = {"format": AERO_FORMAT, "kind": "speed_table", "cg_to_front_axle": A_M,
         "cg_to_rear_axle": B_M, "speed": [20.0, 40.0, 60.0],
         "downforce": [500.0, 2000.0, 4500.0], "balance": [0.40, 0.44, 0.46]}
FRONT_GRID_M = [0.03, 0.05, 0.07]
REAR_GRID_M = [0.06, 0.08]
MAP_DOWNFORCE_N = [[4400.0, 4200.0], [4000.0, 3600.0], [3500.0, 3300.0]]
MAP_BALANCE = [[0.46, 0.44], [0.45, 0.43], [0.44, 0.40]]
MAP = {"format": AERO_FORMAT, "kind": "ride_height_map", "cg_to_front_axle": A_M,
       "cg_to_rear_axle": B_M, "reference_speed": 50.0, "ride_height_front": FRONT_GRID_M,
       "ride_height_rear": REAR_GRID_M, "downforce": MAP_DOWNFORCE_N, "balance": MAP_BALANCE}
DOCS = {"constant": CONSTANT, "speed_table": TABLE, "ride_height_map": MAP}

#: The spec's corner transform z_corner = T [z, theta, phi], rows LF, RF, LR, RR.
T_SPEC = np.array([[1.0, TRACK_M / 2, -A_M], [1.0, -TRACK_M / 2, -A_M],
                   [1.0, TRACK_M / 2, B_M], [1.0, -TRACK_M / 2, B_M]])


def _model(kind, **changes):
    doc = copy.deepcopy(DOCS[kind])
    doc.update(changes)
    return aero_model_from_dict(doc)


def _write(tmp_path, doc, name="aero.toml"):
    path = tmp_path / name
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    return path


# ---------------------------------------------------------------- constant


def test_constant_reference_speed_gives_the_downforce_and_half_speed_a_quarter():
    loads = _model("constant").loads([50.0, 25.0, 0.0, 100.0])
    assert_allclose(loads.downforce_n, [4000.0, 1000.0, 0.0, 16000.0], rtol=RTOL_EXACT)
    assert_allclose(loads.balance, 0.45, rtol=0)
    assert loads.outside_share == 0.0


def test_constant_channels_known_answer():
    """heave = -D; pitch = a * 0.45 D - b * 0.55 D; no roll."""
    loads = _model("constant").loads([50.0, 25.0])
    ch = loads.channels
    assert tuple(ch) == AERO_CHANNELS
    assert_allclose(ch["aero_heave"], [-4000.0, -1000.0], rtol=RTOL_EXACT)
    assert_allclose(ch["aero_pitch"], [A_M * 1800 - B_M * 2200, A_M * 450 - B_M * 550],
                    rtol=RTOL_EXACT)
    assert_array_equal(ch["aero_roll"], [0.0, 0.0])


@pytest.mark.parametrize("kind", AERO_KINDS)
def test_loads_are_read_only_float64_shaped_like_the_speed(kind):
    model = _model(kind)
    speed = np.linspace(0.0, 80.0, 6).reshape(2, 3)
    rh = ({"ride_height_front_m": 0.05, "ride_height_rear_m": 0.07}
          if model.needs_ride_heights else {})
    loads = model.loads(speed, **rh)
    assert isinstance(loads, AeroLoads)
    for arr in (*loads.channels.values(), loads.downforce_n, loads.balance):
        assert arr.shape == (2, 3) and arr.dtype == np.float64 and not arr.flags.writeable
    scalar = model.loads(30.0, **rh)
    assert scalar.channels["aero_heave"].shape == () and scalar.downforce_n.shape == ()
    assert scalar.downforce_n == model.loads([30.0], **rh).downforce_n[0]
    empty = model.loads(np.zeros(0), **({k: np.zeros(0) for k in rh}))
    assert empty.downforce_n.shape == (0,) and empty.outside_share == 0.0
    assert model.needs_ride_heights == (kind == "ride_height_map")


def test_loads_settings_explain_the_result(tmp_path):
    model = read_aero_model(_write(tmp_path, TABLE, "wing.toml"))
    s = model.loads([10.0, 30.0, 90.0, 50.0]).settings
    assert (s["name"], s["kind"]) == ("wing", "speed_table")
    assert s["source"] == str(tmp_path / "wing.toml")
    assert (s["cg_to_front_axle_m"], s["cg_to_rear_axle_m"], s["n_samples"]) == (A_M, B_M, 4)
    assert (s["share_below_table"], s["share_above_table"]) == (0.25, 0.25)


# ---------------------------------------------------------------- speed table


def test_speed_table_interpolates_linearly_between_its_speeds():
    loads = _model("speed_table").loads([20.0, 30.0, 40.0, 55.0, 60.0])
    assert_allclose(loads.downforce_n, [500.0, 1250.0, 2000.0, 3875.0, 4500.0], rtol=RTOL_EXACT)
    assert_allclose(loads.balance, [0.40, 0.42, 0.44, 0.455, 0.46], rtol=RTOL_EXACT)
    assert loads.outside_share == 0.0  # the table's own ends are inside it


def test_speed_table_off_its_ends_scales_the_end_points_by_speed_squared():
    """Below 20 m/s: 500 N * (v / 20)^2 with the first balance; above 60 m/s:
    4500 N * (v / 60)^2 with the last; both counted outside."""
    loads = _model("speed_table").loads([0.0, 10.0, 20.0, 30.0, 60.0, 90.0])
    assert_allclose(loads.downforce_n, [0.0, 125.0, 500.0, 1250.0, 4500.0, 10125.0],
                    rtol=RTOL_EXACT, atol=ATOL_FORCE_N)
    assert_allclose(loads.balance, [0.40, 0.40, 0.40, 0.42, 0.46, 0.46], rtol=RTOL_EXACT)
    assert loads.outside_share == pytest.approx(3 / 6, rel=RTOL_EXACT)
    assert loads.settings["share_below_table"] == pytest.approx(2 / 6, rel=RTOL_EXACT)
    assert loads.settings["share_above_table"] == pytest.approx(1 / 6, rel=RTOL_EXACT)


def test_speed_table_from_zero_has_nothing_below_it():
    model = _model("speed_table", speed=[0.0, 40.0], downforce=[0.0, 2000.0], balance=0.44)
    loads = model.loads([0.0, 20.0, 80.0])
    assert_allclose(loads.downforce_n, [0.0, 1000.0, 8000.0], rtol=RTOL_EXACT)
    assert loads.settings["share_below_table"] == 0.0
    assert loads.outside_share == pytest.approx(1 / 3, rel=RTOL_EXACT)
    assert_array_equal(model.balance, [0.44, 0.44])  # one number, one per speed


def test_a_speed_table_of_v_squared_is_the_constant_model(rng):
    """Equivalence: a table sampled from D_ref (v / v_ref)^2 with one balance gives the
    constant model's loads inside the table (linear interpolation of a parabola is exact
    at the nodes only, so compare there) and everywhere off its ends."""
    speeds = np.array([10.0, 30.0, 50.0, 70.0])
    table = _model("speed_table", speed=speeds.tolist(),
                   downforce=(4000.0 * (speeds / 50.0) ** 2).tolist(), balance=0.45)
    constant = _model("constant")
    v = np.concatenate([speeds, rng.uniform(0.0, 10.0, 50), rng.uniform(70.0, 120.0, 50)])
    got, want = table.loads(v), constant.loads(v)
    for name in AERO_CHANNELS:
        assert_allclose(got.channels[name], want.channels[name], rtol=RTOL_EXACT,
                        atol=ATOL_MOMENT_NM)


# ---------------------------------------------------------------- ride-height map


def _bilinear(f, r, values, x, y):
    """Hand-written bilinear interpolation inside the grid (the reference)."""
    i = np.clip(np.searchsorted(f, x, side="right") - 1, 0, len(f) - 2)
    j = np.clip(np.searchsorted(r, y, side="right") - 1, 0, len(r) - 2)
    u = (x - f[i]) / (f[i + 1] - f[i])
    w = (y - r[j]) / (r[j + 1] - r[j])
    v = np.asarray(values)
    return ((1 - u) * (1 - w) * v[i, j] + u * (1 - w) * v[i + 1, j]
            + (1 - u) * w * v[i, j + 1] + u * w * v[i + 1, j + 1])


def test_map_at_a_node_and_a_cell_midpoint():
    model = _model("ride_height_map")
    loads = model.loads([50.0, 50.0, 25.0], ride_height_front_m=[0.05, 0.04, 0.04],
                        ride_height_rear_m=[0.08, 0.07, 0.07])
    # node (0.05, 0.08); the midpoint of the first cell is the mean of its 4 nodes
    assert_allclose(loads.downforce_n, [3600.0, 4050.0, 4050.0 / 4], rtol=RTOL_EXACT)
    assert_allclose(loads.balance, [0.43, 0.445, 0.445], rtol=RTOL_EXACT)
    assert loads.outside_share == 0.0


def test_map_is_bilinear_inside_the_grid(rng):
    model = _model("ride_height_map")
    hf = rng.uniform(0.03, 0.07, 200)
    hr = rng.uniform(0.06, 0.08, 200)
    v = rng.uniform(0.0, 90.0, 200)
    loads = model.loads(v, ride_height_front_m=hf, ride_height_rear_m=hr)
    f, r = np.array(FRONT_GRID_M), np.array(REAR_GRID_M)
    assert_allclose(loads.downforce_n, _bilinear(f, r, MAP_DOWNFORCE_N, hf, hr) * (v / 50.0) ** 2,
                    rtol=RTOL_EXACT)
    assert_allclose(loads.balance, _bilinear(f, r, MAP_BALANCE, hf, hr), rtol=RTOL_EXACT)


def test_map_clamps_to_its_edges_outside_the_grid_and_counts():
    model = _model("ride_height_map")
    hf = [0.02, 0.09, 0.04, 0.03, 0.07]
    hr = [0.07, 0.10, 0.05, 0.06, 0.08]  # the last two on the grid's corners: inside
    loads = model.loads(np.full(5, 50.0), ride_height_front_m=hf, ride_height_rear_m=hr)
    # (0.03, 0.07) edge midpoint; (0.07, 0.08) corner; (0.04, 0.06) edge midpoint
    assert_allclose(loads.downforce_n, [4300.0, 3300.0, 4200.0, 4400.0, 3300.0],
                    rtol=RTOL_EXACT)
    assert_allclose(loads.balance, [0.45, 0.40, 0.455, 0.46, 0.40], rtol=RTOL_EXACT)
    assert loads.outside_share == pytest.approx(3 / 5, rel=RTOL_EXACT)
    assert loads.settings["share_outside_map"] == loads.outside_share


def test_map_ride_heights_broadcast_to_the_speed():
    model = _model("ride_height_map")
    loads = model.loads([50.0, 25.0], ride_height_front_m=0.05, ride_height_rear_m=0.08)
    assert_allclose(loads.downforce_n, [3600.0, 900.0], rtol=RTOL_EXACT)


def test_other_kinds_ignore_ride_heights():
    model = _model("constant")
    got = model.loads([40.0], ride_height_front_m=[0.01], ride_height_rear_m=[0.2])
    assert_array_equal(got.downforce_n, model.loads([40.0]).downforce_n)


# ---------------------------------------------------------------- signs (the spec's T)


@pytest.mark.parametrize("kind", AERO_KINDS)
def test_loads_are_the_axle_forces_through_the_spec_transform(kind, rng):
    """Virtual work: [heave, roll, pitch] = T^T f with f the corner forces (up positive),
    -D_f / 2 at each front corner and -D_r / 2 at each rear one."""
    model = _model(kind)
    v = rng.uniform(0.0, 90.0, 100)
    rh = ({"ride_height_front_m": rng.uniform(0.02, 0.08, 100),
           "ride_height_rear_m": rng.uniform(0.05, 0.09, 100)}
          if model.needs_ride_heights else {})
    loads = model.loads(v, **rh)
    d, bal = loads.downforce_n, loads.balance
    f_corner = -np.stack([bal * d / 2, bal * d / 2, (1 - bal) * d / 2, (1 - bal) * d / 2])
    generalized = T_SPEC.T @ f_corner  # (3, samples): heave, roll, pitch
    got = np.stack([loads.channels[c] for c in AERO_CHANNELS])
    assert_allclose(got, generalized, rtol=RTOL_EXACT, atol=ATOL_MOMENT_NM)


@pytest.mark.parametrize("balance, front_lower", [(0.60, True), (0.45, False),
                                                  (STATIC_BALANCE, None)])
def test_a_forward_balance_sinks_the_front_more(balance, front_lower):
    """On a car whose springs carry its weight without pitching (corner rates in the ratio
    of the static loads, k_f a = k_r b), the front corners sink more than the rear when the
    balance is forward of b / (a + b), less when behind, and as much at it (pitch 0)."""
    model = _model("constant", balance=balance)
    loads = model.loads(50.0)
    k = 1e5  # N/m per m of lever: any positive rate
    rates = np.array([k * B_M, k * B_M, k * A_M, k * A_M])
    stiffness = T_SPEC.T @ np.diag(rates) @ T_SPEC
    q = np.linalg.solve(stiffness, [float(loads.channels[c]) for c in AERO_CHANNELS])
    z = T_SPEC @ q  # corner displacements [m], up positive
    assert np.all(z < 0)  # downforce pushes every corner down
    assert z[0] == pytest.approx(z[1], abs=ATOL_CORNER_M)  # no roll
    if front_lower is None:
        assert float(loads.channels["aero_pitch"]) == pytest.approx(0.0, abs=ATOL_MOMENT_NM)
        assert z[0] == pytest.approx(z[2], abs=ATOL_CORNER_M)
        assert model.static_balance == pytest.approx(STATIC_BALANCE, rel=RTOL_EXACT)
    else:
        assert (float(loads.channels["aero_pitch"]) > 0) == front_lower  # rear up
        assert (z[0] < z[2] - ATOL_CORNER_M) == front_lower


# ---------------------------------------------------------------- units and files


#: TOML key -> factor from the imperial unit to SI, written out here (not from the module).
IMPERIAL_TO_SI = {"cg_to_front_axle": IN_M, "cg_to_rear_axle": IN_M, "reference_speed": IN_M,
                  "speed": IN_M, "ride_height_front": IN_M, "ride_height_rear": IN_M,
                  "downforce": LBF_N, "balance": 1.0}


@pytest.mark.parametrize("kind", AERO_KINDS)
def test_imperial_file_equals_the_si_one_converted(kind, tmp_path):
    imperial = copy.deepcopy(DOCS[kind])
    imperial["units"] = "imperial"
    si = copy.deepcopy(imperial)
    si["units"] = "SI"
    for key, factor in IMPERIAL_TO_SI.items():
        if key in si:
            si[key] = (np.asarray(si[key], dtype=float) * factor).tolist()
    a = read_aero_model(_write(tmp_path, imperial, "imperial.toml"))
    b = read_aero_model(_write(tmp_path, si, "si.toml"))
    for name in ("cg_to_front_axle_m", "cg_to_rear_axle_m", "reference_speed_m_s",
                 "speed_grid_m_s", "ride_height_front_grid_m", "ride_height_rear_grid_m",
                 "downforce_n", "balance"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert_allclose(x, y, rtol=RTOL_UNITS, err_msg=name)


def test_a_document_without_units_takes_the_callers():
    doc = {k: v for k, v in CONSTANT.items() if k != "units"}
    got = aero_model_from_dict(doc, units="imperial")
    assert got.downforce_n == pytest.approx(4000.0 * LBF_N, rel=RTOL_UNITS)
    doc["units"] = "SI"  # the document's own key wins
    assert aero_model_from_dict(doc, units="imperial").downforce_n == 4000.0


@pytest.mark.parametrize("kind", AERO_KINDS)
def test_write_then_read_gives_the_model_back(kind, tmp_path):
    model = _model(kind)
    path = write_aero_model(model, tmp_path / "out" / "aero.toml")
    assert path == tmp_path / "out" / "aero.toml"
    back = read_aero_model(path)
    assert back == model and back.source == str(path) and model.source is None
    assert hash(back) == hash(model)
    assert sorted(p.name for p in path.parent.iterdir()) == ["aero.toml"]  # no temp file
    imperial = read_aero_model(write_aero_model(model, tmp_path / "imp.toml", units="imperial"))
    for name in ("cg_to_front_axle_m", "downforce_n", "balance"):
        assert_allclose(getattr(imperial, name), getattr(model, name), rtol=RTOL_UNITS)
    assert read_aero_model(tmp_path / "imp.toml").to_dict()["units"] == "SI"


def test_write_refuses_an_existing_file_unless_told(tmp_path):
    model = _model("constant")
    path = write_aero_model(model, tmp_path / "aero.toml")
    with pytest.raises(FileExistsError, match="already exists"):
        write_aero_model(_model("speed_table"), path)
    assert read_aero_model(path) == model  # untouched
    write_aero_model(_model("speed_table"), path, overwrite=True)
    assert read_aero_model(path).kind == "speed_table"
    with pytest.raises(TypeError, match="must be an AeroModel"):
        write_aero_model(CONSTANT, tmp_path / "x.toml")
    with pytest.raises(AeroModelError, match="unknown unit system 'metric'"):
        write_aero_model(model, tmp_path / "x.toml", units="metric")


def test_one_balance_is_written_as_one_number(tmp_path):
    path = write_aero_model(_model("speed_table", balance=0.44), tmp_path / "a.toml")
    assert "balance = 0.44\n" in path.read_text(encoding="utf-8")


def test_name_defaults_to_the_files_name(tmp_path):
    doc = {k: v for k, v in CONSTANT.items() if k != "name"}
    assert read_aero_model(_write(tmp_path, doc, "monza.toml")).name == "monza"
    assert read_aero_model(_write(tmp_path, CONSTANT)).name == "low drag"
    assert aero_model_from_dict(doc).name == "aero"  # no file to name it after


def test_models_compare_by_value_not_source():
    assert _model("ride_height_map") == _model("ride_height_map")
    assert _model("constant") != _model("constant", balance=0.46)
    assert _model("constant") != _model("speed_table")
    model = _model("speed_table")
    with pytest.raises(ValueError, match="read-only"):
        model.downforce_n[0] = 1.0


# ---------------------------------------------------------------- refusals


def _drop(key):
    return lambda doc: doc.pop(key)


def _set(key, value):
    return lambda doc: doc.__setitem__(key, value)


# (kind, change to its document, what the message must say)
BAD_FILES = [
    ("constant", _drop("format"), r"key 'format' is missing; an aero model starts with "
     r"format = \"shockplan-aero/1\""),
    ("constant", _set("format", "shockplan-aero/2"), r"key 'format' is 'shockplan-aero/2'"),
    ("constant", _set("balanse", 0.4), r"unknown key 'balanse' \(did you mean 'balance'\?\)"),
    ("constant", _set("units", "metric"), r"key 'units': unknown unit system 'metric'; use "
     r"\"SI\" or \"imperial\""),
    ("constant", _drop("kind"), r"key 'kind' is missing; give kind = one of 'constant'"),
    ("speed_table", _set("kind", "speed-table"), r"key 'kind' is 'speed-table', unknown \(did "
     r"you mean 'speed_table'\?\); give one of"),
    ("constant", _set("speed", [10.0, 20.0]), r"key 'speed' does not belong to kind "
     r"'constant'; remove it \(kind 'constant' has reference_speed, downforce, balance\)"),
    ("constant", _drop("downforce"), r"key 'downforce' is missing; kind 'constant' needs "
     r"cg_to_front_axle, .* \(file units: downforce in N\)"),
    ("ride_height_map", _drop("ride_height_rear"), r"key 'ride_height_rear' is missing"),
    ("constant", _set("name", 3), r"key 'name' must be a non-empty string, got 3"),
    ("constant", _set("downforce", "4000"), r"key 'downforce' must be a number, got '4000'; "
     "write numbers without quotes"),
    ("speed_table", _set("speed", 20.0), r"key 'speed' must be an array of numbers"),
    ("constant", _set("cg_to_front_axle", 0.0), r"key 'cg_to_front_axle' = 0 m is not "
     r"positive; give the distance from the centre of gravity to the axle, > 0"),
    ("ride_height_map", _set("cg_to_rear_axle", -1.4), r"key 'cg_to_rear_axle' = -1.4 m is "
     "not positive"),
    ("constant", _set("reference_speed", 0.0), r"key 'reference_speed' = 0 m/s is not "
     r"positive; give the speed at which the downforce is given"),
    ("constant", _set("balance", 45.0), r"key 'balance' = 45 is outside \[0, 1\]; give the "
     r"front axle's share of the downforce, 0 to 1 .*not a percentage"),
    ("speed_table", _set("balance", [0.4, -0.1, 0.5]), r"key 'balance' = -0.1 at \[1\] is "
     r"outside \[0, 1\]"),
    ("ride_height_map", _set("balance", [[0.4, 0.4], [0.4, 1.5], [0.4, 0.4]]),
     r"key 'balance' = 1.5 at \[1\]\[1\] is outside \[0, 1\]"),
    ("speed_table", _set("downforce", [500.0, 2000.0]), r"key 'downforce' has 2 values but "
     r"speed has 3; give one downforce per speed"),
    ("speed_table", _set("balance", [0.4, 0.5]), r"key 'balance' has 2 values but speed has "
     r"3; give one balance per speed, or one number"),
    ("speed_table", _set("speed", [20.0, 60.0, 40.0]), r"key 'speed' is not strictly "
     r"increasing at index 2 \(60 then 40 m/s\); sort the points and remove repeats"),
    ("speed_table", _set("speed", [-5.0, 40.0, 60.0]), r"key 'speed' starts at -5 m/s, below "
     r"0; give speeds as magnitudes"),
    ("speed_table", lambda d: d.update(speed=[0.0, 40.0, 60.0]), r"key 'downforce' is 500 N "
     r"at speed 0; give 0 at speed 0"),
    ("ride_height_map", _set("ride_height_front", [0.03, 0.03, 0.07]), r"key "
     r"'ride_height_front' is not strictly increasing at index 1 \(0.03 then 0.03 m\)"),
    ("ride_height_map", lambda d: d.update(ride_height_rear=[0.06], downforce=[[1.0]] * 3,
                                           balance=0.4),
     r"key 'ride_height_rear' has 1 point\(s\); give at least 2 points"),
    ("ride_height_map", _set("downforce", MAP_DOWNFORCE_N[:2]), r"key 'downforce' has shape "
     r"2 x 2 but the grid is 3 front x 2 rear ride heights; give one row per front ride "
     r"height"),
    ("ride_height_map", _set("balance", [[0.4, 0.4, 0.4]] * 3), r"key 'balance' has shape 3 x "
     r"3 but the grid is 3 front x 2 rear"),
    ("ride_height_map", _set("downforce", [[4400.0, 4200.0], [4000.0], [3500.0, 3300.0]]),
     r"key 'downforce' is a map of the wrong shape: row 0 has 2 values but row 1 has 1"),
    ("ride_height_map", _set("downforce", [4400.0, 4200.0, 4000.0]), r"key 'downforce' must "
     r"be a 2-D array"),
    ("constant", _set("downforce", float("nan")), r"key 'downforce' is nan, not finite; give a "
     r"finite number \[N\]"),
    ("speed_table", _set("downforce", [500.0, 2000.0, float("inf")]), r"key 'downforce\[2\]' "
     r"is inf, not finite"),
    ("ride_height_map", _set("balance", [[0.4, 0.4], [0.4, float("nan")], [0.4, 0.4]]),
     r"key 'balance\[1\]\[1\]' is nan, not finite"),
    ("constant", _set("downforce", -300.0), r"key 'downforce' is negative \(-300 N\): a lifting "
     r"car is out of scope of this model; give downforce >= 0"),
    ("ride_height_map", _set("downforce", [[4400.0, -10.0], [4000.0, 3600.0], [3500.0, 0.0]]),
     r"key 'downforce' is negative \(-10 N at \[0\]\[1\]\): a lifting car is out of scope"),
]


@pytest.mark.parametrize("kind, change, match", BAD_FILES,
                         ids=[f"{j}-{k}" for j, (k, _, _) in enumerate(BAD_FILES)])
def test_bad_files_are_refused_naming_the_file_the_key_and_the_fix(kind, change, match,
                                                                    tmp_path):
    doc = copy.deepcopy(DOCS[kind])
    change(doc)
    path = _write(tmp_path, doc)
    with pytest.raises(AeroModelError, match=match) as info:
        read_aero_model(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and message.count("; ") >= 1


def test_an_imperial_files_numbers_are_quoted_as_written(tmp_path):
    """The model checks SI values; a refusal of an imperial file quotes the file's number."""
    doc = dict(CONSTANT, units="imperial", downforce=-4000.0)
    with pytest.raises(AeroModelError, match=r"checked in SI; the file has downforce = "
                                             r"-4000.0 lbf"):
        read_aero_model(_write(tmp_path, doc))
    doc = dict(CONSTANT, units="imperial", balance=1.5)   # no unit: nothing to convert
    with pytest.raises(AeroModelError, match=r"= 1.5 is outside \[0, 1\];"):
        read_aero_model(_write(tmp_path, doc))


def test_a_missing_or_broken_file_is_refused(tmp_path):
    with pytest.raises(AeroModelError, match="aero model not found; check the path"):
        read_aero_model(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("format = \n", encoding="utf-8")
    with pytest.raises(AeroModelError, match="not valid TOML"):
        read_aero_model(bad)
    with pytest.raises(TypeError, match="a mapping"):
        aero_model_from_dict([("format", AERO_FORMAT)])


@pytest.mark.parametrize("kwargs, match", [
    ({"name": " "}, r"aero model ' ': name must be a non-empty string"),
    ({"kind": "constnat"}, r"kind 'constnat' is unknown \(did you mean 'constant'\?\)"),
    ({"speed_grid_m_s": [10.0, 20.0]}, r"speed_grid_m_s is given but kind 'constant' does "
     r"not use it; leave it out"),
    ({"balance": None}, r"balance is missing \(kind 'constant' needs it\)"),
    ({"cg_to_rear_axle_m": float("inf")}, r"cg_to_rear_axle_m is inf, not finite"),
])
def test_direct_construction_refusals_name_the_attribute(kwargs, match):
    args = {"name": "wing", "kind": "constant", "cg_to_front_axle_m": A_M,
            "cg_to_rear_axle_m": B_M, "reference_speed_m_s": 50.0, "downforce_n": 4000.0,
            "balance": 0.45, **kwargs}
    with pytest.raises(AeroModelError, match=match):
        AeroModel(**args)


RH = {"ride_height_front_m": 0.05, "ride_height_rear_m": 0.07}


@pytest.mark.parametrize("kind, speed, extra, error, match", [
    ("constant", [10.0, 20.0, -1.0, -2.0], {}, AeroModelError, r"aero model 'low drag': "
     r"speed_m_s has 2 negative value\(s\) \(first -1 m/s at sample 2\); give the speed as a "
     r"magnitude"),
    ("speed_table", [10.0, np.nan], {}, AeroModelError, r"speed_m_s has 1 NaN or infinite "
     r"value\(s\) \(first at sample 1\); fill or cut the log"),
    ("ride_height_map", [np.inf], RH, AeroModelError, r"speed_m_s has 1 NaN or infinite"),
    ("constant", ["fast"], {}, TypeError, r"speed_m_s must be numbers \[m/s\], got list"),
    ("ride_height_map", [50.0], {}, AeroModelError, r"\(kind 'ride_height_map'\) needs "
     r"ride_height_front_m and ride_height_rear_m; pass the front and rear ride heights"),
    ("ride_height_map", [50.0], {"ride_height_front_m": 0.05}, AeroModelError,
     r"needs ride_height_rear_m; pass"),
    ("ride_height_map", [50.0, 60.0], {**RH, "ride_height_rear_m": [0.07, np.nan]},
     AeroModelError, r"ride_height_rear_m has 1 NaN or infinite value\(s\) \(first at sample "
     r"1\)"),
    ("ride_height_map", [50.0, 60.0], {**RH, "ride_height_front_m": [0.05, 0.05, 0.05]},
     AeroModelError, r"ride_height_front_m has shape \(3,\) but the speed has \(2,\); give one "
     r"ride height per speed sample"),
])
def test_bad_loads_arguments_are_refused(kind, speed, extra, error, match):
    with pytest.raises(error, match=match):
        _model(kind).loads(speed, **extra)


# ---------------------------------------------------------------- docs/formats.md examples

#: The examples of the "Aero model TOML" section proposed for docs/formats.md, as written
#: there (kept here until that section exists and tests/test_demo_inputs.py reads it).
FORMATS_EXAMPLES = {
    "constant": '''\
format = "shockplan-aero/1"
units = "SI"
name = "Monza, low downforce"
kind = "constant"
cg_to_front_axle = 1.25      # m
cg_to_rear_axle = 1.35       # m
reference_speed = 55.0       # m/s (198 km/h)
downforce = 5200.0           # N at the reference speed
balance = 0.46               # 46 % on the front axle
''',
    "speed_table": '''\
format = "shockplan-aero/1"
name = "high downforce, from the coast-down"
kind = "speed_table"
cg_to_front_axle = 1.25                        # m
cg_to_rear_axle = 1.35                         # m
speed = [20.0, 40.0, 60.0, 80.0]               # m/s, strictly increasing
downforce = [650.0, 2700.0, 6000.0, 9800.0]    # N at each speed
balance = [0.44, 0.45, 0.47, 0.48]             # or one number for every speed
''',
    "ride_height_map": '''\
format = "shockplan-aero/1"
units = "imperial"
name = "GT wind-tunnel map"
kind = "ride_height_map"
cg_to_front_axle = 49.0                # in
cg_to_rear_axle = 53.0                 # in
reference_speed = 2640.0               # in/s (150 mph)
ride_height_front = [1.6, 2.0, 2.4]    # in, as the front lasers log them
ride_height_rear = [2.8, 3.2, 3.6]     # in
downforce = [                          # lbf at the reference speed, [front][rear]
  [1250.0, 1310.0, 1340.0],
  [1180.0, 1240.0, 1270.0],
  [1100.0, 1150.0, 1180.0],
]
balance = [                            # front share, [front][rear] (or one number)
  [0.46, 0.48, 0.50],
  [0.44, 0.46, 0.48],
  [0.42, 0.44, 0.46],
]
''',
}


@pytest.mark.parametrize("kind", AERO_KINDS)
def test_the_formats_examples_read(kind, tmp_path):
    path = tmp_path / "aero.toml"
    path.write_text(FORMATS_EXAMPLES[kind], encoding="utf-8")
    model = read_aero_model(path)
    assert model.kind == kind
    if kind == "constant":
        assert model.loads(55.0).downforce_n == pytest.approx(5200.0, rel=RTOL_EXACT)
    elif kind == "speed_table":
        assert model.loads(50.0).downforce_n == pytest.approx(4350.0, rel=RTOL_EXACT)
    else:  # the middle node at 150 mph
        got = model.loads(2640.0 * IN_M, ride_height_front_m=2.0 * IN_M,
                          ride_height_rear_m=3.2 * IN_M)
        assert got.downforce_n == pytest.approx(1240.0 * LBF_N, rel=RTOL_UNITS)
        assert got.balance == pytest.approx(0.46, rel=RTOL_EXACT)
    first, rest = FORMATS_EXAMPLES[kind].split("\n", 1)
    path.write_text(f"{first}\nnmae = \"typo\"\n{rest}", encoding="utf-8")
    with pytest.raises(AeroModelError, match="nmae"):
        read_aero_model(path)
