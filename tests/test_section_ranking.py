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
