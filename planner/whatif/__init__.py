"""What-if studies: how setups' metrics, scores and ranks move when the car, the shocks or
the track are not what the model and drive say.

``evaluate_whatif(model, drives, setups, library, perturbations)`` evaluates every setup
under every perturbation of a :class:`PerturbationSet` (read from a perturbation TOML with
:func:`read_perturbations`, or built with :func:`perturbation_set`), scores each condition
with the objective against the baseline setup *in that condition*, and returns a
:class:`WhatIf`: per setup and condition each metric's change, the score and the rank;
a robust ranking (best mean score, best worst-case score) with the setups whose rank is
fragile flagged; and per-factor effects for tornado charts. :func:`write_whatif` writes
``whatif.xlsx``, CSVs, ``tornado/<setup>.png`` and ``rank_stability.png``.

Perturbations
-------------
``shock_scale``
    Force multiplier of the shocks at some corners or of some shock ids (dyno
    tolerance, fade): the scaled shocks (:meth:`ident.models.shocks.ShockModel.scaled`) are
    simulated by :func:`planner.predict.predict_setups`, the same code path as a
    prediction with a scaled library.
``shock_lag``
    Lag change [s] added to the shocks at some corners or of some ids.
``spring_rate`` / ``arb_rate``
    Spring wheel rate per corner, anti-roll bar rate per axle (at the wheels, the force
    at a wheel per metre of travel difference across the axle). On an identified model
    this is exact without re-identification: an elastic element across the shock's
    corner gives a force ``dK t`` (``t`` the shock travels, compression positive) on the
    same input as the shock force, so it joins the loop as a linear feedback from the
    model's shock-travel outputs to its shock-force inputs (:func:`stiffened_plant`).
    On a known vehicle model the parameters change (the physics itself).
``drive_scale``
    Amplitude multiplier of a channel group (``wheel``, ``aero``) or of named rig inputs.
``drive_window``
    A time window ``[start, end]`` of the drive [s]: a track section.
``drive_file``
    Another drive file (relative paths from the perturbation file).
``vehicle``
    Any parameter of the known vehicle model, by its vehicle-TOML key (masses,
    inertias, tire and spring rates, CG position, tracks, anti-roll bars, torsion):
    needs a known model (a vehicle TOML); an identified model cannot change a mass
    without re-identification, and says so.
``click``
    Adjustable shocks (setting names ``"TTX@ls=6,hs=2"``) a whole number of clicks off,
    every adjuster or those named in ``adjusters``, clipped at the range ends (the
    table's ``clipped`` column); fixed shocks untouched (:mod:`planner.whatif.click_factors`).
``fade``
    Adjustable shocks warmed up: a fractional force loss of the whole curve or, with
    ``part = "low-speed"``, mostly of its low-speed part; fixed shocks untouched.

``third_scale`` / ``third_lag``
    Force multiplier / lag change [s] of the dampers of some third elements
    (``elements = ["heave_front", "roll_front"]``, issue 38): each setup's damper there
    (its own or the baseline run's) is replaced by its scaled copy
    (:meth:`ident.models.shocks.ShockModel.scaled`), simulated with the third elements
    by :func:`planner.predict.predict_setups`; a setup without that damper is unchanged.
``heave_spring_rate`` / ``heave_packer``
    Force multiplier / packer change [m] (a thicker packer closes the gap) of the heave
    spring of some axles (``axles = ["front"]``): the setup's heave spring is replaced
    by the scaled or moved copy. Third-element factors need a car with third elements
    (the model's ``third`` or ``ElementOptions.third``) declaring the element, and the
    time domain (``method = "time"``; the what-if's screening leaves them out).

``shock_scale`` and ``shock_lag`` act on setting names too: ``shocks = ["TTX"]`` names
every setting of an adjustable shock, ``shocks = ["TTX@ls=6,hs=2"]`` one setting. With
click or fade factors, :attr:`WhatIf.tolerance` gives each setup's spread and worst case
over each such factor's levels (levels ``[-1, 0, 1]``: the "+-1 click" tolerance).

Designs: ``one-at-a-time`` (each factor level alone), ``factorial`` (every combination
of levels) and ``monte-carlo`` (draws from each factor's distribution, uniform or
normal, independent per target with ``independent = true``; a factor with levels but no
distribution is drawn uniformly from its levels). The first condition is always the
nominal one (no change).

File format (``format = "shockplan-whatif/1"``)::

    format = "shockplan-whatif/1"
    units = "SI"                   # units of "add" changes of rates (N/m or lbf/in)
    design = "monte-carlo"         # "one-at-a-time" (default), "factorial", "monte-carlo"
    n_draws = 50                   # monte-carlo
    seed = 1

    [[factor]]
    name = "shock tolerance"
    kind = "shock_scale"
    corners = ["LF", "RF", "LR", "RR"]       # or shocks = ["B20", "DS"]
    independent = true
    levels = [0.95, 1.05]                    # one-at-a-time, factorial
    distribution = { kind = "uniform", low = 0.95, high = 1.05 }   # monte-carlo

    [[factor]]
    name = "rear springs"
    kind = "spring_rate"
    corners = ["LR", "RR"]
    change = "scale"                          # or "add" (a rate change, file units)
    levels = [0.9, 1.1]
    baseline_rate = 90000.0                   # identified models: the fitted car's rate

Where it runs: by default in this process, one condition group (the conditions sharing a
plant and a drive) after the other. With ``scheduler="local"`` (a
:class:`dask.distributed.LocalCluster`), a scheduler address or a ``client``, the groups,
cut into chunks of setups, are evaluated on Dask workers by a :mod:`planner.runner`
runner; the tables are the one-process tables bit for bit (see
:func:`evaluate_whatif`).

Scoring: in every condition the objective normalizes by the baseline setup evaluated in
that same condition, so a score says how much better than the team's baseline a setup
is on that car and track; ``max`` limits stay absolute. A setup's rank is *fragile*
when in more than ``fragile_share`` (10 %) of the conditions it moves more than
``rank_tolerance`` (1) place from its nominal rank.

Modules
-------
:mod:`planner.whatif.spec`
    Factors, designs and the perturbation file.
:mod:`planner.whatif.conditions`
    What a condition changes: the plant (:func:`stiffened_plant`), the drive, the shocks.
:mod:`planner.whatif.evaluate`
    :func:`evaluate_whatif` and its result :class:`WhatIf`, in this process or on Dask.
:mod:`planner.whatif.robust`
    The robust ranking and the fragile-rank rule.
:mod:`planner.whatif.baseline`
    The baseline when none is given: a ranking's own (:func:`whatif_baseline`).
:mod:`planner.whatif.click_factors`
    Click tolerance and adjuster fade of adjustable shocks, and the tolerance table.

The effects, figures and files (:func:`factor_effects`, :func:`tornado_figure`,
:func:`rank_stability_figure`, :func:`write_whatif`) are in
:mod:`planner.report.whatif`; this package re-exports them.
"""

from ident.sim.stiffness import suspension_stiffness
from planner.report.whatif import (
    factor_effects,
    rank_stability_figure,
    tornado_figure,
    write_whatif,
)
from planner.whatif.baseline import whatif_baseline
from planner.whatif.click_factors import FADE_HIGH_SPEED_SHARE, FADE_KNEE_M_S
from planner.whatif.conditions import MIN_WINDOW_S, stiffened_plant
from planner.whatif.evaluate import (
    MIN_TASK_EVALUATIONS,
    TASKS_PER_THREAD,
    WhatIf,
    evaluate_whatif,
)
from planner.whatif.robust import FRAGILE_SHARE, RANK_TOLERANCE
from planner.whatif.spec import (
    AXLE_CORNERS,
    CHANNEL_GROUPS,
    DESIGNS,
    FACTOR_KINDS,
    FADE_PARTS,
    MAX_CONDITIONS,
    Factor,
    Perturbation,
    PerturbationSet,
    perturbation_set,
    read_perturbations,
)

__all__ = [
    "FACTOR_KINDS",
    "DESIGNS",
    "RANK_TOLERANCE",
    "FRAGILE_SHARE",
    "Factor",
    "Perturbation",
    "PerturbationSet",
    "WhatIf",
    "perturbation_set",
    "read_perturbations",
    "suspension_stiffness",
    "stiffened_plant",
    "evaluate_whatif",
    "whatif_baseline",
    "factor_effects",
    "tornado_figure",
    "rank_stability_figure",
    "write_whatif",
    # the module's other public constants
    "MAX_CONDITIONS",
    "MIN_WINDOW_S",
    "CHANNEL_GROUPS",
    "AXLE_CORNERS",
    "TASKS_PER_THREAD",
    "MIN_TASK_EVALUATIONS",
    "FADE_PARTS",
    "FADE_HIGH_SPEED_SHARE",
    "FADE_KNEE_M_S",
]
