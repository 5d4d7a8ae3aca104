"""Grey-box identification: named parameters of a system file estimated from logged trials.

The estimator minimises the simulation error of every trial at once (docs/identification.md):

    min over theta, x_0^(1..T)   sum_signals  [ 1/2 SSE_k / sigma_k^2   or   N_k / 2 log(SSE_k / N_k) ]

    SSE_k = sum over the trials' samples of (y_hat_k(theta, x_0) - y_k)^2

* ``theta``: the free parameters (any entries of the system's parameter vector, by name), scaled by their
  starting values; ``x_0^(j)``: each trial's initial state (12), free too, started from the log
  (:func:`arvcas.ident.validate.initial_state`);
* ``y_hat``: the same compiled plant as validation (:mod:`arvcas.ident.plant`), open loop over the whole
  trial, its Jacobian with respect to ``[x_0; theta]`` by forward sensitivities of the same CasADi graph;
* ``sigma``: each signal's noise, stated by the log mapping (``std``); for a signal whose noise no log
  states, the term is the maximum-likelihood one of an unknown noise level, ``N_k / 2 log(SSE_k / N_k)``,
  whose gradient weights the signal by its own mean square error (so a signal the model cannot follow,
  e.g. a drift, does not swamp the others);
* solved by IPOPT (CasADi's ``nlpsol``) with the Gauss-Newton Hessian ``J' W J``, the free parameters
  mapped so that every iterate is physical (:mod:`arvcas.ident.physical`: a rigid body through its
  pseudo-inertia's Cholesky factor, added mass and damping through their own, the rest by sign bounds and
  a hold inside the loader's rules), stopped when the objective changes by less than ``tol`` (default 0.1)
  over :data:`arvcas.ident.solver.STALL_ITER` iterations: the objective is a negative log-likelihood, and a change of 0.5
  moves the estimate by about one standard error, so 0.1 is well inside the intervals (a tail of slow
  creeping, 1e-5 of the objective in 20 iterations on the Hinsdale trials, is cut); every trial is
  simulated on its own thread.

At the optimum the Gauss-Newton information ``F = J' W J`` (trials' initial states eliminated by the Schur
complement) gives the covariance ``s^2 F^-1`` with ``s^2`` the weighted residual sum over its degrees of
freedom: with stated noise levels, intervals widen when the model cannot follow the data; with estimated
ones, the weights are the errors themselves (s^2 = 1 + nz / dof). The residuals are treated as independent
from sample to sample: where the model error is coloured (a real vehicle), the intervals are too narrow,
and the report says so. Directions of ``F`` whose eigenvalue
is below :data:`RANK_TOL` of the largest (in parameters scaled by their values) are reported as
unidentifiable, with the parameters that make them, and no interval is printed for those parameters;
pairs correlated beyond :data:`arvcas.ident.estimate.CORR_WARN` are named.

``cost="prediction", horizon=K`` minimises the K-step-ahead prediction error instead of the simulation error:
each trial cut into segments of K samples, each simulated from the state the log gives at its first sample
(:func:`arvcas.ident.validate.logged_states`, the unmeasured parts from the open-loop simulation at the
starting parameters, all held fixed), so that an error the model cannot follow grows over K samples only;
the initial states are then not free. :func:`jackknife` adds leave-one-trial-out intervals (one refit per
trial), which carry the trial-to-trial spread and the errors correlated within a trial that the Fisher
intervals do not (docs/identification.md).
"""

from __future__ import annotations

import math
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from arvcas.ident import physical
from arvcas.ident import plant as plant_mod
from arvcas.ident.estimate import CORR_WARN, Estimate, IdentifyError
from arvcas.ident.logs import SIGNALS, Log
from arvcas.ident.physical import bounds
from arvcas.ident.solver import solve
from arvcas.ident.validate import initial_state, logged_states, substeps

__all__ = ["IdentifyError", "Estimate", "identify", "jackknife", "check_cost", "COSTS", "Problem", "RANK_TOL"]

RANK_TOL = 1e-8
MAX_FREE = 64
COSTS = ("simulation", "prediction")  # the costs identify can minimise (docs/identification.md)
MAX_HORIZON = 100_000
REFIT_TOL = 1e-4  # the leave-one-trial-out refits' stop (objective change over STALL_ITER iterations)


def check_cost(cost: str, horizon) -> int | None:
    """The prediction horizon (samples) for ``cost``, or None for the simulation error; one line for a bad pair."""
    if cost not in COSTS:
        raise IdentifyError(f"cost: expected one of {', '.join(COSTS)}, got {cost!r}")
    if cost == "simulation":
        if horizon is not None:
            raise IdentifyError("horizon: only the prediction cost has a horizon (--cost prediction --horizon K)")
        return None
    if horizon is None:
        raise IdentifyError("horizon: the prediction cost needs its horizon in samples (--horizon K, e.g. 25)")
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or not 1 <= horizon <= MAX_HORIZON:
        raise IdentifyError(f"horizon: expected a whole number of samples in [1, {MAX_HORIZON}], got {horizon!r}")
    return int(horizon)

class Problem:
    """The objective over every trial (module docstring), its gradient and Gauss-Newton Hessian, memoised by z.

    Residuals are unweighted (simulated - measured, SI); signal k's weight is 1 / sigma_k^2 for a stated noise
    level, and N_k / SSE_k (its own mean square error) for an unstated one, whose term of the objective is
    the maximum-likelihood ``N_k / 2 log(SSE_k / N_k)``: its gradient is the weighted least-squares one.
    """

    def __init__(self, system, logs, free, signals, stated, m, K, threads, mapping=None, horizon=None):
        self.system, self.logs, self.free, self.K = system, logs, tuple(free), K
        self.horizon = horizon  # None: simulation error; else the k-step-ahead prediction error's k (samples)
        self.nx = 12 if horizon is None else 0  # free initial state per trial (simulation error only)
        self.r0 = 0 if horizon is None else 1  # the first residual row (a prediction restarts at sample 0)
        self.plant = plant_mod.LogPlant(system, m=m, free=self.free)
        lay = system.layout
        self.p = system.params.vector()
        self.idx = np.array([lay.index[n] for n in self.free], dtype=int)
        self.map = mapping if mapping is not None else physical.Mapping(lay, self.free, self.p)
        self.theta0 = self.map.theta0
        self.scale = self.map.scale
        self.nonfinite = 0  # evaluations whose simulation was not finite (counted, not printed)
        self.nt = len(self.free)
        self.data = [plant_mod.sample_inputs(lg, system, m) for lg in logs]
        self.m = m
        # free parameters that move a commanded log's thrust: its inputs and d u / d theta follow theta
        self.thrust_idx = [k for k, n in enumerate(self.free) if n in self.plant.thrust_free]
        self.signals = tuple(signals)
        self.stated = dict(stated)
        self.sel = []  # per log: (state indices, measured (N x k))
        ids = []
        for lg in logs:
            sig = [s for s in signals if s in lg.signals]
            self.sel.append((np.array([SIGNALS.index(s) for s in sig], dtype=int),
                             np.stack([lg.signals[s] for s in sig], axis=1)[self.r0:]))
            ids.append(np.tile([self.signals.index(s) for s in sig], len(lg.t) - self.r0))
        self.sig_id = np.concatenate(ids)  # the fitted signal of each residual
        self.n_sig = np.bincount(self.sig_id, minlength=len(self.signals))
        self.nz = self.nt + self.nx * len(logs)
        self.states = None  # prediction error: per trial, the state each segment restarts from (N x 12)
        if horizon is not None:
            p0 = self.p.copy()
            self.states = []
            for lg, d in zip(logs, self.data):
                x0 = initial_state(lg)
                X = plant_mod.simulate(self.plant, lg, x0, p0, K, d)
                st = logged_states(lg, X)
                if not np.all(np.isfinite(st)):
                    raise IdentifyError(f"{lg.name}: the simulation from the starting parameters is not finite, so "
                                        f"the unmeasured parts of the state to restart from are unknown")
                self.states.append(st)
        self.n_res = self.sig_id.size
        self.pool = ThreadPoolExecutor(max(1, threads)) if threads > 1 and len(logs) > 1 else None
        self._last: tuple | None = None
        self._lock = threading.Lock()

    def theta(self, z: np.ndarray) -> np.ndarray:
        return self.map.theta(z[: self.nt])

    def in_v(self, z: np.ndarray, Jm: np.ndarray) -> np.ndarray:
        """The Jacobian with respect to the optimiser's variables: theta's columns (scaled by ``scale``) through
        d theta / d v."""
        out = Jm.copy()
        out[:, : self.nt] = Jm[:, : self.nt] @ (self.map.jacobian(z[: self.nt]) / self.scale[:, None])
        return out

    def x0(self, z: np.ndarray, j: int) -> np.ndarray:
        if self.states is not None:
            return self.states[j][0]
        return z[self.nt + 12 * j: self.nt + 12 * (j + 1)]

    def _segments(self, j: int, d: dict, pv: np.ndarray, th: np.ndarray, sens: bool):
        """The k-step-ahead prediction of trial ``j`` (rows 1..N-1) and its Jacobian in theta: the trial cut into
        segments of ``horizon`` samples, each simulated from :attr:`states` at its first sample."""
        st, H, m = self.states[j], self.horizon, self.m
        N = st.shape[0]
        nf = self.nt
        X = np.empty((N - 1, 12))
        dX = np.empty((N - 1, 12, nf)) if sens else None
        for a in range(0, N - 1, H):
            e = min(a + H, N - 1)
            ds = _slice(d, a, e, m, nf)
            if sens:
                Xs, dXs = plant_mod.simulate_sens(self.plant, None, st[a], pv, th, self.K, ds)
                dX[a:e] = dXs[1:, :, 12:]
            else:
                Xs = plant_mod.simulate(self.plant, None, st[a], pv, self.K, ds)
            X[a:e] = Xs[1:]
        return X, dX

    def _one(self, j: int, z: np.ndarray, sens: bool):
        lg, d = self.logs[j], self.data[j]
        idx, Y = self.sel[j]
        th = self.theta(z)
        pv = self.p.copy()
        pv[self.idx] = th
        if self.thrust_idx and lg.command:
            d = dict(plant_mod.sample_inputs(lg, self.system, self.m, p=pv))
            if sens:
                tf = tuple(self.free[k] for k in self.thrust_idx)
                part = plant_mod.rotor_thrust_sens(lg, self.system, self.m, pv, tf)  # (3 nt) x (len(tf) steps)
                n_st = part.shape[1] // len(tf)
                full = np.zeros((part.shape[0], len(self.free), n_st))
                full[:, self.thrust_idx, :] = part.reshape(part.shape[0], len(tf), n_st, order="F")
                d["dU"] = full.reshape(part.shape[0], len(self.free) * n_st, order="F")
        if self.states is not None:
            X, dX = self._segments(j, d, pv, th, sens)
            r = (X[:, idx] - Y).reshape(-1)
            if dX is None:
                return r, None
            return r, (None, dX[:, idx, :].reshape(-1, self.nt) * self.scale[None, :])
        if sens:
            X, dX = plant_mod.simulate_sens(self.plant, lg, self.x0(z, j), pv, th, self.K, d)
        else:
            X, dX = plant_mod.simulate(self.plant, lg, self.x0(z, j), pv, self.K, d), None
        r = (X[:, idx] - Y).reshape(-1)
        if dX is None:
            return r, None
        Jr = dX[:, idx, :].reshape(-1, 12 + self.nt)
        return r, (Jr[:, :12], Jr[:, 12:] * self.scale[None, :])

    def evaluate(self, z: np.ndarray, sens: bool):
        """(r, J): unweighted residuals and, if ``sens``, their Jacobian (n_res x nz); memoised on the last z."""
        z = np.asarray(z, dtype=float).reshape(-1)
        with self._lock:
            last = self._last
            if last is not None and np.array_equal(last[0], z) and (last[2] is not None or not sens):
                return last[1], last[2]
        jobs = range(len(self.logs))
        res = list(self.pool.map(lambda j: self._one(j, z, sens), jobs)) if self.pool else \
            [self._one(j, z, sens) for j in jobs]
        r = np.concatenate([a for a, _ in res])
        Jm = None
        if sens:
            Jm = np.zeros((self.n_res, self.nz))
            row = 0
            for j, (a, (Jx, Jt)) in enumerate(res):
                Jm[row:row + a.size, : self.nt] = Jt
                if Jx is not None:
                    Jm[row:row + a.size, self.nt + 12 * j: self.nt + 12 * (j + 1)] = Jx
                row += a.size
        with self._lock:
            self._last = (z.copy(), r, Jm)
        return r, Jm

    def sse(self, r: np.ndarray) -> np.ndarray:
        return np.bincount(self.sig_id, weights=r * r, minlength=len(self.signals))

    def weights(self, r: np.ndarray) -> np.ndarray:
        """1 / sigma_k^2 per signal: stated, or N_k / SSE_k."""
        sse = self.sse(r)
        return np.array([1.0 / self.stated[s] ** 2 if s in self.stated else self.n_sig[k] / max(sse[k], 1e-300)
                         for k, s in enumerate(self.signals)])

    def cost(self, z) -> float:
        r, _ = self.evaluate(z, False)
        if not np.all(np.isfinite(r)):
            self.nonfinite += 1
            return math.inf
        sse = self.sse(r)
        c = 0.0
        for k, s in enumerate(self.signals):
            if s in self.stated:
                c += 0.5 * sse[k] / self.stated[s] ** 2
            else:
                c += 0.5 * self.n_sig[k] * math.log(max(sse[k], 1e-300) / self.n_sig[k])
        return c

    def gradient(self, z) -> np.ndarray:
        r, Jm = self.evaluate(z, True)
        w = self.weights(r)[self.sig_id]
        return self.in_v(z, Jm).T @ (w * r)

    def gauss_newton(self, z) -> np.ndarray:
        r, Jm = self.evaluate(z, True)
        w = self.weights(r)[self.sig_id]
        Jv = self.in_v(z, Jm)
        return Jv.T @ (Jv * w[:, None])

    def rms(self, z) -> dict[str, float]:
        """The RMS error of each fitted signal over every trial at ``z`` (SI)."""
        r, _ = self.evaluate(z, False)
        sse = self.sse(r)
        return {s: math.sqrt(sse[k] / self.n_sig[k]) for k, s in enumerate(self.signals)}



def _slice(d: dict, a: int, e: int, m: int, nf: int) -> dict:
    """The block inputs (:func:`arvcas.ident.plant.sample_inputs`) of samples ``a..e`` (steps a m .. e m)."""
    out = dict(d)
    for k in ("W", "payload"):
        out[k] = d[k][:, a * m: e * m]
    for k in ("U", "Q", "QD", "QDD"):
        out[k] = d[k][:, 3 * a * m: 3 * e * m]
    if "dU" in d:
        out["dU"] = d["dU"][:, a * m * nf: e * m * nf]
    return out


def _fisher(Jm: np.ndarray, nt: int) -> np.ndarray:
    """The information about theta (scaled) with the initial states eliminated: F_tt - F_tx F_xx^+ F_xt."""
    F = Jm.T @ Jm
    if F.shape[0] == nt:
        return F
    Ftt, Ftx, Fxx = F[:nt, :nt], F[:nt, nt:], F[nt:, nt:]
    return Ftt - Ftx @ np.linalg.pinv(Fxx, rcond=1e-12, hermitian=True) @ Ftx.T


def _directions(F: np.ndarray, names: tuple[str, ...]) -> tuple[np.ndarray, list[str]]:
    """(identifiable per parameter, one line per unidentifiable direction) from the scaled information."""
    d = np.sqrt(np.clip(np.diag(F), 0, None))
    ok = d > 0
    lines = []
    ident = np.ones(len(names), dtype=bool)
    for i in np.flatnonzero(~ok):
        ident[i] = False
        lines.append(f"{names[i]}: the trials carry no information about it (its sensitivity is zero)")
    if ok.sum():
        sub = np.ix_(ok, ok)
        Fn = F[sub] / np.outer(d[ok], d[ok])  # correlation form: scale-free
        w, V = np.linalg.eigh(Fn)
        idx = np.flatnonzero(ok)
        for k in np.flatnonzero(w < RANK_TOL * max(w[-1], 1e-300)):
            v = V[:, k]
            big = np.argsort(-np.abs(v))
            part = [i for i in big if abs(v[i]) >= 0.2 * np.abs(v).max()]
            for i in part:
                ident[idx[i]] = False
            combo = " ".join(f"{v[i] / np.abs(v).max():+.2f} {names[idx[i]]}" for i in part)
            lines.append(f"{combo}: eigenvalue {w[k]:.2g} of the scaled information (largest {w[-1]:.3g}): the "
                         f"data fix only the other combinations")
    return ident, lines


def identify(system, logs: list[Log], free, *, signals=None, sigma: dict | None = None, h_max: float | None = None,
             max_iter: int = 100, tol: float = 0.1, threads: int = 2, K: int = 50,
             progress=None, physical_set: bool = True, cost: str = "simulation",
             horizon: int | None = None) -> Estimate:
    """Estimate the parameters ``free`` (names of ``system.params``) from ``logs`` (module docstring).

    ``signals``: the measured signals fitted (default every vehicle signal the logs measure, of
    :data:`arvcas.ident.logs.SIGNALS`); ``sigma``: noise per signal (SI), else the logs' stated ``std``,
    else estimated (module docstring); ``h_max``: the largest plant step (default the logs' sample time);
    ``progress(k, cost)``: called every IPOPT iteration. SIGINT (Ctrl-C) stops after the current
    iteration and returns the best iterate (status "interrupted"); SIGTERM and SIGHUP stop it and raise
    :class:`arvcas.util.files.Terminated` (nothing is returned, so nothing unfinished is written).
    ``physical_set``: the physical parameterisations and the hold inside the loader's rules
    (:mod:`arvcas.ident.physical`); False leaves each parameter only its sign bounds (to see where the
    unconstrained optimum lies). ``cost``: ``"simulation"`` (open loop over each trial, its initial state
    free) or ``"prediction"`` (the ``horizon``-step-ahead prediction error: :data:`COSTS`).
    """
    t_start = time.perf_counter()
    lay = system.layout
    free = tuple(free)
    horizon = check_cost(cost, horizon)
    kind = cost
    if not free:
        raise IdentifyError("free: name at least one parameter to identify")
    if len(free) > MAX_FREE:
        raise IdentifyError(f"free: at most {MAX_FREE} parameters, got {len(free)}")
    for n in free:
        if n not in lay.index:
            from arvcas.system.config import closest

            raise IdentifyError(f"free: {system.name} has no parameter {n!r}{closest(n, lay.names)}")
    dup = [n for n in free if free.count(n) > 1]
    if dup:
        raise IdentifyError(f"free: {dup[0]} is named twice")
    unit = [n for n in free if ".direction." in n or (n.startswith("arm.joint") and ".axis." in n)]
    if unit:
        raise IdentifyError(f"free: {unit[0]} is an element of a unit vector, which no single value can move and "
                            f"keep of length 1: hold it (give the measured direction in the system file)")
    if not logs:
        raise IdentifyError("logs: give at least one trial")
    for lg in logs:  # joints, thrusters and commands against the system, before any compile
        plant_mod.check_log(lg, system)
    measured = [s for s in SIGNALS if any(s in lg.signals for lg in logs)]
    signals = tuple(measured if signals is None else signals)
    for s in signals:
        if s not in SIGNALS:
            raise IdentifyError(f"signals: {s!r} is not a model signal (allowed: {', '.join(SIGNALS)})")
        if s not in measured:
            raise IdentifyError(f"signals: no trial measures {s!r} (measured: {', '.join(measured)})")
    if not signals:
        raise IdentifyError("signals: the trials measure none of the model's signals")
    dts = {round(lg.dt, 12) for lg in logs}
    if len(dts) > 1:
        raise IdentifyError(f"logs: the trials have different sample times {sorted(dts)} s: give them one [log] rate")
    stated: dict[str, float] = {}
    for s in signals:
        if sigma and s in sigma:
            stated[s] = float(sigma[s])
        else:
            given = [lg.std[s] for lg in logs if s in lg.std]
            if given:
                stated[s] = float(np.mean(given))
    for s, v in stated.items():
        if not (math.isfinite(v) and v > 0):
            raise IdentifyError(f"sigma: {s}: expected a positive noise level, got {v!r}")
    m = substeps(logs[0].dt, logs[0].dt if h_max is None else float(h_max))
    if horizon is not None and horizon >= max(len(lg.t) for lg in logs) - 1:
        raise IdentifyError(f"horizon: {horizon} samples is as long as the longest trial "
                            f"({max(len(lg.t) for lg in logs) - 1} steps): that is the simulation error, "
                            f"--cost simulation")
    mapping = physical.Mapping(lay, free, system.params.vector(), factors=physical_set)
    prob = Problem(system, logs, free, signals, stated, m, K, threads, mapping, horizon)
    z0 = np.concatenate([np.zeros(len(free))] + ([initial_state(lg) for lg in logs] if prob.nx else []))
    rms0 = prob.rms(z0)
    if not all(math.isfinite(v) for v in rms0.values()):
        raise IdentifyError(f"the simulation from the starting parameters is not finite on some trial "
                            f"({', '.join(lg.name for lg in logs)})")
    lo = np.full(prob.nz, -np.inf)
    hi = np.full(prob.nz, np.inf)
    lo[: prob.nt], hi[: prob.nt] = mapping.lo, mapping.hi
    for k, n in enumerate(free):
        if lo[k] > 0 or hi[k] < 0:
            a, b = bounds(lay, n)
            raise IdentifyError(f"free: {n} starts at {prob.theta0[k]:g}, outside its physical bounds [{a:g}, {b:g}]")
    cost0 = prob.cost(z0)
    # a parameter that moves no fitted signal at the start (zero column of the Jacobian: e.g. a thruster's limit
    # in a passive trial, a coefficient the system's structure does not use) is held at its value: the solver
    # would otherwise wander along it
    _, J0 = prob.evaluate(z0, True)
    dead = [k for k in range(len(free)) if not np.any(J0[:, k])]
    held = tuple(free[k] for k in dead)
    if any(n in mapping.mapped for n in held):  # a held member of a group: the group is formed without it
        mapping = physical.Mapping(lay, free, system.params.vector(), factors=physical_set, held=held)
        prob.map = mapping
        lo[: prob.nt], hi[: prob.nt] = mapping.lo, mapping.hi
    for k in dead:
        lo[k] = hi[k] = 0.0
    stop = threading.Event()
    caught: list[int] = []  # SIGTERM / SIGHUP received during the solve

    def terminate(signum, frame):
        caught.append(signum)
        stop.set()

    old = {}
    if threading.current_thread() is threading.main_thread():
        old[signal.SIGINT] = signal.signal(signal.SIGINT, lambda *a: stop.set())
        for s in (signal.SIGTERM, signal.SIGHUP):
            old[s] = signal.signal(s, terminate)
    try:
        zs, status, iters, history, inf_du = solve(prob, z0, lo, hi, max_iter, tol, progress, stop)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if caught and prob.pool is not None:
            prob.pool.shutdown()
    if caught:  # the unfinished estimate is dropped: nothing is written
        from arvcas.util.files import Terminated

        raise Terminated(caught[0])
    if stop.is_set():
        status = "interrupted"
    zs[: prob.nt] = np.clip(zs[: prob.nt], lo[: prob.nt], hi[: prob.nt])  # IPOPT relaxes bounds by 1e-8
    pulled = None
    if physical_set:
        v, frac, broke = physical.pull_back(system, mapping, zs[: prob.nt])
        if broke is not None and frac < 1.0:
            zs[: prob.nt] = v
            pulled = (frac, broke)
    r, Jm = prob.evaluate(zs, True)
    if prob.pool is not None:
        prob.pool.shutdown()
    cost = prob.cost(zs)
    w = prob.weights(r)
    sig = {s: 1.0 / math.sqrt(w[k]) for k, s in enumerate(signals)}
    wr = w[prob.sig_id]
    dof = max(prob.n_res - prob.nz, 1)
    s2 = float(r @ (wr * r)) / dof  # 1 + nz / dof for signals whose noise is estimated
    F = _fisher(Jm * np.sqrt(wr)[:, None], prob.nt)
    ident, lines = _directions(F, free)
    std = np.full(len(free), np.nan)
    corr = np.full((len(free), len(free)), np.nan)
    if ident.any():
        sub = np.ix_(ident, ident)
        C = s2 * np.linalg.inv(F[sub])
        sd = np.sqrt(np.diag(C))
        std[ident] = sd * prob.scale[ident]
        corr[sub] = C / np.outer(sd, sd)
    pairs = []
    for i in range(len(free)):
        for j in range(i + 1, len(free)):
            if ident[i] and ident[j] and abs(corr[i, j]) > CORR_WARN:
                pairs.append((free[i], free[j], float(corr[i, j])))
    theta = prob.theta(zs)
    at_bound = [n for k, n in enumerate(free) if k not in dead and
                ((math.isfinite(lo[k]) and zs[k] - lo[k] < 1e-6) or (math.isfinite(hi[k]) and hi[k] - zs[k] < 1e-6))]
    values = dict(zip(lay.names, map(float, system.params.vector())))
    values.update(zip(free, map(float, theta)))
    at_bound += [n for n in mapping.edge(values) if n not in at_bound]
    if pulled is not None:  # held on the edge of what loads
        at_bound += [n for k, n in enumerate(free) if theta[k] != prob.theta0[k] and n not in at_bound]
    return Estimate(system=system, free=free, initial=prob.theta0, values=theta, std=std, correlation=corr,
                    identifiable=ident, unidentifiable=tuple(lines), correlated=tuple(pairs),
                    trials=tuple(lg.name for lg in logs), signals=signals, sigma=sig,
                    x0={lg.name: prob.x0(zs, j).copy() for j, lg in enumerate(logs)}, cost0=cost0, cost=cost, s2=s2,
                    n_residuals=prob.n_res, status=status, iterations=iters,
                    seconds=time.perf_counter() - t_start, h=logs[0].dt / m, at_bound=tuple(at_bound),
                    history=tuple(history), rms0=rms0, rms=prob.rms(zs), stated=tuple(stated),
                    groups=tuple(mapping.groups + mapping.notes), pulled=pulled, nonfinite=prob.nonfinite,
                    inf_du=inf_du, max_iter=int(max_iter), cost_kind=kind, horizon=horizon, dt=logs[0].dt)


def jackknife(est: Estimate, logs: list[Log], progress=None, **kw) -> Estimate:
    """``est`` with leave-one-trial-out estimates: one refit per trial of ``logs`` (the trials ``est`` was fitted
    on) without it, started from ``est`` (its values as the system's), with :func:`identify`'s options ``kw``
    (the same cost, signals, noise and step as ``est``'s). Their spread gives
    :attr:`Estimate.jackknife_intervals`: each trial is one draw of whatever varies from trial to trial (a
    tether's pull, the water, the model's error) and carries its own correlated errors, so the spread holds
    both, where the Fisher intervals hold neither. ``progress(trial, estimate)`` after each refit. The refits
    stop at an objective change of :data:`REFIT_TOL` (not ``identify``'s 0.1): started next to their optimum,
    a loose stop would end them before they move, and the spread would be too small."""
    from dataclasses import replace

    from arvcas.system import System

    if len(logs) < 3:
        raise IdentifyError(f"intervals: leave-one-trial-out needs at least 3 trials, got {len(logs)}")
    if tuple(lg.name for lg in logs) != est.trials:
        raise IdentifyError("logs: give the trials the estimate was fitted on")
    names = [lg.name for lg in logs]
    if len(set(names)) != len(names):
        raise IdentifyError(f"logs: two trials are named {next(n for n in names if names.count(n) > 1)!r}")
    kw.setdefault("tol", REFIT_TOL)
    start = System(est.system.params.replace(est.as_dict()))
    out = {}
    for j, lg in enumerate(logs):
        sub = identify(start, [x for i, x in enumerate(logs) if i != j], est.free,
                       **{**kw, "signals": est.signals, "cost": est.cost_kind, "horizon": est.horizon})
        out[lg.name] = sub.values.copy()
        if progress is not None:
            progress(lg.name, sub)
    return replace(est, jackknife=out)


