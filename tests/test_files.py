"""Tests of ident.data.files: the CSV writers and the unit marker (issue 23, item 1)."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_array_equal

from ident.data.files import (
    csv_preamble,
    read_csv_after,
    read_csv_table,
    read_units_marker,
    resolve_units,
    units_marker,
    write_csv,
    write_csv_frame,
    write_parquet_frame,
)
from ident.errors import SessionError


def _frames():
    """A numeric frame (Arrow's fast writer) and a mixed one with an index (pandas')."""
    numeric = pd.DataFrame({"time": np.arange(5) / 100.0, "x": [0.1, -2.5, 1e-9, 3.0, 0.0]})
    mixed = pd.DataFrame({"score": [1.0, 0.97], "note": ["a, b", ""]},
                         index=pd.Index(["base", "soft"], name="setup"))
    return numeric, mixed


def test_csv_writer_reads_back_bit_for_bit(tmp_path):
    """Run CSVs are written by Arrow's writer: the marker, the header as pandas writes it,
    and every float (tiny, huge, negative zero, thirds) read back exactly."""
    rng = np.random.default_rng(7)
    x = rng.standard_normal(1000) * 10.0 ** rng.integers(-300, 300, 1000)
    x[:4] = (-0.0, 1.0 / 3.0, 5e-324, 1.7976931348623157e308)
    frame = pd.DataFrame({"time": np.arange(1000) / 100.0, "a,b": x, "c": -x})
    write_csv_frame(frame, tmp_path / "f.csv", units="SI")
    text = (tmp_path / "f.csv").read_text()
    assert text.splitlines()[:2] == ["# units: SI", 'time,"a,b",c']
    back = pd.read_csv(tmp_path / "f.csv", comment="#")
    for col in frame:
        assert_array_equal(back[col].to_numpy(), frame[col].to_numpy())
        assert np.array_equal(np.signbit(back[col].to_numpy()), np.signbit(frame[col].to_numpy()))


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_every_written_csv_starts_with_its_marker_and_pandas_reads_it(tmp_path, units):
    numeric, mixed = _frames()
    write_csv(tmp_path / "n.csv", numeric, units=units)
    write_csv(tmp_path / "m.csv", mixed, units=units, index=True, float_format="%.6g")
    write_csv(tmp_path / "t.csv", "setup,LF\na,B20\n", units=units.lower())
    for name in ("n.csv", "m.csv", "t.csv"):
        path = tmp_path / name
        assert path.read_text().splitlines()[0] == f"# units: {units}"  # one cell, no quotes
        assert read_units_marker(path) == units
        frame, marked = read_csv_table(path)
        assert marked == units
        assert frame.equals(pd.read_csv(path, comment="#"))
    assert_array_equal(pd.read_csv(tmp_path / "n.csv", comment="#").to_numpy(),
                       numeric.to_numpy())
    back = pd.read_csv(tmp_path / "m.csv", comment="#", index_col="setup",
                       keep_default_na=False)
    assert list(back.index) == ["base", "soft"] and back.loc["base", "note"] == "a, b"


def test_write_csv_is_atomic_and_refuses_to_overwrite(tmp_path):
    path = tmp_path / "x.csv"
    write_csv(path, "a\n1\n", units="SI", overwrite=False)
    with pytest.raises(FileExistsError, match="overwrite"):
        write_csv(path, "a\n2\n", units="SI", overwrite=False)
    with pytest.raises(ValueError, match="unknown unit system 'metric'"):
        write_csv(path, "a\n2\n", units="metric")
    assert path.read_text() == "# units: SI\na\n1\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.csv"]  # no temporary left


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_parquet_files_carry_the_marker_in_their_metadata(tmp_path, units):
    numeric, _ = _frames()
    path = tmp_path / "run.parquet"
    write_parquet_frame(numeric, path, units=units)
    assert read_units_marker(path) == units
    assert pd.read_parquet(path).equals(numeric)
    numeric.to_parquet(tmp_path / "bare.parquet", index=False)
    assert read_units_marker(tmp_path / "bare.parquet") is None


@pytest.mark.parametrize("text, units, n_lines", [
    ("time,x\n0,1\n", None, 0),
    ("# units: SI\ntime,x\n", "SI", 1),
    ("# units: imperial\ntime,x\n", "imperial", 1),
    ("# UNITS = Imperial\ntime,x\n", "imperial", 1),  # any case, '=' too
    ("# units: SI,,,,\ntime,x,y,z,w\n", "SI", 1),  # a spreadsheet's padded row
    ('"# units: imperial"\ntime,x\n', "imperial", 1),  # ... or quoted cell
    ("\ufeff# made by the rig PC\n\n# units: SI\n,,\ntime,x\n", "SI", 4),  # BOM, blanks
    ("# a note, not a marker\ntime,x\n", None, 1),
])
def test_csv_preamble(text, units, n_lines):
    assert csv_preamble(io.StringIO(text), where="f.csv") == (units, n_lines)


@pytest.mark.parametrize("text, match", [
    ("# units: metric\ntime\n", r"f.csv: line 1 .*unknown unit system 'metric'"),
    ("# units: SI\n# units: imperial\ntime\n",
     r"f.csv: lines 1-2 say both '# units: SI' and '# units: imperial'"),
])
def test_csv_preamble_refuses_a_bad_marker(text, match):
    with pytest.raises(SessionError, match=match):
        csv_preamble(io.StringIO(text), where="f.csv", error=SessionError)


def test_units_marker():
    assert units_marker("si") == "# units: SI"
    assert units_marker("IMPERIAL") == "# units: imperial"


@pytest.mark.parametrize("marked, given, expected", [
    (None, None, "SI"),  # neither: the rig-session spec's default
    (None, "imperial", "imperial"),
    ("imperial", None, "imperial"),  # the marker stands in for a missing --units
    ("imperial", "Imperial", "imperial"),
    ("SI", "si", "SI"),
])
def test_resolve_units(marked, given, expected):
    assert resolve_units(marked, given, where="d.csv") == expected


def test_resolve_units_refuses_a_contradiction_naming_file_both_systems_and_fix():
    with pytest.raises(SessionError) as exc:
        resolve_units("imperial", "SI", where="drive file d.csv", given_as="--units",
                      error=SessionError)
    text = str(exc.value)
    assert text.startswith("drive file d.csv: ")
    assert "imperial" in text and "--units says SI" in text
    assert "drop --units" in text and "'# units: SI'" in text
    with pytest.raises(SessionError, match="; set the manifest"):
        resolve_units("SI", "imperial", where="run 'a'", fix="set the manifest's units",
                      error=SessionError)


def test_a_quote_in_a_comment_line_opens_no_field(tmp_path):
    """pandas' own skiprows would parse the comment's quote as opening a field that runs
    to the end of the file."""
    path = tmp_path / "q.csv"
    path.write_text('# exported, "5 in pads\n# units: imperial\ntime,x\n0,1\n0.01,2\n')
    frame, units = read_csv_table(path)
    assert units == "imperial" and frame.to_dict("list") == {"time": [0.0, 0.01], "x": [1, 2]}
    assert read_csv_after(path, 2).equals(frame)


def test_read_csv_table_errors_name_the_file(tmp_path):
    path = tmp_path / "bin.csv"
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(SessionError, match="bin.csv: cannot read the file as CSV"):
        read_csv_table(path, error=SessionError)
    with pytest.raises(SessionError, match="bin.csv: cannot read the file"):
        read_units_marker(path, error=SessionError)
    (tmp_path / "nope.parquet").write_text("not parquet")
    with pytest.raises(SessionError, match="nope.parquet: cannot read the file"):
        read_units_marker(tmp_path / "nope.parquet", error=SessionError)
