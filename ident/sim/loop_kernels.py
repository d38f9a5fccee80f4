"""Compiled kernels of the closed-loop simulator (numba): the rig-input response, the shock
loop's solve and the time loops.

The caller is :mod:`ident.sim.closedloop`, which checks every input and builds these
kernels' arguments (the FIR simulator, :mod:`ident.identify.fir`, takes the shock solve);
the kernels run no checks. Their arguments travel in named tuples (numba compiles a
function per argument type and reads a named tuple's fields at no cost):

- :class:`RigModes`: a plant's rig-input modes for :func:`rig_kernel`;
- :class:`ModalLoop`: the shock part's modes, its same-step velocity response ``Deff`` and
  ``cbar`` (shared by every setup of a batch);
- :class:`ShockSetups` (the curves and the lag's coefficients): the setups' shocks, one
  row per setup (:func:`ident.sim.closedloop.pack_setups`); :class:`ShockCurves`, one
  setup's curves for the shock solve;
- :class:`LoopDrive`: the drive's rig-input part on the internal grid and the outputs'
  coefficients;
- :class:`Elements`: bump stops and tire lift-off (issue 25), or ``None`` for a loop
  without them;
- :class:`ThirdLoop`: third elements (heave and roll dampers, heave springs: issue 38; the
  corner bump stops then among its springs), or ``None`` for a car without them;
- :class:`MetricFilters`: the fused metrics' channels and band-pass filters;
- :class:`SolverState`: the per-setup state and scratch of :func:`shock_step`.

Public kernels:

- :func:`rig_kernel`: the rig-input part of a plant's response on the internal grid,
  parallel over time chunks (:func:`ident.sim.closedloop.rig_response`);
- :func:`loop_one`: the time loop of one setup, with the elements or without
  (``elements=None``: numba compiles that case on its own and drops the elements' code
  from it at compile time, so the plain loop runs as fast as a loop without them);
- :func:`loop_batch`, :func:`loop_serial`: the closed loop of a batch of setups (parallel
  over setups, or one after the other);
- :func:`loop_metrics_worker`: a thread's share of the setups with their metrics computed
  right after each loop (:func:`ident.sim.metric_kernels.setup_metric_rms`);
- :func:`histogram_add`: a setup's shock-velocity histogram counts (the worker's, when
  asked);
- :func:`solver_state`, :func:`shock_step`: the per-step solve of the 4 shock equations,
  shared with the FIR simulator (:mod:`ident.identify.fir`); :func:`invert_small`, the
  4x4 inverse inside it.

The algebra is documented in :mod:`ident.sim.closedloop` (the modal loop, the quadratic
hold, Newton's method on the piecewise-linear shock curves).
"""

from __future__ import annotations

from collections import namedtuple

import numba as _nb
import numpy as np

from ident.sim.metric_kernels import LANES as METRIC_LANES
from ident.sim.metric_kernels import PW_LEVELS as METRIC_PW_LEVELS
from ident.sim.metric_kernels import setup_metric_rms

__all__ = [
    "RigModes",
    "ModalLoop",
    "ShockCurves",
    "ShockSetups",
    "LoopDrive",
    "Elements",
    "ThirdLoop",
    "MetricFilters",
    "SolverState",
    "rig_kernel",
    "solver_state",
    "invert_small",
    "shock_step",
    "loop_one",
    "loop_batch",
    "loop_serial",
    "loop_metrics_worker",
    "histogram_add",
    "HISTOGRAM_COUNTERS",
]

# ----------------------------------------------------------------------------------------------
# the kernels' argument types. Arrays are float64 and C-contiguous unless said otherwise;
# ``n`` counts the modes (padded with zero modes by the caller), ``N`` the internal steps,
# ``n_out`` the output samples (every r-th step), ``S`` the setups.
# ----------------------------------------------------------------------------------------------

RigModes = namedtuple("RigModes", ["BrT", "BiT", "pr", "pi", "g1r", "g1i", "g0r", "g0i", "gmr",
                                   "gmi", "pLr", "pLi", "CrT", "CmiT", "DT"])
RigModes.__doc__ = """A plant's rig-input modes for :func:`rig_kernel` (:func:`ident.sim.closedloop.rig_response`).

Attributes
----------
BrT, BiT : ndarray, shape (m, n)
    Real and imaginary parts of ``B.T`` (m rig inputs).
pr, pi : ndarray, shape (n,)
    ``phi = exp(lambda h)`` per mode, real and imaginary parts.
g1r, g1i, g0r, g0i, gmr, gmi : ndarray, shape (n,)
    The quadratic hold's coefficients per mode (:func:`ident.models.lti.hold_coefficients`).
pLr, pLi : ndarray, shape (n,)
    ``phi^(L-1)`` (a time chunk's zero-input propagation).
CrT, CmiT : ndarray, shape (n, p)
    ``Re(C).T`` and ``-Im(C).T``; the first 4 outputs are the shock velocities [m/s].
DT : ndarray, shape (m, p)
    ``D.T``.
"""

ModalLoop = namedtuple("ModalLoop", ["pr", "pi", "g1r", "g1i", "g0r", "g0i", "gmr", "gmi", "Br",
                                     "Bi", "Cvr", "Cvi", "Deff", "cbar"])
ModalLoop.__doc__ = """The shock loop's plant: the shock-force part's modes (shared by every setup).

Attributes
----------
pr, pi : ndarray, shape (n,)
    ``phi = exp(lambda h)`` per mode, real and imaginary parts (h the internal step).
g1r, g1i, g0r, g0i, gmr, gmi : ndarray, shape (n,)
    The quadratic hold's coefficients per mode (:func:`ident.models.lti.hold_coefficients`).
Br, Bi : ndarray, shape (4, n)
    ``B.T`` of the force inputs ``dF`` [N] (real, imaginary); with lift-off the pad
    corrections' rows are :attr:`Elements.Bwr`, :attr:`Elements.Bwi`.
Cvr, Cvi : ndarray, shape (4, n)
    The shock velocities' rows of ``C`` [m/s per state].
Deff : ndarray, shape (4, 4)
    Same-step response of the shock velocities to ``dF`` [m/(s N)]: ``Re(Cv g1 B) + Dv``.
cbar : ndarray, shape (4,)
    The damping the plant's shock part is closed with [N s/m] (``dF = F - cbar v``).
"""

ShockCurves = namedtuple("ShockCurves", ["kv", "kf", "nk", "slo", "shi"])
ShockCurves.__doc__ = """The shocks' piecewise-linear force-velocity curves, one row per corner.

Batch kernels take them with a leading setup axis (as
:func:`ident.sim.closedloop.pack_setups` packs them); :func:`loop_one`, :func:`solver_state`
and :func:`shock_step` take one setup's rows.

Attributes
----------
kv, kf : ndarray, shape (4, n_knots)
    Knot velocities [m/s] and forces [N], padded with the last knot.
nk : ndarray of int64, shape (4,)
    Knots per curve.
slo, shi : ndarray, shape (4,)
    End slopes below the first and above the last knot [N s/m].
"""

ShockSetups = namedtuple("ShockSetups", ["kv", "kf", "nk", "slo", "shi", "alpha", "b0", "b1",
                                         "bm"])
ShockSetups.__doc__ = """The setups' shocks: the curves (:class:`ShockCurves`' fields) and the lag's coefficients.

One row per setup in the batch kernels (every array with a leading axis of S, as
:func:`ident.sim.closedloop.pack_setups` returns them); one setup's rows in
:func:`loop_one`. Flat, not a :class:`ShockCurves` inside: numba's parallel loops take
named tuples of arrays, not nested ones.

Attributes
----------
kv, kf, nk, slo, shi : ndarray
    As :class:`ShockCurves`.
alpha, b0, b1, bm : ndarray, shape (4,)
    The lag's coefficients (:func:`ident.models.lti.lag_hold_coefficients`): ``F[k] =
    alpha F[k-1] + b0 f[k] + b1 f[k-1] + bm f[k-2]`` with ``f`` the curve's force.
"""

LoopDrive = namedtuple("LoopDrive", ["v_rig", "r", "y_rig", "Cy"])
LoopDrive.__doc__ = """The drive's part of the loop and the outputs asked for.

Attributes
----------
v_rig : ndarray, shape (N, 4)
    The shock velocities' rig-input part on the internal grid [m/s].
r : int
    Internal steps per output sample (the oversampling).
y_rig : ndarray, shape (n_out, p)
    The outputs' rig-input part at the output samples (SI).
Cy : ndarray, shape (2 n + 4 (+ 4), p)
    The outputs' coefficients on the buffered rows ``[Re x, Im x, dF (, w)]``:
    ``[Re(Cy).T; -Im(Cy).T; Dy.T (; Dw.T)]`` (the ``w`` rows with lift-off only).
"""

Elements = namedtuple("Elements", ["Bwr", "Bwi", "Cer", "Cei", "e_rig", "Dt", "Dtw", "Dvw", "Dcf",
                                   "Dcw", "tf_rows", "max_iter", "bs_on", "s0", "bx", "bf", "bn",
                                   "bslope", "lo_on", "static"])
Elements.__doc__ = """Bump stops and tire lift-off in the loop (:func:`loop_one`; issue 25).

The fields from ``bs_on`` on are setup choices: one row per setup in the batch kernels
(a leading axis of S), one setup's rows in :func:`loop_one`.

Attributes
----------
Bwr, Bwi : ndarray, shape (4, n) or (0, n)
    ``B.T`` of the pad corrections ``w`` [m] (the wheelloader inputs) with lift-off; no
    rows without.
Cer, Cei : ndarray, shape (8, n)
    The element rows of ``C``: shock travels [m] (compression positive), then tire
    forces [N].
e_rig : ndarray, shape (N, 8)
    The element rows' rig-input part on the internal grid.
Dt, Dtw : ndarray, shape (4, 4)
    Same-step response of the travels to ``dF`` [m/N] and to ``w`` [m/m].
Dvw : ndarray, shape (4, 4)
    Same-step response of the shock velocities to ``w`` [1/s].
Dcf, Dcw : ndarray, shape (4, 4)
    Same-step response of the tire forces to ``dF`` [N/N] and to ``w`` [N/m].
tf_rows : ndarray of int64, shape (4,)
    The output columns holding the corners' tire forces (-1: not an output), set to
    ``-static`` at lifted samples.
max_iter : int
    Element iterations per step (1: the bump stop explicit).
bs_on : ndarray of int64, shape (4,)
    1 where a corner has a bump stop.
s0 : ndarray, shape (4,)
    Contact travels [m].
bx, bf : ndarray, shape (4, n_points)
    Bump-stop tables: travel beyond contact [m] and force [N], padded with the last point.
bn : ndarray of int64, shape (4,)
    Points per table.
bslope : ndarray, shape (4,)
    Slope beyond the table [N/m].
lo_on : ndarray of int64, shape (4,)
    1 where a corner has a static load (lift-off solved).
static : ndarray, shape (4,)
    Static tire loads [N].
"""

ThirdLoop = namedtuple("ThirdLoop", ["CtTr", "CtTi", "t_rig", "Dt", "drows", "srows", "scorner",
                                     "kv", "kf", "nk", "slo", "shi", "alpha", "b0", "b1", "bm",
                                     "s0", "bx", "bf", "bn", "bslope"])
ThirdLoop.__doc__ = """Third elements in the loop (:func:`loop_one`; issue 38): dampers and springs
acting through rows over the corners.

A damper ``d`` has the row ``drows[d]`` (:func:`ident.data.third.element_row`): its velocity
is ``drows[d] @ v`` of the corners' shock velocities and its force ``F_d`` (a
piecewise-linear curve behind a first-order lag, as a shock's) acts at the corners as
``drows[d] * F_d``. A spring ``j`` (a heave spring, or a corner's bump stop: a unit row) has
the row ``srows[j]``: its force is the table from its contact travel ``s0[j]`` on, at the
travel ``srows[j] @ x``. The fields from ``kv`` on are setup choices: one row per setup in
the batch kernels (a leading axis of S), one setup's rows in :func:`loop_one`. A damper not
fitted in a setup has a flat zero curve; a spring not fitted a contact travel out of reach.

Attributes
----------
CtTr, CtTi : ndarray, shape (n, 4)
    ``Re(Ct).T`` and ``Im(Ct).T`` of the shock travels' rows of ``C`` [m per state], mode-major.
t_rig : ndarray, shape (N, 4)
    The shock travels' rig-input part on the internal grid [m].
Dt : ndarray, shape (4, 4)
    Same-step response of the travels to ``dF`` [m/N].
drows : ndarray, shape (ne, 4)
    The third dampers' rows.
srows : ndarray, shape (ns, 4)
    The springs' rows.
scorner : ndarray of int64, shape (ns,)
    The corner of a corner bump stop, -1 for a heave spring.
kv, kf : ndarray, shape (ne, n_knots)
    The dampers' knot velocities [m/s] and forces [N] in the element's own motion, padded.
nk : ndarray of int64, shape (ne,)
slo, shi : ndarray, shape (ne,)
alpha, b0, b1, bm : ndarray, shape (ne,)
    The dampers' lag coefficients (as :class:`ShockSetups`').
s0 : ndarray, shape (ns,)
    Contact travels [m] (gap less packer).
bx, bf : ndarray, shape (ns, n_points)
    Tables: travel beyond contact [m] and force [N], padded with the last point.
bn : ndarray of int64, shape (ns,)
bslope : ndarray, shape (ns,)
    Slope beyond the table [N/m].
"""

MetricFilters = namedtuple("MetricFilters", ["ia", "sos", "zi", "padlen", "dmap", "dw"])
MetricFilters.__doc__ = """The fused metrics' channels and filters (:func:`loop_metrics_worker`).

Attributes
----------
ia : ndarray of int64, shape (n_metrics,)
    Each metric's row of the setup's buffer (outputs, then the 4 shock velocities).
sos : ndarray, shape (n_bands, n_sections, 6)
    Each band's band-pass filter (second-order sections).
zi : ndarray, shape (n_bands, n_sections, 2)
    Their steady-state initial conditions (:func:`scipy.signal.sosfilt_zi`).
padlen : int
    Odd-extension length of the zero-phase filter [samples].
dmap, dw : ndarray of int64, shape (n_derived, 7), and ndarray, shape (n_derived, 4)
    The derived metrics after the ``ia.size`` filtered ones (combinations of their
    band-passed signals: :func:`ident.sim.metric_kernels.derived_metric_map`).
"""

SolverState = namedtuple("SolverState", ["v", "vfree", "c0", "fv", "sv", "seg", "av", "vnew",
                                         "res", "J", "Jinv", "state"])
SolverState.__doc__ = """The state and scratch of :func:`shock_step` for one setup (:func:`solver_state`).

Attributes
----------
v : ndarray, shape (4,)
    The shock velocities solved for [m/s].
vfree, c0 : ndarray, shape (4,)
    Scratch for the caller's right-hand side (free velocities [m/s], the lag's known force
    part [N]).
fv, sv, av : ndarray, shape (4,)
    The curves' force [N], slope [N s/m] and intercept [N] at `v` on their segments.
seg : ndarray of int64, shape (4,)
    Each curve's segment (carried over between steps).
vnew, res : ndarray, shape (4,)
    Scratch.
J, Jinv : ndarray, shape (4, 4)
    The linear system on the current segments and its cached inverse.
state : ndarray of int64, shape (1,)
    0: `Jinv` invalid; k >= 1: valid for `seg`, k - 1 rank-1 updates since computed.
"""


# ----------------------------------------------------------------------------------------------
# the rig-input response
# ----------------------------------------------------------------------------------------------

@_nb.njit(cache=True, error_model="numpy", inline="always")
def _rig_chunk(u, modes, r, z, k0, k1, v, y, outputs):
    """Steps ``k0 <= k < k1`` of :func:`rig_kernel` from the states ``z`` (4, n): rows
    ``Re z0, Im z0, Re z1, Im z1`` of the transposed direct form II per mode, updated in
    place. With `outputs` False only the states are run (the chunk end states).

    Each step is three loops over 1-D rows, so that numba's loop vectorizer takes them:
    the modes' inputs ``b_i . u[k]`` (over the modes, one input after the other), the
    modes' hold recursions, and the outputs (over the outputs, one mode after the other).
    Every sum keeps its order: the numbers of a loop over modes with the sums inside.
    """
    BrT = modes.BrT
    BiT = modes.BiT
    pr = modes.pr
    pi = modes.pi
    g1r = modes.g1r
    g1i = modes.g1i
    g0r = modes.g0r
    g0i = modes.g0i
    gmr = modes.gmr
    gmi = modes.gmi
    CrT = modes.CrT
    CmiT = modes.CmiT
    DT = modes.DT
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
def rig_kernel(u, modes, r, L, n_chunks, v, y):
    """Kernel of :func:`ident.sim.closedloop.rig_response`'s outputs, parallel over time
    chunks of `L` steps.

    ``u`` (N, m) inputs; `modes` a :class:`RigModes` (``pL = phi^(L-1)``), whose first 4
    outputs (the shock velocities) go to ``v`` (N, 4) on every step and the rest to ``y``
    (n_out, p - 4) on every r-th step; `n_chunks` chunks.
    """
    N = u.shape[0]
    pr = modes.pr
    pi = modes.pi
    pLr = modes.pLr
    pLi = modes.pLi
    n = pr.size
    S = np.zeros((n_chunks, 4, n))  # chunk start states
    if n_chunks > 1:
        E = np.zeros((n_chunks, 4, n))  # chunk end states from rest
        for c in _nb.prange(n_chunks - 1):
            _rig_chunk(u, modes, r, E[c], c * L, (c + 1) * L, v, y, False)
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
        _rig_chunk(u, modes, r, S[c], c * L, min(N, (c + 1) * L), v, y, True)


# ----------------------------------------------------------------------------------------------
# the shock solve
# ----------------------------------------------------------------------------------------------

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
def solver_state(curves):
    """Fresh per-setup :class:`SolverState` of :func:`shock_step` for the :class:`ShockCurves`
    `curves` (one setup's rows): velocities at rest, each shock on the segment holding 0."""
    kv = curves.kv
    nk = curves.nk
    m = 4
    seg = np.zeros(m, dtype=np.int64)
    for c in range(m):
        seg[c] = _segment_of(0.0, kv, c, nk[c], 0)
    return SolverState(np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m), seg,
                       np.zeros(m), np.zeros(m), np.zeros(m), np.zeros((m, m)),
                       np.zeros((m, m)), np.zeros(1, dtype=np.int64))


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
def shock_step(vfree, c0, Deff, cbar, b0, curves, st):
    """Solve one step of the shock loop in place; return the iteration count (-1: failed).

    Solves ``v = vfree + Deff (c0 + b0 f(v) - cbar v)`` for the 4 shock velocities (``f``
    the :class:`ShockCurves` `curves`, one setup's rows) into ``st.v`` and leaves ``f(v)``
    in ``st.fv`` (`st` a :class:`SolverState`). ``st.seg``, ``st.Jinv`` and
    ``st.state[0]`` carry over between steps. Shared by the modal and the FIR simulators;
    the modal time loop first tries the common cases inline (every shock on its segment,
    or segment changes by rank-1 updates of the cached inverse) and calls this for the
    rest. Not inlined: an inlined body with many array arguments costs more in reference
    counting than the solve.
    """
    kv = curves.kv
    kf = curves.kf
    nk = curves.nk
    slo = curves.slo
    shi = curves.shi
    v = st.v
    fv = st.fv
    sv = st.sv
    seg = st.seg
    av = st.av
    vnew = st.vnew
    res = st.res
    J = st.J
    Jinv = st.Jinv
    state = st.state
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
def _fast_solve(vfree, c0, Deff, b0, curves, lines_s, lines_a, bounds, st):
    """The shock loop's common cases (see :func:`loop_one`); returns the iteration count, 0
    when :func:`shock_step` must solve the step. Inlined: the same operations in the same
    order wherever it is used."""
    kv = curves.kv
    nk = curves.nk
    v = st.v
    fv = st.fv
    sv = st.sv
    seg = st.seg
    av = st.av
    vnew = st.vnew
    res = st.res
    J = st.J
    Jinv = st.Jinv
    state = st.state
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
            # every shock strictly inside its segment (the common case), tested without a
            # branch per shock; otherwise each is placed by _segment_of, which decides a
            # velocity on a knot (so the indices are those of the per-shock test)
            inside = True
            for c in range(m):
                x = vnew[c]
                sg = seg[c]
                inside &= (bounds[0, c, sg] < x) & (x < bounds[1, c, sg])
            same = True
            for c in range(m):
                if inside:
                    break
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


# ----------------------------------------------------------------------------------------------
# the loop with third elements (issue 38): dampers and springs through rows over the corners
# ----------------------------------------------------------------------------------------------

#: Segment passes of the third elements' solve before Newton's method with a residual test
#: (:func:`_third_newton`) takes over (segments cycling at a kink).
THIRD_SEGMENT_PASSES = 12
#: Newton's tolerance of that fallback on the corner forces [N], relative to ``1 + |dF|``
#: (:data:`ident.sim.third_loop.THIRD_TOL_N`'s value: the virtual rig's truth solves to it).
THIRD_NEWTON_TOL = 1e-7
#: Residual evaluations of the fallback (Newton steps and their halvings) before the step
#: is reported as failed.
THIRD_NEWTON_MAX = 200
#: Armijo's fraction of the fallback's backtracking: a step of length ``lam`` is accepted
#: when it lowers ``|R|^2`` to ``(1 - THIRD_ARMIJO lam)`` of the last accepted point's.
THIRD_ARMIJO = 1e-4
#: Smallest step fraction of the backtracking; a step at it is taken whatever its residual
#: (at a kink the descent of the near side's Newton step ends at the kink: the far side's
#: Jacobian takes over from just beyond it).
THIRD_MIN_STEP = 2.0 ** -20
#: Segment passes with rank-1 updates of the cached inverse inside the time loop, before
#: :func:`_third_solve` (the full rebuild) takes the step.
THIRD_FAST_PASSES = 6


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _spring_seg(te, j, s0, bx, bn):
    """Segment of spring `j` at its travel `te`: -1 before contact, ``i`` on the table's
    segment from point i, ``bn - 1`` beyond the table."""
    x = te - s0[j]
    if x <= 0.0:
        return -1
    nb = bn[j]
    if x >= bx[j, nb - 1]:
        return nb - 1
    lo = 0
    hi = nb - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if bx[j, mid] <= x:
            lo = mid
        else:
            hi = mid
    return lo


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _spring_line(seg, j, s0, bx, bf, bn, bslope):
    """Stiffness and intercept of spring `j` on segment `seg` in its own travel: g = a + k te."""
    if seg < 0:
        return 0.0, 0.0
    nb = bn[j]
    if seg >= nb - 1:
        k = bslope[j]
        return k, bf[j, nb - 1] - k * (s0[j] + bx[j, nb - 1])
    k = (bf[j, seg + 1] - bf[j, seg]) / (bx[j, seg + 1] - bx[j, seg])
    return k, bf[j, seg] - k * (s0[j] + bx[j, seg])


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _third_assemble(Dv, Dt, cbar, drows, srows, b0, ds, sk, Mv, Mt, J, Jinv):
    """``Mv = sum_d b0_d s_d m_d m_d^T - diag(cbar)``, ``Mt = sum_j k_j q_j q_j^T`` and the
    inverse of ``J = I - Mv Dv - Mt Dt`` on the current segments."""
    nd = drows.shape[0]
    ns = srows.shape[0]
    for a in range(4):
        for c in range(4):
            Mv[a, c] = 0.0
            Mt[a, c] = 0.0
        Mv[a, a] = -cbar[a]
    for d in range(nd):
        wd = b0[d] * ds[d]
        if wd != 0.0:
            for a in range(4):
                ra = drows[d, a] * wd
                if ra != 0.0:
                    for c in range(4):
                        Mv[a, c] += ra * drows[d, c]
    for j in range(ns):
        kj = sk[j]
        if kj != 0.0:
            for a in range(4):
                ra = srows[j, a] * kj
                if ra != 0.0:
                    for c in range(4):
                        Mt[a, c] += ra * srows[j, c]
    for a in range(4):
        for c in range(4):
            acc = 0.0
            for e in range(4):
                acc += Mv[a, e] * Dv[e, c] + Mt[a, e] * Dt[e, c]
            J[a, c] = (1.0 if a == c else 0.0) - acc
    invert_small(J, Jinv, 4)


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _third_residual(vfree, tfree, c0, Dv, Dt, cbar, drows, kv, kf, nk, slo, shi, b0, srows, s0,
                    bx, bf, bn, bslope, dF, v, t, fd, gs, R, Jv, Jt):
    """Residual ``R = dF - G(dF)`` of a step with third elements at `dF` (:func:`_third_newton`)
    with the motions `v`, `t`, the curve forces `fd`, `gs` and the slopes' parts `Jv`, `Jt` of
    its Jacobian there; returns ``max |R|``, ``max |dF|`` and ``|R|^2``."""
    nd = drows.shape[0]
    ns = srows.shape[0]
    for a in range(4):
        sv_ = vfree[a]
        st_ = tfree[a]
        for c in range(4):
            sv_ += Dv[a, c] * dF[c]
            st_ += Dt[a, c] * dF[c]
        v[a] = sv_
        t[a] = st_
        R[a] = -cbar[a] * sv_
        for c in range(4):
            Jv[a, c] = 0.0
            Jt[a, c] = 0.0
        Jv[a, a] = -cbar[a]
    for d in range(nd):
        ve = 0.0
        for c in range(4):
            ve += drows[d, c] * v[c]
        f, s, sg = _pwl(ve, kv, kf, d, nk[d], slo[d], shi[d])
        fd[d] = f
        Fd = c0[d] + b0[d] * f
        ds = b0[d] * s
        for a in range(4):
            if drows[d, a] != 0.0:
                R[a] += drows[d, a] * Fd
                for c in range(4):
                    Jv[a, c] += ds * drows[d, a] * drows[d, c]
    for j in range(ns):
        te = 0.0
        for c in range(4):
            te += srows[j, c] * t[c]
        sg = _spring_seg(te, j, s0, bx, bn)
        k, a0 = _spring_line(sg, j, s0, bx, bf, bn, bslope)
        g = a0 + k * te
        gs[j] = g
        for a in range(4):
            if srows[j, a] != 0.0:
                R[a] += srows[j, a] * g
                for c in range(4):
                    Jt[a, c] += k * srows[j, a] * srows[j, c]
    rmax = 0.0
    fmax = 0.0
    r2 = 0.0
    for a in range(4):
        R[a] = dF[a] - R[a]  # G(dF) summed first: the truth's order
        rmax = max(rmax, abs(R[a]))
        fmax = max(fmax, abs(dF[a]))
        r2 += R[a] * R[a]
    return rmax, fmax, r2


@_nb.njit(cache=True, error_model="numpy")
def _third_newton(vfree, tfree, c0, Dv, Dt, cbar, drows, kv, kf, nk, slo, shi, b0, srows, s0,
                 bx, bf, bn, bslope, dF, v, t, fd, gs, J, Jinv):
    """Newton's method on the corner forces of a step with third elements (the fallback of
    the segment passes), globalized by backtracking: from ``dF`` (the last pass's) to ``|dF -
    G(dF)| <= tol (1 + |dF|)``. A Newton step is accepted when it lowers ``|R|^2`` by
    Armijo's test, else halved (down to :data:`THIRD_MIN_STEP`, then taken: a kink's far
    side); a full step on the final segments is exact, so a converged step equals
    :func:`ident.sim.third_loop.simulate_third`'s (the same iteration) to rounding. Leaves
    the solution in `dF`, `v`, `t`, the dampers' curve forces in `fd` and the springs' in
    `gs`; returns the residual evaluations (-1: no convergence in
    :data:`THIRD_NEWTON_MAX`)."""
    R = np.empty(4)
    P = np.empty(4)
    base = np.empty(4)
    Jv = np.empty((4, 4))
    Jt = np.empty((4, 4))
    it = 0
    lam = 1.0
    r2base = 0.0
    while True:
        rmax, fmax, r2 = _third_residual(vfree, tfree, c0, Dv, Dt, cbar, drows, kv, kf, nk, slo,
                                         shi, b0, srows, s0, bx, bf, bn, bslope, dF, v, t, fd,
                                         gs, R, Jv, Jt)
        if rmax <= THIRD_NEWTON_TOL * (1.0 + fmax):
            return it
        it += 1
        if it > THIRD_NEWTON_MAX:
            return -1
        if it > 1 and r2 > (1.0 - THIRD_ARMIJO * lam) * r2base and lam > THIRD_MIN_STEP:
            # not enough descent: half the step from the last accepted point
            lam *= 0.5
            for a in range(4):
                dF[a] = base[a] - lam * P[a]
            continue
        # accepted: a Newton step from here
        r2base = r2
        for a in range(4):
            for c in range(4):
                acc = 0.0
                for e in range(4):
                    acc += Jv[a, e] * Dv[e, c] + Jt[a, e] * Dt[e, c]
                J[a, c] = (1.0 if a == c else 0.0) - acc
        invert_small(J, Jinv, 4)
        for a in range(4):
            acc = 0.0
            for c in range(4):
                acc += Jinv[a, c] * R[c]
            P[a] = acc
        lam = 1.0
        for a in range(4):
            base[a] = dF[a]
            dF[a] -= P[a]


@_nb.njit(cache=True, error_model="numpy")
def _third_solve(vfree, tfree, c0, Dv, Dt, cbar, drows, kv, kf, nk, slo, shi, b0, srows, s0, bx,
                 bf, bn, bslope, dseg, sseg, ds, da, sk, sa, Mv, Mt, J, Jinv, valid, rhs, ve,
                 te, dF, v, t, fd, gs):
    """One step of the loop with third elements: the corner force deviations ``dF`` with
    ``dF = sum_d m_d (c0_d + b0_d f_d(m_d v)) + sum_j q_j g_j(q_j t) - cbar v``, ``v = vfree
    + Dv dF``, ``t = tfree + Dt dF`` (the dampers ``d`` include the 4 corner shocks as unit
    rows). Every curve and table is piecewise linear, so on fixed segments this is linear:
    ``J dF = A + Mv vfree + Mt tfree`` (:func:`_third_assemble`); the last step's segments
    are assumed, solved with the cached inverse and accepted when every element stays on
    its segment (exact), else moved and solved again (a Newton step). After
    :data:`THIRD_SEGMENT_PASSES` passes (cycling at a kink) :func:`_third_newton` solves the
    step. Returns the passes (-1: failed)."""
    nd = drows.shape[0]
    ns = srows.shape[0]
    it = 0
    while True:
        if valid[0] == 0:
            for d in range(nd):
                ds[d], da[d] = _segment_line(dseg[d], kv, kf, d, nk[d], slo[d], shi[d])
            for j in range(ns):
                sk[j], sa[j] = _spring_line(sseg[j], j, s0, bx, bf, bn, bslope)
            _third_assemble(Dv, Dt, cbar, drows, srows, b0, ds, sk, Mv, Mt, J, Jinv)
            valid[0] = 1
        for a in range(4):
            acc = 0.0
            for c in range(4):
                acc += Mv[a, c] * vfree[c] + Mt[a, c] * tfree[c]
            rhs[a] = acc
        for d in range(nd):
            q = c0[d] + b0[d] * da[d]
            for a in range(4):
                rhs[a] += drows[d, a] * q
        for j in range(ns):
            if sseg[j] >= 0:
                for a in range(4):
                    rhs[a] += srows[j, a] * sa[j]
        for a in range(4):
            acc = 0.0
            for c in range(4):
                acc += Jinv[a, c] * rhs[c]
            dF[a] = acc
        for a in range(4):
            acc_v = vfree[a]
            acc_t = tfree[a]
            for c in range(4):
                acc_v += Dv[a, c] * dF[c]
                acc_t += Dt[a, c] * dF[c]
            v[a] = acc_v
            t[a] = acc_t
        same = True
        for d in range(nd):
            x = 0.0
            for c in range(4):
                x += drows[d, c] * v[c]
            ve[d] = x
            s2 = _segment_of(x, kv, d, nk[d], dseg[d])
            if s2 != dseg[d]:
                same = False
                dseg[d] = s2
        for j in range(ns):
            x = 0.0
            for c in range(4):
                x += srows[j, c] * t[c]
            te[j] = x
            s2 = _spring_seg(x, j, s0, bx, bn)
            if s2 != sseg[j]:
                same = False
                sseg[j] = s2
        it += 1
        if same:
            for d in range(nd):
                fd[d] = da[d] + ds[d] * ve[d]
            for j in range(ns):
                gs[j] = sa[j] + sk[j] * te[j]
            return it
        valid[0] = 0
        if it >= THIRD_SEGMENT_PASSES:
            break
    # cycling at a kink: Newton with a residual test from the last solution
    itn = _third_newton(vfree, tfree, c0, Dv, Dt, cbar, drows, kv, kf, nk, slo, shi, b0, srows,
                       s0, bx, bf, bn, bslope, dF, v, t, fd, gs, J, Jinv)
    if itn < 0:
        return -1
    for d in range(nd):
        x = 0.0
        for c in range(4):
            x += drows[d, c] * v[c]
        dseg[d] = _segment_of(x, kv, d, nk[d], dseg[d])
    for j in range(ns):
        x = 0.0
        for c in range(4):
            x += srows[j, c] * t[c]
        sseg[j] = _spring_seg(x, j, s0, bx, bn)
    valid[0] = 0
    return it + itn


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _third_change(Jinv, rows, W, e, dw, dfc, dF, z, y, valid):
    """A segment change of element `e` in the time loop's fast path (:func:`loop_one`): a
    damper (`rows` the dampers' rows, ``W = rows Dv``) or a spring (the springs' rows, ``W =
    rows Dt``) whose slope changes by `dw` (``J' = J - dw r_e W_e^T``) and whose force at its
    present motion by `dfc`. Moves the solution `dF` (by ``J'^-1 r_e dfc``) and the cached
    inverse `Jinv` (Sherman-Morrison; `z`, `y` scratch) and counts the update in
    ``valid[0]``; returns False (``valid[0] = 0``) when the update is singular. One helper
    for dampers and springs; inlined."""
    m = 4
    for a in range(m):
        acc = 0.0
        for c in range(m):
            acc += Jinv[a, c] * rows[e, c]
        z[a] = acc
    wz = 0.0
    for a in range(m):
        wz += W[e, a] * z[a]
    den = 1.0 - dw * wz
    if abs(den) < 1e-8:
        valid[0] = 0
        return False
    # J'^-1 r_e = z / den
    g = dfc / den
    for a in range(m):
        dF[a] += z[a] * g
    if dw != 0.0:
        for a in range(m):
            acc = 0.0
            for c in range(m):
                acc += W[e, c] * Jinv[c, a]
            y[a] = acc
        q = dw / den
        for a in range(m):
            za = z[a] * q
            for c in range(m):
                Jinv[a, c] += za * y[c]
        valid[0] += 1
    return True


# ----------------------------------------------------------------------------------------------
# the time loops
# ----------------------------------------------------------------------------------------------

@_nb.njit(cache=True, error_model="numpy", inline="always")
def _setup_row(setups, s):
    """Setup `s`'s rows of the batch :class:`ShockSetups` `setups`."""
    return ShockSetups(setups.kv[s], setups.kf[s], setups.nk[s], setups.slo[s], setups.shi[s],
                       setups.alpha[s], setups.b0[s], setups.b1[s], setups.bm[s])


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _element_row(el, s):
    """Setup `s`'s rows of the batch :class:`Elements` `el` (the setup choices' fields)."""
    return Elements(el.Bwr, el.Bwi, el.Cer, el.Cei, el.e_rig, el.Dt, el.Dtw, el.Dvw, el.Dcf,
                    el.Dcw, el.tf_rows, el.max_iter, el.bs_on[s], el.s0[s], el.bx[s], el.bf[s],
                    el.bn[s], el.bslope[s], el.lo_on[s], el.static[s])


@_nb.njit(cache=True, error_model="numpy", inline="always")
def _third_row(th, s):
    """Setup `s`'s rows of the batch :class:`ThirdLoop` `th` (the setup choices' fields)."""
    return ThirdLoop(th.CtTr, th.CtTi, th.t_rig, th.Dt, th.drows, th.srows, th.scorner, th.kv[s],
                     th.kf[s], th.nk[s], th.slo[s], th.shi[s], th.alpha[s], th.b0[s], th.b1[s],
                     th.bm[s], th.s0[s], th.bx[s], th.bf[s], th.bn[s], th.bslope[s])


@_nb.njit(cache=True, error_model="numpy")
def loop_one(plant, setup, drive, y_out, F_out, v_row, elements, stats, third, tstats):
    """Time loop of one setup on the internal grid; returns the largest Newton iteration
    count (-1: no convergence).

    Parameters
    ----------
    plant : ModalLoop
    setup : ShockSetups
        One setup's rows.
    drive : LoopDrive
    y_out : ndarray, shape (p (+ 4), n_out)
        The outputs (channel-major); with ``v_row >= 0`` the shock velocities the loop
        solved for go to its rows ``v_row .. v_row + 3`` (they equal the velocity outputs:
        ``v = v_free + Deff dF``).
    F_out : ndarray, shape (n_out, 4)
        The applied shock forces [N] per output sample (the load cell measures the shock).
    v_row : int
    elements : Elements or None
        One setup's rows; ``None``: the loop without bump stops and lift-off (numba
        compiles that case apart and drops the elements' code from it).
    stats : ndarray, shape (3, 4), or None (with ``elements=None``)
        Output samples in bump-stop contact, output samples lifted off, smallest contact
        force [N].
    third : ThirdLoop or None
        One setup's rows; ``None``: no third elements (numba compiles that case apart and
        drops their code: the plain loop's numbers and speed). With third elements
        `elements` is ``None`` (corner bump stops are among the third's springs; lift-off
        is not combined with them), ``F_out`` has ``4 + ne + ns`` columns (the third
        dampers' forces, then the springs'), and ``tstats`` (ns,) gets each spring's output
        samples in contact.
    tstats : ndarray, shape (ns,), or None (with ``third=None``)

    Notes
    -----
    With third elements the step is one solve on the corner forces ``dF`` of the corner
    shocks and the third dampers (rows over the corners, each with its curve and lag) and
    the springs (heave springs and corner bump stops on their rows' travel), the travels'
    free part ``t_free`` from the predictor as the velocities': inline for the common cases
    (every element inside its segment; segment changes by :func:`_third_change`, which
    moves the solution and the cached inverse), :func:`_third_solve` for the rest.

    The modal states are held as separate real and imaginary arrays (the mode loops
    vectorize). At every r-th step (an output sample) the states and ``dF`` (and ``w``
    with lift-off) are buffered as rows ``[Re x, Im x, dF (, w)]``; every
    :data:`_OUT_BLOCK` samples the outputs ``y_rig + [Re x, Im x, dF (, w)] Cy`` are
    written by one matrix product.

    With the elements the plant's force input of corner ``c`` is ``dF = F_shock + G(s) -
    cbar v`` with ``G`` the bump stop's force at the shock travel ``s``; with lift-off the
    pad input of corner ``c`` gets ``w_c >= 0`` (``Bw``: the modes' wheelloader columns),
    the pad following the tire so that the contact force ``static + tire_force`` is zero
    while ``w_c > 0``. Per step: the predictor gives ``v_free`` and the element rows' free
    parts ``s_free``, ``c_free``. Then, until ``G`` and ``w`` stop changing (by
    :data:`ELEMENT_STOP_TOL_N`, :data:`ELEMENT_TOL_N`): the shock solve with ``v_free +
    Deff G + Dvw w``; the travel ``s = s_free + Dt dF + Dtw w`` and contact ``c = static +
    c_free + Dcf dF + Dcw w``; Newton updates of ``G`` on ``G - g(s)`` and of ``w`` on ``c
    = 0`` with their diagonal derivatives (``Dt[c, c] g'(s)`` and ``Dcw[c, c]``). So the
    travel, the bump-stop force, the contact and the shock forces agree within the step
    (implicit); ``max_iter = 1`` evaluates ``G`` at the travel extrapolated from the state
    and the last step's force (explicit: kept to measure what the iteration buys). At an
    output sample with ``w_c > 0`` the output row ``tf_rows[c]`` (the tire force, if an
    output) is set to ``-static[c]`` exactly. The iteration count is then the largest over
    the element iterations of a step.
    """
    pr = plant.pr
    pi = plant.pi
    g1r = plant.g1r
    g1i = plant.g1i
    g0r = plant.g0r
    g0i = plant.g0i
    gmr = plant.gmr
    gmi = plant.gmi
    Br = plant.Br
    Bi = plant.Bi
    Cvr = plant.Cvr
    Cvi = plant.Cvi
    Deff = plant.Deff
    cbar = plant.cbar
    curves = ShockCurves(setup.kv, setup.kf, setup.nk, setup.slo, setup.shi)
    kv = curves.kv
    kf = curves.kf
    nk = curves.nk
    slo = curves.slo
    shi = curves.shi
    alpha = setup.alpha
    b0 = setup.b0
    b1 = setup.b1
    bm = setup.bm
    v_rig = drive.v_rig
    r = drive.r
    y_rig = drive.y_rig
    Cy = drive.Cy
    n = pr.size
    m = 4
    p = Cy.shape[1]
    N = v_rig.shape[0]
    n_out = y_out.shape[1]
    nw = 0  # w rows of the output buffer: 4 with lift-off
    if elements is not None:
        Bwr = elements.Bwr
        Bwi = elements.Bwi
        e_rig = elements.e_rig
        Dt = elements.Dt
        Dtw = elements.Dtw
        Dvw = elements.Dvw
        Dcf = elements.Dcf
        Dcw = elements.Dcw
        tf_rows = elements.tf_rows
        max_iter = elements.max_iter
        bs_on = elements.bs_on
        s0 = elements.s0
        bx = elements.bx
        bf = elements.bf
        bn = elements.bn
        bslope = elements.bslope
        lo_on = elements.lo_on
        static = elements.static
        nw = Bwr.shape[0]
        CeTr = np.ascontiguousarray(elements.Cer.T)
        CeTi = np.ascontiguousarray(elements.Cei.T)
        any_bs = False
        any_lo = False
        for c in range(m):
            if bs_on[c]:
                any_bs = True
            if lo_on[c]:
                any_lo = True
        sfree = np.zeros(m)
        cfree = np.zeros(m)
        vf2 = np.zeros(m)
        G = np.zeros(m)
        Gn = np.zeros(m)
        w = np.zeros(m)
        wn = np.zeros(m)
        s = np.zeros(m)
        cc = np.zeros(m)
        Fsh = np.zeros(m)
        # the counts in arrays of the kernel's own, written to `stats` at the end: stores
        # into an argument inside the time loop (which may alias the others, for all the
        # compiler knows) made the whole loop twice as slow
        n_bs = np.zeros(m)
        n_lo = np.zeros(m)
        c_min = np.full(m, np.inf)
    if third is not None:
        CtTr = third.CtTr
        CtTi = third.CtTi
        t_rig = third.t_rig
        Dt3 = third.Dt
        srows3 = third.srows
        s03 = third.s0
        bx3 = third.bx
        bf3 = third.bf
        bn3 = third.bn
        bslope3 = third.bslope
        ne3 = third.drows.shape[0]
        ns3 = srows3.shape[0]
        nd3 = m + ne3
        # the corner shocks (unit rows) and the third dampers as one set of curves
        K1 = kv.shape[1]
        K2 = third.kv.shape[1]
        K3 = max(K1, K2)
        kvA = np.empty((nd3, K3))
        kfA = np.empty((nd3, K3))
        nkA = np.empty(nd3, dtype=np.int64)
        sloA = np.empty(nd3)
        shiA = np.empty(nd3)
        alphaA = np.empty(nd3)
        b0A = np.empty(nd3)
        b1A = np.empty(nd3)
        bmA = np.empty(nd3)
        drowsA = np.zeros((nd3, m))
        for c in range(m):
            for q in range(K3):
                kvA[c, q] = kv[c, min(q, K1 - 1)]
                kfA[c, q] = kf[c, min(q, K1 - 1)]
            nkA[c] = nk[c]
            sloA[c] = slo[c]
            shiA[c] = shi[c]
            alphaA[c] = alpha[c]
            b0A[c] = b0[c]
            b1A[c] = b1[c]
            bmA[c] = bm[c]
            drowsA[c, c] = 1.0
        for d in range(ne3):
            for q in range(K3):
                kvA[m + d, q] = third.kv[d, min(q, K2 - 1)]
                kfA[m + d, q] = third.kf[d, min(q, K2 - 1)]
            nkA[m + d] = third.nk[d]
            sloA[m + d] = third.slo[d]
            shiA[m + d] = third.shi[d]
            alphaA[m + d] = third.alpha[d]
            b0A[m + d] = third.b0[d]
            b1A[m + d] = third.b1[d]
            bmA[m + d] = third.bm[d]
            for c in range(m):
                drowsA[m + d, c] = third.drows[d, c]
        # each segment's open interval (bnd3[0], bnd3[1]) in the element's motion: dampers'
        # segments 0 .. nk, springs' (beyond contact) -1 .. bn - 1 at index + 1
        bnd3 = np.empty((2, nd3, K3 + 1))
        for d in range(nd3):
            for sg in range(nkA[d] + 1):
                bnd3[0, d, sg] = -np.inf if sg == 0 else kvA[d, sg - 1]
                bnd3[1, d, sg] = np.inf if sg == nkA[d] else kvA[d, sg]
        sbnd3 = np.empty((2, ns3, bx3.shape[1] + 1))
        for j in range(ns3):
            nbj = bn3[j]
            sbnd3[0, j, 0] = -np.inf
            sbnd3[1, j, 0] = 0.0
            for sg in range(nbj):
                sbnd3[0, j, sg + 1] = bx3[j, sg]
                sbnd3[1, j, sg + 1] = np.inf if sg == nbj - 1 else bx3[j, sg + 1]
        dseg = np.empty(nd3, dtype=np.int64)
        for d in range(nd3):
            dseg[d] = _segment_of(0.0, kvA, d, nkA[d], 0)
        sseg = np.empty(ns3, dtype=np.int64)
        for j in range(ns3):
            sseg[j] = _spring_seg(0.0, j, s03, bx3, bn3)
        # the elements' rows' same-step response to dF (wd3 = drowsA Dv, ws3 = srows Dt),
        # the dampers' lines per segment, the velocity and travel rows as 8 mode-major lanes
        wd3 = np.zeros((nd3, m))
        for d in range(nd3):
            for a in range(m):
                acc = 0.0
                for c in range(m):
                    acc += drowsA[d, c] * Deff[c, a]
                wd3[d, a] = acc
        ws3 = np.zeros((ns3, m))
        for j in range(ns3):
            for a in range(m):
                acc = 0.0
                for c in range(m):
                    acc += srows3[j, c] * Dt3[c, a]
                ws3[j, a] = acc
        dls3 = np.empty((nd3, K3 + 1))
        dla3 = np.empty((nd3, K3 + 1))
        for d in range(nd3):
            for sg in range(nkA[d] + 1):
                dls3[d, sg], dla3[d, sg] = _segment_line(sg, kvA, kfA, d, nkA[d], sloA[d],
                                                         shiA[d])
        CvtTr = np.empty((n, 8))
        CvtTi = np.empty((n, 8))
        for i in range(n):
            for c in range(m):
                CvtTr[i, c] = Cvr[c, i]
                CvtTi[i, c] = Cvi[c, i]
                CvtTr[i, m + c] = CtTr[i, c]
                CvtTi[i, m + c] = CtTi[i, c]
        vef3 = np.zeros(nd3)
        tef3 = np.zeros(ns3)
        tfree = np.zeros(m)
        ds3 = np.zeros(nd3)
        da3 = np.zeros(nd3)
        sk3 = np.zeros(ns3)
        sa3 = np.zeros(ns3)
        Mv3 = np.zeros((m, m))
        Mt3 = np.zeros((m, m))
        J3 = np.zeros((m, m))
        Jinv3 = np.zeros((m, m))
        valid3 = np.zeros(1, dtype=np.int64)
        rhs3 = np.zeros(m)
        ve3 = np.zeros(nd3)
        te3 = np.zeros(ns3)
        dF3 = np.zeros(m)
        t3 = np.zeros(m)
        fd3 = np.zeros(nd3)
        gs3 = np.zeros(ns3)
        c03 = np.zeros(nd3)
        Fp3 = np.zeros(nd3)
        fp3 = np.zeros(nd3)
        n_sp = np.zeros(ns3)
        z3 = np.zeros(m)
        y3 = np.zeros(m)
    xr = np.zeros(n)
    xi = np.zeros(n)
    bdr = np.zeros(n)  # B dF of the last step
    bdi = np.zeros(n)
    bpr = np.zeros(n)  # B dF of the step before
    bpi = np.zeros(n)
    # the corrector folded into the next predictor: x[k] = xp[k] + g1 B dF[k] is never
    # formed, the predictor propagates xp with h = phi g1 + g0 on B dF[k] (xp is what the
    # velocity sums and the element rows read); x itself only at the output samples
    hr = np.empty(n)
    hi = np.empty(n)
    for i in range(n):
        hr[i] = pr[i] * g1r[i] - pi[i] * g1i[i] + g0r[i]
        hi[i] = pr[i] * g1i[i] + pi[i] * g1r[i] + g0i[i]
    St = np.zeros((_OUT_BLOCK, 2 * n + m + nw))  # output samples' [Re x, Im x, dF (, w)]
    dF_prev = np.zeros(m)
    F_prev = np.zeros(m)
    f_prev = np.zeros(m)
    f_prev2 = np.zeros(m)
    st = solver_state(curves)
    v = st.v
    vfree = st.vfree
    c0 = st.c0
    fv = st.fv
    sv = st.sv
    Jinv = st.Jinv
    state = st.state
    # every segment's line (slope, intercept) once, for the segment changes below
    lines_s = np.empty((m, kv.shape[1] + 1))
    lines_a = np.empty((m, kv.shape[1] + 1))
    for c in range(m):
        for sg in range(nk[c] + 1):
            lines_s[c, sg], lines_a[c, sg] = _segment_line(sg, kv, kf, c, nk[c], slo[c], shi[c])
    # and its open interval (bounds[0], bounds[1]), for _fast_solve's branch-free test
    bounds = np.empty((2, m, kv.shape[1] + 1))
    for c in range(m):
        for sg in range(nk[c] + 1):
            bounds[0, c, sg] = -np.inf if sg == 0 else kv[c, sg - 1]
            bounds[1, c, sg] = np.inf if sg == nk[c] else kv[c, sg]
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
            tr = (pr[i] * xr[i] - pi[i] * xi[i] + hr[i] * bdr[i] - hi[i] * bdi[i]
                  + gmr[i] * bpr[i] - gmi[i] * bpi[i])
            ti = (pr[i] * xi[i] + pi[i] * xr[i] + hr[i] * bdi[i] + hi[i] * bdr[i]
                  + gmr[i] * bpi[i] + gmi[i] * bpr[i])
            xr[i] = tr
            xi[i] = ti
        # the velocities in a loop of their own: the update above has no loop-carried
        # chain and vectorizes; fused with these sums (strict FP order) it ran scalar.
        # Same sums in the same order as before, so the same rounding.
        if third is None:
            for i in range(n):
                tr = xr[i]
                ti = xi[i]
                a0 += Cvr[0, i] * tr - Cvi[0, i] * ti
                a1 += Cvr[1, i] * tr - Cvi[1, i] * ti
                a2 += Cvr[2, i] * tr - Cvi[2, i] * ti
                a3 += Cvr[3, i] * tr - Cvi[3, i] * ti
        else:
            # the velocities and the travels as 8 scalar sums of one loop (registers, no
            # store per mode): the travels' chains run beside the velocities'
            t0 = 0.0
            t1 = 0.0
            t2 = 0.0
            t3_ = 0.0
            for i in range(n):
                tr = xr[i]
                ti = xi[i]
                a0 += CvtTr[i, 0] * tr - CvtTi[i, 0] * ti
                a1 += CvtTr[i, 1] * tr - CvtTi[i, 1] * ti
                a2 += CvtTr[i, 2] * tr - CvtTi[i, 2] * ti
                a3 += CvtTr[i, 3] * tr - CvtTi[i, 3] * ti
                t0 += CvtTr[i, 4] * tr - CvtTi[i, 4] * ti
                t1 += CvtTr[i, 5] * tr - CvtTi[i, 5] * ti
                t2 += CvtTr[i, 6] * tr - CvtTi[i, 6] * ti
                t3_ += CvtTr[i, 7] * tr - CvtTi[i, 7] * ti
            tfree[0] = t_rig[k, 0] + t0
            tfree[1] = t_rig[k, 1] + t1
            tfree[2] = t_rig[k, 2] + t2
            tfree[3] = t_rig[k, 3] + t3_
        if elements is not None:
            if any_bs:
                # the travel rows (Ce rows 0-3, held mode-major: CeTr[i, c]), the 4 corners
                # as the inner loop, which the compiler can run as one vector
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
        if elements is not None:
            if any_lo:
                for c in range(m):
                    cfree[c] = static[c] + e_rig[k, 4 + c]
                for i in range(n):
                    tr = xr[i]
                    ti = xi[i]
                    for c in range(m):
                        cfree[c] += CeTr[i, 4 + c] * tr - CeTi[i, 4 + c] * ti
        if third is None:
            for c in range(m):
                c0[c] = alpha[c] * F_prev[c] + b1[c] * f_prev[c] + bm[c] * f_prev2[c]
        if third is not None:
            # (c03, the lags' known part of every element's force, was formed at the end of
            # the last step)
            # the common cases inline (as _fast_solve's): every element strictly inside its
            # segment, or segment changes by rank-1 updates of the cached inverse and of the
            # solution (_third_change); the rest (no valid inverse, cycling, a singular
            # update) in _third_solve. The elements' motions are their free parts plus their
            # rows' same-step response (wd3, ws3) to dF: no corner travel is formed.
            it = 0
            if valid3[0] >= 1:
                # J dF = sum_d m_d (c0_d + b0_d (a_d + s_d m_d vfree)) - cbar vfree + sum_j
                # q_j (a_j + k_j q_j tfree): each element's line at its free motion (the
                # corner shocks' unit rows directly), a spring's term only in contact (out
                # of contact its line is zero)
                for d in range(m):
                    x = vfree[d]
                    vef3[d] = x
                    rhs3[d] = c03[d] + b0A[d] * (da3[d] + ds3[d] * x) - cbar[d] * x
                for d in range(m, nd3):
                    x = 0.0
                    for c in range(m):
                        x += drowsA[d, c] * vfree[c]
                    vef3[d] = x
                    q = c03[d] + b0A[d] * (da3[d] + ds3[d] * x)
                    for a in range(m):
                        rhs3[a] += drowsA[d, a] * q
                for j in range(ns3):
                    x = 0.0
                    for c in range(m):
                        x += srows3[j, c] * tfree[c]
                    tef3[j] = x
                for j in range(ns3):
                    if sseg[j] >= 0:
                        q = sa3[j] + sk3[j] * tef3[j]
                        for a in range(m):
                            rhs3[a] += srows3[j, a] * q
                for a in range(m):
                    acc = 0.0
                    for c in range(m):
                        acc += Jinv3[a, c] * rhs3[c]
                    dF3[a] = acc
                for it_ in range(1, THIRD_FAST_PASSES + 1):
                    # every element strictly inside its segment (the common case), tested
                    # without a branch per element (as _fast_solve); otherwise each is placed
                    # by _segment_of / _spring_seg, which decide a motion on a knot
                    inside = True
                    for d in range(nd3):
                        x = vef3[d]
                        for c in range(m):
                            x += wd3[d, c] * dF3[c]
                        ve3[d] = x
                        sg = dseg[d]
                        inside &= (bnd3[0, d, sg] < x) & (x < bnd3[1, d, sg])
                    for j in range(ns3):
                        x = tef3[j]
                        for c in range(m):
                            x += ws3[j, c] * dF3[c]
                        te3[j] = x
                        xs = x - s03[j]
                        sg = sseg[j] + 1
                        inside &= (sbnd3[0, j, sg] < xs) & (xs < sbnd3[1, j, sg])
                    if not inside:
                        # each element in turn at its motion on the solution so far; a
                        # change moves the solution and the cached inverse (Sherman-Morrison)
                        same = True
                        for d in range(nd3):
                            x = vef3[d]
                            for c in range(m):
                                x += wd3[d, c] * dF3[c]
                            ve3[d] = x
                            s2 = _segment_of(x, kvA, d, nkA[d], dseg[d])
                            if s2 == dseg[d]:
                                continue
                            same = False
                            sl2 = dls3[d, s2]
                            a2 = dla3[d, s2]
                            dsl = sl2 - ds3[d]
                            dfc = b0A[d] * ((a2 - da3[d]) + dsl * x)
                            dseg[d] = s2
                            ds3[d] = sl2
                            da3[d] = a2
                            if not _third_change(Jinv3, drowsA, wd3, d, b0A[d] * dsl, dfc, dF3,
                                                 z3, y3, valid3):
                                break
                        if valid3[0] >= 1:
                            for j in range(ns3):
                                x = tef3[j]
                                for c in range(m):
                                    x += ws3[j, c] * dF3[c]
                                te3[j] = x
                                s2 = _spring_seg(x, j, s03, bx3, bn3)
                                if s2 == sseg[j]:
                                    continue
                                same = False
                                k2, a2 = _spring_line(s2, j, s03, bx3, bf3, bn3, bslope3)
                                dk = k2 - sk3[j]
                                dfc = (a2 - sa3[j]) + dk * x
                                sseg[j] = s2
                                sk3[j] = k2
                                sa3[j] = a2
                                if not _third_change(Jinv3, srows3, ws3, j, dk, dfc, dF3, z3, y3,
                                                     valid3):
                                    break
                        if valid3[0] == 0 or valid3[0] > _MAX_RANK1_UPDATES:
                            valid3[0] = 0
                            break
                        if not same:
                            continue
                    for d in range(nd3):
                        fd3[d] = da3[d] + ds3[d] * ve3[d]
                    for j in range(ns3):
                        gs3[j] = sa3[j] + sk3[j] * te3[j]
                    for c in range(m):
                        v[c] = ve3[c]
                    it = it_
                    if valid3[0] > _MAX_RANK1_UPDATES:
                        valid3[0] = 0
                    break
            if it == 0:
                # from the segments (the fast path keeps the inverse, not Mv and Mt)
                valid3[0] = 0
                it = _third_solve(vfree, tfree, c03, Deff, Dt3, cbar, drowsA, kvA, kfA, nkA,
                                  sloA, shiA, b0A, srows3, s03, bx3, bf3, bn3, bslope3, dseg,
                                  sseg, ds3, da3, sk3, sa3, Mv3, Mt3, J3, Jinv3, valid3, rhs3,
                                  ve3, te3, dF3, v, t3, fd3, gs3)
            if it < 0:
                failed = True
                it = 80
            if it > worst:
                worst = it
            for d in range(nd3):
                f = fd3[d]
                F = c03[d] + b0A[d] * f
                Fp3[d] = F
                # the next step's known part of the force: alpha F[k] + b1 f[k] + bm f[k-1]
                c03[d] = alphaA[d] * F + b1A[d] * f + bmA[d] * fp3[d]
                fp3[d] = f
            for c in range(m):
                F_prev[c] = Fp3[c]
                dF_prev[c] = dF3[c]
            d0 = dF_prev[0]
            d1 = dF_prev[1]
            d2 = dF_prev[2]
            d3 = dF_prev[3]
            for i in range(n):
                ur = Br[0, i] * d0 + Br[1, i] * d1 + Br[2, i] * d2 + Br[3, i] * d3
                ui = Bi[0, i] * d0 + Bi[1, i] * d1 + Bi[2, i] * d2 + Bi[3, i] * d3
                bpr[i] = ur  # the step before's row, swapped in below
                bpi[i] = ui
            bdr, bpr = bpr, bdr
            bdi, bpi = bpi, bdi
        elif elements is None:
            it = _fast_solve(vfree, c0, Deff, b0, curves, lines_s, lines_a, bounds, st)
            if it == 0:
                it = shock_step(vfree, c0, Deff, cbar, b0, curves, st)
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
            # corrector: B dF[k] (x[k] = xp[k] + g1 B dF[k] is folded into the predictor)
            d0 = dF_prev[0]
            d1 = dF_prev[1]
            d2 = dF_prev[2]
            d3 = dF_prev[3]
            for i in range(n):
                ur = Br[0, i] * d0 + Br[1, i] * d1 + Br[2, i] * d2 + Br[3, i] * d3
                ui = Bi[0, i] * d0 + Bi[1, i] * d1 + Bi[2, i] * d2 + Bi[3, i] * d3
                bpr[i] = ur  # the step before's row, swapped in below
                bpi[i] = ui
            bdr, bpr = bpr, bdr
            bdi, bpi = bpi, bdi
        else:
            # first guesses: the bump-stop forces and pad corrections of the last step
            # (zero out of contact, the common case: one solve, then the check). The
            # explicit variant (max_iter 1) takes the stop at the travel extrapolated with
            # the last step's inputs.
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
                it = _fast_solve(vf2, c0, Deff, b0, curves, lines_s, lines_a, bounds, st)
                if it == 0:
                    it = shock_step(vf2, c0, Deff, cbar, b0, curves, st)
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
                            # Newton on G - g(s(G)) with ds_c/dG_c: through the plant
                            # (Dt[c, c], < 0: the stop pushes the wheel away) and the shocks'
                            # answer (with the solve's cached inverse: dv/dG = Jinv Deff)
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
            # corrector: B dF[k] + Bw w[k] (folded into the predictor, as above)
            d0 = dF_prev[0]
            d1 = dF_prev[1]
            d2 = dF_prev[2]
            d3 = dF_prev[3]
            for i in range(n):
                ur = Br[0, i] * d0 + Br[1, i] * d1 + Br[2, i] * d2 + Br[3, i] * d3
                ui = Bi[0, i] * d0 + Bi[1, i] * d1 + Bi[2, i] * d2 + Bi[3, i] * d3
                bpr[i] = ur  # the step before's row, swapped in below
                bpi[i] = ui
            bdr, bpr = bpr, bdr
            bdi, bpi = bpi, bdi
            if w_now:
                for i in range(n):
                    bdr[i] += (Bwr[0, i] * w[0] + Bwr[1, i] * w[1] + Bwr[2, i] * w[2]
                               + Bwr[3, i] * w[3])
                    bdi[i] += (Bwi[0, i] * w[0] + Bwi[1, i] * w[1] + Bwi[2, i] * w[2]
                               + Bwi[3, i] * w[3])
        # an output sample every r-th step (a counter: no integer division per step)
        if phase == 0:
            kk = k // r
            for c in range(m):
                F_out[kk, c] = F_prev[c]
                St[col, 2 * n + c] = dF_prev[c]
            if third is not None:
                for d in range(ne3):
                    F_out[kk, m + d] = Fp3[m + d]
                for j in range(ns3):
                    F_out[kk, m + ne3 + j] = gs3[j]
                    if sseg[j] >= 0:
                        n_sp[j] += 1.0
            if v_row >= 0:
                for c in range(m):
                    y_out[v_row + c, kk] = v[c]
            for i in range(n):  # x[k] = xp[k] + g1 B dF[k]
                St[col, i] = xr[i] + (g1r[i] * bdr[i] - g1i[i] * bdi[i])
                St[col, n + i] = xi[i] + (g1r[i] * bdi[i] + g1i[i] * bdr[i])
            if elements is not None:
                for c in range(nw):
                    St[col, 2 * n + m + c] = w[c]
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
                Y = np.dot(St[:col], Cy)  # (col, p)
                for j in range(col):
                    for o in range(p):
                        y_out[o, kk0 + j] = y_rig[kk0 + j, o] + Y[j, o]
                if elements is not None:
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
    if elements is not None:
        for c in range(m):
            stats[0, c] = n_bs[c]
            stats[1, c] = n_lo[c]
            stats[2, c] = c_min[c]
    if third is not None:
        for j in range(ns3):
            tstats[j] = n_sp[j]
    return -1 if failed else worst


@_nb.njit(cache=True, error_model="numpy", parallel=True)
def loop_batch(plant, setups, drive, y_out, F_out, iters, elements, stats, third, tstats):
    """The closed loop of every setup (`setups` a :class:`ShockSetups` with one row per
    setup), in parallel over the setups, each by :func:`loop_one`: outputs into ``y_out``
    (n_setups, p, n_out), applied shock forces into ``F_out`` (n_setups, n_out, 4), Newton
    iteration counts into ``iters`` (-1: no convergence). `elements`: ``None`` or an
    :class:`Elements` with one row per setup of its setup fields, the element counts then
    into ``stats`` (n_setups, 3, 4) (``None`` without). `third`: ``None`` or a
    :class:`ThirdLoop` with one row per setup of its setup fields (`elements` then
    ``None``), the springs' contact counts into ``tstats`` (n_setups, ns), ``F_out`` with
    ``4 + ne + ns`` columns (:func:`loop_one`)."""
    for s in _nb.prange(setups.b0.shape[0]):
        if third is not None:
            iters[s] = loop_one(plant, _setup_row(setups, s), drive, y_out[s], F_out[s],
                                np.int64(-1), None, None, _third_row(third, s), tstats[s])
        elif elements is None:
            iters[s] = loop_one(plant, _setup_row(setups, s), drive, y_out[s], F_out[s],
                                np.int64(-1), None, None, None, None)
        else:
            iters[s] = loop_one(plant, _setup_row(setups, s), drive, y_out[s], F_out[s],
                                np.int64(-1), _element_row(elements, s), stats[s], None, None)
    return


@_nb.njit(cache=True, error_model="numpy", nogil=True)
def loop_serial(plant, setups, drive, y_out, F_out, iters, elements, stats, third, tstats):
    """:func:`loop_batch` one setup after the other (the same `loop_one`, the same numbers).

    A single setup gains nothing from the parallel loop, and this kernel compiles in about
    60 % of its time: the virtual rig (one setup per run) uses it, so a fresh machine's first
    ``rig simulate`` or demo waits for the smaller compilation only (the demo compiles the
    parallel kernel meanwhile in a worker). It releases the GIL (as :func:`rig_kernel`
    does): the virtual rig runs its runs on threads.
    """
    for s in range(setups.b0.shape[0]):
        if third is not None:
            iters[s] = loop_one(plant, _setup_row(setups, s), drive, y_out[s], F_out[s],
                                np.int64(-1), None, None, _third_row(third, s), tstats[s])
        elif elements is None:
            iters[s] = loop_one(plant, _setup_row(setups, s), drive, y_out[s], F_out[s],
                                np.int64(-1), None, None, None, None)
        else:
            iters[s] = loop_one(plant, _setup_row(setups, s), drive, y_out[s], F_out[s],
                                np.int64(-1), _element_row(elements, s), stats[s], None, None)
    return


#: Counters after the bins in a histogram row of :func:`loop_metrics_worker` (per setup and
#: corner): output samples with ``|v| < knee``, with ``v > 0`` (bump, compression) and with
#: ``v < 0`` (rebound).
HISTOGRAM_COUNTERS = 3


@_nb.njit(cache=True, error_model="numpy", inline="always")
def histogram_add(v, lo, inv_width, knee, row):
    """Count the velocity samples `v` (n,) [m/s] into ``row`` (n_bins + 3): bin ``1 +
    floor((v - lo) * inv_width)`` clipped to the two open end bins 0 and ``n_bins - 1``,
    then the counters of :data:`HISTOGRAM_COUNTERS`. No branch per sample (the clip is a
    min/max, the counters add comparisons). Callable from Python too (the logged
    histograms of :mod:`planner.histograms` count with the same arithmetic)."""
    nb = row.size - HISTOGRAM_COUNTERS
    top = nb - 1.0
    n_low = 0.0
    n_bump = 0.0
    n_reb = 0.0
    for k in range(v.size):
        x = v[k]
        b = min(max(np.floor((x - lo) * inv_width) + 1.0, 0.0), top)
        row[int(b)] += 1.0
        n_low += 1.0 if abs(x) < knee else 0.0
        n_bump += 1.0 if x > 0.0 else 0.0
        n_reb += 1.0 if x < 0.0 else 0.0
    row[nb] += n_low
    row[nb + 1] += n_bump
    row[nb + 2] += n_reb


@_nb.njit(cache=True, error_model="numpy", nogil=True)
def loop_metrics_worker(w, n_workers, plant, setups, drive, metrics, out, iters, elements,
                        stats, hist_spec, hist_out, third, tstats):
    """Worker `w` of `n_workers` of :func:`ident.sim.closedloop.simulate_batch_metrics`:
    the setups ``w, w + n_workers, ...`` (interleaved, so that each worker gets a mix of
    cheap and costly setups), each simulated by :func:`loop_one` and its metrics computed
    right after (:func:`ident.sim.metric_kernels.setup_metric_rms`, per band of the
    :class:`MetricFilters` `metrics`) into ``out`` (n_setups, n_bands, n_metrics).

    The outputs ``drive.Cy`` (2 n + 4 (+ 4), p) are the metrics' signals (a ride height
    pair as one row of averaged coefficients; with lift-off the ``w`` rows, zero for a
    ride height: measured from the real pad; ``elements.tf_rows`` then the columns of the
    tire forces); the shock velocities come from the loop's own solve (rows p .. p + 3 of
    the setup's buffer), not from the product. `elements` and `stats` as
    :func:`loop_batch`. The worker keeps one setup's outputs and the metric's scratch
    (about 2 MB for 12,000 samples): nothing of size (setups x samples) is written. It
    releases the GIL: the workers are threads.

    With `hist_spec` ``(lo, inv_width, knee)`` ([m/s], [s/m], [m/s]) each setup's shock
    velocities at the output samples (the samples the metrics use) are also counted into
    ``hist_out`` (n_setups, 4, n_bins + 3) by :func:`histogram_add` (zeroed first);
    ``None`` for both: no histogram (numba compiles that case apart, without its code).
    The metrics are the same bits either way (the histogram only reads the velocities).
    `third` and `tstats` as :func:`loop_batch` (the third elements' motions are metric
    rows of ``drive.Cy`` as any output's).
    """
    p = drive.Cy.shape[1]
    n_out = drive.y_rig.shape[0]
    ia = metrics.ia
    sos = metrics.sos
    zi = metrics.zi
    padlen = metrics.padlen
    dmap = metrics.dmap
    dw = metrics.dw
    L = METRIC_LANES
    ns = sos.shape[1]
    S = setups.b0.shape[0]
    # the outputs, then the 4 shock velocities. Channel-major, as simulate_batch's: the
    # loop kernel is then the one-setup loop's compiled code (sample-major rows were about
    # 4 % faster but compile the loop once more, 4 s on a fresh machine's first demo)
    y = np.empty((p + 4, n_out))
    nF = 4
    if third is not None:
        nF = 4 + third.drows.shape[0] + third.srows.shape[0]
    F = np.empty((n_out, nF))
    buf = np.empty((n_out + 2 * padlen, L))
    z0 = np.empty((ns, L))
    z1 = np.empty((ns, L))
    stack = np.empty((METRIC_PW_LEVELS, 10, L))
    sums = np.empty(L)
    for s in range(w, S, n_workers):
        if third is not None:
            iters[s] = loop_one(plant, _setup_row(setups, s), drive, y, F, p, None, None,
                                _third_row(third, s), tstats[s])
        elif elements is None:
            iters[s] = loop_one(plant, _setup_row(setups, s), drive, y, F, p, None, None, None,
                                None)
        else:
            iters[s] = loop_one(plant, _setup_row(setups, s), drive, y, F, p,
                                _element_row(elements, s), stats[s], None, None)
        if hist_out is not None:
            for c in range(4):
                row = hist_out[s, c]
                for j in range(row.size):
                    row[j] = 0.0
                histogram_add(y[p + c], hist_spec[0], hist_spec[1], hist_spec[2], row)
        for b in range(sos.shape[0]):
            setup_metric_rms(y, ia, sos[b], zi[b], padlen, out[s, b], buf, z0, z1, stack, sums,
                             dmap, dw)
    return
