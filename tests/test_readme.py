"""Every example in the README runs as written (issue 23): its shell blocks, run one after
the other from inside the demo's output folder as the README says, exit 0 and write the
files they name; the ``rank`` example gives the demo's ranking.

The blocks are read from README.md itself, so an example edited there is the example tested.
Running every block takes about 8 minutes, beyond CI's time with the rest of the suite: the
runs are marked ``heavy`` (``python -m pytest -m heavy``), and every test run parses each
command of each block with the command line's own parser; the demo itself runs in every
test run (:func:`test_demo_outputs`).
The quick start's and the test command's blocks (``pip install``) are left to CI, which runs
them on a fresh machine; the demo they start runs here as written (``shockplan demo``).
"""

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

_FENCE = re.compile(r"^```(?P<lang>\w*)[^\n]*\n(?P<body>.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)
#: Longest a README block may take here [s]: the rig-day block (a 60-minute plan on the
#: virtual rig, identified and ranked) takes about 2 minutes on a 2-core machine; a hang
#: must end the test, not CI.
BLOCK_TIMEOUT_S = 1200


def shell_blocks(text):
    """The README's ```bash blocks, in order, as written."""
    return [m["body"] for m in _FENCE.finditer(text) if m["lang"] in ("bash", "sh", "shell")]


def example_blocks(text):
    """The blocks a user runs on the demo's outputs: all but the install-and-run blocks."""
    return [b for b in shell_blocks(text) if "pip install" not in b]


def commands(block):
    """Each command of a block as argv: continuation lines joined, comments dropped."""
    joined = re.sub(r"\\\n", " ", block)
    out = []
    for line in joined.splitlines():
        line = line.split(" #", 1)[0] if not line.lstrip().startswith("#") else ""
        if line.strip():
            out.append(shlex.split(line))
    return out


def outputs(argv):
    """The paths a command says it writes: its ``--out`` value."""
    return [argv[k + 1] for k, a in enumerate(argv[:-1]) if a == "--out"]


TEXT = README.read_text(encoding="utf-8")
BLOCKS = example_blocks(TEXT)


def test_the_blocks_are_found_and_parsed():
    """The parser sees what a reader sees: the quick start, the tests, and the examples,
    every command a shockplan command."""
    assert len(shell_blocks(TEXT)) - len(BLOCKS) == 2  # quick start, tests
    assert any("shockplan demo" in b for b in shell_blocks(TEXT))
    assert len(BLOCKS) >= 6
    for block in BLOCKS:
        for argv in commands(block):
            assert argv[0] == "shockplan", argv
    assert commands("shockplan a \\\n    --out b/  # c\n# d\n") == [["shockplan", "a", "--out",
                                                                      "b/"]]


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The quick start's ``shockplan demo``, as written, in a fresh folder."""
    home = tmp_path_factory.mktemp("readme")
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    done = subprocess.run(["shockplan", "-q", "demo"], cwd=home, env=env, capture_output=True,
                          text=True, timeout=BLOCK_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    DEMO_STDOUT.append(done.stdout)
    return home / "shockplan-demo", env


#: What the fixture's ``shockplan demo`` printed (one run of the demo serves every test).
DEMO_STDOUT = []
#: What each README block printed (stdout and stderr) when it ran as written, by index.
BLOCK_OUTPUT = {}
#: Each README block's exit status and stderr, by index (each block runs once).
BLOCK_DONE = {}


def run_block(demo, k):
    """Run README block `k` as written in the demo folder, once for every test that needs
    it (the blocks write their outputs without --overwrite); its exit status and stderr."""
    if k not in BLOCK_DONE:
        folder, env = demo
        done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", BLOCKS[k]], cwd=folder,
                              env=env, capture_output=True, text=True,
                              timeout=BLOCK_TIMEOUT_S)
        BLOCK_OUTPUT[k] = done.stdout + done.stderr
        BLOCK_DONE[k] = (done.returncode, done.stderr)
    return BLOCK_DONE[k]


@pytest.mark.slow
@pytest.mark.heavy
def test_readme_third_elements_identify_says_it_used_instruments(demo):
    """The third-elements example's identify (as written) prints that its estimate used
    instrumental variables (its session declares third elements: --instruments auto)."""
    k = next(i for i, b in enumerate(BLOCKS) if "shockplan identify proto/session" in b)
    code, stderr = run_block(demo, k)
    assert code == 0, stderr[-3000:]
    assert "instrumental variables: dF from the shock travels" in BLOCK_OUTPUT[k]


@pytest.mark.slow
@pytest.mark.heavy
@pytest.mark.parametrize("k", range(len(BLOCKS)))
def test_readme_example_runs_as_written(demo, k):
    folder, _ = demo
    block = BLOCKS[k]
    code, stderr = run_block(demo, k)
    assert code == 0, f"README block {k}:\n{block}\nstderr:\n{stderr[-3000:]}"
    for argv in commands(block):
        for path in outputs(argv):
            assert (folder / path).exists(), f"README block {k}: {path} not written"


@pytest.mark.slow
@pytest.mark.heavy
def test_readme_rank_gives_the_demos_ranking(demo):
    """The README's first example, `rank` without --units on the demo's imperial drive: the
    demo's ranking (the drive's unit marker, not a silent SI reading)."""
    folder, _ = demo
    k = next(k for k, b in enumerate(BLOCKS) if "--out my_ranking/" in b)
    if not (folder / "my_ranking" / "ranking.csv").exists():
        test_readme_example_runs_as_written(demo, k)
    mine = pd.read_csv(folder / "my_ranking" / "ranking.csv")
    theirs = pd.read_csv(folder / "ranking" / "ranking.csv")
    assert mine["setup"].head(5).tolist() == theirs["setup"].head(5).tolist()


@pytest.mark.parametrize("k", range(len(BLOCKS)))
def test_readme_example_commands_parse(k):
    """Every command of every example is one the command line takes as written (its
    command, options and values parse), so an example never names a renamed or misspelt
    option: the cheap half of running them, in every test run (the runs themselves are
    ``heavy``: about 8 minutes)."""
    from planner.cli import build_parser

    for argv in commands(BLOCKS[k]):
        try:
            args = build_parser().parse_args(argv[1:])
        except SystemExit as exc:  # argparse's refusal: exit 2 with a message on stderr
            raise AssertionError(f"README block {k}: {' '.join(argv)} does not parse") from exc
        assert callable(args.func), argv


def test_every_file_the_readme_links_is_in_the_repository():
    """A link a newcomer follows leads somewhere (issue 23: the spec was outside the repo)."""
    links = re.findall(r"\]\(((?!https?:)[^)#]+)\)", TEXT)
    assert "docs/rig-session.md" in links and "docs/formats.md" in links
    for link in links:
        assert (ROOT / link).exists(), link


def test_the_spec_copy_is_the_rigs_spec():
    """docs/rig-session.md is a verbatim copy of the rigs' spec (where that is at hand):
    shockplan adds to the contract in docs/formats.md, never edits it."""
    shared = ROOT.parent / "shared" / "spec" / "rig-session.md"
    if not shared.is_file():
        pytest.skip("the rigs' spec is not beside the repository here")
    assert (ROOT / "docs" / "rig-session.md").read_bytes() == shared.read_bytes()


#: The demo's best setup. Its defaults fix it: the paper's car and identification
#: experiment (seeded noise), the seed-7 track drive of 120 s, the built-in crate, the B20
#: baseline and the default objective.
DEMO_BEST = "L28/L28/L28/L28"


@pytest.mark.slow
def test_demo_outputs(demo):
    """The demo's files and what they say: the ranking screened every left/right-symmetric
    setup the crate can build, its columns, its best setup (by the ranking rule, and the
    known one), the baseline's score; the optimizer's figures printed are those of its
    workbook, and its setup file names the optimal shocks (the README's demo, run once for
    the suite by the ``demo`` fixture)."""
    from openpyxl import load_workbook

    from ident.data.channels import CORNERS
    from ident.models.library import read_shock_library
    from ident.sim.metrics import METRIC_NAMES
    from planner.demo import DEMO_LIBRARY_PATH
    from planner.histograms import HISTOGRAM_METRICS
    from planner.objective import default_objective, ranking_order
    from planner.setups import enumerate_setups, read_setups
    from planner.uncertainty import SCORE_INTERVAL_COLUMNS

    out, _ = demo
    assert (out / "session" / "session.toml").is_file()
    assert (out / "model.npz").is_file() and any((out / "frf_plots").glob("*.png"))
    for name in ("ranking.csv", "ranking.xlsx", "pareto.png", "top_setups.png", "screening.csv",
                 "histograms.csv"):
        assert (out / "ranking" / name).is_file(), name
    for name in ("optimal_shocks.toml", "optimal_setup.csv", "optimize.xlsx", "curves.png",
                 "convergence.csv"):
        assert (out / "optimize" / name).is_file(), name
    text = DEMO_STDOUT[-1]
    assert "shockplan demo" in text and "best:" in text
    assert "optimized curves" in text and "better" in text
    assert f"-> {out.name}" in text and ".shockplan-demo." not in text  # the final folder
    # every CSV says the demo's unit system (issue 23): the drive first, read without --units;
    # the header first and the unit system as the last column, on every row (issue 36; the
    # session's Parquet runs: test_every_demo_csv_reads_with_a_plain_read_csv)
    for csv_file in ("track_drive.csv", "model_summary.csv", "ranking/ranking.csv",
                     "ranking/screening.csv", "ranking/histograms.csv",
                     "optimize/optimal_setup.csv", "optimize/convergence.csv"):
        lines = (out / csv_file).read_text().splitlines()
        assert lines[0].endswith(",units"), csv_file
        assert all(line.endswith(",imperial") for line in lines[1:]), csv_file
    # the shock-velocity histograms of the ranked setups, 1 in/s bins (issue 39)
    hist = pd.read_csv(out / "ranking" / "histograms.csv")
    assert hist.setup.drop_duplicates().tolist() == pd.read_csv(
        out / "ranking" / "ranking.csv").setup.tolist()
    assert hist.groupby(["setup", "corner"]).share.sum().sub(1).abs().max() < 1e-12
    # the ranking: every setup of the crate's left/right-symmetric enumeration screened
    library = read_shock_library(DEMO_LIBRARY_PATH)
    screening = pd.read_csv(out / "ranking" / "screening.csv")
    assert sorted(screening["setup"]) == sorted(s.name for s in enumerate_setups(library))
    ranking = pd.read_csv(out / "ranking" / "ranking.csv", keep_default_na=False)
    assert list(ranking.columns) == [
        "rank", "setup", *CORNERS, *METRIC_NAMES, *HISTOGRAM_METRICS, "score", "score_grip",
        "score_platform",
        "feasible", "violations", "screening_rank", "baseline", "unresolved",
        *(f"{m}{s}" for m in METRIC_NAMES for s in ("_lo", "_hi")),
        *SCORE_INTERVAL_COLUMNS, "units"]
    # its best setup: first by the ranking rule, the known one, the one printed
    feasible = ranking["feasible"].to_numpy(dtype=bool)
    score = ranking["score"].to_numpy(dtype=float)
    assert ranking_order(feasible, score)[0] == 0 and ranking["rank"].iloc[0] == 1
    assert feasible[0] and ranking["setup"].iloc[0] == DEMO_BEST
    assert f"best: {DEMO_BEST} (score {score[0]:.4f} vs baseline" in text
    base = ranking.set_index("setup").loc["B20/B20/B20/B20"]  # the baseline, B20 all round
    assert base["score"] == pytest.approx(default_objective().total_weight, rel=1e-12)
    # the optimizer: the printed figures are its workbook's, its setup the optimal shocks
    said = re.search(r"optimized curves \(front, rear\): the optimum \(([\d.]+)\) is "
                     r"([\d.]+) % better than the crate's best (\S+) \(([\d.]+)\)", text)
    assert said is not None, text
    solver = dict(load_workbook(out / "optimize" / "optimize.xlsx")["solver"].iter_rows(
        values_only=True))
    assert said.group(1) == f"{solver['optimum score (time domain)']:.4f}"
    assert f"{said.group(2)} %" == solver["gain over the crate best"]
    assert said.group(3) == solver["crate best"]
    assert said.group(4) == f"{solver['crate best score']:.4f}"
    assert float(said.group(1)) < float(said.group(4))
    optimal = read_setups(out / "optimize" / "optimal_setup.csv")
    assert optimal[0].ids() == ("OPT-front", "OPT-front", "OPT-rear", "OPT-rear")


def python_blocks(text):
    """The README's ```python blocks, in order, as written."""
    return [m["body"] for m in _FENCE.finditer(text) if m["lang"] == "python"]


def test_the_python_section_is_found():
    """The section "From Python" has its block, on public names only."""
    blocks = python_blocks(TEXT)
    assert len(blocks) == 1 and "rank_setups" in blocks[0]
    assert not re.search(r"\bimport _|\._[a-z]", blocks[0])


@pytest.mark.heavy
def test_readme_python_runs_as_written(tmp_path):
    """The "From Python" block runs as written in a fresh folder (a virtual-rig session,
    its identification and a ranking: about 90 s)."""
    script = tmp_path / "from_python.py"
    script.write_text(python_blocks(TEXT)[0], encoding="utf-8")
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True,
                          text=True, timeout=BLOCK_TIMEOUT_S)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "baseline 'B20/B20/B20/B20' scores 1.000" in done.stdout
    assert done.stdout.strip().splitlines()[-1].split()[0] == "L28/L28/L28/L28"


#: The demo's CSV files that are not shockplan's: the clicks example's raw dyno runs, as a
#: dyno's own software exports them (its columns, no unit system stated).
VENDOR_CSV = re.compile(r"^clicks/dyno/")


@pytest.mark.slow
def test_every_demo_csv_reads_with_a_plain_read_csv(demo):
    """Issue 36: every CSV in a fresh demo folder reads with ``pandas.read_csv(path)`` and
    no options (the header is its first line) and has the spec's columns: drives the rig
    inputs, predictions and rankings ``setup`` and the corners; each ends with the column
    ``units``, one unit system on every row. The session's run files are Parquet: a plain
    ``pandas.read_parquet(path)`` gives ``time`` and the channels, the metadata the units."""
    import pyarrow.parquet as pq

    from ident.data.channels import ALL_CHANNELS, CORNERS, RIG_INPUTS, WHEELLOADER_INPUTS

    out, _ = demo
    files = sorted(p for p in out.rglob("*.csv") if not p.name.startswith("."))
    names = [p.relative_to(out).as_posix() for p in files]
    assert {"track_drive.csv", "ranking/ranking.csv", "ranking/screening.csv",
            "optimize/optimal_setup.csv", "real_car/track_drive.csv"} <= set(names)
    # the session's runs are Parquet (the spec allows it): a plain read_parquet reads them
    runs = sorted((out / "session" / "runs").iterdir())
    assert [p.name for p in runs] == [f"{n}.parquet" for n in
                                      ("baseline", "swap-LF", "swap-LR", "swap-RF", "swap-RR")]
    for path in runs:
        frame = pd.read_parquet(path)
        columns = [str(c) for c in frame.columns]
        assert len(frame) > 0 and columns[0] == "time", path.name
        assert set(RIG_INPUTS) <= set(columns) <= {"time", *ALL_CHANNELS}, path.name
        assert pq.read_metadata(path).metadata[b"units"] == b"imperial", path.name
    seen = {"run"}
    for path, name in zip(files, names):
        frame = pd.read_csv(path)
        columns = [str(c) for c in frame.columns]
        assert len(frame) > 0 and not columns[0].startswith("#"), name
        if VENDOR_CSV.match(name):
            assert "units" not in columns, name
            continue
        assert columns[-1] == "units" and frame["units"].nunique() == 1, name
        assert frame["units"].iloc[0] in ("SI", "imperial"), name
        if name.endswith("drive.csv"):
            assert columns[0] == "time" and set(WHEELLOADER_INPUTS) <= set(columns), name
            assert set(columns[1:-1]) <= set(RIG_INPUTS), name
            seen.add("drive")
        elif name.endswith("histograms.csv"):  # issue 39: one row per setup, corner and bin
            assert columns[:-1] == ["setup", "corner", "velocity_lo", "velocity_hi",
                                    "share"], name
        elif name.startswith(("ranking/", "optimize/optimal_setup")):
            head = columns[columns.index("setup"):columns.index("setup") + 5]
            assert head == ["setup", *CORNERS], name
            seen.add("setups")
    assert seen == {"run", "drive", "setups"}


#: Largest size of a fresh demo folder [bytes] (issue 36: it was 363 MB; measured 96.0 MB).
DEMO_FOLDER_MAX_BYTES = 100e6


@pytest.mark.slow
def test_the_demo_folder_is_under_100_mb(demo):
    """Issue 36: Parquet float32 runs, a deflated model and 60 s rig files keep a fresh demo
    folder under 100 MB, with every file a user needs (the README's examples run on it)."""
    out, _ = demo
    sizes = {p.relative_to(out).as_posix(): p.stat().st_size for p in out.rglob("*")
             if p.is_file()}
    total = sum(sizes.values())
    biggest = sorted(sizes.items(), key=lambda kv: -kv[1])[:8]
    assert total < DEMO_FOLDER_MAX_BYTES, f"{total / 1e6:.1f} MB; the largest: {biggest}"
    assert {"model.npz", "session/session.toml", "rig_files/baseline.rsp"} <= set(sizes)


# ---------------------------------------------------------------------------------------
# one unit system per project (issue 36, item 5)
# ---------------------------------------------------------------------------------------

#: An SI unit as shockplan writes one: a number with its unit (``25.5 mm``, ``3503 N``,
#: ``0.05 m/s``), a unit in brackets (a column header or plot axis: ``[N]``, ``[m/s]``), a
#: damping's ``N/(m/s)`` anywhere, or a file in SI (a CSV's units column, a TOML's
#: ``units = "SI"``). Hz, s, rad and % are the same in both systems.
SI_UNIT = re.compile(
    r"unit system SI\b|^units = \"SI\"|N/\(m/s\)|N\*s/m|\[(?:mm|m|N|kN|kg|m/s|mm/s|m/s\^2|N\*m|N/m|N\*m/rad|kg\*m\^2)\]"
    r"|(?<![\w.])[-+]?\d[\d.,]*(?:e[-+]?\d+)?\s?"
    r"(?:mm/s\^2|mm/s|m/s\^2|m/s|mm|kN|kg|N\*m|N/m|N|m)(?![\w/^*(])")

#: Lines of the imperial examples' outputs that may name an SI unit, each with its reason:
#: (pattern of the line, reason).
SI_ALLOWED = (
    (re.compile(r"^format = "), "a file's format name (a spec keyword), not a value"),
)

#: The README blocks whose project is not the demo's imperial one, with the reason: the
#: real-car example is a GT-like car of its own, its inputs written in SI (real_car/*.toml,
#: its drive), so its outputs are in SI as the spec says (the outputs in the drive's units);
#: the third-elements example (proto/) likewise, a prototype-like car of its own in SI.
SI_PROJECT_BLOCKS = ("real_car/", "proto/")

#: Files of the demo folder in units of their own, each with its reason (not read for SI
#: units; everything else the demo writes is).
DEMO_OWN_UNITS = {
    "real_car/": "the real-car example's inputs: a GT-like car of its own, an SI project",
    "proto/": "the third-elements example's inputs: a prototype-like car of its own, an SI "
              "project",
    "rig_map.toml": "a template of a rig's channel map: each channel's units are the rig's "
                    "(here the canonical channels, SI)",
    "track/log_map.toml": "the track logger's channel map: the logger's units (mm, km/h)",
    "track/lap.mf4": "the track logger's own file (mm, km/h)",
    "track/aero.toml": "the team's aero model as aerodynamicists write it (m, m/s, N; "
                       "its units stated in the file), an input",
    "clicks/dyno_map.toml": "the dyno's column map: the dyno's units (ms, lbf, mm)",
    "clicks/dyno/": "the dyno's own exports (ms, lbf, mm)",
}

#: Output files read for words: text (CSV header and units column, TOML, Markdown), the
#: workbooks' text cells and the PNG figures' text chunk (their titles, axes and legends).
_TEXT_SUFFIXES = (".csv", ".toml", ".md", ".txt")


def si_units_in(text, where):
    """Every SI unit named in `text` outside :data:`SI_ALLOWED`, as ``where: line``."""
    found = []
    for line in text.splitlines():
        if any(pattern.search(line) for pattern, _ in SI_ALLOWED):
            continue
        for m in SI_UNIT.finditer(line):
            found.append(f"{where}: [{m.group(0)}] {line.strip()[:200]}")
    return found


def output_words(path):
    """The words a reader of the output file `path` sees, as text lines: a CSV's header and
    its unit system (its units column), a text file whole, a workbook's text cells, a
    figure's text chunk (:func:`ident.data.files.png_metadata`)."""
    from ident.data.files import PNG_TEXT_KEY

    if path.suffix == ".csv":
        frame = pd.read_csv(path, nrows=5)
        units = sorted(set(frame["units"])) if "units" in frame.columns else []
        return "\n".join([",".join(map(str, frame.columns)),
                          *(f"unit system {u}" for u in units if u != "imperial")])
    if path.suffix in _TEXT_SUFFIXES:
        return path.read_text(encoding="utf-8", errors="replace")
    if path.suffix == ".xlsx":
        from openpyxl import load_workbook

        wb = load_workbook(path, read_only=True)
        return "\n".join(str(v) for ws in wb.worksheets for row in ws.iter_rows(values_only=True)
                         for v in row if isinstance(v, str))
    if path.suffix == ".png":
        from PIL import Image

        with Image.open(path) as image:
            text = image.text.get(PNG_TEXT_KEY)
        assert text, f"{path}: the figure's words are not in its PNG text chunk"
        return text
    return ""


def test_si_units_are_found_and_imperial_ones_are_not(tmp_path):
    """The grep finds SI units where shockplan writes them and nothing in imperial lines."""
    from ident.data.files import write_csv

    si = ["RMS travel 25.5 mm predicted", "c_bar 3503, 3503 N/(m/s)", "at 0.05/0.1 m/s: 300 N",
          "force [N]", "velocity [m/s] (compression +)", "mass 1200 kg", "gap 4.5mm",
          'units = "SI"']
    imperial = ["RMS travel 1 in predicted", "c_bar 20 lbf/(in/s)", "at 2/4/10 in/s: 67 lbf",
                "force [lbf]", "10 Hz, 120 s, 5 %, rank 3", "setup L28/L28/TD/TD", "N8,B20",
                "mass 2650 lbm", "stiffness 120 lbf/in", "hop_LR 14.4 Hz", "2 min 3 s",
                'format = "rig-plan/1"', "ride_height_front [in]", 'units = "imperial"']
    assert all(si_units_in(line, "x") for line in si), [s for s in si if not si_units_in(s, "x")]
    assert not any(si_units_in(line, "x") for line in imperial), [
        si_units_in(line, "x") for line in imperial]
    for units in ("SI", "imperial"):
        write_csv(tmp_path / "c.csv", pd.DataFrame({"velocity": [1.0], "force": [2.0]}),
                  units=units, overwrite=True)
        assert bool(si_units_in(output_words(tmp_path / "c.csv"), "c.csv")) == (units == "SI")


@pytest.mark.slow
@pytest.mark.heavy
def test_imperial_examples_print_and_write_imperial_units(demo):
    """Issue 36: in the demo's imperial project, what the demo and every README example
    print (stdout and stderr) and every file they write (CSV headers and unit systems,
    TOML, workbook cells, figures' titles, axes and legends) are in imperial units: no SI
    unit name but in the files of :data:`DEMO_OWN_UNITS` and the lines
    :data:`SI_ALLOWED` allows, each with its reason."""
    folder, _ = demo
    found = si_units_in(DEMO_STDOUT[-1], "shockplan demo printed")
    for f in sorted(p for p in folder.rglob("*") if p.is_file()):  # the demo's own files
        name = f.relative_to(folder).as_posix()
        if name.startswith(tuple(DEMO_OWN_UNITS)) or name.startswith("."):
            continue
        if name.startswith("session/runs/") and not name.endswith("baseline.csv"):
            continue  # one run file read is as good as five
        found += si_units_in(output_words(f), name)
    demo_files = {p for p in folder.rglob("*") if p.is_file()}
    for k, block in enumerate(BLOCKS):
        if any(tag in block for tag in SI_PROJECT_BLOCKS):
            continue
        code, stderr = run_block(demo, k)
        assert code == 0, f"README block {k}: {stderr[-2000:]}"
        found += si_units_in(BLOCK_OUTPUT[k], f"README block {k} printed")
        for argv in commands(block):
            for out in outputs(argv):
                path = folder / out
                files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() \
                    else [path]
                for f in files:
                    if f not in demo_files:  # the demo's own inputs were read above
                        found += si_units_in(output_words(f),
                                             f.relative_to(folder).as_posix())
    assert not found, "\n".join(found[:40])
