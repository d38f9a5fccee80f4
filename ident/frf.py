"""Multi-input frequency-response estimation from rig runs (seed paper, Eqs. 11-28).

The inputs of the identified model are the 7 rig inputs and the 4 shock-force
deviations ``dF_i = F_i - c_bar_i v_i`` (Eq. 19), where ``c_bar`` is a baseline
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
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from ident.channels import CORNERS, RESPONSE_CHANNELS, RIG_INPUTS, SHOCK_FORCES, SHOCK_VELOCITIES
from ident.errors import IdentificationError, LowCoherenceWarning

__all__ = [
    "Frf",
    "DF_INPUTS",
    "MODEL_INPUTS",
    "block_spectra",
    "estimate_frf",
    "frf_from_arrays",
    "shock_force_deviation",
    "baseline_damping",
    "default_nperseg",
]

log = logging.getLogger(__name__)

#: Names of the shock-force-deviation inputs.
DF_INPUTS = tuple(f"dF_{c}" for c in CORNERS)
#: The 11 inputs of an identified model, in order.
MODEL_INPUTS = RIG_INPUTS + DF_INPUTS

#: A corner whose dF keeps less than this fraction of its energy once the rig
#: inputs are accounted for (median over 0.5-20 Hz) is not identifiable (Eq. 17).
MIN_INDEPENDENT_FRACTION = 1e-2
#: Frequencies where the independent fraction of a dF is below this are flagged.
FLAG_INDEPENDENT_FRACTION = 1e-3


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
        method's shock inputs, the ordinary coherence of ``dY`` with ``dF``.
    input_condition : ndarray, shape (n_f,)
        Condition number of the scaled input spectral matrix.
    independent_fraction : ndarray, shape (n_in, n_f)
        Fraction of each input's power not linearly explained by the other
        inputs (1 for independent inputs, 0 for a dependent one).
    flagged : ndarray of bool, shape (n_in, n_f)
        Frequencies where an input has (almost) no independent energy: the
        estimate of that input's column is unreliable there.
    n_averages : int
        Number of Welch blocks used (all runs).
    cbar_n_s_m : ndarray, shape (4,)
        Baseline damping the shock inputs are written around [N/(m/s)].
    fs_hz : float
    settings : dict
        ``method``, ``window``, ``nperseg``, ``noverlap``, ``runs``, ...
    H_raw : ndarray or None
        The estimate before conditioning (set by :func:`ident.condition.condition_frf`).
    replaced : ndarray of bool or None
        Frequencies replaced by residual fits in conditioning, (n_out, n_in, n_f).
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


def frf_from_arrays(u, y, *, fs, window="hamming", nperseg=None, noverlap=None,
                    input_names=None, output_names=None):
    """H1 estimate of a multi-input, multi-output response from one record.

    Parameters
    ----------
    u : ndarray, shape (n_samples, n_in)
        Inputs (SI).
    y : ndarray, shape (n_samples, n_out)
        Outputs (SI).
    fs : float
        Sample rate [Hz].
    window, nperseg, noverlap
        Welch settings (:func:`block_spectra`); ``nperseg`` defaults to
        :func:`default_nperseg`.

    Returns
    -------
    Frf
        With ``cbar_n_s_m`` zeros and ``settings["method"] = "h1"``.

    Examples
    --------
    A pure gain of 2 is recovered exactly:

    >>> rng = np.random.default_rng(0)
    >>> u = rng.standard_normal((4096, 1))
    >>> frf = frf_from_arrays(u, 2 * u, fs=100.0, nperseg=256)
    >>> bool(np.allclose(frf.H, 2.0))
    True
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    if u.ndim != 2 or y.ndim != 2 or u.shape[0] != y.shape[0]:
        raise ValueError(f"u and y must be 2-D with the same number of rows (samples), got "
                         f"{u.shape} and {y.shape}")
    nperseg = default_nperseg(u.shape[0]) if nperseg is None else nperseg
    f, X = block_spectra(np.vstack([u.T, y.T]), fs=fs, window=window, nperseg=nperseg,
                         noverlap=noverlap)
    m = u.shape[1]
    U, Y = X[:m], X[m:]
    Suu = np.einsum("ifk,jfk->fij", np.conj(U), U)
    Suy = np.einsum("ifk,ofk->fio", np.conj(U), Y)
    Syy = np.real(np.einsum("ofk,ofk->fo", np.conj(Y), Y))
    Ht, mult, partial, cond, indep = _solve_h1(Suu, Suy, Syy)
    n_in, n_out = u.shape[1], y.shape[1]
    return Frf(f_hz=f, H=np.transpose(Ht, (2, 1, 0)),
               input_names=tuple(input_names or (f"u{i}" for i in range(n_in))),
               output_names=tuple(output_names or (f"y{o}" for o in range(n_out))),
               multiple_coherence=mult.T, partial_coherence=np.transpose(partial, (2, 1, 0)),
               input_condition=cond, independent_fraction=indep.T,
               flagged=indep.T < FLAG_INDEPENDENT_FRACTION, n_averages=U.shape[-1],
               cbar_n_s_m=np.zeros(4), fs_hz=float(fs),
               settings={"method": "h1", "window": window, "nperseg": int(nperseg),
                         "noverlap": int(nperseg // 2 if noverlap is None else noverlap)})


# ----------------------------------------------------------------------------------------------
# sessions
# ----------------------------------------------------------------------------------------------

def shock_force_deviation(run, shocks, cbar_n_s_m):
    """The shock forces and their deviations ``dF = F - c_bar v`` of one run.

    Parameters
    ----------
    run : ident.session.Run
        Must hold ``shock_velocity_XX``; ``shock_force_XX`` is used when present,
        otherwise the force is computed from the run's shock model (static curve
        and lag, first-order hold at the run's sample rate) and the measured
        velocity.
    shocks : ident.shocks.ShockLibrary
    cbar_n_s_m : array_like, shape (4,)

    Returns
    -------
    F, dF : ndarray, shape (4, n_samples)
        Dynamic parts (means removed) [N].
    """
    from ident.closedloop import lag_coefficients

    cbar = np.asarray(cbar_n_s_m, dtype=float)
    F = np.empty((4, run.n_samples))
    dF = np.empty_like(F)
    for i, c in enumerate(CORNERS):
        v = run.dynamic(f"shock_velocity_{c}")
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
    for run in session.runs:
        missing = [v for v in SHOCK_VELOCITIES if v not in run.channels]
        if missing:
            raise IdentificationError(
                f"run '{run.name}' ({run.file}): identification needs the shock velocities; "
                f"columns {missing} are missing (add them, or map them in [channels])")


def estimate_frf(session, *, method="global", cbar_n_s_m=None, outputs=None, window="hamming",
                 nperseg=None, noverlap=None, band_hz=(0.5, 20.0)):
    """Estimate the closed-loop multi-input FRF of a rig session (Eqs. 18-28).

    Parameters
    ----------
    session : ident.session.Session
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
        shortest run.
    band_hz : (float, float)
        Band used for the identifiability check [Hz].

    Returns
    -------
    Frf
        Inputs :data:`MODEL_INPUTS`.

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
    _check_session(session)
    outs = _output_channels(session, outputs)
    cbar = baseline_damping(session) if cbar_n_s_m is None else np.broadcast_to(
        np.asarray(cbar_n_s_m, dtype=float), (4,)).copy()
    fs = session.fs_hz
    n_min = min(r.n_samples for r in session.runs)
    nperseg = default_nperseg(n_min) if nperseg is None else nperseg
    nperseg, noverlap = _check_spectral_args(fs, window, nperseg, noverlap, n_min)
    m = len(MODEL_INPUTS)
    per_run = []
    for run in session.runs:
        _, dF = shock_force_deviation(run, session.shocks, cbar)
        x = np.vstack([np.vstack([run.dynamic(c) for c in RIG_INPUTS]), dF,
                       np.vstack([run.dynamic(o) for o in outs])])
        f, X = block_spectra(x, fs=fs, window=window, nperseg=nperseg, noverlap=noverlap)
        U, Y = X[:m], X[m:]
        per_run.append((run, np.einsum("ifk,jfk->fij", np.conj(U), U),
                        np.einsum("ifk,ofk->fio", np.conj(U), Y),
                        np.real(np.einsum("ofk,ofk->fo", np.conj(Y), Y)), U.shape[-1],
                        np.mean(dF**2, axis=1)))
    settings = {"method": method, "window": window, "nperseg": nperseg, "noverlap": noverlap,
                "runs": [r.name for r in session.runs], "band_hz": tuple(band_hz)}
    band = (f >= band_hz[0]) & (f <= band_hz[1])
    Suu = sum(pr[1] for pr in per_run)
    Suy = sum(pr[2] for pr in per_run)
    Syy = sum(pr[3] for pr in per_run)
    n_avg = sum(pr[4] for pr in per_run)
    _check_identifiable(session, per_run, Suu, band, cbar)
    if method == "global":
        Ht, mult, partial, cond, indep = _solve_h1(Suu, Suy, Syy)
        H = np.transpose(Ht, (2, 1, 0))
        partial = np.transpose(partial, (2, 1, 0))
    else:
        H, mult, partial, cond, indep = _sequential(session, per_run, outs, f)
    mult = mult.T  # (n_out, n_f)
    flagged = indep.T < FLAG_INDEPENDENT_FRACTION
    nflag = flagged[7:, band].sum(axis=1)
    if np.any(nflag):
        bad = {c: int(n) for c, n in zip(CORNERS, nflag) if n}
        warnings.warn(
            f"session '{session.name}': the shock-force deviation has almost no independent energy "
            f"at some frequencies in {band_hz[0]:g}-{band_hz[1]:g} Hz (count per corner: {bad}); "
            "those frequencies are flagged in Frf.flagged and the conditioning step replaces them",
            LowCoherenceWarning, stacklevel=2)
    return Frf(f_hz=f, H=H, input_names=MODEL_INPUTS, output_names=outs,
               multiple_coherence=mult,
               partial_coherence=partial, input_condition=cond, independent_fraction=indep.T,
               flagged=flagged, n_averages=n_avg, cbar_n_s_m=cbar, fs_hz=fs, settings=settings)


def _check_identifiable(session, per_run, Suu, band, cbar):
    """Refuse experiments whose dF inputs are zero or dependent on the rig inputs (Eq. 17)."""
    energy = np.sum([pr[5] for pr in per_run], axis=0)  # (4,) dF power summed over runs
    force_scale = np.array([max(np.mean([np.mean(pr[0].dynamic(f"shock_velocity_{c}") ** 2)
                                         for pr in per_run]), 1e-30) for c in CORNERS])
    force_scale = force_scale * np.maximum(cbar, 1.0) ** 2
    problems = []
    zero = []
    for i, c in enumerate(CORNERS):
        changed = [pr[0].name for pr in per_run if pr[5][i] > 1e-8 * force_scale[i]]
        if energy[i] <= 1e-8 * force_scale[i] * len(per_run) or not changed:
            zero.append(i)
            problems.append(f"corner {c}: the shock force equals c_bar*v in every run (dF = 0: "
                            f"no run has a different shock there)")
    if not zero:
        d = np.sqrt(np.real(np.einsum("fii->fi", Suu)))
        d = np.where(d > 0, d, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            try:
                inv = np.linalg.inv(Suu / (d[:, :, None] * d[:, None, :]))
                indep = 1.0 / np.real(np.einsum("fii->fi", inv))
            except np.linalg.LinAlgError:
                indep = np.zeros(Suu.shape[:2])
        for i, c in enumerate(CORNERS):
            frac = np.nanmedian(indep[band, 7 + i])
            if not frac >= MIN_INDEPENDENT_FRACTION:
                changed = [pr[0].name for pr in per_run if pr[5][i] > 1e-8 * force_scale[i]]
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
    dF_pow = np.array([pr[5] for pr in per_run])  # (runs, 4)
    F_scale = dF_pow.max(axis=0) + 1e-300
    zero = dF_pow <= 1e-10 * F_scale[None, :]
    base = [k for k in range(len(per_run)) if zero[k].all()]
    if not base:
        raise IdentificationError(
            f"session '{session.name}': method='sequential' needs baseline runs whose shocks are "
            "linear and equal to c_bar (dF = 0 at every corner); none found. Use "
            "method='global' (it handles nonlinear baseline shocks)")
    Suu_r = sum(per_run[k][1][:, :7, :7] for k in base)
    Suy_r = sum(per_run[k][2][:, :7, :] for k in base)
    Syy_r = sum(per_run[k][3] for k in base)
    Ht_r, mult, part_r, cond, indep_r = _solve_h1(Suu_r, Suy_r, Syy_r)
    H = np.zeros((p, 11, n_f), dtype=complex)
    partial = np.zeros((p, 11, n_f))
    H[:, :7] = np.transpose(Ht_r, (2, 1, 0))
    partial[:, :7] = np.transpose(part_r, (2, 1, 0))
    indep = np.ones((n_f, 11))
    indep[:, :7] = indep_r
    for i, c in enumerate(CORNERS):
        swaps = [k for k in range(len(per_run)) if not zero[k, i] and zero[k, np.arange(4) != i].all()]
        if not swaps:
            raise IdentificationError(
                f"session '{session.name}': method='sequential' needs, for corner {c}, a run where "
                f"only the {c} shock differs from the baseline; add one or use method='global'")
        # dY = Y - H_rig U_rig, per block: from the cross spectra
        # S_fdy = S_fy - S_fu H_rig^T ; S_ff ; S_dydy = S_yy - 2 Re(...) + ...
        S_ff = sum(np.real(per_run[k][1][:, 7 + i, 7 + i]) for k in swaps)
        S_fy = sum(per_run[k][2][:, 7 + i, :] for k in swaps)  # (f, p)
        S_fu = sum(per_run[k][1][:, 7 + i, :7] for k in swaps)  # (f, 7)
        S_uu = sum(per_run[k][1][:, :7, :7] for k in swaps)
        S_uy = sum(per_run[k][2][:, :7, :] for k in swaps)
        S_yy = sum(per_run[k][3] for k in swaps)
        S_fdy = S_fy - np.einsum("fj,fjp->fp", S_fu, Ht_r)
        S_dydy = (S_yy - 2 * np.real(np.einsum("fjp,fjp->fp", np.conj(Ht_r), S_uy))
                  + np.real(np.einsum("fjp,fjk,fkp->fp", np.conj(Ht_r), S_uu, Ht_r)))
        with np.errstate(divide="ignore", invalid="ignore"):
            Hs = S_fdy / S_ff[:, None]
            coh = np.where(S_dydy > 0, np.abs(S_fdy) ** 2 / (S_ff[:, None] * S_dydy), 0.0)
        H[:, 7 + i] = Hs.T
        partial[:, 7 + i] = np.clip(coh, 0, 1).T
        # independence of dF from the rig inputs in its swap runs
        with np.errstate(divide="ignore", invalid="ignore"):
            # power of dF explained by the rig inputs: S_fu S_uu^-1 S_uf, S_uf = conj(S_fu)
            expl = np.real(np.einsum("fj,fjk,fk->f", S_fu,
                                     np.linalg.pinv(S_uu, hermitian=True), np.conj(S_fu)))
            indep[:, 7 + i] = np.clip(1 - expl / S_ff, 0, 1)
    return H, mult, partial, cond, indep
