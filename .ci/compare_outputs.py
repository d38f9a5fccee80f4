#!/usr/bin/env python3
"""Run every shockplan workflow with one install, and compare two such runs file by file.

Written for the package restructure (``ident/``, ``planner/``): every output of every
command must stay byte-identical. Run the workflows once with the reference install and
once with the changed one, then compare::

    python .ci/compare_outputs.py run --shockplan /work/refvenv/bin/shockplan --out /work/cmp/ref
    python .ci/compare_outputs.py run --shockplan .venv/bin/shockplan --out /work/cmp/new
    python .ci/compare_outputs.py compare /work/cmp/ref /work/cmp/new   # exit 1 on a difference

Only the standard library, numpy, pandas and openpyxl are used, so the script runs under
either venv's python. It never imports shockplan: every workflow is a subprocess of the
given executable, run with the output folder as its working directory and relative
paths, with ``SHOCKPLAN_CACHE_DIR`` and ``NUMBA_CACHE_DIR`` inside the output folder
(``_cache/``, not compared): the two runs share no compiled optimizer steps or numba
kernels, and nothing is written into the installs.

``run``
    The demo, then the README's workflows on the demo's outputs (sections Commands, From a
    real rig, Optimize, Rig day, What if), each cut to a modest size (short drives, few
    IPOPT iterations, a small sweep in one process): about 5 minutes on a 2-core machine
    (numba compiles its kernels afresh in every run: about a minute of that).
    The inputs that are not the demo's (the crate, the paper car's TOML) are copied from
    the reference checkout (``--inputs-from``, default ``/work/ref``) into ``inputs/``, so
    both runs read the same bytes whatever the package layout; the other inputs (drives
    cut from the demo's track drive, a setups CSV, constraint, perturbation and
    channel-map TOMLs, RPC III rig files built from the demo session's runs) are written
    by this script. Each command's stdout, stderr and exit status go to ``_logs/``; the
    commands, exit statuses and input hashes to ``_run/manifest.json``; wall times to
    ``_run/timings.json`` (not compared). A command that fails does not stop the run (its
    exit status is compared like everything else).

``compare REF NEW``
    Every file of both folders (``_cache/`` excluded), by kind:

    - ``.csv .toml .txt .json .md .tsv``: byte for byte, after the run's folder path is
      replaced by a placeholder;
    - ``.npz``: the same keys, and per key the same dtype and shape, ``np.array_equal``
      (``equal_nan``) and the same bytes (so -0.0/0.0 and NaN payloads count too); string
      arrays with the folder path normalized (the zip container itself holds write times,
      so its bytes are not compared);
    - ``.xlsx``: the same sheets, and in every sheet the same cell values (openpyxl,
      ``values_only``; the workbook's own created/modified times are not values);
    - RPC III files (``.drv .rsp .tim .rpc``): every header parameter but ``DATE``, and the
      data bytes;
    - ``.mat``: every byte after the 116-byte text header, and that header with its
      ``Created on:`` date masked;
    - ``.mf4``: every byte but the MDF4 header's start time and the file history's time
      (asammdf stamps the write time there);
    - ``.png .pdf .svg``: present or absent only (not compared);
    - ``_logs/*``: stdout and stderr after the folder path is normalized and timing
      figures are masked; a difference there is a warning, not a failure;
    - ``_run/manifest.json``: the same commands and exit statuses (a changed exit status
      fails), the same input hashes;
    - anything else: byte for byte.

    A file present on one side only fails. Exit status 1 on any failure, else 0.

Genuinely non-deterministic content is masked where it occurs, and only there (found by
running the reference install twice and comparing the two folders, and by looking for the
day's date in the outputs: two runs on one day agree on it):

- ``sweep/sweep.toml``: ``seconds`` (the ``[seconds]`` table: wall times of the sweep's
  phases) and ``screen_setups_per_s`` / ``simulate_setups_per_s`` (throughputs derived from
  them) are wall-clock measurements written by ``shockplan sweep``; their lines are masked,
  everything else in the file is compared byte for byte.
- RPC III ``DATE`` header parameter: rpc3-file stamps the write time (to the second).
- ``.mat`` header ``Created on:``: scipy's savemat stamps the write time.
- ``test_plan.xlsx``, sheet "run sheet": the value right of the ``date`` label is the day
  the plan was written (``planner.testplan.write_plan`` uses today's date when the plan
  has none), masked when it is an ISO date (two runs on different days differ there).
- the stdout of several commands quotes wall times (``in 7.1 s``, ``... setup-cases/s``):
  masked in the log comparison, which only warns anyway (the mask takes every "<number> s",
  so a drive's "800 s" is masked too; the files hold those figures and are compared).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

PLACEHOLDER = "<RUN_DIR>"
EXCLUDED_TOP = {"_cache"}  # SHOCKPLAN_CACHE_DIR and NUMBA_CACHE_DIR: compiled code
TEXT_SUFFIXES = {".csv", ".toml", ".txt", ".json", ".md", ".tsv"}
IMAGE_SUFFIXES = {".png", ".pdf", ".svg"}
RPC_SUFFIXES = {".drv", ".rsp", ".tim", ".rpc", ".rpc3"}
COMMAND_TIMEOUT_S = 1200

# the inputs copied from the reference checkout: name -> candidate paths in the checkout
REF_INPUTS = {
    "crate.toml": ("planner/data/library.toml", "planner/examples/library.toml"),
    "car.toml": ("ident/data/paper_car.toml", "ident/examples/paper_car.toml"),
}

# ---------------------------------------------------------------------------------------
# genuinely non-deterministic content, masked (see the module docstring)
# ---------------------------------------------------------------------------------------

#: per file (relative path, posix) -> (TOML table or None for the top level, key regex):
#: the values of these keys are masked before the byte comparison
VOLATILE_TOML_KEYS = {
    "sweep/sweep.toml": [
        (None, r"screen_setups_per_s|simulate_setups_per_s"),  # throughputs (wall clock)
        ("seconds", r".+"),  # [seconds]: wall times of the sweep's phases
    ],
}

#: per xlsx file name -> (sheet, row label): the first value right of the label is a date
#: stamped at writing time (masked when it is an ISO date)
VOLATILE_XLSX_DATES = {
    # planner.testplan.write_plan: the run sheet's "date" is the plan's, else today's
    "test_plan.xlsx": [("run sheet", "date")],
}
_ISO_DATE = re.compile(r"\d{4}-\d{2}-\d{2}")

_TIMING_PATTERNS = [
    re.compile(r"\b\d[\d,]*(?:\.\d+)?(?:e[-+]?\d+)?\s*(?:s|sec|secs|seconds|ms)\b(?!/)", re.IGNORECASE),
    re.compile(r"\b\d[\d,]*(?:\.\d+)?\s*[\w-]*/s\b"),  # throughputs: 16,241 setup-cases/s
    re.compile(r"\belapsed\b.*", re.IGNORECASE),
]


def _mask_timings(line):
    for pat in _TIMING_PATTERNS:
        line = pat.sub("<t>", line)
    return line


# ---------------------------------------------------------------------------------------
# run
# ---------------------------------------------------------------------------------------

class Runner:
    def __init__(self, exe, out):
        self.exe = str(exe)
        self.out = Path(out)
        self.logs = self.out / "_logs"
        self.meta = self.out / "_run"
        self.steps = []
        self.timings = {}
        self.prep_errors = []
        self.env = dict(os.environ)
        self.env["SHOCKPLAN_CACHE_DIR"] = str(self.out / "_cache" / "shockplan")
        # numba's on-disk cache would otherwise go next to the installed sources (into the
        # venv, or the work tree of an editable install): a run compiles its own kernels,
        # and a cache left by other code cannot stand in for a changed kernel (numba
        # checks only the kernel's own file, not the modules it calls into)
        self.env["NUMBA_CACHE_DIR"] = str(self.out / "_cache" / "numba")
        self.env.setdefault("MPLBACKEND", "Agg")
        self.env["PYTHONUNBUFFERED"] = "1"

    def cmd(self, name, *args, section):
        """Run ``shockplan -q ARGS`` in the output folder; record its logs and exit status."""
        n = len(self.steps) + 1
        tag = f"{n:02d}-{name}"
        argv = ["-q", *[str(a) for a in args]]
        t0 = time.monotonic()
        try:
            proc = subprocess.run([self.exe, *argv], cwd=self.out, env=self.env,
                                  capture_output=True, timeout=COMMAND_TIMEOUT_S,
                                  check=False)
            rc, so, se = proc.returncode, proc.stdout, proc.stderr
        except subprocess.TimeoutExpired as exc:
            rc, so, se = "timeout", exc.stdout or b"", (exc.stderr or b"") + b"\n[timeout]\n"
        dt = time.monotonic() - t0
        (self.logs / f"{tag}.stdout").write_bytes(so)
        (self.logs / f"{tag}.stderr").write_bytes(se)
        (self.logs / f"{tag}.rc").write_text(f"{rc}\n")
        self.steps.append({"tag": tag, "name": name, "section": section,
                           "argv": ["shockplan", *argv], "rc": rc})
        self.timings[tag] = round(dt, 2)
        print(f"[{tag}] rc={rc} {dt:6.1f} s  shockplan {' '.join(argv)}", flush=True)
        return rc

    def prep(self, what, func, *args):
        """Write an input; an error is recorded (and the commands needing it fail)."""
        try:
            func(*args)
        except Exception as exc:  # noqa: BLE001 - recorded, the run goes on
            msg = f"{what}: {type(exc).__name__}: {exc}"
            self.prep_errors.append(msg)
            print(f"[prep] FAILED {msg}", flush=True)


def _sha256(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _copy_ref_inputs(src_root, dest):
    src_root = Path(src_root)
    copied = {}
    for name, candidates in REF_INPUTS.items():
        for rel in candidates:
            p = src_root / rel
            if p.is_file():
                shutil.copyfile(p, dest / name)
                copied[name] = rel
                break
        else:
            raise FileNotFoundError(f"{name}: none of {candidates} in {src_root}")
    return copied


def _cut_drive(src, dest, first, count):
    """Rows [first, first + count) of a drive CSV, header (and leading '#' lines: the unit
    marker '# units: ...', issue 23) kept, bytes as they are."""
    with open(src, "rb") as fh:
        lines = fh.readlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith(b"#")) + 1
    Path(dest).write_bytes(b"".join([*lines[:head], *lines[head + first: head + first + count]]))


SETUPS_CSV = """setup,LF,RF,LR,RR
baseline,B20,B20,B20,B20
firm,L28,L28,L28,L28
digressive-front,DM,DM,B20,B20
table-rear,B20,B20,TD,TD
mixed,DS,DF,RB,BO
"""

CONSTRAINTS_TOML = """format = "curve-constraints/1"
units = "imperial"

[bump]
low_speed_slope = [5.0, 60.0]

[rebound]
low_speed_slope = [5.0, 80.0]

[shape]
digressive = true
rebound_bump_ratio = { velocity = 2.0, min = 1.0, max = 2.5 }
max_force = 1500.0
"""

WHATIF_TOML = """format = "shockplan-whatif/1"
design = "one-at-a-time"
units = "imperial"

[[factor]]
name = "shock tolerance"
kind = "shock_scale"
corners = ["LF", "RF", "LR", "RR"]
levels = [0.95, 1.05]

[[factor]]
name = "shock lag"
kind = "shock_lag"
shocks = ["TD", "DM"]
levels = [0.002]

[[factor]]
name = "rear springs"
kind = "spring_rate"
corners = ["LR", "RR"]
change = "scale"
levels = [0.9, 1.1]
baseline_rate = 588.0

[[factor]]
name = "bumpier track"
kind = "drive_scale"
channels = "wheel"
levels = [1.2]

[[factor]]
name = "first half"
kind = "drive_window"
levels = [[0.0, 15.0]]
"""

WHATIF_MC_TOML = """format = "shockplan-whatif/1"
design = "monte-carlo"
n_draws = 8
seed = 3

[[factor]]
name = "shock tolerance"
kind = "shock_scale"
corners = ["LF", "RF", "LR", "RR"]
independent = true
distribution = { kind = "uniform", low = 0.95, high = 1.05 }

[[factor]]
name = "front tire"
kind = "vehicle"
parameter = "tire_stiffness"
distribution = { kind = "normal", mean = 1.0, sd = 0.03 }
"""

# the rig's channel names, units, signs (the README's channel map, filled in): canonical
# channel -> (file channel, unit, sign, scale, offset); the RPC III files written below
# hold the demo session's runs in these units (x_raw = x_si / (sign factor scale) + offset)
_CORNERS = ("LF", "RF", "LR", "RR")
RIG_MAP = {
    "aero_heave": ("Aero Heave", "kN", 1, 1.0, 0.0),
    "aero_roll": ("Aero Roll", "lbf*in", 1, 1.0, 0.0),
    "aero_pitch": ("Aero Pitch", "N*m", 1, 1.0, 0.0),
    **{f"wheelloader_{c}": (f"WL_{c}_Disp", "mm", 1, 1.0, 0.0) for c in _CORNERS},
    **{f"shock_velocity_{c}": (f"DmpVel {c}", "in/s", -1, 1.0, 0.0) for c in _CORNERS},
    **{f"shock_force_{c}": (f"DmpF {c}", "lbf", -1, 1.0, 0.0) for c in _CORNERS},
    **{f"shock_travel_{c}": (f"DmpPos {c}", "mm", 1, 1.0, 0.0) for c in _CORNERS},
    **{f"tire_force_{c}": (f"TireF {c}", "kN", 1, 0.5, 3.0) for c in _CORNERS},
    **{f"ride_height_{c}": (f"RH {c}", "mm", 1, 1.0, 0.0) for c in _CORNERS},
    **{f"chassis_accel_{c}": (f"ChAcc {c}", "g", 1, 1.0, 0.0) for c in _CORNERS},
}
# imperial (the demo session's units) -> the map's unit
_FROM_IMPERIAL = {
    "mm": 25.4, "in/s": 1.0, "lbf": 1.0, "lbf*in": 1.0,
    "kN": 4.4482216152605e-3,             # lbf -> kN
    "N*m": 0.1129848290276167,            # lbf*in -> N*m
    "g": 0.0254 / 9.80665,                # in/s^2 -> g
}
RPC_SAMPLES = 4096  # 40.96 s at 100 Hz: four full 1024-point groups


def _map_toml(channels, name):
    lines = ['format = "channel-map/1"', f'name = "{name}"', ""]
    for canon, (src, unit, sign, scale, offset) in channels.items():
        lines += [f"[channels.{canon}]", f'source = "{src}"', f'units = "{unit}"',
                  f"sign = {sign}"]
        if scale != 1.0:
            lines.append(f"scale = {scale!r}")
        if offset != 0.0:
            lines.append(f"offset = {offset!r}")
        lines.append("")
    return "\n".join(lines)


def _rpc_number(x):
    s = repr(float(x))
    if "." not in s and "e" in s:
        m, _, e = s.partition("e")
        s = f"{m}.0e{e}"
    return s


def write_rpc3(path, channels, fs_hz, group=1024, full_scale=32752):
    """A minimal RPC III writer (binary, SHORT_INTEGER, one partition), numpy only.

    `channels`: name -> (values in the file's units, unit string). No DATE parameter: the
    file's bytes depend on its data only.
    """
    names = list(channels)
    data = [np.asarray(channels[n][0], dtype=np.float64) for n in names]
    n = data[0].size
    frames = -(-n // group)
    params = [("FILE_TYPE", "TIME_HISTORY"), ("TIME_TYPE", "RESPONSE"),
              ("DELTA_T", _rpc_number(1.0 / fs_hz)), ("CHANNELS", str(len(names))),
              ("PTS_PER_FRAME", str(group)), ("PTS_PER_GROUP", str(group)),
              ("FRAMES", str(frames)), ("SAMPLES", str(n)), ("DATA_TYPE", "SHORT_INTEGER"),
              ("INT_FULL_SCALE", str(full_scale)), ("BYPASS_FILTER", "0"),
              ("HALF_FRAMES", "0"), ("REPEATS", "1"), ("PARTITIONS", "1"),
              ("PART.CHAN_1", "1"), ("PART.NCHAN_1", str(len(names)))]
    scales = []
    for i, (name, x) in enumerate(zip(names, data), start=1):
        peak = float(np.max(np.abs(x)))
        scale = peak / full_scale if peak > 0 else 1.0
        scales.append(scale)
        params += [(f"DESC.CHAN_{i}", name), (f"UNITS.CHAN_{i}", channels[name][1]),
                   (f"SCALE.CHAN_{i}", _rpc_number(scale)),
                   (f"LOWER_LIMIT.CHAN_{i}", _rpc_number(x.min())),
                   (f"UPPER_LIMIT.CHAN_{i}", _rpc_number(x.max())),
                   (f"MAP.CHAN_{i}", str(i))]
    n_params = len(params) + 3
    blocks = -(-n_params // 4)
    records = [("FORMAT", "BINARY"), ("NUM_HEADER_BLOCKS", str(blocks)),
               ("NUM_PARAMS", str(n_params)), *params]
    records += [("", "")] * (blocks * 4 - len(records))
    head = b"".join(k.encode("latin-1").ljust(32, b"\0") + v.encode("latin-1").ljust(96, b"\0")
                    for k, v in records)
    body = []
    for g in range(frames):
        for x, scale in zip(data, scales):
            chunk = x[g * group:(g + 1) * group]
            if chunk.size < group:
                chunk = np.concatenate([chunk, np.full(group - chunk.size, x[-1])])
            q = np.clip(np.rint(chunk / scale), -full_scale, full_scale).astype("<i2")
            body.append(q.tobytes())
    Path(path).write_bytes(head + b"".join(body))


def _rpc_from_run(run_file, dest, samples=RPC_SAMPLES):
    """An RPC III response file of a demo session's run (CSV or Parquet, imperial units)."""
    import pandas as pd

    run_file = Path(run_file)
    if not run_file.exists():  # the demo writes its runs as Parquet (the spec allows both)
        run_file = run_file.with_suffix(".parquet")
    if run_file.suffix == ".parquet":
        df = pd.read_parquet(run_file).iloc[:samples]
    else:
        df = pd.read_csv(run_file, nrows=samples, comment="#")  # '# units: ...' first
    fs_hz = 1.0 / float(df["time"].iloc[1] - df["time"].iloc[0])
    fs_hz = round(fs_hz, 6)
    chans = {}
    for canon, (src, unit, sign, scale, offset) in RIG_MAP.items():
        x = df[canon].to_numpy(dtype=np.float64) * _FROM_IMPERIAL[unit]
        chans[src] = (x / (sign * scale) + offset, unit)
    write_rpc3(dest, chans, fs_hz)


def _write(path, text):
    Path(path).write_text(text, encoding="utf-8")


def run_all(exe, out, inputs_from):
    r = Runner(exe, out)
    for d in (r.logs, r.meta, r.out / "_cache" / "shockplan", r.out / "_cache" / "numba"):
        d.mkdir(parents=True, exist_ok=True)
    inputs = r.out / "inputs"
    inputs.mkdir()
    t_start = time.monotonic()

    copied = {}
    r.prep("inputs from the reference checkout",
           lambda: copied.update(_copy_ref_inputs(inputs_from, inputs)))
    for name, text in (("setups.csv", SETUPS_CSV), ("constraints.toml", CONSTRAINTS_TOML),
                       ("whatif.toml", WHATIF_TOML), ("whatif_mc.toml", WHATIF_MC_TOML),
                       ("rig_map.toml", _map_toml(RIG_MAP, "8-post, MTS RPC export")),
                       # a map naming a channel the rig files lack: import must refuse it
                       ("bad_map.toml", _map_toml(
                           {**RIG_MAP, "wheel_accel_LF": ("WhAcc LF", "g", 1, 1.0, 0.0)},
                           "8-post, with a channel the files lack"))):
        _write(inputs / name, text)

    # -- Quick start / Commands: the demo --------------------------------------------------
    r.cmd("demo", "demo", "--out", "demo", section="Quick start")
    r.prep("short drives", lambda: (
        _cut_drive(r.out / "demo/track_drive.csv", inputs / "track30.csv", 0, 3000),
        _cut_drive(r.out / "demo/track_drive.csv", inputs / "track30b.csv", 3000, 3000)))

    # -- Commands ----------------------------------------------------------------------------
    sec = "Commands"
    r.cmd("vehicle-modes", "vehicle", "modes", section=sec)
    r.cmd("vehicle-modes-car", "vehicle", "modes", "--vehicle", "inputs/car.toml",
          "--damping", "20", "--units", "imperial", section=sec)
    r.cmd("identify", "identify", "demo/session", "--out", "identify/model.npz", section=sec)
    r.cmd("predict", "predict", "--model", "demo/model.npz", "--drive", "demo/track_drive.csv",
          "--shocks", "inputs/crate.toml", "--setups", "inputs/setups.csv", "--units",
          "imperial", "--out", "predict/predictions.csv", section=sec)
    r.cmd("predict-paper", "predict", "--model", "paper", "--drive", "inputs/track30.csv",
          "--shocks", "inputs/crate.toml", "--setups", "inputs/setups.csv", "--units",
          "imperial", "--out", "predict/predictions_paper.csv", section=sec)
    r.cmd("rank", "rank", "--model", "demo/model.npz", "--drive", "demo/track_drive.csv",
          "--shocks", "inputs/crate.toml", "--units", "imperial", "--out", "rank", section=sec)
    r.cmd("rank-constrained", "rank", "--model", "demo/model.npz", "--drive",
          "inputs/track30.csv", "--shocks", "inputs/crate.toml", "--symmetry", "none",
          "--only", "L12,L28,DM,TD", "--fixed", "LF=L28", "--baseline", "B20", "--simulate", "8",
          "--no-uncertainty", "--units", "imperial", "--out", "rank_constrained", section=sec)
    r.cmd("rank-setups-car", "rank", "--model", "inputs/car.toml", "--drive",
          "inputs/track30.csv", "--shocks", "inputs/crate.toml", "--setups",
          "inputs/setups.csv", "--units", "imperial", "--out", "rank_setups_car", section=sec)
    r.cmd("sweep", "sweep", "--model", "demo/model.npz", "--model", "inputs/car.toml",
          "--drive", "inputs/track30.csv", "--drive", "inputs/track30b.csv", "--shocks",
          "inputs/crate.toml", "--only", "B20,L12,L28,DS,DM", "--baseline", "B20",
          "--symmetry", "none", "--simulate-share", "0.02", "--scheduler", "none", "--units",
          "imperial", "--out", "sweep", section=sec)

    # -- From a real rig -------------------------------------------------------------------
    sec = "From a real rig"
    rpc = inputs / "rpc"
    rpc.mkdir()
    runs = ["baseline", "swap-LF", "swap-RF", "swap-LR", "swap-RR"]
    for run in runs:
        r.prep(f"RPC III file of run {run}", _rpc_from_run,
               r.out / "demo/session/runs" / f"{run}.csv", rpc / f"{run}.rsp")
    r.cmd("import-baseline", "import", "--format", "rpc3", "--map", "inputs/rig_map.toml",
          "inputs/rpc/baseline.rsp", "--setup", "B20,B20,B20,B20", "--role", "baseline",
          "--shocks", "demo/session/shocks.toml", "--units", "imperial", "--out",
          "import/session", section=sec)
    for run, setup in zip(runs[1:], ("N8,B20,B20,B20", "B20,N8,B20,B20", "B20,B20,N8,B20",
                                     "B20,B20,B20,N8")):
        r.cmd(f"import-{run}", "import", "--format", "rpc3", "--map", "inputs/rig_map.toml",
              f"inputs/rpc/{run}.rsp", "--setup", setup, "--role", "swap", "--names", run,
              "--out", "import/session", section=sec)
    r.cmd("import-bad-map", "import", "--format", "rpc3", "--map", "inputs/bad_map.toml",
          "inputs/rpc/baseline.rsp", "--setup", "B20,B20,B20,B20", "--shocks",
          "demo/session/shocks.toml", "--out", "import/refused", section=sec)
    r.cmd("identify-import", "identify", "import/session", "--out", "import/model.npz",
          "--plots", "import/frf_plots", "--mat", "import/model.mat", "--all-pairs",
          section=sec)
    r.cmd("export-drive-map", "export-drive", "inputs/track30.csv", "--format", "rpc3",
          "--map", "inputs/rig_map.toml", "--units", "imperial", "--out", "export/track30.drv",
          section=sec)
    r.cmd("export-drive", "export-drive", "demo/track_drive.csv", "--format", "rpc3",
          "--units", "imperial", "--out", "export/track_drive.drv", section=sec)
    r.cmd("rig-simulate-4post", "rig", "simulate", "--rig", "4-post", "--duration", "30",
          "--noise", "0.01", "--units", "SI", "--out", "rig4post/session", section=sec)
    r.cmd("identify-4post", "identify", "rig4post/session", "--out", "rig4post/model.npz",
          section=sec)

    # -- Optimize --------------------------------------------------------------------------
    sec = "Optimize"
    r.cmd("optimize", "optimize", "--model", "demo/model.npz", "--drive", "inputs/track30.csv",
          "--shocks", "inputs/crate.toml", "--baseline", "B20", "--constraints",
          "inputs/constraints.toml", "--units", "imperial", "--max-iter", "15", "--out",
          "optimum", section=sec)
    r.cmd("optimize-worst-case", "optimize", "--model", "demo/model.npz", "--drive",
          "inputs/track30.csv", "--drive", "inputs/track30b.csv", "--shocks",
          "inputs/crate.toml", "--symmetry", "none", "--worst-case", "--units", "imperial",
          "--max-iter", "10", "--out", "optimum_worst", section=sec)

    # -- Rig day ---------------------------------------------------------------------------
    sec = "Rig day"
    # the README's command as written (60 min with 2 validation runs)
    r.cmd("plan-readme", "plan", "--vehicle", "inputs/car.toml", "--shocks", "inputs/crate.toml",
          "--budget-min", "60", "--drive", "inputs/track30.csv", "--validate", "2", "--units",
          "imperial", "--out", "rigday/plan_readme", section=sec)
    r.cmd("plan", "plan", "--vehicle", "inputs/car.toml", "--shocks", "inputs/crate.toml",
          "--budget-min", "90", "--drive", "inputs/track30.csv", "--validate", "2", "--units",
          "imperial", "--out", "rigday/plan", section=sec)
    r.cmd("rig-simulate-plan", "rig", "simulate", "--plan", "rigday/plan/plan.toml",
          "--vehicle", "inputs/car.toml", "--out", "rigday/session", section=sec)
    r.cmd("identify-rigday", "identify", "rigday/session", "--out", "rigday/model.npz",
          section=sec)
    r.cmd("rank-rigday", "rank", "--model", "rigday/model.npz", "--drive", "inputs/track30.csv",
          "--shocks", "inputs/crate.toml", "--units", "imperial", "--out", "rigday/ranking",
          section=sec)
    r.cmd("plan-decision", "plan", "--model", "rigday/model.npz", "--session", "rigday/session",
          "--shocks", "inputs/crate.toml", "--budget-min", "30", "--criterion", "decision",
          "--drive", "inputs/track30.csv", "--units", "imperial", "--out", "rigday/plan2",
          section=sec)

    # -- What if ---------------------------------------------------------------------------
    sec = "What if"
    r.cmd("whatif", "whatif", "--model", "demo/model.npz", "--drive", "inputs/track30.csv",
          "--shocks", "inputs/crate.toml", "--ranking", "demo/ranking/ranking.csv", "--top",
          "4", "--baseline", "B20", "--perturb", "inputs/whatif.toml", "--units", "imperial",
          "--out", "whatif", section=sec)
    r.cmd("whatif-mc-screening", "whatif", "--model", "inputs/car.toml", "--drive",
          "inputs/track30.csv", "--shocks", "inputs/crate.toml", "--setups",
          "inputs/setups.csv", "--perturb", "inputs/whatif_mc.toml", "--method", "screening",
          "--units", "imperial", "--out", "whatif_mc", section=sec)

    total = time.monotonic() - t_start
    manifest = {
        "format": "shockplan-compare-run/1",
        "shockplan": str(exe),
        "python": sys.version.split()[0],
        "inputs_from": str(inputs_from),
        "inputs_copied": copied,
        "inputs_sha256": {p.relative_to(r.out).as_posix(): _sha256(p)
                          for p in sorted(inputs.rglob("*")) if p.is_file()},
        "prep_errors": r.prep_errors,
        "steps": r.steps,
    }
    (r.meta / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    (r.meta / "timings.json").write_text(json.dumps({"total_s": round(total, 1),
                                                     "steps_s": r.timings}, indent=1) + "\n")
    failed = [s["tag"] for s in r.steps if s["rc"] != 0]
    print(f"ran {len(r.steps)} commands in {total:.0f} s into {r.out}; non-zero exit: "
          f"{', '.join(failed) or 'none'}; prep errors: {len(r.prep_errors)}")
    return 0


# ---------------------------------------------------------------------------------------
# compare
# ---------------------------------------------------------------------------------------

def _files(root):
    root = Path(root)
    out = {}
    for p in root.rglob("*"):
        if not p.is_file():
            continue
        rel = p.relative_to(root)
        if rel.parts[0] in EXCLUDED_TOP:
            continue
        out[rel.as_posix()] = p
    return out


def _dir_variants(root):
    root = Path(root)
    vs = {str(root), str(root.resolve()), os.path.abspath(root)}
    return sorted(vs, key=len, reverse=True)


def _normalize_text(text, root):
    for v in _dir_variants(root):
        text = text.replace(v, PLACEHOLDER)
    return text


def _normalize_bytes(data, root):
    for v in _dir_variants(root):
        data = data.replace(v.encode(), PLACEHOLDER.encode())
    return data


def _mask_volatile(rel, data):
    """Mask the values of VOLATILE_TOML_KEYS[rel] (returns the data, how many masked)."""
    keys = VOLATILE_TOML_KEYS.get(rel)
    if not keys:
        return data, 0
    lines = data.decode("utf-8", errors="surrogateescape").split("\n")
    masked, table = 0, None
    for i, line in enumerate(lines):
        m = re.match(r"^\s*\[+\s*([^\]]+?)\s*\]+\s*$", line)
        if m:
            table = m.group(1)
            continue
        m = re.match(r"^\s*([A-Za-z0-9_-]+)\s*=", line)
        if m and any(t == table and re.fullmatch(k, m.group(1)) for t, k in keys):
            lines[i] = f"{m.group(1)} = <masked: wall clock>"
            masked += 1
    return "\n".join(lines).encode("utf-8", errors="surrogateescape"), masked


def _first_diff_line(a, b):
    """Where two texts first differ: the line, and a window around the first changed
    character (with the CSV column, for a CSV with a header row)."""
    la = a.decode("utf-8", errors="replace").splitlines()
    lb = b.decode("utf-8", errors="replace").splitlines()
    for i, (x, y) in enumerate(zip(la, lb)):
        if x != y:
            c = next((k for k, (p, q) in enumerate(zip(x, y)) if p != q), min(len(x), len(y)))
            col = ""
            if i > 0 and la and "," in la[0]:
                names = la[0].split(",")
                j = x[:c].count(",")
                col = f" column {names[j]!r}" if j < len(names) else ""
            lo = max(0, c - 25)
            return f"line {i + 1}{col}: ...{x[lo:c + 35]!r} vs ...{y[lo:c + 35]!r}"
    if len(la) != len(lb):
        return f"{len(la)} vs {len(lb)} lines"
    return "bytes differ (line endings or trailing newline)"


def cmp_text(rel, a, b, ra, rb):
    da = _normalize_bytes(a.read_bytes(), ra)
    db = _normalize_bytes(b.read_bytes(), rb)
    da, na = _mask_volatile(rel, da)
    db, _ = _mask_volatile(rel, db)
    if da == db:
        return "same", (f"identical ({na} wall-clock line(s) masked)" if na else "")
    return "DIFF", _first_diff_line(da, db)


def _load_npz(path):
    try:
        z = np.load(path, allow_pickle=False)
        return {k: z[k] for k in z.files}
    except ValueError:  # object arrays: our own outputs, safe to unpickle
        z = np.load(path, allow_pickle=True)
        return {k: z[k] for k in z.files}


def cmp_npz(rel, a, b, ra, rb):
    za, zb = _load_npz(a), _load_npz(b)
    if sorted(za) != sorted(zb):
        only_a = sorted(set(za) - set(zb))
        only_b = sorted(set(zb) - set(za))
        return "DIFF", f"keys differ: only ref {only_a[:5]}, only new {only_b[:5]}"
    bad = []
    for k in sorted(za):
        x, y = za[k], zb[k]
        if x.dtype != y.dtype or x.shape != y.shape:
            bad.append(f"{k}: {x.dtype}{x.shape} vs {y.dtype}{y.shape}")
            continue
        if x.dtype.kind in "US":
            x = np.vectorize(lambda s: _normalize_text(s, ra), otypes=[x.dtype])(x) \
                if x.size else x
            y = np.vectorize(lambda s: _normalize_text(s, rb), otypes=[y.dtype])(y) \
                if y.size else y
            if not np.array_equal(x, y):
                bad.append(f"{k}: strings differ")
            continue
        if x.dtype.kind == "O":
            if not all(repr(p) == repr(q) for p, q in zip(x.ravel(), y.ravel())):
                bad.append(f"{k}: objects differ")
            continue
        nan_ok = x.dtype.kind in "fc"
        if not np.array_equal(x, y, equal_nan=nan_ok):
            with np.errstate(all="ignore"):
                d = np.abs(x.astype(np.complex128) - y.astype(np.complex128)) \
                    if x.dtype.kind in "fcbiu" else None
            n = int(np.sum(~((x == y) | (np.isnan(x) & np.isnan(y)) if nan_ok else (x == y))))
            bad.append(f"{k}: {n} element(s) differ"
                       + (f", max |diff| {np.nanmax(d):.3g}" if d is not None and d.size else ""))
        elif np.ascontiguousarray(x).tobytes() != np.ascontiguousarray(y).tobytes():
            bad.append(f"{k}: equal values but different bits (signed zeros or NaN payloads)")
    if bad:
        return "DIFF", f"{len(bad)} array(s): " + "; ".join(bad[:3])
    return "same", f"{len(za)} arrays"


def _mask_xlsx_row(row, labels):
    """Mask the value right of a label of VOLATILE_XLSX_DATES (an ISO date string)."""
    row = list(row)
    for j, c in enumerate(row):
        if c in labels:
            k = next((k for k in range(j + 1, len(row)) if row[k] is not None), None)
            if k is not None and isinstance(row[k], str) and _ISO_DATE.fullmatch(row[k]):
                row[k] = "<date written>"
    return tuple(row)


def _xlsx_values(path, root):
    import openpyxl

    wb = openpyxl.load_workbook(path, read_only=True)
    volatile = VOLATILE_XLSX_DATES.get(Path(path).name, [])
    sheets = {}
    for ws in wb.worksheets:
        labels = {lab for sheet, lab in volatile if sheet == ws.title}
        rows = []
        for row in ws.iter_rows(values_only=True):
            row = tuple(_normalize_text(c, root) if isinstance(c, str) else c for c in row)
            rows.append(_mask_xlsx_row(row, labels) if labels else row)
        while rows and all(c is None for c in rows[-1]):
            rows.pop()
        sheets[ws.title] = rows
    wb.close()
    return sheets


def _cell_eq(x, y):
    if isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y):
        return True
    return type(x) is type(y) and x == y


def cmp_xlsx(rel, a, b, ra, rb):
    sa, sb = _xlsx_values(a, ra), _xlsx_values(b, rb)
    if list(sa) != list(sb):
        return "DIFF", f"sheets {list(sa)} vs {list(sb)}"
    for name in sa:
        ra_, rb_ = sa[name], sb[name]
        for i in range(max(len(ra_), len(rb_))):
            x = ra_[i] if i < len(ra_) else ()
            y = rb_[i] if i < len(rb_) else ()
            w = max(len(x), len(y))
            x = tuple(x) + (None,) * (w - len(x))
            y = tuple(y) + (None,) * (w - len(y))
            for j, (p, q) in enumerate(zip(x, y)):
                if not _cell_eq(p, q):
                    return "DIFF", (f"sheet {name!r} row {i + 1} col {j + 1}: "
                                    f"{str(p)[:40]!r} vs {str(q)[:40]!r}")
    return "same", f"{len(sa)} sheet(s)"


def _rpc_parse(path):
    data = Path(path).read_bytes()

    def rec(i):
        r = data[i * 128:(i + 1) * 128]
        return (r[:32].rstrip(b"\0 ").decode("latin-1"), r[32:].rstrip(b"\0 ").decode("latin-1"))

    k0, _ = rec(0)
    k1, v1 = rec(1)
    k2, v2 = rec(2)
    if k0 != "FORMAT" or k1 != "NUM_HEADER_BLOCKS" or k2 != "NUM_PARAMS":
        raise ValueError("not an RPC III file")
    blocks, n = int(v1), int(v2)
    params = [rec(i) for i in range(n)]
    return params, data[blocks * 512:]


def cmp_rpc(rel, a, b, ra, rb):
    try:
        pa, da = _rpc_parse(a)
        pb, db = _rpc_parse(b)
    except (ValueError, IndexError):
        return cmp_bytes(rel, a, b, ra, rb)
    # DATE: rpc3-file stamps the time of writing (to the second); nothing else is masked
    dated = " (DATE masked)" if any(k == "DATE" for k, _ in pa) else ""
    pa = [(k, _normalize_text(v, ra)) for k, v in pa if k != "DATE"]
    pb = [(k, _normalize_text(v, rb)) for k, v in pb if k != "DATE"]
    if pa != pb:
        diff = next(((x, y) for x, y in zip(pa, pb) if x != y), (len(pa), len(pb)))
        return "DIFF", f"header differs: {diff[0]} vs {diff[1]}"
    if da != db:
        return "DIFF", f"data bytes differ ({len(da)} vs {len(db)} bytes)"
    return "same", f"{len(pa)} header params{dated}, data identical"


def cmp_mat(rel, a, b, ra, rb):
    da, db = a.read_bytes(), b.read_bytes()
    # scipy.io.savemat: 116 bytes of text with the write time ("Created on: ...")
    ha = re.sub(rb"Created on: [^\0]*", b"Created on: <date>", da[:116])
    hb = re.sub(rb"Created on: [^\0]*", b"Created on: <date>", db[:116])
    if ha != hb:
        return "DIFF", f"header {ha!r} vs {hb!r}"
    if da[116:] != db[116:]:
        return "DIFF", f"contents differ ({len(da)} vs {len(db)} bytes)"
    return "same", "identical (header date masked)"


def _mdf4_time_fields(data):
    """Byte ranges of an MDF4 file's write times: the header's start time (HD block at 64,
    ``hd_start_time_ns`` after its 24-byte block header and 6 links) and the first file
    history entry's time (FH block, ``fh_time_ns`` after its header and 2 links)."""
    import struct

    if data[64:68] != b"##HD":
        return []
    fields = [(136, 144)]
    fh = struct.unpack_from("<Q", data, 64 + 24 + 8)[0]  # hd_fh_first: the second link
    if fh and data[fh:fh + 4] == b"##FH":
        fields.append((fh + 40, fh + 48))
    return fields


def cmp_mdf(rel, a, b, ra, rb):
    da, db = bytearray(a.read_bytes()), bytearray(b.read_bytes())
    if len(da) != len(db):
        return "DIFF", f"sizes differ ({len(da)} vs {len(db)} bytes)"
    for data in (da, db):
        for lo, hi in _mdf4_time_fields(data):
            data[lo:hi] = bytes(hi - lo)
    if da == db:
        return "same", "identical (write times masked)"
    return "DIFF", "contents differ"


def cmp_bytes(rel, a, b, ra, rb):
    if _normalize_bytes(a.read_bytes(), ra) == _normalize_bytes(b.read_bytes(), rb):
        return "same", "bytes"
    return "DIFF", "bytes differ"


def _log_lines(path, root):
    text = _normalize_text(path.read_bytes().decode("utf-8", errors="replace"), root)
    return [_mask_timings(line.rstrip()) for line in text.splitlines()]


def cmp_log(rel, a, b, ra, rb):
    la, lb = _log_lines(a, ra), _log_lines(b, rb)
    if la == lb:
        return "same", ""
    for i, (x, y) in enumerate(zip(la, lb)):
        if x != y:
            return "warn", f"line {i + 1}: {x[:60]!r} vs {y[:60]!r}"
    return "warn", f"{len(la)} vs {len(lb)} lines"


def cmp_manifest(rel, a, b, ra, rb):
    ma, mb = json.loads(a.read_text()), json.loads(b.read_text())
    bad = []
    sa = [(s["tag"], s["argv"], s["rc"]) for s in ma.get("steps", [])]
    sb = [(s["tag"], s["argv"], s["rc"]) for s in mb.get("steps", [])]
    if [s[:2] for s in sa] != [s[:2] for s in sb]:
        bad.append("different commands")
    for x, y in zip(sa, sb):
        if x[2] != y[2]:
            bad.append(f"{x[0]}: exit {x[2]} vs {y[2]}")
    if ma.get("inputs_sha256") != mb.get("inputs_sha256"):
        bad.append("different inputs")
    if ma.get("prep_errors") != mb.get("prep_errors"):
        bad.append(f"prep errors {ma.get('prep_errors')} vs {mb.get('prep_errors')}")
    if bad:
        return "DIFF", "; ".join(bad[:4])
    nz = [x[0] for x in sa if x[2] != 0]
    return "same", (f"{len(sa)} commands, same exit statuses"
                    + (f" (non-zero on both: {', '.join(nz)})" if nz else ""))


def _kind(rel):
    p = Path(rel)
    suf = p.suffix.lower()
    if rel == "_run/manifest.json":
        return "manifest", cmp_manifest
    if rel == "_run/timings.json":
        return "timings", None
    if p.parts[0] == "_logs":
        return ("rc", cmp_text) if suf == ".rc" else ("log", cmp_log)
    if suf in TEXT_SUFFIXES:
        return "text", cmp_text
    if suf == ".npz":
        return "npz", cmp_npz
    if suf == ".xlsx":
        return "xlsx", cmp_xlsx
    if suf in RPC_SUFFIXES:
        return "rpc3", cmp_rpc
    if suf == ".mat":
        return "mat", cmp_mat
    if suf in (".mf4", ".mdf"):
        return "mdf4", cmp_mdf
    if suf in IMAGE_SUFFIXES:
        return "image", None
    return "bytes", cmp_bytes


def compare(ref, new, only_diff=False):
    ref, new = Path(ref), Path(new)
    for d in (ref, new):
        if not (d / "_run" / "manifest.json").is_file():
            print(f"{d}: no _run/manifest.json (not a folder written by 'run')", file=sys.stderr)
            return 2
    fa, fb = _files(ref), _files(new)
    rows = []
    for rel in sorted(set(fa) | set(fb)):
        kind, func = _kind(rel)
        if rel not in fb:
            rows.append((rel, kind, "MISSING", "only in the reference"))
            continue
        if rel not in fa:
            rows.append((rel, kind, "EXTRA", "only in the new run"))
            continue
        if kind == "timings":
            rows.append((rel, kind, "skip", "wall times, not compared"))
            continue
        if func is None:
            rows.append((rel, kind, "present", "on both sides (not compared)"))
            continue
        try:
            status, detail = func(rel, fa[rel], fb[rel], ref, new)
        except Exception as exc:  # noqa: BLE001 - a file that cannot be read differs
            status, detail = "DIFF", f"cannot compare: {type(exc).__name__}: {exc}"
        if kind == "rc" and status == "DIFF":
            detail = "exit status differs: " + detail
        rows.append((rel, kind, status, detail))

    failing = {"DIFF", "MISSING", "EXTRA"}
    shown = [r for r in rows if r[2] != "same" and r[2] != "present"] if only_diff else rows
    if shown:
        w0 = max(len(r[0]) for r in shown)
        w1 = max(len(r[1]) for r in shown)
        print(f"{'file'.ljust(w0)}  {'kind'.ljust(w1)}  {'status':8}  detail")
        print(f"{'-' * w0}  {'-' * w1}  {'-' * 8}  {'-' * 6}")
        for rel, kind, status, detail in shown:
            print(f"{rel.ljust(w0)}  {kind.ljust(w1)}  {status:8}  {detail}")
    counts = {}
    for r in rows:
        counts[r[2]] = counts.get(r[2], 0) + 1
    n_fail = sum(counts.get(s, 0) for s in failing)
    by_kind = {}
    for r in rows:
        if r[2] in ("same",):
            by_kind[r[1]] = by_kind.get(r[1], 0) + 1
    print()
    print(f"{len(rows)} files: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
          + "; identical by kind: " + ", ".join(f"{k} {v}" for k, v in sorted(by_kind.items())))
    if counts.get("warn"):
        print(f"{counts['warn']} log(s) differ (warnings: stdout/stderr with timings masked)")
    print("RESULT: " + ("FAIL" if n_fail else "PASS") + f" ({n_fail} failing file(s))")
    return 1 if n_fail else 0


# ---------------------------------------------------------------------------------------

def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run every workflow with one shockplan executable")
    r.add_argument("--shockplan", required=True, help="the shockplan executable")
    r.add_argument("--out", required=True, help="output folder (must not exist, or be empty)")
    r.add_argument("--inputs-from", default="/work/ref",
                   help="checkout to copy the crate and the paper car from (default "
                   "%(default)s; falls back to this script's repository if it is missing)")
    r.add_argument("--force", action="store_true", help="delete an existing --out first")
    c = sub.add_parser("compare", help="compare two run folders; exit 1 on a difference")
    c.add_argument("ref")
    c.add_argument("new")
    c.add_argument("--only-diff", action="store_true", help="list only files that differ")
    args = p.parse_args(argv)

    if args.cmd == "compare":
        return compare(args.ref, args.new, only_diff=args.only_diff)

    exe = Path(args.shockplan)
    if not exe.is_file():
        p.error(f"--shockplan {exe}: no such file")
    exe = exe.absolute()
    out = Path(args.out).absolute()
    if out.exists() and any(out.iterdir()):
        if not args.force:
            p.error(f"--out {out} exists and is not empty (--force deletes it first)")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    inputs_from = Path(args.inputs_from)
    if not inputs_from.is_dir():
        inputs_from = Path(__file__).resolve().parent.parent
    return run_all(exe, out, inputs_from)


if __name__ == "__main__":
    sys.exit(main())
