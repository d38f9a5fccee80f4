"""Tests of ident.sim.metrics: known answers (a sine's RMS, Parseval), equivalences
(batched vs loop, object vs mapping), unit conversion and bad inputs."""

from types import SimpleNamespace

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from ident.data.channels import CORNERS
from ident.sim.metrics import (
    BAND_SUFFIXES,
    METRIC_NAMES,
    METRIC_QUANTITY,
    Metrics,
    bandpass,
    compute_metrics,
)
from ident.data.units import TO_SI

FS = 200.0  # Hz
RTOL_SINE = 1e-3  # 600 cycles: the filtfilt edge transients weigh < 0.05 %
REJECT = 0.02  # out-of-band sine: RMS below 2 % of A/sqrt(2) over 800 s
RTOL_PARSEVAL = 0.03  # Welch with ~300 averages: about 1 % scatter of the integral
RTOL_SPLIT = 0.03  # the two bands lose < 0.5 % of the power around split_hz
ATOL_ZERO = 1e-12  # exact cancellation up to rounding


@pytest.fixture
def rng():
    return np.random.default_rng(20090420)


def _t(duration_s, fs=FS):
    return np.arange(int(round(duration_s * fs))) / fs


def _tire_force_rms(x):
    return compute_metrics({"tire_force_LF": x}, fs=FS).values["tire_force_rms_LF"]


def test_metric_names_follow_the_spec():
    assert METRIC_NAMES == (
        "tire_force_rms_LF", "tire_force_rms_RF", "tire_force_rms_LR", "tire_force_rms_RR",
        "ride_height_rms_front", "ride_height_rms_rear",
        "shock_travel_rms_LF", "shock_travel_rms_RF", "shock_travel_rms_LR",
        "shock_travel_rms_RR",
        "shock_velocity_rms_LF", "shock_velocity_rms_RF", "shock_velocity_rms_LR",
        "shock_velocity_rms_RR",
    )
    assert METRIC_QUANTITY["tire_force_rms_RR"] == "force"
    assert METRIC_QUANTITY["ride_height_rms_front"] == "displacement"
    assert METRIC_QUANTITY["shock_travel_rms_LF"] == "displacement"
    assert METRIC_QUANTITY["shock_velocity_rms_LR_wheelhop"] == "velocity"
    assert METRIC_QUANTITY["tire_force_rms_norm_LF_body"] == "dimensionless"
    # the closed loop's element metrics (issue 25), not band-passed: no band variants
    assert METRIC_QUANTITY["tire_contact_min_RR"] == "force"
    assert METRIC_QUANTITY["tire_liftoff_share_LF"] == "dimensionless"
    assert METRIC_QUANTITY["bump_stop_contact_share_LR"] == "dimensionless"
    assert "tire_contact_min_RR_body" not in METRIC_QUANTITY
    assert set(METRIC_QUANTITY.values()) <= set(TO_SI)


def test_element_metrics_convert_to_imperial():
    """Metrics holding the closed loop's element metrics convert: the contact force as a
    force, the shares unchanged."""
    m = Metrics(values={"tire_contact_min_LF": np.array([4.4482216152605, 0.0]),
                        "tire_liftoff_share_LF": np.array([0.0, 0.02])},
                band_hz=(1.0, 20.0), order=4, fs_hz=100.0)
    got = m.to_units("imperial")
    np.testing.assert_allclose(got["tire_contact_min_LF"], [1.0, 0.0], rtol=1e-12)
    np.testing.assert_array_equal(got["tire_liftoff_share_LF"], [0.0, 0.02])


def test_bandpass_is_the_reference_filter(rng):
    x = rng.standard_normal((3, 2000))
    ref = signal.sosfiltfilt(signal.butter(4, [1, 20], "bandpass", fs=FS, output="sos"), x)
    assert_allclose(bandpass(x, fs=FS), ref, rtol=0, atol=0)
    # vectorized over the other axes: the time axis may be any axis
    assert_allclose(bandpass(x.T, fs=FS, axis=0), ref.T, rtol=0, atol=0)


@pytest.mark.parametrize("phase", [0.0, 0.7])
def test_sine_in_band_has_rms_amplitude_over_sqrt2(phase):
    amplitude = 1234.0  # N
    t = _t(120.0)
    x = amplitude * np.sin(2 * np.pi * 5.0 * t + phase) + 5000.0  # static offset removed
    assert_allclose(_tire_force_rms(x), amplitude / np.sqrt(2), rtol=RTOL_SINE)


@pytest.mark.parametrize("f_hz", [0.3, 40.0])
def test_sine_out_of_band_is_rejected(f_hz):
    amplitude = 1234.0
    x = amplitude * np.sin(2 * np.pi * f_hz * _t(800.0))
    assert _tire_force_rms(x) < REJECT * amplitude / np.sqrt(2)


def test_parseval_band_limited_white_noise(rng):
    # white noise band-limited to 2..10 Hz (brick wall in the frequency
    # domain), where the band-pass gain is within 1.5 % of one
    n = int(600 * FS)
    spectrum = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1 / FS)
    spectrum[(f < 2.0) | (f > 10.0)] = 0.0
    x = np.fft.irfft(spectrum, n)
    f_w, psd = signal.welch(x, fs=FS, nperseg=1024)
    in_band = (f_w >= 1.0) & (f_w <= 20.0)
    expected = np.sqrt(np.trapezoid(psd[in_band], f_w[in_band]))
    assert_allclose(_tire_force_rms(x), expected, rtol=RTOL_PARSEVAL)


def test_parseval_white_noise_weighted_by_the_filter(rng):
    # full-band white noise: the metric's power is the PSD weighted by the
    # zero-phase filter's |H|^2 (forward and backward: |H_butter|^4)
    x = rng.standard_normal(int(600 * FS))
    f_w, psd = signal.welch(x, fs=FS, nperseg=1024)
    sos = signal.butter(4, [1, 20], "bandpass", fs=FS, output="sos")
    _, h = signal.sosfreqz(sos, worN=f_w, fs=FS)
    expected = np.sqrt(np.trapezoid(psd * np.abs(h) ** 4, f_w))
    assert_allclose(_tire_force_rms(x), expected, rtol=RTOL_PARSEVAL)


def test_ride_height_is_the_mean_of_the_two_corners(rng):
    t = _t(60.0)
    s = 0.004 * np.sin(2 * np.pi * 3.0 * t)
    a, b = 0.003 * rng.standard_normal((2, t.size))
    values = compute_metrics(
        {"ride_height_LF": s + 0.05, "ride_height_RF": -s + 0.05,  # roll only
         "ride_height_LR": a, "ride_height_RR": b},
        fs=FS,
    ).values
    assert values["ride_height_rms_front"] < ATOL_ZERO
    mean_rear = (a + b) / 2
    expected = np.sqrt(np.mean(bandpass(mean_rear - mean_rear.mean(), fs=FS) ** 2))
    assert_allclose(values["ride_height_rms_rear"], expected, rtol=1e-12)
    same = compute_metrics({"ride_height_LF": s, "ride_height_RF": s}, fs=FS).values
    assert_allclose(same["ride_height_rms_front"], 0.004 / np.sqrt(2), rtol=RTOL_SINE)


def _full_response(rng, shape, n=4000):
    chans = {}
    for kind in ("tire_force", "ride_height", "shock_travel", "shock_velocity"):
        for c in CORNERS:
            chans[f"{kind}_{c}"] = rng.standard_normal(shape + (n,))
    return chans


def test_all_metrics_in_spec_order(rng):
    metrics = compute_metrics(_full_response(rng, ()), fs=FS)
    assert isinstance(metrics, Metrics)
    assert tuple(metrics.values) == METRIC_NAMES
    assert all(isinstance(v, float) for v in metrics.values.values())
    assert metrics.band_hz == (1.0, 20.0) and metrics.order == 4 and metrics.fs_hz == FS
    assert metrics.split_hz is None


def test_batched_equals_loop(rng):
    chans = _full_response(rng, (3,))
    loads = {"LF": 3000.0, "RR": 3500.0}
    batched = compute_metrics(chans, fs=FS, static_loads_n=loads, split_hz=8.0).values
    for i in range(3):
        single = compute_metrics({k: v[i] for k, v in chans.items()}, fs=FS,
                                 static_loads_n=loads, split_hz=8.0).values
        assert single.keys() == batched.keys()
        for name, value in single.items():
            assert batched[name].shape == (3,)
            assert_allclose(batched[name][i], value, rtol=1e-12)


def test_object_source_equals_mapping(rng):
    chans = _full_response(rng, ())
    run = SimpleNamespace(channels=chans, fs_hz=FS)
    assert compute_metrics(run).values == compute_metrics(chans, fs=FS).values
    assert compute_metrics(run, fs=FS).values == compute_metrics(chans, fs=FS).values


def test_absent_channels_are_omitted(rng):
    x = rng.standard_normal(2000)
    values = compute_metrics(
        {"shock_velocity_LR": x, "ride_height_LF": x, "time": x, "unrelated": "text"},
        fs=FS,
        static_loads_n={"LF": 3000.0},  # no tire force: nothing to normalize, no error
        split_hz=8.0,
    ).values
    assert list(values) == ["shock_velocity_rms_LR", "shock_velocity_rms_LR_body",
                            "shock_velocity_rms_LR_wheelhop"]
    assert compute_metrics({}, fs=FS).values == {}


def test_normalized_tire_force(rng):
    x = 400.0 * rng.standard_normal(4000)
    values = compute_metrics({"tire_force_LF": x, "tire_force_RF": x}, fs=FS,
                             static_loads_n={"LF": 3200.0}).values
    assert_allclose(values["tire_force_rms_norm_LF"], values["tire_force_rms_LF"] / 3200.0)
    assert "tire_force_rms_norm_RF" not in values


def test_split_bands_add_up_for_white_noise(rng):
    x = rng.standard_normal((2, int(300 * FS)))
    metrics = compute_metrics({"shock_velocity_RF": x, "tire_force_RR": x}, fs=FS,
                              split_hz=8.0, static_loads_n={"RR": 4000.0})
    v = metrics.values
    assert metrics.split_hz == 8.0
    for name in ("shock_velocity_rms_RF", "tire_force_rms_RR", "tire_force_rms_norm_RR"):
        body, hop = v[name + BAND_SUFFIXES[0]], v[name + BAND_SUFFIXES[1]]
        assert_allclose(body**2 + hop**2, v[name] ** 2, rtol=RTOL_SPLIT)
        # white noise: power in proportion to the bandwidths (7 Hz vs 12 Hz)
        assert_allclose(hop**2 / body**2, 12.0 / 7.0, rtol=0.1)


def test_imperial_conversion(rng):
    x = 500.0 * rng.standard_normal(4000)
    metrics = compute_metrics({"tire_force_LF": x, "shock_velocity_LF": x / 5000.0},
                              fs=FS, static_loads_n={"LF": 3000.0})
    si, imp = metrics.to_units("SI"), metrics.to_units("imperial")
    assert si == metrics.values
    assert_allclose(imp["tire_force_rms_LF"], si["tire_force_rms_LF"] / 4.4482216152605)
    assert_allclose(imp["shock_velocity_rms_LF"], si["shock_velocity_rms_LF"] / 0.0254)
    assert imp["tire_force_rms_norm_LF"] == si["tire_force_rms_norm_LF"]
    series = metrics.as_series(units="imperial")
    assert list(series.index) == list(imp)
    assert_allclose(series["tire_force_rms_LF"], imp["tire_force_rms_LF"])


def test_as_frame_batched(rng):
    metrics = compute_metrics({"tire_force_LF": rng.standard_normal((4, 2000))}, fs=FS)
    frame = metrics.as_frame()
    assert frame.shape == (4, 1)
    assert_allclose(frame["tire_force_rms_LF"], metrics.values["tire_force_rms_LF"])
    with pytest.raises(ValueError, match="batched"):
        metrics.as_series()


_X = np.zeros(1000)


@pytest.mark.parametrize(
    "source, kwargs, error, match",
    [
        ({"tire_force_LF": _X}, {"fs": 0.0}, ValueError, "positive sample rate"),
        ({"tire_force_LF": _X}, {"fs": -100.0}, ValueError, "positive sample rate"),
        ({"tire_force_LF": _X}, {"fs": "fast"}, TypeError, "fs must be a number"),
        ({"tire_force_LF": _X}, {}, ValueError, "pass fs="),
        ({"tire_force_LF": _X}, {"fs": FS, "band_hz": (0.0, 20.0)}, ValueError,
         "0 < low < high < fs/2"),
        ({"tire_force_LF": _X}, {"fs": FS, "band_hz": (1.0, 100.0)}, ValueError,
         "fs/2 = 100"),
        ({"tire_force_LF": _X}, {"fs": FS, "band_hz": (20.0, 1.0)}, ValueError, "low < high"),
        ({"tire_force_LF": _X}, {"fs": FS, "band_hz": 5.0}, ValueError, "pair"),
        ({"tire_force_LF": _X}, {"fs": FS, "order": 0}, ValueError, "positive integer"),
        ({"tire_force_LF": _X}, {"fs": FS, "split_hz": 25.0}, ValueError, "inside band_hz"),
        ({"tire_force_LF": _X}, {"fs": FS, "static_loads_n": {"LF": -1.0}}, ValueError,
         "positive load"),
        ({"tire_force_LF": _X}, {"fs": FS, "static_loads_n": {"FL": 1.0}}, ValueError,
         "unknown corner 'FL'"),
        ({"shock_velocity_RR": np.zeros(27)}, {"fs": FS}, ValueError,
         r"channel 'shock_velocity_RR': 27 samples.*at least 28"),
        ({"ride_height_LF": _X, "ride_height_RF": _X[:500]}, {"fs": FS}, ValueError,
         "same shape"),
        ({"tire_force_LF": 1.0}, {"fs": FS}, ValueError, "scalar"),
        ([_X], {"fs": FS}, TypeError, "Mapping"),
        (SimpleNamespace(channels={"tire_force_LF": _X}, fs_hz=FS), {"fs": 100.0},
         ValueError, "disagrees"),
    ],
)
def test_bad_inputs(source, kwargs, error, match):
    with pytest.raises(error, match=match):
        compute_metrics(source, **kwargs)


def test_bandpass_bad_inputs():
    with pytest.raises(ValueError, match="at least 28"):
        bandpass(np.zeros(10), fs=FS)
    with pytest.raises(ValueError, match="fs/2"):
        bandpass(_X, fs=30.0)
    with pytest.raises(ValueError, match="units"):
        compute_metrics({"tire_force_LF": _X}, fs=FS).to_units("metric")


def test_batched_filter_equals_scipy(rng):
    """A batch of signals (simulated setups) takes the compiled filter: the same numbers as
    scipy's sosfiltfilt, NaN rows stay NaN."""
    from scipy import signal

    from ident.sim.metrics import _FAST_MIN_SIZE, _design, _filtfilt

    x = rng.standard_normal((3, 4, 6000))
    assert x.size >= _FAST_MIN_SIZE
    x[1, 3, 100] = np.nan
    sos, padlen = _design((1.0, 20.0), 4, 100.0)
    got = _filtfilt(x, sos, padlen, -1, "x")
    ref = signal.sosfiltfilt(sos, x, axis=-1)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.nanmax(np.abs(ref)))
    assert np.isnan(got[1, 3]).all() and np.isfinite(got[0]).all()


#: The compiled filter runs scipy's recurrence (transposed direct form II) operation for
#: operation; 1e-12 leaves room only for a scipy build that fuses multiply-adds.
RTOL_FILTER = 1e-12


def test_lane_blocks_equal_the_one_row_recurrence(rng):
    """Rows filtered side by side in lane blocks (a short last block padded) give each
    row exactly the one-row recurrence's result, and scipy's to round-off."""
    from scipy import signal

    from ident.sim.metric_kernels import LANES as _LANES
    from ident.sim.metric_kernels import _sosfilt_inplace
    from ident.sim.metric_kernels import sosfiltfilt_rows as _sosfiltfilt_rows
    from ident.sim.metrics import _design

    x = rng.standard_normal((2 * _LANES + 3, 1500)) * 50.0
    sos, padlen = _design((1.0, 20.0), 4, 100.0)
    zi = np.ascontiguousarray(signal.sosfilt_zi(sos))
    got = np.empty_like(x)
    _sosfiltfilt_rows(x, sos, zi, padlen, got)
    for i in range(x.shape[0]):  # plain reference: one row, forward then reversed
        ext = np.concatenate([2 * x[i, 0] - x[i, padlen:0:-1], x[i],
                              2 * x[i, -1] - x[i, -2:-padlen - 2:-1]])
        _sosfilt_inplace(sos, zi, ext[0], ext, ext.size)
        rev = ext[::-1].copy()
        _sosfilt_inplace(sos, zi, rev[0], rev, rev.size)
        buf = rev[::-1][padlen:padlen + x.shape[1]]
        np.testing.assert_array_equal(got[i], buf)
    ref = signal.sosfiltfilt(sos, x, axis=-1)
    np.testing.assert_allclose(got, ref, rtol=0, atol=RTOL_FILTER * np.abs(ref).max())


@pytest.mark.parametrize("n", [1, 5, 8, 9, 127, 128, 129, 1000, 4097, 12_000, 12_001])
def test_pairwise_sum_is_numpys(rng, n):
    """The fused metric's sums are numpy's pairwise summation to the last bit (so its means
    and mean squares are numpy's), on a column of a lane buffer."""
    from ident.sim.metric_kernels import _pairwise_sum_col

    x = rng.standard_normal(n) * 1e3 + 7.0
    buf = np.zeros((n + 3, 4))
    buf[3:, 2] = x
    assert _pairwise_sum_col(buf, 3, n, 2) == np.sum(x)
    assert _pairwise_sum_col(buf, 3, n, 2) / n == np.mean(x)


@pytest.mark.parametrize("n", [1, 5, 8, 9, 127, 128, 129, 1000, 4097, 12_000, 12_001])
def test_pairwise_sum_of_all_lanes_is_numpys(rng, n):
    """The lane-wise pairwise sum (every lane at once, row by row, on an explicit stack)
    gives each lane numpy's sum and sum of squares to the last bit."""
    from ident.sim.metric_kernels import LANES as _LANES
    from ident.sim.metric_kernels import PW_LEVELS as _PW_LEVELS
    from ident.sim.metric_kernels import _pairwise_sum_lanes

    buf = rng.standard_normal((n + 3, _LANES)) * 1e3 + 7.0
    out = np.empty(_LANES)
    stack = np.empty((_PW_LEVELS, 10, _LANES))
    _pairwise_sum_lanes(buf, 3, n, False, out, stack)
    cols = [np.ascontiguousarray(buf[3:, j]) for j in range(_LANES)]  # numpy's 1-D sums
    np.testing.assert_array_equal(out, [np.sum(x) for x in cols])
    _pairwise_sum_lanes(buf, 3, n, True, out, stack)
    np.testing.assert_array_equal(out, [np.sum(x * x) for x in cols])


@pytest.mark.slow
@pytest.mark.heavy
def test_metric_kernels_load_from_numba_cache(tmp_path):
    """The compiled metric kernels work when numba loads them from its cache in a new
    process, not only when compiled in it (numba's cache could not reload a self-recursive
    function: the process crashed)."""
    import os
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from ident.sim.metrics import compute_metrics\n"
        "rng = np.random.default_rng(3)\n"
        "y = rng.standard_normal((20, 2, 3000))\n"
        "m = compute_metrics({'tire_force_LF': y[:, 0], 'ride_height_LF': y[:, 0],\n"
        "                     'ride_height_RF': y[:, 1]}, fs=100.0)\n"
        "print(repr(float(m.values['tire_force_rms_LF'].sum())),\n"
        "      repr(float(m.values['ride_height_rms_front'].sum())))\n"
    )
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    runs = [subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                           text=True, timeout=600) for _ in range(2)]
    for run in runs:  # the first compiles and writes the cache, the second loads it
        assert run.returncode == 0, run.stderr[-2000:]
    assert runs[0].stdout == runs[1].stdout
    assert any((tmp_path / "numba").rglob("*.nbi"))


def test_fused_metric_equals_its_steps(rng):
    """compute_metrics on a batch (the fused kernel: channel mean, mean removal, zero-phase
    band-pass and RMS in one pass per row) gives the numbers of the steps one after the
    other (_metric_signal, scipy's sosfiltfilt, numpy's RMS) to the last bit: one channel
    and two averaged, rows with any stride (the channels of a simulated batch are views),
    a block of lanes not filled, a row with a NaN (NaN for that row only)."""
    from scipy import signal

    from ident.sim.metric_kernels import LANES as _LANES
    from ident.sim.metrics import _FAST_MIN_SIZE, _design, _metric_signal

    fs = 100.0
    n_rows, n = 2 * _LANES + 5, 3000
    y = rng.standard_normal((n_rows, 3, n)) * 40.0 + 5.0  # (setup, channel, sample) as a batch
    y[7, 1, 200] = np.nan
    ch = {"tire_force_LF": y[:, 0, :], "ride_height_LF": y[:, 1, :],
          "ride_height_RF": y[:, 2, :]}
    assert y[:, 0, :].size >= _FAST_MIN_SIZE and not y[:, 0, :].flags.c_contiguous
    got = compute_metrics(ch, fs=fs, split_hz=8.0)
    for suffix, band in (("", (1.0, 20.0)), ("_body", (1.0, 8.0)), ("_wheelhop", (8.0, 20.0))):
        sos, _ = _design(band, 4, fs)
        for name, names in (("tire_force_rms_LF", ("tire_force_LF",)),
                            ("ride_height_rms_front", ("ride_height_LF", "ride_height_RF"))):
            x = _metric_signal([ch[c] for c in names])
            ref = np.sqrt(np.mean(signal.sosfiltfilt(sos, x, axis=-1) ** 2, axis=-1))
            np.testing.assert_array_equal(got.values[name + suffix], ref)
    assert np.isnan(got.values["ride_height_rms_front"][7])
    assert np.isfinite(np.delete(got.values["ride_height_rms_front"], 7)).all()
    assert np.isfinite(got.values["tire_force_rms_LF"]).all()


def test_derived_metric_map_places_combinations_in_free_lanes():
    from ident.sim.metric_kernels import LANES as _LANES
    from ident.sim.metric_kernels import derived_metric_map

    # 14 filtered metrics (one block): heave and roll of corners 6, 7 (travel) and 10, 11
    # (velocity); a combination across blocks (16 + 1 sources over 2 blocks) is left out
    n_base = _LANES + 2
    sources = [[6, 7], [6, 7], [10, 11], [3, _LANES + 1]]
    weights = [[0.5, 0.5], [0.4, -0.4], [0.5, 0.5], [1.0, 1.0]]
    dmap, dw, kept = derived_metric_map(sources, weights, n_base)
    assert kept == [0, 1, 2]
    assert dmap.shape == (3, 7) and dw.shape == (3, 4)
    assert np.all(dmap[:, 0] == 0) and np.all(dmap[:, 1] == 0)
    lanes = dmap[:, 2].tolist()
    # distinct lanes, none a source of the block's combinations
    assert len(set(lanes)) == 3 and not set(lanes) & {6, 7, 10, 11}
    assert dmap[1, 3:].tolist() == [6, 7, -1, -1]
    assert dw[1].tolist() == [0.4, -0.4, 0.0, 0.0]
    # more combinations than free lanes: groups of lanes
    many = [[0, 1]] * (_LANES - 2 + 3)
    dmap, dw, kept = derived_metric_map(many, [[1.0, 1.0]] * len(many), 2)
    assert len(kept) == len(many)
    assert dmap[:, 1].tolist() == [0] * (_LANES - 2) + [1] * 3
    for g in (0, 1):
        lanes = dmap[dmap[:, 1] == g, 2]
        assert len(set(lanes.tolist())) == lanes.size and not set(lanes.tolist()) & {0, 1}
