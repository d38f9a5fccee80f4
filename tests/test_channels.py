"""ident.data.channels: the one check of a per-corner table (corner_table)."""

import numpy as np
import pytest

from ident.data.channels import CORNERS, corner_table
from ident.errors import SessionError
from planner.errors import PlannerError


def test_corner_table_orders_and_keeps_the_given_corners():
    assert corner_table(None, name="packers", where="w") == {}
    t = corner_table({"RR": 2.0, "LF": 1.0}, name="packers", where="w")
    assert list(t) == ["LF", "RR"] and t == {"LF": 1.0, "RR": 2.0}
    assert corner_table((1, 2, 3, 4), name="loads", where="w", sequence=True) == dict(
        zip(CORNERS, (1, 2, 3, 4)))


@pytest.mark.parametrize("error", [ValueError, SessionError, PlannerError])
def test_corner_table_raises_the_callers_class_with_one_message(error):
    with pytest.raises(error, match=r"^run 'a': packers names unknown corner\(s\) \['FL'\]; "
                                    r"the corners are LF, RF, LR, RR$"):
        corner_table({"FL": 1.0, "LF": 1.0}, name="packers", where="run 'a'", error=error)
    with pytest.raises(error, match=r"loads must be 4 numbers, one per corner"):
        corner_table([1.0, 2.0], name="loads", where="w", what="numbers", error=error,
                     sequence=True)


def test_corner_table_not_a_table():
    # an argument: TypeError naming a mapping; a file: the file's error naming a table
    with pytest.raises(TypeError, match=r"w: shocks must be a mapping corner -> shock id, got list"):
        corner_table(["A"] * 4, name="shocks", where="w", what="shock id")
    with pytest.raises(SessionError, match=r"w: packers must be a table \{ LF = \.\.\., RF = \.\.\. \} "
                                           r"of thicknesses, got 3\.0"):
        corner_table(3.0, name="packers", where="w", what="thicknesses", type_error=SessionError)
    with pytest.raises(TypeError):
        corner_table("LFRF", name="x", where="w", sequence=True)
    assert issubclass(SessionError, ValueError) and issubclass(PlannerError, ValueError)
    np.testing.assert_array_equal(list(corner_table(np.arange(4.0), name="x", where="w",
                                                    sequence=True).values()), np.arange(4.0))
