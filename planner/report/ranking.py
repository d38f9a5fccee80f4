"""Reports of predicted and ranked setups: CSV, Excel workbook and summary plots.

The input is a *ranking table*: a :class:`pandas.DataFrame` with one row per
setup, indexed by setup name (or with a column ``setup``), holding

- the shock ids ``LF, RF, LR, RR`` (:data:`ident.data.channels.CORNERS`);
- metric columns named as in :mod:`ident.sim.metrics` (``tire_force_rms_LF``,
  ``ride_height_rms_front``, ...), SI;
- optionally interval columns ``<metric>_lo`` and ``<metric>_hi`` (SI);
- optionally the columns of :class:`planner.objective.Scores` (``score``,
  ``score_<group>``, ``feasible``, ``violations``, ``rank``), a
  ``screening_rank`` and a note ``unresolved`` (str); any other column is
  carried along unchanged.

:func:`write_predictions_csv` writes the rig-session spec's predictions CSV;
:func:`write_ranking` writes a folder with ``ranking.csv``, ``ranking.xlsx``,
``pareto.png`` and ``top_setups.png``. The workbook is laid out to print with
the shared print layout of :mod:`planner.report.sheets` (landscape, header repeated,
one page wide or, too wide for that, across pages with the setup repeated; the same
layout as every workbook the planner writes).

Column order of every written CSV (the spec's "Predictions"): ``setup, LF,
RF, LR, RR``, then the spec's metrics in :data:`ident.sim.metrics.METRIC_NAMES`
order (those present), then the other metric columns, then every further
column in table order. The ranking files put ``rank`` first; the workbook
puts the key columns first and the intervals on their own sheet (see
:func:`write_ranking`). Every CSV's last column is ``units``, ``SI`` or ``imperial`` on every row
(:func:`ident.data.files.write_csv`).

Notes
-----
Values are SI inside; :func:`ranking_to_units` converts metric and interval
columns for files and display. Scores are ratios to the baseline and have no
unit. Plots use the object-oriented matplotlib API only (thread-safe, no
GUI). Every file is written atomically and nothing existing is replaced
unless ``overwrite=True``.
"""

from __future__ import annotations

import io
import logging
import math
from pathlib import Path

import numpy as np
import pandas as pd

from openpyxl import Workbook
from openpyxl.styles import Alignment, Border, Font, PatternFill, Side
from openpyxl.utils import get_column_letter

from ident.data.files import atomic_write_bytes, check_can_write, png_metadata, write_csv
from ident.data.channels import CORNERS
from ident.data.units import UNIT_LABELS, check_units, from_si
from ident.sim.metrics import METRIC_NAMES, METRIC_QUANTITY
from planner.click_settings import adjuster_columns
from planner.errors import PlannerError
from planner.objective import Objective, pareto_front
from planner.report.sheets import (
    MAX_COLUMN_WIDTH,
    column_label,
    fit_column_width,
    print_setup,
    text_width,
    wrap_lines,
    write_table,
)
from planner.report.summary import summary_parts, write_summary_sheet

__all__ = [
    "INTERVAL_SUFFIXES",
    "RANKING_FILES",
    "metric_of_column",
    "ranking_columns",
    "label_key_text",
    "ranking_to_units",
    "short_labels",
    "write_predictions_csv",
    "write_ranking",
]

log = logging.getLogger(__name__)

#: Suffixes of the lower and upper interval columns of a metric.
INTERVAL_SUFFIXES = ("_lo", "_hi")
#: Setup columns holding lengths (packers, :mod:`planner.elements`), converted with the units.
PACKER_COLUMNS = tuple(f"packer_{c}" for c in CORNERS)
#: Files written by :func:`write_ranking` (key -> file name); plots only when possible.
RANKING_FILES = {"csv": "ranking.csv", "xlsx": "ranking.xlsx", "pareto": "pareto.png",
                 "top_setups": "top_setups.png", "sections": "sections.csv"}
#: Metrics shown in ``top_setups.png`` without an objective (those present).
DEFAULT_KEY_METRICS = tuple(f"tire_force_rms_{c}" for c in CORNERS) + (
    "ride_height_rms_front", "ride_height_rms_rear")
#: At most this many metrics in ``top_setups.png``.
MAX_KEY_METRICS = 6
#: Setups labelled by name in ``pareto.png``: the best ones; the setups on the Pareto front
#: are labelled too, up to :data:`MAX_PARETO_LABELS` labels in all (spread along the front
#: when it has more).
N_PARETO_LABELS = 5
#: The most labels in ``pareto.png``.
MAX_PARETO_LABELS = 14
#: Setup names longer than this are shown as ``#<rank>`` in the plots, with a key.
SHORT_LABEL_CHARS = 20
# Label layout of pareto.png (see _place_labels) [pt]: the farthest a label may sit from
# its point, the grid its corner is moved on, the gap kept between a label and a marker, a
# line, a leader line or another label, and a leader line beyond this distance.
_LABEL_REACH_PT = 90.0
_LABEL_STEP_PT = 2.0
_LABEL_PAD_PT = 1.5
_LEADER_PT = 8.0
# At most this many free places are tried per label for a clear leader line (bounds the
# time on a crowded plot; a label with none goes to the margin).
_MAX_LEADER_TRIES = 3000
# pareto.png's fixed layout [in]: figure size, margins around the axes; the right margin
# holds the legend and the labels that find no free place beside their point.
_PARETO_SIZE_IN = (8.8, 5.6)
_PARETO_MARGIN_IN = {"left": 0.85, "right": 2.45, "bottom": 0.6, "top": 0.45}
#: Number formats of the Excel sheet.
SCORE_FORMAT = "0.0000"
INTEGER_FORMAT = "0"
_INT_COLUMNS = ("rank", "screening_rank")
_GREY_FILL = "E7E6E6"
_GREY_FONT = "7F7F7F"
#: Font sizes of the printed tables [pt]: values, headers (bold), long notes.
DATA_PT, HEADER_PT, NOTE_PT = 10, 9, 9
#: Text wider than this wraps (violations, unresolved pairs) [Excel width units].
TEXT_WIDTH = 26
# The cell's padding [Excel width units] and the height of a line of each font [pt].
_PAD_W = 1.5
_LINE_PT = {"data": 13.0, "header": 12.0, "note": 12.0}


# ----------------------------------------------------------------------------------------------
# table helpers (compute)
# ----------------------------------------------------------------------------------------------

def metric_of_column(column):
    """Return the metric a column holds (interval suffix stripped), or None.

    Examples
    --------
    >>> metric_of_column("tire_force_rms_LF_hi"), metric_of_column("score")
    ('tire_force_rms_LF', None)
    """
    if not isinstance(column, str):
        return None
    if column in METRIC_QUANTITY:
        return column
    for suffix in INTERVAL_SUFFIXES:
        if column.endswith(suffix) and column[: -len(suffix)] in METRIC_QUANTITY:
            return column[: -len(suffix)]
    return None


def _check_table(table, where, *, corners=True):
    """Return the table indexed by setup name (a copy), or raise a clear error."""
    if not isinstance(table, pd.DataFrame):
        raise TypeError(f"{where}: table must be a pandas DataFrame indexed by setup name, got "
                        f"{type(table).__name__}")
    if "setup" in table.columns:
        table = table.set_index("setup")
    else:
        table = table.copy()
    table.index = table.index.map(str)
    table.index.name = "setup"
    if len(table) == 0:
        raise PlannerError(f"{where}: the table has no rows; predict at least one setup")
    if not table.index.is_unique:
        dup = table.index[table.index.duplicated()].unique().tolist()[:5]
        raise PlannerError(f"{where}: the table repeats setup name(s) {dup}; give each setup "
                           "a unique name")
    if corners:
        missing = [c for c in CORNERS if c not in table.columns]
        if missing:
            raise PlannerError(f"{where}: the table has no shock column(s) {missing}; a "
                               f"predictions table holds the shock id of every corner "
                               f"{list(CORNERS)} (join the setups to the metrics)")
    return table


def ranking_columns(table, *, rank_first=False):
    """Column order of a written table (without ``setup``, which is the index).

    Parameters
    ----------
    table : pandas.DataFrame
        A ranking table indexed by setup name.
    rank_first : bool
        Put ``rank`` (if present) first.

    Returns
    -------
    list of str
        ``[rank,] LF, RF, LR, RR`` (those present), the spec's metrics in
        :data:`ident.sim.metrics.METRIC_NAMES` order, the other metric columns
        (table order), then every further column in table order.

    Examples
    --------
    >>> t = pd.DataFrame(columns=["score", "ride_height_rms_front", "RR", "LR", "RF", "LF",
    ...                           "tire_force_rms_LF", "rank", "tire_force_rms_LF_lo"])
    >>> ranking_columns(t, rank_first=True)  # doctest: +NORMALIZE_WHITESPACE
    ['rank', 'LF', 'RF', 'LR', 'RR', 'tire_force_rms_LF', 'ride_height_rms_front', 'score',
     'tire_force_rms_LF_lo']
    """
    cols = list(table.columns)
    first = ["rank"] if rank_first and "rank" in cols else []
    first += [c for c in CORNERS if c in cols]
    first += [m for m in METRIC_NAMES if m in cols]
    first += [c for c in cols if c in METRIC_QUANTITY and c not in first]
    return first + [c for c in cols if c not in first]


def ranking_to_units(table, units):
    """Convert the metric and interval columns of a ranking table from SI.

    Parameters
    ----------
    table : pandas.DataFrame
        Ranking table (SI).
    units : {"SI", "imperial"}

    Returns
    -------
    pandas.DataFrame
        A copy; every metric column and its ``_lo``/``_hi`` columns converted
        with :func:`ident.data.units.from_si` (quantity from
        :data:`ident.sim.metrics.METRIC_QUANTITY`), the packer columns ``packer_XX``
        (lengths), every other column unchanged.

    Raises
    ------
    TypeError
        If `table` is not a DataFrame.
    ValueError
        If `units` is unknown.
    PlannerError
        If a metric column is not numeric.

    Examples
    --------
    >>> t = pd.DataFrame({"tire_force_rms_LF": [4.4482216152605], "score": [0.9]})
    >>> ranking_to_units(t, "imperial").round(12).iloc[0].tolist()
    [1.0, 0.9]
    """
    if not isinstance(table, pd.DataFrame):
        raise TypeError(f"ranking_to_units: table must be a pandas DataFrame, got "
                        f"{type(table).__name__}")
    units = check_units(units, where="ranking_to_units")
    out = table.copy()
    if units == "SI":
        return out
    for col in out.columns:
        metric = metric_of_column(col)
        if metric is None:
            if col in PACKER_COLUMNS:  # a setup column, a length (read back by read_setups)
                out[col] = from_si(out[col].to_numpy(dtype=float, na_value=np.nan), "displacement",
                                   units)
            continue
        values = out[col]
        if not pd.api.types.is_numeric_dtype(values) or pd.api.types.is_bool_dtype(values):
            raise PlannerError(f"ranking_to_units: metric column {col!r} is not numeric (dtype "
                               f"{values.dtype}); metric values are numbers in SI")
        out[col] = from_si(values.to_numpy(dtype=float, na_value=np.nan),
                           METRIC_QUANTITY[metric], units)
    return out


def _sorted_by_rank(table):
    if "rank" not in table.columns:
        return table
    return table.sort_values("rank", kind="stable", na_position="last")


def _file_frame(table, units, *, rank_first):
    """The table as written: converted, columns ordered, ``setup`` a column; with setting
    names of adjustable shocks, one column per adjuster per corner after the metrics."""
    cols = ranking_columns(table, rank_first=rank_first)
    conv = ranking_to_units(table, units)[cols]
    adj = adjuster_columns(conv)
    adj = adj[[c for c in adj.columns if c not in conv.columns]]
    if len(adj.columns):
        at = 1 + max(j for j, c in enumerate(cols) if c in CORNERS or c in METRIC_QUANTITY)
        conv = pd.concat([conv.iloc[:, :at], adj, conv.iloc[:, at:]], axis=1)
    frame = conv.reset_index()
    if rank_first and "rank" in frame.columns:
        frame = frame[["rank", "setup"] + [c for c in frame.columns if c not in ("rank", "setup")]]
    return frame


def _write_csv(frame, path, *, units, overwrite):
    # floats: shortest round-trip repr; the last column is 'units' (the unit system)
    write_csv(path, frame, units=units, overwrite=overwrite)


def write_predictions_csv(table, path, *, units="SI", overwrite=False):
    """Write the rig-session spec's predictions CSV.

    Parameters
    ----------
    table : pandas.DataFrame
        Ranking table (SI), indexed by setup name or with a column ``setup``;
        must hold the shock columns ``LF, RF, LR, RR``.
    path : str or path
        Output file.
    units : {"SI", "imperial"}
        Unit system of the metric values in the file (the drive's).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    TypeError
        If `table` is not a DataFrame.
    ValueError
        If `units` is unknown.
    PlannerError
        If the table is empty, repeats a setup name, lacks a shock column,
        or has a non-numeric metric column.
    FileExistsError
        If `path` exists and `overwrite` is false.

    Notes
    -----
    Columns ``setup, LF, RF, LR, RR``, the metrics (spec order first), then
    with setting names of adjustable shocks (``TTX@ls=6,hs=2``) one column per adjuster per
    corner (``LF_ls, LF_hs, ...``, :func:`planner.click_settings.adjuster_columns`), then the
    further columns (intervals, scores, ranks) in table order; rows in the
    table's order; floats at full precision (they read back bit-identical);
    NaN as an empty field. The header is the first line and the last column
    is ``units`` (`units` on every row): ``pandas.read_csv(path)`` reads it as it is
    (:func:`ident.data.files.read_csv_table` also drops the column and returns its
    value). Written atomically.
    """
    path = Path(path)
    table = _check_table(table, "write_predictions_csv")
    units = check_units(units, where="write_predictions_csv")
    check_can_write(path, overwrite=overwrite)
    _write_csv(_file_frame(table, units, rank_first=False), path, units=units,
               overwrite=overwrite)
    log.info("wrote predictions of %d setups (%s) to %s", len(table), units, path)
    return path


# ----------------------------------------------------------------------------------------------
# Excel
# ----------------------------------------------------------------------------------------------

def _metric_unit(metric, units):
    return UNIT_LABELS[units][METRIC_QUANTITY[metric]]


def _header(col, units):
    metric = metric_of_column(col)
    if metric is not None and metric != col:  # an interval column
        return f"{column_label(metric)} {col[len(metric) + 1:]} [{_metric_unit(metric, units)}]"
    if metric is not None:
        return f"{column_label(col)} [{_metric_unit(metric, units)}]"
    return column_label(col)


def _metric_decimals(values):
    """Decimals that show about 4 significant digits of a column's typical value (>= 3)."""
    v = np.abs(np.asarray(values, dtype=float))
    v = v[np.isfinite(v) & (v > 0)]
    if v.size == 0:
        return 3
    return int(min(max(3, 3 - math.floor(math.log10(float(np.median(v))))), 10))


def _number_formats(frame):
    """Excel number format per column of the file frame (None: general)."""
    formats = {}
    decimals = {m: _metric_decimals(frame[m]) for m in frame.columns if m in METRIC_QUANTITY}
    for col in frame.columns:
        metric = metric_of_column(col)
        if metric is not None:
            d = decimals.get(metric)
            if d is None:
                d = _metric_decimals(frame[col])
            formats[col] = "0." + "0" * d
        elif col == "score" or str(col).startswith(("score_", "diff_best_", "diff_baseline_")):
            formats[col] = SCORE_FORMAT
        elif col in _INT_COLUMNS:
            formats[col] = INTEGER_FORMAT
        else:
            formats[col] = None
    return formats


def _cell(value):
    """A value Excel can hold: NaN/inf and missing become empty cells."""
    if value is None or value is pd.NA or value is pd.NaT:
        return None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return str(value)


def _shown_text(value, fmt):
    """The text a cell shows with number format `fmt` (None: general)."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float) and fmt and fmt.startswith("0."):
        return f"{value:.{len(fmt) - 2}f}"
    if isinstance(value, float) and fmt == INTEGER_FORMAT:
        return f"{value:.0f}"
    return str(value)


def _sheet_columns(frame, objective):
    """The "ranking" sheet's columns (key ones first) and the "intervals" sheet's.

    Key columns: ``rank, setup, LF, RF, LR, RR, score, score_<group>,
    feasible, verdict, verdict_baseline``, the difference intervals
    (``diff_best_lo/_hi``, ``diff_baseline_lo/_hi``), the objective's weighted metrics; then the other metrics (file
    order), then the further columns, long text last (``unresolved``,
    ``violations``: they wrap in a narrow column at the right edge). The
    intervals go to their own sheet, in the metrics' order.
    """
    cols = list(frame.columns)
    intervals = [c for c in cols if metric_of_column(c) not in (None, c)]
    key = [c for c in ("rank", "setup", *CORNERS) if c in cols]
    key += [c for c in cols if c[:3] in {f"{k}_" for k in CORNERS}]  # adjusters: LF_ls
    key += [c for c in ("score",) if c in cols]
    key += [c for c in cols if str(c).startswith("score_")]
    key += [c for c in ("feasible", "verdict", "verdict_baseline") if c in cols]
    key += [c for c in cols if str(c).startswith(("diff_best_", "diff_baseline_"))]
    if objective is not None:
        key += [m for m, w in objective.weights.items() if w > 0 and m in cols]
    metrics = [c for c in cols if c in METRIC_QUANTITY and c not in key]
    last = [c for c in _TEXT_LAST if c in cols]
    main = key + metrics + [c for c in cols if c not in key and c not in metrics
                            and c not in intervals and c not in last] + last
    order = [m for m in main if m in METRIC_QUANTITY]
    order += [m for m in dict.fromkeys(metric_of_column(c) for c in intervals) if m not in order]
    ordered = [c for m in order for c in (f"{m}_lo", f"{m}_hi") if c in intervals]
    return main, ordered


_TEXT_LAST = ("unresolved", "violations")
_RULE = Side(style="thin", color="A6A6A6")
_WRAP_HEAD = Alignment(wrap_text=True, horizontal="center", vertical="bottom")
_FONT = "Calibri"
#: Booleans shown as yes/no (LibreOffice; Excel shows TRUE/FALSE whatever the format).
YES_NO_FORMAT = '"yes";"yes";"no"'


def _write_table_sheet(ws, frame, cols, formats, headers, infeasible, *, group_headers=None):
    """Write `frame[cols]` under a one- or two-row header; return the last row.

    `group_headers` (optional): ``{column: label}``, a first header row with
    the label merged over each run of consecutive columns sharing it; columns
    without one get their header merged over both rows. Widths fit the values
    and the wrapped headers; text wider than :data:`TEXT_WIDTH` wraps in a
    smaller font; infeasible rows are greyed.
    """
    head_font = Font(name=_FONT, size=HEADER_PT, bold=True)
    fonts = {(size, grey): Font(name=_FONT, size=size, color=_GREY_FONT if grey else None)
             for size in (DATA_PT, NOTE_PT) for grey in (False, True)}
    grey_fill = PatternFill("solid", fgColor=_GREY_FILL)
    n_head = 2 if group_headers else 1
    columns = [frame[c].tolist() for c in cols]
    widths, head_lines, long_text = [], [], []
    for j, col in enumerate(cols):
        shown = max((text_width(_shown_text(_cell(v), formats[col]), size=DATA_PT)
                     for v in columns[j]), default=0)
        long_text.append(shown > TEXT_WIDTH)
        data = TEXT_WIDTH if long_text[-1] else shown
        w, lines = fit_column_width(headers[j], data, size=HEADER_PT)
        widths.append(w + _PAD_W)
        head_lines.append(lines)
    for j, (col, head) in enumerate(zip(cols, headers), start=1):
        if group_headers and col not in group_headers:
            ws.cell(row=1, column=j, value=head)
            ws.merge_cells(start_row=1, start_column=j, end_row=2, end_column=j)
        else:
            ws.cell(row=n_head, column=j, value=head)
    group_lines = 1
    if group_headers:
        j = 0
        while j < len(cols):
            label, k = group_headers.get(cols[j]), j
            while (label is not None and k + 1 < len(cols)
                   and group_headers.get(cols[k + 1]) == label):
                k += 1
            if label is not None:
                ws.cell(row=1, column=j + 1, value=label)
                ws.merge_cells(start_row=1, start_column=j + 1, end_row=1, end_column=k + 1)
                span = sum(widths[j:k + 1]) - _PAD_W
                group_lines = max(group_lines, len(wrap_lines(label, span, size=HEADER_PT,
                                                               bold=True)))
            j = k + 1
    # a group's first column gets a heavier left rule, so groups read apart
    starts = {j for j, c in enumerate(cols) if group_headers and group_headers.get(c)
              and (j == 0 or group_headers.get(cols[j - 1]) != group_headers.get(c))}
    heavy = Side(style="medium", color="595959")

    def boxed(j, bottom=None):
        left = heavy if j in starts else _RULE
        return Border(left=left, right=_RULE, top=_RULE, bottom=bottom or _RULE)

    for r in range(1, n_head + 1):
        for j in range(1, len(cols) + 1):
            cell = ws.cell(row=r, column=j)
            cell.font = head_font
            cell.alignment = _WRAP_HEAD
            cell.border = boxed(j - 1, Side(style="medium") if r == n_head else None)
    line = _LINE_PT["header"]
    if group_headers:
        ws.row_dimensions[1].height = line * group_lines + 3
        ws.row_dimensions[2].height = line * max(
            [n for n, c in zip(head_lines, cols) if c in group_headers] or [1]) + 3
    else:
        ws.row_dimensions[1].height = line * max(head_lines) + 3
    wrapped = Alignment(wrap_text=True, vertical="top")
    top = Alignment(vertical="top")
    data_borders = [boxed(j) for j in range(len(cols))]
    for r in range(len(frame)):
        row = [_cell(col[r]) for col in columns]
        ws.append(row)
        excel_row = n_head + 1 + r
        height = _LINE_PT["data"]
        for j, (value, col) in enumerate(zip(row, cols), start=1):
            cell = ws.cell(row=excel_row, column=j)
            cell.border = data_borders[j - 1]
            size = NOTE_PT if long_text[j - 1] else DATA_PT
            cell.font = fonts[size, bool(infeasible[r])]
            if infeasible[r]:
                cell.fill = grey_fill
            if formats[col]:
                cell.number_format = formats[col]
            elif isinstance(value, bool):
                cell.number_format = YES_NO_FORMAT
            cell.alignment = top
            if long_text[j - 1] and isinstance(value, str) and value:
                cell.alignment = wrapped
                n = len(wrap_lines(value, widths[j - 1] - _PAD_W, size=NOTE_PT))
                height = max(height, _LINE_PT["note"] * n + 2)
        ws.row_dimensions[excel_row].height = height
    for j, w in enumerate(widths, start=1):
        ws.column_dimensions[get_column_letter(j)].width = round(min(w, MAX_COLUMN_WIDTH), 2)
    return n_head + len(frame)


def _group_starts(cols):
    """Columns (1-based) that start a metric family (tire force, ride height, ...) or end
    one: where a printed page across may break."""
    family = [m.rsplit("_", 1)[0] if (m := metric_of_column(c)) is not None else None
              for c in cols]
    return [j + 1 for j in range(1, len(cols)) if family[j] != family[j - 1]]


def _workbook_bytes(frame, *, units, objective, baseline, infeasible, summary=None,
                    sections=None):
    wb = Workbook()
    ws = wb.active
    ws.title = "ranking"
    formats = _number_formats(frame)
    main, interval_cols = _sheet_columns(frame, objective)
    last_row = _write_table_sheet(ws, frame, main, formats, [_header(c, units) for c in main],
                                  infeasible)
    last_col = get_column_letter(len(main))
    setup_col = main.index("setup") + 1
    ws.freeze_panes = ws.cell(row=2, column=setup_col + 1).coordinate
    ws.auto_filter.ref = f"A1:{last_col}{last_row}"
    what = f"shockplan ranking ({units})"
    if objective is not None:
        what += f", objective '{objective.name}'"
    # too wide for one page at a readable size: across pages, rank and setup on each, the
    # key columns (scores, weighted metrics) on the first, a metric family per page break
    print_setup(ws, units=units, area=f"A1:{last_col}{last_row}", title_rows="1:1",
                title_cols=f"A:{get_column_letter(setup_col)}", group_starts=_group_starts(main),
                footer=what + "; rows sorted by rank, infeasible ones greyed")

    if interval_cols:
        iv = wb.create_sheet("intervals")
        cols = [c for c in ("rank", "setup") if c in frame.columns] + interval_cols
        heads = [column_label(c) if metric_of_column(c) is None else c[-2:] for c in cols]
        groups = {c: f"{column_label(metric_of_column(c))} "
                     f"[{_metric_unit(metric_of_column(c), units)}]"
                  for c in interval_cols}
        last = _write_table_sheet(iv, frame, cols, formats, heads, infeasible,
                                  group_headers=groups)
        iv.freeze_panes = iv.cell(row=3, column=cols.index("setup") + 2).coordinate
        letter = get_column_letter(len(cols))
        print_setup(iv, units=units, area=f"A1:{letter}{last}", title_rows="1:2",
                    title_cols=f"A:{get_column_letter(cols.index('setup') + 1)}",
                    group_starts=_group_starts(cols),
                    footer=f"{what}: interval of each prediction (lo, hi)")

    if sections is not None:
        sec = wb.create_sheet("sections")
        heads = [_section_header(c) for c in sections.columns]
        last = write_table(sec, sections, headers=heads, freeze_cols=2,
                           formats={c: SCORE_FORMAT for c in sections.columns
                                    if str(c).endswith("score")})
        print_setup(sec, units=units, area=f"A1:{get_column_letter(sections.shape[1])}{last}",
                    title_rows="1:1", title_cols="A:B",
                    footer=f"{what}: the whole drive's and each section's score (its rank)")
    if summary is not None:
        write_summary_sheet(wb, units=units, footer=f"{what}: summary", **summary)

    bold = Font(name=_FONT, bold=True)
    about = wb.create_sheet("about")
    rows = [("shockplan ranking", None),
            ("units", units),
            ("setups", len(frame)),
            ("feasible setups", int(len(frame) - np.sum(infeasible))),
            ("scores", "lower is better; the baseline scores the sum of the weights"),
            ("rows", "sorted by rank; greyed rows are infeasible (see 'violations')"),
            ("sheets", "ranking: key columns first; intervals: the predictions' intervals"
             if interval_cols else "ranking: key columns first"),
            (None, None)]
    if objective is not None:
        rows += [("objective", objective.name)]
        if objective.source:
            rows += [("objective file", objective.source)]
        rows += [("baseline", baseline if baseline is not None else "(first setup scored)"),
                 (None, None)]
    for row in rows:
        about.append(list(row))
    about["A1"].font = Font(name=_FONT, bold=True, size=12)
    if objective is not None:
        group_of = {m: g for g, ms in objective.groups.items() for m in ms}
        about.append(["weight", "metric", "group"])
        for cell in about[about.max_row]:
            cell.font = bold
        for metric, w in objective.weights.items():
            about.append([w, metric, group_of.get(metric, "")])
        if objective.limits:
            about.append([])
            about.append(["limit", "metric", "max_ratio (x baseline)", "max [SI]",
                          f"max [{units}]"])
            for cell in about[about.max_row]:
                cell.font = bold
            for metric, spec in objective.limits.items():
                mx = spec.get("max")
                q = METRIC_QUANTITY[metric]
                about.append(["", metric, spec.get("max_ratio"),
                              None if mx is None else f"{mx:.6g} {UNIT_LABELS['SI'][q]}",
                              None if mx is None else
                              f"{float(from_si(mx, q, units)):.6g} {UNIT_LABELS[units][q]}"]
                             + ([f"min {spec['min']:.6g}"] if "min" in spec else []))
        about.append([])
    metric_cols = [c for c in frame.columns if c in METRIC_QUANTITY]
    if metric_cols:
        about.append(["metric", "unit", "column (ranking.csv)"])
        for cell in about[about.max_row]:
            cell.font = bold
        for m in metric_cols:
            about.append([column_label(m), _metric_unit(m, units), m])
    about.column_dimensions["A"].width = 24
    about.column_dimensions["B"].width = 30
    for letter in "CDE":
        about.column_dimensions[letter].width = 24
    print_setup(about, units=units, area=f"A1:E{about.max_row}",
                footer="shockplan ranking: about")
    buf = io.BytesIO()
    wb.save(buf)
    return buf.getvalue()


# ----------------------------------------------------------------------------------------------
# plots
# ----------------------------------------------------------------------------------------------

def _new_figure(size):
    from matplotlib.figure import Figure

    return Figure(figsize=size, layout="constrained")


def _save_png(fig, path, *, overwrite, dpi=110):
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata=png_metadata(fig))
    atomic_write_bytes(path, buf.getvalue(), overwrite=overwrite)


def _boxes_hit(box, boxes):
    """Whether `box` (x0, y0, x1, y1) overlaps any row of `boxes`, shape (n, 4)."""
    if len(boxes) == 0:
        return False
    return bool(np.any((boxes[:, 0] < box[2]) & (box[0] < boxes[:, 2])
                       & (boxes[:, 1] < box[3]) & (box[1] < boxes[:, 3])))


def _points_hit(points, boxes):
    """Whether any of `points`, shape (n, 2), lies inside a row of `boxes`, shape (m, 4)."""
    if len(points) == 0 or len(boxes) == 0:
        return False
    x, y = points[:, :1], points[:, 1:]
    return bool(np.any((boxes[:, 0] < x) & (x < boxes[:, 2])
                       & (boxes[:, 1] < y) & (y < boxes[:, 3])))


def _label_candidates(anchor, size, blocked, bounds, *, reach, step, pad):
    """Boxes one label may take, nearest its point first (geometry only).

    Returns
    -------
    ndarray, shape (n, 4)
        x0, y0, x1, y1 [pt] of the boxes of size `size` whose corner lies on a grid of
        `step` around `anchor`, at most `reach` from it, inside `bounds` and clear of
        `blocked` by `pad`; ordered by the distance from the point to the box (to
        0.5 pt), then by the direction (up-right first).
    """
    px, py = anchor
    w, h = size
    gx = np.arange(-w - reach, reach + step / 2, step)
    gy = np.arange(-h - reach, reach + step / 2, step)
    x0 = px + np.tile(gx, gy.size)
    y0 = py + np.repeat(gy, gx.size)
    boxes = np.column_stack([x0, y0, x0 + w, y0 + h])
    grown = boxes + np.array([-pad, -pad, pad, pad])
    x_lo, y_lo, x_hi, y_hi = bounds
    near = np.column_stack([np.clip(px, boxes[:, 0], boxes[:, 2]),
                            np.clip(py, boxes[:, 1], boxes[:, 3])])
    dist = np.hypot(near[:, 0] - px, near[:, 1] - py)
    keep = ((grown[:, 0] >= x_lo) & (grown[:, 1] >= y_lo) & (grown[:, 2] <= x_hi)
            & (grown[:, 3] <= y_hi) & (dist <= reach))
    boxes, grown, dist = boxes[keep], grown[keep], dist[keep]
    far = w + reach + pad, h + reach + pad
    local = blocked[(blocked[:, 2] > px - far[0]) & (blocked[:, 0] < px + far[0])
                    & (blocked[:, 3] > py - far[1]) & (blocked[:, 1] < py + far[1])]
    hit = np.zeros(len(boxes), dtype=bool)
    for b in local:  # one obstacle at a time: memory stays (n,)
        hit |= ((grown[:, 0] < b[2]) & (b[0] < grown[:, 2]) & (grown[:, 1] < b[3])
                & (b[1] < grown[:, 3]))
    boxes, dist = boxes[~hit], dist[~hit]
    angle = np.arctan2((boxes[:, 1] + boxes[:, 3]) / 2 - py, (boxes[:, 0] + boxes[:, 2]) / 2 - px)
    turn = np.abs(np.angle(np.exp(1j * (angle - np.pi / 4))))
    return boxes[np.lexsort((turn, np.round(2.0 * dist)))]


def _place_labels(anchors, sizes, markers, lines, bounds, *, reach=_LABEL_REACH_PT,
                  step=_LABEL_STEP_PT, pad=_LABEL_PAD_PT, leader_pt=_LEADER_PT):
    """Label layout: the nearest free place beside each point (geometry only).

    Each label takes the nearest box (:func:`_label_candidates`) that touches no
    marker, no line, no label and no leader line placed before; a label farther
    than `leader_pt` from its point gets a leader line, straight from the point to
    the nearest point of the label, which may cross no marker (but its own) and no
    label. Labels choose in order; when some find no place, the layout is tried
    again with those first, and the layout with the fewest labels left out (then the
    shortest total distance) is kept.

    Parameters
    ----------
    anchors : array_like, shape (n_labels, 2)
        The labelled points, display coordinates [pt].
    sizes : array_like, shape (n_labels, 2)
        Width and height of each label's text box [pt].
    markers : array_like, shape (n_markers, 4)
        Boxes of the markers: x0, y0, x1, y1 [pt].
    lines : array_like, shape (n_lines, 4)
        Boxes of line segments no label may touch (leader lines may cross them) [pt].
    bounds : sequence of 4 float
        The box every label stays inside (the axes): x0, y0, x1, y1 [pt].
    reach, step, pad, leader_pt : float
        The farthest a label may sit from its point, the grid of its corner, the gap
        kept to everything else, and the distance beyond which a leader line is drawn
        [pt].

    Returns
    -------
    list
        Per label: ``(dx, dy, relpos)``, the offset of the label's lower-left corner
        from its point [pt] and the point of the label its leader line ends at (a
        fraction of its width and height; None: no leader line), or None where no
        place is free. Deterministic: the same inputs give the same layout.
    """
    anchors = np.asarray(anchors, dtype=float).reshape(-1, 2)
    sizes = np.asarray(sizes, dtype=float).reshape(-1, 2)
    markers = np.asarray(markers, dtype=float).reshape(-1, 4)
    blocked = np.vstack([markers, np.asarray(lines, dtype=float).reshape(-1, 4)])
    bounds = tuple(float(b) for b in bounds)
    grow = np.array([-pad, -pad, pad, pad])
    cands = [_label_candidates(a, s, blocked, bounds, reach=reach, step=step, pad=pad)
             for a, s in zip(anchors, sizes)]
    own = [(markers[:, 0] <= px) & (px <= markers[:, 2]) & (markers[:, 1] <= py)
           & (py <= markers[:, 3]) for px, py in anchors]

    def layout(order):
        placed = np.empty((0, 4))  # label boxes placed so far
        leaders = np.empty((0, 2))  # points along the leader lines drawn so far
        out = [None] * len(anchors)
        for i in order:
            px, py = anchors[i]
            boxes = cands[i]
            grown = boxes + grow
            free = np.ones(len(boxes), dtype=bool)
            for b in placed:
                free &= ~((grown[:, 0] < b[2]) & (b[0] < grown[:, 2]) & (grown[:, 1] < b[3])
                          & (b[1] < grown[:, 3]))
            for x, y in leaders:
                free &= ~((grown[:, 0] < x) & (x < grown[:, 2]) & (grown[:, 1] < y)
                          & (y < grown[:, 3]))
            for box in boxes[free][:_MAX_LEADER_TRIES]:
                nx, ny = np.clip(px, box[0], box[2]), np.clip(py, box[1], box[3])
                d = math.hypot(nx - px, ny - py)
                line = np.empty((0, 2))
                if d > leader_pt:  # the leader line: a point every 1 pt
                    s = np.linspace(0.0, 1.0, math.ceil(d) + 1)[:, None]
                    line = np.array([px, py]) + s * np.array([nx - px, ny - py])
                    if (_points_hit(line, markers[~own[i]])
                            or _points_hit(line, placed + grow)):
                        continue
                relpos = None if d <= leader_pt else (
                    (nx - box[0]) / (box[2] - box[0]), (ny - box[1]) / (box[3] - box[1]))
                out[i] = (box[0] - px, box[1] - py, relpos, d)
                placed = np.vstack([placed, box])
                leaders = np.vstack([leaders, line])
                break
        return out

    order = list(range(len(anchors)))
    best = None
    for _ in range(max(len(order), 1)):
        out = layout(order)
        missed = [i for i in order if out[i] is None]
        key = (len(missed), sum(o[3] for o in out if o is not None))
        if best is None or key < best[0]:
            best = (key, out)
        retry = missed + [i for i in order if i not in missed]
        if not missed or retry == order:
            break
        order = retry
    return [None if o is None else o[:3] for o in best[1]]


def _spread_points(x, y, candidates, chosen, n):
    """Up to `n` of `candidates` (positions), each the farthest from those chosen so far
    (`chosen` first; coordinates scaled by their span): the extremes and the isolated
    points first, one of a cluster at a time. Deterministic (ties: the first candidate)."""
    pts = np.column_stack([x, y]).astype(float)
    ok = np.isfinite(pts).all(axis=1)
    span = np.ptp(pts[ok], axis=0) if ok.any() else np.ones(2)
    pts = pts / np.where(span > 0, span, 1.0)
    picked, taken = [], list(chosen)
    rest = [int(k) for k in candidates if k not in set(chosen)]
    while rest and len(picked) < n:
        if taken:
            d = np.min(np.linalg.norm(pts[rest][:, None, :] - pts[taken][None, :, :], axis=2),
                       axis=1)
        else:
            d = -np.asarray(rest, float)  # none chosen yet: the first candidate
        k = rest.pop(int(np.argmax(d)))
        picked.append(k)
        taken.append(k)
    return picked


def _score_label(column, objective):
    """An axis label in words for a group's score column (``score_grip``): the group, the
    metric families it weighs (from the objective), what the score is, which way is better."""
    group = column[len("score_"):]
    families = []
    if objective is not None and group in objective.groups:
        for m in objective.groups[group]:
            words = column_label(m).split()
            fam = " ".join(words[:-1]) if words[-1] in (*CORNERS, "front", "rear") else \
                " ".join(words)
            if fam not in families:
                families.append(fam)
    what = f": {', '.join(families)} / baseline" if families else ""
    return f"{group} score [-]{what}"


def _pareto_figure(table, baseline, objective=None):
    """score_grip vs score_platform: all setups, the Pareto front, the best labelled.

    The :data:`N_PARETO_LABELS` best setups and the setups on the Pareto front (up to
    :data:`MAX_PARETO_LABELS` labels in all, spread along the front) are labelled by name (``#<rank>``
    and a key under the plot when a name is longer than :data:`SHORT_LABEL_CHARS`) at the
    nearest
    place beside their point that touches no marker, no line of the front and no
    other label (:func:`_place_labels`, text measured with the Agg renderer), with a
    leader line when the label sits away from its point; a label with no such place
    goes to a column in the right margin, under the legend, with a leader line. The
    layout is fixed (no layout engine), so the same table draws the same bytes.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.text import Text

    x, y = "score_grip", "score_platform"
    xv = table[x].to_numpy(dtype=float)
    yv = table[y].to_numpy(dtype=float)
    feasible = (table["feasible"].to_numpy(dtype=bool) if "feasible" in table.columns
                else np.ones(len(table), dtype=bool))
    front = pareto_front(table, x, y)
    # the labelled setups: the best, then the front's others, the best first
    order = _best_order(table)
    finite = np.isfinite(xv) & np.isfinite(yv)
    best = [k for k in order[:N_PARETO_LABELS] if finite[k]]
    best += _spread_points(xv, yv, np.flatnonzero(front & finite), best,
                           MAX_PARETO_LABELS - len(best))
    position = np.empty(len(table))
    position[order] = np.arange(1, len(table) + 1)
    ranks = (table["rank"].to_numpy(dtype=float)[best] if "rank" in table.columns
             else position[best])
    names, key = short_labels([str(table.index[k]) for k in best], ranks)
    key = [key[j] for j in np.argsort(ranks, kind="stable")] if key else key
    key_in = 0.135 * (len(key) + 1) + 0.15 if key else 0.0  # the key's lines under the axes
    width_in, height_in = _PARETO_SIZE_IN[0], _PARETO_SIZE_IN[1] + key_in
    m = dict(_PARETO_MARGIN_IN, bottom=_PARETO_MARGIN_IN["bottom"] + key_in)
    fig = Figure(figsize=(width_in, height_in))
    FigureCanvasAgg(fig)
    ax = fig.add_axes((m["left"] / width_in, m["bottom"] / height_in,
                       1.0 - (m["left"] + m["right"]) / width_in,
                       1.0 - (m["bottom"] + m["top"]) / height_in))
    ax.scatter(xv[feasible & ~front], yv[feasible & ~front], s=18, color="C0", alpha=0.6,
               label="feasible")
    if (~feasible).any():
        ax.scatter(xv[~feasible], yv[~feasible], s=18, marker="x", color="0.6",
                   label="infeasible")
    steps = np.empty((0, 2))
    if front.any():
        order = np.argsort(xv[front], kind="stable")
        fx, fy = xv[front][order], yv[front][order]
        ax.step(fx, fy, where="post", color="C3", lw=1.2, alpha=0.8)
        ax.scatter(fx, fy, s=40, color="C3", zorder=3, label="Pareto front")
        # the step line's corners: (x_i, y_i) -> (x_i+1, y_i) -> (x_i+1, y_i+1)
        steps = np.column_stack([np.repeat(fx, 2)[1:], np.repeat(fy, 2)[:-1]])
    if baseline is not None and baseline in table.index:
        b = table.index.get_loc(baseline)
        ax.scatter([xv[b]], [yv[b]], s=120, marker="*", color="k", zorder=4,
                   label=f"baseline ({baseline})")
    ax.set_xlabel(_score_label(x, objective))
    ax.set_ylabel(_score_label(y, objective))
    ax.set_title(f"Grip vs platform (weighted RMS ratios, lower is better): "
                 f"{int(front.sum())} setups on the Pareto front", fontsize=10)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    ax.set_xlim(ax.get_xlim())  # freeze the limits: the labels are placed in display space
    ax.set_ylim(ax.get_ylim())

    pt = 72.0 / fig.dpi  # display pixels -> points

    def to_pt(xy):
        return ax.transData.transform(np.asarray(xy, dtype=float).reshape(-1, 2)) * pt

    markers = [np.empty((0, 4))]
    for coll in ax.collections:  # markers: squares of the marker's size
        offs = np.asarray(coll.get_offsets(), dtype=float).reshape(-1, 2)
        ok = np.isfinite(offs).all(axis=1)
        half = np.sqrt(np.broadcast_to(coll.get_sizes(), (len(offs),)))[ok] / 2.0
        c = to_pt(offs[ok])
        markers.append(np.column_stack([c - half[:, None], c + half[:, None]]))
    lines = np.empty((0, 4))
    if len(steps) > 1:  # the front's segments (horizontal or vertical): boxes of the line
        c = to_pt(steps)
        half_lw = 0.6
        lines = np.column_stack([np.minimum(c[:-1], c[1:]) - half_lw,
                                 np.maximum(c[:-1], c[1:]) + half_lw])
    bounds = np.asarray(ax.bbox.extents) * pt

    if key:
        label_key_text(fig, key, y_in=0.05)
    renderer = fig.canvas.get_renderer()
    sizes = []
    for name in names:
        ext = Text(0.0, 0.0, name, fontsize=7, figure=fig).get_window_extent(renderer)
        sizes.append((ext.width * pt, ext.height * pt))
    anchors = to_pt(np.column_stack([xv[best], yv[best]])) if best else np.empty((0, 2))
    places = _place_labels(anchors, sizes, np.vstack(markers), lines, bounds)
    leader = {"arrowstyle": "-", "color": "0.35", "lw": 0.6, "shrinkA": 0.0, "shrinkB": 3.5}
    for k, name, place in zip(best, names, places):
        if place is None:
            continue
        dx, dy, relpos = place
        arrow = None if relpos is None else dict(leader, relpos=relpos)
        ax.annotate(name, (xv[k], yv[k]), xytext=(dx, dy), textcoords="offset points",
                    ha="left", va="bottom", fontsize=7, arrowprops=arrow)
    # labels with no free place: a column in the right margin, bottom up, ordered by height
    rest = sorted((float(a[1]), j, name) for j, (name, a, place)
                  in enumerate(zip(names, anchors, places)) if place is None)
    line_in = 0.18
    for row, (_, j, name) in enumerate(rest):
        y_frac = (row + 0.5) * line_in / (height_in - m["bottom"] - m["top"])
        ax.annotate(name, (xv[best[j]], yv[best[j]]), xytext=(1.04, y_frac),
                    textcoords="axes fraction", ha="left", va="center", fontsize=7,
                    annotation_clip=False, arrowprops=dict(leader, relpos=(0.0, 0.5)))
    return fig


def _best_order(table):
    """Row positions, best first: by rank, else by score, else table order."""
    n = len(table)
    for col in ("rank", "score"):
        if col in table.columns:
            v = table[col].to_numpy(dtype=float, na_value=np.nan)
            return np.lexsort((np.arange(n), np.where(np.isnan(v), np.inf, v)))
    return np.arange(n)


def _key_metrics(table, objective):
    if objective is not None:
        weighted = [m for m, w in objective.weights.items() if w > 0 and m in table.columns]
        if len(weighted) > MAX_KEY_METRICS:
            w = np.array([objective.weights[m] for m in weighted])
            keep = set(np.argsort(-w, kind="stable")[:MAX_KEY_METRICS])
            weighted = [m for k, m in enumerate(weighted) if k in keep]
        if weighted:
            return weighted
    chosen = [m for m in DEFAULT_KEY_METRICS if m in table.columns]
    return chosen or [c for c in ranking_columns(table) if c in METRIC_QUANTITY][:MAX_KEY_METRICS]


def _normalizing_setup(table, objective, baseline):
    """The setup of `table` that ``top_setups.png`` divides the metrics by, or None (the best).

    Not a baseline resolver (:func:`planner.setups.resolve_baseline` reads a command's
    baseline): this finds, in a finished ranking table, the row its scores were normalized
    by: `baseline` if given, else the objective's, else the row scoring exactly the
    objective's total weight.
    """
    if baseline is not None:
        if baseline not in table.index:
            raise PlannerError(f"write_ranking: baseline setup {baseline!r} is not in the table; "
                               "give a setup name of the table or None")
        return baseline
    if objective is None:
        return None
    if objective.baseline is not None:
        return objective.baseline if objective.baseline in table.index else None
    # score_setups normalized by its first setup: the row scoring exactly the total weight
    if "score" not in table.columns:
        return str(table.index[0])
    score = table["score"].to_numpy(dtype=float, na_value=np.nan)
    hit = np.flatnonzero(np.isclose(score, objective.total_weight, rtol=1e-12, atol=0))
    if hit.size == 0:
        return None
    return str(table.index[0]) if 0 in hit else str(table.index[hit[0]])


def short_labels(names, ranks=None, *, max_chars=SHORT_LABEL_CHARS):
    """Plot labels of setups: their names, or ``#<rank>`` and a key when a name is long.

    Parameters
    ----------
    names : sequence of str
    ranks : sequence of int, optional
        Each setup's rank (default: its position, from 1).
    max_chars : int
        Names up to this long are shown as they are.

    Returns
    -------
    labels : list of str
    key : list of str
        ``"#<rank>  <name>"`` per setup when the labels are short ones, else empty.

    Examples
    --------
    >>> short_labels(["L28/L28/DF/DF", "B20/B20/B20/B20"])
    (['L28/L28/DF/DF', 'B20/B20/B20/B20'], [])
    >>> short_labels(["TTX@ls=6,hs=2/TTX@ls=6,hs=2/TTX@ls=4,hs=2/TTX@ls=4,hs=2"], [3])[0]
    ['#3']
    """
    names = [str(n) for n in names]
    ranks = list(range(1, len(names) + 1)) if ranks is None else [
        int(r) if np.isfinite(r) else k + 1 for k, r in enumerate(np.asarray(ranks, float))]
    if not names or max(len(n) for n in names) <= max_chars:
        return names, []
    labels = [f"#{r}" for r in ranks]
    width = max(len(lab) for lab in labels)
    return labels, [f"{lab:<{width}}  {_compact_name(n)}" for lab, n in zip(labels, names)]


def _compact_name(name):
    """A setup's name ``LF/RF/LR/RR`` said once per axle where the sides match (``front A,
    rear B``; ``all A``); other names as they are."""
    parts = str(name).split("/")
    if len(parts) != 4:
        return str(name)
    if len(set(parts)) == 1:
        return f"all {parts[0]}"
    if parts[0] == parts[1] and parts[2] == parts[3]:
        return f"front {parts[0]}, rear {parts[2]}"
    return str(name)


def label_key_text(fig, key, *, y_in=0.1, size=7, meaning="the rank in ranking.csv"):
    """Draw the key of short labels (:func:`short_labels`) at the bottom left of a figure.

    Parameters
    ----------
    fig : matplotlib.figure.Figure or SubFigure
    key : list of str
        The key's lines (none: nothing drawn).
    y_in : float
        The key's bottom above the figure's [in].
    size : float
        Font size [pt].
    meaning : str
        What ``#n`` is, the key's first line.
    """
    if key:
        height_in = fig.figure.get_figheight() * fig.bbox.height / fig.figure.bbox.height
        fig.text(0.01, y_in / height_in, "\n".join([f"#: {meaning}"] + list(key)),
                 ha="left", va="bottom", fontsize=size, family="monospace")


def _top_figure(table, metrics, reference, top):
    """Key metrics of the best setups as their change from a reference row [%], with the
    intervals; the axis zoomed to the values (the reference at 0), names in words, long
    setup names shortened to ``#<rank>`` with a key under the plot."""
    order = _best_order(table)[:top]
    sub = table.iloc[order]
    ref_name = reference if reference is not None else str(sub.index[0])
    ref = table.loc[ref_name]
    n_s, n_m = len(sub), len(metrics)
    ranks = sub["rank"].to_numpy(dtype=float) if "rank" in sub.columns else None
    labels, key = short_labels(sub.index, ranks)
    if "feasible" in sub.columns:
        labels = [s if f else f"{s}\n(infeasible)" for s, f in
                  zip(labels, sub["feasible"].to_numpy(dtype=bool))]
    key_in = 0.135 * (len(key) + 1) + 0.1 if key else 0.0
    outer = _new_figure((max(6.0, 0.9 * n_s + 2.5), 5.2 + key_in))
    if key:  # the plot above, the key of the short labels under it
        fig, low = outer.subfigures(2, 1, height_ratios=(5.2, key_in))
        label_key_text(low, key, y_in=0.02)
    else:
        fig = outer
    ax = fig.add_subplot()
    x = np.arange(n_s)
    width = 0.8 / n_m
    widest = []  # each metric's widest interval [% of the reference]
    for k, m in enumerate(metrics):
        base = float(ref[m])
        scale = 100.0 / base if np.isfinite(base) and base != 0 else np.nan
        v = sub[m].to_numpy(dtype=float, na_value=np.nan) * scale - 100.0
        yerr = None
        if f"{m}_lo" in sub.columns and f"{m}_hi" in sub.columns:
            lo = sub[f"{m}_lo"].to_numpy(dtype=float, na_value=np.nan) * scale - 100.0
            hi = sub[f"{m}_hi"].to_numpy(dtype=float, na_value=np.nan) * scale - 100.0
            yerr = np.nan_to_num(np.vstack([np.clip(v - lo, 0, None), np.clip(hi - v, 0, None)]))
            widest.append(float(np.max(yerr.sum(axis=0), initial=0.0)))
        ax.errorbar(x - 0.4 + (k + 0.5) * width, v, yerr=yerr, fmt="o", ms=5, capsize=3,
                    lw=1.0, color=f"C{k % 10}", label=column_label(m))
    ax.axhline(0.0, color="k", lw=0.8, ls="--")
    for edge in x[:-1] + 0.5:  # the setups apart
        ax.axvline(edge, color="0.85", lw=0.6)
    ax.set_xlim(-0.5, n_s - 0.5)
    ax.set_xticks(x, labels, rotation=0 if key else 30, ha="center" if key else "right",
                  fontsize=8)
    what = "baseline" if reference is not None else "best setup"
    ax.set_ylabel(f"change from the {what} ({ref_name}) [%]")
    lo_y, hi_y = ax.get_ylim()
    whiskers = "whiskers: the prediction's interval"
    if widest and max(widest) < 0.02 * (hi_y - lo_y):  # hidden by the markers: say how wide
        whiskers = f"the intervals, {max(widest):.2g} % wide at most, hide behind the points"
    fig.suptitle(f"Top {n_s} setups: key metrics against the {what} (lower is lower RMS; "
                 f"{whiskers})")
    ax.grid(True, axis="y", lw=0.3, alpha=0.5)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", fontsize=8,
               ncol=min(n_m, 6), frameon=False)
    return outer


# ----------------------------------------------------------------------------------------------
# the summary sheet and the sections (compute the rows; planner.report.summary lays them out)
# ----------------------------------------------------------------------------------------------

def _section_header(col):
    """A sections table's header: ``kerb_score`` -> ``kerb score``; ``score`` -> ``whole
    drive score``."""
    if col in ("score", "rank"):
        return f"whole drive {col}"
    for end in ("_score", "_rank"):
        if str(col).endswith(end):
            return f"{col[:-len(end)]} {end[1:]}"
    return column_label(col)


def _section_frame(sections):
    """The sections table as written: ``rank, setup``, the shocks, the scores, ``wins``."""
    t = _check_table(sections, "write_ranking: sections", corners=False)
    frame = t.reset_index()
    first = [c for c in ("rank", "setup") if c in frame.columns]
    return frame[first + [c for c in frame.columns if c not in first]]


def _summary_parts(ranked, units, objective, ref, key_metrics, *, sections, run, histograms):
    """The summary sheet's parts (:func:`planner.report.summary.summary_parts`)."""
    best = str(ranked.index[0])
    base = ref if ref is not None else best
    notes = [f"best of {len(ranked)} setups simulated in the time domain: '{best}'"
             + (f"; baseline '{base}'" if base != best else " (also the baseline)")
             + "; scores are ratios to the baseline's metrics, lower is better"]
    if sections is not None and "wins" in sections.columns:
        won = [(s, str(n)) for n, v in sections["wins"].items() for s in str(v or "").split()
               if str(n) != best]
        notes.append("sections won by another setup than the whole drive's best: "
                     + ("; ".join(f"{s}: '{w}'" for s, w in won) if won else "none"))
    used = list((run or {}).items())
    if objective is not None and not any(k == "objective" for k, _ in used):
        used.append(("objective", objective.name + (f" ({objective.source})"
                                                     if objective.source else "")))
    used.append(("units", units))
    return summary_parts(ranked, best=best, baseline=base, metrics=key_metrics, units=units,
                         title="shockplan ranking: summary", notes=notes, used=used,
                         histograms=histograms)


# ----------------------------------------------------------------------------------------------
# the report folder
# ----------------------------------------------------------------------------------------------

def write_ranking(table, out_dir, *, units="SI", objective=None, baseline=None, overwrite=False,
                  top=10, sections=None, run=None, histograms=None):
    """Write the ranking of setups as CSV, Excel workbook and plots.

    Parameters
    ----------
    table : pandas.DataFrame
        Ranking table (SI; see the module docstring), e.g. predictions joined
        with :attr:`planner.objective.Scores.table`.
    out_dir : str or path
        Output folder (created if missing).
    units : {"SI", "imperial"}
        Unit system of the metric values in the files.
    objective : planner.objective.Objective, optional
        Its weights, groups and limits go to the workbook's "about" sheet; its
        weighted metrics are the key metrics of ``top_setups.png``.
    baseline : str, optional
        Setup the metrics of ``top_setups.png`` are normalized by; default the
        objective's baseline (or the setup it was normalized by), else the
        best setup.
    overwrite : bool
        Replace existing files.
    top : int
        Number of best setups in ``top_setups.png``.
    sections : pandas.DataFrame, optional
        The section table (:attr:`planner.section_ranking.SectionRanking.table`): written as
        ``sections.csv`` and the workbook's sheet "sections"; the sections won by another
        setup than the best are named on the summary sheet.
    run : dict of str to object, optional
        What the run used, for the summary sheet (``{"model": ..., "drive": ...,
        "crate": ...}``); the objective's name is added.
    histograms : pandas.DataFrame, optional
        Predicted shock-velocity histograms (columns ``setup, corner, velocity_lo,
        velocity_hi, share`` in `units`): the summary's plot is the best's against the
        baseline's (:func:`planner.report.summary.summary_figure`); without them, the key
        metrics' change.

    Returns
    -------
    dict of str to pathlib.Path
        ``"csv"``: ``ranking.csv``; ``"xlsx"``: ``ranking.xlsx``;
        ``"pareto"``: ``pareto.png`` (only with columns ``score_grip`` and
        ``score_platform``); ``"top_setups"``: ``top_setups.png`` (only with
        metric columns); ``"sections"``: ``sections.csv`` (only with `sections`).

    Raises
    ------
    TypeError
        If `table` is not a DataFrame or `objective` not an Objective.
    ValueError
        If `units` is unknown or `top` is not an integer >= 1.
    PlannerError
        As :func:`write_predictions_csv`; or `baseline` not in the table.
    FileExistsError
        If a file to write exists and `overwrite` is false (checked for every
        file before anything is written).

    Notes
    -----
    ``ranking.csv``: rows sorted by ``rank`` when present, columns ``rank,
    setup, LF, RF, LR, RR``, metrics, further columns. ``ranking.xlsx``, to
    read and to print:

    - sheet "summary", first, on one page (:func:`planner.report.summary.write_summary_sheet`):
      the best setups (and the baseline) with their verdicts against the best and the
      baseline (:func:`planner.report.summary.verdicts`: the ranking's ``verdict``
      columns, tied where the interval of the score difference contains 0; else its
      ``unresolved`` pairs), a line naming the best and the setups tied with it, scores
      and key metrics in
      `units`, the sections' winners, what the run used, and the plot of the best against
      the baseline;
    - sheet "ranking": the key columns first (``rank, setup, LF, RF, LR, RR,
      score, score_<group>, feasible, verdict, verdict_baseline``, the difference
      intervals, the objective's weighted metrics),
      then the other metrics, then the further columns with the long texts
      last (``unresolved``, ``violations``, wrapped); headers are labels
      (:func:`column_label`) with the units of the metrics (``"tire force RMS
      LF [lbf]"``), bold and wrapped; panes frozen below the header and right
      of ``setup``; metric formats with about 4 significant digits (at least
      ``0.000``), ``0.0000`` for scores, ``0`` for ranks, booleans as yes/no;
      fitted widths, an autofilter, infeasible rows greyed;
    - sheet "intervals" (when the table has ``_lo``/``_hi`` columns):
      ``rank, setup`` and each metric's ``lo``, ``hi`` under its label;
    - sheet "about": the units, the objective, the metrics' labels, units and
      CSV columns.

    Every sheet prints landscape, the header repeated on every page, on A4 (SI)
    or US letter (imperial) (:func:`print_setup`): "about" one page wide; the
    wide "ranking" and "intervals" across pages at a scale that keeps their
    text >= 8 pt, ``rank, setup`` repeated on every page and the pages broken
    between metric families, so the first page holds the key columns (the
    summary: shocks, scores, the objective's metrics).
    """
    table = _check_table(table, "write_ranking")
    units = check_units(units, where="write_ranking")
    if objective is not None and not isinstance(objective, Objective):
        raise TypeError(f"write_ranking: objective must be a planner.objective.Objective or "
                        f"None, got {type(objective).__name__}")
    if isinstance(top, bool) or not isinstance(top, (int, np.integer)) or top < 1:
        raise ValueError(f"write_ranking: top must be an integer >= 1, got {top!r}")
    out_dir = Path(out_dir)
    ref = _normalizing_setup(table, objective, baseline)
    key_metrics = _key_metrics(table, objective)
    keys = ["csv", "xlsx"]
    if {"score_grip", "score_platform"} <= set(table.columns):
        keys.append("pareto")
    if key_metrics:
        keys.append("top_setups")
    if sections is not None:
        keys.append("sections")
    paths = {k: out_dir / RANKING_FILES[k] for k in keys}
    for path in paths.values():
        check_can_write(path, overwrite=overwrite)
    out_dir.mkdir(parents=True, exist_ok=True)

    ranked = _sorted_by_rank(table)
    frame = _file_frame(ranked, units, rank_first=True)
    _write_csv(frame, paths["csv"], units=units, overwrite=overwrite)
    infeasible = (~ranked["feasible"].to_numpy(dtype=bool) if "feasible" in ranked.columns
                  else np.zeros(len(ranked), dtype=bool))
    about_base = ref if ref is not None else (objective.baseline if objective else None)
    section_frame = None
    if sections is not None:
        section_frame = _section_frame(sections)
        write_csv(paths["sections"], section_frame, units=units, overwrite=overwrite)
    summary = _summary_parts(ranked, units, objective, ref, key_metrics, sections=sections,
                             run=run, histograms=histograms)
    atomic_write_bytes(paths["xlsx"], _workbook_bytes(
        frame, units=units, objective=objective, baseline=about_base, infeasible=infeasible,
        summary=summary, sections=section_frame), overwrite=overwrite)
    if "pareto" in paths:
        _save_png(_pareto_figure(table, ref, objective), paths["pareto"], overwrite=overwrite)
    if "top_setups" in paths:
        _save_png(_top_figure(table, key_metrics, ref, int(top)), paths["top_setups"],
                  overwrite=overwrite)
    log.info("wrote the ranking of %d setups (%s) to %s: %s", len(table), units, out_dir,
             ", ".join(p.name for p in paths.values()))
    return paths
