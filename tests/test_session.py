"""Tests of ident.data.session and ident.data.runs: rig-session folders and run tables."""

from __future__ import annotations

import logging
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tomli_w
from numpy.testing import assert_allclose, assert_array_equal

import ident.data.session as session_mod
from ident.data.channels import AERO_INPUTS, ALL_CHANNELS, CORNERS, RIG_INPUTS, WHEELLOADER_INPUTS
from ident.errors import SessionError
from ident.data.runs import RunTable, read_run_table, write_run_table
from ident.data.session import (
    Run,
    Session,
    make_session,
    read_session,
    write_session,
)

RTOL_ROUND_TRIP = 1e-12  # float64 written with repr, plus one SI <-> imperial factor
IN_M = 0.0254  # in -> m, by definition
LBF_N = 4.4482216152605  # lbf -> N, by definition

FS_HZ = 100.0
N_SAMPLES = 200
SHOCKS_TOML = """\
units = "SI"

[[shock]]
id = "B20"
kind = "linear"
damping = 3502.5

[[shock]]
id = "D8"
kind = "linear"
damping = 1500.0

[[shock]]
id = "F12"
kind = "linear"
damping = 2100.0
"""
RESPONSES = ("shock_velocity_LF", "shock_velocity_RF", "shock_velocity_LR",
             "shock_velocity_RR", "tire_force_LF", "ride_height_RR")
RUN_SPECS = (  # name, role, setup
    ("baseline-1", "baseline", ("B20", "B20", "B20", "B20")),
    ("swap-LF", "swap", ("D8", "B20", "B20", "B20")),
    ("validation", "validation", ("F12", "F12", "B20", "B20")),
)
# a typical size per channel, so the random data look like rig data [SI]
SCALE = {"aero_heave": 800.0, "aero_roll": 300.0, "aero_pitch": 500.0,
         "wheelloader": 0.01, "shock_velocity": 0.2, "tire_force": 2000.0,
         "ride_height": 0.05}


def _scale(channel):
    return SCALE.get(channel, SCALE.get(channel.rpartition("_")[0]))


def _random_run(rng, name, role, setup, *, fs_hz=FS_HZ, n=N_SAMPLES):
    time_s = 3.0 + np.arange(n) / fs_hz
    channels = {c: _scale(c) * (rng.standard_normal(n) + rng.uniform(-2, 2))
                for c in RIG_INPUTS + RESPONSES}
    return Run(name=name, file=f"runs/{name}.csv", setup=dict(zip(CORNERS, setup)),
               role=role, time_s=time_s, channels=channels, fs_hz=fs_hz)


@pytest.fixture
def rng():
    return np.random.default_rng(20240917)


@pytest.fixture
def shocks(tmp_path):
    from ident.models.library import read_shock_library

    path = tmp_path / "library.toml"
    path.write_text(SHOCKS_TOML)
    return read_shock_library(path)


@pytest.fixture
def session(rng, shocks):
    runs = [_random_run(rng, *spec) for spec in RUN_SPECS]
    return make_session("synthetic 8-post", runs, shocks)


@pytest.fixture
def session_dir(session, tmp_path):
    return write_session(session, tmp_path / "session")


def _assert_same_data(a, b):
    assert [r.name for r in a.runs] == [r.name for r in b.runs]
    assert a.fs_hz == pytest.approx(b.fs_hz, rel=RTOL_ROUND_TRIP)
    for ra, rb in zip(a.runs, b.runs):
        assert ra.setup == rb.setup and ra.role == rb.role
        assert list(ra.channels) == list(rb.channels)
        assert_allclose(rb.time_s, ra.time_s, rtol=RTOL_ROUND_TRIP, atol=0)
        for c in ra.channels:
            assert_allclose(rb.channels[c], ra.channels[c], rtol=RTOL_ROUND_TRIP, atol=0,
                            err_msg=f"{ra.name}: {c}")


# --------------------------------------------------------------------------------------
# round trips
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("run_format", ["csv", "parquet"])
def test_write_read_round_trip(session, tmp_path, run_format):
    folder = write_session(session, tmp_path / "out", run_format=run_format)
    assert sorted(p.name for p in (folder / "runs").iterdir()) == sorted(
        f"{name}.{run_format}" for name, _, _ in RUN_SPECS)
    back = read_session(folder)
    _assert_same_data(session, back)
    assert back.path == folder and back.name == session.name and back.units == "SI"
    assert back.shock_library_file == "shocks.toml"
    assert list(back.shocks) == ["B20", "D8", "F12"]
    assert back.fs_hz == pytest.approx(FS_HZ, rel=RTOL_ROUND_TRIP)
    assert back.run("swap-LF").file == f"runs/swap-LF.{run_format}"
    # the manifest path works as well as the folder
    assert read_session(folder / "session.toml").run_names == back.run_names


#: float32's relative precision (half a unit in the last of its 24 bits), plus the
#: imperial factor's rounding.
RTOL_FLOAT32 = 2.0 ** -24 + 1e-12


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_float32_parquet_runs_round_trip_to_float32_precision(session, tmp_path, units):
    """Parquet runs stored as float32 (the demo's session): time exact (64-bit, so still
    uniform), every channel within float32's precision, plain pandas reads them, and they
    are a fraction of the float64 file's size."""
    import pyarrow.parquet as pq

    single = write_session(session, tmp_path / "f32", run_format="parquet", units=units,
                           float_dtype="float32")
    double = write_session(session, tmp_path / "f64", run_format="parquet", units=units)
    back = read_session(single)
    for ra, rb in zip(session.runs, back.runs):
        assert_array_equal(rb.time_s, ra.time_s)
        for c in ra.channels:
            assert_allclose(rb.channels[c], ra.channels[c], rtol=RTOL_FLOAT32, atol=0,
                            err_msg=f"{ra.name}: {c}")
    path = single / "runs" / "baseline-1.parquet"
    frame = pd.read_parquet(path)
    assert frame["time"].dtype == np.float64
    assert set(frame.dtypes.drop("time").astype(str)) == {"float32"}
    assert pq.read_metadata(path).metadata[b"units"] == units.encode()
    assert path.stat().st_size < (double / "runs" / "baseline-1.parquet").stat().st_size


def test_float32_is_for_parquet_only(session, tmp_path):
    with pytest.raises(ValueError, match="float_dtype 'float32' with run_format 'csv'"):
        write_session(session, tmp_path / "a", float_dtype="float32")
    with pytest.raises(ValueError, match="float_dtype 'half'"):
        write_session(session, tmp_path / "b", run_format="parquet", float_dtype="half")
    with pytest.raises(ValueError, match="float_dtype='float32' is for Parquet files"):
        write_run_table(tmp_path / "t.csv", np.arange(4) / 8.0, {"aero_heave": np.zeros(4)},
                        float_dtype="float32")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["library.toml"]  # nothing written


def test_manifest_is_the_spec_layout(session_dir):
    doc = tomllib.loads((session_dir / "session.toml").read_text())
    assert doc["format"] == "rig-session/1" and doc["units"] == "SI"
    assert doc["shock_library"] == "shocks.toml" and "channels" not in doc
    assert doc["run"][1] == {"name": "swap-LF", "file": "runs/swap-LF.csv", "role": "swap",
                             "setup": {"LF": "D8", "RF": "B20", "LR": "B20", "RR": "B20"}}
    header = pd.read_csv(session_dir / "runs" / "baseline-1.csv", nrows=0).columns
    assert list(header) == ["time", *RIG_INPUTS,
                            *[c for c in ALL_CHANNELS if c in RESPONSES], "units"]


def test_csv_is_written_at_full_precision(rng, tmp_path):
    time_s = np.arange(50) / 64.0
    channels = {"aero_heave": rng.standard_normal(50) * np.exp(rng.uniform(-30, 30, 50)),
                "tire_force_RR": rng.standard_normal(50)}
    write_run_table(tmp_path / "t.csv", time_s, channels)
    table = read_run_table(tmp_path / "t.csv")
    assert_array_equal(table.time_s, time_s)  # SI to SI: repr round trip is exact
    for c, x in channels.items():
        assert_array_equal(table.channels[c], x)
    assert table.fs_hz == 64.0 and table.path == tmp_path / "t.csv"
    with pytest.raises(FileExistsError, match="t.csv: already exists"):
        write_run_table(tmp_path / "t.csv", time_s, channels)


def test_imperial_twin(session, tmp_path):
    si_dir = write_session(session, tmp_path / "si")
    imp_dir = write_session(session, tmp_path / "imperial", units="imperial")
    assert tomllib.loads((imp_dir / "session.toml").read_text())["units"] == "imperial"

    si_file = pd.read_csv(si_dir / "runs" / "swap-LF.csv")
    imp_file = pd.read_csv(imp_dir / "runs" / "swap-LF.csv")
    expected_factor = {"time": 1.0, "wheelloader_LF": IN_M, "ride_height_RR": IN_M,
                       "shock_velocity_LR": IN_M, "aero_heave": LBF_N,
                       "tire_force_LF": LBF_N, "aero_roll": LBF_N * IN_M}
    for column, factor in expected_factor.items():  # file values in in, in/s, lbf, lbf*in
        assert_allclose(imp_file[column] * factor, si_file[column], rtol=RTOL_ROUND_TRIP,
                        atol=0, err_msg=column)
    library = tomllib.loads((imp_dir / "shocks.toml").read_text())
    assert library["units"] == "imperial"
    assert library["shock"][0]["damping"] == pytest.approx(3502.5 * IN_M / LBF_N,
                                                           rel=RTOL_ROUND_TRIP)

    si, imp = read_session(si_dir), read_session(imp_dir)
    assert imp.units == "imperial" and si.units == "SI"
    _assert_same_data(si, imp)
    assert imp.shocks["B20"].to_pwl().force(1.0) == pytest.approx(3502.5,
                                                                 rel=RTOL_ROUND_TRIP)
    # writing the imperial session again keeps its unit system by default
    again = write_session(imp, tmp_path / "again")
    assert tomllib.loads((again / "session.toml").read_text())["units"] == "imperial"


def test_channels_mapping(session, tmp_path):
    folder = tmp_path / "team"
    (folder / "runs").mkdir(parents=True)
    (folder / "shocks.toml").write_text(SHOCKS_TOML)
    run = session.runs[0]
    team = {f"wheelloader_{c}": f"WL_{c}_Disp" for c in CORNERS}
    team["time"] = "Time [s]"
    frame = pd.DataFrame({team.get(c, c): x for c, x in
                          {"time": run.time_s, **run.channels}.items()})
    frame["Comment"] = "free text"  # not a channel: ignored
    frame["wheelloader_LF"] = 99.0  # the mapped column wins over a canonical-looking one
    frame.to_csv(folder / "runs" / "b1.csv", index=False)
    (folder / "session.toml").write_text(
        'format = "rig-session/1"\nname = "team export"\nunits = "SI"\n'
        'shock_library = "shocks.toml"\n\n[[run]]\nname = "b1"\nfile = "runs/b1.csv"\n'
        'setup = { LF = "B20", RF = "B20", LR = "B20", RR = "B20" }\n\n'
        + tomli_w.dumps({"channels": team})
    )
    back = read_session(folder)
    assert back.channel_map == team
    got = back.run("b1")
    assert got.role == "other"
    assert list(got.channels) == list(run.channels)
    for c, x in run.channels.items():
        assert_allclose(got.channels[c], x, rtol=RTOL_ROUND_TRIP, atol=0, err_msg=c)
    # written back with canonical names and no mapping
    again = write_session(back, tmp_path / "canonical")
    assert "channels" not in tomllib.loads((again / "session.toml").read_text())
    _assert_same_data(back, read_session(again))


def test_unknown_manifest_keys_are_preserved(session_dir, tmp_path):
    text = (session_dir / "session.toml").read_text()
    text = text.replace('units = "SI"\n', 'units = "SI"\nrig = "8-post"\n', 1)
    text += '\n[notes]\ndriver = "none"\n'
    (session_dir / "session.toml").write_text(text)
    back = read_session(session_dir)
    assert back.extra == {"rig": "8-post", "notes": {"driver": "none"}}
    again = read_session(write_session(back, tmp_path / "again"))
    assert again.extra == back.extra


def test_run_dynamic_lookup_and_read_only(session):
    run = session.run("swap-LF")
    assert run.n_samples == N_SAMPLES
    x = run.channels["tire_force_LF"]
    dyn = run.dynamic("tire_force_LF")
    assert_allclose(dyn, x - x.mean(), rtol=0, atol=1e-12 * np.abs(x).max())
    assert abs(dyn.mean()) < 1e-12 * np.abs(x).max()
    with pytest.raises(ValueError, match="read-only"):
        x[0] = 0.0
    with pytest.raises(SessionError, match="run 'swap-LF' has no channel 'spring_force_LF'"):
        run.dynamic("spring_force_LF")
    with pytest.raises(SessionError, match=r"no run 'nope'; its runs are \['baseline-1'"):
        session.run("nope")


def test_make_session_copies_and_does_not_require_responses(rng, shocks):
    run = _random_run(rng, "only-inputs", "other", ("B20",) * 4)
    run = Run(name=run.name, file=run.file, setup=run.setup, time_s=run.time_s,
              channels={c: run.channels[c] for c in RIG_INPUTS}, fs_hz=run.fs_hz)
    s = make_session("inputs only", [run], shocks, units="imperial")
    assert isinstance(s, Session) and s.path is None and s.units == "imperial"
    assert list(s.runs[0].channels) == list(RIG_INPUTS)  # no shock_velocity_XX needed here


# --------------------------------------------------------------------------------------
# bad input: one clear SessionError each
# --------------------------------------------------------------------------------------


def _edit_manifest(edit):
    def mutate(folder):
        path = folder / "session.toml"
        doc = tomllib.loads(path.read_text())
        edit(doc)
        path.write_text(tomli_w.dumps(doc))
    return mutate


def _edit_run(edit, name="swap-LF"):
    def mutate(folder):
        path = folder / "runs" / f"{name}.csv"
        frame = edit(pd.read_csv(path).drop(columns="units"))  # as the marker line was
        frame.to_csv(path, index=False)
    return mutate


def _set(frame, column, rows, value):
    frame[column] = frame[column].astype(object if isinstance(value, str) else float)
    frame.loc[rows, column] = value
    return frame


def _shift_time(frame, row, dt):
    frame.loc[row, "time"] += dt
    return frame


def _swap_times(frame):
    frame.loc[[10, 11], "time"] = frame.loc[[11, 10], "time"].to_numpy()
    return frame


def _write(relpath, text):
    def mutate(folder):
        (folder / relpath).write_text(text)
    return mutate


def _remove(relpath):
    def mutate(folder):
        target = folder / relpath
        shutil.rmtree(target) if target.is_dir() else target.unlink()
    return mutate


BAD_SESSIONS = [
    # id, mutation of a good session folder, regex the message must contain
    ("missing-folder", _remove("."), r"session: session folder not found"),
    ("missing-manifest", _remove("session.toml"),
     r"session\.toml: session manifest not found"),
    ("invalid-toml", _write("session.toml", 'format = "rig-session/1\n'),
     r"session\.toml: not valid TOML"),
    ("no-format", _edit_manifest(lambda d: d.pop("format")),
     r"session\.toml: missing 'format'.*rig-session/1"),
    ("bad-format", _edit_manifest(lambda d: d.update(format="rig-session/2")),
     r"session\.toml: format 'rig-session/2' is not supported"),
    ("unknown-units", _edit_manifest(lambda d: d.update(units="metric")),
     r"session\.toml: units: unknown unit system 'metric'"),
    ("no-runs", _edit_manifest(lambda d: d.pop("run")), r"session\.toml: no runs"),
    ("run-without-name", _edit_manifest(lambda d: d["run"][0].pop("name")),
     r"\[\[run\]\] #1: missing 'name'"),
    ("run-without-file", _edit_manifest(lambda d: d["run"][1].pop("file")),
     r"run 'swap-LF': missing 'file'"),
    ("run-without-setup", _edit_manifest(lambda d: d["run"][1].pop("setup")),
     r"run 'swap-LF': missing 'setup'"),
    ("duplicate-run-names", _edit_manifest(lambda d: d["run"][2].update(name="swap-LF")),
     r"session\.toml: run name 'swap-LF' is used more than once"),
    ("setup-not-a-table", _edit_manifest(lambda d: d["run"][1].update(setup="B20")),
     r"run 'swap-LF': setup must be a table"),
    ("setup-unknown-corner", _edit_manifest(lambda d: d["run"][1]["setup"].update(FL="B20")),
     r"run 'swap-LF': setup names unknown corner\(s\) \['FL'\]"),
    ("setup-missing-corner", _edit_manifest(lambda d: d["run"][1]["setup"].pop("RR")),
     r"run 'swap-LF': setup is missing corner\(s\) RR"),
    ("setup-unknown-shock", _edit_manifest(lambda d: d["run"][1]["setup"].update(LF="X9")),
     r"run 'swap-LF': setup LF = 'X9' is not in the shock library shocks\.toml "
     r"\(known ids: B20, D8, F12\)"),
    ("bad-role", _edit_manifest(lambda d: d["run"][0].update(role="Baseline")),
     r"run 'baseline-1': role 'Baseline' is not one of baseline, swap, validation"),
    ("channels-unknown-canonical",
     _edit_manifest(lambda d: d.update(channels={"wheel_LF": "WL_LF"})),
     r"session\.toml: \[channels\] maps 'wheel_LF', which is not a canonical channel"),
    ("missing-shock-library", _remove("shocks.toml"),
     r"session\.toml: shock_library 'shocks\.toml' not found"),
    ("bad-shock-library", _write("shocks.toml", '[[shock]]\nid = "B20"\nkind = "magic"\n'),
     r"session\.toml: shock_library 'shocks\.toml': .*shocks\.toml"),
    ("missing-run-file", _remove("runs/swap-LF.csv"),
     r"run 'swap-LF' \(.*swap-LF\.csv\): run file not found"),
    ("empty-run-file", _write("runs/swap-LF.csv", ""),
     r"run 'swap-LF' \(.*swap-LF\.csv\): the file is empty"),
    ("header-only-run", _edit_run(lambda f: f.iloc[:0]),
     r"run 'swap-LF' .*: has 0 data row\(s\); a run needs at least 2 samples"),
    ("one-row-run", _edit_run(lambda f: f.iloc[:1]),
     r"run 'swap-LF' .*: has 1 data row\(s\)"),
    ("missing-time", _edit_run(lambda f: f.drop(columns="time")),
     r"run 'swap-LF' .*: no 'time' column"),
    ("missing-rig-input", _edit_run(lambda f: f.drop(columns=["aero_roll", "wheelloader_RR"])),
     r"run 'swap-LF' .*: missing required channel\(s\) 'aero_roll', 'wheelloader_RR'; "
     r".*\[channels\]"),
    ("partial-aero", _edit_run(lambda f: f.drop(columns=["aero_pitch"])),
     r"run 'swap-LF' .*: missing required channel\(s\) 'aero_pitch'; .*\(a 4-post run, "
     r"without aero actuators, has no aero channels at all\)"),
    ("4-post-run-in-an-aero-session", _edit_run(lambda f: f.drop(columns=list(AERO_INPUTS))),
     r"run 'swap-LF' \(runs/swap-LF\.csv\) has no aero channels \(4-post\) but run "
     r"'baseline-1' \(runs/baseline-1\.csv\) has aero channels; every run of a session has "
     r"the same rig inputs .*separate sessions"),
    ("nan-samples", _edit_run(lambda f: _set(f, "tire_force_LF", [50, 51, 120], np.nan)),
     r"run 'swap-LF' .*: column 'tire_force_LF' has 3 NaN/inf value\(s\) from t=3\.5 s"),
    ("inf-sample", _edit_run(lambda f: _set(f, "aero_heave", [7], np.inf)),
     r"run 'swap-LF' .*: column 'aero_heave' has 1 NaN/inf value\(s\) from t=3\.07 s"),
    ("non-numeric", _edit_run(lambda f: _set(f, "wheelloader_LF", [10], "abc")),
     r"run 'swap-LF' .*: column 'wheelloader_LF' is not numeric \(data row 11, t=3\.1 s"),
    ("time-not-increasing", _edit_run(_swap_times),
     r"run 'swap-LF' .*: time is not strictly increasing at data row 12"),
    ("time-not-uniform", _edit_run(lambda f: _shift_time(f, 100, 0.003)),
     r"run 'swap-LF' .*: time is not uniformly sampled: a gap of 1\.3 sample intervals "
     r"\(0\.013 s against the typical 0\.01 s\) at t=4\.003 s \(data row 101\)"),
    ("dropped-sample", _edit_run(lambda f: f.drop(index=150)),
     r"run 'swap-LF' .*: time is not uniformly sampled: a gap of 2 sample intervals "
     r"\(0\.02 s against the typical 0\.01 s\) at t=4\.51 s \(data row 151\).*cut the "
     r"record at the gap"),
    ("different-sample-rates", _edit_run(lambda f: f.assign(time=f["time"] * 2)),
     r"runs 'baseline-1' \(100 Hz\) and 'swap-LF' \(50 Hz\) have different sample rates"),
]


@pytest.mark.parametrize("mutate, match", [c[1:] for c in BAD_SESSIONS],
                         ids=[c[0] for c in BAD_SESSIONS])
def test_bad_session_raises_one_clear_error(session_dir, mutate, match):
    mutate(session_dir)
    with pytest.raises(SessionError, match=match):
        read_session(session_dir)


def test_time_jitter_within_tolerance_is_accepted(session_dir):
    _edit_run(lambda f: _shift_time(f, 100, 1e-9))(session_dir)  # 1e-7 of the step
    assert read_session(session_dir).fs_hz == pytest.approx(FS_HZ, rel=1e-6)


#: A logger's jitter in the test below: each time stamp off its grid point by up to 1.5 % of
#: the step, so the steps lie within +-3 % of the median (inside the 5 % tolerance).
LOGGER_JITTER = 0.015
#: Resampling error allowed on a 2 Hz sine at 100 Hz: the degree-7 spline is far below it
#: (about 1e-9); linear interpolation through the stamps would be ~1e-4.
RESAMPLED_SINE_ATOL = 1e-6


def test_logger_time_stamps_that_jitter_are_resampled(session_dir, caplog):
    """A run whose time stamps jitter (a CAN logger's: each stamp up to 1.5 % of the step
    off the grid, steps within +-3 % of the median) is read onto a uniform base, said in one
    warning with the jitter; a signal given at the stamps is its value on the uniform base."""
    rng = np.random.default_rng(36)

    def jitter(frame):
        n = len(frame)
        stamps = frame["time"].to_numpy() + rng.uniform(-LOGGER_JITTER, LOGGER_JITTER, n) / FS_HZ
        frame["time"] = stamps
        frame["tire_force_LF"] = np.sin(2 * np.pi * 2.0 * stamps)
        return frame

    _edit_run(jitter)(session_dir)
    with caplog.at_level("WARNING", logger="ident.data.runs"):
        session = read_session(session_dir)
    run = session.run("swap-LF")
    lines = [r.getMessage() for r in caplog.records if "jitter" in r.getMessage()]
    assert len(lines) == 1 and "swap-LF" in lines[0] and "resampled onto a uniform" in lines[0]
    t = run.time_s
    assert_allclose(np.diff(t), np.diff(t).mean(), rtol=1e-9)
    assert run.fs_hz == pytest.approx(FS_HZ, rel=1e-3)
    assert_allclose(run.channels["tire_force_LF"], np.sin(2 * np.pi * 2.0 * t),
                    atol=RESAMPLED_SINE_ATOL)


#: The 2 Hz sine of the test below resampled to 50 Hz: a 2 s run, every sample within the
#: anti-aliasing filter's reach (0.4 s) of an end, extended by odd reflection: 1e-5 measured.
CHOSEN_RATE_SINE_ATOL = 1e-4


def test_runs_are_read_at_a_chosen_rate(session_dir, caplog):
    """``resample_hz`` (``--resample``): every run onto a uniform base at that rate, a jittered
    one too, each said in one line; a slow signal keeps its values."""
    rng = np.random.default_rng(361)

    def jitter(frame):
        n = len(frame)
        stamps = frame["time"].to_numpy() + rng.uniform(-LOGGER_JITTER, LOGGER_JITTER, n) / FS_HZ
        frame["time"] = stamps
        frame["tire_force_LF"] = np.sin(2 * np.pi * 2.0 * stamps)
        return frame

    _edit_run(jitter)(session_dir)
    with caplog.at_level("WARNING", logger="ident.data.runs"):
        session = read_session(session_dir, resample_hz=0.5 * FS_HZ)
    assert session.fs_hz == 0.5 * FS_HZ
    lines = [r.getMessage() for r in caplog.records if "as asked" in r.getMessage()]
    assert len(lines) == len(session.runs), lines
    said = next(line for line in lines if "swap-LF" in line)
    assert "jittering" in said and f"uniform {0.5 * FS_HZ:g} Hz" in said
    run = session.run("swap-LF")
    assert_allclose(np.diff(run.time_s), 2.0 / FS_HZ, rtol=1e-9)
    mid = slice(20, -20)  # the ends: odd reflection
    assert_allclose(run.channels["tire_force_LF"][mid],
                    np.sin(2 * np.pi * 2.0 * run.time_s[mid]), atol=CHOSEN_RATE_SINE_ATOL)


def test_shock_library_error_is_chained(session_dir):
    from ident.errors import ShockModelError

    _write("shocks.toml", "units = \"SI\"\n")(session_dir)
    with pytest.raises(SessionError) as info:
        read_session(session_dir)
    assert isinstance(info.value.__cause__, ShockModelError)


def _table(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


BAD_TABLES = [
    # id, file name, file text (None: no file), keyword arguments, regex
    ("missing-file", "gone.csv", None, {}, r"gone\.csv: file not found"),
    ("unsupported-suffix", "run.xlsx", "time\n0\n1\n", {}, r"unsupported file type '\.xlsx'"),
    ("corrupt-parquet", "run.parquet", "not parquet", {},
     r"run\.parquet: cannot read the file as PARQUET"),
    ("duplicated-columns", "run.csv", "time,aero_heave,aero_heave\n0,1,2\n1,1,2\n", {},
     r"duplicated column name\(s\) \['aero_heave'\]"),
    ("required-missing", "run.csv", "time,aero_heave\n0,1\n1,1\n",
     {"required": RIG_INPUTS}, r"missing required channel\(s\) 'aero_roll'.*\[channels\]"),
    ("required-mapped-missing", "run.csv", "time,aero_heave\n0,1\n1,1\n",
     {"required": ["aero_heave", "wheelloader_LF"],
      "channel_map": {"wheelloader_LF": "WL_LF_Disp"}},
     r"missing required channel\(s\) 'WL_LF_Disp' \(wheelloader_LF\)"),
    ("required-not-canonical", "run.csv", "time\n0\n1\n", {"required": ["heave"]},
     r"required channel\(s\) \['heave'\] are not canonical"),
    ("bad-units", "run.csv", "time\n0\n1\n", {"units": "cgs"},
     r"units: unknown unit system 'cgs'"),
    ("map-two-channels-to-one-column", "run.csv", "time,X\n0,1\n1,1\n",
     {"channel_map": {"aero_roll": "X", "aero_pitch": "X"}},
     r"\[channels\] maps both 'aero_roll' and 'aero_pitch' to column 'X'"),
    ("map-value-not-a-string", "run.csv", "time\n0\n1\n",
     {"channel_map": {"aero_roll": 3}}, r"\[channels\] aero_roll = 3"),
    ("where-names-the-run", "run.csv", "time,aero_heave\n0,1\n1,nan\n",
     {"where": "drive 'lap-7'"},
     r"^drive 'lap-7': column 'aero_heave' has 1 NaN/inf value\(s\) from t=1 s"),
    ("nan-in-time", "run.csv", "time,aero_heave\n0,1\n,1\n2,1\n", {},
     r"column 'time' has 1 NaN/inf value\(s\), the first at data row"),
    ("bool-column", "run.csv", "time,aero_heave\n0,True\n1,False\n", {},
     r"column 'aero_heave' is not numeric \(data row 1, t=0 s: True\)"),
]


@pytest.mark.parametrize("name, text, kwargs, match", [c[1:] for c in BAD_TABLES],
                         ids=[c[0] for c in BAD_TABLES])
def test_bad_run_table_raises_one_clear_error(tmp_path, name, text, kwargs, match):
    path = tmp_path / name
    if text is not None:
        path.write_text(text)
    with pytest.raises(SessionError, match=match):
        read_run_table(path, **kwargs)


def test_read_run_table_maps_converts_and_ignores(tmp_path):
    path = _table(tmp_path, "drive.csv",
                  "Zeit,WL_LF_Disp,aero_roll,Note\n10,1.0,2.0,a\n10.5,2.0,4.0,b\n11,3,6,c\n")
    table = read_run_table(path, units="imperial",
                           channel_map={"time": "Zeit", "wheelloader_LF": "WL_LF_Disp"})
    assert isinstance(table, RunTable) and table.fs_hz == 2.0
    assert list(table.channels) == ["aero_roll", "wheelloader_LF"]  # ALL_CHANNELS order
    assert_array_equal(table.time_s, [10.0, 10.5, 11.0])
    assert_allclose(table.channels["wheelloader_LF"], np.array([1.0, 2.0, 3.0]) * IN_M,
                    rtol=RTOL_ROUND_TRIP)
    assert_allclose(table.channels["aero_roll"], np.array([2.0, 4.0, 6.0]) * LBF_N * IN_M,
                    rtol=RTOL_ROUND_TRIP)
    assert not table.channels["aero_roll"].flags.writeable


BAD_RUNS = [
    # id, change to the second run, regex
    ("unknown-shock", {"setup": dict(zip(CORNERS, ("B20", "B20", "Z1", "B20")))},
     r"run 'swap-LF' \(runs/swap-LF\.csv\): setup LR = 'Z1' is not in the shock library "
     r"of the session \(known ids: B20, D8, F12\)"),
    ("bad-role", {"role": "sweep"}, r"run 'swap-LF' .*role 'sweep' is not one of"),
    ("missing-rig-input", {"drop": "aero_pitch"},
     r"run 'swap-LF' .*missing required channel\(s\) 'aero_pitch'"),
    ("4-post-run-in-an-aero-session", {"drop": AERO_INPUTS},
     r"session 'bad': run 'swap-LF' \(runs/swap-LF\.csv\) has no aero channels \(4-post\) "
     r"but run 'baseline-1' \(runs/baseline-1\.csv\) has aero channels"),
    ("non-canonical-channel", {"add": "ShockVel_LF"},
     r"run 'swap-LF' .*unknown channel name\(s\) \['ShockVel_LF'\]"),
    ("nan", {"nan": "shock_velocity_RF"},
     r"run 'swap-LF' .*column 'shock_velocity_RF' has 1 NaN/inf value\(s\) from t=3\.05 s"),
    ("different-sample-rates", {"fs_hz": 200.0},
     r"runs 'baseline-1' \(100 Hz\) and 'swap-LF' \(200 Hz\) have different sample rates"),
    ("fs-disagrees-with-time", {"fs_hz_only": 99.0},
     r"run 'swap-LF' .*fs_hz = 99 Hz disagrees with its time_s \(100 Hz\)"),
    ("duplicate-names", {"name": "baseline-1"},
     r"run name 'baseline-1' is used more than once"),
]


@pytest.mark.parametrize("change, match", [c[1:] for c in BAD_RUNS],
                         ids=[c[0] for c in BAD_RUNS])
def test_make_session_uses_the_same_checks(rng, shocks, change, match):
    runs = [_random_run(rng, *spec) for spec in RUN_SPECS]
    r = runs[1]
    channels = dict(r.channels)
    fields = {"name": change.get("name", r.name), "file": r.file,
              "setup": change.get("setup", r.setup), "role": change.get("role", r.role),
              "time_s": r.time_s, "fs_hz": change.get("fs_hz_only", r.fs_hz)}
    for c in np.atleast_1d(change.get("drop", ())):
        del channels[c]
    if "add" in change:
        channels[change["add"]] = channels["aero_heave"]
    if "nan" in change:
        channels[change["nan"]] = np.where(np.arange(N_SAMPLES) == 5, np.nan,
                                           channels[change["nan"]])
    if "fs_hz" in change:
        fields["time_s"] = np.arange(N_SAMPLES) / change["fs_hz"]
        fields["fs_hz"] = change["fs_hz"]
    runs[1] = Run(channels=channels, **fields)
    with pytest.raises(SessionError, match=match):
        make_session("bad", runs, shocks)


def test_four_post_session_round_trip(rng, shocks, tmp_path):
    """A 4-post session (no aero channels in any run) is checked, written and read back; its
    rig inputs are the wheelloaders."""
    runs = [_random_run(rng, *spec) for spec in RUN_SPECS]
    runs = [Run(name=r.name, file=r.file, setup=r.setup, role=r.role, time_s=r.time_s,
                fs_hz=r.fs_hz, channels={c: x for c, x in r.channels.items()
                                         if c not in AERO_INPUTS}) for r in runs]
    session = make_session("synthetic 4-post", runs, shocks)
    assert session.rig_inputs == WHEELLOADER_INPUTS
    back = read_session(write_session(session, tmp_path / "four-post"))
    _assert_same_data(session, back)
    assert back.rig_inputs == WHEELLOADER_INPUTS
    assert not any(c in r.channels for r in back.runs for c in AERO_INPUTS)


def test_make_session_needs_runs(shocks):
    with pytest.raises(SessionError, match="session 'empty': the session has no runs"):
        make_session("empty", [], shocks)


# --------------------------------------------------------------------------------------
# atomic writes
# --------------------------------------------------------------------------------------


def _snapshot(folder):
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def _leftovers(folder):
    """Hidden temporary siblings that write_session may have left behind."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_existing_folder_is_left_untouched_without_overwrite(session, tmp_path):
    target = tmp_path / "busy"
    target.mkdir()
    (target / "notes.txt").write_text("keep me")
    before = _snapshot(target)
    with pytest.raises(FileExistsError, match=r"busy: folder already exists and is not empty"):
        write_session(session, target)
    assert _snapshot(target) == before
    assert _leftovers(tmp_path) == []

    write_session(session, target, overwrite=True)
    assert not (target / "notes.txt").exists()
    _assert_same_data(session, read_session(target))
    assert _leftovers(tmp_path) == []


def test_empty_existing_folder_is_accepted(session, tmp_path):
    (tmp_path / "empty").mkdir()
    assert read_session(write_session(session, tmp_path / "empty")).run_names == tuple(
        name for name, _, _ in RUN_SPECS)


def test_failure_while_writing_leaves_nothing_half_written(session, tmp_path, monkeypatch):
    target = tmp_path / "old"
    write_session(session, target)
    before = _snapshot(target)
    real = session_mod.write_run_table

    def failing(path, *args, **kwargs):
        if Path(path).stem == "swap-LF":  # the second of three runs
            raise OSError("disk full")
        return real(path, *args, **kwargs)

    monkeypatch.setattr(session_mod, "write_run_table", failing)
    with pytest.raises(OSError, match="disk full"):
        write_session(session, target, overwrite=True)
    with pytest.raises(OSError, match="disk full"):
        write_session(session, tmp_path / "new")
    assert _snapshot(target) == before
    assert not (tmp_path / "new").exists() and _leftovers(tmp_path) == []


def test_write_session_rejects_bad_options(session, tmp_path):
    with pytest.raises(ValueError, match="run_format 'xlsx' is not supported"):
        write_session(session, tmp_path / "x", run_format="xlsx")
    with pytest.raises(ValueError, match="unknown unit system 'metric'"):
        write_session(session, tmp_path / "x", units="metric")
    (tmp_path / "file").write_text("")
    with pytest.raises(FileExistsError, match="is not a folder"):
        write_session(session, tmp_path / "file", overwrite=True)


def test_run_names_are_made_safe_file_names(rng, shocks, tmp_path):
    runs = [_random_run(rng, "a/b c", "other", ("B20",) * 4),
            _random_run(rng, "a_b_c", "other", ("B20",) * 4)]
    folder = write_session(make_session("names", runs, shocks), tmp_path / "s")
    back = read_session(folder)
    assert [r.file for r in back.runs] == ["runs/a_b_c.csv", "runs/a_b_c-2.csv"]
    assert back.run_names == ("a/b c", "a_b_c")


# --------------------------------------------------------------------------------------
# the unit marker (issue 23)
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("run_format", ["csv", "parquet"])
@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_run_files_say_their_units(session, tmp_path, run_format, units):
    from ident.data.files import read_units_marker

    folder = write_session(session, tmp_path / "s", units=units, run_format=run_format)
    for name, _, _ in RUN_SPECS:
        path = folder / "runs" / f"{name}.{run_format}"
        assert read_units_marker(path) == units
        if run_format == "csv":
            lines = path.read_text().splitlines()
            assert lines[0].startswith("time,") and lines[0].endswith(",units")
            assert all(line.endswith(f",{units}") for line in lines[1:])
    table = read_run_table(folder / "runs" / f"swap-LF.{run_format}")  # no units given
    assert table.units == table.file_units == units
    _assert_same_data(session, read_session(folder))


@pytest.mark.parametrize("run_format", ["csv", "parquet"])
def test_a_run_file_contradicting_the_manifest_is_an_error(session, tmp_path, run_format):
    folder = write_session(session, tmp_path / "s", units="imperial", run_format=run_format)
    manifest = folder / "session.toml"
    manifest.write_text(manifest.read_text().replace('units = "imperial"', 'units = "SI"'))
    with pytest.raises(SessionError) as exc:
        read_session(folder)
    text = str(exc.value)
    assert text.startswith(f"run 'baseline-1' ({folder / 'runs' / 'baseline-1'}.{run_format}): ")
    assert "in imperial units" in text and 'units = "SI"' in text
    assert "session.toml" in text and "make them agree" in text


def test_a_run_file_without_marker_takes_the_manifest_units(session, tmp_path):
    folder = write_session(session, tmp_path / "s", units="imperial")
    for path in (folder / "runs").iterdir():  # an export that says nothing
        path.write_text("".join(line.rsplit(",", 1)[0] + "\n"
                                for line in path.read_text().splitlines()))
        assert "units" not in pd.read_csv(path, nrows=1).columns
    _assert_same_data(session, read_session(folder))
    for path in (folder / "runs").iterdir():  # the earlier layout: the marker line first
        path.write_text("# units: imperial\n" + path.read_text())
    _assert_same_data(session, read_session(folder))


# --------------------------------------------------------------------------------------
# the real car: bump stops, packers and static corner loads (all optional)
# --------------------------------------------------------------------------------------

BUMPSTOPS_TOML = """\
units = "SI"

[[bump_stop]]
id = "BS-F"
gap = 0.0075
travel = [0.0, 0.005, 0.010]
force = [0.0, 800.0, 3000.0]

[[bump_stop]]
id = "BS-R"
gap = 0.010
travel = [0.0, 0.01]
force = [0.0, 2500.0]
"""
STATIC_N = (3100.0, 3000.0, 3300.0, 3200.0)  # LF RF LR RR [N]
REAL_CAR = {  # run name -> (bump_stops, packers_m)
    "baseline-1": ({"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": "BS-R"}, {}),
    "swap-LF": ({"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": "none"},
                {"LF": 0.003, "RF": 0.0025}),
    "validation": ({}, {}),
}
# the manifest of the fixture session, as written before the real car's keys existed
PLAIN_MANIFEST = """\
format = "rig-session/1"
name = "synthetic 8-post"
units = "SI"
shock_library = "shocks.toml"
""" + "".join(f"""
[[run]]
name = "{name}"
file = "runs/{name}.csv"
setup = {{ LF = "{s[0]}", RF = "{s[1]}", LR = "{s[2]}", RR = "{s[3]}" }}
role = "{role}"
""" for name, role, s in RUN_SPECS)


@pytest.fixture
def bump_stops(tmp_path):
    from ident.models.bumpstops import read_bump_stops

    path = tmp_path / "stops.toml"
    path.write_text(BUMPSTOPS_TOML)
    return read_bump_stops(path)


def _real_car_runs(rng, *, tire_mean=STATIC_N[0]):
    """The fixture's runs with bump stops and packers; tire_force_LF about `tire_mean`."""
    runs = []
    for name, role, setup in RUN_SPECS:
        r = _random_run(rng, name, role, setup)
        channels = {**r.channels,
                    "tire_force_LF": tire_mean + 300.0 * rng.standard_normal(N_SAMPLES)}
        stops, packers = REAL_CAR[name]
        runs.append(Run(name=r.name, file=r.file, setup=r.setup, role=r.role, time_s=r.time_s,
                        channels=channels, fs_hz=r.fs_hz, bump_stops=stops, packers_m=packers))
    return runs


@pytest.fixture
def real_car(rng, shocks, bump_stops):
    return make_session("real car", _real_car_runs(rng), shocks, bump_stops=bump_stops,
                        static_corner_load_n=dict(zip(CORNERS, STATIC_N)))


@pytest.fixture
def real_car_dir(real_car, tmp_path):
    return write_session(real_car, tmp_path / "real-car")


def test_session_without_the_real_car_keys_is_as_before(session, session_dir):
    """No bump stops, packers or static loads: the manifest is byte for byte the old one, no
    bumpstops.toml, and what reads back has none of them."""
    assert (session_dir / "session.toml").read_text() == PLAIN_MANIFEST
    assert sorted(p.name for p in session_dir.iterdir()) == ["runs", "session.toml",
                                                             "shocks.toml"]
    for s in (session, read_session(session_dir)):
        assert s.bump_stops is None and s.bump_stop_library_file is None
        assert s.static_corner_load_n is None
        for r in s.runs:
            assert r.bump_stops == dict.fromkeys(CORNERS)
            assert r.packers_m == dict.fromkeys(CORNERS, 0.0)


def test_make_session_keeps_the_real_car(real_car, bump_stops):
    assert real_car.bump_stops == bump_stops and real_car.bump_stop_library_file == \
        "bumpstops.toml"
    assert_array_equal(real_car.static_corner_load_n, STATIC_N)
    assert not real_car.static_corner_load_n.flags.writeable
    swap = real_car.run("swap-LF")
    assert swap.bump_stops == {"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": None}
    assert swap.packers_m == {"LF": 0.003, "RF": 0.0025, "LR": 0.0, "RR": 0.0}
    assert real_car.run("validation").bump_stops == dict.fromkeys(CORNERS)


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_real_car_round_trip(real_car, bump_stops, tmp_path, units):
    folder = write_session(real_car, tmp_path / units, units=units)
    back = read_session(folder)
    _assert_same_data(real_car, back)
    assert back.bump_stop_library_file == "bumpstops.toml"
    assert back.bump_stops.ids == bump_stops.ids
    for a, b in zip(bump_stops.values(), back.bump_stops.values(), strict=True):
        assert b.gap_m == pytest.approx(a.gap_m, rel=RTOL_ROUND_TRIP)
        assert_allclose(b.force_n, a.force_n, rtol=RTOL_ROUND_TRIP)
    assert_allclose(back.static_corner_load_n, STATIC_N, rtol=RTOL_ROUND_TRIP)
    for ra, rb in zip(real_car.runs, back.runs, strict=True):
        assert rb.bump_stops == ra.bump_stops
        assert_allclose([rb.packers_m[c] for c in CORNERS], [ra.packers_m[c] for c in CORNERS],
                        rtol=RTOL_ROUND_TRIP)
    # what was read writes the same manifest again
    again = write_session(back, tmp_path / f"{units}-again")
    assert (again / "session.toml").read_bytes() == (folder / "session.toml").read_bytes()
    assert (again / "bumpstops.toml").read_bytes() == (folder / "bumpstops.toml").read_bytes()


def test_real_car_manifest_is_the_spec_layout(real_car_dir):
    text = (real_car_dir / "session.toml").read_text()
    assert 'bump_stop_library = "bumpstops.toml"\n' in text
    assert "static_corner_load = { LF = 3100.0, RF = 3000.0, LR = 3300.0, RR = 3200.0 }\n" in text
    doc = tomllib.loads(text)
    assert doc["run"][0]["bump_stops"] == REAL_CAR["baseline-1"][0]
    assert "packers" not in doc["run"][0]  # none fitted: not written
    assert doc["run"][1]["bump_stops"] == {"LF": "BS-F", "RF": "BS-F", "LR": "BS-R"}  # RR none
    assert doc["run"][1]["packers"] == {"LF": 0.003, "RF": 0.0025}
    assert "bump_stops" not in doc["run"][2] and "packers" not in doc["run"][2]
    imperial = tomllib.loads((real_car_dir / "bumpstops.toml").read_text())
    assert imperial["bump_stop"][0]["gap"] == 0.0075


def test_imperial_manifest_converts_packers_and_loads(real_car, tmp_path):
    folder = write_session(real_car, tmp_path / "imp", units="imperial")
    doc = tomllib.loads((folder / "session.toml").read_text())
    assert doc["static_corner_load"]["LF"] == pytest.approx(3100.0 / LBF_N, rel=1e-12)
    assert doc["run"][1]["packers"]["LF"] == pytest.approx(0.003 / IN_M, rel=1e-12)
    stops = tomllib.loads((folder / "bumpstops.toml").read_text())
    assert stops["units"] == "imperial"
    assert stops["bump_stop"][1]["gap"] == pytest.approx(0.010 / IN_M, rel=1e-12)


def test_a_dynamic_tire_channel_is_not_compared_with_the_static_load(rng, shocks, bump_stops):
    """A tire_force channel whose mean is ~0 carries no static offset: any load is accepted;
    one carrying the offset is accepted within STATIC_LOAD_RTOL."""
    from ident.data.session import STATIC_LOAD_RTOL, STATIC_OFFSET_SHARE

    assert 0 < STATIC_LOAD_RTOL < STATIC_OFFSET_SHARE < 1
    for mean in (0.0, 0.15 * STATIC_N[0], (1 + 0.8 * STATIC_LOAD_RTOL) * STATIC_N[0],
                 (1 - 0.8 * STATIC_LOAD_RTOL) * STATIC_N[0]):
        make_session("ok", _real_car_runs(rng, tire_mean=mean), shocks, bump_stops=bump_stops,
                     static_corner_load_n=STATIC_N)


def _runs_with(rng, **change):
    runs = _real_car_runs(rng)
    r = runs[1]
    runs[1] = Run(**{**{k: getattr(r, k) for k in ("name", "file", "setup", "role", "time_s",
                                                    "channels", "fs_hz", "bump_stops",
                                                    "packers_m")}, **change})
    return runs


@pytest.mark.parametrize("change, kwargs, match", [
    ({"bump_stops": {"LF": "BS-X"}}, {},
     r"run 'swap-LF' \(runs/swap-LF.csv\): bump_stops LF: unknown bump-stop id 'BS-X'.*"
     r"stops.toml has \['BS-F', 'BS-R'\]"),
    ({}, {"bump_stops": None}, r"run 'baseline-1' .*bump_stops LF = 'BS-F' but the session has "
                               r"no bump-stop library"),
    ({"packers_m": {"LR": 0.0101}}, {},
     r"run 'swap-LF' .*: packers LR: packer 10\.1 mm .* is thicker than the gap of bump stop "
     r"'BS-R', 10 mm .*use a packer of at most 10 mm"),
    ({"packers_m": {"RR": -0.001}}, {}, r"packers RR = -0\.001 is not a thickness"),
    ({"bump_stops": {"lf": "BS-F"}}, {}, r"bump_stops names unknown corner\(s\) \['lf'\]"),
    ({"bump_stops": {"LF": ""}}, {}, r"bump_stops LF: bump stop '' is not an id"),
    ({}, {"static_corner_load_n": (3100.0, 3000.0, 3300.0)},
     r"static_corner_load_n must be 4 positive numbers"),
    ({}, {"static_corner_load_n": (3100.0, 3000.0, -3300.0, 3200.0)},
     r"static_corner_load_n LR = -3300\.0 is not a load"),
    ({}, {"static_corner_load_n": (3100.0, np.nan, 3300.0, 3200.0)},
     r"static_corner_load_n RF = nan is not a load"),
    ({}, {"static_corner_load_n": {"LF": 3100.0, "RF": 3000.0}},
     r"static_corner_load_n has no load for corner\(s\) LR, RR"),
    ({}, {"static_corner_load_n": (3500.0, 3000.0, 3300.0, 3200.0)},
     r"run 'baseline-1' \(runs/baseline-1.csv\): tire_force_LF has a mean of 31\d\d\.?\d* N, so "
     r"it carries the static load, but static_corner_load_n LF = 3500 N \(-1\d%, more than 10% "
     r"off\); fix static_corner_load_n LF"),
])
def test_make_session_refuses_a_bad_real_car(rng, shocks, bump_stops, change, kwargs, match):
    kwargs = {"bump_stops": bump_stops, "static_corner_load_n": STATIC_N, **kwargs}
    with pytest.raises(SessionError, match=match):
        make_session("bad", _runs_with(rng, **change), shocks, **kwargs)


def _edit_run_entry(name, edit):
    def mutate(doc):
        edit(next(r for r in doc["run"] if r["name"] == name))
    return _edit_manifest(mutate)


BAD_REAL_CARS = [
    ("unknown id", _edit_run_entry("swap-LF", lambda r: r["bump_stops"].update(RR="BS-RR")),
     r"session.toml: run 'swap-LF': bump_stops RR: unknown bump-stop id 'BS-RR' \(did you mean "
     r"'BS-R'\?\); the bump-stop library .*bumpstops.toml has \['BS-F', 'BS-R'\]"),
    ("no library", _edit_manifest(lambda d: d.pop("bump_stop_library")),
     r"run 'baseline-1': bump_stops LF = 'BS-F' but the session has no bump-stop library; "
     r"name it at the top of the manifest with bump_stop_library = \"bumpstops.toml\""),
    ("library missing", _remove("bumpstops.toml"),
     r"bump_stop_library 'bumpstops.toml' not found"),
    ("library malformed", _write("bumpstops.toml", BUMPSTOPS_TOML.replace("gap = 0.010",
                                                                          "gap = -0.010")),
     r"bump_stop_library 'bumpstops.toml': .*#2 \('BS-R'\): key 'gap' = -0\.01 m is negative"),
    ("packer thicker", _edit_run_entry("swap-LF", lambda r: r["packers"].update(LF=0.008)),
     r"run 'swap-LF': packers LF: packer 8 mm \(0\.315 in\) is thicker than the gap of bump "
     r"stop 'BS-F', 7\.5 mm \(0\.2953 in\)"),
    ("packer not a number", _edit_run_entry("swap-LF", lambda r: r["packers"].update(LF="3")),
     r"packers LF: packer '3' is not a finite number"),
    ("packers not a table", _edit_run_entry("swap-LF", lambda r: r.update(packers=0.003)),
     r"packers must be a table"),
    ("static 3 corners", _edit_manifest(lambda d: d["static_corner_load"].pop("RR")),
     r"static_corner_load has no load for corner\(s\) RR; give the static tire load of all four "
     r"corners \(N\)"),
    ("static zero", _edit_manifest(lambda d: d["static_corner_load"].update(LR=0.0)),
     r"static_corner_load LR = 0\.0 is not a load"),
    ("static string", _edit_manifest(lambda d: d["static_corner_load"].update(LR="3300")),
     r"static_corner_load LR = '3300' is not a load"),
    ("static not a table", _edit_manifest(lambda d: d.update(static_corner_load=3100.0)),
     r"static_corner_load must be a table"),
    ("static mismatch", _edit_manifest(lambda d: d["static_corner_load"].update(LF=2500.0)),
     r"run 'baseline-1' \(.*baseline-1.csv\): tire_force_LF has a mean of 3\d{3}(\.\d+)? N, so "
     r"it carries the static load, but static_corner_load LF = 2500 N \(\+2\d%, more than 10% "
     r"off\); fix static_corner_load LF \(the tire's load on its pad"),
    ("static in the wrong units", _edit_manifest(lambda d: d.update(units="imperial")),
     r"the manifest .*units = \"imperial\""),  # the run files' marker stops it first
    ("bump_stops at the top", _edit_manifest(lambda d: d.update(bump_stops={"LF": "BS-F"})),
     r"'bump_stops' is a key of a run .*; move it into each \[\[run\]\]"),
    ("static under a run", _edit_run_entry("validation", lambda r: r.update(
        static_corner_load={"LF": 1.0})),
     r"run 'validation': 'static_corner_load' is a key of the session, not of a run; move it "
     r"to the top of the manifest"),
]


@pytest.mark.parametrize("mutate, match", [c[1:] for c in BAD_REAL_CARS],
                         ids=[c[0] for c in BAD_REAL_CARS])
def test_bad_real_car_raises_one_clear_error(real_car_dir, mutate, match):
    mutate(real_car_dir)
    with pytest.raises(SessionError, match=match):
        read_session(real_car_dir)


def test_static_loads_are_read_in_the_manifest_units(real_car, tmp_path):
    """Imperial static loads (lbf) that match the channel read back; the same numbers
    taken as N would not."""
    folder = write_session(real_car, tmp_path / "imp", units="imperial")
    assert_allclose(read_session(folder).static_corner_load_n, STATIC_N, rtol=1e-12)


def test_a_packer_without_a_bump_stop_is_kept_with_a_warning(rng, shocks, bump_stops, caplog):
    runs = _runs_with(rng, packers_m={"RR": 0.002})  # swap-LF has no bump stop at RR
    s = make_session("ok", runs, shocks, bump_stops=bump_stops)
    assert s.run("swap-LF").packers_m["RR"] == 0.002
    assert "packers RR = 0.002 m at a corner without a bump stop has no effect" in caplog.text


def test_append_runs_keeps_the_real_car(real_car, real_car_dir, rng):
    from ident.data.session import append_runs

    old = (real_car_dir / "session.toml").read_bytes()
    new = _runs_with(rng, name="swap-RR", packers_m={"LF": 0.001})[1]
    back = append_runs(real_car_dir, [new])
    assert (real_car_dir / "session.toml").read_bytes().startswith(old)
    assert back.run("swap-RR").packers_m["LF"] == pytest.approx(0.001, rel=1e-15)
    assert back.run("swap-RR").bump_stops["RR"] is None
    assert_allclose(back.static_corner_load_n, STATIC_N)
    bad = _runs_with(rng, name="swap-X", bump_stops={"LF": "BS-Z"})[1]
    with pytest.raises(SessionError, match="unknown bump-stop id 'BS-Z'"):
        append_runs(real_car_dir, [bad])


def test_check_static_corner_loads():
    """The public checker the virtual rig uses: per corner or in corner order, read-only,
    None for None; the session's messages."""
    from ident.data.session import check_static_corner_loads

    got = check_static_corner_loads({"RR": 4.0, "LF": 1.0, "RF": 2.0, "LR": 3.0}, "plan")
    assert_array_equal(got, [1.0, 2.0, 3.0, 4.0])
    assert not got.flags.writeable
    assert_array_equal(check_static_corner_loads([1, 2, 3, 4], "plan"), [1.0, 2.0, 3.0, 4.0])
    assert check_static_corner_loads(None, "plan") is None
    with pytest.raises(SessionError, match=r"plan: static_corner_load LR = 0 is not a load; "
                       r".*\(lbf, compression positive\)"):
        check_static_corner_loads([1, 2, 0, 4], "plan", key="static_corner_load", unit="lbf")
    with pytest.raises(SessionError, match="no load for corner"):
        check_static_corner_loads({"LF": 1.0}, "plan")


def test_third_element_keys_are_read_and_said_modelled(session_dir, caplog):
    """The spec's optional third elements (heave/roll per axle) are read and checked
    (tests/test_third_elements.py), and said once (info) what shockplan does with them,
    never "not part of the format"."""
    def declare(doc):
        doc["third_elements"] = {"heave_front": 1.0}
        doc["run"][0]["third"] = {"heave_front": "D8"}
    _edit_manifest(declare)(session_dir)
    with caplog.at_level("INFO", logger="ident.data.session"):
        s = read_session(session_dir)
    assert s.runs[0].third.dampers["heave_front"] == "D8"
    said = [r.getMessage() for r in caplog.records if "third elements" in r.getMessage()]
    assert len(said) == 1 and all("predictions put them in the loop" in m for m in said)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert not any("not part of the rig-session format" in r.getMessage()
                   for r in caplog.records)
