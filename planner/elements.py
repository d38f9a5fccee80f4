"""The real car's elements in the planner: each setup's bump stops and packers, the static loads.

A setup (:class:`planner.setups.Setup`) names its shocks and, optionally, the bump stops
and packers of the corners it changes; the others keep those of the model's baseline run
(the spec's "The real car"). :func:`setup_elements` resolves them, for a list of setups,
into the closed loop's tables (:func:`ident.sim.closedloop.simulate_batch`,
``bump_stops=``), with the car's static corner loads (tire lift-off); the one place where
the planner's commands (predict, rank, sweep, what-if) meet the elements.

:func:`vary_elements` enumerates bump-stop and packer choices as setup columns (every
setup with every choice, per axle or corner group), as :func:`planner.setups.enumerate_setups`
enumerates shocks.

Third elements (heave and roll elements per axle, issue 38): :func:`setup_third` resolves
each setup's dampers (``Setup.third``: ids in the shock library) and heave springs
(``Setup.heave_springs``: ids in the bump-stop library) against the car's
(``model.third``, a :class:`ident.data.third.CarThird`; a key a setup leaves out keeps the
baseline run's) into the loop's ``third=`` entries
(:func:`ident.sim.closedloop.simulate_batch`); :func:`vary_third` enumerates their choices
as setup columns.

Where the model came from a session that declared elements, the identified
:class:`ident.identify.model.VehicleModel` carries them (``model.elements``, a
:class:`ident.models.bumpstops.CarElements`); a library given here (``--bump-stops``)
replaces the model's.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ident.data.channels import CORNERS
from ident.data.third import AXLES, HEAVE_ELEMENTS, THIRD_ELEMENTS
from ident.models.bumpstops import (BumpStopLibrary, check_packer, contact_tables,
                                    resolve_corner_stops)
from planner.errors import PlannerError
from planner.options import ElementOptions, as_options
from ident.sim.loop_third import ThirdDamper, ThirdSpring
from planner.setups import Setup
from planner.setups.setup import unknown_id_error

__all__ = [
    "SetupElements",
    "ELEMENT_COLUMNS",
    "GROUPS",
    "model_elements",
    "model_setup_elements",
    "loop_arguments",
    "setup_elements",
    "vary_elements",
    "distinct_setups",
    "parse_length",
    "THIRD_COLUMNS",
    "SetupThird",
    "setup_third",
    "model_setup_third",
    "vary_third",
    "corner_shock_ids",
]

log = logging.getLogger(__name__)

#: The setup columns of the elements, in the order written after the metrics.
ELEMENT_COLUMNS = tuple(f"bump_stop_{c}" for c in CORNERS) + tuple(f"packer_{c}"
                                                                  for c in CORNERS)

#: Corner groups a choice may name (:func:`vary_elements`).
GROUPS = {"front": ("LF", "RF"), "rear": ("LR", "RR"), "all": CORNERS,
          **{c: (c,) for c in CORNERS}}

#: Length units accepted by :func:`parse_length`, to metres.
_LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "in": 0.0254}


def model_elements(model):
    """The elements an identified model carries (``model.elements``), or None."""
    return getattr(model, "elements", None)


@dataclass(frozen=True, eq=False)
class SetupElements:
    """The bump stops, packers and static loads of a list of setups, resolved.

    Attributes
    ----------
    stop_ids : tuple of tuple of (str or None)
        Per setup, the bump-stop id at ``LF, RF, LR, RR`` (None: none).
    packers_m : ndarray, shape (n_setups, 4)
        Packer thickness per setup and corner [m] (0 where there is no stop).
    tables : tuple
        Per setup, the loop's tables (:func:`ident.models.bumpstops.contact_tables`):
        4 entries of None or ``(contact_travel_m, travel_table_m, force_table_n)``, or
        None when the setup has no stop.
    static_corner_load_n : ndarray, shape (4,), or None
        The car's static tire loads [N] (lift-off in the loop), or None.
    library : ident.models.bumpstops.BumpStopLibrary or None
    settings : dict
        Where the library and the loads came from (``"model"``, ``"given"``).
    """

    stop_ids: tuple
    packers_m: np.ndarray
    tables: tuple
    static_corner_load_n: np.ndarray | None
    library: BumpStopLibrary | None
    settings: dict = field(default_factory=dict)

    @property
    def has_stops(self):
        """True if any setup has a bump stop at any corner."""
        return any(t is not None for t in self.tables)

    @property
    def active(self):
        """True if the loop needs the elements (a stop anywhere, or static loads)."""
        return self.has_stops or self.static_corner_load_n is not None

    def loop_stops(self, index=slice(None)):
        """The loop's ``bump_stops=`` for the setups at `index` (None without stops)."""
        if not self.has_stops:
            return None
        picked = self.tables[index]
        return list(picked) if isinstance(picked, tuple) else [picked]

    def columns(self, names):
        """The setup columns ``bump_stop_XX`` (id or ``none``) and ``packer_XX`` [m].

        Parameters
        ----------
        names : sequence of str
            The setups' names (the table's index).

        Returns
        -------
        pandas.DataFrame
            Indexed by `names`; empty (no columns) when no setup has a stop.
        """
        if not self.has_stops:
            return pd.DataFrame(index=pd.Index(list(names), name="setup"))
        data = {f"bump_stop_{c}": [ids[k] or "none" for ids in self.stop_ids]
                for k, c in enumerate(CORNERS)}
        data.update({f"packer_{c}": self.packers_m[:, k] for k, c in enumerate(CORNERS)})
        return pd.DataFrame(data, index=pd.Index(list(names), name="setup"))


def setup_elements(setups, car=None, *, bump_stops=None, static_corner_load_n=None,
                   use_static_loads=True, where="setups"):
    """Resolve the bump stops, packers and static loads of setups.

    Parameters
    ----------
    setups : sequence of planner.setups.Setup
    car : ident.models.bumpstops.CarElements, optional
        The model's elements (:func:`model_elements`): its library, the baseline run's
        stops and packers (what a setup that does not name them keeps), its static loads.
    bump_stops : BumpStopLibrary, optional
        A library that replaces the model's (``--bump-stops FILE``).
    static_corner_load_n : array_like, shape (4,), optional
        Static tire loads [N] that replace the model's.
    use_static_loads : bool
        False leaves lift-off out of the loop (the contact force may go negative, as in
        a linear model).
    where : str
        Who asks, put first in messages.

    Returns
    -------
    SetupElements or None
        None when no setup has a bump stop and there are no static loads: the loop
        without elements, the numbers of a car without them.

    Raises
    ------
    PlannerError
        A setup naming a bump stop not in the library (or without a library), or a packer
        thicker than its stop's gap (the message names the setup and the corner).
    TypeError
        If `bump_stops` is not a :class:`BumpStopLibrary`.
    """
    if bump_stops is not None and not isinstance(bump_stops, BumpStopLibrary):
        raise TypeError(f"{where}: bump_stops must be an ident.models.bumpstops.BumpStopLibrary "
                        f"(read one with read_bump_stops), got {type(bump_stops).__name__}")
    library = bump_stops if bump_stops is not None else getattr(car, "bump_stops", None)
    base_stops = getattr(car, "baseline_stops", None) or {}
    base_packers = getattr(car, "baseline_packers_m", None) or {}
    if library is None and any(base_stops.values()):
        raise PlannerError(f"{where}: the model's baseline run has bump stops "
                           f"({_ids_text(base_stops)}) but no library is known; pass the "
                           "session's bumpstops.toml (--bump-stops FILE)")
    if static_corner_load_n is None and use_static_loads:
        static_corner_load_n = getattr(car, "static_corner_load_n", None)
    if not use_static_loads:
        static_corner_load_n = None
    if static_corner_load_n is not None:
        static_corner_load_n = np.asarray(static_corner_load_n, dtype=float).ravel()
        if static_corner_load_n.size != 4 or not np.all(np.isfinite(static_corner_load_n)) \
                or np.any(static_corner_load_n <= 0):
            raise PlannerError(f"{where}: static corner loads must be 4 positive numbers [N] "
                               f"(LF, RF, LR, RR), got {static_corner_load_n.tolist()}")
    ids, packers, tables = [], [], []
    for s in setups:
        if not isinstance(s, Setup):
            raise TypeError(f"{where}: setups must be planner.setups.Setup objects, got "
                            f"{type(s).__name__}")
        stops, pk = resolve_corner_stops(library, s.bump_stops, s.packers_m,
                                         baseline_stops=base_stops,
                                         baseline_packers_m=base_packers,
                                         where=f"setup {s.name!r}", error=PlannerError)
        ids.append(tuple(None if st is None else st.id for st in stops))
        packers.append(pk)
        tables.append(contact_tables(stops, pk, where=f"setup {s.name!r}", error=PlannerError))
    if all(t is None for t in tables) and static_corner_load_n is None:
        return None
    settings = {"library": "given" if bump_stops is not None else
                ("model" if library is not None else None),
                "static_corner_load_n": None if static_corner_load_n is None
                else static_corner_load_n.tolist()}
    return SetupElements(stop_ids=tuple(ids), packers_m=np.array(packers).reshape(-1, 4),
                         tables=tuple(tables), static_corner_load_n=static_corner_load_n,
                         library=library, settings=settings)


def model_setup_elements(setups, model, elements=None, *, where="setups"):
    """:func:`setup_elements` of setups on a model, with the planner's element options.

    Parameters
    ----------
    setups : sequence of planner.setups.Setup
    model : object
        The model (its ``elements``, if any, are the car's).
    elements : planner.options.ElementOptions, optional
        Default ``ElementOptions()``: the model's elements (``use_model=True``); a
        ``CarElements`` as ``use_model``: those (a model given as a plant); False: none of
        the car's (no static loads; only stops the setups name, from ``bump_stops``). The
        choices (``vary_*``) are not used here (:func:`vary_elements` enumerates them).
    where : str
        Who asks, put first in messages.

    Returns
    -------
    SetupElements or None
    """
    elements = as_options(elements, ElementOptions, "elements", where)
    if elements.use_model is False:
        return setup_elements(setups, None, bump_stops=elements.bump_stops,
                              use_static_loads=False, where=where)
    return setup_elements(setups, elements.car(model), bump_stops=elements.bump_stops,
                          static_corner_load_n=elements.static_corner_load_n, where=where)


def loop_arguments(elem):
    """The closed loop's and the screening's keywords for resolved elements (``{}`` for None)."""
    if elem is None:
        return {}
    return {"bump_stops": elem.loop_stops(), "static_corner_load_n": elem.static_corner_load_n}


def _ids_text(stops):
    return ", ".join(f"{c}={v}" for c, v in stops.items() if v)


def parse_length(text, *, units="SI", where="length"):
    """A length [m] from text: a number in the unit system, or with a unit (``2mm``, ``0.1in``).

    Examples
    --------
    >>> parse_length("2mm"), parse_length("0.002"), round(parse_length("0.1", units="imperial"), 6)
    (0.002, 0.002, 0.00254)
    """
    t = str(text).strip().lower().replace(" ", "")
    for unit in sorted(_LENGTH_UNITS, key=len, reverse=True):
        if t.endswith(unit):
            num, scale = t[: -len(unit)], _LENGTH_UNITS[unit]
            break
    else:
        num, scale = t, (0.0254 if units == "imperial" else 1.0)
    try:
        value = float(num) * scale
    except ValueError:
        raise PlannerError(f"{where}: {text!r} is not a length; write a number in "
                           f"{'in' if units == 'imperial' else 'm'} or with a unit, e.g. 2mm"
                           ) from None
    if not np.isfinite(value) or value < 0:
        raise PlannerError(f"{where}: {text!r} must be a length >= 0")
    return value


def _choices(values, what, where):
    """Group -> tuple of choices, checked."""
    out = {}
    for group, vals in (values or {}).items():
        if group not in GROUPS:
            raise PlannerError(f"{where}: {what} names the group {group!r}; groups are "
                               f"{list(GROUPS)}")
        vals = tuple(vals)
        if not vals:
            raise PlannerError(f"{where}: {what} {group}: give at least one choice")
        corners = set(GROUPS[group])
        for g in out:
            if corners & set(GROUPS[g]):
                raise PlannerError(f"{where}: {what} groups {g!r} and {group!r} share corners; "
                                   "give each corner once")
        out[group] = vals
    return out


def vary_elements(setups, *, bump_stops=None, packers_m=None, library=None,
                  name_format="{name} {what}", where="vary_elements"):
    """Every setup with every bump-stop and packer choice (setup columns enumerated).

    Parameters
    ----------
    setups : sequence of planner.setups.Setup
    bump_stops : mapping of str to sequence of (str or None), optional
        Group (``front``, ``rear``, ``all`` or a corner) -> bump-stop ids to try there
        (None or ``"none"``: no bump stop), e.g. ``{"front": ["BS-F", "BS-F2"]}``.
    packers_m : mapping of str to sequence of float, optional
        Group -> packer thicknesses [m] to try, e.g. ``{"front": [0, 0.002, 0.004]}``.
    library : BumpStopLibrary, optional
        Checks the ids and the packers against the gaps (a packer thicker than a tried
        stop's gap is refused).
    name_format : str
        The new setups' names: ``{name}`` the setup's, ``{what}`` the choices
        (``"F=BS-F2 pF=2mm"``).

    Returns
    -------
    list of planner.setups.Setup
        Each setup as given, then its variants (one per combination of the choices,
        named with them), setup by setup. A variant may repeat the setup's own elements
        (:func:`distinct_setups` drops those once resolved).

    Raises
    ------
    PlannerError
        An unknown group, overlapping groups, an unknown id, a packer thicker than a gap.

    Examples
    --------
    >>> s = Setup("base", dict.fromkeys(CORNERS, "B20"))
    >>> [v.name for v in vary_elements([s], packers_m={"front": [0.0, 0.002]})]
    ['base', 'base pF=0mm', 'base pF=2mm']
    """
    stop_choices = _choices(bump_stops, "bump_stops", where)
    packer_choices = _choices(packers_m, "packers", where)
    for group, vals in stop_choices.items():
        stop_choices[group] = tuple(None if v is None or str(v).strip().lower() == "none"
                                    else str(v).strip() for v in vals)
        if library is not None:
            for v in stop_choices[group]:
                if v is not None and v not in library:
                    raise library.unknown_id_error(v, where=f"{where}: bump_stops {group}",
                                                   error=PlannerError)
    for group, vals in packer_choices.items():
        vals = tuple(float(v) for v in vals)
        if any(not np.isfinite(v) or v < 0 for v in vals):
            raise PlannerError(f"{where}: packers {group}: {list(vals)}; a packer is a "
                               "thickness >= 0 [m]")
        packer_choices[group] = vals
    axes = [("stop", g, v) for g, v in stop_choices.items()] + \
        [("packer", g, v) for g, v in packer_choices.items()]
    if not axes:
        return list(setups)
    out = []
    for s in setups:
        out.append(s)
        for combo in itertools.product(*(v for _, _, v in axes)):
            stops = dict(s.bump_stops or {})
            packers = dict(s.packers_m or {})
            words = []
            for (kind, group, _), value in zip(axes, combo):
                for c in GROUPS[group]:
                    (stops if kind == "stop" else packers)[c] = value
                words.append(_word(kind, group, value))
            if library is not None:
                for c, p in packers.items():
                    sid = stops.get(c)
                    if sid is not None and sid in library:
                        check_packer(library[sid], p, f"{where}: packers {c} with {sid}",
                                     error=PlannerError)
            out.append(Setup(name_format.format(name=s.name, what=" ".join(words)),
                             dict(s.shocks), bump_stops=stops or None,
                             packers_m=packers or None))
    return out


def _copy(mapping):
    return None if mapping is None else dict(mapping)


def distinct_setups(setups, elements, third=None):
    """The setups without repeats: a variant whose shocks, bump stops and packers (resolved),
    and third elements (`third`, a :class:`SetupThird`), equal an earlier setup's is dropped
    (:func:`vary_elements` and :func:`vary_third` may make them).

    Parameters
    ----------
    setups : sequence of planner.setups.Setup
    elements : SetupElements or None
        The setups' resolved elements (:func:`setup_elements`), same order.
    third : SetupThird, optional
        Their third elements (:func:`setup_third`), same order.

    Returns
    -------
    setups : list of planner.setups.Setup
    keep : ndarray of int
        Indices of the kept setups.
    """
    seen, keep = set(), []
    for k, s in enumerate(setups):
        key = (s.ids(),) if elements is None else (
            s.ids(), elements.stop_ids[k], tuple(np.round(elements.packers_m[k], 12)))
        if third is not None:
            key = key + third.key(k)
        if key in seen:
            continue
        seen.add(key)
        keep.append(k)
    return [setups[k] for k in keep], np.array(keep, dtype=int)


def _word(kind, group, value):
    tag = {"front": "F", "rear": "R", "all": ""}.get(group, group)
    if kind == "stop":
        return f"{tag}={value or 'none'}" if tag else f"stops={value or 'none'}"
    return f"p{tag}={value * 1e3:g}mm"


# ----------------------------------------------------------------------------------------------
# third elements (issue 38)
# ----------------------------------------------------------------------------------------------

#: The setup columns of the third elements (the spec's setups-CSV columns), in the order
#: written after the metrics: a damper per element, a heave spring per axle.
THIRD_COLUMNS = THIRD_ELEMENTS + tuple(f"heave_spring_{a}" for a in AXLES)


@dataclass(frozen=True, eq=False)
class SetupThird:
    """The third elements of a list of setups, resolved (:func:`setup_third`).

    Attributes
    ----------
    car : ident.data.third.CarThird
        The car's elements (motion ratios) and baseline.
    damper_ids : tuple of dict
        Per setup, declared element -> damper id (None: not fitted).
    spring_ids : tuple of dict
        Per setup, axle of a declared heave element -> heave-spring id (None: none).
    entries : tuple
        Per setup, the loop's ``(dampers, springs)``
        (:class:`ident.sim.loop_third.ThirdDamper`, :class:`~ident.sim.loop_third.ThirdSpring`;
        every declared element, a damper's ``model`` None where it is not fitted).
    """

    car: object
    damper_ids: tuple
    spring_ids: tuple
    entries: tuple

    def loop_third(self, index=slice(None)):
        """The loop's ``third=`` for the setups at `index` (a list)."""
        picked = self.entries[index]
        return list(picked) if isinstance(picked, tuple) else [picked]

    def key(self, k):
        """Setup `k`'s third choices as a hashable key (:func:`distinct_setups`)."""
        return (tuple(sorted(self.damper_ids[k].items())),
                tuple(sorted(self.spring_ids[k].items())))

    def columns(self, names):
        """The setup columns ``heave_front``, ... (damper id or ``none``) and
        ``heave_spring_<axle>`` (id or ``none``) of the declared elements.

        Returns
        -------
        pandas.DataFrame
            Indexed by `names` (the table's index).
        """
        data = {}
        for e in THIRD_ELEMENTS:
            if e in self.damper_ids[0]:
                data[e] = [d[e] or "none" for d in self.damper_ids]
        for a in AXLES:
            if a in self.spring_ids[0]:
                data[f"heave_spring_{a}"] = [d[a] or "none" for d in self.spring_ids]
        return pd.DataFrame(data, index=pd.Index(list(names), name="setup"))


def _third_keys_text(s):
    keys = [k for k in (s.third or {})] + [f"heave_spring_{a}" for a in (s.heave_springs or {})]
    return ", ".join(keys)


def setup_third(setups, car, library, *, bump_stops=None, where="setups"):
    """Resolve the third elements (heave and roll dampers, heave springs) of setups.

    Parameters
    ----------
    setups : sequence of planner.setups.Setup
    car : ident.data.third.CarThird or None
        The car's third elements (``model.third``): the declared elements with their motion
        ratios, the baseline run's dampers, heave springs and packers (what a setup that
        leaves a key out keeps).
    library : ShockLibrary or mapping of str to ShockModel
        The shock library the dampers' ids are read from (the corner shocks' library).
    bump_stops : ident.models.bumpstops.BumpStopLibrary, optional
        The library the heave springs' ids are read from (the model's bump stops, or a
        given one).
    where : str
        Who asks, put first in messages.

    Returns
    -------
    SetupThird or None
        None for a car without third elements (the loop without them, today's numbers).

    Raises
    ------
    PlannerError
        A setup giving third elements on a car without them, or an element the car does
        not declare; an unknown damper or heave-spring id; a packer thicker than a heave
        spring's gap (each naming the setup, the column and the fix).
    """
    if car is None:
        for s in setups:
            if s.third or s.heave_springs:
                raise PlannerError(
                    f"{where}: setup {s.name!r} gives third elements ({_third_keys_text(s)}) "
                    "but the model has none; drop the columns heave_*, roll_* and "
                    "heave_spring_* from the setups file, or use a model identified from a "
                    "session that declares third_elements")
        return None
    declared = car.elements.elements
    heave_axles = [e.rpartition("_")[2] for e in declared if e in HEAVE_ELEMENTS]
    damper_ids, spring_ids, entries = [], [], []
    models, stops = {}, {}
    for s in setups:
        if not isinstance(s, Setup):
            raise TypeError(f"{where}: setups must be planner.setups.Setup objects, got "
                            f"{type(s).__name__}")
        d = {e: car.baseline.dampers.get(e) for e in declared}
        for e, sid in (s.third or {}).items():
            if e not in declared:
                raise PlannerError(f"{where}: setup {s.name!r}: column {e!r} names a third "
                                   f"element the car does not declare (it has "
                                   f"{list(declared)}); leave the column empty or drop it")
            d[e] = sid
        sp = {a: car.baseline.heave_springs.get(a) for a in heave_axles}
        for a, sid in (s.heave_springs or {}).items():
            if a not in heave_axles:
                raise PlannerError(f"{where}: setup {s.name!r}: column 'heave_spring_{a}' "
                                   f"names a heave spring where the car declares no heave "
                                   f"element (heave_{a}); leave the column empty or drop it")
            sp[a] = sid
        dampers = []
        for e in declared:
            sid = d[e]
            if sid is not None and sid not in models:
                col = f"{where}: setup {s.name!r}: column {e!r}"
                if sid not in library:
                    raise unknown_id_error(col, sid, library)
                try:
                    models[sid] = library[sid]
                except ValueError as exc:  # a setting name out of range, unknown adjuster
                    raise PlannerError(f"{col}: {exc}") from None
            dampers.append(ThirdDamper(e, car.elements.row(e),
                                       None if sid is None else models[sid]))
        springs = []
        for a in heave_axles:
            sid = sp[a]
            packer = float(car.baseline.heave_packers_m.get(a, 0.0) or 0.0)
            col = f"{where}: setup {s.name!r}: column 'heave_spring_{a}'"
            contact = None
            if sid is not None:
                if bump_stops is None:
                    raise PlannerError(f"{col}: heave spring {sid!r} but no bump-stop library "
                                       "is known; pass the session's bumpstops.toml "
                                       "(--bump-stops FILE)")
                if sid not in bump_stops:
                    raise bump_stops.unknown_id_error(sid, where=col, error=PlannerError)
                key = (sid, packer)
                if key not in stops:
                    stops[key] = contact_tables([bump_stops[sid], None, None, None],
                                                [packer, 0.0, 0.0, 0.0], where=col,
                                                error=PlannerError)[0]
                contact = stops[key]
            springs.append(ThirdSpring(f"heave_{a}", car.elements.row(f"heave_{a}"), contact))
        damper_ids.append(d)
        spring_ids.append(sp)
        entries.append((tuple(dampers), tuple(springs)))
    return SetupThird(car=car, damper_ids=tuple(damper_ids), spring_ids=tuple(spring_ids),
                      entries=tuple(entries))


def model_setup_third(setups, model, library, elements=None, *, where="setups"):
    """:func:`setup_third` of setups on a model, with the planner's element options
    (:meth:`planner.options.ElementOptions.car_third`: the model's ``third`` or the given
    one; the heave springs from :meth:`~planner.options.ElementOptions.library`)."""
    elements = as_options(elements, ElementOptions, "elements", where)
    return setup_third(setups, elements.car_third(model), library,
                       bump_stops=elements.library(model), where=where)


def corner_shock_ids(library, car, choices=None):
    """The library's ids an enumeration puts at the corners of a car.

    A damper the library marks as a heave or roll damper (its ``fits``,
    :data:`ident.models.shocks.SHOCK_FITS`), and on a car with third elements a damper the
    car fits as a third element (its baseline's) or that a third-element choice tries, is
    in an element's own travel and force: it is not enumerated at the corners (a user who
    wants it there names it, e.g. ``--only``).

    Parameters
    ----------
    library : ShockLibrary or mapping
    car : ident.data.third.CarThird or None
    choices : mapping of str to sequence, optional
        :func:`vary_third`'s choices (``heave_front`` -> ids, ...).

    Returns
    -------
    list of str or None
        The ids in library order; None when every id is (a car without third elements and
        a library that marks no damper as a heave or roll damper).

    Examples
    --------
    >>> from ident.data.third import CarThird, RunThird, ThirdElements
    >>> car = CarThird(ThirdElements({"heave_front": 1.0}), RunThird({"heave_front": "H0"}))
    >>> corner_shock_ids(["C1", "C2", "H0", "H1"], car, {"heave_front": ["H0", "H1"]})
    ['C1', 'C2']
    """
    marked = {sid for sid in library if _fits(library, sid) in ("heave", "roll")}
    if car is None or not car.elements:
        return [sid for sid in library if sid not in marked] if marked else None
    third = marked | {sid for sid in car.baseline.dampers.values() if sid is not None}
    for column, ids in (choices or {}).items():
        if column in THIRD_ELEMENTS:
            third.update(str(i) for i in ids if i is not None and str(i).lower() != "none")
    return [sid for sid in library if sid not in third]


def _fits(library, sid):
    """The library's ``fits`` of `sid` (None for a list of ids or an unmarked damper)."""
    if isinstance(library, (list, tuple)):
        return None
    return getattr(library[sid], "fits", None)


def vary_third(setups, choices, *, car=None, name_format="{name} {what}", where="vary_third"):
    """Every setup with every third-element choice (setup columns enumerated).

    Parameters
    ----------
    setups : sequence of planner.setups.Setup
    choices : mapping of str to sequence of (str or None)
        A third column (:data:`THIRD_COLUMNS`: ``heave_front`` ... a damper id;
        ``heave_spring_front`` ... a heave-spring id) -> the ids to try (None or ``"none"``:
        not fitted), e.g. ``{"heave_front": ["H1", "H2"]}``.
    car : ident.data.third.CarThird, optional
        Checks the columns against the declared elements.
    name_format : str
        The new setups' names: ``{name}`` the setup's, ``{what}`` the choices
        (``"heave_front=H2"``).

    Returns
    -------
    list of planner.setups.Setup
        Each setup as given, then its variants (one per combination), setup by setup.

    Raises
    ------
    PlannerError
        An unknown column, a column of an element the car does not declare, no choice.

    Examples
    --------
    >>> s = Setup("base", dict.fromkeys(CORNERS, "B20"))
    >>> [v.name for v in vary_third([s], {"heave_front": ["H1", "none"]})]
    ['base', 'base heave_front=H1', 'base heave_front=none']
    """
    axes = []
    for col, vals in (choices or {}).items():
        if col not in THIRD_COLUMNS:
            raise PlannerError(f"{where}: {col!r} is not a third-element column; one of "
                               f"{list(THIRD_COLUMNS)}")
        element = col.replace("heave_spring_", "heave_")
        if car is not None and element not in car.elements.elements:
            raise PlannerError(f"{where}: {col!r}: the car declares no {element} (it has "
                               f"{list(car.elements.elements)}); choose among those")
        vals = tuple(None if v is None or str(v).strip().lower() == "none" else str(v).strip()
                     for v in vals)
        if not vals:
            raise PlannerError(f"{where}: {col}: give at least one choice")
        axes.append((col, vals))
    if not axes:
        return list(setups)
    out = []
    for s in setups:
        out.append(s)
        for combo in itertools.product(*(v for _, v in axes)):
            third = dict(s.third or {})
            springs = dict(s.heave_springs or {})
            words = []
            for (col, _), value in zip(axes, combo):
                if col.startswith("heave_spring_"):
                    springs[col.rpartition("_")[2]] = value
                else:
                    third[col] = value
                words.append(f"{col}={value or 'none'}")
            out.append(Setup(name_format.format(name=s.name, what=" ".join(words)),
                             dict(s.shocks), bump_stops=_copy(s.bump_stops),
                             packers_m=_copy(s.packers_m), third=third or None,
                             heave_springs=springs or None))
    return out
