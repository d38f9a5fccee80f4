"""The physical car's closed loop with third elements (heave and roll elements per axle).

The virtual rig's simulator for a car that carries third elements (the spec's optional
section "Third elements"): the loop of :mod:`ident.sim.closedloop` (the same plant, the
same exact modal discretization with a quadratic hold, the same lag discretization,
Newton's method within the step) with *coupled* nonlinear elements. Every element is a
row ``m`` over the corners (:func:`ident.data.third.element_row`; a corner's own shock or
bump stop is a unit row): its travel and velocity are ``m @ x`` and ``m @ v`` of the
corners' shock travels and velocities, and its force ``F`` acts at the corners as ``m *
F``, in parallel with the shocks. Dampers (the corner shocks and the heave and roll
dampers) are a piecewise-linear force-velocity curve behind a first-order lag; springs
(the corner bump stops and the heave springs) a force-travel table from their contact
travel (gap less packer) on, no force before.

The step's unknowns are the 4 corner force deviations ``dF = sum_e m_e F_e - cbar v``; the
4x4 Newton system is no longer diagonal in the shocks (a heave element couples the two
corners of its axle), so the plain loop's kernels (:mod:`ident.sim.loop_kernels`, tuned
for 4 independent shocks) are not used: this module has its own small compiled loop. It
is the virtual rig's truth, not the planner's fast loop: one setup at a time, every
output on the internal grid. A car without third elements is simulated by
:func:`ident.sim.closedloop.simulate` as before (the virtual rig only comes here when a
run fits one).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba as _nb
import numpy as np

from ident.data.channels import CORNERS, SHOCK_FORCES
from ident.models.lti import hold_coefficients, lag_hold_coefficients
from ident.sim.closedloop import check_oversample, rig_response
from ident.sim.loop_third import ThirdDamper, ThirdSpring

__all__ = [
    "ThirdDamper",
    "ThirdSpring",
    "ThirdResponse",
    "simulate_third",
    "THIRD_TOL_N",
    "THIRD_MAX_ITERATIONS",
    "THIRD_ARMIJO",
    "THIRD_MIN_STEP",
]

#: Newton's tolerance on the step's corner forces [N]: far below a load cell's resolution
#: (~1 N), well above rounding on forces of kN.
THIRD_TOL_N = 1e-7
#: Newton iterations (steps and their halvings) per step before the loop is declared
#: ill-posed (piecewise-linear curves converge in a few; a segment change costs one more;
#: a stiff element cycling at a kink takes halvings).
THIRD_MAX_ITERATIONS = 200
#: Armijo's fraction of Newton's backtracking: a step of length ``lam`` is accepted when it
#: lowers ``|R|^2`` to ``(1 - THIRD_ARMIJO lam)`` of the last accepted point's (else halved;
#: a full step is always tried first, so a step that converged without it is unchanged).
THIRD_ARMIJO = 1e-4
#: Smallest step fraction of the backtracking; a step at it is taken whatever its residual
#: (the near side's descent ends at a kink: the far side's Jacobian takes over beyond it).
THIRD_MIN_STEP = 2.0 ** -20


@dataclass(frozen=True, eq=False)
class ThirdResponse:
    """One setup's response with third elements, on the internal grid.

    Attributes
    ----------
    channels : dict of str to ndarray, shape (n_steps,)
        The plant's outputs, ``shock_force_XX`` (each shock's own force), and per element
        ``<element>_velocity``, ``<element>_travel`` and ``<element>_force`` (``heave_front``
        -> ``heave_velocity_front`` ...), ``heave_spring_force_<axle>`` per heave spring,
        and corner bump stops' forces as ``bump_stop_force_XX`` (SI).
    fs_hz : float
    newton_iterations : int
        The most iterations a step took.
    """

    channels: dict
    fs_hz: float
    newton_iterations: int
    elements: dict = field(default_factory=dict)


def _channel(element, what):
    kind, axle = element.split("_")
    return f"{kind}_{what}_{axle}"


def simulate_third(plant, drive, shocks, *, dampers=(), springs=(), stop_tables=None,
                   oversample=1):
    """Simulate one setup of a car with third elements in closed loop.

    Parameters
    ----------
    plant : ident.models.lti.LoopPlant
        The physical car's loop plant (``shock_velocity_XX`` and ``shock_travel_XX`` among
        its outputs).
    drive : ident.data.drive.Drive
    shocks : sequence of 4 shock models
        LF, RF, LR, RR.
    dampers : sequence of ThirdDamper
    springs : sequence of ThirdSpring
    stop_tables : sequence of 4 ((float, ndarray, ndarray) or None), optional
        The corners' bump stops (:func:`ident.models.bumpstops.contact_tables`).
    oversample : int
        Internal steps per drive sample (the virtual rig refines its drive itself: 1).

    Returns
    -------
    ThirdResponse

    Raises
    ------
    ValueError
        If the plant lacks the shock travels, or Newton's method does not converge.
    """
    r = check_oversample(oversample)
    names = list(plant.output_names)
    try:
        ti = [names.index(f"shock_travel_{c}") for c in CORNERS]
    except ValueError:
        raise ValueError(f"plant {plant.name!r}: third elements need the outputs "
                         "shock_travel_XX") from None
    vi = list(plant.velocity_idx)
    rig = rig_response(plant, drive, oversample=r)
    h = 1.0 / (rig.fs_hz * r)
    if r != 1:
        raise ValueError("simulate_third: give the drive on the internal grid (oversample=1)")
    ms = plant.shock
    phi, g1, g0, gm = hold_coefficients(ms.lam, h)
    B = np.ascontiguousarray(ms.B[:, :4], dtype=complex)
    C = np.ascontiguousarray(ms.C, dtype=complex)
    D = np.ascontiguousarray(np.real(ms.D[:, :4]), dtype=float)
    Dv = np.real(C[vi] @ (g1[:, None] * B)) + D[vi]
    Dt = np.real(C[ti] @ (g1[:, None] * B)) + D[ti]
    models = list(shocks) + [d.model for d in dampers]
    rows = np.vstack([np.eye(4)] + [np.asarray(d.row, dtype=float)[None] for d in dampers])
    pwls = [m.to_pwl() for m in models]
    K = max(p.v_knots_m_s.size for p in pwls)
    nd = len(models)
    kv, kf = np.zeros((nd, K)), np.zeros((nd, K))
    nk = np.zeros(nd, dtype=np.int64)
    slo, shi = np.zeros(nd), np.zeros(nd)
    for i, p in enumerate(pwls):
        k = p.v_knots_m_s.size
        kv[i, :k], kf[i, :k] = p.v_knots_m_s, p.f_knots_n
        kv[i, k:], kf[i, k:] = p.v_knots_m_s[-1], p.f_knots_n[-1]
        nk[i], slo[i], shi[i] = k, p.slope_below, p.slope_above
    alpha, b0, b1, bm = (np.ascontiguousarray(a, dtype=float) for a in
                         lag_hold_coefficients(np.array([m.lag_s for m in models]), h))
    # springs: the corners' bump stops (unit rows), then the heave springs
    spring_rows, contacts, spring_names = [], [], []
    for c, st in zip(CORNERS, stop_tables or [None] * 4):
        if st is not None:
            spring_rows.append(np.eye(4)[CORNERS.index(c)])
            contacts.append(st)
            spring_names.append(f"bump_stop_force_{c}")
    for s in springs:
        spring_rows.append(np.asarray(s.row, dtype=float))
        contacts.append(s.contact)
        spring_names.append(f"heave_spring_force_{s.name.split('_')[1]}")
    ns = len(contacts)
    P = max([2] + [len(ct[1]) for ct in contacts])
    s0, bx, bf = np.zeros(ns), np.zeros((ns, P)), np.zeros((ns, P))
    bn, bslope = np.zeros(ns, dtype=np.int64), np.zeros(ns)
    for i, (gap, x, f) in enumerate(contacts):
        x, f = np.asarray(x, dtype=float), np.asarray(f, dtype=float)
        s0[i], bn[i] = gap, x.size
        bx[i, :x.size], bf[i, :x.size] = x, f
        bx[i, x.size:], bf[i, x.size:] = x[-1], f[-1]
        bslope[i] = (f[-1] - f[-2]) / (x[-1] - x[-2])
    srows = np.vstack(spring_rows) if ns else np.zeros((0, 4))
    y_rig = np.ascontiguousarray(rig.y.T)
    N, p = y_rig.shape
    y = np.empty((N, p))
    F = np.empty((N, nd))
    S = np.empty((N, ns))
    iters = _third_kernel(phi.astype(complex), g1.astype(complex), g0.astype(complex),
                          gm.astype(complex), B, C, D, np.asarray(plant.cbar_n_s_m, dtype=float),
                          y_rig, np.array(vi, dtype=np.int64), np.array(ti, dtype=np.int64),
                          rows, kv, kf, nk, slo, shi, alpha, b0, b1, bm,
                          np.ascontiguousarray(srows), s0, bx, bf, bn, bslope,
                          THIRD_MAX_ITERATIONS, THIRD_TOL_N, THIRD_ARMIJO,
                          THIRD_MIN_STEP, y, F, S)
    if iters < 0:
        raise ValueError(f"closed loop of plant {plant.name!r} with third elements: Newton's "
                         "method did not converge; check the elements' curves and springs, "
                         "or raise the plan's oversample")
    channels = {n: y[:, j] for j, n in enumerate(names)}
    for c, name in enumerate(SHOCK_FORCES):
        channels[name] = F[:, c]
    v = y[:, vi]
    t = y[:, ti]
    for i, d in enumerate(dampers):
        channels[_channel(d.name, "velocity")] = v @ rows[4 + i]
        channels[_channel(d.name, "travel")] = t @ rows[4 + i]
        channels[_channel(d.name, "force")] = F[:, 4 + i]
    for j, name in enumerate(spring_names):
        channels[name] = S[:, j]
    return ThirdResponse(channels=channels, fs_hz=rig.fs_hz, newton_iterations=int(iters))


@_nb.njit(cache=True)
def _pwl(v, kv, kf, nk, slo, shi):
    """Force and slope of a piecewise-linear curve at `v`."""
    n = nk
    if v <= kv[0]:
        return kf[0] + slo * (v - kv[0]), slo
    if v >= kv[n - 1]:
        return kf[n - 1] + shi * (v - kv[n - 1]), shi
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if kv[mid] <= v:
            lo = mid
        else:
            hi = mid
    s = (kf[hi] - kf[lo]) / (kv[hi] - kv[lo])
    return kf[lo] + s * (v - kv[lo]), s


@_nb.njit(cache=True)
def _spring(t, s0, bx, bf, bn, bslope):
    """Force and stiffness of a spring with a gap at travel `t` (none before contact)."""
    s = t - s0
    if s <= 0.0:
        return 0.0, 0.0
    if s >= bx[bn - 1]:
        return bf[bn - 1] + bslope * (s - bx[bn - 1]), bslope
    f, k = _pwl(s, bx, bf, bn, 0.0, 0.0)
    return f, k


@_nb.njit(cache=True, nogil=True)
def _third_kernel(phi, g1, g0, gm, B, C, D, cbar, y_rig, vi, ti, rows, kv, kf, nk, slo, shi,
                  alpha, b0, b1, bm, srows, s0, bx, bf, bn, bslope, max_iter, tol, armijo,
                  min_step, y, F, S):
    """The time loop (see the module docstring); returns the most Newton iterations a step
    took, or -1 if a step did not converge. Newton's steps are globalized by backtracking
    on ``|R|^2`` (Armijo's test with `armijo`, halved down to `min_step`, then taken), as
    :mod:`ident.sim.loop_kernels`' fallback is. Plain loops over preallocated buffers (no
    array temporaries per step)."""
    N, p = y_rig.shape
    n = phi.shape[0]
    nd = rows.shape[0]
    ns = srows.shape[0]
    # the same-step responses of the velocities and travels to dF (real, 4 x 4)
    Dv = np.zeros((4, 4))
    Dt = np.zeros((4, 4))
    for a in range(4):
        for c in range(4):
            sv = 0.0
            st = 0.0
            for m in range(n):
                gb = g1[m] * B[m, c]
                sv += (C[vi[a], m] * gb).real
                st += (C[ti[a], m] * gb).real
            Dv[a, c] = sv + D[vi[a], c]
            Dt[a, c] = st + D[ti[a], c]
    x = np.zeros(n, dtype=np.complex128)
    xf = np.zeros(n, dtype=np.complex128)
    dF = np.zeros(4)
    dF1 = np.zeros(4)
    dF2 = np.zeros(4)
    v = np.zeros(4)
    t = np.zeros(4)
    vfree = np.zeros(4)
    tfree = np.zeros(4)
    G = np.zeros(4)
    R = np.zeros(4)
    base = np.zeros(4)
    step = np.zeros(4)
    Jv = np.zeros((4, 4))
    Jt = np.zeros((4, 4))
    J = np.zeros((4, 4))
    fprev = np.zeros(nd)  # curve forces f[k-1], f[k-2]
    fprev2 = np.zeros(nd)
    Fprev = np.zeros(nd)
    c0 = np.zeros(nd)
    Fd = np.zeros(nd)
    fd = np.zeros(nd)
    gs = np.zeros(ns)
    worst = 0
    for k in range(N):
        for m in range(n):
            u0 = 0.0j
            um = 0.0j
            for c in range(4):
                u0 += B[m, c] * dF1[c]
                um += B[m, c] * dF2[c]
            xf[m] = phi[m] * x[m] + g0[m] * u0 + gm[m] * um
        for a in range(4):
            sv = y_rig[k, vi[a]]
            st = y_rig[k, ti[a]]
            for m in range(n):
                sv += (C[vi[a], m] * xf[m]).real
                st += (C[ti[a], m] * xf[m]).real
            vfree[a] = sv
            tfree[a] = st
        for d in range(nd):
            c0[d] = alpha[d] * Fprev[d] + b1[d] * fprev[d] + bm[d] * fprev2[d]
        for c in range(4):
            dF[c] = dF1[c]
        it = 0
        lam = 1.0
        r2base = 0.0
        while True:
            for a in range(4):
                sv = vfree[a]
                st = tfree[a]
                for c in range(4):
                    sv += Dv[a, c] * dF[c]
                    st += Dt[a, c] * dF[c]
                v[a] = sv
                t[a] = st
                G[a] = -cbar[a] * v[a]
                for c in range(4):
                    Jv[a, c] = 0.0
                    Jt[a, c] = 0.0
                Jv[a, a] = -cbar[a]
            for d in range(nd):
                ve = 0.0
                for c in range(4):
                    ve += rows[d, c] * v[c]
                f, s = _pwl(ve, kv[d], kf[d], nk[d], slo[d], shi[d])
                fd[d] = f
                Fd[d] = c0[d] + b0[d] * f
                ds = b0[d] * s
                for a in range(4):
                    if rows[d, a] != 0.0:
                        G[a] += rows[d, a] * Fd[d]
                        for c in range(4):
                            Jv[a, c] += ds * rows[d, a] * rows[d, c]
            for j in range(ns):
                te = 0.0
                for c in range(4):
                    te += srows[j, c] * t[c]
                g, kk = _spring(te, s0[j], bx[j], bf[j], bn[j], bslope[j])
                gs[j] = g
                for a in range(4):
                    if srows[j, a] != 0.0:
                        G[a] += srows[j, a] * g
                        for c in range(4):
                            Jt[a, c] += kk * srows[j, a] * srows[j, c]
            rmax = 0.0
            fmax = 0.0
            r2 = 0.0
            for a in range(4):
                R[a] = dF[a] - G[a]
                rmax = max(rmax, abs(R[a]))
                fmax = max(fmax, abs(dF[a]))
                r2 += R[a] * R[a]
            if rmax <= tol * (1.0 + fmax):
                break
            it += 1
            if it > max_iter:
                return -1
            if it > 1 and r2 > (1.0 - armijo * lam) * r2base and lam > min_step:
                # not enough descent (cycling at a kink): half the step from the last
                # accepted point
                lam *= 0.5
                for a in range(4):
                    dF[a] = base[a] - lam * step[a]
                continue
            r2base = r2
            for a in range(4):
                for c in range(4):
                    sj = 0.0
                    for e in range(4):
                        sj += Jv[a, e] * Dv[e, c] + Jt[a, e] * Dt[e, c]
                    J[a, c] = (1.0 if a == c else 0.0) - sj
            step = np.linalg.solve(J, R)
            lam = 1.0
            for a in range(4):
                base[a] = dF[a]
                dF[a] -= step[a]
        if it > worst:
            worst = it
        for m in range(n):
            u1 = 0.0j
            for c in range(4):
                u1 += B[m, c] * dF[c]
            x[m] = xf[m] + g1[m] * u1
        for o in range(p):
            so = y_rig[k, o]
            for m in range(n):
                so += (C[o, m] * x[m]).real
            for c in range(4):
                so += D[o, c] * dF[c]
            y[k, o] = so
        for d in range(nd):
            F[k, d] = Fd[d]
            Fprev[d] = Fd[d]
            fprev2[d] = fprev[d]
            fprev[d] = fd[d]
        for j in range(ns):
            S[k, j] = gs[j]
        for c in range(4):
            dF2[c] = dF1[c]
            dF1[c] = dF[c]
    return worst
