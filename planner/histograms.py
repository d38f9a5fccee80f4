"""Shock-velocity histograms: the share of time per velocity bin, per setup and corner.

Race engineers judge dampers on the shock-velocity histogram (the data-analysis tools'
standard view). The time-domain loop counts it for every setup it simulates when
:attr:`planner.options.LoopOptions.histograms` is set (:class:`planner.options.HistogramOptions`:
bins of 0.025 m/s over +-0.25 m/s and an open bin at each end by default, the knee at 0.025
m/s), in the same pass as the metrics (:func:`ident.sim.closedloop.simulate_batch_metrics`),
at the output samples the metrics use (the whole record). :func:`predict_setups
<planner.predict.predict_setups>`, :func:`rank_setups <planner.rank.rank_setups>` and the
sweep's time-domain stage return them as a :class:`ShockHistograms`.

Definitions (velocity ``v`` compression positive, as the rig-session spec's signs):

- ``share`` of a bin: the share of the output samples (of time) with ``v`` in
  ``[velocity_lo, velocity_hi)``; the shares of a setup's corner add up to 1;
- ``share_low_speed_XX``: the share of time with ``|v| < knee``;
- ``bump_rebound_ratio_XX``: the share of time in bump (``v > 0``, compression) over the
  share of time in rebound (``v < 0``); NaN if the shock never rebounds;
- ``histogram_distance_XX``: the total-variation distance ``0.5 sum |p - q|`` over the
  bins between a setup's histogram and a target's (a logged one,
  :func:`histogram_distance`), 0 (equal) to 1 (disjoint).

Examples
--------
>>> import numpy as np
>>> from planner.options import HistogramOptions
>>> t = (np.arange(10_000) + 0.5) / 1000.0
>>> v = 0.1 * np.sin(2 * np.pi * t)  # a 1 Hz sine of 0.1 m/s amplitude, whole periods
>>> h = histograms_of({f"shock_velocity_{c}": v for c in CORNERS}, HistogramOptions(), name="sine")
>>> round(float(h.low_speed_share[0, 0]), 2)  # (2 / pi) asin(0.25) = 0.161
0.16
>>> float(h.bump_rebound_ratio[0, 0])
1.0
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ident.data.channels import CORNERS
from ident.data.files import write_csv
from ident.data.units import check_units, from_si
from ident.sim.closedloop import histogram_edges, velocity_histogram_counts
from ident.sim.loop_kernels import HISTOGRAM_COUNTERS
from planner.options import HistogramOptions

__all__ = [
    "HISTOGRAM_METRICS",
    "HISTOGRAM_COLUMNS",
    "HISTOGRAMS_FILE",
    "ShockHistograms",
    "histograms_of",
    "histogram_distance",
    "total_variation",
    "write_histograms_csv",
    "histograms_path",
    "logged_histograms",
]

#: The summary metrics of a histogram in a predictions or ranking table, per corner.
HISTOGRAM_METRICS = tuple(f"{k}_{c}" for k in ("share_low_speed", "bump_rebound_ratio")
                          for c in CORNERS)
#: The columns of ``histograms.csv`` (before the trailing ``units``).
HISTOGRAM_COLUMNS = ("setup", "corner", "velocity_lo", "velocity_hi", "share")
#: The file name written beside a ranking, predictions or sweep.
HISTOGRAMS_FILE = "histograms.csv"
#: Significant digits of the bin bounds in a file (1 in/s bins read 3.0, not 2.9999999999999996).
_EDGE_DIGITS = 12


def total_variation(p, q, axis=-1):
    """Total-variation distance ``0.5 sum |p - q|`` of two histograms of shares.

    Parameters
    ----------
    p, q : array_like
        Shares (each summing to 1 along `axis`), broadcast against each other.
    axis : int

    Returns
    -------
    ndarray or float
        0 (equal) to 1 (disjoint).

    Examples
    --------
    >>> total_variation([0.5, 0.5, 0.0], [0.0, 0.5, 0.5])
    0.5
    """
    d = 0.5 * np.sum(np.abs(np.asarray(p, dtype=float) - np.asarray(q, dtype=float)), axis=axis)
    return float(d) if np.ndim(d) == 0 else d


@dataclass(frozen=True, eq=False)
class ShockHistograms:
    """Shock-velocity histograms of several setups, per corner (see the module docstring).

    Attributes
    ----------
    edges_m_s : ndarray, shape (n_bins + 1,)
        Bin edges [m/s], ``-inf`` and ``+inf`` first and last (the open end bins).
    shares : ndarray, shape (n_setups, 4, n_bins)
        Share of time (0-1) per setup, corner (LF, RF, LR, RR) and bin.
    low_speed_share : ndarray, shape (n_setups, 4)
        Share of time with ``|v| < knee``.
    bump_share, rebound_share : ndarray, shape (n_setups, 4)
        Share of time with ``v > 0`` (compression) and with ``v < 0``.
    setups : tuple of str
        The setups' names.
    knee_m_s : float
        The low-/high-speed split [m/s].
    n_samples : int
        Samples per setup and corner.
    """

    edges_m_s: np.ndarray
    shares: np.ndarray
    low_speed_share: np.ndarray
    bump_share: np.ndarray
    rebound_share: np.ndarray
    setups: tuple
    knee_m_s: float
    n_samples: int

    @classmethod
    def from_counts(cls, counts, n_samples, setups, options):
        """The histograms of the closed loop's counts.

        Parameters
        ----------
        counts : ndarray, shape (n_setups, 4, n_bins + 3)
            :attr:`ident.sim.closedloop.BatchMetrics.histogram_counts`.
        n_samples : int
            Samples per setup and corner.
        setups : sequence of str
        options : planner.options.HistogramOptions

        Returns
        -------
        ShockHistograms
        """
        counts = np.asarray(counts, dtype=float)
        n = max(int(n_samples), 1)
        nb = counts.shape[-1] - HISTOGRAM_COUNTERS
        if nb != options.n_bins:
            raise ValueError(f"ShockHistograms.from_counts: {nb} bins counted, the options "
                             f"have {options.n_bins}")
        return cls(edges_m_s=histogram_edges(options.width_m_s, options.limit_m_s),
                   shares=counts[..., :nb] / n, low_speed_share=counts[..., nb] / n,
                   bump_share=counts[..., nb + 1] / n, rebound_share=counts[..., nb + 2] / n,
                   setups=tuple(str(s) for s in setups), knee_m_s=float(options.knee_m_s),
                   n_samples=int(n_samples))

    @property
    def n_bins(self):
        """Bins, the open end bins included."""
        return self.shares.shape[-1]

    @property
    def bump_rebound_ratio(self):
        """Share of time in bump over share in rebound, (n_setups, 4); NaN without rebound."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.rebound_share > 0, self.bump_share / self.rebound_share,
                            np.nan)

    def summary(self):
        """The summary metrics per setup: ``share_low_speed_XX``, ``bump_rebound_ratio_XX``.

        Returns
        -------
        pandas.DataFrame
            Indexed by setup name, columns :data:`HISTOGRAM_METRICS` (dimensionless).
        """
        data = {}
        for j, c in enumerate(CORNERS):
            data[f"share_low_speed_{c}"] = self.low_speed_share[:, j]
        ratio = self.bump_rebound_ratio
        for j, c in enumerate(CORNERS):
            data[f"bump_rebound_ratio_{c}"] = ratio[:, j]
        return pd.DataFrame(data, index=pd.Index(list(self.setups), name="setup"))

    def select(self, names):
        """These histograms of the setups `names`, in that order.

        Raises
        ------
        KeyError
            If a name is not among :attr:`setups`.
        """
        pos = {s: i for i, s in enumerate(self.setups)}
        missing = [n for n in names if n not in pos]
        if missing:
            raise KeyError(f"ShockHistograms.select: no histogram of setups {missing[:5]}")
        idx = np.array([pos[n] for n in names], dtype=np.intp)
        return ShockHistograms(self.edges_m_s, self.shares[idx], self.low_speed_share[idx],
                               self.bump_share[idx], self.rebound_share[idx],
                               tuple(str(n) for n in names), self.knee_m_s, self.n_samples)

    @staticmethod
    def concat(parts):
        """The setups of several :class:`ShockHistograms` of the same bins, in order
        (a later setup of a name already present is dropped)."""
        parts = [p for p in parts if p is not None]
        if not parts:
            return None
        first = parts[0]
        for p in parts[1:]:
            if not np.array_equal(p.edges_m_s, first.edges_m_s) or p.knee_m_s != first.knee_m_s:
                raise ValueError("ShockHistograms.concat: the histograms have other bins")
        names = [s for p in parts for s in p.setups]
        cat = ShockHistograms(first.edges_m_s,
                              *(np.concatenate([getattr(p, f) for p in parts])
                                for f in ("shares", "low_speed_share", "bump_share",
                                          "rebound_share")),
                              tuple(names), first.knee_m_s, first.n_samples)
        unique = list(dict.fromkeys(names))
        return cat if len(unique) == len(names) else cat.select(unique)

    def table(self, units="SI"):
        """The histograms as a long table, one row per setup, corner and bin.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Of the velocity bounds (m/s, in/s).

        Returns
        -------
        pandas.DataFrame
            Columns ``setup, corner, velocity_lo, velocity_hi, share`` (:data:`HISTOGRAM_COLUMNS`):
            the bounds of each bin (NaN: the open end bins' missing bound; an empty field
            in a CSV), the share of time 0-1.
        """
        units = check_units(units, where="ShockHistograms.table")
        edges = from_si(self.edges_m_s, "velocity", units)
        finite = np.isfinite(edges)
        edges = np.where(finite, np.round(edges, _EDGE_DIGITS), np.nan)
        S, C, B = self.shares.shape
        return pd.DataFrame({
            "setup": np.repeat(np.array(self.setups, dtype=object), C * B),
            "corner": np.tile(np.repeat(np.array(CORNERS, dtype=object), B), S),
            "velocity_lo": np.tile(edges[:-1], S * C),
            "velocity_hi": np.tile(edges[1:], S * C),
            "share": self.shares.reshape(-1),
        })

    def settings(self, units="SI"):
        """The bins as a mapping for a report (bounds in `units`)."""
        units = check_units(units, where="ShockHistograms.settings")
        inner = from_si(self.edges_m_s[1:-1], "velocity", units)
        return {"width": float(np.round(inner[1] - inner[0], _EDGE_DIGITS)) if inner.size > 1
                else None, "limit": float(np.round(inner[-1], _EDGE_DIGITS)),
                "knee": float(np.round(from_si(self.knee_m_s, "velocity", units),
                                       _EDGE_DIGITS)),
                "n_bins": int(self.n_bins), "units": units}


def histograms_of(channels, options, *, name="logged"):
    """The histogram of measured or logged shock velocities (one "setup").

    Parameters
    ----------
    channels : mapping of str to array_like
        ``shock_velocity_XX`` [m/s], compression positive (a track log's, a run's); a
        corner without its channel gets NaN shares.
    options : planner.options.HistogramOptions
    name : str
        The setup name of the row.

    Returns
    -------
    ShockHistograms
        Counted with the closed loop's arithmetic
        (:func:`ident.sim.closedloop.velocity_histogram_counts`); NaN samples left out.
    """
    counts = np.zeros((1, 4, options.n_bins + HISTOGRAM_COUNTERS))
    n = np.zeros(4)
    for j, c in enumerate(CORNERS):
        v = channels.get(f"shock_velocity_{c}")
        if v is None:
            counts[0, j] = np.nan
            n[j] = 1
            continue
        v = np.asarray(v, dtype=float).ravel()
        counts[0, j] = velocity_histogram_counts(v, options.bins)
        n[j] = max(int(np.isfinite(v).sum()), 1)
    nb = options.n_bins
    edges = histogram_edges(options.width_m_s, options.limit_m_s)
    shares = counts / n[None, :, None]
    return ShockHistograms(edges, shares[..., :nb], shares[..., nb], shares[..., nb + 1],
                           shares[..., nb + 2], (str(name),), float(options.knee_m_s),
                           int(n.max()))


def histogram_distance(histograms, target):
    """Total-variation distance of every setup's histogram from a target's, per corner.

    Parameters
    ----------
    histograms : ShockHistograms
    target : ShockHistograms
        One setup (e.g. :func:`histograms_of` a track log), the same bins.

    Returns
    -------
    pandas.DataFrame
        Indexed by setup, columns ``histogram_distance_XX`` (0-1); NaN where the target
        has no channel.

    Raises
    ------
    ValueError
        If the bins differ.
    """
    if not np.array_equal(histograms.edges_m_s, target.edges_m_s):
        raise ValueError("histogram_distance: the target histogram has other bins; count it "
                         "with the same HistogramOptions")
    d = total_variation(histograms.shares, target.shares[:1], axis=-1)
    return pd.DataFrame({f"histogram_distance_{c}": d[:, j] for j, c in enumerate(CORNERS)},
                        index=pd.Index(list(histograms.setups), name="setup"))


def write_histograms_csv(histograms, path, *, units="SI", overwrite=False):
    """Write ``histograms.csv``: one row per setup, corner and bin.

    Parameters
    ----------
    histograms : ShockHistograms
    path : str or os.PathLike
    units : {"SI", "imperial"}
        Of the velocity bounds (the drive's).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path

    Notes
    -----
    Columns ``setup, corner, velocity_lo, velocity_hi, share, units`` (the header first,
    the unit system on every row, as every CSV shockplan writes); the open end bins
    have an empty bound. ``pandas.read_csv(path)`` reads it as it is. Written atomically.
    """
    from pathlib import Path

    if not isinstance(histograms, ShockHistograms):
        raise TypeError(f"write_histograms_csv: histograms must be a "
                        f"planner.histograms.ShockHistograms, got {type(histograms).__name__}")
    write_csv(path, histograms.table(units), units=units, overwrite=overwrite)
    return Path(path)


def histograms_path(predictions_csv):
    """Where ``shockplan predict`` writes the histograms of a predictions CSV: beside it,
    ``<name>_histograms.csv`` (``predictions.csv`` -> ``predictions_histograms.csv``).

    Examples
    --------
    >>> histograms_path("out/predictions.csv").name
    'predictions_histograms.csv'
    """
    from pathlib import Path

    p = Path(predictions_csv)
    return p.with_name(f"{p.stem}_histograms.csv")


def logged_histograms(logs, options, *, name="logged"):
    """The shock-velocity histogram of track logs (all their samples together).

    Parameters
    ----------
    logs : sequence of ident.data.tracklog.TrackLog
        Or any records with ``channels`` (SI) and ``fs_hz``: each corner's
        ``shock_velocity_XX`` [m/s], else its ``shock_travel_XX`` [m] differentiated
        (:func:`numpy.gradient` at the log's rate); a corner with neither has NaN shares.
    options : planner.options.HistogramOptions
    name : str
        The setup name of the row.

    Returns
    -------
    ShockHistograms
        One row (:func:`histograms_of` of the joined samples).
    """
    joined = {}
    for c in CORNERS:
        parts = []
        for lg in logs:
            ch = lg.channels
            if f"shock_velocity_{c}" in ch:
                parts.append(np.asarray(ch[f"shock_velocity_{c}"], dtype=float))
            elif f"shock_travel_{c}" in ch and len(ch[f"shock_travel_{c}"]) > 1:
                parts.append(np.gradient(np.asarray(ch[f"shock_travel_{c}"], dtype=float))
                             * float(lg.fs_hz))
        if parts:
            joined[f"shock_velocity_{c}"] = np.concatenate(parts)
    return histograms_of(joined, options, name=name)
