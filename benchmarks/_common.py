"""Helpers shared by the benchmark scripts (timing context, memory, drive segments)."""

from __future__ import annotations

import os
import resource
import subprocess
from pathlib import Path

import numpy as np

from ident.data.channels import RIG_INPUTS
from ident.data.drive import Drive

ROOT = Path(__file__).resolve().parents[1]


def mib(n_bytes):
    """Bytes in MiB."""
    return n_bytes / 2**20


def load():
    """The 1-minute load average, as printed next to every timing."""
    return f"1-min load {os.getloadavg()[0]:.2f}"


def maxrss_mib():
    """This process's peak resident memory [MiB] (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def engine_version():
    """The repository's commit, flagged if ident/ or planner/ have uncommitted changes."""
    try:
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "ident",
                                "planner"], capture_output=True, text=True,
                               check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return head + (" + uncommitted changes in ident/ or planner/" if dirty else "")


def jit_source(kernel="loop_metrics_worker"):
    """How a compiled shock loop of :mod:`ident.sim.loop_kernels` was obtained: "compile", "cache
    load" or "unknown". Default: the predictions' (the setup-parallel loop with its
    metrics); the virtual rig runs ``"loop_serial"``."""
    from ident.sim import loop_kernels

    stats = getattr(getattr(loop_kernels, kernel, None), "stats", None)
    if stats is None:
        return "unknown"
    if sum(stats.cache_misses.values()):
        return "compile"
    return "cache load" if sum(stats.cache_hits.values()) else "unknown"


def drive_segment(drive, duration_s):
    """The first `duration_s` of a drive (``round(duration_s * fs) + 1`` samples)."""
    n = int(round(duration_s * drive.fs_hz)) + 1
    if n > drive.n_samples:
        raise ValueError(f"--ref-seconds {duration_s} is longer than the drive "
                         f"({drive.duration_s:g} s); give a shorter segment")
    return Drive(name=f"{drive.name} [0, {duration_s:g} s]", fs_hz=drive.fs_hz,
                 channels={c: drive.channels[c][:n] for c in RIG_INPUTS})


def rel_rms(a, b):
    """``rms(a - b) / rms(b)``."""
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))
