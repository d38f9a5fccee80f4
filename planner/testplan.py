"""Rig-day files of an experiment plan: the plan the virtual rig runs, the drives, the run sheet.

``write_plan(plan, out_dir)`` writes, into a folder built aside and moved into
place:

- ``plan.toml``: a rig plan (``format = "rig-plan/1"``, :mod:`ident.sim.virtual_rig`) whose
  runs play the drive files below, so ``shockplan rig simulate --plan`` runs it
  as is; a real rig's session of the same runs is what ``shockplan identify``
  expects next;
- ``shocks.toml``: the crate (the plan's shock library); ``bumpstops.toml``: the heave
  springs' library (``bump_stop_library``) when the car's baseline fits heave springs;
- ``drives/<run drive>.csv``: every drive the runs play (a last column ``units``);
- ``test_plan.xlsx``: the run sheet (:func:`write_run_sheet`), to print and
  fill in on rig day, and to read back (:func:`read_run_sheet`);
- ``test_plan.csv``: the same rows (:func:`run_sheet_rows`), a last column ``units``;
- ``design.png``: the criterion against rig time, run by run.

The run sheet
-------------
Sheet "run sheet": a header block (car, rig, date, crate, budget, criterion,
planned rig time, baseline, units), then one block of rows per run, in rig
order. The run's columns (number, planned start ``h:mm`` from the session's start,
duration, purpose, drive file, swap time, notes) are merged over its block; the
shock at each corner over the plan's rows, with an empty cell below it in the
measured row for its temperature; a shock changed before the run
(:attr:`PlannedRun.changed <planner.design.PlannedRun>`) is filled amber and
bold. Under each key metric (the objective's weighted ones, units in the
header; the first ones that fit the page, all in ``test_plan.csv``), the
block's rows hold the prediction, its interval (``lo-hi``, when the model was
identified) and an empty cell for the measured value, so the three read down
one column. Sheet "crate" lists the crate's shocks with their forces at
reference velocities (:data:`REFERENCE_VELOCITIES`) and the runs that use
them; sheet "information" holds each run's share of the criterion, the
criterion's values, the solver's report and the design settings.

With adjustable shocks on the car (a plan whose setups name settings, ``TTX@ls=6,hs=2``),
each corner is a group of columns: the shock's id and one column per adjuster
(its setting, clicks or turns; empty for a fixed shock). A corner whose shock was
swapped before the run is filled amber (:data:`CHANGED_FILL`, the shock and its
settings: set them all); an adjuster turned with the shock staying on, blue
(:data:`CLICK_FILL`), that cell alone. The column "change [min]" holds the time of
the changes before the run, shown after their kind (``swap``, ``clicks``,
``swap+clicks``); the legend says which fill is which. A plan without adjustable
shocks gets the sheet above, unchanged.

Every sheet prints landscape, one page wide with its smallest text at >= 7 pt
(:func:`planner.report.sheets.print_setup`), the table's header repeated on
every page, on A4 for SI and US letter for imperial
(:data:`planner.report.PAPER_SIZE`).
"""

from __future__ import annotations

import datetime
import functools
import logging
import math
import re
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import tomli_w
from openpyxl import Workbook, load_workbook
from openpyxl.styles import Alignment, Border, Font, PatternFill, Side
from openpyxl.utils import get_column_letter
from openpyxl.worksheet.pagebreak import Break

from ident.data.channels import CORNERS
from ident.data.drive import write_drive
from ident.data.files import atomic_dir, atomic_path, check_can_write, png_metadata, write_csv
from ident.data.units import UNIT_LABELS, check_units, from_si, to_si
from ident.models.adjustable import format_shock_name, parse_shock_name
from ident.models.bumpstops import write_bump_stops
from ident.models.library import write_shock_library
from ident.models.shocks import format_number
from ident.sim.metrics import METRIC_QUANTITY
from planner.design import ExperimentPlan
from planner.design.candidates import setup_key
from planner.errors import PlannerError
from planner.report.sheets import (column_label, fit_column_width, fit_width_units,
                                   print_setup, printable_size_pt, text_width, wrap_lines)
from planner.report.summary import N_SUMMARY_ROWS, write_summary_sheet

__all__ = ["write_plan", "plan_toml", "run_sheet_rows", "design_figure", "write_run_sheet",
           "read_run_sheet", "start_times_note", "RUN_SHEET_TITLE", "REFERENCE_VELOCITIES",
           "CHANGED_FILL", "CLICK_FILL"]

log = logging.getLogger(__name__)

_ROLE = {"identification": "swap", "baseline repeat": "baseline", "validation": "validation"}

#: Cell A1 of the sheet "run sheet" starts with this; :func:`read_run_sheet` checks it.
RUN_SHEET_TITLE = "shockplan run sheet"
#: Key metrics on the run sheet: the plan's first ones (all are in ``test_plan.csv``).
MAX_SHEET_METRICS = 6
#: Fill of a shock changed before a run (amber: mid-grey on a black-and-white printer).
CHANGED_FILL = "FFC000"
#: Fill of an adjuster turned before a run, its shock staying on the car (light blue:
#: light grey on a black-and-white printer, lighter than a swap's amber).
CLICK_FILL = "9DC3E6"
#: Fill of the plan's own cells (predictions, intervals): white cells are written in.
PLAN_FILL = "F2F2F2"
#: Velocities at which the crate sheet gives each shock's force (the sheet's units).
REFERENCE_VELOCITIES = {"SI": (0.025, 0.05, 0.1, 0.25), "imperial": (1.0, 2.0, 5.0, 10.0)}
#: Significant digits of the printed predictions and intervals.
SIGNIFICANT_DIGITS = 3
_TEMPERATURE_UNIT = {"SI": "°C", "imperial": "°F"}
_CRITERIA = {"d": "D-optimal (sum of log det M)", "a": "A-optimal (- sum of tr M^-1)",
             "decision": "decision (- variance of the top setups' score differences)"}
_FONT = "Calibri"
# the smallest (intervals, row labels) is the font that must print at >= MIN_PRINT_PT; 9.5 pt
# (not 9) so that the clicks sheet (the adjusters' columns) on US letter, at 74 %, prints
# at 7.0 pt (issue 36: 6.75 pt at 75 % with 9 pt)
_DATA_PT, _HEAD_PT, _SMALL_PT, _SHOCK_PT = 10, 9.5, 9.5, 11
_PAD = 1.5  # cell padding [Excel width units] (text_width already spares ~10 % on digits)
# the notes column [Excel width units]: at least (the run's block is 52 pt tall to write
# in), and at most where the page leaves room; the fit's spare for rounding
_NOTES_MIN_W, _NOTES_MAX_W, _FIT_SPARE_W = 12.0, 30.0, 1.0
# the notes column at its narrowest, when the one key metric the sheet shows needs its room
# (the adjusters' columns on US letter); a table still wider prints a little smaller
_NOTES_TIGHT_W = 8.0
# rows of a run's block: height [pt]; the measured row leaves room to write by hand
_ROW_PT = {"predicted": 14.0, "interval": 12.5, "measured": 26.0}
_LINE_PT = 12.0  # a header line of 9 pt text
# the run sheet's fixed column headers (read_run_sheet matches them)
_HEAD = {"run": "run", "start": "start [h:mm]", "duration_min": "duration [min]",
         "purpose": "purpose", "drive_file": "drive file (in drives/)", "swap_min": "swap [min]",
         "row": "", "notes": "notes"}
_SHOCKS_GROUP = "shock fitted (changed: filled)"
# the run sheet with adjustable shocks: a group per corner (the shock, one column per
# adjuster), and the change before the run: its time, its kind in the cell's number format
_SHOCK_HEAD = "shock"
_CLICK_HEAD = {"swap_min": "change [min]"}
_METRICS_GROUP = "key metrics"
_TEMPS_GROUP = "shock temperature"
_DRIVE_DIR = "drives"
#: The heave springs' bump-stop library written beside a plan whose baseline fits them.
BUMP_STOP_FILE = "bumpstops.toml"


def plan_toml(plan, *, units="SI", drive_dir=_DRIVE_DIR, shock_library="shocks.toml"):
    """The rig plan of an experiment plan, as TOML text (``format = "rig-plan/1"``).

    Parameters
    ----------
    plan : planner.design.ExperimentPlan
    units : {"SI", "imperial"}
        Units of the plan and its drive files.
    drive_dir : str
        Folder of the drive files, relative to the plan.
    shock_library : str
        The crate's file, relative to the plan.

    Returns
    -------
    str
    """
    fs = next(iter(plan.drives.values())).fs_hz
    runs = []
    for r in plan.runs:
        role = ("baseline" if setup_key(r.setup) == setup_key(plan.baseline)
                else _ROLE[r.purpose])
        runs.append({"name": r.name, "setup": dict(zip(CORNERS, r.setup.ids())),
                     "role": role, "drive": f"{drive_dir}/{r.drive}.csv"})
        if getattr(plan, "third", None) is not None:
            runs[-1].update(_run_third(plan.third, r.setup, units))
    doc = {"format": "rig-plan/1", "name": f"{plan.settings.get('car')} design "
                                            f"({plan.criterion}, {plan.budget_min:g} min)",
           "units": units, "shock_library": shock_library, "fs_hz": float(fs)}
    if getattr(plan, "bump_stops", None) is not None:  # the heave springs' library
        doc["bump_stop_library"] = BUMP_STOP_FILE
    if getattr(plan, "third", None) is not None:
        doc["third_elements"] = dict(plan.third.elements.motion_ratios)
    doc["run"] = runs
    header = (f"Experiment plan by shockplan plan: criterion {plan.criterion}, budget "
              f"{plan.budget_min:g} min, planned {plan.total_min:.1f} min on rig "
              f"'{plan.rig.name}'.\nRun it on the virtual rig with: shockplan rig simulate "
              "--plan plan.toml --out SESSION")
    if plan.rationale:
        header += "\nWhy these runs:\n" + "\n".join(
            textwrap.fill(line, 90, initial_indent="- ", subsequent_indent="  ",
                          break_on_hyphens=False)
            for line in plan.rationale)
    return "".join(f"# {line}\n" for line in header.splitlines()) + tomli_w.dumps(doc)


def _run_third(car, setup, units):
    """A rig-plan run's ``third``, ``heave_springs`` and ``heave_packers`` (issue 38): the
    dampers fitted (the setup's, else the baseline's; an element not fitted left out, as
    the spec reads it) and the baseline's heave springs and packers (file units)."""
    fitted = {e: (setup.third or {}).get(e, car.baseline.dampers.get(e))
              for e in car.elements.motion_ratios}
    out = {"third": {e: sid for e, sid in fitted.items() if sid is not None}}
    springs = {a: sid for a, sid in car.baseline.heave_springs.items() if sid is not None}
    if springs:
        out["heave_springs"] = springs
    packers = {a: float(from_si(v, "displacement", units))
               for a, v in car.baseline.heave_packers_m.items() if v}
    if packers:
        out["heave_packers"] = packers
    return out


def _shock_settings(library, sid):
    """(entry id, settings) of a shock name: every adjuster of an adjustable shock (its
    default where the name leaves it out), ``{}`` for a fixed shock."""
    base = library.base_id(sid)
    if base not in library.adjustable_ids:
        return sid, {}
    return base, library.adjustable(base).resolve(parse_shock_name(sid)[1])


def _corner_adjusters(plan):
    """Corner -> the adjusters of the adjustable shocks the plan fits there, in order; ``{}``
    when it fits none (the run sheet then has one shock column per corner, as ever)."""
    lib = plan.library
    if not lib.adjustable_ids:
        return {}
    out = {c: {} for c in CORNERS}
    for setup in [plan.baseline] + [r.setup for r in plan.runs]:
        for c, sid in zip(CORNERS, setup.ids()):
            out[c].update(dict.fromkeys(_shock_settings(lib, sid)[1]))
    if not any(out.values()):
        return {}
    return {c: tuple(v) for c, v in out.items()}


def run_sheet_rows(plan, *, units="SI"):
    """The run sheet's rows (one per run, rig order) as a DataFrame, metrics in `units`.

    Columns: ``run``, ``start``, ``start_min``, ``duration_min``, ``purpose``,
    ``drive_file``, ``LF`` .. ``RR``, ``changed``, ``swap_min``, the predicted key
    metrics with ``_lo``/``_hi``, ``share``. When the plan fits adjustable shocks,
    also each corner's settings ``<corner>_<adjuster>`` (clicks or turns; NaN where the
    corner has a fixed shock) after ``RR``, and after ``changed`` the kind of change
    ``change`` (``swap``, ``clicks``, ``swap+clicks`` or empty) and ``clicks`` (the
    adjusters turned, ``LF_ls RF_hs``); ``swap_min`` is then the time of every change
    before the run, swaps and clicks.
    """
    units = check_units(units, where="units", error=PlannerError)
    adj = _corner_adjusters(plan)
    rows = []
    for r in plan.runs:
        h, m = divmod(int(round(r.start_min)), 60)
        row = {"run": r.number, "start": f"{h:d}:{m:02d}", "start_min": round(r.start_min, 2),
               "duration_min": round(r.duration_s / 60, 2), "purpose": r.purpose,
               "drive_file": f"{_DRIVE_DIR}/{r.drive}.csv"}
        row.update(dict(zip(CORNERS, r.setup.ids())))
        if adj:
            for c, sid in zip(CORNERS, r.setup.ids()):
                settings = _shock_settings(plan.library, sid)[1]
                row.update({f"{c}_{a}": settings.get(a, np.nan) for a in adj[c]})
            row.update({"changed": " ".join(r.changed), "change": r.change,
                        "clicks": " ".join(f"{c}_{a}" for c, a in r.clicks)})
        row.update({"changed": " ".join(r.changed), "swap_min": r.swap_min})
        pred = plan.predictions.loc[r.number] if r.number in plan.predictions.index else {}
        for col, val in (pred.items() if len(pred) else []):
            base = col[:-3] if col.endswith(("_lo", "_hi")) else col
            row[col] = float(from_si(val, METRIC_QUANTITY[base], units))
        row["share"] = round(r.share, 4)
        rows.append(row)
    return pd.DataFrame(rows)


def design_figure(plan, *, size_in=(7.5, 4.2)):
    """The criterion against rig time, run by run (matplotlib Figure), `size_in` [in]."""
    from matplotlib.figure import Figure  # heavy; only when the figure is drawn

    fig = Figure(figsize=size_in, layout="constrained")
    ax = fig.subplots()
    c = plan.curve
    ax.step(c["time_min"], c["criterion"], where="post", color="tab:blue", lw=2)
    ax.plot(c["time_min"], c["criterion"], "o", color="tab:blue", ms=4)
    for r, t, v in zip(c["run"][1:], c["time_min"][1:], c["criterion"][1:]):
        ax.annotate(str(int(r)), (t, v), textcoords="offset points", xytext=(3, -10),
                    fontsize=8)
    if plan.values.get("greedy") is not None:
        ax.axhline(plan.values["greedy"], color="0.5", ls="--", lw=1,
                   label=f"cvxpy-free greedy ({plan.values['greedy_min']:.0f} min)")
    ax.axvline(plan.budget_min, color="tab:red", lw=1, label=f"budget {plan.budget_min:g} min")
    names = {"d": "sum of log det (D-optimal)", "a": "- sum of tr M^-1 (A-optimal)",
             "decision": "- variance of score differences"}
    small = size_in[1] < 3.0  # a small plot: smaller text
    ax.set_xlabel("rig time [min]", fontsize=8 if small else None)
    ax.set_ylabel(names.get(plan.criterion, "criterion"), fontsize=8 if small else None)
    ax.set_title(f"information gained against rig time ({len(plan.runs)} runs)",
                 fontsize=9 if small else None)
    if small:
        ax.tick_params(labelsize=8)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    return fig


def _summary(plan, units, date):
    """The plan's summary sheet: the runs in rig order (the first ones), the budget and what
    the plan used. No picture: the run sheet is filled in and saved again, and openpyxl
    cannot save a workbook it read with a picture twice (``design.png`` has the plot)."""
    rows = run_sheet_rows(plan, units=units)
    cols = [c for c in ("run", "start", "duration_min", "purpose", *CORNERS, "changed",
                        "share") if c in rows.columns]
    frame = rows[cols]
    s = plan.settings
    n = len(plan.runs)
    more = (f"; runs {N_SUMMARY_ROWS + 1}-{n} on the sheet 'run sheet'"
            if n > N_SUMMARY_ROWS else "")
    notes = [f"{n} run{'s' * (n != 1)} in {plan.total_min:.1f} of the {plan.budget_min:g} "
             f"min budget, in rig order{more}; share = the run's share of the information "
             "gained; 'run sheet' (next) is the sheet to fill in on rig day"]
    used = [("car", s.get("car") or "car"), ("rig", plan.rig.name), ("date", date),
            ("crate", str(s.get("crate") or "(not from a file)")),
            ("objective", str(s.get("objective") or "")),
            ("criterion", _CRITERIA.get(plan.criterion, plan.criterion)),
            ("baseline", "/".join(plan.baseline.ids())), ("units", units)]
    heads = {"duration_min": "duration [min]", "share": "share"}
    return {"title": f"{RUN_SHEET_TITLE}: summary", "table": frame,
            "headers": [heads.get(c, column_label(c)) for c in cols],
            "formats": {"share": "0.0%", "duration_min": "0.0"}, "notes": notes,
            "used": used, "figure": None}


# ----------------------------------------------------------------------------------------------
# the run sheet (Excel)
# ----------------------------------------------------------------------------------------------

def _decimals(value):
    """Decimals that show `value` to :data:`SIGNIFICANT_DIGITS` (whole numbers stay whole)."""
    if value is None or not np.isfinite(value) or value == 0:
        return 0
    return int(min(max(SIGNIFICANT_DIGITS - 1 - math.floor(math.log10(abs(value))), 0), 6))


def _number(value):
    """A float for a cell, None for a missing or non-finite value."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _wrap(text, width, size=_HEAD_PT, bold=True):
    """Lines of `text` wrapped at spaces into `width` [Excel width units], at least one."""
    return wrap_lines(text, width, size=size, bold=bold) or [""]


def _metric_header(metric, units):
    return f"{column_label(metric)} [{UNIT_LABELS[units][METRIC_QUANTITY[metric]]}]"


def _sheet_metrics(plan):
    keys = [c for c in plan.predictions.columns if c in METRIC_QUANTITY]
    if len(keys) > MAX_SHEET_METRICS:
        log.info("run sheet: %d key metrics; the sheet shows the first %d (all are in "
                 "test_plan.csv)", len(keys), MAX_SHEET_METRICS)
    return keys[:MAX_SHEET_METRICS]


@functools.cache
def _fonts():
    def f(size=_DATA_PT, **kw):
        return Font(name=_FONT, size=size, **kw)

    return {"data": f(), "bold": f(bold=True), "head": f(_HEAD_PT, bold=True),
            "small": f(_SMALL_PT, color="595959"), "label": f(_SMALL_PT, italic=True,
                                                               color="595959"),
            "shock": f(_SHOCK_PT), "changed": f(_SHOCK_PT, bold=True),
            "title": f(14, bold=True), "note": f(_HEAD_PT, italic=True)}


_THIN = Side(style="thin", color="A6A6A6")
_HEAVY = Side(style="medium", color="000000")


@functools.cache
def _border(*, left=False, top=False, bottom=False):
    return Border(left=_HEAVY if left else _THIN, right=_THIN, top=_HEAVY if top else _THIN,
                  bottom=_HEAVY if bottom else _THIN)


def _run_sheet_columns(units, metrics, adj=None):
    """The table's columns: key, group header (or None), header, group start. With `adj`
    (corner -> adjusters, :func:`_corner_adjusters`), a group per corner: the shock and
    one column per adjuster (keyed ``<corner>_<adjuster>``), then the change's kind."""
    cols = [("run", None, _HEAD["run"]), ("start", None, _HEAD["start"]),
            ("duration_min", None, _HEAD["duration_min"]), ("purpose", None, _HEAD["purpose"]),
            ("drive_file", None, _HEAD["drive_file"])]
    if adj:
        for c in CORNERS:
            cols += [(c, c, _SHOCK_HEAD)] + [(f"{c}_{a}", c, a) for a in adj[c]]
        cols += [("swap_min", None, _CLICK_HEAD["swap_min"])]
        starts = {"run", *CORNERS, "swap_min"}
    else:
        cols += [(c, _SHOCKS_GROUP, c) for c in CORNERS]
        cols += [("swap_min", None, _HEAD["swap_min"])]
        starts = {"run", CORNERS[0], "swap_min"}
    cols += [("row", _METRICS_GROUP, _HEAD["row"])]
    cols += [(m, _METRICS_GROUP, _metric_header(m, units)) for m in metrics]
    # the shock temperatures are written under the shocks, in the measured row (a column
    # each would take the width of three key metrics off a page)
    cols += [("notes", None, _HEAD["notes"])]
    starts |= {"row", "notes"}
    return [(k, g, h, k in starts) for k, g, h in cols]


def start_times_note(plan):
    """What the run sheet's start times count from: the session's start, each run after its
    changes and the rig's time a run besides its drive (so run 1 does not start at 0:00).

    Returns
    -------
    str
    """
    first = plan.runs[0].start_min if plan.runs else 0.0
    h, m = divmod(int(round(first)), 60)
    overhead = plan.rig.run_overhead_min
    besides = (f" and the rig's {overhead:g} min a run besides its drive" if overhead > 0
               else "")
    return (f"Start times count from the session's start (0:00): each run starts after its "
            f"changes{besides} (run 1 at {h:d}:{m:02d}).")


def _header_block(ws, plan, units, date, label_col, intervals, clicks=False):
    """Rows 1-7: the title, two columns of facts, the legend (`clicks`: of the layout with
    adjustable shocks); returns the next free row."""
    fonts = _fonts()
    s = plan.settings
    car = s.get("car") or "car"
    ws.cell(row=1, column=1, value=f"{RUN_SHEET_TITLE}: {car}").font = fonts["title"]
    ws.row_dimensions[1].height = 21
    n = len(plan.runs)
    rig = plan.rig
    turn = f"{rig.click_change_s:g} s to turn an adjuster, " if clicks else ""
    left = [("car", car),
            ("rig", f"{rig.name}: {rig.swap_min:g} min to swap a corner's shock, {turn}"
                    f"{rig.run_overhead_min:g} min a run besides its drive"),
            ("date", date),
            ("crate", str(s.get("crate") or "(not from a file)")),
            ("objective", str(s.get("objective") or ""))]
    right = [("budget", f"{plan.budget_min:g} min"),
             ("planned rig time", f"{plan.total_min:.1f} min, {n} run{'s' * (n != 1)}"),
             ("criterion", _CRITERIA.get(plan.criterion, plan.criterion)),
             ("baseline", plan.baseline.ids()[0] if clicks and len(set(plan.baseline.ids())) == 1
              else "/".join(plan.baseline.ids())),
             ("units", units)]
    for k, ((la, va), (lb, vb)) in enumerate(zip(left, right)):
        r = 2 + k
        for col, label, value in ((1, la, va), (label_col, lb, vb)):
            ws.cell(row=r, column=col, value=label).font = fonts["bold"]
            ws.merge_cells(start_row=r, start_column=col, end_row=r, end_column=col + 1)
            ws.cell(row=r, column=col + 2, value=value).font = fonts["data"]
        ws.row_dimensions[r].height = 14
    starts = start_times_note(plan)
    legend = (f"Filled shock: changed before the run. Grey cells are the plan's (predictions"
              f"{', intervals' if intervals else ''}); write the measured values, each shock's "
              f"temperature [{_TEMPERATURE_UNIT[units]}] (in the measured row, under the shock) "
              f"and notes in the white cells. {starts}")
    if clicks:
        legend = ("Each corner: the shock and its adjusters' settings (clicks or turns). Amber: "
                  "shock swapped before the run (set its adjusters as shown); blue: adjuster "
                  "turned before the run (the shock stays on). 'change [min]': the kind (swap, "
                  "clicks, swap+clicks) and time of the changes. Grey cells are the plan's "
                  f"(predictions{', intervals' if intervals else ''}); write the measured "
                  f"values, each shock's temperature [{_TEMPERATURE_UNIT[units]}] (in the "
                  f"measured row, under the shock) and notes in the white cells. {starts}")
    if plan.rationale:
        legend += " Why these runs: " + " ".join(plan.rationale)
    ws.cell(row=7, column=1, value=legend).font = fonts["note"]
    ws.row_dimensions[7].height = 14
    return 9


def _wrap_header_values(ws, widths, label_col):
    """The header block's values (rows 2-6) merged over the columns up to the next label
    (the right-hand ones up to the table's edge) and wrapped there, the rows as tall as
    their lines: a long value (the rig's times, a crate's path) never runs into the next
    column's text. `widths`: the table's columns' widths [Excel width units]."""
    top_left = Alignment(vertical="top", wrap_text=True)
    spans = ((3, label_col - 1), (label_col + 2, len(widths)))
    for r in range(2, 7):
        lines = 1
        for first, last in spans:
            cell = ws.cell(row=r, column=first)
            if cell.value is None or last < first:
                continue
            if last > first:
                ws.merge_cells(start_row=r, start_column=first, end_row=r, end_column=last)
            cell.alignment = top_left
            room = 0.9 * (sum(widths[first - 1:last]) - _PAD)  # prose: 10 % to spare
            lines = max(lines, len(_wrap(str(cell.value), room, size=_DATA_PT, bold=False)))
        ws.row_dimensions[r].height = 14 if lines == 1 else 13 * lines + 1


def _setting_text(value):
    """A setting as the sheet shows it (``8``, ``2.25``; empty for a fixed shock)."""
    v = _number(value)
    return "" if v is None else format_number(v)


def _run_table_widths(rows, metrics, cols, intervals, *, notes=_NOTES_MIN_W, shock_of=None):
    """Widths of the run table's columns (keyed as `cols`) and their headers' lines
    (`shock_of`: corner -> the shock shown per row, when not the rows' own)."""
    kinds = [k for k in ("predicted", "interval", "measured") if k != "interval" or intervals]
    shown = {k: [] for k, *_ in cols}
    small = {k: [] for k, *_ in cols}  # texts in the small font (intervals, row labels)
    for _, row in rows.iterrows():
        shown["run"].append(str(row["run"]))
        shown["start"].append(row["start"])
        shown["duration_min"].append(f"{row['duration_min']:g}")
        shown["purpose"].append(max(str(row["purpose"]).split(), key=len))
        shown["drive_file"].append(max(Path(row["drive_file"]).name.split(), key=len))
        shown["swap_min"].append(f"{row['swap_min']:g}" if shock_of is None
                                 else f"{row['change']} {row['swap_min']:.2f}")
        for c in CORNERS:
            shown[c].append(str(row[c]) if shock_of is None else shock_of[c][len(shown[c])])
        for key in shown:
            if key in row and key[:2] in CORNERS and key[2:3] == "_":
                shown[key].append(_setting_text(row[key]))
        for m in metrics:
            v = _number(row.get(m))
            if v is not None:
                d = _decimals(v)
                shown[m].append(f"{v:.{d}f}")
                lo, hi = _number(row.get(f"{m}_lo")), _number(row.get(f"{m}_hi"))
                if intervals and lo is not None and hi is not None:
                    small[m].append(f"{lo:.{d}f}\u2013{hi:.{d}f}")
    small["row"] = list(kinds)
    minimum = {"notes": notes, "drive_file": 9.0}
    widths = {}
    head_lines = {}
    for key, group, head, _ in cols:
        size = _SHOCK_PT if key in CORNERS or group in CORNERS else _DATA_PT
        bold = key in CORNERS or group in CORNERS
        data = max([text_width(t, size=size, bold=bold) for t in shown[key]]
                   + [text_width(t, size=_SMALL_PT) for t in small[key]] or [0])
        data = max(data, minimum.get(key, 0))
        w, lines = fit_column_width(head, data, size=_HEAD_PT)
        widths[key], head_lines[key] = w + _PAD, lines
    return widths, head_lines


def _fit_run_table(rows, metrics, units, intervals, adj=None, shock_of=None):
    """The key metrics that fit the run table one page wide with its smallest text at
    >= MIN_PRINT_PT (the first ones, at least one: where even one does not fit, as with the
    adjusters' columns on US letter, the notes column gives way, down to
    :data:`_NOTES_TIGHT_W`; all are in test_plan.csv), the columns, their widths and header
    lines; the notes column takes the room left (up to :data:`_NOTES_MAX_W`)."""
    budget = fit_width_units(min(_SMALL_PT, _HEAD_PT), units=units) - _FIT_SPARE_W
    while True:
        cols = _run_sheet_columns(units, metrics, adj)
        widths, head_lines = _run_table_widths(rows, metrics, cols, intervals,
                                               shock_of=shock_of)
        if sum(widths.values()) <= budget or len(metrics) <= 1:
            break
        log.info("run sheet: %d key metrics are too wide for one page; it shows the first "
                 "%d (all are in test_plan.csv)", len(metrics), len(metrics) - 1)
        metrics = metrics[:-1]
    spare = budget - sum(widths.values())
    if spare > 0:
        widths["notes"] = min(widths["notes"] + spare, _NOTES_MAX_W)
    elif spare < 0:  # one key metric that does not fit: the notes give way first
        widths["notes"] = max(widths["notes"] + spare, _NOTES_TIGHT_W)
    _fit_groups(cols, widths)
    return metrics, cols, widths, head_lines


def _fit_groups(cols, widths):
    """Widen a group's last column where the group's header (its longest word) is wider than
    the group's columns, so that the header wraps inside them (never into the next)."""
    for group in dict.fromkeys(g for _, g, *_ in cols if g is not None):
        keys = [k for k, g, *_ in cols if g == group]
        need = max(text_width(w, size=_HEAD_PT, bold=True) for w in group.split()) + _PAD
        have = sum(widths[k] for k in keys)
        if need > have:
            widths[keys[-1]] += need - have


def _write_run_table(ws, units, rows, metrics, cols, top, intervals, widths, head_lines,
                     shock_of=None):
    """The table header at rows `top`, `top` + 1 and the runs' blocks; returns the last row.
    `shock_of` (corner -> the shock's id per row): the layout with adjustable shocks."""
    fonts = _fonts()
    plan_fill = PatternFill("solid", fgColor=PLAN_FILL)
    changed_fill = PatternFill("solid", fgColor=CHANGED_FILL)
    click_fill = PatternFill("solid", fgColor=CLICK_FILL)
    group_of = {k: g for k, g, *_ in cols}
    center = Alignment(horizontal="center", vertical="center", wrap_text=True)
    left_mid = Alignment(horizontal="left", vertical="center", wrap_text=True)
    right_mid = Alignment(horizontal="right", vertical="center")
    right = Alignment(horizontal="right")
    top_left = Alignment(vertical="top", wrap_text=True)
    kinds = [k for k in ("predicted", "interval", "measured") if k != "interval" or intervals]
    for j, (key, *_) in enumerate(cols, start=1):
        ws.column_dimensions[get_column_letter(j)].width = round(widths[key], 2)

    # header: groups on the first row, headers on the second; single columns span both
    h1, h2 = top, top + 1
    j = 0
    while j < len(cols):
        key, group, head, start = cols[j]
        cell = ws.cell(row=h1, column=j + 1, value=group if group else head)
        cell.font, cell.alignment = fonts["head"], center
        cell.border = _border(left=start, top=True)
        if group is None:
            ws.cell(row=h1, column=j + 1).border = _border(left=start, top=True, bottom=True)
            ws.merge_cells(start_row=h1, start_column=j + 1, end_row=h2, end_column=j + 1)
            j += 1
            continue
        k = j
        while k + 1 < len(cols) and cols[k + 1][1] == group:
            k += 1
        if k > j:
            ws.merge_cells(start_row=h1, start_column=j + 1, end_row=h1, end_column=k + 1)
        for i in range(j, k + 1):
            c = ws.cell(row=h2, column=i + 1, value=cols[i][2])
            c.font, c.alignment = fonts["head"], center
            c.border = _border(left=cols[i][3], bottom=True)
        j = k + 1
    group_lines = 1
    for group in {g for _, g, _, _ in cols if g is not None}:
        span = sum(widths[k] for k, g, *_ in cols if g == group) - _PAD
        group_lines = max(group_lines, len(_wrap(group, span)))
    ws.row_dimensions[h1].height = _LINE_PT * group_lines + 4
    ws.row_dimensions[h2].height = _LINE_PT * max(
        [head_lines[k] for k, g, *_ in cols if g is not None] or [1]) + 4
    for j, (key, group, head, start) in enumerate(cols, start=1):
        if group is None:  # the merged single header: lines over both rows
            need = _LINE_PT * head_lines[key] + 4
            spare = need - ws.row_dimensions[h1].height - ws.row_dimensions[h2].height
            if spare > 0:
                ws.row_dimensions[h2].height += spare

    # the runs' blocks
    r0 = h2 + 1
    merged_keys = [k for k, *_ in cols if k not in metrics and k != "row"]
    col_of = {k: j for j, (k, *_) in enumerate(cols, start=1)}
    start_of = {k: s for k, _, _, s in cols}
    blocks = []
    for n, (_, row) in enumerate(rows.iterrows()):
        r_end = r0 + len(kinds) - 1
        end = n == len(rows) - 1  # the last block closes the table with a heavy rule
        changed = set(str(row["changed"]).split())
        values = {"run": int(row["run"]), "start": float(row["start_min"]) / 1440.0,
                  "duration_min": float(row["duration_min"]), "purpose": row["purpose"],
                  "drive_file": Path(row["drive_file"]).name,
                  "swap_min": float(row["swap_min"]), "notes": None}
        values.update({c: row[c] for c in CORNERS})
        clicked = set()
        if shock_of is not None:
            clicked = set(str(row["clicks"]).split())
            changed -= {k.split("_", 1)[0] for k in clicked}  # the swapped corners
            values.update({c: shock_of[c][n] for c in CORNERS})
            change = str(row["change"])
            values.update({k: _number(row[k]) for k, g, *_ in cols if g in CORNERS
                           and k not in CORNERS})
        r_meas = r0 + kinds.index("measured")
        for key in merged_keys:
            j = col_of[key]
            cell = ws.cell(row=r0, column=j, value=values[key])
            cell.border = _border(left=start_of[key], top=True, bottom=end)
            if key in CORNERS:  # the shock over the plan's rows, its temperature below
                cell.border = _border(left=start_of[key], top=True)
                temp = ws.cell(row=r_meas, column=j)
                temp.border = _border(left=start_of[key], bottom=end)
                temp.font, temp.alignment, temp.number_format = fonts["data"], center, "0"
                if r_meas - 1 > r0:
                    ws.merge_cells(start_row=r0, start_column=j, end_row=r_meas - 1,
                                   end_column=j)
            elif group_of[key] in CORNERS:  # an adjuster's setting: level with the shock
                cell.border = _border(top=True)
                below = ws.cell(row=r_meas, column=j)
                below.border, below.fill = _border(bottom=end), plan_fill
                if r_meas - 1 > r0:
                    ws.merge_cells(start_row=r0, start_column=j, end_row=r_meas - 1,
                                   end_column=j)
            cell.font = fonts["data"]
            cell.alignment = center
            if key in CORNERS:
                cell.font = fonts["changed"] if key in changed else fonts["shock"]
                if key in changed:
                    cell.fill = changed_fill
            elif group_of[key] in CORNERS:  # an adjuster's setting
                turned = key in clicked or group_of[key] in changed
                cell.font = fonts["changed"] if turned else fonts["shock"]
                cell.number_format = "General"
                if key in clicked:
                    cell.fill = click_fill
                elif group_of[key] in changed:
                    cell.fill = changed_fill
            elif key == "swap_min" and shock_of is not None:  # the kind, then the time
                cell.number_format = f'"{change} "0.00;-0.00;"-"' if change else '0;-0;"-"'
            elif key == "start":
                cell.number_format = "[h]:mm"
            elif key in ("duration_min", "swap_min"):
                cell.number_format = 'General;-General;"-"'
            elif key == "run":
                cell.font = fonts["bold"]
            elif key in ("purpose", "drive_file"):
                cell.alignment = left_mid
            elif key == "notes":
                cell.alignment = top_left
            if key in ("run", "start", "duration_min", "purpose", "drive_file", "swap_min"):
                cell.fill = plan_fill
            if len(kinds) > 1 and key not in CORNERS and group_of[key] not in CORNERS:
                ws.merge_cells(start_row=r0, start_column=j, end_row=r_end, end_column=j)
        for i, kind in enumerate(kinds):
            r = r0 + i
            bottom = end and r == r_end
            ws.row_dimensions[r].height = _ROW_PT[kind]
            lab = ws.cell(row=r, column=col_of["row"], value=kind)
            lab.font, lab.alignment = fonts["label"], right_mid
            lab.border = _border(left=True, top=i == 0, bottom=bottom)
            if kind != "measured":
                lab.fill = plan_fill
            for m in metrics:
                cell = ws.cell(row=r, column=col_of[m])
                cell.border = _border(top=i == 0, bottom=bottom)
                v = _number(row.get(m))
                d = _decimals(v)
                if kind == "predicted" and v is not None:
                    cell.value = v
                    cell.number_format = "0" if d == 0 else "0." + "0" * d
                    cell.font = fonts["data"]
                elif kind == "interval":
                    lo, hi = _number(row.get(f"{m}_lo")), _number(row.get(f"{m}_hi"))
                    if lo is not None and hi is not None:
                        cell.value = f"{lo:.{d}f}\u2013{hi:.{d}f}"
                    cell.font = fonts["small"]
                    cell.alignment = right
                elif kind == "measured":
                    cell.font = fonts["data"]
                if kind != "measured":
                    cell.fill = plan_fill
        blocks.append((r0, r_end, sum(_ROW_PT[k] for k in kinds)))
        r0 = r_end + 1
    _keep_blocks_whole(ws, blocks, units, sum(widths.values()), len(cols), top)
    return r0 - 1


def _keep_blocks_whole(ws, blocks, units, width_units, n_cols, top):
    """Page breaks between runs, so that no run's block splits over two pages.

    The sheet prints one page wide: the scale is the printable width over the
    table's (Excel's 7 px a width unit plus 5 px a column, at 96 px/in); a page
    then holds the printable height over that scale, less the repeated header
    (and the header block on the first page), with 6 % to spare for the
    application's own rounding. (Excel's is the largest scale an application
    prints the sheet at, so the most rows a page can lose to it.)
    """
    room_w, room_h = printable_size_pt(units)
    table_pt = 0.75 * (7.0 * width_units + 5.0 * n_cols)  # 0.75 pt a px
    scale = min(1.0, room_w / table_pt)
    page_pt = 0.94 * room_h / scale

    def height(r):
        return ws.row_dimensions[r].height or 15.0

    titles = height(top) + height(top + 1)
    used = sum(height(r) for r in range(1, top + 2))
    for first, last, h in blocks:
        if used + h > page_pt and used > titles:
            ws.row_breaks.append(Break(id=first - 1))
            used = titles
        used += h


def _grouped_header(ws, top, heads, starts, widths):
    """Two header rows at `top`: group labels merged over their columns, the columns' own
    headers below (a column without a group spans both rows). `heads`: (header, group)."""
    fonts = _fonts()
    center = Alignment(horizontal="center", vertical="center", wrap_text=True)
    n = len(heads)
    lines1, lines2 = [1], [1]
    j = 0
    while j < n:
        head, group = heads[j]
        cell = ws.cell(row=top, column=j + 1, value=group or head)
        cell.font, cell.alignment = fonts["head"], center
        cell.border = _border(left=j in starts, top=True, bottom=group is None)
        if group is None:
            ws.merge_cells(start_row=top, start_column=j + 1, end_row=top + 1, end_column=j + 1)
            lines2.append(len(_wrap(head, widths[j] - _PAD)) - lines1[0])
            j += 1
            continue
        k = j
        while k + 1 < n and heads[k + 1][1] == group:
            k += 1
        if k > j:
            ws.merge_cells(start_row=top, start_column=j + 1, end_row=top, end_column=k + 1)
        lines1.append(len(_wrap(group, sum(widths[j:k + 1]) - _PAD)))
        for i in range(j, k + 1):
            c = ws.cell(row=top + 1, column=i + 1, value=heads[i][0])
            c.font, c.alignment = fonts["head"], center
            c.border = _border(left=i in starts, bottom=True)
            lines2.append(len(_wrap(heads[i][0], widths[i] - _PAD)))
        j = k + 1
    ws.row_dimensions[top].height = _LINE_PT * max(lines1) + 4
    ws.row_dimensions[top + 1].height = _LINE_PT * max(lines2) + 4


def _crate_sheet(ws, plan, units, footer):
    """Sheet "crate": every shock of the crate, its forces and the runs that fit it."""
    fonts = _fonts()
    lib = plan.library
    v_ref = REFERENCE_VELOCITIES[units]
    v_unit = UNIT_LABELS[units]["velocity"]
    f_unit = UNIT_LABELS[units]["force"]
    used = {sid: [] for sid in lib.ids}
    for r in plan.runs:
        for sid in dict.fromkeys(lib.base_id(s) for s in r.setup.ids()):
            used.setdefault(sid, []).append(str(r.number))
    ws.cell(row=1, column=1, value=f"crate: {lib.source or '(not from a file)'}").font = \
        fonts["title"]
    ws.row_dimensions[1].height = 21
    nv = len(v_ref)
    heads = [("id", None), ("kind", None), ("lag [ms]", None), ("count", None),
             ("used in runs", None)]
    heads += [(f"{v:g} {v_unit}", f"bump force [{f_unit}] at") for v in v_ref]
    heads += [(f"{v:g} {v_unit}", f"rebound force [{f_unit}] at") for v in v_ref]
    heads += [("description", None)]
    force_cols = range(5, 5 + 2 * nv)
    rows = []
    v_si = to_si(np.asarray(v_ref, dtype=float), "velocity", units)
    adjustable = set(lib.adjustable_ids)
    for sid in lib.ids:
        m = lib[sid]
        bump = from_si(np.asarray(m.force(v_si), dtype=float), "force", units)
        reb = from_si(np.abs(np.asarray(m.force(-v_si), dtype=float)), "force", units)
        kind, description = m.kind, m.description or ""
        if sid in adjustable:  # the forces at its default setting, its adjusters named
            entry = lib.adjustable(sid)
            kind, description = entry.kind, entry.description or ""
            ranges = ", ".join(f"{a} {format_number(lo)}-{format_number(hi)} (stiffer "
                               f"{entry.stiffer[a]})" for a, (lo, hi) in entry.adjusters.items())
            default = ", ".join(f"{a} {format_number(x)}" for a, x in entry.default.items())
            description = (f"adjusters {ranges}; forces at the default {default}"
                           + (f". {description}" if description else ""))
        rows.append([sid, kind, 1e3 * m.lag_s, "unlimited" if m.count is None else m.count,
                     " ".join(used.get(sid, [])) or "-"]
                    + [float(x) for x in bump] + [float(x) for x in reb]
                    + [description])
    widths = []
    for j, (head, group) in enumerate(heads):
        texts = [f"{v:.0f}" if j in force_cols else f"{v:g}" if isinstance(v, float)
                 else str(v) for v in (row[j] for row in rows)]
        data = max([text_width(t, size=_DATA_PT, bold=j == 0) for t in texts] or [0])
        cap = 36.0 if head == "description" else 16.0
        w, _ = fit_column_width(head, min(data, cap), size=_HEAD_PT, max_lines=2)
        widths.append(w + _PAD)
        ws.column_dimensions[get_column_letter(j + 1)].width = round(w + _PAD, 2)
    top = 3
    starts = {5, 5 + nv, len(heads) - 1}
    _grouped_header(ws, top, heads, starts, widths)
    center = Alignment(horizontal="center", vertical="top")
    wrapped = Alignment(vertical="top", wrap_text=True)
    for i, values in enumerate(rows):
        r = top + 2 + i
        lines = 1
        for j, v in enumerate(values):
            cell = ws.cell(row=r, column=j + 1, value=v)
            cell.font = fonts["bold"] if j == 0 else fonts["data"]
            cell.border = _border(left=j in starts)
            cell.alignment = Alignment(vertical="top")
            if j in force_cols:
                cell.number_format = "0"
            elif j == 2:
                cell.number_format = "0.#" if v % 1 else "0"
            elif j in (3, 4):
                cell.alignment = center
            elif j == len(values) - 1:
                cell.alignment = wrapped
                # 15 % spare: prose is wider than the estimate's average letter
                lines = len(_wrap(v, 0.85 * (widths[j] - _PAD), size=_DATA_PT, bold=False))
        ws.row_dimensions[r].height = 13.5 * lines + 1
    last = top + 1 + len(rows)
    n = len(heads)
    note = ws.cell(row=last + 2, column=1, value=(
        "Forces of the static curve (before the lag) at the velocities in the header, bump "
        "(compression) and rebound each as a magnitude. 'used in runs': the runs (see the run "
        "sheet) that fit the shock at any corner."))
    note.font = fonts["note"]
    note.alignment = Alignment(wrap_text=True, vertical="top")
    ws.merge_cells(start_row=last + 2, start_column=1, end_row=last + 2, end_column=n)
    ws.row_dimensions[last + 2].height = _LINE_PT * len(_wrap(note.value, sum(widths) - _PAD,
                                                              bold=False)) + 4
    ws.freeze_panes = ws.cell(row=top + 2, column=2).coordinate
    print_setup(ws, units=units, area=f"A1:{get_column_letter(n)}{last + 2}",
                title_rows=f"{top}:{top + 1}", footer=footer)


def _information_sheet(ws, plan, units, footer):
    """Sheet "information": each run's share, the criterion's values, the solver, settings."""
    fonts = _fonts()
    ws.cell(row=1, column=1, value="information gained by the plan").font = fonts["title"]
    ws.row_dimensions[1].height = 21
    r = 3
    heads = ["run", "name", "purpose", "setup", "share of the criterion [%]",
             "criterion after the run", "rig time at its end [min]"]
    widths = (6, 34, 15, 20, 12, 12, 12)
    for j, h in enumerate(heads, start=1):
        c = ws.cell(row=r, column=j, value=h)
        c.font = fonts["head"]
        c.alignment = Alignment(wrap_text=True, horizontal="center", vertical="bottom")
        c.border = _border(top=True, bottom=True)
    ws.row_dimensions[r].height = 2 * _LINE_PT + 4
    curve = plan.curve.set_index("run")
    for run in plan.runs:
        r += 1
        crit = float(curve.loc[run.number, "criterion"]) if run.number in curve.index else None
        end = float(curve.loc[run.number, "time_min"]) if run.number in curve.index else None
        vals = [run.number, run.name, run.purpose, "/".join(run.setup.ids()),
                100.0 * run.share, crit, end]
        fmts = [None, None, None, None, "0.0", "0.00", "0.0"]
        for j, (v, f) in enumerate(zip(vals, fmts), start=1):
            c = ws.cell(row=r, column=j, value=v)
            c.font = fonts["data"]
            c.border = _border()
            if j == 1:
                c.alignment = Alignment(horizontal="center")
            if f:
                c.number_format = f
    r += 2
    meaning = {"prior": "the session's runs alone (none before rig day)",
               "relaxed": "the relaxed optimum (runs as real numbers), every band",
               "relaxed_design_bands": "the relaxed optimum on the design's band groups",
               "plan": "the planned runs (rounded and ordered), every band",
               "greedy": "a cvxpy-free greedy plan of the same budget",
               "greedy_min": "the greedy plan's rig time [min]"}
    sections = [(f"criterion: {_CRITERIA.get(plan.criterion, plan.criterion)}, larger is "
                 "better", [(k, v, meaning.get(k, "")) for k, v in plan.values.items()]),
                ("solver", [(k, v, "") for k, v in plan.solver.items()
                            if not k.endswith("_s")]),  # timings: logged, not in the file
                ("settings", [(k, v, "") for k, v in plan.settings.items()])]
    for title, items in sections:
        ws.cell(row=r, column=2, value=title).font = fonts["bold"]
        for k, v, note in items:
            r += 1
            ws.cell(row=r, column=2, value=str(k)).font = fonts["data"]
            if isinstance(v, float):
                cell = ws.cell(row=r, column=3, value=v if math.isfinite(v) else None)
                cell.number_format = "0.000" if abs(v) < 1e4 else "0"
            elif v is None or isinstance(v, (bool, int, str)):
                cell = ws.cell(row=r, column=3, value=v if v is not None else "-")
            else:
                cell = ws.cell(row=r, column=3, value=str(v))
            cell.font = fonts["data"]
            cell.alignment = Alignment(horizontal="left")
            if note:
                ws.cell(row=r, column=4, value=note).font = fonts["small"]
        r += 2
    for j, w in enumerate(widths, start=1):
        ws.column_dimensions[get_column_letter(j)].width = w
    # a short table, then label-value sections: no header row to repeat
    print_setup(ws, units=units, area=f"A1:{get_column_letter(len(widths))}{r - 2}",
                footer=footer)


def write_run_sheet(plan, path, *, units="SI", overwrite=False):
    """Write the rig-day run sheet ``test_plan.xlsx`` of an experiment plan.

    Parameters
    ----------
    plan : planner.design.ExperimentPlan
    path : str or path
        The workbook to write (``.xlsx``).
    units : {"SI", "imperial"}
        Units of the predictions, forces and temperatures on the sheet; also
        the paper (A4 for SI, US letter for imperial).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    TypeError
        If `plan` is not an ExperimentPlan.
    PlannerError
        If `units` is unknown.
    FileExistsError
        If `path` exists and `overwrite` is false (nothing is written).

    Notes
    -----
    See the module docstring for the layout. The date is the plan's
    (``plan.settings["date"]``), else today. Written atomically (a temporary
    file in the same folder, renamed). Read it back with :func:`read_run_sheet`.
    """
    if not isinstance(plan, ExperimentPlan):
        raise TypeError(f"write_run_sheet: plan must be a planner.design.ExperimentPlan (from "
                        f"design_experiment), got {type(plan).__name__}")
    units = check_units(units, where="write_run_sheet: units", error=PlannerError)
    path = Path(path)
    check_can_write(path, overwrite=overwrite)
    date = plan.settings.get("date") or datetime.date.today().isoformat()
    metrics = _sheet_metrics(plan)
    rows = run_sheet_rows(plan, units=units)
    footer = f"{RUN_SHEET_TITLE}: {plan.settings.get('car') or 'car'}, {date}"
    intervals = bool(metrics) and all(f"{m}_lo" in rows and f"{m}_hi" in rows for m in metrics)
    adj = _corner_adjusters(plan)
    shock_of = ({c: [_shock_settings(plan.library, sid)[0] for sid in rows[c]] for c in CORNERS}
                if adj else None)
    metrics, cols, widths, head_lines = _fit_run_table(rows, metrics, units, intervals, adj,
                                                       shock_of)

    wb = Workbook()
    ws = wb.active
    ws.title = "run sheet"
    # the header's right-hand facts: over the key metrics, or (with the adjusters' columns
    # taking the width) from the last corner on
    label_col = [k for k, *_ in cols].index(CORNERS[-1] if adj else "row") + 1
    top = _header_block(ws, plan, units, str(date), label_col, intervals, clicks=bool(adj))
    last = _write_run_table(ws, units, rows, metrics, cols, top, intervals, widths, head_lines,
                            shock_of)
    last_col = get_column_letter(len(cols))
    # the legend wraps over the table's width (the print area ends there)
    ws.merge_cells(f"A7:{last_col}7")
    ws["A7"].alignment = Alignment(wrap_text=True, vertical="top")
    ws.row_dimensions[7].height = _LINE_PT * len(_wrap(
        ws["A7"].value, 0.9 * (sum(widths.values()) - _PAD), bold=False)) + 2
    _wrap_header_values(ws, [widths[k] for k, *_ in cols], label_col)
    ws.freeze_panes = ws.cell(row=top + 2, column=2).coordinate
    print_setup(ws, units=units, area=f"A1:{last_col}{last}", title_rows=f"{top}:{top + 1}",
                footer=footer)
    _crate_sheet(wb.create_sheet("crate"), plan, units, footer)
    _information_sheet(wb.create_sheet("information"), plan, units, footer)
    write_summary_sheet(wb, units=units, footer=f"{footer}: summary",
                        **_summary(plan, units, str(date)))
    wb.properties.title = f"{RUN_SHEET_TITLE}: {plan.settings.get('car') or 'car'}"
    wb.properties.creator = "shockplan"
    with atomic_path(path, overwrite=overwrite) as tmp:
        wb.save(tmp)
    log.info("wrote the run sheet of %d runs (%s) to %s", len(plan.runs), units, path)
    return path


# ----------------------------------------------------------------------------------------------
# reading it back
# ----------------------------------------------------------------------------------------------

def _change_kind(before, after):
    """``"swap"``, ``"clicks"``, ``"swap+clicks"`` or ``""`` between two runs' shock names."""
    swap = clicks = False
    for a, b in zip(before, after):
        if a != b:
            same = "@" in a and "@" in b and a.partition("@")[0] == b.partition("@")[0]
            clicks |= same
            swap |= not same
    return "+".join(k for k, on in (("swap", swap), ("clicks", clicks)) if on)


def _not_a_run_sheet(path, why):
    return PlannerError(f"{path}: not a shockplan run sheet ({why}); give the test_plan.xlsx "
                        "that write_run_sheet or 'shockplan plan' wrote")


def _merged_value(ws, row, col):
    """The value shown at (row, col): a merged range's top-left value."""
    cell = ws.cell(row=row, column=col)
    if cell.value is not None:
        return cell.value
    for rng in ws.merged_cells.ranges:
        if rng.min_row <= row <= rng.max_row and rng.min_col <= col <= rng.max_col:
            return ws.cell(row=rng.min_row, column=rng.min_col).value
    return None


def _minutes(value, where):
    """A start cell (time, duration, day fraction or "h:mm" text) in minutes."""
    if isinstance(value, datetime.timedelta):
        return value.total_seconds() / 60.0
    if isinstance(value, datetime.time):
        return value.hour * 60 + value.minute + value.second / 60.0
    if isinstance(value, datetime.datetime):
        return value.hour * 60 + value.minute + value.second / 60.0
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value) * 1440.0
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(\d+):(\d{1,2})(?::(\d{1,2}))?\s*", value)
        if m:
            return int(m[1]) * 60 + int(m[2]) + int(m[3] or 0) / 60.0
    raise PlannerError(f"{where}: start {value!r} is not a time; write it as h:mm")


def _read_number(value, where, what):
    if value is None or (isinstance(value, str) and not value.strip()):
        return np.nan
    if isinstance(value, bool):
        raise PlannerError(f"{where}: {what} is {value!r}, not a number; write a number or "
                           "leave the cell empty")
    if isinstance(value, (int, float)):
        return float(value)
    try:
        return float(str(value).replace(",", "."))
    except ValueError:
        raise PlannerError(f"{where}: {what} is {value!r}, not a number; write a number or "
                           "leave the cell empty") from None


def read_run_sheet(path):
    """Read a run sheet (``test_plan.xlsx``) back: one row per run, as filled in.

    Parameters
    ----------
    path : str or path

    Returns
    -------
    pandas.DataFrame
        One row per run in sheet order, columns ``run``, ``start`` (``h:mm``),
        ``start_min``, ``duration_min``, ``purpose``, ``drive_file``
        (``drives/<name>.csv``), ``LF`` .. ``RR``, ``changed`` (corners whose
        shock differs from the run before, the first run from the baseline),
        ``swap_min``, ``change`` (the kind of change, as :attr:`PlannedRun.change
        <planner.design.PlannedRun>`, on a sheet with adjustable shocks; their names
        read back in full, ``TTX@ls=6,hs=2``), every key metric's prediction (SI),
        ``<metric>_measured``
        (SI, NaN where empty), ``shock_temp_<corner>_c`` [degC] and ``notes``.
        ``attrs`` holds ``units`` and the header block (``header``: label ->
        text).

    Raises
    ------
    PlannerError
        If the file is missing or not a workbook, is not a shockplan run sheet
        (no sheet "run sheet" titled :data:`RUN_SHEET_TITLE`, or its table has
        lost a column), or a measured value or temperature is not a number;
        the message names the file (and cell) and the fix.

    Notes
    -----
    Predictions round-trip at full precision (the cells hold the numbers;
    the format only rounds what is shown); intervals are shown text and are
    not read (``test_plan.csv`` has them).
    """
    path = Path(path)
    if not path.is_file():
        raise PlannerError(f"{path}: run sheet not found; check the path")
    try:
        wb = load_workbook(path, data_only=True)
    except (zipfile.BadZipFile, KeyError, OSError, ValueError) as exc:
        raise _not_a_run_sheet(path, f"not an Excel workbook: {exc}") from None
    if "run sheet" not in wb.sheetnames:
        raise _not_a_run_sheet(path, f"no sheet 'run sheet', only {wb.sheetnames}")
    ws = wb["run sheet"]
    title = ws.cell(row=1, column=1).value
    if not (isinstance(title, str) and title.startswith(RUN_SHEET_TITLE)):
        raise _not_a_run_sheet(path, f"cell A1 is {title!r}, not '{RUN_SHEET_TITLE}: <car>'")
    h1 = next((r for r in range(2, min(ws.max_row, 60) + 1)
               if ws.cell(row=r, column=1).value == _HEAD["run"]), None)
    if h1 is None:
        raise _not_a_run_sheet(path, "no table header 'run' in column A")
    header = {}
    for r in range(2, h1):
        cells = [ws.cell(row=r, column=c).value for c in range(1, ws.max_column + 1)]
        for j, v in enumerate(cells):
            if isinstance(v, str) and j + 2 < len(cells) and cells[j + 2] is not None \
                    and cells[j + 1] is None:
                header.setdefault(v, str(cells[j + 2]))
    try:
        units = check_units(header.get("units", ""), where=f"{path}: header 'units'",
                            error=PlannerError)
    except PlannerError:
        raise _not_a_run_sheet(path, "the header block has no 'units'") from None
    labels = {column_label(m): m for m in METRIC_QUANTITY}
    heads = {v: k for k, v in _HEAD.items()}
    heads.update({v: k for k, v in _CLICK_HEAD.items()})
    col = {}
    settings_cols = {c: [] for c in CORNERS}  # (adjuster, column) per corner
    for j in range(1, ws.max_column + 1):
        g, h = _merged_value(ws, h1, j), ws.cell(row=h1 + 1, column=j).value
        if g == _SHOCKS_GROUP and h in CORNERS:
            col[h] = j
        elif g in CORNERS and h == _SHOCK_HEAD:
            col[g] = j
        elif g in CORNERS and isinstance(h, str) and h:
            settings_cols[g].append((h, j))
        elif isinstance(g, str) and g.startswith(_TEMPS_GROUP) and h in CORNERS:
            col[f"temp_{h}"] = j
        elif g == _METRICS_GROUP and h in (None, ""):
            col["row"] = j
        elif g == _METRICS_GROUP and isinstance(h, str):
            m = labels.get(h.split(" [")[0])
            if m is None:
                raise _not_a_run_sheet(path, f"unknown key metric {h!r} in column "
                                             f"{get_column_letter(j)}")
            col[m] = j
        elif g in heads:
            col[heads[g]] = j
    need = ["run", "start", "duration_min", "purpose", "drive_file", *CORNERS, "swap_min",
            "row"]
    missing = [k for k in need if k not in col]
    if missing:
        raise _not_a_run_sheet(path, f"its table has no column(s) {missing}")
    metrics = [k for k in col if k in METRIC_QUANTITY]
    baseline = header.get("baseline", "").split("/")
    if len(baseline) == 1 and baseline[0]:  # one shock at every corner
        baseline = baseline * 4
    prev = baseline if len(baseline) == 4 else None
    out = []
    r = h1 + 2
    while r <= ws.max_row:
        run = ws.cell(row=r, column=col["run"]).value
        if run is None:
            r += 1
            continue
        where = f"{path}: run sheet, run {run} (row {r})"
        rows = {}
        k = r
        while k <= ws.max_row and (k == r or ws.cell(row=k, column=col["run"]).value is None):
            kind = ws.cell(row=k, column=col["row"]).value
            if kind is None:
                break
            rows[kind] = k
            k += 1
        ids = []
        for c in CORNERS:
            sid = str(ws.cell(row=r, column=col[c]).value)
            settings = {a: _read_number(ws.cell(row=r, column=j).value, where, f"{c} {a}")
                        for a, j in settings_cols[c]}
            settings = {a: v for a, v in settings.items() if np.isfinite(v)}
            ids.append(format_shock_name(sid, settings) if settings else sid)
        start = _minutes(ws.cell(row=r, column=col["start"]).value, where)
        h, mm = divmod(int(round(start)), 60)
        drive = ws.cell(row=r, column=col["drive_file"]).value
        rec = {"run": int(run), "start": f"{h:d}:{mm:02d}", "start_min": start,
               "duration_min": _read_number(ws.cell(row=r, column=col["duration_min"]).value,
                                            where, "duration"),
               "purpose": ws.cell(row=r, column=col["purpose"]).value,
               "drive_file": (None if drive is None else f"{_DRIVE_DIR}/{drive}"
                              if str(drive).endswith(".csv") else f"{_DRIVE_DIR}/{drive}.csv")}
        rec.update(dict(zip(CORNERS, ids)))
        rec["changed"] = (" ".join(c for c, a, b in zip(CORNERS, prev, ids) if a != b)
                          if prev is not None else "")
        if any(settings_cols.values()):  # the kind of change, as PlannedRun.change
            rec["change"] = _change_kind(prev, ids) if prev is not None else ""
        swap = ws.cell(row=r, column=col["swap_min"]).value
        rec["swap_min"] = 0.0 if swap in (None, "-") else _read_number(swap, where, "swap")
        for m in metrics:
            q = METRIC_QUANTITY[m]
            p = ws.cell(row=rows.get("predicted", r), column=col[m]).value
            rec[m] = float(to_si(_read_number(p, where, m), q, units))
            cell = ws.cell(row=rows["measured"], column=col[m]) if "measured" in rows else None
            meas = _read_number(cell.value, f"{where}, cell {cell.coordinate}",
                                f"measured {m}") if cell is not None else np.nan
            rec[f"{m}_measured"] = float(to_si(meas, q, units))
        for c in CORNERS:
            # under the shock in the measured row; a column of its own on an older sheet
            cell = (ws.cell(row=r, column=col[f"temp_{c}"]) if f"temp_{c}" in col
                    else ws.cell(row=rows["measured"], column=col[c])
                    if rows.get("measured", r) != r else None)
            if cell is not None:
                t = _read_number(cell.value, f"{where}, cell {cell.coordinate}",
                                 f"shock temperature {c}")
                rec[f"shock_temp_{c}_c"] = (t - 32.0) * 5.0 / 9.0 if units == "imperial" else t
        if "notes" in col:
            note = ws.cell(row=r, column=col["notes"]).value
            rec["notes"] = "" if note is None else str(note)
        out.append(rec)
        prev = ids
        r = max(k, r + 1)
    if not out:
        raise _not_a_run_sheet(path, "its table has no runs")
    frame = pd.DataFrame(out)
    frame.attrs["units"] = units
    frame.attrs["header"] = header
    return frame


# ----------------------------------------------------------------------------------------------
# the folder
# ----------------------------------------------------------------------------------------------

def write_plan(plan, out_dir, *, units="SI", overwrite=False):
    """Write an experiment plan's rig-day files (see the module docstring).

    Parameters
    ----------
    plan : planner.design.ExperimentPlan
    out_dir : str or path
    units : {"SI", "imperial"}
    overwrite : bool
        Replace an existing folder.

    Returns
    -------
    dict of str -> pathlib.Path

    Raises
    ------
    FileExistsError
        If `out_dir` exists and is not empty, and `overwrite` is false (checked first).
    """
    units = check_units(units, where="units", error=PlannerError)
    out = Path(out_dir)
    names = {"plan": "plan.toml", "shocks": "shocks.toml", "xlsx": "test_plan.xlsx",
             "csv": "test_plan.csv", "figure": "design.png", "drives": _DRIVE_DIR}
    with atomic_dir(out, overwrite=overwrite) as work:
        (work / _DRIVE_DIR).mkdir()
        for name, drive in plan.drives.items():
            write_drive(drive, work / _DRIVE_DIR / f"{name}.csv", units=units)
        write_shock_library(plan.library, work / names["shocks"], units=units)
        if getattr(plan, "bump_stops", None) is not None:
            names["bump_stops"] = BUMP_STOP_FILE
            write_bump_stops(plan.bump_stops, work / BUMP_STOP_FILE, units=units)
        (work / names["plan"]).write_text(plan_toml(plan, units=units), encoding="utf-8")
        rows = run_sheet_rows(plan, units=units)
        write_csv(work / names["csv"], rows, units=units, float_format="%.6g")
        write_run_sheet(plan, work / names["xlsx"], units=units)
        fig = design_figure(plan)
        fig.savefig(work / names["figure"], dpi=110, metadata=png_metadata(fig))
    return {k: out / v for k, v in names.items()}
