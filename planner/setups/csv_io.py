"""Setups files: the setups CSV read and written, setups as a table, a ranking's baseline.

The format (``setup,LF,RF,LR,RR``, optional ``bump_stop_XX`` / ``packer_XX`` columns) is
described in :mod:`planner.setups`.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import re
from pathlib import Path

import pandas as pd

from ident.data.files import (UNITS_COLUMN, check_can_write, csv_preamble, resolve_units,
                              units_of_column, write_csv)
from ident.data.channels import CORNERS
from ident.data.third import AXLES, THIRD_ELEMENTS
from ident.data.units import UNIT_LABELS, from_si, to_si
from ident.models.bumpstops import NO_BUMP_STOP, BumpStopLibrary, check_packer, parse_bump_stop_id
from planner.click_settings import canonical_id
from planner.errors import PlannerError
from planner.setups.setup import Setup, check_setups, library_ids, unknown_id_error

__all__ = [
    "read_setups",
    "read_ranking_baseline",
    "write_setups",
    "setups_to_frame",
]

logger = logging.getLogger(__name__)

_SETUP_COLUMN = "setup"
_CORNER_LIKE = re.compile(r"^[A-Za-z]{2}$")
#: The optional columns of a setups CSV: bump stop and packer per corner.
_BUMP_COLUMNS = tuple(f"bump_stop_{c}" for c in CORNERS)
_PACKER_COLUMNS = tuple(f"packer_{c}" for c in CORNERS)
#: The optional columns of the third elements (the spec's "Third elements"): a damper per
#: element, a heave spring per axle.
_THIRD_COLUMNS = THIRD_ELEMENTS
_HEAVE_SPRING_COLUMNS = tuple(f"heave_spring_{a}" for a in AXLES)
#: A misspelt one (case, separators, plural, FL for LF), refused; a longer name that
#: merely starts alike (a metric such as bump_stop_share_LF) is another column.
_ELEMENT_LIKE = re.compile(r"^(bumpstops?|bumps?|packers?)(lf|rf|lr|rr|fl|fr|rl)$")
_CORNER_ALIASES = {"fl": "LF", "fr": "RF", "rl": "LR"}


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
        The unit system of ``packer_XX`` when the file has no unit marker (a ``units``
        column or a ``# units:`` line; default SI); a marker that says otherwise is an
        error.

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
    Third elements (the spec's "Third elements"): optional columns ``heave_front``,
    ``heave_rear``, ``roll_front``, ``roll_rear`` (a damper id or setting name, checked
    against `library`, or ``none``) and ``heave_spring_front``, ``heave_spring_rear`` (a
    bump-stop id, checked against `bump_stops`, or ``none``) give
    :attr:`Setup.third` and :attr:`Setup.heave_springs`; an empty cell keeps the baseline
    run's.

    Columns other than ``setup``, the corners, ``bump_stop_XX`` / ``packer_XX`` and the
    third elements' are ignored (so a predictions CSV reads as a setups file). In ``bump_stop_XX``,
    ``none`` (any case) is no bump stop; an empty ``bump_stop_XX`` or ``packer_XX``
    cell keeps the baseline run's (:attr:`Setup.bump_stops` and
    :attr:`Setup.packers_m` hold only the corners a row gives). Leading ``#``
    comment lines (the earlier layout's unit marker ``# units: ...``) are skipped; a
    ``units`` column (``SI`` or ``imperial`` on every row, what shockplan writes) says
    the unit system of the packers, as the marker line did. Line numbers are the file's
    (the header is line 1 unless comment lines precede it).
    """
    path = Path(path)
    if library is not None:
        library_ids(library, f"read_setups {path}")
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
    reader = csv.reader(io.StringIO(body, newline=""), skipinitialspace=True)
    header = None
    for header in reader:
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
    i_third = {e: header.index(e) for e in _THIRD_COLUMNS if e in header}
    i_spring = {a: header.index(k) for a, k in zip(AXLES, _HEAVE_SPRING_COLUMNS) if k in header}
    rows = [(n_skip + reader.line_num, cells) for cells in reader]
    if UNITS_COLUMN in header:  # the unit system, not a setup's column
        i_units = header.index(UNITS_COLUMN)
        marked = units_of_column((cells[i_units] for _, cells in rows if len(cells) > i_units),
                                 marker=marked, where=str(path), error=PlannerError)
    packer_units = resolve_units(marked, units, where=str(path), error=PlannerError) \
        if i_packer else None
    out = []
    lines = {}
    for line, cells in rows:
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
        if not i_stop and not i_packer and not i_third and not i_spring:
            out.append(Setup._unchecked(name, ids))
            continue
        stops, packers = _row_elements(cells, i_stop, i_packer, bump_stops, packer_units,
                                       where)
        third, springs = _row_third(cells, i_third, i_spring, library, bump_stops, where)
        out.append(Setup(name, dict(zip(CORNERS, ids)), bump_stops=stops or None,
                         packers_m=packers or None, third=third or None,
                         heave_springs=springs or None))
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


def _row_third(cells, i_third, i_spring, library, bump_stops, where):
    """The third elements' dampers and heave springs a setups CSV row gives (empty cells
    left out; ``none`` is none)."""
    third, springs = {}, {}
    for e, i in i_third.items():
        if not cells[i]:
            continue
        col = f"{where}: column {e!r}"
        if cells[i].lower() == NO_BUMP_STOP:
            third[e] = None
            continue
        sid = cells[i]
        if library is not None:
            if sid not in library:
                raise unknown_id_error(col, sid, library)
            sid = canonical_id(library, sid, col)
        third[e] = sid
    for a, i in i_spring.items():
        if not cells[i]:
            continue
        col = f"{where}: column 'heave_spring_{a}'"
        springs[a] = sid = parse_bump_stop_id(cells[i], col, error=PlannerError)
        if sid is not None and bump_stops is not None and sid not in bump_stops:
            raise bump_stops.unknown_id_error(sid, where=col, error=PlannerError)
    return third, springs


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

    The last column is ``units`` (`units` on every row): shock ids have no unit, but
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
    setups = check_setups(setups, f"write_setups {path}")
    check_can_write(path, overwrite=overwrite)
    buf = io.StringIO(newline="")
    writer = csv.writer(buf, lineterminator="\n")
    stops = any(s.bump_stops for s in setups)
    packers = any(s.packers_m for s in setups)
    third = [e for e in THIRD_ELEMENTS if any(s.third and e in s.third for s in setups)]
    springs = [a for a in AXLES if any(s.heave_springs and a in s.heave_springs
                                       for s in setups)]
    writer.writerow((_SETUP_COLUMN, *CORNERS, *(_BUMP_COLUMNS if stops else ()),
                     *(_PACKER_COLUMNS if packers else ()), *third,
                     *(f"heave_spring_{a}" for a in springs)))

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
        for key, given in ((third, s.third or {}), (springs, s.heave_springs or {})):
            row += [("" if k not in given else NO_BUMP_STOP if given[k] is None else given[k])
                    for k in key]
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
    setups = check_setups(setups, "setups_to_frame")
    frame = pd.DataFrame([s.ids() for s in setups], columns=list(CORNERS),
                         index=pd.Index([s.name for s in setups], name=_SETUP_COLUMN))
    return frame
