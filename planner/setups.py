"""Shock setups: one shock id per corner, read, written, enumerated; the baseline.

A setup names one shock of the team's shock library (``ident.models.library``) for
each corner ``LF RF LR RR`` (:data:`ident.data.channels.CORNERS`). The planner
predicts metrics for many setups and ranks them (:mod:`planner.objective`).

File format (``setups.csv``, the rig-session spec's "Setups")::

    setup,LF,RF,LR,RR
    soft-front,D8,D8,B20,B20
    baseline,B20,B20,B20,B20

One row per setup, order kept. :func:`read_setups` needs the columns
``setup`` and the four corners (any column order); **other columns are
allowed and ignored**, so a predictions CSV (``setup, LF, RF, LR, RR``, then
metrics) reads as a setups file. The exception is a column that looks like a
misspelt corner (two letters, such as ``LM`` or ``lf``): that is an error.
Cells are stripped of surrounding spaces; blank lines, and ``#`` comment lines before
the header (the unit marker ``# units: SI`` that every CSV shockplan writes starts
with), are skipped.

Bump stops and packers (the spec's "The real car"; optional): columns ``bump_stop_XX``
(a bump-stop id, or ``none``) and ``packer_XX`` (a thickness in the file's unit system:
m, or in with ``# units: imperial``) give a setup's bump stops and packers at corner
``XX``. A setup without them, a corner without its column, or an empty cell keeps the
model's baseline run's (:func:`ident.models.bumpstops.resolve_corner_stops`)::

    setup,LF,RF,LR,RR,bump_stop_LF,bump_stop_RF,packer_LF,packer_RF
    soft-front-packed,D8,D8,B20,B20,BS-F,BS-F,0.003,0.003
    baseline,B20,B20,B20,B20,,,,

Generated names (:func:`enumerate_setups`) are compact by default:
``"B20/B20/D8/D8"``, the ids in corner order LF/RF/LR/RR; pass
``name_format="LF={LF} RF={RF} LR={LR} RR={RR}"`` for the spelled-out form.

The enumeration is one implementation: :func:`setup_space` holds the setups of
an enumeration as integer codes (a :class:`SetupSpace`, decoded chunk by chunk);
:func:`enumerate_setups` decodes all of it, :mod:`planner.sweep` a chunk at a
time, in the same order and with the same names.

Every command reads its baseline with :func:`resolve_baseline`: a
:class:`Setup`, a listed setup's name, one shock id (every corner) or four ids
``"LF,RF,LR,RR"`` separated by commas.

Examples
--------
>>> from ident.models.library import ShockLibrary
>>> from ident.models.shocks import LinearShock
>>> lib = ShockLibrary.from_models([LinearShock("B20", 3502.5),
...                                 LinearShock("D8", 1400.0, count=2)])
>>> [s.name for s in enumerate_setups(lib)]   # D8 x4 skipped: the team has 2
['B20/B20/B20/B20', 'B20/B20/D8/D8', 'D8/D8/B20/B20']
>>> len(enumerate_setups(lib, symmetry="none"))   # D8 at 3 or 4 corners: only 2 exist
11
>>> base = Setup("baseline", {"LF": "B20", "RF": "B20", "LR": "B20", "RR": "B20"})
>>> [s.name for s in setups_from_baseline(base, lib, corners=("LF", "rear"))]
['baseline', 'baseline LF=D8', 'baseline rear=D8']
"""

from __future__ import annotations

import contextlib
import csv
import gc
import io
import logging
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np
import pandas as pd

from ident.data.files import check_can_write, csv_preamble, resolve_units, write_csv
from ident.data.channels import CORNERS, corner_table
from ident.data.units import UNIT_LABELS, from_si, to_si
from ident.errors import ShockModelError
from ident.models.bumpstops import (NO_BUMP_STOP, BumpStopLibrary, check_packer,
                                    parse_bump_stop_id)
from planner.clicks import base_id, canonical_id, click_steps, expand_candidates, split_shock_ids
from planner.errors import PlannerError

__all__ = [
    "SYMMETRIES",
    "AXLE_MODES",
    "AXLES",
    "DEFAULT_MAX_SETUPS",
    "DEFAULT_NAME_FORMAT",
    "Setup",
    "SetupSpace",
    "setup_space",
    "read_setups",
    "read_ranking_baseline",
    "write_setups",
    "setups_to_frame",
    "enumerate_setups",
    "setups_from_baseline",
    "inventory_shortfall",
    "unknown_id_error",
    "resolve_baseline",
]

logger = logging.getLogger(__name__)

#: Allowed values of `symmetry` in :func:`enumerate_setups`: ``"left-right"`` (LF = RF and
#: LR = RR), ``"all"`` (every corner the same shock: left-right with ``axles="same"``;
#: :func:`planner.optimize.optimize_curves` uses the same names) and ``"none"``.
SYMMETRIES = ("left-right", "all", "none")
#: Allowed values of `axles` in :func:`enumerate_setups`: ``"independent"`` or ``"same"``
#: (the rear corners get the front corners' shocks).
AXLE_MODES = ("independent", "same")
#: Axle name -> its two corners.
AXLES = {"front": ("LF", "RF"), "rear": ("LR", "RR")}
#: Default guard of :func:`enumerate_setups` on the number of candidate setups.
DEFAULT_MAX_SETUPS = 100_000
#: Default name template of generated setups (``str.format`` fields: the corners).
DEFAULT_NAME_FORMAT = "{LF}/{RF}/{LR}/{RR}"

_SETUP_COLUMN = "setup"
_CORNER_LIKE = re.compile(r"^[A-Za-z]{2}$")
#: The optional columns of a setups CSV: bump stop and packer per corner.
_BUMP_COLUMNS = tuple(f"bump_stop_{c}" for c in CORNERS)
_PACKER_COLUMNS = tuple(f"packer_{c}" for c in CORNERS)
#: A misspelt one (case, separators, plural, FL for LF), refused; a longer name that
#: merely starts alike (a metric such as bump_stop_share_LF) is another column.
_ELEMENT_LIKE = re.compile(r"^(bumpstops?|bumps?|packers?)(lf|rf|lr|rr|fl|fr|rl)$")
_CORNER_ALIASES = {"fl": "LF", "fr": "RF", "rl": "LR"}


def _check_text(value, what, fix):
    """Return `value` if it is a non-empty string without surrounding whitespace."""
    if not isinstance(value, str) or not value.strip() or value != value.strip():
        raise PlannerError(f"{what} {value!r} is not valid; {fix}")
    return value


def _library_ids(library, where):
    if not isinstance(library, Mapping):
        raise TypeError(f"{where}: library must be a ShockLibrary (or a mapping id -> "
                        f"ShockModel), got {type(library).__name__}; read one with "
                        "ident.models.library.read_shock_library")
    return list(library)


def _lib_label(library):
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
    return PlannerError(f"{where}: unknown shock id {shock_id!r}; {_lib_label(library)} has "
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
        """The bump stops and packers as plain dicts (None where not given)."""
        return tuple(None if m is None else dict(m) for m in (self.bump_stops, self.packers_m))

    def __reduce__(self):  # mappingproxy does not pickle; rebuild from plain values
        if self.bump_stops is None and self.packers_m is None:
            return (Setup, (self.name, dict(self.shocks)))
        return (Setup, (self.name, dict(self.shocks), *self._elements()))

    def __repr__(self):
        more = "".join(f", {k}={v!r}" for k, v in zip(("bump_stops", "packers_m"),
                                                        self._elements()) if v is not None)
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
        _library_ids(library, f"setup {self.name!r}")
        out = []
        for c, sid in zip(CORNERS, self._ids):
            if sid not in library:
                raise unknown_id_error(f"setup {self.name!r}: corner {c}", sid, library)
            try:
                out.append(library[sid])
            except ShockModelError as exc:  # a setting name out of range, unknown adjuster
                raise PlannerError(f"setup {self.name!r}: corner {c}: {exc}") from None
        return tuple(out)


def _check_setups(setups, where):
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


# ----------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------


def read_setups(path, library=None, bump_stops=None, *, units=None):
    """Read a setups CSV (``setup,LF,RF,LR,RR``, one row per setup).

    Parameters
    ----------
    path : str or path
        The CSV file (UTF-8, a header row).
    library : ShockLibrary, optional
        If given, every shock id must be in it.
    bump_stops : BumpStopLibrary, optional
        If given, every id in a ``bump_stop_XX`` column must be in it, and a packer
        beside a bump stop the row names must fit its gap.
    units : {"SI", "imperial"}, optional
        The unit system of ``packer_XX`` when the file has no unit marker (default SI);
        a marker that says otherwise is an error.

    Returns
    -------
    tuple of Setup
        In file order.

    Raises
    ------
    PlannerError
        If the file is missing or empty, has no setups, lacks the ``setup`` or
        a corner column, repeats a column, has a column that looks like an
        unknown corner (two letters, e.g. ``LM``), a row with the wrong number
        of fields, an empty cell, a duplicate setup name, or (with `library`) an
        unknown shock id, or a setting name with an unknown adjuster or a setting out of
        range; a column that looks like a misspelt ``bump_stop_XX`` or
        ``packer_XX``, a packer that is not a number >= 0, or (with `bump_stops`) an
        unknown bump-stop id or a packer thicker than the gap of the row's bump stop.
        The message names the file, the line and setup, the column, and the fix.

    Notes
    -----
    Columns other than ``setup``, the corners and ``bump_stop_XX`` / ``packer_XX``
    are ignored (so a predictions CSV reads as a setups file). In ``bump_stop_XX``,
    ``none`` (any case) is no bump stop; an empty ``bump_stop_XX`` or ``packer_XX``
    cell keeps the baseline run's (:attr:`Setup.bump_stops` and
    :attr:`Setup.packers_m` hold only the corners a row gives). Leading ``#``
    comment lines (the unit marker
    ``# units: ...`` that shockplan writes) are skipped. Line numbers are the file's
    (the header is line 1 unless comment lines precede it).
    """
    path = Path(path)
    if library is not None:
        _library_ids(library, f"read_setups {path}")
    if bump_stops is not None and not isinstance(bump_stops, BumpStopLibrary):
        bump_stops = BumpStopLibrary(bump_stops)
    if not path.is_file():
        raise PlannerError(f"{path}: setups file not found; check the path")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise PlannerError(f"{path}: not a text CSV file (byte {exc.start}: {exc.reason}); "
                           f"a setups file is UTF-8 text with the header "
                           f"'{_SETUP_COLUMN},{','.join(CORNERS)}'") from None
    if "\x00" in text:
        raise PlannerError(f"{path}: holds NUL bytes, not a text CSV file; a setups file is "
                           f"UTF-8 text with the header '{_SETUP_COLUMN},{','.join(CORNERS)}'")
    # leading '#' comment lines (the unit marker '# units: ...') are skipped, their
    # marker checked; line numbers stay the file's
    marked, n_skip = csv_preamble(text.splitlines(), where=str(path), error=PlannerError)
    body = "".join(text.splitlines(keepends=True)[n_skip:])
    rows = csv.reader(io.StringIO(body, newline=""), skipinitialspace=True)
    header = None
    for header in rows:
        if any(cell.strip() for cell in header):
            break
    else:
        header = None
    if header is None:
        raise PlannerError(f"{path}: the file is empty; write the header "
                           f"'{_SETUP_COLUMN},{','.join(CORNERS)}' and one row per setup")
    header = [h.strip() for h in header]
    for j, h in enumerate(header):
        if h in header[:j]:
            raise PlannerError(f"{path}: column {h!r} appears twice in the header; "
                               "remove the duplicate column")
        if h != _SETUP_COLUMN and h not in CORNERS and _CORNER_LIKE.match(h):
            raise PlannerError(f"{path}: column {h!r} is not a corner; corners are "
                               f"{list(CORNERS)} (upper case); rename the column")
        typo = _ELEMENT_LIKE.match(re.sub(r"[^a-z]", "", h.lower()))
        if typo and h not in _BUMP_COLUMNS + _PACKER_COLUMNS:
            word, corner = typo.groups()
            meant = ("packer_" if word.startswith("p") else "bump_stop_") + \
                _CORNER_ALIASES.get(corner, corner.upper())
            raise PlannerError(f"{path}: column {h!r} is not a bump-stop or packer column "
                               f"(did you mean {meant!r}?); they are bump_stop_XX and "
                               f"packer_XX with XX one of {list(CORNERS)}: rename the column")
    if _SETUP_COLUMN not in header:
        raise PlannerError(f"{path}: no column '{_SETUP_COLUMN}'; the header must be "
                           f"'{_SETUP_COLUMN},{','.join(CORNERS)}' (lower-case 'setup')")
    missing = [c for c in CORNERS if c not in header]
    if missing:
        raise PlannerError(f"{path}: no column for corner(s) {missing}; the header must be "
                           f"'{_SETUP_COLUMN},{','.join(CORNERS)}'")
    i_name = header.index(_SETUP_COLUMN)
    i_corner = [header.index(c) for c in CORNERS]
    i_stop = {c: header.index(k) for c, k in zip(CORNERS, _BUMP_COLUMNS) if k in header}
    i_packer = {c: header.index(k) for c, k in zip(CORNERS, _PACKER_COLUMNS) if k in header}
    packer_units = resolve_units(marked, units, where=str(path), error=PlannerError) \
        if i_packer else None
    out = []
    lines = {}
    for cells in rows:
        line = n_skip + rows.line_num
        if not any(cell.strip() for cell in cells):
            continue
        if len(cells) != len(header):
            raise PlannerError(f"{path}: line {line} has {len(cells)} fields but the header "
                               f"has {len(header)}; give one value per column")
        cells = [c.strip() for c in cells]
        name = cells[i_name]
        if not name:
            raise PlannerError(f"{path}: line {line}: column '{_SETUP_COLUMN}' is empty; "
                               "give each setup a name")
        where = f"{path}: line {line} (setup {name!r})"
        if name in lines:
            raise PlannerError(f"{where}: setup name repeats line {lines[name]}; give each "
                               "setup a unique name")
        lines[name] = line
        ids = tuple(cells[i] for i in i_corner)
        for c, sid in zip(CORNERS, ids):
            if not sid:
                raise PlannerError(f"{where}: column {c!r} is empty; give a shock id for "
                                   "every corner")
            if library is not None and sid not in library:
                raise unknown_id_error(f"{where}: column {c!r}", sid, library)
        if library is not None:  # setting names checked and canonical: TTX@ls=6,hs=2
            ids = tuple(canonical_id(library, sid, f"{where}: column {c!r}")
                        for c, sid in zip(CORNERS, ids))
        if not i_stop and not i_packer:
            out.append(Setup._unchecked(name, ids))
            continue
        stops, packers = _row_elements(cells, i_stop, i_packer, bump_stops, packer_units,
                                       where)
        out.append(Setup(name, dict(zip(CORNERS, ids)), bump_stops=stops or None,
                         packers_m=packers or None))
    if not out:
        raise PlannerError(f"{path}: no setups below the header; add one row per setup")
    logger.debug("read %d setup(s) from %s", len(out), path)
    return tuple(out)


def _row_elements(cells, i_stop, i_packer, bump_stops, units, where):
    """The bump stops and packers [m] a setups CSV row gives (empty cells left out)."""
    stops, packers = {}, {}
    for c, i in i_stop.items():
        if cells[i]:
            col = f"{where}: column 'bump_stop_{c}'"
            stops[c] = sid = parse_bump_stop_id(cells[i], col, error=PlannerError)
            if sid is not None and bump_stops is not None and sid not in bump_stops:
                raise bump_stops.unknown_id_error(sid, where=col, error=PlannerError)
    for c, i in i_packer.items():
        if not cells[i]:
            continue
        col = f"{where}: column 'packer_{c}'"
        unit = UNIT_LABELS[units]["displacement"]
        try:
            value = float(cells[i])
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or value < 0:
            raise PlannerError(f"{col}: {cells[i]!r} is not a thickness; give the packer in "
                               f"{unit} (a number >= 0, 0 = none), or leave the cell empty "
                               "for the baseline's packer")
        packers[c] = to_si(value, "displacement", units)
        if bump_stops is not None and stops.get(c) is not None:
            check_packer(bump_stops[stops[c]], packers[c], col, error=PlannerError)
    return stops, packers


def read_ranking_baseline(path):
    """The baseline a ranking CSV was scored against (its ``baseline`` column).

    ``shockplan rank`` marks the setup its scores are ratios to with ``True`` in the
    column ``baseline`` of ``ranking.csv``; ``whatif --ranking`` takes it as its own
    baseline, so that the what-if scores mean what the ranking's mean.

    Parameters
    ----------
    path : str or path
        A ranking CSV (leading ``#`` comment lines, e.g. the unit marker, are skipped).

    Returns
    -------
    str or None
        The baseline setup's name; None if the file has no ``baseline`` column (a
        ranking written before the column existed, or a plain setups file).

    Raises
    ------
    PlannerError
        If the file cannot be read, or marks more than one setup, or the column marks
        none: the message names the file and the fix (``--baseline``).
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise PlannerError(f"{path}: cannot read the ranking ({exc}); check the path") from None
    _, n_skip = csv_preamble(lines, where=str(path), error=PlannerError)
    rows = list(csv.DictReader(lines[n_skip:], skipinitialspace=True))
    if not rows or "baseline" not in rows[0] or _SETUP_COLUMN not in rows[0]:
        return None
    marked = [r[_SETUP_COLUMN].strip() for r in rows
              if str(r["baseline"]).strip().lower() in ("true", "1", "yes")]
    if len(marked) != 1:
        raise PlannerError(
            f"{path}: column 'baseline' marks {len(marked)} setups ({', '.join(marked) or 'none'}); "
            "a ranking has one baseline: fix the column, or give --baseline")
    return marked[0]


def write_setups(setups, path, *, units="SI", overwrite=False):
    """Write setups as a setups CSV (``setup,LF,RF,LR,RR``), atomically.

    The first line is the unit marker ``# units: <units>``: shock ids have no unit, but
    every CSV shockplan writes says the unit system of the run that wrote it. Setups with
    bump stops or packers add the columns ``bump_stop_XX`` (``none`` for no stop) or
    ``packer_XX`` (in `units`), empty where a setup keeps the baseline's; without them
    the file is as before.

    Parameters
    ----------
    setups : iterable of Setup
        The setups, in order; names must be unique.
    path : str or path
        Output file.
    units : {"SI", "imperial"}
        The unit system of the run that writes the file (the marker).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    PlannerError
        On duplicate setup names.
    TypeError
        If an item is not a :class:`Setup`.
    FileExistsError
        If `path` exists and `overwrite` is false.
    """
    path = Path(path)
    setups = _check_setups(setups, f"write_setups {path}")
    check_can_write(path, overwrite=overwrite)
    buf = io.StringIO(newline="")
    writer = csv.writer(buf, lineterminator="\n")
    stops = any(s.bump_stops for s in setups)
    packers = any(s.packers_m for s in setups)
    writer.writerow((_SETUP_COLUMN, *CORNERS, *(_BUMP_COLUMNS if stops else ()),
                     *(_PACKER_COLUMNS if packers else ())))

    def cells(values, text):
        return [] if values is None else [text(values[c]) if c in values else ""
                                          for c in CORNERS]

    for s in setups:
        row = [s.name, *s.ids()]
        if stops:
            row += cells(s.bump_stops or {}, lambda v: NO_BUMP_STOP if v is None else v)
        if packers:
            row += cells(s.packers_m or {},
                         lambda v: repr(float(from_si(v, "displacement", units))))
        writer.writerow(row)
    write_csv(path, buf.getvalue(), units=units, overwrite=overwrite)
    logger.info("wrote %d setup(s) to %s", len(setups), path)
    return path


def setups_to_frame(setups):
    """Return setups as a table: index ``setup`` (names), columns ``LF RF LR RR``.

    Parameters
    ----------
    setups : iterable of Setup
        Names must be unique.

    Returns
    -------
    pandas.DataFrame, shape (setup, corner)
        Shock ids, in the order of `setups`.

    Raises
    ------
    PlannerError
        On duplicate setup names.
    """
    setups = _check_setups(setups, "setups_to_frame")
    frame = pd.DataFrame([s.ids() for s in setups], columns=list(CORNERS),
                         index=pd.Index([s.name for s in setups], name=_SETUP_COLUMN))
    return frame


# ----------------------------------------------------------------------------
# enumeration
# ----------------------------------------------------------------------------


def _corner_groups(symmetry, axles):
    """Return the groups of corners that share one shock id, in corner order."""
    if symmetry not in SYMMETRIES:
        raise PlannerError(f"enumerate_setups: symmetry={symmetry!r} is unknown; use one of "
                           f"{list(SYMMETRIES)}")
    if axles not in AXLE_MODES:
        raise PlannerError(f"enumerate_setups: axles={axles!r} is unknown; use one of "
                           f"{list(AXLE_MODES)}")
    parent = {c: c for c in CORNERS}

    def root(c):
        while parent[c] != c:
            c = parent[c]
        return c

    links = []
    if symmetry in ("left-right", "all"):
        links += [("LF", "RF"), ("LR", "RR")]
    if axles == "same" or symmetry == "all":
        links += [("LF", "LR"), ("RF", "RR")]
    for a, b in links:
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[rb] = ra
    groups = {}
    for c in CORNERS:
        groups.setdefault(root(c), []).append(c)
    return [tuple(g) for g in groups.values()]


def _id_list(values, what, library, where="enumerate_setups"):
    """Return `values` as a de-duplicated list of known ids (order kept)."""
    if isinstance(values, (str, bytes)) or not isinstance(values, Iterable):
        raise TypeError(f"{where}: {what} must be a list of shock ids, got "
                        f"{type(values).__name__} {values!r}")
    out = []
    for sid in values:
        if sid not in library:
            raise unknown_id_error(f"{where}: {what}", sid, library)
        sid = canonical_id(library, sid, f"{where}: {what}")
        if sid not in out:
            out.append(sid)
    if not out:
        raise PlannerError(f"{where}: {what} is empty; give at least one shock id")
    return out


def _corner_candidates(shocks, library):
    """Return corner -> candidate ids from the `shocks` argument."""
    all_ids = list(library)
    if shocks is None:
        return {c: all_ids for c in CORNERS}
    if not isinstance(shocks, Mapping):
        ids = _id_list(shocks, "shocks", library)
        return {c: ids for c in CORNERS}
    allowed = (*AXLES, *CORNERS)
    unknown = [k for k in shocks if k not in allowed]
    if unknown:
        raise PlannerError(f"enumerate_setups: shocks has the key {unknown[0]!r}; per-axle or "
                           f"per-corner candidates take keys from {list(allowed)}")
    out = {}
    for c in CORNERS:
        axle = "front" if c in AXLES["front"] else "rear"
        if c in shocks:
            out[c] = _id_list(shocks[c], f"shocks[{c!r}]", library)
        elif axle in shocks:
            out[c] = _id_list(shocks[axle], f"shocks[{axle!r}]", library)
        else:
            out[c] = all_ids
    return out


def _check_fixed(fixed, library, groups, symmetry, axles):
    """Return group index -> fixed id."""
    if fixed is None:
        return {}
    if not isinstance(fixed, Mapping):
        raise TypeError(f"enumerate_setups: fixed must be a mapping corner -> shock id, got "
                        f"{type(fixed).__name__}")
    out = {}
    for c, sid in fixed.items():
        if c not in CORNERS:
            raise PlannerError(f"enumerate_setups: fixed has the corner {c!r}; corners are "
                               f"{list(CORNERS)}")
        if sid not in library:
            raise unknown_id_error(f"enumerate_setups: fixed[{c!r}]", sid, library)
        sid = canonical_id(library, sid, f"enumerate_setups: fixed[{c!r}]")
        g = next(j for j, grp in enumerate(groups) if c in grp)
        if g in out and out[g][1] != sid:
            c0, sid0 = out[g]
            raise PlannerError(
                f"enumerate_setups: fixed {c0}={sid0!r} and {c}={sid!r} conflict: with "
                f"symmetry={symmetry!r} and axles={axles!r} corners {list(groups[g])} share "
                "one shock; fix them to the same id or use symmetry='none'")
        out[g] = (c, sid)
    return {g: sid for g, (_, sid) in out.items()}


def _inventory(library):
    """Return id -> count for the shocks with a finite count (an adjustable's settings share
    its count: they are one damper's)."""
    return {sid: int(m.count) for sid, m in library.items()
            if getattr(m, "count", None) is not None}


def inventory_shortfall(setup, library):
    """Say why a setup cannot be built from the crate's inventory, or return ``""``.

    Parameters
    ----------
    setup : Setup
    library : ShockLibrary
        Shocks with ``count = None`` are unlimited.

    Returns
    -------
    str
        ``""`` if every shock id of the setup has enough units, else e.g.
        ``"needs 4 x 'L28' but the library's count is 0"`` (ids joined by ``"; "``).

    Examples
    --------
    >>> from ident.models.library import ShockLibrary
    >>> from ident.models.shocks import LinearShock
    >>> lib = ShockLibrary([LinearShock("B20", 3500.0, count=2), LinearShock("L8", 1400.0)])
    >>> inventory_shortfall(Setup("x", dict(LF="B20", RF="B20", LR="B20", RR="L8")), lib)
    "needs 3 x 'B20' but the library's count is 2"
    """
    counts = _inventory(library)
    used = {}
    for sid in map(base_id, setup.ids()):
        used[sid] = used.get(sid, 0) + 1
    return "; ".join(f"needs {n} x {sid!r} but the library's count is {counts[sid]}"
                     for sid, n in used.items() if sid in counts and n > counts[sid])


def _name_maker(name_format):
    if callable(name_format):
        return lambda ids: name_format(dict(zip(CORNERS, ids)))
    if not isinstance(name_format, str):
        raise TypeError(f"enumerate_setups: name_format must be a str.format template or a "
                        f"callable, got {type(name_format).__name__}")
    if name_format == DEFAULT_NAME_FORMAT:
        return "/".join
    try:
        name_format.format(**dict(zip(CORNERS, CORNERS)))
    except (KeyError, IndexError, ValueError) as exc:
        raise PlannerError(f"enumerate_setups: name_format {name_format!r} is not a valid "
                           f"template ({type(exc).__name__}: {exc}); use the fields "
                           "{LF} {RF} {LR} {RR}") from None
    return lambda ids: name_format.format(LF=ids[0], RF=ids[1], LR=ids[2], RR=ids[3])


@contextlib.contextmanager
def _gc_paused():
    """Pause the cyclic garbage collector while building many small objects.

    Creating 10^5 setups triggers many full collections that find nothing (the
    objects hold no cycles); pausing makes the build about 3x faster.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def _make_named(id_rows, name_format, where):
    """Build setups from rows of 4 ids; raise if two names collide."""
    make_name = _name_maker(name_format)
    names = [make_name(ids) for ids in id_rows]
    if len(set(names)) != len(names):
        seen = {}
        for ids, name in zip(id_rows, names):
            if name in seen:
                raise PlannerError(f"{where}: name_format gives the same name {name!r} to "
                                   f"{list(seen[name])} and {list(ids)}; use a template with "
                                   "every corner that varies, e.g. the default "
                                   f"{DEFAULT_NAME_FORMAT!r}")
            seen[name] = ids
    with _gc_paused():
        return tuple(Setup._unchecked(n, ids) for n, ids in zip(names, id_rows))


@dataclass(frozen=True, eq=False)
class SetupSpace:
    """A set of setups held as integer codes, decoded chunk by chunk.

    Built by :func:`setup_space`. Candidate ``i`` of an enumeration is the mixed-radix
    number whose digits pick each corner group's candidate (the last group fastest), the
    order of :func:`enumerate_setups`; candidates the inventory cannot
    build are skipped when decoded (``respect_inventory``), so the setups decoded in order
    are exactly the enumerated ones. A space from a list holds its codes and names.

    Attributes
    ----------
    shock_ids : tuple of str
        Code ``j`` is ``shock_ids[j]`` (the library's order).
    group_codes : tuple of ndarray of int
        Per corner group, the codes of its candidates (empty for a list).
    corner_group : tuple of int, shape (4,)
        The group of each corner ``LF RF LR RR``.
    inventory : tuple of (tuple of int, int)
        ``(codes, count)`` per shock with a count: a candidate using more than ``count`` of
        ``codes`` (one fixed shock, or an adjustable's settings) is skipped (empty for a
        list or ``respect_inventory=False``).
    listed_codes : ndarray of int, shape (n_setups, 4), or None
        The codes of a given list of setups.
    listed_names : tuple of str, or None
    name_format : str or callable
        The names of generated setups (:func:`enumerate_setups`).
    """

    shock_ids: tuple
    group_codes: tuple
    corner_group: tuple
    inventory: tuple
    listed_codes: np.ndarray | None
    listed_names: tuple | None
    name_format: object

    def __len__(self):
        """Number of candidates (before the inventory filter of an enumeration)."""
        if self.listed_codes is not None:
            return int(self.listed_codes.shape[0])
        return int(math.prod(len(g) for g in self.group_codes))

    @property
    def sizes(self):
        """Candidates per corner group (mixed-radix digits, the last fastest)."""
        return tuple(len(g) for g in self.group_codes)

    @property
    def groups(self):
        """The corners of each group (that share one shock), in group order."""
        return tuple(tuple(c for c, g in zip(CORNERS, self.corner_group) if g == k)
                     for k in range(len(self.group_codes)))

    def chunk(self, start, stop):
        """Decode candidates ``start <= i < stop``.

        Parameters
        ----------
        start, stop : int
            A range of candidate indices.

        Returns
        -------
        index : ndarray of int64, shape (n,)
            The candidates kept (the inventory filter drops some), increasing.
        codes : ndarray of intp, shape (n, 4)
            Their shock codes per corner ``LF RF LR RR``.
        """
        start, stop = max(int(start), 0), min(int(stop), len(self))
        idx = np.arange(start, max(start, stop), dtype=np.int64)
        if self.listed_codes is not None:
            return idx, self.listed_codes[idx]
        digits = [None] * len(self.group_codes)
        rest = idx.copy()
        for g in range(len(self.group_codes) - 1, -1, -1):
            size = len(self.group_codes[g])
            digits[g] = rest % size
            rest //= size
        group_vals = [np.asarray(self.group_codes[g], dtype=np.intp)[digits[g]]
                      for g in range(len(self.group_codes))]
        codes = np.stack([group_vals[g] for g in self.corner_group], axis=1)
        if self.inventory:
            keep = np.ones(idx.size, dtype=bool)
            for code, count in self.inventory:
                hit = codes == code[0] if len(code) == 1 else np.isin(codes, code)
                keep &= hit.sum(axis=1) <= count
            idx, codes = idx[keep], codes[keep]
        return idx, codes

    def first(self, *, chunk_size=20_000):
        """The first candidate the inventory keeps (None if none), decoded chunk by chunk."""
        for start in range(0, len(self), chunk_size):
            index, _ = self.chunk(start, start + chunk_size)
            if index.size:
                return int(index[0])
        return None

    def ids(self, index):
        """Shock ids of candidates.

        Parameters
        ----------
        index : sequence of int
            Candidate indices.

        Returns
        -------
        list of tuple of str
            Per candidate, the ids at ``LF RF LR RR``.
        """
        index = np.asarray(index, dtype=np.int64)
        codes = self._codes_at(index)
        ids = np.asarray(self.shock_ids, dtype=object)
        return [tuple(row) for row in ids[codes].tolist()]

    def _codes_at(self, index):
        if self.listed_codes is not None:
            return self.listed_codes[index]
        rest = index.copy()
        vals = [None] * len(self.group_codes)
        for g in range(len(self.group_codes) - 1, -1, -1):
            size = len(self.group_codes[g])
            vals[g] = np.asarray(self.group_codes[g], dtype=np.intp)[rest % size]
            rest //= size
        return np.stack([vals[g] for g in self.corner_group], axis=1).reshape(-1, 4)

    def names(self, index):
        """Names of candidates (the list's names, or generated by `name_format`).

        Parameters
        ----------
        index : sequence of int

        Returns
        -------
        list of str
        """
        if self.listed_names is not None:
            return [self.listed_names[int(i)] for i in index]
        make = _name_maker(self.name_format)
        return [make(ids) for ids in self.ids(index)]

    def setups(self, index):
        """The :class:`Setup` objects of candidates.

        Parameters
        ----------
        index : sequence of int

        Returns
        -------
        tuple of Setup
        """
        return tuple(Setup._unchecked(n, ids)
                     for n, ids in zip(self.names(index), self.ids(index)))

    def find(self, ids):
        """The candidate index of a setup's shock ids, or None when not in the space.

        Parameters
        ----------
        ids : sequence of str, shape (4,)
            Ids at ``LF RF LR RR``.

        Returns
        -------
        int or None
            None also for a candidate the inventory filter skips.
        """
        code_of = {sid: j for j, sid in enumerate(self.shock_ids)}
        if any(sid not in code_of for sid in ids):
            return None
        codes = np.array([code_of[sid] for sid in ids], dtype=np.intp)
        if self.listed_codes is not None:
            hit = np.flatnonzero((self.listed_codes == codes).all(axis=1))
            return int(hit[0]) if hit.size else None
        index = 0
        for g, cand in enumerate(self.group_codes):
            corners = [c for c in range(4) if self.corner_group[c] == g]
            if len({int(codes[c]) for c in corners}) != 1:
                return None
            where = np.flatnonzero(np.asarray(cand) == codes[corners[0]])
            if not where.size:
                return None
            index = index * len(cand) + int(where[0])
        got_index, _ = self.chunk(index, index + 1)
        return index if got_index.size else None


def setup_space(library, *, setups=None, symmetry="left-right", axles="independent",
                fixed=None, shocks=None, respect_inventory=True,
                name_format=DEFAULT_NAME_FORMAT, clicks=None, where="setup_space"):
    """The setups of an enumeration (decoded lazily) or of a given list, as integer codes.

    The one enumeration: :func:`enumerate_setups` decodes the whole space at once,
    :func:`planner.sweep.sweep_setups` chunk by chunk.

    Parameters
    ----------
    library : ident.models.library.ShockLibrary
        The crate; its ``count`` is the inventory.
    setups : sequence of planner.setups.Setup, optional
        A given list (unique names); then the enumeration options must stay at their
        defaults.
    symmetry, axles, fixed, shocks, respect_inventory, name_format, clicks
        As :func:`enumerate_setups` (which decodes this space, in its order and with
        its names); there is no ``max_setups``: a space may be large. Setting names get
        codes after the library's ids.
    where : str
        The caller named at the start of the errors.

    Returns
    -------
    SetupSpace

    Raises
    ------
    PlannerError
        As :func:`enumerate_setups`; on an unknown shock id in a listed
        setup; or on a list given with enumeration options.
    """
    all_ids = _library_ids(library, where)
    if not all_ids:
        raise PlannerError(f"{where}: the shock library is empty; add shocks to it")
    code_of = {sid: j for j, sid in enumerate(all_ids)}
    if setups is not None:
        if (symmetry, axles, fixed, shocks, clicks) != ("left-right", "independent", None,
                                                        None, None):
            raise PlannerError(f"{where}: give either setups or enumeration options "
                               "(symmetry, axles, fixed, shocks, clicks), not both")
        setups = _check_setups(setups, where)
        if not setups:
            raise PlannerError(f"{where}: no setups given; give at least one setup")
        for s in setups:
            s.resolve(library)
            for sid in s.ids():  # setting names: codes after the library's ids
                code_of.setdefault(sid, len(code_of))
        all_ids = list(code_of)
        codes = np.array([[code_of[sid] for sid in s.ids()] for s in setups], dtype=np.intp)
        return SetupSpace(shock_ids=tuple(all_ids), group_codes=(), corner_group=(),
                          inventory=(), listed_codes=codes,
                          listed_names=tuple(s.name for s in setups), name_format=None)
    _name_maker(name_format)  # a bad template fails here, not on a worker
    groups = _corner_groups(symmetry, axles)
    fixed_by_group = _check_fixed(fixed, library, groups, symmetry, axles)
    per_corner = _corner_candidates(shocks, library)
    steps = click_steps(clicks, library, where)
    if steps:  # each adjustable id among the candidates: its settings' names
        per_corner = {c: expand_candidates(ids, library, steps, where)
                      for c, ids in per_corner.items()}
    group_codes = []
    for g, grp in enumerate(groups):
        if g in fixed_by_group:
            cand = [fixed_by_group[g]]
        else:
            cand = [sid for sid in per_corner[grp[0]]
                    if all(sid in per_corner[c] for c in grp[1:])]
            if not cand:
                raise PlannerError(f"{where}: corners {list(grp)} share one shock but their "
                                   "candidate lists have no id in common; give the same ids "
                                   "for both axles or use axles='independent'")
        group_codes.append(np.array([code_of.setdefault(sid, len(code_of)) for sid in cand],
                                    dtype=np.intp))
    all_ids = list(code_of)
    corner_group = tuple(next(g for g, grp in enumerate(groups) if c in grp) for c in CORNERS)
    counts = _inventory(library) if respect_inventory else {}
    inventory = tuple((tuple(j for sid, j in code_of.items() if base_id(sid) == b), n)
                      for b, n in counts.items())
    if name_format == DEFAULT_NAME_FORMAT:
        name_format = DEFAULT_NAME_FORMAT
    return SetupSpace(shock_ids=tuple(all_ids), group_codes=tuple(group_codes),
                      corner_group=corner_group, inventory=inventory, listed_codes=None,
                      listed_names=None, name_format=name_format)




def enumerate_setups(library, *, symmetry="left-right", axles="independent", fixed=None,
                     shocks=None, respect_inventory=True, max_setups=DEFAULT_MAX_SETUPS,
                     name_format=DEFAULT_NAME_FORMAT, clicks=None):
    """Enumerate the setups that can be built from a shock library.

    Parameters
    ----------
    library : ShockLibrary or mapping of str to ShockModel
        The team's shocks; their ``count`` is the inventory.
    symmetry : {"left-right", "all", "none"}
        ``"left-right"``: the left and right corners of an axle get the same
        shock (LF = RF, LR = RR). ``"all"``: every corner gets the same shock
        (left-right with ``axles="same"``; the name
        :func:`planner.optimize.optimize_curves` uses for one curve at every
        corner). ``"none"``: every corner independent.
    axles : {"independent", "same"}
        ``"same"``: the rear corners get the same shocks as the front ones
        (LR = LF, RR = RF); with left-right symmetry all four are equal (as
        ``symmetry="all"``, whatever `axles`).
    fixed : mapping of str to str, optional
        Corner -> shock id for corners that do not vary. A fixed corner fixes
        every corner that shares its shock (RF with LF under left-right
        symmetry); two fixed corners of one such group must agree.
    shocks : sequence of str, or mapping, optional
        Candidate ids (default: every id in the library, in library order).
        A sequence applies to every corner; a mapping takes keys ``"front"``,
        ``"rear"`` and/or corners (a corner key overrides its axle), and
        corners not covered use every id. Corners sharing a shock use the
        ids common to their lists, in the order of the first corner's list.
        Fixed corners ignore `shocks`.
    respect_inventory : bool
        Skip setups that need more units of a shock than its ``count`` (e.g.
        one id at 3 corners with ``count = 2``); a count of ``None`` is
        unlimited.
    max_setups : int or None
        Refuse to enumerate more candidate setups than this (counted before
        the inventory filter, since that is the work done); ``None`` is no
        limit. Default :data:`DEFAULT_MAX_SETUPS` (100,000).
    name_format : str or callable
        ``str.format`` template with the fields ``{LF} {RF} {LR} {RR}``
        (default ``"{LF}/{RF}/{LR}/{RR}"``, e.g. ``"B20/B20/D8/D8"``), or a
        callable taking the dict corner -> id and returning the name.
    clicks : None, "all" or mapping
        Enumerate the settings of adjustable shocks (:mod:`planner.clicks`): None keeps an
        adjustable id as one candidate (its default); ``"all"`` expands each adjustable
        candidate into its settings grid; ``{"ls": 2}`` steps per adjuster, ``{"TTX":
        "all"}`` per shock. Names are canonical, ``TTX@ls=6,hs=2``; counts per base id.

    Returns
    -------
    tuple of Setup
        In a deterministic order: the product of the corner groups' candidate
        lists, groups ordered by their first corner (LF first), the last group
        varying fastest.

    Raises
    ------
    PlannerError
        On an unknown symmetry, axle mode, corner, shock id, or ``shocks``
        key; an empty candidate list; conflicting fixed corners; more
        candidate setups than `max_setups`; no setup left after the inventory
        filter; or two setups given the same name by `name_format`.
    TypeError
        If `library`, `fixed` or `shocks` has the wrong type.

    Notes
    -----
    The ids are built as integer arrays and filtered by inventory with numpy,
    so the cost is linear in the number of candidate setups (about 1.5 s per
    million); building the :class:`Setup` objects dominates.

    Examples
    --------
    >>> from ident.models.library import ShockLibrary
    >>> from ident.models.shocks import LinearShock
    >>> lib = ShockLibrary.from_models([LinearShock(f"S{k}", 1000.0 * k) for k in range(1, 11)])
    >>> len(enumerate_setups(lib)), len(enumerate_setups(lib, symmetry="none"))
    (100, 10000)
    >>> enumerate_setups(lib, fixed={"LR": "S1"}, shocks={"front": ["S2", "S3"]})[1].name
    'S3/S3/S1/S1'
    """
    where = "enumerate_setups"
    space = setup_space(library, symmetry=symmetry, axles=axles, fixed=fixed, shocks=shocks,
                        respect_inventory=respect_inventory, name_format=name_format,
                        clicks=clicks, where=where)
    n_total = len(space)
    if max_setups is not None:
        if isinstance(max_setups, bool) or not isinstance(max_setups, (int, np.integer)) \
                or max_setups < 1:
            raise PlannerError(f"{where}: max_setups={max_setups!r} must be a positive "
                               "integer or None")
        if n_total > max_setups:
            detail = " x ".join(f"{n} ({'='.join(grp)})"
                                for n, grp in zip(space.sizes, space.groups))
            raise PlannerError(
                f"{where}: {n_total:,} candidate setups ({detail}) exceed "
                f"max_setups={max_setups:,}; use symmetry='left-right', fix corners, restrict "
                "the candidates with shocks=..., or raise max_setups")
    # integer codes into the library's ids, (setup, corner), the last group fastest; the
    # space skips what the inventory cannot build
    index, codes = space.chunk(0, n_total)
    if respect_inventory:
        if not index.size:
            raise PlannerError(f"{where}: none of the {n_total:,} candidate setups fits the "
                               "inventory (shock counts in the library); raise the counts, "
                               "choose other shocks or pass respect_inventory=False")
        n_skipped = int(n_total - index.size)
        if n_skipped:
            logger.info("%s: skipped %d of %d setups that need more shocks than the "
                        "inventory has", where, n_skipped, n_total)
    ids_arr = np.asarray(space.shock_ids, dtype=object)
    with _gc_paused():
        id_rows = list(map(tuple, ids_arr[codes].tolist()))
    return _make_named(id_rows, name_format, where)


def _fits_inventory(ids, inventory):
    ids = [base_id(sid) for sid in ids]
    return all(ids.count(sid) <= n for sid, n in inventory.items() if sid in ids)


def setups_from_baseline(baseline, library, *, corners=CORNERS, shocks=None,
                         respect_inventory=True, include_baseline=True):
    """Every single-corner (or single-axle) swap from a baseline setup.

    Useful for "next run" suggestions: each candidate differs from the
    baseline at one corner, or at one axle with both corners given the same
    shock.

    Parameters
    ----------
    baseline : Setup
        The car's current setup; its ids must be in `library`.
    library : ShockLibrary or mapping of str to ShockModel
        The team's shocks; their ``count`` is the inventory.
    corners : sequence of str
        What to swap: corners (``"LF"``, ...) and/or axles (``"front"``,
        ``"rear"``, both corners of the axle to the same shock). Default the
        four corners.
    shocks : sequence of str, optional
        Candidate ids (default every id in the library).
    respect_inventory : bool
        Skip swaps whose setup needs more units of a shock than its count.
    include_baseline : bool
        Put the baseline first (the objective's default normalization).

    Returns
    -------
    tuple of Setup
        The baseline (if included), then for each item of `corners` in order,
        each candidate id in order. Swaps equal to the baseline or to an
        earlier swap are dropped. Names are ``"<baseline> LF=D8"`` and
        ``"<baseline> front=D8"``.

    Raises
    ------
    PlannerError
        On an unknown corner or axle, an unknown id, or a baseline id not in
        the library.
    TypeError
        If `baseline` is not a :class:`Setup` or `library` not a mapping.
    """
    where = "setups_from_baseline"
    if not isinstance(baseline, Setup):
        raise TypeError(f"{where}: baseline must be a Setup, got {type(baseline).__name__}")
    _library_ids(library, where)
    baseline.resolve(library)
    if isinstance(corners, str):
        corners = (corners,)
    units = []
    for unit in corners:
        if unit in CORNERS:
            units.append((unit, (unit,)))
        elif unit in AXLES:
            units.append((unit, AXLES[unit]))
        else:
            raise PlannerError(f"{where}: corners has {unit!r}; give corners "
                               f"{list(CORNERS)} or axles {list(AXLES)}")
    cand = list(library) if shocks is None else _id_list(shocks, "shocks", library, where)
    inventory = _inventory(library) if respect_inventory else {}
    base_ids = baseline.ids()
    out = [baseline] if include_baseline else []
    seen = {base_ids}
    for label, unit_corners in units:
        for sid in cand:
            ids = tuple(sid if c in unit_corners else b for c, b in zip(CORNERS, base_ids))
            if ids in seen or not _fits_inventory(ids, inventory):
                continue
            seen.add(ids)
            out.append(Setup._unchecked(f"{baseline.name} {label}={sid}", ids))
    return tuple(out)


# ----------------------------------------------------------------------------
# the baseline
# ----------------------------------------------------------------------------


def resolve_baseline(baseline, library, *, setups=(), default=None, find=None,
                     name="baseline", where=None):
    """The baseline setup of a command, from its one syntax.

    Every command takes its baseline the same way: a :class:`Setup`, the name of a
    listed setup, one shock id (at every corner) or four ids ``"LF,RF,LR,RR"``
    separated by commas (spaces around them ignored). ``"A/B/C/D"`` is refused with
    a message to use commas (unless it is a listed setup's name).

    Parameters
    ----------
    baseline : Setup, str, sequence of str, or None
        The baseline as given; a sequence holds one shock id or four (LF, RF, LR, RR).
        None takes `default`.
    library : ShockLibrary or mapping of str to ShockModel
        The crate; the baseline's ids must be in it.
    setups : sequence of Setup
        The listed setups (the candidates). A name picks one; a baseline with the
        shocks of one (and not the name of another) is that one, so that no second
        row holds the same shocks.
    default : str or Setup, optional
        Taken when `baseline` is None (e.g. the objective's ``baseline``), read the
        same way.
    find : callable, optional
        ``find(ids) -> Setup or None``: the candidate with the shock ids ``ids``
        (tuple, corner order), for candidates that are not listed (a sweep's lazy
        enumeration). Default: the first listed setup with these ids.
    name : str or callable
        The name of a setup built from shock ids (default ``"baseline"``); a callable
        gets the ids as given (a list of one or four) and returns the name (a sweep
        names them ``"all-B20"`` or ``"B20/B20/D8/D8"``).
    where : str, optional
        The command or argument named at the start of the errors.

    Returns
    -------
    Setup or None
        The baseline: a listed (or found) setup, or a setup to add to the candidates.
        With neither `baseline` nor `default`: the first listed setup, or None when
        none is listed.

    Raises
    ------
    PlannerError
        On a name that is neither a listed setup nor a shock id, ids separated by
        ``/``, a count of ids other than one or four, an unknown shock id, or a
        baseline setup with the name of a listed setup but other shocks.
    TypeError
        If `baseline` is of another type.

    Examples
    --------
    >>> from ident.models.library import ShockLibrary
    >>> from ident.models.shocks import LinearShock
    >>> lib = ShockLibrary.from_models([LinearShock("B20", 3502.5), LinearShock("D8", 1400.0)])
    >>> resolve_baseline("B20", lib).ids()
    ('B20', 'B20', 'B20', 'B20')
    >>> resolve_baseline("D8, D8, B20, B20", lib).name
    'baseline'
    >>> listed = enumerate_setups(lib)
    >>> resolve_baseline("D8,D8,B20,B20", lib, setups=listed).name   # the listed setup
    'D8/D8/B20/B20'
    """
    pre = f"{where}: " if where else ""
    names = [s.name for s in setups]
    if baseline is None:
        baseline = default
    if baseline is None:
        return setups[0] if len(setups) else None
    if isinstance(baseline, Setup):
        setup = baseline
    elif isinstance(baseline, str):
        if baseline in names:
            return setups[names.index(baseline)]
        if baseline in library and "@" not in baseline:
            given = [baseline]
        elif "," in baseline or baseline in library:  # commas of TTX@ls=6,hs=2 kept
            given = split_shock_ids(baseline)
        elif "/" in baseline:
            raise PlannerError(f"{pre}baseline {baseline!r}: separate the shock ids with "
                               f"commas, {baseline.replace('/', ',')!r} (LF,RF,LR,RR)")
        elif names:
            raise PlannerError(f"{pre}baseline setup {baseline!r} is not among the setups, nor "
                               f"a shock id; name one of the setups (e.g. {names[0]!r}), give "
                               "one shock id (every corner) or four (LF,RF,LR,RR), or pass the "
                               "baseline setup")
        else:
            raise PlannerError(f"{pre}baseline {baseline!r} is neither a shock id nor four ids "
                               f"LF,RF,LR,RR; {_lib_label(library)} has {list(library)}; give "
                               "one shock id (every corner) or four separated by commas")
        setup = _baseline_from_ids([canonical_id(library, s, f"{pre}baseline") for s in given],
                                   name, pre)
    elif isinstance(baseline, (list, tuple)) and all(isinstance(s, str) for s in baseline):
        setup = _baseline_from_ids([canonical_id(library, s, f"{pre}baseline")
                                    for s in baseline], name, pre)
    else:
        raise TypeError(f"{pre}baseline must be a Setup, a setup name or shock ids (str), got "
                        f"{type(baseline).__name__}")
    setup.resolve(library)
    if setup.name in names:
        listed = setups[names.index(setup.name)]
        if listed.ids() != setup.ids():
            raise PlannerError(
                f"{pre}baseline setup {setup.name!r} ({'/'.join(setup.ids())}) has the name of "
                f"a listed setup with other shocks ({'/'.join(listed.ids())}); rename the "
                "baseline or pass its name to use the listed one")
        return listed
    ids = setup.ids()
    found = find(ids) if find is not None else next((s for s in setups if s.ids() == ids), None)
    if found is not None:
        if found.name != setup.name:
            logger.info("baseline %s is the listed setup %r; using it", "/".join(ids),
                        found.name)
        return found  # the listed setup: no second row with the same shocks
    return setup


def _baseline_from_ids(given, name, pre):
    """A baseline Setup from one shock id (every corner) or four, named by `name`."""
    if len(given) not in (1, 4):
        raise PlannerError(f"{pre}baseline {','.join(given)!r}: give one shock id (every "
                           "corner) or four (LF,RF,LR,RR)")
    ids = given * 4 if len(given) == 1 else given
    label = name(list(given)) if callable(name) else name
    return Setup(label, dict(zip(CORNERS, ids)))
