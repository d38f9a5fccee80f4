"""What the linear model cannot see: a rig session checked against its own identified model.

:func:`diagnose_session` looks at every run and corner of a session for the signs of what
the identified model (linear, but for the shocks) leaves out, and returns a
:class:`Diagnosis`: a findings table (run, corner, kind, share of time, a value, what it
does to the predictions, how to fix it), the measured numbers behind it, and its settings.
:func:`ident.identify.pipeline.identify_session` calls it and keeps it as the model's
``diagnosis`` (saved in the model file as :meth:`Diagnosis.to_dict`); ``shockplan identify``
prints it (:meth:`Diagnosis.summary_lines`).

The checks, per run and corner:

``bump stop contact`` (declared stops)
    The share of time the shock travel from rest is beyond the declared gap less the
    packer (:meth:`ident.models.bumpstops.BumpStop.contact_travel_m`).
``stiffening`` (the signs of an undeclared stop)
    The force balance of the wheel, ``tire_force - spring_force - shock_force -
    m_u wheel_accel``, holds whatever the car's linear elements (an anti-roll bar, motion
    ratios) once regressed on the linear part of the travel (both travels of the axle and
    a constant, fitted where the travel is below its median); the residual is the force of
    what the channels do not measure. A bump stop makes it a one-sided excess in
    compression beyond a travel: a hinge ``k max(0, s - s0)^p`` (p = 1 or 2) is fitted
    and reported when significant (:data:`STIFFENING_Z`) and large
    (:data:`STIFFENING_FORCE_SHARE`). Without those channels the same hinge is fitted to
    the validation residual of the travel (measured less than the model's;
    :data:`STIFFENING_TRAVEL_SHARE`), a weaker check.
``heave stiffening`` (the signs of an undeclared heave element; per axle)
    The two wheels' balance residuals of an axle fitted with one hinge common to both
    against the axle's heave travel (the mean of the two shock travels from rest), and with
    a hinge per corner against its own travel: a heave spring with a gap (a third element,
    the spec's "Third elements") pushes both wheels alike as the axle's heave travel passes
    its gap. Reported, naming the axle (``front``, ``rear`` in the findings' ``corner``),
    when the common hinge is significant and large (as ``stiffening``) and explains at least
    :data:`HEAVE_PREFERENCE` times what the corners' own hinges explain; the axle's corners
    are then not reported for ``stiffening`` besides. The declared third elements' force
    (:func:`ident.identify.thirdforce.third_element_force`) is taken out of every balance
    first, and the runs are re-simulated with them
    (:func:`ident.sim.third_loop.simulate_third`).
``friction``
    Suspension friction (bushings, bearings, seals, in parallel with the shock): the same
    balance regressed on its linear part, the shock velocity and the sign of the shock
    velocity as the samples see it (:func:`_friction`); reported when significant
    (:data:`FRICTION_Z`) and large (:data:`FRICTION_FORCE_SHARE`), with the share of time
    within the sticking band (:data:`FRICTION_BAND_M_S`) and the force [N]. It needs the
    force channels (no check without them).
``lift-off``
    The share of time the contact force is near zero (below :data:`NEAR_ZERO_CONTACT` of
    the static load): ``static + tire_force`` with static loads given, or the channel
    itself where it carries the static load (its rest level above
    :data:`CARRIED_REST_SIGMAS` of its dynamic part, or the session's rule
    :data:`ident.data.session.STATIC_OFFSET_SHARE` with loads given).
``residual``
    Each run re-simulated on the identified model with its own shocks
    (:func:`ident.sim.closedloop.simulate` on the model's loop plant, the run's rig
    inputs as the drive) and compared with what was measured in the fitted band: the
    relative residual beyond the channel's noise (estimated from the band above the car's
    response, :func:`channel_noise`) above :data:`RESIDUAL_EXCESS_MAX`.
``amplitude``
    Where the runs' drive levels differ by :data:`AMPLITUDE_LEVEL_RATIO` or more, a
    residual that grows with the level (:data:`AMPLITUDE_GROWTH`).

The static position (rest) of every channel comes from the data: the drives are tapered,
so the car is at rest at the start and end of a run (the first and last
:data:`REST_WINDOW_S`). It is checked against the run's mean, and the rest is used where
the inputs are quiet there (the start preferred: the car's slow modes still ring at the
end); else the mean, and :attr:`Diagnosis.checks` says which (``rest``, with the travel's
rest less its mean).

Notes
-----
Sign conventions are the spec's: travel and forces positive in compression, wheel
acceleration positive up, so that ``m_u a = tire - spring - shock - stop`` at a wheel.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ident.data.channels import CORNERS, RIG_INPUTS, WHEELLOADER_INPUTS
from ident.data.drive import Drive, decimate_bandlimited
from ident.data.session import STATIC_OFFSET_SHARE
from ident.data.third import AXLES
from ident.data.units import format_quantity
from ident.identify.serialdot import serial_dots
from ident.identify.thirdforce import third_element_force
from ident.models.bumpstops import contact_tables
from ident.sim.closedloop import refine_input, simulate
from ident.sim.third_loop import ThirdDamper, ThirdSpring, simulate_third

__all__ = [
    "AMPLITUDE_GROWTH",
    "AMPLITUDE_LEVEL_RATIO",
    "CARRIED_REST_SIGMAS",
    "CONTACT_SHARE_MIN",
    "FINDING_COLUMNS",
    "FRICTION_BAND_M_S",
    "FRICTION_FORCE_SHARE",
    "FRICTION_REFINE",
    "FRICTION_Z",
    "HEAVE_PREFERENCE",
    "KINDS",
    "LIFTOFF_SHARE_MIN",
    "NEAR_ZERO_CONTACT",
    "NOISE_BAND",
    "RESIDUAL_BAND_HZ",
    "RESIDUAL_EXCESS_MAX",
    "REST_INPUT_SHARE",
    "REST_WINDOW_S",
    "STIFFENING_FORCE_SHARE",
    "STIFFENING_TRAVEL_SHARE",
    "STIFFENING_Z",
    "Diagnosis",
    "channel_noise",
    "diagnose_session",
    "rest_levels",
    "shock_velocity",
]

log = logging.getLogger(__name__)

#: Columns of :attr:`Diagnosis.findings`.
FINDING_COLUMNS = ("run", "corner", "kind", "share", "value", "message", "fix")
#: The kinds of finding.
KINDS = ("bump stop contact", "stiffening", "heave stiffening", "lift-off", "friction",
         "residual", "amplitude")

#: Length of the start and end windows that give a channel's rest level [s]: the drives
#: fade in and out over 1 s (raised cosine), whose first 0.1 s is below 2.5 % of full level.
REST_WINDOW_S = 0.1
#: A run starts (or ends) at rest when every rig input's RMS in the rest windows is below
#: this share of its RMS over the run (a tapered drive).
REST_INPUT_SHARE = 0.05
#: A declared bump stop is reported when the travel is beyond its contact at least this
#: share of the time (one sample in a thousand: below it a stop changes no metric).
CONTACT_SHARE_MIN = 1e-3
#: Candidate onsets of the stiffening hinge: travels at these exceedance shares.
_HINGE_SHARES = np.geomspace(0.5, 5e-4, 60)
#: The stiffening hinge is significant at this many standard errors of its slope. Plain
#: cars with 2 % sensor noise (GT-like cars, 5 x 100 s) reach at most 4.6 at the hinge that
#: fits best over 60 onsets x 2 shapes; a GT-like car with stops touched 5-9 % of the time
#: 163 and more. Noise-free data make any hinge significant (the paper car: up to 180 for
#: forces of 1e-5 of the tire's), so :data:`STIFFENING_FORCE_SHARE` decides there.
STIFFENING_Z = 12.0
#: ... and large: the hinge's force at the 99.9th percentile of the travel at least this
#: share of the tire force's RMS. Plain cars: at most 0.011 (paper car below 1e-4); a
#: declared stop taken out of the balance: at most 0.009; undeclared stops touched 5-9 %:
#: 0.64-1.26.
STIFFENING_FORCE_SHARE = 0.2
#: Without the force channels, the hinge on the travel's validation residual (the measured
#: travel short of the model's) is reported when its deficit at the 99.9th percentile is at
#: least this share of the travel's standard deviation (and :data:`STIFFENING_Z`). Plain
#: cars: at most 0.041; stops touched 5-9 %: 0.23-0.68 at the front, but lift-off alone
#: gives 0.22 at a rear corner, and the onsets scatter (shares 2-50 %): a weaker check.
STIFFENING_TRAVEL_SHARE = 0.3
#: An axle's stiffening is read as an undeclared heave element (``heave stiffening``) when
#: one hinge on the axle's heave travel, common to its two wheels, explains at least this
#: many times the force that the two corners' own hinges on their own travels explain
#: together (it is also significant, :data:`STIFFENING_Z`, and large,
#: :data:`STIFFENING_FORCE_SHARE`; a common hinge has half the parameters). Measured at 2 %
#: noise, 100 s runs: gapped heave springs front and rear (prototype-like car, springs
#: closed 25-31 % of the time) 2.0-2.8; undeclared corner stops at the front (GT-like car,
#: touched 5-9 %) 0.28-0.34.
HEAVE_PREFERENCE = 1.0
#: The sticking band of the suspension friction [m/s]: the friction changes sign within
#: +-this shock velocity (or within the velocity's measured noise, where larger: the data
#: cannot place the reversal closer). 5 mm/s: the virtual rig's smoothing
#: (:data:`ident.sim.virtual_rig.FRICTION_V0_M_S`), below a rig's velocity noise at 2 %.
FRICTION_BAND_M_S = 0.005
#: Steps per sample on which the friction's regressor is formed (see :func:`_friction`).
FRICTION_REFINE = 8
#: The friction is significant at this many standard errors. Measured on the GT-like cars
#: at 2 % sensor noise (5 x 100 s, every run and corner): plain, bump stops only, lift-off
#: only, both: |z| at most 2.7 (one regressor: no search); friction of 15 N per corner:
#: z 7.9-16, of 100 N: 53-104. Noise-free data make any force significant (the paper car:
#: up to 67 for forces of 1e-15 of the shock's), so :data:`FRICTION_FORCE_SHARE` decides.
FRICTION_Z = 6.0
#: ... and large: the friction at least this share of the shock force's RMS at the
#: corner. Plain cars: at most 0.0067 (the paper car 2e-15); 15 N: 0.024-0.035; 100 N:
#: 0.20-0.24. The smallest friction found in every run and corner: 15 N (10 N: z from 5.1,
#: shares from 0.015).
FRICTION_FORCE_SHARE = 0.02
#: Contact counts as near zero below this share of the static load: the acquisition
#: filter rings below zero at the lift-off edges by up to about 5 % of the static load.
NEAR_ZERO_CONTACT = 0.05
#: Lift-off is reported from this share of time on (one sample in a thousand).
LIFTOFF_SHARE_MIN = 1e-3
#: A tire-force channel without static loads given carries the static load when its rest
#: level is above this many standard deviations of its dynamic part (a dynamic channel
#: rests at 0; a tire that carries 3 kN with a dynamic RMS beyond it is off the pad most of
#: the time).
CARRIED_REST_SIGMAS = 1.0
#: Without static loads, lift-off shows as a floor in the tire-force channel (its dynamic
#: part sits at minus the static load while the tire is off): the samples within this many
#: standard deviations of the channel's minimum. A Gaussian response puts about 1e-5 of
#: its samples there, a floor its whole lift-off share; the width covers the acquisition
#: filter's dip below the floor at the lift-off edges (up to 5 % of the static load, about
#: 0.15 standard deviations on the GT-like car) and 2 % sensor noise.
FLOOR_WIDTH_SIGMAS = 0.25
#: ... and the floor is that many times more crowded than the same band below the
#: channel's maximum (a bump stop stretches the upper tail, it does not crowd it).
FLOOR_CROWDING = 5.0
#: The band of the validation residual [Hz] (the fit's band, :data:`ident.identify.pipeline.
#: PAPER_WEIGHTS`): outside it the model is not fitted.
RESIDUAL_BAND_HZ = (0.5, 20.0)
#: A channel's validation residual (relative RMS in the band, its noise removed in
#: quadrature; the worst channel of a corner) is reported above this. Plain cars: at most
#: 0.015 (paper car, noise-free, 5 x 800 s), 0.049 (GT-like car with a flexible chassis,
#: 2 % noise, 5 x 100 s), 0.043 (the GT-like car of the stops at a lower drive level); the
#: corners with stops touched 5-9 % or tires lifting 0.6-3.6 % of the time: 0.12-0.53.
RESIDUAL_EXCESS_MAX = 0.08
#: The band (shares of the Nyquist frequency) where a channel holds only its noise: above
#: the car's response and the drive (30 Hz at 100 Hz), below the acquisition filter's
#: edge (0.8) only for noise added after it (a rig whose noise passes the filter shows none
#: there, and its residual is then judged with the noise in it).
NOISE_BAND = (0.85, 0.95)
#: Drive levels (RMS of the wheelloaders) that differ by this factor make an amplitude
#: check; closer levels cannot separate a nonlinearity from the drive's randomness.
AMPLITUDE_LEVEL_RATIO = 1.5
#: A residual that grows by this factor from the lowest to the highest drive level (and is
#: above :data:`RESIDUAL_EXCESS_MAX` / 2 at the highest) is amplitude dependent.
AMPLITUDE_GROWTH = 1.5


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """What a session shows that its linear model cannot see (:func:`diagnose_session`).

    Attributes
    ----------
    findings : pandas.DataFrame
        One row per finding, columns :data:`FINDING_COLUMNS`: ``run``, ``corner`` (``LF``
        .. ``RR``, or ``"all"``), ``kind`` (:data:`KINDS`), ``share`` (share of the
        run's time, 0-1, NaN where not a share), ``value`` (the kind's number: contact
        travel or onset [m] for stops, the smallest contact force [N] for lift-off, the
        friction force [N] for friction, the relative residual beyond noise for
        residuals, its growth for amplitude),
        ``message`` (what was seen and what it does to the predictions) and ``fix``.
        Empty when nothing was found.
    checks : pandas.DataFrame
        The measured numbers per run and corner, found or not: ``rest`` (``"rest"`` or
        ``"mean"``), ``rest_minus_mean_m`` (travel), ``contact_share`` (declared stop),
        ``stiffening_z``, ``stiffening_onset_m``, ``stiffening_share``,
        ``stiffening_force_share``, ``friction_n``, ``friction_z``, ``friction_share``,
        ``friction_band_m_s``, ``friction_v_rms_m_s``, ``friction_force_share``,
        ``liftoff_share``, ``contact_min_n``,
        ``residual_excess``, ``residual_channel``, ``noise`` (relative noise of that
        channel in the band), ``drive_level_m``.
    settings : dict
        The options and the thresholds used.
    """

    findings: pd.DataFrame
    checks: pd.DataFrame
    settings: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.findings)

    def groups(self):
        """The findings grouped by corner and kind, over the runs.

        Returns
        -------
        list of dict
            ``corner``, ``kind``, ``runs`` (their names), ``share_min``, ``share_max``
            (NaN where not a share), ``message`` and ``fix`` (of the run with the
            largest share, or value): corners in ``LF, RF, LR, RR, all`` order.
        """
        out = []
        order = {c: i for i, c in enumerate((*CORNERS, *AXLES, "all"))}
        kinds = {k: i for i, k in enumerate(KINDS)}
        keys = sorted({(f.corner, f.kind) for f in self.findings.itertuples()},
                      key=lambda k: (order.get(k[0], 9), kinds.get(k[1], 9)))
        for corner, kind in keys:
            part = self.findings[(self.findings.corner == corner) & (self.findings.kind == kind)]
            by = part.share if part.share.notna().any() else part.value
            top = part.loc[by.abs().idxmax()]
            out.append({"corner": corner, "kind": kind, "runs": list(part.run),
                        "share_min": float(part.share.min()),
                        "share_max": float(part.share.max()),
                        "message": top.message, "fix": top.fix})
        return out

    def lines(self):
        """The findings as lines for a terminal: one per corner and kind (over the runs),
        then its fix."""
        out = []
        for g in self.groups():
            out.append(f"{g['corner']}: {_headline(g)}: {g['message']}")
            out.append(f"    fix: {g['fix']}")
        return out

    def summary_lines(self):
        """The diagnosis for a terminal: a headline (nothing found, or how many findings),
        then :meth:`lines` with each finding marked as a warning.

        Returns
        -------
        list of str
        """
        amplitude = self.settings.get("amplitude", "")
        if not len(self):
            return ["diagnosis: nothing the linear model cannot see (bump stops, lift-off, the "
                    "runs re-simulated on the model against their noise; amplitude dependence "
                    f"{amplitude})"]
        groups = self.groups()
        lines = [(f"diagnosis: {len(groups)} finding(s) the linear model cannot see (per corner "
                  f"over the runs; {len(self)} per run and corner in the model's settings; "
                  f"amplitude dependence {amplitude}):")]
        lines += [f"  warning: {line}" if not line.startswith("    ") else f"  {line}"
                  for line in self.lines()]
        return lines

    def to_dict(self):
        """A JSON-able dict (kept in the model file; :meth:`from_dict` reads it)."""
        def records(df):
            return [{k: (None if isinstance(v, float) and not np.isfinite(v) else v)
                     for k, v in row.items()} for row in df.to_dict("records")]
        return {"findings": records(self.findings), "checks": records(self.checks),
                "settings": dict(self.settings)}

    @classmethod
    def from_dict(cls, doc):
        """The :class:`Diagnosis` of :meth:`to_dict`."""
        findings = pd.DataFrame(doc.get("findings", []), columns=list(FINDING_COLUMNS))
        findings[["share", "value"]] = findings[["share", "value"]].astype(float)
        return cls(findings=findings, checks=pd.DataFrame(doc.get("checks", [])),
                   settings=dict(doc.get("settings", {})))


def _window(n, fs_hz):
    return max(1, min(round(REST_WINDOW_S * fs_hz), n // 10))


def rest_levels(run):
    """Every channel's static level in a run: the car at rest before the drive, or the mean.

    Parameters
    ----------
    run : ident.data.session.Run

    Returns
    -------
    levels : dict of str to float
        Channel -> the level its dynamic part is measured from (SI).
    used : str
        The median of the first :data:`REST_WINDOW_S`, where every rig input
        is quiet (RMS below :data:`REST_INPUT_SHARE` of the run's: a tapered drive, the
        car at rest); else the end's, where the inputs are quiet there and the channels
        have settled (``"rest (start)"``, ``"rest (end)"``); else ``"mean"``: the run's mean (a drive that starts and ends in
        motion).

    Notes
    -----
    A tapered drive ends at rest too, but the car does not: its slow modes still ring
    over the last fraction of a second (measured: up to 0.65 standard deviations of the
    travel in the last 0.1 s of a 1 s fade-out), so the start is preferred.
    """
    n = run.n_samples
    w = _window(n, run.fs_hz)

    def quiet(sl):
        for c in RIG_INPUTS:
            if c in run.channels:
                x = run.channels[c]
                rms = np.sqrt(np.mean((x - x.mean()) ** 2))
                part = x[sl] - np.median(x[sl])
                if rms > 0 and np.sqrt(np.mean(part ** 2)) > REST_INPUT_SHARE * rms:
                    return False
        return True

    for sl, name in ((slice(0, w), "rest (start)"), (slice(n - w, n), "rest (end)")):
        if quiet(sl):
            return {c: float(np.median(x[sl])) for c, x in run.channels.items()}, name
    return {c: float(np.mean(x)) for c, x in run.channels.items()}, "mean"


def channel_noise(x, fs_hz, *, spectrum=None):
    """Standard deviation of a channel's white noise, from the band :data:`NOISE_BAND`.

    Parameters
    ----------
    x : ndarray, shape (n_samples,)
    fs_hz : float
    spectrum : ndarray of complex, shape (n_samples // 2 + 1,), optional
        ``numpy.fft.rfft`` of `x` less its mean, when already computed.

    Returns
    -------
    float
        ``sqrt(mean |X_k|^2 / n)`` over the band's lines of the periodogram (white noise of
        standard deviation sigma has ``E |X_k|^2 = n sigma^2``); 0 for a channel without
        noise there.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> round(channel_noise(0.5 * rng.standard_normal(100_000), 100.0), 2)
    0.5
    """
    X = np.fft.rfft(x - np.mean(x)) if spectrum is None else spectrum
    f = np.fft.rfftfreq(x.size, 1 / fs_hz)
    nyq = fs_hz / 2
    sel = (f >= NOISE_BAND[0] * nyq) & (f <= NOISE_BAND[1] * nyq)
    if not np.any(sel):
        return 0.0
    return float(np.sqrt(np.mean(np.abs(X[sel]) ** 2) / x.size))


def _band(X, n, fs_hz, band):
    """Zero-phase band-pass by an FFT mask of a spectrum ``X`` (``rfft`` of n samples)."""
    f = np.fft.rfftfreq(n, 1 / fs_hz)
    return np.fft.irfft(np.where((f < band[0]) | (f > band[1]), 0, X), n)


def _hinge(x, r, sigma):
    """Fit ``k max(0, x - s0)^p`` (k > 0) to a residual; the most significant onset.

    Returns ``(z, s0, p, k)``: z = the slope over its standard error ``sigma /
    sqrt(sum h^2)``; z 0 when nothing fits.
    """
    best = (0.0, np.nan, 1, 0.0)
    if sigma <= 0 or x.size < 100:
        return best
    # the products on one BLAS thread with the multithreaded products' bits: 240 products of
    # 10^4-10^5 samples per call, each of which woke OpenBLAS's second thread (issue 40)
    with serial_dots() as dot:
        for s0 in np.unique(np.quantile(x, 1 - _HINGE_SHARES)):
            above = x > s0
            if above.sum() < 5:
                continue
            d = x[above] - s0
            ra = r[above]
            for p in (1, 2):
                h = d ** p
                hh = dot(h, h)
                if hh <= 0:
                    continue
                k = dot(h, ra) / hh
                z = k * np.sqrt(hh) / sigma
                if z > best[0]:
                    best = (z, float(s0), p, k)
    return best


def _balance_parts(run, corner, levels, declared_force):
    """The wheel's force balance ``tire - spring - shock`` (less the declared stop's force)
    and its linear columns: ``(e, X, travel)``, or None without the channels."""
    other = {"LF": "RF", "RF": "LF", "LR": "RR", "RR": "LR"}[corner]
    need = [f"{k}_{corner}" for k in ("tire_force", "spring_force", "shock_force",
                                      "wheel_accel", "shock_travel")]
    if any(c not in run.channels for c in need):
        return None
    ch = {c: run.channels[c] - levels[c] for c in need}
    s = ch[f"shock_travel_{corner}"]
    e = ch[f"tire_force_{corner}"] - ch[f"spring_force_{corner}"] - ch[f"shock_force_{corner}"]
    if declared_force is not None:
        e = e - declared_force
    cols = [ch[f"wheel_accel_{corner}"], s, np.ones_like(s)]
    if f"shock_travel_{other}" in run.channels:
        cols.append(run.channels[f"shock_travel_{other}"] - levels[f"shock_travel_{other}"])
    return e, np.column_stack(cols), s


def _balance_residual(run, corner, levels, declared_force):
    """The wheel's force balance beyond the linear part: ``(residual, sigma)`` or None.

    ``tire - spring - shock`` regressed (where the travel is below its median) on the
    wheel's acceleration, both travels of the axle and a constant; the declared stop's
    force is taken out first.
    """
    parts = _balance_parts(run, corner, levels, declared_force)
    if parts is None:
        return None
    e, X, s = parts
    low = s < np.median(s)
    scale = np.maximum(np.abs(X[low]).max(axis=0), 1e-300)
    coef = np.linalg.lstsq(X[low] / scale, e[low], rcond=None)[0] / scale
    r = e - X @ coef
    return r, float(np.std(r[low]))


def _heave_stiffening(run, levels, declared, tire_rms):
    """Per axle, a stiffening common to its two wheels against their heave travel.

    The two wheels' force-balance residuals (:func:`_balance_residual`, the declared
    elements taken out) are fitted with one hinge on the axle's heave travel (the mean of
    the two corners' shock travel from rest), common to both (:func:`_hinge` of their mean),
    and with a hinge per corner on its own travel. Returns ``{axle: (z, onset_m, share,
    force_share, ratio)}`` for the axles with both wheels' channels: `ratio` is the force
    the common hinge explains over what the two corners' hinges explain together.
    """
    out = {}
    for axle, (left, right) in zip(AXLES, (("LF", "RF"), ("LR", "RR"))):
        parts = []
        for c in (left, right):
            bal = _balance_residual(run, c, levels, declared.get(c))
            if bal is None:
                break
            x = run.channels[f"shock_travel_{c}"] - levels[f"shock_travel_{c}"]
            parts.append((x,) + bal)
        if len(parts) < 2:
            continue
        (xl, rl, sl), (xr, rr, sr) = parts
        xh = (xl + xr) / 2
        z, s0, p, k = _hinge(xh, (rl + rr) / 2, float(np.hypot(sl, sr)) / 2)
        if not z > 0:
            continue
        common = 2 * k ** 2 * float(np.sum(np.maximum(xh - s0, 0.0) ** (2 * p)))
        own = 0.0
        for x, r, sig in parts:
            zc, sc, pc, kc = _hinge(x, r, sig)
            if zc > 0:
                own += kc ** 2 * float(np.sum(np.maximum(x - sc, 0.0) ** (2 * pc)))
        force = k * max(np.quantile(xh, 0.999) - s0, 0.0) ** p
        rms = np.nanmean([tire_rms.get(left, np.nan), tire_rms.get(right, np.nan)])
        out[axle] = (z, s0, float(np.mean(xh > s0)), force / rms if rms > 0 else np.inf,
                     common / own if own > 0 else np.inf)
    return out


def _third_loop(session, run):
    """The run's fitted third elements as :func:`ident.sim.third_loop.simulate_third` takes
    them: ``(dampers, springs)``, or None when the run fits none."""
    elements = getattr(session, "third_elements", None)
    if not elements or not run.third:
        return None
    dampers = [ThirdDamper(e, elements.row(e),
                           session.shocks.get(sid, where=f"run '{run.name}' third {e}"))
               for e, sid in run.third.dampers.items() if sid is not None]
    springs = []
    for axle, sid in run.third.heave_springs.items():
        if sid is None:
            continue
        contact = contact_tables([session.bump_stops[sid], None, None, None],
                                 [run.third.heave_packers_m.get(axle, 0.0), 0.0, 0.0, 0.0],
                                 where=f"run '{run.name}': heave_springs {axle}")[0]
        springs.append(ThirdSpring(f"heave_{axle}", elements.row(f"heave_{axle}"), contact))
    return dampers, springs


def shock_velocity(run, corner):
    """A corner's shock velocity [m/s]: the channel, else the travel differentiated.

    Parameters
    ----------
    run : ident.data.session.Run
    corner : str

    Returns
    -------
    ndarray, shape (n_samples,), or None
        ``shock_velocity_XX``, else the central difference of ``shock_travel_XX``
        (:func:`numpy.gradient` times the sample rate); None without either.
    """
    name = f"shock_velocity_{corner}"
    if name in run.channels:
        return np.asarray(run.channels[name], dtype=float)
    travel = run.channels.get(f"shock_travel_{corner}")
    return None if travel is None else np.gradient(travel) * run.fs_hz


def _friction(run, corner, levels, declared_force):
    """The Coulomb friction the wheel's force balance holds beyond its linear part.

    ``tire - spring - shock`` (less a declared stop) regressed, where the travel is below
    its median (no bump stop), on the balance's linear columns (:func:`_balance_parts`),
    the shock velocity (a viscous part: a shock-force gain or a damping the channels miss)
    and ``tanh(v / band)`` as the samples see it, band the sticking band
    :data:`FRICTION_BAND_M_S` or the velocity's measured noise if larger. As the samples
    see it: the velocity interpolated :data:`FRICTION_REFINE` x (band limited), the tanh
    taken there and decimated back through the band-limited filter; at 100 Hz the
    velocity moves by about 0.1 m/s per sample, far more than the band, so the sampled
    friction is a sign smoothed by the acquisition filter, and ``tanh(v / band)`` on the
    samples themselves would read 100 N as 74 N (measured; matched: 98-99 N). Returns ``dict(friction_n, friction_z,
    friction_share, friction_band_m_s, friction_v_rms_m_s)`` or None without the
    channels: ``friction_n`` the tanh's coefficient [N], ``friction_z`` it over its
    standard error, ``friction_share`` the share of the run's time within the band.
    """
    parts = _balance_parts(run, corner, levels, declared_force)
    v = shock_velocity(run, corner)
    if parts is None or v is None:
        return None
    e, X, s = parts
    v = v - np.mean(v)
    band = max(FRICTION_BAND_M_S, channel_noise(v, run.fs_hz))
    fine = refine_input(v[:, None], FRICTION_REFINE)[:, 0]
    sign = decimate_bandlimited([np.tanh(fine / band)], FRICTION_REFINE, v.size)[0]
    low = s < np.median(s)
    A = np.column_stack([X, v, sign])[low]
    scale = np.maximum(np.abs(A).max(axis=0), 1e-300)
    An = A / scale
    coef = np.linalg.lstsq(An, e[low], rcond=None)[0]
    res = e[low] - An @ coef
    dof = max(int(low.sum()) - A.shape[1], 1)
    sigma = float(np.sqrt(res @ res / dof))
    cov = np.linalg.pinv(An.T @ An)
    se = sigma * np.sqrt(max(float(cov[-1, -1]), 0.0))
    fc = float(coef[-1] / scale[-1])
    z = fc / (se / scale[-1]) if se > 0 else (np.inf if fc > 0 else 0.0)
    return {"friction_n": fc, "friction_z": float(z),
            "friction_share": float(np.mean(np.abs(v) < band)),
            "friction_band_m_s": float(band), "friction_v_rms_m_s": float(np.std(v))}


def _simulate_run(plant, run, session, levels, oversample, failed):
    """The run re-simulated on the model: its rig inputs from rest, its shocks, and the
    bump stops and static loads the session declares (the loop solves them).

    Returns ``(response, note)``: the note says what was left out where the loop did not
    converge with the declared elements ("" when nothing was). `failed` (a set) remembers
    that the full loop failed on an earlier run of the same model, so that it is not
    tried again (a failed loop costs a whole run's simulation).
    """
    drive = Drive(name=f"run {run.name}", fs_hz=run.fs_hz,
                  channels={c: run.channels[c] - levels[c] for c in RIG_INPUTS
                            if c in run.channels})
    models = [session.shocks[run.setup[c]] for c in CORNERS]
    names = set(plant.output_names)
    stops = None
    if session.bump_stops is not None and all(f"shock_travel_{c}" in names for c in CORNERS):
        stops = {}
        for c in CORNERS:
            sid = run.bump_stops.get(c)
            if sid is not None:
                st = session.bump_stops[sid]
                stops[c] = (st.contact_travel_m(run.packers_m.get(c, 0.0)), st.travel_m,
                            st.force_n)
        stops = stops or None
    static = session.static_corner_load_n
    if static is not None and not all(f"tire_force_{c}" in names for c in CORNERS):
        static = None
    third = _third_loop(session, run) if all(
        f"shock_travel_{c}" in names for c in CORNERS) else None
    if third is not None and "third" not in failed:
        # the car with its third elements: the coupled loop, on the refined drive
        r = max(int(oversample), 1)
        u = refine_input(drive.as_array(), r)
        fine = Drive(name=drive.name, fs_hz=drive.fs_hz * r,
                     channels={c: u[:, j] for j, c in enumerate(RIG_INPUTS)
                               if c in drive.rig_inputs})
        try:
            resp = simulate_third(plant, fine, models, dampers=third[0], springs=third[1],
                                  stop_tables=None if stops is None else
                                  [stops.get(c) for c in CORNERS])
        except ValueError as exc:
            failed.add("third")
            log.info("run %s: re-simulation with the third elements failed (%s)", run.name,
                     exc)
        else:
            return _Resampled({k: v[::r] for k, v in resp.channels.items()}), ""
    tries = [("full", stops, static, "")]
    if static is not None:
        tries.append(("stops", stops, None, ("without the static loads (the lift-off loop did "
                                            "not converge on this model)")))
    if stops is not None or static is not None:
        tries.append(("plain", None, None, ("without the bump stops and static loads (the loop "
                                           "did not converge with them on this model)")))
    tries = [t for t in tries if t[0] not in failed]
    if third is not None:
        tries = [(key, st, sl, note or "without the third elements (the loop did not "
                  "converge with them on this model)") for key, st, sl, note in tries]
    for k, (key, st, sl, note) in enumerate(tries):
        try:
            resp = simulate(plant, drive, models, oversample=oversample, stop_tables=st,
                            static_corner_load_n=sl)
        except ValueError as exc:
            if k == len(tries) - 1:
                raise
            failed.add(key)  # not tried again on the other runs
            log.info("run %s: re-simulation with the declared elements failed (%s)",
                     run.name, exc)
            continue
        return resp, note


@dataclass(frozen=True)
class _Resampled:
    """A re-simulated run's channels at the run's samples (as a ``Response`` has them)."""

    channels: dict


_EFFECTS = {
    "stiffening": (("signs of a bump stop: the wheel's force balance stiffens in compression "
                   "beyond {travel} of travel from rest ({rest}); the identified "
                   "model is linear and reads the stop as a stiffer car everywhere, so "
                   "predicted metrics are off by up to a few per cent (on the virtual rig: "
                   "0.4 % median, 3 % max with stops touched 2-6 %) and most for setups "
                   "that change travel"),
                   ("declare the bump stops: bump_stop_library = \"bumpstops.toml\" in "
                   "session.toml and each run's bump_stops (and packers); or lower the drive "
                   "level so that the stops are not reached")),
    "heave stiffening": (("signs of an undeclared heave element at the {axle} axle: the "
                         "{pair} wheels' force balances stiffen together in compression "
                         "beyond {travel} of the axle's heave travel (the mean of their shock "
                         "travels from rest, {rest}), more than either corner's own travel "
                         "explains: a heave spring with a gap (a third element) or a heave "
                         "bump stop; the identified model is linear and reads it as a stiffer "
                         "car everywhere, so predicted metrics are off where it acts"),
                         ("declare the third element: third_elements = {{ heave_{axle} = "
                          "<motion ratio> }} in session.toml, and each run's third and "
                          "heave_springs (the heave spring's gap and table in the bump-stop "
                          "library); or lower the drive level or the aero load so that it is "
                          "not reached")),
    "stiffening_travel": (("signs of a bump stop: the measured travel stays below the "
                          "model's beyond {travel} of its travel from rest ({rest}; "
                          "without force channels the onset and share are rough); the model "
                          "reads the stop as a stiffer car everywhere, so predicted metrics "
                          "are off by up to a few per cent"),
                          ("declare the bump stops (bump_stop_library and each run's "
                          "bump_stops in session.toml), or lower the drive level")),
    "stiffening_declared": (("stiffening beyond the declared bump stop from {travel} "
                            "of travel from rest ({rest}): the declared gap or table does not "
                            "match the car, and predictions with it are off where it acts"),
                            ("check the declared bump stop's gap, table and packer against "
                            "the car")),
    "bump stop contact": (("travel beyond the declared bump stop's contact ({travel} "
                          "from rest, {rest}) {share_pct:.1f} % of the time; the loop solves "
                          "the declared stop, and setups that travel further than the session "
                          "are extrapolated"),
                          ("none needed (declared); for a model that rests less on the "
                          "stop, lower the drive level so that it is touched less")),
    "lift-off": (("contact force near zero (below {near:.0f} % of the static load) "
                 "{share_pct:.1f} % of the time, smallest {force} ({how}); a linear "
                 "model lets the tire pull on the pad: without the static loads, predicted "
                 "metrics are off by up to a few per cent (measured 0.2 % median, 2.6 % max "
                 "at 0.5-1.9 % of the time off the pads)"),
                 "{fix_static}lower the drive level so that the tires stay on the pads"),
    "lift-off floor": (("the tire force sits on a floor at {force} {share_pct:.1f} % of "
                       "the time: the tire leaves its pad there (contact zero, the static "
                       "load about {load_force}); a linear model lets the tire pull on the "
                       "pad: predicted metrics are off by up to a few per cent (measured "
                       "0.2 % median, 2.6 % max at 0.5-1.9 % of the time off the pads)"),
                       "{fix_static}lower the drive level so that the tires stay on the pads"),
    "friction": (("a force in phase with the sign of the shock velocity, {force} "
                 "beyond the wheel's linear force balance: suspension friction in parallel "
                 "with the shock (bushings, bearings, seals; the shock's load cell does not "
                 "see it), the shock within its sticking band (|v| < {band_velocity}) "
                 "{share_pct:.1f} % of the time; the identified model is linear and holds it "
                 "as an equivalent damping of about {c_eq_damping} at this run's shock "
                 "velocity ({v_rms_velocity} RMS): low-speed damping is over-estimated for "
                 "light setups and drives that move the shock faster, under-estimated for "
                 "stiff ones, and predictions near low shock speeds are less certain"),
                 ("friction is not a declarable element of the session: measure its "
                 "breakaway force on the rig with a slow ramp (a few mm/s), lower it "
                 "(bushings, bearings, seals), or accept it and trust predictions for setups "
                 "far from the session's shock velocities less")),
    "residual": (("the run re-simulated on the identified model with its own shocks misses "
                 "{value_pct:.0f} % of {channel} in {band} Hz beyond its noise "
                 "({noise_pct:.1f} %): the model does not describe this run, and predictions "
                 "carry an error of that order at this corner"),
                 ("declare the bump stops and static loads if the car has them, lower the "
                 "drive level, or check the channel's calibration and sign")),
    "amplitude": (("the residual grows with the drive level: {value:.1f}x from run {low} "
                  "(level {low_level}) to this run ({high_level}): the car is "
                  "nonlinear at these amplitudes, and predictions hold only at the "
                  "session's level"),
                  ("lower the drive level to where the residual stays flat, or declare the "
                  "bump stops and static loads")),
}


def diagnose_session(session, model, *, oversample=2, residual=True, plant=None):
    """Check a session against its identified linear model (see the module docstring).

    Parameters
    ----------
    session : ident.data.session.Session
        The session the model was identified from (or any session of the same car).
    model : ident.identify.model.VehicleModel
        The identified model; its loop plant re-simulates the runs.
    oversample : int
        Internal steps per sample of the re-simulation (2: the planner's; the loop's own
        error, 5e-4 of the metrics, is far below the residuals reported).
    residual : bool
        Re-simulate the runs (the validation residual, the amplitude check and, without
        force channels, the stiffening check on the travel). False: the data-only checks.
    plant : ident.models.lti.LoopPlant, optional
        The model's loop plant (default ``model.loop_plant()``, built once per model).

    Returns
    -------
    Diagnosis
        Its findings are logged as warnings, one per finding.

    Raises
    ------
    TypeError
        If `session` or `model` is not a session or a model.
    """
    if not hasattr(session, "runs") or not hasattr(session, "shocks"):
        raise TypeError(f"diagnose_session needs a Session, got {type(session).__name__}")
    if not hasattr(model, "loop_plant"):
        raise TypeError(f"diagnose_session needs a VehicleModel, got {type(model).__name__}")
    if residual and plant is None:
        plant = model.loop_plant()
    static = session.static_corner_load_n
    findings, checks = [], []
    level_by_run = {}
    failed = set()
    for run in session.runs:
        levels, used = rest_levels(run)
        rest_word = ("the car at rest at the start of the run" if used == "rest (start)" else
                     "the car at rest at the end of the run" if used == "rest (end)" else
                     "the run's mean: the run does not start or end at rest")
        fs = run.fs_hz
        wl = [run.dynamic(c) for c in WHEELLOADER_INPUTS if c in run.channels]
        level_by_run[run.name] = float(np.sqrt(np.mean(np.square(wl)))) if wl else 0.0
        sim = None
        if residual:
            resp, note = _simulate_run(plant, run, session, levels, oversample, failed)
            sim = resp.channels
        # the declared third elements' force at the corners, out of the wheels' balance
        third_force = None
        if getattr(session, "third_elements", None) and run.third:
            third_force = third_element_force(run, session.third_elements, session.shocks,
                                              session.bump_stops, levels=levels)[0]
        declared = {}
        for ci, c in enumerate(CORNERS):
            sid = run.bump_stops.get(c)
            stop = None if sid is None or session.bump_stops is None else session.bump_stops[sid]
            if stop is not None and f"shock_travel_{c}" in run.channels:
                declared[c] = stop.force(run.channels[f"shock_travel_{c}"]
                                         - levels[f"shock_travel_{c}"], run.packers_m.get(c, 0.0))
            if third_force is not None and np.any(third_force[ci]):
                declared[c] = third_force[ci] + declared.get(c, 0.0)
        # an undeclared heave element: a stiffening common to both wheels of an axle
        tire_rms = {c: float(np.std(run.channels[f"tire_force_{c}"])) for c in CORNERS
                    if f"tire_force_{c}" in run.channels}
        heave = {}
        for axle, (z, s0, share, force_share, ratio) in _heave_stiffening(
                run, levels, declared, tire_rms).items():
            log.debug("run %s, %s axle: heave stiffening z %.3g, onset %.4g m, force share "
                      "%.3g, common/own %.3g", run.name, axle, z, s0, force_share, ratio)
            if (z >= STIFFENING_Z and force_share >= STIFFENING_FORCE_SHARE
                    and ratio >= HEAVE_PREFERENCE):
                heave[axle] = True
                findings.append(_finding(run.name, axle, "heave stiffening", share, s0,
                                         rest=rest_word, axle=axle))
        for ci, c in enumerate(CORNERS):
            row = {"run": run.name, "corner": c, "drive_level_m": level_by_run[run.name]}
            if sim is not None:
                row["resimulated"] = note or "with the declared elements"
            travel_name = f"shock_travel_{c}"
            travel = None
            if travel_name in run.channels:
                travel = run.channels[travel_name] - levels[travel_name]
                row["rest"] = used
                row["rest_minus_mean_m"] = levels[travel_name] - float(
                    np.mean(run.channels[travel_name]))
            # declared bump stop: share beyond contact
            sid = run.bump_stops.get(c)
            stop = None if sid is None or session.bump_stops is None else session.bump_stops[sid]
            declared_force = declared.get(c)
            if stop is not None and travel is not None:
                packer = run.packers_m.get(c, 0.0)
                s0 = stop.contact_travel_m(packer)
                share = float(np.mean(travel > s0))
                row["contact_share"] = share
                if share >= CONTACT_SHARE_MIN:
                    findings.append(_finding(run.name, c, "bump stop contact", share, s0,
                                             rest=rest_word))
            # undeclared stop: a one-sided force excess in compression
            bal = _balance_residual(run, c, levels, declared_force)
            tire_name = f"tire_force_{c}"
            tire_rms = (float(np.std(run.channels[tire_name])) if tire_name in run.channels
                        else np.nan)
            hinge = None
            if bal is not None:
                r, sigma = bal
                hinge = _hinge(travel, r, sigma) + (travel, "stiffening" if stop is None
                                                    else "stiffening_declared")
            elif sim is not None and travel is not None and travel_name in sim:
                r = sim[travel_name] - travel  # the stop holds the measured travel back
                x = sim[travel_name]
                low = x < np.median(x)
                hinge = _hinge(x, r, float(np.std(r[low]))) + (x, "stiffening_travel")
            if hinge is not None:
                z, s0, p, k, x, variant = hinge
                row["stiffening_z"] = z
                if z > 0:
                    top = np.quantile(x, 0.999)
                    force = k * max(top - s0, 0.0) ** p
                    if variant == "stiffening_travel":
                        # a travel deficit, against the travel's spread
                        force_share = force / max(float(np.std(x)), 1e-300)
                    else:
                        force_share = force / tire_rms if tire_rms > 0 else np.inf
                    share = float(np.mean(x > s0))
                    row.update(stiffening_onset_m=s0, stiffening_share=share, stiffening_power=p,
                               stiffening_force_share=force_share)
                    limit = (STIFFENING_TRAVEL_SHARE if variant == "stiffening_travel"
                             else STIFFENING_FORCE_SHARE)
                    if (z >= STIFFENING_Z and force_share >= limit
                            and ("front" if ci < 2 else "rear") not in heave):
                        findings.append(_finding(run.name, c, "stiffening", share, s0,
                                                 variant=variant, rest=rest_word))
            # suspension friction: a force in phase with the sign of the shock velocity
            fr = _friction(run, c, levels, declared_force)
            if fr is not None:
                row.update(fr)
                shock_rms = float(np.std(run.channels[f"shock_force_{c}"]))
                row["friction_force_share"] = (fr["friction_n"] / shock_rms if shock_rms > 0
                                               else np.inf)
                if (fr["friction_z"] >= FRICTION_Z
                        and row["friction_force_share"] >= FRICTION_FORCE_SHARE):
                    findings.append(_finding(
                        run.name, c, "friction", fr["friction_share"], fr["friction_n"],
                        band=fr["friction_band_m_s"], v_rms=fr["friction_v_rms_m_s"]))
            # lift-off: contact near zero
            if tire_name in run.channels:
                x = run.channels[tire_name]
                contact, load, how = None, None, None
                if static is not None:
                    load = float(static[ci])
                    if abs(np.mean(x)) > STATIC_OFFSET_SHARE * load:
                        contact, how = x, "the tire-force channel carries the static load"
                    else:
                        contact = load + (x - levels[tire_name])
                        how = "static load given plus the tire-force channel"
                elif used != "mean" and levels[tire_name] > CARRIED_REST_SIGMAS * (
                        np.std(x)):
                    load = levels[tire_name]
                    contact, how = x, ("the tire-force channel carries the static load, "
                                       f"{load:.0f} N at rest")
                if contact is None:  # no static load known: a floor in the channel
                    floor = _tire_floor(x)
                    if floor is not None:
                        share, level = floor
                        row["liftoff_share"] = share
                        findings.append(_finding(run.name, c, "lift-off", share, level,
                                                 variant="lift-off floor"))
                if contact is not None:
                    share = float(np.mean(contact < NEAR_ZERO_CONTACT * load))
                    row["liftoff_share"] = share
                    row["contact_min_n"] = float(contact.min())
                    if share >= LIFTOFF_SHARE_MIN:
                        findings.append(_finding(run.name, c, "lift-off", share,
                                                 float(contact.min()), how=how,
                                                 given=static is not None))
            # validation residual
            if sim is not None:
                worst = (0.0, None, 0.0)
                for name in sim:
                    if not name.endswith("_" + c) or name not in run.channels:
                        continue
                    x = run.channels[name]
                    X = np.fft.rfft(x - np.mean(x))
                    r = _band(X - np.fft.rfft(sim[name] - np.mean(x) + levels[name]), x.size,
                              fs, RESIDUAL_BAND_HZ)
                    rms = float(np.sqrt(np.mean(_band(X, x.size, fs, RESIDUAL_BAND_HZ) ** 2)))
                    if rms <= 0:
                        continue
                    e = float(np.sqrt(np.mean(r ** 2))) / rms
                    nz = channel_noise(x, fs, spectrum=X) * np.sqrt(
                        (RESIDUAL_BAND_HZ[1] - RESIDUAL_BAND_HZ[0]) / (fs / 2)) / rms
                    excess = float(np.sqrt(max(e ** 2 - nz ** 2, 0.0)))
                    if excess > worst[0]:
                        worst = (excess, name, nz)
                row.update(residual_excess=worst[0], residual_channel=worst[1], noise=worst[2])
                if worst[0] > RESIDUAL_EXCESS_MAX:
                    findings.append(_finding(run.name, c, "residual", np.nan, worst[0],
                                             channel=worst[1], noise=worst[2]))
            checks.append(row)
    checks = pd.DataFrame(checks)
    if residual and len(level_by_run) > 1:
        findings += _amplitude(checks, level_by_run)
    table = pd.DataFrame(findings, columns=list(FINDING_COLUMNS))
    table[["share", "value"]] = table[["share", "value"]].astype(float)
    diagnosis = Diagnosis(findings=table, checks=checks, settings={})
    for g in diagnosis.groups():
        log.warning("%s: %s: %s; fix: %s", g["corner"], _headline(g), g["message"], g["fix"])
    settings = {"oversample": int(oversample), "residual": bool(residual),
                "rest_window_s": REST_WINDOW_S, "stiffening_z": STIFFENING_Z,
                "stiffening_force_share": STIFFENING_FORCE_SHARE,
                "friction_z": FRICTION_Z, "friction_force_share": FRICTION_FORCE_SHARE,
                "friction_band_m_s": FRICTION_BAND_M_S,
                "near_zero_contact": NEAR_ZERO_CONTACT, "liftoff_share_min": LIFTOFF_SHARE_MIN,
                "contact_share_min": CONTACT_SHARE_MIN, "residual_band_hz": RESIDUAL_BAND_HZ,
                "residual_excess_max": RESIDUAL_EXCESS_MAX,
                "amplitude": ("checked" if residual and len(level_by_run) > 1 and
                              max(level_by_run.values()) >= AMPLITUDE_LEVEL_RATIO * max(
                                  min(level_by_run.values()), 1e-300)
                              else "not checked: the runs' drive levels differ by less than "
                              f"{AMPLITUDE_LEVEL_RATIO:g}x" if residual else
                              "not checked: no re-simulation"),
                "session": session.name}
    return Diagnosis(findings=table, checks=checks, settings=settings)


def _headline(group):
    """``kind, share x-y % of the time in n of m runs`` of a group."""
    n = len(group["runs"])
    runs = f"run {group['runs'][0]}" if n == 1 else f"{n} runs"
    if not np.isfinite(group["share_max"]):
        return f"{group['kind']} ({runs})"
    lo, hi = 100 * group["share_min"], 100 * group["share_max"]
    share = f"{hi:.1f} %" if n == 1 or abs(hi - lo) < 0.05 else f"{lo:.1f}-{hi:.1f} %"
    return f"{group['kind']} {share} of the time ({runs})"


def _amplitude(checks, level_by_run):
    """Residuals that grow with the drive level (one finding per corner at most)."""
    lo_run = min(level_by_run, key=level_by_run.get)
    hi_run = max(level_by_run, key=level_by_run.get)
    lo, hi = level_by_run[lo_run], level_by_run[hi_run]
    if hi < AMPLITUDE_LEVEL_RATIO * max(lo, 1e-300) or "residual_excess" not in checks:
        return []
    out = []
    for c in CORNERS:
        at = checks[checks.corner == c].set_index("run")["residual_excess"]
        e_lo, e_hi = float(at.get(lo_run, np.nan)), float(at.get(hi_run, np.nan))
        if not (np.isfinite(e_lo) and np.isfinite(e_hi)):
            continue
        growth = e_hi / max(e_lo, 1e-3)
        if e_hi > RESIDUAL_EXCESS_MAX / 2 and growth >= AMPLITUDE_GROWTH:
            out.append(_finding(hi_run, c, "amplitude", np.nan, growth, low=lo_run,
                                low_mm=1e3 * lo, high_mm=1e3 * hi))
    return out


def _tire_floor(x):
    """``(share, level)`` of a floor at the bottom of a dynamic tire-force channel (the tire
    off its pad, :data:`FLOOR_WIDTH_SIGMAS`, :data:`FLOOR_CROWDING`), or None."""
    x = np.asarray(x, dtype=float)
    sd = float(np.std(x))
    if not sd > 0:
        return None
    width = FLOOR_WIDTH_SIGMAS * sd
    lo, hi = float(x.min()), float(x.max())
    bottom = float(np.mean(x <= lo + width))
    top = float(np.mean(x >= hi - width))
    if bottom < LIFTOFF_SHARE_MIN or bottom < FLOOR_CROWDING * top:
        return None
    return bottom, float(np.median(x[x <= lo + width]))


def _shown(value_si, quantity, *, small=False):
    """A value with its unit in the display units, ``nan`` kept as ``nan``."""
    if not np.isfinite(value_si):
        return "nan"
    return format_quantity(value_si, quantity, small=small)


def _finding(run, corner, kind, share, value, *, variant=None, rest="rest", how="",
             given=False, channel="", noise=0.0, low="", low_mm=0.0, high_mm=0.0,
             band=np.nan, v_rms=np.nan, axle=""):
    message, fix = _EFFECTS[variant or kind]
    fields = {"value_mm": 1e3 * value if np.isfinite(value) else np.nan, "value": value,
              "rest": rest, "share_pct": 100 * share if np.isfinite(share) else np.nan,
              "near": 100 * NEAR_ZERO_CONTACT, "how": how,
              "fix_static": "" if given else ("give the static loads (static_corner_load in "
                                             "session.toml) so that the loop keeps the contact "
                                             "at or above zero; to identify cleanly, "),
              "value_pct": 100 * value, "channel": channel, "noise_pct": 100 * noise,
              "band": f"{RESIDUAL_BAND_HZ[0]:g}-{RESIDUAL_BAND_HZ[1]:g}", "low": low,
              "low_mm": low_mm, "high_mm": high_mm, "band_mm_s": 1e3 * band,
              "v_rms": v_rms, "c_eq": (value * np.sqrt(2 / np.pi) / v_rms
                                       if v_rms > 0 else np.nan),
              "load": -value if np.isfinite(value) else np.nan, "axle": axle,
              "pair": {"front": "LF and RF", "rear": "LR and RR"}.get(axle, "")}
    # the values with their units, in the run's unit system (ident.data.units.display_units)
    fields.update(travel=_shown(value, "displacement", small=True),
                  force=_shown(value, "force"), load_force=_shown(fields["load"], "force"),
                  band_velocity=_shown(band, "velocity", small=True),
                  c_eq_damping=_shown(fields["c_eq"], "damping"),
                  v_rms_velocity=_shown(v_rms, "velocity"),
                  low_level=_shown(low_mm / 1e3, "displacement", small=True),
                  high_level=_shown(high_mm / 1e3, "displacement", small=True))
    fix = fix.format(**fields)
    if kind == "lift-off" and given:
        fix = ("the static loads are declared (the loop keeps the contact); to identify "
               "cleanly, " + fix)
    return {"run": run, "corner": corner, "kind": kind, "share": share, "value": value,
            "message": message.format(**fields), "fix": fix}
