"""Tests of ident.models.bumpstops: bump stops, packers and bumpstops.toml."""

from __future__ import annotations

import pickle
import tomllib

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from ident.errors import BumpStopError, SessionError
from ident.models.bumpstops import (
    NO_BUMP_STOP,
    PACKER_GAP_ATOL_M,
    BumpStop,
    BumpStopLibrary,
    check_packer,
    parse_bump_stop_id,
    read_bump_stops,
    resolve_corner_stops,
    write_bump_stops,
)

IN_M = 0.0254  # in -> m, by definition
LBF_N = 4.4482216152605  # lbf -> N, by definition
RTOL_ROUND_TRIP = 1e-12  # float64 written with repr, plus one SI <-> imperial factor
ATOL_FORCE_N = 1e-9  # the table's interpolation in float64 on forces of ~1e3 N
RTOL_FD = 1e-6  # central difference of a piecewise-linear force inside one segment

# the spec's example: contact 15 mm from rest, progressive
GAP_M = 0.015
TRAVEL_M = [0.0, 0.005, 0.010, 0.020]
FORCE_N = [0.0, 400.0, 1500.0, 6000.0]
SLOPES_N_M = [80_000.0, 220_000.0, 450_000.0]  # of the three segments

SPEC_TOML = """\
units = "SI"

[[bump_stop]]
id = "BS-F"
gap = 0.015
travel = [0.0, 0.005, 0.010, 0.020]
force = [0.0, 400.0, 1500.0, 6000.0]

[[bump_stop]]
id = "BS-R"
gap = 0.010
travel = [0.0, 0.01]
force = [0.0, 2000.0]
description = "rear, linear"
"""


@pytest.fixture
def stop():
    return BumpStop("BS-F", GAP_M, TRAVEL_M, FORCE_N)


@pytest.fixture
def library(tmp_path):
    path = tmp_path / "bumpstops.toml"
    path.write_text(SPEC_TOML)
    return read_bump_stops(path)


# ---------------------------------------------------------------- force and stiffness


@pytest.mark.parametrize("packer_m", [0.0, 0.004])
def test_force_known_answers(stop, packer_m):
    """Zero up to contact at gap - packer, the table beyond, its last slope past its end."""
    contact = GAP_M - packer_m
    x = contact + np.array([-0.010, -1e-6, 0.0, 0.0025, 0.005, 0.0075, 0.010, 0.020, 0.030])
    want = [0.0, 0.0, 0.0, 200.0, 400.0, 950.0, 1500.0, 6000.0, 6000.0 + 450_000.0 * 0.010]
    assert_allclose(stop.force(x, packer_m=packer_m), want, rtol=0, atol=ATOL_FORCE_N)


def test_a_packer_shifts_the_curve_by_its_thickness(stop, rng):
    x = rng.uniform(-0.01, 0.05, 200)
    assert_allclose(stop.force(x, packer_m=0.003), stop.force(x + 0.003), rtol=0,
                    atol=ATOL_FORCE_N)
    assert_allclose(stop.stiffness(x, packer_m=0.003), stop.stiffness(x + 0.003), rtol=0,
                    atol=ATOL_FORCE_N)


def test_stiffness_known_answers(stop):
    """0 up to and at contact; each segment's slope (at a knot, the one beyond it); the
    last slope past the table's end."""
    x = GAP_M + np.array([-0.005, 0.0, 0.001, 0.005, 0.007, 0.010, 0.015, 0.020, 0.040])
    want = [0.0, 0.0, *SLOPES_N_M[:1], SLOPES_N_M[1], SLOPES_N_M[1], SLOPES_N_M[2],
            SLOPES_N_M[2], SLOPES_N_M[2], SLOPES_N_M[2]]
    assert_allclose(stop.stiffness(x), want, rtol=1e-12)
    assert stop.end_slope_n_m == pytest.approx(SLOPES_N_M[-1], rel=1e-12)


def test_stiffness_is_the_derivative_of_the_force(stop, rng):
    """Equivalence: a central difference of force() inside segments equals stiffness()."""
    knots = GAP_M + np.array(TRAVEL_M)
    x = rng.uniform(GAP_M - 0.01, GAP_M + 0.04, 500)
    h = 1e-7
    x = x[np.min(np.abs(x[:, None] - knots[None, :]), axis=1) > 10 * h]  # off the knots
    fd = (stop.force(x + h) - stop.force(x - h)) / (2 * h)
    assert_allclose(fd, stop.stiffness(x), rtol=RTOL_FD, atol=RTOL_FD * max(SLOPES_N_M))


def test_force_is_vectorized_and_scalar_in_scalar_out(stop):
    x = np.linspace(0.0, 0.04, 12).reshape(3, 4)
    f = stop.force(x)
    assert f.shape == (3, 4) and stop.stiffness(x).shape == (3, 4)
    assert_array_equal(f.ravel(), [stop.force(v) for v in x.ravel()])
    assert isinstance(stop.force(0.02), float) and isinstance(stop.stiffness(0.02), float)
    assert stop.force(0.02) == pytest.approx(400.0)


def test_nan_travel_gives_nan_not_zero(stop):
    out = stop.force([np.nan, 0.0, 0.03])
    assert np.isnan(out[0]) and out[1] == 0.0 and out[2] > 0
    assert np.isnan(stop.stiffness(np.nan))


def test_a_zero_gap_touches_at_rest_without_force():
    bs = BumpStop("BS-0", 0.0, [0.0, 0.01], [0.0, 1000.0])
    assert bs.force(0.0) == 0.0 and bs.force(0.005) == pytest.approx(500.0)
    assert bs.force(-0.01) == 0.0 and bs.contact_travel_m() == 0.0


def test_force_refuses_a_packer_thicker_than_the_gap(stop):
    with pytest.raises(BumpStopError, match=r"packer 16 mm .* thicker than the gap of bump "
                       r"stop 'BS-F', 15 mm .*at most 15 mm"):
        stop.force(0.02, packer_m=0.016)
    with pytest.raises(BumpStopError, match="negative"):
        stop.stiffness(0.02, packer_m=-0.001)


# ---------------------------------------------------------------- packers


def test_check_packer_accepts_up_to_the_gap(stop):
    assert check_packer(stop, 0.0, "x") == 0.0
    assert check_packer(stop, GAP_M, "x") == GAP_M
    assert check_packer(stop, GAP_M + 0.5 * PACKER_GAP_ATOL_M, "x") > GAP_M  # round-off
    assert check_packer(stop, 0.5906 * IN_M, "x") > GAP_M  # 15 mm as 4 decimals of an inch
    with pytest.raises(BumpStopError, match="thicker"):
        check_packer(stop, GAP_M + 2 * PACKER_GAP_ATOL_M, "x")
    assert stop.contact_travel_m(GAP_M) == 0.0


@pytest.mark.parametrize("packer, match", [
    (0.0151, (r"run 'b' LF: packer 15\.1 mm \(0\.5945 in\) is thicker than the gap of bump "
             r"stop 'BS-F', 15 mm \(0\.5906 in\): the stop would press on the car at rest; "
             r"use a packer of at most 15 mm \(0\.5906 in\), or a bump stop with a larger gap")),
    (0.5910 * IN_M, r"thicker than the gap"),
    (-0.001, r"run 'b' LF: packer -1 mm \(-0\.03937 in\) is negative; a packer is a spacer"),
    (float("nan"), r"run 'b' LF: packer nan is not a finite number"),
    ("3", r"is not a finite number"),
    (True, r"is not a finite number"),
])
def test_check_packer_refusals(stop, packer, match):
    with pytest.raises(BumpStopError, match=match):
        check_packer(stop, packer, "run 'b' LF")


def test_check_packer_raises_the_callers_error_family(stop):
    with pytest.raises(SessionError, match="thicker"):
        check_packer(stop, 0.02, "run 'b' LF", error=SessionError)


def test_parse_bump_stop_id():
    assert parse_bump_stop_id(" BS-F ", "x") == "BS-F"
    for none in ("none", "None", "NONE"):
        assert parse_bump_stop_id(none, "x") is None
    assert NO_BUMP_STOP == "none"
    for bad in ("", "  ", 3, None):
        with pytest.raises(BumpStopError, match=r"LF: bump stop .* is not an id"):
            parse_bump_stop_id(bad, "LF")


def test_resolve_corner_stops_takes_the_baseline_where_not_given(library):
    stops, packers = resolve_corner_stops(
        library, {"LF": None, "LR": "BS-F"}, {"LR": 0.002, "RR": 0.001},
        baseline_stops={"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": "BS-R"},
        baseline_packers_m={"RF": 0.003, "LR": 0.009})
    assert [s and s.id for s in stops] == [None, "BS-F", "BS-F", "BS-R"]
    assert packers.tolist() == [0.0, 0.003, 0.002, 0.001]
    assert resolve_corner_stops(None)[1].tolist() == [0.0] * 4  # no stops, no library


@pytest.mark.parametrize("kwargs, match", [
    ({"stops": {"LF": "BS-FF"}}, (r"setup 's': corner LF \(given bump stop\): unknown "
                                 r"bump-stop id 'BS-FF' \(did you mean 'BS-F'\?\)")),
    ({"baseline_stops": {"RR": "BS-R"}, "baseline_packers_m": {"RR": 0.011}},
     (r"corner RR \(baseline packer\): packer 11 mm .* thicker than the gap of bump stop "
     r"'BS-R', 10 mm")),
    ({"stops": {"LF": "BS-F"}, "library": None}, r"no bump-stop library was given"),
])
def test_resolve_corner_stops_refusals(library, kwargs, match):
    kwargs = {"library": library, **kwargs}
    with pytest.raises(BumpStopError, match=match):
        resolve_corner_stops(kwargs.pop("library"), where="setup 's'", **kwargs)


# ---------------------------------------------------------------- the stop's checks


@pytest.mark.parametrize("args, match", [
    (("BS", -0.001, TRAVEL_M, FORCE_N), r"gap_m = -0\.001 m is negative"),
    (("BS", float("nan"), TRAVEL_M, FORCE_N), r"gap_m must be a finite number"),
    (("BS", "0.01", TRAVEL_M, FORCE_N), r"gap_m must be a finite number"),
    (("BS", GAP_M, TRAVEL_M, [0.0, 400.0, 300.0, 6000.0]),
     r"force_n falls with travel at index 2 \(400 N at 0\.005 m, then 300 N at 0\.01 m\)"),
    (("BS", GAP_M, [0.001, 0.005, 0.01, 0.02], FORCE_N), r"travel_m starts at 0\.001 m, not 0"),
    (("BS", GAP_M, [0.0, 0.005, 0.005, 0.02], FORCE_N),
     r"travel_m is not strictly increasing at index 2"),
    (("BS", GAP_M, [0.0, 0.01, 0.005, 0.02], FORCE_N),
     r"travel_m is not strictly increasing at index 2"),
    (("BS", GAP_M, [0.0, np.nan, 0.01, 0.02], FORCE_N), r"travel_m\[1\] is nan, not finite"),
    (("BS", GAP_M, TRAVEL_M, [0.0, 400.0, np.inf, 6000.0]), r"force_n\[2\] is inf"),
    (("BS", GAP_M, TRAVEL_M, [10.0, 400.0, 1500.0, 6000.0]), r"force_n starts at 10 N, not 0"),
    (("BS", GAP_M, TRAVEL_M, FORCE_N[:3]), r"force_n has 3 values but travel_m has 4"),
    (("BS", GAP_M, [0.0], [0.0]), r"travel_m has 1 point\(s\)"),
    (("BS", GAP_M, TRAVEL_M, ["0", 1, 2, 3]), r"force_n\[0\] must be a number"),
    (("none", GAP_M, TRAVEL_M, FORCE_N), r"id is 'none', the word that means no bump stop"),
    ((" BS", GAP_M, TRAVEL_M, FORCE_N), r"id must be a non-empty string"),
])
def test_bump_stop_refusals(args, match):
    with pytest.raises(BumpStopError, match=match):
        BumpStop(*args)


def test_bump_stop_is_frozen_equal_by_value_and_pickles(stop):
    same = BumpStop("BS-F", GAP_M, np.array(TRAVEL_M), tuple(FORCE_N))
    assert same == stop and hash(same) == hash(stop)
    assert stop != BumpStop("BS-F", 0.016, TRAVEL_M, FORCE_N)
    assert pickle.loads(pickle.dumps(stop)) == stop
    assert eval(repr(stop), {"BumpStop": BumpStop}) == stop
    with pytest.raises(ValueError):
        stop.travel_m[0] = 1.0  # read-only
    with pytest.raises(AttributeError):
        stop.gap_m = 0.0


# ---------------------------------------------------------------- library and file


def test_read_the_spec_example(library, tmp_path):
    assert library.ids == ("BS-F", "BS-R") and len(library) == 2
    assert library.source == str(tmp_path / "bumpstops.toml")
    assert library["BS-F"] == BumpStop("BS-F", GAP_M, TRAVEL_M, FORCE_N)
    assert library.get("BS-R").description == "rear, linear"
    assert library.get("BS-X", None) is None


def test_unknown_id_names_the_file_the_ids_and_the_nearest(library, tmp_path):
    with pytest.raises(BumpStopError) as info:
        library.get("BS-Q", where="run 'b' bump_stops LF")
    msg = str(info.value)
    assert msg.startswith("run 'b' bump_stops LF: unknown bump-stop id 'BS-Q' (did you mean")
    assert str(tmp_path / "bumpstops.toml") in msg and "['BS-F', 'BS-R']" in msg
    assert 'write "none"' in msg


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_write_read_round_trip(library, tmp_path, units):
    path = write_bump_stops(library, tmp_path / "out.toml", units=units)
    doc = tomllib.loads(path.read_text())
    assert doc["units"] == units and [t["id"] for t in doc["bump_stop"]] == ["BS-F", "BS-R"]
    back = read_bump_stops(path)
    for a, b in zip(library.values(), back.values(), strict=True):
        assert (a.id, a.description) == (b.id, b.description)
        assert b.gap_m == pytest.approx(a.gap_m, rel=RTOL_ROUND_TRIP)
        assert_allclose(b.travel_m, a.travel_m, rtol=RTOL_ROUND_TRIP)
        assert_allclose(b.force_n, a.force_n, rtol=RTOL_ROUND_TRIP)
    if units == "SI":
        assert back == library  # exact: repr floats
    else:
        assert doc["bump_stop"][0]["gap"] == pytest.approx(GAP_M / IN_M, rel=1e-12)


def test_read_imperial_converts_to_si(tmp_path):
    path = tmp_path / "b.toml"
    path.write_text('units = "imperial"\n[[bump_stop]]\nid = "B"\ngap = 0.5\n'
                    'travel = [0.0, 0.25]\nforce = [0.0, 100.0]\n')
    bs = read_bump_stops(path)["B"]
    assert bs.gap_m == pytest.approx(0.5 * IN_M, rel=1e-15)
    assert_allclose(bs.travel_m, [0.0, 0.25 * IN_M], rtol=1e-15)
    assert_allclose(bs.force_n, [0.0, 100.0 * LBF_N], rtol=1e-15)


def test_write_refuses_an_existing_file_unless_overwrite(library, tmp_path):
    path = write_bump_stops(library, tmp_path / "b.toml")
    with pytest.raises(FileExistsError):
        write_bump_stops(library, path)
    write_bump_stops(list(library.values())[:1], path, overwrite=True)
    assert read_bump_stops(path).ids == ("BS-F",)


_STOP = '[[bump_stop]]\nid = "B"\ngap = 0.01\ntravel = [0.0, 0.01]\nforce = [0.0, 100.0]\n'


@pytest.mark.parametrize("text, match", [
    ('[[bump_stop]]\nid = "B"\ngap = -0.01\ntravel = [0.0, 0.01]\nforce = [0.0, 100.0]\n',
     r"\[\[bump_stop\]\] #1 \('B'\): key 'gap' = -0\.01 m is negative"),
    (('[[bump_stop]]\nid = "B"\ngap = 0.01\ntravel = [0.0, 0.01, 0.02]\n'
     'force = [0.0, 100.0, 50.0]\n'), r"#1 \('B'\): key 'force' falls with travel at index 2"),
    ('[[bump_stop]]\nid = "B"\ngap = 0.01\ntravel = [0.0, nan]\nforce = [0.0, 100.0]\n',
     r"key 'travel\[1\]' is nan, not finite"),
    ('[[bump_stop]]\nid = "B"\ngap = 0.01\ntravel = [0.002, 0.01]\nforce = [0.0, 100.0]\n',
     r"key 'travel' starts at 0\.002 m, not 0"),
    ('[[bump_stop]]\nid = "B"\ngap = 0.01\ntravel = [0.0, 0.01]\n',
     r"key 'force' is missing; every bump stop has id, gap, travel and force \(in N\)"),
    ('[[bump_stop]]\nid = "B"\ngap = "0.01"\ntravel = [0.0, 0.01]\nforce = [0.0, 100.0]\n',
     r"key 'gap' must be a number, got str"),
    (_STOP.replace("gap =", "gapp ="), (r"key 'gapp' is not a key of a bump stop \(did you "
                                       r"mean 'gap'\?\)")),
    (_STOP + _STOP, (r"\[\[bump_stop\]\] #2 \('B'\): key 'id' repeats the id of "
                    r"\[\[bump_stop\]\] #1")),
    (_STOP.replace("[[bump_stop]]", "[[bump_stops]]"),
     r"unknown top-level key 'bump_stops' \(did you mean 'bump_stop'\?\)"),
    ('units = "SI"\n', r"no \[\[bump_stop\]\] tables"),
    ('name = "crate"\n' + _STOP, (r"unknown top-level key 'name'; a bump-stop library has only "
                                 r"'units' and \[\[bump_stop\]\] tables")),
    ('units = "metric"\n' + _STOP, r"key 'units': unknown unit system 'metric'"),
    ('[[bump_stop]]\nid = "none"\ngap = 0.01\ntravel = [0.0, 0.01]\nforce = [0.0, 1.0]\n',
     r"key 'id' is 'none', the word that means no bump stop"),
    ("gap = [", r"not valid TOML"),
])
def test_read_refusals_name_the_file_stop_and_key(tmp_path, text, match):
    path = tmp_path / "bumpstops.toml"
    path.write_text(text)
    with pytest.raises(BumpStopError, match=match) as info:
        read_bump_stops(path)
    assert str(info.value).startswith(str(path))


def test_read_refuses_a_missing_file(tmp_path):
    with pytest.raises(BumpStopError, match="bump-stop library not found"):
        read_bump_stops(tmp_path / "nope.toml")


def test_library_refuses_duplicates_and_strangers(stop):
    with pytest.raises(BumpStopError, match="duplicate bump-stop id 'BS-F'"):
        BumpStopLibrary([stop, stop])
    with pytest.raises(BumpStopError, match="key 'X' holds bump stop 'BS-F'"):
        BumpStopLibrary({"X": stop})
    with pytest.raises(TypeError, match="item 0 is a str, not a BumpStop"):
        BumpStopLibrary(["BS-F"])
    assert BumpStopLibrary({"BS-F": stop}) == BumpStopLibrary([stop])


# ----------------------------------------------------------------------------
# CarElements
# ----------------------------------------------------------------------------


def test_car_elements_round_trip_and_check():
    """What a model keeps of the session's elements: JSON-able, read back equal, checked."""
    import json

    from ident.models.bumpstops import CarElements

    lib = BumpStopLibrary([BumpStop("BS-F", 0.006, [0.0, 0.002, 0.01], [0.0, 200.0, 3000.0],
                                    description="front"),
                           BumpStop("BS-R", 0.008, [0.0, 0.01], [0.0, 2000.0])])
    el = CarElements(lib, {"LF": "BS-F", "RF": "BS-F"}, {"LF": 0.001},
                     [3000.0, 3000.0, 3500.0, 3500.0])
    assert el.baseline_stops == {"LF": "BS-F", "RF": "BS-F", "LR": None, "RR": None}
    assert el.baseline_packers_m == {"LF": 0.001, "RF": 0.0, "LR": 0.0, "RR": 0.0}
    doc = json.loads(json.dumps(el.to_dict()))
    back = CarElements.from_dict(doc)
    assert back.bump_stops == lib
    assert back.baseline_stops == el.baseline_stops
    assert back.baseline_packers_m == el.baseline_packers_m
    np.testing.assert_array_equal(back.static_corner_load_n, el.static_corner_load_n)
    tables = back.baseline_tables()
    assert tables[0][0] == pytest.approx(0.005) and tables[1][0] == pytest.approx(0.006)
    assert tables[2] is None
    assert "BS-F" in el.describe() and "LR 3500 N" in el.describe()
    only_loads = CarElements(None, {}, {}, [1.0, 2.0, 3.0, 4.0])
    assert only_loads.baseline_tables() is None
    assert CarElements.from_dict(only_loads.to_dict()).bump_stops is None
    with pytest.raises(BumpStopError, match="not a bump stop|BS-X"):
        CarElements(lib, {"LF": "BS-X"}, {})
    with pytest.raises(BumpStopError, match="thicker|packer"):
        CarElements(lib, {"LF": "BS-F"}, {"LF": 0.01})
    with pytest.raises(BumpStopError, match="4 finite"):
        CarElements(None, {}, {}, [1.0, 2.0])
