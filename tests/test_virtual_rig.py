"""Tests of ident.sim.virtual_rig: experiment plans and the virtual rig."""

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from ident.data.channels import CORNERS, RIG_INPUTS
from ident.errors import SessionError
from ident.models.bumpstops import BumpStop, BumpStopLibrary, write_bump_stops
from ident.identify.frf import frf_from_arrays
from ident.sim.virtual_rig import PlanRun, default_plan, read_rig_plan, simulate_session
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
    from ident.sim.virtual_rig import _daq_sample

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
    from ident.sim.virtual_rig import _daq_sample

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
    from ident.sim.virtual_rig import DEFAULT_PLAN_PATH

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
    from ident.sim.virtual_rig import DEFAULT_PLAN_PATH

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
    from ident.sim.virtual_rig import DEFAULT_PLAN_PATH

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


# ----------------------------------------------------------------------------------------------
# bump stops, packers and lift-off on the virtual rig (issue 25)
# ----------------------------------------------------------------------------------------------

STOP_TABLE = ([0.0, 0.002, 0.005, 0.010, 0.015], [0.0, 200.0, 1000.0, 3500.0, 6500.0])
#: Bump stops with the same table: never reached (1 m), 3 mm and 5 mm from rest.
STOPS = BumpStopLibrary([BumpStop(sid, gap, *STOP_TABLE) for sid, gap in
                         (("far", 1.0), ("g3", 0.003), ("g5", 0.005))])
#: An imperial file's numbers come back to SI within round-off (in = 0.0254 m exactly; the
#: TOML writer keeps 17 digits).
RTOL_UNITS = 1e-12
#: The dynamic tire force with lift-off stays a deviation from rest: its mean is a small
#: share of the static load (a mean aero share and the run's ends; the session's own check
#: allows 20 %).
MEAN_TIRE_SHARE = 0.1


def _gt_plan(paper_plan, runs, **kw):
    """The paper's plan (shocks, noise-free) with a track drive, for the GT car."""
    drive = {"kind": "track", "speed_m_s": 50.0}
    return replace(paper_plan, runs=runs, drive=drive, oversample=4, noise=0.0, **kw)


def _at(sid):
    return dict.fromkeys(CORNERS, sid)


def test_rig_runs_carry_bump_stops_packers_and_static_loads(paper_plan, bumpstop_vehicle):
    """A run's bump stops (gap less packer) and the plan's static loads change the session
    where they act, and nothing where they are never reached; the shock force channel stays
    the shock's; the session records what each run had fitted."""
    b20 = _at("B20")
    runs = (PlanRun("plain", b20, "baseline", 5, 12.0),
            PlanRun("far", b20, "baseline", 5, 12.0, bump_stops=_at("far")),
            PlanRun("stops", b20, "baseline", 5, 12.0, bump_stops=_at("g3")),
            PlanRun("packed", b20, "baseline", 5, 12.0, bump_stops=_at("g5"),
                    packers_m=dict.fromkeys(CORNERS, 0.002)))
    s = simulate_session(_gt_plan(paper_plan, runs, bump_stops=STOPS), bumpstop_vehicle)
    plain, far, stops, packed = (r.channels for r in s.runs)
    for name, x in plain.items():
        np.testing.assert_array_equal(far[name], x, err_msg=name)
    # a 5 mm gap with a 2 mm packer is a 3 mm gap
    for name, x in stops.items():
        np.testing.assert_array_equal(packed[name], x, err_msg=name)
    travel = plain["shock_travel_LF"]
    assert np.mean(travel > 0.003) > 0.01  # the stops are reached
    assert stops["shock_travel_LF"].max() < travel.max()
    # what was fitted, as a real rig's session records it
    assert s.bump_stops is STOPS and s.static_corner_load_n is None
    assert [r.bump_stops for r in s.runs] == [_at(None), _at("far"), _at("g3"), _at("g5")]
    assert s.runs[3].packers_m == _at(0.002) and s.runs[2].packers_m == _at(0.0)

    static = 0.3 * bumpstop_vehicle.static_corner_load_n
    lifted = simulate_session(_gt_plan(paper_plan, runs[:1], static_corner_load_n=static),
                              bumpstop_vehicle)
    np.testing.assert_array_equal(lifted.static_corner_load_n, static)
    lf = lifted.runs[0].channels["tire_force_LF"]
    # the recorded contact force: zero while off the pad, up to the acquisition filter's
    # ringing at the lift-off edges (a small share of the static load)
    assert np.mean(static[0] + plain["tire_force_LF"] < 0) > 0.001
    assert (static[0] + lf).min() > -0.05 * static[0]
    # the channel stays the dynamic part (no static offset), as without static loads
    assert abs(np.mean(lf)) < MEAN_TIRE_SHARE * static[0]


def test_contact_stops_are_the_loops_tables():
    """PlanRun.contact_stops: the library's stops at gap less packer, None elsewhere; a run
    without bump stops (or with "none" everywhere) gives None: the loop of before."""
    run = PlanRun("r", _at("B20"), "baseline", 1, 1.0, bump_stops={"LF": "g5", "RR": "NONE"},
                  packers_m={"LF": 0.002, "RF": 0.001})
    got = run.contact_stops(STOPS)
    assert got[0][0] == pytest.approx(0.003) and got[1:] == (None, None, None)
    np.testing.assert_array_equal(got[0][2], STOP_TABLE[1])
    assert run.fitted(STOPS) == ({"LF": "g5", "RF": None, "LR": None, "RR": None},
                                 {"LF": 0.002, "RF": 0.001, "LR": 0.0, "RR": 0.0})
    assert PlanRun("r", _at("B20"), "baseline", 1, 1.0).contact_stops(None) is None
    assert PlanRun("r", _at("B20"), "baseline", 1, 1.0,
                   bump_stops=_at("none")).contact_stops(STOPS) is None


@pytest.mark.parametrize("stops, packers, library, match", [
    (_at("g3"), {"LF": 0.004}, STOPS, "packers LF: packer 4 mm .* is thicker than the gap"),
    (_at("g3"), {"LF": -0.001}, STOPS, "packers LF: packer -1 mm .* is negative"),
    (None, {"LR": "thick"}, STOPS, "packers LR = 'thick' is not a thickness"),
    ({"XX": "g3"}, None, STOPS, r"bump_stops names unknown corner\(s\) \['XX'\]"),
    ({"LF": "g4"}, None, STOPS, "bump_stops LF: unknown bump-stop id 'g4'"),
    ({"LF": "g3"}, None, None, "bump_stops LF = 'g3' but the plan has no bump-stop library"),
])
def test_rig_refuses_bad_bump_stops(paper_plan, stops, packers, library, match):
    """Refused before any run is simulated, naming the run and the corner."""
    runs = (PlanRun("bad", _at("B20"), "baseline", 5, 12.0, bump_stops=stops,
                    packers_m=packers),)
    with pytest.raises(SessionError, match=f"run 'bad': {match}"):
        simulate_session(_gt_plan(paper_plan, runs, bump_stops=library))


def test_rig_plan_refuses_bad_static_loads(paper_plan):
    with pytest.raises(SessionError, match="no load for corner"):
        replace(paper_plan, static_corner_load_n={"LF": 3000.0, "RF": 3000.0, "LR": 3000.0})
    with pytest.raises(SessionError, match="RF = -1.0 is not a load"):
        replace(paper_plan, static_corner_load_n=[3000.0, -1.0, 3000.0, 3000.0])


# -- the plan file's keys ----------------------------------------------------------------------

#: A real car for the paper's car (front stops 1.5 mm from rest, rear 2 mm; in inches they
#: are 0.059 and 0.079 in), in SI.
REAL_STOPS = BumpStopLibrary([BumpStop("BS-F", 0.0015, [0.0, 0.004, 0.008], [0.0, 700.0, 3000.0]),
                              BumpStop("BS-R", 0.002, [0.0, 0.008], [0.0, 2500.0])])
SHOCKS = {"SI": "B20", "imperial": "B20"}


def _real_plan(folder, *, units="SI", top=None, run=None, drive=None, stops_units=None):
    """A tiny plan (2 runs of 3 s at 100 Hz) with the real car's keys; `top`, `run` and
    `drive` replace the keys at the top, of the first run and below [drive]."""
    from ident.sim.virtual_rig import DEFAULT_PLAN_PATH

    folder.mkdir(exist_ok=True)
    shutil.copy(DEFAULT_PLAN_PATH.parent / "paper_shocks.toml", folder / "shocks.toml")
    write_bump_stops(REAL_STOPS, folder / "bumpstops.toml", units=stops_units or units,
                     overwrite=True)
    si = units == "SI"
    loads = "{ LF = 3000.0, RF = 3000.0, LR = 3600.0, RR = 3600.0 }" if si else \
        "{ LF = 675.0, RF = 675.0, LR = 810.0, RR = 810.0 }"
    top = (f'bump_stop_library = "bumpstops.toml"\nstatic_corner_load = {loads}\n'
           if top is None else top)
    packer = "0.001" if si else "0.04"
    run = (f'bump_stops = {{ LF = "BS-F", RF = "BS-F", LR = "BS-R", RR = "none" }}\n'
           f"packers = {{ LF = {packer} }}\n" if run is None else run)
    # a gentle drive (the paper's aero moments are 3x the chassis stiffness per degree):
    # the tires lift off a little, and a 3 s run's mean tire force stays near 0
    peak = "0.005\npeak_aero_heave = 200.0" if si else "0.2\npeak_aero_heave = 45.0"
    peak += "\nroll_moment_multiple = 0.3\npitch_moment_multiple = 0.3"
    drive = "" if drive is None else drive
    b20 = '{ LF = "B20", RF = "B20", LR = "B20", RR = "B20" }'
    (folder / "plan.toml").write_text(
        f'format = "rig-plan/1"\nname = "real car"\nunits = "{units}"\n'
        f'shock_library = "shocks.toml"\nfs_hz = 100.0\nduration_s = 3.0\noversample = 2\n'
        f"seed = 4\n{top}\n[drive]\nkind = \"noise\"\ntaper_s = 0.5\n"
        f"peak_wheelloader = {peak}\n{drive}\n"
        f'[[run]]\nname = "baseline"\nsetup = {b20}\nrole = "baseline"\n{run}\n'
        f'[[run]]\nname = "swap-LF"\nsetup = {{ LF = "N8", RF = "B20", LR = "B20", RR = "B20" }}\n'
        f'role = "swap"\n')
    return folder / "plan.toml"


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_plan_keys_round_trip_through_the_session(tmp_path, units):
    """Plan (file units) -> simulated session -> written -> read: the bump stops, the runs'
    fitted stops and packers and the static loads are kept, in SI."""
    from ident.data.session import read_session, write_session

    plan = read_rig_plan(_real_plan(tmp_path / "plan", units=units))
    assert plan.bump_stops.ids == ("BS-F", "BS-R")
    np.testing.assert_allclose([s.gap_m for s in plan.bump_stops.values()], [0.0015, 0.002],
                               rtol=RTOL_UNITS)
    static = [3000.0, 3000.0, 3600.0, 3600.0] if units == "SI" else \
        to_si(np.array([675.0, 675.0, 810.0, 810.0]), "force", "imperial")
    np.testing.assert_allclose(plan.static_corner_load_n, static, rtol=RTOL_UNITS)
    first, second = plan.runs
    assert first.bump_stops == {"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": None}
    assert first.packers_m["LF"] == pytest.approx(0.001 if units == "SI" else 0.001016,
                                                  rel=RTOL_UNITS)
    assert second.bump_stops is None and second.packers_m is None

    session = simulate_session(plan)
    write_session(session, tmp_path / "sess")
    back = read_session(tmp_path / "sess")
    assert back.units == units and back.bump_stop_library_file == "bumpstops.toml"
    assert back.bump_stops.ids == plan.bump_stops.ids
    for a, b in zip(plan.bump_stops.values(), back.bump_stops.values()):
        np.testing.assert_allclose([b.gap_m, *b.travel_m, *b.force_n],
                                   [a.gap_m, *a.travel_m, *a.force_n], rtol=RTOL_UNITS)
    np.testing.assert_allclose(back.static_corner_load_n, static, rtol=RTOL_UNITS)
    assert back.runs[0].bump_stops == first.bump_stops
    assert back.runs[0].packers_m["LF"] == pytest.approx(first.packers_m["LF"], rel=RTOL_UNITS)
    assert back.runs[1].bump_stops == _at(None) and back.runs[1].packers_m == _at(0.0)
    # the truth acts: the stops of the baseline run are reached at the front
    t = session.runs[0].channels["shock_travel_LF"]
    assert np.mean(t > 0.0015 - first.packers_m["LF"]) > 0.01


def test_plan_without_the_keys_gives_the_session_of_before(tmp_path, paper_plan):
    """No real-car keys: nothing on the plan, the session or its files; a library that no run
    names changes the files only (the loop is the same to the bit)."""
    from ident.data.session import write_session

    path = _real_plan(tmp_path / "plain", top="", run="")
    plan = read_rig_plan(path)
    assert plan.bump_stops is None and plan.static_corner_load_n is None
    assert all(r.bump_stops is None and r.packers_m is None for r in plan.runs)
    s = simulate_session(plan)
    assert s.bump_stops is None and s.static_corner_load_n is None
    assert all(r.bump_stops == _at(None) and r.packers_m == _at(0.0) for r in s.runs)
    write_session(s, tmp_path / "sess")
    manifest = (tmp_path / "sess" / "session.toml").read_text()
    for word in ("bump", "packers", "static"):
        assert word not in manifest
    assert not (tmp_path / "sess" / "bumpstops.toml").exists()
    with_lib = simulate_session(replace(plan, bump_stops=REAL_STOPS))
    for a, b in zip(s.runs, with_lib.runs):
        for name, x in a.channels.items():
            np.testing.assert_array_equal(b.channels[name], x, err_msg=name)
    # the built-in plan has none of them either
    assert paper_plan.bump_stops is None and paper_plan.static_corner_load_n is None


BAD_REAL_PLANS = [
    ("unknown id", {"run": 'bump_stops = { LF = "BS-FF" }\n'},
     r"run 'baseline': bump_stops LF: unknown bump-stop id 'BS-FF' \(did you mean 'BS-F'\?\)"),
    ("no library", {"top": "", "run": 'bump_stops = { LF = "BS-F" }\n'},
     "bump_stops LF = 'BS-F' but the plan has no bump-stop library"),
    ("packer thicker than the gap", {"run": ('bump_stops = { LF = "BS-F" }\n'
                                             "packers = { LF = 0.002 }\n")},
     r"run 'baseline': packers LF: packer 2 mm \(0.07874 in\) is thicker than the gap"),
    ("packer in file units", {"units": "imperial", "run": ('bump_stops = { LF = "BS-F" }\n'
                                                           "packers = { LF = 0.1 }\n")},
     r"packers LF: packer 2.54 mm \(0.1 in\) is thicker"),
    ("negative packer", {"run": "packers = { RR = -0.001 }\n"},
     "packers RR = -0.001 is not a thickness"),
    ("unknown corner", {"run": 'bump_stops = { FL = "BS-F" }\n'},
     r"bump_stops names unknown corner\(s\) \['FL'\]"),
    ("not a table", {"run": 'bump_stops = "BS-F"\n'}, "bump_stops must be a table"),
    ("three loads", {"top": 'static_corner_load = { LF = 1.0, RF = 1.0, LR = 1.0 }\n'},
     "static_corner_load has no load for corner"),
    ("missing library", {"top": 'bump_stop_library = "stops.toml"\n'},
     "bump_stop_library 'stops.toml': .*stops.toml: bump-stop library not found"),
    ("a plan key below [drive]", {"top": "", "drive": "static_corner_load = { LF = 1.0 }\n"},
     r"\[drive\]: 'static_corner_load' is a key of the plan; move it to the top"),
    ("a plan key in a run", {"run": 'bump_stop_library = "bumpstops.toml"\n'},
     "run 'baseline': 'bump_stop_library' is a key of the plan"),
    ("a run key at the top", {"top": 'packers = { LF = 0.001 }\n'},
     "'packers' is a key of a run"),
]


@pytest.mark.parametrize("change, match", [c[1:] for c in BAD_REAL_PLANS],
                         ids=[c[0] for c in BAD_REAL_PLANS])
def test_bad_real_car_plan_raises_one_clear_error(tmp_path, change, match):
    path = _real_plan(tmp_path / "plan", **change)
    with pytest.raises(SessionError, match=match) as info:
        read_rig_plan(path)
    assert str(path) in str(info.value)


def test_the_formats_doc_plan_reads(tmp_path):
    """docs/formats.md's rig-plan example, with its bump-stop library example, reads."""
    import re

    from ident.sim.virtual_rig import DEFAULT_PLAN_PATH

    doc = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    stops = re.search(r"```toml bump-stops\n(.*?)```", doc, re.DOTALL)[1]
    plan = re.search(r'```text\n(format = "rig-plan/1".*?)```', doc, re.DOTALL)[1]
    (tmp_path / "bumpstops.toml").write_text(stops)
    (tmp_path / "plan.toml").write_text(plan)
    shutil.copy(DEFAULT_PLAN_PATH.parent / "paper_shocks.toml", tmp_path / "shocks.toml")
    got = read_rig_plan(tmp_path / "plan.toml")
    assert got.runs[0].bump_stops == {"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": "BS-R"}
    assert got.runs[0].packers_m == {"LF": 0.003, "RF": 0.003}
    np.testing.assert_array_equal(got.static_corner_load_n, [3000.0, 3000.0, 3600.0, 3600.0])


def test_a_dynamic_tire_force_that_looks_static_is_refused(tmp_path):
    """A drive too violent for the car on its static loads, on a short run: the dynamic tire
    force's mean is beyond what a session tells from a channel with the static load in it;
    the rig says so, rather than the session blaming the static load."""
    plan = read_rig_plan(_real_plan(tmp_path / "plan"))
    violent = dict(plan.drive, peak_aero_heave_n=2224.0, roll_moment_multiple=3.0,
                   pitch_moment_multiple=3.0)
    with pytest.raises(SessionError, match="run 'baseline': its dynamic tire_force_RF has a "
                       "mean of .* the drive is too violent"):
        simulate_session(replace(plan, drive=violent))


def test_rig_simulate_cli_records_the_real_car(tmp_path, capsys):
    """``shockplan rig simulate --plan`` with the real car's keys, end to end: the session
    written (here converted to SI) has the bump stops, packers and static loads."""
    from ident.data.session import read_session
    from planner.cli import main

    path = _real_plan(tmp_path / "plan", units="imperial")
    out = tmp_path / "sess"
    assert main(["-q", "rig", "simulate", "--plan", str(path), "--out", str(out),
                 "--units", "SI"]) == 0
    said = capsys.readouterr().out
    assert "bump stops on 1 of 2 runs; static corner loads" in said
    s = read_session(out)
    assert s.units == "SI" and s.runs[0].n_samples == 300
    assert s.runs[0].bump_stops == {"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": None}
    assert s.runs[0].packers_m["LF"] == pytest.approx(0.001016, rel=RTOL_UNITS)
    np.testing.assert_allclose(s.static_corner_load_n, to_si(np.array([675.0, 675.0, 810.0,
                                                                       810.0]), "force",
                                                             "imperial"), rtol=RTOL_UNITS)
    text = (out / "session.toml").read_text()
    assert 'bump_stop_library = "bumpstops.toml"' in text and "packers = { LF = 0.001016" in text
    # a bad plan: exit status 2 and one line naming the run and the fix
    bad = _real_plan(tmp_path / "bad", run='bump_stops = { LF = "BS-X" }\n')
    assert main(["-q", "rig", "simulate", "--plan", str(bad), "--out",
                 str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "unknown bump-stop id 'BS-X'" in err and err.count("\n") == 1


#: Friction at a corner [N] for the rig's friction tests (a realistic size on the GT car).
FRICTION_N = 100.0
#: The shock force channel against the shock's own force at the solved velocity, and the
#: wheel's force balance with the friction in it: the loop's rounding (seen 1e-12 N).
ATOL_FORCE_N = 1e-8


def _friction_plan(paper_plan, friction):
    """The paper's plan, two 5 s runs (B20; N8 at LF: a lagged shock) on an 800 Hz grid
    without oversampling, so the recorded channels are the loop's own steps."""
    runs = tuple(replace(r, duration_s=5.0) for r in paper_plan.runs[:2])
    drive = dict(paper_plan.drive, peak_wheelloader_m=0.006, roll_moment_multiple=0.5,
                 pitch_moment_multiple=0.5)
    return replace(paper_plan, runs=runs, drive=drive, fs_hz=800.0, oversample=1, noise=0.0,
                   suspension_friction_n=friction)


def test_suspension_friction_acts_outside_the_shock_force(paper_plan, bumpstop_vehicle,
                                                          monkeypatch):
    """Friction at LF: the shock force channel stays the shock's own force (behind its lag
    for N8), the wheel's balance holds with the friction in it, the car feels it; no
    friction (the key absent, or all 0) runs the plan's shocks themselves: the loop of
    before, to the bit."""
    from scipy.signal import lfilter

    from ident.models.lti import lag_hold_coefficients
    from ident.sim import virtual_rig as rig
    from ident.sim.virtual_rig import friction_force

    s = simulate_session(_friction_plan(paper_plan, {"LF": FRICTION_N}), bumpstop_vehicle)
    h = 1.0 / 800.0
    for run in s.runs:
        ch = run.channels
        shock = paper_plan.shocks[run.setup["LF"]]
        v = ch["shock_velocity_LF"]
        own, fric = shock.force(v), friction_force(v, FRICTION_N)
        if shock.lag_s:
            alpha, b0, b1, bm = (float(x) for x in lag_hold_coefficients(shock.lag_s, h))
            own = lfilter([b0, b1, bm], [1.0, -alpha], own)
            fric = lfilter([b0, b1, bm], [1.0, -alpha], fric)
        np.testing.assert_allclose(ch["shock_force_LF"], own, rtol=0, atol=ATOL_FORCE_N)
        for c, m_u in zip(CORNERS, bumpstop_vehicle.unsprung_mass_kg):
            balance = (ch[f"tire_force_{c}"] - ch[f"spring_force_{c}"]
                       - ch[f"shock_force_{c}"] - m_u * ch[f"wheel_accel_{c}"])
            np.testing.assert_allclose(balance, fric if c == "LF" else 0.0, rtol=0,
                                       atol=ATOL_FORCE_N, err_msg=c)
        assert np.abs(fric).max() > 0.99 * FRICTION_N
    seen = []
    real_simulate = rig.simulate
    monkeypatch.setattr(rig, "simulate",
                        lambda plant, drive, models, **kw: seen.append(models) or
                        real_simulate(plant, drive, models, **kw))
    plain = simulate_session(_friction_plan(paper_plan, None), bumpstop_vehicle)
    zero = simulate_session(_friction_plan(paper_plan, [0.0] * 4), bumpstop_vehicle)
    for models, run in zip(seen, plain.runs + zero.runs):
        assert models == [paper_plan.shocks[run.setup[c]] for c in CORNERS]
    for a, b, f in zip(plain.runs, zero.runs, s.runs):
        for name, x in a.channels.items():
            np.testing.assert_array_equal(b.channels[name], x, err_msg=name)
        # the car feels the friction
        assert np.abs(f.channels["tire_force_LF"] - a.channels["tire_force_LF"]).max() > 10.0


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_suspension_friction_key(tmp_path, units, caplog):
    """``suspension_friction`` at the top of a plan, in the plan's units (a corner left out
    has none); logged by the rig, not written to the session."""
    import logging

    from ident.data.session import write_session

    value = "{ LF = 60.0, RR = 45.0 }" if units == "SI" else "{ LF = 13.5, RR = 10.1 }"
    plan = read_rig_plan(_real_plan(tmp_path / "plan", units=units,
                                    top=f"suspension_friction = {value}\n", run=""))
    want = [60.0, 0.0, 0.0, 45.0] if units == "SI" else to_si(
        np.array([13.5, 0.0, 0.0, 10.1]), "force", "imperial")
    np.testing.assert_allclose(plan.suspension_friction_n, want, rtol=RTOL_UNITS)
    with caplog.at_level(logging.INFO, logger="ident.sim.virtual_rig"):
        session = simulate_session(plan)
    assert any("suspension_friction_LF 60" in r.getMessage() and "_RF 0 N" in r.getMessage()
               for r in caplog.records)
    write_session(session, tmp_path / "sess")
    assert "friction" not in (tmp_path / "sess" / "session.toml").read_text()


@pytest.mark.parametrize("change, match", [
    ({"top": 'suspension_friction = { FL = 50.0 }\n'},
     r"suspension_friction names unknown corner\(s\) \['FL'\]"),
    ({"top": 'suspension_friction = { LF = -5.0 }\n'},
     "suspension_friction LF = -5.0 is not a friction force"),
    ({"top": 'suspension_friction = 50.0\n'}, "suspension_friction must be a table"),
    ({"top": "", "run": 'suspension_friction = { LF = 50.0 }\n'},
     "'suspension_friction' is a key of the plan"),
])
def test_bad_suspension_friction(tmp_path, change, match):
    with pytest.raises(SessionError, match=match):
        read_rig_plan(_real_plan(tmp_path / "plan", **change))
