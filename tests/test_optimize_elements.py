"""Tests of planner.optimize with the real car's elements (issue 25): bump stops in the casadi
loop, packers as decision variables, stops and lift-off in the time-domain verification."""

import warnings

import casadi as ca
import numpy as np
import pytest

from ident.data.channels import CORNERS
from ident.models.shocks import DigressiveShock
from ident.sim.closedloop import simulate_batch
from ident.sim.metrics import compute_metrics
from planner.errors import PlannerError
from planner.objective import Objective
from planner.optimize import OptimizeWarning, optimize_curves
from planner.optimize.loop import LoopModel, stop_force_sx
from planner.optimize.scan import element_predictions, is_element_metric
from planner.optimize.space import curve_space
from planner.predict import prepare_drive
from planner.screen import metric_rows
from planner.optimize import CurveOptions, SolverOptions
from planner.options import ElementOptions

#: A progressive bump stop: 100, 267, 500 and 600 kN/m over 15 mm beyond contact (as
#: tests/test_closedloop.py), touching at 3.5 mm front and 4.5 mm rear from rest.
STOP_TRAVEL_M = [0.0, 0.002, 0.005, 0.010, 0.015]
STOP_FORCE_N = [0.0, 200.0, 1000.0, 3500.0, 6500.0]
SMALL_KNOTS = (0.05, 0.15, 0.4)  # [m/s] three knots a side keep the problems small
#: The rounded stop more than a half-width (0.1 mm) from every kink: the table to rounding.
ATOL_SMOOTH_FORCE_N = 1e-9
ATOL_SMOOTH_STIFFNESS_N_M = 1e-6
#: The casadi loop's metrics with stops against simulate_batch's, less the same difference
#: without stops (the casadi loop's forward |B|^4 filter against sosfiltfilt, the same with
#: or without stops): what the stops add, the rounding of the kinks (0.1 mm) and
#: rounding. Measured 3.1e-5 max on a 60 s drive (the stops move the metrics by 1.4 %).
ATOL_STOP_PART = 2e-4
#: The loop with a packer variable p against the loop with the contact travel shortened by
#: p: the same arithmetic but for the order of one subtraction.
RTOL_PACKER_SHIFT = 1e-12
#: The adjoint's derivative with respect to a packer against central differences (step
#: 1 um, inside the 0.1 mm rounding): the truncation error of the difference.
RTOL_PACKER_GRADIENT = 1e-3
#: The optimum against the scan's best (both verified with the stops): the optimum is the
#: best verified of IPOPT's result, its best iterate and the scan's best, so never worse.
RTOL_SCAN_FLOOR = 1e-9
#: A packer at its bound: IPOPT's interior point meets bounds to its tolerance, scaled by
#: the packer's scale (1 mm).
ATOL_PACKER_BOUND_M = 2e-5


def _stops(front_m=0.0035, rear_m=0.0045):
    return [(front_m if c[1] == "F" else rear_m, STOP_TRAVEL_M, STOP_FORCE_N) for c in CORNERS]


@pytest.fixture(scope="module")
def drive(bumpstop_vehicle):
    """A 20 s track drive with aero load: the stops are touched 3-7 % of the time."""
    from ident.data.drive import make_track_drive

    v = bumpstop_vehicle
    d = make_track_drive(duration_s=20.0, fs_hz=100.0, seed=3, roughness_m3=16e-6,
                         wheelbase_m=v.a_m + v.b_m, track_width_m=v.track_front_m,
                         aero={"aero_heave": 1500.0, "aero_pitch": 800.0, "aero_roll": 300.0},
                         name="gt")
    return prepare_drive(d, None)


@pytest.fixture(scope="module")
def plant(bumpstop_vehicle):
    from ident.models.vehicle import build_full_car

    return build_full_car(bumpstop_vehicle).loop_plant(np.full(4, 9000.0))


def test_stop_force_is_the_table_away_from_its_kinks():
    """The smoothed stop force: zero before contact, the table between its points, its last
    slope beyond, and the table's slope as the stiffness."""
    z = ca.SX.sym("z")
    g, dg = stop_force_sx(z, STOP_TRAVEL_M, STOP_FORCE_N)
    f = ca.Function("f", [z], [g, dg])
    for travel, force, slope in ((-0.002, 0.0, 0.0), (0.001, 100.0, 1e5), (0.0035, 600.0,
                                                                             800e3 / 3),
                                 (0.0125, 5000.0, 6e5), (0.02, 9500.0, 6e5)):
        got, k = (float(v) for v in f(travel))
        assert got == pytest.approx(force, abs=ATOL_SMOOTH_FORCE_N), travel
        assert k == pytest.approx(slope, abs=ATOL_SMOOTH_STIFFNESS_N_M), travel


def test_casadi_loop_with_stops_matches_the_simulator(plant, drive):
    """The optimizer's loop with bump stops gives simulate_batch's metrics (what the stops
    add, to ATOL_STOP_PART); a packer variable is the contact travel shortened; its adjoint
    gradient is the central difference, and a thicker front packer moves the front."""
    space = curve_space(symmetry="left-right", knots_m_s=SMALL_KNOTS, lag_s=[0.002, 0.002])
    shock = DigressiveShock("G", bump_low_n_s_m=9000, bump_knee_m_s=0.08, bump_high_n_s_m=3500,
                            rebound_low_n_s_m=14000, rebound_knee_m_s=0.08,
                            rebound_high_n_s_m=5000, lag_s=0.002)
    x = space.from_curves([shock.to_pwl(), shock.to_pwl()])
    shocks = space.shocks(x)
    setup = [shocks[shocks.ids[space.group_of(c)]] for c in CORNERS]
    names, L = metric_rows(plant)
    T = ca.DM(space.expansion())

    def casadi_metrics(stops, pidx=None):
        lm = LoopModel(plant, drive, space, (names, L), 2, False, bump_stops=stops,
                       packer_index=pidx)
        n_p = 0 if pidx is None else 2
        P = ca.MX.sym("P", space.n_vars + n_p)
        m = lm.metrics(ca.vertcat(T @ P[:space.n_vars], P[space.n_vars:]))
        return ca.Function("m", [P], [m, ca.jacobian(m[0], P)])

    def reference(stops):
        b = simulate_batch(plant, drive, [setup], oversample=2,
                           bump_stops=None if stops is None else [stops])
        met = compute_metrics(b.channels, fs=b.fs_hz).values
        return np.array([float(np.ravel(met[n])[0]) for n in names]), b.elements

    plain = np.array(casadi_metrics(None)(x)[0]).ravel()
    ref_plain, _ = reference(None)
    with_stops = np.array(casadi_metrics(_stops())(x)[0]).ravel()
    ref_stops, elements = reference(_stops())
    assert min(elements["bump_stop_contact_share_LF"][0],
               elements["bump_stop_contact_share_LR"][0]) > 0.02  # the stops are touched
    assert np.max(np.abs(ref_stops / ref_plain - 1)) > 10 * ATOL_STOP_PART  # and matter
    err = np.abs(with_stops / ref_stops - plain / ref_plain)
    assert err.max() < ATOL_STOP_PART, (names[int(err.argmax())], err.max())

    # a packer variable: 1 mm front, 0.5 mm rear = the stops' contact travel shortened
    fn = casadi_metrics(_stops(), [0, 0, 1, 1])
    xp = np.concatenate([x, [0.001, 0.0005]])
    got, grad = (np.array(a) for a in fn(xp))
    shifted = np.array(casadi_metrics(_stops(0.0025, 0.004))(x)[0]).ravel()
    np.testing.assert_allclose(got.ravel(), shifted, rtol=RTOL_PACKER_SHIFT)
    h = 1e-6
    for j in (-2, -1):
        e = np.zeros(xp.size)
        e[j] = h
        fd = (float(fn(xp + e)[0][0]) - float(fn(xp - e)[0][0])) / (2 * h)
        assert grad.ravel()[j] == pytest.approx(fd, rel=RTOL_PACKER_GRADIENT)
    assert abs(grad.ravel()[-2]) > 10 * abs(grad.ravel()[-1])  # LF's tire force: front


def test_element_metric_names():
    assert is_element_metric("tire_liftoff_share_LF")
    assert is_element_metric("bump_stop_contact_share_RR")
    assert not is_element_metric("tire_force_rms_LF")
    assert not is_element_metric("tire_liftoff_share_front")


def test_bad_packers_are_refused(bumpstop_vehicle, drive, demo_library):
    """A packer thicker than the contact travel, packers without stops, for an unknown group
    or a group without stops, and bounds the wrong way round: refused, naming the fix."""
    kw = {"baseline": "DM", "curves": CurveOptions(knots_m_s=SMALL_KNOTS),
          "solver": SolverOptions(max_iter=1)}
    cases = [
        ({"stop_tables": _stops(), "packers": {"front": (0.0, 0.004)}}, "thicker than the gap"),
        ({"packers": {"front": (0.0, 0.002)}}, "without bump stops"),
        ({"stop_tables": _stops(), "packers": {"axle": (0.0, 0.002)}}, "unknown group 'axle'"),
        ({"stop_tables": [None, None, *_stops()[2:]], "packers": {"front": (0.0, 0.002)}},
         "has no bump stop"),
        ({"stop_tables": _stops(), "packers": {"rear": (0.003, 0.001)}}, "above the upper"),
    ]
    for extra, words in cases:
        with pytest.raises(PlannerError, match=words):
            optimize_curves(bumpstop_vehicle, drive, demo_library, **kw, **extra)


@pytest.mark.slow
def test_optimum_with_stops_is_verified_with_them(bumpstop_vehicle, drive, demo_library):
    """Stops declared (and static loads: lift-off in the verification): the optimum is
    verified in the time domain with the stops, at least as good as the scan's best (also
    verified with them), and its score is that of an independent simulation with the stops."""
    static = [3000.0, 3000.0, 3100.0, 3100.0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptimizeWarning)
        opt = optimize_curves(bumpstop_vehicle, drive, demo_library, baseline="DM",
                              curves=CurveOptions(knots_m_s=SMALL_KNOTS),
                              solver=SolverOptions(max_iter=15, n_starts=1, stationarity=False,
                                                   n_closest=1), stop_tables=_stops(),
                              elements=ElementOptions(static_corner_load_n=static))
    assert opt.settings["bump_stops"] and opt.settings["static_corner_load_n"] == static
    assert opt.packers_m == {}
    assert [st[0] for st in opt.bump_stops] == [0.0035, 0.0035, 0.0045, 0.0045]
    assert opt.score <= opt.settings["scan"]["score"] * (1 + RTOL_SCAN_FLOOR)
    met = opt.metrics["gt"]
    assert (met["bump_stop_contact_share_LF"] > 0.02).all()
    assert ((met["tire_liftoff_share_RR"] >= 0) & (met["tire_liftoff_share_RR"] <= 1)).all()
    # the optimum simulated again, with and without the stops
    lib = type(demo_library)(list(opt.shocks.values()) + list(demo_library.values()))
    again = element_predictions(bumpstop_vehicle, drive, [opt.setup], lib, [_stops()],
                                static_corner_load_n=static)
    cols = [c for c in met.columns if c.startswith(("tire_force_rms", "shock_travel_rms"))]
    np.testing.assert_allclose(again.loc["optimum", cols].to_numpy(float),
                               met.loc["optimum", cols].to_numpy(float), rtol=1e-12)
    bare = element_predictions(bumpstop_vehicle, drive, [opt.setup], lib, [None])
    assert not np.allclose(bare.loc["optimum", cols].to_numpy(float),
                           met.loc["optimum", cols].to_numpy(float), rtol=1e-3)


@pytest.mark.slow
def test_packers_move_where_the_objective_asks(bumpstop_vehicle, drive, demo_library):
    """Packers as decision variables (bounds 0.5-3 mm): an objective on the shock travels
    (which thicker packers reduce on this car) takes the front packer to its upper bound; one
    on the band-passed ride heights (which the stops' contact raises) keeps both at the
    lower; the choice is within its bounds and the optimum is verified with it."""
    bounds = {"front": (0.0005, 0.003), "rear": (0.0005, 0.003)}
    runs = {}
    for name, weights in (("travel", {f"shock_travel_rms_{c}": 1.0 for c in CORNERS}),
                          ("ride", {"ride_height_rms_front": 1.0, "ride_height_rms_rear": 1.0})):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OptimizeWarning)
            runs[name] = optimize_curves(bumpstop_vehicle, drive, demo_library, baseline="DM",
                                         objective=Objective(name, weights),
                                         curves=CurveOptions(knots_m_s=SMALL_KNOTS),
                                         solver=SolverOptions(max_iter=15, n_starts=1,
                                                              stationarity=False, n_closest=1),
                                         stop_tables=_stops(), packers=bounds)
    for opt in runs.values():
        assert opt.settings["packers"] == {g: list(b) for g, b in bounds.items()}
        for g, p in opt.packers_m.items():
            assert bounds[g][0] <= p <= bounds[g][1]
        # verified with the chosen packers
        assert [st[0] for st in opt.bump_stops] == pytest.approx(
            [0.0035 - opt.packers_m["front"]] * 2 + [0.0045 - opt.packers_m["rear"]] * 2)
    assert runs["travel"].packers_m["front"] == pytest.approx(0.003, abs=ATOL_PACKER_BOUND_M)
    assert runs["travel"].packers_m["rear"] > 0.001
    for g in ("front", "rear"):
        assert runs["ride"].packers_m[g] == pytest.approx(0.0005, abs=ATOL_PACKER_BOUND_M)
