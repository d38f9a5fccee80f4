"""Tests of planner.report.summary: the verdicts, the summary plot (the key metrics, or the
predicted histograms' hook) and the one-page sheet every workbook opens with."""

import numpy as np
import pandas as pd
import pytest
from openpyxl import Workbook

from ident.data.channels import CORNERS
from planner.report.summary import (HISTOGRAM_COLUMNS, N_SUMMARY_ROWS, SUMMARY_SHEET,
                                    summary_figure, summary_parts, verdicts,
                                    write_summary_sheet)


@pytest.fixture
def ranked():
    """Five setups best first; 'b' is not resolved from the best, 'e' infeasible."""
    return pd.DataFrame({"score": [0.90, 0.91, 0.95, 1.0, 0.85],
                         "feasible": [True, True, True, True, False],
                         "unresolved": ["b", "a", "", "", ""],
                         "tire_force_rms_LF": [400.0, 410.0, 420.0, 430.0, 380.0],
                         "ride_height_rms_front": [0.003, 0.0031, 0.0032, 0.0034, 0.0029]},
                        index=pd.Index(["a", "b", "c", "base", "e"], name="setup"))


def test_verdicts_against_the_best_and_the_baseline(ranked):
    assert verdicts(ranked, "a").tolist() == ["reference", "tied", "worse", "worse",
                                              "infeasible"]
    assert verdicts(ranked, "base").tolist() == ["better", "better", "better", "reference",
                                                 "infeasible"]
    # without the unresolved pairs (a known model), the scores alone decide
    assert verdicts(ranked.drop(columns="unresolved"), "a").tolist()[1] == "worse"
    with pytest.raises(KeyError, match="'nope' is not in the table"):
        verdicts(ranked, "nope")


def test_verdicts_read_the_interval_verdicts_when_present(ranked):
    """The ranking's ``verdict`` / ``verdict_baseline`` columns (intervals of the score
    differences) decide over the ``unresolved`` pairs: here they call 'c' tied with the best
    and 'b' worse, against the pairs' 'b' tied and 'c' worse; against another setup, or
    without the columns, the pairs and the scores decide as before."""
    t = ranked.assign(verdict=["best", "worse", "tied", "worse", "infeasible"],
                      verdict_baseline=["better", "tied", "better", "baseline", "infeasible"])
    assert verdicts(t, "a").tolist() == ["reference", "worse", "tied", "worse", "infeasible"]
    assert verdicts(t, "base", worse="slower", better="faster").tolist() == [
        "faster", "tied", "faster", "reference", "infeasible"]
    assert verdicts(t, "c").tolist() == verdicts(ranked, "c").tolist()  # no column for 'c'
    parts = summary_parts(t, best="a", baseline="base", title="t")
    assert parts["table"]["vs best"].tolist() == ["best", "worse", "tied", "worse",
                                                  "infeasible"]
    assert any("score difference contains 0" in n for n in parts["notes"])
    assert "best: 'a'; tied with it: 'c'" in parts["notes"]


def test_summary_parts_rows_units_and_notes(ranked):
    parts = summary_parts(ranked, best="a", baseline="base", units="imperial",
                          metrics=["tire_force_rms_LF", "ride_height_rms_front"], title="t",
                          used=[("model", "m.npz")])
    t = parts["table"]
    assert t["setup"].tolist() == ["a", "b", "c", "base", "e"]
    assert t["vs best"].tolist() == ["best", "tied", "worse", "worse", "infeasible"]
    assert t["tire_force_rms_LF"].iloc[0] == pytest.approx(400.0 / 4.4482216152605)
    assert "tire force RMS LF [lbf]" in parts["headers"]
    assert any("unresolved" in n for n in parts["notes"])
    assert parts["figure"] is not None and parts["used"] == [("model", "m.npz")]


def test_summary_figure_takes_the_histogram_table():
    """The hook for the predicted histograms: one panel per corner, the best and the baseline
    as step histograms (percent of time), the open end bins drawn one bin wide."""
    edges = np.linspace(-0.25, 0.25, 21)
    rows = []
    for setup, shift in (("best", 0.0), ("base", 0.02)):
        for c in CORNERS:
            share = np.exp(-((edges[:-1] + 0.0125 - shift) / 0.08) ** 2)
            share /= share.sum()
            lo, hi = edges[:-1].copy(), edges[1:].copy()
            lo[0], hi[-1] = np.nan, np.nan  # open end bins
            rows += [{"setup": setup, "corner": c, "velocity_lo": a, "velocity_hi": b,
                      "share": s} for a, b, s in zip(lo, hi, share)]
    hist = pd.DataFrame(rows)
    fig = summary_figure(best="best", baseline="base", histograms=hist)
    assert [ax.get_title() for ax in fig.axes] == list(CORNERS)
    steps = [p for p in fig.axes[0].patches]
    assert len(steps) == 2  # the best and the baseline
    top = max(float(np.max(p.get_data()[0])) for p in steps)
    assert top == pytest.approx(100 * hist["share"].max(), rel=1e-12)
    with pytest.raises(ValueError, match="lacks"):
        summary_figure(best="best", baseline="base", histograms=hist.drop(columns="share"))
    assert HISTOGRAM_COLUMNS == ("setup", "corner", "velocity_lo", "velocity_hi", "share")


@pytest.mark.parametrize("best", ["L28/L28/L28/L28",
                                  "C2/C2/R1/R1 heave_front=H0 heave_rear=HD",
                                  "C2/C2/R1/R1_heave_front=H0_heave_rear=HD_HS-F2_spring"])
@pytest.mark.parametrize("kind", ["histograms", "metrics"])
def test_summary_figure_title_stays_inside_the_figure(ranked, best, kind):
    """A long setup name (third-element columns in it) wraps the title instead of running
    past the figure's edges (the summary page cut it at the left); a short one keeps it on
    one line."""
    edges = np.linspace(-0.25, 0.25, 11)
    hist = pd.DataFrame([{"setup": s, "corner": c, "velocity_lo": a, "velocity_hi": b,
                          "share": 0.1} for s in (best, "B20/B20/B20/B20") for c in CORNERS
                         for a, b in zip(edges[:-1], edges[1:])])
    metrics = ranked.iloc[:2, 3:].set_axis([best, "B20/B20/B20/B20"])
    fig = summary_figure(None if kind == "histograms" else metrics, best=best,
                         baseline="B20/B20/B20/B20",
                         histograms=hist if kind == "histograms" else None)
    fig.canvas.draw()
    title = fig._suptitle
    box = title.get_window_extent()
    assert box.x0 >= 0 and box.x1 <= fig.bbox.width
    assert ("\n" in title.get_text()) == (len(best) > 20)


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_summary_sheet_is_first_and_set_to_one_page(ranked, units):
    wb = Workbook()
    wb.active.title = "table"
    long = pd.concat([ranked] * 4)
    long.index = [f"s{k}" for k in range(len(long))]
    parts = summary_parts(long, best="s0", baseline="s13", units=units,
                          metrics=["tire_force_rms_LF"], title="summary of a run",
                          notes=["a note"])
    scale = write_summary_sheet(wb, units=units, footer="f", **parts)
    ws = wb.worksheets[0]
    assert ws.title == SUMMARY_SHEET and wb.active.title == SUMMARY_SHEET
    assert ws.max_row < 60
    assert (ws.page_setup.fitToWidth, ws.page_setup.fitToHeight) == (1, 1)
    assert ws.sheet_properties.pageSetUpPr.fitToPage
    assert ws.page_setup.orientation == "landscape"
    assert 0.9 <= scale <= 1.0  # the budget: one page near 100 %
    names = [ws.cell(r, 1).value for r in range(1, ws.max_row + 1)]  # no rank: setup first
    shown = [n for n in names if str(n).startswith("s") and str(n)[1:].isdigit()]
    assert shown == [f"s{k}" for k in range(N_SUMMARY_ROWS - 1)] + ["s13"]  # + the baseline
    assert len(ws._images) == 1
