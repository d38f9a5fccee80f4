"""Tests of planner.report: predictions CSV (spec column order, units, precision), the
ranking folder (CSV, workbook layout and print setup read back with openpyxl, PNGs),
overwrite refusal and bad inputs."""


import matplotlib

matplotlib.use("Agg")  # headless; the module itself never touches pyplot

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from openpyxl import load_workbook
from openpyxl.utils import get_column_letter

import planner.report.ranking as report_mod
from planner.report.ranking import DATA_PT, HEADER_PT
from ident.data.channels import CORNERS
from planner.errors import PlannerError
from ident.sim.metrics import METRIC_NAMES, METRIC_QUANTITY
from ident.data.units import TO_SI, UNIT_LABELS
from planner.objective import default_objective, pareto_front, score_setups
from planner.report import (
    PAPER_SIZE,
    column_label,
    metric_of_column,
    ranking_to_units,
    text_width,
    write_predictions_csv,
    write_ranking,
)

N_SETUPS = 20
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
RTOL_UNITS = 1e-15  # one division by a constant factor: round-off only
SHOCK_IDS = ("B20", "D8", "C12")


@pytest.fixture
def table(rng):
    """20 setups: shocks, all spec metrics (SI) with intervals, then default-objective scores."""
    names = ["baseline"] + [f"setup-{k:02d}" for k in range(1, N_SETUPS)]
    shocks = {c: rng.choice(SHOCK_IDS, N_SETUPS) for c in CORNERS}
    typical = {"force": 450.0, "displacement": 0.004, "velocity": 0.12}
    metrics = {m: typical[METRIC_QUANTITY[m]] * rng.uniform(0.8, 1.2, N_SETUPS)
               for m in reversed(METRIC_NAMES)}  # scrambled order: the writer reorders
    t = pd.DataFrame({**metrics, **shocks}, index=pd.Index(names, name="setup"))
    t.loc[["setup-02", "setup-05", "setup-11"], "shock_travel_rms_LF"] = (
        1.4 * t.loc["baseline", "shock_travel_rms_LF"])  # over the default 1.25 x limit
    for m in METRIC_NAMES:
        t[f"{m}_lo"] = t[m] * 0.95
        t[f"{m}_hi"] = t[m] * 1.07
    scores = score_setups(t, default_objective())
    t = t.join(scores.table)
    t["unresolved"] = ""
    t.loc["setup-03", "unresolved"] = "screening interval overlaps the best"
    assert (~t["feasible"]).sum() > 0  # some setups violate the travel limits
    return t


def test_metric_of_column_and_order():
    assert metric_of_column("shock_travel_rms_RR_lo") == "shock_travel_rms_RR"
    assert metric_of_column("tire_force_rms_norm_LF") == "tire_force_rms_norm_LF"
    assert metric_of_column("rank") is None and metric_of_column("LF") is None
    assert metric_of_column(3) is None


def test_ranking_to_units_converts_metrics_and_intervals_only(table):
    imp = ranking_to_units(table, "imperial")
    for col in table.columns:
        m = metric_of_column(col)
        if m is None:
            assert imp[col].equals(table[col]), col
        else:
            assert_allclose(imp[col], table[col] / TO_SI[METRIC_QUANTITY[m]], rtol=RTOL_UNITS)
    si = ranking_to_units(table, "si")
    pd.testing.assert_frame_equal(si, table)
    assert si is not table


def test_predictions_csv_spec_columns_units_and_precision(table, tmp_path):
    si_path = write_predictions_csv(table, tmp_path / "pred_si.csv")
    imp_path = write_predictions_csv(table, tmp_path / "pred_imp.csv", units="imperial")
    for path, units in ((si_path, "SI"), (imp_path, "imperial")):  # the header first, then
        lines = path.read_text().splitlines()  # the unit system as the last column
        assert lines[0].startswith("setup,") and lines[0].endswith(",units")
        assert all(line.endswith(f",{units}") for line in lines[1:])
    si = pd.read_csv(si_path, keep_default_na=False, na_values=[""])
    imp = pd.read_csv(imp_path, keep_default_na=False, na_values=[""])
    n_m = len(METRIC_NAMES)
    assert list(si.columns[:5]) == ["setup", *CORNERS]
    assert list(si.columns[5:5 + n_m]) == list(METRIC_NAMES)  # the spec's order
    assert set(si.columns[5 + n_m:]) == {c for c in table.columns
                                         if c not in CORNERS and c not in METRIC_NAMES} | {
                                             "units"}
    assert si.columns[-1] == "units" and set(si["units"]) == {"SI"}
    assert si["setup"].tolist() == table.index.tolist()  # row order as given
    for c in CORNERS:
        assert si[c].tolist() == table[c].tolist()
    for m in METRIC_NAMES:  # full precision: bit-identical round trip
        assert_array_equal(si[m].to_numpy(), table[m].to_numpy())
        assert_allclose(imp[m], si[m] / TO_SI[METRIC_QUANTITY[m]], rtol=RTOL_UNITS)
        assert_allclose(imp[f"{m}_hi"], si[f"{m}_hi"] / TO_SI[METRIC_QUANTITY[m]],
                        rtol=RTOL_UNITS)
    assert_array_equal(imp["score"], si["score"])
    assert list(imp.columns) == list(si.columns)
    assert not list(tmp_path.glob(".*.tmp"))


def test_predictions_csv_accepts_a_setup_column_and_refuses_overwrite(table, tmp_path):
    path = tmp_path / "pred.csv"
    write_predictions_csv(table.reset_index(), path)
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match=r"pred\.csv.*--overwrite"):
        write_predictions_csv(table, path)
    assert path.read_bytes() == before
    write_predictions_csv(table.iloc[:3], path, overwrite=True)
    assert len(pd.read_csv(path)) == 3


def test_write_ranking_files(table, tmp_path):
    out = tmp_path / "report"
    paths = write_ranking(table, out, units="imperial", objective=default_objective(), top=8)
    assert set(paths) == {"csv", "xlsx", "pareto", "top_setups"}
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["ranking.csv", "ranking.xlsx", "pareto.png", "top_setups.png"])  # no temp files
    for key in ("pareto", "top_setups"):
        data = paths[key].read_bytes()
        assert len(data) > 1000 and data[:8] == PNG_MAGIC
    assert paths["csv"].read_text().startswith("rank,setup,")
    assert paths["csv"].read_text().splitlines()[1].endswith(",imperial")
    csv = pd.read_csv(paths["csv"], keep_default_na=False, na_values=[""])
    assert list(csv.columns[:6]) == ["rank", "setup", *CORNERS]
    assert list(csv.columns[6:6 + len(METRIC_NAMES)]) == list(METRIC_NAMES)
    assert csv["rank"].tolist() == list(range(1, N_SETUPS + 1))
    ranked = table.sort_values("rank")
    assert csv["setup"].tolist() == ranked.index.tolist()
    m = "ride_height_rms_front"
    assert_allclose(csv[m], ranked[m] / TO_SI["displacement"], rtol=RTOL_UNITS)


def test_ranking_workbook_layout(table, tmp_path):
    obj = default_objective()
    paths = write_ranking(table, tmp_path, units="imperial", objective=obj)
    wb = load_workbook(paths["xlsx"])
    assert wb.sheetnames == ["summary", "ranking", "intervals", "about"]
    ws = wb["ranking"]
    header = [c.value for c in ws[1]]
    # key columns first: rank, setup, shocks, scores, feasible, the weighted metrics
    weighted = [f"{column_label(m)} [{'lbf' if 'force' in m else 'in'}]" for m in obj.weights]
    assert header[:10] == ["rank", "setup", *CORNERS, "score", "score grip", "score platform",
                           "feasible"]
    assert header[10:10 + len(weighted)] == weighted
    assert "tire force RMS LF [lbf]" in header
    assert "ride height RMS front [in]" in header
    assert "shock velocity RMS RR [in/s]" in header  # the other metrics follow
    assert header.index("shock travel RMS LF [in]") > header.index("ride height RMS rear [in]")
    assert header[-2:] == ["unresolved", "violations"]  # long text last
    assert not any(str(h).endswith(("lo [in]", "hi [in]", "_lo", "_hi")) for h in header)
    assert all(c.font.bold and c.alignment.wrap_text for c in ws[1])
    assert ws.freeze_panes == "C2"  # below the header, right of the setup column
    assert ws.auto_filter.ref == f"A1:{ws.cell(1, len(header)).column_letter}{N_SETUPS + 1}"
    col = {h: k + 1 for k, h in enumerate(header)}
    assert ws.cell(2, col["tire force RMS LF [lbf]"]).number_format == "0.000"
    # ~0.16 in: 4 significant digits need 4 decimals
    assert ws.cell(2, col["ride height RMS front [in]"]).number_format == "0.0000"
    assert ws.cell(2, col["score"]).number_format == "0.0000"
    assert ws.cell(2, col["rank"]).number_format == "0"
    ranked = table.sort_values("rank")
    values = [ws.cell(r, col["tire force RMS LF [lbf]"]).value for r in range(2, N_SETUPS + 2)]
    assert_allclose(values, ranked["tire_force_rms_LF"] / TO_SI["force"], rtol=RTOL_UNITS)
    # widths fit the shown values and the header's longest word (the header wraps)
    for h in ("tire force RMS LF [lbf]", "setup", "score platform"):
        j = col[h]
        width = ws.column_dimensions[ws.cell(1, j).column_letter].width
        fmt = ws.cell(2, j).number_format
        shown = [format(v, f".{len(fmt) - 2}f") if isinstance(v, float) else str(v)
                 for v in (ws.cell(r, j).value for r in range(2, N_SETUPS + 2))]
        assert width >= max(text_width(t, size=DATA_PT) for t in shown), h
        assert width >= max(text_width(w, size=HEADER_PT, bold=True) for w in h.split()), h
    # infeasible rows greyed, feasible ones not
    for r in range(2, N_SETUPS + 2):
        feasible = ws.cell(r, col["feasible"]).value
        fill = ws.cell(r, col["setup"]).fill
        assert (fill.fill_type == "solid") == (not feasible)
    # the intervals: rank, setup, then lo and hi under each metric's label, rows as ranked
    iv = wb["intervals"]
    groups = [c.value for c in iv[1]]
    subs = [c.value for c in iv[2]]
    assert groups[:2] == ["rank", "setup"] and subs[2:4] == ["lo", "hi"]
    assert groups[2] == "tire force RMS LF [lbf]"
    assert "shock velocity RMS RR [in/s]" in groups
    j = groups.index("ride height RMS front [in]") + 1
    assert iv.freeze_panes == "C3"
    lo = [iv.cell(r, j).value for r in range(3, N_SETUPS + 3)]
    hi = [iv.cell(r, j + 1).value for r in range(3, N_SETUPS + 3)]
    assert [iv.cell(r, 2).value for r in range(3, N_SETUPS + 3)] == ranked.index.tolist()
    assert_allclose(lo, ranked["ride_height_rms_front_lo"] / TO_SI["displacement"],
                    rtol=RTOL_UNITS)
    assert_allclose(hi, ranked["ride_height_rms_front_hi"] / TO_SI["displacement"],
                    rtol=RTOL_UNITS)
    about = wb["about"]
    cells = [[c.value for c in row] for row in about.iter_rows()]
    assert ["units", "imperial"] in [row[:2] for row in cells]
    assert ["objective", "grip and platform"] in [row[:2] for row in cells]
    assert [0.125, "tire_force_rms_LF", "grip"] in [row[:3] for row in cells]
    assert any(row[1] == "shock_travel_rms_LF" and row[2] == 1.25 for row in cells)
    assert ["tire force RMS LF", "lbf", "tire_force_rms_LF"] in [row[:3] for row in cells]


def test_ranking_workbook_prints_across_pages(table, tmp_path):
    """The ranking and intervals sheets are too wide for one page at a readable size: they
    print across pages at a fixed scale, rank and setup repeated on every page, breaking
    between metric families; the about sheet fits one page wide. Every sheet: landscape,
    the header rows repeated, a print area over the whole table, paper by units (A4 for SI,
    letter for imperial), narrow margins, the sheet and page number. (The printed size is
    checked in tests/test_sheets.py.)"""
    for units, paper in (("imperial", PAPER_SIZE["imperial"]), ("SI", PAPER_SIZE["SI"])):
        paths = write_ranking(table, tmp_path / units, units=units, objective=default_objective())
        wb = load_workbook(paths["xlsx"])
        expect = {"ranking": (False, "$1:$1", N_SETUPS + 1),
                  "intervals": (False, "$1:$2", N_SETUPS + 2),
                  "about": (True, None, None)}
        for name, (fit, titles, last_row) in expect.items():
            ws = wb[name]
            ps = ws.page_setup
            assert bool(ws.sheet_properties.pageSetUpPr.fitToPage) == fit, name
            if fit:
                assert (int(ps.fitToWidth), int(ps.fitToHeight)) == (1, 0), name
            else:
                assert ws.print_title_cols == "$A:$B", name  # rank, setup
                assert ws.col_breaks.brk and 0 < int(ps.scale) <= 100, name
            assert ps.orientation == "landscape", name
            assert int(ps.paperSize) == paper, name
            assert ws.print_title_rows == titles, name
            area = ws.print_area if isinstance(ws.print_area, str) else ws.print_area[0]
            last_col = get_column_letter(ws.max_column)
            if last_row is not None:
                assert area.endswith(f"$A$1:${last_col}${last_row}"), (name, area)
            assert ws.page_margins.left <= 0.5 and ws.page_margins.right <= 0.5
            assert "&P" in ws.oddFooter.right.text and "&A" in ws.oddFooter.right.text
            assert not ws.print_options.gridLines  # the cells have borders instead
        # the pages break between metric families: a page's last column and the next
        # page's first are of different families
        ws = wb["ranking"]
        heads = [ws.cell(1, j).value for j in range(1, ws.max_column + 1)]
        for brk in ws.col_breaks.brk:
            left, right = heads[brk.id - 1], heads[brk.id]
            assert left.split(" RMS")[0] != right.split(" RMS")[0], (left, right)
        assert wb["ranking"].cell(2, 1).border.bottom.style == "thin"


def test_ranking_without_scores_and_si(table, tmp_path):
    plain = table[[*CORNERS, *METRIC_NAMES]]
    paths = write_ranking(plain, tmp_path, top=3)
    assert set(paths) == {"csv", "xlsx", "top_setups"}  # no score columns: no Pareto plot
    wb = load_workbook(paths["xlsx"])
    assert wb.sheetnames == ["summary", "ranking", "about"]  # no intervals: no intervals sheet
    ws = wb["ranking"]
    assert ws.freeze_panes == "B2"  # no rank column: setup first
    header = [c.value for c in ws[1]]
    assert header[:5] == ["setup", *CORNERS]
    # no objective: the metrics in the spec's order
    assert header[5:5 + len(METRIC_NAMES)] == [
        f"{column_label(m)} [{UNIT_LABELS['SI'][METRIC_QUANTITY[m]]}]" for m in METRIC_NAMES]
    assert "tire force RMS LF [N]" in header
    ride = header.index("ride height RMS front [m]") + 1
    assert ws.cell(2, ride).number_format == "0.000000"  # ~0.004 m: 4 significant digits
    assert int(ws.page_setup.paperSize) == PAPER_SIZE["SI"]


def test_write_ranking_refuses_overwrite_before_writing_anything(table, tmp_path):
    (tmp_path / "pareto.png").write_bytes(b"keep")
    with pytest.raises(FileExistsError, match=r"pareto\.png.*--overwrite"):
        write_ranking(table, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pareto.png"]
    paths = write_ranking(table, tmp_path, overwrite=True)
    assert paths["pareto"].read_bytes()[:8] == PNG_MAGIC


def test_baseline_normalization_of_top_setups(table):
    obj = default_objective()
    assert report_mod._normalizing_setup(table, obj, None) == "baseline"
    assert report_mod._normalizing_setup(table.iloc[::-1], obj, None) == "baseline"
    assert report_mod._normalizing_setup(table, None, None) is None
    with pytest.raises(PlannerError, match="baseline setup 'nope'"):
        report_mod._normalizing_setup(table, None, "nope")
    assert report_mod._key_metrics(table, obj) == list(obj.weights)
    fig = report_mod._top_figure(table, list(obj.weights), "baseline", 5)
    from matplotlib.container import ErrorbarContainer

    ax = fig.axes[0]
    marks = [c for c in ax.containers if isinstance(c, ErrorbarContainer)][0]
    # the first metric's points: the change from the baseline [%], best setups first, with
    # the intervals' whiskers from _lo/_hi
    assert marks.has_yerr
    best = table.sort_values("rank").iloc[:5]
    m = list(obj.weights)[0]
    points = marks.lines[0].get_ydata()
    assert_allclose(points, 100 * (best[m] / table.loc["baseline", m] - 1), rtol=1e-12)
    # zoomed to the values (not from 0 % or -100 %), every whisker inside the axes
    lo, hi = ax.get_ylim()
    span = 100 * (best[[f"{m}_hi"]].to_numpy().max() / table.loc["baseline", m] - 1) - \
        100 * (best[[f"{m}_lo"]].to_numpy().min() / table.loc["baseline", m] - 1)
    assert hi - lo < 100 and lo > -100
    assert span > 0.05 * (hi - lo)  # the intervals take a visible share of the axis
    assert ax.get_xticklabels()[0].get_text() == str(best.index[0])
    assert "tire force RMS LF" in [t.get_text() for t in fig.legends[0].get_texts()]


def test_top_and_pareto_labels_shorten_long_names_with_a_key(table, tmp_path):
    """Click settings' names (~50 characters) are shown as #rank, with the key beneath."""
    obj = default_objective()
    long = table.rename(index=lambda n: "TTX@ls=10,hs=0/TTX@ls=10,hs=0/TTX@ls=9,hs=0/"
                        f"TTX@ls=9,hs=0-{n}")
    fig = report_mod._top_figure(long, list(obj.weights), None, 5)
    ticks = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    best = long.sort_values("rank")
    assert ticks[0] == f"#{int(best['rank'].iloc[0])}"
    key = "\n".join(t.get_text() for sub in fig.subfigs for t in sub.texts)
    assert all(name in key for name in best.index[:5])
    same = "/".join(["TTX@ls=10,hs=0"] * 2 + ["TTX@ls=9,hs=0"] * 2)  # said once per axle
    assert report_mod.short_labels([same])[1] == ["#1  front TTX@ls=10,hs=0, rear TTX@ls=9,hs=0"]
    fig = report_mod._pareto_figure(long, None, obj)
    ax = fig.axes[0]
    assert all(t.get_text().startswith("#") for t in ax.texts)
    assert "tire force RMS" in ax.get_xlabel() and "score_grip" not in ax.get_xlabel()
    assert "ride height RMS" in ax.get_ylabel()


def _crowded_scores(rng, n, *, grid=False):
    """A ranking of `n` setups crowded around the best ones (scores only); on a grid: every
    place in the axes is taken by a marker, so no label fits beside its point."""
    if grid:
        side = int(np.ceil(np.sqrt(n)))
        g, p = (a.ravel()[:n] for a in np.meshgrid(np.linspace(0.45, 0.55, side),
                                                  np.linspace(0.40, 0.50, side)))
    else:
        g = 0.5 + 0.02 * rng.standard_normal(n)
        p = 0.45 + 0.02 * rng.standard_normal(n)
    t = pd.DataFrame({"score_grip": g, "score_platform": p, "score": g + p,
                      "feasible": rng.uniform(size=n) > 0.1},
                     index=pd.Index([f"setup-{k:04d}" for k in range(n)], name="setup"))
    t["rank"] = t["score"].rank(method="first").astype(int)
    return t


def _label_and_marker_boxes(fig):
    """The label texts' boxes (text only, no leader line) and the markers' boxes [px]."""
    from matplotlib.text import Text
    from matplotlib.transforms import Bbox

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    labels = [Text.get_window_extent(t, renderer) for t in ax.texts]
    markers = []
    for coll in ax.collections:
        offs = np.asarray(coll.get_offsets(), dtype=float)
        half = np.sqrt(np.broadcast_to(coll.get_sizes(), (len(offs),))) / 2 * fig.dpi / 72
        for (x, y), h in zip(ax.transData.transform(offs), half):
            markers.append(Bbox([[x - h, y - h], [x + h, y + h]]))
    return labels, markers


@pytest.mark.parametrize("n, grid", [(60, False), (400, False), (2500, True)])
def test_pareto_labels_overlap_no_marker_and_no_other_label(rng, n, grid):
    """The best setups are labelled; no label box touches another or a marker, at the
    figure's dpi and at the dpi the PNG is written with; on a full grid the labels with no
    free place go to the margin beside the axes."""
    table = _crowded_scores(rng, n, grid=grid)
    fig = report_mod._pareto_figure(table, "setup-0010")
    ax = fig.axes[0]
    best = table.sort_values("rank").index[:report_mod.N_PARETO_LABELS]
    front = table.index[pareto_front(table, "score_grip", "score_platform")]
    labelled = {t.get_text() for t in ax.texts}
    assert set(best) <= labelled and labelled <= set(best) | set(front)
    # every point of the front labelled, up to the most labels
    assert len(labelled) == min(report_mod.MAX_PARETO_LABELS, len(set(best) | set(front)))
    for dpi in (fig.dpi, 110):
        fig.set_dpi(dpi)
        labels, markers = _label_and_marker_boxes(fig)
        for i, a in enumerate(labels):
            assert all(not a.overlaps(b) for b in labels[i + 1:]), (dpi, ax.texts[i].get_text())
            assert all(not a.overlaps(m) for m in markers), (dpi, ax.texts[i].get_text())
            assert fig.bbox.contains(a.x0, a.y0) and fig.bbox.contains(a.x1, a.y1)
    axes_box = ax.get_window_extent()
    inside = [axes_box.contains(b.x0, b.y0) and axes_box.contains(b.x1, b.y1) for b in labels]
    # the grid leaves no free place beside most points: those labels go to the margin
    assert sum(inside) < len(inside) if grid else all(inside)


def test_pareto_figure_is_deterministic(rng, tmp_path):
    table = _crowded_scores(rng, 400)
    for name in ("a.png", "b.png"):
        report_mod._save_png(report_mod._pareto_figure(table, "setup-0010"), tmp_path / name,
                             overwrite=False)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()


@pytest.mark.parametrize("change, kwargs, error, match", [
    (lambda t: t.drop(columns="RR"), {}, PlannerError, r"no shock column\(s\) \['RR'\]"),
    (lambda t: t.iloc[:0], {}, PlannerError, "no rows"),
    (lambda t: t.rename(index={"setup-01": "baseline"}), {}, PlannerError, "repeats setup"),
    (lambda t: t.assign(tire_force_rms_LF="x"), {"units": "imperial"}, PlannerError,
     "not numeric"),
    (lambda t: t, {"units": "metric"}, ValueError, "unknown unit system"),
    (lambda t: t.to_numpy(), {}, TypeError, "must be a pandas DataFrame"),
])
def test_predictions_csv_bad_inputs(table, tmp_path, change, kwargs, error, match):
    with pytest.raises(error, match=match):
        write_predictions_csv(change(table), tmp_path / "p.csv", **kwargs)
    assert not (tmp_path / "p.csv").exists()


@pytest.mark.parametrize("kwargs, error, match", [
    ({"top": 0}, ValueError, "top must be an integer >= 1"),
    ({"top": 2.5}, ValueError, "top must be"),
    ({"objective": "grip"}, TypeError, "objective must be"),
    ({"baseline": "nope"}, PlannerError, "not in the table"),
])
def test_write_ranking_bad_inputs(table, tmp_path, kwargs, error, match):
    with pytest.raises(error, match=match):
        write_ranking(table, tmp_path / "r", **kwargs)
    assert not (tmp_path / "r").exists()

