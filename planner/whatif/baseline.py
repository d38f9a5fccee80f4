"""The what-if study's baseline when none is given: a ranking's own.

``shockplan whatif --ranking ranking.csv`` studies a ranking's best setups; its scores are
ratios to a baseline, and :func:`whatif_baseline` keeps the ranking's (the setup its
``baseline`` column marks, :func:`planner.setups.read_ranking_baseline`), so that the
what-if scores mean what the ranking's mean, even when that setup is beyond the setups
studied.
"""

from __future__ import annotations

from planner.setups import read_ranking_baseline

__all__ = ["whatif_baseline"]


def whatif_baseline(baseline=None, *, ranking=None, ranked=()):
    """The baseline of a what-if study.

    Parameters
    ----------
    baseline : planner.setups.Setup or None
        The baseline given (``--baseline``): taken as it is.
    ranking : str or path, optional
        The ranking CSV the setups come from (``shockplan rank``'s ``ranking.csv``).
    ranked : sequence of planner.setups.Setup
        Every setup of `ranking` (not only those studied), read with
        :func:`planner.setups.read_setups`.

    Returns
    -------
    planner.setups.Setup or None
        `baseline` if given; else the ranking's own baseline (not its best setup) found
        among `ranked`; None without a ranking, when the ranking marks no baseline, or
        when its baseline is not among `ranked` (the objective's baseline, else the first
        setup, is then used by :func:`planner.whatif.evaluate_whatif`).

    Raises
    ------
    planner.errors.PlannerError
        If the ranking cannot be read or marks more than one baseline
        (:func:`planner.setups.read_ranking_baseline`).
    """
    if baseline is not None or ranking is None:
        return baseline
    name = read_ranking_baseline(ranking)
    if name is None:
        return None
    return next((s for s in ranked if s.name == name), None)
