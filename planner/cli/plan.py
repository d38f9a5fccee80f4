"""``shockplan plan``: the next rig runs (optimal experiment design) and the run sheet."""

from __future__ import annotations

import textwrap
from pathlib import Path

from planner.cli.common import (UNITS_OF_DRIVES, add_units, check_out, element_choices,
                                load_vehicle, output_units)
from planner.text import format_table

__all__ = ["add_parser", "run", "vehicle_third"]


def add_parser(subparsers):
    """Add ``plan`` to `subparsers`."""
    pl = subparsers.add_parser("plan", help="the next rig runs (optimal experiment design) "
                               "and the rig-day run sheet")
    pl.add_argument("--vehicle", help="before rig day: the known car, a vehicle TOML or "
                    "'paper' (give this or --model)")
    pl.add_argument("--model", help="between runs: the model identified so far (.npz; give "
                    "this and --session, or --vehicle)")
    pl.add_argument("--session", help="the session the model came from (with --model)")
    pl.add_argument("--shocks", required=True, help="the crate: shock library TOML")
    pl.add_argument("--budget-min", type=float, required=True,
                    help="rig time for the plan [min], swaps included")
    pl.add_argument("--criterion", choices=["d", "a", "decision"], default="d",
                    help="D-optimal (d, default), A-optimal (a), or the ranking's decisions "
                    "(decision)")
    pl.add_argument("--objective", help="objective TOML for the decision criterion and the "
                    "predictions (default: the built-in 'grip and platform')")
    pl.add_argument("--drive", action="append", help="the team's drive for the decision "
                    "criterion and the validation runs; repeatable (default: a 120 s "
                    "synthetic track drive of the car)")
    pl.add_argument("--rig-costs", metavar="RIG.toml", help="the rig's time costs (rig TOML, "
                    "docs/formats.md): swap_min, run_overhead_min [min], click_change_s [s] "
                    "(default: 6 min a changed corner, 20 s an adjuster turned, no overhead)")
    pl.add_argument("--baseline", help="the car's setup at the start: one shock id or "
                    "LF,RF,LR,RR (default: the session's baseline, or the crate's first shock)")
    pl.add_argument("--validate", type=int, default=0,
                    help="validation runs of the current best setups on --drive (default "
                    "%(default)s)")
    pl.add_argument("--baseline-every", type=int, default=0,
                    help="repeat the baseline after every this many runs, for drift (default "
                    "%(default)s: never)")
    add_units(pl, "units of the drive files read and written", default=None,
              default_text=UNITS_OF_DRIVES + "; without --drive, the session's or else the "
              "crate's (--shocks)")
    pl.add_argument("--try-heave", action="append", metavar="AXLE=ID,ID",
                    help="candidate runs swap the heave damper at AXLE (front or rear) for "
                    "each of these crate ids ('none' for none); repeatable (a model with "
                    "third elements, --model; default: no heave damper swaps)")
    pl.add_argument("--try-roll", action="append", metavar="AXLE=ID,ID",
                    help="as --try-heave, for the roll dampers (default: no roll damper "
                    "swaps)")
    pl.add_argument("--third", action="append", metavar="ELEMENT=ID",
                    help="with --vehicle: the baseline's third-element dampers, as a session "
                    "run's third (ELEMENT heave_front, heave_rear, roll_front or roll_rear, "
                    "each the vehicle TOML's third_elements declares; ID a crate id or "
                    "'none'); repeatable or comma-separated (default: none; needed when the "
                    "vehicle declares third_elements)")
    pl.add_argument("--heave-springs", action="append", metavar="AXLE=ID",
                    help="with --vehicle: the baseline's heave springs, as a run's "
                    "heave_springs (AXLE front or rear; ID in --bump-stops or 'none'); "
                    "repeatable or comma-separated (default: none)")
    pl.add_argument("--heave-packers", action="append", metavar="AXLE=LENGTH",
                    help="with --vehicle: packers at the heave springs, as a run's "
                    "heave_packers (e.g. front=2mm; a bare number in --units); repeatable "
                    "(default: none)")
    pl.add_argument("--bump-stops", help="with --heave-springs: the bump-stop library TOML "
                    "holding the heave springs (default: none)")
    pl.add_argument("--out", required=True, help="output folder")
    pl.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    pl.set_defaults(func=run)
    return pl


def run(args):
    """``shockplan plan``: the next rig runs (optimal experiment design) and the run sheet."""
    from ident.data.drive import read_drive
    from ident.identify.model import load_model
    from ident.data.session import read_session
    from ident.models.library import read_shock_library
    from planner.design import CandidateOptions, ScheduleOptions, design_experiment
    from planner.dyno.check import library_units
    from planner.objective import default_objective, read_objective
    from planner.rig_spec import read_rig
    from planner.testplan import write_plan

    out = Path(args.out)
    check_out(args, folder=True)
    if (args.vehicle is None) == (args.model is None):
        raise ValueError("give either --vehicle (before rig day: the known car, a vehicle TOML "
                         "or 'paper') or --model with --session (between runs)")
    session = None
    if args.model is not None:
        if args.session is None:
            raise ValueError("--model needs --session: the runs the model was identified from "
                             "are the plan's prior information")
        model = load_model(args.model)
        session = read_session(args.session)
    else:
        model = load_vehicle(None if args.vehicle == "paper" else args.vehicle)
    library = read_shock_library(args.shocks)
    objective = default_objective() if args.objective is None else read_objective(args.objective)
    drives = [read_drive(d, units=args.units) for d in args.drive] if args.drive else None
    # without --units and drives: the session's unit system, else the crate's (the project's)
    output_units(args, drives, fallback=session.units if session is not None
                 else library_units(args.shocks))
    rig = read_rig(args.rig_costs) if args.rig_costs else None
    car3, bump_stops = vehicle_third(args, model, library)
    third_dampers = element_choices(args).get("vary_third")
    if third_dampers and getattr(model, "third", None) is None and car3 is None:
        raise ValueError("--try-heave/--try-roll need a car with third elements: plan between "
                         "runs with --model (identified from a session that declares "
                         "third_elements) and --session, or with --vehicle (a vehicle TOML "
                         "declaring third_elements) and --third")
    plan = design_experiment(model, library, budget_min=args.budget_min,
                             criterion=args.criterion, session=session, objective=objective,
                             baseline=args.baseline, drives=drives, rig=rig,
                             candidates=CandidateOptions(third=car3, bump_stops=bump_stops,
                                                         third_dampers=third_dampers),
                             schedule=ScheduleOptions(baseline_every=args.baseline_every,
                                                      n_validation=args.validate))
    files = write_plan(plan, out, units=args.units, overwrite=args.overwrite)
    t = plan.table()
    rows = [(n, r["name"], f"{r['start_min']:.1f}", f"{r['duration_s'] / 60:.1f}", r["purpose"],
             "/".join(r[c] for c in ("LF", "RF", "LR", "RR")), r["changed"] or "-",
             f"{100 * r['share']:.0f} %") for n, r in t.iterrows()]
    print(f"planned {len(t)} runs in {plan.total_min:.1f} of {plan.budget_min:g} min "
          f"(criterion {plan.criterion}; cvxpy {plan.solver['status']} in "
          f"{plan.solver['solve_s']:.1f} s; {plan.solver['n_candidates']} candidate runs)")
    print(format_table(rows, ["run", "name", "start min", "min", "purpose", "LF/RF/LR/RR",
                            "changed", "share"]))
    for k, line in enumerate(plan.rationale):
        print(textwrap.fill(line, 100, initial_indent="why: " if k == 0 else "     ",
                            subsequent_indent="     ", break_on_hyphens=False))
    print("wrote " + ", ".join(str(p) for p in files.values()))
    return 0


def _pairs(items, flag, example):
    """``KEY=VALUE`` pairs of a repeatable, comma-separated option, as a dict."""
    out = {}
    for item in items or ():
        for part in item.split(","):
            key, sep, value = part.partition("=")
            if not sep or not key.strip() or not value.strip():
                raise ValueError(f"{flag} {item!r}: write KEY=VALUE pairs, e.g. {flag} {example}")
            out[key.strip()] = value.strip()
    return out


def vehicle_third(args, model, library):
    """The baseline's third elements of ``plan --vehicle`` (``--third``, ``--heave-springs``,
    ``--heave-packers``, ``--bump-stops``) on the vehicle TOML's ``third_elements``.

    Parameters
    ----------
    args : argparse.Namespace
    model : object
        The model read: a ``VehicleParams`` (``--vehicle``) or an identified model.
    library : ShockLibrary
        The crate (``--shocks``): the dampers' ids.

    Returns
    -------
    car : ident.data.third.CarThird or None
        None for ``--model`` or a vehicle without third elements.
    bump_stops : ident.models.bumpstops.BumpStopLibrary or None

    Raises
    ------
    ValueError
        The options with ``--model``, on a vehicle without ``third_elements``, a vehicle with
        them but no ``--third``, an element left out or not declared, a damper not in the
        crate, a heave spring without ``--bump-stops`` or not in it (the file, the field and
        the fix named).
    """
    from ident.data.third import CarThird, ThirdElements, check_run_third
    from ident.models.bumpstops import read_bump_stops
    from planner.elements import parse_length

    given = any(getattr(args, k, None) for k in ("third", "heave_springs", "heave_packers",
                                                 "bump_stops"))
    if getattr(args, "vehicle", None) is None:
        if given:
            raise ValueError("--third/--heave-springs/--heave-packers/--bump-stops are the "
                             "baseline's third elements of a --vehicle; with --model they come "
                             "from the session's baseline run: drop them")
        return None, None
    where = "the paper car" if args.vehicle == "paper" else args.vehicle
    declared = dict(getattr(model, "third_elements", None) or {})
    third = _pairs(args.third, "--third", "heave_front=H1,roll_front=R1")
    springs = _pairs(args.heave_springs, "--heave-springs", "front=HS-F")
    packers = {a: parse_length(v, units=args.units or "SI", where=f"--heave-packers {a}")
               for a, v in _pairs(args.heave_packers, "--heave-packers", "front=2mm").items()}
    if not declared:
        if given:
            raise ValueError(f"{where}: no third_elements; --third, --heave-springs and "
                             "--heave-packers need the car's elements: add third_elements = "
                             "{ heave_front = 1.0, ... } (motion ratios) to the vehicle TOML, or "
                             "drop the options")
        return None, None
    missing = [e for e in declared if e not in third]
    if missing:
        example = ",".join(f"{e}=ID" for e in declared)
        raise ValueError(f"{where}: third_elements declares {', '.join(declared)} but the "
                         f"baseline's dampers of {', '.join(missing)} are not given; name each "
                         f"with --third {example} (a crate id of --shocks, or 'none')")
    undeclared = [e for e in third if e not in declared]
    if undeclared:
        raise ValueError(f"--third {undeclared[0]}: {where} does not declare {undeclared[0]} "
                         f"in third_elements (it declares {', '.join(declared)}); drop it or "
                         "add the element with its motion ratio to the vehicle TOML")
    if springs and not args.bump_stops:
        raise ValueError("--heave-springs: the heave springs' library is not known; give the "
                         "bump-stop library TOML with --bump-stops FILE")
    bump_stops = read_bump_stops(args.bump_stops) if args.bump_stops else None
    run = check_run_third(third, springs, packers, elements=ThirdElements(declared),
                          shocks=library, bump_stops=bump_stops,
                          where=f"plan --vehicle {where}: --third/--heave-springs",
                          library=f"--shocks {args.shocks}")
    return CarThird(ThirdElements(declared), run), bump_stops
