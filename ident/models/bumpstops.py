"""Bump stops, packers and the bump-stop library file, ``bumpstops.toml``.

A bump stop is an elastic element in parallel with the shock at a corner (the rig-session
spec, "The real car: bump stops, packers and static loads"): no force until the shock
travel in compression passes its gap, then a force that rises with the travel beyond
contact, given as a table. A packer is a spacer that shortens the gap.

:class:`BumpStop` holds one stop in SI and evaluates its force and stiffness;
:class:`BumpStopLibrary` maps ids to stops (as :class:`ident.models.library.ShockLibrary`
maps ids to shocks); :func:`read_bump_stops` and :func:`write_bump_stops` read and write
``bumpstops.toml``; :func:`check_packer` checks a packer against a stop's gap and
:func:`parse_bump_stop_id` reads a corner's bump stop as written in a file (an id, or
``"none"``).

File format::

    units = "SI"                          # or "imperial": gap and travel in in, force in lbf

    [[bump_stop]]
    id = "BS-F"
    gap = 0.015                           # m: shock travel from the car at rest to contact
    travel = [0.0, 0.005, 0.010, 0.020]   # m beyond contact, strictly increasing, from 0
    force = [0.0, 400.0, 1500.0, 6000.0]  # N at each travel, from 0, non-decreasing
    description = "front, progressive"    # optional

Notes
-----
Signs as in the spec: shock travel and force are positive in compression. Travel is
counted from the car at rest: with a packer of thickness ``p`` the stop touches when the
travel passes ``gap - p``; beyond the table the force is extended with the last segment's
slope.

Examples
--------
>>> bs = BumpStop("BS-F", 0.015, [0.0, 0.005, 0.010, 0.020], [0.0, 400.0, 1500.0, 6000.0])
>>> bs.force([0.010, 0.020, 0.030]).round(6).tolist()  # before contact, 5 and 15 mm in
[0.0, 400.0, 3750.0]
>>> round(bs.force(0.020, packer_m=0.005), 6)    # a 5 mm packer: 10 mm beyond contact
1500.0
>>> round(bs.stiffness(0.027))                    # the segment from 10 to 20 mm
450000
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident.data.channels import CORNERS
from ident.data.files import atomic_write_toml, did_you_mean, read_toml
from ident.data.units import UNIT_LABELS, check_units, from_si, to_si
from ident.errors import BumpStopError
from ident.models.shocks import is_real_number

__all__ = [
    "NO_BUMP_STOP",
    "PACKER_GAP_ATOL_M",
    "BumpStop",
    "BumpStopLibrary",
    "CarElements",
    "check_packer",
    "contact_tables",
    "parse_bump_stop_id",
    "read_bump_stops",
    "resolve_corner_stops",
    "write_bump_stops",
]

logger = logging.getLogger(__name__)

#: How a file says that a corner has no bump stop (any case); never a bump stop's id.
NO_BUMP_STOP = "none"
#: A packer may exceed the gap by this much [m] and still count as "not thicker": 5 um is
#: nothing to a stop (shims come in 0.001 in or 0.05 mm steps), and covers a gap and a
#: packer written in different unit systems to 4 decimals (15 mm is 0.5906 in, 1.2 um more).
PACKER_GAP_ATOL_M = 5e-6

_TOP_KEYS = ("units", "bump_stop")
#: TOML key -> (attribute, quantity, shape) of a ``[[bump_stop]]`` table.
_TOML_FIELDS = {"gap": ("gap_m", "displacement", "scalar"),
                "travel": ("travel_m", "displacement", "vector"),
                "force": ("force_n", "force", "vector")}
_TABLE_KEYS = ("id", *_TOML_FIELDS, "description")


def _mm_in(x_m):
    """``"4 mm (0.157 in)"``: a length as both unit systems' users read it."""
    return f"{x_m * 1e3:.4g} mm ({x_m / 0.0254:.4g} in)"


def _stop_error(who, field_name, problem, fix):
    """A :class:`BumpStopError` about one field, its parts kept for re-wording with the
    file's keys (as :mod:`ident.models.shocks` does for shocks)."""
    exc = BumpStopError(f"{who}: {field_name} {problem}; {fix}")
    exc.field, exc.problem, exc.fix = field_name, problem, fix
    return exc


def _vector(who, name, values):
    """`values` as a read-only finite 1-D float64 array of >= 2 points, or raise."""
    if isinstance(values, (str, bytes)) or not np.iterable(values):
        raise _stop_error(who, name, f"must be a list of numbers, got {type(values).__name__}",
                          "give a list of finite numbers")
    values = list(values)
    for j, x in enumerate(values):
        if not is_real_number(x):
            raise _stop_error(who, f"{name}[{j}]", f"must be a number, got {type(x).__name__} "
                              f"{x!r}", "give finite real numbers (no quotes)")
    arr = np.array(values, dtype=float)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise _stop_error(who, f"{name}[{bad[0]}]", f"is {arr[bad[0]]}, not finite",
                          "give finite numbers")
    if arr.size < 2:
        raise _stop_error(who, name, f"has {arr.size} point(s)", "give at least 2 points "
                          "(contact at 0 and one more)")
    arr.flags.writeable = False
    return arr


# ----------------------------------------------------------------------------
# BumpStop
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class BumpStop:
    """One bump stop: its gap and its force-travel table (SI).

    Parameters
    ----------
    id : str
        Bump-stop id (non-empty, no surrounding spaces, not ``"none"``).
    gap_m : float
        Shock travel [m] from the car at rest to contact, >= 0.
    travel_m : array_like, shape (K,)
        Compression beyond contact [m], from 0, strictly increasing, ``K >= 2``.
    force_n : array_like, shape (K,)
        Force [N] at each travel, from 0, non-decreasing (compression positive).
    description : str, keyword-only
        Free text.

    Raises
    ------
    BumpStopError
        On a bad id, a negative or non-finite gap, a table with NaN or infinite values,
        fewer than 2 points or a length mismatch, travel not starting at 0 or not strictly
        increasing, or force not starting at 0 or falling with travel. The error keeps
        ``field``, ``problem`` and ``fix`` for :func:`read_bump_stops` to re-word.

    Notes
    -----
    Beyond the table the force is extended with the last segment's slope (a stop that
    bottoms out stiffens without limit, which is what the table's end says). The arrays
    are stored read-only. Two stops are equal when their id, gap, table and description
    are.
    """

    id: str
    gap_m: float
    travel_m: np.ndarray
    force_n: np.ndarray
    description: str = field(default="", kw_only=True)

    def __post_init__(self):
        who = f"bump stop {self.id!r}"
        if not isinstance(self.id, str) or not self.id.strip() or self.id != self.id.strip():
            raise _stop_error(who, "id", "must be a non-empty string without surrounding "
                              "spaces", "give the bump stop a name such as \"BS-F\"")
        if self.id.lower() == NO_BUMP_STOP:
            raise _stop_error(who, "id", f"is {self.id!r}, the word that means no bump stop",
                              "give the bump stop another id")
        if not is_real_number(self.gap_m) or not math.isfinite(float(self.gap_m)):
            raise _stop_error(who, "gap_m", f"must be a finite number, got {self.gap_m!r}",
                              "give the travel from the car at rest to contact")
        gap = float(self.gap_m)
        if gap < 0:
            raise _stop_error(who, "gap_m", f"= {gap:g} m is negative (the stop would push "
                              "on the car at rest)", "give a gap >= 0 (0 = touching at rest); "
                              "measure it from the car at rest to contact")
        t = _vector(who, "travel_m", self.travel_m)
        f = _vector(who, "force_n", self.force_n)
        if t.size != f.size:
            raise _stop_error(who, "force_n", f"has {f.size} values but travel_m has {t.size}",
                              "give one force per travel")
        if t[0] != 0.0:
            raise _stop_error(who, "travel_m", f"starts at {t[0]:g} m, not 0",
                              "count the travel from contact (first point 0); put the "
                              "distance to contact in the gap")
        dt = np.diff(t)
        if np.any(dt <= 0):
            j = int(np.flatnonzero(dt <= 0)[0])
            raise _stop_error(who, "travel_m", f"is not strictly increasing at index {j + 1} "
                              f"({t[j]:g} then {t[j + 1]:g} m)",
                              "sort the points and remove repeated travels")
        if f[0] != 0.0:
            raise _stop_error(who, "force_n", f"starts at {f[0]:g} N, not 0 (a stop has no "
                              "force at contact)", "give 0 at travel 0; if the stop touches "
                              "preloaded, make the gap smaller")
        df = np.diff(f)
        if np.any(df < 0):
            j = int(np.flatnonzero(df < 0)[0])
            raise _stop_error(who, "force_n", f"falls with travel at index {j + 1} "
                              f"({f[j]:g} N at {t[j]:g} m, then {f[j + 1]:g} N at "
                              f"{t[j + 1]:g} m)", "a bump stop's force never falls as it is "
                              "compressed: check the table's order and signs (compression "
                              "positive)")
        if not isinstance(self.description, str):
            raise _stop_error(who, "description", f"must be a string, got "
                              f"{type(self.description).__name__}", "write it in quotes")
        object.__setattr__(self, "gap_m", gap)
        object.__setattr__(self, "travel_m", t)
        object.__setattr__(self, "force_n", f)

    def __eq__(self, other):
        if not isinstance(other, BumpStop):
            return NotImplemented
        return (self.id == other.id and self.gap_m == other.gap_m
                and self.description == other.description
                and np.array_equal(self.travel_m, other.travel_m)
                and np.array_equal(self.force_n, other.force_n))

    def __hash__(self):
        return hash((self.id, self.gap_m, self.travel_m.tobytes(), self.force_n.tobytes()))

    def __repr__(self):
        desc = f", description={self.description!r}" if self.description else ""
        return (f"BumpStop(id={self.id!r}, gap_m={self.gap_m!r}, "
                f"travel_m={self.travel_m.tolist()}, force_n={self.force_n.tolist()}{desc})")

    @property
    def end_slope_n_m(self):
        """float: The last segment's slope [N/m], which extends the table beyond its end."""
        t, f = self.travel_m, self.force_n
        return float((f[-1] - f[-2]) / (t[-1] - t[-2]))

    def contact_travel_m(self, packer_m=0.0):
        """The shock travel [m] from the car at rest at which the stop touches.

        Parameters
        ----------
        packer_m : float
            Packer thickness [m] (checked with :func:`check_packer`).

        Returns
        -------
        float
            ``gap_m - packer_m`` (>= 0).
        """
        return max(self.gap_m - check_packer(self, packer_m, f"bump stop {self.id!r}"), 0.0)

    def _beyond_contact(self, shock_travel_m, packer_m):
        x = np.asarray(shock_travel_m, dtype=float)
        return x - self.contact_travel_m(packer_m)

    def force(self, shock_travel_m, packer_m=0.0):
        """The stop's force for a shock travel.

        Parameters
        ----------
        shock_travel_m : float or array_like, shape (...)
            Shock travel [m] from the car at rest, compression positive.
        packer_m : float
            Packer thickness [m], ``0 <= packer_m <= gap_m``.

        Returns
        -------
        float or ndarray, shape (...)
            Force [N], compression positive: 0 until the travel passes
            ``gap_m - packer_m``, then the table at the travel beyond contact (extended
            with its last slope). NaN travel gives NaN force.

        Raises
        ------
        BumpStopError
            If the packer is negative, not finite or thicker than the gap.
        """
        x = self._beyond_contact(shock_travel_m, packer_m)
        t, f = self.travel_m, self.force_n
        xc = np.maximum(x, 0.0)
        out = np.where(xc > t[-1], f[-1] + self.end_slope_n_m * (xc - t[-1]),
                       np.interp(xc, t, f))
        out = np.where(x > 0, out, np.where(np.isnan(x), np.nan, 0.0))
        return float(out) if out.ndim == 0 else out

    def stiffness(self, shock_travel_m, packer_m=0.0):
        """The stop's stiffness dF/dx for a shock travel.

        Parameters
        ----------
        shock_travel_m : float or array_like, shape (...)
            Shock travel [m] from the car at rest, compression positive.
        packer_m : float
            Packer thickness [m], ``0 <= packer_m <= gap_m``.

        Returns
        -------
        float or ndarray, shape (...)
            Stiffness [N/m]: 0 up to contact (at contact too), then the slope of the
            table's segment holding the travel (at a knot, the segment beyond it), the
            last slope beyond the table. NaN travel gives NaN.

        Raises
        ------
        BumpStopError
            If the packer is negative, not finite or thicker than the gap.
        """
        x = self._beyond_contact(shock_travel_m, packer_m)
        t, f = self.travel_m, self.force_n
        slopes = np.diff(f) / np.diff(t)
        seg = np.clip(np.searchsorted(t, np.maximum(x, 0.0), side="right") - 1, 0, t.size - 2)
        out = np.where(x > 0, slopes[seg], np.where(np.isnan(x), np.nan, 0.0))
        return float(out) if out.ndim == 0 else out

    def to_toml_dict(self, units="SI"):
        """The ``[[bump_stop]]`` table of this stop, values in `units`.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Unit system of the values (imperial: in and lbf).

        Returns
        -------
        dict
            Keys ``id``, ``gap``, ``travel``, ``force`` and ``description`` if any.
        """
        units = check_units(units, where="bump stop units", error=BumpStopError)
        out = {"id": self.id}
        for key, (attr, quantity, shape) in _TOML_FIELDS.items():
            value = from_si(getattr(self, attr), quantity, units)
            out[key] = [float(v) for v in value] if shape == "vector" else float(value)
        if self.description:
            out["description"] = self.description
        return out


def check_packer(stop, packer_m, where, *, error=BumpStopError):
    """Return a packer's thickness [m] if it fits the stop's gap, else raise.

    Parameters
    ----------
    stop : BumpStop
        The stop the packer shortens.
    packer_m : float
        Thickness [m].
    where : str
        Who asks (a file, run, setup and corner), put first in the message.
    error : type
        The ``ValueError`` subclass to raise (the caller's family, e.g. ``SessionError``).

    Returns
    -------
    float
        The thickness [m], >= 0.

    Raises
    ------
    error
        If the thickness is not a finite number, is negative, or is thicker than the gap
        (by more than :data:`PACKER_GAP_ATOL_M`): the stop would press on the car at rest.

    Examples
    --------
    >>> bs = BumpStop("BS-F", 0.015, [0.0, 0.01], [0.0, 1000.0])
    >>> check_packer(bs, 0.003, "run 'baseline' LF")
    0.003
    >>> check_packer(bs, 0.02, "run 'baseline' LF")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ident.errors.BumpStopError: run 'baseline' LF: packer 20 mm (0.7874 in) is thicker than ...
    """
    if not is_real_number(packer_m) or not math.isfinite(float(packer_m)):
        raise error(f"{where}: packer {packer_m!r} is not a finite number; give the "
                    "packer's thickness (0 = none)")
    p = float(packer_m)
    if p < 0:
        raise error(f"{where}: packer {_mm_in(p)} is negative; a packer is a spacer, its "
                    "thickness is >= 0 (0 = none)")
    if p > stop.gap_m + PACKER_GAP_ATOL_M:
        raise error(f"{where}: packer {_mm_in(p)} is thicker than the gap of bump stop "
                    f"{stop.id!r}, {_mm_in(stop.gap_m)}: the stop would press on the car at "
                    f"rest; use a packer of at most {_mm_in(stop.gap_m)}, or a bump stop "
                    "with a larger gap")
    return p


def parse_bump_stop_id(value, where, *, error=BumpStopError):
    """A corner's bump stop as a file gives it: an id, or None for ``"none"`` (any case).

    Parameters
    ----------
    value : str
        The file's value.
    where : str
        The file, run or row and the key or column, put first in the message.
    error : type
        The ``ValueError`` subclass to raise.

    Returns
    -------
    str or None
        The id (stripped), or None for no bump stop.

    Raises
    ------
    error
        If `value` is not a non-empty string.

    Examples
    --------
    >>> parse_bump_stop_id("None", "LF"), parse_bump_stop_id("BS-F", "LF")
    (None, 'BS-F')
    """
    if not isinstance(value, str) or not value.strip():
        raise error(f"{where}: bump stop {value!r} is not an id; give a bump stop's id in "
                    f"quotes, or \"{NO_BUMP_STOP}\"")
    value = value.strip()
    return None if value.lower() == NO_BUMP_STOP else value


def resolve_corner_stops(library, stops=None, packers_m=None, *, baseline_stops=None,
                         baseline_packers_m=None, where="", error=BumpStopError):
    """The bump stop and packer at each corner: as given, else the baseline's.

    A setup (:class:`planner.setups.Setup`) gives the bump stops and packers of the
    corners it changes; the others keep those of the model's baseline run
    (:attr:`ident.data.session.Run.bump_stops` and ``packers_m``).

    Parameters
    ----------
    library : BumpStopLibrary or None
        The bump stops; None when there are none (then no corner may name one).
    stops : mapping of str to (str or None), optional
        Corner -> bump-stop id, or None for no bump stop, for the corners given.
    packers_m : mapping of str to float, optional
        Corner -> packer thickness [m] for the corners given.
    baseline_stops : mapping of str to (str or None), optional
        Corner -> bump-stop id or None of the baseline (default: none anywhere).
    baseline_packers_m : mapping of str to float, optional
        Corner -> packer [m] of the baseline (default 0).
    where : str
        Who asks (e.g. ``"setup 'soft'"``), put first in messages.
    error : type
        The ``ValueError`` subclass to raise (the caller's family).

    Returns
    -------
    stops : tuple of (BumpStop or None), shape (4,)
        The stops for ``LF, RF, LR, RR`` (None: no bump stop).
    packers_m : ndarray, shape (4,)
        Packer thicknesses [m], 0 where there is no stop (a packer without a stop does
        nothing).

    Raises
    ------
    error
        If an id is not in the library (or there is no library), or a packer is negative
        or thicker than its stop's gap; the message names the corner and whether the
        value is the given one or the baseline's.

    Examples
    --------
    >>> lib = BumpStopLibrary([BumpStop("BS-F", 0.015, [0.0, 0.01], [0.0, 1000.0])])
    >>> got, packers = resolve_corner_stops(lib, {"LF": None}, {"RF": 0.002},
    ...     baseline_stops={"LF": "BS-F", "RF": "BS-F"}, baseline_packers_m={"LF": 0.001})
    >>> [None if s is None else s.id for s in got], packers.tolist()
    ([None, 'BS-F', None, None], [0.0, 0.002, 0.0, 0.0])
    """
    stops, packers_m = stops or {}, packers_m or {}
    out, packers = [], np.zeros(len(CORNERS))
    prefix = f"{where}: " if where else ""
    for k, c in enumerate(CORNERS):
        own = c in stops
        sid = stops[c] if own else (baseline_stops or {}).get(c)
        if sid is None:
            out.append(None)
            continue
        label = f"{prefix}corner {c} ({'given' if own else 'baseline'} bump stop)"
        if library is None:
            raise error(f"{label}: bump stop {sid!r} but no bump-stop library was given; "
                        "pass one (--bump-stops FILE)")
        if sid not in library:
            raise library.unknown_id_error(sid, where=label, error=error)
        own = c in packers_m
        p = packers_m[c] if own else (baseline_packers_m or {}).get(c, 0.0)
        label = f"{prefix}corner {c} ({'given' if own else 'baseline'} packer)"
        packers[k] = check_packer(library[sid], p, label, error=error)
        out.append(library[sid])
    return tuple(out), packers


# ----------------------------------------------------------------------------
# BumpStopLibrary
# ----------------------------------------------------------------------------


class BumpStopLibrary(Mapping):
    """An ordered, read-only mapping ``id -> BumpStop``.

    Parameters
    ----------
    stops : iterable of BumpStop, or mapping id -> BumpStop
        The stops, in order. Ids must be unique (and equal the keys of a mapping).
    source : str or path, optional
        Where the library came from (named in error messages).

    Raises
    ------
    BumpStopError
        On a duplicate id or a mapping key different from the stop's id.
    TypeError
        If an item is not a :class:`BumpStop`.

    Notes
    -----
    As :class:`ident.models.library.ShockLibrary`: :meth:`get` raises for an unknown id
    unless a default is passed; ``lib[id]`` raises ``KeyError`` as any mapping does.

    Examples
    --------
    >>> lib = BumpStopLibrary([BumpStop("BS-F", 0.015, [0.0, 0.01], [0.0, 1000.0])])
    >>> lib.get("BS-F").gap_m, "BS-R" in lib
    (0.015, False)
    """

    __slots__ = ("_source", "_stops")
    _MISSING = object()

    def __init__(self, stops=(), *, source=None):
        label = f"bump-stop library{f' {source}' if source else ''}"
        if isinstance(stops, Mapping):
            for key, stop in stops.items():
                if isinstance(stop, BumpStop) and key != stop.id:
                    raise BumpStopError(f"{label}: key {key!r} holds bump stop {stop.id!r}; "
                                        "use the stop's id as the key")
            items = list(stops.values())
        elif isinstance(stops, Iterable) and not isinstance(stops, (str, bytes)):
            items = list(stops)
        else:
            raise TypeError(f"{label}: stops must be an iterable of BumpStop, got "
                            f"{type(stops).__name__}")
        out = {}
        for j, stop in enumerate(items):
            if not isinstance(stop, BumpStop):
                raise TypeError(f"{label}: item {j} is a {type(stop).__name__}, not a "
                                "BumpStop")
            if stop.id in out:
                raise BumpStopError(f"{label}: duplicate bump-stop id {stop.id!r} (items "
                                    f"{list(out).index(stop.id)} and {j}); give each bump "
                                    "stop a unique id")
            out[stop.id] = stop
        self._stops = out
        self._source = None if source is None else str(source)

    @property
    def source(self):
        """str or None: The file the library was read from."""
        return self._source

    @property
    def ids(self):
        """tuple of str: The bump-stop ids, in order."""
        return tuple(self._stops)

    def __getitem__(self, stop_id):
        return self._stops[stop_id]

    def __iter__(self):
        return iter(self._stops)

    def __len__(self):
        return len(self._stops)

    def __eq__(self, other):
        if not isinstance(other, BumpStopLibrary):
            return NotImplemented
        return list(self._stops.items()) == list(other._stops.items())

    __hash__ = None

    def __repr__(self):
        src = f", source={self._source!r}" if self._source else ""
        return f"BumpStopLibrary({list(self._stops.values())!r}{src})"

    def get(self, stop_id, default=_MISSING, *, where=""):
        """Return the stop `stop_id`, or raise a clear error naming the file and the ids.

        Parameters
        ----------
        stop_id : str
            The id to look up.
        default : optional
            Returned for an unknown id if given (as ``dict.get``).
        where : str
            Who asks (e.g. ``"run 'swap-LF' bump_stops LF"``), put first in the message.

        Returns
        -------
        BumpStop

        Raises
        ------
        BumpStopError
            If `stop_id` is not in the library and no `default` is given; the message
            names the library's file, its ids and the nearest one.
        """
        try:
            return self._stops[stop_id]
        except (KeyError, TypeError):
            if default is not BumpStopLibrary._MISSING:
                return default
        raise self.unknown_id_error(stop_id, where=where)

    def unknown_id_error(self, stop_id, *, where="", error=BumpStopError):
        """The error for an id this library does not hold (to raise).

        Parameters
        ----------
        stop_id : str
            The unknown id.
        where : str
            Who asks, put first in the message.
        error : type
            The ``ValueError`` subclass to build (the caller's family).

        Returns
        -------
        error
        """
        prefix = f"{where}: " if where else ""
        lib = f"the bump-stop library {self._source}" if self._source else \
            "the bump-stop library"
        return error(f"{prefix}unknown bump-stop id {stop_id!r}"
                     f"{did_you_mean(stop_id, self._stops, cutoff=0.6)}; {lib} has "
                     f"{list(self._stops)}; fix the id, add the bump stop to the library, "
                     f"or write \"{NO_BUMP_STOP}\"")


# ----------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------


def _stop_from_toml(table, units, where, index):
    """Build one stop from a ``[[bump_stop]]`` table (values in `units`)."""
    raw_id = table.get("id") if isinstance(table, dict) else None
    label = f"{where}: [[bump_stop]] #{index}" + (f" ({raw_id!r})" if isinstance(raw_id, str)
                                                  else "")
    if not isinstance(table, dict):
        raise BumpStopError(f"{label}: is a {type(table).__name__}, not a table; write each "
                            "bump stop as a [[bump_stop]] table")
    extra = [k for k in table if k not in _TABLE_KEYS]
    if extra:
        raise BumpStopError(f"{label}: key {extra[0]!r} is not a key of a bump stop"
                            f"{did_you_mean(extra[0], _TABLE_KEYS)}; remove it or fix its "
                            f"spelling (keys: {list(_TABLE_KEYS)})")
    for key in ("id", *_TOML_FIELDS):
        if key not in table:
            unit = UNIT_LABELS[units][_TOML_FIELDS[key][1]] if key in _TOML_FIELDS else ""
            raise BumpStopError(f"{label}: key {key!r} is missing; every bump stop has id, "
                                f"gap, travel and force" + (f" (in {unit})" if unit else ""))
    if not isinstance(raw_id, str):
        raise BumpStopError(f"{label}: key 'id' must be a string, got "
                            f"{type(raw_id).__name__} {raw_id!r}; write the id in quotes")
    kwargs = {}
    for key, (attr, quantity, shape) in _TOML_FIELDS.items():
        value = table[key]
        if shape == "vector":
            if not isinstance(value, list) or not all(is_real_number(x) for x in value):
                raise BumpStopError(f"{label}: key {key!r} must be an array of numbers, got "
                                    f"{value!r}; write it as [v1, v2, ...] without quotes")
            value = np.array(value, dtype=float)
        elif not is_real_number(value):
            raise BumpStopError(f"{label}: key {key!r} must be a number, got "
                                f"{type(value).__name__} {value!r}; write a number without "
                                "quotes")
        kwargs[attr] = to_si(value, quantity, units)
    try:
        return BumpStop(raw_id, description=table.get("description", ""), **kwargs)
    except BumpStopError as exc:
        names = {attr: key for key, (attr, _, _) in _TOML_FIELDS.items()}
        base, _, sub = exc.field.partition("[")
        key = names.get(base, base) + (f"[{sub}" if sub else "")
        raise BumpStopError(f"{label}: key {key!r} {exc.problem}; {exc.fix}") from None


def read_bump_stops(path):
    """Read a bump-stop library (``bumpstops.toml``) into SI stops.

    Parameters
    ----------
    path : str or path
        The TOML file: a top-level ``units`` ("SI", the default, or "imperial": gap and
        travel in in, force in lbf) and ``[[bump_stop]]`` tables with ``id``, ``gap``,
        ``travel``, ``force`` and an optional ``description``.

    Returns
    -------
    BumpStopLibrary
        The stops in file order, in SI, with the file as its ``source``.

    Raises
    ------
    BumpStopError
        If the file is missing or not TOML, has an unknown unit system, no bump stops, a
        top-level key other than ``units`` and ``bump_stop``, a missing, unknown or
        mistyped key, a duplicate id or an invalid stop (negative gap, force falling
        with travel, travel not from 0 or not increasing, ...); the message names the
        file, the stop (index from 1 and id) and the key.
    """
    path = Path(path)
    doc = read_toml(path, error=BumpStopError, what="bump-stop library")
    for key in doc:  # a typo never falls back to a default: '[[bump_stops]]', 'unit'
        if key not in _TOP_KEYS:
            raise BumpStopError(f"{path}: unknown top-level key {key!r}"
                                f"{did_you_mean(key, _TOP_KEYS)}; a bump-stop library has "
                                "only 'units' and [[bump_stop]] tables")
    units = check_units(doc.get("units", "SI"), where=f"{path}: key 'units'", error=BumpStopError)
    tables = doc.get("bump_stop")
    if tables is None or tables == []:
        raise BumpStopError(f"{path}: no [[bump_stop]] tables; add at least one bump stop "
                            "(see the rig-session spec, 'The real car')")
    if not isinstance(tables, list):
        raise BumpStopError(f"{path}: key 'bump_stop' must be an array of tables, got "
                            f"{type(tables).__name__}; write each stop as a [[bump_stop]] table")
    stops = [_stop_from_toml(t, units, str(path), j + 1) for j, t in enumerate(tables)]
    ids = [s.id for s in stops]
    for j, stop_id in enumerate(ids):
        if stop_id in ids[:j]:
            raise BumpStopError(f"{path}: [[bump_stop]] #{j + 1} ({stop_id!r}): key 'id' "
                                f"repeats the id of [[bump_stop]] #{ids.index(stop_id) + 1}; "
                                "give each bump stop a unique id")
    logger.debug("read %d bump stop(s) from %s (%s)", len(stops), path, units)
    return BumpStopLibrary(stops, source=path)


def write_bump_stops(library, path, *, units="SI", overwrite=False):
    """Write a bump-stop library as ``bumpstops.toml``, atomically.

    Parameters
    ----------
    library : BumpStopLibrary or iterable of BumpStop
        The stops, in order.
    path : str or path
        Output file.
    units : {"SI", "imperial"}
        Unit system of the file (imperial: in and lbf; SI -> imperial -> SI is exact to
        round-off).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    BumpStopError
        If `units` is unknown or the stops have duplicate ids.
    FileExistsError
        If `path` exists and `overwrite` is false.
    """
    if not isinstance(library, BumpStopLibrary):
        library = BumpStopLibrary(library)
    units = check_units(units, where="write_bump_stops: units", error=BumpStopError)
    path = Path(path)
    doc = {"units": units, "bump_stop": [s.to_toml_dict(units) for s in library.values()]}
    atomic_write_toml(path, doc, overwrite=overwrite,
                      header="Bump-stop library (rig-session/1), written by shockplan.")
    logger.info("wrote %d bump stop(s) to %s (%s)", len(library), path, units)
    return path


# ----------------------------------------------------------------------------
# the closed loop's form
# ----------------------------------------------------------------------------


def contact_tables(stops, packers_m=None, *, where="", error=BumpStopError):
    """The corners' bump stops in the closed loop's form.

    The one conversion from the data layer's stops and packers to the tables of
    :func:`ident.sim.closedloop.simulate` (``bump_stops=``).

    Parameters
    ----------
    stops : sequence of (BumpStop or None), shape (4,)
        The stops of ``LF, RF, LR, RR`` (None: no bump stop), as
        :func:`resolve_corner_stops` returns them.
    packers_m : array_like, shape (4,), optional
        Packer thickness [m] per corner (default 0; ignored where there is no stop).
    where : str
        Who asks (e.g. ``"run 'swap-LF'"``), put first in messages.
    error : type
        The ``ValueError`` subclass to raise (the caller's family).

    Returns
    -------
    tuple of ((float, ndarray, ndarray) or None), shape (4,), or None
        Per corner ``(contact_travel_m, travel_m, force_n)``: the shock travel from the
        car at rest at which the stop touches (``gap_m - packer``) [m] and its table;
        None at a corner without a stop. None when no corner has a stop (the loop
        without elements: the same numbers as a car without bump stops).

    Raises
    ------
    error
        If a packer is negative, not finite or thicker than its stop's gap.
    TypeError
        If a stop is neither a :class:`BumpStop` nor None.

    Examples
    --------
    >>> bs = BumpStop("BS-F", 0.015, [0.0, 0.01], [0.0, 1000.0])
    >>> got = contact_tables([bs, bs, None, None], [0.005, 0.0, 0.0, 0.0])
    >>> [None if t is None else round(t[0], 6) for t in got]
    [0.01, 0.015, None, None]
    >>> contact_tables([None] * 4) is None
    True
    """
    stops = tuple(stops)
    if len(stops) != len(CORNERS):
        raise error(f"{where + ': ' if where else ''}{len(stops)} bump stops given; give one "
                    f"per corner {list(CORNERS)} (None: no bump stop)")
    packers = np.zeros(len(CORNERS)) if packers_m is None else np.asarray(packers_m, float)
    out = []
    for c, stop, p in zip(CORNERS, stops, packers):
        if stop is None:
            out.append(None)
            continue
        if not isinstance(stop, BumpStop):
            raise TypeError(f"{where + ': ' if where else ''}corner {c}: a "
                            f"{type(stop).__name__}, not a BumpStop or None")
        label = f"{where + ': ' if where else ''}corner {c}"
        p = check_packer(stop, float(p), label, error=error)
        out.append((max(stop.gap_m - p, 0.0), stop.travel_m, stop.force_n))
    return None if all(t is None for t in out) else tuple(out)


# ----------------------------------------------------------------------------
# CarElements
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class CarElements:
    """The real car's declared elements an identified model carries (issue 25).

    What a session declares beyond the shocks, kept with the model it identified so that
    predictions put the same elements in the loop: the bump-stop library, the baseline
    run's stops and packers, and the tires' static loads.

    Parameters
    ----------
    bump_stops : BumpStopLibrary or None
        The session's bump-stop library (None: none declared).
    baseline_stops : dict of str to (str or None)
        Corner -> bump-stop id of the baseline run (None: no stop there); every corner.
    baseline_packers_m : dict of str to float
        Corner -> packer thickness [m] of the baseline run; every corner (0: none).
    static_corner_load_n : ndarray, shape (4,), or None
        Static corner loads [N] (LF, RF, LR, RR), or None (not declared).

    Raises
    ------
    BumpStopError
        If a baseline stop is not in the library, or a packer is negative or thicker than
        its stop's gap.
    TypeError
        If `bump_stops` is not a library.

    Examples
    --------
    >>> lib = BumpStopLibrary([BumpStop("BS-F", 0.006, [0.0, 0.01], [0.0, 1000.0])])
    >>> el = CarElements(lib, {"LF": "BS-F", "RF": "BS-F"}, {"LF": 0.001})
    >>> el.baseline_stops["LR"], el.baseline_packers_m["LF"]
    (None, 0.001)
    >>> CarElements.from_dict(el.to_dict()).to_dict() == el.to_dict()
    True
    """

    bump_stops: BumpStopLibrary | None = None
    baseline_stops: dict = field(default_factory=lambda: dict.fromkeys(CORNERS))
    baseline_packers_m: dict = field(default_factory=lambda: dict.fromkeys(CORNERS, 0.0))
    static_corner_load_n: np.ndarray | None = None

    def __post_init__(self):
        if self.bump_stops is not None and not isinstance(self.bump_stops, BumpStopLibrary):
            raise TypeError(f"CarElements: bump_stops must be a BumpStopLibrary or None, got "
                            f"{type(self.bump_stops).__name__}")
        stops = dict.fromkeys(CORNERS)
        stops.update({c: v for c, v in (self.baseline_stops or {}).items()})
        packers = dict.fromkeys(CORNERS, 0.0)
        packers.update({c: float(v) for c, v in (self.baseline_packers_m or {}).items()})
        for c in stops:
            if c not in CORNERS:
                raise BumpStopError(f"CarElements: baseline_stops has corner {c!r}; corners "
                                    f"are {list(CORNERS)}")
            sid = stops[c]
            if sid is None:
                continue
            if self.bump_stops is None:
                raise BumpStopError(f"CarElements: baseline_stops {c} = {sid!r} but no "
                                    "bump-stop library is given; give bump_stops")
            check_packer(self.bump_stops.get(sid, where=f"CarElements baseline_stops {c}"),
                         packers.get(c, 0.0), f"CarElements corner {c}")
        object.__setattr__(self, "baseline_stops", stops)
        object.__setattr__(self, "baseline_packers_m", packers)
        if self.static_corner_load_n is not None:
            loads = np.array(self.static_corner_load_n, dtype=float).reshape(-1)
            if loads.size != len(CORNERS) or not np.all(np.isfinite(loads)):
                raise BumpStopError(f"CarElements: static_corner_load_n must be 4 finite loads "
                                    f"[N] (LF, RF, LR, RR), got {self.static_corner_load_n!r}")
            loads.flags.writeable = False
            object.__setattr__(self, "static_corner_load_n", loads)

    def baseline_tables(self):
        """The baseline stops in the loop's form (:func:`contact_tables`), or None."""
        if self.bump_stops is None:
            return None
        stops = [None if self.baseline_stops[c] is None else
                 self.bump_stops[self.baseline_stops[c]] for c in CORNERS]
        return contact_tables(stops, [self.baseline_packers_m[c] for c in CORNERS],
                              where="baseline")

    def describe(self):
        """One line for a model's summary: what the model was identified with."""
        parts = []
        if self.bump_stops is not None:
            st = ", ".join(f"{c} {self.baseline_stops[c]}"
                           + (f" (packer {_mm_in(self.baseline_packers_m[c])})"
                              if self.baseline_packers_m[c] else "")
                           for c in CORNERS if self.baseline_stops[c] is not None)
            parts.append(f"bump stops {list(self.bump_stops.ids)} declared; baseline: "
                         f"{st or 'none fitted'}")
        if self.static_corner_load_n is not None:
            parts.append("static corner loads " + ", ".join(
                f"{c} {v:.0f} N" for c, v in zip(CORNERS, self.static_corner_load_n)))
        return "; ".join(parts) if parts else "no bump stops or static loads declared"

    def to_dict(self):
        """JSON-able dict (SI): ``bump_stops`` (list of stop tables or None),
        ``baseline_stops``, ``baseline_packers_m``, ``static_corner_load_n`` (list or None)."""
        return {"bump_stops": None if self.bump_stops is None else
                [self.bump_stops[i].to_toml_dict("SI") for i in self.bump_stops.ids],
                "baseline_stops": dict(self.baseline_stops),
                "baseline_packers_m": {c: float(v) for c, v in self.baseline_packers_m.items()},
                "static_corner_load_n": None if self.static_corner_load_n is None else
                [float(v) for v in self.static_corner_load_n]}

    @classmethod
    def from_dict(cls, d):
        """The elements :meth:`to_dict` wrote.

        Raises
        ------
        BumpStopError
            If a stop's table is invalid or a key is missing (the dict names the fix).
        """
        if not isinstance(d, Mapping):
            raise BumpStopError(f"CarElements.from_dict: a dict is needed, got "
                                f"{type(d).__name__}")
        lib = d.get("bump_stops")
        if lib is not None:
            lib = BumpStopLibrary([BumpStop(t["id"], t["gap"], t["travel"], t["force"],
                                            description=t.get("description", ""))
                                   for t in lib])
        return cls(lib, d.get("baseline_stops") or {}, d.get("baseline_packers_m") or {},
                   d.get("static_corner_load_n"))
