"""Tests of ident.data.drive: the Drive container, the three generators (known
spectra, peaks, delays), drive files (SI and imperial round trips) and
resampling."""

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from ident.data.channels import AERO_INPUTS, RIG_INPUTS, WHEELLOADER_INPUTS
from ident.data.drive import (
    ISO8608_N0_CYCLES_M,
    Drive,
    make_noise_drive,
    make_sweep_drive,
    make_track_drive,
    read_drive,
    resample_drive,
    write_drive,
)
from ident.errors import DriveError, SessionError
from ident.data.units import TO_SI

FS = 200.0  # Hz
IN = 0.0254  # m
LBF = 4.4482216152605  # N
PAPER_PEAK = {  # the paper's drive: 1 in wheelloaders, 500 lbf heave, moments
    **dict.fromkeys(WHEELLOADER_INPUTS, 1.0 * IN),
    "aero_heave": 500.0 * LBF,
    "aero_roll": 3.0e4 * LBF * IN,
    "aero_pitch": 5.0e4 * LBF * IN,
}
RTOL_FLAT = 0.10  # sub-band means of a Welch PSD with ~80 averages: ~3 % scatter
MAX_CORR = 0.05  # ~12000 independent samples: |r| scatter ~0.01
RTOL_SWEEP = 5e-3  # Hilbert instantaneous frequency, away from the ends
RTOL_DELAY = 1e-3  # 0.01 sample of 11.2: rounding to whole samples would be 1.6 % off
ATOL_SLOPE = 0.1  # log-log fit of a Welch PSD over 2..15 Hz
RTOL_RMS = 0.02  # sum over 1/120 Hz bins vs the integral of the PSD
RTOL_RESAMPLE = 1e-4  # the anti-aliasing FIR is flat to 1e-5 below 0.8 Nyquist
RTOL_FILE = 1e-12  # CSV floats are written with round-trip precision
RTOL_FFT_DECIMATE = 1e-12  # FFT vs polyphase filtering: rounding only (seen < 1e-14 of the RMS)


@pytest.fixture(scope="module")
def noise():
    return make_noise_drive(duration_s=200.0, fs_hz=FS, seed=7,
                            peak={k: v for k, v in PAPER_PEAK.items() if k != "aero_roll"})


@pytest.fixture(scope="module")
def track():
    return make_track_drive(duration_s=120.0, fs_hz=FS, seed=11, taper_s=0.0,
                            aero={"aero_heave": 400.0, "aero_pitch": 250.0})


def _zeros(n=100):
    return {c: np.zeros(n) for c in RIG_INPUTS}


# --------------------------------------------------------------------------------------
# Drive
# --------------------------------------------------------------------------------------


def test_drive_container():
    chans = _zeros(50)
    chans["aero_pitch"] = np.arange(50.0)
    drive = Drive(name="d", fs_hz=100, channels=chans, settings={"kind": "test"})
    assert drive.n_samples == 50 and drive.fs_hz == 100.0
    assert drive.duration_s == 0.5
    assert_allclose(drive.time_s, np.arange(50) / 100.0)
    assert list(drive.channels) == list(RIG_INPUTS)
    a = drive.as_array()
    assert a.shape == (50, 7) and a.dtype == np.float64
    assert_allclose(a[:, RIG_INPUTS.index("aero_pitch")], np.arange(50.0))
    chans["aero_pitch"][0] = 99.0  # the drive holds its own copy
    assert drive.channels["aero_pitch"][0] == 0.0
    with pytest.raises(ValueError):
        drive.channels["aero_pitch"][0] = 1.0  # read-only
    assert "n_samples=50" in repr(drive)


def _without(name):
    chans = _zeros()
    del chans[name]
    return chans


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"channels": _without("wheelloader_RR")}, r"missing \['wheelloader_RR'\]"),
        ({"channels": {**_zeros(), "aero_yaw": np.zeros(100)}}, r"unknown \['aero_yaw'\]"),
        ({"channels": {**_zeros(), "aero_heave": np.zeros(99)}}, "differ in length"),
        ({"channels": {**_zeros(), "aero_heave": np.full(100, np.nan)}},
         r"'aero_heave' has 100 NaN/inf value\(s\) from t=0"),
        ({"channels": {**_zeros(), "aero_roll": np.zeros((100, 2))}}, "one-dimensional"),
        ({"channels": _zeros(1)}, "fewer than 2 samples"),
        ({"channels": [np.zeros(100)] * 7}, "must be a mapping"),
        ({"fs_hz": 0.0}, "fs_hz must be a finite positive number"),
        ({"fs_hz": float("inf")}, "fs_hz must be a finite positive number"),
        ({"fs_hz": "fast"}, "fs_hz must be a number"),
        ({"name": ""}, "non-empty string"),
    ],
)
def test_drive_rejects_bad_input(kwargs, match):
    args = {"name": "bad", "fs_hz": 100.0, "channels": _zeros(), **kwargs}
    with pytest.raises(DriveError, match=match):
        Drive(**args)


# --------------------------------------------------------------------------------------
# Noise drive
# --------------------------------------------------------------------------------------


def test_noise_drive_peaks_are_exact(noise):
    for c in RIG_INPUTS:
        x = noise.channels[c]
        if c == "aero_roll":  # absent from peak: all zeros
            assert not x.any()
        else:
            assert_allclose(np.max(np.abs(x)), PAPER_PEAK[c], rtol=1e-12)
            assert x[0] == 0.0 and x[-1] == 0.0  # the raised-cosine fades
    assert noise.n_samples == 40000
    assert noise.settings["kind"] == "noise" and noise.settings["seed"] == 7
    assert noise.name == "noise-7"


def test_noise_drive_is_seeded(noise):
    again = make_noise_drive(duration_s=200.0, fs_hz=FS, seed=7, peak=noise.settings["peak"])
    other = make_noise_drive(duration_s=200.0, fs_hz=FS, seed=8, peak=noise.settings["peak"])
    assert np.array_equal(again.as_array(), noise.as_array())
    assert not np.allclose(other.as_array(), noise.as_array())


def test_noise_drive_spectrum_flat_then_cut(noise):
    for c in ("wheelloader_LF", "aero_heave"):
        f, psd = signal.welch(noise.channels[c], fs=FS, nperseg=1024)
        sub_bands = [(1, 5), (5, 10), (10, 15), (15, 20), (20, 24)]  # up to 0.8 f_max
        means = np.array([psd[(f >= a) & (f < b)].mean() for a, b in sub_bands])
        assert_allclose(means, means.mean(), rtol=RTOL_FLAT)
        at_2fmax = psd[(f >= 58) & (f <= 62)].mean()
        assert 10 * np.log10(at_2fmax / means.mean()) < -40.0  # order 8: -48 dB


def test_noise_drive_channels_uncorrelated(noise):
    used = [c for c in RIG_INPUTS if c != "aero_roll"]
    r = np.corrcoef(np.array([noise.channels[c] for c in used]))
    assert np.max(np.abs(r - np.eye(len(used)))) < MAX_CORR


def test_noise_drive_without_taper_and_zero_peak():
    drive = make_noise_drive(duration_s=5.0, fs_hz=100.0, seed=1, taper_s=0.0,
                             peak={"aero_heave": 0.0, "wheelloader_LR": 0.01})
    assert not drive.channels["aero_heave"].any()
    assert_allclose(np.abs(drive.channels["wheelloader_LR"]).max(), 0.01)


# --------------------------------------------------------------------------------------
# Sweep drive
# --------------------------------------------------------------------------------------


def _instantaneous_frequency(x, fs):
    phase = np.unwrap(np.angle(signal.hilbert(x)))
    t_mid = (np.arange(x.size - 1) + 0.5) / fs
    return t_mid, np.diff(phase) * fs / (2 * np.pi)


@pytest.mark.parametrize("method", ["logarithmic", "linear"])
def test_sweep_instantaneous_frequency(method):
    f0, f1, duration = 0.5, 25.0, 60.0
    drive = make_sweep_drive(duration_s=duration, fs_hz=FS, amplitude=0.01, method=method,
                             f_start_hz=f0, f_stop_hz=f1)
    t_end = drive.time_s[-1]
    t, f_inst = _instantaneous_frequency(drive.channels["wheelloader_RF"], FS)
    if method == "logarithmic":
        expected = f0 * (f1 / f0) ** (t / t_end)
    else:
        expected = f0 + (f1 - f0) * t / t_end
    interior = (t > 5.0) & (t < duration - 5.0)
    assert_allclose(f_inst[interior], expected[interior], rtol=RTOL_SWEEP)
    for c in WHEELLOADER_INPUTS:  # the same in-phase sweep on the four corners
        assert np.array_equal(drive.channels[c], drive.channels["wheelloader_RF"])
        assert_allclose(np.abs(drive.channels[c]).max(), 0.01, rtol=1e-3)
    for c in AERO_INPUTS:
        assert not drive.channels[c].any()


def test_sweep_per_channel_amplitude():
    drive = make_sweep_drive(duration_s=20.0, fs_hz=FS, channels=("aero_heave", "aero_pitch"),
                             amplitude={"aero_heave": 1000.0, "aero_pitch": 300.0},
                             taper_s=0.0, name="aero sweep")
    assert drive.name == "aero sweep"
    assert_allclose(drive.channels["aero_pitch"], 0.3 * drive.channels["aero_heave"])
    assert_allclose(np.abs(drive.channels["aero_heave"]).max(), 1000.0, rtol=1e-3)
    assert abs(drive.channels["aero_heave"][0]) < 1e-12  # starts at zero phase (sin)
    assert not drive.channels["wheelloader_LF"].any()


# --------------------------------------------------------------------------------------
# Track drive
# --------------------------------------------------------------------------------------


def test_track_rear_is_front_delayed_exactly(track):
    delay = track.settings["delay_s"]
    assert_allclose(delay, 2.794 / 50.0)
    assert (delay * FS) % 1 > 0.1  # a fraction of a sample: rounding would show
    f = np.fft.rfftfreq(track.n_samples, 1 / FS)
    for side in ("L", "R"):
        front = track.channels[f"wheelloader_{side}F"]
        delayed = np.fft.irfft(np.fft.rfft(front) * np.exp(-2j * np.pi * f * delay),
                               track.n_samples)  # periodic record: a closed lap
        assert_allclose(track.channels[f"wheelloader_{side}R"], delayed,
                        atol=1e-12 * np.abs(front).max())


def test_track_delay_from_cross_spectrum_phase():
    drive = make_track_drive(duration_s=120.0, fs_hz=FS, seed=5, speed_m_s=40.0,
                             wheelbase_m=2.6)  # with the default fades
    f, pxy = signal.csd(drive.channels["wheelloader_LF"], drive.channels["wheelloader_LR"],
                        fs=FS, nperseg=2048)  # Pxy = conj(X) Y: phase -2 pi f delay
    band = (f >= 0.5) & (f <= 20.0)
    slope = np.polyfit(f[band], np.unwrap(np.angle(pxy[band])), 1)[0]
    assert_allclose(-slope / (2 * np.pi), 2.6 / 40.0, rtol=RTOL_DELAY)


@pytest.mark.parametrize("waviness", [2.0, 2.5])
def test_track_psd_slope_and_level(waviness):
    speed, roughness = 50.0, 8e-6
    drive = make_track_drive(duration_s=120.0, fs_hz=FS, seed=2, waviness=waviness,
                             taper_s=0.0)
    f, psd = signal.welch(drive.channels["wheelloader_RR"], fs=FS, nperseg=2048)
    band = (f >= 2.0) & (f <= 15.0)
    slope, _ = np.polyfit(np.log(f[band]), np.log(psd[band]), 1)
    assert abs(slope + waviness) < ATOL_SLOPE
    # level: G(f) = Gd(f / v) / v
    n = f[band] / speed
    expected = roughness * (n / ISO8608_N0_CYCLES_M) ** -waviness / speed
    assert_allclose(np.exp(np.mean(np.log(psd[band] / expected))), 1.0, rtol=0.1)


def test_track_default_rms_is_a_few_mm(track):
    gd_n0, n0, v = 8e-6, 0.1, 50.0
    analytic = np.sqrt(gd_n0 * n0**2 * (v / 0.3 - v / 30.0))  # w = 2: 3.6 mm
    for c in WHEELLOADER_INPUTS:
        rms = np.std(track.channels[c])
        assert_allclose(rms, track.settings["wheel_rms_m"], rtol=1e-9)
        assert_allclose(rms, analytic, rtol=RTOL_RMS)
    assert 2e-3 < analytic < 5e-3


def test_track_left_right_coherence():
    track_width, speed, c_b = 1.6, 50.0, 0.3
    drive = make_track_drive(duration_s=240.0, fs_hz=FS, seed=4, track_width_m=track_width,
                             left_right_coherence=c_b)
    f, coh = signal.coherence(drive.channels["wheelloader_LF"],
                              drive.channels["wheelloader_RF"], fs=FS, nperseg=1024)
    for lo, hi in [(1.0, 5.0), (10.0, 20.0), (20.0, 28.0)]:
        band = (f >= lo) & (f <= hi)
        model = c_b ** (f[band] / speed * track_width)
        assert abs(coh[band].mean() - model.mean()) < 0.06
    same = make_track_drive(duration_s=20.0, fs_hz=FS, seed=4, left_right_coherence=1.0)
    assert_allclose(same.channels["wheelloader_LF"], same.channels["wheelloader_RF"],
                    atol=1e-15)


def test_track_aero(track):
    assert_allclose(np.std(track.channels["aero_heave"]), 400.0, rtol=1e-9)
    assert_allclose(np.std(track.channels["aero_pitch"]), 250.0, rtol=1e-9)
    assert not track.channels["aero_roll"].any()
    assert abs(track.channels["aero_heave"].mean()) < 1e-9  # mean-free
    f, psd = signal.welch(track.channels["aero_heave"], fs=FS, nperseg=4096)
    assert psd[f > 4.0].max() < 1e-6 * psd.max()  # slowly varying: below 2 Hz
    plain = make_track_drive(duration_s=120.0, fs_hz=FS, seed=11, taper_s=0.0)
    assert np.array_equal(plain.channels["wheelloader_LF"], track.channels["wheelloader_LF"])
    assert not plain.channels["aero_heave"].any()


# --------------------------------------------------------------------------------------
# Generator input checks
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "make, kwargs, match",
    [
        (make_noise_drive, {"duration_s": 0.0}, "duration_s must be a finite positive"),
        (make_noise_drive, {"fs_hz": -1.0}, "fs_hz must be a finite positive"),
        (make_noise_drive, {"f_max_hz": 60.0}, r"f_max_hz = 60 Hz must be below fs_hz/2"),
        (make_noise_drive, {"peak": {"wheel_LF": 1.0}}, r"unknown channel\(s\) \['wheel_LF'\]"),
        (make_noise_drive, {"peak": {"aero_heave": -1.0}}, "non-negative"),
        (make_noise_drive, {"peak": [1.0]}, "must be a mapping"),
        (make_noise_drive, {"filter_order": 0}, "positive integer"),
        (make_noise_drive, {"taper_s": 6.0}, "shorten taper_s"),
        (make_sweep_drive, {"method": "exponential"}, "unknown method 'exponential'"),
        (make_sweep_drive, {"f_stop_hz": 50.0}, "below fs_hz/2"),
        (make_sweep_drive, {"channels": ("wheelloader_XX",)}, "distinct rig inputs"),
        (make_sweep_drive, {"amplitude": {"wheelloader_LF": 1.0}}, "no value for"),
        (make_track_drive, {"speed_m_s": 0.0}, "speed_m_s must be a finite positive"),
        (make_track_drive, {"left_right_coherence": 1.5}, r"in \[0, 1\]"),
        (make_track_drive, {"f_min_hz": 40.0}, "must be below f_max_hz"),
        (make_track_drive, {"f_min_hz": 0.05}, "shorter than one period"),
        (make_track_drive, {"aero": {"wheelloader_LF": 1.0}}, "unknown channel"),
        (make_track_drive, {"aero": {"aero_heave": 1.0}, "aero_f_max_hz": 0.2},
         "must be above f_min_hz"),
        (make_track_drive, {"duration_s": 4.0, "aero": {"aero_heave": 1.0},
                            "aero_f_max_hz": 0.4}, "no frequency .* in the aero band"),
    ],
)
def test_generators_reject_bad_input(make, kwargs, match):
    base = {"duration_s": 10.0, "fs_hz": 100.0}
    if make is make_noise_drive:
        base.update(seed=1, peak={"aero_heave": 1.0})
    elif make is make_sweep_drive:
        base.update(amplitude=0.01)
    else:
        base.update(seed=1)
    with pytest.raises(DriveError, match=match):
        make(**{**base, **kwargs})


# --------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("units, suffix", [("SI", ".csv"), ("imperial", ".csv"),
                                           ("imperial", ".parquet")])
def test_write_read_round_trip(noise, tmp_path, units, suffix):
    """Read back with the units given, or with none: the file's marker says them."""
    path = tmp_path / f"drive{suffix}"
    write_drive(noise, path, units=units)
    for given in (units, None):
        back = read_drive(path, units=given)
        assert back.name == "drive" and back.settings["kind"] == "file"
        assert back.settings["units"] == units
        assert back.settings["units_from"] == "file"  # the marker says them either way
        assert_allclose(back.fs_hz, FS, rtol=1e-9)
        for c in RIG_INPUTS:
            assert_allclose(back.channels[c], noise.channels[c], rtol=RTOL_FILE,
                            atol=RTOL_FILE * PAPER_PEAK[c])


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_units_contradicting_the_marker_are_an_error(noise, tmp_path, suffix):
    path = tmp_path / f"lap{suffix}"
    write_drive(noise, path, units="imperial")
    with pytest.raises(SessionError) as exc:
        read_drive(path, units="SI")
    text = str(exc.value)
    assert isinstance(exc.value, ValueError)
    assert text.startswith(f"drive file {path}: ")
    assert "in imperial units" in text and "--units says SI" in text
    assert "drop --units" in text  # the fix


def _without_units_column(src, dst):
    """Copy CSV file `src` to `dst` without its last column, ``units``, text kept as is."""
    lines = src.read_text().splitlines()
    assert lines[0].endswith(",units")
    dst.write_text("".join(line.rsplit(",", 1)[0] + "\n" for line in lines))


def test_implausible_drive_of_unknown_units_is_refused(tmp_path, caplog):
    """An inch file without a marker read as SI: metres of wheel-pad motion. Nobody said
    the units, so reading stops and names the fix; said (--units SI, or a marker), it
    warns as before."""
    drive = make_track_drive(duration_s=20.0, fs_hz=100.0, seed=5, name="lap")
    marked = tmp_path / "marked.csv"
    write_drive(drive, marked, units="imperial")
    bare = tmp_path / "bare.csv"
    _without_units_column(marked, bare)  # the units column cut off
    with pytest.raises(DriveError) as exc:
        read_drive(bare)
    text = str(exc.value)
    assert isinstance(exc.value, ValueError)
    assert text.startswith(f"drive file {bare}: wheelloader_")
    assert "--units imperial" in text and "a column 'units' holding imperial" in text
    with caplog.at_level("WARNING", logger="ident.data.drive"):
        as_si = read_drive(bare, units="SI")  # the user said SI: warned, not refused
    assert "--units imperial" in caplog.text and "bare.csv" in caplog.text
    assert as_si.settings["units_from"] == "argument"
    caplog.clear()
    with caplog.at_level("WARNING", logger="ident.data.drive"):
        for path, units in ((bare, "imperial"), (marked, None), (marked, "imperial")):
            back = read_drive(path, units=units)
            assert_allclose(back.channels["wheelloader_LF"], drive.channels["wheelloader_LF"],
                            rtol=RTOL_FILE, atol=RTOL_FILE * IN)
    assert caplog.text == ""
    # a file that says it is SI and is implausible: its own statement stands, with a warning
    bare_si = tmp_path / "said_si.csv"
    bare_si.write_text("# units: SI\n" + bare.read_text())
    with caplog.at_level("WARNING", logger="ident.data.drive"):
        assert read_drive(bare_si).settings["units_from"] == "file"
    assert "said_si.csv" in caplog.text


def _scaled_drive_file(path, scale, *, units):
    """The seed-5 track drive, its wheel pads scaled by `scale`, written without a units
    column (values in `units`)."""
    drive = make_track_drive(duration_s=20.0, fs_hz=100.0, seed=5, name="lap")
    drive = Drive("lap", drive.fs_hz, {c: x * (scale if c in WHEELLOADER_INPUTS else 1.0)
                                       for c, x in drive.channels.items()})
    marked = path.with_name("marked.csv")
    write_drive(drive, marked, units=units, overwrite=True)
    _without_units_column(marked, path)
    return drive


def test_drive_plausible_in_both_unit_systems_is_read_as_si_with_a_warning(tmp_path, caplog):
    """Issue 36: an imperial drive at a quarter of the demo's level (0.036 in RMS) without
    any units statement is plausible as SI too (36 mm): read as SI, the spec's default,
    with a warning naming --units; a demo-level SI drive is not warned of."""
    path = tmp_path / "quarter.csv"
    drive = _scaled_drive_file(path, 1.0, units="imperial")
    rms_in = max(float(np.std(drive.channels[c])) for c in WHEELLOADER_INPUTS) / IN
    scale = 0.036 / rms_in  # 0.036 in RMS
    drive = _scaled_drive_file(path, scale, units="imperial")
    with caplog.at_level("WARNING", logger="ident.data.drive"):
        back = read_drive(path)
    assert back.settings["units"] == "SI" and back.settings["units_from"] == "default"
    assert_allclose(back.channels["wheelloader_LF"],
                    drive.channels["wheelloader_LF"] / IN, rtol=1e-12)  # the values as SI
    assert "quarter.csv" in caplog.text and "--units imperial" in caplog.text
    assert "--units SI" in caplog.text and "36.0 mm" in caplog.text
    caplog.clear()
    si = tmp_path / "si.csv"
    _scaled_drive_file(si, 1.0, units="SI")  # a few mm RMS: not an inch file's level
    with caplog.at_level("WARNING", logger="ident.data.drive"):
        assert read_drive(si).settings["units"] == "SI"
    assert caplog.text == ""


@pytest.mark.parametrize("rms_m", [1e-4, 3.0])
def test_drive_implausible_in_either_unit_system_is_refused(tmp_path, rms_m):
    """Without a units statement, a level no rig plays read as SI or as imperial (0.1 mm or
    3 m as SI: 0.0025 mm or 76 m as inches) is refused, naming the file, the level and the
    fix; given --units, it reads."""
    path = tmp_path / "odd.csv"
    drive = _scaled_drive_file(path, 1.0, units="SI")
    rms = max(float(np.std(drive.channels[c])) for c in WHEELLOADER_INPUTS)
    _scaled_drive_file(path, rms_m / rms, units="SI")
    with pytest.raises(DriveError) as exc:
        read_drive(path)
    text = str(exc.value)
    assert text.startswith(f"drive file {path}: the wheel pads' level, wheelloader_")
    assert f"RMS of {rms_m:.3g}" in text and "implausible in either unit system" in text
    assert "--units SI or --units imperial" in text and "'units' column" in text
    assert read_drive(path, units="SI").settings["units_from"] == "argument"


def test_imperial_file_holds_inches_and_pounds(noise, tmp_path):
    path = tmp_path / "drive.csv"
    write_drive(noise, path, units="imperial")
    assert path.read_text().splitlines()[0] == ",".join(["time", *RIG_INPUTS, "units"])
    raw = pd.read_csv(path)
    assert list(raw.columns) == ["time", *RIG_INPUTS, "units"]
    assert (raw.pop("units") == "imperial").all()
    assert_allclose(raw["wheelloader_LF"].abs().max(), 1.0, rtol=1e-12)  # 1 in
    assert_allclose(raw["aero_heave"].abs().max(), 500.0, rtol=1e-12)  # 500 lbf
    assert_allclose(raw["aero_pitch"].abs().max(), 5.0e4, rtol=1e-12)  # lbf*in
    # the file says its units: read without any, it is read as imperial
    back = read_drive(path)
    assert back.settings["units"] == "imperial" and back.settings["units_from"] == "file"
    assert_allclose(back.channels["wheelloader_LF"], noise.channels["wheelloader_LF"],
                    rtol=RTOL_FILE, atol=RTOL_FILE * PAPER_PEAK["wheelloader_LF"])
    # the same values read as SI would be 39x too large: units matter
    raw.to_csv(tmp_path / "bare.csv", index=False)
    assert_allclose(read_drive(tmp_path / "bare.csv", units="SI").channels["wheelloader_LF"],
                    noise.channels["wheelloader_LF"] / TO_SI["displacement"], rtol=1e-12)


def test_read_drive_channel_map_and_extra_columns(tmp_path):
    n = 50
    frame = pd.DataFrame({"time": np.arange(n) / 100.0 + 3.0,
                          **{c: np.full(n, 0.001 * i) for i, c in enumerate(RIG_INPUTS)},
                          "comment": ["x"] * n, "tire_force_LF": np.ones(n)})
    frame = frame.rename(columns={"wheelloader_LF": "WL_LF_Disp"})
    path = tmp_path / "export.csv"
    frame.to_csv(path, index=False)
    drive = read_drive(path, channel_map={"wheelloader_LF": "WL_LF_Disp"}, name="lap 3")
    assert drive.name == "lap 3" and drive.n_samples == n
    assert list(drive.channels) == list(RIG_INPUTS)
    assert_allclose(drive.channels["wheelloader_LF"], 0.003)
    assert drive.settings["t0_s"] == 3.0


def test_drive_file_errors(noise, tmp_path):
    path = tmp_path / "drive.csv"
    write_drive(noise, path)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_drive(noise, path)
    write_drive(noise, path, overwrite=True)
    pd.read_csv(path).drop(columns="aero_roll").to_csv(path, index=False)
    with pytest.raises(SessionError, match="missing required channel.*aero_roll"):
        read_drive(path)
    with pytest.raises(SessionError, match="file not found"):
        read_drive(tmp_path / "nope.csv")
    with pytest.raises(SessionError, match="unknown unit system"):
        read_drive(path, units="metric")
    with pytest.raises(TypeError, match="must be a Drive"):
        write_drive(noise.channels, tmp_path / "x.csv")


# --------------------------------------------------------------------------------------
# Resampling
# --------------------------------------------------------------------------------------


def test_resample_keeps_in_band_content():
    t = np.arange(4000) / FS
    chans = _zeros(4000)
    chans["wheelloader_LF"] = 0.01 * np.sin(2 * np.pi * 5.0 * t)
    drive = Drive(name="sine", fs_hz=FS, channels=chans)
    for fs_new in (100.0, 500.0, 150.0):
        out = resample_drive(drive, fs_new)
        assert out.fs_hz == fs_new and out.name == "sine"
        assert out.n_samples == int(np.ceil(4000 * fs_new / FS))
        x, tt = out.channels["wheelloader_LF"], out.time_s
        interior = (tt > 1.0) & (tt < 19.0)
        assert_allclose(x[interior], 0.01 * np.sin(2 * np.pi * 5.0 * tt[interior]),
                        atol=RTOL_RESAMPLE * 0.01)
        assert out.settings["resampled_from_hz"] == FS


def test_resample_same_rate_and_bad_rate(noise):
    near = resample_drive(noise, FS * (1 + 1e-9))  # a file's rate, rounded
    assert near.fs_hz == FS * (1 + 1e-9)
    assert np.array_equal(near.as_array(), noise.as_array())
    with pytest.raises(DriveError, match=r"into 200.1 Hz \(closest: "):
        resample_drive(noise, 200.1)  # 2001/2000: no fraction with down <= 1000
    odd = resample_drive(noise, FS * np.sqrt(2.0))  # 1393/985, within 4e-7
    assert (odd.settings["resample_up"], odd.settings["resample_down"]) == (1393, 985)
    with pytest.raises(DriveError, match="positive"):
        resample_drive(noise, 0.0)
    with pytest.raises(TypeError, match="must be a Drive"):
        resample_drive(noise.channels, 100.0)


def _decimate_reference(x, r, n_out, lead):
    """Extend by (FIR_HALF_LENGTH + 1) r samples each end, resample_bandlimited, slice."""
    from ident.data.drive import FIR_HALF_LENGTH, resample_bandlimited

    pad = (FIR_HALF_LENGTH + 1) * r
    xp = np.pad(x, (pad, 0), mode="edge" if lead == "edge" else "constant")
    xp = np.pad(xp, (0, pad), mode="edge")
    return resample_bandlimited(xp, 1, r)[pad // r: pad // r + n_out]


@pytest.mark.parametrize("lead", ["edge", "zero"])
@pytest.mark.parametrize("r, n_in, n_out", [
    (8, 40_001, 5001),  # several FFT segments
    (8, 40_007, 5001),  # a record longer than the samples asked for
    (8, 40_001, 4000),
    (3, 1001, 334), (2, 4096, 2048), (7, 50, 8), (5, 1, 1), (16, 17, 2), (1, 11, 11),
])
def test_fft_decimation_equals_polyphase_reference(rng, lead, r, n_in, n_out):
    """The FFT engine of the acquisition filter gives resample_bandlimited's numbers."""
    from ident.data.drive import decimate_bandlimited

    rows = [rng.standard_normal(n_in) + 3.0, np.linspace(-1.0, 2.0, n_in),
            np.where(np.arange(n_in) % 7 == 0, 1.0, 0.0)]
    out = decimate_bandlimited(rows, r, n_out, lead=lead)
    for x, y in zip(rows, out):
        ref = x[:n_out] if r == 1 else _decimate_reference(x, r, n_out, lead)
        assert y.shape == (n_out,) and y.flags.owndata
        tol = RTOL_FFT_DECIMATE * max(np.sqrt(np.mean(ref ** 2)), 1e-300)
        assert_allclose(y, ref, rtol=0, atol=tol)


@pytest.mark.parametrize("rows, r, n_out, lead, match", [
    ([np.zeros(10), np.zeros(11)], 2, 5, "edge", "one length"),
    ([np.zeros((2, 10))], 2, 5, "edge", "1-D records"),
    ([np.zeros(10)], 2, 6, "edge", r"> 10"),
    ([np.zeros(10)], 2, 0, "edge", "cannot give 0 samples"),
    ([np.zeros(10)], 2, 5, "mirror", "lead must be"),
])
def test_fft_decimation_bad_input(rows, r, n_out, lead, match):
    from ident.data.drive import decimate_bandlimited

    with pytest.raises(ValueError, match=match):
        decimate_bandlimited(rows, r, n_out, lead=lead)
