"""Benchmark of sweeps: ``planner.sweep.sweep_setups`` on 10^6 setups, one process against a
Dask LocalCluster.

Run::

    python benchmarks/bench_sweep.py [--n 1048576] [--drives 1] [--drive-s 120]
                                     [--top-share 0.01] [--workers CORES]
                                     [--ref-setups 20000] [--skip-single]

The problem: the known paper car (``build_full_car(example_vehicle())``), ``--drives``
track drives (``make_track_drive``, 100 Hz, ``--drive-s`` long, seeds 1, 2, ...), a crate
of 32 shocks (the built-in crate's 11, and each scaled by 0.85 and 1.15, the first 32;
counts unlimited) and its every-corner-free enumeration: 32^4 = 1,048,576 setups by
default. A smaller ``--n`` narrows the candidates of the last corners (per-corner lists)
to about ``n`` setups for a quick check. The default objective, the baseline B20 at every
corner, the best ``--top-share`` (1 %) simulated in the time domain (oversample 2).

Prints, one figure per line, each timing with the 1-minute load average at that moment:

1. a warm-up sweep of 2,000 setups in this process (numba cache load, not timed);
2. one process (``scheduler="none"``): screening wall time and setups per second
   (setup x drive), the time-domain stage for the best share (setups per second) and the
   peak resident memory of the process during the sweep (sampled with psutil);
3. a LocalCluster (``scheduler="local"``, ``--workers`` processes, one kernel thread
   each): cluster start, screening and time-domain times and rates, the whole call, the
   peak resident memory of this process and its workers together (sampled with psutil, the
   sum over the process tree: shared pages count once per process, so it overstates);
4. whether the two rankings and every number are identical (they must be);
5. the reference, in the same run: the path a user has without the sweep,
   ``planner.setups.enumerate_setups`` (``Setup`` objects) then
   ``planner.screen.screen_setups`` and ``planner.objective.score_setups`` on
   ``--ref-setups`` setups (20,000 by default; not all 10^6: 10^6 Setup objects and their
   metric table are gigabytes), its setups per second and the ratios sweep / reference;
6. ``target: ...`` lines: 10^6 screened setups in <= 120 s and <= 2 GB peak (cluster and
   one process), with the figures scaled to 10^6 when ``--n`` is smaller (said so).

This is a script, not part of the package: it prints and writes nothing (numba may update
its own cache; Dask writes its workers' scratch space under the temporary folder).
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
from planner.options import RunOptions

# benchmark the working tree this script lives in, installed or not
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

TARGET_SECONDS_PER_MILLION = 120.0
TARGET_PEAK_MIB = 2048.0
N_SHOCKS = 32
SCALES = (1.0, 0.85, 1.15)


class TreeRss:
    """The peak resident memory of this process and all its descendants, sampled."""

    def __init__(self, period_s=0.1):
        import psutil

        self._proc = psutil.Process()
        self._psutil = psutil
        self.period_s = period_s
        self.peak = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _sample(self):
        total = 0
        procs = [self._proc]
        try:
            procs += self._proc.children(recursive=True)
        except self._psutil.Error:
            pass
        for p in procs:
            try:
                total += p.memory_info().rss
            except self._psutil.Error:
                pass
        self.peak = max(self.peak, total)

    def _run(self):
        while not self._stop.is_set():
            self._sample()
            self._stop.wait(self.period_s)

    def __enter__(self):
        self._sample()
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self._sample()


def crate():
    """32 shocks: the built-in crate's 11 and each scaled by 0.85 and 1.15 (counts unlimited)."""
    from dataclasses import replace

    from ident.models.library import ShockLibrary, read_shock_library
    from planner.demo import DEMO_LIBRARY_PATH

    base = read_shock_library(DEMO_LIBRARY_PATH)
    models = []
    for scale in SCALES:
        for sid in base:
            m = base[sid] if scale == 1.0 else base[sid].scaled(scale, id=f"{sid}x{scale:g}")
            models.append(replace(m, count=None))
    return ShockLibrary.from_models(models[:N_SHOCKS])


def corner_lists(ids, n):
    """Per-corner candidate lists whose product is about `n` (the last corners narrowed)."""
    sizes, rest = [], float(n)
    for c in range(4):
        k = max(1, min(len(ids), round(rest ** (1.0 / (4 - c)))))
        sizes.append(k)
        rest /= k
    return dict(zip(("LF", "RF", "LR", "RR"), (list(ids)[:k] for k in sizes)))


def main():
    from _common import engine_version, load

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=N_SHOCKS**4, help="setups (default 32^4)")
    p.add_argument("--drives", type=int, default=1, help="track drives (cases)")
    p.add_argument("--drive-s", type=float, default=120.0, help="drive length [s]")
    p.add_argument("--top-share", type=float, default=0.01)
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--chunk-size", type=int, default=20_000)
    p.add_argument("--ref-setups", type=int, default=20_000)
    p.add_argument("--skip-single", action="store_true", help="only the cluster")
    args = p.parse_args()

    from ident.data.drive import make_track_drive
    from ident.models.vehicle import build_full_car, example_vehicle
    from planner.objective import score_setups
    from planner.screen import screen_setups
    from planner.setups import Setup, enumerate_setups
    from planner.sweep import sweep_setups

    print(f"engine: {engine_version()}")
    veh = example_vehicle()
    model = build_full_car(veh)
    drives = [make_track_drive(duration_s=args.drive_s, fs_hz=100.0, seed=1 + k,
                               wheelbase_m=veh.a_m + veh.b_m, track_width_m=veh.track_front_m,
                               name=f"track {1 + k}") for k in range(args.drives)]
    lib = crate()
    ids = list(lib)
    full = args.n >= N_SHOCKS**4
    constraints = {"symmetry": "none"} if full else \
        {"symmetry": "none", "shocks": corner_lists(ids, args.n)}
    baseline = Setup("baseline", dict.fromkeys(("LF", "RF", "LR", "RR"), "B20"))
    common = dict(constraints=constraints, baseline=baseline, top_share=args.top_share,
                  progress=False)
    print(f"problem: paper car, {len(drives)} drive(s) x {args.drive_s:g} s at 100 Hz, "
          f"crate of {len(lib)} shocks, every-corner-free setups, top share "
          f"{args.top_share:g}, chunk {args.chunk_size}")

    sweep_setups(model, drives[0], lib, constraints={"symmetry": "none", "shocks": ids[:7]},
                 run=RunOptions(scheduler="none"), top=5,
                 progress=False)  # warm-up: numba cache loads

    single = None
    if not args.skip_single:
        with TreeRss() as rss:
            t = time.perf_counter()
            single = sweep_setups(model, drives, lib,
                                  run=RunOptions(scheduler="none", chunk_size=args.chunk_size),
                                  **common)
            wall = time.perf_counter() - t
        report("one process", single, wall, rss.peak, load())

    with TreeRss() as rss:
        t = time.perf_counter()
        cluster = sweep_setups(model, drives, lib,
                               run=RunOptions(scheduler="local", n_workers=args.workers,
                                              chunk_size=args.chunk_size), **common)
        wall = time.perf_counter() - t
    report(f"LocalCluster ({args.workers} worker processes)", cluster, wall, rss.peak, load())
    peak_cluster = rss.peak

    if single is not None:
        same = single.table.equals(cluster.table) and all(
            single.cases[k].equals(cluster.cases[k]) for k in single.cases) and np.array_equal(
            single.screening_score, cluster.screening_score)
        print(f"identical results one process / cluster: {'yes' if same else 'NO'} "
              f"(best {cluster.best!r}, {len(cluster.table)} simulated)")
        print(f"ratio cluster / one process, screening: "
              f"{ratio(single, cluster, 'screen'):.2f}x; time domain: "
              f"{ratio(single, cluster, 'simulate'):.2f}x")

    # reference: Setup objects + screen_setups + score_setups, as rank_setups does
    n_ref = min(args.ref_setups, cluster.settings["n_screened"])
    t = time.perf_counter()
    ref_setups = enumerate_setups(lib, symmetry="none", max_setups=None,
                                  shocks={"LF": ids[:1], "RF": ids, "LR": ids, "RR": ids})
    ref_setups = (baseline,) + tuple(ref_setups)[:n_ref - 1]
    ref_rates = []
    for d in drives:
        ta = time.perf_counter()
        scr = screen_setups(model, d, ref_setups, lib)
        score_setups(scr.table, baseline="baseline")
        ref_rates.append(len(ref_setups) / (time.perf_counter() - ta))
    ref_total = time.perf_counter() - t
    ref_rate = len(ref_setups) * len(drives) / ref_total
    print(f"reference enumerate_setups + screen_setups + score_setups on {len(ref_setups)} "
          f"setups x {len(drives)} drive(s): {ref_total:.1f} s, {ref_rate:,.0f} setups/s "
          f"({load()})")
    for name, res in (("one process", single), ("cluster", cluster)):
        if res is not None:
            print(f"ratio sweep ({name}) / reference, screening setups/s: "
                  f"{res.settings['screen_setups_per_s'] / ref_rate:.2f}x")

    # targets (screening of 10^6 setups; the time domain of the best 1 % is reported apart)
    scale = 1e6 / cluster.settings["n_screened"]
    note = "" if full else f" (scaled from {cluster.settings['n_screened']:,} setups x " \
        f"{scale:.1f})"
    for name, res, peak in (("cluster", cluster, peak_cluster),
                            ("one process", single, None)):
        if res is None:
            continue
        sec = res.settings["seconds"]["screen"] * scale / len(drives)
        print(f"target: 10^6 screened setups (one drive) <= {TARGET_SECONDS_PER_MILLION:g} s, "
              f"{name}: {sec:.0f} s{note}: "
              f"{'PASS' if sec <= TARGET_SECONDS_PER_MILLION else 'FAIL'}")
    print(f"target: peak memory (cluster, all processes) <= {TARGET_PEAK_MIB:g} MiB: "
          f"{peak_cluster / 2**20:.0f} MiB"
          f"{'' if full else ' (at the smaller n: driver arrays grow 17 bytes a setup)'}: "
          f"{'PASS' if peak_cluster / 2**20 <= TARGET_PEAK_MIB else 'FAIL'}")


def ratio(single, cluster, stage):
    key = "screen_setups_per_s" if stage == "screen" else "simulate_setups_per_s"
    return cluster.settings[key] / single.settings[key]


def report(name, res, wall, peak, load_text):
    st = res.settings
    sec = st["seconds"]
    n_cases = len(st["cases"])
    print(f"{name}: whole call {wall:.1f} s (prepare + start {sec['prepare']:.1f} s) "
          f"({load_text})")
    print(f"{name}: screening {st['n_screened']:,} setups x {n_cases} drive(s) in "
          f"{sec['screen']:.1f} s: {st['screen_setups_per_s']:,.0f} setups/s")
    print(f"{name}: time domain, best {st['n_top']:,} + baseline x {n_cases} drive(s) in "
          f"{sec['simulate']:.1f} s: {st['simulate_setups_per_s']:,.1f} setups/s")
    print(f"{name}: peak resident memory {peak / 2**20:.0f} MiB")


if __name__ == "__main__":
    main()
