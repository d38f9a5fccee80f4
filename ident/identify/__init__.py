"""Identification: from a rig session to a vehicle model (the paper's method).

Modules in data-flow order: :mod:`~ident.identify.frf` (the multi-input FRF,
Eqs. 18-28), :mod:`~ident.identify.condition` (residual fits where coherence is
poor, smoothing), :mod:`~ident.identify.fit` (rational fits per pair),
:mod:`~ident.identify.model` (the identified model and its file),
:mod:`~ident.identify.pipeline` (the stages put together:
:func:`~ident.identify.pipeline.fit_model` and
:func:`~ident.identify.pipeline.identify_session`), :mod:`~ident.identify.fir`
(a nonparametric reference), :mod:`~ident.identify.shockcheck` (the session's shock
forces against the library) and :mod:`~ident.identify.plots` (FRF figures).
"""
