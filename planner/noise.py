"""How much an identified model rests on noise, and the identification that reports it.

:func:`noise_report` measures it per pair (the model's summary) and in metrics (the random
part of :func:`planner.uncertainty.prediction_uncertainty` for the session's own first
baseline run); :func:`with_noise_report` returns the model with it
(:attr:`ident.identify.model.VehicleModel.noise`, saved with the model), and
:func:`identify_with_noise` is ``shockplan identify``'s workflow: the identification
(:func:`ident.identify.pipeline.identify_session`) and its noise report, the model that
the command saves.
"""

from __future__ import annotations

from ident.data.channels import CORNERS
from ident.data.drive import Drive
from ident.identify.model import NoiseReport
from ident.identify.pipeline import identify_session
from planner.options import UncertaintyOptions
from planner.setups import Setup
from planner.uncertainty import prediction_uncertainty

__all__ = ["noise_report", "with_noise_report", "identify_with_noise", "NOISE_DRAWS"]

#: Monte Carlo draws of the noise report's intervals.
NOISE_DRAWS = 20


def noise_report(model, session, *, n_draws=NOISE_DRAWS, seed=0):
    """How much the identified model rests on noise: per pair (the model's summary) and in
    metrics.

    The expected metric error is the random part of :func:`planner.uncertainty.
    prediction_uncertainty` (95 %) for the session's own first baseline run: its
    recorded rig inputs as the drive and its shocks as the setup.

    Parameters
    ----------
    model : ident.identify.model.VehicleModel
        The model identified from `session`.
    session : ident.data.session.Session
    n_draws : int
        Monte Carlo draws of the intervals.
    seed : int
        Seed of the draws.

    Returns
    -------
    ident.identify.model.NoiseReport
        ``noise_limited_pairs``, ``zero_pairs`` (counts), ``expected_metric_error_pct``
        (metric -> half-width of the 95 % interval [%]), ``reference`` (run and setup).
    """
    table = model.summary()
    base = next((r for r in session.runs if r.role == "baseline"), session.runs[0])
    drive = Drive(name=f"run {base.name}", fs_hz=session.fs_hz,
                  channels={c: base.dynamic(c) for c in session.rig_inputs})
    setup = Setup("reference", {c: base.setup[c] for c in CORNERS})
    unc = prediction_uncertainty(model, drive, [setup], session.shocks,
                                 draws=UncertaintyOptions(n_draws=n_draws, seed=seed))
    lo, hi = unc.components["random_lo"].iloc[0], unc.components["random_hi"].iloc[0]
    half = {m: 100 * float(max(hi[m] - 1, 1 - lo[m])) for m in unc.metric_names}
    return NoiseReport(noise_limited_pairs=int((table.status == "noise-limited").sum()),
                       zero_pairs=int((table.status == "zero").sum()),
                       expected_metric_error_pct=half,
                       reference={"run": base.name, "setup": "/".join(setup.ids())})


def with_noise_report(model, session, *, n_draws=NOISE_DRAWS, seed=0):
    """The model with its :func:`noise_report` (``model.noise``; the loop plant the report
    built is kept, and saved with the model).

    Parameters
    ----------
    model : ident.identify.model.VehicleModel
    session : ident.data.session.Session
        The session `model` was identified from.
    n_draws, seed
        :func:`noise_report`.

    Returns
    -------
    ident.identify.model.VehicleModel
    """
    return model.with_results(noise=noise_report(model, session, n_draws=n_draws, seed=seed))


def identify_with_noise(session, *, n_draws=NOISE_DRAWS, seed=0, **options):
    """Identify a model from `session` and report how much it rests on noise: the model
    ``shockplan identify`` saves.

    Parameters
    ----------
    session : ident.data.session.Session
    n_draws, seed
        :func:`noise_report`.
    **options
        :func:`ident.identify.pipeline.identify_session`'s options (``estimator``,
        ``fit_method``, ``max_order``, ``diagnose`` ...).

    Returns
    -------
    ident.identify.model.VehicleModel
        :func:`~ident.identify.pipeline.identify_session`'s model with ``noise`` set.
    """
    model = identify_session(session, **options)
    return with_noise_report(model, session, n_draws=n_draws, seed=seed)
