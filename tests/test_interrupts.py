"""Tests of ident.interrupts: Ctrl-C never lost, workers that end with their parent, and the
commands that use them (issue 36, item 4)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from ident import interrupts
from ident.data.files import atomic_dir, atomic_path, atomic_write_text

#: How long the workers of a SIGKILLed parent may take to end [s]: they poll every
#: PARENT_POLL_S (0.5 s); the rest is margin for a loaded 2-core machine.
WORKER_END_TIMEOUT_S = 20.0
#: How long the parent script may take to start its pool and print the workers' pids [s].
POOL_START_TIMEOUT_S = 60.0


@pytest.fixture
def sigint_handler():
    """Put back Python's own SIGINT handler and forget a recorded SIGINT after the test."""
    before = signal.getsignal(signal.SIGINT)
    yield
    signal.signal(signal.SIGINT, before)
    interrupts.reset()


def test_installed_handler_records_and_raises(sigint_handler):
    """After install(), SIGINT raises KeyboardInterrupt as before and is also recorded, so
    check() raises it again where an earlier one was swallowed."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    interrupts.install()
    assert not interrupts.requested()
    with pytest.raises(KeyboardInterrupt):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(1.0)  # the handler runs at the next bytecode
    assert interrupts.requested()
    with pytest.raises(KeyboardInterrupt):
        interrupts.check()
    interrupts.reset()
    interrupts.check()  # nothing recorded: no exception


def test_install_keeps_a_foreign_handler(sigint_handler):
    """An embedding application's handler (or SIG_IGN) is left alone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    interrupts.install()
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_deferred_only_records(sigint_handler):
    """Inside deferred() SIGINT raises nothing (C code in between would swallow it); the
    handler before it is back afterwards and check() raises."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    with interrupts.deferred():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)
        assert interrupts.requested()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with pytest.raises(KeyboardInterrupt):
        interrupts.check()


def test_atomic_writers_write_nothing_after_an_interrupt(tmp_path, sigint_handler):
    """A SIGINT recorded earlier (and swallowed on its way) stops every atomic writer: the
    target is untouched and no temporary file is left."""
    keep = tmp_path / "keep.txt"
    keep.write_text("the user's file\n")
    interrupts.deferred._handle(signal.SIGINT, None)  # a recorded, swallowed SIGINT
    with pytest.raises(KeyboardInterrupt):
        atomic_write_text(keep, "replaced\n")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(tmp_path / "new.csv") as tmp:
            tmp.write_text("a,b\n")
    with pytest.raises(KeyboardInterrupt):
        with atomic_dir(tmp_path / "out") as work:
            (work / "x.txt").write_text("x")
    assert keep.read_text() == "the user's file\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]


def test_atomic_dir_has_the_usual_mode(tmp_path):
    """An output folder gets the mode a mkdir would give it (not mkdtemp's 0700)."""
    with atomic_dir(tmp_path / "out") as work:
        (work / "x.txt").write_text("x")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "out").stat().st_mode & 0o777 == 0o777 & ~umask


def _alive(pid):
    """True if process `pid` runs (a zombie waiting for its reaper counts as ended)."""
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    return "\nState:\tZ" not in state


@pytest.mark.skipif(not Path("/proc").is_dir() or sys.platform != "linux",
                    reason="reads /proc to see which processes run")
def test_workers_end_when_their_parent_is_killed(tmp_path):
    """SIGKILL to a process with a fork pool started with die_with_parent: its workers end
    within seconds instead of living on as orphans."""
    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent("""
        import concurrent.futures, multiprocessing, os, sys, time
        from ident.interrupts import die_with_parent

        def work(_):
            time.sleep(300)

        pool = concurrent.futures.ProcessPoolExecutor(
            max_workers=2, mp_context=multiprocessing.get_context("fork"),
            initializer=die_with_parent, initargs=(os.getpid(),))
        futures = [pool.submit(work, k) for k in range(2)]
        deadline = time.monotonic() + 30
        while len(pool._processes) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        print(" ".join(str(p) for p in pool._processes), flush=True)
        time.sleep(300)
    """))
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True,
                            env=env)
    try:
        line = proc.stdout.readline()
        pids = [int(p) for p in line.split()]
        assert len(pids) == 2, line
        assert all(_alive(p) for p in pids)
        proc.kill()
        proc.wait(timeout=POOL_START_TIMEOUT_S)
        deadline = time.monotonic() + WORKER_END_TIMEOUT_S
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(p) for p in pids), "workers outlived their killed parent"
    finally:
        if proc.poll() is None:
            proc.kill()


def _interrupt_during_solve(monkeypatch, after_calls=3):
    """Send this process SIGINT from inside IPOPT's solve (the optimizer's metrics callback,
    its `after_calls`-th evaluation), as a Ctrl-C during `optimize` would arrive."""
    from planner.optimize import solve

    calls = {"n": 0}
    value = solve.Evaluator.value

    def value_then_sigint(self, x):
        calls["n"] += 1
        if calls["n"] == after_calls:
            os.kill(os.getpid(), signal.SIGINT)
        return value(self, x)

    monkeypatch.setattr(solve.Evaluator, "value", value_then_sigint)
    return calls


@pytest.mark.slow
def test_ctrl_c_stops_optimize(tmp_path, monkeypatch, capsys, paper_vehicle, sigint_handler):
    """Ctrl-C during IPOPT's solve: `optimize` exits 130 and writes no output folder (casadi
    swallowed the KeyboardInterrupt and reported the solve as finished)."""
    from ident.data.drive import make_track_drive, write_drive
    from planner.cli import main
    from planner.demo import DEMO_LIBRARY_PATH

    signal.signal(signal.SIGINT, signal.default_int_handler)
    drive = make_track_drive(duration_s=20.0, fs_hz=100.0, seed=2,
                             wheelbase_m=paper_vehicle.a_m + paper_vehicle.b_m,
                             track_width_m=paper_vehicle.track_front_m)
    write_drive(drive, tmp_path / "drive.csv", units="SI")
    calls = _interrupt_during_solve(monkeypatch)
    out = tmp_path / "opt"
    status = main(["-q", "optimize", "--model", "paper", "--drive", str(tmp_path / "drive.csv"),
                   "--shocks", str(DEMO_LIBRARY_PATH), "--baseline", "B20", "--max-iter", "40",
                   "--out", str(out)])
    assert calls["n"] >= 3  # the solve ran and was interrupted inside it
    assert status == 130
    assert "interrupted" in capsys.readouterr().err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drive.csv"]  # no temporary left


@pytest.mark.heavy
def test_ctrl_c_stops_the_demo_during_optimize(tmp_path, monkeypatch, capsys, sigint_handler):
    """Ctrl-C while the demo optimizes: exit 130, no demo folder."""
    from planner.cli import main

    signal.signal(signal.SIGINT, signal.default_int_handler)
    calls = _interrupt_during_solve(monkeypatch)
    out = tmp_path / "demo"
    assert main(["-q", "demo", "--out", str(out)]) == 130
    assert calls["n"] >= 3
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.heavy
@pytest.mark.skipif(not Path("/proc").is_dir() or sys.platform != "linux",
                    reason="reads /proc to see which processes run")
def test_killed_identify_leaves_no_worker_and_no_half_output(tmp_path):
    """SIGKILL to `shockplan identify` while its fit workers run: the workers are gone
    within seconds, and the model and its summary are both absent (or both present)."""
    import psutil

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    cli = [sys.executable, "-c", "import sys; from planner.cli import main; sys.exit(main())"]
    subprocess.run(cli + ["-q", "rig", "simulate", "--out", str(tmp_path / "session")],
                   check=True, env=env, timeout=600)
    proc = subprocess.Popen(cli + ["-q", "identify", str(tmp_path / "session"), "--out",
                                   str(tmp_path / "model.npz")], env=env)
    try:
        parent = psutil.Process(proc.pid)
        deadline = time.monotonic() + POOL_START_TIMEOUT_S * 5
        workers = []
        while not workers and time.monotonic() < deadline and proc.poll() is None:
            workers = parent.children(recursive=True)
            time.sleep(0.05)
        assert workers, "identify finished before its fit workers could be seen"
        pids = [w.pid for w in workers]
        proc.kill()
        proc.wait(timeout=60)
        deadline = time.monotonic() + WORKER_END_TIMEOUT_S
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(p) for p in pids), "fit workers outlived the killed identify"
        written = {(tmp_path / "model.npz").exists(),
                   (tmp_path / "model_summary.csv").exists()}
        assert len(written) == 1  # both or neither
    finally:
        if proc.poll() is None:
            proc.kill()
