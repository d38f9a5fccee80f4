"""What-if designs: the factors, the conditions they make, and the perturbation file.

A :class:`Factor` is one thing that may change (a shock force scale or lag, a spring or
anti-roll bar rate, a drive's amplitude, window or file, a vehicle parameter) with its
levels and/or distribution; :func:`perturbation_set` expands factors into the conditions
(:class:`Perturbation`) of a design (``one-at-a-time``, ``factorial``, ``monte-carlo``),
the nominal condition first; :func:`read_perturbations` reads them from a perturbation
TOML (``format = "shockplan-whatif/1"``). The factor kinds, the designs and the file
format are described in :mod:`planner.whatif`. Values are SI; the file's ``units``
apply to ``add`` changes of rates.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ident.data.channels import AERO_INPUTS, CORNERS, RIG_INPUTS, WHEELLOADER_INPUTS
from ident.data.drive import read_drive
from ident.data.files import read_toml
from ident.data.third import THIRD_ELEMENTS
from ident.data.units import check_units, to_si
from ident.models.vehicle import VEHICLE_KEYS
from planner.errors import PlannerError

__all__ = [
    "FACTOR_KINDS",
    "FADE_PARTS",
    "DESIGNS",
    "MAX_CONDITIONS",
    "CHANNEL_GROUPS",
    "AXLE_CORNERS",
    "THIRD_FACTOR_KINDS",
    "Factor",
    "Perturbation",
    "PerturbationSet",
    "perturbation_set",
    "read_perturbations",
]

#: Factor kinds and their default change ("scale": multiply, "add": add to the value).
FACTOR_KINDS = {"shock_scale": "scale", "shock_lag": "add", "spring_rate": "scale",
                "arb_rate": "add", "drive_scale": "scale", "drive_window": "set",
                "drive_file": "set", "vehicle": "scale", "packer": "add", "bump_stop": "set",
                "click": "add", "fade": "add", "third_scale": "scale", "third_lag": "add",
                "heave_packer": "add", "heave_spring_rate": "scale"}
#: Factor kinds acting on the car's third elements (issue 38): a damper's force scale and
#: lag per element, a heave spring's packer change and rate scale per axle.
THIRD_FACTOR_KINDS = ("third_scale", "third_lag", "heave_packer", "heave_spring_rate")
#: Where a ``fade`` factor acts (:mod:`planner.whatif.click_factors`).
FADE_PARTS = ("all", "low-speed")
#: Designs of a perturbation set.
DESIGNS = ("one-at-a-time", "factorial", "monte-carlo")
#: Largest number of conditions of a factorial design (guard against a typo exploding it).
MAX_CONDITIONS = 5000
#: Channel groups of drive_scale.
CHANNEL_GROUPS = {"wheel": WHEELLOADER_INPUTS, "aero": AERO_INPUTS}
#: Axles of arb_rate.
AXLE_CORNERS = {"front": (0, 1), "rear": (2, 3)}
_TOP_KEYS = {"format", "units", "design", "n_draws", "seed", "factor", "name"}
_FACTOR_KEYS = {"name", "kind", "corners", "shocks", "axles", "channels", "parameter", "change",
                "levels", "distribution", "independent", "baseline_rate", "adjusters", "part",
                "elements"}
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
        for shock ids, axles (``arb_rate``, ``heave_packer``, ``heave_spring_rate``), third
        elements (``third_scale``, ``third_lag``: ``"heave_front"``, ...), rig inputs
        (``drive_scale``), the vehicle key (``vehicle``); empty for ``drive_window`` and
        ``drive_file``.
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
    adjusters : tuple of str
        ``click``: the adjusters that move (empty: every adjuster of each shock).
    part : {"all", "low-speed"}
        ``fade``: the whole curve loses force, or mostly its low-speed part
        (:func:`planner.whatif.click_factors.faded_shock`).
    """

    name: str
    kind: str
    targets: tuple = ()
    change: str | None = None
    levels: tuple = ()
    distribution: tuple | None = None
    independent: bool = False
    baseline_rate: np.ndarray | None = None
    adjusters: tuple = ()
    part: str = "all"

    def __post_init__(self):
        where = f"factor {self.name!r}"
        if self.kind not in FACTOR_KINDS:
            raise PlannerError(f"{where}: kind {self.kind!r} is unknown; use one of "
                               f"{sorted(FACTOR_KINDS)}")
        object.__setattr__(self, "adjusters", tuple(self.adjusters))
        if self.adjusters and self.kind != "click":
            raise PlannerError(f"{where}: adjusters apply to a click factor only; remove them")
        if self.part not in FADE_PARTS:
            raise PlannerError(f"{where}: part {self.part!r} is unknown; use one of "
                               f"{list(FADE_PARTS)}")
        if self.kind in ("click", "fade") and self.change != FACTOR_KINDS[self.kind] \
                and self.change is not None:
            raise PlannerError(f"{where}: change {self.change!r} does not apply to a "
                               f"{self.kind} factor; use 'add'")
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
    if isinstance(v, str):
        return v
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
    if factor.kind == "bump_stop":
        return f"= {v}"
    if factor.kind == "packer":
        return f"{v * 1e3:+.4g} mm"
    if factor.kind == "click":
        return f"{v:+g} click"
    if factor.kind == "fade":
        return f"{v * 100:.4g} %{' low-speed' if factor.part == 'low-speed' else ''} fade"
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


def _parse_factor(t, units, where, base_dir, *, stated_units=True):
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
               "drive_file": ("set",), "vehicle": ("scale", "add"), "packer": ("add",),
               "bump_stop": ("set",), "click": ("add",), "fade": ("add",),
               "third_scale": ("scale",), "third_lag": ("add",), "heave_packer": ("add",),
               "heave_spring_rate": ("scale",)}[kind]
    if change not in allowed:
        raise _fail(where, "change", f"= {change!r} does not apply to a {kind} factor",
                    f"use {' or '.join(repr(a) for a in allowed)}")
    # targets
    target_key = {"shock_scale": ("corners", "shocks"), "shock_lag": ("corners", "shocks"),
                  "spring_rate": ("corners",), "arb_rate": ("axles",),
                  "drive_scale": ("channels",), "vehicle": ("parameter",),
                  "packer": ("corners",), "bump_stop": ("corners",),
                  "click": ("corners", "shocks"), "fade": ("corners", "shocks"),
                  "third_scale": ("elements",), "third_lag": ("elements",),
                  "heave_packer": ("axles",), "heave_spring_rate": ("axles",)}.get(kind, ())
    given = [k for k in ("corners", "shocks", "axles", "channels", "parameter", "elements")
             if k in t]
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
            vk = VEHICLE_KEYS
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
            elif key == "elements":
                bad = [x for x in raw if x not in THIRD_ELEMENTS]
                if bad:
                    raise _fail(where, key, f"has unknown third element(s) {bad}",
                                f"use {list(THIRD_ELEMENTS)}")
                targets = tuple(raw)
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
        qty = {"shock_lag": None, "spring_rate": "stiffness", "arb_rate": "stiffness",
               "packer": "displacement", "heave_packer": "displacement"}.get(kind, qty)

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
                # the file's units when it states them (the drive's marker must agree),
                # else the drive file's marker, else SI
                lv.append(read_drive(path, units=units if stated_units else None))
            levels = tuple(lv)
        elif kind == "bump_stop":
            bad = [x for x in raw if not isinstance(x, str) or not x.strip()]
            if bad:
                raise _fail(where, "levels", f"has {bad[0]!r}, not a bump-stop id",
                            'write e.g. levels = ["BS-F2", "none"] (ids of the bump-stop '
                            'library, "none" for no bump stop)')
            levels = tuple(x.strip() for x in raw)
        else:
            levels = tuple(value(x, "levels") for x in raw)
        if kind == "click":
            bad = [x for x in levels if x != round(x)]
            if bad:
                raise _fail(where, "levels", f"has {bad[0]:g}, not a whole number of clicks",
                            "write e.g. levels = [-1, 0, 1] (steps of each adjuster)")
        if kind == "fade":
            bad = [x for x in levels if not 0.0 <= x < 1.0]
            if bad:
                raise _fail(where, "levels", f"has {bad[0]:g}, not a force loss in [0, 1)",
                            "write e.g. levels = [0.0, 0.05, 0.1] (5 %, 10 % less force)")
    distribution = None
    if "distribution" in t:
        if kind in ("drive_window", "drive_file", "bump_stop", "click"):
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
        if kind == "fade" and (d["kind"] != "uniform" or a < 0 or b >= 1):
            raise _fail(where, "distribution", f"= {d!r} may draw a fade outside [0, 1)",
                        'write e.g. distribution = { kind = "uniform", low = 0.0, high = 0.1 }')
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
    adjusters = ()
    if "adjusters" in t:
        raw = t["adjusters"]
        raw = [raw] if isinstance(raw, str) else raw
        if kind != "click":
            raise _fail(where, "adjusters", f"does not apply to a {kind} factor",
                        "remove it (only a click factor names adjusters)")
        if (not isinstance(raw, list) or not raw
                or not all(isinstance(x, str) and x.strip() for x in raw)
                or len(set(raw)) != len(raw)):
            raise _fail(where, "adjusters", f"must be a list of adjuster names, got "
                        f"{t['adjusters']!r}", 'write e.g. adjusters = ["ls"] (or leave it out '
                        'for every adjuster)')
        adjusters = tuple(x.strip() for x in raw)
    part = t.get("part", "all")
    if "part" in t and kind != "fade":
        raise _fail(where, "part", f"does not apply to a {kind} factor",
                    "remove it (only a fade factor has a part)")
    if part not in FADE_PARTS:
        raise _fail(where, "part", f"= {part!r} is unknown", f"use one of {list(FADE_PARTS)}")
    return Factor(name=name.strip(), kind=kind, targets=targets, change=change, levels=levels,
                  distribution=distribution, independent=independent,
                  baseline_rate=baseline_rate, adjusters=adjusters, part=part)


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
    factors = [_parse_factor(t, units, f"{where}: factor {j + 1}", path.parent,
                             stated_units="units" in doc)
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
