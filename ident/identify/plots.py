"""Frequency-response plots of estimated FRFs and identified models (seed paper, Figs. 6-9).

For one output channel and a group of inputs, :func:`plot_frf` draws three
stacked axes on a shared logarithmic frequency axis:

1. the partial coherence of every input/output pair (0..1);
2. the magnitude in dB of the response in display units (output quantity per
   input quantity, e.g. ``dB re 1 (in/s)/lbf``);
3. the phase in degrees.

Per input one colour: the raw estimate (thin, light), the conditioned
estimate when the FRF was conditioned (``Frf.H_raw`` is set; a grey band
marks the frequencies replaced by residual fits), the fitted model (solid)
and the ideal response (dashed black) when a truth is given.

Compute and plot are separate: :func:`frf_plot_data` gathers the curves in
display units (no matplotlib), :func:`plot_frf` draws them and
:func:`write_frf_plots` writes one PNG per output channel and input group.

Notes
-----
Only the object-oriented matplotlib API is used (``matplotlib.figure.Figure``,
never ``pyplot``): no global figure state, no GUI backend, so figures can be
made in worker threads. PNGs are rendered by the Agg canvas.

The layout is fixed: margins, gaps and label distances in inches, the same on
every page, instead of a layout engine that measures every tick label on every
save. :func:`write_frf_plots` evaluates the model and the truth once for all
pages and draws the pages one after the other into a single figure (axes, ticks
and grids made once; one Agg renderer with its text caches); a page is
pixel for pixel the page :func:`plot_frf` draws into a new figure.

A response in SI units ``H`` [out_SI / in_SI] is displayed in the unit system
``units`` as ``H * from_si(1, out_q) / from_si(1, in_q)``, where ``out_q`` and
``in_q`` are the quantities of the output and the input channel
(:func:`ident.data.channels.quantity_of`; the shock-force inputs ``dF_XX`` are
forces). The factor is positive, so the phase does not depend on the units.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ident.data.files import atomic_path, png_metadata
from ident.data.channels import RIG_INPUTS, quantity_of
from ident.identify.frf import DF_INPUTS, Frf
from ident.data.units import UNIT_LABELS, check_units, from_si

__all__ = [
    "INPUT_GROUPS",
    "FrfPlotData",
    "display_scale",
    "frf_plot_data",
    "plot_frf",
    "write_frf_plots",
]

log = logging.getLogger(__name__)

#: Named input groups: the 7 rig inputs and the 4 shock-force deviations.
INPUT_GROUPS = {"rig": RIG_INPUTS, "shock": DF_INPUTS}

#: Default frequency range of the plots [Hz].
F_RANGE_HZ = (0.5, 20.0)
#: Points of the log-spaced grid on which models and callable truths are evaluated.
N_MODEL_POINTS = 600
#: The magnitude axis shows at most this range below its largest value [dB].
MAG_RANGE_DB = 100.0
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

#: Size of the figures [in] (width, height).
FIG_SIZE_IN = (8.0, 9.0)
#: Heights of the coherence, magnitude and phase axes relative to each other.
_HEIGHT_RATIOS = (1.0, 1.6, 1.0)
# Fixed layout [in]: margins around the axes, the gap between them, and the distance from
# an axes' left edge to its y label (past the tick labels, up to "-100") and from the bottom
# axes to the x label. Measuring every tick label to place the axes (constrained layout) took
# half of the time of writing the plots (docs/DESIGN.md, "FRF plots").
_MARGIN_IN = {"left": 0.78, "right": 0.12, "bottom": 0.52, "top": 0.28}
_GAP_IN = 0.14
_YLABEL_IN = 0.56
_XLABEL_IN = 0.32


# ----------------------------------------------------------------------------------------------
# units
# ----------------------------------------------------------------------------------------------

def _quantity(channel):
    """Quantity of a channel (``dF_XX`` are forces), or None for a non-canonical name."""
    if channel in DF_INPUTS:
        return "force"
    try:
        return quantity_of(channel)
    except (ValueError, KeyError):
        return None


def _paren(label):
    return f"({label})" if any(ch in label for ch in "/*^") else label


def display_scale(output, input, units="SI"):
    """Factor and unit label that display an SI response of a pair in `units`.

    Parameters
    ----------
    output, input : str
        Canonical channel names; inputs ``dF_XX`` are shock forces.
    units : {"SI", "imperial"}

    Returns
    -------
    factor : float
        Multiplies a response in SI units [out_SI / in_SI] to give it in
        `units`: ``from_si(1, out_q, units) / from_si(1, in_q, units)``.
    label : str
        The unit of the displayed ratio, e.g. ``"(in/s)/lbf"``; for channels
        without a known quantity (only allowed in SI) ``"<output>/<input> SI"``.

    Raises
    ------
    ValueError
        If `units` is unknown, or a channel has no known quantity and `units`
        is not SI (its conversion is unknown).

    Examples
    --------
    >>> factor, label = display_scale("shock_velocity_LF", "dF_LF", "imperial")
    >>> round(factor, 3), label
    (175.127, '(in/s)/lbf')
    >>> display_scale("ride_height_LF", "wheelloader_LF")
    (1.0, 'm/m')
    """
    units = check_units(units)
    q_out, q_in = _quantity(output), _quantity(input)
    if q_out is None or q_in is None:
        if units != "SI":
            bad = output if q_out is None else input
            raise ValueError(f"channel {bad!r} is not a canonical channel, so its unit is "
                             f"unknown and it cannot be shown in {units!r}; use units='SI'")
        return 1.0, f"{output}/{input} SI"
    factor = float(from_si(1.0, q_out, units)) / float(from_si(1.0, q_in, units))
    labels = UNIT_LABELS[units]
    return factor, f"{_paren(labels[q_out])}/{_paren(labels[q_in])}"


# ----------------------------------------------------------------------------------------------
# compute
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class FrfPlotData:
    """The curves of one FRF plot, in display units (see :func:`frf_plot_data`).

    Attributes
    ----------
    output : str
    inputs : tuple of str
    units : str
        ``"SI"`` or ``"imperial"``.
    scale : ndarray, shape (n_in,)
        Display factor per input (:func:`display_scale`).
    unit_labels : tuple of str
        Unit of each displayed ratio, e.g. ``"(in/s)/lbf"``.
    f_est_hz : ndarray, shape (n_est,) or None
        Frequencies of the estimate [Hz], inside ``f_range_hz``; None without an FRF.
    coherence : ndarray, shape (n_in, n_est) or None
        Partial coherence of each pair.
    multiple_coherence : ndarray, shape (n_est,) or None
    H_raw : ndarray of complex, shape (n_in, n_est) or None
        The estimate before conditioning (the FRF itself if it was not conditioned).
    H_cond : ndarray of complex, shape (n_in, n_est) or None
        The conditioned estimate (only for a conditioned FRF).
    replaced : ndarray of bool, shape (n_in, n_est) or None
        Frequencies of `H_cond` replaced by residual fits.
    f_model_hz : ndarray, shape (n_model,)
        Log-spaced frequencies of the model and callable-truth curves [Hz].
    H_model : ndarray of complex, shape (n_in, n_model) or None
        The fitted model (only for a model).
    f_truth_hz : ndarray or None
        Frequencies of `H_truth` [Hz].
    H_truth : ndarray of complex, shape (n_in, n_truth) or None
    f_range_hz : (float, float)
    """

    output: str
    inputs: tuple
    units: str
    scale: np.ndarray
    unit_labels: tuple
    f_est_hz: np.ndarray | None
    coherence: np.ndarray | None
    multiple_coherence: np.ndarray | None
    H_raw: np.ndarray | None
    H_cond: np.ndarray | None
    replaced: np.ndarray | None
    f_model_hz: np.ndarray
    H_model: np.ndarray | None
    f_truth_hz: np.ndarray | None
    H_truth: np.ndarray | None
    f_range_hz: tuple

    @property
    def magnitude_label(self):
        """str: the magnitude axis label, with the unit when all inputs share it."""
        if len(set(self.unit_labels)) == 1:
            return f"|H| [dB re 1 {self.unit_labels[0]}]"
        return "|H| [dB re 1 output unit per input unit, see legend]"


def _split(model_or_frf):
    """Return ``(model or None, frf or None)``."""
    if isinstance(model_or_frf, Frf):
        return None, model_or_frf
    if callable(getattr(model_or_frf, "frequency_response", None)) and hasattr(
            model_or_frf, "output_names") and hasattr(model_or_frf, "input_names"):
        frf = getattr(model_or_frf, "frf", None)
        if frf is not None and not isinstance(frf, Frf):
            raise TypeError(f"model.frf must be an ident.identify.frf.Frf or None, got "
                            f"{type(frf).__name__}")
        return model_or_frf, frf
    raise TypeError(f"expected an ident.identify.frf.Frf or an ident.identify.model.VehicleModel, got "
                    f"{type(model_or_frf).__name__}")


def _resolve_inputs(inputs, names):
    names = tuple(names)
    if inputs is None:
        return DF_INPUTS if all(i in names for i in DF_INPUTS) else names
    if isinstance(inputs, str):
        if inputs == "all":
            return names
        if inputs in INPUT_GROUPS:
            sel = tuple(i for i in INPUT_GROUPS[inputs] if i in names)
            if not sel:
                raise ValueError(f"inputs={inputs!r}: none of the group's inputs "
                                 f"{list(INPUT_GROUPS[inputs])} is in {list(names)}")
            return sel
        inputs = (inputs,)
    inputs = tuple(inputs)
    if not inputs:
        raise ValueError("inputs is empty; give input names, a group ('rig', 'shock', "
                         "'all') or None for the shock inputs")
    missing = [i for i in inputs if i not in names]
    if missing:
        raise ValueError(f"input(s) {missing} not in this model/FRF; it has {list(names)} "
                         "(or use a group: 'rig', 'shock', 'all')")
    return inputs


def _check_range(f_range_hz):
    try:
        lo, hi = (float(x) for x in f_range_hz)
    except (TypeError, ValueError):
        raise ValueError(f"f_range_hz must be two frequencies (low, high) in Hz, got "
                         f"{f_range_hz!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ValueError(f"f_range_hz must satisfy 0 < low < high (log frequency axis), got "
                         f"{f_range_hz!r}")
    return lo, hi


def frf_plot_data(model_or_frf, output, *, inputs=None, truth=None, units="SI",
                  f_range_hz=(0.5, 20.0)):
    """Gather the curves of an FRF plot in display units (no plotting).

    Parameters
    ----------
    model_or_frf : ident.identify.model.VehicleModel or ident.identify.frf.Frf
        A model (its ``frf``, if any, gives the estimates and coherences) or an
        FRF estimate.
    output : str
        Output channel.
    inputs : sequence of str or str, optional
        Input names, or a group: ``"shock"`` (the ``dF_XX``), ``"rig"`` (the 7
        rig inputs), ``"all"``. Default: the 4 ``dF_XX`` inputs if present,
        else all inputs.
    truth : ndarray or callable, optional
        The ideal response: an array of shape (n_out, n_in, n_f) on the FRF's
        frequency grid ``f_hz``, or a callable ``f_hz -> (n_out, n_in, n_f)``;
        SI units, channel order as the model's / FRF's.
    units : {"SI", "imperial"}
        Display units.
    f_range_hz : (float, float)
        Frequency range shown [Hz], ``0 < low < high``.

    Returns
    -------
    FrfPlotData

    Raises
    ------
    TypeError
        If `model_or_frf` is neither an FRF nor a model, or `truth` neither
        an array nor a callable.
    ValueError
        On an unknown output or input, bad `units` or `f_range_hz`, a `truth`
        of the wrong shape, an array `truth` without an FRF grid, or an FRF
        with no frequency inside `f_range_hz`.
    """
    model, frf = _split(model_or_frf)
    units = check_units(units)
    lo, hi = _check_range(f_range_hz)
    src = model if model is not None else frf
    out_names, in_names = tuple(src.output_names), tuple(src.input_names)
    if output not in out_names:
        raise ValueError(f"output {output!r} not in this model/FRF; it has {list(out_names)}")
    inputs = _resolve_inputs(inputs, in_names)
    return _select(_evaluate(model, frf, truth, (lo, hi)), output, inputs, units)


@dataclass(frozen=True, eq=False)
class _Curves:
    """Every pair's curves in SI inside the frequency range: what the plots of one model or
    FRF share (see :func:`_evaluate`); responses are arrays (n_out, n_in, n_f)."""

    frf: Frf | None
    out_names: tuple
    in_names: tuple
    keep: np.ndarray | None
    f_model_hz: np.ndarray
    H_model: np.ndarray | None
    f_truth_hz: np.ndarray | None
    H_truth: np.ndarray | None
    f_range_hz: tuple


def _evaluate(model, frf, truth, f_range_hz):
    """Evaluate the model and the truth for every pair at once (the costly part of the plot
    data), in a checked range ``(low, high)`` [Hz]; raises as :func:`frf_plot_data`."""
    lo, hi = f_range_hz
    src = model if model is not None else frf
    out_names, in_names = tuple(src.output_names), tuple(src.input_names)
    keep = f_est = None
    if frf is not None:
        if tuple(frf.output_names) != out_names or tuple(frf.input_names) != in_names:
            raise ValueError("model.frf has other channels than the model; refit or rebuild "
                             "the model from this FRF")
        keep = (frf.f_hz >= lo) & (frf.f_hz <= hi) & (frf.f_hz > 0)
        if not keep.any():
            raise ValueError(f"the FRF has no frequency in f_range_hz={(lo, hi)!r} (it spans "
                             f"{frf.f_hz.min():g}-{frf.f_hz.max():g} Hz); widen the range")
        f_est = frf.f_hz[keep]

    f_model = np.geomspace(lo, hi, N_MODEL_POINTS)
    H_model = None
    if model is not None:
        H_model = np.asarray(model.frequency_response(f_model))

    f_truth = T = None
    if truth is not None:
        n_out, n_in = len(out_names), len(in_names)
        if callable(truth):
            f_truth = f_model
            T = np.asarray(truth(f_truth))
        elif isinstance(truth, (np.ndarray, list, tuple)):
            if frf is None:
                raise ValueError("truth is an array but there is no FRF frequency grid to put it "
                                 "on (a model without .frf); pass a callable f_hz -> (n_out, "
                                 "n_in, n_f) instead")
            T = np.asarray(truth)
            if T.shape != (n_out, n_in, frf.f_hz.size):
                raise ValueError(f"truth has shape {T.shape}; expected (n_out, n_in, n_f) = "
                                 f"{(n_out, n_in, frf.f_hz.size)} on the FRF's frequency grid")
            f_truth = f_est
            T = T[..., keep]
        else:
            raise TypeError(f"truth must be an array (n_out, n_in, n_f) or a callable "
                            f"f_hz -> array, got {type(truth).__name__}")
        if T.shape != (n_out, n_in, f_truth.size):
            raise ValueError(f"truth(f_hz) returned shape {T.shape}; expected "
                             f"(n_out, n_in, n_f) = {(n_out, n_in, f_truth.size)}")
    return _Curves(frf=frf, out_names=out_names, in_names=in_names, keep=keep,
                   f_model_hz=f_model, H_model=H_model, f_truth_hz=f_truth, H_truth=T,
                   f_range_hz=(lo, hi))


def _select(curves, output, inputs, units):
    """The :class:`FrfPlotData` of one output and checked inputs, in display units."""
    o = curves.out_names.index(output)
    idx = [curves.in_names.index(i) for i in inputs]
    scales, labels = zip(*(display_scale(output, i, units) for i in inputs))
    scale = np.array(scales)[:, None]

    f_est = coh = mult = H_raw = H_cond = replaced = None
    frf, keep = curves.frf, curves.keep
    if frf is not None:
        f_est = frf.f_hz[keep]
        coh = np.asarray(frf.partial_coherence)[o][idx][:, keep]
        mult = np.asarray(frf.multiple_coherence)[o][keep]
        if frf.H_raw is not None:
            H_raw = np.asarray(frf.H_raw)[o][idx][:, keep] * scale
            H_cond = np.asarray(frf.H)[o][idx][:, keep] * scale
            if frf.replaced is not None:
                replaced = np.asarray(frf.replaced, dtype=bool)[o][idx][:, keep]
        else:
            H_raw = np.asarray(frf.H)[o][idx][:, keep] * scale
    H_model = None if curves.H_model is None else curves.H_model[o][idx] * scale
    H_truth = None if curves.H_truth is None else curves.H_truth[o][idx] * scale

    return FrfPlotData(output=output, inputs=inputs, units=units, scale=scale[:, 0],
                       unit_labels=tuple(labels), f_est_hz=f_est, coherence=coh,
                       multiple_coherence=mult, H_raw=H_raw, H_cond=H_cond, replaced=replaced,
                       f_model_hz=curves.f_model_hz, H_model=H_model,
                       f_truth_hz=curves.f_truth_hz, H_truth=H_truth,
                       f_range_hz=curves.f_range_hz)


def _db(h):
    """20 log10 |h|; exact zeros (pairs fitted as zero) are NaN so they are not drawn."""
    a = np.abs(h)
    out = np.full(a.shape, np.nan)
    pos = a > 0
    out[pos] = 20.0 * np.log10(a[pos])
    return out


def _phase_curve(f, h):
    """Phase in (-180, 180] deg, with NaN breaks at wraps so no vertical lines are drawn.

    Returns the frequencies and phases with the breaks inserted at the same places.
    """
    f = np.asarray(f, dtype=float)
    p = np.degrees(np.angle(h))
    p[np.abs(h) == 0] = np.nan
    if p.size > 1:
        at = np.flatnonzero(np.abs(np.diff(p)) > 180.0) + 1
        if at.size:
            return np.insert(f, at, np.nan), np.insert(p, at, np.nan)
    return f, p


# ----------------------------------------------------------------------------------------------
# plot
# ----------------------------------------------------------------------------------------------

def _fixed_layout(width_in, height_in):
    """GridSpec margins and spacing of the fixed layout for a figure of this size, or an
    empty dict (matplotlib's defaults) when the figure is too small for them."""
    m = _MARGIN_IN
    left, right = m["left"] / width_in, 1.0 - m["right"] / width_in
    bottom, top = m["bottom"] / height_in, 1.0 - m["top"] / height_in
    mean_h = ((top - bottom) * height_in - 2 * _GAP_IN) / 3
    if right - left < 0.5 or mean_h <= 0.5:
        return {}
    return {"left": left, "right": right, "bottom": bottom, "top": top,
            "hspace": _GAP_IN / mean_h}


def _frame(fig, f_range_hz):
    """The three axes of an FRF page with what every page shares: scales, limits, ticks,
    grids, the fixed labels and the label positions (:func:`_fill` draws a page into them).
    """
    from matplotlib.transforms import offset_copy

    gridspec_kw = {"height_ratios": _HEIGHT_RATIOS}
    if fig.get_layout_engine() is None:
        gridspec_kw.update(_fixed_layout(*fig.get_size_inches()))
    axes = fig.subplots(3, 1, sharex=True, gridspec_kw=gridspec_kw)
    ax_c, ax_m, ax_p = axes
    ax_c.set_ylabel("partial coherence [-]")
    ax_c.set_ylim(0.0, 1.05)
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_ylim(-190.0, 190.0)
    ax_p.set_yticks([-180, -90, 0, 90, 180])
    ax_p.set_xlabel("frequency [Hz]")
    ax_p.set_xscale("log")
    ax_p.set_xlim(*f_range_hz)
    for ax in axes:
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        # labels at a fixed distance from the axes: aligned, and no tick label is measured
        # to place them
        ax.yaxis.set_label_coords(0.0, 0.5, transform=offset_copy(
            ax.transAxes, fig=fig, x=-_YLABEL_IN, units="inches"))
    ax_p.xaxis.set_label_coords(0.5, 0.0, transform=offset_copy(
        ax_p.transAxes, fig=fig, y=-_XLABEL_IN, units="inches"))
    return tuple(axes)


def _clear(axes):
    """Remove the curves, texts and legends of a page from the axes of :func:`_frame`."""
    for ax in axes:
        for artist in [*ax.lines, *ax.texts]:
            artist.remove()
        if ax.get_legend() is not None:
            ax.get_legend().remove()


def _fill(data, axes):
    """Draw the page of `data` into empty axes of :func:`_frame`."""
    from matplotlib.lines import Line2D

    ax_c, ax_m, ax_p = axes
    colors = [f"C{k % 10}" for k in range(len(data.inputs))]
    styles = {}
    mags = []

    def both(f, h, **kw):
        label = kw.pop("label")
        mag = _db(h)
        mags.append(mag)
        # data lines stay inside the axes: keeping them out of a layout engine (a figure
        # given to plot_frf may have one) halves its time
        ax_m.plot(f, mag, label=label, in_layout=False, **kw)
        ax_p.plot(*_phase_curve(f, h), label=label, in_layout=False, **kw)

    for k, (name, color) in enumerate(zip(data.inputs, colors)):
        if data.coherence is not None:
            ax_c.plot(data.f_est_hz, data.coherence[k], color=color, lw=1.0,
                      label=f"{name} coherence", in_layout=False)
        if data.H_raw is not None:
            both(data.f_est_hz, data.H_raw[k], color=color, lw=0.7, alpha=0.35,
                 label=f"{name} estimate")
            styles["estimate"] = dict(color="0.45", lw=0.7, alpha=0.5)
        if data.H_cond is not None:
            if data.replaced is not None and data.replaced[k].any():
                band = np.where(data.replaced[k], data.H_cond[k], np.nan)
                both(data.f_est_hz, band, color="0.5", lw=6.0, alpha=0.3,
                     solid_capstyle="butt", label=f"{name} replaced")
                styles["replaced by residual fit"] = dict(color="0.5", lw=6.0, alpha=0.3)
            both(data.f_est_hz, data.H_cond[k], color=color, lw=1.1,
                 label=f"{name} conditioned")
            styles["conditioned"] = dict(color="0.3", lw=1.1)
        if data.H_model is not None:
            both(data.f_model_hz, data.H_model[k], color=color, lw=1.8, label=f"{name} fit")
            styles["fit"] = dict(color="0.1", lw=1.8)
        if data.H_truth is not None:
            both(data.f_truth_hz, data.H_truth[k], color="k", lw=1.0, ls="--",
                 label=f"{name} ideal")
            styles["ideal"] = dict(color="k", lw=1.0, ls="--")

    if data.multiple_coherence is not None:
        ax_c.plot(data.f_est_hz, data.multiple_coherence, color="0.4", lw=0.8, ls=":",
                  label="multiple coherence", in_layout=False)
    else:
        ax_c.text(0.5, 0.5, "no FRF estimate: no coherence", transform=ax_c.transAxes,
                  ha="center", va="center", color="0.4")

    ax_c.set_title(data.output, y=1.0)  # a fixed y: no search for decorations above the axes
    ax_m.set_ylabel(data.magnitude_label)
    finite = np.concatenate([m[np.isfinite(m)] for m in mags]) if mags else np.empty(0)
    if finite.size:
        top, bottom = finite.max(), finite.min()
        pad = 0.05 * max(top - bottom, 1.0)
        ax_m.set_ylim(max(bottom, top - MAG_RANGE_DB) - pad, top + pad)
    else:
        ax_m.set_ylim(0.0, 1.0)  # nothing to show (every pair is exactly zero)

    mixed = len(set(data.unit_labels)) > 1
    input_handles = [Line2D([], [], color=c, lw=1.8,
                            label=f"{n} [{u}]" if mixed else n)
                     for n, c, u in zip(data.inputs, colors, data.unit_labels)]
    if data.multiple_coherence is not None:
        input_handles.append(Line2D([], [], color="0.4", lw=0.8, ls=":", label="multiple"))
    ax_c.legend(handles=input_handles, loc="lower left", fontsize=7, ncol=2 if mixed else 1,
                framealpha=0.8)
    if styles:
        ax_m.legend(handles=[Line2D([], [], label=k, **kw) for k, kw in styles.items()],
                    loc="best", fontsize=7, framealpha=0.8)


def _draw(data, fig):
    """Draw the page of `data` into an empty figure; return the figure."""
    _fill(data, _frame(fig, data.f_range_hz))
    return fig


def plot_frf(model_or_frf, output, *, inputs=None, truth=None, units="SI",
             f_range_hz=(0.5, 20.0), fig=None):
    """Plot coherence, magnitude and phase of one output for a group of inputs.

    Parameters
    ----------
    model_or_frf, output, inputs, truth, units, f_range_hz
        As :func:`frf_plot_data`.
    fig : matplotlib.figure.Figure, optional
        Figure to draw into (it is cleared first). Default: a new
        ``Figure(figsize=FIG_SIZE_IN)``, not registered with pyplot. The axes
        get fixed margins unless `fig` has a layout engine.

    Returns
    -------
    matplotlib.figure.Figure
        Three axes sharing a log frequency axis [Hz]: partial coherence (top,
        titled with the output name), magnitude [dB re 1 display unit], phase
        [deg]. Lines are labelled ``"<input> estimate"``, ``"<input>
        conditioned"``, ``"<input> replaced"``, ``"<input> fit"``, ``"<input>
        ideal"`` and ``"<input> coherence"``.

    Raises
    ------
    TypeError
        If `fig` is not a matplotlib Figure (and see :func:`frf_plot_data`).
    ValueError
        See :func:`frf_plot_data`.
    """
    from matplotlib.figure import Figure

    data = frf_plot_data(model_or_frf, output, inputs=inputs, truth=truth, units=units,
                         f_range_hz=f_range_hz)
    if fig is None:
        fig = Figure(figsize=FIG_SIZE_IN)
    elif not isinstance(fig, Figure):
        raise TypeError(f"fig must be a matplotlib.figure.Figure, got {type(fig).__name__}")
    else:
        fig.clear()
    return _draw(data, fig)


def _check_target(path):
    """Refuse to replace anything at `path` but a PNG file (a plot of an earlier run)."""
    if not path.exists():
        return
    if not path.is_file():
        raise FileExistsError(f"{path}: exists and is not a file; move it away or choose "
                              "another output folder")
    with open(path, "rb") as fh:
        head = fh.read(len(_PNG_MAGIC))
    if head != _PNG_MAGIC:
        raise FileExistsError(f"{path}: exists and is not a PNG image, so it is not an earlier "
                              "plot; move it away or choose another output folder")


def write_frf_plots(model_or_frf, out_dir, *, outputs=None, truth=None, units="SI", dpi=110):
    """Write one FRF plot (PNG) per output channel and input group.

    Parameters
    ----------
    model_or_frf : ident.identify.model.VehicleModel or ident.identify.frf.Frf
    out_dir : str or path
        Folder for the PNGs (created if missing).
    outputs : sequence of str, optional
        Output channels; default all.
    truth, units
        As :func:`frf_plot_data`.
    dpi : int
        Resolution of the PNGs.

    Returns
    -------
    list of pathlib.Path
        ``out_dir/frf_<output>_<group>.png`` for every output and every group
        with inputs present: ``rig`` (the 7 rig inputs) and ``shock`` (the 4
        ``dF_XX``); ``all`` when neither group is present. Output-major order.

    Raises
    ------
    FileExistsError
        If a target path holds something other than a PNG file (earlier plots
        are replaced; nothing is written then).
    ValueError, TypeError
        As :func:`frf_plot_data`; on an unknown output or a bad `dpi`.

    Notes
    -----
    Every file is written atomically (a temporary file in the folder, then
    ``os.replace``), so a reader never sees a half-written PNG.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    model, frf = _split(model_or_frf)
    units = check_units(units)
    src = model if model is not None else frf
    out_names, in_names = tuple(src.output_names), tuple(src.input_names)
    if outputs is None:
        outputs = out_names
    elif isinstance(outputs, str):
        outputs = (outputs,)
    outputs = tuple(outputs)
    missing = [o for o in outputs if o not in out_names]
    if missing:
        raise ValueError(f"output(s) {missing} not in this model/FRF; it has {list(out_names)}")
    if isinstance(dpi, bool) or not isinstance(dpi, (int, float, np.integer, np.floating)) \
            or not dpi > 0:
        raise ValueError(f"dpi must be a positive number, got {dpi!r}")
    groups = [g for g, names in INPUT_GROUPS.items() if any(n in in_names for n in names)]
    if not groups:
        groups = ["all"]
    out_dir = Path(out_dir)
    jobs = [(o, g, out_dir / f"frf_{o}_{g}.png") for o in outputs for g in groups]
    for _, _, path in jobs:
        _check_target(path)
    curves = _evaluate(model, frf, truth, _check_range(F_RANGE_HZ))  # once for all pages
    # one figure for all pages: its axes, ticks and grids are made once, and its Agg canvas
    # keeps one renderer with its caches of text sizes and math text (docs/DESIGN.md)
    fig = Figure(figsize=FIG_SIZE_IN)
    FigureCanvasAgg(fig)
    axes = _frame(fig, curves.f_range_hz)
    written = []
    for o, g, path in jobs:
        _clear(axes)
        _fill(_select(curves, o, _resolve_inputs(g, in_names), units), axes)
        with atomic_path(path, overwrite=True) as tmp:
            fig.savefig(tmp, format="png", dpi=dpi, metadata=png_metadata(fig))
        written.append(path)
        log.debug("wrote %s", path)
    log.info("wrote %d FRF plots to %s", len(written), out_dir)
    return written
