"""Small file helpers: TOML reading with clear errors, atomic writes, the unit marker.

The unit marker (an optional addition to the rig-session spec, ``docs/formats.md``):
every CSV shockplan writes starts with its header row, as the spec says, and ends each
row with a ``units`` column, the value ``SI`` or ``imperial`` on every row
(:func:`write_csv`, :func:`write_csv_frame`), so that ``pandas.read_csv(path)``, MATLAB's
``readtable`` and a spreadsheet read it as they are; a Parquet drive or run file carries
the same in its schema metadata, key ``units`` (:func:`write_parquet_frame`). Files of
the earlier layout, whose first line is the marker line ``# units: SI`` (or ``imperial``)
above the header, are still read. Readers skip the leading ``#`` comment lines of a CSV,
take the marker from them, and take the ``units`` column's value (dropping the column)
when there is one (:func:`csv_preamble`, :func:`read_csv_table`, :func:`read_csv_after`,
:func:`read_units_marker`, :func:`units_of_column`); a marker line and a column that
disagree, or a column with more than one value, are refused.
:func:`resolve_units` decides a file's unit system from its marker and the unit system
a caller was given (the manifest's ``units``, ``--units``), refusing a contradiction.

Examples
--------
>>> import io
>>> csv_preamble(io.StringIO("# units: imperial\\ntime,wheelloader_LF\\n0,1\\n"), where="f.csv")
('imperial', 1)
>>> resolve_units(None, None, where="f.csv"), resolve_units("imperial", None, where="f.csv")
('SI', 'imperial')
"""

from __future__ import annotations

import difflib
import os
import re
import tempfile
from pathlib import Path

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

import tomli_w

from ident import interrupts
from ident.data.units import FILE_DIGITS, check_units, round_significant

__all__ = ["read_toml", "round_file_numbers", "write_csv", "write_csv_frame", "write_parquet_frame", "write_table_file",
           "atomic_write_text", "atomic_write_bytes", "atomic_write_toml", "atomic_path",
           "atomic_dir", "check_can_write", "check_output", "did_you_mean",
           "FLOAT_DTYPES", "PARQUET_FLOAT32_OPTIONS",
           "UNITS_KEY", "UNITS_COLUMN", "units_marker", "csv_preamble", "read_units_marker",
           "read_csv_table", "read_csv_after", "units_of_column", "resolve_units",
           "PNG_TEXT_KEY", "figure_text", "png_metadata"]

#: The types :func:`write_parquet_frame` stores float columns in.
FLOAT_DTYPES = ("float64", "float32")
#: ``pyarrow.parquet.write_table`` options of a float32 Parquet file: each float's bytes
#: split into streams (exponents apart from mantissas), then zstd: for noisy signals
#: 14 % smaller than snappy on the floats as they are (the demo's runs: 11.0 MB, 12.8 MB).
PARQUET_FLOAT32_OPTIONS = {"use_byte_stream_split": True, "compression": "zstd"}
#: The key of the unit marker: ``# units: SI`` in a CSV, the Parquet schema metadata key.
UNITS_KEY = "units"
#: The last column of every CSV shockplan writes: the unit system (``SI`` or ``imperial``)
#: on every row.
UNITS_COLUMN = "units"
#: A marker line: ``#``, the key, ``:`` or ``=``, the unit system (a spreadsheet that saves
#: the line back may pad it with commas or quote it; both are tolerated).
_MARKER_LINE = re.compile(r"#\s*units\s*[:=]\s*(.*)$", re.IGNORECASE)


def read_toml(path, *, error=ValueError, what="TOML file"):
    """Read a TOML file; raise `error` naming the file on a missing or malformed file."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: {what} not found; check the path")
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc}); fix the syntax") from None
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text file (byte {exc.start}: {exc.reason}); a {what} is "
                    "UTF-8 TOML text") from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror}); check the file") from None


def _umask():
    umask = os.umask(0)
    os.umask(umask)
    return umask


class atomic_path:
    """Context manager giving a temporary path that replaces `path` on success.

    The temporary file lives in the same folder, so the final ``os.replace`` is
    atomic; on an exception it is removed and `path` is left untouched.
    """

    def __init__(self, path, *, overwrite=True):
        self.path = Path(path)
        self.overwrite = overwrite

    def __enter__(self):
        check_can_write(self.path, overwrite=self.overwrite)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp",
                                   dir=self.path.parent)
        os.close(fd)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None and interrupts.requested():  # Ctrl-C lost on the way: write nothing
            self.tmp.unlink(missing_ok=True)
            raise KeyboardInterrupt
        if exc_type is None:
            os.chmod(self.tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the usual mode
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
        return False


class atomic_dir:
    """Context manager giving a temporary folder that replaces folder `path` on success.

    An existing, non-empty `path` (or a file there) is refused unless `overwrite`
    (checked on entry, before any work). The temporary folder lives beside `path`; on
    success it replaces `path` (an old one removed first), on an exception it is removed
    and `path` is left as it was.
    """

    def __init__(self, path, *, overwrite=False):
        self.path = Path(path)
        self.overwrite = overwrite

    def __enter__(self):
        out = self.path
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            check_can_write(out, overwrite=self.overwrite)
        out.parent.mkdir(parents=True, exist_ok=True)
        self.work = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
        return self.work

    def __exit__(self, exc_type, exc, tb):
        import shutil

        if exc_type is None and interrupts.requested():  # Ctrl-C lost on the way: write nothing
            shutil.rmtree(self.work, ignore_errors=True)
            raise KeyboardInterrupt
        if exc_type is None:
            os.chmod(self.work, 0o777 & ~_umask())  # mkdtemp creates 0700; the usual mode
            if self.path.exists():
                shutil.rmtree(self.path) if self.path.is_dir() else self.path.unlink()
            self.work.rename(self.path)
        else:
            shutil.rmtree(self.work, ignore_errors=True)
        return False


def check_can_write(path, *, overwrite):
    """Raise ``FileExistsError`` if `path` exists and `overwrite` is false."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"{path}: already exists; choose another output path or pass overwrite=True "
            "(--overwrite on the command line)"
        )


def check_output(path, *, overwrite, folder=False, what="--out"):
    """Check, before any computation, that an output can be written at `path`.

    Parameters
    ----------
    path : str or os.PathLike
        The output file (or folder, with ``folder=True``).
    overwrite : bool
        Whether an existing output may be replaced.
    folder : bool
        The output is a folder: an existing empty folder is fine; an existing
        file is not.
    what : str
        How to name the output in messages (the option).

    Raises
    ------
    FileExistsError
        If the output exists (a non-empty folder, or a file) and `overwrite` is false,
        or a folder is wanted where a file is (and the other way round).
    PermissionError
        If the nearest existing folder on the path cannot be written in (read-only
        folder or file system): probed by creating and removing a file there.
    """
    path = Path(path)
    if folder:
        if path.exists() and not path.is_dir():
            raise FileExistsError(f"{path}: {what} exists and is not a folder; choose another "
                                  "output folder")
        if path.is_dir() and any(path.iterdir()) and not overwrite:
            raise FileExistsError(f"{path}: {what} folder already exists and is not empty; "
                                  "choose another output folder or pass --overwrite")
    else:
        if path.is_dir():
            raise FileExistsError(f"{path}: {what} is a folder; give a file name")
        check_can_write(path, overwrite=overwrite)
    parent = path if folder and path.is_dir() else path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise FileExistsError(f"{path}: {what}: {parent} is a file, not a folder; choose "
                              "another output path")
    try:
        fd, probe = tempfile.mkstemp(prefix=".shockplan-probe-", dir=parent)
    except OSError as exc:
        raise PermissionError(f"{path}: {what}: folder {parent} is not writable "
                              f"({exc.strerror}); choose a folder you can write in") from None
    os.close(fd)
    os.unlink(probe)


def did_you_mean(word, choices, *, cutoff=0.75):
    """`` (did you mean 'x'?)`` for the closest of `choices` to `word`, or ``""``.

    The `cutoff` (difflib's similarity ratio) is stricter than difflib's 0.6, so that a
    key of the user's own ('notes') is not taken for a typo of a known one ('units').
    """
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=cutoff)
    return f" (did you mean {close[0]!r}?)" if close else ""


#: The PNG text chunk in which shockplan's figures keep their words (:func:`png_metadata`).
PNG_TEXT_KEY = "Description"


def figure_text(fig):
    """The words a reader sees on a matplotlib figure: its title, each axes' title and axis
    labels, legend entries and texts placed on it, one per line, each once, in drawing
    order (tick labels are numbers: left out).

    Parameters
    ----------
    fig : matplotlib.figure.Figure

    Returns
    -------
    str
    """
    texts = [fig.get_suptitle(), *(t.get_text() for t in fig.texts)]
    for ax in fig.axes:
        texts += [ax.get_title(loc) for loc in ("left", "center", "right")]
        texts += [ax.get_xlabel(), ax.get_ylabel(), *(t.get_text() for t in ax.texts)]
        legend = ax.get_legend()
        if legend is not None:
            texts += [t.get_text() for t in legend.get_texts()]
    for legend in fig.legends:
        texts += [t.get_text() for t in legend.get_texts()]
    return "\n".join(dict.fromkeys(t.strip() for t in texts if t and t.strip()))


def png_metadata(fig):
    """``savefig``'s `metadata` for a PNG: the figure's words (:func:`figure_text`) in the
    text chunk :data:`PNG_TEXT_KEY`, so that a test or a search reads a plot's units and
    labels without looking at it (``PIL.Image.open(path).text``). Call it right before
    ``savefig``: the words are those the figure has then."""
    return {PNG_TEXT_KEY: figure_text(fig)}


def atomic_write_bytes(path, data, *, overwrite=True):
    """Write `data` to `path` atomically."""
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path, text, *, overwrite=True):
    """Write `text` (UTF-8) to `path` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"), overwrite=overwrite)


def round_file_numbers(data, digits=FILE_DIGITS):
    """`data` (nested dicts, lists and tuples) with every float rounded to `digits`
    significant digits (:func:`ident.data.units.round_significant`): a value converted at the
    file boundary as a file should hold it (``damping = 28.0``, not ``28.000000000000004``),
    within 5e-13 of the value (relative) with the default.

    Examples
    --------
    >>> round_file_numbers({"damping": 28.000000000000004, "v": [0.1, 1 / 3], "n": 2})
    {'damping': 28.0, 'v': [0.1, 0.3333333333333], 'n': 2}
    """
    if isinstance(data, dict):
        return {k: round_file_numbers(v, digits) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return type(data)(round_file_numbers(v, digits) for v in data)
    if isinstance(data, float):
        return round_significant(data, digits)
    return data


def atomic_write_toml(path, data, *, overwrite=True, header=None):
    """Write a mapping as TOML to `path` atomically, with an optional comment header; floats
    are written to 13 significant digits (:func:`round_file_numbers`)."""
    text = tomli_w.dumps(round_file_numbers(data))
    if header:
        text = "".join(f"# {line}\n" for line in header.splitlines()) + text
    atomic_write_text(path, text, overwrite=overwrite)


def units_marker(units):
    """The unit marker line of a CSV (no line end): ``# units: SI`` or ``# units: imperial``.

    The earlier layout's first line, still read (:func:`csv_preamble`); shockplan now
    writes a trailing ``units`` column instead (:data:`UNITS_COLUMN`).

    Parameters
    ----------
    units : {"SI", "imperial"}
        Any case.

    Raises
    ------
    ValueError
        If `units` is not a unit system.

    Examples
    --------
    >>> units_marker("si")
    '# units: SI'
    """
    return f"# {UNITS_KEY}: {check_units(units, where='unit marker')}"


def csv_preamble(lines, *, where, error=ValueError):
    """The unit marker and length of a CSV's preamble: its leading comment and blank lines.

    Parameters
    ----------
    lines : iterable of str
        The file's lines (an open text file, or ``text.splitlines()``); consumed up to and
        including the first line that is neither blank nor a ``#`` comment (the header).
    where : str
        How to name the file in messages.
    error : type
        The ``ValueError`` subclass to raise.

    Returns
    -------
    units : str or None
        ``"SI"`` or ``"imperial"`` from a ``# units: ...`` line (any case, ``:`` or ``=``,
        padded with commas or quoted as a spreadsheet may save it); None without one.
        A ``units`` column below the header is not seen here: the readers of the table
        (:func:`read_csv_table`, :func:`read_units_marker`) reconcile it with this
        (:func:`units_of_column`).
    n_lines : int
        The number of leading comment and blank lines (the header is the next line).

    Raises
    ------
    error
        If a marker names an unknown unit system, or two markers disagree.
    """
    units, n = None, 0
    for line in lines:
        text = line.lstrip("\ufeff").strip().rstrip(",").strip().strip('"').strip()
        if text and not text.startswith("#"):
            break
        n += 1
        match = _MARKER_LINE.match(text)
        if match is None:
            continue
        value = check_units(match.group(1).strip().strip("'\""),
                            where=f"{where}: line {n} ('# {UNITS_KEY}: ...')", error=error)
        if units is not None and value != units:
            raise error(f"{where}: lines 1-{n} say both '# {UNITS_KEY}: {units}' and "
                        f"'# {UNITS_KEY}: {value}'; keep the one line that is true")
        units = value
    return units, n


def _is_parquet(path):
    return Path(path).suffix.lower() in (".parquet", ".pq")


def read_units_marker(path, *, where=None, error=ValueError, kind=None):
    """The unit system a CSV or Parquet file says it is in, or None.

    Parameters
    ----------
    path : str or os.PathLike
        A CSV file (its ``units`` column, or the earlier layout's leading ``# units: ...``
        line) or a Parquet file (``.parquet``, ``.pq``: its schema metadata ``units``).
    where : str, optional
        How to name the file in messages (default: the path).
    error : type
        The ``ValueError`` subclass to raise.
    kind : {"csv", "parquet"}, optional
        The file's format, for a file whose suffix does not say it (default: Parquet for
        ``.parquet`` and ``.pq``, else CSV).

    Returns
    -------
    str or None
        ``"SI"``, ``"imperial"``, or None for a file that does not say.

    Raises
    ------
    error
        If the file cannot be read, its marker names an unknown unit system, or its
        ``units`` column holds more than one value or disagrees with its marker line.
    """
    import csv

    import pandas as pd
    import pyarrow
    import pyarrow.parquet as pq

    where = str(path) if where is None else where
    try:
        if kind == "parquet" or (kind is None and _is_parquet(path)):
            raw = (pq.read_schema(path).metadata or {}).get(UNITS_KEY.encode())
        else:
            with open(path, encoding="utf-8-sig", newline="") as fh:
                marker, n = csv_preamble(fh, where=where, error=error)
            with open(path, encoding="utf-8-sig", newline="") as fh:
                for _ in range(n):  # as lines: a quote in a comment opens no field
                    fh.readline()
                header = [h.strip() for h in next(csv.reader(fh), [])]
            if UNITS_COLUMN not in header:
                return marker
            values = read_csv_after(path, n, usecols=[header.index(UNITS_COLUMN)],
                                    dtype=str).iloc[:, 0]
            return units_of_column(values, marker=marker, where=where, error=error)
    except (OSError, UnicodeDecodeError, pyarrow.ArrowException, pd.errors.ParserError,
            pd.errors.EmptyDataError) as exc:
        raise error(f"{where}: cannot read the file ({type(exc).__name__}: {exc}); check "
                    "the path and that it is a UTF-8 CSV or a Parquet file") from None
    if raw is None:
        return None
    return check_units(raw.decode("utf-8", "replace"),
                       where=f"{where}: Parquet metadata '{UNITS_KEY}'", error=error)


def units_of_column(values, *, marker=None, where, error=ValueError):
    """The unit system a CSV's ``units`` column states, checked against its marker line.

    Parameters
    ----------
    values : iterable
        The column's values (strings; blank cells and NaN are skipped).
    marker : {"SI", "imperial"} or None
        The file's marker line (:func:`csv_preamble`), if any.
    where : str
        How to name the file in messages.
    error : type
        The ``ValueError`` subclass to raise.

    Returns
    -------
    str or None
        ``"SI"`` or ``"imperial"``; `marker` for a column without a value (no rows).

    Raises
    ------
    error
        If a value is not a unit system, the column holds more than one (a file is in one
        unit system), or it disagrees with `marker`.

    Examples
    --------
    >>> units_of_column(["imperial", "Imperial"], where="f.csv")
    'imperial'
    >>> units_of_column(["SI", "imperial"], where="f.csv")
    Traceback (most recent call last):
    ...
    ValueError: f.csv: column 'units' says both SI and imperial; a file is in one unit system: give every row the one that is true (SI or imperial)
    """
    # a file's rows repeat one value: its distinct values are few (a column's own unique()
    # is 40x quicker than a set of 80 000 Arrow-backed strings)
    distinct = values.unique() if hasattr(values, "unique") else set(values)
    raw = set()
    for v in distinct:
        if v is None or (isinstance(v, float) and v != v) or type(v).__name__ == "NAType":
            continue  # a blank cell
        text = str(v).strip().strip("'\"").strip()
        if text:
            raw.add(text)
    found = []
    for text in sorted(raw):
        value = check_units(text, where=f"{where}: column '{UNITS_COLUMN}'", error=error)
        if value not in found:
            found.append(value)
    if not found:
        return marker
    if len(found) > 1:
        raise error(f"{where}: column '{UNITS_COLUMN}' says both {' and '.join(sorted(found))}; "
                    "a file is in one unit system: give every row the one that is true (SI "
                    "or imperial)")
    value = found[0]
    if marker is not None and marker != value:
        raise error(f"{where}: the line '# {UNITS_KEY}: {marker}' and the column "
                    f"'{UNITS_COLUMN}' ({value}) disagree; keep the one that is true: delete "
                    "or correct the line, or correct the column")
    return value


def _split_units_column(frame, marker, *, where, error):
    """`frame` without its ``units`` column, and the unit system (column and marker)."""
    names = [str(c).strip() for c in frame.columns]
    if UNITS_COLUMN not in names:
        return frame, marker
    j = names.index(UNITS_COLUMN)
    units = units_of_column(frame.iloc[:, j], marker=marker, where=where, error=error)
    return frame.drop(columns=frame.columns[j]), units


def read_csv_table(path, *, where=None, error=ValueError, index_col=None):
    """Read a CSV file with pandas, its leading ``#`` comment lines skipped, its unit
    system taken from its ``units`` column (dropped from the table) or marker line.

    Parameters
    ----------
    path : str or os.PathLike
        A UTF-8 CSV file (a byte-order mark is allowed) with a header row, after any
        leading comment (``#``) and blank lines.
    where : str, optional
        How to name the file in messages (default: the path).
    error : type
        The ``ValueError`` subclass to raise.
    index_col : int or str, optional
        As :func:`pandas.read_csv`.

    Returns
    -------
    frame : pandas.DataFrame
        Without a ``units`` column.
    units : str or None
        The file's ``units`` column's value or marker line (:func:`units_of_column`,
        :func:`csv_preamble`), or None.

    Raises
    ------
    error
        If the file cannot be read or parsed as CSV, or its marker or ``units`` column
        is invalid (:func:`units_of_column`).

    Examples
    --------
    >>> import tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "t.csv")
    >>> write_csv(p, "a,b\\n1,2\\n", units="imperial")
    >>> frame, units = read_csv_table(p)
    >>> list(frame.columns), units
    (['a', 'b'], 'imperial')
    """
    import pandas as pd

    where = str(path) if where is None else where
    try:
        with open(path, encoding="utf-8-sig", newline="") as fh:
            units, n = csv_preamble(fh, where=where, error=error)
        frame = read_csv_after(path, n, index_col=index_col)
    except (OSError, UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise error(f"{where}: cannot read the file as CSV ({type(exc).__name__}: {exc}); "
                    "give a UTF-8 CSV file with a header row") from None
    return _split_units_column(frame, units, where=where, error=error)


def read_csv_after(path, n_lines, *, index_col=None, usecols=None, dtype=None):
    """The table of a UTF-8 CSV file that starts after its first `n_lines` lines (pandas).

    The lines skipped are a preamble (:func:`csv_preamble`): whatever they hold, a quote
    among them included, they are skipped as lines, not parsed as CSV rows.

    Parameters
    ----------
    path : str or os.PathLike
    n_lines : int
        Lines before the header, e.g. :func:`csv_preamble`'s count.
    index_col : int or str, optional
        As :func:`pandas.read_csv`.
    usecols, dtype : optional
        As :func:`pandas.read_csv`.

    Returns
    -------
    pandas.DataFrame
    """
    import pandas as pd

    if n_lines:
        with open(path, "rb") as fh:
            skipped = b"".join(fh.readline() for _ in range(n_lines))
            if b'"' in skipped:  # pandas' skiprows would parse a quote as opening a field
                return pd.read_csv(fh, encoding="utf-8", index_col=index_col,
                                   usecols=usecols, dtype=dtype)
    # a path reads a third faster than an open file (measured: 0.65 s against 0.90 s for
    # 80 000 rows x 40 columns)
    return pd.read_csv(path, skiprows=n_lines, encoding="utf-8-sig", index_col=index_col,
                       usecols=usecols, dtype=dtype)


def resolve_units(marked, given, *, where, given_as="units", fix=None, error=ValueError):
    """The unit system of a file from its marker and the one a caller was given.

    The file's marker decides when nothing is given; what is given decides a file without a
    marker; neither gives SI (the rig-session spec's default). A marker and a given unit
    system that disagree are an error: one of them is wrong, and reading on would convert
    every value by the wrong factor (an inch read as a metre).

    Parameters
    ----------
    marked : {"SI", "imperial"} or None
        The file's marker (:func:`read_units_marker`).
    given : {"SI", "imperial"} or None
        The unit system the caller was given (``--units``, a manifest's ``units``), any case.
    where : str
        How to name the file in the message.
    given_as : str
        How to name the source of `given` in the message (``"--units"``, ``"the
        manifest's units"``).
    fix : str, optional
        The fix the message ends with (default: drop `given_as`, or correct the marker).
    error : type
        The ``ValueError`` subclass to raise.

    Returns
    -------
    str
        ``"SI"`` or ``"imperial"``.

    Raises
    ------
    error
        If `given` is not a unit system, or contradicts `marked`.

    Examples
    --------
    >>> resolve_units("imperial", "SI", where="track.csv", given_as="--units")
    Traceback (most recent call last):
    ...
    ValueError: track.csv: the file says it is in imperial units (its 'units' column or '# units:' line) but --units says SI; drop --units (the file's marker decides), or if its values really are in SI, correct the marker to SI (its 'units' column, or a line '# units: SI')
    """
    if given is not None:
        given = check_units(given, where=f"{where}: {given_as}", error=error)
    if marked is None:
        return given or "SI"
    if given is not None and given != marked:
        fix = fix or (f"drop {given_as} (the file's marker decides), or if its values really "
                      f"are in {given}, correct the marker to {given} (its '{UNITS_COLUMN}' "
                      f"column, or a line '# {UNITS_KEY}: {given}')")
        raise error(f"{where}: the file says it is in {marked} units (its '{UNITS_COLUMN}' "
                    f"column or '# {UNITS_KEY}:' line) but {given_as} says {given}; {fix}")
    return marked


def write_csv(path, data, *, units, overwrite=True, index=False, float_format=None):
    """Write a CSV file atomically: its header row first, a last column ``units``.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    data : pandas.DataFrame or str
        A table (written by :func:`write_csv_frame`) or CSV text, its header line first
        (parsed with :mod:`csv`, so quoted fields stay as they are; each row, blank lines
        aside, gets the ``units`` cell).
    units : {"SI", "imperial"}
        The unit system the values are written in (a file whose values have no unit says
        the system of the run that wrote it): the value of the ``units`` column.
    overwrite : bool
        Replace an existing file.
    index : bool
        Write a table's index as the first column(s).
    float_format : str, optional
        As :meth:`pandas.DataFrame.to_csv` (default: the shortest text that reads back
        every float exactly).

    Raises
    ------
    ValueError
        If `units` is not a unit system, or the data has a column ``units`` already.
    FileExistsError
        If `path` exists and `overwrite` is false.

    Examples
    --------
    >>> import tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "t.csv")
    >>> write_csv(p, 'a,b\\n1,"x,y"\\n', units="SI")
    >>> print(open(p).read(), end="")
    a,b,units
    1,"x,y",SI
    """
    units = check_units(units, where=f"{path}: units")
    with atomic_path(path, overwrite=overwrite) as tmp:
        if isinstance(data, str):
            tmp.write_text(_text_with_units(data, units, where=str(path)), encoding="utf-8")
        else:
            write_csv_frame(data, tmp, units=units, index=index, float_format=float_format)


def _text_with_units(text, units, *, where):
    """CSV text (header first) with the column ``units`` added: the header names it, every
    other row (blank lines aside) holds `units`."""
    import csv
    import io

    rows = list(csv.reader(io.StringIO(text, newline="")))
    if rows and UNITS_COLUMN in [c.strip() for c in rows[0]]:
        raise ValueError(f"{where}: the table has a column '{UNITS_COLUMN}' already; it is "
                         "the unit system's column: rename the table's")
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    for k, row in enumerate(rows):
        writer.writerow([*row, UNITS_COLUMN if k == 0 else units] if row else row)
    return buf.getvalue()


def write_csv_frame(frame, path, *, units, index=False, float_format=None):
    """Write a DataFrame as CSV to `path` (not atomically: e.g. the temporary path of
    :func:`atomic_path`): the header row first, a last column ``units`` (the unit system
    on every row).

    A numeric frame (without `index` or `float_format`) is written fast: the header as
    pandas writes it, the rows by Arrow's C++ writer (shortest round-trip float text,
    about 10x faster than ``DataFrame.to_csv``; values read back bit for bit). Any other
    frame is written by pandas, with ``\n`` line ends.

    Parameters
    ----------
    frame : pandas.DataFrame
        Without a column ``units``.
    path : str or Path
        The file to write.
    units : {"SI", "imperial"}
        The unit system of the values (the ``units`` column).
    index : bool
        Write the index as the first column(s).
    float_format : str, optional
        As :meth:`pandas.DataFrame.to_csv`.

    Raises
    ------
    ValueError
        If `units` is not a unit system, or `frame` has a column ``units``.
    """
    import csv
    import io

    import pyarrow as pa
    import pyarrow.csv as pacsv

    units = check_units(units, where=f"{path}: units")
    if UNITS_COLUMN in [str(c).strip() for c in frame.columns]:
        raise ValueError(f"{path}: the table has a column '{UNITS_COLUMN}' already; it is "
                         "the unit system's column: rename the table's")
    fast = (not index and float_format is None
            and all(getattr(dt, "kind", "O") in "fiu" for dt in frame.dtypes))
    if not fast:
        frame = frame.copy(deep=False)
        frame[UNITS_COLUMN] = units
        with open(path, "w", encoding="utf-8", newline="") as fh:
            frame.to_csv(fh, index=index, float_format=float_format, lineterminator="\n")
        return
    head = io.StringIO()
    csv.writer(head, lineterminator="\n").writerow([*(str(c) for c in frame.columns),
                                                     UNITS_COLUMN])
    table = pa.Table.from_pandas(frame, preserve_index=False)
    table = table.append_column(UNITS_COLUMN, pa.repeat(pa.scalar(units), table.num_rows))
    with open(path, "wb") as fh:
        fh.write(head.getvalue().encode("utf-8"))
        # no quotes: the numbers need none, and neither does SI or imperial
        pacsv.write_csv(table, fh, write_options=pacsv.WriteOptions(include_header=False,
                                                                    quoting_style="none"))


def write_table_file(frame, path, *, kind, units, overwrite, float_dtype="float64"):
    """Write a run-like table atomically as CSV or Parquet, its unit system stated.

    The one writer of run files, mapped run files and track logs: the frame goes to a
    temporary file beside `path` (:func:`write_csv_frame` or :func:`write_parquet_frame`),
    which then replaces `path`.

    Parameters
    ----------
    frame : pandas.DataFrame
        The table (values already in `units`).
    path : str or Path
        The file to write.
    kind : {"csv", "parquet"}
        The file format.
    units : {"SI", "imperial"}
        The unit system of the values (a CSV's ``units`` column, a Parquet file's
        metadata).
    overwrite : bool
        Replace an existing file.
    float_dtype : {"float64", "float32"}
        The type a Parquet file stores the float columns in, but ``time``
        (:func:`write_parquet_frame`); a CSV is always written with full precision.

    Raises
    ------
    FileExistsError
        If `path` exists and `overwrite` is false.
    ValueError
        If `float_dtype` is ``"float32"`` for a CSV, or not one of the two.
    """
    if float_dtype != "float64" and kind == "csv":
        raise ValueError(f"{path}: float_dtype={float_dtype!r} is for Parquet files; a CSV is "
                         "written with full precision (float_dtype='float64')")
    with atomic_path(path, overwrite=overwrite) as tmp:
        if kind == "csv":
            write_csv_frame(frame, tmp, units=units)
        else:
            write_parquet_frame(frame, tmp, units=units, float_dtype=float_dtype)


def write_parquet_frame(frame, path, *, units, float_dtype="float64"):
    """Write a DataFrame as Parquet (no index), without dictionary encoding, its unit
    system in the schema metadata (key ``units``).

    Measured float signals repeat almost no value, so Arrow's default dictionary
    encoding is tried, abandoned and only costs: without it a run of 80 000 samples
    x 40 channels is written 6x faster (0.03 s instead of 0.17 s) and is 20 % smaller.
    Snappy compression (the default) is kept, and values read back bit for bit.

    With ``float_dtype="float32"`` the float columns but ``time`` are stored as 32-bit
    floats (a relative precision of 6e-8, far finer than any rig sensor's resolution;
    ``time`` stays 64-bit, so that its steps stay uniform to 1e-6 of a step over hours),
    byte-stream split and zstd-compressed: a noisy run of 80 000 samples x 40 channels
    takes 11.0 MB against 61 MB as CSV (:data:`PARQUET_FLOAT32_OPTIONS`). Readers take the
    columns as they are (pandas gives float32 columns; shockplan's readers float64).

    Parameters
    ----------
    frame : pandas.DataFrame
    path : str or Path
        The file to write (e.g. the temporary path of :func:`atomic_path`).
    units : {"SI", "imperial"}
        The unit system of the values (the metadata entry ``units``).
    float_dtype : {"float64", "float32"}
        The type the float columns but ``time`` are stored in.

    Raises
    ------
    ValueError
        If `units` or `float_dtype` is not one of its values.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    units = check_units(units, where=f"{path}: units")
    if float_dtype not in FLOAT_DTYPES:
        raise ValueError(f"{path}: float_dtype={float_dtype!r} is not one of "
                         f"{', '.join(FLOAT_DTYPES)}; use 'float64' (exact) or 'float32'")
    options = {}
    if float_dtype == "float32":
        frame = frame.astype({c: "float32" for c, dt in frame.dtypes.items()
                              if dt.kind == "f" and str(c) != "time"})
        options = PARQUET_FLOAT32_OPTIONS
    table = pa.Table.from_pandas(frame, preserve_index=False)
    meta = dict(table.schema.metadata or {})
    meta[UNITS_KEY.encode()] = units.encode()
    pq.write_table(table.replace_schema_metadata(meta), path, use_dictionary=False, **options)
