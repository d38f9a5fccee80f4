"""Models of the car's parts, independent of how they are simulated or identified.

Modules: :mod:`~ident.models.lti` (linear time-invariant systems in modal form, the
loop plant the simulator steps, their exact discretization and balanced reduction),
:mod:`~ident.models.vehicle` (the paper's 7-DOF full-car model and its vehicle TOML),
:mod:`~ident.models.shocks` (shock force-velocity models: piecewise-linear curves with a
lag), :mod:`~ident.models.adjustable` (adjustable shocks: a curve per click setting),
:mod:`~ident.models.library` (the shock library and its TOML file, ``shocks.toml``),
:mod:`~ident.models.bumpstops` (bump stops, packers and their library file,
``bumpstops.toml``) and :mod:`~ident.models.aero` (the team's downforce and balance
model, the aero loads it gives from speed and ride heights, and its TOML file). Shock
models fitted to dyno data are in :mod:`ident.dyno`.
"""
