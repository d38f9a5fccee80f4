"""Third elements of the closed loop: the setups' heave and roll dampers and heave springs
packed for the compiled loop (issue 38).

A third element acts through a row ``m`` over the corners (:func:`ident.data.third.element_row`):
its travel and velocity are ``m @ x`` and ``m @ v`` of the corners' shock travels and
velocities, its force ``F`` acts at the corners as ``m * F`` in parallel with the shocks.
A damper is a shock model (a piecewise-linear curve behind a first-order lag) in the
element's own motion and force; a heave spring a force-travel table from its contact travel
(gap less packer) on.

One setup's third elements are ``(dampers, springs)``: sequences of :class:`ThirdDamper` and
:class:`ThirdSpring` (the virtual rig's truth simulator,
:func:`ident.sim.third_loop.simulate_third`, takes the same). A damper whose ``model`` is
``None``, or a spring whose ``contact`` is ``None``, is declared but not fitted in that
setup (no force): the batch's elements are the union over its setups, by name.
:func:`pack_third` checks them and packs the setup fields of
:class:`ident.sim.loop_kernels.ThirdLoop`; :mod:`ident.sim.closedloop` adds the plant's part
(the travel rows) and runs the loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ident.data.third import THIRD_ELEMENTS
from ident.models.lti import lag_hold_coefficients

__all__ = [
    "ThirdDamper",
    "ThirdSpring",
    "ThirdPack",
    "pack_third",
    "third_channel",
    "UNREACHED_CONTACT_M",
]

#: Contact travel of a spring not fitted in a setup [m]: never reached (no force, no contact).
UNREACHED_CONTACT_M = 1e9


@dataclass(frozen=True)
class ThirdDamper:
    """A damper acting through a row over the corners.

    Attributes
    ----------
    name : str
        ``heave_front``, ``roll_rear``, ... (a channel's prefix).
    row : ndarray, shape (4,)
        :func:`ident.data.third.element_row`.
    model : shock model or None
        :mod:`ident.models.shocks` (``to_pwl``, ``lag_s``), in the element's own travel and
        force; ``None``: not fitted (no force).
    """

    name: str
    row: np.ndarray
    model: object


@dataclass(frozen=True)
class ThirdSpring:
    """A spring with a gap acting through a row over the corners (a heave spring).

    Attributes
    ----------
    name : str
        ``heave_front`` or ``heave_rear``.
    row : ndarray, shape (4,)
    contact : tuple or None
        ``(gap - packer [m], travel_table_m, force_table_n)`` as
        :func:`ident.models.bumpstops.contact_tables` gives a corner's; ``None``: not fitted.
    """

    name: str
    row: np.ndarray
    contact: object


def third_channel(element, what):
    """The channel of an element's motion or force: ``("heave_front", "travel")`` ->
    ``"heave_travel_front"``; ``what`` ``"spring_force"`` -> ``"heave_spring_force_front"``."""
    kind, axle = element.split("_")
    return f"{kind}_{what}_{axle}"


@dataclass(frozen=True, eq=False)
class ThirdPack:
    """A batch's third elements packed (:func:`pack_third`).

    Attributes
    ----------
    elements : tuple of str
        Every element named in the batch (dampers or springs), in
        :data:`ident.data.third.THIRD_ELEMENTS` order.
    rows : ndarray, shape (n_elements, 4)
        Their rows.
    dampers, springs : tuple of str
        The elements with a damper, with a spring (in any setup).
    damper_args : tuple
        ``drows (ne, 4), kv, kf (S, ne, K), nk (S, ne), slo, shi, alpha, b0, b1, bm (S, ne)``.
    spring_rows : ndarray, shape (n_springs, 4)
    spring_contacts : list
        One entry per setup: a list of checked ``(s0, x, f)`` or ``None`` per spring.
    """

    elements: tuple
    rows: np.ndarray
    dampers: tuple
    springs: tuple
    damper_args: tuple
    spring_rows: np.ndarray
    spring_contacts: list


def _row(entry, where):
    row = np.asarray(getattr(entry, "row", None), dtype=float)
    if row.shape != (4,) or not np.all(np.isfinite(row)):
        raise ValueError(f"{where}: an element's row must be 4 finite numbers over LF, RF, LR, "
                         "RR (ident.data.third.element_row)")
    return row


def pack_third(per_setup, h, *, where="third"):
    """Check and pack the setups' third elements.

    Parameters
    ----------
    per_setup : sequence
        One entry per setup: ``(dampers, springs)`` (sequences of :class:`ThirdDamper` and
        :class:`ThirdSpring`, or any objects with their attributes) or ``None`` (none).
    h : float
        Internal step [s] (the lags' discretization).
    where : str
        Names the argument in error messages.

    Returns
    -------
    ThirdPack

    Raises
    ------
    ValueError
        On an unknown element, rows that differ between setups for one element, an element
        twice in a setup, or a malformed damper model or spring table.
    """
    S = len(per_setup)
    damp = [dict() for _ in range(S)]
    spr = [dict() for _ in range(S)]
    rows = {}
    for i, entry in enumerate(per_setup):
        if entry is None:
            continue
        try:
            dampers, springs = entry
        except (TypeError, ValueError):
            raise TypeError(f"{where}: setup {i}: give (dampers, springs) or None, got "
                            f"{type(entry).__name__}") from None
        for kind, items, table in (("damper", dampers, damp[i]), ("spring", springs, spr[i])):
            for e in items or ():
                name = getattr(e, "name", None)
                if name not in THIRD_ELEMENTS or (kind == "spring"
                                                  and not name.startswith("heave")):
                    raise ValueError(f"{where}: setup {i}: unknown third {kind} {name!r}; one "
                                     f"of {list(THIRD_ELEMENTS) if kind == 'damper' else ['heave_front', 'heave_rear']}")
                if name in table:
                    raise ValueError(f"{where}: setup {i}: the {kind} {name!r} is given twice; "
                                     "give each element once")
                row = _row(e, f"{where}: setup {i} {name}")
                if name in rows and not np.array_equal(rows[name], row):
                    raise ValueError(f"{where}: setup {i}: element {name!r} has another row "
                                     f"than in an earlier setup; a car's motion ratios are "
                                     "the same in every setup")
                rows[name] = row
                table[name] = getattr(e, "model" if kind == "damper" else "contact")
    elements = tuple(e for e in THIRD_ELEMENTS if e in rows)
    dnames = tuple(e for e in elements if any(e in d for d in damp))
    snames = tuple(e for e in elements if any(e in s for s in spr))
    # the dampers' curves (a damper not fitted: a flat zero curve)
    pwls = []
    for i in range(S):
        row_p = []
        for e in dnames:
            model = damp[i].get(e)
            if model is None:
                row_p.append(None)
                continue
            try:
                pwl = model.to_pwl()
                lag = float(getattr(model, "lag_s", 0.0) or 0.0)
            except AttributeError:
                raise TypeError(f"{where}: setup {i} {e}: a damper is a shock model "
                                f"(ident.models.shocks), got {type(model).__name__}") from None
            row_p.append((pwl, lag))
        pwls.append(row_p)
    ne = len(dnames)
    K = max([2] + [p[0].v_knots_m_s.size for row_p in pwls for p in row_p if p is not None])
    kv = np.zeros((S, ne, K))
    kf = np.zeros((S, ne, K))
    nk = np.full((S, ne), 2, dtype=np.int64)
    slo = np.zeros((S, ne))
    shi = np.zeros((S, ne))
    lag = np.zeros((S, ne))
    kv[:, :, 0], kv[:, :, 1:] = -1.0, 1.0
    for i, row_p in enumerate(pwls):
        for d, p in enumerate(row_p):
            if p is None:
                continue
            pwl, lag[i, d] = p
            v, f = np.asarray(pwl.v_knots_m_s, dtype=float), np.asarray(pwl.f_knots_n, float)
            k = v.size
            kv[i, d, :k], kv[i, d, k:] = v, v[-1]
            kf[i, d, :k], kf[i, d, k:] = f, f[-1]
            nk[i, d], slo[i, d], shi[i, d] = k, pwl.slope_below, pwl.slope_above
    alpha, b0, b1, bm = (np.ascontiguousarray(a.reshape(S, ne), dtype=float) for a in
                         lag_hold_coefficients(lag.ravel(), h))
    drows = np.ascontiguousarray(np.array([rows[e] for e in dnames]).reshape(ne, 4))
    damper_args = (drows, kv, kf, nk, slo, shi, alpha, b0, b1, bm)
    contacts = [[spr[i].get(e) for e in snames] for i in range(S)]
    srows = np.ascontiguousarray(np.array([rows[e] for e in snames]).reshape(len(snames), 4))
    return ThirdPack(elements=elements, rows=np.array([rows[e] for e in elements]).reshape(-1, 4),
                     dampers=dnames, springs=snames, damper_args=damper_args,
                     spring_rows=srows, spring_contacts=contacts)
