"""The open-loop plant driven by a log: one compiled RK4 sample, and blocks of samples.

A log's samples are ``dt = 1 / rate`` apart; the plant takes ``m`` RK4 steps of ``h = dt / m`` per sample
(the system's accuracy-matched step, ``results/step/``, or finer), with

* the body wrench held over the sample: ``tau = B_T(p) u + w`` from the logged thrust ``u`` (N, per
  thruster; zero for a passive vehicle) and a logged body wrench ``w``;
* the joints prescribed (docs/model.md §3, the exact coupling of ``uvms.coupled_terms``): ``q, qd, qdd``
  from the log's smoothing splines at every RK4 stage time (t, t + h/2, t + h of each step);
* the payload fraction held over the sample;
* the trim buoyancy of docs/model.md §3 exactly as the system file says: a vehicle described as tested
  carries its ballast in its own numbers and says ``[arm] trim = false`` (the Hinsdale vehicle); a system
  whose vehicle numbers exclude the ballast for its arm keeps the trim, as ``uvms_rhs`` does.

Every parameter is a runtime input (``p``): one compiled block serves every log and parameter value of
the same system structure and block length (K m steps). The identification's sensitivities are compiled
for its choice of free parameters, whose entries of ``p`` are replaced by the input ``theta``: derivatives
flow through those entries only (a symbolic selection of any parameter made every derivative go through
all of them: 2.3 ms a sample instead of about 0.1 ms).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from arvcas.build import calls, codegen
from arvcas.model import manipulator, thrusters, vehicle
from arvcas.model.spatial import J
from arvcas.model.uvms import ModelOptions, coupled_terms
from arvcas.system.params import system_tag, view

__all__ = ["LogPlant", "sample_inputs", "DEFAULT_BLOCK"]

DEFAULT_BLOCK = 50  # samples per compiled block (1 s at 50 Hz)


@dataclass(frozen=True)
class LogPlant:
    """The compiled plant of one system structure for ``m`` RK4 steps per sample and ``free`` parameters."""

    system: object  # arvcas.system.System
    m: int = 1
    free: tuple[str, ...] = ()
    opts: ModelOptions = ModelOptions()

    @property
    def layout(self):
        return self.system.layout

    def _tag(self, free: tuple[str, ...] = ()) -> str:
        return f"ident {self.opts!r}{system_tag(self.layout.structure)}" + (f" free={','.join(free)}" if free else "")

    def step_fn(self, free: tuple[str, ...] = ()) -> ca.Function:
        """``ident_step(x, u, w, Q, QD, QDD, payload, h, theta, p) -> x_next``: one RK4 step.

        ``Q, QD, QDD`` (n_joints x 3): the joints at the step's stage times t, t + h/2, t + h. The parameters
        are ``p`` with the entries ``free`` replaced by ``theta`` (one each), so that derivatives with respect to
        ``theta`` go through those entries only.
        """
        lay = self.layout
        st = lay.structure
        nj, nt = st.n_joints, st.n_thrusters
        x = ca.SX.sym("x", 12)
        u, w = ca.SX.sym("u", nt), ca.SX.sym("w", 6)
        Q, QD, QDD = ca.SX.sym("Q", nj, 3), ca.SX.sym("QD", nj, 3), ca.SX.sym("QDD", nj, 3)
        pl, h = ca.SX.sym("payload"), ca.SX.sym("h")
        theta, p0 = ca.SX.sym("theta", len(free)), ca.SX.sym("p", len(lay))
        pv = [p0[i] for i in range(len(lay))]
        for k, n in enumerate(free):
            pv[lay.index[n]] = theta[k]
        P = view(ca.vertcat(*pv), lay)
        tau = ca.mtimes(thrusters.B_T(P), u) + w

        def f(xx, j):
            eta, nu = xx[0:6], xx[6:12]
            if nj == 0:
                nud = ca.solve(vehicle.M(P), tau - vehicle.forces(P, eta, nu))
            else:
                extra = manipulator.trim_wrench(P, eta, self.opts.n_quad)
                nud, _ = coupled_terms(P, eta, nu, tau, Q[:, j], QD[:, j], QDD[:, j], pl, extra, self.opts)
            return ca.vertcat(ca.mtimes(J(eta), nu), nud)

        k1 = f(x, 0)
        k2 = f(x + 0.5 * h * k1, 1)
        k3 = f(x + 0.5 * h * k2, 1)
        k4 = f(x + h * k3, 2)
        xn = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return ca.Function("ident_step", [x, u, w, Q, QD, QDD, pl, h, theta, p0], [ca.cse(xn)], _IN, ["x_next"])

    def _accumulated(self, name: str, n: int, free: tuple[str, ...] | None) -> ca.Function:
        """n RK4 steps chained (``mapaccum``): the state after each, and with ``free`` (not None) its
        sensitivities to [x0; theta]."""
        lay = self.layout
        nj, nt = lay.structure.n_joints, lay.structure.n_thrusters
        f = self.step_fn(free or ())
        nf = len(free or ())
        if free is not None:  # forward sensitivities: S_next = A S + [0 B], with z = [x0; theta]
            ins = f.sx_in()
            xn = f(*ins)
            A = ca.jacobian(xn, ins[0])
            B = ca.jacobian(xn, ins[8])
            Sx = ca.SX.sym("S", 12, 12 + nf)
            Sn = ca.mtimes(A, Sx) + ca.horzcat(ca.SX(12, 12), B)
            f = ca.Function("ident_sens", [ins[0], Sx, *ins[1:]], [xn, ca.cse(Sn)], ["x", "S", *_IN[1:]],
                            ["x_next", "S_next"])
            acc = f.mapaccum("acc", n, [0, 1], [0, 1])
        else:
            acc = f.mapaccum("acc", n, [0], [0])
        x0 = ca.MX.sym("x0", 12)
        S0 = ca.MX.sym("S0", 12, 12 + nf)
        U, W = ca.MX.sym("U", nt, n), ca.MX.sym("W", 6, n)
        Q, QD, QDD = (ca.MX.sym(k, nj, 3 * n) for k in ("Q", "QD", "QDD"))
        pl, h = ca.MX.sym("payload", 1, n), ca.MX.sym("h")
        theta, p0 = ca.MX.sym("theta", nf), ca.MX.sym("p", len(lay))
        rest = [U, W, Q, QD, QDD, pl, ca.repmat(h, 1, n), ca.repmat(theta, 1, n), ca.repmat(p0, 1, n)]
        if free is not None:
            X, SS = acc(x0, S0, *rest)
            return ca.Function(name, [x0, S0, U, W, Q, QD, QDD, pl, h, theta, p0], [X, SS],
                               ["x0", "S0", *_BLOCK_IN], ["X", "S"])
        X = acc(x0, *rest)
        return ca.Function(name, [x0, U, W, Q, QD, QDD, pl, h, theta, p0], [X], ["x0", *_BLOCK_IN], ["X"])

    def block_fn(self, K: int = DEFAULT_BLOCK) -> ca.Function:
        """``ident_block(x0, U, W, Q, QD, QDD, payload, h, theta, p) -> X``: K log samples (K m RK4 steps).

        Per step: ``U`` (n_thrusters), ``W`` (6), ``Q, QD, QDD`` (n_joints x 3: the stage times t, t + h/2,
        t + h), ``payload``; ``X`` (12 x K m) the state after each step; ``theta`` is empty (every parameter
        comes from ``p``). One library per system structure and block length serves every parameter value.
        """
        _check_K(K)
        n = K * self.m
        return codegen.build_described("ident_block", f"{self._tag()} n={n}",
                                       lambda: self._accumulated("ident_block", n, None))

    def sens_fn(self, K: int = DEFAULT_BLOCK) -> ca.Function:
        """``ident_sens_block(x0, S0, ..., theta, p) -> (X, S)``: as :meth:`block_fn` with the sensitivities.

        ``theta``: the values of :attr:`free`; ``S0`` (12 x (12 + len(free))): d x0 / d z for z = [x at the
        trial's start; theta]; ``S`` (12 x K m (12 + len(free))): d x / d z after each step, step k in columns
        k (12 + len(free)) ... By CasADi's algorithmic differentiation of the same step graph, compiled at
        -O1 (the -O2 build of a large Jacobian takes several times longer for code about as fast), one
        library per choice of free parameters.
        """
        _check_K(K)
        n = K * self.m
        return codegen.build_described("ident_sens_block", f"{self._tag(self.free)} n={n} sens",
                                       lambda: self._accumulated("ident_sens_block", n, self.free), opt_level="-O1")


_IN = ["x", "u", "w", "Q", "QD", "QDD", "payload", "h", "theta", "p"]
_BLOCK_IN = ["U", "W", "Q", "QD", "QDD", "payload", "h", "theta", "p"]


def _check_K(K) -> None:
    if not isinstance(K, int) or isinstance(K, bool) or not 1 <= K <= 10_000:
        raise ValueError(f"block length must be an integer in [1, 10000], got {K!r}")


def sample_inputs(log, system, m: int, thrust_names=None) -> dict[str, np.ndarray]:
    """The block inputs of every RK4 step over ``log`` (m steps per sample, (N - 1) m steps in all).

    ``U`` (n_thrusters x steps; zero where not logged) and ``W`` (6 x steps), held over each sample;
    ``Q, QD, QDD`` (n_joints x 3 steps): the joint splines at each step's stage times; ``payload`` (1 x steps);
    ``h`` = dt / m.
    """
    st = system.layout.structure
    nj, nt = st.n_joints, st.n_thrusters
    names = thrust_names if thrust_names is not None else tuple(st.thrusters or ())
    n = len(log.t) - 1
    h = log.dt / m
    U = np.zeros((nt, n))
    for i, tn in enumerate(names):
        if tn in log.thrust:
            U[i] = log.thrust[tn][:-1]
    W = np.zeros((6, n)) if log.wrench is None else np.ascontiguousarray(log.wrench[:-1].T)
    pl = np.zeros((1, n)) if log.payload is None else log.payload[None, :-1]
    t_step = (log.t[:-1, None] + np.arange(m)[None, :] * h).reshape(-1)
    ts = (t_step[:, None] + np.array([0.0, 0.5, 1.0])[None, :] * h).reshape(-1)  # step-major, stage-minor
    if nj:
        if log.joints is None:
            raise ValueError(f"{log.path}: the system has {nj} joints but the log maps none")
        q, qd, qdd = log.joints(ts)
        Q, QD, QDD = q.T, qd.T, qdd.T
    else:
        Q = QD = QDD = np.zeros((0, 3 * n * m))
    rep = lambda a: np.repeat(a, m, axis=1)  # noqa: E731
    return {"U": rep(U), "W": rep(W), "Q": Q, "QD": QD, "QDD": QDD, "payload": rep(pl), "h": np.array([[h]]),
            "m": m}


def simulate(plant: LogPlant, log, x0: np.ndarray, p: np.ndarray, K: int = DEFAULT_BLOCK,
             data: dict | None = None) -> np.ndarray:
    """The open-loop state (N x 12) on the log's time base from ``x0`` at t_0 (simulation error, not
    prediction), with the parameter vector ``p``."""
    f = plant.block_fn(K)
    d = data if data is not None else sample_inputs(log, plant.system, plant.m)
    pv = np.asarray(p, dtype=float).reshape(-1, 1)
    m, nb = plant.m, K * plant.m
    n = d["U"].shape[1]
    Xs = np.empty((n + 1, 12))
    Xs[0] = x0
    x = np.asarray(x0, dtype=float).reshape(12, 1)
    empty = np.zeros((0, 1))
    for b in range(0, n, nb):
        e = min(b + nb, n)
        c = _pad(d, b, e, nb)
        X = calls.call(f, x, c["U"], c["W"], c["Q"], c["QD"], c["QDD"], c["payload"], d["h"], empty, pv)[0]
        Xs[b + 1:e + 1] = X[:, : e - b].T
        x = X[:, e - b - 1: e - b]
    return Xs[::m]


def simulate_sens(plant: LogPlant, log, x0: np.ndarray, p: np.ndarray, theta, K: int = DEFAULT_BLOCK,
                  data: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(X (N x 12), dX (N x 12 x (12 + len(free)))): the state and its derivative with respect to [x0; theta],
    with ``p`` whose :attr:`LogPlant.free` entries are ``theta``."""
    f = plant.sens_fn(K)
    d = data if data is not None else sample_inputs(log, plant.system, plant.m)
    th = np.asarray(theta, dtype=float).reshape(-1, 1)
    pv = np.asarray(p, dtype=float).reshape(-1, 1)
    nz = 12 + len(plant.free)
    m, nb = plant.m, K * plant.m
    n = d["U"].shape[1]
    N = n // m + 1
    X = np.empty((N, 12))
    dX = np.empty((N, 12, nz))
    X[0] = x0
    dX[0] = np.eye(12, nz)
    x = np.asarray(x0, dtype=float).reshape(12, 1)
    Sk = np.asfortranarray(np.eye(12, nz))
    for b in range(0, n, nb):  # blocks start on a sample (nb is a multiple of m)
        e = min(b + nb, n)
        c = _pad(d, b, e, nb)
        Xb, Sb = calls.call(f, x, Sk, c["U"], c["W"], c["Q"], c["QD"], c["QDD"], c["payload"], d["h"], th, pv)
        k = e - b
        rows = slice(b // m + 1, e // m + 1)
        X[rows] = Xb[:, m - 1:k:m].T
        dX[rows] = Sb[:, : k * nz].reshape(12, nz, k, order="F")[:, :, m - 1::m].transpose(2, 0, 1)
        x = Xb[:, k - 1:k]
        Sk = np.asfortranarray(Sb[:, (k - 1) * nz: k * nz])
    return X, dX


def _pad(d: dict, b: int, e: int, nb: int) -> dict:
    """The block inputs of steps b..e-1, the last repeated up to nb steps (their outputs are dropped)."""
    out = {}
    k = e - b
    for key in ("U", "W", "payload"):
        a = d[key][:, b:e]
        out[key] = np.concatenate([a, np.repeat(a[:, -1:], nb - k, axis=1)], axis=1) if k < nb else a
    for key in ("Q", "QD", "QDD"):
        a = d[key][:, 3 * b:3 * e]
        if k < nb:
            a = np.concatenate([a, np.tile(a[:, -3:], (1, nb - k))], axis=1) if a.shape[0] else np.zeros((0, 3 * nb))
        out[key] = a
    return out
