"""Benchmark of the command line: wall-clock times of ``shockplan`` commands from the shell.

Run::

    python benchmarks/bench_cli.py [--skip-demo]

Each command runs in a fresh process (``subprocess``, the ``shockplan`` next to this
Python), in a temporary folder, as a user would type it; the figure is the wall time of
the whole process (imports, JIT cache loads, computation, files). Prints, one per line,
with the 1-minute load average at that moment:

1. ``shockplan --help`` (import time of the command line);
2. ``shockplan rig simulate`` of the paper plan (5 runs x 800 s), CSV and Parquet;
3. ``shockplan identify`` of that session (CSV);
4. ``shockplan predict`` of 20 crate setups on a 120 s drive with that model (the first
   command that loads it: the loop plant is built from the model file);
5. ``shockplan demo``, first and second run in the same folder tree (``--overwrite``);
   the first as on a fresh machine: ``NUMBA_CACHE_DIR`` and ``SHOCKPLAN_CACHE_DIR`` point
   at empty folders, so numba compiles every kernel and the optimizer its loop; the
   second run finds both caches filled;
6. each against the issue's target, PASS/FAIL.

This is a script, not part of the package: it prints and writes nothing into the
repository.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import engine_version, load  # noqa: E402

#: Issue 13's targets [s], wall clock from the shell on the 2-core machine.
TARGETS = {"help": 1.0, "simulate csv": 10.0, "simulate parquet": 5.0, "identify": 20.0,
           "demo (first)": 90.0, "demo (second)": 60.0}


def shockplan():
    """The ``shockplan`` script of this interpreter's environment."""
    exe = Path(sys.executable).with_name("shockplan")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("shockplan")
    if found:
        return [found]
    return [sys.executable, "-m", "planner.cli"]


def timed(label, args, cwd, env=None):
    """Run one command, print and return its wall time [s]."""
    t0 = time.perf_counter()
    proc = subprocess.run(shockplan() + args, cwd=cwd, capture_output=True, text=True,
                          env=None if env is None else {**os.environ, **env})
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{label} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    target = TARGETS.get(label)
    verdict = "" if target is None else (f"; target <= {target:g} s: "
                                         f"{'PASS' if wall <= target else 'FAIL'}")
    print(f"{label}: {wall:.1f} s wall ({load()}){verdict}", flush=True)
    return wall


def main(argv=None):
    """Run the benchmark and print its figures."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--skip-demo", action="store_true", help="leave out the demo runs")
    args = p.parse_args(argv)
    print(f"shockplan {engine_version()}; {' '.join(shockplan())}")
    with tempfile.TemporaryDirectory() as work:
        w = Path(work)
        timed("help", ["--help"], w)
        timed("simulate csv", ["-q", "rig", "simulate", "--out", "session"], w)
        timed("simulate parquet", ["-q", "rig", "simulate", "--format", "parquet", "--out",
                                   "session_pq"], w)
        timed("identify", ["-q", "identify", "session", "--out", "model.npz"], w)
        # a drive and setups for predict, from the package's own writers
        code = ("from ident.data.drive import make_track_drive, write_drive; "
                "from ident.models.library import read_shock_library; "
                "from planner.demo import DEMO_LIBRARY_PATH; "
                "from planner.setups import enumerate_setups, write_setups; "
                "write_drive(make_track_drive(duration_s=120.0, fs_hz=100.0, seed=1), "
                "'drive.csv'); lib = read_shock_library(DEMO_LIBRARY_PATH); "
                "write_setups(enumerate_setups(lib)[:20], 'setups.csv'); "
                "print(DEMO_LIBRARY_PATH)")
        crate = subprocess.run([sys.executable, "-c", code], cwd=w, capture_output=True,
                               text=True, check=True).stdout.strip()
        timed("predict (first load of the model)",
              ["-q", "predict", "--model", "model.npz", "--drive", "drive.csv", "--shocks",
               crate, "--setups", "setups.csv", "--out", "pred.csv"], w)
        if not args.skip_demo:
            # the first demo as on a fresh machine: numba's and the optimizer's compiled code
            # caches start empty (their own folders here), the second run finds them filled
            fresh = {"NUMBA_CACHE_DIR": str(w / "numba-cache"),
                     "SHOCKPLAN_CACHE_DIR": str(w / "shockplan-cache")}
            timed("demo (first)", ["-q", "demo", "--out", "demo"], w, env=fresh)
            timed("demo (second)", ["-q", "demo", "--out", "demo", "--overwrite"], w, env=fresh)


if __name__ == "__main__":
    main()
