"""Validation: a system simulated open loop over a whole logged trial, against what the vehicle did.

For each trial the plant starts from the logged initial state and is driven by the logged inputs
(thrust, or zero thrust for a passive vehicle; the joints on their logged trajectory), over the whole
trial: simulation error, the field's standard, not one-step-ahead prediction. Per measured signal:

* ``rmse``: root mean square of simulated minus measured, on the log's time base (SI: m, rad, m/s, rad/s);
* ``nrmse``: ``rmse`` divided by the measured signal's range (max - min) over the trial;
* ``r2``: ``1 - sum(e^2) / sum((y - mean y)^2)`` (1 is a perfect fit, 0 no better than the mean, negative worse);
* ``max_error``: the largest absolute error;
* ``fit``: FIT % as the MATLAB System Identification Toolbox's ``compare`` reports it,
  ``100 (1 - ||y - y_hat|| / ||y - mean y||)`` (2-norms; 100 a perfect fit, 0 no better than the mean).

Beside the open-loop simulation, the k-step-ahead prediction (:func:`predict`): the trial cut into
segments of ``k`` samples, each simulated from the state taken from the log at its first sample
(:func:`logged_states`), so that sample ``j`` is predicted ``(j - 1) mod k + 1`` samples ahead. With
``k`` at least the trial's length it is the open-loop simulation. The same metrics are computed for it.

Residual tests as the MATLAB toolbox's ``resid`` (:func:`correlations`, :func:`residual_tests`): the
normalised autocorrelation of the simulation's residual ``e = y - y_hat`` (means removed) at lags
1..:data:`RESID_LAGS` and its cross-correlation with each logged input (thrust or command per thruster,
logged wrench, joint positions) at lags -:data:`RESID_LAGS`..:data:`RESID_LAGS`, against the 99 % band
``+-`` :data:`RESID_Z` ``/ sqrt(N)`` of a white residual independent of the input. The fraction of lags
outside the band is reported: about 1 % for a residual the model has explained, far more where the model
leaves structure behind (lag 0 of the autocorrelation is 1 by definition and is not counted).

The joints are prescribed, so their "error" is the smoothing spline's against the raw joint samples
(linearly interpolated onto the time base): it shows what the smoothing removed, not a model error.

The initial velocity is not measured by pose alone: ``nu_0 = J(eta_0)^-1 eta_dot_0`` with ``eta_dot_0``
the slope at t = 0 of a quadratic fitted by least squares to the first :data:`FIT_WINDOW_S` of the pose
(and the logged body velocities or rates where a stream gives them, fitted the same way).

The k-step predictor restarts at later samples from :func:`logged_states`: a pose component the log measures is its logged value, one it does not is the open-loop simulation's; a body
velocity a stream measures is its logged value; the others are the simulation's, corrected by least
squares (the smallest change) so that ``J(eta) nu`` matches the rate of change of the measured pose
components, taken as the slope of a quadratic fitted over :data:`FIT_WINDOW_S` centred on the sample
(Savitzky-Golay, ``scipy.signal.savgol_filter``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from arvcas.ident import plant as plant_mod
from arvcas.ident.logs import SIGNALS, Log
from arvcas.model.spatial import J

__all__ = ["FIT_WINDOW_S", "RESID_LAGS", "RESID_Z", "TrialResult", "initial_state", "metrics", "fit_percent",
           "validate_log", "substeps", "logged_states", "predict", "correlations", "residual_tests", "drive_inputs"]

FIT_WINDOW_S = 0.5
RESID_LAGS = 25  # lags of the residual tests (MATLAB resid's default)
RESID_Z = 2.58  # the two-sided 99 % point of the standard normal: resid's default band


@dataclass(frozen=True)
class TrialResult:
    """One trial: measured and simulated signals on the log's time base, and the metrics per signal."""

    name: str
    t: np.ndarray
    measured: dict[str, np.ndarray]
    simulated: dict[str, np.ndarray]
    metrics: dict[str, dict[str, float]]  # "rmse" | "nrmse" | "r2" | "max_error" | "fit" -> signal -> value
    x0: np.ndarray
    h: float  # the plant's RK4 step (s)
    ok: bool  # the simulation stayed finite
    k: int | None = None  # the k-step-ahead predictor's k (samples), None: not computed
    predicted: dict[str, np.ndarray] = field(default_factory=dict)  # the k-step-ahead prediction per vehicle signal
    kstep: dict[str, dict[str, float]] = field(default_factory=dict)  # its metrics, as ``metrics``
    resid: dict[str, dict] = field(default_factory=dict)  # signal -> residual_tests' entry

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


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """FIT % of the MATLAB System Identification Toolbox: ``100 (1 - ||y - yhat|| / ||y - mean(y)||)``, 2-norms."""
    y, yhat = np.asarray(y, dtype=float), np.asarray(yhat, dtype=float)
    d = float(np.linalg.norm(y - np.mean(y)))
    return 100.0 * (1.0 - float(np.linalg.norm(y - yhat)) / d) if d > 0 else -math.inf


def metrics(y: np.ndarray, yhat: np.ndarray) -> dict[str, float]:
    e = yhat - y
    rng = float(np.max(y) - np.min(y))
    sst = float(np.sum((y - np.mean(y)) ** 2))
    rmse = float(np.sqrt(np.mean(e ** 2)))
    return {"rmse": rmse, "nrmse": rmse / rng if rng > 0 else math.inf,
            "r2": 1.0 - float(np.sum(e ** 2)) / sst if sst > 0 else -math.inf, "max_error": float(np.max(np.abs(e))),
            "fit": fit_percent(y, yhat)}


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
    return meas, sim, _table(meas, sim)


def _table(meas: dict, sim: dict) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {"rmse": {}, "nrmse": {}, "r2": {}, "max_error": {}, "fit": {}}
    for k in meas:
        for name, v in metrics(meas[k], sim[k]).items():
            out[name][k] = v
    return out


# ---- k-step-ahead prediction --------------------------------------------------------------------------


_J: dict = {}


def _J_many(eta: np.ndarray) -> np.ndarray:
    """J(eta) (N x 6 x 6) of :func:`arvcas.model.spatial.J` at every row of ``eta`` (N x 6)."""
    import casadi as ca

    f = _J.get("J")
    if f is None:
        e = ca.SX.sym("eta", 6)
        f = _J["J"] = ca.Function("J", [e], [ca.vec(J(e))])
    out = np.array(f.map(eta.shape[0])(eta.T))  # 36 x N, column-major 6 x 6 per sample
    return out.T.reshape(-1, 6, 6).transpose(0, 2, 1)


def _slopes(log: Log, y: np.ndarray) -> np.ndarray:
    """d y / d t at every sample: the slope of a quadratic fitted over :data:`FIT_WINDOW_S` centred on it."""
    from scipy.signal import savgol_filter

    n = len(y)
    w = max(3, int(round(FIT_WINDOW_S / log.dt)) // 2 * 2 + 1)
    w = min(w, n if n % 2 else n - 1)
    if w < 3:
        return np.gradient(y, log.dt)
    return savgol_filter(y, w, 2, deriv=1, delta=log.dt, mode="interp")


def logged_states(log: Log, X_sim: np.ndarray) -> np.ndarray:
    """The state (N x 12) at every sample as far as the log gives it (the module's docstring): the measured
    pose and body velocities from the log, the rest from ``X_sim`` (the open-loop simulation), its velocities
    corrected by least squares so that ``J(eta) nu`` matches the measured pose components' rates of change."""
    s = log.signals
    X = np.array(X_sim, dtype=float, copy=True)
    pose = [i for i, k in enumerate(SIGNALS[:6]) if k in s]
    vel = [i for i, k in enumerate(SIGNALS[6:]) if k in s]
    for i in pose:
        X[:, i] = s[SIGNALS[i]]
    for i in vel:
        X[:, 6 + i] = s[SIGNALS[6 + i]]
    free = [i for i in range(6) if i not in vel]
    if pose and free:
        Jm = _J_many(X[:, :6])[:, pose, :]  # N x r x 6
        rates = np.stack([_slopes(log, s[SIGNALS[i]]) for i in pose], axis=1)  # N x r
        b = rates - np.einsum("nij,nj->ni", Jm, X[:, 6:])
        A = Jm[:, :, free]
        X[:, [6 + i for i in free]] += np.einsum("nij,nj->ni", np.linalg.pinv(A), b)
    return X


def predict(plant, log: Log, p: np.ndarray, k: int, states: np.ndarray, data: dict | None = None) -> np.ndarray:
    """The k-step-ahead prediction (N x 12) on the log's time base.

    The trial is cut into segments of ``k`` samples starting at samples 0, k, 2k, ...; each is simulated
    from ``states`` at its first sample (``states`` N x 12: the state to restart from at every sample, e.g.
    :func:`logged_states`, row 0 the trial's initial state), so sample ``j >= 1`` is predicted
    ``(j - 1) mod k + 1`` samples ahead; row 0 is ``states[0]``. All segments advance together, one sample
    per call of the plant's compiled one-sample block (:meth:`arvcas.ident.plant.LogPlant.block_fn`)
    mapped over the segments. The same inputs as the open-loop simulation (``data``:
    :func:`arvcas.ident.plant.sample_inputs`), so ``k >= N - 1`` gives :func:`arvcas.ident.plant.simulate`'s
    trajectory up to rounding."""
    from arvcas.build import calls

    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"k: the prediction horizon must be a positive number of samples, got {k!r}")
    N = len(log.t)
    states = np.asarray(states, dtype=float)
    if states.shape != (N, 12):
        raise ValueError(f"states: expected {N} x 12 (one state per sample of {log.name}), got {states.shape}")
    m = plant.m
    d = data if data is not None else plant_mod.sample_inputs(log, plant.system, m)
    starts = np.arange(0, N - 1, int(k))
    f = _mapped(plant.block_fn(1), len(starts))
    pv = np.asarray(p, dtype=float).reshape(-1, 1)
    X = np.empty((N, 12))
    X[0] = states[0]
    x = np.asfortranarray(states[starts].T)
    sub, sub3 = np.arange(m), np.arange(3 * m)
    for j in range(min(int(k), N - 1)):
        idx = starts + j
        i = np.minimum(idx, N - 2)  # a segment past the trial's end repeats its last sample; dropped below
        steps = (i[:, None] * m + sub).ravel()  # every RK4 step of sample i, segment after segment
        st3 = (i[:, None] * 3 * m + sub3).ravel()
        Xb = calls.call(f, x, d["U"][:, st3], d["W"][:, steps], d["Q"][:, st3], d["QD"][:, st3], d["QDD"][:, st3],
                        d["payload"][:, steps], d["h"], np.zeros((0, 1)), pv)[0]  # 12 x (m per segment)
        x = np.asfortranarray(Xb.reshape(12, len(starts), m)[:, :, -1])
        act = idx < N - 1
        X[idx[act] + 1] = x[:, act].T
    return X


_MAPPED: dict = {}


def _mapped(f, n: int):
    """``f`` mapped over ``n`` segments (CasADi ``map``: one call evaluates the compiled block n times)."""
    key = (f.__hash__(), n)
    hit = _MAPPED.get(key)
    if hit is None or hit[0] is not f:
        if len(_MAPPED) > 32:
            _MAPPED.clear()
        hit = _MAPPED[key] = (f, f.map(f"{f.name()}_segments", "serial", n, [7, 8, 9], []))  # h, theta, p shared
    return hit[1]


# ---- residual tests -------------------------------------------------------------------------------------


def correlations(e: np.ndarray, u: np.ndarray | None = None, lags: int = RESID_LAGS) -> np.ndarray:
    """Normalised sample correlations, means removed (MATLAB ``resid``).

    Without ``u``: the autocorrelation ``r_e(tau) = sum_t e(t + tau) e(t) / sum_t e(t)^2`` at tau = 0..lags.
    With ``u``: the cross-correlation ``r_eu(tau) = sum_t e(t + tau) u(t) / sqrt(sum e^2 sum u^2)`` at
    tau = -lags..lags (tau > 0: the input leads the residual). NaN where a signal is constant."""
    e = np.asarray(e, dtype=float) - np.mean(e)
    N = len(e)
    L = min(int(lags), N - 1)
    if u is None:
        den = float(e @ e)
        r = np.array([e[t:] @ e[:N - t] for t in range(L + 1)])
        return r / den if den > 0 else np.full(L + 1, np.nan)
    u = np.asarray(u, dtype=float) - np.mean(u)
    den = math.sqrt(float(e @ e) * float(u @ u))
    r = np.array([e[t:] @ u[:N - t] if t >= 0 else e[:N + t] @ u[-t:] for t in range(-L, L + 1)])
    return r / den if den > 0 else np.full(2 * L + 1, np.nan)


def drive_inputs(log: Log) -> dict[str, np.ndarray]:
    """The logged inputs that drive the plant, each (N,) on the log's time base, constant ones left out:
    ``thrust.<thruster>`` or ``command.<thruster>``, ``wrench.<X|Y|Z|K|M|N>``, the joint positions by name."""
    out = {f"thrust.{n}": v for n, v in log.thrust.items()}
    out.update({f"command.{n}": v for n, v in log.command.items()})
    if log.wrench is not None:
        out.update({f"wrench.{c}": log.wrench[:, i] for i, c in enumerate("XYZKMN")})
    if log.joints is not None:
        out.update({n: log.signals[n] for n in log.joints.names})
    return {n: np.asarray(v, dtype=float) for n, v in out.items() if np.ptp(v) > 0}


def residual_tests(residuals: dict[str, np.ndarray], inputs: dict[str, np.ndarray],
                   lags: int = RESID_LAGS) -> dict[str, dict]:
    """Per signal: ``band`` (RESID_Z / sqrt(N)), ``auto_outside`` (the fraction of lags 1..lags whose
    autocorrelation is outside the band), ``auto_max`` (the largest |r_e| there), and per input
    ``cross_outside`` (the fraction of lags -lags..lags outside) and ``cross_max``; None where the
    residual is constant (nothing to test)."""
    out: dict[str, dict] = {}
    for s, e in residuals.items():
        if not np.ptp(e) > 0:
            out[s] = None
            continue
        band = RESID_Z / math.sqrt(len(e))
        ra = np.abs(correlations(e, None, lags)[1:])
        ent = {"band": band, "auto_outside": float(np.mean(ra > band)), "auto_max": float(np.max(ra)),
               "cross_outside": {}, "cross_max": {}}
        for n, u in inputs.items():
            rc = np.abs(correlations(e, u, lags))
            ent["cross_outside"][n] = float(np.mean(rc > band))
            ent["cross_max"][n] = float(np.max(rc))
        out[s] = ent
    return out


def validate_log(system, log: Log, *, h_max: float | None = None, p: np.ndarray | None = None,
                 x0: np.ndarray | None = None, k: int | None = None) -> TrialResult:
    """Simulate ``system`` open loop over ``log`` from its initial state and compare every measured signal.

    ``h_max``: the largest RK4 step (default the log's sample time: the passive dynamics of a vehicle are
    slow next to it; results/validation measures the difference to a four times finer step). ``k``: also
    the k-step-ahead prediction (:func:`predict`, from :func:`logged_states`) and its metrics. The residual
    tests (:func:`residual_tests`) are of the open-loop simulation's residual."""
    plant_mod.check_log(log, system)  # every mismatch in one line, before the plant is compiled
    m = substeps(log.dt, log.dt if h_max is None else float(h_max))
    pl = plant_mod.LogPlant(system, m=m)
    x0 = initial_state(log) if x0 is None else np.asarray(x0, dtype=float)
    p = system.params.vector() if p is None else np.asarray(p, dtype=float)
    data = plant_mod.sample_inputs(log, system, m)
    X = plant_mod.simulate(pl, log, x0, p, data=data)
    ok = bool(np.all(np.isfinite(X)))
    if not ok:  # compare up to the first non-finite sample
        X = _held(X)
    meas, sim, met = compare(log, X)
    vehicle = [s for s in SIGNALS if s in log.signals]
    resid = residual_tests({s: meas[s] - sim[s] for s in vehicle}, drive_inputs(log))
    predicted, kmet = {}, {}
    if k is not None:
        states = logged_states(log, X)
        states[0] = x0
        Xk = predict(pl, log, p, k, states, data)
        if not np.all(np.isfinite(Xk)):
            ok = False
            Xk = _held(Xk)
        predicted = {s: Xk[:, SIGNALS.index(s)] for s in vehicle}
        kmet = _table({s: meas[s] for s in vehicle}, predicted)
    return TrialResult(log.name, log.t, meas, sim, met, x0, log.dt / m, ok, k, predicted, kmet, resid)


def _held(X: np.ndarray) -> np.ndarray:
    """``X`` with every row from the first non-finite one on replaced by the last finite row (or zeros)."""
    bad = int(np.argmax(~np.all(np.isfinite(X), axis=1)))
    X = X.copy()
    X[bad:] = X[bad - 1] if bad > 0 else 0.0
    return X
