"""Generate the malformed-input corpus of shockplan's command line (issue 13).

Nothing here is stored data: :func:`build_base` writes small *valid* files (a
virtual-rig session in SI, imperial and Parquet, the built-in shock crate, a
setups CSV, a drive, an objective, a model file, a rig plan, a rig file, a
channel map and a TDMS file to import), and :func:`make_cases` derives every
malformed case from them, each in its own folder. A case is the command line to
run and the substrings its one error line must hold (the file and the field).

Run as a script to write the corpus and print its cases::

    python tests/corpus/make_corpus.py /tmp/corpus

Importable: ``tests/test_corpus.py`` builds the base once per test session and
runs every case through :func:`planner.cli.main` in-process.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["Case", "build_base", "make_cases", "make_corpus", "read_only_folder",
           "release_read_only"]

#: Run length of the base session [s]: the shortest that the virtual rig's 1 s drive
#: taper allows with room to spare, so the corpus builds in about a second.
RUN_S = 4.0
FS_HZ = 100.0
IDS = ("B20", "L12", "L28", "DS")  # shocks of the built-in crate used by the setups


@dataclass(frozen=True)
class Case:
    """One malformed input and what the command line must say about it.

    Attributes
    ----------
    name : str
        Unique id (group/what).
    argv : tuple of str
        Arguments of ``shockplan`` (``planner.cli.main``).
    expect : tuple of str
        Substrings of the error line (case-insensitive): the file and the field.
    out : str or None
        The ``--out`` path: it must not be created (or must be left as it was).
    inputs : tuple of str
        Input files and folders that must not change.
    """

    name: str
    argv: tuple
    expect: tuple
    out: str | None = None
    inputs: tuple = field(default=())


# --------------------------------------------------------------------------------------
# Valid base files
# --------------------------------------------------------------------------------------


def _plan(shock_library, *, duration_s=RUN_S, units="SI"):
    from ident.data.channels import CORNERS
    from ident.sim.virtual_rig import PlanRun, default_plan

    base = {c: "B20" for c in CORNERS}
    plan = default_plan()
    return replace(plan, units=units, oversample=2, runs=(
        PlanRun("baseline", base, "baseline", 1, duration_s),
        PlanRun("swap-LF", {**base, "LF": "N8"}, "swap", 1, duration_s),
    ))


def _synthetic_model(path):
    """A small valid model file: one stable pole per pair (the corpus only reads it)."""
    from ident.identify.frf import MODEL_INPUTS
    from ident.identify.model import VehicleModel
    from planner.predict import METRIC_OUTPUTS

    n_out, n_in = len(METRIC_OUTPUTS), len(MODEL_INPUTS)
    shape = (n_out, n_in)
    model = VehicleModel(
        name="corpus", input_names=tuple(MODEL_INPUTS), output_names=tuple(METRIC_OUTPUTS),
        poles=np.full(shape + (1,), -3.0 + 20.0j), residues=np.full(shape + (1,), 1e-3 + 0j),
        direct=np.zeros(shape), n_poles=np.ones(shape, dtype=int),
        order=np.full(shape, 2), fit_error=np.full(shape, 0.01),
        cbar_n_s_m=np.full(4, 3502.5), fs_hz=FS_HZ, settings={"method": "corpus"})
    model.save(path)
    return path


def _write_tdms(path, run):
    from nptdms import ChannelObject, TdmsWriter

    objects = [ChannelObject("Rig", c, np.asarray(x), properties={
        "wf_increment": 1.0 / run.fs_hz, "wf_start_offset": 0.0}) for c, x in run.channels.items()]
    with TdmsWriter(str(path)) as writer:
        writer.write_segment(objects)
    return path


_MAP_UNITS = {"displacement": "m", "force": "N", "moment": "N*m", "velocity": "m/s",
              "acceleration": "m/s^2"}


def _map_text(channels):
    from ident.data.channels import quantity_of

    lines = ['format = "channel-map/1"', 'name = "corpus rig"']
    for c in channels:
        lines += [f"[channels.{c}]", f'source = "{c}"',
                  f'units = "{_MAP_UNITS[quantity_of(c)]}"', "sign = 1"]
    return "\n".join(lines) + "\n"


def build_base(root):
    """Write the valid files every case starts from; return ``{name: Path}``.

    Parameters
    ----------
    root : str or os.PathLike
        An empty (or new) folder.
    """
    from ident.data.channels import RIG_INPUTS, SHOCK_VELOCITIES
    from ident.data.drive import Drive, write_drive
    from ident.sim.virtual_rig import simulate_session
    from ident.data.runs import write_run_table
    from ident.data.session import write_session
    from planner.setups import Setup, write_setups

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    paper = Path(__file__).resolve().parents[2] / "ident" / "examples"
    crate = Path(__file__).resolve().parents[2] / "planner" / "examples" / "library.toml"
    session = simulate_session(_plan(paper / "paper_shocks.toml"))
    p = {"root": root}
    p["session"] = write_session(session, root / "session")
    p["session_imp"] = write_session(session, root / "session_imp", units="imperial")
    p["session_pq"] = write_session(session, root / "session_pq", run_format="parquet")
    p["shocks"] = root / "crate.toml"
    shutil.copyfile(crate, p["shocks"])
    run = session.runs[0]
    drive = Drive(name="corpus", fs_hz=run.fs_hz, channels={c: run.dynamic(c) for c in RIG_INPUTS})
    p["drive"] = write_drive(drive, root / "drive.csv") or root / "drive.csv"
    p["drive_pq"] = root / "drive.parquet"
    write_run_table(p["drive_pq"], run.time_s - run.time_s[0],
                    {c: run.dynamic(c) for c in RIG_INPUTS})
    p["setups"] = root / "setups.csv"
    write_setups([Setup("all-B20", dict.fromkeys(("LF", "RF", "LR", "RR"), "B20")),
                  Setup("soft-front", {"LF": "L12", "RF": "L12", "LR": "B20", "RR": "B20"}),
                  Setup("firm", dict.fromkeys(("LF", "RF", "LR", "RR"), "L28"))], p["setups"])
    p["objective"] = root / "objective.toml"
    p["objective"].write_text(
        'format = "objective/1"\nname = "corpus"\n[weights]\ntire_force_rms_LF = 0.25\n'
        'tire_force_rms_RF = 0.25\nride_height_rms_front = 0.5\n[groups]\n'
        'grip = ["tire_force_rms_LF", "tire_force_rms_RF"]\n[limits]\n'
        'shock_travel_rms_LF = { max_ratio = 1.25 }\n')
    p["model"] = _synthetic_model(root / "model.npz")
    p["plan"] = root / "plan.toml"
    shutil.copyfile(paper / "paper_shocks.toml", root / "paper_shocks.toml")
    p["plan"].write_text(
        'format = "rig-plan/1"\nname = "corpus"\nunits = "SI"\n'
        'shock_library = "paper_shocks.toml"\nfs_hz = 100.0\nduration_s = 3.0\n'
        'oversample = 2\nseed = 1\n[drive]\nkind = "noise"\nf_max_hz = 30.0\n'
        'filter_order = 8\ntaper_s = 0.5\npeak_wheelloader = 0.0254\npeak_aero_heave = 2224.0\n'
        'roll_moment_multiple = 3.0\npitch_moment_multiple = 3.0\n[[run]]\nname = "baseline"\n'
        'setup = { LF = "B20", RF = "B20", LR = "B20", RR = "B20" }\nrole = "baseline"\n')
    p["rig"] = root / "rig.toml"
    p["rig"].write_text('format = "rig/1"\nname = "corpus 7-post"\nswap_min = 8.0\n'
                        'run_overhead_min = 2.0\n')
    p["map"] = root / "map.toml"
    p["map"].write_text(_map_text(list(RIG_INPUTS) + list(SHOCK_VELOCITIES)))
    p["tdms"] = _write_tdms(root / "run.tdms", run)
    p["perturb"] = root / "perturb.toml"
    p["perturb"].write_text('format = "shockplan-whatif/1"\ndesign = "oat"\n'
                            '[[factor]]\nkind = "spring_rate"\ncorner = "front"\n'
                            'values = [0.9, 1.1]\n')
    return p


# --------------------------------------------------------------------------------------
# Mutations
# --------------------------------------------------------------------------------------


def _copy_session(src, dst):
    shutil.copytree(src, dst)
    return dst


def _edit_text(path, old, new, *, count=1):
    text = path.read_text()
    if old not in text:
        raise AssertionError(f"{path}: {old!r} not found; the corpus is out of date")
    path.write_text(text.replace(old, new, count))
    return path


def _edit_frame(path, func):
    # a CSV's 'units' column is not written back (nor was the earlier '# units:' line)
    frame = (pd.read_parquet(path) if path.suffix == ".parquet" else
             pd.read_csv(path).drop(columns="units"))
    frame = func(frame)
    if path.suffix == ".parquet":
        frame.to_parquet(path, index=False)
    else:
        frame.to_csv(path, index=False)
    return path


def _set(col, row, value):
    def f(frame):
        frame = frame.astype({col: object}) if isinstance(value, str) else frame
        frame.loc[row, col] = value
        return frame
    return f


def read_only_folder(path):
    """Make `path` a folder no one may write in (root too: the immutable flag).

    Returns True if it is read-only for this process.
    """
    path.mkdir(parents=True, exist_ok=True)
    os.chmod(path, stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP)
    if os.geteuid() == 0:
        subprocess.run(["chattr", "+i", str(path)], check=False, capture_output=True)
    probe = path / ".probe"
    try:
        probe.touch()
    except OSError:
        return True
    probe.unlink()
    return False


def release_read_only(path):
    """Undo :func:`read_only_folder` (so that the folder can be removed)."""
    if os.geteuid() == 0:
        subprocess.run(["chattr", "-i", str(path)], check=False, capture_output=True)
    if path.exists():
        os.chmod(path, stat.S_IRWXU)


def make_cases(base, root=None):
    """Derive every malformed case from the valid `base` files; return a list of Case.

    Parameters
    ----------
    base : dict
        :func:`build_base`'s result.
    root : path, optional
        Where the cases' files go (default ``base['root'] / 'cases'``).
    """
    root = Path(base["root"] / "cases" if root is None else root)
    root.mkdir(parents=True, exist_ok=True)
    outs = root / "_outputs"
    outs.mkdir(exist_ok=True)
    cases = []

    def folder(name):
        d = root / name.replace("/", "__")
        d.mkdir()
        return d

    def out(name, suffix):
        return str(outs / (name.replace("/", "__") + suffix))

    # -- commands over the inputs --------------------------------------------------------
    def identify(name, session, expect):
        o = out(name, ".npz")
        cases.append(Case(name, ("-q", "identify", str(session), "--out", o), tuple(expect),
                          out=o, inputs=(str(session),)))

    def predict(name, expect, *, model="paper", drive=None, shocks=None, setups=None,
                units="SI", o=None, extra=()):
        drive, shocks = drive or base["drive"], shocks or base["shocks"]
        setups = setups or base["setups"]
        o = o or out(name, ".csv")
        argv = ("-q", "predict", "--model", str(model), "--drive", str(drive), "--shocks",
                str(shocks), "--setups", str(setups), "--units", units, "--out", o) + extra
        ins = tuple(str(x) for x in (drive, shocks, setups) if Path(x).exists())
        if Path(str(model)).exists():
            ins += (str(model),)
        cases.append(Case(name, argv, tuple(expect), out=o, inputs=ins))

    def rank(name, expect, *, objective=None, setups=None, shocks=None, extra=(), o=None):
        o = o or out(name, "")
        argv = ("-q", "rank", "--model", "paper", "--drive", str(base["drive"]), "--shocks",
                str(shocks or base["shocks"]), "--setups", str(setups or base["setups"]),
                "--out", o, "--simulate", "2", "--no-uncertainty")
        if objective:
            argv += ("--objective", str(objective))
        ins = tuple(str(x) for x in (objective, setups, shocks) if x)
        cases.append(Case(name, argv + extra, tuple(expect), out=o, inputs=ins))

    def simulate(name, plan, expect):
        o = out(name, "")
        cases.append(Case(name, ("-q", "rig", "simulate", "--plan", str(plan), "--out", o),
                          tuple(expect), out=o, inputs=(str(plan),)))

    def import_(name, expect, *, mp=None, tdms=None):
        o = out(name, "")
        mp, tdms = mp or base["map"], tdms or base["tdms"]
        argv = ("-q", "import", str(tdms), "--format", "tdms", "--map", str(mp), "--setup",
                "B20,B20,B20,B20", "--shocks", str(base["shocks"]), "--out", o)
        cases.append(Case(name, argv, tuple(expect), out=o, inputs=(str(mp), str(tdms))))

    def session_case(name, expect, mutate, *, src="session"):
        d = _copy_session(base[src], folder(name) / "session")
        mutate(d)
        identify(name, d, expect)

    run_csv = "runs/baseline.csv"

    # -- sessions: the manifest ---------------------------------------------------------
    session_case("session/typo-units-key", ["session.toml", "unit", "did you mean 'units'"],
                 lambda d: _edit_text(d / "session.toml", 'units = "SI"', 'unit = "imperial"'))
    session_case("session/fs-zero", ["session.toml", "fs_hz", "time"],
                 lambda d: _edit_text(d / "session.toml", 'units = "SI"',
                                      'units = "SI"\nfs_hz = 0'))
    session_case("session/fs-negative", ["session.toml", "fs_hz"],
                 lambda d: _edit_text(d / "session.toml", 'units = "SI"',
                                      'units = "SI"\nfs_hz = -100.0'))
    session_case("session/fs-disagrees", ["session.toml", "fs_hz", "100"],
                 lambda d: _edit_text(d / "session.toml", 'units = "SI"',
                                      'units = "SI"\nfs_hz = 200.0'))
    session_case("session/units-metric", ["session.toml", "units", "metric"],
                 lambda d: _edit_text(d / "session.toml", 'units = "SI"', 'units = "metric"'))
    session_case("session/format-missing", ["session.toml", "format"],
                 lambda d: _edit_text(d / "session.toml", 'format = "rig-session/1"\n', ""))
    session_case("session/not-toml", ["session.toml", "not valid TOML"],
                 lambda d: _edit_text(d / "session.toml", 'name = "', 'name = '))
    session_case("session/binary-manifest", ["session.toml"],
                 lambda d: (d / "session.toml").write_bytes(b"\x00\xff\xfe" * 50))
    session_case("session/duplicate-run-name", ["session.toml", "swap-LF", "more than once"],
                 lambda d: _edit_text(d / "session.toml", 'name = "baseline"',
                                      'name = "swap-LF"'))
    session_case("session/run-missing-file-key", ["session.toml", "baseline", "file"],
                 lambda d: _edit_text(d / "session.toml", 'file = "runs/baseline.csv"\n', ""))
    session_case("session/run-file-not-found", ["baseline", "runs/nothere.csv", "not found"],
                 lambda d: _edit_text(d / "session.toml", "runs/baseline.csv", "runs/nothere.csv"))
    session_case("session/run-key-typo", ["session.toml", "baseline", "rol",
                                          "did you mean 'role'"],
                 lambda d: _edit_text(d / "session.toml", 'role = "baseline"',
                                      'rol = "baseline"'))
    session_case("session/unknown-shock-id", ["session.toml", "baseline", "LF", "B99"],
                 lambda d: _edit_text(d / "session.toml", 'LF = "B20"', 'LF = "B99"'))
    session_case("session/missing-corner", ["session.toml", "baseline", "RR"],
                 lambda d: _edit_text(d / "session.toml", ', RR = "B20" }', " }"))
    session_case("session/bad-role", ["session.toml", "baseline", "role", "base"],
                 lambda d: _edit_text(d / "session.toml", 'role = "baseline"', 'role = "base"'))
    session_case("session/no-runs", ["session.toml", "run"],
                 lambda d: (d / "session.toml").write_text(
                     'format = "rig-session/1"\nname = "x"\nunits = "SI"\n'))
    session_case("session/channels-unknown", ["session.toml", "channels", "wheeloader_LF"],
                 lambda d: _edit_text(d / "session.toml", "\n[[run]]",
                                      '\n[channels]\nwheeloader_LF = "WL"\n\n[[run]]'))
    session_case("session/shock-library-missing", ["session.toml", "shock_library",
                                                   "shocks.toml"],
                 lambda d: (d / "shocks.toml").unlink())

    # -- run files ---------------------------------------------------------------------------
    def run_case(name, expect, func, *, src="session", file=run_csv):
        session_case(name, expect, lambda d: func(d / file), src=src)

    run_case("run/nan", ["baseline.csv", "wheelloader_LF", "NaN/inf"],
             lambda f: _edit_frame(f, _set("wheelloader_LF", 10, np.nan)))
    run_case("run/inf", ["baseline.csv", "tire_force_RR", "NaN/inf"],
             lambda f: _edit_frame(f, _set("tire_force_RR", 5, np.inf)))
    run_case("run/1e308-imperial", ["baseline.csv", "aero_heave", "1e+308"],
             lambda f: _edit_frame(f, _set("aero_heave", 7, 1e308)), src="session_imp")
    run_case("run/1e308-imperial-response", ["baseline.csv", "tire_force_LF"],
             lambda f: _edit_frame(f, _set("tire_force_LF", 3, 1e308)), src="session_imp")
    run_case("run/text-cell", ["baseline.csv", "shock_velocity_LF", "not numeric"],
             lambda f: _edit_frame(f, _set("shock_velocity_LF", 12, "open")))
    run_case("run/text-time", ["baseline.csv", "time", "not numeric"],
             lambda f: _edit_frame(f, _set("time", 2, "0:00:02")))
    run_case("run/decreasing-time", ["baseline.csv", "time", "strictly increasing"],
             lambda f: _edit_frame(f, lambda fr: fr.iloc[::-1]))
    run_case("run/duplicated-time", ["baseline.csv", "time", "strictly increasing"],
             lambda f: _edit_frame(f, lambda fr: pd.concat([fr.iloc[:50], fr.iloc[49:]])))
    run_case("run/gap-in-time", ["baseline.csv", "time", "uniformly sampled"],
             lambda f: _edit_frame(f, lambda fr: fr.drop(index=[100, 101])))
    run_case("run/one-sample", ["baseline.csv", "1 data row"],
             lambda f: _edit_frame(f, lambda fr: fr.iloc[:1]))
    run_case("run/header-only", ["baseline.csv", "0 data row"],
             lambda f: _edit_frame(f, lambda fr: fr.iloc[:0]))
    run_case("run/empty-file", ["baseline.csv", "empty"], lambda f: f.write_bytes(b""))
    run_case("run/binary-garbage", ["baseline.csv", "CSV"],
             lambda f: f.write_bytes(bytes(range(256)) * 40))
    run_case("run/missing-rig-input", ["baseline.csv", "aero_roll", "missing"],
             lambda f: _edit_frame(f, lambda fr: fr.drop(columns=["aero_roll"])))
    run_case("run/no-time", ["baseline.csv", "time"],
             lambda f: _edit_frame(f, lambda fr: fr.drop(columns=["time"])))
    run_case("run/duplicate-column", ["baseline.csv", "duplicated column", "tire_force_LF"],
             lambda f: f.write_text(f.read_text().replace("tire_force_RF", "tire_force_LF", 1)))
    run_case("run/ragged-row", ["baseline.csv"],
             lambda f: f.write_text(f.read_text() + "1,2,3\n"))
    run_case("run/constant-inputs", ["baseline", "baseline.csv", "wheelloader_LF", "constant"],
             lambda f: _edit_frame(f, lambda fr: fr.assign(
                 **{c: 0.0 for c in fr.columns if c.startswith(("wheelloader", "aero"))})))
    run_case("run/parquet-truncated", ["baseline.parquet", "Parquet"],
             lambda f: f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 2]),
             src="session_pq", file="runs/baseline.parquet")
    run_case("run/csv-timestamp-text", ["baseline.csv", "time", "not numeric"],
             lambda f: _edit_frame(f, lambda fr: fr.assign(
                 time=(pd.Timestamp("2024-05-01 10:00") + pd.to_timedelta(fr["time"], unit="s"))
                 .astype(str))))
    run_case("run/parquet-datetime-gap", ["baseline.parquet", "time", "uniformly sampled"],
             lambda f: _edit_frame(f, lambda fr: fr.assign(
                 time=pd.Timestamp("2024-05-01 10:00") + pd.to_timedelta(fr["time"], unit="s"))
                 .drop(index=[7])),
             src="session_pq", file="runs/baseline.parquet")
    run_case("run/few-samples", ["baseline", "baseline.csv", "samples", "nperseg"],
             lambda f: _edit_frame(f, lambda fr: fr.iloc[:12]))
    run_case("run/parquet-garbage", ["baseline.parquet", "Parquet"],
             lambda f: f.write_bytes(b"PAR1" + b"\x00" * 100),
             src="session_pq", file="runs/baseline.parquet")
    run_case("run/parquet-nan", ["baseline.parquet", "wheelloader_RR", "NaN/inf"],
             lambda f: _edit_frame(f, _set("wheelloader_RR", 4, np.nan)),
             src="session_pq", file="runs/baseline.parquet")

    # -- shock libraries -------------------------------------------------------------------
    crate = base["shocks"].read_text()

    def shocks_case(name, expect, text):
        path = folder(name) / "crate.toml"
        path.write_text(text)
        predict(name, expect, shocks=path)

    shocks_case("shocks/duplicate-id", ["crate.toml", "L12"],
                crate.replace('id = "L28"', 'id = "L12"', 1))
    shocks_case("shocks/missing-id", ["crate.toml", "id"],
                crate.replace('id = "L28"\n', "", 1))
    shocks_case("shocks/negative-count", ["crate.toml", "count"],
                crate.replace("count = 4", "count = -1", 1))
    shocks_case("shocks/string-count", ["crate.toml", "count"],
                crate.replace("count = 4", 'count = "4"', 1))
    shocks_case("shocks/unknown-kind", ["crate.toml", "kind", "lineer"],
                crate.replace('kind = "linear"', 'kind = "lineer"', 1))
    shocks_case("shocks/negative-damping", ["crate.toml", "damping"],
                crate.replace("damping = 20.0", "damping = -20.0", 1))
    shocks_case("shocks/units-key", ["crate.toml", "units", "metric"],
                crate.replace('units = "imperial"', 'units = "metric"', 1))
    shocks_case("shocks/unit-typo", ["crate.toml", "unit"],
                crate.replace('units = "imperial"', 'unit = "imperial"', 1))
    shocks_case("shocks/table-not-monotonic", ["crate.toml", "T1", "velocity"],
                crate + '\n[[shock]]\nid = "T1"\nkind = "table"\n'
                'velocity = [-5.0, 0.0, -1.0, 5.0]\nforce = [-100.0, 0.0, 20.0, 90.0]\n')
    shocks_case("shocks/table-lengths", ["crate.toml", "T2", "force"],
                crate + '\n[[shock]]\nid = "T2"\nkind = "table"\n'
                'velocity = [-5.0, 0.0, 5.0]\nforce = [-100.0, 0.0]\n')
    shocks_case("shocks/table-nan", ["crate.toml", "T3", "force"],
                crate + '\n[[shock]]\nid = "T3"\nkind = "table"\n'
                'velocity = [-5.0, 0.0, 5.0]\nforce = [-100.0, nan, 90.0]\n')
    shocks_case("shocks/empty", ["crate.toml", "shock"], 'units = "SI"\n')
    shocks_case("shocks/binary", ["crate.toml"], "\x00\x01garbage\x02")

    # -- setups --------------------------------------------------------------------------------
    setups_text = base["setups"].read_text()

    def setups_case(name, expect, text, **kw):
        path = folder(name) / "setups.csv"
        path.write_text(text) if isinstance(text, str) else path.write_bytes(text)
        predict(name, expect, setups=path, **kw)

    setups_case("setups/duplicate-name", ["setups.csv", "firm"],
                setups_text.replace("soft-front", "firm", 1))
    setups_case("setups/unknown-id", ["setups.csv", "LR", "X99"],
                setups_text.replace("L12,L12,B20", "L12,L12,X99", 1))
    setups_case("setups/missing-corner-column", ["setups.csv", "RR"],
                "\n".join(",".join(r.split(",")[:4]) for r in setups_text.splitlines()) + "\n")
    setups_case("setups/empty-cell", ["setups.csv", "RF", "empty"],
                setups_text.replace("L12,L12", "L12,", 1))
    setups_case("setups/no-rows", ["setups.csv", "no setups"],  # the header alone
                "".join(setups_text.splitlines(keepends=True)[:1]))
    setups_case("setups/binary", ["setups.csv"], bytes(range(256)) * 8)
    setups_case("setups/header-typo", ["setups.csv", "setup"],
                setups_text.replace("setup,", "setpu,", 1))
    shocks_case("shocks/fractional-count", ["crate.toml", "count"],
                crate.replace("count = 4", "count = 2.5", 1))
    shocks_case("shocks/zero-count-bad-kind", ["crate.toml", "count"],
                crate.replace("count = 4", "count = [0]", 1))

    # -- drives -------------------------------------------------------------------------------
    def drive_case(name, expect, func, *, src="drive", **kw):
        path = folder(name) / Path(base[src]).name
        shutil.copyfile(base[src], path)
        func(path)
        predict(name, expect, drive=path, **kw)

    drive_case("drive/nan", ["drive.csv", "wheelloader_LF", "NaN/inf"],
               lambda f: _edit_frame(f, _set("wheelloader_LF", 3, np.nan)))
    drive_case("drive/1e308-imperial", ["drive.csv", "aero_heave", "overflow"],
               lambda f: _edit_frame(f, _set("aero_heave", 3, 1e308)), units="imperial")
    drive_case("drive/text", ["drive.csv", "wheelloader_RR", "not numeric"],
               lambda f: _edit_frame(f, _set("wheelloader_RR", 3, "x")))
    drive_case("drive/decreasing-time", ["drive.csv", "time"],
               lambda f: _edit_frame(f, lambda fr: fr.iloc[::-1]))
    drive_case("drive/missing-wheelloader", ["drive.csv", "wheelloader_LR"],
               lambda f: _edit_frame(f, lambda fr: fr.drop(columns=["wheelloader_LR"])))
    drive_case("drive/two-samples", ["drive.csv", "samples"],
               lambda f: _edit_frame(f, lambda fr: fr.iloc[:2]))
    drive_case("drive/binary", ["drive.csv", "CSV"], lambda f: f.write_bytes(b"\x89PNG\x00" * 99))
    drive_case("drive/parquet-truncated", ["drive.parquet", "Parquet"],
               lambda f: f.write_bytes(f.read_bytes()[:-40]), src="drive_pq")
    drive_case("drive/parquet-duplicated-time", ["drive.parquet", "time", "strictly"],
               lambda f: _edit_frame(f, lambda fr: pd.concat([fr.iloc[:9], fr.iloc[8:]])),
               src="drive_pq")

    # -- objectives ------------------------------------------------------------------------
    obj = base["objective"].read_text()

    def objective_case(name, expect, text):
        path = folder(name) / "objective.toml"
        path.write_text(text)
        rank(name, expect, objective=path)

    objective_case("objective/unknown-metric", ["objective.toml", "tire_force_rms_XX"],
                   obj.replace("tire_force_rms_RF = 0.25", "tire_force_rms_XX = 0.25", 1))
    objective_case("objective/negative-weight", ["objective.toml", "tire_force_rms_LF"],
                   obj.replace("tire_force_rms_LF = 0.25", "tire_force_rms_LF = -0.25", 1))
    objective_case("objective/zero-weights", ["objective.toml", "weights"],
                   obj.replace("0.25", "0.0").replace("0.5", "0.0"))
    objective_case("objective/nan-weight", ["objective.toml", "ride_height_rms_front"],
                   obj.replace("ride_height_rms_front = 0.5", "ride_height_rms_front = nan", 1))
    objective_case("objective/format", ["objective.toml", "format"],
                   obj.replace("objective/1", "objective/7", 1))
    objective_case("objective/limit-key", ["objective.toml", "max_ratoi"],
                   obj.replace("max_ratio", "max_ratoi", 1))
    objective_case("objective/group-unknown-metric", ["objective.toml", "grip"],
                   obj.replace('"tire_force_rms_RF"]', '"tire_force_rms_RR"]', 1))

    # -- models ------------------------------------------------------------------------------
    model_bytes = base["model"].read_bytes()

    def model_case(name, expect, data):
        path = folder(name) / "model.npz"
        path.write_bytes(data)
        predict(name, expect, model=path)

    model_case("model/truncated", ["model.npz"], model_bytes[: len(model_bytes) // 2])
    model_case("model/empty", ["model.npz"], b"")
    model_case("model/text", ["model.npz"], b"this is not a model\n" * 10)
    buf = folder("model/_src") / "x.npz"
    np.savez(buf, a=np.array([{"x": 1}], dtype=object))
    model_case("model/pickled-array", ["model.npz", "not a shockplan model"], buf.read_bytes())
    np.savez(buf, a=np.arange(3))
    model_case("model/other-npz", ["model.npz", "meta"], buf.read_bytes())
    # a model whose meta names another format
    with zipfile.ZipFile(base["model"]) as z:
        members = {n: z.read(n) for n in z.namelist()}
    meta = np.load(base["model"])["meta"]
    import io
    b = io.BytesIO()
    np.save(b, np.array(str(meta).replace('"format": "', '"format": "x')))
    members["meta.npy"] = b.getvalue()
    p = folder("model/_fmt") / "m.npz"
    with zipfile.ZipFile(p, "w") as z:
        for n, data in members.items():
            z.writestr(n, data)
    model_case("model/wrong-format", ["model.npz", "format"], p.read_bytes())
    vehicle_toml = folder("model/vehicle-garbage") / "car.toml"
    vehicle_toml.write_text("mass = \n")
    predict("model/vehicle-garbage", ["car.toml"], model=vehicle_toml)

    # -- rig plans --------------------------------------------------------------------------
    plan = base["plan"].read_text()

    def plan_case(name, expect, text):
        d = folder(name)
        shutil.copyfile(base["root"] / "paper_shocks.toml", d / "paper_shocks.toml")
        (d / "plan.toml").write_text(text)
        simulate(name, d / "plan.toml", expect)

    plan_case("plan/fs-zero", ["plan.toml", "fs_hz"], plan.replace("fs_hz = 100.0", "fs_hz = 0"))
    plan_case("plan/negative-duration", ["plan.toml", "duration_s"],
              plan.replace("duration_s = 3.0", "duration_s = -3.0"))
    plan_case("plan/units", ["plan.toml", "units"], plan.replace('units = "SI"', 'units = "mks"'))
    plan_case("plan/unknown-shock", ["plan.toml", "Q1"], plan.replace('LF = "B20"', 'LF = "Q1"'))
    plan_case("plan/drive-kind", ["plan.toml", "kind"],
              plan.replace('kind = "noise"', 'kind = "nosie"'))
    plan_case("plan/oversample-zero", ["plan.toml", "oversample"],
              plan.replace("oversample = 2", "oversample = 0"))
    plan_case("plan/key-typo", ["plan.toml", "duraton_s"],
              plan.replace("duration_s = 3.0", "duraton_s = 3.0"))
    plan_case("plan/short-for-taper", ["plan.toml", "taper_s"],
              plan.replace("duration_s = 3.0", "duration_s = 0.5"))

    # -- rig files (shockplan plan --rig) -----------------------------------------------------
    def rig_case(name, expect, text):
        path = folder(name) / "rig.toml"
        path.write_text(text)
        o = out(name, "")
        argv = ("-q", "plan", "--vehicle", "paper", "--shocks", str(base["shocks"]),
                "--budget-min", "60", "--rig-costs", str(path), "--out", o)
        cases.append(Case(name, argv, tuple(expect), out=o, inputs=(str(path),)))

    rig_text = base["rig"].read_text()
    rig_case("rig/negative-swap", ["rig.toml", "swap_min"],
             rig_text.replace("swap_min = 8.0", "swap_min = -8.0"))
    rig_case("rig/unknown-key", ["rig.toml", "swap_mins"],
             rig_text.replace("swap_min = 8.0", "swap_mins = 8.0"))

    # -- import channel maps -----------------------------------------------------------------
    mp = base["map"].read_text()

    def map_case(name, expect, text):
        path = folder(name) / "map.toml"
        path.write_text(text)
        import_(name, expect, mp=path)

    map_case("map/unit", ["map.toml", "wheelloader_LF", "furlong"],
             mp.replace('units = "m"', 'units = "furlong"', 1))
    map_case("map/wrong-quantity-unit", ["map.toml", "aero_heave", "N*m"],
             mp.replace('source = "aero_heave"\nunits = "N"', 'source = "aero_heave"\n'
                        'units = "N*m"', 1))
    map_case("map/sign", ["map.toml", "sign"], mp.replace("sign = 1", "sign = 0", 1))
    map_case("map/missing-source-channel", ["map.toml", "aero_roll", "nope"],
             mp.replace('source = "aero_roll"', 'source = "nope"', 1))
    map_case("map/no-format", ["map.toml", "format"], mp.replace('format = "channel-map/1"\n', ""))
    map_case("map/typo", ["map.toml", "sing"], mp.replace("sign = 1", "sing = 1", 1))
    tdms_bad = folder("map/tdms-garbage") / "run.tdms"
    tdms_bad.write_bytes(b"TDSm" + b"\x00" * 64)
    import_("map/tdms-garbage", ["run.tdms"], tdms=tdms_bad)

    # -- outputs ---------------------------------------------------------------------------
    existing = outs / "existing.csv"
    existing.write_text("keep me\n")
    existing_dir = outs / "existing_dir"
    existing_dir.mkdir()
    (existing_dir / "keep.txt").write_text("keep me\n")
    ro = root / "_read_only"
    read_only = read_only_folder(ro)
    predict("out/predict-existing-file", ["existing.csv", "exists"], o=str(existing))
    rank("out/rank-existing-folder", ["existing_dir", "exists"], o=str(existing_dir))
    rank("out/rank-existing-file", ["existing.csv"], o=str(existing))
    identify("out/identify-existing-file", base["session"], ["existing.csv", "exists"])
    cases[-1] = replace(cases[-1], argv=cases[-1].argv[:-1] + (str(existing),), out=str(existing))
    cases.append(Case("out/simulate-existing-folder",
                      ("-q", "rig", "simulate", "--plan", str(base["plan"]), "--out",
                       str(existing_dir)), ("existing_dir",), out=str(existing_dir)))
    cases.append(Case("out/export-drive-existing", ("-q", "export-drive", str(base["drive"]),
                      "--format", "rpc3", "--out", str(existing)), ("existing.csv", "exists"),
                      out=str(existing)))
    cases.append(Case("out/plan-existing-file",
                      ("-q", "plan", "--vehicle", "paper", "--shocks", str(base["shocks"]),
                       "--budget-min", "60", "--out", str(existing)), ("existing.csv",),
                      out=str(existing)))
    cases.append(Case("out/optimize-existing-file",
                      ("-q", "optimize", "--model", "paper", "--drive", str(base["drive"]),
                       "--shocks", str(base["shocks"]), "--out", str(existing)),
                      ("existing.csv",), out=str(existing)))
    cases.append(Case("out/whatif-existing-file",
                      ("-q", "whatif", "--model", "paper", "--drive", str(base["drive"]),
                       "--shocks", str(base["shocks"]), "--perturb", str(base["perturb"]),
                       "--setups", str(base["setups"]), "--out", str(existing)),
                      ("existing.csv",), out=str(existing)))
    if read_only:
        for cmd, target in (("predict", ro / "pred.csv"), ("rank", ro / "ranking"),
                            ("identify", ro / "model.npz"), ("simulate", ro / "session"),
                            ("export-drive", ro / "drive.rsp"), ("plan", ro / "plan"),
                            ("import", ro / "session")):
            name = f"out/{cmd}-read-only-folder"
            expect = ("_read_only", "not writable")
            if cmd == "predict":
                predict(name, expect, o=str(target))
            elif cmd == "rank":
                rank(name, expect, o=str(target))
            elif cmd == "identify":
                cases.append(Case(name, ("-q", "identify", str(base["session"]), "--out",
                                         str(target)), expect, out=str(target)))
            elif cmd == "simulate":
                cases.append(Case(name, ("-q", "rig", "simulate", "--plan", str(base["plan"]),
                                         "--out", str(target)), expect, out=str(target)))
            elif cmd == "export-drive":
                cases.append(Case(name, ("-q", "export-drive", str(base["drive"]), "--format",
                                         "rpc3", "--out", str(target)), expect, out=str(target)))
            elif cmd == "plan":
                cases.append(Case(name, ("-q", "plan", "--vehicle", "paper", "--shocks",
                                         str(base["shocks"]), "--budget-min", "60", "--out",
                                         str(target)), expect, out=str(target)))
            else:
                import_(name, expect)
                cases[-1] = replace(cases[-1], argv=cases[-1].argv[:-1] + (str(target),),
                                    out=str(target))
    names = [c.name for c in cases]
    assert len(names) == len(set(names)), "corpus case names must be unique"
    return cases


def make_corpus(root):
    """Build the base files and every case under `root`; return the cases."""
    base = build_base(Path(root) / "base")
    return make_cases(base, Path(root) / "cases")


if __name__ == "__main__":  # pragma: no cover
    target = Path(sys.argv[1] if len(sys.argv) > 1 else "shockplan-corpus")
    for case in make_corpus(target):
        print(f"{case.name}: shockplan {' '.join(case.argv)}")
