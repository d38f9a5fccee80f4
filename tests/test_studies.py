"""The study scripts in ``studies/`` at a small size: they run, write their files, and their
numbers agree with the paper and the known car."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident.data.units import to_si
from ident.models.vehicle import example_vehicle, modal_summary

STUDIES = Path(__file__).resolve().parent.parent / "studies"

#: The paper's "30 in/s ... near resonance" and "1000 lbs ... gives 10 in/s": read at the body
#: resonance with Table 1's damping, the known car gives 30.3 and 9.6; 15 % allows a graphical
#: reading of the paper's figure.
RTOL_PAPER_FIG3 = 0.15
#: The solved damping reproduces the 30 (in/s)/in wheelloader peak to brentq's tolerance
#: on a 600-point grid (1 % frequency spacing, flat peak).
RTOL_SOLVED = 0.01
#: The studies write their CSVs with 6 significant digits.
RTOL_CSV = 1e-5
#: Fit against the ideal where the ideal is within 20 dB of its peak, direct pairs (the
#: corner's own shock force and wheelloader): 60 s noise-free runs gave 0.0017-0.0018.
RTOL_DIRECT_FIT = 0.02
#: The same for cross-corner pairs, whose small responses come from the shock swaps alone
#: (60 s runs: up to 0.08; 800 s runs: below 0.001).
RTOL_CROSS_FIT = 0.2
#: Metric prediction error of a model identified from 60 s runs (measured at most 0.92 %;
#: 800 s runs: below 0.1 %).
TOL_METRIC_PCT = 3.0
#: Band-passed trace error, RMS of error over RMS of signal (measured 2.1-2.6 % at 60 s).
TOL_TRACE_PCT = 10.0


def _load(name):
    """Import ``studies/<name>.py`` as a module (the studies are scripts, not a package)."""
    key = f"_studies_{name}"
    if key in sys.modules:
        return sys.modules[key]
    spec = importlib.util.spec_from_file_location(key, STUDIES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[key] = module
    spec.loader.exec_module(module)
    return module


def test_fig03_small(tmp_path):
    levels = [15.0, 30.0, 60.0]
    assert _load("fig03").main(["--levels", *map(str, levels), "--n-freq", "600",
                                "--out", str(tmp_path)]) == 0
    assert (tmp_path / "fig03.png").stat().st_size > 0
    table = pd.read_csv(tmp_path / "fig03.csv")
    lv = table[table["kind"] == "level"].sort_values("damping_lbf_in_s")
    assert list(lv["damping_lbf_in_s"]) == levels
    # more damping, lower LF/LF peak
    assert np.all(np.diff(lv["wl_peak_in_s_per_in"]) < 0)
    # the peak lies between the lowest body mode and the highest wheel hop of the car
    # the car's modes without damping (the closed loop's natural frequencies move with it)
    modes = modal_summary(example_vehicle()).table().set_index("mode")["no_damping_hz"]
    body = modes[["heave", "roll", "pitch"]]
    hop = modes[[f"hop_{c}" for c in ("LF", "RF", "LR", "RR")]]
    assert np.all((lv["wl_peak_hz"] > 0.9 * body.min()) & (lv["wl_peak_hz"] < 1.1 * hop.max()))
    # up to Table 1's damping the peak is the LF wheel hop (damped, a little below undamped)
    light = lv[lv["damping_lbf_in_s"] <= 30.0]
    np.testing.assert_allclose(light["wl_peak_hz"], modes["hop_LF"], rtol=0.1)
    # the body resonance: within the body modes for every level
    assert np.all((lv["body_res_hz"] > 0.9 * body.min()) & (lv["body_res_hz"] < 1.2 * body.max()))
    # the paper's statements, at Table 1's damping, read at the body resonance
    nominal = lv[lv["damping_lbf_in_s"] == 30.0].iloc[0]
    np.testing.assert_allclose(nominal["body_res_wl_in_s_per_in"], 30.0, rtol=RTOL_PAPER_FIG3)
    np.testing.assert_allclose(nominal["heave_peak_in_s_per_1000lbf"], 10.0, rtol=RTOL_PAPER_FIG3)
    np.testing.assert_allclose(nominal["damping_n_s_m"], to_si(30.0, "damping", "imperial"),
                               rtol=RTOL_CSV)
    assert 5.0 < nominal["sf_lf_zero_hz"] < 7.0  # paper Fig. 6: "the zero at 6 Hz"
    solved = table[table["kind"] == "solved"].iloc[0]
    assert solved["damping_lbf_in_s"] > 60.0
    np.testing.assert_allclose(solved["wl_peak_in_s_per_in"], 30.0, rtol=RTOL_SOLVED)
    assert (table["kind"] == "paper").sum() == 1


def test_fig06_09_small(tmp_path):
    assert _load("fig06_09").main(["--run-s", "60", "--outputs", "shock_velocity_LF",
                                   "--rig-inputs", "wheelloader_LF", "--out",
                                   str(tmp_path)]) == 0
    for f in ("fig06_09.png", "fig06_09_shock_velocity_LF_shock.png",
              "fig06_09_shock_velocity_LF_rig.png"):
        assert (tmp_path / f).stat().st_size > 0, f
    table = pd.read_csv(tmp_path / "fig06_09.csv").set_index("input")
    assert list(table.index) == ["dF_LF", "dF_RF", "dF_LR", "dF_RR", "wheelloader_LF"]
    assert np.all(table["run_s"] == 60.0)
    assert np.all(table["fit_median_rel_error_high"].loc[["dF_LF", "wheelloader_LF"]]
                  < RTOL_DIRECT_FIT)
    assert np.all(table["fit_median_rel_error_high"] < RTOL_CROSS_FIT)
    assert np.all((table["median_coherence"] > 0.9) & (table["median_coherence"] <= 1.0))
    assert np.all((table["fit_error"] >= 0) & np.isfinite(table["fit_error"]))


def test_fig10_12_small(tmp_path):
    assert _load("fig10_12").main(["--run-s", "60", "--drive-s", "30", "--outputs",
                                   "tire_force_LF", "--out", str(tmp_path)]) == 0
    for f in ("fig10.png", "fig11.png", "fig12.png"):
        assert (tmp_path / f).stat().st_size > 0, f
    table = pd.read_csv(tmp_path / "fig10_12.csv")
    assert set(table["setup"]) == {"baseline", "DS-LF", "DS-RF", "DS-LR", "DS-RR", "DM-all",
                                   "L12-front"}
    assert {"tire_force_rms_LF", "shock_velocity_rms_RR"} <= set(table["metric"])
    np.testing.assert_allclose(table["error_pct"],
                               100 * (table["predicted"] / table["true"] - 1), atol=1e-3)
    assert np.all(table["true"] > 0)
    assert table["error_pct"].abs().max() < TOL_METRIC_PCT
    # the setups change the metrics far more than the prediction errs: the DS swap raises
    # LF shock velocity, which the model must reproduce
    v = table[table["metric"] == "shock_velocity_rms_LF"].set_index("setup")
    assert v.loc["DS-LF", "true"] > 1.2 * v.loc["baseline", "true"]
    assert v.loc["DS-LF", "predicted"] > 1.2 * v.loc["baseline", "predicted"]
    traces = pd.read_csv(tmp_path / "fig10_12_traces.csv")
    assert set(traces["channel"]) == {"tire_force_LF"}
    assert np.all(traces["error_pct_of_signal"] < TOL_TRACE_PCT)
    assert np.all(traces["psd_peak_error_below_signal_db"] > 10.0)


# ------------------------------------------------------------------- rig time, noise, what-if

# short runs (a designed 30-min plan, a 60 s-run paper plan) at 2 % noise identify to within a
# few percent on every metric (measured
# 0.6 % median / 1.1 % max with 100 s runs); a broken chain is off by tens of percent
RTOL_SHORT_RUNS_MAX_PCT = 5.0


@pytest.mark.slow
@pytest.mark.heavy
def test_rig_time_study_small(tmp_path):
    """The paper plan with 60 s runs: its rig time counts the swaps; identified, predicted.
    (The designed plans' path, design -> plan.toml -> virtual rig -> identify, is
    test_design's round trip.)"""
    study = _load("rig_time")
    table = study.main(["--out", str(tmp_path), "--paper-run-s", "60", "--budgets",
                        "--setups", "3", "--drive-s", "10"])
    assert (tmp_path / "rig_time.csv").is_file() and (tmp_path / "rig_time.png").is_file()
    assert list(table["plan"]) == ["paper"]
    # 5 runs of 1 min; LF swapped in (1 corner), then back and the next (2 corners) x 3
    assert table["rig_time_min"].iloc[0] == pytest.approx(5.0 + 6.0 * 7)
    assert (table["max_error_pct"] < RTOL_SHORT_RUNS_MAX_PCT).all()


#: Issue 36, ``plan --validate 2`` on a car the design was not tuned on (plan_validation
#: --quick, noise-free, a 20 s team drive, 8 setups): the designed plan's shock-force paths
#: fit to 0.0027 at most (the demo's session: 0.0085), its metrics 0.008 % median / 0.075 %
#: max, Spearman 1.000, the same best; the same plan with its identification runs on the
#: baseline (the plan before the fix): shock-force paths 0.85 median, metrics 1.8 % / 10 %,
#: Spearman 0.95. The bars: the demo's order for the fit, 10x the measured metric errors,
#: and the no-swap plan an order of magnitude worse.
TOL_VALIDATED_SHOCK_PATH_FIT = 0.03
TOL_VALIDATED_MEDIAN_PCT = 0.1
TOL_VALIDATED_MAX_PCT = 0.75
SPEARMAN_VALIDATED = 0.995
NO_SWAP_SHOCK_PATH_FIT_MEDIAN = 0.3


@pytest.mark.slow
@pytest.mark.heavy
def test_plan_validation_study_swaps_identify_the_held_out_car(tmp_path):
    """A plan with validation runs, run on a held-out car and identified: its shock-force
    paths fit as the demo's do and it predicts the truth; without the swaps it does not."""
    study = _load("plan_validation")
    table, runs = study.main(["--out", str(tmp_path), "--quick", "--noise", "0", "--drive-s",
                              "20", "--setups", "8", "--no-reference"])
    assert (tmp_path / "plan_validation.csv").is_file()
    t = table.set_index("plan")
    ok, bad = t.loc["designed"], t.loc["no swap"]
    assert ok["identification_corners_swapped"] == "LF LR RF RR"
    assert bad["identification_corners_swapped"] == "-"
    ident = runs[(runs["plan"] == "designed") & (runs["role"] != "validation")]
    assert (ident[["LF", "RF", "LR", "RR"]] != study.BASELINE).any().all()
    assert ok["shock_path_fit_error_max"] < TOL_VALIDATED_SHOCK_PATH_FIT
    assert ok["median_error_pct"] < TOL_VALIDATED_MEDIAN_PCT
    assert ok["max_error_pct"] < TOL_VALIDATED_MAX_PCT
    assert ok["spearman"] >= SPEARMAN_VALIDATED and ok["same_best"]
    assert bad["shock_path_fit_error_median"] > NO_SWAP_SHOCK_PATH_FIT_MEDIAN
    assert bad["max_error_pct"] > 10 * ok["max_error_pct"]


def test_random_plan_swaps_every_corner_within_budget():
    """A random plan spends at most its budget and varies every corner's shock (Eq. 17)."""
    import numpy as np

    from ident.models.library import read_shock_library
    from planner.demo import DEMO_LIBRARY_PATH

    study = _load("rig_time")
    library = read_shock_library(DEMO_LIBRARY_PATH)
    for seed in range(5):
        plan = study.random_plan(library, 40.0, 6.0, np.random.default_rng(seed))
        assert study.rig_time_min(plan.runs, 6.0) <= 40.0
        for c in study.CORNERS:
            assert any(r.setup[c] != study.BASELINE for r in plan.runs)


@pytest.mark.slow
@pytest.mark.heavy
def test_noise_study_small_with_missing_shock_forces(tmp_path):
    """The paper plan at 2 % noise without shock-force channels (the exact library standing
    in for the load cells) identifies and predicts."""
    study = _load("noise")
    table = study.main(["--out", str(tmp_path), "--levels", "0.02", "--plans",
                        "--run-s", "60", "--drive-s", "10", "--setups", "3",
                        "--missing-levels", "0.02", "--force-cases", "missing"])
    assert (tmp_path / "noise.csv").is_file() and (tmp_path / "noise.png").is_file()
    assert list(table["shock_forces"]) == ["missing"]
    assert (table["max_error_pct"] < RTOL_SHORT_RUNS_MAX_PCT).all()


def test_without_shock_forces_drops_channels_and_scales_the_library(paper_session):
    study = _load("noise")
    s = study.without_shock_forces(paper_session, 1.04)
    assert not any(k.startswith("shock_force_") for r in s.runs for k in r.channels)
    assert any(k.startswith("shock_force_") for r in paper_session.runs for k in r.channels)
    sid = next(iter(paper_session.shocks))
    v = 0.3
    assert s.shocks[sid].force(v) == pytest.approx(1.04 * paper_session.shocks[sid].force(v))


def test_whatif_study_small(tmp_path):
    """On the known car: springs and shock tolerance move the scores, the nominal condition
    is first, every output is written."""
    study = _load("whatif")
    table = study.main(["--out", str(tmp_path), "--model", "known", "--drive-s", "10",
                        "--top", "3", "--draws", "3"])
    for name in ("whatif.csv", "springs_identified_vs_known.csv", "rank_stability_springs.png",
                 "rank_stability_tolerance.png", "tornado_best.png"):
        assert (tmp_path / name).is_file(), name
    assert set(table["study"]) == {"springs (known model)", "springs (known car)",
                                   "shock tolerance"}
    tol = table[table["study"] == "shock tolerance"]
    assert (tol["conditions"] == 4).all()       # the nominal condition and 3 draws
    springs = table[table["study"] == "springs (known model)"]
    assert (springs["conditions"] == 5).all()   # nominal, front and rear at 0.9 and 1.1
    moved = springs[springs["setup"] != "baseline"]
    assert (moved["worst_score"] > moved["nominal_score"]).all()


def _fake_case(path, rng, *, run_s, error, light=0):
    """A cached identification of the interval study: 20 setups x 14 metrics, relative errors
    of size `error` (one per metric, shared by the setups), a random part of +-0.2 % at scale 1,
    a fit term of 0.05 %."""
    P = rng.uniform(1.0, 2.0, (20, 14))
    e = error * rng.standard_normal(14)
    np.savez(path, P=P, K=P / (1 + e), random_lo=np.full_like(P, 0.998),
             random_hi=np.full_like(P, 1.002), fit=np.full_like(P, 5e-4),
             reduction=np.zeros_like(P), discretization=np.full_like(P, 3e-4),
             package_scale=1.0, grid_df_hz=0.05, light_modes=light, identify_s=1.0,
             intervals_s=1.0, run_s=run_s)


def test_interval_calibration_study_small(tmp_path, rng):
    """The study's calibration from cached identifications (the study reuses them; a real
    identification takes 20-60 s): the fitted scale is the smallest giving 95 % pooled coverage
    on the calibration car, an identification with a lightly damped mode is left out of the
    fit, and every table is written."""
    study = _load("interval_calibration")
    cache = tmp_path / "cases"
    cache.mkdir()
    for k in range(2):
        _fake_case(cache / f"paper_30s_seed{study.SEED0 + k}.npz", rng, run_s=30.0, error=0.002)
        _fake_case(cache / f"GT-like_30s_seed{study.SEED0 + k}.npz", rng, run_s=30.0,
                   error=0.001)
        _fake_case(cache / f"heavy_stiff_30s_seed{study.SEED0 + k}.npz", rng, run_s=30.0,
                   error=0.05, light=1)
    args = ["--out", str(tmp_path), "--cars", "paper", "heavy stiff", "GT-like", "--seeds", "2",
            "--run-s", "30"]
    assert study.main(args) == 0
    cases = pd.read_csv(tmp_path / "interval_cases.csv")
    cars = pd.read_csv(tmp_path / "interval_cars.csv")
    calib = pd.read_csv(tmp_path / "interval_calibration.csv").set_index("fit")
    assert list(cars["car"]) == ["paper", "heavy stiff", "GT-like"]
    assert list(cars["role"]) == ["calibration", "calibration", "held-out"]
    assert list(cars["light_modes"]) == [0, 2, 0]
    k = calib.loc["constant", "scale"]
    assert calib.loc["constant", "calibration_cases"] == 2  # the light-mode cases left out
    paper = [study.load_case(cache / f"paper_30s_seed{study.SEED0 + i}.npz") for i in range(2)]
    step = study.SCALES[1] - study.SCALES[0]
    assert np.mean([study.coverage(c, k) for c in paper]) >= study.TARGET
    assert np.mean([study.coverage(c, k - step) for c in paper]) < study.TARGET
    # T below the reference run length: the run-length fit is the constant one
    assert calib.iloc[1]["scale"] == k
    assert np.allclose(cases["coverage_fitted"],
                       [study.coverage(study.load_case(cache / f"{c.replace(' ', '_')}_30s_seed"
                                                      f"{s}.npz"), k)
                        for c, s in zip(cases["car"], cases["seed"])])
    assert (cars.loc[cars["car"] == "GT-like", "coverage_fitted"] > 0.9).all()


#: Declaring the elements never loses: the declared model's median metric error at most the
#: undeclared one's plus this [percentage points] (200 s runs: the identification's own
#: scatter is about 0.1 point; measured 0.18 declared against 2.4 undeclared at 3.5 mm).
REAL_CAR_MEDIAN_TOL_PCT = 0.1
#: Where the elements act (contact or lift-off >= 1 % of the time) the declared model's
#: largest error is below the undeclared one's by at least this factor (measured 9-15x).
REAL_CAR_MAX_GAIN = 3.0


@pytest.mark.slow
@pytest.mark.heavy
def test_real_car_study_small(tmp_path):
    """Bump stops at 3.5 mm (front contact about 10 % of the time), 200 s runs: declaring never
    loses, and wins by far where the stops act; the undeclared identification finds them
    (the lift-off sweep is the default run's, as the CI's time allows one case)."""
    study = _load("real_car")
    assert study.main(["--out", str(tmp_path), "--quick", "--gaps", "3.5", "--roughness"]) == 0
    assert (tmp_path / "real_car.png").stat().st_size > 0
    table = pd.read_csv(tmp_path / "real_car.csv", keep_default_na=False, na_values=[""])
    assert list(table["kind"]) == ["bump stops"] * 2  # lift-off: the study's default run
    assert list(table["declared"]) == [True, False]
    for _, case in table.groupby(["kind", "active_share"]):
        dec, und = case[case["declared"]].iloc[0], case[~case["declared"]].iloc[0]
        assert dec["median_error_pct"] <= und["median_error_pct"] + REAL_CAR_MEDIAN_TOL_PCT
        assert dec["active_share"] >= 0.01
        assert REAL_CAR_MAX_GAIN * dec["max_error_pct"] <= und["max_error_pct"]
    stops = table[(table["kind"] == "bump stops") & ~table["declared"]].iloc[0]
    assert "LF stiffening" in stops["findings"] and "RF stiffening" in stops["findings"]


#: The clicks study's small grid: ls every 5 clicks, hs every 2 turns (15 settings per axle,
#: 225 setups); one click there is one grid step.
CLICKS_SMALL_GRID = "ls=5,hs=2"
#: Spearman correlation of the identified model's time-domain scores with the known car's over
#: the simulated setups (30 s runs, 10 s drive: measured 0.996); a broken chain, or scores
#: against another baseline, correlate far less.
CLICKS_SPEARMAN_MIN = 0.9


@pytest.mark.slow
def test_clicks_car_study_small(tmp_path):
    """Issue 26 on the small grid: rank on the identified model picks within one grid step
    per adjuster and axle of the brute force on the known car, its true score within 0.2 %;
    the per-setup table agrees with the summary."""
    study = _load("clicks_car")
    assert study.main(["--out", str(tmp_path), "--click-step", CLICKS_SMALL_GRID,
                       "--run-s", "30", "--drive-s", "10", "--outputs", "metrics",
                       "--simulate", "10", "--check", "5"]) == 0
    for name in ("clicks_car.csv", "clicks_car_setups.csv", "clicks_car.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    table = pd.read_csv(tmp_path / "clicks_car.csv")
    assert list(table["axle"]) == ["front", "rear"]
    assert (table["n_setups"] == 15 ** 2).all()
    assert (table["step_ls"] == 5).all() and (table["step_hs"] == 2).all()
    assert (table["d_ls_clicks"] <= 1).all() and (table["d_hs_clicks"] <= 1).all(), table
    row = table.iloc[0]
    assert row["within_one_click"] and row["within_score"] and row["done"]
    assert row["score_rel_pct"] <= 100 * study.SCORE_RTOL
    assert row["spearman_simulated"] >= CLICKS_SPEARMAN_MIN
    setups = pd.read_csv(tmp_path / "clicks_car_setups.csv", index_col=0)
    assert len(setups) == 15 ** 2 and setups["screening_score"].notna().all()
    assert setups["identified_score"].notna().sum() == row["n_simulated"]
    best = setups[setups["true_rank"] == 1].iloc[0]
    for _, axle in table.iterrows():
        a = axle["axle"]
        assert (best[f"{a}_ls"], best[f"{a}_hs"]) == (axle["best_ls"], axle["best_hs"])
    np.testing.assert_allclose(best["true_score"], row["true_score_best"], rtol=RTOL_CSV)


#: Drives from track logs (the soft heavy car, 60 s runs, a 60 s track at 2 % noise): the drive
#: built on the known car reproduces every logged channel to the log's own noise (measured
#: 1.6-1.7 %), and on the identified model within the issue's 5 % (measured 2.9-3.1 % over
#: three tracks; the GT-like car identified from 60 s runs: 16.6 %, it needs longer runs).
TRACK_DRIVE_KNOWN_RESIDUAL = 0.03
TRACK_DRIVE_RESIDUAL = 0.05


@pytest.mark.slow
def test_track_drive_study_small(tmp_path):
    """One car, one identification, one track: the drive from the log reproduces it on the
    known car, the iteration beats the plain inverse, the crate's metrics on it are within the
    issue's bars; the table agrees with itself."""
    study = _load("track_drive")
    assert study.main(["--out", str(tmp_path), "--quick"]) == 0
    assert (tmp_path / "track_drive.png").stat().st_size > 0
    table = pd.read_csv(tmp_path / "track_drive.csv")
    assert len(table) == 1
    row = table.iloc[0]
    assert (row["car"], row["run_s"], row["seed"], row["n_setups"]) == ("soft heavy", 60.0, 11,
                                                                       119)
    assert row["known_residual_max"] < TRACK_DRIVE_KNOWN_RESIDUAL
    assert row["residual_max"] < TRACK_DRIVE_RESIDUAL
    assert row["known_residual_max"] < row["residual_max"]       # the model's error adds
    # the iteration removes the shocks' nonlinearity the plain inverse leaves (10-20 %)
    assert row["plain_inverse_residual"] > 2 * row["residual_max"]
    assert row["metric_median"] < study.BAR_METRIC_MEDIAN
    assert row["metric_max"] < study.BAR_METRIC_MAX
    assert row["spearman"] >= study.BAR_SPEARMAN
    channels = [c for c in table.columns if c.startswith("residual_shock_travel_")
                or c.startswith("residual_ride_height_")]
    assert len(channels) == 8
    np.testing.assert_allclose(row[channels].max(), row["residual_max"], rtol=RTOL_CSV)
    # the pick on the built drive is the true best or within 0.1 % of it (this car's two best
    # setups are 0.001-0.04 % apart on some tracks)
    assert row["same_best"] == (row["best_built"] == row["best_track"])
    assert row["best_score_gap"] < 1e-3


@pytest.mark.heavy
def test_third_elements_study_small(tmp_path):
    """The prototype-like car's study at a small size (20 s runs, 30 s drives, 8 setups):
    it runs end to end, writes its tables, and the identified model with the session's
    third elements predicts better than the one without, once the planner puts them in its
    loop (before that, the row says the planner ignored or refused them)."""
    study = _load("third_elements")
    table, truths = study.main(["--out", str(tmp_path), "--quick", "--setups", "8"])
    back = pd.read_csv(tmp_path / "third_elements.csv")
    assert list(back["case"]) == ["after", "after", "before", "before"]
    assert list(back["drive"]) == ["track", "rig", "track", "rig"]
    for drive in ("track", "rig"):
        truth = pd.read_csv(tmp_path / f"third_elements_truth_{drive}.csv", index_col=0)
        assert len(truth) == 8 and truth.index[0] == study.BASELINE
        assert truth["rank"].idxmin() == study.score_table(truths[drive])["rank"].idxmin()
    for _, row in back.iterrows():
        assert row["planner_third"] == "yes" or row["planner_third"].startswith(
            ("ignored", "refused")), row["planner_third"]
        if not row["planner_third"].startswith("refused"):  # predicted: compared, ranked
            assert row["rank_note"] == "ok" or row["rank_note"].startswith("refused")
            assert 0 <= row["median_error_pct"] <= row["max_error_pct"]
    before = back[back["case"] == "before"].set_index("drive")
    after = back[back["case"] == "after"].set_index("drive")
    for drive in ("track", "rig"):
        if after.loc[drive, "planner_third"] == "yes":
            assert after.loc[drive, "median_error_pct"] < before.loc[drive, "median_error_pct"]


#: The third-elements study at CI size without sensor noise (the example car, 8 runs x 40 s,
#: 8 setups, 30 s drives, no ranking): the identified model's bias alone (FRF estimate on
#: short records, fit, reduction, the elements' forces), deterministic. Measured: track drive
#: 3.24 % median / 7.97 % max / Spearman 0.857, rig drive 0.83 % / 2.90 % / 1.0, the best
#: setup right on both (the short runs' leakage dominates; 8 x 120 s gives 0.084 % / 0.92 %
#: and 0.034 % / 0.16 %). The bounds are about 1.5 x those: a broken element force, input
#: or reduction gives tens of per cent.
THIRD_CI_TRACK_MEDIAN_PCT = 5.0
THIRD_CI_TRACK_MAX_PCT = 12.0
THIRD_CI_RIG_MEDIAN_PCT = 1.3
THIRD_CI_RIG_MAX_PCT = 4.5


def test_third_elements_study_noise_free_accuracy(tmp_path):
    """The third-elements study at CI size on a noise-free session: the identified model's
    predictions within the measured bias (the heavy tests below hold the example's size with
    noise)."""
    study = _load("third_elements")
    study.main(["--out", str(tmp_path), "--quick", "--setups", "8", "--cases", "after",
                "--no-rank", "--noise", "0", "--run-s", "40", "--pair-swap"])
    after = pd.read_csv(tmp_path / "third_elements.csv").set_index("drive")
    assert list(after["case"]) == ["after", "after"]
    assert after.loc["track", "median_error_pct"] < THIRD_CI_TRACK_MEDIAN_PCT
    assert after.loc["track", "max_error_pct"] < THIRD_CI_TRACK_MAX_PCT
    assert after.loc["rig", "median_error_pct"] < THIRD_CI_RIG_MEDIAN_PCT
    assert after.loc["rig", "max_error_pct"] < THIRD_CI_RIG_MAX_PCT
    assert after["same_best"].all()


def test_third_elements_session_plan_and_second_car(tmp_path):
    """The study's session designs: the plan's runs with another length, seed and noise; the
    aero runs carry the car's downforce (mean below zero: the heave springs close) and keep
    the plain runs' wheel inputs' kind; the second car differs from the example where
    SECOND_CAR says and reads as a car."""
    study = _load("third_elements")
    car = study.read_proto()
    plan = study.session_plan(car, run_s=30.0, noise=0.01, seed=5)
    assert {r.duration_s for r in plan.runs} == {30.0} and {r.seed for r in plan.runs} == {5}
    assert plan.noise == 0.01 and len(plan.runs) == len(car.plan.runs)
    both = study.session_plan(car, run_s=30.0, seed=5, aero_runs="add")
    assert len(both.runs) == 2 * len(car.plan.runs)
    aero = [r for r in both.runs if r.drive is not None]
    assert len(aero) == len(car.plan.runs) and all(r.name.endswith("-aero") for r in aero)
    heave = aero[0].drive.channels["aero_heave"]
    assert heave.mean() < -5000.0  # N: downforce of the order of the car's weight
    assert abs(heave[0]) < 1.0  # at rest at the start (the rest levels are taken there)
    pair = study.session_plan(car, pair_swaps=("front",)).runs[-1]
    assert pair.name == "swap-front-pair" and pair.role == "swap"
    assert pair.setup == {"LF": "CD", "RF": "CD", "LR": "C2", "RR": "C2"}
    with pytest.raises(ValueError, match="aero_runs"):
        study.session_plan(car, aero_runs="some")
    second = study.read_proto(study.write_second_car(tmp_path / "second"))
    assert second.vehicle.sprung_mass_kg == 960.0
    assert second.plan.third_elements.motion_ratios == \
        study.SECOND_CAR["proto_plan.toml"]["third_elements"]
    assert second.bump_stops["HS-F"].gap_m == 0.003
    assert [s.name for s in second.setups] == [s.name for s in car.setups]


#: The third-elements study at its default size (8 x 400 s runs and a front pair swap, 2 %
#: noise, 44 setups, 120 s drives, the plan's seed), identified with the defaults
#: (instrumental variables on): measured 0.161 % median / 1.52 % max / Spearman 0.9965 on the
#: track drive, 0.25 % / 1.07 % / 0.9989 on the rig drive, the best setup right on both
#: (without the pair swap 0.22 % / 1.46 % and 0.30 % / 1.17 %; at 120 s runs: 0.165 % / 1.85 %
#: and 0.33 % / 0.91 %; least squares at 120 s 0.51 % / 11.9 %). Other noise draws scatter
#: the track's max to 2 % (13.7 % on one draw of the second car: the study's notes), so the
#: bounds hold this draw only.
THIRD_STUDY_TRACK_MEDIAN_PCT = 0.3
THIRD_STUDY_MAX_PCT = 3.0
THIRD_STUDY_SPEARMAN = 0.99


@pytest.mark.heavy
def test_third_elements_study_accuracy(tmp_path):
    """The prototype-like car's study at the example's size: the identified model's
    predictions within the measured accuracy (the CI twin is
    tests/test_instruments.py's known answer of the instrumental-variable LPM)."""
    study = _load("third_elements")
    study.main(["--out", str(tmp_path)])
    back = pd.read_csv(tmp_path / "third_elements.csv")
    after = back[back["case"] == "after"].set_index("drive")
    assert after.loc["track", "median_error_pct"] < THIRD_STUDY_TRACK_MEDIAN_PCT
    assert after["max_error_pct"].max() < THIRD_STUDY_MAX_PCT
    assert after["spearman"].min() > THIRD_STUDY_SPEARMAN
    assert after["same_best"].all() and after["rank_same_best"].all()
