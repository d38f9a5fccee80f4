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

import contextlib
import contextvars

import numpy as np

__all__ = ["UNIT_SYSTEMS", "TO_SI", "UNIT_LABELS", "SMALL_SI_LABELS", "check_units", "to_si",
           "from_si", "unit_label", "display_units", "set_display_units", "get_display_units",
           "format_quantity", "format_significant", "round_significant", "FILE_DIGITS"]

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


#: SI display units of the quantities a person reads in thousandths (a travel in mm, a shock
#: velocity in mm/s): label and factor from the SI unit. Imperial has no such scale (inches
#: and in/s are read as they are), so ``small=True`` changes the SI display only.
SMALL_SI_LABELS = {"displacement": ("mm", 1e3), "velocity": ("mm/s", 1e3),
                   "acceleration": ("mm/s^2", 1e3)}

#: Significant digits of a number converted at the file boundary and written to a TOML or
#: CSV file (:func:`round_significant`): far below any measurement (5e-13 relative), far
#: above the round-off of a conversion (``28.000000000000004`` is written ``28.0``).
FILE_DIGITS = 13

#: The unit system of messages, tables and plots of the running command (see
#: :func:`display_units`).
_DISPLAY = contextvars.ContextVar("shockplan_display_units", default="SI")


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


def unit_label(quantity, units=None, *, small=False):
    """The display label of a `quantity` in `units` (default: :func:`get_display_units`).

    Parameters
    ----------
    quantity : str
        A key of :data:`TO_SI`.
    units : {"SI", "imperial"}, optional
    small : bool
        SI displacements and velocities in mm and mm/s (:data:`SMALL_SI_LABELS`).

    Examples
    --------
    >>> unit_label("damping", "imperial"), unit_label("displacement", "SI", small=True)
    ('lbf/(in/s)', 'mm')
    """
    units = get_display_units() if units is None else check_units(units)
    _factor(quantity)
    if small and units == "SI" and quantity in SMALL_SI_LABELS:
        return SMALL_SI_LABELS[quantity][0]
    return UNIT_LABELS[units][quantity]


def get_display_units():
    """The unit system the running command displays in: ``"SI"`` unless set by
    :func:`display_units` or :func:`set_display_units` (the command line sets it to the
    project's: the drive's, the session's, the library's or ``--units``)."""
    return _DISPLAY.get()


def set_display_units(units):
    """Set the unit system of messages, tables and plots for the rest of the current
    context (a command); returns the :class:`contextvars.Token` that undoes it.

    Raises
    ------
    ValueError
        If `units` is not a unit system.
    """
    return _DISPLAY.set(check_units(units, where="display units"))


@contextlib.contextmanager
def display_units(units):
    """Display in `units` within a ``with`` block (as :func:`numpy.printoptions` does for
    numbers): every message, table header and plot axis that a library function writes
    through :func:`format_quantity` / :func:`unit_label` without a stated unit system.

    Examples
    --------
    >>> with display_units("imperial"):
    ...     format_quantity(0.0255, "displacement", small=True)
    '1 in'
    >>> format_quantity(0.0255, "displacement", small=True)
    '25.5 mm'
    """
    token = set_display_units(units)
    try:
        yield
    finally:
        _DISPLAY.reset(token)


def format_quantity(value_si, quantity, units=None, *, digits=3, small=False, sign=False):
    """An SI value as the user reads it: converted to `units`, rounded to `digits`
    significant digits, and labelled (``"1.97 in/s"``).

    Parameters
    ----------
    value_si : float
        The value in SI units.
    quantity : str
        A key of :data:`TO_SI`.
    units : {"SI", "imperial"}, optional
        Default :func:`get_display_units`: the running command's unit system.
    digits : int
        Significant digits (``%g``).
    small : bool
        SI displacements and velocities in mm and mm/s (a travel of 25.5 mm, not 0.0255 m).
    sign : bool
        Always show the sign (a change: ``+2 mm``).

    Examples
    --------
    >>> format_quantity(3502.5, "damping", "imperial"), format_quantity(3502.5, "damping", "SI")
    ('20 lbf/(in/s)', '3500 N/(m/s)')
    >>> format_quantity(3502.5, "damping", "SI", digits=4)
    '3502 N/(m/s)'
    """
    units = get_display_units() if units is None else check_units(units)
    value = float(from_si(float(value_si), quantity, units))
    if small and units == "SI" and quantity in SMALL_SI_LABELS:
        value *= SMALL_SI_LABELS[quantity][1]
    return f"{format_significant(value, digits, sign=sign)} {unit_label(quantity, units, small=small)}"


def format_significant(value, digits=3, *, sign=False):
    """`value` written with `digits` significant digits and no exponent between 1e-4 and
    1e15 (``3502.5`` -> ``"3500"``, ``0.0255`` -> ``"0.0255"``, ``28.0`` -> ``"28"``).

    Examples
    --------
    >>> format_significant(3502.5), format_significant(1.969, 3), format_significant(-0.5, sign=True)
    ('3500', '1.97', '-0.5')
    """
    x = float(value)
    plus = "+" if sign else ""
    if not np.isfinite(x) or x == 0.0 or not 1e-4 <= abs(x) < 1e15:
        return f"{x:{plus}.{int(digits)}g}"
    r = round_significant(x, digits)
    mag = int(np.floor(np.log10(abs(r))))
    text = f"{r:{plus}.{max(0, int(digits) - 1 - mag)}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text


def round_significant(value, digits=FILE_DIGITS):
    """`value` rounded to `digits` significant digits (a float, or an array of them):
    a converted number as a file should hold it (``28.000000000000004`` -> ``28.0``).

    Examples
    --------
    >>> round_significant(28.000000000000004), round_significant(-19.66704724409449, 4)
    (28.0, -19.67)
    """
    if np.ndim(value):
        x = np.asarray(value, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            mag = np.where(np.isfinite(x) & (x != 0), np.floor(np.log10(np.abs(x))), 0.0)
        scale = 10.0 ** (digits - 1 - mag)
        return np.where(np.isfinite(x) & (x != 0), np.round(x * scale) / scale, x)
    x = float(value)
    return float(f"{x:.{int(digits)}g}") if np.isfinite(x) else x
