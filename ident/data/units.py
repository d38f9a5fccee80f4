"""Unit systems at the file boundary.

Everything inside shockplan is SI. Files declare ``units = "SI"`` or
``units = "imperial"``; this module converts between the two. The table of the
rig-session spec is encoded in :data:`TO_SI`: the factor that multiplies a value
in the imperial unit to give the SI unit.

Examples
--------
>>> to_si(20.0, "damping", "imperial")  # 20 lbf/(in/s) in N/(m/s)
3502.536...
"""

from __future__ import annotations

import numpy as np

__all__ = ["UNIT_SYSTEMS", "TO_SI", "UNIT_LABELS", "check_units", "to_si", "from_si"]

UNIT_SYSTEMS = ("SI", "imperial")

_IN = 0.0254  # m
_LBF = 4.4482216152605  # N
_LBM = 0.45359237  # kg

#: Factor from the imperial unit to the SI unit, per quantity.
TO_SI = {
    "displacement": _IN,  # in -> m
    "velocity": _IN,  # in/s -> m/s
    "acceleration": _IN,  # in/s^2 -> m/s^2
    "force": _LBF,  # lbf -> N
    "moment": _LBF * _IN,  # lbf*in -> N*m
    "damping": _LBF / _IN,  # lbf/(in/s) -> N/(m/s)
    "stiffness": _LBF / _IN,  # lbf/in -> N/m
    "rotational_stiffness": _LBF * _IN,  # lbf*in/rad -> N*m/rad
    "mass": _LBM,  # lbm -> kg
    "inertia": _LBM * _IN**2,  # lbm*in^2 -> kg*m^2
    "time": 1.0,  # s
    "frequency": 1.0,  # Hz
    "angle": 1.0,  # rad
    "dimensionless": 1.0,
}

#: Display labels per quantity and unit system.
UNIT_LABELS = {
    "SI": {
        "displacement": "m", "velocity": "m/s", "acceleration": "m/s^2",
        "force": "N", "moment": "N*m", "damping": "N/(m/s)", "stiffness": "N/m",
        "rotational_stiffness": "N*m/rad", "mass": "kg", "inertia": "kg*m^2",
        "time": "s", "frequency": "Hz", "angle": "rad", "dimensionless": "-",
    },
    "imperial": {
        "displacement": "in", "velocity": "in/s", "acceleration": "in/s^2",
        "force": "lbf", "moment": "lbf*in", "damping": "lbf/(in/s)", "stiffness": "lbf/in",
        "rotational_stiffness": "lbf*in/rad", "mass": "lbm", "inertia": "lbm*in^2",
        "time": "s", "frequency": "Hz", "angle": "rad", "dimensionless": "-",
    },
}


def check_units(units, *, where="units", error=ValueError):
    """Return the canonical unit-system name, or raise a clear ``ValueError``.

    Parameters
    ----------
    units : str
        ``"SI"`` or ``"imperial"`` (case-insensitive).
    where : str
        Where the value came from (file and key), used in the message.
    error : type
        Exception class to raise (a ``ValueError`` subclass of the caller's
        family, e.g. ``SessionError``).

    Raises
    ------
    ValueError
        If `units` is not a known unit system.
    """
    if isinstance(units, str):
        for name in UNIT_SYSTEMS:
            if units.strip().lower() == name.lower():
                return name
    raise error(
        f"{where}: unknown unit system {units!r}; use \"SI\" or \"imperial\""
    )


def _factor(quantity):
    try:
        return TO_SI[quantity]
    except KeyError:
        raise ValueError(
            f"unknown quantity {quantity!r}; expected one of {sorted(TO_SI)}"
        ) from None


def to_si(value, quantity, units):
    """Convert `value` of a `quantity` given in `units` to SI.

    Parameters
    ----------
    value : float or array_like
        Value(s) in the file's unit system.
    quantity : str
        A key of :data:`TO_SI` (e.g. ``"force"``).
    units : {"SI", "imperial"}
        The unit system of `value`.

    Returns
    -------
    float or ndarray
        The value in SI units.
    """
    units = check_units(units)
    if units == "SI":
        return value
    f = _factor(quantity)
    return np.asarray(value, dtype=float) * f if np.ndim(value) else float(value) * f


def from_si(value, quantity, units):
    """Convert an SI `value` of a `quantity` to `units` (inverse of :func:`to_si`)."""
    units = check_units(units)
    if units == "SI":
        return value
    f = _factor(quantity)
    return np.asarray(value, dtype=float) / f if np.ndim(value) else float(value) / f
