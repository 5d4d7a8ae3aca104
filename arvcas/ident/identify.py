"""Grey-box identification: named parameters of a system file estimated from logged trials.

The estimator minimises the simulation error of every trial at once (docs/identification.md):

    min over theta, x_0^(1..T)   1/2 sum_trials sum_samples sum_signals ((y - y_hat(theta, x_0)) / sigma)^2

* ``theta``: the free parameters (any entries of the system's parameter vector, by name), scaled by their
  starting values; ``x_0^(j)``: each trial's initial state (12), free too, started from the log
  (:func:`arvcas.ident.validate.initial_state`);
* ``y_hat``: the same compiled plant as validation (:mod:`arvcas.ident.plant`), open loop over the whole
  trial, its Jacobian with respect to ``[x_0; theta]`` by forward sensitivities of the same CasADi graph;
* ``sigma``: each signal's noise, stated by the log mapping (``std``) or estimated from the log itself
  (:func:`noise_floor`);
* solved by IPOPT (CasADi's ``nlpsol``) with the Gauss-Newton Hessian ``J' J`` and bounds that keep the model
  physical (:func:`bounds`); every trial is simulated on its own thread.

At the optimum the Gauss-Newton information ``F = J' J`` (trials' initial states eliminated by the Schur
complement) gives the covariance ``s^2 F^-1`` with ``s^2`` the weighted residual sum over its degrees of
freedom, so intervals widen when the model cannot follow the data. Directions of ``F`` whose eigenvalue
is below :data:`RANK_TOL` of the largest (in parameters scaled by their values) are reported as
unidentifiable, with the parameters that make them, and no interval is printed for those parameters;
pairs correlated beyond :data:`CORR_WARN` are named.
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
from arvcas.ident.logs import SIGNALS, Log
from arvcas.ident.validate import initial_state, substeps
from arvcas.systemfile import parse_term

__all__ = ["IdentifyError", "Estimate", "identify", "bounds", "noise_floor", "RANK_TOL", "CORR_WARN", "Z95"]

RANK_TOL = 1e-8
CORR_WARN = 0.95
Z95 = 1.959963984540054  # the normal distribution's 97.5 % point
MAX_FREE = 64


class IdentifyError(ValueError):
    """One line naming the argument or parameter at fault."""


def bounds(layout, name: str) -> tuple[float, float]:
    """(lower, upper) SI bounds that keep ``name`` physical: the layout's sign rule (``pos``: > 0, ``nonneg``:
    >= 0), and for hydrodynamic derivatives Fossen's signs: a diagonal added-mass term (``X_udot``) and a
    diagonal damping term (``X_u``, ``X_u_absu``: force along the velocity it multiplies) are <= 0, so that
    the added mass is positive and the damping dissipates."""
    i = layout.index[name]
    rule = layout.rules[i]
    lo, hi = -math.inf, math.inf
    if rule == "pos":
        lo = 1e-12
    elif rule == "nonneg":
        lo = 0.0
    if name.startswith("hydro."):
        t = parse_term(name[len("hydro."):])
        if (t.dot is not None and t.dot == t.row) or (t.col is not None and t.col == t.row and
                                                       all(f in (f"abs{'uvwpqr'[t.row]}",) for f in t.factors)):
            hi = 0.0
    return lo, hi


def noise_floor(y: np.ndarray) -> float:
    """A signal's white-noise level, from its second differences: for smooth motion sampled fast the second
    difference is noise, with variance 6 sigma^2 (median absolute deviation, robust to jumps)."""
    d2 = np.diff(y, 2)
    if d2.size < 3:
        return float("nan")
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


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

    @property
    def intervals(self) -> np.ndarray:
        """(n, 2) 95 % intervals (Gauss-Newton, normal approximation); nan where unidentifiable."""
        return np.stack([self.values - Z95 * self.std, self.values + Z95 * self.std], axis=1)

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.free, map(float, self.values)))

    def params(self):
        """The system's :class:`arvcas.params.Params` with the estimates."""
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
                f"IPOPT: {self.status}, {self.iterations} iterations, {self.seconds:.1f} s; cost "
                f"{self.cost0:.6g} -> {self.cost:.6g}; residual variance factor s^2 = {self.s2:.4g} "
                f"({self.n_residuals} residuals)", "",
                f"{'parameter':28s} {'initial':>12s} {'estimate':>12s} {'95 % interval':>27s}  unit"]
        for n, a, b, s, ok, u in zip(self.free, self.initial, self.values, self.std, self.identifiable, units):
            iv = f"[{b - Z95 * s:.5g}, {b + Z95 * s:.5g}]" if ok else "not identifiable"
            flag = "  (at its bound)" if n in self.at_bound else ""
            rows.append(f"{n:28s} {a:12.5g} {b:12.5g} {iv:>27s}  {u}{flag}")
        if self.unidentifiable:
            rows += ["", "directions the data do not determine:"] + [f"  {u}" for u in self.unidentifiable]
        if self.correlated:
            rows += ["", f"strongly correlated (|r| > {CORR_WARN}):"] + \
                    [f"  {a} ~ {b}: r = {r:+.3f}" for a, b, r in self.correlated]
        return "\n".join(rows)


class _Problem:
    """Residuals and their Jacobian over every trial, memoised by the decision vector."""

    def __init__(self, system, logs, free, signals, sigma, m, K, threads):
        self.system, self.logs, self.free, self.K = system, logs, tuple(free), K
        self.plant = plant_mod.LogPlant(system, m=m, free=self.free)
        lay = system.layout
        self.p = system.params.vector()
        self.theta0 = np.array([self.p[lay.index[n]] for n in self.free])
        self.scale = np.where(np.abs(self.theta0) > 0, np.abs(self.theta0), 0.1)
        self.nt = len(self.free)
        self.data = [plant_mod.sample_inputs(lg, system, m) for lg in logs]
        self.sel = []  # per log: (state indices, measured (N x k), weights 1/sigma)
        for lg in logs:
            sig = [s for s in signals if s in lg.signals]
            idx = np.array([SIGNALS.index(s) for s in sig], dtype=int)
            Y = np.stack([lg.signals[s] for s in sig], axis=1)
            w = np.array([1.0 / sigma[s] for s in sig])
            self.sel.append((idx, Y, w))
        self.nz = self.nt + 12 * len(logs)
        self.n_res = sum(Y.size for _, Y, _ in self.sel)
        self.pool = ThreadPoolExecutor(max(1, threads)) if threads > 1 and len(logs) > 1 else None
        self._last: tuple | None = None
        self._lock = threading.Lock()

    def theta(self, z: np.ndarray) -> np.ndarray:
        return self.theta0 + self.scale * z[: self.nt]

    def x0(self, z: np.ndarray, j: int) -> np.ndarray:
        return z[self.nt + 12 * j: self.nt + 12 * (j + 1)]

    def _one(self, j: int, z: np.ndarray, sens: bool):
        lg, d = self.logs[j], self.data[j]
        idx, Y, w = self.sel[j]
        th = self.theta(z)
        if sens:
            X, dX = plant_mod.simulate_sens(self.plant, lg, self.x0(z, j), self.p, th, self.K, d)
        else:
            X, dX = plant_mod.simulate(self.plant, lg, self.x0(z, j), self.p, th, self.K, d), None
        r = ((X[:, idx] - Y) * w).reshape(-1)
        if dX is None:
            return r, None
        Jr = dX[:, idx, :] * w[None, :, None]  # (N, k, 12 + nt)
        Jr = Jr.reshape(-1, 12 + self.nt)
        Jt = Jr[:, 12:] * self.scale[None, :]
        return r, (Jr[:, :12], Jt)

    def evaluate(self, z: np.ndarray, sens: bool):
        """(r, J) with J (n_res x nz) if ``sens``; memoised on the last ``z``."""
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
                Jm[row:row + a.size, self.nt + 12 * j: self.nt + 12 * (j + 1)] = Jx
                row += a.size
        with self._lock:
            self._last = (z.copy(), r, Jm)
        return r, Jm

    def cost(self, z) -> float:
        r, _ = self.evaluate(z, False)
        c = 0.5 * float(r @ r)
        return c if math.isfinite(c) else math.inf


class _F(ca.Callback):
    """f(z) = 1/2 r'r, with its gradient J'r (for IPOPT through CasADi's nlpsol)."""

    def __init__(self, prob: _Problem, name: str = "ident_f"):
        ca.Callback.__init__(self)
        self.prob = prob
        self.construct(name, {"enable_fd": False})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.prob.nz, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(1, 1)

    def eval(self, arg):
        z = np.array(arg[0]).reshape(-1)
        c = self.prob.cost(z)
        return [c if math.isfinite(c) else float("nan")]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self._grad = _Grad(self.prob, name)  # CasADi keeps no Python reference: a callback must stay alive
        return self._grad


class _Grad(ca.Callback):
    def __init__(self, prob: _Problem, name: str):
        ca.Callback.__init__(self)
        self.prob = prob
        self.construct(name, {"enable_fd": False})

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.prob.nz, 1) if i == 0 else ca.Sparsity.dense(1, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(1, self.prob.nz)

    def eval(self, arg):
        z = np.array(arg[0]).reshape(-1)
        r, Jm = self.prob.evaluate(z, True)
        return [(Jm.T @ r).reshape(1, -1)]


class _GN(ca.Callback):
    """The Gauss-Newton Hessian J'J (its upper triangle is what nlpsol passes IPOPT)."""

    def __init__(self, prob: _Problem, name: str = "ident_gn"):
        ca.Callback.__init__(self)
        self.prob = prob
        self.construct(name, {"enable_fd": False})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.prob.nz, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.prob.nz, self.prob.nz)

    def eval(self, arg):
        z = np.array(arg[0]).reshape(-1)
        _, Jm = self.prob.evaluate(z, True)
        return [Jm.T @ Jm]


class _Progress(ca.Callback):
    """IPOPT's iteration callback: one line per iteration, the best iterate kept, a stop flag honoured."""

    def __init__(self, nz: int, ng: int, report, stop: threading.Event):
        ca.Callback.__init__(self)
        self.nz, self.ng, self.report, self.stop = nz, ng, report, stop
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
        return [1 if self.stop.is_set() else 0]


def _fisher(Jm: np.ndarray, nt: int) -> np.ndarray:
    """The information about theta (scaled) with the initial states eliminated: F_tt - F_tx F_xx^+ F_xt."""
    F = Jm.T @ Jm
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
             max_iter: int = 100, tol: float = 1e-8, threads: int = 2, K: int = 50,
             progress=None) -> Estimate:
    """Estimate the parameters ``free`` (names of ``system.params``) from ``logs`` (module docstring).

    ``signals``: the measured signals fitted (default every vehicle signal the logs measure, of
    :data:`arvcas.ident.logs.SIGNALS`); ``sigma``: noise per signal (SI), else the logs' stated ``std``,
    else :func:`noise_floor`; ``h_max``: the largest plant step (default the logs' sample time);
    ``progress(k, cost)``: called every IPOPT iteration. SIGINT (Ctrl-C) stops after the current
    iteration and returns the best iterate (status "interrupted").
    """
    t_start = time.perf_counter()
    lay = system.layout
    free = tuple(free)
    if not free:
        raise IdentifyError("free: name at least one parameter to identify")
    if len(free) > MAX_FREE:
        raise IdentifyError(f"free: at most {MAX_FREE} parameters, got {len(free)}")
    for n in free:
        if n not in lay.index:
            from arvcas.config import closest

            raise IdentifyError(f"free: {system.name} has no parameter {n!r}{closest(n, lay.names)}")
    dup = [n for n in free if free.count(n) > 1]
    if dup:
        raise IdentifyError(f"free: {dup[0]} is named twice")
    if not logs:
        raise IdentifyError("logs: give at least one trial")
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
    sig = {}
    for s in signals:
        if sigma and s in sigma:
            sig[s] = float(sigma[s])
        else:
            stated = [lg.std[s] for lg in logs if s in lg.std]
            sig[s] = float(np.mean(stated)) if stated else float(np.median([noise_floor(lg.signals[s]) for lg in logs
                                                                            if s in lg.signals]))
        if not (math.isfinite(sig[s]) and sig[s] > 0):
            sig[s] = 1e-6  # a noiseless signal: weighted as a very precise one
    m = substeps(logs[0].dt, logs[0].dt if h_max is None else float(h_max))
    prob = _Problem(system, logs, free, signals, sig, m, K, threads)
    lo = np.full(prob.nz, -np.inf)
    hi = np.full(prob.nz, np.inf)
    for k, n in enumerate(free):
        a, b = bounds(lay, n)
        lo[k] = (a - prob.theta0[k]) / prob.scale[k]
        hi[k] = (b - prob.theta0[k]) / prob.scale[k]
        if lo[k] > 0 or hi[k] < 0:
            raise IdentifyError(f"free: {n} starts at {prob.theta0[k]:g}, outside its physical bounds [{a:g}, {b:g}]")
    z0 = np.concatenate([np.zeros(len(free))] + [initial_state(lg) for lg in logs])
    cost0 = prob.cost(z0)
    if not math.isfinite(cost0):
        raise IdentifyError(f"the simulation from the starting parameters is not finite on some trial "
                            f"({', '.join(lg.name for lg in logs)})")
    z = ca.MX.sym("z", prob.nz)
    fcb, gncb = _F(prob), _GN(prob)
    lam_f = ca.MX.sym("lam_f")
    hess = ca.Function("hess_gn", [z, ca.MX(0, 1), lam_f, ca.MX(0, 1)], [lam_f * ca.triu(gncb(z))],
                       ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
    stop = threading.Event()
    prog = _Progress(prob.nz, 0, progress, stop)
    opts = {"hess_lag": hess, "iteration_callback": prog, "print_time": False,
            "ipopt": {"print_level": 0, "max_iter": int(max_iter), "tol": float(tol), "sb": "yes",
                      "hessian_approximation": "exact", "mu_strategy": "adaptive"}}
    solver = ca.nlpsol("ident", "ipopt", {"x": z, "f": fcb(z)}, opts)
    old = None
    if threading.current_thread() is threading.main_thread():
        old = signal.signal(signal.SIGINT, lambda *a: stop.set())
    try:
        sol = solver(x0=z0, lbx=lo, ubx=hi)
        zs = np.array(sol["x"]).reshape(-1)
        status = solver.stats().get("return_status", "?")
        iters = int(solver.stats().get("iter_count", prog.k))
    finally:
        if old is not None:
            signal.signal(signal.SIGINT, old)
    if stop.is_set():
        status = "interrupted"
    if prog.best is not None and prog.best[0] < prob.cost(zs):
        zs = prog.best[1]
    r, Jm = prob.evaluate(zs, True)
    if prob.pool is not None:
        prob.pool.shutdown()
    cost = 0.5 * float(r @ r)
    dof = max(prob.n_res - prob.nz, 1)
    s2 = 2.0 * cost / dof
    F = _fisher(Jm, prob.nt)
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
    at_bound = tuple(n for k, n in enumerate(free)
                     if (math.isfinite(lo[k]) and zs[k] - lo[k] < 1e-6) or (math.isfinite(hi[k]) and hi[k] - zs[k] < 1e-6))
    return Estimate(system=system, free=free, initial=prob.theta0, values=theta, std=std, correlation=corr,
                    identifiable=ident, unidentifiable=tuple(lines), correlated=tuple(pairs),
                    trials=tuple(lg.name for lg in logs), signals=signals, sigma=sig,
                    x0={lg.name: prob.x0(zs, j).copy() for j, lg in enumerate(logs)}, cost0=cost0, cost=cost, s2=s2,
                    n_residuals=prob.n_res, status=status, iterations=iters,
                    seconds=time.perf_counter() - t_start, h=logs[0].dt / m, at_bound=at_bound,
                    history=tuple(prog.history))


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
    arm = doc.get("arm", {})
    if not (isinstance(arm, dict) and "urdf" in arm):
        return
    in_toml = (".volume", ".cob", ".drag_diameter", ".drag_from", ".drag_to", ".Cd")
    for n in names:
        if n.startswith(("arm.joint", "arm.tool")) or (n.startswith("arm.link") and not any(k in n for k in in_toml)):
            raise IdentifyError(f"free: {n} comes from the URDF file {arm['urdf']!r}, which arvcas does not rewrite: "
                                f"identify it in a chain-form system file (docs/system-file.md)")


def _si_factor(unit: str, k: int) -> float:
    from arvcas import config

    units = [u.strip() for u in unit.split(",")]
    u = units[k] if len(units) > 1 else units[0]
    if u == config.SI:
        return 1.0
    return config.UNITS[u][1]


def _system_text(est: Estimate, out_path, date: str | None) -> str:
    import datetime
    import os
    from pathlib import Path

    import tomlkit

    from arvcas.systemfile import VECTOR_ELEMENTS

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
            what = f"95 % interval [{lo:.6g}, {hi:.6g}] {unit}"
        else:
            what = "not identifiable from these trials alone (a combination is; see the report): value of the joint fit"
        entry["source"] = (f"identified by arvcas identify on {date} from trials {trials} ({what}; Gauss-Newton, "
                           f"s^2 = {est.s2:.3g}); was {old / f:.6g} {unit}: {old_src}")
    sysname = str(doc["system"]["name"]) if "system" in doc and "name" in doc["system"] else est.system.name
    if "system" not in doc:
        doc.add("system", tomlkit.table())
    doc["system"]["name"] = sysname if sysname.endswith("_identified") else f"{sysname}_identified"
    desc = str(doc["system"].get("description", est.system.description))
    doc["system"]["description"] = f"{desc} (identified from {len(est.trials)} trials, {date})"
    out_dir = Path(out_path).resolve().parent

    def moved(rel: str) -> str:
        p = Path(rel)
        if p.is_absolute():
            return rel
        return os.path.relpath((src.parent / p).resolve(), out_dir)

    for k in list(doc.get("defaults", {}).keys()):
        doc["defaults"][k] = moved(str(doc["defaults"][k]))
    if isinstance(doc.get("arm"), dict) and "urdf" in doc["arm"]:
        doc["arm"]["urdf"] = moved(str(doc["arm"]["urdf"]))
    head = (f"# Identified by arvcas identify on {date} from {src.name} and trials {trials}: parameters "
            f"{', '.join(est.free)} estimated (docs/identification.md); every other number is {src.name}'s.\n")
    return head + tomlkit.dumps(doc)
