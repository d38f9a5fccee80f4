"""The report of ``shockplan drive from-track`` and ``drive iterate``.

:func:`write_drive_report` writes a :class:`planner.trackdrive.TrackDrive`'s report folder:

- ``residuals.csv``: per iteration and target channel, the residual RMS (1-20 Hz, in the
  run's units) and its share of the target's RMS; channel ``all`` is the RMS over channels
  of the shares;
- ``reach.csv``: per target channel, the share of its power (1-20 Hz) the rig inputs cannot
  reach through the linearized loop (what no drive can reproduce on this model);
- ``limits.csv``: where the rig's limits changed the drive (only when they did);
- ``target.csv``: the target (each log's dynamic part at the drive's rate, faded at the
  ends), a track log that ``drive iterate`` reads back;
- ``psd.png``: target and achieved power spectra per channel (:func:`psd_figure`);
- ``convergence.png``: residual share against iteration (:func:`convergence_figure`);
- ``histograms.csv`` (``drive from-track``): the logged shock-velocity histogram per corner
  (setup ``logged``) beside the one the drive reproduces on the model with the track setup
  (``reproduced``), the columns of :mod:`planner.histograms`.

Compute lives in :mod:`planner.trackdrive`; matplotlib is imported where a figure is drawn
(heavy).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy import signal

from ident.data.channels import quantity_of
from ident.data.files import atomic_dir, png_metadata, write_csv
from ident.data.tracklog import TrackLog, write_track_log
from ident.data.units import UNIT_LABELS, check_units, from_si

__all__ = ["DRIVE_REPORT_FILES", "residual_table", "psd_figure", "convergence_figure",
           "write_drive_report", "target_log"]

#: The files of a drive report folder.
DRIVE_REPORT_FILES = {"residuals": "residuals.csv", "reach": "reach.csv",
                      "limits": "limits.csv", "target": "target.csv", "psd": "psd.png",
                      "convergence": "convergence.png", "histograms": "histograms.csv"}
#: Welch segment of the PSD overlays [s] (0.125 Hz resolution).
PSD_SEGMENT_S = 8.0


def residual_table(result, *, units="SI"):
    """The residual history in `units`: ``iteration, channel, residual_rms, unit,
    residual_share``."""
    units = check_units(units, where="residual_table: units")
    h = result.history.copy()
    rms, unit = [], []
    for c, v in zip(h["channel"], h["residual_rms"]):
        if c == "all":
            rms.append(np.nan)
            unit.append("-")
            continue
        q = quantity_of(c)
        rms.append(float(from_si(v, q, units)))
        unit.append(UNIT_LABELS[units][q])
    return pd.DataFrame({"iteration": h["iteration"], "channel": h["channel"],
                         "residual_rms": rms, "unit": unit,
                         "residual_share": h["residual_share"]})


def target_log(result):
    """The target as a :class:`ident.data.tracklog.TrackLog` (its channels at the drive's
    rate, SI), for ``target.csv``."""
    t = result.target
    channels = {c: np.array(v, float) for c, v in t.channels.items()}
    for v in channels.values():
        v.flags.writeable = False
    return TrackLog(name=t.name, fs_hz=t.fs_hz, channels=channels,
                    settings={"source": "target", "format": "csv", "units": "SI", "map": None,
                              "t0_s": 0.0, "resampled": []})


def psd_figure(result, *, units="SI"):
    """Target and achieved PSDs of every target channel, one panel each.

    Parameters
    ----------
    result : planner.trackdrive.TrackDrive
    units : {"SI", "imperial"}

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib  # heavy: imported where a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = result.target
    names = list(t.channels)
    ncol = 4 if len(names) >= 4 else len(names)
    nrow = int(np.ceil(len(names) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 2.9 * nrow), squeeze=False,
                             sharex=True)
    nper = min(int(PSD_SEGMENT_S * t.fs_hz), t.n_samples)
    mask = t.interior()
    for ax, c in zip(axes.ravel(), names):
        q = quantity_of(c)
        scale = float(from_si(1.0, q, units))
        f, pt = signal.welch(t.channels[c][mask] * scale, fs=t.fs_hz, nperseg=nper)
        _, pa = signal.welch(np.asarray(result.response[c])[mask] * scale, fs=t.fs_hz,
                             nperseg=nper)
        _, pr = signal.welch((t.channels[c] - np.asarray(result.response[c]))[mask] * scale,
                             fs=t.fs_hz, nperseg=nper)
        keep = f > 0
        ax.loglog(f[keep], pt[keep], color="black", lw=1.2, label="target")
        ax.loglog(f[keep], pa[keep], color="tab:blue", lw=1.0, ls="--", label="achieved")
        ax.loglog(f[keep], pr[keep], color="tab:red", lw=0.8, alpha=0.8, label="residual")
        ax.axvspan(*t.band_hz, color="0.92", zorder=0)
        derived = t.settings.get("derived", {}).get(c)
        ax.set_title(c if derived is None else f"{c} (from {derived})", fontsize=9)
        ax.set_ylabel(f"PSD [({UNIT_LABELS[units][q]})^2/Hz]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_xlim(0.2, t.fs_hz / 2)
        ax.grid(True, which="major", alpha=0.3)
    for ax in axes.ravel()[len(names):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("frequency [Hz]", fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="lower left")
    fig.suptitle(f"drive '{result.drive.name}': target and achieved, band "
                 f"{t.band_hz[0]:g}-{t.band_hz[1]:g} Hz shaded", fontsize=10)
    fig.tight_layout()
    return fig


def convergence_figure(result):
    """Residual share (1-20 Hz) of each channel against iteration.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib  # heavy: imported where a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (the axis formatters)

    h = result.history
    fig, ax = plt.subplots(figsize=(6.5, 4.0))
    for c, g in h.groupby("channel", sort=False):
        style = {"color": "black", "lw": 2.0} if c == "all" else {"lw": 1.0, "alpha": 0.8}
        ax.semilogy(g["iteration"], 100 * g["residual_share"], marker="o", ms=3, label=c,
                    **style)
    best = result.settings.get("best_iteration")
    if best is not None:
        ax.axvline(best, color="0.5", ls=":", lw=1)
    ax.set_xlabel("iteration (1: the plain frequency-domain inverse)")
    ax.set_ylabel("residual RMS / target RMS, 1-20 Hz [%]")
    ax.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.yaxis.set_minor_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return fig


def write_drive_report(result, out, *, units="SI", overwrite=False, histograms=None):
    """Write a drive's report folder (files in the module docstring), atomically.

    Parameters
    ----------
    result : planner.trackdrive.TrackDrive
    out : str or path
        The folder; an existing non-empty one is replaced only with `overwrite`.
    units : {"SI", "imperial"}
    overwrite : bool
    histograms : planner.histograms.ShockHistograms, optional
        The logged shock-velocity histogram beside the one the drive reproduces on the model
        (``drive from-track``): written as ``histograms.csv``.

    Returns
    -------
    pathlib.Path
    """
    import matplotlib  # heavy: imported where a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    units = check_units(units, where="write_drive_report: units")
    out = Path(out)
    with atomic_dir(out, overwrite=overwrite) as work:
        write_csv(work / DRIVE_REPORT_FILES["residuals"], residual_table(result, units=units),
                  units=units)
        write_csv(work / DRIVE_REPORT_FILES["reach"], result.reach.reset_index(), units=units)
        if result.limits is not None and len(result.limits.report):
            write_csv(work / DRIVE_REPORT_FILES["limits"], result.limits.report, units="SI")
        if all(quantity_of(c) for c in result.target.channels) and not \
                result.target.settings.get("derived"):
            write_track_log(target_log(result), work / DRIVE_REPORT_FILES["target"], units=units)
        if histograms is not None:
            write_csv(work / DRIVE_REPORT_FILES["histograms"], histograms.table(units),
                      units=units)
        for key, fig in (("psd", psd_figure(result, units=units)),
                         ("convergence", convergence_figure(result))):
            fig.savefig(work / DRIVE_REPORT_FILES[key], dpi=110, metadata=png_metadata(fig))
            plt.close(fig)
    return out
