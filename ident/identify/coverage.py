"""What a rig session covered: the shock travels, velocities and tire contact it saw.

An identified model is linear where the session took the car; beyond it, a prediction
extrapolates (a spring that binds, a bushing that stiffens, a tire that leaves the pad:
nothing the session showed). :func:`session_coverage` records, per corner, the largest
RMS shock travel and velocity over the session's runs and their extremes, and, with
static corner loads, the smallest tire contact force; the identified model keeps it
(``settings["coverage"]``) and the planner compares predictions with it
(:func:`outside_coverage`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ident.data.channels import CORNERS

__all__ = [
    "Coverage",
    "COVERAGE_RMS_MARGIN",
    "COVERAGE_CONTACT_MARGIN",
    "session_coverage",
    "outside_coverage",
]

log = logging.getLogger(__name__)

#: A predicted RMS shock travel or velocity above the session's largest by more than this
#: share is outside what the session covered: 25 %, the spread of RMS levels between the
#: runs of one session with different shocks (so a setup as soft as the session's softest
#: is not flagged).
COVERAGE_RMS_MARGIN = 0.25
#: A predicted smallest contact force below the session's smallest by more than this share
#: of the static load is outside it.
COVERAGE_CONTACT_MARGIN = 0.1


@dataclass(frozen=True, eq=False)
class Coverage:
    """What a session covered, per corner ``LF, RF, LR, RR``.

    Attributes
    ----------
    travel_rms_m : ndarray, shape (4,)
        The largest RMS shock travel of the session's runs (mean removed) [m].
    velocity_rms_m_s : ndarray, shape (4,)
        The largest RMS shock velocity [m/s].
    travel_max_m : ndarray, shape (4,)
        The largest compression from the run's mean [m].
    contact_min_n : ndarray, shape (4,), or None
        The smallest tire contact force (static load plus the tire-force channel's
        dynamic part) [N], with static loads known.
    runs : int
        Runs it covers.
    """

    travel_rms_m: np.ndarray
    velocity_rms_m_s: np.ndarray
    travel_max_m: np.ndarray
    contact_min_n: np.ndarray | None
    runs: int

    def to_dict(self):
        """A JSON-able dict (:meth:`from_dict` reads it back)."""
        return {"travel_rms_m": self.travel_rms_m.tolist(),
                "velocity_rms_m_s": self.velocity_rms_m_s.tolist(),
                "travel_max_m": self.travel_max_m.tolist(),
                "contact_min_n": None if self.contact_min_n is None
                else self.contact_min_n.tolist(), "runs": int(self.runs)}

    @classmethod
    def from_dict(cls, d):
        """The coverage of a dict written by :meth:`to_dict`."""
        contact = d.get("contact_min_n")
        return cls(travel_rms_m=np.asarray(d["travel_rms_m"], float),
                   velocity_rms_m_s=np.asarray(d["velocity_rms_m_s"], float),
                   travel_max_m=np.asarray(d["travel_max_m"], float),
                   contact_min_n=None if contact is None else np.asarray(contact, float),
                   runs=int(d.get("runs", 0)))


def _rms(x):
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean((x - x.mean()) ** 2)))


def session_coverage(session):
    """What a session covered (:class:`Coverage`).

    Parameters
    ----------
    session : ident.data.session.Session
        Its runs' ``shock_travel_XX``, ``shock_velocity_XX`` and, with
        ``static_corner_load_n``, ``tire_force_XX`` (corners or channels missing count
        as not covered: NaN).

    Returns
    -------
    Coverage
    """
    n = len(CORNERS)
    trav, vel, tmax = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    static = getattr(session, "static_corner_load_n", None)
    contact = None if static is None else np.full(n, np.nan)
    for run in session.runs:
        ch = run.channels
        for k, c in enumerate(CORNERS):
            if f"shock_travel_{c}" in ch:
                x = np.asarray(ch[f"shock_travel_{c}"], float)
                trav[k] = np.fmax(trav[k], _rms(x))
                tmax[k] = np.fmax(tmax[k], float(np.max(x - x.mean())))
            if f"shock_velocity_{c}" in ch:
                vel[k] = np.fmax(vel[k], _rms(ch[f"shock_velocity_{c}"]))
            if contact is not None and f"tire_force_{c}" in ch:
                f = np.asarray(ch[f"tire_force_{c}"], float)
                contact[k] = np.fmin(contact[k], float(static[k] + np.min(f - f.mean())))
    return Coverage(travel_rms_m=trav, velocity_rms_m_s=vel, travel_max_m=tmax,
                    contact_min_n=contact, runs=len(session.runs))


def outside_coverage(table, coverage, static_corner_load_n=None, *,
                     rms_margin=COVERAGE_RMS_MARGIN, contact_margin=COVERAGE_CONTACT_MARGIN):
    """Where predictions take the car beyond what the session covered.

    Parameters
    ----------
    table : pandas.DataFrame
        Predicted metrics, one row per setup (SI): ``shock_travel_rms_XX``,
        ``shock_velocity_rms_XX`` and, if present, ``tire_contact_min_XX``.
    coverage : Coverage
    static_corner_load_n : array_like, shape (4,), optional
        Scales the contact margin (default: the margin of 1 kN).
    rms_margin, contact_margin : float
        :data:`COVERAGE_RMS_MARGIN`, :data:`COVERAGE_CONTACT_MARGIN`.

    Returns
    -------
    list of (str, str, str, float, float)
        ``(setup, corner, what, predicted, covered)`` for every setup and corner outside
        (``what``: ``"travel"``, ``"velocity"`` or ``"contact"``), SI.
    """
    out = []
    static = (np.full(4, 1e3) if static_corner_load_n is None
              else np.asarray(static_corner_load_n, float))
    checks = (("travel", "shock_travel_rms_", coverage.travel_rms_m, 1),
              ("velocity", "shock_velocity_rms_", coverage.velocity_rms_m_s, 1))
    for name, row in table.iterrows():
        for k, c in enumerate(CORNERS):
            for what, prefix, covered, _ in checks:
                col = prefix + c
                if col in table.columns and np.isfinite(covered[k]):
                    v = float(row[col])
                    if v > (1.0 + rms_margin) * covered[k]:
                        out.append((str(name), c, what, v, float(covered[k])))
            col = f"tire_contact_min_{c}"
            if coverage.contact_min_n is not None and col in table.columns \
                    and np.isfinite(coverage.contact_min_n[k]):
                v = float(row[col])
                if v < coverage.contact_min_n[k] - contact_margin * static[k]:
                    out.append((str(name), c, "contact", v, float(coverage.contact_min_n[k])))
    return out
