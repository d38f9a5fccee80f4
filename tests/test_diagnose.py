"""Tests of ident.identify.diagnose: what the linear model cannot see, found in the session."""

import dataclasses
import json
import logging
import re
import warnings

import numpy as np
import pytest

from ident.data.channels import CORNERS
from ident.data.session import make_session
from ident.identify.diagnose import (
    RESIDUAL_EXCESS_MAX,
    STIFFENING_FORCE_SHARE,
    STIFFENING_Z,
    Diagnosis,
    diagnose_session,
    rest_levels,
)

#: The bump stop of the front corners: progressive (100, 267, 500, 600 kN/m), contact 6 mm
#: from rest; on the drive below it is touched 5-9 % of the time.
STOP_TABLE = ([0.0, 0.002, 0.005, 0.010, 0.015], [0.0, 200.0, 1000.0, 3500.0, 6500.0])
FRONT_GAP_M = 0.006
#: The identification drive for the GT-like car: the paper's noise drive scaled to the car
#: (6 mm peak at the wheelloaders, roll and pitch moments 0.5x the chassis stiffness per
#: degree): travel within +-9 mm at the 1 % quantiles, the tires lifting 0.6-3.6 % of the
#: time with the car's static loads.
DRIVE_PEAK_M = 0.006
MOMENT_MULTIPLE = 0.5
#: Runs of the session [s] (5 runs: the paper's plan); the fits take the time (about 30 s).
RUN_S = 100.0
#: The stiffening's share of time against the travel beyond the true gap: the hinge's onset
#: comes out 0.5-0.9 mm early (the acquisition filter spreads the stop's force over the
#: samples next to contact), so its share is larger: measured +1.6 to +3.3 points.
STIFFENING_SHARE_ATOL = 0.05
#: The share of time near zero contact (below 5 % of the static load) against the
#: simulation's own lift-off share: the samples about to lift count too; measured +0.1 to
#: +0.3 points.
LIFTOFF_SHARE_ATOL = 0.005
#: Lift-off with the static load carried by the channel against given: the rest level
#: (noisy, 10 samples) stands for the load in the near-zero threshold; measured up to 1.2e-3.
CARRIED_SHARE_ATOL = 2e-3
#: The declared stop's contact share (measured travel, filtered and noisy) against the
#: simulation's (its solved travel): measured within 0.1 points.
CONTACT_SHARE_ATOL = 0.005


def _rig_session(paper_plan, vehicle, *, noise=0.02):
    """The GT-like car on the virtual rig: bump stops at the front, the car's static loads
    (the tires lift off), everything declared as the rig records it; and the shares the
    simulation reports per run (``run -> {element stat: value}``, the rig's log)."""
    from ident.models.bumpstops import BumpStop, BumpStopLibrary
    from ident.sim.rig import simulate_session

    library = BumpStopLibrary([BumpStop("BS-F", FRONT_GAP_M, *STOP_TABLE)])
    stops = {"LF": "BS-F", "RF": "BS-F"}
    runs = tuple(dataclasses.replace(r, duration_s=RUN_S, bump_stops=stops)
                 for r in paper_plan.runs)
    drive = dict(paper_plan.drive, peak_wheelloader_m=DRIVE_PEAK_M,
                 roll_moment_multiple=MOMENT_MULTIPLE, pitch_moment_multiple=MOMENT_MULTIPLE)
    plan = dataclasses.replace(paper_plan, runs=runs, noise=noise, drive=drive,
                               bump_stops=library,
                               static_corner_load_n=vehicle.static_corner_load_n)
    truth = {}

    class Elements(logging.Handler):
        def emit(self, record):
            msg = record.getMessage()
            m = re.match(r"run (\S+): (.*bump_stop_contact_share.*)", msg)
            if m:
                truth[m.group(1)] = {k: float(v) for k, v in
                                     re.findall(r"(\w+_(?:LF|RF|LR|RR)) (\S+?)(?:,|$)",
                                                m.group(2))}

    logger = logging.getLogger("ident.sim.rig")
    handler, level = Elements(), logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        session = simulate_session(plan, vehicle)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    return session, truth


def _declared(session, *, stops=False, static=False, carried=False):
    """The session with only some of what the car has declared; `carried`: the tire-force
    channels carry the static load (and no loads are given)."""
    runs = []
    for r in session.runs:
        channels = dict(r.channels)
        if carried:
            for c, load in zip(CORNERS, session.static_corner_load_n):
                channels[f"tire_force_{c}"] = channels[f"tire_force_{c}"] + load
        runs.append(dataclasses.replace(r, channels=channels,
                                        bump_stops=r.bump_stops if stops else None,
                                        packers_m=r.packers_m if stops else None))
    return make_session(session.name, runs, session.shocks,
                        bump_stops=session.bump_stops if stops else None,
                        static_corner_load_n=session.static_corner_load_n if static else None)


@pytest.fixture(scope="module")
def real_car(paper_plan, bumpstop_vehicle):
    """The GT-like car with bump stops and lift-off, identified with nothing declared (the
    identification's own diagnosis kept), the full session and the simulation's shares."""
    from ident.identify.pipeline import identify_session

    session, truth = _rig_session(paper_plan, bumpstop_vehicle)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(_declared(session))
    return session, model, truth


def _found(diag, kind):
    f = diag.findings
    return f[f.kind == kind]


def test_plain_cars_print_nothing(identified_model, gt_identified):
    """The paper car (noise-free) and a GT-like car with a flexible chassis (2 % noise): the
    identification's diagnosis finds nothing, with every run re-simulated."""
    for model in (identified_model, gt_identified):
        diag = Diagnosis.from_dict(model.settings["diagnosis"])
        assert len(diag) == 0, diag.lines()
        assert diag.lines() == []
        assert len(diag.checks) == 4 * len(model.settings["runs"])
        # the checks ran (every run re-simulated), the forces far inside their threshold
        assert diag.checks.residual_excess.notna().all()
        assert diag.checks.residual_excess.max() < RESIDUAL_EXCESS_MAX
        assert diag.checks.stiffening_force_share.max() < STIFFENING_FORCE_SHARE / 10


def test_undeclared_bump_stops_are_found_with_their_corner_and_share(real_car):
    """Nothing declared: the identification warns of a bump stop (stiffening) at the front
    corners in every run, with its share of time near the travel beyond the true gap, and
    at no rear corner."""
    session, model, _ = real_car
    diag = Diagnosis.from_dict(model.settings["diagnosis"])
    json.dumps(model.settings["diagnosis"])  # kept in the model file's JSON
    stiff = _found(diag, "stiffening")
    assert set(stiff.corner) == {"LF", "RF"}
    assert len(stiff) == 2 * len(session.runs)
    for f in stiff.itertuples():
        travel = session.run(f.run).channels[f"shock_travel_{f.corner}"]
        true = np.mean(travel - travel[:10].mean() > FRONT_GAP_M)
        assert 0.02 < true < 0.1
        assert f.share == pytest.approx(true, abs=STIFFENING_SHARE_ATOL)
        assert f.value == pytest.approx(FRONT_GAP_M, abs=0.0015)  # the onset [m]
    rows = diag.checks.set_index(["run", "corner"])
    assert (rows.xs("LF", level="corner").stiffening_z > 10 * STIFFENING_Z).all()
    assert "bump stop" in stiff.message.iloc[0] and "declare the bump stops" in stiff.fix.iloc[0]
    # the re-simulation misses the car at every corner (stops at the front, lift-off all round)
    assert set(_found(diag, "residual").corner) == set(CORNERS)


def test_warnings_name_corner_kind_and_share(real_car, caplog):
    session, model, _ = real_car
    with caplog.at_level(logging.WARNING, logger="ident.identify.diagnose"):
        diag = diagnose_session(_declared(session), model)
    text = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(text) == len(diag.groups())
    lf = [t for t in text if t.startswith("LF: stiffening")]
    assert len(lf) == 1
    assert re.search(r"\d+\.\d-\d+\.\d % of the time \(5 runs\): signs of a bump stop", lf[0])


def test_lift_off_with_static_loads_given_or_carried_by_the_channel(real_car):
    """Static loads given, or tire-force channels that carry them: the share of time near
    zero contact at every corner, close to the simulation's lift-off share; the same shares
    either way."""
    session, model, truth = real_car
    given = diagnose_session(_declared(session, static=True), model, residual=False)
    carried = diagnose_session(_declared(session, carried=True), model, residual=False)
    a, b = _found(given, "lift-off"), _found(carried, "lift-off")
    assert len(a) == 4 * len(session.runs)
    np.testing.assert_allclose(a.share.to_numpy(), b.share.to_numpy(), atol=CARRIED_SHARE_ATOL)
    assert "carries the static load" in b.message.iloc[0]
    assert "static load given" in a.message.iloc[0]
    for f in a.itertuples():
        true = truth[f.run][f"tire_liftoff_share_{f.corner}"]
        assert true > 0.005
        assert f.share == pytest.approx(true, abs=LIFTOFF_SHARE_ATOL)
    # nothing declared and a dynamic channel: no contact level to judge
    assert len(_found(Diagnosis.from_dict(model.settings["diagnosis"]), "lift-off")) == 0


def test_declared_bump_stops_give_the_contact_share(real_car):
    """Declared stops: the share of time beyond the declared gap from rest, as the
    simulation counts it, and no stiffening left (the declared stop explains the force)."""
    session, model, truth = real_car
    diag = diagnose_session(_declared(session, stops=True), model, residual=False)
    contact = _found(diag, "bump stop contact")
    assert set(contact.corner) == {"LF", "RF"} and len(contact) == 2 * len(session.runs)
    for f in contact.itertuples():
        assert f.value == FRONT_GAP_M
        assert f.share == pytest.approx(truth[f.run][f"bump_stop_contact_share_{f.corner}"],
                                        abs=CONTACT_SHARE_ATOL)
    assert len(_found(diag, "stiffening")) == 0
    assert (diag.checks.rest == "rest (start)").all()


def test_rest_from_the_start_else_the_mean(real_car):
    """A tapered run rests at its start; a run cut out of the middle of a drive has no rest,
    and the mean is used (and said)."""
    session, _, _ = real_car
    run = session.runs[0]
    levels, used = rest_levels(run)
    assert used == "rest (start)"
    assert levels["shock_travel_LF"] == pytest.approx(np.median(
        run.channels["shock_travel_LF"][:10]))
    n = run.n_samples
    cut = dataclasses.replace(run, time_s=run.time_s[n // 4:n // 2] - run.time_s[n // 4],
                              channels={k: v[n // 4:n // 2] for k, v in run.channels.items()})
    levels, used = rest_levels(cut)
    assert used == "mean"
    assert levels["shock_travel_LF"] == pytest.approx(cut.channels["shock_travel_LF"].mean())


@pytest.mark.parametrize("which, match", [("session", "needs a Session"),
                                          ("model", "needs a VehicleModel")])
def test_bad_arguments(real_car, which, match):
    session, model, _ = real_car
    with pytest.raises(TypeError, match=match):
        diagnose_session(*((None, model) if which == "session" else (session, None)))


def test_lines_and_round_trip(real_car):
    """What ``shockplan identify`` prints: one line per corner and kind over the runs, then
    its fix; the dict kept in the model's settings reads back to the same findings."""
    _, model, _ = real_car
    diag = Diagnosis.from_dict(model.settings["diagnosis"])
    again = Diagnosis.from_dict(json.loads(json.dumps(diag.to_dict())))
    assert again.findings.equals(diag.findings)
    lines = diag.lines()
    assert len(lines) == 2 * len(diag.groups())
    assert lines[0].startswith("LF: stiffening ") and lines[1].startswith("    fix: declare")
    assert diag.settings["amplitude"].startswith("not checked")  # one drive level
