"""Tests of ident.identify.thirdforce: the third elements' force at the corners, measured or
from their curves and springs (known answers), and the refusal of a heave spring whose
travel the run cannot give."""

import numpy as np
import pytest

from ident.data.channels import CORNERS
from ident.data.session import Run
from ident.data.third import RunThird, ThirdElements, element_row
from ident.errors import IdentificationError
from ident.identify.diagnose import rest_levels
from ident.identify.thirdforce import third_element_force
from ident.models.bumpstops import BumpStop, BumpStopLibrary
from ident.models.library import ShockLibrary
from ident.models.shocks import LinearShock

FS_HZ = 100.0
N = 2000
#: A linear damper's force from its curve on the refined grid against ``c v`` on the
#: samples, away from the record's ends: the band-limited interpolation and decimation pass
#: a 1-3 Hz velocity nearly unchanged (measured 4.4e-5 of the force's peak).
RTOL_REFINED = 1e-4
ELEMENTS = ThirdElements({"heave_front": 1.2, "roll_front": 0.8})
SPRING = BumpStop("HS", 0.003, [0.0, 0.01], [0.0, 3000.0])


def _run(*, third, drop=(), extra=None):
    """A run with smooth corner motion (1-3 Hz, faded in from rest): shock velocity and
    travel at every corner, no rig input."""
    t = np.arange(N) / FS_HZ
    fade = np.clip((t - 0.5) / 2.0, 0.0, 1.0)  # at rest for 0.5 s
    ch = {}
    for i, c in enumerate(CORNERS):
        w = 2 * np.pi * (1.0 + 0.5 * i)
        x = 0.008 * fade * np.sin(w * t + i)
        ch[f"shock_travel_{c}"] = x
        ch[f"shock_velocity_{c}"] = np.gradient(x, 1 / FS_HZ)
    ch.update(extra or {})
    for k in drop:
        del ch[k]
    return Run(name="r1", file="runs/r1.csv", setup=dict.fromkeys(CORNERS, "B"),
               time_s=t, channels=ch, fs_hz=FS_HZ, third=third)


SHOCKS = ShockLibrary.from_models([LinearShock("B", 3000.0), LinearShock("H", 5000.0),
                                   LinearShock("R", 1500.0)])
STOPS = BumpStopLibrary([SPRING])


def _force(run):
    return third_element_force(run, ELEMENTS, SHOCKS, STOPS, levels=rest_levels(run)[0])


def test_dampers_from_their_curves_at_the_corners_motion():
    """No element channel: a linear heave and roll damper push ``c (m @ v)`` through their
    rows (about the velocity's mean: a velocity channel's offset is no motion)."""
    run = _run(third=RunThird(dampers={"heave_front": "H", "roll_front": "R"}))
    G, info = _force(run)
    assert info == {"heave_front": "curve", "roll_front": "curve"}
    v = np.vstack([run.dynamic(f"shock_velocity_{c}") for c in CORNERS])
    want = np.zeros_like(G)
    for e, c in (("heave_front", 5000.0), ("roll_front", 1500.0)):
        m = ELEMENTS.row(e)
        want += m[:, None] * (c * (m @ v))[None, :]
    inner = slice(100, N - 100)
    scale = np.abs(want).max()
    assert np.max(np.abs(G[:, inner] - want[:, inner])) < RTOL_REFINED * scale
    assert np.all(G[2:] == 0.0)  # the rear corners: nothing of the front elements


def test_measured_channels_are_used_and_unfitted_dampers_exert_nothing():
    rng = np.random.default_rng(38)
    load = rng.standard_normal(N)
    noise = rng.standard_normal(N)  # an unfitted damper's load cell: noise only
    run = _run(third=RunThird(dampers={"heave_front": "H"}),
               extra={"heave_force_front": load, "roll_force_front": noise})
    G, info = _force(run)
    assert info == {"heave_front": "measured"}
    np.testing.assert_array_equal(G, element_row("heave_front", 1.2)[:, None] * load)
    G, info = _force(_run(third=RunThird(), extra={"roll_force_front": noise}))
    assert G is None and info is None


@pytest.mark.parametrize("source", ["corners", "heave_travel", "heave_spring_force"])
def test_heave_spring_from_its_travel_from_rest_beyond_gap_less_packer(source):
    """The heave spring's table at the element's travel from rest (its channel, else ``m @
    x`` of the corners' travel) beyond ``gap - packer``; or its force channel as it is."""
    third = RunThird(heave_springs={"front": "HS"}, heave_packers_m={"front": 0.001})
    row = ELEMENTS.row("heave_front")
    base = _run(third=third)
    x = sum(m * base.channels[f"shock_travel_{c}"] for c, m in zip(CORNERS, row))
    offset = 0.05  # the channel's zero is not the car at rest: the rest is taken from the data
    extra = {"corners": {}, "heave_travel": {"heave_travel_front": x + offset},
             "heave_spring_force": {"heave_spring_force_front": 7.0 + x}}[source]
    G, info = _force(_run(third=third, extra=extra))
    if source == "heave_spring_force":
        assert info == {"heave_spring_front": "measured"}
        np.testing.assert_array_equal(G, row[:, None] * (7.0 + x))
        return
    assert info == {"heave_spring_front": "curve"}
    want = np.where(x > 0.002, 3000.0 / 0.01 * (x - 0.002), 0.0)
    assert (x > 0.002).mean() > 0.05  # the spring closes at times
    np.testing.assert_allclose(G, row[:, None] * want, rtol=1e-12, atol=1e-9)


def test_heave_spring_without_travel_refused():
    third = RunThird(heave_springs={"front": "HS"})
    run = _run(third=third, drop=("shock_travel_LF",))
    with pytest.raises(IdentificationError, match=(
            r"run 'r1' \(runs/r1.csv\): heave_springs front = 'HS' but the run records "
            r"neither heave_spring_force_front nor heave_travel_front nor shock_travel_LF and "
            r"shock_travel_RF; .* record one of them, or remove the run's heave_springs "
            r"front")):
        _force(run)
