"""Sections of a drive: a lap or a named time window as a drive file of its own.

A section is a name and a window ``[start_s, stop_s)`` of the drive's time (which is the
track log's, from its first sample; several logs are joined end to end). Each section
becomes a drive of its own (:func:`cut_sections`), faded in and out over ``taper_s`` so that
the rig starts and ends it at rest, so that ``rank`` and ``whatif`` can compare setups per
section.

Examples
--------
>>> parse_sections(["sector1=10:42.5", "sector2=42.5:80"])
[('sector1', 10.0, 42.5), ('sector2', 42.5, 80.0)]
>>> lap_sections([3.0, 95.2, 187.9])
[('lap1', 3.0, 95.2), ('lap2', 95.2, 187.9)]
"""

from __future__ import annotations

import re

import numpy as np

from ident.data.drive import Drive
from planner.errors import PlannerError
from planner.trackdrive.target import segment_taper

__all__ = ["parse_sections", "lap_sections", "check_sections", "cut_sections", "SECTION_TAPER_S"]

#: Fade at each end of a section's drive [s].
SECTION_TAPER_S = 0.5
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


def parse_sections(items, *, where="--section"):
    """Sections from ``NAME=START:STOP`` texts (seconds).

    Parameters
    ----------
    items : iterable of str
    where : str
        The option, first in messages.

    Returns
    -------
    list of (str, float, float)

    Raises
    ------
    PlannerError
        On a text not of that form, a name that is not a file-name stem (letters, digits,
        ``_ . -``), a window with ``start >= stop`` or a negative start, or a repeated name.
    """
    out, seen = [], set()
    for item in items or ():
        name, sep, window = str(item).partition("=")
        start, sep2, stop = window.partition(":")
        name = name.strip()
        try:
            a, b = float(start), float(stop)
        except ValueError:
            a = b = None
        if not sep or not sep2 or a is None:
            raise PlannerError(f"{where} {item!r}: write NAME=START:STOP in seconds, e.g. "
                               "sector1=12.5:40")
        if not _NAME.match(name):
            raise PlannerError(f"{where} {item!r}: the name {name!r} must be letters, digits, "
                               "'_', '.' or '-' (it names a file)")
        if not (np.isfinite(a) and np.isfinite(b)) or a < 0 or a >= b:
            raise PlannerError(f"{where} {item!r}: the window must have 0 <= START < STOP")
        if name in seen:
            raise PlannerError(f"{where} {item!r}: the name {name!r} is given twice")
        seen.add(name)
        out.append((name, a, b))
    return out


def lap_sections(lap_times_s, *, where="--laps"):
    """One section per lap between consecutive lap-start times [s] (``lap1``, ``lap2``, ...).

    Raises
    ------
    PlannerError
        Fewer than two times, or times not strictly increasing or negative.
    """
    try:
        t = np.asarray([float(x) for x in lap_times_s], float)
    except (TypeError, ValueError):
        t = np.array([np.nan])
    if t.size < 2 or np.any(np.diff(t) <= 0) or t[0] < 0 or not np.all(np.isfinite(t)):
        raise PlannerError(f"{where}: give two or more lap-start times in seconds, increasing "
                           "and >= 0 (e.g. --laps 3.0,95.2,187.9: two laps)")
    return [(f"lap{k + 1}", float(t[k]), float(t[k + 1])) for k in range(t.size - 1)]


def check_sections(sections, *, n_samples, fs_hz, of, taper_s=SECTION_TAPER_S,
                   where="sections"):
    """Check section windows against a record before anything is built or written.

    Parameters
    ----------
    sections : sequence of (str, float, float)
        Name, start and stop [s].
    n_samples : int
        The record's length.
    fs_hz : float
        Its sample rate [Hz].
    of : str
        The record, as named in messages (``"the drive 'lap'"``).
    taper_s : float
        Fade at each end of a section [s].
    where : str
        Who asks, first in messages.

    Returns
    -------
    list of (int, int, ndarray)
        Per section: first and end sample, and its fade window, shape (end - first,).

    Raises
    ------
    PlannerError
        A window that ends beyond the record or holds too few samples for its fades.
    """
    out = []
    for name, a, b in sections:
        i, j = int(round(a * fs_hz)), int(round(b * fs_hz))
        if j > n_samples:
            raise PlannerError(f"{where}: section {name!r} ends at {b:g} s, beyond {of} "
                               f"({n_samples / fs_hz:g} s); shorten it")
        w = segment_taper(j - i, fs_hz, taper_s, where=f"{where}: section {name!r}",
                          fix="give a longer window")
        out.append((i, j, w))
    return out


def cut_sections(drive, sections, *, taper_s=SECTION_TAPER_S, where="sections"):
    """The drives of the sections of a drive.

    Parameters
    ----------
    drive : ident.data.drive.Drive
    sections : sequence of (str, float, float)
        Name, start and stop [s] (:func:`parse_sections`, :func:`lap_sections`).
    taper_s : float
        Fade at each end [s].
    where : str
        Who asks, first in messages.

    Returns
    -------
    list of ident.data.drive.Drive
        Named ``"<drive>-<section>"``, each at the drive's rate, its time from 0; settings
        record the section and its window.

    Raises
    ------
    PlannerError
        A window that ends beyond the drive or holds too few samples for its fades.
    """
    windows = check_sections(sections, n_samples=drive.n_samples, fs_hz=drive.fs_hz,
                             of=f"the drive '{drive.name}'", taper_s=taper_s, where=where)
    out = []
    for (name, a, b), (i, j, w) in zip(sections, windows):
        channels = {c: np.asarray(drive.channels[c][i:j], float) * w for c in drive.rig_inputs}
        settings = dict(drive.settings, section=name, window_s=(float(a), float(b)),
                        section_of=drive.name, section_taper_s=float(taper_s))
        out.append(Drive(name=f"{drive.name}-{name}", fs_hz=drive.fs_hz, channels=channels,
                         settings=settings))
    return out
