"""Compiled kernels of the RMS metrics (numba): the zero-phase band-pass and numpy's pairwise
sums, run on many signals side by side in lanes, to the last bit of the reference steps.

Callers: :mod:`ident.sim.metrics` (:func:`sosfiltfilt_rows`, :func:`metric_rms_rows` for
batched signals) and the closed loop's fused metrics worker
(:mod:`ident.sim.loop_kernels`: :func:`setup_metric_rms` with its scratch shapes
:data:`LANES` and :data:`PW_LEVELS`). Every kernel repeats the operations of the
one-row reference (:func:`_sosfilt_inplace`, :func:`_pairwise_sum_col`) in the same
order: the same numbers as :func:`ident.sim.metrics.compute_metrics`' scipy and numpy
steps (tested in ``tests/test_metrics.py``). The kernels are written as plain Python
functions and compiled below, so the module imports without numba (for tooling).
"""

from __future__ import annotations

import numpy as np

__all__ = ["LANES", "PW_LEVELS", "sosfiltfilt_rows", "metric_rms_rows", "setup_metric_rms",
           "derived_metric_map"]


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
LANES = 16


def _sosfilt_lanes(sos, buf, z0, z1, start, stop, step, offset, lo, hi):
    """``sosfilt`` of every column of `buf` in place, over the rows ``range(start, stop,
    step)`` (``step = -1``: the backward pass, without a reversed copy).

    Parameters
    ----------
    sos : ndarray of float, shape (n_sections, 6)
    buf : ndarray of float, shape (n, n_lanes)
        One signal per column; ``n_lanes`` must be :data:`LANES` (the lane loops' trip
        count is that constant, so they compile into whole vectors with no remainder
        loop: the metrics' band-pass 1.7x faster, issue 40).
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
    n_lanes = LANES  # a compile-time trip count: the lane loops unroll into whole vectors
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
            _sosfilt_lanes(sos, buf, z0, z1, first, stop, step, offset, np.int64(0),
                           np.int64(0))


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
    Rows are filtered in blocks of :data:`LANES`, side by side in a (time, lane)
    buffer (a short last block is padded with zero rows, which stay zero), the blocks in
    parallel. Every row sees the operations of the one-row recurrence
    (:func:`_sosfilt_inplace`) in the same order: the same result to the last bit.
    """
    m, n = x.shape
    ne = n + 2 * padlen
    ns = sos.shape[0]
    n_blocks = (m + LANES - 1) // LANES
    for blk in _prange(n_blocks):
        buf = np.zeros((ne, LANES))
        z0 = np.empty((ns, LANES))
        z1 = np.empty((ns, LANES))
        no_offset = np.zeros(LANES)
        i0 = blk * LANES
        n_rows = min(LANES, m - i0)
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
PW_LEVELS = 64


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
    The same numbers, to the last bit, as :mod:`ident.sim.metrics`' mean removal,
    ``sosfiltfilt`` and RMS one after the other (tested): the mean and the mean square are numpy's
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
    n_blocks = (m + LANES - 1) // LANES
    for blk in _prange(n_blocks):
        buf = np.zeros((ne, LANES))
        z0 = np.empty((ns, LANES))
        z1 = np.empty((ns, LANES))
        stack = np.empty((PW_LEVELS, 10, LANES))
        sums = np.empty(LANES)
        i0 = blk * LANES
        n_rows = min(LANES, m - i0)
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
    `z0`, `z1` (n_sections, n_lanes) and `stack` (:data:`PW_LEVELS`, 10, n_lanes) are
    scratch; `buf` is overwritten.
    """
    _pairwise_sum_lanes(buf, padlen, n, np.bool_(False), sums, stack)
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
    _pairwise_sum_lanes(buf, padlen, n, np.bool_(True), sums, stack)
    for j in range(L):
        sums[j] = np.sqrt(sums[j] / n)


def setup_metric_rms(y, ia, sos, zi, padlen, out, buf, z0, z1, stack, sums, dmap, dw):
    """The metrics of one simulated setup, in blocks of :data:`LANES` metrics: metric `i`
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
        (:data:`PW_LEVELS`, 10, L) and (L,) with L = :data:`LANES` (a caller running
        many setups keeps one set per thread).
    dmap : ndarray of int64, shape (n_derived, 3 + 4)
        Derived metrics (:func:`derived_metric_map`): the RMS of a combination of up to 4
        metrics' band-passed signals, into ``out[ia.size + d]``. Row ``d``: the first
        metric of the block holding its sources, its group, its lane, and the sources'
        lanes in that block (-1: none). Shape (0, 7): none.
    dw : ndarray of float, shape (n_derived, 4)
        The sources' weights.

    Notes
    -----
    Compiled into the closed loop's kernel (:mod:`ident.sim.loop_kernels`), which computes each
    setup's metrics as soon as its outputs are simulated, while they are in the cache.
    Each lane gets :func:`_metric_rms_rows_py`'s operations: the same numbers to the last
    bit as :func:`ident.sim.metrics.compute_metrics` on the channels. A derived metric's
    signal is its combination of the band-passed sources (the mean removal, odd extension
    and zero-phase band-pass are linear: the band-passed combination to rounding), formed
    in lanes of the sources' block that no derived metric reads, then its RMS: a third
    element's travel and velocity from the corners' (issue 38) at one pass of squares
    instead of a block of the filter of their own.
    """
    n = y.shape[1]
    n_metrics = ia.size
    nd = dmap.shape[0]
    for i0 in range(0, n_metrics, LANES):
        n_rows = min(LANES, n_metrics - i0)
        for k in range(n):  # the pad rows are written by _metric_block's odd extension
            row = buf[padlen + k]
            for j in range(n_rows):
                row[j] = y[ia[i0 + j], k]
            for j in range(n_rows, LANES):
                row[j] = 0.0
        _metric_block(buf, n, padlen, sos, zi, z0, z1, stack, sums)
        for j in range(n_rows):
            out[i0 + j] = sums[j]
        d = 0
        while d < nd:  # the derived metrics of this block, a group of lanes at a time
            if dmap[d, 0] != i0:
                d += 1
                continue
            e = d + 1
            while e < nd and dmap[e, 0] == i0 and dmap[e, 1] == dmap[d, 1]:
                e += 1
            for k in range(padlen, padlen + n):
                row = buf[k]
                for q in range(d, e):
                    acc = 0.0
                    for c in range(4):
                        src = dmap[q, 3 + c]
                        if src >= 0:
                            acc += dw[q, c] * row[src]
                    row[dmap[q, 2]] = acc
            _pairwise_sum_lanes(buf, padlen, n, np.bool_(True), sums, stack)
            for q in range(d, e):
                out[n_metrics + q] = np.sqrt(sums[dmap[q, 2]] / n)
            d = e


def derived_metric_map(sources, weights, n_base):
    """The derived metrics' map of :func:`setup_metric_rms`: each metric's sources' block,
    group and lane.

    Parameters
    ----------
    sources : list of list of int
        Per derived metric, the indices (among the ``n_base`` filtered metrics) of its
        sources (at most 4).
    weights : list of list of float
        Their weights, as `sources`.
    n_base : int
        The filtered metrics.

    Returns
    -------
    (dmap, dw, kept) : ndarray (n_kept, 7) of int64, ndarray (n_kept, 4), list of int
        The map and weights of the derived metrics whose sources lie in one block of
        :data:`LANES` metrics (ordered by block, then group), and their positions in
        `sources`; the others (``not in kept``) must be filtered metrics of their own.
    """
    rows = []
    by_block = {}
    for i, src in enumerate(sources):
        blocks = {s // LANES for s in src}
        if len(src) == 0 or len(src) > 4 or len(blocks) != 1 or min(src) < 0 \
                or max(src) >= n_base:
            continue
        by_block.setdefault(blocks.pop(), []).append(i)
    kept = []
    for blk in sorted(by_block):
        i0 = blk * LANES
        used = {s - i0 for i in by_block[blk] for s in sources[i]}
        free = [j for j in range(LANES) if j not in used]
        for g, i in enumerate(by_block[blk]):
            lane = free[g % len(free)]
            src = [s - i0 for s in sources[i]] + [-1] * (4 - len(sources[i]))
            rows.append(([i0, g // len(free), lane] + src,
                         list(weights[i]) + [0.0] * (4 - len(weights[i]))))
            kept.append(i)
    dmap = np.array([r[0] for r in rows], dtype=np.int64).reshape(len(rows), 7)
    dw = np.array([r[1] for r in rows], dtype=float).reshape(len(rows), 4)
    return dmap, dw, kept


try:  # numba is a dependency; keep the module importable without it for tooling
    import numba as _nb

    _prange = _nb.prange
    _sosfilt_inplace = _nb.njit(cache=True)(_sosfilt_inplace)
    _sosfilt_lanes = _nb.njit(cache=True)(_sosfilt_lanes)
    _filtfilt_lanes = _nb.njit(cache=True)(_filtfilt_lanes)
    sosfiltfilt_rows = _nb.njit(cache=True, parallel=True)(_sosfiltfilt_rows_py)
    _pairwise_sum_col = _nb.njit(cache=True)(_pairwise_sum_col)
    _add_row = _nb.njit(cache=True, inline="always")(_add_row)
    _pairwise_leaf_lanes = _nb.njit(cache=True)(_pairwise_leaf_lanes)
    _pairwise_sum_lanes = _nb.njit(cache=True)(_pairwise_sum_lanes)
    _metric_block = _nb.njit(cache=True)(_metric_block)
    setup_metric_rms = _nb.njit(cache=True)(setup_metric_rms)
    metric_rms_rows = _nb.njit(cache=True, parallel=True)(_metric_rms_rows_py)
except ImportError:  # pragma: no cover
    _prange = range
    sosfiltfilt_rows = _sosfiltfilt_rows_py
    metric_rms_rows = _metric_rms_rows_py
