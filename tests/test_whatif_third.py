"""Tests of the what-if factors of third elements (issue 38): a heave damper's force scale
and lag, a heave spring's rate scale and packer change, applied through the setups' third
elements (equivalence with the directly changed damper or spring through
planner.predict.predict_setups), and the refusals (a car without third elements, an
element the car does not declare, the screening method, a bad perturbation file)."""

import sys
from pathlib import Path

import numpy as np
import pytest

from ident.data.channels import CORNERS
from ident.models.bumpstops import BumpStop, BumpStopLibrary, CarElements
from ident.models.library import ShockLibrary
from ident.models.vehicle import build_full_car, example_vehicle
from planner.errors import PlannerError
from planner.options import ElementOptions, LoopOptions
from planner.predict import predict_setups
from planner.setups import Setup
from planner.whatif import Factor, evaluate_whatif, perturbation_set, read_perturbations

sys.path.insert(0, str(Path(__file__).parent))
from test_third_loop import _drive  # noqa: E402  (the truth tests' drive)
from test_third_planner import CAR, ELEMENTS, LIB, SPRINGS  # noqa: E402

#: The what-if and the direct prediction run the same loop on the same setups (only the
#: damper's or spring's id differs): equal to rounding.
RTOL_SAME = 1e-12
HEAVE_METRICS = ("heave_travel_rms_front", "heave_velocity_rms_front",
                 "shock_travel_rms_LF", "tire_force_rms_RF")
LOOP = LoopOptions(oversample=1)


def _setup(name, **kw):
    return Setup(name, dict.fromkeys(CORNERS, "S"), **kw)


@pytest.fixture(scope="module")
def plant():
    return build_full_car(example_vehicle()).loop_plant(np.full(4, 3000.0))


@pytest.fixture(scope="module")
def drive():
    return _drive(np.random.default_rng(7), aero=True)


def _rows(w, perturbation):
    t = w.table
    return t[t["perturbation"] == perturbation].set_index("setup")


def test_heave_factors_equal_the_directly_changed_damper_and_spring(plant, drive):
    setups = [_setup("base"), _setup("h2", third={"heave_front": "H2"})]
    factors = [Factor("heave damper", "third_scale", targets=("heave_front",), levels=(1.3,)),
               Factor("heave lag", "third_lag", targets=("heave_front",), levels=(0.003,)),
               Factor("heave rate", "heave_spring_rate", targets=("front",), levels=(1.5,)),
               Factor("heave packer", "heave_packer", targets=("front",), levels=(0.001,))]
    w = evaluate_whatif(plant, drive, setups, LIB, perturbation_set(factors), baseline="base",
                        loop=LOOP, elements=ELEMENTS)
    nominal = _rows(w, "nominal")
    # the table names the setups' own dampers and springs, not the what-if's variants
    assert _rows(w, "heave damper x1.3")["heave_front"].tolist() == ["H1", "H2"]
    assert _rows(w, "heave rate x1.5")["heave_spring_front"].tolist() == ["HS", "HS"]
    # the same setups with the damper or spring changed directly in the libraries
    hs = SPRINGS["HS"]
    lib = ShockLibrary(LIB.entries() + [
        LIB["H1"].scaled(1.3, id="H1x"), LIB["H2"].scaled(1.3, id="H2x"),
        LIB["H1"].scaled(1.0, lag_s=LIB["H1"].lag_s + 0.003, id="H1l"),
        LIB["H2"].scaled(1.0, lag_s=LIB["H2"].lag_s + 0.003, id="H2l")])
    springs = BumpStopLibrary([hs, BumpStop("HSx", hs.gap_m, hs.travel_m,
                                            np.asarray(hs.force_n) * 1.5),
                               BumpStop("HSp", hs.gap_m - 0.001, hs.travel_m, hs.force_n)])
    el = ElementOptions(use_model=CarElements(springs, {}, {}), third=CAR)
    cases = {"heave damper x1.3": ({"heave_front": "H1x"}, {"heave_front": "H2x"}, None),
             "heave lag +0.003": ({"heave_front": "H1l"}, {"heave_front": "H2l"}, None),
             "heave rate x1.5": (None, {"heave_front": "H2"}, {"front": "HSx"}),
             "heave packer +0.001": (None, {"heave_front": "H2"}, {"front": "HSp"})}
    for name, (t_base, t_h2, sp) in cases.items():
        direct = predict_setups(plant, drive, [_setup("base", third=t_base, heave_springs=sp),
                                               _setup("h2", third=t_h2, heave_springs=sp)],
                                lib, loop=LOOP, elements=el).table
        got = _rows(w, name)
        for m in HEAVE_METRICS:
            np.testing.assert_allclose(got.loc[["base", "h2"], m].to_numpy(float),
                                       direct[m].to_numpy(float), rtol=RTOL_SAME, err_msg=name)
        # and the factor does change the heave metrics
        assert not np.allclose(got["heave_travel_rms_front"].to_numpy(float),
                               nominal["heave_travel_rms_front"].to_numpy(float),
                               rtol=1e-6), name


def test_third_factors_are_refused_clearly(plant, drive):
    ps = perturbation_set([Factor("heave damper", "third_scale", targets=("heave_front",),
                                  levels=(1.1,))])
    with pytest.raises(PlannerError, match="changes a third element but the model has none"):
        evaluate_whatif(plant, drive, [_setup("base")], LIB, ps, baseline="base", loop=LOOP,
                        elements=ElementOptions(use_model=False))
    rear = perturbation_set([Factor("rear heave", "third_scale", targets=("heave_rear",),
                                    levels=(1.1,))])
    with pytest.raises(PlannerError, match="declares no heave_rear"):
        evaluate_whatif(plant, drive, [_setup("base")], LIB, rear, baseline="base", loop=LOOP,
                        elements=ELEMENTS)
    with pytest.raises(PlannerError, match="use method = 'time'"):
        evaluate_whatif(plant, drive, [_setup("base")], LIB, ps, baseline="base", loop=LOOP,
                        elements=ELEMENTS, method="screening")
    packer = perturbation_set([Factor("packer", "heave_packer", targets=("front",),
                                      levels=(0.001,))])
    with pytest.raises(PlannerError, match="has no heave spring"):
        evaluate_whatif(plant, drive, [_setup("base", heave_springs={"front": None})], LIB,
                        packer, baseline="base", loop=LOOP, elements=ELEMENTS)


def test_the_perturbation_file_reads_third_factors(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text('format = "shockplan-whatif/1"\nunits = "imperial"\n'
                    '[[factor]]\nname = "heave"\nkind = "third_scale"\n'
                    'elements = ["heave_front", "roll_front"]\nlevels = [0.9, 1.1]\n'
                    '[[factor]]\nname = "packer"\nkind = "heave_packer"\naxles = ["front"]\n'
                    'levels = [0.04]\n')
    ps = read_perturbations(path)
    heave, packer = ps.factors
    assert heave.targets == ("heave_front", "roll_front") and heave.change == "scale"
    assert packer.levels == pytest.approx((0.04 * 0.0254,))  # inches to metres
    path.write_text('format = "shockplan-whatif/1"\n[[factor]]\nname = "h"\n'
                    'kind = "third_lag"\nelements = ["heave_middle"]\nlevels = [0.001]\n')
    with pytest.raises(PlannerError, match="unknown third element"):
        read_perturbations(path)
    path.write_text('format = "shockplan-whatif/1"\n[[factor]]\nname = "h"\n'
                    'kind = "third_scale"\ncorners = ["LF"]\nlevels = [1.1]\n')
    with pytest.raises(PlannerError, match="'corners' does not apply"):
        read_perturbations(path)
