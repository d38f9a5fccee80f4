"""Tests of ident.model: fitted models, realization, files, and the truth round trip."""

import numpy as np
import pytest

from ident.channels import CORNERS
from ident.closedloop import simulate_batch
from ident.errors import ModelFileError
from ident.metrics import compute_metrics
from ident.model import (LOOP_REDUCE_RTOL, RIG_REDUCE_RTOL, VehicleModel, balanced_reduce,
                         has_feedthrough, load_model)

# issue criteria: the identified model in closed loop with the paper's shocks reproduces the
# known model's RMS metrics within 0.5 % median and 1.5 % max (no measurement noise)
RTOL_METRICS_MEDIAN = 0.005
RTOL_METRICS_MAX = 0.015
# with 2 % measurement noise on every response channel: 1 % median, 3 % max
RTOL_NOISE_MEDIAN = 0.01
RTOL_NOISE_MAX = 0.03
# the fitted model's FRF vs the truth (issue 3's 1 dB / 5 deg wherever the true magnitude is
# within 40 dB of the pair's peak, 0.5-20 Hz): the raw estimate meets it on every pair
# (tests/test_frf.py); the rational fits (order <= 10) on all but a few deep cross-axle
# notches at the 40 dB edge (measured 306 of 308)
MIN_FITTED_PAIRS_OK = 300
DB_TOL, DEG_TOL, PEAK_RANGE = 1.0, 5.0, 0.01
METRIC_OUTPUTS = [f"{k}_{c}" for k in ("tire_force", "ride_height", "shock_travel",
                                       "shock_velocity") for c in CORNERS]


def _paper_setups(session):
    b, n = session.shocks["B20"], session.shocks["N8"]
    return [[b] * 4] + [[n if j == i else b for j in range(4)] for i in range(4)]


def _metric_errors(model, truth_model, drive, setups):
    res = {}
    for lab, plant in (("true", truth_model.loop_plant(model.cbar_n_s_m)),
                       ("id", model.loop_plant())):
        b = simulate_batch(plant, drive, setups, oversample=4, outputs=METRIC_OUTPUTS)
        res[lab] = compute_metrics(b.channels, fs=b.fs_hz).values
    return np.array([np.abs(res["id"][k] / res["true"][k] - 1) for k in res["true"]])


def test_truth_round_trip_metrics(identified_model, paper_model, paper_session, validation_drive):
    """Known model -> virtual rig -> identify -> closed loop with the paper's shocks."""
    err = _metric_errors(identified_model, paper_model, validation_drive,
                         _paper_setups(paper_session))
    assert np.median(err) < RTOL_METRICS_MEDIAN
    assert err.max() < RTOL_METRICS_MAX


def test_fitted_frf_matches_truth(identified_model, paper_model):
    """The fitted transfer functions against the true closed-loop FRFs (issue 3 criterion)."""
    f = identified_model.frf.f_hz
    f = f[(f >= 0.5) & (f <= 20.0)]
    Ht = paper_model.frequency_response(f, damping_n_s_m=identified_model.cbar_n_s_m)
    Ht = Ht[[paper_model.output_names.index(o) for o in identified_model.output_names]]
    H = identified_model.frequency_response(f)
    strong = np.abs(Ht) >= PEAK_RANGE * np.abs(Ht).max(axis=-1, keepdims=True)
    bad = ((np.abs(20 * np.log10(np.abs(H) / np.abs(Ht))) > DB_TOL)
           | (np.abs(np.angle(H / Ht, deg=True)) > DEG_TOL)) & strong
    assert (~bad.any(-1)).sum() >= MIN_FITTED_PAIRS_OK


@pytest.mark.slow
def test_truth_round_trip_metrics_with_noise(paper_plan, paper_model, validation_drive):
    """The same round trip with 2 % measurement noise on every response channel."""
    import warnings
    from dataclasses import replace

    from ident.model import identify_session
    from ident.rig import simulate_session

    session = simulate_session(replace(paper_plan, noise=0.02))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(session)
    err = _metric_errors(model, paper_model, validation_drive, _paper_setups(session))
    assert np.median(err) < RTOL_NOISE_MEDIAN
    assert err.max() < RTOL_NOISE_MAX


def test_model_structure(identified_model):
    m = identified_model
    assert m.poles.shape[:2] == (len(m.output_names), 11)
    assert np.all(np.nan_to_num(m.poles.real, nan=-1.0) < 0)  # stable
    zeta = -m.poles.real / np.abs(m.poles)
    assert np.nanmin(zeta) >= 0.02 - 1e-12
    assert np.all(m.order >= 2) and np.all(m.order <= 10)
    assert np.median(m.fit_error) < 0.05
    table = m.summary()
    assert len(table) == 28 * 11 and {"order", "fit_error", "median_coherence"} <= set(table)
    i = m.output_names.index("tire_force_LF")
    assert m.direct[i, m.input_names.index("wheelloader_LF")] != 0  # feedthrough
    assert m.direct[m.output_names.index("shock_velocity_LF")].tolist() == [0.0] * 11


def test_feedthrough_rule():
    assert has_feedthrough("tire_force_LF", "wheelloader_LF")
    assert has_feedthrough("ride_height_RR", "wheelloader_RR")
    assert not has_feedthrough("ride_height_RR", "wheelloader_LF")
    assert not has_feedthrough("shock_velocity_LF", "dF_LF")
    assert has_feedthrough("chassis_accel_LR", "aero_heave")


def test_realizations_agree(identified_model):
    m = identified_model
    f = np.array([0.7, 2.0, 4.5, 11.0, 18.0])
    H = m.frequency_response(f)
    sys = m.to_control()
    import control

    Hc = np.stack([control.evalfr(sys, 2j * np.pi * x) for x in f], axis=-1)
    np.testing.assert_allclose(Hc, H, rtol=1e-8, atol=1e-10 * np.abs(H).max())
    plant = m.loop_plant(reduce_rtol=None)
    np.testing.assert_allclose(plant.frequency_response(f), H, rtol=1e-8,
                               atol=1e-10 * np.abs(H).max())
    red = m.loop_plant()
    Hr = red.frequency_response(f)
    for o in range(H.shape[0]):  # the reduced parts: the balanced-truncation bound per output
        for part, bound in ((slice(7, None), LOOP_REDUCE_RTOL), (slice(0, 7), RIG_REDUCE_RTOL)):
            scale = np.abs(H[o, part]).max()
            assert np.abs(Hr[o, part] - H[o, part]).max() <= bound * scale
    d = m.discretize(100.0, method="tustin", prewarp_hz=4.0)
    z = np.exp(2j * np.pi * 4.0 / 100.0)
    Hd = control.evalfr(d, z)
    np.testing.assert_allclose(Hd, m.frequency_response([4.0])[:, :, 0], rtol=1e-6,
                               atol=1e-9 * np.abs(H).max())


def test_balanced_reduce_keeps_the_physical_model_exactly(paper_model):
    shock = paper_model.loop_plant().shock
    red = balanced_reduce(shock, rtol=1e-8)
    f = np.geomspace(0.3, 30, 20)
    np.testing.assert_allclose(red.frequency_response(f), shock.frequency_response(f),
                               rtol=1e-6, atol=1e-9 * np.abs(shock.frequency_response(f)).max())


def test_save_load_and_export(tmp_path, identified_model):
    path = identified_model.save(tmp_path / "m.npz")
    back = load_model(path)
    assert isinstance(back, VehicleModel) and back.output_names == identified_model.output_names
    f = np.array([1.0, 5.0])
    np.testing.assert_allclose(back.frequency_response(f), identified_model.frequency_response(f))
    np.testing.assert_allclose(back.frf.H, identified_model.frf.H)
    np.testing.assert_array_equal(back.noise_level, identified_model.noise_level)
    np.testing.assert_array_equal(back.frf.sigma, identified_model.frf.sigma)
    assert back.summary().equals(identified_model.summary())
    with pytest.raises(FileExistsError, match="overwrite"):
        identified_model.save(path)
    from scipy.io import loadmat

    mat = identified_model.export_mat(tmp_path / "m.mat")
    data = loadmat(mat)
    assert data["A"].shape[0] == data["B"].shape[0] and data["B"].shape[1] == 11


def test_bad_model_files(tmp_path, identified_model):
    with pytest.raises(ModelFileError, match="not found"):
        load_model(tmp_path / "none.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(ModelFileError, match="corrupt"):
        load_model(junk)
    import json
    import zipfile

    good = identified_model.save(tmp_path / "v.npz")
    with np.load(good) as z:
        data = {k: z[k] for k in z.files}
    meta = json.loads(str(data.pop("meta")))
    meta["version"] = 99
    np.savez(tmp_path / "v99.npz", meta=np.array(json.dumps(meta)), **data)
    with pytest.raises(ModelFileError, match="version 99"):
        load_model(tmp_path / "v99.npz")
    assert zipfile.is_zipfile(good)


def test_vector_fitting_method(identified_model):
    from ident.model import fit_model

    vf = fit_model(identified_model.frf, method="vf")
    assert vf.settings["method"] == "vf"
    # common poles: every pair has the same number of poles
    assert len(set(vf.n_poles.ravel().tolist())) == 1
    assert np.median(vf.fit_error) < 0.2


# a 2-pole resonance measured with 3 % relative error a line: the fit needs 2 poles and stops
# there (the noise floor); a higher order only fits noise
NOISY_PAIR_MAX_ORDER = 4


def _noisy_pair_frf(rng):
    """One output (tire_force_LF), 11 inputs: a 4 Hz resonance from every input, exact except
    input 0 (3 % relative error a line, coherence to match) and input 1 (pure noise: nothing
    but error, coherence 0.01)."""
    import dataclasses

    from ident.condition import condition_frf
    from ident.frf import MODEL_INPUTS, Frf

    f = np.arange(2049) * 100 / 4096
    s = 2j * np.pi * f
    wn = 2 * np.pi * 4.0
    h = 1e5 * wn**2 / (s**2 + 2 * 0.15 * wn * s + wn**2)
    H = np.tile(h, (1, 11, 1)).astype(complex)
    coh = np.full(H.shape, 1.0 - 1e-12)
    coh[0, 0] = 1 / (1 + 40 * 0.03**2)  # |H|^2 / (|H|^2 + 40 var), var = (0.03 |H|)^2
    coh[0, 1] = 0.01
    e = (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)) / np.sqrt(2)
    H[0, 0] = h * (1 + 0.03 * e)
    H[0, 1] = 1e3 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    frf = Frf(f_hz=f, H=H, input_names=MODEL_INPUTS, output_names=("tire_force_LF",),
              multiple_coherence=np.ones((1, f.size)), partial_coherence=coh,
              input_condition=np.ones(f.size), independent_fraction=np.ones((11, f.size)),
              flagged=np.zeros((11, f.size), bool), n_averages=51, cbar_n_s_m=np.zeros(4),
              fs_hz=100.0, settings={"estimator": "welch", "window": "hamming",
                                     "nperseg": 4096})
    return condition_frf(frf), dataclasses.replace(frf, partial_coherence=np.ones(H.shape))


def test_fits_stop_at_the_noise_and_refuse_to_make_up_dynamics(rng):
    """Order selection stops where the fit reaches the data's noise; a pair that is nothing
    but noise is fitted as zero, says so (status, warning) and simulates as zero."""
    import warnings

    from ident.condition import condition_frf
    from ident.errors import LowCoherenceWarning
    from ident.model import ZERO_FIT_NOISE, fit_model

    frf, overconfident = _noisy_pair_frf(rng)
    with pytest.warns(LowCoherenceWarning, match="1 pair.*no response above the noise"):
        model = fit_model(frf)
    assert model.order[0, 1] == 0 and model.n_poles[0, 1] == 0
    assert model.noise_level[0, 1] >= ZERO_FIT_NOISE
    table = model.summary().set_index("input")
    assert table.loc["aero_roll", "status"] == "zero"
    assert table.loc["aero_heave", "status"] == "fit" and table.loc["aero_pitch", "status"] == "fit"
    assert np.all(model.frequency_response([1.0, 4.0, 10.0])[0, 1] == 0)
    assert model.settings["zero_pairs"] == [["tire_force_LF", "aero_roll"]]
    assert 2 <= model.order[0, 0] <= NOISY_PAIR_MAX_ORDER
    assert model.fit_error[0, 0] <= 1.5 * model.noise_level[0, 0]
    assert table.loc["aero_roll", "noise_bands_hz"].startswith("0.5")
    assert table.loc["aero_pitch", "noise_bands_hz"] == ""
    # told the data are exact, the pure-noise pair is fitted with poles
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        naive = fit_model(condition_frf(overconfident))
    assert naive.order[0, 1] > 0 and naive.settings["zero_pairs"] == []


def test_noise_bands_of_an_identified_model(identified_model):
    """The noise-free paper session: every pair fitted, none at the noise level."""
    table = identified_model.summary()
    assert set(table.status) == {"fit"}
    assert table.noise_level.max() < 0.01
    assert {"noise_level", "status", "noise_bands_hz"} <= set(table)
