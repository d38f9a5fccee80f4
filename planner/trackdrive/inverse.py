"""The inverse of the rig-plus-car frequency response, regularized where it is ill-conditioned.

The rig inputs a drive may change (the wheelloaders) move the target channels through the
closed loop of the model and the track setup's shocks, linearized: a shock of curve ``f``
and lag ``tau`` at a Gaussian velocity of RMS ``sigma`` acts as ``c(omega) = c_eq(sigma) /
(1 + j omega tau)`` (``c_eq = E[f'(v)]``, the stochastic linearization the screening uses).
With the plant written around ``c_bar`` (``y = H_rig u + H_shock dF``, ``dF = (c - c_bar)
v``), the closed-loop response of targets ``T`` to inputs ``u`` is::

    G = H_rig[T] + H_shock[T] dC (I - H_shock[V] dC)^-1 H_rig[V],   dC = diag(c - c_bar)

(``V`` the shock velocities), per frequency (:func:`loop_frf`).

The inverse (:func:`regularized_inverse`) solves, per frequency, the weighted Tikhonov
problem ``min |W (G u - y)|^2 + lambda |u|^2`` with ``W`` = one over each target channel's
RMS (so that a travel, a ride height and an acceleration count alike), times the square root
of that output's multiple coherence in the identification where the model has it
(:func:`coherence_weights`: where the model was estimated poorly it is trusted less), and
``lambda =
(alpha sigma_max)^2`` relative to the largest singular value of ``W G`` at that frequency:
directions the rig moves the targets less than ``alpha`` times its best direction are not
inverted (where the model is ill-conditioned: common heave of the pads at low frequency,
which moves no travel, or frequencies where a target channel barely responds). What the
regularized inverse cannot reach is reported as the target's share outside the rig inputs'
reach (:func:`reach_shares`).
"""

from __future__ import annotations

import logging

import numpy as np

from ident.data.channels import RIG_INPUTS, SHOCK_VELOCITIES
from planner.errors import PlannerError

__all__ = [
    "loop_frf",
    "open_loop_parts",
    "close_loop",
    "shock_linearization",
    "regularized_inverse",
    "reach_shares",
    "coherence_weights",
    "COHERENCE_FLOOR",
    "DEFAULT_ALPHA",
    "UNREACHABLE_RTOL",
]

log = logging.getLogger(__name__)

#: Default relative regularization: directions below 3 % of the best one at a frequency
#: are not inverted (2 % sensor noise on a target would be amplified 30x there). Measured
#: on the GT-like car identified from 100 s runs, a 120 s track logged at 2 % noise: 0.01,
#: 0.03, 0.1 and 0.3 give the known car's residual 4.43 / 4.38 / 4.39 / 4.36 % and the
#: crate's metrics 1.18 / 1.17 / 1.14 / 1.14 % median: the choice hardly matters there.
DEFAULT_ALPHA = 0.03
#: A target channel whose weighted response to the drive's inputs stays below this share
#: of the largest, at every frequency of the band, cannot be reached at all.
UNREACHABLE_RTOL = 1e-6
#: Smallest coherence a target row is weighted by (:func:`coherence_weights`): at 0.05 a
#: row counts 4.5x less than a perfectly estimated one, never nothing.
COHERENCE_FLOOR = 0.05
#: Frequencies per chunk when evaluating the plant's modal response (memory bound).
_CHUNK = 2048


def _modal_rows(modal, rows, inputs, f_hz):
    """``H[rows, inputs, f]`` of a :class:`ident.models.lti.ModalSystem`, in chunks."""
    sub = modal.select(outputs=np.asarray(rows), inputs=None if inputs is None
                       else np.asarray(inputs))
    out = np.empty((len(rows), sub.B.shape[1], f_hz.size), complex)
    for a in range(0, f_hz.size, _CHUNK):
        out[:, :, a:a + _CHUNK] = sub.frequency_response(f_hz[a:a + _CHUNK])
    return out


def open_loop_parts(plant, f_hz, *, outputs, inputs):
    """The plant's open-loop responses the loop needs, at `f_hz`.

    Parameters
    ----------
    plant : ident.models.lti.LoopPlant
    f_hz : ndarray, shape (n_f,)
        Frequencies [Hz].
    outputs : sequence of str
        Target channels (plant outputs).
    inputs : sequence of str
        Rig inputs (of ``ident.data.channels.RIG_INPUTS``).

    Returns
    -------
    dict
        ``rig_t`` (n_t, n_in, n_f), ``shock_t`` (n_t, 4, n_f), ``rig_v`` (4, n_in, n_f),
        ``shock_v`` (4, 4, n_f), ``c_bar`` (4,) [N/(m/s)], ``f_hz``.
    """
    f_hz = np.asarray(f_hz, float)
    t_idx = [plant.output_names.index(o) for o in outputs]
    v_idx = [plant.output_names.index(v) for v in SHOCK_VELOCITIES]
    in_idx = [RIG_INPUTS.index(i) for i in inputs]
    return {"rig_t": _modal_rows(plant.rig, t_idx, in_idx, f_hz),
            "shock_t": _modal_rows(plant.shock, t_idx, None, f_hz),
            "rig_v": _modal_rows(plant.rig, v_idx, in_idx, f_hz),
            "shock_v": _modal_rows(plant.shock, v_idx, None, f_hz),
            "c_bar": np.asarray(plant.cbar_n_s_m, float), "f_hz": f_hz}


def close_loop(parts, c_eq_n_s_m, lag_s):
    """The closed-loop response ``G[target, input, f]`` with the shocks linearized.

    Parameters
    ----------
    parts : dict
        From :func:`open_loop_parts`.
    c_eq_n_s_m : array_like, shape (4,)
        Each corner's equivalent damping [N/(m/s)].
    lag_s : array_like, shape (4,)
        Each corner's shock lag [s].

    Returns
    -------
    ndarray, shape (n_t, n_in, n_f)
    """
    w = 2 * np.pi * parts["f_hz"]
    c = np.asarray(c_eq_n_s_m, float)[:, None] / (1 + 1j * w[None, :] * np.asarray(lag_s, float)[:, None])
    dc = c - parts["c_bar"][:, None]                                        # (4, n_f)
    hv = np.moveaxis(parts["shock_v"], -1, 0) * dc.T[:, None, :]            # (n_f, 4, 4)
    m = np.eye(4)[None] - hv
    rv = np.moveaxis(parts["rig_v"], -1, 0)                                 # (n_f, 4, n_in)
    v = np.linalg.solve(m, rv)                                              # (n_f, 4, n_in)
    st = np.moveaxis(parts["shock_t"], -1, 0) * dc.T[:, None, :]            # (n_f, n_t, 4)
    g = np.moveaxis(parts["rig_t"], -1, 0) + st @ v
    return np.moveaxis(g, 0, -1)


def loop_frf(plant, f_hz, *, outputs, inputs, c_eq_n_s_m, lag_s):
    """Closed-loop response of `outputs` to rig `inputs` with linearized shocks (see the
    module docstring); shape (n_outputs, n_inputs, n_f)."""
    return close_loop(open_loop_parts(plant, f_hz, outputs=outputs, inputs=inputs),
                      c_eq_n_s_m, lag_s)


def shock_linearization(shocks, v_rms_m_s):
    """Equivalent damping and lag of a setup's four shocks at given velocity levels.

    Parameters
    ----------
    shocks : sequence of 4 shock models
        With ``equivalent_damping(v_rms)`` and ``lag_s`` (:mod:`ident.models.shocks`).
    v_rms_m_s : array_like, shape (4,)
        RMS shock velocity at each corner [m/s].

    Returns
    -------
    c_eq : ndarray, shape (4,)
        [N/(m/s)].
    lag : ndarray, shape (4,)
        [s].
    """
    v = np.maximum(np.asarray(v_rms_m_s, float), 1e-4)
    c = np.array([float(s.equivalent_damping(x)) for s, x in zip(shocks, v)])
    lag = np.array([float(getattr(s, "lag_s", 0.0) or 0.0) for s in shocks])
    return c, lag


def regularized_inverse(g, weights, *, alpha=DEFAULT_ALPHA, names=None, where="drive"):
    """The weighted, Tikhonov-regularized inverse of ``G`` per frequency.

    Parameters
    ----------
    g : ndarray, shape (n_t, n_in, n_f)
        Closed-loop response of the targets to the free inputs.
    weights : array_like, shape (n_t,) or (n_t, n_f)
        One over each target channel's RMS [1/unit], optionally times a trust per frequency
        (:func:`coherence_weights`).
    alpha : float
        Relative regularization (``lambda = (alpha sigma_max)^2`` per frequency).
    names : sequence of str, optional
        The target channels, for the refusal of one that cannot be reached.
    where : str
        Who asks, first in messages.

    Returns
    -------
    ginv : ndarray, shape (n_in, n_t, n_f)
        ``u = ginv @ y`` per frequency (the weights included).
    gain : ndarray, shape (n_t, n_t, n_f)
        ``W G ginv``: the share of a (weighted) target the regularized drive reaches.

    Raises
    ------
    PlannerError
        If a target channel does not respond to the inputs at any frequency (relative
        :data:`UNREACHABLE_RTOL`): the model cannot reach it at all.
    """
    if not np.isfinite(alpha) or alpha <= 0:
        raise PlannerError(f"{where}: the regularization alpha = {alpha!r} must be > 0")
    w = np.asarray(weights, float)
    w = np.broadcast_to(w[:, None] if w.ndim == 1 else w, g.shape[:1] + g.shape[2:]).T  # (n_f, n_t)
    a = np.moveaxis(g, -1, 0) * w[:, :, None]                          # (n_f, n_t, n_in)
    row = np.abs(a).max(axis=(0, 2))
    dead = row <= UNREACHABLE_RTOL * max(row.max(), 1e-300)
    if dead.any():
        bad = [names[i] if names is not None else str(i) for i in np.flatnonzero(dead)]
        raise PlannerError(f"{where}: the model cannot reach {bad} at all: no rig input the "
                           "drive can change moves it in the band; leave it out of the "
                           "targets, or identify a model whose response includes it")
    u, s, vh = np.linalg.svd(a, full_matrices=False)                  # (n_f,n_t,k),(n_f,k),(n_f,k,n_in)
    lam = (alpha * s[:, :1]) ** 2
    d = s / (s * s + lam)                                              # (n_f, k)
    uh = np.conj(np.swapaxes(u, 1, 2)) * w[:, None, :]                # (n_f, k, n_t)
    ginv = np.conj(np.swapaxes(vh, 1, 2)) @ (d[:, :, None] * uh)      # (n_f, n_in, n_t)
    gain = u @ ((s * d)[:, :, None] * np.conj(np.swapaxes(u, 1, 2)))  # (n_f, n_t, n_t)
    return np.moveaxis(ginv, 0, -1), np.moveaxis(gain, 0, -1)


def coherence_weights(model, names, f_hz, *, floor=COHERENCE_FLOOR):
    """How far to trust each target row of an identified model, per frequency.

    Parameters
    ----------
    model : object
        An identified model with ``frf`` (its conditioned FRF, with ``multiple_coherence``
        per output and ``f_hz``); any other model gives None.
    names : sequence of str
        The target channels (model outputs).
    f_hz : ndarray, shape (n_f,)
        Frequencies [Hz].
    floor : float
        Smallest coherence taken (a row is never dropped altogether).

    Returns
    -------
    ndarray, shape (n_t, n_f) or None
        ``sqrt(max(gamma^2, floor))``: the multiple coherence of each target output in the
        identification (the share of its power the inputs explained), interpolated onto
        `f_hz` (held beyond the FRF's ends). A row the model estimated poorly at some
        frequency counts less in the inverse there: the paper's own reading of coherence
        as where to trust the estimate.
    """
    frf = getattr(model, "frf", None)
    if frf is None or getattr(frf, "multiple_coherence", None) is None:
        return None
    out = np.ones((len(names), np.size(f_hz)))
    for i, c in enumerate(names):
        if c not in frf.output_names:
            continue
        gamma2 = np.asarray(frf.multiple_coherence[frf.output_names.index(c)], float)
        out[i] = np.sqrt(np.clip(np.interp(f_hz, frf.f_hz, gamma2), floor, 1.0))
    return out


def reach_shares(gain, y_weighted):
    """Each target channel's share of power (over the given frequencies) the drive cannot
    reach.

    Parameters
    ----------
    gain : ndarray, shape (n_t, n_t, n_f)
        From :func:`regularized_inverse`.
    y_weighted : ndarray, shape (n_t, n_f)
        The weighted target's spectrum at those frequencies.

    Returns
    -------
    ndarray, shape (n_t,)
        ``sum |y - gain y|^2 / sum |y|^2`` per channel (0: all reachable).
    """
    reached = np.einsum("ijf,jf->if", gain, y_weighted)
    miss = np.sum(np.abs(y_weighted - reached) ** 2, axis=1)
    total = np.sum(np.abs(y_weighted) ** 2, axis=1)
    return np.where(total > 0, miss / np.where(total > 0, total, 1.0), 0.0)
