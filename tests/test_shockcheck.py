"""Tests of ident.identify.shockcheck: the session's shock forces against the library."""

import dataclasses
import json
import logging

import numpy as np
import pytest

from ident.data.channels import CORNERS
from ident.data.session import make_session
from ident.identify.diagnose import rest_levels
from ident.identify.shockcheck import (
    SCALE_FLOOR,
    SCALE_Z,
    SHOCK_COLUMNS,
    ShockLibraryCheck,
    check_shock_library,
    library_force,
)
from ident.models.bumpstops import BumpStop, BumpStopLibrary
from ident.models.library import ShockLibrary
from ident.models.shocks import LinearShock

#: Runs of the session [s]: 5 x 60 s on a 4-post rig at 2 % sensor noise; N8 (one corner
#: per swap run) then has 4 series of 6,000 samples, its scale a standard error of 2e-4.
RUN_S = 60.0
NOISE = 0.02
#: The library entry's error of the done-when (issue 26): 4 %.
OFF = 1.04
#: The scale found for an entry 4 % off against 1 / 1.04: the exact entry's scale departs
#: from 1 by up to 3e-4 (measured 1.0003 for N8: the band-limited reconstruction of the
#: velocity between samples against the rig's own 8x loop), plus 3 standard errors.
SCALE_ATOL = 1e-3
#: The residual after the scale of an exact entry against what the noise explains (the
#: residual's white part): measured 1.05 for N8, 1.01 for B20.
RESIDUAL_OVER_NOISE_MAX = 1.2
#: A first-order lag against its analytic sine response (amplitude 1 / sqrt(1 + (w tau)^2)):
#: the quadratic hold on 8 sub-steps of 10 ms, at 5 Hz.
LAG_RTOL = 1e-3


@pytest.fixture(scope="module")
def session(paper_plan):
    """The paper's plan on a 4-post rig, 5 runs of 60 s with 2 % sensor noise."""
    from ident.sim.virtual_rig import simulate_session

    runs = tuple(dataclasses.replace(r, duration_s=RUN_S) for r in paper_plan.runs)
    return simulate_session(dataclasses.replace(paper_plan, rig="4-post", runs=runs,
                                                noise=NOISE))


def _with_library(session, shock_id, **change):
    """The session with one library entry changed (:meth:`ShockModel.scaled`)."""
    lib = ShockLibrary([m.scaled(**change) if m.id == shock_id else m
                        for m in session.shocks.values()])
    return dataclasses.replace(session, shocks=lib)


@pytest.fixture(scope="module")
def exact(session):
    return check_shock_library(session)


def _row(check, shock_id):
    return check.shocks.set_index("shock").loc[shock_id]


def test_the_exact_library_is_ok_within_its_interval(exact, session):
    assert list(exact.shocks.columns) == list(SHOCK_COLUMNS)
    assert sorted(exact.shocks.shock) == ["B20", "N8"]
    assert list(exact.shocks.verdict) == ["ok", "ok"]
    assert exact.off == [] and exact.warnings() == []
    for row in exact.shocks.itertuples():
        assert abs(row.scale - 1) <= SCALE_Z * row.se, row
        assert row.residual_pct <= RESIDUAL_OVER_NOISE_MAX * row.noise_pct, row
    n8 = _row(exact, "N8")
    assert n8.runs == ["swap-LF", "swap-RF", "swap-LR", "swap-RR"] and n8.n_series == 4
    assert _row(exact, "B20").n_series == 16
    assert set(exact.series.instrument) == {"travel"}
    assert exact.settings["session"] == session.name


def test_one_entry_4_percent_off_is_off_alone(session, caplog):
    with caplog.at_level(logging.WARNING, logger="ident.identify.shockcheck"):
        check = check_shock_library(_with_library(session, "N8", force_scale=OFF))
    assert check.off == ["N8"]
    n8 = _row(check, "N8")
    # the library's forces are 1.04 x the truth: measured ~= a * library with a = 1 / 1.04
    assert n8.scale == pytest.approx(1 / OFF, abs=SCALE_ATOL)
    assert n8.scale_hi < 1 - SCALE_FLOOR
    assert n8.gap_pct > 1.5 * n8.noise_pct
    (line,) = check.warnings()
    assert "'N8'" in line and "swap-LF, swap-RF, swap-LR, swap-RR" in line
    assert "3.8 % below" in line and "scale its library entry's forces by 0.96" in line
    assert "re-measure N8 on the dyno" in line
    assert [r.getMessage() for r in caplog.records] == [line]
    assert _row(check, "B20").verdict == "ok"


def test_the_library_lag_is_respected(session, exact):
    # the paper's N8 has a 4 ms lag: without it (or doubled) the curve is far off
    for lag_s, scale in ((0.0, 0.83), (0.008, 1.16)):
        check = check_shock_library(_with_library(session, "N8", lag_s=lag_s))
        n8 = _row(check, "N8")
        assert check.off == ["N8"] and n8.scale == pytest.approx(scale, abs=0.02)
        assert n8.residual_pct > 5 * _row(exact, "N8").residual_pct


def test_library_force_lag_against_the_analytic_sine_response():
    fs, f_hz, tau = 100.0, 5.0, 0.004
    t = np.arange(4000) / fs
    v = np.sin(2 * np.pi * f_hz * t)
    force = library_force(LinearShock("L", 1000.0, lag_s=tau), v, fs)
    wt = 2 * np.pi * f_hz * tau
    expect = 1000.0 / (1 + wt ** 2) * (np.sin(2 * np.pi * f_hz * t) - wt * np.cos(
        2 * np.pi * f_hz * t))
    tail = slice(2000, 3900)  # the lag's start-up and the record's end left out
    np.testing.assert_allclose(force[tail], expect[tail], atol=LAG_RTOL * 1000.0)


def test_a_load_cell_that_carries_the_bump_stop(session):
    # a stop at LF touched about 10 % of the time, its force added to the force channel (a
    # load cell at the top mount): its samples are left out, and the check stays clean
    travel = {}
    for r in session.runs:
        lv, _ = rest_levels(r)
        travel[r.name] = r.channels["shock_travel_LF"] - lv["shock_travel_LF"]
    gap = min(float(np.quantile(s, 0.9)) for s in travel.values())
    lib = BumpStopLibrary([BumpStop("BS", gap, [0.0, 0.01], [0.0, 3000.0])])
    runs = [dataclasses.replace(r, bump_stops={"LF": "BS"}, channels=dict(
        r.channels, shock_force_LF=r.channels["shock_force_LF"] + lib["BS"].force(
            travel[r.name]))) for r in session.runs]
    stopped = make_session(session.name, runs, session.shocks, bump_stops=lib)
    check = check_shock_library(stopped)
    assert check.off == []
    at_lf = check.series.corner == "LF"
    assert (check.series[at_lf].contact_share > 0.05).all()
    assert (check.series[~at_lf].contact_share == 0).all()
    blind = check_shock_library(stopped, exclude_contact=False)
    assert _row(blind, "B20").gap_pct > 2 * _row(check, "B20").gap_pct


def test_a_session_without_force_channels_is_not_checked(session):
    runs = [dataclasses.replace(r, channels={k: v for k, v in r.channels.items()
                                             if not k.startswith("shock_force_")})
            for r in session.runs]
    check = check_shock_library(make_session(session.name, runs, session.shocks))
    assert len(check) == 0 and check.warnings() == [] and check.lines() == []
    assert list(check.shocks.columns) == list(SHOCK_COLUMNS)


def test_to_dict_round_trip_and_lines(session):
    check = check_shock_library(_with_library(session, "B20", force_scale=OFF))
    doc = json.loads(json.dumps(check.to_dict(series=False)))
    back = ShockLibraryCheck.from_dict(doc)
    assert back.off == ["B20"] and back.warnings() == check.warnings()
    lines = back.lines()
    assert lines[0].startswith("shock library vs measured force: 2 shock(s), 1 off")
    assert any(line.startswith("  warning: shock 'B20'") for line in lines)
    assert len(ShockLibraryCheck.from_dict(check.to_dict()).series) == 20


@pytest.mark.parametrize("kwargs, exc, match", [
    ({"refine": 0}, ValueError, "refine = 0"),
    ({"refine": 2.5}, ValueError, "integer >= 1"),
])
def test_bad_options_are_refused(session, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        check_shock_library(session, **kwargs)


def test_not_a_session_is_refused():
    with pytest.raises(TypeError, match="needs a Session"):
        check_shock_library([1, 2])


def test_identify_keeps_the_summary(four_post_model):
    doc = four_post_model.file_settings()["shock_check"]
    json.dumps(doc)
    assert "series" not in doc
    assert [s["verdict"] for s in doc["shocks"]] == ["ok", "ok"]
    assert all(c in CORNERS for s in doc["shocks"] for c in s["corners"])
