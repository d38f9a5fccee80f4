"""A virtual shock dyno: a known shock driven by a sinusoidal stroke program.

The truth of the raw-dyno import (:mod:`ident.dyno.raw`): a shock whose curve is
known (any object with ``.force(v)`` in SI, e.g. a
:class:`~ident.models.shocks.TableShock`) is driven, as a crank or hydraulic dyno does,
by a sinusoidal displacement of constant stroke, in blocks of whole cycles at increasing
peak velocity. Each block runs at the frequency that gives its peak velocity,
``omega = v_peak / amplitude``; blocks change at full extension (displacement minimum,
velocity zero), so displacement and velocity are continuous through the program.

The force the load cell reads is::

    lag * dF/dt + F = f(v)          (the library's lag, exact for a linear-in-time f(v)
    force = F + gas + noise          between samples: a first-order-hold discretization)

with a constant gas force (the gas spring of a pressurized damper, compression
positive) and white noise on force and displacement. Signs are the spec's: displacement
(shock travel) and velocity positive in compression; force positive in compression.

Examples
--------
>>> from ident.models.shocks import LinearShock
>>> run = simulate_dyno_run(LinearShock("L", 2000.0), peak_velocities_m_s=[0.1, 0.2],
...                         cycles_per_speed=2, fs_hz=500.0)
>>> list(run.columns), round(float(run["force"].max()), 1)
(['time', 'force', 'displacement'], 400.0)
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pandas as pd
from scipy.signal import lfilter

__all__ = ["simulate_dyno_run", "DEFAULT_STROKE_M", "DEFAULT_CYCLES_PER_SPEED",
           "DEFAULT_FS_HZ"]

logger = logging.getLogger(__name__)

#: Peak-to-peak stroke [m] of the default program: 50 mm, a common dyno stroke for
#: race dampers (25-50 mm).
DEFAULT_STROKE_M = 0.05
#: Cycles per peak velocity: dyno software typically averages 3-5 cycles per speed.
DEFAULT_CYCLES_PER_SPEED = 4
#: Sample rate [Hz]: dyno controllers log at 0.5-5 kHz.
DEFAULT_FS_HZ = 1000.0


def _positive(name, value):
    value = float(value)
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"simulate_dyno_run: {name} = {value!r} must be a finite number > 0")
    return value


def _non_negative(name, value):
    value = float(value)
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"simulate_dyno_run: {name} = {value!r} must be a finite number >= 0")
    return value


def _lagged(u, lag_s, dt):
    """``lag * dF/dt + F = u`` with u linear between samples, F(0) = u(0) (at rest)."""
    if lag_s == 0.0:
        return u.copy()
    a = math.exp(-dt / lag_s)
    b0 = 1.0 - lag_s / dt * (1.0 - a)
    b1 = (1.0 - a) - b0
    # steady state at the first sample: F = u = u0 before the start
    zi = np.array([(1.0 - b0) * u[0]])  # direct form II transposed: y0 = b0 u0 + zi
    y, _ = lfilter([b0, b1], [1.0, -a], u, zi=zi)
    return y


def simulate_dyno_run(curve, *, peak_velocities_m_s, stroke_m=DEFAULT_STROKE_M,
                      cycles_per_speed=DEFAULT_CYCLES_PER_SPEED, fs_hz=DEFAULT_FS_HZ,
                      lag_s=0.0, gas_force_n=0.0, noise_force_n=0.0, noise_disp_m=0.0,
                      temperature_c=None, rng=None):
    """Simulate one dyno run: time, force and displacement (and temperature) samples.

    Parameters
    ----------
    curve : object with ``force(v_m_s)``
        The shock's static curve ``f(v)`` [N] of velocity [m/s], compression positive
        (a :class:`~ident.models.shocks.ShockModel`; its own ``lag_s`` is not used:
        give `lag_s`).
    peak_velocities_m_s : sequence of float, shape (n_speeds,)
        Peak velocity [m/s] of each block, in program order (each > 0).
    stroke_m : float
        Peak-to-peak stroke [m] of every block (amplitude ``stroke_m / 2``).
    cycles_per_speed : int
        Whole cycles per block (>= 1).
    fs_hz : float
        Sample rate [Hz].
    lag_s : float
        First-order lag [s] between ``f(v)`` and the force: ``lag * dF/dt + F = f(v)``.
    gas_force_n : float
        Constant gas force [N] added to the force (compression positive).
    noise_force_n, noise_disp_m : float
        Standard deviation of white noise added to force [N] and displacement [m].
    temperature_c : float or (float, float), optional
        Oil temperature [deg C]: constant, or (start, end) of a linear drift over the
        run (a damper warming up). Without it there is no temperature column.
    rng : numpy.random.Generator, optional
        Noise source (default: ``numpy.random.default_rng()``).

    Returns
    -------
    pandas.DataFrame, shape (n_samples, 3 or 4)
        Columns ``time`` [s] (from 0, uniform), ``force`` [N], ``displacement`` [m]
        (shock travel about mid-stroke, compression positive) and ``temperature``
        [deg C] where given. The run starts and ends at full extension, at rest.

    Raises
    ------
    ValueError
        If a peak velocity, the stroke, the rate or the cycles are not positive, or a
        lag, gas force... is not finite (noise and lag must be >= 0).

    Notes
    -----
    Displacement ``x = -A cos(phi)``, ``A = stroke / 2``, with ``dphi/dt = omega_k =
    v_peak_k / A`` in block ``k``; each block is a whole number of cycles, so it ends at
    ``phi = 2 pi n`` (full extension, ``v = 0``) where the next one starts. The block of
    ``v_peak`` lasts ``cycles * 2 pi A / v_peak``: 50 mm stroke at 0.025 m/s is 6.3 s a
    cycle.
    """
    v_peak = np.atleast_1d(np.asarray(peak_velocities_m_s, dtype=float))
    if v_peak.ndim != 1 or v_peak.size == 0 or not np.all(np.isfinite(v_peak)) \
            or np.any(v_peak <= 0):
        raise ValueError(f"simulate_dyno_run: peak_velocities_m_s = {v_peak.tolist()} must be "
                         "one or more finite velocities > 0 [m/s]")
    amp = _positive("stroke_m", stroke_m) / 2.0
    fs = _positive("fs_hz", fs_hz)
    if int(cycles_per_speed) != cycles_per_speed or cycles_per_speed < 1:
        raise ValueError(f"simulate_dyno_run: cycles_per_speed = {cycles_per_speed!r} must be "
                         "an integer >= 1")
    lag = _non_negative("lag_s", lag_s)
    noise_f = _non_negative("noise_force_n", noise_force_n)
    noise_x = _non_negative("noise_disp_m", noise_disp_m)
    gas = float(gas_force_n)
    if not math.isfinite(gas):
        raise ValueError(f"simulate_dyno_run: gas_force_n = {gas_force_n!r} must be finite")
    rng = np.random.default_rng() if rng is None else rng

    omega = v_peak / amp  # rad/s per block
    block_s = int(cycles_per_speed) * 2.0 * np.pi / omega
    edges = np.concatenate([[0.0], np.cumsum(block_s)])
    n = int(math.floor(edges[-1] * fs)) + 1
    t = np.arange(n) / fs
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, v_peak.size - 1)
    phase = 2.0 * np.pi * int(cycles_per_speed) * k + omega[k] * (t - edges[k])
    x = -amp * np.cos(phase)
    v = amp * omega[k] * np.sin(phase)
    f = _lagged(np.asarray(curve.force(v), dtype=float), lag, 1.0 / fs)
    force = f + gas + (noise_f * rng.standard_normal(n) if noise_f else 0.0)
    disp = x + (noise_x * rng.standard_normal(n) if noise_x else 0.0)
    data = {"time": t, "force": force, "displacement": disp}
    if temperature_c is not None:
        temp = np.atleast_1d(np.asarray(temperature_c, dtype=float))
        if temp.size not in (1, 2) or not np.all(np.isfinite(temp)):
            raise ValueError(f"simulate_dyno_run: temperature_c = {temperature_c!r} must be a "
                             "temperature [deg C] or a (start, end) pair")
        data["temperature"] = np.full(n, temp[0]) if temp.size == 1 else \
            np.linspace(temp[0], temp[1], n)
    logger.debug("virtual dyno: %d blocks, %.1f s, %d samples", v_peak.size, t[-1], n)
    return pd.DataFrame(data)
