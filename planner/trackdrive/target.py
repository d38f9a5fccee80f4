"""The target of a drive iteration: what the car logged at the track, and its aero loads.

:func:`make_target` turns one or more track logs (:class:`ident.data.tracklog.TrackLog`)
into a :class:`DriveTarget`: the response channels the rig drive must reproduce (shock
travels, and ride heights and accelerations where logged and the model has them), as their
dynamic part at the model's sample rate, and the aero inputs the drive will carry (from the
logged speed through the team's aero model, from logged aero loads, or none on a 4-post rig),
also as their dynamic part: the mean aero load is the aeroloaders' static preload, which a
rig applies before the drive plays (the spec's static corner loads include it), so a drive
never ramps the whole downforce on in its first second.

Several logs are played one after the other: each log's channels lose their own mean, are
faded in and out over ``taper_s`` (the rig starts and ends each at rest), and are joined
end to end. A target's times are those of the joined record (the first log starts at 0 s).

The band
--------
A drive reproduces its target over ``band_hz`` (default 0.5 Hz up to 30 Hz, or to the
highest frequency the logs' rate supports). Below it the rig cannot reproduce what a track
gives (grades, the car's slow pitch and heave under aero): the target's content there is
left out, and the drive has none. A log must be sampled at 2.5 times the band's upper edge or
faster (:data:`MIN_RATE_FACTOR`), and the band must reach the metrics' 20 Hz.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np
from scipy import signal

from ident.data.channels import AERO_INPUTS, CORNERS
from ident.data.drive import fade_window, resample_bandlimited
from ident.data.timebase import TimeRecord
from planner.errors import PlannerError

__all__ = [
    "DriveTarget",
    "make_target",
    "segment_taper",
    "spectral_derivative",
    "TARGET_KINDS",
    "DEFAULT_BAND_HZ",
    "MIN_RATE_FACTOR",
    "METRIC_BAND_TOP_HZ",
    "AERO_SOURCES",
    "AERO_SPEED_LOWPASS_HZ",
    "AERO_RIDE_HEIGHT_LOWPASS_HZ",
]

log = logging.getLogger(__name__)

#: The response kinds a drive may reproduce, in this order.
TARGET_KINDS = ("shock_travel", "ride_height", "wheel_accel", "chassis_accel")
#: Default band of the iteration [Hz]: from 0.5 Hz (below it a track's content is grades
#: and the car's slow aero platform, not a rig's) to 30 Hz (the top of the road content
#: that moves the car; above it the tires filter it), lowered to the log's rate / 2.5.
DEFAULT_BAND_HZ = (0.5, 30.0)
#: A log must be sampled at this many times the band's upper edge (a band-limited signal
#: needs 2 samples per period; 2.5 leaves the anti-aliasing filter its transition band).
MIN_RATE_FACTOR = 2.5
#: The metrics' band ends at 20 Hz: a drive's band must reach it.
METRIC_BAND_TOP_HZ = 20.0
#: Where a drive's aero inputs come from.
AERO_SOURCES = ("auto", "model", "logged", "none")
#: Low-pass of the logged speed [Hz] before the aero model: a car's speed changes over
#: seconds, and a speed sensor's noise, passed through the model, would become a broadband
#: aero command (0.5 % speed noise: 17 N RMS of the 1-20 Hz heave against 6 N of true load).
AERO_SPEED_LOWPASS_HZ = 2.0
#: Low-pass of the logged ride heights [Hz] before an aero map: the platform moves at the
#: body modes (1-4 Hz); above that the lasers' noise and the road would drive the map.
AERO_RIDE_HEIGHT_LOWPASS_HZ = 5.0
#: Largest denominator of a resampling ratio (as :func:`ident.data.drive.resample_drive`).
_MAX_DENOMINATOR = 1000


@dataclass(frozen=True, eq=False)
class DriveTarget(TimeRecord):
    """The response a rig drive must reproduce, and the aero loads it carries.

    Attributes
    ----------
    name : str
    fs_hz : float
        Sample rate [Hz] (the model's, or the logs').
    channels : dict of str to ndarray, shape (n_samples,)
        Target response channels (canonical names, SI): each log's dynamic part (its mean
        removed), faded at the ends of each log, joined.
    aero : dict of str to ndarray or None
        ``aero_heave`` [N], ``aero_roll``, ``aero_pitch`` [N*m] of the drive: each log's
        loads less their mean (the mean is the aeroloaders' static preload, applied before
        a drive plays, as the spec's static corner loads include it; in
        ``settings["aero_preload"]``, one per log), faded as the targets; or None (no aero
        inputs: a 4-post rig, or none given).
    band_hz : (float, float)
        The band the drive reproduces [Hz].
    segments : tuple of (str, int, int)
        Each log's name, first sample and sample count in the joined record.
    taper_s : float
        The fades at the ends of each log [s].
    settings : dict
        Where the target came from (logs, aero source, rates, channels left out).
    """

    name: str
    fs_hz: float
    channels: dict
    aero: dict | None
    band_hz: tuple
    segments: tuple
    taper_s: float
    settings: dict = field(default_factory=dict)

    def interior(self):
        """ndarray of bool, shape (n_samples,): the samples outside every log's fades, where
        a drive is judged."""
        mask = np.zeros(self.n_samples, bool)
        m = int(round(self.taper_s * self.fs_hz))
        for _, start, count in self.segments:
            mask[start + m:start + count - m] = True
        return mask


def segment_taper(n, fs_hz, taper_s, *, where="target",
                  fix="give a longer log or a shorter --taper"):
    """Raised-cosine fade-in and fade-out over `taper_s` [s] at both ends, shape (n,).

    Raises
    ------
    PlannerError
        If `taper_s` is not a finite time >= 0, or the record is shorter than four fades
        (the message ends with `fix`).
    """
    try:
        taper_s = float(taper_s)
    except (TypeError, ValueError):
        taper_s = float("nan")
    if not np.isfinite(taper_s) or taper_s < 0:
        raise PlannerError(f"{where}: the fade (--taper) must be a time >= 0 [s]; give e.g. "
                           "--taper 1.0")
    if 4 * int(round(taper_s * fs_hz)) > n:
        raise PlannerError(f"{where}: {n / fs_hz:g} s is too short for fades of "
                           f"{taper_s:g} s at each end (at least 4 x the fade); {fix}")
    return fade_window(n, fs_hz, taper_s)


def spectral_derivative(x, fs_hz):
    """The time derivative of a record by the FFT (exact for its band-limited content).

    Parameters
    ----------
    x : array_like, shape (n,)
        The record (e.g. a shock travel [m]), faded to zero at its ends.
    fs_hz : float
        Its sample rate [Hz].

    Returns
    -------
    ndarray, shape (n,)
        ``dx/dt`` (e.g. the shock velocity [m/s]).
    """
    x = np.asarray(x, float)
    f = np.fft.rfftfreq(x.size, 1.0 / fs_hz)
    return np.fft.irfft(2j * np.pi * f * np.fft.rfft(x), x.size)


def _resample(x, fs_from, fs_to, where):
    if abs(fs_from - fs_to) <= 1e-9 * fs_to:
        return np.asarray(x, float)
    ratio = Fraction(fs_to / fs_from).limit_denominator(_MAX_DENOMINATOR)
    if abs(fs_from * ratio - fs_to) > 1e-6 * fs_to:
        raise PlannerError(f"{where}: no ratio up/down with down <= {_MAX_DENOMINATOR} turns "
                           f"{fs_from:g} Hz into {fs_to:g} Hz; resample the log to a rate "
                           "with a simpler ratio to the model's")
    return resample_bandlimited(np.asarray(x, float), ratio.numerator, ratio.denominator)


def _band(band_hz, fs_log, fs_work, where):
    """The checked band: default lowered to what the rates allow; refused below 20 Hz."""
    top_allowed = min(fs_log, fs_work) / MIN_RATE_FACTOR
    if band_hz is None:
        lo, hi = DEFAULT_BAND_HZ[0], min(DEFAULT_BAND_HZ[1], top_allowed)
        if hi < METRIC_BAND_TOP_HZ:
            rate, who = (fs_log, "the log is") if fs_log <= fs_work else (fs_work, "the model is")
            raise PlannerError(
                f"{where}: {who} sampled at {rate:g} Hz, below {MIN_RATE_FACTOR:g} x the "
                f"metrics' {METRIC_BAND_TOP_HZ:g} Hz band; log at "
                f"{MIN_RATE_FACTOR * METRIC_BAND_TOP_HZ:g} Hz or faster")
        return lo, hi
    try:
        lo, hi = (float(v) for v in band_hz)
    except (TypeError, ValueError):
        raise PlannerError(f"{where}: band {band_hz!r} must be two frequencies LOW,HIGH "
                           "[Hz]") from None
    if not 0 < lo < hi:
        raise PlannerError(f"{where}: band {lo:g}-{hi:g} Hz must satisfy 0 < low < high")
    if hi > top_allowed:
        rate = min(fs_log, fs_work)
        raise PlannerError(
            f"{where}: the band's top {hi:g} Hz needs a sample rate of {MIN_RATE_FACTOR:g} x "
            f"{hi:g} = {MIN_RATE_FACTOR * hi:g} Hz, but the {'log' if fs_log <= fs_work else 'model'}"
            f" is at {rate:g} Hz; lower the band's top to {top_allowed:g} Hz or log faster")
    if hi < METRIC_BAND_TOP_HZ:
        raise PlannerError(f"{where}: band top {hi:g} Hz is below the metrics' "
                           f"{METRIC_BAND_TOP_HZ:g} Hz; a drive must reach it")
    return lo, hi


def _aero_source(source, aero, logs, rig_inputs, where):
    if source not in AERO_SOURCES:
        raise PlannerError(f"{where}: aero source {source!r} is not one of {list(AERO_SOURCES)}")
    has_aero_inputs = all(a in rig_inputs for a in AERO_INPUTS)
    logged = all(all(a in lg.channels for a in AERO_INPUTS) for lg in logs)
    if source == "auto":
        source = "model" if aero is not None else ("logged" if logged and has_aero_inputs
                                                   else "none")
    if source == "model" and aero is None:
        raise PlannerError(f"{where}: aero source 'model' needs an aero model (--aero AERO.toml)")
    if source == "logged" and not logged:
        lacking = next(lg.name for lg in logs if not all(a in lg.channels for a in AERO_INPUTS))
        raise PlannerError(f"{where}: aero source 'logged' but log {lacking!r} has no "
                           f"{'/'.join(AERO_INPUTS)} channels; map them, or give an aero model")
    if source in ("model", "logged") and not has_aero_inputs:
        raise PlannerError(f"{where}: the model has no aero inputs (identified on a 4-post "
                           "rig); leave out the aero model and the logged aero loads "
                           "(--aero-source none)")
    return source


def _lowpass(x, f_hz, fs_hz):
    """Zero-phase 4th-order Butterworth low-pass at `f_hz` (none at or above Nyquist)."""
    x = np.asarray(x, float)
    if f_hz >= 0.5 * fs_hz or x.size < 30:
        return x
    sos = signal.butter(4, f_hz, "lowpass", fs=fs_hz, output="sos")
    return signal.sosfiltfilt(sos, x)


def _log_aero(lg, aero, source, where):
    """The aero loads of one log (SI), or None."""
    if source == "logged":
        return {a: np.asarray(lg.channels[a], float) for a in AERO_INPUTS}
    if source != "model":
        return None
    if "speed" not in lg.channels:
        raise PlannerError(f"{where}: log {lg.name!r} has no speed channel, which the aero "
                           "model needs; map the car's speed as 'speed' (m/s), or give logged "
                           "aero loads")
    kw = {}
    if aero.needs_ride_heights:
        rh = [f"ride_height_{c}" for c in CORNERS]
        lacking = [c for c in rh if c not in lg.channels]
        if lacking:
            raise PlannerError(f"{where}: the aero model {aero.name!r} is a ride-height map "
                               f"but log {lg.name!r} has no {lacking}; map the ride heights or "
                               "give a model by speed")
        ch = lg.channels
        kw = {"ride_height_front_m": _lowpass(0.5 * (ch["ride_height_LF"] + ch["ride_height_RF"]),
                                              AERO_RIDE_HEIGHT_LOWPASS_HZ, lg.fs_hz),
              "ride_height_rear_m": _lowpass(0.5 * (ch["ride_height_LR"] + ch["ride_height_RR"]),
                                             AERO_RIDE_HEIGHT_LOWPASS_HZ, lg.fs_hz)}
    speed = _lowpass(np.abs(np.asarray(lg.channels["speed"], float)), AERO_SPEED_LOWPASS_HZ,
                     lg.fs_hz)
    loads = aero.loads(np.maximum(speed, 0.0), **kw)
    if loads.outside_share > 0:
        log.warning("%s: log %r: %.1f %% of the samples lie outside the aero model %r's "
                    "table (extrapolated or clamped)", where, lg.name,
                    100 * loads.outside_share, aero.name)
    return {a: np.asarray(loads.channels[a], float) for a in AERO_INPUTS}


def make_target(logs, *, model_outputs, rig_inputs, fs_hz=None, band_hz=None, aero=None,
                aero_source="auto", targets=None, taper_s=1.0, name=None, where="target"):
    """Build the target of a drive iteration from track logs.

    Parameters
    ----------
    logs : sequence of ident.data.tracklog.TrackLog
        The logs, played one after the other; one sample rate, and each holding the
        target channels.
    model_outputs : sequence of str
        The model's output channels: a logged channel the model lacks is left out (a
        shock travel then becomes a shock-velocity target if the model has that).
    rig_inputs : sequence of str
        The model's rig inputs (without aero inputs, no aero loads may be given).
    fs_hz : float, optional
        The rate to work at [Hz] (the model's); default the logs'. The logs are resampled
        (band-limited) to it.
    band_hz : (float, float), optional
        Band the drive reproduces [Hz]; default :data:`DEFAULT_BAND_HZ`, its top lowered
        to the lower rate / :data:`MIN_RATE_FACTOR`.
    aero : ident.models.aero.AeroModel, optional
        The team's downforce and balance model (aero loads from the logged speed).
    aero_source : {"auto", "model", "logged", "none"}
        ``auto``: the aero model if given, else the logs' aero channels if every log has
        them and the model has aero inputs, else none. The aero model reads the logged
        speed low-passed at :data:`AERO_SPEED_LOWPASS_HZ` (and a map the ride heights at
        :data:`AERO_RIDE_HEIGHT_LOWPASS_HZ`), zero phase.
    targets : sequence of str, optional
        The channels to reproduce (canonical names or kinds such as ``ride_height``);
        default every logged channel of :data:`TARGET_KINDS` the model has. A named
        channel the model cannot produce is refused.
    taper_s : float
        Fades at the ends of each log [s].
    name : str, optional
        Default: the first log's name (``+N`` for more logs).
    where : str
        Who asks, first in messages.

    Returns
    -------
    DriveTarget

    Raises
    ------
    PlannerError
        No logs; logs at different rates or with different channels; a rate below 2.5
        times the band; a band below the metrics'; an aero source without its data; aero
        loads for a model without aero inputs; a named target the model cannot produce;
        a shock travel whose corner the model can give neither as travel nor as velocity.
    """
    logs = list(logs)
    if not logs:
        raise PlannerError(f"{where}: no track logs; give at least one")
    fs_log = float(logs[0].fs_hz)
    for lg in logs[1:]:
        if abs(lg.fs_hz - fs_log) > 1e-6 * fs_log:
            raise PlannerError(f"{where}: log {lg.name!r} is sampled at {lg.fs_hz:g} Hz but "
                               f"{logs[0].name!r} at {fs_log:g} Hz; give logs of one rate")
    fs_work = fs_log if fs_hz is None else float(fs_hz)
    band = _band(band_hz, fs_log, fs_work, where)
    outputs = set(model_outputs)

    logged = [f"{k}_{c}" for k in TARGET_KINDS for c in CORNERS
              if all(f"{k}_{c}" in lg.channels for lg in logs)]
    for lg in logs:
        extra = [c for c in lg.channels if c.rpartition("_")[0] in TARGET_KINDS
                 and c not in logged]
        if extra:
            raise PlannerError(f"{where}: log {lg.name!r} has {extra} but another log has not; "
                               "give logs with the same channels")
    if targets is not None:
        wanted = []
        for t in targets:
            t = str(t).strip()
            names = [f"{t}_{c}" for c in CORNERS] if t in TARGET_KINDS else [t]
            for nm in names:
                if nm not in logged:
                    raise PlannerError(f"{where}: target {nm!r} is not in the logs (they hold "
                                       f"{logged}); name logged channels")
                derived = nm.startswith("shock_travel_") and \
                    nm.replace("travel", "velocity") in outputs
                if nm not in outputs and not derived:
                    raise PlannerError(
                        f"{where}: target {nm!r} cannot be reached: the model has no such "
                        "output; identify a model from a session with that channel, or "
                        "leave it out of --targets")
                wanted.append(nm)
        chosen = list(dict.fromkeys(wanted))
        absent = [f"shock_travel_{c}" for c in CORNERS if f"shock_travel_{c}" not in chosen]
        if absent:  # the loop is linearized at every corner's logged shock speed
            raise PlannerError(f"{where}: --targets must include the shock travels of every "
                               f"corner (missing {', '.join(absent)}); add shock_travel")
    else:
        chosen = [c for c in logged if c in outputs or c.startswith("shock_travel_")]
        left_out = [c for c in logged if c not in chosen]
        if left_out:
            log.warning("%s: the model has no output for the logged %s; they are left out of "
                        "the target", where, ", ".join(left_out))
    mapped = {}
    for c in chosen:
        if c in outputs:
            mapped[c] = c
        elif c.startswith("shock_travel_") and c.replace("travel", "velocity") in outputs:
            mapped[c] = c.replace("travel", "velocity")
            log.info("%s: the model has no %s output: matched as %s (the travel's derivative)",
                     where, c, mapped[c])
        else:
            raise PlannerError(f"{where}: {c} cannot be reached: the model has neither it nor "
                               f"{c.replace('travel', 'velocity')}; give a model with the "
                               "shock velocities of every corner")
    source = _aero_source(aero_source, aero, logs, rig_inputs, where)

    parts, aeros, preloads, segments, start = {c: [] for c in chosen}, [], [], [], 0
    for lg in logs:
        n_log = lg.n_samples
        n = int(np.ceil(n_log * fs_work / fs_log - 1e-9))
        w = segment_taper(n, fs_work, taper_s, where=f"{where}: log {lg.name!r}")
        for c in chosen:
            x = np.asarray(lg.channels[c], float)
            x = _resample(x - x.mean(), fs_log, fs_work, where)[:n]
            if mapped[c] != c:  # travel to velocity: the spectral derivative
                x = spectral_derivative(x, fs_work)
            parts[c].append(w * (x - x.mean()))
        a = _log_aero(lg, aero, source, where)
        if a is not None:  # the dynamic part: the mean is the aeroloaders' static preload
            preloads.append({k: float(np.mean(v)) for k, v in a.items()})
            aeros.append({k: w * _resample(v - np.mean(v), fs_log, fs_work, where)[:n]
                          for k, v in a.items()})
        segments.append((lg.name, start, n))
        start += n
    channels = {mapped[c]: np.concatenate(parts[c]) for c in chosen}
    aero_ch = None if not aeros else {k: np.concatenate([a[k] for a in aeros])
                                      for k in AERO_INPUTS}
    name = name or (logs[0].name + (f"+{len(logs) - 1}" if len(logs) > 1 else ""))
    settings = {"logs": [lg.settings.get("source", lg.name) for lg in logs],
                "log_fs_hz": fs_log, "aero_source": source,
                "aero_model": None if aero is None or source != "model" else aero.name,
                "aero_preload": [dict(p) for p in preloads],
                "derived": {mapped[c]: c for c in chosen if mapped[c] != c},
                "left_out": [c for c in logged if c not in chosen]}
    return DriveTarget(name=name, fs_hz=fs_work, channels=channels, aero=aero_ch,
                       band_hz=band, segments=tuple(segments), taper_s=float(taper_s),
                       settings=settings)
