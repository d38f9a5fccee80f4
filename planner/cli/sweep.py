"""``shockplan sweep``: screen a large enumeration on several drives and models (Dask),
simulate the best share, rank."""

from __future__ import annotations

from planner.cli.common import (OBJECTIVE_HELP, UNITS_OF_DRIVES, add_element_options,
                                add_histogram_option, add_try_options, add_units, baseline_arg,
                                bump_stop_library, check_out, element_choices,
                                histogram_options, int_at_least, load_any_model, output_units,
                                parse_fixed, share, show_progress)

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``sweep`` to `subparsers`."""
    from planner.click_settings import add_click_arguments

    sw = subparsers.add_parser("sweep", help="screen a large enumeration of setups on several "
                               "drives and models (on a Dask cluster), simulate and rank the "
                               "best share")
    sw.add_argument("--model", required=True, action="append",
                    help="identified model (.npz), a vehicle TOML or 'paper' (repeatable)")
    sw.add_argument("--drive", required=True, action="append",
                    help="drive file (CSV or Parquet; repeatable)")
    sw.add_argument("--shocks", required=True, help="the crate: shock library TOML")
    add_units(sw, "unit system of the drive files and of the outputs", default=None,
              default_text=UNITS_OF_DRIVES)
    sw.add_argument("--setups", help="setups CSV (default: enumerate from the library)")
    sw.add_argument("--symmetry", choices=["left-right", "all", "none"], default="none",
                    help="enumeration: one shock per axle (left-right), one for every corner "
                    "(all) or one per corner (default %(default)s: every 4-corner combination)")
    sw.add_argument("--axles", choices=["independent", "same"], default="independent",
                    help="enumeration: the rear corners' shocks chosen on their own "
                    "(independent, default) or the front corners' (same)")
    sw.add_argument("--fixed", action="append", metavar="CORNER=ID",
                    help="fix a corner's shock (repeatable; default: none fixed)")
    sw.add_argument("--only", help="comma-separated shock ids to consider (default: every "
                    "shock of the library)")
    add_click_arguments(sw)
    sw.add_argument("--ignore-inventory", action="store_true",
                    help="enumerate setups beyond the crate's counts, ranked infeasible "
                    "(default: only setups the crate can build)")
    sw.add_argument("--baseline", help="baseline: a setup of --setups by name, one shock id "
                    "(all corners) or four LF,RF,LR,RR (default: the first setup)")
    sw.add_argument("--objective", help=OBJECTIVE_HELP)
    sw.add_argument("--simulate-share", type=share, default=0.01, metavar="SHARE",
                    help="share of the screened setups simulated in the time domain, the best "
                    "by screening (default %(default)s)")
    sw.add_argument("--simulate", type=int_at_least(1), metavar="N",
                    help="simulate the best N in the time domain instead of --simulate-share "
                    "(default: --simulate-share)")
    sw.add_argument("--combine", choices=["mean", "worst"], default="mean",
                    help="a setup's score over the cases (default %(default)s)")
    sw.add_argument("--chunk-size", type=int, default=20000,
                    help="setups per screening task (default %(default)s)")
    sw.add_argument("--scheduler", default="local", metavar="ADDRESS|local|none",
                    help="a Dask scheduler address (tcp://host:8786), 'local' for a cluster on "
                    "this machine (default) or 'none' for one process")
    sw.add_argument("--workers", type=int, help="workers of a local cluster (default: cores)")
    sw.add_argument("--oversample", type=int, default=2,
                    help="internal steps per sample of the shock loop (default %(default)s)")
    add_element_options(sw)
    add_try_options(sw)
    add_histogram_option(sw)
    sw.add_argument("--out", required=True, help="output folder")
    sw.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    sw.set_defaults(func=run)
    return sw


def run(args):
    """``shockplan sweep``: screen a large enumeration on several drives/models (Dask), simulate
    the best share, rank; writes ranking.csv, one CSV per case and sweep.toml."""
    from ident.data.drive import read_drive
    from ident.models.library import read_shock_library
    from planner.objective import default_objective, read_objective
    from planner.report.sweep_files import write_sweep
    from planner.click_settings import clicks_option, split_shock_ids
    from planner.options import ElementOptions, LoopOptions, RunOptions
    from planner.setups import read_setups
    from planner.sweep import sweep_setups

    check_out(args, folder=True)
    models = {m: load_any_model(m) for m in dict.fromkeys(args.model)}
    drives = {d: read_drive(d, units=args.units) for d in dict.fromkeys(args.drive)}
    output_units(args, list(drives.values()))
    library = read_shock_library(args.shocks)
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    setups, constraints = None, None
    clicks = clicks_option(args)
    if args.setups:
        setups = read_setups(args.setups, library)
    else:
        constraints = {"symmetry": args.symmetry, "axles": args.axles,
                       "fixed": parse_fixed(args.fixed) or None,
                       "respect_inventory": not args.ignore_inventory, "clicks": clicks}
        if args.only:
            constraints["shocks"] = split_shock_ids(args.only)
    baseline = baseline_arg(args, library, setups)
    scheduler = args.scheduler
    result = sweep_setups(models, drives, library, setups=setups, constraints=constraints,
                          objective=objective, baseline=baseline, top_share=args.simulate_share,
                          top=args.simulate, combine=args.combine,
                          loop=LoopOptions(oversample=args.oversample,
                                           histograms=histogram_options(args)),
                          elements=ElementOptions(use_model=not args.no_elements,
                                                  bump_stops=bump_stop_library(args, None),
                                                  **element_choices(args)),
                          run=RunOptions(scheduler=scheduler, n_workers=args.workers,
                                         chunk_size=args.chunk_size),
                          progress=show_progress(args))
    written = write_sweep(result, args.out, units=args.units, overwrite=args.overwrite)
    print(result.summary())
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
