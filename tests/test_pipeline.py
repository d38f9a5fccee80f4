"""Tests of ident.identify.pipeline with the real car's elements declared (issue 25): tires
that leave the pads corrected for. The bump stops taken out of the linear model are tested
end to end with the planner in tests/test_elements.py (one 400 s session for both)."""

import numpy as np

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


def _pair_task(common, tasks):
    """A stand-in for the pair fits: each task's result depends on the task alone."""
    return [(common * t, t % 7) for t in tasks]


def test_map_pairs_returns_the_tasks_in_order_whatever_the_processes():
    """The pair fits in batches on several processes come back in the tasks' order, equal to
    the one-process result (the model does not depend on the number of processes)."""
    from ident.identify import pipeline

    tasks = list(range(101))
    serial = pipeline._map_pairs(_pair_task, 3, tasks, 1)
    assert pipeline._map_pairs(_pair_task, 3, tasks, 2) == serial == _pair_task(3, tasks)
