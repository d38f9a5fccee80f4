"""Drives: the time histories of the 7 rig inputs, made, read, written and resampled.

A drive holds the rig inputs of :data:`ident.data.channels.RIG_INPUTS`, in SI:
``aero_heave`` [N], ``aero_roll`` [N*m], ``aero_pitch`` [N*m] and
``wheelloader_LF/RF/LR/RR`` [m] (wheel-pad displacement, up positive), on a
uniform time grid starting at 0 s. A 4-post drive gives only the wheelloaders:
its aero inputs are zero (``Drive.rig_inputs`` records what was given, and a
drive file written from it has no aero columns). :func:`check_drive_inputs`
refuses a drive with nonzero content on a rig input a model was not identified
with (a 4-post model and an aero drive).

Three generators make drives:

- :func:`make_noise_drive`, the seed paper's identification drive: independent
  Gaussian white noise per channel, band-limited 0..30 Hz by an 8th-order
  discrete Butterworth low-pass, scaled to a peak amplitude per channel;
- :func:`make_sweep_drive`, a sine sweep on chosen channels;
- :func:`make_track_drive`, a track-like drive: ISO 8608-style road profiles
  under the left and right wheels at a speed, the rear wheels following the
  front ones, plus optional slowly varying aero loads.

:func:`read_drive` and :func:`write_drive` read and write drive files (the
rig-session run-file format, CSV or Parquet, through
:func:`ident.data.runs.read_run_table` / :func:`ident.data.runs.write_run_table`);
:func:`resample_drive` changes a drive's sample rate. A written drive file says its
unit system (a CSV's ``units`` column, a Parquet file's metadata; the earlier CSV
layout's first line ``# units: imperial`` is still read); a read one takes it from there,
from ``units`` (``--units``), or is SI, and a file that says nothing and is implausible
as SI is refused, one whose level fits either unit system read as SI with a warning (see
:func:`read_drive`).

Examples
--------
>>> drive = make_noise_drive(duration_s=10.0, fs_hz=100.0, seed=1,
...                          peak={"wheelloader_LF": 0.0254, "aero_heave": 2224.0})
>>> drive.n_samples, drive.as_array().shape
(1000, (1000, 7))
>>> float(abs(drive.channels["wheelloader_LF"]).max())
0.0254
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np
from scipy import fft as sp_fft
from scipy import signal

from ident.data.channels import AERO_INPUTS, RIG_INPUTS, WHEELLOADER_INPUTS, missing_aero, rig_inputs_of
from ident.data.runs import read_run_table, write_run_table
# the band-limited resampler lives with the time bases (a reader's --resample uses it too)
from ident.data.timebase import FIR_HALF_LENGTH, TimeRecord, bandlimited_fir, resample_bandlimited
from ident.data.units import to_si
from ident.errors import DriveError

__all__ = [
    "Drive",
    "make_noise_drive",
    "make_sweep_drive",
    "make_track_drive",
    "make_multisine_drive",
    "read_drive",
    "write_drive",
    "resample_drive",
    "resample_bandlimited",
    "check_drive_inputs",
    "drive_label",
    "fade_window",
    "ISO8608_N0_CYCLES_M",
    "FIR_HALF_LENGTH",
]

logger = logging.getLogger(__name__)

#: Fewest samples of a drive file: the metrics' zero-phase band-pass pads by 27 samples.
MIN_DRIVE_SAMPLES = 28
#: Wheel-pad RMS above which a drive file is implausible for a shaker rig [m] (race-car
#: rig drives are a few mm RMS; an inch file read as SI gives 25x its value in metres).
PLAUSIBLE_WHEELLOADER_RMS_M = 0.05
#: Wheel-pad RMS below which a drive file is implausible for a shaker rig [m]: the largest
#: pad RMS of a drive is at least a quarter millimetre (a metre file read as inches gives
#: 1/25.4 of its value: the demo's 3.7 mm drive would be 0.14 mm).
PLAUSIBLE_WHEELLOADER_RMS_MIN_M = 0.25e-3

#: Reference spatial frequency of ISO 8608 road spectra [cycles/m].
ISO8608_N0_CYCLES_M = 0.1

#: Largest denominator of the rational rate ratio in :func:`resample_drive`.
_MAX_DENOMINATOR = 1000
#: Largest relative error of the achieved rate in :func:`resample_drive`
#: (1e-6: one sample in 10^6, a time-scale error far below any rig's clock).
_RTOL_RATE = 1e-6
#: Output samples per FFT segment of :func:`decimate_bandlimited` (1024: segments
#: of 8192 input samples at r = 8, 2.5x faster than one FFT of a whole 800 s record).
_DECIMATE_SEGMENT = 1024
_SWEEP_METHODS = ("linear", "quadratic", "logarithmic", "hyperbolic")


# --------------------------------------------------------------------------------------
# The Drive
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False, repr=False)
class Drive(TimeRecord):
    """The 7 rig-input time histories of one drive, in SI units.

    Attributes
    ----------
    name : str
        Drive name (used in messages and output files).
    fs_hz : float
        Sample rate [Hz]; samples are at ``k / fs_hz``, ``k = 0 .. n_samples-1``.
    channels : dict of str to ndarray, shape (n_samples,)
        Every rig input of :data:`ident.data.channels.RIG_INPUTS` -> samples in SI
        (``aero_heave`` [N], ``aero_roll`` and ``aero_pitch`` [N*m],
        ``wheelloader_XX`` [m]), float64 and read-only, in that order. Give
        all seven, or only the four wheelloaders (a 4-post drive: the aero
        inputs are then zero arrays).
    settings : dict
        How the drive was made (generator and its arguments, or the file it
        was read from), so that a drive explains itself.
    rig_inputs : tuple of str
        The rig inputs given on construction, in ``RIG_INPUTS`` order: all
        seven, or the four wheelloaders (set from `channels`, not an argument).

    Raises
    ------
    DriveError
        On construction, if a wheelloader is missing, only some of the three
        aero inputs are given, a channel is unknown, the channels differ in
        length or are not one-dimensional, a value is NaN/inf, there are fewer
        than 2 samples, or `fs_hz` is not a positive number.

    Notes
    -----
    Signs follow the rig-session spec: wheel-pad displacement up positive,
    ``aero_heave`` acts up, ``aero_roll`` / ``aero_pitch`` act in the positive
    roll (left side up) and pitch (rear up) directions.
    """

    name: str
    fs_hz: float
    channels: dict
    settings: dict = field(default_factory=dict)
    rig_inputs: tuple = field(init=False, repr=False)

    def __post_init__(self):
        where = f"drive {self.name!r}"
        if not isinstance(self.name, str) or not self.name:
            raise DriveError(f"drive name must be a non-empty string, got {self.name!r}")
        object.__setattr__(self, "fs_hz", _check_positive(self.fs_hz, "fs_hz", where=where))
        if not isinstance(self.channels, Mapping):
            raise DriveError(
                f"{where}: channels must be a mapping rig input -> samples, got "
                f"{type(self.channels).__name__}"
            )
        unknown = [c for c in self.channels if c not in RIG_INPUTS]
        missing = [c for c in WHEELLOADER_INPUTS if c not in self.channels]
        missing += missing_aero(self.channels)
        if unknown or missing:
            raise DriveError(
                f"{where}: a drive holds the 7 rig inputs {list(RIG_INPUTS)} (or, for a "
                "4-post rig, the 4 wheelloaders only); "
                + (f"missing {missing}" if missing else "")
                + ("; " if missing and unknown else "")
                + (f"unknown {unknown}" if unknown else "")
                + " (give a zero array for an unused input)"
            )
        given = rig_inputs_of(self.channels)
        channels = {}
        for c in given:
            try:
                x = np.array(self.channels[c], dtype=np.float64)
            except (TypeError, ValueError):
                raise DriveError(f"{where}: channel {c!r} is not numeric") from None
            if x.ndim != 1:
                raise DriveError(
                    f"{where}: channel {c!r} must be one-dimensional (n_samples,), "
                    f"got shape {x.shape}"
                )
            bad = ~np.isfinite(x)
            if bad.any():
                raise DriveError(
                    f"{where}: channel {c!r} has {int(bad.sum())} NaN/inf value(s) from "
                    f"t={np.argmax(bad) / self.fs_hz:.6g} s; fill or cut the drive"
                )
            x.flags.writeable = False
            channels[c] = x
        lengths = {c: x.size for c, x in channels.items()}
        if len(set(lengths.values())) > 1:
            raise DriveError(
                f"{where}: the channels differ in length ({lengths}); give every rig "
                "input the same number of samples"
            )
        if channels[WHEELLOADER_INPUTS[0]].size < 2:
            raise DriveError(f"{where}: has fewer than 2 samples")
        zero = np.zeros(channels[WHEELLOADER_INPUTS[0]].size)
        zero.flags.writeable = False
        channels = {c: channels.get(c, zero) for c in RIG_INPUTS}  # 4-post: aero inputs zero
        object.__setattr__(self, "rig_inputs", given)
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "settings", dict(self.settings))

    def as_array(self):
        """Return the inputs as one array.

        Returns
        -------
        ndarray, shape (n_samples, 7)
            Columns in :data:`ident.data.channels.RIG_INPUTS` order, SI (a new array;
            zero columns for the aero inputs of a 4-post drive).
        """
        return np.column_stack([self.channels[c] for c in RIG_INPUTS])

    def __repr__(self):
        kind = self.settings.get("kind", "?")
        return (f"Drive(name={self.name!r}, fs_hz={self.fs_hz:g}, "
                f"n_samples={self.n_samples}, duration_s={self.duration_s:g}, kind={kind!r})")


# --------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------


def _check_positive(value, name, *, where="drive", allow_zero=False):
    if isinstance(value, (bool, np.bool_)):
        raise DriveError(f"{where}: {name} must be a number, got {value!r}")
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise DriveError(f"{where}: {name} must be a number, got {value!r}") from None
    ok = value >= 0 if allow_zero else value > 0
    if not (math.isfinite(value) and ok):
        bound = "non-negative" if allow_zero else "positive"
        raise DriveError(f"{where}: {name} must be a finite {bound} number, got {value}")
    return value


def _n_samples(duration_s, fs_hz, *, where):
    duration_s = _check_positive(duration_s, "duration_s", where=where)
    fs_hz = _check_positive(fs_hz, "fs_hz", where=where)
    n = int(round(duration_s * fs_hz))
    if n < 2:
        raise DriveError(
            f"{where}: duration_s * fs_hz = {duration_s * fs_hz:g} samples; a drive "
            "needs at least 2"
        )
    return n, fs_hz


def _check_below_nyquist(f_hz, name, fs_hz, *, where):
    f_hz = _check_positive(f_hz, name, where=where)
    if f_hz >= fs_hz / 2:
        raise DriveError(
            f"{where}: {name} = {f_hz:g} Hz must be below fs_hz/2 = {fs_hz / 2:g} Hz; "
            "lower it or raise fs_hz"
        )
    return f_hz


def _check_amplitudes(amplitudes, name, *, where, allowed=RIG_INPUTS):
    if not isinstance(amplitudes, Mapping):
        raise DriveError(
            f"{where}: {name} must be a mapping rig input -> SI amplitude, got "
            f"{type(amplitudes).__name__}"
        )
    unknown = [c for c in amplitudes if c not in allowed]
    if unknown:
        raise DriveError(
            f"{where}: {name} names unknown channel(s) {unknown}; use {list(allowed)}"
        )
    return {c: _check_positive(v, f"{name}[{c!r}]", where=where, allow_zero=True)
            for c, v in amplitudes.items()}


def _taper(n, fs_hz, taper_s, *, where):
    """Raised-cosine fade-in and fade-out of `taper_s` seconds each (ones between).

    The first and last samples are exactly zero (for ``taper_s > 0``).
    """
    taper_s = _check_positive(taper_s, "taper_s", where=where, allow_zero=True)
    m = int(round(taper_s * fs_hz))
    w = np.ones(n)
    if m == 0:
        return w
    if 2 * m > n:
        raise DriveError(
            f"{where}: taper_s = {taper_s:g} s fades in and out over {2 * m} samples but "
            f"the drive has {n}; shorten taper_s or lengthen the drive"
        )
    ramp = 0.5 * (1.0 - np.cos(np.pi * np.arange(m) / m))
    w[:m] = ramp
    w[n - m:] = ramp[::-1]
    return w


def fade_window(n, fs_hz, fade_s):
    """Ones with a raised-cosine fade-in and fade-out of `fade_s` [s] at each end, shape (n,).

    The ramps are sampled half a sample in (neither end sample is exactly 0), the fade
    of a track record (:func:`ident.sim.virtual_track.make_track_log`) and of a drive's target
    (:mod:`planner.trackdrive.target`). The generated drives' own fade starts at exactly
    0 instead.

    Parameters
    ----------
    n : int
        Samples in the record.
    fs_hz : float
        Sample rate [Hz].
    fade_s : float
        Duration of each fade [s] (>= 0; rounded to whole samples; 0: all ones).

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    ValueError
        If the two fades do not fit the record (callers check first, with their own message).

    Examples
    --------
    >>> fade_window(6, 1.0, 2.0).round(3).tolist()
    [0.146, 0.854, 1.0, 1.0, 0.854, 0.146]
    """
    w = np.ones(n)
    m = int(round(fade_s * fs_hz))
    if m > 0:
        if 2 * m > n:
            raise ValueError(f"fades of {fade_s:g} s at each end do not fit a record of "
                             f"{n / fs_hz:g} s; shorten the fade")
        ramp = 0.5 - 0.5 * np.cos(np.pi * (np.arange(m) + 0.5) / m)
        w[:m] = ramp
        w[n - m:] = ramp[::-1]
    return w


def _default_name(name, kind, seed=None):
    if name is None:
        return kind if seed is None else f"{kind}-{seed}"
    if not isinstance(name, str) or not name:
        raise DriveError(f"drive name must be a non-empty string, got {name!r}")
    return name


# --------------------------------------------------------------------------------------
# Generators
# --------------------------------------------------------------------------------------


def make_noise_drive(*, duration_s, fs_hz, peak, seed, f_max_hz=30.0, filter_order=8,
                     taper_s=1.0, name=None):
    """Make the seed paper's band-limited Gaussian white-noise drive.

    Each rig input is independent Gaussian white noise
    (``numpy.random.default_rng(seed)``, one stream drawn for all 7 inputs in
    :data:`~ident.data.channels.RIG_INPUTS` order), low-passed 0..`f_max_hz` by a
    causal `filter_order`-th order discrete Butterworth filter
    (``scipy.signal.sosfilt``), faded in and out with a raised cosine over
    `taper_s` seconds, and finally scaled so that its largest absolute value
    equals ``peak[channel]``.

    Parameters
    ----------
    duration_s : float
        Drive length [s]; ``round(duration_s * fs_hz)`` samples.
    fs_hz : float
        Sample rate [Hz].
    peak : Mapping of str to float
        Rig input -> peak amplitude in SI ([N], [N*m] or [m]). Inputs absent
        or with peak 0 are all zeros. The paper uses 1 in (0.0254 m) for the
        wheelloaders, 500 lbf (2224 N) for ``aero_heave`` and, for the roll
        and pitch moments, 3 times the roll and pitch stiffness in in*lbf/deg.
    seed : int or numpy.random.SeedSequence
        Seed of the noise; the same seed gives the same drive.
    f_max_hz : float
        Cut-off of the low-pass [Hz] (the paper: 30 Hz); below ``fs_hz / 2``.
    filter_order : int
        Butterworth order (the paper: 8).
    taper_s : float
        Raised-cosine fade-in and fade-out length [s] (0: none). A rig ramps
        its inputs in; the fade also keeps the start transient of a
        closed-loop simulation small. It is applied before the peak scaling,
        so the peak holds.
    name : str, optional
        Drive name (default ``"noise-<seed>"``).

    Returns
    -------
    Drive
        With ``settings`` holding the arguments (``kind = "noise"``).

    Raises
    ------
    DriveError
        If a duration, rate, cut-off or peak is not a positive (non-negative
        for peaks and `taper_s`) number, `f_max_hz` is not below
        ``fs_hz / 2``, `peak` names an unknown channel, `filter_order` is not a
        positive integer, or the fades do not fit in the drive.

    Notes
    -----
    The filter is causal, as in the paper; its start-up transient falls in
    the fade-in. The spectrum is flat up to about ``0.8 * f_max_hz`` and
    falls by ``20 * filter_order * log10(f / f_max_hz)`` dB above the cut-off
    (48 dB at twice the cut-off for order 8).
    """
    where = "make_noise_drive"
    n, fs_hz = _n_samples(duration_s, fs_hz, where=where)
    f_max_hz = _check_below_nyquist(f_max_hz, "f_max_hz", fs_hz, where=where)
    peaks = _check_amplitudes(peak, "peak", where=where)
    if isinstance(filter_order, bool) or not isinstance(filter_order, (int, np.integer)) \
            or filter_order < 1:
        raise DriveError(f"{where}: filter_order must be a positive integer, got "
                         f"{filter_order!r}")
    w = _taper(n, fs_hz, taper_s, where=where)

    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((len(RIG_INPUTS), n))
    sos = signal.butter(int(filter_order), f_max_hz, "lowpass", fs=fs_hz, output="sos")
    shaped = signal.sosfilt(sos, noise, axis=-1) * w
    channels = {}
    for c, x in zip(RIG_INPUTS, shaped):
        p = peaks.get(c, 0.0)
        channels[c] = x * (p / np.max(np.abs(x))) if p > 0 else np.zeros(n)
    settings = {"kind": "noise", "duration_s": n / fs_hz, "seed": _seed_setting(seed),
                "peak": dict(peaks), "f_max_hz": f_max_hz,
                "filter_order": int(filter_order), "taper_s": float(taper_s)}
    return Drive(name=_default_name(name, "noise", _seed_setting(seed)), fs_hz=fs_hz,
                 channels=channels, settings=settings)


def make_multisine_drive(*, duration_s, fs_hz, rms, seed, f_min_hz=0.3, f_max_hz=25.0,
                         taper_s=1.0, name=None):
    """Make a random-phase multisine drive: a flat amplitude spectrum in a band.

    Every DFT line of the record (``k / duration_s`` Hz) in
    ``[f_min_hz, f_max_hz]`` gets the same amplitude and a uniformly random
    phase, drawn independently for each rig input
    (``numpy.random.default_rng(seed)``); the record is faded in and out over
    `taper_s` and scaled to ``rms[channel]``. Unlike band-limited noise, the
    spectrum is flat line by line (no random amplitude), so a given rig time
    carries the most information per line; the independent phases keep the
    inputs uncorrelated.

    Parameters
    ----------
    duration_s, fs_hz : float
        Length [s] and sample rate [Hz].
    rms : Mapping of str to float
        Rig input -> RMS in SI ([N], [N*m] or [m]); absent or 0: all zeros.
    seed : int
    f_min_hz, f_max_hz : float
        The excited band [Hz]; `f_max_hz` below ``fs_hz / 2``.
    taper_s : float
        Raised-cosine fades [s].
    name : str, optional

    Returns
    -------
    Drive
        ``settings["kind"] == "multisine"``.

    Raises
    ------
    DriveError
        On bad durations, rates, bands or amplitudes, as :func:`make_noise_drive`.

    Examples
    --------
    >>> d = make_multisine_drive(duration_s=20.0, fs_hz=100.0, seed=1,
    ...                          rms={"wheelloader_LF": 0.004})
    >>> round(float(np.std(d.channels["wheelloader_LF"])), 6), float(d.channels["aero_heave"].max())
    (0.004, 0.0)
    """
    where = "make_multisine_drive"
    n, fs_hz = _n_samples(duration_s, fs_hz, where=where)
    f_max_hz = _check_below_nyquist(f_max_hz, "f_max_hz", fs_hz, where=where)
    f_min_hz = _check_positive(f_min_hz, "f_min_hz", where=where)
    if not f_min_hz < f_max_hz:
        raise DriveError(f"{where}: f_min_hz={f_min_hz:g} must be below f_max_hz={f_max_hz:g}")
    amps = _check_amplitudes(rms, "rms", where=where)
    w = _taper(n, fs_hz, taper_s, where=where)
    f = np.fft.rfftfreq(n, 1.0 / fs_hz)
    band = (f >= f_min_hz) & (f <= f_max_hz)
    if not band.any():
        raise DriveError(f"{where}: no line of a {n / fs_hz:g} s record lies in "
                         f"{f_min_hz:g}-{f_max_hz:g} Hz; lengthen the drive or widen the band")
    rng = np.random.default_rng(seed)
    phases = rng.uniform(0.0, 2 * np.pi, (len(RIG_INPUTS), int(band.sum())))
    channels = {}
    for c, ph in zip(RIG_INPUTS, phases):
        a = amps.get(c, 0.0)
        if a <= 0:
            channels[c] = np.zeros(n)
            continue
        spec = np.zeros(f.size, dtype=complex)
        spec[band] = np.exp(1j * ph)
        x = np.fft.irfft(spec, n) * w
        x -= x.mean()
        channels[c] = x * (a / np.std(x))
    settings = {"kind": "multisine", "duration_s": n / fs_hz, "seed": _seed_setting(seed),
                "rms": dict(amps), "f_min_hz": f_min_hz, "f_max_hz": f_max_hz,
                "taper_s": float(taper_s)}
    return Drive(name=_default_name(name, "multisine", _seed_setting(seed)), fs_hz=fs_hz,
                 channels=channels, settings=settings)


def _seed_setting(seed):
    return seed if isinstance(seed, (int, np.integer, type(None))) else repr(seed)


def make_sweep_drive(*, duration_s, fs_hz, amplitude, f_start_hz=0.5, f_stop_hz=25.0,
                     method="logarithmic", channels=WHEELLOADER_INPUTS, taper_s=1.0,
                     name=None):
    """Make a sine-sweep drive on chosen rig inputs.

    Every chosen input carries the same in-phase sweep
    ``amplitude[c] * sin(phase(t))`` from `f_start_hz` at ``t = 0`` to
    `f_stop_hz` at the last sample (``scipy.signal.chirp``), faded in and out
    with a raised cosine over `taper_s` seconds; the others are zero.

    Parameters
    ----------
    duration_s : float
        Drive length [s].
    fs_hz : float
        Sample rate [Hz].
    amplitude : float or Mapping of str to float
        Sine amplitude in SI ([N], [N*m] or [m]): one value for every chosen
        input, or a value per chosen input.
    f_start_hz, f_stop_hz : float
        Start and stop frequency [Hz], both below ``fs_hz / 2``.
    method : {"logarithmic", "linear", "quadratic", "hyperbolic"}
        Frequency law of ``scipy.signal.chirp``; logarithmic spends equal
        time per octave.
    channels : sequence of str
        The rig inputs that carry the sweep (default the four wheelloaders,
        a heave sweep).
    taper_s : float
        Raised-cosine fade-in and fade-out length [s] (0: none).
    name : str, optional
        Drive name (default ``"sweep"``).

    Returns
    -------
    Drive
        With ``settings`` holding the arguments (``kind = "sweep"``).

    Raises
    ------
    DriveError
        If a number is not positive, a frequency is not below ``fs_hz / 2``,
        `method` is unknown, `channels` names an unknown or repeated input,
        `amplitude` misses a chosen input or names another one, or the fades
        do not fit.

    Notes
    -----
    The instantaneous frequency is that of ``scipy.signal.chirp`` with
    ``t1`` the time of the last sample; the sweep starts at zero phase
    (``sin``, i.e. ``chirp(..., phi=-90)``).
    """
    where = "make_sweep_drive"
    n, fs_hz = _n_samples(duration_s, fs_hz, where=where)
    f0 = _check_below_nyquist(f_start_hz, "f_start_hz", fs_hz, where=where)
    f1 = _check_below_nyquist(f_stop_hz, "f_stop_hz", fs_hz, where=where)
    if method not in _SWEEP_METHODS:
        raise DriveError(f"{where}: unknown method {method!r}; use one of "
                         f"{list(_SWEEP_METHODS)}")
    if method in ("logarithmic", "hyperbolic") and f0 == f1:
        raise DriveError(f"{where}: a {method} sweep needs f_start_hz != f_stop_hz")
    if isinstance(channels, str):
        channels = (channels,)
    channels = tuple(channels)
    unknown = [c for c in channels if c not in RIG_INPUTS]
    if unknown or not channels or len(set(channels)) != len(channels):
        raise DriveError(
            f"{where}: channels must be distinct rig inputs from {list(RIG_INPUTS)}, "
            f"got {list(channels)}"
        )
    if isinstance(amplitude, Mapping):
        amps = _check_amplitudes(amplitude, "amplitude", where=where, allowed=channels)
        missing = [c for c in channels if c not in amps]
        if missing:
            raise DriveError(f"{where}: amplitude has no value for {missing}; give one "
                             "per chosen channel or a single number")
    else:
        a = _check_positive(amplitude, "amplitude", where=where, allow_zero=True)
        amps = dict.fromkeys(channels, a)
    w = _taper(n, fs_hz, taper_s, where=where)

    t = np.arange(n) / fs_hz
    sweep = signal.chirp(t, f0=f0, t1=t[-1], f1=f1, method=method, phi=-90.0) * w
    data = {c: amps[c] * sweep if c in amps else np.zeros(n) for c in RIG_INPUTS}
    settings = {"kind": "sweep", "duration_s": n / fs_hz, "amplitude": dict(amps),
                "f_start_hz": f0, "f_stop_hz": f1, "method": method,
                "channels": list(channels), "taper_s": float(taper_s)}
    return Drive(name=_default_name(name, "sweep"), fs_hz=fs_hz, channels=data,
                 settings=settings)


def _random_phase_spectrum(amplitude, rng):
    """One-sided spectrum with the given amplitudes and uniform random phases."""
    return amplitude * np.exp(2j * np.pi * rng.random(amplitude.shape))


def _sinc_inverse(r):
    """Delta in [0, pi] with sin(Delta)/Delta = r, for r in [0, 1]."""
    delta = np.linspace(0.0, np.pi, 4097)
    sinc = np.sinc(delta / np.pi)  # decreasing from 1 to 0
    return np.interp(r, sinc[::-1], delta[::-1])


def make_track_drive(*, duration_s, fs_hz, seed, speed_m_s=50.0, wheelbase_m=2.794,
                     track_width_m=1.778, roughness_m3=8e-6, waviness=2.0,
                     left_right_coherence=0.5, aero=None, aero_f_max_hz=2.0,
                     f_min_hz=0.3, f_max_hz=30.0, taper_s=1.0, name=None):
    """Make a track-like drive: road profiles under the wheels at a constant speed.

    The left and right wheel tracks are random road profiles with the ISO
    8608 displacement PSD ``Gd(n) = roughness_m3 * (n / n0)**-waviness``
    (one-sided [m^3] = [m^2 / (cycles/m)], ``n0 = 0.1`` cycles/m), seen at
    `speed_m_s`: the time-domain one-sided PSD is ``G(f) = Gd(f / v) / v``
    [m^2/Hz], kept only for ``f_min_hz <= f <= f_max_hz``. Each profile is
    synthesized in the frequency domain (``irfft``) with exact amplitudes and
    uniform random phases (seeded). The rear wheels see the front profile of
    their side delayed by ``wheelbase_m / speed_m_s``, applied exactly as a
    phase shift ``exp(-2j*pi*f*delay)`` (any fraction of a sample).

    Parameters
    ----------
    duration_s : float
        Drive length [s]; at least ``1 / f_min_hz``.
    fs_hz : float
        Sample rate [Hz].
    seed : int or numpy.random.SeedSequence
        Seed of the random phases; the same seed gives the same drive.
    speed_m_s : float
        Car speed [m/s]; default 50 m/s (180 km/h).
    wheelbase_m : float
        Wheelbase [m]; default 2.794 m (110 in, the paper car's a + b).
    track_width_m : float
        Distance between the left and right wheel tracks [m]; default
        1.778 m (70 in, the paper car). Sets the left/right coherence.
    roughness_m3 : float
        ``Gd(n0)`` [m^3]; default 8e-6 m^3, the middle of ISO 8608 class A
        (``Gd(n0) < 32e-6``, "very good"), a smooth race-track surface.
    waviness : float
        Exponent ``w`` of the spatial PSD (ISO 8608: 2).
    left_right_coherence : float
        Magnitude-squared coherence ``C`` in [0, 1] between the left and right
        profiles at a wavelength equal to `track_width_m`. The model is
        ``gamma^2(n) = C ** (n * track_width_m)``: long waves (grades, crests)
        are common to both tracks, short ones independent. Default 0.5.
    aero : Mapping of str to float, optional
        Aero input -> RMS in SI ([N] for ``aero_heave``, [N*m] for
        ``aero_roll`` / ``aero_pitch``) of a mean-free, slowly varying load:
        a flat spectrum from `f_min_hz` to `aero_f_max_hz`, random phases,
        each input independent. The static downforce is not included (only
        the dynamic part matters downstream). Absent inputs are zero.
        Example: ``{"aero_heave": 400.0, "aero_pitch": 250.0}``.
    aero_f_max_hz : float
        Upper band edge of the aero loads [Hz] (default 2 Hz: speed and
        ride-height changes are slow compared with the body modes).
    f_min_hz, f_max_hz : float
        Band of the road input [Hz]; `f_min_hz` > 0 removes the unbounded
        long-wave content (a rig cannot replay it), `f_max_hz` < ``fs_hz / 2``.
    taper_s : float
        Raised-cosine fade-in and fade-out on every input [s] (0: none).
    name : str, optional
        Drive name (default ``"track-<seed>"``).

    Returns
    -------
    Drive
        With ``settings`` holding the arguments and derived values
        (``kind = "track"``): ``delay_s`` (wheelbase / speed) and
        ``wheel_rms_m`` (RMS of the untapered wheel-pad displacement).

    Raises
    ------
    DriveError
        If a number is not positive (non-negative for `roughness_m3` and
        `taper_s`), `left_right_coherence` is not in [0, 1], ``f_min_hz >=
        f_max_hz``, `f_max_hz` is not below ``fs_hz / 2``, the drive is
        shorter than ``1 / f_min_hz``, `aero` names a non-aero input, or the
        fades do not fit.

    Notes
    -----
    With the defaults the road band is 0.006 .. 0.6 cycles/m (wavelengths
    167 m .. 1.7 m) and the wheel-pad displacement RMS is
    ``sqrt(Gd(n0) n0^2 (v/f_min - v/f_max))`` = 3.6 mm; for ``w = 2`` the
    wheel-pad velocity is white, ``4 pi^2 Gd(n0) n0^2 v`` = 1.6e-4
    (m/s)^2/Hz, an RMS of 69 mm/s over the band.

    The record is one period of the synthesized profile (a closed lap), so
    the rear delay wraps around: ``rear(t) = front(t - delay)`` holds for
    every ``t`` between ``taper_s + delay`` and ``duration_s - taper_s``, and
    everywhere when ``taper_s = 0``.

    Left and right: per frequency the right phase is the left phase plus an
    independent offset uniform in ``[-D, D]`` with ``sin(D)/D = gamma(n)``,
    so both sides have exactly the PSD and their cross-spectrum averages to
    ``gamma(n) G(f)``.
    """
    where = "make_track_drive"
    n, fs_hz = _n_samples(duration_s, fs_hz, where=where)
    speed = _check_positive(speed_m_s, "speed_m_s", where=where)
    wheelbase = _check_positive(wheelbase_m, "wheelbase_m", where=where)
    track = _check_positive(track_width_m, "track_width_m", where=where)
    roughness = _check_positive(roughness_m3, "roughness_m3", where=where, allow_zero=True)
    waviness = _check_positive(waviness, "waviness", where=where)
    coherence = _check_positive(left_right_coherence, "left_right_coherence", where=where,
                                allow_zero=True)
    if coherence > 1:
        raise DriveError(f"{where}: left_right_coherence must be in [0, 1], got {coherence}")
    f_min = _check_positive(f_min_hz, "f_min_hz", where=where)
    f_max = _check_below_nyquist(f_max_hz, "f_max_hz", fs_hz, where=where)
    if f_min >= f_max:
        raise DriveError(f"{where}: f_min_hz = {f_min:g} Hz must be below f_max_hz = "
                         f"{f_max:g} Hz")
    if n / fs_hz * f_min < 1.0:
        raise DriveError(
            f"{where}: the drive ({n / fs_hz:g} s) is shorter than one period of "
            f"f_min_hz = {f_min:g} Hz; lengthen it to at least {1 / f_min:g} s or raise "
            "f_min_hz"
        )
    aero_rms = _check_amplitudes({} if aero is None else aero, "aero", where=where,
                                 allowed=AERO_INPUTS)
    aero_f_max = _check_below_nyquist(aero_f_max_hz, "aero_f_max_hz", fs_hz, where=where)
    if aero_rms:
        if aero_f_max <= f_min:
            raise DriveError(f"{where}: aero_f_max_hz = {aero_f_max:g} Hz must be above "
                             f"f_min_hz = {f_min:g} Hz")
    w = _taper(n, fs_hz, taper_s, where=where)

    f = np.fft.rfftfreq(n, 1.0 / fs_hz)
    df = fs_hz / n
    band = (f >= f_min) & (f <= f_max)
    n_spatial = f[band] / speed  # cycles/m
    psd = np.zeros_like(f)
    psd[band] = roughness * (n_spatial / ISO8608_N0_CYCLES_M) ** -waviness / speed
    # x(t) = sum A_k cos(2 pi f_k t + phi_k) with A_k = sqrt(2 G(f_k) df), and
    # irfft(X)[t] = sum_k (2 / n) |X_k| cos(...): X_k = (n / 2) A_k exp(i phi_k)
    amp = 0.5 * n * np.sqrt(2.0 * psd * df)

    rng = np.random.default_rng(seed)
    left = _random_phase_spectrum(amp, rng)
    gamma = np.ones_like(f)
    gamma[band] = np.sqrt(coherence ** (n_spatial * track))  # amplitude coherence
    half_width = _sinc_inverse(gamma)
    offset = half_width * rng.uniform(-1.0, 1.0, f.shape)
    right = left * np.exp(1j * offset)
    delay_s = wheelbase / speed
    shift = np.exp(-2j * np.pi * f * delay_s)

    channels = {
        "wheelloader_LF": np.fft.irfft(left, n),
        "wheelloader_RF": np.fft.irfft(right, n),
        "wheelloader_LR": np.fft.irfft(left * shift, n),
        "wheelloader_RR": np.fft.irfft(right * shift, n),
    }
    aero_band = (f >= f_min) & (f <= aero_f_max)
    n_aero = int(aero_band.sum())
    if aero_rms and not n_aero:
        raise DriveError(
            f"{where}: no frequency of the {n / fs_hz:g} s record lies in the aero band "
            f"{f_min:g} .. {aero_f_max:g} Hz; lengthen the drive or widen the band"
        )
    for c in AERO_INPUTS:  # drawn for every input, so each stream is fixed by the seed
        spectrum = _random_phase_spectrum(aero_band.astype(float), rng)
        rms = aero_rms.get(c, 0.0)
        if rms > 0:
            # unit amplitudes of n_aero cosines have variance n_aero / 2
            scale = rms / math.sqrt(n_aero / 2.0) * 0.5 * n
            channels[c] = np.fft.irfft(spectrum * scale, n)
        else:
            channels[c] = np.zeros(n)
    channels = {c: x * w for c, x in channels.items()}

    wheel_rms_m = float(np.sqrt(np.sum(psd) * df))
    settings = {"kind": "track", "duration_s": n / fs_hz, "seed": _seed_setting(seed),
                "speed_m_s": speed, "wheelbase_m": wheelbase, "track_width_m": track,
                "roughness_m3": roughness, "waviness": waviness,
                "left_right_coherence": coherence, "aero": dict(aero_rms),
                "aero_f_max_hz": aero_f_max, "f_min_hz": f_min,
                "f_max_hz": f_max, "taper_s": float(taper_s), "delay_s": delay_s,
                "wheel_rms_m": wheel_rms_m}
    logger.debug("track drive: wheel RMS %.3g mm, rear delay %.4g s", 1e3 * wheel_rms_m,
                 delay_s)
    return Drive(name=_default_name(name, "track", _seed_setting(seed)), fs_hz=fs_hz,
                 channels=channels, settings=settings)


# --------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------


def read_drive(path, *, units=None, channel_map=None, name=None):
    """Read a drive file (the rig-session run-file format, CSV or Parquet).

    Parameters
    ----------
    path : str or os.PathLike
        A ``.csv`` (header row, after any ``#`` comment lines) or ``.parquet`` file
        with a ``time`` column [s] and the 7 rig inputs, or only the 4 wheelloaders
        (a 4-post drive: no aero columns, the aero inputs are zero); other columns
        are ignored.
    units : {"SI", "imperial"}, optional
        Unit system of the values in the file (``--units`` of the CLI). Default: the
        file's unit marker (a CSV's ``units`` column or ``# units: ...`` line, a Parquet
        file's metadata ``units``), else SI. Given, it must agree with the marker.
    channel_map : Mapping of str to str, optional
        ``{canonical name: file column}`` for files whose names differ.
    name : str, optional
        Drive name (default: the file name without its suffix).

    Returns
    -------
    Drive
        SI values; time restarts at 0 s. ``settings`` records the file, the
        units it was read in, where they came from (``units_from``: ``"file"``,
        ``"argument"`` or ``"default"``) and the channel map (``kind = "file"``).

    Raises
    ------
    SessionError
        If the file is missing or unreadable, lacks ``time`` or a wheelloader,
        has some but not all three aero columns, holds NaN/inf or non-numeric
        values, or its time is not uniform (the checks of
        :func:`ident.data.runs.read_run_table`); if its unit marker contradicts
        `units`.
    DriveError
        If the file has too few samples; or if it does not say its units, none are
        given, and its wheel-pad level (the largest pad RMS) read as SI is not what a
        shaker rig plays (:data:`PLAUSIBLE_WHEELLOADER_RMS_MIN_M` to
        :data:`PLAUSIBLE_WHEELLOADER_RMS_M`): an inch file read as metres, or a level
        implausible in either unit system. Given `units` (or a marker) a level over the
        maximum only logs a warning.

    Notes
    -----
    A file that does not say its units, read without `units`, whose level is plausible
    both as SI and as imperial (e.g. 36 mm RMS as SI, 0.9 mm as inches) is read as SI
    (the spec's default) with a warning naming ``--units``; a pad still at every corner
    (an aero-only drive) says nothing about units and is read as SI.
    """
    path = Path(path)
    table = read_run_table(path, units=units, channel_map=channel_map,
                           required=WHEELLOADER_INPUTS, where=f"drive file {path}",
                           units_from="--units")
    n = table.time_s.size
    if n < MIN_DRIVE_SAMPLES:
        raise DriveError(f"drive file {path}: {n} samples; a drive needs at least "
                         f"{MIN_DRIVE_SAMPLES} (the metrics' zero-phase band-pass), and seconds "
                         "of data for RMS values that mean something; give a longer drive")
    units_from = ("file" if table.file_units is not None else
                  "argument" if units is not None else "default")
    _check_plausible(table.channels, where=f"drive file {path}", units=table.units,
                     units_from=units_from)
    settings = {"kind": "file", "path": str(path), "units": table.units,
                "units_from": units_from, "channel_map": dict(channel_map or {}),
                "t0_s": float(table.time_s[0])}
    return Drive(name=name or path.stem, fs_hz=table.fs_hz,
                 channels={c: table.channels[c] for c in rig_inputs_of(table.channels)},
                 settings=settings)


def _check_plausible(channels, *, where, units, units_from):
    """Refuse (units nobody stated) or warn (logging) when the wheel-pad level is not what
    a rig plays in the units read, or (units nobody stated) would be in the other too."""
    rms = {c: float(np.sqrt(np.mean((channels[c] - channels[c].mean()) ** 2)))
           for c in WHEELLOADER_INPUTS if c in channels}
    worst = max(rms, key=rms.get)
    level = rms[worst]
    lo, hi = PLAUSIBLE_WHEELLOADER_RMS_MIN_M, PLAUSIBLE_WHEELLOADER_RMS_M
    if units_from == "default" and 0.0 < level:  # read as SI: values as the file has them
        as_si = lo <= level <= hi
        as_imperial = lo <= to_si(level, "displacement", "imperial") <= hi
        if as_si and not as_imperial:
            return
        if as_si:
            logger.warning(
                "%s: the file does not say its units and was read as SI (the spec's default): "
                "%s has an RMS of %.1f mm; read as inches (%.3g in) it would be %.2f mm, "
                "plausible too; if the file is in inches and pounds give --units imperial, "
                "else --units SI (or a 'units' column in the file) to say so", where, worst,
                1e3 * level, level, 1e3 * to_si(level, "displacement", "imperial"))
            return
        if not as_imperial:
            raise DriveError(
                f"{where}: the wheel pads' level, {worst} with an RMS of {level:.3g} in the "
                f"file's values, is implausible in either unit system ({1e3 * level:.3g} mm "
                f"as SI, {1e3 * to_si(level, 'displacement', 'imperial'):.3g} mm as inches; "
                f"a shaker rig plays {1e3 * lo:g} to {1e3 * hi:.0f} mm RMS) and the file does "
                "not say its units: check its values (a wrong scale or column?), and if "
                "they are right give --units SI or --units imperial (units=...), or a "
                "'units' column in the file")
    if level <= hi:
        return
    said = (f"{where}: {worst} has an RMS of {1e3 * level:.0f} mm read as {units}, more "
            f"than the {1e3 * hi:.0f} mm a shaker rig plays")
    if units_from == "default":
        raise DriveError(
            f"{said}: the file does not say its units (no 'units' column or '# units:' line) "
            "and was read as SI; if it is in inches and pounds give --units imperial "
            "(units='imperial'), or add a column 'units' holding imperial on every row; "
            "--units SI reads it as SI anyway")
    hint = ("is the file in imperial units (--units imperial)?" if units == "SI" else
            "check the file's units")
    logger.warning("%s; the predictions will be absurd (tire forces of tens of kN): %s",
                   said, hint)


def write_drive(drive, path, *, units="SI", overwrite=False):
    """Write a drive file (``time`` and the drive's rig inputs), atomically.

    The columns are ``drive.rig_inputs``: the 7 rig inputs, or the 4
    wheelloaders of a 4-post drive. The file says its unit system: a CSV's last
    column is ``units`` (``SI`` or ``imperial`` on every row), a Parquet file's schema
    metadata has ``units``; :func:`read_drive` reads it back in those units.

    Parameters
    ----------
    drive : Drive
        The drive.
    path : str or os.PathLike
        Output file; ``.csv`` or ``.parquet`` chooses the format.
    units : {"SI", "imperial"}
        Unit system of the written values.
    overwrite : bool
        Replace an existing file.

    Raises
    ------
    TypeError
        If `drive` is not a :class:`Drive`.
    SessionError
        If the file type or `units` is invalid.
    FileExistsError
        If `path` exists and `overwrite` is false.
    """
    if not isinstance(drive, Drive):
        raise TypeError(f"write_drive: drive must be a Drive, got {type(drive).__name__}")
    write_run_table(path, drive.time_s, {c: drive.channels[c] for c in drive.rig_inputs},
                    units=units, overwrite=overwrite)


# --------------------------------------------------------------------------------------
# Resampling
# --------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=8)
def _bandlimited_response(r, n_fft):
    """Real zero-phase frequency response of ``bandlimited_fir(r) / r`` on an ``n_fft`` grid.

    Read-only, ``n_fft // 2 + 1`` bins (an ``rfft`` grid); the ``1 / r`` is the
    scale of the spectrum folding in :func:`decimate_bandlimited`.
    """
    h = bandlimited_fir(r)
    half = (h.size - 1) // 2
    hc = np.zeros(n_fft)
    hc[:half + 1] = h[half:]  # centred on sample 0, circularly: zero phase
    hc[n_fft - half:] = h[:half]
    resp = sp_fft.rfft(hc).real / r  # the imaginary part is rounding (h is symmetric)
    resp.flags.writeable = False
    return resp


def decimate_bandlimited(rows, r, n_out, *, lead="edge"):
    """Zero-phase band-limited decimation by ``r`` of 1-D records, by FFT.

    The same numbers, to rounding, as extending each record by
    ``pad = (FIR_HALF_LENGTH + 1) * r`` samples at each end and calling
    ``resample_bandlimited(extended, 1, r)[pad // r: pad // r + n_out]``, at
    about a sixth of the cost for ``r = 8`` (measured in docs/DESIGN.md).

    Parameters
    ----------
    rows : sequence of array_like
        ``n_rows`` records of the same length ``n_in``, each 1-D.
    r : int
        Decimation factor, >= 1.
    n_out : int
        Samples to return per record, >= 1 and ``(n_out - 1) * r < n_in``.
        Sample ``k`` is at input sample ``k * r`` in time.
    lead : {"edge", "zero"}
        What the record is extended by before its start: its first value or
        zeros. After its end it is always extended by its last value.

    Returns
    -------
    list of ndarray
        ``n_rows`` arrays of ``n_out`` samples, each owning its data.

    Raises
    ------
    ValueError
        If the records are not 1-D of one length long enough for `n_out`, or
        `lead` is unknown.

    Notes
    -----
    Overlap-save: the extended record is cut into segments of ``L = Q r``
    samples (``Q`` = :data:`_DECIMATE_SEGMENT` or less) that overlap by the
    filter's length; each is filtered by a circular convolution (its ``rfft``
    times the FIR's real, zero-phase response) that never wraps into the
    ``Q - 2 * FIR_HALF_LENGTH`` output samples kept from it, and its spectrum is
    folded ``r`` times (aliased, as decimation does) so that the inverse
    transform has ``Q`` points. Short segments keep the transforms in cache.
    """
    if lead not in ("edge", "zero"):
        raise ValueError(f"decimate_bandlimited: lead must be 'edge' or 'zero', got {lead!r}")
    rows = [np.asarray(x, dtype=float) for x in rows]
    n_in = rows[0].shape[-1] if rows else 0
    if (any(x.shape != (n_in,) for x in rows) or n_out < 1 or (n_out - 1) * r >= n_in):
        raise ValueError(
            f"decimate_bandlimited: records of shapes {sorted({x.shape for x in rows})} cannot "
            f"give {n_out} samples decimated by {r}; expected 1-D records of one length "
            f"> {(n_out - 1) * r}")
    if r == 1:
        return [x[:n_out].copy() for x in rows]
    m0 = FIR_HALF_LENGTH  # the filter's half length in output samples
    e = m0 * r  # ... and in input samples: the lead of every segment
    n_fold = min(_DECIMATE_SEGMENT, sp_fft.next_fast_len(n_out + 2 * m0, real=True))
    q = n_fold - 2 * m0  # output samples kept per segment
    seg = n_fold * r
    n_seg = -(-n_out // q)
    resp = _bandlimited_response(r, seg)
    half = n_fold // 2
    buf = np.empty((n_seg - 1) * q * r + seg)  # lead e, the record, its last value
    tail = min(n_in, buf.size - e)
    out = []
    for x in rows:
        buf[:e] = x[0] if lead == "edge" else 0.0
        buf[e:e + tail] = x[:tail]
        buf[e + tail:] = x[-1]
        # segment j starts at input sample j q r - e; its output m0 + i is sample j q + i
        segments = np.lib.stride_tricks.sliding_window_view(buf, seg)[::q * r]
        spec = sp_fft.rfft(segments, axis=-1, workers=-1)
        spec *= resp
        # fold: every r-th sample of the filtered segment from an inverse FFT of n_fold
        # points; bins above seg / 2 are the conjugates of those below
        folded = spec[:, :half + 1].copy()
        for m in range(1, r):
            if 2 * m + 1 <= r:
                folded += spec[:, m * n_fold: m * n_fold + half + 1]
            else:
                hi = (r - m) * n_fold
                folded += np.conj(spec[:, hi - half: hi + 1][:, ::-1])
        y = sp_fft.irfft(folded, n_fold, axis=-1, workers=-1)[:, m0:m0 + q]
        out.append(y.reshape(-1)[:n_out].copy())
    return out


def resample_drive(drive, fs_hz):
    """Resample a drive to another rate (polyphase, ``scipy.signal.resample_poly``).

    The ratio ``fs_hz / drive.fs_hz`` is approximated by a fraction
    ``up / down`` with ``down <= 1000``; it must reproduce `fs_hz` to a
    relative 1e-6 (so a file's rate of 99.99999999 Hz resamples to 100 Hz as
    a plain copy).

    Parameters
    ----------
    drive : Drive
        The drive.
    fs_hz : float
        The new sample rate [Hz] (e.g. the model's).

    Returns
    -------
    Drive
        At `fs_hz`, ``ceil(n_samples * up / down)`` samples, the same name;
        ``settings`` are the original's plus ``resampled_from_hz``,
        ``resample_up`` and ``resample_down``.

    Raises
    ------
    TypeError
        If `drive` is not a :class:`Drive`.
    DriveError
        If `fs_hz` is not positive, or no fraction with a denominator up to
        1000 gives it (the message names the closest rate reachable).

    Notes
    -----
    The anti-aliasing low-pass is a Kaiser-windowed FIR (``beta = 8``, 40
    taps per unit of ``max(up, down)``), cut off at the lower of the two
    Nyquist frequencies: its gain is 1 within 1e-5 up to 0.8 of that
    frequency and below -80 dB above 1.2 of it. Downsampling therefore removes
    the content above the new Nyquist frequency, so peaks and spectra of a
    drive with content there change. The ends are computed with zero
    padding, which suits the tapered drives made here.
    """
    if not isinstance(drive, Drive):
        raise TypeError(f"resample_drive: drive must be a Drive, got {type(drive).__name__}")
    where = f"resample_drive({drive.name!r})"
    fs_new = _check_positive(fs_hz, "fs_hz", where=where)
    ratio = Fraction(fs_new / drive.fs_hz).limit_denominator(_MAX_DENOMINATOR)
    if ratio == 0:
        raise DriveError(f"{where}: fs_hz = {fs_new:g} Hz is too low for a drive at "
                         f"{drive.fs_hz:g} Hz")
    achieved = drive.fs_hz * ratio.numerator / ratio.denominator
    if abs(achieved - fs_new) > _RTOL_RATE * fs_new:
        raise DriveError(
            f"{where}: no ratio up/down with down <= {_MAX_DENOMINATOR} turns "
            f"{drive.fs_hz:.9g} Hz into {fs_new:.9g} Hz (closest: {achieved:.9g} Hz); "
            "choose a rate with a simpler ratio to the drive's"
        )
    up, down = ratio.numerator, ratio.denominator
    if up == down:
        data = drive.channels
    else:
        x = resample_bandlimited(drive.as_array(), up, down, axis=0)
        data = {c: x[:, j] for j, c in enumerate(RIG_INPUTS)}
    data = {c: data[c] for c in drive.rig_inputs}  # a 4-post drive stays one
    settings = dict(drive.settings, resampled_from_hz=drive.fs_hz, resample_up=up,
                    resample_down=down)
    return Drive(name=drive.name, fs_hz=fs_new, channels=data, settings=settings)


# --------------------------------------------------------------------------------------
# Drives and the rig inputs of a model
# --------------------------------------------------------------------------------------


def drive_label(drive):
    """How messages name a drive: ``"drive file <path>"`` if it was read from one, else
    ``"drive '<name>'"``."""
    path = drive.settings.get("path") if isinstance(drive.settings, Mapping) else None
    return f"drive file {path}" if path else f"drive {drive.name!r}"


def check_drive_inputs(drive, rig_inputs, *, model=None):
    """Refuse a drive that excites rig inputs a model does not have.

    A model identified on a 4-post rig (no aero actuators) has the rig inputs
    ``wheelloader_XX`` only: it knows nothing of the aero loads, so a drive
    with aero content cannot be predicted on it. A drive whose extra channels
    are all exactly zero (or absent: a 4-post drive) is accepted: it asks for
    nothing the model lacks.

    Parameters
    ----------
    drive : Drive
    rig_inputs : sequence of str
        The model's rig inputs (e.g. ``VehicleModel.rig_inputs``,
        ``LoopPlant.rig_inputs``).
    model : str, optional
        The model's name, for the message.

    Raises
    ------
    DriveError
        If a channel not in `rig_inputs` has a nonzero sample; the message
        names the drive file and the channels.

    Examples
    --------
    >>> from ident.data.channels import WHEELLOADER_INPUTS
    >>> d = make_sweep_drive(duration_s=4.0, fs_hz=100.0, amplitude={"aero_heave": 500.0},
    ...                      f_start_hz=1.0, f_stop_hz=10.0, channels=["aero_heave"])
    >>> check_drive_inputs(d, WHEELLOADER_INPUTS, model="4-post car")
    Traceback (most recent call last):
    ...
    ident.errors.DriveError: drive 'sweep': has nonzero content on ['aero_heave'], but model '4-post car' has no such rig input (it was identified from a session with the rig inputs ['wheelloader_LF', 'wheelloader_RF', 'wheelloader_LR', 'wheelloader_RR'], e.g. a 4-post rig without aero actuators); remove those columns from the drive (or zero them), or predict with a model identified with them
    """
    extra = [c for c in RIG_INPUTS if c not in rig_inputs and np.any(drive.channels[c] != 0)]
    if extra:
        who = f"model {model!r}" if model else "the model"
        raise DriveError(
            f"{drive_label(drive)}: has nonzero content on {extra}, but {who} has no such rig "
            f"input (it was identified from a session with the rig inputs {list(rig_inputs)}, "
            "e.g. a 4-post rig without aero actuators); remove those columns from the drive "
            "(or zero them), or predict with a model identified with them")
