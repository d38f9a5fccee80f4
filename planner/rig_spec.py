"""The rig TOML: time costs and actuator limits.

A rig file (``format = "rig/1"``, ``docs/formats.md``) says what a rig run costs besides
its drive, for :func:`planner.design.design_experiment` (:class:`RigSpec`), and,
optionally, what the rig's actuators can play (:class:`RigLimits`), for the drives the
planner builds (:func:`apply_rig_limits`)::

    format = "rig/1"
    name = "8-post"
    swap_min = 4.5                  # min per corner whose shock changes
    run_overhead_min = 2.0          # min per run
    click_change_s = 20             # s per adjuster turned
    units = "imperial"              # of [limits] only (default "SI")

    [limits]                        # every key optional; a key left out: no limit
    wheelloader_displacement = 1.0  # peak, +-  [in | m]
    wheelloader_velocity = 40.0     # [in/s | m/s]
    wheelloader_acceleration = 1500 # [in/s^2 | m/s^2]
    aero_heave = 2000.0             # [lbf | N]
    aero_roll = 9000.0              # [lbf*in | N*m]
    aero_pitch = 30000.0            # [lbf*in | N*m]

``units`` converts the limits only (:func:`ident.data.units.to_si`); the times are
minutes and seconds as their names say, in any unit system. A file without
``[limits]`` reads as it always did (``RigSpec.limits`` is ``None``).

Limits on a drive
-----------------
A wheelloader's velocity and acceleration are the first and second derivatives of its
displacement at the drive's rate: ``v = numpy.gradient(x, 1/fs)`` and
``a = numpy.gradient(v, 1/fs)`` (central differences inside, one-sided at the two ends;
the same definition everywhere in this module: :func:`drive_derivatives`). The aero
inputs have a force or moment limit only. :func:`apply_rig_limits` respects the limits
one of two ways:

- ``"scale"``: the four wheelloaders are multiplied by one factor, the smallest
  ``limit / peak`` over their channels and quantities, so that their relative content
  (left/right, front/rear) is kept; the aero inputs by a factor of their own from their
  force and moment limits. A peak scales with its signal, so every limit then holds.
- ``"clip"``: a smooth local limiter per channel, which changes the drive only around
  the samples that exceed a limit (see :func:`apply_rig_limits`, Notes).

Examples
--------
>>> import numpy as np
>>> from ident.data.channels import WHEELLOADER_INPUTS
>>> from ident.data.drive import Drive
>>> x = 0.02 * np.sin(2 * np.pi * np.arange(2000) / 200.0)   # 20 mm at 1 Hz, 200 Hz
>>> drive = Drive("sine", 200.0, dict.fromkeys(WHEELLOADER_INPUTS, x))
>>> limits = RigLimits(wheelloader_displacement_m=0.01)
>>> scaled = apply_rig_limits(drive, limits, action="scale")
>>> scaled.scale, float(abs(scaled.drive.channels["wheelloader_LF"]).max())
(0.5, 0.01)
>>> clipped = apply_rig_limits(drive, limits, action="clip")
>>> float(abs(clipped.drive.channels["wheelloader_LF"]).max())
0.01
>>> apply_rig_limits(drive, RigLimits(wheelloader_displacement_m=0.05)).drive is drive
True
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import ndimage, signal

from ident.data.channels import AERO_INPUTS, WHEELLOADER_INPUTS, quantity_of
from ident.data.drive import Drive
from ident.data.files import did_you_mean, read_toml
from ident.data.units import UNIT_LABELS, check_units, from_si, to_si
from planner.errors import PlannerError

__all__ = [
    "RIG_FORMAT",
    "LIMIT_KEYS",
    "LIMIT_ACTIONS",
    "LIMIT_RTOL",
    "CLIP_WINDOW_S",
    "RigLimits",
    "RigSpec",
    "LimitedDrive",
    "default_rig",
    "read_rig",
    "drive_derivatives",
    "apply_rig_limits",
]

log = logging.getLogger(__name__)

#: The ``format`` of rig TOML files.
RIG_FORMAT = "rig/1"
#: The keys of a rig file's ``[limits]`` table -> (the :class:`RigLimits` field, the
#: quantity of :data:`ident.data.units.TO_SI`, the rig inputs it limits).
LIMIT_KEYS = {
    "wheelloader_displacement": ("wheelloader_displacement_m", "displacement",
                                 WHEELLOADER_INPUTS),
    "wheelloader_velocity": ("wheelloader_velocity_m_s", "velocity", WHEELLOADER_INPUTS),
    "wheelloader_acceleration": ("wheelloader_acceleration_m_s2", "acceleration",
                                 WHEELLOADER_INPUTS),
    "aero_heave": ("aero_heave_n", "force", ("aero_heave",)),
    "aero_roll": ("aero_roll_n_m", "moment", ("aero_roll",)),
    "aero_pitch": ("aero_pitch_n_m", "moment", ("aero_pitch",)),
}
#: How :func:`apply_rig_limits` respects the limits.
LIMIT_ACTIONS = ("clip", "scale")
#: Relative slack of a limit after ``"clip"`` on the derivatives [-]: the limiter's passes
#: stop once every velocity and acceleration peak is within 0.1 % of its limit (and of the
#: original's peak). Each pass multiplies by a gain that meets the limit at the samples, but
#: the gain's own slope adds ``x * de/dt`` to the velocity, so the peaks approach the limit
#: geometrically; 0.1 % is far below any rig's actuator margin. The displacement (and force,
#: moment) limit holds exactly.
LIMIT_RTOL = 1e-3
#: The limiter's shortest window [s]: the moving minimum and the Hann smoothing of the gain
#: each span this much (0.1 s: a few periods of the 20-30 Hz content of a rig drive, a
#: fraction of a period of its body and wheel modes).
CLIP_WINDOW_S = 0.1
#: Passes of the limiter at one window length before a longer window is tried.
_MAX_PASSES = 12
#: The rig file's top-level keys.
_TOP_KEYS = ("format", "name", "swap_min", "run_overhead_min", "click_change_s", "units",
             "limits")
#: Quantities whose limit is a magnitude (a peak of the signal itself).
_MAGNITUDES = ("displacement", "force", "moment")


# ----------------------------------------------------------------------------------------------
# the rig and its file
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RigLimits:
    """What a rig's actuators can play, in SI; ``None``: no limit.

    Attributes
    ----------
    wheelloader_displacement_m : float or None
        Peak wheel-pad displacement, either way from zero [m].
    wheelloader_velocity_m_s : float or None
        Peak wheel-pad velocity [m/s].
    wheelloader_acceleration_m_s2 : float or None
        Peak wheel-pad acceleration [m/s^2].
    aero_heave_n : float or None
        Peak aero heave force [N].
    aero_roll_n_m, aero_pitch_n_m : float or None
        Peak aero roll and pitch moments [N*m].

    Raises
    ------
    PlannerError
        If a limit is not a positive finite number or ``None``.

    Notes
    -----
    Every limit is a peak of the absolute value: a wheelloader limited to 25 mm plays
    -25 mm .. +25 mm. Velocity and acceleration are those of :func:`drive_derivatives`.
    """

    wheelloader_displacement_m: float | None = None
    wheelloader_velocity_m_s: float | None = None
    wheelloader_acceleration_m_s2: float | None = None
    aero_heave_n: float | None = None
    aero_roll_n_m: float | None = None
    aero_pitch_n_m: float | None = None

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            if not _is_positive_number(v):
                raise PlannerError(f"RigLimits: {f.name} = {v!r} must be a positive number "
                                   "in SI or None (no limit)")
            object.__setattr__(self, f.name, float(v))

    def for_channel(self, channel):
        """The limits of one rig input.

        Parameters
        ----------
        channel : str
            A rig input of :data:`ident.data.channels.RIG_INPUTS`.

        Returns
        -------
        dict of str to float
            Quantity (``"displacement"``, ``"velocity"``, ``"acceleration"`` for a
            wheelloader; ``"force"`` for ``aero_heave``; ``"moment"`` for
            ``aero_roll`` and ``aero_pitch``) -> its limit in SI, for the limits set.

        Examples
        --------
        >>> RigLimits(wheelloader_velocity_m_s=1.0).for_channel("wheelloader_RR")
        {'velocity': 1.0}
        """
        out = {}
        for field_name, quantity, inputs in LIMIT_KEYS.values():
            v = getattr(self, field_name)
            if v is not None and channel in inputs:
                out[quantity] = v
        return out

    @property
    def any(self):
        """bool: Whether any limit is set."""
        return any(getattr(self, f.name) is not None for f in dataclasses.fields(self))


@dataclass(frozen=True)
class RigSpec:
    """A rig's time costs, and the limits of its actuators.

    Attributes
    ----------
    name : str
    swap_min : float
        Time to change the shock at one corner [min].
    run_overhead_min : float
        Time per run besides its drive (load, start, check) [min].
    source : str or None
    click_change_s : float
        Time to change one adjuster of an adjustable shock at one corner (clicks or
        turns, the shock staying on the car) [s].
    limits : RigLimits or None
        What the actuators can play (the file's ``[limits]``), ``None`` when the file has
        no ``[limits]``.

    Notes
    -----
    Going from one setup to the next costs :attr:`swap_min` for every corner whose
    shock is swapped, and :attr:`click_change_s` for every adjuster turned at a
    corner that keeps its adjustable shock (``TTX@ls=6,hs=2`` -> ``TTX@ls=8,hs=2``:
    one click change): :func:`planner.design.change_time_min`.
    """

    name: str = "rig"
    swap_min: float = 6.0
    run_overhead_min: float = 0.0
    source: str | None = None
    click_change_s: float = 20.0
    limits: RigLimits | None = None

    @property
    def click_change_min(self):
        """float: :attr:`click_change_s` in minutes."""
        return self.click_change_s / 60.0


def default_rig():
    """A rig where a shock change takes 6 minutes, a click change 20 s, and runs cost only
    their drive."""
    return RigSpec()


def _is_positive_number(v):
    return (not isinstance(v, (bool, np.bool_)) and isinstance(v, (int, float, np.integer,
                                                                    np.floating))
            and math.isfinite(v) and v > 0)


def read_rig(path):
    """Read a rig TOML (see the module docstring).

    Parameters
    ----------
    path : str or path
        The file: ``format = "rig/1"``, ``name``, ``swap_min``, ``run_overhead_min``,
        ``click_change_s``, ``units`` and a ``[limits]`` table, all optional.

    Returns
    -------
    RigSpec
        With ``source`` set to `path`, ``name`` defaulting to the file's stem, and
        ``limits`` in SI (``None`` without ``[limits]``).

    Raises
    ------
    PlannerError
        On a missing or malformed file, an unknown key (in ``[limits]`` too, with the
        nearest valid one), a time that is not a number >= 0 (a negative swap time), an
        unknown ``units``, or a limit that is not a positive number; the message names the
        file and key.
    """
    path = Path(path)
    doc = read_toml(path, error=PlannerError, what="rig file")
    known = set(_TOP_KEYS)
    for key in doc:
        if key not in known:
            raise PlannerError(f"{path}: unknown key {key!r}{did_you_mean(key, known)}; a rig "
                               f"file has {sorted(known)}: fix its spelling or remove it")
    if doc.get("format", RIG_FORMAT) != RIG_FORMAT:
        raise PlannerError(f"{path}: 'format' is {doc.get('format')!r}; write format = "
                           f"\"{RIG_FORMAT}\"")
    out = {}
    for key in ("swap_min", "run_overhead_min"):
        if key in doc:
            v = doc[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v < 0:
                raise PlannerError(f"{path}: {key} = {v!r} must be a number of minutes >= 0")
            out[key] = float(v)
    if "click_change_s" in doc:
        v = doc["click_change_s"]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                or v < 0:
            raise PlannerError(f"{path}: click_change_s = {v!r} must be a number of seconds "
                               ">= 0 (the time to turn one adjuster at one corner); write e.g. "
                               "click_change_s = 20")
        out["click_change_s"] = float(v)
    name = doc.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise PlannerError(f"{path}: 'name' must be a non-empty string")
    units = check_units(doc.get("units", "SI"), where=f"{path}: 'units'", error=PlannerError)
    if "limits" in doc:
        out["limits"] = _read_limits(doc["limits"], units, path)
    return RigSpec(name=name, source=str(path), **out)


#: A typical rig's limit per quantity, SI: the example a refusal gives (in the file's units).
_LIMIT_EXAMPLE_SI = {"displacement": 0.025, "velocity": 0.5, "acceleration": 50.0,
                     "force": 5000.0, "moment": 3000.0}


def _read_limits(table, units, path):
    """The ``[limits]`` table of a rig file as :class:`RigLimits` (SI)."""
    if not isinstance(table, dict):
        raise PlannerError(f"{path}: 'limits' must be a table, got {type(table).__name__}; "
                           "write it as [limits] with lines such as wheelloader_displacement "
                           "= 0.025")
    values = {}
    for key, v in table.items():
        if key not in LIMIT_KEYS:
            raise PlannerError(f"{path}: unknown key {key!r} in [limits]"
                               f"{did_you_mean(key, LIMIT_KEYS)}; [limits] has "
                               f"{list(LIMIT_KEYS)}; fix its spelling or remove it")
        field_name, quantity, _ = LIMIT_KEYS[key]
        if not _is_positive_number(v):
            unit = UNIT_LABELS[units][quantity]
            example = float(from_si(_LIMIT_EXAMPLE_SI[quantity], quantity, units))
            raise PlannerError(f"{path}: [limits] {key} = {v!r} must be a positive number "
                               f"[{unit}] (units = \"{units}\"); write e.g. {key} = "
                               f"{example:.2g}, or remove the key for no limit")
        values[field_name] = float(to_si(float(v), quantity, units))
    return RigLimits(**values)


# ----------------------------------------------------------------------------------------------
# limits on a drive
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class LimitedDrive:
    """A drive within a rig's limits, and what was done to it.

    Attributes
    ----------
    drive : ident.data.drive.Drive
        The limited drive: the original's name, rate and rig inputs, its ``settings``
        extended with ``"rig_limits"`` (the action, the limits in SI, the factors, the
        share of samples changed per channel; for ``"clip"`` the window [s] and passes per
        channel). The original object itself when no limit was exceeded.
    report : pandas.DataFrame
        One row per changed channel and limited quantity (an aero input scaled with its
        group without a limit of its own: one row, ``limit`` NaN), columns ``channel``,
        ``quantity``, ``unit`` (SI), ``limit``, ``peak_before``, ``peak_after``,
        ``exceeded`` (bool: the original's peak was over the limit), ``share_changed``
        (share of the channel's samples that changed [-]), ``action`` and ``scale``
        (the channel's factor for ``"scale"``, NaN for ``"clip"``). Empty when nothing
        was exceeded.
    scale : float
        The wheelloaders' common factor for ``"scale"`` [-], 1.0 for ``"clip"`` or when
        they are within their limits.
    aero_scale : float
        The aero inputs' common factor for ``"scale"`` [-], 1.0 otherwise.
    warnings : list of str
        One sentence per channel and quantity over its limit (also logged).
    action : str
        ``"clip"`` or ``"scale"``.
    limits : RigLimits or None
        The limits applied.
    """

    drive: Drive
    report: pd.DataFrame
    scale: float = 1.0
    aero_scale: float = 1.0
    warnings: list = dataclasses.field(default_factory=list)
    action: str = "clip"
    limits: RigLimits | None = None


_REPORT_COLUMNS = ("channel", "quantity", "unit", "limit", "peak_before", "peak_after",
                   "exceeded", "share_changed", "action", "scale")


def drive_derivatives(x, fs_hz):
    """Velocity and acceleration of a rig input's samples, as the rig limits read them.

    Parameters
    ----------
    x : array_like, shape (n_samples,)
        Samples at `fs_hz` (n_samples >= 2), e.g. a wheelloader's displacement [m].
    fs_hz : float
        Sample rate [Hz].

    Returns
    -------
    v, a : ndarray, shape (n_samples,)
        ``v = numpy.gradient(x, 1/fs_hz)`` [unit of x / s] and
        ``a = numpy.gradient(v, 1/fs_hz)`` [unit of x / s^2]: second-order central
        differences inside, first-order one-sided at the ends.

    Notes
    -----
    For a sine of frequency ``f`` the central differences read the velocity peak low by
    ``sin(w/fs) / (w/fs)`` and the acceleration peak by its square, ``w = 2 pi f``: 1.6 %
    and 3.2 % at 10 Hz sampled at 200 Hz. Content near the Nyquist frequency is read
    low; a rig drive is band-limited far below it.

    Examples
    --------
    >>> v, a = drive_derivatives([0.0, 1.0, 4.0, 9.0, 16.0], 1.0)  # x = t^2
    >>> v.tolist(), a.tolist()
    ([1.0, 2.0, 4.0, 6.0, 7.0], [1.0, 1.5, 2.0, 1.5, 1.0])
    """
    x = np.asarray(x, dtype=float)
    dt = 1.0 / float(fs_hz)
    v = np.gradient(x, dt)
    return v, np.gradient(v, dt)


def _peaks(x, fs_hz, quantities):
    """Peak |x|, |v|, |a| for the quantities asked (the magnitude under its own name)."""
    return {q: float(np.max(np.abs(s))) for q, s in _signals(x, fs_hz, quantities).items()}


def _signals(x, fs_hz, quantities):
    """The signal each limited quantity reads: the samples, or their derivatives."""
    need_deriv = any(q in ("velocity", "acceleration") for q in quantities)
    v, a = drive_derivatives(x, fs_hz) if need_deriv else (None, None)
    return {q: (v if q == "velocity" else a if q == "acceleration" else x) for q in quantities}


def _check_apply_inputs(drive, limits, action):
    if not isinstance(drive, Drive):
        raise TypeError(f"apply_rig_limits: drive must be an ident.data.drive.Drive, got "
                        f"{type(drive).__name__}")
    if limits is not None and not isinstance(limits, RigLimits):
        raise TypeError(f"apply_rig_limits: limits must be RigLimits or None, got "
                        f"{type(limits).__name__}; read them with read_rig(path).limits")
    if action not in LIMIT_ACTIONS:
        raise PlannerError(f"apply_rig_limits: action {action!r} is not one of "
                           f"{list(LIMIT_ACTIONS)}{did_you_mean(action, LIMIT_ACTIONS)}")


def apply_rig_limits(drive, limits, *, action="clip", warn=True):
    """Make a drive respect a rig's actuator limits, by clipping smoothly or scaling.

    Parameters
    ----------
    drive : ident.data.drive.Drive
        The drive (SI, ``drive.fs_hz``).
    limits : RigLimits or None
        The rig's limits (``read_rig(path).limits``); ``None``: no limits.
    action : {"clip", "scale"}
        ``"scale"``: the four wheelloaders multiplied by one factor, the smallest
        ``limit / peak`` over their channels and quantities (their relative content
        kept); the aero inputs by one factor of their own. ``"clip"``: each channel
        limited where it exceeds, smoothly (Notes); the rest of the drive unchanged.
    warn : bool
        Log the warnings (default); False only collects them in
        :attr:`LimitedDrive.warnings` (a caller that limits every iterate of a drive
        iteration logs the final drive's once).

    Returns
    -------
    LimitedDrive
        The limited drive, a report per changed channel and limited quantity, the
        factors and the warnings. With `limits` ``None`` or no limit exceeded: `drive`
        itself, an empty report and no warning.

    Raises
    ------
    TypeError
        If `drive` is not a Drive or `limits` not RigLimits or None.
    PlannerError
        If `action` is not ``"clip"`` or ``"scale"``.

    Notes
    -----
    Velocity and acceleration are those of :func:`drive_derivatives`
    (``numpy.gradient`` at ``1/fs``, twice). A limit is exceeded when a peak is above
    it; each exceeded channel and quantity is warned about (``logging.warning``, and in
    :attr:`LimitedDrive.warnings`) with the peak, the limit and the share of the
    channel's samples changed.

    ``"clip"`` is a smooth local limiter: a hard clip at the displacement limit would put
    a kink in the drive at every entry into the limit, a velocity step and an
    acceleration spike that no rig can follow. Per channel:

    1. the gain each sample needs, ``g = min(1, D/|x|, V/|v|, A/|a|)`` over the limits
       set (for an aero input, its force or moment limit only);
    2. a smooth envelope at most ``g`` everywhere: the gain's deficit ``1 - g`` through
       a moving maximum over ``L`` samples (the moving minimum of ``g``), then a
       Hann-window mean of the same length ``L``, whose reach (``(L-1)/2`` samples each
       way) lies inside the maximum's, so that the envelope ``1 - mean`` is at most
       ``g`` at every sample; then ``min`` with ``g`` against rounding;
    3. the channel multiplied by the envelope, and steps 1-3 repeated on the result
       until every peak is within its limit to :data:`LIMIT_RTOL` (a gain's own slope
       adds ``x de/dt`` to the velocity, so a pass may leave a little over a velocity or
       acceleration limit; a track drive held to 70 % of its own three peaks needs 2
       passes), at most 12;
    4. accepted if no velocity or acceleration peak of the result is above the
       original's (nor its limit) by more than :data:`LIMIT_RTOL`: the limiter makes
       no spike. Otherwise the window doubles, from :data:`CLIP_WINDOW_S` (a slowly
       varying gain adds less slope: a low-frequency drive needs a window that is a
       fair part of its period: a sine twice over its displacement limit keeps 0.1 s
       from 2 Hz up, and takes 0.2 s at 1 Hz, 0.4 s at 0.5 Hz, 1.8 s at 0.2 Hz) and the
       channel is limited again from the original; at the record's length the envelope is
       one constant, the channel scaled;
    5. the displacement (force, moment) limit guaranteed exactly by a final clip, which
       moves only samples that rounding left a few ulps over.

    A sample farther than ``L - 1`` samples (one window) from every sample over a limit
    (in any pass) is multiplied by exactly 1: unchanged, bit for bit. The window and the
    passes per channel are in the drive's ``settings["rig_limits"]``.

    ``"scale"`` multiplies by factors <= 1: a peak scales with its signal, and
    derivatives are linear, so every limit holds (the displacement one exactly: the
    factor is lowered by ulps if rounding needs it).
    """
    _check_apply_inputs(drive, limits, action)
    empty = pd.DataFrame({c: [] for c in _REPORT_COLUMNS})
    unchanged = LimitedDrive(drive=drive, report=empty, action=action, limits=limits)
    if limits is None or not limits.any:
        return unchanged
    # peaks before, per channel with limits
    before = {}
    for c in drive.rig_inputs:
        lim = limits.for_channel(c)
        if lim:
            before[c] = (lim, _peaks(drive.channels[c], drive.fs_hz, lim))
    over = {c: [q for q in lim if peaks[q] > lim[q]] for c, (lim, peaks) in before.items()}
    if not any(over.values()):
        return unchanged
    if action == "scale":
        new, factors, detail = _scale(drive, before)
    else:
        new, factors, detail = _clip(drive, before, over)
    changed = {c: float(np.mean(new[c] != drive.channels[c])) for c in new}
    rows, messages = [], []
    for c, y in new.items():
        # a channel scaled with its group without limits of its own: its peak, no limit
        lim, peaks = before.get(c, ({quantity_of(c): math.nan},
                                    _peaks(drive.channels[c], drive.fs_hz, [quantity_of(c)])))
        after = _peaks(y, drive.fs_hz, lim)
        for q in lim:
            rows.append({"channel": c, "quantity": q, "unit": UNIT_LABELS["SI"][q],
                         "limit": lim[q], "peak_before": peaks[q], "peak_after": after[q],
                         "exceeded": bool(peaks[q] > lim[q]), "share_changed": changed[c],
                         "action": action, "scale": factors.get(c, math.nan)})
            if peaks[q] > lim[q]:
                messages.append(_warning(drive.name, c, q, lim[q], peaks[q], changed[c],
                                         action, factors.get(c), detail.get(c)))
    for m in messages if warn else ():
        log.warning("%s", m)
    wl = [factors[c] for c in WHEELLOADER_INPUTS if c in factors]
    aero = [factors[c] for c in AERO_INPUTS if c in factors]
    scale = wl[0] if wl else 1.0
    aero_scale = aero[0] if aero else 1.0
    channels = {c: new.get(c, drive.channels[c]) for c in drive.rig_inputs}
    settings = dict(drive.settings)
    settings["rig_limits"] = {
        "action": action,
        "limits": {k: v for k, v in dataclasses.asdict(limits).items() if v is not None},
        "scale": scale, "aero_scale": aero_scale,
        "share_changed": changed,
        **({"window_s": {c: d["window_s"] for c, d in detail.items()},
            "passes": {c: d["passes"] for c, d in detail.items()}} if action == "clip" else {}),
    }
    limited = Drive(name=drive.name, fs_hz=drive.fs_hz, channels=channels, settings=settings)
    report = pd.DataFrame(rows, columns=list(_REPORT_COLUMNS))
    return LimitedDrive(drive=limited, report=report, scale=scale, aero_scale=aero_scale,
                        warnings=messages, action=action, limits=limits)


def _warning(name, channel, quantity, limit, peak, share, action, factor, detail):
    unit = UNIT_LABELS["SI"][quantity]
    head = (f"drive {name!r}: {channel} {quantity} peaks at {peak:.4g} {unit}, "
            f"{peak / limit:.3g}x the rig's limit {limit:.4g} {unit}")
    if action == "scale":
        group = "the wheelloaders" if channel in WHEELLOADER_INPUTS else "the aero inputs"
        return (f"{head}; {group} scaled by {factor:.4g} together ({share:.1%} of the "
                f"channel's samples changed); action 'clip' would change only the peaks")
    return (f"{head}; clipped smoothly ({detail['window_s']:.3g} s window), "
            f"{share:.1%} of the channel's samples changed; action 'scale' would keep the "
            "drive's waveform")


def _safe_factor(x, limit, factor):
    """`factor`, lowered by ulps until ``max |x * factor| <= limit`` holds in floating point."""
    peak = np.max(np.abs(x))
    while peak * factor > limit:
        factor = np.nextafter(factor, 0.0)
    return float(factor)


def _scale(drive, before):
    """Action "scale": one factor for the wheelloaders, one for the aero inputs."""
    new, factors = {}, {}
    for group in (WHEELLOADER_INPUTS, AERO_INPUTS):
        chans = [c for c in group if c in before]
        ratios = [before[c][0][q] / before[c][1][q] for c in chans for q in before[c][0]
                  if before[c][1][q] > 0]
        factor = min([1.0, *ratios])
        if factor >= 1.0:
            continue
        for c in chans:  # the magnitude limit exactly, whatever rounding did
            lim = before[c][0]
            for q in _MAGNITUDES:
                if q in lim:
                    factor = _safe_factor(drive.channels[c], lim[q], factor)
        for c in (c for c in group if c in drive.rig_inputs):
            new[c] = drive.channels[c] * factor
            factors[c] = factor
    return new, factors, {}


def _clip(drive, before, over):
    """Action "clip": the smooth local limiter on every channel over a limit."""
    new, detail = {}, {}
    for c, quantities in over.items():
        if not quantities:
            continue
        new[c], detail[c] = _limit_channel(drive.channels[c], drive.fs_hz, before[c][0])
    return new, {}, detail


def _gain_and_peaks(x, fs_hz, lim):
    """Per sample the gain the limits need, ``min(1, limit / |signal|)`` over the channel's
    limited quantities, and the peaks of the samples and of both derivatives."""
    v, a = drive_derivatives(x, fs_hz)
    signals = {"velocity": v, "acceleration": a}
    g = np.ones_like(x)
    peaks = {"velocity": float(np.max(np.abs(v))), "acceleration": float(np.max(np.abs(a)))}
    for q, value in lim.items():
        mag = np.abs(signals.get(q, x))
        peaks[q] = float(np.max(mag))
        if peaks[q] > value:
            hit = mag > value
            g[hit] = np.minimum(g[hit], value / mag[hit])
    return g, peaks


def _envelope(g, n_window):
    """A smooth gain <= `g` at every sample, 1 exactly where `g` is 1 within one window."""
    n, h = g.size, n_window // 2
    deficit = ndimage.maximum_filter1d(1.0 - g, size=2 * h + 1, mode="nearest")
    w = np.hanning(2 * h + 3)[1:-1]
    w /= w.sum()
    smooth = signal.oaconvolve(np.pad(deficit, h, mode="edge"), w, mode="valid")
    # exactly 0 where the window holds no deficit (the FFT leaves ~1e-17 there)
    count = np.concatenate(([0], np.cumsum(deficit > 0)))
    i = np.arange(n)
    reach = count[np.minimum(i + h + 1, n)] > count[np.maximum(i - h, 0)]
    smooth = np.where(reach, np.maximum(smooth, 0.0), 0.0)
    return np.minimum(1.0 - smooth, g)


def _limit_channel(x, fs_hz, lim):
    """The smooth local limiter on one channel (see apply_rig_limits, Notes).

    Returns the limited samples and ``{"window_s": the window [s] (the record's length when
    the channel had to be scaled as a whole), "passes": passes at that window}``.
    """
    n = x.size
    g0, peaks = _gain_and_peaks(x, fs_hz, lim)
    # no derivative peak above the original's (nor its limit): the no-spike rule
    bound = {q: min(peaks[q], lim.get(q, math.inf)) for q in ("velocity", "acceleration")}
    magnitude = {q: lim[q] for q in lim if q in _MAGNITUDES}
    bound.update(magnitude)
    n_window = max(3, 2 * round(CLIP_WINDOW_S * fs_hz / 2) + 1)
    while n_window < 2 * n + 1:
        y, g, passes = x, g0, 0
        # the first pass on any excess, later ones until within LIMIT_RTOL
        while passes < _MAX_PASSES and np.min(g) < (1.0 / (1.0 + LIMIT_RTOL) if passes else 1.0):
            y = y * _envelope(g, n_window)
            g, peaks = _gain_and_peaks(y, fs_hz, lim)
            passes += 1
        if all(peaks[q] <= bound[q] * (1.0 + LIMIT_RTOL) for q in bound):
            return _final_clip(y, magnitude), {"window_s": n_window / fs_hz, "passes": passes}
        n_window = 2 * n_window + 1
    # the longest window: one gain for the whole channel, the channel scaled
    factor = float(np.min(g0))
    for value in magnitude.values():
        factor = _safe_factor(x, value, factor)
    return x * factor, {"window_s": n / fs_hz, "passes": 1}


def _final_clip(y, magnitude):
    """The magnitude limit exactly (moves only samples rounding left a few ulps over)."""
    for value in magnitude.values():
        y = np.clip(y, -value, value)
    return y
