"""The files of ``shockplan dyno table`` and ``shockplan dyno check``.

:func:`write_dyno_curve` writes a :class:`planner.dyno.check.DynoCurve` as the CSV a shock
builder reads (``velocity, force``, compression positive, the unit marker first).
:func:`write_dyno_check` writes a :class:`planner.dyno.check.DynoCheck` into a folder:
``summary.md``, ``findings.csv`` and, per adjustable shock, ``<id>.fit.csv`` (the model
against every measured point), ``<id>.worst.csv`` (the worst error per setting) and
``<id>.curves.png`` (:func:`check_figure`: measured points and model lines, one colour
per setting, one panel per adjuster sweep). Compute lives in :mod:`planner.dyno.check`.
matplotlib is imported where a figure is drawn (heavy).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ident.data.files import atomic_dir, png_metadata, write_csv
from ident.data.units import UNIT_LABELS, check_units, from_si
from ident.models.shocks import format_number
from planner.errors import PlannerError

__all__ = ["DYNO_CHECK_FILES", "safe_file_name", "write_dyno_curve", "check_figure", "fit_frame",
           "findings_frame", "check_summary", "write_dyno_check"]

#: The files of a check folder; ``{id}`` is the shock id made safe for a file name.
DYNO_CHECK_FILES = {"summary": "summary.md", "findings": "findings.csv",
                    "fit": "{id}.fit.csv", "worst": "{id}.worst.csv",
                    "curves": "{id}.curves.png"}
#: Panels per row of a check figure.
PANEL_COLUMNS = 2


def safe_file_name(name):
    """`name` with every character but letters, digits, ``-``, ``_`` and ``.`` as ``_``.

    Examples
    --------
    >>> safe_file_name("TTX rear/2")
    'TTX_rear_2'
    """
    keep = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in str(name))
    return keep.strip("_") or "shock"


def write_dyno_curve(curve, path, *, overwrite=False):
    """Write a curve table: ``velocity, force`` in the curve's units, atomically.

    Parameters
    ----------
    curve : DynoCurve
    path : str or path
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    FileExistsError
        If `path` exists and `overwrite` is false.
    """
    write_csv(path, curve.to_frame(), units=curve.units, overwrite=overwrite)
    return Path(path)


def fit_frame(shock_check, *, units="SI"):
    """A shock's fit table in `units` (``velocity``, ``force_measured``, ``force_model``
    converted; ``error_pct`` and the rest unchanged), or None without a model."""
    if shock_check.fit is None:
        return None
    out = shock_check.fit.copy()
    out["velocity"] = from_si(out["velocity"].to_numpy(), "velocity", units)
    for c in ("force_measured", "force_model"):
        out[c] = from_si(out[c].to_numpy(), "force", units)
    return out


def findings_frame(check):
    """Every finding of a check, one row each: ``shock, severity, adjuster, setting,
    row, message`` (a library refused for a reason no finding explains: one row with
    ``shock`` empty)."""
    rows = [{"shock": f.shock, "severity": f.severity, "adjuster": f.adjuster,
             "setting": f.setting, "row": f.row, "message": f.message}
            for s in check.shocks for f in s.findings]
    if check.library_error and not any(r["severity"] == "error" for r in rows):
        rows.append({"shock": "", "severity": "error", "adjuster": "", "setting": "",
                     "row": "", "message": check.library_error})
    return pd.DataFrame(rows, columns=["shock", "severity", "adjuster", "setting", "row",
                                       "message"])


def check_figure(shock_check, *, units="SI"):
    """The measured curves of one adjustable shock and its model, per setting.

    One panel per adjuster sweep (the settings that differ in that adjuster only; the
    rest in a last panel); in each, one colour per setting from soft to stiff: the
    measured points as markers, the model at that setting as a line over the measured
    speeds; without a model (an error), the measured points joined by dotted lines.
    Points named by an error are circled in red, by a warning in orange (a crossing in
    the panel of the adjuster it is about).

    Parameters
    ----------
    shock_check : ShockCheck
    units : {"SI", "imperial"}
        Display units: velocity [m/s] and force [N], or [in/s] and [lbf].

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib import colormaps  # heavy: loaded only when a figure is drawn
    from matplotlib.figure import Figure

    units = check_units(units, where="units", error=PlannerError)
    v_unit, f_unit = UNIT_LABELS[units]["velocity"], UNIT_LABELS[units]["force"]
    panels = shock_check.panels or (("measured settings", ()),)
    n = len(panels)
    ncols = min(PANEL_COLUMNS, n)
    nrows = -(-n // ncols)
    fig = Figure(figsize=(6.2 * ncols, 4.6 * nrows + 0.5), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False).ravel())
    cmap = colormaps["viridis"]
    for ax, (title, members) in zip(axes, panels):
        curves = [shock_check.curves[j] for j in members]
        # soft to stiff: the first adjuster that varies in the panel, towards 'stiffer'
        varying = [a for a in shock_check.adjusters
                   if len({c.settings[a] for c in curves}) > 1]
        if varying:
            a = varying[0]
            sign = -1.0 if shock_check.stiffer.get(a, "lower") == "lower" else 1.0
            curves = sorted(curves, key=lambda c: sign * c.settings[a])
        marks = {"error": ([], []), "warning": ([], [])}
        for k, c in enumerate(curves):
            colour = cmap(0.9 * k / max(len(curves) - 1, 1))
            label = (",".join(f"{a}={format_number(c.settings[a])}" for a in varying)
                     if varying else c.name.partition("@")[2] or c.name)
            v = from_si(c.velocity_m_s, "velocity", units)
            f = from_si(c.force_n, "force", units)
            ax.plot(v, f, "o", ms=4, color=colour, label=label)
            if c.model_v_m_s is not None:
                ax.plot(from_si(c.model_v_m_s, "velocity", units),
                        from_si(c.model_f_n, "force", units), "-", lw=1.3, color=colour)
            else:  # no model: the measured curve joined, to show where curves cross
                order = np.argsort(v)
                ax.plot(v[order], f[order], ":", lw=0.9, color=colour)
            for j, flags in enumerate(c.flags):
                # a crossing of another adjuster's sweep is that sweep's panel's
                found = {sev for sev, adj in flags if not adj or adj in varying}
                if found:
                    sev = "error" if "error" in found else "warning"
                    marks[sev][0].append(v[j])
                    marks[sev][1].append(f[j])
        for sev, colour in (("error", "red"), ("warning", "darkorange")):
            if marks[sev][0]:
                ax.plot(*marks[sev], "o", ms=11, mfc="none", mec=colour, mew=1.6,
                        label=f"row named by {'an' if sev == 'error' else 'a'} {sev}")
        ax.axhline(0.0, color="0.6", lw=0.6)
        ax.axvline(0.0, color="0.6", lw=0.6)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(f"velocity [{v_unit}] (compression +)")
        ax.set_ylabel(f"force [{f_unit}]")
        ax.grid(True, lw=0.3, alpha=0.6)
        if curves:
            ax.legend(fontsize=7, ncols=2 if len(curves) > 6 else 1, loc="upper left")
    for ax in axes[n:]:
        ax.set_visible(False)
    state = (f"markers: measured, lines: the model; worst error {_worst_text(shock_check)}"
             if shock_check.shock is not None else
             f"markers: measured, dotted: joined; NO MODEL: {len(shock_check.errors)} "
             "error(s)")
    fig.suptitle(f"{shock_check.id}: dyno curves per setting ({state})", fontsize=11)
    return fig


def _worst_text(shock_check):
    w = shock_check.worst
    if w is None or w.empty:
        return "-"
    k = int(np.argmax(np.abs(w["worst_error_pct"].to_numpy())))
    return f"{w['worst_error_pct'].iloc[k]:+.2f} % at {w['setting'].iloc[k]}"


def _md_table(frame):
    cols = [str(c) for c in frame.columns]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for row in frame.itertuples(index=False):
        out.append("| " + " | ".join(str(x).replace("|", "\\|") for x in row) + " |")
    return out


def check_summary(check, files=None, *, units=None):
    """The check as markdown: per shock its status, worst error per setting and
    every finding with its row.

    Parameters
    ----------
    check : DynoCheck
    files : dict of str to list of str, optional
        Per shock id, the files written for it (listed under the shock).
    units : {"SI", "imperial"}, optional
        Units of the velocities shown (default: the library's).

    Returns
    -------
    str
    """
    units = check_units(units or check.units, where="units", error=PlannerError)
    v_unit = UNIT_LABELS[units]["velocity"]
    verdict = ("no errors" if check.ok else f"{check.n_errors} error(s)") + \
        f", {check.n_warnings} warning(s)"
    lines = [f"# Dyno check of {check.library}", "",
             f"{len(check.shocks)} adjustable shock(s), {len(check.fixed)} fixed; {verdict}. "
             f"Units: {units}. A curve softer towards `stiffer` by more than "
             f"{100 * check.settings.get('monotone_rtol', 0):.0f} % is an error, by less a "
             "warning (fitted flat).", ""]
    if check.library_error:
        lines += ["The library cannot be read by the other commands:", "",
                  f"    {check.library_error}", ""]
    for s in check.shocks:
        status = ("model built" if s.shock is not None else "NO MODEL (errors below)")
        lines += [f"## {s.id}", "", f"{s.entry}; adjusters {list(s.adjusters)}, stiffer "
                  f"{s.stiffer}; {len(s.curves)} measured setting(s); {status}; "
                  f"{len(s.errors)} error(s), {len(s.warnings)} warning(s).", ""]
        if s.worst is not None:
            w = s.worst.copy()
            w["velocity"] = [f"{x:.4g}" for x in from_si(w["velocity"].to_numpy(),
                                                         "velocity", units)]
            w["worst_error_pct"] = [f"{x:+.2f}" for x in w["worst_error_pct"]]
            w["rms_error_pct"] = [f"{x:.2f}" for x in w["rms_error_pct"]]
            w = w.rename(columns={"velocity": f"at velocity [{v_unit}]",
                                  "worst_error_pct": "worst error [%]",
                                  "rms_error_pct": "rms error [%]", "row": "worst row"})
            lines += ["Model against the measured points (model less measured, % of "
                      "measured), per setting:", ""] + _md_table(w) + [""]
        for f in s.findings:
            lines.append(f"- **{f.severity}**: {f.message}")
        if s.findings:
            lines.append("")
        if files and files.get(s.id):
            lines += ["Files: " + ", ".join(f"`{x}`" for x in files[s.id]), ""]
    return "\n".join(lines).rstrip() + "\n"


def write_dyno_check(check, out_dir, *, units=None, overwrite=False):
    """Write a check's files into a folder (built aside, then moved into place).

    Parameters
    ----------
    check : DynoCheck
    out_dir : str or path
    units : {"SI", "imperial"}, optional
        Units of the CSVs and figures (default: the library's).
    overwrite : bool
        Replace an existing, non-empty folder.

    Returns
    -------
    dict of str to pathlib.Path
        ``summary``, ``findings``, and per shock ``<id>.fit``, ``<id>.worst``,
        ``<id>.curves`` for the files written.

    Raises
    ------
    FileExistsError
        If `out_dir` exists, is not empty and `overwrite` is false (checked first).
    """
    units = check_units(units or check.units, where="units", error=PlannerError)
    out = Path(out_dir)
    written, per_shock = {}, {}
    with atomic_dir(out, overwrite=overwrite) as work:
        for s in check.shocks:
            stem = safe_file_name(s.id)
            names = []
            fit = fit_frame(s, units=units)
            if fit is not None:
                name = DYNO_CHECK_FILES["fit"].format(id=stem)
                write_csv(work / name, fit, units=units)
                names.append(name)
                worst = s.worst.copy()
                worst["velocity"] = from_si(worst["velocity"].to_numpy(), "velocity", units)
                name = DYNO_CHECK_FILES["worst"].format(id=stem)
                write_csv(work / name, worst, units=units)
                names.append(name)
            if s.curves:
                name = DYNO_CHECK_FILES["curves"].format(id=stem)
                fig = check_figure(s, units=units)
                fig.savefig(work / name, dpi=100, metadata=png_metadata(fig))
                names.append(name)
            per_shock[s.id] = names
            for name in names:
                written[f"{s.id}.{name.rsplit('.', 2)[-2]}"] = out / name
        write_csv(work / DYNO_CHECK_FILES["findings"], findings_frame(check), units=units)
        (work / DYNO_CHECK_FILES["summary"]).write_text(
            check_summary(check, per_shock, units=units), encoding="utf-8")
    written["summary"] = out / DYNO_CHECK_FILES["summary"]
    written["findings"] = out / DYNO_CHECK_FILES["findings"]
    return written
