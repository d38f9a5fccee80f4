"""Tests of ident.data.timebase: the one time base of drives, track logs and drive targets;
uniform, jittered (resampled) and gapped time stamps."""

from __future__ import annotations

import pickle
from dataclasses import FrozenInstanceError

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from ident.data.drive import Drive, fade_window, make_noise_drive
from ident.data.timebase import (JITTER_RTOL, SPLINE_DEGREE, TimeRecord, nominal_rate,
                                 rate_ratio, uniform_time_base)
from ident.data.tracklog import TrackLog
from ident.errors import SessionError
from planner.trackdrive.target import DriveTarget

#: A logger at 77 Hz (the issue's CAN logger: steps of 12.7-13.4 ms).
FS_HZ = 77.0
#: Each step jittered by up to this share of the step (+-3 %, inside the 5 % tolerance).
STEP_JITTER = 0.03
#: Resampling error allowed, relative to the signal's RMS, for content up to a quarter of
#: the rate: the degree-7 spline gives 1.8e-4 there (measured; a cubic 5e-3, linear 9e-2).
RESAMPLE_RTOL = 3e-4
#: The same, for content up to a third of the rate (closer to Nyquist: 2.0e-3 measured; a
#: cubic 2.3e-2).
RESAMPLE_RTOL_NEAR_NYQUIST = 1e-2


def _stamps(rng, n, fs_hz=FS_HZ, jitter=STEP_JITTER):
    """Time stamps whose steps each jitter uniformly by +-`jitter` of the step (a random
    walk around the grid, as a logger stamping arrivals writes)."""
    steps = (1.0 + rng.uniform(-jitter, jitter, n - 1)) / fs_hz
    return np.concatenate([[0.0], np.cumsum(steps)])


def _signal(rng, f_max_hz, n_tones=40):
    f = rng.uniform(0.5, f_max_hz, n_tones)
    phase = rng.uniform(0.0, 2 * np.pi, n_tones)
    amp = rng.uniform(0.1, 1.0, n_tones)
    return lambda t: (amp[:, None] * np.sin(2 * np.pi * f[:, None] * t[None, :]
                                            + phase[:, None])).sum(axis=0)


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.mark.parametrize("f_max_share, rtol", [(0.25, RESAMPLE_RTOL),
                                               (1 / 3, RESAMPLE_RTOL_NEAR_NYQUIST)])
def test_jittered_signal_is_recovered_on_the_uniform_base(f_max_share, rtol):
    """Truth round trip: a band-limited signal sampled at jittered instants, resampled, equals
    the signal at the uniform times."""
    rng = np.random.default_rng(36)
    t = _stamps(rng, 60 * int(FS_HZ))
    truth = _signal(rng, f_max_share * FS_HZ)
    base = uniform_time_base(t, where="log.csv")
    assert base.resampled and 0.02 < base.jitter <= 1.1 * STEP_JITTER  # against the median
    y = base.resample(truth(t))
    assert _rms(y - truth(base.time_s)) < rtol * _rms(truth(base.time_s))
    # several signals at once, the same
    both = base.resample(np.column_stack([truth(t), -truth(t)]))
    assert_array_equal(both[:, 0], y)


def test_exactly_uniform_time_is_used_as_written():
    """A rig controller's time (steps equal within 1e-6) is not resampled: bit for bit."""
    t = np.arange(1000) / 200.0
    base = uniform_time_base(t, where="run.csv")
    assert not base.resampled and base.fs_hz == pytest.approx(200.0, rel=1e-12)
    assert base.time_s is t or np.shares_memory(base.time_s, t) or \
        np.array_equal(base.time_s, t)
    x = np.sin(t)
    assert_array_equal(base.resample(x), x)


def test_jittered_rate_snaps_to_the_nominal_rate():
    """Runs logged at one rate (stamps off a fixed clock's grid by up to 2 % of a step) share
    it exactly after resampling (a session requires it)."""
    rng = np.random.default_rng(1)
    grid = np.arange(200) / 100.0
    rates = {uniform_time_base(grid + rng.uniform(-0.02, 0.02, 200) / 100.0, where="r").fs_hz
             for _ in range(5)}
    assert rates == {100.0}
    assert nominal_rate(76.923069) == pytest.approx(1e6 / 13000, rel=1e-12)
    assert nominal_rate(55.51) == 55.51


@pytest.mark.parametrize("edit, match", [
    (lambda t: np.delete(t, 500), r"a gap of 2 sample intervals .* at t=.* \(data row 501\)"),
    (lambda t: np.concatenate([t[:300], t[300:] + 0.5 / FS_HZ]),
     r"a gap of 1\.5 sample intervals"),
    (lambda t: np.concatenate([t[:700], t[700] + 0.5 * (t[700:] - t[700])]),
     r"a step of 0\.5\d* sample intervals"),
    (lambda t: np.concatenate([t[:10], t[9:]]), r"not strictly increasing at data row 11"),
])
def test_gaps_and_rate_changes_are_refused_at_their_time(edit, match):
    """A step off the median by more than the jitter tolerance is not jitter: refused with
    its time, its row and the fix (nothing is invented across a gap)."""
    t = edit(_stamps(np.random.default_rng(2), 1000, jitter=0.01))
    with pytest.raises(SessionError, match=match) as info:
        uniform_time_base(t, where="log.csv", error=SessionError)
    text = str(info.value)
    assert text.startswith("log.csv: ") and ("cut the record" in text or "sort" in text)


def test_tolerance_is_an_option():
    """`jitter_rtol=0` accepts only an exact base; the default accepts 5 %."""
    t = _stamps(np.random.default_rng(3), 300, jitter=0.5 * JITTER_RTOL)
    assert uniform_time_base(t, where="x").resampled
    with pytest.raises(ValueError, match="not uniformly sampled"):
        uniform_time_base(t, where="x", jitter_rtol=0.0)
    assert SPLINE_DEGREE >= 5  # the accuracy above rests on a high degree



def test_the_three_records_share_the_time_base():
    assert all(issubclass(c, TimeRecord) for c in (Drive, TrackLog, DriveTarget))
    for c in (Drive, TrackLog, DriveTarget):
        assert "n_samples" not in vars(c) and "time_s" not in vars(c)


def test_a_drive_keeps_its_time_base_frozen_and_pickled():
    d = make_noise_drive(duration_s=2.0, fs_hz=100.0, seed=1, peak={"wheelloader_LF": 1e-3})
    assert d.n_samples == 200 and d.duration_s == 2.0
    np.testing.assert_array_equal(d.time_s, np.arange(200) / 100.0)
    e = pickle.loads(pickle.dumps(d))
    assert e.n_samples == d.n_samples
    np.testing.assert_array_equal(e.as_array(), d.as_array())
    with pytest.raises(FrozenInstanceError):
        d.fs_hz = 50.0


def test_fade_window_is_the_track_and_target_fade():
    from ident.sim.virtual_track import _taper
    from planner.trackdrive.target import segment_taper

    for n, fs, t in [(1000, 100.0, 1.0), (513, 200.0, 0.37), (40, 10.0, 0.0)]:
        w = fade_window(n, fs, t)
        assert w.tobytes() == _taper(n, fs, t).tobytes() == segment_taper(n, fs, t).tobytes()
    w = fade_window(1000, 100.0, 1.0)
    assert 0 < w[0] < 1e-3 and w[100:900].min() == 1.0 and np.allclose(w, w[::-1])
    with pytest.raises(ValueError, match="do not fit"):
        fade_window(10, 10.0, 1.0)


# ---------------------------------------------------------------- a chosen rate (--resample)

#: Resampling to a chosen rate, content up to a quarter of the lower rate, relative to the
#: signal's RMS: the Kaiser FIR is flat to 1e-5 there and the spline close; nearly all of
#: the error is at the record's ends, extended by odd reflection (value and slope go on,
#: curvature does not): 0.9e-4 to 4.0e-4 measured over the cases below.
RATE_CHANGE_RTOL = 1e-3
#: Content above the new Nyquist frequency left after going down (the FIR: below -80 dB
#: above 1.2 of the lower Nyquist frequency).
ALIAS_LEFT_SHARE = 1e-3


@pytest.mark.parametrize("fs_hz, jitter, to_hz, ratio", [
    (100.0, 0.0, 64.0, (16, 25)),
    (200.0, 0.0, 500.0, (5, 2)),
    (FS_HZ, STEP_JITTER, 100.0, None),  # the stamps' rate is an estimate: any ratio
    (100.0, 0.0, 100.0 / np.sqrt(2), None),  # no simple ratio: low-pass and spline
    (100.0, 0.0, 100.0 * np.sqrt(2), None)])
def test_a_chosen_rate_recovers_the_signal(fs_hz, jitter, to_hz, ratio):
    """Truth round trip: a band-limited signal, uniform or jittered, read onto a uniform base
    at a chosen rate (up or down) equals the signal at those times, ends included."""
    rng = np.random.default_rng(362)
    t = _stamps(rng, 40 * int(fs_hz), fs_hz=fs_hz, jitter=jitter)
    truth = _signal(rng, 0.25 * min(fs_hz, to_hz))
    base = uniform_time_base(t, where="log.csv", resample_hz=to_hz)
    assert base.resampled and base.fs_hz == to_hz
    assert ratio is None or base.ratio == ratio
    # a random walk of stamps: its least-squares rate is within 1e-3 of the nominal one
    assert base.native.fs_hz == pytest.approx(fs_hz, rel=1e-6 if jitter == 0 else 1e-3)
    assert base.native.resampled == (jitter > 0)
    assert_array_equal(base.time_s, t[0] + np.arange(base.time_s.size) / to_hz)
    # inside the record (its own uniform base), short of its end by less than a step of each
    assert base.time_s[-1] <= base.native.time_s[-1] <= t[-1]
    assert t[-1] < base.time_s[-1] + 1.0 / to_hz + 1.1 / fs_hz
    y = base.resample(truth(t))
    assert y.shape == base.time_s.shape
    assert _rms(y - truth(base.time_s)) < RATE_CHANGE_RTOL * _rms(truth(base.time_s))
    line = base.describe("log.csv")
    assert f"resampled from {base.native.fs_hz:.6g} Hz" in line
    assert f"uniform {to_hz:.6g} Hz" in line
    assert ("jittering" in line) == (jitter > 0)


def test_going_down_removes_the_content_above_the_new_nyquist_frequency():
    """100 Hz -> 50 Hz: a 5 Hz tone is kept, a 40 Hz one (above 25 Hz) is filtered out, not
    folded down to 10 Hz."""
    t = np.arange(4000) / 100.0
    low, high = np.sin(2 * np.pi * 5 * t), np.sin(2 * np.pi * 40 * t)
    base = uniform_time_base(t, where="run.csv", resample_hz=50.0)
    y = base.resample(np.column_stack([low, high]))
    mid = slice(100, -100)
    assert _rms(y[mid, 0] - np.sin(2 * np.pi * 5 * base.time_s[mid])) < RATE_CHANGE_RTOL
    assert _rms(y[mid, 1]) < ALIAS_LEFT_SHARE
    assert "anti-aliased" in base.describe("run.csv")


def test_the_own_rate_changes_nothing():
    t = np.arange(500) / 100.0
    base = uniform_time_base(t, where="run.csv", resample_hz=100.0)
    assert not base.resampled and base.native is None
    x = np.cos(t)
    assert_array_equal(base.resample(x), x)


@pytest.mark.parametrize("to_hz, match", [
    (0.0, "must be a positive number of Hz, got 0.0"),
    ("fast", "must be a positive number of Hz, got 'fast'")])
def test_a_rate_that_is_not_a_rate_is_refused(to_hz, match):
    with pytest.raises(SessionError, match=match):
        uniform_time_base(np.arange(50) / 100.0, where="run.csv", error=SessionError,
                          resample_hz=to_hz)
    assert rate_ratio(100.0, 100.0 * (1 + 1e-9), where="x") == (1, 1)
