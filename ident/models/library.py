"""The shock library: an ordered mapping of shock models and its file, ``shocks.toml``.

A :class:`ShockLibrary` maps shock ids to the models of :mod:`ident.models.shocks`
(the team's shocks, or a rig session's). :func:`read_shock_library` reads a
``shocks.toml`` into SI models, checking every ``[[shock]]`` table once with a
message that names the file, the shock and the key; :func:`write_shock_library`
writes one atomically, in SI or imperial units.

Examples
--------
>>> from ident.models.shocks import LinearShock, TableShock
>>> b20 = LinearShock("B20", 3502.5)
>>> d8 = TableShock("D8", [-0.5, -0.1, 0.0, 0.1, 0.5],
...                 [-1100.0, -500.0, 0.0, 350.0, 700.0], lag_s=0.004)
>>> lib = ShockLibrary.from_models([b20, d8])
>>> list(lib)
['B20', 'D8']
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from ident.data.files import (atomic_write_toml, check_can_write, did_you_mean, read_toml,
                              write_csv_frame)
from ident.data.units import UNIT_LABELS, from_si, to_si
from ident.errors import ShockModelError
from ident.models.adjustable import (AdjustableShock, format_shock_name, parse_shock_name,
                                     read_dyno_sheets)
from ident.models.shocks import (SHOCK_FITS, SHOCK_KINDS, ShockModel, check_shock_units,
                                  is_real_number)

__all__ = [
    "ShockLibrary",
    "read_shock_library",
    "write_shock_library",
]

logger = logging.getLogger(__name__)


class ShockLibrary(Mapping):
    """An ordered, read-only mapping ``id -> ShockModel``.

    Adjustable shocks (:class:`~ident.models.adjustable.AdjustableShock`) are entries
    too: ``lib["TTX@ls=6,hs=2"]`` is the concrete curve at that setting (a
    :class:`~ident.models.shocks.TableShock` whose id is the canonical name, cached),
    ``lib["TTX"]`` the default setting, and ``"TTX@ls=6" in lib`` is true for any
    setting name of an adjustable entry (a bad setting raises on lookup, naming the
    adjuster). Iteration gives the entries' ids; :meth:`entries` the entries
    themselves.

    Parameters
    ----------
    models : iterable of ShockModel, or mapping id -> ShockModel
        The shocks, in order. Ids must be unique (and equal the keys of a
        mapping).
    source : str or path, optional
        Where the library came from (used in error messages).

    Raises
    ------
    ShockModelError
        On a duplicate id or a mapping key different from the model's id.
    TypeError
        If an item is not a :class:`ShockModel`.

    Notes
    -----
    :meth:`get` raises :class:`ShockModelError` for an unknown id unless a
    default is passed (``dict.get`` returns ``None``): a missing shock is always
    a user error in this project. ``lib[id]`` raises ``KeyError`` as any
    mapping does.

    Examples
    --------
    >>> from ident.models.shocks import LinearShock
    >>> lib = ShockLibrary.from_models([LinearShock("B20", 3502.5)])
    >>> lib.get("B20").c_n_s_m
    3502.5
    >>> "D8" in lib
    False
    """

    __slots__ = ("_models", "_source")

    def __init__(self, models=(), *, source=None):
        items = []
        if isinstance(models, Mapping):
            for key, model in models.items():
                if isinstance(model, ShockModel) and key != model.id:
                    raise ShockModelError(f"shock library: key {key!r} holds shock "
                                          f"{model.id!r}; use the shock's id as the key")
                items.append(model)
        elif isinstance(models, Iterable) and not isinstance(models, (str, bytes)):
            items = list(models)
        else:
            raise TypeError(f"shock library: models must be an iterable of ShockModel, got "
                            f"{type(models).__name__}")
        out = {}
        for j, model in enumerate(items):
            if not isinstance(model, (ShockModel, AdjustableShock)):
                raise TypeError(f"shock library: item {j} is a {type(model).__name__}, not a "
                                "ShockModel; build it with LinearShock, TableShock, "
                                "DigressiveShock or AdjustableShock")
            if model.id in out:
                raise ShockModelError(f"shock library{self._at(source)}: duplicate shock id "
                                      f"{model.id!r} (items {list(out).index(model.id)} and "
                                      f"{j}); give each shock a unique id")
            out[model.id] = model
        self._models = out
        self._source = None if source is None else str(source)

    @staticmethod
    def _at(source):
        return f" {source}" if source else ""

    @classmethod
    def from_models(cls, models, *, source=None):
        """Build a library from shock models (see the class parameters)."""
        return cls(models, source=source)

    @property
    def source(self):
        """str or None: the file the library was read from."""
        return self._source

    @property
    def ids(self):
        """tuple of str: the shock ids, in order."""
        return tuple(self._models)

    @property
    def adjustable_ids(self):
        """tuple of str: the ids of the adjustable entries, in order."""
        return tuple(k for k, m in self._models.items() if isinstance(m, AdjustableShock))

    def entries(self):
        """list of ShockModel or AdjustableShock: the entries as given, in order."""
        return list(self._models.values())

    def entry(self, shock_id):
        """The entry of `shock_id` or of a setting name's base (``KeyError`` if none)."""
        if shock_id in self._models:
            return self._models[shock_id]
        base = shock_id.partition("@")[0].strip() if isinstance(shock_id, str) else shock_id
        return self._models[base]

    def adjustable(self, shock_id):
        """The :class:`~ident.models.adjustable.AdjustableShock` named by `shock_id`.

        Parameters
        ----------
        shock_id : str
            The adjustable's id or one of its setting names.

        Raises
        ------
        ShockModelError
            If the id is unknown or names a fixed shock.
        """
        base = shock_id.partition("@")[0].strip() if isinstance(shock_id, str) else shock_id
        entry = self._models.get(base)
        if not isinstance(entry, AdjustableShock):
            known = list(self.adjustable_ids)
            what = "is not adjustable" if entry is not None else "is not in the library"
            raise ShockModelError(f"shock {base!r} {what}; the adjustable shocks are {known}")
        return entry

    def base_id(self, shock_id):
        """The library entry's id of a shock name (``"TTX@ls=6"`` -> ``"TTX"``)."""
        return shock_id.partition("@")[0].strip() if isinstance(shock_id, str) else shock_id

    def canonical_name(self, shock_id, *, where=""):
        """A shock name with every adjuster written in order (plain ids unchanged)."""
        if not isinstance(shock_id, str) or "@" not in shock_id:
            return shock_id
        base, settings = parse_shock_name(shock_id, where=where)
        entry = self.adjustable(base)
        return format_shock_name(base, entry.resolve(settings, where=where), entry.names)

    def __getitem__(self, shock_id):
        entry = self._models.get(shock_id) if isinstance(shock_id, str) else None
        if entry is None:
            if not isinstance(shock_id, str) or "@" not in shock_id:
                return self._models[shock_id]
            base, settings = parse_shock_name(shock_id)
            entry = self._models[base]
            if not isinstance(entry, AdjustableShock):
                raise ShockModelError(f"shock {shock_id!r}: {base!r} is a fixed shock, it has "
                                      f"no adjusters; write {base!r} alone, or name an "
                                      f"adjustable shock {list(self.adjustable_ids)}")
            return entry.at(settings)
        if isinstance(entry, AdjustableShock):
            return entry.default_shock()
        return entry

    def __contains__(self, shock_id):
        if not isinstance(shock_id, str):
            return False
        if shock_id in self._models:
            return True
        base, sep, _ = shock_id.partition("@")
        return bool(sep) and base.strip() in self._models

    def __iter__(self):
        return iter(self._models)

    def __len__(self):
        return len(self._models)

    def __repr__(self):
        src = f", source={self._source!r}" if self._source else ""
        return f"ShockLibrary({list(self._models.values())!r}{src})"

    _MISSING = object()

    def get(self, shock_id, default=_MISSING, *, where=""):
        """Return the shock `shock_id`, or raise a clear error naming the known ids.

        Parameters
        ----------
        shock_id : str
            The id to look up.
        default : optional
            Returned for an unknown id if given (as ``dict.get``); without it an
            unknown id raises.
        where : str
            Who asks (e.g. ``"run 'swap-LF' setup LF"``), put first in the message.

        Returns
        -------
        ShockModel

        Raises
        ------
        ShockModelError
            If `shock_id` is not in the library and no `default` is given.
        """
        try:
            if isinstance(shock_id, str) and "@" in shock_id and shock_id in self:
                base, settings = parse_shock_name(shock_id, where=where)
                entry = self._models[base.strip()]
                if isinstance(entry, AdjustableShock):
                    return entry.at(settings, where=where)
            return self[shock_id]
        except (KeyError, TypeError):
            if default is not ShockLibrary._MISSING:
                return default
        prefix = f"{where}: " if where else ""
        lib = f"shock library {self._source}" if self._source else "the shock library"
        raise ShockModelError(f"{prefix}unknown shock id {shock_id!r}; {lib} has "
                              f"{list(self._models)}; fix the id or add the shock")


def _fail(where, key, problem, fix):
    return ShockModelError(f"{where}: key {key!r} {problem}; {fix}")


def _toml_number(where, key, value):
    if not is_real_number(value):
        raise _fail(where, key, f"must be a number, got {type(value).__name__} {value!r}",
                    "write a number without quotes")
    return float(value)


def _toml_numbers(where, key, value):
    if not isinstance(value, list):
        raise _fail(where, key, f"must be an array of numbers, got {type(value).__name__} "
                    f"{value!r}", "write it as [v1, v2, ...]")
    for j, x in enumerate(value):
        if not is_real_number(x):
            raise _fail(where, key, f"has a {type(x).__name__} {x!r} at position {j}",
                        "write numbers without quotes")
    return np.array(value, dtype=float)


def _model_from_toml(table, units, where, index):
    """Build one shock from a ``[[shock]]`` table (values in `units`)."""
    raw_id = table.get("id") if isinstance(table, dict) else None
    label = f"{where}: [[shock]] #{index}" + (f" ({raw_id!r})" if isinstance(raw_id, str) else "")
    if not isinstance(table, dict):
        raise ShockModelError(f"{label}: is a {type(table).__name__}, not a table; write "
                              "each shock as a [[shock]] table")
    if "id" not in table:
        raise _fail(label, "id", "is missing", "give each shock an id = \"...\"")
    if not isinstance(raw_id, str):
        raise _fail(label, "id", f"must be a string, got {type(raw_id).__name__} {raw_id!r}",
                    "write the id in quotes")
    if "kind" not in table:
        raise _fail(label, "kind", "is missing", f"give kind = one of {list(SHOCK_KINDS)}")
    kind = table["kind"]
    if kind == AdjustableShock.kind:
        return _adjustable_from_toml(table, units, where, label, raw_id)
    if not isinstance(kind, str) or kind not in SHOCK_KINDS:
        raise _fail(label, "kind", f"is {kind!r}, an unknown kind",
                    f"use one of {[*SHOCK_KINDS, AdjustableShock.kind]}")
    cls = SHOCK_KINDS[kind]
    allowed = {"id", "kind", "lag", "description", "count", "fits", *cls.TOML_FIELDS}
    extra = [k for k in table if k not in allowed]
    if extra:
        raise _fail(label, extra[0], f"is not a key of a {kind!r} shock",
                    f"remove it or fix its spelling (keys: {sorted(allowed)})")
    kwargs = {}
    for key, (attr, quantity, shape) in cls.TOML_FIELDS.items():
        if key not in table:
            raise _fail(label, key, f"is missing (required for kind {kind!r})",
                        f"add {key} in {UNIT_LABELS[units][quantity]}")
        value = (_toml_numbers if shape == "vector" else _toml_number)(label, key, table[key])
        kwargs[attr] = to_si(value, quantity, units)
    if "lag" in table:
        kwargs["lag_s"] = _toml_number(label, "lag", table["lag"])
    if "description" in table:
        if not isinstance(table["description"], str):
            raise _fail(label, "description", f"must be a string, got "
                        f"{type(table['description']).__name__}", "write it in quotes")
        kwargs["description"] = table["description"]
    if "count" in table:
        if not isinstance(table["count"], int) or isinstance(table["count"], bool):
            raise _fail(label, "count", f"must be an integer, got "
                        f"{type(table['count']).__name__} {table['count']!r}",
                        "write a whole number without quotes or decimal point, or omit it "
                        "for unlimited")
        kwargs["count"] = table["count"]
    if "fits" in table:
        kwargs["fits"] = _fits(label, table["fits"])
    keys = {attr: key for key, (attr, _, _) in cls.TOML_FIELDS.items()}
    keys.update(lag_s="lag", id="id", description="description", count="count", fits="fits")
    try:
        return cls(raw_id, **kwargs)
    except ShockModelError as exc:
        attr = getattr(exc, "field", None)
        if attr is None:  # pragma: no cover - every model error carries its field
            raise ShockModelError(f"{label}: {exc}") from None
        base, _, sub = attr.partition("[")
        key = keys.get(base, base) + (f"[{sub}" if sub else "")
        raise ShockModelError(f"{label}: key {key!r} {exc.problem}; {exc.fix}") from None


ADJUSTABLE_KEYS = ("id", "kind", "adjusters", "default", "stiffer", "step", "dyno", "lag",
                   "description", "count", "fits", "force_resolution")


def _fits(label, value):
    """A ``fits`` value checked (:data:`ident.models.shocks.SHOCK_FITS`)."""
    if value not in SHOCK_FITS:
        raise _fail(label, "fits", f"is {value!r}, not a use",
                    f"write one of {[f for f in SHOCK_FITS]} in quotes (a third element's "
                    "damper: \"heave\" or \"roll\"), or leave it out for any use")
    return value


def _adjustable_from_toml(table, units, where, label, raw_id):
    """Build an :class:`AdjustableShock` from its ``[[shock]]`` table and dyno sheets."""
    extra = [k for k in table if k not in ADJUSTABLE_KEYS]
    if extra:
        raise _fail(label, extra[0], "is not a key of an 'adjustable' shock",
                    f"remove it or fix its spelling (keys: {list(ADJUSTABLE_KEYS)})")
    for key in ("adjusters", "dyno"):
        if key not in table:
            raise _fail(label, key, "is missing (required for kind 'adjustable')",
                        "see the spec's 'Adjustable shocks': adjusters = { ls = [0, 25] }, "
                        "dyno = \"sheet.csv\"")
    for key in ("adjusters", "default", "stiffer", "step"):
        if key in table and not isinstance(table[key], dict):
            raise _fail(label, key, f"must be a table {{adjuster = ...}}, got "
                        f"{type(table[key]).__name__}", f"write {key} = {{ ls = ..., hs = ... }}")
    dyno = table["dyno"]
    files = [dyno] if isinstance(dyno, str) else dyno
    if not isinstance(files, list) or not files or not all(isinstance(f, str) for f in files):
        raise _fail(label, "dyno", f"must be a file name or a list of them, got {dyno!r}",
                    "write dyno = \"ttx_dyno.csv\" (relative to the library file)")
    base = Path(where).parent if where else Path(".")
    for key in ("default", "step"):
        for name, x in table.get(key, {}).items():
            if not is_real_number(x):
                raise _fail(label, f"{key}.{name}", f"must be a number, got {x!r}",
                            "write clicks or turns as a number")
    adjusters = table["adjusters"]
    names = list(adjusters)
    for name, rng in adjusters.items():
        if not isinstance(rng, list) or len(rng) != 2 or not all(is_real_number(x)
                                                                 for x in rng):
            raise _fail(label, f"adjusters.{name}", f"must be [lo, hi], got {rng!r}",
                        "write the adjuster's range of settings, e.g. ls = [0, 25]")
    points = read_dyno_sheets([base / f for f in files], names, units=units,
                              where=f"{label}")
    kwargs = {}
    if "lag" in table:
        kwargs["lag_s"] = _toml_number(label, "lag", table["lag"])
    if "description" in table:
        if not isinstance(table["description"], str):
            raise _fail(label, "description", "must be a string", "write it in quotes")
        kwargs["description"] = table["description"]
    if "count" in table:
        if not isinstance(table["count"], int) or isinstance(table["count"], bool):
            raise _fail(label, "count", f"must be an integer, got {table['count']!r}",
                        "write a whole number, or omit it for unlimited")
        kwargs["count"] = table["count"]
    if "fits" in table:
        kwargs["fits"] = _fits(label, table["fits"])
    if "force_resolution" in table:
        kwargs["force_resolution_n"] = to_si(
            _toml_number(label, "force_resolution", table["force_resolution"]), "force", units)
    try:
        return AdjustableShock(raw_id, {k: tuple(v) for k, v in adjusters.items()}, points,
                               default=table.get("default"), stiffer=table.get("stiffer"),
                               step=table.get("step"), dyno_files=tuple(files),
                               sheet_units=units, **kwargs)
    except ShockModelError as exc:
        raise ShockModelError(f"{label}: {exc}") from None


def read_shock_library(path):
    """Read a shock library (``shocks.toml``) into SI models.

    Parameters
    ----------
    path : str or path
        The TOML file: a top-level ``units`` ("SI", the default, or
        "imperial") and ``[[shock]]`` tables with ``id``, ``kind`` ("linear":
        ``damping``; "table": ``velocity``, ``force``; "digressive":
        ``bump_low``, ``bump_knee``, ``bump_high``, ``rebound_low``,
        ``rebound_knee``, ``rebound_high``), optional ``lag`` [s],
        ``description``, ``count`` (inventory, integer >= 0; omitted =
        unlimited) and ``fits`` (``"corner"``, ``"heave"`` or ``"roll"``: what the damper
        is for; omitted = any use).

    Returns
    -------
    ShockLibrary
        The shocks in file order, in SI.

    Raises
    ------
    ShockModelError
        If the file is missing or not TOML, has no shocks, an unknown kind, a
        missing, unknown or mistyped key, a duplicate id, or an invalid model;
        the message names the file, the shock (index from 1 and id) and the key.

    Notes
    -----
    Imperial values are converted on load: velocity in/s, force lbf, damping
    lbf/(in/s); ``lag`` is always in seconds. Other top-level keys are ignored, unless
    they look like a typo of ``units`` or ``shock`` (refused, with a did-you-mean).
    """
    path = Path(path)
    doc = read_toml(path, error=ShockModelError, what="shock library")
    for key in doc:
        hint = did_you_mean(key, ("units", "shock")) if key not in ("units", "shock") else ""
        if hint:  # a typo would silently read an imperial library as SI
            raise ShockModelError(f"{path}: unknown top-level key {key!r}{hint}; a shock "
                                  "library has 'units' and [[shock]] tables")
    units = check_shock_units(doc.get("units", "SI"), f"{path}: key 'units'")
    shocks = doc.get("shock")
    if shocks is None:
        raise ShockModelError(f"{path}: no [[shock]] tables; add at least one shock")
    if not isinstance(shocks, list):
        raise ShockModelError(f"{path}: key 'shock' must be an array of tables, got "
                              f"{type(shocks).__name__}; write each shock as a [[shock]] table")
    ignored = [k for k in doc if k not in ("units", "shock")]
    if ignored:
        logger.debug("%s: ignoring top-level keys %s", path, ignored)
    models = [_model_from_toml(t, units, str(path), j + 1) for j, t in enumerate(shocks)]
    ids = [m.id for m in models]
    for j, shock_id in enumerate(ids):
        if shock_id in ids[:j]:
            raise ShockModelError(f"{path}: [[shock]] #{j + 1} ({shock_id!r}): key 'id' repeats "
                                  f"the id of [[shock]] #{ids.index(shock_id) + 1}; give each "
                                  "shock a unique id")
    logger.debug("read %d shock(s) from %s (%s)", len(models), path, units)
    return ShockLibrary(models, source=path)


def _sheet_paths(shock, path, units, overwrite):
    """The ``dyno`` value of an adjustable shock written next to `path`.

    Sheets read from files are referenced relative to the new library (not copied);
    points built in memory are written as ``<library stem>.<id>.dyno.csv``.
    """
    if shock.points.sources and units == shock.sheet_units:
        rel = [os.path.relpath(src, path.parent.resolve()) for src in shock.points.sources]
        return rel[0] if len(rel) == 1 else rel
    name = f"{path.stem}.{shock.id}.dyno.csv"
    check_can_write(path.parent / name, overwrite=overwrite)
    frame = shock.points.to_frame()
    frame["velocity"] = from_si(frame["velocity"].to_numpy(), "velocity", units)
    frame["force"] = from_si(frame["force"].to_numpy(), "force", units)
    write_csv_frame(frame, path.parent / name, units=units)
    return name


def write_shock_library(library, path, *, units="SI", overwrite=False):
    """Write a shock library as ``shocks.toml``, atomically.

    Parameters
    ----------
    library : ShockLibrary or iterable of ShockModel
        The shocks, in order.
    path : str or path
        Output file.
    units : {"SI", "imperial"}
        Unit system of the file. Imperial converts back from SI (a round trip
        SI -> imperial -> SI is exact to round-off).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    ShockModelError
        If `units` is unknown or the models have duplicate ids.
    FileExistsError
        If `path` exists and `overwrite` is false.
    """
    if not isinstance(library, ShockLibrary):
        library = ShockLibrary.from_models(library)
    units = check_shock_units(units, "write_shock_library: units")
    path = Path(path)
    tables = []
    for m in library.entries():
        table = m.to_toml_dict(units)
        if isinstance(m, AdjustableShock):
            table["dyno"] = _sheet_paths(m, path, units, overwrite)
        tables.append(table)
    doc = {"units": units, "shock": tables}
    atomic_write_toml(path, doc, overwrite=overwrite,
                      header="Shock library (rig-session/1), written by shockplan.")
    logger.info("wrote %d shock(s) to %s (%s)", len(library), path, units)
    return path
