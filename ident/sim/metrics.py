"""RMS metrics of rig runs and simulated responses (the rig-session spec's Metrics).

A metric is the RMS of a channel after a zero-phase band-pass filter, a
Butterworth of order 4 from 1 to 20 Hz by default::

    sosfiltfilt(butter(4, [1, 20], "bandpass", fs=fs, output="sos"), x)

applied to the dynamic part of the channel (its mean removed first). The
front (rear) ride height is the mean of the LF and RF (LR and RR) ride
heights. :func:`bandpass` is that reference filter; :func:`compute_metrics`
applies it to every metric channel present in a run, a drive or a simulated
response.

The RMS is taken over the whole record. The reference filter pads only 27
samples at each end (``sosfiltfilt``'s default), short against the 1 Hz
edge, so the first and last second or so carry a start-up transient: a
negligible weight for an in-band signal (5 Hz sine over 100 s: 0.02 %), but
it is what limits the rejection of an out-of-band one (a 40 Hz sine over
200 s still gives 2 % of its RMS). Use records of minutes, as rigs do.

Examples
--------
>>> import numpy as np
>>> fs = 200.0
>>> t = np.arange(20_000) / fs
>>> m = compute_metrics({"tire_force_LF": 100.0 * np.sin(2 * np.pi * 5.0 * t)}, fs=fs)
>>> round(m.values["tire_force_rms_LF"], 1)  # 100 / sqrt(2), edges aside
70.7
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import signal

from ident.data.channels import CORNERS, quantity_of
from ident.data.units import check_units, from_si

__all__ = [
    "METRIC_NAMES",
    "METRIC_QUANTITY",
    "BAND_SUFFIXES",
    "Metrics",
    "bandpass",
    "compute_metrics",
]

logger = logging.getLogger(__name__)

#: Channels averaged into each metric's signal, in the spec's metric order.
_METRIC_CHANNELS = {}
_METRIC_CHANNELS.update({f"tire_force_rms_{c}": (f"tire_force_{c}",) for c in CORNERS})
_METRIC_CHANNELS["ride_height_rms_front"] = ("ride_height_LF", "ride_height_RF")
_METRIC_CHANNELS["ride_height_rms_rear"] = ("ride_height_LR", "ride_height_RR")
_METRIC_CHANNELS.update({f"shock_travel_rms_{c}": (f"shock_travel_{c}",) for c in CORNERS})
_METRIC_CHANNELS.update({f"shock_velocity_rms_{c}": (f"shock_velocity_{c}",)
                         for c in CORNERS})

#: The spec's metric names, in the spec's order (tire force x4, ride height
#: front/rear, shock travel x4, shock velocity x4).
METRIC_NAMES = tuple(_METRIC_CHANNELS)

_NORM_NAMES = tuple(f"tire_force_rms_norm_{c}" for c in CORNERS)

#: Name suffixes of the body band and wheel-hop band metrics (``split_hz``).
BAND_SUFFIXES = ("_body", "_wheelhop")

#: Physical quantity of every metric :func:`compute_metrics` can return (key of
#: ``ident.data.units.TO_SI``), including the normalized tire-force metrics and the
#: ``_body`` / ``_wheelhop`` band variants.
METRIC_QUANTITY = {}
for _suffix in ("",) + BAND_SUFFIXES:
    METRIC_QUANTITY.update({f"{name}{_suffix}": quantity_of(chans[0])
                            for name, chans in _METRIC_CHANNELS.items()})
    METRIC_QUANTITY.update({f"{name}{_suffix}": "dimensionless" for name in _NORM_NAMES})
del _suffix


@dataclass(frozen=True)
class Metrics:
    """Band-passed RMS metrics and the settings that produced them.

    Attributes
    ----------
    values : dict of str to float or ndarray
        Metric name -> RMS value in SI units (see :data:`METRIC_QUANTITY`), in
        the order: the spec's metrics (:data:`METRIC_NAMES`, those present),
        the normalized tire forces ``tire_force_rms_norm_XX``, then the same
        with the suffix ``_body`` and then ``_wheelhop`` when `split_hz` is
        set. A float for signals of shape ``(n_samples,)``; an array of the
        leading shape for batched signals of shape ``(..., n_samples)``.
    band_hz : tuple of float
        The band-pass edges (low, high) [Hz].
    order : int
        The Butterworth prototype order (the band-pass has twice that order,
        applied forward and backward).
    fs_hz : float
        The sample rate of the signals [Hz].
    split_hz : float or None
        The frequency [Hz] separating the body band (``band_hz[0]`` ..
        `split_hz`) from the wheel-hop band (`split_hz` .. ``band_hz[1]``).
    static_loads_n : dict of str to float or None
        Corner -> static corner load [N] used for ``tire_force_rms_norm_XX``.
    """

    values: dict
    band_hz: tuple
    order: int
    fs_hz: float
    split_hz: float | None = None
    static_loads_n: dict | None = None

    def to_units(self, units):
        """Return the metric values converted to a unit system.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Target unit system (force in lbf, displacement in in, velocity in
            in/s; normalized metrics are dimensionless).

        Returns
        -------
        dict of str to float or ndarray
            Metric name -> value in `units`, in the order of :attr:`values`.
        """
        units = check_units(units, where="Metrics.to_units")
        return {name: from_si(value, METRIC_QUANTITY[name], units)
                for name, value in self.values.items()}

    def as_series(self, *, units="SI"):
        """Return the metrics of one signal set as a :class:`pandas.Series`.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Unit system of the values.

        Returns
        -------
        pandas.Series
            Indexed by metric name.

        Raises
        ------
        ValueError
            If the metrics are batched (use :meth:`as_frame`).
        """
        import pandas as pd

        values = self.to_units(units)
        if any(np.ndim(v) for v in values.values()):
            raise ValueError(
                "Metrics.as_series: the metrics are batched (array values); "
                "use Metrics.as_frame() for one row per signal set"
            )
        series = pd.Series(values, dtype=float, name="metric_value")
        series.index.name = "metric"
        return series

    def as_frame(self, *, units="SI"):
        """Return the metrics as a :class:`pandas.DataFrame`, one row per signal set.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Unit system of the values.

        Returns
        -------
        pandas.DataFrame
            Columns are metric names; one row for unbatched metrics, ``n``
            rows for metrics of leading shape ``(n,)``.

        Raises
        ------
        ValueError
            If the metrics have more than one leading (batch) axis.
        """
        import pandas as pd

        values = self.to_units(units)
        if any(np.ndim(v) > 1 for v in values.values()):
            raise ValueError(
                "Metrics.as_frame: the metrics have more than one batch axis; "
                "reshape the signals to (n_sets, n_samples) first"
            )
        return pd.DataFrame({k: np.atleast_1d(v) for k, v in values.items()})


def _check_fs(fs):
    try:
        fs = float(fs)
    except (TypeError, ValueError):
        raise TypeError(f"fs must be a number (sample rate in Hz), got {fs!r}") from None
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sample rate in Hz, got {fs}")
    return fs


def _check_band(band_hz, fs):
    try:
        low, high = (float(f) for f in band_hz)
    except (TypeError, ValueError):
        raise ValueError(
            f"band_hz must be a pair (low, high) in Hz, got {band_hz!r}"
        ) from None
    if not (0.0 < low < high < fs / 2):
        raise ValueError(
            f"band_hz={band_hz!r} must satisfy 0 < low < high < fs/2 = {fs / 2:g} Hz; "
            "narrow the band or use a higher sample rate"
        )
    return (low, high)


def _check_order(order):
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)):
        raise TypeError(f"order must be an integer, got {order!r}")
    if order < 1:
        raise ValueError(f"order must be a positive integer, got {order}")
    return int(order)


def _design(band, order, fs):
    """The reference band-pass as second-order sections, and sosfiltfilt's padlen."""
    sos = signal.butter(order, band, "bandpass", fs=fs, output="sos")
    # sosfiltfilt's default padding, computed as scipy does (its input must be
    # longer than this).
    ntaps = 2 * len(sos) + 1 - min((sos[:, 2] == 0).sum(), (sos[:, 5] == 0).sum())
    return sos, 3 * int(ntaps)


@functools.lru_cache(maxsize=32)
def _band_filter(band, order, fs):
    """:func:`_design` with ``sosfilt_zi``, as contiguous float arrays, once per (band,
    order, rate): a batch prediction computes metrics chunk after chunk with the same
    filter (about 5 ms per design). Shared arrays: read them only."""
    sos, padlen = _design(band, order, fs)
    sos = np.ascontiguousarray(sos, dtype=float)
    return sos, padlen, np.ascontiguousarray(signal.sosfilt_zi(sos))


def _filtfilt(x, sos, padlen, axis, label):
    n = x.shape[axis]
    if n <= padlen:
        raise ValueError(
            f"{label}: {n} samples, but the zero-phase band-pass needs at least "
            f"{padlen + 1} (sosfiltfilt's padding); use a longer record"
        )
    x = np.asarray(x, dtype=float)
    if x.ndim < 2 or x.size < _FAST_MIN_SIZE or axis not in (-1, x.ndim - 1):
        return signal.sosfiltfilt(sos, x, axis=axis)
    # batched signals (a batch of simulated setups): the same filter, compiled and parallel
    rows = np.ascontiguousarray(x.reshape(-1, n))
    out = np.empty_like(rows)
    _sosfiltfilt_rows(rows, np.ascontiguousarray(sos, dtype=float),
                      np.ascontiguousarray(signal.sosfilt_zi(sos)), int(padlen), out)
    return out.reshape(x.shape)


#: Smallest batch (samples in all) filtered by the compiled path; below it, scipy directly.
_FAST_MIN_SIZE = 20_000


def _sosfilt_inplace(sos, zi0, x0, buf, n):
    """scipy's ``sosfilt(sos, buf[:n], zi=zi0 * x0)`` in place (transposed direct form II).

    The one-row reference of :func:`_sosfilt_lanes` (kept for tests and tooling).
    """
    ns = sos.shape[0]
    z = np.empty((ns, 2))
    for s in range(ns):
        z[s, 0] = zi0[s, 0] * x0
        z[s, 1] = zi0[s, 1] * x0
    for k in range(n):
        xc = buf[k]
        for s in range(ns):
            yc = sos[s, 0] * xc + z[s, 0]
            z[s, 0] = sos[s, 1] * xc - sos[s, 4] * yc + z[s, 1]
            z[s, 1] = sos[s, 2] * xc - sos[s, 5] * yc
            xc = yc
        buf[k] = xc


#: Rows filtered together (the lanes of one block). A biquad is a serial recurrence of
#: a few cycles' latency per sample; rows side by side in a (time, lane) buffer make the
#: lane loop a vector loop over independent recurrences (AVX2: 4 rows per instruction).
#: 16 lanes measured best per core on 64 rows of 12,000 samples (8: 10 % slower, 32:
#: fewer blocks than a batch of 64 rows needs to share among the cores).
_LANES = 16


def _sosfilt_lanes(sos, buf, z0, z1, start, stop, step, offset, lo, hi):
    """``sosfilt`` of every column of `buf` in place, over the rows ``range(start, stop,
    step)`` (``step = -1``: the backward pass, without a reversed copy).

    Parameters
    ----------
    sos : ndarray of float, shape (n_sections, 6)
    buf : ndarray of float, shape (n, n_lanes)
        One signal per column.
    z0, z1 : ndarray of float, shape (n_sections, n_lanes)
        The transposed direct form II states, holding the initial state on entry
        (``zi * x0`` as ``sosfilt(..., zi=zi * x0)``); left with the final state.
    offset : ndarray of float, shape (n_lanes,)
        Subtracted from the rows ``lo <= k < hi`` as they are read (``row - offset``, a
        metric's mean removal in the pass that filters it); ``lo = hi``: none.

    Notes
    -----
    Each column gets exactly :func:`_sosfilt_inplace`'s operations in the same order, so
    the same rounding. The lane loop indexes 1-D row views: numba's loop vectorizer then
    turns it into vector instructions (it does not for 2-D indexing of the same loop).
    """
    ns = sos.shape[0]
    n_lanes = buf.shape[1]
    for k in range(start, stop, step):
        row = buf[k]
        if lo <= k < hi:
            for j in range(n_lanes):
                row[j] = row[j] - offset[j]
        for s in range(ns):
            b0 = sos[s, 0]
            b1 = sos[s, 1]
            b2 = sos[s, 2]
            a1 = sos[s, 4]
            a2 = sos[s, 5]
            zs0 = z0[s]
            zs1 = z1[s]
            for j in range(n_lanes):  # independent recurrences: no loop-carried chain
                xc = row[j]
                yc = b0 * xc + zs0[j]
                zs0[j] = b1 * xc - a1 * yc + zs1[j]
                zs1[j] = b2 * xc - a2 * yc
                row[j] = yc


def _filtfilt_lanes(sos, zi, buf, z0, z1, offset, lo, hi):
    """``sosfiltfilt`` of every column of the padded `buf` (n_padded, n_lanes) in place:
    forward, then backward over the same buffer, each pass from the steady state of its
    first input sample (sosfiltfilt's ``zi * x0``). `z0`, `z1` (n_sections, n_lanes) are
    scratch. `offset` is subtracted from the rows ``lo <= k < hi`` before the forward pass
    filters them (see :func:`_sosfilt_lanes`); row 0 must be outside them."""
    ne = buf.shape[0]
    for first, stop, step in ((0, ne, 1), (ne - 1, -1, -1)):
        for s in range(sos.shape[0]):
            for j in range(buf.shape[1]):
                z0[s, j] = zi[s, 0] * buf[first, j]
                z1[s, j] = zi[s, 1] * buf[first, j]
        if step == 1:
            _sosfilt_lanes(sos, buf, z0, z1, first, stop, step, offset, lo, hi)
        else:
            _sosfilt_lanes(sos, buf, z0, z1, first, stop, step, offset, 0, 0)


def _sosfiltfilt_rows_py(x, sos, zi, padlen, out):
    """``scipy.signal.sosfiltfilt(sos, x, axis=-1)`` (odd padding of `padlen`) per row.

    Parameters
    ----------
    x : ndarray of float, shape (m, n)
        C-contiguous rows.
    sos : ndarray of float, shape (n_sections, 6)
    zi : ndarray of float, shape (n_sections, 2)
        ``scipy.signal.sosfilt_zi(sos)``.
    padlen : int
    out : ndarray of float, shape (m, n)
        Written with the filtered rows.

    Notes
    -----
    Rows are filtered in blocks of :data:`_LANES`, side by side in a (time, lane)
    buffer (a short last block is padded with zero rows, which stay zero), the blocks in
    parallel. Every row sees the operations of the one-row recurrence
    (:func:`_sosfilt_inplace`) in the same order: the same result to the last bit.
    """
    m, n = x.shape
    ne = n + 2 * padlen
    ns = sos.shape[0]
    n_blocks = (m + _LANES - 1) // _LANES
    for blk in _prange(n_blocks):
        buf = np.zeros((ne, _LANES))
        z0 = np.empty((ns, _LANES))
        z1 = np.empty((ns, _LANES))
        no_offset = np.zeros(_LANES)
        i0 = blk * _LANES
        n_rows = min(_LANES, m - i0)
        for j in range(n_rows):
            i = i0 + j
            # odd extension: 2 x[0] - x[padlen:0:-1], x, 2 x[-1] - x[-2:-padlen-2:-1]
            for k in range(padlen):
                buf[k, j] = 2 * x[i, 0] - x[i, padlen - k]
                buf[padlen + n + k, j] = 2 * x[i, n - 1] - x[i, n - 2 - k]
            for k in range(n):
                buf[padlen + k, j] = x[i, k]
        _filtfilt_lanes(sos, zi, buf, z0, z1, no_offset, 0, 0)
        for j in range(n_rows):
            for k in range(n):
                out[i0 + j, k] = buf[padlen + k, j]


#: numpy's pairwise summation: blocks of at most this many samples are summed with 8
#: partial sums (numpy's ``PW_BLOCKSIZE``).
_PW_BLOCK = 128


def _pairwise_sum_col(buf, start, n, j):
    """``numpy.sum`` of ``buf[start:start + n, j]``, to the last bit: numpy's pairwise
    summation (8 partial sums on blocks of up to 128 samples, halves above), on a column.

    The one-column reference of :func:`_pairwise_sum_lanes` (kept for tests and tooling).
    """
    if n < 8:
        res = 0.0
        for i in range(n):
            res += buf[start + i, j]
        return res
    if n <= _PW_BLOCK:
        r0 = buf[start, j]
        r1 = buf[start + 1, j]
        r2 = buf[start + 2, j]
        r3 = buf[start + 3, j]
        r4 = buf[start + 4, j]
        r5 = buf[start + 5, j]
        r6 = buf[start + 6, j]
        r7 = buf[start + 7, j]
        i = 8
        while i < n - (n % 8):
            r0 += buf[start + i, j]
            r1 += buf[start + i + 1, j]
            r2 += buf[start + i + 2, j]
            r3 += buf[start + i + 3, j]
            r4 += buf[start + i + 4, j]
            r5 += buf[start + i + 5, j]
            r6 += buf[start + i + 6, j]
            r7 += buf[start + i + 7, j]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += buf[start + i, j]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise_sum_col(buf, start, n2, j) + _pairwise_sum_col(buf, start + n2, n - n2, j)


def _add_row(acc, row, square):
    """``acc += row`` (``row * row`` when `square`), lane by lane: one step of numpy's
    pairwise sum for every lane (inlined into :func:`_pairwise_leaf_lanes`)."""
    for j in range(acc.size):
        v = row[j]
        if square:
            v = v * v
        acc[j] += v


def _pairwise_leaf_lanes(buf, start, n, square, r, out):
    """A leaf of :func:`_pairwise_sum_lanes` (``n <= 128`` samples): numpy's 8 partial sums
    per lane in the rows of `r` (8, n_lanes), then their sum and the remainder into `out`."""
    L = buf.shape[1]
    if n < 8:
        for j in range(L):
            out[j] = 0.0
        for i in range(n):
            _add_row(out, buf[start + i], square)
        return
    for q in range(8):
        row = buf[start + q]
        rq = r[q]
        for j in range(L):
            v = row[j]
            if square:
                v = v * v
            rq[j] = v
    i = 8
    while i < n - (n % 8):
        for q in range(8):
            _add_row(r[q], buf[start + i + q], square)
        i += 8
    r0 = r[0]
    r1 = r[1]
    r2 = r[2]
    r3 = r[3]
    r4 = r[4]
    r5 = r[5]
    r6 = r[6]
    r7 = r[7]
    for j in range(L):
        out[j] = ((r0[j] + r1[j]) + (r2[j] + r3[j])) + ((r4[j] + r5[j]) + (r6[j] + r7[j]))
    while i < n:
        _add_row(out, buf[start + i], square)
        i += 1


def _pairwise_sum_lanes(buf, start, n, square, out, stack):
    """``numpy.sum`` of ``buf[start:start + n, j]`` (of its squares when `square`) for every
    lane `j` at once, into ``out`` (n_lanes,): :func:`_pairwise_sum_col`'s operations per
    lane, to the last bit, reading `buf` row by row (a column walk of a (time, lane) buffer
    larger than the cache streams it once per lane).

    The recursion (halves of ``n // 2 - (n // 2) % 8`` samples down to leaves of at most
    128) runs on an explicit stack: numba's cache cannot reload a self-recursive function
    (it crashes). ``stack`` (levels, 10, n_lanes) is scratch: per level, a leaf's 8
    partial sums and the two halves' sums.
    """
    levels = stack.shape[0]
    f_start = np.empty(levels, dtype=np.int64)
    f_n = np.empty(levels, dtype=np.int64)
    f_stage = np.empty(levels, dtype=np.int64)  # 0: left half next, 1: right, 2: sum them
    d = 0
    f_start[0] = start
    f_n[0] = n
    f_stage[0] = 0
    while d >= 0:
        s0 = f_start[d]
        nn = f_n[d]
        # where this frame's sum goes: `out` at the top, else its parent's half slot
        target = out if d == 0 else stack[d - 1, 7 + f_stage[d - 1]]
        if nn <= _PW_BLOCK:
            _pairwise_leaf_lanes(buf, s0, nn, square, stack[d], target)
            d -= 1
            continue
        n2 = nn // 2
        n2 -= n2 % 8
        stage = f_stage[d]
        if stage == 2:
            left = stack[d, 8]
            right = stack[d, 9]
            for j in range(buf.shape[1]):
                target[j] = left[j] + right[j]
            d -= 1
            continue
        f_stage[d] = stage + 1
        f_start[d + 1] = s0 if stage == 0 else s0 + n2
        f_n[d + 1] = n2 if stage == 0 else nn - n2
        f_stage[d + 1] = 0
        d += 1


#: Levels of :func:`_pairwise_sum_lanes`' stack: halving from 2**63 samples to a block of
#: at most 128 takes fewer than 64.
_PW_LEVELS = 64


def _metric_rms_rows_py(a, b, two, sos, zi, padlen, out):
    """The metric of every row, fused: ``_rms(sosfiltfilt(x - x.mean()))`` with ``x = a[i]``,
    or ``(a[i] + b[i]) / 2`` when `two` (a ride height of two corners).

    Parameters
    ----------
    a, b : ndarray of float, shape (m, n)
        One channel per row (any row stride); `b` is read only when `two`.
    two : bool
    sos, zi, padlen
        As :func:`_sosfiltfilt_rows_py`.
    out : ndarray of float, shape (m,)
        Written with the RMS per row.

    Notes
    -----
    The same numbers, to the last bit, as :func:`_metric_signal`, :func:`_filtfilt` and
    :func:`_rms` one after the other (tested): the mean and the mean square are numpy's
    pairwise sums (:func:`_pairwise_sum_lanes`), the filter :func:`_sosfiltfilt_rows_py`'s
    lanes. Nothing of size ``(m, n)`` is allocated or written: a batch of 64 simulated
    setups' metrics costs one pass of the filter over the channels. Every pass over a
    block's (time, lane) buffer goes in time order over all its lanes (a buffer of 12,000
    samples is 1.5 MB, more than a core's cache: a walk down one lane at a time would
    stream it once per lane).
    """
    m, n = a.shape
    ne = n + 2 * padlen
    ns = sos.shape[0]
    n_blocks = (m + _LANES - 1) // _LANES
    for blk in _prange(n_blocks):
        buf = np.zeros((ne, _LANES))
        z0 = np.empty((ns, _LANES))
        z1 = np.empty((ns, _LANES))
        stack = np.empty((_PW_LEVELS, 10, _LANES))
        sums = np.empty(_LANES)
        i0 = blk * _LANES
        n_rows = min(_LANES, m - i0)
        for k in range(n):  # the rows side by side (lanes past n_rows stay zero)
            row = buf[padlen + k]
            if two:
                for j in range(n_rows):
                    row[j] = (a[i0 + j, k] + b[i0 + j, k]) / 2
            else:
                for j in range(n_rows):
                    row[j] = a[i0 + j, k]
        _metric_block(buf, n, padlen, sos, zi, z0, z1, stack, sums)
        for j in range(n_rows):
            out[i0 + j] = sums[j]


def _metric_block(buf, n, padlen, sos, zi, z0, z1, stack, sums):
    """The metric of every lane of a block whose signals (already the metric's channel
    or mean of two) fill ``buf[padlen:padlen + n]`` (n + 2 padlen, n_lanes): the mean
    removal, odd extension, zero-phase band-pass and RMS, left in ``sums`` (n_lanes,).
    `z0`, `z1` (n_sections, n_lanes) and `stack` (:data:`_PW_LEVELS`, 10, n_lanes) are
    scratch; `buf` is overwritten.
    """
    _pairwise_sum_lanes(buf, padlen, n, False, sums, stack)
    L = buf.shape[1]
    for j in range(L):
        sums[j] = sums[j] / n  # the means
    # odd extension, as _sosfiltfilt_rows_py, of the mean-removed signal (the forward
    # pass removes the mean from the signal's own rows as it reads them)
    first = buf[padlen]
    last = buf[padlen + n - 1]
    for k in range(padlen):
        lo = buf[k]
        lo_src = buf[2 * padlen - k]
        hi = buf[padlen + n + k]
        hi_src = buf[padlen + n - 2 - k]
        for j in range(L):
            lo[j] = 2 * (first[j] - sums[j]) - (lo_src[j] - sums[j])
            hi[j] = 2 * (last[j] - sums[j]) - (hi_src[j] - sums[j])
    _filtfilt_lanes(sos, zi, buf, z0, z1, sums, padlen, padlen + n)
    _pairwise_sum_lanes(buf, padlen, n, True, sums, stack)
    for j in range(L):
        sums[j] = np.sqrt(sums[j] / n)


def _setup_metric_rms(y, ia, sos, zi, padlen, out, buf, z0, z1, stack, sums):
    """The metrics of one simulated setup, in blocks of :data:`_LANES` metrics: metric `i`
    is the RMS metric of channel ``y[ia[i]]`` (a ride height of two corners comes as one
    channel of averaged output coefficients), into ``out[i]``.

    Parameters
    ----------
    y : ndarray of float, shape (n_channels, n)
        The setup's output channels (any row stride).
    ia : ndarray of int64, shape (n_metrics,)
    sos, zi, padlen
        As :func:`_sosfiltfilt_rows_py`.
    out : ndarray of float, shape (n_metrics,)
    buf, z0, z1, stack, sums
        Scratch of :func:`_metric_block`: shapes (n + 2 padlen, L), (n_sections, L) twice,
        (:data:`_PW_LEVELS`, 10, L) and (L,) with L = :data:`_LANES` (a caller running
        many setups keeps one set per thread).

    Notes
    -----
    Compiled into the closed loop's kernel (:mod:`ident.sim.closedloop`), which computes each
    setup's metrics as soon as its outputs are simulated, while they are in the cache.
    Each lane gets :func:`_metric_rms_rows_py`'s operations: the same numbers to the last
    bit as :func:`compute_metrics` on the channels.
    """
    n = y.shape[1]
    n_metrics = ia.size
    for i0 in range(0, n_metrics, _LANES):
        n_rows = min(_LANES, n_metrics - i0)
        for k in range(n):  # the pad rows are written by _metric_block's odd extension
            row = buf[padlen + k]
            for j in range(n_rows):
                row[j] = y[ia[i0 + j], k]
            for j in range(n_rows, _LANES):
                row[j] = 0.0
        _metric_block(buf, n, padlen, sos, zi, z0, z1, stack, sums)
        for j in range(n_rows):
            out[i0 + j] = sums[j]


try:  # numba is a dependency; keep the module importable without it for tooling
    import numba as _nb

    _prange = _nb.prange
    _sosfilt_inplace = _nb.njit(cache=True)(_sosfilt_inplace)
    _sosfilt_lanes = _nb.njit(cache=True)(_sosfilt_lanes)
    _filtfilt_lanes = _nb.njit(cache=True)(_filtfilt_lanes)
    _sosfiltfilt_rows = _nb.njit(cache=True, parallel=True)(_sosfiltfilt_rows_py)
    _pairwise_sum_col = _nb.njit(cache=True)(_pairwise_sum_col)
    _add_row = _nb.njit(cache=True, inline="always")(_add_row)
    _pairwise_leaf_lanes = _nb.njit(cache=True)(_pairwise_leaf_lanes)
    _pairwise_sum_lanes = _nb.njit(cache=True)(_pairwise_sum_lanes)
    _metric_block = _nb.njit(cache=True)(_metric_block)
    _setup_metric_rms = _nb.njit(cache=True)(_setup_metric_rms)
    _metric_rms_rows = _nb.njit(cache=True, parallel=True)(_metric_rms_rows_py)
except ImportError:  # pragma: no cover
    _prange = range
    _sosfiltfilt_rows = _sosfiltfilt_rows_py
    _metric_rms_rows = _metric_rms_rows_py


def bandpass(x, *, fs, band_hz=(1.0, 20.0), order=4, axis=-1):
    """Apply the spec's reference zero-phase Butterworth band-pass.

    Exactly ``sosfiltfilt(butter(order, band_hz, "bandpass", fs=fs,
    output="sos"), x, axis=axis)``; the mean is not removed here (the
    metrics remove it before filtering).

    Parameters
    ----------
    x : array_like, shape (..., n_samples, ...)
        Signal(s); filtered along `axis`, vectorized over the other axes.
    fs : float
        Sample rate [Hz].
    band_hz : tuple of float
        Band edges (low, high) [Hz], with ``0 < low < high < fs/2``.
    order : int
        Butterworth prototype order.
    axis : int
        The time axis of `x`.

    Returns
    -------
    ndarray
        The filtered signal, same shape as `x`.

    Raises
    ------
    ValueError
        If `fs` is not positive, the band is not inside ``(0, fs/2)``, or `x`
        is too short for the filter's padding.
    TypeError
        If `fs` is not a number or `order` not an integer.
    """
    fs = _check_fs(fs)
    band = _check_band(band_hz, fs)
    order = _check_order(order)
    x = np.asarray(x, dtype=float)
    if x.ndim == 0:
        raise ValueError("bandpass: x must have a time axis, got a scalar")
    sos, padlen = _design(band, order, fs)
    return _filtfilt(x, sos, padlen, axis, "bandpass: x")


def _source_channels(source, fs):
    """Split `source` into (channels mapping, fs [Hz])."""
    if hasattr(source, "channels") and hasattr(source, "fs_hz"):
        channels, fs_source = source.channels, _check_fs(source.fs_hz)
        if fs is not None and not math.isclose(_check_fs(fs), fs_source, rel_tol=1e-9):
            raise ValueError(
                f"compute_metrics: fs={fs} disagrees with the source's fs_hz="
                f"{fs_source}; leave fs unset for objects that carry their sample rate"
            )
        fs = fs_source
    elif isinstance(source, Mapping):
        if fs is None:
            raise ValueError(
                "compute_metrics: a Mapping of channels carries no sample rate; pass fs=..."
            )
        channels, fs = source, _check_fs(fs)
    else:
        raise TypeError(
            "compute_metrics: source must have .channels and .fs_hz (a run, a drive, "
            f"a response) or be a Mapping of channel -> array, got {type(source).__name__}"
        )
    if not isinstance(channels, Mapping):
        raise TypeError(
            f"compute_metrics: source.channels must be a Mapping, got "
            f"{type(channels).__name__}"
        )
    return channels, fs


def _check_static_loads(static_loads_n):
    if static_loads_n is None:
        return {}
    if not isinstance(static_loads_n, Mapping):
        raise TypeError(
            "static_loads_n must be a mapping corner -> static corner load [N], got "
            f"{type(static_loads_n).__name__}"
        )
    loads = {}
    for corner, load in static_loads_n.items():
        if corner not in CORNERS:
            raise ValueError(
                f"static_loads_n: unknown corner {corner!r}; use one of {list(CORNERS)}"
            )
        load = float(load)
        if not (math.isfinite(load) and load > 0):
            raise ValueError(
                f"static_loads_n[{corner!r}] = {load} must be a positive load in N"
            )
        loads[corner] = load
    return loads


def _metric_rms(xs, sos, zi, padlen, label):
    """RMS of the band-passed dynamic signal of one metric's channels `xs` (see
    :func:`_metric_channels`): batches of two-dimensional channels take the fused kernel
    (:func:`_metric_rms_rows_py`, the same numbers), the rest :func:`_metric_signal`'s steps.
    `zi` is ``sosfilt_zi(sos)`` as a contiguous float array (once per band)."""
    x = xs[0]
    n = x.shape[-1]
    if x.ndim != 2 or x.size < _FAST_MIN_SIZE or len(xs) > 2 or n <= padlen:
        return _rms(_filtfilt(_metric_signal(xs), sos, padlen, -1, label))
    out = np.empty(x.shape[0])
    _metric_rms_rows(x, xs[-1], len(xs) == 2, sos, zi, int(padlen), out)
    return out


def _metric_channels(channels, names, label):
    """The channels of one metric as float arrays of one shape (checked)."""
    xs = [np.asarray(channels[c], dtype=float) for c in names]
    for c, x in zip(names, xs):
        if x.ndim == 0:
            raise ValueError(
                f"channel {c!r} is a scalar; expected an array of shape (..., n_samples)"
            )
    if any(x.shape != xs[0].shape for x in xs):
        shapes = ", ".join(f"{c} {x.shape}" for c, x in zip(names, xs))
        raise ValueError(
            f"{label}: the channels averaged must have the same shape, got {shapes}"
        )
    return xs


def _metric_signal(xs):
    """The dynamic (mean-removed) signal of one metric: the mean of its channels `xs`."""
    x = xs[0] if len(xs) == 1 else sum(xs) / len(xs)
    return x - x.mean(axis=-1, keepdims=True)


def _rms(y):
    rms = np.sqrt(np.mean(y * y, axis=-1))
    return float(rms) if rms.ndim == 0 else rms


def compute_metrics(source, *, fs=None, band_hz=(1.0, 20.0), order=4,
                    static_loads_n=None, split_hz=None):
    """Compute the spec's band-passed RMS metrics of a run, drive or response.

    Parameters
    ----------
    source : object or Mapping
        Either an object with ``channels`` (Mapping channel -> array) and
        ``fs_hz`` (a session run, a drive, a simulated response), or a
        Mapping channel -> array (then `fs` is required). Arrays have shape
        ``(n_samples,)`` or ``(..., n_samples)`` (batched, e.g.
        ``(n_setups, n_samples)``), SI units, canonical channel names.
    fs : float, optional
        Sample rate [Hz]; required for a Mapping source, otherwise it must
        agree with ``source.fs_hz`` if given.
    band_hz : tuple of float
        The band-pass edges (low, high) [Hz], default the spec's (1, 20).
    order : int
        Butterworth prototype order, default the spec's 4.
    static_loads_n : Mapping of str to float, optional
        Corner -> static corner load [N]. Adds ``tire_force_rms_norm_XX`` =
        ``tire_force_rms_XX / static_loads_n[XX]`` (dimensionless) for each
        corner given whose tire force is present.
    split_hz : float, optional
        If given (e.g. 8.0), every metric is also computed in a body band
        (``band_hz[0]`` .. `split_hz`) and a wheel-hop band (`split_hz` ..
        ``band_hz[1]``), with the same filter order, under the name suffixed
        ``_body`` and ``_wheelhop``.

    Returns
    -------
    Metrics
        Values in SI units; a float per metric for unbatched signals, an
        array of the leading shape for batched ones.

    Raises
    ------
    ValueError
        If `fs` is not positive, a band is not inside ``(0, fs/2)``,
        `split_hz` is not inside `band_hz`, a static load is not positive,
        the channels averaged into a ride height differ in shape, or a
        channel is too short for the filter's padding (the message names the
        channel and the minimum length).
    TypeError
        If `source` is neither kind of object, or a parameter has a bad type.

    Notes
    -----
    Metrics whose channels are absent are omitted, not NaN: a front ride
    height needs both ``ride_height_LF`` and ``ride_height_RF``, a normalized
    tire force needs the tire force and a static load of its corner. Extra
    channels are ignored. Non-finite samples give NaN for that signal set
    (they are not an error, so a diverged simulation in a batch does not
    stop the others).

    Signs do not matter (RMS); the channels follow the spec's conventions.
    """
    channels, fs = _source_channels(source, fs)
    plan = _metric_plan(channels, fs, band_hz=band_hz, order=order,
                        static_loads_n=static_loads_n, split_hz=split_hz)
    signals = {name: _metric_channels(channels, _METRIC_CHANNELS[name], name)
               for name in plan.names}
    rms = {}
    for suffix, b in plan.bands.items():
        sos, padlen, zi = plan.filter(b)
        for name, xs in signals.items():
            label = "channel " + " and ".join(repr(c) for c in _METRIC_CHANNELS[name])
            rms[name + suffix] = _metric_rms(xs, sos, zi, padlen, label)
    return plan.assemble(rms)


@dataclass(frozen=True)
class _MetricPlan:
    """What :func:`compute_metrics` computes from a set of channels: the checked settings,
    the bands (suffix -> (low, high) [Hz]) and the metrics whose channels are present, in
    the spec's order. Shared with the closed loop's fused kernel
    (:func:`ident.sim.closedloop.simulate_batch_metrics`), which computes the RMS values
    itself and assembles them here."""

    band: tuple
    order: int
    fs: float
    split: object
    loads: dict
    bands: dict
    names: tuple

    def filter(self, b):
        """``(sos, padlen, zi)`` of band `b`."""
        return _band_filter(tuple(float(f) for f in b), self.order, float(self.fs))

    def assemble(self, rms):
        """The :class:`Metrics` from ``rms`` (metric name with band suffix -> values):
        the band-passed RMS metrics in order, and the normalized tire forces."""
        values = {}
        for suffix in self.bands:
            for name in self.names:
                values[name + suffix] = rms[name + suffix]
            for corner in CORNERS:
                tire = f"tire_force_rms_{corner}{suffix}"
                if corner in self.loads and tire in values:
                    values[f"tire_force_rms_norm_{corner}{suffix}"] = (values[tire]
                                                                      / self.loads[corner])
        return Metrics(values=values, band_hz=self.band, order=self.order, fs_hz=self.fs,
                       split_hz=self.split, static_loads_n=dict(self.loads) or None)


def _metric_plan(channel_names, fs, *, band_hz=(1.0, 20.0), order=4, static_loads_n=None,
                 split_hz=None):
    """Check :func:`compute_metrics`' settings for channels `channel_names` at rate `fs`
    (already checked) and return its :class:`_MetricPlan`."""
    band = _check_band(band_hz, fs)
    order = _check_order(order)
    loads = _check_static_loads(static_loads_n)
    bands = {"": band}
    if split_hz is not None:
        split = float(split_hz)
        if not (band[0] < split < band[1]):
            raise ValueError(
                f"split_hz={split_hz!r} must lie strictly inside band_hz={band}"
            )
        bands["_body"] = (band[0], split)
        bands["_wheelhop"] = (split, band[1])
    else:
        split = None
    names = []
    for name, chans in _METRIC_CHANNELS.items():
        missing = [c for c in chans if c not in channel_names]
        if missing:
            logger.debug("metric %s omitted: no channel %s", name, ", ".join(missing))
            continue
        names.append(name)
    return _MetricPlan(band=band, order=order, fs=fs, split=split, loads=loads, bands=bands,
                       names=tuple(names))
