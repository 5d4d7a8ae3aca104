"""The controller's state estimator: an EKF on ``[eta; nu]`` (docs/model.md §4) and the sensor set it reads
(docs/sensors.md).

The measurement update takes H = I and a diagonal R (the scenario's sensor variances) as 12 sequential
scalar updates, or with a scenario's sensor set only the measured components, each when its sensor has a
fresh reading; the prediction is the constant-velocity transition ``eta+ = eta + h J(eta) nu``, ``nu+ = nu``
with its covariance ``F P F' + Q``. The covariance lives as its upper triangle (:data:`PSYM`), in the
controller's memory from sample to sample (:func:`arvcas.sim.closedloop.controller_memory`).

Here because it reads the scenario (its sensor set and the DOFs a task holds): the closed loop's sample
(:func:`arvcas.sim.closedloop.controller_sample`) calls :func:`measure` and :func:`predict`, and so the
exported controller performs the same operations in the same order.
"""

from __future__ import annotations

import casadi as ca

from arvcas.model.spatial import J
from arvcas.sim import scenario
from arvcas.sim.scenario import ScenarioConfig

__all__ = ["PSYM", "N_PSYM", "measure", "predict", "update", "transition", "sensor_rows", "held_only", "lag_size",
           "delayed"]

PSYM = [(i, j) for i in range(12) for j in range(i, 12)]  # the covariance's upper triangle, row by row
_PSYM_INDEX = {ij: k for k, ij in enumerate(PSYM)}
N_PSYM = len(PSYM)


def _sym_get(Pu, i, j):
    return Pu[_PSYM_INDEX[(i, j) if i <= j else (j, i)]]


def measure(cfg: ScenarioConfig, y, tk, first, xh, Pu, ekf):
    """The measurement update of sample k: ``(xh, the covariance's triangle as a list)`` after ``y``.

    ``y``: ``[eta; nu] + noise`` (12); ``tk``: t_k (s); ``first``: 1 at sample 0, when the filter starts from
    ``y`` (the measured components; 0 for the others) with ``P = R``; ``xh``, ``Pu``: the prior (the
    controller's memory, ``Pu`` the triangle as a column); ``ekf``: ``[q_eta, q_nu, var_position,
    var_attitude, var_velocity]`` or with per-axis sensors ``[q_eta, q_nu, 12 variances]`` (R's diagonal)."""
    if ekf.shape[0] == 14:  # per-axis sensor variances (the scenario's var_eta, var_nu)
        r_meas = ekf[2:14]
    else:
        r_meas = ca.vertcat(ca.repmat(ekf[2], 3, 1), ca.repmat(ekf[3], 3, 1), ca.repmat(ekf[4], 6, 1))
    rows = sensor_rows(cfg, tk)  # None: the whole [eta; nu] at every sample
    y0 = y if rows is None else ca.vertcat(*[y[i] if i in dict(rows) else 0 for i in range(12)])
    xh = ca.if_else(first, y0, xh)
    Pc = [ca.if_else(first, r_meas[i] if i == j else 0, Pu[k]) for k, (i, j) in enumerate(PSYM)]
    return update(xh, Pc, y, r_meas, rows)


def predict(xh, Pu, h, q_eta, q_nu):
    """The prediction for sample k+1: ``(transition(xh), the triangle of F P F' + Q as a column)``."""
    return transition(xh, h), _predict_covariance(xh, Pu, h, q_eta, q_nu)


def update(xh, Pu, y, r, rows=None):
    """EKF measurement update with H = I and diagonal R = diag(r), as 12 sequential scalar updates.

    Exactly the batch update ``K = P (P + R)^-1`` for uncorrelated measurement noise, at a fraction
    of the cost of a 12x12 solve in the graph. ``Pu``: the covariance's upper triangle (a list in
    :data:`PSYM` order); each scalar update ``P - P_i P_i' / s`` is symmetric, so only that triangle is
    computed and P stays symmetric by construction. ``rows``: a sensor set's measured components as
    ``(index, due)`` (``due`` 1 when the sensor has a fresh reading at this sample, else 0: its gain is
    zero; None: every sample), or None for all twelve at every sample (docs/sensors.md).
    Returns (xh, the updated triangle).
    """
    n = xh.shape[0]
    Pu = list(Pu)
    xh = [xh[a] for a in range(n)]
    for i, due in ((i, None) for i in range(n)) if rows is None else rows:
        col = [_sym_get(Pu, a, i) for a in range(n)]  # P[:, i] = P[i, :]
        s = col[i] + r[i]
        K = [c / s for c in col] if due is None else [due * c / s for c in col]
        innov = y[i] - xh[i]
        xh = [xh[a] + K[a] * innov for a in range(n)]
        Pu = [Pu[k] - K[a] * col[b] for k, (a, b) in enumerate(PSYM)]
    return ca.vertcat(*xh), Pu


def sensor_rows(cfg: ScenarioConfig, tk):
    """A sensor set's EKF rows ``(index in [eta; nu], due)`` (:func:`update`): ``due`` is 1 at the samples
    ``k = round(t_k / h)`` that are multiples of the sensor's ``every``, else 0 (``every`` 1: always 1, a
    constant); None when the scenario names no sensor set (the whole [eta; nu] at every sample)."""
    if scenario.sensor_set(cfg) is None:
        return None
    k = ca.floor(tk / cfg.time_h + 0.5)
    return [(i, None if every == 1 else ca.fmod(k, every) == 0) for i, _, every in scenario.measured(cfg)]


def lag_size(cfg: ScenarioConfig) -> int:
    """The rows of the loop state's shift register of lagging readings (:func:`delayed`): ``d`` past values of
    each component of every sensor that lags ``d`` samples; 0 when none lags (no register in the loop state)."""
    return sum(d * len(scenario.SENSORS[n]) for n, d in scenario.latencies(cfg))


def delayed(cfg: ScenarioConfig, x, lag, first: bool):
    """What the sensors report at sample k before noise, and the shift register for sample k+1 (docs/sensors.md).

    ``x``: the true ``[eta; nu]`` at t_k (12); ``lag``: the register (:func:`lag_size` rows): for each lagging
    sensor (:func:`arvcas.sim.scenario.latencies` order) ``d`` blocks of its components, block ``j`` the state of
    sample ``k - 1 - j``. A sensor lagging ``d`` samples reports its components of sample ``k - d``; before the run
    the vehicle was at its initial state, so at sample 0 (``first``) the register is that state. Returns ``(x
    with the lagging components replaced, the register for k+1)``; ``x`` itself and an empty register when no
    sensor lags."""
    out, nxt, o = [x[i] for i in range(12)], [], 0
    for n, d in scenario.latencies(cfg):
        comps = scenario.SENSORS[n]
        m = len(comps)
        blocks = [[x[i] if first else lag[o + j * m + c] for c, i in enumerate(comps)] for j in range(d)]
        for c, i in enumerate(comps):
            out[i] = blocks[d - 1][c]
        nxt += [x[i] for i in comps] + [v for b in blocks[:d - 1] for v in b]
        o += d * m
    if not nxt:
        return x, None
    return ca.vertcat(*out), ca.vertcat(*nxt)


def held_only(cfg: ScenarioConfig, e):
    """``e`` (6, per DOF) with the DOFs the task does not hold set to 0 (docs/sensors.md); ``e`` itself when it
    holds all six."""
    held = scenario.held_dofs(cfg)
    return e if all(held) else ca.vertcat(*[e[d] if held[d] else 0 for d in range(6)])


def transition(xh, h):
    """Kinematic (constant-velocity) transition of docs/model.md §4: eta+ = eta + h J(eta) nu, nu+ = nu."""
    return ca.vertcat(xh[0:6] + h * ca.mtimes(J(xh[0:6]), xh[6:12]), xh[6:12])


def _predict_covariance(xh, Pu, h, q_eta, q_nu):
    """P+ = F P F' + Q with F the AD Jacobian of the transition (docs/model.md §4), Q = diag(q_eta I6, q_nu I6).

    ``Pu``: P's upper triangle (:data:`PSYM` order); returns that of P+ as a column. F is kept sparse
    (its structural zeros and ones are never multiplied: the velocity rows are the identity, the
    pose block is I + h d(J nu)/d eta with only the attitude columns), and only the upper triangle of
    the symmetric F P F' is formed, each entry a sparse row product ``(F P)[a, :] . F[b, :]``.
    """
    xs = ca.SX.sym("xs", 12)
    F = ca.substitute(ca.jacobian(transition(xs, h), xs), xs, xh)
    P = ca.SX(12, 12)
    for a in range(12):
        for b in range(12):
            P[a, b] = _sym_get(Pu, a, b)
    FP = ca.mtimes(F, P)
    q = [q_eta] * 6 + [q_nu] * 6
    out = []
    for a, b in PSYM:
        v = ca.mtimes(FP[a, :], F[b, :].T)
        out.append(v + q[a] if a == b else v)
    return ca.vertcat(*out)
