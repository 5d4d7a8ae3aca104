"""The tuning problem as a vectorised pymoo :class:`~pymoo.core.problem.Problem` (docs/model.md §7).

Decision vector ``x`` (n_var,): ``log10`` of the controller's flat gain vector (Table 2 order,
:func:`arvcas.controllers.gains.gain_names`), within the study's bounds. Each call evaluates the whole
population in one batched call of the compiled run per draw (through an engine).

Objectives ``F = (f_chat, f_rmse)``: :func:`arvcas.metrics.normalised_objectives` of each draw,
averaged over the draws (one draw: exactly that function's value).

One inequality constraint ``G <= 0`` (pymoo's convention):

* ``G = 0`` when every draw ran the whole scenario;
* ``G = 1 + max over draws of (t_end - t_fail) / t_end`` when a draw diverged (non-finite state,
  the error bound of the scenario's ``[limits]`` exceeded): between 1 and 2, larger for an earlier
  failure, so NSGA-II's constraint domination prefers candidates that survive longer;
* ``G = 2`` when a run completed but returned non-finite metrics (not expected; never silent).

A study with other objectives or constraints (docs/objectives.md, :func:`assemble_objectives`): ``F`` has
one column per objective (each draw's value, averaged over the draws), ``G`` the column above and one per
constraint (its largest relative violation over the draws, 0 for a diverged candidate).

An infeasible candidate's objectives are unknown. pymoo needs finite numbers, so it is given the
placeholder :data:`INFEASIBLE_F` for both; it can never win, because NSGA-II ranks any feasible
candidate above every infeasible one and infeasible ones among themselves by ``G``. The stored
objectives (``Evaluation.F``, ``front.h5``) are NaN for them, never the placeholder.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pymoo.core.problem import Problem

from arvcas.metrics import normalised_objectives
from arvcas.sim.scenario import held_dofs

__all__ = ["INFEASIBLE_F", "Evaluation", "GainProblem", "to_gains", "assemble", "assemble_objectives"]

INFEASIBLE_F = 1.0e6  # pymoo's F for infeasible candidates (never stored, never on a front)


def to_gains(X) -> np.ndarray:
    """log10 decision vectors (n, n_var) -> gains (n, n_var), ``10 ** X``."""
    return np.power(10.0, np.asarray(X, dtype=float))


@dataclass(frozen=True)
class Evaluation:
    """One evaluated batch: per draw ``d`` and candidate ``i``.

    ``chat``/``rmse``: (K, n, 6) per-DOF metrics (NaN where that draw diverged); ``ok``/``t_fail``:
    (K, n); ``F``: (n, 2) objectives, NaN for infeasible candidates; ``G``: (n, 1).
    """

    chat: np.ndarray
    rmse: np.ndarray
    ok: np.ndarray
    t_fail: np.ndarray
    F: np.ndarray
    G: np.ndarray
    values: np.ndarray | None = None  # (K, n, m) each draw's objectives (other objectives than the paper's)

    @property
    def feasible(self) -> np.ndarray:
        return (self.G <= 0).all(axis=1)

    @property
    def F_pymoo(self) -> np.ndarray:
        """F with the placeholder in infeasible rows (what NSGA-II sees)."""
        return pymoo_F(self.F, self.G)


def pymoo_F(F: np.ndarray, G: np.ndarray) -> np.ndarray:
    out = np.array(F, dtype=float, copy=True)
    out[G[:, 0] > 0] = INFEASIBLE_F
    return out


def assemble(chat, rmse, ok, t_fail, duration: float, ref=None, held=None) -> Evaluation:
    """Objectives and constraint from per-draw metrics (K, n, 6) and status (K, n); ``ref``: the
    per-DOF normalisation (:func:`arvcas.metrics.normalised_objectives`), None for Table 3's AGSTA; ``held``:
    the DOFs the task holds (:func:`arvcas.sim.scenario.held_dofs`; None: all six)."""
    chat, rmse = np.asarray(chat, dtype=float), np.asarray(rmse, dtype=float)
    ok, t_fail = np.asarray(ok, dtype=bool), np.asarray(t_fail, dtype=float)
    K, n = ok.shape
    F = np.full((n, 2), np.nan)
    G = np.zeros((n, 1))
    for i in range(n):
        if not ok[:, i].all():
            left = [(duration - t_fail[d, i]) / duration for d in range(K) if not ok[d, i]]
            left = [x if np.isfinite(x) else 1.0 for x in left]
            G[i, 0] = 1.0 + min(1.0, max(0.0, max(left)))
            continue
        per_draw = [normalised_objectives(chat[d, i], rmse[d, i], ref, held) for d in range(K)]
        f = per_draw[0] if K == 1 else tuple(float(np.mean([p[j] for p in per_draw])) for j in range(2))
        if not all(np.isfinite(f)):
            G[i, 0] = 2.0
            continue
        F[i] = f
    return Evaluation(chat=chat, rmse=rmse, ok=ok, t_fail=t_fail, F=F, G=G)


def assemble_objectives(outs: list, objectives, constraints, ctx, duration: float) -> Evaluation:
    """Objectives and constraints (docs/objectives.md) from each draw's run outputs (``outs``: K dicts of
    :meth:`arvcas.sim.run.CompiledRun.outputs`, with ``chat`` the study's CHAT); ``objectives``:
    :class:`arvcas.metrics.objectives.Objective` s; ``constraints``: (objective, Constraint) pairs;
    ``ctx``: their :class:`arvcas.metrics.objectives.Context`."""
    from arvcas.metrics import objectives as objectives_mod

    K, n, m = len(outs), len(outs[0]["ok"]), len(objectives)
    ok = np.stack([np.asarray(o["ok"]) > 0.5 for o in outs])
    t_fail = np.stack([np.where(k, np.nan, o["t_fail"]) for k, o in zip(ok, outs)])
    chat = np.stack([np.where(k[:, None], o["chat"], np.nan) for k, o in zip(ok, outs)])
    rmse = np.stack([np.where(k[:, None], o["rmse"], np.nan) for k, o in zip(ok, outs)])
    ev = assemble(chat, rmse, ok, t_fail, duration, ctx.ref,  # G's first column: divergence, as the paper's
                  None if ctx.cfg is None else held_dofs(ctx.cfg))
    G = np.zeros((n, 1 + len(constraints)))
    G[:, 0] = np.where(ev.G[:, 0] == 2.0, 0.0, ev.G[:, 0])
    vals = np.full((K, n, m), np.nan)
    with np.errstate(all="ignore"):
        for d, out in enumerate(outs):
            for j, o in enumerate(objectives):
                vals[d, :, j] = np.where(ok[d], objectives_mod.call_objective(o, "values", out, ctx, n), np.nan)
        F = vals[0].copy() if K == 1 else vals.mean(axis=0)
        for j, (o, c) in enumerate(constraints):
            v = np.stack([c.violation(o, out, ctx) for out in outs]).max(axis=0)
            G[:, 1 + j] = np.where(ok.all(axis=0), v, 0.0)
    alive = ok.all(axis=0)
    bad = alive & ~(np.isfinite(F).all(axis=1) & np.isfinite(G).all(axis=1))
    G[bad] = 0.0
    G[bad, 0] = 2.0
    F[~alive | bad] = np.nan
    return Evaluation(chat=chat, rmse=rmse, ok=ok, t_fail=t_fail, F=F, G=G, values=vals)


class GainProblem(Problem):
    """``x = log10(gains)`` -> ``F = (f_chat, f_rmse)``, ``G`` (see the module docstring).

    ``evaluate_gains(gains (n, n_var)) -> Evaluation`` does the work (an engine bound to the study's
    controller, draws and scenario); the last :class:`Evaluation` is kept in ``last`` so the study
    loop can store the per-DOF metrics with the population.
    """

    def __init__(self, names, log_lower, log_upper, evaluate_gains, n_obj: int = 2, n_constr: int = 1):
        self.names = list(names)
        self.evaluate_gains = evaluate_gains
        self.last: Evaluation | None = None
        super().__init__(n_var=len(self.names), n_obj=n_obj, n_ieq_constr=n_constr,
                         xl=np.asarray(log_lower, dtype=float), xu=np.asarray(log_upper, dtype=float))

    def _evaluate(self, X, out, *args, **kwargs):
        ev = self.evaluate_gains(to_gains(X))
        self.last = ev
        out["F"] = ev.F_pymoo
        out["G"] = ev.G
