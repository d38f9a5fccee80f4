"""Tests of planner.cli.dyno (with planner.report.dyno):
``shockplan dyno table`` and ``shockplan dyno check`` end to end."""

import numpy as np
import pandas as pd
import pytest

from ident.data.files import read_csv_table
from ident.models.library import read_shock_library
from ident.sim.dampers import ClickerDamper
from planner.cli import main
from planner.dyno.check import FORCE_DECIMALS, dyno_curve

#: The dyno's speeds [m/s], each side.
DYNO_SPEEDS = (0.01, 0.025, 0.05, 0.1, 0.2, 0.3, 0.5)
#: The CSV holds the shortest text that reads back every float: equal to the bit.
CSV_RTOL = 0.0

TRUTH = ClickerDamper()
LIBRARY_TOML = """units = "SI"
[[shock]]
id = "B20"
kind = "linear"
damping = 3500.0
[[shock]]
id = "TTX"
kind = "adjustable"
adjusters = { ls = [0, 20], hs = [0, 4] }
default = { ls = 8, hs = 2 }
stiffer = { ls = "lower", hs = "lower" }
step = { hs = 0.25 }
dyno = "ttx.csv"
"""


def write_library(folder, *, bad=False):
    folder.mkdir(parents=True, exist_ok=True)
    sheet = TRUTH.dyno_sheet(TRUTH.sweep_settings(), DYNO_SPEEDS)
    if bad:   # a wrong-sign force at row 18, and ls=4 softer than ls=8 (lower is stiffer)
        sheet.loc[17, "force"] *= -1
        sheet.loc[(sheet.ls == 4) & (sheet.hs == 2), "force"] *= 0.8
    sheet.to_csv(folder / "ttx.csv", index=False)
    (folder / "shocks.toml").write_text(LIBRARY_TOML)
    return folder / "shocks.toml"


@pytest.fixture(scope="module")
def good_lib(tmp_path_factory):
    return write_library(tmp_path_factory.mktemp("good"))


@pytest.fixture(scope="module")
def checked(tmp_path_factory, good_lib):
    """Both checks run once: (exit status, printed text, folder) per library."""
    import contextlib
    import io

    out = {}
    for name, lib in (("good", good_lib),
                      ("bad", write_library(tmp_path_factory.mktemp("bad"), bad=True))):
        folder = lib.parent / "check"
        text = io.StringIO()
        with contextlib.redirect_stdout(text):
            rc = main(["dyno", "check", str(lib), "--out", str(folder)])
        out[name] = (rc, text.getvalue(), folder)
    return out


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_table_writes_the_model_at_the_setting(tmp_path, capsys, good_lib, units):
    path = tmp_path / "curve.csv"
    argv = ["dyno", "table", str(good_lib), "--shock", "TTX@ls=10,hs=1.5", "--units", units,
            "--out", str(path)]
    assert main(argv) == 0
    assert "TTX@ls=10,hs=1.5: 15 velocities" in capsys.readouterr().out
    frame, marker = read_csv_table(path)
    assert marker == units and list(frame.columns) == ["velocity", "force"]
    lib = read_shock_library(good_lib)
    want = dyno_curve(lib, "TTX@ls=10,hs=1.5", units=units)
    np.testing.assert_allclose(frame["velocity"], want.velocity, rtol=CSV_RTOL)
    np.testing.assert_allclose(frame["force"], want.force, rtol=CSV_RTOL)
    at = lib.adjustable("TTX").at({"ls": 10, "hs": 1.5})
    scale_v, scale_f = (1.0, 1.0) if units == "SI" else (0.0254, 4.4482216152605)
    # the model at the written velocities, the force to the 0.1 N or 0.1 lbf written
    np.testing.assert_allclose(frame["force"], at.force(frame["velocity"] * scale_v) / scale_f,
                               rtol=0, atol=0.5 * 10.0 ** -FORCE_DECIMALS + 1e-9)
    assert "0000000" not in path.read_text()  # numbers as they mean (issue 36)
    # refused without --overwrite, replaced with it
    assert main(argv) == 2 and "already exists" in capsys.readouterr().err
    argv[argv.index("TTX@ls=10,hs=1.5")] = "TTX@ls=2"
    assert main(argv + ["--overwrite", "--velocity=-0.7,0.05"]) == 0
    said = capsys.readouterr().out
    assert "TTX@ls=2,hs=2: 2 velocities" in said
    assert ("1 velocity is beyond the dyno's measured speeds" in said) == (units == "SI")
    assert read_csv_table(path)[0]["velocity"].tolist() == [-0.7, 0.05]


def test_table_errors(tmp_path, capsys, good_lib):
    base = ["dyno", "table", str(good_lib), "--out", str(tmp_path / "c.csv")]
    assert main(base + ["--shock", "TTX@ls=30"]) == 2
    assert "outside its range [0, 20]" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(base + ["--shock", "TTX", "--velocity", "0.1,x"])
    assert exc.value.code == 2 and "'x' is not a number" in capsys.readouterr().err
    assert not (tmp_path / "c.csv").exists()


def test_check_good_library(checked):
    rc, text, folder = checked["good"]
    assert rc == 0 and "0 error(s), 0 warning(s)" in text
    names = sorted(p.name for p in folder.iterdir())
    assert names == ["TTX.curves.png", "TTX.fit.csv", "TTX.worst.csv", "findings.csv",
                     "summary.md"]
    fit, marker = read_csv_table(folder / "TTX.fit.csv")
    assert marker == "SI" and len(fit) == 10 * 2 * len(DYNO_SPEEDS)
    worst = read_csv_table(folder / "TTX.worst.csv")[0]
    assert worst["setting"].tolist()[:2] == ["TTX@ls=0,hs=2", "TTX@ls=4,hs=2"]
    summary = (folder / "summary.md").read_text()
    assert "no errors" in summary and "| TTX@ls=8,hs=4 | 14 |" in summary
    assert (folder / "TTX.curves.png").read_bytes()[:4] == b"\x89PNG"
    assert read_csv_table(folder / "findings.csv")[0].empty


def test_check_bad_sheet(checked):
    rc, text, folder = checked["bad"]
    assert rc == 1 and "3 error(s), 0 warning(s)" in text
    lines = [ln for ln in text.splitlines() if ln.strip().startswith("error:")]
    assert len(lines) == 3
    assert "ttx.csv row 18: force" in lines[0] and "wrong sign" in lines[0]
    assert {ln.split("ttx.csv row ")[1].split(":")[0] for ln in lines[1:]} == {"15", "28"}
    assert all("the curve at TTX@ls=4,hs=2 is" in ln and "softer than at TTX@ls=8,hs=2" in ln
               and "(the curves cross)" in ln for ln in lines[1:])
    findings = read_csv_table(folder / "findings.csv")[0]
    assert findings["severity"].tolist() == ["error"] * 3
    assert findings["row"].str.endswith(("row 18", "row 28", "row 15")).all()
    assert sorted(p.name for p in folder.iterdir()) == ["TTX.curves.png", "findings.csv",
                                                       "summary.md"]
    summary = (folder / "summary.md").read_text()
    assert "NO MODEL" in summary and "cannot be read" in summary
    assert summary.count("- **error**") == 3


def test_check_refuses_a_full_folder(checked, capsys, good_lib):
    folder = checked["good"][2]
    assert main(["dyno", "check", str(good_lib), "--out", str(folder)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert isinstance(pd.read_csv(folder / "TTX.worst.csv"), pd.DataFrame)
