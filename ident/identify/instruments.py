"""Instrumental variables for the shock-force inputs: an LPM free of errors in variables.

The inputs ``dF = F - c_bar v`` of the multi-input estimate (:mod:`ident.identify.frf`)
are computed from measured channels, so they carry the force and velocity sensors' noise
``n_F - c_bar n_v``; least squares on a noisy regressor is biased (errors in variables):
toward zero by the noise's share of ``dF``'s power, and, for the outputs that share a
sensor with ``dF`` (the shock velocities: ``n_v``), by the cross-power ``-c_bar S_nv``.
On a car with third elements the heave and roll dampers' linear part ``sum_e c_e m_e m_e^T
v`` is taken off at the measured shock velocities too, so ``n_v`` enters the inputs of
every corner of an axle in every run, not only the swapped corners'.

An instrumental-variable (IV) estimate removes both: ``theta = (Z^H A)^-1 Z^H B`` with
instruments ``Z`` correlated with the true inputs and independent of every noise of the
equation (the output's and the regressor's). :func:`travel_run` builds a second version
of a run's shock-force inputs from other sensors: the corners' velocity differentiated
from their shock travel (:func:`travel_velocity`), every force from its library curve at
that velocity (never a load cell), the third elements' velocities from their travel
channels (else the corners'), the heave springs from their travel. The two versions share
no sensor except the travel (corner bump stops and heave springs without load cells are
functions of a travel in both: their force is small and rare). Per output row
(:func:`iv_lpm_solve`): rows whose noise is in the travel-derived version (the shock
travels) are regressed on it with the measured version as instrument; every other row on
the measured version with the travel-derived one as instrument.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ident.data.channels import CORNERS
from ident.data.third import THIRD_CHANNELS
from ident.errors import IdentificationError

__all__ = ["session_instruments", "travel_velocity", "travel_run", "travel_rows", "iv_lpm_solve", "travel_from_velocity",
           "TRAVELS"]

#: The corner travel channels the instruments are derived from.
TRAVELS = tuple(f"shock_travel_{c}" for c in CORNERS)


def session_instruments(session, instruments=None, *, estimator="lpm"):
    """Whether a session is estimated with the travel-derived instruments.

    Parameters
    ----------
    session : ident.data.session.Session
    instruments : bool or None
        None ("auto"): on for a session that declares third elements and records
        ``shock_travel_XX`` at every corner in every run, with the LPM; off otherwise (a
        plain session identifies as before). True: on (refused without the travels or
        with the Welch estimator); False: off.
    estimator : str

    Returns
    -------
    bool

    Raises
    ------
    IdentificationError
        True for a session without every corner's travel, or with ``estimator="welch"``.
    """
    has_travel = all(t in r.channels for r in session.runs for t in TRAVELS)
    if instruments is None:
        return bool(getattr(session, "third_elements", None)) and has_travel \
            and estimator == "lpm"
    if not instruments:
        return False
    if estimator != "lpm":
        raise IdentificationError(
            f"instruments=True needs estimator='lpm' (got {estimator!r}): use the LPM or "
            "instruments=False (shockplan identify: --instruments off)")
    if not has_travel:
        raise IdentificationError(
            f"session '{session.name}': instruments=True derives the instruments from the "
            f"shock travels, but not every run records {', '.join(TRAVELS)}: record them, "
            "or use instruments=False (shockplan identify: --instruments off)")
    return True


def travel_velocity(x, fs_hz):
    """The velocity of a travel record, differentiated in the frequency domain.

    The band-limited derivative ``irfft(j 2 pi f rfft(x))`` of the record with its mean
    removed (the Nyquist line dropped): exact in band for a record that starts and ends at
    rest (the rig's tapered drives), without the finite difference's loss of gain (a
    central difference is 24 % low at 20 Hz at 100 Hz).

    Parameters
    ----------
    x : ndarray, shape (n_samples,)
        Travel [m].
    fs_hz : float

    Returns
    -------
    ndarray, shape (n_samples,)
        [m/s]

    Examples
    --------
    >>> t = np.arange(1000) / 100.0
    >>> v = travel_velocity(np.sin(2 * np.pi * 2.0 * t), 100.0)
    >>> bool(np.allclose(v, 2 * np.pi * 2.0 * np.cos(2 * np.pi * 2.0 * t)))
    True
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    X = np.fft.rfft(x - x.mean())
    w = 2j * np.pi * np.fft.rfftfreq(n, 1.0 / fs_hz)
    if n % 2 == 0:
        w[-1] = 0.0
    return np.fft.irfft(w * X, n)


def travel_run(run):
    """The run as the instruments see it: velocities from travels, no load cell.

    ``shock_velocity_XX`` replaced by :func:`travel_velocity` of ``shock_travel_XX``; the
    shock and third-element load cells (``shock_force_XX``, ``heave_force_<axle>``,
    ``heave_spring_force_<axle>``, ``roll_force_<axle>``) dropped, so that the forces are
    computed from the library's curves; a third element's velocity channel replaced by
    the derivative of its travel channel where recorded, else dropped (its velocity is
    then ``m_e @ v`` of the travel-derived corner velocities).

    Parameters
    ----------
    run : ident.data.session.Run
        With ``shock_travel_XX`` at every corner.

    Returns
    -------
    ident.data.session.Run
    """
    ch = {k: v for k, v in run.channels.items()
          if not k.startswith("shock_force_") and not (k in THIRD_CHANNELS and (
              "_force_" in k or "_velocity_" in k))}
    for c in CORNERS:
        ch[f"shock_velocity_{c}"] = travel_velocity(run.channels[f"shock_travel_{c}"],
                                                    run.fs_hz)
    for k in THIRD_CHANNELS:
        if "_velocity_" in k and k.replace("_velocity_", "_travel_") in run.channels:
            ch[k] = travel_velocity(run.channels[k.replace("_velocity_", "_travel_")],
                                    run.fs_hz)
    return dataclasses.replace(run, channels=ch)


def travel_rows(outputs):
    """Boolean mask of the outputs whose noise is in the travel-derived inputs."""
    return np.array([o in TRAVELS or o in THIRD_CHANNELS and "_travel_" in o
                     for o in outputs])


def iv_lpm_solve(spectra, n_samples, n_in, n_out, f_hz, fs, degree, half_width,
                 coherence_dof, travel, *, rcond=1e-10, chunk=256):
    """The local polynomial method with instrumental variables (module notes).

    As :func:`ident.identify.frf._lpm_solve` (the same windows, polynomials, transients
    removed by projection, columns scaled to unit norm), with two versions of the inputs:
    ``A`` (measured) and ``X`` (travel-derived; the rig inputs the same in both). Output
    rows not in `travel`: ``theta = (X^H A)^-1 X^H B``; rows in `travel`: ``theta = (A^H
    X)^-1 A^H B``. The covariance is ``sigma^2 (Z^H R)^-1 Z^H Z (Z^H R)^-H`` (``R`` the
    regressor, ``Z`` the instrument), ``sigma^2`` the residual power over the degrees of
    freedom.

    Parameters
    ----------
    spectra : list of ndarray of complex, shape (n_in + n_out + n_df, n_lines_r)
        Each run's full-record DFT: the inputs (rig, then measured ``dF``), the outputs,
        then the travel-derived ``dF`` (``n_df`` rows: the last ``n_df`` inputs).
    n_samples : list of int
    n_in, n_out : int
    f_hz : ndarray, shape (n_f,)
    fs : float
    degree, half_width : int
    coherence_dof : float
    travel : ndarray of bool, shape (n_out,)
        :func:`travel_rows`.
    rcond : float
        Singular values of ``Z^H R`` (columns scaled) below this fraction of the largest
        count as zero.
    chunk : int
        Target frequencies per batched solve.

    Returns
    -------
    H, mult, partial, cond, indep, dof
        As :func:`ident.identify.frf._lpm_solve` (``cond`` and ``indep`` those of the
        measured inputs' least-squares problem: the experiment's, not the estimator's).
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):  # many small products: BLAS threads only contend
        return _iv_lpm_solve(spectra, n_samples, n_in, n_out, f_hz, fs, degree, half_width,
                             coherence_dof, travel, rcond, chunk)


def _iv_lpm_solve(spectra, n_samples, n_in, n_out, f_hz, fs, degree, half_width,
                  coherence_dof, travel, rcond, chunk):
    n_runs = len(spectra)
    m, p = n_in, n_out
    n_df = spectra[0].shape[0] - n_in - n_out
    lines, nd = 2 * half_width + 1, degree + 1
    ncol = m * nd
    dof = n_runs * (lines - nd) - ncol
    q, _ = np.linalg.qr(np.vander(np.arange(-half_width, half_width + 1) / half_width, nd,
                                  increasing=True))
    proj = np.eye(lines) - q @ q.T
    n_ref = max(n_samples)
    idx, xpow = [], []
    for n in n_samples:
        pos = np.asarray(f_hz, dtype=float) * n / fs
        start = np.clip(np.rint(pos).astype(int) - half_width, 1, n // 2 - lines + 1)
        k = start[:, None] + np.arange(lines)
        x = (k - pos[:, None]) * (n_ref / n) / half_width
        idx.append(k)
        xpow.append(x[..., None] ** np.arange(nd))
    n_f = f_hz.size
    H = np.empty((n_f, m, p), dtype=complex)
    partial = np.empty((n_f, m, p))
    mult = np.empty((n_f, p))
    cond = np.empty(n_f)
    indep = np.empty((n_f, m))
    col0 = np.arange(m) * nd
    groups = [(np.ones(p, dtype=bool), False)]
    xin = list(range(m - n_df)) + list(range(m + p, m + p + n_df))
    for a in range(0, n_f, chunk):
        sl = slice(a, min(a + chunk, n_f))
        t = sl.stop - sl.start
        A = np.empty((t, n_runs, lines, m, nd), dtype=complex)
        X = np.empty_like(A)
        B = np.empty((t, n_runs, lines, p), dtype=complex)
        for r, S in enumerate(spectra):
            W = np.moveaxis(S[:, idx[r][sl]], 0, -1)
            A[:, r] = W[..., :m, None] * xpow[r][sl][:, :, None, :]
            X[:, r] = W[..., xin, None] * xpow[r][sl][:, :, None, :]
            B[:, r] = W[..., m:m + p]
        ypow = np.sum(np.abs(B) ** 2, axis=(1, 2))
        A = (proj @ A.reshape(t, n_runs, lines, ncol)).reshape(t, n_runs * lines, ncol)
        X = (proj @ X.reshape(t, n_runs, lines, ncol)).reshape(t, n_runs * lines, ncol)
        B = (proj @ B).reshape(t, n_runs * lines, p)
        scales = []
        for M in (A, X):
            sc = np.sqrt(np.sum(np.abs(M) ** 2, axis=1))
            scales.append(np.where(sc > 0, sc, 1.0))
        As, Xs = A / scales[0][:, None, :], X / scales[1][:, None, :]
        gram = np.conj(np.swapaxes(As, 1, 2)) @ As
        sv = np.linalg.svd(gram, compute_uv=False)
        smin = sv[:, -1]
        cond[sl] = np.where(smin > 0, sv[:, 0] / np.where(smin > 0, smin, 1.0), np.inf)
        ginv = np.linalg.pinv(gram, rcond=rcond, hermitian=True)
        cdiag_ls = np.real(np.einsum("tcc->tc", ginv))[:, col0]
        indep[sl] = np.clip(1.0 / np.maximum(cdiag_ls, 1e-300), 0.0, 1.0)
        for rows, swap in groups:
            if not rows.any():
                continue
            R, Z, sc = (Xs, As, scales[1]) if swap else (As, Xs, scales[0])
            Zh = np.conj(np.swapaxes(Z, 1, 2))
            Minv = np.linalg.pinv(Zh @ R, rcond=rcond)
            Bg = B[:, :, rows]
            th = Minv @ (Zh @ Bg)
            sse = np.sum(np.abs(Bg - R @ th) ** 2, axis=1)
            C = Minv @ (Zh @ Z) @ np.conj(np.swapaxes(Minv, 1, 2))
            cdiag = np.real(np.einsum("tcc->tc", C))[:, col0]
            h = th[:, col0, :] / sc[:, col0, None]
            H[sl] = _put(H[sl], h, rows)
            var = sse[:, None, :] / dof * (cdiag / sc[:, col0] ** 2)[:, :, None]
            num = np.abs(h) ** 2
            den = num + coherence_dof * var
            pc = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
            partial[sl] = _put(partial[sl], pc, rows)
            mg = np.clip(1.0 - sse / np.where(ypow[:, rows] > 0, ypow[:, rows], 1.0), 0.0, 1.0)
            mult[sl] = _put(mult[sl][:, None, :], (mg * (ypow[:, rows] > 0))[:, None, :],
                            rows)[:, 0, :]
    return (np.transpose(H, (2, 1, 0)), mult.T, np.transpose(partial, (2, 1, 0)), cond,
            indep.T, dof)


def travel_from_velocity(H, partial, mult, outputs, f_hz):
    """The shock-travel rows as the shock-velocity rows integrated (``/ j 2 pi f``).

    The travel-derived instruments share the travel sensors' noise with the shock-travel
    outputs, so those rows are taken from the velocity rows (the travel is the velocity's
    integral, exactly), with their coherences; the DC line keeps its own estimate.

    Parameters
    ----------
    H : ndarray of complex, shape (n_out, n_in, n_f)
    partial : ndarray, shape (n_out, n_in, n_f)
    mult : ndarray, shape (n_out, n_f)
    outputs : sequence of str
    f_hz : ndarray, shape (n_f,)

    Returns
    -------
    H, partial, mult
        New arrays; unchanged where an output's velocity is not among `outputs`.
    """
    outs = list(outputs)
    H, partial, mult = np.array(H), np.array(partial), np.array(mult)
    f = np.asarray(f_hz, dtype=float)
    live = f > 0
    s = 2j * np.pi * f[live]
    for c in CORNERS:
        x, v = f"shock_travel_{c}", f"shock_velocity_{c}"
        if x in outs and v in outs:
            i, j = outs.index(x), outs.index(v)
            H[i][:, live] = H[j][:, live] / s
            partial[i][:, live] = partial[j][:, live]
            mult[i][live] = mult[j][live]
    return H, partial, mult


def _put(target, values, rows):
    """`target` (t, m, p) with its output columns `rows` set to `values` (t, m, k)."""
    out = np.array(target)
    out[:, :, rows] = values
    return out
