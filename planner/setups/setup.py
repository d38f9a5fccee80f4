"""The shock setup: one shock id per corner, and optionally bump stops and packers.

:class:`Setup` and the checks the other modules of :mod:`planner.setups` share (a
library's ids, the unknown-id error, a list of setups with unique names).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from ident.data.channels import CORNERS, corner_table
from ident.data.third import AXLES, THIRD_ELEMENTS
from ident.errors import ShockModelError
from ident.models.bumpstops import parse_bump_stop_id
from planner.errors import PlannerError

__all__ = [
    "Setup",
    "unknown_id_error",
    "check_setups",
    "library_ids",
    "library_label",
]


def _check_text(value, what, fix):
    """Return `value` if it is a non-empty string without surrounding whitespace."""
    if not isinstance(value, str) or not value.strip() or value != value.strip():
        raise PlannerError(f"{what} {value!r} is not valid; {fix}")
    return value


def library_ids(library, where):
    """The ids of a shock library (a mapping id -> shock model), or raise :class:`TypeError`
    naming `where`."""
    if not isinstance(library, Mapping):
        raise TypeError(f"{where}: library must be a ShockLibrary (or a mapping id -> "
                        f"ShockModel), got {type(library).__name__}; read one with "
                        "ident.models.library.read_shock_library")
    return list(library)


def library_label(library):
    """How messages name a shock library: its file when it has one."""
    source = getattr(library, "source", None)
    return f"shock library {source}" if source else "the shock library"


def unknown_id_error(where, shock_id, library):
    """The error for a shock id that `library` does not hold, listing the ids it has.

    Parameters
    ----------
    where : str
        Where the id was given (a setup and corner, a column, an argument), the message's
        first words.
    shock_id : str
        The unknown id.
    library : ShockLibrary or mapping of str to ShockModel
        The library looked in (its ``source`` is named when it has one).

    Returns
    -------
    PlannerError
        To raise: ``raise unknown_id_error(...)``.

    Examples
    --------
    >>> from ident.models.library import ShockLibrary
    >>> from ident.models.shocks import LinearShock
    >>> lib = ShockLibrary.from_models([LinearShock("B20", 3502.5), LinearShock("D8", 1400.0)])
    >>> print(unknown_id_error("candidate shocks", "X9", lib))  # doctest: +NORMALIZE_WHITESPACE
    candidate shocks: unknown shock id 'X9'; the shock library has ['B20', 'D8']; fix the id or
    add the shock to the library
    """
    return PlannerError(f"{where}: unknown shock id {shock_id!r}; {library_label(library)} has "
                        f"{list(library)}; fix the id or add the shock to the library")


# ----------------------------------------------------------------------------
# Setup
# ----------------------------------------------------------------------------


def _corner_elements(who, bump_stops, packers_m):
    """A setup's bump stops and packers, checked: read-only mappings in corner order (only
    the corners given; an empty one becomes None)."""
    out = []
    for key, values in (("bump_stops", bump_stops), ("packers_m", packers_m)):
        if values is None:
            out.append(None)
            continue
        values = corner_table(values, name=key, where=who, error=PlannerError,
                              what="bump-stop id" if key == "bump_stops" else "packer [m]")
        given = {}
        for c in (c for c in CORNERS if c in values):
            v = values[c]
            if key == "bump_stops":
                given[c] = None if v is None else parse_bump_stop_id(
                    v, f"{who}: bump_stops {c}", error=PlannerError)
            elif isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or \
                    not math.isfinite(v) or v < 0:
                raise PlannerError(f"{who}: packers_m {c} = {v!r} is not a thickness; give a "
                                   "number >= 0 [m] (0 = none)")
            else:
                given[c] = float(v)
        out.append(MappingProxyType(given) if given else None)
    return out


def _third_elements(who, third, heave_springs):
    """A setup's third-element dampers and heave springs, checked: read-only mappings in
    the spec's order (only the elements given; an empty one becomes None)."""
    out = []
    for key, values, known in (("third", third, THIRD_ELEMENTS),
                               ("heave_springs", heave_springs, AXLES)):
        if values is None:
            out.append(None)
            continue
        if not isinstance(values, Mapping):
            raise PlannerError(f"{who}: {key} must be a mapping {known[0]} -> id, got "
                               f"{values!r}")
        unknown = [k for k in values if k not in known]
        if unknown:
            raise PlannerError(f"{who}: {key} {unknown[0]!r} is not one of {list(known)}")
        given = {}
        for k in (k for k in known if k in values):
            v = values[k]
            if v is not None:
                _check_text(v, f"{who}: {key} {k}", 'give a library id or "none"')
                v = None if v.lower() == "none" else v
            given[k] = v
        out.append(MappingProxyType(given) if given else None)
    return out


@dataclass(frozen=True)
class Setup:
    """One shock id per corner, and optionally bump stops and packers.

    Parameters
    ----------
    name : str
        The setup's name (non-empty, no surrounding whitespace).
    shocks : mapping of str to str
        Corner -> shock id, exactly the corners ``LF RF LR RR`` (any order;
        stored read-only in corner order).
    bump_stops : mapping of str to (str or None), optional
        Corner -> bump-stop id, or None (or ``"none"``) for no bump stop, for the
        corners the setup sets; the others keep the model's baseline run's. Stored
        read-only in corner order; None (the default) when no corner is given.
    packers_m : mapping of str to float, optional
        Corner -> packer thickness [m] (>= 0) for the corners the setup sets; the others
        keep the baseline run's. As `bump_stops`.
    third : mapping of str to (str or None), optional
        Third element (``heave_front``, ``heave_rear``, ``roll_front``, ``roll_rear``) ->
        its damper's shock id (a setting name such as ``TTX@ls=6``), or None (or
        ``"none"``) for none, for the elements the setup sets; the others keep the
        baseline run's. As `bump_stops`.
    heave_springs : mapping of str to (str or None), optional
        Axle (``front``, ``rear``) -> heave spring's bump-stop id, or None for none; as
        `third`.

    Raises
    ------
    PlannerError
        On an empty or padded name, a missing or unknown corner, or an empty
        or padded shock id; an unknown corner, an empty bump-stop id or a negative or
        non-finite packer.

    Notes
    -----
    Setups compare by name, ids, bump stops and packers, and hash by name and ids.
    Whether the ids exist is checked against a library by :meth:`resolve` (and
    :func:`read_setups` when given libraries); the bump stops and packers at each
    corner, the setup's or the baseline run's, by
    :func:`ident.models.bumpstops.resolve_corner_stops`.

    Examples
    --------
    >>> s = Setup("soft-front", {"LF": "D8", "RF": "D8", "LR": "B20", "RR": "B20"})
    >>> s.ids()
    ('D8', 'D8', 'B20', 'B20')
    >>> s.shocks["LR"]
    'B20'
    """

    name: str
    shocks: Mapping
    # defaults stay class attributes, so _unchecked's setups read None without a store
    bump_stops: Mapping | None = None
    packers_m: Mapping | None = None
    third: Mapping | None = None
    heave_springs: Mapping | None = None

    def __post_init__(self):
        _check_text(self.name, "setup name", "give a non-empty name without surrounding "
                    "spaces")
        who = f"setup {self.name!r}"
        shocks = corner_table(self.shocks, name="shocks", where=who, what="shock id",
                              error=PlannerError)
        missing = [c for c in CORNERS if c not in shocks]
        if missing:
            raise PlannerError(f"{who}: no shock for corner(s) {missing}; give a shock id for "
                               f"each of {list(CORNERS)}")
        ids = tuple(shocks[c] for c in CORNERS)
        for c, sid in zip(CORNERS, ids):
            _check_text(sid, f"{who}: corner {c}: shock id", "give a shock id from the "
                        "library (non-empty, no surrounding spaces)")
        self._set(ids)
        if self.bump_stops is not None or self.packers_m is not None:
            stops, packers = _corner_elements(who, self.bump_stops, self.packers_m)
            object.__setattr__(self, "bump_stops", stops)
            object.__setattr__(self, "packers_m", packers)
        if self.third is not None or self.heave_springs is not None:
            third, springs = _third_elements(who, self.third, self.heave_springs)
            object.__setattr__(self, "third", third)
            object.__setattr__(self, "heave_springs", springs)

    def _set(self, ids):
        object.__setattr__(self, "shocks", MappingProxyType(dict(zip(CORNERS, ids))))
        object.__setattr__(self, "_ids", ids)

    @classmethod
    def _unchecked(cls, name, ids):
        """Build a setup from trusted values (enumeration's fast path)."""
        obj = object.__new__(cls)
        object.__setattr__(obj, "name", name)
        obj._set(ids)
        return obj

    def __hash__(self):
        return hash((self.name, self._ids))

    def _elements(self):
        """The bump stops, packers, third elements and heave springs as plain dicts (None
        where not given)."""
        return tuple(None if m is None else dict(m) for m in (
            self.bump_stops, self.packers_m, self.third, self.heave_springs))

    def __reduce__(self):  # mappingproxy does not pickle; rebuild from plain values
        elements = self._elements()
        if all(m is None for m in elements):
            return (Setup, (self.name, dict(self.shocks)))
        if elements[2:] == (None, None):
            return (Setup, (self.name, dict(self.shocks), *elements[:2]))
        return (Setup, (self.name, dict(self.shocks), *elements))

    def __repr__(self):
        more = "".join(f", {k}={v!r}" for k, v in zip(
            ("bump_stops", "packers_m", "third", "heave_springs"), self._elements())
            if v is not None)
        return f"Setup(name={self.name!r}, shocks={dict(self.shocks)!r}{more})"

    def ids(self):
        """Return the shock ids in corner order.

        Returns
        -------
        tuple of str, shape (4,)
            Ids for ``LF, RF, LR, RR``.
        """
        return self._ids

    def resolve(self, library):
        """Look up the setup's shocks in a library.

        Parameters
        ----------
        library : ShockLibrary or mapping of str to ShockModel
            The team's shocks.

        Returns
        -------
        tuple of ShockModel, shape (4,)
            The models for ``LF, RF, LR, RR``.

        Raises
        ------
        PlannerError
            If an id is not in the library (naming the setup, the corner, the
            id and the known ids).
        TypeError
            If `library` is not a mapping.
        """
        library_ids(library, f"setup {self.name!r}")
        out = []
        for c, sid in zip(CORNERS, self._ids):
            if sid not in library:
                raise unknown_id_error(f"setup {self.name!r}: corner {c}", sid, library)
            try:
                out.append(library[sid])
            except ShockModelError as exc:  # a setting name out of range, unknown adjuster
                raise PlannerError(f"setup {self.name!r}: corner {c}: {exc}") from None
        return tuple(out)


def check_setups(setups, where):
    """Return `setups` as a tuple of :class:`Setup` with unique names."""
    if isinstance(setups, Setup):
        setups = (setups,)
    if isinstance(setups, (str, bytes)) or not isinstance(setups, Iterable):
        raise TypeError(f"{where}: setups must be an iterable of Setup, got "
                        f"{type(setups).__name__}")
    setups = tuple(setups)
    seen = {}
    for j, s in enumerate(setups):
        if not isinstance(s, Setup):
            raise TypeError(f"{where}: item {j} is a {type(s).__name__}, not a Setup")
        if s.name in seen:
            raise PlannerError(f"{where}: setups {seen[s.name]} and {j} are both named "
                               f"{s.name!r}; give each setup a unique name")
        seen[s.name] = j
    return setups
