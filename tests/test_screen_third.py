"""Tests of the screening with third elements (planner.screen with ``third=``,
planner.screen_third_kernels): known answers (linear lag-free elements are exact against the
truth simulator; no element is the plain screening), an equivalence (a linear heave damper
is the plant with that damping closed around it), the ranking against the time domain with
nonlinear lagged corner and heave dampers, a gapped heave spring, the resolution of the
setups' choices against a model's baseline, and the kernel's 4x4 inverse."""

from types import SimpleNamespace

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.stats import spearmanr

from ident.data.channels import CORNERS
from ident.data.drive import make_track_drive
from ident.data.third import CarThird, RunThird, ThirdElements, element_row
from ident.models.bumpstops import BumpStop, BumpStopLibrary
from ident.models.library import ShockLibrary
from ident.models.shocks import DigressiveShock, LinearShock, TableShock
from ident.models.vehicle import build_full_car, example_vehicle
from ident.sim.metrics import METRIC_NAMES, bandpass, compute_metrics
from ident.sim.third_loop import ThirdDamper, ThirdSpring, simulate_third
from planner.errors import PlannerError
from planner.options import ScreenOptions
from planner.screen import (
    ThirdChoices,
    drive_bands,
    resolve_third,
    screen_response,
    screen_setups,
)
from planner.screen_codegen import committed_source, third_band_source
from planner.screen_third_kernels import inverse_cofactor
from planner.setups import Setup

# The virtual rig's internal grid: the truth simulator of a stiff lagged heave damper goes
# unstable at 200 Hz (its lag's fast pole), not at 800 Hz.
FS_HZ = 800.0
MR = 1.2
ELEMENTS = ("heave_front", "roll_front", "heave_rear")  # any order: the kernel's slots
ROWS = np.array([element_row(e, MR) for e in ELEMENTS])

# Linear lag-free shocks and elements, screening vs the truth simulator on a 60 s drive: both
# exact linear analyses; what differs is how the drive's power is taken (a Welch estimate in
# 96 bands against the whole record). As in tests/test_screen.py the absolute error is the
# Welch estimate's, common to every setup (measured 2.1 % max, 0.7 % median over 3 setups x
# 20 metrics); as ratios to the first setup it cancels (measured 1.1 % max, 0.06 % median).
RTOL_LINEAR_MAX = 0.045
RTOL_LINEAR_RATIO_MAX = 0.015
RTOL_LINEAR_RATIO_MEDIAN = 0.004
# The dense kernel against the plain one (no element) and against the plant with the linear
# heave damper closed around it: the same fixed point run to tol = 1e-12, other arithmetic
# (cofactor inverse, dense products): round-off amplified by the fixed point (measured
# 3e-12).
RTOL_SAME_FIXED_POINT = 1e-8
TIGHT = ScreenOptions(tol=1e-12, max_iter=200)
# Nonlinear lagged corner and heave dampers: screening's ranking of the setups against the
# truth simulator's (measured Spearman 1.0, ratio error 3.1 % max: see
# test_ranking_agrees_with_the_time_domain); the plain screening's criterion is 0.95.
SPEARMAN_MIN = 0.95
RTOL_NONLINEAR_RATIO_MAX = 0.05
# A gapped heave spring: the screening's change of the metrics by the spring against the
# truth simulator's (see test_heave_spring_linearized_follows_the_time_domain); the Gaussian
# contact share against the share of time the truth's spring force is on: measured 0.052
# off at the rear (0.229 against 0.280), of which ~0.02 is the travel's skew (-0.55: the
# asymmetric heave dampers; the Gaussian share of the truth's own mean and RMS is 0.260) and
# the rest the linearized travel RMS 6 % low (the travel's power below the screening's
# 0.2 Hz bands and the Welch estimate); the front within 0.01.
RTOL_SPRING_EFFECT_MAX = 0.04
SPRING_EFFECT_SHRINK = 3.0
ATOL_CONTACT_SHARE = 0.065
# The 4x4 cofactor inverse against numpy.linalg.inv for condition numbers <= 100: round-off
# of a few eps times the condition number (measured 2e-14).
RTOL_INVERSE = 1e-12


@pytest.fixture(scope="module")
def car():
    return build_full_car(example_vehicle())


@pytest.fixture(scope="module")
def plant(car):
    return car.loop_plant(np.array([3000.0] * 4))


@pytest.fixture(scope="module")
def drive():
    veh = example_vehicle()
    return make_track_drive(duration_s=60.0, fs_hz=FS_HZ, seed=3,
                            wheelbase_m=veh.a_m + veh.b_m, track_width_m=veh.track_front_m,
                            aero={"aero_heave": 1500.0, "aero_pitch": 800.0,
                                  "aero_roll": 300.0})


def _setup(name, front, rear):
    return Setup(name, {"LF": front, "RF": front, "LR": rear, "RR": rear})


def _choices(dampers, springs=None):
    springs = springs or [(None,) * len(ELEMENTS)] * len(dampers)
    return ThirdChoices(ELEMENTS, ROWS, dampers=tuple(map(tuple, dampers)),
                        springs=tuple(map(tuple, springs)))


def _truth(plant, drive, setups, library, third, responses=None):
    """The truth simulator's metrics (the screening's names) per setup (its responses
    appended to `responses`)."""
    out = []
    for i, s in enumerate(setups):
        dampers = [ThirdDamper(e, ROWS[j], d) for j, (e, d) in
                   enumerate(zip(ELEMENTS, third.dampers[i])) if d is not None]
        springs = [ThirdSpring(e, ROWS[j], sp) for j, (e, sp) in
                   enumerate(zip(ELEMENTS, third.springs[i])) if sp is not None]
        r = simulate_third(plant, drive, s.resolve(library), dampers=dampers, springs=springs)
        if responses is not None:
            responses.append(r)
        m = dict(compute_metrics(r.channels, fs=drive.fs_hz).values)
        for e in ELEMENTS:
            kind, axle = e.split("_")
            for what in ("travel", "velocity"):
                x = r.channels[f"shock_{what}_{CORNERS[0]}"] * 0.0
                for c, corner in enumerate(CORNERS):
                    x = x + ROWS[ELEMENTS.index(e), c] * r.channels[f"shock_{what}_{corner}"]
                m[f"{kind}_{what}_rms_{axle}"] = float(np.sqrt(np.mean(
                    bandpass(x - x.mean(), fs=drive.fs_hz) ** 2)))
        out.append(m)
    return out


def _table(pred, truth):
    names = [n for n in pred.metric_names if "contact_share" not in n]
    return (pred.table[names].to_numpy(float),
            np.array([[m[n] for n in names] for m in truth]))


# ---------------------------------------------------------------- known answers


def test_linear_elements_match_the_truth_simulator(plant, drive):
    """Linear lag-free corner shocks and third elements: the linearization is exact, so the
    screening is linear frequency-domain analysis of the coupled loop and matches the truth
    simulator up to the finite record's spectral estimate (common to all setups)."""
    lib = ShockLibrary.from_models([LinearShock("C3", 3000.0), LinearShock("C2", 2000.0)])
    setups = [_setup("a", "C3", "C3"), _setup("b", "C2", "C3"), _setup("c", "C3", "C2")]
    h4, h8, r2 = LinearShock("H4", 4000.0), LinearShock("H8", 8000.0), LinearShock("R2", 2000.0)
    third = _choices([(h4, None, h4), (h8, r2, None), (None, r2, h8)])
    pred = screen_setups(plant, drive, setups, lib, third=third)
    names = pred.metric_names
    assert names == list(METRIC_NAMES) + [
        "heave_travel_rms_front", "heave_velocity_rms_front", "roll_travel_rms_front",
        "roll_velocity_rms_front", "heave_travel_rms_rear", "heave_velocity_rms_rear"]
    A, B = _table(pred, _truth(plant, drive, setups, lib, third))
    assert np.abs(A / B - 1).max() < RTOL_LINEAR_MAX
    ratio = np.abs((A / A[0]) / (B / B[0]) - 1)
    assert ratio.max() < RTOL_LINEAR_RATIO_MAX
    assert np.median(ratio) < RTOL_LINEAR_RATIO_MEDIAN
    # the elements matter: the heave damper moves the heave velocity by far more than that
    j = names.index("heave_velocity_rms_front")
    assert abs(B[2, j] / B[0, j] - 1) > 5 * RTOL_LINEAR_RATIO_MAX
    assert pred.diagnostics["iterations"].max() <= 2
    assert_allclose(pred.diagnostics["third_damping_eq"][0], [4000.0, 0.0, 4000.0])
    assert pred.settings["third_elements"] == list(ELEMENTS)


def _nonlinear_library():
    def shock(name, scale):
        return DigressiveShock(name, bump_low_n_s_m=6000 * scale, bump_knee_m_s=0.06,
                               bump_high_n_s_m=2000 * scale,
                               rebound_low_n_s_m=9000 * scale, rebound_knee_m_s=0.06,
                               rebound_high_n_s_m=3000 * scale, lag_s=0.003)

    return ShockLibrary.from_models([shock("G07", 0.7), shock("G10", 1.0), shock("G14", 1.4)])


def _heave(name, scale, lag_s=0.004):
    return TableShock(name, velocity_m_s=[-0.3, -0.05, 0.0, 0.05, 0.3],
                      force_n=[-5000 * scale, -1500 * scale, 0.0, 1000 * scale, 3500 * scale],
                      lag_s=lag_s)


def test_no_element_is_the_plain_screening(plant, drive):
    """Declared elements none of which is fitted, or no element at all: the dense kernel
    gives the plain screening's numbers (nonlinear lagged shocks and corner bump stops)."""
    lib = _nonlinear_library()
    setups = [_setup("a", "G10", "G10"), _setup("b", "G07", "G14"), _setup("c", "G14", "G07")]
    stops = [{c: (0.003, [0.0, 0.005, 0.01], [0.0, 800.0, 4000.0]) for c in CORNERS}] * 3
    kw = dict(screen=TIGHT, bump_stops=stops)
    plain = screen_setups(plant, drive, setups, lib, **kw)
    none = ThirdChoices((), np.zeros((0, 4)), dampers=((),) * 3, springs=((),) * 3)
    idle = _choices([(None,) * 3] * 3)
    for third in (none, idle):
        got = screen_setups(plant, drive, setups, lib, third=third, **kw)
        names = plain.metric_names
        assert_allclose(got.table[names].to_numpy(float), plain.table[names].to_numpy(float),
                        rtol=RTOL_SAME_FIXED_POINT)
        assert_allclose(got.table[[f"bump_stop_contact_share_{c}" for c in CORNERS]],
                        plain.table[[f"bump_stop_contact_share_{c}" for c in CORNERS]],
                        rtol=RTOL_SAME_FIXED_POINT, atol=1e-12)
        assert_allclose(got.diagnostics["shock_velocity_rms_linearized"],
                        plain.diagnostics["shock_velocity_rms_linearized"],
                        rtol=RTOL_SAME_FIXED_POINT)


def test_static_loads_without_elements_are_the_plain_screening(plant, drive):
    """The lift-off estimates with the dense loop correction (no element fitted) are the
    plain screening's, with and without corner bump stops."""
    lib = _nonlinear_library()
    setups = [_setup("a", "G10", "G10"), _setup("b", "G07", "G14")]
    stops = [None, {c: (0.003, [0.0, 0.005, 0.01], [0.0, 800.0, 4000.0]) for c in CORNERS}]
    kw = dict(screen=TIGHT, bump_stops=stops, static_corner_load_n=[2500.0, 2500.0, None, 3000.0])
    plain = screen_setups(plant, drive, setups, lib, **kw)
    got = screen_setups(plant, drive, setups, lib, third=_choices([(None,) * 3] * 2), **kw)
    cols = [c for c in plain.table.columns if c.startswith(("tire_liftoff", "tire_contact"))]
    assert len(cols) == 6
    assert_allclose(got.table[cols].to_numpy(float), plain.table[cols].to_numpy(float),
                    rtol=RTOL_SAME_FIXED_POINT, atol=1e-12)


def test_linear_heave_damper_is_the_plant_with_it_closed_around(plant, drive):
    """Equivalence: screening with a linear lag-free heave damper ``c`` (row ``m``) equals the
    plain screening of the plant whose loop has ``m c m^T`` closed around it (nonlinear
    lagged corner shocks)."""
    lib = _nonlinear_library()
    setups = [_setup("a", "G10", "G10"), _setup("b", "G07", "G14")]
    c = 6000.0
    third = _choices([(LinearShock("H", c), None, None)] * 2)
    got = screen_setups(plant, drive, setups, lib, third=third, screen=TIGHT)
    bands = drive_bands(drive, n_bands=96)
    H = plant.frequency_response(bands.f_hz)  # (p, 11, nf)
    outs = list(plant.output_names)
    vi = [outs.index(f"shock_velocity_{c_}") for c_ in CORNERS]
    Dh = c * np.outer(ROWS[0], ROWS[0])
    Hc = np.empty_like(H)
    for k in range(H.shape[2]):
        Hr, Hs = H[:, :7, k], H[:, 7:, k]
        M = np.linalg.inv(np.eye(4) - Dh @ Hs[vi])
        Hc[:, :7, k] = Hr + Hs @ M @ Dh @ Hr[vi]
        Hc[:, 7:, k] = Hs @ M
    names, metrics, sig, _ = screen_response(Hc, outs, plant.cbar_n_s_m, bands,
                                             [s.resolve(lib) for s in setups], max_iter=200,
                                             tol=1e-12)
    assert_allclose(got.table[names].to_numpy(float), metrics, rtol=RTOL_SAME_FIXED_POINT)
    assert_allclose(got.diagnostics["shock_velocity_rms_linearized"], sig,
                    rtol=RTOL_SAME_FIXED_POINT)


def test_ranking_agrees_with_the_time_domain(plant, drive):
    """Nonlinear lagged corner dampers and heave dampers (a lagged asymmetric table) varied
    together: screening orders the setups as the truth simulator does and its metric ratios
    to the first setup are within a few per cent.

    Measured over these 8 setups x 20 metrics: Spearman of the score (mean ratio of the tire
    force and heave travel metrics) 1.0 with the same best setup; ratio error 3.1 % max,
    0.2 % median (absolute 5.3 % max, 1.2 % median: the stochastic linearization of the
    digressive lagged dampers and the Welch estimate, as the plain screening's)."""
    lib = _nonlinear_library()
    pairs = [("G10", "G10"), ("G07", "G14"), ("G14", "G07"), ("G10", "G14"), ("G07", "G07"),
             ("G14", "G14"), ("G10", "G07"), ("G14", "G10")]
    heaves = [_heave("HA", 1.0), _heave("HB", 2.5), _heave("HC", 0.4, lag_s=0.008)]
    roll = _heave("R1", 0.6)
    setups = [_setup(f"s{i}", f, r) for i, (f, r) in enumerate(pairs)]
    third = _choices([(heaves[i % 3], roll if i % 2 else None, heaves[(i + 1) % 3])
                      for i in range(len(setups))])
    pred = screen_setups(plant, drive, setups, lib, third=third)
    A, B = _table(pred, _truth(plant, drive, setups, lib, third))
    ratio = np.abs((A / A[0]) / (B / B[0]) - 1)
    assert ratio.max() < RTOL_NONLINEAR_RATIO_MAX
    names = [n for n in pred.metric_names if "contact_share" not in n]
    cols = [names.index(n) for n in names if n.startswith(("tire_force", "heave_travel"))]

    def score(X):
        return (X[:, cols] / X[0, cols]).mean(axis=1)

    rho = spearmanr(score(A), score(B)).statistic
    assert rho >= SPEARMAN_MIN
    assert np.argmin(score(A)) == np.argmin(score(B))


def test_heave_spring_linearized_follows_the_time_domain(plant, drive):
    """A gapped heave spring that closes part of the time: linearized on the element's
    travel, the screening's change of every metric by the spring follows the truth
    simulator's (which it would miss entirely ignoring the spring), and its contact share is
    the time domain's.

    Measured (3 setups x 20 metrics): the spring changes the truth's metrics by up to 12.9 %
    (median 1.9 %); the screening's change differs from it by 2.6 % max, 0.3 % median; the
    contact shares 0.14-0.24 against the truth's within 0.02."""
    lib = _nonlinear_library()
    setups = [_setup("a", "G10", "G10"), _setup("b", "G07", "G14"), _setup("c", "G14", "G07")]
    h = _heave("HA", 1.0)
    spring = (0.002, np.array([0.0, 0.004, 0.01]), np.array([0.0, 2000.0, 9000.0]))
    springs = [(spring, None, None), (spring, None, spring), (None, None, spring)]
    third = _choices([(h, None, h)] * 3, springs)
    bare = _choices([(h, None, h)] * 3)
    lin = screen_setups(plant, drive, setups, lib, third=third)
    ign = screen_setups(plant, drive, setups, lib, third=bare)
    responses = []
    A, B = _table(lin, _truth(plant, drive, setups, lib, third, responses))
    C, D = _table(ign, _truth(plant, drive, setups, lib, bare))
    effect = B / D - 1  # the spring's change of each metric in the time domain
    e_lin = np.abs((A / C) / (B / D) - 1)
    assert e_lin.max() < RTOL_SPRING_EFFECT_MAX
    assert np.median(np.abs(effect)) > SPRING_EFFECT_SHRINK * np.median(e_lin)
    assert np.abs(effect).max() > SPRING_EFFECT_SHRINK * e_lin.max()
    for axle in ("front", "rear"):
        share = lin.table[f"heave_spring_contact_share_{axle}"].to_numpy(float)
        td = np.array([np.mean(r.channels[f"heave_spring_force_{axle}"] > 0)
                       if f"heave_spring_force_{axle}" in r.channels else 0.0
                       for r in responses])
        assert_allclose(share, td, atol=ATOL_CONTACT_SHARE)
    assert lin.table["heave_spring_contact_share_front"].iloc[0] > 0.05
    assert lin.diagnostics["heave_spring_stiffness_eq"][2, 0] == 0.0  # no front spring in c


# ---------------------------------------------------------------- resolution


def _model():
    car = CarThird(ThirdElements({"heave_front": MR, "roll_front": 0.8}),
                   RunThird(dampers={"heave_front": "G10"}, heave_springs={"front": "HS"},
                            heave_packers_m={"front": 0.001}))
    stops = BumpStopLibrary([BumpStop("HS", 0.004, [0.0, 0.01], [0.0, 5000.0]),
                             BumpStop("HT", 0.002, [0.0, 0.01], [0.0, 9000.0])])
    return SimpleNamespace(third=car, elements=SimpleNamespace(bump_stops=stops))


def test_resolve_third_keeps_the_baseline_where_a_setup_is_silent():
    lib = _nonlinear_library()
    model = _model()
    setups = [_setup("base", "G10", "G10"),
              Setup("swap", {c: "G10" for c in CORNERS}, third={"heave_front": "G14",
                                                               "roll_front": "G07"},
                    heave_springs={"front": "HT"}),
              Setup("off", {c: "G10" for c in CORNERS}, third={"heave_front": None},
                    heave_springs={"front": None})]
    got = resolve_third(setups, model, lib)
    assert got.elements == ("heave_front", "roll_front")
    assert_allclose(got.rows, [element_row("heave_front", MR), element_row("roll_front", 0.8)])
    assert got.dampers[0] == (lib["G10"], None)
    assert got.dampers[1] == (lib["G14"], lib["G07"])
    assert got.dampers[2] == (None, None)
    assert got.springs[0][0][0] == pytest.approx(0.003)  # gap less the baseline's packer
    assert got.springs[1][0][0] == pytest.approx(0.001)
    assert got.springs[2][0] is None and got.springs[0][1] is None
    assert got.columns == {"heave_front": ["G10", "G14", "none"],
                           "roll_front": ["none", "G07", "none"],
                           "heave_spring_front": ["HS", "HT", "none"]}
    assert resolve_third(setups, SimpleNamespace(third=None), lib) is None
    assert resolve_third(setups, object(), lib) is None


def test_resolve_third_refuses_unknown_ids():
    lib = _nonlinear_library()
    model = _model()
    bad = Setup("bad", {c: "G10" for c in CORNERS}, third={"heave_front": "X9"})
    with pytest.raises(PlannerError, match="setup 'bad'.*heave_front.*'X9'"):
        resolve_third([bad], model, lib)
    bad = Setup("bad", {c: "G10" for c in CORNERS}, heave_springs={"front": "ZZ"})
    with pytest.raises(PlannerError, match="setup 'bad'.*heave_spring_front.*'ZZ'.*bump-stop library"):
        resolve_third([bad], model, lib)


def test_bad_third_inputs(plant, drive):
    lib = _nonlinear_library()
    setups = [_setup("a", "G10", "G10")]
    with pytest.raises(ValueError, match="rows must have shape"):
        ThirdChoices(ELEMENTS, ROWS[:2], dampers=((None,) * 3,), springs=((None,) * 3,))
    with pytest.raises(ValueError, match="reaches the other axle"):
        ThirdChoices(("heave_front",), [[0.6, 0.6, 0.1, 0.0]], dampers=((None,),),
                     springs=((None,),))
    with pytest.raises(ValueError, match="at most once"):
        ThirdChoices(("heave_front", "heave_front"), ROWS[:2], dampers=(), springs=())
    with pytest.raises(ValueError, match="one per element"):
        ThirdChoices(ELEMENTS, ROWS, dampers=((None,) * 2,), springs=((None,) * 3,))
    with pytest.raises(PlannerError, match="third has 2 setups for 1"):
        screen_setups(plant, drive, setups, lib, third=_choices([(None,) * 3] * 2))
    with pytest.raises(TypeError, match="ThirdChoices"):
        screen_setups(plant, drive, setups, lib, third=[(None,) * 3])


# ---------------------------------------------------------------- kernel


def test_cofactor_inverse_known_answer():
    rng = np.random.default_rng(7)
    A = np.empty((2000, 4, 4), dtype=complex)
    n = 0
    while n < A.shape[0]:
        M = np.eye(4) + 0.5 * (rng.standard_normal((4, 4)) + 1j * rng.standard_normal((4, 4)))
        if np.linalg.cond(M) <= 100.0:
            A[n] = M
            n += 1
    got = inverse_cofactor(A)
    want = np.linalg.inv(A)
    err = np.abs(got - want).max(axis=(1, 2)) / np.abs(want).max(axis=(1, 2))
    assert err.max() < RTOL_INVERSE


def test_band_loops_are_their_generator_output():
    assert committed_source(third=True) == third_band_source()
