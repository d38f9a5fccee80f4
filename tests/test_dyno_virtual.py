"""The virtual shock dyno (ident.dyno.virtual): known answers of its program, lag and noise."""

import math

import numpy as np
import pytest

from ident.models.shocks import LinearShock, TableShock
from ident.dyno.virtual import simulate_dyno_run

#: The program's velocity from the sampled displacement: central differences at 2 kHz of a
#: sine of period >= 0.2 s are exact to (omega dt)^2 / 6 < 1e-4.
RTOL_PEAK = 1e-3
#: A first-order lag's steady state: after 4 of 6 cycles (> 100 time constants) the
#: transient is gone; the first-order hold is exact for the linear segments of a sine
#: sampled 200 times a cycle to (omega dt)^2 ~ 1e-3.
RTOL_LAG = 2e-3


def test_program_known_answer():
    curve = TableShock("T", [-0.5, 0.0, 0.1, 0.5], [-1500.0, 0.0, 500.0, 900.0])
    run = simulate_dyno_run(curve, peak_velocities_m_s=[0.1, 0.3], stroke_m=0.04,
                            cycles_per_speed=2, fs_hz=2000.0, gas_force_n=120.0,
                            temperature_c=(30.0, 34.0))
    t, x, f = run["time"].to_numpy(), run["displacement"].to_numpy(), run["force"].to_numpy()
    amp = 0.02
    assert list(run.columns) == ["time", "force", "displacement", "temperature"]
    # whole cycles: 2 * 2 pi A / v per block; starts and ends at full extension, at rest
    assert t[-1] == pytest.approx(2 * 2 * math.pi * amp * (1 / 0.1 + 1 / 0.3), abs=1 / 2000)
    assert x[0] == pytest.approx(-amp) and x[-1] == pytest.approx(-amp, rel=1e-4)
    np.testing.assert_allclose([x.min(), x.max()], [-amp, amp], rtol=1e-6)
    v = np.gradient(x, t)
    first = t < t[-1] * 0.5
    np.testing.assert_allclose(v[first].max(), 0.1, rtol=RTOL_PEAK)
    np.testing.assert_allclose(v.max(), 0.3, rtol=RTOL_PEAK)
    # no lag, no noise: the load cell reads the curve plus the gas force
    np.testing.assert_allclose(f[1:-1], curve.force(v[1:-1]) + 120.0, atol=1.0)
    np.testing.assert_allclose(run["temperature"].to_numpy()[[0, -1]], [30.0, 34.0])


def test_lag_known_answer():
    """A linear shock c with lag tau driven at omega: amplitude c v / sqrt(1 + (tau omega)^2)."""
    c, lag, vp, amp = 2000.0, 0.01, 0.4, 0.02
    run = simulate_dyno_run(LinearShock("L", c), peak_velocities_m_s=[vp], stroke_m=2 * amp,
                            cycles_per_speed=6, fs_hz=2000.0, lag_s=lag)
    omega = vp / amp
    f = run["force"].to_numpy()
    late = run["time"].to_numpy() > 4 * 2 * math.pi / omega
    np.testing.assert_allclose(f[late].max(), c * vp / math.sqrt(1 + (lag * omega) ** 2),
                               rtol=RTOL_LAG)


def test_noise_is_seeded_and_sized():
    curve = LinearShock("L", 1000.0)
    kw = dict(peak_velocities_m_s=[0.2], cycles_per_speed=2, noise_force_n=5.0,
              noise_disp_m=1e-5)
    a = simulate_dyno_run(curve, rng=np.random.default_rng(3), **kw)
    b = simulate_dyno_run(curve, rng=np.random.default_rng(3), **kw)
    clean = simulate_dyno_run(curve, **{**kw, "noise_force_n": 0.0, "noise_disp_m": 0.0})
    assert a.equals(b)
    # 5 N white noise over ~3000 samples: the sample std within 5 %
    assert np.std(a["force"] - clean["force"]) == pytest.approx(5.0, rel=0.05)


@pytest.mark.parametrize("kw, match", [
    ({"peak_velocities_m_s": []}, "peak_velocities_m_s"),
    ({"peak_velocities_m_s": [0.1, -0.2]}, "peak_velocities_m_s"),
    ({"peak_velocities_m_s": [0.1], "cycles_per_speed": 0}, "cycles_per_speed"),
    ({"peak_velocities_m_s": [0.1], "lag_s": -1.0}, "lag_s"),
    ({"peak_velocities_m_s": [0.1], "stroke_m": 0.0}, "stroke_m"),
    ({"peak_velocities_m_s": [0.1], "temperature_c": [1, 2, 3]}, "temperature_c"),
])
def test_bad_program_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        simulate_dyno_run(LinearShock("L", 1000.0), **kw)
