"""What-if reports: the factor effects behind the tornado charts, the figures and the files.

:func:`factor_effects` reads one setup's change per factor off a
:class:`planner.whatif.WhatIf` (the levels of a one-at-a-time design, a regression
over the conditions otherwise); :func:`tornado_figure` draws them and
:func:`rank_stability_figure` the top setups' ranks over the conditions;
:func:`write_whatif` writes ``whatif.xlsx``, the CSVs and the figures into a folder.
These read the result only (no import of :mod:`planner.whatif`, which re-exports
them). matplotlib and openpyxl are imported where used: they are heavy and the
what-if computation does not need them.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd

from ident.data.files import atomic_dir, png_metadata, write_csv
from ident.data.units import UNIT_LABELS, check_units, from_si
from ident.models.vehicle import VEHICLE_KEYS
from ident.sim.metrics import METRIC_QUANTITY
from planner.errors import PlannerError
from planner.report.ranking import label_key_text, ranking_to_units, short_labels
from planner.report.sheets import (
    column_label,
    print_setup,
    write_key_values,
    write_table,
)
from planner.report.summary import N_SUMMARY_ROWS, summary_figure, write_summary_sheet
from planner.screen import describe_agreement

__all__ = [
    "WEIGHTED_CHANGE",
    "factor_effects",
    "robust_verdicts",
    "tornado_figure",
    "rank_stability_figure",
    "write_whatif",
]

#: Quantity of :func:`factor_effects` and :func:`tornado_figure`: the objective-weighted
#: mean change of a setup's metrics against its own nominal condition [%].
WEIGHTED_CHANGE = "weighted_change_pct"
# Colours of the tornado bars: the change at the factor's low and at its high value.
_TORNADO_COLORS = ("#4C72B0", "#DD8452")


# ----------------------------------------------------------------------------------------------
# effects (tornado)
# ----------------------------------------------------------------------------------------------

def factor_effects(result, setup, *, quantity="score_change"):
    """Per-factor effect on one setup: the change at the factor's low and high values.

    One-at-a-time: the change of each factor level alone. Factorial and Monte Carlo:
    numeric factors by a linear regression of the change on every factor's values over
    the conditions (the change at the 10th and 90th percentile of the factor's values
    in Monte Carlo, at its lowest and highest level in a factorial), categorical ones
    (windows, files) by the mean change per level.

    Parameters
    ----------
    result : WhatIf
    setup : str
    quantity : str
        A column of ``result.table`` (default ``score_change``; e.g. ``rank_change`` or
        ``tire_force_rms_LF_change_pct``), or :data:`WEIGHTED_CHANGE`: the mean of the
        objective's metrics' changes [%] weighted by the objective's weights, each
        against the setup's own nominal condition (the change of the score the setup
        would have against its own nominal metrics; it moves for the baseline, whose
        ``score_change`` is 0 in every condition).

    Returns
    -------
    pandas.DataFrame
        Index the factor (per target for independent factors), columns ``low``,
        ``high`` (the values, text), ``change_low``, ``change_high``, ``swing``
        (``|change_high - change_low|``); largest swing first.
    """
    t = result.table
    if setup not in set(t["setup"]):
        raise PlannerError(f"setup {setup!r} is not in the what-if; it has "
                           f"{sorted(set(t['setup']))[:8]}")
    if quantity not in t.columns and quantity != WEIGHTED_CHANGE:
        raise PlannerError(f"{quantity!r} is not a column of the what-if table")
    d0 = result.settings["drives"][0]
    rows = t[(t["setup"] == setup) & (t["drive"] == d0)].set_index("perturbation")
    conds = result.perturbations.table().loc[rows.index]
    y = (_weighted_change(result, rows) if quantity == WEIGHTED_CHANGE
         else rows[quantity].to_numpy(dtype=float))
    out = []
    design = result.perturbations.design
    if design == "one-at-a-time":
        for col in conds.columns:
            vals = conds[col]
            moved = vals.apply(lambda v: v not in ("nominal",) and v != _nominal_of(result, col))
            if not moved.any():
                continue
            sub = vals[moved]
            keyed = sorted(zip(sub.tolist(), y[moved.to_numpy()]),
                           key=lambda p: (p[0] if isinstance(p[0], float) else 0.0))
            if len(keyed) == 1:  # one level: from the nominal to it
                nom = _nominal_of(result, col)
                keyed = [("nominal" if nom is None else nom, 0.0)] + keyed
                keyed.sort(key=lambda p: (p[0] if isinstance(p[0], float) else 0.0))
            lo, hi = keyed[0], keyed[-1]
            out.append((col, _value_text_out(lo[0]), _value_text_out(hi[0]), lo[1], hi[1]))
    else:
        numeric = [c for c in conds.columns if pd.api.types.is_numeric_dtype(conds[c])
                   and conds[c].nunique() > 1]
        if numeric:
            X = conds[numeric].to_numpy(dtype=float)
            Xc = X - X.mean(axis=0)
            coef, *_ = np.linalg.lstsq(Xc, y - y.mean(), rcond=None)
            for j, col in enumerate(numeric):
                if design == "monte-carlo":
                    lo_v, hi_v = np.percentile(X[:, j], [10, 90])
                else:
                    lo_v, hi_v = X[:, j].min(), X[:, j].max()
                nom = _nominal_of(result, col)
                nom = X[:, j].mean() if nom is None else nom
                # the change the factor alone makes from its nominal value
                out.append((col, lo_v, hi_v, coef[j] * (lo_v - nom), coef[j] * (hi_v - nom)))
        for col in conds.columns:
            if col in numeric or conds[col].nunique() < 2:
                continue
            means = pd.Series(y, index=conds.index).groupby(conds[col].astype(str)).mean()
            lo_k, hi_k = means.idxmin(), means.idxmax()
            out.append((col, lo_k, hi_k, float(means[lo_k]), float(means[hi_k])))
    eff = pd.DataFrame(out, columns=["factor", "low", "high", "change_low", "change_high"])
    eff["swing"] = (eff["change_high"] - eff["change_low"]).abs()
    return eff.set_index("factor").sort_values("swing", ascending=False)


def _nominal_of(result, column):
    for f in result.perturbations.factors:
        for label, _ in f.atoms():
            if label == column:
                return f.nominal
    return None


def _value_text_out(v):
    return v if isinstance(v, str) else float(v)


def _weighted_change(result, rows):
    """:data:`WEIGHTED_CHANGE` of the rows of one setup: sum w_k change_k / sum w_k [%]."""
    weights = {m: w for m, w in result.objective.weights.items()
               if w > 0 and f"{m}_change_pct" in rows.columns}
    if not weights:
        raise PlannerError(f"{WEIGHTED_CHANGE!r}: the what-if table has no '<metric>_change_pct' "
                           f"column of the objective's weighted metrics "
                           f"{sorted(result.objective.weights)}")
    total = sum(weights.values())
    return sum(w * rows[f"{m}_change_pct"].to_numpy(dtype=float)
               for m, w in weights.items()) / total


def _tornado_quantity(result, setup, quantity):
    """The quantity a setup's tornado shows, and a note saying why when it is not `quantity`.

    The scores of a what-if are relative to the baseline in the same condition, so the
    baseline scores the total weight in every condition and its ``score_change`` is 0
    for every factor: its tornado shows :data:`WEIGHTED_CHANGE` instead.
    """
    if quantity == "score_change" and setup == result.baseline:
        return WEIGHTED_CHANGE, (f"{setup} is the baseline: its score is the same in every "
                                 "condition (scores are relative to it), so its own metrics' "
                                 "weighted change is shown")
    return quantity, None


def _quantity_label(quantity):
    """Axis label of a tornado quantity, with its unit."""
    if quantity == WEIGHTED_CHANGE:
        return "weighted change of the objective's metrics [%]"
    if quantity == "score_change":
        return "score change [-]"
    if quantity == "rank_change":
        return "rank change [places]"
    if quantity.endswith("_change_pct") and quantity[:-len("_change_pct")] in METRIC_QUANTITY:
        return f"{column_label(quantity[:-len('_change_pct')])} change [%]"
    return quantity.replace("_", " ")


def _level_text(result, column, value, units):
    """A factor value as the tornado labels it: ``x0.95`` (scale), ``+5 lbf/in`` (add)."""
    if isinstance(value, str):
        return value
    for f in result.perturbations.factors:
        for label, _ in f.atoms():
            if label != column:
                continue
            if f.change == "scale":
                return f"x{value:.4g}"
            if f.kind == "click":
                return f"{value:+g} click"
            if f.kind == "fade":
                return f"{100 * value:.4g} % fade"
            qty = {"shock_lag": "time", "spring_rate": "stiffness",
                   "arb_rate": "stiffness"}.get(f.kind)
            if f.kind == "vehicle" and f.targets:
                qty = VEHICLE_KEYS.get(f.targets[0], (None,))[0]
            if qty is None:
                return f"{value:+.4g}"
            return f"{float(from_si(value, qty, units)):+.4g} {UNIT_LABELS[units][qty]}"
    return f"{value:.4g}"


# ----------------------------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------------------------

def tornado_figure(result, setup, *, quantity="score_change", max_factors=12, units="SI"):
    """Tornado chart of the factors' effects on one setup (:func:`factor_effects`).

    Each factor has two bars in its row: the change at the factor's low value (upper,
    blue) and at its high value (lower, orange), each labelled with the value
    (``x0.95`` for a scale, ``+5 lbf/in`` for an added rate, in `units`).

    Parameters
    ----------
    result : WhatIf
    setup : str
    quantity : str
        As :func:`factor_effects`. The baseline's ``score_change`` is 0 in every
        condition (the scores are relative to it), so its chart shows
        :data:`WEIGHTED_CHANGE` instead and says so under the title.
    max_factors : int
        The factors with the largest swing shown.
    units : {"SI", "imperial"}
        Units of the factor values added to a rate (``spring_rate``, ``arb_rate``,
        ``vehicle`` with ``change = "add"``).

    Returns
    -------
    matplotlib.figure.Figure
        When no factor changes `quantity` (every change 0), the axes say so in a
        line of text instead of drawing bars of zero length.
    """
    from matplotlib.figure import Figure  # heavy, needed only for the figures

    units = check_units(units, where="units", error=PlannerError)
    shown, note = _tornado_quantity(result, setup, quantity)
    eff = factor_effects(result, setup, quantity=shown).head(max_factors).iloc[::-1]
    fig = Figure(figsize=(7.5, 0.5 * max(len(eff), 3) + (2.0 if note else 1.7)))
    ax = fig.add_subplot()
    ypos = np.arange(len(eff))
    moved = bool(len(eff)) and bool((eff["swing"].to_numpy(dtype=float) > 0).any())
    half = 0.38  # each bar takes under half of its row: the two labels never meet
    for y_, (name, r) in zip(ypos if moved else [], eff.iterrows()):
        for val, label, color, dy in ((r["change_low"], r["low"], _TORNADO_COLORS[0], 0.2),
                                      (r["change_high"], r["high"], _TORNADO_COLORS[1], -0.2)):
            ax.barh(y_ + dy, val, color=color, height=half)
            ax.annotate(_level_text(result, name, label, units), (val, y_ + dy),
                        xytext=(3 if val >= 0 else -3, 0), textcoords="offset points",
                        va="center", ha="left" if val >= 0 else "right", fontsize=7)
    if not moved:  # no bars to draw: say so (the values of each factor are in the effects)
        what = shown.replace("_", " ")
        ax.text(0.5, 0.5, "no factor moved in this design" if len(eff) == 0 else
                f"no factor changes the {what} of {setup}: every change is 0",
                transform=ax.transAxes, ha="center", va="center", fontsize=9,
                bbox={"facecolor": "white", "edgecolor": "0.6"})
    ax.set_yticks(ypos, [str(i) for i in eff.index], fontsize=8)
    ax.set_ylim(-0.6, max(len(eff), 1) - 0.4)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel(f"{_quantity_label(shown)}\nupper bar (blue): the factor at its low value; "
                  "lower bar (orange): at its high value", fontsize=9)
    title = f"what-if effects on {setup}"
    if note:
        title += "\n" + textwrap.fill(note, 95)
    ax.set_title(title, fontsize=9)
    ax.margins(x=0.25)
    # short tick labels: "-0.000075" side by side ran into each other; 1e-4 goes to an offset
    ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4), useMathText=True)
    fig.tight_layout()
    return fig


def rank_stability_figure(result, *, top=10):
    """Rank of the top setups (by nominal rank) across the conditions.

    Few conditions (<= 30): one line per setup over the conditions. More: the
    distribution of each setup's rank (box plot, nominal rank as a diamond).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure  # heavy, needed only for the figures

    rob = result.robust.sort_values("nominal_rank")
    names = list(rob.index[:top])
    t = result.table[result.table["setup"].isin(names)].copy()
    t["condition"] = t["drive"] + " | " + t["perturbation"]
    piv = t.pivot_table(index="condition", columns="setup", values="rank", sort=False)[names]
    # long names (click settings): #<nominal rank> on the plot, the key under it
    short, key = short_labels(names, rob.loc[names, "nominal_rank"].to_numpy(dtype=float))
    label = dict(zip(names, short))
    key_in = 0.135 * (len(key) + 1) + 0.1 if key else 0.0
    fig = Figure(figsize=(9.0, 5.0 + key_in))
    label_key_text(fig, key, y_in=0.05, meaning="the nominal rank (robust.csv)")
    ax = fig.add_subplot()
    if len(piv) <= 30:
        x = np.arange(len(piv))
        for n in names:
            ax.plot(x, piv[n].to_numpy(), marker="o", ms=3, lw=1.2,
                    label=f"{label[n]}{' (fragile)' if rob.loc[n, 'fragile'] else ''}")
        labels = [c.split(" | ", 1)[1] if len(result.settings["drives"]) == 1 else c
                  for c in piv.index]
        ax.set_xticks(x, labels, rotation=60, ha="right", fontsize=7)
        ax.legend(fontsize=7, ncol=2, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    else:
        data = [piv[n].dropna().to_numpy() for n in names]
        ax.boxplot(data, vert=True, whis=(5, 95), widths=0.6)
        ax.plot(np.arange(1, len(names) + 1), rob.loc[names, "nominal_rank"].to_numpy(), "D",
                color="#C44E52", ms=5, label="nominal rank")
        ax.set_xticks(np.arange(1, len(names) + 1),
                      [f"{label[n]}{' *' if rob.loc[n, 'fragile'] else ''}" for n in names],
                      rotation=0 if key else 45, ha="center" if key else "right", fontsize=7)
        # beside the axes, as the lines' legend: inside, it may cover a box or a whisker
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
        ax.set_xlabel("setup (* fragile rank); boxes 25-75 %, whiskers 5-95 % of conditions")
    ax.invert_yaxis()
    ax.yaxis.get_major_locator().set_params(integer=True)  # ranks are whole places
    ax.set_ylabel("rank (1 = best)")
    ax.set_title(f"rank stability over {len(piv)} conditions "
                 f"({result.perturbations.design}, {result.settings['method']})", fontsize=10)
    fig.tight_layout(rect=(0, key_in / fig.get_figheight(), 1, 1))
    return fig


# ----------------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------------

def _safe_name(name):
    keep = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
    return keep.strip("_") or "setup"


#: Settings that time a run or say where it ran: logged and kept on the result, not
#: written to the files (a rerun, on a cluster or not, writes the same cells).
_TIMING_KEYS = ("elapsed_s", "evaluations_per_s", "scheduler", "address", "n_workers",
                "n_tasks")


def write_whatif(result, out_dir, *, units="SI", top=5, overwrite=False, run=None):
    """Write a what-if's files into a folder (built aside, moved into place at the end).

    Files: ``whatif.xlsx`` (first the one-page ``summary``: the robust ranking's best
    setups, each one's verdict against the robust best, what the run used and the best's
    scores against the baseline's; then, as the appendix, the sheets ``robust``,
    ``conditions``, ``effects`` and ``table``), ``whatif.csv`` (the long table, metrics in `units`), ``robust.csv``,
    ``conditions.csv``, ``rank_stability.png`` and ``tornado/<nn>_<setup>.png`` for the
    `top` setups of the robust ranking. With ``click`` or ``fade`` factors also
    ``tolerance.csv`` and the sheet ``tolerance`` (each setup's spread of score, rank
    and metrics over each such factor's levels, :attr:`WhatIf.tolerance`); the table's
    ``clipped`` column says where a click hit the end of an adjuster's range. Each
    CSV's last column is ``units`` (`units` on every row).

    `run` (optional, ``{label: value}``): what the run used (model, drive, crate, what-if
    file), on the summary sheet.

    Returns
    -------
    dict of str -> pathlib.Path

    Raises
    ------
    FileExistsError
        If `out_dir` exists and is not empty and `overwrite` is false (checked first).
    """
    units = check_units(units, where="units", error=PlannerError)
    out = Path(out_dir)
    files = {}
    with atomic_dir(out, overwrite=overwrite) as work:
        table = ranking_to_units(result.table, units)
        # each CSV's last column is 'units' (the unit system on every row)
        write_csv(work / "whatif.csv", table, units=units, float_format="%.6g")
        write_csv(work / "robust.csv", result.robust, units=units, index=True,
                  float_format="%.6g")
        write_csv(work / "conditions.csv", result.conditions, units=units, index=True)
        tolerance = _tolerance_to_units(getattr(result, "tolerance", None), units)
        if tolerance is not None:
            write_csv(work / "tolerance.csv", tolerance, units=units, float_format="%.6g")
        top_names = list(result.robust.index[:top])
        effects = []
        (work / "tornado").mkdir()
        for k, n in enumerate(top_names):
            eff = factor_effects(result, n)
            effects.append(eff.reset_index().assign(setup=n))
            fig = tornado_figure(result, n, units=units)
            fig.savefig(work / "tornado" / f"{k + 1:02d}_{_safe_name(n)}.png", dpi=110,
                        metadata=png_metadata(fig))
        fig = rank_stability_figure(result)
        fig.savefig(work / "rank_stability.png", dpi=110, metadata=png_metadata(fig))
        _write_workbook(result, table, effects, units, work / "whatif.xlsx", tolerance,
                        run=run)
    for p in sorted(out.rglob("*")):
        if p.is_file():
            files[str(p.relative_to(out))] = p
    return files


_CHANGE_PCT = "_change_pct"


def _tolerance_to_units(tol, units):
    """The tolerance table with each metric's values in `units` (None stays None)."""
    if tol is None:
        return None
    out = tol.copy()
    for q, rows in out.groupby("quantity").groups.items():
        qty = METRIC_QUANTITY.get(q)
        if qty is None or units == "SI":
            continue
        for c in ("nominal", "low", "high", "spread", "worst"):
            out.loc[rows, c] = from_si(out.loc[rows, c].to_numpy(dtype=float), qty, units)
    return out


def robust_verdicts(robust):
    """Each setup of a robust ranking against its best (the first row): ``best``, ``tied``
    where the setup ranks first in some condition (``best_share`` > 0: the conditions do
    not separate it from the best), else ``worse``; ``infeasible`` where it is feasible in
    no condition.

    Examples
    --------
    >>> r = pd.DataFrame({"best_share": [0.7, 0.3, 0.0], "feasible_share": [1, 1, 0.0]},
    ...                  index=["a", "b", "c"])
    >>> robust_verdicts(r).tolist()
    ['best', 'tied', 'infeasible']
    """
    out = []
    for k, (name, r) in enumerate(robust.iterrows()):
        if k == 0:
            out.append("best")
        elif "feasible_share" in robust.columns and float(r["feasible_share"]) == 0.0:
            out.append("infeasible")
        elif float(r.get("best_share", 0.0)) > 0.0:
            out.append("tied")
        else:
            out.append("worse")
    return pd.Series(out, index=robust.index, name="verdict")


def _summary(result, units, run):
    """The what-if's summary sheet: the robust ranking's head (its first page)."""
    rob = result.robust
    head = rob.head(N_SUMMARY_ROWS)
    frame = pd.DataFrame({"robust rank": np.arange(1, len(head) + 1),
                          "setup": [str(n) for n in head.index],
                          "vs robust best": robust_verdicts(rob).loc[head.index].to_numpy()},
                         index=head.index)
    keep = [c for c in ("nominal_rank", "mean_score", "worst_score", "nominal_score",
                        "best_rank", "worst_rank", "best_share", "moved_share",
                        "feasible_share", "fragile") if c in head.columns]
    frame = pd.concat([frame, head[keep]], axis=1)
    formats = {c: "0.0%" for c in keep if c.endswith("_share")}
    formats.update({c: "0.0000" for c in keep if c.endswith("_score")})
    n_cond = len(result.conditions)
    notes = [f"robust ranking of {len(rob)} setups over {n_cond} conditions (by mean score; "
             "scores are ratios to the baseline's nominal metrics, lower is better); the "
             "other sheets are the appendix: 'robust' holds every setup",
             "vs robust best: tied = ranks first in some condition (the conditions do not "
             "separate it from the best); fragile = its rank moves more than "
             f"{result.settings.get('rank_tolerance', '?')} place(s) in more than "
             f"{result.settings.get('fragile_share', '?')} of the conditions"]
    used = list((run or {}).items())
    if "model" in result.settings and not any(k == "model" for k, _ in used):
        used.append(("model", result.settings["model"]))
    if "drives" in result.settings and not any(k == "drive" for k, _ in used):
        d = result.settings["drives"]
        used.append(("drives", ", ".join(map(str, d)) if isinstance(d, (list, tuple)) else d))
    used += [("objective", result.objective.name), ("baseline", result.baseline),
             ("units", units)]
    figure = None
    best, base = str(rob.index[0]), result.baseline
    scores = [c for c in ("nominal_score", "mean_score", "worst_score") if c in rob.columns]
    if base in rob.index and base != best and scores:
        labels = {c: f"{column_label(c)}: {rob.loc[base, c]:.4f} -> {rob.loc[best, c]:.4f}"
                  for c in scores}
        figure = summary_figure(rob[scores], best=best, baseline=base, labels=labels,
                                title=f"scores: robust best '{best}' against baseline "
                                      f"'{base}'")
    return {"title": "shockplan what-if: robust ranking", "table": frame,
            "headers": [column_label(c) for c in frame.columns], "formats": formats,
            "notes": notes, "used": used, "figure": figure}


def _write_workbook(result, table, effects, units, path, tolerance=None, run=None):
    """``whatif.xlsx``: sheets robust, conditions, effects, table and settings, each laid out
    and set to print with :mod:`planner.report.sheets` (the wide table across pages, the
    drive, condition and setup repeated on each)."""
    from openpyxl import Workbook  # heavy, needed only here
    from openpyxl.styles import PatternFill
    from openpyxl.utils import get_column_letter

    wb = Workbook()
    what = f"shockplan what-if ({units}), baseline {result.baseline}"
    fragile_fill = PatternFill("solid", fgColor="F8CBAD")

    def area(frame, last):
        return f"A1:{get_column_letter(frame.shape[1])}{last}"

    ws = wb.active
    ws.title = "robust"
    rob = result.robust.reset_index().round(4)
    shares = {c: "0.0%" for c in rob.columns if str(c).endswith("_share")}
    last = write_table(ws, rob, formats=shares)
    for r, flag in enumerate(rob["fragile"].tolist(), start=2):
        if flag:
            for cell in ws[r]:
                cell.fill = fragile_fill
    print_setup(ws, units=units, area=area(rob, last), title_rows="1:1",
                footer=f"{what}: robust ranking over the conditions; fragile rows filled")
    cond = result.conditions.reset_index()
    ws = wb.create_sheet("conditions")
    last = write_table(ws, cond, headers=[str(c) if c in result.conditions.columns
                                          else column_label(c) for c in cond.columns],
                       freeze_cols=2)
    print_setup(ws, units=units, area=area(cond, last), title_rows="1:1", title_cols="A:B",
                footer=f"{what}: the conditions (a factor's value in each)")
    if effects:
        eff = pd.concat(effects, ignore_index=True)[
            ["setup", "factor", "low", "high", "change_low", "change_high", "swing"]]
        ws = wb.create_sheet("effects")
        last = write_table(ws, eff, freeze_cols=2)
        print_setup(ws, units=units, area=area(eff, last), title_rows="1:1",
                    title_cols="A:B", footer=f"{what}: each factor's effect on the score")
    if tolerance is not None:
        ws = wb.create_sheet("tolerance")
        tol = tolerance.assign(quantity=[column_label(q) if q in METRIC_QUANTITY else q
                                         for q in tolerance["quantity"]])
        last = write_table(ws, tol, freeze_cols=3, formats={"spread_pct": "0.00"})
        print_setup(ws, units=units, area=area(tol, last), title_rows="1:1", title_cols="A:C",
                    footer=f"{what}: each setup's spread over each click or fade factor's "
                           "levels and the nominal condition")
    changes = [c for c in table.columns if c.endswith(_CHANGE_PCT)]
    cols = ["drive", "perturbation", "setup", "score", "rank", "score_change",
            "rank_change", "feasible"] + (["clipped"] if "clipped" in table.columns
                                          else []) + changes
    heads = [f"{column_label(c[:-len(_CHANGE_PCT)])} change [%]" if c in changes
             else column_label(c) for c in cols]
    # pages across break between metric families (tire force, ride height, ...)
    groups = ["run"] * (len(cols) - len(changes)) + [
        c[:-len(_CHANGE_PCT)].rsplit("_", 1)[0] for c in changes]
    ws = wb.create_sheet("table")
    frame = table[cols]
    last = write_table(ws, frame, headers=heads, freeze_cols=3,
                       formats={c: "0.00" for c in changes})
    print_setup(ws, units=units, area=area(frame, last), title_rows="1:1", title_cols="A:C",
                group_starts=[j + 1 for j in range(1, len(groups)) if groups[j] != groups[j - 1]],
                footer=f"{what}: every setup in every condition; metric changes from the "
                       "setup's nominal")
    rows = []
    for k, v in result.settings.items():
        if k in _TIMING_KEYS:  # a rerun writes the same cells (timings go to the log)
            continue
        if k == "agreement":  # screening's nominal scores checked in the time domain
            rows.append(("screening vs time domain (nominal)", describe_agreement(v, what=None)))
            continue
        rows.append((k, _xl(v if not isinstance(v, (list, tuple)) else ", ".join(map(str, v)))))
    rows += [("units", units), ("baseline", result.baseline),
             ("objective", result.objective.name)]
    ws = wb.create_sheet("settings")
    last = write_key_values(ws, rows)
    print_setup(ws, units=units, area=f"A1:B{last}", footer=f"{what}: settings")
    write_summary_sheet(wb, units=units, footer=f"{what}: robust ranking (summary)",
                        **_summary(result, units, run))
    wb.save(path)


def _xl(x):
    if isinstance(x, (np.bool_,)):
        return bool(x)
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
