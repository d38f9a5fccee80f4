"""Tests of ident.data.files: the CSV writers and the unit marker (issue 23, item 1; the
header first and a trailing ``units`` column: issue 36, item 1)."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_array_equal

from ident.data.files import (
    PNG_TEXT_KEY,
    atomic_write_toml,
    csv_preamble,
    png_metadata,
    read_toml,
    read_csv_after,
    read_csv_table,
    read_units_marker,
    resolve_units,
    units_marker,
    units_of_column,
    write_csv,
    write_csv_frame,
    write_parquet_frame,
)
from ident.models.library import read_shock_library, write_shock_library
from ident.errors import SessionError


def _frames():
    """A numeric frame (Arrow's fast writer) and a mixed one with an index (pandas')."""
    numeric = pd.DataFrame({"time": np.arange(5) / 100.0, "x": [0.1, -2.5, 1e-9, 3.0, 0.0]})
    mixed = pd.DataFrame({"score": [1.0, 0.97], "note": ["a, b", ""]},
                         index=pd.Index(["base", "soft"], name="setup"))
    return numeric, mixed


def test_csv_writer_reads_back_bit_for_bit(tmp_path):
    """Run CSVs are written by Arrow's writer: the header as pandas writes it first, the
    ``units`` column last, and every float (tiny, huge, negative zero, thirds) read back
    exactly by a plain ``pandas.read_csv``."""
    rng = np.random.default_rng(7)
    x = rng.standard_normal(1000) * 10.0 ** rng.integers(-300, 300, 1000)
    x[:4] = (-0.0, 1.0 / 3.0, 5e-324, 1.7976931348623157e308)
    frame = pd.DataFrame({"time": np.arange(1000) / 100.0, "a,b": x, "c": -x})
    write_csv_frame(frame, tmp_path / "f.csv", units="SI")
    text = (tmp_path / "f.csv").read_text()
    assert text.splitlines()[:2] == ['time,"a,b",c,units', "0,-0,0,SI"]
    back = pd.read_csv(tmp_path / "f.csv")
    assert list(back.columns) == ["time", "a,b", "c", "units"]
    assert (back["units"] == "SI").all()
    for col in frame:
        assert_array_equal(back[col].to_numpy(), frame[col].to_numpy())
        assert np.array_equal(np.signbit(back[col].to_numpy()), np.signbit(frame[col].to_numpy()))


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_every_written_csv_has_its_header_first_and_pandas_reads_it(tmp_path, units):
    """Every writer: the header is line 1, the last column ``units`` holds the unit system
    on every row (no quotes), and ``pandas.read_csv(path)`` without options reads the
    table; :func:`read_csv_table` returns it without the column, the unit system apart."""
    numeric, mixed = _frames()
    write_csv(tmp_path / "n.csv", numeric, units=units)
    write_csv(tmp_path / "m.csv", mixed, units=units, index=True, float_format="%.6g")
    write_csv(tmp_path / "t.csv", 'setup,LF\na,B20\n"b, c","x""y"\n', units=units.lower())
    headers = {"n.csv": "time,x,units", "m.csv": "setup,score,note,units",
               "t.csv": "setup,LF,units"}
    for name, header in headers.items():
        path = tmp_path / name
        lines = path.read_text().splitlines()
        assert lines[0] == header
        assert all(line.endswith(f",{units}") for line in lines[1:])  # one cell, no quotes
        assert read_units_marker(path) == units
        plain = pd.read_csv(path)
        assert list(plain.columns) == header.split(",") and (plain["units"] == units).all()
        frame, marked = read_csv_table(path)
        assert marked == units
        assert frame.equals(plain.drop(columns="units"))
    assert_array_equal(pd.read_csv(tmp_path / "n.csv").drop(columns="units").to_numpy(),
                       numeric.to_numpy())
    back = pd.read_csv(tmp_path / "m.csv", index_col="setup", keep_default_na=False)
    assert list(back.index) == ["base", "soft"] and back.loc["base", "note"] == "a, b"
    text = pd.read_csv(tmp_path / "t.csv")  # quoted fields of CSV text stay as they were
    assert text.to_dict("list") == {"setup": ["a", "b, c"], "LF": ["B20", 'x"y'],
                                    "units": [units] * 2}


def test_a_table_with_a_units_column_of_its_own_is_refused(tmp_path):
    with pytest.raises(ValueError, match="has a column 'units' already"):
        write_csv(tmp_path / "u.csv", pd.DataFrame({"units": ["mm"]}), units="SI")
    with pytest.raises(ValueError, match="has a column 'units' already"):
        write_csv(tmp_path / "u.csv", "a,units\n1,mm\n", units="SI")
    assert not (tmp_path / "u.csv").exists()


@pytest.mark.parametrize("text, units", [
    ("time,x,units\n0,1,SI\n1,2,SI\n", "SI"),
    ("time,x,units\n0,1,imperial\n1,2,Imperial\n", "imperial"),  # any case
    ("units,time,x\n imperial ,0,1\n", "imperial"),  # any position, spaces
    ("time,x,units\n", None),  # no rows: nothing said
    ("# units: imperial\ntime,x\n0,1\n", "imperial"),  # the earlier layout
    ("# units: imperial\ntime,x,units\n0,1,imperial\n", "imperial"),  # both, agreeing
    ("time,x\n0,1\n", None),  # neither
])
def test_the_units_column_and_the_marker_line_both_read(tmp_path, text, units):
    path = tmp_path / "f.csv"
    path.write_text(text)
    assert read_units_marker(path) == units
    frame, marked = read_csv_table(path)
    assert marked == units and list(frame.columns) == ["time", "x"]


@pytest.mark.parametrize("text, match", [
    ("# units: SI\ntime,x,units\n0,1,imperial\n",
     r"f.csv: the line '# units: SI' and the column 'units' \(imperial\) disagree; keep the "
     "one that is true"),
    ("time,x,units\n0,1,SI\n1,2,imperial\n",
     r"f.csv: column 'units' says both SI and imperial; a file is in one unit system"),
    ("time,x,units\n0,1,metric\n", r"f.csv: column 'units'.*unknown unit system 'metric'"),
])
def test_a_units_column_that_contradicts_is_refused(tmp_path, text, match):
    path = tmp_path / "f.csv"
    path.write_text(text)
    with pytest.raises(SessionError, match=match):
        read_csv_table(path, error=SessionError)
    with pytest.raises(SessionError, match=match):
        read_units_marker(path, error=SessionError)


def test_units_of_column():
    assert units_of_column(["SI", "", float("nan"), " si "], where="f") == "SI"
    assert units_of_column([], marker="imperial", where="f") == "imperial"
    with pytest.raises(ValueError, match="f: the line '# units: imperial' and the column"):
        units_of_column(["SI"], marker="imperial", where="f")


def test_write_csv_is_atomic_and_refuses_to_overwrite(tmp_path):
    path = tmp_path / "x.csv"
    write_csv(path, "a\n1\n", units="SI", overwrite=False)
    with pytest.raises(FileExistsError, match="overwrite"):
        write_csv(path, "a\n2\n", units="SI", overwrite=False)
    with pytest.raises(ValueError, match="unknown unit system 'metric'"):
        write_csv(path, "a\n2\n", units="metric")
    assert path.read_text() == "a,units\n1,SI\n"
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
    assert "drop --units" in text and "'# units: SI'" in text and "'units' column" in text
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


def test_toml_files_hold_converted_numbers_rounded(tmp_path):
    """Issue 36: a TOML shockplan writes holds ``damping = 28.0``, not the conversion's
    ``28.000000000000004``; every float to 13 significant digits, nested ones too, and an
    imperial library read and written again gives its own numbers back."""
    atomic_write_toml(tmp_path / "a.toml", {"damping": 28.000000000000004,
                                            "t": {"v": [0.1 + 0.2, 3]}, "n": 7, "s": "x"})
    text = (tmp_path / "a.toml").read_text()
    assert "damping = 28.0\n" in text and "0.3," in text and "0.30000000000000004" not in text
    assert read_toml(tmp_path / "a.toml")["t"]["v"] == [0.3, 3]
    (tmp_path / "lib.toml").write_text(
        'units = "imperial"\n\n[[shock]]\nid = "L28"\nkind = "linear"\ndamping = 28.0\n'
        '\n[[shock]]\nid = "T"\nkind = "table"\nvelocity = [-10.0, 0.0, 2.5, 10.0]\n'
        'force = [-120.5, 0.0, 40.25, 95.0]\n')
    library = read_shock_library(tmp_path / "lib.toml")
    write_shock_library(library, tmp_path / "again.toml", units="imperial")
    again = (tmp_path / "again.toml").read_text()
    assert "damping = 28.0\n" in again and "40.25" in again and "0000000" not in again


def test_png_metadata_holds_the_figures_words():
    """A figure's labels (axes, title, legend) in the PNG text chunk a test reads."""
    from matplotlib.figure import Figure

    fig = Figure()
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1], label="optimum")
    ax.set(xlabel="shock velocity [in/s]", ylabel="force [lbf]", title="front")
    ax.legend()
    words = png_metadata(fig)[PNG_TEXT_KEY].splitlines()
    assert {"shock velocity [in/s]", "force [lbf]", "front", "optimum"} <= set(words)
