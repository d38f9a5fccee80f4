"""Benchmark: the time domain with third elements against the plain loop (issue 38).

The same plant (the known GT car, ``build_full_car(example_gt_vehicle())``), the same track
drive (``make_track_drive``, 120 s at 100 Hz, oversample 2) and the same corner shocks
(digressive curves of several scales, some lagged); once plain, once with a front and rear
heave damper (digressive, lagged), a front roll damper and front and rear heave springs
with a gap that closes on the drive. Each timed through
``ident.sim.closedloop.simulate_batch_metrics`` (the predictions' fused loop and metrics),
``--repeat`` calls of each after a warm-up call (compilation or cache load), the three
runs alternating in each repetition; wall and CPU time (the process's, all threads), the
median and the best. The figure: the time per setup with third elements over the plain
loop's (issue 38's target: at most 1.3x), with the six motion metrics and without them (the
loop's own cost; the motion metrics are formed from the corners' band-passed travels and
velocities, no filter lanes of their own).

Run::

    python benchmarks/bench_third_loop.py [--setups 16] [--repeat 3] [--threads 1]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import engine_version, jit_source, load  # noqa: E402

DRIVE_S = 120.0
FS_HZ = 100.0
DRIVE_SEED = 1
OVERSAMPLE = 2


def _setups(n):
    from ident.models.shocks import DigressiveShock

    def dig(name, scale, lag_s=0.0):
        return DigressiveShock(name, bump_low_n_s_m=8000.0 * scale, bump_knee_m_s=0.03,
                               bump_high_n_s_m=2500.0 * scale,
                               rebound_low_n_s_m=12000.0 * scale, rebound_knee_m_s=0.04,
                               rebound_high_n_s_m=4000.0 * scale, lag_s=lag_s)

    scales = [0.7 + 0.6 * k / max(n - 1, 1) for k in range(n)]
    return [[dig("a", s), dig("b", s, 0.002), dig("c", 1.4 - 0.5 * s), dig("d", 1.4 - 0.5 * s,
                                                                            0.002)]
            for s in scales], dig


def _third(n, dig):
    from ident.data.third import element_row
    from ident.models.bumpstops import BumpStop
    from ident.sim.loop_third import ThirdDamper, ThirdSpring

    hf, hr, rf = (element_row("heave_front", 1.0), element_row("heave_rear", 1.2),
                  element_row("roll_front", 0.8))
    spring = BumpStop(id="HS", gap_m=0.004, travel_m=[0.0, 0.004, 0.01],
                      force_n=[0.0, 4000.0, 20000.0])
    out = []
    for k in range(n):
        s = 0.6 + 0.8 * k / max(n - 1, 1)
        dampers = [ThirdDamper("heave_front", hf, dig("h", 1.5 * s, 0.003)),
                   ThirdDamper("heave_rear", hr, dig("h", 1.0 * s, 0.003)),
                   ThirdDamper("roll_front", rf, dig("r", 0.8))]
        springs = [ThirdSpring("heave_front", hf, (0.002, spring.travel_m, spring.force_n)),
                   ThirdSpring("heave_rear", hr, (0.003, spring.travel_m, spring.force_n))]
        out.append((dampers, springs))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setups", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1,
                    help="numba threads (default 1: the figure per setup on one core)")
    args = ap.parse_args(argv)
    os.environ.setdefault("NUMBA_NUM_THREADS", str(args.threads))
    import numpy as np

    from ident.data.drive import make_track_drive
    from ident.models.vehicle import build_full_car, example_gt_vehicle
    from ident.sim.closedloop import rig_response, simulate_batch_metrics
    from ident.sim.metrics import METRIC_CHANNELS, THIRD_METRIC_NAMES

    vehicle = example_gt_vehicle()
    car = build_full_car(vehicle)
    plant = car.loop_plant(np.full(4, 6000.0))
    drive = make_track_drive(duration_s=DRIVE_S, fs_hz=FS_HZ, seed=DRIVE_SEED,
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m, name="bench track")
    setups, dig = _setups(args.setups)
    third = _third(args.setups, dig)
    rig = rig_response(plant, drive, oversample=OVERSAMPLE)
    print(f"engine {engine_version()}; {load()}; numba threads "
          f"{os.environ.get('NUMBA_NUM_THREADS')}")
    print(f"GT car, track drive {DRIVE_S:g} s at {FS_HZ:g} Hz, oversample {OVERSAMPLE}, "
          f"{args.setups} setups")
    runs = (("plain", {}, False), ("third", {"third": third}, False),
            ("third, the plain metric set", {"third": third}, True))

    def call(kw, same_metrics):
        saved = {}
        if same_metrics:
            # the loop's own cost: the six motion metrics left out for this run, restored
            # after
            saved = {m: METRIC_CHANNELS.pop(m) for m in THIRD_METRIC_NAMES}
        try:
            c0, t0 = time.process_time(), time.perf_counter()
            out = simulate_batch_metrics(plant, drive, setups, oversample=OVERSAMPLE, rig=rig,
                                         **kw)
            return out, time.perf_counter() - t0, time.process_time() - c0
        finally:
            METRIC_CHANNELS.update(saved)

    warm = {}
    for label, kw, same_metrics in runs:
        warm[label] = call(kw, same_metrics)[1]
    # the runs alternate within each repetition (a load change hits all of them alike); CPU
    # time is the process's (all threads: the loop runs in a worker thread)
    wall = {label: [] for label, _, _ in runs}
    cpu = {label: [] for label, _, _ in runs}
    outs = {}
    for _ in range(args.repeat):
        for label, kw, same_metrics in runs:
            outs[label], w, c = call(kw, same_metrics)
            wall[label].append(w)
            cpu[label].append(c)
    ms = 1e3 / args.setups
    for label, _, _ in runs:
        out = outs[label]
        print(f"{label}: {ms * statistics.median(wall[label]):7.2f} ms per setup (median of "
              f"{args.repeat}, min {ms * min(wall[label]):.2f}), CPU "
              f"{ms * statistics.median(cpu[label]):.2f} (min {ms * min(cpu[label]):.2f}); "
              f"first call {warm[label]:.1f} s ({jit_source()}); Newton iterations max "
              f"{int(out.newton_iterations.max())}")
        if label == "third":
            share = out.metrics.values["heave_spring_contact_share_front"]
            print(f"        heave spring front in contact {100 * share.min():.1f}-"
                  f"{100 * share.max():.1f} % of the time; metrics "
                  f"{[m for m in THIRD_METRIC_NAMES if m in out.metrics.values]}")
    print(load())

    def ratio(d, label, f):
        return f(d[label]) / f(d["plain"])

    for label, what in (("third", "third elements / plain loop, time per setup"),
                        ("third, the plain metric set", "the loop alone (the same metrics)")):
        print(f"{what}: wall {ratio(wall, label, statistics.median):.2f}x median, "
              f"{ratio(wall, label, min):.2f}x best; CPU "
              f"{ratio(cpu, label, statistics.median):.2f}x median, "
              f"{ratio(cpu, label, min):.2f}x best (target <= 1.3x)")

if __name__ == "__main__":
    main()
