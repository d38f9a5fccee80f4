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
- with the car's bump stops (``bump_stops=``), each corner's stop force
  ``g(s - s0)`` at the model's shock travel joins the corner's force input,
  its table's kinks rounded by a quadratic (:func:`stop_force_sx`,
  :data:`STOP_SMOOTHING_M`), and the travels join the shock velocities as
  Newton's unknowns (:data:`STOP_NEWTON_ITERATIONS`): travel, stop force and
  shock force agree within the sub-step, as in
  :func:`ident.sim.closedloop.simulate_batch`; a packer is a parameter that
  shortens ``s0`` (its gradient ``-g'(s - s0)``, nonzero only in contact);
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
from planner.errors import PlannerError
from planner.optimize.cache import compiled_steps

__all__ = [
    "LoopModel",
    "NEWTON_ITERATIONS",
    "STOP_NEWTON_ITERATIONS",
    "STOP_SMOOTHING_M",
    "THIRD_NEWTON_ITERATIONS",
    "FOLD_BASE",
    "stop_force_sx",
]

#: Newton iterations of the shock loop per sub-step in the casadi recursion.
NEWTON_ITERATIONS = 3
#: Newton iterations per sub-step with bump stops (shock velocities and travels together, the
#: stop's force at the step's own travel: implicit). ``k Dt`` is about -0.04 at oversample 2
#: on the GT car, so the travel barely moves the stop's segment: a fourth iteration changed
#: no metric by more than 1e-9 (60 s drive).
STOP_NEWTON_ITERATIONS = 3
#: Half-width [m] of the quadratic that rounds each kink of a bump stop's piecewise-linear
#: table in the casadi loop (0.1 mm, the kink spread over 0.2 mm): IPOPT's gradients, also
#: with respect to a packer (nonzero only in contact), stay continuous, and the force is the
#: table's exactly beyond a half-width from every kink; at a kink it is off by its slope
#: change times a quarter of the half-width (15 N for a 600 kN/m stop at contact).
STOP_SMOOTHING_M = 1e-4
#: Newton iterations per sub-step with third elements (shock velocities, with heave springs
#: or stops also the travels): a heave element couples an axle's corners and a stiff heave
#: spring moves the travel more than a corner stop, so one more than the stops' (measured
#: against :func:`ident.sim.closedloop.simulate_batch`, tests/test_optimize_third.py).
THIRD_NEWTON_ITERATIONS = 4


def stop_force_sx(z, x_m, f_n, width_m=None):
    """A bump stop's force and stiffness at travel `z` beyond contact, its kinks rounded.

    ``g(z) = sum_i dk_i r(z - x_i)``: the table's slope changes ``dk_i`` (the first
    segment's slope at contact ``x_0 = 0``) at its points ``x_i``, with ``r`` the ramp
    ``max(u, 0)`` rounded by a quadratic within ``|u| < w`` (``(u + w)^2 / (4 w)``; value
    and slope continuous), ``w`` = `width_m`; beyond the table the last slope continues
    (as :func:`ident.sim.closedloop.pack_bump_stops`). Exact beyond ``w`` from every kink;
    no transcendental function (the loop evaluates it every Newton iteration).

    Parameters
    ----------
    z : casadi.SX or float
        Travel beyond contact [m] (negative: not in contact).
    x_m, f_n : ndarray, shape (K,)
        The stop's table [m], [N] (from 0, as the loop's form).
    width_m : float, optional
        Default :data:`STOP_SMOOTHING_M`.

    Returns
    -------
    g, dg : casadi.SX
        Force [N] and stiffness [N/m].
    """
    w = STOP_SMOOTHING_M if width_m is None else float(width_m)
    x = np.asarray(x_m, dtype=float)
    f = np.asarray(f_n, dtype=float)
    k = np.diff(f) / np.diff(x)
    dk = np.diff(np.concatenate([[0.0], k]))
    g, dg = 0, 0
    for xi, d in zip(x[:-1], dk):
        if d == 0.0:
            continue
        u = z - float(xi)
        t = ca.fmin(ca.fmax(u, -w), w) + w  # 0 .. 2 w
        g = g + float(d) * (t * t / (4 * w) + ca.fmax(u - w, 0))
        dg = dg + float(d) * t / (2 * w)
    return g, dg


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

    def __init__(self, plant, drive, space, metric_rows, oversample, jit, *, inputs=True,
                 bump_stops=None, packer_index=None, third=None, free_third=(),
                 third_packer_index=None):
        """`inputs` False: build (and compile) the step functions only, for the drive's
        sample rate; the rig response and the recursion's inputs are left out.

        `bump_stops`: the car's stops in the loop's form (4 of None or ``(contact_travel_m,
        travel_table_m, force_table_n)``), their force ``g(s - s0)`` (kinks smoothed,
        :func:`stop_force_sx`) at the model's ``shock_travel_XX`` added to the corner's
        force input and solved with the shocks within the sub-step (implicit);
        `packer_index`: per corner the index of its packer among the parameters after the
        curves' (``s0`` then is the contact travel less that parameter), or None.

        `third`: the car's third elements, the loop's ``(dampers, springs)`` entry
        (:class:`ident.sim.loop_third.ThirdDamper`, :class:`~ident.sim.loop_third.ThirdSpring`,
        as :func:`ident.sim.closedloop.simulate_batch` takes one): each damper's force
        ``F_e`` (its curve at ``m_e @ v`` behind its lag) acts at the corners as ``m_e F_e``,
        each heave spring's ``g(m_e @ s - s0)`` (kinks smoothed as the stops') as ``m_e g``,
        solved with the shocks within the sub-step (:data:`THIRD_NEWTON_ITERATIONS`);
        `free_third`: the dampers (element names) whose curve is a parameter group after the
        corner groups' (in that order; their lag the entry's damper's);
        `third_packer_index`: per heave spring the index of its packer among the parameters
        after the curves' (as `packer_index`), or None. ``third=None``: the loop as before."""
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
        stops, pidx = None, [None] * 4
        if bump_stops is not None and any(st is not None for st in bump_stops):
            stops = [None if st is None else (float(st[0]), np.asarray(st[1], dtype=float),
                                              np.asarray(st[2], dtype=float))
                     for st in bump_stops]
            pidx = [None] * 4 if packer_index is None else list(packer_index)
            ti = _travel_rows(plant)
        n_pack = 0 if stops is None else 1 + max([i for i in pidx if i is not None],
                                                 default=-1)
        # the car's third elements (issue 38): dampers (a fixed curve or a free group after
        # the corner groups) and heave springs (a packer parameter or none)
        td, tsp, G3 = [], [], 0
        if third is not None:
            td, tsp, tpidx = _third_parts(third, free_third, third_packer_index)
            G3 = len(tuple(free_third))
            n_pack = 1 + max([i for i in (pidx if stops is not None else []) + tpidx
                              if i is not None], default=-1)
            if stops is None and tsp:
                ti = _travel_rows(plant)
        has_trav = stops is not None or bool(tsp)
        nd = len(td)

        # state: modes (re, im), dF[k-1], dF[k-2], F[k-1], f[k-1], f[k-2] (the loop part),
        # filter states, sums (z^2, z s, y) per metric, then the curve parameters (carried,
        # constant). A step is an MX function calling two SX functions: the loop's sub-step
        # (r times) and the metrics' outputs, filters and sums (once)
        n_loop = 2 * n + 20 + 3 * nd  # (third dampers: F[k-1], f[k-1], f[k-2] each)
        nx = n_loop + 2 * ns * nm + 3 * nm
        S = ca.SX.sym("s", n_loop)
        Pc = ca.SX.sym("p", (G + G3) * npar + n_pack)
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
        if third is not None:
            fv, F, dF, tail, extra_in = _third_substep(
                S[2 * n + 20:], dF1, vfree, c0, xpr, xpi, ms, ti if has_trav else None, g1, B,
                De, b0, cbar, pg, grp, vk, stops, pidx, Pc, (G + G3) * npar, G * npar, npar,
                td, tsp, h)
        elif stops is None:
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
            extra_in = []
        else:
            # the travel: the rig part's (an input) + the predictor's + the step's own
            # input through the hold's same-step weight, as the velocity
            Ct = ms.C[ti]
            Dte = ca.DM(np.real(Ct @ (g1[:, None] * B)) + ms.D[ti])
            sr = ca.SX.sym("sr", 4)
            sfree = sr + ca.DM(Ct.real) @ xpr - ca.DM(Ct.imag) @ xpi
            s0 = [None if st is None else
                  (st[0] - Pc[G * npar + pidx[c]] if pidx[c] is not None else st[0])
                  for c, st in enumerate(stops)]

            def stop_at(trav):
                gd = [(0, 0) if st is None else stop_force_sx(trav[c] - s0[c], st[1], st[2])
                      for c, st in enumerate(stops)]
                return ca.vertcat(*[a for a, _ in gd]), ca.vertcat(*[b for _, b in gd])

            trav = sfree
            I4 = ca.DM.eye(4)
            for _ in range(STOP_NEWTON_ITERATIONS if _STOP_IMPLICIT else NEWTON_ITERATIONS):
                fs = [_pwl_sx(v[c], pg[grp[c]], vk) for c in range(4)]
                fv = ca.vertcat(*[a for a, _ in fs])
                sl = ca.vertcat(*[s for _, s in fs])
                gs, dgs = stop_at(trav if _STOP_IMPLICIT else sfree)
                dF = c0 + b0 * fv - cbar * v + gs
                Av = ca.diag(b0 * sl - cbar)
                if _STOP_IMPLICIT:
                    Ag = ca.diag(dgs)
                    res = ca.vertcat(v - vfree - De @ dF, trav - sfree - Dte @ dF)
                    J = ca.blockcat([[I4 - De @ Av, -De @ Ag], [-Dte @ Av, I4 - Dte @ Ag]])
                    d = ca.solve(J, res)
                    v, trav = v - d[:4], trav - d[4:]
                else:
                    v = v - ca.solve(I4 - De @ Av, v - vfree - De @ dF)
            fv = ca.vertcat(*[_pwl_sx(v[c], pg[grp[c]], vk)[0] for c in range(4)])
            F = c0 + b0 * fv
            dF = F - cbar * v + stop_at(trav if _STOP_IMPLICIT else sfree)[0]
            extra_in = [sr]
        t0r, t0i = cmul(g1.real, g1.imag, Br @ dF, Bi @ dF)
        if third is None:
            tail = []
        substep = ca.Function("substep", [S, vr, *extra_in, Pc],
                              [ca.vertcat(xpr + t0r, xpi + t0i, dF, dF1, F, fv, f1, *tail)])

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

        # inputs per sample: the r fine shock velocities of the rig part (with stops: then its
        # r fine travels), its metric rows, the filter's step response
        n_fine = 8 * r if has_trav else 4 * r
        XP, U = ca.MX.sym("x", nx + (G + G3) * npar + n_pack), ca.MX.sym("u", n_fine + nm + 1)
        P = XP[nx:]

        def body(nsub):
            s = XP[:n_loop]
            for k in range(nsub):
                more = [U[4 * r + 4 * k:4 * r + 4 * k + 4]] if has_trav else []
                s = substep(s, U[4 * k:4 * k + 4], *more, P)
            rest = outputs(s, XP[n_loop:n_loop + 2 * ns * nm], XP[n_loop + 2 * ns * nm:nx],
                           U[n_fine:])
            return ca.Function(f"step{nsub}", [XP, U], [ca.vertcat(s, rest, P)])

        key_parts = (ms, h, r, lag, vk, grp, Cm, Dm, Deff, cbar, bool(jit))
        if stops is not None:
            key_parts += (repr([None if st is None else (st[0], st[1].tolist(), st[2].tolist())
                                for st in stops]), repr(pidx), ti, STOP_SMOOTHING_M,
                          _STOP_IMPLICIT)
        if third is not None:
            key_parts += (repr(_third_key(td, tsp)), G3, n_pack, THIRD_NEWTON_ITERATIONS,
                          ti if has_trav else ())
        key = _step_key(*key_parts)
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
        Uin = np.zeros((n_fine + nm + 1, N))
        fine = [v_fine]
        if has_trav:
            fine.append(_rig_fine_rows(plant, ti, rig.u_fine, h))
        for j, a in enumerate(fine):
            Uin[4 * r * j:4 * r * j + 4, 0] = a[0]
            for k in range(r):
                Uin[4 * r * j + 4 * k:4 * r * j + 4 * k + 4, 1:] = a[k + 1::r][:N - 1].T
        Uin[n_fine:n_fine + nm] = Lm @ rig.y
        Uin[-1] = step_resp
        self.N, self.nm, self.names = N, nm, list(names)
        self._first, self._step, self._U = first, step, Uin
        self._nx, self._G, self._npar = nx, G, npar
        self.n_params = (G + G3) * npar + n_pack

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


def _third_parts(third, free_third, packer_index):
    """The loop's third elements: dampers ``(row, curve, lag_s)`` (``curve`` the index of a
    free group, or the fitted damper's PiecewiseLinear), the fitted heave springs ``(row,
    contact_travel_m, x_m, f_n, packer)`` and the springs' packer indices."""
    try:
        dampers, springs = third
    except (TypeError, ValueError):
        raise PlannerError("optimize: third must be the loop's (dampers, springs) entry "
                           "(planner.elements.SetupThird.entries)") from None
    free = tuple(free_third)
    names = [d.name for d in dampers]
    unknown = [e for e in free if e not in names]
    if unknown:
        raise PlannerError(f"optimize: free third dampers {unknown} are not among the car's "
                           f"third elements {names}; free only a declared damper")
    td = []
    for d in dampers:
        lag = 0.0 if d.model is None else float(getattr(d.model, "lag_s", 0.0) or 0.0)
        row = np.asarray(d.row, dtype=float)
        if d.name in free:
            td.append((row, free.index(d.name), lag))
        elif d.model is not None:
            td.append((row, d.model.to_pwl(), lag))
    pidx = list(packer_index) if packer_index is not None else [None] * len(springs)
    if len(pidx) != len(springs):
        raise PlannerError(f"optimize: third_packer_index has {len(pidx)} entries for "
                           f"{len(springs)} heave springs; give one per spring (or None)")
    tsp = [(np.asarray(sp.row, dtype=float), float(sp.contact[0]),
            np.asarray(sp.contact[1], dtype=float), np.asarray(sp.contact[2], dtype=float), k)
           for sp, k in zip(springs, pidx) if sp.contact is not None]
    return td, tsp, [k for sp, k in zip(springs, pidx) if sp.contact is not None]


def _third_key(td, tsp):
    """A repr-able summary of the loop's third elements (the step cache's key)."""
    out = []
    for row, curve, lag in td:
        c = curve if isinstance(curve, int) else (
            np.asarray(curve.v_knots_m_s, float).tolist(),
            np.asarray(curve.f_knots_n, float).tolist(), float(curve.slope_below),
            float(curve.slope_above))
        out.append((row.tolist(), c, lag))
    out += [(row.tolist(), s0, x.tolist(), f.tolist(), k) for row, s0, x, f, k in tsp]
    return out


def _third_substep(St, dF1, vfree, c0, xpr, xpi, ms, ti, g1, B, De, b0, cbar, pg, grp, vk, stops,
                   pidx, Pc, pack0, third0, npar, td, tsp, h):
    """The sub-step's solve with the car's third elements (see :class:`LoopModel`): the
    corners' force deviations by Newton's method (velocities and travels follow them), the third
    dampers' lags stepped as the shocks'.

    Returns
    -------
    fv, F, dF : casadi.SX
        The corner curves' forces, the shocks' forces, the corners' force deviations.
    tail : list of casadi.SX
        The third dampers' next loop state (``F``, ``f``, ``f[k-1]``).
    extra_in : list of casadi.SX
        The rig part's travels (an input) when the travels are unknowns.
    """
    nd = len(td)
    Fe1, fe1, fe2 = St[:nd], St[nd:2 * nd], St[2 * nd:3 * nd]
    ce, e0 = [], []
    if nd:
        al, b0e, b1e, bme = (np.atleast_1d(np.asarray(a, dtype=float)) for a in
                             lag_hold_coefficients(np.array([lag for _, _, lag in td]), h))
        ce = [float(al[i]) * Fe1[i] + float(b1e[i]) * fe1[i] + float(bme[i]) * fe2[i]
              for i in range(nd)]
        e0 = [float(b) for b in b0e]
    params = []
    for _, curve, _ in td:
        if isinstance(curve, int):
            params.append((Pc[third0 + curve * npar:third0 + (curve + 1) * npar], vk))
        else:
            params.append(([float(a) for a in curve.f_knots_n]
                           + [float(curve.slope_below), float(curve.slope_above)],
                           np.asarray(curve.v_knots_m_s, dtype=float)))
    has_trav = ti is not None
    extra_in, sfree, Dte = [], None, None
    if has_trav:
        Ct = ms.C[ti]
        Dte = ca.DM(np.real(Ct @ (g1[:, None] * B)) + ms.D[ti])
        sr = ca.SX.sym("sr", 4)
        sfree = sr + ca.DM(Ct.real) @ xpr - ca.DM(Ct.imag) @ xpi
        extra_in = [sr]
    s0c = None if stops is None else [
        None if st is None else (st[0] - Pc[pack0 + pidx[c]] if pidx[c] is not None else st[0])
        for c, st in enumerate(stops)]
    s0t = [s0 - Pc[pack0 + k] if k is not None else s0 for _, s0, _, _, k in tsp]

    def forces(v, trav):
        fs = [_pwl_sx(v[c], pg[grp[c]], vk) for c in range(4)]
        fv = ca.vertcat(*[a for a, _ in fs])
        sl = ca.vertcat(*[s for _, s in fs])
        dF = c0 + b0 * fv - cbar * v
        Av = ca.diag(b0 * sl - cbar)
        fe, Fe = [], []
        for i, (row, _, _) in enumerate(td):
            f, s = _pwl_sx(ca.dot(ca.DM(row), v), *params[i])
            Fi = ce[i] + e0[i] * f
            dF = dF + ca.DM(row) * Fi
            Av = Av + (e0[i] * s) * ca.DM(np.outer(row, row))
            fe.append(f)
            Fe.append(Fi)
        Ag = None
        if has_trav:
            gd = [(0, 0) if s0c is None or s0c[c] is None else
                  stop_force_sx(trav[c] - s0c[c], stops[c][1], stops[c][2]) for c in range(4)]
            dF = dF + ca.vertcat(*[a for a, _ in gd])
            Ag = ca.diag(ca.vertcat(*[b for _, b in gd]))
            for j, (row, _, x, f, _) in enumerate(tsp):
                g, dg = stop_force_sx(ca.dot(ca.DM(row), trav) - s0t[j], x, f)
                dF = dF + ca.DM(row) * g
                Ag = Ag + dg * ca.DM(np.outer(row, row))
        return fv, dF, Av, Ag, fe, Fe

    # Newton on the 4 corner force deviations (as the truth, ident.sim.third_loop), from the
    # previous step's: the velocities and travels follow them through the hold's same-step
    # weights, so the system stays 4 x 4 with springs (8 x 8 on velocities and travels
    # compiled several times slower)
    I4 = ca.DM.eye(4)
    x = dF1
    for _ in range(THIRD_NEWTON_ITERATIONS):
        v = vfree + De @ x
        trav = sfree + Dte @ x if has_trav else None
        _, G, Av, Ag, _, _ = forces(v, trav)
        J = I4 - Av @ De - (Ag @ Dte if has_trav else 0)
        x = x - ca.solve(J, x - G)
    v = vfree + De @ x
    trav = sfree + Dte @ x if has_trav else None
    fv, dF, _, _, fe, Fe = forces(v, trav)
    tail = [ca.vertcat(*Fe), ca.vertcat(*fe), fe1] if nd else []
    return fv, c0 + b0 * fv, dF, tail, extra_in


#: Bump stops solved within the sub-step (True); False evaluates each stop at the travel
#: extrapolated from the state (the step's own input left out): kept to measure the
#: difference (tests), not an option.
_STOP_IMPLICIT = True


def _travel_rows(plant):
    """Rows of ``shock_travel_XX`` in the plant's outputs (bump stops need them)."""
    names = [f"shock_travel_{c}" for c in CORNERS]
    missing = [n for n in names if n not in plant.output_names]
    if missing:
        raise PlannerError(f"optimize: bump_stops need the model's outputs {missing}; model "
                           f"{plant.name!r} has none of them: identify it with the shock "
                           "travel channels, or leave bump_stops out")
    return [plant.output_names.index(n) for n in names]


def _rig_fine_rows(plant, rows, u_fine, h):
    """The rig part's outputs `rows` on the internal grid, shape (n_fine, len(rows)): each
    mode's hold recursion (as :func:`ident.sim.closedloop.rig_response` forms its
    velocities) from rest."""
    mr = plant.rig.select(outputs=list(rows)).pruned()
    phi, g1, g0, gm = hold_coefficients(mr.lam, h)
    bu = u_fine @ np.asarray(mr.B).T  # (n_fine, modes), complex
    x = np.empty_like(bu, dtype=complex)
    for i in range(bu.shape[1]):
        x[:, i] = signal.lfilter([g1[i], g0[i], gm[i]], [1.0, -phi[i]], bu[:, i])
    return np.real(x @ np.asarray(mr.C).T) + u_fine @ np.asarray(mr.D, dtype=float).T


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
