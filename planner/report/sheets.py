"""The print layout shared by every workbook the planner writes: column widths that fit
wrapped headers, labels for people, tables and key-value sheets, and the print setup.

Every workbook (``ranking.xlsx``, ``optimize.xlsx``, ``whatif.xlsx``, ``test_plan.xlsx``)
lays out its sheets with these: :func:`column_label` (a column's name for people),
:func:`text_width` (a text's width in Excel units, estimated from Calibri's character
widths), :func:`wrap_lines` and :func:`fit_column_width` (a header wrapped at spaces into at
most :data:`HEADER_MAX_LINES` lines), :func:`write_table` (a table under one bold wrapped
header row) and :func:`write_key_values` (label-value rows, two columns), and
:func:`print_setup`, the one print setup of every sheet.

Printing
--------
Every sheet prints landscape on :data:`PAPER_SIZE` (A4 for SI, US letter for imperial)
with :data:`PRINT_MARGINS_IN`, its header rows repeated on every page, a footer with the
writer's note, the sheet's name and the page number. A sheet whose smallest text prints at
>= :data:`MIN_PRINT_PT` when the table is fit to one page wide is fit to one page wide (any
number of pages tall). A wider one is not shrunk further: it prints across pages at a fixed
scale that keeps its smallest text >= :data:`SPLIT_PRINT_PT`, its key columns
(``title_cols``) repeated on every page, with column breaks where the caller's column groups
start, pages ordered across then down.

The printed size is estimated the way LibreOffice prints (checked by converting the
workbooks to PDF): one Excel width unit prints as the width of a digit of the workbook's
default font at 11 pt, which is 7.0 pt where Calibri (and its metric twin Carlito) is
missing and DejaVu Sans stands in, against 5.6 pt in Calibri and Excel's 5.25 pt (+ 3.75 pt
a column). :data:`WIDTH_UNIT_PT` takes the widest, so the estimate is a floor: the text
prints at least that large everywhere. LibreOffice scales the footer with the sheet, so its
font grows to stay >= :data:`MIN_PRINT_PT` too.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
from openpyxl.styles import Alignment, Border, Font, Side
from openpyxl.utils import column_index_from_string, get_column_letter
from openpyxl.utils.cell import range_boundaries
from openpyxl.worksheet.page import PageMargins
from openpyxl.worksheet.pagebreak import Break
from openpyxl.worksheet.properties import PageSetupProperties

from ident.data.units import check_units

__all__ = [
    "DEFAULT_COLUMN_WIDTH",
    "FOOTER_PT",
    "HEADER_MAX_LINES",
    "MAX_COLUMN_WIDTH",
    "MIN_PRINT_PT",
    "PAPER_IN",
    "PAPER_SIZE",
    "PRINT_MARGINS_IN",
    "SPLIT_PRINT_PT",
    "TABLE_HEADER_PT",
    "TABLE_PT",
    "WIDTH_UNIT_PT",
    "PrintLayout",
    "column_label",
    "column_widths",
    "decimals_format",
    "fit_column_width",
    "fit_width_units",
    "print_setup",
    "printable_size_pt",
    "smallest_font_pt",
    "text_width",
    "wrap_lines",
    "write_key_values",
    "write_table",
]

#: Excel paper codes of the printed workbooks per unit system: ISO A4 for SI files, US
#: letter for imperial ones (the unit system a team writes says where it prints).
PAPER_SIZE = {"SI": 9, "imperial": 1}
#: Paper of each code of :data:`PAPER_SIZE`, portrait: (width, height) [in].
PAPER_IN = {9: (8.27, 11.69), 1: (8.5, 11.0)}
#: Page margins of the printed workbooks [in]: narrow, so one page wide stays readable.
PRINT_MARGINS_IN = {"left": 0.4, "right": 0.4, "top": 0.45, "bottom": 0.55, "header": 0.2,
                    "footer": 0.25}
#: The smallest printed text [pt]: a sheet is never scaled below this for its smallest font.
MIN_PRINT_PT = 7.0
#: The smallest printed text of a sheet that prints across pages [pt] (its smallest font
#: permitting): once split, a sheet is not squeezed for fewer pages.
SPLIT_PRINT_PT = 8.0
#: Printed width of one Excel column-width unit at 100 % [pt]: the widest rendering
#: measured, LibreOffice with DejaVu Sans standing in for a missing Calibri (a digit of
#: DejaVu Sans at 11 pt); Calibri or Carlito print 5.6 pt, Excel 5.25 pt + 3.75 pt a column.
WIDTH_UNIT_PT = 7.0
#: Width of a column the writer did not size [Excel width units] (Excel's and
#: LibreOffice's default).
DEFAULT_COLUMN_WIDTH = 8.43
#: The footer's font at 100 % [pt] (larger where the sheet prints scaled down).
FOOTER_PT = 8.0
#: A header cell wraps to at most this many lines before its column widens.
HEADER_MAX_LINES = 4
#: The widest column [Excel width units].
MAX_COLUMN_WIDTH = 50
#: Font sizes of :func:`write_table` and :func:`write_key_values` [pt]: values, headers.
TABLE_PT, TABLE_HEADER_PT = 10, 9
#: Text wider than this wraps in :func:`write_table` and :func:`write_key_values`
#: [Excel width units].
WRAP_WIDTH = 40
_FONT = "Calibri"
_PAD = 1.5  # a cell's padding [Excel width units]
_LINE_PT = {TABLE_PT: 13.0, TABLE_HEADER_PT: 12.0}  # height of a line of each font [pt]
_RULE = Side(style="thin", color="A6A6A6")
#: Booleans shown as yes/no (LibreOffice; Excel shows TRUE/FALSE whatever the format).
_YES_NO = '"yes";"yes";"no"'


def column_label(column):
    """A column's name for people: words instead of underscores, ``rms`` as ``RMS``.

    Examples
    --------
    >>> column_label("tire_force_rms_LF"), column_label("score_platform")
    ('tire force RMS LF', 'score platform')
    """
    return " ".join("RMS" if w == "rms" else w for w in str(column).split("_") if w)


def text_width(text, *, size=11, bold=False):
    """Width of a text in Excel width units (a digit of 11 pt Calibri), estimated.

    Per-character widths (digits 1.1: the unit is rounded down to whole pixels,
    and LibreOffice draws the columns a little narrower than Excel; most
    lower-case letters 0.95, narrow ones 0.55, capitals 1.15, ``M``/``W`` 1.5,
    space and punctuation about 0.5, ``+ = < > %`` 1.3-1.5), scaled by the font
    size and 20 % for bold. The letters are those of DejaVu Sans against its digit, wider than
    Calibri's: where Calibri is missing, LibreOffice draws DejaVu Sans, with
    its columns a DejaVu digit wide, and its bold 15-20 % wider than its
    regular (seen as cut labels and header words in the PDFs). Good to about
    a character over a header; enough to size columns and count wrapped lines.

    Examples
    --------
    >>> round(text_width("0.0809"), 2), round(text_width("0.0809", size=9), 2)
    (6.0, 4.91)
    """
    w = 0.0
    for ch in str(text):
        if ch.isdigit():
            w += 1.1
        elif ch in "MWmw":
            w += 1.5
        elif ch.isupper():
            w += 1.15
        elif ch in "ijlrtf":
            w += 0.55
        elif ch.islower():
            w += 0.95
        elif ch in " .,:;'!|":
            w += 0.5
        elif ch in "%&@":
            w += 1.5
        elif ch in "+=<>~^#$*±°":
            w += 1.3
        else:
            w += 0.65
    return w * size / 11 * (1.2 if bold else 1.0)


def wrap_lines(text, width, *, size=11, bold=False):
    """Lines of `text` wrapped at spaces into `width` (a longer word stays whole).

    Parameters
    ----------
    text : str
    width : float
        [Excel width units] (see :func:`text_width`).
    size : float
        Font size [pt].
    bold : bool

    Returns
    -------
    list of str
        The lines (none for an empty text).

    Examples
    --------
    >>> wrap_lines("tire force RMS LF [lbf]", 8)
    ['tire force', 'RMS LF', '[lbf]']
    """
    lines, line = [], ""
    for word in str(text).split():
        trial = f"{line} {word}" if line else word
        if line and text_width(trial, size=size, bold=bold) > width:
            lines.append(line)
            line = word
        else:
            line = trial
    return lines + ([line] if line else [])


def fit_column_width(header, data_width, *, size=11, bold=True, max_lines=HEADER_MAX_LINES,
                     max_width=MAX_COLUMN_WIDTH):
    """Width of a column whose header wraps at spaces, and the header's lines.

    Parameters
    ----------
    header : str
    data_width : float
        Width of the widest value shown in the column [Excel width units, a
        digit of 11 pt Calibri; see :func:`text_width`].
    size : float
        The header's font size [pt].
    bold : bool
        The header's font is bold.
    max_lines : int
        The header wraps to at most this many lines (the column widens instead).
    max_width : float
        The widest column [Excel width units].

    Returns
    -------
    width : float
        At least the data's and the header's longest word (up to `max_width`),
        without the cell's padding.
    lines : int
        Lines of the header at that width.

    Examples
    --------
    >>> fit_column_width("tire force RMS LF [lbf]", 6, size=9)
    (6.5, 4)
    >>> fit_column_width("tire force RMS LF [lbf]", 7, size=9)
    (7, 3)
    """
    words = str(header).split() or [""]
    widest = max(text_width(w, size=size, bold=bold) for w in words)
    width = min(max(data_width, widest, 1), max_width)

    def lines(w):
        return max(len(wrap_lines(header, w, size=size, bold=bold)), 1)

    while lines(width) > max_lines and width < max_width:
        width += 0.5
    return width, lines(width)



def decimals_format(values, *, significant=4):
    """Excel number format showing about `significant` digits of a column's typical value.

    Parameters
    ----------
    values : array_like of float
    significant : int

    Returns
    -------
    str
        ``"0"`` for whole numbers, else ``"0.0..."`` with the decimals that show the
        median magnitude to `significant` digits (at most 6).

    Examples
    --------
    >>> decimals_format([0.0745, 0.0937]), decimals_format([87.6, 92.2]), decimals_format([1, 3])
    ('0.00000', '0.00', '0')
    """
    v = np.asarray([x for x in values if isinstance(x, (int, float, np.number))
                    and not isinstance(x, (bool, np.bool_))], dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0 or np.all(v == np.round(v)):
        return "0"
    typical = float(np.median(np.abs(v[v != 0]))) if np.any(v != 0) else 1.0
    d = int(min(max(significant - 1 - math.floor(math.log10(typical)), 0), 6))
    return "0" if d == 0 else "0." + "0" * d


def printable_size_pt(units, *, landscape=True):
    """Width and height of a page inside :data:`PRINT_MARGINS_IN` [pt].

    Parameters
    ----------
    units : {"SI", "imperial"}
        Chooses the paper (:data:`PAPER_SIZE`).
    landscape : bool

    Returns
    -------
    (float, float)

    Examples
    --------
    >>> [round(x) for x in printable_size_pt("SI")]
    [784, 523]
    """
    units = check_units(units, where="printable_size_pt")
    w, h = PAPER_IN[PAPER_SIZE[units]]
    if landscape:
        w, h = h, w
    m = PRINT_MARGINS_IN
    return 72.0 * (w - m["left"] - m["right"]), 72.0 * (h - m["top"] - m["bottom"])


def _scale(width_units, units, landscape):
    """Fit-to-width scale of a table, floored to a whole percent (as applications print)."""
    room = printable_size_pt(units, landscape=landscape)[0]
    return min(100, math.floor(100.0 * room / (WIDTH_UNIT_PT * max(width_units, 1e-9)))) / 100


def fit_width_units(font_pt, *, units, landscape=True):
    """The widest table that prints one page wide with `font_pt` text at >= MIN_PRINT_PT.

    Parameters
    ----------
    font_pt : float
        The table's smallest font [pt].
    units : {"SI", "imperial"}
    landscape : bool

    Returns
    -------
    float
        [Excel width units]

    Examples
    --------
    >>> round(fit_width_units(9, units="imperial"), 1)
    134.5
    """
    scale = min(1.0, math.ceil(100.0 * MIN_PRINT_PT / font_pt) / 100)
    return printable_size_pt(units, landscape=landscape)[0] / (WIDTH_UNIT_PT * scale)


def column_widths(ws, first, last):
    """Widths of columns `first`..`last` (1-based) of a sheet [Excel width units].

    Reads the sheet's column dimensions, also where they span several columns (as
    openpyxl loads a saved workbook); an unsized column has
    :data:`DEFAULT_COLUMN_WIDTH`.
    """
    widths = {}
    for key, dim in ws.column_dimensions.items():
        lo = dim.min or column_index_from_string(key)
        hi = dim.max or lo
        for j in range(lo, hi + 1):
            if dim.width:
                widths[j] = float(dim.width)
    return [widths.get(j, DEFAULT_COLUMN_WIDTH) for j in range(first, last + 1)]


def smallest_font_pt(ws, area):
    """The smallest font [pt] of the non-empty cells in `area` (e.g. ``"A1:K62"``)."""
    lo_c, lo_r, hi_c, hi_r = range_boundaries(area.replace("$", ""))
    sizes = [float(cell.font.sz or 11.0)
             for row in ws.iter_rows(min_row=lo_r, max_row=hi_r, min_col=lo_c, max_col=hi_c)
             for cell in row if cell.value is not None and str(cell.value).strip()]
    return min(sizes, default=11.0)


@dataclasses.dataclass(frozen=True)
class PrintLayout:
    """How a sheet prints (from :func:`print_setup`).

    Attributes
    ----------
    scale : float
        The print scale estimated for :data:`WIDTH_UNIT_PT` (1 = 100 %); one page wide when
        `pages_wide` is 1, else the sheet's fixed scale.
    pages_wide : int
    column_breaks : tuple of int
        The last column of each page but the last (1-based, in the sheet).
    smallest_pt : float
        The smallest printed text [pt]: the smallest font times `scale`.
    """

    scale: float
    pages_wide: int
    column_breaks: tuple
    smallest_pt: float


def _column_pages(widths, room, n_titles, starts):
    """Greedy pages of columns: each page as many as fit in `room` (the titles repeated on
    every page after the first), ended at the last group start of the page when that leaves
    the page at least half full. Returns each page's end (0-based, exclusive)."""
    title = sum(widths[:n_titles])
    ends, start = [], 0
    while start < len(widths):
        avail = room - (title if start else 0)
        end, used = start, 0.0
        while end < len(widths) and used + widths[end] <= avail:
            used += widths[end]
            end += 1
        end = max(end, start + 1, n_titles + 1 if start == 0 else 0)
        if end < len(widths):
            good = [b for b in starts if start < b <= end and b > n_titles
                    and sum(widths[start:b]) >= 0.5 * avail]
            if good:
                end = max(good)
        ends.append(min(end, len(widths)))
        start = ends[-1]
    return ends


def _row_heights(ws, area, title_rows):
    """Heights of the title rows and of the other rows of `area` [pt] (15 pt where unset)."""
    _, lo_r, _, hi_r = range_boundaries(area.replace("$", ""))
    titles = set()
    if title_rows:
        a, b = (int(x) for x in (title_rows.replace("$", "").split(":") * 2)[:2])
        titles = set(range(a, b + 1))
    h = {r: (ws.row_dimensions[r].height if r in ws.row_dimensions else None) or 15.0
         for r in range(lo_r, hi_r + 1)}
    return (sum(v for r, v in h.items() if r in titles),
            sum(v for r, v in h.items() if r not in titles))


def print_setup(ws, *, units, area, title_rows=None, title_cols=None, group_starts=(),
                landscape=True, footer=None):
    """Set a worksheet to print: one page wide when its text stays readable, else across pages.

    Parameters
    ----------
    ws : openpyxl.worksheet.worksheet.Worksheet
        Written (values, fonts and column widths set): the layout is computed from them.
    units : {"SI", "imperial"}
        Chooses the paper (:data:`PAPER_SIZE`: A4 for SI, letter for imperial).
    area : str
        The print area, e.g. ``"A1:K62"``.
    title_rows : str, optional
        Rows repeated at the top of every page, e.g. ``"1:1"`` (print titles).
    title_cols : str, optional
        Columns repeated at the left of every page when the sheet prints across pages, e.g.
        ``"A:B"`` (default: the first column).
    group_starts : iterable of int
        Columns (1-based) that start a group of columns: a page across ends before one
        where it can.
    landscape : bool
    footer : str, optional
        Left footer text (the sheet's name and the page number are on the right).

    Returns
    -------
    PrintLayout

    Notes
    -----
    One page wide (any number tall) when the smallest font of the area's non-empty cells
    prints at >= :data:`MIN_PRINT_PT` so; else a fixed scale, the largest that spans the
    fewest pages (across times down, from the row heights) with that font at >=
    :data:`SPLIT_PRINT_PT` (:data:`MIN_PRINT_PT` for a smaller font), the `title_cols`
    repeated, column breaks at `group_starts` where a page stays at least half full, pages
    across then down. Widths at :data:`WIDTH_UNIT_PT` (see the module's notes). Margins
    :data:`PRINT_MARGINS_IN`, centred horizontally, no printed gridlines (the writers draw
    borders).
    """
    units = check_units(units, where="print_setup")
    lo_c, _, hi_c, _ = range_boundaries(area.replace("$", ""))
    widths = column_widths(ws, lo_c, hi_c)
    font = smallest_font_pt(ws, area)
    ps = ws.page_setup
    ps.orientation = "landscape" if landscape else "portrait"
    ps.paperSize = PAPER_SIZE[units]
    ws.page_margins = PageMargins(**PRINT_MARGINS_IN)
    ws.print_options.horizontalCentered = True
    ws.print_options.gridLines = False
    ws.print_area = area
    if title_rows:
        ws.print_title_rows = title_rows
    scale = _scale(sum(widths), units, landscape)
    if font * scale >= MIN_PRINT_PT:
        ps.fitToWidth, ps.fitToHeight = 1, 0
        ws.sheet_properties.pageSetUpPr = PageSetupProperties(fitToPage=True)
        layout = PrintLayout(scale, 1, (), font * scale)
    else:
        cols = (title_cols or get_column_letter(lo_c)).replace("$", "")
        first, last = (column_index_from_string(c) for c in (cols.split(":") * 2)[:2])
        n_titles = last - lo_c + 1
        starts = [j - lo_c for j in group_starts if lo_c < j <= hi_c]
        room_pt, tall_pt = printable_size_pt(units, landscape=landscape)
        lowest = math.ceil(100.0 * max(MIN_PRINT_PT, min(SPLIT_PRINT_PT, font)) / font)
        heights = _row_heights(ws, area, title_rows)

        def pages(percent):
            return _column_pages(widths, room_pt / (WIDTH_UNIT_PT * percent / 100), n_titles,
                                 starts)

        def count(percent):  # pages across x pages down
            body = tall_pt / (percent / 100) - heights[0]
            return len(pages(percent)) * max(1, math.ceil(heights[1] / max(body, 1.0)))

        fewest = count(lowest)
        percent = max(p for p in range(lowest, 101) if count(p) == fewest)
        ends = pages(percent)
        scale = percent / 100
        ps.scale = percent
        ps.fitToWidth = ps.fitToHeight = None
        ws.sheet_properties.pageSetUpPr = PageSetupProperties(fitToPage=False)
        ps.pageOrder = "overThenDown"
        ws.print_title_cols = f"{get_column_letter(first)}:{get_column_letter(last)}"
        breaks = tuple(lo_c + e - 1 for e in ends[:-1])
        for b in breaks:
            ws.col_breaks.append(Break(id=b))
        layout = PrintLayout(scale, len(ends), breaks, font * scale)
    # whole points in a footer; LibreOffice scales it a little below the sheet's scale
    size = max(FOOTER_PT, math.ceil((MIN_PRINT_PT + 0.25) / layout.scale))
    if footer:
        ws.oddFooter.left.text = str(footer).replace("&", "&&")
        ws.oddFooter.left.size = size
    ws.oddFooter.right.text = "&A, page &P of &N"
    ws.oddFooter.right.size = size
    return layout


def _shown(value, fmt):
    """The text a cell shows for `value` under number format `fmt` (for widths)."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, float)) and fmt and fmt.startswith("0"):
        d = len(fmt.split(".")[1]) if "." in fmt else 0
        return f"{value:.{d}f}"
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def _excel_value(value):
    """A value Excel can hold: NaN/inf and missing become empty cells, numpy -> Python."""
    if value is None:
        return None
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (bool, int, float, str)):
        return value
    try:
        if pd.isna(value):  # pandas NA / NaT
            return None
    except (TypeError, ValueError):  # an array-like: shown as text
        pass
    return str(value)


def write_table(ws, frame, *, headers=None, formats=None, top=1, freeze_cols=1):
    """Write a table under one bold, wrapped header row; size the columns to fit.

    Parameters
    ----------
    ws : openpyxl.worksheet.worksheet.Worksheet
    frame : pandas.DataFrame
        The rows (the index is not written).
    headers : list of str, optional
        The header of each column (default: :func:`column_label` of the column's name).
    formats : dict of str -> str, optional
        Excel number format per column; other numeric columns get :func:`decimals_format`,
        booleans show yes/no.
    top : int
        The header's row; the rows follow.
    freeze_cols : int
        Columns kept in view when scrolling (the panes freeze under the header).

    Returns
    -------
    int
        The last row written.

    Notes
    -----
    Values :data:`TABLE_PT`, headers :data:`TABLE_HEADER_PT` bold, wrapped at spaces into at
    most :data:`HEADER_MAX_LINES` lines; text wider than :data:`WRAP_WIDTH` wraps in its
    column; thin rules. Call :func:`print_setup` after it.
    """
    cols = list(frame.columns)
    headers = list(headers) if headers is not None else [column_label(c) for c in cols]
    formats = dict(formats or {})
    data = [[_excel_value(v) for v in frame[c].tolist()] for c in cols]
    for c, values in zip(cols, data):
        if c not in formats:
            numbers = [v for v in values if isinstance(v, (int, float))
                       and not isinstance(v, bool)]
            formats[c] = decimals_format(numbers) if numbers else None
    head_font = Font(name=_FONT, size=TABLE_HEADER_PT, bold=True)
    font = Font(name=_FONT, size=TABLE_PT)
    box = Border(left=_RULE, right=_RULE, top=_RULE, bottom=_RULE)
    head_box = Border(left=_RULE, right=_RULE, top=_RULE, bottom=Side(style="medium"))
    head_align = Alignment(wrap_text=True, horizontal="center", vertical="bottom")
    wrapped, plain = Alignment(wrap_text=True, vertical="top"), Alignment(vertical="top")
    widths, lines, long_text = [], [], []
    for c, head, values in zip(cols, headers, data):
        shown = max((text_width(_shown(v, formats[c]), size=TABLE_PT) for v in values),
                    default=0.0)
        long_text.append(shown > WRAP_WIDTH)
        w, n = fit_column_width(head, min(shown, WRAP_WIDTH), size=TABLE_HEADER_PT)
        widths.append(w + _PAD)
        lines.append(n)
    for j, head in enumerate(headers, start=1):
        cell = ws.cell(row=top, column=j, value=head)
        cell.font, cell.alignment, cell.border = head_font, head_align, head_box
    ws.row_dimensions[top].height = _LINE_PT[TABLE_HEADER_PT] * max(lines, default=1) + 3
    for i in range(len(frame)):
        r = top + 1 + i
        height = 1
        for j, c in enumerate(cols):
            v = data[j][i]
            cell = ws.cell(row=r, column=j + 1, value=v)
            cell.font, cell.border = font, box
            cell.alignment = plain
            if isinstance(v, bool):
                cell.number_format = _YES_NO
            elif formats[c] and isinstance(v, (int, float)):
                cell.number_format = formats[c]
            if long_text[j] and isinstance(v, str):
                cell.alignment = wrapped
                height = max(height, len(wrap_lines(v, widths[j] - _PAD, size=TABLE_PT)))
        if height > 1:
            ws.row_dimensions[r].height = _LINE_PT[TABLE_PT] * height + 2
    for j, w in enumerate(widths, start=1):
        ws.column_dimensions[get_column_letter(j)].width = round(min(w, MAX_COLUMN_WIDTH), 2)
    if freeze_cols is not None:
        ws.freeze_panes = ws.cell(row=top + 1, column=freeze_cols + 1).coordinate
    return top + len(frame)


def write_key_values(ws, rows, *, top=1, title=None):
    """Write label-value rows in two columns sized so that each label and value read together.

    Parameters
    ----------
    ws : openpyxl.worksheet.worksheet.Worksheet
    rows : iterable of (str, object)
        A row whose value is None and label is not: a bold section heading; (None, None):
        an empty row.
    top : int
        The first row (the title's, if any).
    title : str, optional
        A bold title above the rows.

    Returns
    -------
    int
        The last row written.

    Notes
    -----
    Labels :data:`TABLE_PT` in column A, values in column B, left-aligned, each column as
    wide as its longest text up to :data:`WRAP_WIDTH`; longer text wraps in its cell and
    the row is as tall as its lines (so a label and its value stay on one row, and one
    page wide keeps them on one page). Call :func:`print_setup` after it.
    """
    font, bold = Font(name=_FONT, size=TABLE_PT), Font(name=_FONT, size=TABLE_PT, bold=True)
    left = Alignment(horizontal="left", vertical="top", wrap_text=True)
    rows = [(label, _excel_value(value)) for label, value in rows]
    texts = [(None if label is None else str(label), _shown(value, None) if value is not None
              else None) for label, value in rows]
    label_w = min(max([text_width(a, size=TABLE_PT, bold=b is None) for a, b in texts
                       if a is not None] or [1.0]), WRAP_WIDTH)
    value_w = min(max([text_width(b, size=TABLE_PT) for _, b in texts if b is not None]
                      or [1.0]), WRAP_WIDTH)
    r = top
    if title is not None:
        ws.cell(row=r, column=1, value=title).font = Font(name=_FONT, size=12, bold=True)
        r += 2
    for (label, value), (a, b) in zip(rows, texts):
        lines = 1
        if a is not None:
            cell = ws.cell(row=r, column=1, value=a)
            cell.font, cell.alignment = (bold if value is None else font), left
            lines = len(wrap_lines(a, label_w, size=TABLE_PT, bold=value is None))
        if b is not None:
            cell = ws.cell(row=r, column=2, value=value)
            cell.font, cell.alignment = font, left
            lines = max(lines, len(wrap_lines(b, value_w, size=TABLE_PT)))
        if lines > 1:
            ws.row_dimensions[r].height = _LINE_PT[TABLE_PT] * lines + 2
        r += 1
    ws.column_dimensions["A"].width = round(label_w + _PAD, 2)
    ws.column_dimensions["B"].width = round(value_w + _PAD, 2)
    return r - 1
