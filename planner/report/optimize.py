"""The optimizer's files: its shocks and setups, ``optimize.xlsx``, ``curves.png``, convergence.

:func:`write_optimum` writes a :class:`planner.optimize.CurveOptimum` into a
folder; :func:`curve_table` is the shock builder's force table (the xlsx's
curve sheets) and :func:`curves_figure` the optimal curves against the
crate's. Compute lives in :mod:`planner.optimize`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from openpyxl import Workbook
from openpyxl.styles import Font

from ident.data.channels import CORNERS
from ident.data.files import atomic_dir
from ident.data.units import check_units, from_si, to_si
from ident.models.library import ShockLibrary, write_shock_library
from ident.sim.metrics import METRIC_NAMES
from planner.errors import PlannerError
from planner.report.ranking import ranking_to_units
from planner.setups import Setup, write_setups

__all__ = [
    "BUILDER_VELOCITIES_M_S",
    "BUILDER_VELOCITIES_IN_S",
    "curve_table",
    "curves_figure",
    "write_optimum",
]

#: Velocities of the shock builder's force table [m/s] and [in/s].
BUILDER_VELOCITIES_M_S = (0.0125, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.25, 0.35, 0.5, 0.75, 1.0)
BUILDER_VELOCITIES_IN_S = (0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0, 40.0)


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


def curves_figure(optimum, library):
    """The optimal curves against the crate's, with the optimum's shock-velocity histograms.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure  # heavy: loaded only when a figure is drawn

    G = len(optimum.space.groups)
    fig = Figure(figsize=(5.5 * G, 4.6), layout="constrained")
    axes = fig.subplots(1, G, squeeze=False)[0]
    v = np.linspace(-0.6, 0.6, 241)
    for ax, (name, corners), pwl in zip(axes, optimum.space.groups, optimum.curves):
        samples = np.concatenate([optimum.velocity_m_s[c] for c in corners])
        hist = ax.twinx()
        hist.hist(samples, bins=np.linspace(-0.6, 0.6, 61), color="#d9e6f2", density=True)
        hist.set_yticks([])
        ax.set_zorder(hist.get_zorder() + 1)
        ax.patch.set_visible(False)
        for k, m in enumerate(library.values()):
            ax.plot(v, m.force(v), color="0.7", lw=0.8, label="crate" if k == 0 else None)
        for sid in set(optimum.table.loc[optimum.crate_best, list(corners)]):
            ax.plot(v, library[sid].force(v), color="tab:orange", lw=1.6,
                    label=f"crate best ({sid})")
        ax.plot(v, pwl.force(v), color="tab:blue", lw=2.2, label=f"optimum ({name})")
        ax.plot(pwl.v_knots_m_s, pwl.f_knots_n, "o", color="tab:blue", ms=4)
        ax.axhline(0, color="0.5", lw=0.6)
        ax.axvline(0, color="0.5", lw=0.6)
        ax.set(xlabel="shock velocity [m/s] (compression +)", ylabel="force [N]",
               title=f"{name}: {', '.join(corners)}", xlim=(-0.6, 0.6))
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(f"optimal curves (score {optimum.score:.4f}) and the crate; shaded: the "
                 "optimum's shock velocities", fontsize=10)
    return fig


def _setups_sheet(optimum, units):
    first = next(iter(optimum.metrics))
    met = optimum.metrics[first].loc[optimum.table.index]
    metric_cols = [c for c in met.columns if c in METRIC_NAMES]
    t = optimum.table.copy()
    t = pd.concat([t, ranking_to_units(met[metric_cols], units)], axis=1)
    return t.reset_index()


def write_optimum(optimum, library, out_dir, *, units="SI", overwrite=False):
    """Write an optimum's files into a folder (built aside, then moved into place).

    Files: ``optimal_shocks.toml`` (the optimal shocks, table kind with lag, and the
    crate's, so the setups file reads against it), ``optimal_setup.csv`` (the optimum,
    then the crate setups closest to it), ``optimize.xlsx`` (force tables for the shock
    builder in SI and imperial, the setups side by side, the solver's report),
    ``curves.png`` and ``convergence.csv``.

    Parameters
    ----------
    optimum : CurveOptimum
    library : ShockLibrary
        The crate.
    out_dir : str or path
    units : {"SI", "imperial"}
        Units of the shock library and the metrics.
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
    names = {"shocks": "optimal_shocks.toml", "setups": "optimal_setup.csv",
             "xlsx": "optimize.xlsx", "curves": "curves.png", "convergence": "convergence.csv"}
    with atomic_dir(out, overwrite=overwrite) as work:
        lib = ShockLibrary(list(optimum.shocks.values())
                           + [m for m in library.values() if m.id not in optimum.shocks])
        write_shock_library(lib, work / names["shocks"], units=units)
        closest = [s for s in _table_setups(optimum) if s.name != optimum.setup.name
                   and optimum.table.loc[s.name, "kind"] == "closest"]
        write_setups([optimum.setup] + closest, work / names["setups"])
        wb = Workbook()
        ws = wb.active
        ws.title = "curves SI"
        for title, u in (("curves SI", "SI"), ("curves imperial", "imperial")):
            sheet = ws if title == "curves SI" else wb.create_sheet(title)
            tab = curve_table(optimum, units=u).round(1).reset_index()
            sheet.append(list(tab.columns))
            for row in tab.itertuples(index=False):
                sheet.append([float(x) for x in row])
            for cell in sheet[1]:
                cell.font = Font(bold=True)
            sheet.freeze_panes = "B2"
        ss = wb.create_sheet("setups")
        tab = _setups_sheet(optimum, units)
        ss.append(list(tab.columns))
        for row in tab.itertuples(index=False):
            ss.append([x.item() if hasattr(x, "item") else x for x in row])
        for cell in ss[1]:
            cell.font = Font(bold=True)
        ss.freeze_panes = "B2"
        rep = wb.create_sheet("solver")
        s = optimum.solver
        for key, value in (("optimum score (time domain)", optimum.score),
                           ("crate best", optimum.crate_best),
                           ("crate best score", float(optimum.table.loc[optimum.crate_best,
                                                                         "score"])),
                           ("gain over the crate best", f"{100 * optimum.gap:.2f} %"),
                           ("IPOPT status", s["status"]), ("iterations", s["iterations"]),
                           ("closed-loop evaluations", s["n_eval"]),
                           ("adjoint sweeps", s["n_grad"]), ("compiled (jit)", s["jit"]),
                           ("symmetry", optimum.space.symmetry),
                           ("objective", optimum.objective.name),
                           ("baseline", "/".join(optimum.baseline.ids())),
                           ("drives", ", ".join(optimum.settings["drives"])),
                           ("units", units)):
            rep.append([key, value])
        if optimum.stationarity is not None and len(optimum.stationarity):
            rep.append(["largest gain of a +-5 % knot move",
                        f"{-100 * min(0.0, optimum.stationarity.relative_change.min()):.3f} %"])
        rep.column_dimensions["A"].width = 34
        rep.column_dimensions["B"].width = 40
        wb.save(work / names["xlsx"])
        fig = curves_figure(optimum, library)
        fig.savefig(work / names["curves"], dpi=110)
        # wall times are logged, not written: a rerun writes the same bytes
        optimum.history.drop(columns=["time_s"], errors="ignore").to_csv(
            work / names["convergence"], index=False, float_format="%.9g")
    return {k: out / v for k, v in names.items()}


def _table_setups(optimum):
    return [Setup(n, dict(zip(CORNERS, (optimum.table.loc[n, c] for c in CORNERS))))
            for n in optimum.table.index]
