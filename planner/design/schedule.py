"""The schedule of a plan: its runs in rig order, repeats and validation runs, their shares
of the criterion and the predictions of every run.

Part of :mod:`planner.design` (see its docstring).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ident.data.channels import CORNERS
from planner.options import UncertaintyOptions
from planner.predict import predict_setups
from planner.uncertainty import prediction_uncertainty
from planner.design.candidates import corner_change, named_settings, setup_key, third_changed
from planner.design.information import criterion_value
from planner.design.solve import swap_order

__all__ = [
    "PURPOSES",
    "ScheduleOptions",
    "PlannedRun",
    "schedule_runs",
    "criterion_shares",
    "criterion_curve",
    "run_predictions",
    "plan_rationale",
]


#: What a planned run is for.
PURPOSES = ("identification", "baseline repeat", "validation")


@dataclass(frozen=True)
class ScheduleOptions:
    """How a design's runs are scheduled and sheeted.

    Parameters
    ----------
    baseline_every : int
        Repeat the baseline (shortest duration) after every this many runs (0: never),
        to catch drift.
    n_validation : int
        Validation runs of the current best setups on the team's drive, at the plan's end;
        their durations and changes are rig time in the budget, and the identification
        runs before them must identify every shock's path on their own.
    seed : int
        Seeds of the planned drives.
    date : str, optional
        For the run sheet's header.
    """

    baseline_every: int = 0
    n_validation: int = 0
    seed: int = 0
    date: str | None = None


@dataclass(frozen=True)
class PlannedRun:
    """One run of the plan, in rig order.

    Attributes
    ----------
    number : int
        From 1.
    name : str
    setup : planner.setups.Setup
    purpose : str
        :data:`PURPOSES`.
    drive : str
        Name of the drive (its file is ``drives/<drive>.csv``).
    kind : str
    duration_s : float
    start_min : float
        Planned start, minutes from the plan's start (swaps before it included).
    changed : tuple of str
        Corners changed before this run: a shock swapped, or an adjustable shock's
        setting changed; then the third elements' columns swapped (``heave_front``,
        ``heave_spring_front``, ...; issue 38).
    swap_min : float
        Time of those changes [min], swaps and click changes.
    share : float
        The run's share of the criterion (leave-one-out, the shares summing to 1).
    clicks : tuple of (str, str)
        ``(corner, adjuster)`` of every adjuster turned before this run at a corner that
        kept its adjustable shock (those corners are in `changed` too).
    """

    number: int
    name: str
    setup: object
    purpose: str
    drive: str
    kind: str
    duration_s: float
    start_min: float
    changed: tuple
    swap_min: float
    share: float
    clicks: tuple = ()

    @property
    def swapped(self):
        """tuple of str: the corners of `changed` whose shock was swapped."""
        clicked = {c for c, _ in self.clicks}
        return tuple(c for c in self.changed if c not in clicked)

    @property
    def change(self):
        """str: the kind of change before the run: ``"swap"``, ``"clicks"``,
        ``"swap+clicks"`` or ``""`` (none)."""
        kinds = [k for k, on in (("swap", self.swapped), ("clicks", self.clicks)) if on]
        return "+".join(kinds)


def schedule_runs(seq, cands, val_setups, base, rig, make, val_drive, baseline_every, short_s,
                  seed, Mc_s, val_info, scale):
    """The planned runs in rig order: the identification sequence with baseline repeats
    every `baseline_every` runs, then the validation runs (fewest swaps); their drives and
    scaled information."""
    base_cand = {c.kind: i for i, c in enumerate(cands) if setup_key(c.setup) == setup_key(base)
                 and c.duration_s == short_s}
    long_s = max(c.duration_s for c in cands)
    blocks = []
    for c in seq:                       # runs of one setup in a row, by drive kind
        if blocks and setup_key(cands[blocks[-1][0]].setup) == setup_key(cands[c].setup):
            blocks[-1].append(c)
        else:
            blocks.append([c])
    kind_rank = {c.kind: k for k, c in reversed(list(enumerate(cands)))}
    groups = []
    for c in (c for b in blocks for c in sorted(b, key=lambda i: kind_rank[cands[i].kind])):
        # consecutive runs of one setup and drive kind play as one longer run (up to the
        # longest candidate duration): the same information, fewer starts on the rig
        g = groups[-1] if groups else None
        if (g is not None and setup_key(cands[g[0]].setup) == setup_key(cands[c].setup)
                and cands[g[0]].kind == cands[c].kind
                and sum(cands[i].duration_s for i in g) + cands[c].duration_s <= long_s):
            g.append(c)
        else:
            groups.append([c])
    items = []
    for k, g in enumerate(groups):
        if baseline_every and k and k % baseline_every == 0:
            items.append(("baseline repeat", [base_cand[cands[g[0]].kind]], None))
        items.append(("identification", g, None))
    if val_setups:
        last = cands[seq[-1]].setup if seq else base
        items += [("validation", None, j) for j in swap_order(val_setups, last, rig)]
    runs, drives, infos = [], {}, []
    t, prev = 0.0, base
    for n, (purpose, g, vj) in enumerate(items, 1):
        c = g[0] if g is not None else None
        setup = cands[c].setup if c is not None else val_setups[vj]
        dur = (sum(cands[i].duration_s for i in g) if c is not None
               else val_drive.duration_s)
        changed = tuple(k for k, a, b in zip(CORNERS, prev.ids(), setup.ids()) if a != b)
        third = third_changed(prev, setup)  # heave and roll dampers, heave springs swapped
        clicks = []
        for k, a, b in zip(CORNERS, prev.ids(), setup.ids()):
            if a != b and corner_change(a, b)[0] == 0:
                da, db = dict(named_settings(a)[1]), dict(named_settings(b)[1])
                clicks += [(k, adj) for adj in da if da[adj] != db[adj]]
        swap = rig.swap_min * (len(changed) + len(third) - len({k for k, _ in clicks}))
        changed += third
        if clicks:
            swap += rig.click_change_min * len(clicks)
        start = t + swap + rig.run_overhead_min
        t, prev = start + dur / 60.0, setup
        if c is not None:
            label = "baseline" if setup_key(setup) == setup_key(base) else setup.name
            dname = f"run{n:02d}-{cands[c].kind}"
            drives[dname] = make(cands[c].kind, dur, seed + n, dname)
            kind = cands[c].kind
            infos.append(sum(Mc_s[i] for i in g))
        else:
            label = f"validation-{setup.name}"
            dname = re.sub(r"[^A-Za-z0-9_.-]+", "_", val_drive.name).strip("_") or "validation"
            drives[dname] = val_drive
            kind = "validation"
            infos.append(scale(val_info[vj]))
        runs.append(PlannedRun(number=n, name=f"run{n:02d}-{label}".replace("/", "-"),
                               setup=setup, purpose=purpose, drive=dname, kind=kind,
                               duration_s=float(dur), start_min=float(start), changed=changed,
                               swap_min=float(swap), share=0.0, clicks=tuple(clicks)))
    return runs, drives, infos


def criterion_shares(runs, infos, M0_s, criterion, W_s):
    """Each run's share of the criterion: the loss when it is left out, shares summing to 1."""
    M_all = M0_s + sum(infos)
    full = criterion_value(M_all, criterion, W_s)
    loss = np.array([max(full - criterion_value(M_all - M, criterion, W_s), 0.0)
                     for M in infos])
    share = loss / loss.sum() if loss.sum() > 0 else np.full(len(runs), 1.0 / len(runs))
    return [PlannedRun(**{**r.__dict__, "share": float(sh)}) for r, sh in zip(runs, share)]


def criterion_curve(runs, infos, M0_s, criterion, W_s):
    """The criterion after each run against the rig time at its end."""
    rows, M = [], M0_s.copy()
    rows.append({"run": 0, "time_min": 0.0, "criterion": criterion_value(M, criterion, W_s)})
    for r, info in zip(runs, infos):
        M = M + info
        rows.append({"run": r.number, "time_min": r.start_min + r.duration_s / 60,
                     "criterion": criterion_value(M, criterion, W_s)})
    return pd.DataFrame(rows)


def run_predictions(model, ident_model, runs, drives, library, objective, elements=None):
    """The key metrics predicted for every run on its own drive, with intervals (identified);
    `elements` (:class:`planner.options.ElementOptions`) as
    :func:`planner.predict.predict_setups` takes them (the car's third elements)."""
    keys = [m for m in objective.weights if objective.weights[m] > 0]
    rows = []
    for r in runs:
        setup = r.setup
        pred = predict_setups(model, drives[r.drive], [setup], library,
                              **({} if elements is None else {"elements": elements}))
        t = pred.table
        if ident_model is not None:
            unc = prediction_uncertainty(ident_model, drives[r.drive], [setup], library,
                                         draws=UncertaintyOptions(n_draws=20), predictions=pred)
            t = unc.intervals(t)
        row = {"run": r.number}
        for m in keys:
            row[m] = float(t[m].iloc[0])
            if f"{m}_lo" in t:
                row[f"{m}_lo"] = float(t[f"{m}_lo"].iloc[0])
                row[f"{m}_hi"] = float(t[f"{m}_hi"].iloc[0])
        rows.append(row)
    return pd.DataFrame(rows).set_index("run")


def _numbers(ns):
    """``"run 3"``, ``"runs 1-4, 6"``: run numbers in ranges."""
    ns = sorted(ns)
    parts, k = [], 0
    while k < len(ns):
        j = k
        while j + 1 < len(ns) and ns[j + 1] == ns[j] + 1:
            j += 1
        parts.append(f"{ns[k]}" if j == k else f"{ns[k]}-{ns[j]}")
        k = j + 1
    return ("run " if len(ns) == 1 else "runs ") + ", ".join(parts)


def plan_rationale(runs, base, *, session=False):
    """Why the plan has the runs it has, a line per purpose (for its summary and sheet).

    Parameters
    ----------
    runs : sequence of PlannedRun
    base : planner.setups.Setup
        The baseline.
    session : bool
        Whether a recorded session's runs are the prior (corners they vary need no run).

    Returns
    -------
    tuple of str
        The identification runs: the runs that change each corner's shock from the
        baseline's, and why (the seed paper's Eqs. 21-24); the validation runs and their
        changes' rig time; the baseline repeats.
    """
    lines = []
    ident = [r for r in runs if r.purpose == "identification"]
    val = [r for r in runs if r.purpose == "validation"]
    rep = [r for r in runs if r.purpose == "baseline repeat"]
    if ident:
        varied = {}
        for c in CORNERS:
            ns = tuple(r.number for r in ident if r.setup.shocks[c] != base.shocks[c])
            varied.setdefault(ns, []).append(c)
        where = "; ".join(f"{', '.join(cs)}: {_numbers(ns)}" for ns, cs in varied.items() if ns)
        kept = varied.get((), [])
        if kept:
            where += (f"; {', '.join(kept)} kept (the session's runs vary them)" if session
                      else f"; {', '.join(kept)} kept")
        lines.append(
            f"{_numbers([r.number for r in ident]).capitalize()} "
            f"{'identify: they change' if len(ident) > 1 else 'identifies: it changes'} the "
            f"shocks (or their settings) from the baseline's ({where}) so that every shock's "
            "path is identified (seed paper Eqs. 21-24: the shock forces must vary apart from "
            "the rig inputs, which only different shocks between runs give); the criterion "
            f"chose {'them' if len(ident) > 1 else 'it'} for the most information a minute.")
    if val:
        change = sum(r.swap_min for r in val)
        setups = ", ".join("/".join(r.setup.ids()) for r in val)
        many = len(val) > 1
        line = (f"{_numbers([r.number for r in val]).capitalize()} "
                f"{'validate' if many else 'validates'} the predicted best setup{'s' * many} "
                f"({setups}) on the team's drive; {'their' if many else 'its'} changes "
                f"({change:.0f} min) count in the rig time")
        free = [r.number for r in val if not r.changed]
        if free and ident:
            line += (f"; {_numbers(free)} need{'s' * (len(free) == 1)} no change: the runs "
                     "before identify on its setup")
        lines.append(line + ".")
    if rep:
        lines.append(f"{_numbers([r.number for r in rep]).capitalize()} "
                     f"{'repeat' if len(rep) > 1 else 'repeats'} the baseline to catch drift.")
    return tuple(lines)
