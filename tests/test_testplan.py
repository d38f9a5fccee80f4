"""Tests of planner.testplan: the run sheet (layout, print setup, highlighted swaps, reading
it back as filled in), overwrite refusal, refusal of other workbooks, and the plan folder
(``write_plan``, its ``plan.toml`` read by ``ident.sim.virtual_rig.read_rig_plan``)."""

import dataclasses
import datetime

import matplotlib

matplotlib.use("Agg")  # headless; the module itself never touches pyplot

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from openpyxl import Workbook, load_workbook
from openpyxl.utils import get_column_letter

from ident.data.channels import CORNERS
from ident.models.adjustable import AdjustableShock, DynoPoints
from ident.models.library import ShockLibrary
from ident.sim.dampers import ClickerDamper
from planner.errors import PlannerError
from ident.sim.metrics import METRIC_QUANTITY
from ident.sim.virtual_rig import read_rig_plan
from ident.data.units import TO_SI
from planner.design import change_time_min, design_experiment
from planner.report import PAPER_SIZE, write_ranking
from planner.setups import Setup
from planner.testplan import (
    CHANGED_FILL,
    CLICK_FILL,
    RUN_SHEET_TITLE,
    read_run_sheet,
    run_sheet_rows,
    write_plan,
    write_run_sheet,
)
from planner.design import ScheduleOptions

#: The plan: a budget that buys identification runs and two validation runs.
BUDGET_MIN = 90.0
N_VALIDATION = 2
#: SI -> sheet units -> SI is a division and a multiplication by one constant: round-off.
RTOL_UNITS = 1e-12
#: run_sheet_rows rounds start times and durations to 0.01 min.
ATOL_MIN = 0.005 + 1e-9
#: Intervals made up for the sheet's interval rows: +-5 % of the prediction.
INTERVAL = 0.05
# key metrics the run sheet shows one page wide with its smallest text at >= 7 pt (of the
# fixture's six): all on A4, the four tire forces on the narrower US letter
MIN_SHEET_METRICS = {"SI": 6, "imperial": 4}
#: The clicker plan's setups, run after run (the last one repeats): clicks at one corner,
#: a swap, clicks and a swap together, both front clickers turned.
CLICK_SETUPS = [("TTX@ls=8,hs=2", "TTX@ls=8,hs=2", "B20", "B20"),
                ("TTX@ls=4,hs=2", "TTX@ls=8,hs=2", "B20", "B20"),
                ("TTX@ls=4,hs=2", "TTX@ls=8,hs=2", "TTX@ls=20,hs=4", "TTX@ls=20,hs=4"),
                ("TTX@ls=4,hs=0.5", "TTX@ls=8,hs=2", "B20", "TTX@ls=20,hs=4"),
                ("TTX@ls=0,hs=0", "TTX@ls=0,hs=0", "B20", "TTX@ls=20,hs=4")]


@pytest.fixture(scope="module")
def plan(paper_vehicle, demo_library):
    """A plan on the paper car and the demo crate, with validation runs (about 15 s)."""
    return design_experiment(paper_vehicle, demo_library, budget_min=BUDGET_MIN,
                             baseline="B20", schedule=ScheduleOptions(n_validation=N_VALIDATION))


@pytest.fixture(scope="module")
def plan_with_intervals(plan):
    """The plan with intervals on its predictions, as an identified model gives."""
    pred = plan.predictions.copy()
    for m in list(pred.columns):
        pred[f"{m}_lo"] = pred[m] * (1 - INTERVAL)
        pred[f"{m}_hi"] = pred[m] * (1 + INTERVAL)
    return dataclasses.replace(plan, predictions=pred)


@pytest.fixture(scope="module")
def click_plan(plan, demo_library):
    """The plan's runs refitted with a clicker (ls 0-20 clicks, hs 0-4 turns) at the front and
    the settings of CLICK_SETUPS: a run sheet's worth of swaps and click changes."""
    truth = ClickerDamper()
    sheet = truth.dyno_sheet(truth.sweep_settings(), (0.01, 0.025, 0.05, 0.1, 0.2, 0.3, 0.5))
    ttx = AdjustableShock("TTX", truth.adjusters,
                          DynoPoints(sheet["velocity"].to_numpy(), sheet["force"].to_numpy(),
                                     sheet[["ls", "hs"]].to_numpy(), ("ls", "hs"), ()),
                          default={"ls": 8, "hs": 2}, step={"ls": 1, "hs": 0.25})
    library = ShockLibrary(demo_library.entries() + [ttx])
    base = Setup("baseline", dict(zip(CORNERS, CLICK_SETUPS[0])))
    runs, prev = [], base
    for k, r in enumerate(plan.runs):
        setup = Setup(r.name, dict(zip(CORNERS, CLICK_SETUPS[min(k, len(CLICK_SETUPS) - 1)])))
        clicks = []
        for c, a, b in zip(CORNERS, prev.ids(), setup.ids()):
            if a != b and "@" in a and "@" in b:
                sa, sb = (dict(x.split("=") for x in n.split("@")[1].split(",")) for n in (a, b))
                clicks += [(c, adj) for adj in sa if sa[adj] != sb[adj]]
        changed = tuple(c for c, a, b in zip(CORNERS, prev.ids(), setup.ids()) if a != b)
        runs.append(dataclasses.replace(r, setup=setup, changed=changed, clicks=tuple(clicks),
                                        swap_min=change_time_min(prev, setup, plan.rig)))
        prev = setup
    return dataclasses.replace(plan, runs=tuple(runs), library=library, baseline=base)


def _blocks(ws):
    """Row of the table header and {run number: first row of its block}."""
    top = next(r for r in range(1, 30) if ws.cell(r, 1).value == "run")
    runs = {ws.cell(r, 1).value: r for r in range(top + 2, ws.max_row + 1)
            if isinstance(ws.cell(r, 1).value, int)}
    return top, runs


def test_plan_has_validation_runs(plan):
    purposes = [r.purpose for r in plan.runs]
    assert purposes.count("validation") == N_VALIDATION
    assert "identification" in purposes


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_run_sheet_reads_back_to_the_plans_runs(plan, tmp_path, units):
    path = write_run_sheet(plan, tmp_path / "test_plan.xlsx", units=units)
    wb = load_workbook(path)
    assert wb.sheetnames == ["summary", "run sheet", "crate", "information"]
    assert wb["run sheet"]["A1"].value.startswith(RUN_SHEET_TITLE)
    assert not list(tmp_path.glob(".*.tmp"))  # written atomically, nothing left over

    back = read_run_sheet(path)
    table = plan.table()
    assert back["run"].tolist() == table.index.tolist()
    for col in ("purpose", *CORNERS, "changed"):
        assert back[col].tolist() == table[col].tolist(), col
    assert back["drive_file"].tolist() == [f"drives/{d}.csv" for d in table["drive"]]
    assert_allclose(back["start_min"], table["start_min"], atol=ATOL_MIN)
    assert_allclose(back["duration_min"], table["duration_s"] / 60, atol=ATOL_MIN)
    assert_allclose(back["swap_min"], table["swap_min"], atol=ATOL_MIN)
    assert back["start"].tolist() == run_sheet_rows(plan)["start"].tolist()
    # the first key metrics that fit one page wide at a readable size (all are in the CSV)
    metrics = [m for m in plan.predictions.columns if m in back.columns]
    assert metrics == list(plan.predictions.columns)[:len(metrics)]
    assert len(metrics) >= MIN_SHEET_METRICS[units]
    assert_allclose(back[metrics].to_numpy(), plan.predictions[metrics].to_numpy(),
                    rtol=RTOL_UNITS)
    assert back[[f"{m}_measured" for m in metrics]].isna().all().all()  # nothing measured yet
    assert back[[f"shock_temp_{c}_c" for c in CORNERS]].isna().all().all()
    assert (back["notes"] == "").all()
    assert back.attrs["units"] == units


def test_run_sheet_header_block(plan, tmp_path):
    ws = load_workbook(write_run_sheet(plan, tmp_path / "a.xlsx"))["run sheet"]
    texts = [c.value for row in ws.iter_rows(max_row=8) for c in row if c.value is not None]
    header = read_run_sheet(tmp_path / "a.xlsx").attrs["header"]
    assert header["car"] == plan.settings["car"]
    assert header["date"] == datetime.date.today().isoformat()  # the plan has no date
    assert header["crate"] == plan.settings["crate"]
    assert header["budget"] == f"{BUDGET_MIN:g} min"
    assert header["planned rig time"].startswith(f"{plan.total_min:.1f} min")
    assert header["criterion"].startswith("D-optimal")
    assert header["baseline"] == "B20/B20/B20/B20"
    assert any("Filled shock" in str(t) for t in texts)
    # the plan says why it chose its runs (issue 36): the legend ends with it
    legend = next(str(t) for t in texts if "Filled shock" in str(t))
    assert legend.endswith("Why these runs: " + " ".join(plan.rationale))
    assert "Eqs. 21-24" in legend and "validate the predicted best" in legend
    dated = dataclasses.replace(plan, settings={**plan.settings, "date": "2009-04-20"})
    write_run_sheet(dated, tmp_path / "b.xlsx")
    assert read_run_sheet(tmp_path / "b.xlsx").attrs["header"]["date"] == "2009-04-20"


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_run_sheet_prints_one_page_wide(plan_with_intervals, tmp_path, units):
    wb = load_workbook(write_run_sheet(plan_with_intervals, tmp_path / "p.xlsx", units=units))
    ws = wb["run sheet"]
    top, runs = _blocks(ws)
    for sheet, orientation in (("run sheet", "landscape"), ("crate", "landscape"),
                               ("information", "landscape")):
        s = wb[sheet]
        ps = s.page_setup
        assert s.sheet_properties.pageSetUpPr.fitToPage, sheet
        assert (int(ps.fitToWidth), int(ps.fitToHeight)) == (1, 0), sheet
        assert ps.orientation == orientation, sheet
        assert int(ps.paperSize) == PAPER_SIZE[units], sheet
        assert s.print_area, sheet
        assert "&P" in s.oddFooter.right.text
    # the table's two header rows repeat on every page; the area covers the whole table
    assert ws.print_title_rows == f"${top}:${top + 1}"
    last_row = max(runs.values()) + 2  # predicted, interval, measured
    area = ws.print_area if isinstance(ws.print_area, str) else ws.print_area[0]
    assert area.endswith(f"$A$1:${get_column_letter(ws.max_column)}${last_row}")
    assert ws.max_row == last_row
    assert ws.freeze_panes == f"B{top + 2}"
    assert wb["crate"].print_title_rows == "$3:$4"
    # every block is whole on a page: page breaks fall just before a run's block
    for brk in ws.row_breaks.brk:
        assert brk.id + 1 in runs.values()


def test_changed_corners_are_highlighted(plan, tmp_path):
    ws = load_workbook(write_run_sheet(plan, tmp_path / "h.xlsx"))["run sheet"]
    top, runs = _blocks(ws)
    col = {ws.cell(top + 1, j).value: j for j in range(1, 12)}
    assert [r.number for r in plan.runs] == list(runs)
    n_changed = 0
    for r in plan.runs:
        for c in CORNERS:
            cell = ws.cell(runs[r.number], col[c])
            assert cell.value == dict(zip(CORNERS, r.setup.ids()))[c]
            filled = cell.fill.fill_type == "solid" and cell.fill.fgColor.rgb.endswith(
                CHANGED_FILL)
            assert filled == (c in r.changed), (r.number, c)
            assert cell.font.bold == (c in r.changed)
            n_changed += c in r.changed
    assert n_changed > 0  # the plan swaps shocks


def test_interval_rows_show_the_intervals(plan_with_intervals, tmp_path):
    plan = plan_with_intervals
    ws = load_workbook(write_run_sheet(plan, tmp_path / "i.xlsx", units="imperial"))[
        "run sheet"]
    top, runs = _blocks(ws)
    head = [ws.cell(top + 1, j).value for j in range(1, ws.max_column + 1)]
    j = head.index("tire force RMS LF [lbf]") + 1
    groups = [ws.cell(top, j).value for j in range(1, ws.max_column + 1)]
    label = groups.index("key metrics") + 1  # the group's first column labels the rows
    for r in plan.runs:
        row = runs[r.number]
        assert [ws.cell(row + k, label).value for k in range(3)] == [
            "predicted", "interval", "measured"]
        text = ws.cell(row + 1, j).value
        lo, hi = (float(x) for x in text.split("\u2013"))
        pred = plan.predictions.loc[r.number]
        assert lo == pytest.approx(pred["tire_force_rms_LF_lo"] / TO_SI["force"], rel=0.01)
        assert hi == pytest.approx(pred["tire_force_rms_LF_hi"] / TO_SI["force"], rel=0.01)
        assert ws.cell(row + 2, j).value is None  # the measured value: written on rig day
    back = read_run_sheet(tmp_path / "i.xlsx")
    assert back["run"].tolist() == [r.number for r in plan.runs]
    metrics = [m for m in plan.predictions.columns if m in METRIC_QUANTITY and m in back]
    assert len(metrics) >= MIN_SHEET_METRICS["imperial"]
    assert_allclose(back[metrics].to_numpy(), plan.predictions[metrics].to_numpy(),
                    rtol=RTOL_UNITS)


def test_measured_values_read_back_in_si(plan, tmp_path):
    path = write_run_sheet(plan, tmp_path / "m.xlsx", units="imperial")
    wb = load_workbook(path)
    ws = wb["run sheet"]
    top, runs = _blocks(ws)
    head = {ws.cell(top + 1, j).value: j for j in range(1, ws.max_column + 1)}
    groups = [ws.cell(top, j).value for j in range(1, ws.max_column + 1)]
    notes = groups.index("notes") + 1
    row = runs[3] + 1  # run 3's measured row (no intervals: predicted, measured)
    ws.cell(row, head["tire force RMS LF [lbf]"], 1000.0)
    ws.cell(row, head["tire force RMS RF [lbf]"], "1,5")  # a decimal comma is read
    ws.cell(row, head["LF"], 212)  # the shock's temperature: under it, in the measured row
    ws.cell(runs[3], notes, "LF damper weeps oil")
    wb.save(path)
    back = read_run_sheet(path).set_index("run")
    assert back.loc[3, "tire_force_rms_LF_measured"] == pytest.approx(1000.0 * TO_SI["force"])
    assert back.loc[3, "tire_force_rms_RF_measured"] == pytest.approx(1.5 * TO_SI["force"])
    assert back.loc[3, "shock_temp_LF_c"] == pytest.approx(100.0)
    assert np.isnan(back.loc[3, "shock_temp_RF_c"])
    assert back.loc[3, "notes"] == "LF damper weeps oil"
    assert np.isnan(back.loc[4, "tire_force_rms_LF_measured"])
    ws.cell(row, head["tire force RMS LF [lbf]"], "about 1000")
    wb.save(path)
    with pytest.raises(PlannerError, match=r"m\.xlsx.*run 3.*'about 1000', not a number"):
        read_run_sheet(path)


def test_write_run_sheet_refuses_an_existing_file(plan, tmp_path):
    path = tmp_path / "test_plan.xlsx"
    path.write_bytes(b"keep")
    with pytest.raises(FileExistsError, match=r"test_plan\.xlsx.*overwrite"):
        write_run_sheet(plan, path)
    assert path.read_bytes() == b"keep"
    write_run_sheet(plan, path, overwrite=True)
    assert read_run_sheet(path)["run"].tolist() == [r.number for r in plan.runs]


@pytest.mark.parametrize("kwargs, error, match", [
    ({"units": "metric"}, PlannerError, "unknown unit system"),
])
def test_write_run_sheet_bad_inputs(plan, tmp_path, kwargs, error, match):
    with pytest.raises(error, match=match):
        write_run_sheet(plan, tmp_path / "x.xlsx", **kwargs)
    with pytest.raises(TypeError, match="ExperimentPlan"):
        write_run_sheet(plan.table(), tmp_path / "x.xlsx")
    assert not (tmp_path / "x.xlsx").exists()


def _other_workbook(path):
    wb = Workbook()
    wb.active.title = "run sheet"
    wb.active["A1"] = "my own run sheet"
    wb.save(path)


def _ranking_workbook(path):
    t = pd.DataFrame({c: ["B20"] for c in CORNERS} | {"tire_force_rms_LF": [1000.0]},
                     index=pd.Index(["baseline"], name="setup"))
    write_ranking(t, path.parent / "ranking")
    (path.parent / "ranking" / "ranking.xlsx").rename(path)


def _not_a_workbook(path):
    path.write_text("run,start\n1,0:00\n")


def _run_sheet_without_shocks(path, plan):
    write_run_sheet(plan, path)
    wb = load_workbook(path)
    ws = wb["run sheet"]
    top, _ = _blocks(ws)
    for j in range(1, ws.max_column + 1):
        if ws.cell(top + 1, j).value == "LR":
            ws.cell(top + 1, j).value = "left rear"
    wb.save(path)


@pytest.mark.parametrize("make, match", [
    (_other_workbook, r"not a shockplan run sheet \(cell A1 is 'my own run sheet'"),
    (_ranking_workbook, r"not a shockplan run sheet \(no sheet 'run sheet'"),
    (_not_a_workbook, r"not a shockplan run sheet \(not an Excel workbook"),
    (None, "run sheet not found"),
    ("no LR", r"no column\(s\) \['LR'\]"),
])
def test_read_run_sheet_refuses_other_files(plan, tmp_path, make, match):
    path = tmp_path / "book.xlsx"
    if make == "no LR":
        _run_sheet_without_shocks(path, plan)
    elif make is not None:
        make(path)
    with pytest.raises(PlannerError, match=match) as info:
        read_run_sheet(path)
    assert "book.xlsx" in str(info.value)


def test_write_plan_files_and_rig_plan(plan, tmp_path):
    files = write_plan(plan, tmp_path / "plan", units="imperial")
    assert sorted(p.name for p in (tmp_path / "plan").iterdir()) == sorted(
        ["plan.toml", "shocks.toml", "test_plan.xlsx", "test_plan.csv", "design.png", "drives"])
    assert not [p for p in tmp_path.iterdir() if p.name != "plan"]  # the work folder is gone
    for key, path in files.items():
        assert path.exists(), key
    assert sorted(p.name for p in files["drives"].iterdir()) == sorted(
        f"{name}.csv" for name in plan.drives)

    rig = read_rig_plan(files["plan"])
    assert rig.units == "imperial"
    comments = " ".join(line[1:].strip() for line in files["plan"].read_text().splitlines()
                        if line.startswith("#"))
    assert "Why these runs:" in comments
    assert all(line in comments for line in plan.rationale)  # wrapped, every word kept
    assert [r.name for r in rig.runs] == [r.name for r in plan.runs]
    assert [r.setup for r in rig.runs] == [dict(zip(CORNERS, r.setup.ids())) for r in plan.runs]
    for rr, pr in zip(rig.runs, plan.runs):
        fs = plan.drives[pr.drive].fs_hz
        assert rr.duration_s == pytest.approx(pr.duration_s, abs=1.0 / fs)  # one sample
        assert rr.drive.duration_s == pytest.approx(plan.drives[pr.drive].duration_s,
                                                    abs=1.0 / fs)
    roles = {r.name: r.role for r in rig.runs}
    assert [roles[r.name] for r in plan.runs if r.purpose == "validation"] == [
        "validation"] * N_VALIDATION
    assert set(rig.shocks.ids) == set(plan.library.ids)

    back = read_run_sheet(files["xlsx"])
    csv = pd.read_csv(files["csv"], keep_default_na=False)
    assert back["run"].tolist() == csv["run"].tolist() == [r.number for r in plan.runs]
    assert back["drive_file"].tolist() == csv["drive_file"].tolist()
    assert all((tmp_path / "plan" / f).is_file() for f in back["drive_file"])
    with pytest.raises(FileExistsError, match="overwrite"):
        write_plan(plan, tmp_path / "plan")


# ---------------------------------------------------------------------------- clicks (issue 26)


def _fill(cell):
    return cell.fill.fgColor.rgb[-6:] if cell.fill.fill_type == "solid" else None


def test_click_sheet_shows_the_settings_and_highlights_the_changes(click_plan, tmp_path):
    """With a clicker on the car: per corner the shock and one column per adjuster; a swapped
    corner amber (shock and settings), a turned adjuster blue, the rest unfilled; the change's
    kind and time per run; the legend says which fill is which."""
    plan = click_plan
    ws = load_workbook(write_run_sheet(plan, tmp_path / "c.xlsx"))["run sheet"]
    top, runs = _blocks(ws)
    groups = [ws.cell(top, j).value for j in range(1, ws.max_column + 1)]
    heads = [ws.cell(top + 1, j).value for j in range(1, ws.max_column + 1)]
    col = {}
    for c in CORNERS:
        j = groups.index(c)
        assert heads[j:j + 3] == ["shock", "ls", "hs"], c
        col.update({c: j + 1, (c, "ls"): j + 2, (c, "hs"): j + 3})
    j_change = groups.index("change [min]") + 1
    kinds = set()
    for r in plan.runs:
        row = runs[r.number]
        swapped, clicked = set(r.swapped), set(r.clicks)
        for c, sid in zip(CORNERS, r.setup.ids()):
            base, _, rest = sid.partition("@")
            settings = {k: float(v) for k, v in (x.split("=") for x in rest.split(","))} \
                if rest else {}
            shock = ws.cell(row, col[c])
            assert shock.value == base
            assert _fill(shock) == (CHANGED_FILL if c in swapped else None), (r.number, c)
            for adj in ("ls", "hs"):
                cell = ws.cell(row, col[(c, adj)])
                assert cell.value == settings.get(adj), (r.number, c, adj)
                want = (CHANGED_FILL if c in swapped else CLICK_FILL if (c, adj) in clicked
                        else None)
                assert _fill(cell) == want, (r.number, c, adj)
                assert cell.font.bold == (want is not None)
        change = ws.cell(row, j_change)
        assert change.value == pytest.approx(r.swap_min)
        assert (f'"{r.change} "' in change.number_format) == bool(r.change)
        kinds.add(r.change)
    assert {"clicks", "swap", "swap+clicks"} <= kinds
    text = " ".join(str(c.value) for row in ws.iter_rows(max_row=top - 1) for c in row
                    if c.value is not None)
    assert "Amber: shock swapped" in text and "blue: adjuster turned" in text
    assert f"{plan.rig.click_change_s:g} s to turn an adjuster" in text


def test_click_sheet_reads_back_and_the_csv_has_the_settings(click_plan, tmp_path):
    plan = click_plan
    files = write_plan(plan, tmp_path / "plan")
    back = read_run_sheet(files["xlsx"])
    table = plan.table()
    for c in CORNERS:  # the names in full, from the shock and its adjusters' cells
        assert back[c].tolist() == table[c].tolist(), c
    assert back["changed"].tolist() == table["changed"].tolist()
    assert back["change"].tolist() == table["change"].tolist()
    assert_allclose(back["swap_min"], table["swap_min"], atol=ATOL_MIN)
    rows = run_sheet_rows(plan)
    assert rows["LF_ls"].tolist()[:2] == [8.0, 4.0] and rows["LR_ls"].isna().iloc[0]
    assert rows["clicks"].iloc[1] == "LF_ls" and rows["change"].iloc[1] == "clicks"
    rig = read_rig_plan(files["plan"])  # the rig plan names the settings the library resolves
    assert [r.setup for r in rig.runs] == [dict(zip(CORNERS, r.setup.ids())) for r in plan.runs]


# ---------------------------------------------------------------------------- issue 36


def test_click_sheet_shows_a_key_metric_with_its_values(click_plan, tmp_path):
    """With the adjusters' columns the run sheet still shows a key metric (at least one),
    its predictions in the 'predicted' rows, not the row labels alone (issue 36)."""
    rows = run_sheet_rows(click_plan)
    for units in ("SI", "imperial"):
        ws = load_workbook(write_run_sheet(click_plan, tmp_path / f"k_{units}.xlsx",
                                           units=units))["run sheet"]
        top, runs = _blocks(ws)
        groups = [ws.cell(top, j).value for j in range(1, ws.max_column + 1)]
        j = groups.index("key metrics") + 2  # the row labels, then the first metric
        metric = click_plan.predictions.columns[0]
        assert ws.cell(top + 1, j).value.startswith("tire force RMS LF"), units
        want = run_sheet_rows(click_plan, units=units)[metric]
        for k, (number, r) in enumerate(runs.items()):
            assert ws.cell(r, j - 1).value == "predicted"
            assert ws.cell(r, j).value == pytest.approx(want.iloc[k], rel=1e-12), number
        assert len(rows) == len(runs)


@pytest.mark.parametrize("which", ["plan", "click_plan"])
def test_header_texts_stay_in_their_cells(which, request, tmp_path):
    """No header text runs into the next column (issue 36): every group header is as wide
    as its longest word, and the header block's values are merged up to the next label and
    wrapped there."""
    from planner.report.sheets import text_width

    plan = request.getfixturevalue(which)
    ws = load_workbook(write_run_sheet(plan, tmp_path / "w.xlsx"))["run sheet"]
    top, _ = _blocks(ws)
    width = {j: ws.column_dimensions[get_column_letter(j)].width
             for j in range(1, ws.max_column + 1)}
    merged = {(m.min_row, m.min_col): m for m in ws.merged_cells.ranges}
    for j in range(1, ws.max_column + 1):
        group = ws.cell(top, j).value
        m = merged.get((top, j))
        if group is None or (m is not None and m.max_row > top):
            continue  # a single column's header over both rows: wrapped in its own width
        span = sum(width[c] for c in range(j, (m.max_col if m else j) + 1))
        longest = max(text_width(w, size=9, bold=True) for w in str(group).split())
        assert span >= longest, (group, span, longest)
    for r in range(2, 7):
        value = ws.cell(r, 3)
        assert value.alignment.wrap_text, r
        m = merged[(r, 3)]
        label = next(j for j in range(4, ws.max_column + 1) if ws.cell(r, j).value)
        assert m.max_col == label - 1, r  # up to the right-hand label
        assert ws.cell(r, label + 2).alignment.wrap_text


def test_start_times_note_is_true_to_the_schedule(plan, tmp_path):
    """The legend says what the start times count from: the session's start, run 1 after its
    changes and the rig's time a run (issue 36: it said 'from the first run's start' while
    run 1 started at 0:04)."""
    rig = dataclasses.replace(plan.rig, run_overhead_min=4.0)
    runs = tuple(dataclasses.replace(r, start_min=r.start_min + 4.0 * r.number)
                 for r in plan.runs)
    late = dataclasses.replace(plan, rig=rig, runs=runs)
    ws = load_workbook(write_run_sheet(late, tmp_path / "s.xlsx"))["run sheet"]
    legend = ws["A7"].value
    assert "first run's start" not in legend
    assert "Start times count from the session's start (0:00)" in legend
    first = run_sheet_rows(late)["start"].iloc[0]
    assert first != "0:00" and f"(run 1 at {first})" in legend
    assert "4 min a run besides its drive" in legend


#: The smallest text a printed sheet may have [pt] (issue 23's floor, planner.report.sheets).
SMALLEST_PRINTED_PT = 7.0
#: Rounding of the sizes read from LibreOffice's PDF (its text matrices carry 2 decimals).
PDF_PT_ATOL = 0.015


def _estimated_smallest_pt(ws):
    """The smallest printed text [pt] of a sheet set to one page wide, estimated as
    :mod:`planner.report.sheets` prints (a width unit = WIDTH_UNIT_PT, whole per cent)."""
    import math

    from openpyxl.utils.cell import range_boundaries

    from planner.report.sheets import (WIDTH_UNIT_PT, column_widths, printable_size_pt,
                                       smallest_font_pt)

    area = (ws.print_area if isinstance(ws.print_area, str) else ws.print_area[0])
    area = area.split("!")[-1].replace("$", "")
    lo, _, hi, _ = range_boundaries(area)
    units = "imperial" if int(ws.page_setup.paperSize) == PAPER_SIZE["imperial"] else "SI"
    room = printable_size_pt(units)[0]
    scale = min(100, math.floor(100 * room / (WIDTH_UNIT_PT * sum(column_widths(ws, lo, hi)))))
    return smallest_font_pt(ws, area) * scale / 100


def _pdf_text_sizes(path):
    """Every text size [pt] a PDF draws (LibreOffice's export: Tf size x text matrix x cm)."""
    import re
    import zlib

    data = path.read_bytes()
    op = re.compile(r"q\b|Q\b|([-\d.]+) ([-\d.]+) [-\d.]+ [-\d.]+ [-\d.]+ [-\d.]+ (cm|Tm)\b"
                    r"|/\S+ ([-\d.]+) Tf|\((?:[^()\\]|\\.)*\)\s*Tj|\[[^\]]*\]\s*TJ"
                    r"|<[0-9A-Fa-f]+>\s*Tj")
    sizes = []
    for m in re.finditer(rb"stream\r?\n(.*?)\r?\nendstream", data, re.S):
        try:
            text = zlib.decompress(m.group(1)).decode("latin-1")
        except zlib.error:
            continue
        cm, stack, tm, tf = 1.0, [], 1.0, None
        for tok in op.finditer(text):
            s = tok.group(0)
            if s == "q":
                stack.append(cm)
            elif s == "Q":
                cm = stack.pop() if stack else 1.0
            elif tok.group(3):
                scale = float(np.hypot(float(tok.group(1)), float(tok.group(2))))
                if tok.group(3) == "cm":
                    cm *= scale
                else:
                    tm = scale
            elif tok.group(4):
                tf = float(tok.group(4))
            elif tf is not None:
                sizes.append(tf * tm * cm)
    return sizes


def test_click_run_sheet_prints_at_7_pt_on_us_letter(click_plan, tmp_path):
    """Issue 36: the clicks run sheet (a corner's shock and its adjusters' columns) printed on
    US letter through LibreOffice had text slightly under 7 pt; its smallest text prints at
    >= 7 pt, estimated as the sheets module does and, where LibreOffice is installed, as it
    prints (its PDF's text sizes)."""
    import shutil
    import subprocess

    path = write_run_sheet(click_plan, tmp_path / "clicks.xlsx", units="imperial")
    ws = load_workbook(path)["run sheet"]
    assert int(ws.page_setup.paperSize) == PAPER_SIZE["imperial"]
    assert _estimated_smallest_pt(ws) >= SMALLEST_PRINTED_PT
    soffice = shutil.which("soffice") or shutil.which("libreoffice")
    if soffice is None:
        pytest.skip("LibreOffice is not installed: the estimate alone is checked")
    profile = tmp_path / "lo-profile"  # its own profile: no lock shared with a running one
    subprocess.run([soffice, f"-env:UserInstallation=file://{profile}", "--headless",
                    "--convert-to", "pdf", "--outdir", str(tmp_path), str(path)],
                   check=True, capture_output=True, timeout=300)
    sizes = _pdf_text_sizes(tmp_path / "clicks.pdf")
    assert len(sizes) > 50
    assert min(sizes) >= SMALLEST_PRINTED_PT - PDF_PT_ATOL, sorted(sizes)[:5]
