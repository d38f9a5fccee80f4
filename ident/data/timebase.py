"""The time base of a sampled record: samples, length and times from ``fs_hz``.

:class:`TimeRecord` is the base of the records that hold equal-length channels sampled
uniformly from t = 0 (:class:`ident.data.drive.Drive`, :class:`ident.data.tracklog.TrackLog`,
:class:`planner.trackdrive.target.DriveTarget`): it reads ``n_samples``, ``duration_s`` and
``time_s`` from their ``fs_hz`` and ``channels``, so the three are written once.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TimeRecord"]


class TimeRecord:
    """Mixin of a record with ``fs_hz`` [Hz] and ``channels`` (a dict of equal-length 1-D
    arrays, at least one): its sample count, length and sample times.

    Subclasses are (frozen) dataclasses that define the two attributes; the mixin adds no
    state, so they stay frozen and pickle as before.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Rec(TimeRecord):
    ...     fs_hz: float
    ...     channels: dict
    >>> r = Rec(4.0, {"x": np.zeros(6)})
    >>> r.n_samples, r.duration_s, r.time_s.tolist()
    (6, 1.5, [0.0, 0.25, 0.5, 0.75, 1.0, 1.25])
    """

    __slots__ = ()

    @property
    def n_samples(self):
        """int: Number of samples."""
        return int(next(iter(self.channels.values())).size)

    @property
    def duration_s(self):
        """float: Record length ``n_samples / fs_hz`` [s]."""
        return self.n_samples / self.fs_hz

    @property
    def time_s(self):
        """ndarray, shape (n_samples,): Sample times ``k / fs_hz`` [s] from 0 at the first
        sample."""
        return np.arange(self.n_samples) / self.fs_hz
