"""The water around the vehicle: an irrotational current seen as relative velocity, and a quasi-static
tether (docs/model.md §10).

Current (Fossen 2011, ch. 10, the equations of relative motion): the water moves at ``v_c`` in {n},
the same over the whole vehicle and arm (irrotational), so in {b} ``nu_c = [R(eta)' v_c; 0]`` and the
hydrodynamic terms act on the relative velocity ``nu_r = nu - nu_c``:

    M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau

with ``nu_r_dot = nu_dot - nu_c_dot`` and ``nu_c_dot = [R' dv_c/dt - w x (R' v_c); 0]`` (``dv_c/dt`` the
current's change along the vehicle's path, ``d v_c/d t + d v_c/d z z_dot``, zero for a constant current).
The arm's links see the relative flow ``v - R' v_c`` at every quadrature point of their drag
(:func:`arvcas.model.manipulator.drag_wrench`).

Tether: a cable of diameter ``d`` and length ``L`` in the water from the surface down to the attachment
point ``r_a`` of the vehicle, taken straight and vertical (the vehicle holds station, the cable moves
little): the current's normal drag per unit length ``1/2 rho C_n d |v_h| v_h`` (``v_h`` the current's
horizontal part) loads it uniformly, and a uniformly loaded straight cable held at both ends carries
half of the load at each end, so the vehicle feels ``f = 1/4 rho C_n d L |v_h| v_h + f_pull`` in {n}
at ``r_a`` (``f_pull`` a steady pull, e.g. of the tether's handler or its slack's weight).
"""

from __future__ import annotations

import casadi as ca

from arvcas.model.spatial import Rzyx

__all__ = ["relative_current", "tether_wrench"]


def relative_current(eta, nu, v_c, dvc_dt=None, dvc_dz=None):
    """``(nu_c, nu_c_dot)`` in {b} of the current ``v_c`` (3, {n}) at the vehicle, with its rates of change
    in time and in depth (None: zero): ``nu_c = [R' v_c; 0]``, ``nu_c_dot = [R' v_c_dot - w x R' v_c; 0]``,
    ``v_c_dot = dvc_dt + dvc_dz z_dot``."""
    R = Rzyx(eta[3], eta[4], eta[5])
    vcb = ca.mtimes(R.T, v_c)
    w = nu[3:6]
    acc = -ca.cross(w, vcb)
    if dvc_dt is not None or dvc_dz is not None:
        vdot = 0
        if dvc_dt is not None:
            vdot = vdot + dvc_dt
        if dvc_dz is not None:
            zdot = ca.mtimes(R[2, :], nu[0:3])
            vdot = vdot + dvc_dz * zdot
        acc = acc + ca.mtimes(R.T, vdot)
    z3 = ca.DM.zeros(3)
    return ca.vertcat(vcb, z3), ca.vertcat(acc, z3)


def tether_wrench(rho, eta, v_c, attachment, length, diameter, Cn, pull):
    """The tether's wrench on the vehicle in {b} about the body origin (see the module docstring)."""
    vh = ca.vertcat(v_c[0], v_c[1], 0)
    f_n = 0.25 * rho * Cn * diameter * length * ca.norm_2(vh) * vh + pull
    R = Rzyx(eta[3], eta[4], eta[5])
    f = ca.mtimes(R.T, f_n)
    return ca.vertcat(f, ca.cross(attachment, f))
