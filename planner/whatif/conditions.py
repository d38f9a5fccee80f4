"""What-if conditions: what a perturbation changes, and the plant, drive and setups it gives.

:func:`condition_effect` sums a condition's factor values into a
:class:`ConditionEffect` (shock scales and lags per corner or id, spring and bar
changes, vehicle-parameter changes, drive scales, a window or another drive file).
From it, :func:`condition_plant` builds the condition's loop plant (the changed known
vehicle, or the identified plant stiffened by :func:`stiffened_plant`),
:func:`condition_drive` the condition's drive, and :func:`condition_setups` the setups
with their scaled or lagged shocks (:class:`ShockVariants`, shared between identical
conditions). :func:`plant_key` and :func:`drive_key` say which conditions share a plant
and a drive (one simulation call per group in :mod:`planner.whatif.evaluate`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident.data.channels import CORNERS, RIG_INPUTS
from ident.data.drive import Drive
from ident.errors import VehicleError
from ident.models.bumpstops import BumpStop, BumpStopLibrary
from ident.models.library import ShockLibrary
from ident.models.vehicle import FullCarModel, VehicleParams, build_full_car
from ident.sim import stiffness as ident_stiffness
from planner.errors import PlannerError
from planner.setups import Setup
from planner.whatif.click_factors import (click_note, click_steps, clicked_settings, fade_amounts,
                                   faded_shock, parse_setting)
from planner.whatif.spec import AXLE_CORNERS

__all__ = [
    "MIN_WINDOW_S",
    "stiffened_plant",
    "ConditionEffect",
    "condition_effect",
    "plant_key",
    "drive_key",
    "known_params",
    "condition_plant",
    "condition_drive",
    "ShockVariants",
    "StopVariants",
    "condition_setups",
    "condition_notes",
]

#: A drive window shorter than this cannot resolve the 1 Hz end of the metric band with
#: the metric filter's transients [s].
MIN_WINDOW_S = 4.0


# ----------------------------------------------------------------------------------------------
# applying a condition
# ----------------------------------------------------------------------------------------------

def stiffened_plant(plant, *, spring_n_m=None, arb_n_m=None, name=None):
    """:func:`ident.sim.stiffness.stiffened_plant`, raising the what-if's error.

    The same plant and messages; a :class:`~ident.errors.VehicleError` of the
    transform (no shock-travel outputs, a singular or unstable stiffened loop) is
    raised as a :class:`~planner.errors.PlannerError`.
    """
    try:
        return ident_stiffness.stiffened_plant(plant, spring_n_m=spring_n_m, arb_n_m=arb_n_m,
                                               name=name)
    except VehicleError as exc:
        raise PlannerError(str(exc)) from None


@dataclass(frozen=True)
class ConditionEffect:
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
    packer_add: np.ndarray = field(default_factory=lambda: np.zeros(4))  # (4,) [m]
    stop_set: tuple = (None,) * 4  # per corner: None (unchanged), an id or "none"
    click: tuple = ()              # ((corner or "id:<name>", adjusters, steps), ...)
    fade: tuple = ()               # ((corner or "id:<name>", part, loss), ...)
    third_scale: dict = field(default_factory=dict)  # third element -> damper force scale
    third_lag: dict = field(default_factory=dict)    # third element -> damper lag added [s]
    heave_packer_add: dict = field(default_factory=dict)  # axle -> heave packer added [m]
    heave_rate_scale: dict = field(default_factory=dict)  # axle -> heave spring force scale

    @property
    def changes_third(self):
        """True if the condition changes a third element's damper or a heave spring."""
        return (any(v != 1.0 for v in self.third_scale.values())
                or any(v != 0.0 for v in self.third_lag.values())
                or any(v != 0.0 for v in self.heave_packer_add.values())
                or any(v != 1.0 for v in self.heave_rate_scale.values()))

    @property
    def changes_adjustables(self):
        """True if the condition clicks or fades the adjustable shocks."""
        return any(v for _, _, v in self.click) or any(v for _, _, v in self.fade)

    @property
    def changes_elements(self):
        """True if the condition changes a bump stop or a packer."""
        return bool(np.any(self.packer_add)) or any(v is not None for v in self.stop_set)


def condition_effect(perturbation, factors):
    """What a condition changes: its factors' values summed per corner, id, axle, channel.

    Parameters
    ----------
    perturbation : planner.whatif.spec.Perturbation
    factors : sequence of planner.whatif.spec.Factor

    Returns
    -------
    ConditionEffect
        Scales multiply and additions add when several factors act on one target.
    """
    e = dict(corner_scale=np.ones(4), id_scale={}, corner_lag=np.zeros(4), id_lag={},
             spring_add=np.zeros(4), spring_scale=np.ones(4), arb_add=np.zeros(2),
             arb_scale=np.ones(2), vehicle=[], channel_scale=np.ones(7), window=None, drive=None,
             packer_add=np.zeros(4), stop_set=[None] * 4, click=[], fade=[], third_scale={},
             third_lag={}, heave_packer_add={}, heave_rate_scale={})
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
            elif f.kind == "packer":
                e["packer_add"][CORNERS.index(t)] += v
            elif f.kind == "bump_stop" and v is not None:
                e["stop_set"][CORNERS.index(t)] = v
            elif f.kind in ("third_scale", "heave_spring_rate"):
                d = e["third_scale" if f.kind == "third_scale" else "heave_rate_scale"]
                d[t] = d.get(t, 1.0) * v
            elif f.kind in ("third_lag", "heave_packer"):
                d = e["third_lag" if f.kind == "third_lag" else "heave_packer_add"]
                d[t] = d.get(t, 0.0) + v
            elif f.kind == "click" and v:
                e["click"].append((t, f.adjusters, float(v)))
            elif f.kind == "fade" and v:
                if not 0.0 <= v < 1.0:
                    raise PlannerError(f"factor {f.name!r}: a fade of {v:g} is not a force "
                                       "loss in [0, 1); give fades such as 0.05 or 0.1")
                e["fade"].append((t, f.part, float(v)))
    e["click"] = tuple(e["click"])
    e["fade"] = tuple(e["fade"])
    e["vehicle"] = tuple(e["vehicle"])
    e["stop_set"] = tuple(e["stop_set"])
    return ConditionEffect(**e)


def plant_key(e):
    """A hashable key of the plant a :class:`ConditionEffect` makes (equal key, one plant)."""
    return (tuple(np.round(e.spring_add, 9)), tuple(np.round(e.spring_scale, 12)),
            tuple(np.round(e.arb_add, 9)), tuple(np.round(e.arb_scale, 12)),
            tuple((k, c, round(float(v), 12)) for k, c, v, _ in e.vehicle))


def drive_key(e):
    """A hashable key of the drive change of a :class:`ConditionEffect`."""
    return (tuple(np.round(e.channel_scale, 12)), e.window,
            None if e.drive is None else id(e.drive))


def known_params(model):
    """The known vehicle's parameters of `model`, or None for an identified model.

    Parameters
    ----------
    model : VehicleParams, FullCarModel, VehicleModel or LoopPlant

    Returns
    -------
    ident.models.vehicle.VehicleParams or None
    """
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


def condition_plant(model, base_plant, e, where, nominal_rates):
    """The loop plant of a condition (the model's own when nothing structural changes).

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
        As :func:`planner.whatif.evaluate_whatif` takes it.
    base_plant : ident.models.lti.LoopPlant
        The model's nominal loop plant.
    e : ConditionEffect
    where : str
        The condition's name for error messages.
    nominal_rates : array_like, shape (4,), or None
        The identified car's spring wheel rates [N/m], if known.

    Returns
    -------
    ident.models.lti.LoopPlant
        `base_plant` itself; the changed known vehicle's plant; or `base_plant`
        stiffened (:func:`stiffened_plant`) on an identified model.

    Raises
    ------
    PlannerError
        If the change needs a known vehicle, the current rates, or makes a rate negative.
    """
    params = known_params(model)
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


def condition_drive(drive, e, where):
    """The drive of a condition: another file, a window, scaled channels (in that order).

    Parameters
    ----------
    drive : ident.data.drive.Drive
        The prepared nominal drive.
    e : ConditionEffect
    where : str
        The condition's name for error messages.

    Returns
    -------
    ident.data.drive.Drive
        `drive` itself when the condition leaves it alone.

    Raises
    ------
    PlannerError
        If a window lies outside the drive or is shorter than :data:`MIN_WINDOW_S`.
    """
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


class ShockVariants:
    """Derived shocks of the conditions (scaled, lagged), shared between identical ones.

    Parameters
    ----------
    library : ident.models.library.ShockLibrary
        The crate.

    Attributes
    ----------
    extra : dict of str -> ident.models.shocks.ShockModel
        The derived shocks by id (``"<id>~<n>"``).
    """

    def __init__(self, library):
        self.library = library
        self.extra = {}
        self._key = {}
        self._names = {}

    def model_id(self, shock_id, scale, lag_add, fade=(0.0, 0.0)):
        """The id of shock `shock_id` scaled by `scale` with `lag_add` [s] more lag and
        faded by ``fade = (fade_all, fade_low)`` (made once)."""
        if scale == 1.0 and lag_add == 0.0 and not any(fade):
            return shock_id
        key = (shock_id, round(float(scale), 14), round(float(lag_add), 14))
        if any(fade):
            key += (round(float(fade[0]), 14), round(float(fade[1]), 14))
        if key not in self._key:
            base = self.library.get(shock_id)
            lag = base.lag_s + lag_add
            if lag < 0:
                raise PlannerError(f"shock {shock_id!r}: the lag change {lag_add:g} s makes its "
                                   f"lag {lag:g} s negative; reduce the change")
            # a setting name's variant is named without its '@' (not a setting name)
            new_id = f"{shock_id.replace('@', '~at~')}~{len(self._key) + 1}"
            if any(fade):
                base = faded_shock(base, *fade)
            self.extra[new_id] = base.scaled(scale, lag_s=lag, id=new_id)
            self._key[key] = new_id
        return self._key[key]

    def names(self, shock_id):
        """``(base id, full setting or None, canonical name or None)`` of a shock name."""
        hit = self._names.get(shock_id)
        if hit is None:
            hit = self._names[shock_id] = parse_setting(self.library, shock_id)
        return hit

    def matches(self, target, shock_id):
        """True if a factor's shock target (an id or a setting name) names `shock_id`."""
        if target == shock_id:
            return True
        base, _, canonical = self.names(shock_id)
        if canonical is None:
            return False
        if target == base:
            return True
        return "@" in target and self.names(target)[2] == canonical

    def corner_shock(self, sid, i, e):
        """The id a corner's shock `sid` takes under condition `e`, and a clip note.

        Clicks move an adjustable shock's setting first (clipped at its range ends),
        then the fade, the scale and the lag apply (fixed shocks: scale and lag only).
        """
        base, settings, canonical = self.names(sid)
        if canonical is None and "@" not in sid:  # a fixed shock: the plain path
            return self.model_id(sid, e.corner_scale[i] * e.id_scale.get(sid, 1.0),
                                 e.corner_lag[i] + e.id_lag.get(sid, 0.0)), ""
        c = CORNERS[i]
        scale, lag = e.corner_scale[i], e.corner_lag[i]
        for k, v in e.id_scale.items():
            if self.matches(k, sid):
                scale = scale * v
        for k, v in e.id_lag.items():
            if self.matches(k, sid):
                lag = lag + v
        if settings is None:  # a setting name of a fixed shock is refused on lookup
            return self.model_id(sid, scale, lag), ""

        def match(target):
            return self.matches(target, sid)

        note = ""
        name = sid
        steps = click_steps(e, c, match)
        if steps:
            entry = self.library.adjustable(base)
            every = steps.pop("*", 0.0)
            per = {k: every + steps.get(k, 0.0) for k in entry.names}
            moved, clipped = clicked_settings(entry, settings, per)
            name = entry.name(moved) if moved != settings else sid
            note = click_note(c, base, clipped)
        return self.model_id(name, scale, lag, fade_amounts(e, c, match)), note

    def full_library(self):
        """The crate (adjustable entries kept) and the derived shocks in one library."""
        return ShockLibrary(self.library.entries() + list(self.extra.values()),
                            source=self.library.source)


def condition_setups(setups, e, variants, tag, elements=None, stop_variants=None, third=None):
    """The setups under a condition: their shocks scaled or lagged, their bump stops swapped
    and packers changed, names tagged.

    Parameters
    ----------
    setups : sequence of planner.setups.Setup
    e : ConditionEffect
    variants : ShockVariants
        Makes (once) and names the derived shocks.
    tag : str
        The condition's tag, ``"<drive>:<perturbation>"`` (indices).
    elements : planner.elements.SetupElements, optional
        The setups' bump stops and packers, resolved (needed when the condition changes
        them: a swap replaces a stop, a packer change moves its contact).
    stop_variants : StopVariants, optional
        Makes (once) and names the moved stops of packer changes (and the scaled or moved
        heave springs of heave-spring factors).
    third : planner.elements.SetupThird, optional
        The setups' third elements, resolved (needed when the condition changes a third
        element's damper or a heave spring: the variant replaces the damper or spring the
        setup fits, its own or the baseline's).

    Returns
    -------
    list of planner.setups.Setup
        Named ``"<setup>\x1f<tag>"``; with every corner's bump stop and packer given
        when the condition changes them.

    Raises
    ------
    PlannerError
        A packer change at a corner without a stop, or one that makes the stop press on
        the car at rest.
    """
    out = []
    for k, s in enumerate(setups):
        kw = _third_setup(s, k, e, variants, third, stop_variants)
        if e.changes_elements:
            out.append(_element_setup(s, k, e, variants, tag, elements, stop_variants, kw))
            continue
        ids = {c: variants.corner_shock(sid, i, e)[0]
               for i, (c, sid) in enumerate(zip(CORNERS, s.ids()))}
        out.append(Setup(f"{s.name}\x1f{tag}", ids, **kw))
    return out


def _third_setup(s, k, e, variants, third, stop_variants):
    """A setup's ``third`` and ``heave_springs`` under a condition (Setup keywords).

    The setup's own keys are kept; a condition that changes a third element's damper
    names its scaled or lagged variant (:meth:`ShockVariants.model_id`, the setup's
    damper or the baseline's it keeps), one that changes a heave spring its scaled or
    moved variant (:meth:`StopVariants.scaled_id`, :meth:`StopVariants.stop_id`).
    """
    kw = {"third": dict(s.third) if s.third else None,
          "heave_springs": dict(s.heave_springs) if s.heave_springs else None}
    if not e.changes_third:
        return kw
    if third is None:
        raise PlannerError("what-if: a third-element factor on a car without third elements; "
                           "remove the factor, or use a model identified from a session that "
                           "declares third_elements")
    dampers = dict(kw["third"] or {})
    for element in sorted(set(e.third_scale) | set(e.third_lag)):
        sid = third.damper_ids[k].get(element)
        if sid is None:  # not fitted in this setup: nothing to scale or lag
            continue
        dampers[element] = variants.model_id(sid, e.third_scale.get(element, 1.0),
                                             e.third_lag.get(element, 0.0))
    springs = dict(kw["heave_springs"] or {})
    for axle in sorted(set(e.heave_packer_add) | set(e.heave_rate_scale)):
        scale = e.heave_rate_scale.get(axle, 1.0)
        change = e.heave_packer_add.get(axle, 0.0)
        if scale == 1.0 and change == 0.0:
            continue
        sid = third.spring_ids[k].get(axle)
        where = f"setup {s.name!r} column 'heave_spring_{axle}'"
        if sid is None:
            raise PlannerError(f"{where}: a heave spring factor on the {axle} axle, where the "
                               "setup has no heave spring; give it one or leave the axle out "
                               "of the factor's axles")
        sid = stop_variants.scaled_id(sid, scale, where)
        springs[axle] = stop_variants.stop_id(sid, change, where)
    kw["third"] = dampers or None
    kw["heave_springs"] = springs or None
    return kw


def condition_notes(setups, e, variants):
    """Where a condition's clicks hit the end of an adjuster's range, per setup.

    Parameters
    ----------
    setups : sequence of planner.setups.Setup
    e : ConditionEffect
    variants : ShockVariants

    Returns
    -------
    dict of str -> str
        Setup name -> ``"LF TTX ls 0-1 -> 0; RF ..."`` for the setups clipped.
    """
    out = {}
    if not e.click:
        return out
    for s in setups:
        notes = [variants.corner_shock(sid, i, e)[1] for i, sid in enumerate(s.ids())]
        text = "; ".join(n for n in notes if n)
        if text:
            out[s.name] = text
    return out


class StopVariants:
    """Bump stops moved by a packer change, made once per (stop, change) and named.

    A what-if ``packer`` change of ``d`` [m] moves the stop's contact ``d`` closer (a
    thicker packer) or farther (thinner, also below none: the stop's tolerance): the
    variant is the stop with the gap ``gap - d``, named ``"<id>~p<+d mm>"``, and the
    setup keeps its packer.

    Parameters
    ----------
    library : ident.models.bumpstops.BumpStopLibrary or None
    """

    def __init__(self, library):
        self.library = library
        self.extra = {}

    def stop_id(self, stop_id, change_m, where):
        """The id of `stop_id` with its contact moved by `change_m` [m] (made once)."""
        if not change_m:
            return stop_id
        if stop_id not in self.extra and (self.library is None or stop_id not in self.library):
            raise PlannerError(f"{where}: bump stop {stop_id!r} is not in the bump-stop "
                               "library; give the library (--bump-stops FILE)")
        new_id = f"{stop_id}~p{change_m * 1e3:+g}mm"
        if new_id not in self.extra:
            base = self.extra.get(stop_id) or self.library[stop_id]
            gap = base.gap_m - change_m
            if gap < 0:
                raise PlannerError(f"{where}: the packer change {change_m * 1e3:+g} mm is more "
                                   f"than bump stop {stop_id!r}'s gap "
                                   f"({base.gap_m * 1e3:g} mm): the stop would press on the "
                                   "car at rest; use a smaller change")
            self.extra[new_id] = BumpStop(new_id, gap, base.travel_m, base.force_n)
        return new_id

    def scaled_id(self, stop_id, scale, where):
        """The id of `stop_id` with its force table times `scale` (made once): a heave
        spring's rate tolerance (``"<id>~x<scale>"``)."""
        if scale == 1.0:
            return stop_id
        if self.library is None or stop_id not in self.library:
            raise PlannerError(f"{where}: heave spring {stop_id!r} is not in the bump-stop "
                               "library; give the library (--bump-stops FILE)")
        new_id = f"{stop_id}~x{scale:.12g}"
        if new_id not in self.extra:
            base = self.library[stop_id]
            self.extra[new_id] = BumpStop(new_id, base.gap_m, base.travel_m,
                                          np.asarray(base.force_n, float) * scale)
        return new_id

    def full_library(self):
        """The library and the moved stops in one library (None without a library)."""
        if self.library is None:
            return None
        return BumpStopLibrary(list(self.library.values()) + list(self.extra.values()))


def _element_setup(s, k, e, variants, tag, elements, stop_variants, kw):
    """One setup under a condition that changes its bump stops or packers."""
    ids = {c: variants.corner_shock(sid, i, e)[0]
           for i, (c, sid) in enumerate(zip(CORNERS, s.ids()))}
    if elements is None:
        stops, packers = [None] * 4, np.zeros(4)
    else:
        stops, packers = list(elements.stop_ids[k]), elements.packers_m[k].copy()
    for i, c in enumerate(CORNERS):
        if e.stop_set[i] is not None:
            stops[i] = None if e.stop_set[i].lower() == "none" else e.stop_set[i]
    for i, c in enumerate(CORNERS):
        if not e.packer_add[i]:
            continue
        if stops[i] is None:
            raise PlannerError(f"setup {s.name!r}: a packer change at {c}, which has no bump "
                               "stop; give the corner a bump stop or leave it out of the "
                               "packer factor's corners")
        where = f"setup {s.name!r} corner {c}"
        stops[i] = stop_variants.stop_id(stops[i], float(e.packer_add[i]), where)
        if stop_variants.extra[stops[i]].gap_m < packers[i]:
            raise PlannerError(f"{where}: the packer change {e.packer_add[i] * 1e3:+g} mm with "
                               f"its packer of {packers[i] * 1e3:g} mm is more than the gap "
                               "of its bump stop: the stop would press on the car at rest; "
                               "use a smaller change")
    return Setup(f"{s.name}\x1f{tag}", ids, bump_stops=dict(zip(CORNERS, stops)),
                 packers_m={c: float(p) for c, p in zip(CORNERS, packers)}, **kw)
