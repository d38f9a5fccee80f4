"""The closed loop written in casadi for the optimizer: a recursion over a drive's samples.

The closed loop is that of :mod:`ident.sim.closedloop`, written in casadi as a
discrete recursion (a fold, single shooting) over the drive's samples:

- the rig part of the model's :class:`~ident.models.lti.LoopPlant` is
  simulated once per drive (:func:`ident.sim.closedloop.rig_response`);
- the shock part's modes are stepped with the same quadratic-hold
  coefficients (:func:`ident.models.lti.hold_coefficients`) and the lag with
  :func:`ident.models.lti.lag_hold_coefficients`, ``oversample`` sub-steps per
  sample;
- the algebraic loop ``v = v_free + D_eff dF(v)`` is solved at every sub-step
  by Newton's method on the 4 shock velocities (3 iterations from ``v_free``;
  with piecewise-linear curves it is exact once the segments are found, and
  ``D_eff`` is small), never broken by a delay;
- each metric channel passes the metric filter's power response ``|B|^4``
  (the 1-20 Hz Butterworth twice, forward) and its mean is removed exactly
  (``sum (z - m s)^2`` with ``s`` the filter's step response): within 0.001 %
  of ``sosfiltfilt``'s RMS on a 120 s track drive.

A sample's step is an MX function calling two SX functions, the loop's
sub-step (``oversample`` times) and the metrics' filters and sums (once); the
step and its adjoint are compiled to C when a C compiler is found
(:mod:`planner.optimize.cache`), and the recursion over the samples is a
tower of folds (:func:`_fold_chain`) that casadi's virtual machine runs,
calling them. Built steps are kept per process by problem, so a second
optimization of the same problem builds and compiles nothing.
"""

from __future__ import annotations

import hashlib

import casadi as ca
import numpy as np
from scipy import signal

from ident.data.channels import CORNERS
from ident.models.lti import hold_coefficients, lag_hold_coefficients
from ident.sim.closedloop import rig_response
from planner.optimize.cache import compiled_steps

__all__ = [
    "LoopModel",
    "NEWTON_ITERATIONS",
    "FOLD_BASE",
]

#: Newton iterations of the shock loop per sub-step in the casadi recursion.
NEWTON_ITERATIONS = 3


def _pwl_sx(v, p, vk):
    """Force and slope of a piecewise-linear curve at `v` (SX), parameters `p` (knot forces,
    slope below, slope above) and knots `vk`."""
    K = vk.size
    f = p[0] + p[K] * (v - vk[0])
    s = p[K]
    for j in range(K - 1):
        sj = (p[j + 1] - p[j]) / (vk[j + 1] - vk[j])
        on = v >= vk[j]
        f = ca.if_else(on, p[j] + sj * (v - vk[j]), f)
        s = ca.if_else(on, sj, s)
    on = v >= vk[-1]
    f = ca.if_else(on, p[K - 1] + p[K + 1] * (v - vk[-1]), f)
    s = ca.if_else(on, p[K + 1], s)
    return f, s


class LoopModel:
    """The closed loop of one plant and drive as a casadi recursion (module notes)."""

    def __init__(self, plant, drive, space, metric_rows, oversample, jit, *, inputs=True):
        """`inputs` False: build (and compile) the step functions only, for the drive's
        sample rate; the rig response and the recursion's inputs are left out."""
        self.space = space
        r = int(oversample)
        names, L = metric_rows
        outs = [plant.output_names[o] for o in np.flatnonzero(np.any(L != 0, axis=0))]
        Lm = L[:, [plant.output_names.index(o) for o in outs]]
        ms = plant.shock
        vi = plant.velocity_idx
        oi = [plant.output_names.index(o) for o in outs]
        h = 1.0 / (drive.fs_hz * r)
        phi, g1, g0, gm = hold_coefficients(ms.lam, h)
        n = ms.lam.size
        B, Cv, Dv = ms.B, ms.C[vi], ms.D[vi]
        Cm = Lm @ ms.C[oi]  # metric rows of the shock part
        Dm = Lm @ ms.D[oi]
        Deff = np.real(Cv @ (g1[:, None] * B)) + Dv
        cbar = np.asarray(plant.cbar_n_s_m, dtype=float)
        lag = np.array([space.lag_s[space.group_of(c)] for c in CORNERS])
        alpha, b0, b1, bm = (np.asarray(a, dtype=float) for a in lag_hold_coefficients(lag, h))
        nm = Lm.shape[0]
        sos = signal.butter(4, (1.0, 20.0), "bandpass", fs=drive.fs_hz, output="sos")
        sos = np.vstack([sos, sos])  # |B|^4: the power response of filtfilt
        ns = sos.shape[0]
        G, npar = len(space.groups), space.n_params
        vk = space.v_knots_m_s
        grp = [space.group_of(c) for c in CORNERS]

        # state: modes (re, im), dF[k-1], dF[k-2], F[k-1], f[k-1], f[k-2] (the loop part),
        # filter states, sums (z^2, z s, y) per metric, then the curve parameters (carried,
        # constant). A step is an MX function calling two SX functions: the loop's sub-step
        # (r times) and the metrics' outputs, filters and sums (once)
        n_loop = 2 * n + 20
        nx = n_loop + 2 * ns * nm + 3 * nm
        S = ca.SX.sym("s", n_loop)
        Pc = ca.SX.sym("p", G * npar)
        xr, xi = S[:n], S[n:2 * n]
        dF1, dF2, F1, f1, f2 = (S[2 * n + 4 * k:2 * n + 4 * k + 4] for k in range(5))
        Br, Bi = ca.DM(B.real), ca.DM(B.imag)
        Cvr, Cvi = ca.DM(Cv.real), ca.DM(Cv.imag)
        De = ca.DM(Deff)
        pg = [Pc[g * npar:(g + 1) * npar] for g in range(G)]

        def cmul(ar, ai, br, bi):
            return ar * br - ai * bi, ar * bi + ai * br

        # the loop's sub-step: (loop state, the rig part's shock velocities, curves) -> state
        vr = ca.SX.sym("v", 4)
        t1r, t1i = cmul(g0.real, g0.imag, Br @ dF1, Bi @ dF1)
        t2r, t2i = cmul(gm.real, gm.imag, Br @ dF2, Bi @ dF2)
        ar, ai = cmul(phi.real, phi.imag, xr, xi)
        xpr, xpi = ar + t1r + t2r, ai + t1i + t2i
        vfree = vr + Cvr @ xpr - Cvi @ xpi
        c0 = alpha * F1 + b1 * f1 + bm * f2
        v = vfree
        for _ in range(NEWTON_ITERATIONS):
            fs = [_pwl_sx(v[c], pg[grp[c]], vk) for c in range(4)]
            fv = ca.vertcat(*[a for a, _ in fs])
            sl = ca.vertcat(*[s for _, s in fs])
            res = v - vfree - De @ (c0 + b0 * fv - cbar * v)
            J = ca.DM.eye(4) - De @ ca.diag(b0 * sl - cbar)
            v = v - ca.solve(J, res)
        fv = ca.vertcat(*[_pwl_sx(v[c], pg[grp[c]], vk)[0] for c in range(4)])
        F = c0 + b0 * fv
        dF = F - cbar * v
        t0r, t0i = cmul(g1.real, g1.imag, Br @ dF, Bi @ dF)
        substep = ca.Function("substep", [S, vr, Pc],
                              [ca.vertcat(xpr + t0r, xpi + t0i, dF, dF1, F, fv, f1)])

        # the metrics' part: (loop state, filter states, sums, the rig part's metric rows and
        # the filter's step response) -> (filter states, sums)
        zf, sums = ca.SX.sym("z", 2 * ns * nm), ca.SX.sym("sums", 3 * nm)
        uy = ca.SX.sym("uy", nm + 1)
        y = uy[:nm] + ca.DM(Cm.real) @ xr - ca.DM(Cm.imag) @ xi + ca.DM(Dm) @ dF1
        sig, newz = y, []
        for k in range(ns):
            b_, a_ = sos[k, :3], sos[k, 3:]
            z1 = zf[2 * k * nm:(2 * k + 1) * nm]
            z2 = zf[(2 * k + 1) * nm:(2 * k + 2) * nm]
            out = b_[0] * sig + z1
            newz += [b_[1] * sig - a_[1] * out + z2, b_[2] * sig - a_[2] * out]
            sig = out
        sk = uy[nm]
        new_sums = ca.vertcat(sums[:nm] + sig**2, sums[nm:2 * nm] + sig * sk, sums[2 * nm:] + y)
        outputs = ca.Function("outputs", [S, zf, sums, uy], [ca.vertcat(*newz, new_sums)])

        XP, U = ca.MX.sym("x", nx + G * npar), ca.MX.sym("u", 4 * r + nm + 1)
        P = XP[nx:]

        def body(nsub):
            s = XP[:n_loop]
            for k in range(nsub):
                s = substep(s, U[4 * k:4 * k + 4], P)
            rest = outputs(s, XP[n_loop:n_loop + 2 * ns * nm], XP[n_loop + 2 * ns * nm:nx],
                           U[4 * r:])
            return ca.Function(f"step{nsub}", [XP, U], [ca.vertcat(s, rest, P)])

        key = _step_key(ms, h, r, lag, vk, grp, Cm, Dm, Deff, cbar, bool(jit))
        if key not in _STEP_CACHE:
            first, step = body(1), body(r)
            # instructions of the symbolic step (not of a library)
            n_instructions = r * substep.n_instructions() + outputs.n_instructions()
            if jit:  # the first step runs once per sweep: it is not worth its compile
                step = compiled_steps((step,))[0]
            # casadi keeps derivative functions only while something holds them: hold the
            # adjoints with the steps, so a second solve reuses them
            _STEP_CACHE[key] = (first, step, first.reverse(1), step.reverse(1), n_instructions)
        first, step = _STEP_CACHE[key][:2]
        self.n_instructions = _STEP_CACHE[key][-1]
        if not inputs:
            return
        rig = rig_response(plant, drive, oversample=r, outputs=outs)
        N = rig.n_samples
        step_resp = signal.sosfilt(sos, np.ones(N))
        # inputs per sample: the r fine shock velocities of the rig part ending at the sample
        # (the first sample: its own), the metric rows of the rig part, the step response
        v_fine = rig.v_fine
        Uin = np.zeros((4 * r + nm + 1, N))
        Uin[:4, 0] = v_fine[0]
        for k in range(r):
            Uin[4 * k:4 * k + 4, 1:] = v_fine[k + 1::r][:N - 1].T
        Uin[4 * r:4 * r + nm] = Lm @ rig.y
        Uin[-1] = step_resp
        self.N, self.nm, self.names = N, nm, list(names)
        self._first, self._step, self._U = first, step, Uin
        self._nx, self._G, self._npar = nx, G, npar

    def metrics(self, P):
        """Symbolic metrics (MX, shape (nm,)) of curve parameters `P` (MX)."""
        x0 = ca.vertcat(ca.DM.zeros(self._nx), P)
        x1 = self._first(x0, ca.DM(self._U[:, 0]))
        x_last = _fold_chain(self._step, self.N - 1)(x1, ca.DM(self._U[:, 1:]))
        sums = x_last[self._nx - 3 * self.nm:self._nx]
        nm, N = self.nm, self.N
        zz, zs, ysum = sums[:nm], sums[nm:2 * nm], sums[2 * nm:]
        mean = ysum / N
        ss = float(np.sum(self._U[-1] ** 2))
        power = (zz - 2 * mean * zs + mean**2 * ss) / N
        return ca.sqrt(ca.fmax(power, 1e-300))


#: Steps per level of the optimizer's recursion (:func:`_fold_chain`).
FOLD_BASE = 32


def _fold_chain(step, n_steps, base=FOLD_BASE):
    """``step`` applied `n_steps` times, feeding its state back: ``(x0, U) -> x_n``.

    ``step`` maps (x, u) -> x; ``U`` holds the inputs column by column, shape
    (n_u, n_steps). The chain is a tower of functions, level ``i`` folding
    ``base**i`` steps as `base` calls of level ``i - 1``, and the top calls
    each level as often as that digit of `n_steps` in base `base`. It builds
    in milliseconds for any length (casadi's ``mapaccum`` took 0.3-13 s to
    build for 10^4 steps, depending on the length's remainders), keeps only
    the final state (the metrics' sums need no trajectory), and its adjoint
    recomputes each level's states from the level's input (checkpointing),
    so memory grows with ``base`` times the levels, not with `n_steps`. The
    arithmetic of every step, and of every adjoint step, is the same as a
    loop's.

    Returns
    -------
    casadi.Function
    """
    nx, nu = step.size1_in(0), step.size1_in(1)
    levels = [step]
    while base ** len(levels) <= n_steps:
        inner, k = levels[-1], base ** (len(levels) - 1)
        x, U = ca.MX.sym("x", nx), ca.MX.sym("U", nu, k * base)
        y = x
        for j in range(base):
            y = inner(y, U[:, j * k:(j + 1) * k])
        levels.append(ca.Function(f"fold{k * base}", [x, U], [y]))
    x, U = ca.MX.sym("x", nx), ca.MX.sym("U", nu, n_steps)
    y, pos = x, 0
    for i in range(len(levels) - 1, -1, -1):
        k = base ** i
        while n_steps - pos >= k:
            y = levels[i](y, U[:, pos:pos + k])
            pos += k
    return ca.Function(f"fold{n_steps}", [x, U], [y])


#: Compiled step functions by model, step, lags, knots, groups and metric rows: a second
#: optimization of the same problem (another drive, other constraints) compiles nothing.
_STEP_CACHE = {}


def _step_key(ms, *parts):
    """A hashable key of the shock part's modes and the step's settings."""
    h = hashlib.sha1()
    for a in (ms.lam, ms.B, ms.C, ms.D) + parts:
        a = np.atleast_1d(np.asarray(a))
        h.update(str((a.shape, a.dtype.str)).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()
