"""Tests of ident.identify.instruments: the instrumental-variable LPM removes the
errors-in-variables bias that least squares has when the regressor and an output share a
sensor's noise; the travel rows from the velocity rows; when the instruments are on."""

import dataclasses

import numpy as np
import pytest

from ident.errors import IdentificationError
from ident.identify.frf import frf_from_arrays
from ident.identify.instruments import (iv_lpm_solve, session_instruments, travel_from_velocity,
                                        travel_run, travel_velocity)

FS_HZ = 100.0
#: The true gains of the synthetic case: output v from the rig input r and from the force
#: deviation d (a velocity-like output whose sensor noise also enters the measured d).
G_VR, G_VD = 0.8, -0.5
#: c_bar of the synthetic case: the measured dF carries -C_BAR n_v.
C_BAR = 1.0
#: Least squares' relative error on the dF path in the synthetic case: the cross term
#: -c_bar S_nv / S_dF with the noise's power 40 % of dF's (expected about 0.4 / 1.4 x 2 =
#: 57 % here); the test asks for more than this to show the case can fail.
LS_BIAS_MIN = 0.2
#: The IV estimate's error on the same path, averaged over 20 target lines: its scatter
#: (4 runs of 2^14 samples, windows of 41 lines: about 1-2 %), not a bias.
IV_ERROR_MAX = 0.05


def _synthetic_runs(rng, n_runs=4, n=2 ** 14, noise=0.63):
    """Runs of v = G_VR r + G_VD d measured with noise n_v; dF measured as d - C_BAR n_v (the
    shared sensor), an instrument d + n_x (its own sensor)."""
    runs = []
    for k in range(n_runs):
        r = rng.standard_normal(n)
        d = rng.standard_normal(n) * (k > 0)
        n_v = noise * rng.standard_normal(n)
        v_m = G_VR * r + G_VD * d + n_v
        dF_m = d - C_BAR * n_v
        dF_x = d + noise * rng.standard_normal(n)
        runs.append((r, dF_m, v_m, dF_x))
    return runs


def test_iv_lpm_removes_the_shared_noise_bias_least_squares_has(rng):
    """Known answer: with the regressor dF = d - c n_v and the output v + n_v sharing n_v,
    least squares (the LPM) is biased on the dF path by far more than its scatter; the IV
    LPM with an instrument of independent noise recovers the gains."""
    runs = _synthetic_runs(rng)
    f = np.linspace(2.0, 40.0, 20)
    spectra = [np.fft.rfft(np.vstack([r, dF, v, x]), axis=-1) for r, dF, v, x in runs]
    n = [runs[0][0].size] * len(runs)
    H, _, partial, *_ = iv_lpm_solve(spectra, n, 2, 1, f, FS_HZ, 2, 20, 40,
                                     np.zeros(1, dtype=bool))
    iv_err = abs(np.mean(H[0, 1]) / G_VD - 1)
    ls = frf_from_arrays([np.column_stack([r, dF]) for r, dF, _, _ in runs],
                         [v[:, None] for _, _, v, _ in runs], fs=FS_HZ, nperseg=1024,
                         estimator="lpm", lpm_half_width=20)
    band = (ls.f_hz >= 2.0) & (ls.f_hz <= 40.0)
    ls_err = abs(np.mean(ls.H[0, 1, band]) / G_VD - 1)
    assert ls_err > LS_BIAS_MIN
    assert iv_err < IV_ERROR_MAX
    assert abs(np.mean(H[0, 0]) / G_VR - 1) < IV_ERROR_MAX
    assert np.all((partial >= 0) & (partial <= 1))


def test_travel_rows_are_the_velocity_rows_integrated():
    """shock_travel_XX rows = shock_velocity_XX rows / (j 2 pi f) with their coherences; DC
    and outputs without their velocity kept."""
    outs = ("shock_velocity_LF", "shock_travel_LF", "shock_travel_RF")
    f = np.array([0.0, 1.0, 2.0])
    H = np.arange(18, dtype=complex).reshape(3, 2, 3) + 1
    partial = np.full((3, 2, 3), 0.5)
    partial[0] = 0.9
    mult = np.zeros((3, 3))
    H2, p2, m2 = travel_from_velocity(H, partial, mult, outs, f)
    np.testing.assert_allclose(H2[1][:, 1:], H[0][:, 1:] / (2j * np.pi * f[1:]))
    np.testing.assert_array_equal(H2[1][:, 0], H[1][:, 0])
    np.testing.assert_array_equal(H2[2], H[2])
    assert np.all(p2[1][:, 1:] == 0.9) and np.all(p2[2] == 0.5)


def test_travel_run_takes_velocities_from_travels_and_drops_load_cells(prototype_case):
    """The instruments' run: corner and element velocities from their travels, no load
    cell, the rest unchanged."""
    _, session = prototype_case
    run = session.runs[0]
    z = travel_run(run)
    assert not any(k.startswith("shock_force_") or k.endswith(("force_front", "force_rear"))
                   for k in z.channels)
    np.testing.assert_array_equal(z.channels["shock_velocity_LF"],
                                  travel_velocity(run.channels["shock_travel_LF"], run.fs_hz))
    np.testing.assert_array_equal(z.channels["heave_velocity_front"], travel_velocity(
        run.channels["heave_travel_front"], run.fs_hz))
    np.testing.assert_array_equal(z.channels["tire_force_LF"], run.channels["tire_force_LF"])


def test_instruments_on_by_default_only_with_third_elements(prototype_case, paper_session):
    """auto: on for the prototype session (third elements, travels recorded), off for a
    plain session (it identifies as before); on is refused without travels or with Welch."""
    _, session = prototype_case
    assert session_instruments(session) is True
    assert session_instruments(session, False) is False
    assert session_instruments(paper_session) is False
    with pytest.raises(IdentificationError, match="--instruments off"):
        session_instruments(session, True, estimator="welch")
    bare = dataclasses.replace(session, runs=tuple(
        dataclasses.replace(r, channels={k: v for k, v in r.channels.items()
                                         if k != "shock_travel_RR"}) for r in session.runs))
    assert session_instruments(bare) is False
    with pytest.raises(IdentificationError, match="shock_travel_RR"):
        session_instruments(bare, True)
