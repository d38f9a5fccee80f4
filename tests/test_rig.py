"""Tests of ident.sim.rig: experiment plans and the virtual rig."""

from dataclasses import replace

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from ident.data.channels import CORNERS, RIG_INPUTS
from ident.errors import SessionError
from ident.identify.frf import frf_from_arrays
from ident.sim.rig import PlanRun, default_plan, read_rig_plan, simulate_session
from ident.data.units import to_si

DB_TOL_FRF = 0.5  # issue: H1 vs analytic within 0.5 dB where coherence > 0.99
COH_MIN = 0.99
RTOL_NOISE = 0.05  # std of 80 000 noise samples is known to ~0.3 %; 5 % margin
ATOL_DAQ = 1e-4  # the acquisition filter: flat to 1e-5 in band, below -80 dB above 60 Hz
RTOL_DAQ_FFT = 1e-12  # FFT vs polyphase acquisition filter: rounding (seen < 1e-14 of the RMS)


def test_default_plan_is_the_papers(paper_plan):
    assert [r.name for r in paper_plan.runs] == ["baseline", "swap-LF", "swap-RF", "swap-LR", "swap-RR"]
    assert all(r.duration_s == 800.0 for r in paper_plan.runs)
    assert paper_plan.fs_hz == 100.0
    assert paper_plan.shocks["B20"].c_n_s_m == pytest.approx(to_si(20.0, "damping", "imperial"))
    for run in paper_plan.runs[1:]:
        swapped = [c for c in CORNERS if run.setup[c] != "B20"]
        assert swapped == [run.name[-2:]] and run.setup[swapped[0]] == "N8"
    assert paper_plan.drive["peak_wheelloader_m"] == pytest.approx(0.0254)
    assert paper_plan.drive["peak_aero_heave_n"] == pytest.approx(to_si(500.0, "force", "imperial"))


def test_swap_shock_is_about_8_lbf_in_s(paper_session):
    """The paper's swap shock: about 8 lbf/(in/s) equivalent damping where it runs."""
    n8 = paper_session.shocks["N8"]
    for c in CORNERS:
        run = paper_session.run(f"swap-{c}")
        v_rms = np.std(run.channels[f"shock_velocity_{c}"])
        c_eq = to_si(1.0, "damping", "imperial") ** -1 * float(n8.equivalent_damping(v_rms))
        assert 7.0 <= c_eq <= 9.0
        # the swapped corner moves faster than with the 20 lbf/(in/s) baseline
        base = np.std(paper_session.run("baseline").channels[f"shock_velocity_{c}"])
        assert v_rms > 1.2 * base


def test_session_channels(paper_session, paper_model):
    run = paper_session.runs[1]
    assert run.n_samples == 80000 and run.fs_hz == pytest.approx(100.0)
    for name in RIG_INPUTS + paper_model.output_names + tuple(f"shock_force_{c}" for c in CORNERS):
        assert name in run.channels and np.all(np.isfinite(run.channels[name]))
    # wheelloader peaks are the paper's 1 in
    assert np.abs(run.channels["wheelloader_LF"]).max() == pytest.approx(0.0254, rel=1e-9)


def test_h1_frf_of_linear_run_matches_analytic(linear_session, paper_model):
    """Issue criterion: the H1 FRF of a simulated run with linear shocks matches the analytic
    closed-loop FRF within 0.5 dB wherever coherence > 0.99, 0.5-20 Hz.

    The coherence is the partial coherence of each input/output pair: with the paper's
    drive, weak paths sit under strong ones and the leakage of the strong ones (a
    transient error that falls only with the total record length) is noise for them,
    which the multiple coherence of the output does not show.
    """
    run = linear_session.runs[0]
    outs = paper_model.output_names
    frf = frf_from_arrays(np.column_stack([run.dynamic(c) for c in RIG_INPUTS]),
                          np.column_stack([run.dynamic(o) for o in outs]), fs=run.fs_hz,
                          nperseg=4096, input_names=RIG_INPUTS, output_names=outs)
    c = linear_session.shocks["B20"].c_n_s_m
    Ha = paper_model.frequency_response(frf.f_hz, damping_n_s_m=c)[:, :7]
    band = (frf.f_hz >= 0.5) & (frf.f_hz <= 20.0)
    ok = (frf.partial_coherence > COH_MIN) & band[None, None, :]
    err_db = np.abs(20 * np.log10(np.abs(frf.H[ok]) / np.abs(Ha[ok])))
    assert err_db.max() < DB_TOL_FRF
    assert ok.sum() > 0.4 * ok.shape[0] * ok.shape[1] * band.sum()  # a real share of the band
    # the direct path is covered over most of the band (below ~3 Hz the aero moments
    # dominate the tire force and the wheelloader's partial coherence drops)
    o, i = outs.index("tire_force_LF"), RIG_INPUTS.index("wheelloader_LF")
    assert ok[o, i, band].mean() > 0.7


def test_acquisition_filter_removes_aliases():
    """Every simulated channel passes the same anti-aliasing low-pass before decimation:
    a tone above the sampled Nyquist frequency (it would alias to 10 Hz) is removed, an in-band
    tone passes unchanged, and the samples stay aligned in time."""
    from ident.sim.rig import _daq_sample

    r, fs, n = 8, 100.0, 2000
    t = np.arange((n - 1) * r + 1) / (fs * r)
    out = _daq_sample({"band": np.sin(2 * np.pi * 10.0 * t), "alias": np.sin(2 * np.pi * 90.0 * t)},
                      r, n)
    inner = slice(100, n - 100)  # away from the record's ends
    k = np.arange(n)
    np.testing.assert_allclose(out["band"][inner], np.sin(2 * np.pi * 10.0 * k / fs)[inner],
                               atol=ATOL_DAQ)
    assert np.abs(out["alias"][inner]).max() < ATOL_DAQ
    assert out["band"].shape == (n,)


@pytest.mark.parametrize("r, n", [(8, 8000), (8, 1), (8, 2), (8, 1021), (3, 1001), (2, 4097),
                                  (5, 40), (16, 300), (1, 50)])
def test_acquisition_filter_equals_polyphase_reference(rng, r, n):
    """The FFT acquisition filter gives the numbers of the polyphase one it replaced
    (edge-extended record, resample_bandlimited, decimated), on records of odd and
    even length, shorter than the filter and longer than one FFT segment."""
    from ident.data.drive import FIR_HALF_LENGTH, resample_bandlimited
    from ident.sim.rig import _daq_sample

    n_fine = (n - 1) * r + 1
    t = np.arange(n_fine) / (100.0 * r)
    channels = {"noise": rng.standard_normal(n_fine) + 3.0,
                "ramp": np.linspace(-1.0, 2.0, n_fine),
                "tones": np.sin(2 * np.pi * 10.0 * t) + 0.3 * np.sin(2 * np.pi * 90.0 * t)}
    out = _daq_sample(channels, r, n)
    pad = (FIR_HALF_LENGTH + 1) * r
    for name, x in channels.items():
        ref = x if r == 1 else resample_bandlimited(np.pad(x, pad, mode="edge"), 1, r)[
            pad // r: pad // r + n]
        assert out[name].shape == (n,)
        np.testing.assert_allclose(out[name], ref, rtol=0,
                                   atol=RTOL_DAQ_FFT * np.sqrt(np.mean(ref ** 2)),
                                   err_msg=f"r={r}, n={n}: {name}")


def test_measurement_noise(paper_plan):
    runs = (PlanRun("b", {c: "B20" for c in CORNERS}, "baseline", 5, 100.0),)
    clean = simulate_session(replace(paper_plan, runs=runs))
    noisy = simulate_session(replace(paper_plan, runs=runs, noise=0.02))
    for name in ("tire_force_LF", "ride_height_RR", "shock_velocity_LR"):
        a, b = clean.runs[0].channels[name], noisy.runs[0].channels[name]
        assert np.std(b - a) == pytest.approx(0.02 * np.std(a), rel=RTOL_NOISE)
    np.testing.assert_array_equal(clean.runs[0].channels["aero_heave"],
                                  noisy.runs[0].channels["aero_heave"])


def test_noise_floor_per_channel_and_inputs(paper_plan):
    """Per-kind and per-channel overrides, input noise on the recorded rig inputs only, and one
    noise floor per channel for the whole session (a sensor's, not a run's): a swap run whose
    shock velocity is larger gets the same noise as the baseline's.

    A channel without noise is the clean session's bit for bit: the runs are simulated on
    threads, each run's loop on one thread from start to end, and BLAS (the one call in the
    loop: its output product) on one thread, so the bits do not depend on the scheduling.
    """
    runs = (PlanRun("b", {c: "B20" for c in CORNERS}, "baseline", 5, 100.0),
            PlanRun("s", {"LF": "N8", "RF": "B20", "LR": "B20", "RR": "B20"}, "swap", 5, 100.0))
    plan = replace(paper_plan, runs=runs, noise=0.02, input_noise=0.005,
                   channel_noise={"tire_force": 0.0, "ride_height_RR": 0.05, "aero": 0.0})
    with threadpool_limits(limits=1, user_api="blas"):
        clean = simulate_session(replace(paper_plan, runs=runs))
        noisy = simulate_session(plan)

    def session_rms(name):
        return np.sqrt(np.mean([np.mean((r.channels[name] - r.channels[name].mean()) ** 2)
                                for r in clean.runs]))

    for name, level in (("shock_velocity_LF", 0.02), ("ride_height_RR", 0.05),
                        ("wheelloader_LF", 0.005), ("wheelloader_RR", 0.005)):
        for a, b in zip(clean.runs, noisy.runs):
            got = np.std(b.channels[name] - a.channels[name])
            assert got == pytest.approx(level * session_rms(name), rel=RTOL_NOISE)
    for name in ("tire_force_LF", "aero_heave", "aero_roll"):
        for a, b in zip(clean.runs, noisy.runs):
            np.testing.assert_array_equal(a.channels[name], b.channels[name])
    # the swapped corner's velocity differs between runs, its noise does not
    v = [np.std(r.channels["shock_velocity_LF"]) for r in clean.runs]
    assert abs(v[1] / v[0] - 1) > 0.1


@pytest.mark.parametrize("kind", ["sweep", "track"])
def test_other_drive_kinds(paper_plan, kind):
    drive = {"kind": kind, "amplitude_wheelloader_m": 0.005, "f_start_hz": 0.5,
             "f_stop_hz": 25.0, "taper_s": 1.0, "speed_m_s": 50.0}
    runs = (PlanRun("b", {c: "B20" for c in CORNERS}, "baseline", 5, 30.0),)
    s = simulate_session(replace(paper_plan, runs=runs, drive=drive))
    assert np.std(s.runs[0].channels["tire_force_LF"]) > 0


def test_write_and_read_back(tmp_path, paper_plan):
    from ident.data.session import read_session, write_session

    runs = (PlanRun("b", {c: "B20" for c in CORNERS}, "baseline", 5, 20.0),
            PlanRun("s", {"LF": "N8", "RF": "B20", "LR": "B20", "RR": "B20"}, "swap", 5, 20.0))
    s = simulate_session(replace(paper_plan, runs=runs))
    write_session(s, tmp_path / "sess", units="imperial")
    back = read_session(tmp_path / "sess")
    assert back.units == "imperial"
    for a, b in zip(s.runs, back.runs):
        for name in ("tire_force_RR", "aero_pitch", "shock_force_LF"):
            np.testing.assert_allclose(b.channels[name], a.channels[name], rtol=1e-12, atol=1e-12)


def _plan_text():
    from ident.sim.rig import DEFAULT_PLAN_PATH

    return DEFAULT_PLAN_PATH.read_text()


BAD_PLANS = [
    (lambda t: t.replace('format = "rig-plan/1"', 'format = "rig-plan/9"'), "format"),
    (lambda t: t.replace('units = "imperial"', 'units = "furlongs"'), "unknown unit system"),
    (lambda t: t.replace('kind = "noise"', 'kind = "earthquake"'), "earthquake"),
    (lambda t: t.replace('LF = "N8"', 'LF = "Z99"', 1), "Z99"),
    (lambda t: t.replace('name = "swap-RF"', 'name = "swap-LF"'), "duplicate run names"),
    (lambda t: t.replace('setup = { LF = "B20", RF = "B20", LR = "B20", RR = "B20" }',
                         'setup = { LF = "B20", RF = "B20", LR = "B20" }'), "setup"),
    (lambda t: t.replace('fs_hz = 100.0', 'fs_hz = -100.0'), "positive"),
    (lambda t: t.replace('role = "swap"', 'role = "party"', 1), "role"),
    (lambda t: t.replace("noise = 0.0 ", "noise = 1.5 "), "'noise' = 1.5 must be a fraction"),
    (lambda t: t.replace("noise = 0.0 ", "input_noise = -0.1\nnoise = 0.0 "), "'input_noise'"),
    (lambda t: t.replace("[drive]", "[channel_noise]\ntire_forces = 0.01\n\n[drive]"),
     "unknown key 'tire_forces' .did you mean 'tire_force'"),
    (lambda t: t.replace("[drive]", "[channel_noise]\nwheelloader = 2.0\n\n[drive]"),
     "'wheelloader' = 2.0"),
]


@pytest.mark.parametrize("edit,match", BAD_PLANS)
def test_bad_plans(tmp_path, edit, match):
    from ident.sim.rig import DEFAULT_PLAN_PATH

    (tmp_path / "paper_shocks.toml").write_text(
        (DEFAULT_PLAN_PATH.parent / "paper_shocks.toml").read_text())
    path = tmp_path / "plan.toml"
    path.write_text(edit(_plan_text()))
    with pytest.raises(SessionError, match=match):
        read_rig_plan(path)


def test_plan_missing_shock_library(tmp_path):
    path = tmp_path / "plan.toml"
    path.write_text(_plan_text())
    with pytest.raises(Exception, match="paper_shocks.toml"):
        read_rig_plan(path)


def test_default_plan_reads():
    assert default_plan().name == "paper identification experiment"


def test_plan_noise_keys(tmp_path):
    from ident.sim.rig import DEFAULT_PLAN_PATH

    (tmp_path / "paper_shocks.toml").write_text(
        (DEFAULT_PLAN_PATH.parent / "paper_shocks.toml").read_text())
    path = tmp_path / "plan.toml"
    path.write_text(_plan_text().replace("noise = 0.0 ", "noise = 0.02\ninput_noise = 0.005 ")
                    .replace("[drive]", "[channel_noise]\nshock_force = 0.01\n"
                             "wheelloader_LF = 0.001\n\n[drive]"))
    plan = read_rig_plan(path)
    assert (plan.noise, plan.input_noise) == (0.02, 0.005)
    assert plan.channel_noise == {"shock_force": 0.01, "wheelloader_LF": 0.001}
    assert [plan.noise_level(c) for c in ("shock_force_RR", "shock_velocity_RR",
                                          "wheelloader_LF", "wheelloader_RF")] == [
        0.01, 0.02, 0.001, 0.005]
