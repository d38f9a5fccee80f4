"""Report writers: what a person reads and prints (CSV, xlsx run sheets, figures).

:mod:`~planner.report.ranking` writes the predictions CSV and a ranking's
files (``ranking.csv``, ``ranking.xlsx``, ``pareto.png``, ``top_setups.png``)
and holds the print layout shared by every workbook. Compute lives in the
decision modules; these only format and write their results.
"""

from planner.report.ranking import (
    INTERVAL_SUFFIXES,
    PAPER_SIZE,
    RANKING_FILES,
    column_label,
    fit_column_width,
    metric_of_column,
    print_setup,
    ranking_columns,
    ranking_to_units,
    text_width,
    wrap_lines,
    write_predictions_csv,
    write_ranking,
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
]
