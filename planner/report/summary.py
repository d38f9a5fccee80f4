"""The one-page summary sheet every workbook opens with, its verdicts and its small plot.

Every workbook the planner writes (``ranking.xlsx``, ``whatif.xlsx``, ``optimize.xlsx``,
``test_plan.xlsx``) opens with a sheet ``summary`` that prints on one page (fit to one page,
landscape, text >= :data:`planner.report.sheets.MIN_PRINT_PT`): a title, a few notes, the
best setups (at most :data:`N_SUMMARY_ROWS` rows) with their verdicts and key metrics in the
project's units, what the run used (model, drive, crate, objective) and a small plot
(:func:`summary_figure`). The workbook's other sheets follow as the appendix.

- :func:`verdicts`: better / tied / worse of each setup against a reference one (the best,
  the baseline) from the uncertainty a ranking has: its ``verdict`` columns (the intervals
  of the score differences, :func:`planner.uncertainty.score_intervals`), else its
  ``unresolved`` pairs (the setups whose order the identified model's error does not
  resolve);
- :func:`summary_figure`: the best against the baseline: the predicted shock-velocity
  histograms per corner when a histogram table is given (columns ``setup, corner,
  velocity_lo, velocity_hi, share``, as ``histograms.csv``), else the key metrics' change;
- :func:`write_summary_sheet`: the sheet, first in the workbook, set to print on one page.

The sheet's height is budgeted (:data:`SUMMARY_FIGURE_IN`, the rows) so that one page holds
it at >= 7 pt on A4 and US letter; ``tests/test_sheets.py`` converts each workbook's first
sheet to PDF with LibreOffice and checks one page and the text size.
"""

from __future__ import annotations

import io
import logging
import math
import textwrap

import numpy as np
import pandas as pd
from openpyxl.drawing.image import Image
from openpyxl.styles import Alignment, Font
from openpyxl.utils import get_column_letter
from openpyxl.worksheet.page import PageMargins
from openpyxl.worksheet.properties import PageSetupProperties

from ident.data.units import UNIT_LABELS, check_units, from_si
from ident.sim.metrics import METRIC_QUANTITY
from planner.report.sheets import (FOOTER_PT, MIN_PRINT_PT, PAPER_SIZE, PRINT_MARGINS_IN,
                                   WIDTH_UNIT_PT, column_label, column_widths, decimals_format,
                                   printable_size_pt, smallest_font_pt, wrap_lines, write_table)

__all__ = ["N_SUMMARY_ROWS", "SUMMARY_FIGURE_IN", "SUMMARY_SHEET", "HISTOGRAM_COLUMNS",
           "summary_figure", "summary_parts", "verdicts", "write_summary_sheet"]

log = logging.getLogger(__name__)

#: The summary sheet's name (first in every workbook).
SUMMARY_SHEET = "summary"
#: At most this many setups in the summary's table (the page's height).
N_SUMMARY_ROWS = 10
#: The summary plot's size [in] (width, height) as placed on the sheet.
SUMMARY_FIGURE_IN = (6.4, 2.5)
#: Columns of a histogram table :func:`summary_figure` takes (``histograms.csv``).
HISTOGRAM_COLUMNS = ("setup", "corner", "velocity_lo", "velocity_hi", "share")
_FONT = "Calibri"
_NOTE_PT, _TITLE_PT = 9, 12
_LINE_PT = {_NOTE_PT: 12.0, _TITLE_PT: 17.0}
_PX_PER_IN = 96  # openpyxl places images in pixels of 96 per inch
_FIG_DPI = 150
#: The plot's text [pt] as placed (>= 7 pt printed at the page's scale, which stays >= 0.9).
_FIG_PT = 8.0


def verdicts(table, reference, *, worse="worse", better="better"):
    """Better / tied / worse of every setup against `reference`, by the ranking's uncertainty.

    Parameters
    ----------
    table : pandas.DataFrame
        Indexed by setup name, with ``score`` (lower is better); optionally ``feasible``,
        the verdicts of :func:`planner.uncertainty.score_intervals` (``verdict`` against the
        best, ``verdict_baseline`` against the baseline: from the intervals of the score
        differences) and ``unresolved`` (space-separated names of the setups a setup is not
        resolved from, :func:`planner.uncertainty.unresolved_pairs`).
    reference : str
        The setup compared with (the best, the baseline).
    worse, better : str
        The words for a higher and a lower score.

    Returns
    -------
    pandas.Series of str
        ``"reference"`` for `reference` itself, ``"infeasible"`` for an infeasible setup;
        where `reference` is the setup the table's ``verdict`` calls ``best`` (or
        ``verdict_baseline`` calls ``baseline``), that column's verdict (``tied``: the
        interval of the score difference contains 0; ``better``/``worse`` as `better`,
        `worse`); else ``"tied"`` where either names the other as not resolved, else
        `better` or `worse` by the score (``"tied"`` for an equal one). Without those
        columns, or with them empty everywhere (a known model, or no intervals asked),
        only the scores decide.

    Examples
    --------
    >>> t = pd.DataFrame({"score": [0.9, 0.92, 1.0], "unresolved": ["b", "a", ""]},
    ...                  index=["a", "b", "c"])
    >>> verdicts(t, "a").tolist()
    ['reference', 'tied', 'worse']
    """
    if reference not in table.index:
        raise KeyError(f"verdicts: the reference setup {reference!r} is not in the table")
    pairs = {}
    if "unresolved" in table.columns:
        pairs = {str(n): set(str(v or "").split()) for n, v in table["unresolved"].items()}
    feasible = (table["feasible"].astype(bool) if "feasible" in table.columns
                else pd.Series(True, index=table.index))
    ref_score = float(table.loc[reference, "score"])
    ref_pairs = pairs.get(str(reference), set())
    judged = None  # the interval verdicts against `reference`, when the table has them
    for col, word in (("verdict", "best"), ("verdict_baseline", "baseline")):
        if col in table.columns and str(table.loc[reference, col]) == word:
            judged = table[col].astype(str).replace({"better": better, "worse": worse})
            break
    out = []
    for name, score in table["score"].items():
        if name == reference:
            out.append("reference")
        elif not feasible.loc[name]:
            out.append("infeasible")
        elif judged is not None and judged.loc[name] in (better, worse, "tied"):
            out.append(judged.loc[name])
        elif str(reference) in pairs.get(str(name), set()) or str(name) in ref_pairs:
            out.append("tied")
        elif float(score) == ref_score:
            out.append("tied")
        else:
            out.append(better if float(score) < ref_score else worse)
    return pd.Series(out, index=table.index, name="verdict")


def _histogram_axes(ax, hist, setups):
    """Step histograms of `setups` (share per bin) on one axes; open end bins drawn one
    bin wide."""
    for k, (name, style) in enumerate(zip(setups, ("-", "--"))):
        h = hist[hist["setup"] == name]
        lo = h["velocity_lo"].to_numpy(dtype=float)
        hi = h["velocity_hi"].to_numpy(dtype=float)
        share = h["share"].to_numpy(dtype=float)
        width = np.nanmedian(hi - lo) if np.isfinite(hi - lo).any() else 1.0
        lo = np.where(np.isfinite(lo), lo, hi - width)
        hi = np.where(np.isfinite(hi), hi, lo + width)
        order = np.argsort(lo)
        edges = np.append(lo[order], hi[order][-1:])
        ax.stairs(100.0 * share[order], edges, ls=style, color=f"C{3 * k}", lw=1.1,
                  label=name)
    ax.axvline(0.0, color="0.5", lw=0.5)
    ax.tick_params(labelsize=_FIG_PT)


#: Width of a character of the summary figure's title, in units of its font size (a
#: generous mean for DejaVu Sans, so that a wrapped line never runs past the figure's edge).
_TITLE_CHAR_EM = 0.62


def _fit_title(text):
    """The summary figure's title wrapped to the figure's width (long setup names,
    ``C2/C2/R1/R1 heave_front=H0 heave_rear=HD``, would run past both edges)."""
    width = int(SUMMARY_FIGURE_IN[0] * 72.0 / ((_FIG_PT + 0.5) * _TITLE_CHAR_EM))
    return textwrap.fill(text, width, break_long_words=True, break_on_hyphens=False)


def summary_figure(metrics=None, *, best, baseline, histograms=None, labels=None,
                   velocity_unit="m/s", title=None):
    """The summary's small plot: the best setup against the baseline.

    Parameters
    ----------
    metrics : pandas.DataFrame, optional
        Indexed by setup name, the key metrics' values (any unit; shown as the best's change
        from the baseline [%], the values in the bar's label).
    best, baseline : str
        The setups compared.
    histograms : pandas.DataFrame, optional
        Columns :data:`HISTOGRAM_COLUMNS` (``histograms.csv``: one row per setup, corner and
        velocity bin, the share of time 0-1, an open end bin's missing bound NaN). Given, the
        plot is the shock-velocity histogram of the best and the baseline per corner
        (taking precedence over `metrics`).
    labels : dict of str to str, optional
        Per metric column, the bar's text (e.g. ``"tire force RMS LF: 412 -> 398 lbf"``);
        default the column's name and the two values.
    velocity_unit : str
        The histogram's velocity unit (``"m/s"``, ``"in/s"``).
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
        :data:`SUMMARY_FIGURE_IN` in size.

    Raises
    ------
    ValueError
        A histogram table without the columns, or neither table given.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=SUMMARY_FIGURE_IN, layout="constrained")
    FigureCanvasAgg(fig)
    if histograms is not None:
        missing = [c for c in HISTOGRAM_COLUMNS if c not in histograms.columns]
        if missing:
            raise ValueError(f"summary_figure: the histogram table lacks {missing}; it needs "
                             f"the columns {list(HISTOGRAM_COLUMNS)} (histograms.csv)")
        corners = list(dict.fromkeys(histograms["corner"].astype(str)))
        axes = fig.subplots(1, len(corners), sharey=True, squeeze=False)[0]
        for ax, corner in zip(axes, corners):
            _histogram_axes(ax, histograms[histograms["corner"].astype(str) == corner],
                            [best, baseline] if best != baseline else [best])
            ax.set_title(corner, fontsize=_FIG_PT, pad=2)
        axes[0].set_ylabel("time [%]", fontsize=_FIG_PT)
        for ax in axes:  # short labels that do not run into each other; the legend below
            ax.set_xlabel(f"velocity [{velocity_unit}], bump +", fontsize=_FIG_PT, labelpad=1)
        fig.legend(*axes[-1].get_legend_handles_labels(), fontsize=_FIG_PT, frameon=False,
                   loc="outside lower center", ncols=2)
        fig.suptitle(_fit_title(title or f"shock-velocity histogram: best '{best}' against "
                                f"baseline '{baseline}'"), fontsize=_FIG_PT + 0.5)
        return fig
    if metrics is None or len(metrics.columns) == 0:
        raise ValueError("summary_figure: give the key metrics or a histogram table")
    cols = list(metrics.columns)
    b = metrics.loc[baseline, cols].to_numpy(dtype=float)
    v = metrics.loc[best, cols].to_numpy(dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        change = 100.0 * (v / b - 1.0)
    ax = fig.add_subplot()
    y = np.arange(len(cols))[::-1]
    colors = ["C2" if c < 0 else "C3" for c in np.nan_to_num(change)]
    ax.barh(y, np.nan_to_num(change), color=colors, height=0.6)
    ax.axvline(0.0, color="k", lw=0.6)
    text = [(labels or {}).get(c, f"{c}: {bv:.4g} -> {vv:.4g}") for c, bv, vv in zip(cols, b, v)]
    ax.set_yticks(y, text, fontsize=_FIG_PT)
    ax.tick_params(axis="x", labelsize=_FIG_PT)
    span = max(float(np.nanmax(np.abs(change))) if np.isfinite(change).any() else 1.0, 0.5)
    ax.set_xlim(-1.6 * span, 1.6 * span)
    for yy, c in zip(y, change):
        if np.isfinite(c):
            ax.text(c, yy, f" {c:+.1f} %", va="center", ha="left" if c >= 0 else "right",
                    fontsize=_FIG_PT)
    ax.set_xlabel("change from the baseline [%]", fontsize=_FIG_PT)
    ax.grid(True, axis="x", lw=0.3, alpha=0.5)
    fig.suptitle(_fit_title(title or f"key metrics: best '{best}' against baseline "
                            f"'{baseline}'"), fontsize=_FIG_PT + 0.5)
    return fig


def summary_parts(table, *, best, baseline, metrics=(), units="SI", first=("rank",),
                  rows=None, title, notes=(), used=(), histograms=None):
    """The summary sheet of a ranked table: its rows, verdicts, key metrics and plot.

    Parameters
    ----------
    table : pandas.DataFrame
        Indexed by setup name, best first: ``score`` (lower is better), optionally
        ``score_<group>``, ``feasible``, ``verdict``/``verdict_baseline``
        (:func:`planner.uncertainty.score_intervals`: a note then names the best and the
        setups tied with it), ``unresolved`` and the metric columns (SI).
    best, baseline : str
        The setups the verdicts compare with (:func:`verdicts`) and the plot shows.
    metrics : sequence of str
        The key metrics shown (converted to `units`, headers with their unit).
    units : {"SI", "imperial"}
    first : sequence of str
        Columns of `table` shown before the setup's name (those present).
    rows : sequence of str, optional
        The setups shown; default the first :data:`N_SUMMARY_ROWS` - 1 and the baseline.
    title : str
    notes, used : sequence
        As :func:`write_summary_sheet`; a line on what the verdicts rest on is added to
        `notes`.
    histograms : pandas.DataFrame, optional
        For :func:`summary_figure`, in `units`.

    Returns
    -------
    dict
        The keyword arguments of :func:`write_summary_sheet` but `wb`, `units` and `footer`.
    """
    units = check_units(units, where="summary_parts")
    if rows is None:
        rows = list(table.index[:N_SUMMARY_ROWS - 1])
        if baseline in table.index and baseline not in rows:
            rows.append(baseline)
    shown = table.loc[list(rows)]
    frame = shown[[c for c in first if c in shown.columns]].copy()
    frame.insert(len(frame.columns), "setup", [str(n) for n in shown.index])
    if "score" in shown.columns:
        frame["vs best"] = verdicts(table, best).loc[list(rows)].replace({"reference": "best"})
        if baseline in table.index:
            frame["vs baseline"] = verdicts(table, baseline).loc[list(rows)].replace(
                {"reference": "baseline"})
        for c in ["score"] + [c for c in shown.columns if str(c).startswith("score_")
                              and c not in ("score_lo", "score_hi")]:
            frame[c] = shown[c].to_numpy()
    metrics = [m for m in metrics if m in table.columns]
    conv = pd.DataFrame({m: from_si(table[m].to_numpy(dtype=float), METRIC_QUANTITY[m], units)
                         for m in metrics}, index=table.index)
    for m in metrics:
        frame[m] = conv.loc[list(rows), m].to_numpy()

    def unit(m):
        return UNIT_LABELS[units][METRIC_QUANTITY[m]]

    headers = [f"{column_label(c)} [{unit(c)}]" if c in METRIC_QUANTITY else column_label(c)
               for c in frame.columns]
    formats = {c: "0.0000" for c in frame.columns if str(c).startswith("score")}
    formats.update({m: decimals_format(frame[m].tolist()) for m in metrics})
    pairs = ("unresolved" in table.columns
             and table["unresolved"].astype(str).str.strip().astype(bool).any())
    intervals = any(str(c).endswith("_lo") for c in table.columns)
    judged = "verdict" in table.columns and (table["verdict"].astype(str) == "best").any()
    if judged:
        why = ("tied: the 95 % interval of the two setups' score difference contains 0 (the "
               "identified model's error shared by both cancels in it); better/worse: the "
               "interval is below/above 0")
    elif intervals or pairs:
        why = ("tied: the identified model's error does not resolve the two setups' order "
               "(the 'unresolved' pairs, from the intervals)")
    else:
        why = "by the scores alone (no intervals: a known model, or none asked)"
    notes = list(notes) + [f"verdicts against the best and the baseline: {why}"]
    if judged:
        best_name = table.index[table["verdict"].astype(str) == "best"][0]
        tied = [str(n) for n in table.index[table["verdict"].astype(str) == "tied"]]
        more = f" and {len(tied) - N_SUMMARY_ROWS} more" if len(tied) > N_SUMMARY_ROWS else ""
        notes.append(f"best: '{best_name}'; tied with it: "
                     + (", ".join(f"'{n}'" for n in tied[:N_SUMMARY_ROWS]) + more
                        if tied else "none"))
    figure = None
    if histograms is not None:
        figure = summary_figure(best=best, baseline=baseline, histograms=histograms,
                                velocity_unit=UNIT_LABELS[units]["velocity"])
    elif metrics and baseline in table.index and baseline != best:
        labels = {m: f"{column_label(m)}: {conv.loc[baseline, m]:.4g} -> "
                     f"{conv.loc[best, m]:.4g} {unit(m)}" for m in metrics}
        figure = summary_figure(conv, best=best, baseline=baseline, labels=labels)
    return {"title": title, "table": frame, "headers": headers, "formats": formats,
            "notes": notes, "used": list(used), "figure": figure}


def _merged_text(ws, row, text, last_col, width_units, *, bold=False, size=_NOTE_PT):
    """A line of text over columns A..`last_col` (merged, wrapped); returns its height [pt]."""
    cell = ws.cell(row=row, column=1, value=str(text))
    cell.font = Font(name=_FONT, size=size, bold=bold)
    cell.alignment = Alignment(wrap_text=True, vertical="top", horizontal="left")
    if last_col > 1:
        ws.merge_cells(start_row=row, start_column=1, end_row=row, end_column=last_col)
    n = max(1, len(wrap_lines(text, width_units - 1.0, size=size, bold=bold)))
    height = _LINE_PT.get(size, size * 1.35) * n + 1
    ws.row_dimensions[row].height = height
    return height


def write_summary_sheet(wb, *, title, table, units, headers=None, formats=None, notes=(),
                        used=(), figure=None, footer=None):
    """Write the summary sheet, first in the workbook, set to print on one page.

    Parameters
    ----------
    wb : openpyxl.Workbook
    title : str
        Bold, on the first row.
    table : pandas.DataFrame
        The rows to show (the index is not written): the best setups, their verdicts and
        key metrics, already in the project's units; at most :data:`N_SUMMARY_ROWS` rows
        are written.
    units : {"SI", "imperial"}
        Chooses the paper (A4, US letter).
    headers, formats : optional
        As :func:`planner.report.sheets.write_table`.
    notes : sequence of str
        Lines under the title (what the verdicts mean, the sections' winners, ...).
    used : sequence of (str, object)
        What the run used (model, drive, crate, objective, ...): one line each, under the
        table.
    figure : matplotlib.figure.Figure, optional
        Placed under the lines at :data:`SUMMARY_FIGURE_IN`.
    footer : str, optional

    Returns
    -------
    float
        The print scale estimated (1 = 100 %): the page's width and height over the sheet's.
    """
    units = check_units(units, where="write_summary_sheet")
    ws = wb.create_sheet(SUMMARY_SHEET, 0)
    wb.active = 0
    for other in wb.worksheets[1:]:
        other.sheet_view.tabSelected = False
    frame = table.head(N_SUMMARY_ROWS)
    n_cols = max(len(frame.columns), 1)
    room_w, room_h = printable_size_pt(units)
    head = 1 + (len(notes) + 1 if notes else 1)
    last = write_table(ws, frame, headers=headers, formats=formats, top=head, freeze_cols=None)
    widths = column_widths(ws, 1, n_cols)
    fig_w_units = SUMMARY_FIGURE_IN[0] * 72.0 / WIDTH_UNIT_PT if figure is not None else 0.0
    while sum(widths) < fig_w_units + 1:  # the plot wider than the table: more columns
        widths.append(8.43)
    last_col = len(widths)
    total = sum(widths)
    height = _merged_text(ws, 1, title, last_col, total, bold=True, size=_TITLE_PT)
    for k, line in enumerate(notes):
        height += _merged_text(ws, 2 + k, line, last_col, total)
    heights = [ws.row_dimensions[r].height or 15.0 for r in range(head, last + 1)]
    height += sum(heights) + 6
    r = last + 2
    for label, value in used:
        height += _merged_text(ws, r, f"{label}: {value}", last_col, total)
        r += 1
    if figure is not None:
        buf = io.BytesIO()
        figure.savefig(buf, format="png", dpi=_FIG_DPI)
        img = Image(io.BytesIO(buf.getvalue()))
        img.width = int(SUMMARY_FIGURE_IN[0] * _PX_PER_IN)
        img.height = int(SUMMARY_FIGURE_IN[1] * _PX_PER_IN)
        r += 1
        ws.add_image(img, f"A{r}")
        fig_h = SUMMARY_FIGURE_IN[1] * 72.0 + 6
        n_rows = math.ceil(fig_h / 15.0)
        for k in range(n_rows):
            ws.row_dimensions[r + k].height = 15.0
        r += n_rows
        height += fig_h + 15.0
    area = f"A1:{get_column_letter(last_col)}{r}"
    ps = ws.page_setup
    ps.orientation = "landscape"
    ps.paperSize = PAPER_SIZE[units]
    ps.fitToWidth, ps.fitToHeight = 1, 1
    ws.sheet_properties.pageSetUpPr = PageSetupProperties(fitToPage=True)
    ws.page_margins = PageMargins(**PRINT_MARGINS_IN)
    ws.print_options.horizontalCentered = True
    ws.print_options.gridLines = False
    ws.print_area = area
    scale = min(1.0, room_w / (WIDTH_UNIT_PT * total), room_h / height)
    font = smallest_font_pt(ws, area)
    if font * scale < MIN_PRINT_PT:
        log.warning("summary sheet: its smallest text prints at %.1f pt (< %.0f pt); the "
                    "table or the notes are too long for one page", font * scale, MIN_PRINT_PT)
    size = max(FOOTER_PT, math.ceil((MIN_PRINT_PT + 0.25) / max(scale, 0.1)))
    if footer:
        ws.oddFooter.left.text = str(footer).replace("&", "&&")
        ws.oddFooter.left.size = size
    ws.oddFooter.right.text = "&A, page &P of &N"
    ws.oddFooter.right.size = size
    return scale
