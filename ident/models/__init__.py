"""Models of the car's parts, independent of how they are simulated or identified.

Modules: :mod:`~ident.models.lti` (linear time-invariant systems in modal form, the
loop plant the simulator steps, their exact discretization and balanced reduction),
:mod:`~ident.models.vehicle` (the paper's 7-DOF full-car model and its vehicle TOML)
and :mod:`~ident.models.shocks` (shock force-velocity models, the shock library TOML
and fits to dyno data).
"""
