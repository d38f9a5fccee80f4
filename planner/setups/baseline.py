"""The baseline of a command, from its one syntax (:func:`resolve_baseline`): a
:class:`~planner.setups.setup.Setup`, a listed setup's name, one shock id (every corner)
or four ids ``"LF,RF,LR,RR"``.
"""

from __future__ import annotations

import logging

from ident.data.channels import CORNERS
from planner.click_settings import canonical_id, split_shock_ids
from planner.errors import PlannerError
from planner.setups.setup import Setup, library_label

__all__ = [
    "resolve_baseline",
]

logger = logging.getLogger(__name__)


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
    >>> from planner.setups import enumerate_setups
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
                               f"LF,RF,LR,RR; {library_label(library)} has {list(library)}; give "
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
