"""Aero loads from speed: the team's downforce and balance model and its TOML file.

A rig drive built from track data (issue 27) loads the chassis with the aero forces the
car felt on track. They come from the logged speed (and, for a ride-height map, the
logged front and rear ride heights) through a downforce and balance model the team
gives, in one of three kinds (:data:`AERO_KINDS`):

``constant``
    One downforce ``D_ref`` at a reference speed ``v_ref`` and one balance:
    ``D = D_ref * (v / v_ref)**2``.
``speed_table``
    Downforce (and balance) at speeds ``v_0 < v_1 < ... < v_{K-1}``, linear between
    them. Below ``v_0 > 0`` the first point is scaled, ``D = D_0 * (v / v_0)**2`` (0 at
    ``v = 0``), with the first balance; above ``v_{K-1}`` the last,
    ``D = D_{K-1} * (v / v_{K-1})**2``, with the last balance.
``ride_height_map``
    Downforce and balance at ``v_ref`` on a grid of front and rear ride heights,
    bilinear between the grid's nodes and held at its edges outside it (each ride height
    clamped to its grid), scaled by ``(v / v_ref)**2``.

:class:`AeroModel` holds a model in SI and gives its loads (:meth:`AeroModel.loads`,
an :class:`AeroLoads`); :func:`read_aero_model` and :func:`aero_model_from_dict` read
one, checking every key once; :func:`write_aero_model` writes one atomically.

File format (lengths in m or in, speeds in m/s or in/s, forces in N or lbf, per
``units``)::

    format = "shockplan-aero/1"
    units = "SI"                   # or "imperial"
    name = "high downforce"        # optional: the file's name without .toml
    kind = "constant"              # or "speed_table", "ride_height_map"
    cg_to_front_axle = 1.25        # a [m], > 0
    cg_to_rear_axle = 1.35         # b [m], > 0
    reference_speed = 50.0         # [m/s], > 0 (constant, ride_height_map)
    downforce = 4000.0             # [N] at the reference speed, >= 0
    balance = 0.45                 # front share of the downforce, 0 to 1

    # kind = "speed_table": speed (strictly increasing, >= 0), downforce (one per
    # speed), balance (a number, or one per speed)
    # kind = "ride_height_map": reference_speed, ride_height_front and
    # ride_height_rear (strictly increasing grids of absolute ride heights as the car's
    # lasers log them), downforce and balance as 2-D arrays [front index][rear index]
    # (balance may be one number)

Notes
-----
Signs, as in the rig-session spec: ``aero_heave`` is a force acting **up** at the
centre of gravity; ``aero_pitch`` a moment in the positive pitch direction, which
**raises the rear** (corner displacement rows ``LF [1, t/2, -a]``, ``LR [1, t/2, b]``);
``aero_roll`` a moment in the positive roll direction.

The downforce ``D >= 0`` pushes the car down. Its front share ``balance`` acts at the
front axle, ``D_f = balance * D``, the rest at the rear axle, ``D_r = (1 - balance) *
D``. With ``a`` the distance from the centre of gravity to the front axle and ``b`` to
the rear axle::

    aero_heave = -D                                   [N]
    aero_pitch = a * D_f - b * D_r = D * ((a + b) * balance - b)    [N*m]
    aero_roll  = 0                                    [N*m] (no lateral aero)

A front down-force lowers the front, that is it pitches the car in the positive
direction (rear up); a rear down-force lowers the rear. These are the generalized forces
of the axle loads by virtual work: ``[heave, roll, pitch] = T^T f`` with ``f`` the
corner forces (up positive: ``-D_f / 2`` at each front corner, ``-D_r / 2`` at each
rear one). At ``balance = b / (a + b)`` (the static weight distribution) the pitch
moment is 0; forward of it the moment is positive and, on a car whose springs carry the
weight without pitching, the front sinks more than the rear.

Speeds are magnitudes [m/s] (the aero does not care which way the car goes); ride
heights are absolute [m], the same quantity as the map's grid. A lifting car (negative
downforce) is out of scope and refused.

Examples
--------
>>> model = aero_model_from_dict({"format": "shockplan-aero/1", "kind": "constant",
...     "cg_to_front_axle": 1.2, "cg_to_rear_axle": 1.4, "reference_speed": 50.0,
...     "downforce": 4000.0, "balance": 0.45})
>>> loads = model.loads([0.0, 25.0, 50.0])
>>> loads.downforce_n.tolist()            # a quarter at half the speed
[0.0, 1000.0, 4000.0]
>>> loads.channels["aero_heave"].tolist()  # the spec's heave force acts up
[-0.0, -1000.0, -4000.0]
>>> loads.channels["aero_pitch"].round(6).tolist()  # balance behind 1.4 / 2.6: rear down
[0.0, -230.0, -920.0]
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from ident.data.channels import AERO_INPUTS
from ident.data.files import atomic_write_toml, did_you_mean, read_toml
from ident.data.units import UNIT_LABELS, check_units, from_si, to_si
from ident.errors import AeroModelError
from ident.models.shocks import is_real_number

__all__ = [
    "AERO_CHANNELS",
    "AERO_FORMAT",
    "AERO_KINDS",
    "AeroLoads",
    "AeroModel",
    "aero_model_from_dict",
    "read_aero_model",
    "write_aero_model",
]

logger = logging.getLogger(__name__)

#: Value of an aero model file's ``format`` key.
AERO_FORMAT = "shockplan-aero/1"
#: The kinds of aero model (see the module docstring).
AERO_KINDS = ("constant", "speed_table", "ride_height_map")
#: The rig-input channels :meth:`AeroModel.loads` gives, in the spec's order.
AERO_CHANNELS = AERO_INPUTS

#: TOML key -> (attribute, quantity) of the keys every kind has.
_GEOMETRY = {"cg_to_front_axle": ("cg_to_front_axle_m", "displacement"),
             "cg_to_rear_axle": ("cg_to_rear_axle_m", "displacement")}
#: Per kind, TOML key -> (attribute, quantity, shape). Shapes: "scalar" a number,
#: "vector" a list of numbers, "matrix" a 2-D list; "vector|scalar" and "matrix|scalar"
#: either.
_KIND_FIELDS = {
    "constant": {"reference_speed": ("reference_speed_m_s", "velocity", "scalar"),
                 "downforce": ("downforce_n", "force", "scalar"),
                 "balance": ("balance", "dimensionless", "scalar")},
    "speed_table": {"speed": ("speed_grid_m_s", "velocity", "vector"),
                    "downforce": ("downforce_n", "force", "vector"),
                    "balance": ("balance", "dimensionless", "vector|scalar")},
    "ride_height_map": {"reference_speed": ("reference_speed_m_s", "velocity", "scalar"),
                        "ride_height_front": ("ride_height_front_grid_m", "displacement",
                                              "vector"),
                        "ride_height_rear": ("ride_height_rear_grid_m", "displacement",
                                             "vector"),
                        "downforce": ("downforce_n", "force", "matrix"),
                        "balance": ("balance", "dimensionless", "matrix|scalar")},
}
_HEAD_KEYS = ("format", "units", "name", "kind")
_TOP_KEYS = tuple(dict.fromkeys([*_HEAD_KEYS, *_GEOMETRY,
                                 *(k for f in _KIND_FIELDS.values() for k in f)]))
#: The kind-dependent attributes, and the TOML key of every attribute (for messages).
_KIND_ATTRS = ("reference_speed_m_s", "speed_grid_m_s", "ride_height_front_grid_m",
               "ride_height_rear_grid_m", "downforce_n", "balance")
_ATTR_KEYS = {"name": "name", "kind": "kind",
              **{attr: key for key, (attr, _) in _GEOMETRY.items()},
              **{attr: key for f in _KIND_FIELDS.values() for key, (attr, _, _) in f.items()}}


def _error(who, field_name, problem, fix):
    """An :class:`AeroModelError` about one field, its parts kept for re-wording with the
    file's keys (as :mod:`ident.models.bumpstops` does)."""
    exc = AeroModelError(f"{who}: {field_name} {problem}; {fix}")
    exc.field, exc.problem, exc.fix = field_name, problem, fix
    return exc


def _where_bad(mask):
    """``(count, first flat index)`` of the true entries of `mask`."""
    flat = np.flatnonzero(np.ravel(mask))
    return flat.size, int(flat[0]) if flat.size else -1


def _at(first, shape):
    """`` at [i]`` or `` at [i][j]``: where the flat index `first` is (``""`` for a number)."""
    if not shape:
        return ""
    return " at " + "".join(f"[{int(i)}]" for i in np.unravel_index(first, shape))


def _finite_float(who, name, value, unit):
    """`value` as a finite float, or raise naming the field."""
    if not is_real_number(value):
        raise _error(who, name, f"must be a number, got {type(value).__name__} {value!r}",
                     "give a finite number")
    x = float(value)
    if not math.isfinite(x):
        raise _error(who, name, f"is {x}, not finite",
                     "give a finite number" + (f" [{unit}]" if unit != "-" else ""))
    return x


def _finite_array(who, name, value, ndim, unit):
    """`value` as a read-only finite float64 array with `ndim` dimensions, or raise."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise _error(who, name, f"is not a {ndim}-D array of numbers ({value!r})",
                     "give numbers" if ndim == 1 else "give one row of numbers per front "
                     "ride height, all rows as long") from None
    if arr.ndim != ndim:
        raise _error(who, name, f"has {arr.ndim} dimension(s), not {ndim}",
                     "give a list of numbers" if ndim == 1 else "give a 2-D array, one row "
                     "per front ride height and one value per rear ride height")
    count, first = _where_bad(~np.isfinite(arr))
    if count:
        raise _error(who, f"{name}{_at(first, arr.shape)[4:]}", f"is {arr.flat[first]}, not "
                     "finite", "give finite numbers" + (f" [{unit}]" if unit != "-" else ""))
    arr.flags.writeable = False
    return arr


def _increasing_grid(who, name, value, unit):
    """A strictly increasing 1-D grid of at least 2 points, read-only, or raise."""
    grid = _finite_array(who, name, value, 1, unit)
    if grid.size < 2:
        raise _error(who, name, f"has {grid.size} point(s)", "give at least 2 points")
    step = np.diff(grid)
    if np.any(step <= 0):
        j = int(np.flatnonzero(step <= 0)[0])
        raise _error(who, name, f"is not strictly increasing at index {j + 1} ({grid[j]:g} "
                     f"then {grid[j + 1]:g} {unit})", "sort the points and remove repeats")
    return grid


def _check_downforce(who, name, d):
    """Refuse negative downforce (a lifting car)."""
    count, first = _where_bad(np.asarray(d) < 0)
    if count:
        value = float(np.ravel(d)[first])
        raise _error(who, name, f"is negative ({value:g} N{_at(first, np.shape(d))}): a "
                     "lifting car is out of scope of this model", "give downforce >= 0 "
                     "(positive pushes the car down): if the source gives lift (a negative "
                     "lift coefficient), change its sign")


def _check_balance(who, name, bal):
    """Refuse a balance outside [0, 1]."""
    count, first = _where_bad((np.asarray(bal) < 0) | (np.asarray(bal) > 1))
    if count:
        value = float(np.ravel(bal)[first])
        raise _error(who, name, f"= {value:g}{_at(first, np.shape(bal))} is outside [0, 1]",
                     "give the front axle's share of the downforce, 0 to 1 (0.45 = 45 % "
                     "front), not a percentage")


# ----------------------------------------------------------------------------
# results
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class AeroLoads:
    """The aero loads of a drive, from :meth:`AeroModel.loads`.

    Attributes
    ----------
    channels : dict of str to ndarray, shape (...)
        The spec's rig inputs :data:`AERO_CHANNELS`: ``aero_heave`` [N] (up positive,
        ``-downforce_n``), ``aero_roll`` [N*m] (zeros) and ``aero_pitch`` [N*m]
        (positive raises the rear), float64, read-only, shaped like the speed.
    downforce_n : ndarray, shape (...)
        Total downforce [N], positive pushes the car down.
    balance : ndarray, shape (...)
        Front axle's share of the downforce, 0 to 1.
    outside_share : float
        Share (0 to 1) of the samples whose speed or ride heights lay outside the model's
        table or map: extrapolated by the square of the speed (``speed_table``) or
        clamped to the map's edges (``ride_height_map``); 0 for ``constant``.
    settings : dict
        What produced the loads: the model's ``name``, ``kind``, ``source``, its
        ``cg_to_front_axle_m`` and ``cg_to_rear_axle_m``, ``n_samples``, and per kind the
        shares that make up `outside_share` (``share_below_table`` and
        ``share_above_table``; ``share_outside_map``).
    """

    channels: dict
    downforce_n: np.ndarray
    balance: np.ndarray
    outside_share: float
    settings: dict


# ----------------------------------------------------------------------------
# the model
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class AeroModel:
    """A downforce and balance model: constant, by speed, or by speed and ride heights.

    Parameters
    ----------
    name : str
        Shown in messages and in the loads' settings (non-empty).
    kind : {"constant", "speed_table", "ride_height_map"}
        The model's form (module docstring).
    cg_to_front_axle_m : float
        ``a`` [m], centre of gravity to front axle, > 0.
    cg_to_rear_axle_m : float
        ``b`` [m], centre of gravity to rear axle, > 0.
    reference_speed_m_s : float, optional
        ``v_ref`` [m/s], > 0, at which `downforce_n` is given (``constant`` and
        ``ride_height_map``; None otherwise).
    speed_grid_m_s : array_like, shape (K,), optional
        The table's speeds [m/s], >= 0, strictly increasing, ``K >= 2``
        (``speed_table``; None otherwise).
    ride_height_front_grid_m, ride_height_rear_grid_m : array_like, shape (F,) and (R,), optional
        The map's absolute front and rear ride heights [m] (as the lasers log them),
        strictly increasing, at least 2 each (``ride_height_map``; None otherwise).
    downforce_n : float or array_like
        Downforce [N], >= 0: a number at `reference_speed_m_s` (``constant``), shape (K,)
        at each table speed (``speed_table``), shape (F, R) at `reference_speed_m_s` on
        the grid, ``[front index, rear index]`` (``ride_height_map``).
    balance : float or array_like
        Front axle's share of the downforce, 0 to 1: a number (``constant``), a number
        or shape (K,) (``speed_table``), a number or shape (F, R) (``ride_height_map``);
        stored with the shape of `downforce_n`.
    source : str, optional
        The file the model was read from.

    Raises
    ------
    AeroModelError
        On an empty name, an unknown kind, non-positive geometry or reference speed, a
        parameter missing for the kind or given for another kind, NaN or infinite values,
        negative downforce, a balance outside [0, 1], a grid that is not strictly
        increasing (or a negative table speed, or downforce at speed 0), or tables of
        the wrong length or shape. The error keeps ``field``, ``problem`` and ``fix``
        for :func:`aero_model_from_dict` to re-word with the file's keys.

    Notes
    -----
    Signs and formulas in the module docstring. Arrays are stored read-only. Two models
    are equal when everything but their `source` is.

    Examples
    --------
    >>> m = AeroModel("wing", "speed_table", 1.2, 1.4, speed_grid_m_s=[20.0, 60.0],
    ...               downforce_n=[500.0, 4500.0], balance=0.44)
    >>> m.loads([10.0, 40.0, 80.0]).downforce_n.round(6).tolist()
    [125.0, 2500.0, 8000.0]
    >>> m.balance.tolist()
    [0.44, 0.44]
    """

    name: str
    kind: str
    cg_to_front_axle_m: float
    cg_to_rear_axle_m: float
    reference_speed_m_s: float | None = None
    speed_grid_m_s: np.ndarray | None = None
    ride_height_front_grid_m: np.ndarray | None = None
    ride_height_rear_grid_m: np.ndarray | None = None
    downforce_n: float | np.ndarray | None = None
    balance: float | np.ndarray | None = None
    source: str | None = field(default=None, kw_only=True)

    def __post_init__(self):
        who = f"aero model {self.name!r}"
        if not isinstance(self.name, str) or not self.name.strip():
            raise _error(who, "name", "must be a non-empty string", "give the model a name "
                         "such as \"high downforce\"")
        if self.kind not in AERO_KINDS:
            raise _error(who, "kind", f"{self.kind!r} is unknown"
                         f"{did_you_mean(str(self.kind), AERO_KINDS)}",
                         f"use one of {list(AERO_KINDS)}")
        for attr in ("cg_to_front_axle_m", "cg_to_rear_axle_m"):
            x = _finite_float(who, attr, getattr(self, attr), "m")
            if x <= 0:
                raise _error(who, attr, f"= {x:g} m is not positive", "give the distance "
                             "from the centre of gravity to the axle, > 0")
            self._set(attr, x)
        needed = {attr for attr, _, _ in _KIND_FIELDS[self.kind].values()}
        for attr in _KIND_ATTRS:
            if attr in needed and getattr(self, attr) is None:
                raise _error(who, attr, f"is missing (kind {self.kind!r} needs it)",
                             f"give it; kind {self.kind!r} needs {sorted(needed)}")
            if attr not in needed and getattr(self, attr) is not None:
                raise _error(who, attr, f"is given but kind {self.kind!r} does not use it",
                             f"leave it out; kind {self.kind!r} has {sorted(needed)}")
        if self.reference_speed_m_s is not None:
            v = _finite_float(who, "reference_speed_m_s", self.reference_speed_m_s, "m/s")
            if v <= 0:
                raise _error(who, "reference_speed_m_s", f"= {v:g} m/s is not positive",
                             "give the speed at which the downforce is given, > 0")
            self._set("reference_speed_m_s", v)
        {"constant": self._check_constant, "speed_table": self._check_speed_table,
         "ride_height_map": self._check_ride_height_map}[self.kind](who)
        if self.source is not None:
            self._set("source", str(self.source))

    def _set(self, attr, value):
        """Set a field of the frozen instance (its checked, SI value)."""
        object.__setattr__(self, attr, value)

    def _check_constant(self, who):
        d = _finite_float(who, "downforce_n", self.downforce_n, "N")
        _check_downforce(who, "downforce_n", d)
        bal = _finite_float(who, "balance", self.balance, "-")
        _check_balance(who, "balance", bal)
        self._set("downforce_n", d)
        self._set("balance", bal)

    def _check_speed_table(self, who):
        v = _increasing_grid(who, "speed_grid_m_s", self.speed_grid_m_s, "m/s")
        if v[0] < 0:
            raise _error(who, "speed_grid_m_s", f"starts at {v[0]:g} m/s, below 0",
                         "give speeds as magnitudes, >= 0")
        d = _finite_array(who, "downforce_n", self.downforce_n, 1, "N")
        if d.size != v.size:
            raise _error(who, "downforce_n", f"has {d.size} values but speed_grid_m_s has "
                         f"{v.size}", "give one downforce per speed")
        _check_downforce(who, "downforce_n", d)
        if v[0] == 0 and d[0] != 0:
            raise _error(who, "downforce_n", f"is {d[0]:g} N at speed 0", "give 0 at speed "
                         "0 (a car at rest has no downforce), or start the table above 0")
        if np.ndim(self.balance) == 0:
            bal = np.full(v.size, _finite_float(who, "balance", self.balance, "-"))
            bal.flags.writeable = False
        else:
            bal = _finite_array(who, "balance", self.balance, 1, "-")
            if bal.size != v.size:
                raise _error(who, "balance", f"has {bal.size} values but speed_grid_m_s "
                             f"has {v.size}", "give one balance per speed, or one number")
        _check_balance(who, "balance", bal)
        self._set("speed_grid_m_s", v)
        self._set("downforce_n", d)
        self._set("balance", bal)

    def _check_ride_height_map(self, who):
        f = _increasing_grid(who, "ride_height_front_grid_m", self.ride_height_front_grid_m,
                             "m")
        r = _increasing_grid(who, "ride_height_rear_grid_m", self.ride_height_rear_grid_m, "m")
        d = _finite_array(who, "downforce_n", self.downforce_n, 2, "N")
        if d.shape != (f.size, r.size):
            raise _error(who, "downforce_n", f"has shape {d.shape[0]} x {d.shape[1]} but the "
                         f"grid is {f.size} front x {r.size} rear ride heights",
                         "give one row per front ride height, each with one value per rear "
                         "ride height")
        _check_downforce(who, "downforce_n", d)
        if np.ndim(self.balance) == 0:
            bal = np.full(d.shape, _finite_float(who, "balance", self.balance, "-"))
            bal.flags.writeable = False
        else:
            bal = _finite_array(who, "balance", self.balance, 2, "-")
            if bal.shape != d.shape:
                raise _error(who, "balance", f"has shape {bal.shape[0]} x {bal.shape[1]} "
                             f"but the grid is {f.size} front x {r.size} rear ride heights",
                             "give one row per front ride height, each with one value per "
                             "rear ride height, or one number")
        _check_balance(who, "balance", bal)
        self._set("ride_height_front_grid_m", f)
        self._set("ride_height_rear_grid_m", r)
        self._set("downforce_n", d)
        self._set("balance", bal)

    def _compared(self):
        return [getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "source"]

    def __eq__(self, other):
        if not isinstance(other, AeroModel):
            return NotImplemented
        return all(x is y if x is None or y is None else np.array_equal(x, y)
                   for x, y in zip(self._compared(), other._compared()))

    def __hash__(self):
        return hash((self.name, self.kind, self.cg_to_front_axle_m, self.cg_to_rear_axle_m))

    @property
    def needs_ride_heights(self):
        """bool: Whether :meth:`loads` needs the ride heights (kind ``ride_height_map``)."""
        return self.kind == "ride_height_map"

    @property
    def static_balance(self):
        """float: ``b / (a + b)``, the balance at which the pitch moment is 0."""
        a, b = self.cg_to_front_axle_m, self.cg_to_rear_axle_m
        return b / (a + b)

    def loads(self, speed_m_s, *, ride_height_front_m=None, ride_height_rear_m=None):
        """The aero loads at each sample of a speed trace.

        Parameters
        ----------
        speed_m_s : float or array_like, shape (...)
            The car's speed [m/s], a magnitude (>= 0, finite), e.g. one value per sample
            of a track log.
        ride_height_front_m, ride_height_rear_m : float or array_like, shape (...), optional
            The front and rear ride heights [m] at each sample, absolute as the map's grid
            (the means of the logged ``ride_height_LF/RF`` and ``ride_height_LR/RR``),
            broadcastable to the speed's shape. Required by a ``ride_height_map``
            (:attr:`needs_ride_heights`), ignored by the other kinds.

        Returns
        -------
        AeroLoads
            ``aero_heave``, ``aero_roll`` and ``aero_pitch`` shaped like `speed_m_s`, with
            the downforce, the balance and the share of samples outside the table or map.

        Raises
        ------
        AeroModelError
            If a speed is negative, NaN or infinite; for a ``ride_height_map``, if the
            ride heights are missing, NaN or infinite, or do not broadcast to the speed's
            shape.
        TypeError
            If the speeds or ride heights are not numbers.

        Examples
        --------
        >>> m = AeroModel("wing", "ride_height_map", 1.2, 1.4, reference_speed_m_s=50.0,
        ...               ride_height_front_grid_m=[0.03, 0.05],
        ...               ride_height_rear_grid_m=[0.06, 0.08],
        ...               downforce_n=[[4400.0, 4200.0], [4000.0, 3600.0]], balance=0.45)
        >>> got = m.loads([50.0, 25.0, 50.0], ride_height_front_m=[0.04, 0.04, 0.02],
        ...               ride_height_rear_m=0.07)
        >>> got.downforce_n.round(6).tolist(), round(got.outside_share, 6)
        ([4050.0, 1012.5, 4300.0], 0.333333)
        """
        who = f"aero model {self.name!r}"
        v = _samples(who, "speed_m_s", speed_m_s, "m/s")
        bad, first = _where_bad(v < 0)
        if bad:
            raise AeroModelError(f"{who}: speed_m_s has {bad} negative value(s) (first "
                                 f"{float(v.flat[first]):g} m/s at sample {first}); give the "
                                 "speed as a magnitude (its absolute value), >= 0")
        settings = {"name": self.name, "kind": self.kind, "source": self.source,
                    "cg_to_front_axle_m": self.cg_to_front_axle_m,
                    "cg_to_rear_axle_m": self.cg_to_rear_axle_m, "n_samples": int(v.size)}
        if self.kind == "constant":
            d = np.array(self.downforce_n * (v / self.reference_speed_m_s) ** 2, dtype=float)
            bal = np.full(v.shape, self.balance)
            outside = 0.0
        elif self.kind == "speed_table":
            d, bal, below, above = self._table(v)
            settings["share_below_table"] = _share(below)
            settings["share_above_table"] = _share(above)
            outside = _share(below | above)
        else:
            d, bal, off = self._map(who, v, ride_height_front_m, ride_height_rear_m)
            settings["share_outside_map"] = outside = _share(off)
        a, b = self.cg_to_front_axle_m, self.cg_to_rear_axle_m
        front = bal * d
        rear = d - front
        channels = {"aero_heave": np.array(-d, dtype=float), "aero_roll": np.zeros(v.shape),
                    "aero_pitch": np.array(a * front - b * rear, dtype=float)}
        for arr in (d, bal, *channels.values()):
            arr.flags.writeable = False
        logger.debug("%s: %d sample(s), %.3g outside the %s", who, v.size, outside, self.kind)
        return AeroLoads(channels=channels, downforce_n=d, balance=bal,
                         outside_share=outside, settings=settings)

    def _table(self, v):
        """Downforce, balance and the below / above masks of a speed table."""
        s, dt, bt = self.speed_grid_m_s, self.downforce_n, self.balance
        below, above = v < s[0], v > s[-1]
        vc = np.clip(v, s[0], s[-1])
        # off the table: the end point scaled by the square of the speed (vc is s[-1] > 0
        # above the table, s[0] > 0 below it, since speeds are >= 0)
        ratio = np.divide(v, vc, out=np.ones(v.shape), where=vc > 0)
        scale = np.where(below | above, ratio**2, 1.0)
        return (np.array(np.interp(vc, s, dt) * scale, dtype=float),
                np.array(np.interp(vc, s, bt), dtype=float), below, above)

    def _map(self, who, v, ride_height_front_m, ride_height_rear_m):
        """Downforce, balance and the outside mask of a ride-height map."""
        if ride_height_front_m is None or ride_height_rear_m is None:
            missing = [n for n, x in (("ride_height_front_m", ride_height_front_m),
                                      ("ride_height_rear_m", ride_height_rear_m)) if x is None]
            raise AeroModelError(f"{who} (kind 'ride_height_map') needs {' and '.join(missing)}"
                                 "; pass the front and rear ride heights [m] of each sample "
                                 "(the means of the logged ride_height_LF/RF and "
                                 "ride_height_LR/RR), or use a model of kind 'constant' or "
                                 "'speed_table'")
        f, r = self.ride_height_front_grid_m, self.ride_height_rear_grid_m
        heights = []
        for name, x in (("ride_height_front_m", ride_height_front_m),
                        ("ride_height_rear_m", ride_height_rear_m)):
            h = _samples(who, name, x, "m")
            try:
                heights.append(np.broadcast_to(h, v.shape))
            except ValueError:
                raise AeroModelError(f"{who}: {name} has shape {h.shape} but the speed has "
                                     f"{v.shape}; give one ride height per speed sample (or "
                                     "one number)") from None
        hf, hr = heights
        off = (hf < f[0]) | (hf > f[-1]) | (hr < r[0]) | (hr > r[-1])
        points = np.column_stack([np.clip(hf, f[0], f[-1]).ravel(),
                                  np.clip(hr, r[0], r[-1]).ravel()])
        table = RegularGridInterpolator((f, r), np.stack([self.downforce_n, self.balance], -1),
                                        method="linear")
        at = table(points).reshape(*v.shape, 2)
        d = np.array(at[..., 0] * (v / self.reference_speed_m_s) ** 2, dtype=float)
        return d, np.array(at[..., 1], dtype=float), off

    def to_dict(self, units="SI"):
        """The model as a TOML document, values in `units`: what :func:`write_aero_model`
        writes and :func:`aero_model_from_dict` reads.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Unit system of the values (imperial: in, in/s, lbf).

        Returns
        -------
        dict
            ``format``, ``units``, ``name``, ``kind``, the geometry and the kind's keys
            (a speed table's balance as one number when it is the same at every speed).

        Raises
        ------
        AeroModelError
            If `units` is unknown.
        """
        units = check_units(units, where="aero model units", error=AeroModelError)
        doc = {"format": AERO_FORMAT, "units": units, "name": self.name, "kind": self.kind}
        for key, (attr, quantity) in _GEOMETRY.items():
            doc[key] = float(from_si(getattr(self, attr), quantity, units))
        for key, (attr, quantity, _) in _KIND_FIELDS[self.kind].items():
            value = getattr(self, attr)
            if attr == "balance" and np.ndim(value) and np.all(value == np.ravel(value)[0]):
                value = float(np.ravel(value)[0])
            value = from_si(value, quantity, units)
            doc[key] = np.asarray(value, dtype=float).tolist()
        return doc


def _samples(who, name, value, unit):
    """`value` as a float64 array without NaN or infinity, or raise."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"{who}: {name} must be numbers [{unit}], got "
                        f"{type(value).__name__}") from None
    bad, first = _where_bad(~np.isfinite(arr))
    if bad:
        raise AeroModelError(f"{who}: {name} has {bad} NaN or infinite value(s) (first at "
                             f"sample {first}); fill or cut the log there before building "
                             "the loads")
    return arr


def _share(mask):
    """The share of true entries of `mask` (0 for no samples)."""
    return float(np.mean(mask)) if np.size(mask) else 0.0


# ----------------------------------------------------------------------------
# the file
# ----------------------------------------------------------------------------


def _toml_value(where, key, value, shape):
    """A TOML value of `shape` ("scalar", "vector", "matrix", or one of two with "|"),
    checked for type only (values are checked by :class:`AeroModel`)."""
    shapes = shape.split("|")
    if "scalar" in shapes and is_real_number(value):
        return float(value)
    if "vector" in shapes and isinstance(value, list) and all(map(is_real_number, value)):
        return np.array(value, dtype=float)
    if "matrix" in shapes and isinstance(value, list) and value and all(
            isinstance(row, list) and all(map(is_real_number, row)) for row in value):
        lengths = [len(row) for row in value]
        if len(set(lengths)) > 1:
            j = next(i for i, n in enumerate(lengths) if n != lengths[0])
            raise AeroModelError(f"{where}: key {key!r} is a map of the wrong shape: row 0 "
                                 f"has {lengths[0]} values but row {j} has {lengths[j]}; "
                                 "give one row per front ride height, each with one value "
                                 "per rear ride height")
        return np.array(value, dtype=float)
    want = {"scalar": "a number", "vector": "an array of numbers [v1, v2, ...]",
            "matrix": "a 2-D array [[...], [...]], one row per front ride height"}
    quoted = isinstance(value, str) or (isinstance(value, list) and any(
        isinstance(x, str) or (isinstance(x, list) and any(isinstance(y, str) for y in x))
        for x in value))
    fix = ("write numbers without quotes" if quoted else
           f"write it as {' or '.join(want[s] for s in shapes)}")
    raise AeroModelError(f"{where}: key {key!r} must be {' or '.join(want[s] for s in shapes)}"
                         f", got {value!r}; {fix}")


def aero_model_from_dict(doc, *, where="aero model", units="SI"):
    """Build an :class:`AeroModel` from a parsed aero TOML document.

    Parameters
    ----------
    doc : mapping
        The document (format in the module docstring and :func:`read_aero_model`).
    where : str
        How to name the document in messages (the file); when the document has no
        ``name``, the model is named by the file's name without ``.toml`` if `where`
        ends in ``.toml``, else ``"aero"``.
    units : {"SI", "imperial"}
        Unit system of a document without its own ``units`` key (e.g. that of an
        enclosing file); a ``units`` key in `doc` wins.

    Returns
    -------
    AeroModel
        In SI, ``source`` None.

    Raises
    ------
    AeroModelError
        In one sentence naming `where`, the key and the fix: a missing or wrong
        ``format``, an unknown key (with the nearest valid one), a key of another kind, an
        unknown unit system or kind, a missing required key, a value of the wrong type, or
        a value :class:`AeroModel` refuses (non-positive geometry or reference speed,
        balance outside [0, 1], tables of unequal length, a grid not strictly increasing,
        a map of the wrong shape, NaN or infinity, negative downforce).
    TypeError
        If `doc` is not a mapping.

    Examples
    --------
    >>> m = aero_model_from_dict({"format": "shockplan-aero/1", "units": "imperial",
    ...     "kind": "constant", "cg_to_front_axle": 48.0, "cg_to_rear_axle": 54.0,
    ...     "reference_speed": 2000.0, "downforce": 900.0, "balance": 0.5}, where="wing.toml")
    >>> m.name, round(m.cg_to_front_axle_m, 4), round(m.downforce_n, 1)
    ('wing', 1.2192, 4003.4)
    """
    if not isinstance(doc, Mapping):
        raise TypeError(f"{where}: an aero model is a mapping (a parsed TOML document), got "
                        f"{type(doc).__name__}")
    fmt = doc.get("format")
    if fmt != AERO_FORMAT:
        got = "key 'format' is missing" if fmt is None else f"key 'format' is {fmt!r}"
        raise AeroModelError(f"{where}: {got}; an aero model starts with format = "
                             f"\"{AERO_FORMAT}\"")
    for key in doc:  # a typo never falls back to a default
        if key not in _TOP_KEYS:
            raise AeroModelError(f"{where}: unknown key {key!r}{did_you_mean(key, _TOP_KEYS)}"
                                 f"; the keys are {', '.join(_TOP_KEYS)}")
    units = check_units(doc.get("units", units), where=f"{where}: key 'units'",
                        error=AeroModelError)
    kind = doc.get("kind")
    if kind is None:
        raise AeroModelError(f"{where}: key 'kind' is missing; give kind = one of "
                             f"{', '.join(repr(k) for k in AERO_KINDS)}")
    if kind not in AERO_KINDS:
        raise AeroModelError(f"{where}: key 'kind' is {kind!r}, unknown"
                             f"{did_you_mean(kind, AERO_KINDS)}; give one of "
                             f"{', '.join(repr(k) for k in AERO_KINDS)}")
    fields_ = _KIND_FIELDS[kind]
    for key in doc:
        if key not in (*_HEAD_KEYS, *_GEOMETRY, *fields_):
            raise AeroModelError(f"{where}: key {key!r} does not belong to kind {kind!r}; "
                                 f"remove it (kind {kind!r} has {', '.join(fields_)}), or "
                                 "change the kind")
    for key in (*_GEOMETRY, *fields_):
        if key not in doc:
            quantity = _GEOMETRY[key][1] if key in _GEOMETRY else fields_[key][1]
            unit = UNIT_LABELS[units][quantity]
            raise AeroModelError(f"{where}: key {key!r} is missing; kind {kind!r} needs "
                                 f"{', '.join((*_GEOMETRY, *fields_))}"
                                 + ("" if unit == "-" else f" (file units: {key} in {unit})"))
    name = doc.get("name", Path(where).stem if str(where).lower().endswith(".toml") else "aero")
    if not isinstance(name, str) or not name.strip():
        raise AeroModelError(f"{where}: key 'name' must be a non-empty string, got {name!r}; "
                             "write it in quotes")
    kwargs = {}
    for key, (attr, quantity) in _GEOMETRY.items():
        kwargs[attr] = to_si(_toml_value(where, key, doc[key], "scalar"), quantity, units)
    for key, (attr, quantity, shape) in fields_.items():
        kwargs[attr] = to_si(_toml_value(where, key, doc[key], shape), quantity, units)
    try:
        return AeroModel(name, kind, **kwargs)
    except AeroModelError as exc:
        base, _, sub = exc.field.partition("[")
        key = _ATTR_KEYS.get(base, base) + (f"[{sub}" if sub else "")
        problem = exc.problem
        for attr, file_key in _ATTR_KEYS.items():  # attribute names in the problem, too
            problem = problem.replace(attr, file_key)
        file_key = _ATTR_KEYS.get(base, base)
        spec = _GEOMETRY.get(file_key) or fields_.get(file_key)
        unit = None if spec is None else UNIT_LABELS[units][spec[1]]
        if units != "SI" and unit not in (None, "-"):  # checked in SI: show the file's number
            raw = doc.get(file_key)
            shown = (f"{file_key} = {raw!r} {unit}" if isinstance(raw, (int, float))
                     else f"{file_key} in {unit}")
            problem += f" (checked in SI; the file has {shown})"
        raise AeroModelError(f"{where}: key {key!r} {problem}; {exc.fix}") from None


def read_aero_model(path):
    """Read an aero model file (``format = "shockplan-aero/1"``) into SI.

    Parameters
    ----------
    path : str or path
        The TOML file: ``format``, ``units`` ("SI", the default, or "imperial": lengths in
        in, speeds in in/s, forces in lbf), an optional ``name``, ``kind``,
        ``cg_to_front_axle``, ``cg_to_rear_axle`` and the kind's keys (module docstring).

    Returns
    -------
    AeroModel
        Named by ``name``, or the file's name without ``.toml``; ``source`` the path.

    Raises
    ------
    AeroModelError
        If the file is missing or not TOML, or any refusal of
        :func:`aero_model_from_dict`; the message names the file and the key.
    """
    path = Path(path)
    doc = read_toml(path, error=AeroModelError, what="aero model")
    model = aero_model_from_dict(doc, where=str(path))
    logger.debug("read aero model %r (%s) from %s", model.name, model.kind, path)
    return dataclasses.replace(model, source=str(path))


def write_aero_model(model, path, *, units="SI", overwrite=False):
    """Write an aero model file, atomically.

    Parameters
    ----------
    model : AeroModel
        The model.
    path : str or path
        Output file.
    units : {"SI", "imperial"}
        Unit system of the file (SI -> imperial -> SI is exact to round-off; an SI file
        reads back equal).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    AeroModelError
        If `units` is unknown.
    TypeError
        If `model` is not an :class:`AeroModel`.
    FileExistsError
        If `path` exists and `overwrite` is false.
    """
    if not isinstance(model, AeroModel):
        raise TypeError(f"write_aero_model: model must be an AeroModel, got "
                        f"{type(model).__name__}")
    units = check_units(units, where="write_aero_model: units", error=AeroModelError)
    path = Path(path)
    atomic_write_toml(path, model.to_dict(units), overwrite=overwrite,
                      header=f"Aero model ({AERO_FORMAT}), written by shockplan.")
    logger.info("wrote aero model %r to %s (%s)", model.name, path, units)
    return path
