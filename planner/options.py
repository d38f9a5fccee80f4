"""The planner's option objects: one per concept, resolved once where a command starts.

The planner's commands (:func:`planner.predict.predict_setups`,
:func:`planner.rank.rank_setups`, :func:`planner.sweep.sweep_setups`,
:func:`planner.whatif.evaluate_whatif`, :func:`planner.optimize.optimize_curves`,
:func:`planner.trackdrive.build_track_drive`, ...) take the data, the few choices a caller
makes, and these keyword-only objects:

- :class:`ElementOptions`: the car's elements in the loop besides its shocks (bump stops,
  packers, the tires' static loads) and the element choices enumerated as setup columns;
- :class:`LoopOptions`: the time-domain loop (oversampling, metric band, model reduction,
  setups per compiled call, the shock-velocity histograms: :class:`HistogramOptions`);
- :class:`ScreenOptions`: the frequency-domain screening (bands, fixed-point iterations);
- :class:`RunOptions`: where and how the work runs (Dask scheduler, workers, task sizes);
- :class:`UncertaintyOptions`: the Monte Carlo intervals of the predictions.

Their defaults are the commands' defaults. A later element of the car (beyond bump stops
and packers) is added to :class:`ElementOptions` only.

Examples
--------
>>> from planner.options import ElementOptions, LoopOptions
>>> LoopOptions(oversample=4).band_hz
(1.0, 20.0)
>>> ElementOptions(use_model=False).has_choices
False
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from ident.data.third import CarThird
from ident.identify.model import LOOP_REDUCE_RTOL
from ident.models.bumpstops import BumpStopLibrary, CarElements

__all__ = ["ElementOptions", "HistogramOptions", "LoopOptions", "ScreenOptions", "RunOptions",
           "UncertaintyOptions", "as_options"]


def _check_int(value, name, cls, low=1, none=False):
    if none and value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise (TypeError if not isinstance(value, (int, np.integer)) or isinstance(value, bool)
               else ValueError)(f"{cls}: {name}={value!r} must be an integer >= {low}"
                                + (" or None" if none else ""))


def _check_band(band_hz, cls):
    try:
        lo, hi = (float(b) for b in band_hz)
    except (TypeError, ValueError):
        raise TypeError(f"{cls}: band_hz={band_hz!r} must be two frequencies (low, high) [Hz], "
                        "e.g. (1.0, 20.0)") from None
    if not (0 < lo < hi and np.isfinite(hi)):
        raise ValueError(f"{cls}: band_hz={tuple(band_hz)!r} must be 0 < low < high [Hz], "
                         "e.g. (1.0, 20.0)")


@dataclass(frozen=True, eq=False)
class ElementOptions:
    """The car's elements in the loop besides its shocks, and the choices to enumerate.

    Parameters
    ----------
    use_model : bool or ident.models.bumpstops.CarElements
        True (default): the model's own elements (``model.elements``, an identified model
        of a session that declared them: the bump-stop library, the baseline run's stops
        and packers, the static loads); a ``CarElements``: those (a model given as a
        plant); False: none of the car's (no static loads; only the stops the setups name,
        from `bump_stops`): the linear car of the paper.
    bump_stops : ident.models.bumpstops.BumpStopLibrary, optional
        A bump-stop library that replaces the model's (``--bump-stops FILE``): the stops
        the setups name (``bump_stop_XX``) are read from it.
    static_corner_load_n : array_like, shape (4,), optional
        Static tire loads [N] (LF, RF, LR, RR) that replace the model's: the loop keeps the
        contact force at or above zero (tire lift-off).
    vary_bump_stops : mapping of str to sequence of (str or None), optional
        Bump-stop choices per corner group enumerated as setup columns
        (:func:`planner.elements.vary_elements`), e.g. ``{"front": ["BS-F", "BS-F2"]}``
        (rank and sweep: every setup is ranked with each combination too).
    vary_packers_m : mapping of str to sequence of float, optional
        Packer choices [m] per corner group, e.g. ``{"front": [0, 0.002, 0.004]}``.
    third : ident.data.third.CarThird, optional
        The car's third elements (heave and roll elements per axle, issue 38) for a model
        given as a plant, or replacing the model's (``model.third``); None (default): the
        model's. With ``use_model=False`` none.
    vary_third : mapping of str to sequence of (str or None), optional
        Third-element choices enumerated as setup columns
        (:func:`planner.elements.vary_third`): a setups-CSV column (``heave_front``,
        ``roll_rear``: damper ids; ``heave_spring_front``: heave-spring ids) -> the ids to
        try (None or ``"none"``: not fitted), e.g. ``{"heave_front": ["H1", "H2"]}``.

    Raises
    ------
    TypeError
        If `use_model` is neither a bool nor a ``CarElements``, `bump_stops` is not a
        ``BumpStopLibrary``, or a choice is not a mapping.
    ValueError
        If `static_corner_load_n` is not 4 numbers.
    """

    use_model: bool | CarElements = True
    bump_stops: BumpStopLibrary | None = None
    static_corner_load_n: object = None
    vary_bump_stops: Mapping | None = None
    vary_packers_m: Mapping | None = None
    third: CarThird | None = None
    vary_third: Mapping | None = None

    def __post_init__(self):
        if not isinstance(self.use_model, (bool, CarElements)):
            raise TypeError(f"ElementOptions: use_model must be True, False or an "
                            f"ident.models.bumpstops.CarElements, got "
                            f"{type(self.use_model).__name__}")
        if self.bump_stops is not None and not isinstance(self.bump_stops, BumpStopLibrary):
            raise TypeError(f"ElementOptions: bump_stops must be an "
                            f"ident.models.bumpstops.BumpStopLibrary (read one with "
                            f"read_bump_stops), got {type(self.bump_stops).__name__}")
        if self.static_corner_load_n is not None \
                and np.size(self.static_corner_load_n) != 4:
            raise ValueError(f"ElementOptions: static_corner_load_n must be 4 loads [N] "
                             f"(LF, RF, LR, RR), got {self.static_corner_load_n!r}")
        if self.third is not None and not isinstance(self.third, CarThird):
            raise TypeError(f"ElementOptions: third must be an ident.data.third.CarThird, got "
                            f"{type(self.third).__name__}")
        for name in ("vary_bump_stops", "vary_packers_m", "vary_third"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, Mapping):
                raise TypeError(f"ElementOptions: {name} must be a mapping group -> choices, "
                                f"e.g. {{'front': [...]}}, got {type(value).__name__}")

    @property
    def has_choices(self):
        """True if bump-stop or packer choices are to be enumerated."""
        return bool(self.vary_bump_stops or self.vary_packers_m or self.vary_third)

    def without_choices(self):
        """These options without the choices (the elements of setups already enumerated)."""
        if self.vary_bump_stops is None and self.vary_packers_m is None \
                and self.vary_third is None:
            return self
        return replace(self, vary_bump_stops=None, vary_packers_m=None, vary_third=None)

    def car_third(self, model):
        """The car's third elements for `model`: `third`, else ``model.third``; None with
        ``use_model=False`` or a model without them."""
        if self.use_model is False:
            return None
        if self.third is not None:
            return self.third
        return getattr(model, "third", None)

    def car(self, model):
        """The car's elements for `model`: ``model.elements`` (``use_model=True``), the
        given ``CarElements``, or None (``use_model=False`` or a model without them)."""
        if self.use_model is False:
            return None
        if self.use_model is True:
            return getattr(model, "elements", None)
        return self.use_model

    def library(self, model):
        """The bump-stop library the setups' ids are read from: `bump_stops`, else the
        car's (:meth:`car`), or None."""
        if self.bump_stops is not None:
            return self.bump_stops
        return getattr(self.car(model), "bump_stops", None)

    def for_model(self, model):
        """These options with the model's elements fixed (``use_model`` the model's
        ``CarElements`` when it has them): what a worker given only a plant needs."""
        car = self.car(model)
        out = self
        if self.use_model is True and car is not None:
            out = replace(out, use_model=car)
        third = self.car_third(model)
        if third is not None and self.third is None:
            out = replace(out, third=third)
        return out


#: Default shock-velocity histogram per unit system: (bin width, limit of the inner bins,
#: knee) [m/s]; 1 in/s bins over +-10 in/s with a 1 in/s knee in an imperial project.
HISTOGRAM_DEFAULTS_M_S = {"SI": (0.025, 0.25, 0.025), "imperial": (0.0254, 0.254, 0.0254)}


@dataclass(frozen=True)
class HistogramOptions:
    """The shock-velocity histograms the time-domain loop counts (:mod:`planner.histograms`).

    Bins of `width_m_s` from ``-limit_m_s`` to ``+limit_m_s`` and an open bin at each end
    (every sample beyond the limit); the low-/high-speed split at `knee_m_s`.

    Parameters
    ----------
    width_m_s : float
        Bin width [m/s] (default 0.025 m/s; 1 in/s = 0.0254 m/s in an imperial project).
    limit_m_s : float
        The inner bins' extent [m/s] (default 0.25 m/s); ``2 limit / width`` a whole number.
    knee_m_s : float
        Low speed is ``|v| < knee`` [m/s] (default 0.025 m/s).

    Raises
    ------
    ValueError
        On a width, limit or knee that is not finite and positive, or a limit that is not
        a multiple of half the width.

    Examples
    --------
    >>> HistogramOptions().n_bins
    22
    >>> HistogramOptions.default("imperial").width_m_s
    0.0254
    """

    width_m_s: float = 0.025
    limit_m_s: float = 0.25
    knee_m_s: float = 0.025

    def __post_init__(self):
        for name in ("width_m_s", "limit_m_s", "knee_m_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) \
                    or not (np.isfinite(value) and value > 0):
                raise ValueError(f"HistogramOptions: {name}={value!r} must be a finite number "
                                 "> 0 [m/s], e.g. HistogramOptions(width_m_s=0.025, "
                                 "limit_m_s=0.25, knee_m_s=0.025)")
            object.__setattr__(self, name, float(value))
        n = 2.0 * self.limit_m_s / self.width_m_s
        if abs(n - round(n)) > 1e-9 * max(n, 1.0):
            raise ValueError(f"HistogramOptions: limit_m_s={self.limit_m_s:g} is not a multiple "
                             f"of half the width ({self.width_m_s:g} m/s); e.g. 0.025 m/s bins "
                             "over +-0.25 m/s")

    @classmethod
    def default(cls, units="SI"):
        """The default histogram of a unit system: 0.025 m/s bins over +-0.25 m/s (SI),
        1 in/s bins over +-10 in/s (imperial); the knee one bin."""
        return cls(*HISTOGRAM_DEFAULTS_M_S["imperial" if str(units).lower() == "imperial"
                                           else "SI"])

    @property
    def n_bins(self):
        """Bins, the two open end bins included."""
        return int(round(2.0 * self.limit_m_s / self.width_m_s)) + 2

    @property
    def bins(self):
        """``(width_m_s, limit_m_s, knee_m_s)``: the closed loop's ``histogram_bins``
        (:func:`ident.sim.closedloop.simulate_batch_metrics`)."""
        return (self.width_m_s, self.limit_m_s, self.knee_m_s)


@dataclass(frozen=True)
class LoopOptions:
    """The time-domain closed loop of the planner's predictions.

    Parameters
    ----------
    oversample : int
        Internal steps per drive sample of the shock loop (quadratic hold: at 2, metrics
        within about 0.3 % of a 32x run on a track drive at 100 Hz).
    band_hz : (float, float)
        Metric band [Hz] (spec default 1-20 Hz); also the screening's where a command
        screens.
    reduce_rtol : float or None
        Balanced-truncation bound of an identified model's shock part
        (:meth:`ident.identify.model.VehicleModel.loop_plant`); None: no reduction.
    chunk_size : int
        Setups simulated per compiled call (a progress bar's step; memory does not grow
        with it).
    metric_loads_n : mapping of str to float, optional
        Corner -> static load [N] the tire-force metrics are normalized by
        (``tire_force_rms_XX / load``, :func:`ident.sim.metrics.compute_metrics`'
        ``static_loads_n``). Not the loop's lift-off loads
        (:attr:`ElementOptions.static_corner_load_n`).
    histograms : HistogramOptions, optional
        Count every simulated setup's shock-velocity histogram per corner in the loop
        (:class:`planner.histograms.ShockHistograms`, the table's ``share_low_speed_XX``
        and ``bump_rebound_ratio_XX``); None (default): none, at no cost.

    Raises
    ------
    TypeError, ValueError
        On a non-integer or non-positive `oversample` or `chunk_size`, or a bad band.
    """

    oversample: int = 2
    band_hz: tuple = (1.0, 20.0)
    reduce_rtol: float | None = LOOP_REDUCE_RTOL
    chunk_size: int = 64
    metric_loads_n: Mapping | None = None
    histograms: HistogramOptions | None = None

    def __post_init__(self):
        if self.histograms is not None and not isinstance(self.histograms, HistogramOptions):
            raise TypeError(f"LoopOptions: histograms must be a planner.options.HistogramOptions "
                            f"or None, got {type(self.histograms).__name__}; e.g. "
                            "histograms=HistogramOptions()")
        _check_int(self.oversample, "oversample", "LoopOptions")
        _check_int(self.chunk_size, "chunk_size", "LoopOptions")
        _check_band(self.band_hz, "LoopOptions")


@dataclass(frozen=True)
class ScreenOptions:
    """The frequency-domain screening (:func:`planner.screen.screen_setups`).

    Parameters
    ----------
    n_bands : int
        Log-spaced frequency bands of the integration.
    max_iter : int
        Fixed-point iterations on the shock-velocity RMS.
    tol : float
        Their relative tolerance.
    chunk_size : int
        Setups per compiled batch (bounds memory).

    Raises
    ------
    TypeError, ValueError
        On a non-positive count or tolerance.
    """

    n_bands: int = 96
    max_iter: int = 30
    tol: float = 1e-5
    chunk_size: int = 20000

    def __post_init__(self):
        _check_int(self.n_bands, "n_bands", "ScreenOptions")
        _check_int(self.max_iter, "max_iter", "ScreenOptions")
        _check_int(self.chunk_size, "chunk_size", "ScreenOptions")
        if not (isinstance(self.tol, (int, float, np.floating)) and self.tol > 0):
            raise ValueError(f"ScreenOptions: tol={self.tol!r} must be a number > 0, "
                             "e.g. 1e-5")


@dataclass(frozen=True, eq=False)
class RunOptions:
    """Where and how a command's tasks run (:mod:`planner.runner`).

    Parameters
    ----------
    scheduler : str, optional
        ``"local"``: a new :class:`dask.distributed.LocalCluster` (`n_workers`, default one
        per core, closed at the end); a scheduler address (``"tcp://host:8786"``);
        ``"none"``: this process only. None: the command's default (the sweep's
        ``"local"``, the others' this process).
    client : distributed.Client, optional
        An existing client to use instead (not closed).
    n_workers : int, optional
        Workers of a new LocalCluster.
    processes : bool
        LocalCluster workers as processes (default) or threads of this process.
    chunk_size : int, optional
        Setups per task (screening tasks of the sweep; what-if and screening tasks);
        None: the command's default.
    simulate_chunk : int, optional
        Setups per time-domain task of the sweep; None: its default.

    Raises
    ------
    TypeError, ValueError
        On a non-integer or non-positive worker count or task size.
    """

    scheduler: str | None = None
    client: object = None
    n_workers: int | None = None
    processes: bool = True
    chunk_size: int | None = None
    simulate_chunk: int | None = None

    def __post_init__(self):
        if self.scheduler is not None and not isinstance(self.scheduler, str):
            raise TypeError(f"RunOptions: scheduler must be 'local', 'none', an address "
                            f"('tcp://host:8786') or None, got {type(self.scheduler).__name__}")
        _check_int(self.n_workers, "n_workers", "RunOptions", none=True)


@dataclass(frozen=True)
class UncertaintyOptions:
    """The Monte Carlo intervals of predictions.

    The draws of :func:`planner.uncertainty.prediction_uncertainty`.

    Parameters
    ----------
    n_draws : int
        Monte Carlo draws of the random part (at least 2).
    seed : int
        Seed of the draws.
    quantiles : (float, float)
        Interval bounds (default a 95 % interval).
    random_scale : float, optional
        Factor on the FRF's standard errors in the random part; default the session's
        cross-validation (:func:`planner.uncertainty.cross_validated_scale`) where the
        model has one, else :func:`planner.uncertainty.random_error_scale` of the model's
        FRF (the formula fitted to a family of cars).

    Raises
    ------
    TypeError
        If `n_draws` or `seed` is not an integer.
    """

    n_draws: int = 40
    seed: int = 0
    quantiles: tuple = (0.025, 0.975)
    random_scale: float | None = None

    def __post_init__(self):
        for name in ("n_draws", "seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise TypeError(f"UncertaintyOptions: {name}={value!r} must be an integer")


def as_options(value, cls, name, where):
    """`value` checked to be a `cls` (None: ``cls()``, the defaults).

    Raises
    ------
    TypeError
        If `value` is another type (the message names the argument and the class).
    """
    if value is None:
        return cls()
    if not isinstance(value, cls):
        raise TypeError(f"{where}: {name} must be a planner.options.{cls.__name__}, got "
                        f"{type(value).__name__}; e.g. {name}={cls.__name__}()")
    return value
