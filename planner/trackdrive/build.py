"""Drive iteration: the rig drive whose response reproduces a target, on a model or a rig.

:func:`build_track_drive` is what rig software calls drive iteration (Kelly et al.,
reference [1] of the seed paper; MTS RPC), done on the identified model before rig day:

1. the plain inverse: the wheelloader inputs ``u = G+ (y - G_aero u_aero)`` with ``G+`` the
   regularized inverse of the closed loop with the track setup's shocks linearized
   (:mod:`planner.trackdrive.inverse`) and ``G_aero`` the loop's response to the drive's
   given aero loads;
2. then, in the time domain through the nonlinear shocks (and the model's bump stops and
   static loads): simulate the drive (:func:`ident.sim.closedloop.simulate`), take the
   residual ``r = y_target - y`` in the band, and correct ``u <- u + gain G+ r``, the shocks
   re-linearized at the velocities simulated, until the residual stops falling (by less
   than ``tol`` of itself twice in a row); a step that makes it worse is undone and the
   gain halved. The best drive is kept.

A linear inverse alone leaves an error of the size of the shocks' nonlinearity; the
iteration removes what the model can reach. The rig's limits (:func:`planner.rig_spec.
apply_rig_limits`) are applied to every iterate with ``limit_action="clip"`` (so that the
iteration works around them) or to the final drive with ``"scale"``.

:func:`update_drive` is one step of the same iteration on the rig: the response the rig
recorded while playing a drive (a session run) replaces the model's simulation, the model
supplies ``G+`` (linearized at the recorded shock velocities).

Residuals are judged as the issue's report states them: per channel, the RMS of the
residual over the RMS of the target, both band-passed 1-20 Hz (the metrics' filter,
:func:`ident.sim.metrics.bandpass`), over the samples outside each log's fades.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import fft as sp_fft

from ident.data.channels import AERO_INPUTS, CORNERS, SHOCK_VELOCITIES, WHEELLOADER_INPUTS
from ident.data.drive import Drive
from ident.sim.closedloop import simulate
from ident.sim.metrics import bandpass
from planner.elements import loop_arguments, model_setup_elements
from planner.options import ElementOptions, as_options
from planner.errors import PlannerError
from planner.plant import as_loop_plant
from planner.rig_spec import LIMIT_ACTIONS, apply_rig_limits
from planner.setups import Setup
from planner.trackdrive.inverse import (DEFAULT_ALPHA, close_loop, coherence_weights,
                                        open_loop_parts, reach_shares, regularized_inverse,
                                        shock_linearization)
from planner.trackdrive.target import DriveTarget, segment_taper, spectral_derivative

__all__ = [
    "TrackDrive",
    "build_track_drive",
    "update_drive",
    "residual_shares",
    "REPORT_BAND_HZ",
    "LIMIT_ACTIONS",
    "DEFAULT_MAX_ITER",
    "DEFAULT_TOL",
    "RIG_GAIN",
]

log = logging.getLogger(__name__)

#: The band residuals are reported in [Hz]: the metrics'.
REPORT_BAND_HZ = (1.0, 20.0)
#: What to do where the drive exceeds the rig's limits.
#: Most time-domain iterations of :func:`build_track_drive`.
DEFAULT_MAX_ITER = 20
#: The residual "stops falling" when an iteration lowers it by less than this share of
#: itself, twice in a row (1 %: below what a metric can show).
DEFAULT_TOL = 0.01
#: Default gain of a rig iteration (MTS practice: below 1, since the recorded response is
#: noisy and the model's inverse only approximate).
RIG_GAIN = 0.7
#: Zero padding at each end of the record for the frequency-domain inverse [s]: the
#: inverse is non-causal, and its response to one end must not wrap onto the other
#: (the body modes ring out within 2 s).
PAD_S = 4.0
#: Shock linearization is refreshed when a corner's equivalent damping moves by more than
#: this share.
RELINEARIZE_RTOL = 0.02


@dataclass(frozen=True, eq=False)
class TrackDrive:
    """A rig drive built (or updated) to reproduce a target.

    Attributes
    ----------
    drive : ident.data.drive.Drive
        The drive, at the target's rate: the wheelloaders found, the target's aero loads.
    target : planner.trackdrive.target.DriveTarget
    response : dict of str to ndarray, shape (n_samples,)
        The response to `drive`: the model's (built) or the rig's (updated), target channels.
    history : pandas.DataFrame
        One row per iteration and channel: ``iteration``, ``channel``, ``residual_rms``
        (SI), ``residual_share`` (residual RMS over target RMS, 1-20 Hz), ``gain``,
        ``seconds``; the rows of channel ``"all"`` hold the RMS over channels of the shares.
        Iteration 1 is the plain frequency-domain inverse.
    reach : pandas.DataFrame
        Per target channel: ``unreachable_share``, the share of the target's power
        (1-20 Hz) the regularized inverse of the linearized loop cannot reach.
    limits : planner.rig_spec.LimitedDrive or None
        How the rig's limits changed the drive (None without limits).
    settings : dict
        The options, the setup, the linearization, the best iteration and why it stopped.
    """

    drive: Drive
    target: DriveTarget
    response: dict
    history: pd.DataFrame
    reach: pd.DataFrame
    limits: object = None
    settings: dict = field(default_factory=dict)

    @property
    def residual_share(self):
        """pandas.Series: The final residual share per target channel (1-20 Hz)."""
        h = self.history
        last = h[h["iteration"] == self.settings["best_iteration"]]
        return last.set_index("channel")["residual_share"].drop("all")


def residual_shares(target, response, *, band_hz=REPORT_BAND_HZ, mask=None):
    """Residual RMS and its share of the target's RMS per channel, band-passed.

    Parameters
    ----------
    target : DriveTarget
    response : mapping of str to ndarray, shape (n_samples,)
        A response holding the target's channels (at its rate).
    band_hz : (float, float)
        [Hz].
    mask : ndarray of bool, optional
        The samples judged (default ``target.interior()``).

    Returns
    -------
    pandas.DataFrame
        Index: channel; columns ``residual_rms`` (SI), ``target_rms`` (SI),
        ``residual_share``.
    """
    mask = target.interior() if mask is None else mask
    rows = {}
    for c, y in target.channels.items():
        r = bandpass(y - np.asarray(response[c], float), fs=target.fs_hz, band_hz=band_hz)[mask]
        t = bandpass(y, fs=target.fs_hz, band_hz=band_hz)[mask]
        rr, tr = float(np.sqrt(np.mean(r * r))), float(np.sqrt(np.mean(t * t)))
        rows[c] = {"residual_rms": rr, "target_rms": tr, "residual_share": rr / tr if tr else 0.0}
    return pd.DataFrame.from_dict(rows, orient="index")


class _Problem:
    """What every iteration shares: the plant, the shocks, the grid, the open loop."""

    def __init__(self, model, target, setup, library, *, alpha, oversample, elements, where):
        if not isinstance(target, DriveTarget):
            raise TypeError(f"{where}: target must be a DriveTarget, got {type(target).__name__}")
        if not isinstance(setup, Setup):
            raise TypeError(f"{where}: setup must be a planner.setups.Setup, got "
                            f"{type(setup).__name__}")
        self.where = where
        self.target = target
        self.setup = setup
        self.plant = as_loop_plant(model)
        self.shocks = setup.resolve(library)
        elem = model_setup_elements([setup], model, elements, where=where)
        kw = loop_arguments(elem)
        stops = kw.pop("bump_stops", None)  # simulate takes the one setup's
        if stops is not None:
            kw["stop_tables"] = stops[0]
        self.loop_kw = kw
        self.elements = None if elem is None else elem.settings
        self.oversample = oversample
        self.alpha = alpha
        self.names = list(target.channels)
        missing = [c for c in self.names if c not in self.plant.output_names]
        if missing:
            raise PlannerError(f"{where}: the model has no output {missing}; build the target "
                               "with the model's outputs (make_target(model_outputs=...))")
        self.aero_inputs = [a for a in AERO_INPUTS if a in self.plant.rig_inputs]
        if target.aero is not None and not self.aero_inputs:
            raise PlannerError(f"{where}: the target has aero loads but the model has no aero "
                               "inputs (a 4-post model); build the target without aero")
        n, fs = target.n_samples, target.fs_hz
        self.n, self.fs = n, fs
        self.pad = int(round(PAD_S * fs))
        self.n_fft = sp_fft.next_fast_len(n + 2 * self.pad, real=True)
        f = np.fft.rfftfreq(self.n_fft, 1.0 / fs)
        lo, hi = target.band_hz
        self.bins = np.flatnonzero((f >= lo) & (f <= hi))
        self.f_band = f[self.bins]
        report = (self.f_band >= REPORT_BAND_HZ[0]) & (self.f_band <= REPORT_BAND_HZ[1])
        self.report_bins = np.flatnonzero(report)
        inputs = list(WHEELLOADER_INPUTS) + self.aero_inputs
        self.parts = open_loop_parts(self.plant, self.f_band, outputs=self.names, inputs=inputs)
        self.mask = target.interior()
        self.window = np.concatenate([segment_taper(cnt, fs, target.taper_s, where=where)
                                      for _, _, cnt in target.segments])
        self.weights = np.array([1.0 / _band_rms(target.channels[c], fs, target.band_hz,
                                                 self.mask, c, where) for c in self.names])
        trust = coherence_weights(model, self.names, self.f_band)
        self.row_weights = (self.weights[:, None] if trust is None
                            else self.weights[:, None] * trust)          # (n_t, n_f)
        self.c_eq = None
        self.outputs = list(dict.fromkeys(self.names + list(SHOCK_VELOCITIES)))
        # the target's band spectrum (n_t, n_b), faded as every correction is
        self.y_spec = self.spectrum(np.array([target.channels[c] for c in self.names])
                                    * self.window)

    # -- the linear loop ----------------------------------------------------------------
    def linearize(self, v_rms):
        """(Re)build the inverse at shock velocity RMS `v_rms` (4,); returns whether it
        changed."""
        c, lag = shock_linearization(self.shocks, v_rms)
        if self.c_eq is not None and np.all(np.abs(c - self.c_eq) <= RELINEARIZE_RTOL
                                            * np.abs(self.c_eq)):
            return False
        self.c_eq, self.lag = c, lag
        self.v_rms = np.asarray(v_rms, float)
        g = close_loop(self.parts, c, lag)
        self.g_free = g[:, :4]
        self.g_aero = g[:, 4:]
        self.ginv, self.gain = regularized_inverse(self.g_free, self.row_weights,
                                                   alpha=self.alpha,
                                                   names=self.names, where=self.where)
        return True

    def spectrum(self, x):
        """The band's bins of the zero-padded record `x` (..., n)."""
        padded = np.zeros(x.shape[:-1] + (self.n_fft,))
        padded[..., self.pad:self.pad + self.n] = x
        return np.fft.rfft(padded, axis=-1)[..., self.bins]

    def _inverted(self, spec):
        """The wheelloader inputs (4, n) the inverse gives for target-row spectra (n_t, n_b)."""
        du = np.einsum("itf,tf->if", self.ginv, spec)                     # (4, n_b)
        full = np.zeros((4, self.n_fft // 2 + 1), complex)
        full[:, self.bins] = du
        x = np.fft.irfft(full, self.n_fft, axis=-1)[:, self.pad:self.pad + self.n]
        return x * self.window

    def correction(self, residual):
        """Wheelloader correction (4, n) for a residual (n_t, n) of the target channels."""
        return self._inverted(self.spectrum(residual * self.window))

    def plain_inverse(self):
        """The drive of the linear inverse alone: ``G+ (y - G_aero u_aero)`` (4, n)."""
        ys = self.y_spec
        if self.target.aero is not None:
            ua = self.spectrum(np.array([self.target.aero[a] for a in self.aero_inputs]))
            ys = ys - np.einsum("taf,af->tf", self.g_aero, ua)
        return self._inverted(ys)

    def reach(self):
        """Unreachable share per target channel (1-20 Hz) at the current linearization."""
        yw = self.y_spec * self.row_weights
        b = self.report_bins
        shares = reach_shares(self.gain[:, :, b], yw[:, b])
        return pd.DataFrame({"unreachable_share": shares}, index=pd.Index(self.names,
                                                                          name="channel"))

    # -- drives and responses -------------------------------------------------------------
    def drive(self, wheels, name, aero=None):
        """A drive of the wheelloaders `wheels` (4, n) and `aero` (default the target's)."""
        aero = self.target.aero if aero is None else aero
        channels = {w: wheels[j] for j, w in enumerate(WHEELLOADER_INPUTS)}
        if self.aero_inputs:
            for a in self.aero_inputs:
                channels[a] = (np.zeros(self.n) if aero is None
                               else np.resize(np.asarray(aero[a], float), self.n))
        settings = {"kind": "track", "target": self.target.name, "band_hz": self.target.band_hz,
                    "setup": dict(zip(CORNERS, self.setup.ids()))}
        return Drive(name=name, fs_hz=self.fs, channels=channels, settings=settings)

    def simulate(self, drive):
        resp = simulate(self.plant, drive, self.shocks, oversample=self.oversample,
                        outputs=self.outputs, **self.loop_kw)
        return {c: np.asarray(v) for c, v in resp.channels.items()}

    def velocity_rms(self, response):
        return np.array([_band_rms(response[v], self.fs, self.target.band_hz, self.mask, v,
                                   self.where, allow_zero=True) for v in SHOCK_VELOCITIES])

    def residual(self, response):
        return np.array([self.target.channels[c] - response[c] for c in self.names])


def _band_rms(x, fs, band, mask, name, where, allow_zero=False):
    top = min(band[1], 0.45 * fs)
    y = bandpass(np.asarray(x, float) - np.mean(x), fs=fs, band_hz=(band[0], top))[mask]
    rms = float(np.sqrt(np.mean(y * y)))
    if rms <= 0 and not allow_zero:
        raise PlannerError(f"{where}: target {name} has no content in the band "
                           f"{band[0]:g}-{band[1]:g} Hz; leave it out of the targets")
    return rms


def _history_rows(iteration, shares, gain, seconds):
    rows = [{"iteration": iteration, "channel": c, "residual_rms": r.residual_rms,
             "residual_share": r.residual_share, "gain": gain, "seconds": seconds}
            for c, r in shares.iterrows()]
    total = float(np.sqrt(np.mean(np.square(shares["residual_share"]))))
    rows.append({"iteration": iteration, "channel": "all", "residual_rms": np.nan,
                 "residual_share": total, "gain": gain, "seconds": seconds})
    return rows, total


def _check_options(max_iter, tol, gain, limit_action, where):
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 0:
        raise PlannerError(f"{where}: max_iter = {max_iter!r} must be an integer >= 0 (0: the "
                           "plain inverse alone)")
    if not np.isfinite(tol) or not 0 <= tol < 1:
        raise PlannerError(f"{where}: tol = {tol!r} must be in [0, 1)")
    if not np.isfinite(gain) or not 0 < gain <= 2:
        raise PlannerError(f"{where}: gain = {gain!r} must be in (0, 2]")
    if limit_action not in LIMIT_ACTIONS:
        raise PlannerError(f"{where}: limit action {limit_action!r} is not one of "
                           f"{list(LIMIT_ACTIONS)}")


def _limited(drive, limits, action, *, warn=True):
    if limits is None:
        return drive, None
    out = apply_rig_limits(drive, limits, action=action, warn=warn)
    return out.drive, out


def build_track_drive(model, target, setup, library, *, alpha=DEFAULT_ALPHA,
                      max_iter=DEFAULT_MAX_ITER, tol=DEFAULT_TOL, gain=1.0, oversample=2,
                      limits=None, limit_action="clip", elements=ElementOptions(), name=None,
                      progress=None, where="drive from-track"):
    """Build the rig drive that reproduces a target on a model (drive iteration).

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
        The identified model (or the known car).
    target : DriveTarget
        From :func:`planner.trackdrive.target.make_target` (at the model's rate).
    setup : planner.setups.Setup
        The shocks the car ran at the track.
    library : ident.models.library.ShockLibrary
    alpha : float
        Relative regularization of the inverse (:data:`DEFAULT_ALPHA`).
    max_iter : int
        Most time-domain iterations after the plain inverse (0: the plain frequency-domain
        inverse alone, simulated once).
    tol : float
        Stop when an iteration lowers the residual by less than this share, twice.
    gain : float
        Step of each correction (1: the full inverse).
    oversample : int
        The simulator's internal steps per sample.
    limits : planner.rig_spec.RigLimits, optional
        The rig's actuator limits.
    limit_action : {"clip", "scale"}
        ``clip`` limits every iterate locally (the iteration works around it); ``scale``
        scales the final drive as a whole.
    elements : planner.options.ElementOptions
        The car's bump stops and static loads, as :func:`planner.predict.predict_setups`
        (default the model's).
    name : str, optional
        The drive's name (default ``"<target>-drive"``).
    progress : callable, optional
        Called ``progress(iteration, residual_share)`` after every iteration.
    where : str
        Who asks, first in messages.

    Returns
    -------
    TrackDrive
    """
    _check_options(max_iter, tol, gain, limit_action, where)
    elements = as_options(elements, ElementOptions, "elements", where)
    p = _Problem(model, target, setup, library, alpha=alpha, oversample=oversample,
                 elements=elements, where=where)
    name = name or f"{target.name}-drive"
    # linearize at the logged travel's velocity: the spectral derivative, in the band
    v0 = []
    for c in CORNERS:
        tv = f"shock_travel_{c}"
        if tv in target.channels:
            v = spectral_derivative(target.channels[tv], p.fs)
        else:
            v = target.channels[f"shock_velocity_{c}"]
        v0.append(_band_rms(v, p.fs, target.band_hz, p.mask, tv, where, allow_zero=True))
    p.linearize(np.array(v0))
    t0 = time.perf_counter()
    wheels = p.plain_inverse()
    history, best, stalls, step = [], None, 0, float(gain)
    limit_report = None
    stop = "max_iter"
    for it in range(1, max_iter + 2):
        drive = p.drive(wheels, name)
        if limits is not None and limit_action == "clip":
            drive, limit_report = _limited(drive, limits, "clip", warn=False)
            wheels = np.array([drive.channels[w] for w in WHEELLOADER_INPUTS])
        resp = p.simulate(drive)
        shares = residual_shares(target, resp, mask=p.mask)
        rows, total = _history_rows(it, shares, step, time.perf_counter() - t0)
        history += rows
        if progress is not None:
            progress(it, total)
        log.info("%s: iteration %d: residual %.4f (gain %.2f)", where, it, total, step)
        if best is None or total < best[0]:
            improved = best is None or total < best[0] * (1 - tol)
            best = (total, it, drive, resp, limit_report)   # the drive as limited and played
            stalls = 0 if improved else stalls + 1
        else:
            stalls += 1
            step *= 0.5
            drive, resp = best[2], best[3]
            wheels = np.array([drive.channels[w] for w in WHEELLOADER_INPUTS])
        if stalls >= 2:
            stop = "converged"
            break
        if it > max_iter:
            break
        p.linearize(p.velocity_rms(resp))
        wheels = wheels + step * p.correction(p.residual(resp))
    total, best_it, drive, resp, limit_report = best
    if limits is not None and limit_action == "scale":
        drive, limit_report = _limited(drive, limits, "scale")
        if limit_report is not None and min(limit_report.scale, limit_report.aero_scale) < 1:
            resp = p.simulate(drive)
    if limit_report is not None and limit_action == "clip":
        for w in limit_report.warnings:     # the final drive's, once
            log.warning("%s", w)
    p.linearize(p.velocity_rms(resp))
    settings = {"alpha": alpha, "max_iter": max_iter, "tol": tol, "gain": gain,
                "oversample": oversample, "setup": dict(zip(CORNERS, setup.ids())),
                "c_eq_n_s_m": p.c_eq.tolist(), "v_rms_m_s": p.v_rms.tolist(),
                "best_iteration": best_it, "stopped": stop, "band_hz": target.band_hz,
                "limit_action": limit_action if limits is not None else None,
                "elements": p.elements, "seconds": time.perf_counter() - t0}
    return TrackDrive(drive=drive, target=target,
                      response={c: resp[c] for c in p.names},
                      history=pd.DataFrame(history), reach=p.reach(), limits=limit_report,
                      settings=settings)


def update_drive(model, drive, target, recorded, setup, library, *, gain=RIG_GAIN,
                 alpha=DEFAULT_ALPHA, limits=None, limit_action="clip", where="drive iterate"):
    """One rig iteration: correct a drive by the residual the rig recorded playing it.

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
        The model whose linearized loop gives the inverse.
    drive : ident.data.drive.Drive
        The drive the rig played (at the target's rate, as long as the target).
    target : DriveTarget
    recorded : mapping of str to ndarray, or an object with ``channels`` and ``fs_hz``
        What the rig recorded while playing `drive` (a session run): the target channels
        and the four shock velocities, at the target's rate.
    setup : planner.setups.Setup
        The shocks on the car during the run.
    library : ident.models.library.ShockLibrary
    gain : float
        Step of the correction (:data:`RIG_GAIN`).
    alpha : float
        Relative regularization.
    limits, limit_action
        As :func:`build_track_drive`.
    where : str
        Who asks, first in messages.

    Returns
    -------
    TrackDrive
        The corrected drive; ``response`` and ``history`` (iteration 0) are the recorded
        run's; ``reach`` at the recorded linearization.
    """
    _check_options(1, 0.0, gain, limit_action, where)
    p = _Problem(model, target, setup, library, alpha=alpha, oversample=2,
                 elements=ElementOptions(use_model=False), where=where)
    fs = getattr(recorded, "fs_hz", target.fs_hz)
    channels = getattr(recorded, "channels", recorded)
    if abs(fs - target.fs_hz) > 1e-6 * target.fs_hz:
        raise PlannerError(f"{where}: the run is sampled at {fs:g} Hz but the target at "
                           f"{target.fs_hz:g} Hz; record the run at the drive's rate")
    if abs(drive.fs_hz - target.fs_hz) > 1e-6 * target.fs_hz or \
            abs(drive.n_samples - target.n_samples) > 1:
        raise PlannerError(f"{where}: the drive ({drive.n_samples} samples at {drive.fs_hz:g} Hz)"
                           f" is not the target's ({target.n_samples} at {target.fs_hz:g} Hz); "
                           "give the drive that was built for this target")
    need = list(dict.fromkeys(p.names + list(SHOCK_VELOCITIES)))
    lacking = [c for c in need if c not in channels]
    if lacking:
        raise PlannerError(f"{where}: the recorded run has no {lacking}; record the target "
                           "channels and the shock velocities")
    n = p.n
    rec = {}
    for c in need:
        x = np.asarray(channels[c], float)
        if abs(x.size - n) > 1:
            raise PlannerError(f"{where}: the recorded {c} has {x.size} samples, the target "
                               f"{n}; record the whole drive")
        x = np.resize(x, n) if x.size != n else x
        parts = [x[s:s + m] - x[s:s + m].mean() for _, s, m in target.segments]
        rec[c] = np.concatenate(parts) * p.window if c in p.names else x
    p.linearize(p.velocity_rms(rec))
    shares = residual_shares(target, rec, mask=p.mask)
    rows, total = _history_rows(0, shares, gain, 0.0)
    wheels = np.array([np.resize(np.asarray(drive.channels[w], float), n)
                       for w in WHEELLOADER_INPUTS])
    wheels = wheels + gain * p.correction(p.residual(rec))
    new = p.drive(wheels, drive.name, aero={a: drive.channels[a] for a in p.aero_inputs})
    new, limit_report = _limited(new, limits, limit_action)
    log.info("%s: recorded residual %.4f; drive corrected with gain %.2f", where, total, gain)
    settings = {"alpha": alpha, "gain": gain, "setup": dict(zip(CORNERS, setup.ids())),
                "c_eq_n_s_m": p.c_eq.tolist(), "v_rms_m_s": p.v_rms.tolist(),
                "best_iteration": 0, "stopped": "rig iteration", "band_hz": target.band_hz,
                "limit_action": limit_action if limits is not None else None}
    return TrackDrive(drive=new, target=target, response={c: rec[c] for c in p.names},
                      history=pd.DataFrame(rows), reach=p.reach(), limits=limit_report,
                      settings=settings)
