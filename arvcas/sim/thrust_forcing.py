"""The thrusters' forcing within one controller sample (docs/model.md §9): the lag's closed form at the
sample's stage times or quadrature nodes, the table maps' inverse and cubic on it, the body wrench (or the
forcing's moments) the plant steps take, and the command map the exported controller sends.

Where the cut lies: what needs only a parameter view and CasADi (the maps, the lag's closed form, the table
lookups) is the model (:mod:`arvcas.model.thrusters`, :mod:`arvcas.model.thruster_tables`); what reads the
scenario's time step, plant step and ``time.thrust_quadrature`` is here: the offsets at which the rotor
states are evaluated (:func:`lag_offsets`), the quadrature's weights (:func:`moment_weights`) and the plant
step that takes the forcing out of RK4's stages by them (:func:`substep_quadrature`: the two share the
moments' layout), the per-run constants (:func:`thruster_constants`), the sample's SX functions
(:func:`thruster_functions`) and their MX composition (:func:`thruster_step`). The closed loop
(:mod:`arvcas.sim.closedloop`) and the lockstep run (:mod:`arvcas.sim.lockstep`) call them.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from arvcas.model import hydro, thrusters
from arvcas.model.linalg import lu_solve
from arvcas.model.spatial import J
from arvcas.model.thruster_tables import IV, pchip_interval, pchip_newton, stage_intervals, table_grids, target_intervals
from arvcas.sim import schedule
from arvcas.sim.scenario import ScenarioConfig
from arvcas.system.params import view

__all__ = ["stage_offsets", "quadrature", "lag_offsets", "N_MOMENTS", "moment_weights", "substep_quadrature",
           "thruster_constants", "constant_sizes", "constants_function", "tau_size", "tau_stride",
           "thruster_functions", "thruster_step", "command_functions"]


def stage_offsets(cfg: ScenarioConfig) -> list[float]:
    """The times of a sample's RK4 stages after its start, ``j h_plant / 2`` (the last one is ``h``)."""
    return [j * 0.5 * cfg.time_h_plant for j in range(schedule.n_stages(cfg))]


def quadrature(cfg: ScenarioConfig) -> int | None:
    """Gauss-Legendre nodes per half plant step for the thrusters' forcing (``time.thrust_quadrature``), or None."""
    return cfg.time_thrust_quadrature or None


def lag_offsets(cfg: ScenarioConfig) -> list[float]:
    """The times after a sample's start at which the thrusters' rotor states and thrust are evaluated: RK4's
    stage times (:func:`stage_offsets`), or with ``time.thrust_quadrature`` the Gauss-Legendre nodes of every
    half plant step in order, then the sample's end (docs/model.md §9)."""
    ng = quadrature(cfg)
    if ng is None:
        return stage_offsets(cfg)
    gx = hydro.leggauss(ng)[0]
    hp = cfg.time_h_plant
    out = [float(i * hp + j * 0.5 * hp + 0.25 * hp * (x + 1)) for i in range(cfg.substeps) for j in range(2) for x in gx]
    return out + [stage_offsets(cfg)[-1]]


N_MOMENTS = 12  # per plant step: (w(hp/2), w(hp), omega(hp/2), omega(hp)) x the three stage records' A


def moment_weights(cfg: ScenarioConfig) -> np.ndarray:
    """(nodes, 12 substeps) weights of the thrusters' forcing moments (:func:`substep_quadrature`).

    Within plant step i (start a, length hp), ``A(t) = (M + M_arm(q(t)))^-1`` is the quadratic through its
    values A_j at the stage times a, a + hp/2, a + hp (Lagrange basis l_j), so
    ``w(tau) = int_a^tau A B F dt = sum_j A_j B int_a^tau l_j F dt`` and ``omega(tau) = int_a^tau w =
    sum_j A_j B int_a^tau (tau - t) l_j F dt``; column ``12 i + 3 k + j`` holds node weights of
    ``int l_j F`` for k = 0: w(a + hp/2), 1: w(a + hp), 2: omega(a + hp/2), 3: omega(a + hp)."""
    ng, hp, n_sub = quadrature(cfg), cfg.time_h_plant, cfg.substeps
    gx, gw = hydro.leggauss(ng)
    C = np.zeros((2 * ng * n_sub, N_MOMENTS * n_sub))
    ts = (0.0, 0.5 * hp, hp)  # stage times, relative to a step's start
    for i in range(n_sub):
        for half in range(2):
            for q in range(ng):
                row = (2 * i + half) * ng + q
                t = half * 0.5 * hp + 0.25 * hp * (gx[q] + 1)  # relative to the step's start
                wq = 0.25 * hp * gw[q]
                for j in range(3):
                    lj = np.prod([(t - ts[m]) / (ts[j] - ts[m]) for m in range(3) if m != j])
                    if half == 0:
                        C[row, N_MOMENTS * i + j] = wq * lj
                        C[row, N_MOMENTS * i + 6 + j] = wq * lj * (0.5 * hp - t)
                    C[row, N_MOMENTS * i + 3 + j] = wq * lj
                    C[row, N_MOMENTS * i + 9 + j] = wq * lj * (hp - t)
    return C


def thruster_constants(P, cfg: ScenarioConfig):
    """Per-run constants of the thruster dynamics, from p: the lag's ``exp(-t / tau)`` at the stage offsets
    (:func:`arvcas.model.thrusters.lag_constants`) and each table map's rotor-state grid, thrust and slopes
    (:func:`arvcas.model.thrusters.map_table`). ``(E, tables)``."""
    E = thrusters.lag_constants(P, lag_offsets(cfg))
    tabs = [ca.vertcat(*thrusters.map_table(P, m)) for m in P.s.thruster_maps if m.kind == "table"]
    return E, (ca.vertcat(*tabs) if tabs else ca.DM.zeros(0, 1))


def constant_sizes(cfg: ScenarioConfig, lay) -> tuple[int, int] | None:
    """Sizes of the thruster dynamics' per-run constants (E, tables), None without dynamics."""
    if not lay.structure.has_thruster_dynamics:
        return None
    P = view(ca.SX.sym("p", len(lay)), lay)
    E, tabs = thruster_constants(P, cfg)
    return E.shape[0], tabs.shape[0]


def constants_function(cfg: ScenarioConfig, lay) -> ca.Function:
    """``thruster_constants(p) -> (E, tables)``: :func:`thruster_constants` as a function of the parameter vector."""
    p = ca.SX.sym("p", len(lay))
    return ca.Function("thruster_constants", [p], list(thruster_constants(view(p, lay), cfg)))


def tau_size(cfg: ScenarioConfig, st) -> int:
    """The thrusters' input of one plant step: the held wrench (6), the wrench at its three stage times (18),
    or with ``time.thrust_quadrature`` the forcing's moments (6 x 12, :func:`moment_weights`)."""
    if not st.has_thruster_dynamics:
        return 6
    return 6 * N_MOMENTS if quadrature(cfg) is not None else 18


def tau_stride(cfg: ScenarioConfig) -> int:
    """Where plant step i's thrusters' input starts in the sample's wrench vector, divided by i: the stage
    wrenches overlap (12: a step's last stage is the next one's first), the moments do not."""
    return 6 * N_MOMENTS if quadrature(cfg) is not None else 12


def substep_quadrature(hp, xs, mom, recs, accel):
    """One plant step with the thrusters' forcing taken out of the RK4 stages (docs/model.md §9).

    The forcing enters the velocities linearly, ``nu_dot = A(t) (B F(t) + R(eta, nu, t))`` with
    ``A = (M + M_arm(q(t)))^-1`` known at the stage times (the time table's LU factors in ``recs``), so RK4
    integrates ``z = nu - w(t)`` and ``zeta = eta - J(eta_a) omega(t)``: ``z_dot = A R(eta, z + w, t)``,
    ``zeta_dot = J(eta) (z + w) - J(eta_a) w``, with ``w`` and ``omega`` from the moments ``mom`` (6 x 12, the
    quadrature of the lag's closed form through the map: :func:`moment_weights`). ``accel(eta, nu, j, rec,
    None)``: ``A R`` at stage j (:func:`arvcas.sim.closedloop._plant_substep`'s, without the thrusters' wrench)."""
    def moment(k):  # sum_j A_j (B int l_j F): w(hp/2), w(hp), omega(hp/2), omega(hp)
        return sum(lu_solve(*recs[j]["lu"], mom[6 * (3 * k + j):6 * (3 * k + j) + 6]) for j in range(3))

    w1, w2, o1, o2 = (moment(k) for k in range(4))
    Ja = J(xs[0:6])
    zero = ca.SX.zeros(6)

    def g(zz, j, w, om):
        ee, nn = zz[0:6] + ca.mtimes(Ja, om), zz[6:12] + w
        return ca.vertcat(ca.mtimes(J(ee), nn) - ca.mtimes(Ja, w), accel(ee, nn, j, recs[j], None))

    k_1 = g(xs, 0, zero, zero)
    k_2 = g(xs + 0.5 * hp * k_1, 1, w1, o1)
    k_3 = g(xs + 0.5 * hp * k_2, 1, w1, o1)
    k_4 = g(xs + hp * k_3, 2, w2, o2)
    z = xs + hp / 6 * (k_1 + 2 * k_2 + 2 * k_3 + k_4)
    return ca.vertcat(z[0:6] + ca.mtimes(Ja, o2), z[6:12] + w2)


def thruster_functions(cfg: ScenarioConfig, lay):
    """The SX parts of a sample's thruster dynamics (docs/model.md §9): ``(cl_thr_lag, cl_thr_wrench,
    cl_thr_lag_iv, cl_thr_wrench_iv)``.

    ``cl_thr_lag(s0, u, y_tab, E, p) -> (s, command)``: each rotor state's target (a table map's from
    ``y_tab``, the inverse computed in MX; a quadratic map's here), the lag's closed form at every stage
    offset of the sample (``s``: thruster-major, n_thr x n_stages) and the command sent;
    ``cl_thr_wrench(T_tab, s, p) -> (W, T_end)``: each thruster's thrust at the stages (a table map's from
    ``T_tab``, evaluated in MX), the thrusters' body wrench at each stage (6 x n_stages, stage-major; with
    the thrust quadrature, the forcing's moments) and the thrust at the sample's end. The scalar run
    evaluates the tables' cubics element by element in MX (:func:`thruster_step`: loops over the
    sample's 808 points that the compiler vectorises, faster there than the same operations as
    straight-line SX).

    The ``_iv`` forms take the tables' intervals instead (:data:`arvcas.model.thruster_tables.IV`: ``ig0..id1`` per thruster at ``u``,
    ``g0..d1`` at each of ``s``, 0 for a thruster without a table) and evaluate the inverse's Newton steps
    and the cubics themselves in SX, with the same operations: the lockstep run rewrites them to lanes
    (:mod:`arvcas.sim.lockstep`), gathering the intervals in C.
    """
    st = lay.structure
    n, offs = st.n_thrusters, lag_offsets(cfg)
    m_off = len(offs)
    p_s = ca.SX.sym("p", len(lay))
    P = view(p_s, lay)
    maps = thrusters.thruster_maps(P)
    s0, u, y_tab = ca.SX.sym("s0", n), ca.SX.sym("u", n), ca.SX.sym("y_tab", n)
    E = ca.SX.sym("E", thrusters.lag_constants(P, offs).shape[0])
    y = ca.vertcat(*[y_tab[i] if m.kind == "table" else thrusters.map_inverse(P, m, u[i]) for i, m in enumerate(maps)])
    S = thrusters.lag_states(P, s0, y, E, offs, cfg.time_h)
    cmd = ca.vertcat(*[thrusters.command_of(P, m, y[i]) for i, m in enumerate(maps)])
    lag = ca.Function("cl_thr_lag", [s0, u, y_tab, E, p_s], [ca.vertcat(*[ca.vertcat(*row) for row in S]), cmd],
                      ["s0", "u", "y_tab", "E", "p"], ["s", "command"])
    s_all, T_tab = ca.SX.sym("s", n * m_off), ca.SX.sym("T_tab", n * m_off)
    T = [[T_tab[i * m_off + j] if m.kind == "table" else thrusters.map_thrust(P, m, s_all[i * m_off + j])
          for j in range(m_off)] for i, m in enumerate(maps)]
    B = thrusters.B_T(P)
    if quadrature(cfg) is None:  # the wrench at every stage
        W = ca.vertcat(*[ca.mtimes(B, ca.vertcat(*[T[i][j] for i in range(n)])) for j in range(m_off)])
    else:  # per plant step, the forcing's 12 moments (6 x 12, column-major): B (T at the nodes) C
        Tn = ca.vertcat(*[ca.horzcat(*T[i][:m_off - 1]) for i in range(n)])  # n x nodes (the sample's end left out)
        C = moment_weights(cfg)
        W = ca.vertcat(*[ca.vec(ca.mtimes(B, ca.mtimes(Tn, ca.DM(C[:, N_MOMENTS * i:N_MOMENTS * (i + 1)]))))
                         for i in range(cfg.substeps)])
    wrench = ca.Function("cl_thr_wrench", [T_tab, s_all, p_s], [W, ca.vertcat(*[T[i][-1] for i in range(n)])],
                         ["T_tab", "s", "p"], ["W", "T_end"])
    iu = [ca.SX.sym("i" + k, n) for k in IV]
    lag_iv = ca.Function("cl_thr_lag_iv", [s0, u, *iu, E, p_s], lag(s0, u, pchip_newton(*iu, u), E, p_s),
                         ["s0", "u", *("i" + k for k in IV), "E", "p"], ["s", "command"])
    iv = [ca.SX.sym(k, n * m_off) for k in IV]
    wrench_iv = ca.Function("cl_thr_wrench_iv", [*iv, s_all, p_s], wrench(thrusters.hermite(*iv, s_all), s_all, p_s),
                            [*IV, "s", "p"], ["W", "T_end"])
    return lag, wrench, lag_iv, wrench_iv


def thruster_step(cfg: ScenarioConfig, st, lag: ca.Function, wrench: ca.Function, u, s0, E, tabs, p):
    """One sample of the thruster dynamics in MX: the intervals of the inverse maps (a search on the table's
    values) and the inverse's Newton steps, the lag (SX), the intervals at every stage (one division each on
    a uniform grid) and the maps' cubics element by element, the wrenches (SX). Returns ``(W (6 n_stages), s_end, T_end, command)``."""
    n, m_off = st.n_thrusters, len(lag_offsets(cfg))
    _, grids = table_grids(st, tabs)
    s_all, cmd = lag(s0, u, pchip_newton(*target_intervals(st, grids, u), u), E, p)
    W, T_end = wrench(thrusters.hermite(*stage_intervals(st, grids, s_all, m_off), s_all), s_all, p)
    s_end = ca.vertcat(*[s_all[(i + 1) * m_off - 1] for i in range(n)])
    return W, s_end, T_end, cmd


def command_functions(cfg: ScenarioConfig, layout, prefix: str = "") -> dict[str, ca.Function]:
    """The thruster command map of the controller (docs/model.md §9), for ``arvcas export-controller``: the
    command each thruster is sent for its saturated thrust, in the map's unit (PWM µs, normalised, rad/s),
    computed as the run computes its ``command`` (:func:`thruster_step`: the same helpers, the same order).

    * ``thr_tab(p) -> tab``: each table map's rotor-state grid, thrust and slopes (the run's per-run
      constants, :func:`thruster_constants`), once per init;
    * ``command(u, tab, p) -> command``: the rotor-state target ``y = F^-1(u)`` (a table's cubic inverted in
      MX, :func:`arvcas.model.thruster_tables.pchip_interval`, then :func:`~arvcas.model.thruster_tables.pchip_newton`; the quadratic law's in closed form) and ``command_of(y)``.

    Empty for a system without thruster dynamics (its commands are the thrust itself)."""
    st = layout.structure
    if not st.has_thruster_dynamics:
        return {}
    n = st.n_thrusters
    p = ca.SX.sym("p", len(layout))
    P = view(p, layout)
    tab = thruster_constants(P, cfg)[1]
    maps = thrusters.thruster_maps(P)
    u_s, y_tab = ca.SX.sym("u", n), ca.SX.sym("y_tab", n)
    y = [y_tab[i] if m.kind == "table" else thrusters.map_inverse(P, m, u_s[i]) for i, m in enumerate(maps)]
    cmd_sx = ca.Function(prefix + "command_of", [u_s, y_tab, p],
                         [ca.vertcat(*[thrusters.command_of(P, m, y[i]) for i, m in enumerate(maps)])])
    # a table's inverse: the interval looked up in MX, Newton's method in SX (scalar code: the same operations
    # as the run's MX ones, element by element; tests/test_export_controller.py checks the bits)
    um, tm, pm = ca.MX.sym("u", n), ca.MX.sym("tab", tab.shape[0]), ca.MX.sym("p", len(layout))
    maps_s = [st.thruster_map(d.map) for d in st.thruster_dynamics]
    _, grids = table_grids(st, tm)
    y_tab = [ca.MX(1, 1)] * n
    for name, (g, v, d, _) in grids.items():
        idx = [i for i, m in enumerate(maps_s) if m.name == name]
        iv = [ca.SX.sym(k, len(idx)) for k in ("g0", "g1", "v0", "v1", "d0", "d1", "u")]
        newton = ca.Function(f"{prefix}newton_{name}", iv, [pchip_newton(*iv)])
        uu = ca.vertcat(*[um[i] for i in idx])
        ys = newton(*pchip_interval(g, v, d, uu), uu)
        for r, i in enumerate(idx):
            y_tab[i] = ys[r]
    return {"thr_tab": ca.Function(prefix + "thr_tab", [p], [tab], ["p"], ["tab"]),
            "command": ca.Function(prefix + "command", [um, tm, pm], [cmd_sx(um, ca.vertcat(*y_tab), pm)],
                                   ["u", "tab", "p"], ["command"])}
