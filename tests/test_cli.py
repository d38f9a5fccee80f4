"""Tests of planner.cli: the shockplan command line."""

import argparse
import re
from pathlib import Path

import numpy as np
import pytest

import ident
from ident.data.session import read_session
from planner.cli import build_parser, main
from planner.options import LoopOptions


def test_rig_simulate_writes_a_session(tmp_path, capsys):
    out = tmp_path / "sess"
    assert main(["-q", "rig", "simulate", "--duration", "10", "--out", str(out)]) == 0
    s = read_session(out)
    assert [r.name for r in s.runs][:2] == ["baseline", "swap-LF"]
    assert s.runs[0].n_samples == 1000 and s.units == "imperial"
    said = capsys.readouterr().out
    # without --rig the built-in plan runs on a 7-post rig, as --help says (issue 23)
    assert "wrote rig session" in said and "7-post rig (7 rig inputs)" in said
    # a second run refuses to overwrite, with one clear line
    assert main(["-q", "rig", "simulate", "--duration", "10", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "already exists" in err and err.count("\n") == 1
    # --overwrite and --units SI
    assert main(["-q", "rig", "simulate", "--duration", "10", "--out", str(out), "--overwrite",
                 "--units", "SI", "--noise", "0.01"]) == 0
    s2 = read_session(out)
    assert s2.units == "SI"
    np.testing.assert_allclose(s2.runs[0].channels["aero_heave"], s.runs[0].channels["aero_heave"],
                               rtol=1e-12)


def test_rig_simulate_four_post(tmp_path, capsys):
    """--rig 4-post: the runs have the wheelloaders and no aero channels (issue 12)."""
    from ident.data.channels import AERO_INPUTS, WHEELLOADER_INPUTS

    out = tmp_path / "four-post"
    assert main(["-q", "rig", "simulate", "--duration", "10", "--rig", "4-post",
                 "--out", str(out)]) == 0
    assert "4-post rig (4 rig inputs)" in capsys.readouterr().out
    s = read_session(out)
    assert s.rig_inputs == WHEELLOADER_INPUTS
    assert not any(c in r.channels for r in s.runs for c in AERO_INPUTS)


def test_rig_simulate_bad_plan(tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text('format = "nope"\n')
    assert main(["-q", "rig", "simulate", "--plan", str(plan), "--out", str(tmp_path / "o")]) == 2
    assert "format" in capsys.readouterr().err


def test_rig_simulate_duration_with_drive_files_is_refused(tmp_path, capsys):
    """--duration sets generated drives only: on a plan whose runs play drive files it would
    be ignored, so it is refused, naming the run (issue 23)."""
    from ident.data.drive import make_track_drive, write_drive

    from planner.demo import DEMO_LIBRARY_PATH

    write_drive(make_track_drive(duration_s=5.0, fs_hz=100.0, seed=1), tmp_path / "d.csv")
    (tmp_path / "shocks.toml").write_bytes(DEMO_LIBRARY_PATH.read_bytes())
    plan = tmp_path / "plan.toml"
    plan.write_text('format = "rig-plan/1"\nshock_library = "shocks.toml"\n\n[[run]]\n'
                    'name = "track"\ndrive = "d.csv"\n'
                    'setup = { LF = "B20", RF = "B20", LR = "B20", RR = "B20" }\n')
    code = main(["-q", "rig", "simulate", "--plan", str(plan), "--duration", "10", "--out",
                 str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "--duration" in err and "track" in err and "drive file" in err, err
    assert not (tmp_path / "o").exists()


#: The modes table prints frequencies and damping ratios with 3 decimals.
ATOL_PRINTED_3_DECIMALS = 0.0005
#: The CLI's predictions CSV against predict_setups on the same inputs: the same call in the
#: same process, its floats written at full precision (they read back bit for bit).
RTOL_CLI_VS_LIBRARY = 1e-12


def test_vehicle_modes(capsys):
    """The printed modes are the vehicle model's (modal_summary of the paper's car with the
    damping converted from lbf/(in/s)), row by row, to the printed decimals."""
    from ident.data.units import to_si
    from ident.models.vehicle import example_vehicle, modal_summary

    assert main(["vehicle", "modes", "--damping", "20", "--units", "imperial"]) == 0
    out = capsys.readouterr().out
    assert "hop_LF" in out and "heave" in out
    s = modal_summary(example_vehicle(), damping_n_s_m=to_si(20.0, "damping", "imperial"))
    lines = out.splitlines()
    assert "shocks 20 lbf/(in/s)" in lines[0]  # in the units asked (issue 36)
    assert lines[1].split() == ["mode", "no-damping", "Hz", "natural", "Hz", "damped", "Hz",
                                "zeta"]
    rows = [line.split() for line in lines[3:3 + len(s.labels)]]
    assert [r[0] for r in rows] == list(s.labels)
    printed = np.array([[float(x) for x in r[1:]] for r in rows])
    expected = np.column_stack([s.no_damping_hz, s.natural_hz, s.damped_hz, s.damping_ratio])
    assert np.all(printed[:, 2] <= printed[:, 1] + ATOL_PRINTED_3_DECIMALS)  # damped <= natural
    np.testing.assert_allclose(printed, expected, rtol=0, atol=ATOL_PRINTED_3_DECIMALS)


def _small_session(tmp_path):
    out = tmp_path / "sess"
    assert main(["-q", "rig", "simulate", "--duration", "120", "--out", str(out),
                 "--units", "SI"]) == 0
    return out


@pytest.mark.slow
@pytest.mark.heavy
def test_identify_predict_rank(tmp_path, capsys, paper_vehicle):
    from ident.data.drive import make_track_drive, write_drive
    from ident.identify.model import load_model
    from ident.models.library import read_shock_library, write_shock_library
    from planner.demo import DEMO_LIBRARY_PATH

    sess = _small_session(tmp_path)
    model = tmp_path / "model.npz"
    assert main(["-q", "identify", str(sess), "--out", str(model), "--nperseg", "1024",
                 "--plots", str(tmp_path / "plots"), "--mat", str(tmp_path / "m.mat")]) == 0
    out = capsys.readouterr().out
    assert "fit error" in out and "wrote model" in out
    assert "noise:" in out and "expected metric error" in out
    loaded = load_model(model)
    assert loaded.settings["session"] == "paper identification experiment"
    noise = loaded.noise
    assert set(noise.expected_metric_error_pct) >= {"tire_force_rms_LF", "ride_height_rms_rear"}
    assert noise.reference == {"run": "baseline", "setup": "B20/B20/B20/B20"}
    assert any((tmp_path / "plots").glob("frf_*.png")) and (tmp_path / "m.mat").is_file()
    # the drive and the shocks in imperial units, setups CSV per the spec
    drive = make_track_drive(duration_s=30.0, fs_hz=100.0, seed=2,
                             wheelbase_m=paper_vehicle.a_m + paper_vehicle.b_m,
                             track_width_m=paper_vehicle.track_front_m)
    write_drive(drive, tmp_path / "drive.csv", units="imperial")
    write_shock_library(read_shock_library(DEMO_LIBRARY_PATH), tmp_path / "shocks.toml",
                        units="imperial")
    (tmp_path / "setups.csv").write_text("setup,LF,RF,LR,RR\nbaseline,B20,B20,B20,B20\n"
                                         "firm,L28,L28,DF,DF\n")
    pred = tmp_path / "pred.csv"
    assert main(["-q", "predict", "--model", str(model), "--drive", str(tmp_path / "drive.csv"),
                 "--shocks", str(tmp_path / "shocks.toml"), "--setups",
                 str(tmp_path / "setups.csv"), "--out", str(pred), "--units", "imperial"]) == 0
    import pandas as pd

    assert pred.read_text().splitlines()[0].startswith("setup,")  # the header first
    table = pd.read_csv(pred)
    assert (table["units"] == "imperial").all() and table.columns[-1] == "units"
    assert list(table.columns[:6]) == ["setup", "LF", "RF", "LR", "RR", "tire_force_rms_LF"]
    assert table["setup"].tolist() == ["baseline", "firm"]
    assert 5 < table["tire_force_rms_LF"].iloc[0] < 1000  # lbf on a smooth track
    # the CLI's tire forces are the library's prediction on the same files, in lbf
    from ident.data.drive import read_drive
    from planner.predict import predict_setups
    from planner.report import ranking_to_units
    from planner.setups import read_setups

    lib = read_shock_library(tmp_path / "shocks.toml")
    ref = predict_setups(load_model(model), read_drive(tmp_path / "drive.csv", units="imperial"),
                         read_setups(tmp_path / "setups.csv", lib), lib,
                         loop=LoopOptions(oversample=2)).table
    ref = ranking_to_units(ref, "imperial")
    for c in ("LF", "RF", "LR", "RR"):
        np.testing.assert_allclose(table[f"tire_force_rms_{c}"].to_numpy(),
                                   ref[f"tire_force_rms_{c}"].to_numpy(),
                                   rtol=RTOL_CLI_VS_LIBRARY, atol=0)
    rank_dir = tmp_path / "rank"
    assert main(["-q", "rank", "--model", "paper", "--drive", str(tmp_path / "drive.csv"),
                 "--shocks", str(tmp_path / "shocks.toml"), "--units", "imperial",
                 "--only", "B20,L12,L28,DM", "--baseline", "B20", "--simulate", "6",
                 "--out", str(rank_dir)]) == 0
    assert (rank_dir / "ranking.xlsx").is_file() and "best" in capsys.readouterr().out
    # bad input: a setup with an unknown shock id, one line naming it
    (tmp_path / "bad.csv").write_text("setup,LF,RF,LR,RR\nx,B20,B20,B20,ZZZ\n")
    assert main(["-q", "predict", "--model", "paper", "--drive", str(tmp_path / "drive.csv"),
                 "--shocks", str(tmp_path / "shocks.toml"), "--setups", str(tmp_path / "bad.csv"),
                 "--out", str(tmp_path / "p2.csv"), "--units", "imperial"]) == 2
    assert "ZZZ" in capsys.readouterr().err


@pytest.mark.slow
def test_optimize_command(tmp_path, capsys, paper_vehicle):
    """``shockplan optimize`` end to end on a short drive (imperial files), and its refusals:
    constraints no curve meets (one line naming them, nothing written), an existing folder."""
    from ident.data.drive import make_track_drive, write_drive
    from ident.models.library import read_shock_library
    from planner.demo import DEMO_LIBRARY_PATH

    drive = make_track_drive(duration_s=30.0, fs_hz=100.0, seed=2,
                             wheelbase_m=paper_vehicle.a_m + paper_vehicle.b_m,
                             track_width_m=paper_vehicle.track_front_m)
    write_drive(drive, tmp_path / "drive.csv", units="imperial")
    out = tmp_path / "opt"
    args = ["-q", "optimize", "--model", "paper", "--drive", str(tmp_path / "drive.csv"),
            "--shocks", str(DEMO_LIBRARY_PATH), "--baseline", "B20", "--units", "imperial",
            "--max-iter", "15"]
    bad = tmp_path / "bad.toml"
    bad.write_text('[bump]\nlow_speed_slope = [20000.0, 30000.0]\n[shape]\nmax_force = 50.0\n')
    assert main(args + ["--constraints", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "cannot all hold" in err and "max force" in err and err.count("\n") == 1
    assert not out.exists()
    assert main(args + ["--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "verified in the time domain" in text and "better than the crate's best" in text
    lib = read_shock_library(out / "optimal_shocks.toml")
    assert lib.get("OPT-front").kind == "table" and "lbf" in text
    assert main(args + ["--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err


def test_whatif_command(tmp_path, capsys, paper_vehicle, track_drive):
    """``shockplan whatif`` on the known paper car from a ranking CSV's top setups (imperial
    files), and its refusals: a perturbation file with a bad key (one line naming it)."""
    import textwrap

    import pandas as pd

    from ident.data.drive import Drive, write_drive
    from planner.demo import DEMO_LIBRARY_PATH

    n = int(20 * track_drive.fs_hz)
    write_drive(Drive("short", track_drive.fs_hz, {c: x[:n] for c, x in track_drive.channels.items()}),
                tmp_path / "drive.csv", units="imperial")
    (tmp_path / "ranking.csv").write_text(
        "setup,LF,RF,LR,RR,score\nbaseline,B20,B20,B20,B20,1.0\nsoft,L12,L12,L12,L12,0.97\n"
        "firm,L28,L28,L28,L28,0.95\nmixed,L28,L28,DM,DM,0.96\n")
    (tmp_path / "perturb.toml").write_text(textwrap.dedent("""
        format = "shockplan-whatif/1"
        units = "imperial"
        design = "monte-carlo"
        n_draws = 6
        seed = 2
        [[factor]]
        name = "rear springs"
        kind = "spring_rate"
        corners = ["LR", "RR"]
        distribution = { kind = "uniform", low = 0.9, high = 1.1 }
        [[factor]]
        name = "tolerance"
        kind = "shock_scale"
        corners = ["LF", "RF", "LR", "RR"]
        independent = true
        distribution = { kind = "normal", mean = 1.0, sd = 0.025 }
        """))
    out = tmp_path / "whatif"
    args = ["-q", "whatif", "--model", "paper", "--drive", str(tmp_path / "drive.csv"),
            "--shocks", str(DEMO_LIBRARY_PATH), "--ranking", str(tmp_path / "ranking.csv"),
            "--top", "3", "--units", "imperial", "--baseline", "baseline"]
    assert main(args + ["--perturb", str(tmp_path / "perturb.toml"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "3 setups x 7 conditions" in text and "baseline 'baseline'" in text
    rob = pd.read_csv(out / "robust.csv", index_col="setup")
    assert set(rob.index) == {"baseline", "soft", "firm"}
    assert (out / "whatif.xlsx").is_file() and (out / "rank_stability.png").is_file()
    (tmp_path / "bad.toml").write_text('format = "shockplan-whatif/1"\n[[factor]]\nname = "m"\n'
                                       'kind = "vehicle"\nparameter = "mass"\nlevels = [1.1]\n')
    assert main(args + ["--perturb", str(tmp_path / "bad.toml"), "--out",
                        str(tmp_path / "w2")]) == 2
    err = capsys.readouterr().err
    assert "'parameter'" in err and "bad.toml" in err and err.count("\n") == 1
    assert not (tmp_path / "w2").exists()


# --- Units that cannot be mistaken (issue 23, item 1) ----------------------------------

#: The commands that read drive files: their --units defaults to the drive file's marker.
DRIVE_COMMANDS = ("predict", "rank", "sweep", "optimize", "plan", "whatif", "export-drive")


def _short_imperial_drive(track_drive, path, seconds=20.0):
    """The first `seconds` of the track drive, written in imperial units (with the marker)."""
    from ident.data.drive import Drive, write_drive

    n = int(seconds * track_drive.fs_hz)
    write_drive(Drive("short", track_drive.fs_hz,
                      {c: x[:n] for c, x in track_drive.channels.items()}), path,
                units="imperial")
    return path


def _without_units_column(src, dst):
    """Copy CSV file `src` to `dst` without its last column, ``units``, text kept as is."""
    lines = src.read_text().splitlines()
    assert lines[0].endswith(",units")
    dst.write_text("".join(line.rsplit(",", 1)[0] + "\n" for line in lines))


def _rank_argv(drive, out, *extra):
    from planner.demo import DEMO_LIBRARY_PATH

    return ["-q", "rank", "--model", "paper", "--drive", str(drive), "--shocks",
            str(DEMO_LIBRARY_PATH), "--only", "B20,L12,L28,DM,TD", "--simulate", "4",
            "--no-uncertainty", *extra, "--out", str(out)]


def _ranking_lines(text):
    """What rank printed, without the line of written paths (which name --out)."""
    return [line for line in text.splitlines() if not line.startswith("wrote ")]


def test_rank_gives_one_ranking_with_or_without_units(tmp_path, capsys, track_drive):
    """Issue 23's Done-when on a short imperial drive: ``rank`` with and without
    ``--units imperial`` gives the same ranking (the file's 'units' column stands in for
    the option, and the outputs are in its units); with the column cut off and no --units,
    it stops with exit 2 naming --units imperial and writes nothing; --units SI against
    the line is an error naming the file and both unit systems."""
    drive = _short_imperial_drive(track_drive, tmp_path / "track.csv")
    assert main(_rank_argv(drive, tmp_path / "with", "--units", "imperial")) == 0
    said_with = capsys.readouterr().out
    assert main(_rank_argv(drive, tmp_path / "without")) == 0
    said_without = capsys.readouterr().out
    ranking = (tmp_path / "with" / "ranking.csv").read_bytes()
    assert ranking.split(b"\n", 2)[1].endswith(b",imperial")
    assert (tmp_path / "without" / "ranking.csv").read_bytes() == ranking
    assert _ranking_lines(said_without) == _ranking_lines(said_with)
    assert "best:" in said_with
    # the marker cut off: values nobody says the units of, implausible as SI
    bare = tmp_path / "bare.csv"
    _without_units_column(drive, bare)
    assert main(_rank_argv(bare, tmp_path / "bare_out")) == 2
    err = capsys.readouterr().err
    assert err.startswith("shockplan: error: drive file ") and "bare.csv" in err
    assert "--units imperial" in err and err.count("\n") == 1
    assert not (tmp_path / "bare_out").exists()
    assert main(_rank_argv(bare, tmp_path / "bare_imperial", "--units", "imperial")) == 0
    assert (tmp_path / "bare_imperial" / "ranking.csv").read_bytes() == ranking
    capsys.readouterr()
    # a contradiction: one line naming the file, both systems and the fix
    assert main(_rank_argv(drive, tmp_path / "si", "--units", "si")) == 2
    err = capsys.readouterr().err
    assert "track.csv" in err and "imperial" in err and "--units says SI" in err
    assert "drop --units" in err and err.count("\n") == 1
    assert not (tmp_path / "si").exists()


def test_export_drive_takes_the_drive_files_units(tmp_path, track_drive):
    drive = _short_imperial_drive(track_drive, tmp_path / "track.csv", seconds=5.0)
    argv = ["-q", "export-drive", str(drive), "--format", "rpc3"]
    assert main(argv + ["--out", str(tmp_path / "a.drv")]) == 0
    assert main(argv + ["--units", "imperial", "--out", str(tmp_path / "b.drv")]) == 0
    from ident.data.formats.rpc3 import read_rpc3

    a, b = read_rpc3(tmp_path / "a.drv"), read_rpc3(tmp_path / "b.drv")
    for name in a.channels:
        np.testing.assert_array_equal(a.channels[name], b.channels[name])


def test_units_help_states_the_drive_files_default():
    for path, sub in _commands(build_parser()):
        if path[0] in DRIVE_COMMANDS:
            action = sub._option_string_actions["--units"]
            assert action.default is None, path
            assert "the drive file's own, from its 'units' column, else SI" in action.help \
                or "each drive file's own, from its 'units' column, else SI" in action.help, path


# --- One vocabulary across commands (issue 23, item 3) ---------------------------------

def _parsers(parser, path=()):
    """Every parser under `parser` (itself included) with its command path, e.g.
    ``(("rig", "simulate"), <parser>)``."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, path + (name,))


def _commands(parser):
    """The leaf commands: (path, parser) of every parser without commands of its own."""
    return [(path, p) for path, p in _parsers(parser)
            if path and not any(isinstance(a, argparse._SubParsersAction) for a in p._actions)]


def _required_argv(parser):
    """Placeholder arguments that satisfy `parser`'s positionals and required options."""
    argv = []
    for a in parser._actions:
        if not a.option_strings:
            argv.append("1")
        elif a.required:
            argv += [a.option_strings[-1], next(iter(a.choices)) if a.choices else "1"]
    for group in parser._mutually_exclusive_groups:
        if group.required:
            argv += [group._group_actions[0].option_strings[-1], "1"]
    return argv


def test_the_walk_finds_every_command():
    assert {" ".join(path) for path, _ in _commands(build_parser())} == {
        "demo", "rig simulate", "identify", "predict", "rank", "optimize", "plan", "whatif",
        "sweep", "import", "export-drive", "vehicle modes", "dyno import", "dyno table",
        "dyno check", "drive from-track", "drive iterate", "drive section", "drive resample"}


@pytest.mark.parametrize("given, canonical", [
    ("SI", "SI"), ("si", "SI"), ("Si", "SI"),
    ("imperial", "imperial"), ("Imperial", "imperial"), ("IMPERIAL", "imperial")])
def test_units_in_any_case_become_the_canonical_name(given, canonical):
    """Every command's --units takes any case and hands the library "SI" or "imperial"."""
    parser = build_parser()
    with_units = [(path, sub) for path, sub in _commands(parser)
                  if "--units" in sub._option_string_actions]
    assert len(with_units) == 17  # drive resample is the 17th (issue 36)
    for path, sub in with_units:
        args = parser.parse_args([*path, *_required_argv(sub), "--units", given])
        assert args.units == canonical, path


def test_units_unknown_is_refused_with_the_names(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["vehicle", "modes", "--units", "metric"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'metric'" in err and "'SI', 'imperial'" in err


def test_units_case_changes_no_output(capsys):
    """The modes printed with --units IMPERIAL are those of --units imperial, and not those
    of SI: the canonical name reached the unit conversion."""
    argv = ["vehicle", "modes", "--damping", "20", "--units"]
    assert main(argv + ["imperial"]) == 0
    canonical = capsys.readouterr().out
    assert main(argv + ["IMPERIAL"]) == 0
    assert capsys.readouterr().out == canonical
    assert main(argv + ["si"]) == 0
    assert capsys.readouterr().out != canonical


@pytest.mark.parametrize("flag, dest", [("-q", "quiet"), ("--quiet", "quiet"),
                                        ("-v", "verbose"), ("--verbose", "verbose")])
def test_quiet_and_verbose_before_or_after_the_command(flag, dest):
    """-q/-v before the command, right after it or at the end: the same flag; and a command
    never resets the top level's (``-q rank ...`` stays quiet)."""
    parser = build_parser()
    for path, sub in _commands(parser):
        req = _required_argv(sub)
        assert getattr(parser.parse_args([*path, *req]), dest) is False, path
        for argv in ([flag, *path, *req], [*path, flag, *req], [*path, *req, flag]):
            assert getattr(parser.parse_args(argv), dest) is True, argv
    assert getattr(parser.parse_args(["rig", flag, "simulate", "--out", "o"]), dest) is True


def test_version_prints_the_version_and_exits_zero(capsys):
    """``shockplan --version`` (issue 36): ``shockplan <version>`` on stdout, exit status 0;
    the installed distribution's version, the package's ``__version__`` without one."""
    from importlib import metadata

    import planner
    from planner.cli import common

    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    out = capsys.readouterr()
    assert out.out == f"shockplan {metadata.version('shockplan')}\n" and out.err == ""
    assert common.package_version() == planner.__version__ == ident.__version__

    def missing(name):
        raise metadata.PackageNotFoundError(name)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(metadata, "version", missing)
        assert common.package_version() == planner.__version__


def test_optimize_messages_name_the_options_and_say_each_score_once():
    """optimize's summary (issue 36): the library's "raise max_iter" reads "raise --max-iter";
    the scan's line names the best linear score once when the best curve is linear."""
    from planner.cli.optimize import cli_wording, scan_line

    warning = ("optimize: IPOPT stopped with status 'Maximum_Iterations_Exceeded' after 80 "
               "iterations; the best verified iterate is returned (score 0.9285): raise "
               "max_iter, or check the constraints")
    assert cli_wording(warning).endswith("raise --max-iter, or check the constraints")
    assert "max_iter" not in cli_wording(warning)
    scan = {"n_screened": 120, "n_verified": 16, "linear_score": 0.9285, "best": "linear",
            "score": 0.9285, "screen_s": 1.0, "verify_s": 2.0}
    line = scan_line(scan, "IPOPT's solution")
    assert line.count("0.9285") == 1 and "best linear 0.9285, best linear" not in line
    assert "a linear curve" in line
    line = scan_line(dict(scan, best="two-slope", score=0.9102), "the scan's best curve")
    assert "best linear 0.9285, best two-slope 0.9102 (3.0 s)" in line


class _Stream:
    def __init__(self, tty):
        self.tty = tty

    def isatty(self):
        return self.tty

    def write(self, text):
        return len(text)

    def flush(self):
        pass


@pytest.mark.parametrize("quiet, tty, shown", [(False, True, True), (False, False, False),
                                               (True, True, False), (True, False, False)])
def test_progress_bars_only_on_a_terminal(monkeypatch, quiet, tty, shown):
    """Progress bars unless -q, and only when stderr (where tqdm draws) is a terminal: a log
    file gets none (issue 36)."""
    from planner.cli.common import show_progress

    monkeypatch.setattr("sys.stderr", _Stream(tty))
    args = build_parser().parse_args(["-q", "vehicle", "modes"] if quiet else
                                     ["vehicle", "modes"])
    assert show_progress(args) is shown


def test_every_command_decides_progress_bars_in_one_place():
    """No command passes ``progress=not args.quiet``: every one asks show_progress."""
    folder = Path(__file__).resolve().parents[1] / "planner" / "cli"
    calls = 0
    for path in folder.glob("*.py"):
        text = path.read_text()
        assert "not args.quiet" not in text, path.name
        calls += text.count("progress=show_progress(args)")
    assert calls >= 7  # demo, rig, predict, rank, optimize, whatif, sweep


def test_grouped_flags_equals_form_and_negative_values_still_parse():
    parser = build_parser()
    args = parser.parse_args(["vehicle", "modes", "-qv", "--damping=-5", "--units", "si"])
    assert args.quiet and args.verbose and args.damping == -5.0 and args.units == "SI"
    assert parser.parse_args(["vehicle", "modes", "--damping", "-0.5"]).damping == -0.5


@pytest.mark.parametrize("argv, prog, typo, meant", [
    (["rank", "--shock", "crate.toml"], "shockplan rank", "--shock", "--shocks"),
    (["rank", "--unit", "si"], "shockplan rank", "--unit", "--units"),
    (["predict", "--modle", "paper"], "shockplan predict", "--modle", "--model"),
    (["sweep", "--simulate-shar", "0.1"], "shockplan sweep", "--simulate-shar", "--simulate-share"),
    (["rig", "simulate", "--durtion", "10"], "shockplan rig simulate", "--durtion",
     "--duration"),
    (["vehicle", "modes", "--damp", "20"], "shockplan vehicle modes", "--damp", "--damping"),
    (["vehicle", "modes", "--dampnig=20"], "shockplan vehicle modes", "--dampnig",
     "--damping"),
    (["--quite", "vehicle", "modes"], "shockplan", "--quite", "--quiet"),
    (["rnk", "--model", "paper"], "shockplan", "rnk", "rank"),
    (["rig", "simulat"], "shockplan rig", "simulat", "simulate"),
    (["vehicle", "mode"], "shockplan vehicle", "mode", "modes"),
])
def test_a_typo_names_the_nearest_valid_spelling(argv, prog, typo, meant, capsys):
    """A misspelled or abbreviated option (or command) of that command: exit status 2 and one
    line naming it and the nearest valid one, before argparse reports missing options."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"{prog}: error: "), err
    assert repr(typo) in err, err
    assert re.search(rf"did you mean {re.escape(meant)}[ ?]", err), err


@pytest.mark.parametrize("argv, old, new", [
    (["rank", "--top", "5"], "--top", "--simulate"),
    (["sweep", "--top", "5"], "--top", "--simulate"),
    (["sweep", "--top-share", "0.1"], "--top-share", "--simulate-share"),
    (["plan", "--rig", "rig.toml"], "--rig", "--rig-costs"),
])
def test_a_renamed_option_is_refused_with_its_new_name(argv, old, new, capsys):
    """One name, one meaning (issue 23): rank's and sweep's --top (simulate this many) and
    plan's --rig (a TOML of times) were renamed; the old spelling is refused, never taken."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and repr(old) in err and f"renamed {new} " in err, err


@pytest.mark.parametrize("argv, option, bound", [
    (["rank", "--simulate", "0"], "--simulate", ">= 1"),
    (["sweep", "--simulate", "-3"], "--simulate", ">= 1"),
    (["sweep", "--simulate-share", "2"], "--simulate-share", "(0, 1]"),
    (["identify", "s", "--out", "m.npz", "--max-order", "1"], "--max-order", ">= 2"),
    (["identify", "s", "--out", "m.npz", "--max-order", "ten"], "--max-order", ">= 2"),
])
def test_new_counts_are_refused_out_of_range_before_any_work(argv, option, bound, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"argument {option}" in err and bound in err, err


def test_one_option_name_means_one_thing_across_commands():
    """--top is whatif's only (setups taken from a ranking); --rig is 'rig simulate''s only
    (the rig kind); rank and sweep simulate --simulate setups."""
    assert _action(["whatif"], "--top") is not None
    assert _action(["rig", "simulate"], "--rig") is not None
    for cmd in (["rank"], ["sweep"], ["plan"], ["predict"], ["optimize"]):
        assert _action(cmd, "--top") is None and _action(cmd, "--rig") is None, cmd
    assert "time domain" in _action(["rank"], "--simulate").help
    assert "time domain" in _action(["sweep"], "--simulate").help


def test_an_option_before_its_command_says_where_it_goes(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--units", "SI", "vehicle", "modes"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "did you mean" not in err
    assert "it is an option of" in err and "vehicle modes" in err and "rank" in err
    assert "write it after the command" in err


def test_an_option_with_nothing_close_points_to_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["vehicle", "modes", "--shocks", "crate.toml"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err == ("shockplan vehicle modes: error: unrecognized option '--shocks'; see "
                   "'shockplan vehicle modes --help' for the options\n")


#: Options without a default: the command needs one of each pair (plan: --vehicle, or
#: --model with --session; whatif: --setups or --ranking).
NO_DEFAULT = {("plan", "--vehicle"), ("plan", "--model"), ("plan", "--session"),
              ("whatif", "--setups"), ("whatif", "--ranking")}


def test_every_option_has_help():
    """Every action of every parser but --help has a help text, every command a help line,
    and every help formats (no stray %)."""
    for path, parser in _parsers(build_parser()):
        parser.format_help()
        for a in parser._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            assert a.help and a.help is not argparse.SUPPRESS and a.help.strip(), \
                (path, a.option_strings or a.dest)
            if isinstance(a, argparse._SubParsersAction):
                for choice in a._choices_actions:
                    assert choice.help and choice.help.strip(), (path, choice.dest)


def test_every_optional_value_states_its_default():
    """An option that takes a value and may be left out says what happens then; one with a
    default value names that value."""
    checked = 0
    for path, parser in _parsers(build_parser()):
        for a in parser._actions:
            if not a.option_strings or a.required or a.nargs == 0:
                continue  # positionals, required options, flags (off unless given)
            key = (" ".join(path), a.option_strings[-1])
            if key in NO_DEFAULT:
                assert a.default is None, key
                continue
            assert "default" in a.help, key
            if a.default is not None:
                assert "%(default)s" in a.help or str(a.default) in a.help, key
            checked += 1
    assert checked >= 80  # every command's (80 when written)


def _action(path, option):
    parser = dict(_parsers(build_parser()))[tuple(path)]
    return parser._option_string_actions.get(option)


def test_rank_symmetry_and_axles_state_their_default():
    for option, default in (("--symmetry", "left-right"), ("--axles", "independent")):
        a = _action(["rank"], option)
        assert a.default == default and f"({default}, default)" in a.help


@pytest.mark.parametrize("path, option, unit", [
    (["rig", "simulate"], "--duration", "[s]"),
    (["plan"], "--budget-min", "[min]"),
    (["plan"], "--rig-costs", "[min]"),
    (["identify"], "--nperseg", "[samples]"),
    (["vehicle", "modes"], "--damping", "[N/(m/s), or lbf/(in/s) with --units imperial]"),
])
def test_physical_options_state_their_unit(path, option, unit):
    assert unit in _action(path, option).help


def test_help_defaults_are_what_runs():
    """The defaults stated in words are the library's: the rig simulated without --rig (a
    plan that names none, as the built-in one: 7-post), the built-in plan's units and
    duration, the rig swap time, the what-if tolerances."""
    import dataclasses

    from ident.sim.virtual_rig import RigPlan, default_plan
    from planner.rig_spec import default_rig
    from planner.whatif import FRAGILE_SHARE, RANK_TOLERANCE

    plan = default_plan()
    field_default = {f.name: f.default for f in dataclasses.fields(RigPlan)}["rig"]
    rig_help = _action(["rig", "simulate"], "--rig").help
    assert plan.rig == field_default == "7-post"
    assert f"{plan.rig} for the built-in plan and for a plan that names none" in rig_help
    assert "(default)" not in rig_help
    assert f"{plan.units} for the built-in plan" in _action(["rig", "simulate"], "--units").help
    assert f"{plan.runs[0].duration_s:g} s in the built-in plan" in \
        _action(["rig", "simulate"], "--duration").help
    assert f"{default_rig().swap_min:g} min a changed corner" in _action(["plan"], "--rig-costs").help
    assert f"(default {RANK_TOLERANCE})" in _action(["whatif"], "--rank-tolerance").help
    assert f"(default {FRAGILE_SHARE})" in _action(["whatif"], "--fragile-share").help


PAPER_SHOCKS = Path(ident.__file__).parent / "examples" / "paper_shocks.toml"


def test_rig_simulate_prints_the_sample_count_of_every_run(tmp_path, capsys):
    """Runs of different lengths: the printed count is per run and in all, not the first
    run's (issue 23: "12000 samples" for a plan whose second run has 36000)."""
    base = '{ LF = "B20", RF = "B20", LR = "B20", RR = "B20" }'
    swap = '{ LF = "N8", RF = "B20", LR = "B20", RR = "B20" }'
    plan = tmp_path / "plan.toml"
    plan.write_text(
        f'format = "rig-plan/1"\nname = "two lengths"\nshock_library = "{PAPER_SHOCKS.as_posix()}"\n'
        f'fs_hz = 100.0\noversample = 2\n'
        f'[[run]]\nname = "short"\nsetup = {base}\nrole = "baseline"\nduration_s = 10.0\n'
        f'[[run]]\nname = "long"\nsetup = {swap}\nrole = "swap"\nduration_s = 30.0\n')
    assert main(["-q", "rig", "simulate", "--plan", str(plan), "--out", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert "2 runs, 1000-3000 samples per run (4000 in all) at 100 Hz" in out
    assert main(["-q", "rig", "simulate", "--duration", "10", "--out", str(tmp_path / "d")]) == 0
    assert "runs, 1000 samples each at 100 Hz" in capsys.readouterr().out


def test_rank_writes_histograms_and_scores_a_logged_one(tmp_path, capsys, track_drive,
                                                        paper_vehicle, demo_library):
    """Issue 39: rank writes histograms.csv (1 in/s bins in an imperial project) and the
    summaries; with --log each setup's distance from the logged histogram, which the
    objective weights."""
    import pandas as pd

    from ident.data.channels import CORNERS
    from ident.data.tracklog import write_track_log
    from ident.models.vehicle import build_full_car
    from ident.sim.virtual_track import log_track_run, make_track_run
    from planner.objective import default_objective, objective_to_toml, Objective
    from planner.setups import Setup

    drive = _short_imperial_drive(track_drive, tmp_path / "track.csv")
    run = make_track_run(duration_s=20.0, fs_hz=100.0, seed=5,
                         wheelbase_m=paper_vehicle.a_m + paper_vehicle.b_m,
                         track_width_m=paper_vehicle.track_front_m)
    log = log_track_run(build_full_car(paper_vehicle).loop_plant(), run,
                        Setup("t", {c: "DM" for c in CORNERS}).resolve(demo_library))
    write_track_log(log, tmp_path / "log.csv", units="imperial")
    base = default_objective()
    objective_to_toml(Objective("near the log", {**base.weights, "histogram_distance_LF": 0.5},
                                groups=dict(base.groups)), tmp_path / "obj.toml")
    assert main(_rank_argv(drive, tmp_path / "r", "--log", str(tmp_path / "log.csv"),
                           "--objective", str(tmp_path / "obj.toml"))) == 0
    assert "histograms.csv" in capsys.readouterr().out
    ranking = pd.read_csv(tmp_path / "r" / "ranking.csv")
    for kind in ("share_low_speed", "bump_rebound_ratio", "histogram_distance"):
        assert ranking[[f"{kind}_{c}" for c in CORNERS]].notna().all().all(), kind
    assert ranking["histogram_distance_LF"].between(0, 1).all()
    hist = pd.read_csv(tmp_path / "r" / "histograms.csv")
    assert hist.setup.drop_duplicates().tolist() == ranking.setup.tolist()
    lf = hist[(hist.setup == ranking.setup[0]) & (hist.corner == "LF")]
    assert lf.velocity_hi.iloc[:-1].tolist() == list(np.arange(-10.0, 11.0))
    assert set(hist.units) == {"imperial"}
    # --histogram-bins none: no histograms, no summaries
    assert main(_rank_argv(drive, tmp_path / "n", "--histogram-bins", "none")) == 0
    assert not (tmp_path / "n" / "histograms.csv").exists()
    assert "share_low_speed_LF" not in pd.read_csv(tmp_path / "n" / "ranking.csv")


def test_plan_without_drives_writes_in_the_crates_units(tmp_path):
    """Issue 36: a plan with no drive and no --units takes its project's unit system from the
    crate (an imperial crate: an imperial plan.toml and run sheet), not SI."""
    from ident.models.library import read_shock_library, write_shock_library
    from planner.demo import DEMO_LIBRARY_PATH

    crate = tmp_path / "crate.toml"
    write_shock_library(read_shock_library(DEMO_LIBRARY_PATH), crate, units="imperial")
    code = main(["plan", "--vehicle", "paper", "--shocks", str(crate), "--budget-min", "30",
                 "--baseline", "B20", "--out", str(tmp_path / "plan")])
    assert code == 0
    assert 'units = "imperial"' in (tmp_path / "plan" / "plan.toml").read_text()


PROTO = Path(__file__).resolve().parents[1] / "ident" / "examples"


@pytest.mark.parametrize("extra, match", [
    ([], r"proto_car.toml: third_elements declares heave_front, heave_rear, roll_front but "
         r"the baseline's dampers of heave_front, heave_rear, roll_front are not given; name "
         r"each with --third"),
    (["--third", "heave_front=H0,heave_rear=H0"], "dampers of roll_front are not given"),
    (["--third", "heave_front=H0,heave_rear=H0,roll_front=R0", "--third", "roll_rear=R1"],
     "--third roll_rear: .*proto_car.toml does not declare roll_rear in third_elements"),
    (["--third", "heave_front=H0,heave_rear=HX,roll_front=R0"],
     "third heave_rear = 'HX' is not in the shock library --shocks .*proto_shocks.toml"),
    (["--third", "heave_front=H0,heave_rear=H0,roll_front=R0", "--heave-springs",
      "front=HS-F"], "--heave-springs: .* give the bump-stop library TOML with --bump-stops"),
    (["--third", "heave_front=H0,heave_rear=H0,roll_front=R0", "--heave-springs",
      "front=HS-X", "--bump-stops", str(PROTO / "proto_bumpstops.toml")], "HS-X"),
    (["--third", "heave_front"], "--third 'heave_front': write KEY=VALUE pairs"),
])
def test_plan_vehicle_with_third_elements_refusals(tmp_path, capsys, extra, match):
    """plan --vehicle on a vehicle TOML declaring third_elements: the baseline's dampers are
    given with --third (each declared element), the heave springs with --heave-springs and
    --bump-stops; anything else is refused in one line naming the file, field and fix."""
    code = main(["plan", "--vehicle", str(PROTO / "proto_car.toml"), "--shocks",
                 str(PROTO / "proto_shocks.toml"), "--budget-min", "30", "--baseline", "C2",
                 "--out", str(tmp_path / "plan"), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and re.search(match, err[0]), err
    assert not (tmp_path / "plan").exists()


def test_plan_third_options_need_a_vehicle_with_third_elements(tmp_path, capsys):
    code = main(["plan", "--vehicle", "paper", "--shocks", str(PROTO / "proto_shocks.toml"),
                 "--budget-min", "30", "--baseline", "C2", "--third", "heave_front=H0",
                 "--out", str(tmp_path / "plan")])
    assert code != 0
    assert "the paper car: no third_elements; --third" in capsys.readouterr().err


@pytest.mark.slow
def test_plan_vehicle_with_third_elements(tmp_path):
    """plan --vehicle with the baseline's third elements: the rig plan declares them, every
    run fits them (a --try-heave swap its own), the heave springs' library is written beside
    it, and the virtual rig reads the plan back."""
    import tomllib

    from ident.sim.virtual_rig import read_rig_plan

    out = tmp_path / "plan"
    code = main(["plan", "--vehicle", str(PROTO / "proto_car.toml"), "--shocks",
                 str(PROTO / "proto_shocks.toml"), "--budget-min", "30", "--baseline", "C2",
                 "--third", "heave_front=H0,heave_rear=H0", "--third", "roll_front=R0",
                 "--heave-springs", "front=HS-F,rear=HS-R", "--heave-packers", "front=1mm",
                 "--bump-stops", str(PROTO / "proto_bumpstops.toml"),
                 "--out", str(out)])
    assert code == 0
    doc = tomllib.loads((out / "plan.toml").read_text())
    assert doc["third_elements"] == {"heave_front": 1.0, "heave_rear": 1.1, "roll_front": 0.8}
    assert doc["bump_stop_library"] == "bumpstops.toml" and (out / "bumpstops.toml").exists()
    for run in doc["run"]:
        assert run["third"] == {"heave_front": "H0", "heave_rear": "H0", "roll_front": "R0"}
        assert run["heave_springs"] == {"front": "HS-F", "rear": "HS-R"}
        assert run["heave_packers"] == {"front": pytest.approx(0.001)}
    back = read_rig_plan(out / "plan.toml")
    assert all(dict(r.heave_springs) == {"front": "HS-F", "rear": "HS-R"} for r in back.runs)


def test_free_third_option_is_read_and_checked():
    """``optimize --free-third``: element names, comma-separated; an unknown one refused in
    one line naming the option and the elements."""
    from planner.cli.optimize import free_third_arg

    assert free_third_arg(None) == ()
    assert free_third_arg("heave_front, heave_rear") == ("heave_front", "heave_rear")
    with pytest.raises(ValueError, match=r"--free-third 'heave_middle'.*heave_front"):
        free_third_arg("heave_middle")


def test_optimize_reads_the_third_element_choices():
    """``optimize --try-heave front=H1,H2 --try-roll front=none``: the crate's third-element
    choices, read as rank reads them (``vary_third``)."""
    from planner.cli import build_parser
    from planner.cli.common import element_choices

    args = build_parser().parse_args(
        ["optimize", "--model", "m.npz", "--drive", "d.csv", "--shocks", "s.toml",
         "--out", "o", "--try-heave", "front=H1,H2", "--try-roll", "front=none"])
    assert element_choices(args) == {"vary_third": {"heave_front": ["H1", "H2"],
                                                    "roll_front": ["none"]}}
