"""Tests of planner.dyno.check: a shock's curve as a table, and a library's dyno check."""

import numpy as np
import pytest

from ident.data.units import from_si, to_si
from ident.errors import ShockModelError
from ident.models.adjustable import AdjustableShock, DynoPoints
from ident.models.library import ShockLibrary
from ident.models.shocks import LinearShock, TableShock
from ident.sim.dampers import ClickerDamper
from planner.dyno.check import (BUILDER_GRID, FORCE_DECIMALS, VELOCITY_DIGITS, check_dyno_library,
                                default_velocities, dyno_curve)
from planner.errors import PlannerError

#: The dyno's speeds [m/s], each side.
DYNO_SPEEDS = (0.01, 0.025, 0.05, 0.1, 0.2, 0.3, 0.5)
#: The table is the model evaluated at the velocities: equal to round-off (the imperial
#: table goes through one unit conversion each way).
TABLE_RTOL = 1e-12
#: A one-at-a-time sweep is fitted exactly: the check's errors are round-off.
EXACT_PCT = 1e-8

TRUTH = ClickerDamper()
LIBRARY_TOML = """units = "{units}"
[[shock]]
id = "B20"
kind = "{fixed_kind}"
damping = 3500.0
[[shock]]
id = "TTX"
kind = "adjustable"
adjusters = {{ ls = [0, 20], hs = [0, 4] }}
default = {{ ls = 8, hs = 2 }}
stiffer = {{ ls = "lower", hs = "lower" }}
step = {{ hs = 0.25 }}
dyno = "ttx.csv"
"""


def sweep_sheet():
    return TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)


def write_library(folder, sheet, *, fixed_kind="linear"):
    folder.mkdir(parents=True, exist_ok=True)
    sheet.to_csv(folder / "ttx.csv", index=False)
    (folder / "shocks.toml").write_text(LIBRARY_TOML.format(units="SI", fixed_kind=fixed_kind))
    return folder / "shocks.toml"


def bad_sheet():
    """A wrong-sign force at data row 18 (ls=4, -0.1 m/s) and the ls=4 curve 20 % softer
    than ls=8 (lower is stiffer): the curves cross at every speed."""
    sheet = sweep_sheet()
    sheet.loc[17, "force"] *= -1
    sheet.loc[(sheet.ls == 4) & (sheet.hs == 2), "force"] *= 0.8
    return sheet


@pytest.fixture(scope="module")
def library():
    sheet = sweep_sheet()
    pts = DynoPoints(sheet["velocity"].to_numpy(), sheet["force"].to_numpy(),
                     sheet[["ls", "hs"]].to_numpy(), ("ls", "hs"))
    ttx = AdjustableShock("TTX", TRUTH.adjusters, pts, default={"ls": 8, "hs": 2},
                          stiffer={"ls": "lower", "hs": "lower"}, step={"hs": 0.25})
    return ShockLibrary([LinearShock("B20", 3500.0), ttx])


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    return check_dyno_library(write_library(tmp_path_factory.mktemp("good"), sweep_sheet()))


@pytest.fixture(scope="module")
def bad(tmp_path_factory):
    return check_dyno_library(write_library(tmp_path_factory.mktemp("bad"), bad_sheet()))


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_table_is_the_model_at_the_setting(library, units):
    s = {"ls": 10, "hs": 1.25}
    given = [-20.0, -0.3, 0.02, 0.1, 0.45] if units == "SI" else [-12.0, -1.0, 0.5, 18.0]
    curve = dyno_curve(library, "TTX@hs=1.25,ls=10", velocities=given, units=units)
    assert curve.shock == "TTX@ls=10,hs=1.25" and curve.grid == "given"
    assert curve.velocity.tolist() == sorted(given)
    model = library.adjustable("TTX").at(s)
    want = from_si(model.force(to_si(np.array(sorted(given)), "velocity", units)), "force",
                   units)
    np.testing.assert_allclose(curve.force_n, to_si(want, "force", units), rtol=TABLE_RTOL)
    # the table's forces to 0.1 N or 0.1 lbf: what a dyno's force means (issue 36)
    np.testing.assert_allclose(curve.force, want, rtol=0, atol=0.5 * 10.0 ** -FORCE_DECIMALS)
    assert np.all(curve.force == np.round(curve.force, FORCE_DECIMALS))
    assert np.all(curve.force * curve.velocity > 0)
    assert curve.extrapolated.tolist() == [abs(v) > 0.5 + 1e-9 for v in curve.velocity_m_s]


def test_default_grid_is_the_measured_speeds(library):
    curve = dyno_curve(library, "TTX@ls=3", units="SI")
    assert curve.shock == "TTX@ls=3,hs=2" and curve.grid == "table knots"
    speeds = np.array(DYNO_SPEEDS)
    np.testing.assert_allclose(curve.velocity, np.concatenate([-speeds[::-1], [0], speeds]))
    np.testing.assert_allclose(curve.force, TRUTH.force(curve.velocity, {"ls": 3, "hs": 2}),
                               rtol=0.05)   # a held-out setting: the model's 5 % bar
    assert not curve.extrapolated.any()
    imperial = dyno_curve(library, "TTX@ls=3", units="imperial")
    # the measured speeds converted, to VELOCITY_DIGITS significant digits; the forces at
    # those speeds to 0.1 lbf (issue 36: 0.98425 in/s, not 0.984251968503937)
    np.testing.assert_allclose(imperial.velocity, curve.velocity / 0.0254,
                               rtol=0.5 * 10.0 ** (1 - VELOCITY_DIGITS))
    assert all(len(f"{abs(v):.10g}".replace(".", "").strip("0")) <= VELOCITY_DIGITS
               for v in imperial.velocity)
    np.testing.assert_allclose(imperial.force, from_si(imperial.force_n, "force", "imperial"),
                               rtol=0, atol=0.05 + 1e-9)
    # the id alone is the default setting, named in full
    assert dyno_curve(library, "TTX").shock == "TTX@ls=8,hs=2"


def test_fixed_shocks(library):
    curve = dyno_curve(library, "B20", units="imperial")
    g = np.array(BUILDER_GRID["imperial"])
    assert curve.shock == "B20" and curve.grid == "builder grid"
    np.testing.assert_allclose(curve.velocity, np.concatenate([-g[::-1], [0], g]))
    np.testing.assert_allclose(curve.force_n, 3500.0 * curve.velocity_m_s)
    table = TableShock("D8", [-0.5, 0.0, 0.2], [-900.0, 0.0, 300.0])
    v, grid = default_velocities(table)
    assert v.tolist() == [-0.5, 0.0, 0.2] and grid == "table knots"


def test_table_refuses_bad_names(library):
    with pytest.raises(ShockModelError, match="--shock: shock 'TTX': adjuster 'ls' setting "
                                              "30 is outside its range"):
        dyno_curve(library, "TTX@ls=30")
    with pytest.raises(ShockModelError, match="no adjuster 'lx'"):
        dyno_curve(library, "TTX@lx=3")
    with pytest.raises(ShockModelError, match="unknown shock id 'B21'"):
        dyno_curve(library, "B21")
    with pytest.raises(ShockModelError, match="'B20' is a fixed shock"):
        dyno_curve(library, "B20@ls=3")
    with pytest.raises(PlannerError, match="no velocities"):
        dyno_curve(library, "TTX", velocities=[])


def test_check_good_library(good):
    assert good.ok and good.n_errors == 0 and good.n_warnings == 0
    assert good.library_error == "" and good.fixed == ("B20",)
    (ttx,) = good.shocks
    assert ttx.shock is not None and len(ttx.curves) == len(TRUTH.sweep_settings())
    assert len(ttx.fit) == len(sweep_sheet())
    assert ttx.worst["setting"].tolist() == [c.name for c in ttx.curves]
    assert ttx.worst["worst_error_pct"].abs().max() < EXACT_PCT
    assert [t for t, _ in ttx.panels] == ["ls sweep at hs=2", "hs sweep at ls=8"]
    assert all(c.model_v_m_s is not None for c in ttx.curves)


def test_check_bad_sheet_names_every_finding(bad):
    assert not bad.ok and "row 18" in bad.library_error
    (ttx,) = bad.shocks
    assert ttx.shock is None and ttx.fit is None and len(ttx.curves) == 10
    errors = ttx.errors
    assert len(errors) == 3 and not ttx.warnings
    sign, *cross = errors
    assert sign.row.endswith("ttx.csv row 18") and "has the wrong sign" in sign.message
    assert sign.setting == "TTX@ls=4,hs=2" and sign.adjuster == ""
    # the crossing, on each side, at the row of the softer (ls=4) curve's 0.5 m/s point
    assert sorted(f.row.rsplit(" ", 1)[-1] for f in cross) == ["15", "28"]
    for f in cross:
        assert f.adjuster == "ls" and f.setting == "TTX@ls=4,hs=2"
        assert "softer than at TTX@ls=8,hs=2" in f.message and "curves cross" in f.message
    flagged = {c.name: [r for r, fl in zip(c.rows, c.flags) if fl] for c in ttx.curves}
    assert len(flagged["TTX@ls=4,hs=2"]) == 3 and sum(map(len, flagged.values())) == 3


def test_check_warnings_and_other_entries(tmp_path):
    sheet = sweep_sheet()   # a 2 % crossing at one speed: dyno noise, a warning
    sheet.loc[(sheet.ls == 0) & (sheet.velocity == 0.5), "force"] = float(
        TRUTH.force(0.5, {"ls": 4, "hs": 2})) * 0.98
    check = check_dyno_library(write_library(tmp_path / "warn", sheet))
    assert check.ok and check.n_warnings == 1 and check.shocks[0].shock is not None
    # a fixed shock the library refuses: the adjustable one is still checked
    check = check_dyno_library(write_library(tmp_path / "fixed", sweep_sheet(),
                                             fixed_kind="linnear"))
    assert not check.ok and check.n_errors == 1 and "unknown kind" in check.library_error
    assert check.shocks[0].shock is not None and not check.shocks[0].findings
    # a missing sheet: an error finding, not an exception
    (tmp_path / "fixed" / "ttx.csv").unlink()
    check = check_dyno_library(tmp_path / "fixed" / "shocks.toml")
    assert check.shocks[0].errors[0].message.count("not found") == 1
