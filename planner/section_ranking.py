"""Rank setups per section of a drive: the whole drive's score and each section's, in one table.

``rank_sections(ranking, model, drive, library, sections=...)`` takes a finished
:class:`planner.rank.Ranking` of a drive and scores the setups it simulated in the time
domain (:attr:`planner.rank.Ranking.candidates`) on each named section of that drive.

How a section is simulated
--------------------------
Each section is cut from the drive as its own drive file would be
(:func:`planner.trackdrive.cut_sections`: the window, faded in and out over
:data:`planner.trackdrive.sections.SECTION_TAPER_S`, its time from 0, exactly what ``shockplan drive
section`` writes) and simulated alone, from rest, with the ranking's loop and elements; its
setups are scored against the ranking's baseline on that section (ratios to the baseline's
metrics on the section). So a section's column *equals* ``rank`` run on that section's drive
file alone, setup for setup (to the drive file's decimal round trip), not a window of the
whole drive's simulation: the whole drive's response carries into a window from before it,
and the metric band's filters need the section's own start and end.

A section ranks the setups the whole drive's ranking simulated (its best by screening, a
spread of the others, the baseline): ``rank`` on the section's file alone screens all of
them again and may simulate other ones; the scores of the setups both simulate are the same.

Examples
--------
>>> from planner.trackdrive import parse_sections
>>> parse_sections(["kerb=10:22.5"])
[('kerb', 10.0, 22.5)]
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import pandas as pd

from planner.errors import PlannerError
from planner.objective import mark_inventory, score_setups
from planner.options import ElementOptions, LoopOptions, as_options
from planner.predict import predict_setups
from planner.text import format_table
from planner.trackdrive import cut_sections
from planner.trackdrive.sections import SECTION_TAPER_S

__all__ = ["SectionRanking", "rank_sections", "section_columns"]

log = logging.getLogger(__name__)


def section_columns(name):
    """The columns of section `name` in :attr:`SectionRanking.table`: score and rank.

    Examples
    --------
    >>> section_columns("kerb")
    ('kerb_score', 'kerb_rank')
    """
    return f"{name}_score", f"{name}_rank"


@dataclass(frozen=True, eq=False)
class SectionRanking:
    """The result of :func:`rank_sections`.

    Attributes
    ----------
    table : pandas.DataFrame
        Indexed by setup name, in the whole drive's rank order: ``LF, RF, LR, RR``,
        ``score``, ``rank`` and ``feasible`` on the whole drive, then per section
        ``<name>_score`` and ``<name>_rank`` (:func:`section_columns`; rank 1 = the
        section's best feasible setup), and ``wins``: the sections the setup wins
        (space-separated, empty for none).
    sections : tuple of (str, float, float)
        Name, start and stop [s] of each section, in the drive's time from its first sample.
    baseline : str
        The setup every score is a ratio to (the ranking's).
    best : str
        The whole drive's best setup.
    winners : dict of str to str
        Each section's best setup.
    section_tables : dict of str to pandas.DataFrame
        Each section's predictions (SI metrics) joined with its scores, as ``rank`` writes
        them.
    settings : dict
        ``taper_s`` and each section's drive name.
    """

    table: pd.DataFrame
    sections: tuple
    baseline: str
    best: str
    winners: dict
    section_tables: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)

    def section_winners(self):
        """The setups that win a section but not the whole drive.

        Returns
        -------
        list of (str, str)
            ``(section, setup)`` in section order.
        """
        return [(s, w) for s, w in self.winners.items() if w != self.best]

    def summary(self, n=5):
        """The section table for a terminal: the whole drive's best `n` setups and each
        section's score and rank, then each section's winner that does not win the whole
        drive."""
        t = self.table
        names = [s for s, _, _ in self.sections]
        heads = ["rank", "setup", "whole drive"] + names
        rows = []
        show = list(t.index[:n]) + [w for w in self.winners.values() if w not in t.index[:n]]
        for name in dict.fromkeys(show):
            r = t.loc[name]
            rows.append([int(r["rank"]), name, f"{r['score']:.4f}"]
                        + [f"{r[section_columns(s)[0]]:.4f} ({int(r[section_columns(s)[1]])})"
                           for s in names])
        lines = [f"sections: {len(names)} ("
                 + ", ".join(f"{s} {a:g}-{b:g} s" for s, a, b in self.sections)
                 + "); score per section (its rank)", format_table(rows, heads)]
        won = self.section_winners()
        if won:
            lines += [f"  '{w}' wins section {s!r} but not the whole drive (best "
                      f"'{self.best}')" for s, w in won]
        else:
            lines.append(f"  '{self.best}' wins the whole drive and every section")
        return "\n".join(lines)


def rank_sections(ranking, model, drive, library, *, sections, loop=LoopOptions(),
                  elements=ElementOptions(), taper_s=SECTION_TAPER_S, progress=False):
    """Score a ranking's setups on each section of its drive.

    Parameters
    ----------
    ranking : planner.rank.Ranking
        The whole drive's ranking (:func:`planner.rank.rank_setups` on `drive`); its
        ``candidates`` are simulated on each section.
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
        The ranking's model.
    drive : ident.data.drive.Drive
        The ranking's drive.
    library : ident.models.library.ShockLibrary
    sections : sequence of (str, float, float)
        Name, start and stop [s] in the drive's time from its first sample
        (:func:`planner.trackdrive.parse_sections`, :func:`planner.trackdrive.lap_sections`);
        None: the drive's own ``settings["sections"]`` (a drive that carries them).
    loop : planner.options.LoopOptions
        As the ranking's.
    elements : planner.options.ElementOptions
        As the ranking's (its choices are already in the candidates' elements).
    taper_s : float
        Fade at each end of a section [s], as ``shockplan drive section``'s.
    progress : bool

    Returns
    -------
    SectionRanking

    Raises
    ------
    PlannerError
        No sections, a ranking without candidates, or a window beyond the drive or too
        short for its fades.
    """
    loop = as_options(loop, LoopOptions, "loop", "rank_sections")
    elements = as_options(elements, ElementOptions, "elements", "rank_sections")
    if sections is None:
        sections = drive.settings.get("sections") if isinstance(drive.settings, dict) else None
    sections = [(str(n), float(a), float(b)) for n, a, b in (sections or ())]
    if not sections:
        raise PlannerError("rank_sections: no sections; give --section NAME=START:STOP (or "
                           "--laps T0,T1,...) in seconds of the drive")
    cand = list(getattr(ranking, "candidates", ()) or ())
    if not cand:
        raise PlannerError("rank_sections: the ranking has no candidates (the setups it "
                           "simulated); rank with planner.rank.rank_setups first")
    drives = cut_sections(drive, sections, taper_s=taper_s, where="rank --section")
    whole = ranking.table
    table = whole[[c for c in ("LF", "RF", "LR", "RR") if c in whole.columns]].copy()
    table["score"] = whole["score"]
    table["rank"] = whole["rank"]
    table["feasible"] = whole["feasible"] if "feasible" in whole.columns else True
    winners, per = {}, {}
    ekw = elements.without_choices()
    for (name, _, _), d in zip(sections, drives):
        td = predict_setups(model, d, cand, library, loop=loop, elements=ekw, progress=progress)
        sc = mark_inventory(score_setups(td.table, ranking.objective,
                                         baseline=ranking.baseline).table, cand, library)
        score_col, rank_col = section_columns(name)
        table[score_col] = sc.loc[table.index, "score"].to_numpy()
        table[rank_col] = sc.loc[table.index, "rank"].to_numpy()
        winners[name] = str(sc["rank"].idxmin())
        per[name] = pd.concat([td.table, sc], axis=1).sort_values("rank")
        log.info("rank: section %s (%d samples): best %s", name, d.n_samples, winners[name])
    table["wins"] = [" ".join(s for s, w in winners.items() if w == n) for n in table.index]
    best = str(ranking.best)
    return SectionRanking(table=table, sections=tuple(sections), baseline=ranking.baseline,
                          best=best, winners=winners, section_tables=per,
                          settings={"taper_s": float(taper_s),
                                    "drives": {s: d.name for (s, _, _), d in
                                               zip(sections, drives)}})
