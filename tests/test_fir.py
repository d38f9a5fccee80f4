"""Tests of ident.identify.fir: the FRF as FIR filters in the closed loop with the shocks."""

import doctest
import warnings

import numpy as np
import pytest

import ident.identify.fir as firmod
from ident.data.channels import CORNERS, RIG_INPUTS, SHOCK_FORCES
from ident.models.lti import lag_coefficients
from ident.sim.closedloop import simulate_batch
from ident.data.drive import make_noise_drive
from ident.errors import FitWarning
from ident.identify.fir import FirPlant, fir_from_frf, simulate_fir_batch
from ident.identify.frf import MODEL_INPUTS, Frf
from ident.sim.metrics import compute_metrics
from ident.models.shocks import DigressiveShock, LinearShock
from ident.data.units import to_si

FS = 100.0
NPERSEG = 4096  # the paper's Welch block: 40.96 s, 0.024 Hz resolution
C20 = to_si(20.0, "damping", "imperial")  # 3502.5 N/(m/s)

# linear shocks equal to c_bar: dF = 0, only the rig FIRs act; the modal reference at 8x has
# its own 0.05 %, the FIRs are exact up to the kept window (measured 0.2 % worst, wheel accel)
RTOL_LINEAR = 5e-3
# nonlinear loop at 4x oversampling: 0.3 % worst against a 16x modal reference, plus the 8x
# reference's own 0.1 % (measured 0.4 % worst, 0.1 % median)
RTOL_METRICS = 5e-3
# FIR vs its source FRF where significant, below 0.8 Nyquist (measured 3e-4; only the last
# 10 % of the band feels the truncated pre-ringing and the real-valued Nyquist bin)
RTOL_FRF = 1e-2
# the same physical loop written around two baselines: both FIRs exact, both loops at 4x
RTOL_CBAR = 3e-3
# convergence of the passes (tol=1e-9) and FFT round-off
RTOL_PASSES = 1e-7


def _drive(duration_s, seed=3, fs_hz=FS):
    peak = {"aero_heave": 2000.0, "aero_roll": 2.0e4, "aero_pitch": 4.0e4}
    peak.update({w: 0.02 for w in RIG_INPUTS[3:]})
    return make_noise_drive(duration_s=duration_s, fs_hz=fs_hz, peak=peak, seed=seed)


def _n8():
    k = to_si(1.0, "damping", "imperial")
    v = to_si(2.0, "velocity", "imperial")
    return DigressiveShock("N8", bump_low_n_s_m=22 * k, bump_knee_m_s=v, bump_high_n_s_m=5.5 * k,
                           rebound_low_n_s_m=34 * k, rebound_knee_m_s=v, rebound_high_n_s_m=8.5 * k,
                           lag_s=0.004)


def _analytic_frf(model, cbar, *, nperseg=NPERSEG, fs=FS):
    """The physical model closed around cbar, on the Welch grid, as an estimated Frf."""
    f = np.arange(nperseg // 2 + 1) * fs / nperseg
    H = model.frequency_response(f, damping_n_s_m=cbar)
    p, nf = H.shape[0], f.size
    return Frf(f_hz=f, H=H, input_names=MODEL_INPUTS, output_names=tuple(model.output_names),
               multiple_coherence=np.ones((p, nf)), partial_coherence=np.ones(H.shape),
               input_condition=np.ones(nf), independent_fraction=np.ones((11, nf)),
               flagged=np.zeros((11, nf), dtype=bool), n_averages=40,
               cbar_n_s_m=np.full(4, float(cbar)), fs_hz=fs,
               settings={"method": "analytic", "window": "hamming", "nperseg": nperseg,
                         "noverlap": nperseg // 2})


def _rel_rms(a, b):
    return np.sqrt(np.mean((a - b) ** 2, axis=-1) / np.mean(b**2, axis=-1))


@pytest.fixture(scope="module")
def frf20(paper_model):
    return _analytic_frf(paper_model, C20)


@pytest.fixture(scope="module")
def fir20(frf20):
    with warnings.catch_warnings():
        warnings.simplefilter("error", FitWarning)  # the paper car's FIRs fit the window
        return fir_from_frf(frf20)


@pytest.fixture(scope="module")
def comparison(paper_model, fir20):
    """Modal (8x) and FIR responses of the same setups to one 120 s drive."""
    drive = _drive(120.0)
    b20 = LinearShock("B20", C20)
    setups = [[b20] * 4, [_n8()] * 4, [_n8(), b20, b20, _n8()]]
    ref = simulate_batch(paper_model.loop_plant(C20), drive, setups, oversample=8)
    fir = simulate_fir_batch(fir20, drive, setups)
    return ref, fir


def test_fir_reproduces_the_source_frf(frf20, fir20):
    H = frf20.H
    Hf = fir20.frequency_response(frf20.f_hz)
    assert Hf.shape == H.shape
    mag = np.abs(H)
    significant = (mag >= 1e-2 * mag.max(axis=-1, keepdims=True)) \
        & (frf20.f_hz <= 0.8 * FS / 2)[None, None, :]
    rel = np.abs(Hf - H)[significant] / mag[significant]
    assert rel.max() < RTOL_FRF
    assert fir20.settings["discarded_fraction"].max() < firmod.MAX_DISCARDED_FRACTION
    # the pre-ringing of relative-degree-one pairs is real and kept
    vi = fir20.output_names.index("shock_velocity_LF")
    assert fir20.settings["acausal_fraction"][vi, MODEL_INPUTS.index("dF_LF")] > 1e-3


def test_linear_shocks_equal_to_cbar_match_the_modal_simulation(comparison):
    ref, fir = comparison
    assert set(fir.channels) == set(ref.channels)
    for name, y in ref.channels.items():
        assert fir.channels[name].shape == y.shape
        assert _rel_rms(fir.channels[name][0], y[0]) < RTOL_LINEAR, name
    assert np.all(np.abs(fir.channels["shock_force_RR"][0]) > 0)


@pytest.mark.slow
@pytest.mark.heavy
def test_nonlinear_shocks_metrics_match_the_modal_simulation(comparison):
    ref, fir = comparison
    m_ref, m_fir = compute_metrics(ref).values, compute_metrics(fir).values
    assert set(m_ref) == set(m_fir)
    for name, value in m_ref.items():
        np.testing.assert_allclose(m_fir[name], value, rtol=RTOL_METRICS, err_msg=name)
    assert fir.settings["kind"] == "fir" and fir.settings["oversample"] == 4
    assert fir.settings["change"] <= 1e-5 and fir.settings["passes"] < firmod.MAX_PASSES
    assert np.all(fir.newton_iterations >= 1)


def test_result_does_not_depend_on_cbar(paper_model, fir20):
    """One physical loop, written around two baselines (different FIRs and dF)."""
    fir12 = fir_from_frf(_analytic_frf(paper_model, 0.6 * C20))
    drive = _drive(30.0, seed=5)
    setups = [[_n8(), LinearShock("B", C20), _n8(), LinearShock("C", 1.3 * C20)]]
    a = simulate_fir_batch(fir20, drive, setups)
    b = simulate_fir_batch(fir12, drive, setups)
    ma, mb = compute_metrics(a).values, compute_metrics(b).values
    for name in ma:
        np.testing.assert_allclose(mb[name], ma[name], rtol=RTOL_CBAR, err_msg=name)


def _causal_plant(rng, n_taps=40):
    """A small random causal FIR plant whose shock loop is well posed."""
    names = tuple(f"shock_velocity_{c}" for c in CORNERS) + ("tire_force_LF",)
    decay = np.exp(-np.arange(n_taps) / 8.0)
    h_rig = rng.standard_normal((5, 7, n_taps)) * decay
    h_shock = 1e-5 * rng.standard_normal((5, 4, n_taps)) * decay
    h_shock[:4, :, 0] = -2e-5 * np.eye(4)  # a damping-like direct term
    return FirPlant(h_rig=h_rig, h_shock=h_shock, fs_hz=FS, output_names=names,
                    cbar_n_s_m=np.full(4, 1000.0), name="random")


def test_loop_equals_a_plain_recursion(rng):
    """Causal plant at the drive's rate: the compiled loop is the textbook recursion."""
    plant = _causal_plant(rng)
    drive = _drive(2.0, seed=7)
    c = np.array([1500.0, 800.0, 1000.0, 2500.0])
    lag = np.array([0.0, 0.004, 0.01, 0.002])
    setup = [LinearShock(f"L{i}", c[i], lag_s=lag[i]) for i in range(4)]
    res = simulate_fir_batch(plant, drive, [setup], oversample=1)
    assert res.settings["passes"] == 1  # nothing outside the loop's span
    # reference: v_k = v_rig_k + sum_l h[l] dF_{k-l}, F_k = alpha F_{k-1} + b1 f_{k-1} + b0 f_k
    u = drive.as_array()
    N, L = u.shape[0], plant.n_taps
    y_rig = np.zeros((5, N))
    for o in range(5):
        for j in range(7):
            y_rig[o] += np.convolve(u[:, j], plant.h_rig[o, j])[:N]
    alpha, b0, b1 = lag_coefficients(lag, 1.0 / FS)
    cbar = plant.cbar_n_s_m
    h = plant.h_shock
    dF = np.zeros((N, 4))
    F = np.zeros((N, 4))
    v_prev = np.zeros(4)
    F_prev = np.zeros(4)
    for k in range(N):
        past = sum(h[:4, :, lag_k] @ dF[k - lag_k] for lag_k in range(1, min(k, L - 1) + 1))
        c0 = alpha * F_prev + b1 * c * v_prev
        # v = vfree + D0 (c0 + b0 c v - cbar v)
        D0 = h[:4, :, 0]
        v = np.linalg.solve(np.eye(4) - D0 * (b0 * c - cbar)[None, :],
                            y_rig[:4, k] + past + D0 @ c0)
        F[k] = c0 + b0 * c * v
        dF[k] = F[k] - cbar * v
        v_prev, F_prev = v, F[k]
    tire = y_rig[4] + sum(np.convolve(dF[:, j], h[4, j])[:N] for j in range(4))
    np.testing.assert_allclose(res.channels["tire_force_LF"][0], tire, rtol=1e-9,
                               atol=1e-9 * np.abs(tire).max())
    for i, name in enumerate(SHOCK_FORCES):
        np.testing.assert_allclose(res.channels[name][0], F[:, i], rtol=1e-9,
                                   atol=1e-9 * np.abs(F[:, i]).max())


def test_batch_equals_single_and_outputs(fir20):
    drive = _drive(8.0, seed=11)
    setups = [[_n8()] * 4, {"LF": LinearShock("X", 0.5 * C20), "RF": _n8(), "LR": _n8(),
                            "RR": LinearShock("B", C20)}]
    outputs = ["tire_force_LR", "shock_velocity_RF"]
    batch = simulate_fir_batch(fir20, drive, setups, outputs=outputs, tol=1e-9)
    assert set(batch.channels) == set(outputs) | set(SHOCK_FORCES)
    assert batch.channels["tire_force_LR"].shape == (2, drive.n_samples)
    for i, s in enumerate(setups):
        one = simulate_fir_batch(fir20, drive, [s], outputs=outputs, tol=1e-9)
        for name in batch.channels:
            np.testing.assert_allclose(batch.channels[name][i], one.channels[name][0],
                                       rtol=RTOL_PASSES,
                                       atol=RTOL_PASSES * np.abs(one.channels[name]).max())


def test_short_window_warns(frf20):
    with pytest.warns(FitWarning, match="lengthen length_s"):
        plant = fir_from_frf(frf20, length_s=0.3, taper_s=0.1)
    assert plant.settings["discarded_fraction"].max() > firmod.MAX_DISCARDED_FRACTION


def _frf_with(frf, **changes):
    from dataclasses import replace

    return replace(frf, **changes)


BAD_FIR = [
    (dict(length_s=60.0), ValueError, "nperseg/2"),
    (dict(length_s=0.001), ValueError, "taps"),
    (dict(length_s=1.0, taper_s=2.0), ValueError, "longer than length_s"),
    (dict(acausal_s=-0.1), ValueError, "acausal_s"),
    (dict(acausal_s=0.1, acausal_taper_s=0.2), ValueError, "longer than"),
    (dict(length_s="4"), ValueError, "length_s"),
]


@pytest.mark.parametrize("kwargs,exc,match", BAD_FIR)
def test_fir_from_frf_rejects_bad_lengths(frf20, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        fir_from_frf(frf20, **kwargs)


def test_fir_from_frf_rejects_bad_frf(frf20):
    with pytest.raises(TypeError, match="ident.identify.frf.Frf"):
        fir_from_frf(frf20.H)
    cut = _frf_with(frf20, f_hz=frf20.f_hz[:-10], H=frf20.H[..., :-10])
    with pytest.raises(ValueError, match="Welch grid"):
        fir_from_frf(cut)
    H = frf20.H.copy()
    H[3, 8, 100] = np.nan
    with pytest.raises(ValueError, match="condition_frf"):
        fir_from_frf(_frf_with(frf20, H=H))
    with pytest.raises(ValueError, match="inputs must be"):
        fir_from_frf(_frf_with(frf20, input_names=MODEL_INPUTS[::-1]))
    with pytest.raises(ValueError, match="nperseg"):
        fir_from_frf(_frf_with(frf20, settings={}))


def test_simulate_rejects_bad_input(fir20):
    setup = [LinearShock("B", C20)] * 4
    with pytest.raises(ValueError, match="resample_drive"):
        simulate_fir_batch(fir20, _drive(2.0, fs_hz=200.0), [setup])
    drive = _drive(2.0)
    with pytest.raises(TypeError, match="FirPlant"):
        simulate_fir_batch("plant", drive, [setup])
    with pytest.raises(ValueError, match="no setups"):
        simulate_fir_batch(fir20, drive, [])
    with pytest.raises(ValueError, match="unknown outputs"):
        simulate_fir_batch(fir20, drive, [setup], outputs=["tire_force_XX"])
    with pytest.raises(ValueError, match="4 shock models"):
        simulate_fir_batch(fir20, drive, [setup[:3]])
    with pytest.raises(ValueError, match="oversample"):
        simulate_fir_batch(fir20, drive, [setup], oversample=0)


def test_fir_plant_checks_its_fields(rng):
    good = _causal_plant(rng)
    with pytest.raises(ValueError, match="shock velocities"):
        FirPlant(good.h_rig, good.h_shock, FS, ("a", "b", "c", "d", "e"), good.cbar_n_s_m)
    with pytest.raises(ValueError, match="n_taps"):
        FirPlant(good.h_rig[:, :6], good.h_shock, FS, good.output_names, good.cbar_n_s_m)
    with pytest.raises(ValueError, match="n_acausal"):
        FirPlant(good.h_rig, good.h_shock, FS, good.output_names, good.cbar_n_s_m,
                 settings={"n_acausal": good.n_taps})
    assert not good.h_rig.flags.writeable


def test_docstring_examples_run():
    result = doctest.testmod(firmod, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted > 0
