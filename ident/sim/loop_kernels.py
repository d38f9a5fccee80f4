"""Compiled kernels of the closed-loop simulator (numba): the rig-input response, the shock
loop's solve and the time loops.

The caller is :mod:`ident.sim.closedloop`, which checks every input and builds these
kernels' arguments (the FIR simulator, :mod:`ident.identify.fir`, takes the shock solve);
the kernels take plain arrays and run no checks. Public names, for them:

- :func:`rig_kernel`: the rig-input part of a plant's response on the internal grid,
  parallel over time chunks (:func:`ident.sim.closedloop.rig_response`);
- :func:`loop_batch`, :func:`loop_serial`: the closed loop of a batch of setups (parallel
  over setups, or one after the other), each setup by :func:`loop_one`;
- :func:`loop_metrics_worker`: a thread's share of the setups with their metrics computed
  right after each loop (:func:`ident.sim.metric_kernels.setup_metric_rms`);
- :func:`loop_one_elements` (bump stops and tire lift-off in the loop) and its drivers
  :func:`loop_elements_serial`, :func:`loop_elements_batch` and
  :func:`loop_metrics_elements_worker` (the fused metrics path with the elements);
- :func:`solver_state`, :func:`shock_step`: the per-step solve of the 4 shock equations,
  shared with the FIR simulator (:mod:`ident.identify.fir`); :func:`invert_small`, the
  4x4 inverse inside it.

The algebra is documented in :mod:`ident.sim.closedloop` (the modal loop, the quadratic
hold, Newton's method on the piecewise-linear shock curves).
"""

from __future__ import annotations

import numba as _nb
import numpy as np

from ident.sim.metric_kernels import LANES as METRIC_LANES
from ident.sim.metric_kernels import PW_LEVELS as METRIC_PW_LEVELS
from ident.sim.metric_kernels import setup_metric_rms

__all__ = [
    "rig_kernel",
    "solver_state",
    "invert_small",
    "shock_step",
    "loop_one",
    "loop_batch",
    "loop_serial",
    "loop_metrics_worker",
    "loop_one_elements",
    "loop_elements_serial",
    "loop_elements_batch",
    "loop_metrics_elements_worker",
]


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _rig_chunk(u, BrT, BiT, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, CrT, CmiT, DT, r, z, k0, k1,
               v, y, outputs):
    """Steps ``k0 <= k < k1`` of :func:`rig_kernel` from the states ``z`` (4, n): rows
    ``Re z0, Im z0, Re z1, Im z1`` of the transposed direct form II per mode, updated in
    place. With `outputs` False only the states are run (the chunk end states).

    Each step is three loops over 1-D rows, so that numba's loop vectorizer takes them:
    the modes' inputs ``b_i . u[k]`` (over the modes, one input after the other), the
    modes' hold recursions, and the outputs (over the outputs, one mode after the other).
    Every sum keeps its order: the numbers of a loop over modes with the sums inside.
    """
    n = pr.size
    m = u.shape[1]
    p = CrT.shape[1]
    z0r = z[0]
    z0i = z[1]
    z1r = z[2]
    z1i = z[3]
    acc = np.empty(p)
    ar = np.empty(n)
    ai = np.empty(n)
    xr = np.empty(n)
    xi = np.empty(n)
    phase = k0 % r
    for k in range(k0, k1):
        q = p if phase == 0 else 4  # the outputs on every r-th step, the velocities on all
        for i in range(n):
            ar[i] = 0.0
            ai[i] = 0.0
        for j in range(m):  # the modes' inputs b_i . u[k]
            uj = u[k, j]
            brj = BrT[j]
            bij = BiT[j]
            for i in range(n):
                ar[i] += brj[i] * uj
                ai[i] += bij[i] * uj
        for i in range(n):
            a = ar[i]
            b = ai[i]
            # x = g1 w + z0; z0 <- g0 w + phi x + z1; z1 <- gm w (lfilter's recurrence)
            x_r = g1r[i] * a - g1i[i] * b + z0r[i]
            x_i = g1r[i] * b + g1i[i] * a + z0i[i]
            z0r[i] = g0r[i] * a - g0i[i] * b + (pr[i] * x_r - pi[i] * x_i) + z1r[i]
            z0i[i] = g0r[i] * b + g0i[i] * a + (pr[i] * x_i + pi[i] * x_r) + z1i[i]
            z1r[i] = gmr[i] * a - gmi[i] * b
            z1i[i] = gmr[i] * b + gmi[i] * a
            xr[i] = x_r
            xi[i] = x_i
        if outputs:
            for o in range(q):
                acc[o] = 0.0
            for j in range(m):
                uj = u[k, j]
                dj = DT[j]
                for o in range(q):
                    acc[o] += dj[o] * uj
            for i in range(n):  # Re(C[o, i] x)
                x_r = xr[i]
                x_i = xi[i]
                cr = CrT[i]
                ci = CmiT[i]
                for o in range(q):
                    acc[o] += cr[o] * x_r + ci[o] * x_i
            for o in range(4):
                v[k, o] = acc[o]
            if phase == 0:
                kk = k // r
                for o in range(4, p):
                    y[kk, o - 4] = acc[o]
        phase += 1
        if phase == r:
            phase = 0


@_nb.njit(cache=True, error_model="numpy", parallel=True, nogil=True)
def rig_kernel(u, BrT, BiT, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, pLr, pLi, CrT, CmiT, DT, r,
               L, n_chunks, v, y):
    """Kernel of :func:`ident.sim.closedloop.rig_response`'s outputs, parallel over time
    chunks of `L` steps.

    ``u`` (N, m) inputs; ``B.T`` (m, n) split in real and imaginary parts; the hold
    coefficients per mode; ``pL = phi^(L-1)``; ``CrT = Re(C).T``, ``CmiT = -Im(C).T`` (n, p)
    and ``DT = D.T`` (m, p), whose first 4 columns (the shock velocities) go to ``v`` (N, 4)
    on every step and the rest to ``y`` (n_out, p - 4) on every r-th step.
    """
    N = u.shape[0]
    n = pr.size
    S = np.zeros((n_chunks, 4, n))  # chunk start states
    if n_chunks > 1:
        E = np.zeros((n_chunks, 4, n))  # chunk end states from rest
        for c in _nb.prange(n_chunks - 1):
            _rig_chunk(u, BrT, BiT, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, CrT, CmiT, DT, r, E[c],
                       c * L, (c + 1) * L, v, y, False)
        for c in range(1, n_chunks):
            for i in range(n):
                # the previous start state propagated over a chunk without input, plus the
                # previous chunk's own response from rest
                qr = pr[i] * S[c - 1, 0, i] - pi[i] * S[c - 1, 1, i] + S[c - 1, 2, i]
                qi = pr[i] * S[c - 1, 1, i] + pi[i] * S[c - 1, 0, i] + S[c - 1, 3, i]
                S[c, 0, i] = E[c - 1, 0, i] + (pLr[i] * qr - pLi[i] * qi)
                S[c, 1, i] = E[c - 1, 1, i] + (pLr[i] * qi + pLi[i] * qr)
                S[c, 2, i] = E[c - 1, 2, i]
                S[c, 3, i] = E[c - 1, 3, i]
    for c in _nb.prange(n_chunks):
        _rig_chunk(u, BrT, BiT, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, CrT, CmiT, DT, r, S[c],
                   c * L, min(N, (c + 1) * L), v, y, True)


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _segment_line(seg, kv, kf, c, nk, slo, shi):
    """Slope and intercept of segment `seg` of row `c` (0: below the knots, nk: above, else
    between knots seg-1 and seg): f = a + s v on it."""
    if seg <= 0:
        return slo, kf[c, 0] - slo * kv[c, 0]
    if seg >= nk:
        return shi, kf[c, nk - 1] - shi * kv[c, nk - 1]
    s = (kf[c, seg] - kf[c, seg - 1]) / (kv[c, seg] - kv[c, seg - 1])
    return s, kf[c, seg - 1] - s * kv[c, seg - 1]


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _segment_of(v, kv, c, nk, guess):
    """Segment index of v on row `c` (as _pwl), checking the guessed segment and its two
    neighbours first (a binary search otherwise)."""
    if guess <= 0:
        if v <= kv[c, 0]:
            return 0
    elif guess >= nk:
        if v >= kv[c, nk - 1]:
            return nk
    elif kv[c, guess - 1] < v < kv[c, guess]:
        return guess
    # a neighbouring segment, the usual move in one step (strict bounds: a velocity on a
    # knot is left to the search below, which decides it; the same index either way)
    up = guess + 1
    if 1 <= up <= nk - 1 and kv[c, up - 1] < v < kv[c, up]:
        return up
    dn = guess - 1
    if 1 <= dn <= nk - 1 and kv[c, dn - 1] < v < kv[c, dn]:
        return dn
    if v <= kv[c, 0]:
        return 0
    if v >= kv[c, nk - 1]:
        return nk
    lo = 0
    hi = nk - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if kv[c, mid] <= v:
            lo = mid
        else:
            hi = mid
    return hi


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _pwl(v, kv, kf, c, nk, slo, shi):
    """Force, slope and segment index of the piecewise-linear curve of row `c` of the knot
    arrays (linear end extensions). Rows are indexed in place: no array views are made in
    the shock loop's inner steps."""
    seg = _segment_of(v, kv, c, nk, -1)
    s, a = _segment_line(seg, kv, kf, c, nk, slo, shi)
    return a + s * v, s, seg


@_nb.njit(cache=True, error_model="numpy")
def solver_state(kv, nk):
    """Fresh per-setup state of :func:`shock_step`: ``v, vfree, c0, fv, sv, seg, av, vnew,
    res, J, Jinv, state`` (velocities at rest, each shock on the segment holding 0)."""
    m = 4
    seg = np.zeros(m, dtype=np.int64)
    for c in range(m):
        seg[c] = _segment_of(0.0, kv, c, nk[c], 0)
    return (np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m), seg, np.zeros(m),
            np.zeros(m), np.zeros(m), np.zeros((m, m)), np.zeros((m, m)),
            np.zeros(1, dtype=np.int64))


@_nb.njit(cache=True, error_model="numpy", inline="always")
def invert_small(J, Jinv, m):
    """Jinv <- inverse of J (Gauss-Jordan with partial pivoting); J is overwritten.

    Real or complex (numba specializes per dtype); inlined, so the screening's per-band
    solve (:mod:`planner.screen`) costs no call.
    """
    for i in range(m):
        for j in range(m):
            Jinv[i, j] = 1.0 if i == j else 0.0
    for c in range(m):
        p = c
        big = abs(J[c, c])
        for i in range(c + 1, m):
            if abs(J[i, c]) > big:
                big = abs(J[i, c])
                p = i
        if p != c:
            for j in range(m):
                t = J[c, j]
                J[c, j] = J[p, j]
                J[p, j] = t
                t = Jinv[c, j]
                Jinv[c, j] = Jinv[p, j]
                Jinv[p, j] = t
        d = 1.0 / J[c, c]
        for j in range(m):
            J[c, j] *= d
            Jinv[c, j] *= d
        for i in range(m):
            if i != c:
                fct = J[i, c]
                if fct != 0.0:
                    for j in range(m):
                        J[i, j] -= fct * J[c, j]
                        Jinv[i, j] -= fct * Jinv[c, j]


#: Segment-change passes tried with rank-1 updates of the cached inverse (and of the
#: solution) before the full solve (with its damped Newton fallback) takes over.
_FAST_ITERATIONS = 6
#: Rank-1 updates of the cached inverse before it is recomputed from scratch.
_MAX_RANK1_UPDATES = 64


#: Smallest velocity scale of the damped Newton iteration's convergence test [m/s]: a step
#: below 1e-12 of it (1e-15 m/s) ends the iteration. At rest the solution sits on a knot
#: (every curve has one at 0), where half steps of 1e-20 m/s can cycle between segments.
_V_SCALE_MIN_M_S = 1e-3


@_nb.njit(cache=True, error_model="numpy")
def shock_step(vfree, c0, Deff, cbar, b0, kv, kf, nk, slo, shi, v, fv, sv, seg, av, vnew, res,
               J, Jinv, state):
    """Solve one step of the shock loop in place; return the iteration count (-1: failed).

    Solves ``v = vfree + Deff (c0 + b0 f(v) - cbar v)`` for the 4 shock velocities and
    leaves ``f(v)`` in `fv`. `seg`, `Jinv` and ``state[0]`` (0: `Jinv` invalid; k >= 1:
    valid for `seg`, k - 1 rank-1 updates since it was computed) carry over between steps.
    Shared by the modal and the FIR simulators; the modal time loop first tries the
    common cases inline (every shock on its segment, or segment changes by rank-1 updates
    of the cached inverse) and calls this for the rest. Not inlined: an inlined body with
    many array arguments costs more in reference counting than the solve.
    """
    m = 4
    # Solve v = vfree + Deff (c0 + b0 f(v) - cbar v). f is piecewise linear, so on a
    # fixed set of segments (f = a + s v) this is linear: J v = vfree + Deff (c0 + b0 a)
    # with J = I - Deff diag(b0 s - cbar). Assume the last step's segments, solve with
    # the cached inverse, and accept when v stays on them (exact); otherwise move to
    # the new segments (a Newton step) and repeat. Damped Newton if segments cycle.
    it = 0
    while True:
        if state[0] == 0:
            for c in range(m):
                sl_c, a_c = _segment_line(seg[c], kv, kf, c, nk[c], slo[c], shi[c])
                sv[c] = sl_c
                av[c] = a_c
            for c in range(m):
                for j in range(m):
                    J[c, j] = -Deff[c, j] * (b0[j] * sv[j] - cbar[j])
                J[c, c] += 1.0
            invert_small(J, Jinv, m)
            state[0] = 1
        for c in range(m):
            acc = vfree[c]
            for j in range(m):
                acc += Deff[c, j] * (c0[j] + b0[j] * av[j])
            res[c] = acc
        same = True
        for c in range(m):
            acc = 0.0
            for j in range(m):
                acc += Jinv[c, j] * res[j]
            vnew[c] = acc
        for c in range(m):
            s2 = _segment_of(vnew[c], kv, c, nk[c], seg[c])
            if s2 != seg[c]:
                same = False
                seg[c] = s2
        it += 1
        if same:
            for c in range(m):
                v[c] = vnew[c]
            break
        state[0] = 0
        if it >= 12:
            # segments cycle at a kink: damped Newton from the last accepted v
            itn = 0
            while True:
                for c in range(m):
                    fv[c], sv[c], seg[c] = _pwl(v[c], kv, kf, c, nk[c], slo[c], shi[c])
                for c in range(m):
                    acc = 0.0
                    for j in range(m):
                        acc += Deff[c, j] * (c0[j] + b0[j] * fv[j] - cbar[j] * v[j])
                        J[c, j] = -Deff[c, j] * (b0[j] * sv[j] - cbar[j])
                    res[c] = vfree[c] + acc - v[c]
                    J[c, c] += 1.0
                # Newton step J d = res; Jinv is scratch here (state[0] is reset below)
                invert_small(J, Jinv, m)
                for c in range(m):
                    acc = 0.0
                    for j in range(m):
                        acc += Jinv[c, j] * res[j]
                    vnew[c] = acc
                step = 0.0
                scale = _V_SCALE_MIN_M_S
                for c in range(m):
                    v[c] += 0.5 * vnew[c]
                    step = max(step, abs(vnew[c]))
                    scale = max(scale, abs(v[c]))
                itn += 1
                if step <= 1e-12 * scale:
                    break
                if itn >= 200:
                    return -1
            it += itn
            state[0] = 0
            break
    if state[0] >= 1:  # accepted on the cached segments: f is their line there
        for c in range(m):
            fv[c] = av[c] + sv[c] * v[c]
        return it
    for c in range(m):
        fv[c], sl_c, s3 = _pwl(v[c], kv, kf, c, nk[c], slo[c], shi[c])
        if s3 != seg[c]:
            seg[c] = s3
    return it


#: Output samples gathered before one matrix product writes them (the loop's states are
#: buffered so the outputs cost a BLAS product per block, not a scalar sum per sample).
#: 128 with one product of ``[Re x, Im x, dF]``: 0.65 ms less per setup (12,000 samples,
#: 11 modes, 16 outputs) than three products of 64 samples (``Re x``, ``Im x``, ``dF``).
_OUT_BLOCK = 128


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _fast_solve(vfree, c0, Deff, b0, kv, nk, lines_s, lines_a, v, fv, sv, seg, av, vnew, res, J,
                Jinv, state):
    """The shock loop's common cases (see :func:`loop_one`); returns the iteration count, 0
    when :func:`shock_step` must solve the step. Inlined: the same operations in the same
    order wherever it is used."""
    m = 4
    # the common cases inline: every shock on its segment, or segment changes (a zero
    # crossing of a digressive shock, a knee) by Sherman-Morrison updates of the cached
    # inverse of J = I - Deff diag(b0 s - cbar); the rest in shock_step. One solve per
    # step: a segment change of shock c is a rank-1 change of J and of the right-hand
    # side along d = Deff[:, c], so the new solution is the last one plus
    # J'^-1 d (= Jinv d / den) times the force change the new line makes at v_c.
    it = 0
    if state[0] >= 1:
        for c in range(m):
            acc = vfree[c]
            for j in range(m):
                acc += Deff[c, j] * (c0[j] + b0[j] * av[j])
            res[c] = acc
        for c in range(m):
            acc = 0.0
            for j in range(m):
                acc += Jinv[c, j] * res[j]
            vnew[c] = acc
        for it_ in range(1, _FAST_ITERATIONS + 1):
            same = True
            for c in range(m):
                s2 = _segment_of(vnew[c], kv, c, nk[c], seg[c])
                if s2 == seg[c]:
                    continue
                same = False
                sl2 = lines_s[c, s2]
                a2 = lines_a[c, s2]
                dsl = sl2 - sv[c]
                # the force change at vnew[c] that the new line makes, through shock c
                dfc = b0[c] * ((a2 - av[c]) + dsl * vnew[c])
                for r_ in range(m):  # u = Jinv Deff[:, c]
                    acc = 0.0
                    for j in range(m):
                        acc += Jinv[r_, j] * Deff[j, c]
                    res[r_] = acc
                dsc = b0[c] * dsl
                den = 1.0 - dsc * res[c]
                if abs(den) < 1e-8:
                    seg[c] = s2
                    av[c] = a2
                    state[0] = 0
                    break
                # the solution on the new segments (Sherman-Morrison: J'^-1 d = u / den)
                g = dfc / den
                for r_ in range(m):
                    vnew[r_] += res[r_] * g
                seg[c] = s2
                av[c] = a2
                if dsl != 0.0:
                    q = dsc / den
                    for j in range(m):
                        J[0, j] = Jinv[c, j] * q
                    for r_ in range(m):
                        for j in range(m):
                            Jinv[r_, j] += res[r_] * J[0, j]
                    sv[c] = sl2
                    state[0] += 1
            if same:
                for c in range(m):
                    v[c] = vnew[c]
                    fv[c] = av[c] + sv[c] * vnew[c]
                it = it_
                if state[0] > _MAX_RANK1_UPDATES:
                    state[0] = 0
                break
            if state[0] == 0 or state[0] > _MAX_RANK1_UPDATES:
                state[0] = 0
                break
    return it


@_nb.njit(cache=True, error_model="numpy")
def loop_one(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar,
             kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy, y_rig, y_out, F_out, v_row):
    """Time loop of one setup on the internal grid.

    The modal states are held as separate real and imaginary arrays (the mode loops
    vectorize). At every r-th step (an output sample) the states and ``dF`` are buffered
    as rows ``[Re x, Im x, dF]``; every :data:`_OUT_BLOCK` samples the outputs
    ``y_rig + Re(Cy x) + Dy dF`` are written by one matrix product with ``Cy`` (2 n + 4,
    p) ``= [Re(Cy).T; -Im(Cy).T; Dy.T]``, and the applied shock forces per sample. With
    ``v_row >= 0`` the shock velocities the loop solved for go to the rows ``v_row ..
    v_row + 3`` of `y_out` (they equal the velocity outputs: ``v = v_free + Deff dF``).
    Returns the largest Newton iteration count (-1: no convergence).
    """
    n = pr.size
    m = 4
    p = Cy.shape[1]
    N = v_rig.shape[0]
    n_out = y_out.shape[1]
    xr = np.zeros(n)
    xi = np.zeros(n)
    bdr = np.zeros(n)  # B dF of the last step
    bdi = np.zeros(n)
    bpr = np.zeros(n)  # B dF of the step before
    bpi = np.zeros(n)
    St = np.zeros((_OUT_BLOCK, 2 * n + m))  # output samples' [Re x, Im x, dF]
    dF_prev = np.zeros(m)
    F_prev = np.zeros(m)
    f_prev = np.zeros(m)
    f_prev2 = np.zeros(m)
    v, vfree, c0, fv, sv, seg, av, vnew, res, J, Jinv, state = solver_state(kv, nk)
    # every segment's line (slope, intercept) once, for the segment changes below
    lines_s = np.empty((m, kv.shape[1] + 1))
    lines_a = np.empty((m, kv.shape[1] + 1))
    for c in range(m):
        for sg in range(nk[c] + 1):
            lines_s[c, sg], lines_a[c, sg] = _segment_line(sg, kv, kf, c, nk[c], slo[c], shi[c])
    worst = 0
    failed = False
    col = 0
    kk0 = 0
    phase = 0  # k % r
    for k in range(N):
        # predictor: x[k] without the unknown g1 * B dF[k] term, and v_free from it
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        for i in range(n):
            tr = (pr[i] * xr[i] - pi[i] * xi[i] + g0r[i] * bdr[i] - g0i[i] * bdi[i]
                  + gmr[i] * bpr[i] - gmi[i] * bpi[i])
            ti = (pr[i] * xi[i] + pi[i] * xr[i] + g0r[i] * bdi[i] + g0i[i] * bdr[i]
                  + gmr[i] * bpi[i] + gmi[i] * bpr[i])
            xr[i] = tr
            xi[i] = ti
        # the velocities in a loop of their own: the update above has no loop-carried
        # chain and vectorizes; fused with these sums (strict FP order) it ran scalar.
        # Same sums in the same order as before, so the same rounding.
        for i in range(n):
            tr = xr[i]
            ti = xi[i]
            a0 += Cvr[0, i] * tr - Cvi[0, i] * ti
            a1 += Cvr[1, i] * tr - Cvi[1, i] * ti
            a2 += Cvr[2, i] * tr - Cvi[2, i] * ti
            a3 += Cvr[3, i] * tr - Cvi[3, i] * ti
        vfree[0] = v_rig[k, 0] + a0
        vfree[1] = v_rig[k, 1] + a1
        vfree[2] = v_rig[k, 2] + a2
        vfree[3] = v_rig[k, 3] + a3
        for c in range(m):
            c0[c] = alpha[c] * F_prev[c] + b1[c] * f_prev[c] + bm[c] * f_prev2[c]
        it = _fast_solve(vfree, c0, Deff, b0, kv, nk, lines_s, lines_a, v, fv, sv, seg, av,
                         vnew, res, J, Jinv, state)
        if it == 0:
            it = shock_step(vfree, c0, Deff, cbar, b0, kv, kf, nk, slo, shi, v, fv, sv, seg, av,
                            vnew, res, J, Jinv, state)
        if it < 0:
            failed = True
            it = 80
        if it > worst:
            worst = it
        for c in range(m):
            F = c0[c] + b0[c] * fv[c]
            F_prev[c] = F
            f_prev2[c] = f_prev[c]
            f_prev[c] = fv[c]
            dF_prev[c] = F - cbar[c] * v[c]
        # corrector: complete x[k] with g1 * B dF[k]
        d0 = dF_prev[0]
        d1 = dF_prev[1]
        d2 = dF_prev[2]
        d3 = dF_prev[3]
        for i in range(n):
            ur = Br[0, i] * d0 + Br[1, i] * d1 + Br[2, i] * d2 + Br[3, i] * d3
            ui = Bi[0, i] * d0 + Bi[1, i] * d1 + Bi[2, i] * d2 + Bi[3, i] * d3
            bpr[i] = bdr[i]
            bpi[i] = bdi[i]
            bdr[i] = ur
            bdi[i] = ui
            xr[i] += g1r[i] * ur - g1i[i] * ui
            xi[i] += g1r[i] * ui + g1i[i] * ur
        # an output sample every r-th step (a counter: no integer division per step)
        if phase == 0:
            kk = k // r
            for c in range(m):
                F_out[kk, c] = F_prev[c]
                St[col, 2 * n + c] = dF_prev[c]
            if v_row >= 0:
                for c in range(m):
                    y_out[v_row + c, kk] = v[c]
            for i in range(n):
                St[col, i] = xr[i]
                St[col, n + i] = xi[i]
            col += 1
            if col == _OUT_BLOCK or kk == n_out - 1:
                Y = np.dot(St[:col], Cy)  # (col, p)
                for j in range(col):
                    for o in range(p):
                        y_out[o, kk0 + j] = y_rig[kk0 + j, o] + Y[j, o]
                kk0 += col
                col = 0
        phase += 1
        if phase == r:
            phase = 0
    return -1 if failed else worst


@_nb.njit(cache=True, error_model="numpy", parallel=True)
def loop_batch(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar,
               kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy, y_rig, y_out, F_out, iters):
    """The closed loop of every setup (``kv`` and the curves' other arrays: one row per
    setup, as :func:`ident.sim.closedloop.pack_setups` packs them), in parallel over the
    setups, each by :func:`loop_one`: outputs into ``y_out`` (n_setups, p, n_out), applied
    shock forces into ``F_out`` (n_setups, n_out, 4), Newton iteration counts into
    ``iters`` (-1: no convergence)."""
    for s in _nb.prange(kv.shape[0]):
        iters[s] = loop_one(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff,
                            v_rig, cbar, kv[s], kf[s], nk[s], slo[s], shi[s], alpha[s], b0[s],
                            b1[s], bm[s], r, Cy, y_rig, y_out[s], F_out[s], -1)
    return


@_nb.njit(cache=True, error_model="numpy", nogil=True)
def loop_serial(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar,
                kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy, y_rig, y_out, F_out, iters):
    """:func:`loop_batch` one setup after the other (the same `loop_one`, the same numbers).

    A single setup gains nothing from the parallel loop, and this kernel compiles in about
    60 % of its time: the virtual rig (one setup per run) uses it, so a fresh machine's first
    ``rig simulate`` or demo waits for the smaller compilation only (the demo compiles the
    parallel kernel meanwhile in a worker). It releases the GIL (as :func:`rig_kernel`
    does): the virtual rig runs its runs on threads.
    """
    for s in range(kv.shape[0]):
        iters[s] = loop_one(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff,
                            v_rig, cbar, kv[s], kf[s], nk[s], slo[s], shi[s], alpha[s], b0[s],
                            b1[s], bm[s], r, Cy, y_rig, y_out[s], F_out[s], -1)
    return


@_nb.njit(cache=True, error_model="numpy", nogil=True)
def loop_metrics_worker(w, n_workers, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi,
                        Deff, v_rig, cbar, kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy,
                        y_rig, n_out, ia, sos, zi, padlen, out, iters):
    """Worker `w` of `n_workers` of :func:`ident.sim.closedloop.simulate_batch_metrics`:
    the setups ``w, w + n_workers, ...`` (interleaved, so that each worker gets a mix of
    cheap and costly setups), each simulated by :func:`loop_one` and its metrics computed
    right after (:func:`ident.sim.metric_kernels.setup_metric_rms`, per band: ``sos``
    (n_bands, n_sections, 6), ``zi`` (n_bands, n_sections, 2)) into ``out`` (n_setups,
    n_bands, n_metrics).

    The outputs ``Cy`` (2 n + 4, p) are the metrics' signals (a ride height pair as one
    row of averaged coefficients); the shock velocities come from the loop's own solve
    (rows p .. p + 3 of the setup's buffer), not from the product. The worker keeps one
    setup's outputs and the metric's scratch (about 2 MB for 12,000 samples): nothing of
    size (setups x samples) is written. It releases the GIL: the workers are threads.
    """
    p = Cy.shape[1]
    L = METRIC_LANES
    ns = sos.shape[1]
    S = kv.shape[0]
    # the outputs, then the 4 shock velocities. Channel-major, as simulate_batch's: the
    # loop kernel is then the one-setup loop's compiled code (sample-major rows were about
    # 4 % faster but compile the loop once more, 4 s on a fresh machine's first demo)
    y = np.empty((p + 4, n_out))
    F = np.empty((n_out, 4))
    buf = np.empty((n_out + 2 * padlen, L))
    z0 = np.empty((ns, L))
    z1 = np.empty((ns, L))
    stack = np.empty((METRIC_PW_LEVELS, 10, L))
    sums = np.empty(L)
    for s in range(w, S, n_workers):
        iters[s] = loop_one(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff,
                            v_rig, cbar, kv[s], kf[s], nk[s], slo[s], shi[s], alpha[s], b0[s],
                            b1[s], bm[s], r, Cy, y_rig, y, F, p)
        for b in range(sos.shape[0]):
            setup_metric_rms(y, ia, sos[b], zi[b], padlen, out[s, b], buf, z0, z1, stack, sums)
    return


# ----------------------------------------------------------------------------------------------
# the loop with the car's other nonlinear elements: bump stops and tire lift-off (issue 25)
# ----------------------------------------------------------------------------------------------

#: Largest element iterations per step (each one a shock solve) before the step is reported
#: as failed. The iteration contracts by the bump stop's stiffness times the travel's
#: same-step response to a force (0.04 at 600 kN/m on a GT car at 200 Hz internal steps),
#: and the Newton update takes out its diagonal: 2-4 iterations in contact.
ELEMENT_MAX_ITERATIONS = 60
#: Pad-correction change (as a contact force) below which the element iteration has
#: converged [N]: 1e-9 of a kN force (the results move by 2e-9 relative against 1e-9 N, at
#: 8 % fewer solves). The lift-off share counts the samples with a pad correction, so it is
#: solved tightly (at 1e-3 N one sample in 2,000 moved between lifted and not).
ELEMENT_TOL_N = 1e-6
#: Bump-stop force change below which the element iteration has converged [N]: 1e-6 of a
#: kN force. A contact step then takes 2 solves (the first guess, then the check of the
#: Newton update) where 1e-6 N took a third in half of them: the time with stops touched
#: 4-8 % drops by 3 % (1.33x to 1.30x of the plain loop's, one setup after the other); the
#: metrics move by 1e-8 relative at most (GT car, 24 setups, 120 s).
ELEMENT_STOP_TOL_N = 1e-3


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _stop_force(s, c, s0, bx, bf, bn, bslope):
    """Bump-stop force and slope of corner `c` at shock travel `s` (compression positive):
    zero up to the contact travel ``s0[c]``, then the table ``bx[c], bf[c]`` (``bn[c]``
    points, travel beyond contact from 0) linearly interpolated, extended with ``bslope[c]``."""
    x = s - s0[c]
    if x <= 0.0:
        return 0.0, 0.0
    n = bn[c]
    if x >= bx[c, n - 1]:
        return bf[c, n - 1] + bslope[c] * (x - bx[c, n - 1]), bslope[c]
    lo = 0
    hi = n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if bx[c, mid] <= x:
            lo = mid
        else:
            hi = mid
    k = (bf[c, hi] - bf[c, lo]) / (bx[c, hi] - bx[c, lo])
    return bf[c, lo] + k * (x - bx[c, lo]), k


@_nb.njit(cache=True, error_model="numpy")
def loop_one_elements(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar,
                      kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy, y_rig, y_out, F_out, v_row,
                      Bwr, Bwi, Cer, Cei, e_rig, Dt, Dtw, Dvw, Dcf, Dcw, bs_on, s0, bx, bf, bn,
                      bslope, lo_on, static, tf_rows, max_iter, stats):
    """:func:`loop_one` with bump stops and tire lift-off in the loop.

    The plant's force input of corner ``c`` is ``dF = F_shock + G(s) - cbar v`` with ``G``
    the bump stop's force at the shock travel ``s``; with lift-off the pad input of corner
    ``c`` gets ``w_c >= 0`` (``Bw``: the modes' wheelloader columns), the pad following the
    tire so that the contact force ``static + tire_force`` is zero while ``w_c > 0``.

    Per step: the predictor gives ``v_free`` and the element rows' free parts ``s_free``,
    ``c_free`` (``Ce`` (8, n): travel then tire force rows; ``e_rig`` (N, 8): their
    rig-input part on the internal grid). Then, until ``G`` and ``w`` stop changing (by
    :data:`ELEMENT_STOP_TOL_N`, :data:`ELEMENT_TOL_N`): the shock solve with ``v_free +
    Deff G + Dvw w``; the travel
    ``s = s_free + Dt dF + Dtw w`` and contact ``c = static + c_free + Dcf dF + Dcw w``;
    Newton updates of ``G`` on ``G - g(s)`` and of ``w`` on ``c = 0`` with their diagonal
    derivatives (``Dt[c, c] g'(s)`` and ``Dcw[c, c]``). So the travel, the bump-stop force,
    the contact and the shock forces agree within the step (implicit); ``max_iter = 1``
    evaluates ``G`` at the travel extrapolated from the state and the last step's force
    (explicit: kept to measure what the iteration buys).

    ``F_out`` holds the shock forces only (the load cell measures the shock). ``Cy`` has
    rows ``[Re x, Im x, dF, w]`` (the ``w`` rows only with lift-off, ``Bwr.shape[0] == 4``
    then; 0 rows without). At an output sample with ``w_c > 0`` the output row
    ``tf_rows[c]`` (the tire force, if an output) is set to ``-static[c]`` exactly.
    ``stats`` (3, 4): output samples in bump-stop contact, output samples lifted off,
    smallest contact force. Returns the largest Newton iteration count over the element
    iterations of a step (-1: no convergence).
    """
    n = pr.size
    m = 4
    p = Cy.shape[1]
    N = v_rig.shape[0]
    n_out = y_out.shape[1]
    nw = Bwr.shape[0]  # 4 with lift-off, 0 without
    CeTr = np.ascontiguousarray(Cer.T)
    CeTi = np.ascontiguousarray(Cei.T)
    any_bs = False
    any_lo = False
    for c in range(m):
        if bs_on[c]:
            any_bs = True
        if lo_on[c]:
            any_lo = True
    xr = np.zeros(n)
    xi = np.zeros(n)
    bdr = np.zeros(n)
    bdi = np.zeros(n)
    bpr = np.zeros(n)
    bpi = np.zeros(n)
    St = np.zeros((_OUT_BLOCK, 2 * n + m + nw))
    dF_prev = np.zeros(m)
    F_prev = np.zeros(m)
    f_prev = np.zeros(m)
    f_prev2 = np.zeros(m)
    vf2 = np.zeros(m)
    sfree = np.zeros(m)
    cfree = np.zeros(m)
    G = np.zeros(m)
    Gn = np.zeros(m)
    w = np.zeros(m)
    wn = np.zeros(m)
    s = np.zeros(m)
    cc = np.zeros(m)
    Fsh = np.zeros(m)
    v, vfree, c0, fv, sv, seg, av, vnew, res, J, Jinv, state = solver_state(kv, nk)
    lines_s = np.empty((m, kv.shape[1] + 1))
    lines_a = np.empty((m, kv.shape[1] + 1))
    for c in range(m):
        for sg in range(nk[c] + 1):
            lines_s[c, sg], lines_a[c, sg] = _segment_line(sg, kv, kf, c, nk[c], slo[c], shi[c])
    # the counts in arrays of the kernel's own, written to `stats` at the end: stores into an
    # argument inside the time loop (which may alias the others, for all the compiler
    # knows) made the whole loop twice as slow
    n_bs = np.zeros(m)
    n_lo = np.zeros(m)
    c_min = np.full(m, np.inf)
    worst = 0
    failed = False
    col = 0
    kk0 = 0
    phase = 0
    for k in range(N):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        for i in range(n):
            tr = (pr[i] * xr[i] - pi[i] * xi[i] + g0r[i] * bdr[i] - g0i[i] * bdi[i]
                  + gmr[i] * bpr[i] - gmi[i] * bpi[i])
            ti = (pr[i] * xi[i] + pi[i] * xr[i] + g0r[i] * bdi[i] + g0i[i] * bdr[i]
                  + gmr[i] * bpi[i] + gmi[i] * bpr[i])
            xr[i] = tr
            xi[i] = ti
        for i in range(n):
            tr = xr[i]
            ti = xi[i]
            a0 += Cvr[0, i] * tr - Cvi[0, i] * ti
            a1 += Cvr[1, i] * tr - Cvi[1, i] * ti
            a2 += Cvr[2, i] * tr - Cvi[2, i] * ti
            a3 += Cvr[3, i] * tr - Cvi[3, i] * ti
        if any_bs:
            # the travel rows (Ce rows 0-3, held mode-major: CeTr[i, c]), the 4 corners as
            # the inner loop, which the compiler can run as one vector
            for c in range(m):
                sfree[c] = e_rig[k, c]
            for i in range(n):
                tr = xr[i]
                ti = xi[i]
                for c in range(m):
                    sfree[c] += CeTr[i, c] * tr - CeTi[i, c] * ti
        vfree[0] = v_rig[k, 0] + a0
        vfree[1] = v_rig[k, 1] + a1
        vfree[2] = v_rig[k, 2] + a2
        vfree[3] = v_rig[k, 3] + a3
        if any_lo:
            for c in range(m):
                cfree[c] = static[c] + e_rig[k, 4 + c]
            for i in range(n):
                tr = xr[i]
                ti = xi[i]
                for c in range(m):
                    cfree[c] += CeTr[i, 4 + c] * tr - CeTi[i, 4 + c] * ti
        for c in range(m):
            c0[c] = alpha[c] * F_prev[c] + b1[c] * f_prev[c] + bm[c] * f_prev2[c]
        # first guesses: the bump-stop forces and pad corrections of the last step (zero
        # out of contact, the common case: one solve, then the check). The explicit
        # variant (max_iter 1) takes the stop at the travel extrapolated with the last
        # step's inputs.
        if any_bs:
            for c in range(m):
                if bs_on[c] and (G[c] != 0.0 or sfree[c] > s0[c] or max_iter == 1):
                    acc = sfree[c]
                    for j in range(m):
                        acc += Dt[c, j] * dF_prev[j] + Dtw[c, j] * w[j]
                    G[c], kb = _stop_force(acc, c, s0, bx, bf, bn, bslope)
        step_worst = 0
        for itx in range(max_iter):
            for c in range(m):
                vf2[c] = vfree[c]
            g_any = False
            for c in range(m):
                if G[c] != 0.0:
                    g_any = True
            if g_any:
                for c in range(m):
                    acc = vf2[c]
                    for j in range(m):
                        acc += Deff[c, j] * G[j]
                    vf2[c] = acc
            w_nz = False
            if any_lo:
                for c in range(m):
                    if w[c] != 0.0:
                        w_nz = True
            if w_nz:
                for c in range(m):
                    acc = vf2[c]
                    for j in range(m):
                        acc += Dvw[c, j] * w[j]
                    vf2[c] = acc
            it = _fast_solve(vf2, c0, Deff, b0, kv, nk, lines_s, lines_a, v, fv, sv, seg, av,
                             vnew, res, J, Jinv, state)
            if it == 0:
                it = shock_step(vf2, c0, Deff, cbar, b0, kv, kf, nk, slo, shi, v, fv, sv, seg,
                                av, vnew, res, J, Jinv, state)
            if it < 0:
                failed = True
                it = 80
            step_worst = max(step_worst, it)
            for c in range(m):
                Fsh[c] = c0[c] + b0[c] * fv[c]
                dF_prev[c] = Fsh[c] - cbar[c] * v[c] + G[c]
            change = 0.0  # of the pad corrections
            change_g = 0.0  # of the bump-stop forces
            if any_bs:
                for c in range(m):
                    acc = sfree[c]
                    for j in range(m):
                        acc += Dt[c, j] * dF_prev[j]
                    if any_lo:
                        for j in range(m):
                            acc += Dtw[c, j] * w[j]
                    s[c] = acc
                    Gn[c] = G[c]
                    if bs_on[c] and (acc > s0[c] or G[c] != 0.0):
                        g, kb = _stop_force(acc, c, s0, bx, bf, bn, bslope)
                        # Newton on G - g(s(G)) with ds_c/dG_c: through the plant (Dt[c, c],
                        # < 0: the stop pushes the wheel away) and the shocks' answer (with
                        # the solve's cached inverse: dv/dG = Jinv Deff)
                        dsdg = Dt[c, c]
                        if state[0] >= 1:
                            for j in range(m):
                                u = 0.0
                                for q in range(m):
                                    u += Jinv[j, q] * Deff[q, c]
                                dsdg += Dt[c, j] * (b0[j] * sv[j] - cbar[j]) * u
                        den = 1.0 - kb * dsdg
                        den = max(den, 0.5)
                        Gn[c] = G[c] + (g - G[c]) / den
                        change_g = max(change_g, abs(Gn[c] - G[c]))
            if any_lo:
                for c in range(m):
                    acc = cfree[c]
                    for j in range(m):
                        acc += Dcf[c, j] * dF_prev[j] + Dcw[c, j] * w[j]
                    cc[c] = acc
                    wn[c] = w[c]
                    if lo_on[c]:
                        wn[c] = max(0.0, w[c] - acc / Dcw[c, c])
                        change = max(change, abs(Dcw[c, c] * (wn[c] - w[c])))
            if change <= ELEMENT_TOL_N and change_g <= ELEMENT_STOP_TOL_N:
                break
            if itx == max_iter - 1:
                if max_iter > 1:
                    failed = True
                break
            for c in range(m):
                G[c] = Gn[c]
                w[c] = wn[c]
        worst = max(worst, step_worst)
        for c in range(m):
            F_prev[c] = Fsh[c]
            f_prev2[c] = f_prev[c]
            f_prev[c] = fv[c]
        w_now = False
        for c in range(m):
            if w[c] != 0.0:
                w_now = True
        d0 = dF_prev[0]
        d1 = dF_prev[1]
        d2 = dF_prev[2]
        d3 = dF_prev[3]
        for i in range(n):
            ur = Br[0, i] * d0 + Br[1, i] * d1 + Br[2, i] * d2 + Br[3, i] * d3
            ui = Bi[0, i] * d0 + Bi[1, i] * d1 + Bi[2, i] * d2 + Bi[3, i] * d3
            bpr[i] = bdr[i]
            bpi[i] = bdi[i]
            bdr[i] = ur
            bdi[i] = ui
        if w_now:
            for i in range(n):
                bdr[i] += Bwr[0, i] * w[0] + Bwr[1, i] * w[1] + Bwr[2, i] * w[2] + Bwr[3, i] * w[3]
                bdi[i] += Bwi[0, i] * w[0] + Bwi[1, i] * w[1] + Bwi[2, i] * w[2] + Bwi[3, i] * w[3]
        for i in range(n):
            ur = bdr[i]
            ui = bdi[i]
            xr[i] += g1r[i] * ur - g1i[i] * ui
            xi[i] += g1r[i] * ui + g1i[i] * ur
        if phase == 0:
            kk = k // r
            for c in range(m):
                F_out[kk, c] = F_prev[c]
                St[col, 2 * n + c] = dF_prev[c]
            for c in range(nw):
                St[col, 2 * n + m + c] = w[c]
            if v_row >= 0:
                for c in range(m):
                    y_out[v_row + c, kk] = v[c]
            for i in range(n):
                St[col, i] = xr[i]
                St[col, n + i] = xi[i]
            for c in range(m):
                if bs_on[c] and s[c] > s0[c]:
                    n_bs[c] += 1.0
                if lo_on[c]:
                    cont = 0.0
                    if w[c] > 0.0:
                        n_lo[c] += 1.0
                    else:
                        cont = cc[c]
                    c_min[c] = min(c_min[c], cont)
            col += 1
            if col == _OUT_BLOCK or kk == n_out - 1:
                Y = np.dot(St[:col], Cy)
                for j in range(col):
                    for o in range(p):
                        y_out[o, kk0 + j] = y_rig[kk0 + j, o] + Y[j, o]
                if nw > 0:
                    for j in range(col):
                        for c in range(m):
                            if tf_rows[c] >= 0 and St[j, 2 * n + m + c] > 0.0:
                                y_out[tf_rows[c], kk0 + j] = -static[c]
                kk0 += col
                col = 0
        phase += 1
        if phase == r:
            phase = 0
    for c in range(m):
        stats[0, c] = n_bs[c]
        stats[1, c] = n_lo[c]
        stats[2, c] = c_min[c]
    return -1 if failed else worst


@_nb.njit(cache=True, error_model="numpy", nogil=True)
def loop_elements_serial(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig,
                         cbar, kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy, Bwr, Bwi, Cer, Cei,
                         e_rig, Dt, Dtw, Dvw, Dcf, Dcw, bs_on, s0, bx, bf, bn, bslope, lo_on,
                         static, tf_rows, max_iter, y_rig, y_out, F_out, iters, stats):
    """:func:`loop_one_elements` of every setup, one after the other: the element arrays
    ``bs_on, s0, bx, bf, bn, bslope, lo_on, static`` have one row per setup (bump stops and
    packers are setup choices), ``stats`` (n_setups, 3, 4)."""
    for s_ in range(kv.shape[0]):
        iters[s_] = loop_one_elements(
            pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar, kv[s_],
            kf[s_], nk[s_], slo[s_], shi[s_], alpha[s_], b0[s_], b1[s_], bm[s_], r, Cy, y_rig,
            y_out[s_], F_out[s_], -1, Bwr, Bwi, Cer, Cei, e_rig, Dt, Dtw, Dvw, Dcf, Dcw,
            bs_on[s_], s0[s_], bx[s_], bf[s_], bn[s_], bslope[s_], lo_on[s_], static[s_],
            tf_rows, max_iter, stats[s_])


@_nb.njit(cache=True, error_model="numpy", parallel=True)
def loop_elements_batch(pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig,
                        cbar, kv, kf, nk, slo, shi, alpha, b0, b1, bm, r, Cy, Bwr, Bwi, Cer, Cei,
                        e_rig, Dt, Dtw, Dvw, Dcf, Dcw, bs_on, s0, bx, bf, bn, bslope, lo_on,
                        static, tf_rows, max_iter, y_rig, y_out, F_out, iters, stats):
    """:func:`loop_elements_serial` in parallel over the setups (the same numbers)."""
    for s_ in _nb.prange(kv.shape[0]):
        iters[s_] = loop_one_elements(
            pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar, kv[s_],
            kf[s_], nk[s_], slo[s_], shi[s_], alpha[s_], b0[s_], b1[s_], bm[s_], r, Cy, y_rig,
            y_out[s_], F_out[s_], -1, Bwr, Bwi, Cer, Cei, e_rig, Dt, Dtw, Dvw, Dcf, Dcw,
            bs_on[s_], s0[s_], bx[s_], bf[s_], bn[s_], bslope[s_], lo_on[s_], static[s_],
            tf_rows, max_iter, stats[s_])


@_nb.njit(cache=True, error_model="numpy", nogil=True)
def loop_metrics_elements_worker(w, n_workers, pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi,
                                 Cvr, Cvi, Deff, v_rig, cbar, kv, kf, nk, slo, shi, alpha, b0,
                                 b1, bm, r, Cy, Bwr, Bwi, Cer, Cei, e_rig, Dt, Dtw, Dvw, Dcf, Dcw,
                                 bs_on, s0, bx, bf, bn, bslope, lo_on, static, tf_rows, max_iter,
                                 y_rig, n_out, ia, sos, zi, padlen, out, iters, stats):
    """:func:`loop_metrics_worker` with bump stops and tire lift-off: each setup of worker
    `w` simulated by :func:`loop_one_elements` (the element arrays one row per setup, as
    :func:`loop_elements_serial`) and its metrics computed right after into ``out``
    (n_setups, n_bands, n_metrics), the element counts into ``stats`` (n_setups, 3, 4).

    ``Cy`` (2 n + 4 (+ 4), p) are the metrics' signals with the ``w`` rows under lift-off
    (zero for a ride-height pair: measured from the real pad); ``tf_rows`` the columns of
    ``Cy`` holding the tire forces (-1: none), set to ``-static`` at lifted samples.
    """
    p = Cy.shape[1]
    L = METRIC_LANES
    ns = sos.shape[1]
    S = kv.shape[0]
    y = np.empty((p + 4, n_out))
    F = np.empty((n_out, 4))
    buf = np.empty((n_out + 2 * padlen, L))
    z0 = np.empty((ns, L))
    z1 = np.empty((ns, L))
    stack = np.empty((METRIC_PW_LEVELS, 10, L))
    sums = np.empty(L)
    for s_ in range(w, S, n_workers):
        iters[s_] = loop_one_elements(
            pr, pi, g1r, g1i, g0r, g0i, gmr, gmi, Br, Bi, Cvr, Cvi, Deff, v_rig, cbar, kv[s_],
            kf[s_], nk[s_], slo[s_], shi[s_], alpha[s_], b0[s_], b1[s_], bm[s_], r, Cy, y_rig,
            y, F, p, Bwr, Bwi, Cer, Cei, e_rig, Dt, Dtw, Dvw, Dcf, Dcw, bs_on[s_], s0[s_],
            bx[s_], bf[s_], bn[s_], bslope[s_], lo_on[s_], static[s_], tf_rows, max_iter,
            stats[s_])
        for b in range(sos.shape[0]):
            setup_metric_rms(y, ia, sos[b], zi[b], padlen, out[s_, b], buf, z0, z1, stack, sums)
