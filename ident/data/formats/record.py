"""What every format reader returns, and the checks they share (format sniffing)."""

from __future__ import annotations

import logging
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident.errors import SessionError

__all__ = ["FORMATS", "FORMAT_NAMES", "RawRecord", "sniff_format", "check_file",
           "not_format_error", "logged_warnings", "as_float_samples"]

logger = logging.getLogger(__name__)

#: The formats a rig file can be read from (values of ``--format``).
FORMATS = ("rpc3", "mdf", "tdms")
#: How each format is named in messages.
FORMAT_NAMES = {"rpc3": "RPC III", "mdf": "MDF", "tdms": "TDMS"}
_ARTICLE = {"rpc3": "an", "mdf": "an", "tdms": "a"}
#: Bytes read to recognize a file.
_SNIFF_BYTES = 128


@dataclass(frozen=True, eq=False)
class RawRecord:
    """The channels of one rig data file, as stored (file units, file names).

    Attributes
    ----------
    path : pathlib.Path
        The file.
    format : {"rpc3", "mdf", "tdms"}
        Its format.
    channels : dict of str to ndarray, shape (n_samples,)
        Source channel name -> raw values (float64), for the channels asked for
        that the file has (every channel if none were asked for).
    time_s : dict of str to ndarray or None
        Source channel name -> sample times [s], shape (n_samples,), or ``None``
        where the file gives the channel no time base (a TDMS channel without
        waveform properties).
    units : dict of str to str
        Source channel name -> the unit string the file gives it (``""`` if none).
    available : tuple of str
        Every data channel the file has (for messages), in file order.
    header : dict
        Format-specific metadata (the RPC III header parameters, the MDF
        version, the TDMS file properties).
    """

    path: Path
    format: str
    channels: dict
    time_s: dict
    units: dict
    available: tuple
    header: dict = field(default_factory=dict)


def sniff_format(path):
    """Recognize a file from its first bytes.

    Parameters
    ----------
    path : str or os.PathLike
        An existing file.

    Returns
    -------
    str or None
        ``"rpc3"``, ``"mdf"``, ``"tdms"``, ``"tdms-index"`` (a ``.tdms_index``
        file), ``"zip"`` (e.g. a zipped MDF, ``.mf4z``), ``"parquet"``,
        ``"hdf5"``, ``"text"`` or ``"empty"``; ``None`` if not recognized.
    """
    with open(path, "rb") as fh:
        head = fh.read(_SNIFF_BYTES)
    if not head:
        return "empty"
    if head.startswith((b"MDF     ", b"UnFinMF ")):
        return "mdf"
    if head.startswith(b"TDSm"):
        return "tdms"
    if head.startswith(b"TDSh"):
        return "tdms-index"
    if head[:32].rstrip(b"\x00 ") == b"FORMAT":
        return "rpc3"
    if head.startswith(b"PK\x03\x04"):
        return "zip"
    if head.startswith(b"PAR1"):
        return "parquet"
    if head.startswith(b"\x89HDF"):
        return "hdf5"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        return None
    if all(ch.isprintable() or ch in "\r\n\t" for ch in text):
        return "text"
    return None


_LOOKS_LIKE = {
    "rpc3": "it looks like an RPC III file",
    "mdf": "it looks like an MDF file",
    "tdms": "it looks like a TDMS file",
    "tdms-index": "it looks like a TDMS index file; give the .tdms file beside it",
    "zip": "it is a ZIP archive",
    "parquet": "it looks like a Parquet file",
    "hdf5": "it looks like an HDF5 / MATLAB v7.3 file",
    "text": "it is a text file, e.g. CSV",
}


def not_format_error(path, expected, *, where=None):
    """Return the :class:`SessionError` for a file that is not of format `expected`.

    The message names the file, the expected format, what the file looks like
    (from its first bytes) and the fix (``--format``).
    """
    path = Path(path)
    kind = sniff_format(path)
    start = f"file {path}" if where is None else where
    if kind == "empty":
        return SessionError(f"{start} is empty (0 bytes), not {_ARTICLE[expected]} "
                            f"{FORMAT_NAMES[expected]} file; check the file and its export")
    with open(path, "rb") as fh:
        head = fh.read(8)
    seen = _LOOKS_LIKE.get(kind, f"it starts with the bytes {head!r}")
    return SessionError(
        f"{start} is not {_ARTICLE[expected]} {FORMAT_NAMES[expected]} file ({seen}); "
        f"check --format (one of {', '.join(FORMATS)}) and the file"
    )


def check_file(path, expected, *, where=None):
    """Check that `path` is an existing file of format `expected`; return it as a Path.

    Raises
    ------
    SessionError
        If the file is missing, is a folder, is empty, or its first bytes are
        not those of `expected` (:func:`not_format_error`).
    """
    path = Path(path)
    start = f"file {path}" if where is None else where
    if not path.exists():
        raise SessionError(f"{start} not found; check the path")
    if not path.is_file():
        raise SessionError(f"{start} is not a file; give the path of {_ARTICLE[expected]} "
                           f"{FORMAT_NAMES[expected]} file")
    kind = sniff_format(path)
    ok = kind == expected or (expected == "mdf" and kind == "zip")
    if not ok:
        raise not_format_error(path, expected, where=where)
    return path


@contextmanager
def logged_warnings(where):
    """Turn a third-party library's warnings into log records naming the file."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        logger.warning("%s: %s", where, w.message)


def as_float_samples(values, *, where, name):
    """Return a 1-D float64 copy of a channel's values, or raise naming the channel."""
    a = np.asarray(values)
    if a.ndim != 1:
        raise SessionError(f"{where}: channel {name!r} has shape {a.shape}, not one value "
                           "per sample; map a one-dimensional channel")
    if a.dtype.kind not in "iuf":
        raise SessionError(f"{where}: channel {name!r} holds {a.dtype} values, not numbers; "
                           "map a numeric channel")
    return np.array(a, dtype=np.float64)
