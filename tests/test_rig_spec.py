"""Tests of planner.rig_spec: the rig TOML (time costs, units, [limits]) and the rig's limits
applied to a drive (scaled, or clipped by the smooth local limiter).

(tests/test_virtual_rig.py tests the virtual rig, ident.sim.virtual_rig.)"""

import dataclasses
import logging

import numpy as np
import pytest
import tomli_w
from numpy.testing import assert_allclose, assert_array_equal

from ident.data.channels import AERO_INPUTS, RIG_INPUTS, WHEELLOADER_INPUTS
from ident.data.drive import Drive, make_noise_drive, make_track_drive
from ident.data.units import to_si
from planner.errors import PlannerError
from planner.rig_spec import (
    CLIP_WINDOW_S,
    LIMIT_KEYS,
    LIMIT_RTOL,
    LimitedDrive,
    RigLimits,
    RigSpec,
    apply_rig_limits,
    default_rig,
    drive_derivatives,
    read_rig,
)

#: Velocity and acceleration peaks after "clip" against their limits (and the original's
#: peaks): the limiter stops its passes once every derivative peak is within LIMIT_RTOL
#: (0.1 %) of its bound, because a gain's own slope adds x de/dt and the peaks approach the
#: limit geometrically, not in a finite number of passes. Displacement holds exactly.
RTOL_DERIVATIVE = LIMIT_RTOL
#: A drive's derivatives after "scale" against the original's times the factor: numpy's
#: gradient of x*s and s times the gradient of x differ by rounding only.
RTOL_SCALED = 1e-12
#: Sample rate of the synthetic drives [Hz] and a 2x over displacement limit [m].
FS_HZ = 200.0
LIMIT_M = 0.01

OLD_RIG = 'format = "rig/1"\nname = "8-post"\nswap_min = 4.5\nrun_overhead_min = 1.0\n'
SI_LIMITS = {"wheelloader_displacement": 0.025, "wheelloader_velocity": 1.0,
             "wheelloader_acceleration": 40.0, "aero_heave": 8000.0, "aero_roll": 1000.0,
             "aero_pitch": 3500.0}


def _rig_file(path, limits=None, units=None, head=OLD_RIG):
    text = head + (f'units = "{units}"\n' if units else "")
    if limits is not None:
        text += "[limits]\n" + tomli_w.dumps(limits)
    path.write_text(text)
    return path


def _wheel_drive(x, name="sine", fs_hz=FS_HZ):
    """A 4-post drive with every wheelloader playing `x`."""
    return Drive(name, fs_hz, dict.fromkeys(WHEELLOADER_INPUTS, x))


def _sine(f_hz, amplitude_m=2 * LIMIT_M, duration_s=10.0):
    t = np.arange(int(round(duration_s * FS_HZ))) / FS_HZ
    return amplitude_m * np.sin(2 * np.pi * f_hz * t)


# ---------------------------------------------------------------------------- the rig file

def test_read_rig(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text('format = "rig/1"\nname = "8-post"\nswap_min = 4.5\nrun_overhead_min = 1.0\n')
    rig = read_rig(path)
    assert (rig.name, rig.swap_min, rig.run_overhead_min) == ("8-post", 4.5, 1.0)
    assert default_rig().swap_min == 6.0
    assert rig.click_change_s == default_rig().click_change_s == 20.0  # left out: the default
    path.write_text('format = "rig/1"\nswap_min = 4.5\nclick_change_s = 15\n')
    assert read_rig(path).click_change_s == 15.0
    for text, match in (("swap_min = -2.0\n", "swap_min = -2.0 must be a number of minutes"),
                        ("swap = 3.0\n", "unknown key 'swap'"),
                        ('format = "rig/2"\n', "format"),
                        ("click_change_s = -5\n", r"rig\.toml: click_change_s = -5 must be a "
                                                  r"number of seconds >= 0.*click_change_s = 20"),
                        ('click_change_s = "20 s"\n', "click_change_s = '20 s' must be a number"),
                        ("click_change_s = nan\n", "click_change_s = nan must be"),
                        ("click_changes_s = 20\n", "unknown key 'click_changes_s'")):
        path.write_text(text)
        with pytest.raises(PlannerError, match=match):
            read_rig(path)


def test_an_old_rig_file_reads_exactly_as_before(tmp_path):
    """No [limits], no units: the same RigSpec as before issue 27, limits None."""
    path = _rig_file(tmp_path / "rig.toml")
    rig = read_rig(path)
    assert rig == RigSpec(name="8-post", swap_min=4.5, run_overhead_min=1.0, source=str(path),
                          click_change_s=20.0)
    assert rig.limits is None and default_rig().limits is None
    # units alone changes nothing: it converts limits only, never the times
    assert read_rig(_rig_file(tmp_path / "rig.toml", units="imperial")) == rig


def test_read_rig_limits_in_si(tmp_path):
    rig = read_rig(_rig_file(tmp_path / "rig.toml", SI_LIMITS))
    assert rig.limits == RigLimits(wheelloader_displacement_m=0.025, wheelloader_velocity_m_s=1.0,
                                   wheelloader_acceleration_m_s2=40.0, aero_heave_n=8000.0,
                                   aero_roll_n_m=1000.0, aero_pitch_n_m=3500.0)
    assert (rig.swap_min, rig.run_overhead_min) == (4.5, 1.0)
    assert rig.limits.for_channel("wheelloader_LR") == {
        "displacement": 0.025, "velocity": 1.0, "acceleration": 40.0}
    assert rig.limits.for_channel("aero_heave") == {"force": 8000.0}
    assert rig.limits.for_channel("aero_pitch") == {"moment": 3500.0}
    # every key optional; an empty table: no limits
    part = read_rig(_rig_file(tmp_path / "rig.toml", {"wheelloader_velocity": 2}))
    assert part.limits == RigLimits(wheelloader_velocity_m_s=2.0) and part.limits.any
    empty = read_rig(_rig_file(tmp_path / "rig.toml", {}))
    assert empty.limits == RigLimits() and not empty.limits.any


def test_imperial_limits_equal_si_ones_converted(tmp_path):
    """The same limits in inches, lbf and lbf*in read as the SI file of their conversion."""
    imperial = {"wheelloader_displacement": 1.0, "wheelloader_velocity": 40.0,
                "wheelloader_acceleration": 1500.0, "aero_heave": 2000.0, "aero_roll": 9000.0,
                "aero_pitch": 30000.0}
    si = {k: float(to_si(v, LIMIT_KEYS[k][1], "imperial")) for k, v in imperial.items()}
    got = read_rig(_rig_file(tmp_path / "imp.toml", imperial, units="imperial")).limits
    assert got == read_rig(_rig_file(tmp_path / "si.toml", si, units="SI")).limits
    assert got.wheelloader_displacement_m == pytest.approx(0.0254, rel=1e-15)
    assert got.aero_heave_n == pytest.approx(2000.0 * 4.4482216152605, rel=1e-15)
    assert read_rig(_rig_file(tmp_path / "any.toml", imperial, units="Imperial")).limits == got


@pytest.mark.parametrize("limits, units, match", [
    ({"wheelloader_velocty": 1.0}, None,
     r"rig\.toml: unknown key 'wheelloader_velocty' in \[limits\] \(did you mean "
     r"'wheelloader_velocity'\?\).*fix its spelling or remove it"),
    ({"max_speed": 1.0}, None, r"rig\.toml: unknown key 'max_speed' in \[limits\]; \[limits\] "
                               r"has \['wheelloader_displacement'"),
    ({"wheelloader_displacement": 0.0}, None,
     r"rig\.toml: \[limits\] wheelloader_displacement = 0\.0 must be a positive number \[m\]"),
    ({"wheelloader_velocity": -1.0}, "imperial",
     r"\[limits\] wheelloader_velocity = -1\.0 must be a positive number \[in/s\] "
     r"\(units = \"imperial\"\).*remove the key for no limit"),
    ({"aero_roll": "900 lbf*in"}, "imperial", r"aero_roll = '900 lbf\*in' must be a positive "
                                              r"number \[lbf\*in\]"),
    ({"aero_heave": True}, None, r"aero_heave = True must be a positive number \[N\]"),
    ({"wheelloader_acceleration": float("inf")}, None,
     r"wheelloader_acceleration = inf must be a positive number"),
    ({"aero_pitch": float("nan")}, None, r"aero_pitch = nan must be a positive number"),
    ({}, "metric", r"rig\.toml: 'units': unknown unit system 'metric'; use \"SI\" or "
                   r"\"imperial\""),
])
def test_read_rig_refuses(tmp_path, limits, units, match):
    path = _rig_file(tmp_path / "rig.toml", limits, units=units)
    with pytest.raises(PlannerError, match=match):
        read_rig(path)


@pytest.mark.parametrize("text, match", [
    ("limits = 3\n", r"rig\.toml: 'limits' must be a table, got int; write it as \[limits\]"),
    ("units = 1\n", r"rig\.toml: 'units': unknown unit system 1"),
    ("limit = 3\n", r"rig\.toml: unknown key 'limit' \(did you mean 'limits'\?\); a rig file "
                    r"has \[.*'limits'"),
])
def test_read_rig_refuses_top_level(tmp_path, text, match):
    path = tmp_path / "rig.toml"
    path.write_text(OLD_RIG + text)
    with pytest.raises(PlannerError, match=match):
        read_rig(path)


@pytest.mark.parametrize("kwargs", [{"wheelloader_velocity_m_s": -1.0},
                                    {"aero_heave_n": 0}, {"aero_roll_n_m": "5"},
                                    {"wheelloader_displacement_m": float("nan")}])
def test_rig_limits_refuse_non_positive_values(kwargs):
    with pytest.raises(PlannerError, match=f"RigLimits: {next(iter(kwargs))} = .* must be a "
                                           "positive number in SI or None"):
        RigLimits(**kwargs)


# ---------------------------------------------------------------------------- limits on a drive

def test_derivatives_are_numpy_gradients():
    """Known answer: a sine's velocity and acceleration peaks as central differences read
    them, A sin(w dt)/dt and A (sin(w dt)/dt)^2."""
    x = _sine(2.0, amplitude_m=0.01)
    v, a = drive_derivatives(x, FS_HZ)
    wdt = 2 * np.pi * 2.0 / FS_HZ
    assert_allclose(np.max(np.abs(v[5:-5])), 0.01 * np.sin(wdt) * FS_HZ, rtol=1e-6)
    assert_allclose(np.max(np.abs(a[5:-5])), 0.01 * (np.sin(wdt) * FS_HZ) ** 2, rtol=1e-6)


def test_no_limits_or_none_exceeded_returns_the_same_drive(caplog):
    drive = _wheel_drive(_sine(1.0))
    with caplog.at_level(logging.WARNING, logger="planner.rig_spec"):
        for limits in (None, RigLimits(), RigLimits(wheelloader_displacement_m=0.05),
                       RigLimits(aero_heave_n=1.0)):  # a 4-post drive: no aero to limit
            for action in ("clip", "scale"):
                out = apply_rig_limits(drive, limits, action=action)
                assert isinstance(out, LimitedDrive) and out.drive is drive
                assert out.report.empty and out.warnings == [] and out.scale == 1.0
                assert list(out.report.columns)[:4] == ["channel", "quantity", "unit", "limit"]
    assert not caplog.records


def test_scale_halves_a_sine_twice_over_the_limit(caplog):
    """Known answer: a sine whose peak is 2x the limit is scaled by 1/2, every wheelloader
    alike (their relative content kept), a warning per exceeded channel."""
    x = _sine(1.0)
    drive = Drive("sine", FS_HZ, {"wheelloader_LF": x, "wheelloader_RF": 0.5 * x,
                                  "wheelloader_LR": -0.25 * x, "wheelloader_RR": 0.0 * x})
    with caplog.at_level(logging.WARNING, logger="planner.rig_spec"):
        out = apply_rig_limits(drive, RigLimits(wheelloader_displacement_m=LIMIT_M),
                               action="scale")
    assert out.scale == 0.5 and out.aero_scale == 1.0 and out.action == "scale"
    for c in WHEELLOADER_INPUTS:
        assert_array_equal(out.drive.channels[c], 0.5 * drive.channels[c])
    assert np.max(np.abs(out.drive.channels["wheelloader_LF"])) == LIMIT_M
    r = out.report.set_index("channel")
    assert list(r.index) == list(WHEELLOADER_INPUTS)
    assert r.loc["wheelloader_LF", "exceeded"] and not r.loc["wheelloader_RF", "exceeded"]
    assert r.loc["wheelloader_LF", "peak_before"] == 2 * LIMIT_M
    assert r.loc["wheelloader_LF", "peak_after"] == LIMIT_M
    assert (r["scale"] == 0.5).all()
    assert len(out.warnings) == 1 and [m.getMessage() for m in caplog.records] == out.warnings
    assert ("'sine': wheelloader_LF displacement peaks at 0.02 m, 2x the rig's limit 0.01 m; "
            "the wheelloaders scaled by 0.5") in out.warnings[0]
    settings = out.drive.settings["rig_limits"]
    assert settings["action"] == "scale" and settings["scale"] == 0.5
    assert settings["limits"] == {"wheelloader_displacement_m": LIMIT_M}


def test_scale_takes_the_tightest_quantity_and_keeps_aero_apart():
    """One wheelloader factor, the smallest limit/peak over channels and quantities (here the
    velocity's); the aero inputs their own factor from their force and moment limits."""
    drive = make_track_drive(duration_s=20.0, fs_hz=FS_HZ, seed=4,
                             aero={"aero_heave": 400.0, "aero_pitch": 250.0})
    peaks = {c: np.max(np.abs(drive_derivatives(drive.channels[c], FS_HZ)[0]))
             for c in WHEELLOADER_INPUTS}
    v_limit = 0.5 * max(peaks.values())
    heave_peak = np.max(np.abs(drive.channels["aero_heave"]))
    limits = RigLimits(wheelloader_displacement_m=1.0, wheelloader_velocity_m_s=v_limit,
                       aero_heave_n=0.8 * heave_peak, aero_pitch_n_m=1e6)
    out = apply_rig_limits(drive, limits, action="scale")
    assert out.scale == pytest.approx(0.5, rel=1e-12)
    assert out.aero_scale == pytest.approx(0.8, rel=1e-12)
    for c in WHEELLOADER_INPUTS:
        assert_allclose(drive_derivatives(out.drive.channels[c], FS_HZ)[0],
                        out.scale * drive_derivatives(drive.channels[c], FS_HZ)[0],
                        rtol=RTOL_SCALED, atol=1e-15)
    for c in AERO_INPUTS:
        assert_array_equal(out.drive.channels[c], out.aero_scale * drive.channels[c])
    assert out.drive.rig_inputs == RIG_INPUTS and out.drive.fs_hz == FS_HZ
    r = out.report
    assert set(r.loc[r["exceeded"], "quantity"]) == {"velocity", "force"}
    roll = r[r["channel"] == "aero_roll"].iloc[0]  # scaled with its group, no limit of its own
    assert np.isnan(roll["limit"]) and roll["quantity"] == "moment"


def test_clip_holds_the_peak_at_the_limit():
    """Known answer: a sine twice over the limit, clipped: its peak is the limit exactly
    (the gain at a peak is limit/peak, not less), for slow and fast sines."""
    for f_hz in (0.5, 1.0, 2.0, 8.0):
        drive = _wheel_drive(_sine(f_hz))
        out = apply_rig_limits(drive, RigLimits(wheelloader_displacement_m=LIMIT_M))
        y = out.drive.channels["wheelloader_LF"]
        assert np.max(np.abs(y)) <= LIMIT_M
        assert_allclose(np.max(np.abs(y)), LIMIT_M, rtol=1e-12)
        assert out.scale == 1.0 and out.action == "clip"
        assert out.report["peak_after"].max() <= LIMIT_M


def test_clip_leaves_samples_away_from_the_peaks_unchanged():
    """A sine burst twice over the limit in the middle of a small sine: every sample farther
    than one window from a sample over the limit is bit for bit the original; those near the
    burst change; the share changed is reported."""
    t = np.arange(int(20 * FS_HZ)) / FS_HZ
    x = (0.005 + 0.015 * np.exp(-((t - 10.0) / 0.5) ** 2)) * np.sin(2 * np.pi * 2.0 * t)
    drive = _wheel_drive(x, name="burst")
    out = apply_rig_limits(drive, RigLimits(wheelloader_displacement_m=LIMIT_M))
    y = out.drive.channels["wheelloader_LF"]
    window_s = out.drive.settings["rig_limits"]["window_s"]["wheelloader_LF"]
    assert window_s == pytest.approx(CLIP_WINDOW_S, abs=1.5 / FS_HZ)  # no longer one needed
    over = np.flatnonzero(np.abs(x) > LIMIT_M)
    near = (t >= t[over[0]] - window_s) & (t <= t[over[-1]] + window_s)
    assert_array_equal(y[~near], x[~near])
    assert (y[over] != x[over]).all() and np.max(np.abs(y)) == pytest.approx(LIMIT_M)
    share = np.mean(y != x)
    assert 0.03 < share < 0.07
    assert out.report["share_changed"].tolist() == [share] * 4
    assert "5.2% of the channel's samples changed" in out.warnings[0]
    assert "clipped smoothly" in out.warnings[0]


def test_clip_makes_no_spike_where_a_hard_clip_does():
    """The clipped drive's peak |velocity| and |acceleration| never exceed the original's
    (within RTOL_DERIVATIVE); a hard clip at the same limit makes an acceleration spike (so
    the check can fail)."""
    cases = [_sine(f) for f in (0.3, 1.0, 3.0, 10.0)]
    cases.append(make_noise_drive(duration_s=20.0, fs_hz=FS_HZ, seed=2,
                                  peak={"wheelloader_LF": 2 * LIMIT_M}).channels["wheelloader_LF"])
    for x in cases:
        out = apply_rig_limits(_wheel_drive(x), RigLimits(wheelloader_displacement_m=LIMIT_M))
        v0, a0 = drive_derivatives(x, FS_HZ)
        v, a = drive_derivatives(out.drive.channels["wheelloader_LF"], FS_HZ)
        assert np.max(np.abs(v)) <= np.max(np.abs(v0)) * (1 + RTOL_DERIVATIVE)
        assert np.max(np.abs(a)) <= np.max(np.abs(a0)) * (1 + RTOL_DERIVATIVE)
    hard = np.clip(_sine(1.0), -LIMIT_M, LIMIT_M)
    assert np.max(np.abs(drive_derivatives(hard, FS_HZ)[1])) > \
        2 * np.max(np.abs(drive_derivatives(_sine(1.0), FS_HZ)[1]))


@pytest.mark.parametrize("quantities", [("velocity",), ("acceleration",),
                                        ("displacement", "velocity", "acceleration")])
def test_clip_holds_velocity_and_acceleration_limits(quantities):
    """A track drive limited to 70 % of its own peaks: after clip every limit holds (velocity
    and acceleration within RTOL_DERIVATIVE, displacement exactly), a warning per channel and
    quantity exceeded, and only part of the drive changed."""
    drive = make_track_drive(duration_s=30.0, fs_hz=FS_HZ, seed=3)
    peak = {}
    for c in WHEELLOADER_INPUTS:
        x = drive.channels[c]
        for q, s in zip(("displacement", "velocity", "acceleration"),
                        (x, *drive_derivatives(x, FS_HZ))):
            peak[q] = max(peak.get(q, 0.0), float(np.max(np.abs(s))))
    fields = {"displacement": "wheelloader_displacement_m", "velocity": "wheelloader_velocity_m_s",
              "acceleration": "wheelloader_acceleration_m_s2"}
    limits = RigLimits(**{fields[q]: 0.7 * peak[q] for q in quantities})
    out = apply_rig_limits(drive, limits, action="clip")
    for c in WHEELLOADER_INPUTS:
        y = out.drive.channels[c]
        got = dict(zip(("displacement", "velocity", "acceleration"),
                       (np.max(np.abs(s)) for s in (y, *drive_derivatives(y, FS_HZ)))))
        for q in quantities:
            rtol = 0.0 if q == "displacement" else RTOL_DERIVATIVE
            assert got[q] <= 0.7 * peak[q] * (1 + rtol), (c, q)
    assert out.drive.rig_inputs == drive.rig_inputs and out.drive.name == drive.name
    assert out.drive.settings["kind"] == drive.settings["kind"]  # the original's, extended
    assert 0.0 < out.report["share_changed"].max() < 0.5
    exceeded = out.report[out.report["exceeded"]]
    assert len(out.warnings) == len(exceeded) > 0
    assert all(f"{r.channel} {r.quantity} peaks at" in w
               for r, w in zip(exceeded.itertuples(), out.warnings))


def test_clip_of_a_ramp_ends_as_one_gain():
    """A ramp has no acceleration: any local dip of the gain would make one, so the limiter's
    window grows to the record and the channel is scaled as a whole."""
    x = np.linspace(0.0, 2 * LIMIT_M, 200)
    out = apply_rig_limits(_wheel_drive(x, name="ramp"),
                           RigLimits(wheelloader_displacement_m=LIMIT_M))
    y = out.drive.channels["wheelloader_LF"]
    assert_allclose(y, 0.5 * x, rtol=1e-15, atol=0)
    assert np.max(np.abs(y)) <= LIMIT_M
    assert out.drive.settings["rig_limits"]["window_s"]["wheelloader_LF"] == 200 / FS_HZ


def test_clip_of_an_aero_force_and_a_four_post_drive():
    """An aero force over its limit is clipped on its own; the wheelloaders stay; a 4-post
    drive stays 4-post."""
    drive = make_track_drive(duration_s=20.0, fs_hz=FS_HZ, seed=5, aero={"aero_heave": 400.0})
    limit = 0.6 * np.max(np.abs(drive.channels["aero_heave"]))
    out = apply_rig_limits(drive, RigLimits(aero_heave_n=limit))
    assert np.max(np.abs(out.drive.channels["aero_heave"])) <= limit
    for c in (*WHEELLOADER_INPUTS, "aero_roll", "aero_pitch"):
        assert_array_equal(out.drive.channels[c], drive.channels[c])
    assert out.report["channel"].tolist() == ["aero_heave"]
    assert out.report["unit"].tolist() == ["N"]
    four = _wheel_drive(_sine(1.0))
    out4 = apply_rig_limits(four, RigLimits(wheelloader_displacement_m=LIMIT_M, aero_heave_n=1.0))
    assert out4.drive.rig_inputs == WHEELLOADER_INPUTS


def test_apply_rig_limits_refuses_bad_arguments():
    drive = _wheel_drive(_sine(1.0))
    with pytest.raises(TypeError, match="drive must be an ident.data.drive.Drive, got ndarray"):
        apply_rig_limits(_sine(1.0), RigLimits())
    with pytest.raises(TypeError, match="limits must be RigLimits or None, got RigSpec"):
        apply_rig_limits(drive, RigSpec())
    with pytest.raises(PlannerError, match=r"action 'scaled' is not one of \['clip', 'scale'\] "
                                           r"\(did you mean 'scale'\?\)"):
        apply_rig_limits(drive, RigLimits(), action="scaled")


def test_limited_drive_is_frozen():
    out = apply_rig_limits(_wheel_drive(_sine(1.0)), None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        out.scale = 2.0


def test_limit_refusal_gives_an_example_in_the_files_units(tmp_path):
    """The example value is a typical limit in the file's own units (1 in, not 0.025)."""
    path = tmp_path / "rig.toml"
    path.write_text('units = "imperial"\n[limits]\nwheelloader_displacement = -1\n')
    with pytest.raises(PlannerError, match=r"\[in\].*write e.g. wheelloader_displacement = "
                                           r"0\.98,"):
        read_rig(path)
    path.write_text('[limits]\nwheelloader_displacement = -1\n')
    with pytest.raises(PlannerError, match=r"write e.g. wheelloader_displacement = 0\.025,"):
        read_rig(path)
