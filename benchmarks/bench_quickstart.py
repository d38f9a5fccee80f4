"""Benchmark of the quick start (issue 40, item 3): identification of the paper session and
the first ``shockplan demo`` from a fresh clone, each beside a reference install in the same
run.

Run::

    python benchmarks/bench_quickstart.py [--repeat N] [--ref-python PATH] [--no-demo]

Prints, one figure per line, each timing with the machine's 1-minute load average:

1. the speed probe (``/work/shared/tools/speedprobe.py``, or ``--probe``), run first: its
   total is the machine's speed at that moment (figures divided by it compare across days);
2. the session: the paper plan (5 runs x 800 s at 100 Hz) written once by ``shockplan rig
   simulate`` (Parquet) into a temporary folder (not timed);
3. identification as a library call, ``ident.identify.pipeline.identify_session`` on that
   session read once (``read_session``, not timed): the first call in a fresh process
   (numba's cache loads of the diagnosis' kernels included) and the median of `--repeat`
   further calls, for this checkout and for the reference (``--ref-python``, default
   ``/work/refvenv/bin/python``: the unchanged base), alternately, each in its own process;
   the ratio reference / this;
4. identification from the shell, ``shockplan identify SESSION --out model.npz``: wall time
   of a fresh process (start-up, reading, identification, writing), this and the reference,
   median of `--repeat`;
5. the demo (unless ``--no-demo``): ``shockplan demo`` with ``NUMBA_CACHE_DIR`` and
   ``SHOCKPLAN_CACHE_DIR`` pointing at empty folders (a fresh clone: every numba kernel and
   the optimizer's C code compiled), then again on the same caches (warm), this and the
   reference; wall time and the CPU time of the process tree;
6. the targets: identify (library, median) < 8 s and the fresh demo < 60 s, each as
   measured and scaled to a speed probe of 0.5 s (figure x 0.5 / probe, when the probe is
   slower).

This is a script, not part of the package: it writes only into a temporary folder.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Issue 40's targets [s]: identification of the paper session, and the first demo.
TARGET_IDENTIFY_S = 8.0
TARGET_DEMO_S = 60.0
#: The speed probe at which the targets hold [s] (slower machines: figures scaled by it).
TARGET_PROBE_S = 0.5

_CHILD = r"""
import sys, time, warnings, statistics
warnings.simplefilter("ignore")
from ident.data.session import read_session
from ident.identify.pipeline import identify_session
session = read_session(sys.argv[1])
n = int(sys.argv[2])
times = []
for k in range(n + 1):
    t = time.perf_counter()
    identify_session(session)
    times.append(time.perf_counter() - t)
print("FIRST", times[0])
print("MEDIAN", statistics.median(times[1:]) if n else times[0])
"""


def _load():
    return f"1-min load {os.getloadavg()[0]:.2f}"


def _children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(cmd, *, env=None, cwd=None):
    """Run a command; (wall s, CPU s of the process tree, stdout)."""
    cpu0, t0 = _children_cpu(), time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    if proc.returncode:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed:\n{proc.stderr[-3000:]}")
    return wall, cpu, proc.stdout


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env.update({k: str(v) for k, v in extra.items()})
    return env


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--ref-python", default="/work/refvenv/bin/python")
    parser.add_argument("--probe", default="/work/shared/tools/speedprobe.py")
    parser.add_argument("--no-demo", action="store_true")
    args = parser.parse_args(argv)
    installs = {"this": Path(sys.executable)}
    if args.ref_python and Path(args.ref_python).exists():
        installs["reference"] = Path(args.ref_python)
    else:
        print(f"no reference install at {args.ref_python}: this checkout alone")

    probe_s = None
    if Path(args.probe).exists():
        _, _, out = _run([sys.executable, args.probe])
        print("speed probe:", " | ".join(line.strip() for line in out.splitlines() if line.strip()))
        m = re.search(r"total[^0-9]*([0-9.]+)", out, re.IGNORECASE)
        probe_s = float(m.group(1)) if m else None
    print(f"speed probe total: {probe_s} s ({_load()})")

    with tempfile.TemporaryDirectory(prefix="bench_quickstart_") as tmp:
        tmp = Path(tmp)
        session = tmp / "session"
        shockplan = {k: str(p.parent / "shockplan") for k, p in installs.items()}
        _run([shockplan["this"], "rig", "simulate", "--out", str(session), "--format",
              "parquet", "-q"], env=_env())
        print(f"session: paper plan (5 x 800 s, 100 Hz) written to {session}")

        results = {}
        script = tmp / "child.py"
        script.write_text(_CHILD)
        for name, py in installs.items():  # each in its own fresh process, one after the other
            _, _, out = _run([str(py), str(script), str(session), str(args.repeat)], env=_env())
            first = float(re.search(r"FIRST (\S+)", out).group(1))
            med = float(re.search(r"MEDIAN (\S+)", out).group(1))
            results[("lib", name)] = med
            print(f"identify_session ({name}): first call {first:.2f} s, median of "
                  f"{args.repeat} more {med:.2f} s ({_load()})")
        if "reference" in installs:
            print(f"identify_session: reference / this = "
                  f"{results[('lib', 'reference')] / results[('lib', 'this')]:.2f}")

        for name in installs:
            walls = []
            for k in range(max(args.repeat, 1)):
                wall, _, _ = _run([shockplan[name], "identify", str(session), "--out",
                                   str(tmp / f"model_{name}_{k}.npz"), "-q"], env=_env())
                walls.append(wall)
            results[("cli", name)] = statistics.median(walls)
            print(f"shockplan identify ({name}): median {results[('cli', name)]:.2f} s of "
                  f"{len(walls)} ({', '.join(f'{w:.2f}' for w in walls)}) ({_load()})")

        if not args.no_demo:
            for name in installs:
                cache = tmp / f"cache_{name}"
                env = _env(NUMBA_CACHE_DIR=cache / "numba", SHOCKPLAN_CACHE_DIR=cache / "jit")
                demo = tmp / f"demo_{name}"
                for label in ("fresh", "warm"):
                    wall, cpu, _ = _run([shockplan[name], "demo", "--out", str(demo),
                                         "--overwrite", "-q"], env=env)
                    results[(label, name)] = wall
                    print(f"shockplan demo ({name}, {label} caches): {wall:.1f} s wall, "
                          f"{cpu:.1f} s CPU ({_load()})")

    scale = (TARGET_PROBE_S / probe_s) if probe_s and probe_s > TARGET_PROBE_S else 1.0
    ident = results[("lib", "this")]
    print(f"target: identify_session < {TARGET_IDENTIFY_S:g} s: {ident:.2f} s measured, "
          f"{ident * scale:.2f} s at probe {TARGET_PROBE_S} s: "
          f"{'PASS' if ident * scale < TARGET_IDENTIFY_S else 'FAIL'}")
    if ("fresh", "this") in results:
        fresh = results[("fresh", "this")]
        print(f"target: fresh demo < {TARGET_DEMO_S:g} s: {fresh:.1f} s measured, "
              f"{fresh * scale:.1f} s at probe {TARGET_PROBE_S} s: "
              f"{'PASS' if fresh * scale < TARGET_DEMO_S else 'FAIL'}")


if __name__ == "__main__":
    main()
