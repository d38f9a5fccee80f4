"""Tests of planner.rank: screening, time-domain check of the best and a spread, agreement,
settings, baselines, uncertainty on an identified model and bad inputs."""

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.stats import spearmanr

from ident.data.channels import CORNERS
from planner.errors import PlannerError
from ident.sim.metrics import METRIC_NAMES
from planner.objective import Objective, default_objective, score_setups
from planner.predict import predict_setups
from planner.rank import Ranking, rank_setups
from planner.screen import describe_agreement, screen_setups
from planner.setups import Setup, enumerate_setups
from planner.options import UncertaintyOptions
from planner.uncertainty import SCORE_INTERVAL_COLUMNS

RTOL_SUM = 1e-14  # a weighted sum of metric ratios, summed in another order: round-off only
TOP = 5
N_CHECK = 4
RANKING_COLUMNS = ("score", "score_grip", "score_platform", "feasible", "violations", "rank",
                   "screening_rank", "unresolved")


def _candidates(library, baseline):
    """The baseline and every 4th symmetric setup of the crate (31 setups)."""
    return [baseline] + list(enumerate_setups(library)[::4])


@pytest.fixture(scope="module")
def ranking(paper_model, track_drive, demo_library, baseline_setup):
    """A ranking of 31 setups on the known car and the 60 s track drive."""
    return rank_setups(paper_model, track_drive, demo_library,
                       setups=_candidates(demo_library, baseline_setup), top=TOP,
                       n_check=N_CHECK, uncertainty=False)


# ---------------------------------------------------------------- layout and content


def test_result_has_the_documented_fields(ranking):
    """A Ranking: the simulated setups' table with metrics, scores and ranks (best first), the
    screening of every setup, the baseline, the objective, the agreement and the settings."""
    assert isinstance(ranking, Ranking)
    t = ranking.table
    assert list(t.columns[:4]) == ["LF", "RF", "LR", "RR"]
    assert set(METRIC_NAMES) <= set(t.columns)
    assert all(c in t.columns for c in RANKING_COLUMNS)
    assert not any(c.endswith(("_lo", "_hi")) for c in t.columns)  # no uncertainty asked
    assert t["rank"].tolist() == list(range(1, len(t) + 1))
    assert (t["unresolved"] == "").all()
    s = ranking.screening
    assert len(s) == 31 and s.index.is_unique
    assert s["rank"].tolist() == list(range(1, 31 + 1))
    assert set(METRIC_NAMES) <= set(s.columns) and "score" in s.columns
    assert ranking.baseline == "baseline" and ranking.objective == default_objective()
    assert set(ranking.agreement) == {"spearman", "n", "same_best", "time_best",
                                      "screening_best", "time_best_screening_rank", "top",
                                      "score_gap", "polished"}
    assert ranking.agreement["time_best"] == t.index[0]
    assert t.index[t["baseline"]].tolist() == ["baseline"]  # the one row scores are ratios to


def test_simulated_setups_are_the_top_and_a_spread(ranking):
    """The time domain checks the `top` best by screening, `n_check` setups spread evenly over
    the remaining screening ranks (the first and last of them included) and the baseline."""
    t = ranking.table
    n = len(ranking.screening)
    assert_array_equal(t["screening_rank"], ranking.screening.loc[t.index, "rank"])
    base_rank = ranking.screening.loc["baseline", "rank"]
    assert base_rank > TOP  # so the baseline is an extra row here
    ranks = sorted(t["screening_rank"])
    assert ranks[:TOP] == list(range(1, TOP + 1))
    checks = [r for r in ranks[TOP:] if r != base_rank]
    assert len(checks) == N_CHECK and len(t) == TOP + N_CHECK + 1
    assert checks[0] == TOP + 1 and checks[-1] == n
    gaps = np.diff(checks)
    assert gaps.max() - gaps.min() <= 1


def test_rows_are_the_screening_and_time_domain_predictions(ranking, paper_model, track_drive,
                                                            demo_library, baseline_setup):
    """The screening table is screen_setups of every setup; the ranking table holds
    predict_setups of the simulated ones, scored by the objective against the baseline."""
    setups = _candidates(demo_library, baseline_setup)
    names = list(METRIC_NAMES)
    sc = screen_setups(paper_model, track_drive, setups, demo_library)
    assert_array_equal(ranking.screening.loc[sc.table.index, names].to_numpy(float),
                       sc.table[names].to_numpy(float))
    simulated = [s for s in setups if s.name in ranking.table.index]
    td = predict_setups(paper_model, track_drive, simulated, demo_library)
    assert_array_equal(ranking.table.loc[td.table.index, names].to_numpy(float),
                       td.table[names].to_numpy(float))
    scores = score_setups(ranking.table[names], ranking.objective, baseline="baseline").table
    assert_allclose(ranking.table["score"], scores.loc[ranking.table.index, "score"],
                    rtol=RTOL_SUM)
    assert ranking.table.loc["baseline", "score"] == ranking.objective.total_weight


def test_best_is_the_best_of_its_own_table(ranking):
    """The final best is rank 1 of the time-domain table: feasible, and no feasible setup of
    the table scores lower."""
    t = ranking.table
    assert ranking.best == t.index[0] == t["rank"].idxmin()
    assert t.loc[ranking.best, "feasible"]
    assert t.loc[ranking.best, "score"] == t.loc[t["feasible"], "score"].min()


def test_agreement_is_the_spearman_of_screening_and_time_domain(ranking):
    """The reported Spearman is that of the screening and time-domain scores over the
    simulated setups, a number in [-1, 1]; same_best says whether screening's best won."""
    t = ranking.table
    a = ranking.agreement
    rho = spearmanr(ranking.screening.loc[t.index, "score"], t["score"]).statistic
    assert isinstance(a["spearman"], float) and -1.0 <= a["spearman"] <= 1.0
    assert a["spearman"] == pytest.approx(rho, abs=1e-12)
    assert a["spearman"] > 0.5  # 10 setups spread over the range of a good screening
    assert a["n"] == len(t)
    assert a["same_best"] == (ranking.best == ranking.screening.index[0])


def test_agreement_says_how_far_the_bests_differ(ranking):
    """The agreement holds what tells a near-tie from a miss (issue 36): screening's rank of
    the time domain's best, the setups screening chose, and the time-domain score gap."""
    t, a = ranking.table, ranking.agreement
    assert a["time_best_screening_rank"] == ranking.screening.loc[a["time_best"], "rank"]
    assert a["top"] == TOP and a["polished"] is False
    assert a["score_gap"] == pytest.approx(
        t.loc[a["screening_best"], "score"] / t.loc[a["time_best"], "score"] - 1.0, abs=1e-15)
    assert (a["score_gap"] == 0.0) == a["same_best"]
    assert describe_agreement(a) in ranking.summary()


_DIFFER = {"spearman": 0.93, "n": 45, "same_best": False, "screening_best": "A",
           "time_best": "B", "top": 40}


@pytest.mark.parametrize("extra, strong, says", [
    ({"time_best_screening_rank": 3, "score_gap": 0.002}, False,
     ["(screening's #3), but 'B' scores only 0.2 % better", "expected when the best setups"]),
    ({"time_best_screening_rank": 57, "score_gap": 0.002}, True,
     ["'B' was screening's #57, outside the 40 it chose to simulate"]),
    ({"time_best_screening_rank": 2, "score_gap": 0.05}, True,
     ["'B' scores 5 % better in the time domain"]),
    ({"time_best_screening_rank": 9, "score_gap": 0.0, "polished": True}, False,
     ["click polish"]),
    ({}, True, ["screening's best 'A' is not the time domain's 'B'"]),  # no gap: called out
])
def test_a_differing_best_is_called_out_only_when_it_matters(extra, strong, says):
    """Every plain rank used to print "DISAGREE" (issue 36): a differing best within
    screening's choice and close in score is the expected near-tie; the sentence says so and
    that the ranking (the time domain's) is the one to use; DISAGREE only for a best outside
    screening's choice or a gap above DISAGREE_SCORE_GAP."""
    text = describe_agreement(dict(_DIFFER, **extra))
    assert ("DISAGREE" in text) == strong, text
    for part in says:
        assert part in text, text
    assert "use the ranking: it is the time domain's" in text
    assert "linearized pre-selection" in text


def test_setups_beyond_the_crate_say_why_they_are_infeasible(paper_model, track_drive,
                                                             demo_library, baseline_setup):
    """A listed setup needing more of a shock than the crate holds (the demo crate has 2 x RB):
    infeasible, ranked after the feasible ones, the reason in ``violations`` and in the
    summary beside the table (issue 36)."""
    assert demo_library["RB"].count == 2
    setups = [baseline_setup, Setup("four-RB", dict.fromkeys(CORNERS, "RB")),
              Setup("two-RB", dict(zip(CORNERS, ("RB", "RB", "DM", "DM"))))]
    r = rank_setups(paper_model, track_drive, demo_library, setups=setups, top=3, n_check=0,
                    uncertainty=False)
    t = r.table
    assert not t.loc["four-RB", "feasible"] and t.loc["two-RB", "feasible"]
    assert t.loc["four-RB", "rank"] == len(t)
    why = "inventory: needs 4 x 'RB' but the library's count is 2"
    assert t.loc["four-RB", "violations"] == why
    assert (t.loc[t["feasible"], "violations"] == "").all()
    assert r.screening.loc["four-RB", "violations"] == why
    assert f"'four-RB' is infeasible: {why}" in r.summary()
    short = r.summary(n=2)  # the two feasible ones shown: the infeasible one is counted
    assert "'four-RB' is infeasible" not in short
    assert "1 more infeasible setup(s) below these" in short


def test_settings_are_remembered(ranking):
    """The settings keep the options, the number of setups, the model and the drive."""
    st = ranking.settings
    assert (st["top"], st["n_check"], st["oversample"], st["band_hz"]) == (TOP, N_CHECK, 2,
                                                                          (1.0, 20.0))
    assert st["n_setups"] == 31
    assert st["model"] == "Boggs et al. (SAE 2009) Table 1 car" and st["drive"] == "track test"
    assert "uncertainty" not in st


# ---------------------------------------------------------------- options


def test_constraints_enumerate_and_default_baseline_is_first(paper_model, track_drive,
                                                             demo_library):
    """Without setups the candidates are enumerated with the constraints; with no baseline
    named (default objective) the first setup is the baseline. A known model has no FRF, so
    uncertainty=True adds nothing."""
    r = rank_setups(paper_model, track_drive, demo_library,
                    constraints={"shocks": ["B20", "L12", "L28"]}, top=2, n_check=1,
                    uncertainty=True)
    assert len(r.screening) == 9 and r.settings["n_setups"] == 9
    assert r.baseline == "B20/B20/B20/B20" and r.baseline in r.table.index
    assert r.table.loc[r.baseline, "score"] == 1.0
    assert not any(c.endswith(("_lo", "_hi")) for c in r.table.columns)
    assert "uncertainty" not in r.settings and (r.table["unresolved"] == "").all()


def test_baseline_setup_is_added_and_objective_baseline_is_used(paper_model, track_drive,
                                                                demo_library, baseline_setup):
    """A baseline Setup not among the setups is added to them; an objective naming a setup
    as its baseline normalizes against it; n_check=0 simulates no spread. (A baseline whose
    shocks are a listed setup's is that setup: tests/test_corpus.py.)"""
    pool = [s for s in enumerate_setups(demo_library)[:7] if s.ids() != baseline_setup.ids()][:6]
    r = rank_setups(paper_model, track_drive, demo_library, setups=pool,
                    baseline=baseline_setup, top=2, n_check=1, uncertainty=False)
    assert r.baseline == "baseline" and len(r.screening) == 7
    assert "baseline" in r.table.index and r.settings["n_setups"] == 7
    obj = dataclasses.replace(default_objective(), baseline=pool[3].name)
    r2 = rank_setups(paper_model, track_drive, demo_library, setups=pool, objective=obj,
                     top=2, n_check=0, uncertainty=False)
    assert r2.baseline == pool[3].name and r2.objective is obj
    assert r2.table.loc[pool[3].name, "score"] == pytest.approx(obj.total_weight, rel=RTOL_SUM)
    top2 = set(r2.screening.sort_values("rank").index[:2])
    assert set(r2.table.index) == top2 | {pool[3].name}  # the top 2 and the baseline, no spread


def test_custom_objective_ranks_by_its_own_metric(paper_model, track_drive, demo_library,
                                                  baseline_setup):
    """An objective of the front tire-force RMS alone: the best has the lowest of it."""
    obj = Objective("front grip", {"tire_force_rms_LF": 1.0, "tire_force_rms_RF": 1.0})
    r = rank_setups(paper_model, track_drive, demo_library,
                    setups=_candidates(demo_library, baseline_setup), objective=obj,
                    baseline="baseline", top=3, n_check=2, uncertainty=False)
    t = r.table
    front = t["tire_force_rms_LF"] / t.loc["baseline", "tire_force_rms_LF"] + \
        t["tire_force_rms_RF"] / t.loc["baseline", "tire_force_rms_RF"]
    assert r.best == front.idxmin()
    assert r.settings["top"] == 3 and "score_grip" not in t.columns


def test_too_few_simulated_setups_give_no_spearman(paper_model, track_drive, demo_library,
                                                   baseline_setup):
    """With two simulated setups a rank correlation is meaningless: NaN."""
    pool = list(enumerate_setups(demo_library)[:3])
    r = rank_setups(paper_model, track_drive, demo_library, setups=[baseline_setup] + pool,
                    top=1, n_check=0, uncertainty=False)
    assert len(r.table) == r.agreement["n"] <= 2
    assert math.isnan(r.agreement["spearman"])


@pytest.fixture(scope="module")
def identified_ranking(identified_model, track_drive, demo_library, baseline_setup):
    """A ranking on the identified paper car (the virtual rig's session) with intervals: the
    baseline and every 4th symmetric setup, the best 8 and 2 more simulated, 20 draws."""
    return rank_setups(identified_model, track_drive, demo_library,
                       setups=_candidates(demo_library, baseline_setup), top=8, n_check=2,
                       uncertainty=UncertaintyOptions(n_draws=20, seed=5))


def test_uncertainty_on_an_identified_model(identified_ranking, identified_model):
    """An identified model (with its FRF): every metric gets an interval containing the
    time-domain value, the unresolved notes name simulated setups, the settings keep the
    Monte Carlo settings."""
    r = identified_ranking
    t = r.table
    for m in METRIC_NAMES:
        lo, hi = t[f"{m}_lo"].to_numpy(float), t[f"{m}_hi"].to_numpy(float)
        assert np.all(lo <= t[m].to_numpy(float)) and np.all(t[m].to_numpy(float) <= hi), m
        assert np.all(hi > lo), m
    for note in t["unresolved"]:
        assert all(name in t.index for name in note.split())
    unc = r.settings["uncertainty"]
    assert unc["n_draws"] == 20 and unc["seed"] == 5 and unc["quantiles"] == (0.025, 0.975)
    assert unc["n_averages"] == identified_model.frf.n_averages


def test_score_and_difference_intervals_and_verdicts(identified_ranking):
    """The score's interval holds the score, the difference's holds the nominal difference
    (0 for the best: the best scores no differently from itself in any draw), the verdicts
    follow the difference intervals and match the best's unresolved pairs, the summary
    prints the best and every setup tied with it, one line each."""
    r = identified_ranking
    t = r.table
    assert set(SCORE_INTERVAL_COLUMNS) <= set(t.columns)
    assert np.all(t["score_lo"] <= t["score"]) and np.all(t["score"] <= t["score_hi"])
    best = t.index[0]
    assert t.loc[best, "verdict"] == "best" and (t["verdict"] == "best").sum() == 1
    assert t.loc[best, ["diff_best_lo", "diff_best_hi"]].tolist() == [0.0, 0.0]
    d = t["score"] - t.loc[best, "score"]
    assert np.all(t["diff_best_lo"] <= d + RTOL_SUM) and np.all(d <= t["diff_best_hi"] + RTOL_SUM)
    feasible = t["feasible"].astype(bool)
    contains = (t["diff_best_lo"] <= 0) & (t["diff_best_hi"] >= 0)
    assert (t["verdict"][feasible].drop(best) == np.where(contains[feasible].drop(best),
                                                          "tied", "worse")).all()
    tied = set(t.index[t["verdict"] == "tied"])
    assert tied == set(t.loc[best, "unresolved"].split()) & set(t.index[feasible])
    # the shared error cancels: the differences are narrower than the scores' intervals
    others = t.drop(index=[best, r.baseline])
    assert np.median((others["diff_best_hi"] - others["diff_best_lo"])
                     / (others["score_hi"] - others["score_lo"])) < 1.0
    assert t.loc[r.baseline, "verdict_baseline"] == "baseline"
    lines = r.summary().splitlines()
    assert sum(line.startswith(f"best: '{best}', score ") for line in lines) == 1
    said = [line for line in lines if line.startswith("tied with the best: ")]
    assert [line.split("'")[1] for line in said] == [n for n in t.index if n in tied]
    if not tied:
        assert any(line.startswith("no other feasible setup is tied with the best") for line in lines)


#: The truth check's loose bound: the share of the true differences from the best its
#: intervals hold on the identified paper car. Issue 37 measured the *metric* intervals
#: covering 73 % of the known car's values on this (noise-free) session, the model's
#: systematic error being partly outside them; the differences cancel most of that error.
#: Measured (20 draws, seed 5): 7 of the 10 differences from the best (errors of the
#: differences 0.2e-4 to 1.5e-4 of a score, the misses by less than 0.5e-4); against the
#: baseline 9 of 10; the scores 10 of 11. A loose bound (one miss more passes), so that a
#: broken difference fails, not a calibration claim (that is issue 37, item 1).
MIN_DIFFERENCE_COVERAGE = 0.6


def test_verdicts_against_the_known_car(identified_ranking, paper_model, track_drive,
                                        demo_library):
    """Truth check: the same setups on the known car (the virtual rig's): its best is among
    those the identified model calls best or tied, and the intervals of the differences
    from the best hold most of the true differences (MIN_DIFFERENCE_COVERAGE)."""
    r = identified_ranking
    t = r.table
    truth = predict_setups(paper_model, track_drive, list(r.candidates), demo_library)
    true = score_setups(truth.table, r.objective, baseline=r.baseline).table.loc[t.index]
    true_best = true[true["feasible"]]["score"].idxmin()
    assert t.loc[true_best, "verdict"] in ("best", "tied")
    d = (true["score"] - true.loc[r.best, "score"]).drop(index=r.best)
    lo, hi = t["diff_best_lo"].drop(index=r.best), t["diff_best_hi"].drop(index=r.best)
    assert np.mean((lo <= d) & (d <= hi)) >= MIN_DIFFERENCE_COVERAGE


#: Issue 37's done-when on this session (the paper's, noise-free, 5 runs x 800 s): every
#: interval wider than zero and the known car's metrics inside. With the formula the
#: intervals covered 73 % here; sized by the session's cross-validation 97 % (11 setups x 14
#: metrics, 20 draws). At least 90 % (the issue's lower bound on a car).
MIN_NOISE_FREE_COVERAGE = 0.90


def test_noise_free_paper_intervals_are_wide_and_cover_the_known_car(identified_ranking,
                                                                     identified_model,
                                                                     paper_model, track_drive,
                                                                     demo_library):
    """The noise-free paper session: its intervals come from its own cross-validation, are
    wider than zero, and hold the known car's metrics (issue 37). The known car is simulated
    around the model's baseline damping (its loop plant at the model's ``cbar``, as the
    studies do): around its own, the loop's time step moves its metrics by up to 0.02 %, as
    much as these intervals' half-widths (measured: 83 % against that one, 97 % here)."""
    r = identified_ranking
    assert r.settings["uncertainty"]["random_error"] == "cross-validation"
    t = r.table.dropna(subset=[f"{METRIC_NAMES[0]}_lo"])
    truth = predict_setups(paper_model.loop_plant(identified_model.cbar_n_s_m), track_drive,
                           [c for c in r.candidates if c.name in t.index],
                           demo_library).table.loc[t.index]
    inside = []
    for m in METRIC_NAMES:
        lo, hi = t[f"{m}_lo"].to_numpy(float), t[f"{m}_hi"].to_numpy(float)
        assert np.all(hi - lo > 0), m
        inside.append((truth[m].to_numpy(float) >= lo) & (truth[m].to_numpy(float) <= hi))
    assert np.mean(inside) >= MIN_NOISE_FREE_COVERAGE, np.mean(inside)


def test_verdict_lines_of_a_ranking():
    """The summary's lines: the best with its score's interval and its verdict against the
    baseline, then each tied setup with its difference's interval; none without intervals."""
    t = pd.DataFrame({"score": [0.9, 0.91, 1.0], "rank": [1, 2, 3],
                      "score_lo": [0.88, 0.89, 1.0], "score_hi": [0.92, 0.93, 1.0],
                      "diff_best_lo": [0.0, -0.002, 0.08], "diff_best_hi": [0.0, 0.02, 0.12],
                      "diff_baseline_lo": [-0.12, -0.11, 0.0],
                      "diff_baseline_hi": [-0.08, -0.07, 0.0],
                      "verdict": ["best", "tied", "worse"],
                      "verdict_baseline": ["better", "better", "baseline"]},
                     index=["a", "b", "base"])
    r = Ranking(table=t, screening=t, baseline="base", objective=default_objective(),
                agreement={}, settings={"uncertainty": {"quantiles": (0.025, 0.975)}})
    assert r.verdict_lines() == [
        "best: 'a', score 0.9000 (95 % interval 0.8800 to 0.9200), better than the baseline "
        "(difference -0.1200 to -0.0800)",
        "tied with the best: 'b', score 0.9100 (difference from the best -0.0020 to +0.0200 "
        "contains 0)"]
    r2 = dataclasses.replace(r, table=t.assign(verdict=["best", "worse", "worse"]))
    assert r2.verdict_lines()[1].startswith("no other feasible setup is tied with the best")
    assert dataclasses.replace(r, table=t.drop(columns="verdict")).verdict_lines() == [
        "best: 'a', score 0.9000; no intervals (a known model, or none asked): ties with it "
        "are not judged"]


# ---------------------------------------------------------------- bad inputs


def test_bad_inputs(paper_model, track_drive, demo_library, baseline_setup):
    """Setups and constraints together, no setups, a baseline (argument or objective's) not
    among the setups, top < 1 and an unknown shock id give clear errors."""
    setups = _candidates(demo_library, baseline_setup)[:4]
    with pytest.raises(PlannerError, match="either setups or constraints"):
        rank_setups(paper_model, track_drive, demo_library, setups=setups,
                    constraints={"symmetry": "none"}, uncertainty=False)
    with pytest.raises(PlannerError, match="no setups to rank"):
        rank_setups(paper_model, track_drive, demo_library, setups=[], uncertainty=False)
    with pytest.raises(PlannerError, match=r"baseline setup 'nope' is not among the setups"):
        rank_setups(paper_model, track_drive, demo_library, setups=setups, baseline="nope",
                    uncertainty=False)
    obj = dataclasses.replace(default_objective(), baseline="soft")
    with pytest.raises(PlannerError, match=r"baseline setup 'soft' is not among the setups"):
        rank_setups(paper_model, track_drive, demo_library, setups=setups, objective=obj,
                    uncertainty=False)
    with pytest.raises(PlannerError, match="top must be at least 1, got 0"):
        rank_setups(paper_model, track_drive, demo_library, setups=setups, top=0,
                    uncertainty=False)
    with pytest.raises(PlannerError, match="Z99"):
        rank_setups(paper_model, track_drive, demo_library,
                    setups=setups + [dataclasses.replace(baseline_setup, name="bad",
                                                         shocks={"LF": "Z99", "RF": "B20",
                                                                 "LR": "B20", "RR": "B20"})],
                    uncertainty=False)


def test_objective_on_metrics_not_predicted(paper_model, track_drive, demo_library,
                                            baseline_setup):
    """An objective weighting a metric the prediction does not give (normalized tire force,
    which needs static loads) is refused with the metric named."""
    obj = Objective("norm", {"tire_force_rms_norm_LF": 1.0})
    with pytest.raises(PlannerError, match=r"no column\(s\) \['tire_force_rms_norm_LF'\]"):
        rank_setups(paper_model, track_drive, demo_library,
                    setups=_candidates(demo_library, baseline_setup)[:4], objective=obj,
                    uncertainty=False)
    # an unknown metric cannot even make an objective
    with pytest.raises(PlannerError, match="unknown metric 'grip'"):
        rank_setups(paper_model, track_drive, demo_library,
                    setups=_candidates(demo_library, baseline_setup)[:4],
                    objective=Objective("bad", {"grip": 1.0}), uncertainty=False)


def test_objective_of_wrong_type_is_a_type_error(paper_model, track_drive, demo_library,
                                                 baseline_setup):
    """An objective that is not an Objective should be a TypeError naming the type (as
    score_setups does), not an AttributeError from inside rank_setups."""
    with pytest.raises(TypeError, match="Objective"):
        rank_setups(paper_model, track_drive, demo_library,
                    setups=_candidates(demo_library, baseline_setup)[:4],
                    objective={"tire_force_rms_LF": 1.0}, uncertainty=False)


def test_baseline_setup_named_like_another_setup_is_refused(paper_model, track_drive,
                                                            demo_library, baseline_setup):
    """A baseline Setup with the name of a listed setup but other shocks is an error, not a
    silent swap for the listed one."""
    pool = _candidates(demo_library, baseline_setup)[:4]
    other = Setup(pool[1].name, {c: "L28" for c in CORNERS})
    assert other.ids() != pool[1].ids()
    with pytest.raises(PlannerError, match="has the name of a listed setup"):
        rank_setups(paper_model, track_drive, demo_library, setups=pool, baseline=other,
                    uncertainty=False)


def test_cli_prints_the_best_and_the_setups_tied_with_it(identified_model, track_drive,
                                                         tmp_path, capsys):
    """``shockplan rank`` on an identified model prints the best and each setup tied with it,
    one line each, as ``ranking.csv``'s ``verdict`` says."""
    from ident.data.drive import write_drive
    from planner.cli import main
    from planner.demo import DEMO_LIBRARY_PATH

    model = tmp_path / "model.npz"
    identified_model.save(model)
    write_drive(track_drive, tmp_path / "drive.csv")
    assert main(["-q", "rank", "--model", str(model), "--drive", str(tmp_path / "drive.csv"),
                 "--shocks", str(DEMO_LIBRARY_PATH), "--only", "B20,L12,L28,DM,DF",
                 "--baseline", "B20", "--simulate", "4", "--out", str(tmp_path / "r")]) == 0
    lines = capsys.readouterr().out.splitlines()
    ranked = pd.read_csv(tmp_path / "r" / "ranking.csv", keep_default_na=False)
    best = ranked["setup"].iloc[0]
    assert ranked["verdict"].iloc[0] == "best"
    assert sum(line.startswith(f"best: '{best}', score ") for line in lines) == 1
    tied = ranked["setup"][ranked["verdict"] == "tied"].tolist()
    said = [line.split("'")[1] for line in lines if line.startswith("tied with the best: ")]
    assert said == tied
    assert tied or any(line.startswith("no other feasible setup is tied") for line in lines)


def test_workbook_names_the_best_and_the_tied(identified_ranking, tmp_path):
    """``ranking.xlsx``: its summary sheet names the best and the setups tied with it, its
    ranking sheet has the verdicts among the key columns (before the metrics)."""
    from openpyxl import load_workbook

    from planner.report import write_ranking

    r = identified_ranking
    files = write_ranking(r.table, tmp_path / "out", objective=r.objective,
                          baseline=r.baseline)
    wb = load_workbook(files["xlsx"])
    text = [str(c.value) for row in wb["summary"].iter_rows() for c in row if c.value]
    tied = [n for n in r.table.index if r.table.loc[n, "verdict"] == "tied"]
    assert f"best: '{r.best}'; tied with it: " + (
        ", ".join(f"'{n}'" for n in tied) if tied else "none") in text
    header = [c.value for c in next(wb["ranking"].iter_rows(max_row=1))]
    assert "verdict" in header and "verdict baseline" in header
    assert header.index("verdict") < header.index("tire force RMS LF [N]")
