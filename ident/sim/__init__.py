"""Simulation: the one closed loop that serves the virtual rig and the planner.

Modules: :mod:`~ident.sim.closedloop` (a linear plant with nonlinear shock feedback,
stepped exactly: the simulate API), :mod:`~ident.sim.loop_kernels` (its compiled
kernels), :mod:`~ident.sim.metrics` (the spec's RMS metrics) with
:mod:`~ident.sim.metric_kernels` (their compiled filters and sums, also fused into the
loop), :mod:`~ident.sim.stiffness` (spring and anti-roll-bar changes of a plant, as a
feedback from shock travel to shock force), :mod:`~ident.sim.virtual_rig` (the virtual
rig: a known car and an experiment plan to a rig session) and
:mod:`~ident.sim.virtual_track` (the virtual track: a road at a varying speed and a known
car's logger).
"""
