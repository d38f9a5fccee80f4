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
from pathlib import Path

import numpy as np
import pandas as pd

from ident.data.files import atomic_dir
from ident.data.units import check_units
from planner.errors import PlannerError
from planner.report.ranking import ranking_to_units

__all__ = [
    "factor_effects",
    "tornado_figure",
    "rank_stability_figure",
    "write_whatif",
]


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
        ``tire_force_rms_LF_change_pct``).

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
    if quantity not in t.columns:
        raise PlannerError(f"{quantity!r} is not a column of the what-if table")
    d0 = result.settings["drives"][0]
    rows = t[(t["setup"] == setup) & (t["drive"] == d0)].set_index("perturbation")
    conds = result.perturbations.table().loc[rows.index]
    y = rows[quantity].to_numpy(dtype=float)
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


# ----------------------------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------------------------

def tornado_figure(result, setup, *, quantity="score_change", max_factors=12):
    """Tornado chart of the factors' effects on one setup (:func:`factor_effects`).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure  # heavy, needed only for the figures

    eff = factor_effects(result, setup, quantity=quantity).head(max_factors).iloc[::-1]
    fig = Figure(figsize=(7.5, 0.45 * max(len(eff), 3) + 1.4))
    ax = fig.add_subplot()
    ypos = np.arange(len(eff))
    for y_, (name, r) in zip(ypos, eff.iterrows()):
        for val, label, color in ((r["change_low"], r["low"], "#4C72B0"),
                                  (r["change_high"], r["high"], "#DD8452")):
            ax.barh(y_, val, color=color, height=0.6)
            txt = label if isinstance(label, str) else f"{label:.4g}"
            ax.annotate(txt, (val, y_), xytext=(3 if val >= 0 else -3, 0),
                        textcoords="offset points", va="center",
                        ha="left" if val >= 0 else "right", fontsize=7)
    ax.set_yticks(ypos, [str(i) for i in eff.index], fontsize=8)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel(quantity.replace("_", " ") + " (low value blue, high value orange)")
    ax.set_title(f"what-if effects on {setup}", fontsize=10)
    ax.margins(x=0.25)
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
    fig = Figure(figsize=(9.0, 5.0))
    ax = fig.add_subplot()
    if len(piv) <= 30:
        x = np.arange(len(piv))
        for n in names:
            ax.plot(x, piv[n].to_numpy(), marker="o", ms=3, lw=1.2,
                    label=f"{n}{' (fragile)' if rob.loc[n, 'fragile'] else ''}")
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
                      [f"{n}{' *' if rob.loc[n, 'fragile'] else ''}" for n in names],
                      rotation=45, ha="right", fontsize=7)
        ax.legend(fontsize=8, loc="lower left")
        ax.set_xlabel("setup (* fragile rank); boxes 25-75 %, whiskers 5-95 % of conditions")
    ax.invert_yaxis()
    ax.set_ylabel("rank (1 = best)")
    ax.set_title(f"rank stability over {len(piv)} conditions "
                 f"({result.perturbations.design}, {result.settings['method']})", fontsize=10)
    fig.tight_layout()
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


def write_whatif(result, out_dir, *, units="SI", top=5, overwrite=False):
    """Write a what-if's files into a folder (built aside, moved into place at the end).

    Files: ``whatif.xlsx`` (sheets ``robust``, ``conditions``, ``effects`` and
    ``table``), ``whatif.csv`` (the long table, metrics in `units`), ``robust.csv``,
    ``conditions.csv``, ``rank_stability.png`` and ``tornado/<nn>_<setup>.png`` for the
    `top` setups of the robust ranking.

    Returns
    -------
    dict of str -> pathlib.Path

    Raises
    ------
    FileExistsError
        If `out_dir` exists and is not empty and `overwrite` is false (checked first).
    """
    from openpyxl import Workbook  # heavy, needed only here
    from openpyxl.styles import Font, PatternFill

    units = check_units(units, where="units", error=PlannerError)
    out = Path(out_dir)
    files = {}
    with atomic_dir(out, overwrite=overwrite) as work:
        table = ranking_to_units(result.table, units)
        table.to_csv(work / "whatif.csv", index=False, float_format="%.6g")
        result.robust.to_csv(work / "robust.csv", float_format="%.6g")
        result.conditions.to_csv(work / "conditions.csv")
        top_names = list(result.robust.index[:top])
        effects = []
        (work / "tornado").mkdir()
        for k, n in enumerate(top_names):
            eff = factor_effects(result, n)
            effects.append(eff.reset_index().assign(setup=n))
            fig = tornado_figure(result, n)
            fig.savefig(work / "tornado" / f"{k + 1:02d}_{_safe_name(n)}.png", dpi=110)
        fig = rank_stability_figure(result)
        fig.savefig(work / "rank_stability.png", dpi=110)
        wb = Workbook()
        bold = Font(bold=True)
        fragile_fill = PatternFill("solid", fgColor="F8CBAD")

        def sheet(ws, frame, *, highlight=None):
            ws.append(list(frame.columns))
            for cell in ws[1]:
                cell.font = bold
            for row in frame.itertuples(index=False):
                ws.append([_xl(x) for x in row])
            if highlight is not None:
                for r, flag in enumerate(highlight, start=2):
                    if flag:
                        for cell in ws[r]:
                            cell.fill = fragile_fill
            ws.freeze_panes = "B2"
            for col in ws.columns:
                width = max(len(str(c.value)) if c.value is not None else 0 for c in col)
                ws.column_dimensions[col[0].column_letter].width = min(max(width + 2, 8), 40)

        ws = wb.active
        ws.title = "robust"
        rob = result.robust.reset_index()
        sheet(ws, rob.round(4), highlight=rob["fragile"].tolist())
        sheet(wb.create_sheet("conditions"), result.conditions.reset_index())
        if effects:
            sheet(wb.create_sheet("effects"), pd.concat(effects, ignore_index=True)[
                ["setup", "factor", "low", "high", "change_low", "change_high", "swing"]])
        cols = ["drive", "perturbation", "setup", "score", "rank", "score_change",
                "rank_change", "feasible"] + [c for c in table.columns
                                              if c.endswith("_change_pct")]
        sheet(wb.create_sheet("table"), table[cols])
        info = wb.create_sheet("settings")
        for k, v in result.settings.items():
            if k in _TIMING_KEYS:  # a rerun writes the same cells (timings go to the log)
                continue
            info.append([k, _xl(v if not isinstance(v, (list, tuple)) else ", ".join(map(str, v)))])
        info.append(["units", units])
        info.append(["baseline", result.baseline])
        info.append(["objective", result.objective.name])
        wb.save(work / "whatif.xlsx")
    for p in sorted(out.rglob("*")):
        if p.is_file():
            files[str(p.relative_to(out))] = p
    return files


def _xl(x):
    if isinstance(x, (np.bool_,)):
        return bool(x)
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
