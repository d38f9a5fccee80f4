"""Solving an experiment design: the relaxed problem (cvxpy), greedy rounding, run order.

Part of :mod:`planner.design` (see its docstring).
"""

from __future__ import annotations

import itertools
import time

import numpy as np

from planner.rig_spec import default_rig
from planner.design.candidates import change_counts
from planner.design.information import INFORMATION_EPS, criterion_value, hermitian

__all__ = [
    "relaxed_design",
    "sequence_cost",
    "greedy_design",
    "fit_budget",
    "swap_order",
]


def relaxed_design(Mc, M0, cost, budget, criterion, W, groups):
    """cvxpy on the design bands: relaxed run counts (n_cand,), the value and status."""
    import cvxpy as cp  # heavy (1.6 s to import); only the relaxed design needs it

    n = cp.Variable(Mc.shape[0], nonneg=True)
    terms = []
    for g in groups:
        A = np.sum(Mc[:, g], axis=1)  # (n_cand, 11, 11)
        B = hermitian(np.sum(M0[g], axis=0)) + INFORMATION_EPS * len(g) * np.eye(11)
        Ag = A.reshape(A.shape[0], -1).T  # (121, n_cand)
        Mg = cp.reshape(Ag @ n, (11, 11), order="C") + B
        Mg = (Mg + cp.conj(Mg).T) / 2
        if criterion == "d":
            terms.append(len(g) * cp.log_det(Mg / len(g)))
        else:
            Wg = np.eye(11) if criterion == "a" else hermitian(np.sum(W[g], axis=0))
            w_eig, V = np.linalg.eigh(Wg)
            Lw = V * np.sqrt(np.clip(w_eig, 0, None))
            terms.append(-cp.real(cp.matrix_frac(Lw, Mg)))
    prob = cp.Problem(cp.Maximize(sum(terms)), [cost @ n <= budget])
    t0 = time.perf_counter()
    try:
        prob.solve(solver=cp.CLARABEL)
    except cp.error.SolverError as exc:  # pragma: no cover - reported, the greedy stands in
        return None, float("nan"), f"solver error: {exc}", time.perf_counter() - t0
    status = prob.status
    if status not in ("optimal", "optimal_inaccurate") or n.value is None:
        return None, float("nan"), status, time.perf_counter() - t0
    return np.maximum(np.asarray(n.value), 0.0), float(prob.value), status, \
        time.perf_counter() - t0


def sequence_cost(seq, cands, base, rig, tail=()):
    """Rig time [min] of candidate runs in the order `seq`, from the baseline installed, and
    of the fixed runs `tail` after them (``(setup, duration_s)`` pairs: the validation runs,
    whose changes from the last run count as rig time too)."""
    t, prev = 0.0, base
    runs = [(cands[c].setup, cands[c].duration_s) for c in seq] + list(tail)
    for setup, duration_s in runs:
        swaps, clicks = change_counts(prev, setup)
        t += (duration_s / 60 + rig.run_overhead_min + rig.swap_min * swaps
              + rig.click_change_min * clicks)
        prev = setup
    return t


def _insertion(seq, c, cands, base, rig, tail=()):
    """Cheapest place to insert candidate `c` in `seq` (before the fixed runs `tail`): (extra
    minutes, position)."""
    s = cands[c].setup
    own = cands[c].duration_s / 60 + rig.run_overhead_min
    best = (np.inf, 0)
    setups = [base] + [cands[i].setup for i in seq] + [t[0] for t in tail[:1]]
    for p in range(len(seq) + 1):
        prev, nxt = setups[p], (setups[p + 1] if p + 1 < len(setups) else None)
        ds, dc = change_counts(prev, s)
        if nxt is not None:
            (s1, c1), (s0, c0) = change_counts(s, nxt), change_counts(prev, nxt)
            ds, dc = ds + s1 - s0, dc + c1 - c0
        best = min(best, (own + rig.swap_min * ds + rig.click_change_min * dc, p))
    return best


def greedy_design(Mc, M0, cands, base, rig, budget, criterion, W=None, start=(), tail=()):
    """Add runs one at a time where they cost least in the sequence, each the best criterion
    gain per minute that still fits the budget.

    Parameters
    ----------
    Mc : ndarray, shape (n_cand, n_b, 11, 11)
        Scaled information of each candidate run.
    M0 : ndarray, shape (n_b, 11, 11)
    cands : list of Candidate
    base : Setup
        The setup installed at the start.
    rig : planner.rig_spec.RigSpec
    budget : float
        [min]
    criterion : str
    W : ndarray, optional
    start : sequence of int
        Runs already planned, in order.
    tail : sequence of (Setup, float)
        Runs fixed at the end of the plan (the validation runs: setup, duration [s]); they
        add no information here, but their changes and durations spend the budget.

    Returns
    -------
    list of int
        Candidate indices in rig order.
    """
    seq = list(start)
    M = M0 + sum((Mc[i] for i in seq), np.zeros_like(M0))
    spent = sequence_cost(seq, cands, base, rig, tail)
    value = criterion_value(M, criterion, W)
    while True:
        best = None
        for c in range(len(cands)):
            extra, pos = _insertion(seq, c, cands, base, rig, tail)
            if spent + extra > budget + 1e-9:
                continue
            v = criterion_value(M + Mc[c], criterion, W)
            gain = (v - value) / extra
            if gain > 0 and (best is None or gain > best[0]):
                best = (gain, c, pos, extra, v)
        if best is None:
            return seq
        _, c, pos, extra, value = best
        seq.insert(pos, c)
        M = M + Mc[c]
        spent += extra


def fit_budget(seq, Mc, M0, cands, base, rig, budget, criterion, W, tail=()):
    """Drop runs from `seq` (the least criterion per minute saved first) until it fits, with
    the fixed runs `tail` after it (see :func:`greedy_design`)."""
    seq = list(seq)
    while seq and sequence_cost(seq, cands, base, rig, tail) > budget + 1e-9:
        M = M0 + sum(Mc[i] for i in seq)
        full = criterion_value(M, criterion, W)
        cost = sequence_cost(seq, cands, base, rig, tail)
        best = None
        for k, i in enumerate(seq):
            rest = seq[:k] + seq[k + 1:]
            saved = cost - sequence_cost(rest, cands, base, rig, tail)
            loss = full - criterion_value(M - Mc[i], criterion, W)
            ratio = loss / max(saved, 1e-9)
            if best is None or ratio < best[0]:
                best = (ratio, k)
        seq.pop(best[1])
    return seq


def _changes(a, b):
    return sum(x != y for x, y in zip(a.ids(), b.ids()))


def swap_order(setups, start, rig=None, end=None):
    """Run order (indices) that changes the car least, starting from setup `start` (and
    going on to setup `end`, if given: the first run after these): the fewest corners
    swapped, a click change counting its time in swaps of `rig`."""
    n = len(setups)
    if n <= 1:
        return list(range(n))
    rig = default_rig() if rig is None else rig
    w = rig.click_change_min / rig.swap_min if rig.swap_min > 0 else 1.0

    def dist(a, b):
        swaps, clicks = change_counts(a, b)
        return swaps + w * clicks if clicks else swaps

    d = np.array([[dist(a, b) for b in setups] for a in setups])
    d0 = np.array([dist(start, s) for s in setups])
    d_end = (np.zeros(n) if end is None else np.array([dist(s, end) for s in setups]))
    if n <= 9:  # Held-Karp, exact
        best = {}
        for j in range(n):
            best[(1 << j, j)] = (d0[j], -1)
        for size in range(2, n + 1):
            for subset in itertools.combinations(range(n), size):
                mask = sum(1 << j for j in subset)
                for j in subset:
                    prev = mask & ~(1 << j)
                    best[(mask, j)] = min((best[(prev, i)][0] + d[i, j], i) for i in subset
                                          if i != j)
        full = (1 << n) - 1
        j = min(range(n), key=lambda j: best[(full, j)][0] + d_end[j])
        order, mask = [], full
        while j != -1:
            order.append(j)
            mask, j = mask & ~(1 << j), best[(mask, j)][1]
        return order[::-1]
    order, left, cur = [], set(range(n)), None
    while left:  # nearest neighbour, then 2-opt
        j = min(left, key=lambda j: (d0[j] if cur is None else d[cur, j], j))
        order.append(j)
        left.remove(j)
        cur = j

    def length(o):
        return d0[o[0]] + sum(d[o[k], o[k + 1]] for k in range(len(o) - 1)) + d_end[o[-1]]

    improved = True
    while improved:
        improved = False
        for i in range(len(order) - 1):
            for k in range(i + 1, len(order)):
                cand = order[:i] + order[i:k + 1][::-1] + order[k + 1:]
                if length(cand) < length(order):
                    order, improved = cand, True
    return order
