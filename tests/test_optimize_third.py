"""Tests of planner.optimize on a car with third elements (issue 38): the car's baseline heave
and roll elements kept in every time-domain verification (the optimum's metrics equal
predict_setups' with them), said left out of IPOPT's loop, kept off the crate's corners, and
the refusals (a baseline naming third elements, lift-off with third elements)."""

import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ident.data.channels import CORNERS
from ident.models.library import ShockLibrary
from ident.models.shocks import LinearShock
from ident.models.vehicle import build_full_car, example_vehicle
from planner.errors import PlannerError
from planner.objective import Objective, default_objective, score_setups
from planner.optimize import CurveOptions, OptimizeWarning, SolverOptions, optimize_curves
from planner.options import ElementOptions
from planner.predict import predict_setups, prepare_drive
from planner.setups import Setup

sys.path.insert(0, str(Path(__file__).parent))
from test_third_planner import CAR, ELEMENTS  # noqa: E402  (the planner tests' third car)

#: The optimizer's verification (simulate_batch, compute_metrics) against predict_setups
#: (simulate_batch_metrics, the fused metric rows): the same loop, the metrics summed in
#: another order.
RTOL_SAME_LOOP = 1e-9
#: What the third elements move the metrics by on this car, at least (measured 5-15 %).
MIN_THIRD_EFFECT = 0.01

LIB = ShockLibrary([LinearShock("S", 3000.0), LinearShock("S2", 4500.0),
                    LinearShock("H1", 8000.0, lag_s=0.004), LinearShock("R1", 3000.0,
                                                                      lag_s=0.002)])
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
    assert any("third elements (heave_front, roll_front) are not in IPOPT's loop" in m
               for m in said)
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


def test_refusals_with_third_elements(plant, drive):
    with pytest.raises(PlannerError, match="baseline 'b' names third elements"):
        optimize_curves(plant, drive, LIB, elements=ELEMENTS, **FAST,
                        baseline=Setup("b", dict.fromkeys(CORNERS, "S"),
                                       third={"heave_front": "H1"}))
    with pytest.raises(PlannerError, match="static_corner_load_n.*third elements"):
        optimize_curves(plant, drive, LIB, baseline="S", **FAST,
                        elements=replace(ELEMENTS, static_corner_load_n=[3000.0] * 4))


@pytest.mark.slow
def test_a_heave_travel_limit_is_held_in_the_verification(plant, drive):
    """A limit on the front heave element's travel (10 % below the baseline's): IPOPT's loop
    does not see it, the verification holds it: every verified row's feasibility is the
    limit's, and the optimum meets it."""
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
