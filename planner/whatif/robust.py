"""Robust ranks: how a setup's score and rank hold up over the what-if's conditions.

:func:`robust_table` turns the long what-if table (one row per drive, perturbation and
setup, scored and ranked within each condition) into one row per setup: nominal, mean
and worst score and rank, the share of conditions it ranks first or moves in, and
whether its rank is *fragile* (it moves more than :data:`RANK_TOLERANCE` places in more
than :data:`FRAGILE_SHARE` of the conditions).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["RANK_TOLERANCE", "FRAGILE_SHARE", "robust_table"]

#: A rank moving more than this many places from the nominal one counts as a move (a
#: swap with a neighbour is a near-tie, which the ranking's intervals already flag).
RANK_TOLERANCE = 1
#: A setup whose rank moves (see RANK_TOLERANCE) in more than this share of the
#: conditions is fragile: one condition in ten reorders it past a neighbour.
FRAGILE_SHARE = 0.1


def robust_table(table, names, rank_tolerance, fragile_share):
    """One row per setup: how its score and rank move over the conditions.

    Parameters
    ----------
    table : pandas.DataFrame
        The what-if table: columns ``perturbation``, ``setup``, ``score``, ``rank``,
        ``rank_change`` (against the setup's nominal rank) and ``feasible``; the nominal
        condition's rows have ``perturbation == "nominal"``.
    names : list of str
        The setups, in order.
    rank_tolerance : int
        A rank change larger than this many places counts as a move.
    fragile_share : float
        A setup that moves in more than this share of the conditions is fragile.

    Returns
    -------
    pandas.DataFrame
        Index ``setup``, best mean score first; columns as
        :attr:`planner.whatif.WhatIf.robust` lists.
    """
    g = table.groupby("setup", sort=False)
    nominal = table[table["perturbation"] == "nominal"].groupby("setup").first()
    rob = pd.DataFrame(index=pd.Index(names, name="setup"))
    rob["nominal_rank"] = nominal.loc[names, "rank"].astype(int)
    rob["nominal_score"] = nominal.loc[names, "score"]
    rob["mean_score"] = g["score"].mean().loc[names]
    rob["worst_score"] = g["score"].max().loc[names]
    rob["mean_rank"] = g["rank"].mean().loc[names]
    rob["best_rank"] = g["rank"].min().loc[names].astype(int)
    rob["worst_rank"] = g["rank"].max().loc[names].astype(int)
    rob["best_share"] = g["rank"].apply(lambda r: float(np.mean(r == 1))).loc[names]
    rob["moved_share"] = g["rank_change"].apply(
        lambda r: float(np.mean(np.abs(r) > rank_tolerance))).loc[names]
    rob["feasible_share"] = g["feasible"].mean().loc[names]
    rob["fragile"] = rob["moved_share"] > fragile_share
    rob["rank_mean_score"] = rob["mean_score"].rank(method="min").astype(int)
    rob["rank_worst_score"] = rob["worst_score"].rank(method="min").astype(int)
    return rob.sort_values(["rank_mean_score", "nominal_rank"], kind="stable")
