"""``shockplan rank``: rank setups (screen, simulate the best, score) and write a report."""

from __future__ import annotations

from pathlib import Path

from planner.cli.common import (OBJECTIVE_HELP, add_prediction_inputs, add_try_options,
                                baseline_arg, bump_stop_library, check_out, element_choices,
                                histogram_options, int_at_least, parse_fixed, read_inputs,
                                section_windows, show_progress)

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``rank`` to `subparsers`."""
    from planner.click_settings import add_click_arguments

    sp = subparsers.add_parser("rank", help="rank shock setups and write a report")
    add_prediction_inputs(sp, out_help="output folder")
    sp.add_argument("--setups", help="setups CSV (default: enumerate from the library)")
    sp.add_argument("--symmetry", choices=["left-right", "all", "none"],
                    default="left-right",
                    help="enumeration: one shock per axle (left-right, default), one "
                    "for every corner (all), or one per corner (none)")
    sp.add_argument("--axles", choices=["independent", "same"], default="independent",
                    help="enumeration: the rear corners' shocks chosen on their own "
                    "(independent, default) or the front corners' (same)")
    sp.add_argument("--fixed", action="append", metavar="CORNER=ID",
                    help="fix a corner's shock (repeatable; default: none fixed)")
    sp.add_argument("--only", help="comma-separated shock ids to consider (default: "
                    "every shock of the library)")
    add_click_arguments(sp)
    sp.add_argument("--baseline", help="baseline: a setup of --setups by name, one "
                    "shock id (all corners) or four LF,RF,LR,RR (default: the first "
                    "setup)")
    sp.add_argument("--objective", help=OBJECTIVE_HELP)
    sp.add_argument("--simulate", type=int_at_least(1), default=40, metavar="N",
                    help="the best N setups by screening simulated in the time "
                    "domain (default %(default)s; the baseline and a spread of the "
                    "others are checked besides)")
    add_try_options(sp)
    sp.add_argument("--log", action="append", metavar="LOG", default=None,
                    help="track log(s) whose shock-velocity histogram is the target: each "
                    "setup's distance from it per corner, histogram_distance_XX (total "
                    "variation, 0-1), which the objective may weight (repeatable; default: "
                    "none)")
    sp.add_argument("--log-map", metavar="MAP.toml", default=None,
                    help="channel map of the --log files (as drive from-track --map; "
                    "default: their columns are canonical names)")
    sp.add_argument("--no-uncertainty", action="store_true",
                    help="skip the Monte Carlo intervals (default: computed)")
    sp.add_argument("--scheduler", metavar="ADDRESS|local",
                    help="screen on Dask: a scheduler address (tcp://host:8786) or "
                    "'local' for a cluster on this machine (default: this process; "
                    "the same ranking either way)")
    sp.add_argument("--workers", type=int,
                    help="workers of a local cluster (default: cores)")
    sp.add_argument("--section", action="append", metavar="NAME=START:STOP", default=None,
                    help="also rank on this time window [s] of the drive, simulated alone as "
                    "its drive file ('drive section') would be: sections.csv, the workbook's "
                    "sheet 'sections' (repeatable; default: none)")
    sp.add_argument("--laps", metavar="T0,T1,...", default=None,
                    help="lap-start times [s]: also rank on each lap, as --section "
                    "lapN=Tk:Tk+1 (default: none)")
    sp.set_defaults(func=run)
    return sp


def run(args):
    """``shockplan rank``: rank setups (screen, simulate the best, score) and write a report."""
    from planner.objective import default_objective, read_objective
    from planner.click_settings import MAX_CLICK_SETUPS, clicks_option, split_shock_ids
    from planner.options import ElementOptions, LoopOptions, RunOptions
    from planner.rank import rank_setups
    from planner.report import write_ranking
    from planner.setups import read_setups

    check_out(args, folder=True)
    sections = section_windows(args, "rank", option_prefix="rank ")
    model, drive, library = read_inputs(args)
    if sections:  # a window beyond the drive: said before anything is simulated
        from planner.trackdrive import check_sections

        check_sections(sections, n_samples=drive.n_samples, fs_hz=drive.fs_hz,
                       of=f"the drive '{drive.name}'", where="rank --section")
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    setups, constraints = None, None
    clicks = clicks_option(args)
    stops = bump_stop_library(args, model)
    if args.setups:
        setups = read_setups(args.setups, library, stops, units=args.units)
    else:
        constraints = {"symmetry": args.symmetry, "axles": args.axles,
                       "fixed": parse_fixed(args.fixed) or None}
        if clicks is not None:  # screened, then the best --simulate in the time domain
            constraints.update(clicks=clicks, max_setups=MAX_CLICK_SETUPS)
        if args.only:
            constraints["shocks"] = split_shock_ids(args.only)
    baseline = baseline_arg(args, library, setups)
    elements = ElementOptions(use_model=not args.no_elements, bump_stops=stops,
                              **element_choices(args))
    out = Path(args.out)
    hist = histogram_options(args)
    target = None
    if args.log:
        from ident.data.tracklog import read_track_log
        from planner.errors import PlannerError
        from planner.histograms import logged_histograms

        if hist is None:
            raise PlannerError("rank: --log compares histograms; drop --histogram-bins none")
        logs = [read_track_log(p, channel_map=args.log_map) for p in args.log]
        target = logged_histograms(logs, hist, name="logged")
    ranking = rank_setups(model, drive, library, setups=setups, constraints=constraints,
                          objective=objective, baseline=baseline, top=args.simulate,
                          uncertainty=not args.no_uncertainty,
                          loop=LoopOptions(oversample=args.oversample, histograms=hist),
                          histogram_target=target,
                          elements=elements,
                          run=RunOptions(scheduler=args.scheduler, n_workers=args.workers),
                          progress=show_progress(args))
    by_section = None
    if sections:
        from planner.section_ranking import rank_sections

        by_section = rank_sections(ranking, model, drive, library, sections=sections,
                                   loop=LoopOptions(oversample=args.oversample),
                                   elements=elements, progress=show_progress(args))
    used = {"model": args.model, "drive": f"{args.drive} ({drive.n_samples / drive.fs_hz:g} s "
            f"at {drive.fs_hz:g} Hz)", "crate": args.shocks}
    files = write_ranking(ranking.table, out, units=args.units, objective=objective,
                          baseline=ranking.baseline, overwrite=args.overwrite,
                          sections=None if by_section is None else by_section.table, run=used,
                          histograms=None if ranking.histograms is None
                          else ranking.histograms.table(args.units))
    write_ranking_screening = out / "screening.csv"
    from planner.report import write_predictions_csv

    write_predictions_csv(ranking.screening, write_ranking_screening, units=args.units,
                          overwrite=args.overwrite)
    written = list(files.values()) + [write_ranking_screening]
    if ranking.histograms is not None:
        from planner.histograms import HISTOGRAMS_FILE, write_histograms_csv

        written.append(write_histograms_csv(ranking.histograms, out / HISTOGRAMS_FILE,
                                            units=args.units, overwrite=args.overwrite))
    print(ranking.summary())
    if by_section is not None:
        print(by_section.summary())
    print("wrote " + ", ".join(str(p) for p in written))
    return 0

