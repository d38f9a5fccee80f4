"""IPOPT on the optimizer's problem: metrics and gradients per iterate, the solves, the record.

:class:`Evaluator` evaluates the problem's rows (the drives' scores and the
objective's limits, linear combinations of the loop's metrics) and their
gradients by reverse mode, once per iterate; :func:`solve_problem` runs IPOPT
(a limited-memory Hessian) on them, adding the limits as constraints when they
bind, and keeps the convergence record (every iterate, its objective and
infeasibilities).
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from ident import interrupts
from ident.errors import ShockplanWarning

__all__ = [
    "ACCEPTABLE_CHANGE",
    "ACCEPTABLE_ITER",
    "ACCEPTABLE_TOL",
    "IPOPT_TOL",
    "acceptable_reason",
    "OptimizeWarning",
    "Evaluator",
    "solve_problem",
]

#: IPOPT stops as converged ("acceptable") once the objective's relative change stays below
#: this for 5 iterations: 1e-5 of a score is far below the model's accuracy (~1e-3), and
#: the piecewise-linear curves' kinks make the last digits of a tighter tolerance costly.
ACCEPTABLE_CHANGE = 1e-5
#: IPOPT's convergence tolerance (scaled NLP error) and the looser "acceptable" one, with the
#: iterations the acceptable test must hold. A stop at the acceptable level is reported as
#: such (``solver["acceptable"]``, an :class:`OptimizeWarning` with the reason): it is not a
#: converged optimum (issue 24: the GT car's optimum stopped there on a flat landscape).
IPOPT_TOL = 1e-6
ACCEPTABLE_TOL = 1e-3
ACCEPTABLE_ITER = 5
#: IPOPT statuses that count as solved ("acceptable" with a warning).
_SOLVED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
_ACCEPTABLE = "Solved_To_Acceptable_Level"


class OptimizeWarning(ShockplanWarning):
    """The optimizer stopped without converging (or only at IPOPT's acceptable level); the
    best verified candidate is returned."""


def acceptable_reason(history, iterations):
    """Why IPOPT stopped at its acceptable level, in one phrase.

    Parameters
    ----------
    history : pandas.DataFrame
        The iterations (``objective``, and ``inf_pr``, ``inf_du`` when IPOPT gave them).
    iterations : int

    Returns
    -------
    str

    Examples
    --------
    >>> h = pd.DataFrame({"objective": [1.0, 0.9, 0.9, 0.9, 0.9, 0.9, 0.9],
    ...                   "inf_pr": [0.0] * 7, "inf_du": [1.0, 0.1, 0.05, 0.03, 0.03, 0.03, 0.02]})
    >>> acceptable_reason(h, 6)
    'the objective changed by 0 (relative) over the last 5 iterations, below 1e-05, with the dual infeasibility 2.0e-02 above the tolerance 1e-06 after 6 iterations'
    """
    obj = history["objective"].to_numpy(float) if len(history) else np.array([np.nan])
    tail = obj[-(ACCEPTABLE_ITER + 1):]
    change = float(np.max(np.abs(np.diff(tail))) / max(abs(tail[-1]), 1e-300)) \
        if tail.size > 1 else float("nan")
    parts = [f"the objective changed by {change:.2g} (relative) over the last "
             f"{ACCEPTABLE_ITER} iterations, below {ACCEPTABLE_CHANGE:g}"
             if change <= ACCEPTABLE_CHANGE else
             f"the scaled NLP error stayed below the acceptable tolerance {ACCEPTABLE_TOL:g} "
             f"for {ACCEPTABLE_ITER} iterations"]
    for key, what in (("inf_du", "dual infeasibility"), ("inf_pr", "primal infeasibility")):
        if key in history and len(history) and float(history[key].iloc[-1]) > IPOPT_TOL:
            parts.append(f"the {what} {float(history[key].iloc[-1]):.1e} above the tolerance "
                         f"{IPOPT_TOL:g}")
    return ", with ".join(parts) + f" after {iterations} iterations"


class Evaluator:
    """The combinations ``z = C m`` of all drives' metrics (the scores and the limited
    metrics) and their gradients, cached per decision vector.

    The step functions are compiled (when jitted); the recursion runs in casadi's virtual
    machine, calling them. A row's gradient comes by reverse mode, one adjoint sweep (the
    compiled step's adjoint), so the cost of the gradients grows with the rows the problem
    holds, not with the decision variables.
    """

    def __init__(self, models, T, scale, C):  # noqa: N803 (matrices)
        x = ca.MX.sym("x", T.shape[1])
        seed = ca.MX.sym("seed", C.shape[0])
        P = ca.DM(T) @ (scale * x)
        m = ca.vertcat(*[mdl.metrics(P) for mdl in models])
        z = ca.DM(C) @ m
        self.f = ca.Function("scores", [x], [z])
        self.g = ca.Function("scores_adj", [x, seed], [z, ca.jtimes(z, x, seed, True)])
        self.n_x, self.n_z = T.shape[1], C.shape[0]
        self._x = None
        self._z = None
        self._grad = {}
        self.n_eval = 0
        self.n_grad = 0
        self.eval_s = 0.0
        self.grad_s = 0.0

    def _at(self, x):
        x = np.asarray(x, dtype=float)
        if self._x is None or not np.array_equal(x, self._x):
            self._x, self._z, self._grad = x.copy(), None, {}
        return x

    def value(self, x):
        """``z`` at `x`, shape (n_z,)."""
        x = self._at(x)
        if self._z is None:
            t0 = time.perf_counter()
            self._z = np.array(self.f(x)).ravel()
            self.eval_s += time.perf_counter() - t0
            self.n_eval += 1
        return self._z

    def gradients(self, x, rows):
        """The gradients of rows `rows` of ``z`` at `x`, shape (len(rows), n_x)."""
        x = self._at(x)
        out = np.empty((len(rows), self.n_x))
        for k, j in enumerate(rows):
            if j not in self._grad:
                seed = np.zeros(self.n_z)
                seed[j] = 1.0
                t0 = time.perf_counter()
                z, gr = self.g(x, seed)
                self.grad_s += time.perf_counter() - t0
                self.n_grad += 1
                self._z = np.array(z).ravel()
                self._grad[j] = np.array(gr).ravel()
            out[k] = self._grad[j]
        return out


class _MetricsCallback(ca.Callback):
    """casadi Callback: x -> rows `rows` of ``z`` (:class:`Evaluator`), with their Jacobian."""

    def __init__(self, ev, rows):
        ca.Callback.__init__(self)
        self.ev, self.rows = ev, list(rows)
        self.construct("scores_cb", {})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.ev.n_x, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(len(self.rows), 1)

    def eval(self, arg):
        return [ca.DM(self.ev.value(np.array(arg[0]).ravel())[self.rows])]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        ev, rows = self.ev, self.rows

        class _Jac(ca.Callback):
            def __init__(self):
                ca.Callback.__init__(self)
                self.construct(name, {})

            def get_n_in(self):
                return 2

            def get_n_out(self):
                return 1

            def get_sparsity_in(self, i):
                return ca.Sparsity.dense(ev.n_x, 1) if i == 0 else ca.Sparsity(len(rows), 1)

            def get_sparsity_out(self, i):
                return ca.Sparsity.dense(len(rows), ev.n_x)

            def eval(self, arg):
                return [ca.DM(ev.gradients(np.array(arg[0]).ravel(), rows))]

        self._jac = _Jac()  # keep a reference alive
        return self._jac


class _Iterations(ca.Callback):
    """IPOPT iteration callback: history, progress, the best feasible iterate."""

    def __init__(self, n_x, n_g, progress):
        ca.Callback.__init__(self)
        self.n_x, self.n_g = n_x, n_g
        self.history = []
        self.t0 = time.perf_counter()
        self.bar = None
        if progress:
            self.bar = tqdm(desc="optimize", unit="it")
        self.construct("iterations", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        n = ca.nlpsol_out(i)
        if n in ("f",):
            return ca.Sparsity.dense(1)
        if n in ("x", "lam_x"):
            return ca.Sparsity.dense(self.n_x)
        if n in ("g", "lam_g"):
            return ca.Sparsity.dense(self.n_g)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        d = {ca.nlpsol_out(i): arg[i] for i in range(ca.nlpsol_n_out())}
        self.history.append({"iteration": len(self.history), "objective": float(d["f"]),
                             "x": np.array(d["x"]).ravel().copy(),
                             "time_s": time.perf_counter() - self.t0})
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(objective=f"{float(d['f']):.5f}")
        # a non-zero return asks IPOPT to stop (User_Requested_Stop)
        return [1 if interrupts.requested() else 0]

    def close(self):
        if self.bar is not None:
            self.bar.close()


def solve_problem(ev, space, kinds, weights, aggregate, A_lin, b_lin, xs0, scale, max_iter,
                  progress):
    """IPOPT on the scaled decision variables; returns (x, solver dict, history DataFrame).

    The objective's limits enter as constraints when they bind: first those within 5 % of
    their bound at the start, then, after each solve, any the solution violates (a warm
    start from it). A limit row costs an adjoint sweep per iterate, so rows that never bind
    are left out.
    """
    score_rows = [j for j, (kind, _) in enumerate(kinds) if kind == "score"]
    limit_rows = [j for j, (kind, _) in enumerate(kinds) if kind == "limit"]
    z0 = ev.value(xs0)
    active = [j for j in limit_rows if z0[j] > 0.95]
    x_start, histories, info, total_its = xs0, [], None, 0
    t0 = time.perf_counter()
    for _ in range(len(limit_rows) + 1):
        xs_opt, info, hist = _ipopt(ev, space, score_rows, active, weights, aggregate, A_lin,
                                    b_lin, x_start, scale, max_iter - total_its, progress)
        histories.append(hist)
        total_its += info["iterations"]
        z = ev.value(xs_opt)
        late = [j for j in limit_rows if j not in active and z[j] > 1.0 + 1e-6]
        if not late or total_its >= max_iter:
            break
        active += late
        x_start = xs_opt
    hist = pd.concat(histories, ignore_index=True)
    hist.insert(0, "iteration", np.arange(len(hist)))
    info["acceptable"] = info["status"] == _ACCEPTABLE
    info["converged"] = info["status"] == "Solve_Succeeded"
    info["reason"] = (acceptable_reason(histories[-1], total_its) if info["acceptable"]
                      else "")
    info.update(iterations=total_its, solve_s=time.perf_counter() - t0,
                active_limits=len(active), limits=len(limit_rows),
                iterates=[x for h in histories for x in h.attrs["iterates"]])
    return xs_opt * scale, info, hist


def _ipopt(ev, space, score_rows, limit_rows, weights, aggregate, A_lin, b_lin, xs0, scale,
           max_iter, progress):
    """One IPOPT solve with the given score and limit rows of ``z``; the decision variables
    are the columns of `A_lin` (the curves', then any packers')."""
    n_x = A_lin.shape[1]
    cb = _MetricsCallback(ev, score_rows + limit_rows)
    xs = ca.MX.sym("xs", n_x)
    z = cb(xs)
    scores = [z[k] for k in range(len(score_rows))]
    g, lbg, ubg = [], [], []
    # linear constraints on the scaled variables, rows normalized
    As = A_lin * scale[None, :]
    rn = np.maximum(np.abs(As).max(axis=1), 1e-300)
    g.append(ca.DM(As / rn[:, None]) @ xs)
    lbg.append(np.full(As.shape[0], -np.inf))
    ubg.append(b_lin / rn)
    for k in range(len(limit_rows)):
        g.append(z[len(score_rows) + k])
        lbg.append([-np.inf])
        ubg.append([1.0])
    if aggregate == "sum":
        f = sum(float(wd) * sd for wd, sd in zip(weights, scores))
        x_all, x_start = xs, xs0
    else:
        t = ca.MX.sym("t")
        f = t
        for sd in scores:
            g.append(sd - t)
            lbg.append([-np.inf])
            ubg.append([0.0])
        x_all = ca.vertcat(xs, t)
        x_start = np.concatenate([xs0, [float(np.max(ev.value(xs0)[score_rows]))]])
    G = ca.vertcat(*g)
    it_cb = _Iterations(x_all.shape[0], G.shape[0], progress)
    opts = {"ipopt.hessian_approximation": "limited-memory", "ipopt.max_iter": int(max_iter),
            "ipopt.tol": IPOPT_TOL, "ipopt.acceptable_tol": ACCEPTABLE_TOL,
            "ipopt.acceptable_iter": ACCEPTABLE_ITER,
            "ipopt.acceptable_obj_change_tol": ACCEPTABLE_CHANGE, "ipopt.print_level": 0,
            "print_time": False, "ipopt.sb": "yes", "iteration_callback": it_cb,
            "ipopt.mu_strategy": "adaptive"}
    solver = ca.nlpsol("curves", "ipopt", {"x": x_all, "f": f, "g": G}, opts)
    try:
        # casadi would swallow a KeyboardInterrupt raised in a callback and report the solve
        # as finished: SIGINT only sets a flag while it runs, the callbacks stop IPOPT on it
        with interrupts.deferred():
            sol = solver(x0=x_start, lbg=np.concatenate(lbg), ubg=np.concatenate(ubg))
    finally:
        it_cb.close()
    interrupts.check()  # an interrupted solve is never reported as a result
    stats = solver.stats()
    its = stats.get("iterations", {})
    hist = pd.DataFrame({"objective": [h["objective"] for h in it_cb.history],
                         "time_s": [h["time_s"] for h in it_cb.history]})
    for key in ("inf_pr", "inf_du"):
        if key in its and len(its[key]) == len(hist):
            hist[key] = its[key]
    hist.attrs["iterates"] = [(h["x"][:n_x] * scale, h["objective"])
                              for h in it_cb.history]
    info = {"status": stats.get("return_status", "unknown"),
            "success": stats.get("return_status") in _SOLVED,
            "iterations": int(stats.get("iter_count", len(hist))),
            "objective": float(sol["f"])}
    return np.array(sol["x"]).ravel()[:n_x], info, hist
