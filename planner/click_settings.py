"""Rank in clicks: adjustable shocks' settings as setup candidates, their names and columns.

An adjustable shock of the library (spec "Adjustable shocks",
:class:`ident.models.adjustable.AdjustableShock`) stands in a setup by a setting name,
``"TTX@ls=6,hs=2"``. This module holds what the planner needs to enumerate, name and
tabulate such settings; :func:`planner.setups.setup_space` and
:func:`planner.setups.enumerate_setups` take its ``clicks`` option:

- ``clicks=None`` (the default): an adjustable id is one candidate, its default setting
  (as before);
- ``clicks="all"``: every adjustable id among the candidates becomes every setting of its
  grid (:meth:`~ident.models.adjustable.AdjustableShock.settings_grid`, the adjusters'
  own steps);
- ``clicks={"ls": 2, "hs": 1}``: the same on a coarser grid, a step per adjuster name
  (adjusters not named keep their own step); ``clicks={"TTX": {"ls": 2}, "DDX": "all"}``:
  per adjustable id (only the ids named are expanded).

The expansion is per corner group, so the symmetry options apply as for shocks: left-right
symmetric (the default) gives ``n_settings`` candidates per axle. Sizes grow fast: a
2-adjuster damper with 21 x 17 settings has 357 names, ``357^2 = 127,449`` setups per axle
symmetric; :func:`planner.sweep.sweep_setups` decodes them lazily, and ``rank`` screens all
and simulates only the best (``top``).

Setting names are canonical (:meth:`ident.models.library.ShockLibrary.canonical_name`:
every adjuster, in declaration order), so ``"TTX@hs=2,ls=6"`` and ``"TTX@ls=6,hs=2"`` are
one shock; the inventory counts units per base id (four corners on TTX settings use four TTX
units, :func:`base_id`). Tables gain one column per adjuster per corner,
``LF_ls, LF_hs, ...`` (:func:`adjuster_columns`), after the spec's columns.

Examples
--------
>>> base_id("TTX@ls=6,hs=2"), base_id("B20")
('TTX', 'B20')
>>> split_shock_ids("B20, TTX@ls=6,hs=2, D8")
['B20', 'TTX@ls=6,hs=2', 'D8']
>>> parse_click_step("ls=2,hs=0.5")
{'ls': 2.0, 'hs': 0.5}
>>> adjuster_columns(pd.DataFrame({"LF": ["TTX@ls=6,hs=2"], "RF": ["B20"], "LR": ["B20"],
...                                "RR": ["B20"]})).to_dict("list")
{'LF_ls': [6], 'LF_hs': [2]}
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping

import numpy as np
import pandas as pd

from ident.data.channels import CORNERS
from ident.errors import ShockModelError
from ident.models.adjustable import parse_shock_name
from ident.models.shocks import is_real_number
from planner.errors import PlannerError

__all__ = [
    "click_values",
    "click_neighbours",
    "CLICKS_ALL",
    "MAX_CLICK_SETUPS",
    "base_id",
    "canonical_id",
    "click_steps",
    "expand_candidates",
    "split_shock_ids",
    "parse_click_step",
    "clicks_option",
    "add_click_arguments",
    "adjuster_columns",
]

#: The ``clicks`` value that enumerates every setting of every adjustable candidate.
CLICKS_ALL = "all"
#: Guard of ``rank --clicks`` on the number of candidate setups (screened in one process;
#: about 10 s per 10^5 on a laptop core); ``sweep`` has no guard (lazy, chunked).
MAX_CLICK_SETUPS = 500_000


def base_id(name):
    """The library entry's id of a shock name: ``"TTX@ls=6"`` -> ``"TTX"`` (others as given).

    Parameters
    ----------
    name : str

    Returns
    -------
    str
    """
    return name.partition("@")[0].strip() if isinstance(name, str) else name


def canonical_id(library, name, where):
    """A shock name checked and written canonically (plain ids and non-libraries unchanged).

    Parameters
    ----------
    library : ShockLibrary or mapping
        The crate; a plain mapping (no adjustable shocks) leaves `name` as is.
    name : str
        ``"TTX@hs=2,ls=6"`` or a plain id.
    where : str
        Who gives the name (a setups file, row and corner; an option), the message's start.

    Returns
    -------
    str
        ``"TTX@ls=6,hs=2"``: every adjuster, in declaration order.

    Raises
    ------
    PlannerError
        On an unknown adjuster, a setting out of range or off its steps, or settings on a
        fixed shock, naming `where`, the shock, the adjuster and the setting.
    """
    if not isinstance(name, str) or "@" not in name or not hasattr(library, "canonical_name"):
        return name
    try:
        return library.canonical_name(name, where=where)
    except ShockModelError as exc:
        msg = str(exc)
        raise PlannerError(msg if msg.startswith(where) else f"{where}: {msg}") from None


def _step_value(value, what, where):
    if isinstance(value, bool) or not is_real_number(value) or not float(value) > 0 \
            or not math.isfinite(float(value)):
        raise PlannerError(f"{where}: clicks {what} = {value!r} is not a step; give a number "
                           "> 0 of clicks or turns (a multiple of the adjuster's resolution)")
    return float(value)


def click_steps(clicks, library, where="enumerate_setups"):
    """The grid step of each adjustable shock to enumerate, from the ``clicks`` option.

    Parameters
    ----------
    clicks : None, "all", or mapping
        None: no expansion. ``"all"``: every adjustable shock, its own steps. A mapping of
        adjuster name -> step (every adjustable shock with that adjuster), or of adjustable
        id -> ``"all"`` or {adjuster: step} (only the ids named).
    library : ShockLibrary
    where : str
        The caller, first in error messages.

    Returns
    -------
    dict of str to dict
        Adjustable id -> its step per adjuster (empty: its own steps); empty for None.

    Raises
    ------
    PlannerError
        On an unknown key (neither an adjustable id nor an adjuster), a step that is not a
        positive number, or ``clicks`` given with a library without adjustable shocks.
    TypeError
        On another type.
    """
    if clicks is None or clicks is False:
        return {}
    adjustable = tuple(getattr(library, "adjustable_ids", ()))
    if not adjustable:
        raise PlannerError(f"{where}: clicks={clicks!r} but the shock library has no adjustable "
                           "shock (kind = \"adjustable\"); leave clicks out or add one")
    entries = {sid: library.adjustable(sid) for sid in adjustable}
    if clicks is True or (isinstance(clicks, str) and clicks.strip().lower() == CLICKS_ALL):
        return {sid: {} for sid in adjustable}
    if not isinstance(clicks, Mapping):
        raise TypeError(f"{where}: clicks must be None, 'all' or a mapping of steps, got "
                        f"{type(clicks).__name__} {clicks!r}")
    names = sorted({a for e in entries.values() for a in e.names})
    per_id, per_adj = {}, {}
    for key, value in clicks.items():
        if key in entries:
            if isinstance(value, str) and value.strip().lower() == CLICKS_ALL:
                per_id[key] = {}
            elif isinstance(value, Mapping):
                for a, st in value.items():
                    if a not in entries[key].names:
                        raise PlannerError(f"{where}: clicks[{key!r}] names adjuster {a!r}; "
                                           f"shock {key!r} has adjusters "
                                           f"{list(entries[key].names)}")
                per_id[key] = {a: _step_value(st, f"{key}.{a}", where)
                               for a, st in value.items()}
            else:
                raise PlannerError(f"{where}: clicks[{key!r}] = {value!r}; give 'all' or a "
                                   "step per adjuster, e.g. {'ls': 2}")
        elif key in names:
            per_adj[key] = _step_value(value, key, where)
        else:
            raise PlannerError(f"{where}: clicks has the key {key!r}, neither an adjustable "
                               f"shock {list(adjustable)} nor an adjuster {names}; fix the key")
    if per_adj:
        for sid, e in entries.items():
            per_id.setdefault(sid, {a: st for a, st in per_adj.items() if a in e.names})
    return per_id


def expand_candidates(ids, library, steps, where="enumerate_setups"):
    """Candidate ids with each adjustable id of `steps` replaced by its grid's names.

    Parameters
    ----------
    ids : list of str
        Candidate ids (a setting name stays one candidate).
    library : ShockLibrary
    steps : dict
        From :func:`click_steps`.
    where : str

    Returns
    -------
    list of str
        In order: each expanded id's names with its first adjuster varying slowest;
        duplicates dropped.

    Raises
    ------
    PlannerError
        On a step that is not a whole multiple of an adjuster's resolution.
    """
    if not steps:
        return list(ids)
    out = []
    for sid in ids:
        if sid not in steps:
            out.append(sid)
            continue
        entry = library.adjustable(sid)
        try:
            grid = entry.settings_grid(step=steps[sid] or None)
        except ShockModelError as exc:
            raise PlannerError(f"{where}: clicks: {exc}") from None
        out.extend(entry.name(s) for s in grid)
    return list(dict.fromkeys(out))


def split_shock_ids(text):
    """Split a comma-separated list of shock names, keeping ``TTX@ls=6,hs=2`` whole.

    A piece without ``@`` that reads ``word=value`` continues the setting name before it.

    Parameters
    ----------
    text : str

    Returns
    -------
    list of str
        The names, stripped; empty pieces dropped.
    """
    out = []
    for piece in (p.strip() for p in str(text).split(",")):
        if not piece:
            continue
        if out and "@" in out[-1] and "@" not in piece and "=" in piece:
            out[-1] += "," + piece
        else:
            out.append(piece)
    return out


def parse_click_step(text, option="--click-step"):
    """``"ls=2,hs=0.5"`` as ``{"ls": 2.0, "hs": 0.5}`` (``TTX.ls=2`` for one shock's adjuster).

    Raises
    ------
    PlannerError
        On a piece without ``=`` or a value that is not a number > 0.
    """
    out = {}
    for piece in (p.strip() for p in str(text).split(",")):
        if not piece:
            continue
        key, sep, value = piece.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not sep or not key.strip() or not number > 0 or not math.isfinite(number):
            raise PlannerError(f"{option} {text!r}: write ADJUSTER=STEP[,ADJUSTER=STEP] with "
                               "steps > 0 in clicks or turns, e.g. ls=2,hs=0.5 (or "
                               "SHOCK.ADJUSTER=STEP for one shock)")
        shock, dot, adj = key.strip().rpartition(".")
        if dot:
            out.setdefault(shock, {})[adj] = number
        else:
            out[adj] = number
    if not out:
        raise PlannerError(f"{option} {text!r}: give at least one ADJUSTER=STEP")
    return out


def clicks_option(args):
    """The ``clicks`` of :func:`planner.setups.setup_space` from ``--clicks`` and
    ``--click-step`` (None when neither is given).

    Raises
    ------
    PlannerError
        With ``--setups`` (a setups file names its settings itself), or a bad step.
    """
    steps = getattr(args, "click_step", None)
    given = bool(steps) or bool(getattr(args, "clicks", False))
    if given and getattr(args, "setups", None):
        raise PlannerError("--clicks/--click-step enumerate the settings of adjustable shocks; "
                           "with --setups write the settings in the file (TTX@ls=6,hs=2), or "
                           "leave --setups out")
    if steps:
        return parse_click_step(steps)
    return CLICKS_ALL if given else None


def add_click_arguments(parser):
    """``--clicks`` and ``--click-step`` on a ``rank`` or ``sweep`` parser."""
    parser.add_argument("--clicks", action="store_true",
                        help="enumeration: every setting of each adjustable shock among the "
                        "candidates (default: its default setting only); screened, the best "
                        "simulated")
    parser.add_argument("--click-step", metavar="ADJ=N[,ADJ=N]",
                        help="as --clicks on a coarser grid: a step per adjuster, e.g. "
                        "ls=2,hs=0.5 (SHOCK.ADJ=N for one shock; others keep their own step); default: "
                        "each adjuster's own step (its resolution) with --clicks, none without")


def adjuster_columns(table):
    """One column per adjuster per corner from the setting names of a table's corners.

    Parameters
    ----------
    table : pandas.DataFrame
        With the corner columns ``LF RF LR RR`` (shock names).

    Returns
    -------
    pandas.DataFrame
        Columns ``<corner>_<adjuster>`` (corner order, adjusters as first named), the
        settings; empty (no column) when no corner names a setting. Whole-number columns are
        integers; a fixed shock's cell is empty (NA).
    """
    cols = {}
    for c in CORNERS:
        if c not in table.columns:
            continue
        values = table[c].tolist()
        if not any(isinstance(v, str) and "@" in v for v in values):
            continue
        parsed = [parse_shock_name(v)[1] if isinstance(v, str) and "@" in v else {}
                  for v in values]
        for adj in dict.fromkeys(a for s in parsed for a in s):
            cols[f"{c}_{adj}"] = np.array([s.get(adj, np.nan) for s in parsed], dtype=float)
    out = pd.DataFrame(index=table.index)
    for name, v in cols.items():
        fin = v[np.isfinite(v)]
        whole = fin.size and np.all(fin == np.round(fin)) and np.all(np.abs(fin) < 2**53)
        out[name] = pd.array([None if math.isnan(x) else int(x) for x in v], dtype="Int64") \
            if whole else v
    return out


def click_values(setups):
    """The settings each adjuster takes in a list of setups (the enumeration's grid).

    Parameters
    ----------
    setups : sequence of planner.setups.Setup

    Returns
    -------
    dict of (str, str) to ndarray
        ``(base id, adjuster) -> sorted distinct settings`` over every setting name in
        `setups`; empty when no setup names a setting.
    """
    names = {sid for s in setups for sid in s.ids() if "@" in sid}
    out = {}
    for sid in names:
        base, settings = parse_shock_name(sid)
        for adj, x in settings.items():
            out.setdefault((base, adj), set()).add(float(x))
    return {k: np.array(sorted(v)) for k, v in out.items()}


def click_neighbours(ids, values, library):
    """Every corner assignment one grid step away in each adjuster of each corner.

    Parameters
    ----------
    ids : tuple of str, length 4
        A setup's shock names (LF, RF, LR, RR).
    values : dict
        :func:`click_values` of the setups the neighbours must come from.
    library : ident.models.library.ShockLibrary
        Gives the canonical names.

    Returns
    -------
    list of tuple of str
        The id tuples with every adjuster of every corner at its setting or the grid's
        next lower or higher one (the product, `ids` itself left out); fixed shocks stay.
        The caller keeps those that are setups of its enumeration (symmetry and fixed
        corners filter the product).
    """
    per_corner = []
    for sid in ids:
        if "@" not in sid:
            per_corner.append([sid])
            continue
        base, settings = parse_shock_name(sid)
        adj = library.adjustable(base)
        choices = []
        for name in adj.names:
            grid = values.get((base, name))
            x = float(settings.get(name, adj.default[name]))
            if grid is None or grid.size == 0:
                choices.append([x])
                continue
            k = int(np.argmin(np.abs(grid - x)))
            choices.append(sorted({float(grid[j]) for j in (k - 1, k, k + 1)
                                   if 0 <= j < grid.size}))
        names = []
        for combo in itertools.product(*choices):
            names.append(adj.name(dict(zip(adj.names, combo))))
        per_corner.append(names)
    out = [c for c in itertools.product(*per_corner) if c != tuple(ids)]
    return out
