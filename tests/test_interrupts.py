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

import hashlib
import shutil

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



# ---------------------------------------------------------------- every long command (issue 36)

#: Longest a long command may run in the test below, start-up and interrupt included [s]
#: (about 10 s each on a quiet 2-core machine; the rest is margin for a loaded one).
COMMAND_TIMEOUT_S = 300.0

#: Runs the command line as ``shockplan`` does, and sends SIGINT to its process group (as a
#: terminal's Ctrl-C does) at the n-th call of one function, once across forked workers: a
#: fixed point of the work, so the test never races the command.
_CTRL_C_AT = textwrap.dedent("""
    import os, signal, sys, threading

    suffix, name, nth = sys.argv[1], sys.argv[2], int(sys.argv[3])
    seen = {"n": 0, "done": False}
    lock = threading.Lock()

    def profile(frame, event, arg):
        if seen["done"] or event != "call" or frame.f_code.co_name != name:
            return
        if not frame.f_code.co_filename.replace(os.sep, "/").endswith(suffix):
            return
        with lock:
            seen["n"] += 1
            if seen["n"] != nth or seen["done"]:
                return
            seen["done"] = True
        try:  # once, a forked worker's count included
            os.close(os.open(os.environ["CTRL_C_ONCE"], os.O_CREAT | os.O_EXCL))
        except FileExistsError:
            return
        sys.setprofile(None)
        print(f"Ctrl-C at call {nth} of {name}", file=sys.stderr, flush=True)
        os.killpg(os.getpgrp(), signal.SIGINT)

    sys.setprofile(profile)
    threading.setprofile(profile)
    from planner.cli import main
    sys.exit(main(sys.argv[4:]))
""")

_DRIVE = ["--model", "paper", "--drive", "drive.csv", "--shocks", "crate.toml"]
_SLOW = pytest.mark.slow

#: Every long command once it is working: its command line (run in the inputs' folder) and
#: the call (file, function, n-th call) at which Ctrl-C comes.
LONG_COMMANDS = [
    pytest.param(["rank", *_DRIVE, "--out", "ranking"],
                 ("planner/predict.py", "predict_setups", 1), id="rank"),
    pytest.param(["rank", *_DRIVE, "--out", "old_ranking", "--overwrite"],
                 ("planner/predict.py", "predict_setups", 1), id="rank-overwrite"),
    pytest.param(["sweep", *_DRIVE, "--symmetry", "left-right", "--scheduler", "none",
                  "--chunk-size", "20", "--out", "sweep"],
                 ("planner/sweep.py", "_screen_chunk", 2), id="sweep"),
    pytest.param(["whatif", *_DRIVE, "--setups", "setups.csv", "--perturb", "perturb.toml",
                  "--out", "whatif"],
                 ("planner/predict.py", "predict_setups", 1), id="whatif"),
    pytest.param(["predict", *_DRIVE, "--setups", "setups.csv", "--out", "old.csv",
                  "--overwrite"],
                 ("planner/predict.py", "predict_setups", 1), id="predict-overwrite"),
    pytest.param(["rig", "simulate", "--duration", "30", "--out", "simulated"],
                 ("ident/sim/virtual_rig.py", "_daq_sample", 1), id="rig-simulate"),
    pytest.param(["plan", "--vehicle", "paper", "--shocks", "crate.toml", "--budget-min", "30",
                  "--baseline", "B20", "--out", "plan"],
                 ("planner/design/solve.py", "relaxed_design", 1), id="plan", marks=_SLOW),
    pytest.param(["identify", "session", "--out", "model.npz"],
                 ("ident/identify/pipeline.py", "_fit_pairs", 1), id="identify", marks=_SLOW),
    pytest.param(["drive", "from-track", "log.csv", "--model", "paper", "--shocks",
                  "crate.toml", "--setup", "DM", "--aero", "aero.toml", "--out", "track.csv"],
                 ("planner/trackdrive/build.py", "simulate", 2), id="drive-from-track",
                 marks=_SLOW),
    pytest.param(["optimize", *_DRIVE, "--baseline", "B20", "--max-iter", "40", "--out",
                  "optimum"],
                 ("planner/optimize/solve.py", "value", 3), id="optimize", marks=_SLOW),
]


@pytest.fixture(scope="module")
def user_folder(tmp_path_factory, paper_vehicle, paper_plan, demo_library):
    """A user's folder: a 20 s drive, setups, a what-if file, the crate, a 20 s track log and
    its aero model, a session of 5 runs x 60 s, and earlier outputs (``old_ranking/``,
    ``old.csv``) that an interrupted ``--overwrite`` must leave as they are."""
    from dataclasses import replace

    from ident.data.channels import CORNERS
    from ident.data.drive import make_track_drive, write_drive
    from ident.data.session import write_session
    from ident.data.tracklog import write_track_log
    from ident.models.aero import AeroModel, write_aero_model
    from ident.models.vehicle import build_full_car
    from ident.sim.virtual_rig import simulate_session
    from ident.sim.virtual_track import log_track_run, make_track_run
    from planner.demo import DEMO_LIBRARY_PATH
    from planner.setups import Setup

    folder = tmp_path_factory.mktemp("user")
    v = paper_vehicle
    geometry = dict(wheelbase_m=v.a_m + v.b_m, track_width_m=v.track_front_m)
    write_drive(make_track_drive(duration_s=20.0, fs_hz=100.0, seed=2, **geometry),
                folder / "drive.csv", units="SI")
    (folder / "setups.csv").write_text(
        "setup,LF,RF,LR,RR\nbaseline,B20,B20,B20,B20\nsoft,L12,L12,L12,L12\n"
        "firm,L28,L28,L28,L28\nmixed,L28,L28,DM,DM\n")
    (folder / "perturb.toml").write_text(textwrap.dedent("""
        format = "shockplan-whatif/1"
        design = "monte-carlo"
        n_draws = 4
        seed = 2
        [[factor]]
        name = "tolerance"
        kind = "shock_scale"
        corners = ["LF", "RF", "LR", "RR"]
        independent = true
        distribution = { kind = "uniform", low = 0.95, high = 1.05 }
        """))
    shutil.copy(DEMO_LIBRARY_PATH, folder / "crate.toml")
    aero = AeroModel(name="paper", kind="constant", cg_to_front_axle_m=v.a_m,
                     cg_to_rear_axle_m=v.b_m, reference_speed_m_s=60.0, downforce_n=3000.0,
                     balance=0.45)
    write_aero_model(aero, folder / "aero.toml")
    run = make_track_run(duration_s=20.0, fs_hz=100.0, seed=3, aero=aero, **geometry)
    log = log_track_run(build_full_car(v).loop_plant(), run,
                        Setup("t", {c: "DM" for c in CORNERS}).resolve(demo_library),
                        noise=0.02)
    write_track_log(log, folder / "log.csv", units="SI")
    plan = replace(paper_plan, runs=tuple(replace(r, duration_s=60.0) for r in paper_plan.runs))
    write_session(simulate_session(plan, v), folder / "session")
    (folder / "old_ranking").mkdir()
    (folder / "old_ranking" / "ranking.csv").write_text("setup,LF,RF,LR,RR,score\n")
    (folder / "old.csv").write_text("the user's predictions\n")
    return folder


def _state(folder):
    """Every file and folder under `folder`, with a digest of each file's bytes."""
    return {p.relative_to(folder).as_posix(): (hashlib.sha256(p.read_bytes()).hexdigest()
                                               if p.is_file() else "folder")
            for p in sorted(Path(folder).rglob("*"))}


def _session_members(sid):
    """Processes of session `sid` still running (a command started with its own session)."""
    members = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError, IndexError):
            continue
        if int(stat[3]) == sid and stat[0] != "Z":  # the session id; a zombie has ended
            members.append(int(entry.name))
    return members


@pytest.mark.skipif(not Path("/proc").is_dir() or sys.platform != "linux",
                    reason="reads /proc to see which processes run")
@pytest.mark.parametrize("argv, at", LONG_COMMANDS)
def test_ctrl_c_stops_every_long_command(argv, at, user_folder, tmp_path):
    """Issue 36: Ctrl-C (SIGINT to the command's process group) once the command is working:
    exit status 130, "interrupted", no output file or folder, no temporary file, nothing
    the user wrote changed (an earlier output under --overwrite included), and no process
    of the command left running."""
    before = _state(user_folder)
    script = tmp_path / "ctrl_c_at.py"
    script.write_text(_CTRL_C_AT)
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]),
               CTRL_C_ONCE=str(tmp_path / "once"))
    proc = subprocess.Popen([sys.executable, str(script), *map(str, at), "-q", *argv],
                            cwd=user_folder, env=env, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _, err = proc.communicate(timeout=COMMAND_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise AssertionError(f"{argv[0]} did not stop within {COMMAND_TIMEOUT_S:g} s of "
                             "start-up and Ctrl-C") from None
    assert "Ctrl-C at call" in err, f"the command finished before it was interrupted:\n{err}"
    assert proc.returncode == 130, err[-3000:]
    assert "shockplan: interrupted" in err
    assert _state(user_folder) == before
    deadline = time.monotonic() + WORKER_END_TIMEOUT_S
    while _session_members(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _session_members(proc.pid), "processes of the command outlived it"
