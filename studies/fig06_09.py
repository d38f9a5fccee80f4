"""Identified FRFs against the known car: raw, conditioned, fit, ideal (paper Figs. 6-9).

The virtual rig runs the seed paper's identification plan (``ident.sim.virtual_rig.default_plan``:
a baseline run with the linear B20 shocks and four single-corner swaps to the
nonlinear N8, the same 800 s band-limited white-noise drive in every run, no
sensor noise) on the paper's car, and shockplan identifies the session with
the defaults of ``ident.identify.pipeline.identify_session`` (LPM estimate, conditioning
with residual fits and 0.6 Hz smoothing, ``invfreqs`` fits with automatic
orders). Only the plotted outputs are identified: every output is estimated,
conditioned and fitted on its own, so their pairs are the same as those of
``identify_session`` on every output (checked to 1e-13), and the study runs
several times faster.

For each plotted output, two figures drawn by ``ident.identify.plots.plot_frf`` (the
figures of ``shockplan identify --plots``, with the ideal response added):

- the shock-force inputs ``dF_XX`` (paper Figs. 6-8: left front shock velocity,
  left front tire force, front ride height; Fig. 9: the fits against the ideal);
- a few rig inputs (the chassis heave force and two wheelloaders), whose
  estimates the paper calls "very close to the ideal frequency response, with
  a coherence very close to 1".

With the defaults the estimates are nearly exact (noise-free runs, LPM) and
the coherences are about 1 everywhere. ``--estimator welch`` uses the paper's
Welch H1 estimate instead (the rest unchanged) and reproduces the paper's
observations: coherence drops where the response is low (the LF/LF shock pair
near its 6 Hz zero, cross-corner pairs away from the body resonances, every
shock pair near the 13-14 Hz notches), residual fits replace those stretches,
and the fits still follow the ideal where its magnitude is high.

The ideal is the known car's closed-loop response around the model's
baseline damping ``c_bar`` (``FullCarModel.frequency_response``), the
response the model stands for.

Writes one PNG per output and input group (``fig06_09_<output>_<group>.png``),
``fig06_09.png`` (the errors against the ideal, per pair) and ``fig06_09.csv``
(one row per plotted pair: run length, estimator, fit error, median coherence 0.5-20 Hz, median
relative error of the raw estimate, the conditioned estimate and the fit
against the ideal over 0.5-20 Hz, and of the fit where the ideal is within 20 dB
of its peak, where the paper asks the fit to be close).

    python studies/fig06_09.py --out DIR [--run-s 800] [--estimator lpm] [--outputs ...]
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

from ident.identify.condition import condition_frf
from ident.identify.frf import DF_INPUTS, estimate_frf
from ident.identify.pipeline import fit_model
from ident.identify.plots import plot_frf
from ident.sim.virtual_rig import default_plan, simulate_session
from ident.models.vehicle import build_full_car, example_vehicle

log = logging.getLogger("studies.fig06_09")

#: Outputs of paper Figs. 6, 7 and 8 (the front ride height is read at LF).
DEFAULT_OUTPUTS = ("shock_velocity_LF", "tire_force_LF", "ride_height_LF")
#: Rig inputs plotted for every output.
RIG_PLOT_INPUTS = ("aero_heave", "wheelloader_LF", "wheelloader_RF")
#: Band of the errors and coherences [Hz] (the fit band of ``identify_session``).
BAND_HZ = (0.5, 20.0)
#: "High magnitude": the ideal within this many dB of its peak in the band.
HIGH_DB = 20.0


def identify(run_s, outputs, vehicle, estimator="lpm"):
    """Simulate the paper's plan with runs of `run_s` and identify `outputs` (defaults but
    `estimator`)."""
    plan = default_plan()
    plan = replace(plan, runs=tuple(replace(r, duration_s=run_s) for r in plan.runs))
    t0 = time.perf_counter()
    session = simulate_session(plan, vehicle)
    t1 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frf = condition_frf(estimate_frf(session, outputs=list(outputs), estimator=estimator))
        model = fit_model(frf, name=session.name, units=session.units)
    t2 = time.perf_counter()
    log.info("simulated %d runs of %g s in %.1f s, identified %d outputs (%s) in %.1f s",
             len(plan.runs), run_s, t1 - t0, len(outputs), estimator, t2 - t1)
    return model


def ideal(vehicle, model):
    """The known response ``f_hz -> (n_out, n_in, n_f)`` in the model's channel order."""
    car = build_full_car(vehicle)
    rows = [car.output_names.index(o) for o in model.output_names]
    cols = [car.input_names.index(i.replace("dF_", "shock_force_")) for i in model.input_names]

    def truth(f_hz):
        H = car.frequency_response(f_hz, damping_n_s_m=model.cbar_n_s_m)
        return H[np.ix_(rows, cols)]

    return truth


def pair_errors(model, truth, output, input):
    """Coherence and errors against the ideal of one pair (see the module docstring)."""
    o, i = model.output_names.index(output), model.input_names.index(input)
    frf = model.frf
    sel = (frf.f_hz >= BAND_HZ[0]) & (frf.f_hz <= BAND_HZ[1])
    f = frf.f_hz[sel]
    Ht = truth(f)[o, i]
    Hf = model.frequency_response(f)[o, i]
    mag = np.abs(Ht)
    high = mag >= mag.max() * 10 ** (-HIGH_DB / 20)

    def rel(h, where=slice(None)):
        return float(np.median(np.abs(h[where] - Ht[where]) / mag[where]))

    return {"output": output, "input": input,
            "group": "shock" if input in DF_INPUTS else "rig",
            "order": int(model.order[o, i]), "fit_error": float(model.fit_error[o, i]),
            "median_coherence": float(np.median(frf.partial_coherence[o, i, sel])),
            "raw_median_rel_error": rel(frf.H_raw[o, i, sel]),
            "conditioned_median_rel_error": rel(frf.H[o, i, sel]),
            "fit_median_rel_error": rel(Hf),
            "fit_median_rel_error_high": rel(Hf, high),
            "replaced_fraction": float(frf.replaced[o, i, sel].mean())
            if frf.replaced is not None else 0.0}


def plot_summary(table, path):
    """Median relative error against the ideal per pair: raw, conditioned, fit."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 4.5), constrained_layout=True)
    x = np.arange(len(table))
    cols = [("raw_median_rel_error", "raw estimate"),
            ("conditioned_median_rel_error", "conditioned"),
            ("fit_median_rel_error", "fit, 0.5-20 Hz"),
            ("fit_median_rel_error_high", f"fit, within {HIGH_DB:g} dB of peak")]
    w = 0.8 / len(cols)
    for k, (col, label) in enumerate(cols):
        ax.bar(x + (k - 1.5) * w, table[col], w, label=label)
    ax.set_xticks(x, [f"{r.output}\n{r.input}" for r in table.itertuples()], rotation=90,
                  fontsize=7)
    ax.set(yscale="log", ylabel="median |H - H_ideal| / |H_ideal|",
           title="identified FRF against the known car (paper Figs. 6-9)")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    """Run the study; returns 0."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--run-s", type=float, default=800.0, help="length of every run [s]")
    p.add_argument("--outputs", nargs="+", default=list(DEFAULT_OUTPUTS),
                   help="output channels to identify and plot")
    p.add_argument("--rig-inputs", nargs="*", default=list(RIG_PLOT_INPUTS),
                   help="rig inputs plotted per output (none: shock inputs only)")
    p.add_argument("--estimator", choices=("lpm", "welch"), default="lpm",
                   help="FRF estimator: shockplan's default LPM, or the paper's Welch H1")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name in ("ident", "planner"):
        logging.getLogger(name).setLevel(logging.WARNING)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vehicle = example_vehicle()
    model = identify(args.run_s, args.outputs, vehicle, args.estimator)
    truth = ideal(vehicle, model)
    rows = []
    for output in args.outputs:
        for group, inputs in (("shock", DF_INPUTS), ("rig", tuple(args.rig_inputs))):
            if not inputs:
                continue
            fig = plot_frf(model, output, inputs=inputs, truth=truth, units=model.units,
                           f_range_hz=BAND_HZ)
            fig.savefig(out / f"fig06_09_{output}_{group}.png", dpi=110)
            rows += [pair_errors(model, truth, output, i) for i in inputs]
    table = pd.DataFrame(rows)
    table.insert(0, "estimator", args.estimator)
    table.insert(0, "run_s", args.run_s)
    table.to_csv(out / "fig06_09.csv", index=False, float_format="%.6g")
    plot_summary(table, out / "fig06_09.png")
    for r in table.itertuples():
        log.info("%-18s %-14s order %2d, fit error %.4f, coherence %.3f, fit vs ideal %.4f "
                 "(%.4f near the peak)", r.output, r.input, r.order, r.fit_error,
                 r.median_coherence, r.fit_median_rel_error, r.fit_median_rel_error_high)
    log.info("wrote %s, %s and %d FRF plots", out / "fig06_09.csv", out / "fig06_09.png",
             sum(1 for _ in out.glob("fig06_09_*.png")))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
