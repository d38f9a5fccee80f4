"""Unit systems at the display and file boundary (``ident/data/units.py``; issue 36, item 5:
one unit system per project, numbers rounded to what they mean)."""

import math

import numpy as np
import pytest

from ident.data.units import (
    FILE_DIGITS,
    TO_SI,
    display_units,
    format_quantity,
    format_significant,
    from_si,
    get_display_units,
    round_significant,
    set_display_units,
    to_si,
    unit_label,
)

#: Relative error a number written to a file may carry (FILE_DIGITS significant digits):
#: half a unit in the last digit kept.
FILE_RTOL = 0.5 * 10.0 ** (1 - FILE_DIGITS)


def test_format_quantity_speaks_the_unit_system_asked():
    """An SI value in either system, labelled, with the digits asked."""
    assert format_quantity(3502.5367, "damping", "imperial") == "20 lbf/(in/s)"
    assert format_quantity(3502.5367, "damping", "SI", digits=4) == "3503 N/(m/s)"
    assert format_quantity(0.0255, "displacement", "SI", small=True) == "25.5 mm"
    assert format_quantity(0.0255, "displacement", "imperial", small=True) == "1 in"
    assert format_quantity(0.05, "velocity", "imperial") == "1.97 in/s"
    assert format_quantity(-0.001, "displacement", "SI", small=True, sign=True) == "-1 mm"
    assert format_quantity(0.002, "displacement", "SI", small=True, sign=True) == "+2 mm"


def test_display_units_set_what_library_messages_use_and_are_undone():
    """Without a stated system, the running command's (set by the command line): inside a
    ``with display_units`` block, and back to what it was after it (also after an error)."""
    assert get_display_units() == "SI"
    with display_units("Imperial"):
        assert get_display_units() == "imperial"
        assert format_quantity(4.4482216152605, "force") == "1 lbf"
        assert unit_label("velocity") == "in/s"
        token = set_display_units("SI")  # a command inside sets its own, as the CLI does
        assert unit_label("velocity", small=True) == "mm/s"
        assert token is not None
    assert get_display_units() == "SI"
    with pytest.raises(RuntimeError), display_units("imperial"):
        raise RuntimeError("an interrupted command")
    assert get_display_units() == "SI"
    with pytest.raises(ValueError, match="SI"):
        set_display_units("metric")


@pytest.mark.parametrize("value, digits, text", [
    (3502.5, 3, "3500"), (1.969, 3, "1.97"), (28.000000000000004, 3, "28"), (0.0255, 3, "0.0255"),
    (-19.66704724409449, 4, "-19.67"), (1e-7, 3, "1e-07"), (0.0, 3, "0"), (123456.0, 2, "120000"),
])
def test_format_significant(value, digits, text):
    assert format_significant(value, digits) == text


def test_round_significant_keeps_files_accurate_far_below_what_matters():
    """A converted value written to a file: conversion round-off gone (28.000000000000004 ->
    28.0), every value within FILE_RTOL of itself, arrays as scalars, 0 and inf kept."""
    assert round_significant(28.000000000000004) == 28.0
    assert round_significant(20.0 * TO_SI["damping"]) == pytest.approx(3502.53670493, abs=1e-8)
    rng = np.random.default_rng(36)
    x = rng.lognormal(0.0, 6.0, 200) * rng.choice([-1.0, 1.0], 200)
    y = round_significant(x)
    assert np.all(np.abs(y - x) <= FILE_RTOL * np.abs(x))
    assert [round_significant(float(v)) for v in x] == y.tolist()
    assert round_significant(np.array([0.0, np.inf, -1.0 / 3.0])).tolist()[:2] == [0.0, np.inf]
    assert math.isnan(round_significant(float("nan")))
    # an imperial value read, converted to SI and written back as imperial is the value
    for v in (28.0, 12.0, 0.1, 16.5, 2.0 / 3.0):
        back = from_si(to_si(v, "damping", "imperial"), "damping", "imperial")
        assert round_significant(back) == round_significant(v)
