"""The IPOPT driver of the identification: the objective, its gradient and the Gauss-Newton Hessian of a
problem (:class:`arvcas.ident.identify.Problem`'s ``cost``, ``gradient``, ``gauss_newton``) as CasADi callbacks
for ``nlpsol``, and an iteration callback that prints progress, keeps the best iterate, honours a stop flag
(Ctrl-C) and ends the solve when the objective changes by less than ``tol`` over :data:`STALL_ITER`
iterations (docs/identification.md).
"""

from __future__ import annotations

import math
import threading

import casadi as ca
import numpy as np

__all__ = ["STALL_ITER", "solve"]

STALL_ITER = 3  # iterations over which a relative objective change below ``tol`` ends the solve


class _Fn(ca.Callback):
    """A function of z (dense, ``nz``) computed in Python, as a CasADi Function; with ``jac``, its Jacobian.

    The objective (1 x 1) with its gradient (1 x nz), and the Gauss-Newton Hessian (nz x nz), for IPOPT through
    CasADi's nlpsol. CasADi keeps no Python reference to a callback: each is held by its owner.
    """

    def __init__(self, name: str, nz: int, out: tuple[int, int], fn, jac=None, f_out: tuple[int, int] | None = None):
        ca.Callback.__init__(self)
        self.nz, self.out, self.fn, self.jac, self.f_out = nz, out, fn, jac, f_out
        self.construct(name, {"enable_fd": False})

    def get_n_in(self):
        return 1 if self.f_out is None else 2  # a Jacobian also takes the function's output

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.nz, 1) if i == 0 else ca.Sparsity.dense(*self.f_out)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(*self.out)

    def eval(self, arg):
        return [self.fn(np.array(arg[0]).reshape(-1))]

    def has_jacobian(self):
        return self.jac is not None

    def get_jacobian(self, name, inames, onames, opts):  # inputs: z and f's output; output: d f / d z
        self._jacobian = _Fn(name, self.nz, (self.out[0], self.nz), self.jac, f_out=self.out)
        return self._jacobian


def _callbacks(prob) -> tuple[_Fn, _Fn]:
    def f(z):
        c = prob.cost(z)
        return c if math.isfinite(c) else float("nan")

    return (_Fn("ident_f", prob.nz, (1, 1), f, lambda z: prob.gradient(z).reshape(1, -1)),
            _Fn("ident_gn", prob.nz, (prob.nz, prob.nz), prob.gauss_newton))


class _Progress(ca.Callback):
    """IPOPT's iteration callback: one line per iteration, the best iterate kept, a stop flag honoured."""

    def __init__(self, nz: int, ng: int, report, stop: threading.Event, ftol: float):
        ca.Callback.__init__(self)
        self.nz, self.ng, self.report, self.stop, self.ftol = nz, ng, report, stop, ftol
        self.converged = False
        self.k = 0
        self.best: tuple[float, np.ndarray] | None = None
        self.history: list[float] = []
        self.construct("ident_progress", {})

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
            return ca.Sparsity.dense(1, 1)
        if n in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nz, 1)
        if n in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng, 1)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        f = float(arg[1])
        z = np.array(arg[0]).reshape(-1)
        if math.isfinite(f) and (self.best is None or f < self.best[0]):
            self.best = (f, z.copy())
        self.history.append(f)
        if self.report is not None:
            self.report(self.k, f)
        self.k += 1
        h = self.history
        if len(h) > STALL_ITER and all(math.isfinite(v) for v in h[-STALL_ITER - 1:]):
            self.converged = max(h[-STALL_ITER - 1:]) - min(h[-STALL_ITER - 1:]) <= self.ftol
        return [1 if self.stop.is_set() or self.converged else 0]


def solve(prob, z0, lo, hi, max_iter, tol, progress, stop):
    """One IPOPT solve with the Gauss-Newton Hessian from ``z0``: (z, status, iterations, cost history, the
    dual infeasibility of the last iteration: IPOPT's optimality measure)."""
    z = ca.MX.sym("z", prob.nz)
    fcb, gncb = _callbacks(prob)
    lam_f = ca.MX.sym("lam_f")
    hess = ca.Function("hess_gn", [z, ca.MX(0, 1), lam_f, ca.MX(0, 1)], [lam_f * ca.triu(gncb(z))],
                       ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
    prog = _Progress(prob.nz, 0, progress, stop, tol)
    opts = {"hess_lag": hess, "iteration_callback": prog, "print_time": False, "show_eval_warnings": False,
            "ipopt": {"print_level": 0, "max_iter": int(max_iter), "tol": 1e-8, "sb": "yes",
                      "mu_strategy": "adaptive"}}
    solver = ca.nlpsol("ident", "ipopt", {"x": z, "f": fcb(z)}, opts)
    sol = solver(x0=z0, lbx=lo, ubx=hi)
    zs = np.array(sol["x"]).reshape(-1)
    stats = solver.stats()
    if prog.best is not None and prog.best[0] < prob.cost(zs):
        zs = prog.best[1]
    status = str(stats.get("return_status", "?"))
    if prog.converged:
        status = f"converged (objective changed by less than {tol:g} over {STALL_ITER} iterations)"
    inf_du = stats.get("iterations", {}).get("inf_du") or [math.nan]
    return zs, status, int(stats.get("iter_count", prog.k)), list(prog.history), float(inf_du[-1])

