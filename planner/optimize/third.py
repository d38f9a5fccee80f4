"""A car's third elements in a curve optimization (issue 38): the baseline's, the free
third dampers' check and the crate's third-element choices.

:func:`optimize_third` resolves the car's heave and roll dampers and heave springs that
every verification of :func:`planner.optimize.optimize_curves` keeps (the baseline's);
:func:`check_free_third` checks ``CurveOptions.free_third`` against them; and
:func:`crate_choices` gives the choices the crate's best is searched over (``--try-heave``,
or the crate's dampers that fit a free element), which :meth:`OptimizeThird.crate`
enumerates on the crate's corner setups.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.elements import (
    corner_shock_ids,
    distinct_setups,
    setup_third,
    vary_third,
)
from planner.errors import PlannerError
from planner.screen import third_choices

__all__ = ["OptimizeThird", "optimize_third", "check_free_third", "crate_choices"]


@dataclass(frozen=True, eq=False)
class OptimizeThird:
    """The car's third elements in an optimization (issue 38): the car
    (:class:`ident.data.third.CarThird`), the heave springs' library and the baseline's
    resolved elements, the loop's ``(dampers, springs)`` entry every setup is verified with."""

    car: object
    springs: object
    entry: tuple
    # the crate's third-element choices (a setups-CSV column -> ids, as vary_third takes
    # them): the mapping searches the crate's best over them too (empty: the baseline's)
    choices: dict = field(default_factory=dict)

    @property
    def names(self):
        """tuple of str: the car's declared third elements."""
        return tuple(self.car.elements.elements)

    def screening(self, setups, library):
        """The screening's third elements of `setups` (each keeps the car's baseline)."""
        return third_choices(setup_third(setups, self.car, library, bump_stops=self.springs,
                                         where="optimize"))

    def corner_ids(self, library):
        """The library's ids the crate puts at the corners (not the third elements', nor
        those the crate's third choices try)."""
        return corner_shock_ids(library, self.car, self.choices or None)

    def crate(self, setups, library, where="optimize: the crate"):
        """The crate's setups with every third-element choice (:attr:`choices`,
        :func:`planner.elements.vary_third`; each setup as given first, repeats dropped) and,
        by name, the loop's ``(dampers, springs)`` entry of each one naming its own third
        elements, and per setup returned the index in `setups` of its corner setup. Without
        choices: `setups`, no entries, ``range(len(setups))``."""
        setups = list(setups)
        if not self.choices:
            return setups, {}, np.arange(len(setups))
        got = vary_third(setups, self.choices, car=self.car, where=where)
        per = len(got) // max(len(setups), 1)  # each setup, then its variants
        resolved = setup_third(got, self.car, library, bump_stops=self.springs, where=where)
        # (a variant that is its setup with the car's own third elements, or repeats another
        # variant, is dropped; the setups themselves are kept, the baseline among them)
        _, keep = distinct_setups(got, None, resolved)
        keep = np.union1d(keep, np.arange(0, len(got), per))
        got = [got[k] for k in keep]
        own = {s.name: resolved.entries[k] for s, k in zip(got, keep)
               if s.third or s.heave_springs}
        return got, own, keep // per


def optimize_third(model, base, library, elements):
    """The car's third elements of an optimization: the baseline's heave and roll dampers
    and heave springs, kept in every verification.

    Parameters
    ----------
    model : object
        The model (its ``third``, unless `elements` gives the car's).
    base : planner.setups.Setup
        The baseline (its corner shocks only).
    library : ShockLibrary
        The crate (the dampers' ids).
    elements : planner.options.ElementOptions

    Returns
    -------
    OptimizeThird or None
        None for a car without third elements.

    Raises
    ------
    PlannerError
        A baseline naming third elements; an unknown damper or heave-spring id.
    """
    car = elements.car_third(model)
    if car is None or not car.elements.elements:
        return None
    if base.third or base.heave_springs:
        raise PlannerError(f"optimize: baseline {base.name!r} names third elements; the "
                           "optimizer keeps the car's baseline ones (model.third or "
                           "ElementOptions.third): give the baseline's corner shocks only")
    springs = elements.library(model)
    resolved = setup_third([base], car, library, bump_stops=springs, where="optimize: baseline")
    return OptimizeThird(car=car, springs=springs, entry=resolved.entries[0])


def check_free_third(free_third, third):
    """The free third dampers (``CurveOptions.free_third``), checked against the car's.

    Parameters
    ----------
    free_third : sequence of str or None
    third : OptimizeThird or None

    Returns
    -------
    tuple of str
        The free elements in the car's order (empty without).

    Raises
    ------
    PlannerError
        Free dampers on a car without third elements, an element the baseline fits no
        damper at, or one given twice.
    """
    free = tuple(free_third or ())
    if not free:
        return ()
    if third is None:
        raise PlannerError(f"optimize: free_third {list(free)} but the car has no third "
                           "elements; leave free_third out, or give the car's third elements "
                           "(model.third, ElementOptions.third)")
    fitted = [e for e in third.names if third.car.baseline.dampers.get(e) is not None]
    bad = [e for e in free if e not in fitted]
    if bad or len(set(free)) < len(free):
        raise PlannerError(f"optimize: free_third {list(free)}: {bad or 'an element twice'} "
                           f"is not a third damper the car's baseline fits (it fits "
                           f"{fitted}); free each of those at most once")
    return tuple(e for e in third.names if e in free)


def crate_choices(third, library, vary, free):
    """The crate's third-element choices of an optimization (:attr:`OptimizeThird.choices`).

    The given ones (``ElementOptions.vary_third``, ``--try-heave``, ...) and, for a free
    third damper they leave out, the crate's dampers that fit such an element (their
    ``fits``, ``"heave"`` or ``"roll"``) besides the baseline's: the optimum's freedom is
    the crate's too, so its gain over the crate's best is a fair one.

    Parameters
    ----------
    third : OptimizeThird or None
    library : ShockLibrary
        The crate.
    vary : mapping of str to sequence, optional
        A setups-CSV column (``heave_front``, ``roll_rear``, ``heave_spring_front``) -> ids.
    free : tuple of str
        The free third dampers (:func:`check_free_third`).

    Returns
    -------
    dict of str to tuple
        Column -> ids (``"none"``: not fitted); empty: the crate keeps the baseline's.

    Raises
    ------
    PlannerError
        Choices on a car without third elements.
    """
    if third is None:
        if vary:
            raise PlannerError(f"optimize: third-element choices {dict(vary)} (vary_third, "
                               "--try-heave) but the car has no third elements; leave them "
                               "out, or give the car's third elements (model.third, "
                               "ElementOptions.third)")
        return {}
    choices = {str(k): tuple(v) for k, v in (vary or {}).items()}
    for e in free:
        if e in choices:
            continue
        kind = e.partition("_")[0]
        base = third.car.baseline.dampers.get(e)
        ids = tuple(sid for sid in library
                    if getattr(library[sid], "fits", None) == kind and sid != base)
        if ids:
            choices[e] = ids
    return choices
