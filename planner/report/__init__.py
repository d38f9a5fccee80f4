"""Report writers: what a person reads and prints (CSV, xlsx run sheets, figures).

:mod:`~planner.report.ranking` writes the predictions CSV and a ranking's
files (``ranking.csv``, ``ranking.xlsx``, ``pareto.png``, ``top_setups.png``).
:mod:`~planner.report.sheets` holds the print layout shared by every workbook
(column widths, labels, one page wide).
:mod:`~planner.report.whatif` writes a what-if's files (``whatif.xlsx``, CSVs,
``rank_stability.png``, ``tornado/*.png``) and reads the per-factor effects the
tornado charts show off the what-if's table (:func:`factor_effects`).
:mod:`~planner.report.optimize` writes a curve optimum's files (``optimize.xlsx``,
``curves.png``, ``convergence.csv``, the optimal shocks and setups).
:mod:`~planner.report.sweep_files` writes a sweep's files (``ranking.csv``, a CSV per case
named from its model and drive, ``sweep.toml``).
:mod:`~planner.report.dyno` writes ``shockplan dyno table``'s curve CSV and ``shockplan
dyno check``'s folder (``summary.md``, ``findings.csv``, per adjustable shock its fit,
worst error per setting and ``<id>.curves.png``). Compute lives in
the decision modules; these only format and write their results.
"""

from planner.report.optimize import (
    BUILDER_VELOCITIES_IN_S,
    BUILDER_VELOCITIES_M_S,
    curve_table,
    curves_figure,
    write_optimum,
)
from planner.report.ranking import (
    INTERVAL_SUFFIXES,
    RANKING_FILES,
    metric_of_column,
    ranking_columns,
    ranking_to_units,
    write_predictions_csv,
    write_ranking,
)
from planner.report.sheets import (
    PAPER_SIZE,
    column_label,
    fit_column_width,
    print_setup,
    text_width,
    wrap_lines,
)
from planner.report.sweep_files import case_file_names, write_sweep
from planner.report.whatif import (
    factor_effects,
    rank_stability_figure,
    tornado_figure,
    write_whatif,
)

__all__ = [
    "INTERVAL_SUFFIXES",
    "PAPER_SIZE",
    "RANKING_FILES",
    "column_label",
    "fit_column_width",
    "text_width",
    "wrap_lines",
    "metric_of_column",
    "print_setup",
    "ranking_columns",
    "ranking_to_units",
    "write_predictions_csv",
    "write_ranking",
    "BUILDER_VELOCITIES_M_S",
    "BUILDER_VELOCITIES_IN_S",
    "curve_table",
    "curves_figure",
    "write_optimum",
    "factor_effects",
    "tornado_figure",
    "rank_stability_figure",
    "write_whatif",
    "case_file_names",
    "write_sweep",
]
