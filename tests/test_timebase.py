"""ident.data.timebase: the one time base of drives, track logs and drive targets."""

import pickle
from dataclasses import FrozenInstanceError

import numpy as np
import pytest

from ident.data.drive import Drive, fade_window, make_noise_drive
from ident.data.timebase import TimeRecord
from ident.data.tracklog import TrackLog
from planner.trackdrive.target import DriveTarget


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
