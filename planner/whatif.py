"""What-if studies: how setups' metrics, scores and ranks move when the car, the shocks or
the track are not what the model and drive say.

``evaluate_whatif(model, drives, setups, library, perturbations)`` evaluates every setup
under every perturbation of a :class:`PerturbationSet` (read from a perturbation TOML with
:func:`read_perturbations`, or built with :func:`perturbation_set`), scores each condition
with the objective against the baseline setup *in that condition*, and returns a
:class:`WhatIf`: per setup and condition each metric's change, the score and the rank;
a robust ranking (best mean score, best worst-case score) with the setups whose rank is
fragile flagged; and per-factor effects for tornado charts. :func:`write_whatif` writes
``whatif.xlsx``, CSVs, ``tornado/<setup>.png`` and ``rank_stability.png``.

Perturbations
-------------
``shock_scale``
    Force multiplier of the shocks at some corners or of some shock ids (dyno
    tolerance, fade): the scaled shocks (:meth:`ident.models.shocks.ShockModel.scaled`) are
    simulated by :func:`planner.predict.predict_setups`, the same code path as a
    prediction with a scaled library.
``shock_lag``
    Lag change [s] added to the shocks at some corners or of some ids.
``spring_rate`` / ``arb_rate``
    Spring wheel rate per corner, anti-roll bar rate per axle (at the wheels, the force
    at a wheel per metre of travel difference across the axle). On an identified model
    this is exact without re-identification: an elastic element across the shock's
    corner gives a force ``dK t`` (``t`` the shock travels, compression positive) on the
    same input as the shock force, so it joins the loop as a linear feedback from the
    model's shock-travel outputs to its shock-force inputs (:func:`stiffened_plant`).
    On a known vehicle model the parameters change (the physics itself).
``drive_scale``
    Amplitude multiplier of a channel group (``wheel``, ``aero``) or of named rig inputs.
``drive_window``
    A time window ``[start, end]`` of the drive [s]: a track section.
``drive_file``
    Another drive file (relative paths from the perturbation file).
``vehicle``
    Any parameter of the known vehicle model, by its vehicle-TOML key (masses,
    inertias, tire and spring rates, CG position, tracks, anti-roll bars, torsion):
    needs a known model (a vehicle TOML); an identified model cannot change a mass
    without re-identification, and says so.

Designs: ``one-at-a-time`` (each factor level alone), ``factorial`` (every combination
of levels) and ``monte-carlo`` (draws from each factor's distribution, uniform or
normal, independent per target with ``independent = true``; a factor with levels but no
distribution is drawn uniformly from its levels). The first condition is always the
nominal one (no change).

File format (``format = "shockplan-whatif/1"``)::

    format = "shockplan-whatif/1"
    units = "SI"                   # units of "add" changes of rates (N/m or lbf/in)
    design = "monte-carlo"         # "one-at-a-time" (default), "factorial", "monte-carlo"
    n_draws = 50                   # monte-carlo
    seed = 1

    [[factor]]
    name = "shock tolerance"
    kind = "shock_scale"
    corners = ["LF", "RF", "LR", "RR"]       # or shocks = ["B20", "DS"]
    independent = true
    levels = [0.95, 1.05]                    # one-at-a-time, factorial
    distribution = { kind = "uniform", low = 0.95, high = 1.05 }   # monte-carlo

    [[factor]]
    name = "rear springs"
    kind = "spring_rate"
    corners = ["LR", "RR"]
    change = "scale"                          # or "add" (a rate change, file units)
    levels = [0.9, 1.1]
    baseline_rate = 90000.0                   # identified models: the fitted car's rate

Where it runs: by default in this process, one condition group (the conditions sharing a
plant and a drive) after the other. With ``scheduler="local"`` (a
:class:`dask.distributed.LocalCluster`), a scheduler address or a ``client``, the groups,
cut into chunks of setups, are evaluated on Dask workers through the runner of
:mod:`planner.sweep`; the tables are the one-process tables bit for bit (see
:func:`evaluate_whatif`).

Scoring: in every condition the objective normalizes by the baseline setup evaluated in
that same condition, so a score says how much better than the team's baseline a setup
is on that car and track; ``max`` limits stay absolute. A setup's rank is *fragile*
when in more than ``fragile_share`` (10 %) of the conditions it moves more than
``rank_tolerance`` (1) place from its nominal rank.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ident.data.channels import AERO_INPUTS, CORNERS, RIG_INPUTS, WHEELLOADER_INPUTS
from planner.errors import PlannerError
from ident.data.units import check_units, to_si

__all__ = [
    "FACTOR_KINDS",
    "DESIGNS",
    "RANK_TOLERANCE",
    "FRAGILE_SHARE",
    "Factor",
    "Perturbation",
    "PerturbationSet",
    "WhatIf",
    "perturbation_set",
    "read_perturbations",
    "suspension_stiffness",
    "stiffened_plant",
    "evaluate_whatif",
    "factor_effects",
    "tornado_figure",
    "rank_stability_figure",
    "write_whatif",
]

log = logging.getLogger(__name__)

#: Factor kinds and their default change ("scale": multiply, "add": add to the value).
FACTOR_KINDS = {"shock_scale": "scale", "shock_lag": "add", "spring_rate": "scale",
                "arb_rate": "add", "drive_scale": "scale", "drive_window": "set",
                "drive_file": "set", "vehicle": "scale"}
#: Designs of a perturbation set.
DESIGNS = ("one-at-a-time", "factorial", "monte-carlo")
#: A rank moving more than this many places from the nominal one counts as a move (a
#: swap with a neighbour is a near-tie, which the ranking's intervals already flag).
RANK_TOLERANCE = 1
#: A setup whose rank moves (see RANK_TOLERANCE) in more than this share of the
#: conditions is fragile: one condition in ten reorders it past a neighbour.
FRAGILE_SHARE = 0.1
#: Largest number of conditions of a factorial design (guard against a typo exploding it).
MAX_CONDITIONS = 5000
#: A drive window shorter than this cannot resolve the 1 Hz end of the metric band with
#: the metric filter's transients [s].
MIN_WINDOW_S = 4.0
#: Channel groups of drive_scale.
CHANNEL_GROUPS = {"wheel": WHEELLOADER_INPUTS, "aero": AERO_INPUTS}
#: Axles of arb_rate.
AXLE_CORNERS = {"front": (0, 1), "rear": (2, 3)}
#: On a cluster: tasks per worker thread at least (condition groups cut into chunks), so
#: that none idles at the end.
TASKS_PER_THREAD = 4
#: On a cluster: fewest evaluations (setup x condition) a task is cut to, per method (a
#: task redoes the drive's rig response, about 0.1 s, or the screening operands).
MIN_TASK_EVALUATIONS = {"time": 32, "screening": 2000}
_TOP_KEYS = {"format", "units", "design", "n_draws", "seed", "factor", "name"}
_FACTOR_KEYS = {"name", "kind", "corners", "shocks", "axles", "channels", "parameter", "change",
                "levels", "distribution", "independent", "baseline_rate"}
_DIST_KEYS = {"uniform": ("low", "high"), "normal": ("mean", "sd")}
_FORMAT = "shockplan-whatif/1"


# ----------------------------------------------------------------------------------------------
# factors, perturbations
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Factor:
    """One thing that may change, with its levels and/or distribution (values SI).

    Attributes
    ----------
    name : str
    kind : str
        One of :data:`FACTOR_KINDS`.
    targets : tuple
        Corners (``shock_scale``, ``shock_lag``, ``spring_rate``), ``("id:<shock>", ...)``
        for shock ids, axles (``arb_rate``), rig inputs (``drive_scale``), the vehicle
        key (``vehicle``); empty for ``drive_window`` and ``drive_file``.
    change : {"scale", "add", "set"}, optional
        How a value acts: multiply, add (SI: N/m, s, the key's SI unit), or replace;
        default the kind's (:data:`FACTOR_KINDS`).
    levels : tuple
        Values of the one-at-a-time and factorial designs (floats; ``(start_s, end_s)``
        windows; :class:`ident.data.drive.Drive` for drive files).
    distribution : tuple or None
        ``("uniform", low, high)`` or ``("normal", mean, sd)`` (SI) for Monte Carlo.
    independent : bool
        Each target takes its own value (its own factor in one-at-a-time and factorial
        designs, its own draw in Monte Carlo).
    baseline_rate : ndarray or None
        The current rate per target [N/m] for a ``scale`` change of a rate on an
        identified model.
    """

    name: str
    kind: str
    targets: tuple = ()
    change: str | None = None
    levels: tuple = ()
    distribution: tuple | None = None
    independent: bool = False
    baseline_rate: np.ndarray | None = None

    def __post_init__(self):
        where = f"factor {self.name!r}"
        if self.kind not in FACTOR_KINDS:
            raise PlannerError(f"{where}: kind {self.kind!r} is unknown; use one of "
                               f"{sorted(FACTOR_KINDS)}")
        if self.change is None:
            object.__setattr__(self, "change", FACTOR_KINDS[self.kind])
        if self.change not in ("scale", "add", "set"):
            raise PlannerError(f"{where}: change {self.change!r} is unknown; use 'scale' or 'add'")
        if not self.levels and self.distribution is None:
            raise PlannerError(f"{where}: give levels = [...] (one-at-a-time, factorial) or a "
                               "distribution (monte-carlo)")
        object.__setattr__(self, "targets", tuple(self.targets))
        object.__setattr__(self, "levels", tuple(self.levels))

    @property
    def nominal(self):
        """The value that changes nothing (1 for scale, 0 for add, None for set)."""
        return {"scale": 1.0, "add": 0.0}.get(self.change)

    def atoms(self):
        """``(label, target indices)`` of the factors the design varies separately."""
        if self.independent and len(self.targets) > 1:
            return [(f"{self.name} {_target_label(t)}", (j,)) for j, t in enumerate(self.targets)]
        return [(self.name, tuple(range(max(len(self.targets), 1))))]


def _target_label(t):
    return t[3:] if isinstance(t, str) and t.startswith("id:") else str(t)


@dataclass(frozen=True, eq=False)
class Perturbation:
    """One condition: factor values.

    Attributes
    ----------
    name : str
    values : dict
        Factor name -> tuple of one value per target (or one value for the drive kinds).
        Factors not named keep their nominal value.
    """

    name: str
    values: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class PerturbationSet:
    """A what-if design: the factors and the conditions, the nominal one first.

    Attributes
    ----------
    factors : tuple of Factor
    perturbations : tuple of Perturbation
    design : str
    settings : dict
        ``n_draws``, ``seed``, ``source`` (the file), ``units``.
    """

    factors: tuple
    perturbations: tuple
    design: str
    settings: dict = field(default_factory=dict)

    def table(self):
        """One row per condition, one column per (factor, target) with its value.

        Returns
        -------
        pandas.DataFrame
            Index ``perturbation``; numeric values SI (multipliers for scale factors),
            windows as ``"start-end s"`` text, drive files by name.
        """
        rows = []
        for p in self.perturbations:
            row = {}
            for f in self.factors:
                vals = p.values.get(f.name)
                for j, (label, idx) in enumerate(f.atoms()):
                    v = f.nominal if vals is None else vals[idx[0]]
                    row[label] = _value_text(v)
            rows.append(row)
        return pd.DataFrame(rows, index=pd.Index([p.name for p in self.perturbations],
                                                 name="perturbation"))


def _value_text(v):
    if v is None:
        return "nominal"
    if isinstance(v, tuple) and len(v) == 2:
        return f"{v[0]:g}-{v[1]:g} s"
    if hasattr(v, "channels"):
        return v.name
    return float(v)


def _level_label(factor, v):
    if factor.kind == "drive_window":
        return f"{v[0]:g}-{v[1]:g} s"
    if factor.kind == "drive_file":
        return v.name
    if factor.change == "scale":
        return f"x{v:.4g}"
    unit = {"shock_lag": " s", "spring_rate": " N/m", "arb_rate": " N/m"}.get(factor.kind, "")
    return f"{v:+.4g}{unit}"


def perturbation_set(factors, *, design="one-at-a-time", n_draws=50, seed=0, settings=None):
    """Build the conditions of a design from factors.

    Parameters
    ----------
    factors : sequence of Factor
    design : {"one-at-a-time", "factorial", "monte-carlo"}
    n_draws : int
        Monte Carlo draws (besides the nominal condition).
    seed : int
        Monte Carlo seed (``numpy.random.default_rng``).

    Returns
    -------
    PerturbationSet
    """
    factors = tuple(factors)
    if not factors:
        raise PlannerError("a what-if needs at least one factor; add a [[factor]] table")
    names = [f.name for f in factors]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise PlannerError(f"factor name(s) {dup} appear twice; give each factor its own name")
    if design not in DESIGNS:
        raise PlannerError(f"design {design!r} is unknown; use one of {list(DESIGNS)}")
    nominal = Perturbation("nominal", {})
    out = [nominal]
    if design == "one-at-a-time":
        for f in factors:
            if not f.levels:
                raise PlannerError(f"factor {f.name!r}: the one-at-a-time design needs levels = "
                                   "[...]; add them or use design = 'monte-carlo'")
            for label, idx in f.atoms():
                for v in f.levels:
                    vals = [f.nominal] * max(len(f.targets), 1)
                    for j in idx or (0,):
                        vals[j] = v
                    out.append(Perturbation(f"{label} {_level_label(f, v)}",
                                            {f.name: tuple(vals)}))
    elif design == "factorial":
        atoms = []
        for f in factors:
            if not f.levels:
                raise PlannerError(f"factor {f.name!r}: the factorial design needs levels = "
                                   "[...]; add them or use design = 'monte-carlo'")
            atoms += [(f, label, idx) for label, idx in f.atoms()]
        n = math.prod(len(f.levels) for f, _, _ in atoms)
        if n > MAX_CONDITIONS:
            raise PlannerError(f"the factorial design has {n} conditions (more than "
                               f"{MAX_CONDITIONS}); use fewer levels or design = 'monte-carlo'")
        for combo in itertools.product(*[f.levels for f, _, _ in atoms]):
            vals = {f.name: [f.nominal] * max(len(f.targets), 1) for f in factors}
            parts = []
            for (f, label, idx), v in zip(atoms, combo):
                for j in idx or (0,):
                    vals[f.name][j] = v
                parts.append(f"{label} {_level_label(f, v)}")
            out.append(Perturbation(", ".join(parts), {k: tuple(v) for k, v in vals.items()}))
    else:
        if isinstance(n_draws, bool) or not isinstance(n_draws, (int, np.integer)) or n_draws < 1:
            raise PlannerError(f"n_draws must be a positive integer, got {n_draws!r}")
        rng = np.random.default_rng(seed)
        for k in range(int(n_draws)):
            vals = {}
            for f in factors:
                m = max(len(f.targets), 1)
                if f.distribution is None:
                    pick = rng.integers(len(f.levels), size=m if f.independent else 1)
                    v = [f.levels[i] for i in pick]
                else:
                    kind, a, b = f.distribution
                    size = m if f.independent else 1
                    v = list(rng.uniform(a, b, size) if kind == "uniform" else rng.normal(a, b, size))
                vals[f.name] = tuple(v if f.independent else v * m)
            out.append(Perturbation(f"draw {k + 1}", vals))
    st = {"n_draws": int(n_draws) if design == "monte-carlo" else None,
          "seed": seed if design == "monte-carlo" else None}
    st.update(settings or {})
    return PerturbationSet(factors=factors, perturbations=tuple(out), design=design, settings=st)


# ----------------------------------------------------------------------------------------------
# reading a perturbation file
# ----------------------------------------------------------------------------------------------

def _fail(where, key, problem, fix):
    return PlannerError(f"{where}: key {key!r} {problem}; {fix}")


def _number(where, key, x):
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise _fail(where, key, f"must be a finite number, got {x!r}", "write a number")
    return float(x)


def _vehicle_keys():
    from ident.models.vehicle import _KEYS

    return _KEYS


def _parse_factor(t, units, where, base_dir):
    from ident.data.drive import read_drive

    if not isinstance(t, dict):
        raise PlannerError(f"{where}: must be a table [[factor]]")
    unknown = sorted(set(t) - _FACTOR_KEYS)
    if unknown:
        raise _fail(where, unknown[0], "is unknown", f"known keys are {sorted(_FACTOR_KEYS)}")
    name = t.get("name")
    if not isinstance(name, str) or not name.strip():
        raise _fail(where, "name", f"must be a non-empty string, got {name!r}",
                    'name the factor, e.g. name = "rear springs"')
    where = f"{where} ({name!r})"
    kind = t.get("kind")
    if kind not in FACTOR_KINDS:
        raise _fail(where, "kind", f"= {kind!r} is unknown", f"use one of {sorted(FACTOR_KINDS)}")
    change = t.get("change", FACTOR_KINDS[kind])
    allowed = {"shock_scale": ("scale",), "shock_lag": ("add",), "spring_rate": ("scale", "add"),
               "arb_rate": ("add", "scale"), "drive_scale": ("scale",), "drive_window": ("set",),
               "drive_file": ("set",), "vehicle": ("scale", "add")}[kind]
    if change not in allowed:
        raise _fail(where, "change", f"= {change!r} does not apply to a {kind} factor",
                    f"use {' or '.join(repr(a) for a in allowed)}")
    # targets
    target_key = {"shock_scale": ("corners", "shocks"), "shock_lag": ("corners", "shocks"),
                  "spring_rate": ("corners",), "arb_rate": ("axles",),
                  "drive_scale": ("channels",), "vehicle": ("parameter",)}.get(kind, ())
    given = [k for k in ("corners", "shocks", "axles", "channels", "parameter") if k in t]
    wrong = [k for k in given if k not in target_key]
    if wrong:
        raise _fail(where, wrong[0], f"does not apply to a {kind} factor",
                    f"use {' or '.join(target_key) or 'no target key'}")
    if target_key and not given:
        raise _fail(where, target_key[0], "is missing", f"say which {target_key[0]} change")
    if len(given) > 1:
        raise _fail(where, given[1], f"and {given[0]!r} are both given", "give one of them")
    targets = ()
    qty = None
    if given:
        key = given[0]
        raw = t[key]
        if key == "parameter":
            vk = _vehicle_keys()
            if raw not in vk or raw in ("damping",):
                raise _fail(where, "parameter", f"= {raw!r} is not a vehicle parameter",
                            f"use a vehicle-TOML key: {sorted(k for k in vk if k != 'damping')}")
            qty = vk[raw][0]
            targets = (raw,)
        else:
            raw = [raw] if isinstance(raw, str) else raw
            if not isinstance(raw, list) or not raw or not all(isinstance(x, str) for x in raw):
                raise _fail(where, key, f"must be a list of names, got {t[key]!r}",
                            'write e.g. corners = ["LR", "RR"]')
            if key == "corners":
                bad = [c for c in raw if c not in CORNERS]
                if bad:
                    raise _fail(where, key, f"has unknown corner(s) {bad}",
                                f"use {list(CORNERS)}")
                targets = tuple(raw)
            elif key == "shocks":
                targets = tuple(f"id:{s}" for s in raw)
            elif key == "axles":
                bad = [a for a in raw if a not in AXLE_CORNERS]
                if bad:
                    raise _fail(where, key, f"has unknown axle(s) {bad}", "use 'front', 'rear'")
                targets = tuple(raw)
            else:
                chans = []
                for c in raw:
                    if c in CHANNEL_GROUPS:
                        chans += list(CHANNEL_GROUPS[c])
                    elif c in RIG_INPUTS:
                        chans.append(c)
                    else:
                        raise _fail(where, key, f"has {c!r}, neither a group nor a rig input",
                                    f"use {sorted(CHANNEL_GROUPS)} or {list(RIG_INPUTS)}")
                targets = tuple(dict.fromkeys(chans))
            if len(set(targets)) != len(targets):
                raise _fail(where, key, "names a target twice", "list each once")
    # unit of "add" values
    if change == "add":
        qty = {"shock_lag": None, "spring_rate": "stiffness", "arb_rate": "stiffness"}.get(kind,
                                                                                          qty)

    def value(x, key):
        v = _number(where, key, x)
        return to_si(v, qty, units) if (change == "add" and qty) else v

    levels = ()
    if "levels" in t:
        raw = t["levels"]
        if not isinstance(raw, list) or not raw:
            raise _fail(where, "levels", f"must be a non-empty list, got {raw!r}",
                        "write e.g. levels = [0.9, 1.1]")
        if kind == "drive_window":
            lv = []
            for w in raw:
                if (not isinstance(w, list) or len(w) != 2
                        or _number(where, "levels", w[0]) >= _number(where, "levels", w[1])):
                    raise _fail(where, "levels", f"has {w!r}, not a window [start, end] with "
                                "start < end", "write e.g. levels = [[0.0, 30.0], [30.0, 60.0]]"
                                " (seconds)")
                lv.append((float(w[0]), float(w[1])))
            levels = tuple(lv)
        elif kind == "drive_file":
            lv = []
            for p in raw:
                if not isinstance(p, str):
                    raise _fail(where, "levels", f"has {p!r}, not a file name",
                                'write e.g. levels = ["bumpy.csv"]')
                path = Path(p) if Path(p).is_absolute() else Path(base_dir) / p
                if not path.is_file():
                    raise _fail(where, "levels", f"names drive file {str(path)!r}, which does not "
                                "exist", "fix the path (relative to the perturbation file)")
                lv.append(read_drive(path, units=units))
            levels = tuple(lv)
        else:
            levels = tuple(value(x, "levels") for x in raw)
    distribution = None
    if "distribution" in t:
        if kind in ("drive_window", "drive_file"):
            raise _fail(where, "distribution", f"does not apply to a {kind} factor",
                        "give levels; a monte-carlo design draws among them")
        d = t["distribution"]
        if not isinstance(d, dict) or d.get("kind") not in _DIST_KEYS:
            raise _fail(where, "distribution", f"= {d!r} is not a distribution",
                        'write e.g. distribution = { kind = "uniform", low = 0.95, high = 1.05 } '
                        'or { kind = "normal", mean = 1.0, sd = 0.025 }')
        a_key, b_key = _DIST_KEYS[d["kind"]]
        extra = sorted(set(d) - {"kind", a_key, b_key})
        if extra or a_key not in d or b_key not in d:
            raise _fail(where, "distribution", f"of kind {d['kind']!r} needs {a_key!r} and "
                        f"{b_key!r} only", f"write {{ kind = {d['kind']!r}, {a_key} = ..., "
                        f"{b_key} = ... }}")
        a = value(d[a_key], f"distribution.{a_key}")
        b = _number(where, f"distribution.{b_key}", d[b_key])
        if d["kind"] == "uniform":
            b = value(d[b_key], f"distribution.{b_key}")
            if not a < b:
                raise _fail(where, "distribution", f"has low {a:g} >= high {b:g}",
                            "give low < high")
        else:
            b = to_si(b, qty, units) if (change == "add" and qty) else b
            if not b > 0:
                raise _fail(where, "distribution.sd", f"= {b:g} is not positive",
                            "give a positive standard deviation")
        distribution = (d["kind"], a, b)
    independent = t.get("independent", False)
    if not isinstance(independent, bool):
        raise _fail(where, "independent", f"must be true or false, got {independent!r}",
                    "write independent = true")
    if change == "scale":
        vals = list(levels) if kind not in ("drive_window", "drive_file") else []
        if distribution is not None and distribution[0] == "uniform":
            vals += [distribution[1], distribution[2]]
        bad = [v for v in vals if not v > 0]
        if bad and kind != "drive_scale":
            raise _fail(where, "levels" if levels and bad[0] in levels else "distribution",
                        f"has the multiplier {bad[0]:g}", "give multipliers > 0 (1 = no change)")
        if bad and kind == "drive_scale" and any(v < 0 for v in bad):
            raise _fail(where, "levels", f"has the multiplier {bad[0]:g}",
                        "give multipliers >= 0 (1 = no change)")
    baseline_rate = None
    if "baseline_rate" in t:
        if kind not in ("spring_rate", "arb_rate") or change != "scale":
            raise _fail(where, "baseline_rate", "applies only to a spring_rate or arb_rate factor "
                        "with change = 'scale'", "remove it")
        raw = t["baseline_rate"]
        raw = [raw] * len(targets) if not isinstance(raw, list) else raw
        if len(raw) != len(targets):
            raise _fail(where, "baseline_rate", f"has {len(raw)} values for {len(targets)} "
                        "targets", "give one rate, or one per target")
        baseline_rate = np.array([to_si(_number(where, "baseline_rate", x), "stiffness", units)
                                  for x in raw])
        if np.any(baseline_rate <= 0):
            raise _fail(where, "baseline_rate", "is not positive", "give the current rate(s)")
    return Factor(name=name.strip(), kind=kind, targets=targets, change=change, levels=levels,
                  distribution=distribution, independent=independent,
                  baseline_rate=baseline_rate)


def read_perturbations(path):
    """Read a perturbation TOML file (``format = "shockplan-whatif/1"``).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    PerturbationSet

    Raises
    ------
    PlannerError
        On a missing or malformed file, an unknown key, kind, corner, channel or vehicle
        parameter, a non-positive multiplier, a bad window or a missing drive file: the
        message names the file, the factor and the key.
    """
    from ident.data.files import read_toml

    path = Path(path)
    doc = read_toml(path, error=PlannerError, what="perturbation file")
    where = str(path)
    fmt = doc.get("format")
    if fmt != _FORMAT:
        raise _fail(where, "format", f"= {fmt!r}", f'write format = "{_FORMAT}" first')
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise _fail(where, unknown[0], "is unknown", f"known keys are {sorted(_TOP_KEYS)}")
    units = check_units(doc.get("units", "SI"), where=f"{where}: key 'units'", error=PlannerError)
    design = doc.get("design", "one-at-a-time")
    if design not in DESIGNS:
        raise _fail(where, "design", f"= {design!r} is unknown", f"use one of {list(DESIGNS)}")
    n_draws = doc.get("n_draws", 50)
    seed = doc.get("seed", 0)
    for key, val in (("n_draws", n_draws), ("seed", seed)):
        if isinstance(val, bool) or not isinstance(val, int) or val < (1 if key == "n_draws" else 0):
            raise _fail(where, key, f"= {val!r} is not a {'positive' if key == 'n_draws' else 'non-negative'} integer",
                        "write a whole number")
    tables = doc.get("factor")
    if not isinstance(tables, list) or not tables:
        raise _fail(where, "factor", "is missing", "add at least one [[factor]] table")
    factors = [_parse_factor(t, units, f"{where}: factor {j + 1}", path.parent)
               for j, t in enumerate(tables)]
    if design != "monte-carlo":
        for f in factors:
            if not f.levels:
                raise _fail(f"{where}: factor {f.name!r}", "levels", f"is missing (design "
                            f"{design!r})", "give levels = [...] or use design = 'monte-carlo'")
    if sum(f.kind == "drive_file" for f in factors) > 1:
        raise _fail(where, "factor", "has more than one drive_file factor",
                    "put all drive files in one factor's levels")
    return perturbation_set(factors, design=design, n_draws=n_draws, seed=seed,
                            settings={"source": str(path), "units": units})


# ----------------------------------------------------------------------------------------------
# applying a condition
# ----------------------------------------------------------------------------------------------

def suspension_stiffness(spring_n_m=None, arb_n_m=None):
    """The stiffness matrix ``dK`` [N/m], shape (4, 4), of spring and anti-roll bar changes.

    Parameters
    ----------
    spring_n_m : array_like, shape (4,), optional
        Spring wheel-rate change per corner LF, RF, LR, RR [N/m].
    arb_n_m : array_like, shape (2,), optional
        Anti-roll bar rate change per axle (front, rear) [N/m]: ``k [[1, -1], [-1, 1]]``
        on the axle's corners.

    Examples
    --------
    >>> suspension_stiffness(arb_n_m=[1000.0, 0.0])[:2, :2].tolist()
    [[1000.0, -1000.0], [-1000.0, 1000.0]]
    """
    K = np.diag(np.zeros(4) if spring_n_m is None else np.asarray(spring_n_m, float))
    if arb_n_m is not None:
        for k, (l, r) in zip(np.asarray(arb_n_m, float), AXLE_CORNERS.values()):
            K[np.ix_([l, r], [l, r])] += k * np.array([[1.0, -1.0], [-1.0, 1.0]])
    return K


def stiffened_plant(plant, *, spring_n_m=None, arb_n_m=None, name=None):
    """A loop plant with extra elastic elements between wheels and chassis (springs, bars).

    An elastic element across a shock's corner acts on the shock-force input: the applied
    force becomes ``F = f(v) + dK t`` with ``t`` the shock travels (compression positive),
    so the element closes a linear feedback from the plant's shock-travel outputs to its
    shock-force inputs. Exact for any linear plant, identified or known.

    Parameters
    ----------
    plant : ident.sim.closedloop.LoopPlant
        Must have the outputs ``shock_travel_XX``.
    spring_n_m : array_like, shape (4,), optional
        Spring wheel-rate change per corner LF, RF, LR, RR [N/m].
    arb_n_m : array_like, shape (2,), optional
        Anti-roll bar rate change per axle (front, rear) [N/m]; see
        :func:`suspension_stiffness`. The force at corner i is ``sum_j dK[i, j] t_j``.

    Returns
    -------
    ident.sim.closedloop.LoopPlant
        The rig part is the series connection of the rig part and the stiffened shock
        part (a spring transmits rig-driven travel as a force); the ``spring_force_XX``
        outputs (if any, the coil's force) include the spring changes, not the bars.

    Raises
    ------
    PlannerError
        If the plant has no shock-travel outputs, or the stiffened loop cannot be put
        in modal form (repeated poles).
    """
    from ident.sim.closedloop import LoopPlant, modal_form

    for what, v, n in (("spring_n_m", spring_n_m, 4), ("arb_n_m", arb_n_m, 2)):
        if v is not None and (np.shape(v) != (n,) or not np.all(np.isfinite(v))):
            raise ValueError(f"{what} must be {n} finite values [N/m], got {v!r}")
    K = suspension_stiffness(spring_n_m, arb_n_m)
    ks = np.zeros(4) if spring_n_m is None else np.asarray(spring_n_m, float)
    names = tuple(plant.output_names)
    missing = [f"shock_travel_{c}" for c in CORNERS if f"shock_travel_{c}" not in names]
    if missing:
        raise PlannerError(f"plant {plant.name!r}: no outputs {missing}; a spring or anti-roll "
                           "bar what-if acts through the shock travel, so identify a model with "
                           "the shock-travel channels")
    ti = [names.index(f"shock_travel_{c}") for c in CORNERS]
    As, Bs, Cs, Ds = plant.shock.to_real()
    Ar, Br, Cr, Dr = plant.rig.to_real()
    # the spring-force outputs carry the added springs (diagonal), before the feedback
    Cs, Ds, Cr, Dr = Cs.copy(), Ds.copy(), Cr.copy(), Dr.copy()
    for j, c in enumerate(CORNERS):
        if f"spring_force_{c}" in names:
            k = names.index(f"spring_force_{c}")
            Cs[k] += ks[j] * Cs[ti[j]]
            Ds[k] += ks[j] * Ds[ti[j]]
            Cr[k] += ks[j] * Cr[ti[j]]
            Dr[k] += ks[j] * Dr[ti[j]]
    Dt = Ds[ti]
    try:
        M = np.linalg.inv(np.eye(4) - K @ Dt)
    except np.linalg.LinAlgError:
        raise PlannerError("the stiffened loop is singular (travel feedthrough); check the "
                           "stiffness change") from None
    MK = M @ K
    As2, Bs2 = As + Bs @ MK @ Cs[ti], Bs @ M
    Cs2, Ds2 = Cs + Ds @ MK @ Cs[ti], Ds @ M
    nr, ns = Ar.shape[0], As.shape[0]
    A = np.block([[Ar, np.zeros((nr, ns))], [Bs @ MK @ Cr[ti], As2]])
    B = np.vstack([Br, Bs @ MK @ Dr[ti]])
    C = np.hstack([Cr + Ds @ MK @ Cr[ti], Cs2])
    D = Dr + Ds @ MK @ Dr[ti]
    try:
        rig = modal_form(A, B, C, D).pruned()
        shock = modal_form(As2, Bs2, Cs2, Ds2).pruned()
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise PlannerError(f"plant {plant.name!r}: the stiffened loop has no modal form ({exc}); "
                           "the change moves poles onto each other, try a slightly other "
                           "value") from None
    if np.any(shock.lam.real > 0) or np.any(rig.lam.real > 0):
        raise PlannerError(f"plant {plant.name!r}: the stiffness change {np.diag(K)} N/m makes "
                           "the car unstable (a negative net rate); check its sign and size")
    return LoopPlant(rig, shock, names, plant.cbar_n_s_m,
                     name=name or f"{plant.name} (stiffened)")


@dataclass(frozen=True)
class _Effect:
    """The accumulated change of one condition (SI)."""

    corner_scale: np.ndarray       # (4,)
    id_scale: dict
    corner_lag: np.ndarray         # (4,) added [s]
    id_lag: dict
    spring_add: np.ndarray         # (4,) [N/m]
    spring_scale: np.ndarray       # (4,) multiplier of the known rate
    arb_add: np.ndarray            # (2,) [N/m]
    arb_scale: np.ndarray          # (2,)
    vehicle: tuple                 # ((key, change, value), ...)
    channel_scale: np.ndarray      # (7,)
    window: tuple | None
    drive: object | None


def _effect(perturbation, factors):
    e = dict(corner_scale=np.ones(4), id_scale={}, corner_lag=np.zeros(4), id_lag={},
             spring_add=np.zeros(4), spring_scale=np.ones(4), arb_add=np.zeros(2),
             arb_scale=np.ones(2), vehicle=[], channel_scale=np.ones(7), window=None, drive=None)
    for f in factors:
        vals = perturbation.values.get(f.name)
        if vals is None:
            continue
        for j, t in enumerate(f.targets or (None,)):
            v = vals[j] if j < len(vals) else vals[0]
            if f.kind in ("shock_scale", "shock_lag"):
                key = "scale" if f.kind == "shock_scale" else "lag"
                if isinstance(t, str) and t.startswith("id:"):
                    d = e[f"id_{key}"]
                    d[t[3:]] = d.get(t[3:], 1.0 if key == "scale" else 0.0)
                    d[t[3:]] = d[t[3:]] * v if key == "scale" else d[t[3:]] + v
                else:
                    i = CORNERS.index(t)
                    if key == "scale":
                        e["corner_scale"][i] *= v
                    else:
                        e["corner_lag"][i] += v
            elif f.kind == "spring_rate":
                i = CORNERS.index(t)
                if f.change == "add":
                    e["spring_add"][i] += v
                elif f.baseline_rate is not None:
                    e["spring_add"][i] += (v - 1.0) * f.baseline_rate[j]
                else:
                    e["spring_scale"][i] *= v
            elif f.kind == "arb_rate":
                a = list(AXLE_CORNERS).index(t)
                if f.change == "add":
                    e["arb_add"][a] += v
                elif f.baseline_rate is not None:
                    e["arb_add"][a] += (v - 1.0) * f.baseline_rate[j]
                else:
                    e["arb_scale"][a] *= v
            elif f.kind == "drive_scale":
                e["channel_scale"][RIG_INPUTS.index(t)] *= v
            elif f.kind == "drive_window":
                e["window"] = v
            elif f.kind == "drive_file":
                e["drive"] = v
            elif f.kind == "vehicle":
                e["vehicle"].append((t, f.change, v, f.name))
    e["vehicle"] = tuple(e["vehicle"])
    return _Effect(**e)


def _plant_key(e):
    return (tuple(np.round(e.spring_add, 9)), tuple(np.round(e.spring_scale, 12)),
            tuple(np.round(e.arb_add, 9)), tuple(np.round(e.arb_scale, 12)),
            tuple((k, c, round(float(v), 12)) for k, c, v, _ in e.vehicle))


def _drive_key(e):
    return (tuple(np.round(e.channel_scale, 12)), e.window,
            None if e.drive is None else id(e.drive))


def _known_params(model):
    from ident.models.vehicle import FullCarModel, VehicleParams

    if isinstance(model, VehicleParams):
        return model
    if isinstance(model, FullCarModel):
        return model.params
    return None


_VEHICLE_ATTR = {  # vehicle-TOML key -> (attribute, indices or None)
    "track": (("track_front_m", None), ("track_rear_m", None)),
    "track_front": (("track_front_m", None),),
    "track_rear": (("track_rear_m", None),),
    "cg_lateral_offset": (("cg_lateral_offset_m", None),),
    "cg_to_front_axle": (("a_m", None),),
    "cg_to_rear_axle": (("b_m", None),),
    "sprung_mass": (("sprung_mass_kg", None),),
    "roll_inertia": (("roll_inertia_kg_m2", None),),
    "pitch_inertia": (("pitch_inertia_kg_m2", None),),
    "front_unsprung_mass": (("unsprung_mass_kg", (0, 1)),),
    "rear_unsprung_mass": (("unsprung_mass_kg", (2, 3)),),
    "front_spring_rate": (("spring_rate_n_m", (0, 1)),),
    "rear_spring_rate": (("spring_rate_n_m", (2, 3)),),
    "tire_stiffness": (("tire_rate_n_m", (0, 1, 2, 3)),),
    "front_tire_stiffness": (("tire_rate_n_m", (0, 1)),),
    "rear_tire_stiffness": (("tire_rate_n_m", (2, 3)),),
    "torsion_stiffness": (("torsion_stiffness_n_m_rad", None),),
    "torsion_inertia": (("torsion_inertia_kg_m2", None),),
    "tire_damping": (("tire_damping_n_s_m", (0, 1, 2, 3)),),
    "front_tire_damping": (("tire_damping_n_s_m", (0, 1)),),
    "rear_tire_damping": (("tire_damping_n_s_m", (2, 3)),),
    "tire_damping_corner": (("tire_damping_corner_hz", None),),
    "front_arb_rate": (("arb_rate_n_m", (0,)),),
    "rear_arb_rate": (("arb_rate_n_m", (1,)),),
}


def _changed_params(params, e, where):
    """The known vehicle with a condition's spring, bar and parameter changes."""
    from ident.errors import VehicleError

    changes = {}

    def current(attr):
        if attr in changes:
            return changes[attr]
        v = getattr(params, attr)
        if v is None and attr in ("arb_rate_n_m", "tire_damping_n_s_m"):
            v = np.zeros(2 if attr == "arb_rate_n_m" else 4)
        return None if v is None else np.array(v, dtype=float)

    k = current("spring_rate_n_m") * e.spring_scale + e.spring_add
    changes["spring_rate_n_m"] = k
    arb = current("arb_rate_n_m") * e.arb_scale + e.arb_add
    if np.any(arb != 0) or params.arb_rate_n_m is not None:
        changes["arb_rate_n_m"] = arb
    for key, change, v, fname in e.vehicle:
        for attr, idx in _VEHICLE_ATTR[key]:
            cur = current(attr)
            if cur is None:
                raise PlannerError(f"{where}: factor {fname!r} key 'parameter' = {key!r}: the "
                                   "vehicle has no such element to change; give it in the "
                                   "vehicle file first")
            if idx is None:
                cur = float(cur) * v if change == "scale" else float(cur) + v
            else:
                cur = cur.copy()
                cur[list(idx)] = cur[list(idx)] * v if change == "scale" else cur[list(idx)] + v
            changes[attr] = cur
    for attr, val in changes.items():
        if np.any(np.asarray(val, dtype=float) < 0):
            key = {"spring_rate_n_m": "spring_rate", "arb_rate_n_m": "arb_rate"}.get(attr, attr)
            raise PlannerError(f"{where}: the change makes {key} negative "
                               f"({np.round(np.asarray(val, float), 1).tolist()}); reduce the "
                               "change (a rate cannot be below zero)")
    try:
        return params.replace(**changes)
    except VehicleError as exc:
        raise PlannerError(f"{where}: the changed vehicle is not valid: {exc}") from None


def _condition_plant(model, base_plant, e, where, nominal_rates):
    """The loop plant of a condition (the model's own when nothing structural changes)."""
    from ident.models.vehicle import build_full_car

    params = _known_params(model)
    structural = (np.any(e.spring_add) or np.any(e.spring_scale != 1) or np.any(e.arb_add)
                  or np.any(e.arb_scale != 1) or e.vehicle)
    if not structural:
        return base_plant
    if params is not None:
        p2 = _changed_params(params, e, where)
        return build_full_car(p2).loop_plant(cbar_n_s_m=base_plant.cbar_n_s_m)
    if e.vehicle:
        key = e.vehicle[0][0]
        raise PlannerError(f"{where}: factor {e.vehicle[0][3]!r} key 'parameter' = {key!r} "
                           "needs a known vehicle model (a vehicle TOML); an identified model "
                           "cannot change it without re-identification (springs and anti-roll "
                           "bars can: use a spring_rate or arb_rate factor)")
    if np.any(e.spring_scale != 1) or np.any(e.arb_scale != 1):
        raise PlannerError(f"{where}: a spring_rate or arb_rate factor with change = 'scale' on an "
                           "identified model needs the current rates: add baseline_rate = ... "
                           "(N/m or lbf/in per the file's units) or use change = 'add'")
    if nominal_rates is not None:
        net = np.asarray(nominal_rates, float) + e.spring_add
        if np.any(net < 0):
            raise PlannerError(f"{where}: the change makes a spring rate negative "
                               f"({np.round(net, 1).tolist()} N/m); reduce the change")
    return stiffened_plant(base_plant, spring_n_m=e.spring_add, arb_n_m=e.arb_add,
                           name=f"{base_plant.name} [{where}]")


def _condition_drive(drive, e, where):
    from ident.data.drive import Drive

    if e.drive is not None:
        drive = e.drive
    if e.window is not None:
        t0, t1 = e.window
        if t0 < 0 or t1 > drive.duration_s + 0.5 / drive.fs_hz:
            raise PlannerError(f"{where}: key 'levels': window {t0:g}-{t1:g} s is outside drive "
                               f"{drive.name!r} (0-{drive.duration_s:g} s); give a window within "
                               "the drive")
        if t1 - t0 < MIN_WINDOW_S:
            raise PlannerError(f"{where}: key 'levels': window {t0:g}-{t1:g} s is shorter than "
                               f"{MIN_WINDOW_S:g} s; the 1 Hz end of the metric band needs a "
                               "longer section")
        a, b = int(round(t0 * drive.fs_hz)), int(round(t1 * drive.fs_hz))
        drive = Drive(f"{drive.name} [{t0:g}-{t1:g} s]", drive.fs_hz,
                      {c: drive.channels[c][a:b] for c in drive.rig_inputs},
                      settings={**drive.settings, "window_s": (t0, t1)})
    if np.any(e.channel_scale != 1):
        s = dict(zip(RIG_INPUTS, e.channel_scale))
        drive = Drive(f"{drive.name} [scaled]", drive.fs_hz,
                      {c: drive.channels[c] * s[c] for c in drive.rig_inputs},
                      settings={**drive.settings, "scale": s})
    return drive


class _ShockVariants:
    """Derived shocks of the conditions (scaled, lagged), shared between identical ones."""

    def __init__(self, library):
        self.library = library
        self.extra = {}
        self._key = {}

    def model_id(self, shock_id, scale, lag_add):
        if scale == 1.0 and lag_add == 0.0:
            return shock_id
        key = (shock_id, round(float(scale), 14), round(float(lag_add), 14))
        if key not in self._key:
            base = self.library.get(shock_id)
            lag = base.lag_s + lag_add
            if lag < 0:
                raise PlannerError(f"shock {shock_id!r}: the lag change {lag_add:g} s makes its "
                                   f"lag {lag:g} s negative; reduce the change")
            new_id = f"{shock_id}~{len(self._key) + 1}"
            self.extra[new_id] = base.scaled(scale, lag_s=lag, id=new_id)
            self._key[key] = new_id
        return self._key[key]

    def full_library(self):
        from ident.models.shocks import ShockLibrary

        return ShockLibrary(list(self.library.values()) + list(self.extra.values()),
                            source=self.library.source)


def _condition_setups(setups, e, variants, tag):
    from planner.setups import Setup

    out = []
    for s in setups:
        ids = {}
        for i, c in enumerate(CORNERS):
            sid = s.ids()[i]
            scale = e.corner_scale[i] * e.id_scale.get(sid, 1.0)
            lag = e.corner_lag[i] + e.id_lag.get(sid, 0.0)
            ids[c] = variants.model_id(sid, scale, lag)
        out.append(Setup(f"{s.name}\x1f{tag}", ids))
    return out


# ----------------------------------------------------------------------------------------------
# evaluation
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class WhatIf:
    """The result of :func:`evaluate_whatif`.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per (drive, perturbation, setup): ``drive``, ``perturbation``,
        ``setup``, the shock ids, the metrics (SI), ``score``, ``score_<group>``,
        ``feasible``, ``violations``, ``rank`` (within the condition),
        ``score_change`` and ``rank_change`` against the same setup's nominal condition
        (the first drive, no perturbation), and ``<metric>_change_pct``.
    robust : pandas.DataFrame
        One row per setup, best mean score first: ``nominal_rank``, ``nominal_score``,
        ``mean_score``, ``worst_score``, ``mean_rank``, ``best_rank``, ``worst_rank``,
        ``best_share`` (share of conditions it ranks first), ``moved_share`` (share of
        conditions its rank moves more than ``rank_tolerance`` places),
        ``feasible_share``, ``fragile``, ``rank_mean_score``, ``rank_worst_score``.
    perturbations : PerturbationSet
    conditions : pandas.DataFrame
        One row per condition (``drive``, ``perturbation``) with the factor values.
    baseline : str
    objective : planner.objective.Objective
    settings : dict
        ``method``, ``oversample``, ``band_hz``, ``rank_tolerance``, ``fragile_share``,
        ``n_evaluations``, ``elapsed_s``, ``model``, ``drives``; where it ran:
        ``scheduler`` (``"none"``, ``"local"``, ``"address"`` or ``"client"``),
        ``address``, ``n_workers`` and ``n_tasks`` (neither these nor the timings are
        written to the files).
    """

    table: pd.DataFrame
    robust: pd.DataFrame
    perturbations: PerturbationSet
    conditions: pd.DataFrame
    baseline: str
    objective: object
    settings: dict = field(default_factory=dict)

    @property
    def fragile(self):
        """Names of the setups whose rank is fragile, in robust order."""
        return list(self.robust.index[self.robust["fragile"]])

    def condition(self, perturbation="nominal", drive=None):
        """The rows of one condition (default the nominal one), indexed by setup."""
        d = self.settings["drives"][0] if drive is None else drive
        t = self.table[(self.table["perturbation"] == perturbation) & (self.table["drive"] == d)]
        if t.empty:
            raise PlannerError(f"no condition ({d!r}, {perturbation!r}); conditions are "
                               f"{self.conditions.index.tolist()[:5]}...")
        return t.set_index("setup")


def _as_drives(drives):
    from ident.data.drive import Drive

    if isinstance(drives, Drive):
        return [drives]
    drives = list(drives)
    if not drives or not all(isinstance(d, Drive) for d in drives):
        raise TypeError("drives must be an ident.data.drive.Drive or a non-empty sequence of them")
    names = [d.name for d in drives]
    if len(set(names)) != len(names):
        raise PlannerError(f"the drives' names {names} repeat; give each drive its own name")
    return drives


def _evaluate_group(plant, drive, setups, library, method, oversample, band_hz):
    """Metrics of one condition group's setups (a list of condition setups), SI.

    Returns
    -------
    pandas.DataFrame
        :func:`planner.predict.predict_setups`' (``method="time"``) or
        :func:`planner.screen.screen_setups`' table: one row per setup, in order.
    """
    from planner.predict import predict_setups
    from planner.screen import screen_setups

    if method == "time":
        return predict_setups(plant, drive, setups, library, oversample=oversample,
                              band_hz=band_hz).table
    return screen_setups(plant, drive, setups, library, band_hz=band_hz).table


def _group_setups(setups, members, effects, variants):
    """The setups of a condition group: every setup under every member condition."""
    cond_setups = []
    for (dj, pj) in members:
        cond_setups += _condition_setups(setups, effects[pj], variants, f"{dj}:{pj}")
    return cond_setups


def _group_table(pred_table, by_name, drives, perturbations):
    """A group's rows of the what-if table from its metrics table (names carry the tags)."""
    t = pred_table.copy()
    t.insert(0, "setup", [n.split("\x1f")[0] for n in t.index])
    tag = [n.split("\x1f")[1] for n in t.index]
    t.insert(0, "perturbation", [perturbations.perturbations[int(x.split(":")[1])].name
                                 for x in tag])
    t.insert(0, "drive", [drives[int(x.split(":")[0])].name for x in tag])
    # the table's shock ids: the setup's own (the variants are internal)
    for i, c in enumerate(CORNERS):
        t[c] = [by_name[n].ids()[i] for n in t["setup"]]
    t["_order"] = [int(x.split(":")[0]) * 10**7 + int(x.split(":")[1]) for x in tag]
    return t


def _blas_threads():
    """This process's BLAS thread count per library prefix (``threadpoolctl``)."""
    from threadpoolctl import threadpool_info

    return {i["prefix"]: int(i["num_threads"]) for i in threadpool_info()
            if i.get("user_api") == "blas"}


def _whatif_task(plant, drive, effect, where, setups, library, extra, method, oversample,
                 band_hz, blas):
    """Metrics of a chunk of a condition group's setups (a task on a Dask worker).

    Parameters
    ----------
    plant : ident.sim.closedloop.LoopPlant
        The condition's plant (built by the client).
    drive : ident.data.drive.Drive
        The prepared nominal drive; the condition's drive is derived here
        (:func:`_condition_drive`: a window, channel scales, elementwise).
    effect : _Effect
    where : str
        The condition's name for error messages.
    setups : list of planner.setups.Setup, shape (n,)
        Condition setups (names ``"<setup>\\x1f<drive>:<perturbation>"``).
    library : ident.models.shocks.ShockLibrary
        The crate.
    extra : list of ident.models.shocks.ShockModel
        The scaled or lagged shocks `setups` use.
    method, oversample, band_hz
        As :func:`evaluate_whatif`.
    blas : dict of str -> int
        The client's BLAS threads per library: the screening operands' products differ
        in the last bits with the BLAS thread count, so the worker uses the client's (a
        Dask worker process starts with one).

    Returns
    -------
    pandas.DataFrame, shape (n, 4 + n_metrics)
        The metrics only (no time histories).
    """
    from threadpoolctl import threadpool_limits

    from ident.models.shocks import ShockLibrary
    from planner.sweep import _KERNEL_LOCK

    lib = ShockLibrary(list(library.values()) + list(extra), source=library.source) \
        if extra else library
    with _KERNEL_LOCK:
        drive = _condition_drive(drive, effect, where)
        with threadpool_limits(limits=blas):
            return _evaluate_group(plant, drive, setups, lib, method, oversample, band_hz)


class _LazyTasks:
    """Task arguments built when the runner submits them (bounded memory on the client)."""

    def __init__(self, specs, make):
        self.specs = specs
        self.make = make

    def __len__(self):
        return len(self.specs)

    def __iter__(self):
        return (self.make(*spec) for spec in self.specs)


def _is_serial(scheduler, client):
    """True when `scheduler`/`client` ask for this process only (the default)."""
    from planner.sweep import SCHEDULER_NONE

    return client is None and (scheduler is None or (
        isinstance(scheduler, str) and scheduler.strip().lower() in SCHEDULER_NONE))


def _task_specs(sizes, chunk):
    """``(group, start, stop)`` of every task: each group cut into near-equal chunks."""
    specs = []
    for g, n in enumerate(sizes):
        step = math.ceil(n / math.ceil(n / chunk))
        specs += [(g, a, min(a + step, n)) for a in range(0, n, step)]
    return specs


def evaluate_whatif(model, drives, setups, library, perturbations, *, objective=None,
                    baseline=None, method="time", oversample=2, band_hz=(1.0, 20.0),
                    nominal_spring_rates_n_m=None, rank_tolerance=RANK_TOLERANCE,
                    fragile_share=FRAGILE_SHARE, progress=False, scheduler=None, client=None,
                    n_workers=None, processes=True, chunk_size=None):
    """Evaluate every setup under every perturbation of a what-if design.

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
        Identified or known. Spring and anti-roll bar changes act on any (exactly: a
        feedback through the shock travel on identified models, the parameters on known
        ones); vehicle-parameter changes need a known model.
    drives : ident.data.drive.Drive or sequence of Drive
        Every condition is evaluated on every drive; the first is the nominal one.
    setups : sequence of planner.setups.Setup
        The setups (e.g. the top of a ranking); the baseline is added if missing.
    library : ident.models.shocks.ShockLibrary
    perturbations : PerturbationSet
    objective : planner.objective.Objective, optional
        Default :func:`planner.objective.default_objective`.
    baseline : str or Setup, optional
        The setup scores are normalized by, in each condition; default the
        objective's, else the first setup.
    method : {"time", "screening"}
        ``time``: the nonlinear shocks in the time domain (:func:`planner.predict.
        predict_setups`, the reference); ``screening``: frequency-domain screening
        (:func:`planner.screen.screen_setups`), about 100x faster, for large sweeps.
    oversample : int
        Internal steps per sample of the time-domain loop.
    band_hz : (float, float)
        Metric band [Hz].
    nominal_spring_rates_n_m : array_like, shape (4,), optional
        The identified car's spring wheel rates [N/m], if known: a change that would
        make one negative is refused.
    rank_tolerance, fragile_share : int, float
        See the module docstring (fragile ranks).
    progress : bool
        Show a progress bar over the condition groups (over the tasks on a cluster).
    scheduler : str, optional
        Where the condition groups are evaluated: None or ``"none"`` (default) in this
        process, one group after the other; ``"local"`` on a new
        :class:`dask.distributed.LocalCluster` (`n_workers`, default one per core,
        closed at the end); or a scheduler address (``"tcp://host:8786"``). Checked
        before any work: an unknown value or an unreachable address raises at once.
    client : distributed.Client, optional
        An existing client to use instead of `scheduler` (not closed).
    n_workers : int, optional
        Workers of a new LocalCluster.
    processes : bool
        LocalCluster workers as processes (default) or threads of this process.
    chunk_size : int, optional
        Evaluations (setup x condition) per task at most on a cluster; default the
        groups cut so that every worker thread gets about four tasks (at least
        :data:`MIN_TASK_EVALUATIONS` evaluations a task). Ignored in this process.

    Returns
    -------
    WhatIf
        ``settings["scheduler"]`` says where it ran (``"none"``, ``"local"``,
        ``"address"`` or ``"client"``).

    Raises
    ------
    PlannerError
        On a bad option, a bad perturbation for the model, an unknown scheduler or an
        unreachable one (raised before any work).
    TypeError
        On arguments of the wrong type.

    Notes
    -----
    On a cluster the tables are the one-process tables bit for bit, whatever the
    workers, `chunk_size` or the order tasks finish in: the plants are built here as in
    one process, every setup is simulated on its own (a chunk of a group gives the rows
    of the whole group), the workers compute the drive's rig response with this
    process's BLAS thread count (its last bits depend on it) and the rows are put back
    in group order. Workers
    on other machines must run the same library builds on the same kind of CPU. Memory:
    a task sends back its metrics table only (no time histories); at most
    ``2 * threads + 1`` tasks are in flight, and their arguments are built as they are
    submitted.
    """
    from planner.objective import Objective, default_objective, score_setups
    from planner.predict import as_loop_plant, prepare_drive
    from planner.rank import _choose_baseline

    t_start = time.perf_counter()
    if not isinstance(perturbations, PerturbationSet):
        raise TypeError("perturbations must be a PerturbationSet (read_perturbations or "
                        f"perturbation_set), got {type(perturbations).__name__}")
    if method not in ("time", "screening"):
        raise PlannerError(f"method {method!r} is unknown; use 'time' or 'screening'")
    if chunk_size is not None and (isinstance(chunk_size, bool)
                                   or not isinstance(chunk_size, (int, np.integer))
                                   or chunk_size < 1):
        raise PlannerError(f"chunk_size={chunk_size!r} must be a positive integer "
                           "(evaluations per task), e.g. 64, or None for the default")
    drives = _as_drives(drives)
    if len(drives) > 1 and any(f.kind == "drive_file" for f in perturbations.factors):
        raise PlannerError("a drive_file factor replaces the drive; give one drive with it")
    objective = default_objective() if objective is None else objective
    if not isinstance(objective, Objective):
        raise TypeError(f"objective must be a planner.objective.Objective, got "
                        f"{type(objective).__name__}")
    setups = list(setups)
    if not setups:
        raise PlannerError("no setups for the what-if; give a setups CSV or a ranking")
    for s in setups:
        s.resolve(library)
    base = _choose_baseline(setups, objective, baseline)
    if base.name not in {s.name for s in setups}:
        setups = [base] + setups
    names = [s.name for s in setups]
    if len(set(names)) != len(names):
        raise PlannerError("setup names repeat; give each setup its own name")
    # the scheduler before any work: a wrong address fails here
    runner = None
    if not _is_serial(scheduler, client):
        from planner.sweep import _start

        runner = _start(scheduler, client, n_workers, processes, "whatif")
    try:
        src = perturbations.settings.get("source") or "what-if"
        fs = getattr(model, "fs_hz", None)
        drives = [prepare_drive(d, fs, where=f"drive {d.name!r}") for d in drives]
        base_plant = as_loop_plant(model)
        params = _known_params(model)
        if params is not None:  # the known model around its own nominal damping, built once
            base_plant = as_loop_plant(params)
        # group conditions by (plant, drive): one simulation call per group
        effects = [_effect(p, perturbations.factors) for p in perturbations.perturbations]
        groups = {}
        for di, d in enumerate(drives):
            for pi, (p, e) in enumerate(zip(perturbations.perturbations, effects)):
                groups.setdefault((_plant_key(e), di, _drive_key(e)), []).append((di, pi))
        plants, tables = {}, []
        variants = _ShockVariants(library)
        by_name = {s.name: s for s in setups}

        def condition(pkey, members):
            """The plant (built once per key, here) and the name of a group's condition."""
            e0 = effects[members[0][1]]
            where = f"{src}: condition {perturbations.perturbations[members[0][1]].name!r}"
            if pkey not in plants:
                plants[pkey] = _condition_plant(model, base_plant, e0, where,
                                                nominal_spring_rates_n_m)
            return plants[pkey], e0, where

        n_eval = 0
        if runner is None:  # this process, one group after the other
            items = list(groups.items())
            if progress:
                from tqdm.auto import tqdm

                items = tqdm(items, desc="what-if", unit="group")
            for (pkey, di, _), members in items:
                plant, e0, where = condition(pkey, members)
                drive = _condition_drive(drives[di], e0, where)
                cond_setups = _group_setups(setups, members, effects, variants)
                lib = variants.full_library()
                pred_table = _evaluate_group(plant, drive, cond_setups, lib, method,
                                             oversample, band_hz)
                n_eval += len(cond_setups)
                tables.append(_group_table(pred_table, by_name, drives, perturbations))
            kind, address, workers, n_tasks = "none", None, 1, len(groups)
        else:
            keys = list(groups)
            sizes = [len(groups[k]) * len(setups) for k in keys]
            chunk = int(chunk_size) if chunk_size is not None else max(
                MIN_TASK_EVALUATIONS[method],
                math.ceil(sum(sizes) / (TASKS_PER_THREAD * runner.n_threads)))
            specs = _task_specs(sizes, chunk)
            drive_refs = [runner.scatter(d) for d in drives]
            lib_ref = runner.scatter(library)
            blas = _blas_threads()
            current = {}  # the group being submitted: its condition setups

            def make(g, a, b):
                pkey, di, _ = keys[g]
                members = groups[keys[g]]
                plant, e0, where = condition(pkey, members)
                if current.get("g") != g:
                    current.clear()
                    current.update(g=g, setups=_group_setups(setups, members, effects,
                                                             variants))
                chunk_setups = current["setups"][a:b]
                extra = list({sid: variants.extra[sid] for s in chunk_setups
                              for sid in s.ids() if sid in variants.extra}.values())
                return (plant, drive_refs[di], e0, where, chunk_setups, lib_ref, extra,
                        method, oversample, tuple(band_hz), blas)

            log.info("what-if: %d condition groups, %d evaluations in %d tasks (%s, %d "
                     "worker(s))", len(keys), sum(sizes), len(specs), runner.kind,
                     runner.n_workers)
            parts = [None] * len(specs)
            for j, res in runner.map_unordered(_whatif_task, _LazyTasks(specs, make),
                                               progress, "what-if"):
                parts[j] = res
            for g in range(len(keys)):  # the groups' rows, in group order, as one process
                got = [parts[j] for j, spec in enumerate(specs) if spec[0] == g]
                pred_table = got[0] if len(got) == 1 else pd.concat(got)
                n_eval += len(pred_table)
                tables.append(_group_table(pred_table, by_name, drives, perturbations))
            parts = None
            kind, address, workers, n_tasks = (runner.kind, runner.address, runner.n_workers,
                                               len(specs))
    finally:
        if runner is not None:
            runner.close()
    table = pd.concat(tables).sort_values("_order", kind="stable").drop(columns="_order")
    table = table.reset_index(drop=True)
    metrics = [c for c in table.columns if c not in ("drive", "perturbation", "setup") + CORNERS]
    # score each condition against the baseline in that condition
    scored = []
    for _, cond in table.groupby(["drive", "perturbation"], sort=False):
        sc = score_setups(cond.set_index("setup")[metrics], objective, baseline=base.name).table
        scored.append(pd.concat([cond.reset_index(drop=True),
                                 sc.reset_index(drop=True)], axis=1))
    table = pd.concat(scored, ignore_index=True)
    nominal = table[(table["drive"] == drives[0].name)
                    & (table["perturbation"] == "nominal")].set_index("setup")
    table["score_change"] = table["score"].to_numpy() - nominal.loc[table["setup"], "score"].to_numpy()
    table["rank_change"] = table["rank"].to_numpy() - nominal.loc[table["setup"], "rank"].to_numpy()
    for m in metrics:
        ref = nominal.loc[table["setup"], m].to_numpy(dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            table[f"{m}_change_pct"] = 100.0 * (table[m].to_numpy(dtype=float) / ref - 1.0)
    robust = _robust_table(table, names, rank_tolerance, fragile_share)
    ptab = perturbations.table()
    conditions = pd.concat([ptab.assign(drive=d.name) for d in drives]).reset_index()
    conditions = conditions.set_index(["drive", "perturbation"])
    elapsed = time.perf_counter() - t_start
    settings = {"method": method, "oversample": oversample, "band_hz": tuple(band_hz),
                "rank_tolerance": int(rank_tolerance), "fragile_share": float(fragile_share),
                "n_evaluations": int(n_eval), "n_conditions": int(len(conditions)),
                "n_setups": len(setups), "elapsed_s": elapsed,
                "evaluations_per_s": n_eval / elapsed if elapsed > 0 else float("nan"),
                "model": getattr(base_plant, "name", None), "drives": [d.name for d in drives],
                "design": perturbations.design, "source": perturbations.settings.get("source"),
                "scheduler": kind, "address": address, "n_workers": int(workers),
                "n_tasks": int(n_tasks)}
    log.info("what-if: %d setups x %d conditions (%d evaluations, %s, scheduler %s) in %.1f s",
             len(setups), len(conditions), n_eval, method, kind, elapsed)
    return WhatIf(table=table, robust=robust, perturbations=perturbations, conditions=conditions,
                  baseline=base.name, objective=objective, settings=settings)


def _robust_table(table, names, rank_tolerance, fragile_share):
    g = table.groupby("setup", sort=False)
    nominal = table[table["perturbation"] == "nominal"].groupby("setup").first()
    rob = pd.DataFrame(index=pd.Index(names, name="setup"))
    rob["nominal_rank"] = nominal.loc[names, "rank"].astype(int)
    rob["nominal_score"] = nominal.loc[names, "score"]
    rob["mean_score"] = g["score"].mean().loc[names]
    rob["worst_score"] = g["score"].max().loc[names]
    rob["mean_rank"] = g["rank"].mean().loc[names]
    rob["best_rank"] = g["rank"].min().loc[names].astype(int)
    rob["worst_rank"] = g["rank"].max().loc[names].astype(int)
    rob["best_share"] = g["rank"].apply(lambda r: float(np.mean(r == 1))).loc[names]
    rob["moved_share"] = g["rank_change"].apply(
        lambda r: float(np.mean(np.abs(r) > rank_tolerance))).loc[names]
    rob["feasible_share"] = g["feasible"].mean().loc[names]
    rob["fragile"] = rob["moved_share"] > fragile_share
    rob["rank_mean_score"] = rob["mean_score"].rank(method="min").astype(int)
    rob["rank_worst_score"] = rob["worst_score"].rank(method="min").astype(int)
    return rob.sort_values(["rank_mean_score", "nominal_rank"], kind="stable")


# ----------------------------------------------------------------------------------------------
# effects (tornado)
# ----------------------------------------------------------------------------------------------

def factor_effects(result, setup, *, quantity="score_change"):
    """Per-factor effect on one setup: the change at the factor's low and high values.

    One-at-a-time: the change of each factor level alone. Factorial and Monte Carlo:
    numeric factors by a linear regression of the change on every factor's values over
    the conditions (the change at the 10th and 90th percentile of the factor's values
    in Monte Carlo, at its lowest and highest level in a factorial), categorical ones
    (windows, files) by the mean change per level.

    Parameters
    ----------
    result : WhatIf
    setup : str
    quantity : str
        A column of ``result.table`` (default ``score_change``; e.g. ``rank_change`` or
        ``tire_force_rms_LF_change_pct``).

    Returns
    -------
    pandas.DataFrame
        Index the factor (per target for independent factors), columns ``low``,
        ``high`` (the values, text), ``change_low``, ``change_high``, ``swing``
        (``|change_high - change_low|``); largest swing first.
    """
    t = result.table
    if setup not in set(t["setup"]):
        raise PlannerError(f"setup {setup!r} is not in the what-if; it has "
                           f"{sorted(set(t['setup']))[:8]}")
    if quantity not in t.columns:
        raise PlannerError(f"{quantity!r} is not a column of the what-if table")
    d0 = result.settings["drives"][0]
    rows = t[(t["setup"] == setup) & (t["drive"] == d0)].set_index("perturbation")
    conds = result.perturbations.table().loc[rows.index]
    y = rows[quantity].to_numpy(dtype=float)
    out = []
    design = result.perturbations.design
    if design == "one-at-a-time":
        for col in conds.columns:
            vals = conds[col]
            moved = vals.apply(lambda v: v not in ("nominal",) and v != _nominal_of(result, col))
            if not moved.any():
                continue
            sub = vals[moved]
            keyed = sorted(zip(sub.tolist(), y[moved.to_numpy()]),
                           key=lambda p: (p[0] if isinstance(p[0], float) else 0.0))
            if len(keyed) == 1:  # one level: from the nominal to it
                nom = _nominal_of(result, col)
                keyed = [("nominal" if nom is None else nom, 0.0)] + keyed
                keyed.sort(key=lambda p: (p[0] if isinstance(p[0], float) else 0.0))
            lo, hi = keyed[0], keyed[-1]
            out.append((col, _value_text_out(lo[0]), _value_text_out(hi[0]), lo[1], hi[1]))
    else:
        numeric = [c for c in conds.columns if pd.api.types.is_numeric_dtype(conds[c])
                   and conds[c].nunique() > 1]
        if numeric:
            X = conds[numeric].to_numpy(dtype=float)
            Xc = X - X.mean(axis=0)
            coef, *_ = np.linalg.lstsq(Xc, y - y.mean(), rcond=None)
            for j, col in enumerate(numeric):
                if design == "monte-carlo":
                    lo_v, hi_v = np.percentile(X[:, j], [10, 90])
                else:
                    lo_v, hi_v = X[:, j].min(), X[:, j].max()
                nom = _nominal_of(result, col)
                nom = X[:, j].mean() if nom is None else nom
                # the change the factor alone makes from its nominal value
                out.append((col, lo_v, hi_v, coef[j] * (lo_v - nom), coef[j] * (hi_v - nom)))
        for col in conds.columns:
            if col in numeric or conds[col].nunique() < 2:
                continue
            means = pd.Series(y, index=conds.index).groupby(conds[col].astype(str)).mean()
            lo_k, hi_k = means.idxmin(), means.idxmax()
            out.append((col, lo_k, hi_k, float(means[lo_k]), float(means[hi_k])))
    eff = pd.DataFrame(out, columns=["factor", "low", "high", "change_low", "change_high"])
    eff["swing"] = (eff["change_high"] - eff["change_low"]).abs()
    return eff.set_index("factor").sort_values("swing", ascending=False)


def _nominal_of(result, column):
    for f in result.perturbations.factors:
        for label, _ in f.atoms():
            if label == column:
                return f.nominal
    return None


def _value_text_out(v):
    return v if isinstance(v, str) else float(v)


# ----------------------------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------------------------

def tornado_figure(result, setup, *, quantity="score_change", max_factors=12):
    """Tornado chart of the factors' effects on one setup (:func:`factor_effects`).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    eff = factor_effects(result, setup, quantity=quantity).head(max_factors).iloc[::-1]
    fig = Figure(figsize=(7.5, 0.45 * max(len(eff), 3) + 1.4))
    ax = fig.add_subplot()
    ypos = np.arange(len(eff))
    for y_, (name, r) in zip(ypos, eff.iterrows()):
        for val, label, color in ((r["change_low"], r["low"], "#4C72B0"),
                                  (r["change_high"], r["high"], "#DD8452")):
            ax.barh(y_, val, color=color, height=0.6)
            txt = label if isinstance(label, str) else f"{label:.4g}"
            ax.annotate(txt, (val, y_), xytext=(3 if val >= 0 else -3, 0),
                        textcoords="offset points", va="center",
                        ha="left" if val >= 0 else "right", fontsize=7)
    ax.set_yticks(ypos, [str(i) for i in eff.index], fontsize=8)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel(quantity.replace("_", " ") + " (low value blue, high value orange)")
    ax.set_title(f"what-if effects on {setup}", fontsize=10)
    ax.margins(x=0.25)
    fig.tight_layout()
    return fig


def rank_stability_figure(result, *, top=10):
    """Rank of the top setups (by nominal rank) across the conditions.

    Few conditions (<= 30): one line per setup over the conditions. More: the
    distribution of each setup's rank (box plot, nominal rank as a diamond).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    rob = result.robust.sort_values("nominal_rank")
    names = list(rob.index[:top])
    t = result.table[result.table["setup"].isin(names)].copy()
    t["condition"] = t["drive"] + " | " + t["perturbation"]
    piv = t.pivot_table(index="condition", columns="setup", values="rank", sort=False)[names]
    fig = Figure(figsize=(9.0, 5.0))
    ax = fig.add_subplot()
    if len(piv) <= 30:
        x = np.arange(len(piv))
        for n in names:
            ax.plot(x, piv[n].to_numpy(), marker="o", ms=3, lw=1.2,
                    label=f"{n}{' (fragile)' if rob.loc[n, 'fragile'] else ''}")
        labels = [c.split(" | ", 1)[1] if len(result.settings["drives"]) == 1 else c
                  for c in piv.index]
        ax.set_xticks(x, labels, rotation=60, ha="right", fontsize=7)
        ax.legend(fontsize=7, ncol=2, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    else:
        data = [piv[n].dropna().to_numpy() for n in names]
        ax.boxplot(data, vert=True, whis=(5, 95), widths=0.6)
        ax.plot(np.arange(1, len(names) + 1), rob.loc[names, "nominal_rank"].to_numpy(), "D",
                color="#C44E52", ms=5, label="nominal rank")
        ax.set_xticks(np.arange(1, len(names) + 1),
                      [f"{n}{' *' if rob.loc[n, 'fragile'] else ''}" for n in names],
                      rotation=45, ha="right", fontsize=7)
        ax.legend(fontsize=8, loc="lower left")
        ax.set_xlabel("setup (* fragile rank); boxes 25-75 %, whiskers 5-95 % of conditions")
    ax.invert_yaxis()
    ax.set_ylabel("rank (1 = best)")
    ax.set_title(f"rank stability over {len(piv)} conditions "
                 f"({result.perturbations.design}, {result.settings['method']})", fontsize=10)
    fig.tight_layout()
    return fig


# ----------------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------------

def _safe_name(name):
    keep = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
    return keep.strip("_") or "setup"


#: Settings that time a run or say where it ran: logged and kept on the result, not
#: written to the files (a rerun, on a cluster or not, writes the same cells).
_TIMING_KEYS = ("elapsed_s", "evaluations_per_s", "scheduler", "address", "n_workers",
                "n_tasks")


def write_whatif(result, out_dir, *, units="SI", top=5, overwrite=False):
    """Write a what-if's files into a folder (built aside, moved into place at the end).

    Files: ``whatif.xlsx`` (sheets ``robust``, ``conditions``, ``effects`` and
    ``table``), ``whatif.csv`` (the long table, metrics in `units`), ``robust.csv``,
    ``conditions.csv``, ``rank_stability.png`` and ``tornado/<nn>_<setup>.png`` for the
    `top` setups of the robust ranking.

    Returns
    -------
    dict of str -> pathlib.Path

    Raises
    ------
    FileExistsError
        If `out_dir` exists and is not empty and `overwrite` is false (checked first).
    """
    from openpyxl import Workbook
    from openpyxl.styles import Font, PatternFill

    from ident.data.files import atomic_dir
    from planner.report import ranking_to_units

    units = check_units(units, where="units", error=PlannerError)
    out = Path(out_dir)
    files = {}
    with atomic_dir(out, overwrite=overwrite) as work:
        table = ranking_to_units(result.table, units)
        table.to_csv(work / "whatif.csv", index=False, float_format="%.6g")
        result.robust.to_csv(work / "robust.csv", float_format="%.6g")
        result.conditions.to_csv(work / "conditions.csv")
        top_names = list(result.robust.index[:top])
        effects = []
        (work / "tornado").mkdir()
        for k, n in enumerate(top_names):
            eff = factor_effects(result, n)
            effects.append(eff.reset_index().assign(setup=n))
            fig = tornado_figure(result, n)
            fig.savefig(work / "tornado" / f"{k + 1:02d}_{_safe_name(n)}.png", dpi=110)
        fig = rank_stability_figure(result)
        fig.savefig(work / "rank_stability.png", dpi=110)
        wb = Workbook()
        bold = Font(bold=True)
        fragile_fill = PatternFill("solid", fgColor="F8CBAD")

        def sheet(ws, frame, *, highlight=None):
            ws.append(list(frame.columns))
            for cell in ws[1]:
                cell.font = bold
            for row in frame.itertuples(index=False):
                ws.append([_xl(x) for x in row])
            if highlight is not None:
                for r, flag in enumerate(highlight, start=2):
                    if flag:
                        for cell in ws[r]:
                            cell.fill = fragile_fill
            ws.freeze_panes = "B2"
            for col in ws.columns:
                width = max(len(str(c.value)) if c.value is not None else 0 for c in col)
                ws.column_dimensions[col[0].column_letter].width = min(max(width + 2, 8), 40)

        ws = wb.active
        ws.title = "robust"
        rob = result.robust.reset_index()
        sheet(ws, rob.round(4), highlight=rob["fragile"].tolist())
        sheet(wb.create_sheet("conditions"), result.conditions.reset_index())
        if effects:
            sheet(wb.create_sheet("effects"), pd.concat(effects, ignore_index=True)[
                ["setup", "factor", "low", "high", "change_low", "change_high", "swing"]])
        cols = ["drive", "perturbation", "setup", "score", "rank", "score_change",
                "rank_change", "feasible"] + [c for c in table.columns
                                              if c.endswith("_change_pct")]
        sheet(wb.create_sheet("table"), table[cols])
        info = wb.create_sheet("settings")
        for k, v in result.settings.items():
            if k in _TIMING_KEYS:  # a rerun writes the same cells (timings go to the log)
                continue
            info.append([k, _xl(v if not isinstance(v, (list, tuple)) else ", ".join(map(str, v)))])
        info.append(["units", units])
        info.append(["baseline", result.baseline])
        info.append(["objective", result.objective.name])
        wb.save(work / "whatif.xlsx")
    for p in sorted(out.rglob("*")):
        if p.is_file():
            files[str(p.relative_to(out))] = p
    return files


def _xl(x):
    if isinstance(x, (np.bool_,)):
        return bool(x)
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
