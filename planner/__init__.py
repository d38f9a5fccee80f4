"""shockplan's model-to-decision half: which shocks to bolt on, and which rig runs to do next.

Modules, from the shared vocabulary up to the decisions (a module imports only those
before it):

- vocabulary: :mod:`~planner.errors`, :mod:`~planner.click_settings` (adjustable
  shocks' settings as setup candidates), :mod:`planner.setups` (the setup type, its
  files, the one enumeration, the one baseline resolver, the symmetry names),
  :mod:`~planner.objective` (scores, limits and the one ranking rule) and
  :mod:`~planner.rig_spec` (the rig TOML: time costs and actuator limits, and the limits
  applied to a drive), :mod:`~planner.options` (the commands' option objects: the car's
  elements, the loop, the screening, where it runs, the intervals' draws);
- engines: :mod:`~planner.runner` (tasks in this process or on Dask),
  :mod:`~planner.plant` (any model to the loop plant), :mod:`~planner.histograms` (the
  shock-velocity histograms the loop counts, their summaries and file),
  :mod:`~planner.predict` (the closed loop in the time domain), :mod:`~planner.screen`
  with :mod:`~planner.screen_kernels` and :mod:`~planner.screen_codegen` (the frequency
  domain, stochastic linearization), :mod:`~planner.uncertainty` (intervals from the
  identification's random error) and :mod:`~planner.noise` (an identified model's noise
  report);
- writers: :mod:`planner.report` (ranking, optimum and what-if files and figures, the
  print layout of every workbook) and :mod:`~planner.text` (the summaries' tables);
- decisions: :mod:`~planner.sweep` and :mod:`~planner.rank` (which crate setup),
  :mod:`planner.optimize` (which damper curve), :mod:`~planner.design` and
  :mod:`~planner.testplan` (which rig runs, the run sheet) and :mod:`planner.whatif`
  (does the best stay best); :mod:`planner.dyno` (a shock's curve as a table, the dyno
  check);
- :mod:`planner.cli` (the command line, a thin layer: a module per command) and
  :mod:`~planner.demo`.

``planner`` imports :mod:`ident`, never the reverse.
"""

__version__ = "0.1.0"
