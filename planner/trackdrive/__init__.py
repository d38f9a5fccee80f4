"""Drives from track data (issue 27): the rig drive that reproduces what the car logged.

The data flow is that of rig software's drive iteration, on the identified model:

- :mod:`planner.trackdrive.target`: track logs and the aero loads to a :class:`DriveTarget`;
- :mod:`planner.trackdrive.inverse`: the closed loop with the track setup's shocks
  linearized, and its regularized inverse;
- :mod:`planner.trackdrive.build`: :func:`build_track_drive` (the plain inverse, then
  time-domain iteration through the nonlinear shocks) and :func:`update_drive` (one rig
  iteration from a recorded run);
- :mod:`planner.trackdrive.sections`: laps and named windows as drives of their own.

The files (residual tables, PSD overlays) are written by :mod:`planner.report.trackdrive`.
"""

from planner.trackdrive.build import (DEFAULT_MAX_ITER, DEFAULT_TOL, LIMIT_ACTIONS,
                                      REPORT_BAND_HZ, RIG_GAIN, TrackDrive, build_track_drive,
                                      residual_shares, update_drive)
from planner.trackdrive.inverse import (DEFAULT_ALPHA, close_loop, loop_frf, open_loop_parts,
                                        reach_shares, regularized_inverse, shock_linearization)
from planner.trackdrive.sections import (check_sections, cut_sections, lap_sections,
                                         parse_sections)
from planner.trackdrive.target import (AERO_SOURCES, DEFAULT_BAND_HZ, MIN_RATE_FACTOR,
                                       TARGET_KINDS, DriveTarget, make_target)

__all__ = [
    "DriveTarget",
    "make_target",
    "TrackDrive",
    "build_track_drive",
    "update_drive",
    "residual_shares",
    "loop_frf",
    "open_loop_parts",
    "close_loop",
    "shock_linearization",
    "regularized_inverse",
    "reach_shares",
    "parse_sections",
    "lap_sections",
    "check_sections",
    "cut_sections",
    "TARGET_KINDS",
    "AERO_SOURCES",
    "DEFAULT_BAND_HZ",
    "MIN_RATE_FACTOR",
    "DEFAULT_ALPHA",
    "DEFAULT_MAX_ITER",
    "DEFAULT_TOL",
    "LIMIT_ACTIONS",
    "REPORT_BAND_HZ",
    "RIG_GAIN",
]
