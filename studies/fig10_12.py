"""Validation: identified model against the known car on crate setups (paper Figs. 10-12).

The virtual rig runs the seed paper's identification plan (``ident.sim.virtual_rig.default_plan``,
runs of ``--run-s``, no sensor noise) on the paper's car and shockplan
identifies it with the defaults of ``ident.identify.pipeline.identify_session``; only the
outputs the metrics need are identified (``planner.predict.METRIC_OUTPUTS``:
every output is estimated and fitted on its own, so these pairs are those of a
full identification). Both the identified model and the known car (the same
closed-loop simulator, ``--model paper`` in the CLI) then simulate a set of
shock setups of the built-in crate on a fresh realization of the plan's
band-limited white-noise drive (seed 7, not the identification drive):

- ``baseline``: the linear B20 all round (the identification baseline);
- ``DS-LF`` ... ``DS-RR``: one corner swapped to the digressive ``DS`` (soft high
  speed, 3 ms lag), as the paper swaps one corner at a time to a nonlinear
  dynamic shock;
- ``DM-all``: the digressive ``DM`` all round (every corner nonlinear);
- ``L12-front``: soft linear L12 in front, firm linear L28 at the rear.

Figures, as the paper's: ``fig10.png`` the band-passed (1-20 Hz) time histories of
LF tire force, front ride height and LF shock travel, predicted and true, for
the baseline and the LF and RF swaps; ``fig11.png`` their power spectral
densities with the error's; ``fig12.png`` the RMS metrics predicted against
true per setup, and the prediction errors.

Writes ``fig10_12.csv`` (one row per setup and metric: predicted, true, error
in %, SI units) and ``fig10_12_traces.csv`` (per plotted setup and channel: the
RMS of the signal and of the error trace, and how far the error's PSD peak lies
below the signal's, in dB; the paper: ride-height errors about 50 dB below the
signal, tire force more than 20 dB, the worst trace error about 25 % of the
signal level).

    python studies/fig10_12.py --out DIR [--run-s 800] [--drive-s 120] [--outputs ...]
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import welch

from ident.sim.closedloop import simulate_batch
from ident.identify.condition import condition_frf
from ident.identify.frf import estimate_frf
from ident.sim.metrics import METRIC_QUANTITY, bandpass
from ident.identify.pipeline import fit_model
from ident.sim.virtual_rig import default_plan, make_plan_drive, simulate_session
from ident.models.library import read_shock_library
from ident.data.units import from_si
from ident.models.vehicle import build_full_car, example_vehicle
from planner.demo import DEMO_LIBRARY_PATH
from planner.plant import as_loop_plant
from planner.predict import METRIC_OUTPUTS, predict_setups, resolve_setups
from planner.setups import Setup
from planner.options import LoopOptions

log = logging.getLogger("studies.fig10_12")

CORNERS = ("LF", "RF", "LR", "RR")
#: Setups of paper Fig. 10 (time histories and PSDs).
TRACE_SETUPS = ("baseline", "DS-LF", "DS-RF")
#: Plotted channels: name -> (model outputs averaged, quantity, display unit).
TRACE_CHANNELS = {"tire_force_LF": (("tire_force_LF",), "force", "lbf"),
                  "ride_height_front": (("ride_height_LF", "ride_height_RF"), "displacement",
                                        "in"),
                  "shock_travel_LF": (("shock_travel_LF",), "displacement", "in")}
#: Metrics of the bar chart (fig12.png).
BAR_METRICS = ("tire_force_rms_LF", "tire_force_rms_LR", "ride_height_rms_front",
               "ride_height_rms_rear", "shock_travel_rms_LF", "shock_velocity_rms_LF")
#: Oversampling of the shock loop (``predict_setups``' default).
OVERSAMPLE = 2
#: Range of the PSD axes below the signal's peak [dB].
PSD_RANGE_DB = 100.0
#: Drive seed of the validation (the identification drive has the plan's seed, 2009).
DRIVE_SEED = 7


def study_setups():
    """The validation setups (see the module docstring)."""
    base = {c: "B20" for c in CORNERS}
    setups = [Setup("baseline", base)]
    setups += [Setup(f"DS-{c}", dict(base, **{c: "DS"})) for c in CORNERS]
    setups.append(Setup("DM-all", {c: "DM" for c in CORNERS}))
    setups.append(Setup("L12-front", {"LF": "L12", "RF": "L12", "LR": "L28", "RR": "L28"}))
    return setups


def identify(plan, run_s, outputs, vehicle):
    """Simulate `plan` with runs of `run_s`; identify `outputs` (``identify_session`` defaults)."""
    plan = replace(plan, runs=tuple(replace(r, duration_s=run_s) for r in plan.runs))
    t0 = time.perf_counter()
    session = simulate_session(plan, vehicle)
    t1 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frf = condition_frf(estimate_frf(session, outputs=list(outputs)))
        model = fit_model(frf, name=session.name, units=session.units)
    log.info("simulated %d runs of %g s in %.1f s, identified %d outputs in %.1f s",
             len(plan.runs), run_s, t1 - t0, len(outputs), time.perf_counter() - t1)
    return model


def traces(plant, drive, setups, library):
    """Band-passed traces of TRACE_CHANNELS (those the plant has), per setup, SI."""
    chans = {k: v for k, v in TRACE_CHANNELS.items()
             if all(o in plant.output_names for o in v[0])}
    outputs = sorted({o for v in chans.values() for o in v[0]})
    batch = simulate_batch(plant, drive, resolve_setups(setups, library), oversample=OVERSAMPLE,
                           outputs=outputs)
    out = {}
    for name, (outs, _, _) in chans.items():
        x = np.mean([batch.channels[o] for o in outs], axis=0)
        x = x - x.mean(axis=-1, keepdims=True)
        out[name] = bandpass(x, fs=batch.fs_hz)
    return out, batch.fs_hz


def trace_rows(pred, true, fs, setups):
    """Per setup and channel: signal and error RMS, PSD peak of the error below the signal's."""
    rows = []
    for name in pred:
        for k, s in enumerate(setups):
            sig, err = true[name][k], pred[name][k] - true[name][k]
            f, ps = welch(sig, fs=fs, nperseg=1024)
            _, pe = welch(err, fs=fs, nperseg=1024)
            band = (f >= 1.0) & (f <= 20.0)
            rows.append({"setup": s.name, "channel": name,
                         "signal_rms_si": float(np.sqrt(np.mean(sig ** 2))),
                         "error_rms_si": float(np.sqrt(np.mean(err ** 2))),
                         "error_pct_of_signal": 100 * float(np.sqrt(np.mean(err ** 2))
                                                            / np.sqrt(np.mean(sig ** 2))),
                         "max_abs_error_pct_of_peak": 100 * float(np.abs(err).max()
                                                                  / np.abs(sig).max()),
                         "psd_peak_error_below_signal_db": float(
                             10 * np.log10(ps[band].max() / pe[band].max()))})
    return rows


def plot_traces(pred, true, fs, setups, window_s, path):
    """Fig. 10: predicted and true band-passed traces over `window_s`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(pred)
    n0 = int(round(5.0 * fs))  # skip the filter's start-up transient
    n = int(round(window_s * fs))
    t = np.arange(n) / fs + n0 / fs
    fig, axes = plt.subplots(len(names), len(setups), figsize=(4 * len(setups), 2.6 * len(names)),
                             squeeze=False, constrained_layout=True, sharex=True)
    for i, name in enumerate(names):
        _, q, unit = TRACE_CHANNELS[name]
        scale = from_si(1.0, q, "imperial")
        for k, s in enumerate(setups):
            ax = axes[i, k]
            ax.plot(t, true[name][k, n0:n0 + n] * scale, "k", lw=1.0, label="known car")
            ax.plot(t, pred[name][k, n0:n0 + n] * scale, "C1--", lw=1.0, label="identified model")
            ax.plot(t, (pred[name][k, n0:n0 + n] - true[name][k, n0:n0 + n]) * scale, "C3", lw=0.8,
                    label="error")
            ax.set(title=f"{s.name}: {name}", ylabel=f"[{unit}]")
            ax.grid(True, alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    axes[0, 0].legend(fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_psd(pred, true, fs, setups, path):
    """Fig. 11: PSD of the true signal, the prediction and the error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(pred)
    fig, axes = plt.subplots(len(names), len(setups), figsize=(4 * len(setups), 2.6 * len(names)),
                             squeeze=False, constrained_layout=True, sharex=True)
    for i, name in enumerate(names):
        _, q, unit = TRACE_CHANNELS[name]
        scale = from_si(1.0, q, "imperial") ** 2
        for k, s in enumerate(setups):
            ax = axes[i, k]
            top = 0.0
            for x, style, label in ((true[name][k], "k", "known car"),
                                    (pred[name][k], "C1--", "identified model"),
                                    (pred[name][k] - true[name][k], "C3", "error")):
                f, pxx = welch(x, fs=fs, nperseg=1024)
                ax.semilogy(f, pxx * scale, style, lw=1.0, label=label)
                top = max(top, pxx.max() * scale) if label == "known car" else top
            ax.set(title=f"{s.name}: {name}", ylabel=f"PSD [{unit}^2/Hz]", xlim=(0.5, 25),
                   ylim=(top * 10 ** (-PSD_RANGE_DB / 10), top * 3))
            ax.grid(True, which="both", alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("frequency [Hz]")
    axes[0, 0].legend(fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_metrics(table, path):
    """Fig. 12: RMS metrics predicted against true, and the errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = [m for m in BAR_METRICS if m in set(table["metric"])]
    setups = list(dict.fromkeys(table["setup"]))
    ncol = max(1, int(np.ceil(len(metrics) / 2)))
    fig = plt.figure(figsize=(3.2 * ncol + 5, 7.5), constrained_layout=True)
    grid = fig.add_gridspec(2, ncol + 1, width_ratios=[1] * ncol + [1.6])
    axes = [fig.add_subplot(grid[k % 2, k // 2]) for k in range(len(metrics))]
    axes.append(fig.add_subplot(grid[:, ncol]))
    x = np.arange(len(setups))
    for ax, m in zip(axes, metrics):
        sub = table[table["metric"] == m].set_index("setup").loc[setups]
        scale = from_si(1.0, METRIC_QUANTITY[m], "imperial")
        ax.bar(x - 0.2, sub["true"] * scale, 0.4, color="0.3", label="known car")
        ax.bar(x + 0.2, sub["predicted"] * scale, 0.4, color="C1", label="identified model")
        lo = 0.9 * min(sub["true"].min(), sub["predicted"].min()) * scale
        ax.set(title=m, ylim=(lo, None))
        ax.set_xticks(x, setups, rotation=60, fontsize=7)
    axes[0].legend(fontsize=7)
    ax = axes[-1]
    for m in dict.fromkeys(table["metric"]):
        sub = table[table["metric"] == m].set_index("setup").loc[setups]
        if m in metrics:
            ax.plot(x, sub["error_pct"], "o-", lw=0.8, ms=3, label=m)
        else:
            ax.plot(x, sub["error_pct"], ".", color="0.6", ms=4)
    ax.axhline(0, color="k", lw=0.6)
    ax.set(title="prediction error (grey: other metrics)", ylabel="error [%]")
    ax.set_xticks(x, setups, rotation=60, fontsize=7)
    ax.legend(fontsize=6)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    """Run the study; returns 0."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--run-s", type=float, default=800.0, help="length of every rig run [s]")
    p.add_argument("--drive-s", type=float, default=120.0, help="validation drive [s]")
    p.add_argument("--window-s", type=float, default=4.0, help="time window of fig10.png [s]")
    p.add_argument("--outputs", nargs="+", default=list(METRIC_OUTPUTS),
                   help="outputs to identify (the 4 shock velocities are always added)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name in ("ident", "planner"):
        logging.getLogger(name).setLevel(logging.WARNING)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    vehicle = example_vehicle()
    library = read_shock_library(DEMO_LIBRARY_PATH)
    plan = default_plan()
    outputs = list(dict.fromkeys([f"shock_velocity_{c}" for c in CORNERS] + args.outputs))
    model = identify(plan, args.run_s, outputs, vehicle)
    drive = make_plan_drive(plan, vehicle, seed=DRIVE_SEED, duration_s=args.drive_s,
                            name="validation noise drive")
    setups = study_setups()
    truth = build_full_car(vehicle).loop_plant(model.cbar_n_s_m)
    t1 = time.perf_counter()
    a = predict_setups(model, drive, setups, library,
                       loop=LoopOptions(oversample=OVERSAMPLE)).table
    b = predict_setups(truth, drive, setups, library,
                       loop=LoopOptions(oversample=OVERSAMPLE)).table
    names = [c for c in a.columns if c not in CORNERS and c in b.columns]
    rows = [{"setup": s.name, "shocks": " ".join(s.ids()), "metric": m,
             "predicted": float(a.loc[s.name, m]), "true": float(b.loc[s.name, m]),
             "error_pct": 100 * float(a.loc[s.name, m] / b.loc[s.name, m] - 1)}
            for s in setups for m in names]
    table = pd.DataFrame(rows)
    table.insert(0, "run_s", args.run_s)
    table.to_csv(out / "fig10_12.csv", index=False, float_format="%.6g")
    shown = [s for s in setups if s.name in TRACE_SETUPS]
    pred, fs = traces(as_loop_plant(model), drive, shown, library)
    true, _ = traces(truth, drive, shown, library)
    true = {k: v for k, v in true.items() if k in pred}
    tr = pd.DataFrame(trace_rows(pred, true, fs, shown))
    tr.to_csv(out / "fig10_12_traces.csv", index=False, float_format="%.6g")
    log.info("predicted %d setups x 2 models on a %g s drive in %.1f s", len(setups),
             args.drive_s, time.perf_counter() - t1)
    plot_traces(pred, true, fs, shown, min(args.window_s, args.drive_s - 10.0), out / "fig10.png")
    plot_psd(pred, true, fs, shown, out / "fig11.png")
    plot_metrics(table, out / "fig12.png")
    for r in tr.itertuples():
        log.info("%-10s %-18s trace error %.2f %% of the signal RMS, PSD peak %.1f dB below",
                 r.setup, r.channel, r.error_pct_of_signal, r.psd_peak_error_below_signal_db)
    err = table["error_pct"].abs()
    worst = table.loc[err.idxmax()]
    log.info("metrics: median |error| %.3f %%, max %.3f %% (%s, %s); wrote fig10_12.csv, "
             "fig10_12_traces.csv, fig10.png, fig11.png, fig12.png to %s (%.1f s)",
             err.median(), err.max(), worst["setup"], worst["metric"], out,
             time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
