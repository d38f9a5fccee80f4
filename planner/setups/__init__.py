"""Shock setups: one shock id per corner, read, written, enumerated; the baseline.

A setup names one shock of the team's shock library (``ident.models.library``) for
each corner ``LF RF LR RR`` (:data:`ident.data.channels.CORNERS`). The planner
predicts metrics for many setups and ranks them (:mod:`planner.objective`).

File format (``setups.csv``, the rig-session spec's "Setups")::

    setup,LF,RF,LR,RR
    soft-front,D8,D8,B20,B20
    baseline,B20,B20,B20,B20

One row per setup, order kept. :func:`read_setups` needs the columns
``setup`` and the four corners (any column order); **other columns are
allowed and ignored**, so a predictions CSV (``setup, LF, RF, LR, RR``, then
metrics) reads as a setups file. The exception is a column that looks like a
misspelt corner (two letters, such as ``LM`` or ``lf``): that is an error.
Cells are stripped of surrounding spaces; blank lines, and ``#`` comment lines before
the header (the earlier layout's unit marker ``# units: SI``), are skipped. The column
``units`` (``SI`` or ``imperial`` on every row, the last column of every CSV shockplan
writes) is the file's unit system, not a setup's.

Bump stops and packers (the spec's "The real car"; optional): columns ``bump_stop_XX``
(a bump-stop id, or ``none``) and ``packer_XX`` (a thickness in the file's unit system:
m, or in with a ``units`` column holding ``imperial``) give a setup's bump stops and packers at corner
``XX``. A setup without them, a corner without its column, or an empty cell keeps the
model's baseline run's (:func:`ident.models.bumpstops.resolve_corner_stops`)::

    setup,LF,RF,LR,RR,bump_stop_LF,bump_stop_RF,packer_LF,packer_RF
    soft-front-packed,D8,D8,B20,B20,BS-F,BS-F,0.003,0.003
    baseline,B20,B20,B20,B20,,,,

Generated names (:func:`enumerate_setups`) are compact by default:
``"B20/B20/D8/D8"``, the ids in corner order LF/RF/LR/RR; pass
``name_format="LF={LF} RF={RF} LR={LR} RR={RR}"`` for the spelled-out form.

The enumeration is one implementation: :func:`setup_space` holds the setups of
an enumeration as integer codes (a :class:`SetupSpace`, decoded chunk by chunk);
:func:`enumerate_setups` decodes all of it, :mod:`planner.sweep` a chunk at a
time, in the same order and with the same names.

Every command reads its baseline with :func:`resolve_baseline`: a
:class:`Setup`, a listed setup's name, one shock id (every corner) or four ids
``"LF,RF,LR,RR"`` separated by commas.

Examples
--------
>>> from ident.models.library import ShockLibrary
>>> from ident.models.shocks import LinearShock
>>> lib = ShockLibrary.from_models([LinearShock("B20", 3502.5),
...                                 LinearShock("D8", 1400.0, count=2)])
>>> [s.name for s in enumerate_setups(lib)]   # D8 x4 skipped: the team has 2
['B20/B20/B20/B20', 'B20/B20/D8/D8', 'D8/D8/B20/B20']
>>> len(enumerate_setups(lib, symmetry="none"))   # D8 at 3 or 4 corners: only 2 exist
11
>>> base = Setup("baseline", {"LF": "B20", "RF": "B20", "LR": "B20", "RR": "B20"})
>>> [s.name for s in setups_from_baseline(base, lib, corners=("LF", "rear"))]
['baseline', 'baseline LF=D8', 'baseline rear=D8']
"""

from planner.setups.baseline import resolve_baseline
from planner.setups.csv_io import read_ranking_baseline, read_setups, setups_to_frame, write_setups
from planner.setups.enumeration import (
    AXLE_MODES,
    AXLES,
    DEFAULT_MAX_SETUPS,
    DEFAULT_NAME_FORMAT,
    SYMMETRIES,
    SetupSpace,
    enumerate_setups,
    inventory_shortfall,
    setup_space,
    setups_from_baseline,
)
from planner.setups.setup import Setup, unknown_id_error

__all__ = [
    "SYMMETRIES",
    "AXLE_MODES",
    "AXLES",
    "DEFAULT_MAX_SETUPS",
    "DEFAULT_NAME_FORMAT",
    "Setup",
    "SetupSpace",
    "setup_space",
    "read_setups",
    "read_ranking_baseline",
    "write_setups",
    "setups_to_frame",
    "enumerate_setups",
    "setups_from_baseline",
    "inventory_shortfall",
    "unknown_id_error",
    "resolve_baseline",
]
