"""Closed-loop prediction of shock setups on a vehicle model (time domain).

``predict_setups(model, drive, setups, library)`` simulates every setup in closed
loop (nonlinear shocks with lag in the loop, the algebraic loop solved exactly) and
computes the spec's RMS metrics, both in
:func:`ident.sim.closedloop.simulate_batch_metrics` (the numbers of
:func:`ident.sim.closedloop.simulate_batch` then :func:`ident.sim.metrics.compute_metrics`). The
model may be an identified :class:`ident.identify.model.VehicleModel`, the known
:class:`ident.models.vehicle.FullCarModel`, or any :class:`ident.models.lti.LoopPlant`:
the same code path serves all, so identified and true predictions compare
like for like.

The rig-input part of the response does not depend on the setup: it is
computed once per drive and shared by every chunk of setups.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from ident.data.channels import CORNERS
from ident.data.drive import Drive, resample_drive
from ident.data.units import format_quantity
from ident.identify.coverage import Coverage, outside_coverage
from ident.identify.model import LOOP_REDUCE_RTOL, VehicleModel, load_model
from ident.models.lti import LoopPlant
from ident.models.vehicle import build_full_car, example_vehicle, read_vehicle
from ident.sim.closedloop import rig_response, simulate_batch_metrics
from planner.elements import (ELEMENT_COLUMNS, THIRD_COLUMNS, model_setup_elements,
                              model_setup_third)
from planner.errors import PlannerError
from planner.histograms import ShockHistograms
from planner.options import ElementOptions, HistogramOptions, LoopOptions, as_options
from planner.plant import as_loop_plant
from planner.setups import Setup

__all__ = [
    "Predictions",
    "METRIC_OUTPUTS",
    "as_loop_plant",  # from planner.plant
    "load_any_model",
    "prepare_drive",
    "predict_setups",
    "resolve_setups",
    "warn_outside_session",
]

log = logging.getLogger(__name__)

#: Output channels the spec's metrics need.
METRIC_OUTPUTS = tuple(f"{k}_{c}" for k in ("tire_force", "ride_height", "shock_travel",
                                            "shock_velocity") for c in CORNERS)
#: Two drive rates closer than this (relative) are the same rate.
RTOL_RATE = 1e-6
#: Predicted tire-force RMS above which a prediction is implausible [N]: 10 x a race
#: car's typical tire force (static corner loads of 1-3 kN, dynamic RMS well below).
PLAUSIBLE_TIRE_FORCE_RMS_N = 20e3


@dataclass(frozen=True, eq=False)
class Predictions:
    """Predicted metrics of a list of setups on one drive.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per setup (index: setup name, in the given order): the shock
        ids ``LF, RF, LR, RR`` then one column per metric (SI).
    setups : tuple of planner.setups.Setup
    settings : dict
        ``kind`` ("time" or "screening"), ``model``, ``drive``, ``oversample``,
        ``band_hz`` and whatever the predictor used.
    diagnostics : dict
        Per-setup arrays (e.g. Newton iterations, screening iterations).
    histograms : planner.histograms.ShockHistograms or None
        The setups' shock-velocity histograms per corner (time domain with
        :attr:`planner.options.LoopOptions.histograms`), in the table's order; None
        without.
    """

    table: pd.DataFrame
    setups: tuple
    settings: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)
    histograms: ShockHistograms | None = None

    @property
    def metric_names(self):
        """The metric columns of the table."""
        return [c for c in self.table.columns if c not in CORNERS and c not in ELEMENT_COLUMNS
                and c not in THIRD_COLUMNS]

    def element_lines(self):
        """What the loop held besides the shocks (``settings["elements"]``), and the largest
        shares of time in it, as lines for a terminal; none without elements.

        Returns
        -------
        list of str
        """
        settings, table = self.settings.get("elements"), self.table
        if not settings:
            return []
        lines = []
        shares = [c for c in table.columns if c.startswith("bump_stop_contact_share_")]
        if shares:
            worst = table[shares].max()
            lines.append("bump stops in the loop (library: " + str(settings.get("library"))
                         + "); largest share of time in contact: "
                         + ", ".join(f"{c[-2:]} {100 * v:.1f} %" for c, v in worst.items()))
        lifts = [c for c in table.columns if c.startswith("tire_liftoff_share_")]
        if lifts:
            worst = table[lifts].max()
            lines.append("static corner loads in the loop (tire lift-off); largest share of "
                         "time off the pad: " + ", ".join(f"{c[-2:]} {100 * v:.2f} %"
                                                          for c, v in worst.items()))
        return lines


def _warn_implausible(table, drive):
    """Log a warning when predicted tire forces are beyond any race car (wrong drive units?)."""
    cols = [c for c in table.columns if c.startswith("tire_force_rms_")
            and c[-2:] in CORNERS]
    if not cols:
        return
    worst = float(np.nanmax(table[cols].to_numpy(dtype=float)))
    if worst > PLAUSIBLE_TIRE_FORCE_RMS_N:
        log.warning("drive %r: a predicted tire force RMS of %.3g kN is more than %.0f kN "
                    "(10 x a race car's typical tire force); check the drive's units "
                    "(--units) and scale", drive.name, worst / 1e3,
                    PLAUSIBLE_TIRE_FORCE_RMS_N / 1e3)


def load_any_model(path):
    """A model from the command line's ``--model``: an identified model (``.npz``), a vehicle
    TOML (the known physical model, built) or ``"paper"`` (the seed paper's car).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    VehicleModel or FullCarModel
    """
    if str(path) == "paper":
        return build_full_car(example_vehicle())
    p = Path(path)
    if p.suffix.lower() == ".toml":
        return build_full_car(read_vehicle(p))
    return load_model(p)


def prepare_drive(drive, fs_hz=None, *, where="drive"):
    """Check a drive for prediction and bring it to the model's rate.

    The models are continuous-time, so any rate could be simulated; the drive
    is nevertheless *resampled* (band-limited, :func:`ident.data.drive.resample_drive`)
    to the model's data rate `fs_hz` so that metrics are computed at the rate
    the model was identified at. It is refused if its Nyquist frequency is
    below 25 Hz (the metric band ends at 20 Hz).

    Returns
    -------
    ident.data.drive.Drive
    """
    if not isinstance(drive, Drive):
        raise TypeError(f"{where}: expected an ident.data.drive.Drive, got {type(drive).__name__}")
    if drive.fs_hz < 50.0:
        raise PlannerError(f"{where}: sampled at {drive.fs_hz:g} Hz; the metrics need content up "
                           "to 20 Hz, so give a drive sampled at 50 Hz or more")
    if fs_hz is not None and abs(drive.fs_hz - fs_hz) > RTOL_RATE * fs_hz:
        log.warning("%s: resampling the drive from %g Hz to the model's %g Hz", where,
                    drive.fs_hz, fs_hz)
        drive = resample_drive(drive, fs_hz)
    return drive


def resolve_setups(setups, library):
    """Shock models of every setup: a list of 4-tuples (LF, RF, LR, RR).

    Raises
    ------
    PlannerError
        On a setup naming an unknown shock id (the message names the setup,
        the corner and the known ids).
    """
    out = []
    known = {}  # each id looked up once: a setting name (TTX@ls=6,hs=2) costs ~10 us a lookup
    for s in setups:
        if not isinstance(s, Setup):
            raise TypeError(f"setups must be planner.setups.Setup objects, got {type(s).__name__}")
        ids = s.ids()
        try:
            out.append(tuple(map(known.__getitem__, ids)))
            continue
        except KeyError:
            pass
        row = s.resolve(library)
        known.update(zip(ids, row))
        out.append(row)
    if not out:
        raise PlannerError("no setups to predict; give at least one setup")
    return out


def _model_fs(model):
    return getattr(model, "fs_hz", None)


def predict_setups(model, drive, setups, library, *, loop=LoopOptions(),
                   elements=ElementOptions(), progress=False, check_coverage=True):
    """Predict the metrics of shock setups on a model and drive (time domain).

    Parameters
    ----------
    model : VehicleModel, FullCarModel, VehicleParams or LoopPlant
    drive : ident.data.drive.Drive
    setups : sequence of planner.setups.Setup
    library : ident.models.library.ShockLibrary
    loop : planner.options.LoopOptions
        The loop: ``oversample``, the metric band ``band_hz`` [Hz], ``reduce_rtol`` (see
        :func:`as_loop_plant`), ``chunk_size`` (setups per compiled call, a progress bar's
        step; memory does not grow with it: each thread keeps one setup's outputs, whose
        metrics it computes right after simulating it,
        :func:`ident.sim.closedloop.simulate_batch_metrics`), ``metric_loads_n`` (the
        normalized tire-force metrics' loads).
    elements : planner.options.ElementOptions
        The real car's elements (:func:`planner.elements.model_setup_elements`): by
        default the model's (``model.elements``, an identified model of a session that
        declared them: the bump stops the setups name, ``bump_stop_XX``, else the
        baseline run's, and the static tire loads, tire lift-off); ``bump_stops`` a
        library replacing the model's, ``static_corner_load_n`` loads [N] replacing its;
        ``use_model=False``: the setups without the model's bump stops and static loads
        (the linear car of the paper; only stops the setups name, with ``bump_stops``).
        The setups are simulated as given: choices (``vary_*``) are refused (rank and
        sweep enumerate them).
    progress : bool
        Show a progress bar.
    check_coverage : bool
        Warn when setups take the car beyond what the model's session covered
        (:func:`warn_outside_session`; ``diagnostics["outside_session"]``).

    Returns
    -------
    Predictions
        With bump stops the table adds ``bump_stop_contact_share_XX`` (share of time in
        contact); with static loads ``tire_contact_min_XX`` [N] and
        ``tire_liftoff_share_XX``; with ``loop.histograms`` the histograms' summaries
        ``share_low_speed_XX`` and ``bump_rebound_ratio_XX`` (:mod:`planner.histograms`;
        the histograms in :attr:`Predictions.histograms`); then the setup columns
        ``bump_stop_XX`` and ``packer_XX`` [m] (after the metrics, as the spec allows).
        With third elements (``model.third`` or ``elements.third``; issue 38) each
        setup's dampers and heave springs (``Setup.third``, ``Setup.heave_springs``; a key
        left out keeps the baseline run's) are in the loop: the table adds per declared
        element ``<kind>_travel_rms_<axle>`` and ``<kind>_velocity_rms_<axle>``, per heave
        spring ``heave_spring_contact_share_<axle>``, and the setup columns
        ``heave_front``, ..., ``heave_spring_<axle>`` (ids or ``none``; a ranking reads
        back as a setups file).
    """
    loop = as_options(loop, LoopOptions, "loop", "predict_setups")
    elements = as_options(elements, ElementOptions, "elements", "predict_setups")
    if elements.has_choices:
        raise ValueError("predict_setups: simulates the setups given; enumerate the bump-stop "
                         "and packer choices with planner.elements.vary_elements (or rank "
                         "them with rank_setups)")
    oversample, chunk_size, band_hz = loop.oversample, loop.chunk_size, loop.band_hz
    reduce_rtol = loop.reduce_rtol
    plant = as_loop_plant(model, reduce_rtol=reduce_rtol)
    if not isinstance(plant, LoopPlant):
        raise TypeError(f"time-domain prediction needs a state-space model, got "
                        f"{type(plant).__name__}; use planner.screen for frequency-response plants")
    drive = prepare_drive(drive, _model_fs(model))
    models = resolve_setups(setups, library)
    elem = model_setup_elements(setups, model, elements)
    third = model_setup_third(setups, model, library, elements, where="predict")
    outputs = [o for o in METRIC_OUTPUTS if o in plant.output_names]
    rig = rig_response(plant, drive, oversample=oversample, outputs=outputs)
    extra = {} if elem is None else {
        "bump_stops": elem.loop_stops(), "static_corner_load_n": elem.static_corner_load_n}
    if third is not None:
        extra["third"] = third.loop_third()
    hist = loop.histograms
    # the kernel's histogram variant runs either way (its counts dropped when no histogram
    # is asked for: the metrics are the same bits, the counting ~1 % of the loop), so every
    # prediction uses one compiled kernel: a fresh machine compiles it once (issue 40)
    extra["histogram_bins"] = (HistogramOptions() if hist is None else hist).bins
    rows, iters, counts = [], [], []
    starts = range(0, len(models), chunk_size)
    if progress:
        starts = tqdm(starts, desc="predict", unit="chunk")
    for a in starts:
        if extra.get("bump_stops") is not None:
            extra["bump_stops"] = elem.loop_stops(slice(a, a + chunk_size))
        if third is not None:
            extra["third"] = third.loop_third(slice(a, a + chunk_size))
        batch = simulate_batch_metrics(plant, drive, models[a:a + chunk_size],
                                       oversample=oversample, outputs=outputs, rig=rig,
                                       band_hz=band_hz, static_loads_n=loop.metric_loads_n,
                                       **extra)
        rows.append(pd.DataFrame({k: np.asarray(v) for k, v in batch.metrics.values.items()}))
        iters.append(batch.newton_iterations)
        counts.append(batch.histogram_counts)
    table = pd.concat(rows, ignore_index=True)
    ids = pd.DataFrame([s.ids() for s in setups], columns=list(CORNERS))
    table = pd.concat([ids, table], axis=1)
    table.index = pd.Index([s.name for s in setups], name="setup")
    histograms = None
    if hist is not None:
        histograms = ShockHistograms.from_counts(np.concatenate(counts), batch.n_samples,
                                                 table.index, hist)
        table = pd.concat([table, histograms.summary().set_axis(table.index)], axis=1)
    if elem is not None:
        table = pd.concat([table, elem.columns(table.index)], axis=1)
    if third is not None:
        table = pd.concat([table, third.columns(table.index)], axis=1)
    _warn_implausible(table, drive)
    settings = {"kind": "time", "model": getattr(plant, "name", None), "drive": drive.name,
                "oversample": oversample, "band_hz": tuple(band_hz), "fs_hz": drive.fs_hz,
                "reduce_rtol": reduce_rtol, "n_shock_modes": int(plant.shock.n_states)}
    if elem is not None:
        settings["elements"] = elem.settings
    if third is not None:
        settings["third"] = third.car.to_dict()
    if histograms is not None:
        settings["histograms"] = histograms.settings()
    diagnostics = {"newton_iterations": np.concatenate(iters)}
    outside = None if not check_coverage else warn_outside_session(
        model, table, None if elem is None else elem.static_corner_load_n)
    if outside is not None:
        diagnostics["outside_session"] = outside
    return Predictions(table=table, setups=tuple(setups), settings=settings,
                       diagnostics=diagnostics, histograms=histograms)


def warn_outside_session(model, table, static_corner_load_n=None):
    """Warn when predictions take the car beyond what the model's session covered.

    Parameters
    ----------
    model : VehicleModel or other
        An identified model keeps its session's coverage (``settings["coverage"]``,
        :func:`ident.identify.coverage.session_coverage`); other models have none.
    table : pandas.DataFrame
        Predicted metrics (SI), one row per setup.
    static_corner_load_n : array_like, shape (4,), optional

    Returns
    -------
    pandas.DataFrame or None
        One row per setup and corner outside (``setup, corner, what, predicted,
        covered``, SI), or None for a model without coverage. A warning is logged
        when it is not empty: the model extrapolates there (a travel, velocity or
        contact the session never reached), so the predictions of those setups are
        less certain than the intervals say.
    """
    settings = getattr(model, "settings", None)
    cov = settings.get("coverage") if isinstance(settings, dict) else None
    if cov is None:
        return None
    rows = outside_coverage(table, Coverage.from_dict(cov), static_corner_load_n)
    frame = pd.DataFrame(rows, columns=["setup", "corner", "what", "predicted", "covered"])
    if len(frame):
        worst = frame.assign(ratio=frame.predicted / frame.covered).sort_values(
            "ratio", ascending=False).iloc[0]
        quantity = {"travel": "displacement", "velocity": "velocity",
                    "contact": "force"}[worst["what"]]
        log.warning("%d of %d setups take the car beyond what the session covered (%s); "
                    "e.g. setup %r at %s: %s %s predicted, %s covered. The model "
                    "extrapolates there: check those setups on the rig, or record a run "
                    "that reaches them", frame.setup.nunique(), len(table),
                    ", ".join(sorted(set(frame.what))), worst["setup"], worst["corner"],
                    "RMS " + worst["what"] if worst["what"] != "contact"
                    else "smallest contact force",
                    format_quantity(worst["predicted"], quantity, small=True),
                    format_quantity(worst["covered"], quantity, small=True))
    return frame
