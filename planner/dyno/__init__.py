"""The shock dyno in the planner: a library shock's curve as a table, and an adjustable
shock's model checked against its dyno (``shockplan dyno table`` and ``shockplan dyno
check``).

Modules: :mod:`~planner.dyno.check` (the computations); the files are written by
:mod:`planner.report.dyno` (as every feature's, in :mod:`planner.report`). The public
names of :mod:`~planner.dyno.check` are re-exported here.
"""

from planner.dyno.check import (
    BUILDER_GRID,
    MODEL_LINE_POINTS,
    DynoCheck,
    DynoCurve,
    SettingCurve,
    ShockCheck,
    check_dyno_library,
    default_velocities,
    dyno_curve,
    library_units,
)

__all__ = [
    "BUILDER_GRID",
    "MODEL_LINE_POINTS",
    "DynoCurve",
    "SettingCurve",
    "ShockCheck",
    "DynoCheck",
    "library_units",
    "default_velocities",
    "dyno_curve",
    "check_dyno_library",
]
