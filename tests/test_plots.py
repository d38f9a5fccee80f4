"""Tests of ident.identify.plots: FRF figures from a small synthetic FRF and model, unit conversion
read back from the drawn lines, PNG files written atomically, bad inputs."""

import io
import threading

import matplotlib

matplotlib.use("Agg")  # headless; the module itself never touches pyplot

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.testing import assert_allclose

from ident.data.files import png_metadata
from ident.identify.frf import DF_INPUTS, MODEL_INPUTS, Frf
from ident.identify.model import VehicleModel
from ident.identify.plots import display_scale, frf_plot_data, plot_frf, write_frf_plots
from ident.data.units import TO_SI

OUTPUTS = ("shock_velocity_LF", "ride_height_LF")
N_F = 200
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
ATOL_DB = 1e-9  # a constant factor in dB: round-off only


def _model(frf=None):
    """Two outputs x 11 inputs, one or two modes per pair (SI)."""
    n_out, n_in = len(OUTPUTS), len(MODEL_INPUTS)
    rng = np.random.default_rng(7)
    poles = np.full((n_out, n_in, 2), np.nan, dtype=complex)
    residues = np.full_like(poles, np.nan)
    n_poles = np.ones((n_out, n_in), dtype=int)
    wb, ww = 2 * np.pi * 1.5, 2 * np.pi * 12.0
    poles[..., 0] = -0.3 * wb + 1j * wb
    residues[..., 0] = rng.standard_normal((n_out, n_in)) * 1e-3 + 1j * 1e-3
    poles[:, 7:, 1] = -0.2 * ww + 1j * ww
    residues[:, 7:, 1] = 2e-3
    n_poles[:, 7:] = 2
    return VehicleModel(name="tiny", input_names=MODEL_INPUTS, output_names=OUTPUTS,
                        poles=poles, residues=residues, direct=np.zeros((n_out, n_in)),
                        n_poles=n_poles, order=2 * n_poles, fit_error=np.zeros((n_out, n_in)),
                        cbar_n_s_m=np.full(4, 3500.0), fs_hz=100.0, frf=frf)


def _frf(conditioned=True):
    """A noisy estimate of :func:`_model`'s response on 200 frequencies."""
    f = np.linspace(0.0, 25.0, N_F)
    truth = _model().frequency_response(np.maximum(f, 1e-3))  # f = 0: padded poles 0/0
    rng = np.random.default_rng(3)
    noise = 1 + 0.05 * (rng.standard_normal(truth.shape) + 1j * rng.standard_normal(truth.shape))
    coh = np.clip(1 - 0.5 * rng.random(truth.shape), 0, 1)
    n_out, n_in = truth.shape[:2]
    replaced = np.zeros(truth.shape, dtype=bool)
    replaced[..., f > 18.0] = True
    return Frf(f_hz=f, H=truth * (1 + 0.2 * (noise - 1)) if conditioned else truth * noise,
               input_names=MODEL_INPUTS, output_names=OUTPUTS,
               multiple_coherence=coh.max(axis=1), partial_coherence=coh,
               input_condition=np.ones(N_F), independent_fraction=np.ones((n_in, N_F)),
               flagged=np.zeros((n_in, N_F), dtype=bool), n_averages=40,
               cbar_n_s_m=np.full(4, 3500.0), fs_hz=100.0,
               H_raw=truth * noise if conditioned else None,
               replaced=replaced if conditioned else None), truth


def _lines(ax):
    return {line.get_label(): line for line in ax.get_lines()}


def test_display_scale_known_factors():
    f, label = display_scale("shock_velocity_RR", "dF_RR", "imperial")
    assert_allclose(f, TO_SI["force"] / TO_SI["velocity"], rtol=1e-15)
    assert label == "(in/s)/lbf"
    assert display_scale("tire_force_LF", "aero_roll", "SI") == (1.0, "N/(N*m)")
    f, label = display_scale("tire_force_LF", "aero_roll", "imperial")
    assert_allclose(f, TO_SI["moment"] / TO_SI["force"], rtol=1e-15)
    assert label == "lbf/(lbf*in)"


def test_plot_frf_default_shock_group_and_labels():
    frf, truth = _frf()
    fig = plot_frf(_model(frf), "shock_velocity_LF", truth=truth, units="imperial")
    assert isinstance(fig, Figure)
    ax_c, ax_m, ax_p = fig.axes[:3]
    assert ax_c.get_title() == "shock_velocity_LF"
    assert ax_m.get_ylabel() == "|H| [dB re 1 (in/s)/lbf]"
    assert ax_p.get_ylabel() == "phase [deg]"
    assert ax_p.get_xscale() == "log"
    names = _lines(ax_m)
    for i in DF_INPUTS:  # default inputs: the 4 shock forces, every kind of curve
        for kind in ("estimate", "conditioned", "replaced", "fit", "ideal"):
            assert f"{i} {kind}" in names
        assert f"{i} coherence" in _lines(ax_c)
    assert not any(k.startswith("wheelloader") for k in names)
    coh = _lines(ax_c)["dF_LF coherence"].get_ydata()
    assert np.all((coh >= 0) & (coh <= 1))
    assert ax_c.get_legend() is not None and ax_m.get_legend() is not None
    # the shaded (replaced) part lies only above 18 Hz
    x, y = (np.asarray(a, dtype=float) for a in names["dF_LF replaced"].get_data())
    assert np.all(x[np.isfinite(y)] > 18.0) and np.isfinite(y).any()


def test_imperial_magnitude_shift_read_back_from_axes():
    frf, truth = _frf()
    model = _model(frf)
    ax_si = plot_frf(model, "shock_velocity_LF", truth=truth, units="SI").axes[1]
    ax_im = plot_frf(model, "shock_velocity_LF", truth=truth, units="imperial").axes[1]
    assert "(m/s)/N" in ax_si.get_ylabel()
    shift = 20 * np.log10(TO_SI["force"] / TO_SI["velocity"])  # ~ +44.9 dB
    for label in ("dF_LF estimate", "dF_RF conditioned", "dF_LR fit", "dF_RR ideal"):
        y_si = np.asarray(_lines(ax_si)[label].get_ydata(), dtype=float)
        y_im = np.asarray(_lines(ax_im)[label].get_ydata(), dtype=float)
        assert_allclose(y_im - y_si, shift, atol=ATOL_DB)
    # phase is unit-independent
    p_si = _lines(plot_frf(model, "shock_velocity_LF", units="SI").axes[2])["dF_LF fit"]
    p_im = _lines(plot_frf(model, "shock_velocity_LF", units="imperial").axes[2])["dF_LF fit"]
    assert_allclose(p_si.get_ydata(), p_im.get_ydata())


def test_plot_data_equals_model_response_in_display_units():
    """Equivalence: the fit curve is the model's response x the display factor."""
    model = _model()
    data = frf_plot_data(model, "ride_height_LF", inputs="rig", units="imperial")
    assert data.inputs == MODEL_INPUTS[:7] and data.H_raw is None and data.coherence is None
    H = model.frequency_response(data.f_model_hz)[1, :7]
    expected = np.array([display_scale("ride_height_LF", i, "imperial")[0]
                         for i in MODEL_INPUTS[:7]])
    assert_allclose(data.H_model, H * expected[:, None], rtol=1e-14)
    assert_allclose(expected[3:], 1.0)  # wheelloader -> ride height: in/in = m/m
    assert "see legend" in data.magnitude_label  # mixed input quantities


def test_truth_array_and_callable_agree_on_the_frf_grid():
    frf, truth = _frf()
    a = frf_plot_data(frf, "shock_velocity_LF", truth=truth, f_range_hz=(1.0, 10.0))
    assert_allclose(a.f_truth_hz, a.f_est_hz)
    assert a.f_est_hz.min() >= 1.0 and a.f_est_hz.max() <= 10.0
    b = frf_plot_data(frf, "shock_velocity_LF", truth=_model().frequency_response,
                      f_range_hz=(1.0, 10.0))
    H_b = _model().frequency_response(b.f_truth_hz)[0, 7:]
    assert_allclose(b.H_truth, H_b, rtol=1e-14)


def test_unconditioned_frf_draws_the_estimate_only():
    frf, _ = _frf(conditioned=False)
    fig = plot_frf(frf, "ride_height_LF", inputs=["dF_LF", "wheelloader_LF"])
    names = _lines(fig.axes[1])
    assert set(names) == {"dF_LF estimate", "wheelloader_LF estimate"}


def test_plot_into_given_figure_clears_it():
    frf, _ = _frf()
    fig = Figure()
    fig.add_subplot(111)
    out = plot_frf(frf, "shock_velocity_LF", fig=fig)
    assert out is fig and len(fig.axes) == 3


def test_write_frf_plots_files_are_png(tmp_path):
    frf, truth = _frf()
    out = tmp_path / "plots" / "frf"
    paths = write_frf_plots(_model(frf), out, truth=truth, units="imperial", dpi=40)
    assert [p.name for p in paths] == [f"frf_{o}_{g}.png" for o in OUTPUTS
                                       for g in ("rig", "shock")]
    for p in paths:
        data = p.read_bytes()
        assert len(data) > 1000 and data[:8] == PNG_MAGIC
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in paths)  # no temps
    # earlier plots are replaced
    again = write_frf_plots(frf, out, outputs=["ride_height_LF"], dpi=40)
    assert [p.name for p in again] == ["frf_ride_height_LF_rig.png",
                                      "frf_ride_height_LF_shock.png"]


def test_written_pages_equal_fresh_figures(tmp_path):
    """Equivalence: the writer draws every page into one reused figure; each PNG has the
    bytes of the page drawn into a new figure, so nothing of an earlier page is left."""
    frf, truth = _frf()
    model = _model(frf)
    paths = write_frf_plots(model, tmp_path, truth=truth, units="imperial", dpi=40)
    for path in paths:
        output, group = path.stem[len("frf_"):].rsplit("_", 1)
        buf = io.BytesIO()
        fresh = plot_frf(model, output, inputs=group, truth=truth, units="imperial")
        fresh.savefig(buf, format="png", dpi=40, metadata=png_metadata(fresh))
        assert path.read_bytes() == buf.getvalue(), path.name
    again = write_frf_plots(model, tmp_path / "again", truth=truth, units="imperial", dpi=40)
    assert [p.read_bytes() for p in again] == [p.read_bytes() for p in paths]  # deterministic


@pytest.mark.parametrize("units", ["SI", "imperial"])
def test_fixed_layout_keeps_labels_inside_and_clear_of_ticks(units):
    """The fixed margins hold the longest labels: mixed units (rig inputs) and dB ticks."""
    frf, truth = _frf()
    fig = plot_frf(_model(frf), "ride_height_LF", inputs="rig", truth=truth, units=units)
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    width, height = fig.bbox.width, fig.bbox.height
    for ax in fig.axes:
        label = ax.yaxis.label.get_window_extent(renderer)
        ticks = [t.get_window_extent(renderer) for t in ax.get_yticklabels() if t.get_text()]
        assert label.x0 >= 0 and label.x1 < min(b.x0 for b in ticks), ax.get_ylabel()
    ax_p = fig.axes[2]
    xlabel = ax_p.xaxis.label.get_window_extent(renderer)
    xticks = [t.get_window_extent(renderer) for t in ax_p.get_xticklabels() if t.get_text()]
    assert xlabel.y0 >= 0 and xlabel.y1 < min(b.y0 for b in xticks)
    title = fig.axes[0].title.get_window_extent(renderer)
    assert title.y1 <= height
    tight = fig.get_tightbbox(renderer)  # inches
    assert tight.x0 >= 0 and tight.y0 >= 0
    assert tight.x1 <= width / fig.dpi and tight.y1 <= height / fig.dpi


def test_write_frf_plots_never_replaces_a_user_file(tmp_path):
    frf, _ = _frf()
    user = tmp_path / "frf_shock_velocity_LF_shock.png"
    user.write_text("my notes")
    with pytest.raises(FileExistsError, match="not a PNG"):
        write_frf_plots(frf, tmp_path, dpi=40)
    assert user.read_text() == "my notes"
    assert sorted(p.name for p in tmp_path.iterdir()) == [user.name]  # nothing written


def test_plots_in_threads(tmp_path):
    """Figures are independent objects: plotting from threads works."""
    frf, _ = _frf()
    errors = []

    def work(k):
        try:
            write_frf_plots(frf, tmp_path / str(k), outputs=[OUTPUTS[k % 2]], dpi=30)
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert all(len(list((tmp_path / str(k)).glob("*.png"))) == 2 for k in range(2))


@pytest.mark.parametrize("kwargs, error, match", [
    ({"output": "tire_force_LF"}, ValueError, "output 'tire_force_LF' not in"),
    ({"inputs": ["dF_XX"]}, ValueError, r"input\(s\) \['dF_XX'\] not in"),
    ({"inputs": []}, ValueError, "inputs is empty"),
    ({"units": "metric"}, ValueError, "unknown unit system"),
    ({"f_range_hz": (0.0, 20.0)}, ValueError, "0 < low < high"),
    ({"f_range_hz": (30.0, 40.0)}, ValueError, "no frequency in f_range_hz"),
    ({"truth": np.zeros((2, 11, 5))}, ValueError, "truth has shape"),
    ({"truth": lambda f: np.zeros((1, 11, f.size))}, ValueError, r"truth\(f_hz\) returned"),
    ({"truth": "ideal"}, TypeError, "truth must be"),
    ({"fig": "figure"}, TypeError, "fig must be"),
])
def test_plot_frf_bad_inputs(kwargs, error, match):
    frf, _ = _frf()
    kwargs = {"output": "shock_velocity_LF", **kwargs}
    with pytest.raises(error, match=match):
        plot_frf(frf, kwargs.pop("output"), **kwargs)


def test_bad_object_and_unknown_channel_in_imperial():
    with pytest.raises(TypeError, match="expected an ident.identify.frf.Frf"):
        plot_frf(np.zeros(3), "x")
    with pytest.raises(ValueError, match="array but there is no FRF"):
        frf_plot_data(_model(), "ride_height_LF", truth=np.zeros((2, 11, N_F)))
    with pytest.raises(ValueError, match="not a canonical channel"):
        display_scale("y0", "u0", "imperial")
    assert display_scale("y0", "u0")[0] == 1.0

