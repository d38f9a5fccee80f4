"""What the commands share: the spelling-checking parser, the option helpers, output checks.

Light on purpose: the command line builds its parser on every start (``shockplan
--help``), so this module imports nothing heavy at its top; the helpers that read files
import the library inside the function.
"""

from __future__ import annotations

import argparse
import difflib
import logging
import re
import sys

from ident.data.files import check_output
from ident.data.units import UNIT_SYSTEMS, set_display_units

__all__ = [
    "Parser", "add_flags_anywhere", "FLAGS_ANYWHERE", "TYPO_CUTOFF", "RENAMED_OPTIONS",
    "unit_system", "int_at_least", "share", "add_units", "add_command_group",
    "run_subcommand", "add_element_options",
    "add_try_options", "add_third_try_options", "add_prediction_inputs", "add_histogram_option", "histogram_options", "check_out", "warn_inventory",
    "baseline_arg", "load_vehicle", "load_any_model", "read_inputs", "output_units",
    "bump_stop_library", "section_windows", "parse_fixed", "packer_bounds", "element_choices", "one_line",
    "UNITS_OF_DRIVE", "UNITS_OF_DRIVES", "MODEL_HELP", "OBJECTIVE_HELP", "log",
    "show_progress", "package_version", "VersionAction",
]

log = logging.getLogger("shockplan")

#: difflib similarity a misspelled option or command must reach for the nearest valid one to
#: be named: stricter than difflib's 0.6, as :func:`ident.data.files.did_you_mean`, so that
#: an option of a command written before it ('--units') is not taken for '--quiet'.
TYPO_CUTOFF = 0.75

#: Options renamed so that one name means one thing in every command (issue 23):
#: ``{command: {old: (new, what the new one means)}}``. The old spelling is refused with
#: the new one named, never taken silently.
RENAMED_OPTIONS = {
    "rank": {"--top": ("--simulate", "the number of setups simulated in the time domain; "
                       "--top is whatif's: the number of setups taken from a ranking")},
    "sweep": {"--top": ("--simulate", "the number of setups simulated in the time domain"),
              "--top-share": ("--simulate-share", "the share of setups simulated in the "
                              "time domain")},
    "plan": {"--rig": ("--rig-costs", "the rig TOML of swap and run times; --rig is the rig "
                       "kind of 'rig simulate'")},
}

#: What argparse takes for a negative number (a value, not an option).
_NEGATIVE_NUMBER = re.compile(r"^-\d+$|^-\d*\.\d+$")

#: The flags taken before or after any command (issue 23): short, long, help.
FLAGS_ANYWHERE = (("-v", "--verbose",
                   "log progress details (default: warnings only); before or after the command"),
                  ("-q", "--quiet",
                   "no progress bars (default: shown when the error output is a terminal, "
                   "never in a log file); before or after the command"))

#: ``--units`` default of the commands that read one drive file / several (issue 23): the
#: file's unit marker, else SI; a given ``--units`` that contradicts the marker is an error.
UNITS_OF_DRIVE = "the drive file's own, from its 'units' column, else SI"
UNITS_OF_DRIVES = ("each drive file's own, from its 'units' column, else SI; the outputs "
                   "in the first drive's")

MODEL_HELP = "identified model (.npz), a vehicle TOML (the known physical model) or 'paper'"
OBJECTIVE_HELP = "objective TOML (default: the built-in 'grip and platform')"


def package_version():
    """shockplan's version: the installed distribution's (:func:`importlib.metadata.version`),
    else the package's ``__version__`` (a source tree run without installing)."""
    from importlib import metadata

    try:
        return metadata.version("shockplan")
    except metadata.PackageNotFoundError:
        from planner import __version__

        return __version__


class VersionAction(argparse.Action):
    """``--version``: print ``shockplan <version>`` and exit with status 0. The version is
    looked up only when asked (:func:`package_version`), not on every start."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="print shockplan's version and exit"):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog.split()[0]} {package_version()}", file=sys.stdout)
        parser.exit(0)


def show_progress(args):
    """Whether a command shows progress bars: unless ``-q``, and only when the error output
    (where tqdm draws) is a terminal, so that a log file gets no bars."""
    if getattr(args, "quiet", False):
        return False
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # replaced by an object without it, or closed
        return False


# -- argument types --------------------------------------------------------------------------

def unit_system(text):
    """``--units`` in any case as its canonical name ("SI" or "imperial"); other text
    unchanged, for argparse's ``choices`` to refuse with the valid names."""
    for name in UNIT_SYSTEMS:
        if text.strip().lower() == name.lower():
            return name
    return text


def int_at_least(low):
    """An argparse type: an integer >= `low`, refused before any work with the bound named."""
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {value}")
        return value
    return parse


def positive_hz(text):
    """An argparse type: a sample rate [Hz] > 0 (``--resample``)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a rate in Hz, e.g. 100, got {text!r}") from None
    if not (value > 0.0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive rate in Hz, e.g. 100, got "
                                         f"{value:g}")
    return value


def share(text):
    """An argparse type: a share in (0, 1] (e.g. 0.01 for the best 1 %)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number in (0, 1], got {text!r}") from None
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], e.g. 0.01 for the best 1 %, got "
                                         f"{value:g}")
    return value


# -- shared options --------------------------------------------------------------------------

def add_units(parser, what, *, default="SI", default_text="SI"):
    """Add ``--units`` (``SI`` or ``imperial``, any case) to `parser`."""
    parser.add_argument("--units", type=unit_system, choices=list(UNIT_SYSTEMS),
                        default=default, help=f"{what}: SI or imperial, in any case (default: "
                        f"{default_text})")


def add_resample(parser, what):
    """Add ``--resample HZ``: read `what` onto a uniform time base at HZ (band-limited)."""
    parser.add_argument("--resample", type=positive_hz, default=None, metavar="HZ",
                        help=f"resample {what} onto a uniform time base at HZ (band-limited, "
                        "anti-aliased when going down), e.g. files logged at different rates; "
                        "its ratio to a file's rate must be a fraction up/down with down <= "
                        "1000 (default: each file's own rate, jittered time stamps resampled "
                        "onto it)")


def add_command_group(subparsers, name, subcommands, *, help, dest, dest_help):
    """Add a command with sub-commands (``dyno``, ``drive``) to `subparsers`.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The top-level parser's commands.
    name, help : str
        The command's name and help.
    subcommands : dict of str to (callable, callable)
        Sub-command name -> (function adding its parser to the group, function running it).
    dest, dest_help : str
        The attribute naming the chosen sub-command, and its help.

    Returns
    -------
    argparse.ArgumentParser
        The command's parser.
    """
    group = subparsers.add_parser(name, help=help)
    sub = group.add_subparsers(dest=dest, required=True, help=dest_help)
    for add, _ in subcommands.values():
        add(sub)
    return group


def run_subcommand(subcommands, args, dest):
    """Run the sub-command of `subcommands` that ``args.<dest>`` names; its exit status."""
    return subcommands[getattr(args, dest)][1](args)


def add_element_options(parser):
    """``--bump-stops FILE`` and ``--no-elements`` (the real car's elements)."""
    parser.add_argument("--bump-stops", metavar="FILE",
                        help="bump-stop library TOML (bumpstops.toml) naming the stops of the "
                        "setups' bump_stop_XX columns and of bump_stop factors (default: the "
                        "model's, from its session)")
    parser.add_argument("--no-elements", action="store_true",
                        help="leave the model's bump stops and static loads (tire lift-off) "
                        "out of the loop (default: in the loop when the session declared "
                        "them)")


def add_try_options(parser):
    """``--try-bump-stops`` and ``--try-packers`` (bump stops and packers as setup columns),
    ``--try-heave``, ``--try-roll``, ``--try-heave-spring`` (third elements)."""
    parser.add_argument("--try-bump-stops", action="append", metavar="GROUP=ID,ID",
                        help="rank every setup with each of these bump stops at GROUP "
                        "(front, rear, all or a corner; 'none' for none); repeatable "
                        "(default: the setups' own)")
    parser.add_argument("--try-packers", action="append", metavar="GROUP=L,L",
                        help="rank every setup with each of these packers at GROUP, in "
                        "the drive's units or with a unit (0,2mm,4mm); repeatable "
                        "(default: the setups' own)")
    add_third_try_options(parser)


def add_third_try_options(parser, *, crate=False):
    """``--try-heave``, ``--try-roll``, ``--try-heave-spring`` (third-element choices);
    `crate`: optimize's wording (the crate's best is searched over them)."""
    if crate:
        what = "search the crate's best with each of these heave dampers at AXLE"
        default = "the baseline's, or with --free-third the crate's dampers that fit it"
    else:
        what = "rank every setup with each of these heave dampers at AXLE"
        default = "the setups' own, else the baseline's"
    parser.add_argument("--try-heave", action="append", metavar="AXLE=ID,ID",
                        help=f"{what} (front "
                        "or rear; shock-library ids, 'none' for none); repeatable (a car with "
                        f"third elements; default: {default})")
    parser.add_argument("--try-roll", action="append", metavar="AXLE=ID,ID",
                        help=f"as --try-heave, for the roll dampers (default: {default})")
    parser.add_argument("--try-heave-spring", action="append", metavar="AXLE=ID,ID",
                        help="as --try-heave, for the heave springs (bump-stop-library ids; "
                        f"default: {default})")


def add_prediction_inputs(parser, *, out_help):
    """The options ``predict`` and ``rank`` share: model, drive, crate, units, oversampling,
    output and the real car's elements."""
    parser.add_argument("--model", required=True, help=MODEL_HELP)
    parser.add_argument("--drive", required=True, help="drive file (CSV or Parquet)")
    parser.add_argument("--shocks", required=True, help="shock library TOML")
    add_units(parser, "unit system of the drive file and of the outputs", default=None,
              default_text=UNITS_OF_DRIVE)
    parser.add_argument("--oversample", type=int, default=2,
                        help="internal steps per sample of the shock loop (default %(default)s)")
    parser.add_argument("--out", required=True, help=out_help)
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    add_element_options(parser)
    add_histogram_option(parser)


def add_histogram_option(parser):
    """``--histogram-bins WIDTH,LIMIT[,KNEE] | none``: the shock-velocity histograms."""
    parser.add_argument("--histogram-bins", metavar="WIDTH,LIMIT[,KNEE]|none",
                        help="shock-velocity histograms of every setup simulated in the time "
                        "domain (histograms.csv; predict: PREDICTIONS_histograms.csv; drive "
                        "from-track: the logged and the reproduced one in its report): bins "
                        "WIDTH wide over +-LIMIT with an open "
                        "bin at each end, low speed below KNEE, in the outputs' units "
                        "(default 0.025,0.25,0.025 m/s; 1,10,1 in/s in imperial units); "
                        "'none': no histograms")


def histogram_options(args):
    """``--histogram-bins`` as a :class:`planner.options.HistogramOptions` in the outputs'
    units (``args.units`` resolved first), or None for ``none``.

    Raises
    ------
    planner.errors.PlannerError
        On a malformed value (the message names the option and an example).
    """
    from ident.data.units import to_si
    from planner.errors import PlannerError
    from planner.options import HistogramOptions

    text = getattr(args, "histogram_bins", None)
    units = args.units or "SI"
    if text is None:
        return HistogramOptions.default(units)
    if text.strip().lower() in ("none", "off"):
        return None
    example = "1,10,1 (in/s)" if units == "imperial" else "0.025,0.25,0.025 (m/s)"
    try:
        values = [float(x) for x in text.split(",")]
        if len(values) not in (2, 3):
            raise ValueError
        si = [float(to_si(v, "velocity", units)) for v in values]
        if len(si) == 2:
            si.append(si[0])
        return HistogramOptions(*si)
    except ValueError as exc:
        detail = f" ({exc})" if str(exc) else ""
        raise PlannerError(f"--histogram-bins {text!r}: give WIDTH,LIMIT[,KNEE] in {units} "
                           f"units, e.g. {example}, or 'none'{detail}") from None


# -- what the commands share when they run ---------------------------------------------------

def check_out(args, *, folder=False, overwrite=None):
    """Check ``--out`` before any computation: exists (without --overwrite), read-only folder."""
    check_output(args.out, overwrite=args.overwrite if overwrite is None else overwrite,
                 folder=folder)


def warn_inventory(setups, library):
    """Log a warning for every setup that needs more units of a shock than the crate's count."""
    from planner.setups import inventory_shortfall

    for s in setups:
        short = inventory_shortfall(s, library)
        if short:
            log.warning("setup %r: %s", s.name, short)


def baseline_arg(args, library, setups=None):
    """``--baseline`` read by :func:`planner.setups.resolve_baseline` (None when not given):
    a listed setup's name, one shock id (every corner) or four ``LF,RF,LR,RR``; a setup
    built from ids is named ``baseline``."""
    from planner.setups import resolve_baseline

    if not args.baseline:
        return None
    return resolve_baseline(args.baseline, library, setups=setups or (), where="--baseline")


def load_vehicle(path):
    """The vehicle TOML at `path`, or the paper's car for None."""
    from ident.models.vehicle import example_vehicle, read_vehicle

    return example_vehicle() if path is None else read_vehicle(path)


def load_any_model(path):
    """An identified model (.npz), a vehicle TOML (the known physical model) or 'paper'."""
    from planner.predict import load_any_model as load

    return load(path)


def read_inputs(args):
    """``--model``, ``--drive`` and ``--shocks`` read (``args.units`` set from the drive)."""
    from ident.data.drive import read_drive
    from ident.models.library import read_shock_library

    model = load_any_model(args.model)
    drive = read_drive(args.drive, units=args.units)
    output_units(args, [drive])
    library = read_shock_library(args.shocks)
    return model, drive, library


def output_units(args, drives, *, fallback="SI"):
    """The unit system of the outputs, set as ``args.units``: ``--units`` if given, else the
    first drive file's (its ``units`` column or ``# units:`` line; the spec: predictions
    in the drive file's units), else `fallback` (a command without drives: its project's
    other files, e.g. :func:`planner.dyno.check.library_units`). The run's messages,
    tables and plots are then in them too (:func:`ident.data.units.set_display_units`)."""
    if args.units is None:
        args.units = drives[0].settings.get("units", "SI") if drives else fallback
    set_display_units(args.units)  # the messages, tables and plots of the run in them too
    return args.units


def section_windows(args, where, *, option_prefix=""):
    """The ``--section`` windows and the ``--laps`` laps of a command, checked (names,
    order): a list of ``(name, start_s, stop_s)``.

    `where` names the command in a clash of names; `option_prefix` goes before the option
    names in the other messages (``"rank "``: ``rank --section ...``).
    """
    from planner.errors import PlannerError
    from planner.trackdrive import lap_sections, parse_sections

    sections = parse_sections(args.section, where=f"{option_prefix}--section")
    if args.laps:
        laps = lap_sections(str(args.laps).split(","), where=f"{option_prefix}--laps")
        clash = {n for n, _, _ in laps} & {n for n, _, _ in sections}
        if clash:
            raise PlannerError(f"{where}: --section names {sorted(clash)} clash with the laps' "
                               "names; rename them")
        sections += laps
    return sections


def bump_stop_library(args, model):
    """``--bump-stops FILE`` read (it replaces the model's library), else None."""
    from ident.models.bumpstops import read_bump_stops

    path = getattr(args, "bump_stops", None)
    return None if path is None else read_bump_stops(path)


def parse_fixed(items):
    """``--fixed CORNER=ID`` (repeatable) as ``{corner: id}``."""
    fixed = {}
    for item in items or ():
        corner, sep, sid = item.partition("=")
        if not sep:
            raise ValueError(f"--fixed {item!r}: write CORNER=SHOCK_ID, e.g. --fixed LF=B20")
        fixed[corner.strip()] = sid.strip()
    return fixed


def packer_bounds(args):
    """``--packers GROUP=LO:HI`` as :func:`planner.optimize.optimize_curves`' ``packers``."""
    from planner.elements import parse_length

    out = {}
    for item in getattr(args, "packers", None) or ():
        group, sep, span = item.partition("=")
        lo, sep2, hi = span.partition(":")
        if not sep or not sep2 or not group.strip():
            raise ValueError(f"--packers {item!r}: write GROUP=LO:HI with GROUP a corner group "
                             "of the symmetry (front, rear; a corner with --symmetry none), "
                             "e.g. --packers front=0:4mm")
        unit = re.search(r"[a-z]+$", hi.strip().lower())
        if unit and not re.search(r"[a-z]+$", lo.strip().lower()):
            lo = lo.strip() + unit.group(0)  # 2:4mm is 2 mm to 4 mm
        out[group.strip()] = tuple(parse_length(x, units=args.units, where="--packers")
                                   for x in (lo, hi))
    return out or None


def element_choices(args):
    """``--try-bump-stops GROUP=ID,ID`` and ``--try-packers GROUP=L,L`` as
    :func:`planner.elements.vary_elements`' arguments; ``--try-heave AXLE=ID,ID``,
    ``--try-roll`` and ``--try-heave-spring`` as ``vary_third``
    (:func:`planner.elements.vary_third`)."""
    from planner.elements import parse_length

    out = {}
    for opt, key in (("try_bump_stops", "vary_bump_stops"), ("try_packers", "vary_packers_m")):
        items = getattr(args, opt, None) or ()
        flag = "--" + opt.replace("_", "-")
        for item in items:
            group, sep, values = item.partition("=")
            vals = [v.strip() for v in values.split(",") if v.strip()]
            if not sep or not group.strip() or not vals:
                raise ValueError(f"{flag} {item!r}: write GROUP=A,B with GROUP front, rear, "
                                 "all or a corner, e.g. " + ("--try-bump-stops front=BS-F,BS-F2"
                                                              if key == "vary_bump_stops" else
                                                              "--try-packers front=0,2mm,4mm"))
            if key == "vary_packers_m":
                vals = [parse_length(v, units=args.units or "SI", where=flag) for v in vals]
            out.setdefault(key, {})[group.strip()] = vals
    for opt, column in (("try_heave", "heave_{}"), ("try_roll", "roll_{}"),
                        ("try_heave_spring", "heave_spring_{}")):
        flag = "--" + opt.replace("_", "-")
        for item in getattr(args, opt, None) or ():
            axle, sep, values = item.partition("=")
            vals = [v.strip() for v in values.split(",") if v.strip()]
            if not sep or axle.strip() not in ("front", "rear") or not vals:
                raise ValueError(f"{flag} {item!r}: write AXLE=A,B with AXLE front or rear, "
                                 f"e.g. {flag} front=H1,H2")
            out.setdefault("vary_third", {})[column.format(axle.strip())] = vals
    return out


def one_line(exc):
    """The message of `exc` on one line (a bare errno error gets its file named)."""
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc)
    return " ".join(text.split())


# -- the parser ------------------------------------------------------------------------------

def _subcommands(parser):
    """The subparsers action of `parser` (its commands), or None."""
    return next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)),
                None)


def _option_owners(option, commands):
    """The commands under `commands` (``rank``, ``rig simulate``) that take `option`."""
    owners = []
    for name, parser in commands.choices.items():
        inner = _subcommands(parser)
        if inner is not None:
            owners += [f"{name} {o}" for o in _option_owners(option, inner)]
        elif option in parser._option_string_actions:
            owners.append(name)
    return owners


def _looks_like_option(arg):
    """Whether argparse takes `arg` for an option (not a value such as ``-0.5``)."""
    return len(arg) > 1 and arg[0] == "-" and " " not in arg and not _NEGATIVE_NUMBER.match(arg)


class Parser(argparse.ArgumentParser):
    """An argument parser that takes options only spelled out in full, and answers a
    misspelled option or command with the nearest valid one of that command (issue 23).

    Abbreviations (``--shock`` for ``--shocks``) are refused: one that works today
    breaks or changes meaning when an option with the same beginning is added. An
    unknown option or command ends the program with exit status 2 and one line, before
    argparse's own checks (so a misspelled ``--shocks`` is named, not reported missing).
    """

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def parse_known_args(self, args=None, namespace=None):
        """:meth:`argparse.ArgumentParser.parse_known_args`, after refusing a misspelled
        option or command of this parser."""
        args = sys.argv[1:] if args is None else list(args)
        self._check_spelling(args)
        return super().parse_known_args(args, namespace)

    def _check_spelling(self, args):
        """Refuse the first unknown option or command of `args` (up to this parser's
        command: the rest is the command's parser's to check)."""
        commands = _subcommands(self)
        is_value = False
        for arg in args:
            if is_value:
                is_value = False
                continue
            if arg == "--":
                return
            if not _looks_like_option(arg):
                if commands is None:
                    continue
                if arg not in commands.choices:
                    close = difflib.get_close_matches(arg, list(commands.choices), n=3,
                                                      cutoff=TYPO_CUTOFF)
                    hint = (f"did you mean {' or '.join(close)}?" if close else
                            f"the commands are {', '.join(commands.choices)}")
                    self._fail(f"unknown command {arg!r}; {hint}")
                return
            name = arg.split("=", 1)[0] if arg.startswith("--") else arg
            action = self._option_string_actions.get(name)
            if action is None and not arg.startswith("--"):
                action = self._option_string_actions.get(arg[:2])  # grouped flags: -qv
            if action is None:
                self._unknown_option(name, commands)
            # an option's value before the command is not the command
            is_value = (commands is not None and action.nargs != 0
                        and arg in self._option_string_actions)

    def _unknown_option(self, name, commands):
        said = f"unrecognized option {name!r}"
        renamed = RENAMED_OPTIONS.get(self.prog.split(" ", 1)[-1], {}).get(name)
        if renamed is not None:
            self._fail(f"{said}: it was renamed {renamed[0]} ({renamed[1]})")
        owners = [] if commands is None else _option_owners(name, commands)
        if owners:
            self._fail(f"{said}: it is an option of {', '.join(owners)}; write it after the "
                       "command")
        longs = {o.lstrip("-"): o for o in self._option_string_actions if o.startswith("--")}
        stem = name.lstrip("-")
        # an abbreviation's full spellings first, then the misspellings' nearest
        close = [o for o in longs if stem and o.startswith(stem)]
        close += [o for o in difflib.get_close_matches(stem, list(longs), n=3,
                                                        cutoff=TYPO_CUTOFF) if o not in close]
        close = close[:3]
        if close:
            self._fail(f"{said}; did you mean {' or '.join(longs[c] for c in close)}?")
        self._fail(f"{said}; see '{self.prog} --help' for the options")

    def _fail(self, message):
        """Exit with status 2 and one line (no usage: the line says what to write)."""
        self.exit(2, f"{self.prog}: error: {message}\n")


def add_flags_anywhere(parser):
    """Give every command (and its commands) the top level's ``-v`` and ``-q``, so that
    ``shockplan rank ... -q`` works as ``shockplan -q rank ...``. A command's copy sets the
    flag only when given (default SUPPRESS): it never resets the top level's."""
    commands = _subcommands(parser)
    for sub in () if commands is None else commands.choices.values():
        for short, long, text in FLAGS_ANYWHERE:
            sub.add_argument(short, long, action="store_true", default=argparse.SUPPRESS,
                             help=text)
        add_flags_anywhere(sub)
