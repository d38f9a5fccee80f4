"""The virtual track: a known car driven over a road, logged as a data logger would.

Issue 27 builds rig drives from track logs; this module makes the truth those drives are
checked against. A *track run* (:func:`make_track_run`) is a car at a varying speed over
two random road tracks (left and right), with the aero loads of an aero model
(:class:`ident.models.aero.AeroModel`) at that speed. It is returned as the rig drive that
reproduces the track exactly on a shaker rig (the road under each wheel as the wheelloader
displacements, the aero loads as the aero inputs), so that a known car can run it through the
project's one simulator. :func:`log_track_run` runs a known car over it and writes what its
logger would record: shock travels (damper potentiometers with zero offsets), ride heights
(lasers: the static ride height included), wheel and chassis accelerations and the speed,
each with white sensor noise, as an :class:`ident.data.tracklog.TrackLog`.

The road
--------
Each track's profile is a random ISO 8608 profile in *space* (displacement PSD
``Gd(n) = roughness_m3 (n / n0)^-waviness`` over ``road_band_cycles_m``), synthesized once
(:func:`ident.data.drive.make_track_drive` at 1 m/s on a fine distance grid: the rear wheels
see their side's profile one wheelbase later, the left and right tracks cohere over long
waves) and read at the front axle's position ``x(t) = integral of speed``. So the road's
time-domain spectrum moves with the speed, as on a real lap (short waves give higher
frequencies on the straights). The profile is read on a time grid ``oversample`` times finer
than the log's and brought to the log's rate by a band-limited decimation (the road's content
above the log's Nyquist frequency is removed, not aliased).

The speed
---------
:func:`make_speed_trace`: a smooth random trace between ``speed_range_m_s`` (straights and
corners), its content between 0.01 Hz and ``speed_f_max_hz``.

Examples
--------
>>> run = make_track_run(duration_s=20.0, fs_hz=100.0, seed=1)
>>> run.drive.n_samples, round(float(run.speed_m_s.min()), 1) >= 35.0
(2000, True)
"""

from __future__ import annotations

import logging
import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from ident.data.channels import AERO_INPUTS, CORNERS, WHEELLOADER_INPUTS
from ident.data.drive import Drive, fade_window, make_track_drive, resample_bandlimited
from ident.data.tracklog import TrackLog
from ident.errors import DriveError
from ident.sim.closedloop import simulate

__all__ = [
    "TrackRun",
    "make_speed_trace",
    "make_track_run",
    "log_track_run",
    "LOGGED_KINDS",
]

log = logging.getLogger(__name__)

#: The response kinds a virtual logger records by default: damper potentiometers and ride
#: height lasers (accelerometers on request).
LOGGED_KINDS = ("shock_travel", "ride_height")
#: Distance step of the synthesized road profile [m]: 25 samples per wavelength at the
#: shortest default wave (0.5 m), so that reading it by linear interpolation loses at most
#: 0.7 % of that wave's amplitude.
ROAD_STEP_M = 0.02
#: Default spatial band of the road [cycles/m]: wavelengths from 333 m (crests, grades) to
#: 0.5 m (joints, ripples); at 35-75 m/s that is 0.1-150 Hz before the log's own band.
ROAD_BAND_CYCLES_M = (0.003, 2.0)
#: Static ride heights the lasers read with the car at rest [m] (front, rear).
STATIC_RIDE_HEIGHT_M = (0.050, 0.070)
#: Zero offsets of the damper potentiometers [m] (LF, RF, LR, RR): logs are never zeroed.
POT_OFFSET_M = (0.031, 0.029, 0.042, 0.040)


def _taper(n, fs_hz, taper_s):
    """Raised-cosine fade-in and fade-out over `taper_s` at each end, shape (n,)."""
    if 2 * int(round(taper_s * fs_hz)) > n:
        raise DriveError(f"virtual track: the fades of {taper_s:g} s do not fit a record of "
                         f"{n / fs_hz:g} s; shorten taper_s")
    return fade_window(n, fs_hz, taper_s)


def make_speed_trace(*, duration_s, fs_hz, seed, speed_range_m_s=(35.0, 75.0),
                     speed_f_max_hz=0.1):
    """A smooth random speed trace: straights and corners.

    Parameters
    ----------
    duration_s, fs_hz : float
        Length [s] and sample rate [Hz].
    seed : int
        Seed of the random phases.
    speed_range_m_s : (float, float)
        The slowest and fastest speed [m/s]; the trace reaches both.
    speed_f_max_hz : float
        Upper edge of its content [Hz] (default 0.1 Hz: a corner every 10 s or so).

    Returns
    -------
    ndarray, shape (n_samples,)
        Speed [m/s].
    """
    lo, hi = (float(v) for v in speed_range_m_s)
    if not 0 < lo < hi:
        raise DriveError(f"make_speed_trace: speed_range_m_s = {speed_range_m_s!r} must be two "
                         "speeds 0 < slow < fast [m/s]")
    n = int(round(duration_s * fs_hz))
    f = np.fft.rfftfreq(n, 1.0 / fs_hz)
    rng = np.random.default_rng(seed)
    band = (f >= 0.01) & (f <= speed_f_max_hz)
    if not band.any():
        raise DriveError(f"make_speed_trace: a {duration_s:g} s trace has no frequency in "
                         f"0.01 .. {speed_f_max_hz:g} Hz; lengthen it")
    spectrum = np.where(band, np.exp(2j * np.pi * rng.uniform(size=f.size)), 0.0)
    s = np.fft.irfft(spectrum, n)
    s = (s - s.min()) / (s.max() - s.min())
    return lo + (hi - lo) * s


@dataclass(frozen=True, eq=False)
class TrackRun:
    """A car's run on the virtual track, as the rig drive that reproduces it.

    Attributes
    ----------
    drive : ident.data.drive.Drive
        The road under each wheel (``wheelloader_XX`` [m]) and, with an aero model, the
        dynamic part of the aero loads at the run's speed (``aero_heave`` [N], ``aero_roll``,
        ``aero_pitch`` [N*m]: their mean is the aeroloaders' static preload, in
        ``settings["aero_preload"]``, as on a rig), both faded in and out over
        ``settings["taper_s"]`` (the car starts and ends at rest on a rig).
    speed_m_s : ndarray, shape (n_samples,)
        The car's speed [m/s].
    settings : dict
        The arguments and derived values (distance covered, road RMS).
    """

    drive: Drive
    speed_m_s: np.ndarray
    settings: dict = field(default_factory=dict)


def make_track_run(*, duration_s, fs_hz, seed, speed_range_m_s=(35.0, 75.0),
                   speed_f_max_hz=0.1, wheelbase_m=2.794, track_width_m=1.778,
                   roughness_m3=8e-6, waviness=2.0, left_right_coherence=0.5,
                   road_band_cycles_m=ROAD_BAND_CYCLES_M, aero=None, taper_s=1.0,
                   oversample=8, name=None):
    """A run on the virtual track: a road at a varying speed, with aero loads.

    Parameters
    ----------
    duration_s, fs_hz : float
        Length [s] and sample rate [Hz] of the run.
    seed : int
        Seed of the speed trace and the road (the same seed, the same run).
    speed_range_m_s : (float, float)
        Slowest and fastest speed [m/s] (:func:`make_speed_trace`).
    speed_f_max_hz : float
        Upper edge of the speed trace's content [Hz].
    wheelbase_m, track_width_m : float
        The car's wheelbase and track [m] (the rear wheels follow the front ones; the left
        and right tracks cohere over waves longer than the track width).
    roughness_m3, waviness, left_right_coherence : float
        The road's ISO 8608 displacement PSD at 0.1 cycles/m [m^3], its exponent, and the
        left/right coherence at a wavelength of one track width
        (:func:`ident.data.drive.make_track_drive`).
    road_band_cycles_m : (float, float)
        The road's spatial band [cycles/m].
    aero : ident.models.aero.AeroModel, optional
        Aero loads from the speed (a model that needs ride heights is refused: the virtual
        track drives the aero loads open loop). None: no aero inputs (a 4-post drive).
    taper_s : float
        Fade-in and fade-out of every input [s].
    oversample : int
        Time steps per sample at which the road is read before the band-limited decimation.
    name : str, optional
        Default ``"track-run-<seed>"``.

    Returns
    -------
    TrackRun
    """
    where = "make_track_run"
    if aero is not None and getattr(aero, "needs_ride_heights", False):
        raise DriveError(f"{where}: the aero model {aero.name!r} needs ride heights; the "
                         "virtual track computes aero loads from the speed only: give a "
                         "'constant' or 'speed_table' model")
    for key, value in (("duration_s", duration_s), ("fs_hz", fs_hz), ("taper_s", taper_s)):
        if isinstance(value, bool) or not isinstance(value, numbers.Real) \
                or not math.isfinite(value) or value < 0 or (value == 0 and key != "taper_s"):
            raise DriveError(f"{where}: {key} = {value!r} must be a finite number "
                             f"{'>= 0' if key == 'taper_s' else '> 0'}")
    if isinstance(oversample, bool) or not isinstance(oversample, numbers.Real) \
            or oversample != int(oversample) or oversample < 1:
        raise DriveError(f"{where}: oversample = {oversample!r} must be an integer >= 1")
    r = int(oversample)
    n = int(round(duration_s * fs_hz))
    if n < 2:
        raise DriveError(f"{where}: duration_s * fs_hz = {duration_s * fs_hz:g} samples; a run "
                         "needs at least 2: lengthen it")
    fine = n * r
    speed_fine = make_speed_trace(duration_s=duration_s, fs_hz=fs_hz * r, seed=seed,
                                  speed_range_m_s=speed_range_m_s,
                                  speed_f_max_hz=speed_f_max_hz)[:fine]
    x = np.concatenate([[0.0], np.cumsum(0.5 * (speed_fine[1:] + speed_fine[:-1]))
                        / (fs_hz * r)])
    n_lo, n_hi = (float(v) for v in road_band_cycles_m)
    length_m = float(x[-1]) + 2.0 * wheelbase_m + 1.0 / n_lo
    road = make_track_drive(duration_s=length_m, fs_hz=1.0 / ROAD_STEP_M, seed=seed,
                            speed_m_s=1.0, wheelbase_m=wheelbase_m, track_width_m=track_width_m,
                            roughness_m3=roughness_m3, waviness=waviness,
                            left_right_coherence=left_right_coherence, f_min_hz=n_lo,
                            f_max_hz=n_hi, taper_s=0.0, name="road")
    grid = np.arange(road.n_samples) * ROAD_STEP_M
    at = x + wheelbase_m  # the front axle, one wheelbase into the profile (the rear's start)
    channels = {}
    for c in WHEELLOADER_INPUTS:
        fine_x = np.interp(at, grid, road.channels[c])
        channels[c] = resample_bandlimited(fine_x, 1, r)[:n]
    speed = speed_fine[::r][:n]
    preload = None
    if aero is not None:
        loads = aero.loads(speed)
        preload = {c: float(np.mean(loads.channels[c])) for c in AERO_INPUTS}
        channels.update({c: np.asarray(loads.channels[c], float) - preload[c]
                         for c in AERO_INPUTS})
    w = _taper(n, fs_hz, taper_s)
    channels = {c: v * w for c, v in channels.items()}
    name = name or f"track-run-{seed}"
    settings = {"kind": "virtual-track", "duration_s": n / fs_hz, "seed": seed,
                "speed_range_m_s": tuple(map(float, speed_range_m_s)),
                "speed_f_max_hz": float(speed_f_max_hz), "wheelbase_m": float(wheelbase_m),
                "track_width_m": float(track_width_m), "roughness_m3": float(roughness_m3),
                "waviness": float(waviness), "left_right_coherence": float(left_right_coherence),
                "road_band_cycles_m": (n_lo, n_hi), "taper_s": float(taper_s),
                "distance_m": float(x[-1]), "aero": None if aero is None else aero.name,
                "aero_preload": preload,
                "wheel_rms_m": float(np.sqrt(np.mean(np.square(channels["wheelloader_LF"]))))}
    log.debug("virtual track %s: %.0f m at %.0f-%.0f m/s", name, x[-1], speed.min(), speed.max())
    return TrackRun(drive=Drive(name=name, fs_hz=float(fs_hz), channels=channels,
                                settings=settings), speed_m_s=speed, settings=settings)


def log_track_run(plant, run, setup, *, noise=0.02, speed_noise=0.005, kinds=LOGGED_KINDS,
                  seed=0, oversample=4, bump_stops=None, static_corner_load_n=None,
                  static_ride_height_m=STATIC_RIDE_HEIGHT_M, pot_offset_m=POT_OFFSET_M,
                  name=None):
    """Run a known car over a track run and log it as its data logger would.

    Parameters
    ----------
    plant : ident.models.lti.LoopPlant
        The known car (``FullCarModel.loop_plant()``).
    run : TrackRun
        The run (:func:`make_track_run`).
    setup : sequence of 4 shock models
        The car's shocks (LF, RF, LR, RR), nonlinear and lagged as they are.
    noise : float
        White sensor noise on every response channel, a fraction of that channel's RMS.
    speed_noise : float
        White noise on the speed, a fraction of its mean.
    kinds : sequence of str
        The response kinds logged (``shock_travel`` always; ``ride_height``,
        ``wheel_accel``, ``chassis_accel``), at every corner.
    seed : int
        Seed of the sensor noise.
    oversample : int
        The simulator's internal steps per sample.
    bump_stops, static_corner_load_n
        The car's bump stops and static loads, as :func:`ident.sim.closedloop.simulate`.
    static_ride_height_m : (float, float)
        Front and rear ride heights at rest [m], added to the lasers' readings.
    pot_offset_m : sequence of 4 float
        Zero offsets of the potentiometers [m], added to the travels.
    name : str, optional
        The log's name (default: the run's).

    Returns
    -------
    ident.data.tracklog.TrackLog
        SI channels ``shock_travel_XX`` (+ offsets), the other kinds logged (ride heights
        absolute), ``speed``, each with its noise, at the run's rate.
    """
    kinds = tuple(dict.fromkeys(("shock_travel",) + tuple(kinds)))
    outputs = [f"{k}_{c}" for k in kinds for c in CORNERS]
    missing = [o for o in outputs if o not in plant.output_names]
    if missing:
        raise DriveError(f"log_track_run: the plant has no output(s) {missing}; log only the "
                         "kinds it has")
    resp = simulate(plant, run.drive, setup, oversample=oversample, outputs=outputs,
                    stop_tables=bump_stops, static_corner_load_n=static_corner_load_n)
    rng = np.random.default_rng(seed)
    channels = {}
    for k in kinds:
        for j, c in enumerate(CORNERS):
            y = np.asarray(resp.channels[f"{k}_{c}"], float)
            sd = noise * float(np.sqrt(np.mean(np.square(y - y.mean()))))
            y = y + sd * rng.standard_normal(y.size)
            if k == "shock_travel":
                y = y + pot_offset_m[j]
            elif k == "ride_height":
                y = y + static_ride_height_m[0 if c in ("LF", "RF") else 1]
            channels[f"{k}_{c}"] = y
    speed = run.speed_m_s + speed_noise * float(np.mean(run.speed_m_s)) * \
        rng.standard_normal(run.speed_m_s.size)
    channels["speed"] = speed
    for v in channels.values():
        v.flags.writeable = False
    settings = {"source": "virtual track", "format": "virtual", "units": "SI", "map": None,
                "t0_s": 0.0, "resampled": [], "noise": float(noise), "run": run.drive.name,
                "kinds": list(kinds)}
    return TrackLog(name=name or run.drive.name, fs_hz=run.drive.fs_hz, channels=channels,
                    settings=settings)
