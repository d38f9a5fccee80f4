"""Simulation: the one closed loop that serves the virtual rig and the planner.

Modules: :mod:`~ident.sim.closedloop` (a linear plant with nonlinear shock
feedback, stepped exactly), :mod:`~ident.sim.metrics` (the spec's RMS metrics)
and :mod:`~ident.sim.rig` (the virtual rig: a known car and an experiment plan
to a rig session).
"""
