"""The print layout shared by every workbook the planner writes: column widths that fit
wrapped headers, labels for people, and one-page-wide print setup.

:mod:`planner.report.ranking` (``ranking.xlsx``) and :mod:`planner.testplan` (the rig-day
run sheet) lay out their sheets with these: :func:`column_label` (a column's name for
people), :func:`text_width` (a text's width in Excel units, estimated from Calibri's
character widths), :func:`wrap_lines` and :func:`fit_column_width` (a header wrapped at
spaces into at most :data:`HEADER_MAX_LINES` lines), and :func:`print_setup` (landscape or
portrait, one page wide, :data:`PAPER_SIZE` by unit system, :data:`PRINT_MARGINS_IN`).
"""

from __future__ import annotations

from openpyxl.worksheet.page import PageMargins
from openpyxl.worksheet.properties import PageSetupProperties

from ident.data.units import check_units

__all__ = [
    "PAPER_SIZE",
    "PRINT_MARGINS_IN",
    "HEADER_MAX_LINES",
    "MAX_COLUMN_WIDTH",
    "column_label",
    "text_width",
    "wrap_lines",
    "fit_column_width",
    "print_setup",
]

#: Excel paper codes of the printed workbooks per unit system: ISO A4 for SI files, US
#: letter for imperial ones (the unit system a team writes says where it prints).
PAPER_SIZE = {"SI": 9, "imperial": 1}
#: Page margins of the printed workbooks [in]: narrow, so one page wide stays readable.
PRINT_MARGINS_IN = {"left": 0.4, "right": 0.4, "top": 0.45, "bottom": 0.55, "header": 0.2,
                    "footer": 0.25}
#: A header cell wraps to at most this many lines before its column widens.
HEADER_MAX_LINES = 4
#: The widest column [Excel width units].
MAX_COLUMN_WIDTH = 50


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

    Per-character widths of Calibri (digits 1.1: the unit is rounded down to
    whole pixels, and LibreOffice draws the columns a little narrower than
    Excel; most lower-case letters 0.85, narrow ones 0.5, capitals 1.15,
    ``M``/``W`` 1.5, space and punctuation about 0.5), scaled by the font size
    and 5 % for bold. Good to about a character over a header; enough to size
    columns and count wrapped lines.

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
            w += 0.5
        elif ch.islower():
            w += 0.85
        elif ch in " .,:;'!|":
            w += 0.5
        else:
            w += 0.65
    return w * size / 11 * (1.05 if bold else 1.0)


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
    >>> w, lines = fit_column_width("tire force RMS LF [lbf]", 6, size=9)
    >>> w, lines
    (6, 3)
    """
    words = str(header).split() or [""]
    widest = max(text_width(w, size=size, bold=bold) for w in words)
    width = min(max(data_width, widest, 1), max_width)

    def lines(w):
        return max(len(wrap_lines(header, w, size=size, bold=bold)), 1)

    while lines(width) > max_lines and width < max_width:
        width += 0.5
    return width, lines(width)


def print_setup(ws, *, units, area, title_rows=None, landscape=True, footer=None):
    """Set a worksheet to print one page wide (any number tall).

    Parameters
    ----------
    ws : openpyxl.worksheet.worksheet.Worksheet
    units : {"SI", "imperial"}
        Chooses the paper (:data:`PAPER_SIZE`: A4 for SI, letter for imperial).
    area : str
        The print area, e.g. ``"A1:K62"``.
    title_rows : str, optional
        Rows repeated at the top of every page, e.g. ``"1:1"`` (print titles).
    landscape : bool
    footer : str, optional
        Left footer text (the page number is on the right).

    Notes
    -----
    Fit to one page wide and as many tall as it takes, margins
    :data:`PRINT_MARGINS_IN`, centred horizontally, no printed gridlines (the
    writers draw borders).
    """
    units = check_units(units, where="print_setup")
    ws.page_setup.orientation = "landscape" if landscape else "portrait"
    ws.page_setup.paperSize = PAPER_SIZE[units]
    ws.page_setup.fitToWidth = 1
    ws.page_setup.fitToHeight = 0
    ws.sheet_properties.pageSetUpPr = PageSetupProperties(fitToPage=True)
    ws.page_margins = PageMargins(**PRINT_MARGINS_IN)
    ws.print_options.horizontalCentered = True
    ws.print_options.gridLines = False
    ws.print_area = area
    if title_rows:
        ws.print_title_rows = title_rows
    if footer:
        ws.oddFooter.left.text = str(footer).replace("&", "&&")
        ws.oddFooter.left.size = 8
    ws.oddFooter.right.text = "page &P of &N"
    ws.oddFooter.right.size = 8
