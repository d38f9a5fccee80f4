"""Candidate runs of an experiment design: setups, drives, durations, their costs on a rig.

Part of :mod:`planner.design` (see its docstring): the runs a design may choose
(:func:`candidate_runs`), the settings of adjustable shocks they try
(:func:`click_settings`) and the rig time of a setup change (:func:`change_time_min`).
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass

import numpy as np

from ident.data.channels import CORNERS
from ident.models.adjustable import parse_shock_name
from planner.elements import corner_shock_ids
from planner.errors import PlannerError
from planner.rig_spec import default_rig
from planner.setups import Setup, unknown_id_error

__all__ = [
    "DRIVE_KINDS",
    "DEFAULT_CLICK_LEVELS",
    "CandidateOptions",
    "Candidate",
    "click_settings",
    "named_settings",
    "corner_change",
    "change_counts",
    "change_time_min",
    "setup_key",
    "third_changed",
    "full_names",
    "candidate_runs",
    "validation_candidates",
]


#: Drive kinds a candidate run may play.
DRIVE_KINDS = ("noise", "multisine", "sweep", "track")

#: Settings per adjuster that candidate runs try across its range (ends included).
DEFAULT_CLICK_LEVELS = 3


@dataclass(frozen=True)
class CandidateOptions:
    """The candidate runs a design chooses from (:func:`candidate_runs`).

    Parameters
    ----------
    kinds : sequence of str
        Drive kinds of the candidates (:data:`DRIVE_KINDS`).
    durations_s : sequence of float
        Run durations [s]; the shortest is also the baseline repeats'.
    shocks : sequence of str, optional
        Shock ids the candidates swap in; default the crate's (``n_shocks`` of them).
    n_shocks : int
        Shocks chosen from the crate when `shocks` is not given.
    click_levels : int
        Settings per adjuster tried across its range (ends included).
    third : ident.data.third.CarThird, optional
        The car's third elements (issue 38) for a model without them (a known vehicle);
        default the identified model's (``model.third``).
    third_dampers : mapping of str to sequence of str, optional
        Element (``heave_front``, ...) -> crate ids the candidates swap in there
        (``"none"``: the element's damper taken off).
    bump_stops : ident.models.bumpstops.BumpStopLibrary, optional
        The library of `third`'s heave springs for a model without one (a known vehicle;
        the runs' predictions put them in the loop); default the identified model's.

    Raises
    ------
    PlannerError
        Checked where the candidates are built (an unknown kind or shock id).
    """

    kinds: tuple = ("noise", "multisine")
    durations_s: tuple = (120.0, 300.0, 600.0)
    shocks: tuple | None = None
    n_shocks: int = 4
    click_levels: int = DEFAULT_CLICK_LEVELS
    third: object = None
    third_dampers: object = None
    bump_stops: object = None


@dataclass(frozen=True)
class Candidate:
    """A run the design may choose.

    Attributes
    ----------
    name : str
    setup : planner.setups.Setup
    kind : str
        Drive kind (:data:`DRIVE_KINDS`).
    duration_s : float
    changed : tuple of str
        Corners whose shock (or its setting) differs from the baseline's.
    cost_min : float
        Duration, swaps and click changes (from the baseline) and overhead [min].
    clicks : int
        Adjusters turned from the baseline (corners keeping their adjustable shock).
    """

    name: str
    setup: object
    kind: str
    duration_s: float
    changed: tuple
    cost_min: float
    clicks: int = 0


_GROUPS = {"single": [(c,) for c in CORNERS], "diagonal": [("LF", "RR"), ("RF", "LR")],
           "axle": [("LF", "RF"), ("LR", "RR")], "all": [CORNERS]}


def click_settings(shock, levels=DEFAULT_CLICK_LEVELS):
    """Settings of an adjustable shock that candidate runs try.

    Each adjuster at `levels` settings evenly across its range (its ends included,
    snapped to its step), the others at their default; and, with two adjusters or
    more, every adjuster at its stiffer end and every one at its softer end. The
    design criterion chooses among them (the ends usually: they move the damping
    most from the baseline's).

    Parameters
    ----------
    shock : ident.models.adjustable.AdjustableShock
    levels : int
        Settings per adjuster, >= 2.

    Returns
    -------
    list of str
        Canonical setting names (``"TTX@ls=0,hs=2"``), each once: the stiffest, the
        softest, then each adjuster's levels.

    Examples
    --------
    >>> from ident.models.adjustable import AdjustableShock, DynoPoints
    >>> rows = [(v, 3000 * v * (1.5 - ls / 40), ls) for ls in (0, 20)
    ...         for v in (-0.5, -0.1, 0.1, 0.5)]
    >>> ttx = AdjustableShock("TTX", {"ls": (0, 20)}, DynoPoints.from_rows(rows, ("ls",)),
    ...                       default={"ls": 8}, step={"ls": 1})
    >>> click_settings(ttx)
    ['TTX@ls=0', 'TTX@ls=10', 'TTX@ls=20']
    """
    if isinstance(levels, bool) or not isinstance(levels, int) or levels < 2:
        raise PlannerError(f"click levels = {levels!r}: give a whole number >= 2 of settings "
                           "per adjuster (2: the ends of its range)")
    ends = {}
    for k, (lo, hi) in shock.adjusters.items():
        ends[k] = (lo, hi) if shock.stiffer[k] == "lower" else (hi, lo)
    out = []
    if len(ends) > 1:
        out += [shock.name({k: e[0] for k, e in ends.items()}),
                shock.name({k: e[1] for k, e in ends.items()})]
    for k, (lo, hi) in shock.adjusters.items():
        st = shock.step.get(k)
        for j in range(levels):
            x = lo + (hi - lo) * j / (levels - 1)
            if st:
                x = min(lo + st * math.floor((x - lo) / st + 0.5), hi)
            out.append(shock.name({k: x}))
    return list(dict.fromkeys(out))


@functools.lru_cache(maxsize=4096)
def named_settings(name):
    base, settings = parse_shock_name(name)
    return base, tuple(settings.items())


def corner_change(before, after):
    """(swaps, click changes) to go from shock name `before` to `after` at one corner: 0 and
    the adjusters whose setting differs when both name settings of one adjustable shock
    (every adjuster written, as :func:`design_experiment` keeps them), else one swap."""
    if before == after:
        return 0, 0
    if "@" not in before or "@" not in after:
        return 1, 0
    (ba, sa), (bb, sb) = named_settings(before), named_settings(after)
    da, db = dict(sa), dict(sb)
    if ba != bb or da.keys() != db.keys():
        return 1, 0
    return 0, sum(da[k] != db[k] for k in da)


@functools.lru_cache(maxsize=1 << 16)
def _id_change_counts(ids_a, ids_b):
    swaps = clicks = 0
    for x, y in zip(ids_a, ids_b):
        ds, dc = corner_change(x, y)
        swaps += ds
        clicks += dc
    return swaps, clicks


def third_changed(a, b):
    """The third elements' columns (``heave_front``, ``heave_spring_front``, ...) whose damper
    or heave spring differs from setup `a` to setup `b` (a key a setup leaves out keeps the
    baseline's: it differs from any id given), in column order."""
    out = []
    for x, y, pre in ((a.third, b.third, ""), (a.heave_springs, b.heave_springs,
                                                 "heave_spring_")):
        if x or y:
            x, y = x or {}, y or {}
            out += [pre + k for k in sorted(set(x) | set(y)) if x.get(k, _BASE) != y.get(k, _BASE)]
    return tuple(out)


def _third_swaps(a, b):
    return len(third_changed(a, b))


_BASE = object()  # a third key a setup leaves out: the baseline's


def change_counts(a, b):
    """Swaps and click changes from setup `a` to setup `b` (the greedy asks for the same
    pairs again and again: cached on the ids); a third element's damper or heave spring
    swapped (``Setup.third``, ``Setup.heave_springs``, issue 38) is a swap too."""
    swaps, clicks = _id_change_counts(a.ids(), b.ids())
    if a.third or b.third or a.heave_springs or b.heave_springs:
        swaps += _third_swaps(a, b)
    return swaps, clicks


def setup_key(setup):
    """What makes two setups the same car on the rig: the corners' shock names and the third
    elements' dampers and heave springs a setup gives (issue 38), hashable.

    Examples
    --------
    >>> a = Setup("a", dict.fromkeys(CORNERS, "S"))
    >>> setup_key(a) == setup_key(Setup("b", dict.fromkeys(CORNERS, "S")))
    True
    >>> setup_key(a) == setup_key(Setup("h", a.shocks, third={"heave_front": "H2"}))
    False
    """
    return (setup.ids(), tuple(sorted((setup.third or {}).items())),
            tuple(sorted((setup.heave_springs or {}).items())))


def change_time_min(before, after, rig=None):
    """Rig time [min] to change the car from one setup to the next.

    Parameters
    ----------
    before, after : planner.setups.Setup
        Adjustable shocks named with every adjuster (``TTX@ls=6,hs=2``; a corner whose
        name keeps its adjustable shock and changes settings is a click change).
    rig : planner.rig_spec.RigSpec, optional
        Default :func:`planner.rig_spec.default_rig`.

    Returns
    -------
    float
        ``swap_min`` a corner whose shock is swapped plus ``click_change_s / 60`` an
        adjuster turned.

    Examples
    --------
    >>> from planner.rig_spec import RigSpec
    >>> a = Setup("a", dict.fromkeys(CORNERS, "TTX@ls=6,hs=2"))
    >>> b = Setup("b", {**dict.fromkeys(CORNERS, "TTX@ls=6,hs=2"), "LF": "TTX@ls=8,hs=1"})
    >>> round(change_time_min(a, b, RigSpec(swap_min=6.0, click_change_s=20.0)), 3)
    0.667
    >>> change_time_min(a, Setup("c", {**a.shocks, "LF": "B20"}), RigSpec(swap_min=6.0))
    6.0
    """
    rig = default_rig() if rig is None else rig
    swaps, clicks = change_counts(before, after)
    return rig.swap_min * swaps + rig.click_change_min * clicks


def _full_name(library, sid):
    """An adjustable shock's name with every adjuster written (fixed ids unchanged)."""
    base = library.base_id(sid)
    if base not in library.adjustable_ids:
        return sid
    _, settings = parse_shock_name(sid)
    return library.adjustable(base).name(settings)


def full_names(setup, library):
    """`setup` with its adjustable shocks named in full (itself when nothing changes)."""
    if not library.adjustable_ids:
        return setup
    ids = tuple(_full_name(library, sid) for sid in setup.ids())
    if ids == setup.ids():
        return setup
    return Setup(setup.name, dict(zip(CORNERS, ids)), setup.bump_stops, setup.packers_m,
                 setup.third, setup.heave_springs)


def candidate_runs(library, baseline, *, rig=None, kinds=("noise", "multisine"),
                   durations_s=(120.0, 300.0, 600.0), shocks=None, n_shocks=4, c_bar=None,
                   v_rms_m_s=0.1, click_levels=DEFAULT_CLICK_LEVELS, third=None,
                   third_dampers=None):
    """The runs a design chooses from.

    The baseline, and the baseline with shocks swapped in at one corner, at a
    diagonal pair, at an axle, or at all four, for each of `kinds` and
    `durations_s`. The shocks swapped in are `shocks`, or the `n_shocks` crate
    shocks whose linearized damping (at `v_rms_m_s`) differs most from the
    baseline damping `c_bar` (the most informative, Eq. 22), softest and
    firmest alternating, followed by each adjustable shock of the crate at its
    :func:`click_settings` (`click_levels` per adjuster). A corner whose baseline
    shock is that adjustable shock changes clicks, not its shock: the run costs
    ``click_change_s`` an adjuster turned, not ``swap_min``.

    On a car with third elements (`third`, a :class:`ident.data.third.CarThird`; issue 38)
    the crate's third dampers (the baseline's and those of `third_dampers`, element ->
    ids) are not swapped in at the corners (:func:`planner.elements.corner_shock_ids`);
    each damper of `third_dampers` other than the baseline's is swapped in at its element
    (a candidate ``"<id>@heave_front"``, one swap, ``changed`` names the element).

    Returns
    -------
    list of Candidate
    """
    rig = default_rig() if rig is None else rig
    baseline = full_names(baseline, library)
    base_ids = baseline.ids()
    adjustable = set(library.adjustable_ids)
    if shocks is None:
        cb = np.mean(c_bar) if c_bar is not None else np.mean(
            [library[s].equivalent_damping(v_rms_m_s) for s in base_ids])
        corner_ids = corner_shock_ids(library, third, third_dampers)
        others = [s for s in library.ids if s not in base_ids and s not in adjustable
                  and (corner_ids is None or s in corner_ids)]
        ceq = {s: float(library[s].equivalent_damping(v_rms_m_s)) for s in others}
        soft = sorted([s for s in others if ceq[s] < cb], key=lambda s: ceq[s])
        firm = sorted([s for s in others if ceq[s] >= cb], key=lambda s: -ceq[s])
        shocks = [s for pair in itertools.zip_longest(soft, firm) for s in pair if s][:n_shocks]
        for sid in library.adjustable_ids:
            shocks += click_settings(library.adjustable(sid), click_levels)
    else:
        for s in shocks:
            if s not in library:
                raise unknown_id_error("candidate shocks", s, library)
        shocks = list(dict.fromkeys(_full_name(library, s) for s in shocks))
    setups = [("baseline", baseline, ())]
    for group, sets in _GROUPS.items():
        for corners in sets:
            for sid in shocks:
                ids = dict(zip(CORNERS, base_ids))
                ids.update({c: sid for c in corners})
                if tuple(ids[c] for c in CORNERS) == base_ids:
                    continue
                tag = "all" if group == "all" else "+".join(corners)
                setups.append((f"{sid}@{tag}", Setup(f"{sid}@{tag}", ids),
                               tuple(c for c in CORNERS if ids[c] != dict(zip(CORNERS,
                                                                             base_ids))[c])))
    if third_dampers:
        if third is None or not third.elements:
            raise PlannerError("candidate third dampers on a car without third elements; "
                               "drop them, or give the car's third elements (CarThird)")
        for element, ids in third_dampers.items():
            if element not in third.elements.elements:
                raise PlannerError(f"candidate third dampers: {element!r} is not an element "
                                   f"the car declares ({list(third.elements.elements)}); "
                                   "choose among those")
            for sid in ids:
                if sid is not None and str(sid).lower() == "none":
                    sid = None
                if sid is not None and sid not in library:
                    raise unknown_id_error(f"candidate third dampers ({element})", sid, library)
                if sid == third.baseline.dampers.get(element):
                    continue
                name = f"{sid or 'none'}@{element}"
                setups.append((name, Setup(name, dict(baseline.shocks),
                                           third={element: sid}), (element,)))
    out = []
    for name, setup, changed in setups:
        swaps, clicks = change_counts(baseline, setup)
        for kind in kinds:
            if kind not in DRIVE_KINDS:
                raise PlannerError(f"drive kind {kind!r} is not one of {list(DRIVE_KINDS)}")
            for T in durations_s:
                cost = (T / 60.0 + rig.swap_min * swaps + rig.click_change_min * clicks
                        + rig.run_overhead_min)
                out.append(Candidate(f"{name} {kind} {T:g}s", setup, kind, float(T),
                                     changed, cost, clicks))
    return out


def validation_candidates(val_setups, cands, baseline, rig, kinds, durations_s):
    """Identification candidates on the validation setups that `cands` lacks.

    The validation runs put the car in those setups anyway, so an identification run there
    (a drive of `kinds`, before the validation run) costs no swap of its own: the design
    may take one to vary the shock forces at the corners the validation setups change.

    Parameters
    ----------
    val_setups : sequence of planner.setups.Setup
        Named in full (:func:`full_names`).
    cands : sequence of Candidate
        The candidates so far (a setup already among them is not added again).
    baseline : planner.setups.Setup
    rig : planner.rig_spec.RigSpec
    kinds : sequence of str
    durations_s : sequence of float

    Returns
    -------
    list of Candidate
        Named ``"<setup> <kind> <T>s"``, costed from the baseline as :func:`candidate_runs`.
    """
    have = {setup_key(c.setup) for c in cands}
    base_ids = dict(zip(CORNERS, baseline.ids()))
    out = []
    for setup in val_setups:
        if setup_key(setup) in have:
            continue
        have.add(setup_key(setup))
        changed = tuple(c for c in CORNERS if setup.shocks[c] != base_ids[c])
        swaps, clicks = change_counts(baseline, setup)
        for kind in kinds:
            for T in durations_s:
                cost = (T / 60.0 + rig.swap_min * swaps + rig.click_change_min * clicks
                        + rig.run_overhead_min)
                out.append(Candidate(f"{setup.name} {kind} {T:g}s", setup, kind, float(T),
                                     changed, cost, clicks))
    return out
