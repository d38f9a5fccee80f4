"""Shock-absorber models: force-velocity curves, shock libraries, dyno fits.

Every shock kind is exactly a continuous piecewise-linear force-velocity curve
(:class:`PiecewiseLinear`) plus a first-order lag ``lag_s`` between the curve's
force and the applied force, ``lag * dF/dt + F = f(v)``. The closed-loop
simulator only sees :meth:`ShockModel.to_pwl`, so a new kind needs no simulator
change.

SI inside: velocity [m/s], force [N], damping [N/(m/s)], lag [s]. Shock
velocity and force are positive in **compression** (bump), negative in
rebound, as in ``shared/spec/rig-session.md``.

Kinds (``kind`` in ``shocks.toml``):

``"linear"``
    :class:`LinearShock`, ``f = c v``.
``"table"``
    :class:`TableShock`, a piecewise-linear table (e.g. from a dyno), extended
    linearly beyond its ends with the slopes of its end segments.
``"digressive"``
    :class:`DigressiveShock`, two slopes per side (low speed up to a knee, high
    speed beyond), separate for bump and rebound.

Every ``[[shock]]`` table may also give ``count``, an integer >= 0: how many
of that shock the team has (its inventory, used by the planner to skip setups
that need more units than exist). Omitted means unlimited (``count=None``).

Examples
--------
>>> b20 = LinearShock("B20", 3502.5)
>>> float(b20.force(0.1))
350.25
>>> d8 = TableShock("D8", [-0.5, -0.1, 0.0, 0.1, 0.5],
...                 [-1100.0, -500.0, 0.0, 350.0, 700.0], lag_s=0.004)
>>> d8.force([0.05, 1.0]).tolist()
[175.0, 1137.5]
>>> lib = ShockLibrary.from_models([b20, d8])
>>> list(lib)
['B20', 'D8']
"""

from __future__ import annotations

import logging
import math
import numbers
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar, nnls
from scipy.special import ndtr

from ident.data.files import atomic_write_toml, did_you_mean, read_toml
from ident.errors import FitWarning, ShockModelError
from ident.data.units import UNIT_LABELS, check_units, from_si, to_si

__all__ = [
    "PASSIVITY_RTOL",
    "SHOCK_KINDS",
    "PiecewiseLinear",
    "ShockModel",
    "LinearShock",
    "TableShock",
    "DigressiveShock",
    "ShockLibrary",
    "read_shock_library",
    "write_shock_library",
    "fit_shock_to_dyno",
]

logger = logging.getLogger(__name__)

#: Relative tolerance (to the largest |force| of a table) within which a curve
#: counts as passing through (0, 0). Covers round-off of unit conversions.
PASSIVITY_RTOL = 1e-9


# ----------------------------------------------------------------------------
# small private helpers
# ----------------------------------------------------------------------------


def _out(x):
    """Return a Python float for a 0-d result, the array otherwise."""
    x = np.asarray(x)
    return float(x) if x.ndim == 0 else x


def _fmt(x):
    """Format a number for an error message (short, unambiguous)."""
    return f"{float(x):.6g}"


def _model_error(who, field_name, problem, fix):
    """Build a :class:`ShockModelError` about one field of one shock.

    `who` is the label of the object (``"shock 'B20'"``). The parts are kept as
    attributes so that :func:`read_shock_library` can re-word the message with
    the file, the shock's index and the TOML key.
    """
    exc = ShockModelError(f"{who}: {field_name} {problem}; {fix}")
    exc.field = field_name
    exc.problem = problem
    exc.fix = fix
    return exc


def _is_real_number(x):
    return isinstance(x, (numbers.Real, np.number)) and not isinstance(x, (bool, np.bool_))


def _check_scalar(who, name, value, *, minimum=None, strict=False, unit=""):
    """Return `value` as a finite float, or raise naming the object and field."""
    if not _is_real_number(value):
        raise _model_error(who, name, f"must be a number, got {type(value).__name__} "
                           f"{value!r}", "give a finite real number (no quotes)")
    value = float(value)
    if not math.isfinite(value):
        raise _model_error(who, name, f"is {value}, not finite", "give a finite number")
    if minimum is not None and (value < minimum or (strict and value == minimum)):
        rel = ">" if strict else ">="
        raise _model_error(who, name, f"= {_fmt(value)} {unit} is not {rel} {_fmt(minimum)}",
                           f"give a value {rel} {_fmt(minimum)}")
    return value


def _check_vector(who, name, values):
    """Return `values` as a read-only 1-D float64 array, or raise."""
    if isinstance(values, (str, bytes)) or not np.iterable(values):
        raise _model_error(who, name, f"must be a 1-D sequence of numbers, got "
                           f"{type(values).__name__}", "give a list of finite numbers")
    if not isinstance(values, np.ndarray):
        values = list(values)
        for j, x in enumerate(values):
            if not _is_real_number(x):
                raise _model_error(who, f"{name}[{j}]", f"must be a number, got "
                                   f"{type(x).__name__} {x!r}",
                                   "give finite real numbers (no quotes)")
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise _model_error(who, name, "is not an array of real numbers",
                           "give a list of finite numbers") from None
    if arr.ndim != 1:
        raise _model_error(who, name, f"must be 1-D, got shape {arr.shape}",
                           "give a flat list of numbers")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise _model_error(who, f"{name}[{bad[0]}]", f"is {arr[bad[0]]}, not finite "
                           f"({bad.size} non-finite value(s))", "give finite numbers")
    arr = np.ascontiguousarray(arr)
    arr.flags.writeable = False
    return arr


def _check_units_for(units, where):
    try:
        return check_units(units, where=where)
    except ValueError as exc:
        raise ShockModelError(str(exc)) from None


# ----------------------------------------------------------------------------
# PiecewiseLinear: the one representation the simulator uses
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PiecewiseLinear:
    """A continuous piecewise-linear force-velocity curve with linear extensions.

    Parameters
    ----------
    v_knots_m_s : array_like, shape (K,)
        Knot velocities [m/s], strictly increasing, ``K >= 1``.
    f_knots_n : array_like, shape (K,)
        Force at each knot [N].
    slope_below : float
        Slope [N/(m/s)] of the extension for ``v < v_knots_m_s[0]``.
    slope_above : float
        Slope [N/(m/s)] of the extension for ``v > v_knots_m_s[-1]``.

    Raises
    ------
    ShockModelError
        If the knots are not finite, not 1-D, of different lengths or not
        strictly increasing, or a slope is not finite.

    Notes
    -----
    The arrays are stored as read-only, C-contiguous float64 (ready for numba).
    This class does not require passivity (the simulator also uses it for
    force deviations ``f(v) - c_bar v``); the shock models check it.

    Examples
    --------
    >>> pwl = PiecewiseLinear([0.0, 0.1], [0.0, 500.0], 5000.0, 1000.0)
    >>> pwl.force([-0.1, 0.05, 0.2]).tolist()
    [-500.0, 250.0, 600.0]
    >>> pwl.slope([-0.1, 0.0, 0.1]).tolist()
    [5000.0, 5000.0, 1000.0]
    """

    v_knots_m_s: np.ndarray
    f_knots_n: np.ndarray
    slope_below: float
    slope_above: float

    def __post_init__(self):
        who = "piecewise-linear curve"
        v = _check_vector(who, "v_knots_m_s", self.v_knots_m_s)
        f = _check_vector(who, "f_knots_n", self.f_knots_n)
        if v.size < 1:
            raise _model_error(who, "v_knots_m_s", "is empty", "give at least one knot")
        if f.size != v.size:
            raise _model_error(who, "f_knots_n", f"has {f.size} values but v_knots_m_s has "
                               f"{v.size}", "give one force per knot velocity")
        dv = np.diff(v)
        if np.any(dv <= 0):
            j = int(np.flatnonzero(dv <= 0)[0])
            raise _model_error(who, "v_knots_m_s", f"is not strictly increasing at index "
                               f"{j + 1} ({_fmt(v[j])} then {_fmt(v[j + 1])} m/s)",
                               "sort the knots and remove duplicate velocities")
        object.__setattr__(self, "v_knots_m_s", v)
        object.__setattr__(self, "f_knots_n", f)
        object.__setattr__(self, "slope_below",
                           _check_scalar(who, "slope_below", self.slope_below))
        object.__setattr__(self, "slope_above",
                           _check_scalar(who, "slope_above", self.slope_above))
        slopes = np.concatenate([[self.slope_below], np.diff(f) / dv, [self.slope_above]])
        slopes.flags.writeable = False
        object.__setattr__(self, "_slopes", slopes)

    @property
    def segment_slopes(self):
        """ndarray, shape (K + 1,): slopes [N/(m/s)] below, of each segment, above."""
        return self._slopes

    def force(self, v_m_s):
        """Force [N] at velocity `v_m_s` [m/s].

        Parameters
        ----------
        v_m_s : float or array_like, any shape
            Velocity [m/s], compression positive.

        Returns
        -------
        float or ndarray, same shape as `v_m_s`
            Force [N]; NaN where `v_m_s` is NaN.
        """
        v = np.asarray(v_m_s, dtype=float)
        vk, fk = self.v_knots_m_s, self.f_knots_n
        f = np.interp(v, vk, fk)
        f = np.where(v < vk[0], fk[0] + self.slope_below * (v - vk[0]), f)
        f = np.where(v > vk[-1], fk[-1] + self.slope_above * (v - vk[-1]), f)
        return _out(f)

    def slope(self, v_m_s):
        """Slope df/dv [N/(m/s)] at velocity `v_m_s` [m/s].

        Parameters
        ----------
        v_m_s : float or array_like, any shape
            Velocity [m/s].

        Returns
        -------
        float or ndarray, same shape as `v_m_s`
            The slope of the segment containing `v_m_s`.

        Notes
        -----
        At a knot the slope of the segment on its **right** (towards higher
        velocity) is returned: the curve's right derivative. At the last knot
        that is `slope_above`.
        """
        v = np.asarray(v_m_s, dtype=float)
        idx = np.searchsorted(self.v_knots_m_s, v, side="right")
        return _out(self._slopes[idx])

    def equivalent_damping(self, v_rms_m_s):
        """Stochastic-linearization damping [N/(m/s)] for a Gaussian velocity.

        Parameters
        ----------
        v_rms_m_s : float or array_like, any shape
            RMS [m/s] of a zero-mean Gaussian velocity, ``> 0``.

        Returns
        -------
        float or ndarray, same shape as `v_rms_m_s`
            ``c_eq = E[v f(v)] / E[v^2] = E[f'(v)]`` (Stein's lemma), that is the
            sum over segments of slope times the probability of the segment.

        Raises
        ------
        ShockModelError
            If a `v_rms_m_s` is not finite and > 0.
        """
        return self._equivalent_damping(v_rms_m_s, "piecewise-linear curve")

    def _equivalent_damping(self, v_rms_m_s, who):
        s = np.asarray(v_rms_m_s, dtype=float)
        if not np.all(np.isfinite(s) & (s > 0)):
            bad = s[~(np.isfinite(s) & (s > 0))].ravel()[0]
            raise _model_error(who, "v_rms_m_s", f"= {bad} is not a finite value > 0",
                               "give the RMS shock velocity in m/s (> 0)")
        z = self.v_knots_m_s / s[..., None]                      # (..., K)
        cdf = ndtr(z)
        prob = np.concatenate([cdf[..., :1], np.diff(cdf, axis=-1), ndtr(-z[..., -1:])],
                              axis=-1)                          # (..., K + 1)
        return _out(prob @ self._slopes)

    def __repr__(self):
        return (f"PiecewiseLinear(v_knots_m_s={self.v_knots_m_s.tolist()}, "
                f"f_knots_n={self.f_knots_n.tolist()}, slope_below={self.slope_below!r}, "
                f"slope_above={self.slope_above!r})")


def _passivity_problem(pwl):
    """Return ``(field, problem, fix)`` if `pwl` is not passive, else ``None``.

    Passive means ``f(v) * v >= 0`` for every v: every knot force has the sign of
    its velocity, the curve passes through (0, 0) within :data:`PASSIVITY_RTOL`
    of the largest knot force, and both extension slopes are >= 0.
    """
    v, f = pwl.v_knots_m_s, pwl.f_knots_n
    tol = PASSIVITY_RTOL * float(np.max(np.abs(f)))
    wrong = np.flatnonzero(((v > 0) & (f < 0)) | ((v < 0) & (f > 0)))
    if wrong.size:
        j = int(wrong[0])
        return (f"force_n[{j}]", f"= {_fmt(f[j])} N at velocity {_fmt(v[j])} m/s has the "
                "wrong sign (f*v < 0, the shock would give energy)",
                "forces must have the sign of the velocity (compression positive, "
                "rebound negative)")
    f0 = pwl.force(0.0)
    if abs(f0) > tol:
        if v[0] <= 0 <= v[-1]:
            return ("force_n", f"gives f(0) = {_fmt(f0)} N, not 0 (not passive)",
                    "the curve must pass through (0, 0); subtract any gas or static force")
        return ("force_n", f"does not span v = 0 and its linear extension gives f(0) = "
                f"{_fmt(f0)} N, not 0 (not passive)", "add the point (0, 0) to the table")
    if pwl.slope_below < 0:
        return ("force_n", f"has a first-segment slope of {_fmt(pwl.slope_below)} N/(m/s) < 0, "
                "so its extension below the table is not passive",
                "make the force non-decreasing over the first two points")
    if pwl.slope_above < 0:
        return ("force_n", f"has a last-segment slope of {_fmt(pwl.slope_above)} N/(m/s) < 0, "
                "so its extension above the table is not passive",
                "make the force non-decreasing over the last two points")
    return None


# ----------------------------------------------------------------------------
# shock models
# ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ShockModel:
    """Base class of the shock models: a static curve ``f(v)`` plus a lag.

    Parameters
    ----------
    id : str
        The shock's name in the library (non-empty, no surrounding whitespace).
    lag_s : float, keyword-only
        First-order lag [s] between the curve's force and the applied force,
        ``lag_s * dF/dt + F = f(v)``; 0 (the default) is none. Must be >= 0.
    description : str, keyword-only
        Free text kept through read/write of a library.
    count : int or None, keyword-only
        How many of this shock the team has (inventory), an integer >= 0;
        ``None`` (the default) is unlimited. TOML key ``count``.

    Notes
    -----
    Shock velocity and force are positive in compression. Every kind is an
    exact continuous piecewise-linear curve, :meth:`to_pwl`. Models compare by
    identity (``eq=False``); compare :meth:`to_toml_dict` to compare values.
    """

    #: The TOML ``kind`` of the class.
    kind: ClassVar[str] = ""
    #: TOML key -> (attribute, quantity, "scalar" | "vector"), in file order.
    _TOML_FIELDS: ClassVar[dict] = {}

    id: str
    lag_s: float = field(default=0.0, kw_only=True)
    description: str = field(default="", kw_only=True)
    count: int | None = field(default=None, kw_only=True)

    def __post_init__(self):
        if not isinstance(self.id, str) or not self.id.strip() or self.id != self.id.strip():
            raise _model_error("shock", "id", f"{self.id!r} is not a valid shock id",
                               "give a non-empty string without surrounding whitespace")
        object.__setattr__(self, "lag_s", _check_scalar(self._who, "lag_s", self.lag_s,
                                                        minimum=0.0, unit="s"))
        if not isinstance(self.description, str):
            raise _model_error(self._who, "description", f"must be a string, got "
                               f"{type(self.description).__name__}", "give free text")
        if self.count is not None:
            if not isinstance(self.count, (numbers.Integral, np.integer)) or isinstance(
                    self.count, (bool, np.bool_)):
                raise _model_error(self._who, "count", f"must be an integer, got "
                                   f"{type(self.count).__name__} {self.count!r}",
                                   "give the number of units the team has (or None for "
                                   "unlimited)")
            if self.count < 0:
                raise _model_error(self._who, "count", f"= {self.count} is not >= 0",
                                   "give the number of units the team has (0 or more)")
            object.__setattr__(self, "count", int(self.count))
        self._validate()
        pwl = self._build_pwl()
        problem = _passivity_problem(pwl)
        if problem is not None:
            raise _model_error(self._who, *problem)
        object.__setattr__(self, "_pwl", pwl)

    @property
    def _who(self):
        return f"shock {self.id!r}"

    def _validate(self):  # pragma: no cover - overridden
        raise NotImplementedError

    def _build_pwl(self):  # pragma: no cover - overridden
        raise NotImplementedError

    def to_pwl(self):
        """Return the exact piecewise-linear curve of this shock.

        Returns
        -------
        PiecewiseLinear
            The curve ``f(v)`` (without the lag, see `lag_s`).
        """
        return self._pwl

    def force(self, v_m_s):
        """Static curve force ``f(v)`` [N] at shock velocity `v_m_s` [m/s].

        Parameters
        ----------
        v_m_s : float or array_like, any shape
            Shock velocity [m/s], compression positive.

        Returns
        -------
        float or ndarray, same shape as `v_m_s`
            Force [N], compression positive. The lag is not applied.
        """
        return self._pwl.force(v_m_s)

    def slope(self, v_m_s):
        """Slope ``df/dv`` [N/(m/s)] at `v_m_s` [m/s] (right derivative at knots).

        Parameters
        ----------
        v_m_s : float or array_like, any shape
            Shock velocity [m/s].

        Returns
        -------
        float or ndarray, same shape as `v_m_s`
        """
        return self._pwl.slope(v_m_s)

    def equivalent_damping(self, v_rms_m_s):
        """Equivalent linear damping [N/(m/s)] by stochastic linearization.

        Parameters
        ----------
        v_rms_m_s : float or array_like, any shape
            RMS [m/s] of a zero-mean Gaussian shock velocity, ``> 0``.

        Returns
        -------
        float or ndarray, same shape as `v_rms_m_s`
            ``c_eq = E[v f(v)] / E[v^2] = E[f'(v)]``.

        Raises
        ------
        ShockModelError
            If a `v_rms_m_s` is not finite and > 0.

        Notes
        -----
        By Stein's lemma ``E[v f(v)] = sigma^2 E[f'(v)]`` for a zero-mean
        Gaussian ``v`` of standard deviation ``sigma``; for a piecewise-linear
        curve ``E[f'(v)]`` is the sum over segments of the slope times
        ``Phi(b / sigma) - Phi(a / sigma)`` (``Phi`` the normal CDF).

        Examples
        --------
        >>> LinearShock("B20", 3502.5).equivalent_damping([0.01, 0.1]).tolist()
        [3502.5, 3502.5]
        """
        return self._pwl._equivalent_damping(v_rms_m_s, f"shock {self.id!r}")

    def scaled(self, force_scale=1.0, *, lag_s=None, id=None):
        """A copy with every force multiplied by `force_scale` and optionally another lag.

        The what-if of a shock that comes back from the dyno off by some
        percent, or fades when hot: the same kind of model, forces and
        damping coefficients scaled (velocities kept), so the curve is
        ``force_scale * f(v)`` exactly.

        Parameters
        ----------
        force_scale : float
            Force multiplier, > 0.
        lag_s : float, optional
            The copy's lag [s] (>= 0); default this shock's.
        id : str, optional
            The copy's id; default this shock's.

        Returns
        -------
        ShockModel
            Same class; the inventory ``count`` is kept.

        Examples
        --------
        >>> LinearShock("B20", 3500.0).scaled(1.1).c_n_s_m
        3850.0000000000005
        """
        import dataclasses

        s = _check_scalar(self._who, "force_scale", force_scale, minimum=0.0, strict=True)
        changes = {attr: np.asarray(getattr(self, attr), dtype=float) * s
                   if shape == "vector" else float(getattr(self, attr)) * s
                   for attr, quantity, shape in self._TOML_FIELDS.values()
                   if quantity in ("force", "damping")}
        changes["lag_s"] = self.lag_s if lag_s is None else lag_s
        changes["id"] = self.id if id is None else id
        return dataclasses.replace(self, **changes)

    def to_toml_dict(self, units="SI"):
        """Return this shock as one ``[[shock]]`` table of ``shocks.toml``.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Unit system of the values (velocity in/s, force lbf, damping
            lbf/(in/s) in imperial; lag always in s).

        Returns
        -------
        dict
            Keys ``id``, ``kind``, ``description`` (if not empty), the kind's
            keys, ``lag`` (if not 0), ``count`` (if not None).

        Raises
        ------
        ShockModelError
            If `units` is not a unit system.
        """
        units = _check_units_for(units, f"shock {self.id!r}: units")
        out = {"id": self.id, "kind": self.kind}
        if self.description:
            out["description"] = self.description
        for key, (attr, quantity, shape) in self._TOML_FIELDS.items():
            value = from_si(getattr(self, attr), quantity, units)
            out[key] = (np.asarray(value, dtype=float).tolist() if shape == "vector"
                        else float(value))
        if self.lag_s:
            out["lag"] = float(self.lag_s)
        if self.count is not None:
            out["count"] = int(self.count)
        return out


@dataclass(frozen=True, eq=False)
class LinearShock(ShockModel):
    """A linear shock, ``f = c_n_s_m * v``.

    Parameters
    ----------
    id : str
        Shock id.
    c_n_s_m : float
        Damping [N/(m/s)], >= 0.
    lag_s : float, keyword-only
        First-order lag [s], >= 0.
    description : str, keyword-only
        Free text.

    Raises
    ------
    ShockModelError
        On an invalid id, a negative or non-finite damping or lag.

    Examples
    --------
    >>> LinearShock("B20", 3502.5).force([-0.1, 0.2]).tolist()
    [-350.25, 700.5]
    """

    kind: ClassVar[str] = "linear"
    _TOML_FIELDS: ClassVar[dict] = {"damping": ("c_n_s_m", "damping", "scalar")}

    c_n_s_m: float

    def _validate(self):
        object.__setattr__(self, "c_n_s_m", _check_scalar(self._who, "c_n_s_m", self.c_n_s_m,
                                                          minimum=0.0, unit="N/(m/s)"))

    def _build_pwl(self):
        return PiecewiseLinear([0.0], [0.0], self.c_n_s_m, self.c_n_s_m)


@dataclass(frozen=True, eq=False)
class TableShock(ShockModel):
    """A piecewise-linear table shock (e.g. from a dyno).

    Parameters
    ----------
    id : str
        Shock id.
    velocity_m_s : array_like, shape (K,)
        Velocities [m/s], strictly increasing, compression positive, ``K >= 2``.
    force_n : array_like, shape (K,)
        Force [N] at each velocity, with the sign of the velocity.
    lag_s : float, keyword-only
        First-order lag [s], >= 0.
    description : str, keyword-only
        Free text.

    Raises
    ------
    ShockModelError
        On fewer than 2 points, a length mismatch, non-finite values, velocities
        not strictly increasing, or a curve that is not passive (see Notes).

    Notes
    -----
    Beyond the table the curve is extended linearly with the slopes of its end
    segments (spec). Passive means ``f(v) v >= 0`` everywhere: each force has
    the sign of its velocity, the curve (or its extension, when the table does
    not span 0) passes through (0, 0) within :data:`PASSIVITY_RTOL` times the
    largest |force|, and both end slopes are >= 0. Interior segments may have
    negative slopes. The arrays are stored read-only.
    """

    kind: ClassVar[str] = "table"
    _TOML_FIELDS: ClassVar[dict] = {"velocity": ("velocity_m_s", "velocity", "vector"),
                                    "force": ("force_n", "force", "vector")}

    velocity_m_s: np.ndarray
    force_n: np.ndarray

    def _validate(self):
        v = _check_vector(self._who, "velocity_m_s", self.velocity_m_s)
        f = _check_vector(self._who, "force_n", self.force_n)
        if v.size != f.size:
            raise _model_error(self._who, "force_n", f"has {f.size} values but velocity_m_s "
                               f"has {v.size}", "give one force per velocity")
        if v.size < 2:
            raise _model_error(self._who, "velocity_m_s", f"has {v.size} point(s)",
                               "give at least 2 points (or use a linear shock)")
        dv = np.diff(v)
        if np.any(dv <= 0):
            j = int(np.flatnonzero(dv <= 0)[0])
            raise _model_error(self._who, "velocity_m_s", f"is not strictly increasing at index "
                               f"{j + 1} ({_fmt(v[j])} then {_fmt(v[j + 1])} m/s)",
                               "sort the points and remove duplicate velocities")
        object.__setattr__(self, "velocity_m_s", v)
        object.__setattr__(self, "force_n", f)

    def _build_pwl(self):
        v, f = self.velocity_m_s, self.force_n
        return PiecewiseLinear(v, f, (f[1] - f[0]) / (v[1] - v[0]),
                               (f[-1] - f[-2]) / (v[-1] - v[-2]))

    def __repr__(self):
        lag = f", lag_s={self.lag_s!r}" if self.lag_s else ""
        return (f"TableShock(id={self.id!r}, velocity_m_s={self.velocity_m_s.tolist()}, "
                f"force_n={self.force_n.tolist()}{lag})")


@dataclass(frozen=True, eq=False)
class DigressiveShock(ShockModel):
    """A two-slope (knee) shock, separate for bump (v > 0) and rebound (v < 0).

    Parameters
    ----------
    id : str
        Shock id.
    bump_low_n_s_m : float
        Bump slope [N/(m/s)] for ``0 <= v <= bump_knee_m_s``, >= 0.
    bump_knee_m_s : float
        Bump knee velocity [m/s], > 0.
    bump_high_n_s_m : float
        Bump slope [N/(m/s)] for ``v > bump_knee_m_s``, >= 0.
    rebound_low_n_s_m : float
        Rebound slope [N/(m/s)] for ``-rebound_knee_m_s <= v < 0``, >= 0.
    rebound_knee_m_s : float
        Rebound knee velocity as a magnitude [m/s], > 0.
    rebound_high_n_s_m : float
        Rebound slope [N/(m/s)] for ``v < -rebound_knee_m_s``, >= 0.
    lag_s : float, keyword-only
        First-order lag [s], >= 0.
    description : str, keyword-only
        Free text.

    Raises
    ------
    ShockModelError
        On a negative or non-finite slope, a knee not > 0, or a bad id or lag.

    Notes
    -----
    The name follows usage (high slope below low slope), but any non-negative
    slopes are accepted, so a progressive curve is representable too. The
    curve is the table with knots ``[-rebound_knee, 0, bump_knee]``.

    Examples
    --------
    >>> s = DigressiveShock("K1", 8000.0, 0.1, 2000.0, 12000.0, 0.05, 3000.0)
    >>> s.force([-0.15, -0.05, 0.1, 0.2]).tolist()
    [-900.0, -600.0, 800.0, 1000.0]
    """

    kind: ClassVar[str] = "digressive"
    _TOML_FIELDS: ClassVar[dict] = {
        "bump_low": ("bump_low_n_s_m", "damping", "scalar"),
        "bump_knee": ("bump_knee_m_s", "velocity", "scalar"),
        "bump_high": ("bump_high_n_s_m", "damping", "scalar"),
        "rebound_low": ("rebound_low_n_s_m", "damping", "scalar"),
        "rebound_knee": ("rebound_knee_m_s", "velocity", "scalar"),
        "rebound_high": ("rebound_high_n_s_m", "damping", "scalar"),
    }

    bump_low_n_s_m: float
    bump_knee_m_s: float
    bump_high_n_s_m: float
    rebound_low_n_s_m: float
    rebound_knee_m_s: float
    rebound_high_n_s_m: float

    def _validate(self):
        for attr, quantity, _ in self._TOML_FIELDS.values():
            knee = quantity == "velocity"
            value = _check_scalar(self._who, attr, getattr(self, attr), minimum=0.0,
                                  strict=knee, unit="m/s" if knee else "N/(m/s)")
            object.__setattr__(self, attr, value)

    def _build_pwl(self):
        kb, kr = self.bump_knee_m_s, self.rebound_knee_m_s
        return PiecewiseLinear([-kr, 0.0, kb],
                               [-self.rebound_low_n_s_m * kr, 0.0, self.bump_low_n_s_m * kb],
                               self.rebound_high_n_s_m, self.bump_high_n_s_m)


#: TOML ``kind`` -> model class.
SHOCK_KINDS = {cls.kind: cls for cls in (LinearShock, TableShock, DigressiveShock)}


# ----------------------------------------------------------------------------
# shock library
# ----------------------------------------------------------------------------


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
    if not _is_real_number(value):
        raise _fail(where, key, f"must be a number, got {type(value).__name__} {value!r}",
                    "write a number without quotes")
    return float(value)


def _toml_numbers(where, key, value):
    if not isinstance(value, list):
        raise _fail(where, key, f"must be an array of numbers, got {type(value).__name__} "
                    f"{value!r}", "write it as [v1, v2, ...]")
    for j, x in enumerate(value):
        if not _is_real_number(x):
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
    allowed = {"id", "kind", "lag", "description", "count", *cls._TOML_FIELDS}
    extra = [k for k in table if k not in allowed]
    if extra:
        raise _fail(label, extra[0], f"is not a key of a {kind!r} shock",
                    f"remove it or fix its spelling (keys: {sorted(allowed)})")
    kwargs = {}
    for key, (attr, quantity, shape) in cls._TOML_FIELDS.items():
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
    keys = {attr: key for key, (attr, _, _) in cls._TOML_FIELDS.items()}
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
    units = _check_units_for(doc.get("units", "SI"), f"{path}: key 'units'")
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
    units = _check_units_for(units, "write_shock_library: units")
    path = Path(path)
    doc = {"units": units, "shock": [m.to_toml_dict(units) for m in library.values()]}
    atomic_write_toml(path, doc, overwrite=overwrite,
                      header="Shock library (rig-session/1), written by shockplan.")
    logger.info("wrote %d shock(s) to %s (%s)", len(library), path, units)
    return path


# ----------------------------------------------------------------------------
# dyno fitting
# ----------------------------------------------------------------------------


def _dyno_points(data, units, where):
    """Return signed (velocity [m/s], force [N], row labels) from dyno data."""
    if isinstance(data, pd.DataFrame):
        df = data
    elif isinstance(data, (str, Path)):
        p = Path(data)
        if not p.is_file():
            raise ShockModelError(f"{where}: dyno file not found; check the path")
        try:
            df = pd.read_csv(p)
        except (ValueError, pd.errors.ParserError, UnicodeDecodeError) as exc:
            raise ShockModelError(f"{where}: cannot read the dyno CSV ({exc}); give a CSV "
                                  "with a header row") from None
    else:
        raise TypeError(f"dyno data must be a CSV path or a pandas DataFrame, got "
                        f"{type(data).__name__}")
    cols = {str(c).strip().lower(): c for c in df.columns}

    def column(name, quantity):
        raw = df[cols[name]]
        num = pd.to_numeric(raw, errors="coerce")
        bad = np.flatnonzero(num.isna().to_numpy())
        if bad.size:
            r = int(bad[0])
            raise ShockModelError(f"{where}: column {cols[name]!r} has {bad.size} missing or "
                                  f"non-numeric value(s), the first at data row {r + 1} "
                                  f"({raw.iloc[r]!r}); fill or remove those rows")
        return np.asarray(to_si(num.to_numpy(dtype=float), quantity, units), dtype=float)

    if "velocity" not in cols:
        raise ShockModelError(f"{where}: no column 'velocity' (columns: "
                              f"{[str(c) for c in df.columns]}); give columns velocity, force "
                              "or velocity, bump_force, rebound_force")
    if len(df) == 0:
        raise ShockModelError(f"{where}: no data rows; give at least one measured point")
    has_signed = "force" in cols
    has_split = "bump_force" in cols or "rebound_force" in cols
    if has_signed and has_split:
        raise ShockModelError(f"{where}: has both a 'force' column and 'bump_force'/"
                              "'rebound_force' columns; keep one layout")
    v = column("velocity", "velocity")
    rows = np.arange(1, len(df) + 1)
    if has_signed:
        f = column("force", "force")
        return v, f, rows, ("velocity", "force")
    for name in ("bump_force", "rebound_force"):
        if name not in cols:
            raise ShockModelError(f"{where}: no column {name!r} (columns: "
                                  f"{[str(c) for c in df.columns]}); give columns velocity, "
                                  "bump_force, rebound_force, or velocity, force (signed)")
    fb = column("bump_force", "force")
    fr = column("rebound_force", "force")
    neg = np.flatnonzero(v < 0)
    if neg.size:
        raise ShockModelError(f"{where}: column {cols['velocity']!r} has a negative value at "
                              f"data row {neg[0] + 1} while bump_force/rebound_force are "
                              "given; give velocity magnitudes, or use signed columns "
                              "velocity, force")
    for name, arr in (("bump_force", fb), ("rebound_force", fr)):
        neg = np.flatnonzero(arr < 0)
        if neg.size:
            raise ShockModelError(f"{where}: column {cols[name]!r} has a negative value at "
                                  f"data row {neg[0] + 1}; give force magnitudes (positive) "
                                  "as the dyno reports them")
    return (np.concatenate([v, -v]), np.concatenate([fb, -fr]), np.concatenate([rows, rows]),
            ("velocity", "bump_force/rebound_force"))


def _check_dyno_passive(v, f, rows, colnames, where, units):
    wrong = np.flatnonzero(v * f < 0)
    if wrong.size:
        j = int(wrong[0])
        raise ShockModelError(
            f"{where}: column {colnames[1]!r} data row {rows[j]}: force "
            f"{_fmt(from_si(f[j], 'force', units))} {UNIT_LABELS[units]['force']} at velocity "
            f"{_fmt(from_si(v[j], 'velocity', units))} {UNIT_LABELS[units]['velocity']} has the "
            "wrong sign (not passive); check the sign convention (compression positive)")
    tol = PASSIVITY_RTOL * float(np.max(np.abs(f)))
    zero = np.flatnonzero((v == 0) & (np.abs(f) > tol))
    if zero.size:
        j = int(zero[0])
        raise ShockModelError(
            f"{where}: column {colnames[1]!r} data row {rows[j]}: force "
            f"{_fmt(from_si(f[j], 'force', units))} {UNIT_LABELS[units]['force']} at zero "
            "velocity (not passive); subtract the gas or static force first")


def _fit_table(v, f, where, units, colnames):
    keep = v != 0
    v, f = v[keep], f[keep]
    if v.size == 0:
        raise ShockModelError(f"{where}: column {colnames[0]!r} has no non-zero velocity; "
                              "give measured points away from 0")
    uv, inv = np.unique(v, return_inverse=True)
    uf = np.bincount(inv, weights=f) / np.bincount(inv)
    vk = np.concatenate([uv[uv < 0], [0.0], uv[uv > 0]])
    fk = np.concatenate([uf[uv < 0], [0.0], uf[uv > 0]])
    for side, present in (("rebound", np.any(uv < 0)), ("bump", np.any(uv > 0))):
        if not present:
            warnings.warn(f"{where}: no {side} points; the {side} side of the table is the "
                          "linear extension of the other side's first segment through (0, 0); "
                          f"measure {side} points to model it", FitWarning, stacklevel=3)
    pwl = PiecewiseLinear(vk, fk, 0.0, 0.0)
    slopes = pwl.segment_slopes[1:-1]
    for end, s, pts in (("lowest", slopes[0], (0, 1)), ("highest", slopes[-1], (-2, -1))):
        if s < 0:
            va, vb = (from_si(vk[i], "velocity", units) for i in pts)
            raise ShockModelError(
                f"{where}: column {colnames[1]!r}: the force decreases in magnitude between "
                f"velocities {_fmt(va)} and {_fmt(vb)} {UNIT_LABELS[units]['velocity']} (the "
                f"{end} two points), so the table's linear extension would not be passive; "
                "remove the outlier or fit kind='digressive'")
    return vk, fk, uv.size


def _fit_side(u, g, where, side):
    """Fit ``g = a min(u, k) + b max(u - k, 0)`` with a, b >= 0 and a knee k.

    Returns ``(a, k, b, sse)``.
    """
    uniq = np.unique(u)
    if uniq.size < 3:
        raise ShockModelError(f"{where}: the {side} side has {uniq.size} distinct non-zero "
                              "velocities; a digressive fit needs at least 3 per side; measure "
                              "more points or use kind='table'")
    lo, hi = float(uniq[0]), float(uniq[-2])

    def solve(k):
        a_mat = np.column_stack([np.minimum(u, k), np.maximum(u - k, 0.0)])
        x, rnorm = nnls(a_mat, g)
        return x, rnorm * rnorm

    grid = np.unique(np.concatenate([np.linspace(lo, hi, 65), uniq[:-1]]))
    sse = np.array([solve(k)[1] for k in grid])
    j = int(np.argmin(sse))
    k_best, sse_best = float(grid[j]), float(sse[j])
    a_lo, a_hi = float(grid[max(j - 1, 0)]), float(grid[min(j + 1, grid.size - 1)])
    if a_hi > a_lo:
        res = minimize_scalar(lambda k: solve(k)[1], bounds=(a_lo, a_hi), method="bounded",
                              options={"xatol": 1e-10 * hi})
        if res.fun <= sse_best:
            k_best, sse_best = float(res.x), float(res.fun)
    (a, b), sse_best = solve(k_best)
    if k_best <= lo * (1 + 1e-6) or k_best >= hi * (1 - 1e-6):
        warnings.warn(f"{where}: the {side} knee is at the edge of the measured velocities "
                      f"({_fmt(k_best)} m/s); the knee is poorly determined, measure more "
                      "points around it", FitWarning, stacklevel=3)
    return float(a), k_best, float(b), float(sse_best)


def fit_shock_to_dyno(data, *, id, kind="table", units="SI", lag_s=0.0, where=None):
    """Fit a shock model to dyno data (peak force vs peak velocity).

    Parameters
    ----------
    data : str, path or pandas.DataFrame
        A CSV file (with a header row) or a DataFrame, in one of two layouts:
        (a) columns ``velocity``, ``force``: signed, compression positive,
        rebound rows negative; (b) columns ``velocity``, ``bump_force``,
        ``rebound_force``: velocity magnitudes and force magnitudes (all >= 0)
        as dynos report them. Column names are matched case-insensitively.
    id : str
        The id of the fitted shock.
    kind : {"table", "digressive"}
        ``"table"``: the measured points (duplicate velocities averaged) plus
        the (0, 0) knot. ``"digressive"``: least-squares low slope, knee and
        high slope per side (knee by a bounded 1-D search, slopes >= 0 by
        non-negative linear least squares given the knee).
    units : {"SI", "imperial"}
        Unit system of the data (velocity m/s or in/s, force N or lbf).
    lag_s : float
        Lag [s] of the returned model.
    where : str, optional
        Name of the data in messages; default the file path or
        ``"dyno DataFrame"``.

    Returns
    -------
    TableShock or DigressiveShock
        The fitted model in SI; its ``description`` says what it was fitted to.

    Raises
    ------
    ShockModelError
        If a column is missing or non-numeric, the data are not passive (a
        force of the wrong sign, a non-zero force at zero velocity, a table
        whose end slope is negative), a side has too few points for the
        digressive fit, or `kind` or `units` is unknown.
    TypeError
        If `data` is neither a path nor a DataFrame.

    Warns
    -----
    FitWarning
        A table with no points on one side; a digressive knee at the edge of
        the measured velocities.
    """
    if where is None:
        where = "dyno DataFrame" if isinstance(data, pd.DataFrame) else str(data)
    if kind not in ("table", "digressive"):
        raise ShockModelError(f"{where}: unknown fit kind {kind!r}; use 'table' or "
                              "'digressive'")
    units = _check_units_for(units, f"{where}: units")
    v, f, rows, colnames = _dyno_points(data, units, where)
    _check_dyno_passive(v, f, rows, colnames, where, units)
    n = v.size
    if kind == "table":
        vk, fk, n_unique = _fit_table(v, f, where, units, colnames)
        model = TableShock(id, vk, fk, lag_s=lag_s,
                           description=f"table fitted to dyno data {where} ({n} points, "
                                       f"{n_unique} distinct velocities)")
        logger.info("fitted table shock %r to %s: %d knots", id, where, vk.size)
        return model
    params = {}
    sse_total = 0.0
    for side, mask, sign in (("bump", v > 0, 1.0), ("rebound", v < 0, -1.0)):
        a, k, b, sse = _fit_side(sign * v[mask], sign * f[mask], where, side)
        params.update({f"{side}_low_n_s_m": a, f"{side}_knee_m_s": k,
                       f"{side}_high_n_s_m": b})
        sse_total += sse
    # points at v = 0 have f = 0 (checked) and the model gives 0 there: no residual
    rms = math.sqrt(sse_total / n)
    model = DigressiveShock(id, **params, lag_s=lag_s,
                            description=f"digressive fitted to dyno data {where} ({n} points, "
                                        f"RMS residual {rms:.4g} N)")
    logger.info("fitted digressive shock %r to %s: RMS residual %.4g N over %d points",
                id, where, rms, n)
    return model
