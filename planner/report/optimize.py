"""The optimizer's files: its shocks and setups, ``optimize.xlsx``, ``curves.png``, convergence.

:func:`write_optimum` writes a :class:`planner.optimize.CurveOptimum` into a
folder; :func:`curve_table` is the shock builder's force table (the xlsx's
curve sheets) and :func:`curves_figure` the optimal curves against the
crate's. With adjustable shocks in the crate, the best clicks
(``CurveOptimum.clicks``) too: ``clicks.csv``, a ``clicks`` sheet, their curves
in ``curves.png`` and :func:`click_summary` (the command's printed lines).
Compute lives in :mod:`planner.optimize`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from openpyxl import Workbook
from openpyxl.utils import get_column_letter

from ident.data.channels import CORNERS
from ident.data.files import atomic_dir, png_metadata, write_csv
from ident.data.third import AXLES, THIRD_ELEMENTS, element_row
from ident.data.units import UNIT_LABELS, check_units, from_si, to_si
from ident.models.library import ShockLibrary, write_shock_library
from ident.models.shocks import format_number
from ident.sim.metrics import METRIC_NAMES, METRIC_QUANTITY
from planner.elements import THIRD_COLUMNS
from planner.errors import PlannerError
from planner.report.ranking import ranking_to_units
from planner.report.sheets import (
    column_label,
    print_setup,
    write_key_values,
    write_table,
)
from planner.report.summary import summary_parts, write_summary_sheet
from planner.setups import Setup, write_setups

__all__ = [
    "BUILDER_VELOCITIES_M_S",
    "BUILDER_VELOCITIES_IN_S",
    "CURVE_V_MAX",
    "click_summary",
    "click_table",
    "curve_table",
    "curves_figure",
    "stop_reason",
    "write_optimum",
]

#: Velocities of the shock builder's force table [m/s] and [in/s].
BUILDER_VELOCITIES_M_S = (0.0125, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.25, 0.35, 0.5, 0.75, 1.0)
BUILDER_VELOCITIES_IN_S = (0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0, 40.0)
#: Half-span of the velocity axis of ``curves.png`` per unit system [m/s] and [in/s].
CURVE_V_MAX = {"SI": 0.6, "imperial": 24.0}


def curve_table(optimum, *, units="SI"):
    """The optimal curves as a force table for a shock builder.

    Parameters
    ----------
    optimum : CurveOptimum
    units : {"SI", "imperial"}
        SI: force [N] at :data:`BUILDER_VELOCITIES_M_S` [m/s]; imperial: [lbf]
        at :data:`BUILDER_VELOCITIES_IN_S` [in/s]; bump (compression) positive,
        rebound rows negative.

    Returns
    -------
    pandas.DataFrame
        Index: velocity; one column per optimal shock.
    """
    units = check_units(units, where="units", error=PlannerError)
    vel = np.asarray(BUILDER_VELOCITIES_M_S if units == "SI" else BUILDER_VELOCITIES_IN_S)
    v = np.concatenate([-vel[::-1], vel])
    v_si = to_si(v, "velocity", units)
    cols = {sid: from_si(m.force(v_si), "force", units) for sid, m in optimum.shocks.items()}
    label = "velocity [m/s]" if units == "SI" else "velocity [in/s]"
    out = pd.DataFrame(cols, index=pd.Index(v, name=label))
    return out.rename(columns=lambda c: f"{c} [{'N' if units == 'SI' else 'lbf'}]")


#: A +-5 % knot move that changes the verified score by less than this (relative) either way
#: is flat: below the identified model's accuracy (about 1e-3 on metrics) it says nothing
#: about optimality (issue 24; ``shockplan optimize`` says the same).
STATIONARY_FLAT = 1e-4


def curves_figure(optimum, library, *, units="SI"):
    """The optimal curves against the crate's, with the optimum's shock-velocity histograms.

    Parameters
    ----------
    optimum : CurveOptimum
    library : ShockLibrary
        The crate.
    units : {"SI", "imperial"}
        Display units: velocity [m/s] and force [N], or [in/s] and [lbf]; the
        velocity axis spans :data:`CURVE_V_MAX` of the unit system.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure  # heavy: loaded only when a figure is drawn

    units = check_units(units, where="units", error=PlannerError)
    v_unit, f_unit = UNIT_LABELS[units]["velocity"], UNIT_LABELS[units]["force"]
    v_max = CURVE_V_MAX[units]
    G = len(optimum.space.groups)
    n_panels = G + len(optimum.third_curves)
    fig = Figure(figsize=(5.5 * n_panels, 4.6), layout="constrained")
    axes = fig.subplots(1, n_panels, squeeze=False)[0]
    v = np.linspace(-v_max, v_max, 241)  # display units
    v_si = to_si(v, "velocity", units)

    def force(model, vel_si):  # a curve in display units
        return from_si(model.force(vel_si), "force", units)

    env = optimum.settings.get("envelope_n") or {}
    env_lo = np.asarray(env.get("lo", np.full((G, optimum.space.v_knots_m_s.size), np.nan)),
                        dtype=float)
    env_hi = np.asarray(env.get("hi", np.full_like(env_lo, np.nan)), dtype=float)
    rng = optimum.space.v_range_m_s
    for g, (ax, (name, corners), pwl) in enumerate(zip(axes, optimum.space.groups,
                                                         optimum.curves)):
        samples = from_si(np.concatenate([optimum.velocity_m_s[c] for c in corners]),
                          "velocity", units)
        hist = ax.twinx()
        hist.hist(samples, bins=np.linspace(-v_max, v_max, 61), color="#d9e6f2", density=True)
        hist.set_yticks([])
        ax.set_zorder(hist.get_zorder() + 1)
        ax.patch.set_visible(False)
        for k, m in enumerate(library.values()):
            ax.plot(v, force(m, v_si), color="0.7", lw=0.8, label="crate" if k == 0 else None)
        for sid in sorted(set(optimum.table.loc[optimum.crate_best, list(corners)])):
            ax.plot(v, force(library[sid], v_si), color="tab:orange", lw=1.6,
                    label=f"crate best ({sid})")
        best = None if optimum.clicks is None else optimum.clicks.best
        if best is not None:
            for sid in sorted(set(best.setup.shocks[c] for c in corners)):
                ax.plot(v, force(library[sid], v_si), color="tab:red", lw=1.6, ls="--",
                        label=f"best clicks ({sid})")
        vk = from_si(pwl.v_knots_m_s, "velocity", units)
        f_lim = 1.5 * max(np.max(np.abs(force(pwl, v_si))), 1e-9)
        lo = np.clip(from_si(env_lo[g], "force", units), -f_lim, f_lim)
        hi = np.clip(from_si(env_hi[g], "force", units), -f_lim, f_lim)
        ok = np.isfinite(lo) & np.isfinite(hi)
        ax.fill_between(vk[ok], lo[ok], hi[ok], color="tab:green", alpha=0.13, lw=0,
                        label="constraint envelope")
        if rng is not None:
            for k, vr in enumerate((-rng[0], rng[1])):
                ax.axvline(from_si(vr, "velocity", units), color="tab:green", lw=0.9, ls="--",
                           label="99 % of the shock speeds (constraints' range)" if k == 0
                           else None)
        ax.plot(v, force(pwl, v_si), color="tab:blue", lw=2.2, label=f"optimum ({name})")
        ax.plot(from_si(pwl.v_knots_m_s, "velocity", units),
                from_si(pwl.f_knots_n, "force", units), "o", color="tab:blue", ms=4)
        ax.axhline(0, color="0.5", lw=0.6)
        ax.axvline(0, color="0.5", lw=0.6)
        ax.set(xlabel=f"shock velocity [{v_unit}] (compression +)", ylabel=f"force [{f_unit}]",
               title=f"{name}: {', '.join(corners)}", xlim=(-v_max, v_max))
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    for ax, (name, pwl) in zip(axes[G:], optimum.third_curves.items()):
        _third_panel(ax, optimum, library, name, pwl, v, v_si, units, force)
    fig.suptitle(f"optimal curves (score {optimum.score:.4f}) and the crate; blue histogram: "
                 "the optimum's shock velocities; green: the forces the constraints allow at "
                 "the knots", fontsize=10)
    return fig


def _third_columns(optimum):
    """The setups' third-element columns (``heave_front``, ... ``heave_spring_<axle>``; damper
    and heave-spring ids, ``none`` where none), indexed as ``optimum.table``: the optimizer's
    table's own where it has them (a free third damper's optimum), else those the metrics
    carry, else the car's baseline's (``settings["third"]``), which every verification
    fitted; no columns for a car without third elements."""
    index = optimum.table.index
    car = optimum.settings.get("third") or {}
    declared = car.get("motion_ratios") or {}
    data = {e: (car.get("dampers") or {}).get(e) or "none"
            for e in THIRD_ELEMENTS if e in declared}
    data.update({f"heave_spring_{a}": (car.get("heave_springs") or {}).get(a) or "none"
                 for a in AXLES if f"heave_{a}" in declared})
    out = pd.DataFrame({c: [v] * len(index) for c, v in data.items()}, index=index)
    met = optimum.metrics[next(iter(optimum.metrics))]
    for source in (met.loc[index], optimum.table):
        for c in THIRD_COLUMNS:
            if c in source.columns:
                out[c] = source[c].to_numpy()
    return out[[c for c in THIRD_COLUMNS if c in out.columns]]


def _third_panel(ax, optimum, library, name, pwl, v, v_si, units, force):
    """A free third damper's panel of :func:`curves_figure`: the optimum's curve against the
    baseline's damper, over the element's velocity histogram (``m_e @ v``)."""
    v_unit, f_unit = UNIT_LABELS[units]["velocity"], UNIT_LABELS[units]["force"]
    mr = (optimum.settings.get("third") or {}).get("motion_ratios", {}).get(name)
    if mr is not None:
        row = element_row(name, mr)
        ve = sum(row[k] * np.asarray(optimum.velocity_m_s[c]) for k, c in enumerate(CORNERS))
        hist = ax.twinx()
        hist.hist(from_si(ve, "velocity", units), bins=np.linspace(v[0], v[-1], 61),
                  color="#d9e6f2", density=True)
        hist.set_yticks([])
        ax.set_zorder(hist.get_zorder() + 1)
        ax.patch.set_visible(False)
    base = optimum.table.loc[optimum.baseline.name].get(name)
    if isinstance(base, str) and base in library:
        ax.plot(v, force(library[base], v_si), color="tab:orange", lw=1.6,
                label=f"baseline ({base})")
    # (a crate searched over third-element choices: its best's damper here, if another)
    best = optimum.table.loc[optimum.crate_best].get(name)
    if optimum.settings.get("crate_third") and isinstance(best, str) and best != base \
            and best in library:
        ax.plot(v, force(library[best], v_si), color="tab:green", lw=1.6, ls="--",
                label=f"crate best ({best})")
    ax.plot(v, force(pwl, v_si), color="tab:blue", lw=2.2, label=f"optimum ({name})")
    ax.plot(from_si(pwl.v_knots_m_s, "velocity", units), from_si(pwl.f_knots_n, "force", units),
            "o", color="tab:blue", ms=4)
    ax.axhline(0, color="0.5", lw=0.6)
    ax.axvline(0, color="0.5", lw=0.6)
    ax.set(xlabel=f"element velocity [{v_unit}] (compression +)",
           ylabel=f"element force [{f_unit}]", title=f"{name} (third element)",
           xlim=(v[0], v[-1]))
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")


def _setups_sheet(optimum, units):
    first = next(iter(optimum.metrics))
    met = optimum.metrics[first].loc[optimum.table.index]
    metric_cols = [c for c in met.columns if c in METRIC_NAMES]
    third = _third_columns(optimum)
    t = optimum.table.drop(columns=list(third.columns), errors="ignore")
    at = max((t.columns.get_loc(c) + 1 for c in CORNERS if c in t.columns), default=0)
    for j, c in enumerate(third.columns):  # setup columns, after the corners' shocks
        t.insert(at + j, c, third[c].to_numpy())
    t = pd.concat([t, ranking_to_units(met[metric_cols], units)], axis=1)
    return t.reset_index()


def click_table(optimum):
    """The best clicks per adjustable shock and corner group (``clicks.csv``).

    Parameters
    ----------
    optimum : CurveOptimum

    Returns
    -------
    pandas.DataFrame or None
        :meth:`planner.optimize.click_search.ClickResult.table` (one column per adjuster, in
        its own units, clicks or turns); None without adjustable shocks.
    """
    return None if optimum.clicks is None else optimum.clicks.table()


def click_summary(optimum):
    """The printed lines of the click search (``shockplan optimize``); none without it.

    Parameters
    ----------
    optimum : CurveOptimum

    Returns
    -------
    list of str
        A header line, the settings table (a column per adjuster, a row per adjustable
        and corner group) and the verdict: the gain over the best fixed setup and the
        gap to the continuous optimum.
    """
    clicks = optimum.clicks
    if clicks is None:
        return []
    lines = [f"clicks: each adjustable's settings per corner group, from the settings nearest "
             f"the optimum's curves and the crate best's, moves of +-1..{clicks.radius} "
             "steps, verified in the time domain"]
    tab = clicks.table()
    if len(tab):
        cols = list(tab.columns)
        adj = cols[cols.index("corners") + 1:cols.index("setting")]
        heads = ["shock", "group", "corners"] + adj + ["score", "simulated"]
        rows = [[r["shock"], r["group"], r["corners"]]
                + ["" if pd.isna(r[a]) else format_number(r[a]) for a in adj]
                + [f"{r['score']:.4f}", str(int(r["simulated"]))] for _, r in tab.iterrows()]
        width = [max(len(h), *(len(row[j]) for row in rows)) for j, h in enumerate(heads)]
        for row in [heads] + rows:
            lines.append("  " + "  ".join(x.ljust(w) for x, w in zip(row, width)).rstrip())
    for sid, why in clicks.skipped.items():
        lines.append(f"  {sid} not searched: {why}")
    lines.append(clicks.verdict())
    return lines


def _summary(optimum, units, run):
    """The optimum's summary sheet: the optimum, the crate's best, the baseline and the
    closest crate setups with their verdicts, key metrics (the first drive) and the plot."""
    first = next(iter(optimum.metrics))
    met = optimum.metrics[first]
    t = optimum.table.sort_values("score", kind="stable")
    t = pd.concat([t, met.loc[t.index, [c for c in met.columns if c in METRIC_QUANTITY]]],
                  axis=1)
    weighted = [m for m, w in optimum.objective.weights.items() if w > 0 and m in t.columns]
    base = "/".join(optimum.baseline.ids())
    base = base if base in t.index else next(
        (n for n in t.index if t.loc[n, "kind"] == "baseline"), optimum.setup.name)
    best = str(t.index[0])
    notes = [f"the optimal curves ('{optimum.setup.name}', to build) gain "
             f"{100 * optimum.gap:.2f} % over the crate's best '{optimum.crate_best}'; "
             "scores are ratios to the baseline's metrics over the drives, lower is better; "
             f"metrics on the drive '{first}'"]
    used = list((run or {}).items())
    used += [("drives", ", ".join(optimum.settings["drives"])),
             ("objective", optimum.objective.name), ("symmetry", optimum.space.symmetry),
             ("IPOPT", f"{optimum.solver['status']}, {optimum.solver['iterations']} "
                       "iterations"), ("units", units)]
    return summary_parts(t, best=best, baseline=base, metrics=weighted[:6], units=units,
                         first=("kind",), title="shockplan optimize: summary", notes=notes,
                         used=used)


def _write_workbook(optimum, units, path, run=None):
    """``optimize.xlsx``: a one-page summary, the force table in the run's units (one unit
    system per project), the setups, the solver's report; every sheet laid out and set to
    print with :mod:`planner.report.sheets`."""
    wb = Workbook()
    what = f"shockplan optimize ({units})"
    for k, u in enumerate((units,)):
        sheet = wb.active if k == 0 else wb.create_sheet()
        sheet.title = f"curves {u}"
        tab = curve_table(optimum, units=u).round(1).reset_index()
        last = write_table(sheet, tab, headers=list(tab.columns),
                           formats={c: "0.0###" if j == 0 else "0.0"
                                    for j, c in enumerate(tab.columns)})
        print_setup(sheet, units=units, area=f"A1:{get_column_letter(tab.shape[1])}{last}",
                    title_rows="1:1", footer=f"{what}: force table for the shock builder "
                                             f"({u}), bump positive, rebound negative")
    ss = wb.create_sheet("setups")
    tab = _setups_sheet(optimum, units)
    heads = [f"{column_label(c)} [{UNIT_LABELS[units][METRIC_QUANTITY[c]]}]"
             if c in METRIC_QUANTITY else column_label(c) for c in tab.columns]
    formats = {c: "0.0000" for c in tab.columns if str(c).startswith("score")}
    last = write_table(ss, tab, headers=heads, formats=formats, freeze_cols=2)
    # pages across break between metric families (tire force, ride height, ...)
    group = [c.rsplit("_", 1)[0] if c in METRIC_QUANTITY else "setup" for c in tab.columns]
    print_setup(ss, units=units, area=f"A1:{get_column_letter(tab.shape[1])}{last}",
                title_rows="1:1", title_cols="A:B",
                group_starts=[j + 1 for j in range(1, len(group)) if group[j] != group[j - 1]],
                footer=f"{what}: the optimum, the baseline and the crate setups closest to it")
    rep = wb.create_sheet("solver")
    s = optimum.solver
    rows = [("optimum score (time domain)", optimum.score),
            ("crate best", optimum.crate_best),
            ("crate best score", float(optimum.table.loc[optimum.crate_best, "score"])),
            ("gain over the crate best", f"{100 * optimum.gap:.2f} %"),
            ("IPOPT status", s["status"] + (" (not converged: a warning)"
                                             if s.get("acceptable") else "")),
            ("IPOPT stop reason", stop_reason(s)),
            ("iterations", s["iterations"]),
            ("result taken from", {"ipopt": "IPOPT's solution", "iterate": "IPOPT's best "
                                   "feasible iterate", "scan": "the scan's best curve"}
             .get(s.get("source"), "IPOPT's solution")),
            ("IPOPT starts", "; ".join(
                f"{st['start']}: {st['iterations']} iterations, {st['status']}"
                for st in s.get("starts", []))),
            ("closed-loop evaluations", s["n_eval"]),
            ("adjoint sweeps", s["n_grad"]), ("compiled (jit)", s["jit"]),
            ("symmetry", optimum.space.symmetry),
            ("objective", optimum.objective.name),
            ("baseline", "/".join(optimum.baseline.ids())),
            *([("crate searched with the third-element choices", "; ".join(
                f"{k}: {', '.join(v)}" for k, v in optimum.settings["crate_third"].items()))]
              if optimum.settings.get("crate_third") else []),
            ("drives", ", ".join(optimum.settings["drives"])),
            ("units", units)]
    scan = optimum.settings.get("scan")
    if scan:
        d_unit = UNIT_LABELS[units]["damping"]

        def rate(c):
            return f"{from_si(c, 'damping', units):.0f}"

        rates = ", ".join(f"{name} {rate(c)} {d_unit}" for (name, _), c in
                          zip(optimum.space.groups, scan["rates_n_s_m"]))
        lo, hi, n = scan["grid_n_s_m"]
        rows += [("scan: linear rates per group",
                  f"{n} from {rate(lo)} to {rate(hi)} {d_unit}"),
                 ("scan: candidates / within the constraints (screened) / verified",
                  f"{scan['n_candidates']} / {scan['n_screened']} / {scan['n_verified']}"),
                 ("scan: best linear curves", rates),
                 ("scan: best linear score (time domain)", scan["linear_score"]),
                 ("scan: best curves", "; ".join(scan["curves"][units])),
                 ("scan: best score (time domain)", scan["score"])]
        # the scan's wall time is in settings["scan"], not here: a rerun writes the same bytes
    if optimum.stationarity is not None and len(optimum.stationarity):
        st = optimum.stationarity
        flat = st.groupby("variable")["relative_change"].apply(
            lambda r: bool(np.all(np.abs(r) < STATIONARY_FLAT)))
        rows.append(("largest gain of a +-5 % knot move",
                     f"{-100 * min(0.0, st.relative_change.min()):.4f} %"))
        rows.append(("variables whose +-5 % moves change the score by less than "
                     f"{100 * STATIONARY_FLAT:g} % (flat)", f"{int(flat.sum())} of {len(flat)}"))
    clicks = optimum.clicks
    if clicks is not None:
        best = clicks.best
        rows += [("clicks: best", "none searched" if best is None else best.setup.name),
                 ("clicks: best score (time domain)", "-" if best is None else best.score),
                 ("clicks: gain over the best fixed setup", f"{100 * clicks.gain:.2f} %"),
                 ("clicks: gap to the optimum (a custom valving)", f"{100 * clicks.gap:.2f} %"),
                 ("clicks: moves", f"+-1..{clicks.radius} steps of one adjuster, then the "
                                   "+-1 step product")]
    last = write_key_values(rep, rows)
    print_setup(rep, units=units, area=f"A1:B{last}", footer=f"{what}: the solver's report")
    tab = click_table(optimum)
    if tab is not None:
        cs = wb.create_sheet("clicks")
        last = write_table(cs, tab, formats={"score": "0.0000", "gain": "0.00%",
                                             "gap": "0.00%"}, freeze_cols=2)
        print_setup(cs, units=units, area=f"A1:{get_column_letter(tab.shape[1])}{last}",
                    title_rows="1:1", footer=f"{what}: the best clicks per adjustable shock "
                    f"and corner group; gain over the best fixed setup {clicks.crate_best}, "
                    "gap to the continuous optimum")
    write_summary_sheet(wb, units=units, footer=f"{what}: summary",
                        **_summary(optimum, units, run))
    wb.save(path)


#: What IPOPT's statuses other than the solved ones mean, for the workbook's stop reason.
_STOP_REASONS = {"Maximum_Iterations_Exceeded": "the iteration limit (--max-iter)",
                 "Maximum_CpuTime_Exceeded": "the time limit",
                 "User_Requested_Stop": "stopped on request"}


def stop_reason(solver):
    """Why IPOPT stopped, in words: ``converged`` only when it did.

    Parameters
    ----------
    solver : dict
        The optimum's solver record (``status``, ``converged``, ``reason``).

    Returns
    -------
    str
    """
    if solver.get("reason"):
        return solver["reason"]
    if solver.get("converged"):
        return "converged"
    status = solver.get("status", "unknown")
    return _STOP_REASONS.get(status, f"not converged ({status})")


def write_optimum(optimum, library, out_dir, *, units="SI", overwrite=False, run=None):
    """Write an optimum's files into a folder (built aside, then moved into place).

    Files: ``optimal_shocks.toml`` (the optimal shocks, table kind with lag, and the
    crate's, so the setups file reads against it), ``optimal_setup.csv`` (the optimum,
    then the crate setups closest to it), ``optimize.xlsx`` (the force table for the shock
    builder in `units`, the setups side by side, the solver's report),
    ``curves.png`` and ``convergence.csv``; with adjustable shocks in the crate,
    ``clicks.csv`` (:func:`click_table`), the click setups after the optimum in
    ``optimal_setup.csv`` and a ``clicks`` sheet. Each CSV's last column is ``units`` (`units` on
    every row).
    On a car with third elements, ``optimal_setup.csv`` and the ``setups`` sheet add the
    setups' third-element columns as predictions carry them (``heave_front``, ...,
    ``heave_spring_<axle>``: the ids the verification fitted, the car's baseline's); a
    car without them writes the same files as before. A crate searched over third-element
    choices (``settings["crate_third"]``: ``--try-heave``, ``--free-third``) adds its best
    setup, with its own third elements, after the optimum in ``optimal_setup.csv``, and the
    choices to the solver sheet.

    Parameters
    ----------
    optimum : CurveOptimum
    library : ShockLibrary
        The crate.
    out_dir : str or path
    units : {"SI", "imperial"}
        Units of the shock library, the metrics and ``curves.png``'s axes.
    overwrite : bool
        Replace an existing folder.
    run : dict of str to object, optional
        What the run used (model, drive, crate), on the workbook's first sheet, the one-page
        ``summary`` (the optimum, the crate's best, the baseline and the closest crate
        setups with their verdicts and key metrics).

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
    names = {"shocks": "optimal_shocks.toml", "setups": "optimal_setup.csv",
             "xlsx": "optimize.xlsx", "curves": "curves.png", "convergence": "convergence.csv"}
    with atomic_dir(out, overwrite=overwrite) as work:
        # (the crate's entries: its adjustables stay adjustable, the setups name settings)
        lib = ShockLibrary(list(optimum.shocks.values())
                           + [m for m in library.entries() if m.id not in optimum.shocks])
        write_shock_library(lib, work / names["shocks"], units=units)
        setups = _table_setups(optimum)
        clicks = [s for s in setups if optimum.table.loc[s.name, "kind"] == "clicks"]
        closest = [s for s in setups if s.name != optimum.setup.name
                   and optimum.table.loc[s.name, "kind"] == "closest"]
        optimal = _with_third(optimum.setup, _third_columns(optimum))
        # (a crate searched over third-element choices: its best, with its own, after the
        # optimum)
        best = [s for s in setups if s.name == optimum.crate_best != optimum.setup.name
                and optimum.settings.get("crate_third")]
        write_setups([optimal] + best + clicks + closest, work / names["setups"], units=units)
        _write_workbook(optimum, units, work / names["xlsx"], run=run)
        fig = curves_figure(optimum, library, units=units)
        fig.savefig(work / names["curves"], dpi=110, metadata=png_metadata(fig))
        # wall times are logged, not written: a rerun writes the same bytes
        write_csv(work / names["convergence"],
                  optimum.history.drop(columns=["time_s"], errors="ignore"), units=units,
                  float_format="%.9g")
        tab = click_table(optimum)
        if tab is not None:
            names["clicks"] = "clicks.csv"
            write_csv(work / names["clicks"], tab, units=units, float_format="%.9g")
    return {k: out / v for k, v in names.items()}


def _table_setups(optimum):
    third = _third_columns(optimum)
    return [Setup(n, dict(zip(CORNERS, (optimum.table.loc[n, c] for c in CORNERS))),
                  **_third_keys(third, n)) for n in optimum.table.index]


def _third_keys(third, name):
    """A setup's ``third`` and ``heave_springs`` keywords from its third-element columns
    (none without them)."""
    if not len(third.columns):
        return {}
    row = third.loc[name]
    dampers = {c: row[c] for c in third.columns if not c.startswith("heave_spring_")}
    springs = {c.rpartition("_")[2]: row[c] for c in third.columns
               if c.startswith("heave_spring_")}
    return {"third": dampers or None, "heave_springs": springs or None}


def _with_third(setup, third):
    """`setup` with the third-element columns of its row (itself without them)."""
    keys = _third_keys(third, setup.name) if setup.name in third.index else {}
    if not keys:
        return setup
    return Setup(setup.name, dict(setup.shocks), bump_stops=setup.bump_stops,
                 packers_m=setup.packers_m, **keys)
