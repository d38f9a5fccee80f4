"""Multi-input frequency-response estimation from rig runs (seed paper, Eqs. 11-28).

The inputs of the identified model are the session's rig inputs (the 7 of
:data:`ident.data.channels.RIG_INPUTS`, or the 4 wheelloaders of a 4-post rig) and
the 4 shock-force deviations ``dF_i = F_i - c_bar_i v_i`` (Eq. 19), where ``c_bar`` is a baseline
linear damping per corner. Runs with different shocks make ``dF`` linearly
independent of the rig inputs (Eqs. 21-24), so the closed-loop responses
around ``c_bar`` (``H~rig`` and ``H~shocks`` of Eq. 20) can be estimated for
every measured output channel.

Notes
-----
Spectra come from Welch blocks (``scipy.signal.stft`` with the given
``window``, ``nperseg``, ``noverlap``; each block's mean removed). The
convention is scipy's: ``S_xy = sum over blocks of conj(X) * Y``, so that for
``Y = H U`` the normal equations (Eq. 15) read ``S_uu H^T = S_uy`` with
``S_uu[i, j] = sum conj(U_i) U_j`` (the H1 estimator). Inputs are scaled to
unit RMS before the solve, so the condition number reported is that of the
scaled input spectral matrix.

Partial coherence of input ``i`` at output ``o`` compares the part of the
output explained by the *conditioned* input (input ``i`` with the linear
effect of the other inputs removed, autospectrum ``1 / [S_uu^-1]_ii``) with
the residual: a weak path under strong inputs gets a low partial coherence
even where the multiple coherence of the output is near 1.

Local polynomial method (``estimator="lpm"``; Pintelon & Schoukens, *System
Identification*, 2nd ed., Ch. 7). Welch blocks cut the record, so each block
also holds the response to inputs before it (transient leakage): a random
error that falls only with the total record length, not with the averaging.
The LPM instead takes each run's full-record DFT (no window, means removed)
and, around every target frequency ``f0``, fits in a window of ``2R + 1``
consecutive DFT lines of every run, jointly over the runs::

    Y_r(k) = sum_i P_i(x_k) U_r,i(k) + T_r(x_k) + E_r(k),   x_k = (f_k - f0) / (R df)

with ``P_i`` (the FRF, shared by all runs) and ``T_r`` (the transient of run
``r``: leakage is a smooth function of frequency) polynomials of degree ``D``;
``H_i(f0) = P_i(0)``. Target frequencies need not be DFT lines (``P_i`` is
evaluated at the offset of ``f0``), so runs of any length can be combined,
each on its own DFT grid. The transient terms are eliminated per run by
projecting every window onto the complement of the degree-``D`` polynomials
(exact by Frisch-Waugh-Lovell); the remaining least-squares problem for all
outputs at once (one regressor) is solved by SVD with columns scaled to unit
norm. With ``nu = rows - unknowns`` residual degrees of freedom, ``SSE_o``
the residual power of output ``o`` and ``C = (A^H A)^-1`` for the local
regressor ``A`` (transients removed), the estimate's variance is
``var(H_oi) = SSE_o / nu * C_ii``. The other results are defined on the local
problem:

- partial coherence ``gamma2 = |H|^2 / (|H|^2 + nu_c var(H))``, the H1
  coherence an estimate with ``nu_c`` degrees of freedom would have for the
  same random error (H1: ``var(H) = (1 - gamma2) |H|^2 / (gamma2 n_d)``).
  ``nu_c = lpm_coherence_dof``, default :data:`LPM_COHERENCE_DOF` = 40 (the
  paper's 40 Welch blocks per run), so that a coherence threshold keeps the
  meaning it has in the paper whatever the window: 0.9 is a relative standard
  error ``sqrt(var) / |H|`` of 5.3 % (0.45 dB, 3 degrees), 0.5 of 16 %. A
  poorly determined estimate (a weak path under strong ones, an input with
  little independent energy, a bias of the local polynomials near a sharp
  resonance, which ends up in the residual) gets a low value;
- ``n_averages = nu_c + n_in``, so that the H1 random-error formula
  ``sqrt((1 - gamma2) / (2 (n_averages - n_in) gamma2))`` (as used by
  :mod:`planner.uncertainty`) is exactly the LPM's relative standard error of
  ``|H|``; the true residual degrees of freedom are ``settings["lpm_dof"]``;
- multiple coherence ``1 - SSE_o / sum |Y_o|^2`` over the window's lines;
- independent fraction ``1 / (||a_i||^2 C_ii)`` for the input's degree-0
  column ``a_i``: the fraction of the input's local power (transients
  removed) that no other regressor of the local problem explains (the Welch
  ``1 / [Sn^-1]_ii`` on the local regressor; about 0.3 for the paper session,
  whose rig inputs are the same drive in every run);
- input condition: that of the column-scaled normal matrix ``A^H A``.

Errors in variables. A measured ``dF_i = F_i - c_bar_i v_i`` carries the
noise ``N_i = n_F - c_bar_i n_v`` of the force and velocity sensors, and the
velocity output of the same corner carries ``n_v`` too, so least squares
estimates ``H~shocks`` biased: toward zero by ``S_N / S_dF`` and, for the
corner's own velocity, by the cross-power ``E[conj(N) n_v] = -c_bar S_nv``.
On the paper's plan the bias is second order in the noise level: with 2 %
sensor noise it is below the random error; with 5 % the velocity channels'
noise alone gives metric errors of 0.16 % median and 1.3 % max. A
bias-compensated solve with the noise spectra measured at the linear
``c_bar`` corners (where ``F - c_bar v`` is pure noise) was tried and left out:
on one realization it moved the worst error from 1.5 % to 0.8-2.9 % depending
on where it stopped compensating, with the median unchanged (docs/DESIGN.md).
``instruments=True`` removes the bias instead with instrumental variables: the same
inputs computed again from the shock travels (:mod:`ident.identify.instruments`), on by
default for sessions with third elements (:func:`ident.identify.pipeline.identify_session`).
"""

from __future__ import annotations

import concurrent.futures
import logging
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import signal

from ident.data.channels import (CORNERS, RESPONSE_CHANNELS, RIG_INPUTS, SHOCK_FORCES, SHOCK_VELOCITIES,
                            rig_inputs_of)
from ident.errors import IdentificationError, LowCoherenceWarning
from ident.identify.diagnose import rest_levels
from ident.identify.instruments import (iv_lpm_solve, travel_from_velocity, travel_rows,
                                        travel_run)
from ident.identify.serialdot import serial_dots
from ident.identify.thirdforce import third_element_force
from ident.models.lti import lag_coefficients
from ident.models.shocks import LinearShock

__all__ = [
    "Frf",
    "DF_INPUTS",
    "MODEL_INPUTS",
    "model_inputs",
    "embed_inputs",
    "block_spectra",
    "estimate_frf",
    "frf_from_arrays",
    "shock_force_deviation",
    "bump_stop_force",
    "third_force_deviation",
    "third_linear_damping",
    "baseline_damping",
    "default_nperseg",
    "ESTIMATORS",
    "LPM_DEGREE",
    "LPM_COHERENCE_DOF",
]

log = logging.getLogger(__name__)

#: Names of the shock-force-deviation inputs.
DF_INPUTS = tuple(f"dF_{c}" for c in CORNERS)
#: The 11 inputs of an identified model of a rig with aero actuators, in order (a 4-post
#: model has 8: :func:`model_inputs`).
MODEL_INPUTS = RIG_INPUTS + DF_INPUTS


def model_inputs(session):
    """The inputs of a model identified from a session: its rig inputs, then ``dF_XX``.

    The rig inputs are those of the session's runs (the spec: every run has
    the same set): the 7 of :data:`ident.data.channels.RIG_INPUTS` on a 7/8-post
    rig, the 4 wheelloaders on a 4-post rig (8 inputs in all).
    """
    return rig_inputs_of(session.runs[0].channels) + DF_INPUTS


def embed_inputs(X, input_names, *, axis=1, fill=0.0):
    """Place per-input data of some model inputs into the 11 :data:`MODEL_INPUTS` columns.

    A 4-post model's FRF has the inputs ``wheelloader_XX`` and ``dF_XX``; the
    loop and the screening work on the canonical 11 columns, where the absent
    aero inputs get `fill` (a zero response: the model says nothing about
    them, and a drive that excites them is refused,
    :func:`ident.data.drive.check_drive_inputs`).

    Parameters
    ----------
    X : ndarray
        Per-input data along `axis`, in the order of `input_names`.
    input_names : sequence of str
        Names of `X`'s columns, a subset of :data:`MODEL_INPUTS`.
    axis : int
    fill : scalar
        Value of the absent inputs' columns.

    Returns
    -------
    ndarray
        `X` itself if it already has the 11 inputs, else a new array with 11
        entries along `axis`.

    Examples
    --------
    >>> H = np.ones((2, 8, 3))
    >>> names = ("wheelloader_LF", "wheelloader_RF", "wheelloader_LR", "wheelloader_RR") + DF_INPUTS
    >>> embed_inputs(H, names)[0, :, 0]
    array([0., 0., 0., 1., 1., 1., 1., 1., 1., 1., 1.])
    """
    names = tuple(input_names)
    if names == MODEL_INPUTS:
        return X
    unknown = [n for n in names if n not in MODEL_INPUTS]
    if unknown:
        raise ValueError(f"embed_inputs: unknown inputs {unknown}; model inputs are "
                         f"{list(MODEL_INPUTS)}")
    X = np.asarray(X)
    shape = list(X.shape)
    shape[axis] = len(MODEL_INPUTS)
    out = np.full(shape, fill, dtype=X.dtype)
    idx = [MODEL_INPUTS.index(n) for n in names]
    np.moveaxis(out, axis, 0)[idx] = np.moveaxis(X, axis, 0)
    return out

#: A corner whose dF keeps less than this fraction of its energy once the rig
#: inputs are accounted for (median over 0.5-20 Hz) is not identifiable (Eq. 17).
MIN_INDEPENDENT_FRACTION = 1e-2
#: Frequencies where the independent fraction of a dF is below this are flagged.
FLAG_INDEPENDENT_FRACTION = 1e-3

#: The FRF estimators of :func:`estimate_frf` and :func:`frf_from_arrays`.
ESTIMATORS = ("welch", "lpm")
#: Default degree of the local polynomials (FRF and transient) of the LPM.
LPM_DEGREE = 2
#: The default LPM window has at least this many rows (lines x runs) per unknown.
LPM_ROWS_PER_UNKNOWN = 2
#: An input's records in several runs count as one realization unless an eigen-direction of
#: their Gram matrix holds at least this fraction of the largest one's energy
#: (:func:`_distinct_realizations`).
LPM_DISTINCT_FRACTION = 0.1
#: Default ``lpm_coherence_dof``: the LPM reports its standard error as the
#: partial coherence an H1 estimate with this many degrees of freedom (the
#: seed paper's 40 Welch blocks per run) would have for the same random error,
#: so :func:`ident.identify.condition.condition_frf`'s threshold 0.9 keeps the meaning it
#: has in the paper: a relative standard error of ``sqrt(0.1 / 0.9 / 40)`` = 5.3 %.
LPM_COHERENCE_DOF = 40
#: Singular values of the column-scaled local LPM regressor below this fraction
#: of the largest count as zero (that direction is undetermined: coherence ~0).
LPM_RCOND = 1e-10
#: The LPM's default grid is at least this fine [Hz] (the paper session's is 0.024 Hz).
LPM_GRID_HZ = 0.1
#: Target frequencies per batched LPM solve (memory ~ chunk x rows x columns).
_LPM_CHUNK = 256
#: Threads of the LPM solve and the runs' DFTs (None: one per free core, at most 4, each
#: holding one chunk's arrays, some 30 MB on the paper session; see _lpm_threads); the
#: result does not depend on it.
_LPM_THREADS = None
_LPM_MAX_THREADS = 4


@dataclass(frozen=True, eq=False)
class Frf:
    """An estimated multi-input frequency response.

    Attributes
    ----------
    f_hz : ndarray, shape (n_f,)
        Frequencies [Hz].
    H : ndarray of complex, shape (n_out, n_in, n_f)
        Frequency response ``H[output, input, frequency]`` in SI units of
        output per input.
    input_names, output_names : tuple of str
    multiple_coherence : ndarray, shape (n_out, n_f)
        Fraction of each output's power explained by all inputs together.
    partial_coherence : ndarray, shape (n_out, n_in, n_f)
        Per input/output pair (see the module notes); for the sequential
        method's shock inputs, the ordinary coherence of ``dY`` with ``dF``;
        for the LPM, the estimate's standard error as a coherence.
    input_condition : ndarray, shape (n_f,)
        Condition number of the scaled input spectral matrix (LPM: of the
        local problem's scaled normal matrix).
    independent_fraction : ndarray, shape (n_in, n_f)
        Fraction of each input's power not linearly explained by the other
        inputs (1 for independent inputs, 0 for a dependent one; LPM: by the
        other regressors of the local problem).
    flagged : ndarray of bool, shape (n_in, n_f)
        Frequencies where an input has (almost) no independent energy: the
        estimate of that input's column is unreliable there.
    n_averages : int
        Number of Welch blocks used (all runs); for the LPM the equivalent
        number ``lpm_coherence_dof + n_in`` (module notes).
    cbar_n_s_m : ndarray, shape (4,)
        Baseline damping the shock inputs are written around [N/(m/s)].
    fs_hz : float
    settings : dict
        ``estimator``, ``method``, ``window``, ``nperseg``, ``noverlap``,
        ``runs``, ... (LPM: ``lpm_degree``, ``lpm_half_width``, ``lpm_dof``, ...)
    H_raw : ndarray or None
        The estimate before conditioning (set by :func:`ident.identify.condition.condition_frf`).
    replaced : ndarray of bool or None
        Frequencies replaced by residual fits in conditioning, (n_out, n_in, n_f).
    sigma : ndarray or None
        Standard error of each line of ``H`` (complex, ``E|H - H_true|^2 =
        sigma^2``), (n_out, n_in, n_f); set by conditioning
        (:func:`ident.identify.condition.conditioned_standard_error`).
    cv_deviation : ndarray or None
        The session's cross-validation (:mod:`ident.identify.crossval`): each time
        block's relative deviation from the blocks' mean, scaled to the full estimate's
        error, complex64 (n_blocks, n_out, n_in, n_grid) on the frequencies
        ``settings["cross_validation"]["f_hz"]``; set by identification.
    noise_bias : ndarray or None
        The estimate's bias from the noise on its shock-force inputs, measured on the
        session (:func:`ident.identify.crossval.noise_bias`): relative, complex64
        (n_out, n_in, n_grid) on the cross-validation's frequencies; set by
        identification where the session measures shock forces.
    """

    f_hz: np.ndarray
    H: np.ndarray
    input_names: tuple
    output_names: tuple
    multiple_coherence: np.ndarray
    partial_coherence: np.ndarray
    input_condition: np.ndarray
    independent_fraction: np.ndarray
    flagged: np.ndarray
    n_averages: int
    cbar_n_s_m: np.ndarray
    fs_hz: float
    settings: dict = field(default_factory=dict)
    H_raw: np.ndarray | None = None
    replaced: np.ndarray | None = None
    sigma: np.ndarray | None = None
    cv_deviation: np.ndarray | None = None
    noise_bias: np.ndarray | None = None

    def index(self, output, input):
        """Return ``(output index, input index)`` of a pair, with a clear error."""
        try:
            o = self.output_names.index(output)
        except ValueError:
            raise ValueError(f"output {output!r} not in this FRF; it has {list(self.output_names)}") from None
        try:
            i = self.input_names.index(input)
        except ValueError:
            raise ValueError(f"input {input!r} not in this FRF; it has {list(self.input_names)}") from None
        return o, i

    def pair(self, output, input):
        """Frequency response and partial coherence of one pair, shapes (n_f,)."""
        o, i = self.index(output, input)
        return self.H[o, i], self.partial_coherence[o, i]


def default_nperseg(n_samples):
    """Default block length: the power of two nearest ``n_samples / 20``.

    40 blocks with 50 % overlap, as the paper's 800 s runs: 4096 samples
    (40.96 s, 0.024 Hz resolution) at 100 Hz.
    """
    return int(2 ** np.round(np.log2(max(n_samples / 20, 16))))


#: Shortest spectral block [samples] (and so the shortest run) an FRF is estimated from.
MIN_NPERSEG = 16


def _check_spectral_args(fs, window, nperseg, noverlap, n_min):
    if not fs > 0:
        raise ValueError(f"fs must be positive, got {fs!r}")
    if isinstance(nperseg, bool) or not isinstance(nperseg, (int, np.integer)) or nperseg < 16:
        raise ValueError(f"nperseg must be an integer >= 16, got {nperseg!r}")
    if noverlap is None:
        noverlap = nperseg // 2
    if not 0 <= noverlap < nperseg:
        raise ValueError(f"noverlap must be in [0, nperseg), got {noverlap!r} with nperseg={nperseg}")
    if n_min < nperseg:
        raise ValueError(f"a run has {n_min} samples, fewer than nperseg={nperseg}; use shorter "
                         "blocks (nperseg) or longer runs")
    signal.get_window(window, nperseg)  # raises on an unknown window
    return int(nperseg), int(noverlap)


def block_spectra(x, *, fs, window="hamming", nperseg, noverlap=None):
    """Fourier transforms of the Welch blocks of several channels.

    The one spectral engine of the package: every estimate is built on it.

    Parameters
    ----------
    x : ndarray, shape (n_channels, n_samples)
    fs : float
        Sample rate [Hz].
    window : str or tuple
        A ``scipy.signal.get_window`` window.
    nperseg : int
        Block length [samples].
    noverlap : int, optional
        Overlap [samples]; default half a block.

    Returns
    -------
    f_hz : ndarray, shape (n_f,)
    X : ndarray of complex, shape (n_channels, n_f, n_blocks)
        Each block's mean is removed before windowing.
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    nperseg, noverlap = _check_spectral_args(fs, window, nperseg, noverlap, x.shape[-1])
    f, _, X = signal.stft(x, fs=fs, window=window, nperseg=nperseg, noverlap=noverlap,
                          boundary=None, padded=False, detrend="constant", return_onesided=True)
    return f, X


def _solve_h1(Suu, Suy, Syy):
    """H1 solve with coherences. Suu (f, m, m), Suy (f, m, p), Syy (f, p)."""
    d = np.sqrt(np.real(np.einsum("fii->fi", Suu)))
    d = np.where(d > 0, d, 1.0)
    Sn = Suu / (d[:, :, None] * d[:, None, :])
    cond = np.linalg.cond(Sn)
    Ht = np.linalg.solve(Sn, Suy / d[:, :, None]) / d[:, :, None]  # (f, m, p)
    explained = np.real(np.einsum("fmp,fmp->fp", np.conj(Suy), Ht))
    with np.errstate(invalid="ignore", divide="ignore"):
        mult = np.clip(np.where(Syy > 0, explained / Syy, 0.0), 0.0, 1.0)
        See = np.maximum(Syy - explained, 0.0)
        inv_diag = np.real(np.einsum("fii->fi", np.linalg.inv(Sn))) / d**2  # [Suu^-1]_ii
        cond_auto = np.where(inv_diag > 0, 1.0 / inv_diag, 0.0)  # conditioned input autospectrum
        indep = np.clip(np.where(d**2 > 0, cond_auto / d**2, 0.0), 0.0, 1.0)
        part_num = np.abs(Ht) ** 2 * cond_auto[:, :, None]
        partial = np.where(part_num + See[:, None, :] > 0,
                           part_num / (part_num + See[:, None, :]), 0.0)
    return Ht, mult, partial, cond, indep


# ----------------------------------------------------------------------------------------------
# local polynomial method
# ----------------------------------------------------------------------------------------------

def _distinct_realizations(records):
    """Number of realizations among runs' records of one input that carry their own information.

    Records of the same length are compared by the eigenvalues ``lambda`` of
    their Gram matrix (records scaled to unit norm): an eigen-direction whose
    ``lambda`` is below :data:`LPM_DISTINCT_FRACTION` of the largest is not a
    realization of its own. Copies of one drive count once whether they are
    exact, scaled, or differ by measurement noise (0.5 % input noise leaves
    ``lambda_2 / lambda_1`` at about 1e-5): the noise is all that tells them
    apart, and a local regression that leans on it amplifies the noise by
    ``1 / (noise fraction)`` (the failure of a noisy session of the paper's
    plan, whose runs all play one drive, with the half-width of 5 distinct
    runs: 5 % median metric error). Records of different lengths are distinct.

    Parameters
    ----------
    records : list of ndarray, shape (n_samples_r,)

    Returns
    -------
    int
    """
    groups = {}
    for x in records:
        groups.setdefault(x.shape[0], []).append(x)
    count = 0
    for xs in groups.values():
        if len(xs) == 1:
            count += 1
            continue
        # the norms of records of 10^4-10^5 samples on one BLAS thread with the multithreaded
        # sums' bits (serial_dots): OpenBLAS's thread hand-over costs more than the sums
        with serial_dots() as dot:
            norms = [np.sqrt(dot(x, x)) for x in xs]
        X = np.array([x / max(nx, 1e-300) for x, nx in zip(xs, norms)])
        lam = np.linalg.eigvalsh(X @ X.T)
        count += int(np.sum(lam > LPM_DISTINCT_FRACTION * lam[-1]))
    return count


def _lpm_default_half_width(inputs, degree):
    """Default LPM half-width ``R`` [lines] from the runs' input records.

    The smallest ``R`` (at least ``degree + 1``) whose local problems have at
    least :data:`LPM_ROWS_PER_UNKNOWN` rows per unknown:

    - all runs together: ``n_runs (2R + 1) >= 2 (n_in + n_runs)(D + 1)``
      (an FRF polynomial per input, a transient polynomial per run);
    - inputs repeated in several runs (the same rig drive in every run, as in
      the paper's plan, exact or up to scale and measurement noise:
      :func:`_distinct_realizations`) add no information with the repeats,
      so for them alone, with ``g`` distinct realizations:
      ``g (2R + 1) >= 2 (n_repeated + g)(D + 1)``.

    Paper session (5 runs of one drive, 11 inputs, D = 2): the first rule
    gives R = 10, the second (7 rig inputs, g = 1) R = 24.

    Parameters
    ----------
    inputs : list of ndarray, shape (n_in, n_samples_r)
        Each run's input records (time domain).
    degree : int
    """
    n_runs, m, nd = len(inputs), inputs[0].shape[0], degree + 1
    needs = [(LPM_ROWS_PER_UNKNOWN * (m + n_runs) * nd, n_runs)]
    n_rep, g_rep = 0, n_runs
    for i in range(m):
        records = [x[i] - np.mean(x[i]) for x in inputs]
        power = np.array([np.mean(r ** 2) for r in records])
        live = [r for r, pw in zip(records, power) if pw > 1e-10 * power.max()]
        distinct = _distinct_realizations(live) if live else 0
        if distinct < len(live):
            n_rep += 1
            g_rep = min(g_rep, distinct)
    if n_rep:
        needs.append((LPM_ROWS_PER_UNKNOWN * (n_rep + g_rep) * nd, g_rep))
    lines = max(int(np.ceil(rows / runs)) for rows, runs in needs)
    return max(int(np.ceil((lines - 1) / 2)), nd)


def _check_lpm_args(degree, half_width, coherence_dof, inputs, names):
    """Check the LPM options once; return (degree, half_width, coherence_dof).

    ``inputs``: each run's input records, shape (n_in, n_samples_r).
    """
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)) or not 0 <= degree <= 6:
        raise ValueError(f"lpm_degree must be an integer in 0..6, got {degree!r}")
    degree = int(degree)
    if half_width is None:
        half_width = _lpm_default_half_width(inputs, degree)
    elif isinstance(half_width, bool) or not isinstance(half_width, (int, np.integer)) or half_width < 1:
        raise ValueError(f"lpm_half_width must be a positive integer (DFT lines), got {half_width!r}")
    half_width = int(half_width)
    if (isinstance(coherence_dof, bool) or not isinstance(coherence_dof, (int, np.integer))
            or coherence_dof < 1):
        raise ValueError(f"lpm_coherence_dof must be a positive integer, got {coherence_dof!r}")
    n_runs, n_in = len(inputs), inputs[0].shape[0]
    lines, nd = 2 * half_width + 1, degree + 1
    dof = n_runs * (lines - nd) - n_in * nd
    if dof < 1:
        raise ValueError(
            f"lpm_half_width={half_width} with lpm_degree={degree} leaves no residual degrees of "
            f"freedom ({n_runs} run(s) x {lines} lines for {(n_in + n_runs) * nd} unknowns); use a "
            f"wider window (default: {_lpm_default_half_width(inputs, degree)}) or a lower degree")
    for x, name in zip(inputs, names):
        n = x.shape[-1]
        if n // 2 < lines:
            raise ValueError(
                f"run '{name}' has {n} samples: {n // 2} DFT lines, fewer than the LPM window of "
                f"{lines} lines (lpm_half_width={half_width}); use longer runs or a smaller "
                "lpm_half_width")
    return degree, half_width, int(coherence_dof)


def _lpm_threads(n_tasks):
    """Threads for `n_tasks` independent parts of the LPM (:data:`_LPM_THREADS`).

    By default one per core that is free: the cores less the 1-minute load average, this
    process's own core counted free (threads cost about 20 % more CPU time than one
    thread, allocating a chunk's arrays each: worth it only on idle cores; on a loaded
    machine, or in the demo while a worker compiles, one thread). The numbers do not
    depend on it.
    """
    if _LPM_THREADS:
        n = _LPM_THREADS
    else:
        cores = os.cpu_count() or 1
        try:
            load = os.getloadavg()[0]
        except (AttributeError, OSError):  # not POSIX: no load figure
            load = 0.0
        n = min(cores, _LPM_MAX_THREADS, int(cores - load + 1.0))
    return max(1, min(n, n_tasks))


def _lpm_solve(spectra, n_samples, n_in, f_hz, fs, degree, half_width, coherence_dof):
    """Local polynomial method over several runs (see the module notes).

    Parameters
    ----------
    spectra : list of ndarray of complex, shape (n_in + n_out, n_samples_r // 2 + 1)
        Full-record DFTs (``numpy.fft.rfft``, no window) of each run, inputs first.
    n_samples : list of int
        Record length of each run.
    n_in : int
    f_hz : ndarray, shape (n_f,)
        Target frequencies [Hz].
    fs : float
    degree, half_width : int
        ``D`` and ``R``.
    coherence_dof : float
        ``nu_c`` of the partial coherence ``|H|^2 / (|H|^2 + nu_c var(H))``.

    Returns
    -------
    H : ndarray of complex, shape (n_out, n_in, n_f)
    mult : ndarray, shape (n_out, n_f)
    partial : ndarray, shape (n_out, n_in, n_f)
    cond : ndarray, shape (n_f,)
        Condition number of the column-scaled normal matrix ``A^H A``.
    indep : ndarray, shape (n_in, n_f)
    dof : int
        Residual degrees of freedom ``nu`` of each local problem.
    """
    from threadpoolctl import threadpool_limits

    n_runs = len(spectra)
    m, p = n_in, spectra[0].shape[0] - n_in
    lines, nd = 2 * half_width + 1, degree + 1
    ncol = m * nd  # columns ordered input-major: i * nd + d
    dof = n_runs * (lines - nd) - ncol
    # projector onto the complement of the polynomials of degree <= D over a window
    # of consecutive lines: removes any transient T_r, whatever the window's offset
    q, _ = np.linalg.qr(np.vander(np.arange(-half_width, half_width + 1) / half_width, nd,
                                  increasing=True))
    proj = np.eye(lines) - q @ q.T
    n_ref = max(n_samples)
    idx, xpow = [], []
    for n in n_samples:
        pos = np.asarray(f_hz, dtype=float) * n / fs  # target in this run's lines
        start = np.clip(np.rint(pos).astype(int) - half_width, 1, n // 2 - lines + 1)
        k = start[:, None] + np.arange(lines)  # DC (line 0) is never used: means removed
        x = (k - pos[:, None]) * (n_ref / n) / half_width  # common frequency variable
        idx.append(k)
        xpow.append(x[..., None] ** np.arange(nd))  # (n_f, lines, nd)
    n_f = f_hz.size
    H = np.empty((n_f, m, p), dtype=complex)
    partial = np.empty((n_f, m, p))
    mult = np.empty((n_f, p))
    cond = np.empty(n_f)
    indep = np.empty((n_f, m))
    col0 = np.arange(m) * nd

    def solve_chunk(a):  # target lines a .. a + _LPM_CHUNK: disjoint slices of the outputs
        sl = slice(a, min(a + _LPM_CHUNK, n_f))
        t = sl.stop - sl.start
        A = np.empty((t, n_runs, lines, m, nd), dtype=complex)
        B = np.empty((t, n_runs, lines, p), dtype=complex)
        for r, X in enumerate(spectra):
            W = np.moveaxis(X[:, idx[r][sl]], 0, -1)  # (t, lines, m + p)
            A[:, r] = W[..., :m, None] * xpow[r][sl][:, :, None, :]
            B[:, r] = W[..., m:]
        ypow = np.sum(np.abs(B) ** 2, axis=(1, 2))  # (t, p)
        A = (proj @ A.reshape(t, n_runs, lines, ncol)).reshape(t, n_runs * lines, ncol)
        B = (proj @ B).reshape(t, n_runs * lines, p)
        sc = np.sqrt(np.sum(np.abs(A) ** 2, axis=1))  # (t, ncol)
        sc = np.where(sc > 0, sc, 1.0)
        As = A / sc[:, None, :]
        U, sv, Vh = np.linalg.svd(As, full_matrices=False)
        keep = sv > LPM_RCOND * sv[:, :1]
        floor = LPM_RCOND * sv[:, :1]
        inv_s = np.where(keep, 1.0 / np.where(keep, sv, 1.0), 0.0)
        V = np.conj(np.swapaxes(Vh, 1, 2))
        th = V @ (inv_s[..., None] * (np.conj(np.swapaxes(U, 1, 2)) @ B))  # (t, ncol, p)
        sse = np.sum(np.abs(B - As @ th) ** 2, axis=1)  # (t, p)
        # diag of (As^H As)^-1; undetermined directions count with the floor (~infinite)
        inv_s2 = 1.0 / np.maximum(sv, np.maximum(floor, 1e-300)) ** 2
        cdiag = np.einsum("tkc,tk->tc", np.abs(Vh) ** 2, inv_s2)[:, col0]  # (t, m)
        h = th[:, col0, :] / sc[:, col0, None]  # (t, m, p)
        H[sl] = h
        # var(H) = SSE / dof * C_ii, C_ii = cdiag / sc_i^2 in unscaled units
        var = sse[:, None, :] / dof * (cdiag / sc[:, col0] ** 2)[:, :, None]
        num = np.abs(h) ** 2
        den = num + coherence_dof * var
        partial[sl] = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
        mult[sl] = np.clip(1.0 - sse / np.where(ypow > 0, ypow, 1.0), 0.0, 1.0) * (ypow > 0)
        indep[sl] = np.clip(1.0 / cdiag, 0.0, 1.0)
        smin = sv[:, -1]
        cond[sl] = np.where(smin > 0, (sv[:, 0] / np.where(smin > 0, smin, 1.0)) ** 2, np.inf)

    starts = range(0, n_f, _LPM_CHUNK)
    # the chunks are independent: numpy's batched SVDs and products release the GIL, so a
    # thread per free core solves them side by side (each chunk the same arithmetic: the same
    # numbers, bit for bit, whatever the number of threads)
    n_threads = _lpm_threads(len(starts))
    with threadpool_limits(1):  # many tiny LAPACK calls: threads only contend
        if n_threads == 1:
            for a in starts:
                solve_chunk(a)
        else:
            with concurrent.futures.ThreadPoolExecutor(n_threads) as pool:
                list(pool.map(solve_chunk, starts))
    return (np.transpose(H, (2, 1, 0)), mult.T, np.transpose(partial, (2, 1, 0)), cond,
            indep.T, dof)


def _as_runs(u, y):
    """``u``, ``y`` as lists of 2-D runs (one array = one run); checked."""
    multi = isinstance(u, (list, tuple)) and len(u) > 0 and np.ndim(u[0]) == 2
    us = [np.asarray(a, dtype=float) for a in (u if multi else [u])]
    ys = [np.asarray(a, dtype=float) for a in (y if multi else [y])]
    if len(us) != len(ys):
        raise ValueError(f"u and y must hold the same number of runs, got {len(us)} and {len(ys)}")
    for k, (a, b) in enumerate(zip(us, ys)):
        if a.ndim != 2 or b.ndim != 2 or a.shape[0] != b.shape[0]:
            where = f"run {k}: " if multi else ""
            raise ValueError(f"{where}u and y must be 2-D with the same number of rows (samples), "
                             f"got {a.shape} and {b.shape}")
        if a.shape[1] != us[0].shape[1] or b.shape[1] != ys[0].shape[1]:
            raise ValueError(f"run {k}: every run must have the same channels; got u {a.shape} "
                             f"and y {b.shape}, run 0 has u {us[0].shape} and y {ys[0].shape}")
    return us, ys


def _check_estimator(estimator):
    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {list(ESTIMATORS)}, got {estimator!r}")


def frf_from_arrays(u, y, *, fs, window="hamming", nperseg=None, noverlap=None,
                    input_names=None, output_names=None, estimator="welch",
                    lpm_degree=LPM_DEGREE, lpm_half_width=None,
                    lpm_coherence_dof=LPM_COHERENCE_DOF):
    """Multi-input, multi-output FRF estimate from one record or several runs.

    Parameters
    ----------
    u : ndarray, shape (n_samples, n_in), or list of such (one per run)
        Inputs (SI). Runs may differ in length.
    y : ndarray, shape (n_samples, n_out), or list of such (one per run)
        Outputs (SI).
    fs : float
        Sample rate [Hz].
    window, nperseg, noverlap
        Welch settings (:func:`block_spectra`); ``nperseg`` defaults to
        :func:`default_nperseg` of the shortest run. For ``estimator="lpm"``
        only ``nperseg`` is used: the estimate is on the same frequency grid
        ``k fs / nperseg``.
    estimator : {"welch", "lpm"}
        ``welch``: H1 from Welch blocks (every run's blocks summed).
        ``lpm``: local polynomial method on the full-record DFTs (module notes).
    lpm_degree : int
        Degree ``D`` of the local FRF and transient polynomials (LPM only).
    lpm_half_width : int, optional
        Half-width ``R`` of the local window [DFT lines of each run] (LPM only);
        default the smallest with ``rows >= 2 x unknowns``,
        ``n_runs (2R + 1) >= 2 (n_in + n_runs)(D + 1)``, and the same for the
        inputs repeated identically in several runs, counted once
        (:func:`_lpm_default_half_width`).
    lpm_coherence_dof : int
        ``nu_c`` of the LPM's partial coherence (module notes); default
        :data:`LPM_COHERENCE_DOF`.
    exact_linear : bool
        :func:`shock_force_deviation`: ``dF = 0`` exactly at corners whose
        shock is linear at ``c_bar`` without lag (default), instead of the
        measured (noisy) ``F - c_bar v``.

    Returns
    -------
    Frf
        With ``cbar_n_s_m`` zeros and ``settings["method"] = "h1"`` (Welch)
        or ``"lpm"``; on the grid ``k fs / nperseg``, ``k = 0 .. nperseg // 2``.

    Raises
    ------
    ValueError
        For arrays of the wrong shape, runs with different channels, or bad
        Welch or LPM settings.

    Examples
    --------
    A pure gain of 2 is recovered exactly:

    >>> rng = np.random.default_rng(0)
    >>> u = rng.standard_normal((4096, 1))
    >>> frf = frf_from_arrays(u, 2 * u, fs=100.0, nperseg=256)
    >>> bool(np.allclose(frf.H, 2.0))
    True
    >>> frf = frf_from_arrays(u, 2 * u, fs=100.0, nperseg=256, estimator="lpm")
    >>> bool(np.allclose(frf.H, 2.0)), frf.settings["lpm_half_width"]
    (True, 6)
    """
    _check_estimator(estimator)
    us, ys = _as_runs(u, y)
    n_min = min(a.shape[0] for a in us)
    nperseg = default_nperseg(n_min) if nperseg is None else nperseg
    n_in, n_out = us[0].shape[1], ys[0].shape[1]
    names = dict(input_names=tuple(input_names or (f"u{i}" for i in range(n_in))),
                 output_names=tuple(output_names or (f"y{o}" for o in range(n_out))))
    if estimator == "lpm":
        nperseg, _ = _check_spectral_args(fs, window, nperseg, noverlap, n_min)
        degree, half, nu_c = _check_lpm_args(lpm_degree, lpm_half_width, lpm_coherence_dof,
                                             [a.T for a in us], [f"{k}" for k in range(len(us))])
        f = np.fft.rfftfreq(nperseg, 1.0 / fs)
        spectra = [np.fft.rfft(np.vstack([a.T, b.T]), axis=-1) for a, b in zip(us, ys)]
        H, mult, partial, cond, indep, dof = _lpm_solve(
            spectra, [a.shape[0] for a in us], n_in, f, float(fs), degree, half, nu_c)
        return Frf(f_hz=f, H=H, **names, multiple_coherence=mult, partial_coherence=partial,
                   input_condition=cond, independent_fraction=indep,
                   flagged=indep < FLAG_INDEPENDENT_FRACTION, n_averages=nu_c + n_in,
                   cbar_n_s_m=np.zeros(4), fs_hz=float(fs),
                   settings=_lpm_settings(nperseg, fs, degree, half, dof, nu_c, us, n_in))
    Suu = Suy = Syy = 0
    n_avg = 0
    for a, b in zip(us, ys):
        f, X = block_spectra(np.vstack([a.T, b.T]), fs=fs, window=window, nperseg=nperseg,
                             noverlap=noverlap)
        U, Y = X[:n_in], X[n_in:]
        Suu = Suu + np.einsum("ifk,jfk->fij", np.conj(U), U)
        Suy = Suy + np.einsum("ifk,ofk->fio", np.conj(U), Y)
        Syy = Syy + np.real(np.einsum("ofk,ofk->fo", np.conj(Y), Y))
        n_avg += U.shape[-1]
    Ht, mult, partial, cond, indep = _solve_h1(Suu, Suy, Syy)
    return Frf(f_hz=f, H=np.transpose(Ht, (2, 1, 0)), **names,
               multiple_coherence=mult.T, partial_coherence=np.transpose(partial, (2, 1, 0)),
               input_condition=cond, independent_fraction=indep.T,
               flagged=indep.T < FLAG_INDEPENDENT_FRACTION, n_averages=n_avg,
               cbar_n_s_m=np.zeros(4), fs_hz=float(fs),
               settings={"method": "h1", "window": window, "nperseg": int(nperseg),
                         "noverlap": int(nperseg // 2 if noverlap is None else noverlap)})


def _lpm_settings(nperseg, fs, degree, half, dof, nu_c, runs, n_in):
    """The settings an LPM estimate carries (``runs``: arrays or lengths)."""
    n = [int(getattr(r, "shape", (r,))[0]) for r in runs]
    lines = 2 * half + 1
    return {"estimator": "lpm", "method": "lpm", "nperseg": int(nperseg),
            "grid_df_hz": float(fs) / int(nperseg), "lpm_degree": degree, "lpm_half_width": half,
            "lpm_lines": lines, "lpm_rows": len(n) * lines,
            "lpm_unknowns": (n_in + len(n)) * (degree + 1), "lpm_dof": int(dof),
            "lpm_coherence_dof": nu_c,
            "resolution_hz": [float(fs) / k for k in n]}


# ----------------------------------------------------------------------------------------------
# sessions
# ----------------------------------------------------------------------------------------------

def shock_force_deviation(run, shocks, cbar_n_s_m, *, exact_linear=True):
    """The shock forces and their deviations ``dF = F - c_bar v`` of one run.

    Parameters
    ----------
    run : ident.data.session.Run
        Must hold ``shock_velocity_XX``; ``shock_force_XX`` is used when present,
        otherwise the force is computed from the run's shock model (static curve
        and lag, first-order hold at the run's sample rate) and the measured
        velocity.
    shocks : ident.models.library.ShockLibrary
    cbar_n_s_m : array_like, shape (4,)
    exact_linear : bool
        A corner whose shock is, per the library, linear with ``c == c_bar``
        (relative 1e-9) and without lag has ``dF = 0`` exactly, whatever the
        measured force and velocity say. Measurement noise on those channels
        would otherwise enter the regression as noise on the ``dF`` inputs,
        which biases ``H~shocks`` toward zero (errors in variables): with 2 %
        noise on every channel, the baseline run and the unswapped corners of
        the swap runs would add 5 to 10 times the noise of the swapped corner
        alone. False uses the measurements everywhere (a linear shock known to
        depart from its nominal rate).

    Returns
    -------
    F, dF : ndarray, shape (4, n_samples)
        Dynamic parts (means removed) [N].
    """
    cbar = np.asarray(cbar_n_s_m, dtype=float)
    F = np.empty((4, run.n_samples))
    dF = np.empty_like(F)
    for i, c in enumerate(CORNERS):
        v = run.dynamic(f"shock_velocity_{c}")
        if exact_linear and _is_cbar_linear(shocks.get(run.setup[c], where=f"run '{run.name}' "
                                                        f"setup {c}"), cbar[i]):
            F[i], dF[i] = cbar[i] * v, 0.0
            continue
        if f"shock_force_{c}" in run.channels:
            F[i] = run.dynamic(f"shock_force_{c}")
        else:
            model = shocks.get(run.setup[c], where=f"run '{run.name}' setup {c}")
            fv = model.force(v)
            alpha, b0, b1 = (float(x) for x in lag_coefficients(model.lag_s, 1.0 / run.fs_hz))
            F[i] = signal.lfilter([b0, b1], [1.0, -alpha], fv) if model.lag_s > 0 else fv
            F[i] -= F[i].mean()
        dF[i] = F[i] - cbar[i] * v
    return F, dF


def bump_stop_force(run, library):
    """The declared bump stops' force of one run, from its measured shock travel.

    The stop of corner ``c`` pushes with ``G_c(s_c)`` (its table beyond the contact travel
    ``gap - packer``, :meth:`ident.models.bumpstops.BumpStop.force`), ``s_c`` the shock
    travel (compression positive) from the car at rest. The rest comes from the data
    (:func:`ident.identify.diagnose.rest_levels`: the drives are tapered, so the car is at
    rest at the start of a run; else at its end; else the run's mean).

    Parameters
    ----------
    run : ident.data.session.Run
        Needs ``shock_travel_XX`` at every corner with a stop.
    library : ident.models.bumpstops.BumpStopLibrary or None
        The session's bump stops.

    Returns
    -------
    force : ndarray, shape (4, n_samples), or None
        The stop forces [N] (0 at corners without a stop and out of contact; not
        mean-removed); None when the run has no stop (or no library).
    info : dict or None
        ``rest`` (``"rest (start)"``, ``"rest (end)"`` or ``"mean"``),
        ``rest_minus_mean_m`` (corner -> the travel's rest level less its mean [m]) and
        ``contact_share`` (corner -> share of samples beyond contact) of the corners
        with a stop; None with `force`.

    Raises
    ------
    IdentificationError
        If a corner with a stop has no ``shock_travel_XX`` channel.
    """
    if library is None or all(run.bump_stops.get(c) is None for c in CORNERS):
        return None, None
    levels, used = rest_levels(run)
    G = np.zeros((4, run.n_samples))
    info = {"rest": used, "rest_minus_mean_m": {}, "contact_share": {}}
    for i, c in enumerate(CORNERS):
        sid = run.bump_stops.get(c)
        if sid is None:
            continue
        name = f"shock_travel_{c}"
        if name not in run.channels:
            raise IdentificationError(
                f"run '{run.name}': corner {c} has bump stop {sid!r} but no {name} channel; "
                "the stop's force is computed from the measured shock travel: record "
                f"{name}, or remove the run's bump_stops {c}")
        stop = library.get(sid, where=f"run '{run.name}' bump_stops {c}")
        packer = float(run.packers_m.get(c, 0.0))
        x = run.channels[name]
        travel = x - levels[name]
        G[i] = stop.force(travel, packer)
        info["rest_minus_mean_m"][c] = levels[name] - float(np.mean(x))
        info["contact_share"][c] = float(np.mean(travel > stop.contact_travel_m(packer)))
    log.info("run %s: bump-stop force from the travel measured from %s (rest less mean: %s); "
             "contact %s", run.name, used,
             ", ".join(f"{c} {v * 1e3:+.2f} mm" for c, v in info["rest_minus_mean_m"].items()),
             ", ".join(f"{c} {v * 100:.1f} %" for c, v in info["contact_share"].items()))
    return G, info


def third_linear_damping(session):
    """The third elements' linear part at the baseline: the corners' damping matrix they add.

    ``sum_e c_e m_e m_e^T`` over the elements with a damper in the baseline runs (those of
    :func:`baseline_damping`), ``c_e`` the damper's equivalent linear damping at the
    element's velocity RMS there (``m_e @ v``; stochastic linearization, as ``c_bar``).
    :func:`estimate_frf` writes the corners' inputs around ``diag(c_bar)`` plus this matrix
    (the elements' force less their linear part is then small and independent of the rig
    inputs, as a corner shock's ``F - c_bar v``), and brings the estimate back to
    ``diag(c_bar)`` (:func:`_around_corner_damping`): the model is the car without the
    elements. On the prototype-like car of the tests the linear car's metric error falls
    from 3.0 % median to 1.1 % (the same plan without elements: 0.8 %).

    Parameters
    ----------
    session : ident.data.session.Session

    Returns
    -------
    ndarray, shape (4, 4), or None
        [N/(m/s)]; None without a damper fitted in the baseline runs.
    """
    elements = getattr(session, "third_elements", None)
    if not elements:
        return None
    runs = list(session.runs)
    base = [r for r in runs if r.role == "baseline"]
    if not base:
        setups = [tuple(r.setup[c] for c in CORNERS) for r in runs]
        common = max(set(setups), key=setups.count)
        base = [r for r, s in zip(runs, setups) if s == common]
    C = np.zeros((4, 4))
    for e in elements.elements:
        row = elements.row(e)
        ids = {r.third.dampers.get(e) for r in base} - {None}
        if not ids:
            continue
        v_rms = np.sqrt(np.mean([np.mean((row @ np.vstack([r.dynamic(c) for c in
                                                          SHOCK_VELOCITIES])) ** 2)
                                 for r in base]))
        c = np.mean([float(session.shocks.get(i).equivalent_damping(max(v_rms, 1e-6)))
                     for i in ids])
        C += c * np.outer(row, row)
    return C if np.any(C) else None


def _around_corner_damping(frf, damping, outputs):
    """An estimate around ``diag(c_bar) + damping`` brought back to ``diag(c_bar)``.

    With ``dF' = dF - D v`` (``D`` = `damping`) the estimate is ``y = H_r u + H_s dF'``;
    with ``v = H_vr u + H_vs dF'`` (the shock-velocity rows), ``v = M (H_vr u + H_vs dF)``,
    ``M = (I + H_vs D)^-1``, so ``y = (H_r - H_s D M H_vr) u + (H_s - H_s D M H_vs) dF``.
    The coherences and independent fractions stay those of the estimate (its quality); the
    rows are then cut to `outputs`.
    """
    outs = list(frf.output_names)
    vi = [outs.index(v) for v in SHOCK_VELOCITIES]
    nr = len(frf.input_names) - len(DF_INPUTS)
    H = np.moveaxis(frf.H, -1, 0)  # (f, out, in)
    Hr, Hs = H[:, :, :nr], H[:, :, nr:]
    D = np.asarray(damping, dtype=float)[None]
    K = D @ np.linalg.inv(np.eye(4)[None] + Hs[:, vi] @ D)
    H = np.concatenate([Hr - Hs @ K @ Hr[:, vi], Hs - Hs @ K @ Hs[:, vi]], axis=2)
    keep = [outs.index(o) for o in outputs]
    settings = dict(frf.settings, third_linear_damping_n_s_m=np.asarray(damping).tolist())
    return Frf(f_hz=frf.f_hz, H=np.moveaxis(H, 0, -1)[keep], input_names=frf.input_names,
               output_names=tuple(outputs), multiple_coherence=frf.multiple_coherence[keep],
               partial_coherence=frf.partial_coherence[keep],
               input_condition=frf.input_condition,
               independent_fraction=frf.independent_fraction, flagged=frf.flagged,
               n_averages=frf.n_averages, cbar_n_s_m=frf.cbar_n_s_m, fs_hz=frf.fs_hz,
               settings=settings)


def third_force_deviation(session, run):
    """The dynamic part (mean removed) of a run's third elements' force at the corners.

    :func:`ident.identify.thirdforce.third_element_force` with the session's elements and
    libraries, the heave springs' travel from the run's rest
    (:func:`ident.identify.diagnose.rest_levels`): what :func:`estimate_frf` adds to the
    corners' ``dF`` (beside the bump stops').

    Parameters
    ----------
    session : ident.data.session.Session
    run : ident.data.session.Run

    Returns
    -------
    ndarray, shape (4, n_samples), or None
        None when the session declares no third elements or the run fits none.
    """
    elements = getattr(session, "third_elements", None)
    if not elements or not run.third:
        return None
    G, _ = third_element_force(run, elements, session.shocks,
                               getattr(session, "bump_stops", None),
                               levels=rest_levels(run)[0], where=_run_file(session, run))
    return None if G is None else G - G.mean(axis=1, keepdims=True)


def _stop_deviations(session, runs, damping=None):
    """Per run the dynamic part (mean removed) of the declared stops' and third elements'
    force at the corners, or None, and the settings that record how it was computed (empty
    without stops and elements). `damping` (4, 4): the third elements' linear part
    (:func:`third_linear_damping`), taken off at the measured shock velocities."""
    library = getattr(session, "bump_stops", None)
    elements = getattr(session, "third_elements", None)
    out, info, third_info = [], {}, {}
    for run in runs:
        G, inf = bump_stop_force(run, library)
        T, tinf = (None, None) if not elements or not run.third else third_element_force(
            run, elements, session.shocks, library, levels=rest_levels(run)[0],
            where=_run_file(session, run))
        if T is not None:
            G = T if G is None else G + T
            third_info[run.name] = tinf
        if damping is not None:
            lin = damping @ np.vstack([run.channels[c] for c in SHOCK_VELOCITIES])
            G = -lin if G is None else G - lin
        out.append(None if G is None else G - G.mean(axis=1, keepdims=True))
        if inf is not None:
            info[run.name] = inf
    settings = {"bump_stop_force": info} if info else {}
    if third_info:
        settings["third_element_force"] = third_info
    return out, settings


def _run_file(session, run):
    return run.file if session.path is None else str(Path(session.path) / run.file)


def _is_cbar_linear(model, cbar):
    """True if a shock model is linear with rate ``cbar`` (relative 1e-9) and has no lag."""
    return (isinstance(model, LinearShock) and model.lag_s == 0
            and abs(model.c_n_s_m - cbar) <= 1e-9 * abs(cbar))


def baseline_damping(session, *, runs=None):
    """Default ``c_bar``: the equivalent linear damping of the baseline runs' shocks.

    Each corner's shock in the runs with role ``baseline`` (or, without any,
    the most common setup) is linearized at the shock-velocity RMS measured
    there (stochastic linearization; exact for linear shocks).

    Returns
    -------
    ndarray, shape (4,)
        [N/(m/s)]
    """
    runs = session.runs if runs is None else runs
    base = [r for r in runs if r.role == "baseline"]
    if not base:
        setups = [tuple(r.setup[c] for c in CORNERS) for r in runs]
        common = max(set(setups), key=setups.count)
        base = [r for r, s in zip(runs, setups) if s == common]
    cbar = np.empty(4)
    for i, c in enumerate(CORNERS):
        v_rms = np.sqrt(np.mean([np.mean(r.dynamic(f"shock_velocity_{c}") ** 2) for r in base]))
        ids = {r.setup[c] for r in base}
        vals = [float(session.shocks.get(s).equivalent_damping(max(v_rms, 1e-6))) for s in ids]
        cbar[i] = float(np.mean(vals))
    return cbar


def _output_channels(session, outputs):
    present = [ch for ch in RESPONSE_CHANNELS
               if ch not in SHOCK_FORCES and all(ch in r.channels for r in session.runs)]
    if outputs is None:
        return tuple(present)
    missing = [o for o in outputs if o not in present]
    if missing:
        raise IdentificationError(
            f"session '{session.name}': output channel(s) {missing} are not in every run; "
            f"available in all runs: {present}")
    return tuple(outputs)


def _check_session(session):
    rig = [c for c in RIG_INPUTS if all(c in r.channels for r in session.runs)]
    flat = {}
    for run in session.runs:
        where = run.file if session.path is None else Path(session.path) / run.file
        const = [c for c in rig if np.ptp(run.channels[c]) == 0]
        flat[run.name] = const
        if const and len(const) == len(rig):
            raise IdentificationError(
                f"run '{run.name}' ({where}): every rig input is constant ({', '.join(const)}: "
                f"e.g. {const[0]} = {run.channels[const[0]][0]:g} throughout); the rig did not "
                "move in this run: drop the run or export its rig input channels")
    for c in rig:
        if all(c in flat[r.name] for r in session.runs):
            run = session.runs[0]
            where = run.file if session.path is None else Path(session.path) / run.file
            raise IdentificationError(
                f"rig input {c!r} is constant in every run (e.g. run '{run.name}' ({where})), so "
                "its response cannot be identified; check the channel in the run files (a "
                "dead sensor, or a channel map to the wrong column)")
    for run in session.runs:
        missing = [v for v in SHOCK_VELOCITIES if v not in run.channels]
        if missing:
            raise IdentificationError(
                f"run '{run.name}' ({run.file}): identification needs the shock velocities; "
                f"columns {missing} are missing (add them, or map them in [channels])")


def estimate_frf(session, *, method="global", cbar_n_s_m=None, outputs=None, window="hamming",
                 nperseg=None, noverlap=None, band_hz=(0.5, 20.0), estimator="lpm",
                 lpm_degree=LPM_DEGREE, lpm_half_width=None,
                 lpm_coherence_dof=LPM_COHERENCE_DOF, exact_linear=True, instruments=False):
    """Estimate the closed-loop multi-input FRF of a rig session (Eqs. 18-28).

    Parameters
    ----------
    session : ident.data.session.Session
    method : {"global", "sequential"}
        ``global``: one least-squares problem over all runs' blocks (Eq. 23);
        works with nonlinear baseline shocks. ``sequential``: the rig inputs
        from the baseline runs (Eqs. 25-26), then each shock input from the
        runs where only that corner differs (Eqs. 27-28); needs linear
        baseline shocks equal to ``c_bar``.
    cbar_n_s_m : array_like, shape (4,), optional
        Baseline damping [N/(m/s)]; default :func:`baseline_damping`.
    outputs : sequence of str, optional
        Output channels; default every response channel present in all runs
        (``shock_force_XX`` excluded: the force is an input).
    window, nperseg, noverlap
        Welch settings; ``nperseg`` defaults to :func:`default_nperseg` of the
        shortest run. With ``estimator="lpm"`` only ``nperseg`` is used: it
        sets the frequency grid ``k fs / nperseg`` (the Welch grid, so
        conditioning and fitting see the same frequencies).
    band_hz : (float, float)
        Band used for the identifiability check [Hz].
    estimator : {"lpm", "welch"}
        ``lpm`` (default): the local polynomial method on each run's
        full-record DFT, jointly over all runs with a transient polynomial per
        run (module notes); free of the transient-leakage error of Welch
        blocks, which dominates weak paths under strong inputs (on the paper
        session it cuts the identified model's closed-loop metric error from
        1.0 % to 0.13 % max). Only with ``method="global"``. ``welch``: the
        paper's H1 from Welch blocks (Hamming, 50 % overlap).
    lpm_degree : int
        Degree ``D`` of the local FRF and transient polynomials (LPM only).
    lpm_half_width : int, optional
        Half-width ``R`` of the local window [DFT lines of each run]; default
        the smallest ``R`` with rows at least twice the unknowns, counting
        inputs repeated identically in several runs (the same rig drive) once
        (:func:`_lpm_default_half_width`). The paper's 5 runs of 800 s with one
        drive: R = 24 (49 lines of 1/800 Hz = 0.061 Hz; 245 rows, 48
        unknowns, 197 residual degrees of freedom). The window must be narrow
        against the resonances' half-power bandwidths (the local polynomials'
        bias grows with it; it shows up as low coherence).
    lpm_coherence_dof : int
        ``nu_c`` of the LPM's partial coherence (module notes); default
        :data:`LPM_COHERENCE_DOF`.
    exact_linear : bool
        :func:`shock_force_deviation`: ``dF = 0`` exactly at corners whose
        shock is linear at ``c_bar`` without lag (default).
    instruments : bool
        LPM only: instrumental variables (:func:`ident.identify.instruments.iv_lpm_solve`)
        with the inputs computed again from the shock travels
        (:func:`ident.identify.instruments.travel_run`) as instruments, and the shock-travel
        rows taken from the velocity rows; needs ``shock_travel_XX`` in every run. Default
        False (least squares); ``settings["instruments"]`` says ``"travel"`` when on.

    Returns
    -------
    Frf
        Inputs :func:`model_inputs`: the session's rig inputs (7, or the 4
        wheelloaders of a 4-post session: the Eq. 17 rank is then 8), then the
        4 ``dF``. For the LPM, ``n_averages`` is ``lpm_coherence_dof + n_in``
        (module notes) and ``settings`` holds
        ``estimator``, ``lpm_degree``, ``lpm_half_width``, ``lpm_rows``,
        ``lpm_unknowns``, ``lpm_dof`` (residual degrees of freedom),
        ``lpm_coherence_dof``, ``resolution_hz`` (per run). A session that declares
        bump stops has their force in the ``dF`` of the corners that have one
        (:func:`bump_stop_force`: the table at the travel measured from the car at rest),
        so that the estimate is of the car without them; ``settings["bump_stop_force"]``
        then says per run where the rest was taken, the rest less the mean travel and
        the share of time in contact. A session that declares third elements has their
        force at the corners in the ``dF`` too (:func:`third_force_deviation`), and
        ``settings["third_element_force"]`` says per run and element whether it was
        measured or computed from its curve.

    Raises
    ------
    IdentificationError
        If a run lacks shock velocities, or the experiment cannot identify
        the shock inputs: a corner's ``dF`` is zero or a linear function of
        the rig inputs in every run (only linear or identical shocks, no swap
        runs, a corner never swapped; Eq. 17). The message says which runs to
        add.
    """
    if method not in ("global", "sequential"):
        raise ValueError(f"method must be 'global' or 'sequential', got {method!r}")
    _check_estimator(estimator)
    if estimator == "lpm" and method != "global":
        raise ValueError(f"estimator='lpm' solves all runs jointly (method='global'); got "
                         f"method={method!r}; use method='global' or estimator='welch'")
    if instruments and estimator != "lpm":
        raise ValueError("instruments=True is an LPM estimate (estimator='lpm'); got "
                         f"estimator={estimator!r}: use the LPM or instruments=False")
    _check_session(session)
    outs = _output_channels(session, outputs)
    cbar = baseline_damping(session) if cbar_n_s_m is None else np.broadcast_to(
        np.asarray(cbar_n_s_m, dtype=float), (4,)).copy()
    damping = third_linear_damping(session)
    if damping is not None:  # the velocities are needed to bring the estimate back
        wanted = outs
        outs = outs + tuple(v for v in SHOCK_VELOCITIES if v not in outs)
    fs = session.fs_hz
    n_min = min(r.n_samples for r in session.runs)
    if nperseg is None:
        nperseg = default_nperseg(n_min)
        if estimator == "lpm":
            # the LPM's grid only names the target frequencies: keep it at least as fine as
            # LPM_GRID_HZ for short runs (60 s runs would give 0.39 Hz, too coarse to smooth)
            nperseg = min(max(nperseg, int(2 ** np.ceil(np.log2(fs / LPM_GRID_HZ)))),
                          int(2 ** np.floor(np.log2(n_min))))
    if isinstance(nperseg, (int, np.integer)) and not isinstance(nperseg, bool) \
            and n_min < max(nperseg, MIN_NPERSEG):
        nperseg = max(nperseg, MIN_NPERSEG)
        short = min(session.runs, key=lambda r: r.n_samples)
        where = short.file if session.path is None else Path(session.path) / short.file
        raise IdentificationError(
            f"run '{short.name}' ({where}): {short.n_samples} samples "
            f"({short.n_samples / fs:g} s), fewer than the {nperseg} of one spectral block "
            f"(nperseg, {nperseg / fs:g} s); record runs of at least {nperseg / fs:g} s (the "
            f"paper's are 800 s; 60 s or more is advised) or pass a smaller --nperseg")
    nperseg, noverlap = _check_spectral_args(fs, window, nperseg, noverlap, n_min)
    inputs = model_inputs(session)
    rig = inputs[:-len(DF_INPUTS)]
    m = len(inputs)
    if estimator == "lpm":
        frf = _estimate_frf_lpm(session, outs, cbar, nperseg, band_hz, lpm_degree,
                                lpm_half_width, lpm_coherence_dof, exact_linear, damping,
                                instruments)
        return frf if damping is None else _around_corner_damping(frf, damping, wanted)
    per_run = []
    stop_dev, stop_settings = _stop_deviations(session, session.runs, damping)
    for run, G in zip(session.runs, stop_dev):
        _, dF = shock_force_deviation(run, session.shocks, cbar, exact_linear=exact_linear)
        if G is not None:
            dF = dF + G  # the stops' force is part of the corner's input (issue 25)
        x = np.vstack([np.vstack([run.dynamic(c) for c in rig]), dF,
                       np.vstack([run.dynamic(o) for o in outs])])
        f, X = block_spectra(x, fs=fs, window=window, nperseg=nperseg, noverlap=noverlap)
        U, Y = X[:m], X[m:]
        per_run.append((run, np.einsum("ifk,jfk->fij", np.conj(U), U),
                        np.einsum("ifk,ofk->fio", np.conj(U), Y),
                        np.real(np.einsum("ofk,ofk->fo", np.conj(Y), Y)), U.shape[-1],
                        np.mean(dF**2, axis=1)))
    settings = {"estimator": "welch", "exact_linear": bool(exact_linear), "method": method,
                "window": window, "nperseg": nperseg,
                "noverlap": noverlap, "runs": [r.name for r in session.runs],
                "band_hz": tuple(band_hz), **stop_settings}
    band = (f >= band_hz[0]) & (f <= band_hz[1])
    Suu = sum(pr[1] for pr in per_run)
    Suy = sum(pr[2] for pr in per_run)
    Syy = sum(pr[3] for pr in per_run)
    n_avg = sum(pr[4] for pr in per_run)
    _check_identifiable(session, [pr[0] for pr in per_run], [pr[5] for pr in per_run], band,
                        cbar, Suu=Suu)
    if method == "global":
        Ht, mult, partial, cond, indep = _solve_h1(Suu, Suy, Syy)
        H = np.transpose(Ht, (2, 1, 0))
        partial = np.transpose(partial, (2, 1, 0))
    else:
        H, mult, partial, cond, indep = _sequential(session, per_run, outs, f)
    mult = mult.T  # (n_out, n_f)
    flagged = indep.T < FLAG_INDEPENDENT_FRACTION
    _warn_flagged(session, flagged, band, band_hz, stacklevel=2)
    frf = Frf(f_hz=f, H=H, input_names=inputs, output_names=outs,
              multiple_coherence=mult,
              partial_coherence=partial, input_condition=cond, independent_fraction=indep.T,
              flagged=flagged, n_averages=n_avg, cbar_n_s_m=cbar, fs_hz=fs, settings=settings)
    return frf if damping is None else _around_corner_damping(frf, damping, wanted)


def _warn_flagged(session, flagged, band, band_hz, *, stacklevel):
    """Warn about flagged dF frequencies; `stacklevel` as for a warning raised in the caller."""
    nflag = flagged[-len(DF_INPUTS):, band].sum(axis=1)
    if np.any(nflag):
        bad = {c: int(n) for c, n in zip(CORNERS, nflag) if n}
        warnings.warn(
            f"session '{session.name}': the shock-force deviation has almost no independent energy "
            f"at some frequencies in {band_hz[0]:g}-{band_hz[1]:g} Hz (count per corner: {bad}); "
            "those frequencies are flagged in Frf.flagged and the conditioning step replaces them",
            LowCoherenceWarning, stacklevel=stacklevel + 1)


def _estimate_frf_lpm(session, outs, cbar, nperseg, band_hz, degree, half_width, coherence_dof,
                      exact_linear, damping=None, instruments=False):
    """The ``estimator="lpm"`` branch of :func:`estimate_frf` (arguments checked there)."""
    fs = session.fs_hz
    inputs = model_inputs(session)
    rig = inputs[:-len(DF_INPUTS)]
    m = len(inputs)
    runs = list(session.runs)
    n_samples = [r.n_samples for r in runs]
    records, dF_pow = [], []
    stop_dev, stop_settings = _stop_deviations(session, runs, damping)
    for run, G in zip(runs, stop_dev):
        _, dF = shock_force_deviation(run, session.shocks, cbar, exact_linear=exact_linear)
        if G is not None:
            dF = dF + G  # the stops' force is part of the corner's input (issue 25)
        records.append(np.vstack([np.vstack([run.dynamic(c) for c in rig]), dF,
                                  np.vstack([run.dynamic(o) for o in outs])]))
        dF_pow.append(np.mean(dF**2, axis=1))
    if instruments:  # the inputs again from the travels: ident.identify.instruments
        zruns = [travel_run(r) for r in runs]
        for k, (zr, G) in enumerate(zip(zruns, _stop_deviations(session, zruns, damping)[0])):
            dF = shock_force_deviation(zr, session.shocks, cbar, exact_linear=exact_linear)[1]
            records[k] = np.vstack([records[k], dF if G is None else dF + G])
    degree, half_width, coherence_dof = _check_lpm_args(
        degree, half_width, coherence_dof, [x[:m] for x in records], [r.name for r in runs])
    # the runs' DFTs side by side (numpy's FFT releases the GIL; the same numbers)
    n_threads = _lpm_threads(len(records))
    with concurrent.futures.ThreadPoolExecutor(n_threads) as pool:
        spectra = list(pool.map(lambda x: np.fft.rfft(x, axis=-1), records))
    del records
    f = np.fft.rfftfreq(nperseg, 1.0 / fs)
    band = (f >= band_hz[0]) & (f <= band_hz[1])
    # dF = 0 everywhere is refused before the solve (the solve would not fail, only be useless)
    _check_identifiable(session, runs, dF_pow, band, cbar)
    if instruments:
        H, mult, partial, cond, indep, dof = iv_lpm_solve(
            spectra, n_samples, m, len(outs), f, float(fs), degree, half_width, coherence_dof,
            travel_rows(outs), rcond=LPM_RCOND, chunk=_LPM_CHUNK)
        H, partial, mult = travel_from_velocity(H, partial, mult, outs, f)
    else:
        H, mult, partial, cond, indep, dof = _lpm_solve(spectra, n_samples, m, f, float(fs),
                                                        degree, half_width, coherence_dof)
    _check_identifiable(session, runs, dF_pow, band, cbar, indep=indep.T)
    flagged = indep < FLAG_INDEPENDENT_FRACTION
    _warn_flagged(session, flagged, band, band_hz, stacklevel=3)
    settings = _lpm_settings(nperseg, fs, degree, half_width, dof, coherence_dof, n_samples, m)
    settings.update(method="global", runs=[r.name for r in runs], band_hz=tuple(band_hz),
                    exact_linear=bool(exact_linear), **stop_settings)
    if instruments:
        settings["instruments"] = "travel"
    return Frf(f_hz=f, H=H, input_names=inputs, output_names=outs,
               multiple_coherence=mult, partial_coherence=partial, input_condition=cond,
               independent_fraction=indep, flagged=flagged, n_averages=coherence_dof + m,
               cbar_n_s_m=cbar, fs_hz=fs, settings=settings)


def _check_identifiable(session, runs, dF_power, band, cbar, *, Suu=None, indep=None):
    """Refuse experiments whose dF inputs are zero or dependent on the rig inputs (Eq. 17).

    Parameters
    ----------
    runs : list of Run
    dF_power : list of ndarray, shape (4,)
        Mean square ``dF`` per corner of each run.
    Suu : ndarray, shape (n_f, n_in, n_in), optional
        Input spectral matrix (Welch): the independent fraction is ``1 / [Sn^-1]_ii``.
        Inputs: the rig inputs (7, or 4 on a 4-post rig), then the 4 ``dF``.
    indep : ndarray, shape (n_f, n_in), optional
        The independent fraction itself (LPM). Without `Suu` and `indep` only
        the ``dF = 0`` check is made.
    """
    energy = np.sum(dF_power, axis=0)  # (4,) dF power summed over runs
    force_scale = np.array([max(np.mean([np.mean(r.dynamic(f"shock_velocity_{c}") ** 2)
                                         for r in runs]), 1e-30) for c in CORNERS])
    force_scale = force_scale * np.maximum(cbar, 1.0) ** 2
    problems = []
    zero = []
    for i, c in enumerate(CORNERS):
        changed = [r.name for r, pw in zip(runs, dF_power) if pw[i] > 1e-8 * force_scale[i]]
        if energy[i] <= 1e-8 * force_scale[i] * len(runs) or not changed:
            zero.append(i)
            problems.append(f"corner {c}: the shock force equals c_bar*v in every run (dF = 0: "
                            f"no run has a different shock there)")
    if not zero and (Suu is not None or indep is not None):
        if indep is None:
            d = np.sqrt(np.real(np.einsum("fii->fi", Suu)))
            d = np.where(d > 0, d, 1.0)
            with np.errstate(divide="ignore", invalid="ignore"):
                try:
                    inv = np.linalg.inv(Suu / (d[:, :, None] * d[:, None, :]))
                    indep = 1.0 / np.real(np.einsum("fii->fi", inv))
                except np.linalg.LinAlgError:
                    indep = np.zeros(Suu.shape[:2])
        for i, c in enumerate(CORNERS):
            frac = np.nanmedian(indep[band, indep.shape[1] - len(CORNERS) + i])
            if not frac >= MIN_INDEPENDENT_FRACTION:
                changed = [r.name for r, pw in zip(runs, dF_power)
                           if pw[i] > 1e-8 * force_scale[i]]
                problems.append(f"corner {c}: dF is a linear function of the rig inputs in every "
                                f"run (independent fraction {frac:.2g}; runs with dF: {changed}); "
                                "linear or identical shocks cannot separate shock from rig inputs")
    if problems:
        raise IdentificationError(
            f"session '{session.name}' cannot identify the shock inputs (seed paper Eq. 17: with "
            "linear or identical shocks the shock forces are linearly dependent on the rig "
            "inputs): " + "; ".join(problems) + ". Add, for each such corner, a run with a "
            "different shock at that corner only (a 'swap' run: e.g. the baseline setup with "
            "that corner changed to a shock of clearly different damping)")


def _sequential(session, per_run, outs, f):
    """Eqs. 25-28: rig FRF from baseline runs, then each shock input from its swap runs."""
    n_f, p = f.size, len(outs)
    r = per_run[0][1].shape[1] - len(CORNERS)  # rig inputs: 7, or 4 on a 4-post rig
    dF_pow = np.array([pr[5] for pr in per_run])  # (runs, 4)
    F_scale = dF_pow.max(axis=0) + 1e-300
    zero = dF_pow <= 1e-10 * F_scale[None, :]
    base = [k for k in range(len(per_run)) if zero[k].all()]
    if not base:
        raise IdentificationError(
            f"session '{session.name}': method='sequential' needs baseline runs whose shocks are "
            "linear and equal to c_bar (dF = 0 at every corner); none found. Use "
            "method='global' (it handles nonlinear baseline shocks)")
    Suu_r = sum(per_run[k][1][:, :r, :r] for k in base)
    Suy_r = sum(per_run[k][2][:, :r, :] for k in base)
    Syy_r = sum(per_run[k][3] for k in base)
    Ht_r, mult, part_r, cond, indep_r = _solve_h1(Suu_r, Suy_r, Syy_r)
    H = np.zeros((p, r + 4, n_f), dtype=complex)
    partial = np.zeros((p, r + 4, n_f))
    H[:, :r] = np.transpose(Ht_r, (2, 1, 0))
    partial[:, :r] = np.transpose(part_r, (2, 1, 0))
    indep = np.ones((n_f, r + 4))
    indep[:, :r] = indep_r
    for i, c in enumerate(CORNERS):
        swaps = [k for k in range(len(per_run)) if not zero[k, i] and zero[k, np.arange(4) != i].all()]
        if not swaps:
            raise IdentificationError(
                f"session '{session.name}': method='sequential' needs, for corner {c}, a run where "
                f"only the {c} shock differs from the baseline; add one or use method='global'")
        # dY = Y - H_rig U_rig, per block: from the cross spectra
        # S_fdy = S_fy - S_fu H_rig^T ; S_ff ; S_dydy = S_yy - 2 Re(...) + ...
        S_ff = sum(np.real(per_run[k][1][:, r + i, r + i]) for k in swaps)
        S_fy = sum(per_run[k][2][:, r + i, :] for k in swaps)  # (f, p)
        S_fu = sum(per_run[k][1][:, r + i, :r] for k in swaps)  # (f, r)
        S_uu = sum(per_run[k][1][:, :r, :r] for k in swaps)
        S_uy = sum(per_run[k][2][:, :r, :] for k in swaps)
        S_yy = sum(per_run[k][3] for k in swaps)
        S_fdy = S_fy - np.einsum("fj,fjp->fp", S_fu, Ht_r)
        S_dydy = (S_yy - 2 * np.real(np.einsum("fjp,fjp->fp", np.conj(Ht_r), S_uy))
                  + np.real(np.einsum("fjp,fjk,fkp->fp", np.conj(Ht_r), S_uu, Ht_r)))
        with np.errstate(divide="ignore", invalid="ignore"):
            Hs = S_fdy / S_ff[:, None]
            coh = np.where(S_dydy > 0, np.abs(S_fdy) ** 2 / (S_ff[:, None] * S_dydy), 0.0)
        H[:, r + i] = Hs.T
        partial[:, r + i] = np.clip(coh, 0, 1).T
        # independence of dF from the rig inputs in its swap runs
        with np.errstate(divide="ignore", invalid="ignore"):
            # power of dF explained by the rig inputs: S_fu S_uu^-1 S_uf, S_uf = conj(S_fu)
            expl = np.real(np.einsum("fj,fjk,fk->f", S_fu,
                                     np.linalg.pinv(S_uu, hermitian=True), np.conj(S_fu)))
            indep[:, r + i] = np.clip(1 - expl / S_ff, 0, 1)
    return H, mult, partial, cond, indep
