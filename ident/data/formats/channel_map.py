"""Channel maps: which channel of a rig data file holds each canonical channel.

A rig's acquisition names its channels its own way (``WL_LF_Disp``), in its
own units (mm, kN, in/s) and sign conventions. A channel-map TOML file says,
per canonical shockplan channel (:data:`ident.data.channels.ALL_CHANNELS`), where
to find it in the file and how to turn it into SI with shockplan's signs:

.. code-block:: toml

    format = "channel-map/1"
    name = "8-post, MTS RPC export"       # optional
    time = "Time"                          # optional: a channel holding time [s]

    [channels.wheelloader_LF]
    source = "WL_LF_Disp"                  # the channel's name in the file
    units = "mm"                           # the unit of scale * (raw - offset)
    sign = 1                               # +1 or -1 (required)
    scale = 1.0                            # optional, default 1
    offset = 0.0                           # optional, default 0, raw file units

    [channels.shock_velocity_LF]
    source = "Damper LF vel"
    units = "in/s"
    sign = -1                              # this rig logs extension positive

Conversion (one formula for every channel; ``raw`` is the number in the file)::

    x_si = sign * factor(units) * scale * (raw - offset)

- ``offset`` is in the file's raw numbers: the raw value at the channel's zero,
  subtracted first (downstream only the dynamic part counts, so it rarely
  matters);
- ``scale`` multiplies next (a calibration correction, or the gain of a raw
  channel such as volts), so ``units`` is the unit of ``scale * (raw - offset)``;
- ``factor(units)`` converts that unit to SI (:data:`UNIT_FACTORS`);
- ``sign`` turns the file's convention into shockplan's: vertical
  displacements and accelerations up positive; shock velocity, force and
  travel, spring and tire forces compression positive. ``sign = -1`` for a
  file whose convention is the opposite.

Accepted ``units`` per quantity (:data:`UNIT_FACTORS`; a few common spellings
such as ``"Nm"``, ``"m/s2"`` or ``"in-lbf"`` are accepted as aliases,
:data:`UNIT_ALIASES`):

- displacement: ``m``, ``cm``, ``mm``, ``in``
- velocity: ``m/s``, ``mm/s``, ``in/s``
- acceleration: ``m/s^2``, ``mm/s^2``, ``in/s^2``, ``g`` (standard gravity)
- force: ``N``, ``kN``, ``lbf``
- moment: ``N*m``, ``kN*m``, ``lbf*in``, ``lbf*ft``

The optional top-level ``time`` names a channel holding the time in seconds,
for files without a time base of their own (a TDMS file without waveform
properties); otherwise the file's own time base is used.

The same file maps a car's data logger onto a track log (:mod:`ident.data.tracklog`),
whose maps may also hold ``speed`` (velocity units, :data:`ident.data.channels.TRACK_CHANNELS`);
a session import's map may not (the ``allowed`` option of :func:`make_channel_map` and
:func:`read_channel_map`).

Examples
--------
>>> cmap = make_channel_map({"wheelloader_LF": {"source": "WL_LF", "units": "mm", "sign": 1},
...                          "shock_force_LF": {"source": "F_LF", "units": "lbf", "sign": -1}})
>>> x = apply_channel_map(cmap, {"WL_LF": [25.4, -12.7], "F_LF": [-100.0, 50.0]})
>>> [round(float(v), 12) for v in x["wheelloader_LF"]]
[0.0254, -0.0127]
>>> [round(float(v), 6) for v in x["shock_force_LF"]]
[444.822162, -222.411081]
"""

from __future__ import annotations

import difflib
import logging
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from ident.data.files import read_toml
from ident.data.channels import ALL_CHANNELS, TRACK_CHANNELS, quantity_of
from ident.errors import SessionError
from ident.data.units import TO_SI

__all__ = [
    "CHANNEL_MAP_FORMAT",
    "UNIT_FACTORS",
    "UNIT_ALIASES",
    "STANDARD_GRAVITY_M_S2",
    "ChannelSpec",
    "ChannelMap",
    "read_channel_map",
    "make_channel_map",
    "apply_channel_map",
    "unit_factor",
    "normalize_unit",
]

logger = logging.getLogger(__name__)

#: Value of the ``format`` key understood by this version.
CHANNEL_MAP_FORMAT = "channel-map/1"
#: Standard gravity [m/s^2] (the unit ``g``).
STANDARD_GRAVITY_M_S2 = 9.80665

_IN = TO_SI["displacement"]  # in -> m
_LBF = TO_SI["force"]  # lbf -> N

#: Factor from each accepted unit to the SI unit, per quantity.
UNIT_FACTORS = MappingProxyType({
    "displacement": MappingProxyType({"m": 1.0, "cm": 1e-2, "mm": 1e-3, "in": _IN}),
    # km/h and mph: a track logger's speed (the shock velocities are never in them)
    "velocity": MappingProxyType({"m/s": 1.0, "mm/s": 1e-3, "in/s": _IN, "km/h": 1.0 / 3.6,
                                  "mph": 0.44704}),
    "acceleration": MappingProxyType({"m/s^2": 1.0, "mm/s^2": 1e-3, "in/s^2": _IN,
                                      "g": STANDARD_GRAVITY_M_S2}),
    "force": MappingProxyType({"N": 1.0, "kN": 1e3, "lbf": _LBF}),
    "moment": MappingProxyType({"N*m": 1.0, "kN*m": 1e3, "lbf*in": _LBF * _IN,
                                "lbf*ft": _LBF * 12.0 * _IN}),
})

#: Other spellings accepted for a unit (alias -> the spelling of :data:`UNIT_FACTORS`).
UNIT_ALIASES = MappingProxyType({
    "inch": "in", "inches": "in",
    "in/sec": "in/s", "ips": "in/s",
    "kph": "km/h", "kmh": "km/h", "km/hr": "km/h", "mi/h": "mph",
    "m/s2": "m/s^2", "m/s²": "m/s^2", "m/sec^2": "m/s^2",
    "mm/s2": "mm/s^2", "mm/s²": "mm/s^2",
    "in/s2": "in/s^2", "in/s²": "in/s^2", "in/sec^2": "in/s^2",
    "G": "g",
    "Nm": "N*m", "N.m": "N*m", "N-m": "N*m", "N m": "N*m", "N·m": "N*m", "m*N": "N*m",
    "kNm": "kN*m", "kN.m": "kN*m", "kN-m": "kN*m", "kN·m": "kN*m",
    "lbf.in": "lbf*in", "lbf-in": "lbf*in", "in*lbf": "lbf*in", "in-lbf": "lbf*in",
    "in.lbf": "lbf*in", "lbf in": "lbf*in", "in lbf": "lbf*in",
    "lbf.ft": "lbf*ft", "lbf-ft": "lbf*ft", "ft*lbf": "lbf*ft", "ft-lbf": "lbf*ft",
    "ft.lbf": "lbf*ft",
})

_TOP_KEYS = ("format", "name", "time", "channels")
_ENTRY_KEYS = ("source", "units", "sign", "scale", "offset")
_REQUIRED_KEYS = ("source", "units", "sign")


# --------------------------------------------------------------------------------------
# Units
# --------------------------------------------------------------------------------------


def normalize_unit(units, quantity):
    """Return the spelling of :data:`UNIT_FACTORS` for a unit string, or ``None``.

    Parameters
    ----------
    units : str
        A unit as written in a map or a file (``"mm"``, ``"Nm"``, ``" in/s "``).
    quantity : str
        ``"displacement"``, ``"velocity"``, ``"acceleration"``, ``"force"`` or
        ``"moment"``.

    Returns
    -------
    str or None
        The accepted spelling (``"N*m"`` for ``"Nm"``), or ``None`` if the
        unit is not one of the quantity's.

    Examples
    --------
    >>> normalize_unit("Nm", "moment"), normalize_unit("mm", "force")
    ('N*m', None)
    """
    if not isinstance(units, str):
        return None
    table = UNIT_FACTORS.get(quantity, {})
    u = units.strip()
    u = UNIT_ALIASES.get(u, u)
    return u if u in table else None


def unit_factor(units, quantity, *, where="units"):
    """Return the factor from `units` to the SI unit of `quantity`.

    Parameters
    ----------
    units : str
        An accepted unit or alias (see the module docstring).
    quantity : str
        A quantity of :data:`UNIT_FACTORS`.
    where : str
        Start of the error message (file and channel).

    Returns
    -------
    float
        Multiply a value in `units` by it to get SI.

    Raises
    ------
    SessionError
        If `units` is not a unit of `quantity` (the message lists the accepted ones).

    Examples
    --------
    >>> unit_factor("kN", "force"), unit_factor("in/s", "velocity")
    (1000.0, 0.0254)
    """
    name = normalize_unit(units, quantity)
    if name is None:
        accepted = ", ".join(repr(u) for u in UNIT_FACTORS[quantity])
        raise SessionError(
            f"{where}: unit {units!r} is not a {quantity} unit; use one of {accepted}"
        )
    return UNIT_FACTORS[quantity][name]


# --------------------------------------------------------------------------------------
# The map
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ChannelSpec:
    """Where one canonical channel is in a file and how to convert it to SI.

    Attributes
    ----------
    canonical : str
        The shockplan channel (:data:`ident.data.channels.ALL_CHANNELS`).
    source : str
        The channel's name in the file.
    units : str
        Unit of ``scale * (raw - offset)``, as an accepted spelling of
        :data:`UNIT_FACTORS` (aliases are normalized).
    sign : int
        +1 or -1: the file's convention times `sign` is shockplan's.
    scale : float
        Multiplies the raw value after the offset is subtracted (default 1).
    offset : float
        Raw value at the channel's zero, in the file's raw numbers (default 0).

    Notes
    -----
    ``x_si = sign * factor(units) * scale * (raw - offset)``.
    """

    canonical: str
    source: str
    units: str
    sign: int
    scale: float = 1.0
    offset: float = 0.0

    @property
    def quantity(self):
        """str: The physical quantity of the channel (``"force"``, ...)."""
        return quantity_of(self.canonical)

    @property
    def gain_si(self):
        """float: ``sign * factor(units) * scale``, the SI value of one raw unit."""
        return self.sign * UNIT_FACTORS[self.quantity][self.units] * self.scale

    def to_si(self, raw):
        """Convert raw file values to SI with shockplan's sign.

        Parameters
        ----------
        raw : array_like, shape (n_samples,)
            Values as stored in the file.

        Returns
        -------
        ndarray, shape (n_samples,)
            ``sign * factor(units) * scale * (raw - offset)`` [SI], float64.
        """
        return self.gain_si * (np.asarray(raw, dtype=np.float64) - self.offset)

    def from_si(self, x_si):
        """Convert SI values to the file's raw values (inverse of :meth:`to_si`).

        Parameters
        ----------
        x_si : array_like, shape (n_samples,)
            Values in SI with shockplan's sign.

        Returns
        -------
        ndarray, shape (n_samples,)
            ``x_si / (sign * factor(units) * scale) + offset``, float64.
        """
        return np.asarray(x_si, dtype=np.float64) / self.gain_si + self.offset

    def check_file_unit(self, file_unit, *, where):
        """Refuse a unit the file gives the channel that contradicts the map's `units`.

        Only a unit the file states, that is a known unit of the channel's
        quantity, is compared, and only when ``scale == 1`` (with another
        scale, `units` describes the scaled value, not the file's numbers).
        An empty or unknown file unit (``"V"``, ``"mm "`` with odd spelling)
        is logged at debug level and accepted.

        Parameters
        ----------
        file_unit : str
            The unit string stored in the file for `source` (``""`` if none).
        where : str
            The file, as named in messages.

        Raises
        ------
        SessionError
            If the file's unit is a different known unit (``"m"`` where the
            map says ``"mm"``).
        """
        if self.scale != 1.0 or not file_unit:
            return
        found = normalize_unit(file_unit, self.quantity)
        if found is None:
            logger.debug("%s: channel %r has unit %r, not a known %s unit; the map's %r is "
                         "used", where, self.source, file_unit, self.quantity, self.units)
        elif found != self.units:
            raise SessionError(
                f"{where}: channel {self.source!r} ({self.canonical}) is in {file_unit!r} "
                f"according to the file but the channel map says units = {self.units!r}; "
                f"set units = {found!r} in [channels.{self.canonical}] (and a scale if the "
                "file's values are not really in that unit)"
            )


@dataclass(frozen=True)
class ChannelMap:
    """A checked channel map: canonical channel -> :class:`ChannelSpec`.

    Attributes
    ----------
    channels : mapping of str to ChannelSpec
        Read-only, in :data:`ident.data.channels.ALL_CHANNELS` order (then the track-log
        channels of :data:`ident.data.channels.TRACK_CHANNELS`, which only a map built with
        them ``allowed`` holds).
    time : str or None
        The source channel holding time [s], or ``None`` to use the file's own
        time base.
    name : str
        The map's name (default its file name).
    path : pathlib.Path or None
        The file it was read from.
    """

    channels: Mapping = field(default_factory=dict)
    time: str | None = None
    name: str = "channel map"
    path: Path | None = None

    def __post_init__(self):
        ordered = {c: self.channels[c] for c in ALL_CHANNELS + TRACK_CHANNELS
                   if c in self.channels}
        object.__setattr__(self, "channels", MappingProxyType(ordered))

    @property
    def sources(self):
        """dict of str to str: Canonical channel -> source channel name."""
        return {c: s.source for c, s in self.channels.items()}

    @property
    def where(self):
        """str: How the map is named in messages (its file, else its name)."""
        return f"channel map {self.path}" if self.path is not None else self.name

    def spec(self, canonical):
        """Return the :class:`ChannelSpec` of a canonical channel.

        Raises
        ------
        SessionError
            If the map does not map `canonical` (the message lists what it maps).
        """
        try:
            return self.channels[canonical]
        except KeyError:
            raise SessionError(
                f"{self.where}: maps no source for {canonical!r}; add a "
                f"[channels.{canonical}] table (it maps {list(self.channels)})"
            ) from None


def _suggest(name, choices):
    close = difflib.get_close_matches(str(name), list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _number(value, *, where, key, nonzero=False):
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or \
            not math.isfinite(float(value)) or (nonzero and float(value) == 0.0):
        need = "a finite non-zero number" if nonzero else "a finite number"
        raise SessionError(f"{where}: {key} = {value!r} must be {need}; write it without "
                           "quotes")
    return float(value)


def _spec_from_table(canonical, table, *, where, allowed=ALL_CHANNELS):
    entry = f"{where}: [channels.{canonical}]"
    if canonical not in allowed:
        extra = [c for c in allowed if c not in ALL_CHANNELS]
        if set(ALL_CHANNELS) <= set(allowed):
            keys = ("the rig inputs and '<kind>_<corner>' names of "
                    "ident.data.channels.ALL_CHANNELS"
                    + (f", and {', '.join(map(repr, extra))}" if extra else ""))
        else:
            keys = ", ".join(allowed)
        raise SessionError(
            f"{entry}: {canonical!r} is not a canonical channel"
            f"{_suggest(canonical, allowed)}; keys are {keys}"
        )
    if not isinstance(table, Mapping):
        raise SessionError(
            f"{entry}: must be a table with source, units and sign, got {table!r}; write "
            f"[channels.{canonical}] followed by source = \"...\", units = \"...\", sign = 1"
        )
    for key in table:
        if key not in _ENTRY_KEYS:
            raise SessionError(
                f"{entry}: unknown key {key!r}{_suggest(key, _ENTRY_KEYS)}; the keys are "
                f"{', '.join(_ENTRY_KEYS)}"
            )
    for key in _REQUIRED_KEYS:
        if key not in table:
            raise SessionError(
                f"{entry}: missing {key!r}; every mapped channel needs source, units and "
                "sign (+1 or -1)"
            )
    source = table["source"]
    if not isinstance(source, str) or not source.strip():
        raise SessionError(
            f"{entry}: source = {source!r} must be the channel's name in the file (a "
            "non-empty string)"
        )
    quantity = quantity_of(canonical)
    units = table["units"]
    if not isinstance(units, str):
        raise SessionError(f"{entry}: units = {units!r} must be a string such as "
                           f"{next(iter(UNIT_FACTORS[quantity]))!r}")
    unit_factor(units, quantity, where=f"{entry} ({quantity})")
    sign = table["sign"]
    if isinstance(sign, bool) or not isinstance(sign, numbers.Real) or sign not in (1, -1):
        raise SessionError(
            f"{entry}: sign = {sign!r} must be 1 or -1 (-1 if the file's convention is "
            "the opposite of shockplan's: up and compression positive)"
        )
    scale = _number(table.get("scale", 1.0), where=entry, key="scale", nonzero=True)
    offset = _number(table.get("offset", 0.0), where=entry, key="offset")
    return ChannelSpec(canonical=canonical, source=source, units=normalize_unit(units, quantity),
                       sign=int(sign), scale=scale, offset=offset)


def make_channel_map(channels, *, time=None, name="channel map", path=None, allowed=None):
    """Build a checked :class:`ChannelMap` from plain tables (as in the TOML file).

    Parameters
    ----------
    channels : mapping of str to mapping
        Canonical channel -> ``{"source": str, "units": str, "sign": 1 | -1,
        "scale": float (optional), "offset": float (optional)}``.
    time : str, optional
        The source channel holding time [s].
    name : str
        The map's name, used in messages.
    path : str or os.PathLike, optional
        The file the tables came from (used in messages).
    allowed : iterable of str, optional
        The canonical channels the map may hold (default
        :data:`ident.data.channels.ALL_CHANNELS`, those of session runs and drives). A
        track log's map (:mod:`ident.data.tracklog`) also allows the channels of
        :data:`ident.data.channels.TRACK_CHANNELS` (``speed``); a name outside
        ``ALL_CHANNELS + TRACK_CHANNELS`` is never held.

    Returns
    -------
    ChannelMap

    Raises
    ------
    ValueError
        If `allowed` names a channel that is not canonical.
    SessionError
        One sentence naming the map and the channel, if: a key is not a
        canonical channel (not in `allowed`); an entry misses ``source``, ``units`` or
        ``sign`` or has an unknown key; ``units`` is not a unit of the channel's quantity
        (the accepted ones are listed); ``sign`` is not +1/-1; ``scale`` is
        zero or not a number; ``offset`` is not a number; two channels (or a
        channel and ``time``) name the same source.
    """
    path = None if path is None else Path(path)
    where = f"channel map {path}" if path is not None else str(name)
    allowed = ALL_CHANNELS if allowed is None else tuple(dict.fromkeys(allowed))
    unknown = [c for c in allowed if c not in ALL_CHANNELS + TRACK_CHANNELS]
    if unknown:
        raise ValueError(f"make_channel_map: allowed names {unknown}, which are not canonical "
                         "channels (ident.data.channels.ALL_CHANNELS, TRACK_CHANNELS)")
    if not isinstance(channels, Mapping):
        raise SessionError(f"{where}: [channels] must be a table of [channels.<canonical>] "
                           f"tables, got {type(channels).__name__}")
    specs = {c: _spec_from_table(c, t, where=where, allowed=allowed)
             for c, t in channels.items()}
    if time is not None and (not isinstance(time, str) or not time.strip()):
        raise SessionError(f"{where}: time = {time!r} must be the name of the channel "
                           "holding time in seconds (a non-empty string), or be omitted")
    seen = {} if time is None else {time: "time"}
    for c, spec in specs.items():
        if spec.source in seen:
            raise SessionError(
                f"{where}: [channels.{c}] source {spec.source!r} is already the source of "
                f"{seen[spec.source]!r}; each file channel can hold only one channel"
            )
        seen[spec.source] = c
    return ChannelMap(channels=specs, time=time, name=str(name), path=path)


def read_channel_map(path, *, allowed=None):
    """Read and check a channel-map TOML file.

    Parameters
    ----------
    path : str or os.PathLike
        The TOML file (format in the module docstring).
    allowed : iterable of str, optional
        The canonical channels the map may hold, as :func:`make_channel_map` (default
        :data:`ident.data.channels.ALL_CHANNELS`).

    Returns
    -------
    ChannelMap
        Frozen; ``name`` defaults to the file name.

    Raises
    ------
    SessionError
        If the file is missing or not TOML; ``format`` is missing or not
        ``"channel-map/1"``; a top-level key is unknown; there is no
        ``[channels]`` table; or an entry fails the checks of
        :func:`make_channel_map`. Every message names the file and the channel.

    Examples
    --------
    >>> import os, tempfile
    >>> p = os.path.join(tempfile.mkdtemp(), "map.toml")
    >>> _ = open(p, "w").write('format = "channel-map/1"\\n[channels.wheelloader_LF]\\n'
    ...                        'source = "WL_LF_Disp"\\nunits = "mm"\\nsign = 1\\n')
    >>> cmap = read_channel_map(p)
    >>> cmap.sources, cmap.channels["wheelloader_LF"].gain_si
    ({'wheelloader_LF': 'WL_LF_Disp'}, 0.001)
    """
    path = Path(path)
    doc = read_toml(path, error=SessionError, what="channel map")
    where = f"channel map {path}"
    fmt = doc.get("format")
    if fmt != CHANNEL_MAP_FORMAT:
        got = "no 'format' key" if fmt is None else f"format {fmt!r}"
        raise SessionError(
            f"{where}: {got}; a channel map starts with format = \"{CHANNEL_MAP_FORMAT}\""
        )
    for key in doc:
        if key not in _TOP_KEYS:
            raise SessionError(
                f"{where}: unknown top-level key {key!r}{_suggest(key, _TOP_KEYS)}; the "
                f"keys are {', '.join(_TOP_KEYS)} and the [channels.<canonical>] tables"
            )
    if "channels" not in doc or not doc["channels"]:
        raise SessionError(
            f"{where}: no [channels.<canonical>] tables; map at least one channel, e.g. "
            "[channels.wheelloader_LF] with source, units and sign"
        )
    name = doc.get("name", path.name)
    if not isinstance(name, str):
        raise SessionError(f"{where}: name = {name!r} must be a string")
    cmap = make_channel_map(doc["channels"], time=doc.get("time"), name=name, path=path,
                            allowed=allowed)
    logger.debug("read channel map %s: %d channel(s)", path, len(cmap.channels))
    return cmap


def apply_channel_map(channel_map, raw, *, where=None):
    """Convert raw file channels to SI canonical channels with a channel map.

    Parameters
    ----------
    channel_map : ChannelMap
        The map.
    raw : mapping of str to array_like, shape (n_samples,)
        Source channel name -> raw values as stored in the file.
    where : str, optional
        Start of the error message (default: the map).

    Returns
    -------
    dict of str to ndarray, shape (n_samples,)
        Canonical channel -> SI values with shockplan's signs (float64), for
        every channel of the map, in :data:`ident.data.channels.ALL_CHANNELS` order.

    Raises
    ------
    TypeError
        If `channel_map` is not a :class:`ChannelMap`.
    SessionError
        If `raw` lacks a mapped source channel (the message names it and lists
        the channels `raw` has).

    Notes
    -----
    ``x_si = sign * factor(units) * scale * (raw - offset)``; no check of
    lengths, sampling or finiteness here (see :func:`ident.data.formats.read_run`).
    """
    if not isinstance(channel_map, ChannelMap):
        raise TypeError(f"channel_map must be a ChannelMap, got {type(channel_map).__name__}")
    where = channel_map.where if where is None else where
    out = {}
    for canonical, spec in channel_map.channels.items():
        if spec.source not in raw:
            raise SessionError(
                f"{where}: no channel {spec.source!r} (mapped to {canonical}); the data "
                f"have {sorted(raw)}; fix source in [channels.{canonical}]"
            )
        out[canonical] = spec.to_si(raw[spec.source])
    return out
