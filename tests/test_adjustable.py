"""Tests of ident.models.adjustable: the click model, its checks and the library's names."""

import numpy as np
import pandas as pd
import pytest

from ident.errors import ShockModelError
from ident.models.adjustable import (AdjustableShock, DynoPoints, check_dyno_points,
                                     format_shock_name, parse_shock_name)
from ident.models.library import ShockLibrary, read_shock_library, write_shock_library
from ident.models.shocks import LinearShock, TableShock
from ident.sim.dampers import ClickerDamper

#: The dyno's speeds [m/s] (a typical 7-speed sweep, each side).
DYNO_SPEEDS = (0.01, 0.025, 0.05, 0.1, 0.2, 0.3, 0.5)
#: Held-out settings are predicted at the measured speeds within 5 % (the issue's bar);
#: the interaction of the two adjusters at the knee is the model's only error.
HELD_OUT_RTOL = 0.05
#: Measured settings are reproduced to round-off: a one-at-a-time sweep is fitted exactly.
EXACT_RTOL = 1e-9

TRUTH = ClickerDamper()


def points_from(frame, rows=None):
    return DynoPoints(frame["velocity"].to_numpy(), frame["force"].to_numpy(),
                      frame[["ls", "hs"]].to_numpy(), ("ls", "hs"), rows or ())


@pytest.fixture(scope="module")
def ttx():
    """The clicker damper from one-at-a-time sweeps (ls every 4 clicks, hs every turn)."""
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)
    return AdjustableShock("TTX", TRUTH.adjusters, points_from(sheet),
                           default={"ls": 8, "hs": 2}, stiffer={"ls": "lower", "hs": "lower"},
                           step={"ls": 1, "hs": 0.25})


def test_names_round_trip():
    assert parse_shock_name("TTX@ls=6,hs=2") == ("TTX", {"ls": 6.0, "hs": 2.0})
    assert parse_shock_name(" B20 ") == ("B20", {})
    assert format_shock_name("TTX", {"hs": 0.25, "ls": 6.0}, ("ls", "hs")) == "TTX@ls=6,hs=0.25"
    for bad in ("TTX@ls", "TTX@ls=x", "@ls=1", "TTX@ls=1,ls=2", "TTX@ls=nan"):
        with pytest.raises(ShockModelError, match="TTX|@"):
            parse_shock_name(bad)


def test_measured_settings_exact(ttx):
    v = np.concatenate([-np.array(DYNO_SPEEDS), DYNO_SPEEDS])
    for s in TRUTH.sweep_settings():
        got = ttx.at(s).force(v)
        np.testing.assert_allclose(got, TRUTH.force(v, s), rtol=EXACT_RTOL)


def test_held_out_settings_within_five_percent(ttx):
    v = np.concatenate([-np.array(DYNO_SPEEDS), DYNO_SPEEDS])
    worst = 0.0
    for s in ttx.settings_grid(step={"ls": 1, "hs": 0.5}):
        err = np.abs(ttx.at(s).force(v) / TRUTH.force(v, s) - 1)
        worst = max(worst, float(err.max()))
    assert 0.001 < worst < HELD_OUT_RTOL   # not exact (the adjusters interact), within 5 %


def test_monotone_and_passive_everywhere(ttx):
    rng = np.random.default_rng(7)
    v = np.concatenate([-np.geomspace(1e-3, 2.0, 40)[::-1], [0.0], np.geomspace(1e-3, 2.0, 40)])
    for _ in range(40):
        ls = rng.uniform(0, 19)
        hs = rng.uniform(0, 3.75)
        base = np.abs(ttx.at({"ls": round(ls), "hs": round(4 * hs) / 4}).force(v))
        softer_ls = np.abs(ttx.at({"ls": round(ls) + 1, "hs": round(4 * hs) / 4}).force(v))
        softer_hs = np.abs(ttx.at({"ls": round(ls), "hs": round(4 * hs) / 4 + 0.25}).force(v))
        assert np.all(softer_ls <= base * (1 + 1e-12))
        assert np.all(softer_hs <= base * (1 + 1e-12))
        f = ttx.at({"ls": round(ls), "hs": round(4 * hs) / 4}).force(v)
        assert np.all(f * v >= 0)


def test_at_is_a_cached_table_shock(ttx):
    a = ttx.at({"ls": 6})
    assert isinstance(a, TableShock) and a.id == "TTX@ls=6,hs=2"
    assert ttx.at({"hs": 2, "ls": 6}) is a
    assert ttx.name({"ls": 6}) == "TTX@ls=6,hs=2"
    assert ttx.default_shock().id == "TTX"


def test_settings_refused(ttx):
    with pytest.raises(ShockModelError, match=r"'ls' setting 30 is outside its range \[0, 20\]"):
        ttx.at({"ls": 30})
    with pytest.raises(ShockModelError, match="no adjuster 'lx'"):
        ttx.at({"lx": 3})
    with pytest.raises(ShockModelError, match="not on its steps of 0.25"):
        ttx.at({"hs": 1.1})


def test_settings_grid(ttx):
    grid = ttx.settings_grid(step={"ls": 5, "hs": 1})
    assert len(grid) == 5 * 5 and grid[0] == {"ls": 0.0, "hs": 0.0}
    held = ttx.settings_grid(fixed={"hs": 2})
    assert len(held) == 21 and {s["hs"] for s in held} == {2.0}


def test_wrong_sign_force_refused():
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)
    sheet.loc[17, "force"] *= -1
    rows = tuple(f"ttx.csv row {j + 1}" for j in range(len(sheet)))
    with pytest.raises(ShockModelError, match=r"ttx.csv row 18: force .* has the wrong sign"):
        AdjustableShock("TTX", TRUTH.adjusters, points_from(sheet, rows))


def test_softer_towards_stiffer_refused():
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)
    at4 = (sheet.ls == 4) & (sheet.hs == 2)
    sheet.loc[at4, "force"] *= 0.8   # ls=4 now softer than ls=8: the curves cross
    rows = tuple(f"ttx.csv row {j + 1}" for j in range(len(sheet)))
    with pytest.raises(ShockModelError, match=r"TTX@ls=4,hs=2 is \d+\.\d % softer than at "
                                              r"TTX@ls=8,hs=2.*curves cross"):
        AdjustableShock("TTX", TRUTH.adjusters, points_from(sheet, rows))
    # a 2 % crossing at one speed is dyno noise: a warning, fitted flat
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)
    sheet.loc[(sheet.ls == 0) & (sheet.velocity == 0.5), "force"] = float(
        TRUTH.force(0.5, {"ls": 4, "hs": 2})) * 0.98
    pts = points_from(sheet)
    found = check_dyno_points(pts, shock="TTX", adjusters=TRUTH.adjusters,
                              stiffer={"ls": "lower", "hs": "lower"})
    assert [f.severity for f in found] == ["warning"]
    shock = AdjustableShock("TTX", TRUTH.adjusters, pts)
    assert shock.at({"ls": 0, "hs": 2}).force(0.5) >= shock.at({"ls": 4, "hs": 2}).force(0.5)


#: Force noise of a real dyno near zero velocity [N] (digitized curves of a two-adjuster
#: damper: a few newtons, 68 % of the force at 0.0007 m/s).
NEAR_ZERO_NOISE_N = 4.0


def test_noise_near_zero_velocity_is_fitted_through():
    """A real sheet's low-speed points (0.0007-0.002 m/s, a few newtons of noise) cross by
    tens of per cent: within the dyno's resolution (2 % of the force range, or stated), so
    the model is built, with one warning naming the rows; a mislabelled setting is still
    refused."""
    rng = np.random.default_rng(36)
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), (0.0007, 0.002) + DYNO_SPEEDS)
    slow = sheet.velocity.abs() < 0.005
    sheet.loc[slow, "force"] += rng.uniform(-NEAR_ZERO_NOISE_N, NEAR_ZERO_NOISE_N, slow.sum())
    sheet.loc[slow, "force"] = np.where(sheet.velocity[slow] > 0, 1, -1) * \
        np.abs(sheet.force[slow])
    rows = tuple(f"ttx.csv row {j + 2}" for j in range(len(sheet)))
    pts = points_from(sheet, rows)
    stiffer = {"ls": "lower", "hs": "lower"}
    strict = check_dyno_points(pts, shock="TTX", adjusters=TRUTH.adjusters, stiffer=stiffer,
                               resolution_n=1e-9)
    assert any(f.severity == "error" for f in strict)  # relative only: refused, as before
    found = check_dyno_points(pts, shock="TTX", adjusters=TRUTH.adjusters, stiffer=stiffer)
    assert found and all(f.severity == "warning" for f in found)
    assert all("within the dyno's resolution" in f.message and "ttx.csv row" in f.message
               for f in found)
    shock = AdjustableShock("TTX", TRUTH.adjusters, pts)
    v = np.array([0.05, 0.3, -0.1])
    np.testing.assert_allclose(shock.at({"ls": 8, "hs": 2}).force(v),
                               TRUTH.force(v, {"ls": 8, "hs": 2}), rtol=HELD_OUT_RTOL)
    # settings written wrong (ls=4 and ls=12 swapped): a crossing far above the resolution
    swapped = sheet.copy()
    a, b = (swapped.ls == 4), (swapped.ls == 12)
    swapped.loc[a, "ls"], swapped.loc[b, "ls"] = 12, 4
    with pytest.raises(ShockModelError, match=r"curves cross"):
        AdjustableShock("TTX", TRUTH.adjusters, points_from(swapped, rows))
    # a resolution stated in the library is used instead of the default
    tight = AdjustableShock("TTX", TRUTH.adjusters, pts, force_resolution_n=50.0)
    assert tight.force_resolution_n == 50.0
    with pytest.raises(ShockModelError, match="force_resolution"):
        AdjustableShock("TTX", TRUTH.adjusters, pts, force_resolution_n=-1.0)


def test_sheet_settings_out_of_range_and_inseparable_refused():
    sheet = TRUTH.dyno_sheet([{"ls": 0, "hs": 2}, {"ls": 24, "hs": 2}, {"ls": 8, "hs": 0}],
                             DYNO_SPEEDS)
    with pytest.raises(ShockModelError, match=r"'ls' setting 24 is outside its range"):
        AdjustableShock("TTX", TRUTH.adjusters, points_from(sheet))
    sheet = TRUTH.dyno_sheet([{"ls": 0, "hs": 0}, {"ls": 8, "hs": 2}], DYNO_SPEEDS)
    with pytest.raises(ShockModelError, match="do not separate the adjusters"):
        AdjustableShock("TTX", TRUTH.adjusters, points_from(sheet))


def test_library_resolves_setting_names(ttx):
    lib = ShockLibrary([LinearShock("B20", 3500.0), ttx])
    assert lib.ids == ("B20", "TTX") and lib.adjustable_ids == ("TTX",)
    assert "TTX@ls=3,hs=1" in lib and "TTX@anything" in lib and "B21" not in lib
    assert lib["TTX@ls=3,hs=1"].id == "TTX@ls=3,hs=1"
    assert lib["TTX"].id == "TTX" and isinstance(lib["TTX"], TableShock)
    assert lib.canonical_name("TTX@hs=1,ls=3") == "TTX@ls=3,hs=1"
    assert lib.adjustable("TTX@ls=1") is ttx
    with pytest.raises(ShockModelError, match="setups.csv row 2 LF: shock 'TTX' has no "
                                              "adjuster 'xx'"):
        lib.get("TTX@xx=1", where="setups.csv row 2 LF")
    with pytest.raises(ShockModelError, match="'B20' is a fixed shock"):
        lib.get("B20@ls=1")
    with pytest.raises(ShockModelError, match="'B20' is not adjustable"):
        lib.adjustable("B20")


@pytest.mark.parametrize("units", ["SI", "imperial"])
@pytest.mark.parametrize("layout", ["signed", "magnitudes"])
def test_toml_round_trip(tmp_path, ttx, units, layout):
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)
    scale_v, scale_f = (1.0, 1.0) if units == "SI" else (1 / 0.0254, 1 / 4.4482216152605)
    if layout == "signed":
        out = sheet.assign(velocity=sheet.velocity * scale_v, force=sheet.force * scale_f)
    else:
        b = sheet[sheet.velocity > 0].reset_index(drop=True)
        r = sheet[sheet.velocity < 0].iloc[::-1].reset_index(drop=True)
        r = r.sort_values(["ls", "hs"], kind="stable").reset_index(drop=True)
        b = b.sort_values(["ls", "hs"], kind="stable").reset_index(drop=True)
        out = pd.DataFrame({"velocity": b.velocity * scale_v, "bump_force": b.force * scale_f,
                            "rebound_force": -r.force * scale_f, "ls": b.ls, "hs": b.hs,
                            "temperature": 40.0})
    (tmp_path / "dyno").mkdir()
    out.to_csv(tmp_path / "dyno" / "ttx.csv", index=False)
    (tmp_path / "shocks.toml").write_text(
        f'units = "{units}"\n[[shock]]\nid = "B20"\nkind = "linear"\ndamping = 3500.0\n'
        '[[shock]]\nid = "TTX"\nkind = "adjustable"\n'
        'adjusters = { ls = [0, 20], hs = [0, 4] }\ndefault = { ls = 8, hs = 2 }\n'
        'stiffer = { ls = "lower", hs = "lower" }\nstep = { hs = 0.25 }\n'
        'dyno = "dyno/ttx.csv"\nlag = 0.003\ncount = 4\nforce_resolution = 10.0\n')
    lib = read_shock_library(tmp_path / "shocks.toml")
    assert lib.adjustable("TTX").force_resolution_n == pytest.approx(10.0 / scale_f, rel=1e-12)
    s = {"ls": 5, "hs": 1.25}
    np.testing.assert_allclose(lib[ttx.name(s)].force([-0.3, 0.07, 0.4]),
                               ttx.at(s).force([-0.3, 0.07, 0.4]), rtol=1e-9)
    assert lib["TTX@ls=5,hs=1.25"].lag_s == 0.003 and lib.adjustable("TTX").count == 4
    (tmp_path / "out").mkdir()
    write_shock_library(lib, tmp_path / "out" / "lib.toml", units=units)
    again = read_shock_library(tmp_path / "out" / "lib.toml")
    assert again.adjustable("TTX").to_toml_dict(units) == {
        **lib.adjustable("TTX").to_toml_dict(units), "dyno": "../dyno/ttx.csv"}
    assert again.adjustable("TTX").to_toml_dict(units)["force_resolution"] == pytest.approx(10.0)
    np.testing.assert_allclose(again["TTX@ls=5"].force([0.2]), lib["TTX@ls=5"].force([0.2]))


def test_in_memory_library_writes_its_sheet(tmp_path, ttx):
    write_shock_library(ShockLibrary([ttx]), tmp_path / "lib.toml", units="imperial")
    assert (tmp_path / "lib.TTX.dyno.csv").is_file()
    again = read_shock_library(tmp_path / "lib.toml")
    np.testing.assert_allclose(again["TTX@ls=2,hs=3"].force([-0.2, 0.2]),
                               ttx.at({"ls": 2, "hs": 3}).force([-0.2, 0.2]), rtol=1e-9)


@pytest.mark.parametrize("edit, match", [
    ('adjusters = { ls = [0, 20], hs = [0, 4] }\ndyno = "nope.csv"', "dyno sheet .*nope.csv not found"),
    ('adjusters = { ls = [0, 20] }\ndyno = "ttx.csv"', "column 'hs' is neither"),
    ('adjusters = { ls = [0, 20], hs = [0, 4] }\ndyno = "ttx.csv"\nstiffer = { ls = "up" }',
     "stiffer.ls is 'up'"),
    ('adjusters = { ls = [0, 20], hs = [0, 4] }\ndyno = "ttx.csv"\ndefault = { ls = 40 }',
     "'ls' default 40 is outside its range"),
    ('adjusters = { ls = [0, 20], hs = [0, 4] }\ndyno = "ttx.csv"\nclicks = 3',
     "key 'clicks' is not a key of an 'adjustable' shock"),
])
def test_library_entry_refused(tmp_path, edit, match):
    TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS).to_csv(tmp_path / "ttx.csv",
                                                                index=False)
    (tmp_path / "shocks.toml").write_text(f'[[shock]]\nid = "TTX"\nkind = "adjustable"\n{edit}\n')
    with pytest.raises(ShockModelError, match=match):
        read_shock_library(tmp_path / "shocks.toml")
