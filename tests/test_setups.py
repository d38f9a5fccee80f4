"""Tests of planner.setups: the Setup type, setups CSV files, enumeration and swaps."""

import copy
import dataclasses
import doctest
import pickle
import re
from itertools import product

import pandas as pd
import pytest

import planner.setups as setups_mod
from ident.data.channels import CORNERS
from planner.errors import PlannerError
from ident.models.bumpstops import BumpStop, BumpStopLibrary
from ident.models.library import ShockLibrary
from ident.models.shocks import LinearShock
from planner.setups import (
    DEFAULT_MAX_SETUPS,
    SYMMETRIES,
    Setup,
    enumerate_setups,
    read_setups,
    resolve_baseline,
    setup_space,
    setups_from_baseline,
    setups_to_frame,
    write_setups,
)

SPEC_CSV = "setup,LF,RF,LR,RR\nsoft-front,D8,D8,B20,B20\nbaseline,B20,B20,B20,B20\n"


def _lib(n=10, counts=None, prefix="S"):
    """A library of `n` linear shocks S1..Sn; `counts` maps id -> inventory."""
    counts = counts or {}
    return ShockLibrary.from_models(
        [LinearShock(f"{prefix}{k}", 500.0 * k, count=counts.get(f"{prefix}{k}"))
         for k in range(1, n + 1)], source="shocks.toml")


def _setup(name, lf, rf, lr, rr):
    return Setup(name, {"LF": lf, "RF": rf, "LR": lr, "RR": rr})


@pytest.fixture
def spec_lib():
    return ShockLibrary.from_models([LinearShock("B20", 3502.5), LinearShock("D8", 1400.0)])


# ---------------------------------------------------------------- Setup


def test_setup_ids_in_corner_order_and_read_only():
    s = Setup("x", {"RR": "d", "LR": "c", "RF": "b", "LF": "a"})
    assert s.ids() == ("a", "b", "c", "d")
    assert list(s.shocks) == list(CORNERS)
    with pytest.raises(TypeError):
        s.shocks["LF"] = "z"
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.name = "y"


def test_setup_equality_hash_and_repr():
    a = _setup("x", "A", "A", "B", "B")
    b = Setup("x", {"LF": "A", "RF": "A", "LR": "B", "RR": "B"})
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
    assert a != _setup("y", "A", "A", "B", "B")
    assert eval(repr(a)) == a


def test_setup_pickles_and_copies():
    a = _setup("x", "A", "A", "B", "B")
    for b in (pickle.loads(pickle.dumps(a)), copy.deepcopy(a), dataclasses.replace(a)):
        assert b == a and b.ids() == a.ids()


def test_setup_resolve_returns_models_in_corner_order(spec_lib):
    models = _setup("soft-front", "D8", "D8", "B20", "B20").resolve(spec_lib)
    assert [m.id for m in models] == ["D8", "D8", "B20", "B20"]
    assert models[0] is spec_lib["D8"]


def test_setup_resolve_unknown_id_names_setup_corner_and_known_ids(spec_lib):
    with pytest.raises(PlannerError, match=r"setup 'x': corner LR: unknown shock id 'Z9'; "
                       r"the shock library has \['B20', 'D8'\]"):
        _setup("x", "B20", "B20", "Z9", "B20").resolve(spec_lib)


BAD_SETUPS = [
    ("empty name", lambda: _setup("", "A", "A", "A", "A"), r"setup name '' is not valid"),
    ("padded name", lambda: _setup(" x", "A", "A", "A", "A"), r"setup name ' x' is not valid"),
    ("missing corner", lambda: Setup("x", {"LF": "A", "RF": "A", "LR": "A"}),
     r"setup 'x': no shock for corner\(s\) \['RR'\]"),
    ("unknown corner", lambda: Setup("x", {"LF": "A", "RF": "A", "LR": "A", "RR": "A",
                                           "LM": "A"}),
     r"setup 'x': shocks names unknown corner\(s\) \['LM'\]"),
    ("empty id", lambda: _setup("x", "A", "", "A", "A"), r"setup 'x': corner RF: shock id ''"),
    ("id not str", lambda: _setup("x", "A", "A", 20, "A"), r"corner LR: shock id 20"),
]


@pytest.mark.parametrize("make, match", [c[1:] for c in BAD_SETUPS],
                         ids=[c[0] for c in BAD_SETUPS])
def test_bad_setups_raise(make, match):
    with pytest.raises(PlannerError, match=match):
        make()


def test_setup_shocks_must_be_a_mapping():
    with pytest.raises(TypeError, match="mapping corner -> shock id"):
        Setup("x", ["A", "A", "A", "A"])


# ---------------------------------------------------------------- enumeration


@pytest.mark.parametrize("symmetry, axles, expected", [
    ("left-right", "independent", 10 ** 2),
    ("none", "independent", 10 ** 4),
    ("left-right", "same", 10),
    ("none", "same", 10 ** 2),
])
def test_enumeration_counts_for_ten_shocks(symmetry, axles, expected):
    out = enumerate_setups(_lib(10), symmetry=symmetry, axles=axles)
    assert len(out) == expected
    assert len({s.ids() for s in out}) == expected  # all distinct
    assert len({s.name for s in out}) == expected


@pytest.mark.parametrize("axles", ["independent", "same"])
def test_symmetry_all_is_left_right_with_the_same_axles(axles):
    """``symmetry="all"`` (every corner one shock, optimize's name) enumerates exactly what
    left-right symmetry with ``axles="same"`` does: same setups, order and names."""
    assert "all" in SYMMETRIES
    lib = _lib(6, counts={"S2": 2})
    ref = enumerate_setups(lib, symmetry="left-right", axles="same")
    got = enumerate_setups(lib, symmetry="all", axles=axles)
    assert got == ref and [s.name for s in got] == [s.name for s in ref]
    assert all(len(set(s.ids())) == 1 for s in got) and len(got) == 5  # S2 x4: only 2


def test_enumeration_respects_symmetry_and_axles():
    for s in enumerate_setups(_lib(4)):
        lf, rf, lr, rr = s.ids()
        assert lf == rf and lr == rr
    for s in enumerate_setups(_lib(4), symmetry="none", axles="same"):
        lf, rf, lr, rr = s.ids()
        assert lr == lf and rr == rf


def test_enumeration_order_and_names_are_deterministic():
    lib = _lib(3)
    out = enumerate_setups(lib)
    expected = [(a, a, b, b) for a, b in product(lib.ids, lib.ids)]  # rear varies fastest
    assert [s.ids() for s in out] == expected
    assert out[1].name == "S1/S1/S2/S2"
    per_corner = enumerate_setups(lib, symmetry="none")
    assert [s.ids() for s in per_corner] == list(product(lib.ids, repeat=4))
    assert enumerate_setups(lib) == out


def test_spelled_out_and_callable_names():
    out = enumerate_setups(_lib(2), name_format="LF={LF} RF={RF} LR={LR} RR={RR}")
    assert out[1].name == "LF=S1 RF=S1 LR=S2 RR=S2"
    out = enumerate_setups(_lib(2), name_format=lambda ids: f"front {ids['LF']}, rear "
                           f"{ids['LR']}")
    assert out[2].name == "front S2, rear S1"
    # a template with only the varying corners is fine under symmetry
    assert enumerate_setups(_lib(2), name_format="{LF}|{LR}")[3].name == "S2|S2"


def test_inventory_skips_setups_needing_more_units_than_exist():
    lib = _lib(2, counts={"S1": 2})
    per_corner = enumerate_setups(lib, symmetry="none")
    # 16 combinations minus S1 at 3 corners (4 ways) or 4 corners (1)
    assert len(per_corner) == 16 - 5
    assert all(s.ids().count("S1") <= 2 for s in per_corner)
    assert len(enumerate_setups(lib, symmetry="none", respect_inventory=False)) == 16
    # symmetric: S1 on both axles needs 4 units
    assert [s.name for s in enumerate_setups(lib)] == ["S1/S1/S2/S2", "S2/S2/S1/S1",
                                                        "S2/S2/S2/S2"]


@pytest.mark.parametrize("count, expected", [(0, 1), (1, 1), (2, 3), (3, 3), (4, 4)])
def test_inventory_counts_under_symmetry(count, expected):
    assert len(enumerate_setups(_lib(2, counts={"S1": count}))) == expected


def test_fixed_corner_fixes_its_symmetric_partner():
    out = enumerate_setups(_lib(5), fixed={"LF": "S3"})
    assert len(out) == 5
    assert all(s.ids()[:2] == ("S3", "S3") for s in out)
    out = enumerate_setups(_lib(5), fixed={"LF": "S3", "RF": "S3"})  # agreeing: fine
    assert len(out) == 5


def test_fixed_corner_without_symmetry_and_fixed_overrides_candidates():
    out = enumerate_setups(_lib(3), symmetry="none", fixed={"RR": "S2"})
    assert len(out) == 27
    assert {s.shocks["RR"] for s in out} == {"S2"}
    out = enumerate_setups(_lib(3), fixed={"LR": "S3"}, shocks=["S1", "S2"])
    assert [s.ids() for s in out] == [("S1", "S1", "S3", "S3"), ("S2", "S2", "S3", "S3")]


def test_fixed_counts_towards_inventory():
    out = enumerate_setups(_lib(2, counts={"S1": 2}), fixed={"LF": "S1"})
    assert [s.ids() for s in out] == [("S1", "S1", "S2", "S2")]


def test_per_axle_and_per_corner_candidates():
    lib = _lib(4)
    out = enumerate_setups(lib, shocks={"front": ["S1", "S2"], "rear": ["S4"]})
    assert [s.ids() for s in out] == [("S1", "S1", "S4", "S4"), ("S2", "S2", "S4", "S4")]
    out = enumerate_setups(lib, symmetry="none", shocks={"front": ["S1"], "RF": ["S2", "S3"],
                                                         "rear": ["S4"]})
    assert [s.ids() for s in out] == [("S1", "S2", "S4", "S4"), ("S1", "S3", "S4", "S4")]
    # only one axle given: the other takes every id; duplicates are dropped
    assert len(enumerate_setups(lib, shocks={"rear": ["S1", "S1"]})) == 4
    # axles="same": the ids common to both axles
    out = enumerate_setups(lib, axles="same", shocks={"front": ["S3", "S1", "S2"],
                                                      "rear": ["S2", "S3"]})
    assert [s.ids()[0] for s in out] == ["S3", "S2"]


def test_max_setups_guards_and_large_enumerations_work():
    lib = _lib(18)  # per corner: 18**4 = 104,976
    with pytest.raises(PlannerError, match=r"104,976 candidate setups .* exceed "
                       r"max_setups=100,000; use symmetry='left-right'"):
        enumerate_setups(lib, symmetry="none")
    assert DEFAULT_MAX_SETUPS == 100_000
    out = enumerate_setups(lib, symmetry="none", max_setups=200_000)
    assert len(out) == 18 ** 4
    assert out[-1].ids() == ("S18",) * 4
    assert len(enumerate_setups(_lib(3), symmetry="none", max_setups=None)) == 81
    with pytest.raises(PlannerError, match="exceed max_setups=80"):
        enumerate_setups(_lib(3), symmetry="none", max_setups=80)


BAD_ENUMERATIONS = [
    ("symmetry", dict(symmetry="diagonal"), r"symmetry='diagonal' is unknown; use one of "
     r"\['left-right', 'all', 'none'\]"),
    ("axles", dict(axles="swapped"), r"axles='swapped' is unknown"),
    ("fixed corner", dict(fixed={"LM": "S1"}), r"fixed has the corner 'LM'; corners are"),
    ("fixed id", dict(fixed={"LF": "X"}), r"fixed\['LF'\]: unknown shock id 'X'; shock library "
     r"shocks.toml has \['S1', 'S2', 'S3'\]"),
    ("fixed conflict", dict(fixed={"LF": "S1", "RF": "S2"}),
     r"fixed LF='S1' and RF='S2' conflict: .* corners \['LF', 'RF'\] share one shock"),
    ("fixed conflict same axles", dict(symmetry="none", axles="same",
                                       fixed={"RF": "S1", "RR": "S2"}),
     r"fixed RF='S1' and RR='S2' conflict"),
    ("unknown candidate", dict(shocks=["S1", "B20"]), r"shocks: unknown shock id 'B20'"),
    ("unknown axle key", dict(shocks={"middle": ["S1"]}), r"shocks has the key 'middle'"),
    ("unknown id per axle", dict(shocks={"rear": ["S9"]}),
     r"shocks\['rear'\]: unknown shock id 'S9'"),
    ("empty candidates", dict(shocks=[]), r"shocks is empty; give at least one shock id"),
    ("no common ids", dict(axles="same", shocks={"front": ["S1"], "rear": ["S2"]}),
     r"corners \['LF', 'RF', 'LR', 'RR'\] share one shock but their candidate lists have no "
     r"id in common"),
    ("max_setups zero", dict(max_setups=0), r"max_setups=0 must be a positive integer"),
    ("max_setups float", dict(max_setups=1e6), r"max_setups=1000000.0 must be"),
    ("bad template", dict(name_format="{LF}/{XX}"), r"name_format '\{LF\}/\{XX\}' is not a "
     r"valid template"),
    ("name collision", dict(symmetry="none", name_format="{LF}-{LR}"),
     r"name_format gives the same name 'S1-S2' to \['S1', 'S2', 'S2', 'S2'\] and"),
    ("inventory leaves nothing", dict(shocks=["S1"], fixed=None, max_setups=None),
     r"none of the 1 candidate setups fits the inventory"),
]


@pytest.mark.parametrize("options, match", [c[1:] for c in BAD_ENUMERATIONS],
                         ids=[c[0] for c in BAD_ENUMERATIONS])
def test_bad_enumerations_raise(options, match):
    with pytest.raises(PlannerError, match=match):
        enumerate_setups(_lib(3, counts={"S1": 1}), **options)


def test_enumeration_type_errors():
    with pytest.raises(TypeError, match="library must be a ShockLibrary"):
        enumerate_setups(["S1", "S2"])
    with pytest.raises(TypeError, match="shocks must be a list of shock ids"):
        enumerate_setups(_lib(2), shocks="S1")
    with pytest.raises(TypeError, match="fixed must be a mapping"):
        enumerate_setups(_lib(2), fixed=["S1"])
    with pytest.raises(PlannerError, match="the shock library is empty"):
        enumerate_setups(ShockLibrary.from_models([]))


@pytest.mark.parametrize("options", [
    {}, {"symmetry": "none"}, {"symmetry": "none", "axles": "same"}, {"symmetry": "all"},
    {"symmetry": "none", "fixed": {"LR": "S3"}, "shocks": {"front": ["S5", "S1", "S2"]}},
    {"symmetry": "none", "respect_inventory": False},
])
def test_setup_space_decodes_to_the_enumeration(options):
    """The one enumeration: the space decoded chunk by chunk (any chunk boundaries) gives
    enumerate_setups' setups, in its order, with its names and inventory filter."""
    lib = _lib(5, counts={"S1": 1, "S4": 2})
    ref = enumerate_setups(lib, **options)
    space = setup_space(lib, **options)
    got = []
    for start in range(0, len(space), 7):
        index, _ = space.chunk(start, start + 7)
        got += space.setups(index)
    assert got == list(ref)
    assert space.first() == space.find(ref[0].ids())


# ---------------------------------------------------------------- the baseline


def test_resolve_baseline_syntax(spec_lib):
    """One syntax: a Setup, a listed name, one shock id (every corner) or four ids separated
    by commas; a setup built from ids is named by `name` (a str or a callable)."""
    base = resolve_baseline("B20", spec_lib)
    assert base == _setup("baseline", "B20", "B20", "B20", "B20")
    assert resolve_baseline(" D8 , D8,B20,B20 ", spec_lib) == \
        _setup("baseline", "D8", "D8", "B20", "B20")
    assert resolve_baseline(["D8", "D8", "B20", "B20"], spec_lib).ids() == \
        ("D8", "D8", "B20", "B20")
    sweep_name = lambda given: f"all-{given[0]}" if len(given) == 1 else "/".join(given)  # noqa: E731
    assert resolve_baseline("B20", spec_lib, name=sweep_name).name == "all-B20"
    assert resolve_baseline("D8,D8,B20,B20", spec_lib, name=sweep_name).name == "D8/D8/B20/B20"
    own = _setup("mine", "D8", "B20", "B20", "B20")
    assert resolve_baseline(own, spec_lib) is own
    assert resolve_baseline(None, spec_lib) is None
    assert resolve_baseline(None, spec_lib, default="D8").ids() == ("D8",) * 4


def test_resolve_baseline_against_listed_setups(spec_lib):
    """A name picks a listed setup; shocks equal to a listed setup's give that setup (no
    second row); nothing given is the first listed setup; `find` looks beyond the list."""
    listed = enumerate_setups(spec_lib)
    assert resolve_baseline("D8/D8/B20/B20", spec_lib, setups=listed) is listed[2]
    assert resolve_baseline("D8,D8,B20,B20", spec_lib, setups=listed) is listed[2]
    assert resolve_baseline(_setup("x", "B20", "B20", "B20", "B20"), spec_lib,
                            setups=listed) is listed[0]
    assert resolve_baseline(None, spec_lib, setups=listed) is listed[0]
    assert resolve_baseline(None, spec_lib, setups=listed, default=listed[1].name) is listed[1]
    other = _setup("found", "D8", "B20", "D8", "B20")
    assert resolve_baseline("D8,B20,D8,B20", spec_lib, find=lambda ids: other) is other


@pytest.mark.parametrize("baseline, kwargs, error, match", [
    ("B20/B20/D8/D8", {}, PlannerError, r"separate the shock ids with commas, 'B20,B20,D8,D8'"),
    ("B20,D8", {}, PlannerError, r"give one shock id \(every corner\) or four"),
    ("Z9", {}, PlannerError, r"baseline 'Z9' is neither a shock id nor four ids"),
    ("Z9", {"setups": (_setup("a", "B20", "B20", "B20", "B20"),)}, PlannerError,
     r"baseline setup 'Z9' is not among the setups"),
    ("B20,B20,B20,Z9", {"where": "rank"}, PlannerError,
     r"setup 'baseline': corner RR: unknown shock id 'Z9'"),
    (_setup("a", "D8", "D8", "D8", "D8"), {"setups": (_setup("a", "B20", "B20", "B20", "B20"),)},
     PlannerError, r"has the name of a listed setup with other shocks"),
    (3, {"where": "sweep"}, TypeError, r"sweep: baseline must be a Setup"),
])
def test_bad_baselines_raise(spec_lib, baseline, kwargs, error, match):
    with pytest.raises(error, match=match):
        resolve_baseline(baseline, spec_lib, **kwargs)


# ---------------------------------------------------------------- swaps from a baseline


def test_single_corner_swaps_from_baseline():
    lib = _lib(4)
    base = _setup("baseline", "S1", "S1", "S1", "S1")
    out = setups_from_baseline(base, lib)
    assert out[0] is base
    assert len(out) == 1 + 4 * 3  # every corner, every other shock
    assert out[1].name == "baseline LF=S2"
    assert out[1].ids() == ("S2", "S1", "S1", "S1")
    for s in out[1:]:
        assert sum(a != b for a, b in zip(s.ids(), base.ids())) == 1


def test_axle_swaps_dedupe_and_inventory():
    lib = _lib(3, counts={"S3": 1})
    base = _setup("b", "S1", "S2", "S1", "S1")
    out = setups_from_baseline(base, lib, corners=("RF", "front", "rear"),
                               include_baseline=False)
    names = [s.name for s in out]
    # RF=S1 and front=S1... give S1 S1 S1 S1: only the first is kept; S3 twice needs 2 units
    assert names == ["b RF=S1", "b RF=S3", "b front=S2", "b rear=S2"]
    assert out[2].ids() == ("S2", "S2", "S1", "S1")
    unlimited = setups_from_baseline(base, lib, corners=("front",), respect_inventory=False)
    assert [s.name for s in unlimited] == ["b", "b front=S1", "b front=S2", "b front=S3"]
    only = setups_from_baseline(base, lib, corners="LR", shocks=["S3"])
    assert [s.name for s in only] == ["b", "b LR=S3"]


def test_bad_swaps_raise():
    lib = _lib(2)
    with pytest.raises(PlannerError, match=r"corners has 'middle'; give corners"):
        setups_from_baseline(_setup("b", "S1", "S1", "S1", "S1"), lib, corners=["middle"])
    with pytest.raises(PlannerError, match=r"setup 'b': corner LF: unknown shock id 'X'"):
        setups_from_baseline(_setup("b", "X", "S1", "S1", "S1"), lib)
    with pytest.raises(PlannerError, match=r"setups_from_baseline: shocks: unknown shock id"):
        setups_from_baseline(_setup("b", "S1", "S1", "S1", "S1"), lib, shocks=["Q"])
    with pytest.raises(TypeError, match="baseline must be a Setup"):
        setups_from_baseline({"LF": "S1"}, lib)


# ---------------------------------------------------------------- files


def test_spec_example_reads_in_order(tmp_path, spec_lib):
    path = tmp_path / "setups.csv"
    path.write_text(SPEC_CSV)
    out = read_setups(path, spec_lib)
    assert [s.name for s in out] == ["soft-front", "baseline"]
    assert out[0] == _setup("soft-front", "D8", "D8", "B20", "B20")
    assert read_setups(path) == out  # the library is optional


def test_csv_round_trip(tmp_path):
    lib = _lib(3)
    setups = enumerate_setups(lib, symmetry="none") + (_setup("with, comma", "S1", "S2",
                                                              "S3", "S1"),)
    path = write_setups(setups, tmp_path / "out" / "setups.csv")
    assert path.read_text().splitlines()[:2] == ["setup,LF,RF,LR,RR,units",
                                                 "S1/S1/S1/S1,S1,S1,S1,S1,SI"]
    assert read_setups(path, lib) == setups
    write_setups(setups, path, units="imperial", overwrite=True)
    assert path.read_text().splitlines()[0] == "setup,LF,RF,LR,RR,units"
    assert pd.read_csv(path)["setup"].tolist() == [s.name for s in setups]
    assert set(pd.read_csv(path)["units"]) == {"imperial"}
    assert read_setups(path, lib) == setups


@pytest.mark.parametrize("preamble", [
    "# units: imperial\n",  # as shockplan writes it
    "# units: SI,,,,\n",  # saved back by a spreadsheet: the row padded with commas
    "\ufeff# exported by the rig PC\n\n# Units = si\n",  # a BOM, a comment, a blank line
])
def test_leading_comment_lines_are_skipped_and_lines_keep_their_numbers(tmp_path, preamble):
    path = tmp_path / "setups.csv"
    path.write_text(preamble + "setup,LF,RF,LR,RR\na,B20,B20,B20,B20\nb,B20,,B20,B20\n",
                    encoding="utf-8")
    line = preamble.count("\n") + 3  # the file's own line number of setup 'b'
    with pytest.raises(PlannerError, match=rf"line {line} \(setup 'b'\): column 'RF' is empty"):
        read_setups(path)


def test_a_bad_unit_marker_is_refused(tmp_path):
    path = tmp_path / "setups.csv"
    path.write_text("# units: metric\nsetup,LF,RF,LR,RR\na,B20,B20,B20,B20\n")
    with pytest.raises(PlannerError, match=r"setups.csv: line 1 .*unknown unit system 'metric'"):
        read_setups(path)


def test_write_refuses_to_overwrite(tmp_path):
    path = write_setups([_setup("a", "A", "A", "A", "A")], tmp_path / "s.csv")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_setups([_setup("b", "B", "B", "B", "B")], path)
    write_setups([_setup("b", "B", "B", "B", "B")], path, overwrite=True)
    assert [s.name for s in read_setups(path)] == ["b"]


def test_write_rejects_duplicate_names_and_non_setups(tmp_path):
    a = _setup("a", "A", "A", "A", "A")
    with pytest.raises(PlannerError, match=r"setups 0 and 1 are both named 'a'"):
        write_setups([a, a], tmp_path / "s.csv")
    with pytest.raises(TypeError, match="item 1 is a dict, not a Setup"):
        write_setups([a, {"LF": "A"}], tmp_path / "s.csv")
    assert not (tmp_path / "s.csv").exists()


def test_extra_columns_are_ignored_and_layout_is_forgiving(tmp_path):
    """A predictions-like file: other column order, metrics, spaces, BOM, blank lines."""
    path = tmp_path / "pred.csv"
    path.write_text("\ufeffRR, LR ,setup,RF,LF,tire_force_rms_LF\n\n"
                    "B20, B20, soft-front ,D8,D8,512.5\n\nB20,B20,baseline,B20,B20,530.1\n",
                    encoding="utf-8")
    out = read_setups(path)
    assert out == (_setup("soft-front", "D8", "D8", "B20", "B20"),
                   _setup("baseline", "B20", "B20", "B20", "B20"))


def test_setups_to_frame():
    frame = setups_to_frame(enumerate_setups(_lib(2)))
    assert list(frame.columns) == list(CORNERS)
    assert frame.index.name == "setup"
    assert frame.loc["S2/S2/S1/S1", "LR"] == "S1"


BAD_FILES = [
    ("empty file", "", r"the file is empty; write the header 'setup,LF,RF,LR,RR'"),
    ("blank file", "\n\n", r"the file is empty"),
    ("header only", "setup,LF,RF,LR,RR\n", r"no setups below the header"),
    ("no setup column", "name,LF,RF,LR,RR\na,B20,B20,B20,B20\n", r"no column 'setup'"),
    ("missing corner", "setup,LF,RF,LR\na,B20,B20,B20\n",
     r"no column for corner\(s\) \['RR'\]"),
    ("unknown corner", "setup,LF,RF,LR,RR,LM\na,B20,B20,B20,B20,B20\n",
     r"column 'LM' is not a corner; corners are \['LF', 'RF', 'LR', 'RR'\]"),
    ("lower-case corner", "setup,lf,RF,LR,RR\na,B20,B20,B20,B20\n", r"column 'lf' is not a "
     r"corner"),
    ("duplicate column", "setup,LF,RF,LR,RR,LF\na,B20,B20,B20,B20,D8\n",
     r"column 'LF' appears twice"),
    ("short row", "setup,LF,RF,LR,RR\na,B20,B20,B20\n", r"line 2 has 4 fields but the header "
     r"has 5"),
    ("empty name", "setup,LF,RF,LR,RR\n,B20,B20,B20,B20\n", r"line 2: column 'setup' is empty"),
    ("empty cell", "setup,LF,RF,LR,RR\na,B20,B20,B20,B20\nb,B20, ,B20,B20\n",
     r"line 3 \(setup 'b'\): column 'RF' is empty; give a shock id"),
    ("duplicate name", "setup,LF,RF,LR,RR\na,B20,B20,B20,B20\n\na,D8,D8,D8,D8\n",
     r"line 4 \(setup 'a'\): setup name repeats line 2; give each setup a unique name"),
    ("unknown id", "setup,LF,RF,LR,RR\na,B20,B20,B20,B20\nsoft,D8,D8,B2O,B20\n",
     r"line 3 \(setup 'soft'\): column 'LR': unknown shock id 'B2O'; the shock library has "
     r"\['B20', 'D8'\]; fix the id or add the shock"),
]


@pytest.mark.parametrize("text, match", [c[1:] for c in BAD_FILES], ids=[c[0] for c in BAD_FILES])
def test_bad_setup_files_raise(tmp_path, spec_lib, text, match):
    path = tmp_path / "setups.csv"
    path.write_text(text)
    with pytest.raises(PlannerError, match=match) as info:
        read_setups(path, spec_lib)
    assert str(info.value).startswith(f"{path}: ")


def test_missing_setups_file_raises(tmp_path):
    with pytest.raises(PlannerError, match=re.escape(f"{tmp_path / 'nope.csv'}: setups file "
                                                     "not found")):
        read_setups(tmp_path / "nope.csv")


# ---------------------------------------------------------------- documentation


def test_docstring_examples_run():
    result = doctest.testmod(setups_mod, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted > 0


def test_read_ranking_baseline(tmp_path):
    """The setup a ranking's scores are ratios to: its `baseline` column, after the unit
    marker; None without the column; more than one marked is refused, naming the fix."""
    from planner.setups import read_ranking_baseline

    path = tmp_path / "ranking.csv"
    path.write_text("# units: imperial\nrank,setup,LF,RF,LR,RR,baseline\n"
                    "1,best,L28,L28,L28,L28,False\n2,base,B20,B20,B20,B20,True\n")
    assert read_ranking_baseline(path) == "base"
    path.write_text("rank,setup,LF,RF,LR,RR,baseline,units\n"  # as shockplan writes it now
                    "1,best,L28,L28,L28,L28,False,SI\n2,base,B20,B20,B20,B20,True,SI\n")
    assert read_ranking_baseline(path) == "base"
    path.write_text("setup,LF,RF,LR,RR\nbest,L28,L28,L28,L28\n")
    assert read_ranking_baseline(path) is None
    path.write_text("setup,LF,RF,LR,RR,baseline\na,B20,B20,B20,B20,True\n"
                    "b,L28,L28,L28,L28,True\n")
    with pytest.raises(PlannerError, match="marks 2 setups.*--baseline"):
        read_ranking_baseline(path)


# ---------------------------------------------------------------- bump stops and packers

IN_M = 0.0254  # in -> m, by definition
RTOL_PACKER = 1e-12  # a packer written with repr, plus one SI <-> imperial factor
ELEMENTS_CSV = (
    "# units: SI\n"
    "setup,LF,RF,LR,RR,bump_stop_LF,bump_stop_RF,bump_stop_LR,packer_LF,packer_RF\n"
    "packed,D8,D8,B20,B20,BS-F,BS-F,none,0.003,0.0025\n"
    "soft-stops,B20,B20,B20,B20,BS-S,BS-S,,,\n"
    "baseline,B20,B20,B20,B20,,,,,\n"
)


@pytest.fixture
def stops():
    return BumpStopLibrary([BumpStop("BS-F", 0.0075, [0.0, 0.01], [0.0, 3000.0]),
                            BumpStop("BS-S", 0.0050, [0.0, 0.01], [0.0, 1000.0])],
                           source="bumpstops.toml")


def test_setups_with_bump_stops_and_packers_are_read(tmp_path, spec_lib, stops):
    path = tmp_path / "setups.csv"
    path.write_text(ELEMENTS_CSV)
    packed, soft, base = read_setups(path, spec_lib, stops)
    assert packed.ids() == ("D8", "D8", "B20", "B20")
    assert dict(packed.bump_stops) == {"LF": "BS-F", "RF": "BS-F", "LR": None}  # RR: baseline's
    assert dict(packed.packers_m) == {"LF": 0.003, "RF": 0.0025}
    assert dict(soft.bump_stops) == {"LF": "BS-S", "RF": "BS-S"} and soft.packers_m is None
    assert base.bump_stops is None and base.packers_m is None  # empty cells: the baseline's
    assert base == _setup("baseline", "B20", "B20", "B20", "B20")
    assert read_setups(path) == (packed, soft, base)  # the libraries are optional


def test_packers_are_read_in_the_files_units(tmp_path):
    path = tmp_path / "setups.csv"
    body = "setup,LF,RF,LR,RR,packer_LR\na,B20,B20,B20,B20,0.1\n"
    path.write_text("# units: imperial\n" + body)
    assert read_setups(path)[0].packers_m["LR"] == pytest.approx(0.1 * IN_M, rel=1e-15)
    path.write_text(body)  # no marker: units= decides, SI by default
    assert read_setups(path)[0].packers_m["LR"] == 0.1
    assert read_setups(path, units="imperial")[0].packers_m["LR"] == pytest.approx(0.00254)
    path.write_text("# units: SI\n" + body)
    with pytest.raises(PlannerError, match=r"the file says it is in SI units .* but units says "
                       "imperial"):
        read_setups(path, units="imperial")
    # the units column (what shockplan writes) says the same as the line did
    path.write_text("setup,LF,RF,LR,RR,packer_LR,units\na,B20,B20,B20,B20,0.1,imperial\n")
    assert read_setups(path)[0].packers_m["LR"] == pytest.approx(0.1 * IN_M, rel=1e-15)
    with pytest.raises(PlannerError, match=r"the file says it is in imperial units .* but "
                       "units says SI"):
        read_setups(path, units="SI")


def test_a_units_column_is_the_files_unit_system_not_a_setups_column(tmp_path):
    """Issue 36: a setups CSV with a units column reads (the column is no setup's); a column
    with two unit systems, or one against the marker line, is refused."""
    path = tmp_path / "setups.csv"
    path.write_text("setup,LF,RF,LR,RR,units\na,B20,B20,B20,B20,SI\nb,D8,D8,B20,B20,SI\n")
    assert read_setups(path) == (_setup("a", "B20", "B20", "B20", "B20"),
                                 _setup("b", "D8", "D8", "B20", "B20"))
    path.write_text("setup,LF,RF,LR,RR,units\na,B20,B20,B20,B20,SI\nb,D8,D8,B20,B20,imperial\n")
    with pytest.raises(PlannerError, match=r"setups.csv: column 'units' says both SI and "
                       "imperial"):
        read_setups(path)
    path.write_text("# units: imperial\nsetup,LF,RF,LR,RR,units\na,B20,B20,B20,B20,SI\n")
    with pytest.raises(PlannerError, match=r"setups.csv: the line '# units: imperial' and the "
                       r"column 'units' \(SI\) disagree"):
        read_setups(path)


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_setups_with_elements_round_trip(tmp_path, spec_lib, stops, units):
    src = tmp_path / "setups.csv"
    src.write_text(ELEMENTS_CSV)
    setups = read_setups(src, spec_lib, stops)
    path = write_setups(setups, tmp_path / "out.csv", units=units)
    lines = path.read_text().splitlines()
    assert lines[0] == ("setup,LF,RF,LR,RR,bump_stop_LF,bump_stop_RF,bump_stop_LR,bump_stop_RR,"
                        "packer_LF,packer_RF,packer_LR,packer_RR,units")
    if units == "SI":
        assert lines[1:] == ["packed,D8,D8,B20,B20,BS-F,BS-F,none,,0.003,0.0025,,,SI",
                             "soft-stops,B20,B20,B20,B20,BS-S,BS-S,,,,,,,SI",
                             "baseline,B20,B20,B20,B20,,,,,,,,,SI"]
    back = read_setups(path, spec_lib, stops)
    assert [(s.name, s.ids(), s.bump_stops) for s in back] == \
        [(s.name, s.ids(), s.bump_stops) for s in setups]
    assert back[0].packers_m["RF"] == pytest.approx(0.0025, rel=RTOL_PACKER)


def test_setups_without_elements_are_written_as_before(tmp_path):
    """No bump-stop or packer columns unless a setup has some: the spec's columns, then the
    units column (issue 36)."""
    path = write_setups([_setup("a", "A", "B", "C", "D")], tmp_path / "s.csv")
    assert path.read_text() == "setup,LF,RF,LR,RR,units\na,A,B,C,D,SI\n"
    only_stops = Setup("b", dict(zip(CORNERS, "ABCD")), bump_stops={"RR": None})
    path = write_setups([only_stops], tmp_path / "t.csv")
    assert path.read_text() == ("setup,LF,RF,LR,RR,bump_stop_LF,bump_stop_RF,"
                                "bump_stop_LR,bump_stop_RR,units\nb,A,B,C,D,,,,none,SI\n")


@pytest.mark.parametrize("header, row, match", [
    ("bump_stop_LF", "BS-X", r"setups.csv: line 3 \(setup 'a'\): column 'bump_stop_LF': "
                             r"unknown bump-stop id 'BS-X'.*; the bump-stop library "
                             r"bumpstops.toml has \['BS-F', 'BS-S'\]"),
    ("bump_stop_RR", "BS-SS", r"column 'bump_stop_RR': unknown bump-stop id 'BS-SS' \(did you "
                              r"mean 'BS-S'\?\)"),
    ("bump_stop_LF,packer_LF", "BS-S,0.006",
     r"line 3 \(setup 'a'\): column 'packer_LF': packer 6 mm \(0\.2362 in\) is thicker than "
     r"the gap of bump stop 'BS-S', 5 mm \(0\.1969 in\)"),
    ("packer_LF", "-0.001", r"column 'packer_LF': '-0.001' is not a thickness; give the "
                            r"packer in m \(a number >= 0, 0 = none\)"),
    ("packer_LF", "3mm", r"column 'packer_LF': '3mm' is not a thickness"),
    ("packer_LF", "nan", r"column 'packer_LF': 'nan' is not a thickness"),
    ("bump_stop_lf", "BS-F", r"column 'bump_stop_lf' is not a bump-stop or packer column "
                             r"\(did you mean 'bump_stop_LF'\?\)"),
    ("packers_LF", "0.001", r"column 'packers_LF' is not a bump-stop or packer column "
                            r"\(did you mean 'packer_LF'\?\)"),
    ("bumpstop_FL", "BS-F", r"column 'bumpstop_FL' is not a bump-stop or packer column "
                            r"\(did you mean 'bump_stop_LF'\?\)"),
    ("Packer RL", "0.001", r"column 'Packer RL' .*\(did you mean 'packer_LR'\?\)"),
])
def test_bad_bump_stop_columns_are_refused(tmp_path, stops, header, row, match):
    path = tmp_path / "setups.csv"
    path.write_text(f"# units: SI\nsetup,LF,RF,LR,RR,{header}\na,B20,B20,B20,B20,{row}\n")
    with pytest.raises(PlannerError, match=match):
        read_setups(path, bump_stops=stops)


def test_a_longer_column_that_starts_alike_is_another_column(tmp_path):
    path = tmp_path / "pred.csv"
    path.write_text("setup,LF,RF,LR,RR,bump_stop_share_LF,packer_cost\na,A,A,A,A,0.05,3\n")
    assert read_setups(path)[0].bump_stops is None


def test_a_packer_beside_a_baseline_stop_is_checked_later(tmp_path, stops):
    """Without a bump stop in the row the packer's stop is the baseline's: read_setups cannot
    check it, so it reads; and any packer reads without a library."""
    path = tmp_path / "setups.csv"
    path.write_text("setup,LF,RF,LR,RR,packer_LF\na,B20,B20,B20,B20,0.009\n")
    assert read_setups(path, bump_stops=stops)[0].packers_m["LF"] == 0.009


def test_setup_with_elements_compares_pickles_and_reprs():
    a = Setup("x", dict(zip(CORNERS, "ABCD")), bump_stops={"LF": "BS-F", "RR": "none"},
              packers_m={"LF": 0.003})
    assert dict(a.bump_stops) == {"LF": "BS-F", "RR": None}
    with pytest.raises(TypeError):
        a.bump_stops["LF"] = "Z"
    for b in (pickle.loads(pickle.dumps(a)), copy.deepcopy(a), dataclasses.replace(a),
              eval(repr(a))):
        assert b == a and b.bump_stops == a.bump_stops and b.packers_m == a.packers_m
    plain = Setup("x", dict(zip(CORNERS, "ABCD")))
    assert a != plain and hash(a) == hash(plain)
    assert repr(plain) == "Setup(name='x', shocks={'LF': 'A', 'RF': 'B', 'LR': 'C', 'RR': 'D'})"
    assert Setup("x", dict(zip(CORNERS, "ABCD")), bump_stops={}, packers_m={}) == plain


@pytest.mark.parametrize("kwargs, err, match", [
    ({"bump_stops": {"FL": "BS-F"}}, PlannerError, r"bump_stops names unknown corner\(s\) \['FL'\]"),
    ({"bump_stops": {"LF": ""}}, PlannerError, r"bump_stops LF: bump stop '' is not an id"),
    ({"packers_m": {"LF": -0.001}}, PlannerError, r"packers_m LF = -0\.001 is not a thickness"),
    ({"packers_m": {"LF": "0.003"}}, PlannerError, r"packers_m LF = '0\.003' is not a thickness"),
    ({"packers_m": [0.003]}, TypeError, r"packers_m must be a mapping"),
])
def test_setup_refuses_bad_elements(kwargs, err, match):
    with pytest.raises(err, match=match):
        Setup("x", dict(zip(CORNERS, "ABCD")), **kwargs)
