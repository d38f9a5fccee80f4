"""Property-based fuzzing of every file reader (issue 13): bad bytes give a project error.

For each reader, random bytes and random mutations of a valid file (bytes flipped,
inserted, deleted, the file cut short; for text formats also a token replaced by
another) either read or raise a :class:`ident.errors.ShockplanError` (a ``ValueError``)
-- never another exception. The valid files are the corpus's base files
(``tests/corpus/make_corpus.py``). Fixed seed (``derandomize=True``) and small example
counts keep the file well under a minute.
"""

from __future__ import annotations

import importlib.util
import shutil
import sys
import warnings
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ident.data.drive import read_drive
from ident.errors import ShockplanError
from ident.data.formats import read_channel_map
from ident.identify.model import load_model
from ident.sim.virtual_rig import read_rig_plan
from ident.data.runs import read_run_table
from ident.data.session import read_session
from ident.models.library import read_shock_library
from ident.models.vehicle import read_vehicle
from planner.objective import read_objective
from planner.rig_spec import read_rig
from planner.setups import read_setups
from planner.whatif import read_perturbations

_SPEC = importlib.util.spec_from_file_location(
    "make_corpus", Path(__file__).parent / "corpus" / "make_corpus.py")
make_corpus = importlib.util.module_from_spec(_SPEC)
sys.modules.setdefault("make_corpus", make_corpus)
_SPEC.loader.exec_module(make_corpus)

#: Examples per property: enough to hit every reader's branches on bytes and on
#: mutations, few enough for the whole file to run in well under a minute.
N_BYTES = 60
N_MUTATIONS = 150
FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    files = make_corpus.build_base(root / "base")
    files["vehicle"] = Path(__file__).resolve().parents[1] / "ident" / "examples" / "paper_car.toml"
    files["work"] = root / "work"
    files["work"].mkdir()
    return files


def _session_reader(base):
    folder = base["work"] / "session"
    if not folder.exists():
        shutil.copytree(base["session"], folder)

    def read(path):
        shutil.copyfile(path, folder / "session.toml")
        return read_session(folder)
    return read


# name -> (the valid file, the reader of a file at a path, suffix of the fuzzed file)
READERS = {
    "session.toml": ("session/session.toml", _session_reader, ".toml"),
    "run csv": ("session/runs/baseline.csv",
                lambda b: lambda p: read_run_table(p, required=("wheelloader_LF",)), ".csv"),
    "run parquet": ("session_pq/runs/baseline.parquet",
                    lambda b: lambda p: read_run_table(p), ".parquet"),
    "imperial run csv": ("session_imp/runs/baseline.csv",
                         lambda b: lambda p: read_run_table(p, units="imperial"), ".csv"),
    "shock library": ("crate.toml", lambda b: read_shock_library, ".toml"),
    "setups csv": ("setups.csv", lambda b: lambda p: read_setups(p, read_shock_library(
        b["shocks"])), ".csv"),
    "drive csv": ("drive.csv", lambda b: read_drive, ".csv"),
    "drive parquet": ("drive.parquet", lambda b: read_drive, ".parquet"),
    "objective": ("objective.toml", lambda b: read_objective, ".toml"),
    "model npz": ("model.npz", lambda b: load_model, ".npz"),
    "rig plan": ("plan.toml", lambda b: read_rig_plan, ".toml"),
    "channel map": ("map.toml", lambda b: read_channel_map, ".toml"),
    "rig": ("rig.toml", lambda b: read_rig, ".toml"),
    "perturbations": ("perturb.toml", lambda b: read_perturbations, ".toml"),
    "vehicle": (None, lambda b: read_vehicle, ".toml"),
}


def _valid(base, name):
    rel = READERS[name][0]
    return (base["vehicle"] if rel is None else base["root"] / rel).read_bytes()


def _target(base, name):
    path = base["work"] / ("fuzzed" + READERS[name][2])
    if name == "rig plan":  # the plan names its shock library relative to itself
        lib = base["work"] / "paper_shocks.toml"
        if not lib.exists():
            shutil.copyfile(base["root"] / "paper_shocks.toml", lib)
    return path


def _check(base, name, data):
    path = _target(base, name)
    path.write_bytes(data)
    reader = READERS[name][1](base)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a doubtful but readable file may warn
        try:
            reader(path)
        except ShockplanError:
            pass


@st.composite
def mutations(draw, data):
    """A valid file with 1-4 random edits: flip, insert, delete, cut, swap a token."""
    data = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "insert", "delete", "cut", "token"]))
        i = draw(st.integers(0, max(len(data) - 1, 0)))
        if kind == "flip" and data:
            data[i] = draw(st.integers(0, 255))
        elif kind == "insert":
            data[i:i] = draw(st.binary(min_size=1, max_size=8))
        elif kind == "delete" and data:
            data[i:i + draw(st.integers(1, 16))] = b""
        elif kind == "cut":
            data = data[:i]
        elif kind == "token" and data:
            # replace the number, word or string around i by another (text formats)
            j = i
            while j < len(data) and chr(data[j]).isalnum() or j < len(data) and data[j] in b".-_":
                j += 1
            new = draw(st.sampled_from([b"nan", b"inf", b"-1", b"0", b"1e308", b"\"x\"", b"[]",
                                        b"true", b"{}", b"", b"-0.0", b"99999999999999999999"]))
            data[i:j] = new
    return bytes(data)


@pytest.mark.parametrize("name", list(READERS))
def test_random_bytes_give_a_project_error(base, name):
    @settings(FUZZ, max_examples=N_BYTES)
    @given(st.binary(max_size=600))
    def prop(data):
        _check(base, name, data)
    prop()


@pytest.mark.parametrize("name", list(READERS))
def test_mutated_valid_files_give_a_project_error(base, name):
    valid = _valid(base, name)
    _check(base, name, valid)  # the valid file itself reads

    @settings(FUZZ, max_examples=N_MUTATIONS)
    @given(mutations(valid))
    def prop(data):
        _check(base, name, data)
    prop()
