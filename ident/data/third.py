"""Third elements: heave and roll elements per axle (the spec's optional section).

Prototypes and single-seaters carry, per axle, a heave element (a heave damper and a
heave spring, often with a gap and packers) acting on the axle's two wheels together,
and sometimes a roll damper acting on their difference. They are mounted through
rockers: an element's travel is its motion ratio ``mr`` times the axle's mean (heave)
or half-difference (roll) of the two corners' shock travel, and its force ``F`` acts at
the corners in parallel with the shocks, ``mr F / 2`` at each (roll: ``+`` left, ``-``
right). :func:`element_row` is that geometry as a row over the corners ``LF, RF, LR,
RR``: the element's travel is ``row @ x_corner`` and its force at the corners ``row *
F`` (the same row both ways: the rocker does no work of its own).

This module holds the typed form of the session keys (:class:`ThirdElements`: the
elements a car carries and their motion ratios; :class:`RunThird`: what one run
fitted) and their checks; :mod:`ident.data.session` reads and writes them. Everything
is SI inside (packers in m); motion ratios are dimensionless.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field

import numpy as np

from ident.data.channels import THIRD_CHANNEL_QUANTITIES, THIRD_CHANNELS
from ident.errors import SessionError
from ident.models.bumpstops import check_packer, parse_bump_stop_id
from ident.models.shocks import is_real_number

__all__ = [
    "THIRD_ELEMENTS",
    "HEAVE_ELEMENTS",
    "ROLL_ELEMENTS",
    "AXLES",
    "THIRD_CHANNELS",
    "THIRD_CHANNEL_QUANTITIES",
    "ThirdElements",
    "RunThird",
    "CarThird",
    "element_row",
    "element_axle",
    "check_third_elements",
    "check_run_third",
]

#: The axles of a car (the suffix of an element's name and of its channels).
AXLES = ("front", "rear")
#: The heave elements, one per axle.
HEAVE_ELEMENTS = ("heave_front", "heave_rear")
#: The roll dampers, one per axle.
ROLL_ELEMENTS = ("roll_front", "roll_rear")
#: Every third element a car may declare (``third_elements`` keys, a run's ``third``).
THIRD_ELEMENTS = HEAVE_ELEMENTS + ROLL_ELEMENTS

#: The corner pair of each axle (left, right) in :data:`ident.data.channels.CORNERS`.
_AXLE_CORNERS = {"front": (0, 1), "rear": (2, 3)}


def element_axle(element):
    """``"front"`` or ``"rear"``: the axle of a third element (``"heave_rear"`` -> ``"rear"``)."""
    return element.rpartition("_")[2]


def element_row(element, mr):
    """The geometry of one element: its row over the corners ``LF, RF, LR, RR``.

    Parameters
    ----------
    element : str
        One of :data:`THIRD_ELEMENTS`.
    mr : float
        Its motion ratio (> 0).

    Returns
    -------
    ndarray, shape (4,)
        ``m`` such that the element's travel (velocity) is ``m @ x`` with ``x`` the corners'
        shock travels (velocities), and its force ``F`` acts at the corners as ``m * F``
        (compression positive): ``mr / 2`` at both corners of the axle for a heave element,
        ``+mr / 2`` left and ``-mr / 2`` right for a roll damper.

    Examples
    --------
    >>> element_row("heave_front", 1.2).tolist(), element_row("roll_rear", 0.8).tolist()
    ([0.6, 0.6, 0.0, 0.0], [0.0, 0.0, 0.4, -0.4])
    """
    if element not in THIRD_ELEMENTS:
        raise ValueError(f"unknown third element {element!r}; one of {list(THIRD_ELEMENTS)}")
    left, right = _AXLE_CORNERS[element_axle(element)]
    row = np.zeros(4)
    row[left] = mr / 2.0
    row[right] = (mr if element.startswith("heave") else -mr) / 2.0
    return row


@dataclass(frozen=True)
class ThirdElements:
    """The third elements a car carries (the session's ``third_elements``).

    Attributes
    ----------
    motion_ratios : dict of str to float
        Element (:data:`THIRD_ELEMENTS`, in that order) -> motion ratio (> 0); only the
        declared elements.
    """

    motion_ratios: dict = field(default_factory=dict)

    def __bool__(self):
        return bool(self.motion_ratios)

    @property
    def elements(self):
        """tuple of str: The declared elements, in :data:`THIRD_ELEMENTS` order."""
        return tuple(self.motion_ratios)

    def row(self, element):
        """:func:`element_row` of a declared element."""
        return element_row(element, self.motion_ratios[element])


@dataclass(frozen=True)
class RunThird:
    """What one run fitted of the third elements (a run's ``third``, ``heave_springs``,
    ``heave_packers``).

    Attributes
    ----------
    dampers : dict of str to (str or None)
        Element (every one of :data:`THIRD_ELEMENTS`) -> its damper's shock-library id (a
        setting name such as ``TTX@ls=6`` for an adjustable shock), or None: not fitted.
    heave_springs : dict of str to (str or None)
        Axle (``front``, ``rear``) -> the heave spring's bump-stop-library id, or None.
    heave_packers_m : dict of str to float
        Axle -> packer thickness at the heave spring [m] (0: none).
    """

    dampers: dict = field(default_factory=lambda: dict.fromkeys(THIRD_ELEMENTS))
    heave_springs: dict = field(default_factory=lambda: dict.fromkeys(AXLES))
    heave_packers_m: dict = field(default_factory=lambda: dict.fromkeys(AXLES, 0.0))

    def __bool__(self):
        return any(v is not None for v in self.dampers.values()) or any(
            v is not None for v in self.heave_springs.values())


@dataclass(frozen=True)
class CarThird:
    """The third elements an identified model carries (``VehicleModel.third``).

    What the session declared of its heave and roll elements, kept with the model so that
    predictions put the same elements in the loop: the car's elements with their motion
    ratios and what the model's baseline run fitted (a setup without third-element columns
    keeps the baseline's). The dampers are ids in the shock library the planner is given;
    the heave springs ids in the model's bump-stop library
    (``VehicleModel.elements.bump_stops``).

    Attributes
    ----------
    elements : ThirdElements
        The declared elements and their motion ratios.
    baseline : RunThird
        The baseline run's dampers, heave springs and packers.

    Examples
    --------
    >>> car = CarThird(ThirdElements({"heave_front": 1.0}),
    ...                RunThird(dampers={"heave_front": "H1"}))
    >>> CarThird.from_dict(car.to_dict()) == car
    True
    """

    elements: ThirdElements
    baseline: RunThird = field(default_factory=RunThird)

    def __post_init__(self):
        if not isinstance(self.elements, ThirdElements):
            raise TypeError(f"CarThird: elements must be a ThirdElements, got "
                            f"{type(self.elements).__name__}")
        if not isinstance(self.baseline, RunThird):
            raise TypeError(f"CarThird: baseline must be a RunThird, got "
                            f"{type(self.baseline).__name__}")
        dampers = dict.fromkeys(THIRD_ELEMENTS)
        dampers.update(self.baseline.dampers)
        springs = dict.fromkeys(AXLES)
        springs.update(self.baseline.heave_springs)
        packers = dict.fromkeys(AXLES, 0.0)
        packers.update({a: float(v) for a, v in self.baseline.heave_packers_m.items()})
        object.__setattr__(self, "baseline", RunThird(dampers, springs, packers))

    def to_dict(self):
        """JSON-able dict (SI): ``motion_ratios``, ``dampers``, ``heave_springs``,
        ``heave_packers_m``."""
        return {"motion_ratios": dict(self.elements.motion_ratios),
                "dampers": dict(self.baseline.dampers),
                "heave_springs": dict(self.baseline.heave_springs),
                "heave_packers_m": {a: float(v) for a, v in
                                    self.baseline.heave_packers_m.items()}}

    @classmethod
    def from_dict(cls, d):
        """The third elements :meth:`to_dict` wrote.

        Raises
        ------
        ValueError
            If `d` is not such a dict.
        """
        if not isinstance(d, dict) or "motion_ratios" not in d:
            raise ValueError(f"CarThird.from_dict: a dict with motion_ratios is needed, got "
                             f"{d!r}; the model file's third elements are damaged")
        return cls(ThirdElements({k: float(v) for k, v in d["motion_ratios"].items()}),
                   RunThird(dict(d.get("dampers") or {}), dict(d.get("heave_springs") or {}),
                            dict(d.get("heave_packers_m") or {})))


def check_third_elements(value, where):
    """The session's ``third_elements`` table, checked.

    Parameters
    ----------
    value : mapping of str to float, or None
        Element -> motion ratio (``{ heave_front = 1.0, roll_front = 0.8 }``).
    where : str
        The file (and key) put first in messages.

    Returns
    -------
    ThirdElements
        Empty for None.

    Raises
    ------
    SessionError
        On a key that is not an element, or a motion ratio that is not a finite number > 0.
    """
    if value is None:
        return ThirdElements()
    if not isinstance(value, dict):
        raise SessionError(f"{where}: third_elements must be a table {{ heave_front = 1.0, "
                           f"... }} of motion ratios, got {value!r}")
    out = {}
    for key in value:
        if key not in THIRD_ELEMENTS:
            raise SessionError(f"{where}: third_elements {key!r} is not a third element"
                               f"{_hint(key, THIRD_ELEMENTS)}; the elements are "
                               f"{', '.join(THIRD_ELEMENTS)}")
    for key in THIRD_ELEMENTS:
        if key not in value:
            continue
        mr = value[key]
        if not is_real_number(mr) or not np.isfinite(mr) or mr <= 0:
            raise SessionError(f"{where}: third_elements {key} = {mr!r} is not a motion ratio; "
                               "give a number > 0 (the element's travel per unit of the "
                               "axle's mean or half-difference shock travel)")
        out[key] = float(mr)
    return ThirdElements(out)


def _hint(key, known):
    close = difflib.get_close_matches(str(key), known, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _id_or_none(value, where):
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        raise SessionError(f"{where} = {value!r} is not an id; give a library id or \"none\"")
    return None if value.strip().lower() == "none" else value


def check_run_third(third, heave_springs, heave_packers_m, *, elements, shocks, bump_stops,
                    where, library="of the session"):
    """A run's third elements, checked against the session's elements and libraries.

    Parameters
    ----------
    third : mapping of str to str, or None
        Element -> damper id (``"none"``: not fitted).
    heave_springs : mapping of str to str, or None
        Axle -> heave spring id in the bump-stop library (``"none"``: none).
    heave_packers_m : mapping of str to float, or None
        Axle -> packer thickness [m] (SI already).
    elements : ThirdElements
        The session's declared elements.
    shocks : mapping
        The shock library (ids, setting names resolved by ``in``).
    bump_stops : mapping or None
        The bump-stop library (None: the session names none).
    where : str
        The run (and file), put first in messages.
    library : str
        How the messages name the shock library.

    Returns
    -------
    RunThird

    Raises
    ------
    SessionError
        An element the session does not declare (``third_elements``), a damper not in the
        shock library, an axle that is not ``front``/``rear``, a heave spring without a
        bump-stop library or not in it, a heave spring or packer on an axle without a
        declared heave element, or a packer that is negative or thicker than the spring's
        gap (a negative gap).
    """
    dampers = dict.fromkeys(THIRD_ELEMENTS)
    if third is not None and not isinstance(third, dict):
        raise SessionError(f"{where}: third must be a table {{ heave_front = \"H1\", ... }} "
                           f"of damper ids, got {third!r}")
    for key, sid in (third or {}).items():
        if key not in THIRD_ELEMENTS:
            raise SessionError(f"{where}: third {key!r} is not a third element"
                               f"{_hint(key, THIRD_ELEMENTS)}; the elements are "
                               f"{', '.join(THIRD_ELEMENTS)}")
        sid = _id_or_none(sid, f"{where}: third {key}")
        if sid is None:
            continue
        if key not in elements.motion_ratios:
            raise SessionError(f"{where}: third {key} = {sid!r} but the session does not "
                               f"declare {key}; add it with its motion ratio to the "
                               f"manifest's third_elements (e.g. {key} = 1.0), or remove it "
                               "from the run")
        if sid not in shocks:
            raise SessionError(f"{where}: third {key} = {sid!r} is not in the shock library "
                               f"{library} (known ids: {', '.join(map(str, shocks)) or 'none'})"
                               "; add the damper to the library or fix the id")
        dampers[key] = sid
    springs = dict.fromkeys(AXLES)
    packers = dict.fromkeys(AXLES, 0.0)
    for key, table in (("heave_springs", heave_springs), ("heave_packers", heave_packers_m)):
        if table is None:
            continue
        if not isinstance(table, dict):
            raise SessionError(f"{where}: {key} must be a table {{ front = ..., rear = ... }}, "
                               f"got {table!r}")
        for axle in table:
            if axle not in AXLES:
                raise SessionError(f"{where}: {key} {axle!r} is not an axle"
                                   f"{_hint(axle, AXLES)}; use front or rear")
    for axle, sid in (heave_springs or {}).items():
        sid = _id_or_none(sid, f"{where}: heave_springs {axle}")
        if sid is not None:
            sid = parse_bump_stop_id(sid, f"{where}: heave_springs {axle}", error=SessionError)
        if sid is None:
            continue
        if f"heave_{axle}" not in elements.motion_ratios:
            raise SessionError(f"{where}: heave_springs {axle} = {sid!r} but the session does "
                               f"not declare heave_{axle}; add it with its motion ratio to the "
                               f"manifest's third_elements (heave_{axle} = 1.0), or remove it "
                               "from the run")
        if bump_stops is None:
            raise SessionError(f"{where}: heave_springs {axle} = {sid!r} but the session has no "
                               "bump-stop library; name it at the top of the manifest with "
                               "bump_stop_library = \"bumpstops.toml\" (a heave spring is a "
                               "bump-stop entry), or remove the run's heave_springs")
        if sid not in bump_stops:
            raise bump_stops.unknown_id_error(sid, where=f"{where}: heave_springs {axle}",
                                              error=SessionError)
        springs[axle] = sid
    for axle, p in (heave_packers_m or {}).items():
        w = f"{where}: heave_packers {axle}"
        if springs[axle] is not None:
            packers[axle] = float(check_packer(bump_stops[springs[axle]], p, w,
                                               error=SessionError))
            continue
        if not is_real_number(p) or not np.isfinite(p) or p < 0:
            raise SessionError(f"{w} = {p!r} is not a thickness; give a number >= 0 (0 = none)")
        if p:
            raise SessionError(f"{w} = {p!r} but the run has no heave spring {axle}; give it "
                               f"one in heave_springs ({axle} = \"...\") or remove the packer")
    return RunThird(dampers=dampers, heave_springs=springs, heave_packers_m=packers)
