"""Tests of planner.click_settings and ranking in clicks: setting names in setups, the enumeration of
adjustable shocks' settings (sizes, names, inventory per base id), screening then the time
domain on a click grid (rank and sweep against a brute force), the refusals naming the file,
row and corner, and one table column per adjuster per corner."""

import numpy as np
import pandas as pd
import pytest

from ident.data.channels import CORNERS
from ident.models.adjustable import AdjustableShock, DynoPoints, parse_shock_name
from ident.models.library import ShockLibrary
from ident.sim.dampers import ClickerDamper
from ident.sim.metrics import METRIC_NAMES
from planner.click_settings import (adjuster_columns, click_steps, clicks_option, parse_click_step,
                            split_shock_ids)
from planner.errors import PlannerError
from planner.objective import score_setups
from planner.predict import predict_setups
from planner.rank import rank_setups
from planner.report import write_predictions_csv
from planner.report.ranking import ranking_columns
from planner.setups import (Setup, enumerate_setups, inventory_shortfall, read_setups,
                            resolve_baseline, setup_space)
from planner.sweep import sweep_setups
from planner.options import RunOptions

TRUTH = ClickerDamper()   # ls 0-20 clicks (step 1), hs 0-4 turns (step 0.25): 21 x 17
DYNO_SPEEDS = (0.01, 0.025, 0.05, 0.1, 0.2, 0.3, 0.5)
N_SETTINGS = 21 * 17
#: The small grid ranked on the car: ls every 5 clicks (0..20), hs every 2 turns (0, 2, 4).
GRID = {"ls": 5, "hs": 2}
N_GRID = 5 * 3
#: The same setup simulated in another group of setups: independent, round-off at most.
RTOL_SAME_SIMULATION = 1e-9


def _ttx(count=None):
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)
    pts = DynoPoints(sheet["velocity"].to_numpy(), sheet["force"].to_numpy(),
                     sheet[["ls", "hs"]].to_numpy(), ("ls", "hs"), ())
    return AdjustableShock("TTX", TRUTH.adjusters, pts, default={"ls": 8, "hs": 2},
                           step={"ls": 1, "hs": 0.25}, count=count)


@pytest.fixture(scope="module")
def lib(demo_library):
    """The demo crate and the clicker damper TTX (unlimited)."""
    return ShockLibrary(demo_library.entries() + [_ttx()])


@pytest.fixture(scope="module")
def front_grid():
    """Front axle on TTX settings of the small grid, rear on B20: 15 setups."""
    return {"shocks": {"front": ["TTX"]}, "fixed": {"LR": "B20"}, "clicks": GRID}


@pytest.fixture(scope="module")
def ranked(paper_model, track_drive, lib, front_grid):
    return rank_setups(paper_model, track_drive, lib, constraints=front_grid,
                       baseline="B20", top=4, n_check=0, uncertainty=False)


# ---------------------------------------------------------------- enumeration


def test_every_setting_per_axle_and_its_size(lib):
    """clicks='all': each adjustable candidate is its 357 settings; left-right symmetric
    (the default) per axle gives 357^2 setups, decoded lazily; names canonical."""
    space = setup_space(lib, shocks=["TTX"], clicks="all")
    assert space.sizes == (N_SETTINGS, N_SETTINGS) and len(space) == N_SETTINGS ** 2
    assert space.names([0, 1])[1] == "TTX@ls=0,hs=0/TTX@ls=0,hs=0/TTX@ls=0,hs=0.25/TTX@ls=0,hs=0.25"
    assert space.names([len(space) - 1]) == ["/".join(["TTX@ls=20,hs=4"] * 4)]
    one = setup_space(lib, shocks=["TTX"], clicks="all", symmetry="all")
    assert len(one) == N_SETTINGS
    assert len(setup_space(lib, shocks=["TTX"], symmetry="all")) == 1   # no clicks: default
    index, codes = space.chunk(1000, 1010)
    assert index.tolist() == list(range(1000, 1010)) and codes.shape == (10, 4)


def test_steps_per_adjuster_and_per_shock(lib):
    """A step per adjuster thins the grid (ends kept); per shock only the ids named expand;
    fixed shocks stay one candidate."""
    assert setup_space(lib, shocks=["TTX", "B20"], clicks=GRID).sizes == (N_GRID + 1,) * 2
    names = enumerate_setups(lib, shocks=["TTX"], symmetry="all", clicks={"TTX": {"ls": 10}})
    assert len(names) == 3 * 17 and names[0].ids()[0] == "TTX@ls=0,hs=0"
    per_id = click_steps({"TTX": "all"}, lib)
    assert per_id == {"TTX": {}}
    assert click_steps(None, lib) == {}


def test_setting_names_are_canonical(lib, tmp_path):
    """TTX@hs=2,ls=6 and TTX@ls=6,hs=2 are one shock: in candidates, fixed corners, setups
    files and baselines; ids separated by commas keep the settings' commas."""
    setups = enumerate_setups(lib, shocks=["TTX@hs=2,ls=6", "TTX@ls=6,hs=2"], symmetry="all")
    assert [s.name for s in setups] == ["/".join(["TTX@ls=6,hs=2"] * 4)]
    path = tmp_path / "setups.csv"
    path.write_text("setup,LF,RF,LR,RR\na,TTX@hs=2,ls=6,TTX@ls=6,B20,B20\n".replace(
        "TTX@hs=2,ls=6,TTX@ls=6", '"TTX@hs=2,ls=6","TTX@ls=6"'))
    (s,) = read_setups(path, lib)
    assert s.ids() == ("TTX@ls=6,hs=2", "TTX@ls=6,hs=2", "B20", "B20")
    base = resolve_baseline("TTX@hs=2,ls=6, TTX@ls=6,hs=2, B20, B20", lib)
    assert base.ids() == s.ids()
    assert split_shock_ids("TTX@ls=6,hs=2,B20") == ["TTX@ls=6,hs=2", "B20"]


def test_inventory_counts_units_per_base_id(demo_library):
    """Four corners on TTX settings use four TTX units: with count 3 they are skipped by the
    enumeration and the sweep's space, and named by inventory_shortfall."""
    lib3 = ShockLibrary(demo_library.entries() + [_ttx(count=3)])
    space = setup_space(lib3, shocks=["TTX", "B20"], clicks=GRID)
    index, codes = space.chunk(0, len(space))
    ttx = [j for j, sid in enumerate(space.shock_ids) if sid.startswith("TTX")]
    assert len(space) == (N_GRID + 1) ** 2
    assert index.size == len(space) - N_GRID ** 2   # TTX on both axles: 4 units
    assert (np.isin(codes, ttx).sum(axis=1) <= 3).all()
    assert len(enumerate_setups(lib3, shocks=["TTX", "B20"], clicks=GRID)) == index.size
    s = Setup("x", dict(LF="TTX@ls=0,hs=0", RF="TTX@ls=5,hs=0", LR="TTX", RR="TTX@ls=0,hs=0"))
    assert inventory_shortfall(s, lib3) == "needs 4 x 'TTX' but the library's count is 3"


# ---------------------------------------------------------------- refusals


@pytest.mark.parametrize("cell, message", [
    ("TTX@zz=3", r"line 3 \(setup 'b'\): column 'RF': shock 'TTX' has no adjuster 'zz'"),
    ("TTX@ls=30", r"line 3 \(setup 'b'\): column 'RF'.*adjuster 'ls' setting 30 is "
                  r"outside its range \[0, 20\]"),
    ("TTX@hs=0.3", r"column 'RF'.*adjuster 'hs' setting 0.3 is not on its steps"),
    ("B20@ls=3", r"line 3 \(setup 'b'\): column 'RF'.*'B20' is not adjustable"),
    ("XX@ls=3", r"line 3 \(setup 'b'\): column 'RF': unknown shock id 'XX@ls=3'"),
])
def test_setups_file_refusals_name_file_row_and_corner(lib, tmp_path, cell, message):
    path = tmp_path / "setups.csv"
    path.write_text(f"setup,LF,RF,LR,RR\na,B20,B20,B20,B20\nb,B20,{cell},B20,B20\n")
    with pytest.raises(PlannerError, match=message) as info:
        read_setups(path, lib)
    assert str(path) in str(info.value)


def test_bad_clicks_options_refused(lib, demo_library):
    with pytest.raises(PlannerError, match=r"clicks has the key 'xs', neither an adjustable "
                                           r"shock \['TTX'\] nor an adjuster \['hs', 'ls'\]"):
        setup_space(lib, clicks={"xs": 2})
    with pytest.raises(PlannerError, match=r"step 0.3 for adjuster 'hs' is not a positive "
                                           r"multiple of its resolution 0.25"):
        setup_space(lib, clicks={"hs": 0.3})
    with pytest.raises(PlannerError, match="has no adjustable shock"):
        setup_space(demo_library, clicks="all")
    with pytest.raises(PlannerError, match="adjuster 'ls' setting 21 is outside"):
        enumerate_setups(lib, fixed={"LF": "TTX@ls=21"})
    with pytest.raises(PlannerError, match="--click-step 'ls2'"):
        parse_click_step("ls2")
    assert parse_click_step("TTX.ls=2,hs=0.5") == {"TTX": {"ls": 2.0}, "hs": 0.5}


def test_cli_click_options():
    """--clicks is every setting, --click-step a step per adjuster; with --setups refused."""
    class Args:
        clicks, click_step, setups = False, None, None
    a = Args()
    assert clicks_option(a) is None
    a.clicks = True
    assert clicks_option(a) == "all"
    a.click_step = "ls=2"
    assert clicks_option(a) == {"ls": 2.0}
    a.setups = "s.csv"
    with pytest.raises(PlannerError, match="with --setups write the settings in the file"):
        clicks_option(a)


# ---------------------------------------------------------------- screening, then time domain


def test_rank_screens_the_grid_and_simulates_the_best(ranked, paper_model, track_drive, lib,
                                                      front_grid):
    """rank on a click grid: every setting screened, only the best 4 (and the baseline) in
    the time domain; its best is the brute force's (every grid setup simulated)."""
    assert len(ranked.screening) == N_GRID + 1           # the grid and the baseline B20
    polish = ranked.settings["click_polish"]               # the best's grid neighbours
    assert len(ranked.table) == 4 + 1 + polish["simulated"] and polish["simulated"] <= 8
    assert ranked.agreement["n"] == 4 + 1                  # judged on screening's choice
    base = Setup("baseline", {c: "B20" for c in CORNERS})
    setups = [base, *enumerate_setups(lib, **front_grid)]
    brute = predict_setups(paper_model, track_drive, setups, lib).table
    scores = score_setups(brute, baseline="baseline").table
    best = scores["score"].idxmin()
    assert ranked.best == best and ranked.baseline == "baseline"
    np.testing.assert_allclose(ranked.table.loc[best, "score"], scores.loc[best, "score"],
                               rtol=RTOL_SAME_SIMULATION)


def test_sweep_screens_the_grid_lazily(ranked, paper_model, track_drive, lib, front_grid):
    """sweep on the same grid (one process): the same best setup as rank."""
    res = sweep_setups(paper_model, track_drive, lib, constraints=front_grid, baseline="B20",
                       top=4, run=RunOptions(scheduler="none"), progress=False)
    assert res.settings["n_candidates"] == N_GRID
    assert res.best == ranked.best
    assert res.table.index[0].startswith("TTX@")


# ---------------------------------------------------------------- tables


def test_csv_has_a_column_per_adjuster_per_corner(ranked, tmp_path):
    """After the spec's columns (setup, corners, metrics): LF_ls, LF_hs, RF_ls, RF_hs; the
    rear (B20) has none; a table of fixed shocks gets no such column."""
    path = write_predictions_csv(ranked.table, tmp_path / "p.csv")
    got = pd.read_csv(path)
    spec = ["setup", *CORNERS, *METRIC_NAMES]
    assert list(got.columns[:len(spec)]) == spec
    assert list(got.columns[len(spec):len(spec) + 4]) == ["LF_ls", "LF_hs", "RF_ls", "RF_hs"]
    row = got.set_index("setup").loc[ranked.best]
    assert ranked.best.startswith(f"TTX@ls={row['LF_ls']:g},hs={row['LF_hs']:g}/")
    fixed = ranked.table.loc[["baseline"]]
    path = write_predictions_csv(fixed, tmp_path / "f.csv")
    assert list(pd.read_csv(path).columns) == ["setup"] + ranking_columns(fixed) + ["units"]
    cols = adjuster_columns(pd.DataFrame({c: ["B20", "TTX@ls=6,hs=2.5"] for c in CORNERS}))
    assert cols["LF_ls"].isna().tolist() == [True, False] and cols["LF_ls"].iloc[1] == 6
    assert str(cols["LF_ls"].dtype) == "Int64" and cols["LF_hs"].iloc[1] == 2.5


# ---------------------------------------------------------------- done-when: clicks on a car

#: The click session's runs [s]: 60 s identify the GT-like car to 0.3 % median / 1.2 % max
#: on its track drive, enough for a ranking (100 s: 0.07 % / 0.6 %; the fits, not the runs,
#: take the time).
CLICK_RUN_S = 60.0
#: The issue's bar: the identified model's best, simulated on the known car, scores within
#: 0.2 % of the brute force's best.
CLICK_SCORE_RTOL = 0.002
#: ... and lies within one click (one step) of it in every adjuster.
ONE_CLICK = {"ls": 1.0, "hs": 0.5}


@pytest.fixture(scope="module")
def click_car(gt_vehicle, paper_plan):
    """The GT-like car on the virtual rig with a clicker at each corner (ls 0-20 clicks, hs
    0-4 turns in half turns: 21 x 9 settings), 2 % noise; identified from a click session:
    the baseline at ls=10,hs=2 and one corner at a time clicked to ls=2,hs=0.5 (no shock
    swapped). Returns (model, library)."""
    import dataclasses
    import warnings

    from ident.identify.pipeline import identify_session
    from ident.sim.dampers import clicker_shock, gt_clicker
    from ident.sim.virtual_rig import PlanRun, simulate_session

    ttx = clicker_shock(gt_clicker())
    base, stiff = ttx.name({"ls": 10, "hs": 2}), ttx.name({"ls": 2, "hs": 0.5})
    runs = [PlanRun("baseline", {c: base for c in CORNERS}, "baseline", 1, CLICK_RUN_S)]
    for j, c in enumerate(CORNERS):
        runs.append(PlanRun(f"click-{c}", {k: stiff if k == c else base for k in CORNERS},
                            "swap", 2 + j, CLICK_RUN_S))
    lib = ShockLibrary([ttx])
    drive = dict(paper_plan.drive, peak_wheelloader_m=0.006, roll_moment_multiple=0.5,
                 pitch_moment_multiple=0.5)
    plan = dataclasses.replace(paper_plan, runs=tuple(runs), noise=0.02, drive=drive,
                               shocks=lib)
    session = simulate_session(plan, gt_vehicle)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify_session(session), lib


@pytest.mark.slow
def test_rank_in_clicks_finds_the_known_cars_best(click_car, gt_vehicle, gt_track_drive):
    """Issue 26's done-when on a small grid (every corner on one setting: 21 x 9 = 189
    setups): rank on the identified model (screening, then the best 40 in the time domain)
    finds the brute force's best on the known car within one click per adjuster, with a
    score within 0.2 %; the best is inside both ranges (the grid matters)."""
    model, lib = click_car
    ttx = lib.adjustable("TTX")
    grid = {"shocks": ["TTX"], "symmetry": "all", "clicks": "all"}
    setups = enumerate_setups(lib, **grid, max_setups=10_000)
    assert len(setups) == 21 * 9
    base = ttx.name({"ls": 10, "hs": 2})   # the session's baseline: the scores' reference
    base_name = next(s.name for s in setups if s.shocks["LF"] == base)
    truth = predict_setups(gt_vehicle, gt_track_drive, setups, lib).table
    true_score = score_setups(truth[list(METRIC_NAMES)], baseline=base_name).table["score"]
    best = true_score.idxmin()
    ranked = rank_setups(model, gt_track_drive, lib, constraints=grid, baseline=base, top=40,
                         n_check=0, uncertainty=False)
    assert len(ranked.screening) >= 21 * 9
    found = ranked.table.loc[ranked.best, "LF"]
    want = setups[[s.name for s in setups].index(best)].shocks["LF"]
    s_found = ttx.resolve(parse_shock_name(found)[1])
    s_want = ttx.resolve(parse_shock_name(want)[1])
    assert 0 < s_want["ls"] < 20 and 0 < s_want["hs"] < 4, s_want
    for k, tol in ONE_CLICK.items():
        assert abs(s_found[k] - s_want[k]) <= tol + 1e-9, (found, want)
    name_found = next(s.name for s in setups if s.shocks["LF"] == found)
    assert true_score[name_found] <= true_score[best] * (1 + CLICK_SCORE_RTOL)


def test_click_neighbours_step_on_the_enumerated_grid(lib):
    """The polish's neighbourhood: each adjuster of each corner at its setting or the next
    on the enumeration's grid (not the adjuster's own step), fixed shocks kept."""
    from planner.click_settings import click_neighbours, click_values

    setups = enumerate_setups(lib, shocks={"front": ["TTX"]}, fixed={"LR": "B20"}, clicks=GRID)
    values = click_values(setups)
    assert values[("TTX", "ls")].tolist() == [0, 5, 10, 15, 20]
    assert values[("TTX", "hs")].tolist() == [0, 2, 4]
    mid = ("TTX@ls=10,hs=2", "TTX@ls=10,hs=2", "B20", "B20")
    near = click_neighbours(mid, values, lib)
    assert len(near) == 9 * 9 - 1 and mid not in near      # 3 x 3 settings at two corners
    known = {s.ids() for s in setups}
    assert sum(ids in known for ids in near) == 8        # left-right: 3 x 3 - 1
    corner = ("TTX@ls=0,hs=0", "TTX@ls=0,hs=0", "B20", "B20")
    assert sum(ids in known for ids in click_neighbours(corner, values, lib)) == 3
