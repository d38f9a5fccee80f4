"""What shrinks the model's differences between setups on the GT cars (issue 37 item 2).

On the GT cars of ``studies/interval_calibration_cv.py`` the model's differences between
setups are 0.5-2 % (relative) smaller than the known car's, alike for every setup. This
study takes the shrink apart on one identification of that study (its kept model), with
the screening (``planner.screen.screen_response``) on the study's 60 s track and 20
setups, as the *slope*: each setup's metrics over the baseline's, less 1, regressed on
the known car's (1 = no shrink). Responses compared (all on the model's FRF inputs):

- the known car (``build_full_car(car).loop_plant``), the model's loop plant, its
  conditioned FRF;
- ``--window``: the session estimated again with the LPM half-width R (the model's), 2R
  and 4R (raw and conditioned), with the Richardson extrapolations from R and 2R;
- the band swap: the FRF's (the model's) response put into the known car's in one band
  and input group (rig, dF) at a time;
- ``--simex``: the noise bias as ``ident.identify.crossval.noise_bias`` measures it, at the
  added noise's variance x1 and x3 (the estimate's at x2 and x4), and extrapolated to 0;
- ``--variants``: the same session without response noise, without the rig inputs' noise,
  with noise on the shock velocity and force only (its variance x0.5, x1, x2, x4), and on
  every channel but those.

Results: docs/DESIGN.md, "What shrinks the GT cars' differences".

    python studies/difference_shrink.py --cases DIR/cases --car "GT 4-post" [--seed 0]
        [--window] [--simex] [--variants]

(``DIR`` an ``interval_calibration_cv.py --out``; a few minutes per option at 100 Hz.)
"""

from __future__ import annotations

import argparse
import logging
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from ident.data.drive import make_track_drive
from ident.identify import crossval as cv
from ident.identify.condition import condition_frf
from ident.identify.frf import MODEL_INPUTS, embed_inputs, estimate_frf
from ident.identify.model import load_model
from ident.models.library import read_shock_library
from ident.models.vehicle import build_full_car
from ident.sim.virtual_rig import simulate_session
from planner.demo import DEMO_LIBRARY_PATH
from planner.predict import prepare_drive, resolve_setups
from planner.screen import drive_bands, screen_response
from planner.uncertainty import interpolate, noise_bias_deviation

sys.path.insert(0, str(Path(__file__).resolve().parent))
import interval_calibration_cv as study  # noqa: E402

log = logging.getLogger("difference_shrink")
BANDS_HZ = ((0.0, 2.0), (2.0, 3.0), (3.0, 4.5), (4.5, 8.0), (8.0, 14.0), (14.0, 30.0))


def estimate_like(session, frf, **overrides):
    """Raw and conditioned LPM FRF of `session` with `frf`'s settings, on ``frf.f_hz``."""
    s = frf.settings
    cond = dict(s.get("conditioning") or {})
    cond.pop("poor_pairs", None)
    kw = {"estimator": "lpm", "method": s.get("method", "global"),
          "cbar_n_s_m": frf.cbar_n_s_m, "outputs": list(frf.output_names),
          "lpm_degree": s["lpm_degree"], "lpm_half_width": s["lpm_half_width"]}
    if s.get("lpm_coherence_dof") is not None:
        kw["lpm_coherence_dof"] = s["lpm_coherence_dof"]
    kw.update(overrides)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = estimate_frf(session, **kw)
        con = condition_frf(raw, **cond)
    return (cv._on_grid(raw.f_hz, raw.H, frf.f_hz), cv._on_grid(con.f_hz, con.H, frf.f_hz))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", required=True, type=Path)
    p.add_argument("--car", default="GT 4-post")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--window", action="store_true")
    p.add_argument("--simex", action="store_true")
    p.add_argument("--variants", action="store_true")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    warnings.simplefilter("ignore")
    spec = study.car_family()[a.car]
    vehicle = spec["vehicle"]
    stem = f"{a.car.replace(' ', '_').replace('%', 'pct')}_seed{study.SEED0 + a.seed}"
    model = load_model(a.cases / f"{stem}_model.npz")
    frf = model.frf
    f = frf.f_hz
    plan = study.study_plan(spec, study.SEED0 + a.seed)
    lp = build_full_car(vehicle).loop_plant(frf.cbar_n_s_m)
    order = [list(lp.output_names).index(o) for o in frf.output_names]
    cols = [list(MODEL_INPUTS).index(i) for i in frf.input_names]
    library = read_shock_library(DEMO_LIBRARY_PATH)
    drive = make_track_drive(duration_s=60.0, fs_hz=100.0, seed=24, speed_m_s=spec["speed_m_s"],
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m, name="track")
    models = resolve_setups(study.study_setups(library, 19), library)
    bands = drive_bands(prepare_drive(drive, model.fs_hz), band_hz=(1.0, 20.0), n_bands=96)
    fb = bands.f_hz

    def on_bands(H):
        return embed_inputs(interpolate(f, np.nan_to_num(H), fb), frf.input_names)

    def metrics(Hb):
        return screen_response(Hb, frf.output_names, frf.cbar_n_s_m, bands, models)[1]

    known = embed_inputs(lp.frequency_response(fb)[order][:, cols], frf.input_names)
    m_known = metrics(known)
    d_known = (m_known / m_known[0] - 1)[1:]

    def slope(Hb):
        m = metrics(Hb)
        d = (m / m[0] - 1)[1:]
        return float(np.sum(d * d_known) / np.sum(d_known ** 2))

    mo = [list(model.loop_plant().output_names).index(o) for o in frf.output_names]
    fitted = embed_inputs(model.loop_plant(reduce_rtol=None).frequency_response(fb)[mo][:, cols],
                          frf.input_names)
    estimate = on_bands(frf.H)
    log.info("%s seed %d: slope of the differences against the known car's: model %.4f, "
             "conditioned FRF %.4f", a.car, a.seed, slope(fitted), slope(estimate))
    bias = noise_bias_deviation(frf, fb)
    if bias is not None:
        log.info("  without the measured noise bias: model %.4f, FRF %.4f",
                 slope(fitted * (1 - bias)), slope(estimate * (1 - bias)))
    rig = np.arange(11) < 7
    for lo, hi in BANDS_HZ:
        inband = (fb >= lo) & (fb < hi)
        for group, cm in (("rig", rig), ("dF", ~rig)):
            mask = inband[None, None, :] & cm[None, :, None]
            log.info("  %4.1f-%4.1f Hz %-3s: FRF in the known car %.4f, model %.4f", lo, hi, group,
                     slope(np.where(mask, estimate, known)), slope(np.where(mask, fitted, known)))
    if not (a.window or a.simex or a.variants):
        return
    session = simulate_session(plan, vehicle)
    if a.window:
        R = frf.settings["lpm_half_width"]
        sl = {}
        for mult in (1, 2, 4):
            raw, con = estimate_like(session, frf, lpm_half_width=mult * R)
            sl[mult] = (slope(on_bands(raw)), slope(on_bands(con)))
            log.info("  LPM half-width %d (%d R): raw %.4f, conditioned %.4f", mult * R, mult,
                     *sl[mult])
        for j, name in enumerate(("raw", "conditioned")):
            s1, s2, s4 = (sl[m][j] for m in (1, 2, 4))
            log.info("  %s: (S4R - S2R) / (S2R - SR) = %.2f; Richardson from R, 2R: p = 2 %.4f, "
                     "p = 3 %.4f", name, (s4 - s2) / (s2 - s1), s1 - (s2 - s1) / 3,
                     s1 - (s2 - s1) / 7)
    if a.simex:
        sensor_noise = cv.sensor_noise
        sl = {1: slope(estimate)}
        try:
            for mult in (1, 3):
                def scaled(*args, _m=mult):
                    return {c: tuple(np.sqrt(_m) * np.asarray(v))
                            for c, v in sensor_noise(*args).items()}
                cv.sensor_noise = scaled
                pair = cv.noisier_sessions(session, frf.cbar_n_s_m)
                if pair is None:
                    log.info("  no noise to add (noise-free sensors)")
                    break
                H = 0.5 * (cv._estimate_like(pair[0], frf) + cv._estimate_like(pair[1], frf))
                sl[1 + mult] = slope(on_bands(H))
        finally:
            cv.sensor_noise = sensor_noise
        if len(sl) == 3:
            lam = np.array([1.0, 2.0, 4.0])
            y = np.array([sl[1], sl[2], sl[4]])
            log.info("  noise variance x1, x2, x4: %.4f, %.4f, %.4f; extrapolated to 0: linear "
                     "%.4f, quadratic %.4f", *y, 2 * y[0] - y[1],
                     np.polyval(np.polyfit(lam, y, 2), 0.0))
    if a.variants:
        variants = {
            "without response noise": replace(plan, noise=0.0),
            "without the rig inputs' noise": replace(plan, input_noise=0.0),
            "noise on shock velocity and force only": replace(
                plan, noise=0.0, channel_noise={"shock_velocity": plan.noise,
                                                "shock_force": plan.noise}),
            "noise on every channel but those": replace(
                plan, channel_noise={"shock_velocity": 0.0, "shock_force": 0.0}),
        }
        for v in (0.5, 2.0, 4.0):
            level = plan.noise * np.sqrt(v)
            variants[f"shock sensors' noise only, variance x{v:g}"] = replace(
                plan, noise=0.0, channel_noise={"shock_velocity": level, "shock_force": level})
        for name, pl in variants.items():
            _, con = estimate_like(simulate_session(pl, vehicle), frf)
            Hb = on_bands(con)
            body = (fb >= 3.0) & (fb < 4.5)
            log.info("  %s: FRF %.4f; at 3-4.5 Hz only: rig %.4f, dF %.4f", name, slope(Hb),
                     slope(np.where(body[None, None] & rig[None, :, None], Hb, known)),
                     slope(np.where(body[None, None] & ~rig[None, :, None], Hb, known)))


if __name__ == "__main__":
    main()
