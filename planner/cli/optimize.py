"""``shockplan optimize``: the best damper curve per corner group, mapped to the crate."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from planner.cli.common import (MODEL_HELP, OBJECTIVE_HELP, UNITS_OF_DRIVES, add_element_options,
                                add_third_try_options, add_units, bump_stop_library, check_out,
                                element_choices, int_at_least, load_any_model, output_units,
                                packer_bounds, show_progress)

__all__ = ["add_parser", "run", "cli_wording", "scan_line", "OPTION_NAMES",
           "REFERENCE_VELOCITIES"]

#: The library's names of optimize's options -> the command's, for the library's messages
#: printed by the command ("raise max_iter" reads "raise --max-iter").
OPTION_NAMES = {"max_iter": "--max-iter", "n_starts": "--starts",
                "click_radius": "--click-radius"}

#: The shock velocities at which the optimal curves' forces are printed, per unit system:
#: round numbers in the units the project reads (about 0.05, 0.1 and 0.25 m/s).
REFERENCE_VELOCITIES = {"SI": (0.05, 0.1, 0.25), "imperial": (2.0, 4.0, 10.0)}


def cli_wording(message):
    """A library message (warning) worded for the command line: the options named as the
    command spells them (:data:`OPTION_NAMES`).

    Examples
    --------
    >>> cli_wording("score 0.9285): raise max_iter, or check the constraints")
    'score 0.9285): raise --max-iter, or check the constraints'
    """
    return re.sub(r"\b(" + "|".join(OPTION_NAMES) + r")\b",
                  lambda m: OPTION_NAMES[m.group(1)], str(message))


def scan_line(scan, source):
    """The summary's line on the scan (:meth:`planner.optimize.scan` ``summary()``): the
    counts, the best linear score, the best overall when it is of another kind, the time
    and where the optimum came from (`source`, in words)."""
    best = f"best linear {scan['linear_score']:.4f}"
    if scan["best"] == "linear":
        best = f"best {scan['score']:.4f}, a linear curve (no two-slope one scored better)"
    else:
        best += f", best {scan['best']} {scan['score']:.4f}"
    return (f"scan: {scan['n_screened']} linear and two-slope setups screened, "
            f"{scan['n_verified']} verified, {best} "
            f"({scan['screen_s'] + scan['verify_s']:.1f} s); the optimum is {source}")


def add_parser(subparsers):
    """Add ``optimize`` to `subparsers`."""
    opt = subparsers.add_parser("optimize", help="the best damper curve per corner group, "
                                "mapped to the crate")
    opt.add_argument("--model", required=True, help=MODEL_HELP)
    opt.add_argument("--drive", required=True, action="append",
                     help="drive file (CSV or Parquet); repeat for several drives")
    opt.add_argument("--shocks", required=True, help="the crate: shock library TOML")
    opt.add_argument("--objective", help=OBJECTIVE_HELP)
    opt.add_argument("--baseline", help="baseline shock id(s): one for all corners or "
                     "LF,RF,LR,RR (default: the crate's first shock)")
    opt.add_argument("--symmetry", choices=["left-right", "all", "none"], default="left-right",
                     help="a curve per axle (left-right, default), one for every corner (all), "
                          "or one per corner (none)")
    opt.add_argument("--constraints", help="curve constraints TOML (default: buildable race "
                     "shock bounds)")
    opt.add_argument("--drive-weights", help="weights of the drives, comma-separated, one per "
                     "--drive (default: equal)")
    opt.add_argument("--worst-case", action="store_true",
                     help="minimize the worst drive's score instead of the weighted sum "
                     "(default: the weighted sum)")
    opt.add_argument("--robust", action="store_true", help="hold the objective's limits "
                     "with the identified model's 95 %% intervals (default: nominal limits)")
    add_units(opt, "unit system of the drive files and outputs", default=None,
              default_text=UNITS_OF_DRIVES)
    opt.add_argument("--oversample", type=int, default=2,
                     help="internal steps per sample (default %(default)s)")
    opt.add_argument("--max-iter", type=int, default=80, help="IPOPT iterations "
                     "(default %(default)s)")
    opt.add_argument("--starts", type=int_at_least(1), default=2,
                     help="IPOPT starts: the scan's best curve, then the best of the other "
                     "kind (linear or two-slope), 10 iterations (default %(default)s)")
    opt.add_argument("--knots", choices=["quantiles", "fixed"], default="quantiles",
                     help="velocity knots of the curves: on the quantiles 25, 50, 75, 90, 99 %% "
                     "of the baseline's shock speeds on the drives, per side (quantiles, "
                     "default), or fixed at 0.025, 0.05, 0.1, 0.25, 0.5 m/s (fixed)")
    add_element_options(opt)
    opt.add_argument("--packers", action="append", metavar="GROUP=LO:HI",
                     help="optimize the packers of a corner group too, between LO and HI (the "
                     "drive's units or with a unit: front=0:4mm); needs bump stops (the "
                     "model's, or --bump-stops); repeatable (default: packers as the "
                     "baseline's)")
    opt.add_argument("--free-third", metavar="ELEMENT[,ELEMENT]",
                     help="a car with third elements: optimize these third dampers' curves "
                     "with the corner curves, e.g. heave_front,heave_rear (each within 1/3 "
                     "to 3 times the baseline damper's forces; written as OPT-<element>) "
                     "(default: none, the car's baseline third dampers)")
    add_third_try_options(opt, crate=True)
    opt.add_argument("--click-radius", type=int_at_least(1), default=2, metavar="K",
                     help="adjustable shocks: the click search moves one adjuster by 1..K "
                     "steps (default %(default)s)")
    opt.add_argument("--out", required=True, help="output folder")
    opt.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    opt.set_defaults(func=run)
    return opt


def free_third_arg(value):
    """``--free-third heave_front,heave_rear`` as a tuple of element names (checked)."""
    from ident.data.third import THIRD_ELEMENTS

    if not value:
        return ()
    names = tuple(v.strip() for v in value.split(",") if v.strip())
    bad = [n for n in names if n not in THIRD_ELEMENTS]
    if bad or not names:
        raise ValueError(f"--free-third {value!r}: {bad or 'no element'} is not a third "
                         f"element; give some of {', '.join(THIRD_ELEMENTS)}, comma-separated")
    return names


def run(args):
    """``shockplan optimize``: the best damper curve per corner group, mapped to the crate."""
    import warnings

    from ident.data.drive import read_drive
    from ident.models.library import read_shock_library
    from ident.data.units import format_quantity, from_si, to_si, unit_label
    from planner.objective import default_objective, read_objective
    from planner.options import ElementOptions, LoopOptions
    from planner.optimize import (
        DEFAULT_KNOTS_M_S,
        QUANTILE_KNOTS,
        CurveOptions,
        SolverOptions,
        optimize_curves,
        read_curve_constraints,
        write_optimum,
    )
    from planner.report.optimize import STATIONARY_FLAT, click_summary

    out = Path(args.out)
    check_out(args, folder=True)
    model = load_any_model(args.model)
    drives = [read_drive(d, units=args.units) for d in args.drive]
    output_units(args, drives)
    library = read_shock_library(args.shocks)
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    constraints = None if args.constraints is None else read_curve_constraints(args.constraints)
    weights = None
    if args.drive_weights:
        try:
            weights = [float(w) for w in args.drive_weights.split(",")]
        except ValueError:
            raise ValueError(f"--drive-weights {args.drive_weights!r}: give numbers separated "
                             "by commas, one per --drive") from None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        opt = optimize_curves(model, drives, library, objective=objective,
                              baseline=args.baseline,
                              curves=CurveOptions(symmetry=args.symmetry,
                                                  knots_m_s=(QUANTILE_KNOTS
                                                             if args.knots == "quantiles"
                                                             else DEFAULT_KNOTS_M_S),
                                                  free_third=free_third_arg(args.free_third)),
                              constraints=constraints, drive_weights=weights,
                              aggregate="worst" if args.worst_case else "sum",
                              robust=args.robust, loop=LoopOptions(oversample=args.oversample),
                              solver=SolverOptions(max_iter=args.max_iter, n_starts=args.starts,
                                                   click_radius=args.click_radius),
                              elements=ElementOptions(
                                  use_model=not args.no_elements,
                                  bump_stops=bump_stop_library(args, model),
                                  **element_choices(args)),
                              packers=packer_bounds(args), progress=show_progress(args))
    files = write_optimum(opt, library, out, units=args.units, overwrite=args.overwrite,
                          run={"model": args.model, "crate": args.shocks})
    t = opt.table
    s = opt.solver
    lines = [f"optimized {len(opt.curves)} curve(s) ({opt.space.symmetry}) on "
             f"{len(drives)} drive(s): IPOPT {s['status']} after {s['iterations']} iterations, "
             f"{s['n_eval']} closed-loop evaluations, {s['build_s'] + s['solve_s']:.1f} s",
             f"verified in the time domain (baseline {t.loc[opt.baseline.name, 'score']:.4f}): "
             f"{opt.verdict()}"]
    if opt.bump_stops is not None:
        lines.append("bump stops in the loop and the verification"
                     + (", packers chosen: " + ", ".join(
                         f"{g} {format_quantity(p, 'displacement', args.units, small=True)}"
                         for g, p in opt.packers_m.items()) if opt.packers_m else ""))
    if opt.third_curves:
        lines.append("third dampers optimized with the corner curves: "
                     + ", ".join(f"{e} (OPT-{e})" for e in opt.third_curves))
    heave_packers = {g: p for g, p in opt.packers_m.items() if g.startswith("heave_")}
    if heave_packers and opt.bump_stops is None:
        lines.append("heave packers chosen (on the baseline's): " + ", ".join(
            f"{g} {format_quantity(p, 'displacement', args.units, small=True)}"
            for g, p in heave_packers.items()))
    scan = opt.settings.get("scan")
    if scan:
        source = {"scan": "the scan's best curve",
                  "iterate": "IPOPT's best feasible iterate"}.get(s.get("source"),
                                                                   "IPOPT's solution")
        lines.append(scan_line(scan, source))
    crate_third = opt.settings.get("crate_third")
    if crate_third:
        third = [c for c in t.columns if c.startswith(("heave_", "roll_"))]
        lines.append("the crate's best searched with the third-element choices "
                     + ", ".join(f"{k}={','.join(v)}" for k, v in crate_third.items())
                     + f": {opt.crate_best} ("
                     + ", ".join(f"{c} {t.loc[opt.crate_best, c]}" for c in third) + ")")
    close = t[t["kind"] == "closest"]
    if len(close):
        lines.append("closest crate setups: " + ", ".join(
            f"{n} ({r['score']:.4f}, distance {r['distance']:.2f})" for n, r in close.iterrows()))
    if opt.stationarity is not None and len(opt.stationarity):
        st = opt.stationarity
        change = float(st.relative_change.min())
        # a move that changes the score by less than the model's accuracy says nothing
        flat = st.groupby("variable")["relative_change"].apply(
            lambda r: bool(np.all(np.abs(r) < STATIONARY_FLAT)))
        note = ""
        if flat.any():
            note = (f"; {int(flat.sum())} of {len(flat)} variables change it by less than "
                    f"{100 * STATIONARY_FLAT:g} % either way (flat: the score hardly depends "
                    "on them)")
        lines.append("stationarity: every knot force moved by +-5 % " + (
            f"worsens the score (by {100 * change:.4f} % at least)" if change >= 0 else
            f"improves the score by at most {-100 * change:.4f} %") + note)
    ref = REFERENCE_VELOCITIES[args.units]  # round numbers in the project's units
    for sid, m in opt.shocks.items():
        vals = ", ".join(
            f"{from_si(m.force(to_si(v, 'velocity', args.units)), 'force', args.units):.0f}/"
            f"{from_si(m.force(-to_si(v, 'velocity', args.units)), 'force', args.units):.0f}"
            for v in ref)
        lines.append(f"{sid}: bump/rebound force at {'/'.join(f'{v:g}' for v in ref)} "
                     f"{unit_label('velocity', args.units)}: {vals} "
                     f"{unit_label('force', args.units)}")
    lines += click_summary(opt)
    for w in caught:
        lines.append(f"warning: {cli_wording(w.message)}")
    lines.append("wrote " + ", ".join(str(p) for p in files.values()))
    print("\n".join(lines))
    return 0
