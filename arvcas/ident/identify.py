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
  over :data:`STALL_ITER` iterations: the objective is a negative log-likelihood, and a change of 0.5
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
pairs correlated beyond :data:`CORR_WARN` are named.

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
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from arvcas.ident import plant as plant_mod
from arvcas.ident import physical
from arvcas.ident.logs import SIGNALS, Log
from arvcas.ident.physical import bounds
from arvcas.ident.validate import initial_state, logged_states, substeps

__all__ = ["IdentifyError", "Estimate", "identify", "jackknife", "check_cost", "COSTS", "bounds", "identified_name",
           "RANK_TOL", "CORR_WARN", "Z95",
           "MOVE_FACTOR"]

RANK_TOL = 1e-8
STALL_ITER = 3  # iterations over which a relative objective change below ``tol`` ends the solve
CORR_WARN = 0.95
Z95 = 1.959963984540054  # the normal distribution's 97.5 % point
MOVE_FACTOR = 3.0  # an estimate more than this many times (or less than 1 / this) its source value is flagged
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


def t95(dof: int) -> float:
    """The two-sided 95 % point of Student's t with ``dof`` degrees of freedom."""
    from scipy.stats import t

    return float(t.ppf(0.975, dof))


class IdentifyError(ValueError):
    """One line naming the argument or parameter at fault."""


@dataclass(frozen=True)
class Estimate:
    """The result of :func:`identify`: values, intervals, what the data could not identify."""

    system: object
    free: tuple[str, ...]
    initial: np.ndarray
    values: np.ndarray
    std: np.ndarray  # one standard deviation (nan where unidentifiable)
    correlation: np.ndarray
    identifiable: np.ndarray  # bool per parameter
    unidentifiable: tuple[str, ...]  # one line per direction
    correlated: tuple[tuple[str, str, float], ...]
    trials: tuple[str, ...]
    signals: tuple[str, ...]
    sigma: dict[str, float]
    x0: dict[str, np.ndarray]
    cost0: float
    cost: float
    s2: float  # weighted residual sum of squares / degrees of freedom
    n_residuals: int
    status: str
    iterations: int
    seconds: float
    h: float
    at_bound: tuple[str, ...] = ()
    history: tuple[float, ...] = field(default=(), repr=False)
    rms0: dict = field(default_factory=dict)  # unweighted RMS error per fitted signal, at the start
    rms: dict = field(default_factory=dict)  # and at the estimate
    stated: tuple[str, ...] = ()  # the signals whose noise the logs state (the others are estimated)
    groups: tuple[str, ...] = ()  # the physical parameterisations used (arvcas.ident.physical)
    pulled: tuple | None = None  # (fraction of the last step kept, the loader's rule it broke) or None
    nonfinite: int = 0  # objective evaluations whose simulation was not finite
    inf_du: float = math.nan  # IPOPT's dual infeasibility at its last iteration
    max_iter: int = 0
    cost_kind: str = "simulation"  # the cost minimised (COSTS)
    horizon: int | None = None  # the prediction error's k (samples)
    dt: float = math.nan  # the logs' sample time (s)
    jackknife: dict | None = None  # leave-one-trial-out: trial -> estimates (jackknife_intervals)

    @property
    def cost_text(self) -> str:
        """The cost minimised, in words."""
        if self.cost_kind == "prediction":
            return (f"{self.horizon}-step-ahead prediction error ({self.horizon * self.dt:g} s: "
                    f"each trial cut into segments of {self.horizon} samples, each restarted from the logged state)")
        return "simulation error (open loop over each whole trial, its initial state free)"

    @property
    def jackknife_std(self) -> np.ndarray | None:
        """The leave-one-trial-out standard error per parameter, ``sqrt((T-1)/T sum (theta_(-j) - mean)^2)``."""
        if not self.jackknife:
            return None
        v = np.array(list(self.jackknife.values()))
        T = len(v)
        return np.sqrt((T - 1) / T * np.sum((v - v.mean(axis=0)) ** 2, axis=0))

    @property
    def jackknife_intervals(self) -> np.ndarray | None:
        """(n, 2) 95 % intervals ``estimate +- t_(T-1) sd_jackknife`` (Student's t with T - 1 degrees of freedom:
        T trials are T draws of everything a trial varies in); None without :func:`jackknife`."""
        sd = self.jackknife_std
        if sd is None:
            return None
        q = t95(len(self.jackknife) - 1)
        return np.stack([self.values - q * sd, self.values + q * sd], axis=1)

    def flags(self) -> list[tuple[str, str]]:
        """(parameter, what it usually means) for every estimate at a bound, at the edge of its physical set,
        moved more than :data:`MOVE_FACTOR` times from its source value, or changed in sign."""
        out = []
        for k, n in enumerate(self.free):
            a, b = float(self.initial[k]), float(self.values[k])
            if n in self.at_bound:
                out.append((n, f"ended at the edge of its physical set ({b:.6g}): the data push it past what is "
                               f"physical, usually because it absorbs an effect the model lacks (a drift, a "
                               f"tether, a wrong number elsewhere); do not read it as measured"))
            if a != 0 and b != 0 and (a > 0) != (b > 0):
                out.append((n, f"changed sign ({a:.6g} -> {b:.6g}): check the model's sign convention, or what "
                               f"the parameter absorbs"))
            elif a != 0 and b != 0 and max(abs(b / a), abs(a / b)) > MOVE_FACTOR:
                out.append((n, f"moved {abs(b / a):.3g} times its source value ({a:.6g} -> {b:.6g}, more than "
                               f"{MOVE_FACTOR:g} times): a parameter that moves this far usually absorbs "
                               f"something the model lacks (e.g. heave damping soaking up a depth drift); compare "
                               f"fits on subsets of trials and validate on held-out ones"))
        return out

    @property
    def intervals(self) -> np.ndarray:
        """(n, 2) 95 % intervals (Gauss-Newton, normal approximation); nan where unidentifiable."""
        return np.stack([self.values - Z95 * self.std, self.values + Z95 * self.std], axis=1)

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.free, map(float, self.values)))

    def params(self):
        """The system's :class:`arvcas.system.params.Params` with the estimates."""
        return self.system.params.replace(self.as_dict())

    def system_text(self, out_path, date: str | None = None) -> str:
        """The system file with the estimates: the original file's text (comments kept, by ``tomlkit``) with
        each free entry's value replaced (in the file's own unit) and its ``source`` naming the trials, the
        date and the 95 % interval; ``[system] name`` gets ``_identified``; relative paths to other files
        (``[defaults]``, a URDF) are rewritten for ``out_path``'s folder. Everything else is unchanged."""
        return _system_text(self, out_path, date)

    def report(self) -> str:
        units = [self.system.params.unit(n) for n in self.free]
        rows = [f"identification of {len(self.free)} parameters of {self.system.name} on {len(self.trials)} trials "
                f"({', '.join(self.trials)}); signals {', '.join(self.signals)}; plant step {self.h:g} s",
                f"cost minimised: {self.cost_text}",
                f"IPOPT: {self.status}, {self.iterations} iterations, {self.seconds:.1f} s; cost "
                f"{self.cost0:.6g} -> {self.cost:.6g}; residual variance factor s^2 = {self.s2:.4g} "
                f"({self.n_residuals} residuals)"]
        rows += [f"physical parameterisation: {g}" for g in self.groups]
        rows += self._solver_notes()
        jk = self.jackknife_intervals
        rows += ["", f"{'parameter':28s} {'initial':>12s} {'estimate':>12s} {'95 % interval (Fisher)':>27s}" +
                 (f" {'95 % (leave-one-trial-out)':>27s}" if jk is not None else "") + "  unit"]
        flagged = {n for n, _ in self.flags()}
        for k, (n, a, b, s, ok, u) in enumerate(zip(self.free, self.initial, self.values, self.std, self.identifiable,
                                                    units)):
            iv = f"[{_num(b - Z95 * s, s)}, {_num(b + Z95 * s, s)}]" if ok else "not identifiable"
            iv = f"{iv:>27s}"
            if jk is not None:
                w = (jk[k, 1] - jk[k, 0]) / 2
                iv += f" {'[' + _num(jk[k, 0], w) + ', ' + _num(jk[k, 1], w) + ']':>27s}"
            flag = "  (at its bound)" if n in self.at_bound else "  (flagged)" if n in flagged else ""
            rows.append(f"{n:28s} {a:12.5g} {b:12.5g} {iv}  {u}{flag}")
        rows += ["", "The Fisher intervals assume errors independent from sample to sample; where the model cannot",
                 "follow the vehicle (errors that persist over seconds), they are too narrow."]
        if jk is not None:
            rows += [f"The leave-one-trial-out (jackknife) intervals come from {len(self.jackknife)} refits, each "
                     f"without one trial:", "they carry the trial-to-trial spread and errors correlated within a "
                     "trial (docs/identification.md)."]
        else:
            rows += ["For intervals that carry them, --intervals jackknife (at least 3 trials); validate on held-out "
                     "trials."]
        if self.flags():
            rows += ["", "flags:"] + [f"  {n}: {why}" for n, why in self.flags()]
        if self.unidentifiable:
            rows += ["", "directions the data do not determine:"] + [f"  {u}" for u in self.unidentifiable]
        if self.correlated:
            rows += ["", f"strongly correlated (|r| > {CORR_WARN}):"] + \
                    [f"  {a} ~ {b}: r = {r:+.3f}" for a, b, r in self.correlated]
        return "\n".join(rows)

    def _solver_notes(self) -> list[str]:
        """What the solver's end means: the iteration cap with the optimality measure and what to try, the
        count of non-finite evaluations, the hold inside the loader's rules."""
        rows = []
        if self.status == "Maximum_Iterations_Exceeded":
            h = [v for v in self.history if math.isfinite(v)][-STALL_ITER - 1:]
            rows.append(f"stopped at the iteration cap ({self.max_iter}) before converging: IPOPT's dual "
                        f"infeasibility (its optimality measure, 0 at an optimum) is {self.inf_du:.3g}, the "
                        f"objective changed by {max(h) - min(h) if h else math.nan:.3g} over the last "
                        f"{len(h) - 1} iterations; try more iterations (--max-iter), fewer free parameters "
                        f"(those named below as unidentifiable or correlated), or starting values nearer the "
                        f"data (a previous estimate as the system file)")
        elif self.status not in ("interrupted", "Solve_Succeeded", "Solved_To_Acceptable_Level",
                                 "User_Requested_Stop") and not self.status.startswith("converged"):
            rows.append(f"IPOPT ended with {self.status} (dual infeasibility {self.inf_du:.3g}): the estimate is "
                        f"the best iterate, not an optimum; try fewer free parameters or better starting values")
        if self.nonfinite:
            rows.append(f"{self.nonfinite} evaluations of the simulation were not finite (NaN or inf; counted, not "
                        f"printed): IPOPT tried parameters at which the model diverges on a trial and stepped "
                        f"back; harmless when the fit converged, otherwise the starting values or the free set "
                        f"let the model go unstable")
        if self.pulled is not None:
            frac, why = self.pulled
            rows.append(f"the optimiser's last point broke a rule of the system file ({why}); the estimate is "
                        f"held at {100 * frac:.3g} % of the way from the start to it, on the edge of what loads: "
                        f"its values are bounded there, not fitted")
        return rows


def _num(x: float, width: float) -> str:
    """``x`` with enough digits to show a difference of ``width``."""
    if not (math.isfinite(x) and math.isfinite(width)) or width <= 0 or x == 0:
        return f"{x:.5g}"
    d = max(4, int(math.ceil(math.log10(abs(x) / width))) + 2)
    return f"{x:.{min(d, 15)}g}"


class _Problem:
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


def _callbacks(prob: _Problem) -> tuple[_Fn, _Fn]:
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


def _solve(prob: _Problem, z0, lo, hi, max_iter, tol, progress, stop):
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
    :class:`arvcas.io.files.Terminated` (nothing is returned, so nothing unfinished is written).
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
    prob = _Problem(system, logs, free, signals, stated, m, K, threads, mapping, horizon)
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
        zs, status, iters, history, inf_du = _solve(prob, z0, lo, hi, max_iter, tol, progress, stop)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if caught and prob.pool is not None:
            prob.pool.shutdown()
    if caught:  # the unfinished estimate is dropped: nothing is written
        from arvcas.io.files import Terminated

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


# ---- the identified system file ---------------------------------------------------------------------------


def _locate(doc, leaf: str):
    """The tomlkit table holding ``leaf`` (a parameter's file key) and the key within it."""
    parts = leaf.split(".")
    node = doc
    if parts[0] == "thrusters" and "unit" in doc.get("thrusters", {}):
        node = next(u for u in doc["thrusters"]["unit"] if u["name"] == parts[1])
        parts = parts[2:]
        return node, parts[0]
    for k in parts[:-1]:
        node = node[k]
    return node, parts[-1]


def writable(system, names) -> None:
    """Refuse (one line) free parameters the system file does not write itself: a URDF arm's joints,
    inertials and tool come from the URDF, which arvcas does not rewrite."""
    import tomllib

    from arvcas.io.files import read_text

    doc = tomllib.loads(read_text(system.path, "system file", IdentifyError))
    maps = doc.get("thrusters", {}).get("map", {}) if isinstance(doc.get("thrusters"), dict) else {}
    for n in names:
        parts = n.split(".")
        if n.startswith("thrusters.map.") and isinstance(maps.get(parts[2]), dict) and "table" in maps[parts[2]]:
            raise IdentifyError(f"free: {n} comes from the thrust table file {maps[parts[2]]['table']!r}, which "
                                f"arvcas does not rewrite: write the map's points in the system file "
                                f"(command = {{...}}, thrust = {{...}}, docs/system-file.md) to identify them")
    arm = doc.get("arm", {})
    if not (isinstance(arm, dict) and "urdf" in arm):
        return
    in_toml = (".volume", ".cob", ".drag_diameter", ".drag_from", ".drag_to", ".Cd")
    for n in names:
        if n.startswith(("arm.joint", "arm.tool")) or (n.startswith("arm.link") and not any(k in n for k in in_toml)):
            raise IdentifyError(f"free: {n} comes from the URDF file {arm['urdf']!r}, which arvcas does not rewrite: "
                                f"identify it in a chain-form system file (docs/system-file.md)")


def _si_factor(unit: str, k: int) -> float:
    from arvcas.system import config

    units = [u.strip() for u in unit.split(",")]
    u = units[k] if len(units) > 1 else units[0]
    if u == config.SI:
        return 1.0
    return config.UNITS[u][1]


def identified_name(name: str) -> str:
    """``<name>_identified`` within the loader's rule for names (at most 64 characters: the old name is
    shortened to make room); a name that already ends in ``_identified`` is kept."""
    from arvcas.system.systemfile import NAME_RE

    suffix = "_identified"
    if name.endswith(suffix) and NAME_RE.match(name):
        return name
    out = name[: 64 - len(suffix)] + suffix
    assert NAME_RE.match(out), out
    return out


def _system_text(est: Estimate, out_path, date: str | None) -> str:
    import datetime
    import os
    from pathlib import Path

    import tomlkit

    from arvcas.system.systemfile import VECTOR_ELEMENTS

    src = Path(est.system.path)
    from arvcas.io.files import read_text

    doc = tomlkit.parse(read_text(src, "system file", IdentifyError))
    date = date or datetime.date.today().isoformat()
    lay = est.system.layout
    trials = ", ".join(est.trials)
    for k, name in enumerate(est.free):
        leaf = lay.leaf[lay.index[name]]
        table, key = _locate(doc, leaf)
        entry = table[key]
        unit = str(entry.get("unit", "SI"))
        old_src = str(entry.get("source", ""))
        if leaf == name:
            el = 0
            f = _si_factor(unit, 0)
            old = float(entry["value"]) * f
            entry["value"] = float(f"{est.values[k] / f:.10g}")
        else:
            el = VECTOR_ELEMENTS[leaf.rsplit(".", 1)[-1]].index(name.rsplit(".", 1)[-1])
            f = _si_factor(unit, el)
            old = float(entry["value"][el]) * f
            entry["value"][el] = float(f"{est.values[k] / f:.10g}")
        if est.identifiable[k]:
            lo, hi = (est.values[k] - Z95 * est.std[k]) / f, (est.values[k] + Z95 * est.std[k]) / f
            w = Z95 * est.std[k] / f
            what = f"95 % interval [{_num(lo, w)}, {_num(hi, w)}] {unit} (Gauss-Newton, s^2 = {est.s2:.3g})"
        else:
            what = "not identifiable from these trials alone (a combination is; see the report): value of the joint fit"
        jk = est.jackknife_intervals
        if jk is not None:
            w = (jk[k, 1] - jk[k, 0]) / 2 / f
            what += f"; leave-one-trial-out 95 % interval [{_num(jk[k, 0] / f, w)}, {_num(jk[k, 1] / f, w)}] {unit}"
        what += f"; cost: {est.cost_kind}" + (f", horizon {est.horizon} samples" if est.horizon else "")
        entry["source"] = (f"identified by arvcas identify on {date} from trials {trials} ({what}); "
                           f"was {old / f:.6g} {unit}: {old_src}")
    sysname = str(doc["system"]["name"]) if "system" in doc and "name" in doc["system"] else est.system.name
    if "system" not in doc:
        doc.add("system", tomlkit.table())
    doc["system"]["name"] = identified_name(sysname)
    desc = str(doc["system"].get("description", est.system.description))
    doc["system"]["description"] = f"{desc} (identified from {len(est.trials)} trials, {date})"
    out_dir = Path(out_path).resolve().parent

    def moved(rel: str) -> str:
        p = Path(rel)
        if p.is_absolute():
            return rel
        return Path(os.path.relpath((src.parent / p).resolve(), out_dir)).as_posix()

    for k in list(doc.get("defaults", {}).keys()):
        doc["defaults"][k] = moved(str(doc["defaults"][k]))
    if isinstance(doc.get("arm"), dict) and "urdf" in doc["arm"]:
        doc["arm"]["urdf"] = moved(str(doc["arm"]["urdf"]))
    maps = doc.get("thrusters", {}).get("map", {}) if isinstance(doc.get("thrusters"), dict) else {}
    for m in maps.values():  # a table beside the old file (a shipped table's bare name is found anywhere)
        if isinstance(m, dict) and isinstance(m.get("table"), str) and (src.parent / m["table"]).exists():
            m["table"] = moved(m["table"])
    head = (f"# Identified by arvcas identify on {date} from {src.name} and trials {trials}: parameters "
            f"{', '.join(est.free)} estimated (docs/identification.md) by minimising the {est.cost_text}; every "
            f"other number is {src.name}'s.\n")
    return head + tomlkit.dumps(doc)
