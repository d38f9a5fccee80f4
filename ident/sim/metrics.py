"""RMS metrics of rig runs and simulated responses (the rig-session spec's Metrics).

A metric is the RMS of a channel after a zero-phase band-pass filter, a
Butterworth of order 4 from 1 to 20 Hz by default::

    sosfiltfilt(butter(4, [1, 20], "bandpass", fs=fs, output="sos"), x)

applied to the dynamic part of the channel (its mean removed first). The
front (rear) ride height is the mean of the LF and RF (LR and RR) ride
heights. :func:`bandpass` is that reference filter; :func:`compute_metrics`
applies it to every metric channel present in a run, a drive or a simulated
response.

The RMS is taken over the whole record. The reference filter pads only 27
samples at each end (``sosfiltfilt``'s default), short against the 1 Hz
edge, so the first and last second or so carry a start-up transient: a
negligible weight for an in-band signal (5 Hz sine over 100 s: 0.02 %), but
it is what limits the rejection of an out-of-band one (a 40 Hz sine over
200 s still gives 2 % of its RMS). Use records of minutes, as rigs do.

Examples
--------
>>> import numpy as np
>>> fs = 200.0
>>> t = np.arange(20_000) / fs
>>> m = compute_metrics({"tire_force_LF": 100.0 * np.sin(2 * np.pi * 5.0 * t)}, fs=fs)
>>> round(m.values["tire_force_rms_LF"], 1)  # 100 / sqrt(2), edges aside
70.7
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import signal

from ident.data.channels import CORNERS, quantity_of
from ident.data.units import check_units, from_si
from ident.sim.metric_kernels import metric_rms_rows, sosfiltfilt_rows

__all__ = [
    "METRIC_NAMES",
    "METRIC_CHANNELS",
    "THIRD_METRIC_NAMES",
    "METRIC_QUANTITY",
    "BAND_SUFFIXES",
    "Metrics",
    "MetricPlan",
    "bandpass",
    "compute_metrics",
    "metric_plan",
]

logger = logging.getLogger(__name__)

#: Channels averaged into each metric's signal, in the spec's metric order (metric name ->
#: tuple of channel names; a ride height is the mean of two corners).
METRIC_CHANNELS = {}
METRIC_CHANNELS.update({f"tire_force_rms_{c}": (f"tire_force_{c}",) for c in CORNERS})
METRIC_CHANNELS["ride_height_rms_front"] = ("ride_height_LF", "ride_height_RF")
METRIC_CHANNELS["ride_height_rms_rear"] = ("ride_height_LR", "ride_height_RR")
METRIC_CHANNELS.update({f"shock_travel_rms_{c}": (f"shock_travel_{c}",) for c in CORNERS})
METRIC_CHANNELS.update({f"shock_velocity_rms_{c}": (f"shock_velocity_{c}",)
                         for c in CORNERS})

#: The spec's metric names, in the spec's order (tire force x4, ride height
#: front/rear, shock travel x4, shock velocity x4).
METRIC_NAMES = tuple(METRIC_CHANNELS)

#: The third elements' motion metrics (the spec's section "Third elements"; issue 38): per
#: element (heave or roll, front or rear) the RMS of its travel and of its velocity, band-passed
#: as the others, present when the element's channels are (a closed loop with the element, or
#: a run that recorded them). Not among :data:`METRIC_NAMES` (the 14 every prediction has).
THIRD_METRIC_CHANNELS = {f"{kind}_{what}_rms_{axle}": (f"{kind}_{what}_{axle}",)
                         for kind in ("heave", "roll") for axle in ("front", "rear")
                         for what in ("travel", "velocity")}
THIRD_METRIC_NAMES = tuple(THIRD_METRIC_CHANNELS)
METRIC_CHANNELS.update(THIRD_METRIC_CHANNELS)

_NORM_NAMES = tuple(f"tire_force_rms_norm_{c}" for c in CORNERS)

#: Name suffixes of the body band and wheel-hop band metrics (``split_hz``).
BAND_SUFFIXES = ("_body", "_wheelhop")

#: Physical quantity of every metric :func:`compute_metrics` can return (key of
#: ``ident.data.units.TO_SI``), including the normalized tire-force metrics and the
#: ``_body`` / ``_wheelhop`` band variants.
METRIC_QUANTITY = {}
for _suffix in ("",) + BAND_SUFFIXES:
    METRIC_QUANTITY.update({f"{name}{_suffix}": quantity_of(chans[0])
                            for name, chans in METRIC_CHANNELS.items()})
    METRIC_QUANTITY.update({f"{name}{_suffix}": "dimensionless" for name in _NORM_NAMES})
del _suffix
#: The closed loop's element metrics (bump stops and tire lift-off, issue 25; not band-passed:
#: :data:`ident.sim.closedloop.ELEMENT_STATS`), per corner.
METRIC_QUANTITY.update({f"bump_stop_contact_share_{c}": "dimensionless" for c in CORNERS})
METRIC_QUANTITY.update({f"tire_liftoff_share_{c}": "dimensionless" for c in CORNERS})
METRIC_QUANTITY.update({f"tire_contact_min_{c}": "force" for c in CORNERS})
#: The heave springs' contact share in the closed loop with third elements (issue 38).
METRIC_QUANTITY.update({f"heave_spring_contact_share_{a}": "dimensionless"
                        for a in ("front", "rear")})
#: The shock-velocity histograms' summaries (the planner's ``LoopOptions.histograms``,
#: :mod:`planner.histograms`; not band-passed): the share of time below the knee, the time
#: in bump over the time in rebound, the distance from a target (logged) histogram.
for _kind in ("share_low_speed", "bump_rebound_ratio", "histogram_distance"):
    METRIC_QUANTITY.update({f"{_kind}_{c}": "dimensionless" for c in CORNERS})
del _kind


@dataclass(frozen=True)
class Metrics:
    """Band-passed RMS metrics and the settings that produced them.

    Attributes
    ----------
    values : dict of str to float or ndarray
        Metric name -> RMS value in SI units (see :data:`METRIC_QUANTITY`), in
        the order: the spec's metrics (:data:`METRIC_NAMES`, those present),
        the normalized tire forces ``tire_force_rms_norm_XX``, then the same
        with the suffix ``_body`` and then ``_wheelhop`` when `split_hz` is
        set. A float for signals of shape ``(n_samples,)``; an array of the
        leading shape for batched signals of shape ``(..., n_samples)``. The closed
        loop with bump stops or static loads
        (:func:`ident.sim.closedloop.simulate_batch_metrics`) appends its element
        metrics: ``bump_stop_contact_share_XX``, ``tire_liftoff_share_XX`` (0-1) and
        ``tire_contact_min_XX`` [N].
    band_hz : tuple of float
        The band-pass edges (low, high) [Hz].
    order : int
        The Butterworth prototype order (the band-pass has twice that order,
        applied forward and backward).
    fs_hz : float
        The sample rate of the signals [Hz].
    split_hz : float or None
        The frequency [Hz] separating the body band (``band_hz[0]`` ..
        `split_hz`) from the wheel-hop band (`split_hz` .. ``band_hz[1]``).
    static_loads_n : dict of str to float or None
        Corner -> static corner load [N] used for ``tire_force_rms_norm_XX``.
    """

    values: dict
    band_hz: tuple
    order: int
    fs_hz: float
    split_hz: float | None = None
    static_loads_n: dict | None = None

    def to_units(self, units):
        """Return the metric values converted to a unit system.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Target unit system (force in lbf, displacement in in, velocity in
            in/s; normalized metrics are dimensionless).

        Returns
        -------
        dict of str to float or ndarray
            Metric name -> value in `units`, in the order of :attr:`values`.
        """
        units = check_units(units, where="Metrics.to_units")
        return {name: from_si(value, METRIC_QUANTITY[name], units)
                for name, value in self.values.items()}

    def as_series(self, *, units="SI"):
        """Return the metrics of one signal set as a :class:`pandas.Series`.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Unit system of the values.

        Returns
        -------
        pandas.Series
            Indexed by metric name.

        Raises
        ------
        ValueError
            If the metrics are batched (use :meth:`as_frame`).
        """
        import pandas as pd

        values = self.to_units(units)
        if any(np.ndim(v) for v in values.values()):
            raise ValueError(
                "Metrics.as_series: the metrics are batched (array values); "
                "use Metrics.as_frame() for one row per signal set"
            )
        series = pd.Series(values, dtype=float, name="metric_value")
        series.index.name = "metric"
        return series

    def as_frame(self, *, units="SI"):
        """Return the metrics as a :class:`pandas.DataFrame`, one row per signal set.

        Parameters
        ----------
        units : {"SI", "imperial"}
            Unit system of the values.

        Returns
        -------
        pandas.DataFrame
            Columns are metric names; one row for unbatched metrics, ``n``
            rows for metrics of leading shape ``(n,)``.

        Raises
        ------
        ValueError
            If the metrics have more than one leading (batch) axis.
        """
        import pandas as pd

        values = self.to_units(units)
        if any(np.ndim(v) > 1 for v in values.values()):
            raise ValueError(
                "Metrics.as_frame: the metrics have more than one batch axis; "
                "reshape the signals to (n_sets, n_samples) first"
            )
        return pd.DataFrame({k: np.atleast_1d(v) for k, v in values.items()})


def _check_fs(fs):
    try:
        fs = float(fs)
    except (TypeError, ValueError):
        raise TypeError(f"fs must be a number (sample rate in Hz), got {fs!r}") from None
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sample rate in Hz, got {fs}")
    return fs


def _check_band(band_hz, fs):
    try:
        low, high = (float(f) for f in band_hz)
    except (TypeError, ValueError):
        raise ValueError(
            f"band_hz must be a pair (low, high) in Hz, got {band_hz!r}"
        ) from None
    if not (0.0 < low < high < fs / 2):
        raise ValueError(
            f"band_hz={band_hz!r} must satisfy 0 < low < high < fs/2 = {fs / 2:g} Hz; "
            "narrow the band or use a higher sample rate"
        )
    return (low, high)


def _check_order(order):
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)):
        raise TypeError(f"order must be an integer, got {order!r}")
    if order < 1:
        raise ValueError(f"order must be a positive integer, got {order}")
    return int(order)


def _design(band, order, fs):
    """The reference band-pass as second-order sections, and sosfiltfilt's padlen."""
    sos = signal.butter(order, band, "bandpass", fs=fs, output="sos")
    # sosfiltfilt's default padding, computed as scipy does (its input must be
    # longer than this).
    ntaps = 2 * len(sos) + 1 - min((sos[:, 2] == 0).sum(), (sos[:, 5] == 0).sum())
    return sos, 3 * int(ntaps)


@functools.lru_cache(maxsize=32)
def _band_filter(band, order, fs):
    """:func:`_design` with ``sosfilt_zi``, as contiguous float arrays, once per (band,
    order, rate): a batch prediction computes metrics chunk after chunk with the same
    filter (about 5 ms per design). Shared arrays: read them only."""
    sos, padlen = _design(band, order, fs)
    sos = np.ascontiguousarray(sos, dtype=float)
    return sos, padlen, np.ascontiguousarray(signal.sosfilt_zi(sos))


def _filtfilt(x, sos, padlen, axis, label):
    n = x.shape[axis]
    if n <= padlen:
        raise ValueError(
            f"{label}: {n} samples, but the zero-phase band-pass needs at least "
            f"{padlen + 1} (sosfiltfilt's padding); use a longer record"
        )
    x = np.asarray(x, dtype=float)
    if x.ndim < 2 or x.size < _FAST_MIN_SIZE or axis not in (-1, x.ndim - 1):
        return signal.sosfiltfilt(sos, x, axis=axis)
    # batched signals (a batch of simulated setups): the same filter, compiled and parallel
    rows = np.ascontiguousarray(x.reshape(-1, n))
    out = np.empty_like(rows)
    sosfiltfilt_rows(rows, np.ascontiguousarray(sos, dtype=float),
                     np.ascontiguousarray(signal.sosfilt_zi(sos)), int(padlen), out)
    return out.reshape(x.shape)


#: Smallest batch (samples in all) filtered by the compiled path; below it, scipy directly.
_FAST_MIN_SIZE = 20_000




def bandpass(x, *, fs, band_hz=(1.0, 20.0), order=4, axis=-1):
    """Apply the spec's reference zero-phase Butterworth band-pass.

    Exactly ``sosfiltfilt(butter(order, band_hz, "bandpass", fs=fs,
    output="sos"), x, axis=axis)``; the mean is not removed here (the
    metrics remove it before filtering).

    Parameters
    ----------
    x : array_like, shape (..., n_samples, ...)
        Signal(s); filtered along `axis`, vectorized over the other axes.
    fs : float
        Sample rate [Hz].
    band_hz : tuple of float
        Band edges (low, high) [Hz], with ``0 < low < high < fs/2``.
    order : int
        Butterworth prototype order.
    axis : int
        The time axis of `x`.

    Returns
    -------
    ndarray
        The filtered signal, same shape as `x`.

    Raises
    ------
    ValueError
        If `fs` is not positive, the band is not inside ``(0, fs/2)``, or `x`
        is too short for the filter's padding.
    TypeError
        If `fs` is not a number or `order` not an integer.
    """
    fs = _check_fs(fs)
    band = _check_band(band_hz, fs)
    order = _check_order(order)
    x = np.asarray(x, dtype=float)
    if x.ndim == 0:
        raise ValueError("bandpass: x must have a time axis, got a scalar")
    sos, padlen, _ = _band_filter(band, order, fs)   # designed once per (band, order, rate)
    return _filtfilt(x, sos, padlen, axis, "bandpass: x")


def _source_channels(source, fs):
    """Split `source` into (channels mapping, fs [Hz])."""
    if hasattr(source, "channels") and hasattr(source, "fs_hz"):
        channels, fs_source = source.channels, _check_fs(source.fs_hz)
        if fs is not None and not math.isclose(_check_fs(fs), fs_source, rel_tol=1e-9):
            raise ValueError(
                f"compute_metrics: fs={fs} disagrees with the source's fs_hz="
                f"{fs_source}; leave fs unset for objects that carry their sample rate"
            )
        fs = fs_source
    elif isinstance(source, Mapping):
        if fs is None:
            raise ValueError(
                "compute_metrics: a Mapping of channels carries no sample rate; pass fs=..."
            )
        channels, fs = source, _check_fs(fs)
    else:
        raise TypeError(
            "compute_metrics: source must have .channels and .fs_hz (a run, a drive, "
            f"a response) or be a Mapping of channel -> array, got {type(source).__name__}"
        )
    if not isinstance(channels, Mapping):
        raise TypeError(
            f"compute_metrics: source.channels must be a Mapping, got "
            f"{type(channels).__name__}"
        )
    return channels, fs


def _check_static_loads(static_loads_n):
    if static_loads_n is None:
        return {}
    if not isinstance(static_loads_n, Mapping):
        raise TypeError(
            "static_loads_n must be a mapping corner -> static corner load [N], got "
            f"{type(static_loads_n).__name__}"
        )
    loads = {}
    for corner, load in static_loads_n.items():
        if corner not in CORNERS:
            raise ValueError(
                f"static_loads_n: unknown corner {corner!r}; use one of {list(CORNERS)}"
            )
        load = float(load)
        if not (math.isfinite(load) and load > 0):
            raise ValueError(
                f"static_loads_n[{corner!r}] = {load} must be a positive load in N"
            )
        loads[corner] = load
    return loads


def _metric_rms(xs, sos, zi, padlen, label):
    """RMS of the band-passed dynamic signal of one metric's channels `xs` (see
    :func:`_metric_channels`): batches of two-dimensional channels take the fused kernel
    (:func:`ident.sim.metric_kernels.metric_rms_rows`, the same numbers), the rest
    :func:`_metric_signal`'s steps. `zi` is ``sosfilt_zi(sos)`` as a contiguous float array (once per band)."""
    x = xs[0]
    n = x.shape[-1]
    if x.ndim != 2 or x.size < _FAST_MIN_SIZE or len(xs) > 2 or n <= padlen:
        return _rms(_filtfilt(_metric_signal(xs), sos, padlen, -1, label))
    out = np.empty(x.shape[0])
    metric_rms_rows(x, xs[-1], len(xs) == 2, sos, zi, int(padlen), out)
    return out


def _metric_channels(channels, names, label):
    """The channels of one metric as float arrays of one shape (checked)."""
    xs = [np.asarray(channels[c], dtype=float) for c in names]
    for c, x in zip(names, xs):
        if x.ndim == 0:
            raise ValueError(
                f"channel {c!r} is a scalar; expected an array of shape (..., n_samples)"
            )
    if any(x.shape != xs[0].shape for x in xs):
        shapes = ", ".join(f"{c} {x.shape}" for c, x in zip(names, xs))
        raise ValueError(
            f"{label}: the channels averaged must have the same shape, got {shapes}"
        )
    return xs


def _metric_signal(xs):
    """The dynamic (mean-removed) signal of one metric: the mean of its channels `xs`."""
    x = xs[0] if len(xs) == 1 else sum(xs) / len(xs)
    return x - x.mean(axis=-1, keepdims=True)


def _rms(y):
    rms = np.sqrt(np.mean(y * y, axis=-1))
    return float(rms) if rms.ndim == 0 else rms


def compute_metrics(source, *, fs=None, band_hz=(1.0, 20.0), order=4,
                    static_loads_n=None, split_hz=None):
    """Compute the spec's band-passed RMS metrics of a run, drive or response.

    Parameters
    ----------
    source : object or Mapping
        Either an object with ``channels`` (Mapping channel -> array) and
        ``fs_hz`` (a session run, a drive, a simulated response), or a
        Mapping channel -> array (then `fs` is required). Arrays have shape
        ``(n_samples,)`` or ``(..., n_samples)`` (batched, e.g.
        ``(n_setups, n_samples)``), SI units, canonical channel names.
    fs : float, optional
        Sample rate [Hz]; required for a Mapping source, otherwise it must
        agree with ``source.fs_hz`` if given.
    band_hz : tuple of float
        The band-pass edges (low, high) [Hz], default the spec's (1, 20).
    order : int
        Butterworth prototype order, default the spec's 4.
    static_loads_n : Mapping of str to float, optional
        Corner -> static corner load [N]. Adds ``tire_force_rms_norm_XX`` =
        ``tire_force_rms_XX / static_loads_n[XX]`` (dimensionless) for each
        corner given whose tire force is present.
    split_hz : float, optional
        If given (e.g. 8.0), every metric is also computed in a body band
        (``band_hz[0]`` .. `split_hz`) and a wheel-hop band (`split_hz` ..
        ``band_hz[1]``), with the same filter order, under the name suffixed
        ``_body`` and ``_wheelhop``.

    Returns
    -------
    Metrics
        Values in SI units; a float per metric for unbatched signals, an
        array of the leading shape for batched ones.

    Raises
    ------
    ValueError
        If `fs` is not positive, a band is not inside ``(0, fs/2)``,
        `split_hz` is not inside `band_hz`, a static load is not positive,
        the channels averaged into a ride height differ in shape, or a
        channel is too short for the filter's padding (the message names the
        channel and the minimum length).
    TypeError
        If `source` is neither kind of object, or a parameter has a bad type.

    Notes
    -----
    Metrics whose channels are absent are omitted, not NaN: a front ride
    height needs both ``ride_height_LF`` and ``ride_height_RF``, a normalized
    tire force needs the tire force and a static load of its corner. Extra
    channels are ignored. Non-finite samples give NaN for that signal set
    (they are not an error, so a diverged simulation in a batch does not
    stop the others).

    Signs do not matter (RMS); the channels follow the spec's conventions.
    """
    channels, fs = _source_channels(source, fs)
    plan = metric_plan(channels, fs, band_hz=band_hz, order=order,
                        static_loads_n=static_loads_n, split_hz=split_hz)
    signals = {name: _metric_channels(channels, METRIC_CHANNELS[name], name)
               for name in plan.names}
    rms = {}
    for suffix, b in plan.bands.items():
        sos, padlen, zi = plan.filter(b)
        for name, xs in signals.items():
            label = "channel " + " and ".join(repr(c) for c in METRIC_CHANNELS[name])
            rms[name + suffix] = _metric_rms(xs, sos, zi, padlen, label)
    return plan.assemble(rms)


@dataclass(frozen=True)
class MetricPlan:
    """What :func:`compute_metrics` computes from a set of channels (:func:`metric_plan`):
    the checked settings, the bands (suffix -> (low, high) [Hz]) and the metrics whose
    channels are present, in the spec's order. Shared with the closed loop's fused kernel
    (:func:`ident.sim.closedloop.simulate_batch_metrics`), which computes the RMS values
    itself and assembles them here."""

    band: tuple
    order: int
    fs: float
    split: object
    loads: dict
    bands: dict
    names: tuple

    def filter(self, b):
        """``(sos, padlen, zi)`` of band `b`."""
        return _band_filter(tuple(float(f) for f in b), self.order, float(self.fs))

    def assemble(self, rms):
        """The :class:`Metrics` from ``rms`` (metric name with band suffix -> values):
        the band-passed RMS metrics in order, and the normalized tire forces."""
        values = {}
        for suffix in self.bands:
            for name in self.names:
                values[name + suffix] = rms[name + suffix]
            for corner in CORNERS:
                tire = f"tire_force_rms_{corner}{suffix}"
                if corner in self.loads and tire in values:
                    values[f"tire_force_rms_norm_{corner}{suffix}"] = (values[tire]
                                                                      / self.loads[corner])
        return Metrics(values=values, band_hz=self.band, order=self.order, fs_hz=self.fs,
                       split_hz=self.split, static_loads_n=dict(self.loads) or None)


def metric_plan(channel_names, fs, *, band_hz=(1.0, 20.0), order=4, static_loads_n=None,
                 split_hz=None):
    """Check :func:`compute_metrics`' settings for channels `channel_names` at rate `fs`
    (already checked) and return its :class:`MetricPlan`.

    Raises
    ------
    ValueError, TypeError
        As :func:`compute_metrics` for a bad band, order, static load or `split_hz`.
    """
    band = _check_band(band_hz, fs)
    order = _check_order(order)
    loads = _check_static_loads(static_loads_n)
    bands = {"": band}
    if split_hz is not None:
        split = float(split_hz)
        if not (band[0] < split < band[1]):
            raise ValueError(
                f"split_hz={split_hz!r} must lie strictly inside band_hz={band}"
            )
        bands["_body"] = (band[0], split)
        bands["_wheelhop"] = (split, band[1])
    else:
        split = None
    names = []
    for name, chans in METRIC_CHANNELS.items():
        missing = [c for c in chans if c not in channel_names]
        if missing:
            logger.debug("metric %s omitted: no channel %s", name, ", ".join(missing))
            continue
        names.append(name)
    return MetricPlan(band=band, order=order, fs=fs, split=split, loads=loads, bands=bands,
                       names=tuple(names))
