"""The scenario's prescribed signals (docs/model.md §4, §10): the arm's joint trajectory and its payload, the
disturbance of eq. 41, the water's current and tether, and the sensor noise.

The scenario file, its checks and the loaded :class:`arvcas.sim.scenario.ScenarioConfig` are
:mod:`arvcas.sim.scenario`; this module holds what the run evaluates from them. The functions of time work
on CasADi types (and on numbers), so the compiled closed loop evaluates them inside its time loop, and the
run's time table (:mod:`arvcas.sim.schedule`) tabulates their time-only terms once per run;
:func:`noise_sequence` draws the noise a run is fed, from its seed.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from arvcas.sim.scenario import ScenarioConfig, ScenarioError, n_samples

__all__ = ["quintic", "has_arm_motion", "joint_trajectory", "payload_profile", "disturbance", "disturbance_tabulated",
           "current_at", "tether_of", "noise_sequence"]


def quintic(t, t0: float, t1: float):
    """Rest-to-rest quintic blend s(t) in [0, 1] with zero end velocity and acceleration.

    Returns (s, s_dot, s_ddot); constant outside [t0, t1].
    """
    T = t1 - t0
    tau = ca.fmin(ca.fmax((t - t0) / T, 0), 1)
    inside = ca.logic_and(t > t0, t < t1)
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    sd = ca.if_else(inside, 30 * tau**2 * (1 - tau) ** 2 / T, 0)
    sdd = ca.if_else(inside, 60 * tau * (1 - tau) * (1 - 2 * tau) / T**2, 0)
    return s, sd, sdd


def has_arm_motion(cfg: ScenarioConfig) -> bool:
    """Whether the scenario moves the arm (the paper's keys or waypoints); without, the arm holds its stow
    pose and no payload is carried (a scenario for a system without an arm has no ``[arm]`` section)."""
    return cfg.arm_waypoint is not None or cfg.arm_qg is not None


def joint_trajectory(cfg: ScenarioConfig, q0, t):
    """q, qd, qdd of the scenario's arm motion from the stow pose ``q0``.

    The paper's form (docs/model.md §4): hold q0, quintic to qg, hold, quintic back to q0, hold.
    Waypoints: hold q0 until the first waypoint, then a rest-to-rest quintic between consecutive
    waypoints (``q = w_1 + sum_k (w_{k+1} - w_k) s_k(t)``), hold after the last.
    """
    if not has_arm_motion(cfg):  # no [arm]: hold the stow pose
        return q0, 0 * q0, 0 * q0
    if cfg.arm_waypoint is not None:
        ws = [q0 if w.stow else ca.DM(w.q) for w in cfg.arm_waypoint]
        q, qd, qdd = ws[0], 0 * q0, 0 * q0
        for k in range(1, len(ws)):
            s, sd, sdd = quintic(t, cfg.arm_waypoint[k - 1].t, cfg.arm_waypoint[k].t)
            dq = ws[k] - ws[k - 1]
            q, qd, qdd = q + dq * s, qd + dq * sd, qdd + dq * sdd
        return q, qd, qdd
    qg = ca.DM(cfg.arm_qg)
    s1, sd1, sdd1 = quintic(t, cfg.arm_hold_until, cfg.arm_reach_end)
    s2, sd2, sdd2 = quintic(t, cfg.arm_return_start, cfg.arm_return_end)
    dq = qg - q0
    q = q0 + dq * (s1 - s2)
    qd = dq * (sd1 - sd2)
    qdd = dq * (sdd1 - sdd2)
    return q, qd, qdd


def payload_profile(cfg: ScenarioConfig, t):
    """Payload fraction in [0, 1]: the paper's linear ramp over [payload_on, payload_on + payload_ramp]
    (section 4.2), or the scenario's events, each ramping linearly to its ``to`` over [t, t + ramp]."""
    if not has_arm_motion(cfg):
        return 0 * t
    if cfg.arm_waypoint is not None:
        frac, prev = 0, 0.0
        for e in cfg.payload_event or ():
            frac = frac + (e.to - prev) * ca.fmin(ca.fmax((t - e.t) / e.ramp, 0), 1)
            prev = e.to
        return frac
    return ca.fmin(ca.fmax((t - cfg.arm_payload_on) / cfg.arm_payload_ramp, 0), 1)


def disturbance(cfg: ScenarioConfig, t, phase):
    """tau_u(t) of eq. 41 in {b}: offset + amplitude sin(freq t + phase); ``phase`` is a 6-vector input."""
    off, amp, w = ca.DM(cfg.disturbance_offset), ca.DM(cfg.disturbance_amplitude), ca.DM(cfg.disturbance_freq)
    return off + amp * ca.sin(w * t + phase)


def disturbance_tabulated(cfg: ScenarioConfig, dist_sin, dist_cos, phase_cs):
    """eq. 41 from tabulated ``sin(freq t)``, ``cos(freq t)`` and ``phase_cs = [cos(phase); sin(phase)]``.

    ``sin(w t + phase) = sin(w t) cos(phase) + cos(w t) sin(phase)``: the run tabulates the time part
    once (:mod:`arvcas.sim.schedule`) and the phase part once per run.
    """
    off, amp = ca.DM(cfg.disturbance_offset), ca.DM(cfg.disturbance_amplitude)
    return off + amp * (dist_sin * phase_cs[0:6] + dist_cos * phase_cs[6:12])


def _ramps(xs, fs, x):
    """Piecewise-linear ``f(x)`` through the points ``(xs[i], fs[i])``, held beyond the ends (symbolic xs)."""
    out = fs[0]
    for i in range(len(xs) - 1):
        out = out + (fs[i + 1] - fs[i]) * ca.fmin(ca.fmax((x - xs[i]) / (xs[i + 1] - xs[i]), 0), 1)
    return out


def current_at(cfg: ScenarioConfig, water, t, z):
    """``(v_c, dv_c/dt, dv_c/dz)`` of the scenario's current at time ``t`` and depth ``z`` (3-vectors in {n};
    the rates None for a constant current), from the run's ``water`` input; None without a current.

    A table is bilinear in time and depth (the current's value is linear between its points, held beyond the
    first and last time and depth); its rates are those of the cell the point is in.
    """
    if cfg.current == "none":
        return None
    if cfg.current == "constant":
        return water[0:3], None, None
    ts, zs = cfg.current_grid
    nt, nz = len(ts), len(zs)
    T = [water[i] for i in range(nt)]
    Z = [water[nt + j] for j in range(nz)]
    V = [[water[nt + nz + 3 * (i * nz + j): nt + nz + 3 * (i * nz + j) + 3] for j in range(nz)] for i in range(nt)]
    tt, zz = ca.SX.sym("t"), ca.SX.sym("z")
    by_depth = [_ramps(T, [V[i][j] for i in range(nt)], tt) if nt > 1 else V[0][j] for j in range(nz)]
    v = _ramps(Z, by_depth, zz) if nz > 1 else by_depth[0]
    dt = ca.jacobian(v, tt) if nt > 1 else None
    dz = ca.jacobian(v, zz) if nz > 1 else None
    outs = [x for x in (v, dt, dz) if x is not None]
    if any(isinstance(x, ca.SX) for x in (water, t, z)):
        vals = ca.substitute(outs, [tt, zz], [ca.SX(t), ca.SX(z)])
    else:
        vals = ca.Function("current", [tt, zz], outs).call([t, z])
    v = vals[0]
    dt = vals[1] if nt > 1 else None
    dz = vals[-1] if nz > 1 else None
    return v, dt, dz


def tether_of(cfg: ScenarioConfig, water):
    """``(attachment, length, diameter, Cn, pull)`` of the scenario's tether from the ``water`` input, or None."""
    if not cfg.has_tether:
        return None
    k = {"none": 0, "constant": 3}.get(cfg.current)
    if k is None:
        ts, zs = cfg.current_grid
        k = len(ts) + len(zs) + 3 * len(ts) * len(zs)
    return water[k:k + 3], water[k + 3], water[k + 4], water[k + 5], water[k + 6:k + 9]


def noise_sequence(cfg: ScenarioConfig, seed: int, n: int | None = None) -> np.ndarray:
    """Sensor noise for samples k = 0..N, shape (12, N+1): seeded ``numpy.random.default_rng(seed)``."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise ScenarioError(f"seed: must be an integer with 0 <= seed < 2**63 (result files store it as int64), "
                            f"got {seed!r}")
    n = n_samples(cfg) if n is None else n
    rng = np.random.default_rng(int(seed))
    std = np.sqrt(cfg.sensor_variances)
    return (rng.standard_normal((n, 12)) * std).T.copy()
