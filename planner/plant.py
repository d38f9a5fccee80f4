"""Any model to the plant a closed loop or a screening runs against.

:func:`as_loop_plant` takes each of the model types the planner accepts and returns its
plant: an identified :class:`ident.identify.model.VehicleModel` (its reduced loop plant),
the known :class:`ident.models.vehicle.FullCarModel` or its
:class:`ident.models.vehicle.VehicleParams` (built), a
:class:`ident.models.lti.LoopPlant` (as is) and a :class:`FrfPlant` (a plant given by a
frequency response on a grid, for the frequency-domain screening only: as is).
"""

from __future__ import annotations

import numpy as np

from ident.data.channels import SHOCK_VELOCITIES
from ident.identify.model import LOOP_REDUCE_RTOL, VehicleModel
from ident.models.lti import LoopPlant
from ident.models.vehicle import FullCarModel, VehicleParams, build_full_car

__all__ = [
    "MODEL_TYPES",
    "FrfPlant",
    "as_loop_plant",
    "interpolate",
]


class FrfPlant:
    """A plant given by a frequency response on a grid (for frequency-domain screening).

    Parameters
    ----------
    f_hz : ndarray, shape (n_f,)
    H : ndarray of complex, shape (n_out, 11, n_f)
        Inputs rig (7) then dF (4).
    output_names : sequence of str
    cbar_n_s_m : ndarray, shape (4,)
    name : str
    """

    def __init__(self, f_hz, H, output_names, cbar_n_s_m, name="frf"):
        self.f_hz = np.asarray(f_hz, dtype=float)
        self.H = H
        self.output_names = tuple(output_names)
        self.cbar_n_s_m = np.asarray(cbar_n_s_m, dtype=float)
        self.name = name
        self.velocity_idx = np.array([self.output_names.index(v) for v in SHOCK_VELOCITIES])

    def frequency_response(self, f_hz):
        """Linear interpolation of the real and imaginary parts, shape (n_out, 11, n_f)."""
        return interpolate(self.f_hz, self.H, f_hz)


def interpolate(f_grid, X, f_hz):
    """Linear interpolation of ``X[..., grid]`` at `f_hz` along the last axis.

    Real and imaginary parts (of a complex `X`) alike, each between its two
    neighbouring grid lines; outside the grid, the first or last segment is
    extended linearly.

    Parameters
    ----------
    f_grid : ndarray, shape (n_grid,)
        Increasing frequencies [Hz], at least two.
    X : ndarray, shape (..., n_grid)
        Values on the grid (real or complex).
    f_hz : array_like, shape (n,)
        Frequencies to interpolate at [Hz].

    Returns
    -------
    ndarray, shape (..., n)

    Examples
    --------
    >>> import numpy as np
    >>> interpolate(np.array([1.0, 2.0, 4.0]), np.array([0.0, 1.0, 3.0]), [1.5, 3.0, 5.0])
    array([0.5, 2. , 4. ])
    """
    f = np.asarray(f_hz, dtype=float)
    idx = np.clip(np.searchsorted(f_grid, f) - 1, 0, f_grid.size - 2)
    t = (f - f_grid[idx]) / (f_grid[idx + 1] - f_grid[idx])
    return X[..., idx] * (1 - t) + X[..., idx + 1] * t


#: The model types :func:`as_loop_plant` accepts.
MODEL_TYPES = (VehicleModel, FullCarModel, VehicleParams, LoopPlant, FrfPlant)


def as_loop_plant(model, *, reduce_rtol=LOOP_REDUCE_RTOL):
    """Return the plant of a vehicle model: a :class:`ident.models.lti.LoopPlant`, or a
    :class:`FrfPlant` as is.

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams, LoopPlant or FrfPlant
        :data:`MODEL_TYPES`. A :class:`FrfPlant` serves the frequency-domain screening
        only (:mod:`planner.screen`).
    reduce_rtol : float or None
        Balanced-truncation bound for an identified model's shock part
        (:meth:`ident.identify.model.VehicleModel.loop_plant`).

    Returns
    -------
    LoopPlant or FrfPlant

    Raises
    ------
    TypeError
        If `model` is none of :data:`MODEL_TYPES`.
    """
    if isinstance(model, (LoopPlant, FrfPlant)):
        return model
    if isinstance(model, VehicleModel):
        return model.loop_plant(reduce_rtol=reduce_rtol)
    if isinstance(model, VehicleParams):
        return build_full_car(model).loop_plant()
    if isinstance(model, FullCarModel):
        return model.loop_plant()
    raise TypeError(f"model must be one of {', '.join(t.__name__ for t in MODEL_TYPES)} "
                    f"(an identified model, the known car, its parameters or a plant), got "
                    f"{type(model).__name__}")
