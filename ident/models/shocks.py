"""Shock-absorber models: force-velocity curves with a lag.

Every shock kind is exactly a continuous piecewise-linear force-velocity curve
(:class:`PiecewiseLinear`) plus a first-order lag ``lag_s`` between the curve's
force and the applied force, ``lag * dF/dt + F = f(v)``. The closed-loop
simulator only sees :meth:`ShockModel.to_pwl`, so a new kind needs no simulator
change. The shock library and its file ``shocks.toml`` are in
:mod:`ident.models.library`, fits to dyno data in :mod:`ident.dyno.sheet_fit`.

SI inside: velocity [m/s], force [N], damping [N/(m/s)], lag [s]. Shock
velocity and force are positive in **compression** (bump), negative in
rebound, as in ``shared/spec/rig-session.md``.

Kinds (``kind`` in ``shocks.toml``, :data:`SHOCK_KINDS`):

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
It may give ``fits``, what the damper is for (:data:`SHOCK_FITS`): ``"corner"``,
``"heave"`` or ``"roll"`` (a third element's damper, in the element's own travel and
force: enumerations do not put it at the corners). Omitted means any use (``fits=None``).

:func:`is_real_number`, :func:`format_number` and :func:`check_shock_units` are the
input checks and message formatting shared with the library and the dyno fits.

Examples
--------
>>> b20 = LinearShock("B20", 3502.5)
>>> float(b20.force(0.1))
350.25
>>> d8 = TableShock("D8", [-0.5, -0.1, 0.0, 0.1, 0.5],
...                 [-1100.0, -500.0, 0.0, 350.0, 700.0], lag_s=0.004)
>>> d8.force([0.05, 1.0]).tolist()
[175.0, 1137.5]
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from scipy.special import ndtr

from ident.data.units import check_units, from_si
from ident.errors import ShockModelError

__all__ = [
    "PASSIVITY_RTOL",
    "SHOCK_FITS",
    "SHOCK_KINDS",
    "PiecewiseLinear",
    "ShockModel",
    "LinearShock",
    "TableShock",
    "DigressiveShock",
    "is_real_number",
    "format_number",
    "check_shock_units",
]

#: Relative tolerance (to the largest |force| of a table) within which a curve
#: counts as passing through (0, 0). Covers round-off of unit conversions.
PASSIVITY_RTOL = 1e-9
#: A damper's uses (the library's optional ``fits``): at a corner, or as an axle's heave or
#: roll element's damper (in the element's own travel and force).
SHOCK_FITS = ("corner", "heave", "roll")


# ----------------------------------------------------------------------------
# small private helpers
# ----------------------------------------------------------------------------


def _out(x):
    """Return a Python float for a 0-d result, the array otherwise."""
    x = np.asarray(x)
    return float(x) if x.ndim == 0 else x


def format_number(x):
    """Format a number for an error message (short, unambiguous).

    Examples
    --------
    >>> format_number(3502.5), format_number(1 / 3)
    ('3502.5', '0.333333')
    """
    return f"{float(x):.6g}"


def _model_error(who, field_name, problem, fix):
    """Build a :class:`ShockModelError` about one field of one shock.

    `who` is the label of the object (``"shock 'B20'"``). The parts are kept as
    attributes so that :func:`ident.models.library.read_shock_library` can re-word the
    message with the file, the shock's index and the TOML key.
    """
    exc = ShockModelError(f"{who}: {field_name} {problem}; {fix}")
    exc.field = field_name
    exc.problem = problem
    exc.fix = fix
    return exc


def is_real_number(x):
    """Return whether `x` is a real number (Python or numpy), booleans excluded.

    Examples
    --------
    >>> is_real_number(2), is_real_number(np.float32(0.5)), is_real_number(True)
    (True, True, False)
    """
    return isinstance(x, (numbers.Real, np.number)) and not isinstance(x, (bool, np.bool_))


def _check_scalar(who, name, value, *, minimum=None, strict=False, unit=""):
    """Return `value` as a finite float, or raise naming the object and field."""
    if not is_real_number(value):
        raise _model_error(who, name, f"must be a number, got {type(value).__name__} "
                           f"{value!r}", "give a finite real number (no quotes)")
    value = float(value)
    if not math.isfinite(value):
        raise _model_error(who, name, f"is {value}, not finite", "give a finite number")
    if minimum is not None and (value < minimum or (strict and value == minimum)):
        rel = ">" if strict else ">="
        raise _model_error(who, name,
                           f"= {format_number(value)} {unit} is not {rel} {format_number(minimum)}",
                           f"give a value {rel} {format_number(minimum)}")
    return value


def _check_vector(who, name, values):
    """Return `values` as a read-only 1-D float64 array, or raise."""
    if isinstance(values, (str, bytes)) or not np.iterable(values):
        raise _model_error(who, name, f"must be a 1-D sequence of numbers, got "
                           f"{type(values).__name__}", "give a list of finite numbers")
    if not isinstance(values, np.ndarray):
        values = list(values)
        for j, x in enumerate(values):
            if not is_real_number(x):
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


def check_shock_units(units, where):
    """Return the unit system `units` checked, raising :class:`ShockModelError` if unknown.

    Parameters
    ----------
    units : {"SI", "imperial"}
        The unit system name.
    where : str
        Prefix of the error message.

    Returns
    -------
    str

    Raises
    ------
    ShockModelError
        If `units` is not a unit system (:func:`ident.data.units.check_units`).
    """
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
                               f"{j + 1} ({format_number(v[j])} then "
                               f"{format_number(v[j + 1])} m/s)",
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
        return (f"force_n[{j}]", f"= {format_number(f[j])} N at velocity "
                f"{format_number(v[j])} m/s has the wrong sign (f*v < 0, the shock would "
                "give energy)",
                "forces must have the sign of the velocity (compression positive, "
                "rebound negative)")
    f0 = pwl.force(0.0)
    if abs(f0) > tol:
        if v[0] <= 0 <= v[-1]:
            return ("force_n", f"gives f(0) = {format_number(f0)} N, not 0 (not passive)",
                    "the curve must pass through (0, 0); subtract any gas or static force")
        return ("force_n", f"does not span v = 0 and its linear extension gives f(0) = "
                f"{format_number(f0)} N, not 0 (not passive)", "add the point (0, 0) to the table")
    if pwl.slope_below < 0:
        return ("force_n", f"has a first-segment slope of {format_number(pwl.slope_below)} "
                "N/(m/s) < 0, so its extension below the table is not passive",
                "make the force non-decreasing over the first two points")
    if pwl.slope_above < 0:
        return ("force_n", f"has a last-segment slope of {format_number(pwl.slope_above)} "
                "N/(m/s) < 0, so its extension above the table is not passive",
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
    fits : {"corner", "heave", "roll"} or None, keyword-only
        What the damper is for (:data:`SHOCK_FITS`); None (the default): any use. TOML
        key ``fits``.

    Notes
    -----
    Shock velocity and force are positive in compression. Every kind is an
    exact continuous piecewise-linear curve, :meth:`to_pwl`. Models compare by
    identity (``eq=False``); compare :meth:`to_toml_dict` to compare values.
    """

    #: The TOML ``kind`` of the class.
    kind: ClassVar[str] = ""
    #: TOML key -> (attribute, quantity, "scalar" | "vector"), in file order.
    TOML_FIELDS: ClassVar[dict] = {}

    id: str
    lag_s: float = field(default=0.0, kw_only=True)
    description: str = field(default="", kw_only=True)
    count: int | None = field(default=None, kw_only=True)
    fits: str | None = field(default=None, kw_only=True)

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
        if self.fits is not None and self.fits not in SHOCK_FITS:
            raise _model_error(self._who, "fits", f"= {self.fits!r} is not a use",
                               f"give one of {list(SHOCK_FITS)}, or leave it out for any use")
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
                   for attr, quantity, shape in self.TOML_FIELDS.values()
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
            keys, ``lag`` (if not 0), ``count`` and ``fits`` (if not None).

        Raises
        ------
        ShockModelError
            If `units` is not a unit system.
        """
        units = check_shock_units(units, f"shock {self.id!r}: units")
        out = {"id": self.id, "kind": self.kind}
        if self.description:
            out["description"] = self.description
        for key, (attr, quantity, shape) in self.TOML_FIELDS.items():
            value = from_si(getattr(self, attr), quantity, units)
            out[key] = (np.asarray(value, dtype=float).tolist() if shape == "vector"
                        else float(value))
        if self.lag_s:
            out["lag"] = float(self.lag_s)
        if self.count is not None:
            out["count"] = int(self.count)
        if self.fits is not None:
            out["fits"] = self.fits
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
    TOML_FIELDS: ClassVar[dict] = {"damping": ("c_n_s_m", "damping", "scalar")}

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
    TOML_FIELDS: ClassVar[dict] = {"velocity": ("velocity_m_s", "velocity", "vector"),
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
                               f"{j + 1} ({format_number(v[j])} then "
                               f"{format_number(v[j + 1])} m/s)",
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
    TOML_FIELDS: ClassVar[dict] = {
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
        for attr, quantity, _ in self.TOML_FIELDS.values():
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
