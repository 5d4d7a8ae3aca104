"""The reference of benchmarks/step_accuracy.py: the plant integrated by CVODES with the thrust held per sample
(:func:`cvodes_states`), the same plant by textbook RK4 (:func:`rk4_states`), and what they are fed from a traced
run (:func:`plant_inputs`, :func:`held_wrench`). step_accuracy.py, bluerov2_step.py, thruster_step.py and the tests
use it through step_accuracy.py (which loads this file by its path, as they load step_accuracy.py).
"""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np

CVODES_TOL = 1e-14

# ---- the reference: CVODES on the plant with the thrust held per sample ---------------------------------

def _plant_ode(cfg, opts=None, layout=None):
    """(x, s, par, xdot): the plant over one sample, local time ``s`` in [0, h], ``par = [u; t_k; phase (6); water; p]``.

    ``u`` is the held body wrench of the thrusters (6); with thruster dynamics (docs/model.md §9) it is each
    rotor's held target (one per thruster) and the rotor states join ``x`` (12 + n_thrusters), following the
    textbook lag ``ds/dt = clip((y - s) / tau, -r, r)`` (tau the spin-up constant while ``|s|`` grows, the
    spin-down one while it shrinks) through the map's table (CasADi's linear interpolant) or rotor law,
    here integrated with the plant: an independent implementation of the closed loop's closed form.
    ``t = t_k + s``. The right-hand side is the plant with the direct Newton-Euler arm wrench
    (``uvms_xdot``, the function behind ``uvms_rhs``; the trim of docs/model.md §3 at q0), the scenario's
    joint trajectory, payload ramp, eq. 41's disturbance, current and tether as functions of ``t``.
    ``layout``: the system's :class:`arvcas.system.params.Layout` (default Haidou-1's); ``p`` is its parameter vector.
    """
    from arvcas.model import manipulator, thrusters
    from arvcas.model.uvms import ModelOptions, uvms_xdot
    from arvcas.system.params import default_layout, view
    from arvcas.sim import closedloop, profiles

    lay = layout or default_layout()
    st = lay.structure
    dyn = st.has_thruster_dynamics
    npar, nw = len(lay), cfg.water_vector.size
    nu_in = st.n_thrusters if dyn else 6
    x, s, par = ca.SX.sym("x", 12 + (st.n_thrusters if dyn else 0)), ca.SX.sym("s"), ca.SX.sym("par", nu_in + 7 + nw + npar)
    u, tk, ph, w, p = par[0:nu_in], par[nu_in], par[nu_in + 1:nu_in + 7], par[nu_in + 7:nu_in + 7 + nw], par[nu_in + 7 + nw:]
    P = view(p, lay)
    t = tk + s
    q, qd, qdd = profiles.joint_trajectory(cfg, manipulator.stow_pose(P), t)
    pl = profiles.payload_profile(cfg, t)
    extra = []
    if dyn:
        sr = x[12:]
        T, sdot = [], []
        for i, d in enumerate(st.thruster_dynamics):
            m = st.thruster_map(d.map)
            up, down, rate = thrusters.time_constants(P, i)
            tau = ca.if_else(sr[i] * (u[i] - sr[i]) >= 0, up, down)
            v = (u[i] - sr[i]) / tau
            sdot.append(v if rate is None else ca.fmin(ca.fmax(v, -rate), rate))
            T.append(thrusters.map_thrust(P, m, sr[i]))
        wrench = ca.mtimes(thrusters.B_T(P), ca.vertcat(*T))
        extra = [ca.vertcat(*sdot)]
    else:
        wrench = u
    eta, nu = x[0:6], x[6:12]
    current, tether = closedloop._water(cfg, P, w, t, eta, nu) if cfg.has_water else (None, 0)
    xdot = uvms_xdot(P, x[0:12], wrench + profiles.disturbance(cfg, t, ph) + tether, q, qd, qdd, pl, opts or ModelOptions(),
                     current=current)
    return x, s, par, ca.vertcat(xdot, *extra)


def _par_columns(cfg, pv, inputs, phase):
    """The per-sample ``par`` columns for samples k = 0 .. min(len(inputs), N) - 1 (inputs: a row per sample)."""
    n = min(len(inputs), scenario_n(cfg) - 1)
    w = cfg.water_vector
    return np.vstack([np.asarray(inputs, float)[:n].T, (np.arange(n) * cfg.time_h)[None, :],
                      np.tile(np.asarray(phase, float)[:, None], (1, n)), np.tile(w[:, None], (1, n)),
                      np.tile(np.asarray(pv, float)[:, None], (1, n))])


def plant_inputs(pv, r, layout=None) -> np.ndarray:
    """The reference's input per sample of a traced run ``r``: the held wrench of its saturated thrust, or with
    thruster dynamics each rotor's target, the inverse map of the allocation's thrust (``r.thrust_cmd``)."""
    from arvcas.model import thrusters
    from arvcas.system.params import default_layout, view

    lay = layout or default_layout()
    if not lay.structure.has_thruster_dynamics:
        return held_wrench(pv, r.thrust, lay)
    P = view(ca.DM(np.asarray(pv, float)), lay)
    maps = thrusters.thruster_maps(P)
    cmd = np.asarray(r.thrust_cmd, float)  # one inversion per thruster over all its samples (elementwise)
    return np.stack([np.array(thrusters.map_inverse(P, m, ca.DM(cmd[:, i]))).ravel() for i, m in enumerate(maps)],
                    axis=1)


def scenario_n(cfg) -> int:
    from arvcas.sim import scenario

    return scenario.n_samples(cfg)


def held_wrench(pv, thrust, layout=None) -> np.ndarray:
    """Body wrench ``B_T u`` per sample (rows) of the held, saturated thrust ``thrust`` (N+1, n_thrusters);
    ``B_T`` (6 x n_thrusters) of the system of ``layout`` (default Haidou-1)."""
    from arvcas.model import thrusters
    from arvcas.system.params import view

    B = np.array(ca.evalf(thrusters.B_T(view(ca.DM(np.asarray(pv, float)), layout))))
    return np.asarray(thrust, float) @ B.T


def _x0(x0, x):
    """The reference's initial state: the vehicle's, and the rotors at rest (the run's first sample)."""
    x0 = np.asarray(x0, float)
    return np.r_[x0, np.zeros(x.shape[0] - x0.size)]


def cvodes_states(cfg, pv, x0, taus, phase, tol: float = CVODES_TOL, n_samples: int | None = None, opts=None,
                  layout=None):
    """Plant states at t_k, k = 0..n (rows, (n+1, 12)) under the held inputs ``taus[k]`` over [t_k, t_k + h]
    (:func:`plant_inputs`: wrenches, or the rotors' targets with thruster dynamics, whose states are integrated
    with the plant and left out of the rows).

    CVODES (Adams, functional iteration: the plant is not stiff, and the AD Jacobian of the drag term
    is NaN at zero relative velocity), abstol = reltol = ``tol``, restarted at every sample.
    """
    x, F = _reference(cfg, np.asarray(pv, float), tol, opts, layout)
    P = _par_columns(cfg, pv, taus, phase)
    n = P.shape[1] if n_samples is None else int(n_samples)
    X = np.array(F.mapaccum(n)(x0=_x0(x0, x), p=P[:, :n])["xf"]).T
    return np.vstack([_x0(x0, x)[None, :], X])[:, :12]


_REFERENCES: dict = {}  # the integrators built in this process, by everything their ODE is made of


def _reference(cfg, pv, tol, opts, layout):
    """(x, CVODES over one sample) for :func:`cvodes_states`, built once per scenario (any plant step),
    parameters, tolerance, model options and system structure in a process (the plant with a 200-point thrust
    table takes seconds to build).

    The parameters are the same on every sample: numbers in the right-hand side (their arithmetic, the thrust
    table's slopes among it, folded once instead of at every evaluation: about 2.5x faster with the T200 table)."""
    from arvcas.system.params import default_layout

    lay = layout or default_layout()
    # the plant's step and thrust quadrature are the closed loop's, not the reference's: one integrator for all steps
    same = dataclasses.replace(cfg, time_h_plant=cfg.time_h, time_thrust_quadrature=None)
    key = (repr(same), pv.tobytes(), tol, repr(opts), repr(lay.structure), tuple(lay.names))
    if key not in _REFERENCES:
        x, s, par, xdot = _plant_ode(cfg, opts, lay)
        xdot = ca.substitute(xdot, par[par.numel() - pv.size:], ca.DM(pv))
        o = dict(abstol=tol, reltol=tol, max_num_steps=1_000_000, linear_multistep_method="adams",
                 nonlinear_solver_iteration="functional")
        _REFERENCES[key] = x, ca.integrator("ref", "cvodes", {"x": x, "p": par, "t": s, "ode": xdot}, 0.0,
                                            [cfg.time_h], o)
    return _REFERENCES[key]


def rk4_states(cfg, pv, x0, taus, phase, h_plant: float, n_samples: int | None = None, opts=None, layout=None):
    """The textbook RK4 of the same ODE (same held inputs), ``h / h_plant`` steps per sample; (n+1, 12).

    An independent RK4 (no time table, the direct plant function) that checks the reference machinery.
    With thruster dynamics the rotors are not RK4 states: their closed form (docs/model.md §9) gives the
    thrust at every stage, as in the closed loop, here evaluated in NumPy sample by sample.
    """
    from arvcas.system.params import default_layout

    lay = layout or default_layout()
    if lay.structure.has_thruster_dynamics:
        return _rk4_states_lag(cfg, pv, x0, taus, phase, h_plant, n_samples, opts, lay)
    x, s, par, xdot = _plant_ode(cfg, opts, layout)
    f = ca.Function("f", [x, s, par], [xdot])
    m = int(round(cfg.time_h / h_plant))
    assert abs(m * h_plant - cfg.time_h) < 1e-12, "h_plant must divide h"
    xk = x
    for i in range(m):
        si = i * h_plant
        k1 = f(xk, si, par)
        k2 = f(xk + h_plant / 2 * k1, si + h_plant / 2, par)
        k3 = f(xk + h_plant / 2 * k2, si + h_plant / 2, par)
        k4 = f(xk + h_plant * k3, si + h_plant, par)
        xk = xk + h_plant / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    step = ca.Function("rk4_sample", [x, par], [xk])
    P = _par_columns(cfg, pv, taus, phase)
    n = P.shape[1] if n_samples is None else int(n_samples)
    X = np.array(step.mapaccum(n)(_x0(x0, x), P[:, :n])).T
    return np.vstack([_x0(x0, x)[None, :], X])[:, :12]


def _rk4_states_lag(cfg, pv, x0, targets, phase, h_plant, n_samples, opts, lay):
    """:func:`rk4_states` with thruster dynamics: the vehicle's RK4 driven by the wrench ``B F(s(t))`` at its
    stages, ``s(t)`` the lag's closed form from each sample's rotor states towards its ``targets``."""
    from arvcas.model import thrusters
    from arvcas.system.params import layout_for, view

    inst = layout_for(lay.structure.instantaneous())
    pv_inst = np.asarray(pv, float)[[lay.index[n] for n in inst.names]]
    x, s, par, xdot = _plant_ode(cfg, opts, inst)  # the plant with a wrench input
    f = ca.Function("f", [x, s, par], [xdot])
    P = view(ca.DM(np.asarray(pv, float)), lay)
    maps = thrusters.thruster_maps(P)
    B = np.array(ca.DM(thrusters.B_T(P)))
    m = int(round(cfg.time_h / h_plant))
    offs = [j * 0.5 * h_plant for j in range(2 * m + 1)]
    E = thrusters.lag_constants(P, offs)
    n = min(len(targets), scenario_n(cfg) - 1) if n_samples is None else int(n_samples)
    xk, sk = np.asarray(x0, float), np.zeros(len(maps))
    out = [xk]
    # one time constant and no rate limit (the BlueROV2's T200s): s(t) = y + (s0 - y) exp(-t / tau) in NumPy;
    # otherwise the closed form of arvcas.model.thrusters.lag_states, evaluated on numbers
    simple = not any(d.asymmetric or d.rate_limit for d in lay.structure.thruster_dynamics)
    if simple:
        taus = np.array([float(ca.DM(thrusters.time_constants(P, i)[0])) for i in range(len(maps))])
        Es = np.exp(-np.asarray(offs)[None, :] / taus[:, None])
    tables = {m.name: tuple(np.array(ca.DM(a)).ravel() for a in thrusters.map_table(P, m))
              for m in lay.structure.thruster_maps if m.kind == "table"}
    for k in range(n):
        y = np.asarray(targets[k], float)
        if simple:
            srows = y[:, None] + (sk - y)[:, None] * Es
        else:
            S = thrusters.lag_states(P, ca.DM(sk), ca.DM(y), E, offs, cfg.time_h)
            srows = np.array([[float(ca.DM(v)) for v in row] for row in S])  # (n_thr, stages)
        T = np.array([thrusters._pchip_np(*tables[maps[i].name], srows[i]) if maps[i].kind == "table" else
                      np.array(ca.DM(thrusters.map_thrust(P, maps[i], ca.DM(srows[i])))).ravel()
                      for i in range(len(maps))])
        W = B @ T  # (6, stages)
        base = np.r_[k * cfg.time_h, np.asarray(phase, float), cfg.water_vector, pv_inst]
        fx = lambda xx, j: np.array(f(xx, offs[j], np.r_[W[:, j], base])).ravel()  # noqa: E731
        for i in range(m):
            a = 2 * i
            k1 = fx(xk, a)
            k2 = fx(xk + h_plant / 2 * k1, a + 1)
            k3 = fx(xk + h_plant / 2 * k2, a + 1)
            k4 = fx(xk + h_plant * k3, a + 2)
            xk = xk + h_plant / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        sk = srows[:, -1]
        out.append(xk)
    return np.vstack(out)


def _state_err(A, B) -> dict:
    """max |A - B| over samples: positions (m), angles (rad), linear (m/s) and angular (rad/s) rates."""
    d = np.abs(np.asarray(A) - np.asarray(B))
    return {"position_m": float(d[:, 0:3].max()), "angle_rad": float(d[:, 3:6].max()),
            "linear_rate_m_s": float(d[:, 6:9].max()), "angular_rate_rad_s": float(d[:, 9:12].max()),
            "argmax_state": int(np.unravel_index(np.argmax(d[:, 0:6]), d[:, 0:6].shape)[1])}
