"""Thruster allocation and asymmetric saturation (paper eq. 2, Appendix B, section 4.1)."""

from __future__ import annotations

import casadi as ca

__all__ = ["B_T", "allocate", "saturate", "thrust"]


def B_T(P):
    """Thruster configuration matrix of Appendix B: tau_v = B_T u_T.

    Columns: stern-left, stern-right (rotatable, at delta_sL/delta_sR), two side (sway) thrusters,
    two vertical thrusters.
    """
    dL, dR = P["thrusters.delta_sL"], P["thrusters.delta_sR"]
    x_stn, y_stn, z_stn = P["thrusters.x_stn"], P["thrusters.y_stn"], P["thrusters.z_stn"]
    x_bow, y_bow = P["thrusters.x_bow"], P["thrusters.y_bow"]
    x_hB, x_hS = P["thrusters.x_hB"], P["thrusters.x_hS"]
    cL, sL, cR, sR = ca.cos(dL), ca.sin(dL), ca.cos(dR), ca.sin(dR)
    return ca.vertcat(
        ca.horzcat(cL, cR, 0, 0, 0, 0),
        ca.horzcat(0, 0, 1, 1, 0, 0),
        ca.horzcat(-sL, -sR, 0, 0, 1, 1),
        ca.horzcat(y_stn * sL, -y_stn * sR, 0, 0, -y_bow, y_bow),
        ca.horzcat(z_stn * cL + x_stn * sL, z_stn * cR + x_stn * sR, 0, 0, -x_bow, -x_bow),
        ca.horzcat(y_stn * cL, -y_stn * cR, x_hB, x_hS, 0, 0),
    )


def allocate(P, tau):
    """u_T = B_T^-1 tau_v (eq. 2): thrust per thruster, N, before saturation."""
    return ca.solve(B_T(P), tau)


def saturate(P, u):
    """Each thrust clipped to [u_min, u_max] = [-146.9, 231.6] N (section 4.1)."""
    return ca.fmin(ca.fmax(u, P["thrusters.u_min"]), P["thrusters.u_max"])


def thrust(P, u):
    """Realised body wrench B_T sat(u) (docs/model.md §2)."""
    return ca.mtimes(B_T(P), saturate(P, u))
