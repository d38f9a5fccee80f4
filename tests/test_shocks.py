"""Tests of ident.models.shocks, library and dyno: shock models, the shock library file, dyno
fits."""

import doctest
import math

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import integrate
from scipy.stats import norm

import ident.models.shocks as shocks
from ident.errors import FitWarning, ShockModelError
from ident.dyno.sheet_fit import fit_shock_to_dyno
from ident.models.library import ShockLibrary, read_shock_library, write_shock_library
from ident.models.shocks import (
    DigressiveShock,
    LinearShock,
    PiecewiseLinear,
    TableShock,
)
from ident.data.units import TO_SI

RTOL_EXACT = 1e-12  # closed forms and unit round trips: round-off only
RTOL_MC = 3e-3  # 1e6 Gaussian samples: the ratio estimator's relative std is ~3e-4
RTOL_QUAD = 1e-8  # adaptive quadrature split at the knots
# dyno fit: 40 velocities per side, force noise 3 N on forces of 100-2000 N; over 20 seeds
# the worst errors were 0.8 % (slopes) and 1.4 % (knees)
RTOL_FIT_SLOPE = 0.03
RTOL_FIT_KNEE = 0.05
ATOL_FIT_FORCE_N = 10.0  # table through noisy points: within ~3 noise sigmas of truth

SPEC_TOML = """\
units = "SI"

[[shock]]
id = "B20"
kind = "linear"
damping = 3502.5                    # N/(m/s)

[[shock]]
id = "D8"
kind = "table"                      # piecewise-linear force-velocity curve, e.g. from a dyno
velocity = [-0.5, -0.1, 0.0, 0.1, 0.5]          # strictly increasing, compression positive
force = [-1100.0, -500.0, 0.0, 350.0, 700.0]    # force at each velocity
lag = 0.004                         # optional, s: first-order lag between the curve's
                                    # force and the applied force (hysteresis); 0 = none
"""


@pytest.fixture
def rng():
    return np.random.default_rng(20090401)


def _d8():
    return TableShock("D8", [-0.5, -0.1, 0.0, 0.1, 0.5],
                      [-1100.0, -500.0, 0.0, 350.0, 700.0], lag_s=0.004)


def _digressive():
    return DigressiveShock("K1", bump_low_n_s_m=8000.0, bump_knee_m_s=0.08,
                           bump_high_n_s_m=2000.0, rebound_low_n_s_m=12000.0,
                           rebound_knee_m_s=0.06, rebound_high_n_s_m=3000.0)


def _all_kinds():
    return [LinearShock("B20", 3502.5), _d8(), _digressive(),
            TableShock("T1", [0.05, 0.2, 0.6], [400.0, 1600.0, 2100.0],
                       description="bump-only table through (0, 0) by extension")]


# ---------------------------------------------------------------- known answers


def test_piecewise_linear_force_slope_and_extensions():
    pwl = PiecewiseLinear([-0.1, 0.0, 0.2], [-300.0, 0.0, 400.0], 1000.0, 500.0)
    v = np.array([[-0.3, -0.1, -0.05], [0.0, 0.1, 0.4]])
    assert_allclose(pwl.force(v), [[-500.0, -300.0, -150.0], [0.0, 200.0, 500.0]],
                    rtol=RTOL_EXACT)
    # right derivative at knots: -0.1 and 0.0 take the segment to their right
    assert_array_equal(pwl.slope(v), [[1000.0, 3000.0, 3000.0], [2000.0, 2000.0, 500.0]])
    assert pwl.slope(0.2) == 500.0
    assert isinstance(pwl.force(0.1), float)
    assert pwl.force(v).shape == v.shape
    assert not pwl.v_knots_m_s.flags.writeable
    one = PiecewiseLinear([0.0], [0.0], 1000.0, 2000.0)
    assert_allclose(one.force([-1.0, 1.0]), [-1000.0, 2000.0], rtol=RTOL_EXACT)


def test_linear_shock_force_and_equivalent_damping_is_c_for_any_rms():
    c = 3502.5
    shock = LinearShock("B20", c)
    v = np.linspace(-1.0, 1.0, 11)
    assert_allclose(shock.force(v), c * v, rtol=RTOL_EXACT)
    assert_allclose(shock.slope(v), c, rtol=RTOL_EXACT)
    rms = np.logspace(-4, 1, 12).reshape(3, 4)
    c_eq = shock.equivalent_damping(rms)
    assert c_eq.shape == (3, 4)
    assert_allclose(c_eq, c, rtol=RTOL_EXACT)
    assert isinstance(shock.equivalent_damping(0.1), float)


def test_table_shock_reproduces_knots_and_extends_with_end_slopes():
    d8 = _d8()
    assert_allclose(d8.force(d8.velocity_m_s), d8.force_n, rtol=RTOL_EXACT)
    # end slopes: (-500 + 1100) / 0.4 = 1500 below, (700 - 350) / 0.4 = 875 above
    assert_allclose(d8.force([-1.5, 1.5]), [-1100.0 - 1500.0, 700.0 + 875.0],
                    rtol=RTOL_EXACT)
    assert_allclose(d8.slope([-2.0, 2.0]), [1500.0, 875.0], rtol=RTOL_EXACT)
    pwl = d8.to_pwl()
    assert (pwl.slope_below, pwl.slope_above) == (1500.0, 875.0)
    assert d8.lag_s == 0.004


def _equivalent_damping_quad(shock, sigma):
    """E[v f(v)] / sigma^2 by quadrature of the Gaussian density, split at the knots."""
    knots = shock.to_pwl().v_knots_m_s
    edges = np.concatenate([[-12 * sigma], knots[np.abs(knots) < 12 * sigma], [12 * sigma]])

    def integrand(v):
        return v * shock.force(v) * norm.pdf(v, scale=sigma)

    total = sum(integrate.quad(integrand, a, b, epsabs=0, epsrel=1e-12)[0]
                for a, b in zip(edges[:-1], edges[1:]))
    return total / sigma**2


@pytest.mark.parametrize("sigma", [0.02, 0.08, 0.3])
def test_digressive_equivalent_damping_matches_monte_carlo_and_quadrature(rng, sigma):
    shock = _digressive()
    c_eq = shock.equivalent_damping(sigma)
    v = rng.normal(0.0, sigma, 1_000_000)
    c_mc = np.sum(v * shock.force(v)) / np.sum(v * v)
    assert_allclose(c_eq, c_mc, rtol=RTOL_MC)
    assert_allclose(c_eq, _equivalent_damping_quad(shock, sigma), rtol=RTOL_QUAD)


def test_equivalent_damping_limits_are_low_and_high_speed_slopes():
    shock = _digressive()
    # tiny rms: only the low-speed slopes, each side with probability 1/2
    assert_allclose(shock.equivalent_damping(1e-6), 0.5 * (8000.0 + 12000.0),
                    rtol=RTOL_EXACT)
    # huge rms: the high-speed slopes dominate (knees ~1e-4 sigma)
    assert_allclose(shock.equivalent_damping(1e3), 0.5 * (2000.0 + 3000.0), rtol=1e-3)


@pytest.mark.parametrize("shock", _all_kinds(), ids=lambda s: s.id)
def test_to_pwl_equals_force_on_dense_grid(shock):
    v = np.linspace(-2.0, 2.0, 40_001)
    pwl = shock.to_pwl()
    assert_allclose(pwl.force(v), shock.force(v), rtol=RTOL_EXACT, atol=0)
    # slope agrees with central differences away from the knots
    h = 1e-7
    far = np.min(np.abs(v[:, None] - pwl.v_knots_m_s[None, :]), axis=1) > 10 * h
    fd = (shock.force(v[far] + h) - shock.force(v[far] - h)) / (2 * h)
    assert_allclose(shock.slope(v[far]), fd, rtol=1e-6, atol=1e-6)
    # passive: f(v) v >= 0 everywhere
    assert np.all(shock.force(v) * v >= 0)


# ---------------------------------------------------------------- library files


def test_spec_example_loads_exactly(tmp_path):
    path = tmp_path / "shocks.toml"
    path.write_text(SPEC_TOML)
    lib = read_shock_library(path)
    assert list(lib) == ["B20", "D8"]
    b20, d8 = lib["B20"], lib["D8"]
    assert isinstance(b20, LinearShock) and b20.c_n_s_m == 3502.5 and b20.lag_s == 0.0
    assert isinstance(d8, TableShock)
    assert d8.velocity_m_s.tolist() == [-0.5, -0.1, 0.0, 0.1, 0.5]
    assert d8.force_n.tolist() == [-1100.0, -500.0, 0.0, 350.0, 700.0]
    assert d8.lag_s == 0.004
    assert lib.source == str(path)


def test_imperial_damping_converts_to_si(tmp_path):
    path = tmp_path / "shocks.toml"
    path.write_text('units = "imperial"\n[[shock]]\nid = "B20"\nkind = "linear"\n'
                    "damping = 20\n")
    c = read_shock_library(path)["B20"].c_n_s_m
    assert c == 20 * TO_SI["damping"]
    # 20 lbf/(in/s) = 20 * 4.4482216152605 / 0.0254 = 3502.53670... N/(m/s)
    assert c == pytest.approx(3502.5366, abs=2e-4)


def test_imperial_table_converts_velocity_and_force(tmp_path):
    path = tmp_path / "shocks.toml"
    path.write_text('units = "imperial"\n[[shock]]\nid = "T"\nkind = "table"\n'
                    "velocity = [-10.0, 0.0, 10.0]\nforce = [-200.0, 0.0, 100.0]\nlag = 0.01\n")
    t = read_shock_library(path)["T"]
    assert_allclose(t.velocity_m_s, [-0.254, 0.0, 0.254], rtol=RTOL_EXACT)
    assert_allclose(t.force_n, [-200 * TO_SI["force"], 0.0, 100 * TO_SI["force"]],
                    rtol=RTOL_EXACT)
    assert t.lag_s == 0.01  # seconds in both unit systems


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_write_read_round_trip(tmp_path, units):
    models = _all_kinds()
    models[0] = LinearShock("B20", 3502.5, lag_s=0.002, description="baseline")
    path = write_shock_library(ShockLibrary.from_models(models), tmp_path / "s.toml",
                               units=units)
    back = read_shock_library(path)
    assert list(back) == [m.id for m in models]
    for m in models:
        b = back[m.id]
        assert type(b) is type(m)
        assert (b.lag_s, b.description) == (m.lag_s, m.description)
        for (_, attr_values), (_, back_values) in zip(_values(m), _values(b)):
            assert_allclose(back_values, attr_values, rtol=RTOL_EXACT, atol=0)
    assert f'units = "{units}"' in path.read_text()


def test_count_inventory_round_trip_and_default(tmp_path):
    assert LinearShock("B20", 3502.5).count is None  # default: unlimited
    models = [LinearShock("B20", 3502.5, count=2), _d8(), TableShock(
        "T0", [-0.1, 0.0, 0.1], [-10.0, 0.0, 10.0], count=0)]
    assert models[0].to_toml_dict()["count"] == 2
    assert "count" not in models[1].to_toml_dict()
    path = write_shock_library(models, tmp_path / "s.toml", units="imperial")
    back = read_shock_library(path)
    assert [back[i].count for i in ("B20", "D8", "T0")] == [2, None, 0]
    assert isinstance(LinearShock("B", 1.0, count=np.int64(3)).count, int)


def test_fits_round_trip_default_and_refusal(tmp_path):
    """A damper's use (``fits``, optional): kept through write and read, copies keep it,
    absent is any use (None), an unknown use refused naming the file, shock and key."""
    assert LinearShock("B20", 3502.5).fits is None
    models = [LinearShock("H1", 8000.0, fits="heave"), _d8(),
              TableShock("R1", [-0.1, 0.0, 0.1], [-10.0, 0.0, 10.0], fits="roll")]
    assert models[0].to_toml_dict()["fits"] == "heave"
    assert "fits" not in models[1].to_toml_dict()
    assert models[0].scaled(2.0).fits == "heave"
    back = read_shock_library(write_shock_library(models, tmp_path / "s.toml"))
    assert [back[i].fits for i in ("H1", "D8", "R1")] == ["heave", None, "roll"]
    with pytest.raises(ShockModelError, match="fits"):
        LinearShock("H", 1.0, fits="axle")
    bad = tmp_path / "bad.toml"
    bad.write_text('[[shock]]\nid = "H2"\nkind = "linear"\ndamping = 1.0\nfits = "heav"\n')
    with pytest.raises(ShockModelError, match=r"bad.toml: \[\[shock\]\] #1 \('H2'\): key "
                       r"'fits' is 'heav', not a use; write one of \['corner', 'heave', 'roll'\]"):
        read_shock_library(bad)


def _values(model):
    return [(key, getattr(model, attr)) for key, (attr, _, _) in model.TOML_FIELDS.items()]


def test_imperial_file_holds_imperial_values(tmp_path):
    path = write_shock_library([LinearShock("B20", 20 * TO_SI["damping"])],
                               tmp_path / "s.toml", units="imperial")
    doc = tomllib.loads(path.read_text())
    assert doc["shock"][0]["damping"] == pytest.approx(20.0, rel=RTOL_EXACT)


def test_write_refuses_to_overwrite(tmp_path):
    path = tmp_path / "s.toml"
    write_shock_library([_d8()], path)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_shock_library([_d8()], path)
    write_shock_library([_digressive()], path, overwrite=True)
    assert list(read_shock_library(path)) == ["K1"]


def test_digressive_toml_keys(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('[[shock]]\nid = "K1"\nkind = "digressive"\nbump_low = 8000\n'
                    "bump_knee = 0.08\nbump_high = 2000\nrebound_low = 12000\n"
                    "rebound_knee = 0.06\nrebound_high = 3000\n")
    k1 = read_shock_library(path)["K1"]
    ref = _digressive()
    assert_allclose(k1.force(np.linspace(-1, 1, 101)), ref.force(np.linspace(-1, 1, 101)),
                    rtol=RTOL_EXACT)
    assert k1.to_toml_dict() == {"id": "K1", "kind": "digressive", "bump_low": 8000.0,
                                 "bump_knee": 0.08, "bump_high": 2000.0,
                                 "rebound_low": 12000.0, "rebound_knee": 0.06,
                                 "rebound_high": 3000.0}


def test_library_is_ordered_read_only_mapping_with_clear_lookup():
    models = _all_kinds()
    lib = ShockLibrary.from_models(models)
    assert lib.ids == ("B20", "D8", "K1", "T1")
    assert lib.get("D8") is models[1]
    assert lib.get("nope", None) is None
    assert "K1" in lib and len(lib) == 4
    with pytest.raises(TypeError):
        lib["X"] = models[0]
    with pytest.raises(KeyError):
        lib["X"]
    with pytest.raises(ShockModelError, match=r"run 'swap-LF' setup LF: unknown shock id "
                                              r"'X'; .*\['B20', 'D8', 'K1', 'T1'\]"):
        lib.get("X", where="run 'swap-LF' setup LF")
    assert list(ShockLibrary.from_models({m.id: m for m in models})) == list(lib)
    with pytest.raises(TypeError, match="not a ShockModel"):
        ShockLibrary.from_models([models[0], "B20"])


# ---------------------------------------------------------------- dyno fits


def _dyno_frames(rng, noise_n=3.0):
    truth = _digressive()
    speed = np.linspace(0.01, 0.5, 40)
    bump = truth.force(speed) + rng.normal(0.0, noise_n, speed.size)
    rebound = -truth.force(-speed) + rng.normal(0.0, noise_n, speed.size)
    split = pd.DataFrame({"velocity": speed, "bump_force": bump, "rebound_force": rebound})
    signed = pd.DataFrame({"velocity": np.concatenate([-speed[::-1], speed]),
                           "force": np.concatenate([-rebound[::-1], bump])})
    return truth, signed, split


@pytest.mark.parametrize("layout", ["signed", "split"])
def test_dyno_fit_digressive_recovers_parameters(rng, tmp_path, layout):
    truth, signed, split = _dyno_frames(rng)
    data = {"signed": signed, "split": split}[layout]
    path = tmp_path / f"{layout}.csv"
    data.to_csv(path, index=False)
    fit = fit_shock_to_dyno(path, id="K1fit", kind="digressive", lag_s=0.003)
    assert isinstance(fit, DigressiveShock) and fit.id == "K1fit" and fit.lag_s == 0.003
    assert str(path) in fit.description
    for side in ("bump", "rebound"):
        for name, rtol in (("low_n_s_m", RTOL_FIT_SLOPE), ("knee_m_s", RTOL_FIT_KNEE),
                           ("high_n_s_m", RTOL_FIT_SLOPE)):
            attr = f"{side}_{name}"
            assert_allclose(getattr(fit, attr), getattr(truth, attr), rtol=rtol,
                            err_msg=attr)


@pytest.mark.parametrize("layout", ["signed", "split"])
def test_dyno_fit_table_follows_truth(rng, layout):
    truth, signed, split = _dyno_frames(rng)
    fit = fit_shock_to_dyno({"signed": signed, "split": split}[layout], id="T")
    assert isinstance(fit, TableShock)
    assert 0.0 in fit.velocity_m_s.tolist()
    assert fit.velocity_m_s.size == 81  # 40 per side + (0, 0)
    v = np.linspace(-0.5, 0.5, 1001)
    # a linear interpolation cuts the corner within one data spacing of a knee
    spacing = 0.5 / 39
    away = ((np.abs(v - truth.bump_knee_m_s) > spacing)
            & (np.abs(v + truth.rebound_knee_m_s) > spacing))
    assert_allclose(fit.force(v[away]), truth.force(v[away]), atol=ATOL_FIT_FORCE_N)


def test_dyno_fit_table_averages_duplicates_and_adds_origin():
    df = pd.DataFrame({"velocity": [0.1, -0.1, 0.1, 0.3, -0.2],
                       "force": [100.0, -150.0, 120.0, 200.0, -250.0]})
    fit = fit_shock_to_dyno(df, id="T")
    assert fit.velocity_m_s.tolist() == [-0.2, -0.1, 0.0, 0.1, 0.3]
    assert_allclose(fit.force_n, [-250.0, -150.0, 0.0, 110.0, 200.0], rtol=RTOL_EXACT)


def test_dyno_fit_imperial_equals_si(rng):
    _, signed, _ = _dyno_frames(rng)
    imperial = pd.DataFrame({"velocity": signed["velocity"] / TO_SI["velocity"],
                             "force": signed["force"] / TO_SI["force"]})
    for kind in ("table", "digressive"):
        a = fit_shock_to_dyno(signed, id="A", kind=kind)
        b = fit_shock_to_dyno(imperial, id="A", kind=kind, units="imperial")
        v = np.linspace(-0.6, 0.6, 301)
        assert_allclose(b.force(v), a.force(v), rtol=1e-6, atol=1e-6)


def test_dyno_fit_table_one_side_warns():
    df = pd.DataFrame({"velocity": [0.1, 0.2], "force": [500.0, 800.0]})
    with pytest.warns(FitWarning, match="no rebound points"):
        fit = fit_shock_to_dyno(df, id="T")
    assert_allclose(fit.force(-0.1), -500.0, rtol=RTOL_EXACT)


# ---------------------------------------------------------------- bad inputs

_GOOD_TABLE = dict(velocity_m_s=[-0.1, 0.0, 0.1], force_n=[-100.0, 0.0, 80.0])
_DIG = dict(bump_low_n_s_m=8000.0, bump_knee_m_s=0.08, bump_high_n_s_m=2000.0,
            rebound_low_n_s_m=12000.0, rebound_knee_m_s=0.06, rebound_high_n_s_m=3000.0)

BAD_MODELS = [
    ("empty id", lambda: LinearShock("", 1000.0), r"shock: id '' is not a valid shock id"),
    ("id not str", lambda: LinearShock(7, 1000.0), r"id 7 is not a valid shock id"),
    ("padded id", lambda: LinearShock(" B20", 1000.0), r"not a valid shock id"),
    ("negative damping", lambda: LinearShock("B", -1.0), r"shock 'B': c_n_s_m = -1 .* not >= 0"),
    ("string damping", lambda: LinearShock("B", "3502"), r"c_n_s_m must be a number, got str"),
    ("nan damping", lambda: LinearShock("B", math.nan), r"c_n_s_m is nan, not finite"),
    ("negative lag", lambda: LinearShock("B", 1.0, lag_s=-0.1), r"lag_s = -0.1 s is not >= 0"),
    ("inf lag", lambda: LinearShock("B", 1.0, lag_s=math.inf), r"lag_s is inf, not finite"),
    ("description type", lambda: LinearShock("B", 1.0, description=3),
     r"description must be a string"),
    ("one point", lambda: TableShock("T", [0.0], [0.0]), r"velocity_m_s has 1 point"),
    ("length mismatch", lambda: TableShock("T", [0.0, 0.1], [0.0, 1.0, 2.0]),
     r"force_n has 3 values but velocity_m_s has 2"),
    ("not increasing", lambda: TableShock("T", [0.0, 0.2, 0.1], [0.0, 1.0, 2.0]),
     r"velocity_m_s is not strictly increasing at index 2"),
    ("duplicate velocity", lambda: TableShock("T", [0.0, 0.1, 0.1], [0.0, 1.0, 2.0]),
     r"not strictly increasing"),
    ("nan force", lambda: TableShock("T", [0.0, 0.1], [0.0, math.nan]),
     r"force_n\[1\] is nan, not finite"),
    ("string in table", lambda: TableShock("T", [0.0, "0.1"], [0.0, 1.0]),
     r"velocity_m_s\[1\] must be a number, got str"),
    ("wrong sign", lambda: TableShock("T", [-0.1, 0.0, 0.1], [100.0, 0.0, 80.0]),
     r"force_n\[0\] = 100 N at velocity -0.1 m/s has the wrong sign"),
    ("f(0) not zero", lambda: TableShock("T", [-0.1, 0.1], [-50.0, 150.0]),
     r"f\(0\) = 50 N, not 0"),
    ("offset at 0 knot", lambda: TableShock("T", [-0.1, 0.0, 0.1], [-50.0, 1e-3, 150.0]),
     r"f\(0\) = 0.001 N"),
    ("extension misses origin", lambda: TableShock("T", [0.1, 0.2], [10.0, 30.0]),
     r"does not span v = 0 .* f\(0\) = -10 N"),
    ("negative end slope above",
     lambda: TableShock("T", [-0.1, 0.0, 0.1, 0.2], [-10.0, 0.0, 20.0, 10.0]),
     r"last-segment slope of -100 N/\(m/s\) < 0"),
    ("negative end slope below",
     lambda: TableShock("T", [-0.2, -0.1, 0.0, 0.1], [-5.0, -10.0, 0.0, 20.0]),
     r"first-segment slope of -50 N/\(m/s\) < 0"),
    ("negative digressive slope",
     lambda: DigressiveShock("D", **{**_DIG, "rebound_high_n_s_m": -1.0}),
     r"shock 'D': rebound_high_n_s_m = -1 N/\(m/s\) is not >= 0"),
    ("zero knee", lambda: DigressiveShock("D", **{**_DIG, "bump_knee_m_s": 0.0}),
     r"bump_knee_m_s = 0 m/s is not > 0"),
    ("pwl not increasing", lambda: PiecewiseLinear([0.0, 0.0], [0.0, 1.0], 1.0, 1.0),
     r"piecewise-linear curve: v_knots_m_s is not strictly increasing"),
    ("rms zero", lambda: LinearShock("B", 1.0).equivalent_damping([0.1, 0.0]),
     r"shock 'B': v_rms_m_s = 0.0 is not a finite value > 0"),
    ("rms nan", lambda: _d8().equivalent_damping(math.nan), r"v_rms_m_s = nan"),
    ("duplicate ids", lambda: ShockLibrary.from_models([_d8(), _d8()]),
     r"duplicate shock id 'D8'"),
    ("negative count", lambda: LinearShock("B", 1.0, count=-1), r"shock 'B': count = -1 is "
     r"not >= 0"),
    ("float count", lambda: LinearShock("B", 1.0, count=2.0), r"count must be an integer, got "
     r"float"),
    ("bool count", lambda: LinearShock("B", 1.0, count=True), r"count must be an integer"),
    ("bad write units", lambda: _d8().to_toml_dict("metric"), r"unknown unit system 'metric'"),
]


@pytest.mark.parametrize("make, match", [c[1:] for c in BAD_MODELS],
                         ids=[c[0] for c in BAD_MODELS])
def test_bad_models_raise(make, match):
    with pytest.raises(ShockModelError, match=match):
        make()


_HEAD = '[[shock]]\nid = "B20"\nkind = "linear"\ndamping = 3502.5\n'
BAD_FILES = [
    ("not toml", "units = \n", r"not valid TOML"),
    ("no shocks", 'units = "SI"\n', r"no \[\[shock\]\] tables"),
    ("shock not array", 'shock = 3\n', r"key 'shock' must be an array of tables"),
    ("bad units", 'units = "metric"\n' + _HEAD, r"key 'units': unknown unit system 'metric'"),
    ("missing id", '[[shock]]\nkind = "linear"\ndamping = 1.0\n',
     r"\[\[shock\]\] #1: key 'id' is missing"),
    ("id not string", '[[shock]]\nid = 20\nkind = "linear"\ndamping = 1.0\n',
     r"#1: key 'id' must be a string, got int"),
    ("missing kind", _HEAD + '[[shock]]\nid = "X"\ndamping = 1.0\n',
     r"#2 \('X'\): key 'kind' is missing"),
    ("unknown kind", _HEAD + '[[shock]]\nid = "X"\nkind = "magic"\n',
     r"#2 \('X'\): key 'kind' is 'magic', an unknown kind; use one of \['linear', 'table', "
     r"'digressive', 'adjustable'\]"),
    ("missing damping", '[[shock]]\nid = "X"\nkind = "linear"\n',
     r"#1 \('X'\): key 'damping' is missing .* N/\(m/s\)"),
    ("string damping", '[[shock]]\nid = "X"\nkind = "linear"\ndamping = "3502"\n',
     r"#1 \('X'\): key 'damping' must be a number, got str '3502'"),
    ("bool damping", '[[shock]]\nid = "X"\nkind = "linear"\ndamping = true\n',
     r"key 'damping' must be a number, got bool"),
    ("negative damping", '[[shock]]\nid = "X"\nkind = "linear"\ndamping = -1.0\n',
     r"#1 \('X'\): key 'damping' = -1 N/\(m/s\) is not >= 0"),
    ("string lag", _HEAD + 'lag = "4 ms"\n', r"#1 \('B20'\): key 'lag' must be a number"),
    ("negative lag", _HEAD + "lag = -0.1\n", r"#1 \('B20'\): key 'lag' = -0.1 s is not >= 0"),
    ("unknown key", _HEAD + "lagg = 0.1\n", r"key 'lagg' is not a key of a 'linear' shock"),
    ("description type", _HEAD + "description = 3\n", r"key 'description' must be a string"),
    ("table scalar", '[[shock]]\nid = "T"\nkind = "table"\nvelocity = 1.0\nforce = [1.0]\n',
     r"#1 \('T'\): key 'velocity' must be an array of numbers"),
    ("table string item",
     '[[shock]]\nid = "T"\nkind = "table"\nvelocity = [0.0, "a"]\nforce = [0.0, 1.0]\n',
     r"key 'velocity' has a str 'a' at position 1"),
    ("table missing force", '[[shock]]\nid = "T"\nkind = "table"\nvelocity = [0.0, 1.0]\n',
     r"key 'force' is missing"),
    ("table length",
     '[[shock]]\nid = "T"\nkind = "table"\nvelocity = [0.0, 1.0]\nforce = [0.0, 1.0, 2.0]\n',
     r"#1 \('T'\): key 'force' has 3 values"),
    ("table not increasing",
     '[[shock]]\nid = "T"\nkind = "table"\nvelocity = [0.0, 1.0, 0.5]\nforce = [0, 1, 2]\n',
     r"key 'velocity' is not strictly increasing"),
    ("table nan", '[[shock]]\nid = "T"\nkind = "table"\nvelocity = [0.0, 1.0]\n'
     "force = [0.0, nan]\n", r"key 'force\[1\]' is nan"),
    ("table not passive",
     '[[shock]]\nid = "T"\nkind = "table"\nvelocity = [-1.0, 0.0, 1.0]\nforce = [5, 0, 1]\n',
     r"#1 \('T'\): key 'force\[0\]' = 5 N .* wrong sign"),
    ("digressive missing", '[[shock]]\nid = "K"\nkind = "digressive"\nbump_low = 1.0\n',
     r"key 'bump_knee' is missing \(required for kind 'digressive'\)"),
    ("digressive zero knee",
     '[[shock]]\nid = "K"\nkind = "digressive"\nbump_low = 1.0\nbump_knee = 0.0\n'
     "bump_high = 1.0\nrebound_low = 1.0\nrebound_knee = 0.1\nrebound_high = 1.0\n",
     r"key 'bump_knee' = 0 m/s is not > 0"),
    ("float count", _HEAD + "count = 2.0\n", r"#1 \('B20'\): key 'count' must be an integer, "
     r"got float"),
    ("string count", _HEAD + 'count = "2"\n', r"key 'count' must be an integer, got str"),
    ("negative count", _HEAD + "count = -2\n", r"#1 \('B20'\): key 'count' = -2 is not >= 0"),
    ("duplicate id", _HEAD + _HEAD, r"\[\[shock\]\] #2 \('B20'\): key 'id' repeats"),
]


@pytest.mark.parametrize("text, match", [c[1:] for c in BAD_FILES], ids=[c[0] for c in BAD_FILES])
def test_bad_library_files_raise(tmp_path, text, match):
    path = tmp_path / "shocks.toml"
    path.write_text(text)
    with pytest.raises(ShockModelError, match=match) as info:
        read_shock_library(path)
    assert str(path) in str(info.value)


def test_missing_library_file_raises(tmp_path):
    with pytest.raises(ShockModelError, match="shock library not found"):
        read_shock_library(tmp_path / "nope.toml")


BAD_DYNO = [
    ("no velocity", {"speed": [0.1], "force": [1.0]}, {}, r"no column 'velocity'"),
    ("no force", {"velocity": [0.1], "bump_force": [1.0]}, {},
     r"no column 'rebound_force'"),
    ("both layouts", {"velocity": [0.1], "force": [1.0], "bump_force": [1.0]}, {},
     r"both a 'force' column and"),
    ("non numeric", {"velocity": [0.1, 0.2], "force": [1.0, "x"]}, {},
     r"column 'force' has 1 missing or non-numeric value\(s\), the first at data row 2"),
    ("missing value", {"velocity": [0.1, None], "force": [1.0, 2.0]}, {},
     r"column 'velocity' has 1 missing"),
    ("wrong sign", {"velocity": [0.1, -0.1], "force": [10.0, 5.0]}, {},
     r"column 'force' data row 2: force 5 N at velocity -0.1 m/s has the wrong sign"),
    ("force at zero", {"velocity": [0.0, 0.1], "force": [30.0, 50.0]}, {},
     r"data row 1: force 30 N at zero velocity"),
    ("negative end slope",
     {"velocity": [-0.1, 0.1, 0.2, 0.3], "force": [-10.0, 10.0, 30.0, 20.0]}, {},
     r"column 'force': the force decreases .* 0.2 and 0.3 m/s"),
    ("split negative velocity",
     {"velocity": [-0.1], "bump_force": [1.0], "rebound_force": [1.0]}, {},
     r"column 'velocity' has a negative value at data row 1"),
    ("split negative force",
     {"velocity": [0.1, 0.2], "bump_force": [1.0, 2.0], "rebound_force": [1.0, -2.0]}, {},
     r"column 'rebound_force' has a negative value at data row 2"),
    ("digressive too few",
     {"velocity": [0.1, 0.2], "bump_force": [1.0, 2.0], "rebound_force": [1.0, 2.0]},
     {"kind": "digressive"}, r"the bump side has 2 distinct non-zero velocities"),
    ("unknown kind", {"velocity": [0.1], "force": [1.0]}, {"kind": "spline"},
     r"unknown fit kind 'spline'"),
    ("unknown units", {"velocity": [0.1], "force": [1.0]}, {"units": "cgs"},
     r"unknown unit system 'cgs'"),
    ("no rows", {"velocity": [], "force": []}, {}, r"no data rows"),
]


@pytest.mark.parametrize("columns, options, match", [c[1:] for c in BAD_DYNO],
                         ids=[c[0] for c in BAD_DYNO])
def test_bad_dyno_data_raise(tmp_path, columns, options, match):
    path = tmp_path / "dyno.csv"
    pd.DataFrame(columns).to_csv(path, index=False)
    with pytest.raises(ShockModelError, match=match) as info:
        fit_shock_to_dyno(path, id="X", **options)
    assert str(path) in str(info.value)


def test_dyno_csv_with_leading_comment_lines_reads(tmp_path):
    """A dyno sheet with a unit marker (and a comment) first reads like one without."""
    path = tmp_path / "dyno.csv"
    body = "velocity,force\n-0.2,-600\n-0.05,-200\n0.05,150\n0.2,450\n"
    path.write_text(body)
    plain = fit_shock_to_dyno(path, id="X")
    path.write_text("# units: SI\n# dyno of 3 May\n" + body)
    marked = fit_shock_to_dyno(path, id="X")
    np.testing.assert_array_equal(marked.to_pwl().f_knots_n, plain.to_pwl().f_knots_n)
    path.write_text("".join(line + (",units\n" if k == 0 else ",SI\n")  # a units column
                            for k, line in enumerate(body.splitlines())))
    column = fit_shock_to_dyno(path, id="X")
    np.testing.assert_array_equal(column.to_pwl().f_knots_n, plain.to_pwl().f_knots_n)


def test_dyno_missing_file_and_bad_type(tmp_path):
    with pytest.raises(ShockModelError, match="dyno file not found"):
        fit_shock_to_dyno(tmp_path / "nope.csv", id="X")
    with pytest.raises(TypeError, match="CSV path or a pandas DataFrame"):
        fit_shock_to_dyno([[0.1, 1.0]], id="X")


# ---------------------------------------------------------------- documentation


def test_docstring_examples_run():
    result = doctest.testmod(shocks, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted > 0
