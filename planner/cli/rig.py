"""``shockplan rig simulate``: run a rig plan on the virtual rig, write a session."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ident.data.channels import RIG_KINDS
from ident.data.units import set_display_units
from planner.cli.common import add_units, check_out, load_vehicle, show_progress

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``rig`` and its command ``simulate`` to `subparsers`."""
    rig = subparsers.add_parser("rig", help="the virtual rig")
    rig_sub = rig.add_subparsers(dest="rig_command", required=True, help="the rig command")
    sim = rig_sub.add_parser("simulate", help="simulate a rig plan and write a rig session")
    sim.add_argument("--plan", help="rig plan TOML (default: the built-in plan, the paper's "
                     "identification experiment: 5 runs of 800 s at 100 Hz, imperial, 7-post)")
    sim.add_argument("--vehicle", help="vehicle TOML (default: the paper's Table 1 car)")
    sim.add_argument("--out", required=True, help="session folder to write")
    add_units(sim, "units of the written session", default=None,
              default_text="the plan's 'units'; imperial for the built-in plan")
    sim.add_argument("--format", choices=["csv", "parquet"], default="csv",
                     help="run file format (default %(default)s)")
    sim.add_argument("--duration", type=float, help="every run's duration [s] (default: the "
                     "plan's; 800 s in the built-in plan)")
    sim.add_argument("--noise", type=float, help="measurement noise of the response channels, "
                     "a fraction of each channel's RMS (default: the plan's 'noise'; 0 in the "
                     "built-in plan)")
    sim.add_argument("--input-noise", type=float, help="measurement noise of the recorded rig "
                     "inputs, a fraction of each input's RMS (default: the plan's "
                     "'input_noise'; 0 in the built-in plan)")
    sim.add_argument("--rig", choices=list(RIG_KINDS), help="the rig kind (default: the plan's "
                     "'rig'; 7-post for the built-in plan and for a plan that names none): "
                     "'7-post' and '8-post' have aero actuators; '4-post' has none and writes "
                     "runs without aero channels")
    sim.add_argument("--overwrite", action="store_true", help="replace an existing session folder")
    sim.set_defaults(func=run)
    return rig


def run(args):
    """``shockplan rig simulate``: run a rig plan on the virtual rig, write a session."""

    from ident.sim.virtual_rig import default_plan, read_rig_plan, simulate_session
    from ident.data.session import write_session

    check_out(args, folder=True)
    plan = default_plan() if args.plan is None else read_rig_plan(args.plan)
    if args.duration is not None:
        played = [r.name for r in plan.runs if r.drive is not None]
        if played:
            raise ValueError(
                f"--duration {args.duration:g}: the plan's run(s) {', '.join(played[:3])}"
                f"{' ...' if len(played) > 3 else ''} play drive files, whose length is the "
                "file's; --duration sets only generated drives: leave it out, or give a plan "
                "without drive files")
        plan = replace(plan, runs=tuple(replace(r, duration_s=args.duration) for r in plan.runs))
    if args.noise is not None:
        plan = replace(plan, noise=args.noise)
    if args.input_noise is not None:
        plan = replace(plan, input_noise=args.input_noise)
    if args.rig is not None:
        plan = replace(plan, rig=args.rig)
    vehicle = load_vehicle(args.vehicle)
    out = Path(args.out)
    set_display_units(args.units or plan.units)  # the session's unit system in its messages
    session = simulate_session(plan, vehicle, progress=show_progress(args))
    write_session(session, out, units=args.units or plan.units, run_format=args.format,
                  overwrite=args.overwrite)
    counts = [r.n_samples for r in session.runs]
    samples = (f"{counts[0]} samples each" if len(set(counts)) == 1 else
               f"{min(counts)}-{max(counts)} samples per run ({sum(counts)} in all)")
    real = []  # the real car of the plan (issue 25), said only when the plan has it
    if session.bump_stops is not None:
        fitted = sum(any(r.bump_stops.values()) for r in session.runs)
        real.append(f"bump stops on {fitted} of {len(session.runs)} runs")
    if session.static_corner_load_n is not None:
        real.append("static corner loads (the tires may lift off)")
    print(f"wrote rig session '{session.name}' to {out}: {len(session.runs)} runs, "
          f"{samples} at {session.fs_hz:g} Hz, vehicle '{vehicle.name}', "
          f"{plan.rig} rig ({len(session.rig_inputs)} rig inputs)"
          + "".join(f"; {x}" for x in real))
    return 0
