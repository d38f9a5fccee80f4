"""Tests of planner.cli: the shockplan command line."""

import numpy as np
import pytest

from ident.data.session import read_session
from planner.cli import main


def test_rig_simulate_writes_a_session(tmp_path, capsys):
    out = tmp_path / "sess"
    assert main(["-q", "rig", "simulate", "--duration", "10", "--out", str(out)]) == 0
    s = read_session(out)
    assert [r.name for r in s.runs][:2] == ["baseline", "swap-LF"]
    assert s.runs[0].n_samples == 1000 and s.units == "imperial"
    assert "wrote rig session" in capsys.readouterr().out
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
    assert f"shocks {s.damping_n_s_m[0]:.1f} N/(m/s)" in lines[0]
    assert lines[1].split() == ["mode", "undamped", "Hz", "damped", "Hz", "zeta"]
    rows = [line.split() for line in lines[3:]]
    assert [r[0] for r in rows] == list(s.labels)
    printed = np.array([[float(x) for x in r[1:]] for r in rows])
    expected = np.column_stack([s.undamped_hz, s.damped_hz, s.damping_ratio])
    np.testing.assert_allclose(printed, expected, rtol=0, atol=ATOL_PRINTED_3_DECIMALS)


#: The demo's best setup. Its defaults fix it: the paper's car and identification
#: experiment (seeded noise), the seed-7 track drive of 120 s, the built-in crate, the B20
#: baseline and the default objective.
DEMO_BEST = "L28/L28/L28/L28"


@pytest.mark.slow
def test_demo(tmp_path, capsys):
    """The demo's files and what they say: the ranking screened every left/right-symmetric
    setup the crate can build, its columns, its best setup (by the ranking rule, and the
    known one), the baseline's score; the optimizer's figures printed are those of its
    workbook, and its setup file names the optimal shocks."""
    import re

    import pandas as pd
    from openpyxl import load_workbook

    from ident.data.channels import CORNERS
    from ident.models.library import read_shock_library
    from ident.sim.metrics import METRIC_NAMES
    from planner.demo import DEMO_LIBRARY_PATH
    from planner.objective import default_objective, ranking_order
    from planner.setups import enumerate_setups, read_setups

    out = tmp_path / "demo"
    assert main(["-q", "demo", "--out", str(out)]) == 0
    assert (out / "session" / "session.toml").is_file()
    assert (out / "model.npz").is_file() and any((out / "frf_plots").glob("*.png"))
    for name in ("ranking.csv", "ranking.xlsx", "pareto.png", "top_setups.png", "screening.csv"):
        assert (out / "ranking" / name).is_file(), name
    for name in ("optimal_shocks.toml", "optimal_setup.csv", "optimize.xlsx", "curves.png",
                 "convergence.csv"):
        assert (out / "optimize" / name).is_file(), name
    text = capsys.readouterr().out
    assert "shockplan demo" in text and "best:" in text
    assert "optimized curves" in text and "better" in text
    assert str(out) in text and ".demo." not in text  # final paths, not the temporary folder
    # the ranking: every setup of the crate's left/right-symmetric enumeration screened
    library = read_shock_library(DEMO_LIBRARY_PATH)
    screening = pd.read_csv(out / "ranking" / "screening.csv")
    assert sorted(screening["setup"]) == sorted(s.name for s in enumerate_setups(library))
    ranking = pd.read_csv(out / "ranking" / "ranking.csv", keep_default_na=False)
    assert list(ranking.columns) == [
        "rank", "setup", *CORNERS, *METRIC_NAMES, "score", "score_grip", "score_platform",
        "feasible", "violations", "screening_rank", "unresolved",
        *(f"{m}{s}" for m in METRIC_NAMES for s in ("_lo", "_hi"))]
    # its best setup: first by the ranking rule, the known one, the one printed
    feasible = ranking["feasible"].to_numpy(dtype=bool)
    score = ranking["score"].to_numpy(dtype=float)
    assert ranking_order(feasible, score)[0] == 0 and ranking["rank"].iloc[0] == 1
    assert feasible[0] and ranking["setup"].iloc[0] == DEMO_BEST
    assert f"best: {DEMO_BEST} (score {score[0]:.4f} vs baseline" in text
    base = ranking.set_index("setup").loc["B20/B20/B20/B20"]  # the baseline, B20 all round
    assert base["score"] == pytest.approx(default_objective().total_weight, rel=1e-12)
    # the optimizer: the printed figures are its workbook's, its setup the optimal shocks
    said = re.search(r"optimized curves \(front, rear\): the optimum \(([\d.]+)\) is "
                     r"([\d.]+) % better than the crate's best (\S+) \(([\d.]+)\)", text)
    assert said is not None, text
    solver = dict(load_workbook(out / "optimize" / "optimize.xlsx")["solver"].iter_rows(
        values_only=True))
    assert said.group(1) == f"{solver['optimum score (time domain)']:.4f}"
    assert f"{said.group(2)} %" == solver["gain over the crate best"]
    assert said.group(3) == solver["crate best"]
    assert said.group(4) == f"{solver['crate best score']:.4f}"
    assert float(said.group(1)) < float(said.group(4))
    optimal = read_setups(out / "optimize" / "optimal_setup.csv")
    assert optimal[0].ids() == ("OPT-front", "OPT-front", "OPT-rear", "OPT-rear")


def _small_session(tmp_path):
    out = tmp_path / "sess"
    assert main(["-q", "rig", "simulate", "--duration", "120", "--out", str(out),
                 "--units", "SI"]) == 0
    return out


@pytest.mark.slow
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
    noise = loaded.settings["noise"]
    assert set(noise["expected_metric_error_pct"]) >= {"tire_force_rms_LF", "ride_height_rms_rear"}
    assert noise["reference"] == {"run": "baseline", "setup": "B20/B20/B20/B20"}
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

    table = pd.read_csv(pred)
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
                         read_setups(tmp_path / "setups.csv", lib), lib, oversample=2).table
    ref = ranking_to_units(ref, "imperial")
    for c in ("LF", "RF", "LR", "RR"):
        np.testing.assert_allclose(table[f"tire_force_rms_{c}"].to_numpy(),
                                   ref[f"tire_force_rms_{c}"].to_numpy(),
                                   rtol=RTOL_CLI_VS_LIBRARY, atol=0)
    rank_dir = tmp_path / "rank"
    assert main(["-q", "rank", "--model", "paper", "--drive", str(tmp_path / "drive.csv"),
                 "--shocks", str(tmp_path / "shocks.toml"), "--units", "imperial",
                 "--only", "B20,L12,L28,DM", "--baseline", "B20", "--top", "6",
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
