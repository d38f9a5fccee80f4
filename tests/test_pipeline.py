"""Tests of ident.identify.pipeline with the real car's elements declared (issue 25): tires
that leave the pads corrected for. The bump stops taken out of the linear model are tested
end to end with the planner in tests/test_elements.py (one 400 s session for both). Third
elements (issue 38): the truth round trip of a prototype-like car, its elements' forces
measured or computed from their curves."""

import dataclasses
import warnings

import numpy as np
import pytest

from ident.data.channels import CORNERS
from ident.data.session import make_session


class _TireGain:
    """A stand-in model: each tire force is `k` times its own wheelloader (no dynamics)."""

    def __init__(self, k, cbar):
        from ident.identify.frf import MODEL_INPUTS

        self.k, self.cbar_n_s_m = k, np.full(4, cbar)
        self.input_names = MODEL_INPUTS
        self.output_names = tuple(f"tire_force_{c}" for c in CORNERS)

    def frequency_response(self, f_hz):
        H = np.zeros((4, len(self.input_names), np.size(f_hz)), dtype=complex)
        for j, c in enumerate(CORNERS):
            H[j, self.input_names.index(f"wheelloader_{c}")] = self.k
        return H


def test_lifted_samples_and_the_pad_correction(rng):
    """Lift-off found where static + tire force (from rest) is near zero; the pad
    correction is the wheelloader offset that the model's tire forces need to match the
    measured ones there (exact for a model without dynamics), the ride height moved by it."""
    from ident.data.channels import RIG_INPUTS
    from ident.data.session import Run
    from ident.identify.pipeline import liftoff_samples, pad_corrected_session
    from ident.models.library import ShockLibrary
    from ident.models.shocks import LinearShock

    fs, n, k, static = 100.0, 3000, 4e5, 3000.0
    t = np.arange(n) / fs
    taper = np.clip(t - 1.0, 0.0, 1.0)
    u = {c: 0.001 * taper * rng.standard_normal(n) for c in CORNERS}
    episodes = rng.choice(np.arange(200, n - 200, 5), 12, replace=False)
    u["LF"][episodes] = -0.01  # the pad drops 10 mm: the tire (7.5 mm static) leaves it
    u["RR"][episodes + 1] = -0.009
    channels = {c: np.zeros(n) for c in RIG_INPUTS}
    for c in CORNERS:
        channels[f"wheelloader_{c}"] = u[c]
        channels[f"shock_velocity_{c}"] = 0.1 * taper * rng.standard_normal(n)
        channels[f"tire_force_{c}"] = np.maximum(k * u[c], -static)  # contact >= 0
        channels[f"ride_height_{c}"] = 0.05 - u[c]
    shocks = ShockLibrary([LinearShock("L", 9000.0)])
    run = Run(name="r", file="r.csv", setup=dict.fromkeys(CORNERS, "L"), role="baseline",
              time_s=t, channels=channels, fs_hz=fs)
    session = make_session("lift", [run], shocks, static_corner_load_n=[static] * 4)
    lifted = liftoff_samples(session)["r"]
    assert lifted.sum(axis=1).tolist() == [12, 0, 0, 12]
    assert liftoff_samples(make_session("no loads", [run], shocks)) is None
    # the model's tire force is k (u + w): -static where lifted with w = -static / k - u
    corrected, info = pad_corrected_session(session, _TireGain(k, 9000.0), {"r": lifted})
    got = corrected.runs[0].channels
    for j, c in enumerate(CORNERS):
        w = got[f"wheelloader_{c}"] - u[c]
        want = np.where(lifted[j], np.maximum(-static / k - u[c], 0.0), 0.0)
        np.testing.assert_allclose(w, want, atol=1e-9)
        np.testing.assert_allclose(got[f"ride_height_{c}"] - channels[f"ride_height_{c}"], -w,
                                   atol=1e-12)
    assert info["r"]["lifted_samples"]["LF"] == 12


#: The identified model's FRFs (every rig input and dF to every output, 0.5-20 Hz) against
#: the known car's linear plant without its third elements: the median over the pairs of
#: the relative RMS error. The same plan and noise on the car without elements (a plain
#: car): 1.0 %; with them, forces measured: 1.1 % (1.6 % with the elements' whole force in
#: dF, not written around their linear part); from their curves: 1.3 %; the elements left
#: in the linear car (before issue 38): 43 %.
THIRD_FRF_MEDIAN = 0.02


def _frf_error(model, vehicle):
    """Per pair, the relative RMS error of the model's FRF against the known car's linear
    plant (without third elements) at the model's ``c_bar``, 0.5-20 Hz."""
    from ident.models.vehicle import build_full_car

    truth = build_full_car(vehicle)
    f = model.frf.f_hz
    f = f[(f >= 0.5) & (f <= 20.0)]
    Ht = truth.frequency_response(f, damping_n_s_m=model.cbar_n_s_m)
    Ht = Ht[[truth.output_names.index(o) for o in model.output_names]]
    H = model.frequency_response(f)
    return np.sqrt(np.mean(np.abs(H - Ht) ** 2, -1) / np.mean(np.abs(Ht) ** 2, -1))


def test_third_elements_truth_round_trip(prototype_case, prototype_identified, tmp_path):
    """A prototype-like car (heave elements with gapped springs front and rear, a front
    roll damper; runs changing corner, heave and roll dampers; 2 % noise): the elements'
    measured forces in the corners' inputs, the identified linear car is the known car
    without them; the model keeps the declared elements and the baseline's fit, and its
    diagnosis (the runs re-simulated with the elements) finds nothing."""
    from ident.data.third import CarThird
    from ident.identify.model import load_model

    vehicle, session = prototype_case
    model = prototype_identified
    assert model.settings["third"] == {
        "motion_ratios": {"heave_front": 1.0, "heave_rear": 1.2, "roll_front": 0.8},
        "dampers": {"heave_front": "H1", "heave_rear": "H1", "roll_front": "R1",
                    "roll_rear": None},
        "heave_springs": {"front": "HS-F", "rear": "HS-R"},
        "heave_packers_m": {"front": 0.0, "rear": 0.0}}
    assert model.third == CarThird(session.third_elements, session.run("baseline").third)
    model.save(tmp_path / "m.npz")
    assert load_model(tmp_path / "m.npz").third == model.third  # kept in the model file
    assert set(model.elements.bump_stops.ids) == {"HS-F", "HS-R"}  # the heave springs
    how = model.frf.settings["third_element_force"]
    assert set(how) == {r.name for r in session.runs}
    assert how["baseline"] == {"heave_front": "measured", "heave_spring_front": "measured",
                               "heave_rear": "measured", "heave_spring_rear": "measured",
                               "roll_front": "measured"}
    err = _frf_error(model, vehicle)
    assert np.median(err) < THIRD_FRF_MEDIAN
    # instrumental variables by default for a session with third elements, the band-end
    # gate relaxed with them (ident.identify.instruments; pipeline.IV_COHERENCE_MIN)
    from ident.identify.pipeline import IV_COHERENCE_MIN

    assert model.frf.settings["instruments"] == "travel"
    assert model.frf.settings["conditioning"]["coherence_min"] == IV_COHERENCE_MIN
    # written around the heave and roll dampers' linear part at the baseline, brought back
    damping = np.array(model.frf.settings["third_linear_damping_n_s_m"])
    assert damping[0, 1] > 0 and damping[0, 1] != damping[0, 0] and not damping[:2, 2:].any()
    assert len(model.diagnosis) == 0, model.diagnosis.lines()


@pytest.mark.slow
def test_third_elements_from_their_curves(prototype_case):
    """The same session without the elements' channels (no load cells, velocities or
    travels): their forces from their curves at the corners' motion identify as well."""
    from ident.data.channels import THIRD_CHANNELS
    from ident.identify.pipeline import identify_session

    vehicle, session = prototype_case
    runs = [dataclasses.replace(r, channels={k: x for k, x in r.channels.items()
                                             if k not in THIRD_CHANNELS})
            for r in session.runs]
    bare = make_session(session.name, runs, session.shocks, bump_stops=session.bump_stops,
                        third_elements=session.third_elements)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify_session(bare, diagnose=False)
    assert set(model.frf.settings["third_element_force"]["heave-front"].values()) == {"curve"}
    assert np.median(_frf_error(model, vehicle)) < THIRD_FRF_MEDIAN


def _pair_task(common, tasks):
    """A stand-in for the pair fits: each task's result depends on the task alone."""
    return [(common * t, t % 7) for t in tasks]


def test_map_pairs_returns_the_tasks_in_order_whatever_the_processes():
    """The pair fits in batches on several processes come back in the tasks' order, equal to
    the one-process result (the model does not depend on the number of processes)."""
    from ident.identify import pipeline

    tasks = list(range(101))
    serial = pipeline._map_pairs(_pair_task, 3, tasks, 1)
    assert pipeline._map_pairs(_pair_task, 3, tasks, 2) == serial == (_pair_task(3, tasks), None)


def test_map_pairs_runs_meanwhile_here_once_while_the_workers_fit():
    """``meanwhile`` (identify_session's cross-validation) runs once, in this process, with one
    or several worker processes, and its result comes back beside the tasks' results."""
    import os

    from ident.identify import pipeline

    tasks = list(range(31))
    for n_jobs in (1, 2):
        calls = []
        results, aside = pipeline._map_pairs(_pair_task, 5, tasks, n_jobs,
                                             lambda: calls.append(os.getpid()) or "done")
        assert results == _pair_task(5, tasks)
        assert aside == "done"
        assert calls == [os.getpid()]


def test_frf_options_must_be_the_options_object(prototype_case):
    """identify_session's frf_options is an FrfOptions; anything else is refused naming the
    class and the fix, before any work."""
    from ident.identify.pipeline import identify_session

    with pytest.raises(TypeError, match="FrfOptions"):
        identify_session(prototype_case[1], frf_options={"instruments": False})
