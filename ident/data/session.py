"""Rig sessions: the manifest, the shock library and the run files of a rig test.

A session folder (``shared/spec/rig-session.md``) holds ``session.toml`` (the
manifest), ``shocks.toml`` (the shock models named by the runs' setups) and one
run file per rig run (CSV with a header row, or Parquet). This module reads and
writes that layout and checks it once, at the boundary, so that everything
downstream can trust a :class:`Session`.

The run files are run tables (:mod:`ident.data.runs`): :func:`read_session` reads
them with :func:`ident.data.runs.read_run_table`, and :func:`make_session` checks
in-memory runs with the same checking engine (:func:`ident.data.runs.check_columns`).
:func:`read_session` and :func:`make_session` share the same session-level checks
(setups against the shock library, run roles, duplicate names, one common sample
rate; the bump stops and packers of each run and the static corner loads, the spec's
"The real car", both optional).

Notes
-----
Inside the package every value is SI and every channel has its canonical name
(:mod:`ident.data.channels`). Files may be in ``"imperial"`` units (the manifest's
``units`` key; run files take the unit system of the manifest, and a run file that
says its own, a CSV's ``units`` column or ``# units: ...`` line or a Parquet file's
metadata, must agree
with it) and may name
their columns differently (the manifest's ``[channels]`` table maps canonical
names to file columns). Values may carry static offsets; :meth:`Run.dynamic`
gives the dynamic part (the run's mean removed) on which everything downstream
works.
"""

from __future__ import annotations

import logging
import os
import re
import secrets
import shutil
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tomli_w

from ident.data.channels import (CORNERS, RIG_INPUTS, WHEELLOADER_INPUTS, corner_table,
                                 rig_inputs_of)
from ident.data.files import (FLOAT_DTYPES, atomic_write_text, did_you_mean, read_toml,
                              round_file_numbers)
from ident.data.runs import (RTOL_TIME_STEP, check_channel_map, check_columns,
                             check_session_units, frozen_array, in_memory_columns,
                             read_run_table, write_mapped_run_table, write_run_table)
from ident.data.third import RunThird, ThirdElements, check_run_third, check_third_elements
from ident.data.units import UNIT_LABELS, from_si, to_si
from ident.errors import BumpStopError, SessionError, ShockModelError
from ident.models.bumpstops import (BumpStopLibrary, check_packer, parse_bump_stop_id,
                                    read_bump_stops, write_bump_stops)
from ident.models.library import ShockLibrary, read_shock_library, write_shock_library
from ident.models.shocks import is_real_number

__all__ = [
    "SESSION_FORMAT",
    "THIRD_ELEMENT_KEYS",
    "third_elements_note",
    "MANIFEST_NAME",
    "RUN_ROLES",
    "BUMP_STOP_LIBRARY_NAME",
    "STATIC_OFFSET_SHARE",
    "STATIC_LOAD_RTOL",
    "Run",
    "Session",
    "read_session",
    "write_session",
    "make_session",
    "append_runs",
    "check_static_corner_loads",
]

logger = logging.getLogger(__name__)

#: Value of the manifest's ``format`` key understood by this version.
SESSION_FORMAT = "rig-session/1"
#: File name of the manifest inside a session folder.
MANIFEST_NAME = "session.toml"
#: Allowed values of a run's ``role``.
RUN_ROLES = ("baseline", "swap", "validation", "other")
#: File name of the bump-stop library :func:`write_session` writes.
BUMP_STOP_LIBRARY_NAME = "bumpstops.toml"
#: A run's ``tire_force_XX`` carries the static load when the magnitude of its mean is
#: above this share of the corner's static load: a dynamic channel's mean is near 0 (the
#: drive moves the car about its rest, and tapered drives start and end at rest), while a
#: channel with the static offset has a mean near the load itself. A fifth leaves room for
#: a drive's mean aero load and a load cell's drift on either side.
STATIC_OFFSET_SHARE = 0.2
#: Where ``tire_force_XX`` carries the static load, its run mean may differ from the static
#: load given by at most this share: a drive's mean aero load above the actuators' static
#: preload and the load cell's zero drift move it by a few per cent, while the usual
#: mistakes (another corner's load, lbf written as N, the weight without the aero preload,
#: the sign) are far beyond.
STATIC_LOAD_RTOL = 0.10

_RUN_FORMATS = {"csv": ".csv", "parquet": ".parquet"}
_MANIFEST_KEYS = ("format", "name", "units", "shock_library", "run", "channels",
                  "bump_stop_library", "static_corner_load", "third_elements")
_RUN_KEYS = ("name", "file", "setup", "role", "bump_stops", "packers", "third", "heave_springs",
             "heave_packers")
_MANIFEST_TYPES = {"format": str, "name": str, "units": str, "shock_library": str, "run": list,
                   "channels": dict, "bump_stop_library": str, "static_corner_load": dict,
                   "third_elements": dict}
#: Keys of one run that a manifest may hold only under a [[run]], and the reverse.
_RUN_ONLY_KEYS = ("bump_stops", "packers", "third", "heave_springs", "heave_packers")
_SESSION_ONLY_KEYS = ("bump_stop_library", "static_corner_load", "third_elements")
#: Optional manifest keys that state the sample rate [Hz]: checked against the run files
#: (the rate itself always comes from their ``time`` column).
_RATE_KEYS = ("fs_hz", "fs", "sample_rate", "sample_rate_hz", "sampling_rate_hz")

# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False, kw_only=True)
class Run:
    """One rig run of a session: its shock setup and its measured signals (SI).

    Attributes
    ----------
    name : str
        Run name, unique within the session.
    file : str
        The run file as written in the manifest (relative to the session folder).
    setup : dict of str to str
        Corner (``LF``, ``RF``, ``LR``, ``RR``) -> shock id in the session's library.
    role : {"baseline", "swap", "validation", "other"}
        What the run is for (default ``"other"``).
    time_s : ndarray, shape (n_samples,)
        Sample times [s] (read-only).
    channels : dict of str to ndarray, shape (n_samples,)
        Canonical channel name -> samples in SI units, static offsets included
        (float64, read-only). A checked run has all 7 rig inputs, or the 4
        wheelloaders only (a 4-post rig: no aero channels).
    fs_hz : float
        Sample rate [Hz].
    bump_stops : dict of str to (str or None)
        Corner -> id of the bump stop fitted on the run, in the session's bump-stop
        library, or None for none (the default, also for ``bump_stops=None``, at every
        corner). A checked run has all four corners.
    packers_m : dict of str to float
        Corner -> packer thickness [m] (default 0 at every corner). A checked run has
        all four corners.
    third : ident.data.third.RunThird
        The third elements fitted on the run (its ``third``, ``heave_springs`` and
        ``heave_packers``; default none).

    Notes
    -----
    The arrays are copied to read-only float64 on construction; the data are
    checked by :func:`read_session` and :func:`make_session`, not here.
    """

    name: str
    file: str
    setup: dict
    role: str = "other"
    time_s: np.ndarray
    channels: dict
    fs_hz: float
    bump_stops: dict = field(default_factory=lambda: dict.fromkeys(CORNERS))
    packers_m: dict = field(default_factory=lambda: dict.fromkeys(CORNERS, 0.0))
    third: RunThird = field(default_factory=RunThird)

    def __post_init__(self):
        object.__setattr__(self, "setup", dict(self.setup))
        if self.third is None:
            object.__setattr__(self, "third", RunThird())
        object.__setattr__(self, "bump_stops", dict.fromkeys(CORNERS) if self.bump_stops is None
                           else dict(self.bump_stops))
        object.__setattr__(self, "packers_m", dict.fromkeys(CORNERS, 0.0)
                           if self.packers_m is None else dict(self.packers_m))
        object.__setattr__(self, "time_s", frozen_array(self.time_s))
        object.__setattr__(
            self, "channels", {k: frozen_array(v) for k, v in dict(self.channels).items()}
        )
        object.__setattr__(self, "fs_hz", float(self.fs_hz))

    @property
    def n_samples(self):
        """int: Number of samples of the run."""
        return int(self.time_s.shape[0])

    def dynamic(self, channel):
        """Return the dynamic part of a channel: its samples minus the run's mean.

        Parameters
        ----------
        channel : str
            Canonical channel name (e.g. ``"tire_force_LF"``).

        Returns
        -------
        ndarray, shape (n_samples,)
            The signal in SI units with its mean over the run removed (a new array).

        Raises
        ------
        SessionError
            If the run has no such channel.
        """
        try:
            x = self.channels[channel]
        except KeyError:
            raise SessionError(
                f"run {self.name!r} has no channel {channel!r}; it has "
                f"{list(self.channels)}"
            ) from None
        return x - x.mean()


@dataclass(frozen=True, eq=False, kw_only=True)
class Session:
    """A checked rig session: runs, their setups and the shock library.

    Attributes
    ----------
    path : pathlib.Path or None
        The session folder it was read from (``None`` when built in memory).
    name : str
        Session name.
    units : {"SI", "imperial"}
        Unit system of the files (the default when the session is written again);
        the arrays in memory are always SI.
    runs : tuple of Run
        The runs, in manifest order.
    shocks : ShockLibrary
        Ordered mapping shock id -> shock model (:mod:`ident.models.shocks`).
    shock_library_file : str
        The shock library as named in the manifest (relative to the folder).
    fs_hz : float
        The sample rate shared by all runs [Hz].
    channel_map : dict of str to str
        The manifest's ``[channels]`` table (canonical name -> file column).
    extra : dict
        Manifest keys this version does not know, kept so that writing the
        session again preserves them.
    bump_stops : BumpStopLibrary or None
        The bump stops the runs name (:mod:`ident.models.bumpstops`), None when the
        manifest names no ``bump_stop_library``.
    bump_stop_library_file : str or None
        The bump-stop library as named in the manifest (relative to the folder).
    static_corner_load_n : ndarray, shape (4,), or None
        The tires' static loads [N] in corner order ``LF, RF, LR, RR`` (the car at rest
        on the rig, with the aero actuators' static preload; read-only), None when the
        manifest gives none.
    third_elements : ident.data.third.ThirdElements
        The car's third elements and their motion ratios (the manifest's
        ``third_elements``; empty when it declares none).
    """

    path: Path | None
    name: str
    units: str
    runs: tuple
    shocks: Mapping
    shock_library_file: str
    fs_hz: float
    channel_map: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    bump_stops: Mapping | None = None
    bump_stop_library_file: str | None = None
    static_corner_load_n: np.ndarray | None = None
    third_elements: ThirdElements = field(default_factory=ThirdElements)

    def __post_init__(self):
        object.__setattr__(self, "runs", tuple(self.runs))
        if self.third_elements is None:
            object.__setattr__(self, "third_elements", ThirdElements())
        if self.static_corner_load_n is not None:
            object.__setattr__(self, "static_corner_load_n",
                               frozen_array(self.static_corner_load_n))

    @property
    def rig_inputs(self):
        """tuple of str: The rig inputs of the session's runs, in ``RIG_INPUTS`` order.

        All 7 on a rig with aero actuators (7-post, 8-post), the 4 wheelloaders
        on a 4-post rig; every run of a checked session has the same set, and
        it is the identified model's rig inputs.
        """
        return rig_inputs_of(self.runs[0].channels) if self.runs else RIG_INPUTS

    @property
    def run_names(self):
        """tuple of str: The run names, in manifest order."""
        return tuple(r.name for r in self.runs)

    def run(self, name):
        """Return the run called `name`.

        Raises
        ------
        SessionError
            If the session has no such run (the message lists the runs).
        """
        for r in self.runs:
            if r.name == name:
                return r
        raise SessionError(
            f"session {self.name!r} has no run {name!r}; its runs are {list(self.run_names)}"
        )


# --------------------------------------------------------------------------------------
# Session-level checks (shared by read_session and make_session)
# --------------------------------------------------------------------------------------


def _check_setup(setup, shocks, *, where, library):
    """Return the setup as ``{corner: id}`` in CORNERS order, or raise."""
    setup = corner_table(setup, name="setup", where=where, what='shock ids ("id")',
                         error=SessionError, type_error=SessionError)
    missing = [c for c in CORNERS if c not in setup]
    if missing:
        raise SessionError(
            f"{where}: setup is missing corner(s) {', '.join(missing)}; give a shock id "
            f"for all four corners {', '.join(CORNERS)}"
        )
    for corner in CORNERS:
        sid = setup[corner]
        if not isinstance(sid, str) or sid not in shocks:
            raise SessionError(
                f"{where}: setup {corner} = {sid!r} is not in the shock library "
                f"{library} (known ids: {', '.join(map(str, shocks)) or 'none'}); add it "
                "to the library or fix the id"
            )
    return {c: setup[c] for c in CORNERS}


def _check_role(role, *, where):
    if role not in RUN_ROLES:
        raise SessionError(
            f"{where}: role {role!r} is not one of {', '.join(RUN_ROLES)}; fix or omit "
            "it (default 'other')"
        )
    return role


def _check_unique_names(names, *, where):
    seen = set()
    for name in names:
        if name in seen:
            raise SessionError(
                f"{where}: run name {name!r} is used more than once; run names must be "
                "unique"
            )
        seen.add(name)


def _check_same_rig_inputs(runs, *, where):
    """Every run of a session has the same rig inputs (with or without aero channels)."""
    first = runs[0]
    want = rig_inputs_of(first.channels)
    for r in runs[1:]:
        got = rig_inputs_of(r.channels)
        if got != want:
            def kind(inputs):
                return "aero channels" if "aero_heave" in inputs else "no aero channels (4-post)"
            raise SessionError(
                f"{where}: run {r.name!r} ({r.file}) has {kind(got)} but run {first.name!r} "
                f"({first.file}) has {kind(want)}; every run of a session has the same rig "
                "inputs (they are the identified model's): put runs of a 4-post rig and of a "
                "rig with aero actuators in separate sessions"
            )


def _check_run_set(runs, *, where):
    """Check there are runs with unique names sharing one sample rate; return it."""
    if not runs:
        raise SessionError(
            f"{where}: the session has no runs; add at least one [[run]] with name, "
            "file and setup"
        )
    _check_unique_names([r.name for r in runs], where=where)
    _check_same_rig_inputs(runs, where=where)
    first = runs[0]
    for r in runs[1:]:
        if abs(r.fs_hz - first.fs_hz) > RTOL_TIME_STEP * first.fs_hz:
            raise SessionError(
                f"{where}: runs {first.name!r} ({first.fs_hz:.9g} Hz) and {r.name!r} "
                f"({r.fs_hz:.9g} Hz) have different sample rates; all runs of a session "
                "share one sample rate: resample them to a common rate"
            )
    return first.fs_hz


def _run_where(name, file_path):
    return f"run {name!r} ({file_path})"


def _check_bump_stops(bump_stops, packers_m, library, *, where):
    """A run's bump stops and packers [m], checked; ``({corner: id or None},
    {corner: m})`` in corner order.

    `library` is the session's bump-stop library, or None when it has none (then a run
    naming a bump stop is refused).
    """
    stops = corner_table(bump_stops, name="bump_stops", where=where,
                         what='bump-stop ids or "none"', error=SessionError,
                         type_error=SessionError)
    ids = {}
    for c in CORNERS:
        sid = stops.get(c)
        if sid is not None:
            sid = parse_bump_stop_id(sid, f"{where}: bump_stops {c}", error=SessionError)
        if sid is not None and library is None:
            raise SessionError(
                f"{where}: bump_stops {c} = {sid!r} but the session has no bump-stop "
                "library; name it at the top of the manifest with bump_stop_library = "
                f"\"{BUMP_STOP_LIBRARY_NAME}\" (make_session: bump_stops=), or remove the "
                "run's bump_stops")
        if sid is not None and sid not in library:
            raise library.unknown_id_error(sid, where=f"{where}: bump_stops {c}",
                                           error=SessionError)
        ids[c] = sid
    given = corner_table(packers_m, name="packers", where=where,
                         what="thicknesses (numbers >= 0)", error=SessionError,
                         type_error=SessionError)
    packers = {}
    for c in CORNERS:
        p = given.get(c, 0.0)
        if sid := ids[c]:
            packers[c] = check_packer(library[sid], p, f"{where}: packers {c}",
                                      error=SessionError)
            continue
        if not is_real_number(p) or not np.isfinite(p) or p < 0:
            raise SessionError(f"{where}: packers {c} = {p!r} is not a thickness; give a "
                               "number >= 0 (0 = none)")
        if p:
            logger.warning("%s: packers %s = %g m at a corner without a bump stop has no "
                           "effect", where, c, p)
        packers[c] = float(p)
    return ids, packers


def _check_static_loads(value, *, where, key, unit):
    """The static corner loads as an array (4,) in the units given, or raise."""
    if value is None:
        return None
    loads = corner_table(value, name=key, where=where, what=f"positive numbers ({unit})",
                         error=SessionError, type_error=SessionError, sequence=True)
    missing = [c for c in CORNERS if c not in loads]
    if missing:
        raise SessionError(f"{where}: {key} has no load for corner(s) {', '.join(missing)}; "
                           f"give the static tire load of all four corners ({unit})")
    for c in CORNERS:
        x = loads[c]
        if not is_real_number(x) or not np.isfinite(x) or x <= 0:
            raise SessionError(
                f"{where}: {key} {c} = {x!r} is not a load; give the tire's static load on "
                f"its pad, a positive number ({unit}, compression positive)")
    return np.array([float(loads[c]) for c in CORNERS])


def check_static_corner_loads(value, where, *, key="static_corner_load_n", unit="N"):
    """The tires' static loads as a session holds them, or raise.

    Parameters
    ----------
    value : mapping of str to float, array_like, shape (4,), or None
        Per corner ``{LF = ..., ...}`` (all four) or in corner order ``LF, RF, LR, RR``.
    where : str
        The file or object, put first in messages.
    key : str
        The key or argument named in messages.
    unit : str
        The unit of `value` named in messages (the values are returned as given: convert
        them with :func:`ident.data.units.to_si` where they are not SI).

    Returns
    -------
    ndarray, shape (4,), or None
        The loads in corner order, read-only; None for None.

    Raises
    ------
    SessionError
        If a corner is missing or unknown, or a load is not a positive finite number.
    """
    loads = _check_static_loads(value, where=where, key=key, unit=unit)
    return None if loads is None else frozen_array(loads)


def _check_static_vs_tire(runs, loads_n, *, where_run, units, key="static_corner_load"):
    """Refuse static loads that the tire-force channels carrying the static load deny."""
    if loads_n is None:
        return
    unit = UNIT_LABELS[units]["force"]
    for r in runs:
        for c, load in zip(CORNERS, loads_n):
            x = r.channels.get(f"tire_force_{c}")
            if x is None:
                continue
            mean = float(np.mean(x))
            if abs(mean) <= STATIC_OFFSET_SHARE * load:
                continue  # the dynamic part only: nothing to compare
            if abs(mean - load) > STATIC_LOAD_RTOL * load:
                m, g = from_si(mean, "force", units), from_si(float(load), "force", units)
                raise SessionError(
                    f"{where_run(r)}: tire_force_{c} has a mean of {m:.6g} {unit}, so it "
                    f"carries the static load, but {key} {c} = {g:.6g} {unit} "
                    f"({(mean - load) / load:+.0%}, more than {STATIC_LOAD_RTOL:.0%} off); "
                    f"fix {key} {c} (the tire's load on its pad with the car at "
                    "rest and the aero preload on, compression positive), or the channel's "
                    "offset or sign")


# --------------------------------------------------------------------------------------
# Sessions
# --------------------------------------------------------------------------------------


def _manifest_paths(path):
    path = Path(path)
    if path.is_dir() or path.suffix.lower() != ".toml":
        folder, manifest = path, path / MANIFEST_NAME
    else:
        folder, manifest = path.parent, path
    if not folder.is_dir():
        raise SessionError(
            f"{folder}: session folder not found; give the folder holding "
            f"{MANIFEST_NAME}, shocks.toml and the run files"
        )
    if not manifest.is_file():
        raise SessionError(
            f"{manifest}: session manifest not found; a session folder holds "
            f"{MANIFEST_NAME} (see shared/spec/rig-session.md)"
        )
    return folder, manifest


def _manifest_str(doc, key, *, where, default=None):
    value = doc.get(key, default)
    if not isinstance(value, str) or not value.strip():
        raise SessionError(
            f"{where}: '{key}' must be a non-empty string, got {value!r}"
        )
    return value


def _parse_run_entries(entries, *, where):
    """Check the manifest's ``[[run]]`` entries (structure only); return plain dicts."""
    if entries is None or (isinstance(entries, list) and not entries):
        raise SessionError(
            f"{where}: no runs; add at least one [[run]] with name, file and setup"
        )
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise SessionError(
            f"{where}: 'run' must be an array of tables ([[run]] sections)"
        )
    parsed = []
    for i, entry in enumerate(entries, start=1):
        label = f"{where}: [[run]] #{i}"
        if isinstance(entry.get("name"), str) and entry["name"].strip():
            label = f"{where}: run {entry['name']!r}"
        for key in ("name", "file", "setup"):
            if key not in entry:
                raise SessionError(
                    f"{label}: missing '{key}'; every [[run]] needs name, file and setup"
                )
        name = _manifest_str(entry, "name", where=label)
        file = _manifest_str(entry, "file", where=label)
        role = _check_role(entry.get("role", "other"), where=label)
        unknown = [k for k in entry if k not in _RUN_KEYS]
        for key in unknown:
            if key in _SESSION_ONLY_KEYS:  # written below a [[run]], TOML gives it to the run
                raise SessionError(
                    f"{label}: {key!r} is a key of the session, not of a run; move it to the "
                    "top of the manifest, before the first [[run]]")
            hint = did_you_mean(key, _RUN_KEYS)
            if hint:
                raise SessionError(
                    f"{label}: unknown key {key!r}{hint}; a [[run]] has the keys "
                    f"{', '.join(_RUN_KEYS)}"
                )
        if unknown:
            logger.warning("%s: unknown key(s) %s are ignored", label, unknown)
        parsed.append({"name": name, "file": file, "setup": entry["setup"],
                       "role": role, "label": label, "bump_stops": entry.get("bump_stops"),
                       "packers": entry.get("packers"), "third": entry.get("third"),
                       "heave_springs": entry.get("heave_springs"),
                       "heave_packers": entry.get("heave_packers")})
    return parsed


def _check_extra_keys(extra, *, where):
    """Refuse near-misses of manifest keys; check a stated sample rate; warn about the rest.

    Returns ``(key, rate_hz)`` for a stated sample rate, else None.
    """
    stated = None
    for key, value in extra.items():
        if key in _RATE_KEYS:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not np.isfinite(value) or value <= 0:
                raise SessionError(
                    f"{where}: {key} = {value!r} is not a sample rate (a number > 0 Hz); the "
                    "rate comes from the run files' 'time' column: fix or remove the key"
                )
            stated = (key, float(value))
            continue
        if key in _RUN_ONLY_KEYS:
            raise SessionError(
                f"{where}: {key!r} is a key of a run (what was fitted on that run); move it "
                "into each [[run]] that had it")
        hint = did_you_mean(key, _MANIFEST_KEYS)
        # a typo has the value of the key it misspells: a table [notes] is no 'units'
        if hint and isinstance(value, _MANIFEST_TYPES[hint.split("'")[1]]):
            raise SessionError(
                f"{where}: unknown key {key!r}{hint}; the manifest's keys are "
                f"{', '.join(_MANIFEST_KEYS)} (see shared/spec/rig-session.md)"
            )
        logger.warning("%s: key %r is not part of the rig-session format; it is kept but "
                       "not used", where, key)
    return stated


#: The keys of the spec's optional section "Third elements" (heave and roll elements per
#: axle): read and checked (:mod:`ident.data.third`), not yet modelled by the
#: identification and the predictions.
THIRD_ELEMENT_KEYS = ("third_elements", "third", "heave_springs", "heave_packers")


def third_elements_note(where, key, elements):
    """The one line logged (info) for a session that declares third elements: which, and
    what shockplan does with them."""
    return (f"{where}: {key!r} declares third elements {', '.join(elements)} (heave or roll "
            "elements per axle, the spec's optional section 'Third elements'): the "
            "identification takes their forces out of the linear car and predictions put "
            "them in the loop")


def _check_session_third(third_elements, entries, shocks, bump_stops, *, where, units,
                         library):
    """The session's elements and each run entry's (``third``, ``heave_springs``,
    ``heave_packers`` in file units): ``(ThirdElements, [RunThird, ...])``, warning once
    when any is declared."""
    elements = check_third_elements(third_elements, where)
    runs = []
    for e in entries:
        packers = e.get("heave_packers")
        if isinstance(packers, dict):
            packers = {a: to_si(p, "displacement", units) if is_real_number(p) else p
                       for a, p in packers.items()}
        runs.append(check_run_third(e.get("third"), e.get("heave_springs"), packers,
                                    elements=elements, shocks=shocks, bump_stops=bump_stops,
                                    where=e["label"], library=library))
    if elements:
        logger.info(third_elements_note(where, "third_elements", elements.elements))
    elif any(runs):  # pragma: no cover - a run's element needs a declared one
        raise SessionError(f"{where}: runs fit third elements the session does not declare")
    return elements, runs


def _read_bump_stop_library(doc, folder, *, where):
    """``(file as named, BumpStopLibrary)`` of the manifest's bump_stop_library, or
    ``(None, None)``."""
    if "bump_stop_library" not in doc:
        return None, None
    bump_file = _manifest_str(doc, "bump_stop_library", where=where)
    bump_path = folder / bump_file
    if not bump_path.is_file():
        raise SessionError(
            f"{where}: bump_stop_library {bump_file!r} not found ({bump_path}); put the "
            "bump-stop library beside the manifest or fix the path")
    try:
        return bump_file, read_bump_stops(bump_path)
    except BumpStopError as exc:
        raise SessionError(f"{where}: bump_stop_library {bump_file!r}: {exc}") from exc


def read_session(path, *, resample_hz=None):
    """Read and check a rig session folder.

    Parameters
    ----------
    path : str or os.PathLike
        The session folder, or its ``session.toml``.
    resample_hz : float, optional
        Resample every run onto a uniform base at this rate [Hz] (``--resample``: runs
        logged at different rates, or a rate chosen for the model; band-limited,
        anti-aliased when going down; :func:`ident.data.runs.read_run_table`), each said
        in a logged warning. Default: the run files' rate (which must be one).

    Returns
    -------
    Session
        Runs with SI signals under canonical names, the shock library and the
        common sample rate. Responses are loaded as present; which ones a stage
        needs (e.g. ``shock_velocity_XX`` for identification) is that stage's check.

    Raises
    ------
    SessionError
        One clear message naming the file, run, channel or field, and the fix, if:
        the folder or manifest is missing; the manifest is not valid TOML; its
        ``format`` is missing or not ``"rig-session/1"``; ``units`` is unknown;
        there are no runs; a run lacks name, file or setup; two runs share a name;
        a setup names an unknown corner, misses a corner or names a shock id not in
        the library; a role is invalid; ``[channels]`` names an unknown canonical
        channel; the shock library is missing or malformed (the
        :class:`~ident.errors.ShockModelError` is chained); a run file is missing,
        unreadable, has fewer than 2 rows, misses a wheelloader, has some but not
        all three aero channels, holds NaN/inf or non-numeric values, has
        non-uniform time or a unit marker that disagrees with the manifest's
        ``units``; or the runs have different sample rates or different
        rig inputs (runs with and without aero channels). For the real car (all
        optional): the bump-stop library is missing or malformed (the
        :class:`~ident.errors.BumpStopError` is chained); a run names a bump stop
        without a ``bump_stop_library``, or an id not in it (naming the run, the
        corner, the library file and its ids); a packer is negative or thicker
        than its bump stop's gap; ``static_corner_load`` is not 4 positive numbers;
        a run's ``tire_force_XX`` carries the static load (its mean is above
        :data:`STATIC_OFFSET_SHARE` of the load) and differs from it by more than
        :data:`STATIC_LOAD_RTOL`; ``bump_stops`` or ``packers`` stand outside a
        ``[[run]]``, or a session key (``static_corner_load``,
        ``bump_stop_library``) inside one.

    Notes
    -----
    The real car's keys (the spec's "The real car"): ``bump_stop_library`` (read
    into :attr:`Session.bump_stops`), per run ``bump_stops = { LF = "BS-F", ... }``
    (a corner left out, or ``"none"``, has none) and ``packers = { LF = 0.003 }``
    (file units, default 0), kept as :attr:`Run.bump_stops` and
    :attr:`Run.packers_m`, and ``static_corner_load`` (file units) as
    :attr:`Session.static_corner_load_n`. A manifest without them reads as before.
    """
    folder, manifest = _manifest_paths(path)
    where = str(manifest)
    doc = read_toml(manifest, error=SessionError, what="session manifest")

    fmt = doc.get("format")
    if fmt is None:
        raise SessionError(
            f"{where}: missing 'format'; the manifest must start with "
            f"format = \"{SESSION_FORMAT}\""
        )
    if fmt != SESSION_FORMAT:
        raise SessionError(
            f"{where}: format {fmt!r} is not supported; this version reads "
            f"format = \"{SESSION_FORMAT}\""
        )
    units = check_session_units(doc.get("units", "SI"), where=f"{where}: units")
    name = _manifest_str(doc, "name", where=where, default=folder.resolve().name)
    library_file = _manifest_str(doc, "shock_library", where=where, default="shocks.toml")
    channel_map = check_channel_map(doc.get("channels"), where=where)
    entries = _parse_run_entries(doc.get("run"), where=where)
    extra = {k: v for k, v in doc.items() if k not in _MANIFEST_KEYS}
    stated_rate = _check_extra_keys(extra, where=where)

    library_path = folder / library_file
    if not library_path.is_file():
        raise SessionError(
            f"{where}: shock_library {library_file!r} not found ({library_path}); "
            "put the shock library beside the manifest or fix the path"
        )
    try:
        shocks = read_shock_library(library_path)
    except ShockModelError as exc:
        raise SessionError(f"{where}: shock_library {library_file!r}: {exc}") from exc

    setups = [_check_setup(e["setup"], shocks, where=e["label"], library=library_file)
              for e in entries]
    bump_file, bump_stops = _read_bump_stop_library(doc, folder, where=where)
    static = _check_static_loads(doc.get("static_corner_load"), where=where,
                                 key="static_corner_load",
                                 unit=UNIT_LABELS[units]["force"])
    static = None if static is None else to_si(static, "force", units)
    elements = []
    for e in entries:
        packers = corner_table(e["packers"], name="packers", where=e["label"],
                               what="thicknesses (numbers >= 0)", error=SessionError,
                               type_error=SessionError)
        packers = {c: to_si(p, "displacement", units) if is_real_number(p) else p
                   for c, p in packers.items()}
        elements.append(_check_bump_stops(e["bump_stops"], packers, bump_stops,
                                          where=e["label"]))
    third_elements, thirds = _check_session_third(
        doc.get("third_elements"), entries, shocks, bump_stops, where=where, units=units,
        library=library_file)
    # before reading any run file: a cheap, manifest-only mistake
    _check_unique_names([e["name"] for e in entries], where=where)

    runs = []
    for e, setup, (stops, packers), third in zip(entries, setups, elements, thirds):
        file_path = folder / e["file"]
        run_where = _run_where(e["name"], file_path)
        if not file_path.is_file():
            raise SessionError(
                f"{run_where}: run file not found; fix the run's 'file' in {where} "
                "(paths are relative to the manifest)"
            )
        table = read_run_table(
            file_path, units=units, channel_map=channel_map, required=WHEELLOADER_INPUTS,
            where=run_where, units_from=f"the manifest ({where}: units = \"{units}\")",
            units_fix="make them agree: set the manifest's units to the run files' unit "
            "system, or correct the run file's 'units' column (or '# units:' line)",
            resample_hz=resample_hz)
        runs.append(Run(name=e["name"], file=e["file"], setup=setup, role=e["role"],
                        time_s=table.time_s, channels=table.channels,
                        fs_hz=table.fs_hz, bump_stops=stops, packers_m=packers,
                        third=third))
    fs_hz = _check_run_set(runs, where=where)
    _check_static_vs_tire(runs, static, units=units,
                          where_run=lambda r: f"{where}: {_run_where(r.name, folder / r.file)}")
    if (stated_rate is not None and resample_hz is None  # else the files' rate is gone
            and abs(stated_rate[1] - fs_hz) > RTOL_TIME_STEP * fs_hz):
        raise SessionError(
            f"{where}: {stated_rate[0]} = {stated_rate[1]:g} disagrees with the run files, "
            f"whose 'time' column gives {fs_hz:.9g} Hz; fix or remove {stated_rate[0]} (the "
            "sample rate always comes from the time column)"
        )
    logger.info("read session %r: %d run(s) at %.6g Hz from %s", name, len(runs),
                fs_hz, folder)
    return Session(path=folder, name=name, units=units, runs=tuple(runs), shocks=shocks,
                   shock_library_file=library_file, fs_hz=fs_hz,
                   channel_map=channel_map, extra=extra, bump_stops=bump_stops,
                   bump_stop_library_file=bump_file, static_corner_load_n=static,
                   third_elements=third_elements)


def make_session(name, runs, shocks, *, units="SI", bump_stops=None,
                 static_corner_load_n=None, third_elements=None):
    """Build a checked :class:`Session` from in-memory runs.

    Parameters
    ----------
    name : str
        Session name.
    runs : iterable of Run
        The runs, with SI signals under canonical names; each ``fs_hz`` must agree
        with its ``time_s``.
    shocks : ShockLibrary or mapping of str to ShockModel
        The shock models named by the runs' setups.
    units : {"SI", "imperial"}
        Unit system used when the session is written (the arrays stay SI).
    bump_stops : BumpStopLibrary or iterable of BumpStop, optional
        The bump stops named by the runs' ``bump_stops`` (default: none, and no run may
        name one).
    static_corner_load_n : mapping of str to float, or array_like, shape (4,), optional
        The tires' static loads [N], per corner or in corner order ``LF, RF, LR, RR``.
    third_elements : ident.data.third.ThirdElements or mapping of str to float, optional
        The car's third elements and their motion ratios (default none: no run may fit
        one); each run's :attr:`Run.third` is checked against them and the libraries.

    Returns
    -------
    Session
        With ``path=None``, ``shock_library_file="shocks.toml"``,
        ``bump_stop_library_file="bumpstops.toml"`` when `bump_stops` is given (else
        None) and no ``[channels]`` mapping.

    Raises
    ------
    SessionError
        On the same problems :func:`read_session` reports for a run's setup,
        role, rig inputs, samples and time, duplicated run names and different
        sample rates (one engine checks both), a run's bump stops and packers,
        static loads (as :func:`read_session`), or a run's ``fs_hz`` that
        disagrees with its ``time_s``.
    """
    where = f"session {name!r}"
    if not isinstance(name, str) or not name.strip():
        raise SessionError(f"session name must be a non-empty string, got {name!r}")
    units = check_session_units(units, where=f"{where}: units")
    if not isinstance(shocks, ShockLibrary):
        shocks = ShockLibrary(shocks)
    if bump_stops is not None and not isinstance(bump_stops, BumpStopLibrary):
        bump_stops = BumpStopLibrary(bump_stops)
    static = _check_static_loads(static_corner_load_n, where=where,
                                 key="static_corner_load_n", unit="N")
    if isinstance(third_elements, ThirdElements):
        third_elements = dict(third_elements.motion_ratios)
    runs = list(runs)
    for r in runs:
        if not isinstance(r, Run):
            raise SessionError(f"{where}: runs must be Run objects, got {type(r).__name__}")
    third_elements, thirds = _check_session_third(
        third_elements, [{"label": _run_where(r.name, r.file), "third": r.third.dampers,
                          "heave_springs": r.third.heave_springs,
                          "heave_packers": r.third.heave_packers_m} for r in runs],
        shocks, bump_stops, where=where, units="SI", library="of the session")
    checked = []
    for r, third in zip(runs, thirds):
        if not isinstance(r, Run):
            raise SessionError(f"{where}: runs must be Run objects, got {type(r).__name__}")
        run_where = _run_where(r.name, r.file)
        setup = _check_setup(r.setup, shocks, where=run_where, library="of the session")
        role = _check_role(r.role, where=run_where)
        stops, packers = _check_bump_stops(r.bump_stops, r.packers_m, bump_stops,
                                           where=run_where)
        columns = in_memory_columns(r.time_s, r.channels, where=run_where)
        time_s, channels, fs_hz = check_columns(
            columns, where=run_where, units="SI", channel_map={}, required=WHEELLOADER_INPUTS
        )
        if abs(fs_hz - r.fs_hz) > RTOL_TIME_STEP * fs_hz:
            raise SessionError(
                f"{run_where}: fs_hz = {r.fs_hz:.9g} Hz disagrees with its time_s "
                f"({fs_hz:.9g} Hz); pass fs_hz = 1 / time step"
            )
        checked.append(Run(name=r.name, file=r.file, setup=setup, role=role,
                           time_s=time_s, channels=channels, fs_hz=fs_hz,
                           bump_stops=stops, packers_m=packers, third=third))
    fs_hz = _check_run_set(checked, where=where)
    _check_static_vs_tire(checked, static, units="SI", key="static_corner_load_n",
                          where_run=lambda r: _run_where(r.name, r.file))
    return Session(path=None, name=name, units=units, runs=tuple(checked), shocks=shocks,
                   shock_library_file="shocks.toml", fs_hz=fs_hz, bump_stops=bump_stops,
                   bump_stop_library_file=None if bump_stops is None
                   else BUMP_STOP_LIBRARY_NAME, static_corner_load_n=static,
                   third_elements=third_elements)


def _safe_stem(name):
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "run"
    return stem


def _toml_value(value):
    """Render one TOML value (string, number, inline table) via tomli_w."""
    return tomli_w.dumps(round_file_numbers({"x": value})).partition("=")[2].strip()


def _inline_table(values):
    """``{ LF = ..., RF = ... }``: a TOML inline table of corner values."""
    return "{ " + ", ".join(f"{c} = {_toml_value(v)}" for c, v in values.items()) + " }"


def _run_block(run, file, *, units):
    """The ``[[run]]`` table of a run in the manifest; ``bump_stops`` and ``packers`` only
    where the run has some (so a run without them is written as before)."""
    setup = ", ".join(f"{c} = {_toml_value(run.setup[c])}" for c in CORNERS)
    text = ("\n[[run]]\n"
            f"name = {_toml_value(run.name)}\n"
            f"file = {_toml_value(file)}\n"
            f"setup = {{ {setup} }}\n"
            f"role = {_toml_value(run.role)}\n")
    stops = {c: run.bump_stops[c] for c in CORNERS if run.bump_stops.get(c) is not None}
    if stops:
        text += f"bump_stops = {_inline_table(stops)}\n"
    packers = {c: from_si(float(run.packers_m[c]), "displacement", units) for c in CORNERS
               if run.packers_m.get(c, 0.0)}
    if packers:
        text += f"packers = {_inline_table(packers)}\n"
    third = {k: v for k, v in run.third.dampers.items() if v is not None}
    if third:
        text += f"third = {_inline_table(third)}\n"
    springs = {a: v for a, v in run.third.heave_springs.items() if v is not None}
    if springs:
        text += f"heave_springs = {_inline_table(springs)}\n"
    packers = {a: from_si(float(p), "displacement", units)
               for a, p in run.third.heave_packers_m.items() if p}
    if packers:
        text += f"heave_packers = {_inline_table(packers)}\n"
    return text


def _manifest_text(session, *, units, files):
    head = {"format": SESSION_FORMAT, "name": session.name, "units": units,
            "shock_library": "shocks.toml"}
    if session.bump_stops is not None:
        head["bump_stop_library"] = BUMP_STOP_LIBRARY_NAME
    extra = {}
    for key, value in session.extra.items():
        if key in _MANIFEST_KEYS:
            logger.warning("session extra key %r clashes with a manifest key; not written",
                           key)
            continue
        extra[key] = value
    if session.third_elements:  # an inline table, as in the spec
        head_text = (tomli_w.dumps(round_file_numbers(head)) + "third_elements = "
                     f"{_inline_table(session.third_elements.motion_ratios)}\n")
        loads = ("" if session.static_corner_load_n is None else
                 "static_corner_load = " + _inline_table(dict(zip(CORNERS, (
                     from_si(float(x), "force", units)
                     for x in session.static_corner_load_n)))) + "\n")
        parts = [head_text, loads, tomli_w.dumps(round_file_numbers(extra))]
    elif session.static_corner_load_n is None:
        parts = [tomli_w.dumps(round_file_numbers({**head, **extra}))]
    else:  # an inline table, as in the spec, before any [table] of the extra keys
        loads = dict(zip(CORNERS, (from_si(float(x), "force", units)
                                   for x in session.static_corner_load_n)))
        parts = [tomli_w.dumps(head), f"static_corner_load = {_inline_table(loads)}\n",
                 tomli_w.dumps(round_file_numbers(extra))]
    parts.extend(_run_block(run, file, units=units) for run, file in zip(session.runs, files))
    return "".join(parts)


def _check_target(target, *, overwrite):
    if target.is_file() or (target.exists() and not target.is_dir()):
        raise FileExistsError(
            f"{target}: exists and is not a folder; choose another output folder"
        )
    if target.is_dir() and any(target.iterdir()) and not overwrite:
        raise FileExistsError(
            f"{target}: folder already exists and is not empty; choose another output "
            "folder or pass overwrite=True (--overwrite on the command line)"
        )


def _sibling(target, tag):
    while True:
        candidate = target.parent / f".{target.name}.{tag}-{secrets.token_hex(4)}"
        try:
            candidate.mkdir()  # honours the umask, unlike tempfile.mkdtemp (0700)
            return candidate
        except FileExistsError:  # pragma: no cover - 32 random bits collided
            continue


def write_session(session, path, *, units=None, run_format="csv", overwrite=False,
                  float_dtype="float64"):
    """Write a session folder: ``session.toml``, the libraries and ``runs/``.

    Parameters
    ----------
    session : Session
        The session to write.
    path : str or os.PathLike
        The output folder.
    units : {"SI", "imperial"}, optional
        Unit system of every written value (default: ``session.units``).
    run_format : {"csv", "parquet"}
        File format of the run files, written as ``runs/<name>.csv`` (or
        ``.parquet``); characters unsafe in file names become ``_``.
    overwrite : bool
        Replace an existing non-empty folder.
    float_dtype : {"float64", "float32"}
        The type Parquet run files store the channels in (``time`` is always 64-bit):
        ``"float32"`` makes them a sixth of the CSV's size, at a relative precision of
        6e-8, far finer than a rig sensor's (:func:`ident.data.files.write_parquet_frame`).
        CSV run files are always written with full precision.

    Returns
    -------
    pathlib.Path
        The written folder.

    Notes
    -----
    Everything is built in a temporary sibling folder that is renamed into place
    at the end, so a failure leaves nothing half-written; an existing folder is
    replaced only after the new one is complete. The manifest has no
    ``[channels]`` table (written files use canonical names); unknown manifest
    keys kept in ``session.extra`` are written back. A session with bump stops
    gets ``bumpstops.toml`` and ``bump_stop_library``, its runs' ``bump_stops``
    and ``packers`` (only where a run has some) and ``static_corner_load``, all in
    `units`; a session without them is written exactly as before.

    Raises
    ------
    FileExistsError
        If `path` is a non-empty folder and `overwrite` is false, or is a file.
    ValueError
        If `units` or `run_format` is invalid.
    SessionError
        If a run's data fail the run-file checks.
    """
    units = check_session_units(session.units if units is None else units, where="units")
    if run_format not in _RUN_FORMATS:
        raise ValueError(
            f"run_format {run_format!r} is not supported; use 'csv' or 'parquet'"
        )
    if float_dtype not in FLOAT_DTYPES or (run_format == "csv" and float_dtype != "float64"):
        raise ValueError(f"float_dtype {float_dtype!r} with run_format {run_format!r} is not "
                         "supported; use 'float64', or 'float32' with run_format='parquet'")
    target = Path(path)
    _check_target(target, overwrite=overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)

    files, used = [], set()
    for run in session.runs:
        stem, k = _safe_stem(run.name), 1
        while stem.lower() in used:
            k += 1
            stem = f"{_safe_stem(run.name)}-{k}"
        used.add(stem.lower())
        files.append(f"runs/{stem}{_RUN_FORMATS[run_format]}")

    tmp = _sibling(target, "tmp")
    try:
        (tmp / "runs").mkdir()
        write_shock_library(session.shocks, tmp / "shocks.toml", units=units)
        if session.bump_stops is not None:
            write_bump_stops(session.bump_stops, tmp / BUMP_STOP_LIBRARY_NAME, units=units)
        for run, file in zip(session.runs, files):
            write_run_table(tmp / file, run.time_s, run.channels, units=units,
                            float_dtype=float_dtype)
        atomic_write_text(tmp / MANIFEST_NAME,
                          _manifest_text(session, units=units, files=files))
        _check_target(target, overwrite=overwrite)  # it may have appeared meanwhile
        if target.exists():
            old = _sibling(target, "old")
            os.replace(target, old)  # old is an empty folder: replaced atomically
            try:
                os.replace(tmp, target)
            except OSError:
                os.replace(old, target)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    logger.info("wrote session %r (%d run(s), %s units) to %s", session.name,
                len(session.runs), units, target)
    return target


# --------------------------------------------------------------------------------------
# Appending runs to an existing session
# --------------------------------------------------------------------------------------


def append_runs(path, runs, *, run_format="csv"):
    """Append runs to an existing session folder, leaving everything in it as it was.

    Parameters
    ----------
    path : str or os.PathLike
        The session folder, or its ``session.toml``.
    runs : iterable of Run
        The new runs (SI, canonical names; ``file`` is ignored: each is written
        to ``runs/<name>.csv`` or ``.parquet``, with ``-2``, ``-3`` ... added
        if a file of that name exists).
    run_format : {"csv", "parquet"}
        File format of the new run files.

    Returns
    -------
    Session
        The session as read back from the folder, old runs first.

    Raises
    ------
    SessionError
        If the folder is not a valid session (:func:`read_session`); a new run's
        name is already a run of the session or is repeated; its setup names a
        shock not in the session's library, its role is invalid, it lacks a
        rig input, or its sample rate differs from the session's (the checks
        of :func:`make_session`); or the manifest cannot take appended
        ``[[run]]`` tables (e.g. it writes its runs as an inline array). Nothing
        is changed then.
    ValueError
        If `run_format` is invalid or there are no runs.
    TypeError
        If a run is not a :class:`Run`.

    Notes
    -----
    The existing manifest is kept byte for byte: the new ``[[run]]`` tables are
    appended to its text (comments, ``[channels]`` and unknown keys stay). New
    run files are written in the session's unit system, with the column names
    of its ``[channels]`` table, and are never written over an existing file;
    existing run files and ``shocks.toml`` are not touched. The new manifest is
    written to a temporary file in the folder, read back whole with
    :func:`read_session`, and only then renamed over ``session.toml``; on any
    failure the new run files are removed, so a session is never left
    half-written.
    """
    if run_format not in _RUN_FORMATS:
        raise ValueError(
            f"run_format {run_format!r} is not supported; use 'csv' or 'parquet'"
        )
    runs = list(runs)
    if not runs:
        raise ValueError("append_runs: no runs to append; give at least one Run")
    for r in runs:
        if not isinstance(r, Run):
            raise TypeError(f"append_runs: runs must be Run objects, got {type(r).__name__}")
    folder, manifest = _manifest_paths(path)
    where = str(manifest)
    existing = read_session(folder)
    for r in runs:
        if r.name in existing.run_names:
            raise SessionError(
                f"{where}: run {r.name!r} already exists in session {existing.name!r}; "
                "give the new run another name (nothing was written)"
            )
    # the checks of a whole session (setups, roles, rig inputs, one sample rate)
    combined = make_session(existing.name, list(existing.runs) + runs, existing.shocks,
                            units=existing.units, bump_stops=existing.bump_stops,
                            static_corner_load_n=existing.static_corner_load_n,
                            third_elements=existing.third_elements or None)
    new_runs = combined.runs[len(existing.runs):]

    runs_dir = folder / "runs"
    taken = {r.file.replace("\\", "/").lower() for r in existing.runs}
    if runs_dir.is_dir():
        taken |= {f"runs/{p.name}".lower() for p in runs_dir.iterdir()}
    files = []
    for run in new_runs:
        stem, k = _safe_stem(run.name), 1
        file = f"runs/{stem}{_RUN_FORMATS[run_format]}"
        while file.lower() in taken:
            k += 1
            file = f"runs/{stem}-{k}{_RUN_FORMATS[run_format]}"
        taken.add(file.lower())
        files.append(file)

    old = manifest.read_bytes()
    blocks = [_run_block(run, file, units=existing.units)
              for run, file in zip(new_runs, files)]
    text = ("" if not old or old.endswith(b"\n") else "\n") + "".join(blocks)

    written, tmp = [], None
    try:
        runs_dir.mkdir(exist_ok=True)
        for run, file in zip(new_runs, files):
            write_mapped_run_table(folder / file, run.time_s, run.channels,
                                    units=existing.units, channel_map=existing.channel_map)
            written.append(folder / file)
        tmp = folder / f".{manifest.stem}.append-{secrets.token_hex(4)}.toml"
        tmp.write_bytes(old + text.encode("utf-8"))
        shutil.copymode(manifest, tmp)
        try:
            result = read_session(tmp)
        except SessionError as exc:
            raise SessionError(
                f"{where}: the session with the new runs appended does not read back "
                f"({exc}); nothing was changed"
            ) from exc
        expected = existing.run_names + tuple(r.name for r in new_runs)
        if result.run_names != expected:  # pragma: no cover - a manifest TOML oddity
            raise SessionError(
                f"{where}: appending [[run]] tables gave the runs {list(result.run_names)}, "
                f"not {list(expected)}; add the runs by hand (nothing was changed)"
            )
        if manifest.read_bytes() != old:
            raise SessionError(
                f"{where}: the manifest changed while the runs were being appended; try "
                "again (nothing was changed)"
            )
        os.replace(tmp, manifest)
        tmp = None
    except BaseException:
        for p in written:
            p.unlink(missing_ok=True)
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise
    logger.info("appended %d run(s) to session %r in %s", len(new_runs), existing.name,
                folder)
    return result
