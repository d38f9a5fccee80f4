"""Tests of planner.optimize on a car with third elements (issue 38): the car's baseline heave
and roll elements kept in every time-domain verification (the optimum's metrics equal
predict_setups' with them), in IPOPT's casadi loop (its metrics against simulate_batch's),
kept off the crate's corners, a heave damper's curve optimized with the corner curves, and
the refusals (a baseline naming third elements, lift-off with third elements, a free third
damper the car does not fit)."""

import sys
import warnings
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd
import pytest
from scipy import signal

from ident.data.channels import CORNERS
from ident.data.third import CarThird, RunThird
from ident.models.library import ShockLibrary
from ident.models.shocks import LinearShock
from ident.models.vehicle import build_full_car, example_vehicle
from planner.errors import PlannerError
from planner.objective import Objective, default_objective, score_setups
from ident.sim.closedloop import simulate_batch
from planner.elements import setup_third
from planner.optimize import CurveOptions, OptimizeWarning, SolverOptions, optimize_curves
from planner.optimize.loop import LoopModel
from planner.optimize.space import curve_space
from planner.screen import metric_rows
from planner.options import ElementOptions
from planner.predict import predict_setups, prepare_drive
from planner.setups import Setup

sys.path.insert(0, str(Path(__file__).parent))
from test_third_planner import CAR, ELEMENTS, SPRINGS  # noqa: E402  (the planner tests' car)

#: The optimizer's verification (simulate_batch, compute_metrics) against predict_setups
#: (simulate_batch_metrics, the fused metric rows): the same loop, the metrics summed in
#: another order.
RTOL_SAME_LOOP = 1e-9
#: The casadi loop with third dampers against simulate_batch's channels through the casadi
#: loop's metric filter (forward |B|^4, the mean removed exactly): the same recursion and
#: root per sub-step (Newton from the free response converges on piecewise-linear curves),
#: so rounding (measured 2e-15).
RTOL_THIRD_DAMPERS = 1e-10
#: The same with the heave spring: its table's kinks rounded over 0.1 mm
#: (planner.optimize.loop.STOP_SMOOTHING_M) against a 3 mm gap (measured 1.8e-5 with the
#: spring alone, 5.8e-5 with the dampers, 10 s drive).
RTOL_THIRD_SPRING = 3e-4
#: A free third damper whose parameters are its fixed curve's: the same arithmetic.
RTOL_FREE_FIXED = 1e-12
#: What the third elements move the metrics by on this car, at least (measured 5-15 %).
MIN_THIRD_EFFECT = 0.01

LIB = ShockLibrary([LinearShock("S", 3000.0), LinearShock("S2", 4500.0),
                    LinearShock("H1", 8000.0, lag_s=0.004), LinearShock("R1", 3000.0,
                                                                      lag_s=0.002)])
#: The crate's heave dampers besides the car's (its ``fits``: never at a corner).
HEAVE_CRATE = [LinearShock("H2", 15000.0, fits="heave"), LinearShock("H3", 4000.0, fits="heave")]
FAST = dict(curves=CurveOptions(symmetry="all", linear=True),
            solver=SolverOptions(max_iter=5, n_starts=1, stationarity=False, n_closest=1))


@pytest.fixture(scope="module")
def plant():
    return build_full_car(example_vehicle()).loop_plant(np.full(4, 3000.0))


@pytest.fixture(scope="module")
def drive():
    """A 10 s track drive at 100 Hz with aero load: the heave spring is touched ~10 %."""
    from ident.data.drive import make_track_drive

    v = example_vehicle()
    d = make_track_drive(duration_s=10.0, fs_hz=100.0, seed=3, roughness_m3=16e-6,
                         wheelbase_m=v.a_m + v.b_m, track_width_m=v.track_front_m,
                         aero={"aero_heave": 1500.0, "aero_pitch": 800.0, "aero_roll": 300.0},
                         name="gt")
    return prepare_drive(d, None)


@pytest.fixture(scope="module")
def optimum(plant, drive):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        opt = optimize_curves(plant, drive, LIB, baseline="S", elements=ELEMENTS, **FAST)
    return opt, [str(w.message) for w in caught if issubclass(w.category, OptimizeWarning)]


@pytest.mark.slow
def test_optimum_is_verified_with_the_cars_third_elements(plant, drive, optimum):
    opt, said = optimum
    assert not any("third elements" in m for m in said)  # IPOPT's loop has them now
    assert opt.settings["third"] == CAR.to_dict()
    met = opt.metrics["gt"]
    assert (met["heave_spring_contact_share_front"] > 0).all()
    # the optimum, the baseline and the crate through predict_setups with the third elements
    lib = ShockLibrary(list(opt.shocks.values()) + list(LIB.values()))
    names = list(opt.table.index)
    setups = [opt.setup if n == opt.setup.name else
              (opt.baseline if n == opt.baseline.name else
               Setup(n, dict(zip(CORNERS, opt.table.loc[n, list(CORNERS)])))) for n in names]
    pred = predict_setups(plant, drive, setups, lib, elements=ELEMENTS).table
    cols = [c for c in met.columns if c.startswith(("tire_force_rms", "shock_travel_rms",
                                                    "heave_travel_rms", "roll_velocity_rms"))]
    np.testing.assert_allclose(met.loc[names, cols].to_numpy(float),
                               pred.loc[names, cols].to_numpy(float), rtol=RTOL_SAME_LOOP)
    scores = score_setups(pred, default_objective(), baseline=opt.baseline.name).table
    np.testing.assert_allclose(opt.table["score"].to_numpy(float),
                               scores.loc[names, "score"].to_numpy(float), rtol=RTOL_SAME_LOOP)
    # and not the car without them
    bare = predict_setups(plant, drive, [opt.setup], lib,
                          elements=ElementOptions(use_model=False)).table
    spec = [c for c in cols if not c.startswith(("heave", "roll"))]
    assert np.max(np.abs(bare.loc["optimum", spec].to_numpy(float)
                         / met.loc["optimum", spec].to_numpy(float) - 1)) > MIN_THIRD_EFFECT
    # the car's heave and roll dampers stay off the corners of the crate's setups
    assert not set(opt.table[list(CORNERS)].to_numpy().ravel()) & {"H1", "R1"}
    crate = [n for n in opt.settings["crate_scores"] if n != opt.baseline.name]
    assert crate and all(set(n.split("/")) <= {"S", "S2"} for n in crate)


@pytest.fixture(scope="module")
def crate_choices(plant, drive):
    """The optimum with the crate's best searched over heave damper choices."""
    lib = ShockLibrary(list(LIB.values()) + HEAVE_CRATE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptimizeWarning)
        opt = optimize_curves(plant, drive, lib, baseline="S", **FAST,
                              elements=replace(ELEMENTS,
                                               vary_third={"heave_front": ["H1", "H2", "H3"]}))
    return opt, lib


@pytest.mark.slow
def test_the_crate_best_is_searched_over_the_heave_choices(plant, drive, optimum,
                                                            crate_choices, tmp_path):
    """vary_third (--try-heave front=H1,H2,H3): the crate's setups are screened and verified
    with each heave damper (none of them at a corner); its best is at least as good as the
    crate's best with the car's own heave damper, its verified metrics are predict_setups'
    with its heave damper, and the table, optimal_setup.csv and the workbook name it."""
    from openpyxl import load_workbook

    from planner.report.optimize import write_optimum
    from planner.setups.csv_io import read_setups

    plain, _ = optimum
    opt, lib = crate_choices
    assert opt.settings["crate_third"] == {"heave_front": ["H1", "H2", "H3"]}
    verified = list(opt.settings["crate_scores"])
    assert {n.rpartition("=")[2] for n in verified if "heave_front=" in n} == {"H2", "H3"}
    assert not any(n.endswith("heave_front=H1") for n in verified)  # (the car's own: a repeat)
    assert not set(opt.table[list(CORNERS)].to_numpy().ravel()) & {"H1", "H2", "H3", "R1"}
    best = float(opt.table.loc[opt.crate_best, "score"])
    assert best <= float(plain.table.loc[plain.crate_best, "score"]) * (1 + RTOL_SAME_LOOP)
    heave = opt.table.loc[opt.crate_best, "heave_front"]
    assert opt.table.loc[opt.crate_best, "kind"] == "crate best"
    assert (heave == "H1") == ("heave_front=" not in opt.crate_best)
    setup = Setup(opt.crate_best, dict(zip(CORNERS, opt.table.loc[opt.crate_best, list(CORNERS)])),
                  third={"heave_front": heave})
    pred = predict_setups(plant, drive, [opt.baseline, setup], lib, elements=ELEMENTS).table
    met = opt.metrics["gt"]
    cols = [c for c in met.columns if c.startswith(("tire_force_rms", "shock_travel_rms",
                                                    "heave_travel_rms"))]
    np.testing.assert_allclose(met.loc[opt.crate_best, cols].to_numpy(float),
                               pred.loc[opt.crate_best, cols].to_numpy(float),
                               rtol=RTOL_SAME_LOOP)
    files = write_optimum(opt, lib, tmp_path / "opt")
    back = read_setups(files["setups"])
    assert back[1].name == opt.crate_best and back[1].third["heave_front"] == heave
    solver = {r[0].value: r[1].value for r in load_workbook(files["xlsx"])["solver"].iter_rows()}
    assert solver["crate best"] == opt.crate_best
    assert solver["crate searched with the third-element choices"] == "heave_front: H1, H2, H3"
    # a free heave damper's panel of curves.png draws the crate best's heave damper too
    import matplotlib.pyplot as plt

    from planner.report.optimize import curves_figure

    fig = curves_figure(replace(opt, third_curves={"heave_front": LIB["H1"].to_pwl()}), lib)
    labels = [t.get_text() for ax in fig.axes if ax.get_legend() is not None
              for t in ax.get_legend().get_texts()]
    plt.close(fig)
    assert ("baseline (H1)" in labels) and ((f"crate best ({heave})" in labels) == (heave != "H1"))


def test_refusals_with_third_elements(plant, drive):
    with pytest.raises(PlannerError, match="baseline 'b' names third elements"):
        optimize_curves(plant, drive, LIB, elements=ELEMENTS, **FAST,
                        baseline=Setup("b", dict.fromkeys(CORNERS, "S"),
                                       third={"heave_front": "H1"}))
    with pytest.raises(PlannerError, match="static_corner_load_n.*third elements"):
        optimize_curves(plant, drive, LIB, baseline="S", **FAST,
                        elements=replace(ELEMENTS, static_corner_load_n=[3000.0] * 4))
    with pytest.raises(PlannerError, match="vary_bump_stops.*not searched.*--packers"):
        optimize_curves(plant, drive, LIB, baseline="S", **FAST,
                        elements=replace(ELEMENTS, vary_packers_m={"front": [0.0, 0.002]}))
    with pytest.raises(PlannerError, match="choices.*no third elements"):
        optimize_curves(plant, drive, LIB, baseline="S", **FAST,
                        elements=ElementOptions(use_model=False,
                                                vary_third={"heave_front": ["H1"]}))


@pytest.mark.slow
def test_a_heave_travel_limit_is_held_in_the_verification(plant, drive):
    """A limit on the front heave element's travel (10 % below the baseline's): IPOPT's loop
    holds it (a metric row over the shock travels), the verification holds it: every verified
    row's feasibility is the limit's, and the optimum meets it."""
    limit = 0.9
    base = default_objective()
    objective = Objective("floor", dict(base.weights),
                          limits={"heave_travel_rms_front": {"max_ratio": limit}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptimizeWarning)
        opt = optimize_curves(plant, drive, LIB, baseline="S", elements=ELEMENTS,
                              objective=objective, **FAST)
    travel = opt.metrics["gt"]["heave_travel_rms_front"]
    ok = travel <= limit * travel[opt.baseline.name]
    assert (opt.table["feasible"] == ok.loc[opt.table.index]).all()
    assert bool(opt.table.loc[opt.setup.name, "feasible"])
    assert not bool(opt.table.loc[opt.baseline.name, "feasible"])


def test_third_metric_objectives_are_checked(plant, drive):
    rear = Objective("rear", dict(default_objective().weights),
                     limits={"heave_travel_rms_rear": {"max_ratio": 1.0}})
    with pytest.raises(PlannerError, match=r"heave_travel_rms_rear.*does not declare"):
        optimize_curves(plant, drive, LIB, baseline="S", elements=ELEMENTS, objective=rear,
                        **FAST)
    weighted = Objective("w", {"heave_travel_rms_front": 1.0})
    with pytest.raises(PlannerError, match="only as limits"):
        optimize_curves(plant, drive, LIB, baseline="S", elements=ELEMENTS,
                        objective=weighted, **FAST)


@pytest.mark.slow
def test_write_optimum_tables_the_third_elements(optimum, tmp_path):
    """optimal_setup.csv and the workbook's setups sheet carry the setups' third-element
    columns (the car's baseline's, which the verification fitted); the CSV reads back."""
    from openpyxl import load_workbook

    from planner.report.optimize import write_optimum
    from planner.setups.csv_io import read_setups

    opt, _ = optimum
    files = write_optimum(opt, LIB, tmp_path / "opt")
    header = files["setups"].read_text().splitlines()[0].split(",")
    assert header[:5] == ["setup", *CORNERS]
    assert header[5:] == ["heave_front", "roll_front", "heave_spring_front", "units"]
    back = read_setups(files["setups"])
    assert back[0].name == opt.setup.name
    assert all(dict(s.third) == {"heave_front": "H1", "roll_front": "R1"}
               and dict(s.heave_springs) == {"front": "HS"} for s in back)
    sheet = load_workbook(files["xlsx"])["setups"]
    heads = [c.value for c in sheet[1]]
    at = heads.index("RR")
    assert heads[at + 1:at + 4] == ["heave front", "roll front", "heave spring front"]
    assert {sheet.cell(row=2, column=at + 2).value, sheet.cell(row=2, column=at + 3).value} \
        == {"H1", "R1"}


def _filtered_rms(plant, drive, names, L, models, entry):
    """simulate_batch's metric rows through the casadi loop's metric filter (forward |B|^4,
    the mean removed exactly), RMS."""
    b = simulate_batch(plant, drive, [models], oversample=2,
                       third=None if entry is None else [entry])
    y = L @ np.array([b.channels[o][0] for o in plant.output_names])
    sos = signal.butter(4, (1.0, 20.0), "bandpass", fs=drive.fs_hz, output="sos")
    sos = np.vstack([sos, sos])
    step = signal.sosfilt(sos, np.ones(y.shape[1]))
    z = signal.sosfilt(sos, y, axis=1)
    return np.sqrt(np.mean((z - y.mean(axis=1, keepdims=True) * step) ** 2, axis=1))


def test_casadi_loop_with_third_elements_matches_the_simulator(plant, drive):
    """IPOPT's loop with the car's heave and roll dampers and heave spring gives
    simulate_batch's metric rows (through the same metric filter): the dampers to rounding,
    the spring to its kinks' rounding; a free heave damper at its fixed curve's parameters is
    the fixed damper; and the elements matter."""
    space = curve_space(symmetry="all", knots_m_s=(0.05, 0.15, 0.4), lag_s=0.0)
    x = space.from_curves([LIB["S"].to_pwl()])
    P = np.asarray(ca.DM(space.expansion()) @ x).ravel()
    names, L = metric_rows(plant)
    models = [LIB["S"]] * 4
    entry = setup_third([Setup("b", dict.fromkeys(CORNERS, "S"))], CAR, LIB,
                        bump_stops=SPRINGS).entries[0]

    def loop(third, free=()):
        lm = LoopModel(plant, drive, space, (names, L), 2, False, third=third, free_third=free)
        p = ca.MX.sym("p", lm.n_params)
        return ca.Function("m", [p], [lm.metrics(p)])

    dampers = (entry[0], ())
    got = np.asarray(loop(dampers)(P)).ravel()
    np.testing.assert_allclose(got, _filtered_rms(plant, drive, names, L, models, dampers),
                               rtol=RTOL_THIRD_DAMPERS)
    got = np.asarray(loop(entry)(P)).ravel()
    ref = _filtered_rms(plant, drive, names, L, models, entry)
    np.testing.assert_allclose(got, ref, rtol=RTOL_THIRD_SPRING)
    bare = _filtered_rms(plant, drive, names, L, models, None)
    assert np.max(np.abs(ref / bare - 1)) > 10 * RTOL_THIRD_SPRING
    heave = space.from_curves([LIB["H1"].to_pwl()])
    P_free = np.concatenate([P, np.asarray(ca.DM(space.expansion()) @ heave).ravel()])
    free = np.asarray(loop(entry, ("heave_front",))(P_free)).ravel()
    np.testing.assert_allclose(free, got, rtol=RTOL_FREE_FIXED)


@pytest.mark.slow
def test_a_free_heave_damper_is_optimized_with_the_corner_curves(plant, drive):
    """free_third=heave_front and the heave spring's packer free: the optimum names its own
    heave damper (OPT-heave_front, in its shocks and table), its verified metrics are
    predict_setups' with that damper and packer, it is no worse than the scan's best (the
    baseline heave damper) and beats the crate's best."""
    crate = ShockLibrary(list(LIB.values()) + HEAVE_CRATE[:1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptimizeWarning)
        opt = optimize_curves(plant, drive, crate, baseline="S", elements=ELEMENTS,
                              curves=CurveOptions(symmetry="all", linear=True,
                                                  free_third=("heave_front",)),
                              packers={"heave_front": (0.0, 0.002)}, solver=FAST["solver"])
    # (the crate's best searched over its heave dampers too: the fair comparison)
    assert opt.settings["crate_third"] == {"heave_front": ["H2"]}
    assert any(n.endswith("heave_front=H2") for n in opt.settings["crate_scores"])
    assert opt.setup.third == {"heave_front": "OPT-heave_front"}
    assert "OPT-heave_front" in opt.shocks and set(opt.third_curves) == {"heave_front"}
    assert opt.table.loc["optimum", "heave_front"] == "OPT-heave_front"
    assert opt.table.loc[opt.baseline.name, "heave_front"] == "H1"
    assert opt.settings["free_third"] == ["heave_front"]
    packer = opt.packers_m["heave_front"]
    assert -1e-6 <= packer <= 0.002 + 1e-6
    lib = ShockLibrary(list(opt.shocks.values()) + list(crate.values()))
    # (the chosen packer on top of the baseline's)
    car = CarThird(CAR.elements, RunThird(dict(CAR.baseline.dampers),
                                          dict(CAR.baseline.heave_springs),
                                          {"front": CAR.baseline.heave_packers_m["front"]
                                           + packer}))
    pred = predict_setups(plant, drive, [opt.baseline, opt.setup], lib,
                          elements=replace(ELEMENTS, third=car)).table
    cols = [c for c in pred.columns if c.startswith(("tire_force_rms", "shock_travel_rms"))]
    np.testing.assert_allclose(opt.metrics["gt"].loc["optimum", cols].to_numpy(float),
                               pred.loc["optimum", cols].to_numpy(float), rtol=RTOL_SAME_LOOP)
    assert opt.score <= opt.solver["candidates"]["scan"] * (1 + RTOL_SAME_LOOP)
    assert opt.gap > 0
    # the heave curve differs from the baseline's (IPOPT moved it) and is passive
    f = opt.third_curves["heave_front"].f_knots_n
    v = opt.third_curves["heave_front"].v_knots_m_s
    assert np.all(f * v >= 0)
    assert not np.allclose(f, LIB["H1"].to_pwl().force(v), rtol=1e-3)


def test_free_third_refusals(plant, drive):
    with pytest.raises(PlannerError, match="free_third.*heave_rear.*is not a third damper"):
        optimize_curves(plant, drive, LIB, baseline="S", elements=ELEMENTS,
                        curves=CurveOptions(free_third=("heave_rear",)), solver=FAST["solver"])
    with pytest.raises(PlannerError, match=r"packers\['heave_front'\].*gap left"):
        optimize_curves(plant, drive, LIB, baseline="S", elements=ELEMENTS,
                        packers={"heave_front": (0.0, 0.01)}, solver=FAST["solver"])
    with pytest.raises(PlannerError, match=r"packers\['heave_rear'\].*no heave spring"):
        optimize_curves(plant, drive, LIB, baseline="S", elements=ELEMENTS,
                        packers={"heave_rear": (0.0, 0.001)}, solver=FAST["solver"])
    with pytest.raises(PlannerError, match="free_third.*no third elements"):
        optimize_curves(plant, drive, LIB, baseline="S",
                        elements=ElementOptions(use_model=False),
                        curves=CurveOptions(free_third=("heave_front",)), solver=FAST["solver"])


@pytest.mark.heavy
def test_free_heave_dampers_beat_the_crate_on_the_known_prototype():
    """On the known example car (ident/examples/proto_*, its plant and baseline third
    elements), a 20 s track drive with its downforce: the optimum with both heave dampers
    free beats the best of the 44 crate setups (corner, heave and roll dampers, heave
    springs; time domain with the third elements, scored against the same baseline), and
    the best of its own crate mapping, searched over the crate's heave dampers too.
    Oversample 4, the figures of docs/DESIGN.md (at 2 the time-domain loop's Newton did not
    converge on IPOPT's curves before its backtracking; it does now)."""
    import importlib.util

    from ident.models.bumpstops import CarElements
    from ident.sim.virtual_rig import loop_damping
    from planner.options import LoopOptions

    path = Path(__file__).parent.parent / "studies" / "third_elements.py"
    spec = importlib.util.spec_from_file_location("_studies_third_elements", path)
    study = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, study)  # (its dataclasses look their module up)
    spec.loader.exec_module(sys.modules[spec.name])
    study = sys.modules[spec.name]
    car = study.read_proto()
    base_run = next(r for r in car.plan.runs if r.role == "baseline")
    third = CarThird(car.plan.third_elements, base_run.fitted_third(car.plan))
    baseline = next(s for s in car.setups if s.name == study.BASELINE)
    plant = build_full_car(car.vehicle).loop_plant(
        loop_damping([car.library[baseline.shocks[c]] for c in CORNERS]))
    elements = ElementOptions(use_model=CarElements(car.bump_stops, {}, {}), third=third)
    drive = prepare_drive(study.study_drives(car, drive_s=20.0)["track"], None)
    objective = study.study_objective()
    loop = LoopOptions(oversample=4)
    crate = predict_setups(plant, drive, list(car.setups), car.library, elements=elements,
                           loop=loop).table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptimizeWarning)
        opt = optimize_curves(plant, drive, car.library, objective=objective, elements=elements,
                              baseline=Setup("base", dict(baseline.shocks)), loop=loop,
                              curves=CurveOptions(free_third=("heave_front", "heave_rear")),
                              solver=SolverOptions(max_iter=30, n_starts=1, stationarity=False,
                                                   n_closest=1))
    met = opt.metrics[drive.name].loc[["optimum"]]
    scores = score_setups(pd.concat([crate, met]), objective, baseline=study.BASELINE).table
    best = scores.drop(index="optimum")
    best = best[best["feasible"]]["score"].min()
    assert opt.setup.third == {"heave_front": "OPT-heave_front", "heave_rear": "OPT-heave_rear"}
    assert bool(scores.loc["optimum", "feasible"])
    assert scores.loc["optimum", "score"] < best
    # and the optimizer's own crate, searched over the crate's heave dampers too (fits =
    # "heave"): the optimum beats its best
    assert set(opt.settings["crate_third"]) == {"heave_front", "heave_rear"}
    assert opt.gap > 0


@pytest.mark.slow
def test_compile_curves_compiles_the_loop_with_third_elements(
        plant, drive, tmp_path, monkeypatch, as_another_process_without_compiler):
    """compile_curves on a car with third elements compiles the loop optimize_curves builds
    (the car's heave and roll dampers and heave spring, a free heave damper's curve group):
    the optimization with the same arguments then loads it without running the compiler;
    and it refuses what optimize refuses (lift-off with third elements)."""
    import planner.optimize.cache as po
    import planner.optimize.loop as pl
    from planner.optimize import compile_curves

    with pytest.raises(PlannerError, match="static_corner_load_n.*third elements"):
        compile_curves(plant, drive, LIB, baseline="S",
                       elements=replace(ELEMENTS, static_corner_load_n=[3000.0] * 4))
    if not po.jit_available():
        pytest.skip("no C compiler: compile_curves compiles nothing")
    monkeypatch.setenv("SHOCKPLAN_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(pl, "_STEP_CACHE", {})
    curves = CurveOptions(symmetry="all", linear=True, free_third=("heave_front",))
    assert compile_curves(plant, drive, LIB, baseline="S", elements=ELEMENTS,
                          curves=curves) is True
    libs = list(po.jit_cache_dir().glob("steps-*.so"))
    assert len(libs) == 1

    as_another_process_without_compiler()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptimizeWarning)
        opt = optimize_curves(plant, drive, LIB, baseline="S", elements=ELEMENTS, curves=curves,
                              solver=SolverOptions(max_iter=2, n_starts=1, n_closest=1,
                                                   stationarity=False))
    assert opt.solver["jit"] and opt.solver["n_grad"] > 0
    assert opt.setup.third == {"heave_front": "OPT-heave_front"}
    assert list(po.jit_cache_dir().glob("steps-*.so")) == libs
