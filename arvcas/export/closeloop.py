"""The exported controller closed around the plant: :func:`close_loop`, the check that an
``arvcas export-controller`` package performs the compiled run's controller.

:func:`load_binding` imports a package's ctypes binding (``<lib>.py``, built with its Makefile);
:func:`close_loop` closes it around the exported plant functions (``arvcas export-c``'s ``uvms_rhs``
and ``thrust``, or any given) over a compiled run's scenario, its noise sequence and its time table,
in NumPy, for the tests (tests/test_export_controller.py) and for anyone who wants to see the
equality for themselves (docs/exporting-a-controller.md). :class:`_Rotors` is the thrusters' side of
a plant with thruster dynamics: what a thruster does with the command it is sent.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas.export.controller import WHAT, ExportError
from arvcas.sim.closedloop import RunSpec, arm_truth
from arvcas.sim.scenario import measured

__all__ = ["load_binding", "close_loop"]



def load_binding(out_dir, lib_path=None):
    """The ``<lib>.py`` binding module of an export directory, and a :class:`Controller` of it
    (``lib_path``: the built library, default ``lib<lib>.so`` in the directory)."""
    out = Path(out_dir)
    mods = [p for p in out.glob("*.py") if p.name != "example.py"]
    if len(mods) != 1:
        raise ExportError(f"{out}: expected one <lib>.py binding, found {[p.name for p in mods]}")
    spec = importlib.util.spec_from_file_location(f"_arvcas_binding_{mods[0].stem}", mods[0])
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod, mod.Controller(None if lib_path is None else str(lib_path))


class _Rotors:
    """The thrusters' side of the plant with thruster dynamics (docs/model.md §9), in NumPy: what a thruster
    does with the command it is sent. ``target(command)``: the rotor state it steers to (the command beyond
    the dead band's edge, 0 inside the band); ``stages(s0, y)``: the rotor states at a sample's RK4 stage
    times (the lag's closed form, :func:`arvcas.model.thrusters.lag_states`, with the command held), one
    column per stage; ``thrust(s)``: the steady thrust of rotor states (a table's monotone cubic by
    SciPy's ``PchipInterpolator``, the quadratic law ``k s |s|``)."""

    def __init__(self, P, cfg):
        from scipy.interpolate import PchipInterpolator

        from arvcas.model import thrusters as thr
        from arvcas.sim.thrust_forcing import stage_offsets
        from arvcas.system.params import view

        lay = P.layout
        st = lay.structure
        pv = P.vector()
        Pn = view(ca.DM(pv), lay)
        self.lo, self.hi, self.F = [], [], []
        for d in st.thruster_dynamics:
            m = st.thruster_map(d.map)
            if m.kind == "table":
                i0, i1 = m.zero
                lo, hi = float(Pn[f"thrusters.map.{m.name}.command.{i0}"]), float(Pn[f"thrusters.map.{m.name}.command.{i1}"])
                g, v = (np.array(ca.DM(x), dtype=float).ravel() for x in thr.map_grid(Pn, m))
                self.F.append(PchipInterpolator(g, v, extrapolate=True))
            else:
                hi = float(Pn[f"thrusters.map.{m.name}.dead_band"])
                lo = -hi
                k = float(Pn[f"thrusters.map.{m.name}.rotor_constant"])
                self.F.append(lambda x, k=k: k * x * np.abs(x))
            self.lo.append(lo)
            self.hi.append(hi)
        self.lo, self.hi = np.array(self.lo), np.array(self.hi)
        offs = stage_offsets(cfg)
        p_s, s0, y = ca.SX.sym("p", len(lay)), ca.SX.sym("s0", st.n_thrusters), ca.SX.sym("y", st.n_thrusters)
        Ps = view(p_s, lay)
        S = thr.lag_states(Ps, s0, y, thr.lag_constants(Ps, offs), offs, cfg.time_h)
        self._lag = ca.Function("rotor_stages", [s0, y, p_s], [ca.horzcat(*[ca.vertcat(*row) for row in zip(*S)])])
        self._p = pv

    def target(self, command):
        c = np.asarray(command, dtype=float)
        return np.where(c > self.hi, c - self.hi, np.where(c < self.lo, c - self.lo, 0.0))

    def stages(self, s0, y):
        return np.array(self._lag(s0, y, self._p), dtype=float)

    def thrust(self, s):
        s = np.asarray(s, dtype=float)
        return np.array([F(s[i]) for i, F in enumerate(self.F)], dtype=float)


def _tether_pull(cfg):
    """The wrench (6, {b}, about the body origin) of a tether without a current at the state ``x``: its pull
    ``f`` ({n}) turned into the body frame, ``R(eta)' f``, and its moment ``r_a x R(eta)' f`` (docs/model.md §10;
    R = Rz(psi) Ry(theta) Rx(phi), NumPy)."""
    r_a, f_n = np.array(cfg.tether_attachment, dtype=float), np.array(cfg.tether_pull, dtype=float)

    def wrench(x):
        cf, sf, ct, st, cp, sp = (np.cos(x[3]), np.sin(x[3]), np.cos(x[4]), np.sin(x[4]), np.cos(x[5]), np.sin(x[5]))
        R = np.array([[cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
                      [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
                      [-st, ct * sf, ct * cf]])
        f = R.T @ f_n
        return np.concatenate([f, np.cross(r_a, f)])

    return wrench


def close_loop(controller, run, seed: int = 0, rhs=None, thrust=None, states=None, delivered=None) -> dict:
    """The exported controller closed around the plant over a compiled run's scenario.

    ``controller``: a binding's ``Controller`` (:func:`load_binding`), initialised with the gains to
    compare; ``run``: the :class:`arvcas.sim.run.CompiledRun` whose scenario, system and time table
    are used; ``seed``: the noise sequence (:func:`arvcas.sim.profiles.noise_sequence`), fed in as the
    measurement ``y = x + noise`` (a lagging sensor's components of ``x`` from ``d`` samples ago); ``rhs(x, tau, q, qd, qdd, payload) -> xdot`` and ``thrust(u) ->
    tau``: the exported plant (default: ``arvcas.dynamics("uvms_rhs")`` and ``("thrust")`` of the
    run's system, the compiled C that ``arvcas export-c`` writes). The plant is integrated like the
    run's: ``h / h_plant`` RK4 steps per sample with the thrust held, the arm's motion and the
    disturbance (eq. 41) at the RK4 stage times from the run's time table. A law whose step reads
    ``tau_arm`` gets the true value at the sample computed as in the run
    (:func:`arvcas.sim.closedloop.arm_truth`). ``states``: (N + 1, 12) true states
    ``[eta; nu]`` to measure instead of integrating the plant (a run's own ``eta``, ``nu``: the
    controller then sees exactly the run's measurements).

    With thruster dynamics (docs/model.md §9) the controller's commands (its ``command()``, in the map's
    unit: PWM µs for the T200) drive the rotors (:class:`_Rotors`: the rotor state each command steers to,
    the lag's closed form at the RK4 stage times, the map's thrust by SciPy's PCHIP), and ``thrust(T)`` of
    the rotors' thrust at each stage drives the plant's RK4 stages; the series add ``thrust_cmd`` (the
    controller's thrust), ``command`` and ``tau_delivered``, and ``thrust`` is the delivered thrust at t_k,
    as in the run. ``delivered``: (N + 1, n_thrusters) delivered thrust at t_k to give ``arm_truth`` instead
    of the rotors' (a run's own ``thrust``, for a replay with ``states``).

    A tether (docs/model.md §10) is a wrench on the plant: without a current its drag is zero and it pulls
    with ``pull`` ({n}) at its attachment, ``f_b = R(eta)' pull`` and ``r_a x f_b`` (NumPy, at every RK4
    stage's state), added to the plant's ``tau``. A current is refused: it acts inside the hydrodynamics
    (``D(nu_r) nu_r``, ``C_A(nu_r) nu_r``, ``M_A nu_c_dot``, the links' drag in the relative flow), which the
    exported plant's body-wrench input cannot carry.

    Returns the series of the run's signals that the controller and the plant give (``t``, ``eta``,
    ``nu``, ``eta_hat``, ``eta_ref``, ``tau_cmd``, ``thrust``, ``q``, ``payload`` and the law's own),
    each (N + 1, width), and ``chat``, ``rmse`` (6) as the run computes them (eq. 42-43).
    """
    from arvcas.build.dynamics import dynamics
    from arvcas.sim import profiles, scenario, schedule

    cfg, P = run.cfg, run.params
    if cfg.time_thrust_quadrature:
        raise ExportError(f"{WHAT}: close_loop integrates the exported plant by RK4 with the thrust at its stage times; "
                          f"this run's scenario sets time.thrust_quadrature ({cfg.time_thrust_quadrature}), another "
                          f"integration of the thrusters' forcing (docs/model.md §9); give a scenario without it")
    if cfg.current != "none":
        raise ExportError(f"{WHAT}: close_loop integrates the exported plant (arvcas export-c's uvms_rhs and thrust), "
                          f"which takes a body wrench: a current acts inside its hydrodynamic terms (the relative "
                          f"velocity, docs/model.md §10) and cannot be added to it; give a scenario without [current]")
    tether = _tether_pull(cfg) if cfg.has_tether else None
    dyn = P.structure.has_thruster_dynamics
    if dyn and not getattr(controller, "HAS_COMMAND_MAP", False):
        raise ExportError(f"{WHAT}: close_loop: the run's system has thruster dynamics but the controller has no "
                          f"command map (export it for that system)")
    rotors = _Rotors(P, cfg) if dyn else None
    lay = P.layout
    p = P.vector()
    rhs = rhs or (lambda f: lambda x, tau, q, qd, qdd, pl: f(x, tau, q, qd, qdd, pl))(dynamics("uvms_rhs", P))
    thrust = thrust or dynamics("thrust", P)
    truth = None
    if controller.USES_TAU_ARM:
        truth = arm_truth(RunSpec(run.controller, cfg.graph_key(), run.opts, lay))
    tab = run.table
    R = schedule.records(lay)
    TS, AS = R.time_size, R.arm_size
    sl = R.slices
    n = scenario.n_samples(cfg)
    N = n - 1
    hp, h = cfg.time_h_plant, cfg.time_h
    noise = profiles.noise_sequence(cfg, seed)
    lag = np.zeros(12, dtype=int)  # each component's latency in samples: it reads the state of sample k - lag
    for name, d in scenario.latencies(cfg):
        lag[list(scenario.SENSORS[name])] = d
    past = []  # the true states of the samples so far (before sample 0: the initial state)
    held = np.array(scenario.held_dofs(cfg), dtype=float)
    ph = np.array(cfg.disturbance_phase, dtype=float)
    cos_ph = np.array([math.cos(v) for v in ph])
    sin_ph = np.array([math.sin(v) for v in ph])
    off, amp = np.array(cfg.disturbance_offset, dtype=float), np.array(cfg.disturbance_amplitude, dtype=float)
    water = cfg.water_vector

    def stage(k, j):
        r = tab.time[j * TS:(j + 1) * TS, k]
        dist = off + amp * (r[sl["dist_sin"]] * cos_ph + r[sl["dist_cos"]] * sin_ph)  # eq. 41 (disturbance_tabulated)
        return r[sl["q"]], r[sl["qd"]], r[sl["qdd"]], r[sl["payload"]], dist

    x = np.array(list(cfg.initial_eta0) + list(cfg.initial_nu0) if states is None else states[0], dtype=float)
    n_thr = P.structure.n_thrusters
    u_hold = np.zeros(n_thr)  # the thrust acting at t_k: held, or the rotors' delivered thrust
    s_rot = np.zeros(n_thr)  # the rotor states (at rest)
    names = [name for name, *_ in controller.DIAGNOSTICS]
    series = {k: [] for k in ("t", "eta", "nu", *names, "thrust", "q", "payload")}
    if dyn:
        series.update(thrust_cmd=[], command=[], tau_delivered=[])
    chat_sum, e2_sum, chatd_sum, tau_prev, tdel_prev = np.zeros(6), np.zeros(6), np.zeros(6), None, None
    controller.reset()
    for k in range(n):
        tk = k * h  # the run's t_k
        q, qd, qdd, pl, dist = stage(k, 0)
        tau_arm = None
        if truth is not None:
            u_true = u_hold if delivered is None else np.asarray(delivered[k], dtype=float)
            tau_arm = np.array(truth(x, u_true, tab.time[0:TS, k], tab.arm[0:AS, k], p, ph, water, tk)).ravel()
        past.append(x.copy())
        x_read = np.array([past[max(k - lag[i], 0)][i] for i in range(12)])  # a lagging sensor's reading (docs/sensors.md)
        u = np.array(controller.step([(x_read + noise[:, k])[i] for i, _, _ in measured(cfg)], tk, tau_arm))
        dg = controller.diagnostics()
        tau_v, y1 = np.array(dg["tau_cmd"]), np.array(dg["eta_ref"])
        for name in names:
            series[name].append(dg[name])
        series["t"].append([tk])
        series["eta"].append(x[0:6].copy())
        series["nu"].append(x[6:12].copy())
        if dyn:  # the command drives the rotors; the wrench at every RK4 stage is that of their thrust
            cmd = np.array(controller.command())
            S = rotors.stages(s_rot, rotors.target(cmd))
            T = rotors.thrust(S)  # (n_thr, stages); column 0 is the thrust at t_k
            W = [np.asarray(thrust(T[:, j])).ravel() for j in range(T.shape[1])]
            series["thrust"].append(T[:, 0])
            series["thrust_cmd"].append(u)
            series["command"].append(cmd)
            series["tau_delivered"].append(W[0])
            tau_del = W[0]
        else:
            series["thrust"].append(u)
            tau_del = np.asarray(thrust(u)).ravel()
        series["q"].append(q)
        series["payload"].append(pl)
        e = (x[0:6] - y1) * held  # the error of the DOFs the task holds (docs/sensors.md)
        if k > 0:
            chat_sum = chat_sum + np.abs(tau_v - tau_prev)
            chatd_sum = chatd_sum + np.abs(tau_del - tdel_prev)  # CHAT on the delivered wrench (docs/model.md §6)
        if k < N:
            e2_sum = e2_sum + e**2
        tau_prev, tdel_prev = tau_v, tau_del
        tau_real = tau_del
        for i in range(0 if states is not None else cfg.substeps):
            def f(xx, j):
                qj, qdj, qddj, plj, dj = stage(k, 2 * i + j)
                tr = W[2 * i + j] if dyn else tau_real  # stage 2i + j of the sample
                if tether is not None:
                    tr = tr + tether(xx)
                return np.asarray(rhs(xx, tr + dj, qj, qdj, qddj, plj)).ravel()

            k1 = f(x, 0)
            k2 = f(x + 0.5 * hp * k1, 1)
            k3 = f(x + 0.5 * hp * k2, 1)
            k4 = f(x + hp * k3, 2)
            x = x + hp / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        if dyn:
            s_rot = S[:, -1]
            u_hold = T[:, -1]
        else:
            u_hold = u
        if states is not None and k + 1 < n:
            x = np.array(states[k + 1], dtype=float)
    out = {k: np.array(v, dtype=float) for k, v in series.items()}
    for k in ("t", "payload"):
        out[k] = out[k].reshape(-1)
    out["chat"] = chat_sum / N
    out["rmse"] = np.sqrt(e2_sum / N)
    out["chat_delivered"] = chatd_sum / N
    return out
