"""``shockplan predict``: metrics of every setup of a setups CSV (spec's predictions CSV)."""

from __future__ import annotations

from planner.cli.common import (add_prediction_inputs, bump_stop_library, check_out,
                                histogram_options, read_inputs, show_progress, warn_inventory)

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``predict`` to `subparsers`."""
    sp = subparsers.add_parser("predict", help="predict every setup of a setups CSV")
    add_prediction_inputs(sp, out_help="predictions CSV")
    sp.add_argument("--setups", required=True, help="setups CSV")
    sp.set_defaults(func=run)
    return sp


def run(args):
    """``shockplan predict``: metrics of every setup of a setups CSV (spec's predictions CSV)."""
    from ident.data.files import check_output
    from planner.histograms import histograms_path, write_histograms_csv
    from planner.options import ElementOptions, LoopOptions
    from planner.predict import predict_setups
    from planner.report import write_predictions_csv
    from planner.setups import read_setups

    check_out(args)
    model, drive, library = read_inputs(args)
    hist = histogram_options(args)
    hist_path = histograms_path(args.out)
    if hist is not None:
        check_output(hist_path, overwrite=args.overwrite)
    stops = bump_stop_library(args, model)
    setups = read_setups(args.setups, library, stops, units=args.units)
    warn_inventory(setups, library)
    pred = predict_setups(model, drive, setups, library,
                          loop=LoopOptions(oversample=args.oversample, histograms=hist),
                          elements=ElementOptions(use_model=not args.no_elements,
                                                  bump_stops=stops),
                          progress=show_progress(args))
    write_predictions_csv(pred.table, args.out, units=args.units, overwrite=args.overwrite)
    wrote = str(args.out)
    if pred.histograms is not None:
        write_histograms_csv(pred.histograms, hist_path, units=args.units,
                             overwrite=args.overwrite)
        wrote += f" and {hist_path}"
    print(f"predicted {len(setups)} setups on drive '{drive.name}' ({drive.duration_s:g} s): "
          f"wrote {wrote} ({args.units})")
    for line in pred.element_lines():
        print(line)
    return 0
