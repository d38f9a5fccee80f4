"""Velocity knots fitted to the car: quantiles of the shock velocities the drives produce.

The optimizer's curves are piecewise linear between velocity knots. Fixed knots
(:data:`planner.optimize.space.DEFAULT_KNOTS_M_S`, 0.025 to 0.5 m/s) put most of
them where a car rarely goes: on the GT-like car of issue 24 the baseline's
shock velocities have q99.9 of 0.21-0.25 m/s, 35-43 % of the samples lie below
the first knot and the two outer knots are held only by the force cap (a flat
landscape there). :func:`velocity_knots` places the knots on quantiles of the
baseline's pooled shock speeds ``|v|`` (all corners, all drives), so each
segment carries a share of the samples: on that car (0.015, 0.033, 0.061,
0.096, 0.172) m/s.

>>> spread_knots([0.001, 0.0101, 0.0102, 0.2])
[0.005, 0.0101, 0.0151, 0.2]
"""

from __future__ import annotations

import numpy as np

from ident.data.channels import CORNERS
from ident.sim.closedloop import simulate

__all__ = [
    "KNOT_QUANTILES",
    "MIN_KNOT_M_S",
    "MIN_KNOT_GAP_M_S",
    "QUANTILE_KNOTS",
    "RANGE_QUANTILE",
    "shock_speeds",
    "spread_knots",
    "velocity_knots",
    "velocity_range",
]

#: The value of ``knots_m_s`` that asks :func:`planner.optimize.optimize_curves` for knots
#: on the quantiles of the baseline's shock speeds.
QUANTILE_KNOTS = "quantiles"
#: Quantiles of the pooled shock speeds the knots sit on: a quarter of the samples on each
#: of the first segments, the last knot at q99 (beyond it one extension).
KNOT_QUANTILES = (0.25, 0.5, 0.75, 0.9, 0.99)
#: The lowest knot [m/s] and the least gap between knots [m/s]: 5 mm/s is about the
#: resolution of a shock dyno's low-speed sweep, a segment narrower than that is not built.
MIN_KNOT_M_S = 0.005
#: The share of the time the buildable constraints cover: the velocity range is the speed
#: below which this share of each side's shock velocities lies (docs/DESIGN.md).
RANGE_QUANTILE = 0.99
MIN_KNOT_GAP_M_S = 0.005


def spread_knots(knots_m_s, *, min_m_s=MIN_KNOT_M_S, min_gap_m_s=MIN_KNOT_GAP_M_S):
    """Knots at least `min_m_s` and at least `min_gap_m_s` apart, moved up as little as needed.

    Parameters
    ----------
    knots_m_s : sequence of float
        Increasing (or equal) knot speeds [m/s].
    min_m_s, min_gap_m_s : float

    Returns
    -------
    list of float
    """
    out = []
    for k in np.asarray(knots_m_s, dtype=float):
        lo = min_m_s if not out else out[-1] + min_gap_m_s
        out.append(round(float(max(k, lo)), 4))
    return out


def shock_speeds(plant, drives, setup, library, *, oversample=2, third=None):
    """A setup's shock velocities over drives, every corner pooled.

    Parameters
    ----------
    plant : LoopPlant
    drives : list of ident.data.drive.Drive
        Prepared; every drive's samples count equally.
    setup : planner.setups.Setup
        Usually the baseline.
    library : ident.models.library.ShockLibrary
        Holds the setup's shocks.
    oversample : int
    third : tuple, optional
        The car's third elements, the setup's ``(dampers, springs)`` (issue 38).

    Returns
    -------
    ndarray, shape (n_samples,)
        Shock velocities [m/s], bump positive (closed-loop simulation,
        :func:`ident.sim.closedloop.simulate`), non-finite samples dropped.
    """
    out = []
    for d in drives:
        resp = simulate(plant, d, setup.resolve(library), oversample=oversample, third=third)
        out += [np.asarray(resp.channels[f"shock_velocity_{c}"], dtype=float) for c in CORNERS]
    v = np.concatenate(out)
    return v[np.isfinite(v)]


def velocity_knots(speeds_m_s, *, quantiles=KNOT_QUANTILES, min_m_s=MIN_KNOT_M_S,
                   min_gap_m_s=MIN_KNOT_GAP_M_S):
    """Knot speeds on the quantiles of shock speeds, per side.

    Parameters
    ----------
    speeds_m_s : ndarray, shape (n_samples,)
        Shock velocities [m/s], bump positive (:func:`shock_speeds`).
    quantiles : sequence of float
        In (0, 1), increasing.
    min_m_s, min_gap_m_s : float
        As :func:`spread_knots`.

    Returns
    -------
    bump, rebound : list of float
        Knot speeds [m/s], increasing, positive: of the bump samples (v > 0)
        and of the rebound samples' speeds (v < 0); a side without samples
        takes the other's.

    Examples
    --------
    >>> v = np.concatenate([np.linspace(0.0, 0.2, 201), -np.linspace(0.0, 0.1, 101)])
    >>> velocity_knots(v, quantiles=(0.5, 0.9))
    ([0.1005, 0.1801], [0.0505, 0.0901])
    """
    v = np.asarray(speeds_m_s, dtype=float)
    q = np.asarray(quantiles, dtype=float)
    out = []
    for side in (v[v > 0], -v[v < 0]):
        out.append(None if side.size == 0 else spread_knots(
            np.quantile(side, q), min_m_s=min_m_s, min_gap_m_s=min_gap_m_s))
    if out[0] is None and out[1] is None:
        raise ValueError("velocity_knots: no shock-velocity samples; the drive does not move "
                         "the shocks (check the drive's channels)")
    bump, reb = (out[0] or out[1]), (out[1] or out[0])
    return bump, reb


def velocity_range(speeds_m_s, *, quantile=RANGE_QUANTILE):
    """The speeds below which a share `quantile` of each side's samples lies.

    Parameters
    ----------
    speeds_m_s : ndarray, shape (n_samples,)
        Shock velocities [m/s], bump positive.
    quantile : float

    Returns
    -------
    (float, float)
        Rebound and bump speed [m/s] (positive), at least :data:`MIN_KNOT_M_S`.

    Examples
    --------
    >>> v = np.concatenate([np.linspace(0.0, 0.2, 201), -np.linspace(0.0, 0.1, 101)])
    >>> velocity_range(v, quantile=0.5)
    (0.0505, 0.1005)
    """
    v = np.asarray(speeds_m_s, dtype=float)
    out = []
    for side in (-v[v < 0], v[v > 0]):
        out.append(MIN_KNOT_M_S if side.size == 0 else
                   max(round(float(np.quantile(side, quantile)), 4), MIN_KNOT_M_S))
    return out[0], out[1]
