"""Tests of planner.objective: known scores, groups, limits and ranks, Pareto fronts,
objective files and bad inputs."""

import copy
import dataclasses
import math
import pickle
import re

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

import planner.objective as objective_mod
from ident.data.channels import CORNERS
from planner.errors import PlannerError
from ident.sim.metrics import METRIC_NAMES
from planner.objective import (
    OBJECTIVE_FORMAT,
    Objective,
    Scores,
    default_objective,
    mark_inventory,
    objective_to_toml,
    pareto_front,
    ranking_order,
    ranking_position,
    ranks,
    read_objective,
    score_setups,
)

RTOL_SUM = 1e-14  # a weighted sum of exact ratios: round-off only

BRIEF_TOML = """\
format = "objective/1"
name = "grip and platform"
baseline = "baseline"          # setup name to normalize against (default: the first setup)
[weights]                      # metric name -> weight; each metric enters as value / baseline
tire_force_rms_LF = 0.125
tire_force_rms_RF = 0.125
tire_force_rms_LR = 0.125
tire_force_rms_RR = 0.125
ride_height_rms_front = 0.25
ride_height_rms_rear = 0.25
[groups]                       # optional: named sub-scores (for Pareto plots)
grip = ["tire_force_rms_LF", "tire_force_rms_RF", "tire_force_rms_LR", "tire_force_rms_RR"]
platform = ["ride_height_rms_front", "ride_height_rms_rear"]
[limits]                       # optional: constraints, relative to the baseline
shock_travel_rms_LF = { max_ratio = 1.25 }
"""


@pytest.fixture
def rng():
    return np.random.default_rng(20090501)


def _baseline_values():
    """Plausible SI metrics of a baseline setup (N, m, m/s)."""
    values = {}
    values.update({f"tire_force_rms_{c}": 500.0 + 20.0 * j for j, c in enumerate(CORNERS)})
    values.update(ride_height_rms_front=0.004, ride_height_rms_rear=0.005)
    values.update({f"shock_travel_rms_{c}": 0.006 + 0.001 * j for j, c in enumerate(CORNERS)})
    values.update({f"shock_velocity_rms_{c}": 0.08 for c in CORNERS})
    return values


def _table(factors, names=None):
    """Metrics table: one row per setup, each the baseline's values times a factor.

    `factors` maps setup -> a number (every metric) or a dict metric -> factor.
    """
    base = _baseline_values()
    rows = {}
    for setup, f in factors.items():
        f = f if isinstance(f, dict) else dict.fromkeys(base, f)
        rows[setup] = {m: v * f.get(m, 1.0) for m, v in base.items()}
    return pd.DataFrame.from_dict(rows, orient="index")


# ---------------------------------------------------------------- known answers


def test_default_objective_matches_the_documented_defaults():
    obj = default_objective()
    assert obj.name == "grip and platform" and obj.baseline is None
    assert dict(obj.weights) == {**{f"tire_force_rms_{c}": 0.125 for c in CORNERS},
                                 "ride_height_rms_front": 0.25, "ride_height_rms_rear": 0.25}
    assert {g: sum(obj.weights[m] for m in ms) for g, ms in obj.groups.items()} == {
        "grip": 0.5, "platform": 0.5}
    assert dict(obj.limits) == {f"shock_travel_rms_{c}": {"max_ratio": 1.25} for c in CORNERS}
    assert obj.metrics[-1] == "shock_travel_rms_RR" and obj.total_weight == 1.0


def test_baseline_scores_sum_of_weights_and_uniform_change_scales_it():
    obj = Objective("w", {"tire_force_rms_LF": 0.3, "ride_height_rms_rear": 1.7,
                          "shock_velocity_rms_RR": 2.0})
    t = score_setups(_table({"baseline": 1.0, "better": 0.9, "worse": 1.25}), obj).table
    total = 0.3 + 1.7 + 2.0
    assert_allclose(t["score"], [total, 0.9 * total, 1.25 * total], rtol=RTOL_SUM)
    assert t.loc["baseline", "score"] == obj.total_weight
    assert t["rank"].tolist() == [2, 1, 3]


def test_one_metric_changed_moves_the_score_by_its_weight():
    obj = default_objective()
    t = score_setups(_table({"b": 1.0, "lf": {"tire_force_rms_LF": 0.8},
                             "front": {"ride_height_rms_front": 1.1}}), obj).table
    assert_allclose(t["score"], [1.0, 1.0 - 0.2 * 0.125, 1.0 + 0.1 * 0.25], rtol=RTOL_SUM)
    assert_allclose(t["score_grip"], [0.5, 0.5 - 0.2 * 0.125, 0.5], rtol=RTOL_SUM)
    assert_allclose(t["score_platform"], [0.5, 0.5, 0.5 + 0.1 * 0.25], rtol=RTOL_SUM)
    assert_allclose(t["score_grip"] + t["score_platform"], t["score"], rtol=RTOL_SUM)


def test_scores_do_not_depend_on_units_and_match_a_loop(rng):
    obj = default_objective()
    names = list(obj.metrics)
    values = rng.uniform(0.5, 2.0, (50, len(names)))
    t = pd.DataFrame(values, columns=names, index=[f"s{i}" for i in range(50)])
    scores = score_setups(t, obj, baseline="s7")
    expected = [sum(w * t.loc[s, m] / t.loc["s7", m] for m, w in obj.weights.items())
                for s in t.index]
    assert_allclose(scores.table["score"], expected, rtol=RTOL_SUM * 10)
    imperial = t * {m: (1 / 4.4482216152605 if "force" in m else 1 / 0.0254) for m in names}
    assert_allclose(score_setups(imperial, obj, baseline="s7").table["score"],
                    scores.table["score"], rtol=1e-13)


def test_baseline_choice_objective_argument_and_first_row():
    t = _table({"first": 1.0, "baseline": 2.0})
    assert score_setups(t).baseline == "first"
    obj = dataclasses.replace(default_objective(), baseline="baseline")
    s = score_setups(t, obj)
    assert s.baseline == "baseline"
    assert_allclose(s.table["score"], [0.5, 1.0], rtol=RTOL_SUM)
    assert score_setups(t, obj, baseline="first").baseline == "first"  # argument wins
    assert s.baseline_values["tire_force_rms_LF"] == 1000.0
    assert list(s.baseline_values.index) == list(obj.metrics)


def test_setup_column_is_used_as_index_and_extra_columns_ignored():
    t = _table({"a": 1.0, "b": 0.5}).reset_index(names="setup")
    t.insert(1, "LF", ["B20", "D8"])
    s = score_setups(t)
    assert list(s.table.index) == ["a", "b"] and s.table.index.name == "setup"


# ---------------------------------------------------------------- limits and ranking


def test_limits_feasibility_violations_and_ranks():
    obj = Objective("lim", {"tire_force_rms_LF": 1.0},
                    limits={"shock_travel_rms_LF": {"max_ratio": 1.25},
                            "shock_velocity_rms_LF": {"max": 0.1, "max_ratio": 2.0}})
    t = _table({
        "base": 1.0,
        "best_but_travel": {"tire_force_rms_LF": 0.5, "shock_travel_rms_LF": 1.3},
        "good": {"tire_force_rms_LF": 0.8, "shock_travel_rms_LF": 1.25},   # on the limit: ok
        "both": {"tire_force_rms_LF": 0.6, "shock_travel_rms_LF": 1.5,
                 "shock_velocity_rms_LF": 1.5},                             # 0.12 m/s > 0.1
        "worse": {"tire_force_rms_LF": 1.1},
    })
    s = score_setups(t, obj).table
    assert s["feasible"].tolist() == [True, False, True, False, True]
    assert s.loc["good", "violations"] == "" and s.loc["base", "violations"] == ""
    assert s.loc["best_but_travel", "violations"] == (
        "shock_travel_rms_LF = 1.3 x baseline > max_ratio 1.25")
    assert s.loc["both", "violations"] == (
        "shock_travel_rms_LF = 1.5 x baseline > max_ratio 1.25; "
        "shock_velocity_rms_LF = 0.12 > max 0.1")
    # feasible by score (good 0.8, base 1.0, worse 1.1), then infeasible by score
    assert s["rank"].tolist() == [2, 4, 1, 5, 3]
    assert s["feasible"].dtype == bool and s["rank"].dtype == np.int64


def test_nan_metrics_fail_limits_and_nan_scores_rank_last():
    obj = Objective("n", {"tire_force_rms_LF": 1.0},
                    limits={"shock_travel_rms_LF": {"max_ratio": 1.25}})
    t = _table({"base": 1.0, "nan_travel": {"shock_travel_rms_LF": math.nan},
                "nan_score": {"tire_force_rms_LF": math.nan}, "bad": 1.5, "ok": 1.1})
    s = score_setups(t, obj).table
    assert s.loc["nan_travel", "violations"] == "shock_travel_rms_LF is NaN"
    assert not s.loc["nan_travel", "feasible"] and s.loc["nan_score", "feasible"]
    assert math.isnan(s.loc["nan_score", "score"])
    # feasible: base, ok, then the NaN score; infeasible: nan_travel (1.0), bad (1.5)
    assert s["rank"].tolist() == [1, 4, 3, 5, 2]


def test_ties_rank_in_table_order_and_ranked_sorts():
    s = score_setups(_table({"a": 1.0, "b": 0.9, "c": 0.9, "d": 1.0}))
    assert s.table["rank"].tolist() == [3, 1, 2, 4]
    assert list(s.ranked().index) == ["b", "c", "a", "d"]


def test_scores_is_frozen():
    s = score_setups(_table({"a": 1.0}))
    assert isinstance(s, Scores) and s.objective == default_objective()
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.baseline = "x"


def test_100k_setups_score_and_pareto(rng):
    """Performance sanity (not timed): 10^5 setups go through scoring and the front."""
    obj = default_objective()
    n = 100_000
    t = pd.DataFrame(rng.uniform(0.8, 1.3, (n, len(obj.metrics))), columns=obj.metrics,
                     index=pd.Index([f"s{i}" for i in range(n)], name="setup"))
    t.iloc[0] = 1.0  # the baseline: travel ratios of the others span 0.8 .. 1.3
    s = score_setups(t, obj)
    assert len(s.table) == n
    assert sorted(s.table["rank"]) == list(range(1, n + 1))
    assert s.table["feasible"].any() and not s.table["feasible"].all()
    assert (s.table["violations"] == "").to_numpy().tolist() == s.table["feasible"].tolist()
    front = pareto_front(s)
    assert 0 < front.sum() < 1000 and s.table["feasible"].to_numpy()[front].all()


# ---------------------------------------------------------------- Pareto front


def _brute_front(x, y, valid):
    n = len(x)
    out = np.zeros(n, dtype=bool)
    for i in range(n):
        if not valid[i]:
            continue
        out[i] = not any(valid[j] and x[j] <= x[i] and y[j] <= y[i]
                         and (x[j] < x[i] or y[j] < y[i]) for j in range(n))
    return out


def test_pareto_front_on_a_hand_made_set():
    t = pd.DataFrame({
        "score_grip":     [1.0, 0.8, 0.9, 1.2, 0.8, 0.7, 0.9, 0.7, math.nan],
        "score_platform": [1.0, 1.1, 0.9, 0.7, 1.1, 1.4, 1.2, 1.5, 0.1],
    }, index=list("abcdefghi"))
    # b and e identical (both on), f beats h at equal x, g dominated by c, a by c, i NaN
    assert pareto_front(t).tolist() == [False, True, True, True, True, True, False, False,
                                        False]


def test_pareto_front_matches_brute_force_with_ties(rng):
    x = rng.integers(0, 8, 300).astype(float)
    y = rng.integers(0, 8, 300).astype(float)
    x[::37] = np.nan
    feasible = rng.random(300) < 0.8
    t = pd.DataFrame({"a": x, "b": y, "feasible": feasible})
    valid = ~np.isnan(x) & feasible
    assert_array_equal(pareto_front(t, "a", "b"), _brute_front(x, y, valid))
    assert_array_equal(pareto_front(t, "a", "b", feasible_only=False),
                       _brute_front(x, y, ~np.isnan(x)))


def test_pareto_front_with_scores_and_edge_cases():
    s = score_setups(_table({"base": 1.0, "grip": {"tire_force_rms_LF": 0.5,
                                                    "ride_height_rms_front": 1.2},
                             "platform": {"ride_height_rms_rear": 0.5},
                             "bad": 1.1}))
    assert pareto_front(s).tolist() == [False, True, True, False]
    empty = pd.DataFrame({"score_grip": [math.nan], "score_platform": [1.0]})
    assert pareto_front(empty).tolist() == [False]
    assert pareto_front(pd.DataFrame({"a": [2.0], "b": [math.inf]}), "a", "b").tolist() == [
        True]


def test_pareto_front_bad_inputs():
    with pytest.raises(PlannerError, match=r"no column 'score_ride'; the table has"):
        pareto_front(pd.DataFrame({"score_grip": [1.0]}), "score_grip", "score_ride")
    with pytest.raises(TypeError, match="Scores or a DataFrame"):
        pareto_front({"score_grip": [1.0]})


# ---------------------------------------------------------------- files


def test_brief_example_file_reads(tmp_path):
    path = tmp_path / "objective.toml"
    path.write_text(BRIEF_TOML)
    obj = read_objective(path)
    assert obj.source == str(path) and obj.baseline == "baseline"
    assert obj.weights == default_objective().weights
    assert obj.groups == default_objective().groups
    assert dict(obj.limits) == {"shock_travel_rms_LF": {"max_ratio": 1.25}}


def test_toml_round_trip_and_defaults(tmp_path):
    obj = dataclasses.replace(default_objective(), baseline="soft")
    obj = dataclasses.replace(obj, limits={**obj.limits, "shock_velocity_rms_LF": {
        "max": 0.2, "max_ratio": 1.5}})
    path = objective_to_toml(obj, tmp_path / "o.toml")
    back = read_objective(path)
    assert back == obj and back.source == str(path)
    assert list(back.weights) == list(obj.weights)
    assert path.read_text().startswith("# Objective (objective/1)")
    # the minimal file: only weights; name from the file, format and baseline defaulted
    (tmp_path / "min.toml").write_text("[weights]\ntire_force_rms_LF = 1\n")
    m = read_objective(tmp_path / "min.toml")
    assert (m.name, m.baseline, dict(m.weights), dict(m.groups)) == (
        "min", None, {"tire_force_rms_LF": 1.0}, {})
    assert f'format = "{OBJECTIVE_FORMAT}"' in objective_to_toml(m, tmp_path / "m2.toml"
                                                                 ).read_text()


def test_band_and_normalized_metric_names_are_valid():
    obj = Objective("bands", {"tire_force_rms_norm_LF": 1.0,
                              "tire_force_rms_LF_wheelhop": 1.0,
                              "ride_height_rms_front_body": 1.0})
    assert obj.metrics == ("tire_force_rms_norm_LF", "tire_force_rms_LF_wheelhop",
                           "ride_height_rms_front_body")


def test_objective_is_read_only():
    obj = default_objective()
    with pytest.raises(TypeError):
        obj.weights["tire_force_rms_LF"] = 2.0
    with pytest.raises(TypeError):
        obj.limits["shock_travel_rms_LF"]["max_ratio"] = 2.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        obj.name = "x"


def test_objective_and_scores_pickle():
    obj = dataclasses.replace(default_objective(), baseline="b", source="o.toml")
    back = pickle.loads(pickle.dumps(obj))
    assert back == obj and back.source == "o.toml"
    assert copy.deepcopy(obj) == obj
    s = pickle.loads(pickle.dumps(score_setups(_table({"b": 1.0, "c": 0.9}), obj)))
    assert s.objective == obj and s.table["rank"].tolist() == [2, 1]


def test_write_refuses_to_overwrite(tmp_path):
    path = objective_to_toml(default_objective(), tmp_path / "o.toml")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        objective_to_toml(default_objective(), path)
    objective_to_toml(default_objective(), path, overwrite=True)
    with pytest.raises(TypeError, match="must be an Objective"):
        objective_to_toml({"weights": {}}, tmp_path / "x.toml")


_W = "[weights]\ntire_force_rms_LF = 1.0\n"
BAD_FILES = [
    ("not toml", "weights = \n", r"not valid TOML"),
    ("unknown top key", "weight = 1\n" + _W, r"unknown key 'weight'; an objective file has "
     r"the keys"),
    ("bad format", 'format = "objective/2"\n' + _W, r"key 'format' is 'objective/2'; this "
     r"version reads 'objective/1'"),
    ("no weights", 'name = "x"\n', r"no \[weights\] table"),
    ("weights not table", "weights = 3\n", r"key 'weights' must be a table, got int"),
    ("limits not table", "limits = [1]\n" + _W, r"key 'limits' must be a table, got list"),
    ("empty name", 'name = ""\n' + _W, r"key 'name' '' must be a non-empty string"),
    ("baseline not str", "baseline = 3\n" + _W, r"baseline 3 must be a non-empty string"),
    ("empty weights", "[weights]\n", r"\[weights\] is empty"),
    ("unknown metric", "[weights]\ntire_force_LF = 1.0\n",
     r"objective 'objective' \(.*objective.toml\): \[weights\]: unknown metric 'tire_force_LF'; "
     r"did you mean 'tire_force_rms_LF'\? valid names are \['tire_force_rms_LF'"),
    ("string weight", '[weights]\ntire_force_rms_LF = "1"\n',
     r"\[weights\]: tire_force_rms_LF = '1' is not a number"),
    ("bool weight", "[weights]\ntire_force_rms_LF = true\n", r"= True is not a number"),
    ("negative weight", "[weights]\ntire_force_rms_LF = -0.5\n",
     r"\[weights\]: tire_force_rms_LF = -0.5 is not a finite number >= 0"),
    ("nan weight", "[weights]\ntire_force_rms_LF = nan\n", r"= nan is not a finite number"),
    ("all zero", "[weights]\ntire_force_rms_LF = 0\nride_height_rms_rear = 0.0\n",
     r"every weight is 0"),
    ("group unknown metric", _W + '[groups]\ngrip = ["tire_force_rms_XX"]\n',
     r"\[groups\]: unknown metric 'tire_force_rms_XX'"),
    ("group unweighted", _W + '[groups]\nplatform = ["ride_height_rms_front"]\n',
     r"\[groups\]: platform lists 'ride_height_rms_front', which has no weight in "
     r"\[weights\]"),
    ("group not list", _W + '[groups]\ngrip = "tire_force_rms_LF"\n',
     r"\[groups\]: grip must be a list of metric names, got str"),
    ("group empty", _W + "[groups]\ngrip = []\n", r"\[groups\]: grip is empty"),
    ("group name", _W + '[groups]\n"grip score" = ["tire_force_rms_LF"]\n',
     r"group name 'grip score' is not valid"),
    ("group duplicate", _W + '[groups]\ng = ["tire_force_rms_LF", "tire_force_rms_LF"]\n',
     r"g lists 'tire_force_rms_LF' twice"),
    ("limit unknown metric", _W + "[limits]\nshock_travel_LF = { max_ratio = 1.2 }\n",
     r"\[limits\]: unknown metric 'shock_travel_LF'; did you mean 'shock_travel_rms_LF'"),
    ("limit not table", _W + "[limits]\nshock_travel_rms_LF = 1.25\n",
     r"\[limits\]: shock_travel_rms_LF = 1.25 is not a table"),
    ("limit empty", _W + "[limits]\nshock_travel_rms_LF = {}\n",
     r"\[limits\]: shock_travel_rms_LF is empty"),
    ("limit unknown key", _W + "[limits]\nshock_travel_rms_LF = { min = 0.1 }\n",
     r"shock_travel_rms_LF has the unknown key 'min'; a limit takes \['max_ratio', 'max'\]"),
    ("limit negative", _W + "[limits]\nshock_travel_rms_LF = { max_ratio = -1 }\n",
     r"shock_travel_rms_LF.max_ratio = -1 is not a finite number > 0"),
    ("limit string", _W + '[limits]\nshock_travel_rms_LF = { max = "1 in" }\n',
     r"shock_travel_rms_LF.max = '1 in' is not a finite number > 0"),
]


@pytest.mark.parametrize("text, match", [c[1:] for c in BAD_FILES], ids=[c[0] for c in BAD_FILES])
def test_bad_objective_files_raise(tmp_path, text, match):
    path = tmp_path / "objective.toml"
    path.write_text(text)
    with pytest.raises(PlannerError, match=match) as info:
        read_objective(path)
    assert str(path) in str(info.value)


def test_missing_objective_file_raises(tmp_path):
    with pytest.raises(PlannerError, match="objective file not found"):
        read_objective(tmp_path / "nope.toml")


def test_unknown_metric_message_lists_every_spec_metric():
    with pytest.raises(PlannerError) as info:
        Objective("x", {"grip": 1.0})
    assert all(repr(m) in str(info.value) for m in METRIC_NAMES)
    assert "['_body', '_wheelhop']" in str(info.value)


BAD_SCORING = [
    ("baseline missing", lambda t: score_setups(t, baseline="nope"),
     r"baseline setup 'nope' is not in the metrics table \(setups \['a', 'b'\]\)"),
    ("objective baseline missing",
     lambda t: score_setups(t, dataclasses.replace(default_objective(), baseline="base")),
     r"baseline setup 'base' is not in the metrics table"),
    ("weighted metric missing", lambda t: score_setups(t.drop(columns="tire_force_rms_RR")),
     r"no column\(s\) \['tire_force_rms_RR'\] that objective 'grip and platform' uses"),
    ("limit metric missing", lambda t: score_setups(t.drop(columns="shock_travel_rms_LR")),
     r"no column\(s\) \['shock_travel_rms_LR'\]"),
    ("baseline zero", lambda t: score_setups(t.assign(ride_height_rms_rear=[0.0, 1.0])),
     r"baseline 'a' has ride_height_rms_rear = 0.0, which cannot normalize"),
    ("baseline nan limit", lambda t: score_setups(t.assign(shock_travel_rms_RF=[np.nan, 1.0])),
     r"baseline 'a' has shock_travel_rms_RF = nan"),
    ("non-numeric", lambda t: score_setups(t.assign(tire_force_rms_LF=["1", "2"])),
     r"metrics column 'tire_force_rms_LF' is not numeric"),
    ("duplicate setups", lambda t: score_setups(t.set_axis(["a", "a"])),
     r"repeats setup name\(s\) \['a'\]"),
    ("empty", lambda t: score_setups(t.iloc[:0]), r"the metrics table has no rows"),
]


@pytest.mark.parametrize("call, match", [c[1:] for c in BAD_SCORING],
                         ids=[c[0] for c in BAD_SCORING])
def test_bad_scoring_inputs_raise(call, match):
    with pytest.raises(PlannerError, match=match):
        call(_table({"a": 1.0, "b": 0.9}))


def test_scoring_type_errors():
    with pytest.raises(TypeError, match="metrics must be a pandas DataFrame"):
        score_setups({"tire_force_rms_LF": [1.0]})
    with pytest.raises(TypeError, match="objective must be an Objective"):
        score_setups(_table({"a": 1.0}), {"tire_force_rms_LF": 1.0})


def test_max_limit_needs_no_positive_baseline():
    obj = Objective("abs", {"tire_force_rms_LF": 1.0},
                    limits={"shock_velocity_rms_LF": {"max": 0.1}})
    t = _table({"a": 1.0, "b": 2.0}).assign(shock_velocity_rms_LF=[0.0, 0.2])
    assert score_setups(t, obj).table["feasible"].tolist() == [True, False]


# ---------------------------------------------------------------- documentation


def test_module_docstring_documents_every_file_key():
    doc = objective_mod.__doc__
    for key in ("format", "name", "baseline", "[weights]", "[groups]", "[limits]",
                "max_ratio", "max ="):
        assert key in doc, key
    assert re.search(r"lower\s+is\s+better", doc, re.IGNORECASE)


# ---------------------------------------------------------------- the ranking rule


def test_ranking_rule_feasible_then_score_nan_last_ties_by_index():
    """The one ranking rule: feasible first, NaN scores last within each, then by score,
    ties by index; ranks and the sort-free position agree with the order."""
    feasible = np.array([True, False, True, True, True, False, True])
    score = np.array([1.0, 0.1, np.nan, 0.5, 1.0, np.nan, 0.9])
    order = ranking_order(feasible, score)
    assert order.tolist() == [3, 6, 0, 4, 2, 1, 5]
    assert ranking_order(feasible, score, np.array([6, 5, 4, 3, 2, 1, 0])).tolist() == \
        [3, 6, 4, 0, 2, 1, 5]
    r = ranks(feasible, score)
    assert r.dtype == np.int64 and r.tolist() == [3, 6, 5, 1, 4, 7, 2]
    index = np.arange(len(score))
    assert [ranking_position(k, feasible, score, index) for k in range(7)] == r.tolist()


def test_mark_inventory_makes_unbuildable_setups_infeasible_and_reranks():
    from ident.models.library import ShockLibrary
    from ident.models.shocks import LinearShock
    from planner.setups import Setup

    lib = ShockLibrary([LinearShock("A", 1000.0, count=2), LinearShock("B", 2000.0)])
    setups = [Setup("four-A", dict.fromkeys(CORNERS, "A")),
              Setup("two-A", dict(zip(CORNERS, "AABB")))]
    scores = pd.DataFrame({"score": [0.5, 1.0], "feasible": [True, True],
                           "violations": ["", ""], "rank": [1, 2]},
                          index=pd.Index(["four-A", "two-A"], name="setup"))
    out = mark_inventory(scores, setups, lib)
    assert out["feasible"].tolist() == [False, True] and out["rank"].tolist() == [2, 1]
    assert out.loc["four-A", "violations"] == \
        "inventory: needs 4 x 'A' but the library's count is 2"
    assert scores["rank"].tolist() == [1, 2]  # the input is left as it was
    buildable = scores.iloc[1:]
    assert mark_inventory(buildable, setups, lib) is buildable  # nothing to mark: unchanged


def test_histogram_summaries_take_a_min_limit(tmp_path):
    """Issue 39: more time below the knee is a ``min`` on ``share_low_speed_XX`` (histogram
    summaries only); it round-trips through the file and makes a setup below it infeasible."""
    import pandas as pd

    obj = Objective("knee", {"tire_force_rms_LF": 1.0},
                    limits={"share_low_speed_LF": {"min": 0.4, "max": 0.9}})
    assert dict(obj.limits["share_low_speed_LF"]) == {"max": 0.9, "min": 0.4}
    assert read_objective(objective_to_toml(obj, tmp_path / "knee.toml")) == obj
    m = pd.DataFrame({"tire_force_rms_LF": [1.0, 0.9, 0.8],
                      "share_low_speed_LF": [0.5, 0.3, 0.95]}, index=["base", "a", "b"])
    t = score_setups(m, obj).table
    assert t["feasible"].tolist() == [True, False, False]
    assert t.loc["a", "violations"] == "share_low_speed_LF = 0.3 < min 0.4"
    assert t.loc["b", "violations"] == "share_low_speed_LF = 0.95 > max 0.9"
    with pytest.raises(PlannerError, match=r"unknown key 'min'; a limit takes \['max_ratio', "
                                           r"'max'\]"):
        Objective("x", {"tire_force_rms_LF": 1.0}, limits={"tire_force_rms_LF": {"min": 1.0}})
