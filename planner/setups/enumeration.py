"""The setups a shock library can build: enumerated under a symmetry, held as integer
codes (:class:`SetupSpace`), the swaps from a baseline, the crate's inventory.

The symmetry names (:data:`SYMMETRIES`, :data:`AXLE_MODES`, :data:`AXLES`) are those
:func:`planner.optimize.optimize_curves` uses too.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from ident.data.channels import CORNERS
from planner.click_settings import base_id, canonical_id, click_steps, expand_candidates
from planner.errors import PlannerError
from planner.setups.setup import Setup, check_setups, library_ids, unknown_id_error

__all__ = [
    "SYMMETRIES",
    "AXLE_MODES",
    "AXLES",
    "DEFAULT_MAX_SETUPS",
    "DEFAULT_NAME_FORMAT",
    "SetupSpace",
    "setup_space",
    "enumerate_setups",
    "setups_from_baseline",
    "inventory_shortfall",
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
    all_ids = library_ids(library, where)
    if not all_ids:
        raise PlannerError(f"{where}: the shock library is empty; add shocks to it")
    code_of = {sid: j for j, sid in enumerate(all_ids)}
    if setups is not None:
        if (symmetry, axles, fixed, shocks, clicks) != ("left-right", "independent", None,
                                                        None, None):
            raise PlannerError(f"{where}: give either setups or enumeration options "
                               "(symmetry, axles, fixed, shocks, clicks), not both")
        setups = check_setups(setups, where)
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
        Enumerate the settings of adjustable shocks (:mod:`planner.click_settings`): None keeps an
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
    library_ids(library, where)
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
