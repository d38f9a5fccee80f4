"""Tests of planner.sweep: the lazy setup space against enumerate_setups, bounded memory,
the Dask sweep against the single-process path (bit for bit), chunking invariance,
agreement with screen_setups / predict_setups / rank_setups, several cases, bad options
and schedulers, the files (planner.report.sweep_files) and the command line."""

import math
import re
import tomllib
import tracemalloc
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from ident.data.channels import CORNERS
from planner.errors import PlannerError
from planner import runner as runner_mod
from planner.objective import score_setups
from planner.predict import predict_setups
from planner.rank import rank_setups
from planner.screen import screen_setups
from planner.report.sweep_files import (MAX_STEM_CHARS, case_file_name, case_file_names, name_stem,
                                  write_sweep)
from planner.setups import Setup, enumerate_setups, setup_space
from planner.sweep import RTOL_SCORE_ROUNDOFF, sweep_setups
from planner.options import RunOptions

# the drive's rig response is computed with one BLAS thread in a sweep, with all in
# predict_setups: the last bits of the metrics differ (measured 3e-13 relative)
RTOL_BLAS_THREADS = 1e-11
# 30^4 candidates decoded 10,000 at a time: a chunk's arrays are about 1 MB, all of them
# at once 810,000 x 4 codes = 26 MB (plus the index)
CHUNK = 10_000
MAX_CHUNKED_PEAK_BYTES = 8 * 2**20
CRATE_10 = ["B20", "L12", "L28", "DS", "DM", "DF", "RB", "BB", "BO", "TD"]  # 10^4 setups
TEN_THOUSAND = {"symmetry": "none", "shocks": CRATE_10, "respect_inventory": False}


def _crate(n):
    from ident.models.library import ShockLibrary
    from ident.models.shocks import LinearShock

    return ShockLibrary.from_models([LinearShock(f"S{k}", 500.0 * k, count=3)
                                     for k in range(1, n + 1)])


def _frames_identical(a, b):
    pd.testing.assert_frame_equal(a, b, check_exact=True)


# ---------------------------------------------------------------- the space of setups


@pytest.mark.parametrize("constraints", [
    {},
    {"symmetry": "none"},
    {"symmetry": "none", "respect_inventory": False},
    {"axles": "same"},
    {"symmetry": "none", "axles": "same"},
    {"fixed": {"LR": "B20"}, "shocks": {"front": ["DS", "L12", "B20"]}},
    {"symmetry": "none", "shocks": {"LF": ["RB", "BB"], "rear": ["RB", "BB", "TD"]}},
    {"name_format": "LF={LF} RF={RF} LR={LR} RR={RR}"},
])
def test_space_decodes_the_enumeration(demo_library, constraints):
    """Decoded in chunks, a space gives enumerate_setups' setups: same order, names, ids."""
    expected = enumerate_setups(demo_library, max_setups=None, **constraints)
    space = setup_space(demo_library, **constraints)
    parts = [space.chunk(a, a + 1000) for a in range(0, len(space), 1000)]
    index = np.concatenate([p[0] for p in parts])
    assert space.names(index) == [s.name for s in expected]
    assert space.ids(index) == [s.ids() for s in expected]
    assert space.setups(index) == tuple(expected)


def test_space_find_and_listed_setups(demo_library, baseline_setup):
    space = setup_space(demo_library, symmetry="none")
    idx = space.find(("DS", "DS", "B20", "TD"))
    assert space.names([idx]) == ["DS/DS/B20/TD"]
    assert space.find(("RB", "RB", "RB", "B20")) is None  # count 2: skipped
    assert space.find(("XX", "B20", "B20", "B20")) is None
    listed = setup_space(demo_library, setups=[baseline_setup, Setup("x", dict(
        LF="DS", RF="DS", LR="B20", RR="B20"))])
    assert len(listed) == 2 and listed.find(("DS", "DS", "B20", "B20")) == 1
    assert listed.names([1, 0]) == ["x", "baseline"]


def test_space_generation_is_memory_bounded():
    """A 30-shock crate's 810,000 four-corner setups decoded chunk by chunk: the peak is one
    chunk's, not the enumeration's (no Setup objects, no full code array)."""
    space = setup_space(_crate(30), symmetry="none", respect_inventory=False)
    assert len(space) == 30**4
    tracemalloc.start()
    try:
        n = 0
        last = -1
        for a in range(0, len(space), CHUNK):
            index, codes = space.chunk(a, a + CHUNK)
            assert codes.shape == (index.size, 4) and index[0] == last + 1
            n += index.size
            last = int(index[-1])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert n == 30**4 and last == 30**4 - 1
    assert peak < MAX_CHUNKED_PEAK_BYTES, f"peak {peak / 2**20:.1f} MiB"
    assert space.names([809_999]) == ["S30/S30/S30/S30"]


# ---------------------------------------------------------------- Dask = one process


@pytest.fixture(scope="module")
def single(paper_model, track_drive, demo_library):
    """10,000 setups (every 4-corner combination of 10 shocks), one process."""
    return sweep_setups(paper_model, track_drive, demo_library, constraints=TEN_THOUSAND,
                        run=RunOptions(scheduler="none"), progress=False)


def test_dask_sweep_equals_single_process(single, paper_model, track_drive, demo_library):
    """A LocalCluster of 2 worker processes gives the same ranking and the same numbers, bit
    for bit, as one process (other chunk size too)."""
    dask = sweep_setups(paper_model, track_drive, demo_library, constraints=TEN_THOUSAND,
                        run=RunOptions(scheduler="local", n_workers=2, chunk_size=1500),
                        progress=False)
    assert single.settings["n_screened"] == dask.settings["n_screened"] == 10_000
    assert dask.settings["scheduler"] == "local" and dask.settings["n_workers"] == 2
    assert single.table.index.tolist() == dask.table.index.tolist()
    _frames_identical(single.table, dask.table)
    for label in single.cases:
        _frames_identical(single.cases[label], dask.cases[label])
        _frames_identical(single.screening_top[label], dask.screening_top[label])
    assert_array_equal(single.screening_index, dask.screening_index)
    assert_array_equal(single.screening_score, dask.screening_score)
    assert_array_equal(single.screening_feasible, dask.screening_feasible)


@pytest.mark.parametrize("chunk_size", [997, 4096])
def test_chunking_does_not_change_results(single, paper_model, track_drive, demo_library,
                                          chunk_size):
    other = sweep_setups(paper_model, track_drive, demo_library, constraints=TEN_THOUSAND,
                         run=RunOptions(scheduler="none", chunk_size=chunk_size, simulate_chunk=7),
                         progress=False)
    _frames_identical(single.table, other.table)
    assert_array_equal(single.screening_score, other.screening_score)


def test_existing_cluster_by_client_and_address(paper_model, track_drive, demo_library):
    """An existing cluster (thread workers in this process), given as a client or by its
    scheduler's address, gives the one-process results."""
    from distributed import Client, LocalCluster

    constraints = {"shocks": CRATE_10}
    ref = sweep_setups(paper_model, track_drive, demo_library, constraints=constraints,
                       top=8, run=RunOptions(scheduler="none"), progress=False)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        got = sweep_setups(paper_model, track_drive, demo_library, constraints=constraints,
                           top=8, run=RunOptions(client=client, chunk_size=9), progress=False)
        by_address = sweep_setups(paper_model, track_drive, demo_library,
                                  constraints=constraints, top=8,
                                  run=RunOptions(scheduler=cluster.scheduler_address),
                                  progress=False)
    assert got.settings["scheduler"] == "client"
    assert by_address.settings["scheduler"] == "address"
    assert by_address.settings["address"] == cluster.scheduler_address
    _frames_identical(ref.table, got.table)
    _frames_identical(ref.table, by_address.table)


def test_best_share_is_simulated(single):
    st = single.settings
    assert st["n_top"] == math.ceil(0.01 * 10_000) == 100
    t = single.table
    assert len(t) == 101  # the best 1 % and the baseline B20/B20/B20/B20 (first setup)
    assert single.baseline == "B20/B20/B20/B20" and single.baseline in t.index
    assert t["rank"].tolist() == list(range(1, 102))
    assert sorted(t["screening_rank"].tolist())[:100] == list(range(1, 101))
    best = single.screening_order(100)
    assert set(single.space.names(best)) <= set(t.index)
    assert st["screen_setups_per_s"] > 0 and st["simulate_setups_per_s"] > 0


# ---------------------------------------------------------------- agreement with the engines


def test_agrees_with_screen_predict_and_rank(paper_model, track_drive, demo_library,
                                             baseline_setup):
    """On a list of setups: screening metrics equal screen_setups' bit for bit, scores
    score_setups' to round-off, time-domain metrics predict_setups' to the BLAS round-off,
    and the ranking equals rank_setups' (same simulated setups)."""
    setups = [baseline_setup] + list(enumerate_setups(demo_library)[::4])
    n_top = 6
    res = sweep_setups(paper_model, track_drive, demo_library, setups=setups, top=n_top,
                       baseline="baseline", run=RunOptions(scheduler="none"), progress=False)
    label = next(iter(res.cases))
    scr = screen_setups(paper_model, track_drive, setups, demo_library)
    st = res.screening_top[label]
    metrics = scr.metric_names
    assert_array_equal(st[metrics].to_numpy(), scr.table.loc[st.index, metrics].to_numpy())
    ref_scores = score_setups(scr.table, baseline="baseline").table
    assert_allclose(res.screening_score, ref_scores["score"].to_numpy(),
                    rtol=RTOL_SCORE_ROUNDOFF)
    sim = [s for s in setups if s.name in res.table.index]
    td = predict_setups(paper_model, track_drive, sim, demo_library).table
    got = res.cases[label].loc[td.index, metrics]
    assert_allclose(got.to_numpy(), td[metrics].to_numpy(), rtol=RTOL_BLAS_THREADS)
    ranking = rank_setups(paper_model, track_drive, demo_library, setups=setups, top=n_top,
                          n_check=0, baseline="baseline", uncertainty=False)
    assert ranking.table.index.tolist() == res.table.index.tolist()
    assert_allclose(res.table["score"], ranking.table["score"], rtol=RTOL_BLAS_THREADS)


def test_several_drives_and_models_combine(paper_vehicle, track_drive, demo_library):
    """Two models x two drives = four cases; the sweep score is the mean (or the largest) of
    the case scores, feasible only where every case is."""
    from dataclasses import replace

    from ident.data.drive import make_track_drive
    from ident.models.vehicle import build_full_car

    other = make_track_drive(duration_s=40.0, fs_hz=100.0, seed=11, name="track other",
                             wheelbase_m=paper_vehicle.a_m + paper_vehicle.b_m,
                             track_width_m=paper_vehicle.track_front_m)
    models = {"car": build_full_car(paper_vehicle),
              "heavy": build_full_car(replace(paper_vehicle,
                                              sprung_mass_kg=1.2 * paper_vehicle.sprung_mass_kg))}
    kw = dict(constraints={"shocks": ["B20", "L12", "L28", "DS", "DF"]}, top=5,
              run=RunOptions(scheduler="none"), progress=False)
    mean = sweep_setups(models, [track_drive, other], demo_library, **kw)
    worst = sweep_setups(models, [track_drive, other], demo_library, combine="worst", **kw)
    labels = mean.settings["cases"]
    assert len(labels) == 4 and labels[0] == "car | track test"
    assert mean.settings["models"] == ("car", "heavy")
    assert mean.settings["drives"] == ("track test", "track other")  # the drives' names
    assert list(case_file_names(mean).values()) == [
        "case-1-car-track-test.csv", "case-2-car-track-other.csv",
        "case-3-heavy-track-test.csv", "case-4-heavy-track-other.csv"]
    for res, combine in ((mean, np.mean), (worst, np.max)):
        cols = [f"score@{lab}" for lab in labels]
        assert_allclose(res.table["score"], combine(res.table[cols].to_numpy(), axis=1),
                        rtol=RTOL_SCORE_ROUNDOFF)
        feas = np.logical_and.reduce([res.cases[lab]["feasible"].loc[res.table.index]
                                      for lab in labels])
        assert_array_equal(res.table["feasible"].to_numpy(), feas)


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize("kwargs, error, match", [
    ({"scheduler": "nonsense"}, PlannerError, "neither 'local', 'none' nor a scheduler"),
    ({"scheduler": 3}, TypeError, "scheduler must be"),
    ({"top_share": 0.0}, PlannerError, "top_share"),
    ({"top": 0}, PlannerError, "top=0"),
    ({"combine": "best"}, PlannerError, "combine='best'"),
    ({"chunk_size": 0}, PlannerError, "chunk_size=0"),
    ({"baseline": "nope"}, PlannerError, "baseline 'nope'"),
    ({"constraints": {"symmetry": "diagonal"}}, PlannerError, "symmetry='diagonal'"),
    ({"objective": "grip"}, TypeError, "Objective"),
])
def test_bad_options(paper_model, track_drive, demo_library, kwargs, error, match):
    run_keys = ("scheduler", "chunk_size")
    with pytest.raises(error, match=match):
        run = RunOptions(**{"scheduler": "none",
                            **{k: v for k, v in kwargs.items() if k in run_keys}})
        sweep_setups(paper_model, track_drive, demo_library, progress=False, run=run,
                     **{k: v for k, v in kwargs.items() if k not in run_keys})


def test_unreachable_scheduler_is_a_clear_error(paper_model, track_drive, demo_library,
                                                monkeypatch):
    monkeypatch.setattr(runner_mod, "CONNECT_TIMEOUT_S", 2.0)
    with pytest.raises(PlannerError, match=r"cannot reach the Dask scheduler at "
                       r"'tcp://127.0.0.1:9'.*dask scheduler"):
        sweep_setups(paper_model, track_drive, demo_library,
                     run=RunOptions(scheduler="tcp://127.0.0.1:9"),
                     progress=False)


# ---------------------------------------------------------------- the files

#: A case file's name: the case number, then a stem of portable characters that neither
#: starts nor ends with "-" or "." (no hidden file, no path).
SAFE_CASE_FILE = re.compile(r"case-[0-9]+(-[A-Za-z0-9_]([A-Za-z0-9._-]*[A-Za-z0-9_])?)?\.csv")


@pytest.mark.parametrize("models, drives, k, expected", [
    (["paper"], ["track.csv"], 1, "case-1-track.csv"),  # issue 23: was case-1-track.csv.csv
    (["paper"], ["runs/2026/track.csv"], 1, "case-1-track.csv"),
    (["paper"], ["C:\\data\\Bumps #3.PQ"], 1, "case-1-Bumps-3.csv"),
    (["paper"], ["track test"], 1, "case-1-track-test.csv"),  # a Drive's own name
    (["paper"], ["v1.2 run"], 1, "case-1-v1.2-run.csv"),  # only a reader's suffix goes
    (["paper"], ["../../etc/passwd"], 1, "case-1-passwd.csv"),
    (["paper"], ["???.csv"], 1, "case-1.csv"),
    (["paper"], [".hidden.csv"], 1, "case-1-hidden.csv"),
    (["paper"], ["x" * 100 + ".csv"], 1, "case-1-" + "x" * MAX_STEM_CHARS + ".csv"),
    (["models/car.npz", "heavy.TOML"], ["track.csv"], 2, "case-2-heavy.csv"),
    (["car.npz", "heavy.toml"], ["a.csv", "b.parquet"], 3, "case-3-heavy-a.csv"),
])
def test_case_file_name_from_stems(models, drives, k, expected):
    assert case_file_name(k, models, drives) == expected
    assert SAFE_CASE_FILE.fullmatch(expected)


def test_case_file_names_are_unique_and_safe():
    """Names that give the same stem, or differ only in case, still give distinct files
    (on a case-insensitive file system too); a bad case number is refused."""
    models = ["paper", "cars/paper.npz", "Paper.toml"]
    drives = ["a/track.csv", "b/track.csv", "Track.CSV", "track", "/", "ü ñ.csv"]
    labels = [f"{m} | {d}" for m in models for d in drives]
    files = case_file_names(SimpleNamespace(settings={"cases": tuple(labels),
                                                      "models": models, "drives": drives}))
    assert list(files) == labels
    assert len({f.lower() for f in files.values()}) == len(labels)
    assert all(SAFE_CASE_FILE.fullmatch(f) for f in files.values()), files
    assert name_stem("/") == "" and files[labels[4]] == "case-5-paper.csv"
    for k in (0, len(labels) + 1, True, 1.0):
        with pytest.raises(ValueError, match="case number"):
            case_file_name(k, models, drives)


def test_write_sweep(tmp_path, paper_model, track_drive, demo_library):
    """The drive given as ``runs/track.csv`` (the mapping key, as the command line passes
    it) names its case file ``case-1-track.csv``; sweep.toml points to it."""
    res = sweep_setups({"paper": paper_model}, {"runs/track.csv": track_drive}, demo_library,
                       constraints={"shocks": ["B20", "L12", "L28", "DS"]}, top=3,
                       run=RunOptions(scheduler="none"), progress=False)
    assert res.settings["models"] == ("paper",)
    assert res.settings["drives"] == ("runs/track.csv",)
    out = tmp_path / "out"
    written = write_sweep(res, out, units="imperial")
    assert [p.name for p in written] == ["ranking.csv", "case-1-track.csv", "sweep.toml"]
    assert sorted(p.name for p in out.iterdir()) == ["case-1-track.csv", "ranking.csv",
                                                     "sweep.toml"]
    summary = tomllib.loads((out / "sweep.toml").read_text())
    assert summary["cases"] == [{"label": "runs/track.csv", "file": "case-1-track.csv"}]
    assert summary["best"] == res.best and summary["n_simulated"] == len(res.table)
    assert len(pd.read_csv(out / "case-1-track.csv")) == len(res.table)
    with pytest.raises(FileExistsError):
        write_sweep(res, out)
    assert write_sweep(res, out, overwrite=True) == written


def test_sweep_histograms_are_predict_setups(tmp_path, paper_model, track_drive, demo_library):
    """Issue 39: the sweep's time-domain stage counts the histograms of predict_setups (a
    sample on a bin edge aside: the rig response's last bits differ with BLAS's threads),
    written beside the case file; an objective on a histogram summary screens without it."""
    from planner.histograms import HISTOGRAM_METRICS
    from planner.objective import Objective, default_objective
    from planner.options import HistogramOptions, LoopOptions

    base = default_objective()
    obj = Objective(base.name, dict(base.weights), groups=dict(base.groups),
                    limits={"bump_rebound_ratio_LF": {"max": 10.0}})
    res = sweep_setups({"paper": paper_model}, {"track.csv": track_drive}, demo_library,
                       constraints={"shocks": ["B20", "L12", "L28", "DS"]}, top=3,
                       objective=obj, run=RunOptions(scheduler="none"), progress=False)
    hist = res.histograms["track.csv"]
    assert hist.setups == tuple(res.table.index)
    case = res.cases["track.csv"]
    assert case[list(HISTOGRAM_METRICS)].notna().all().all()
    setups = [Setup(n, dict(zip(CORNERS, res.table.loc[n, list(CORNERS)])))
              for n in res.table.index]
    ref = predict_setups(paper_model, track_drive, setups, demo_library,
                         loop=LoopOptions(histograms=HistogramOptions())).histograms
    np.testing.assert_allclose(hist.shares, ref.shares, rtol=0,
                               atol=2.0 / track_drive.n_samples)
    written = write_sweep(res, tmp_path / "out")
    assert [p.name for p in written] == ["ranking.csv", "case-1-track.csv",
                                         "case-1-track_histograms.csv", "sweep.toml"]
    frame = pd.read_csv(tmp_path / "out" / "case-1-track_histograms.csv")
    assert len(frame) == len(res.table) * 4 * 22


# ---------------------------------------------------------------- command line


def test_cli_sweep_names_case_files_from_stems(tmp_path, track_drive, monkeypatch):
    from ident.data.drive import write_drive
    from planner.cli import main
    from planner.demo import DEMO_LIBRARY_PATH

    write_drive(track_drive, tmp_path / "track.csv")
    monkeypatch.chdir(tmp_path)  # the drive as a user names it: track.csv
    assert main(["-q", "sweep", "--model", "paper", "--drive", "track.csv", "--shocks",
                 str(DEMO_LIBRARY_PATH), "--only", "B20,L12", "--simulate", "2", "--scheduler",
                 "none", "--out", "sweep"]) == 0
    assert sorted(p.name for p in (tmp_path / "sweep").iterdir()) == [
        "case-1-track.csv", "case-1-track_histograms.csv", "ranking.csv", "sweep.toml"]


def test_cli_sweep(tmp_path, track_drive, capsys):
    from ident.data.drive import write_drive
    from planner.cli import main
    from planner.demo import DEMO_LIBRARY_PATH

    write_drive(track_drive, tmp_path / "drive.csv")
    out = tmp_path / "sweep"
    args = ["-q", "sweep", "--model", "paper", "--drive", str(tmp_path / "drive.csv"),
            "--shocks", str(DEMO_LIBRARY_PATH), "--only", "B20,L12,L28,DS",
            "--simulate", "4", "--scheduler", "none", "--out", str(out)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "screened 256 setups x 1 case(s)" in text and "scheduler none" in text
    assert (out / "ranking.csv").read_text().splitlines()[1].endswith(",SI")  # the drive's
    table = pd.read_csv(out / "ranking.csv")
    assert list(table.columns[:5]) == ["setup", *CORNERS] and len(table) == 5
    summary = tomllib.loads((out / "sweep.toml").read_text())
    assert summary["n_screened"] == 256 and summary["best"] == table["setup"][0]
    assert (out / summary["cases"][0]["file"]).is_file()
    assert main(args) == 2  # existing folder without --overwrite
    assert "already exists" in capsys.readouterr().err
    bad = args[:-4] + ["--scheduler", "nonsense", "--out", str(tmp_path / "o2")]
    assert main(bad) == 2
    err = capsys.readouterr().err
    assert err.startswith("shockplan: error: sweep: scheduler 'nonsense'")
    assert "Traceback" not in err


# ---------------------------------------------------------------- rank --scheduler


def test_screen_on_a_cluster_equals_screen_setups(paper_model, track_drive, demo_library):
    """``screen_setups_on`` (chunks on Dask workers, any chunk size) gives screen_setups'
    table bit for bit; ``rank_setups(scheduler=...)`` the same ranking."""
    from distributed import LocalCluster

    from planner.sweep import screen_setups_on

    setups = enumerate_setups(demo_library, symmetry="none", shocks=CRATE_10[:5],
                              respect_inventory=False)
    ref = screen_setups(paper_model, track_drive, setups, demo_library)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        got = screen_setups_on(paper_model, track_drive, setups, demo_library,
                               run=RunOptions(chunk_size=97, scheduler=cluster.scheduler_address))
        ranked = rank_setups(paper_model, track_drive, demo_library, setups=setups[:60],
                             top=6, n_check=4, uncertainty=False,
                             run=RunOptions(scheduler=cluster.scheduler_address))
    assert got.settings["scheduler"] == "address"
    _frames_identical(ref.table, got.table)
    assert_array_equal(ref.diagnostics["iterations"], got.diagnostics["iterations"])
    plain = rank_setups(paper_model, track_drive, demo_library, setups=setups[:60], top=6,
                        n_check=4, uncertainty=False)
    assert ranked.settings["scheduler"] == "address"
    _frames_identical(plain.table, ranked.table)
    _frames_identical(plain.screening, ranked.screening)
    with pytest.raises(PlannerError, match="chunk_size"):
        screen_setups_on(paper_model, track_drive, setups, demo_library,
                         run=RunOptions(chunk_size=0, scheduler="none"))


def test_cli_rank_scheduler(tmp_path, track_drive, capsys):
    """``rank --scheduler ADDRESS`` writes the ranking of the one-process command, byte for
    byte; a bad scheduler is one clear error line."""
    from distributed import LocalCluster

    from ident.data.drive import write_drive
    from planner.cli import main
    from planner.demo import DEMO_LIBRARY_PATH

    write_drive(track_drive, tmp_path / "drive.csv")
    args = ["-q", "rank", "--model", "paper", "--drive", str(tmp_path / "drive.csv"),
            "--shocks", str(DEMO_LIBRARY_PATH), "--only", "B20,L12,L28,DS", "--simulate", "5",
            "--no-uncertainty"]
    assert main(args + ["--out", str(tmp_path / "plain")]) == 0
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        assert main(args + ["--scheduler", cluster.scheduler_address,
                            "--out", str(tmp_path / "dask")]) == 0
    for name in ("ranking.csv", "screening.csv", "histograms.csv"):
        assert (tmp_path / "dask" / name).read_bytes() == (tmp_path / "plain" / name).read_bytes()
    capsys.readouterr()
    assert main(args + ["--scheduler", "nonsense", "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("shockplan: error: rank: scheduler 'nonsense'") and "Traceback" not in err
    assert not (tmp_path / "bad").exists()


def test_sweep_with_third_elements_ranks_as_rank(prototype_case, prototype_identified,
                                                  track_drive):
    """A car with third elements (the prototype, identified): the sweep screens every
    setup with each --try-heave choice and the car's heave and roll elements linearized, as
    rank does: the same candidates, the same screening scores (to round-off) and ranks, in
    chunks that split a setup's variants; the same simulated best and scores."""
    from planner.options import ElementOptions, LoopOptions

    library = prototype_case[1].shocks
    el = ElementOptions(vary_third={"heave_front": ["H1", "H2"]})
    loop = LoopOptions(oversample=1)
    res = sweep_setups(prototype_identified, track_drive, library, elements=el, loop=loop,
                       top=4, baseline="B20", progress=False,
                       run=RunOptions(scheduler="none", chunk_size=5))
    ranking = rank_setups(prototype_identified, track_drive, library, elements=el, loop=loop,
                          top=4, n_check=0, baseline="B20", uncertainty=False)
    names = res.space.names(res.screening_index)
    scr = ranking.screening
    assert sorted(names) == sorted(scr.index)  # heave dampers off the corners, H1 once
    assert any(n.endswith("heave_front=H2") for n in names)
    assert_allclose(res.screening_score, scr.loc[names, "score"].to_numpy(),
                    rtol=RTOL_SCORE_ROUNDOFF)
    order = [names[k] for k in np.argsort(res.screening_score, kind="stable")]
    assert order == scr.sort_values("score", kind="stable").index.tolist()
    assert res.best == ranking.best
    common = ranking.table.index.intersection(res.table.index)
    assert len(common) >= 4
    assert_allclose(res.table.loc[common, "score"], ranking.table.loc[common, "score"],
                    rtol=RTOL_BLAS_THREADS)
    assert set(res.table["heave_front"]) <= {"H1", "H2"}
