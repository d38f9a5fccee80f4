"""Benchmark of the curve optimizer: ``planner.optimize.optimize_curves`` on the paper car.

Run::

    python benchmarks/bench_optimize.py [--drive-s 120] [--knots quantiles | 0.025 0.05 0.1 0.25 0.5]

Prints, one figure per line, each timing with the machine's 1-minute load
average at that moment:

1. the problem: the known paper car (its 7-DOF model, the same loop an identified
   model goes through), a track drive of ``--drive-s`` seconds at 100 Hz, the
   built-in crate, the default objective and constraints, left-right symmetry (2
   curve groups), knots on the shock speeds' quantiles (default) or ``--knots`` (5 a
   side: 12 variables a group); the scan's share of the call;
2. one optimization, first call in this process (it compiles the loop's step and
   its adjoint when a C compiler is found): wall time, its build (compilation)
   and solve parts, IPOPT's status and iterations, the closed-loop evaluations
   (forward sweeps) and adjoint sweeps, the time of each;
3. the same optimization again (the compiled step is cached): wall time;
4. the gradient against a finite-difference reference in the same run, at the
   optimum: one adjoint sweep (the engine) against ``n_vars + 1`` forward sweeps
   (forward differences, the reference), their times, the ratio, and the largest
   difference between the two gradients relative to the gradient's norm;
5. ``target: one optimization < 60 s: PASS/FAIL`` (first call).

This is a script, not part of the package: it prints and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

# benchmark the working tree this script lives in, installed or not
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ident.data.drive import make_track_drive  # noqa: E402
from ident.models.library import read_shock_library  # noqa: E402
from ident.models.vehicle import build_full_car, example_vehicle  # noqa: E402
from planner import optimize as opt_mod  # noqa: E402
from planner.optimize.cache import jit_available  # noqa: E402
from planner.optimize.core import score_rows  # noqa: E402
from planner.optimize.loop import LoopModel  # noqa: E402
from planner.optimize.solve import Evaluator  # noqa: E402
from planner.demo import DEMO_LIBRARY_PATH  # noqa: E402
from planner.objective import default_objective  # noqa: E402
from planner.screen import metric_rows  # noqa: E402
from _common import engine_version, load  # noqa: E402
from planner.optimize import CurveOptions

#: The issue's target for one optimization (2 groups x about 10 knots, 120 s at 100 Hz) [s].
TARGET_S = 60.0


def gradient_check(model, drive, optimum):
    """Adjoint gradient of the score against forward differences at the optimum."""
    plant = model.loop_plant()
    space = optimum.space
    obj = optimum.objective
    names, L = metric_rows(plant)
    need = [m for m in obj.metrics if m in names]
    rows = (need, L[[names.index(m) for m in need]])
    base = optimum.metrics[drive.name].loc[optimum.baseline.name, need].to_numpy(float)
    C, _ = score_rows(obj, need, [base], np.ones(len(need)))
    jit = jit_available()
    loop = LoopModel(plant, drive, space, rows, 2, jit)
    scale = np.maximum(np.abs(optimum.x), 1.0)
    ev = Evaluator([loop], space.expansion(), scale, C)
    x = optimum.x / scale
    t0 = time.perf_counter()
    g_ad = ev.gradients(x, [0])[0]
    t_ad = time.perf_counter() - t0
    f0 = ev.value(x)[0]
    t0 = time.perf_counter()
    eps = 1e-6
    g_fd = np.empty_like(g_ad)
    for j in range(x.size):
        xt = x.copy()
        xt[j] += eps
        g_fd[j] = (ev.value(xt)[0] - f0) / eps
    t_fd = time.perf_counter() - t0
    err = float(np.max(np.abs(g_ad - g_fd)) / np.linalg.norm(g_ad))
    return t_ad, t_fd, err, x.size


def main(argv=None):
    """Run the benchmark and print its figures."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--drive-s", type=float, default=120.0, help="track drive length [s]")
    p.add_argument("--knots", nargs="+", default=["quantiles"],
                   help="'quantiles' (the default: on the shock speeds) or bump knot velocities "
                   "[m/s] (rebound mirrors them), e.g. 0.025 0.05 0.1 0.25 0.5 (the fixed knots)")
    args = p.parse_args(argv)
    knots = "quantiles" if args.knots == ["quantiles"] else [float(k) for k in args.knots]
    vehicle = example_vehicle()
    model = build_full_car(vehicle)
    library = read_shock_library(DEMO_LIBRARY_PATH)
    drive = make_track_drive(duration_s=args.drive_s, fs_hz=100.0, seed=7,
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m, name="bench track")
    print(f"shockplan {engine_version()}; casadi compiles the loop: "
          f"{jit_available()}")
    print(f"problem: paper car (known model), {args.drive_s:g} s track drive at 100 Hz, "
          f"{len(library)} crate shocks, objective '{default_objective().name}', left-right, "
          f"knots {'on the quantiles' if knots == 'quantiles' else knots}")
    times = []
    for call in ("first call", "second call"):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            opt = opt_mod.optimize_curves(model, drive, library, baseline="B20",
                                          curves=CurveOptions(knots_m_s=knots))
        wall = time.perf_counter() - t0
        times.append(wall)
        s = opt.solver
        print(f"optimize ({call}): {wall:.1f} s wall ({load()}); build {s['build_s']:.1f} s, "
              f"solve {s['solve_s']:.1f} s; IPOPT {s['status']}, {s['iterations']} iterations; "
              f"{s['n_eval']} closed-loop evaluations ({1e3 * s['eval_s'] / max(s['n_eval'], 1):.0f}"
              f" ms each), {s['n_grad']} adjoint sweeps "
              f"({1e3 * s['grad_s'] / max(s['n_grad'], 1):.0f} ms each); "
              f"{opt.space.n_vars} variables")
        scan = opt.settings.get("scan") or {}
        if scan:
            scan_s = scan["screen_s"] + scan["verify_s"]
            print(f"  scan: {scan['n_screened']} screened in {scan['screen_s']:.2f} s, "
                  f"{scan['n_verified']} verified in {scan['verify_s']:.2f} s: "
                  f"{100 * scan_s / wall:.0f} % of the call; best {scan['best']} "
                  f"{scan['score']:.4f} (linear {scan['linear_score']:.4f}); the optimum is "
                  f"the {s.get('source')}'s; knots {opt.settings['knots_m_s']} m/s (moved "
                  f"{100 * opt.settings['knot_update']['moved']:.0f} %, updated "
                  f"{opt.settings['knot_update']['updated']})")
    print(f"result: optimum {opt.score:.4f}, crate best {opt.crate_best} "
          f"{opt.table.loc[opt.crate_best, 'score']:.4f} (gain {100 * opt.gap:.2f} %)")
    t_ad, t_fd, err, n = gradient_check(model, drive, opt)
    print(f"gradient at the optimum: adjoint {1e3 * t_ad:.0f} ms, finite-difference reference "
          f"({n + 1} forward sweeps) {1e3 * t_fd:.0f} ms: ratio reference / adjoint "
          f"{t_fd / t_ad:.1f}x; largest difference {err:.2e} of the gradient's norm ({load()})")
    verdict = "PASS" if times[0] < TARGET_S else "FAIL"
    print(f"target: one optimization < {TARGET_S:g} s: {verdict} (first call {times[0]:.1f} s)")


if __name__ == "__main__":
    main()
