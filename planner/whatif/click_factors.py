"""Click tolerance and adjuster fade: what-if changes of adjustable shocks.

Two factor kinds act on the adjustable shocks of the setups (setting names such as
``"TTX@ls=6,hs=2"``, :mod:`ident.models.adjustable`); fixed shocks are untouched.

``click``
    The mechanic is some clicks off: each adjustable shock's named adjusters (all of
    them by default) move by a whole number of steps (the adjuster's ``step``, 1 when
    the shock declares none; +1 raises the setting, which is softer on a shock whose
    stiffer end is ``"lower"``), clipped at the ends of the range
    (:func:`clicked_settings`; the what-if table says where in its ``clipped`` column).
``fade``
    A damper warming up loses force: the curve times ``1 - fade`` (``part = "all"``) or,
    the oil's viscosity falling, mostly at low speed: ``1 - fade * w(|v|)`` with
    :func:`fade_weight` falling from 1 at rest to :data:`FADE_HIGH_SPEED_SHARE` above
    :data:`FADE_KNEE_M_S` (``part = "low-speed"``; :func:`faded_shock`).

:func:`tolerance_table` sums a click or fade factor up per setup: the nominal, lowest,
highest and worst value and the spread of the score, the rank and every metric over
the nominal condition and the factor's own conditions (for levels ``[-1, 0, 1]``: the
"+-1 click" tolerance).
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pandas as pd

from ident.data.channels import CORNERS
from ident.models.adjustable import parse_shock_name
from ident.models.shocks import TableShock, format_number
from planner.errors import PlannerError

__all__ = [
    "ADJUSTER_KINDS",
    "FADE_HIGH_SPEED_SHARE",
    "FADE_KNEE_M_S",
    "fade_weight",
    "faded_shock",
    "clicked_settings",
    "click_steps",
    "fade_amounts",
    "click_note",
    "parse_setting",
    "check_adjuster_factors",
    "tolerance_table",
]

log = logging.getLogger("planner.whatif")

#: The factor kinds that act on adjustable shocks only.
ADJUSTER_KINDS = ("click", "fade")
#: Share of a low-speed fade left at high speed. Below the knee the force is the bleed's
#: laminar flow, proportional to the oil's viscosity, which falls by half over a typical
#: warm-up; above it the shim stack carries the flow, its force set by steel preload and
#: turbulent orifice losses (density, not viscosity), so only the bleed's parallel share
#: and the laminar part of the shim gaps fade: about a third. An assumption: dyno sheets
#: of one setting at two temperatures (the sheets' ``temperature`` column) measure it.
FADE_HIGH_SPEED_SHARE = 0.3
#: Shock speed [m/s] of the low- to high-speed change of the fade weight: 3 in/s, the
#: usual split of race-damper dyno sheets (the bleed's knee lies at 0.05-0.1 m/s).
FADE_KNEE_M_S = 0.075
#: Extra knots of a low-speed faded curve, in units of FADE_KNEE_M_S: the weight's bend.
_FADE_KNOTS = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0)


def fade_weight(speed_m_s):
    """Share of a low-speed fade acting at a shock speed.

    Parameters
    ----------
    speed_m_s : float or array_like, any shape
        Shock speed ``|v|`` [m/s].

    Returns
    -------
    float or ndarray, same shape
        ``S + (1 - S) / (1 + (|v| / FADE_KNEE_M_S)^2)`` with ``S`` =
        :data:`FADE_HIGH_SPEED_SHARE`: 1 at rest, falling smoothly to ``S``.
    """
    u = np.abs(np.asarray(speed_m_s, dtype=float)) / FADE_KNEE_M_S
    s = FADE_HIGH_SPEED_SHARE
    out = s + (1.0 - s) / (1.0 + u * u)
    return float(out) if out.ndim == 0 else out


def faded_shock(shock, fade_all=0.0, fade_low=0.0, *, id=None):
    """A shock that has lost force warming up.

    Parameters
    ----------
    shock : ident.models.shocks.ShockModel
        The cold (dyno) curve.
    fade_all : float
        Fractional force loss over the whole curve, ``0 <= fade_all < 1``.
    fade_low : float
        Fractional force loss at low speed, weighted by :func:`fade_weight`.
    id : str, optional
        The faded shock's id; default the shock's.

    Returns
    -------
    ShockModel
        Without `fade_low`: ``shock.scaled(1 - fade_all)`` (exact). With it: a
        :class:`~ident.models.shocks.TableShock` through the shock's knots and knots
        around :data:`FADE_KNEE_M_S`, forces times ``1 - fade_all - fade_low w(|v|)``
        (the product is exact at the knots, linear between them); lag and count kept.

    Raises
    ------
    PlannerError
        If the fades are negative or leave no force (their sum at rest >= 1).
    """
    fade_all, fade_low = float(fade_all), float(fade_low)
    if fade_all < 0 or fade_low < 0 or fade_all + fade_low >= 1:
        raise PlannerError(f"shock {shock.id!r}: a fade of {fade_all + fade_low:g} is not a "
                           "force loss in [0, 1); give fades such as 0.05 or 0.1 (5 %, 10 %)")
    new_id = shock.id if id is None else id
    if fade_low == 0.0:
        return shock.scaled(1.0 - fade_all, id=new_id)
    knots = shock.to_pwl().v_knots_m_s
    extra = FADE_KNEE_M_S * np.asarray(_FADE_KNOTS)
    v = np.unique(np.concatenate([knots, [0.0], extra, -extra]))
    f = shock.force(v) * (1.0 - fade_all - fade_low * fade_weight(v))
    return TableShock(new_id, v, f, lag_s=shock.lag_s, count=shock.count,
                      description=shock.description)


def clicked_settings(entry, settings, steps):
    """A setting moved by some steps of its adjusters, clipped at the range ends.

    Parameters
    ----------
    entry : ident.models.adjustable.AdjustableShock
    settings : dict of str to float
        A full setting (:meth:`AdjustableShock.resolve`).
    steps : dict of str to float
        Steps per adjuster (whole numbers; adjusters left out do not move).

    Returns
    -------
    moved : dict of str to float
        The new setting, in the adjusters' order.
    clipped : list of str
        One text per adjuster that hit a range end, ``"ls 0 -1 click -> 0"``.
    """
    moved, clipped = {}, []
    for k in entry.names:
        x = settings[k]
        n = steps.get(k, 0.0)
        if n:
            lo, hi = entry.adjusters[k]
            want = x + n * entry.step.get(k, 1.0)
            got = min(max(want, lo), hi)
            if abs(got - want) > 1e-9:
                clipped.append(f"{k} {format_number(x)} {n:+g} click -> "
                               f"{format_number(got)}")
            x = got
        moved[k] = x
    return moved, clipped


def click_steps(e, corner, match):
    """Steps per adjuster (``"*"``: all) of a :class:`ConditionEffect` at one corner.

    `match(shock_target)` says whether an ``"id:<name>"`` target names the corner's shock.
    """
    out = {}
    for target, adjusters, v in e.click:
        if not _hits(target, corner, match):
            continue
        for a in adjusters or ("*",):
            out[a] = out.get(a, 0.0) + v
    return out


def fade_amounts(e, corner, match):
    """``(fade_all, fade_low)`` of a :class:`ConditionEffect` at one corner (as
    :func:`click_steps`)."""
    fa = fl = 0.0
    for target, part, v in e.fade:
        if _hits(target, corner, match):
            if part == "low-speed":
                fl += v
            else:
                fa += v
    return fa, fl


def _hits(target, corner, match):
    if isinstance(target, str) and target.startswith("id:"):
        return match(target[3:])
    return target == corner


def check_adjuster_factors(factors, setups, library, where):
    """Check click and fade factors against the setups' shocks before any work.

    Parameters
    ----------
    factors : sequence of planner.whatif.spec.Factor
    setups : sequence of planner.setups.Setup
    library : ident.models.library.ShockLibrary
    where : str
        The perturbation file, first in messages.

    Returns
    -------
    list of str
        Notes (a click or fade factor that changes no setup).

    Raises
    ------
    PlannerError
        A ``shocks`` target that is a fixed shock or not in the library, or an
        ``adjusters`` name no adjustable shock of the setups has.
    """
    notes = []
    used = {}
    for s in setups:
        for sid in s.ids():
            base = library.base_id(sid)
            if base in library.adjustable_ids:
                used[base] = library.adjustable(base)
    for f in factors:
        if f.kind not in ADJUSTER_KINDS:
            continue
        who = f"{where}: factor {f.name!r}"
        for t in f.targets:
            if isinstance(t, str) and t.startswith("id:"):
                name = t[3:]
                base = library.base_id(name)
                if base not in library:
                    raise PlannerError(f"{who}: key 'shocks' names {name!r}, which is not in "
                                       f"the shock library; its adjustable shocks are "
                                       f"{list(library.adjustable_ids)}")
                if base not in library.adjustable_ids:
                    raise PlannerError(f"{who}: key 'shocks' names {name!r}, a fixed shock: a "
                                       f"{f.kind} factor changes adjustable shocks only (use "
                                       f"shock_scale for a fixed one); adjustable shocks are "
                                       f"{list(library.adjustable_ids)}")
        if not used:
            notes.append(f"factor {f.name!r} ({f.kind}) changes no setup: none uses an "
                         "adjustable shock")
            log.warning("%s: %s", where, notes[-1])
            continue
        have = sorted({a for e in used.values() for a in e.names})
        for a in getattr(f, "adjusters", ()):
            if a not in have:
                raise PlannerError(f"{who}: key 'adjusters' names {a!r}, which no adjustable "
                                   f"shock of the setups has; they have {have}")
    return notes


def click_note(corner, base, clipped):
    """The ``clipped`` cell text of one corner: ``"LF TTX ls 0 -1 click -> 0, ..."``."""
    return f"{corner} {base} " + ", ".join(clipped) if clipped else ""


def tolerance_table(table, perturbations, drive):
    """Per setup and click or fade factor: the spread of the score, rank and metrics.

    Parameters
    ----------
    table : pandas.DataFrame
        The what-if table (:attr:`planner.whatif.WhatIf.table`).
    perturbations : planner.whatif.spec.PerturbationSet
    drive : str
        The drive the tolerance is taken on (the first, nominal one).

    Returns
    -------
    pandas.DataFrame
        One row per (setup, factor, quantity), ``quantity`` being ``score``, ``rank``
        or a metric: ``n_conditions`` (the nominal condition and those where the factor
        moves), ``nominal``, ``low``, ``high``, ``spread`` (``high - low``),
        ``spread_pct`` (of ``|nominal|``) and ``worst``: the highest score or rank
        (lower is better), for a metric the value farthest from the nominal. Empty
        without click or fade factors.
    """
    cols = ["setup", "factor", "quantity", "n_conditions", "nominal", "low", "high",
            "spread", "spread_pct", "worst"]
    facs = [f for f in perturbations.factors if f.kind in ADJUSTER_KINDS]
    if not facs:
        return pd.DataFrame(columns=cols)
    t = table[table["drive"] == drive]
    skip = {"drive", "perturbation", "setup", "feasible", "violations", "score_change",
            "rank_change", "clipped"} | set(CORNERS)
    quantities = ["score", "rank"] + [
        c for c in t.columns if c not in skip and not c.startswith("score_")
        and not c.endswith("_change_pct") and pd.api.types.is_numeric_dtype(t[c])
        and c not in ("score", "rank")]
    rows = []
    for f in facs:
        names = {"nominal"} | {p.name for p in perturbations.perturbations
                               if any(v != f.nominal for v in p.values.get(f.name, ()))}
        sub = t[t["perturbation"].isin(names)]
        for setup, g in sub.groupby("setup", sort=False):
            nom = g[g["perturbation"] == "nominal"]
            for q in quantities:
                x = g[q].to_numpy(dtype=float)
                x0 = float(nom[q].iloc[0]) if len(nom) else math.nan
                lo, hi = float(np.nanmin(x)), float(np.nanmax(x))
                if q in ("score", "rank"):
                    worst = hi
                else:
                    worst = float(x[np.nanargmax(np.abs(x - x0))])
                spread = hi - lo
                rows.append((setup, f.name, q, len(g), x0, lo, hi, spread,
                             100.0 * spread / abs(x0) if x0 else math.nan, worst))
    return pd.DataFrame(rows, columns=cols)


def parse_setting(library, sid):
    """``(base, full setting or None, canonical name or None)`` of a setup's shock name."""
    base = library.base_id(sid)
    if base not in library.adjustable_ids:
        return base, None, None
    entry = library.adjustable(base)
    settings = entry.resolve(parse_shock_name(sid)[1] if "@" in sid else None)
    return base, settings, entry.name(settings)
