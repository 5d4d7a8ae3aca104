"""Validation: a system simulated open loop over a whole logged trial, against what the vehicle did.

For each trial the plant starts from the logged initial state and is driven by the logged inputs
(thrust, or zero thrust for a passive vehicle; the joints on their logged trajectory), over the whole
trial: simulation error, the field's standard, not one-step-ahead prediction. Per measured signal:

* ``rmse``: root mean square of simulated minus measured, on the log's time base (SI: m, rad, m/s, rad/s);
* ``nrmse``: ``rmse`` divided by the measured signal's range (max - min) over the trial;
* ``r2``: ``1 - sum(e^2) / sum((y - mean y)^2)`` (1 is a perfect fit, 0 no better than the mean, negative worse);
* ``max_error``: the largest absolute error.

The joints are prescribed, so their "error" is the smoothing spline's against the raw joint samples
(linearly interpolated onto the time base): it shows what the smoothing removed, not a model error.

The initial velocity is not measured by pose alone: ``nu_0 = J(eta_0)^-1 eta_dot_0`` with ``eta_dot_0``
the slope at t = 0 of a quadratic fitted by least squares to the first :data:`FIT_WINDOW_S` of the pose
(and the logged body velocities or rates where a stream gives them, fitted the same way).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from arvcas.ident import plant as plant_mod
from arvcas.ident.logs import SIGNALS, Log
from arvcas.model.spatial import J

__all__ = ["FIT_WINDOW_S", "TrialResult", "initial_state", "metrics", "validate_log", "substeps"]

FIT_WINDOW_S = 0.5


@dataclass(frozen=True)
class TrialResult:
    """One trial: measured and simulated signals on the log's time base, and the metrics per signal."""

    name: str
    t: np.ndarray
    measured: dict[str, np.ndarray]
    simulated: dict[str, np.ndarray]
    metrics: dict[str, dict[str, float]]  # "rmse" | "nrmse" | "r2" | "max_error" -> signal -> value
    x0: np.ndarray
    h: float  # the plant's RK4 step (s)
    ok: bool  # the simulation stayed finite

    def table(self) -> list[tuple[str, float, float, float, float]]:
        return [(s, self.metrics["rmse"][s], self.metrics["nrmse"][s], self.metrics["r2"][s],
                 self.metrics["max_error"][s]) for s in self.metrics["rmse"]]


def _slope(t: np.ndarray, y: np.ndarray) -> float:
    k = t <= t[0] + FIT_WINDOW_S
    if k.sum() < 3:
        k = slice(0, min(3, len(t)))
    c = np.polyfit(t[k] - t[0], y[k], 2 if np.size(t[k]) >= 3 else 1)
    return float(c[-2])


def _value(t: np.ndarray, y: np.ndarray) -> float:
    k = t <= t[0] + FIT_WINDOW_S
    if k.sum() < 3:
        return float(y[0])
    return float(np.polyval(np.polyfit(t[k] - t[0], y[k], 2), 0.0))


def initial_state(log: Log) -> np.ndarray:
    """x_0 = [eta_0; nu_0] at the log's first sample (docstring of this module); unmeasured pose parts are 0."""
    s = log.signals
    eta = np.array([s[k][0] if k in s else 0.0 for k in SIGNALS[:6]])
    etad = np.array([_slope(log.t, s[k]) if k in s else 0.0 for k in SIGNALS[:6]])
    nu = np.linalg.solve(np.array(J(eta), dtype=float), etad)
    for i, k in enumerate(SIGNALS[6:]):
        if k in s:
            nu[i] = _value(log.t, s[k])
    return np.concatenate([eta, nu])


def metrics(y: np.ndarray, yhat: np.ndarray) -> dict[str, float]:
    e = yhat - y
    rng = float(np.max(y) - np.min(y))
    sst = float(np.sum((y - np.mean(y)) ** 2))
    rmse = float(np.sqrt(np.mean(e ** 2)))
    return {"rmse": rmse, "nrmse": rmse / rng if rng > 0 else math.inf,
            "r2": 1.0 - float(np.sum(e ** 2)) / sst if sst > 0 else -math.inf, "max_error": float(np.max(np.abs(e)))}


def substeps(dt: float, h_max: float) -> int:
    """RK4 steps per log sample so that each is at most ``h_max``."""
    return max(1, int(math.ceil(dt / h_max - 1e-9)))


def compare(log: Log, X: np.ndarray) -> tuple[dict, dict, dict]:
    """(measured, simulated, metrics) of a simulated state trajectory X (N x 12) against ``log``."""
    meas, sim = {}, {}
    for i, k in enumerate(SIGNALS):
        if k in log.signals:
            meas[k], sim[k] = log.signals[k], X[:, i]
    if log.joints is not None:
        for k, (nm, tt, qq) in enumerate(zip(log.joints.names, log.joints.raw_t, log.joints.raw_q)):
            meas[nm], sim[nm] = np.interp(log.t, tt, qq), log.signals[nm]
    out: dict[str, dict[str, float]] = {"rmse": {}, "nrmse": {}, "r2": {}, "max_error": {}}
    for k in meas:
        for name, v in metrics(meas[k], sim[k]).items():
            out[name][k] = v
    return meas, sim, out


def validate_log(system, log: Log, *, h_max: float | None = None, p: np.ndarray | None = None,
                 x0: np.ndarray | None = None) -> TrialResult:
    """Simulate ``system`` open loop over ``log`` from its initial state and compare every measured signal.

    ``h_max``: the largest RK4 step (default the log's sample time: the passive dynamics of a vehicle are
    slow next to it; results/validation measures the difference to a four times finer step)."""
    plant_mod.check_log(log, system)  # every mismatch in one line, before the plant is compiled
    m = substeps(log.dt, log.dt if h_max is None else float(h_max))
    pl = plant_mod.LogPlant(system, m=m)
    x0 = initial_state(log) if x0 is None else np.asarray(x0, dtype=float)
    p = system.params.vector() if p is None else np.asarray(p, dtype=float)
    X = plant_mod.simulate(pl, log, x0, p)
    ok = bool(np.all(np.isfinite(X)))
    if not ok:  # compare up to the first non-finite sample
        bad = int(np.argmax(~np.all(np.isfinite(X), axis=1)))
        X = X.copy()
        X[bad:] = X[bad - 1] if bad > 0 else 0.0
    meas, sim, met = compare(log, X)
    return TrialResult(log.name, log.t, meas, sim, met, x0, log.dt / m, ok)
