"""``shockplan demo``: the main job on the built-in example, end to end.

1. The virtual rig runs the seed paper's identification experiment on the
   paper's car (Table 1) and writes it as a rig session.
2. The session is identified (FRF over all runs, conditioning, per-pair
   rational fits) and the model saved, with FRF-vs-fit plots.
3. A track-like drive is made (and written as a drive file).
4. Every left/right-symmetric setup of the built-in crate of shocks (linear,
   digressive, asymmetric, blow-off, a dyno table, with lags) is screened,
   the best are simulated in the time domain with the nonlinear shocks,
   scored against the baseline (the identification's B20 shocks) with
   intervals from the identification's random error, and written as a
   ranking (CSV, formatted XLSX, Pareto and top-setup plots).
5. The best force-velocity curve per axle is optimized on the same model and
   drive (:mod:`planner.optimize`), verified in the time domain, mapped to the
   crate, and written for a shock builder: how much better than the crate's
   best a new shock could be.

Everything goes to one output folder, built in a temporary sibling and moved
into place at the end. Beside the results, :func:`write_demo_inputs` writes the inputs
the README's examples name (``crate.toml``, ``car.toml``, ``objective.toml``,
``constraints.toml``, ``whatif.toml``, ``rig_map.toml``), each readable as is by its
reader, and :func:`write_real_car_example` the README's real-car example (``real_car/``:
a GT-like car with bump stops and static loads); ``docs/formats.md`` describes their
formats.
"""

from __future__ import annotations

import functools
import logging
import os
import warnings
from pathlib import Path

from ident.data.channels import ALL_CHANNELS, CORNERS, quantity_of
from ident.interrupts import die_with_parent
from ident.data.files import (atomic_write_bytes, atomic_write_text, atomic_write_toml,
                              check_can_write, write_csv)
from ident.data.formats.channel_map import CHANNEL_MAP_FORMAT, UNIT_FACTORS
from ident.data.formats.rpc3 import write_rpc3
from ident.data.units import check_units
from ident.models.library import write_shock_library
from ident.models.vehicle import EXAMPLE_VEHICLE_PATH
from planner.objective import default_objective, objective_to_toml

__all__ = ["run_demo", "write_demo_inputs", "write_demo_rig_files", "write_real_car_example",
           "DEMO_LIBRARY_PATH", "DEMO_INPUT_FILES", "DEMO_RIG_FILES", "REAL_CAR_FOLDER",
           "REAL_CAR_FILES", "write_clicks_example", "CLICKS_FOLDER", "CLICKS_FILES",
           "write_track_example", "TRACK_FOLDER", "TRACK_FILES", "write_proto_example",
           "PROTO_FOLDER", "PROTO_FILES", "PROTO_EXAMPLES", "proto_speed_trace",
           "proto_track_drive"]

log = logging.getLogger(__name__)

DEMO_LIBRARY_PATH = Path(__file__).parent / "examples" / "library.toml"
_PLOT_OUTPUTS = tuple(f"{k}_{c}" for k in ("shock_velocity", "tire_force", "ride_height")
                      for c in ("LF", "RF", "LR", "RR"))
#: The inputs :func:`write_demo_inputs` writes (file name -> what it is), in README order.
DEMO_INPUT_FILES = {
    "crate.toml": "the demo's crate of shocks (shock library TOML)",
    "car.toml": "the paper's car (vehicle TOML)",
    "objective.toml": "the default objective (objective TOML)",
    "constraints.toml": "curve constraints for optimize (curve-constraints TOML)",
    "whatif.toml": "the README's what-if study (what-if TOML)",
    "rig_map.toml": "a channel map of the canonical channels to themselves, SI, sign 1",
}
#: The SI unit name of each quantity (the channel map's unit of factor 1), as the demo's
#: channel map and rig files name them.
_SI_UNIT = {q: next(u for u, f in table.items() if f == 1.0) for q, table in UNIT_FACTORS.items()}
#: Folder of the session's runs as a real rig writes them (:func:`write_demo_rig_files`).
DEMO_RIG_FILES = "rig_files"
#: Length of each run in ``rig_files/`` [s]: the first 60 s, which identify a model on
#: their own (the runs whole are in ``session/``; the folder stays under 100 MB).
DEMO_RIG_FILES_S = 60.0
#: Folder of the README's real-car example (:func:`write_real_car_example`).
REAL_CAR_FOLDER = "real_car"
#: Folder of the README's adjustable-damper example (:func:`write_clicks_example`).
CLICKS_FOLDER = "clicks"
#: Folder of the README's track-data example (:func:`write_track_example`).
TRACK_FOLDER = "track"
#: The track example's files (name -> what it is), in README order.
TRACK_FILES = {
    "lap.mf4": "two laps of the paper car on a virtual track, as its logger writes them "
               "(MDF4: damper pots and ride-height lasers in mm at 200 Hz, speed in km/h at "
               "20 Hz), DM shocks all round",
    "log_map.toml": "the channel map of the logger's channels to the canonical log channels",
    "aero.toml": "the car's downforce and balance (aero model TOML, constant coefficients)",
    "rig.toml": "the rig's wheelloader and aero limits (rig TOML with [limits])",
    "plan.toml": "a rig plan that plays drive.csv (which `drive from-track` writes) on the car",
}
#: The logger's channels: canonical -> (name, unit); the pots carry the virtual logger's
#: zero offsets (:data:`ident.sim.virtual_track.POT_OFFSET_M`), which the map takes off.
_TRACK_LOGGER = {
    **{f"{kind}_{c}": (f"{label} {w}", "mm")
       for kind, label in (("shock_travel", "Damper Pos"), ("ride_height", "Ride Height"))
       for c, w in (("LF", "FL"), ("RF", "FR"), ("LR", "RL"), ("RR", "RR"))},
}
#: The example's track run: 120 s (two laps of 60 s) at 200 Hz, seed, the car's downforce.
_TRACK_RUN = {"duration_s": 120.0, "fs_hz": 200.0, "seed": 27}
#: Folder of the README's third-elements example (:func:`write_proto_example`).
PROTO_FOLDER = "proto"
#: Where the prototype-like car's files live in the package (``ident/examples``).
PROTO_EXAMPLES = Path(EXAMPLE_VEHICLE_PATH).parent
#: The third-elements example's files (name -> what it is), in README order: copies of
#: ``ident/examples/proto_*`` and the car's track drive.
PROTO_FILES = {
    "proto_car.toml": "a prototype-like car with heave elements front and rear and a front "
                      "roll damper, soft corner springs (vehicle TOML, third_elements)",
    "proto_aero.toml": "its downforce, about 1.7 times its weight at 70 m/s (aero model TOML)",
    "proto_shocks.toml": "corner shocks, heave and roll dampers: linear, table, digressive, "
                         "with lag (shock library)",
    "proto_bumpstops.toml": "its heave springs, stiff with a gap (bump-stop library)",
    "proto_plan.toml": "a 7-post session: baseline, a swap per corner and per third element's "
                       "damper, 8 runs of 120 s, 2 % noise (rig plan)",
    "proto_setups.csv": "44 setups varying corner, heave and roll dampers and the front heave "
                        "spring (setups CSV with third-element columns)",
    "track_drive.csv": "a 120 s track drive with the car's downforce at a lap's speeds: the "
                       "heave springs closed at speed (drive)",
}
_TRACK_AERO = """# Aero model (shockplan-aero/1), written by shockplan demo: the README's "From track data
# to a rig drive" example. The paper car's downforce, growing with the square of speed,
# 45 % on the front axle.
format = "shockplan-aero/1"
units = "SI"
name = "paper car, constant coefficients"
kind = "constant"
cg_to_front_axle = 1.524     # m (60 in)
cg_to_rear_axle = 1.27       # m (50 in)
reference_speed = 60.0       # m/s
downforce = 3000.0           # N at the reference speed
balance = 0.45               # front share
"""
_TRACK_RIG = """# Rig TOML (rig/1), written by shockplan demo: the README's "From track data to a rig
# drive" example. What the 7-post's actuators can play; a drive beyond it is clipped
# (smoothly, with a warning) or scaled (--limit-action scale).
format = "rig/1"
name = "7-post"
units = "imperial"

[limits]
wheelloader_displacement = 1.5      # in, +-
wheelloader_velocity = 40.0         # in/s
wheelloader_acceleration = 3000.0   # in/s^2
aero_heave = 1500.0                 # lbf
"""
_TRACK_PLAN = """# Rig plan (rig-plan/1), written by shockplan demo: the README's "From track data to a rig
# drive" example. The rig plays drive.csv (written by shockplan drive from-track) on the
# car with the DM shocks it ran at the track, 2 % sensor noise. Run it with
#   shockplan rig simulate --plan track/plan.toml --vehicle car.toml --out track/session
format = "rig-plan/1"
name = "track drive on the rig"
units = "imperial"                 # the session it writes, as the demo's project
shock_library = "../crate.toml"
fs_hz = 100.0
noise = 0.02

[[run]]
name = "track"
setup = { LF = "DM", RF = "DM", LR = "DM", RR = "DM" }
role = "validation"
drive = "drive.csv"
"""

#: The settings of the clicks example's raw dyno runs: the low-speed adjuster swept at
#: ``hs`` 2, the high-speed one at ``ls`` 10, as a dyno session records them.
_CLICKS_DYNO_SETTINGS = ({"ls": 0, "hs": 2}, {"ls": 10, "hs": 2}, {"ls": 20, "hs": 2},
                         {"ls": 10, "hs": 0}, {"ls": 10, "hs": 4})
#: The dyno program of each raw run: peak velocities [m/s], 50 mm stroke, 3 cycles each.
_CLICKS_DYNO_SPEEDS = (0.025, 0.05, 0.1, 0.2, 0.35, 0.5)
#: The clicker's lag [s] (hysteresis; the import reports its estimate per file).
_CLICKS_LAG_S = 0.004
#: The adjustable-damper example's files (name -> what it is), in README order.
CLICKS_FILES = {
    **{f"dyno/ls{s['ls']}-hs{s['hs']}.csv": f"a raw dyno run (time, load, position, "
       f"temperature as the dyno logs them) at ls={s['ls']}, hs={s['hs']}"
       for s in _CLICKS_DYNO_SETTINGS},
    "dyno_map.toml": "the dyno map: the raw files' column names, units, signs and offsets",
    "shocks.toml": "the crate: B20 and the adjustable TTX (ls 0-20 clicks, hs 0-4 turns), "
                   "whose curves come from ttx_dyno.csv (which `dyno import` writes)",
    "rig.toml": "rig costs: a shock swap 12 min a corner, an adjuster turned 20 s",
}
_CLICKS_MAP = """\
format = "dyno-map/1"
name = "shock dyno, CSV export"

[columns.time]
source = "Time (ms)"
units = "ms"

[columns.force]
source = "Load"
units = "lbf"
sign = -1                  # this dyno logs tension positive

[columns.displacement]
source = "Position"
units = "mm"
sign = 1
offset = 25.0              # the raw position at mid-stroke

[columns.temperature]
source = "Shock Temp"
units = "degC"
"""
_CLICKS_SHOCKS = """\
# The clicks example's crate (rig-session/1 shock library, imperial units, as the demo's
# project). TTX's curves at any setting come from its dyno sheet: `shockplan dyno import`
# writes ttx_dyno.csv.
units = "imperial"

[[shock]]
id = "B20"
kind = "linear"
damping = 20.0

[[shock]]
id = "TTX"
kind = "adjustable"
description = "two-way clicker: ls = low-speed bleed (clicks from closed), hs = high-speed preload (turns)"
adjusters = { ls = [0, 20], hs = [0, 4] }
default = { ls = 10, hs = 2 }
stiffer = { ls = "lower", hs = "lower" }
step = { ls = 1, hs = 0.5 }
dyno = "ttx_dyno.csv"
lag = 0.004
count = 4
"""
_CLICKS_RIG = """\
format = "rig/1"
name = "7-post rig, one crew"
swap_min = 12.0            # min per corner to swap a shock
run_overhead_min = 3.0     # min per run: start, settle, save
click_change_s = 20.0      # s per adjuster turned at a corner (the shock stays on)
"""
#: The real-car example's files (name -> what it is), in README order.
REAL_CAR_FILES = {
    "car.toml": "a GT-like car (ident.models.vehicle.example_gt_vehicle), vehicle TOML",
    "shocks.toml": "its crate: one digressive valving at five force levels (shock library)",
    "bumpstops.toml": "its bump stops: progressive, front at 4.5 mm, a softer 6 mm choice, "
                      "rear at 6 mm (bump-stop library)",
    "plan.toml": "a rig plan: the paper's experiment on this car, its bump stops fitted and "
                 "its static corner loads declared (rig plan)",
    "track_drive.csv": "a 60 s track drive for this car, with aero loads (drive)",
    "whatif.toml": "packers +-1 mm and a bump-stop swap at the front (what-if TOML)",
}
#: The real-car example's crate: force levels of one digressive valving (N s/m at low speed
#: in bump and rebound, knee 0.08 m/s, 2 ms lag), named by the level.
_REAL_CAR_LEVELS = (0.6, 0.8, 1.0, 1.25, 1.5)
#: Its bump stops: one progressive table (100-600 kN/m over 15 mm) at three gaps [m].
_REAL_CAR_STOP_TABLE = ([0.0, 0.002, 0.005, 0.010, 0.015], [0.0, 200.0, 1000.0, 3500.0, 6500.0])
_REAL_CAR_GAPS = {"BS-F": 0.0045, "BS-F2": 0.006, "BS-R": 0.006}

_REAL_CAR_PLAN = """\
# Rig plan (rig-plan/1), written by shockplan demo: the README's "A real car" example.
# The seed paper's identification experiment (a baseline run, then a softer shock at each
# corner) on a GT-like car whose bump stops are fitted and whose static corner loads are
# known, 2 % sensor noise. Run it with
#   shockplan rig simulate --plan real_car/plan.toml --vehicle real_car/car.toml \\
#       --out real_car/session
format = "rig-plan/1"
name = "GT-like car with bump stops"
units = "SI"
shock_library = "shocks.toml"
bump_stop_library = "bumpstops.toml"
static_corner_load = @STATIC@   # N, the car at rest
fs_hz = 100.0
duration_s = 100.0
oversample = 4
seed = 25
noise = 0.02

[drive]
kind = "noise"
peak_wheelloader = 0.010          # m
peak_aero_heave = 2000.0          # N
roll_moment_multiple = 0.2
pitch_moment_multiple = 0.2

[[run]]
name = "baseline"
setup = { LF = "G1.00", RF = "G1.00", LR = "G1.00", RR = "G1.00" }
role = "baseline"
bump_stops = { LF = "BS-F", RF = "BS-F", LR = "BS-R", RR = "BS-R" }
@SWAPS@"""

_REAL_CAR_WHATIF = """\
# What-if study (shockplan-whatif/1), written by shockplan demo: the README's "A real car"
# example. The front packers 1 mm thinner and thicker than each setup's, and the softer
# front bump stop. Run it with
#   shockplan whatif --model real_car/model.npz --drive real_car/track_drive.csv \\
#       --shocks real_car/shocks.toml --ranking real_car/ranking/ranking.csv --top 5 \\
#       --perturb real_car/whatif.toml --out real_car/whatif
format = "shockplan-whatif/1"
units = "SI"

[[factor]]
name = "front packers"
kind = "packer"
corners = ["LF", "RF"]
levels = [-0.001, 0.001]          # m

[[factor]]
name = "front bump stops"
kind = "bump_stop"
corners = ["LF", "RF"]
levels = ["BS-F2"]
"""

# Buildable-curve constraints a race shock meets, in round numbers of each unit system:
# the slopes and maximum force of planner.optimize.default_constraints (the imperial ones
# within 6 %), plus rebound at least as firm as bump and at most 3 times (a rebound/bump
# force ratio of 1 to 3 at low speed, as most race valving): (low-speed slope, high-speed
# slope [damping]; the ratio's velocity; max force).
_CONSTRAINTS = {
    "imperial": {"low": (3.0, 225.0), "high": (0.0, 85.0), "segment": (5.7, 228.0), "ratio_v": 2.0,
                 "max_force": 2250.0, "damping": "lbf/(in/s)", "velocity": "in/s",
                 "force": "lbf", "reach": "39.4 in/s"},
    "SI": {"low": (500.0, 40000.0), "high": (0.0, 15000.0), "segment": (1000.0, 40000.0),
           "ratio_v": 0.05,
           "max_force": 10000.0, "damping": "N/(m/s)", "velocity": "m/s", "force": "N",
           "reach": "1 m/s"},
}

# the README's "What if" example, as written there (after a header naming the units)
_WHATIF_TOML = """\
# What-if study (shockplan-whatif/1), written by shockplan demo: the README's "What if"
# example. Each shock's force scaled by its own draw from 0.95 to 1.05 (a dyno tolerance
# of +-5 %), 50 Monte Carlo draws. Run it with
#   shockplan whatif --model model.npz --drive track_drive.csv --shocks crate.toml \\
#       --ranking ranking/ranking.csv --top 10 --perturb whatif.toml --units @UNITS@ \\
#       --out whatif/
format = "shockplan-whatif/1"
design = "monte-carlo"
n_draws = 50

[[factor]]
name = "shock tolerance"
kind = "shock_scale"
corners = ["LF", "RF", "LR", "RR"]
independent = true
distribution = { kind = "uniform", low = 0.95, high = 1.05 }
"""


def run_demo(out, *, overwrite=False, progress=True, drive_s=120.0):
    """Run the demo into folder `out`.

    Parameters
    ----------
    out : str or Path
        Output folder; must not exist (or be empty) unless `overwrite`.
    overwrite : bool
        Replace an existing folder once the new results are complete.
    progress : bool
        Show progress bars.
    drive_s : float
        Duration of the track drive [s].

    Returns
    -------
    str
        A short summary for the terminal.

    Raises
    ------
    FileExistsError
        If `out` exists, is not empty and `overwrite` is false.
    """
    from ident.data.files import atomic_dir
    from ident.data.drive import make_track_drive, write_drive
    from ident.identify.pipeline import identify_session
    from ident.sim.virtual_rig import default_plan, simulate_session
    from ident.data.session import write_session
    from ident.models.library import read_shock_library
    from ident.models.vehicle import example_vehicle, modal_summary
    from planner.optimize import optimize_curves, write_optimum
    from planner.options import HistogramOptions, LoopOptions
    from planner.rank import rank_setups
    from planner.setups import resolve_baseline

    out = Path(out)
    with atomic_dir(out, overwrite=overwrite) as work:
        # on a fresh machine numba compiles every kernel on first use. The virtual rig's two
        # compile side by side (the rig response's in a worker, the one-setup loop's here);
        # then a worker compiles the predictions' kernel and the screening kernels into
        # numba's cache while the virtual rig runs here. Otherwise these are cache loads.
        # One worker, forked before this process uses any kernel, takes the jobs in turn:
        # the rig response's kernel (the virtual rig needs it), then the screening and
        # predictions' kernels, starting as soon as the first is done rather than when this
        # process is done with the one-setup loop (about twice the rig kernel's compile):
        # no core idles while the other compiles, and by the predictions' kernel the
        # one-setup loop's `loop_one` (which it calls) is in numba's cache. Last, the
        # README's examples (which need none of this process's results) are written by
        # that worker while this process identifies (whose last steps run on one core).
        rig_kernel, warm, examples = _start_jobs(
            _warm_rig_response, _warm_kernels, functools.partial(_write_examples_job, work))
        compiler = steps = plots = None
        try:
            _warm_one_setup_loop()
            # a warm-up that fails only costs time (e.g. a forked worker cannot use numba's
            # OpenMP threads once this process has): the kernels then compile here on first
            # use
            _settle_job(rig_kernel)
            vehicle = example_vehicle()
            plan = default_plan()
            units = plan.units
            session = simulate_session(plan, vehicle, progress=progress)
            # the optimizer's compile worker (below) is spawned now: its interpreter starts
            # and imports while this process identifies, not once the model is there
            compiler = _spawn_worker(_import_optimizer)
            # Parquet, float32 (far finer than the sensors): 55 MB against 306 MB of CSV
            write_session(session, work / "session", units=units, run_format="parquet",
                          float_dtype="float32")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model = identify_session(session)
            log.info("demo: identified the session")
            model.save(work / "model.npz")
            log.info("demo: saved the model")
            drive = make_track_drive(duration_s=drive_s, fs_hz=plan.fs_hz, seed=7,
                                     wheelbase_m=vehicle.a_m + vehicle.b_m,
                                     track_width_m=vehicle.track_front_m, name="demo track")
            library = read_shock_library(DEMO_LIBRARY_PATH)
            baseline = resolve_baseline("B20", library)  # B20 at every corner, "baseline"
            # the optimizer's C compile (once per machine) needs only the model: a worker
            # runs the optimization's global stage and compiles the problem it ends on while
            # this process ranks; the optimization here, reaching that problem, waits for
            # the compile (planner.optimize.cache) rather than compiling it again. The FRF
            # plots (one core) are drawn by a worker while this process optimizes (one core).
            # spawned: the global stage screens (numba's OpenMP pool)
            steps = _submit(compiler, _compile_optimizer_job, model, drive, library, baseline)
            write_csv(work / "model_summary.csv", model.summary(), units=units)
            write_drive(drive, work / "track_drive.csv", units=units)
            write_demo_inputs(work, units=units, channels=session.runs[0].channels)
            write_demo_rig_files(work / DEMO_RIG_FILES, session, duration_s=DEMO_RIG_FILES_S)
            # the ranking needs the kernels the warm-up worker compiles: on a fresh machine
            # it may still be compiling them while this process identified
            _settle_job(warm)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                log.info("demo: ranking the crate's setups")
                ranking = rank_setups(model, drive, library, baseline=baseline, top=20,
                                      loop=LoopOptions(
                                          histograms=HistogramOptions.default(units)),
                                      progress=progress)
            used = {"model": "model.npz (identified from session/)",
                    "drive": "track_drive.csv", "crate": "crate.toml"}
            # the ranking's files (CSV, XLSX, plots) and the FRF plots, one core, are written
            # by a worker while this process optimizes (one core)
            plots = _start_job(_reports_job, work, ranking, used, vehicle, units)
            log.info("demo: optimizing the curves")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                optimum = optimize_curves(model, drive, library, baseline=baseline,
                                          progress=progress)
            _settle_job(steps)  # a failed compile only cost time: the optimizer compiled
            write_optimum(optimum, library, work / "optimize", units=units,
                          run={k: used[k] for k in ("model", "crate")})
            modes = modal_summary(vehicle).table()
            _finish_job(examples)
            files = plots.result()  # the worker's errors are raised here
        except BaseException:
            # nothing may write into the folder once it is rolled back
            for job in (rig_kernel, warm, examples, steps, plots):
                _settle_job(job)
            if compiler is not None:
                compiler.shutdown(wait=True, cancel_futures=True)
            raise
    best = ranking.table.iloc[0]
    lines = [
        f"shockplan demo -> {out}",
        f"  vehicle: {vehicle.name}; modes [Hz]: " + ", ".join(
            f"{lab} {f:.1f}" for lab, f in zip(modes["mode"], modes["no_damping_hz"])),
        f"  rig session: {out / 'session'} ({len(session.runs)} runs x "
        f"{session.runs[0].n_samples / session.fs_hz:g} s at {session.fs_hz:g} Hz)",
        f"  identified model: {out / 'model.npz'} (median fit error "
        f"{float(model.summary().fit_error.median()):.4f}); FRF plots: {out / 'frf_plots'}",
        f"  ranked {len(ranking.screening)} setups of {len(library)} shocks on a "
        f"{drive_s:g} s track drive; {len(ranking.table)} simulated in the time domain "
        f"(screening vs time domain Spearman {ranking.agreement['spearman']:.3f})",
        f"  best: {ranking.best} (score {best['score']:.4f} vs baseline "
        f"{ranking.objective.total_weight:.3f}; grip {best.get('score_grip', float('nan')):.4f},"
        f" platform {best.get('score_platform', float('nan')):.4f})",
        "  top 5: " + ", ".join(ranking.table.index[:5]),
        "  ranking: " + ", ".join(str(out / "ranking" / Path(p).name) for p in files.values()),
        f"  optimized curves (front, rear): {optimum.verdict()}; closest crate setup "
        f"{optimum.table.index[optimum.table['kind'] == 'closest'][0]}; files in "
        f"{out / 'optimize'}",
    ]
    return "\n".join(lines)


def _example_paths(folder, names, overwrite):
    """An example's folder (created) and its files' paths, after checking that none of them
    exists unless `overwrite` (so that nothing is written when one would be refused)."""
    folder = Path(folder)
    paths = {name: folder / name for name in names}
    for path in paths.values():
        check_can_write(path, overwrite=overwrite)
    folder.mkdir(parents=True, exist_ok=True)
    return folder, paths


def write_demo_inputs(folder, *, units="imperial", channels=ALL_CHANNELS, overwrite=False):
    """Write the inputs the README's examples need into `folder`, each atomically.

    Parameters
    ----------
    folder : str or Path
        The demo's output folder (created if missing).
    units : {"SI", "imperial"}
        Unit system of the crate and the curve constraints (the demo's: that of its
        rig session and drive). The car keeps its file's imperial units; the objective
        and the channel map have no unit system of their own.
    channels : sequence of str
        Canonical channels of the demo's rig session: those the channel map maps.
    overwrite : bool
        Replace existing files.

    Returns
    -------
    dict of str to pathlib.Path
        File name -> written path, in :data:`DEMO_INPUT_FILES` order:

        - ``crate.toml``: the built-in crate (``planner/examples/library.toml``) through
          :func:`ident.models.library.write_shock_library`, in `units`;
        - ``car.toml``: the paper's car, a copy of ``ident/examples/paper_car.toml``;
        - ``objective.toml``: :func:`planner.objective.default_objective`;
        - ``constraints.toml``: buildable-curve constraints (slopes, a rebound/bump
          ratio, a maximum force), read by
          :func:`planner.optimize.constraints.read_curve_constraints`;
        - ``whatif.toml``: the README's what-if example
          (:func:`planner.whatif.read_perturbations`);
        - ``rig_map.toml``: a channel map (:func:`ident.data.formats.read_channel_map`)
          of every channel in `channels` to a file channel of the same name, in SI
          units, sign 1.

    Raises
    ------
    FileExistsError
        If one of the files exists and `overwrite` is false (checked before any is
        written, so none is).
    ValueError
        If `units` is not a unit system, or `channels` names no channel or one that is
        not canonical.

    Examples
    --------
    >>> import tempfile
    >>> from ident.models.library import read_shock_library
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     paths = write_demo_inputs(folder)
    ...     crate = read_shock_library(paths["crate.toml"])
    >>> list(paths)
    ['crate.toml', 'car.toml', 'objective.toml', 'constraints.toml', 'whatif.toml', 'rig_map.toml']
    >>> list(crate) == list(_demo_library())
    True
    """
    units = check_units(units, where="write_demo_inputs: units")
    channels = tuple(channels)
    bad = [c for c in channels if c not in ALL_CHANNELS]
    if not channels or bad:
        raise ValueError(f"write_demo_inputs: channels {bad or '(none)'} are not canonical "
                         "channels; give names of ident.data.channels.ALL_CHANNELS")
    folder, paths = _example_paths(folder, DEMO_INPUT_FILES, overwrite)
    write_shock_library(_demo_library(), paths["crate.toml"], units=units, overwrite=True)
    atomic_write_bytes(paths["car.toml"], EXAMPLE_VEHICLE_PATH.read_bytes())
    objective_to_toml(default_objective(), paths["objective.toml"], overwrite=True)
    atomic_write_text(paths["constraints.toml"], _constraints_toml(units))
    atomic_write_text(paths["whatif.toml"], _WHATIF_TOML.replace("@UNITS@", units))
    rig_map = {"format": CHANNEL_MAP_FORMAT,
               "name": "canonical channels in SI (shockplan demo)",
               "channels": {c: {"source": c, "units": _SI_UNIT[quantity_of(c)], "sign": 1}
                            for c in channels}}
    atomic_write_toml(paths["rig_map.toml"], rig_map, header=(
        f"Channel map ({CHANNEL_MAP_FORMAT}), written by shockplan demo: every channel of the\n"
        "demo's rig session, named as in shockplan (source = the canonical name), in SI\n"
        "units with shockplan's signs (up and compression positive, sign = 1). For a real\n"
        "rig, set each channel's source, units and sign (and scale, offset) to the rig's."))
    log.info("demo: wrote the examples' inputs to %s", folder)
    return paths


def write_demo_rig_files(folder, session, *, overwrite=False, duration_s=None):
    """Write a session's runs as a real rig's files: RPC III, one ``<run>.rsp`` a run.

    The README's import example reads them back through ``rig_map.toml``
    (:func:`write_demo_inputs`): every canonical channel under its own name, in SI
    units with shockplan's signs, 16-bit integers as an RPC III V5 controller writes
    them (each channel quantized to its full scale).

    Parameters
    ----------
    folder : str or Path
        Output folder (created).
    session : ident.data.session.RigSession
        The session whose runs to write (SI inside).
    overwrite : bool
        Replace existing files.
    duration_s : float, optional
        Write each run's first `duration_s` seconds only (default: the whole run); the
        demo writes :data:`DEMO_RIG_FILES_S`.

    Returns
    -------
    dict of str to pathlib.Path
        Run name -> written file, in run order.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    n = None if duration_s is None else max(2, int(round(duration_s * session.fs_hz)))
    paths = {}
    for run in session.runs:
        names = [c for c in ALL_CHANNELS if c in run.channels]
        paths[run.name] = write_rpc3(
            folder / f"{run.name}.rsp", {c: run.channels[c][:n] for c in names},
            fs_hz=session.fs_hz, units={c: _SI_UNIT[quantity_of(c)] for c in names},
            overwrite=overwrite)
    log.info("demo: wrote %d runs as RPC III files to %s", len(paths), folder)
    return paths


def _constraints_toml(units):
    """The text of the demo's ``constraints.toml`` in `units` (see :data:`_CONSTRAINTS`)."""
    c = _CONSTRAINTS[units]
    low, high, seg = (f"[{a!r}, {b!r}]" for a, b in (c["low"], c["high"], c["segment"]))
    ratio = f"{{ velocity = {c['ratio_v']!r}, min = 1.0, max = 3.0 }}"

    def line(text, comment):  # comments in one column
        return f"{text:<40}# {comment}\n"

    return "".join([
        "# Curve constraints (curve-constraints/1), written by shockplan demo: a buildable\n",
        f"# race shock, in {units} units. Passive and increasing curves always hold. Use with\n",
        "#   shockplan optimize --model model.npz --drive track_drive.csv --shocks crate.toml \\\n",
        f"#       --baseline B20 --constraints constraints.toml --units {units} --out optimum/\n",
        'format = "curve-constraints/1"\n',
        f'units = "{units}"\n',
        "\n",
        line("[bump]", "compression, v > 0"),
        line(f"low_speed_slope = {low}", f"{c['damping']}: from 0 to the first knot"),
        line(f"high_speed_slope = {high}", f"{c['damping']}: beyond the last knot"),
        line(f"segment_slope = {seg}", f"{c['damping']}: every segment where the car spends "
             "99 % of its time"),
        "\n",
        line("[rebound]", "extension, v < 0"),
        line(f"low_speed_slope = {low}", f"{c['damping']}"),
        line(f"high_speed_slope = {high}", f"{c['damping']}"),
        line(f"segment_slope = {seg}", f"{c['damping']}"),
        "\n",
        "[shape]\n",
        line("digressive = true", "slopes do not grow away from 0"),
        line("min_slope_ratio = 0.15", "no segment flatter than 0.15 x its side's first"),
        line("crate_envelope = [0.333, 3.0]", "forces within 1/3 of the crate's weakest, 3 x "
             "its strongest"),
        f"# |F(-v)| / F(v) between min and max at v = velocity [{c['velocity']}]\n",
        f"rebound_bump_ratio = {ratio}\n",
        line(f"max_force = {c['max_force']!r}", f"{c['force']}: |F| at every knot and at {c['reach']}"),
    ])


def _reports_job(work, ranking, used, vehicle, units):
    """Write the ranking's files (:func:`planner.report.write_ranking`, the screening's
    predictions, the histograms) into ``work / "ranking"``, then the FRF plots
    (:func:`_frf_plots_job`). Runs in a worker while the demo's process optimizes.

    Returns the ranking's files (name -> path), as :func:`planner.report.write_ranking`."""
    from planner.histograms import HISTOGRAMS_FILE, write_histograms_csv
    from planner.report import write_predictions_csv, write_ranking

    files = write_ranking(ranking.table, work / "ranking", units=units,
                          objective=ranking.objective, baseline=ranking.baseline,
                          run=used, histograms=ranking.histograms.table(units))
    write_predictions_csv(ranking.screening, work / "ranking" / "screening.csv", units=units)
    write_histograms_csv(ranking.histograms, work / "ranking" / HISTOGRAMS_FILE, units=units)
    _frf_plots_job(work / "model.npz", vehicle, work / "frf_plots", units)
    return files


def _frf_plots_job(model_path, vehicle, folder, units):
    """Write the demo's FRF plots: estimate, conditioned estimate, fit and the known car's
    closed-loop FRF around the model's c_bar (the ideal). Runs in a worker process."""
    from ident.identify.model import load_model
    from ident.identify.plots import write_frf_plots
    from ident.models.vehicle import build_full_car

    model = load_model(model_path)
    truth_model = build_full_car(vehicle)
    order = [truth_model.output_names.index(o) for o in model.output_names]

    def truth(f_hz):
        return truth_model.frequency_response(f_hz, damping_n_s_m=model.cbar_n_s_m)[order]

    write_frf_plots(model, folder, outputs=_PLOT_OUTPUTS, units=units, truth=truth)
    return str(folder)


def _compile_optimizer_job(model, drive, library, baseline):
    """Compile the optimizer's step functions (:func:`planner.optimize.compile_curves`) into
    the machine's cache, with the arguments the demo optimizes with. Runs in a worker."""
    from planner.optimize import compile_curves

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return compile_curves(model, drive, library, baseline=baseline)


def _write_examples_job(work):
    """Write the README's examples (real car, clicks, track data, third elements) into the
    demo's folder `work`. Runs in the warm-up worker (their kernels are its own)."""
    write_real_car_example(work / REAL_CAR_FOLDER)
    write_clicks_example(work / CLICKS_FOLDER)
    write_track_example(work / TRACK_FOLDER)
    write_proto_example(work / PROTO_FOLDER)
    return True


def _warm_kernels():
    """The screening kernels, then the predictions' kernel (:func:`_warm_screening`,
    :func:`_warm_predictions`), one after the other in one worker: a second worker would
    compete with the identification for the two cores. Screening first: the predictions'
    kernel calls the one-setup loop's `loop_one` (one compiled version for every caller),
    which the demo's process compiles meanwhile (:func:`_warm_one_setup_loop`); started
    later, this worker loads it from numba's cache instead of compiling it a second time."""
    _warm_screening()
    _warm_predictions()
    return True


def _warm_screening():
    """Compile (into numba's cache) the screening kernels on a small problem; the demo's
    process then loads them. Runs in a worker process."""
    from planner.screen import screen_setups
    from planner.setups import enumerate_setups

    plant, drive = _warm_plant_and_drive()
    library = _demo_library()
    screen_setups(plant, drive, enumerate_setups(library)[:2], library)
    return True


def _warm_predictions():
    """Compile (into numba's cache) the predictions' kernel (the setup-parallel loop with
    each setup's metrics) on a small problem with a zero rig response; the demo's process
    then loads it. Runs in the warm-up worker after the rig response's kernel."""
    from ident.sim.closedloop import simulate_batch_metrics
    from planner.setups import enumerate_setups

    plant, drive = _warm_plant_and_drive()
    library = _demo_library()
    setups = [[library[i] for i in s.ids()] for s in enumerate_setups(library)[:2]]
    # the predictions always run the kernel's histogram variant (planner.predict)
    simulate_batch_metrics(plant, drive, setups, oversample=1, rig=_zero_rig(plant, drive),
                           histogram_bins=(0.025, 0.25, 0.025))
    return True


def _demo_library():
    from ident.models.library import read_shock_library

    return read_shock_library(DEMO_LIBRARY_PATH)


def _zero_rig(plant, drive):
    """A zero rig response of the right shape (the warm-ups need only the types)."""
    import numpy as np

    from ident.sim.closedloop import RigResponse

    n = drive.n_samples
    return RigResponse(v_fine=np.zeros((n, 4)), y=np.zeros((len(plant.output_names), n)),
                       u_fine=np.zeros((n, 7)), fs_hz=drive.fs_hz, oversample=1, n_samples=n,
                       plant_name=plant.name, output_names=tuple(plant.output_names))


@functools.lru_cache(maxsize=1)
def _warm_plant_and_drive():
    """The paper car's loop plant and a short track drive, for the warm-up jobs (built once
    per process: a worker forked after this process built them inherits them; read only)."""
    from ident.data.drive import make_track_drive
    from ident.models.vehicle import build_full_car, example_vehicle

    vehicle = example_vehicle()
    drive = make_track_drive(duration_s=10.0, fs_hz=100.0, seed=1,
                             wheelbase_m=vehicle.a_m + vehicle.b_m,
                             track_width_m=vehicle.track_front_m)
    return build_full_car(vehicle).loop_plant(), drive


def _warm_rig_response():
    """Compile (into numba's cache) the rig-response kernel. Runs in a worker process."""
    from ident.sim.closedloop import rig_response

    plant, drive = _warm_plant_and_drive()
    rig_response(plant, drive, oversample=1)
    return True


def _warm_one_setup_loop():
    """Compile (or load) the one-setup loop kernel on a zero rig response of the right shape,
    so that the rig-response kernel is left to the worker compiling it meanwhile."""
    from ident.sim.closedloop import simulate

    plant, drive = _warm_plant_and_drive()
    library = _demo_library()
    simulate(plant, drive, [library["B20"]] * 4, oversample=1, rig=_zero_rig(plant, drive))


def _start_job(func, *args, method="fork"):
    """Start ``func(*args)`` on a worker process started by `method` (POSIX ``fork``; or
    ``spawn``, a fresh interpreter, for a job that runs a numba parallel kernel: a process
    forked after one used its OpenMP pool cannot use it), or run it here.

    Returns the future (done, when it ran in this process).
    """
    import concurrent.futures
    import multiprocessing

    if method not in multiprocessing.get_all_start_methods():
        future = concurrent.futures.Future()
        future.set_result(func(*args))
        return future
    pool = concurrent.futures.ProcessPoolExecutor(
        max_workers=1, mp_context=multiprocessing.get_context(method),
        initializer=die_with_parent, initargs=(os.getpid(),))
    future = pool.submit(func, *args)
    pool.shutdown(wait=False)
    return future


def _spawn_worker(func):
    """A worker process started by ``spawn`` (a fresh interpreter: it may use numba's OpenMP
    pool), running ``func()`` first (e.g. its imports); None where spawn is not available.
    Give it jobs with :func:`_submit`."""
    import concurrent.futures
    import multiprocessing

    if "spawn" not in multiprocessing.get_all_start_methods():
        return None
    pool = concurrent.futures.ProcessPoolExecutor(
        max_workers=1, mp_context=multiprocessing.get_context("spawn"),
        initializer=die_with_parent, initargs=(os.getpid(),))
    pool.submit(func)
    return pool


def _submit(pool, func, *args):
    """Run ``func(*args)`` on the worker `pool` (:func:`_spawn_worker`), its last job (the
    worker ends when it is done), or here when `pool` is None. Returns the future, or None
    when it already ran in this process."""
    if pool is None:
        func(*args)
        return None
    future = pool.submit(func, *args)
    pool.shutdown(wait=False)
    return future


def _import_optimizer():
    """The compile worker's first job: the optimizer's imports (casadi, the screening)."""
    import planner.optimize  # noqa: F401 - imported for its cost, ahead of the compile
    import planner.screen  # noqa: F401

    return True


def _start_jobs(*funcs):
    """Start ``func()`` for each of `funcs`, one after the other on one forked worker process
    (or run them here where fork is not available).

    Returns their futures (None for one that already ran in this process).
    """
    import concurrent.futures
    import multiprocessing

    if "fork" not in multiprocessing.get_all_start_methods():
        for func in funcs:
            func()
        return [None] * len(funcs)
    pool = concurrent.futures.ProcessPoolExecutor(
        max_workers=1, mp_context=multiprocessing.get_context("fork"),
        initializer=die_with_parent, initargs=(os.getpid(),))
    futures = [pool.submit(func) for func in funcs]
    pool.shutdown(wait=False)
    return futures


def _finish_job(future):
    """Wait for a worker; its errors are raised here."""
    if future is not None:
        future.result()


def _settle_job(future):
    """Wait for a worker without raising: the caller is already failing, or the worker's
    work was optional (a warm-up)."""
    if future is not None:
        try:
            future.result()
        except BaseException:  # noqa: BLE001 - the caller's error is the one to report
            log.debug("a demo worker failed (its error is not the one to report)", exc_info=True)


def write_real_car_example(folder, *, overwrite=False):
    """Write the README's real-car example (:data:`REAL_CAR_FILES`) into `folder`.

    A GT-like car (:func:`ident.models.vehicle.example_gt_vehicle`) with bump stops and
    static corner loads, its crate, a rig plan that fits the stops and declares the loads,
    a track drive and a what-if study of packers and bump stops; all SI.

    Parameters
    ----------
    folder : str or Path
        Created if missing.
    overwrite : bool
        Replace existing files.

    Returns
    -------
    dict of str to pathlib.Path
        File name -> written path, in :data:`REAL_CAR_FILES` order.

    Raises
    ------
    FileExistsError
        If one of the files exists and `overwrite` is false (none is written then).
    """
    from ident.data.drive import make_track_drive, write_drive
    from ident.models.bumpstops import BumpStop, BumpStopLibrary, write_bump_stops
    from ident.models.library import ShockLibrary
    from ident.models.shocks import DigressiveShock
    from ident.models.vehicle import example_gt_vehicle, write_vehicle

    folder, paths = _example_paths(folder, REAL_CAR_FILES, overwrite)
    car = example_gt_vehicle()
    write_vehicle(car, paths["car.toml"], overwrite=True)
    crate = ShockLibrary.from_models([
        DigressiveShock(f"G{k:.2f}", bump_low_n_s_m=9000 * k, bump_knee_m_s=0.08,
                        bump_high_n_s_m=3500 * k, rebound_low_n_s_m=14000 * k,
                        rebound_knee_m_s=0.08, rebound_high_n_s_m=5000 * k, lag_s=0.002,
                        description=f"digressive valving at {k:g} x the baseline's force")
        for k in _REAL_CAR_LEVELS])
    write_shock_library(crate, paths["shocks.toml"], overwrite=True)
    stops = BumpStopLibrary([BumpStop(sid, gap, *_REAL_CAR_STOP_TABLE)
                             for sid, gap in _REAL_CAR_GAPS.items()])
    write_bump_stops(stops, paths["bumpstops.toml"], overwrite=True)
    static = ", ".join(f"{c} = {round(float(x), -1):.1f}"
                       for c, x in zip(("LF", "RF", "LR", "RR"), car.static_corner_load_n))
    swaps = []
    for c in ("LF", "RF", "LR", "RR"):
        setup = ", ".join(f'{k} = "{"G0.60" if k == c else "G1.00"}"'
                          for k in ("LF", "RF", "LR", "RR"))
        swaps.append(f'\n[[run]]\nname = "swap-{c}"\nsetup = {{ {setup} }}\nrole = "swap"\n'
                     'bump_stops = { LF = "BS-F", RF = "BS-F", LR = "BS-R", RR = "BS-R" }\n')
    swaps = "".join(swaps)
    atomic_write_text(paths["plan.toml"], _REAL_CAR_PLAN.replace("@STATIC@", f"{{ {static} }}")
                      .replace("@SWAPS@", swaps))
    drive = make_track_drive(duration_s=60.0, fs_hz=100.0, seed=3, roughness_m3=16e-6,
                             wheelbase_m=car.a_m + car.b_m, track_width_m=car.track_front_m,
                             aero={"aero_heave": 1500.0, "aero_pitch": 800.0,
                                   "aero_roll": 300.0}, name="GT track")
    write_drive(drive, paths["track_drive.csv"], overwrite=True)
    atomic_write_text(paths["whatif.toml"], _REAL_CAR_WHATIF)
    log.info("demo: wrote the real-car example to %s", folder)
    return paths


def write_clicks_example(folder, *, overwrite=False):
    """Write the README's adjustable-damper example (:data:`CLICKS_FILES`) into `folder`.

    Raw dyno runs of a two-adjuster clicker (:class:`ident.sim.dampers.ClickerDamper`,
    the truth) at five settings, as a dyno logs them (time in ms, load in lbf with
    tension positive, position in mm from full extension, oil temperature; 50 N gas
    force, a 4 ms lag, noise), the dyno map that reads them, the crate naming the clicker
    as an adjustable shock whose sheet the user imports, and rig costs with a click change
    time. The clicker suits the demo's (the paper's) car: its best setting on the demo's
    track lies inside both ranges.

    Parameters
    ----------
    folder : str or Path
        Created if missing.
    overwrite : bool
        Replace existing files.

    Returns
    -------
    dict of str to pathlib.Path
        File name -> written path, in :data:`CLICKS_FILES` order.

    Raises
    ------
    FileExistsError
        If one of the files exists and `overwrite` is false (none is written then).
    """
    import numpy as np
    import pandas as pd

    from ident.sim.dampers import ClickerDamper
    from ident.dyno.virtual import simulate_dyno_run

    folder, paths = _example_paths(folder, CLICKS_FILES, overwrite)
    (folder / "dyno").mkdir(parents=True, exist_ok=True)
    truth = ClickerDamper()
    rng = np.random.default_rng(26)
    for j, setting in enumerate(_CLICKS_DYNO_SETTINGS):
        run = simulate_dyno_run(truth.shock_at(setting), peak_velocities_m_s=_CLICKS_DYNO_SPEEDS,
                                stroke_m=0.05, cycles_per_speed=3, fs_hz=500.0,
                                lag_s=_CLICKS_LAG_S, gas_force_n=50.0, noise_force_n=3.0,
                                noise_disp_m=2e-5, temperature_c=(40.0 + j, 41.0 + j), rng=rng)
        raw = pd.DataFrame({"Time (ms)": np.round(run["time"].to_numpy() * 1e3, 3),
                            "Load": np.round(-run["force"].to_numpy() / 4.4482216152605, 3),
                            "Position": np.round(run["displacement"].to_numpy() * 1e3 + 25.0, 4),
                            "Shock Temp": np.round(run["temperature"].to_numpy(), 2)})
        name = f"dyno/ls{setting['ls']}-hs{setting['hs']}.csv"
        atomic_write_text(paths[name], raw.to_csv(index=False, lineterminator="\n"))
    atomic_write_text(paths["dyno_map.toml"], _CLICKS_MAP)
    atomic_write_text(paths["shocks.toml"], _CLICKS_SHOCKS)
    atomic_write_text(paths["rig.toml"], _CLICKS_RIG)
    log.info("demo: wrote the adjustable-damper example to %s", folder)
    return paths


def write_track_example(folder, *, overwrite=False):
    """Write the README's track-data example (:data:`TRACK_FILES`) into `folder`.

    The paper car (the truth) runs two laps of a virtual track (:mod:`ident.sim.virtual_track`: a
    road at a varying speed, 35-75 m/s, with the aero loads of ``aero.toml``) on the demo
    crate's DM shocks, and its logger writes them: an MDF4 file with the damper
    potentiometers (mm, with their zero offsets) and the ride-height lasers (mm, absolute)
    at 200 Hz, and the speed in km/h at 20 Hz, 2 % sensor noise. Beside it: the channel map
    that reads the log, the aero model, rig limits, and a rig plan that plays the drive
    ``drive from-track`` writes (``drive.csv``) for ``drive iterate``.

    Parameters
    ----------
    folder : str or Path
        Created if missing.
    overwrite : bool
        Replace existing files.

    Returns
    -------
    dict of str to pathlib.Path
        File name -> written path, in :data:`TRACK_FILES` order.

    Raises
    ------
    FileExistsError
        If one of the files exists and `overwrite` is false (none is written then).
    """
    import numpy as np
    from asammdf import MDF, Signal  # heavy: only the demo writes an MDF file

    from ident.models.aero import read_aero_model
    from ident.models.library import read_shock_library
    from ident.models.vehicle import build_full_car, example_vehicle
    from ident.sim.virtual_track import POT_OFFSET_M, log_track_run, make_track_run

    folder, paths = _example_paths(folder, TRACK_FILES, overwrite)
    atomic_write_text(paths["aero.toml"], _TRACK_AERO)
    atomic_write_text(paths["rig.toml"], _TRACK_RIG)
    atomic_write_text(paths["plan.toml"], _TRACK_PLAN)
    vehicle = example_vehicle()
    aero = read_aero_model(paths["aero.toml"])
    run = make_track_run(**_TRACK_RUN, wheelbase_m=vehicle.a_m + vehicle.b_m,
                         track_width_m=vehicle.track_front_m, aero=aero, name="lap")
    library = read_shock_library(DEMO_LIBRARY_PATH)
    shocks = [library["DM"]] * 4
    logged = log_track_run(build_full_car(vehicle).loop_plant(), run, shocks, noise=0.02,
                           seed=27)
    t = logged.time_s
    fast = [Signal(np.round(logged.channels[canonical] * 1e3, 3), t, name=name, unit=unit)
            for canonical, (name, unit) in _TRACK_LOGGER.items()]
    slow = slice(None, None, int(round(logged.fs_hz / 20.0)))
    speed = Signal(np.round(logged.channels["speed"][slow] * 3.6, 2), t[slow],
                   name="Ground Speed", unit="km/h")
    mdf = MDF(version="4.10")
    mdf.append(fast, comment="200 Hz")
    mdf.append([speed], comment="20 Hz")
    part = folder / ".lap.part.mf4"   # asammdf names its file by the suffix: keep .mf4
    try:
        saved = Path(mdf.save(part, overwrite=True))
        mdf.close()
        os.replace(saved, paths["lap.mf4"])
    finally:
        part.unlink(missing_ok=True)
    lines = ['format = "channel-map/1"', 'name = "the demo car\'s logger (MDF4)"', ""]
    offsets_mm = {f"shock_travel_{c}": round(1e3 * o, 6) for c, o in zip(CORNERS, POT_OFFSET_M)}
    for canonical, (name, unit) in _TRACK_LOGGER.items():
        offset = offsets_mm.get(canonical)
        lines += [f"[channels.{canonical}]", f'source = "{name}"', f'units = "{unit}"',
                  "sign = 1"] + ([f"offset = {offset!r}                  # the pot's reading "
                                  "at zero travel, mm"] if offset else []) + [""]
    lines += ["[channels.speed]", 'source = "Ground Speed"', 'units = "km/h"', "sign = 1", ""]
    header = ("# Channel map (channel-map/1), written by shockplan demo: the README's \"From "
              "track data to a\n# rig drive\" example. The logger's channel names and units to "
              "the canonical log channels.\n")
    atomic_write_text(paths["log_map.toml"], header + "\n".join(lines))
    log.info("demo: wrote the track-data example to %s", folder)
    return paths


def proto_speed_trace(t_s):
    """A lap-like speed trace [m/s] at times `t_s` [s]: between about 15 and 81 m/s, slow
    (below 0.2 Hz: straights, braking zones and corners), the same every call.

    Examples
    --------
    >>> round(float(proto_speed_trace(0.0)), 2)
    55.57
    """
    import numpy as np

    t = np.asarray(t_s, dtype=float)
    return (48.0 + 24.0 * np.sin(2 * np.pi * t / 15.0)
            + 9.0 * np.sin(2 * np.pi * t / 6.3 + 1.0))


def proto_track_drive(vehicle, aero, *, duration_s=120.0, fs_hz=100.0, seed=7, ramp_s=3.0):
    """The prototype example's track drive: the demo's road with the car's downforce.

    The road is :func:`ident.data.drive.make_track_drive` (the demo's, seed 7); the aero
    loads are the car's (:meth:`ident.models.aero.AeroModel.loads`) at
    :func:`proto_speed_trace`'s speeds, mean included (the downforce that closes the heave
    springs at speed; the car is at rest without it), faded in and out over `ramp_s`.

    Parameters
    ----------
    vehicle : ident.models.vehicle.VehicleParams
        Its wheelbase and front track.
    aero : ident.models.aero.AeroModel
        A model of speed alone (``constant`` or ``speed_table``).
    duration_s, fs_hz : float
        Length [s] and sample rate [Hz].
    seed : int
        The road's seed.
    ramp_s : float
        Fade-in and fade-out of the aero loads [s].

    Returns
    -------
    ident.data.drive.Drive
        SI; ``aero_heave`` < 0 is downforce.
    """
    import numpy as np

    from ident.data.drive import Drive, make_track_drive

    road = make_track_drive(duration_s=duration_s, fs_hz=fs_hz, seed=seed,
                            wheelbase_m=vehicle.a_m + vehicle.b_m,
                            track_width_m=vehicle.track_front_m, name="prototype track")
    t = road.time_s
    ramp = np.clip(np.minimum(t, t[-1] - t) / ramp_s, 0.0, 1.0)
    ramp = 0.5 - 0.5 * np.cos(np.pi * ramp)
    loads = aero.loads(proto_speed_trace(t))
    ch = dict(road.channels)
    for name in ("aero_heave", "aero_roll", "aero_pitch"):
        ch[name] = ch.get(name, np.zeros_like(t)) + ramp * np.asarray(loads.channels[name])
    return Drive(name="prototype track with downforce", fs_hz=road.fs_hz, channels=ch)


def write_proto_example(folder, *, overwrite=False):
    """Write the README's third-elements example (:data:`PROTO_FILES`) into `folder`.

    The prototype-like car of ``ident/examples`` (issue 38: heave elements front and rear
    with gapped heave springs, a front roll damper, downforce), copied as is, and its track
    drive (:func:`proto_track_drive`, 120 s at 100 Hz, SI).

    Parameters
    ----------
    folder : str or Path
        Created if missing.
    overwrite : bool
        Replace existing files.

    Returns
    -------
    dict of str to pathlib.Path
        File name -> written path, in :data:`PROTO_FILES` order.

    Raises
    ------
    FileExistsError
        If one of the files exists and `overwrite` is false (none is written then).
    """
    from ident.data.drive import write_drive
    from ident.models.aero import read_aero_model
    from ident.models.vehicle import read_vehicle

    folder, paths = _example_paths(folder, PROTO_FILES, overwrite)
    for name, path in paths.items():
        if name != "track_drive.csv":
            atomic_write_bytes(path, (PROTO_EXAMPLES / name).read_bytes())
    drive = proto_track_drive(read_vehicle(PROTO_EXAMPLES / "proto_car.toml"),
                              read_aero_model(PROTO_EXAMPLES / "proto_aero.toml"))
    write_drive(drive, paths["track_drive.csv"], units="SI", overwrite=True)
    log.info("demo: wrote the third-elements example to %s", folder)
    return paths
