"""Tests of ident.identify.model: fitted models, realization, files, and the truth round trip."""

import numpy as np
import pytest

from ident.data.channels import CORNERS
from ident.sim.closedloop import simulate_batch
from ident.errors import ModelFileError
from ident.sim.metrics import compute_metrics
from ident.identify.model import LOOP_REDUCE_RTOL, RIG_REDUCE_RTOL, VehicleModel, has_feedthrough, load_model
from ident.models.lti import balanced_reduce

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
@pytest.mark.heavy
def test_truth_round_trip_metrics_with_noise(paper_plan, paper_model, validation_drive):
    """The same round trip with 2 % measurement noise on every response channel."""
    import warnings
    from dataclasses import replace

    from ident.identify.pipeline import identify_session
    from ident.sim.virtual_rig import simulate_session

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


# closed-form gramians vs a Lyapunov solver: both at rounding level
RTOL_GRAMIAN = 1e-10
# a merged common-pole realization vs the model's pole-residue response: rounding only
RTOL_REALIZATION = 1e-10
# a loaded model's plant vs one built afresh in the same process: the same arithmetic
RTOL_SAME_PLANT = 1e-9


def _random_modal(rng, n_complex=9, n_real=3, m=3, p=4):
    from ident.models.lti import ModalSystem

    lam = np.concatenate([-rng.uniform(0.5, 5, n_complex) + 1j * rng.uniform(2, 60, n_complex),
                          -rng.uniform(0.5, 80, n_real) + 0j])
    B = rng.standard_normal((lam.size, m)) + 1j * rng.standard_normal((lam.size, m))
    C = rng.standard_normal((p, lam.size)) + 1j * rng.standard_normal((p, lam.size))
    B[n_complex:], C[:, n_complex:] = B[n_complex:].real, C[:, n_complex:].real
    return ModalSystem(lam, B, C, np.zeros((p, m)))


def test_modal_gramians_solve_the_lyapunov_equations(rng):
    """The closed-form gramians in real modal coordinates equal a Lyapunov solver's."""
    from scipy.linalg import solve_continuous_lyapunov

    from ident.models.lti import _modal_gramians

    sys = _random_modal(rng)
    P, Q = _modal_gramians(sys, sys.B, sys.C)
    A, B, C, _ = sys.to_real()
    P_ref = solve_continuous_lyapunov(A, -B @ B.T)
    Q_ref = solve_continuous_lyapunov(A.T, -C.T @ C)
    np.testing.assert_allclose(P, P_ref, rtol=0, atol=RTOL_GRAMIAN * np.abs(P_ref).max())
    np.testing.assert_allclose(Q, Q_ref, rtol=0, atol=RTOL_GRAMIAN * np.abs(Q_ref).max())


def test_gram_factor_of_a_low_rank_gramian(rng):
    from ident.models.lti import _gram_factor

    X = rng.standard_normal((40, 6))
    M = X @ X.T  # rank 6
    L = _gram_factor(M)
    assert L.shape[0] == 40 and 6 <= L.shape[1] <= 8  # rank 6, and a rounding-level column or two
    np.testing.assert_allclose(L @ L.T, M, rtol=0, atol=RTOL_GRAMIAN * np.abs(M).max())
    assert _gram_factor(np.zeros((5, 5))).shape == (5, 0)


def test_balanced_reduce_of_a_random_system_within_its_bound(rng):
    sys = _random_modal(rng, n_complex=20, n_real=4)
    f = np.geomspace(0.3, 30, 200)
    H = sys.frequency_response(f)
    red = balanced_reduce(sys, rtol=1e-2)
    assert red.n_states < sys.n_states
    err = np.abs(red.frequency_response(f) - H).max(axis=(1, 2))
    assert np.all(err <= 1e-2 * np.abs(H).max(axis=(1, 2)))


def _common_pole_model(rng, n_poles=3):
    """Every pair of an input column has the same poles (as a vector fit stores them)."""
    from ident.identify.frf import MODEL_INPUTS
    from planner.predict import METRIC_OUTPUTS

    p, m = len(METRIC_OUTPUTS), len(MODEL_INPUTS)
    col = (-rng.uniform(2, 6, (m, n_poles)) + 1j * rng.uniform(10, 90, (m, n_poles)))
    col[:, 0] = -rng.uniform(5, 50, m)  # one real pole per column
    poles = np.broadcast_to(col, (p, m, n_poles)).copy()
    residues = rng.standard_normal((p, m, n_poles)) + 1j * rng.standard_normal((p, m, n_poles))
    residues[..., 0] = residues[..., 0].real
    return VehicleModel(name="common poles", input_names=tuple(MODEL_INPUTS),
                        output_names=tuple(METRIC_OUTPUTS), poles=poles, residues=residues,
                        direct=rng.standard_normal((p, m)), n_poles=np.full((p, m), n_poles),
                        order=np.full((p, m), 2 * n_poles - 1), fit_error=np.zeros((p, m)),
                        cbar_n_s_m=np.full(4, 3500.0), fs_hz=100.0)


def test_pair_modal_merges_the_poles_an_input_column_shares(rng):
    """A common-pole model realizes with one state per pole per input, exactly."""
    m = _common_pole_model(rng)
    n_in = len(m.input_names)
    sys = m.pair_modal(range(n_in))
    assert sys.n_states == n_in * 3  # not n_out x n_in x 3
    f = np.array([0.5, 3.0, 9.0, 17.0])
    H = m.frequency_response(f)
    np.testing.assert_allclose(sys.frequency_response(f), H, rtol=0,
                               atol=RTOL_REALIZATION * np.abs(H).max())


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


def test_model_files_are_compressed_and_uncompressed_ones_still_read(tmp_path,
                                                                     identified_model):
    """Issue 36: the file is deflated (the demo folder's size), every array stored exactly,
    and a stored (uncompressed) file, as earlier versions wrote, loads to the same model."""
    import zipfile

    path = identified_model.save(tmp_path / "m.npz")
    with zipfile.ZipFile(path) as zf:
        assert {i.compress_type for i in zf.infolist()} == {zipfile.ZIP_DEFLATED}
    old = _rewrite(path, tmp_path / "stored.npz", lambda meta, data: None)  # np.savez
    with zipfile.ZipFile(old) as zf:
        assert {i.compress_type for i in zf.infolist()} == {zipfile.ZIP_STORED}
    assert path.stat().st_size < old.stat().st_size
    with np.load(path) as a, np.load(old) as b:
        assert a.files == b.files
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    new, back = load_model(path), load_model(old)
    np.testing.assert_array_equal(new.frf.H, identified_model.frf.H)
    np.testing.assert_array_equal(back.frf.H, identified_model.frf.H)
    np.testing.assert_array_equal(back.residues, identified_model.residues)
    assert back.summary().equals(new.summary())


def _rewrite(src, dst, edit):
    """Copy a model file with its meta and arrays edited by ``edit(meta, data)``."""
    import json

    with np.load(src) as z:
        data = {k: z[k] for k in z.files}
    meta = json.loads(str(data.pop("meta")))
    edit(meta, data)
    np.savez(dst, meta=np.array(json.dumps(meta)), **data)
    return dst


def test_model_file_holds_the_loop_plant(tmp_path, identified_model, track_drive,
                                         demo_library, baseline_setup):
    """The default loop plant is stored in the file, restored on load, and predicts exactly as
    the plant built afresh; older files and files whose arrays changed rebuild it."""
    import dataclasses

    from ident.data.drive import Drive
    from ident.identify.model import MODEL_VERSION
    from planner.predict import predict_setups
    from planner.setups import Setup

    path = identified_model.save(tmp_path / "m.npz")
    saved = identified_model.loop_plant()
    back = load_model(path)
    assert LOOP_REDUCE_RTOL in back._plants  # no reduction after loading
    plant = back.loop_plant()
    for part in ("rig", "shock"):
        for k in ("lam", "B", "C", "D"):
            np.testing.assert_array_equal(getattr(getattr(plant, part), k),
                                          getattr(getattr(saved, part), k))
    assert plant.output_names == saved.output_names and plant.rig_inputs == saved.rig_inputs
    np.testing.assert_array_equal(plant.cbar_n_s_m, saved.cbar_n_s_m)

    fresh = dataclasses.replace(identified_model)  # an empty plant cache: builds anew
    assert not fresh._plants
    setups = [baseline_setup, Setup("soft front", {"LF": "L12", "RF": "L12", "LR": "B20",
                                                   "RR": "B20"})]
    short = Drive(name="short", fs_hz=track_drive.fs_hz,  # 20 s are enough to compare
                  channels={c: x[:int(20 * track_drive.fs_hz)]
                            for c, x in track_drive.channels.items()})
    a = predict_setups(back, short, setups, demo_library).table
    b = predict_setups(fresh, short, setups, demo_library).table
    cols = [c for c in a.columns if c not in CORNERS]
    np.testing.assert_allclose(a[cols].to_numpy(float), b[cols].to_numpy(float),
                               rtol=RTOL_SAME_PLANT)

    def old_version(meta, data):  # a version-1 file: no plant
        meta["version"] = 1
        del meta["loop_plant"]
        for k in [k for k in data if k.startswith("plant_")]:
            del data[k]

    v1 = load_model(_rewrite(path, tmp_path / "v1.npz", old_version))
    assert MODEL_VERSION > 1 and not v1._plants
    f = np.array([1.0, 6.0, 15.0])
    np.testing.assert_allclose(v1.loop_plant().frequency_response(f),
                               plant.frequency_response(f), rtol=RTOL_SAME_PLANT,
                               atol=RTOL_SAME_PLANT * np.abs(plant.frequency_response(f)).max())

    def changed(meta, data):  # residues edited after the plant was stored
        data["residues"] = data["residues"] * 2

    edited = load_model(_rewrite(path, tmp_path / "edited.npz", changed))
    assert not edited._plants
    H = edited.frequency_response(f)
    Hp = edited.loop_plant(reduce_rtol=None).frequency_response(f)
    np.testing.assert_allclose(Hp, H, rtol=0, atol=RTOL_REALIZATION * np.abs(H).max())

    no_plant = load_model(identified_model.save(tmp_path / "np.npz", with_plant=False))
    assert not no_plant._plants


def test_vector_fitting_method(identified_model):
    from ident.identify.pipeline import fit_model

    vf = fit_model(identified_model.frf, method="vf")
    assert vf.settings["method"] == "vf"
    # common poles: every pair has the same number of poles
    assert len(set(vf.n_poles.ravel().tolist())) == 1
    assert np.median(vf.fit_error) < 0.2
    # one state per common pole and input column
    full = vf.pair_modal(range(len(vf.input_names)))
    assert full.n_states <= len(vf.input_names) * int(vf.n_poles.max())
    f = np.array([0.7, 4.5, 18.0])
    H = vf.frequency_response(f)
    np.testing.assert_allclose(full.frequency_response(f), H, rtol=0,
                               atol=RTOL_REALIZATION * np.abs(H).max())


# a 2-pole resonance measured with 3 % relative error a line: the fit needs 2 poles and stops
# there (the noise floor); a higher order only fits noise
NOISY_PAIR_MAX_ORDER = 4


def _noisy_pair_frf(rng):
    """One output (tire_force_LF), 11 inputs: a 4 Hz resonance from every input, exact except
    input 0 (3 % relative error a line, coherence to match) and input 1 (pure noise: nothing
    but error, coherence 0.01)."""
    import dataclasses

    from ident.identify.condition import condition_frf
    from ident.identify.frf import MODEL_INPUTS, Frf

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

    from ident.identify.condition import condition_frf
    from ident.errors import LowCoherenceWarning
    from ident.identify.pipeline import ZERO_FIT_NOISE, fit_model

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


def test_vector_fitting_weighs_lines_by_their_noise(rng):
    """``vf``: a pure-noise pair (coherence 0.01) and a 3 % noisy one do not place the common
    poles: the exact pairs still fit within ORDER_FLOOR (with every pair at unit weight they
    did not: 2.4e-3 on this case), and the 4 Hz, 15 % mode is found."""
    import warnings

    from ident.identify.pipeline import ORDER_FLOOR, fit_model

    frf, _ = _noisy_pair_frf(rng)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        vf = fit_model(frf, method="vf")
    assert vf.fit_error[0, 2:].max() < ORDER_FLOOR
    assert vf.fit_error[0, 0] <= 1.5 * vf.noise_level[0, 0]
    p = vf.poles[0, 2, :vf.n_poles[0, 2]]
    k = np.argmin(np.abs(np.abs(p) - 2 * np.pi * 4.0))
    assert abs(np.abs(p[k]) / (2 * np.pi) - 4.0) < 0.02 and abs(-p[k].real / abs(p[k]) - 0.15) < 0.01


def test_model_summary_file_says_its_units(identified_model, tmp_path):
    """``identify``'s summary beside the model: the summary's table, then its unit system
    as the last column (issues 23 and 36), which pandas and the marker reader both read."""
    import pandas as pd

    from ident.data.files import read_csv_table
    from ident.identify.model import summary_path, write_model_summary

    path = write_model_summary(identified_model, summary_path(tmp_path / "model.npz"),
                               units="imperial")
    assert path.name == "model_summary.csv"
    assert path.read_text().splitlines()[0].endswith(",units")
    assert set(pd.read_csv(path)["units"]) == {"imperial"}
    frame, units = read_csv_table(path)
    summary = identified_model.summary()
    assert units == "imperial" and list(frame.columns) == list(summary.columns)
    assert frame["fit_error"].tolist() == summary["fit_error"].tolist()


def test_model_keeps_its_declared_elements(tmp_path, identified_model):
    """settings["elements"]: read as CarElements, saved and loaded with the model, named in
    the summary; a model without them has none."""
    from ident.models.bumpstops import BumpStop, BumpStopLibrary, CarElements

    assert identified_model.elements is None
    lib = BumpStopLibrary([BumpStop("BS-F", 0.006, [0.0, 0.01], [0.0, 2000.0])])
    el = CarElements(lib, {"LF": "BS-F", "RF": "BS-F"}, {"RF": 0.001},
                     [3000.0, 3000.0, 3200.0, 3200.0])
    model = identified_model.with_settings(dict(identified_model.settings,
                                                elements=el.to_dict()))
    back = load_model(model.save(tmp_path / "m.npz"))
    assert back.elements.to_dict() == el.to_dict()
    assert back.elements.bump_stops == lib
    assert "BS-F" in back.summary().attrs["elements"]
    assert "no bump stops" in identified_model.summary().attrs["elements"]
