"""Small file helpers: TOML reading with clear errors, atomic writes."""

from __future__ import annotations

import difflib
import os
import tempfile
from pathlib import Path

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

import tomli_w

__all__ = ["read_toml", "write_csv_frame", "write_parquet_frame", "atomic_write_text",
           "atomic_write_bytes", "atomic_write_toml", "atomic_path", "atomic_dir",
           "check_can_write", "check_output", "did_you_mean"]


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
        if exc_type is None:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self.tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the usual mode
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

        if exc_type is None:
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


def atomic_write_bytes(path, data, *, overwrite=True):
    """Write `data` to `path` atomically."""
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path, text, *, overwrite=True):
    """Write `text` (UTF-8) to `path` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"), overwrite=overwrite)


def atomic_write_toml(path, data, *, overwrite=True, header=None):
    """Write a mapping as TOML to `path` atomically, with an optional comment header."""
    text = tomli_w.dumps(data)
    if header:
        text = "".join(f"# {line}\n" for line in header.splitlines()) + text
    atomic_write_text(path, text, overwrite=overwrite)


def write_csv_frame(frame, path):
    """Write a numeric DataFrame as CSV, fast: the header as pandas writes it, the rows by
    Arrow's C++ writer (shortest round-trip float text, about 10x faster than
    ``DataFrame.to_csv``; values read back bit for bit).

    Parameters
    ----------
    frame : pandas.DataFrame
        Numeric columns (a frame with other columns is written by pandas).
    path : str or Path
        The file to write (e.g. the temporary path of :func:`atomic_path`).
    """
    import csv
    import io

    import pyarrow as pa
    import pyarrow.csv as pacsv

    if not all(getattr(dt, "kind", "O") in "fiu" for dt in frame.dtypes):
        frame.to_csv(path, index=False)
        return
    head = io.StringIO()
    csv.writer(head, lineterminator="\n").writerow([str(c) for c in frame.columns])
    table = pa.Table.from_pandas(frame, preserve_index=False)
    with open(path, "wb") as fh:
        fh.write(head.getvalue().encode("utf-8"))
        pacsv.write_csv(table, fh, write_options=pacsv.WriteOptions(include_header=False))


def write_parquet_frame(frame, path):
    """Write a DataFrame as Parquet (no index), without dictionary encoding.

    Measured float signals repeat almost no value, so Arrow's default dictionary
    encoding is tried, abandoned and only costs: without it a run of 80 000 samples
    x 40 channels is written 6x faster (0.03 s instead of 0.17 s) and is 20 % smaller.
    Snappy compression (the default) is kept. Values read back bit for bit.

    Parameters
    ----------
    frame : pandas.DataFrame
    path : str or Path
        The file to write (e.g. the temporary path of :func:`atomic_path`).
    """
    frame.to_parquet(path, index=False, use_dictionary=False)
