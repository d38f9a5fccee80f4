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
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from ident.data.files import atomic_write_toml, did_you_mean, read_toml
from ident.data.units import UNIT_LABELS, to_si
from ident.errors import ShockModelError
from ident.models.shocks import SHOCK_KINDS, ShockModel, check_shock_units, is_real_number

__all__ = [
    "ShockLibrary",
    "read_shock_library",
    "write_shock_library",
]

logger = logging.getLogger(__name__)


class ShockLibrary(Mapping):
    """An ordered, read-only mapping ``id -> ShockModel``.

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
            if not isinstance(model, ShockModel):
                raise TypeError(f"shock library: item {j} is a {type(model).__name__}, not a "
                                "ShockModel; build it with LinearShock, TableShock or "
                                "DigressiveShock")
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

    def __getitem__(self, shock_id):
        return self._models[shock_id]

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
            return self._models[shock_id]
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
    if not isinstance(kind, str) or kind not in SHOCK_KINDS:
        raise _fail(label, "kind", f"is {kind!r}, an unknown kind",
                    f"use one of {list(SHOCK_KINDS)}")
    cls = SHOCK_KINDS[kind]
    allowed = {"id", "kind", "lag", "description", "count", *cls.TOML_FIELDS}
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
    keys = {attr: key for key, (attr, _, _) in cls.TOML_FIELDS.items()}
    keys.update(lag_s="lag", id="id", description="description", count="count")
    try:
        return cls(raw_id, **kwargs)
    except ShockModelError as exc:
        attr = getattr(exc, "field", None)
        if attr is None:  # pragma: no cover - every model error carries its field
            raise ShockModelError(f"{label}: {exc}") from None
        base, _, sub = attr.partition("[")
        key = keys.get(base, base) + (f"[{sub}" if sub else "")
        raise ShockModelError(f"{label}: key {key!r} {exc.problem}; {exc.fix}") from None


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
        ``description`` and ``count`` (inventory, integer >= 0; omitted =
        unlimited).

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
    doc = {"units": units, "shock": [m.to_toml_dict(units) for m in library.values()]}
    atomic_write_toml(path, doc, overwrite=overwrite,
                      header="Shock library (rig-session/1), written by shockplan.")
    logger.info("wrote %d shock(s) to %s (%s)", len(library), path, units)
    return path
