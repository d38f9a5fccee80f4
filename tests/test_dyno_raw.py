"""Raw dyno files to dyno sheets (ident.dyno.raw, ``shockplan dyno import``).

The truth is a digressive adjustable-like damper on the virtual dyno (ident.dyno.virtual):
raw runs with noise, a gas-force offset and a lag, exported through a dyno map in a
dyno's own units and signs, must give back the curve at the measured settings.
"""

import re

import numpy as np
import pandas as pd
import pytest

from ident.dyno.raw import (DynoImport, import_dyno_runs, make_dyno_map, parse_settings,
                                 read_dyno_map, read_dyno_raw, write_dyno_sheet)
from ident.data.units import to_si
from ident.errors import DynoError
from ident.dyno.sheet_fit import fit_shock_to_dyno
from ident.models.shocks import TableShock
from ident.dyno.virtual import simulate_dyno_run
from planner.cli import main

#: The done-when of issue 26: the curve at the measured settings within 2 % of force
#: above 0.02 m/s, with noise, a gas force and a lag (measured: 0.6 % at worst).
RTOL_CURVE = 0.02
#: Gas force [N]: 5 N force noise over ~20 000 samples, fitted with the lag (measured 0.6 N).
ATOL_GAS_N = 2.0
#: Lag [s]: 4 ms fitted from the fast blocks' hysteresis (measured within 0.01 ms).
ATOL_LAG_S = 2e-4

PEAKS_M_S = [0.025, 0.05, 0.1, 0.2, 0.3, 0.5]
GAS_N, LAG_S = 150.0, 0.004
SETTINGS = ({"ls": 6.0, "hs": 2.0}, {"ls": 14.0, "hs": 2.0})
MAP_TOML = """format = "dyno-map/1"
name = "test dyno"

[columns.time]
source = "Time ms"
units = "ms"

[columns.force]
source = "Load"
units = "lbf"
sign = -1

[columns.displacement]
source = "Pos"
units = "mm"
sign = 1
offset = 100.0

[columns.temperature]
source = "Temp"
units = "degF"
"""


def truth(ls, hs):
    """A digressive damper whose low-speed slopes soften with ls clicks (stiffer lower)."""
    low = 12000.0 * (1.0 - ls / 30.0)
    high = 2500.0 * (1.0 - hs / 10.0)
    kb, kr = 0.05, 0.08
    return TableShock(f"T@ls={ls:g},hs={hs:g}", [-0.6, -kr, 0.0, kb, 0.6],
                      [-(1.5 * low * kr + 1.5 * high * (0.6 - kr)), -1.5 * low * kr, 0.0,
                       low * kb, low * kb + high * (0.6 - kb)])


def export(frame, path):
    """Write a virtual-dyno run as the test dyno exports it (MAP_TOML's units and signs)."""
    raw = pd.DataFrame({"Time ms": frame["time"] * 1e3,
                        "Load": -frame["force"] / to_si(1.0, "force", "imperial"),
                        "Pos": frame["displacement"] * 1e3 + 100.0,
                        "Temp": frame["temperature"] * 9 / 5 + 32})
    raw.to_csv(path, index=False)
    return path


def run_frame(setting, *, seed, temperature=40.0, **kw):
    args = dict(peak_velocities_m_s=PEAKS_M_S, stroke_m=0.025, cycles_per_speed=3,
                lag_s=LAG_S, gas_force_n=GAS_N, noise_force_n=5.0, noise_disp_m=1e-5,
                temperature_c=temperature, rng=np.random.default_rng(seed))
    args.update(kw)
    return simulate_dyno_run(truth(**setting), **args)


@pytest.fixture(scope="module")
def dyno_files(tmp_path_factory):
    root = tmp_path_factory.mktemp("dyno")
    (root / "map.toml").write_text(MAP_TOML)
    files = [export(run_frame(s, seed=j), root / f"run{j}.csv") for j, s in enumerate(SETTINGS)]
    return root, files


@pytest.fixture(scope="module")
def imports(dyno_files):
    root, files = dyno_files
    return [import_dyno_runs([f], settings=s, dyno_map=root / "map.toml")
            for f, s in zip(files, SETTINGS)]


def test_import_recovers_the_curves(imports):
    """Done-when: the curves at the measured settings within 2 % above 0.02 m/s."""
    for result, setting in zip(imports, SETTINGS):
        assert isinstance(result, DynoImport) and dict(result.settings) == setting
        v, f = result.points()
        assert np.all(np.abs(v) > 0.02) and v.size == 2 * len(PEAKS_M_S)
        np.testing.assert_allclose(f, truth(**setting).force(v), rtol=RTOL_CURVE)
        run, = result.runs
        assert run.gas_force_n == pytest.approx(GAS_N, abs=ATOL_GAS_N)
        assert run.lag_s == pytest.approx(LAG_S, abs=ATOL_LAG_S)
        assert run.cycles == 3 * len(PEAKS_M_S) and all(b.cycles == 3 for b in run.blocks)
        assert run.temperature_c == pytest.approx(40.0) and not result.warnings
        b = run.blocks[-1]  # the averaged loop spans the block's speeds
        assert b.loop_velocity_m_s.max() == pytest.approx(b.bump_velocity_m_s, rel=0.02)


def test_clicks_order_the_recovered_curves(imports):
    """Stiffer at fewer ls clicks, the known slopes' ratio at low speed."""
    (v6, f6), (v14, f14) = (r.points() for r in imports)
    low = np.abs(v6) < 0.03
    np.testing.assert_allclose(f14[low] / f6[low], (1 - 14 / 30) / (1 - 6 / 30), rtol=0.02)


def test_temperature_drift_between_runs_is_warned(tmp_path, caplog):
    files = [export(run_frame(SETTINGS[0], seed=s, temperature=t, peak_velocities_m_s=[0.1, 0.3],
                              cycles_per_speed=2), tmp_path / f"r{s}.csv")
             for s, t in ((1, 40.0), (2, 47.0))]
    (tmp_path / "map.toml").write_text(MAP_TOML)
    with caplog.at_level("WARNING"):
        result = import_dyno_runs(files, settings=SETTINGS[0], dyno_map=tmp_path / "map.toml")
    assert len(result.warnings) == 1 and "40.0 deg C (r1.csv) to 47.0 deg C (r2.csv)" in \
        result.warnings[0]
    assert "temperature drift" in caplog.text


def test_canonical_csv_needs_no_map(tmp_path):
    frame = run_frame(SETTINGS[0], seed=5, peak_velocities_m_s=[0.1, 0.3], cycles_per_speed=2,
                      temperature=None)
    frame.to_csv(tmp_path / "canon.csv", index=False)
    got = read_dyno_raw(tmp_path / "canon.csv")
    assert list(got.columns) == ["time", "force", "displacement"]
    result = import_dyno_runs([tmp_path / "canon.csv"], settings={})
    v, f = result.points()
    np.testing.assert_allclose(f, truth(**SETTINGS[0]).force(v), rtol=RTOL_CURVE)
    assert result.runs[0].temperature_c is None and "temperature" not in result.columns


#: Curves from millisecond stamps against those from exact ones: the stamps' rounding
#: (up to half a millisecond) is not in the data, which is on the dyno's uniform clock.
RTOL_ROUNDED_STAMPS = 1e-3


def test_millisecond_time_stamps_are_read_as_the_grid_they_round(tmp_path, caplog):
    """A dyno PC that writes time in whole milliseconds at 512 Hz (steps of 1 or 2 ms, 50 %
    off the 1.95 ms interval) was refused; its stamps round a uniform clock: the run is read
    on that grid, said in one warning, and gives the curve of the exact stamps."""
    frame = run_frame(SETTINGS[0], seed=5, peak_velocities_m_s=[0.1, 0.3], cycles_per_speed=2,
                      temperature=None, fs_hz=512.0)
    frame.to_csv(tmp_path / "exact.csv", index=False)
    frame["time"] = np.round(frame["time"], 3)
    frame.to_csv(tmp_path / "ms.csv", index=False)
    with caplog.at_level("WARNING"):
        rounded = import_dyno_runs([tmp_path / "ms.csv"], settings={})
    said = [r.getMessage() for r in caplog.records if "rounded to" in r.getMessage()]
    assert len(said) == 1 and "0.001 s" in said[0] and "512 Hz grid" in said[0], said
    exact = import_dyno_runs([tmp_path / "exact.csv"], settings={})
    (v0, f0), (v1, f1) = exact.points(), rounded.points()
    np.testing.assert_allclose(v1, v0, rtol=RTOL_ROUNDED_STAMPS)
    np.testing.assert_allclose(f1, f0, rtol=RTOL_ROUNDED_STAMPS)


#: Sheet points of a run resampled to a chosen rate against those at its own rate: the peaks
#: are sampled at other instants, and going down filters out part of the 5 N force noise,
#: which moves the gas-force fit by up to 4 N (measured 0.1 % up, 0.7 % down at 580 N).
RTOL_CHOSEN_RATE = 1e-2


@pytest.mark.parametrize("to_hz", [1000.0, 400.0])
def test_raw_runs_are_read_at_a_chosen_rate(tmp_path, caplog, capsys, to_hz):
    """``dyno import --resample HZ``: the 512 Hz run stamped in whole milliseconds, onto a
    uniform base at HZ (up, or down anti-aliased), said in one line; the same curve."""
    frame = run_frame(SETTINGS[0], seed=5, peak_velocities_m_s=[0.1, 0.3], cycles_per_speed=2,
                      temperature=None, fs_hz=512.0)
    frame.to_csv(tmp_path / "exact.csv", index=False)
    frame["time"] = np.round(frame["time"], 3)
    frame.to_csv(tmp_path / "ms.csv", index=False)
    assert read_dyno_raw(tmp_path / "ms.csv", resample_hz=to_hz)["time"].diff().dropna() \
        .to_numpy() == pytest.approx(1.0 / to_hz, rel=1e-9)
    caplog.clear()
    with caplog.at_level("WARNING"):
        assert main(["-q", "dyno", "import", str(tmp_path / "ms.csv"), "--resample",
                     f"{to_hz:g}", "--out", str(tmp_path / "sheet.csv")]) == 0
    said = [r.getMessage() for r in caplog.records if "as asked" in r.getMessage()]
    assert len(said) == 1 and f"uniform {to_hz:g} Hz" in said[0], said
    assert ("anti-aliased" in said[0]) == (to_hz < 512.0)
    exact = import_dyno_runs([tmp_path / "exact.csv"], settings={}).sheet()
    sheet = pd.read_csv(tmp_path / "sheet.csv")
    np.testing.assert_allclose(sheet["velocity"], exact["velocity"], rtol=RTOL_CHOSEN_RATE)
    np.testing.assert_allclose(sheet["force"], exact["force"], rtol=RTOL_CHOSEN_RATE)


def test_dropped_sample_among_millisecond_stamps_is_refused(tmp_path):
    """Rounded stamps widen the tolerance by the rounding only: a dropped sample still is
    one."""
    frame = run_frame(SETTINGS[0], seed=5, peak_velocities_m_s=[0.1, 0.3], cycles_per_speed=2,
                      temperature=None, fs_hz=512.0)
    frame["time"] = np.round(frame["time"], 3)
    frame.drop(index=700).to_csv(tmp_path / "ms.csv", index=False)
    with pytest.raises(DynoError, match=r"\(time\) is not uniformly sampled"):
        import_dyno_runs([tmp_path / "ms.csv"], settings={})


# ---------------------------------------------------------------------------------------
# refusals
# ---------------------------------------------------------------------------------------

def _small():
    return run_frame(SETTINGS[0], seed=9, peak_velocities_m_s=[0.2, 0.4], cycles_per_speed=2,
                     temperature=None)


def _flat(df):
    df["force"] = 12.5
    return df


def _no_disp(df):
    return df.drop(columns="displacement")


def _nan(df):
    df.loc[100, "force"] = np.nan
    return df


def _backwards(df):
    df.loc[50, "time"] = df.loc[49, "time"]
    return df


def _dropped(df):
    return df.drop(index=500)


def _one_cycle(df):
    return df[df["time"] < df["time"].iloc[-1] * 0.3]


@pytest.mark.parametrize("damage, match", [
    (_flat, r"column 'force' \(force\) is flat .* the channel is dead"),
    (_no_disp, r"no column 'displacement' \(displacement\) \(velocity alone is not enough"),
    (_nan, r"column 'force' \(force\) has 1 NaN, empty or non-numeric value\(s\), the first "
           r"at data row 101"),
    (_backwards, r"\(time\) is not increasing at data row 51"),
    (_dropped, r"\(time\) is not uniformly sampled: data row 501"),
    (_one_cycle, r"too few cycles: .* at least 2 whole strokes"),
])
def test_bad_raw_file_refused(damage, match, tmp_path):
    path = tmp_path / "bad.csv"
    damage(_small()).to_csv(path, index=False)
    with pytest.raises(DynoError, match=match) as exc:
        import_dyno_runs([path], settings={"ls": 1.0})
    assert str(path) in str(exc.value)


def test_wrong_force_sign_refused(tmp_path):
    df = _small()
    df["force"] = -df["force"]
    df.to_csv(tmp_path / "s.csv", index=False)
    with pytest.raises(DynoError, match=r"not passive; check the signs of 'force' and "
                                        r"'displacement'"):
        import_dyno_runs([tmp_path / "s.csv"], settings={})


@pytest.mark.parametrize("columns, match", [
    ({"time": {"source": "t", "units": "s"}, "force": {"source": "F", "units": "N"},
      "displacement": {"source": "x", "units": "m", "sign": 1}}, r"\[columns.force\]: missing "
                                                                r"'sign'"),
    ({"time": {"source": "t", "units": "s"}, "force": {"source": "F", "units": "mm", "sign": 1},
      "displacement": {"source": "x", "units": "m", "sign": 1}}, "'mm' is not a force unit"),
    ({"time": {"source": "t", "units": "s"}, "force": {"source": "F", "units": "N", "sign": 1}},
     r"no \[columns.displacement\]"),
    ({"time": {"source": "t", "units": "s", "sign": 1}}, "time and temperature have no sign"),
    ({"temprature": {"source": "T", "units": "degC"}}, r"did you mean 'temperature'"),
])
def test_bad_map_refused(columns, match):
    with pytest.raises(DynoError, match=match):
        make_dyno_map(columns)


def test_map_file_typo_refused(tmp_path):
    path = tmp_path / "m.toml"
    path.write_text(MAP_TOML.replace('name = "test dyno"', 'nmae = "x"'))
    with pytest.raises(DynoError, match=r"unknown top-level key 'nmae' \(did you mean 'name'"):
        read_dyno_map(path)


@pytest.mark.parametrize("text, match", [
    ("ls6", "not name=value"), ("ls=6,ls=7", "given twice"), ("ls=six", "not a finite"),
    ("force=1", "not an adjuster name"),
])
def test_bad_settings_refused(text, match):
    with pytest.raises(DynoError, match=match):
        parse_settings(text)


# ---------------------------------------------------------------------------------------
# the sheet
# ---------------------------------------------------------------------------------------

def test_sheet_written_appended_and_read(imports, tmp_path):
    sheet = tmp_path / "sheet.csv"
    write_dyno_sheet(imports[0], sheet)
    first = sheet.read_bytes()
    assert first.startswith(b"velocity,force,ls,hs,temperature,cycles,lag,source,units\n")
    with pytest.raises(FileExistsError):
        write_dyno_sheet(imports[1], sheet)
    write_dyno_sheet(imports[1], sheet, append=True)
    assert sheet.read_bytes().startswith(first)  # every byte the sheet had is kept
    table = pd.read_csv(sheet)
    assert len(table) == 4 * len(PEAKS_M_S) and sorted(set(table["ls"])) == [6.0, 14.0]
    assert (table["units"] == "SI").all()
    # the existing dyno fit reads one setting's rows as a table
    rows = table[table["ls"] == 6.0][["velocity", "force"]]
    shock = fit_shock_to_dyno(rows, id="T6")
    np.testing.assert_allclose(shock.force(rows["velocity"]), rows["force"], rtol=1e-12)


def test_a_sheet_of_the_earlier_layout_is_read_and_appended_to_as_it_is(imports, tmp_path):
    """A sheet whose first line is '# units: imperial' (no units column): appended rows
    keep its layout; a units column that disagrees with the line is refused."""
    new = tmp_path / "new.csv"
    write_dyno_sheet(imports[0], new, units="imperial")
    lines = new.read_text().splitlines()
    old = tmp_path / "old.csv"
    old.write_text("# units: imperial\n" + "".join(ln.rsplit(",", 1)[0] + "\n" for ln in lines))
    before = old.read_bytes()
    with pytest.raises(DynoError, match=r"in imperial units"):
        write_dyno_sheet(imports[1], old, append=True)  # SI rows
    write_dyno_sheet(imports[1], old, units="imperial", append=True)
    text = old.read_text()
    assert text.startswith(before.decode()) and "imperial" not in text.split("\n", 1)[1]
    both = tmp_path / "both.csv"
    write_dyno_sheet(imports[0], both, units="imperial")
    both.write_text("# units: SI\n" + both.read_text())
    with pytest.raises(DynoError, match=r"the line '# units: SI' and the column 'units'"):
        write_dyno_sheet(imports[1], both, units="imperial", append=True)


def test_append_refuses_other_columns_and_units(imports, tmp_path):
    sheet = tmp_path / "sheet.csv"
    write_dyno_sheet(imports[0], sheet, units="imperial")
    before = sheet.read_bytes()
    with pytest.raises(DynoError, match=r"in imperial units .*\(--units imperial\)"):
        write_dyno_sheet(imports[1], sheet, append=True)
    other = DynoImport(settings={"clicks": 3.0}, runs=imports[1].runs)
    with pytest.raises(DynoError, match=r"missing \['clicks'\], extra \['ls', 'hs'\]"):
        write_dyno_sheet(other, sheet, units="imperial", append=True)
    assert sheet.read_bytes() == before
    v = pd.read_csv(sheet)["velocity"].to_numpy()
    np.testing.assert_allclose(to_si(v, "velocity", "imperial"),
                               imports[0].sheet()["velocity"], rtol=1e-5)


def test_cli_dyno_import_end_to_end(dyno_files, tmp_path, capsys):
    root, files = dyno_files
    sheet = tmp_path / "ttx.csv"
    base = ["dyno", "import", "--map", str(root / "map.toml"), "--out", str(sheet)]
    assert main([*base[:2], str(files[0]), *base[2:], "--settings", "ls=6,hs=2"]) == 0
    out = capsys.readouterr().out
    assert "run0.csv: 18 cycles, 6 speeds 0.025-0.50" in out and "wrote 12 rows" in out
    assert re.search(r"gas force 1(49|50|51)\.\d N \(removed\), lag (3\.9\d|4\.0\d) ms", out)
    assert main([*base[:2], str(files[1]), *base[2:], "--settings", "ls=14,hs=2",
                 "--append"]) == 0
    assert "appended 12 rows" in capsys.readouterr().out
    table = pd.read_csv(sheet)
    assert list(table["source"].unique()) == ["run0.csv", "run1.csv"]
    # a mismatch is one line naming the sheet and the fix
    assert main([*base[:2], str(files[1]), *base[2:], "--settings", "ls=14", "--append"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("shockplan: error: ") and "missing [], extra ['hs']" in err


#: Held-out settings from a library built on imported sheets, at the dyno's speeds above
#: 0.02 m/s (the issue's bar: 5 %; the click model alone 3.4 %, the import 0.6 %).
RTOL_HELD_OUT = 0.05


def test_imported_sweeps_predict_held_out_settings(tmp_path):
    """Issue 26's done-when end to end: raw runs of a known clicker (noise, gas force,
    lag) at its one-at-a-time sweep settings -> dyno import -> a sheet -> an adjustable
    shock in a library -> every setting on a grid the dyno never ran within 5 %."""
    from ident.models.library import read_shock_library
    from ident.sim.dampers import ClickerDamper

    damper = ClickerDamper()
    sweep = damper.sweep_settings(ls_step=10, hs_step=2, ls_held=10, hs_held=2)
    sheet = tmp_path / "ttx.csv"
    for j, s in enumerate(sweep):
        raw = simulate_dyno_run(damper.shock_at(s), peak_velocities_m_s=PEAKS_M_S,
                                stroke_m=0.025, cycles_per_speed=2, lag_s=LAG_S,
                                gas_force_n=GAS_N, noise_force_n=5.0, noise_disp_m=1e-5,
                                fs_hz=500.0, rng=np.random.default_rng(100 + j))
        raw.to_csv(tmp_path / f"run{j}.csv", index=False)
        result = import_dyno_runs([tmp_path / f"run{j}.csv"], settings=s)
        write_dyno_sheet(result, sheet, append=j > 0)
    (tmp_path / "shocks.toml").write_text(
        '[[shock]]\nid = "TTX"\nkind = "adjustable"\nadjusters = { ls = [0, 20], hs = [0, 4] }'
        '\ndefault = { ls = 10, hs = 2 }\nstep = { hs = 0.5 }\ndyno = "ttx.csv"\n')
    ttx = read_shock_library(tmp_path / "shocks.toml").adjustable("TTX")
    v = np.concatenate([-np.asarray(PEAKS_M_S), PEAKS_M_S])
    measured = {(s["ls"], s["hs"]) for s in sweep}
    worst = 0.0
    for s in ttx.settings_grid(step={"ls": 1, "hs": 0.5}):
        if (s["ls"], s["hs"]) in measured:
            continue
        err = np.abs(ttx.at(s).force(v) / damper.force(v, s) - 1.0)
        worst = max(worst, float(err.max()))
    assert worst < RTOL_HELD_OUT, worst
