"""Objectives: score and rank setups from their predicted RMS metrics.

An objective is a weighted sum of metrics, each normalized by its value for a
baseline setup, so the baseline scores exactly the sum of the weights and a
setup whose every metric is 10 % lower scores 0.9 times that. **Lower is
better.** Named groups of the weighted metrics give sub-scores for trade-off
(Pareto) plots, and limits make setups infeasible.

For setup ``s`` with metric values ``m_s`` and baseline ``b``::

    score(s)         = sum over weighted metrics k of  w_k * m_s[k] / m_b[k]
    score_<group>(s) = the same sum over the group's metrics only
    feasible(s)      = every limit met: m_s[k] <= max_ratio_k * m_b[k] and
                       m_s[k] <= max_k (and m_s[k] >= min_k, histogram summaries)
                       (a NaN metric fails its limits)

File format (``objective.toml``)::

    format = "objective/1"         # optional, the only version
    name = "grip and platform"     # optional, default the file name
    baseline = "baseline"          # optional: setup to normalize against
                                   # (default: the first setup scored)
    [weights]                      # metric name -> weight >= 0 (not all 0)
    tire_force_rms_LF = 0.125
    tire_force_rms_RF = 0.125
    tire_force_rms_LR = 0.125
    tire_force_rms_RR = 0.125
    ride_height_rms_front = 0.25
    ride_height_rms_rear = 0.25
    [groups]                       # optional: group -> weighted metrics
    grip = ["tire_force_rms_LF", "tire_force_rms_RF", "tire_force_rms_LR",
            "tire_force_rms_RR"]
    platform = ["ride_height_rms_front", "ride_height_rms_rear"]
    [limits]                       # optional: metric -> constraints
    shock_travel_rms_LF = { max_ratio = 1.25 }   # <= 1.25 x the baseline's
    shock_velocity_rms_LF = { max = 0.5 }        # absolute, SI (here m/s)

Metric names are those of :mod:`ident.sim.metrics` (:data:`METRIC_QUANTITY`): the
spec's metrics, the normalized tire forces ``tire_force_rms_norm_XX``, and all
of them with the suffix ``_body`` or ``_wheelhop``; and, where the loop holds the real
car's elements (:mod:`planner.elements`), ``bump_stop_contact_share_XX``,
``tire_liftoff_share_XX`` (shares of time, 0-1) and ``tire_contact_min_XX`` [N]: limit
lift-off as travel is limited, ``tire_liftoff_share_LR = { max = 0.01 }``; where the loop
counts the shock-velocity histograms (:mod:`planner.histograms`), ``share_low_speed_XX``,
``bump_rebound_ratio_XX`` and, against a logged histogram, ``histogram_distance_XX``: e.g.
``bump_rebound_ratio_LF = { max = 1.2 }``, ``share_low_speed_LF = { min = 0.4 }`` (these
take a ``min`` too: more time below the knee), or a weight on ``histogram_distance_XX`` to
stay near the logged car (the screening scores without them, :func:`time_domain_metrics`). A
car with third elements (issue 38) adds per declared element ``heave_travel_rms_front``,
``heave_velocity_rms_front``, ``roll_travel_rms_front``, ... (SI: m, m/s): a heave travel
limit protects the floor, ``heave_travel_rms_front = { max_ratio = 1.1 }``. Group
names may use
letters, digits, ``_`` and ``-``; a group ``grip`` gives the score column
``score_grip``. A group sub-score is not re-normalized: when the groups
partition the weights, the group scores add up to the score.

Examples
--------
>>> import pandas as pd
>>> obj = Objective("demo", {"tire_force_rms_LF": 1.0, "ride_height_rms_front": 1.0},
...                 groups={"grip": ["tire_force_rms_LF"]},
...                 limits={"tire_force_rms_LF": {"max_ratio": 1.1}})
>>> m = pd.DataFrame({"tire_force_rms_LF": [500.0, 450.0, 600.0],
...                   "ride_height_rms_front": [0.004, 0.0036, 0.002]},
...                  index=["base", "soft", "stiff"])
>>> s = score_setups(m, obj)
>>> s.table["score"].round(12).tolist(), s.table["score_grip"].round(12).tolist()
([2.0, 1.8, 1.7], [1.0, 0.9, 1.2])
>>> s.table["feasible"].tolist(), s.table["rank"].tolist()  # stiff: LF 1.2 x baseline
([True, True, False], [2, 1, 3])
>>> s.table.loc["stiff", "violations"]
'tire_force_rms_LF = 1.2 x baseline > max_ratio 1.1'
"""

from __future__ import annotations

import difflib
import logging
import math
import numbers
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np
import pandas as pd

from ident.data.files import atomic_write_toml, check_can_write, read_toml
from ident.data.channels import CORNERS
from ident.sim.metrics import (BAND_SUFFIXES, METRIC_NAMES, METRIC_QUANTITY,
                               THIRD_METRIC_NAMES)
from planner.errors import PlannerError
from planner.setups import inventory_shortfall

__all__ = [
    "OBJECTIVE_FORMAT",
    "LIMIT_KEYS",
    "Objective",
    "Scores",
    "default_objective",
    "read_objective",
    "objective_to_toml",
    "score_setups",
    "ranking_order",
    "ranks",
    "ranking_position",
    "mark_inventory",
    "pareto_front",
    "TIME_DOMAIN_PREFIXES",
    "HISTOGRAM_LIMIT_KEYS",
    "time_domain_metrics",
]

logger = logging.getLogger(__name__)

#: The ``format`` of objective files this version reads and writes.
OBJECTIVE_FORMAT = "objective/1"
#: Keys of a limit: ``max_ratio`` (relative to the baseline), ``max`` (absolute, SI).
LIMIT_KEYS = ("max_ratio", "max")
#: The further key of a limit on a histogram summary (:data:`TIME_DOMAIN_PREFIXES`): ``min``
#: (absolute), e.g. ``share_low_speed_LF = { min = 0.4 }`` for more time below the knee.
HISTOGRAM_LIMIT_KEYS = ("min",)

_TOP_KEYS = ("format", "name", "baseline", "weights", "groups", "limits")
_GROUP_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
_BASE_NAMES = METRIC_NAMES + tuple(f"tire_force_rms_norm_{c}" for c in CORNERS) \
    + THIRD_METRIC_NAMES


def _is_number(x):
    return isinstance(x, (numbers.Real, np.number)) and not isinstance(x, (bool, np.bool_))


def _unknown_metric(where, table, name):
    close = difflib.get_close_matches(str(name), list(METRIC_QUANTITY), n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    return PlannerError(
        f"{where}: [{table}]: unknown metric {name!r}; {hint}valid names are "
        f"{list(_BASE_NAMES)}, each also with a suffix {list(BAND_SUFFIXES)}")


def _check_metric(where, table, name):
    if not isinstance(name, str) or name not in METRIC_QUANTITY:
        raise _unknown_metric(where, table, name)
    return name


def _check_text(where, key, value):
    if not isinstance(value, str) or not value.strip():
        raise PlannerError(f"{where}: {key} {value!r} must be a non-empty string; write it in "
                           "quotes")
    return value


def _fmt(x):
    return f"{float(x):.6g}"


# ----------------------------------------------------------------------------
# Objective
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Objective:
    """A weighted, baseline-normalized sum of metrics, with groups and limits.

    Parameters
    ----------
    name : str
        Name of the objective (for reports).
    weights : mapping of str to float
        Metric name -> weight >= 0; at least one weight > 0. Order is kept.
    groups : mapping of str to sequence of str, keyword-only
        Group name -> weighted metrics, for sub-scores ``score_<group>``.
    limits : mapping of str to mapping, keyword-only
        Metric name -> ``{"max_ratio": r}`` (value <= r x baseline value) and/or
        ``{"max": x}`` (value <= x, SI units of the metric); r, x > 0. A histogram
        summary (:data:`TIME_DOMAIN_PREFIXES`) also takes ``{"min": x}`` (value >= x),
        e.g. ``share_low_speed_LF`` at least 0.4: more time below the knee.
    baseline : str or None, keyword-only
        Setup to normalize against; ``None`` is the first setup scored.
    source : str or None, keyword-only
        The file the objective was read from (messages only; not compared).

    Raises
    ------
    PlannerError
        On an unknown metric (in weights, groups or limits), a weight that is
        not a finite number >= 0, no weights or all 0, a group that is empty,
        badly named or lists a metric without a weight, a limit that is not a
        table, is empty, has an unknown key or a value not finite and > 0, or
        an empty name or baseline. Messages name the source, the table and
        the entry.

    Notes
    -----
    Stored read-only (mappings as ``MappingProxyType``, groups as tuples,
    weights and limits as floats). Objectives compare by value; they are not
    hashable.
    """

    name: str
    weights: Mapping
    groups: Mapping = field(default_factory=dict, kw_only=True)
    limits: Mapping = field(default_factory=dict, kw_only=True)
    baseline: str | None = field(default=None, kw_only=True)
    source: str | None = field(default=None, kw_only=True, compare=False)

    __hash__ = None

    def __reduce__(self):  # mappingproxy does not pickle; rebuild from plain values
        state = self.to_toml_dict()
        return (_objective_from_state, (state, self.source))

    def __post_init__(self):
        if self.source is not None:
            object.__setattr__(self, "source", str(self.source))
        src = f" ({self.source})" if self.source else ""
        if not isinstance(self.name, str) or not self.name.strip():
            raise PlannerError(f"objective{src}: name {self.name!r} must be a non-empty "
                               "string; write it in quotes")
        where = f"objective {self.name!r}{src}"
        if self.baseline is not None:
            _check_text(where, "baseline", self.baseline)
        object.__setattr__(self, "weights", MappingProxyType(self._check_weights(where)))
        object.__setattr__(self, "groups", MappingProxyType(self._check_groups(where)))
        object.__setattr__(self, "limits", MappingProxyType(self._check_limits(where)))

    def _check_weights(self, where):
        if not isinstance(self.weights, Mapping):
            raise PlannerError(f"{where}: weights must be a table metric -> weight, got "
                               f"{type(self.weights).__name__}; write [weights] with lines "
                               "metric = weight")
        if not self.weights:
            raise PlannerError(f"{where}: [weights] is empty; give at least one metric = "
                               "weight")
        out = {}
        for metric, w in self.weights.items():
            _check_metric(where, "weights", metric)
            if not _is_number(w):
                raise PlannerError(f"{where}: [weights]: {metric} = {w!r} is not a number; "
                                   "write the weight as a number without quotes")
            w = float(w)
            if not math.isfinite(w) or w < 0:
                raise PlannerError(f"{where}: [weights]: {metric} = {_fmt(w)} is not a finite "
                                   "number >= 0; weights are >= 0 (lower metrics are always "
                                   "better), drop metrics you do not want to reward")
            out[metric] = w
        if not any(out.values()):
            raise PlannerError(f"{where}: [weights]: every weight is 0; give at least one "
                               "weight > 0")
        return out

    def _check_groups(self, where):
        if not isinstance(self.groups, Mapping):
            raise PlannerError(f"{where}: groups must be a table group -> list of metrics, "
                               f"got {type(self.groups).__name__}")
        out = {}
        for group, metrics in self.groups.items():
            if not isinstance(group, str) or not _GROUP_NAME.match(group):
                raise PlannerError(f"{where}: [groups]: group name {group!r} is not valid; use "
                                   "letters, digits, '_' and '-' (it becomes the column "
                                   "score_<group>)")
            if isinstance(metrics, str) or not isinstance(metrics, (list, tuple)):
                raise PlannerError(f"{where}: [groups]: {group} must be a list of metric "
                                   f"names, got {type(metrics).__name__} {metrics!r}; write "
                                   f'{group} = ["metric", ...]')
            if not metrics:
                raise PlannerError(f"{where}: [groups]: {group} is empty; list at least one "
                                   "weighted metric or remove the group")
            for j, metric in enumerate(metrics):
                _check_metric(where, "groups", metric)
                if metric in metrics[:j]:
                    raise PlannerError(f"{where}: [groups]: {group} lists {metric!r} twice; "
                                       "remove the duplicate")
                if metric not in self.weights:
                    raise PlannerError(f"{where}: [groups]: {group} lists {metric!r}, which "
                                       "has no weight in [weights]; add a weight for it or "
                                       "remove it from the group")
            out[group] = tuple(metrics)
        return out

    def _check_limits(self, where):
        if not isinstance(self.limits, Mapping):
            raise PlannerError(f"{where}: limits must be a table metric -> {{max_ratio, max}}, "
                               f"got {type(self.limits).__name__}")
        out = {}
        for metric, spec in self.limits.items():
            _check_metric(where, "limits", metric)
            if not isinstance(spec, Mapping):
                raise PlannerError(f"{where}: [limits]: {metric} = {spec!r} is not a table; "
                                   f"write {metric} = {{ max_ratio = 1.25 }} or "
                                   "{ max = <SI value> }")
            if not spec:
                raise PlannerError(f"{where}: [limits]: {metric} is empty; give max_ratio "
                                   "and/or max, or remove the limit")
            checked = {}
            allowed = LIMIT_KEYS + (HISTOGRAM_LIMIT_KEYS if metric.startswith(
                TIME_DOMAIN_PREFIXES) else ())
            for key, value in spec.items():
                if key not in allowed:
                    raise PlannerError(f"{where}: [limits]: {metric} has the unknown key "
                                       f"{key!r}; a limit takes {list(allowed)} (max_ratio "
                                       "relative to the baseline, max absolute in SI)")
                if not _is_number(value) or not math.isfinite(float(value)) or value <= 0:
                    raise PlannerError(f"{where}: [limits]: {metric}.{key} = {value!r} is not "
                                       "a finite number > 0; write a positive number without "
                                       "quotes")
                checked[key] = float(value)
            out[metric] = MappingProxyType({k: checked[k] for k in allowed if k in checked})
        return out

    @property
    def metrics(self):
        """tuple of str: every metric the objective needs (weights, then limits)."""
        return tuple(dict.fromkeys([*self.weights, *self.limits]))

    def without_metrics(self, names):
        """This objective without the metrics `names` (their weights, group entries and
        limits): what a stage that cannot predict them scores with (the screening has no
        shock-velocity histograms, :func:`time_domain_metrics`).

        Returns
        -------
        Objective or None
            `self` when it uses none of them; None when no weight > 0 would remain.
        """
        drop = set(names)
        if not drop & set(self.metrics):
            return self
        weights = {m: w for m, w in self.weights.items() if m not in drop}
        if not any(weights.values()):
            return None
        groups = {g: [m for m in ms if m not in drop] for g, ms in self.groups.items()}
        return Objective(self.name, weights, groups={g: ms for g, ms in groups.items() if ms},
                         limits={m: dict(v) for m, v in self.limits.items() if m not in drop},
                         baseline=self.baseline, source=self.source)

    @property
    def total_weight(self):
        """float: the sum of the weights, the baseline's score."""
        return math.fsum(self.weights.values())

    def to_toml_dict(self):
        """Return the objective as the mapping written by :func:`objective_to_toml`.

        Returns
        -------
        dict
            Keys ``format``, ``name``, ``baseline`` (if set), ``weights``,
            ``groups`` and ``limits`` (if not empty).
        """
        out = {"format": OBJECTIVE_FORMAT, "name": self.name}
        if self.baseline is not None:
            out["baseline"] = self.baseline
        out["weights"] = dict(self.weights)
        if self.groups:
            out["groups"] = {g: list(m) for g, m in self.groups.items()}
        if self.limits:
            out["limits"] = {m: dict(spec) for m, spec in self.limits.items()}
        return out


#: Metric name prefixes predicted in the time domain only (the shock-velocity histograms'
#: summaries, :mod:`planner.histograms`): the screening scores without them.
TIME_DOMAIN_PREFIXES = ("share_low_speed_", "bump_rebound_ratio_", "histogram_distance_")


def time_domain_metrics(objective):
    """The metrics `objective` uses that only the time domain predicts (the histograms'
    summaries, :data:`TIME_DOMAIN_PREFIXES`), in its order.

    Returns
    -------
    tuple of str
    """
    return tuple(m for m in objective.metrics if m.startswith(TIME_DOMAIN_PREFIXES))


def _objective_from_state(state, source):
    """Rebuild an :class:`Objective` from :meth:`Objective.to_toml_dict` (for pickle)."""
    return Objective(state["name"], state["weights"], groups=state.get("groups", {}),
                     limits=state.get("limits", {}), baseline=state.get("baseline"),
                     source=source)


def default_objective():
    """Return the default objective: grip and platform, travel limited.

    Returns
    -------
    Objective
        ``"grip and platform"``: weights 0.125 on each tire-force RMS (group
        ``grip``, 0.5 in total) and 0.25 on the front and rear ride-height RMS
        (group ``platform``, 0.5 in total), so the baseline scores 1; every
        ``shock_travel_rms_XX`` limited to 1.25 times the baseline's; the
        baseline is the first setup scored.

    Examples
    --------
    >>> obj = default_objective()
    >>> obj.total_weight, list(obj.groups)
    (1.0, ['grip', 'platform'])
    """
    grip = [f"tire_force_rms_{c}" for c in CORNERS]
    platform = ["ride_height_rms_front", "ride_height_rms_rear"]
    weights = {m: 0.5 / len(grip) for m in grip}
    weights.update({m: 0.5 / len(platform) for m in platform})
    return Objective("grip and platform", weights,
                     groups={"grip": grip, "platform": platform},
                     limits={f"shock_travel_rms_{c}": {"max_ratio": 1.25} for c in CORNERS})


def read_objective(path):
    """Read an objective file (``objective.toml``, see the module docstring).

    Parameters
    ----------
    path : str or path
        The TOML file.

    Returns
    -------
    Objective
        With ``source`` set to `path`; ``name`` defaults to the file's stem.

    Raises
    ------
    PlannerError
        If the file is missing or not TOML, has an unknown top-level key, a
        ``format`` other than ``"objective/1"``, no ``[weights]``, or any
        error listed under :class:`Objective`; the message names the file.
    """
    path = Path(path)
    doc = read_toml(path, error=PlannerError, what="objective file")
    unknown = [k for k in doc if k not in _TOP_KEYS]
    if unknown:
        raise PlannerError(f"{path}: unknown key {unknown[0]!r}; an objective file has the "
                           f"keys {list(_TOP_KEYS)}; fix its spelling or remove it")
    fmt = doc.get("format", OBJECTIVE_FORMAT)
    if fmt != OBJECTIVE_FORMAT:
        raise PlannerError(f"{path}: key 'format' is {fmt!r}; this version reads "
                           f"{OBJECTIVE_FORMAT!r}; write format = \"{OBJECTIVE_FORMAT}\"")
    if "weights" not in doc:
        raise PlannerError(f"{path}: no [weights] table; add [weights] with lines "
                           "metric = weight")
    for key in ("weights", "groups", "limits"):
        if key in doc and not isinstance(doc[key], dict):
            raise PlannerError(f"{path}: key {key!r} must be a table, got "
                               f"{type(doc[key]).__name__}; write it as [{key}]")
    name = doc.get("name", path.stem)
    if not isinstance(name, str) or not name.strip():
        raise PlannerError(f"{path}: key 'name' {name!r} must be a non-empty string; write it "
                           "in quotes")
    obj = Objective(name, doc["weights"], groups=doc.get("groups", {}),
                    limits=doc.get("limits", {}), baseline=doc.get("baseline"),
                    source=str(path))
    logger.debug("read objective %r from %s", obj.name, path)
    return obj


def objective_to_toml(objective, path, *, overwrite=False):
    """Write an objective as TOML, atomically (read back by :func:`read_objective`).

    Parameters
    ----------
    objective : Objective
        The objective.
    path : str or path
        Output file.
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        The written path.

    Raises
    ------
    TypeError
        If `objective` is not an :class:`Objective`.
    FileExistsError
        If `path` exists and `overwrite` is false.
    """
    if not isinstance(objective, Objective):
        raise TypeError(f"objective_to_toml: objective must be an Objective, got "
                        f"{type(objective).__name__}")
    path = Path(path)
    check_can_write(path, overwrite=overwrite)
    atomic_write_toml(path, objective.to_toml_dict(), overwrite=overwrite,
                      header=f"Objective ({OBJECTIVE_FORMAT}), written by shockplan. Lower "
                             "scores are better; metrics are normalized by the baseline's.")
    return path


# ----------------------------------------------------------------------------
# scoring
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Scores:
    """Scores of setups under an objective.

    Attributes
    ----------
    table : pandas.DataFrame, shape (setup, column)
        Indexed by setup name, in the order of the metrics table, with columns
        ``score`` (lower is better), ``score_<group>`` per group, ``feasible``
        (bool, every limit met), ``violations`` (str, ``"; "``-separated, empty
        when feasible) and ``rank`` (int, 1 = best feasible; infeasible
        setups after all feasible ones; within each, by score with NaN scores
        last; ties in table order).
    objective : Objective
        The objective used.
    baseline : str
        The setup the metrics were normalized by.
    baseline_values : pandas.Series
        The baseline's values (SI) of the metrics the objective uses.
    """

    table: pd.DataFrame
    objective: Objective
    baseline: str
    baseline_values: pd.Series

    def ranked(self):
        """Return :attr:`table` sorted by rank (best first).

        Returns
        -------
        pandas.DataFrame
        """
        return self.table.sort_values("rank", kind="stable")


def _metric_matrix(metrics, names, objective_name):
    missing = [m for m in names if m not in metrics.columns]
    if missing:
        raise PlannerError(f"score_setups: the metrics table has no column(s) {missing} "
                           f"that objective {objective_name!r} uses; predict these metrics "
                           "or remove them from the objective")
    out = np.empty((len(metrics), len(names)))
    for j, m in enumerate(names):
        col = metrics[m]
        if not (pd.api.types.is_numeric_dtype(col) and not pd.api.types.is_bool_dtype(col)):
            raise PlannerError(f"score_setups: metrics column {m!r} is not numeric (dtype "
                               f"{col.dtype}); give metric values as numbers in SI")
        out[:, j] = col.to_numpy(dtype=float, na_value=np.nan)
    return out


def _join_messages(acc, idx, parts):
    """Append message `parts` (str array) at rows `idx` of `acc` (str array)."""
    cur = acc[idx].astype(str)
    acc[idx] = np.where(cur == "", parts, np.char.add(np.char.add(cur, "; "), parts)
                        ).astype(object)


# ----------------------------------------------------------------------------
# the ranking rule
# ----------------------------------------------------------------------------


def ranking_order(feasible, score, index=None):
    """Positions of setups, best first: the one ranking rule of every command.

    Feasible setups come before infeasible ones; within each, NaN scores last, then
    by score (lower is better), ties by `index` (by position when None).

    Parameters
    ----------
    feasible : ndarray of bool, shape (n,)
    score : ndarray of float, shape (n,)
    index : ndarray of int, shape (n,), optional
        The tie-break (e.g. the setups' enumeration indices); default ``arange(n)``.

    Returns
    -------
    ndarray of int, shape (n,)
        ``order[0]`` is the position of the best setup.

    Examples
    --------
    >>> import numpy as np
    >>> ranking_order(np.array([True, False, True, True]),
    ...               np.array([2.0, 0.5, np.nan, 1.0])).tolist()
    [3, 0, 2, 1]
    """
    nan = np.isnan(score)
    if index is None:
        index = np.arange(len(score))
    return np.lexsort((index, np.where(nan, 0.0, score), nan, ~feasible))


def ranks(feasible, score):
    """1-based ranks of setups by :func:`ranking_order` (ties in table order).

    Parameters
    ----------
    feasible : ndarray of bool, shape (n,)
    score : ndarray of float, shape (n,)

    Returns
    -------
    ndarray of int64, shape (n,)
    """
    n = len(score)
    rank = np.empty(n, dtype=np.int64)
    rank[ranking_order(feasible, score)] = np.arange(1, n + 1)
    return rank


def ranking_position(at, feasible, score, index):
    """1-based position of setup `at` in :func:`ranking_order`, without sorting.

    Parameters
    ----------
    at : int
        Position of the setup in the arrays.
    feasible, score, index : ndarray, shape (n,)
        As :func:`ranking_order`.

    Returns
    -------
    int
    """
    nan = np.isnan(score)
    filled = np.where(nan, 0.0, score)
    f, n, s, i = feasible[at], nan[at], filled[at], index[at]
    ahead = (feasible & ~f) | ((feasible == f) & (
        (~nan & n) | ((nan == n) & ((filled < s) | ((filled == s) & (index < i))))))
    return int(ahead.sum()) + 1


def mark_inventory(scores, setups, library):
    """Mark setups that the crate's ``count`` cannot build as infeasible, and re-rank.

    Parameters
    ----------
    scores : pandas.DataFrame
        A scores table (:attr:`Scores.table`: ``score``, ``feasible``, ``violations``,
        ``rank``), indexed by setup name.
    setups : iterable of planner.setups.Setup
        The setups by name (rows of other names are left as they are).
    library : ShockLibrary
        The crate; shocks with ``count = None`` are unlimited.

    Returns
    -------
    pandas.DataFrame
        `scores` itself when every setup can be built, else a copy with the reason
        appended to ``violations`` (``"inventory: needs 3 x 'B20' ..."``), ``feasible``
        updated and ``rank`` by :func:`ranking_order`.
    """
    by_name = {s.name: s for s in setups}
    short = [inventory_shortfall(by_name[n], library) if n in by_name else ""
             for n in scores.index]
    if not any(short):
        return scores
    scores = scores.copy()
    viol = scores["violations"].to_numpy(dtype=object).copy()
    for k, text in enumerate(short):
        if text:
            viol[k] = f"{viol[k]}; inventory: {text}" if viol[k] else f"inventory: {text}"
    feasible = viol == ""
    rank = ranks(feasible, scores["score"].to_numpy(dtype=float))
    scores["feasible"] = feasible.astype(bool)
    scores["violations"] = viol
    scores["rank"] = rank
    logger.info("%d setup(s) need more shocks than the library's count: infeasible",
                sum(bool(t) for t in short))
    return scores


def score_setups(metrics, objective=None, *, baseline=None):
    """Score and rank setups from their metrics (lower is better).

    Parameters
    ----------
    metrics : pandas.DataFrame, shape (setup, metric)
        Indexed by setup name (unique) with one column per metric, in SI
        units (ratios do not depend on units; ``max`` limits do). A column
        ``setup`` is used as the index instead, so a predictions table reads
        as is. Other columns are ignored.
    objective : Objective, optional
        Default :func:`default_objective`.
    baseline : str, optional
        Setup to normalize against; default the objective's ``baseline``,
        else the first row.

    Returns
    -------
    Scores
        The table of scores, feasibility and ranks (see :class:`Scores`).

    Raises
    ------
    PlannerError
        If the table is empty, has duplicate setup names, lacks a metric the
        objective uses (weighted or limited) or has it non-numeric, the
        baseline is not in the table, or the baseline's value of a weighted
        or ``max_ratio``-limited metric is not finite and > 0.
    TypeError
        If `metrics` is not a DataFrame or `objective` not an Objective.

    Notes
    -----
    Vectorized over setups: 10^5 setups take a few tens of milliseconds. A
    NaN metric gives a NaN score (ranked last) and fails its limits.

    Examples
    --------
    >>> import pandas as pd
    >>> names = default_objective().metrics
    >>> m = pd.DataFrame([[1.0] * len(names), [0.9] * len(names)], columns=names,
    ...                  index=["baseline", "better"])
    >>> score_setups(m).table["score"].round(12).tolist()
    [1.0, 0.9]
    """
    if objective is None:
        objective = default_objective()
    if not isinstance(objective, Objective):
        raise TypeError(f"score_setups: objective must be an Objective, got "
                        f"{type(objective).__name__}")
    if not isinstance(metrics, pd.DataFrame):
        raise TypeError(f"score_setups: metrics must be a pandas DataFrame indexed by setup "
                        f"name, got {type(metrics).__name__}")
    if "setup" in metrics.columns:
        metrics = metrics.set_index("setup")
    if len(metrics) == 0:
        raise PlannerError("score_setups: the metrics table has no rows; predict the metrics "
                           "of at least one setup")
    if not metrics.index.is_unique:
        dup = metrics.index[metrics.index.duplicated()].unique().tolist()[:5]
        raise PlannerError(f"score_setups: the metrics table repeats setup name(s) {dup}; "
                           "give each setup a unique name")
    if baseline is None:
        baseline = objective.baseline if objective.baseline is not None else metrics.index[0]
    if baseline not in metrics.index:
        shown = metrics.index[:5].tolist()
        more = f" and {len(metrics) - 5} more" if len(metrics) > 5 else ""
        raise PlannerError(f"score_setups: baseline setup {baseline!r} is not in the metrics "
                           f"table (setups {shown}{more}); predict the baseline too or choose "
                           "another baseline")
    names = objective.metrics
    values = _metric_matrix(metrics, names, objective.name)          # (setup, metric)
    i_base = metrics.index.get_loc(baseline)
    base = values[i_base]
    col = {m: j for j, m in enumerate(names)}
    needs_base = [*objective.weights,
                  *(m for m, spec in objective.limits.items() if "max_ratio" in spec)]
    for m in needs_base:
        b = base[col[m]]
        if not (np.isfinite(b) and b > 0):
            raise PlannerError(f"score_setups: baseline {baseline!r} has {m} = {float(b)!r}, "
                               "which cannot normalize (need a finite value > 0); choose "
                               "another baseline or drop the metric from the objective")
    n = len(metrics)
    w_idx = np.array([col[m] for m in objective.weights], dtype=np.intp)
    w = np.array(list(objective.weights.values()))
    ratios = values[:, w_idx] / base[w_idx]                             # (setup, weighted)
    data = {"score": ratios @ w}
    w_pos = {m: j for j, m in enumerate(objective.weights)}
    for group, members in objective.groups.items():
        g = np.array([w_pos[m] for m in members], dtype=np.intp)
        data[f"score_{group}"] = ratios[:, g] @ w[g]
    violations = np.full(n, "", dtype=object)
    for m, spec in objective.limits.items():
        v = values[:, col[m]]
        nan = np.isnan(v)
        if nan.any():
            _join_messages(violations, np.flatnonzero(nan), np.array(f"{m} is NaN"))
        if "max_ratio" in spec:
            r = v / base[col[m]]
            idx = np.flatnonzero(~nan & ~(r <= spec["max_ratio"]))
            if idx.size:
                text = np.char.mod("%.4g", r[idx])
                _join_messages(violations, idx, np.char.add(np.char.add(
                    f"{m} = ", text), f" x baseline > max_ratio {spec['max_ratio']:g}"))
        if "min" in spec:
            idx = np.flatnonzero(~nan & ~(v >= spec["min"]))
            if idx.size:
                text = np.char.mod("%.4g", v[idx])
                _join_messages(violations, idx, np.char.add(np.char.add(
                    f"{m} = ", text), f" < min {spec['min']:.4g}"))
        if "max" in spec:
            idx = np.flatnonzero(~nan & ~(v <= spec["max"]))
            if idx.size:
                text = np.char.mod("%.4g", v[idx])
                _join_messages(violations, idx, np.char.add(np.char.add(
                    f"{m} = ", text), f" > max {spec['max']:.4g}"))
    feasible = violations == ""
    rank = ranks(feasible, data["score"])
    data["feasible"] = feasible.astype(bool)
    data["violations"] = violations
    data["rank"] = rank
    index = metrics.index.copy()
    if index.name is None:
        index.name = "setup"
    table = pd.DataFrame(data, index=index)
    baseline_values = pd.Series(base, index=list(names), name=baseline)
    logger.info("scored %d setups with objective %r (baseline %r): %d feasible", n,
                objective.name, baseline, int(feasible.sum()))
    return Scores(table, objective, baseline, baseline_values)


def pareto_front(scores, x="score_grip", y="score_platform", *, feasible_only=True):
    """Mask of the non-dominated setups for two scores (lower is better).

    Parameters
    ----------
    scores : Scores or pandas.DataFrame
        The scores (a DataFrame with columns `x` and `y`, e.g. ``Scores.table``).
    x, y : str
        The two columns to trade off.
    feasible_only : bool
        If the table has a ``feasible`` column, only feasible setups can be on
        the front (and dominate others).

    Returns
    -------
    ndarray of bool, shape (setup,)
        True for setups no other setup dominates (no other is <= in both and
        < in one); in table order. Identical points are all on the front; a
        NaN in `x` or `y` is never on it.

    Raises
    ------
    PlannerError
        If `x` or `y` is not a column.
    TypeError
        If `scores` is neither Scores nor a DataFrame.

    Notes
    -----
    O(n log n): sort by (x, y); a point is on the front if it has the
    smallest y of its x and a y strictly below every smaller x's.

    Examples
    --------
    >>> import pandas as pd
    >>> t = pd.DataFrame({"a": [1.0, 2.0, 3.0, 2.0], "b": [3.0, 1.0, 0.5, 2.0]})
    >>> pareto_front(t, "a", "b").tolist()
    [True, True, True, False]
    """
    table = scores.table if isinstance(scores, Scores) else scores
    if not isinstance(table, pd.DataFrame):
        raise TypeError(f"pareto_front: scores must be Scores or a DataFrame, got "
                        f"{type(scores).__name__}")
    for c in (x, y):
        if c not in table.columns:
            raise PlannerError(f"pareto_front: no column {c!r}; the table has "
                               f"{list(table.columns)}; pick two score columns")
    xv = table[x].to_numpy(dtype=float)
    yv = table[y].to_numpy(dtype=float)
    valid = ~(np.isnan(xv) | np.isnan(yv))
    if feasible_only and "feasible" in table.columns:
        valid &= table["feasible"].to_numpy(dtype=bool)
    mask = np.zeros(len(table), dtype=bool)
    rows = np.flatnonzero(valid)
    if rows.size == 0:
        return mask
    order = np.lexsort((yv[rows], xv[rows]))
    xs, ys = xv[rows][order], yv[rows][order]
    start = np.concatenate([[True], xs[1:] != xs[:-1]])
    gid = np.cumsum(start) - 1
    group_min = ys[start]                                   # first in group: smallest y
    prev_best = np.concatenate([[np.inf], np.minimum.accumulate(group_min)[:-1]])
    on_front = (ys == group_min[gid]) & ((gid == 0) | (ys < prev_best[gid]))
    mask[rows[order[on_front]]] = True
    return mask
