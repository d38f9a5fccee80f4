"""A known adjustable damper: the truth behind synthetic dyno sheets and clicker tests.

:class:`ClickerDamper` is a race damper with a low-speed and a high-speed adjuster,
modelled on how bleed and shim-stack adjusters act (a digressive curve per side):

- the low-speed adjuster (``ls``, clicks from closed) opens a bleed: the low-speed
  slope falls about exponentially with the clicks and the knee moves up a little;
- the high-speed adjuster (``hs``, turns from closed) preloads the shim stack: the
  high-speed slope falls with the turns;
- rebound is stiffer than bump by a constant ratio.

Its curve at any setting is exact, so a click model fitted to its sheets can be judged
at settings the sheets leave out, and a car fitted with it has a known best setting.
Lower settings are stiffer for both adjusters (``stiffer = "lower"``).

Examples
--------
>>> d = ClickerDamper()
>>> round(float(d.force(0.1, {"ls": 8, "hs": 2})), 1) > 0
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ident.models.adjustable import AdjustableShock, DynoPoints
from ident.models.shocks import TableShock

__all__ = ["ClickerDamper", "gt_clicker", "clicker_shock"]


@dataclass(frozen=True)
class ClickerDamper:
    """A digressive damper with ``ls`` (clicks) and ``hs`` (turns) adjusters.

    Parameters
    ----------
    c_low_n_s_m : float
        Low-speed slope [N/(m/s)] at ``ls = 0`` (closed), bump, above its floor.
    c_low_floor_n_s_m : float
        Low-speed slope [N/(m/s)] that remains fully open.
    ls_rate : float
        Fall of the low-speed slope per click (1/click).
    c_high_n_s_m, c_high_floor_n_s_m, hs_rate : float
        The same for the high-speed slope and the ``hs`` turns.
    knee_m_s, knee_per_click_m_s : float
        Knee velocity [m/s] at ``ls = 0`` and its rise per click.
    rebound_ratio : float
        Rebound force over bump force at the same speed.
    ls_range, hs_range : (float, float)
        The adjusters' ranges.
    """

    c_low_n_s_m: float = 9000.0
    c_low_floor_n_s_m: float = 1500.0
    ls_rate: float = 0.09
    c_high_n_s_m: float = 2200.0
    c_high_floor_n_s_m: float = 500.0
    hs_rate: float = 0.25
    knee_m_s: float = 0.05
    knee_per_click_m_s: float = 0.002
    rebound_ratio: float = 1.6
    ls_range: tuple = (0.0, 20.0)
    hs_range: tuple = (0.0, 4.0)

    @property
    def adjusters(self):
        """dict: the ranges, as an adjustable shock declares them."""
        return {"ls": tuple(self.ls_range), "hs": tuple(self.hs_range)}

    def force(self, v_m_s, settings):
        """Force [N] at velocity `v_m_s` [m/s] (any shape) and a setting ``{ls, hs}``."""
        v = np.asarray(v_m_s, dtype=float)
        ls, hs = float(settings["ls"]), float(settings["hs"])
        c_low = self.c_low_n_s_m * np.exp(-self.ls_rate * ls) + self.c_low_floor_n_s_m
        c_high = self.c_high_n_s_m * np.exp(-self.hs_rate * hs) + self.c_high_floor_n_s_m
        knee = self.knee_m_s + self.knee_per_click_m_s * ls
        u = np.abs(v)
        f = np.where(u < knee, c_low * u, c_low * knee + c_high * (u - knee))
        return np.sign(v) * f * np.where(v > 0, 1.0, self.rebound_ratio)

    def shock_at(self, settings, *, id=None, velocities_m_s=None, lag_s=0.0):
        """The exact curve at a setting as a :class:`TableShock` (knots at the knee).

        Parameters
        ----------
        settings : dict
            ``{"ls": clicks, "hs": turns}``.
        id : str, optional
            Default ``"truth@ls=..,hs=.."``.
        velocities_m_s : array_like, optional
            Extra positive speeds [m/s] to put knots at (default a 0.5 m/s span).
        lag_s : float
            The shock's lag [s].
        """
        knee = self.knee_m_s + self.knee_per_click_m_s * float(settings["ls"])
        u = np.unique(np.concatenate([[knee, 0.5, 1.0],
                                      np.asarray(velocities_m_s if velocities_m_s is not None
                                                 else [], dtype=float)]))
        v = np.concatenate([-u[::-1], [0.0], u])
        name = id or f"truth@ls={settings['ls']:g},hs={settings['hs']:g}"
        return TableShock(name, v, self.force(v, settings), lag_s=lag_s)

    def dyno_sheet(self, settings_list, velocities_m_s):
        """A dyno sheet (SI) of the curves at `settings_list`, at +/- `velocities_m_s`.

        Returns
        -------
        pandas.DataFrame
            Columns ``velocity, force, ls, hs``; rebound rows first per setting.
        """
        u = np.sort(np.asarray(velocities_m_s, dtype=float))
        v = np.concatenate([-u[::-1], u])
        frames = []
        for s in settings_list:
            frames.append(pd.DataFrame({"velocity": v, "force": self.force(v, s),
                                        "ls": float(s["ls"]), "hs": float(s["hs"])}))
        return pd.concat(frames, ignore_index=True)

    def sweep_settings(self, ls_step=4, hs_step=1, *, ls_held=8.0, hs_held=2.0):
        """One-at-a-time sweeps, as dynos record them: ``ls`` at ``hs_held``, ``hs`` at
        ``ls_held`` (the held point once)."""
        lo, hi = self.ls_range
        out = [{"ls": float(x), "hs": float(hs_held)} for x in np.arange(lo, hi + 1e-9, ls_step)]
        if not any(s["ls"] == ls_held for s in out):
            out.append({"ls": float(ls_held), "hs": float(hs_held)})
        lo, hi = self.hs_range
        out += [{"ls": float(ls_held), "hs": float(x)} for x in np.arange(lo, hi + 1e-9, hs_step)
                if float(x) != float(hs_held)]
        return out


def gt_clicker():
    """The clicker of the GT-like car (:func:`ident.models.vehicle.example_gt_vehicle`).

    Sized so that the car's best setting lies inside both ranges: low-speed slope
    28,000 to 8,000 N/(m/s) over ``ls`` 0-20 clicks, high-speed slope 17,000 to 6,000
    N/(m/s) over ``hs`` 0-4 turns, knee 0.02-0.04 m/s. On a track drive the two
    adjusters trade against each other along a valley of near-equal scores (a stiffer
    ``hs`` pairs with a softer ``ls``), as on real cars.

    Returns
    -------
    ClickerDamper
    """
    return ClickerDamper(c_low_n_s_m=24000.0, c_low_floor_n_s_m=4000.0, c_high_n_s_m=14000.0,
                         c_high_floor_n_s_m=3000.0, knee_m_s=0.02, knee_per_click_m_s=0.001,
                         hs_rate=0.4)


#: The dyno's speeds [m/s] of :func:`clicker_shock`'s sheets (a 7-speed sweep).
DYNO_SPEEDS_M_S = (0.01, 0.025, 0.05, 0.1, 0.2, 0.3, 0.5)


def clicker_shock(damper, id="TTX", *, step=None, default=None, count=None, lag_s=0.0):
    """An adjustable shock from a damper's one-at-a-time dyno sweeps (the test crate).

    Parameters
    ----------
    damper : ClickerDamper
        The truth; its sheets are :meth:`ClickerDamper.sweep_settings` (``ls`` every 4
        clicks at ``hs`` 2, ``hs`` every turn at ``ls`` 8) at :data:`DYNO_SPEEDS_M_S`.
    id : str
    step : dict, optional
        The adjusters' resolution (default ``ls`` 1 click, ``hs`` 0.5 turn).
    default : dict, optional
        Default ``{"ls": 8, "hs": 2}``.
    count : int, optional
    lag_s : float

    Returns
    -------
    ident.models.adjustable.AdjustableShock
    """
    sheet = damper.dyno_sheet(damper.sweep_settings(), DYNO_SPEEDS_M_S)
    points = DynoPoints(sheet["velocity"].to_numpy(), sheet["force"].to_numpy(),
                        sheet[["ls", "hs"]].to_numpy(), ("ls", "hs"))
    return AdjustableShock(id, damper.adjusters, points, default=default or {"ls": 8, "hs": 2},
                           stiffer={"ls": "lower", "hs": "lower"},
                           step=step or {"ls": 1, "hs": 0.5}, count=count, lag_s=lag_s)
