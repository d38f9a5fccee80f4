"""The third elements' forces at the corners (heave and roll elements per axle).

The spec's optional section "Third elements": an element ``e`` of a car (a heave damper, a
heave spring, a roll damper) acts at the corners as ``m_e F_e`` with ``m_e`` its row over
the corners (:func:`ident.data.third.element_row`). Identification takes the corner-
equivalent force ``sum_e m_e F_e`` into the corners' force inputs, beside the shocks' and
the bump stops' (:mod:`ident.identify.frf`), so that the identified linear car is the car
without the elements; the diagnosis takes it out of the wheels' force balance
(:mod:`ident.identify.diagnose`).
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import signal

from ident.data.channels import CORNERS
from ident.data.drive import decimate_bandlimited
from ident.data.third import HEAVE_ELEMENTS, element_axle
from ident.errors import IdentificationError
from ident.models.lti import lag_hold_coefficients
from ident.sim.closedloop import refine_input

__all__ = ["third_element_force", "element_channel", "describe_third", "DAMPER_REFINE"]

log = logging.getLogger(__name__)


def element_channel(element, what):
    """``heave_front``, ``velocity`` -> ``heave_velocity_front``."""
    kind, axle = element.split("_")
    return f"{kind}_{what}_{axle}"


#: Steps per sample on which a third damper's force is computed from its curve: the curve
#: of the sampled velocity would fold the force's harmonics above the Nyquist frequency into
#: the band (a rig's load cell passes its acquisition filter first). Prototype-like car, 2 %
#: noise, heave damper H1 (3 ms lag): the force computed against the load cell, in 0.5-20
#: Hz, 5.3 % of its RMS on the samples themselves, 2.5 % at 2x, 2.3 % at 4x and 8x (the
#: channels' noise).
DAMPER_REFINE = 4


def _damper_force(model, v, fs_hz):
    """A damper's force at velocity `v` behind its lag, as a load cell samples it: the
    velocity interpolated band-limited :data:`DAMPER_REFINE` x, the curve and the lag (the
    virtual rig's discretization) taken there, decimated back through the band-limited
    filter."""
    r = DAMPER_REFINE
    fine = refine_input(np.asarray(v, dtype=float)[:, None], r)[:, 0]
    pwl = model.to_pwl() if hasattr(model, "to_pwl") else model
    fv = np.asarray(pwl.force(fine), dtype=float)
    if model.lag_s > 0:
        alpha, b0, b1, bm = (float(x) for x in lag_hold_coefficients(model.lag_s,
                                                                     1.0 / (r * fs_hz)))
        fv = signal.lfilter([b0, b1, bm], [1.0, -alpha], fv)
    return decimate_bandlimited([fv], r, v.size)[0]


def third_element_force(run, elements, shocks, bump_stops=None, *, levels, where=None):
    """The third elements' force of one run at the corners (the spec's "Third elements").

    Each element ``e`` fitted on the run (its damper, and for a heave element its heave
    spring) pushes with ``F_e``, which acts at the corners as ``m_e F_e``
    (:func:`ident.data.third.element_row`): the corner-equivalent force ``sum_e m_e F_e``
    is part of the corners' force inputs (:func:`ident.identify.frf.estimate_frf`), as the bump stops' is, so
    that the identified linear car is the car without the elements.

    A damper's ``F_e`` is its load cell (``heave_force_front``, ``roll_force_rear``, ...)
    where the run records it, else its library curve with its lag (on a refined grid,
    :data:`DAMPER_REFINE`) at the element's velocity: its channel (``heave_velocity_front``), else ``m_e @ v`` of the corners' ``shock_velocity_XX``. A
    heave spring's is ``heave_spring_force_<axle>`` where recorded, else its bump-stop
    table (:meth:`ident.models.bumpstops.BumpStop.force`: beyond the gap less the packer)
    at the element's travel from rest (``heave_travel_<axle>``, else ``m_e @ x`` of the
    corners' ``shock_travel_XX``; the rest as
    :func:`ident.identify.frf.bump_stop_force` takes it). A damper
    not fitted on the run exerts nothing (its load cell's noise is not read).

    Parameters
    ----------
    run : ident.data.session.Run
    elements : ident.data.third.ThirdElements
        The session's declared elements.
    shocks : ident.models.library.ShockLibrary
        The shock library (the dampers are entries of it).
    bump_stops : ident.models.bumpstops.BumpStopLibrary, optional
        The bump-stop library (the heave springs are entries of it).
    levels : mapping of str to float
        Every channel's rest level (:func:`ident.identify.diagnose.rest_levels`): the
        heave springs' travel is measured from it.
    where : str, optional
        The run's file, put in messages (default the run's ``file``).

    Returns
    -------
    force : ndarray, shape (4, n_samples), or None
        ``sum_e m_e F_e`` at LF, RF, LR, RR [N] (not mean-removed); None when the run fits
        no element.
    info : dict or None
        Per element (``heave_front``, ``heave_spring_front``, ...) how its force was had:
        ``"measured"`` or ``"curve"``; None with `force`.

    Raises
    ------
    IdentificationError
        If a heave spring's travel can be had neither from ``heave_travel_<axle>`` (or its
        force from ``heave_spring_force_<axle>``) nor from the corners' ``shock_travel_XX``.
    """
    third = run.third
    if not elements or not third:
        return None, None
    where = run.file if where is None else where
    ch = run.channels
    G = np.zeros((4, run.n_samples))
    info = {}
    for e in elements.elements:
        row = elements.row(e)
        sid = third.dampers.get(e)
        if sid is not None:
            name = element_channel(e, "force")
            if name in ch:
                F, info[e] = np.asarray(ch[name], dtype=float), "measured"
            else:
                vname = element_channel(e, "velocity")
                v = (np.asarray(ch[vname], dtype=float) if vname in ch else
                     row @ np.vstack([ch[f"shock_velocity_{c}"] for c in CORNERS]))
                model = shocks.get(sid, where=f"run '{run.name}' third {e}")
                F, info[e] = _damper_force(model, v - np.mean(v), run.fs_hz), "curve"
            G += row[:, None] * F[None, :]
        if e not in HEAVE_ELEMENTS:
            continue
        axle = element_axle(e)
        sid = third.heave_springs.get(axle)
        if sid is None:
            continue
        key = f"heave_spring_{axle}"
        name = f"heave_spring_force_{axle}"
        if name in ch:
            F, info[key] = np.asarray(ch[name], dtype=float), "measured"
        else:
            tname = f"heave_travel_{axle}"
            corners = [f"shock_travel_{c}" for c, m in zip(CORNERS, row) if m != 0]
            if tname in ch:
                x = np.asarray(ch[tname], dtype=float) - levels[tname]
            elif all(c in ch for c in corners):
                x = sum(m * (ch[f"shock_travel_{c}"] - levels[f"shock_travel_{c}"])
                        for c, m in zip(CORNERS, row) if m != 0)
            else:
                raise IdentificationError(
                    f"run '{run.name}' ({where}): heave_springs {axle} = {sid!r} but the run "
                    f"records neither {name} nor {tname} nor {' and '.join(corners)}; the "
                    "heave spring's force is computed from its travel: record one of them, "
                    f"or remove the run's heave_springs {axle}")
            if bump_stops is None:  # pragma: no cover - the session checks refuse it
                raise IdentificationError(f"run '{run.name}' ({where}): heave_springs {axle} "
                                          "without a bump-stop library")
            spring = bump_stops.get(sid, where=f"run '{run.name}' heave_springs {axle}")
            F = spring.force(x, float(third.heave_packers_m.get(axle, 0.0)))
            info[key] = "curve"
        G += row[:, None] * F[None, :]
    if not info:
        return None, None
    log.info("run %s: third elements' force in the corners' inputs (%s)", run.name,
             ", ".join(f"{k} {v}" for k, v in info.items()))
    return G, info


def describe_third(third):
    """One line for a model's summary: the third elements declared and the baseline's fit.

    Parameters
    ----------
    third : ident.data.third.CarThird

    Returns
    -------
    str

    Examples
    --------
    >>> from ident.data.third import CarThird, RunThird, ThirdElements
    >>> describe_third(CarThird(ThirdElements({"heave_front": 1.0, "roll_front": 0.8}),
    ...                         RunThird(dampers={"heave_front": "H1"},
    ...                                  heave_springs={"front": "HS-F"},
    ...                                  heave_packers_m={"front": 0.002})))
    'third elements heave_front (motion ratio 1), roll_front (motion ratio 0.8) declared; baseline: heave_front H1, roll_front none, heave spring front HS-F (packer 2 mm (0.07874 in))'
    """
    mr = third.elements.motion_ratios
    declared = ", ".join(f"{e} (motion ratio {m:.4g})" for e, m in mr.items())
    base = third.baseline
    fitted = [f"{e} {base.dampers.get(e) or 'none'}" for e in mr]
    for axle, sid in base.heave_springs.items():
        if sid is None:
            continue
        packer = float(base.heave_packers_m.get(axle, 0.0))
        fitted.append(f"heave spring {axle} {sid}"
                      + (f" (packer {packer * 1e3:.4g} mm ({packer / 0.0254:.4g} in))"
                         if packer else ""))
    return f"third elements {declared} declared; baseline: {', '.join(fitted)}"
