"""Tests of planner.optimize.click_search: the continuous optimum mapped to an adjustable shock's
clicks (the start nearest the optimum, the neighbourhood search, the report)."""

import itertools
import warnings

import numpy as np
import pandas as pd
import pytest
from openpyxl import load_workbook

from ident.data.channels import CORNERS
from ident.models.adjustable import AdjustableShock, DynoPoints
from ident.models.library import ShockLibrary, read_shock_library
from ident.models.shocks import TableShock
from ident.sim.dampers import ClickerDamper
from planner.objective import score_setups
from planner.optimize import (
    OptimizeWarning,
    click_summary,
    optimize_curves,
    search_clicks,
    write_optimum,
)
from planner.optimize.click_search import click_axes, nearest_setting
from planner.predict import predict_setups
from planner.setups import Setup, read_setups
from planner.optimize import CurveOptions, SolverOptions
from planner.options import ElementOptions

TRUTH = ClickerDamper()
#: The dyno's speeds [m/s] (a 7-speed sweep a side).
DYNO_SPEEDS = (0.01, 0.025, 0.05, 0.1, 0.2, 0.3, 0.5)
#: Three knots a side keep the problem small (the compiled loop of tests/test_optimize.py's).
SMALL_KNOTS = (0.05, 0.15, 0.4)
#: The brute-force neighbours are simulated in other batches than the search's: the same
#: per-setup simulation, equal to round-off.
RTOL_SCORE = 1e-9
#: A crate setup reproduced by the adjustable at its settings scores the same to round-off.
RTOL_COVERED = 1e-9


def clicker(step):
    """The known clicker as an adjustable shock from one-at-a-time dyno sweeps."""
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)
    pts = DynoPoints(sheet["velocity"].to_numpy(), sheet["force"].to_numpy(),
                     sheet[["ls", "hs"]].to_numpy(), ("ls", "hs"), ())
    return AdjustableShock("TTX", TRUTH.adjusters, pts, default={"ls": 8, "hs": 2},
                           step=step)


def fixed_copy(adj, shock_id, settings):
    """A fixed shock with the adjustable's curve at `settings` (the range covers it)."""
    pwl = adj.at(settings).to_pwl()
    return TableShock(shock_id, pwl.v_knots_m_s, pwl.f_knots_n)


@pytest.fixture(scope="module")
def ttx():
    # two clicks and half a turn a step: a coarse grid keeps the search short in CI
    return clicker({"ls": 2, "hs": 0.5})


@pytest.fixture(scope="module")
def crate(ttx):
    """Two fixed shocks the clicker's range covers, and the clicker."""
    return ShockLibrary([fixed_copy(ttx, "F14", {"ls": 14, "hs": 3}),
                         fixed_copy(ttx, "F4", {"ls": 4, "hs": 1}), ttx])


@pytest.fixture(scope="module")
def click_drive(paper_vehicle):
    from ident.data.drive import make_track_drive

    return make_track_drive(duration_s=10.0, fs_hz=100.0, seed=7,
                            wheelbase_m=paper_vehicle.a_m + paper_vehicle.b_m,
                            track_width_m=paper_vehicle.track_front_m, name="click track")


@pytest.fixture(scope="module")
def click_run(paper_model, click_drive, crate):
    """The paper car, a curve per axle, the crate of one clicker and two fixed shocks."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptimizeWarning)
        return optimize_curves(paper_model, click_drive, crate, baseline="F14",
                               curves=CurveOptions(knots_m_s=SMALL_KNOTS),
                               solver=SolverOptions(max_iter=15, n_starts=1, stationarity=False))


def _verified(model, drive, setups, library, optimum):
    """Scores of setups, simulated here (predict_setups, scored against the baseline)."""
    base = optimum.baseline
    table = predict_setups(model, drive, [base] + list(setups), library,
                           elements=ElementOptions(use_model=False)).table
    sc = score_setups(table, optimum.objective, baseline=base.name).table
    return sc


def test_clicks_beat_every_setting_one_click_away(click_run, paper_model, click_drive, crate,
                                                  ttx):
    clicks = click_run.clicks
    best = clicks.best
    assert [s.shock for s in clicks.searches] == ["TTX"] and not clicks.skipped
    assert best.polish == "full" and best.feasible
    # the table's row of the clicks is the search's setup, with the search's score
    row = click_run.table.loc[best.setup.name]
    assert row["kind"] == "clicks"
    assert row["score"] == pytest.approx(best.score, rel=RTOL_SCORE)
    # every setting one step away in every adjuster of every group (3**4 - 1), by brute force
    axes = dict(zip(ttx.names, click_axes(ttx)))
    groups = [g for g, _ in click_run.space.groups]
    dims = [(g, a) for g in groups for a in ttx.names]
    here = [int(np.flatnonzero(np.isclose(axes[a], best.settings[g][a]))[0]) for g, a in dims]
    neighbours = []
    for delta in itertools.product((-1, 0, 1), repeat=len(dims)):
        idx = [i + d for i, d in zip(here, delta)]
        if not any(delta) or not all(0 <= i < axes[a].size for i, (_, a) in zip(idx, dims)):
            continue
        per = {g: {} for g in groups}
        for i, (g, a) in zip(idx, dims):
            per[g][a] = float(axes[a][i])
        ids = {c: ttx.name(per[g]) for g, cs in click_run.space.groups for c in cs}
        neighbours.append(Setup("/".join(ids[c] for c in CORNERS), ids))
    assert len(neighbours) >= 2 ** len(dims) - 1  # (a corner of the ranges at least)
    sc = _verified(paper_model, click_drive, neighbours, crate, click_run)
    others = sc.loc[[s.name for s in neighbours]]
    assert others["feasible"].all()
    assert best.score <= others["score"].min() * (1 + RTOL_SCORE)
    # the search's own score of its setting is the one simulated here
    mine = _verified(paper_model, click_drive, [best.setup], crate, click_run)
    assert mine.loc[best.setup.name, "score"] == pytest.approx(best.score, rel=RTOL_SCORE)


def test_clicks_are_no_worse_than_the_best_fixed_setup(click_run):
    clicks = click_run.clicks
    t = click_run.table
    assert clicks.crate_best == click_run.crate_best
    assert t.loc[clicks.crate_best, "kind"] == "crate best"
    assert clicks.crate_best_score == t.loc[clicks.crate_best, "score"]
    # the crate's shocks are settings of the clicker: the search can only improve on them
    assert clicks.best.score <= clicks.crate_best_score * (1 + RTOL_COVERED)
    assert clicks.gain == pytest.approx(1 - clicks.best.score / clicks.crate_best_score)
    assert clicks.gain >= -RTOL_COVERED
    # the start from the crate best's curves is the crate best itself (distance 0)
    starts = clicks.best.starts.set_index("start")
    assert max(starts.loc["crate best", "distance"]) == pytest.approx(0.0, abs=1e-12)
    assert starts.loc["crate best", "start_score"] == pytest.approx(clicks.crate_best_score,
                                                                    rel=RTOL_COVERED)
    assert (starts["score"] <= starts["start_score"]).all()


def test_the_gap_to_the_optimum_is_reported(click_run, crate, tmp_path):
    clicks = click_run.clicks
    assert clicks.optimum_score == click_run.score
    assert clicks.gap == pytest.approx(1 - click_run.score / clicks.best.score)
    assert clicks.gap >= 0
    files = write_optimum(click_run, crate, tmp_path / "opt")
    tab = pd.read_csv(files["clicks"])
    assert list(tab["group"]) == ["front", "rear"]
    assert {"ls", "hs", "score", "gain", "gap"} <= set(tab.columns)
    np.testing.assert_allclose(tab["gap"], clicks.gap, rtol=1e-9)
    for _, r in tab.iterrows():
        assert clicks.best.settings[r["group"]] == {"ls": r["ls"], "hs": r["hs"]}
    # the click setup follows the optimum in optimal_setup.csv, read against the written crate
    lib = read_shock_library(files["shocks"])
    assert lib.adjustable_ids == ("TTX",)
    setups = read_setups(files["setups"], lib)
    assert [s.name for s in setups][:2] == [click_run.setup.name, clicks.best.setup.name]
    wb = load_workbook(files["xlsx"])
    assert "clicks" in wb.sheetnames
    lines = click_summary(click_run)
    assert lines[1].split() == ["shock", "group", "corners", "ls", "hs", "score", "simulated"]
    assert "custom valving" in lines[-1] and clicks.crate_best in lines[-1]


# ------------------------------------------------------------- the search on a known score


def _bowl(target, counts):
    """A score over the settings (a tilted bowl, its minimum at `target` per group), counting
    each setup scored."""
    def score(setups):
        out = {}
        for s in setups:
            counts[s.name] = counts.get(s.name, 0) + 1
            v = 0.0
            for c in CORNERS:
                ls, hs = (float(x.split("=")[1]) for x in s.shocks[c].split("@")[1].split(","))
                t = target[c]
                v += (ls - t[0]) ** 2 + 4 * (hs - t[1]) ** 2 + 1.5 * (ls - t[0]) * (hs - t[1])
            out[s.name] = (True, 1.0 + v)
        return out
    return score


def test_search_finds_a_known_bowls_minimum_scoring_each_setting_once():
    ttx = clicker({"ls": 1, "hs": 0.25})
    lib = ShockLibrary([ttx])
    groups = [("front", ("LF", "RF")), ("rear", ("LR", "RR"))]
    target = {"LF": (13, 0.75), "RF": (13, 0.75), "LR": (3, 3.5), "RR": (3, 3.5)}
    counts = {}
    v = {c: np.linspace(-0.3, 0.3, 61) for c in CORNERS}
    start = {c: ttx.at({"ls": 8, "hs": 2}).to_pwl() for c in CORNERS}
    (found,), skipped = search_clicks(lib, groups, {"optimum": start}, v, _bowl(target, counts))
    assert not skipped
    assert found.settings == {"front": {"ls": 13.0, "hs": 0.75}, "rear": {"ls": 3.0, "hs": 3.5}}
    assert found.score == 1.0 and found.start == "optimum"
    assert max(counts.values()) == 1 and found.n_simulated == len(counts)
    # the start is the setting nearest its curves: the default here, distance 0
    assert found.starts.loc[0, "settings"].startswith("TTX@ls=8,hs=2/")
    assert set(found.moves["kind"]) <= {"move", "line", "polish"}


def test_nearest_setting_and_skipped_inventory():
    ttx = clicker({"ls": 1, "hs": 0.25})
    axes = click_axes(ttx)
    assert [a.size for a in axes] == [21, 17]
    assert [a.size for a in click_axes(ttx, 50)] == [6, 5]  # every 4th click and turn
    v = {c: np.linspace(-0.3, 0.3, 61) for c in CORNERS}
    target = {c: TRUTH.shock_at({"ls": 6, "hs": 1.5}).to_pwl() for c in CORNERS}
    idx, dist = nearest_setting(ttx, axes, target, v, ("LF", "RF"))
    assert (axes[0][idx[0]], axes[1][idx[1]]) == (6.0, 1.5)
    assert dist < 0.05  # the click model within 5 % of the truth (tests/test_adjustable.py)
    short = AdjustableShock("TTX2", ttx.adjusters, ttx.points, step=ttx.step, count=2)
    searches, skipped = search_clicks(ShockLibrary([short]), [("all", CORNERS)],
                                      {"optimum": target}, v, _bowl({}, {}))
    assert searches == [] and "count 2" in skipped["TTX2"]
    with pytest.raises(ValueError, match="click radius"):
        search_clicks(ShockLibrary([ttx]), [("all", CORNERS)], {"optimum": target}, v,
                      _bowl({}, {}), radius=0)


@pytest.mark.slow
def test_optimize_command_in_clicks(tmp_path, capsys, paper_vehicle, ttx):
    """``shockplan optimize`` with a crate TOML holding an adjustable shock (its dyno sheet
    beside it): the printed settings table (a column per adjuster), the verdict and the
    files."""
    from ident.data.drive import make_track_drive, write_drive
    from ident.models.library import write_shock_library
    from planner.cli import main

    drive = make_track_drive(duration_s=10.0, fs_hz=100.0, seed=2,
                             wheelbase_m=paper_vehicle.a_m + paper_vehicle.b_m,
                             track_width_m=paper_vehicle.track_front_m)
    write_drive(drive, tmp_path / "drive.csv", units="SI")
    write_shock_library(ShockLibrary([fixed_copy(ttx, "F14", {"ls": 14, "hs": 3}), ttx]),
                        tmp_path / "shocks.toml")
    out = tmp_path / "opt"
    assert main(["-q", "optimize", "--model", "paper", "--drive", str(tmp_path / "drive.csv"),
                 "--shocks", str(tmp_path / "shocks.toml"), "--baseline", "F14",
                 "--units", "SI", "--max-iter", "10", "--starts", "1", "--click-radius", "1",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "moves of +-1..1 steps" in text
    head = next(line for line in text.splitlines() if line.strip().startswith("shock"))
    assert head.split()[3:5] == ["ls", "hs"]
    assert "TTX in clicks" in text and "custom valving" in text
    tab = pd.read_csv(out / "clicks.csv")
    assert list(tab["shock"]) == ["TTX", "TTX"]
    lib = read_shock_library(out / "optimal_shocks.toml")
    assert "TTX" in lib.adjustable_ids
    names = [s.name for s in read_setups(out / "optimal_setup.csv", lib)]
    assert names[1] == "/".join(tab["setting"].repeat(2))
