"""Canonical channel names of the rig-session format and their quantities.

The names, corners and sign conventions are those of
``shared/spec/rig-session.md``: vertical displacements positive up; shock
deflection, velocity and force, spring force and tire force positive in
compression.
"""

from __future__ import annotations

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
    "TRACK_CHANNELS",
    "rig_inputs_of",
    "missing_aero",
    "quantity_of",
    "corner_of",
    "kind_of",
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
    return RESPONSE_KINDS[kind_of(channel)]


#: The rigs a session or plan may come from: 7- and 8-post rigs have aero actuators, a
#: 4-post rig has the wheel pads only.
RIG_KINDS = ("7-post", "8-post", "4-post")
