"""The malformed-input corpus (issue 13): every case gives one clear error line.

The cases are generated from small valid files by ``tests/corpus/make_corpus.py``
(nothing stored); each runs through :func:`planner.cli.main` in-process and must end
with a non-zero exit and one ``shockplan: error:`` line, no traceback, naming the file
and the field, leave nothing at ``--out`` and change no input file.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import shutil
import sys
import tempfile
from pathlib import Path

import pandas as pd
import pytest

from planner.cli import main

_SPEC = importlib.util.spec_from_file_location(
    "make_corpus", Path(__file__).parent / "corpus" / "make_corpus.py")
make_corpus = importlib.util.module_from_spec(_SPEC)
sys.modules.setdefault("make_corpus", make_corpus)
_SPEC.loader.exec_module(make_corpus)

#: The issue asks for at least this many cases.
MIN_CASES = 60


def _state(path):
    """A hash of a file, or of every file under a folder (name -> digest)."""
    path = Path(path)
    if path.is_file():
        return {path.name: hashlib.sha256(path.read_bytes()).hexdigest()}
    if path.is_dir():
        return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(path.rglob("*")) if p.is_file()}
    return None


# Built once, at collection (the case names parametrize the test); removed at the end.
_ROOT = Path(tempfile.mkdtemp(prefix="shockplan-corpus-"))
_BASE = make_corpus.build_base(_ROOT / "base")
_CASES = {c.name: c for c in make_corpus.make_cases(_BASE, _ROOT / "cases")}
_CASE_NAMES = list(_CASES)


@pytest.fixture(scope="session")
def corpus():
    yield _BASE, _CASES
    make_corpus.release_read_only(_ROOT / "cases" / "_read_only")
    shutil.rmtree(_ROOT, ignore_errors=True)


def test_corpus_is_large_enough():
    groups = {n.split("/")[0] for n in _CASE_NAMES}
    assert len(_CASE_NAMES) >= MIN_CASES
    assert {"session", "run", "shocks", "setups", "drive", "objective", "model", "plan",
            "map", "out"} <= groups


@pytest.mark.parametrize("name", _CASE_NAMES)
def test_case_gives_one_clear_error(corpus, name, capsys):
    _, cases = corpus
    case = cases[name]
    before = {p: _state(p) for p in case.inputs}
    out_before = _state(case.out) if case.out else None
    code = main(list(case.argv))
    err = capsys.readouterr().err
    assert code != 0, f"{name}: exit code 0 (stderr {err!r})"
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.startswith("shockplan: error:")]
    assert len(lines) == 1, err
    line = lines[0]
    assert "allow_pickle" not in line and "pickle.load" not in line, line  # no unsafe advice
    for want in case.expect:
        assert want.lower() in line.lower(), f"{name}: {want!r} not in {line!r}"
    assert {p: _state(p) for p in case.inputs} == before, f"{name}: an input changed"
    if case.out:
        assert _state(case.out) == out_before, f"{name}: output left at {case.out}"
        parent = Path(case.out).parent
        if parent.is_dir():
            assert not [p for p in parent.iterdir() if p.name.startswith(".")
                        and p.name.endswith(".tmp")], f"{name}: temporary file left"


# --------------------------------------------------------------------------------------
# What the corpus found and that is not an error: converted, warned, marked infeasible
# --------------------------------------------------------------------------------------


def test_parquet_datetime_time_is_converted_to_seconds(corpus, tmp_path):
    from ident.data.drive import read_drive
    from ident.data.session import read_session

    base, _ = corpus
    folder = shutil.copytree(base["session_pq"], tmp_path / "s")
    run = folder / "runs" / "baseline.parquet"
    frame = pd.read_parquet(run)
    frame["time"] = pd.Timestamp("2024-05-01 10:00") + pd.to_timedelta(frame["time"], unit="s")
    frame.to_parquet(run, index=False)
    session = read_session(folder)
    assert session.fs_hz == pytest.approx(make_corpus.FS_HZ, rel=1e-9)
    assert session.run("baseline").time_s[0] == 0.0
    drive_file = tmp_path / "drive.parquet"
    frame = pd.read_parquet(base["drive_pq"])
    frame["time"] = pd.Timestamp("2024-05-01") + pd.to_timedelta(frame["time"], unit="s")
    frame.to_parquet(drive_file, index=False)
    assert read_drive(drive_file).fs_hz == pytest.approx(make_corpus.FS_HZ, rel=1e-9)


def test_drive_in_inches_read_as_si_warns(corpus, tmp_path, caplog):
    from ident.data.drive import read_drive

    base, _ = corpus
    frame = pd.read_csv(base["drive"]).drop(columns="units")  # units nobody states
    wl = [c for c in frame.columns if c.startswith("wheelloader")]
    frame[wl] = frame[wl] / 0.0254  # an inch file
    path = tmp_path / "drive_in.csv"
    frame.to_csv(path, index=False)
    with caplog.at_level(logging.WARNING, logger="ident.data.drive"):
        read_drive(path, units="SI")
    assert "--units imperial" in caplog.text and "drive_in.csv" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="ident.data.drive"):
        read_drive(path, units="imperial")
    assert caplog.text == ""


def test_unknown_manifest_key_without_near_miss_is_kept_with_a_warning(corpus, tmp_path,
                                                                       caplog):
    from ident.data.session import read_session

    base, _ = corpus
    folder = shutil.copytree(base["session"], tmp_path / "s")
    manifest = folder / "session.toml"
    manifest.write_text(manifest.read_text().replace('units = "SI"', 'units = "SI"\n'
                                                     'driver = "none"\nfs_hz = 100.0', 1))
    with caplog.at_level(logging.WARNING, logger="ident.data.session"):
        session = read_session(folder)
    assert session.extra == {"driver": "none", "fs_hz": 100.0}
    assert "'driver'" in caplog.text


def _crate_with_count(base, tmp_path, shock_id, count):
    text = base["shocks"].read_text()
    head = f'id = "{shock_id}"\n'
    i = text.index(head)
    j = text.index("count = ", i)
    k = text.index("\n", j)
    path = tmp_path / "crate.toml"
    path.write_text(text[:j] + f"count = {count}" + text[k:])
    return path


def test_rank_marks_setups_beyond_the_inventory_infeasible(corpus, tmp_path, capsys):
    base, _ = corpus
    crate = _crate_with_count(base, tmp_path, "L28", 2)
    out = tmp_path / "rank"
    code = main(["-q", "rank", "--model", "paper", "--drive", str(base["drive"]), "--shocks",
                 str(crate), "--setups", str(base["setups"]), "--out", str(out), "--simulate", "3",
                 "--no-uncertainty"])
    assert code == 0, capsys.readouterr().err
    table = pd.read_csv(out / "ranking.csv", index_col="setup")
    assert not table.loc["firm", "feasible"]
    assert "needs 4 x 'L28' but the library's count is 2" in table.loc["firm", "violations"]
    assert table.loc["firm", "rank"] == len(table)  # after every feasible setup


def test_predict_warns_about_the_inventory(corpus, tmp_path, caplog):
    base, _ = corpus
    crate = _crate_with_count(base, tmp_path, "L12", 0)
    with caplog.at_level(logging.WARNING, logger="shockplan"):
        code = main(["-q", "predict", "--model", "paper", "--drive", str(base["drive"]),
                     "--shocks", str(crate), "--setups", str(base["setups"]), "--out",
                     str(tmp_path / "p.csv")])
    assert code == 0
    assert "soft-front" in caplog.text and "count is 0" in caplog.text


def test_rank_baseline_reuses_the_listed_setup(corpus, tmp_path):
    base, _ = corpus
    out = tmp_path / "rank"
    code = main(["-q", "rank", "--model", "paper", "--drive", str(base["drive"]), "--shocks",
                 str(base["shocks"]), "--setups", str(base["setups"]), "--baseline", "B20",
                 "--out", str(out), "--simulate", "3", "--no-uncertainty"])
    assert code == 0
    table = pd.read_csv(out / "ranking.csv", index_col="setup")
    assert "baseline" not in table.index
    assert sorted(table.index) == ["all-B20", "firm", "soft-front"]
