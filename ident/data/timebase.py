"""Time bases: a record's sample times, and time stamps as instruments write them.

:class:`TimeRecord` is the base of the records that hold equal-length channels sampled
uniformly from t = 0 (:class:`ident.data.drive.Drive`, :class:`ident.data.tracklog.TrackLog`,
:class:`planner.trackdrive.target.DriveTarget`): it reads ``n_samples``, ``duration_s`` and
``time_s`` from their ``fs_hz`` and ``channels``, so the three are written once.

:func:`uniform_time_base` checks the time column of a file as it was written and gives the
uniform time base its samples are read onto.

A rig controller writes time on an exact grid. A data logger on a CAN or serial bus stamps
each sample when it arrives, so its steps jitter around the sample interval (a 77 Hz logger:
steps of 12.7-13.4 ms), and a dyno's PC writes millisecond time stamps. Both are sound
records of a uniformly sampled signal. :func:`uniform_time_base` tells the cases apart by
each step's deviation from the median step:

- every step within :data:`EXACT_RTOL` (1e-6) of the median: the time base is uniform, and
  is used as it is (bit for bit as before);
- every step within `jitter_rtol` (default :data:`JITTER_RTOL`, 5 %) of the median: the
  time stamps jitter; the signals are resampled onto a uniform base (from the first stamp,
  at the stamps' least-squares rate snapped to the nominal one by :func:`nominal_rate`, up
  to the last stamp) by interpolation through the *measured* time stamps (:meth:`TimeBase.resample`), and the caller says so in one line
  with the jitter measured (:meth:`TimeBase.describe`);
- any step further off: samples were dropped, repeated, or the rate changed. That is not
  jitter, and resampling across it would invent data: refused at its time with the fix.

Where a rate must be chosen (runs logged at different rates, a model at another rate than
the logger's), a reader's ``resample_hz`` (``--resample HZ`` on the command line) puts the
record on a uniform base at that rate: the record is first made uniform at its own rate as
above, then resampled by the rational ratio of the rates with the band-limited polyphase
filter of :func:`resample_bandlimited` (the one of ``shockplan drive resample``), which
removes the content above the lower Nyquist frequency when going down (anti-aliasing).
Where no ratio of small integers gives the rate exactly (a jittered record's estimated
rate, an odd rate), the spline takes the stamps straight onto the new base going up, and
the same filter's low-pass precedes it going down. :meth:`TimeBase.describe` says what
was done in one line.

The interpolation is a B-spline of degree :data:`SPLINE_DEGREE` (7) through the measured
samples. As the degree grows, spline interpolation converges to band-limited (sinc)
interpolation; at degree 7 a signal with content up to a quarter of the sample rate is
reproduced within 2e-4 of its RMS (steps jittered by +-3 %, measured in
``tests/test_timebase.py``), against 5e-3 for a cubic spline and 9e-2 for linear
interpolation. 20 channels of 160,000 samples take about a second.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np
from scipy import signal
from scipy.interpolate import make_interp_spline

__all__ = [
    "TimeRecord",
    "EXACT_RTOL",
    "JITTER_RTOL",
    "NOMINAL_RATE_RTOL",
    "SPLINE_DEGREE",
    "FIR_HALF_LENGTH",
    "FIR_KAISER_BETA",
    "MAX_RATE_DENOMINATOR",
    "RATE_RTOL",
    "EXACT_RATIO_RTOL",
    "TimeBase",
    "nominal_rate",
    "uniform_time_base",
    "rate_ratio",
    "resample_bandlimited",
    "resample_uniform",
    "bandlimited_fir",
]

#: Largest deviation of a step from the median step, relative to it, of a time base taken
#: as exactly uniform (a rig controller's, or one written with full precision).
EXACT_RTOL = 1e-6
#: Largest deviation of a step from the median step, relative to it, taken as a logger's
#: jitter and resampled; a step further off is a gap (dropped or repeated samples).
JITTER_RTOL = 0.05
#: Largest relative difference between a jittered record's estimated rate and the nominal
#: rate it is snapped to (:func:`nominal_rate`).
NOMINAL_RATE_RTOL = 1e-4
#: Degree of the interpolating B-spline through jittered samples (see the module docstring).
SPLINE_DEGREE = 7
#: Anti-aliasing FIR of :func:`resample_bandlimited`: half length in units of
#: ``max(up, down)`` and Kaiser window parameter.
FIR_HALF_LENGTH = 20
FIR_KAISER_BETA = 8.0
#: Largest denominator of a rate ratio ``up / down`` (:func:`rate_ratio`).
MAX_RATE_DENOMINATOR = 1000
#: Largest relative error of the rate a ratio reaches (:func:`rate_ratio`; one sample in
#: 10^6, a time-scale error far below any clock's).
RATE_RTOL = 1e-6
#: The same, for a record resampled to a chosen rate by a ratio (else by the spline):
#: rounding only, so that the samples' times are the times they are labelled with.
EXACT_RATIO_RTOL = 1e-12


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


@dataclass(frozen=True, eq=False)
class TimeBase:
    """A record's time base, checked: uniform as written, or the uniform one it is resampled to.

    Attributes
    ----------
    time_s : ndarray, shape (n_samples,)
        The uniform sample times [s]: as written when :attr:`resampled` is False, else
        ``t[0] + k / fs_hz`` up to the last stamp (the count may differ from the record's
        by a sample or two).
    fs_hz : float
        Sample rate [Hz] (of a resampled record: its nominal rate, :func:`nominal_rate`).
    raw_time_s : ndarray, shape (n_samples,)
        The time stamps as written [s].
    jitter : float
        The largest deviation of a step from the median step, relative to it.
    resampled : bool
        True if the signals must be resampled onto :attr:`time_s` (:meth:`resample`).
    native : TimeBase or None
        At a rate chosen by the reader (``resample_hz``), the record's uniform base at its
        own rate, which the chosen one is resampled from; else None.
    ratio : (int, int) or None
        At a chosen rate, ``(up, down)`` of the polyphase resampling from :attr:`native`
        (:func:`resample_uniform`), or None where no ratio of small integers gives the rate
        exactly (low-pass and spline); ``(1, 1)`` otherwise.
    """

    time_s: np.ndarray
    fs_hz: float
    raw_time_s: np.ndarray
    jitter: float
    resampled: bool
    native: "TimeBase | None" = None
    ratio: "tuple | None" = (1, 1)

    def resample(self, values):
        """Signals sampled at :attr:`raw_time_s`, on :attr:`time_s`.

        Parameters
        ----------
        values : array_like, shape (n_samples,) or (n_samples, n_signals)

        Returns
        -------
        ndarray
            The same shape but the first axis ``time_s.size``, float; `values` itself (as
            an array) when the time base is uniform as written.
        """
        x = np.asarray(values, dtype=float)
        if not self.resampled:
            return x
        if self.native is not None:  # uniform at the record's rate, then at the chosen one
            if self.ratio is None and self.fs_hz >= self.native.fs_hz:  # up: one spline
                return make_interp_spline(self.raw_time_s, x, k=SPLINE_DEGREE,
                                          axis=0)(self.time_s)
            x = self.native.resample(x)
            if self.ratio is not None:
                return resample_uniform(x, *self.ratio, self.time_s.size)
            return _spline_onto(x, self.native.fs_hz, self.fs_hz, self.time_s.size)
        return make_interp_spline(self.raw_time_s, x, k=SPLINE_DEGREE, axis=0)(self.time_s)

    def describe(self, where):
        """One line saying what was resampled, with the jitter measured (for the log)."""
        if self.native is not None:
            own = self.native
            how = ("anti-aliased below its Nyquist frequency" if self.fs_hz < own.fs_hz
                   else "band-limited")
            jitter = (f", its time stamps jittering by up to {100 * own.jitter:.2g} % of the "
                      "step" if own.resampled else "")
            return (f"{where}: resampled from {own.fs_hz:.6g} Hz{jitter} onto a uniform "
                    f"{self.fs_hz:.6g} Hz time base as asked ({self.time_s.size} samples, "
                    f"{how})")
        step_ms = 1e3 / self.fs_hz
        return (f"{where}: time stamps jitter by up to {100 * self.jitter:.2g} % of the "
                f"{step_ms:.4g} ms step: resampled onto a uniform {self.fs_hz:.6g} Hz time "
                f"base ({self.time_s.size} samples, band-limited interpolation)")


def uniform_time_base(time_s, *, where, jitter_rtol=JITTER_RTOL, error=ValueError,
                      row_offset=2, row_label="data row", resample_hz=None):
    """Check a record's time stamps and give its uniform time base (see the module docstring).

    Parameters
    ----------
    time_s : array_like, shape (n_samples,)
        Time stamps [s], finite.
    where : str
        Prefix of every error message (the file, the run).
    jitter_rtol : float
        Largest deviation of a step from the median step, relative to it, resampled as
        jitter (default 5 %); 0 accepts only an exactly uniform base.
    error : type
        The exception raised (a subclass of ``ValueError``, e.g. ``SessionError``).
    row_offset : int
        Added to the 0-based index of a step (from sample ``i`` to ``i + 1``) to give the
        data row an error message names: the default 2 names sample ``i + 1`` as a 1-based
        data row.
    row_label : str
        What a file's sample is called in messages (``"sample"`` in a binary file).
    resample_hz : float, optional
        The rate [Hz] of the uniform base to resample onto (``--resample``): the record,
        made uniform at its own rate, is resampled by the ratio of the rates
        (:func:`rate_ratio`, :func:`resample_uniform`), or, where no ratio of small
        integers gives it, low-passed below the new Nyquist frequency (going down) and
        interpolated by the B-spline; :attr:`TimeBase.native` is its own base. Default:
        the record's own rate.

    Returns
    -------
    TimeBase

    Raises
    ------
    error
        If there are fewer than 2 samples, time is not strictly increasing, or a step
        differs from the median step by more than `jitter_rtol` (a gap, a repeated
        sample, a changed rate), naming the first such step's time and row, and the fix;
        or `resample_hz` is not a positive number.

    Examples
    --------
    >>> tb = uniform_time_base([0.0, 0.0101, 0.0199, 0.0301, 0.04], where="log.csv")
    >>> tb.resampled, round(tb.fs_hz, 6), round(tb.jitter, 3)
    (True, 100.0, 0.02)
    >>> uniform_time_base([0.0, 0.01, 0.02], where="run.csv").resampled
    False
    """
    if resample_hz is not None:
        own = uniform_time_base(time_s, where=where, jitter_rtol=jitter_rtol, error=error,
                                row_offset=row_offset, row_label=row_label)
        ratio = rate_ratio(own.fs_hz, resample_hz, where=where, error=error,
                           rtol=EXACT_RATIO_RTOL)
        if ratio == (1, 1):
            return own
        fs = float(resample_hz)
        span = (own.time_s.size - 1) / own.fs_hz
        n = int(np.floor(span * fs * (1.0 + 1e-12))) + 1  # inside the record: no extrapolation
        if ratio is not None:
            n = (own.time_s.size - 1) * ratio[0] // ratio[1] + 1  # the same, exactly
        return TimeBase(own.time_s[0] + np.arange(n) / fs, fs, own.raw_time_s, own.jitter, True,
                        own, ratio)
    t = np.asarray(time_s, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise error(f"{where}: time needs at least 2 samples; export the whole record")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise error(f"{where}: time is not strictly increasing at {row_label} {i + row_offset} "
                    f"(t={t[i]:.9g} s then {t[i + 1]:.9g} s); sort the samples and remove "
                    "duplicated rows")
    typical = float(np.median(dt))
    dev = np.abs(dt - typical) / typical
    jitter = float(dev.max())
    if jitter <= EXACT_RTOL:
        step = (t[-1] - t[0]) / (t.size - 1)
        return TimeBase(t, float(1.0 / step), t, jitter, False)
    if jitter > jitter_rtol:
        i = int(np.argmax(dev > jitter_rtol))
        steps = dt[i] / typical
        what = (f"a gap of {steps:.3g} sample intervals" if steps > 1 else
                f"a step of {steps:.3g} sample intervals")
        raise error(
            f"{where}: time is not uniformly sampled: {what} ({dt[i]:.6g} s against the "
            f"typical {typical:.6g} s) at t={t[i + 1]:.9g} s ({row_label} {i + row_offset}); "
            f"steps within {100 * jitter_rtol:g} % of the typical one are a logger's jitter "
            "and resampled, this one is dropped or repeated samples or a changed rate: cut "
            "the record at the gap, fill it, or export at one constant rate")
    step = np.polyfit(np.arange(t.size, dtype=float), t, 1)[0]  # jitter averages out
    fs = nominal_rate(1.0 / step)
    n = int(np.floor((t[-1] - t[0]) * fs * (1.0 + 1e-12))) + 1  # inside the record: no
    return TimeBase(t[0] + np.arange(n) / fs, float(fs), t, jitter, True)  # extrapolation


def nominal_rate(fs_hz):
    """A jittered record's rate, snapped to the nominal rate it was logged at.

    The least-squares rate of jittered stamps is within about 1e-5 of the logger's true rate
    (stamps off by a few per cent of a step, a few hundred samples or more), and loggers run
    at a whole number of hertz or a whole number of microseconds per sample. The nearest
    such rate within :data:`NOMINAL_RATE_RTOL` is taken, so that runs logged at one rate
    share it exactly (a session's runs must); otherwise the estimate itself.

    Parameters
    ----------
    fs_hz : float
        The estimated rate [Hz].

    Returns
    -------
    float

    Examples
    --------
    >>> nominal_rate(99.99917), round(nominal_rate(76.923069), 6), nominal_rate(55.51)
    (100.0, 76.923077, 55.51)
    """
    whole_hz = float(round(fs_hz))
    if whole_hz > 0 and abs(whole_hz - fs_hz) <= NOMINAL_RATE_RTOL * fs_hz:
        return whole_hz
    # whole microseconds per sample lie densely below 1 kHz: only a much closer one counts
    whole_us = 1e6 / round(1e6 / fs_hz)
    if abs(whole_us - fs_hz) <= 0.01 * NOMINAL_RATE_RTOL * fs_hz:
        return whole_us
    return float(fs_hz)


def rate_ratio(fs_from_hz, fs_to_hz, *, where, error=ValueError, rtol=RATE_RTOL):
    """The ratio ``up / down`` of small integers that turns one sample rate into another.

    Parameters
    ----------
    fs_from_hz, fs_to_hz : float
        The record's rate and the rate wanted [Hz].
    where : str
        Prefix of an error message.
    error : type
        The exception raised.
    rtol : float
        Largest relative error of the rate reached (default :data:`RATE_RTOL`; a record's
        values resampled to a chosen rate take :data:`EXACT_RATIO_RTOL`: an error of
        1e-6 would shift the end of an 800 s record by 0.8 ms).

    Returns
    -------
    (int, int) or None
        ``up, down`` (coprime, ``down <= MAX_RATE_DENOMINATOR``), ``(1, 1)`` for rates
        equal within `rtol`; None if no such ratio reaches `fs_to_hz` within `rtol` (a
        jittered record's estimated rate, an odd rate).

    Raises
    ------
    error
        If `fs_to_hz` is not a positive number.

    Examples
    --------
    >>> rate_ratio(100.0, 64.0, where="run.csv"), rate_ratio(76.923077, 100.0, where="log")
    ((16, 25), (13, 10))
    >>> rate_ratio(100.0, 314.159265, where="run.csv")  # within 1e-6: 8.5e-8
    (355, 113)
    >>> rate_ratio(100.0, 314.159265, where="run.csv", rtol=EXACT_RATIO_RTOL) is None
    True
    """
    try:
        fs_to = float(fs_to_hz)
    except (TypeError, ValueError):
        fs_to = float("nan")
    if not (np.isfinite(fs_to) and fs_to > 0):
        raise error(f"{where}: the rate to resample to must be a positive number of Hz, got "
                    f"{fs_to_hz!r}; give e.g. --resample 100")
    ratio = Fraction(fs_to / fs_from_hz).limit_denominator(MAX_RATE_DENOMINATOR)
    achieved = fs_from_hz * ratio.numerator / ratio.denominator
    if ratio == 0 or abs(achieved - fs_to) > rtol * fs_to:
        return None
    return ratio.numerator, ratio.denominator


def resample_bandlimited(x, up, down=1, *, axis=0):
    """Polyphase resampling of samples of a band-limited signal by ``up / down``.

    A longer, sharper anti-aliasing filter than ``resample_poly``'s default
    (which has 0.1 % ripple): a Kaiser-windowed FIR (``beta = 8``, 40 taps per
    unit of ``max(up, down)`` each side) flat to 1e-5 up to 0.8 of the lower
    Nyquist frequency and below -80 dB above 1.2 of it. Zero phase: output
    sample ``k * down`` is input sample ``k * up`` in time. The closed-loop
    simulator uses it to refine a drive onto its internal grid.

    Parameters
    ----------
    x : ndarray
    up, down : int
    axis : int

    Returns
    -------
    ndarray
        ``ceil(n * up / down)`` samples along `axis`.
    """
    if up == down:
        return np.array(x, dtype=float, copy=True)
    return signal.resample_poly(x, up, down, axis=axis, window=bandlimited_fir(max(up, down)))


def bandlimited_fir(rate):
    """The anti-aliasing FIR of :func:`resample_bandlimited` for ``max(up, down) = rate``.

    ``2 * FIR_HALF_LENGTH * rate + 1`` taps, symmetric, gain 1 at 0 Hz.
    """
    return signal.firwin(2 * FIR_HALF_LENGTH * rate + 1, 1.0 / rate,
                         window=("kaiser", FIR_KAISER_BETA))


def resample_uniform(x, up, down, n_out):
    """A uniformly sampled record resampled by ``up / down`` (:func:`resample_bandlimited`)
    along its first axis, its ends extended by odd reflection about the end samples (the
    value and slope go on; not zeros, which would pull the ends toward 0).

    Parameters
    ----------
    x : ndarray, shape (n, ...)
    up, down : int
        Coprime.
    n_out : int
        Output samples; sample ``k`` is at input sample ``k * down / up`` in time, so
        ``(n - 1) * up // down + 1`` keeps them inside the record.

    Returns
    -------
    ndarray, shape (n_out, ...)

    Examples
    --------
    >>> t = np.arange(200) / 100.0  # 2 s of 3 Hz at 100 Hz, onto 64 Hz
    >>> y = resample_uniform(np.sin(2 * np.pi * 3 * t + 0.3), 16, 25, 128)
    >>> err = np.abs(y - np.sin(2 * np.pi * 3 * np.arange(128) / 64.0 + 0.3))
    >>> bool(err.max() < 1e-3), bool(err[20:-20].max() < 1e-5)  # the ends, the middle
    (True, True)
    """
    x = np.asarray(x, dtype=float)
    # pad by whole multiples of `down` input samples (the output grid stays on sample 0),
    # longer than the filter's half length in input samples
    m = -(-(FIR_HALF_LENGTH * max(up, down) // up + 2) // down)
    pad = [(m * down, m * down)] + [(0, 0)] * (x.ndim - 1)
    y = resample_bandlimited(np.pad(x, pad, mode="reflect", reflect_type="odd"), up, down,
                             axis=0)
    return y[m * up:m * up + n_out]


def _spline_onto(x, fs_from_hz, fs_to_hz, n_out):
    """A uniform record at `fs_from_hz` on `n_out` samples at a lower `fs_to_hz` from its
    first, for rates of no simple ratio: low-passed below the new Nyquist frequency (zero
    phase, the FIR of :func:`bandlimited_fir` with the cut-off scaled), then through the
    B-spline of degree :data:`SPLINE_DEGREE`."""
    if fs_to_hz < fs_from_hz:
        r = int(np.ceil(fs_from_hz / fs_to_hz))
        h = signal.firwin(2 * FIR_HALF_LENGTH * r + 1, fs_to_hz / fs_from_hz,
                          window=("kaiser", FIR_KAISER_BETA))
        half = FIR_HALF_LENGTH * r
        pad = [(half, half)] + [(0, 0)] * (x.ndim - 1)
        xp = np.pad(x, pad, mode="reflect", reflect_type="odd")
        x = signal.oaconvolve(xp, h.reshape((-1,) + (1,) * (x.ndim - 1)), mode="valid",
                              axes=0)
    t_from = np.arange(x.shape[0]) / fs_from_hz
    return make_interp_spline(t_from, x, k=SPLINE_DEGREE, axis=0)(np.arange(n_out) / fs_to_hz)
