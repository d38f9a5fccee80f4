"""The optimizer's compiled step functions on disk: casadi's C code, compiled once per machine.

The loop's step functions and their adjoints (:mod:`planner.optimize.loop`)
are generated as C, hashed with the compiler and its flags
(:data:`JIT_FLAGS`), and compiled into one shared library in
:func:`jit_cache_dir` (``$SHOCKPLAN_CACHE_DIR``, else
``~/.cache/shockplan``), where a later run finds it
(:func:`compiled_steps`). The least recently used libraries beyond
:data:`JIT_CACHE_MAX_FILES` are removed; without a C compiler, or if it
fails, the functions run uncompiled in casadi's virtual machine.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import time
import warnings
from pathlib import Path

import casadi as ca

__all__ = [
    "JIT_CACHE_MAX_FILES",
    "JIT_FLAGS",
    "jit_cache_dir",
    "jit_available",
    "compiled_steps",
]

log = logging.getLogger(__name__)

#: The process's temporary folder for compiled code, once made (:func:`_jit_dir`).
_JIT_DIR = []


def _jit_dir():
    """The process's folder for compiled code (removed at exit): the fallback when the
    machine's cache folder (:func:`jit_cache_dir`) cannot be written."""
    if not _JIT_DIR:
        path = tempfile.mkdtemp(prefix="shockplan-jit-")
        _JIT_DIR.append(path)
        atexit.register(shutil.rmtree, path, ignore_errors=True)
    return _JIT_DIR[0]


#: Compiled step libraries kept in the cache folder; the least recently used beyond this
#: are removed when a new one is written.
JIT_CACHE_MAX_FILES = 64
#: C compiler flags of the step functions (-O1: most of -O2's speed on this code at a
#: fraction of its compile time; -O0 compiles in 40 % of the time but its adjoint runs slower).
JIT_FLAGS = ("-O1", "-fPIC")


def jit_cache_dir():
    """The folder of compiled step functions kept between runs.

    ``$SHOCKPLAN_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/shockplan`` (default
    ``~/.cache/shockplan``), with a subfolder per casadi version. A library is
    named by a hash of its generated C source and the compiler flags, so a
    changed model, drive grid, curve space or shockplan version compiles anew
    and a stale file is never used. Safe to delete at any time.

    Returns
    -------
    pathlib.Path
    """
    root = os.environ.get("SHOCKPLAN_CACHE_DIR")
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"),
                                                                 ".cache")
        root = os.path.join(base, "shockplan")
    return Path(root) / f"jit-casadi-{ca.__version__}"


def _compiler():
    return shutil.which("cc") or shutil.which("gcc")


def jit_available():
    """bool: a C compiler (``cc`` or ``gcc``) is found, so the step functions can be compiled."""
    return shutil.which("cc") is not None or shutil.which("gcc") is not None


def compiled_steps(fns):
    """The step functions `fns` and their adjoints as one compiled shared library.

    The C source (each function and its ``reverse(1)``, which casadi's
    ``external`` finds by name) is generated and hashed; the library is
    compiled only when the cache (:func:`jit_cache_dir`) has no library of that
    hash, atomically (a temporary name, then a rename), so concurrent
    processes never load a half-written file. On a cache folder that cannot
    be written the process's temporary folder is used; if the compiler fails,
    the functions run uncompiled in casadi's virtual machine (slower, the same
    results) with a warning.

    Returns
    -------
    tuple of casadi.Function
    """
    # one C file per function (each step and its adjoint), compiled to objects side by side
    # on the cores, then linked into one library: the adjoints' code is the bulk
    funcs = [g for f in fns for g in (f, f.reverse(1))]
    sources = []
    for g in funcs:
        cg = ca.CodeGenerator(f"{g.name()}.c", {"with_header": False})
        cg.add(g)
        sources.append(cg.dump())
    cc = _compiler()
    digest = hashlib.sha256("\0".join([*sources, cc or "", *JIT_FLAGS]).encode()).hexdigest()
    name = f"steps-{digest[:24]}.so"
    folder = jit_cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".probe-{os.getpid()}"
        probe.touch()
        probe.unlink()
    except OSError:
        log.info("compiled-step cache %s cannot be written; compiling into a temporary "
                 "folder", folder)
        folder = Path(_jit_dir())
    lib = folder / name
    with _compile_lock(folder / f".{name}.lock"):
        return _load_or_compile(fns, sources, cc, folder, name, lib)


@contextlib.contextmanager
def _compile_lock(path):
    """Hold an exclusive lock on `path` (POSIX ``flock``): a process that needs the library
    another process is compiling waits for it rather than compiling it a second time. The
    lock ends with its process however it ends; without ``flock`` (or on a folder where the
    lock file cannot be made) there is no lock and a process compiles as before."""
    try:
        import fcntl
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except (ImportError, OSError):
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:  # e.g. a file system without locks: compile as before
            pass
        yield
    finally:
        os.close(fd)  # releases the lock; the (empty) lock file stays for the next process


def _load_or_compile(fns, sources, cc, folder, name, lib):
    """The library `lib` of `fns` (C `sources`), compiled from them if not in `folder`."""
    if lib.exists():
        try:
            os.utime(lib)  # least recently used goes first
        except OSError:
            pass
    else:
        t0 = time.perf_counter()
        stem = folder / f".{name}.{os.getpid()}"
        files_c = [Path(f"{stem}.{k}.c") for k in range(len(sources))]
        files_o = [Path(f"{stem}.{k}.o") for k in range(len(sources))]
        tmp_so = Path(f"{stem}.tmp")
        try:
            for path, src in zip(files_c, sources):
                path.write_text(src)
            order = sorted(range(len(sources)), key=lambda k: -len(sources[k]))
            _run_parallel([[cc, *JIT_FLAGS, "-c", str(files_c[k]), "-o", str(files_o[k])]
                           for k in order], os.cpu_count() or 1)
            _run_parallel([[cc, "-shared", *map(str, files_o), "-o", str(tmp_so), "-lm"]], 1)
            os.replace(tmp_so, lib)
        except (OSError, TypeError) as exc:
            warnings.warn(f"compiling the optimizer's step functions failed ({exc}); they run "
                          "uncompiled (slower, same results)", RuntimeWarning, stacklevel=4)
            return tuple(fns)
        finally:
            for t in (*files_c, *files_o, tmp_so):
                t.unlink(missing_ok=True)
        log.info("compiled the optimizer's step functions in %.1f s: %s",
                 time.perf_counter() - t0, lib)
        _prune_cache(folder)
    return tuple(ca.external(f.name(), str(lib)) for f in fns)


def _run_parallel(commands, n_jobs):
    """Run compiler `commands`, up to `n_jobs` at once; raise OSError on the first failure."""
    running, pending = [], list(commands)
    try:
        while pending or running:
            while pending and len(running) < max(1, n_jobs):
                running.append(subprocess.Popen(pending.pop(0), stdout=subprocess.PIPE,
                                                stderr=subprocess.PIPE, text=True))
            proc = running.pop(0)
            _, err = proc.communicate()
            if proc.returncode != 0:
                raise OSError((err or "").strip()[-400:] or f"exit {proc.returncode}")
    finally:
        for proc in running:
            proc.kill()
            proc.wait()


def _prune_cache(folder):
    """Remove the least recently used libraries beyond :data:`JIT_CACHE_MAX_FILES`."""
    try:
        libs = sorted(folder.glob("steps-*.so"), key=lambda p: p.stat().st_mtime)
        for old in libs[:max(0, len(libs) - JIT_CACHE_MAX_FILES)]:
            old.unlink(missing_ok=True)
            (folder / f".{old.name}.lock").unlink(missing_ok=True)
    except OSError:
        pass
