"""The physical full-car model of the seed paper (Eqs. 1-9), as a state-space system.

The 7-DOF model has a rigid chassis (heave ``z``, roll ``theta``, pitch ``phi``)
on four suspensions (linear spring plus an arbitrary shock force) and four
unsprung masses on linear tires. Two optional extensions make cars that are
*not* the paper's model, for testing that identification is generic: a chassis
torsion mode (front and rear halves twisting against a torsion spring) and
unequal half-tracks (a lateral centre-of-gravity offset, and different front
and rear tracks).

Inputs, in order: ``aero_heave`` [N], ``aero_roll`` [N*m], ``aero_pitch``
[N*m], ``wheelloader_LF/RF/LR/RR`` [m], ``shock_force_LF/RF/LR/RR`` [N].
Outputs: every response channel of the rig-session spec that is a function of
the state and the inputs (shock velocity, shock travel, tire force, ride
height, chassis and wheel acceleration, spring force); the shock force is an
input, not an output.

Notes
-----
Sign conventions (spec): displacements up positive; suspension deflection,
velocity and force, spring and tire forces positive in compression; roll
positive raises the left side, pitch positive raises the rear. The corner
transform is ``z_corner = T [z, theta, phi]`` with rows ``[1, y_c, x_c]`` where
``y_c`` is the corner's lateral position (left positive) and ``x_c`` its
longitudinal position (rear positive: ``-a`` front, ``+b`` rear).

With torsion, a twist coordinate ``psi`` is added: the front chassis rolls by
``theta + psi/2`` and the rear by ``theta - psi/2``; its inertia defaults to
a quarter of the roll inertia (front and rear halves each carry half).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from ident.data.channels import CORNERS, RIG_INPUTS
from ident.data.files import atomic_write_toml, read_toml
from ident.data.third import check_third_elements
from ident.data.units import check_units, from_si, to_si
from ident.errors import SessionError, VehicleError
from ident.models.lti import LoopPlant

__all__ = [
    "EXAMPLE_VEHICLE_PATH",
    "FULL_CAR_OUTPUT_KINDS",
    "G_M_S2",
    "VEHICLE_KEYS",
    "FullCarModel",
    "ModalSummary",
    "VehicleParams",
    "build_full_car",
    "example_gt_vehicle",
    "example_vehicle",
    "modal_summary",
    "mode_frequencies",
    "read_vehicle",
    "write_vehicle",
]

log = logging.getLogger(__name__)

G_M_S2 = 9.80665  # standard gravity [m/s^2]
EXAMPLE_VEHICLE_PATH = Path(__file__).parents[1] / "examples" / "paper_car.toml"

#: Output kinds of the physical model, in output order (each for LF, RF, LR, RR).
FULL_CAR_OUTPUT_KINDS = (
    "shock_velocity",
    "shock_travel",
    "tire_force",
    "ride_height",
    "chassis_accel",
    "wheel_accel",
    "spring_force",
)

#: The vehicle TOML's parameter keys: key -> (quantity, required); the quantity names the
#: unit conversion (:data:`ident.data.units.TO_SI`).
VEHICLE_KEYS = {
    "track": ("displacement", False),
    "track_front": ("displacement", False),
    "track_rear": ("displacement", False),
    "cg_lateral_offset": ("displacement", False),
    "cg_to_front_axle": ("displacement", True),
    "cg_to_rear_axle": ("displacement", True),
    "sprung_mass": ("mass", True),
    "roll_inertia": ("inertia", True),
    "pitch_inertia": ("inertia", True),
    "front_unsprung_mass": ("mass", True),
    "rear_unsprung_mass": ("mass", True),
    "front_spring_rate": ("stiffness", True),
    "rear_spring_rate": ("stiffness", True),
    "tire_stiffness": ("stiffness", False),
    "front_tire_stiffness": ("stiffness", False),
    "rear_tire_stiffness": ("stiffness", False),
    "damping": ("damping", False),
    "torsion_stiffness": ("rotational_stiffness", False),
    "torsion_inertia": ("inertia", False),
    "tire_damping": ("damping", False),
    "front_tire_damping": ("damping", False),
    "rear_tire_damping": ("damping", False),
    "tire_damping_corner": ("frequency", False),
    "front_arb_rate": ("stiffness", False),
    "rear_arb_rate": ("stiffness", False),
}


def _per_axle(front, rear):
    return np.array([front, front, rear, rear], dtype=float)


@dataclass(frozen=True, eq=False)
class VehicleParams:
    """Parameters of the full-car model, SI.

    Parameters
    ----------
    name : str
        Display name.
    track_front_m, track_rear_m : float
        Front and rear track widths [m].
    a_m, b_m : float
        Distances from the centre of gravity to the front and rear axles [m].
    sprung_mass_kg : float
        Chassis (sprung) mass [kg].
    roll_inertia_kg_m2, pitch_inertia_kg_m2 : float
        Chassis roll and pitch inertia about the centre of gravity [kg*m^2].
    unsprung_mass_kg : ndarray, shape (4,)
        Unsprung mass per corner LF, RF, LR, RR [kg].
    spring_rate_n_m : ndarray, shape (4,)
        Suspension spring wheel rate per corner [N/m].
    tire_rate_n_m : ndarray, shape (4,)
        Tire vertical stiffness per corner [N/m].
    damping_n_s_m : ndarray, shape (4,)
        Nominal linear damper per corner [N/(m/s)]; used for the modal summary
        and as the default shock of the analytic model, never by the rig.
    cg_lateral_offset_m : float
        Lateral offset of the centre of gravity, positive to the left [m]:
        the left half-tracks become ``t/2 - e`` and the right ``t/2 + e``.
    torsion_stiffness_n_m_rad : float or None
        Chassis torsion stiffness between the front and rear halves
        [N*m/rad]; ``None`` for a rigid chassis (the paper's model).
    torsion_inertia_kg_m2 : float or None
        Inertia of the twist coordinate [kg*m^2]; default a quarter of the
        roll inertia.
    tire_damping_n_s_m : ndarray, shape (4,) or None
        Tire damping per corner [N/(m/s)], in parallel with the tire rate;
        ``None`` (or zeros) for the paper's undamped tire.
    tire_damping_corner_hz : float
        The tire damper acts as a dashpot below this frequency [Hz] and as a
        stiff spring ``c * 2 pi f`` above it (a damper in series with that
        spring: a viscous tire force on a displacement-driven pad would need
        the pad's velocity, an improper response). Default 100 Hz, well above
        a rig's band.
    arb_rate_n_m : ndarray, shape (2,) or None
        Anti-roll bar rates at the wheels, front and rear [N/m].
    third_elements : dict of str to float or None
        The car's third elements (heave and roll elements per axle, the rig-session spec's
        "Third elements") and their motion ratios, ``{"heave_front": 1.0, ...}``
        (:data:`ident.data.third.THIRD_ELEMENTS`); the geometry only: what is fitted
        (dampers, heave springs) is a run's choice (:mod:`ident.sim.virtual_rig`). None:
        none. The linear model (:func:`build_full_car`) does not include them.
    """

    name: str
    track_front_m: float
    track_rear_m: float
    a_m: float
    b_m: float
    sprung_mass_kg: float
    roll_inertia_kg_m2: float
    pitch_inertia_kg_m2: float
    unsprung_mass_kg: np.ndarray
    spring_rate_n_m: np.ndarray
    tire_rate_n_m: np.ndarray
    damping_n_s_m: np.ndarray
    cg_lateral_offset_m: float = 0.0
    torsion_stiffness_n_m_rad: float | None = None
    torsion_inertia_kg_m2: float | None = None
    tire_damping_n_s_m: np.ndarray | None = None
    tire_damping_corner_hz: float = 100.0
    arb_rate_n_m: np.ndarray | None = None
    third_elements: dict | None = None

    def __post_init__(self):
        if self.third_elements is not None:
            try:
                checked = check_third_elements(dict(self.third_elements),
                                               f"vehicle {self.name!r}")
            except (SessionError, TypeError, ValueError) as exc:
                raise VehicleError(str(exc)) from None
            object.__setattr__(self, "third_elements", dict(checked.motion_ratios) or None)
        for f in fields(self):
            if f.name == "third_elements":
                continue
            val = getattr(self, f.name)
            if f.name in ("tire_damping_n_s_m", "arb_rate_n_m") and val is None:
                continue
            if f.name == "arb_rate_n_m":
                arr = np.array(val, dtype=float).reshape(-1)
                if arr.shape != (2,):
                    raise VehicleError(f"vehicle {self.name!r}: arb_rate_n_m must have 2 values "
                                       f"(front, rear), got {arr.size}")
                arr.setflags(write=False)
                object.__setattr__(self, f.name, arr)
                val = arr
            if f.name in ("unsprung_mass_kg", "spring_rate_n_m", "tire_rate_n_m", "damping_n_s_m",
                          "tire_damping_n_s_m"):
                arr = np.array(val, dtype=float).reshape(-1)
                if arr.shape != (4,):
                    raise VehicleError(
                        f"vehicle {self.name!r}: {f.name} must have 4 values (LF, RF, LR, RR), "
                        f"got {arr.size}"
                    )
                arr.setflags(write=False)
                object.__setattr__(self, f.name, arr)
                val = arr
            if f.name in ("name", "cg_lateral_offset_m"):
                continue
            if val is None:
                continue
            v = np.asarray(val, dtype=float)
            if not np.all(np.isfinite(v)):
                raise VehicleError(f"vehicle {self.name!r}: {f.name} is not finite; give a number")
            allow_zero = f.name in ("damping_n_s_m", "tire_damping_n_s_m", "arb_rate_n_m")
            if np.any(v < 0) or (not allow_zero and np.any(v == 0)):
                raise VehicleError(
                    f"vehicle {self.name!r}: {f.name} must be positive, got {val}; check the sign and units"
                )
        half = min(self.track_front_m, self.track_rear_m) / 2
        if abs(self.cg_lateral_offset_m) >= half:
            raise VehicleError(
                f"vehicle {self.name!r}: cg_lateral_offset ({self.cg_lateral_offset_m} m) must be "
                f"smaller than half the track ({half} m)"
            )

    @property
    def has_tire_damping(self):
        """True if any tire has damping."""
        return self.tire_damping_n_s_m is not None and bool(np.any(self.tire_damping_n_s_m > 0))

    @property
    def has_torsion(self):
        """True if the chassis has a torsion mode."""
        return self.torsion_stiffness_n_m_rad is not None

    @property
    def corner_y_m(self):
        """Lateral corner positions, left positive, LF RF LR RR [m], shape (4,)."""
        e = self.cg_lateral_offset_m
        tf, tr = self.track_front_m / 2, self.track_rear_m / 2
        return np.array([tf - e, -(tf + e), tr - e, -(tr + e)])

    @property
    def corner_x_m(self):
        """Longitudinal corner positions, rear positive [m], shape (4,)."""
        return np.array([-self.a_m, -self.a_m, self.b_m, self.b_m])

    @property
    def corner_matrix(self):
        """Corner transform ``T``, shape (4, 3) or (4, 4) with torsion: ``z_corner = T q_chassis``."""
        y, x = self.corner_y_m, self.corner_x_m
        cols = [np.ones(4), y, x]
        if self.has_torsion:
            cols.append(y * np.array([0.5, 0.5, -0.5, -0.5]))
        return np.column_stack(cols)

    @property
    def chassis_inertia(self):
        """Diagonal of the chassis mass matrix ``J_C`` [kg, kg*m^2, ...]."""
        j = [self.sprung_mass_kg, self.roll_inertia_kg_m2, self.pitch_inertia_kg_m2]
        if self.has_torsion:
            j.append(self.torsion_inertia_kg_m2 or self.roll_inertia_kg_m2 / 4)
        return np.array(j)

    @property
    def static_corner_load_n(self):
        """Static tire load per corner [N], shape (4,).

        Axle loads by the lever rule on ``a`` and ``b``, split left/right by the
        lever rule on the half-tracks (a car set up level with equal cross
        weights), plus the unsprung weight.
        """
        ms = self.sprung_mass_kg * G_M_S2
        wb = self.a_m + self.b_m
        axle = np.array([ms * self.b_m / wb, ms * self.a_m / wb])
        y = self.corner_y_m
        out = np.empty(4)
        for i, (l, r) in enumerate(((0, 1), (2, 3))):
            yl, yr = y[l], -y[r]
            out[l] = axle[i] * yr / (yl + yr)
            out[r] = axle[i] * yl / (yl + yr)
        return out + self.unsprung_mass_kg * G_M_S2

    @property
    def has_arb(self):
        """True if an axle has an anti-roll bar."""
        return self.arb_rate_n_m is not None and bool(np.any(self.arb_rate_n_m > 0))

    @property
    def suspension_stiffness(self):
        """Suspension stiffness between wheel and chassis at the corners [N/m], shape (4, 4).

        ``F = K t`` gives the elastic suspension forces (compression positive)
        for shock travels ``t`` (LF, RF, LR, RR): the spring wheel rates on the
        diagonal plus the anti-roll bars, ``k [[1, -1], [-1, 1]]`` per axle.
        """
        K = np.diag(self.spring_rate_n_m)
        if self.arb_rate_n_m is not None:
            for k, (l, r) in zip(self.arb_rate_n_m, ((0, 1), (2, 3))):
                K[np.ix_([l, r], [l, r])] += k * np.array([[1.0, -1.0], [-1.0, 1.0]])
        return K

    @property
    def roll_stiffness_n_m_rad(self):
        """Suspension (springs and anti-roll bars) roll stiffness of the chassis [N*m/rad]."""
        y = self.corner_y_m
        return float(y @ self.suspension_stiffness @ y)

    @property
    def pitch_stiffness_n_m_rad(self):
        """Suspension (spring) pitch stiffness of the chassis [N*m/rad]."""
        return float(np.sum(self.spring_rate_n_m * self.corner_x_m**2))

    def replace(self, **changes):
        """Return a copy with some fields changed (``dataclasses.replace``)."""
        import dataclasses

        return dataclasses.replace(self, **changes)


def _num(doc, key, where):
    val = doc[key]
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise VehicleError(f"{where}: '{key}' must be a number, got {val!r}; write e.g. {key} = 1.0")
    return float(val)


def vehicle_from_dict(doc, *, where="vehicle"):
    """Build :class:`VehicleParams` from a parsed vehicle TOML mapping (see :func:`read_vehicle`)."""
    fmt = doc.get("format", "vehicle/1")
    if fmt != "vehicle/1":
        raise VehicleError(f"{where}: format {fmt!r} is not supported; expected \"vehicle/1\"")
    units = check_units(doc.get("units", "SI"), where=f"{where}: 'units'", error=VehicleError)
    unknown = (set(doc) - set(VEHICLE_KEYS)
               - {"format", "units", "name", "description", "third_elements"})
    if unknown:
        raise VehicleError(
            f"{where}: unknown key(s) {sorted(unknown)}; known keys are {sorted(VEHICLE_KEYS)}"
        )
    v = {}
    for key, (quantity, required) in VEHICLE_KEYS.items():
        if key in doc:
            v[key] = to_si(_num(doc, key, where), quantity, units)
        elif required:
            raise VehicleError(f"{where}: required key '{key}' is missing; add it ({quantity})")
    track = v.get("track")
    tf, tr = v.get("track_front", track), v.get("track_rear", track)
    if tf is None or tr is None:
        raise VehicleError(f"{where}: give 'track' or both 'track_front' and 'track_rear'")
    tire = v.get("tire_stiffness")
    ktf, ktr = v.get("front_tire_stiffness", tire), v.get("rear_tire_stiffness", tire)
    if ktf is None or ktr is None:
        raise VehicleError(
            f"{where}: give 'tire_stiffness' or both 'front_tire_stiffness' and 'rear_tire_stiffness'"
        )
    if "torsion_inertia" in v and "torsion_stiffness" not in v:
        raise VehicleError(f"{where}: 'torsion_inertia' needs 'torsion_stiffness'; add it or remove both")
    ctire = v.get("tire_damping")
    ctf, ctr = v.get("front_tire_damping", ctire), v.get("rear_tire_damping", ctire)
    if (ctf is None) != (ctr is None):
        raise VehicleError(
            f"{where}: give 'tire_damping' or both 'front_tire_damping' and 'rear_tire_damping'"
        )
    if "tire_damping_corner" in v and ctf is None:
        raise VehicleError(f"{where}: 'tire_damping_corner' needs 'tire_damping'; add it or "
                           "remove both")
    return VehicleParams(
        name=str(doc.get("name", Path(str(where)).stem)),
        track_front_m=tf,
        track_rear_m=tr,
        a_m=v["cg_to_front_axle"],
        b_m=v["cg_to_rear_axle"],
        sprung_mass_kg=v["sprung_mass"],
        roll_inertia_kg_m2=v["roll_inertia"],
        pitch_inertia_kg_m2=v["pitch_inertia"],
        unsprung_mass_kg=_per_axle(v["front_unsprung_mass"], v["rear_unsprung_mass"]),
        spring_rate_n_m=_per_axle(v["front_spring_rate"], v["rear_spring_rate"]),
        tire_rate_n_m=_per_axle(ktf, ktr),
        damping_n_s_m=_per_axle(v.get("damping", 0.0), v.get("damping", 0.0)),
        cg_lateral_offset_m=v.get("cg_lateral_offset", 0.0),
        torsion_stiffness_n_m_rad=v.get("torsion_stiffness"),
        torsion_inertia_kg_m2=v.get("torsion_inertia"),
        tire_damping_n_s_m=None if ctf is None else _per_axle(ctf, ctr),
        tire_damping_corner_hz=v.get("tire_damping_corner", 100.0),
        arb_rate_n_m=(None if "front_arb_rate" not in v and "rear_arb_rate" not in v
                      else [v.get("front_arb_rate", 0.0), v.get("rear_arb_rate", 0.0)]),
        third_elements=_third_elements_of(doc, where),
    )


def _third_elements_of(doc, where):
    """The file's ``third_elements`` (motion ratios, dimensionless), or None."""
    value = doc.get("third_elements")
    if value is None:
        return None
    if not isinstance(value, dict):
        raise VehicleError(f"{where}: third_elements must be a table {{ heave_front = 1.0, ... "
                           f"}} of motion ratios, got {value!r}")
    try:
        return dict(check_third_elements(value, where).motion_ratios)
    except SessionError as exc:
        raise VehicleError(str(exc)) from None


def read_vehicle(path):
    """Read a vehicle TOML file (``format = "vehicle/1"``) and return SI parameters.

    Parameters
    ----------
    path : str or Path
        The file. Keys (units per the file's ``units``): ``track`` (or
        ``track_front``/``track_rear``), ``cg_to_front_axle``,
        ``cg_to_rear_axle``, ``sprung_mass``, ``roll_inertia``,
        ``pitch_inertia``, ``front_unsprung_mass``, ``rear_unsprung_mass`` (per
        corner), ``front_spring_rate``, ``rear_spring_rate`` (wheel rates),
        ``tire_stiffness`` (or per axle), optional ``damping``,
        ``cg_lateral_offset``, ``torsion_stiffness``, ``torsion_inertia``,
        ``front_arb_rate``, ``rear_arb_rate`` (anti-roll bars, at the wheels),
        ``third_elements = { heave_front = 1.0, roll_front = 0.8 }`` (the car's heave
        and roll elements and their motion ratios, dimensionless).
        Masses are mass (lbm in imperial files), not weight.

    Returns
    -------
    VehicleParams

    Raises
    ------
    VehicleError
        On a missing file, invalid TOML, unknown or missing keys, bad values.
    """
    path = Path(path)
    doc = read_toml(path, error=VehicleError, what="vehicle file")
    return vehicle_from_dict(doc, where=str(path))


def write_vehicle(params, path, *, units="SI", overwrite=False):
    """Write `params` as a vehicle TOML file in `units` (atomic).

    Per-axle values are written per axle; the left/right values of an axle must
    be equal (the file format has no per-corner rates).
    """
    units = check_units(units)
    p = params
    for arr, what in ((p.unsprung_mass_kg, "unsprung mass"), (p.spring_rate_n_m, "spring rate"),
                      (p.tire_rate_n_m, "tire rate"), (p.damping_n_s_m, "damping")):
        if arr[0] != arr[1] or arr[2] != arr[3]:
            raise VehicleError(f"vehicle {p.name!r}: left and right {what} differ; the vehicle file "
                               "format holds one value per axle")

    def c(x, q):
        return float(from_si(x, q, units))

    doc = {
        "format": "vehicle/1", "name": p.name, "units": units,
        "track_front": c(p.track_front_m, "displacement"),
        "track_rear": c(p.track_rear_m, "displacement"),
        "cg_to_front_axle": c(p.a_m, "displacement"),
        "cg_to_rear_axle": c(p.b_m, "displacement"),
        "sprung_mass": c(p.sprung_mass_kg, "mass"),
        "roll_inertia": c(p.roll_inertia_kg_m2, "inertia"),
        "pitch_inertia": c(p.pitch_inertia_kg_m2, "inertia"),
        "front_unsprung_mass": c(p.unsprung_mass_kg[0], "mass"),
        "rear_unsprung_mass": c(p.unsprung_mass_kg[2], "mass"),
        "front_spring_rate": c(p.spring_rate_n_m[0], "stiffness"),
        "rear_spring_rate": c(p.spring_rate_n_m[2], "stiffness"),
        "front_tire_stiffness": c(p.tire_rate_n_m[0], "stiffness"),
        "rear_tire_stiffness": c(p.tire_rate_n_m[2], "stiffness"),
        "damping": c(p.damping_n_s_m[0], "damping"),
    }
    if p.cg_lateral_offset_m:
        doc["cg_lateral_offset"] = c(p.cg_lateral_offset_m, "displacement")
    if p.has_torsion:
        doc["torsion_stiffness"] = c(p.torsion_stiffness_n_m_rad, "rotational_stiffness")
        if p.torsion_inertia_kg_m2 is not None:
            doc["torsion_inertia"] = c(p.torsion_inertia_kg_m2, "inertia")
    if p.tire_damping_n_s_m is not None:
        doc["front_tire_damping"] = c(p.tire_damping_n_s_m[0], "damping")
        doc["rear_tire_damping"] = c(p.tire_damping_n_s_m[2], "damping")
        doc["tire_damping_corner"] = c(p.tire_damping_corner_hz, "frequency")
    if p.arb_rate_n_m is not None:
        doc["front_arb_rate"] = c(p.arb_rate_n_m[0], "stiffness")
        doc["rear_arb_rate"] = c(p.arb_rate_n_m[1], "stiffness")
    if p.third_elements:
        doc["third_elements"] = dict(p.third_elements)
    atomic_write_toml(path, doc, overwrite=overwrite)


def example_vehicle():
    """The built-in example car: the seed paper's Table 1 (read from its imperial file)."""
    return read_vehicle(EXAMPLE_VEHICLE_PATH)


def example_gt_vehicle():
    """A GT-like car unlike the paper's, for checks on a car not tuned on (issue 24).

    Heavier (1,350 kg sprung) and stiffer (springs 280 / 320 kN/m against 224 /
    103, tires 420 / 450 kN/m), with a flexible chassis (torsion 2e5 N m/rad: a
    twist mode at 7.9 Hz, damping ratio 0.077 with its 800 N s/m tire damping)
    and the c.g. 2 cm off centre; the paper car's other parameters.

    Returns
    -------
    VehicleParams
    """
    return example_vehicle().replace(
        name="GT-like", track_front_m=1.66, track_rear_m=1.62, a_m=1.30, b_m=1.45,
        sprung_mass_kg=1350.0, roll_inertia_kg_m2=520.0, pitch_inertia_kg_m2=2100.0,
        unsprung_mass_kg=np.array([55.0, 55.0, 62.0, 62.0]),
        spring_rate_n_m=np.array([280e3, 280e3, 320e3, 320e3]),
        tire_rate_n_m=np.array([420e3, 420e3, 450e3, 450e3]),
        damping_n_s_m=np.full(4, 7000.0), torsion_stiffness_n_m_rad=2.0e5,
        tire_damping_n_s_m=np.full(4, 800.0), cg_lateral_offset_m=0.02)


@dataclass(frozen=True, eq=False)
class FullCarModel:
    """The physical full-car model as a continuous-time state-space system.

    Attributes
    ----------
    params : VehicleParams
    A, B, C, D : ndarray
        State-space matrices, shapes (n, n), (n, 11), (28, n), (28, 11). States
        are the generalized displacements then velocities.
    input_names, output_names : tuple of str
    """

    params: VehicleParams
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    input_names: tuple
    output_names: tuple
    mass_matrix: np.ndarray = field(repr=False)
    stiffness_matrix: np.ndarray = field(repr=False)

    def to_control(self):
        """Return the model as a ``control.StateSpace`` with named signals."""
        import control

        return control.ss(self.A, self.B, self.C, self.D, inputs=list(self.input_names),
                          outputs=list(self.output_names),
                          name=self.params.name.replace(".", ""))  # control forbids '.' in names

    def loop_plant(self, cbar_n_s_m=None):
        """The model as an :class:`ident.models.lti.LoopPlant` around linear damping `cbar_n_s_m`.

        Parameters
        ----------
        cbar_n_s_m : float or array_like, shape (4,), optional
            Baseline damping per corner [N/(m/s)]; default the vehicle's
            nominal damping. Any value gives the same closed loop with the same
            shocks; a realistic one keeps the plant itself well damped.
        """
        c = self.params.damping_n_s_m if cbar_n_s_m is None else np.broadcast_to(
            np.asarray(cbar_n_s_m, float), (4,))
        A, B, C, D = close_shock_loop(self.A, self.B, self.C, self.D, c)
        return LoopPlant.from_state_space(A, B, C, D, self.output_names, c, name=self.params.name)

    def frequency_response(self, f_hz, *, damping_n_s_m=None):
        """Frequency response with linear shocks closed around the model.

        Parameters
        ----------
        f_hz : array_like, shape (n_f,)
            Frequencies [Hz].
        damping_n_s_m : array_like, shape (4,), optional
            Linear shock damping per corner [N/(m/s)]; default the vehicle's
            nominal damping. ``0`` gives the open-loop response to the shock
            force inputs.

        Returns
        -------
        ndarray, shape (28, 11, n_f)
            ``H[output, input, frequency]`` with inputs the 7 rig inputs and the
            4 shock forces (additional force on top of the linear shocks).
        """
        c = self.params.damping_n_s_m if damping_n_s_m is None else np.broadcast_to(
            np.asarray(damping_n_s_m, float), (4,))
        A, B, C, D = close_shock_loop(self.A, self.B, self.C, self.D, c)
        s = 2j * np.pi * np.asarray(f_hz, dtype=float)
        n = A.shape[0]
        out = np.empty((C.shape[0], B.shape[1], s.size), dtype=complex)
        for k, sk in enumerate(s):
            out[:, :, k] = C @ np.linalg.solve(sk * np.eye(n) - A, B) + D
        return out


def close_shock_loop(A, B, C, D, damping_n_s_m):
    """Close linear shocks ``F = c v`` around a model whose last 4 inputs are shock forces.

    The first 4 outputs must be the shock velocities, with no direct
    feedthrough from the shock forces (true of the physical model). The shock
    force inputs remain as inputs: the returned system's last 4 inputs are the
    force *in addition to* ``c v`` (``dF`` of the paper's Eq. 18).

    Returns
    -------
    A, B, C, D : ndarray
        The closed-loop matrices (same shapes).
    """
    c = np.diag(np.asarray(damping_n_s_m, dtype=float))
    Cv, Dvf = C[:4], D[:4, -4:]
    if np.any(Dvf != 0):
        raise ValueError("close_shock_loop needs no feedthrough from shock force to shock velocity")
    Bf, Df = B[:, -4:], D[:, -4:]
    A2 = A + Bf @ c @ Cv
    B2 = B + Bf @ c @ D[:4]
    C2 = C + Df @ c @ Cv
    D2 = D + Df @ c @ D[:4]
    return A2, B2, C2, D2


def build_full_car(params):
    """Build the 7-DOF (8 with torsion) full-car state-space model of Eqs. 1-9.

    Parameters
    ----------
    params : VehicleParams

    Returns
    -------
    FullCarModel
        Inputs ``RIG_INPUTS + shock_force_XX`` (11), outputs
        ``<kind>_<corner>`` for kind in :data:`FULL_CAR_OUTPUT_KINDS` (28).

    Notes
    -----
    Equations of motion (Eq. 7): ``M q'' + K q = L u`` with
    ``q = [chassis coordinates, z_t]``,
    ``M = diag(J_C, M_t)``, ``K = [[T' Ks T (+ K_psi), -T' Ks], [-Ks T, Ks + Kt]]``,
    ``L = [[E, 0, T'], [0, Kt, -I]]`` where ``E`` maps the aero heave force,
    roll and pitch moments onto the chassis coordinates. With tire damping
    (``VehicleParams.tire_damping_n_s_m``) each tire also carries
    ``F_d = k_d (z_r - z_t - delta)`` with ``c delta' = F_d`` and ``k_d = c
    2 pi f_c``: 4 more states ``delta`` after ``[q, q']``.

    Examples
    --------
    >>> m = build_full_car(example_vehicle())
    >>> m.A.shape, m.B.shape, m.C.shape
    ((14, 14), (14, 11), (28, 14))
    """
    p = params
    T = p.corner_matrix
    nc = T.shape[1]
    Ks, Kt = p.suspension_stiffness, np.diag(p.tire_rate_n_m)
    M = np.diag(np.concatenate([p.chassis_inertia, p.unsprung_mass_kg]))
    Kc = T.T @ Ks @ T
    if p.has_torsion:
        Kc[3, 3] += p.torsion_stiffness_n_m_rad
    K = np.block([[Kc, -T.T @ Ks], [-Ks @ T, Ks + Kt]])
    E = np.zeros((nc, 3))
    E[:3, :3] = np.eye(3)
    L = np.block([[E, np.zeros((nc, 4)), T.T], [np.zeros((4, 3)), Kt, -np.eye(4)]])
    nq = nc + 4
    Minv = np.diag(1.0 / np.diag(M))
    # selectors on q: corner displacement and wheel displacement
    Sc = np.hstack([T, np.zeros((4, 4))])  # z_corner = Sc q
    St = np.hstack([np.zeros((4, nc)), np.eye(4)])  # z_t = St q
    Zu = np.zeros((4, 11))
    Ur = np.zeros((4, 11))
    Ur[:, 3:7] = np.eye(4)  # z_r = Ur u
    # tire dampers (Maxwell: dashpot c in series with k_d = c w_c), states delta (4):
    # F_d = k_d (z_r - z_t - delta), delta' = w_c (z_r - z_t - delta); none without damping
    nd = 4 if p.has_tire_damping else 0
    wc = 2 * np.pi * p.tire_damping_corner_hz
    Kd = np.diag(p.tire_damping_n_s_m * wc) if nd else np.zeros((4, 4))
    # q'' = acc_q q + acc_d delta + acc_u u
    acc_q = -Minv @ (K + St.T @ Kd @ St)
    acc_d = -Minv @ St.T @ Kd
    acc_u = Minv @ (L + St.T @ Kd @ Ur)
    n = 2 * nq + nd
    A = np.zeros((n, n))
    A[:nq, nq:2 * nq] = np.eye(nq)
    A[nq:2 * nq, :nq] = acc_q
    B = np.zeros((n, 11))
    B[nq:2 * nq] = acc_u
    if nd:
        A[nq:2 * nq, 2 * nq:] = acc_d[:, :nd]
        A[2 * nq:, :nq] = -wc * St
        A[2 * nq:, 2 * nq:] = -wc * np.eye(nd)
        B[2 * nq:] = wc * Ur

    def row(q=None, v=None, d=None):
        out = np.zeros((4, n))
        if q is not None:
            out[:, :nq] = q
        if v is not None:
            out[:, nq:2 * nq] = v
        if d is not None and nd:
            out[:, 2 * nq:] = d
        return out

    rows_C, rows_D = [], []
    # shock velocity = z_t' - z_corner'
    rows_C.append(row(v=St - Sc))
    rows_D.append(Zu)
    # shock travel = z_t - z_corner
    rows_C.append(row(q=St - Sc))
    rows_D.append(Zu)
    # tire force = Kt (z_r - z_t) + F_d
    rows_C.append(row(q=-(Kt + Kd) @ St, d=-Kd))
    rows_D.append((Kt + Kd) @ Ur)
    # ride height = z_corner - z_r
    rows_C.append(row(q=Sc))
    rows_D.append(-Ur)
    # chassis accel = Sc q'', wheel accel = St q''
    rows_C.append(row(q=Sc @ acc_q, d=Sc @ acc_d))
    rows_D.append(Sc @ acc_u)
    rows_C.append(row(q=St @ acc_q, d=St @ acc_d))
    rows_D.append(St @ acc_u)
    # spring force = k_spring (z_t - z_corner) (the coil alone, not the anti-roll bar)
    rows_C.append(row(q=np.diag(p.spring_rate_n_m) @ (St - Sc)))
    rows_D.append(Zu)
    C = np.vstack(rows_C)
    D = np.vstack(rows_D)
    inputs = RIG_INPUTS + tuple(f"shock_force_{c}" for c in CORNERS)
    outputs = tuple(f"{k}_{c}" for k in FULL_CAR_OUTPUT_KINDS for c in CORNERS)
    for arr in (A, B, C, D, M, K):
        arr.setflags(write=False)
    return FullCarModel(params=p, A=A, B=B, C=C, D=D, input_names=inputs,
                        output_names=outputs, mass_matrix=M, stiffness_matrix=K)


def mode_frequencies(poles):
    """Natural frequency, damped frequency and damping ratio of one vibration mode.

    A mode is a pair of poles of ``m x'' + c x' + k x = 0``:
    ``s = -zeta w_n +- j w_n sqrt(1 - zeta^2)`` when underdamped, two real poles
    ``s1 s2 = w_n^2``, ``s1 + s2 = -2 zeta w_n`` when overdamped.

    Parameters
    ----------
    poles : complex or array_like of complex, shape (1,) or (2,)
        The mode's pole with a positive imaginary part (its conjugate is implied), its
        conjugate pair, or its two real poles [rad/s].

    Returns
    -------
    f_n_hz : float
        Natural frequency ``w_n / (2 pi)`` [Hz], the mode's frequency without its damping.
    f_d_hz : float
        Damped natural frequency ``f_n sqrt(1 - zeta^2)`` [Hz] (0 when overdamped).
    zeta : float
        Damping ratio (``>= 1`` when overdamped, negative for an unstable mode).

    Raises
    ------
    ValueError
        If `poles` is neither one pole, a conjugate pair nor two real poles.

    Notes
    -----
    The three numbers come from the same poles, so ``f_d = f_n sqrt(1 - zeta^2)`` holds
    to round-off (python-control's ``damp`` gives the same ``w_n`` and ``zeta`` for a
    complex pole).

    Examples
    --------
    >>> import numpy as np
    >>> m, c, k = 2.0, 40.0, 800.0      # w_n = 20 rad/s, zeta = c / (2 sqrt(k m)) = 0.5
    >>> f_n, f_d, zeta = mode_frequencies(np.roots([m, c, k]))
    >>> round(f_n * 2 * np.pi, 12), round(zeta, 12), round(f_d / f_n, 12)
    (20.0, 0.5, 0.866025403784)
    """
    p = np.atleast_1d(np.asarray(poles, dtype=complex))
    if p.size == 2 and np.all(p.imag == 0):  # overdamped (or critically damped)
        s1, s2 = p.real
        wn = np.sqrt(s1 * s2) if s1 * s2 > 0 else 0.0
        zeta = -(s1 + s2) / (2 * wn) if wn > 0 else 1.0
        return float(wn / (2 * np.pi)), 0.0, float(zeta)
    if p.size == 2 and np.isclose(p[0], np.conj(p[1]), rtol=1e-9, atol=0.0):
        p = p[p.imag > 0]  # a conjugate pair
    if p.size != 1:
        raise ValueError(f"a mode has one complex pole or two real poles, got {p.tolist()}")
    s = p[0]
    wn = abs(s)
    zeta = -s.real / wn if wn > 0 else 1.0
    return float(wn / (2 * np.pi)), float(abs(s.imag) / (2 * np.pi)), float(zeta)


@dataclass(frozen=True, eq=False)
class ModalSummary:
    """Natural frequencies of the full-car model.

    Attributes
    ----------
    natural_hz : ndarray, shape (n_dof,)
        Natural frequency ``|s| / (2 pi)`` of each mode of the car with its shocks [Hz]
        (``f_n`` of :func:`mode_frequencies`): the frequency at which the mode would ring
        without its damping. Not :attr:`no_damping_hz`: stiff shocks couple chassis and
        wheels (their damping is not proportional), which moves ``|s|``.
    labels : tuple of str
        The dominant coordinate of each mode without damping (by modal kinetic energy):
        ``heave``, ``roll``, ``pitch``, ``twist``, ``hop_LF``, ...
    damped_hz : ndarray, shape (n_dof,)
        Damped natural frequencies ``Im(s) / (2 pi)`` [Hz] (0 for overdamped modes): in
        every mode ``damped_hz = natural_hz sqrt(1 - damping_ratio^2)``.
    damping_ratio : ndarray, shape (n_dof,)
        Damping ratio ``-Re(s) / |s|`` of each mode with the given shocks (of the two real
        poles of an overdamped mode, ``>= 1``).
    damping_n_s_m : ndarray, shape (4,)
        The linear shock damping used [N/(m/s)].
    no_damping_hz : ndarray, shape (n_dof,)
        Natural frequencies of the car without shocks and tire dampers [Hz], ascending
        (``K phi = w^2 M phi``, what a ride-rate hand calculation gives); the modes are in
        this order.

    Notes
    -----
    ``natural_hz``, ``damped_hz`` and ``damping_ratio`` come from one eigenproblem, the
    closed loop with the shocks; each of its modes is matched to the mode without
    damping of the most similar shape. A damped frequency compared with
    ``no_damping_hz`` instead can lie above it (the paper's car: heave, pitch and roll).
    """

    natural_hz: np.ndarray
    labels: tuple
    damped_hz: np.ndarray
    damping_ratio: np.ndarray
    damping_n_s_m: np.ndarray
    no_damping_hz: np.ndarray

    def table(self):
        """The summary as a ``pandas.DataFrame`` (one row per mode)."""
        import pandas as pd

        return pd.DataFrame({"mode": self.labels, "natural_hz": self.natural_hz,
                             "damped_hz": self.damped_hz, "damping_ratio": self.damping_ratio,
                             "no_damping_hz": self.no_damping_hz})


def modal_summary(model, *, damping_n_s_m=None):
    """Natural frequencies, damped frequencies and damping ratios of a full-car model.

    Parameters
    ----------
    model : FullCarModel or VehicleParams
    damping_n_s_m : float or array_like, shape (4,), optional
        Linear shock damping per corner [N/(m/s)]; default the vehicle's nominal.

    Returns
    -------
    ModalSummary

    Examples
    --------
    >>> s = modal_summary(example_vehicle())
    >>> bool(np.all(s.damped_hz <= s.natural_hz))
    True
    """
    if isinstance(model, VehicleParams):
        model = build_full_car(model)
    p = model.params
    c = p.damping_n_s_m if damping_n_s_m is None else np.broadcast_to(
        np.asarray(damping_n_s_m, float), (4,)).copy()
    M, K = model.mass_matrix, model.stiffness_matrix
    # without damping: K phi = w^2 M phi (M diagonal): symmetric form
    ms = 1 / np.sqrt(np.diag(M))
    w2, vec = np.linalg.eigh(ms[:, None] * K * ms[None, :])
    order = np.argsort(w2)
    w2, vec = w2[order], vec[:, order]
    nc = p.corner_matrix.shape[1]
    names = ["heave", "roll", "pitch", "twist"][:nc] + [f"hop_{c}" for c in CORNERS]
    labels = tuple(names[int(np.argmax(vec[:, i] ** 2))] for i in range(len(w2)))
    no_damping = np.sqrt(np.maximum(w2, 0)) / (2 * np.pi)
    # with the shocks: the closed loop's poles, assigned to those modes by shape
    A, _, _, _ = close_shock_loop(model.A, model.B, model.C, model.D, c)
    lam, V = np.linalg.eig(A)
    nq = M.shape[0]
    keep = np.ones(lam.size, dtype=bool)
    if p.has_tire_damping:  # the tire dampers' relaxation roots (near -2 pi f_c) are no modes
        wc = 2 * np.pi * p.tire_damping_corner_hz
        keep[np.argsort(np.abs(lam + wc))[:4]] = False
    # shapes compared mass-weighted (M^1/2 q: kinetic energy, whatever the coordinates'
    # units), where the modes without damping are orthonormal (`vec`)
    shapes = V[:nq] / ms[:, None]
    shapes /= np.maximum(np.linalg.norm(shapes, axis=0), 1e-300)
    mac = np.abs(vec.T @ shapes)  # (mode, pole): 1 for the same shape
    upper = np.flatnonzero(keep & (lam.imag > 0))  # one pole of each oscillating mode
    real = np.flatnonzero(keep & (lam.imag == 0))  # overdamped modes: two real poles each
    # the oscillating poles to the modes they resemble most (one each, best total), then
    # the real poles in pairs to the modes left
    rows, cols = linear_sum_assignment(mac[:, upper], maximize=True)
    poles = {int(i): [lam[upper[j]]] for i, j in zip(rows, cols)}
    rest = np.array([i for i in range(nq) if i not in poles], dtype=np.intp)
    if rest.size and real.size:
        slots = np.repeat(rest, 2)
        rows, cols = linear_sum_assignment(mac[np.ix_(slots, real)], maximize=True)
        for r, j in zip(rows, cols):
            poles.setdefault(int(slots[r]), []).append(lam[real[j]])
    natural, damped, zeta = np.full(nq, np.nan), np.full(nq, np.nan), np.full(nq, np.nan)
    for i, pl in poles.items():
        natural[i], damped[i], zeta[i] = mode_frequencies(pl)
    return ModalSummary(natural_hz=natural, labels=labels, damped_hz=damped,
                        damping_ratio=zeta, damping_n_s_m=np.asarray(c, float),
                        no_damping_hz=no_damping)
