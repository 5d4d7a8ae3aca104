"""The open-loop plant driven by a log: one compiled RK4 sample, and blocks of samples.

A log's samples are ``dt = 1 / rate`` apart; the plant takes ``m`` RK4 steps of ``h = dt / m`` per sample
(the system's accuracy-matched step, ``results/step/``, or finer), with

* the body wrench ``tau = B_T(p) u + w`` at every RK4 stage time from the thrust ``u`` (N, per thruster) and
  a logged body wrench ``w`` held over the sample; ``u`` is the logged thrust held over the sample (zero for
  a passive vehicle), or, for a log of thruster commands, the thrust of the system's thruster dynamics
  driven by them (docs/model.md §9: each command held until the next sample, the rotor state's lag in
  closed form at the stage times, the command map's thrust; the rotors start at the steady state of the
  first command). The rotors do not feel the vehicle's motion in this model, so their path is computed
  once per log and parameter value (:func:`rotor_thrust`) and is exact at the stage times;
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

import hashlib
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas.build import calls, codegen
from arvcas.model import manipulator, thrusters, vehicle
from arvcas.model.spatial import J
from arvcas.model.uvms import ModelOptions, coupled_terms
from arvcas.system.params import system_tag, view

__all__ = ["LogPlant", "sample_inputs", "check_log", "check_commands", "rotor_thrust", "rotor_thrust_sens", "DEFAULT_BLOCK"]

DEFAULT_BLOCK = 50  # samples per compiled block (1 s at 50 Hz)
_SOURCE_DIGEST = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]


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
        # this module's own source is part of the key (arvcas.build.provenance.model_hash covers the model
        # and simulation layers, not this one)
        return (f"ident {_SOURCE_DIGEST} {self.opts!r}{system_tag(self.layout.structure)}" +
                (f" free={','.join(free)}" if free else ""))

    def step_fn(self, free: tuple[str, ...] = ()) -> ca.Function:
        """``ident_step(x, u, w, Q, QD, QDD, payload, h, theta, p) -> x_next``: one RK4 step.

        ``u`` (n_thrusters x 3) the thrust and ``Q, QD, QDD`` (n_joints x 3) the joints at the step's stage
        times t, t + h/2, t + h. The parameters
        are ``p`` with the entries ``free`` replaced by ``theta`` (one each), so that derivatives with respect to
        ``theta`` go through those entries only.
        """
        lay = self.layout
        st = lay.structure
        nj, nt = st.n_joints, st.n_thrusters
        x = ca.SX.sym("x", 12)
        u, w = ca.SX.sym("u", nt, 3), ca.SX.sym("w", 6)
        Q, QD, QDD = ca.SX.sym("Q", nj, 3), ca.SX.sym("QD", nj, 3), ca.SX.sym("QDD", nj, 3)
        pl, h = ca.SX.sym("payload"), ca.SX.sym("h")
        theta, p0 = ca.SX.sym("theta", len(free)), ca.SX.sym("p", len(lay))
        pv = [p0[i] for i in range(len(lay))]
        for k, n in enumerate(free):
            pv[lay.index[n]] = theta[k]
        P = view(ca.vertcat(*pv), lay)
        B = thrusters.B_T(P)

        def f(xx, j):
            tau = ca.mtimes(B, u[:, j]) + w
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

    @property
    def thrust_free(self) -> tuple[str, ...]:
        """The free parameters that move the thrust of a commanded log (the thruster dynamics' time constants
        and rate limits, the command maps' numbers): their effect enters the sensitivities through ``dU``."""
        return tuple(n for n in self.free if n.startswith("thrusters.map.") or
                     (n.startswith("thrusters.") and n.rsplit(".", 1)[-1].startswith(("time_constant", "rate_limit"))))

    def _accumulated(self, name: str, n: int, free: tuple[str, ...] | None) -> ca.Function:
        """n RK4 steps chained (``mapaccum``): the state after each, and with ``free`` (not None) its
        sensitivities to [x0; theta] (with ``dU``, d u / d theta of the stage thrusts, when the free
        parameters move the thrust of a commanded log)."""
        lay = self.layout
        nj, nt = lay.structure.n_joints, lay.structure.n_thrusters
        f = self.step_fn(free or ())
        nf = len(free or ())
        with_du = free is not None and bool(self.thrust_free)
        if free is not None:  # forward sensitivities: S_next = A S + [0 B], with z = [x0; theta]
            ins = f.sx_in()
            xn = f(*ins)
            A = ca.jacobian(xn, ins[0])
            B = ca.jacobian(xn, ins[8])
            Sx = ca.SX.sym("S", 12, 12 + nf)
            extra, names = [], []
            if with_du:  # the thrust's own dependence on theta: B + (d x_next / d u) (d u / d theta)
                dU = ca.SX.sym("dU", 3 * nt, nf)
                B = B + ca.mtimes(ca.jacobian(xn, ca.vec(ins[1])), dU)
                extra, names = [dU], ["dU"]
            Sn = ca.mtimes(A, Sx) + ca.horzcat(ca.SX(12, 12), B)
            f = ca.Function("ident_sens", [ins[0], Sx, *ins[1:], *extra], [xn, ca.cse(Sn)],
                            ["x", "S", *_IN[1:], *names], ["x_next", "S_next"])
            acc = f.mapaccum("acc", n, [0, 1], [0, 1])
        else:
            acc = f.mapaccum("acc", n, [0], [0])
        x0 = ca.MX.sym("x0", 12)
        S0 = ca.MX.sym("S0", 12, 12 + nf)
        U, W = ca.MX.sym("U", nt, 3 * n), ca.MX.sym("W", 6, n)
        Q, QD, QDD = (ca.MX.sym(k, nj, 3 * n) for k in ("Q", "QD", "QDD"))
        pl, h = ca.MX.sym("payload", 1, n), ca.MX.sym("h")
        theta, p0 = ca.MX.sym("theta", nf), ca.MX.sym("p", len(lay))
        rest = [U, W, Q, QD, QDD, pl, ca.repmat(h, 1, n), ca.repmat(theta, 1, n), ca.repmat(p0, 1, n)]
        if free is not None:
            dUs = [ca.MX.sym("dU", 3 * nt, nf * n)] if with_du else []
            X, SS = acc(x0, S0, *rest, *dUs)
            return ca.Function(name, [x0, S0, U, W, Q, QD, QDD, pl, h, theta, p0, *dUs], [X, SS],
                               ["x0", "S0", *_BLOCK_IN, *(["dU"] if with_du else [])], ["X", "S"])
        X = acc(x0, *rest)
        return ca.Function(name, [x0, U, W, Q, QD, QDD, pl, h, theta, p0], [X], ["x0", *_BLOCK_IN], ["X"])

    def block_fn(self, K: int = DEFAULT_BLOCK) -> ca.Function:
        """``ident_block(x0, U, W, Q, QD, QDD, payload, h, theta, p) -> X``: K log samples (K m RK4 steps).

        Per step: ``U`` (n_thrusters x 3: the stage times), ``W`` (6), ``Q, QD, QDD`` (n_joints x 3: the stage times t, t + h/2,
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
        du = " dU" if self.thrust_free else ""
        return codegen.build_described("ident_sens_block", f"{self._tag(self.free)} n={n} sens{du}",
                                       lambda: self._accumulated("ident_sens_block", n, self.free), opt_level="-O1")


_IN = ["x", "u", "w", "Q", "QD", "QDD", "payload", "h", "theta", "p"]
_BLOCK_IN = ["U", "W", "Q", "QD", "QDD", "payload", "h", "theta", "p"]


def _check_K(K) -> None:
    if not isinstance(K, int) or isinstance(K, bool) or not 1 <= K <= 10_000:
        raise ValueError(f"block length must be an integer in [1, 10000], got {K!r}")


def check_log(log, system) -> None:
    """Every mismatch between ``system`` and ``log``, refused in one line before any compile
    (:class:`arvcas.ident.logs.LogError`): the joints the log maps (every joint of the system's arm, or none
    for a system without an arm), the thrusters it names, and its commands (:func:`check_commands`)."""
    from arvcas.ident.logs import LogError

    st = system.layout.structure
    nj = st.n_joints
    mapped = tuple(log.joints.names) if log.joints is not None else ()
    want = tuple(f"q{k}" for k in range(1, nj + 1))
    if nj and not mapped:
        raise LogError(f"{log.path}: {system.name} has an arm of {nj} joints but the log maps none: map "
                       f"{', '.join(want)} (a [[stream]]'s joints), or validate against a system without an arm")
    if mapped and not nj:
        raise LogError(f"{log.path}: joints.{mapped[0]}: {system.name} has no arm, but the log maps joints "
                       f"{', '.join(mapped)}: remove them from the mapping, or use a system with an arm")
    if mapped and sorted(mapped) != sorted(want):
        other = sorted(set(mapped) ^ set(want))
        raise LogError(f"{log.path}: joints.{other[0]}: {system.name} has joints {', '.join(want)}, the log maps "
                       f"{', '.join(mapped)} (map every joint or none)")
    names = tuple(st.thrusters or ())
    for kind in ("thrust", "command"):
        for tn in (getattr(log, kind, None) or {}):
            if tn not in names:
                raise LogError(f"{log.path}: {kind}.{tn}: {system.name} has no thruster {tn!r} (it has "
                               f"{', '.join(names) or 'a fixed layout, whose thrust is not logged by name'})")
    check_commands(log, system)


def check_commands(log, system) -> None:
    """A log of thruster commands needs a system with thruster dynamics, each command in its map's unit and
    within its map's range: :class:`arvcas.ident.logs.LogError` (one line naming the log and the thruster)."""
    from arvcas.ident.logs import LogError

    if not log.command:
        return
    st = system.layout.structure
    if not st.has_thruster_dynamics:
        raise LogError(f"{log.path}: command.{next(iter(log.command))}: {system.name} has no thruster dynamics "
                       f"(no command map): map the thrusters' thrust instead, or describe their command maps "
                       f"(docs/system-file.md [thrusters.map.<name>])")
    P = view(ca.DM(system.params.vector()), system.layout)
    names = tuple(st.thrusters or ())
    for tn, c in log.command.items():
        m = st.thruster_map(st.thruster_dynamics[names.index(tn)].map)
        if log.command_unit[tn] != m.unit:
            raise LogError(f"{log.path}: command.{tn}.unit: {log.command_unit[tn]!r}, but its map {m.name} takes "
                           f"commands in {m.unit!r}")
        s_lo, s_hi = (float(ca.DM(v)) for v in thrusters.map_range(P, m))
        c_lo, c_hi = (float(ca.DM(thrusters.command_of(P, m, v))) for v in (s_lo, s_hi))
        bad = np.flatnonzero((c < c_lo - 1e-9) | (c > c_hi + 1e-9))
        if bad.size:
            raise LogError(f"{log.path}: command.{tn}: {c[bad[0]]:.6g} {m.unit} at t = {log.t[bad[0]]:.6g} s is "
                           f"outside the range of its map {m.name} ([{c_lo:.6g}, {c_hi:.6g}] {m.unit})")


_ROTOR: dict = {}


def _rotor_fn(system, h: float) -> ca.Function:
    """``rotor(s0, c, p) -> (s_end, S)``: every thruster's rotor state at a step's stage offsets 0, h/2, h
    (``S``: n_thrusters x 3) from ``s0``, with the commands ``c`` held (docs/model.md §9's closed form)."""
    lay = system.layout
    key = (system_tag(lay.structure), float(h))
    f = _ROTOR.get(key)
    if f is None:
        st = lay.structure
        nt = st.n_thrusters
        p = ca.SX.sym("p", len(lay))
        P = view(p, lay)
        s0, c = ca.SX.sym("s0", nt), ca.SX.sym("c", nt)
        maps = thrusters.thruster_maps(P)
        y = ca.vertcat(*[thrusters.state_of(P, m, c[i]) for i, m in enumerate(maps)])
        offs = [0.0, 0.5 * h, h]
        S = thrusters.lag_states(P, s0, y, thrusters.lag_constants(P, offs), offs, h)
        Sm = ca.vertcat(*[ca.horzcat(*row) for row in S])
        f = ca.Function("rotor", [s0, c, p], [Sm[:, 2], Sm], ["s0", "c", "p"], ["s_end", "S"])
        _ROTOR[key] = f
    return f


def rotor_thrust(log, system, m: int, p) -> np.ndarray:
    """The thrust (n_thrusters x 3 steps, N) at every RK4 stage time of a commanded log: the rotors from the
    steady state of the first command, each command held over its sample (m steps), the maps' thrust."""
    st = system.layout.structure
    names = tuple(st.thrusters or ())
    nt, n = st.n_thrusters, len(log.t) - 1
    h = log.dt / m
    pv = np.asarray(p, dtype=float).reshape(-1)
    P = view(ca.DM(pv), system.layout)
    maps = thrusters.thruster_maps(P)
    C = np.zeros((nt, n + 1))
    for i, tn in enumerate(names):
        if tn in log.command:
            C[i] = log.command[tn]
        else:  # not logged: at rest (the middle of its dead band)
            C[i] = float(ca.DM(thrusters.command_of(P, maps[i], 0.0)))
    s0 = np.array([float(ca.DM(thrusters.state_of(P, mp, C[i, 0]))) for i, mp in enumerate(maps)])
    acc = _rotor_fn(system, h).mapaccum("rotor_path", n * m, [0], [0])
    _, S = acc(s0, np.repeat(C[:, :-1], m, axis=1), pv)
    S = np.array(S)  # nt x 3 n m, step-major, stage-minor
    T = np.empty_like(S)
    for i, mp in enumerate(maps):
        if mp.kind == "table":
            g, v, d = (thrusters._np(a) for a in thrusters.map_table(P, mp))
            T[i] = thrusters._pchip_np(g, v, d, S[i])
        else:
            T[i] = np.array(ca.DM(thrusters.map_thrust(P, mp, ca.DM(S[i])))).ravel()
    return T


def rotor_thrust_sens(log, system, m: int, p, free: tuple[str, ...]) -> np.ndarray:
    """d u / d theta of :func:`rotor_thrust` for the parameters ``free`` (3 n_thrusters x len(free) per step,
    steps side by side: (3 nt) x (len(free) steps)), by central differences (relative step 1e-6; the
    rotor path is a smooth closed form of its parameters away from a table's points)."""
    lay = system.layout
    pv = np.asarray(p, dtype=float).reshape(-1)
    T0 = rotor_thrust(log, system, m, pv)
    nt, k3 = T0.shape
    n = k3 // 3
    out = np.zeros((3 * nt, len(free), n))
    for j, name in enumerate(free):
        i = lay.index[name]
        dh = 1e-6 * max(abs(pv[i]), 1e-3)
        a, b = pv.copy(), pv.copy()
        a[i] += dh
        b[i] -= dh
        d = (rotor_thrust(log, system, m, a) - rotor_thrust(log, system, m, b)) / (2 * dh)  # nt x 3n
        # rows in the order of vec(u) for u (nt x 3): thruster i at stage j is row i + nt j
        out[:, j, :] = d.reshape(nt, n, 3).transpose(0, 2, 1).reshape(3 * nt, n, order="F")
    return out.reshape(3 * nt, len(free) * n, order="F")


def sample_inputs(log, system, m: int, thrust_names=None, p=None) -> dict[str, np.ndarray]:
    """The block inputs of every RK4 step over ``log`` (m steps per sample, (N - 1) m steps in all).

    ``U`` (n_thrusters x 3 steps: the thrust at each step's stage times; zero where not logged; a logged
    thrust held over its sample, a logged command's thrust from :func:`rotor_thrust` with the parameters
    ``p``, default the system's) and ``W`` (6 x steps), held over each sample; ``Q, QD, QDD`` (n_joints x 3
    steps): the joint splines at each step's stage times; ``payload`` (1 x steps); ``h`` = dt / m.
    """
    st = system.layout.structure
    nj, nt = st.n_joints, st.n_thrusters
    names = thrust_names if thrust_names is not None else tuple(st.thrusters or ())
    n = len(log.t) - 1
    h = log.dt / m
    if getattr(log, "command", None):
        check_commands(log, system)
        U3 = rotor_thrust(log, system, m, system.params.vector() if p is None else p)
    else:
        U = np.zeros((nt, n))
        for i, tn in enumerate(names):
            if tn in log.thrust:
                U[i] = log.thrust[tn][:-1]
        U3 = np.repeat(U, 3 * m, axis=1)
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
    return {"U": U3, "W": rep(W), "Q": Q, "QD": QD, "QDD": QDD, "payload": rep(pl), "h": np.array([[h]]),
            "m": m}


def simulate(plant: LogPlant, log, x0: np.ndarray, p: np.ndarray, K: int = DEFAULT_BLOCK,
             data: dict | None = None) -> np.ndarray:
    """The open-loop state (N x 12) on the log's time base from ``x0`` at t_0 (simulation error, not
    prediction), with the parameter vector ``p``."""
    f = plant.block_fn(K)
    d = data if data is not None else sample_inputs(log, plant.system, plant.m)
    pv = np.asarray(p, dtype=float).reshape(-1, 1)
    m, nb = plant.m, K * plant.m
    n = d["W"].shape[1]  # steps
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
    n = d["W"].shape[1]  # steps
    N = n // m + 1
    X = np.empty((N, 12))
    dX = np.empty((N, 12, nz))
    X[0] = x0
    dX[0] = np.eye(12, nz)
    x = np.asarray(x0, dtype=float).reshape(12, 1)
    Sk = np.asfortranarray(np.eye(12, nz))
    nf = len(plant.free)
    du = None
    if plant.thrust_free:  # d u / d theta per step; zero for a log whose thrust the parameters do not move
        du = d.get("dU")
        if du is None:
            du = np.zeros((d["U"].shape[0], nf * n))
    for b in range(0, n, nb):  # blocks start on a sample (nb is a multiple of m)
        e = min(b + nb, n)
        c = _pad(d, b, e, nb)
        extra = ()
        if du is not None:
            a = du[:, b * nf:e * nf]
            if e - b < nb:
                a = np.concatenate([a, np.tile(a[:, -nf:], (1, nb - (e - b)))], axis=1)
            extra = (a,)
        Xb, Sb = calls.call(f, x, Sk, c["U"], c["W"], c["Q"], c["QD"], c["QDD"], c["payload"], d["h"], th, pv,
                            *extra)
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
    for key in ("W", "payload"):
        a = d[key][:, b:e]
        out[key] = np.concatenate([a, np.repeat(a[:, -1:], nb - k, axis=1)], axis=1) if k < nb else a
    for key in ("U", "Q", "QD", "QDD"):
        a = d[key][:, 3 * b:3 * e]
        if k < nb:
            a = np.concatenate([a, np.tile(a[:, -3:], (1, nb - k))], axis=1) if a.shape[0] else np.zeros((0, 3 * nb))
        out[key] = a
    return out
