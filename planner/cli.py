"""The ``shockplan`` command line: a thin layer over :mod:`ident` and :mod:`planner`.

Every command is a call into the library; this module parses arguments,
prints summaries and turns the project's errors into one-line messages.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

__all__ = ["main", "build_parser"]

log = logging.getLogger("shockplan")


def _fmt_table(rows, headers):
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(headers)]
    line = "  ".join(str(h).rjust(w) for h, w in zip(headers, widths))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(str(c).rjust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(out)


def _load_vehicle(path):
    from ident.vehicle import example_vehicle, read_vehicle

    return example_vehicle() if path is None else read_vehicle(path)


def cmd_rig_simulate(args):
    """``shockplan rig simulate``: run a rig plan on the virtual rig, write a session."""
    from dataclasses import replace

    from ident.rig import default_plan, read_rig_plan, simulate_session
    from ident.session import write_session

    plan = default_plan() if args.plan is None else read_rig_plan(args.plan)
    if args.duration is not None:
        plan = replace(plan, runs=tuple(replace(r, duration_s=args.duration) for r in plan.runs))
    if args.noise is not None:
        plan = replace(plan, noise=args.noise)
    vehicle = _load_vehicle(args.vehicle)
    out = Path(args.out)
    from ident._io import check_can_write

    if out.exists() and any(out.iterdir()) and not args.overwrite:
        check_can_write(out, overwrite=False)
    session = simulate_session(plan, vehicle, progress=not args.quiet)
    write_session(session, out, units=args.units or plan.units, run_format=args.format,
                  overwrite=args.overwrite)
    print(f"wrote rig session '{session.name}' to {out}: {len(session.runs)} runs, "
          f"{session.runs[0].n_samples} samples at {session.fs_hz:g} Hz, vehicle '{vehicle.name}'")
    return 0


def cmd_vehicle_modes(args):
    """``shockplan vehicle modes``: natural frequencies of a vehicle."""
    from ident.units import to_si
    from ident.vehicle import modal_summary

    vehicle = _load_vehicle(args.vehicle)
    damping = None
    if args.damping is not None:
        damping = to_si(args.damping, "damping", args.units)
    s = modal_summary(vehicle, damping_n_s_m=damping)
    rows = [(lab, f"{u:.3f}", f"{d:.3f}", f"{z:.3f}")
            for lab, u, d, z in zip(s.labels, s.undamped_hz, s.damped_hz, s.damping_ratio)]
    print(f"vehicle '{vehicle.name}', shocks {s.damping_n_s_m[0]:.1f} N/(m/s)")
    print(_fmt_table(rows, ["mode", "undamped Hz", "damped Hz", "zeta"]))
    return 0


def cmd_demo(args):
    """``shockplan demo``: the main job end to end on the built-in example."""
    from planner.demo import run_demo

    summary = run_demo(Path(args.out), overwrite=args.overwrite, progress=not args.quiet)
    print(summary)
    return 0


def build_parser():
    """Build the argument parser (exposed for documentation and tests)."""
    p = argparse.ArgumentParser(
        prog="shockplan",
        description="Shock-absorber selection planner for 7-post and 8-post shaker rigs.")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    sub = p.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="run the whole job on the built-in example car")
    demo.add_argument("--out", default="shockplan-demo", help="output folder (default %(default)s)")
    demo.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    demo.set_defaults(func=cmd_demo)

    rig = sub.add_parser("rig", help="the virtual rig")
    rig_sub = rig.add_subparsers(dest="rig_command", required=True)
    sim = rig_sub.add_parser("simulate", help="simulate a rig plan and write a rig session")
    sim.add_argument("--plan", help="rig plan TOML (default: the paper's experiment)")
    sim.add_argument("--vehicle", help="vehicle TOML (default: the paper's Table 1 car)")
    sim.add_argument("--out", required=True, help="session folder to write")
    sim.add_argument("--units", choices=["SI", "imperial"], help="units of the written session "
                     "(default: the plan's)")
    sim.add_argument("--format", choices=["csv", "parquet"], default="csv", help="run file format")
    sim.add_argument("--duration", type=float, help="override every run's duration [s]")
    sim.add_argument("--noise", type=float, help="measurement noise, fraction of channel RMS")
    sim.add_argument("--overwrite", action="store_true", help="replace an existing session folder")
    sim.set_defaults(func=cmd_rig_simulate)

    veh = sub.add_parser("vehicle", help="vehicle model tools")
    veh_sub = veh.add_subparsers(dest="vehicle_command", required=True)
    modes = veh_sub.add_parser("modes", help="natural frequencies of a vehicle")
    modes.add_argument("--vehicle", help="vehicle TOML (default: the paper's Table 1 car)")
    modes.add_argument("--damping", type=float, help="linear shock damping for the damped modes")
    modes.add_argument("--units", choices=["SI", "imperial"], default="SI",
                       help="units of --damping (default %(default)s)")
    modes.set_defaults(func=cmd_vehicle_modes)
    return p


def main(argv=None):
    """Entry point of the ``shockplan`` program; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except (ValueError, TypeError, FileExistsError, FileNotFoundError) as exc:
        print(f"shockplan: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # pragma: no cover
        print("shockplan: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
