"""Small file helpers: TOML reading with clear errors, atomic writes."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

import tomli_w

__all__ = ["read_toml", "atomic_write_text", "atomic_write_bytes", "atomic_write_toml",
           "atomic_path", "check_can_write"]


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


def check_can_write(path, *, overwrite):
    """Raise ``FileExistsError`` if `path` exists and `overwrite` is false."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"{path}: already exists; choose another output path or pass overwrite=True "
            "(--overwrite on the command line)"
        )


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
