"""Write a sweep's files: ``ranking.csv``, one CSV per case and ``sweep.toml``.

A case file is named after its case's number and the stems of its model's and drive's
names (:func:`case_file_names`): the drive ``runs/track.csv`` swept on one model gives
``case-1-track.csv``, not ``case-1-runs-track.csv.csv``. With one model the drive names
the file, with one drive the model, else both (``case-3-heavy-track.csv``). The case
number keeps the names unique (on case-insensitive file systems too); every other
character outside ``A-Z a-z 0-9 . _ -`` becomes ``-``.

Examples
--------
>>> name_stem("runs/2026/track.csv"), name_stem("C:\\\\cars\\\\car v2.npz"), name_stem("paper")
('track', 'car-v2', 'paper')
>>> case_file_name(1, ["paper"], ["runs/track.csv"])
'case-1-track.csv'
>>> case_file_name(4, ["car.toml", "heavy.toml"], ["track.csv", "bumps.parquet"])
'case-4-heavy-bumps.csv'
"""

from __future__ import annotations

import re
from pathlib import Path

from ident.data.files import atomic_write_toml
from planner.histograms import histograms_path, write_histograms_csv
from planner.report.ranking import write_predictions_csv

__all__ = [
    "CASE_NAME_SUFFIXES",
    "MAX_STEM_CHARS",
    "SWEEP_FORMAT",
    "case_file_name",
    "case_file_names",
    "name_stem",
    "write_sweep",
]

#: File suffixes taken off a model's or drive's name in a case file's name: the formats
#: models (``.npz``, a vehicle ``.toml``) and drives (``.csv``, ``.parquet``, ``.pq``) are
#: read from. Any other dot stays (``"v1.2 run"`` -> ``v1.2-run``).
CASE_NAME_SUFFIXES = (".csv", ".parquet", ".pq", ".npz", ".toml")
#: Longest part of a case file's name taken from one name [characters].
MAX_STEM_CHARS = 40
#: The ``format`` of ``sweep.toml``.
SWEEP_FORMAT = "shockplan-sweep/1"
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def name_stem(name):
    """A model's or drive's name as part of a file name.

    The last path component (``/`` or ``\\`` separated), without one suffix of
    :data:`CASE_NAME_SUFFIXES` (case-insensitive), runs of characters outside
    ``A-Z a-z 0-9 . _ -`` as one ``-``, no leading or trailing ``-`` or ``.``, at most
    :data:`MAX_STEM_CHARS` characters. May be empty.

    Parameters
    ----------
    name : str

    Returns
    -------
    str
    """
    base = re.split(r"[/\\]", str(name).rstrip("/\\"))[-1]
    for suffix in CASE_NAME_SUFFIXES:
        if base.lower().endswith(suffix) and len(base) > len(suffix):
            base = base[:-len(suffix)]
            break
    return _UNSAFE.sub("-", base).strip("-.")[:MAX_STEM_CHARS].strip("-.")


def case_file_name(k, model_names, drive_names):
    """The file name of case `k` (1-based; models outer, drives inner) of a sweep.

    Parameters
    ----------
    k : int
        Case number, 1 to ``len(model_names) * len(drive_names)``.
    model_names, drive_names : sequence of str
        The sweep's models' and drives' names (``SweepResult.settings["models"]`` and
        ``["drives"]``).

    Returns
    -------
    str
        ``case-<k>-<stem>.csv``: the drive's stem with one model, the model's with one
        drive, else ``<model stem>-<drive stem>``; ``case-<k>.csv`` when the stem is
        empty.

    Raises
    ------
    ValueError
        If `k` is not a case number of these models and drives.
    """
    n_m, n_d = len(model_names), len(drive_names)
    if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= n_m * n_d:
        raise ValueError(f"case number {k!r} is not in 1..{n_m * n_d} "
                         f"({n_m} model(s) x {n_d} drive(s))")
    m, d = name_stem(model_names[(k - 1) // n_d]), name_stem(drive_names[(k - 1) % n_d])
    parts = [d] if n_m == 1 else [m] if n_d == 1 else [m, d]
    stem = "-".join(p for p in parts if p)
    return f"case-{k}-{stem}.csv" if stem else f"case-{k}.csv"


def case_file_names(result):
    """The file name of every case of a sweep.

    Parameters
    ----------
    result : planner.sweep.SweepResult

    Returns
    -------
    dict of str to str
        Case label -> file name (:func:`case_file_name`), in case order; unique.
    """
    st = result.settings
    return {label: case_file_name(k, st["models"], st["drives"])
            for k, label in enumerate(st["cases"], start=1)}


def write_sweep(result, out_dir, *, units="SI", overwrite=False):
    """Write a sweep's ranking, its cases' tables and its summary.

    Parameters
    ----------
    result : planner.sweep.SweepResult
    out_dir : str or path
        Output folder (created if missing).
    units : {"SI", "imperial"}
        Unit system of the metric values in the CSV files.
    overwrite : bool
        Replace existing files.

    Returns
    -------
    list of pathlib.Path
        ``ranking.csv`` (:func:`planner.report.ranking.write_predictions_csv` of
        ``result.table``), a CSV per case (:func:`case_file_names`, the case's table),
        with the shock-velocity histograms each case's beside it
        (``case-1-track_histograms.csv``, :func:`planner.histograms.histograms_path`),
        and ``sweep.toml``: ``format``, ``baseline``, ``objective``, ``best``,
        ``cases`` (``label`` and ``file``), ``combine``, ``n_candidates``,
        ``n_screened``, ``n_simulated``, ``top_share``, ``scheduler``, ``n_workers``,
        ``seconds``, ``screen_setups_per_s``, ``simulate_setups_per_s`` and
        ``spearman`` (screening against time domain over the simulated setups).

    Raises
    ------
    FileExistsError
        If a file exists and `overwrite` is false.
    ValueError, PlannerError
        As :func:`planner.report.ranking.write_predictions_csv`.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = [write_predictions_csv(result.table, out / "ranking.csv", units=units,
                                     overwrite=overwrite)]
    files = case_file_names(result)
    for label, table in result.cases.items():
        written.append(write_predictions_csv(table, out / files[label], units=units,
                                             overwrite=overwrite))
        if result.histograms.get(label) is not None:
            written.append(write_histograms_csv(result.histograms[label],
                                                histograms_path(out / files[label]),
                                                units=units, overwrite=overwrite))
    st = result.settings
    summary = {"format": SWEEP_FORMAT, "baseline": result.baseline,
               "objective": result.objective.name, "best": result.best,
               "cases": [{"label": lab, "file": files[lab]} for lab in st["cases"]],
               "combine": st["combine"], "n_candidates": st["n_candidates"],
               "n_screened": st["n_screened"], "n_simulated": int(len(result.table)),
               "top_share": float(st["top_share"]), "scheduler": st["scheduler"],
               "n_workers": st["n_workers"], "seconds": st["seconds"],
               "screen_setups_per_s": st["screen_setups_per_s"],
               "simulate_setups_per_s": st["simulate_setups_per_s"],
               "spearman": result.agreement["spearman"]}
    atomic_write_toml(out / "sweep.toml", summary, overwrite=True)
    written.append(out / "sweep.toml")
    return written
