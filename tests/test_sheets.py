"""Tests of planner.report.sheets: the shared print layout, and every workbook the planner
writes (ranking.xlsx, optimize.xlsx, whatif.xlsx, test_plan.xlsx) read back with openpyxl
and checked to print landscape, its header rows repeated, one page wide or across pages
with its key columns repeated, and no text under 7 pt.

The printed size is estimated here on its own (not with the module's functions): one Excel
width unit prints 7.0 pt wide at 100 % in LibreOffice where Calibri is missing (DejaVu Sans
stands in; measured by converting the workbooks to PDF, see the module's notes), less with
Calibri or in Excel, so the estimate is a floor.
"""

import math
import re
import shutil
import subprocess
import warnings

import numpy as np
import pandas as pd
import pytest
from openpyxl import Workbook, load_workbook
from openpyxl.styles import Font
from openpyxl.utils import column_index_from_string
from openpyxl.utils.cell import range_boundaries

from ident.data.channels import CORNERS
from ident.sim.metrics import METRIC_NAMES, METRIC_QUANTITY
from planner.objective import default_objective, score_setups
from planner.report import write_ranking
from planner.report.sheets import (
    MIN_PRINT_PT,
    PAPER_SIZE,
    print_setup,
    text_width,
    write_key_values,
    write_table,
)
from planner.optimize import CurveOptions, SolverOptions
from planner.design import InformationOptions, ScheduleOptions

# printed width of one Excel width unit at 100 % [pt]: LibreOffice, DejaVu Sans for Calibri
UNIT_PT = 7.0
# paper (portrait width, height) [in] of the Excel paper codes: A4, US letter
PAPER_IN = {9: (8.27, 11.69), 1: (8.5, 11.0)}
DEFAULT_WIDTH = 8.43  # an unsized column [Excel width units]
SMALLEST_PT = 7.0  # the floor for any printed text


def _widths(ws):
    """{column index: width}, also for dimensions spanning several columns (as loaded)."""
    out = {}
    for key, dim in ws.column_dimensions.items():
        lo = dim.min or column_index_from_string(key)
        for j in range(lo, (dim.max or lo) + 1):
            if dim.width:
                out[j] = dim.width
    return out


def _area(ws):
    area = ws.print_area if isinstance(ws.print_area, str) else ws.print_area[0]
    return range_boundaries(area.split("!")[-1].replace("$", ""))


def _printed(ws):
    """Check a loaded sheet's print setup; return its smallest printed text [pt].

    Landscape; either fit to one page wide (fitToWidth 1, fitToHeight 0: any number tall)
    at the scale its width needs, or a fixed scale with column breaks whose pages (the
    title columns repeated after the first) each fit the printable width.
    """
    ps = ws.page_setup
    assert ps.orientation == "landscape", ws.title
    assert int(ps.paperSize) in PAPER_IN, ws.title
    lo_c, lo_r, hi_c, hi_r = _area(ws)
    long_in = PAPER_IN[int(ps.paperSize)][1]  # landscape: the long side across
    room_pt = 72.0 * (long_in - ws.page_margins.left - ws.page_margins.right)
    known = _widths(ws)
    widths = [known.get(j, DEFAULT_WIDTH) for j in range(lo_c, hi_c + 1)]
    if ws.sheet_properties.pageSetUpPr.fitToPage:
        fit = (int(ps.fitToWidth), int(ps.fitToHeight or 0))
        assert fit in ((1, 0), (1, 1)), ws.title  # one page wide, or one page (a summary)
        scale = min(1.0, math.floor(100 * room_pt / (UNIT_PT * sum(widths))) / 100)
        if fit == (1, 1):  # the height too: the rows' heights (15 pt where unset)
            tall_pt = 72.0 * (PAPER_IN[int(ps.paperSize)][0] - ws.page_margins.top
                              - ws.page_margins.bottom)
            rows = sum((ws.row_dimensions[r].height if r in ws.row_dimensions else None)
                       or 15.0 for r in range(lo_r, hi_r + 1))
            scale = min(scale, math.floor(100 * tall_pt / rows) / 100)
    else:
        scale = int(ps.scale) / 100
        assert ws.print_title_cols, ws.title  # the key columns repeat on every page
        a, b = (column_index_from_string(c) for c in ws.print_title_cols.replace("$", "")
                .split(":"))
        titles = sum(widths[a - lo_c:b - lo_c + 1])
        ends = sorted(brk.id for brk in ws.col_breaks.brk) + [hi_c]
        start = lo_c
        for k, end in enumerate(ends):
            page = sum(widths[start - lo_c:end - lo_c + 1]) + (titles if k else 0)
            assert UNIT_PT * scale * page <= room_pt, (ws.title, start, end)
            start = end + 1
    sizes = [float(c.font.sz or 11.0) for row in ws.iter_rows(min_row=lo_r, max_row=hi_r,
                                                              min_col=lo_c, max_col=hi_c)
             for c in row if c.value is not None and str(c.value).strip()]
    footer = ws.oddFooter.right
    assert "&P" in footer.text and "&A" in footer.text, ws.title  # the sheet and the page
    assert float(footer.size) * scale >= SMALLEST_PT, ws.title
    return min(sizes) * scale


def _check_workbook(path, *, key_value=(), summary=False):
    """Every sheet prints at >= 7 pt; every table sheet repeats its header rows; with
    `summary` (a written workbook), the first sheet is the one-page summary (checked through
    LibreOffice where it is installed)."""
    wb = load_workbook(path)
    for ws in wb.worksheets:
        assert _printed(ws) >= SMALLEST_PT, (path.name, ws.title, _printed(ws))
        if ws.title not in key_value and ws.title != "summary":
            assert ws.print_title_rows, (path.name, ws.title)
    if summary:
        assert wb.sheetnames[0] == "summary", path.name
        _check_first_page(path)
    return wb


# ----------------------------------------------------------------------------------------------
# the first sheet through LibreOffice: one page, no text under 7 pt
# ----------------------------------------------------------------------------------------------

SOFFICE = shutil.which("soffice") or shutil.which("libreoffice")
PDF_TOOLS = all(shutil.which(t) for t in ("pdftotext", "pdfinfo"))
CALIBRATION_PT = 10.0  # the calibration cell's font [pt]
# LibreOffice's text sizes read back to 0.1 pt (the words' boxes, calibrated on a 10 pt cell)
PT_TOLERANCE = 0.1
_WORD = re.compile(r'<word xMin="[-\d.]+" yMin="([-\d.]+)" xMax="[-\d.]+" yMax="([-\d.]+)">'
                   r'(.*?)</word>')


def _pdf(xlsx, out_dir):
    """Convert a workbook to PDF with LibreOffice; return the PDF's path."""
    subprocess.run([SOFFICE, "--headless", "--norestore", "--convert-to", "pdf", "--outdir",
                    str(out_dir), str(xlsx)], check=True, capture_output=True, timeout=300)
    pdf = out_dir / (xlsx.stem + ".pdf")
    assert pdf.exists(), xlsx
    return pdf


def _words(pdf):
    """The PDF's words and their box heights [pt] (pdftotext -bbox)."""
    text = subprocess.run(["pdftotext", "-bbox", str(pdf), "-"], check=True,
                          capture_output=True, text=True).stdout
    return [(w, float(y1) - float(y0)) for y0, y1, w in _WORD.findall(text)]


def _pages(pdf):
    info = subprocess.run(["pdfinfo", str(pdf)], check=True, capture_output=True,
                          text=True).stdout
    return int(re.search(r"Pages:\s+(\d+)", info).group(1))


_CALIBRATION = {}


def _box_per_pt(out_dir):
    """A word's box height per point of font, as LibreOffice prints it here (a 10 pt cell;
    measured once a session)."""
    if "box_per_pt" in _CALIBRATION:
        return _CALIBRATION["box_per_pt"]
    wb = Workbook()
    cell = wb.active.cell(1, 1, "Calibration")
    cell.font = Font(name="Calibri", sz=CALIBRATION_PT)
    path = out_dir / "calibration.xlsx"
    wb.save(path)
    heights = [h for _, h in _words(_pdf(path, out_dir))]
    assert heights
    _CALIBRATION["box_per_pt"] = max(heights) / CALIBRATION_PT
    return _CALIBRATION["box_per_pt"]


def _check_first_page(path):
    """The workbook's first sheet alone, through LibreOffice to PDF: one page, its smallest
    word >= 7 pt (skipped where LibreOffice or poppler is missing)."""
    if not (SOFFICE and PDF_TOOLS):
        return
    out = path.parent / f"{path.stem}_pdf"
    out.mkdir(exist_ok=True)
    wb = load_workbook(path)
    for name in wb.sheetnames[1:]:
        del wb[name]
    first = out / f"{path.stem}_first.xlsx"
    wb.save(first)
    pdf = _pdf(first, out)
    assert _pages(pdf) == 1, (path.name, _pages(pdf))
    words = _words(pdf)
    assert len(words) > 20, path.name  # the table, the notes and the footer printed
    smallest = min(h for _, h in words) / _box_per_pt(out)
    assert smallest >= SMALLEST_PT - PT_TOLERANCE, (path.name, smallest)


# ----------------------------------------------------------------------------------------------
# the layout functions
# ----------------------------------------------------------------------------------------------

def _sheet(n_cols, width, *, font=10, rows=5):
    wb = Workbook()
    ws = wb.active
    for j in range(1, n_cols + 1):
        ws.cell(1, j, f"h{j}")
        for r in range(2, rows + 2):
            ws.cell(r, j, r * j)
        for r in range(1, rows + 2):
            ws.cell(r, j).font = Font(name="Calibri", sz=font)
        ws.column_dimensions[ws.cell(1, j).column_letter].width = width
    return wb, ws


def test_narrow_sheet_fits_one_page_wide(tmp_path):
    wb, ws = _sheet(12, 8.0)
    layout = print_setup(ws, units="SI", area="A1:L6", title_rows="1:1", footer="f & g")
    assert layout.pages_wide == 1 and layout.scale == 1.0
    assert ws.oddFooter.left.text == "f && g"  # '&' is a code in a footer
    wb.save(tmp_path / "n.xlsx")
    back = _check_workbook(tmp_path / "n.xlsx")
    assert back.active.print_title_rows == "$1:$1"
    assert _printed(back.active) == pytest.approx(10.0)


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_wide_sheet_prints_across_pages_not_smaller(tmp_path, units):
    """40 columns of 8 units (2240 pt at 100 %) fit one page wide only at 3-4 pt: it prints
    across pages at >= 8 pt instead, the first two columns repeated, breaking where a group
    starts when that keeps a page at least half full."""
    wb, ws = _sheet(40, 8.0, font=9)
    starts = [3, 11, 21, 31]
    layout = print_setup(ws, units=units, area="A1:AN6", title_rows="1:1", title_cols="A:B",
                         group_starts=starts)
    assert layout.pages_wide > 1 and layout.smallest_pt >= 8.0 - 1e-9
    assert set(layout.column_breaks) <= {s - 1 for s in starts}  # each ends before a group
    assert ws.page_setup.pageOrder == "overThenDown"
    assert int(PAPER_SIZE[units]) == int(ws.page_setup.paperSize)
    wb.save(tmp_path / "w.xlsx")
    back = _check_workbook(tmp_path / "w.xlsx")
    assert not back.active.sheet_properties.pageSetUpPr.fitToPage
    assert back.active.print_title_cols == "$A:$B"
    assert _printed(back.active) >= 8.0 - 1e-9


def test_small_font_on_a_wide_sheet_is_not_squeezed_below_the_floor(tmp_path):
    _, ws = _sheet(30, 8.0, font=8)
    layout = print_setup(ws, units="imperial", area="A1:AD6", title_rows="1:1")
    assert layout.smallest_pt >= MIN_PRINT_PT - 1e-9
    assert ws.print_title_cols == "$A:$A"  # by default the first column repeats
    assert ws.oddFooter.right.size * layout.scale >= MIN_PRINT_PT


def test_write_table_sizes_columns_to_headers_and_values(tmp_path):
    frame = pd.DataFrame({"setup": ["L28/L28/L28/L28", "B20/B20/B20/B20"],
                          "tire_force_rms_LF": [87.622, 92.198], "feasible": [True, False],
                          "violations": ["", ("shock travel RMS LF 1.40 x baseline > max_ratio "
                                              "1.25; shock travel RMS RF 1.41 x baseline")]})
    wb = Workbook()
    ws = wb.active
    last = write_table(ws, frame, headers=["setup", "tire force RMS LF [lbf]", "feasible",
                                           "violations"])
    assert last == 3
    assert ws.cell(2, 2).number_format == "0.00"  # 4 significant digits
    assert ws.cell(3, 3).value is False and "no" in ws.cell(3, 3).number_format
    for j, head in enumerate(["setup", "tire force RMS LF [lbf]", "feasible"], start=1):
        width = ws.column_dimensions[ws.cell(1, j).column_letter].width
        assert width >= max(text_width(w, size=9, bold=True) for w in head.split())
    assert ws.cell(3, 4).alignment.wrap_text and ws.row_dimensions[3].height > 13
    assert ws.freeze_panes == "B2"


def test_key_values_keep_label_and_value_on_one_row(tmp_path):
    """A two-column sheet one page wide: every label and its value on the same row, a long
    value wrapped in its cell with the row as tall as its lines."""
    long = "a rather long value that needs more than one line " * 3
    rows = [("optimum score (time domain)", 0.926057), ("crate best", "L28/L28/L28/L28"),
            ("notes", long), (None, None), ("section", None), ("units", "imperial")]
    wb = Workbook()
    ws = wb.active
    last = write_key_values(ws, rows)
    assert last == len(rows)
    assert [ws.cell(r, 1).value for r in range(1, last + 1)] == [
        "optimum score (time domain)", "crate best", "notes", None, "section", "units"]
    assert ws.cell(1, 2).value == pytest.approx(0.926057) and ws.cell(3, 2).alignment.wrap_text
    assert ws.cell(5, 1).font.b  # a heading
    assert ws.row_dimensions[3].height >= 2 * 13
    print_setup(ws, units="SI", area=f"A1:B{last}", footer="report")
    wb.save(tmp_path / "kv.xlsx")
    back = _check_workbook(tmp_path / "kv.xlsx", key_value=("Sheet",))
    assert back.active.sheet_properties.pageSetUpPr.fitToPage  # label and value: one page


# ----------------------------------------------------------------------------------------------
# the written workbooks
# ----------------------------------------------------------------------------------------------

@pytest.fixture
def ranking_table(rng):
    """60 setups with every spec metric (SI), intervals, scores, notes: ~30 columns."""
    n = 60
    names = ["baseline"] + [f"setup-{k:02d}" for k in range(1, n)]
    typical = {"force": 450.0, "displacement": 0.004, "velocity": 0.12}
    t = pd.DataFrame({m: typical[METRIC_QUANTITY[m]] * rng.uniform(0.8, 1.2, n)
                      for m in METRIC_NAMES}, index=pd.Index(names, name="setup"))
    for c in CORNERS:
        t[c] = rng.choice(["B20", "L28", "DM"], n)
    for m in METRIC_NAMES:
        t[f"{m}_lo"], t[f"{m}_hi"] = t[m] * 0.95, t[m] * 1.07
    t = t.join(score_setups(t, default_objective()).table)
    t["unresolved"] = ""
    return t


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_ranking_workbook_prints_readably(ranking_table, tmp_path, units):
    paths = write_ranking(ranking_table, tmp_path, units=units, objective=default_objective())
    wb = _check_workbook(paths["xlsx"], key_value=("about",), summary=True)
    assert wb["ranking"].max_column >= 25  # the ~30-column table of the issue
    for name in ("ranking", "intervals"):  # too wide for one page: across pages at >= 8 pt
        assert not wb[name].sheet_properties.pageSetUpPr.fitToPage
        assert _printed(wb[name]) >= 8.0 - 1e-9


def test_run_sheet_workbook_prints_readably(paper_vehicle, demo_library, tmp_path):
    from planner.design import design_experiment
    from planner.testplan import write_run_sheet

    plan = design_experiment(paper_vehicle, demo_library, budget_min=90.0, baseline="B20",
                             schedule=ScheduleOptions(n_validation=2),
                             information=InformationOptions(n_bands=24, n_design_bands=6))
    for units in ("SI", "imperial"):
        path = write_run_sheet(plan, tmp_path / f"{units}.xlsx", units=units)
        wb = _check_workbook(path, key_value=("information",), summary=True)
        assert wb["run sheet"].sheet_properties.pageSetUpPr.fitToPage  # one page wide


def test_whatif_workbook_prints_readably(paper_vehicle, track_drive, demo_library, tmp_path):
    from ident.data.drive import Drive
    from planner.setups import enumerate_setups
    from planner.whatif import Factor, evaluate_whatif, perturbation_set, write_whatif

    n = int(10 * track_drive.fs_hz)
    drive = Drive("track 10 s", track_drive.fs_hz,
                  {c: x[:n] for c, x in track_drive.channels.items()})
    setups = enumerate_setups(demo_library)[:3]
    ps = perturbation_set([Factor("dyno", "shock_scale", targets=CORNERS,
                                  levels=(0.95, 1.05))])
    w = evaluate_whatif(paper_vehicle, drive, setups, demo_library, ps, baseline=setups[0])
    files = write_whatif(w, tmp_path / "w", units="imperial", top=2)
    wb = _check_workbook(files["whatif.xlsx"], key_value=("settings",), summary=True)
    assert wb["table"]["A1"].value == "drive"


def test_optimize_workbook_prints_readably(paper_model, track_drive, demo_library, tmp_path):
    from ident.data.drive import Drive
    from planner.optimize import OptimizeWarning, optimize_curves, write_optimum

    n = int(20 * track_drive.fs_hz)
    drive = Drive("track 20 s", track_drive.fs_hz,
                  {c: x[:n] for c, x in track_drive.channels.items()})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptimizeWarning)
        opt = optimize_curves(paper_model, drive, demo_library, baseline="B20",
                              curves=CurveOptions(knots_m_s=(0.05, 0.15, 0.4)),
                              solver=SolverOptions(max_iter=5))
    files = write_optimum(opt, demo_library, tmp_path / "o", units="imperial")
    wb = _check_workbook(files["xlsx"], key_value=("solver",), summary=True)
    rep = wb["solver"]
    labels = [rep.cell(r, 1).value for r in range(1, rep.max_row + 1)]
    values = [rep.cell(r, 2).value for r in range(1, rep.max_row + 1)]
    assert labels[0] == "optimum score (time domain)" and np.isfinite(values[0])
    assert all(v is not None for v in values)  # every label has its value on its row
