"""Benchmark of the screening with third elements (issue 38) against the plain screening.

Usage::

    python benchmarks/bench_third_screen.py [--n N] [--repeat R] [--small S]

The known paper car's loop plant (``build_full_car(example_vehicle())``), a 120 s track
drive at 100 Hz (seed 1), the built-in crate (``planner/examples/library.toml``); the first
`--n` (default 14,559: all) every-corner-free setups of the crate. The same setups are
screened twice with ``planner.screen.screen_setups``: plainly, and with third elements (a
heave element front and rear, motion ratio 1.2, and a front roll damper, whose dampers are
crate shocks cycled over the setups; a gapped heave spring at the front in every other
setup). After a warm-up (compilation) of each, the median of `--repeat` (default 3) calls:
setups/s, microseconds per setup and the ratio third / plain, for the large batch and for
`--small` (default 119) setups (the plain screening's scalar kernel); then the target line.

Target (issue 38): screening with third elements at most 1.5x the plain screening's time
per setup.
"""

from __future__ import annotations

import argparse
import gc
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from ident.data.drive import make_track_drive  # noqa: E402
from ident.data.third import element_row  # noqa: E402
from ident.models.library import read_shock_library  # noqa: E402
from ident.models.vehicle import build_full_car, example_vehicle  # noqa: E402
from ident.sim.virtual_rig import loop_damping  # noqa: E402
from planner.screen import ThirdChoices, screen_setups  # noqa: E402
from planner.setups import enumerate_setups  # noqa: E402
from _common import engine_version, load  # noqa: E402

LIBRARY_PATH = ROOT / "planner" / "examples" / "library.toml"
DRIVE_S = 120.0
FS_HZ = 100.0
DRIVE_SEED = 1
ELEMENTS = ("heave_front", "heave_rear", "roll_front")
MOTION_RATIO = 1.2
#: A heave spring touching 3 mm from rest, progressive (element travel [m], force [N]).
HEAVE_SPRING = (0.003, np.array([0.0, 0.004, 0.01]), np.array([0.0, 2000.0, 9000.0]))
#: The issue's target: third / plain time per setup.
TARGET_RATIO = 1.5


def _time(fn, repeat):
    """Median wall time, the wall times and the median CPU time (all threads: on a loaded
    machine the wall time of a parallel kernel depends on what else runs)."""
    times, cpu = [], []
    for _ in range(repeat):
        gc.collect()
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(times), times, statistics.median(cpu)


def _choices(setups, library):
    ids = list(library.ids)
    models = [library[i] for i in ids]
    rows = np.array([element_row(e, MOTION_RATIO) for e in ELEMENTS])
    dampers, springs = [], []
    for i in range(len(setups)):
        dampers.append((models[i % len(models)], models[(i // 3) % len(models)],
                        models[(i // 7) % len(models)] if i % 2 else None))
        springs.append((HEAVE_SPRING if i % 2 == 0 else None, None, None))
    return ThirdChoices(ELEMENTS, rows, dampers=tuple(dampers), springs=tuple(springs))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=None, help="setups in the large batch (all)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--small", type=int, default=119)
    args = ap.parse_args(argv)
    print(f"engine version: {engine_version()}; {load()}; numba threads "
          f"{os.environ.get('NUMBA_NUM_THREADS', 'default')}")
    vehicle = example_vehicle()
    library = read_shock_library(LIBRARY_PATH)
    plant = build_full_car(vehicle).loop_plant(loop_damping([library["B20"]] * 4))
    drive = make_track_drive(duration_s=DRIVE_S, fs_hz=FS_HZ, seed=DRIVE_SEED,
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m)
    free = list(enumerate_setups(library, symmetry="none", max_setups=None))
    if args.n:
        free = free[:args.n]
    ratios, cpu_ratios = {}, {}
    for label, setups in (("large batch", free), ("small batch", free[:args.small])):
        third = _choices(setups, library)
        t0 = time.perf_counter()  # warm-up: the kernels this batch size runs
        screen_setups(plant, drive, setups, library)
        screen_setups(plant, drive, setups, library, third=third)
        warm = time.perf_counter() - t0
        plain, pt, pc = _time(lambda: screen_setups(plant, drive, setups, library),
                              args.repeat)
        with3, tt, tc = _time(lambda: screen_setups(plant, drive, setups, library,
                                                    third=third), args.repeat)
        n = len(setups)
        ratios[label] = with3 / plain
        cpu_ratios[label] = tc / pc
        print(f"[{label}] warm-up (compile or cache load) {warm:.1f} s; {load()}")
        print(f"[{label}] plain screening: {n / plain:,.0f} setups/s, "
              f"{1e6 * plain / n:.1f} us per setup ({n} setups, median of "
              f"{[round(t, 3) for t in pt]} s)")
        print(f"[{label}] screening with third elements ({', '.join(ELEMENTS)}, heave spring "
              f"front in half): {n / with3:,.0f} setups/s, {1e6 * with3 / n:.1f} us per setup "
              f"(median of {[round(t, 3) for t in tt]} s)")
        print(f"[{label}] ratio third / plain time per setup: {with3 / plain:.2f}x wall, "
              f"{tc / pc:.2f}x CPU (all threads; {1e6 * pc / n:.1f} and {1e6 * tc / n:.1f} us "
              "per setup)")
    worst, worst_cpu = max(ratios.values()), max(cpu_ratios.values())
    print(f"target: third / plain <= {TARGET_RATIO}x: "
          f"{'PASS' if worst <= TARGET_RATIO else 'FAIL'} (worst {worst:.2f}x wall, "
          f"{worst_cpu:.2f}x CPU; {load()})")


if __name__ == "__main__":
    main()
