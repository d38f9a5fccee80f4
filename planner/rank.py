"""Rank shock setups: screen many, simulate the best, score, attach uncertainty.

``rank_setups(model, drive, library, ...)``:

1. takes the setups given (a setups CSV) or enumerates them from the library
   with constraints (:func:`planner.setups.enumerate_setups`);
2. screens all of them in the frequency domain (:mod:`planner.screen`) and
   scores them with the objective (:mod:`planner.objective`);
3. simulates the best `top` of them (and the baseline) in the time domain with
   the nonlinear shocks (:mod:`planner.predict`) and scores those;
4. reports how well the screening ranks agree with the time-domain ranks
   (Spearman), and for an identified model gives every metric an interval, every
   setup's score an interval and its difference from the best's and the baseline's
   one, a verdict (tied with the best or worse, better than the baseline, tied or
   worse) and flags setup pairs whose order the model does not resolve
   (:mod:`planner.uncertainty`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy.stats import spearmanr

from planner.elements import (corner_shock_ids, distinct_setups, loop_arguments,
                              model_setup_elements, model_setup_third, vary_elements,
                              vary_third)
from planner.errors import PlannerError
from planner.histograms import ShockHistograms, histogram_distance
from planner.options import (ElementOptions, HistogramOptions, LoopOptions, RunOptions,
                             UncertaintyOptions, as_options)
from planner.objective import (Objective, default_objective, mark_inventory, score_setups,
                               time_domain_metrics)
from planner.predict import predict_setups
from planner.screen import describe_agreement, screen_setups, third_choices
from planner.click_settings import click_neighbours, click_values
from planner.setups import enumerate_setups, resolve_baseline
from planner.sweep import screen_setups_on
from planner.text import format_table
from planner.uncertainty import (prediction_uncertainty, score_errors, score_intervals,
                                 unresolved_pairs)

__all__ = ["Ranking", "rank_setups"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Ranking:
    """The result of :func:`rank_setups`.

    Attributes
    ----------
    table : pandas.DataFrame
        The setups simulated in the time domain, best first: shock ids, metrics
        (SI), ``<metric>_lo/_hi`` intervals (identified models), ``score``,
        ``score_<group>``, ``feasible``, ``violations``, ``rank``,
        ``screening_rank``, ``unresolved``; with intervals also
        :data:`planner.uncertainty.SCORE_INTERVAL_COLUMNS` (``score_lo/_hi``,
        ``diff_best_lo/_hi``, ``diff_baseline_lo/_hi``, ``verdict``,
        ``verdict_baseline``).
    screening : pandas.DataFrame
        Every setup's screening metrics, scores and ranks.
    baseline : str
        The setup the objective normalizes against.
    objective : planner.objective.Objective
    agreement : dict
        ``spearman`` between screening and time-domain scores over the
        simulated setups, ``n``, ``same_best``, ``time_best``, ``screening_best``,
        ``time_best_screening_rank``, ``top``, ``score_gap`` and ``polished``
        (:func:`planner.screen.describe_agreement`).
    settings : dict
    candidates : tuple of planner.setups.Setup
        The setups simulated in the time domain (the rows of `table`), with their elements:
        what :func:`planner.section_ranking.rank_sections` simulates on each section.
    histograms : planner.histograms.ShockHistograms or None
        The shock-velocity histograms of the setups simulated in the time domain, in the
        table's order (with ``loop.histograms``); None without.
    """

    table: pd.DataFrame
    screening: pd.DataFrame
    baseline: str
    objective: object
    agreement: dict
    settings: dict = field(default_factory=dict)
    candidates: tuple = ()
    histograms: object = None

    @property
    def best(self):
        """Name of the best setup: the best feasible one (the top row, even if infeasible,
        when no setup is feasible)."""
        return self.table.index[0]

    def polish_lines(self):
        """The click polish's line (``settings["click_polish"]``): none without adjustable
        settings.

        Returns
        -------
        list of str
        """
        polish = self.settings.get("click_polish")
        if not polish:
            return []
        moved = f"; it moved the best from {polish['start']}" if polish["moved"] else ""
        return [f"click polish: {polish['simulated']} neighbouring setting(s) simulated in "
                f"{polish['rounds']} round(s){moved}"]

    def verdict_lines(self):
        """The best setup and the setups tied with it, one line each (``verdict``).

        Returns
        -------
        list of str
            Without intervals (a known model, or none asked) one line: the best, ties not
            judged.
        """
        t = self.table
        best = t.index[t["verdict"] == "best"] if "verdict" in t.columns else []
        if not len(best):
            return [f"best: '{self.best}', score {t.loc[self.best, 'score']:.4f}; no "
                    "intervals (a known model, or none asked): ties with it are not judged"]
        b = best[0]
        q = (self.settings.get("uncertainty") or {}).get("quantiles", (0.025, 0.975))
        level = f"{100 * (q[1] - q[0]):g} %"
        r = t.loc[b]
        lines = [f"best: '{b}', score {r['score']:.4f} ({level} interval "
                 f"{r['score_lo']:.4f} to {r['score_hi']:.4f})"
                 + ("" if b == self.baseline else
                    f", {_versus(r['verdict_baseline'])} the baseline (difference "
                    f"{r['diff_baseline_lo']:+.4f} to {r['diff_baseline_hi']:+.4f})")]
        tied = t.index[t["verdict"] == "tied"]
        for name in tied[:MAX_TIED_LINES]:
            r = t.loc[name]
            lines.append(f"tied with the best: '{name}', score {r['score']:.4f} (difference "
                         f"from the best {r['diff_best_lo']:+.4f} to {r['diff_best_hi']:+.4f} "
                         "contains 0)")
        if len(tied) > MAX_TIED_LINES:
            lines.append(f"tied with the best: {len(tied) - MAX_TIED_LINES} more (ranking.csv's "
                         "'verdict')")
        if not len(tied):
            lines.append(f"no other feasible setup is tied with the best (no difference's "
                         f"{level} interval from it contains 0)")
        return lines

    def summary(self, n=5):
        """The ranking for a terminal: what was screened and simulated, how screening and the
        time domain agree, the click polish, the baseline, the best `n` setups and why those
        of them that are infeasible are (their ``violations``: a limit, the crate's count).

        Parameters
        ----------
        n : int
            Setups in the table.

        Returns
        -------
        str
        """
        t = self.table
        lines = [f"screened {len(self.screening)} setups, simulated {len(t)} in the time "
                 f"domain; screening vs time-domain Spearman {self.agreement['spearman']:.3f}",
                 describe_agreement(self.agreement, what="ranking"),
                 *self.polish_lines(),
                 *self.verdict_lines(),
                 f"baseline '{self.baseline}' scores {self.objective.total_weight:.3f}; best:"]
        rows = []
        judged = "verdict" in t.columns
        for name, r in t.head(n).iterrows():
            rows.append((int(r["rank"]), name, f"{r['score']:.4f}",
                         "yes" if r.get("feasible", True) else "no",
                         *((r["verdict"],) if judged else ()),
                         r.get("unresolved", "") or "-"))
        lines.append(format_table(rows, ["rank", "setup", "score", "feasible",
                                         *(("vs best",) if judged else ()),
                                         "not resolved from"]))
        lines += [f"  '{name}' is infeasible: {r.get('violations', '') or 'no reason recorded'}"
                  for name, r in t.head(n).iterrows() if not r.get("feasible", True)]
        more = int((~t["feasible"].iloc[n:].astype(bool)).sum()) if "feasible" in t else 0
        if more:
            lines.append(f"  {more} more infeasible setup(s) below these; each one's reason is "
                         "in its 'violations' (ranking.csv)")
        return "\n".join(lines)


#: At most this many "tied with the best" lines in :meth:`Ranking.summary` (then a count).
MAX_TIED_LINES = 10


def _versus(verdict):
    """``better`` -> "better than", ``tied`` -> "tied with", ..."""
    return {"better": "better than", "worse": "worse than", "tied": "tied with"}.get(
        verdict, f"{verdict} against")


#: Rounds of the click polish at most (each simulates the best's untried neighbours).
MAX_POLISH_ROUNDS = 10


def _polish_clicks(td, scores, cand, setups, library, objective, base_name, simulate):
    """Move the time domain's best to a better neighbouring click setting until none is.

    Returns (predictions, scores, candidates, summary) with the neighbours simulated added.
    """
    values = click_values(setups)
    index = {s.ids(): s for s in setups}
    start = best = scores.table["rank"].idxmin()
    simulated = set(td.table.index)
    added, rounds = 0, 0
    by_name = {c.name: c for c in cand}
    for rounds in range(1, MAX_POLISH_ROUNDS + 1):
        more = [index[ids] for ids in click_neighbours(by_name[best].ids(), values, library)
                if ids in index and index[ids].name not in simulated]
        if not more:
            break
        extra = simulate(more)
        td = replace(td, table=pd.concat([td.table, extra.table]),
                     histograms=ShockHistograms.concat([td.histograms, extra.histograms]))
        cand = cand + more
        by_name.update((m.name, m) for m in more)
        simulated.update(m.name for m in more)
        added += len(more)
        scores = score_setups(td.table, objective, baseline=base_name)
        new = scores.table["rank"].idxmin()
        if new == best:
            break
        best = new
    log.info("rank: click polish simulated %d neighbouring setting(s) in %d round(s); best "
             "%s%s", added, rounds, best, "" if best == start else f" (screening's choice "
             f"led to {start})")
    return td, scores, cand, {"simulated": added, "rounds": rounds, "start": start,
                              "best": best, "moved": best != start}


def rank_setups(model, drive, library, *, setups=None, constraints=None, objective=None,
                baseline=None, top=40, n_check=20, uncertainty=UncertaintyOptions(),
                loop=LoopOptions(), elements=ElementOptions(), run=RunOptions(),
                progress=False, polish_clicks=True, histogram_target=None):
    """Rank shock setups on a model and a drive.

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
    drive : ident.data.drive.Drive
    library : ident.models.library.ShockLibrary
    setups : sequence of planner.setups.Setup, optional
        The candidates; default: enumerated from `library` with `constraints`.
    constraints : dict, optional
        Keyword arguments of :func:`planner.setups.enumerate_setups`
        (``symmetry``, ``axles``, ``fixed``, ``shocks``, ``respect_inventory``,
        ``max_setups``, ``clicks``: the settings of adjustable shocks, ``"all"`` or a step
        per adjuster). On a car with third elements, ``shocks`` defaults to the ids that
        are not its heave or roll dampers (:func:`planner.elements.corner_shock_ids`).
    objective : planner.objective.Objective, optional
        Default :func:`planner.objective.default_objective`.
    baseline : Setup or str, optional
        The setup metrics are normalized against
        (:func:`planner.setups.resolve_baseline`): a Setup, a setup's name, one
        shock id (every corner) or four ``"LF,RF,LR,RR"``; default the
        objective's ``baseline``, else the first setup. A baseline whose shocks
        equal a listed setup's is that setup (no second row); otherwise it is
        added to the candidates (a setup built from ids is named
        ``"baseline"``). Setups that need more units of a shock
        than the library's ``count`` are infeasible (``violations`` says why).
    top : int
        Setups (best by screening) simulated in the time domain.
    n_check : int
        Further setups, spread evenly over the screening ranks below the
        top, also simulated, so that the screening/time-domain agreement is
        measured over the whole range (near the top the scores are close and
        a rank correlation among near-ties says little).
    uncertainty : planner.options.UncertaintyOptions or bool
        Attach Monte Carlo intervals and unresolved pairs (identified models only) with
        these draws (True: the defaults); False: none.
    loop : planner.options.LoopOptions
        The time-domain loop (``oversample``: internal steps per sample of the shock
        loop; ``band_hz``: the metric band [Hz], the screening's too; ``reduce_rtol``).
    elements : planner.options.ElementOptions
        The real car's elements, as :func:`planner.predict.predict_setups`: by default the
        model's bump stops (each setup's, else the baseline run's) and static loads are in
        the loop. Its choices ``vary_bump_stops``, ``vary_packers_m`` per group are
        enumerated as setup columns (:func:`planner.elements.vary_elements`): every setup
        is ranked with each combination too (e.g. ``vary_packers_m={"front": [0, 0.002,
        0.004]}``).
    run : planner.options.RunOptions
        Screen on Dask (:func:`planner.sweep.screen_setups_on`): ``scheduler``
        ``"local"`` (a LocalCluster of ``n_workers``, default one per core) or a scheduler
        address (``"tcp://host:8786"``). Default (None): in this process. The metrics,
        and so the ranking, are the same bit for bit; it pays from about 10^5 setups.
    polish_clicks : bool
        Where the time domain's best names settings of adjustable shocks, also simulate
        its neighbours among the ranked setups (every adjuster of every corner at its
        setting or the next one on the grid) and move to a better one until none is
        (at most :data:`MAX_POLISH_ROUNDS` rounds): screening orders neighbouring
        settings less well than it orders different shocks, so the decision is made in
        the time domain. ``settings["click_polish"]`` says what it simulated.
    histogram_target : planner.histograms.ShockHistograms, optional
        A target shock-velocity histogram (one row, e.g. a track log's,
        :func:`planner.histograms.histograms_of`, counted with ``loop.histograms``' bins):
        the table gets each setup's distance from it per corner,
        ``histogram_distance_XX`` (total variation, 0-1), which the objective may weight.
        The histograms are counted (``loop.histograms``, default bins when None) whenever
        this is given or the objective uses a histogram metric; the screening scores
        without those metrics (:func:`planner.objective.time_domain_metrics`).

    Returns
    -------
    Ranking
    """
    loop = as_options(loop, LoopOptions, "loop", "rank")
    elements = as_options(elements, ElementOptions, "elements", "rank")
    run = as_options(run, RunOptions, "run", "rank")
    if uncertainty is True:
        uncertainty = UncertaintyOptions()
    elif uncertainty is not False and uncertainty is not None:
        uncertainty = as_options(uncertainty, UncertaintyOptions, "uncertainty", "rank")
    oversample, band_hz, scheduler = loop.oversample, loop.band_hz, run.scheduler
    objective = default_objective() if objective is None else objective
    if not isinstance(objective, Objective):
        raise TypeError(f"objective must be a planner.objective.Objective (read one with "
                        f"read_objective), got {type(objective).__name__}")
    hist_metrics = time_domain_metrics(objective)
    if (hist_metrics or histogram_target is not None) and loop.histograms is None:
        loop = replace(loop, histograms=HistogramOptions())
    if histogram_target is not None and not isinstance(histogram_target, ShockHistograms):
        raise TypeError(f"rank: histogram_target must be a planner.histograms.ShockHistograms "
                        f"(planner.histograms.histograms_of a log), got "
                        f"{type(histogram_target).__name__}")
    if any(m.startswith("histogram_distance_") for m in hist_metrics) \
            and histogram_target is None:
        raise PlannerError(f"rank: objective {objective.name!r} uses "
                           f"{[m for m in hist_metrics if m.startswith('histogram_distance_')]}"
                           ", the distance from a target histogram; give the target (rank "
                           "--log LOG) or remove them from the objective")
    screen_objective = objective.without_metrics(hist_metrics)
    if screen_objective is None:
        raise PlannerError(f"rank: objective {objective.name!r} weights only histogram metrics "
                           f"({list(hist_metrics)}), which the screening cannot predict; "
                           "weight at least one RMS metric too (e.g. tire_force_rms_LF)")
    if setups is None:
        constraints = dict(constraints or {})
        if constraints.get("shocks") is None:  # a car's heave and roll dampers stay off its corners
            corner = corner_shock_ids(library, elements.car_third(model), elements.vary_third)
            if corner is not None:
                constraints["shocks"] = corner
        setups = enumerate_setups(library, **constraints)
    elif constraints:
        raise PlannerError("give either setups or constraints, not both")
    setups = list(setups)
    if not setups:
        raise PlannerError("no setups to rank")
    base = resolve_baseline(baseline, library, setups=setups, default=objective.baseline)
    if base.name not in {s.name for s in setups}:
        setups = [base] + setups
    if elements.vary_bump_stops or elements.vary_packers_m:
        setups = vary_elements(setups, bump_stops=elements.vary_bump_stops,
                               packers_m=elements.vary_packers_m,
                               library=elements.library(model), where="rank: the bump-stop "
                               "and packer choices (--try-bump-stops, --try-packers)")
    if elements.vary_third:
        if elements.car_third(model) is None:
            raise PlannerError("rank: third-element choices (--try-heave, --try-roll, "
                               "--try-heave-spring) on a model without third elements; drop "
                               "them, or use a model identified from a session that declares "
                               "third_elements")
        setups = vary_third(setups, elements.vary_third, car=elements.car_third(model),
                            where="rank: the third-element choices (--try-heave, --try-roll, "
                            "--try-heave-spring)")
    ekw = elements.without_choices()  # the setups' elements, once enumerated
    elem = model_setup_elements(setups, model, ekw)
    third = model_setup_third(setups, model, library, ekw, where="rank")
    if elem is not None or third is not None:
        n_enumerated = len(setups)
        setups, keep = distinct_setups(setups, elem, third)
        if len(keep) < n_enumerated:
            elem = model_setup_elements(setups, model, ekw)
            third = model_setup_third(setups, model, library, ekw, where="rank")
    if top < 1:
        raise PlannerError(f"top must be at least 1, got {top}")
    # 1. screening of everything
    if third is not None:  # the third elements (and any stops) linearized with the shocks
        if scheduler is not None and str(scheduler).strip().lower() != "none":
            log.info("rank: screening with third elements runs in this process (not on %s)",
                     scheduler)
        screened = screen_setups(model, drive, setups, library, band_hz=band_hz,
                                 reduce_rtol=loop.reduce_rtol, progress=progress,
                                 third=third_choices(third), **loop_arguments(elem))
        if elem is not None:
            screened = replace(screened, table=pd.concat(
                [screened.table, elem.columns(screened.table.index)], axis=1))
    elif elem is not None:  # the stops linearized with the shocks, in this process
        if scheduler is not None and str(scheduler).strip().lower() != "none":
            log.info("rank: screening with bump stops or static loads runs in this process "
                     "(not on %s)", scheduler)
        screened = screen_setups(model, drive, setups, library, band_hz=band_hz,
                                 reduce_rtol=loop.reduce_rtol, progress=progress,
                                 **loop_arguments(elem))
        screened = replace(screened, table=pd.concat(
            [screened.table, elem.columns(screened.table.index)], axis=1))
    elif scheduler is None or str(scheduler).strip().lower() == "none":
        screened = screen_setups(model, drive, setups, library, band_hz=band_hz,
                                 reduce_rtol=loop.reduce_rtol, progress=progress)
    else:
        screened = screen_setups_on(model, drive, setups, library, band_hz=band_hz,
                                    reduce_rtol=loop.reduce_rtol, run=run, progress=progress)
    sc = mark_inventory(score_setups(screened.table, screen_objective,
                                     baseline=base.name).table, setups, library)
    screening = pd.concat([screened.table, sc], axis=1)
    # 2. time domain on the best `top` by screening (plus the baseline)
    order = sc.sort_values("rank").index.tolist()
    chosen = order[:top]
    rest = order[top:]
    if n_check and rest:
        pick = np.unique(np.linspace(0, len(rest) - 1, min(n_check, len(rest))).round().astype(int))
        chosen += [rest[k] for k in pick]
    if base.name not in chosen:
        chosen.append(base.name)
    by_name = {s.name: s for s in setups}
    cand = [by_name[n] for n in chosen]
    def simulate(more, show):
        pred = predict_setups(model, drive, more, library, loop=loop, elements=ekw,
                              progress=show)
        if histogram_target is None:
            return pred
        dist = histogram_distance(pred.histograms, histogram_target)
        return replace(pred, table=pd.concat([pred.table, dist.set_axis(pred.table.index)],
                                             axis=1))

    td = simulate(cand, progress)
    scores = score_setups(td.table, objective, baseline=base.name)
    polish = None
    if polish_clicks and any("@" in sid for c in cand for sid in c.ids()):
        td, scores, cand, polish = _polish_clicks(
            td, scores, cand, setups, library, objective, base.name,
            lambda more: simulate(more, False))
    table = pd.concat([td.table, mark_inventory(scores.table, setups, library)], axis=1)
    table["screening_rank"] = sc.loc[table.index, "rank"].to_numpy()
    table["baseline"] = table.index == base.name  # the setup the scores are ratios to
    # 3. agreement between screening and time domain over the simulated setups
    # (over the setups screening chose: the click polish's near-ties would blur it)
    judged = table.index if polish is None else table.index[:len(chosen)]
    rho = float(spearmanr(sc.loc[judged, "score"], table.loc[judged, "score"]).statistic) \
        if len(judged) > 2 else float("nan")
    time_best, screening_best = table["rank"].idxmin(), sc.loc[judged, "rank"].idxmin()
    agreement = {"spearman": rho, "n": int(len(judged)), "same_best": bool(time_best == screening_best),
                 "time_best": time_best, "screening_best": screening_best,
                 # how far they differ: describe_agreement tells a near-tie from a miss
                 "time_best_screening_rank": int(sc.loc[time_best, "rank"]), "top": int(top),
                 "score_gap": float(table.loc[screening_best, "score"]
                                    / table.loc[time_best, "score"] - 1.0),
                 "polished": bool(time_best not in judged)}
    # 4. uncertainty (identified models)
    settings = {"top": top, "n_check": n_check, "oversample": oversample, "band_hz": tuple(band_hz),
                "n_setups": len(setups), "model": td.settings.get("model"),
                "drive": td.settings.get("drive"),
                "scheduler": screened.settings.get("scheduler", "none")}
    if polish is not None:
        settings["click_polish"] = polish
    if elem is not None:
        settings["elements"] = dict(elem.settings, n_variants=len(setups),
                                    vary_bump_stops=elements.vary_bump_stops,
                                    vary_packers_m=elements.vary_packers_m)
    if third is not None:
        settings["third"] = dict(third.car.to_dict(), vary_third=elements.vary_third,
                                 screening="linearized")
    table["unresolved"] = ""
    if uncertainty and getattr(model, "frf", None) is not None:
        unc = prediction_uncertainty(model, drive, cand, library, draws=uncertainty, loop=loop,
                                     elements=ekw, predictions=td)
        table = unc.intervals(table)
        errors = score_errors(td.table, unc, objective, baseline=base.name)
        pairs = unresolved_pairs(td.table, unc, objective, baseline=base.name, errors=errors)
        table["unresolved"] = [" ".join(pairs.get(n, [])) for n in table.index]
        best = table["rank"].idxmin()
        table = pd.concat([table, score_intervals(errors, best=best, baseline=base.name)
                           .loc[table.index]], axis=1)
        settings["uncertainty"] = unc.settings
    table = table.sort_values("rank")
    histograms = None if td.histograms is None else td.histograms.select(list(table.index))
    if histograms is not None:
        settings["histograms"] = histograms.settings()
    return Ranking(table=table, screening=screening.sort_values("rank"), baseline=base.name,
                   objective=objective, agreement=agreement, settings=settings,
                   candidates=tuple(cand), histograms=histograms)
