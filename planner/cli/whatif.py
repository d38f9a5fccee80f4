"""``shockplan whatif``: every setup under every perturbation; robust ranking, files."""

from __future__ import annotations

from pathlib import Path

from planner.cli.common import (MODEL_HELP, OBJECTIVE_HELP, UNITS_OF_DRIVES, add_element_options,
                                add_units, baseline_arg, bump_stop_library, check_out,
                                load_any_model, output_units, show_progress)

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``whatif`` to `subparsers`."""
    wi = subparsers.add_parser("whatif", help="what-if study: setups under spring, shock, "
                               "drive and vehicle changes; robust ranking")
    wi.add_argument("--model", required=True, help=MODEL_HELP)
    wi.add_argument("--drive", required=True, action="append",
                    help="drive file (CSV or Parquet); repeat for several drives")
    wi.add_argument("--shocks", required=True, help="the crate: shock library TOML")
    wi.add_argument("--perturb", required=True, help="perturbation TOML "
                    "(format = \"shockplan-whatif/1\")")
    src = wi.add_mutually_exclusive_group(required=True)
    src.add_argument("--setups", help="setups CSV (give this or --ranking)")
    src.add_argument("--ranking", help="a ranking CSV (shockplan rank's ranking.csv): its top "
                     "--top setups (give this or --setups)")
    wi.add_argument("--top", type=int, default=10,
                    help="setups taken from --ranking (default %(default)s)")
    wi.add_argument("--objective", help=OBJECTIVE_HELP)
    wi.add_argument("--baseline", help="baseline: a setup name, one shock id (all corners) "
                    "or four LF,RF,LR,RR (default: with --ranking the ranking's baseline, "
                    "with --setups the first setup)")
    wi.add_argument("--method", choices=["time", "screening"], default="time",
                    help="time domain (time, default, the reference) or frequency-domain "
                    "screening (screening)")
    wi.add_argument("--rank-tolerance", type=int, default=None,
                    help="places a rank may move before it counts as moved (default 1)")
    wi.add_argument("--fragile-share", type=float, default=None,
                    help="share of conditions with a moved rank that makes it fragile "
                    "(default 0.1)")
    add_units(wi, "units of the drive files and outputs", default=None,
              default_text=UNITS_OF_DRIVES)
    wi.add_argument("--oversample", type=int, default=2,
                    help="internal steps per sample (default %(default)s)")
    wi.add_argument("--scheduler", metavar="ADDRESS|local",
                    help="evaluate on Dask: a scheduler address (tcp://host:8786) or 'local' "
                    "for a cluster on this machine (default: this process; the same files "
                    "either way)")
    wi.add_argument("--workers", type=int, help="workers of a local cluster (default: cores)")
    add_element_options(wi)
    wi.add_argument("--out", required=True, help="output folder")
    wi.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    wi.set_defaults(func=run)
    return wi


def run(args):
    """``shockplan whatif``: every setup under every perturbation; robust ranking, files."""
    from ident.data.drive import read_drive
    from ident.models.library import read_shock_library
    from planner.objective import default_objective, read_objective
    from planner.options import ElementOptions, LoopOptions, RunOptions
    from planner.setups import read_setups
    from planner.whatif import (FRAGILE_SHARE, RANK_TOLERANCE, evaluate_whatif,
                                read_perturbations, whatif_baseline, write_whatif)

    out = Path(args.out)
    check_out(args, folder=True)
    model = load_any_model(args.model)
    library = read_shock_library(args.shocks)
    drives = [read_drive(d, units=args.units) for d in args.drive]
    output_units(args, drives)
    perturbations = read_perturbations(args.perturb)
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    stops = bump_stop_library(args, model)
    ranked = ()
    if args.setups:
        setups = read_setups(args.setups, library, stops, units=args.units)
    else:
        if args.top < 1:
            raise ValueError(f"--top must be at least 1, got {args.top}")
        ranked = read_setups(args.ranking, library, stops, units=args.units)
        setups = ranked[: args.top]
    # --baseline, else the ranking's own baseline (not its best setup), added if beyond --top
    baseline = whatif_baseline(baseline_arg(args, library, setups), ranking=args.ranking,
                               ranked=ranked)
    if baseline is None and objective.baseline is None:
        first = setups[0].name
        print(f"baseline: '{first}', the first setup of {args.setups or args.ranking} "
              "(give --baseline to score against another)")
    result = evaluate_whatif(
        model, drives, setups, library, perturbations, objective=objective, baseline=baseline,
        method=args.method, loop=LoopOptions(oversample=args.oversample),
        rank_tolerance=RANK_TOLERANCE if args.rank_tolerance is None else args.rank_tolerance,
        fragile_share=FRAGILE_SHARE if args.fragile_share is None else args.fragile_share,
        elements=ElementOptions(use_model=not args.no_elements, bump_stops=stops),
        run=RunOptions(scheduler=args.scheduler, n_workers=args.workers),
        progress=show_progress(args))
    used = {"model": args.model, "drive": ", ".join(map(str, args.drive))
            if isinstance(args.drive, (list, tuple)) else args.drive, "crate": args.shocks,
            "what-if": args.perturb}
    files = write_whatif(result, out, units=args.units, overwrite=args.overwrite, run=used)
    print(result.summary())
    print(f"wrote {len(files)} files to {out}: " + ", ".join(sorted(files)[:6])
          + (" ..." if len(files) > 6 else ""))
    return 0
