"""Tests of ident.data.tracklog: track logs read from CSV, Parquet, MDF4, TDMS and RPC III.

The logger's files are written here by the libraries loggers' software uses (pandas,
asammdf, npTDMS, rpc3-file) from known SI signals, in the logger's own names, units
(mm, g, kN, km/h through a scale), signs and offsets; reading them must give back the
signals, and every bad file must be refused with one sentence naming the file and the fix.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import rpc3
from asammdf import MDF, Signal
from nptdms import ChannelObject, TdmsWriter
from numpy.testing import assert_allclose, assert_array_equal

from ident.data.channels import (AERO_INPUTS, ALL_CHANNELS, CORNERS, TRACK_CHANNELS, kind_of,
                                 quantity_of)
from ident.data.formats import make_channel_map, read_channel_map
from ident.data.tracklog import (TRACK_LOG_CHANNELS, TRACK_LOG_RESPONSES, TrackLog,
                                 read_track_log, track_section, write_track_log)
from ident.errors import SessionError, TrackLogError

# --------------------------------------------------------------------------------------
# Tolerances (each with its reason)
# --------------------------------------------------------------------------------------

#: SI -> imperial -> shortest-repr text -> imperial -> SI: two roundings of 1.1e-16 by the
#: unit factor, plus the text's (none: repr round-trips).
RTOL_ROUND_TRIP = 1e-12
#: A map's conversion, ``sign * factor * scale * (raw - offset)``, against the same formula
#: inverted by hand: a few float64 roundings, relative to the channel's peak and offset.
RTOL_MAP = 1e-12
#: The sample rate derived from the times (``(n - 1) / (t[-1] - t[0])``) of a file written
#: with shortest-repr times ``k / fs``: a rounding or two of the span.
RTOL_FS = 1e-12
#: RPC III FLOATING_POINT holds float32: within 2**-24 of each raw value, 1 % slack for the
#: float64 conversions around it.
REL_FLOAT32 = 2.0**-24 * 1.01
#: Linear interpolation of a sine ``A sin(w t)`` sampled every ``h`` is off by at most
#: ``A w^2 h^2 / 8`` (the second derivative's bound); 1 % slack for rounding.
INTERP_SLACK = 1.01

IN_M = 0.0254  # by definition
LBF_N = 4.4482216152605  # by definition
G_M_S2 = 9.80665  # standard gravity, by definition
KMH_M_S = 1 / 3.6  # km/h -> m/s

FS_HZ = 200.0
N_SAMPLES = 1000

# the logger's conventions: canonical -> (source, units, sign, scale, offset)
LOGGER = {
    **{f"shock_travel_{c}": (f"Pot {c}", "mm", 1 if c[1] == "F" else -1, 1.0,
                             25.0 if c == "LF" else 0.0) for c in CORNERS},
    **{f"ride_height_{c}": (f"RH {c}", "mm", 1, 1.0, 0.0) for c in CORNERS},
    "wheel_accel_LF": ("Hub Acc LF", "g", 1, 1.0, 0.0),
    "chassis_accel_RR": ("Body Acc RR", "m/s^2", -1, 2.0, 0.5),
    "speed": ("GPS Speed", "m/s", 1, KMH_M_S, 0.0),  # logged in km/h: m/s times 1/3.6
    "aero_heave": ("Aero Heave", "kN", 1, 1.0, 0.0),
    "aero_roll": ("Aero Roll", "N*m", 1, 1.0, 0.0),
    "aero_pitch": ("Aero Pitch", "lbf*in", -1, 1.0, 0.0),
}
FACTOR = {"mm": 1e-3, "g": G_M_S2, "m/s^2": 1.0, "m/s": 1.0, "kN": 1e3, "N*m": 1.0,
          "lbf*in": LBF_N * IN_M}


def _gain(canonical):
    source, units, sign, scale, offset = LOGGER[canonical]
    return sign * FACTOR[units] * scale


def _raw(canonical, x_si):
    """The logger's raw numbers of SI values (the documented formula, inverted by hand)."""
    return np.asarray(x_si) / _gain(canonical) + LOGGER[canonical][4]


def _map_toml(channels, *, rename=None, time=None, extra=""):
    lines = ['format = "channel-map/1"', 'name = "test logger"']
    if time:
        lines.append(f'time = "{time}"')
    for c in channels:
        source, units, sign, scale, offset = LOGGER[c]
        source = (rename or {}).get(c, source)
        lines += [f"[channels.{c}]", f'source = "{source}"', f'units = "{units}"',
                  f"sign = {sign}", f"scale = {scale!r}", f"offset = {offset!r}"]
    return "\n".join(lines) + "\n" + extra


def _write_map(folder, channels=tuple(LOGGER), **kwargs):
    path = Path(folder) / "logger.toml"
    path.write_text(_map_toml(channels, **kwargs))
    return path


@pytest.fixture
def truth(rng):
    """Known SI signals of a lap: 5 s at 200 Hz, every channel a log may hold (some corners)."""
    n = N_SAMPLES
    t = np.arange(n) / FS_HZ
    sizes = {"shock_travel": 0.01, "ride_height": 0.005, "wheel_accel": 30.0,
             "chassis_accel": 5.0, "speed": 5.0, "aero_heave": 3000.0, "aero_roll": 200.0,
             "aero_pitch": 800.0}
    base = {"ride_height": 0.05, "speed": 50.0, "aero_heave": -8000.0}
    channels = {}
    for c in LOGGER:
        kind = c if c in TRACK_CHANNELS + AERO_INPUTS else kind_of(c)
        channels[c] = base.get(kind, 0.0) + sizes[kind] * rng.standard_normal(n)
    return TrackLog(name="lap", fs_hz=FS_HZ, channels=channels,
                    settings={"t0_s": 0.0}), t


def _logger_frame(log, t):
    """The log in the logger's names and numbers, plus a column the map does not name."""
    frame = {"Time": t, "Lap": np.ones(t.size)}
    frame.update({LOGGER[c][0]: _raw(c, x) for c, x in log.channels.items()})
    return pd.DataFrame(frame)


def write_mdf(path, groups):
    """An MDF4 file: one channel group per ``(times, {name: (values, unit)})``."""
    mdf = MDF(version="4.10")
    for t, chans in groups:
        mdf.append([Signal(np.asarray(x), np.asarray(t), name=n, unit=u)
                    for n, (x, u) in chans.items()])
    mdf.save(path, overwrite=False)
    mdf.close()
    return Path(path)


def _logger_channels(log, names=None):
    names = list(log.channels) if names is None else names
    return {LOGGER[c][0]: (_raw(c, log.channels[c]), LOGGER[c][1]) for c in names}


def _assert_channels(got, want, *, rtol):
    assert list(got.channels) == list(want.channels)
    for c, x in want.channels.items():
        peak = np.max(np.abs(x)) + abs(_gain(c) * LOGGER[c][4]) if c in LOGGER else 0.0
        assert_allclose(got.channels[c], x, rtol=rtol, atol=rtol * peak, err_msg=c)


# --------------------------------------------------------------------------------------
# The new channel: speed
# --------------------------------------------------------------------------------------


def test_speed_is_a_track_channel_only(tmp_path):
    assert quantity_of("speed") == "velocity" and TRACK_CHANNELS == ("speed",)
    assert "speed" not in ALL_CHANNELS and "speed" in TRACK_LOG_CHANNELS
    with pytest.raises(ValueError, match="unknown channel 'speed'"):
        kind_of("speed")
    path = _write_map(tmp_path, ["shock_travel_LF", "speed"])
    with pytest.raises(SessionError, match=r"\[channels.speed\]: 'speed' is not a canonical "
                                           r"channel; keys are the rig inputs"):
        read_channel_map(path)  # a session import's map still refuses it
    cmap = read_channel_map(path, allowed=ALL_CHANNELS + TRACK_CHANNELS)
    assert list(cmap.channels) == ["shock_travel_LF", "speed"]
    with pytest.raises(ValueError, match=r"allowed names \['sped'\]"):
        make_channel_map({}, allowed=["sped"])


# --------------------------------------------------------------------------------------
# Round trips and known answers
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("units", ["SI", "imperial"])
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_write_read_round_trip(truth, units, suffix, tmp_path):
    log, _ = truth
    path = write_track_log(log, tmp_path / f"lap{suffix}", units=units)
    back = read_track_log(path)
    assert back.name == "lap" and back.n_samples == N_SAMPLES
    assert back.fs_hz == pytest.approx(FS_HZ, rel=RTOL_FS)
    assert back.settings == {"source": str(path), "format": suffix[1:], "units": units,
                             "map": None, "t0_s": 0.0, "resampled": []}
    _assert_channels(back, log, rtol=RTOL_ROUND_TRIP)
    if units == "SI":  # shortest-repr text and Parquet doubles: bit for bit
        for c, x in log.channels.items():
            assert_array_equal(back.channels[c], x)
    assert all(not x.flags.writeable for x in back.channels.values())
    if suffix == ".csv":
        lines = path.read_text().splitlines()
        assert lines[0].startswith("time,") and lines[0].endswith(",units")
        assert all(line.endswith(f",{units}") for line in lines[1:])
        assert (pd.read_csv(path)["units"] == units).all()
    with pytest.raises(FileExistsError, match="already exists"):
        write_track_log(log, path)
    write_track_log(log, path, units=units, overwrite=True)


def test_csv_with_canonical_names(tmp_path, caplog):
    """Known answers: inches read as metres by `units`, extra columns ignored, t0 kept."""
    path = tmp_path / "logger_export.csv"
    rows = ["time,shock_travel_LF,shock_travel_RF,shock_travel_LR,shock_travel_RR,speed,"
            "Lap,shock_velocity_LF"]
    rows += [f"{12.5 + k / 100},{k},{-k},{2 * k},0.5,{1000 + k},1,9" for k in range(3)]
    path.write_text("\n".join(rows) + "\n")
    with caplog.at_level(logging.DEBUG, logger="ident.data.runs"):
        log = read_track_log(path, units="imperial", name="stint 2")
    assert "'Lap' is not a canonical channel; ignored" in caplog.text
    assert list(log.channels) == [f"shock_travel_{c}" for c in CORNERS] + ["speed"]
    assert_allclose(log.channels["shock_travel_LR"], [0.0, 0.0508, 0.1016], rtol=RTOL_MAP)
    assert_allclose(log.channels["speed"], [25.4, 25.4254, 25.4508], rtol=RTOL_MAP)
    assert log.fs_hz == pytest.approx(100.0, rel=1e-9)  # times 12.5, 12.51, 12.52 as text
    assert log.name == "stint 2" and log.settings["t0_s"] == 12.5
    assert_allclose(log.time_s, [0.0, 0.01, 0.02])
    assert log.duration_s == pytest.approx(0.03)
    assert log.settings["units"] == "imperial"


def test_map_known_answers(tmp_path):
    """One sample per channel, converted by hand: sign, factor, scale, offset."""
    frame = pd.DataFrame({"Time": [0.0, 0.002], "Pot LF": [30.0, 25.0], "Pot RF": [4.0, 0.0],
                          "Pot LR": [4.0, 0.0], "Pot RR": [0.0, 0.0],
                          "GPS Speed": [180.0, 0.0], "Body Acc RR": [1.5, 0.5]})
    path = tmp_path / "lap.csv"
    frame.to_csv(path, index=False)
    cmap = _write_map(tmp_path, [*(f"shock_travel_{c}" for c in CORNERS), "speed",
                                 "chassis_accel_RR"], time="Time")
    log = read_track_log(path, channel_map=cmap, units="imperial")  # units: not used
    assert log.channels["shock_travel_LF"][0] == pytest.approx(0.005, rel=RTOL_MAP)  # 30-25 mm
    assert log.channels["shock_travel_LR"][0] == pytest.approx(-0.004, rel=RTOL_MAP)  # sign -1
    assert log.channels["speed"][0] == pytest.approx(50.0, rel=RTOL_MAP)  # 180 km/h
    assert log.channels["chassis_accel_RR"][0] == pytest.approx(-2.0, rel=RTOL_MAP)  # -2(1.5-.5)
    assert log.fs_hz == pytest.approx(500.0, rel=RTOL_FS)
    assert log.settings["units"] is None and log.settings["map"] == str(cmap)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_csv_and_parquet_through_a_map(truth, suffix, tmp_path):
    log, t = truth
    path = tmp_path / f"logger{suffix}"
    frame = _logger_frame(log, t)
    if suffix == ".csv":
        frame.to_csv(path, index=False)
    else:
        frame.to_parquet(path, index=False)
    cmap = _write_map(tmp_path, time="Time")
    back = read_track_log(path, channel_map=cmap)
    _assert_channels(back, log, rtol=RTOL_MAP)
    assert back.fs_hz == pytest.approx(FS_HZ, rel=RTOL_FS)
    assert back.settings["format"] == suffix[1:] and back.settings["map"] == str(cmap)
    # the same map built in memory, and the file's format given instead of its suffix
    in_memory = read_channel_map(cmap, allowed=TRACK_LOG_CHANNELS)
    renamed = path.rename(tmp_path / "logger.export")
    again = read_track_log(renamed, channel_map=in_memory, format=suffix[1:])
    assert_array_equal(again.channels["speed"], back.channels["speed"])


@pytest.mark.parametrize("case", ["mdf", "tdms", "tdms-time-channel", "rpc3"])
def test_logger_files_through_a_map(truth, case, tmp_path):
    log, t = truth
    raw = _logger_channels(log)
    time = None
    if case == "mdf":
        path = write_mdf(tmp_path / "lap.mf4", [(t, {n: v for n, v in raw.items()
                                                      if n.startswith("Pot")}),
                                                 (t, {n: v for n, v in raw.items()
                                                      if not n.startswith("Pot")})])
    elif case.startswith("tdms"):
        path = tmp_path / "lap.tdms"
        timed = case == "tdms"
        objects = [ChannelObject("Logger", n, x, properties={
            "unit_string": u, **({"wf_increment": 1 / FS_HZ, "wf_start_offset": 0.0}
                                 if timed else {})}) for n, (x, u) in raw.items()]
        if not timed:
            objects.append(ChannelObject("Logger", "Time", t, properties={"unit_string": "s"}))
            time = "Logger/Time"
        with TdmsWriter(str(path)) as writer:
            writer.write_segment(objects)
    else:
        path = tmp_path / "lap.rsp"
        rpc3.write(str(path), [rpc3.Channel(n, u, dt=1 / FS_HZ, data=x)
                               for n, (x, u) in raw.items()], datatype=float)
    back = read_track_log(path, channel_map=_write_map(tmp_path, time=time))
    assert back.settings["format"] == case[:4] and back.settings["resampled"] == []
    assert back.fs_hz == pytest.approx(FS_HZ, rel=RTOL_FS)
    if case == "rpc3":  # float32 samples: each within 2**-24 of its raw value
        for c, x in log.channels.items():
            bound = REL_FLOAT32 * np.abs(_gain(c) * _raw(c, x))
            assert np.all(np.abs(back.channels[c] - x) <= bound + 1e-300), c
    else:
        _assert_channels(back, log, rtol=RTOL_MAP)


def test_mixed_rates_interpolated_onto_the_travel(tmp_path, caplog):
    """Pots at 500 Hz, ride heights at 100 Hz, speed at 20 Hz: known sines recovered."""
    duration = 10.0
    t_pot = np.arange(int(duration * 500)) / 500.0
    t_rh = np.arange(int(duration * 100)) / 100.0
    t_speed = 0.01 + np.arange(int(duration * 20)) / 20.0  # starts late by half its step
    a_rh, f_rh = 0.01, 1.5
    a_v, f_v = 5.0, 0.2

    def rh(t):
        return 0.05 + a_rh * np.sin(2 * np.pi * f_rh * t)

    def speed(t):
        return 50.0 + a_v * np.sin(2 * np.pi * f_v * t)

    pots = {LOGGER[f"shock_travel_{c}"][0]: (np.full(t_pot.size, 25.0 + k), "mm")
            for k, c in enumerate(CORNERS)}
    path = write_mdf(tmp_path / "mixed.mf4", [
        (t_pot, pots),
        (t_rh, {"RH LF": (1e3 * rh(t_rh), "mm")}),
        (t_speed, {"GPS Speed": (3.6 * speed(t_speed), "")}),
    ])
    cmap = _write_map(tmp_path, [*(f"shock_travel_{c}" for c in CORNERS), "ride_height_LF",
                                 "speed"])
    with caplog.at_level(logging.INFO, logger="ident.data.tracklog"):
        log = read_track_log(path, channel_map=cmap)
    assert "ride_height_LF, speed interpolated linearly onto the time base of 'Pot LF'" \
        in caplog.text
    assert log.settings["resampled"] == ["ride_height_LF", "speed"]
    assert log.n_samples == t_pot.size and log.fs_hz == pytest.approx(500.0, rel=RTOL_FS)
    for c, f, t_c, a, f_hz in (("ride_height_LF", rh, t_rh, a_rh, f_rh),
                               ("speed", speed, t_speed, a_v, f_v)):
        x, h = log.channels[c], t_c[1] - t_c[0]
        inside = (t_pot >= t_c[0]) & (t_pot <= t_c[-1])
        bound = INTERP_SLACK * a * (2 * np.pi * f_hz) ** 2 * h**2 / 8
        assert np.max(np.abs(x[inside] - f(t_pot[inside]))) <= bound, c
        # beyond its first and last samples (less than one of its steps) the end value holds
        assert_allclose(x[t_pot < t_c[0]], f(t_c[0]), rtol=RTOL_MAP)
        assert_allclose(x[t_pot > t_c[-1]], f(t_c[-1]), rtol=RTOL_MAP)


# --------------------------------------------------------------------------------------
# Sections
# --------------------------------------------------------------------------------------


def test_sections(truth):
    log, _ = truth
    log = TrackLog(name="lap", fs_hz=FS_HZ, channels=log.channels, settings={"t0_s": 100.0})
    part = track_section(log, 1.0, 2.5)
    assert part.name == "lap_1-2.5s" and part.n_samples == 300  # samples 200 .. 499
    assert part.fs_hz == FS_HZ and part.duration_s == pytest.approx(1.5)
    for c, x in log.channels.items():
        assert_array_equal(part.channels[c], x[200:500])
    assert part.settings["t0_s"] == pytest.approx(101.0)
    assert part.settings["section_s"] == [1.0, 2.5]
    assert_allclose(part.time_s, np.arange(300) / FS_HZ)
    # a bound that is a sample's time in decimal but not in binary: 1.1 * 200 is
    # 220.00000000000003, yet 1.1 s is sample 220 (samples 220 .. 459)
    window = track_section(log, 1.1, 2.3, name="w")
    assert window.name == "w"
    assert_array_equal(window.channels["speed"], log.channels["speed"][220:460])
    # adjacent windows tile the log; the whole log is a window; a section of a section
    halves = [track_section(log, 0.0, 2.5), track_section(log, 2.5, log.duration_s)]
    assert_array_equal(np.concatenate([h.channels["speed"] for h in halves]),
                       log.channels["speed"])
    inner = track_section(part, 0.5, 1.0)
    assert_array_equal(inner.channels["aero_roll"], log.channels["aero_roll"][300:400])
    assert inner.settings["t0_s"] == pytest.approx(101.5)


def test_a_written_section_keeps_its_time(truth, tmp_path):
    log, _ = truth
    part = track_section(log, 2.0, 3.0)
    back = read_track_log(write_track_log(part, tmp_path / "part.csv"))
    assert back.settings["t0_s"] == pytest.approx(2.0, rel=1e-15)
    assert_array_equal(back.channels["shock_travel_RR"], part.channels["shock_travel_RR"])


# --------------------------------------------------------------------------------------
# Refusals: one sentence naming the file, the channel and the fix
# --------------------------------------------------------------------------------------


def _canonical_csv(folder, *, drop=(), rows=None, time=None, edit=None, marker=None):
    """A small canonical CSV (50 samples at 100 Hz), with a change."""
    n = 50
    t = np.arange(n) / 100.0 if time is None else time
    cols = {"time": t, **{f"shock_travel_{c}": np.linspace(0, 0.01, n) for c in CORNERS},
            "aero_heave": np.zeros(n), "aero_roll": np.zeros(n), "aero_pitch": np.zeros(n)}
    cols = {k: v for k, v in cols.items() if k not in drop}
    frame = pd.DataFrame(cols)
    if rows is not None:
        frame = frame.iloc[:rows]
    if edit:
        edit(frame)
    path = Path(folder) / "log.csv"
    text = frame.to_csv(index=False)
    path.write_text((f"# units: {marker}\n" if marker else "") + text)
    return path


def _mdf(folder, *, pot_t=None, extra=None):
    """An MDF4 log: the four pots at 500 Hz for 2 s, plus extra groups."""
    t = np.arange(1000) / 500.0 if pot_t is None else pot_t
    pots = {LOGGER[f"shock_travel_{c}"][0]: (np.zeros(t.size), "mm") for c in CORNERS}
    return write_mdf(Path(folder) / "log.mf4", [(t, pots)] + (extra or []))


def _pot_map(folder, more=(), **kwargs):
    return _write_map(folder, [*(f"shock_travel_{c}" for c in CORNERS), *more], **kwargs)


def _nan_at(column, i):
    def edit(frame):
        frame.loc[i, column] = np.nan
    return edit


def _case_missing_file(d):
    return dict(path=d / "nope.csv"), "nope.csv: file not found; check the path"


def _case_unknown_format_given(d):
    return (dict(path=_canonical_csv(d), format="xls"),
            r"log.csv: unknown format 'xls'; give one of csv, parquet, rpc3, mdf, tdms")


def _case_unknown_format_of_file(d):
    path = d / "log.dat"
    path.write_bytes(b"\x07\x00\x01garbage" + bytes(range(256)))
    return dict(path=path), (r"log.dat: unknown format \(suffix '.dat', and its first bytes "
                             r"look like nothing known\); give the format with format=")


def _case_csv_without_travel(d):
    return (dict(path=_canonical_csv(d, drop=("shock_travel_RF", "shock_travel_RR"))),
            r"log.csv: no shock travel at RF, RR \(no column shock_travel_RF, "
            r"shock_travel_RR\); name the columns shock_travel_XX, or map the logger's columns "
            r"with \[channels.shock_travel_XX\]")


def _case_map_without_travel(d):
    path = _canonical_csv(d)
    cmap = _write_map(d, ["shock_travel_LF", "shock_travel_RF", "shock_travel_RR"])
    return (dict(path=path, channel_map=cmap),
            r"logger.toml: maps no shock travel at LR \(reading track log .*log.csv\); a track "
            r"log needs shock travel at all four corners: add \[channels.shock_travel_LR\]")


def _case_nan_csv(d):
    return (dict(path=_canonical_csv(d, edit=_nan_at("shock_travel_RF", 25))),
            r"log.csv: column 'shock_travel_RF' has 1 NaN/inf value\(s\) from t=0.25 s; fill "
            r"or cut")


def _case_nan_mdf(d):
    x = np.zeros(100)
    x[40] = np.inf
    path = _mdf(d, extra=[(np.arange(100) / 50.0, {"GPS Speed": (x, "")})])
    return (dict(path=path, channel_map=_pot_map(d, ["speed"])),
            r"log.mf4: channel 'GPS Speed' \(speed\) has 1 NaN/inf value\(s\) from t=0.8 s")


def _case_time_not_increasing(d):
    t = np.arange(50) / 100.0
    t[30] = t[29]
    return (dict(path=_canonical_csv(d, time=t)),
            r"log.csv: time is not strictly increasing at data row 31 \(t=0.29 s then 0.29 s\)")


def _case_time_not_uniform_csv(d):
    t = np.arange(50) / 100.0
    t[20:] += 0.004
    return (dict(path=_canonical_csv(d, time=t)),
            r"log.csv: time is not uniformly sampled: a gap of 1\.4 sample intervals \(0\.014 s "
            r"against the typical 0\.01 s\) at t=0\.204 s \(data row 21\)")


def _case_time_not_uniform_mdf(d):
    t = np.arange(1000) / 500.0
    t[600:] += 0.001
    return (dict(path=_mdf(d, pot_t=t), channel_map=_pot_map(d)),
            r"log.mf4: the time of 'Pot LF': time is not uniformly sampled: a gap of 1\.5 "
            r"sample intervals \(0\.003 s against the typical 0\.002 s\) at t=1\.201 s "
            r"\(sample 600\)")


def _case_one_sample(d):
    return (dict(path=_canonical_csv(d, rows=1)),
            r"log.csv: has 1 data row\(s\); a run needs at least 2 samples")


def _case_one_sample_mdf(d):
    return (dict(path=_mdf(d, pot_t=np.zeros(1)), channel_map=_pot_map(d)),
            r"log.mf4: has 1 sample\(s\) of 'Pot LF'; a track log needs at least 2")


def _case_some_aero_csv(d):
    return (dict(path=_canonical_csv(d, drop=("aero_roll", "aero_pitch"))),
            r"log.csv: has aero-load columns but not \['aero_roll', 'aero_pitch'\]; the aero "
            r"loads come all three")


def _case_some_aero_map(d):
    return (dict(path=_canonical_csv(d), channel_map=_pot_map(d, ["aero_heave", "aero_roll"])),
            r"logger.toml: maps some aero loads but not \['aero_pitch'\] \(reading track log")


def _case_marker_contradicts_units(d):
    return (dict(path=_canonical_csv(d, marker="imperial"), units="SI"),
            r"log.csv: the file says it is in imperial units \(its 'units' column or "
            r"'# units:' line\) but "
            r"--units says SI; drop --units \(the file's marker decides\)")


def _case_units_column_contradicts_units(d):
    return (dict(path=_canonical_csv(d, edit=lambda f: f.insert(len(f.columns), "units",
                                                                "imperial")), units="SI"),
            r"log.csv: the file says it is in imperial units \(its 'units' column or "
            r"'# units:' line\) but --units says SI")


def _case_units_column_of_two_systems(d):
    def edit(frame):
        frame.insert(len(frame.columns), "units", "SI")
        frame.loc[frame.index[-1], "units"] = "imperial"
    return (dict(path=_canonical_csv(d, edit=edit)),
            r"log.csv: column 'units' says both SI and imperial; a file is in one unit system")


def _case_source_missing_csv(d):
    frame = pd.DataFrame({"time": [0.0, 0.01], **{f"Pot {c}": [0.0, 1.0] for c in CORNERS}})
    path = d / "log.csv"
    frame.to_csv(path, index=False)
    cmap = _pot_map(d, rename={"shock_travel_LR": "Pot_LR"})
    return (dict(path=path, channel_map=cmap),
            r"log.csv: has no column 'Pot_LR' \(did you mean 'Pot LR'\?\) \(mapped to "
            r"shock_travel_LR by channel map .*logger.toml\); the file has \['time', 'Pot LF'")


def _case_source_missing_mdf(d):
    return (dict(path=_mdf(d), channel_map=_pot_map(d, rename={"shock_travel_RF": "Pot_RF"})),
            r"log.mf4: has no channel 'Pot_RF' \(did you mean 'Pot RF'\?\) \(mapped to "
            r"shock_travel_RF by channel map")


def _case_map_channel_not_a_log_channel(d):
    cmap = _pot_map(d)
    cmap.write_text(cmap.read_text() + '[channels.tire_force_LF]\nsource = "TF"\n'
                    'units = "N"\nsign = 1\n')
    return (dict(path=_canonical_csv(d), channel_map=cmap),
            r"logger.toml: \[channels.tire_force_LF\] maps 'tire_force_LF', which is not a "
            r"track-log channel \(reading track log .*\); a track log's channels are "
            r"shock_travel_XX, .*: remove the table")


def _case_map_channel_not_canonical(d):
    cmap = _pot_map(d)
    cmap.write_text(cmap.read_text() + '[channels.sped]\nsource = "v"\nunits = "m/s"\n'
                    'sign = 1\n')
    return (dict(path=_canonical_csv(d), channel_map=cmap),
            r"logger.toml: \[channels.sped\]: 'sped' is not a canonical channel \(did you mean "
            r"'speed'\?\); keys are .* and 'speed'")


def _case_mdf_without_map(d):
    return (dict(path=_mdf(d)),
            r"log.mf4: MDF files are read through a channel map; give one \(channel_map=, "
            r"--map MAP.toml\)")


def _case_faster_than_travel(d):
    path = _mdf(d, extra=[(np.arange(2000) / 1000.0, {"Hub Acc LF": (np.zeros(2000), "g")})])
    return (dict(path=path, channel_map=_pot_map(d, ["wheel_accel_LF"])),
            r"log.mf4: channel 'Hub Acc LF' \(wheel_accel_LF\) is sampled faster \(1000 Hz\) "
            r"than the shock travel 'Pot LF' \(500 Hz\)")


def _case_not_covering(d):
    t = np.arange(30) / 20.0  # 0 .. 1.45 s; the pots run to 1.998 s
    path = _mdf(d, extra=[(t, {"GPS Speed": (np.zeros(30), "")})])
    return (dict(path=path, channel_map=_pot_map(d, ["speed"])),
            r"log.mf4: channel 'GPS Speed' \(speed\) covers t=0..1.45 s but the shock travel "
            r"'Pot LF' covers t=0..1.998 s; a channel must cover the travel's span")


REFUSALS = {  # id -> case builder (folder -> (read_track_log kwargs, match))
    "missing file": _case_missing_file,
    "format given unknown": _case_unknown_format_given,
    "format of the file unknown": _case_unknown_format_of_file,
    "csv without travel": _case_csv_without_travel,
    "map without travel": _case_map_without_travel,
    "NaN in csv": _case_nan_csv,
    "inf in mdf": _case_nan_mdf,
    "time not increasing": _case_time_not_increasing,
    "time not uniform (csv)": _case_time_not_uniform_csv,
    "time not uniform (mdf)": _case_time_not_uniform_mdf,
    "one sample (csv)": _case_one_sample,
    "one sample (mdf)": _case_one_sample_mdf,
    "some aero columns": _case_some_aero_csv,
    "some aero in the map": _case_some_aero_map,
    "marker contradicts units": _case_marker_contradicts_units,
    "units column contradicts units": _case_units_column_contradicts_units,
    "units column of two systems": _case_units_column_of_two_systems,
    "map source missing (csv)": _case_source_missing_csv,
    "map source missing (mdf)": _case_source_missing_mdf,
    "map channel not a log channel": _case_map_channel_not_a_log_channel,
    "map channel not canonical": _case_map_channel_not_canonical,
    "mdf without a map": _case_mdf_without_map,
    "channel faster than the travel": _case_faster_than_travel,
    "channel not covering the travel": _case_not_covering,
}


@pytest.mark.parametrize("case", list(REFUSALS))
def test_read_refusals(case, tmp_path):
    kwargs, match = REFUSALS[case](tmp_path)
    with pytest.raises(TrackLogError, match=match) as info:
        read_track_log(**kwargs)
    message = str(info.value)
    assert message.count("; ") >= 1 and "\n" not in message  # one sentence, with its fix
    at_fault = [str(kwargs[k]) for k in ("path", "channel_map") if k in kwargs]
    assert any(f in message for f in at_fault)  # the log, or the map when the map is wrong


def _log(n=10, **extra):
    return {f"shock_travel_{c}": np.zeros(n) for c in CORNERS} | extra


LOG_REFUSALS = [  # (what is done, match)
    (lambda: TrackLog(name="x", fs_hz=100.0, channels=_log(speeed=np.zeros(10))),
     r"track log 'x': unknown channel\(s\) \['speeed'\] \(did you mean 'speed'\?\)"),
    (lambda: TrackLog(name="x", fs_hz=100.0, channels={"shock_travel_LF": np.zeros(10)}),
     r"track log 'x': no shock travel at RF, LR, RR"),
    (lambda: TrackLog(name="x", fs_hz=100.0, channels=_log(aero_heave=np.zeros(10))),
     r"has aero loads but not \['aero_roll', 'aero_pitch'\]"),
    (lambda: TrackLog(name="x", fs_hz=100.0, channels=_log(speed=np.full(10, np.nan))),
     r"channel 'speed' has 10 NaN/inf value\(s\) from t=0 s"),
    (lambda: TrackLog(name="x", fs_hz=100.0, channels=_log(speed=np.zeros(9))),
     r"channel 'speed' has 9 samples but shock_travel_LF has 10"),
    (lambda: TrackLog(name="x", fs_hz=100.0, channels=_log(n=1)),
     r"has 1 sample\(s\); a track log needs at least 2"),
    (lambda: TrackLog(name="x", fs_hz=0.0, channels=_log()), r"fs_hz = 0.0 must be a positive"),
    (lambda: track_section(TrackLog(name="x", fs_hz=100.0, channels=_log()), 0.05, 0.2),
     r"track log 'x': the window 0.05..0.2 s is not inside the log's 0..0.1 s; give "
     r"0 <= start_s < stop_s <= 0.1"),
    (lambda: track_section(TrackLog(name="x", fs_hz=100.0, channels=_log()), -0.01, 0.05),
     r"the window -0.01..0.05 s is not inside the log's"),
    (lambda: track_section(TrackLog(name="x", fs_hz=100.0, channels=_log()), 0.05, 0.05),
     r"the window 0.05..0.05 s is not inside"),
    (lambda: track_section(TrackLog(name="x", fs_hz=100.0, channels=_log()), 0.05, 0.06),
     r"track log 'x': the window 0.05..0.06 s holds 1 sample\(s\) at 100 Hz; give a window of "
     r"at least 2 samples \(0.02 s\)"),
    (lambda: track_section(TrackLog(name="x", fs_hz=100.0, channels=_log()), 0.0, math.nan),
     r"stop_s = nan must be a finite time"),
    (lambda: write_track_log(TrackLog(name="x", fs_hz=100.0, channels=_log()), "x.xlsx"),
     r"x.xlsx: a track log is written as CSV \(.csv\) or Parquet \(.parquet\), not '.xlsx'"),
]


@pytest.mark.parametrize("call, match", LOG_REFUSALS)
def test_log_section_and_write_refusals(call, match):
    with pytest.raises(TrackLogError, match=match):
        call()


def test_every_refusal_is_a_session_error_too(tmp_path):
    """Callers that catch the session family (the command line) catch track logs too."""
    with pytest.raises(SessionError):
        read_track_log(tmp_path / "none.csv")
    assert TRACK_LOG_RESPONSES[:4] == tuple(f"shock_travel_{c}" for c in CORNERS)


def test_loggers_speed_units_are_known():
    """A logger's km/h and mph are channel-map units (no scale factor to write by hand)."""
    from ident.data.formats.channel_map import unit_factor

    mph_m_s = 1609.344 / 3600.0   # the international mile, by definition
    assert unit_factor("km/h", "velocity") == pytest.approx(KMH_M_S, rel=1e-15)
    assert unit_factor("kph", "velocity") == unit_factor("km/h", "velocity")
    assert unit_factor("mph", "velocity") == pytest.approx(mph_m_s, rel=1e-15)
