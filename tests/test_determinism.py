"""Byte-identical reruns: the same inputs give the same CSV and TOML bytes, and the same xlsx
cell values, from every command that writes them (issue 13)."""

import hashlib
import textwrap
from pathlib import Path

import pytest

from planner.cli import main
from planner.demo import DEMO_LIBRARY_PATH

#: Files compared byte for byte; xlsx files are compared cell by cell (their zip holds
#: creation times).
BYTE_SUFFIXES = (".csv", ".toml")


def _digest(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _cells(path):
    from openpyxl import load_workbook

    wb = load_workbook(path)
    return {ws.title: [[c.value for c in row] for row in ws.iter_rows()] for ws in wb.worksheets}


def _assert_same_outputs(a, b):
    files_a = sorted(p.relative_to(a) for p in Path(a).rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in Path(b).rglob("*") if p.is_file())
    assert files_a == files_b
    compared = 0
    for rel in files_a:
        if rel.suffix in BYTE_SUFFIXES:
            assert _digest(Path(a) / rel) == _digest(Path(b) / rel), rel
            compared += 1
        elif rel.suffix == ".xlsx":
            assert _cells(Path(a) / rel) == _cells(Path(b) / rel), rel
            compared += 1
    assert compared, "nothing compared"


def _twice(tmp_path, args):
    outs = []
    for k in (1, 2):
        out = tmp_path / f"out{k}"
        assert main(["-q"] + args + ["--out", str(out)]) == 0
        outs.append(out)
    _assert_same_outputs(*outs)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, track_drive):
    """A 20 s imperial drive, a ranking CSV and a perturbation file."""
    from ident.data.drive import Drive, write_drive

    d = tmp_path_factory.mktemp("inputs")
    n = int(20 * track_drive.fs_hz)
    write_drive(Drive("short", track_drive.fs_hz,
                      {c: x[:n] for c, x in track_drive.channels.items()}),
                d / "drive.csv", units="imperial")
    (d / "setups.csv").write_text(
        "setup,LF,RF,LR,RR\nbaseline,B20,B20,B20,B20\nsoft,L12,L12,L12,L12\n"
        "firm,L28,L28,L28,L28\nmixed,L28,L28,DM,DM\n")
    (d / "perturb.toml").write_text(textwrap.dedent("""
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
    return d


def test_rig_simulate_is_byte_identical(tmp_path):
    _twice(tmp_path, ["rig", "simulate", "--duration", "10", "--noise", "0.01"])


def test_predict_and_rank_are_byte_identical(tmp_path, inputs):
    common = ["--model", "paper", "--drive", str(inputs / "drive.csv"), "--shocks",
              str(DEMO_LIBRARY_PATH), "--units", "imperial"]
    for k in (1, 2):
        (tmp_path / f"p{k}").mkdir()
        assert main(["-q", "predict"] + common + ["--setups", str(inputs / "setups.csv"),
                                                  "--out", str(tmp_path / f"p{k}" / "p.csv")]) == 0
    _assert_same_outputs(tmp_path / "p1", tmp_path / "p2")
    _twice(tmp_path / "rank", ["rank"] + common + ["--symmetry", "left-right"])


@pytest.mark.slow
@pytest.mark.heavy
def test_whatif_and_plan_are_byte_identical(tmp_path, inputs):
    _twice(tmp_path / "whatif", [
        "whatif", "--model", "paper", "--drive", str(inputs / "drive.csv"), "--shocks",
        str(DEMO_LIBRARY_PATH), "--setups", str(inputs / "setups.csv"), "--perturb",
        str(inputs / "perturb.toml"), "--units", "imperial", "--method", "screening"])
    _twice(tmp_path / "plan", ["plan", "--vehicle", "paper", "--shocks", str(DEMO_LIBRARY_PATH),
                               "--budget-min", "30", "--baseline", "B20"])


@pytest.mark.slow
def test_optimize_is_byte_identical(tmp_path, inputs):
    """IPOPT from the same start on the same problem: the same curves, tables and history
    (wall times are logged, not written)."""
    _twice(tmp_path, ["optimize", "--model", "paper", "--drive", str(inputs / "drive.csv"),
                      "--shocks", str(DEMO_LIBRARY_PATH), "--baseline", "B20", "--units",
                      "imperial", "--max-iter", "3"])
