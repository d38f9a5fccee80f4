"""shockplan identification: from rig data to vehicle models.

Modules follow the data flow: :mod:`ident.session` (rig sessions),
:mod:`ident.shocks` (shock models), :mod:`ident.vehicle` (the physical full-car
model), :mod:`ident.drive` (drive files), :mod:`ident.closedloop` (closed-loop
simulation with nonlinear shocks), :mod:`ident.rig` (the virtual rig) and
:mod:`ident.metrics` (RMS metrics).
"""

__version__ = "0.1.0"
