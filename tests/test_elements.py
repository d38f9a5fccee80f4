"""Tests of planner.elements: setups' bump stops, packers and static loads resolved (issue 25)."""

import numpy as np
import pytest

from ident.data.channels import CORNERS
from ident.models.bumpstops import BumpStop, BumpStopLibrary, CarElements
from planner.elements import (
    ELEMENT_COLUMNS,
    distinct_setups,
    parse_length,
    setup_elements,
    vary_elements,
)
from planner.errors import PlannerError
from planner.setups import Setup
from planner.options import ElementOptions, RunOptions

#: Contact travels are gap - packer: exact in binary for these millimetre values to 1e-15 m.
TRAVEL_TOL_M = 1e-12


@pytest.fixture
def stops():
    """Two front stops (15 and 10 mm gaps) and a rear one, progressive tables."""
    return BumpStopLibrary([
        BumpStop("BS-F", 0.015, [0.0, 0.005, 0.010], [0.0, 500.0, 2000.0]),
        BumpStop("BS-F2", 0.010, [0.0, 0.005, 0.010], [0.0, 800.0, 3000.0]),
        BumpStop("BS-R", 0.020, [0.0, 0.010], [0.0, 1500.0]),
    ])


@pytest.fixture
def car(stops):
    """The elements of a model whose baseline run had BS-F front (2 mm packers), BS-R rear."""
    return CarElements(bump_stops=stops,
                       baseline_stops={"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": "BS-R"},
                       baseline_packers_m={"LF": 0.002, "RF": 0.002},
                       static_corner_load_n=np.array([3000.0, 3000.0, 3300.0, 3300.0]))


def _setup(name, **kw):
    return Setup(name, dict.fromkeys(CORNERS, "B20"), **kw)


def test_no_elements_is_none():
    """No stop and no static loads: None, the loop of a car without elements."""
    assert setup_elements([_setup("a")]) is None
    assert setup_elements([_setup("a")], CarElements(None, {}, {}, None)) is None


def test_setups_keep_the_baseline_runs_elements(car):
    got = setup_elements([_setup("base"), _setup("soft", bump_stops={"LF": "BS-F2",
                                                                   "RF": "BS-F2"},
                                                 packers_m={"LF": 0.0, "RF": 0.0})], car)
    assert got.stop_ids[0] == ("BS-F", "BS-F", "BS-R", "BS-R")
    assert got.stop_ids[1] == ("BS-F2", "BS-F2", "BS-R", "BS-R")
    np.testing.assert_allclose(got.packers_m, [[0.002, 0.002, 0, 0], [0, 0, 0, 0]])
    # contact travel = gap - packer
    assert abs(got.tables[0][0][0] - 0.013) < TRAVEL_TOL_M
    assert abs(got.tables[1][0][0] - 0.010) < TRAVEL_TOL_M
    assert abs(got.tables[1][2][0] - 0.020) < TRAVEL_TOL_M
    np.testing.assert_array_equal(got.static_corner_load_n, car.static_corner_load_n)
    assert got.active and got.has_stops
    assert len(got.loop_stops(slice(1, 2))) == 1


def test_columns(car):
    got = setup_elements([_setup("a", bump_stops={"LR": None})], car)
    cols = got.columns(["a"])
    assert tuple(cols.columns) == ELEMENT_COLUMNS
    assert cols.loc["a", "bump_stop_LR"] == "none" and cols.loc["a", "packer_LF"] == 0.002


def test_static_loads_off_and_override(car):
    got = setup_elements([_setup("a")], car, use_static_loads=False)
    assert got.static_corner_load_n is None and got.has_stops
    got = setup_elements([_setup("a")], car, static_corner_load_n=[1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(got.static_corner_load_n, [1, 2, 3, 4])
    with pytest.raises(PlannerError, match="4 positive numbers"):
        setup_elements([_setup("a")], car, static_corner_load_n=[1.0, -2.0, 3.0, 4.0])


def test_unknown_id_and_thick_packer_refused(car, stops):
    with pytest.raises(PlannerError, match="setup 'x'.*LF.*BS-Q"):
        setup_elements([_setup("x", bump_stops={"LF": "BS-Q"})], car)
    with pytest.raises(PlannerError, match="setup 'y'.*RF"):
        setup_elements([_setup("y", packers_m={"RF": 0.016})], car)
    with pytest.raises(TypeError, match="BumpStopLibrary"):
        setup_elements([_setup("z")], car, bump_stops={"BS-F": 1})


def test_given_library_replaces_the_models(car):
    other = BumpStopLibrary([BumpStop("BS-F", 0.012, [0.0, 0.01], [0.0, 900.0]),
                             BumpStop("BS-R", 0.02, [0.0, 0.01], [0.0, 900.0])])
    got = setup_elements([_setup("a")], car, bump_stops=other)
    assert abs(got.tables[0][0][0] - 0.010) < TRAVEL_TOL_M
    assert got.settings["library"] == "given"


def test_vary_elements_and_distinct(car, stops):
    base = _setup("base")
    out = vary_elements([base], bump_stops={"front": ["BS-F", "BS-F2"]},
                        packers_m={"front": [0.0, 0.002]}, library=stops)
    assert [s.name for s in out] == ["base", "base F=BS-F pF=0mm", "base F=BS-F pF=2mm",
                                     "base F=BS-F2 pF=0mm", "base F=BS-F2 pF=2mm"]
    elem = setup_elements(out, car)
    kept, idx = distinct_setups(out, elem)
    # "base" resolves to BS-F with 2 mm (the baseline run's): its variant is dropped
    assert [s.name for s in kept] == ["base", "base F=BS-F pF=0mm", "base F=BS-F2 pF=0mm",
                                      "base F=BS-F2 pF=2mm"]
    np.testing.assert_array_equal(idx, [0, 1, 3, 4])
    with pytest.raises(PlannerError, match="groups"):
        vary_elements([base], packers_m={"front": [0.0], "LF": [0.001]})
    with pytest.raises(PlannerError, match="group 'middle'"):
        vary_elements([base], packers_m={"middle": [0.0]})
    with pytest.raises(PlannerError, match="BS-Q"):
        vary_elements([base], bump_stops={"rear": ["BS-Q"]}, library=stops)
    with pytest.raises(PlannerError, match="thicker|gap"):
        vary_elements([base], bump_stops={"front": ["BS-F2"]}, packers_m={"front": [0.012]},
                      library=stops)


def test_parse_length():
    assert parse_length("2mm") == pytest.approx(0.002)
    assert parse_length("0.1in") == pytest.approx(0.00254)
    assert parse_length("0.1", units="imperial") == pytest.approx(0.00254)
    assert parse_length("0.003") == pytest.approx(0.003)
    with pytest.raises(PlannerError, match="not a length"):
        parse_length("two")
    with pytest.raises(PlannerError, match=">= 0"):
        parse_length("-1mm")


# ----------------------------------------------------------------------------------------------
# the real car end to end (issue 25's "done when"): identified with its elements declared,
# predicted on setups with bump-stop and packer choices, against the known car
# ----------------------------------------------------------------------------------------------

#: The issue's bars for a car with its elements declared: 0.2 % median and 1 % max of the
#: spec's metrics against the known car, Spearman >= 0.99 of the scores, the same best.
#: Measured (55 setups): bump stops 0.115 % / 0.63 %, Spearman 0.9995; lift-off 0.109 % /
#: 0.67 %, Spearman 0.9992 (the identification's own floor on these runs: 0.107 % / 0.67 %).
REAL_MEDIAN, REAL_MAX, REAL_SPEARMAN = 0.002, 0.01, 0.99
#: The lift-off share against the known car's: the issue's 0.5 percentage points
#: (measured 0.07).
LIFTOFF_SHARE_ATOL = 0.005
#: The rest found in the data (the start of a tapered run) against the run's mean travel [m]:
#: the stops hold the mean back by 0.01-0.2 mm.
REST_MEAN_M = 5e-4
#: Session runs [s]: 5 runs of 400 s (the paper's are 800 s); 100 s runs leave this car's
#: identification a floor of about 0.3 % median, above the bar.
REAL_RUN_S = 400.0
#: The bump stops of the real-car tests: one progressive table (100-600 kN/m over 15 mm),
#: front contact 4.5 mm from rest (a softer choice at 6 mm), rear 6 mm.
REAL_TABLE = ([0.0, 0.002, 0.005, 0.010, 0.015], [0.0, 200.0, 1000.0, 3500.0, 6500.0])


def _gt_crate():
    from ident.models.shocks import DigressiveShock

    return [DigressiveShock(f"G{s:.2f}", bump_low_n_s_m=9000 * s, bump_knee_m_s=0.08,
                            bump_high_n_s_m=3500 * s, rebound_low_n_s_m=14000 * s,
                            rebound_knee_m_s=0.08, rebound_high_n_s_m=5000 * s, lag_s=0.002)
            for s in (0.6, 0.8, 1.0, 1.25, 1.5)]


def _real_car(paper_plan, vehicle, *, stops, static, moment_multiple, diagnose=False):
    """The GT-like car on the virtual rig (the paper's plan, 2 % noise), identified with the
    elements it has declared; returns (model, session)."""
    import dataclasses
    import warnings

    from ident.identify.pipeline import identify_session
    from ident.sim.virtual_rig import simulate_session

    base = {"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": "BS-R"} if stops else None
    runs = tuple(dataclasses.replace(r, duration_s=REAL_RUN_S, bump_stops=base)
                 for r in paper_plan.runs)
    drive = dict(paper_plan.drive, peak_wheelloader_m=0.006,
                 roll_moment_multiple=moment_multiple, pitch_moment_multiple=moment_multiple)
    plan = dataclasses.replace(paper_plan, runs=runs, noise=0.02, drive=drive,
                               bump_stops=stops, static_corner_load_n=static)
    session = simulate_session(plan, vehicle)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify_session(session, diagnose=diagnose), session


def _validation_drive(vehicle, roughness_m3):
    from ident.data.drive import make_track_drive

    return make_track_drive(duration_s=60.0, fs_hz=100.0, seed=3, roughness_m3=roughness_m3,
                            wheelbase_m=vehicle.a_m + vehicle.b_m,
                            track_width_m=vehicle.track_front_m,
                            aero={"aero_heave": 1500.0, "aero_pitch": 800.0,
                                  "aero_roll": 300.0})


def _compare(truth, pred):
    """(median, max) relative error of the spec's metrics, Spearman of the scores, same best."""
    from scipy.stats import spearmanr

    from ident.sim.metrics import METRIC_NAMES
    from planner.objective import score_setups

    m = list(METRIC_NAMES)
    err = np.abs(pred.table[m].to_numpy(float) / truth.table[m].to_numpy(float) - 1.0)
    st = score_setups(truth.table[m]).table["score"]
    sp = score_setups(pred.table[m]).table["score"]
    return (float(np.median(err)), float(err.max()), float(spearmanr(st, sp).statistic),
            st.idxmin() == sp.idxmin())


@pytest.mark.slow
def test_declared_bump_stops_predict_the_known_car(paper_plan, bumpstop_vehicle):
    """A GT-like car with progressive bump stops (front touched 3-8 % of the time on the
    validation drive), 2 % noise, identified with them declared, predicted on 55 setups
    with packer and bump-stop choices: within the issue's bars of the known car; the
    model carries its elements, and the linear car without them is far off."""
    from ident.models.library import ShockLibrary
    from planner.predict import predict_setups

    stops = BumpStopLibrary([BumpStop("BS-F", 0.0045, *REAL_TABLE),
                             BumpStop("BS-F2", 0.006, *REAL_TABLE),
                             BumpStop("BS-R", 0.006, *REAL_TABLE)])
    from ident.identify.diagnose import RESIDUAL_EXCESS_MAX

    model, session = _real_car(paper_plan, bumpstop_vehicle, stops=stops, static=None,
                               moment_multiple=0.5, diagnose=True)
    assert model.elements.baseline_stops["LF"] == "BS-F"
    # the stop force from the travel measured from rest (the start of each tapered run)
    info = model.frf.settings["bump_stop_force"]
    assert set(info) == {r.name for r in session.runs}
    for run in session.runs:
        assert info[run.name]["rest"] == "rest (start)"
        assert max(abs(v) for v in info[run.name]["rest_minus_mean_m"].values()) < REST_MEAN_M
    # declared, the diagnosis reports the stops' contact and nothing the model cannot see
    diag = model.diagnosis
    assert set(diag.findings.kind) == {"bump stop contact"}
    assert diag.checks.residual_excess.max() < RESIDUAL_EXCESS_MAX
    crate = _gt_crate()
    lib = ShockLibrary.from_models(crate + list(session.shocks.values()))
    setups = []
    for f in crate:
        for r in crate:
            ids = {"LF": f.id, "RF": f.id, "LR": r.id, "RR": r.id}
            setups.append(Setup(f"{f.id}/{r.id}", ids))
            setups.append(Setup(f"{f.id}/{r.id} p2", ids, packers_m={"LF": 0.002, "RF": 0.002}))
            if f.id == r.id:
                setups.append(Setup(f"{f.id}/{r.id} F2", ids,
                                    bump_stops={"LF": "BS-F2", "RF": "BS-F2"}))
    base_ids = dict(session.runs[0].setup)  # the session's baseline shocks
    setups.append(Setup("baseline", base_ids))
    assert len(setups) >= 40
    drive = _validation_drive(bumpstop_vehicle, 16e-6)
    truth = predict_setups(bumpstop_vehicle, drive, setups, lib,
                           elements=ElementOptions(use_model=model.elements))
    pred = predict_setups(model, drive, setups, lib)
    front = truth.table.loc["baseline", ["bump_stop_contact_share_LF",
                                         "bump_stop_contact_share_RF"]]
    assert 0.03 <= front.min() and front.max() <= 0.08, front
    med, mx, rho, same = _compare(truth, pred)
    assert med <= REAL_MEDIAN and mx <= REAL_MAX and rho >= REAL_SPEARMAN and same
    np.testing.assert_allclose(pred.table["bump_stop_contact_share_LF"],
                               truth.table["bump_stop_contact_share_LF"], atol=0.01)
    linear = predict_setups(model, drive, setups, lib, elements=ElementOptions(use_model=False,
                                                                               bump_stops=stops))
    assert _compare(truth, linear)[1] > 3 * REAL_MAX  # the stops matter on this car
    # the linear part is the car without its stops: the stop force left the model
    bare = [Setup(s.name, dict(s.shocks)) for s in setups if s.bump_stops is None
            and s.packers_m is None]
    med, mx, _, _ = _compare(predict_setups(bumpstop_vehicle, drive, bare, lib),
                             predict_setups(model, drive, bare, lib,
                                            elements=ElementOptions(use_model=False)))
    assert med <= REAL_MEDIAN and mx <= REAL_MAX


@pytest.mark.slow
def test_declared_static_loads_predict_lift_off(paper_plan, bumpstop_vehicle):
    """The same car on its static loads (the session's runs hardly lift), predicted on a
    rough drive where the rear tires leave the pads 1-3 % of the time: within the bars, and
    the lift-off share within 0.5 percentage points of the known car's."""
    from ident.models.library import ShockLibrary
    from planner.predict import predict_setups

    static = bumpstop_vehicle.static_corner_load_n
    model, session = _real_car(paper_plan, bumpstop_vehicle, stops=None, static=static,
                               moment_multiple=0.2)
    np.testing.assert_array_equal(model.elements.static_corner_load_n, static)
    crate = _gt_crate()
    lib = ShockLibrary.from_models(crate + list(session.shocks.values()))
    setups = [Setup(f"{f.id}/{r.id}", {"LF": f.id, "RF": f.id, "LR": r.id, "RR": r.id})
              for f in crate for r in crate]
    drive = _validation_drive(bumpstop_vehicle, 32e-6)
    truth = predict_setups(bumpstop_vehicle, drive, setups, lib,
                           elements=ElementOptions(static_corner_load_n=static))
    pred = predict_setups(model, drive, setups, lib)
    shares = truth.table[[f"tire_liftoff_share_{c}" for c in CORNERS]].max()
    assert 0.01 <= shares.max() <= 0.03
    med, mx, rho, same = _compare(truth, pred)
    assert med <= REAL_MEDIAN and mx <= REAL_MAX and rho >= REAL_SPEARMAN and same
    for c in CORNERS:
        np.testing.assert_allclose(pred.table[f"tire_liftoff_share_{c}"],
                                   truth.table[f"tire_liftoff_share_{c}"],
                                   atol=LIFTOFF_SHARE_ATOL)


# ----------------------------------------------------------------------------------------------
# rank, sweep and the CLI with elements (the known car: no identification)
# ----------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def gt_case(bumpstop_vehicle, tmp_path_factory):
    """The known GT-like car with stops, a 10 s drive, a 3-shock crate, written as files."""
    from ident.data.drive import write_drive
    from ident.models.bumpstops import write_bump_stops
    from ident.models.library import ShockLibrary, write_shock_library
    from ident.models.vehicle import write_vehicle

    folder = tmp_path_factory.mktemp("gt_case")
    stops = BumpStopLibrary([BumpStop("BS-F", 0.0045, *REAL_TABLE),
                             BumpStop("BS-F2", 0.006, *REAL_TABLE),
                             BumpStop("BS-R", 0.006, *REAL_TABLE)])
    crate = ShockLibrary.from_models([_gt_crate()[k] for k in (0, 2, 4)])
    drive = _validation_drive(bumpstop_vehicle, 16e-6)
    drive = type(drive)(drive.name, drive.fs_hz, {c: x[:1000] for c, x in drive.channels.items()})
    write_bump_stops(stops, folder / "bumpstops.toml")
    write_shock_library(crate, folder / "shocks.toml")
    write_vehicle(bumpstop_vehicle, folder / "car.toml")
    write_drive(drive, folder / "drive.csv")
    return {"folder": folder, "stops": stops, "crate": crate, "drive": drive,
            "car": CarElements(stops, {"LF": "BS-F", "RF": "BS-F", "LR": "BS-R", "RR": "BS-R"},
                               {}, bumpstop_vehicle.static_corner_load_n)}


def test_rank_tries_packers_and_stops(bumpstop_vehicle, gt_case):
    """rank_setups with packer and stop choices: every setup with each, the repeats of a
    setup's own elements dropped, columns written, the stops' contact in the loop."""
    from planner.rank import rank_setups
    from planner.setups import enumerate_setups

    setups = enumerate_setups(gt_case["crate"])
    r = rank_setups(bumpstop_vehicle, gt_case["drive"], gt_case["crate"], setups=setups,
                    elements=ElementOptions(use_model=gt_case["car"],
                                            vary_packers_m={"front": [0.0, 0.002]},
                    vary_bump_stops={"front": ["BS-F", "BS-F2"]}), top=40, n_check=0,
                    uncertainty=False)
    # per setup: itself (BS-F, 0 mm), BS-F 2 mm, BS-F2 0 mm, BS-F2 2 mm
    assert len(r.screening) == 4 * len(setups)
    assert set(r.table["packer_LF"]) == {0.0, 0.002}
    assert set(r.table["bump_stop_RF"]) == {"BS-F", "BS-F2"}
    share = r.table["bump_stop_contact_share_LF"]
    assert share.max() > 0.05
    # a 2 mm packer: more contact than the same setup without (every shock setup)
    for s in setups:
        assert share[f"{s.name} F=BS-F pF=2mm"] > share[s.name]
        assert share[f"{s.name} F=BS-F2 pF=0mm"] < share[s.name]


def test_sweep_simulates_every_choice(bumpstop_vehicle, gt_case):
    from planner.sweep import sweep_setups

    res = sweep_setups(bumpstop_vehicle, gt_case["drive"], gt_case["crate"],
                       elements=ElementOptions(use_model=gt_case["car"],
                                               vary_packers_m={"front": [0.0, 0.002]}),
                       run=RunOptions(scheduler="none"),
                       top=2, progress=False)
    n_top = res.settings["n_top"]
    assert len(res.table) >= 2 * n_top
    assert {"packer_LF", "bump_stop_LF"} <= set(res.table.columns)
    with pytest.raises(PlannerError, match="sweep enumerates shocks"):
        sweep_setups(bumpstop_vehicle, gt_case["drive"], gt_case["crate"],
                     setups=[Setup("x", dict.fromkeys(CORNERS, "G1.00"),
                                   packers_m={"LF": 0.001})],
                     run=RunOptions(scheduler="none"), progress=False)


def test_cli_predict_and_rank_with_bump_stops(gt_case, capsys):
    """``predict --bump-stops`` with a setups CSV naming stops and packers (in mm through the
    file's units), ``rank --try-packers``; the files carry the element columns."""
    import pandas as pd

    from planner.cli import main

    f = gt_case["folder"]
    (f / "setups.csv").write_text("setup,LF,RF,LR,RR,bump_stop_LF,bump_stop_RF,packer_LF,packer_RF\n"
                                  "a,G1.00,G1.00,G1.00,G1.00,BS-F,BS-F,0.002,0.002\n"
                                  "b,G0.60,G0.60,G1.00,G1.00,BS-F2,BS-F2,,\n")
    assert main(["predict", "--model", str(f / "car.toml"), "--drive", str(f / "drive.csv"),
                 "--shocks", str(f / "shocks.toml"), "--setups", str(f / "setups.csv"),
                 "--bump-stops", str(f / "bumpstops.toml"), "--out", str(f / "pred.csv"),
                 "-q"]) == 0
    out = capsys.readouterr().out
    assert "bump stops in the loop" in out
    t = pd.read_csv(f / "pred.csv").set_index("setup")
    assert t.loc["a", "packer_LF"] == 0.002 and t.loc["b", "bump_stop_LF"] == "BS-F2"
    assert list(t.columns).index("bump_stop_LF") > list(t.columns).index(
        "shock_velocity_rms_RR")  # the spec's metrics first
    assert main(["rank", "--model", str(f / "car.toml"), "--drive", str(f / "drive.csv"),
                 "--shocks", str(f / "shocks.toml"), "--setups", str(f / "setups.csv"),
                 "--bump-stops", str(f / "bumpstops.toml"), "--try-packers", "front=0,1mm",
                 "--no-uncertainty", "--out", str(f / "ranking"), "-q"]) == 0
    r = pd.read_csv(f / "ranking" / "ranking.csv")
    assert set(r["packer_LF"]) == {0.0, 0.001, 0.002}
    assert main(["rank", "--model", str(f / "car.toml"), "--drive", str(f / "drive.csv"),
                 "--shocks", str(f / "shocks.toml"), "--try-packers", "front", "--out",
                 str(f / "r2"), "-q"]) != 0
    assert "--try-packers 'front': write GROUP=A,B" in capsys.readouterr().err
