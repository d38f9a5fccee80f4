"""The information of rig runs and the design criteria (D, A, decision).

Part of :mod:`planner.design` (see its docstring): the drives a plan plays, each candidate's
Fisher information through the linearized loop, a session's measured information, the
criteria (:func:`criterion_value`) and the decision criterion's weights.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy import signal

from ident.data import drive as drv
from ident.data.channels import CORNERS, RIG_INPUTS
from ident.identify.condition import frf_standard_error
from ident.identify.frf import shock_force_deviation, third_force_deviation
from ident.sim.virtual_rig import default_plan, make_plan_drive
from planner.objective import score_setups
from planner.screen import DriveBands, metric_rows, screen_response, screen_setups
from planner.setups import enumerate_setups
from planner.options import UncertaintyOptions
from planner.uncertainty import (interpolate, prediction_uncertainty, score_errors,
                                 unresolved_pairs)

__all__ = [
    "CRITERIA",
    "INFORMATION_EPS",
    "DEFAULT_BAND_HZ",
    "InformationOptions",
    "drive_maker",
    "candidate_information",
    "session_information",
    "hermitian",
    "criterion_value",
    "decision_weight_matrices",
    "decision_pairs",
    "DECISION_DRAWS",
]

log = logging.getLogger(__name__)


#: The design criteria.
CRITERIA = ("d", "a", "decision")

#: Regularization of log det and inverses of the scaled information matrices (a direction
#: with less information than this, relative to the whole candidate set, counts as none).
INFORMATION_EPS = 1e-9

#: Bands of the information (common to every candidate) and the design band [Hz].
DEFAULT_BAND_HZ = (0.5, 20.0)


@dataclass(frozen=True)
class InformationOptions:
    """The information a design's criterion sums: bands, design bands, noise.

    Parameters
    ----------
    n_bands : int
        Log-spaced bands over `band_hz` the criterion sums over.
    n_design_bands : int
        Groups of adjacent bands in the relaxed problem.
    band_hz : (float, float)
        The design band [Hz].
    noise : float
        Output noise as a fraction of each output's RMS, white (a known model).

    Raises
    ------
    ValueError
        If `n_design_bands` exceeds `n_bands` or a count is below 1.
    """

    n_bands: int = 96
    n_design_bands: int = 12
    band_hz: tuple = DEFAULT_BAND_HZ
    noise: float = 0.02

    def __post_init__(self):
        if not (1 <= int(self.n_design_bands) <= int(self.n_bands)):
            raise ValueError(f"InformationOptions: n_design_bands={self.n_design_bands} must "
                             f"be between 1 and n_bands={self.n_bands}")


def drive_maker(vehicle, session):
    """kind -> function(duration_s, seed, name) -> Drive, sized like the session's inputs (an
    identified model) or the paper's plan on the vehicle (a known one)."""
    fs = session.fs_hz if session is not None else 100.0
    if session is not None:
        ref = session.runs[0]
        rms = {c: float(np.std(ref.dynamic(c))) for c in RIG_INPUTS}
        peak = {c: float(np.max(np.abs(ref.dynamic(c)))) for c in RIG_INPUTS}
    else:
        paper = make_plan_drive(default_plan(), vehicle, seed=0, duration_s=60.0)
        rms = {c: float(np.std(paper.channels[c])) for c in RIG_INPUTS}
        peak = {c: float(np.max(np.abs(paper.channels[c]))) for c in RIG_INPUTS}
    wheelbase = vehicle.a_m + vehicle.b_m if vehicle is not None else 2.794
    track = vehicle.track_front_m if vehicle is not None else 1.778

    def make(kind, duration_s, seed, name):
        if kind == "noise":
            return drv.make_noise_drive(duration_s=duration_s, fs_hz=fs, peak=peak, seed=seed,
                                        name=name)
        if kind == "multisine":
            return drv.make_multisine_drive(duration_s=duration_s, fs_hz=fs, rms=rms, seed=seed,
                                            f_min_hz=0.3, f_max_hz=25.0, name=name)
        if kind == "sweep":
            amp = {c: np.sqrt(2) * rms[c] for c in RIG_INPUTS[3:]}
            return drv.make_sweep_drive(duration_s=duration_s, fs_hz=fs, amplitude=amp,
                                        f_start_hz=0.5, f_stop_hz=25.0, name=name)
        return drv.make_track_drive(duration_s=duration_s, fs_hz=fs, seed=seed,
                                    wheelbase_m=wheelbase, track_width_m=track, name=name)

    return make


def _band_power(x, fs, edges, weight=None):
    """Cross-power of channels `x` (n_ch, N) in bands (scipy's ``conj(X_i) X_j``): the
    cross-spectral density at each band's centre (interpolated between Welch lines, so
    bands narrower than the resolution still get their share) times the band's width,
    optionally weighted by ``weight(f_c)``. Returns ``(f_c (n_b,), S (n_b, n_ch, n_ch))``."""
    nperseg = int(min(x.shape[1], 2 ** round(np.log2(20 * fs))))
    f, P = signal.csd(x[:, None, :], x[None, :, :], fs=fs, window="hann", nperseg=nperseg,
                      axis=-1)
    f_c = np.sqrt(edges[:-1] * edges[1:])
    j = np.clip(np.searchsorted(f, f_c) - 1, 0, f.size - 2)
    t = (f_c - f[j]) / (f[j + 1] - f[j])
    dens = P[:, :, j] * (1 - t) + P[:, :, j + 1] * t  # (n_ch, n_ch, n_b)
    wt = np.diff(edges) * (1.0 if weight is None else np.asarray(weight(f_c), dtype=float))
    return f_c, np.moveaxis(dens * wt, -1, 0)


def _linearized(plant, bands_fb, S_b, models):
    """Equivalent damping per setup and corner at the velocity the setup sees on a drive."""
    bands = DriveBands(f_hz=bands_fb, S=S_b, SB=S_b, fs_hz=100.0, band_hz=(1.0, 20.0),
                       drive_name="design")
    H = plant.frequency_response(bands_fb)
    _, _, sig, _ = screen_response(H, plant.output_names, plant.cbar_n_s_m, bands, models)
    return sig


def _third_damping(entries, Hvs, Hvr, S, Dc, w):
    """The corners' damping matrix of a setup's third dampers, linearized (nb, 4, 4).

    Each damper ``e`` (row ``m_e``, :class:`ident.sim.loop_third.ThirdDamper`) adds
    ``c_e m_e m_e^T / (1 + j w lag_e)`` (its force ``m_e F_e`` at the corners, as the
    identification puts it into the corner inputs), ``c_e`` its equivalent damping at the
    element's velocity RMS (``m_e @ v``, ``v`` through the loop of the corner shocks
    alone: a stochastic linearization as :mod:`planner.screen`'s).
    """
    nb = Dc.shape[0]
    out = np.zeros((nb, 4, 4), dtype=complex)
    dampers = [d for d in entries if d.model is not None]
    if not dampers:
        return out
    V = np.linalg.inv(np.eye(4)[None] - Hvs * Dc[:, None, :]) @ Hvr  # (nb, 4, 7)
    # scipy's S[i, j] = E[conj(U_i) U_j]: v v^H is V S^T V^H
    Svv = V @ np.transpose(S, (0, 2, 1)) @ np.conj(np.transpose(V, (0, 2, 1)))
    for d in dampers:
        m = np.asarray(d.row, dtype=float)
        sig = float(np.sqrt(max(np.real(np.einsum("i,kij,j->", m, Svv, m)), 0.0)))
        ceq = float(d.model.equivalent_damping(sig))
        out += (ceq / (1 + 1j * w * d.model.lag_s))[:, None, None] * np.outer(m, m)[None]
    return out


def candidate_information(plant, setups, kinds, drive_of, library, edges, f_c, third=None,
                          third_reference=None):
    """Information per second of every (setup, kind): (n_setups, n_kinds, n_b, 11, 11), the
    drives' band power (n_kinds, n_b, 7, 7) and the linearized damping.

    With third elements (`third`: :class:`planner.elements.SetupThird` of `setups`, issue
    38) the corner inputs' force deviation is the shocks' and the third dampers' at the
    corners (``sum_e m_e F_e``, as :func:`ident.identify.frf.third_force_deviation` puts it
    in), less `third_reference` (4, 4) [N s/m] (the linear part the identification takes
    off: :func:`ident.identify.frf.third_linear_damping`; default none): the corners'
    damping deviation is then a full matrix, and a run that changes a heave damper varies
    the corner inputs along ``m_e`` (one direction of Eq. 17's rank). The heave springs'
    contact is left out (a gap the car rests clear of)."""
    nb = edges.size - 1
    H = plant.frequency_response(f_c)  # (p, 11, nb)
    vi = plant.velocity_idx
    Hvr = np.transpose(H[vi, :7], (2, 0, 1))  # (nb, 4, 7)
    Hvs = np.transpose(H[vi, 7:], (2, 0, 1))  # (nb, 4, 4)
    cbar = plant.cbar_n_s_m
    w = 2 * np.pi * f_c
    info = np.zeros((len(setups), len(kinds), nb, 11, 11), dtype=complex)
    powers = []
    for j, kind in enumerate(kinds):
        d = drive_of[kind]
        _, S = _band_power(np.vstack([d.channels[c] - d.channels[c].mean() for c in RIG_INPUTS]),
                           d.fs_hz, edges)
        S_rate = S / 1.0  # band power: a run of T seconds carries T * S
        powers.append(S_rate)
        models = [s.resolve(library) for s in setups]
        sig = _linearized(plant, f_c, S, models)
        for i, mods in enumerate(models):
            ceq = np.array([m.equivalent_damping(sig[i, c]) for c, m in enumerate(mods)])
            lag = np.array([m.lag_s for m in mods])
            Dc = ceq[None, :] / (1 + 1j * w[:, None] * lag[None, :]) - cbar[None, :]  # (nb, 4)
            if third is None:
                K = np.linalg.inv(np.eye(4)[None] - Hvs * Dc[:, None, :])
                A = Dc[:, :, None] * (K @ Hvr)  # (nb, 4, 7)
            else:  # the corners' damping deviation, a full matrix with the third dampers
                D = np.eye(4)[None] * Dc[:, None, :] + _third_damping(
                    third.entries[i][0], Hvs, Hvr, S, Dc, w)
                K = np.linalg.inv(np.eye(4)[None] - Hvs @ D)
                if third_reference is not None:
                    D = D - np.asarray(third_reference, dtype=float)[None]
                A = D @ (K @ Hvr)
            G = np.concatenate([np.broadcast_to(np.eye(7), (nb, 7, 7)), A], axis=1)  # (nb,11,7)
            # scipy's S[i, j] = E[conj(U_i) U_j]; the regressors' x x^H is G S^T G^H
            info[i, j] = G @ np.transpose(S, (0, 2, 1)) @ np.conj(np.transpose(G, (0, 2, 1)))
    return info, np.array(powers)


def session_information(session, cbar, edges):
    """The recorded runs' own information: sum over runs of ``T * S_xx`` of their measured
    ``[u_rig, dF]`` (with the third elements' force, as the FRF estimate has it), shape
    (n_b, 11, 11)."""
    nb = edges.size - 1
    M = np.zeros((nb, 11, 11), dtype=complex)
    for run in session.runs:
        _, dF = shock_force_deviation(run, session.shocks, cbar)
        third = third_force_deviation(session, run)
        if third is not None:  # the third elements' force: part of the corners' inputs
            dF = dF + third
        x = np.vstack([np.vstack([run.dynamic(c) for c in RIG_INPUTS]), dF])
        _, S = _band_power(x, session.fs_hz, edges)
        M += run.n_samples / session.fs_hz * np.transpose(S, (0, 2, 1))
    return M


def hermitian(M):
    """The Hermitian part of square matrices, ``(M + M^H) / 2`` over the last two axes.

    Parameters
    ----------
    M : ndarray, shape (..., n, n), complex or real

    Returns
    -------
    ndarray, shape (..., n, n)
    """
    return 0.5 * (M + np.conj(np.swapaxes(M, -1, -2)))


def criterion_value(M, criterion, W=None):
    """The criterion of scaled information matrices (larger is better), summed over bands.

    Parameters
    ----------
    M : ndarray, shape (n_b, 11, 11)
        Hermitian information per band (scaled).
    criterion : {"d", "a", "decision"}
    W : ndarray, shape (n_b, 11, 11), optional
        The decision weights (``decision`` only).

    Returns
    -------
    float
        ``sum log det M`` (d), ``-sum tr M^-1`` (a), ``-sum tr W M^-1`` (decision), each
        with ``M + eps I``.
    """
    Mr = hermitian(M) + INFORMATION_EPS * np.eye(M.shape[-1])
    if criterion == "d":
        sign, logdet = np.linalg.slogdet(Mr)
        return float(np.sum(logdet))
    inv = np.linalg.inv(Mr)
    if criterion == "a":
        return -float(np.real(np.einsum("kii->", inv)))
    return -float(np.real(np.einsum("kij,kji->", W, inv)))


def _score_gradients(H, out_names, cbar, f_c, SB, models, sig, objective, m_base,
                     return_scores=False):
    """Gradient of each setup's score with respect to the FRF, per band (screening's
    linearized loop, differentiated analytically).

    ``dP_j = 2 Re sum_{o,i} g_j[o, i] dH[o, i]`` per band for the metric power ``P_j``;
    the score ``s = sum_j w_j m_j / m_b,j`` with ``m_j = sqrt(P_j)``.

    Returns
    -------
    grads : ndarray of complex, shape (n_setups, n_b, n_out, 11)
    scores : ndarray, shape (n_setups,)
        With `return_scores`: the scores themselves (the linearization frozen at `sig`).
    """
    names, L = metric_rows(SimpleNamespace(output_names=list(out_names)))
    w = np.array([objective.weights.get(n, 0.0) for n in names])
    mb = np.array([m_base.get(n, np.nan) for n in names])
    keep = w > 0
    names, L, w, mb = [n for n, k in zip(names, keep) if k], L[keep], w[keep], mb[keep]
    vi = [list(out_names).index(f"shock_velocity_{c}") for c in CORNERS]
    p, nb = H.shape[0], f_c.size
    om = 2 * np.pi * f_c
    out = np.zeros((len(models), nb, p, 11), dtype=complex)
    scores = np.zeros(len(models))
    for s, mods in enumerate(models):
        ceq = np.array([m.equivalent_damping(sig[s, c]) for c, m in enumerate(mods)])
        lag = np.array([m.lag_s for m in mods])
        Dc = ceq[None, :] / (1 + 1j * om[:, None] * lag[None, :]) - cbar[None, :]
        P = np.zeros(len(names))
        parts = []
        for k in range(nb):
            Hr, Hs = H[:, :7, k], H[:, 7:, k]
            Hvr, Hvs = Hr[vi], Hs[vi]
            D = np.diag(Dc[k])
            K = np.linalg.inv(np.eye(4) - Hvs @ D)
            A = D @ K @ Hvr  # (4, 7)
            B = L @ Hs @ D @ K  # (m, 4)
            Ty = L @ Hr + B @ Hvr  # (m, 7)
            Sk = SB[k].T  # E[u u^H]
            P += np.real(np.einsum("mi,ij,mj->m", Ty, Sk, np.conj(Ty)))
            parts.append((Sk, Ty, A, B))
        m = np.sqrt(np.maximum(P, 1e-300))
        scores[s] = float(np.sum(w * m / mb))
        coef = w / mb / (2 * m)  # ds/dP_j
        for k, (Sk, Ty, A, B) in enumerate(parts):
            # dP_j = 2 Re tr(Q_j dTy) with Q_j = Sk^T... in the Wirtinger sense; combine over j
            Q = (np.conj(Ty) * coef[:, None]) @ Sk.T  # (m, 7): sum_j coef_j conj(Ty_j) Sk^T
            Q = Q.T  # (7, m)
            g = np.zeros((p, 11), dtype=complex)
            g[:, :7] += (Q @ L).T  # dTy = L dHr
            g[:, 7:] += (A @ Q @ L).T  # dTy = L dHs A
            gv = (A @ Q @ B).T  # dTy = B dHvs A  (rows vi of dHs)
            for r, o in enumerate(vi):
                g[o, 7:] += gv[r]
            gr = (Q @ B).T  # dTy = B dHvr
            for r, o in enumerate(vi):
                g[o, :7] += gr[r]
            out[s, k] = g
    return (out, scores) if return_scores else out


def _decision_weights(grads, scores, noise_var, top_pairs):
    """``W_k = sum_pairs 2 sum_o sigma_o^2 conj(g_ab) g_ab^T / (s_a - s_b)^2``, (n_b, 11, 11)."""
    nb = grads.shape[1]
    W = np.zeros((nb, 11, 11), dtype=complex)
    for a, b in top_pairs:
        d = scores[a] - scores[b]
        wt = 1.0 / max(d * d, 1e-8)
        g = grads[a] - grads[b]  # (nb, p, 11)
        # with M = sum x x^H the row's covariance is sigma^2 conj(M)^-1, and
        # var(2 Re g^T dh) = 2 sigma^2 g^T conj(M)^-1 conj(g) = tr(W M^-1), W = 2 sigma^2 g g^H
        W += 2 * wt * np.einsum("kp,kpi,kpj->kij", noise_var, g, np.conj(g))
    return hermitian(W)


def _noise_variance(plant, frf, f_c, edges, M0, S_ref, noise):
    """Each output's noise power per band, (n_b, n_out): from the identified FRF's standard
    errors and the session's information, or `noise` of each output's RMS, white."""
    p = len(plant.output_names)
    if frf is not None:
        sig = interpolate(frf.f_hz, frf_standard_error(frf), f_c)  # (p, 11, nb)
        order = [list(frf.output_names).index(o) for o in plant.output_names]
        sig = sig[order]
        C = np.linalg.inv(np.conj(hermitian(M0)) + INFORMATION_EPS * np.eye(11) * np.abs(
            np.einsum("kii->k", M0)).max())
        cd = np.real(np.einsum("kii->ki", C))  # (nb, 11)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.isfinite(sig), sig**2, np.nan) / cd.T[None, :, :]
        var = np.nanmedian(ratio, axis=1).T  # (nb, p)
        return np.nan_to_num(var, nan=0.0, posinf=0.0)
    H = plant.frequency_response(f_c)
    y = np.real(np.einsum("pik,kij,pjk->kp", H[:, :7], np.transpose(S_ref, (0, 2, 1)),
                          np.conj(H[:, :7])))  # output power per band (rig part)
    total = y.sum(axis=0)  # (p,)
    bw = np.diff(edges) / (edges[-1] - edges[0])
    return (noise**2) * total[None, :] * bw[:, None]


def decision_weight_matrices(plant, ident_model, library, base, objective, drive, f_c, edges,
                             M0, S_ref, noise, top):
    """The decision criterion's weights (unscaled): the top contenders' score differences."""
    pool = [base] + [s for s in enumerate_setups(library) if s.ids() != base.ids()]
    sc = screen_setups(plant, drive, pool, library)
    scores = score_setups(sc.table, objective, baseline=base.name).table
    ranked = scores[scores["feasible"]].sort_values("rank").index[:top].tolist()
    idx = [list(sc.table.index).index(n) for n in ranked]
    sig = sc.diagnostics["shock_velocity_rms_linearized"][idx]
    models = [pool[i].resolve(library) for i in idx]
    sos = signal.butter(4, (1.0, 20.0), "bandpass", fs=drive.fs_hz, output="sos")

    def b4(f_hz):
        return np.abs(signal.sosfreqz(sos, worN=f_hz, fs=drive.fs_hz)[1]) ** 4

    _, SB = _band_power(np.vstack([drive.channels[c] - drive.channels[c].mean()
                                   for c in RIG_INPUTS]), drive.fs_hz, edges, weight=b4)
    H = plant.frequency_response(f_c)
    m_base = sc.table.loc[base.name].to_dict()
    grads = _score_gradients(H, plant.output_names, plant.cbar_n_s_m, f_c, SB, models, sig,
                             objective, m_base)
    frf = getattr(ident_model, "frf", None)
    noise_var = _noise_variance(plant, frf, f_c, edges, M0, S_ref, noise)
    s = scores.loc[ranked, "score"].to_numpy()
    pairs = decision_pairs(ident_model, drive, [pool[i] for i in idx], base, sc.table, library,
                           objective)
    return _decision_weights(grads, s, noise_var, pairs)


#: Monte Carlo draws of the decision criterion's difference intervals (screening only).
DECISION_DRAWS = 20


def decision_pairs(ident_model, drive, contenders, base, metrics, library, objective):
    """The pairs of contenders the decision criterion weighs: those the model does not resolve.

    With an identified model (its FRF), the pairs whose score difference's interval contains
    0 (:func:`planner.uncertainty.unresolved_pairs` on the screening's metrics,
    :data:`DECISION_DRAWS` draws); where the model resolves every pair, or for a known
    model (before rig day: no estimation error to judge), every pair.

    Parameters
    ----------
    ident_model : ident.identify.model.VehicleModel or None
    drive : ident.data.drive.Drive
    contenders : list of planner.setups.Setup
        Best first.
    base : planner.setups.Setup
        The baseline (a row of `metrics`).
    metrics : pandas.DataFrame
        The screening's metrics (SI), indexed by setup name.
    library : ident.models.library.ShockLibrary
    objective : planner.objective.Objective

    Returns
    -------
    list of (int, int)
        Index pairs into `contenders`.
    """
    every = list(itertools.combinations(range(len(contenders)), 2))
    if getattr(ident_model, "frf", None) is None or len(contenders) < 2:
        return every
    setups = [base] + [c for c in contenders if c.name != base.name]
    unc = prediction_uncertainty(ident_model, drive, setups, library,
                                 draws=UncertaintyOptions(n_draws=DECISION_DRAWS))
    table = metrics.loc[[c.name for c in setups]]
    errors = score_errors(table, unc, objective, baseline=base.name)
    open_ = unresolved_pairs(table, unc, objective, baseline=base.name, errors=errors)
    names = [c.name for c in contenders]
    pairs = [(a, b) for a, b in every if names[b] in open_.get(names[a], [])]
    if not pairs:
        log.info("design: the model resolves every pair of the %d contenders; the decision "
                 "criterion weighs them all", len(contenders))
        return every
    log.info("design: %d of %d contender pairs are not resolved (their score difference's "
             "interval contains 0); the decision criterion weighs those", len(pairs),
             len(every))
    return pairs
