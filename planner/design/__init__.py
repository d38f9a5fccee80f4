"""Optimal experiment design: which rig runs to do next, and in what order.

A rig run is a setup (the baseline, or crate shocks swapped in at one to four
corners), a drive and a duration. ``design_experiment`` chooses runs within a
rig-time budget so that the identification (:mod:`ident.identify.frf`, Eqs. 18-23 of the
seed paper) learns the most, by one of three criteria, then orders them to
swap as few shocks as possible.

Information of a run
--------------------
At each frequency the identification regresses every output on the 11 model
inputs ``x = [u_rig (7), dF (4)]``. For a run of duration ``T`` the Fisher
information about an output's row of the FRF in a frequency band is
``T * S_xx / sigma^2``: the band's cross-power of the regressors over the
output's noise power. The regressors of a candidate run are predicted through
the loop with each shock linearized as :mod:`planner.screen` does (its
equivalent damping at the shock velocity it will see, with its lag):
``dF = D_c K H_vr u`` with ``D_c = diag(c(omega) - c_bar)`` and
``K = (I - H_vs D_c)^-1``, so ``S_xx = G S_uu G^H`` with ``G = [I; D_c K H_vr]``
(11 x 7). One run alone has rank 7 (Eq. 17: with linearized shocks the shock
forces are linear functions of the rig inputs); runs with different shocks
add up to rank 11. A session already recorded adds its own measured
information (its runs' ``[u_rig, dF]``, the nonlinear part included). This
linearized model ignores the independent excitation a shock's nonlinearity
gives, so it values nonlinear shocks conservatively.

Criteria (all over the bands of ``band_hz``)
--------------------------------------------
- ``d``: D-optimal, ``sum_k log det M_k``;
- ``a``: A-optimal, ``sum_k tr M_k^-1`` (each band's inputs scaled to unit
  information of the whole candidate set, so units do not weigh);
- ``decision``: the variance of the predicted score differences between the
  top contenders of the current ranking, ``sum_pairs var(s_a - s_b) /
  (s_a - s_b)^2 = sum_k tr(W_k M_k^-1)``, with ``W_k`` from the scores'
  gradients with respect to the FRF (the screening's linearized loop,
  differentiated analytically) and the outputs' noise. With an identified model the
  pairs are those it does not resolve (the interval of their score difference contains
  0: :func:`planner.uncertainty.unresolved_pairs`, :func:`~planner.design.information.
  decision_pairs`); every pair where it resolves them all, or before rig day.

The relaxed problem (runs as real numbers) is solved with cvxpy (Clarabel) on
``n_design_bands`` groups of adjacent bands (a group's information summed:
``log det`` of a sum bounds the sum of ``log det``); the information
matrices are scaled per band so the solver sees unit diagonals. The relaxed
counts are rounded down and the budget left is filled greedily, run by run,
on the full criterion over every band (the cvxpy-free greedy of the benchmark
does the same from nothing). Each run costs its duration, the swap time of
every corner it changes and the rig's overhead per run; the order that swaps
least is found exactly for up to 9 runs (Held-Karp), by nearest neighbour and
2-opt above, and runs are dropped (least criterion share first) until the
ordered plan fits the budget.

Validation runs (``ScheduleOptions.n_validation``: the current best setups on the
team's drive) close the plan: their durations and their changes from the run before
spend the budget as the identification runs' do (the greedy's fixed ``tail``); the
validation setups are identification candidates too (the car is in them anyway, so an
identification run there costs no swap of its own); and the identification runs must
meet Eq. 17 on their own, without the validation runs' information (those play the
team's drive, which does not excite the band as a rig drive does). A budget that cannot
hold both is refused with the budget that would. ``ExperimentPlan.rationale`` says in a
line per purpose why the plan chose its runs.

Adjustable shocks (clickers)
----------------------------
The candidates include each adjustable shock of the crate at a few settings
(:func:`click_settings`: each adjuster across its range, all stiff, all soft),
named with every adjuster (``TTX@ls=0,hs=2``). A corner that keeps its
adjustable shock and changes its settings is a click change: it costs the
rig's ``click_change_s`` per adjuster turned (seconds), not ``swap_min``
(minutes) (:func:`change_time_min`), in the candidates' costs, the greedy's
insertion, the run order and the schedule. With an adjustable shock on the
baseline the design can thus vary a corner's damping for seconds of rig time;
the criterion decides which settings inform. A crate without adjustable shocks
plans exactly as before.

Third elements (issue 38)
-------------------------
On a car with heave and roll elements (the identified model's ``third``, or
``CandidateOptions.third`` for a known vehicle) the candidates also swap an element's
damper (``CandidateOptions.third_dampers``: element -> crate ids; a run
``"<id>@heave_front"`` costs one swap), and the crate's third dampers are not swapped in at
the corners. The identification puts the elements' force at the corners (``sum_e m_e
F_e``) into the corner inputs, so the corners' damping deviation of a candidate is a full
matrix: ``diag(c - c_bar) + sum_e c_e m_e m_e^T / (1 + j w lag_e)``, each third damper
linearized at its element's velocity RMS; a heave or roll damper swap varies the corner
inputs along ``m_e``, one direction of Eq. 17's rank. The heave springs' contact is left
out. Runs are the same car when :func:`~planner.design.candidates.setup_key` (corners and
third elements) is; the rig plan writes ``third_elements`` and each run's ``third``,
``heave_springs`` and ``heave_packers``.

Modules
-------
- :mod:`~planner.design.candidates`: the candidate runs and their costs on a rig;
- :mod:`~planner.design.information`: the runs' information and the criteria;
- :mod:`~planner.design.solve`: the relaxed problem (cvxpy), the greedy rounding, the order;
- :mod:`~planner.design.schedule`: the plan's runs in rig order and their predictions;
- :mod:`~planner.design.core`: :func:`design_experiment` and :class:`ExperimentPlan`.
"""

from planner.design.candidates import (
    DEFAULT_CLICK_LEVELS,
    DRIVE_KINDS,
    CandidateOptions,
    Candidate,
    click_settings,
    change_time_min,
    candidate_runs,
)
from planner.design.information import (
    CRITERIA,
    DEFAULT_BAND_HZ,
    InformationOptions,
    criterion_value,
)
from planner.design.solve import (
    greedy_design,
)
from planner.design.schedule import (
    PURPOSES,
    ScheduleOptions,
    PlannedRun,
)
from planner.design.core import (
    ExperimentPlan,
    design_experiment,
)

__all__ = [
    "Candidate",
    "PlannedRun",
    "ExperimentPlan",
    "CRITERIA",
    "DRIVE_KINDS",
    "PURPOSES",
    "candidate_runs",
    "click_settings",
    "change_time_min",
    "design_experiment",
    "CandidateOptions",
    "InformationOptions",
    "ScheduleOptions",
    "criterion_value",
    "greedy_design",
]
