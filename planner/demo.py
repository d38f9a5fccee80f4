"""``shockplan demo``: the main job on the built-in example, end to end.

Writes everything to one output folder and returns a short text summary.
Stages: the virtual rig writes the seed paper's identification experiment on
the paper's car as a rig session; the per-run RMS metrics of the session are
tabulated. (Identification and ranking join the demo as they land.)
"""

from __future__ import annotations

import logging
import shutil
import tempfile
from pathlib import Path

__all__ = ["run_demo"]

log = logging.getLogger(__name__)


def run_demo(out, *, overwrite=False, progress=True):
    """Run the demo into folder `out`.

    Parameters
    ----------
    out : str or Path
        Output folder; must not exist (or be empty) unless `overwrite`.
    overwrite : bool
        Replace an existing folder once the new results are complete.
    progress : bool
        Show progress bars.

    Returns
    -------
    str
        A short summary for the terminal.

    Raises
    ------
    FileExistsError
        If `out` exists, is not empty and `overwrite` is false.
    """
    import pandas as pd

    from ident._io import check_can_write
    from ident.metrics import compute_metrics
    from ident.rig import default_plan, simulate_session
    from ident.session import write_session
    from ident.vehicle import example_vehicle, modal_summary

    out = Path(out)
    if out.exists() and any(out.iterdir()):
        check_can_write(out, overwrite=overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        vehicle = example_vehicle()
        plan = default_plan()
        session = simulate_session(plan, vehicle, progress=progress)
        write_session(session, work / "session", units=plan.units)
        modes = modal_summary(vehicle).table()
        modes.to_csv(work / "modes.csv", index=False)
        rows = []
        for run in session.runs:
            m = compute_metrics(run, static_loads_n=dict(zip(("LF", "RF", "LR", "RR"),
                                                             vehicle.static_corner_load_n)))
            rows.append(m.as_series(units=plan.units).rename(run.name))
        metrics = pd.DataFrame(rows)
        metrics.index.name = "run"
        metrics.to_csv(work / "session_metrics.csv")
        if out.exists():
            shutil.rmtree(out)
        work.rename(out)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    lines = [
        f"shockplan demo -> {out}",
        f"  vehicle: {vehicle.name}",
        f"  rig session: {out / 'session'} ({len(session.runs)} runs x "
        f"{session.runs[0].n_samples / session.fs_hz:g} s at {session.fs_hz:g} Hz)",
        "  natural frequencies [Hz]: " + ", ".join(
            f"{lab} {f:.2f}" for lab, f in zip(modes["mode"], modes["undamped_hz"])),
        f"  per-run metrics ({plan.units}): {out / 'session_metrics.csv'}",
    ]
    cols = [c for c in ("tire_force_rms_LF", "ride_height_rms_front", "shock_velocity_rms_LF")
            if c in metrics]
    lines.append(metrics[cols].to_string(float_format=lambda x: f"{x:.4g}"))
    return "\n".join(lines)
