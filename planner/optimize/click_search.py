"""The continuous optimum mapped to the crate's adjustable shocks: the best clicks per group.

:func:`optimize_curves` finds the best curve per corner group and maps it to the
crate's fixed shocks (every adjustable at its default setting). An adjustable shock
(:class:`~ident.models.adjustable.AdjustableShock`) is a family of curves, one per
setting of its adjusters; :func:`search_clicks` finds, for each adjustable shock of
the crate, the settings per corner group that score best in the time domain:

1. **Starts.** Per group, the setting whose curve is nearest a target curve, by
   :func:`curve_distance` (the relative RMS force difference over the shock velocities
   the optimum excites at the group's corners: the distance the crate mapping uses),
   over the adjuster grid (every setting on its steps; thinned to at most
   :data:`MAX_START_SETTINGS`). The targets are the continuous optimum's curves
   ("optimum") and the crate's best setup's curves ("crate best"): the second start
   makes the result no worse than the crate's best wherever the adjustable's range
   covers it.
2. **Neighbourhood search.** From each start: every move of one adjuster of one group
   by +-1..`radius` steps is simulated (one batch), and the best is taken if it
   improves the score (a feasible setup before an infeasible one), then up to
   :data:`LINE_STEPS` further moves along it (one batch) where they improve; when no such move
   improves, the +-1 step product neighbourhood (every adjuster of every group moved by
   -1, 0 or +1 step: ``3**n - 1`` setups, or per group when that is more than
   :data:`MAX_POLISH_NEIGHBOURS`) is simulated too, and the search goes on from an
   improving one. It stops when none improves: the result is at least as good as every
   setting one step away in every adjuster. Scores are cached: no setting is simulated
   twice.
3. The better of the starts' results is the adjustable's best.

The scores come from the caller's ``score`` function (the optimizer's time-domain
verification, :func:`planner.optimize.scan.time_domain_scores`). Settings are in the
adjusters' own units (clicks or turns).
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ident.models.adjustable import SETTING_ATOL, format_shock_name
from ident.models.shocks import TableShock
from planner.setups import Setup

__all__ = [
    "CLICK_RADIUS",
    "MAX_POLISH_NEIGHBOURS",
    "MAX_START_SETTINGS",
    "MAX_ROUNDS",
    "LINE_STEPS",
    "ClickSearch",
    "ClickResult",
    "curve_distance",
    "click_axes",
    "nearest_setting",
    "search_clicks",
]

logger = logging.getLogger(__name__)

#: Steps per move of one adjuster in the search (+-1..CLICK_RADIUS): two clicks see past a
#: flat step (a bleed adjuster's last clicks change little) at twice the cost of one.
CLICK_RADIUS = 2
#: The +-1 step product neighbourhood over every adjuster of every group is simulated when it
#: has at most this many setups (2 adjusters x 2 groups: 80); beyond, per group.
MAX_POLISH_NEIGHBOURS = 80
#: Further moves along an improving move's direction simulated with it (one batch): a
#: setting sliding over its range (a quarter-turn adjuster from 2 turns to 0) takes a few
#: rounds, not one per move.
LINE_STEPS = 3
#: Settings compared by curve distance for a start, at most (the grid is thinned by whole
#: steps beyond: the time-domain search refines the start).
MAX_START_SETTINGS = 5000
#: Search rounds at most per start (each strictly improves; a guard on cost).
MAX_ROUNDS = 100


def curve_distance(pwl_a, pwl_b, v_samples):
    """RMS difference of two curves over velocity samples, relative to the second's RMS force.

    Parameters
    ----------
    pwl_a, pwl_b : PiecewiseLinear
    v_samples : ndarray
        Shock velocities [m/s] (the distribution the curves are compared over).

    Returns
    -------
    float
    """
    fa, fb = pwl_a.force(v_samples), pwl_b.force(v_samples)
    return float(np.sqrt(np.mean((fa - fb) ** 2) / max(np.mean(fb**2), 1e-300)))


def click_axes(adjustable, max_settings=None):
    """Each adjuster's settings on its steps (the range's ends always in).

    Parameters
    ----------
    adjustable : AdjustableShock
    max_settings : int, optional
        Thin the steps (by whole multiples, every adjuster alike) until the grid has at
        most this many settings.

    Returns
    -------
    list of ndarray
        Per adjuster (in order), its settings, increasing.
    """
    mult = 1
    while True:
        axes = []
        for k in adjustable.names:
            lo, hi = adjustable.adjusters[k]
            st = mult * adjustable.step.get(k, 1.0)
            n = int(math.floor((hi - lo) / st + 1e-9))
            vals = [lo + j * st for j in range(n + 1)]
            if hi - vals[-1] > SETTING_ATOL:
                vals.append(hi)
            axes.append(np.array(vals, dtype=float))
        if max_settings is None or math.prod(a.size for a in axes) <= max_settings or \
                all(a.size <= 2 for a in axes):
            return axes
        mult *= 2


def _settings(names, axes, idx):
    return {k: float(axes[a][i]) for a, (k, i) in enumerate(zip(names, idx))}


def nearest_setting(adjustable, axes, targets, velocity_m_s, corners):
    """The setting whose curve is nearest the target curves at some corners.

    Parameters
    ----------
    adjustable : AdjustableShock
    axes : list of ndarray
        Each adjuster's settings (:func:`click_axes`).
    targets : dict of str -> PiecewiseLinear
        The target curve per corner.
    velocity_m_s : dict of str -> ndarray
        The shock velocities [m/s] per corner the curves are compared over.
    corners : sequence of str
        The group's corners: the distance is the RMS over them of :func:`curve_distance`.

    Returns
    -------
    index : tuple of int
        Per adjuster, the index of the setting in its axis.
    distance : float
    """
    best = None
    for idx in itertools.product(*(range(a.size) for a in axes)):
        v, f = adjustable.curve(_settings(adjustable.names, axes, idx))
        pwl = TableShock("candidate", v, f).to_pwl()
        d = math.sqrt(np.mean([curve_distance(pwl, targets[c], velocity_m_s[c]) ** 2
                               for c in corners]))
        if best is None or d < best[1]:
            best = (idx, d)
    return best


@dataclass(frozen=True, eq=False)
class ClickSearch:
    """The best settings of one adjustable shock per corner group (:func:`search_clicks`).

    Attributes
    ----------
    shock : str
        The adjustable's id.
    adjusters : tuple of str
    groups : tuple of (str, tuple of str)
        The corner groups (name, corners).
    settings : dict of str -> dict of str -> float
        Per group, each adjuster's setting (clicks or turns).
    setup : planner.setups.Setup
        The setup: each corner on the shock at its group's setting (canonical names).
    score : float
        Its verified score (time domain).
    feasible : bool
    start : str
        The start the best came from (``"optimum"`` or ``"crate best"``).
    starts : pandas.DataFrame
        Per start: ``start``, ``settings`` (the start's setup), ``distance`` (per group,
        to the start's target curves), ``start_score``, ``score`` (the search's result),
        ``rounds``.
    moves : pandas.DataFrame
        Every improving move: ``start``, ``round``, ``kind`` (``"move"``: one adjuster;
        ``"polish"``: the +-1 product), ``setup``, ``score``.
    n_simulated : int
        Settings simulated (each once).
    polish : str
        ``"full"`` (the +-1 product over every group) or ``"per group"``.
    """

    shock: str
    adjusters: tuple
    groups: tuple
    settings: dict
    setup: Setup
    score: float
    feasible: bool
    start: str
    starts: pd.DataFrame
    moves: pd.DataFrame
    n_simulated: int
    polish: str

    def names(self):
        """dict of str -> str: per group, the setting's name (``"TTX@ls=6,hs=2"``)."""
        return {g: format_shock_name(self.shock, s, self.adjusters)
                for g, s in self.settings.items()}


@dataclass(frozen=True, eq=False)
class ClickResult:
    """The crate's adjustables mapped from the continuous optimum (``CurveOptimum.clicks``).

    Attributes
    ----------
    searches : tuple of ClickSearch
        One per adjustable shock searched, in library order.
    skipped : dict of str -> str
        Adjustables not searched, with the reason (inventory).
    crate_best : str
        The best fixed setup (the crate's fixed shocks and its adjustables at their
        default, as the crate mapping found it).
    crate_best_score, optimum_score : float
        Verified scores of the best fixed setup and of the continuous optimum.
    radius : int
        Steps per move (+-1..radius).
    settings : dict
        ``search_s`` (the search's wall time, with the final verification [s]) and
        ``n_simulated`` (settings simulated, every adjustable).
    """

    searches: tuple
    skipped: dict
    crate_best: str
    crate_best_score: float
    optimum_score: float
    radius: int
    settings: dict = field(default_factory=dict)

    @property
    def best(self):
        """ClickSearch or None: the best search (a feasible one first)."""
        if not self.searches:
            return None
        return min(self.searches, key=lambda s: (not s.feasible, s.score))

    @property
    def gain(self):
        """float: ``1 - score(clicks) / score(best fixed)`` (> 0: the clicks are better)."""
        b = self.best
        return float("nan") if b is None else float(1.0 - b.score / self.crate_best_score)

    @property
    def gap(self):
        """float: ``1 - score(optimum) / score(clicks)``: what a custom valving adds over the
        best clicks (> 0 when the continuous optimum is better)."""
        b = self.best
        return float("nan") if b is None else float(1.0 - self.optimum_score / b.score)

    def table(self):
        """One row per adjustable and corner group: ``shock``, ``group``, ``corners``, one
        column per adjuster (blank for another shock's), ``setting`` (the name),
        ``score``, ``feasible``, ``gain`` and ``gap`` (of the adjustable's best setup),
        ``start``, ``rounds``, ``simulated``.

        Returns
        -------
        pandas.DataFrame
        """
        adj = []
        for s in self.searches:
            adj += [a for a in s.adjusters if a not in adj]
        rows = []
        for s in self.searches:
            rounds = int(s.starts.loc[s.starts["start"] == s.start, "rounds"].iloc[0])
            for g, corners in s.groups:
                row = {"shock": s.shock, "group": g, "corners": ",".join(corners)}
                row.update({a: s.settings[g].get(a, np.nan) for a in adj})
                row.update(setting=s.names()[g], score=s.score, feasible=s.feasible,
                           gain=1.0 - s.score / self.crate_best_score,
                           gap=1.0 - self.optimum_score / s.score, start=s.start,
                           rounds=rounds, simulated=s.n_simulated)
                rows.append(row)
        cols = ["shock", "group", "corners"] + adj + ["setting", "score", "feasible", "gain",
                                                      "gap", "start", "rounds", "simulated"]
        return pd.DataFrame(rows, columns=cols)

    def verdict(self):
        """One sentence: the best clicks against the best fixed setup and the optimum."""
        b = self.best
        if b is None:
            why = "; ".join(f"{k}: {v}" for k, v in self.skipped.items())
            return f"no adjustable shock searched ({why})"
        gain = (f"{100 * self.gain:.2f} % better than" if self.gain >= 0 else
                f"{-100 * self.gain:.2f} % worse than")
        gap = (f"the continuous optimum ({self.optimum_score:.4f}) is {100 * self.gap:.2f} % "
               "better still: what a custom valving would add" if self.gap >= 0 else
               f"they beat the continuous optimum ({self.optimum_score:.4f}) by "
               f"{-100 * self.gap:.2f} %: the curve constraints keep it from the clicker's "
               "curves")
        return (f"{b.shock} in clicks ({b.score:.4f}) is {gain} the best fixed setup "
                f"{self.crate_best} ({self.crate_best_score:.4f}); {gap}")


def _step_neighbours(cur, sizes, radius):
    out = []
    for j, n in enumerate(sizes):
        for d in range(1, radius + 1):
            for sgn in (-1, 1):
                k = cur[j] + sgn * d
                if 0 <= k < n:
                    out.append(cur[:j] + (k,) + cur[j + 1:])
    return out


def _line(prev, cur, sizes, n):
    """Up to `n` further steps from `cur` along the move ``cur - prev``, within range."""
    d = tuple(b - a for a, b in zip(prev, cur))
    out = []
    for m in range(1, n + 1):
        p = tuple(c + m * x for c, x in zip(cur, d))
        if not all(0 <= p[j] < sizes[j] for j in range(len(p))):
            break
        out.append(p)
    return out


def _product_neighbours(cur, sizes, blocks):
    out = []
    for block in blocks:
        for delta in itertools.product((-1, 0, 1), repeat=len(block)):
            if not any(delta):
                continue
            p = list(cur)
            for j, d in zip(block, delta):
                p[j] += d
            if all(0 <= p[j] < sizes[j] for j in block):
                out.append(tuple(p))
    return out


def search_clicks(library, groups, targets, velocity_m_s, score, *, radius=CLICK_RADIUS,
                  name_format="{LF}/{RF}/{LR}/{RR}"):
    """The best settings per corner group of each adjustable shock of a crate.

    See the module docstring for the search.

    Parameters
    ----------
    library : ident.models.library.ShockLibrary
        The crate; its adjustable entries are searched (an adjustable with a ``count``
        below the corners it would fill is skipped, with the reason).
    groups : sequence of (str, sequence of str)
        The corner groups (name, corners), e.g. ``CurveSpace.groups``.
    targets : dict of str -> dict of str -> PiecewiseLinear
        Per start label (``"optimum"``, ``"crate best"``), the target curve per corner.
    velocity_m_s : dict of str -> ndarray
        Per corner, the shock velocities [m/s] the curves are compared over.
    score : callable
        ``score(setups) -> {setup name: (feasible, score)}``, verified in the time domain.
    radius : int
        Steps per move, +-1..radius (>= 1).
    name_format : str
        The setups' names (fields ``LF RF LR RR``: the corners' setting names).

    Returns
    -------
    searches : list of ClickSearch
    skipped : dict of str -> str
    """
    if not (isinstance(radius, int) and radius >= 1):
        raise ValueError(f"click radius {radius!r} must be an integer >= 1 (steps per move)")
    groups = tuple((str(g), tuple(cs)) for g, cs in groups)
    n_corners = sum(len(cs) for _, cs in groups)
    searches, skipped = [], {}
    for sid in library.adjustable_ids:
        adj = library.adjustable(sid)
        if adj.count is not None and adj.count < n_corners:
            skipped[sid] = (f"count {adj.count} < the {n_corners} corners it would fill; "
                            "give its count")
            continue
        searches.append(_search_shock(adj, groups, targets, velocity_m_s, score, radius,
                                      name_format))
    return searches, skipped


def _search_shock(adj, groups, targets, velocity_m_s, score, radius, name_format):
    names = adj.names
    axes = click_axes(adj)
    start_axes = click_axes(adj, MAX_START_SETTINGS)
    A = len(names)
    sizes = tuple(a.size for a in axes) * len(groups)
    n_dim = len(sizes)
    if 3 ** n_dim - 1 <= MAX_POLISH_NEIGHBOURS:
        blocks, polish = [tuple(range(n_dim))], "full"
    else:
        blocks, polish = [tuple(range(g * A, (g + 1) * A)) for g in range(len(groups))], \
            "per group"

    def settings_of(p):
        return {g: _settings(names, axes, p[k * A:(k + 1) * A])
                for k, (g, _) in enumerate(groups)}

    def setup_of(p):
        per = settings_of(p)
        ids = {c: format_shock_name(adj.id, per[g], names) for g, cs in groups for c in cs}
        return Setup(name_format.format(**ids), ids)

    cache = {}

    def evaluate(points):
        new = list(dict.fromkeys(p for p in points if p not in cache))
        if new:
            setups = [setup_of(p) for p in new]
            res = score(setups)
            for p, s in zip(new, setups):
                feasible, sc = res[s.name]
                cache[p] = (not bool(feasible), float(sc))

    starts, moves, results = [], [], []
    for label, target in targets.items():
        idx, dist = [], []
        for g, cs in groups:
            i, d = nearest_setting(adj, start_axes, target, velocity_m_s, cs)
            # the thinned grid's setting on the full axes
            idx += [int(np.argmin(np.abs(axes[a] - start_axes[a][i[a]]))) for a in range(A)]
            dist.append(d)
        cur = tuple(idx)
        evaluate([cur])
        start_key, rounds = cache[cur], 0
        while rounds < MAX_ROUNDS:
            rounds += 1
            moved = False
            for kind in ("move", "polish"):
                cand = (_step_neighbours(cur, sizes, radius) if kind == "move" else
                        _product_neighbours(cur, sizes, blocks))
                evaluate(cand)
                if not cand:
                    continue
                best = min(cand, key=lambda p: (cache[p], p))
                if cache[best] < cache[cur]:
                    prev, cur, moved = cur, best, True
                    moves.append({"start": label, "round": rounds, "kind": kind,
                                  "setup": setup_of(cur).name, "score": cache[cur][1]})
                    # on along the move's direction (a ridge of one adjuster), in one batch
                    line = _line(prev, cur, sizes, LINE_STEPS)
                    evaluate(line)
                    if line:
                        best = min(line, key=lambda p: (cache[p], p))
                        if cache[best] < cache[cur]:
                            cur = best
                            moves.append({"start": label, "round": rounds, "kind": "line",
                                          "setup": setup_of(cur).name,
                                          "score": cache[cur][1]})
                    break
            if not moved:
                break
        else:
            logger.warning("click search of %r from the %s: stopped after %d rounds", adj.id,
                           label, MAX_ROUNDS)
        starts.append({"start": label, "settings": setup_of(tuple(idx)).name,
                       "distance": dist, "start_score": start_key[1],
                       "score": cache[cur][1], "rounds": rounds})
        results.append((cache[cur], len(results), cur, label))
    key, _, cur, label = min(results)
    logger.info("click search of %r: %s, score %.4f (%d settings simulated)", adj.id,
                setup_of(cur).name, key[1], len(cache))
    return ClickSearch(shock=adj.id, adjusters=names, groups=groups,
                       settings=settings_of(cur), setup=setup_of(cur), score=key[1],
                       feasible=not key[0], start=label, starts=pd.DataFrame(starts),
                       moves=pd.DataFrame(moves, columns=["start", "round", "kind", "setup",
                                                          "score"]),
                       n_simulated=len(cache), polish=polish)

