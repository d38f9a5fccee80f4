"""Canonical channel names of the rig-session format and their quantities.

The names, corners and sign conventions are those of
``shared/spec/rig-session.md``: vertical displacements positive up; shock
deflection, velocity and force, spring force and tire force positive in
compression.
"""

from __future__ import annotations

from collections.abc import Mapping

__all__ = [
    "CORNERS",
    "AERO_INPUTS",
    "WHEELLOADER_INPUTS",
    "RIG_INPUTS",
    "RIG_KINDS",
    "RESPONSE_KINDS",
    "RESPONSE_CHANNELS",
    "SHOCK_VELOCITIES",
    "SHOCK_FORCES",
    "ALL_CHANNELS",
    "THIRD_CHANNELS",
    "THIRD_CHANNEL_QUANTITIES",
    "TRACK_CHANNELS",
    "rig_inputs_of",
    "missing_aero",
    "quantity_of",
    "corner_of",
    "kind_of",
    "corner_table",
]

CORNERS = ("LF", "RF", "LR", "RR")
AERO_INPUTS = ("aero_heave", "aero_roll", "aero_pitch")
WHEELLOADER_INPUTS = tuple(f"wheelloader_{c}" for c in CORNERS)
#: The 7 rig inputs, in the order used for every input vector. A 4-post rig (no aero
#: actuators) has only the :data:`WHEELLOADER_INPUTS` (:func:`rig_inputs_of`).
RIG_INPUTS = AERO_INPUTS + WHEELLOADER_INPUTS

#: Measured response kinds and their physical quantity.
RESPONSE_KINDS = {
    "shock_velocity": "velocity",
    "shock_force": "force",
    "shock_travel": "displacement",
    "tire_force": "force",
    "ride_height": "displacement",
    "chassis_accel": "acceleration",
    "wheel_accel": "acceleration",
    "spring_force": "force",
}
RESPONSE_CHANNELS = tuple(f"{k}_{c}" for k in RESPONSE_KINDS for c in CORNERS)
SHOCK_VELOCITIES = tuple(f"shock_velocity_{c}" for c in CORNERS)
SHOCK_FORCES = tuple(f"shock_force_{c}" for c in CORNERS)
ALL_CHANNELS = RIG_INPUTS + RESPONSE_CHANNELS
#: Run-file channels of the third elements (the spec's optional section "Third elements":
#: heave and roll elements per axle), each optional, and their quantities.
THIRD_CHANNEL_QUANTITIES = {
    f"{name}_{axle}": quantity
    for axle in ("front", "rear")
    for name, quantity in (("heave_velocity", "velocity"), ("heave_travel", "displacement"),
                           ("heave_force", "force"), ("heave_spring_force", "force"),
                           ("roll_velocity", "velocity"), ("roll_travel", "displacement"),
                           ("roll_force", "force"))}
#: The third elements' run-file channels, in the spec's order.
THIRD_CHANNELS = tuple(THIRD_CHANNEL_QUANTITIES)
#: Channels of a track log (:mod:`ident.data.tracklog`) that no rig run has: ``speed``, the
#: car's speed [m/s]. Not in :data:`ALL_CHANNELS` (session runs and drives never hold them)
#: and without a response kind (:func:`kind_of` refuses them); :func:`quantity_of` knows them.
TRACK_CHANNELS = ("speed",)

_INPUT_QUANTITY = {"aero_heave": "force", "aero_roll": "moment", "aero_pitch": "moment"}
_INPUT_QUANTITY.update({w: "displacement" for w in WHEELLOADER_INPUTS})
_TRACK_QUANTITY = {"speed": "velocity"}


def rig_inputs_of(channels):
    """Return the rig inputs among some channel names, in :data:`RIG_INPUTS` order.

    A run of a 7-post or 8-post rig has all seven; a 4-post run only the four
    wheelloaders (the spec's "Run files").

    Examples
    --------
    >>> rig_inputs_of(["time", "wheelloader_RF", "wheelloader_LF", "tire_force_LF"])
    ('wheelloader_LF', 'wheelloader_RF')
    """
    return tuple(c for c in RIG_INPUTS if c in channels)


def missing_aero(channels):
    """Aero inputs missing from channels that hold some but not all three (else ``[]``).

    The aero channels come all three (a rig with aero actuators) or not at all
    (a 4-post rig).

    Examples
    --------
    >>> missing_aero(["aero_heave", "wheelloader_LF"]), missing_aero(["wheelloader_LF"])
    (['aero_roll', 'aero_pitch'], [])
    """
    present = [c for c in AERO_INPUTS if c in channels]
    return [c for c in AERO_INPUTS if c not in channels] if present else []


def kind_of(channel):
    """Return the response kind of a channel (``"tire_force_LF"`` -> ``"tire_force"``).

    Rig inputs return their own name.
    """
    if channel in _INPUT_QUANTITY:
        return channel
    kind, _, corner = channel.rpartition("_")
    if kind in RESPONSE_KINDS and corner in CORNERS:
        return kind
    raise ValueError(
        f"unknown channel {channel!r}; canonical channels are the rig inputs "
        f"{list(RIG_INPUTS)} and '<kind>_<corner>' with kind in {list(RESPONSE_KINDS)} "
        f"and corner in {list(CORNERS)}"
    )


def corner_of(channel):
    """Return the corner of a per-corner channel, or ``None`` for aero inputs."""
    if channel in AERO_INPUTS:
        return None
    kind_of(channel)
    return channel.rpartition("_")[2]


def quantity_of(channel):
    """Return the physical quantity of a canonical channel (key of ``units.TO_SI``).

    The canonical channels are :data:`ALL_CHANNELS` and the track-log channels
    :data:`TRACK_CHANNELS`.

    Examples
    --------
    >>> quantity_of("aero_roll"), quantity_of("shock_velocity_RR"), quantity_of("speed")
    ('moment', 'velocity', 'velocity')
    """
    if channel in _INPUT_QUANTITY:
        return _INPUT_QUANTITY[channel]
    if channel in _TRACK_QUANTITY:
        return _TRACK_QUANTITY[channel]
    if channel in THIRD_CHANNEL_QUANTITIES:
        return THIRD_CHANNEL_QUANTITIES[channel]
    return RESPONSE_KINDS[kind_of(channel)]


#: The rigs a session or plan may come from: 7- and 8-post rigs have aero actuators, a
#: 4-post rig has the wheel pads only.
RIG_KINDS = ("7-post", "8-post", "4-post")


def corner_table(value, *, name, where, what="values", error=ValueError, type_error=TypeError,
                 sequence=False):
    """Check a per-corner table and return it as a dict in :data:`CORNERS` order.

    The one check of the per-corner inputs (a session's, a plan's and a setup's bump stops
    and packers, static loads, friction, a setup's shocks, a simulation's per-corner
    arguments): a mapping corner -> value whose keys are corners, or (with `sequence`) 4
    values in corner order. Which corners must be given and what a value must be is the
    caller's check.

    Parameters
    ----------
    value : mapping, sequence of 4 or None
        The table; None is the empty table.
    name : str
        The argument or key named in messages (``"bump_stops"``).
    where : str
        Who asks, put first in messages.
    what : str, optional
        What a value is, named in messages (``"bump-stop ids"``).
    error : type, optional
        The exception raised on an unknown corner or a sequence not of 4 (default
        :class:`ValueError`; a caller passes its own subclass).
    type_error : type, optional
        The exception raised when `value` is neither a mapping nor (with `sequence`) a
        sequence (default :class:`TypeError`: an argument, the message names a mapping;
        a file's error class, such as :class:`~ident.errors.SessionError`, names a table).
    sequence : bool, optional
        Accept 4 values in the order LF, RF, LR, RR too (default False).

    Returns
    -------
    dict of str to object
        Corner -> value for the corners given, in :data:`CORNERS` order (all four for
        a sequence).

    Raises
    ------
    error
        On an unknown corner, or a sequence not of 4.
    type_error
        If `value` is not a table.

    Examples
    --------
    >>> corner_table({"RR": 1.0, "LF": 2.0}, name="packers", where="run 'a'")
    {'LF': 2.0, 'RR': 1.0}
    >>> corner_table({"FL": 1.0}, name="packers", where="run 'a'")
    Traceback (most recent call last):
    ...
    ValueError: run 'a': packers names unknown corner(s) ['FL']; the corners are LF, RF, LR, RR
    """
    if value is None:
        return {}
    if isinstance(value, Mapping):
        unknown = [c for c in value if c not in CORNERS]
        if unknown:
            raise error(f"{where}: {name} names unknown corner(s) {unknown}; the corners are "
                        f"{', '.join(CORNERS)}")
        return {c: value[c] for c in CORNERS if c in value}
    if sequence and not isinstance(value, (str, bytes)) and hasattr(value, "__len__"):
        if len(value) != 4:
            raise error(f"{where}: {name} must be 4 {what}, one per corner LF, RF, LR, RR "
                        f"(or a table {{ LF = ..., RF = ... }}), got {value!r}")
        return dict(zip(CORNERS, value))
    or_4 = " or 4 of them in corner order" if sequence else ""
    if issubclass(type_error, TypeError):   # an argument
        raise type_error(f"{where}: {name} must be a mapping corner -> {what}{or_4}, got "
                         f"{type(value).__name__}")
    raise type_error(f"{where}: {name} must be a table {{ LF = ..., RF = ... }} of {what}{or_4}, "
                     f"got {value!r}")
