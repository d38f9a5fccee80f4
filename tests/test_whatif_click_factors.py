"""Tests of planner.whatif.click_factors: click tolerance and adjuster fade of adjustable shocks."""

import textwrap

import numpy as np
import pandas as pd
import pytest

from ident.data.channels import CORNERS
from ident.models.adjustable import AdjustableShock, DynoPoints
from ident.models.library import ShockLibrary
from ident.sim.dampers import ClickerDamper
from planner.errors import PlannerError
from planner.setups import Setup
from planner.whatif import Factor, evaluate_whatif, perturbation_set, read_perturbations
from planner.whatif.click_factors import (FADE_HIGH_SPEED_SHARE, FADE_KNEE_M_S, clicked_settings,
                                   fade_weight, faded_shock)
from planner.whatif.conditions import ShockVariants, condition_effect, condition_setups

#: The same simulator on the same shocks: bit-for-bit up to summation order.
SAME_PATH_RTOL = 1e-12
#: The dyno's speeds [m/s] of the clicker's sheets.
DYNO_SPEEDS = (0.01, 0.025, 0.05, 0.1, 0.2, 0.3, 0.5)
#: Fade weight well below the knee (0.01 m/s): 1 - 0.7 / (1 + (0.01 / 0.075)^2) = 0.988.
LOW_SPEED_WEIGHT = 0.988

TRUTH = ClickerDamper()


@pytest.fixture(scope="module")
def ttx():
    """The clicker from one-at-a-time sweeps (ls 0-20 clicks, hs 0-4 turns in 0.25 steps)."""
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)
    pts = DynoPoints(sheet["velocity"].to_numpy(), sheet["force"].to_numpy(),
                     sheet[["ls", "hs"]].to_numpy(), ("ls", "hs"), ())
    return AdjustableShock("TTX", TRUTH.adjusters, pts, default={"ls": 8, "hs": 2},
                           step={"ls": 1, "hs": 0.25})


@pytest.fixture(scope="module")
def crate(demo_library, ttx):
    """The demo crate with the clicker added (copied keeping the adjustable entry)."""
    return ShockLibrary(demo_library.entries() + [ttx])


@pytest.fixture(scope="module")
def setups():
    """A fixed setup, the clicker mid-range, and the clicker fully closed (a range end)."""
    return [Setup("fixed", {c: "B20" for c in CORNERS}),
            Setup("mid", {c: "TTX@ls=8,hs=2" for c in CORNERS}),
            Setup("closed", {c: "TTX@ls=0,hs=0" for c in CORNERS})]


@pytest.fixture(scope="module")
def short_drive(track_drive):
    """The first 20 s of the track drive."""
    from ident.data.drive import Drive

    n = int(20 * track_drive.fs_hz)
    return Drive("track 20 s", track_drive.fs_hz,
                 {c: x[:n] for c, x in track_drive.channels.items()})


@pytest.fixture(scope="module")
def clicks_whatif(paper_model, short_drive, crate, setups):
    """Clicks, fades, and the existing shock kinds on setting names, one at a time."""
    ps = perturbation_set([
        Factor("clicks", "click", targets=CORNERS, levels=(-1.0, 0.0, 1.0)),
        Factor("warm", "fade", targets=CORNERS, levels=(0.1,)),
        Factor("warm low", "fade", targets=CORNERS, levels=(0.1,), part="low-speed"),
        Factor("soft", "shock_scale", targets=("id:TTX",), levels=(0.9,)),
        Factor("lag", "shock_lag", targets=("id:TTX@ls=8",), levels=(0.004,)),
    ])
    return evaluate_whatif(paper_model, short_drive, setups, crate, ps, baseline="fixed")


def _velocity(w, perturbation, setup):
    row = w.condition(perturbation).loc[setup]
    return np.array([row[f"shock_velocity_rms_{c}"] for c in CORNERS], dtype=float)


def _metrics(w):
    t = w.condition()
    return [c for c in t.columns if c.startswith(("tire_force_rms", "shock_velocity_rms",
                                                  "ride_height_rms", "shock_travel_rms"))]


# ----------------------------------------------------------------------------------------------
# the pieces
# ----------------------------------------------------------------------------------------------

def test_clicked_settings_step_and_clip(ttx):
    s = ttx.resolve({"ls": 8, "hs": 2})
    moved, clipped = clicked_settings(ttx, s, {"ls": 1.0, "hs": -1.0})
    assert moved == {"ls": 9.0, "hs": 1.75} and clipped == []   # hs steps are 0.25 turn
    moved, clipped = clicked_settings(ttx, ttx.resolve({"ls": 20, "hs": 0}),
                                      {"ls": 1.0, "hs": -2.0})
    assert moved == {"ls": 20.0, "hs": 0.0}
    assert clipped == ["ls 20 +1 click -> 20", "hs 0 -2 click -> 0"]


def test_fade_weight_and_faded_shock(ttx):
    assert fade_weight(0.0) == 1.0
    assert fade_weight(100 * FADE_KNEE_M_S) == pytest.approx(FADE_HIGH_SPEED_SHARE, abs=1e-3)
    u = np.geomspace(1e-3, 2.0, 50)
    assert np.all(np.diff(fade_weight(u)) < 0)
    cold = ttx.at({"ls": 8, "hs": 2})
    whole = faded_shock(cold, 0.1)
    v = np.linspace(-1.0, 1.0, 81)
    np.testing.assert_allclose(whole.force(v), 0.9 * cold.force(v), rtol=1e-14)
    low = faded_shock(cold, 0.0, 0.1, id="warm")
    ratio = low.force(np.array([0.01, -0.01])) / cold.force(np.array([0.01, -0.01]))
    np.testing.assert_allclose(ratio, 1 - 0.1 * LOW_SPEED_WEIGHT, rtol=1e-3)
    hi = low.force(1.0) / cold.force(1.0)
    assert 1 - 0.1 * FADE_HIGH_SPEED_SHARE - 0.01 < hi < 1 - 0.1 * FADE_HIGH_SPEED_SHARE + 0.002
    vv = np.concatenate([-np.geomspace(1e-3, 2.0, 60)[::-1], [0.0], np.geomspace(1e-3, 2.0, 60)])
    f = low.force(vv)
    assert np.all(np.diff(f) > 0) and np.all(f * vv >= 0)         # monotone and passive
    assert low.id == "warm" and low.lag_s == cold.lag_s
    with pytest.raises(PlannerError, match="fade"):
        faded_shock(cold, 0.6, 0.5)


def test_condition_setups_click_only_named_adjusters_and_adjustables(crate, setups):
    ps = perturbation_set([Factor("ls", "click", targets=CORNERS, adjusters=("ls",),
                                  levels=(2.0,))])
    e = condition_effect(ps.perturbations[1], ps.factors)
    variants = ShockVariants(crate)
    got = condition_setups(setups, e, variants, "0:1")
    assert got[0].ids() == setups[0].ids()                       # fixed: untouched
    assert set(got[1].ids()) == {"TTX@ls=10,hs=2"}               # hs held
    assert set(got[2].ids()) == {"TTX@ls=2,hs=0"}
    assert variants.extra == {}                                  # a setting, not a variant
    assert len(variants.full_library().adjustable_ids) == 1      # the copy keeps TTX


# ----------------------------------------------------------------------------------------------
# on the car
# ----------------------------------------------------------------------------------------------

def test_one_click_moves_shock_velocity_the_expected_way(clicks_whatif):
    nominal = _velocity(clicks_whatif, "nominal", "mid")
    stiffer = _velocity(clicks_whatif, "clicks -1 click", "mid")   # lower = stiffer
    softer = _velocity(clicks_whatif, "clicks +1 click", "mid")
    assert np.all(stiffer < nominal) and np.all(softer > nominal)
    same = _velocity(clicks_whatif, "clicks +0 click", "mid")
    np.testing.assert_array_equal(same, nominal)


def test_clicks_clip_at_the_range_end_and_say_so(clicks_whatif):
    w = clicks_whatif
    m = _metrics(w)
    closed = w.condition("clicks -1 click").loc["closed", m].to_numpy(float)
    np.testing.assert_array_equal(closed, w.condition().loc["closed", m].to_numpy(float))
    note = w.condition("clicks -1 click").loc["closed", "clipped"]
    assert "LF TTX ls 0 -1 click -> 0, hs 0 -1 click -> 0" in note and "RR TTX" in note
    assert w.condition("clicks -1 click").loc["mid", "clipped"] == ""
    assert w.condition("clicks +1 click").loc["closed", "clipped"] == ""  # opens fine
    assert w.settings["clipped"] == 1 and "clipped" in w.settings["notes"][0]


def test_fixed_shocks_untouched_by_clicks_and_fade(clicks_whatif):
    w = clicks_whatif
    m = _metrics(w)
    ref = w.condition().loc["fixed", m].to_numpy(float)
    for p in w.table["perturbation"].unique():
        np.testing.assert_array_equal(w.condition(p).loc["fixed", m].to_numpy(float), ref)


def test_fade_is_a_softer_shock_mostly_at_low_speed(clicks_whatif):
    w = clicks_whatif
    m = _metrics(w)
    # the whole curve 10 % down is shock_scale 0.9 on the setting names (id "TTX")
    for s in ("mid", "closed"):
        np.testing.assert_allclose(w.condition("warm 10 % fade").loc[s, m].to_numpy(float),
                                   w.condition("soft x0.9").loc[s, m].to_numpy(float),
                                   rtol=SAME_PATH_RTOL)
    # a low-speed fade moves the same way, less (high-speed forces keep 97 %)
    for s in ("mid", "closed"):
        v0 = _velocity(w, "nominal", s)
        low = _velocity(w, "warm low 10 % low-speed fade", s) - v0
        whole = _velocity(w, "warm 10 % fade", s) - v0
        assert np.all(low > 0) and np.all(low < whole)


def test_existing_kinds_apply_to_setting_names(clicks_whatif):
    w = clicks_whatif
    lagged = w.condition("lag +0.004 s")
    nominal = w.condition()
    # the target "TTX@ls=8" is the setting "TTX@ls=8,hs=2": mid moves, closed does not
    assert lagged.loc["mid", "score"] != nominal.loc["mid", "score"]
    assert lagged.loc["closed", "score"] == nominal.loc["closed", "score"]


def test_tolerance_table_is_the_spread_over_the_clicks(clicks_whatif):
    w = clicks_whatif
    tol = w.tolerance.set_index(["setup", "factor", "quantity"])
    conds = ["nominal", "clicks -1 click", "clicks +1 click"]  # "+0" is the nominal
    scores = [w.condition(p).loc["mid", "score"] for p in conds]
    row = tol.loc[("mid", "clicks", "score")]
    assert row["n_conditions"] == 3
    assert (row["low"], row["high"], row["worst"]) == (min(scores), max(scores), max(scores))
    vel = [w.condition(p).loc["mid", "shock_velocity_rms_LF"] for p in conds]
    row = tol.loc[("mid", "clicks", "shock_velocity_rms_LF")]
    assert row["spread"] == pytest.approx(max(vel) - min(vel), rel=1e-12)
    assert row["spread"] > 0
    assert tol.loc[("fixed", "warm", "shock_velocity_rms_LF"), "spread"] == 0.0
    assert set(w.tolerance["factor"]) == {"clicks", "warm", "warm low"}


def test_files_have_the_tolerance_and_clip_notes(clicks_whatif, tmp_path):
    from planner.whatif import write_whatif

    files = write_whatif(clicks_whatif, tmp_path / "w", top=0)  # no tornado: fast
    assert "tolerance.csv" in files
    tol = pd.read_csv(files["tolerance.csv"])
    assert {"setup", "factor", "quantity", "worst", "spread"} <= set(tol.columns)
    table = pd.read_csv(files["whatif.csv"], keep_default_na=False)
    assert (table["clipped"] != "").sum() == 1


def test_fixed_setups_alone_give_the_same_table_as_before(paper_model, short_drive,
                                                          demo_library, crate):
    # the crate with an adjustable entry changes nothing for fixed setups (and no column)
    s = [Setup("a", {c: "B20" for c in CORNERS}), Setup("b", {c: "DS" for c in CORNERS})]
    ps = perturbation_set([Factor("tol", "shock_scale", targets=CORNERS, levels=(1.05,))])
    a = evaluate_whatif(paper_model, short_drive, s, demo_library, ps)
    b = evaluate_whatif(paper_model, short_drive, s, crate, ps)
    pd.testing.assert_frame_equal(a.table, b.table)
    assert a.tolerance is None and "clipped" not in a.settings


# ----------------------------------------------------------------------------------------------
# refusals
# ----------------------------------------------------------------------------------------------

BAD = {
    "fractional click": ("""
        kind = "click"
        corners = ["LF"]
        levels = [0.5]
        """, "'levels'"),
    "click distribution": ("""
        kind = "click"
        corners = ["LF"]
        levels = [-1, 1]
        distribution = { kind = "uniform", low = -1.0, high = 1.0 }
        """, "'distribution'"),
    "click scale": ("""
        kind = "click"
        corners = ["LF"]
        change = "scale"
        levels = [1]
        """, "'change'"),
    "click without targets": ("""
        kind = "click"
        levels = [1]
        """, "'corners'"),
    "fade above one": ("""
        kind = "fade"
        corners = ["LF"]
        levels = [1.2]
        """, "'levels'"),
    "fade normal": ("""
        kind = "fade"
        corners = ["LF"]
        levels = [0.1]
        distribution = { kind = "normal", mean = 0.05, sd = 0.02 }
        """, "'distribution'"),
    "bad part": ("""
        kind = "fade"
        corners = ["LF"]
        part = "low"
        levels = [0.1]
        """, "'part'"),
    "part on a click": ("""
        kind = "click"
        corners = ["LF"]
        part = "low-speed"
        levels = [1]
        """, "'part'"),
    "adjusters on a scale": ("""
        kind = "shock_scale"
        corners = ["LF"]
        adjusters = ["ls"]
        levels = [1.1]
        """, "'adjusters'"),
    "empty adjusters": ("""
        kind = "click"
        corners = ["LF"]
        adjusters = []
        levels = [1]
        """, "'adjusters'"),
    "unknown kind": ("""
        kind = "clicks"
        corners = ["LF"]
        levels = [1]
        """, "'click'"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_click_and_fade_factors_name_the_key(tmp_path, case):
    body, key = BAD[case]
    p = tmp_path / "whatif.toml"
    p.write_text('format = "shockplan-whatif/1"\n[[factor]]\nname = "x"\n'
                 + textwrap.dedent(body))
    with pytest.raises(PlannerError) as err:
        read_perturbations(p)
    assert key in str(err.value) and str(p) in str(err.value)


def test_click_and_fade_read_from_a_file(tmp_path):
    p = tmp_path / "whatif.toml"
    p.write_text(textwrap.dedent("""
        format = "shockplan-whatif/1"
        [[factor]]
        name = "ls"
        kind = "click"
        shocks = ["TTX"]
        adjusters = "ls"
        levels = [-1, 1]
        [[factor]]
        name = "warm"
        kind = "fade"
        corners = ["LR", "RR"]
        part = "low-speed"
        levels = [0.05]
        """))
    ps = read_perturbations(p)
    click, fade = ps.factors
    assert (click.kind, click.change, click.adjusters, click.levels) == (
        "click", "add", ("ls",), (-1.0, 1.0))
    assert (fade.part, fade.targets) == ("low-speed", ("LR", "RR"))
    assert [q.name for q in ps.perturbations] == [
        "nominal", "ls -1 click", "ls +1 click", "warm 5 % low-speed fade"]


@pytest.mark.parametrize("factor, match", [
    (Factor("warm", "fade", targets=("id:B20",), levels=(0.1,)), "fixed shock"),
    (Factor("warm", "fade", targets=("id:XYZ",), levels=(0.1,)), "not in the shock library"),
    (Factor("c", "click", targets=CORNERS, adjusters=("lss",), levels=(1.0,)), "'ls'"),
])
def test_bad_targets_are_refused_before_any_work(paper_model, short_drive, crate, setups,
                                                factor, match):
    ps = perturbation_set([factor])
    with pytest.raises(PlannerError, match=match):
        evaluate_whatif(paper_model, short_drive, setups, crate, ps)
