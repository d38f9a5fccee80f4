"""Tests of planner.cli: the shockplan command line."""

import numpy as np
import pytest

from ident.session import read_session
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


def test_rig_simulate_bad_plan(tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text('format = "nope"\n')
    assert main(["-q", "rig", "simulate", "--plan", str(plan), "--out", str(tmp_path / "o")]) == 2
    assert "format" in capsys.readouterr().err


def test_vehicle_modes(capsys):
    assert main(["vehicle", "modes", "--damping", "20", "--units", "imperial"]) == 0
    out = capsys.readouterr().out
    assert "hop_LF" in out and "heave" in out


@pytest.mark.slow
def test_demo(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["-q", "demo", "--out", str(out)]) == 0
    assert (out / "session" / "session.toml").is_file()
    assert (out / "session_metrics.csv").is_file()
    assert "shockplan demo" in capsys.readouterr().out
