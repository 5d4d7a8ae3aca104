"""A scenario checked against a system's limits, before anything is built: every pose of the arm's motion
within its joint limits (:func:`check_joint_limits`), and a vehicle trajectory that asks no thruster for more
than its limit (:func:`check_trajectory_limits`, docs/tasks.md). The scenario's own checks, which need no
system, are :mod:`arvcas.sim.scenario`'s."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from arvcas.sim.scenario import ScenarioConfig, ScenarioError, n_samples

__all__ = ["check_joint_limits", "check_trajectory_limits"]


def check_joint_limits(cfg: ScenarioConfig, params) -> None:
    """Every pose of the motion (the stow pose, qg or each waypoint) has one angle per joint of the
    system and lies within its joint limits (quintics stay between their end poses)."""
    n = params.structure.n_joints
    poses = [("arm.stow (q0)", [params[f"arm.stow.q{i}"] for i in range(1, n + 1)])]
    if cfg.arm_waypoint is not None:
        poses += [(f"arm.waypoint[{j}].q", list(w.q)) for j, w in enumerate(cfg.arm_waypoint, start=1) if not w.stow]
    elif cfg.arm_qg is not None:
        poses.append(("arm.qg", list(cfg.arm_qg)))
    for label, q in poses:
        if len(q) != n:
            raise ScenarioError(f"{cfg.path or 'scenario'}: {label}: {len(q)} joint angles, but system "
                                f"'{params.structure.name}' has {n} joints")
        for i, qi in enumerate(q, start=1):
            lo, hi = params[f"arm.joint{i}.qmin"], params[f"arm.joint{i}.qmax"]
            if not (lo - 1e-12 <= qi <= hi + 1e-12):
                raise ScenarioError(
                    f"{label}: joint {i} target {math.degrees(qi):.2f} deg outside Table 1 limits "
                    f"[{math.degrees(lo):.0f}, {math.degrees(hi):.0f}] deg"
                )


def check_trajectory_limits(cfg: ScenarioConfig, params) -> None:
    """The desired trajectory asks no thruster for more than its limit (docs/tasks.md): at every sample time,
    the wrench that moves the vehicle alone along it in still water, ``M nu_dot + C(nu) nu + D(nu) nu + g(eta)``
    (nu, nu_dot from eta_d and its derivatives), allocated to the thrusters, stays within each thruster's
    [u_min, u_max] (the system file's stated limits). One line naming the key and the thruster otherwise."""
    if not cfg.has_trajectory:
        return
    from arvcas.model import thrusters, vehicle  # the models sit below; only this check needs them
    from arvcas.model.spatial import J_dot, J_inv
    from arvcas.system.params import view

    lay = params.layout
    e, ed, edd, p = ca.SX.sym("e", 6), ca.SX.sym("ed", 6), ca.SX.sym("edd", 6), ca.SX.sym("p", len(lay))
    P = view(p, lay)
    nu = ca.mtimes(J_inv(e), ed)
    nud = ca.mtimes(J_inv(e), edd - ca.mtimes(J_dot(e, ed), nu))
    u = thrusters.allocate(P, ca.mtimes(vehicle.M(P), nud) + vehicle.forces(P, e, nu))
    lo, hi = thrusters.limits(P)
    f = ca.Function("trajectory_thrust", [e, ed, edd, p], [u, ca.if_else(u >= 0, u / hi, u / lo)])
    traj = cfg.trajectory()
    t = np.arange(n_samples(cfg)) * cfg.time_h
    pd, vd, ad = traj.sample(t)
    _, ratio = f.map(t.size)(pd.T, vd.T, ad.T, params.vector())
    ratio = np.asarray(ratio)
    if not (ratio <= 1.0).all():
        i, k = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        names = params.structure.thrusters or [str(j + 1) for j in range(ratio.shape[0])]
        seg = int(np.clip(np.searchsorted(traj.times, t[k], side="right"), 1, len(traj.times) - 1))
        key = {"waypoints": f"trajectory.waypoint[{seg + 1}].t", "lawnmower": "trajectory.speed",
               "approach": "trajectory.duration"}[cfg.trajectory_pattern]
        raise ScenarioError(f"{cfg.path or 'scenario'}: {key}: the trajectory asks thruster {names[i]} for "
                            f"{100 * ratio[i, k]:.0f} % of its limit at t = {t[k]:g} s (segment {seg} of "
                            f"{len(traj.times) - 1}, the vehicle alone in still water; system "
                            f"'{params.structure.name}'): give the move more time")
