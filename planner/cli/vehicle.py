"""``shockplan vehicle modes``: natural frequencies of a vehicle."""

from __future__ import annotations

from planner.cli.common import add_units, load_vehicle
from planner.text import format_table

__all__ = ["add_parser", "run"]


def add_parser(subparsers):
    """Add ``vehicle`` and its command ``modes`` to `subparsers`."""
    veh = subparsers.add_parser("vehicle", help="vehicle model tools")
    veh_sub = veh.add_subparsers(dest="vehicle_command", required=True,
                                 help="the vehicle command")
    modes = veh_sub.add_parser("modes", help="natural frequencies of a vehicle")
    modes.add_argument("--vehicle", help="vehicle TOML (default: the paper's Table 1 car)")
    modes.add_argument("--damping", type=float, help="linear shock damping of every corner for "
                       "the damped modes [N/(m/s), or lbf/(in/s) with --units imperial] "
                       "(default: the vehicle's own)")
    add_units(modes, "units of --damping and of the damping printed")
    modes.set_defaults(func=run)
    return veh


def run(args):
    """``shockplan vehicle modes``: natural frequencies of a vehicle."""
    from ident.data.units import format_quantity, to_si
    from ident.models.vehicle import modal_summary

    vehicle = load_vehicle(args.vehicle)
    damping = None
    if args.damping is not None:
        damping = to_si(args.damping, "damping", args.units)
    s = modal_summary(vehicle, damping_n_s_m=damping)
    rows = [(lab, f"{f0:.3f}", f"{u:.3f}", f"{d:.3f}", f"{z:.3f}")
            for lab, f0, u, d, z in zip(s.labels, s.no_damping_hz, s.natural_hz, s.damped_hz,
                                        s.damping_ratio)]
    print(f"vehicle '{vehicle.name}', shocks "
          f"{format_quantity(s.damping_n_s_m[0], 'damping', args.units, digits=4)}")
    print(format_table(rows, ["mode", "no-damping Hz", "natural Hz", "damped Hz", "zeta"]))
    print("no-damping: springs and tires alone (the ride-rate hand calculation); natural and "
          "damped: the modes with these shocks, |s|/2pi and Im(s)/2pi (damped = natural * "
          "sqrt(1 - zeta^2)); shock damping couples chassis and wheels, so natural differs from "
          "no-damping")
    return 0
