"""Stiffness changes of a linear plant: springs and anti-roll bars as a feedback.

An elastic element between a wheel and the chassis acts across the shock of its corner:
a spring or anti-roll-bar change adds the force ``dK t`` (``t`` the shock travels,
compression positive) to the shock-force input. :func:`stiffened_plant` closes that
linear feedback from the plant's shock-travel outputs to its shock-force inputs and
returns the changed :class:`ident.models.lti.LoopPlant`, exact for any linear plant,
identified or known; :func:`suspension_stiffness` builds ``dK`` from per-corner spring
and per-axle bar rate changes. The what-if analysis (:mod:`planner.whatif`) changes an
identified car's springs and bars with it.
"""

from __future__ import annotations

import numpy as np

from ident.data.channels import CORNERS
from ident.errors import VehicleError
from ident.models.lti import LoopPlant, modal_form

__all__ = ["suspension_stiffness", "stiffened_plant"]

#: The corners (indices into LF, RF, LR, RR) an anti-roll bar of each axle connects.
_AXLE_CORNERS = {"front": (0, 1), "rear": (2, 3)}


def suspension_stiffness(spring_n_m=None, arb_n_m=None):
    """The stiffness matrix ``dK`` [N/m], shape (4, 4), of spring and anti-roll bar changes.

    Parameters
    ----------
    spring_n_m : array_like, shape (4,), optional
        Spring wheel-rate change per corner LF, RF, LR, RR [N/m].
    arb_n_m : array_like, shape (2,), optional
        Anti-roll bar rate change per axle (front, rear) [N/m]: ``k [[1, -1], [-1, 1]]``
        on the axle's corners.

    Examples
    --------
    >>> suspension_stiffness(arb_n_m=[1000.0, 0.0])[:2, :2].tolist()
    [[1000.0, -1000.0], [-1000.0, 1000.0]]
    """
    K = np.diag(np.zeros(4) if spring_n_m is None else np.asarray(spring_n_m, float))
    if arb_n_m is not None:
        for k, (l, r) in zip(np.asarray(arb_n_m, float), _AXLE_CORNERS.values()):
            K[np.ix_([l, r], [l, r])] += k * np.array([[1.0, -1.0], [-1.0, 1.0]])
    return K


def stiffened_plant(plant, *, spring_n_m=None, arb_n_m=None, name=None):
    """A loop plant with extra elastic elements between wheels and chassis (springs, bars).

    An elastic element across a shock's corner acts on the shock-force input: the applied
    force becomes ``F = f(v) + dK t`` with ``t`` the shock travels (compression positive),
    so the element closes a linear feedback from the plant's shock-travel outputs to its
    shock-force inputs. Exact for any linear plant, identified or known.

    Parameters
    ----------
    plant : ident.models.lti.LoopPlant
        Must have the outputs ``shock_travel_XX``.
    spring_n_m : array_like, shape (4,), optional
        Spring wheel-rate change per corner LF, RF, LR, RR [N/m].
    arb_n_m : array_like, shape (2,), optional
        Anti-roll bar rate change per axle (front, rear) [N/m]; see
        :func:`suspension_stiffness`. The force at corner i is ``sum_j dK[i, j] t_j``.

    Returns
    -------
    ident.models.lti.LoopPlant
        The rig part is the series connection of the rig part and the stiffened shock
        part (a spring transmits rig-driven travel as a force); the ``spring_force_XX``
        outputs (if any, the coil's force) include the spring changes, not the bars.

    Raises
    ------
    ValueError
        If `spring_n_m` or `arb_n_m` is not 4 (2) finite values.
    ident.errors.VehicleError
        If the plant has no shock-travel outputs, the stiffened loop is singular or
        cannot be put in modal form (repeated poles), or the change makes it unstable.
    """
    for what, v, n in (("spring_n_m", spring_n_m, 4), ("arb_n_m", arb_n_m, 2)):
        if v is not None and (np.shape(v) != (n,) or not np.all(np.isfinite(v))):
            raise ValueError(f"{what} must be {n} finite values [N/m], got {v!r}")
    K = suspension_stiffness(spring_n_m, arb_n_m)
    ks = np.zeros(4) if spring_n_m is None else np.asarray(spring_n_m, float)
    names = tuple(plant.output_names)
    missing = [f"shock_travel_{c}" for c in CORNERS if f"shock_travel_{c}" not in names]
    if missing:
        raise VehicleError(f"plant {plant.name!r}: no outputs {missing}; a spring or anti-roll "
                           "bar what-if acts through the shock travel, so identify a model with "
                           "the shock-travel channels")
    ti = [names.index(f"shock_travel_{c}") for c in CORNERS]
    As, Bs, Cs, Ds = plant.shock.to_real()
    Ar, Br, Cr, Dr = plant.rig.to_real()
    # the spring-force outputs carry the added springs (diagonal), before the feedback
    Cs, Ds, Cr, Dr = Cs.copy(), Ds.copy(), Cr.copy(), Dr.copy()
    for j, c in enumerate(CORNERS):
        if f"spring_force_{c}" in names:
            k = names.index(f"spring_force_{c}")
            Cs[k] += ks[j] * Cs[ti[j]]
            Ds[k] += ks[j] * Ds[ti[j]]
            Cr[k] += ks[j] * Cr[ti[j]]
            Dr[k] += ks[j] * Dr[ti[j]]
    Dt = Ds[ti]
    try:
        M = np.linalg.inv(np.eye(4) - K @ Dt)
    except np.linalg.LinAlgError:
        raise VehicleError("the stiffened loop is singular (travel feedthrough); check the "
                           "stiffness change") from None
    MK = M @ K
    As2, Bs2 = As + Bs @ MK @ Cs[ti], Bs @ M
    Cs2, Ds2 = Cs + Ds @ MK @ Cs[ti], Ds @ M
    nr, ns = Ar.shape[0], As.shape[0]
    A = np.block([[Ar, np.zeros((nr, ns))], [Bs @ MK @ Cr[ti], As2]])
    B = np.vstack([Br, Bs @ MK @ Dr[ti]])
    C = np.hstack([Cr + Ds @ MK @ Cr[ti], Cs2])
    D = Dr + Ds @ MK @ Dr[ti]
    try:
        rig = modal_form(A, B, C, D).pruned()
        shock = modal_form(As2, Bs2, Cs2, Ds2).pruned()
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise VehicleError(f"plant {plant.name!r}: the stiffened loop has no modal form ({exc}); "
                           "the change moves poles onto each other, try a slightly other "
                           "value") from None
    if np.any(shock.lam.real > 0) or np.any(rig.lam.real > 0):
        raise VehicleError(f"plant {plant.name!r}: the stiffness change {np.diag(K)} N/m makes "
                           "the car unstable (a negative net rate); check its sign and size")
    return LoopPlant(rig, shock, names, plant.cbar_n_s_m,
                     name=name or f"{plant.name} (stiffened)")
