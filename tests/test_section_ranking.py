"""Tests of planner.section_ranking: the whole drive's and each section's score per setup in
one table, equal to ``rank`` run on each section's drive file alone."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from ident.data.drive import read_drive, write_drive
from planner.errors import PlannerError
from planner.rank import rank_setups
from planner.section_ranking import SectionRanking, rank_sections, section_columns
from planner.setups import enumerate_setups
from planner.trackdrive import cut_sections, parse_sections

# The section's drive goes through a CSV file (shortest round-trip decimals, SI): the values
# read back are the same floats, so the scores agree to the simulation's round-off only.
RTOL_FILE = 1e-12
SECTIONS = parse_sections(["kerb=4:19", "braking=26.5:41"])


@pytest.fixture(scope="module")
def setups(demo_library, baseline_setup):
    return [baseline_setup] + list(enumerate_setups(demo_library)[::6])


@pytest.fixture(scope="module")
def sections(paper_model, track_drive, demo_library, setups):
    whole = rank_setups(paper_model, track_drive, demo_library, setups=setups,
                        top=len(setups), n_check=0, uncertainty=False)
    return rank_sections(whole, paper_model, track_drive, demo_library, sections=SECTIONS)


def test_table_holds_the_whole_drive_and_each_section(sections, setups):
    assert isinstance(sections, SectionRanking)
    t = sections.table
    assert len(t) == len(setups) and t["rank"].tolist() == list(range(1, len(t) + 1))
    for name, _, _ in SECTIONS:
        score, rank = section_columns(name)
        assert sorted(t[rank]) == list(range(1, len(t) + 1))
        assert sections.winners[name] == t[rank].idxmin()
        assert t.loc[sections.baseline, score] == pytest.approx(t.loc[sections.baseline,
                                                                         "score"])
    # the sections differ from the whole drive (else the test below could not fail)
    assert not np.allclose(t["kerb_score"], t["score"], rtol=1e-3)
    won = sections.section_winners()
    assert won == [(s, w) for s, w in sections.winners.items() if w != t.index[0]]
    text = sections.summary()
    assert "kerb" in text and "braking" in text
    for s, w in won:
        assert f"'{w}' wins section '{s}'" in text


def test_each_section_equals_rank_on_its_drive_file_alone(sections, paper_model, track_drive,
                                                          demo_library, setups, tmp_path):
    """The equivalence of the issue: cut each section to a drive file (as ``shockplan drive
    section`` does), read it back and rank it alone: every setup's score and rank equal the
    section's column."""
    for d, (name, _, _) in zip(cut_sections(track_drive, SECTIONS), SECTIONS):
        path = tmp_path / f"{name}.csv"
        write_drive(d, path, units="SI")
        alone = rank_setups(paper_model, read_drive(path), demo_library, setups=setups,
                            top=len(setups), n_check=0, uncertainty=False)
        score, rank = section_columns(name)
        t = sections.table
        assert_allclose(t[score].to_numpy(), alone.table.loc[t.index, "score"].to_numpy(),
                        rtol=RTOL_FILE)
        assert (t[rank] == alone.table.loc[t.index, "rank"]).all()
        assert sections.winners[name] == alone.best


def test_bad_sections(sections, paper_model, track_drive, demo_library):
    class Empty:
        candidates = ()

    with pytest.raises(PlannerError, match="no sections"):
        rank_sections(Empty(), paper_model, track_drive, demo_library, sections=[])
    with pytest.raises(PlannerError, match="no candidates"):
        rank_sections(Empty(), paper_model, track_drive, demo_library, sections=SECTIONS)


def test_rank_command_ranks_each_section(track_drive, setups, tmp_path, capsys):
    """``shockplan rank --section``: sections.csv (the whole drive's and each section's score
    and rank), the workbook's sheet 'sections', the winners in the printed summary; a window
    beyond the drive is refused before anything is simulated."""
    import pandas as pd
    from openpyxl import load_workbook

    from ident.data.drive import Drive
    from planner.cli import main
    from planner.demo import DEMO_LIBRARY_PATH
    from planner.setups import write_setups

    n = int(20 * track_drive.fs_hz)
    drive = Drive("track 20 s", track_drive.fs_hz,
                  {c: x[:n] for c, x in track_drive.channels.items()})
    write_drive(drive, tmp_path / "d.csv", units="SI")
    write_setups(setups[:4], tmp_path / "s.csv")
    args = ["-q", "rank", "--model", "paper", "--drive", str(tmp_path / "d.csv"), "--shocks",
            str(DEMO_LIBRARY_PATH), "--setups", str(tmp_path / "s.csv"), "--simulate", "4",
            "--no-uncertainty", "--section", "a=1:9", "--laps", "10,14,19.5"]
    assert main(args + ["--out", str(tmp_path / "r")]) == 0
    out = capsys.readouterr().out
    assert "sections: 3 (a 1-9 s, lap1 10-14 s, lap2 14-19.5 s)" in out
    t = pd.read_csv(tmp_path / "r" / "sections.csv")
    assert list(t.columns[:2]) == ["rank", "setup"] and t.columns[-1] == "units"
    for name in ("a", "lap1", "lap2"):
        assert sorted(t[f"{name}_rank"]) == [1, 2, 3, 4]
    wb = load_workbook(tmp_path / "r" / "ranking.xlsx")
    assert wb.sheetnames[:3] == ["summary", "ranking", "sections"]
    summary = " ".join(str(c.value) for row in wb["summary"].iter_rows() for c in row if c.value)
    assert "sections won by another setup" in summary
    assert main(args[:-4] + ["--section", "far=15:25", "--out", str(tmp_path / "x")]) == 2
    assert "beyond the drive" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
