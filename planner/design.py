"""Optimal experiment design: which rig runs to do next, and in what order.

A rig run is a setup (the baseline, or crate shocks swapped in at one to four
corners), a drive and a duration. ``design_experiment`` chooses runs within a
rig-time budget so that the identification (:mod:`ident.identify.frf`, Eqs. 18-23 of the
seed paper) learns the most, by one of three criteria, then orders them to
swap as few shocks as possible.

Information of a run
--------------------
At each frequency the identification regresses every output on the 11 model
inputs ``x = [u_rig (7), dF (4)]``. For a run of duration ``T`` the Fisher
information about an output's row of the FRF in a frequency band is
``T * S_xx / sigma^2``: the band's cross-power of the regressors over the
output's noise power. The regressors of a candidate run are predicted through
the loop with each shock linearized as :mod:`planner.screen` does (its
equivalent damping at the shock velocity it will see, with its lag):
``dF = D_c K H_vr u`` with ``D_c = diag(c(omega) - c_bar)`` and
``K = (I - H_vs D_c)^-1``, so ``S_xx = G S_uu G^H`` with ``G = [I; D_c K H_vr]``
(11 x 7). One run alone has rank 7 (Eq. 17: with linearized shocks the shock
forces are linear functions of the rig inputs); runs with different shocks
add up to rank 11. A session already recorded adds its own measured
information (its runs' ``[u_rig, dF]``, the nonlinear part included). This
linearized model ignores the independent excitation a shock's nonlinearity
gives, so it values nonlinear shocks conservatively.

Criteria (all over the bands of ``band_hz``)
--------------------------------------------
- ``d``: D-optimal, ``sum_k log det M_k``;
- ``a``: A-optimal, ``sum_k tr M_k^-1`` (each band's inputs scaled to unit
  information of the whole candidate set, so units do not weigh);
- ``decision``: the variance of the predicted score differences between the
  top contenders of the current ranking, ``sum_pairs var(s_a - s_b) /
  (s_a - s_b)^2 = sum_k tr(W_k M_k^-1)``, with ``W_k`` from the scores'
  gradients with respect to the FRF (the screening's linearized loop,
  differentiated analytically) and the outputs' noise.

The relaxed problem (runs as real numbers) is solved with cvxpy (Clarabel) on
``n_design_bands`` groups of adjacent bands (a group's information summed:
``log det`` of a sum bounds the sum of ``log det``); the information
matrices are scaled per band so the solver sees unit diagonals. The relaxed
counts are rounded down and the budget left is filled greedily, run by run,
on the full criterion over every band (the cvxpy-free greedy of the benchmark
does the same from nothing). Each run costs its duration, the swap time of
every corner it changes and the rig's overhead per run; the order that swaps
least is found exactly for up to 9 runs (Held-Karp), by nearest neighbour and
2-opt above, and runs are dropped (least criterion share first) until the
ordered plan fits the budget.

Adjustable shocks (clickers)
----------------------------
The candidates include each adjustable shock of the crate at a few settings
(:func:`click_settings`: each adjuster across its range, all stiff, all soft),
named with every adjuster (``TTX@ls=0,hs=2``). A corner that keeps its
adjustable shock and changes its settings is a click change: it costs the
rig's ``click_change_s`` per adjuster turned (seconds), not ``swap_min``
(minutes) (:func:`change_time_min`), in the candidates' costs, the greedy's
insertion, the run order and the schedule. With an adjustable shock on the
baseline the design can thus vary a corner's damping for seconds of rig time;
the criterion decides which settings inform. A crate without adjustable shocks
plans exactly as before.
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
import re
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pandas as pd
from scipy import signal

from ident.data import drive as drv
from ident.data.channels import CORNERS, RIG_INPUTS
from ident.identify.condition import frf_standard_error
from ident.identify.frf import shock_force_deviation
from ident.identify.model import VehicleModel
from ident.models.adjustable import parse_shock_name
from ident.models.vehicle import FullCarModel, VehicleParams, build_full_car
from ident.sim.rig import default_plan, loop_damping, make_plan_drive
from planner.errors import PlannerError
from planner.objective import default_objective, score_setups
from planner.options import UncertaintyOptions
from planner.predict import predict_setups
from planner.rig import RigSpec, default_rig
from planner.screen import DriveBands, metric_rows, screen_response, screen_setups
from planner.setups import Setup, enumerate_setups, resolve_baseline, unknown_id_error
from planner.uncertainty import interpolate, prediction_uncertainty

__all__ = [
    "Candidate",
    "PlannedRun",
    "ExperimentPlan",
    "CRITERIA",
    "DRIVE_KINDS",
    "PURPOSES",
    "candidate_runs",
    "click_settings",
    "change_time_min",
    "design_experiment",
    "CandidateOptions",
    "InformationOptions",
    "ScheduleOptions",
    "criterion_value",
    "greedy_design",
]

log = logging.getLogger(__name__)

#: The design criteria.
CRITERIA = ("d", "a", "decision")
#: Drive kinds a candidate run may play.
DRIVE_KINDS = ("noise", "multisine", "sweep", "track")
#: What a planned run is for.
PURPOSES = ("identification", "baseline repeat", "validation")
#: Regularization of log det and inverses of the scaled information matrices (a direction
#: with less information than this, relative to the whole candidate set, counts as none).
_EPS = 1e-9
#: A band whose scaled total information has an eigenvalue below this is not identifiable.
_RANK_TOL = 1e-8
#: Bands of the information (common to every candidate) and the design band [Hz].
DEFAULT_BAND_HZ = (0.5, 20.0)
#: Settings per adjuster that candidate runs try across its range (ends included).
DEFAULT_CLICK_LEVELS = 3


# ----------------------------------------------------------------------------------------------
# options
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CandidateOptions:
    """The candidate runs a design chooses from (:func:`candidate_runs`).

    Parameters
    ----------
    kinds : sequence of str
        Drive kinds of the candidates (:data:`DRIVE_KINDS`).
    durations_s : sequence of float
        Run durations [s]; the shortest is also the baseline repeats'.
    shocks : sequence of str, optional
        Shock ids the candidates swap in; default the crate's (``n_shocks`` of them).
    n_shocks : int
        Shocks chosen from the crate when `shocks` is not given.
    click_levels : int
        Settings per adjuster tried across its range (ends included).

    Raises
    ------
    PlannerError
        Checked where the candidates are built (an unknown kind or shock id).
    """

    kinds: tuple = ("noise", "multisine")
    durations_s: tuple = (120.0, 300.0, 600.0)
    shocks: tuple | None = None
    n_shocks: int = 4
    click_levels: int = DEFAULT_CLICK_LEVELS


@dataclass(frozen=True)
class InformationOptions:
    """The information a design's criterion sums: bands, design bands, noise.

    Parameters
    ----------
    n_bands : int
        Log-spaced bands over `band_hz` the criterion sums over.
    n_design_bands : int
        Groups of adjacent bands in the relaxed problem.
    band_hz : (float, float)
        The design band [Hz].
    noise : float
        Output noise as a fraction of each output's RMS, white (a known model).

    Raises
    ------
    ValueError
        If `n_design_bands` exceeds `n_bands` or a count is below 1.
    """

    n_bands: int = 96
    n_design_bands: int = 12
    band_hz: tuple = DEFAULT_BAND_HZ
    noise: float = 0.02

    def __post_init__(self):
        if not (1 <= int(self.n_design_bands) <= int(self.n_bands)):
            raise ValueError(f"InformationOptions: n_design_bands={self.n_design_bands} must "
                             f"be between 1 and n_bands={self.n_bands}")


@dataclass(frozen=True)
class ScheduleOptions:
    """How a design's runs are scheduled and sheeted.

    Parameters
    ----------
    baseline_every : int
        Repeat the baseline (shortest duration) after every this many runs (0: never),
        to catch drift.
    n_validation : int
        Validation runs of the current best setups on the team's drive.
    seed : int
        Seeds of the planned drives.
    date : str, optional
        For the run sheet's header.
    """

    baseline_every: int = 0
    n_validation: int = 0
    seed: int = 0
    date: str | None = None


# ----------------------------------------------------------------------------------------------
# candidates and plans
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Candidate:
    """A run the design may choose.

    Attributes
    ----------
    name : str
    setup : planner.setups.Setup
    kind : str
        Drive kind (:data:`DRIVE_KINDS`).
    duration_s : float
    changed : tuple of str
        Corners whose shock (or its setting) differs from the baseline's.
    cost_min : float
        Duration, swaps and click changes (from the baseline) and overhead [min].
    clicks : int
        Adjusters turned from the baseline (corners keeping their adjustable shock).
    """

    name: str
    setup: object
    kind: str
    duration_s: float
    changed: tuple
    cost_min: float
    clicks: int = 0


@dataclass(frozen=True)
class PlannedRun:
    """One run of the plan, in rig order.

    Attributes
    ----------
    number : int
        From 1.
    name : str
    setup : planner.setups.Setup
    purpose : str
        :data:`PURPOSES`.
    drive : str
        Name of the drive (its file is ``drives/<drive>.csv``).
    kind : str
    duration_s : float
    start_min : float
        Planned start, minutes from the plan's start (swaps before it included).
    changed : tuple of str
        Corners changed before this run: a shock swapped, or an adjustable shock's
        setting changed.
    swap_min : float
        Time of those changes [min], swaps and click changes.
    share : float
        The run's share of the criterion (leave-one-out, the shares summing to 1).
    clicks : tuple of (str, str)
        ``(corner, adjuster)`` of every adjuster turned before this run at a corner that
        kept its adjustable shock (those corners are in `changed` too).
    """

    number: int
    name: str
    setup: object
    purpose: str
    drive: str
    kind: str
    duration_s: float
    start_min: float
    changed: tuple
    swap_min: float
    share: float
    clicks: tuple = ()

    @property
    def swapped(self):
        """tuple of str: the corners of `changed` whose shock was swapped."""
        clicked = {c for c, _ in self.clicks}
        return tuple(c for c in self.changed if c not in clicked)

    @property
    def change(self):
        """str: the kind of change before the run: ``"swap"``, ``"clicks"``,
        ``"swap+clicks"`` or ``""`` (none)."""
        kinds = [k for k, on in (("swap", self.swapped), ("clicks", self.clicks)) if on]
        return "+".join(kinds)


@dataclass(frozen=True, eq=False)
class ExperimentPlan:
    """The result of :func:`design_experiment`.

    Attributes
    ----------
    runs : tuple of PlannedRun
    drives : dict of str -> ident.data.drive.Drive
        Every drive the runs play, by name.
    library : ShockLibrary
        The crate.
    baseline : planner.setups.Setup
    criterion : str
    budget_min, total_min : float
        The budget and the ordered plan's rig time [min].
    values : dict
        The criterion: ``prior`` (the session's), ``relaxed`` (the relaxed
        optimum on the design bands), ``plan`` (the rounded plan on every
        band), ``greedy`` (the cvxpy-free greedy plan of the same budget).
    relaxed : pandas.DataFrame
        Per candidate: the relaxed number of runs and its cost.
    predictions : pandas.DataFrame
        Per run: the key metrics predicted for it (SI), with ``_lo``/``_hi``
        intervals for an identified model.
    curve : pandas.DataFrame
        The criterion after each run against the rig time so far.
    solver : dict
        cvxpy's status, solver, times.
    rig : planner.rig.RigSpec
    settings : dict
    """

    runs: tuple
    drives: dict
    library: object
    baseline: object
    criterion: str
    budget_min: float
    total_min: float
    values: dict
    relaxed: pd.DataFrame
    predictions: pd.DataFrame
    curve: pd.DataFrame
    solver: dict
    rig: RigSpec
    settings: dict = field(default_factory=dict)

    def table(self):
        """The runs as a DataFrame (one row per run, in rig order); with adjustable shocks
        in the crate, a ``change`` column holds :attr:`PlannedRun.change`."""
        rows = []
        for r in self.runs:
            row = {"run": r.number, "name": r.name, "purpose": r.purpose,
                   "start_min": r.start_min, "duration_s": r.duration_s, "drive": r.drive,
                   "kind": r.kind}
            row.update(dict(zip(CORNERS, r.setup.ids())))
            row["changed"] = " ".join(r.changed)
            if self.library.adjustable_ids:
                row["change"] = r.change
            row.update({"swap_min": r.swap_min, "share": r.share})
            rows.append(row)
        return pd.DataFrame(rows).set_index("run")


# ----------------------------------------------------------------------------------------------
# drives
# ----------------------------------------------------------------------------------------------

def _drive_maker(vehicle, session):
    """kind -> function(duration_s, seed, name) -> Drive, sized like the session's inputs (an
    identified model) or the paper's plan on the vehicle (a known one)."""
    fs = session.fs_hz if session is not None else 100.0
    if session is not None:
        ref = session.runs[0]
        rms = {c: float(np.std(ref.dynamic(c))) for c in RIG_INPUTS}
        peak = {c: float(np.max(np.abs(ref.dynamic(c)))) for c in RIG_INPUTS}
    else:
        paper = make_plan_drive(default_plan(), vehicle, seed=0, duration_s=60.0)
        rms = {c: float(np.std(paper.channels[c])) for c in RIG_INPUTS}
        peak = {c: float(np.max(np.abs(paper.channels[c]))) for c in RIG_INPUTS}
    wheelbase = vehicle.a_m + vehicle.b_m if vehicle is not None else 2.794
    track = vehicle.track_front_m if vehicle is not None else 1.778

    def make(kind, duration_s, seed, name):
        if kind == "noise":
            return drv.make_noise_drive(duration_s=duration_s, fs_hz=fs, peak=peak, seed=seed,
                                        name=name)
        if kind == "multisine":
            return drv.make_multisine_drive(duration_s=duration_s, fs_hz=fs, rms=rms, seed=seed,
                                            f_min_hz=0.3, f_max_hz=25.0, name=name)
        if kind == "sweep":
            amp = {c: np.sqrt(2) * rms[c] for c in RIG_INPUTS[3:]}
            return drv.make_sweep_drive(duration_s=duration_s, fs_hz=fs, amplitude=amp,
                                        f_start_hz=0.5, f_stop_hz=25.0, name=name)
        return drv.make_track_drive(duration_s=duration_s, fs_hz=fs, seed=seed,
                                    wheelbase_m=wheelbase, track_width_m=track, name=name)

    return make


def _band_power(x, fs, edges, weight=None):
    """Cross-power of channels `x` (n_ch, N) in bands (scipy's ``conj(X_i) X_j``): the
    cross-spectral density at each band's centre (interpolated between Welch lines, so
    bands narrower than the resolution still get their share) times the band's width,
    optionally weighted by ``weight(f_c)``. Returns ``(f_c (n_b,), S (n_b, n_ch, n_ch))``."""
    nperseg = int(min(x.shape[1], 2 ** round(np.log2(20 * fs))))
    f, P = signal.csd(x[:, None, :], x[None, :, :], fs=fs, window="hann", nperseg=nperseg,
                      axis=-1)
    f_c = np.sqrt(edges[:-1] * edges[1:])
    j = np.clip(np.searchsorted(f, f_c) - 1, 0, f.size - 2)
    t = (f_c - f[j]) / (f[j + 1] - f[j])
    dens = P[:, :, j] * (1 - t) + P[:, :, j + 1] * t  # (n_ch, n_ch, n_b)
    wt = np.diff(edges) * (1.0 if weight is None else np.asarray(weight(f_c), dtype=float))
    return f_c, np.moveaxis(dens * wt, -1, 0)


# ----------------------------------------------------------------------------------------------
# candidates
# ----------------------------------------------------------------------------------------------

_GROUPS = {"single": [(c,) for c in CORNERS], "diagonal": [("LF", "RR"), ("RF", "LR")],
           "axle": [("LF", "RF"), ("LR", "RR")], "all": [CORNERS]}


def click_settings(shock, levels=DEFAULT_CLICK_LEVELS):
    """Settings of an adjustable shock that candidate runs try.

    Each adjuster at `levels` settings evenly across its range (its ends included,
    snapped to its step), the others at their default; and, with two adjusters or
    more, every adjuster at its stiffer end and every one at its softer end. The
    design criterion chooses among them (the ends usually: they move the damping
    most from the baseline's).

    Parameters
    ----------
    shock : ident.models.adjustable.AdjustableShock
    levels : int
        Settings per adjuster, >= 2.

    Returns
    -------
    list of str
        Canonical setting names (``"TTX@ls=0,hs=2"``), each once: the stiffest, the
        softest, then each adjuster's levels.

    Examples
    --------
    >>> from ident.models.adjustable import AdjustableShock, DynoPoints
    >>> rows = [(v, 3000 * v * (1.5 - ls / 40), ls) for ls in (0, 20)
    ...         for v in (-0.5, -0.1, 0.1, 0.5)]
    >>> ttx = AdjustableShock("TTX", {"ls": (0, 20)}, DynoPoints.from_rows(rows, ("ls",)),
    ...                       default={"ls": 8}, step={"ls": 1})
    >>> click_settings(ttx)
    ['TTX@ls=0', 'TTX@ls=10', 'TTX@ls=20']
    """
    if isinstance(levels, bool) or not isinstance(levels, int) or levels < 2:
        raise PlannerError(f"click levels = {levels!r}: give a whole number >= 2 of settings "
                           "per adjuster (2: the ends of its range)")
    ends = {}
    for k, (lo, hi) in shock.adjusters.items():
        ends[k] = (lo, hi) if shock.stiffer[k] == "lower" else (hi, lo)
    out = []
    if len(ends) > 1:
        out += [shock.name({k: e[0] for k, e in ends.items()}),
                shock.name({k: e[1] for k, e in ends.items()})]
    for k, (lo, hi) in shock.adjusters.items():
        st = shock.step.get(k)
        for j in range(levels):
            x = lo + (hi - lo) * j / (levels - 1)
            if st:
                x = min(lo + st * math.floor((x - lo) / st + 0.5), hi)
            out.append(shock.name({k: x}))
    return list(dict.fromkeys(out))


@functools.lru_cache(maxsize=4096)
def _named_settings(name):
    base, settings = parse_shock_name(name)
    return base, tuple(settings.items())


def _corner_change(before, after):
    """(swaps, click changes) to go from shock name `before` to `after` at one corner: 0 and
    the adjusters whose setting differs when both name settings of one adjustable shock
    (every adjuster written, as :func:`design_experiment` keeps them), else one swap."""
    if before == after:
        return 0, 0
    if "@" not in before or "@" not in after:
        return 1, 0
    (ba, sa), (bb, sb) = _named_settings(before), _named_settings(after)
    da, db = dict(sa), dict(sb)
    if ba != bb or da.keys() != db.keys():
        return 1, 0
    return 0, sum(da[k] != db[k] for k in da)


@functools.lru_cache(maxsize=1 << 16)
def _id_change_counts(ids_a, ids_b):
    swaps = clicks = 0
    for x, y in zip(ids_a, ids_b):
        ds, dc = _corner_change(x, y)
        swaps += ds
        clicks += dc
    return swaps, clicks


def _change_counts(a, b):
    """Swaps and click changes from setup `a` to setup `b` (the greedy asks for the same
    pairs again and again: cached on the ids)."""
    return _id_change_counts(a.ids(), b.ids())


def change_time_min(before, after, rig=None):
    """Rig time [min] to change the car from one setup to the next.

    Parameters
    ----------
    before, after : planner.setups.Setup
        Adjustable shocks named with every adjuster (``TTX@ls=6,hs=2``; a corner whose
        name keeps its adjustable shock and changes settings is a click change).
    rig : planner.rig.RigSpec, optional
        Default :func:`planner.rig.default_rig`.

    Returns
    -------
    float
        ``swap_min`` a corner whose shock is swapped plus ``click_change_s / 60`` an
        adjuster turned.

    Examples
    --------
    >>> a = Setup("a", dict.fromkeys(CORNERS, "TTX@ls=6,hs=2"))
    >>> b = Setup("b", {**dict.fromkeys(CORNERS, "TTX@ls=6,hs=2"), "LF": "TTX@ls=8,hs=1"})
    >>> round(change_time_min(a, b, RigSpec(swap_min=6.0, click_change_s=20.0)), 3)
    0.667
    >>> change_time_min(a, Setup("c", {**a.shocks, "LF": "B20"}), RigSpec(swap_min=6.0))
    6.0
    """
    rig = default_rig() if rig is None else rig
    swaps, clicks = _change_counts(before, after)
    return rig.swap_min * swaps + rig.click_change_min * clicks


def _full_name(library, sid):
    """An adjustable shock's name with every adjuster written (fixed ids unchanged)."""
    base = library.base_id(sid)
    if base not in library.adjustable_ids:
        return sid
    _, settings = parse_shock_name(sid)
    return library.adjustable(base).name(settings)


def _full_names(setup, library):
    """`setup` with its adjustable shocks named in full (itself when nothing changes)."""
    if not library.adjustable_ids:
        return setup
    ids = tuple(_full_name(library, sid) for sid in setup.ids())
    if ids == setup.ids():
        return setup
    return Setup(setup.name, dict(zip(CORNERS, ids)), setup.bump_stops, setup.packers_m)


def candidate_runs(library, baseline, *, rig=None, kinds=("noise", "multisine"),
                   durations_s=(120.0, 300.0, 600.0), shocks=None, n_shocks=4, c_bar=None,
                   v_rms_m_s=0.1, click_levels=DEFAULT_CLICK_LEVELS):
    """The runs a design chooses from.

    The baseline, and the baseline with shocks swapped in at one corner, at a
    diagonal pair, at an axle, or at all four, for each of `kinds` and
    `durations_s`. The shocks swapped in are `shocks`, or the `n_shocks` crate
    shocks whose linearized damping (at `v_rms_m_s`) differs most from the
    baseline damping `c_bar` (the most informative, Eq. 22), softest and
    firmest alternating, followed by each adjustable shock of the crate at its
    :func:`click_settings` (`click_levels` per adjuster). A corner whose baseline
    shock is that adjustable shock changes clicks, not its shock: the run costs
    ``click_change_s`` an adjuster turned, not ``swap_min``.

    Returns
    -------
    list of Candidate
    """
    rig = default_rig() if rig is None else rig
    baseline = _full_names(baseline, library)
    base_ids = baseline.ids()
    adjustable = set(library.adjustable_ids)
    if shocks is None:
        cb = np.mean(c_bar) if c_bar is not None else np.mean(
            [library[s].equivalent_damping(v_rms_m_s) for s in base_ids])
        others = [s for s in library.ids if s not in base_ids and s not in adjustable]
        ceq = {s: float(library[s].equivalent_damping(v_rms_m_s)) for s in others}
        soft = sorted([s for s in others if ceq[s] < cb], key=lambda s: ceq[s])
        firm = sorted([s for s in others if ceq[s] >= cb], key=lambda s: -ceq[s])
        shocks = [s for pair in itertools.zip_longest(soft, firm) for s in pair if s][:n_shocks]
        for sid in library.adjustable_ids:
            shocks += click_settings(library.adjustable(sid), click_levels)
    else:
        for s in shocks:
            if s not in library:
                raise unknown_id_error("candidate shocks", s, library)
        shocks = list(dict.fromkeys(_full_name(library, s) for s in shocks))
    setups = [("baseline", baseline, ())]
    for group, sets in _GROUPS.items():
        for corners in sets:
            for sid in shocks:
                ids = dict(zip(CORNERS, base_ids))
                ids.update({c: sid for c in corners})
                if tuple(ids[c] for c in CORNERS) == base_ids:
                    continue
                tag = "all" if group == "all" else "+".join(corners)
                setups.append((f"{sid}@{tag}", Setup(f"{sid}@{tag}", ids),
                               tuple(c for c in CORNERS if ids[c] != dict(zip(CORNERS,
                                                                             base_ids))[c])))
    out = []
    for name, setup, changed in setups:
        swaps, clicks = _change_counts(baseline, setup)
        for kind in kinds:
            if kind not in DRIVE_KINDS:
                raise PlannerError(f"drive kind {kind!r} is not one of {list(DRIVE_KINDS)}")
            for T in durations_s:
                cost = (T / 60.0 + rig.swap_min * swaps + rig.click_change_min * clicks
                        + rig.run_overhead_min)
                out.append(Candidate(f"{name} {kind} {T:g}s", setup, kind, float(T),
                                     changed, cost, clicks))
    return out


# ----------------------------------------------------------------------------------------------
# information
# ----------------------------------------------------------------------------------------------

def _linearized(plant, bands_fb, S_b, models):
    """Equivalent damping per setup and corner at the velocity the setup sees on a drive."""
    bands = DriveBands(f_hz=bands_fb, S=S_b, SB=S_b, fs_hz=100.0, band_hz=(1.0, 20.0),
                       drive_name="design")
    H = plant.frequency_response(bands_fb)
    _, _, sig, _ = screen_response(H, plant.output_names, plant.cbar_n_s_m, bands, models)
    return sig


def _candidate_information(plant, setups, kinds, drive_of, library, edges, f_c):
    """Information per second of every (setup, kind): (n_setups, n_kinds, n_b, 11, 11), the
    drives' band power (n_kinds, n_b, 7, 7) and the linearized damping."""
    nb = edges.size - 1
    H = plant.frequency_response(f_c)  # (p, 11, nb)
    vi = plant.velocity_idx
    Hvr = np.transpose(H[vi, :7], (2, 0, 1))  # (nb, 4, 7)
    Hvs = np.transpose(H[vi, 7:], (2, 0, 1))  # (nb, 4, 4)
    cbar = plant.cbar_n_s_m
    w = 2 * np.pi * f_c
    info = np.zeros((len(setups), len(kinds), nb, 11, 11), dtype=complex)
    powers = []
    for j, kind in enumerate(kinds):
        d = drive_of[kind]
        _, S = _band_power(np.vstack([d.channels[c] - d.channels[c].mean() for c in RIG_INPUTS]),
                           d.fs_hz, edges)
        S_rate = S / 1.0  # band power: a run of T seconds carries T * S
        powers.append(S_rate)
        models = [s.resolve(library) for s in setups]
        sig = _linearized(plant, f_c, S, models)
        for i, mods in enumerate(models):
            ceq = np.array([m.equivalent_damping(sig[i, c]) for c, m in enumerate(mods)])
            lag = np.array([m.lag_s for m in mods])
            Dc = ceq[None, :] / (1 + 1j * w[:, None] * lag[None, :]) - cbar[None, :]  # (nb, 4)
            K = np.linalg.inv(np.eye(4)[None] - Hvs * Dc[:, None, :])
            A = Dc[:, :, None] * (K @ Hvr)  # (nb, 4, 7)
            G = np.concatenate([np.broadcast_to(np.eye(7), (nb, 7, 7)), A], axis=1)  # (nb,11,7)
            # scipy's S[i, j] = E[conj(U_i) U_j]; the regressors' x x^H is G S^T G^H
            info[i, j] = G @ np.transpose(S, (0, 2, 1)) @ np.conj(np.transpose(G, (0, 2, 1)))
    return info, np.array(powers)


def _session_information(session, cbar, edges):
    """The recorded runs' own information: sum over runs of ``T * S_xx`` of their measured
    ``[u_rig, dF]``, shape (n_b, 11, 11)."""
    nb = edges.size - 1
    M = np.zeros((nb, 11, 11), dtype=complex)
    for run in session.runs:
        _, dF = shock_force_deviation(run, session.shocks, cbar)
        x = np.vstack([np.vstack([run.dynamic(c) for c in RIG_INPUTS]), dF])
        _, S = _band_power(x, session.fs_hz, edges)
        M += run.n_samples / session.fs_hz * np.transpose(S, (0, 2, 1))
    return M


def _herm(M):
    return 0.5 * (M + np.conj(np.swapaxes(M, -1, -2)))


def criterion_value(M, criterion, W=None):
    """The criterion of scaled information matrices (larger is better), summed over bands.

    Parameters
    ----------
    M : ndarray, shape (n_b, 11, 11)
        Hermitian information per band (scaled).
    criterion : {"d", "a", "decision"}
    W : ndarray, shape (n_b, 11, 11), optional
        The decision weights (``decision`` only).

    Returns
    -------
    float
        ``sum log det M`` (d), ``-sum tr M^-1`` (a), ``-sum tr W M^-1`` (decision), each
        with ``M + eps I``.
    """
    Mr = _herm(M) + _EPS * np.eye(M.shape[-1])
    if criterion == "d":
        sign, logdet = np.linalg.slogdet(Mr)
        return float(np.sum(logdet))
    inv = np.linalg.inv(Mr)
    if criterion == "a":
        return -float(np.real(np.einsum("kii->", inv)))
    return -float(np.real(np.einsum("kij,kji->", W, inv)))


# ----------------------------------------------------------------------------------------------
# the decision criterion's weights
# ----------------------------------------------------------------------------------------------

def _score_gradients(H, out_names, cbar, f_c, SB, models, sig, objective, m_base,
                     return_scores=False):
    """Gradient of each setup's score with respect to the FRF, per band (screening's
    linearized loop, differentiated analytically).

    ``dP_j = 2 Re sum_{o,i} g_j[o, i] dH[o, i]`` per band for the metric power ``P_j``;
    the score ``s = sum_j w_j m_j / m_b,j`` with ``m_j = sqrt(P_j)``.

    Returns
    -------
    grads : ndarray of complex, shape (n_setups, n_b, n_out, 11)
    scores : ndarray, shape (n_setups,)
        With `return_scores`: the scores themselves (the linearization frozen at `sig`).
    """
    names, L = metric_rows(SimpleNamespace(output_names=list(out_names)))
    w = np.array([objective.weights.get(n, 0.0) for n in names])
    mb = np.array([m_base.get(n, np.nan) for n in names])
    keep = w > 0
    names, L, w, mb = [n for n, k in zip(names, keep) if k], L[keep], w[keep], mb[keep]
    vi = [list(out_names).index(f"shock_velocity_{c}") for c in CORNERS]
    p, nb = H.shape[0], f_c.size
    om = 2 * np.pi * f_c
    out = np.zeros((len(models), nb, p, 11), dtype=complex)
    scores = np.zeros(len(models))
    for s, mods in enumerate(models):
        ceq = np.array([m.equivalent_damping(sig[s, c]) for c, m in enumerate(mods)])
        lag = np.array([m.lag_s for m in mods])
        Dc = ceq[None, :] / (1 + 1j * om[:, None] * lag[None, :]) - cbar[None, :]
        P = np.zeros(len(names))
        parts = []
        for k in range(nb):
            Hr, Hs = H[:, :7, k], H[:, 7:, k]
            Hvr, Hvs = Hr[vi], Hs[vi]
            D = np.diag(Dc[k])
            K = np.linalg.inv(np.eye(4) - Hvs @ D)
            A = D @ K @ Hvr  # (4, 7)
            B = L @ Hs @ D @ K  # (m, 4)
            Ty = L @ Hr + B @ Hvr  # (m, 7)
            Sk = SB[k].T  # E[u u^H]
            P += np.real(np.einsum("mi,ij,mj->m", Ty, Sk, np.conj(Ty)))
            parts.append((Sk, Ty, A, B))
        m = np.sqrt(np.maximum(P, 1e-300))
        scores[s] = float(np.sum(w * m / mb))
        coef = w / mb / (2 * m)  # ds/dP_j
        for k, (Sk, Ty, A, B) in enumerate(parts):
            # dP_j = 2 Re tr(Q_j dTy) with Q_j = Sk^T... in the Wirtinger sense; combine over j
            Q = (np.conj(Ty) * coef[:, None]) @ Sk.T  # (m, 7): sum_j coef_j conj(Ty_j) Sk^T
            Q = Q.T  # (7, m)
            g = np.zeros((p, 11), dtype=complex)
            g[:, :7] += (Q @ L).T  # dTy = L dHr
            g[:, 7:] += (A @ Q @ L).T  # dTy = L dHs A
            gv = (A @ Q @ B).T  # dTy = B dHvs A  (rows vi of dHs)
            for r, o in enumerate(vi):
                g[o, 7:] += gv[r]
            gr = (Q @ B).T  # dTy = B dHvr
            for r, o in enumerate(vi):
                g[o, :7] += gr[r]
            out[s, k] = g
    return (out, scores) if return_scores else out


def _decision_weights(grads, scores, noise_var, top_pairs):
    """``W_k = sum_pairs 2 sum_o sigma_o^2 conj(g_ab) g_ab^T / (s_a - s_b)^2``, (n_b, 11, 11)."""
    nb = grads.shape[1]
    W = np.zeros((nb, 11, 11), dtype=complex)
    for a, b in top_pairs:
        d = scores[a] - scores[b]
        wt = 1.0 / max(d * d, 1e-8)
        g = grads[a] - grads[b]  # (nb, p, 11)
        # with M = sum x x^H the row's covariance is sigma^2 conj(M)^-1, and
        # var(2 Re g^T dh) = 2 sigma^2 g^T conj(M)^-1 conj(g) = tr(W M^-1), W = 2 sigma^2 g g^H
        W += 2 * wt * np.einsum("kp,kpi,kpj->kij", noise_var, g, np.conj(g))
    return _herm(W)


# ----------------------------------------------------------------------------------------------
# solving
# ----------------------------------------------------------------------------------------------

def _relaxed(Mc, M0, cost, budget, criterion, W, groups):
    """cvxpy on the design bands: relaxed run counts (n_cand,), the value and status."""
    import cvxpy as cp  # heavy (1.6 s to import); only the relaxed design needs it

    n = cp.Variable(Mc.shape[0], nonneg=True)
    terms = []
    for g in groups:
        A = np.sum(Mc[:, g], axis=1)  # (n_cand, 11, 11)
        B = _herm(np.sum(M0[g], axis=0)) + _EPS * len(g) * np.eye(11)
        Ag = A.reshape(A.shape[0], -1).T  # (121, n_cand)
        Mg = cp.reshape(Ag @ n, (11, 11), order="C") + B
        Mg = (Mg + cp.conj(Mg).T) / 2
        if criterion == "d":
            terms.append(len(g) * cp.log_det(Mg / len(g)))
        else:
            Wg = np.eye(11) if criterion == "a" else _herm(np.sum(W[g], axis=0))
            w_eig, V = np.linalg.eigh(Wg)
            Lw = V * np.sqrt(np.clip(w_eig, 0, None))
            terms.append(-cp.real(cp.matrix_frac(Lw, Mg)))
    prob = cp.Problem(cp.Maximize(sum(terms)), [cost @ n <= budget])
    t0 = time.perf_counter()
    try:
        prob.solve(solver=cp.CLARABEL)
    except cp.error.SolverError as exc:  # pragma: no cover - reported, the greedy stands in
        return None, float("nan"), f"solver error: {exc}", time.perf_counter() - t0
    status = prob.status
    if status not in ("optimal", "optimal_inaccurate") or n.value is None:
        return None, float("nan"), status, time.perf_counter() - t0
    return np.maximum(np.asarray(n.value), 0.0), float(prob.value), status, \
        time.perf_counter() - t0


def _seq_cost(seq, cands, base, rig):
    """Rig time [min] of candidate runs in the order `seq`, from the baseline installed."""
    t, prev = 0.0, base
    for c in seq:
        swaps, clicks = _change_counts(prev, cands[c].setup)
        t += (cands[c].duration_s / 60 + rig.run_overhead_min + rig.swap_min * swaps
              + rig.click_change_min * clicks)
        prev = cands[c].setup
    return t


def _insertion(seq, c, cands, base, rig):
    """Cheapest place to insert candidate `c` in `seq`: (extra minutes, position)."""
    s = cands[c].setup
    own = cands[c].duration_s / 60 + rig.run_overhead_min
    best = (np.inf, 0)
    setups = [base] + [cands[i].setup for i in seq]
    for p in range(len(seq) + 1):
        prev, nxt = setups[p], (setups[p + 1] if p + 1 < len(setups) else None)
        ds, dc = _change_counts(prev, s)
        if nxt is not None:
            (s1, c1), (s0, c0) = _change_counts(s, nxt), _change_counts(prev, nxt)
            ds, dc = ds + s1 - s0, dc + c1 - c0
        best = min(best, (own + rig.swap_min * ds + rig.click_change_min * dc, p))
    return best


def greedy_design(Mc, M0, cands, base, rig, budget, criterion, W=None, start=()):
    """Add runs one at a time where they cost least in the sequence, each the best criterion
    gain per minute that still fits the budget.

    Parameters
    ----------
    Mc : ndarray, shape (n_cand, n_b, 11, 11)
        Scaled information of each candidate run.
    M0 : ndarray, shape (n_b, 11, 11)
    cands : list of Candidate
    base : Setup
        The setup installed at the start.
    rig : planner.rig.RigSpec
    budget : float
        [min]
    criterion : str
    W : ndarray, optional
    start : sequence of int
        Runs already planned, in order.

    Returns
    -------
    list of int
        Candidate indices in rig order.
    """
    seq = list(start)
    M = M0 + sum((Mc[i] for i in seq), np.zeros_like(M0))
    spent = _seq_cost(seq, cands, base, rig)
    value = criterion_value(M, criterion, W)
    while True:
        best = None
        for c in range(len(cands)):
            extra, pos = _insertion(seq, c, cands, base, rig)
            if spent + extra > budget + 1e-9:
                continue
            v = criterion_value(M + Mc[c], criterion, W)
            gain = (v - value) / extra
            if gain > 0 and (best is None or gain > best[0]):
                best = (gain, c, pos, extra, v)
        if best is None:
            return seq
        _, c, pos, extra, value = best
        seq.insert(pos, c)
        M = M + Mc[c]
        spent += extra


def _fit_budget(seq, Mc, M0, cands, base, rig, budget, criterion, W):
    """Drop runs from `seq` (the least criterion per minute saved first) until it fits."""
    seq = list(seq)
    while seq and _seq_cost(seq, cands, base, rig) > budget + 1e-9:
        M = M0 + sum(Mc[i] for i in seq)
        full = criterion_value(M, criterion, W)
        cost = _seq_cost(seq, cands, base, rig)
        best = None
        for k, i in enumerate(seq):
            rest = seq[:k] + seq[k + 1:]
            saved = cost - _seq_cost(rest, cands, base, rig)
            loss = full - criterion_value(M - Mc[i], criterion, W)
            ratio = loss / max(saved, 1e-9)
            if best is None or ratio < best[0]:
                best = (ratio, k)
        seq.pop(best[1])
    return seq


def _changes(a, b):
    return sum(x != y for x, y in zip(a.ids(), b.ids()))


def _order(setups, start, rig=None):
    """Run order (indices) that changes the car least, starting from setup `start`: the
    fewest corners swapped, a click change counting its time in swaps of `rig`."""
    n = len(setups)
    if n <= 1:
        return list(range(n))
    rig = default_rig() if rig is None else rig
    w = rig.click_change_min / rig.swap_min if rig.swap_min > 0 else 1.0

    def dist(a, b):
        swaps, clicks = _change_counts(a, b)
        return swaps + w * clicks if clicks else swaps

    d = np.array([[dist(a, b) for b in setups] for a in setups])
    d0 = np.array([dist(start, s) for s in setups])
    if n <= 9:  # Held-Karp, exact
        best = {}
        for j in range(n):
            best[(1 << j, j)] = (d0[j], -1)
        for size in range(2, n + 1):
            for subset in itertools.combinations(range(n), size):
                mask = sum(1 << j for j in subset)
                for j in subset:
                    prev = mask & ~(1 << j)
                    best[(mask, j)] = min((best[(prev, i)][0] + d[i, j], i) for i in subset
                                          if i != j)
        full = (1 << n) - 1
        j = min(range(n), key=lambda j: best[(full, j)][0])
        order, mask = [], full
        while j != -1:
            order.append(j)
            mask, j = mask & ~(1 << j), best[(mask, j)][1]
        return order[::-1]
    order, left, cur = [], set(range(n)), None
    while left:  # nearest neighbour, then 2-opt
        j = min(left, key=lambda j: (d0[j] if cur is None else d[cur, j], j))
        order.append(j)
        left.remove(j)
        cur = j

    def length(o):
        return d0[o[0]] + sum(d[o[k], o[k + 1]] for k in range(len(o) - 1))

    improved = True
    while improved:
        improved = False
        for i in range(len(order) - 1):
            for k in range(i + 1, len(order)):
                cand = order[:i] + order[i:k + 1][::-1] + order[k + 1:]
                if length(cand) < length(order):
                    order, improved = cand, True
    return order


# ----------------------------------------------------------------------------------------------
# the design
# ----------------------------------------------------------------------------------------------

def _plant_and_vehicle(model, baseline, library):
    """The loop plant, the vehicle (known models) and the model's FRF (identified ones)."""
    if isinstance(model, VehicleModel):
        return model.loop_plant(), None, model
    if isinstance(model, VehicleParams):
        model = build_full_car(model)
    if isinstance(model, FullCarModel):
        cbar = loop_damping(baseline.resolve(library))
        return model.loop_plant(cbar), model.params, None
    raise TypeError(f"model must be an identified VehicleModel (with the session), a "
                    f"VehicleParams or a FullCarModel, got {type(model).__name__}")


def _noise_variance(plant, frf, f_c, edges, M0, S_ref, noise):
    """Each output's noise power per band, (n_b, n_out): from the identified FRF's standard
    errors and the session's information, or `noise` of each output's RMS, white."""
    p = len(plant.output_names)
    if frf is not None:
        sig = interpolate(frf.f_hz, frf_standard_error(frf), f_c)  # (p, 11, nb)
        order = [list(frf.output_names).index(o) for o in plant.output_names]
        sig = sig[order]
        C = np.linalg.inv(np.conj(_herm(M0)) + _EPS * np.eye(11) * np.abs(
            np.einsum("kii->k", M0)).max())
        cd = np.real(np.einsum("kii->ki", C))  # (nb, 11)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.isfinite(sig), sig**2, np.nan) / cd.T[None, :, :]
        var = np.nanmedian(ratio, axis=1).T  # (nb, p)
        return np.nan_to_num(var, nan=0.0, posinf=0.0)
    H = plant.frequency_response(f_c)
    y = np.real(np.einsum("pik,kij,pjk->kp", H[:, :7], np.transpose(S_ref, (0, 2, 1)),
                          np.conj(H[:, :7])))  # output power per band (rig part)
    total = y.sum(axis=0)  # (p,)
    bw = np.diff(edges) / (edges[-1] - edges[0])
    return (noise**2) * total[None, :] * bw[:, None]


def design_experiment(model, library, *, budget_min, criterion="d", session=None,
                      objective=None, baseline=None, drives=None, rig=None,
                      candidates=CandidateOptions(), information=InformationOptions(),
                      schedule=ScheduleOptions(), top=10):
    """Choose the next rig runs within a budget, order them, and predict them.

    Parameters
    ----------
    model : VehicleModel, VehicleParams or FullCarModel
        An identified model with the `session` it came from (between runs), or
        the known physical model (before rig day).
    library : ShockLibrary
        The crate.
    budget_min : float
        Rig time [min], runs, swaps and overheads included.
    criterion : {"d", "a", "decision"}
    session : ident.data.session.Session, optional
        The runs recorded so far (their information is the prior).
    objective : planner.objective.Objective, optional
        For the decision criterion, validation runs and predictions; default
        :func:`planner.objective.default_objective`.
    baseline : Setup, str or 4 str, optional
        The car's setup at the start and the reference of swaps; default the
        session's baseline run's setup, else the crate's first shock.
    drives : sequence of ident.data.drive.Drive, optional
        The team's drives (e.g. a track's): the contenders of the decision
        criterion are ranked on the first, validation runs play it. Default a
        120 s track-like drive.
    rig : planner.rig.RigSpec, optional
        Default :func:`planner.rig.default_rig`.
    candidates : CandidateOptions
        The candidate runs (:func:`candidate_runs`): ``kinds``, ``durations_s``,
        ``shocks``, ``n_shocks``, ``click_levels``.
    information : InformationOptions
        ``n_bands`` (log-spaced bands over ``band_hz`` the criterion sums over),
        ``n_design_bands`` (groups of adjacent bands in the relaxed problem), ``band_hz``
        [Hz], ``noise`` (output noise as a fraction of each output's RMS, white; a known
        model).
    schedule : ScheduleOptions
        ``baseline_every`` (repeat the baseline, shortest duration, after every this many
        runs; 0: never, to catch drift), ``n_validation`` (validation runs of the current
        best setups on the team's drive), ``seed`` (seeds of the planned drives),
        ``date`` (for the run sheet's header).
    top : int
        Contenders of the decision criterion.

    Returns
    -------
    ExperimentPlan

    Raises
    ------
    PlannerError
        On a budget shorter than one run, an unknown criterion, drive kind,
        shock id or baseline, a crate with which no plan meets Eq. 17 (naming
        the corners and the fix), or a budget too short for any identifying
        plan.
    """
    for value, cls, name in ((candidates, CandidateOptions, "candidates"),
                             (information, InformationOptions, "information"),
                             (schedule, ScheduleOptions, "schedule")):
        if not isinstance(value, cls):
            raise TypeError(f"design: {name} must be a {cls.__name__}, got "
                            f"{type(value).__name__}; e.g. {name}={cls.__name__}()")
    kinds, durations_s, shocks, n_shocks, click_levels = (
        candidates.kinds, candidates.durations_s, candidates.shocks, candidates.n_shocks,
        candidates.click_levels)
    n_bands, n_design_bands, band_hz, noise = (information.n_bands, information.n_design_bands,
                                               information.band_hz, information.noise)
    baseline_every, n_validation, seed, date = (schedule.baseline_every, schedule.n_validation,
                                                schedule.seed, schedule.date)
    if criterion not in CRITERIA:
        raise PlannerError(f"criterion {criterion!r} is not one of {list(CRITERIA)}")
    if not (isinstance(budget_min, (int, float)) and math.isfinite(budget_min)
            and budget_min > 0):
        raise PlannerError(f"budget_min must be a positive number of minutes, got "
                           f"{budget_min!r}")
    rig = default_rig() if rig is None else rig
    objective = default_objective() if objective is None else objective
    if baseline is None and session is not None:
        base_run = next((r for r in session.runs if r.role == "baseline"), session.runs[0])
        baseline = [base_run.setup[c] for c in CORNERS]
    base = resolve_baseline(library.ids[0] if baseline is None else baseline, library)
    base = _full_names(base, library)  # adjustable shocks named with every adjuster
    plant, vehicle, ident_model = _plant_and_vehicle(model, base, library)
    if ident_model is not None and session is None:
        raise PlannerError("an identified model needs the session it came from (its runs are "
                           "the prior information); pass session=")
    if session is not None and tuple(session.rig_inputs) != tuple(RIG_INPUTS):
        where = getattr(session, "path", None) or getattr(session, "name", "session")
        raise PlannerError(
            f"{where}: a session without aero channels (a 4-post rig: rig inputs "
            f"{list(session.rig_inputs)}) cannot be planned from yet: the design's information "
            f"is for the 7-post rig's 11 inputs; plan before rig day from the vehicle TOML "
            f"(--vehicle) instead")
    t0 = time.perf_counter()
    make = _drive_maker(vehicle, session)
    edges = np.geomspace(band_hz[0], band_hz[1], n_bands + 1)
    f_c = np.sqrt(edges[:-1] * edges[1:])
    if drives is None:
        drives = [make("track", 120.0, seed + 777, "validation-track")]
    drives = list(drives)
    cands = candidate_runs(library, base, rig=rig, kinds=kinds, durations_s=durations_s,
                           shocks=shocks, n_shocks=n_shocks, c_bar=plant.cbar_n_s_m,
                           click_levels=click_levels)
    cheapest = min(c.cost_min for c in cands)
    if budget_min < cheapest:
        raise PlannerError(f"a budget of {budget_min:g} min is shorter than one run (the "
                           f"cheapest candidate, {cands[0].name}, takes {cheapest:.3g} min); "
                           "give more time or shorter durations_s")
    setups = list(dict.fromkeys(c.setup for c in cands))
    ref_drives = {k: make(k, 120.0, seed + 1000 + j, f"reference {k}")
                  for j, k in enumerate(kinds)}
    info, powers = _candidate_information(plant, setups, list(kinds), ref_drives, library,
                                          edges, f_c)
    M0 = (_session_information(session, plant.cbar_n_s_m, edges) if session is not None
          else np.zeros((n_bands, 11, 11), dtype=complex))
    s_index = {s: i for i, s in enumerate(setups)}
    k_index = {k: j for j, k in enumerate(kinds)}
    Mc = np.stack([c.duration_s * info[s_index[c.setup], k_index[c.kind]] for c in cands])

    # validation runs: the current best setups on the team's drive, planned first
    val_setups = []
    if n_validation:
        pool = list(enumerate_setups(library))
        sc = screen_setups(plant, drives[0], [base] + [s for s in pool if s != base], library)
        ranked = score_setups(sc.table, objective, baseline=base.name).table.sort_values("rank")
        names = [n for n in ranked.index if n != base.name][:n_validation]
        by = {s.name: s for s in pool}
        val_setups = [_full_names(by[n], library) for n in names]
    val_info = None
    if val_setups:
        vi, _ = _candidate_information(plant, val_setups, ["validation"],
                                       {"validation": drives[0]}, library, edges, f_c)
        val_info = drives[0].duration_s * vi[:, 0]

    # scaling: unit diagonal of the whole candidate set's information per band
    total = _herm(M0 + Mc.sum(axis=0))
    dg = np.sqrt(np.maximum(np.real(np.einsum("kii->ki", total)), 1e-300))
    D = 1.0 / dg  # (nb, 11)

    def scale(M):
        return M * D[..., :, None] * D[..., None, :]

    Mc_s, M0_s = scale(Mc), scale(M0)
    _check_identifiable(scale(total), base, cands, library, plant, f_c)

    W_s = None
    if criterion == "decision":
        W_s = scale(_decision_w(plant, ident_model, library, base, objective, drives[0], f_c,
                                edges, M0, powers[0], noise, top))
    # the budget the identification runs may spend: validation and repeats come out of it
    reserve = 0.0
    val_cost = []
    for s in val_setups:
        val_cost.append(drives[0].duration_s / 60 + rig.run_overhead_min
                        + change_time_min(base, s, rig))
        reserve += val_cost[-1]
    short = min(durations_s) / 60 + rig.run_overhead_min
    if baseline_every:
        reserve += short * max(1, int(6 // baseline_every))
    budget_id = budget_min - reserve
    if budget_id < cheapest:
        raise PlannerError(f"the validation runs and baseline repeats leave {budget_id:.3g} min "
                           f"of {budget_min:g} for identification, less than one run; give more "
                           "time or fewer validation runs")
    cost = np.array([c.cost_min for c in cands])
    groups = np.array_split(np.arange(n_bands), n_design_bands)
    relaxed, val_relaxed, status, solve_s = _relaxed(Mc_s, M0_s, cost, budget_id, criterion,
                                                    W_s, groups)
    t_greedy = time.perf_counter()
    greedy_ref = greedy_design(Mc_s, M0_s, cands, base, rig, budget_id, criterion, W_s)
    greedy_s = time.perf_counter() - t_greedy
    # rounding: the relaxed counts rounded and fitted to the budget, then filled greedily;
    # the greedy is myopic (a two-corner swap can block the all-four one an identifying plan
    # needs), so it also starts from every one-run core that varies all four corners, and
    # the identifying plan with the best criterion wins
    starts = [[]]
    if relaxed is not None:
        counts = np.floor(relaxed + 0.5).astype(int)
        start = [c for c in np.flatnonzero(counts) for _ in range(counts[c])]
        order = _order([cands[c].setup for c in start], base, rig)
        starts.append(_fit_budget([start[k] for k in order], Mc_s, M0_s, cands, base, rig,
                                  budget_id, criterion, W_s))
    else:
        log.warning("design: the relaxed problem's status is %r; greedy designs stand in",
                    status)
    starts += [[c] for c, cand in enumerate(cands) if len(cand.changed) == 4
               and cand.duration_s == min(durations_s) and cand.cost_min <= budget_id]
    best = None
    for st in starts:
        seq = greedy_design(Mc_s, M0_s, cands, base, rig, budget_id, criterion, W_s, start=st)
        order = _order([cands[c].setup for c in seq], base, rig)  # the fill may have left swaps
        seq = greedy_design(Mc_s, M0_s, cands, base, rig, budget_id, criterion, W_s,
                            start=[seq[k] for k in order])
        M = M0_s + sum((Mc_s[c] for c in seq), np.zeros_like(M0_s))
        key = (_identifies(M), criterion_value(M, criterion, W_s))
        if best is None or key > best[0]:
            best = (key, seq)
    seq = best[1]
    if not seq:
        raise PlannerError(f"a budget of {budget_min:g} min buys no run that adds information; "
                           "give more time")
    plan_M = M0_s + sum(Mc_s[c] for c in seq)
    if val_info is not None:
        plan_M = plan_M + scale(val_info).sum(axis=0)
    _check_plan_identifiable(plan_M, budget_min, cands, rig)
    runs, drives_out, infos = _schedule(seq, cands, val_setups, base, rig, make, drives[0],
                                        baseline_every, min(durations_s), seed, Mc_s,
                                        val_info, scale)
    preds = _predictions(model, ident_model, runs, drives_out, library, objective)
    runs = _shares(runs, infos, M0_s, criterion, W_s)
    curve = _curve(runs, infos, M0_s, criterion, W_s)
    values = {"prior": criterion_value(M0_s, criterion, W_s) if session is not None else None,
              "relaxed": (criterion_value(M0_s + np.einsum("c,ckij->kij", relaxed, Mc_s),
                                          criterion, W_s) if relaxed is not None else None),
              "relaxed_design_bands": val_relaxed,
              "plan": float(curve["criterion"].iloc[-1]),
              "greedy": criterion_value(M0_s + sum((Mc_s[c] for c in greedy_ref),
                                                   np.zeros_like(M0_s)), criterion, W_s),
              "greedy_min": _seq_cost(greedy_ref, cands, base, rig)}
    chosen = np.bincount(np.asarray(seq, dtype=int), minlength=len(cands))
    relaxed_df = pd.DataFrame({"candidate": [c.name for c in cands],
                               "runs": relaxed if relaxed is not None else np.nan,
                               "cost_min": cost, "chosen": chosen}).set_index("candidate")
    total_min = runs[-1].start_min + runs[-1].duration_s / 60 if runs else 0.0
    solver = {"status": status, "solver": "CLARABEL", "solve_s": solve_s, "greedy_s": greedy_s,
              "design_s": time.perf_counter() - t0, "n_candidates": len(cands),
              "n_bands": n_bands, "n_design_bands": n_design_bands}
    settings = {"car": getattr(vehicle, "name", None) or getattr(ident_model, "name", "model"),
                "rig": rig.name, "date": date, "crate": library.source,
                "objective": objective.name, "budget_min": budget_min,
                "kinds": list(kinds), "durations_s": list(durations_s), "noise": noise,
                "baseline_every": baseline_every, "n_validation": n_validation,
                "session": getattr(session, "name", None), "band_hz": tuple(band_hz)}
    return ExperimentPlan(runs=tuple(runs), drives=drives_out, library=library, baseline=base,
                          criterion=criterion, budget_min=float(budget_min),
                          total_min=float(total_min), values=values, relaxed=relaxed_df,
                          predictions=preds, curve=curve, solver=solver, rig=rig,
                          settings=settings)


def _check_identifiable(total_s, base, cands, library, plant, f_c):
    """Refuse a candidate set (with the prior) that cannot identify all 11 inputs (Eq. 17)."""
    lam = np.linalg.eigvalsh(_herm(total_s))
    bad = lam[:, 0] < _RANK_TOL * np.maximum(lam[:, -1], 1e-300)
    if not bad.any():
        return
    diag = np.real(np.einsum("kii->ki", total_s))
    dead = [c for i, c in enumerate(CORNERS) if np.all(diag[:, 7 + i] < _RANK_TOL)]
    if dead:
        why = (f"corner(s) {dead}: no candidate run changes the shock force there (every crate "
               f"shock at those corners acts like the baseline's linear rate "
               f"{np.round(plant.cbar_n_s_m, 1).tolist()} N/(m/s), so dF = 0)")
    else:
        why = (f"at {np.round(f_c[bad][:3], 2).tolist()} Hz the shock forces of every "
               "candidate are the same linear function of the rig inputs")
    raise PlannerError(
        f"no plan from this crate can identify the shock inputs (seed paper Eq. 17): {why}; add "
        "to the crate a shock whose damping clearly differs from the baseline's (or a "
        "nonlinear one), or give a session whose runs already swap those corners")


def _identifies(M):
    """Whether scaled information matrices have full rank in every band."""
    lam = np.linalg.eigvalsh(_herm(M))
    return bool(np.all(lam[:, 0] >= _RANK_TOL * np.maximum(lam[:, -1], 1e-300)))


def _check_plan_identifiable(plan_M, budget, cands, rig):
    if _identifies(plan_M):
        return
    short = min(c.duration_s for c in cands) / 60 + rig.run_overhead_min
    need = 2 * short + 4 * rig.swap_min
    if budget < need:
        raise PlannerError(
            f"a budget of {budget:g} min cannot buy runs that identify all 11 inputs (Eq. 17: "
            f"the shock forces must vary apart from the rig inputs at every corner); the "
            f"baseline and one run with all four corners swapped take about {need:.0f} min "
            f"with this rig (swap {rig.swap_min:g} min a corner); give more time")
    # the time is there: the runs themselves do not separate the shock forces
    raise PlannerError(
        f"the runs a budget of {budget:g} min buys (the baseline and a four-corner swap take "
        f"about {need:.0f} min) still do not identify all 11 inputs at every band (Eq. 17): "
        "the crate's shocks give shock forces that do not vary apart from the rig inputs "
        "(shocks too alike, or a drive that saturates them: check the drive's units and "
        "level); add a shock unlike the baseline to the crate, or check the drive")


def _decision_w(plant, ident_model, library, base, objective, drive, f_c, edges, M0, S_ref,
                noise, top):
    """The decision criterion's weights (unscaled): the top contenders' score differences."""
    pool = [base] + [s for s in enumerate_setups(library) if s.ids() != base.ids()]
    sc = screen_setups(plant, drive, pool, library)
    scores = score_setups(sc.table, objective, baseline=base.name).table
    ranked = scores[scores["feasible"]].sort_values("rank").index[:top].tolist()
    idx = [list(sc.table.index).index(n) for n in ranked]
    sig = sc.diagnostics["shock_velocity_rms_linearized"][idx]
    models = [pool[i].resolve(library) for i in idx]
    sos = signal.butter(4, (1.0, 20.0), "bandpass", fs=drive.fs_hz, output="sos")

    def b4(f_hz):
        return np.abs(signal.sosfreqz(sos, worN=f_hz, fs=drive.fs_hz)[1]) ** 4

    _, SB = _band_power(np.vstack([drive.channels[c] - drive.channels[c].mean()
                                   for c in RIG_INPUTS]), drive.fs_hz, edges, weight=b4)
    H = plant.frequency_response(f_c)
    m_base = sc.table.loc[base.name].to_dict()
    grads = _score_gradients(H, plant.output_names, plant.cbar_n_s_m, f_c, SB, models, sig,
                             objective, m_base)
    frf = getattr(ident_model, "frf", None)
    noise_var = _noise_variance(plant, frf, f_c, edges, M0, S_ref, noise)
    s = scores.loc[ranked, "score"].to_numpy()
    pairs = list(itertools.combinations(range(len(ranked)), 2))
    return _decision_weights(grads, s, noise_var, pairs)


def _schedule(seq, cands, val_setups, base, rig, make, val_drive, baseline_every, short_s,
              seed, Mc_s, val_info, scale):
    """The planned runs in rig order: the identification sequence with baseline repeats
    every `baseline_every` runs, then the validation runs (fewest swaps); their drives and
    scaled information."""
    base_cand = {c.kind: i for i, c in enumerate(cands) if c.setup.ids() == base.ids()
                 and c.duration_s == short_s}
    long_s = max(c.duration_s for c in cands)
    blocks = []
    for c in seq:                       # runs of one setup in a row, by drive kind
        if blocks and cands[blocks[-1][0]].setup.ids() == cands[c].setup.ids():
            blocks[-1].append(c)
        else:
            blocks.append([c])
    kind_rank = {c.kind: k for k, c in reversed(list(enumerate(cands)))}
    groups = []
    for c in (c for b in blocks for c in sorted(b, key=lambda i: kind_rank[cands[i].kind])):
        # consecutive runs of one setup and drive kind play as one longer run (up to the
        # longest candidate duration): the same information, fewer starts on the rig
        g = groups[-1] if groups else None
        if (g is not None and cands[g[0]].setup.ids() == cands[c].setup.ids()
                and cands[g[0]].kind == cands[c].kind
                and sum(cands[i].duration_s for i in g) + cands[c].duration_s <= long_s):
            g.append(c)
        else:
            groups.append([c])
    items = []
    for k, g in enumerate(groups):
        if baseline_every and k and k % baseline_every == 0:
            items.append(("baseline repeat", [base_cand[cands[g[0]].kind]], None))
        items.append(("identification", g, None))
    if val_setups:
        last = cands[seq[-1]].setup if seq else base
        items += [("validation", None, j) for j in _order(val_setups, last, rig)]
    runs, drives, infos = [], {}, []
    t, prev = 0.0, base
    for n, (purpose, g, vj) in enumerate(items, 1):
        c = g[0] if g is not None else None
        setup = cands[c].setup if c is not None else val_setups[vj]
        dur = (sum(cands[i].duration_s for i in g) if c is not None
               else val_drive.duration_s)
        changed = tuple(k for k, a, b in zip(CORNERS, prev.ids(), setup.ids()) if a != b)
        clicks = []
        for k, a, b in zip(CORNERS, prev.ids(), setup.ids()):
            if a != b and _corner_change(a, b)[0] == 0:
                da, db = dict(_named_settings(a)[1]), dict(_named_settings(b)[1])
                clicks += [(k, adj) for adj in da if da[adj] != db[adj]]
        swap = rig.swap_min * (len(changed) - len({k for k, _ in clicks}))
        if clicks:
            swap += rig.click_change_min * len(clicks)
        start = t + swap + rig.run_overhead_min
        t, prev = start + dur / 60.0, setup
        if c is not None:
            label = "baseline" if setup.ids() == base.ids() else setup.name
            dname = f"run{n:02d}-{cands[c].kind}"
            drives[dname] = make(cands[c].kind, dur, seed + n, dname)
            kind = cands[c].kind
            infos.append(sum(Mc_s[i] for i in g))
        else:
            label = f"validation-{setup.name}"
            dname = re.sub(r"[^A-Za-z0-9_.-]+", "_", val_drive.name).strip("_") or "validation"
            drives[dname] = val_drive
            kind = "validation"
            infos.append(scale(val_info[vj]))
        runs.append(PlannedRun(number=n, name=f"run{n:02d}-{label}".replace("/", "-"),
                               setup=setup, purpose=purpose, drive=dname, kind=kind,
                               duration_s=float(dur), start_min=float(start), changed=changed,
                               swap_min=float(swap), share=0.0, clicks=tuple(clicks)))
    return runs, drives, infos


def _shares(runs, infos, M0_s, criterion, W_s):
    """Each run's share of the criterion: the loss when it is left out, shares summing to 1."""
    M_all = M0_s + sum(infos)
    full = criterion_value(M_all, criterion, W_s)
    loss = np.array([max(full - criterion_value(M_all - M, criterion, W_s), 0.0)
                     for M in infos])
    share = loss / loss.sum() if loss.sum() > 0 else np.full(len(runs), 1.0 / len(runs))
    return [PlannedRun(**{**r.__dict__, "share": float(sh)}) for r, sh in zip(runs, share)]


def _curve(runs, infos, M0_s, criterion, W_s):
    """The criterion after each run against the rig time at its end."""
    rows, M = [], M0_s.copy()
    rows.append({"run": 0, "time_min": 0.0, "criterion": criterion_value(M, criterion, W_s)})
    for r, info in zip(runs, infos):
        M = M + info
        rows.append({"run": r.number, "time_min": r.start_min + r.duration_s / 60,
                     "criterion": criterion_value(M, criterion, W_s)})
    return pd.DataFrame(rows)


def _predictions(model, ident_model, runs, drives, library, objective):
    """The key metrics predicted for every run on its own drive, with intervals (identified)."""
    keys = [m for m in objective.weights if objective.weights[m] > 0]
    rows = []
    for r in runs:
        setup = r.setup
        pred = predict_setups(model, drives[r.drive], [setup], library)
        t = pred.table
        if ident_model is not None:
            unc = prediction_uncertainty(ident_model, drives[r.drive], [setup], library,
                                         draws=UncertaintyOptions(n_draws=20), predictions=pred)
            t = unc.intervals(t)
        row = {"run": r.number}
        for m in keys:
            row[m] = float(t[m].iloc[0])
            if f"{m}_lo" in t:
                row[f"{m}_lo"] = float(t[f"{m}_lo"].iloc[0])
                row[f"{m}_hi"] = float(t[f"{m}_hi"].iloc[0])
        rows.append(row)
    return pd.DataFrame(rows).set_index("run")
