"""The virtual rig: run an experiment plan on a vehicle model and write a rig session.

A plan (TOML, ``format = "rig-plan/1"``) lists the runs of a rig test (name,
setup, role, optional drive seed and duration), the drive (the paper's
band-limited Gaussian noise, a sine sweep or a track-like drive), the sample
rate, the measurement noise and the shock library the setups name. The
built-in default plan is the seed paper's identification experiment: one
800 s baseline run with linear 20 lbf/(in/s) shocks and four 800 s runs, each
with one corner swapped to a nonlinear dynamic shock of about 8 lbf/(in/s)
equivalent damping, at 100 Hz.

A plan's ``rig`` is ``"7-post"`` (default) or ``"8-post"`` (rigs with aero
actuators: every run records the 7 rig inputs) or ``"4-post"`` (no aero
actuators: the physical model is driven with the aero inputs zero and the runs
have no aero channels, as the spec's "Run files" says of a 4-post rig).

Each run is simulated with :func:`ident.sim.closedloop.simulate` on the physical
full-car model, closed around the equivalent linear damping of that run's
shocks (so the feedback carries only their nonlinear, dynamic residual) and
oversampled internally.

The real car (the spec's "The real car", all optional): a plan may name a bump-stop
library (``bump_stop_library``), fit bump stops and packers per run (``bump_stops``,
``packers``) and give the tires' static loads (``static_corner_load``: the tires may then
leave the pads). The loop then carries the stops' forces and the lift-off, and the
session written records what was fitted, as a real rig's session would.

Suspension friction (``suspension_friction``, optional): a Coulomb friction per corner in
parallel with the shock (bushings, bearings, seals), ``F = F_c tanh(v / v0)``
(:data:`FRICTION_V0_M_S`) at the shock velocity: the chassis and the tire feel it, the
shock's load cell does not (``shock_force_XX`` stays the shock's own force). It is the
car's undeclared truth: the session written does not record it (the rig logs it per
corner), and ``identify`` finds it (:mod:`ident.identify.diagnose`, kind ``friction``).

Third elements (the spec's "Third elements", optional): a plan may declare the car's heave
and roll elements with their motion ratios (``third_elements = { heave_front = 1.0, ... }``;
else the vehicle's, :attr:`ident.models.vehicle.VehicleParams.third_elements`) and fit per
run their dampers (``third``: shock-library ids, any kind, with lag), heave springs
(``heave_springs``: bump-stop-library ids, with their gap) and packers (``heave_packers``).
Such a car is simulated by :func:`ident.sim.third_loop.simulate_third` (the same loop with
the elements coupled through their motion ratios); every run records the declared
elements' channels (``heave_velocity_front``, ``heave_travel_front``, ``heave_force_front``,
``heave_spring_force_front``, ``roll_...``: 0 force where an element is not fitted) and the
session written records the keys. A plan without third elements runs as before, to the bit.
"""

from __future__ import annotations

import difflib
import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from ident.data.channels import (ALL_CHANNELS, CORNERS, RESPONSE_KINDS, RIG_INPUTS, RIG_KINDS,
                                 THIRD_CHANNELS, WHEELLOADER_INPUTS, corner_table, kind_of)
from ident.data.drive import (Drive, check_drive_inputs, decimate_bandlimited, make_multisine_drive,
                              make_noise_drive, make_sweep_drive, make_track_drive, read_drive)
from ident.data.files import read_toml
from ident.data.session import (STATIC_OFFSET_SHARE, Run, check_static_corner_loads,
                                 make_session)
from ident.data.third import (HEAVE_ELEMENTS, ThirdElements, check_run_third,
                              check_third_elements, element_axle)
from ident.data.units import UNIT_LABELS, check_units, to_si
from ident.errors import BumpStopError, DriveError, SessionError, ShockModelError
from ident.models.bumpstops import (BumpStopLibrary, check_packer, contact_tables,
                                    parse_bump_stop_id, read_bump_stops)
from ident.models.library import read_shock_library
from ident.models.lti import lag_hold_coefficients
from ident.models.shocks import PiecewiseLinear, is_real_number
from ident.models.vehicle import build_full_car, example_vehicle
from ident.sim.closedloop import refine_input, simulate
from ident.sim.third_loop import ThirdDamper, ThirdSpring, simulate_third

__all__ = [
    "PlanRun",
    "RigPlan",
    "read_rig_plan",
    "default_plan",
    "make_plan_drive",
    "simulate_session",
    "DEFAULT_PLAN_PATH",
    "NOMINAL_V_RMS_M_S",
    "FRICTION_V0_M_S",
    "FRICTION_KNOTS",
    "friction_force",
    "check_suspension_friction",
    "loop_damping",
]

log = logging.getLogger(__name__)

DEFAULT_PLAN_PATH = Path(__file__).parents[1] / "examples" / "paper_plan.toml"
#: Shock-velocity RMS at which the loop's baseline damping is linearized [m/s].
#: Any value gives the same closed loop; a typical one keeps the feedback small.
NOMINAL_V_RMS_M_S = 0.1

#: Velocity scale [m/s] of the suspension friction ``F = F_c tanh(v / v0)``. A true Coulomb
#: step is ill posed in the loop (at rest any force within +-F_c: sticking) and its slope
#: infinite; smoothed over 5 mm/s, the curve's steepest slope (F_c / v0: 20 kN/(m/s) at
#: 100 N) is of the order of a shock's low-speed damping, so Newton's method keeps
#: converging, while the band stays below a rig's measured velocity noise (2 % of 0.1-0.3
#: m/s RMS: 2-6 mm/s), where the data cannot tell it from a step.
FRICTION_V0_M_S = 0.005
#: Knots of the friction curve in the loop's piecewise-linear form, in units of
#: :data:`FRICTION_V0_M_S`: the tanh interpolated at 0.25 v0 steps (within 0.6 % of F_c),
#: constant beyond +-4 v0 (``tanh 4``: 0.07 % short of F_c).
FRICTION_KNOTS = np.linspace(-4.0, 4.0, 33)

_DRIVE_KINDS = ("noise", "sweep", "track", "multisine")
#: The rigs a plan may name (key ``rig``): a 4-post rig has no aero actuators.
_ROLES = ("baseline", "swap", "validation", "other")


@dataclass(frozen=True)
class PlanRun:
    """One run of a rig plan.

    Attributes
    ----------
    name : str
    setup : dict
        Corner -> shock id.
    role : str
    seed : int
        Drive seed (the same seed gives the same drive).
    duration_s : float
    drive : ident.data.drive.Drive or None
        A drive of its own (read from the plan's ``drive`` file); None plays the
        plan's generated drive (``seed``, ``duration_s``).
    bump_stops : dict or None
        Corner -> id of the bump stop fitted there, in the plan's bump-stop library
        (:attr:`RigPlan.bump_stops`); a corner left out, ``None`` or ``"none"`` has
        none. None: no bump stops (the car of the paper).
    packers_m : dict or None
        Corner -> packer thickness [m] (shortens that corner's gap; default 0).
    """

    name: str
    setup: dict
    role: str
    seed: int
    duration_s: float
    drive: object = None
    bump_stops: dict | None = None
    packers_m: dict | None = None
    third: dict | None = None
    heave_springs: dict | None = None
    heave_packers_m: dict | None = None

    def fitted_third(self, plan, *, where=None):
        """The run's third elements checked against the plan's: a
        :class:`ident.data.third.RunThird` (raises :class:`SessionError` as a session
        would: an element the car does not declare, a damper or heave spring not in the
        libraries, a packer thicker than the spring's gap)."""
        return check_run_third(self.third, self.heave_springs, self.heave_packers_m,
                               elements=plan.car_third_elements, shocks=plan.shocks,
                               bump_stops=plan.bump_stops,
                               where=f"run '{self.name}'" if where is None else where,
                               library="of the plan")

    def fitted(self, library=None, *, where=None):
        """The run's bump stops and packers, checked against the library.

        Parameters
        ----------
        library : ident.models.bumpstops.BumpStopLibrary or None
            The plan's bump stops (:attr:`RigPlan.bump_stops`).
        where : str, optional
            Who asks, put first in messages (default ``"run '<name>'"``).

        Returns
        -------
        stops : dict of str to (str or None)
            Corner -> bump-stop id, or None (all four corners).
        packers_m : dict of str to float
            Corner -> packer [m] (all four corners, 0 where none was given).

        Raises
        ------
        SessionError
            On an unknown corner, a bump stop without a library or not in it, a packer
            that is not a number, negative, or thicker than its stop's gap.
        """
        where = f"run '{self.name}'" if where is None else where
        given = {key: corner_table(table, name=key, where=where, what=what,
                                   error=SessionError, type_error=SessionError)
                 for key, table, what in (
                     ("bump_stops", self.bump_stops, 'bump-stop ids or "none"'),
                     ("packers", self.packers_m, "thicknesses (numbers >= 0)"))}
        stops, packers = {}, {}
        for c in CORNERS:
            sid = given["bump_stops"].get(c)
            if sid is not None:
                sid = parse_bump_stop_id(sid, f"{where}: bump_stops {c}", error=SessionError)
            if sid is not None and library is None:
                raise SessionError(f"{where}: bump_stops {c} = {sid!r} but the plan has no "
                                   "bump-stop library; name it at the top of the plan with "
                                   "bump_stop_library = \"bumpstops.toml\" (RigPlan: "
                                   "bump_stops=), or remove the run's bump_stops")
            if sid is not None and sid not in library:
                raise library.unknown_id_error(sid, where=f"{where}: bump_stops {c}",
                                               error=SessionError)
            p = given["packers"].get(c, 0.0)
            if sid is not None:
                p = check_packer(library[sid], p, f"{where}: packers {c}", error=SessionError)
            elif not is_real_number(p) or not np.isfinite(p) or p < 0:
                raise SessionError(f"{where}: packers {c} = {p!r} is not a thickness; give a "
                                   "number >= 0 (0 = none)")
            stops[c], packers[c] = sid, float(p)
        return stops, packers

    def contact_stops(self, library=None, *, where=None):
        """The run's bump stops as the simulator takes them.

        Parameters
        ----------
        library : ident.models.bumpstops.BumpStopLibrary or None
            The plan's bump stops.
        where : str, optional
            Who asks, put first in messages.

        Returns
        -------
        tuple of ((float, ndarray, ndarray) or None), shape (4,), or None
            :func:`ident.models.bumpstops.contact_tables`: per corner ``(gap - packer,
            travel_table_m, force_table_n)`` or None; None without bump stops.

        Raises
        ------
        SessionError
            As :meth:`fitted`.
        """
        stops, packers = self.fitted(library, where=where)
        return contact_tables([None if stops[c] is None else library[stops[c]]
                               for c in CORNERS], [packers[c] for c in CORNERS],
                              where=f"run '{self.name}'" if where is None else where,
                              error=SessionError)


@dataclass(frozen=True, eq=False)
class RigPlan:
    """A virtual-rig experiment plan (see the module docstring).

    Attributes
    ----------
    name : str
    fs_hz : float
        Sample rate of the written session [Hz].
    oversample : int
        Internal simulation steps per sample.
    noise : float
        Measurement noise on every response channel: white Gaussian noise
        (seeded per run) whose standard deviation is this fraction of the
        channel's RMS over the whole session (a sensor's noise floor, the same
        in every run).
    drive : dict
        Drive settings in SI (``kind`` and its options).
    shocks : ident.models.library.ShockLibrary
    runs : tuple of PlanRun
    units : str
        Unit system of the session to write.
    source : str or None
        The plan file.
    input_noise : float
        Measurement noise on every recorded rig input (wheelloaders and aero
        loads), as a fraction of that input's RMS over the session. The rig still plays the
        commanded drive; only the recorded channels are noisy, so the inputs of
        runs that share a drive differ by their noise.
    channel_noise : dict
        Per-channel overrides of `noise` and `input_noise`: a key is a
        canonical channel (``"tire_force_LF"``), a response kind
        (``"tire_force"``), ``"wheelloader"`` or ``"aero"``; the most specific
        key wins (:meth:`noise_level`).
    rig : {"7-post", "8-post", "4-post"}
        The rig: a ``"4-post"`` rig has no aero actuators (its runs have no
        aero channels and the model is driven with zero aero loads).
    static_corner_load_n : array_like, shape (4,), mapping or None
        The tires' static loads [N] (LF, RF, LR, RR, all four; stored as a read-only
        array): the tires leave the pads when the contact force ``static +
        tire_force`` would be negative (the recorded ``tire_force_XX`` is then
        ``-static``). None: the tires stay on the pads (the loop lets them pull).
    bump_stops : ident.models.bumpstops.BumpStopLibrary or None
        The bump stops the runs name (an iterable of ``BumpStop`` is made a library).
        None: no run may name one.
    suspension_friction_n : array_like, shape (4,), mapping or None
        Coulomb friction ``F_c`` per corner [N] (LF, RF, LR, RR; a mapping may leave a
        corner out: 0), in parallel with the shock in every run (:func:`friction_force`);
        stored as a read-only array. None (or all 0): none, the loop of before.
    third_elements : ident.data.third.ThirdElements, mapping or None
        The car's third elements and their motion ratios (a mapping is checked into a
        ``ThirdElements``). None: the vehicle's (``VehicleParams.third_elements``), if any.
    """

    name: str
    fs_hz: float
    oversample: int
    noise: float
    drive: dict
    shocks: object
    runs: tuple
    units: str = "SI"
    source: str | None = None
    input_noise: float = 0.0
    channel_noise: dict = field(default_factory=dict)
    rig: str = "7-post"
    static_corner_load_n: object = None
    bump_stops: object = None
    suspension_friction_n: object = None
    third_elements: object = None
    #: The elements used when `third_elements` is None (set by :func:`simulate_session`
    #: from the vehicle); not a plan key.
    car_third_elements: object = field(default=None, repr=False)

    def __post_init__(self):
        if self.third_elements is not None and not isinstance(self.third_elements,
                                                              ThirdElements):
            object.__setattr__(self, "third_elements", check_third_elements(
                dict(self.third_elements), f"rig plan {self.name!r}"))
        if self.car_third_elements is None:
            object.__setattr__(self, "car_third_elements", self.third_elements
                               if self.third_elements is not None else ThirdElements())
        if self.rig not in RIG_KINDS:
            raise SessionError(f"rig plan {self.name!r}: rig {self.rig!r} is not one of "
                               f"{list(RIG_KINDS)}")
        object.__setattr__(self, "static_corner_load_n", check_static_corner_loads(
            self.static_corner_load_n, f"rig plan {self.name!r}"))
        if self.bump_stops is not None and not isinstance(self.bump_stops, BumpStopLibrary):
            object.__setattr__(self, "bump_stops", BumpStopLibrary(self.bump_stops))
        object.__setattr__(self, "suspension_friction_n", check_suspension_friction(
            self.suspension_friction_n, f"rig plan {self.name!r}"))

    @property
    def aero(self):
        """bool: Whether the rig has aero actuators (every rig but a 4-post)."""
        return self.rig != "4-post"

    def noise_level(self, channel):
        """Measurement noise of one recorded channel, a fraction of its RMS.

        The channel's own key in `channel_noise`, else its kind's (a response
        kind, ``wheelloader`` or ``aero``), else `input_noise` for rig inputs
        and `noise` for responses.

        Examples
        --------
        >>> from dataclasses import replace
        >>> plan = replace(default_plan(), noise=0.02, input_noise=0.005,
        ...                channel_noise={"tire_force": 0.01, "tire_force_LF": 0.03})
        >>> [plan.noise_level(c) for c in ("tire_force_LF", "tire_force_RR", "ride_height_LF",
        ...                                 "wheelloader_LF", "aero_roll")]
        [0.03, 0.01, 0.02, 0.005, 0.005]
        """
        if channel in self.channel_noise:
            return float(self.channel_noise[channel])
        group = _noise_group(channel)
        if group in self.channel_noise:
            return float(self.channel_noise[group])
        return float(self.input_noise if channel in RIG_INPUTS else self.noise)


def _noise_group(channel):
    """The `channel_noise` key of a channel's kind: response kind, 'wheelloader' or 'aero'."""
    if channel in RIG_INPUTS:
        return "aero" if channel.startswith("aero_") else "wheelloader"
    if channel in THIRD_CHANNELS:
        return channel.rpartition("_")[0]
    return kind_of(channel)


#: Keys of a rig plan and of its [[run]] tables (a near miss is refused: a typo would
#: silently fall back to a default).
_PLAN_KEYS = ("format", "name", "units", "shock_library", "fs_hz", "duration_s", "oversample",
              "seed", "noise", "input_noise", "channel_noise", "rig", "drive", "run",
              "bump_stop_library", "static_corner_load", "suspension_friction",
              "third_elements")
_PLAN_RUN_KEYS = ("name", "setup", "role", "seed", "duration_s", "drive", "bump_stops",
                  "packers", "third", "heave_springs", "heave_packers")
#: Plan keys that a TOML file gives to the table above them when written below one, and
#: the run keys that belong in a [[run]]: refused with where they go.
_PLAN_ONLY_KEYS = ("bump_stop_library", "static_corner_load", "suspension_friction",
                   "third_elements")
_RUN_ONLY_KEYS = ("bump_stops", "packers", "third", "heave_springs", "heave_packers")


def _check_misplaced(table, where, *, plan_keys, run_keys):
    """Refuse the real car's keys where TOML put them by mistake (a plan key below a table
    or a run, a run key outside a run)."""
    for key in table:
        if plan_keys and key in _PLAN_ONLY_KEYS:
            raise SessionError(f"{where}: {key!r} is a key of the plan; move it to the top "
                               "of the plan, before the first [table] or [[run]]")
        if run_keys and key in _RUN_ONLY_KEYS:
            raise SessionError(f"{where}: {key!r} is a key of a run (what was fitted on "
                               "that run); move it into each [[run]] that has it")


def check_suspension_friction(value, where, *, key="suspension_friction_n", unit="N"):
    """The friction per corner as a plan holds it, or raise.

    Parameters
    ----------
    value : mapping of str to float, array_like, shape (4,), or None
        ``{LF = ..., ...}`` (a corner left out: 0) or 4 values in corner order.
    where : str
        The plan, put first in messages.
    key : str
        The key named in messages.
    unit : str
        The unit of `value` named in messages (values are returned as given).

    Returns
    -------
    ndarray, shape (4,), or None
        Read-only; None for None.

    Raises
    ------
    SessionError
        On an unknown corner, not 4 values, or a value that is not a finite number >= 0.
    """
    if value is None:
        return None
    table = corner_table(value, name=key, where=where, what=f"friction forces ({unit})",
                         error=SessionError, type_error=SessionError, sequence=True)
    vals = [table.get(c, 0.0) for c in CORNERS]
    for c, f in zip(CORNERS, vals):
        if not is_real_number(f) or not np.isfinite(f) or f < 0:
            raise SessionError(f"{where}: {key} {c} = {f!r} is not a friction force; give a "
                               f"number >= 0 ({unit}, 0 = none)")
    out = np.array(vals, dtype=float)
    out.flags.writeable = False
    return out


def friction_force(v_m_s, friction_n):
    """The suspension friction at a shock velocity, as the virtual rig's loop applies it.

    Parameters
    ----------
    v_m_s : array_like, any shape
        Shock velocity [m/s], compression positive.
    friction_n : float
        Coulomb force ``F_c`` [N] (>= 0).

    Returns
    -------
    ndarray, same shape as `v_m_s`
        ``F_c tanh(v / v0)`` (:data:`FRICTION_V0_M_S`) interpolated at
        :data:`FRICTION_KNOTS`, constant beyond them [N]: the loop's piecewise-linear
        curve, exactly.

    Examples
    --------
    >>> friction_force([-1.0, 0.0, 0.005], 100.0).round(1).tolist()
    [-99.9, 0.0, 76.2]
    """
    pwl = _friction_pwl(friction_n)
    return np.asarray(pwl.force(v_m_s), dtype=float)


def _friction_pwl(friction_n):
    v = FRICTION_KNOTS * FRICTION_V0_M_S
    return PiecewiseLinear(v, friction_n * np.tanh(FRICTION_KNOTS), 0.0, 0.0)


@dataclass(frozen=True, eq=False)
class _ShockWithFriction:
    """A shock and the suspension friction in parallel, as the loop takes a shock: one
    force-velocity curve (the shock's plus the friction's, exact on the union of their
    knots) behind the shock's lag (see :func:`simulate_session`'s notes)."""

    shock: object
    friction_n: float

    @property
    def lag_s(self):
        return self.shock.lag_s

    @property
    def id(self):
        return getattr(self.shock, "id", None)

    def to_pwl(self):
        shock = self.shock.to_pwl()
        friction = _friction_pwl(self.friction_n)
        v = np.union1d(shock.v_knots_m_s, friction.v_knots_m_s)
        return PiecewiseLinear(v, shock.force(v) + friction.force(v),
                               shock.slope_below + friction.slope_below,
                               shock.slope_above + friction.slope_above)


def _shock_own_force(resp, models, friction_n, h):
    """``shock_force_XX`` of a response with friction: the solved total less the friction
    at the solved velocity, behind the shock's lag as the loop applied it (the lag's
    recursion is linear: the total's is the shock's plus the friction's)."""
    channels = dict(resp.channels)
    for c, mdl, fc in zip(CORNERS, models, friction_n):
        if fc <= 0:
            continue
        f = friction_force(channels[f"shock_velocity_{c}"], fc)
        if mdl.lag_s > 0:
            alpha, b0, b1, bm = (float(x) for x in lag_hold_coefficients(mdl.lag_s, h))
            f = lfilter([b0, b1, bm], [1.0, -alpha], f)
        channels[f"shock_force_{c}"] = channels[f"shock_force_{c}"] - f
    return channels


def _read_plan_bump_stops(doc, folder, where):
    """The plan's bump-stop library (``bump_stop_library``), or None."""
    if "bump_stop_library" not in doc:
        return None
    file = doc["bump_stop_library"]
    if not isinstance(file, str) or not file:
        raise SessionError(f"{where}: 'bump_stop_library' must be the path of a bump-stop "
                           f"library (relative to the plan), got {file!r}")
    try:
        return read_bump_stops(folder / file)
    except BumpStopError as exc:
        raise SessionError(f"{where}: bump_stop_library {file!r}: {exc}") from exc


def _plan_packers(entry, units, where, *, key="packers"):
    """A run's ``packers`` (or ``heave_packers``) table in SI [m] (values in the plan's
    `units`), or None."""
    table = entry.get(key)
    if table is None:
        return None
    if not isinstance(table, dict):
        raise SessionError(f"{where}: {key} must be a table {{ LF = ..., RF = ... }} of "
                           f"thicknesses ({UNIT_LABELS[units]['displacement']}), got {table!r}")
    out = {}
    for c, p in table.items():
        if not is_real_number(p) or not np.isfinite(p) or p < 0:
            raise SessionError(f"{where}: {key} {c} = {p!r} is not a thickness; give a "
                               f"number >= 0 ({UNIT_LABELS[units]['displacement']}, 0 = none)")
        out[c] = float(to_si(float(p), "displacement", units))
    return out


def _check_keys(table, known, where):
    """Refuse a key that is a near miss of a known one; log other unknown keys."""
    if not isinstance(table, dict):
        raise SessionError(f"{where}: must be a table, got {table!r}")
    for key in table:
        if key in known:
            continue
        close = difflib.get_close_matches(str(key), known, n=1)
        if close:
            raise SessionError(f"{where}: unknown key {key!r} (did you mean {close[0]!r}?); "
                               f"the keys are {', '.join(known)}")
        log.warning("%s: unknown key %r is ignored", where, key)


def _num(doc, key, where, default=None, *, positive=True, integer=False):
    if key not in doc:
        if default is None:
            raise SessionError(f"{where}: required key '{key}' is missing; add it")
        return default
    val = doc[key]
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise SessionError(f"{where}: '{key}' must be a number, got {val!r}")
    if integer and val != int(val):
        raise SessionError(f"{where}: '{key}' must be an integer, got {val!r}")
    if positive and not val > 0:
        raise SessionError(f"{where}: '{key}' must be positive, got {val!r}")
    return int(val) if integer else float(val)


def read_rig_plan(path):
    """Read a rig plan TOML file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    RigPlan

    Raises
    ------
    SessionError
        On a malformed plan (format, units, drive kind, runs, setups naming
        unknown shocks or corners).

    Notes
    -----
    Keys: ``format = "rig-plan/1"``, ``name``, ``units``, ``fs_hz``,
    ``duration_s`` (default per run), ``oversample`` (default 8), ``seed``,
    ``noise`` (default 0: measurement noise of the response channels, a
    fraction of each channel's RMS), ``input_noise`` (default 0: the same for
    the recorded rig inputs), ``[channel_noise]`` (optional overrides: a
    channel, a response kind, ``wheelloader`` or ``aero`` -> fraction),
    ``shock_library`` (path relative to the plan), ``rig`` (``"7-post"``
    (default), ``"8-post"`` or ``"4-post"``: no aero actuators, runs without
    aero channels);
    ``[drive]`` with ``kind`` = ``noise`` (``f_max_hz``, ``filter_order``,
    ``taper_s``, ``peak_wheelloader`` [length], ``peak_aero_heave`` [force],
    ``roll_moment_multiple`` and ``pitch_moment_multiple``: peak moments as
    multiples of the chassis' spring roll/pitch stiffness per degree),
    ``sweep`` (``amplitude_wheelloader``, ``f_start_hz``, ``f_stop_hz``) or
    ``track`` (``speed_m_s``) or ``multisine`` (``f_min_hz``, ``f_max_hz``,
    ``rms_wheelloader`` [length], ``rms_aero_heave`` [force], and the roll and
    pitch moments' RMS as ``roll_moment_multiple``/``pitch_moment_multiple``
    of the stiffness per degree); ``[[run]]`` tables with ``name``,
    ``setup``, ``role``, optional ``seed`` and ``duration_s``, or ``drive``: a
    drive file (relative to the plan, in the plan's units when it states them,
    else in the drive file's own, else SI) the run plays instead.

    The real car (optional; the spec's "The real car"): ``bump_stop_library``
    (path of a ``bumpstops.toml`` relative to the plan) and ``static_corner_load =
    { LF = ..., RF = ..., LR = ..., RR = ... }`` (the tires' static loads, N or lbf, all
    four) at the top of the plan, before any table; per ``[[run]]``, ``bump_stops = {
    LF = "BS-F", ... }`` (ids in the library; a corner left out, or ``"none"``, has
    none) and ``packers = { LF = 0.003, ... }`` (m or in, default 0). Refused: an
    unknown id or corner, a bump stop without a library, a packer that is negative or
    thicker than its stop's gap, static loads that are not 4 positive numbers, and
    these keys where TOML put them by mistake (a plan key below ``[drive]`` or a
    ``[[run]]``, a run key at the top). ``suspension_friction = { LF = ..., ... }`` (N or
    lbf, a corner left out has none; at the top too): a Coulomb friction in parallel with
    each corner's shock, the car's undeclared truth (not written to the session).

    Third elements (optional; the spec's "Third elements"): ``third_elements = {
    heave_front = 1.0, roll_front = 0.8 }`` (motion ratios, at the top; without it the
    vehicle's) and per ``[[run]]`` ``third = { heave_front = "H1", ... }`` (shock-library
    ids), ``heave_springs = { front = "HS-F" }`` (bump-stop-library ids) and
    ``heave_packers = { front = 0.001 }`` (m or in). Refused as a session refuses them
    (:func:`ident.data.third.check_run_third`), and on the wrong level.
    """
    path = Path(path)
    where = str(path)
    doc = read_toml(path, error=SessionError, what="rig plan")
    _check_misplaced(doc, where, plan_keys=False, run_keys=True)
    for table in ("drive", "channel_noise"):
        if isinstance(doc.get(table), dict):
            _check_misplaced(doc[table], f"{where}: [{table}]", plan_keys=True, run_keys=True)
    _check_keys(doc, _PLAN_KEYS, where)
    if doc.get("format") != "rig-plan/1":
        raise SessionError(f"{where}: 'format' is {doc.get('format')!r}; expected \"rig-plan/1\"")
    units = check_units(doc.get("units", "SI"), where=f"{where}: 'units'", error=SessionError)
    lib_file = doc.get("shock_library")
    if not isinstance(lib_file, str):
        raise SessionError(f"{where}: 'shock_library' (path to a shocks TOML file) is missing")
    try:
        shocks = read_shock_library(path.parent / lib_file)
    except ShockModelError as exc:
        raise SessionError(f"{where}: shock_library: {exc}") from exc
    fs = _num(doc, "fs_hz", where, 100.0)
    duration = _num(doc, "duration_s", where, 800.0)
    seed = _num(doc, "seed", where, 0, positive=False, integer=True)
    drive = _parse_drive(doc.get("drive", {}), units, f"{where}: [drive]")
    bump_stops = _read_plan_bump_stops(doc, path.parent, where)
    static = doc.get("static_corner_load")
    if static is not None:
        static = to_si(check_static_corner_loads(static, where, key="static_corner_load",
                                                 unit=UNIT_LABELS[units]["force"]),
                       "force", units)
    friction = doc.get("suspension_friction")
    if friction is not None:
        friction = to_si(check_suspension_friction(friction, where, key="suspension_friction",
                                                   unit=UNIT_LABELS[units]["force"]),
                         "force", units)
    third_elements = doc.get("third_elements")
    if third_elements is not None:
        third_elements = check_third_elements(third_elements, where)
    rig = doc.get("rig", "7-post")
    if rig not in RIG_KINDS:
        close = difflib.get_close_matches(str(rig), RIG_KINDS, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise SessionError(f"{where}: rig {rig!r} is not one of {list(RIG_KINDS)}{hint}; "
                           "'4-post' is a rig without aero actuators")
    runs = []
    entries = doc.get("run", [])
    if not isinstance(entries, list) or not entries:
        raise SessionError(f"{where}: no [[run]] tables; add at least one run")
    for i, entry in enumerate(entries):
        w = f"{where}: run {i + 1}"
        if not isinstance(entry, dict):
            raise SessionError(f"{w}: must be a [[run]] table, got {entry!r}")
        name = entry.get("name")
        if not isinstance(name, str) or not name:
            raise SessionError(f"{w}: 'name' is missing")
        w = f"{where}: run '{name}'"
        _check_misplaced(entry, w, plan_keys=True, run_keys=False)
        _check_keys(entry, _PLAN_RUN_KEYS, w)
        setup = entry.get("setup")
        if not isinstance(setup, dict) or sorted(setup) != sorted(CORNERS):
            raise SessionError(f"{w}: 'setup' must name a shock for each of {list(CORNERS)}, "
                               f"got {setup!r}")
        for c, sid in setup.items():
            if sid not in shocks:
                raise SessionError(f"{w}: setup {c} names unknown shock id {sid!r}; the shock "
                                   f"library {lib_file} has {list(shocks)}")
        role = entry.get("role", "other")
        if role not in _ROLES:
            raise SessionError(f"{w}: role {role!r} is not one of {list(_ROLES)}")
        drive_file = entry.get("drive")
        run_drive = None
        if drive_file is not None:
            if not isinstance(drive_file, str) or not drive_file:
                raise SessionError(f"{w}: 'drive' must be the path of a drive file (relative "
                                   f"to the plan), got {drive_file!r}")
            try:
                # the plan's units when it states them (the drive's marker must agree),
                # else the drive file's marker, else SI
                run_drive = read_drive(path.parent / drive_file,
                                       units=units if "units" in doc else None,
                                       name=Path(drive_file).stem)
            except SessionError as exc:
                raise SessionError(f"{w}: drive: {exc}") from exc
        runs.append(PlanRun(name=name, setup={c: setup[c] for c in CORNERS}, role=role,
                            seed=_num(entry, "seed", w, seed, positive=False, integer=True),
                            duration_s=(run_drive.duration_s if run_drive is not None else
                                        _num(entry, "duration_s", w, duration)),
                            drive=run_drive, bump_stops=entry.get("bump_stops"),
                            packers_m=_plan_packers(entry, units, w),
                            third=entry.get("third"), heave_springs=entry.get("heave_springs"),
                            heave_packers_m=_plan_packers(entry, units, w, key="heave_packers")))
        # the ids and packers, against the library; ids as read ("none" -> None)
        stops, _ = runs[-1].fitted(bump_stops, where=w)
        if third_elements is not None:
            check_run_third(runs[-1].third, runs[-1].heave_springs, runs[-1].heave_packers_m,
                            elements=third_elements, shocks=shocks, bump_stops=bump_stops,
                            where=w, library=str(lib_file))
        if runs[-1].bump_stops is not None:
            runs[-1] = replace(runs[-1], bump_stops=stops)
    names = [r.name for r in runs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SessionError(f"{where}: duplicate run names {dup}; make them unique")
    taper = drive.get("taper_s", 0.0)
    for r in runs:
        if r.drive is None and r.duration_s * fs < 2 * taper * fs + 2:
            raise SessionError(
                f"{where}: run '{r.name}': duration_s = {r.duration_s:g} s is too short for "
                f"[drive] taper_s = {taper:g} s (faded in and out); give at least "
                f"{2 * taper + 2 / fs:g} s or shorten taper_s")
    return RigPlan(name=str(doc.get("name", path.stem)), fs_hz=fs,
                   oversample=_num(doc, "oversample", where, 8, integer=True),
                   noise=_noise_num(doc, "noise", where),
                   drive=drive, shocks=shocks, runs=tuple(runs), units=units, source=where,
                   input_noise=_noise_num(doc, "input_noise", where),
                   channel_noise=_parse_channel_noise(doc.get("channel_noise", {}),
                                                      f"{where}: [channel_noise]"),
                   rig=rig, static_corner_load_n=static, bump_stops=bump_stops,
                   suspension_friction_n=friction, third_elements=third_elements)


#: Keys of ``[channel_noise]`` besides the canonical channels.
NOISE_GROUPS = tuple(RESPONSE_KINDS) + ("wheelloader", "aero")


def _noise_num(doc, key, where):
    val = _num(doc, key, where, 0.0, positive=False)
    if val < 0 or val >= 1:
        raise SessionError(f"{where}: '{key}' = {val!r} must be a fraction of the channel RMS in "
                           "[0, 1) (e.g. 0.02 for 2 %)")
    return val


def _parse_channel_noise(table, where):
    if not isinstance(table, dict):
        raise SessionError(f"{where}: must be a table of channel or kind = fraction")
    out = {}
    for key in table:
        if key not in ALL_CHANNELS and key not in NOISE_GROUPS:
            close = difflib.get_close_matches(str(key), list(NOISE_GROUPS) + list(ALL_CHANNELS),
                                              n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise SessionError(f"{where}: unknown key {key!r}{hint}; use a canonical channel, a "
                               f"response kind {list(RESPONSE_KINDS)}, 'wheelloader' or 'aero'")
        out[key] = _noise_num(table, key, where)
    return out


def _parse_drive(d, units, where):
    kind = d.get("kind", "noise")
    if kind not in _DRIVE_KINDS:
        raise SessionError(f"{where}: kind {kind!r} is not one of {list(_DRIVE_KINDS)}")
    out = {"kind": kind}
    if kind == "noise":
        out["f_max_hz"] = _num(d, "f_max_hz", where, 30.0)
        out["filter_order"] = _num(d, "filter_order", where, 8, integer=True)
        out["taper_s"] = _num(d, "taper_s", where, 1.0, positive=False)
        out["peak_wheelloader_m"] = to_si(_num(d, "peak_wheelloader", where, 0.0254 if units == "SI"
                                               else 1.0, positive=False), "displacement", units)
        out["peak_aero_heave_n"] = to_si(_num(d, "peak_aero_heave", where, 2224.0 if units == "SI"
                                              else 500.0, positive=False), "force", units)
        out["roll_moment_multiple"] = _num(d, "roll_moment_multiple", where, 3.0, positive=False)
        out["pitch_moment_multiple"] = _num(d, "pitch_moment_multiple", where, 3.0, positive=False)
    elif kind == "sweep":
        out["amplitude_wheelloader_m"] = to_si(_num(d, "amplitude_wheelloader", where,
                                                    0.005 if units == "SI" else 0.2),
                                               "displacement", units)
        out["f_start_hz"] = _num(d, "f_start_hz", where, 0.5)
        out["f_stop_hz"] = _num(d, "f_stop_hz", where, 25.0)
        out["taper_s"] = _num(d, "taper_s", where, 1.0, positive=False)
    elif kind == "multisine":
        out["f_min_hz"] = _num(d, "f_min_hz", where, 0.3)
        out["f_max_hz"] = _num(d, "f_max_hz", where, 25.0)
        out["taper_s"] = _num(d, "taper_s", where, 1.0, positive=False)
        out["rms_wheelloader_m"] = to_si(_num(d, "rms_wheelloader", where, 0.006 if units == "SI"
                                              else 0.25, positive=False), "displacement", units)
        out["rms_aero_heave_n"] = to_si(_num(d, "rms_aero_heave", where, 550.0 if units == "SI"
                                             else 125.0, positive=False), "force", units)
        out["roll_moment_multiple"] = _num(d, "roll_moment_multiple", where, 0.75, positive=False)
        out["pitch_moment_multiple"] = _num(d, "pitch_moment_multiple", where, 0.75,
                                            positive=False)
    else:
        out["speed_m_s"] = _num(d, "speed_m_s", where, 50.0)
    return out


def default_plan():
    """The built-in plan: the seed paper's identification experiment."""
    return read_rig_plan(DEFAULT_PLAN_PATH)


def make_plan_drive(plan, vehicle, *, seed, duration_s, name=None):
    """Build the drive of a plan for one run.

    Parameters
    ----------
    plan : RigPlan
    vehicle : ident.models.vehicle.VehicleParams
        Needed for the roll/pitch moment amplitudes and the wheelbase.
    seed : int
    duration_s : float

    Returns
    -------
    ident.data.drive.Drive
    """
    d = plan.drive
    if d["kind"] == "noise":
        deg = np.pi / 180
        peak = {w: d["peak_wheelloader_m"] for w in RIG_INPUTS[3:]}
        peak["aero_heave"] = d["peak_aero_heave_n"]
        peak["aero_roll"] = d["roll_moment_multiple"] * vehicle.roll_stiffness_n_m_rad * deg
        peak["aero_pitch"] = d["pitch_moment_multiple"] * vehicle.pitch_stiffness_n_m_rad * deg
        return make_noise_drive(duration_s=duration_s, fs_hz=plan.fs_hz, peak=peak, seed=seed,
                                f_max_hz=d["f_max_hz"], filter_order=d["filter_order"],
                                taper_s=d["taper_s"], name=name)
    if d["kind"] == "multisine":
        deg = np.pi / 180
        rms = {w: d["rms_wheelloader_m"] for w in RIG_INPUTS[3:]}
        rms["aero_heave"] = d["rms_aero_heave_n"]
        rms["aero_roll"] = d["roll_moment_multiple"] * vehicle.roll_stiffness_n_m_rad * deg
        rms["aero_pitch"] = d["pitch_moment_multiple"] * vehicle.pitch_stiffness_n_m_rad * deg
        return make_multisine_drive(duration_s=duration_s, fs_hz=plan.fs_hz, rms=rms,
                                    seed=seed, f_min_hz=d["f_min_hz"],
                                    f_max_hz=d["f_max_hz"], taper_s=d["taper_s"], name=name)
    if d["kind"] == "sweep":
        amp = {w: d["amplitude_wheelloader_m"] for w in RIG_INPUTS[3:]}
        return make_sweep_drive(duration_s=duration_s, fs_hz=plan.fs_hz, amplitude=amp,
                                f_start_hz=d["f_start_hz"], f_stop_hz=d["f_stop_hz"],
                                channels=RIG_INPUTS[3:], taper_s=d["taper_s"], name=name)
    return make_track_drive(duration_s=duration_s, fs_hz=plan.fs_hz, seed=seed,
                            speed_m_s=d["speed_m_s"], wheelbase_m=vehicle.a_m + vehicle.b_m,
                            track_width_m=vehicle.track_front_m, name=name)


def _fine_drive(drive, r):
    """The drive interpolated band-limited onto the simulation grid (``r`` steps per sample)."""
    u = refine_input(drive.as_array(), r)
    return Drive(name=drive.name, fs_hz=drive.fs_hz * r,
                 channels={c: u[:, j] for j, c in enumerate(RIG_INPUTS) if c in drive.rig_inputs},
                 settings=dict(drive.settings, refined_by=r))


def _daq_sample(channels, r, n_samples):
    """Sample simulation-grid signals as a rig's data acquisition does.

    Every channel passes the same zero-phase anti-aliasing low-pass
    (:func:`ident.data.drive.resample_bandlimited`, flat to 1e-5 up to 0.8 of the
    output Nyquist frequency, below -80 dB above 1.2 of it) before it is
    decimated by ``r``. The nonlinear shock forces have content above the
    Nyquist frequency; sampled without the filter it folds into the band,
    acts like input noise on ``dF`` and biases the identified FRFs. The
    common filter cancels in every input/output relation.

    Each record is extended by its end values over the filter's length; the
    filtering is done by FFT (:func:`ident.data.drive.decimate_bandlimited`: the
    same numbers as ``resample_bandlimited`` to rounding, about 4x faster on
    an 800 s run at 8x oversampling).
    """
    names = list(channels)
    if r == 1:
        return {c: np.array(channels[c], dtype=float) for c in names}
    out = decimate_bandlimited([channels[c] for c in names], r, n_samples)
    return dict(zip(names, out))


def loop_damping(models):
    """Baseline damping per corner: each shock's equivalent damping at a nominal velocity.

    Parameters
    ----------
    models : sequence of 4 shock models
        LF, RF, LR, RR (:mod:`ident.models.shocks`).

    Returns
    -------
    ndarray, shape (4,)
        ``equivalent_damping(NOMINAL_V_RMS_M_S)`` per corner [N/(m/s)]: the ``c_bar`` the
        virtual rig closes its loop around.
    """
    return np.array([float(m.equivalent_damping(NOMINAL_V_RMS_M_S)) for m in models])


def _check_dynamic_tire_mean(run, channels, static_n):
    """Refuse a run whose dynamic tire force a session would take for one with the static
    load in it (:data:`ident.data.session.STATIC_OFFSET_SHARE`): a drive too violent or a
    run too short for its mean to settle near 0. Said here, for what it is, rather than as
    a wrong static load by :func:`ident.data.session.make_session`."""
    if static_n is None:
        return
    for c, load in zip(CORNERS, static_n):
        x = channels.get(f"tire_force_{c}")
        if x is None:
            continue
        mean = float(np.mean(x))
        if abs(mean) > STATIC_OFFSET_SHARE * load:
            raise SessionError(
                f"run '{run.name}': its dynamic tire_force_{c} has a mean of {mean:.6g} N, "
                f"more than {STATIC_OFFSET_SHARE:.0%} of the static load {load:.6g} N, so a "
                "session would take it for a channel with the static load in it; the drive "
                "is too violent for the car on its static loads (or the run too short for "
                "its mean to settle): make the run longer or the drive gentler")


#: Runs of a rig plan simulated at once (threads; each run's loop is serial).
_RUN_THREADS = 2


def simulate_session(plan=None, vehicle=None, *, progress=False):
    """Run a rig plan on the physical full-car model and return the session.

    Parameters
    ----------
    plan : RigPlan, optional
        Default :func:`default_plan`.
    vehicle : ident.models.vehicle.VehicleParams, optional
        Default the built-in example car (the paper's Table 1).
    progress : bool
        Show a progress bar (tqdm) over the runs.

    Returns
    -------
    ident.data.session.Session
        In memory (``path`` None); write it with :func:`ident.data.session.write_session`.
        Every run holds the 7 rig inputs (the 4 wheelloaders on a 4-post
        rig), ``shock_force_XX`` and every output of the full-car model. It records
        the real car of the plan: ``Session.bump_stops`` (the plan's library, written as
        ``bumpstops.toml``), each run's ``bump_stops`` and ``packers_m`` (all four
        corners: None and 0 where nothing was fitted) and ``static_corner_load_n``; a
        plan without them gives the session (and files) of before.

    Raises
    ------
    SessionError
        If a run's drive is sampled at another rate than the plan, or, on a
        4-post plan, a run's drive file moves an aero input; if a run names a bump
        stop the plan's library does not hold (or the plan has none), or a packer is
        negative or thicker than its stop's gap (all before any run is simulated); if,
        with static loads, a run's dynamic ``tire_force_XX`` has a mean over
        :data:`ident.data.session.STATIC_OFFSET_SHARE` of the corner's load (a drive
        too violent for the car on its loads, or a run too short: its session would
        read as one whose channel carries the static load).

    Notes
    -----
    With static loads the tires may leave the pads, but ``tire_force_XX`` stays the
    dynamic part, as without them: the deviation from the car at rest (the static
    load is not added, so its mean stays near zero as before), with the contact force
    ``static + tire_force_XX`` (exactly ``-static`` while a tire is off its pad, up to
    the acquisition filter's ringing at the edges). ``shock_force_XX`` is the shock's
    alone (the bump stop's force is not in it, as on a real shock's load cell).

    Suspension friction (:attr:`RigPlan.suspension_friction_n`) is simulated exactly as
    one force-velocity curve with the shock (:func:`friction_force` added to the shock's
    curve on the union of their knots); ``shock_force_XX`` is the solved total less the
    friction at the solved shock velocity, the shock's own force to rounding. The loop
    puts the shock's lag on the whole curve, so behind a shock with a lag (the paper's
    N8: 4 ms) the friction lags too: its force builds over the lag after a reversal, like
    the pre-sliding of a real bushing or seal (a Dahl-type friction), and the recorded
    shock force takes the lagged friction out (the lag is linear), so it stays exact.
    The friction is logged per corner (``suspension_friction_XX``) and not recorded in
    the session (the car's undeclared truth).
    """
    plan = default_plan() if plan is None else plan
    vehicle = example_vehicle() if vehicle is None else vehicle
    elements = _car_third_elements(plan, vehicle)
    if elements and plan.car_third_elements is not elements:
        plan = replace(plan, car_third_elements=elements)
    if elements and plan.static_corner_load_n is not None:
        raise SessionError(f"rig plan {plan.name!r}: third elements with static_corner_load "
                           "(tire lift-off) are not simulated yet; remove one of them")
    model = build_full_car(vehicle)
    runs, clean = [], []
    drives, fine_drives = {}, {}
    jobs = []
    for pr in plan.runs:
        key = (pr.seed, pr.duration_s) if pr.drive is None else ("file", id(pr.drive))
        if key not in drives:
            drives[key] = pr.drive if pr.drive is not None else make_plan_drive(
                plan, vehicle, seed=pr.seed, duration_s=pr.duration_s,
                name=f"{plan.name} seed {pr.seed}")
        drive = drives[key]
        if not plan.aero and drive.rig_inputs != WHEELLOADER_INPUTS:
            if pr.drive is not None:
                try:
                    check_drive_inputs(drive, WHEELLOADER_INPUTS, model=f"{plan.rig} rig")
                except DriveError as exc:
                    raise SessionError(f"run '{pr.name}': {exc}") from exc
            # a 4-post rig has no aero actuators: the drive's wheelloaders, aero loads zero
            drive = drives[key] = Drive(name=drive.name, fs_hz=drive.fs_hz,
                                        channels={c: drive.channels[c]
                                                  for c in WHEELLOADER_INPUTS},
                                        settings=dict(drive.settings, rig=plan.rig))
        if abs(drive.fs_hz - plan.fs_hz) > 1e-9 * plan.fs_hz:
            raise SessionError(f"run '{pr.name}': its drive '{drive.name}' is sampled at "
                               f"{drive.fs_hz:g} Hz, the plan at {plan.fs_hz:g} Hz; resample "
                               "the drive or set the plan's fs_hz")
        models = [plan.shocks[pr.setup[c]] for c in CORNERS]
        # checked here, before any run is simulated
        stops = pr.contact_stops(plan.bump_stops)
        third = pr.fitted_third(plan) if elements else None
        plant = model.loop_plant(loop_damping(models))
        fine = fine_drives.get(key)
        if fine is None:
            fine = fine_drives[key] = _fine_drive(drive, plan.oversample)
        jobs.append((pr, drive, plant, fine, models, stops, third))

    friction = plan.suspension_friction_n
    if friction is not None and not np.any(friction > 0):
        friction = None
    if friction is not None:
        log.info("suspension friction (not recorded in the session): %s", ", ".join(
            f"suspension_friction_{c} {f:.4g} N" for c, f in zip(CORNERS, friction)))

    def run_one(job):
        pr, drive, plant, fine, models, stops, third = job
        loop_models = models if friction is None else [
            m if f <= 0 else _ShockWithFriction(m, float(f)) for m, f in zip(models, friction)]
        if third is not None:
            resp = _simulate_with_third(plan, elements, plant, fine, loop_models, stops, third,
                                        pr.name)
        else:
            resp = simulate(plant, fine, loop_models, oversample=1, stop_tables=stops,
                            static_corner_load_n=plan.static_corner_load_n)
        if resp.elements:
            log.info("run %s: %s", pr.name, ", ".join(f"{k} {v:.4g}"
                                                      for k, v in resp.elements.items()))
        channels = resp.channels
        if friction is not None:
            channels = _shock_own_force(resp, models, friction, 1.0 / fine.fs_hz)
        return resp.newton_iterations, _daq_sample(channels, plan.oversample, drive.n_samples)

    # the runs on threads (the compiled loop and rig response release the GIL, and a run
    # is one setup: the loop itself is serial); each run's numbers do not depend on it
    with ThreadPoolExecutor(max_workers=max(1, min(_RUN_THREADS, len(jobs)))) as pool:
        results = pool.map(run_one, jobs)
        if progress:
            from tqdm.auto import tqdm

            results = tqdm(results, total=len(jobs), desc="virtual rig", unit="run")
        for (pr, drive, *_, third), (iters, sampled) in zip(jobs, results):
            # the rig inputs are recorded as commanded (the drive file's samples: in band
            # the acquisition filter passes them to 1e-5)
            channels = {c: drive.channels[c] for c in drive.rig_inputs}
            channels.update(sampled)
            log.info("run %s: %d samples, Newton iterations <= %d", pr.name, drive.n_samples,
                     iters)
            clean.append((pr, channels, drive, third))
    # sensor noise: a noise floor per channel, the same in every run (a sensor's property),
    # sized as a fraction of the channel's RMS over the whole session
    rms = {}
    for _, channels, _, _ in clean:
        for name, x in channels.items():
            rms.setdefault(name, []).append(np.mean((x - np.mean(x)) ** 2))
    for i, (pr, channels, drive, third) in enumerate(clean):
        rng = np.random.default_rng([pr.seed, i, 7])
        rng_in = np.random.default_rng([pr.seed, i, 8])  # its own stream: inputs, then outputs
        for name in ([c for c in channels if c not in RIG_INPUTS]
                     + [c for c in RIG_INPUTS if c in channels]):
            level = plan.noise_level(name)
            if level > 0:
                x = channels[name]
                gen = rng_in if name in RIG_INPUTS else rng
                channels[name] = x + gen.standard_normal(x.shape) * level * np.sqrt(
                    np.mean(rms[name]))
        _check_dynamic_tire_mean(pr, channels, plan.static_corner_load_n)
        fitted, packers = pr.fitted(plan.bump_stops)
        runs.append(Run(name=pr.name, file=f"runs/{pr.name}.csv", setup=dict(pr.setup),
                        role=pr.role, time_s=drive.time_s, channels=channels, fs_hz=drive.fs_hz,
                        bump_stops=fitted, packers_m=packers, third=third))
    return make_session(plan.name, runs, plan.shocks, units=plan.units,
                        bump_stops=plan.bump_stops, static_corner_load_n=plan.static_corner_load_n,
                        third_elements=elements if elements else None)


def _car_third_elements(plan, vehicle):
    """The car's third elements: the plan's, else the vehicle's, else none."""
    if plan.third_elements is not None:
        return plan.third_elements
    declared = getattr(vehicle, "third_elements", None)
    if declared is None:
        return ThirdElements()
    if isinstance(declared, ThirdElements):
        return declared
    return check_third_elements(dict(declared), "vehicle")


def _simulate_with_third(plan, elements, plant, fine, models, stops, third, name):
    """One run of a car with third elements (:func:`ident.sim.third_loop.simulate_third`):
    the plant's outputs, the shocks' own forces and every declared element's channels
    (its motion from the corners', 0 force where it is not fitted)."""
    dampers = [ThirdDamper(e, elements.row(e), plan.shocks[sid])
               for e, sid in third.dampers.items() if sid is not None]
    springs = []
    for axle, sid in third.heave_springs.items():
        if sid is None:
            continue
        contact = contact_tables([plan.bump_stops[sid], None, None, None],
                                 [third.heave_packers_m[axle], 0.0, 0.0, 0.0],
                                 where=f"run '{name}': heave_springs {axle}",
                                 error=SessionError)[0]
        springs.append(ThirdSpring(f"heave_{axle}", elements.row(f"heave_{axle}"), contact))
    resp = simulate_third(plant, fine, models, dampers=dampers, springs=springs,
                          stop_tables=stops)
    channels = {k: v for k, v in resp.channels.items() if not k.startswith("bump_stop_force_")}
    v = np.column_stack([channels[f"shock_velocity_{c}"] for c in CORNERS])
    t = np.column_stack([channels[f"shock_travel_{c}"] for c in CORNERS])
    for e in elements.elements:
        kind, axle = e.split("_")
        row = elements.row(e)
        channels.setdefault(f"{kind}_velocity_{axle}", v @ row)
        channels.setdefault(f"{kind}_travel_{axle}", t @ row)
        channels.setdefault(f"{kind}_force_{axle}", np.zeros(v.shape[0]))
        if e in HEAVE_ELEMENTS:
            channels.setdefault(f"heave_spring_force_{element_axle(e)}", np.zeros(v.shape[0]))
    return _ThirdRunResponse(channels=channels, newton_iterations=resp.newton_iterations)


@dataclass(frozen=True, eq=False)
class _ThirdRunResponse:
    """What :func:`simulate_session` reads of a run's response (as of ``Response``)."""

    channels: dict
    newton_iterations: int
    elements: dict = field(default_factory=dict)
