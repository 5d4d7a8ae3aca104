"""Rotations and cross-product matrices for the NED/body frames (Fossen 2011, ch. 2).

Pure functions over any CasADi type (SX, MX, DM); they build graphs or evaluate numbers alike.
"""

from __future__ import annotations

import casadi as ca

__all__ = ["skew", "Rx", "Rz", "Rzyx", "Ttheta", "J", "J_inv", "J_dot"]


def skew(a):
    """Cross-product matrix S(a): S(a) b = a x b."""
    return ca.vertcat(
        ca.horzcat(0, -a[2], a[1]),
        ca.horzcat(a[2], 0, -a[0]),
        ca.horzcat(-a[1], a[0], 0),
    )


def Rx(t):
    c, s = ca.cos(t), ca.sin(t)
    return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))


def Rz(t):
    c, s = ca.cos(t), ca.sin(t)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def Rzyx(phi, theta, psi):
    """R^n_b(Theta) = Rz(psi) Ry(theta) Rx(phi), body -> NED (Fossen eq. 2.18)."""
    cf, sf = ca.cos(phi), ca.sin(phi)
    ct, st = ca.cos(theta), ca.sin(theta)
    cp, sp = ca.cos(psi), ca.sin(psi)
    return ca.vertcat(
        ca.horzcat(cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st),
        ca.horzcat(sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf),
        ca.horzcat(-st, ct * sf, ct * cf),
    )


def Ttheta(phi, theta):
    """T(Theta): Theta_dot = T nu2 (Fossen eq. 2.29), singular at theta = +-pi/2 (Assumption 2)."""
    cf, sf = ca.cos(phi), ca.sin(phi)
    ct, tt = ca.cos(theta), ca.tan(theta)
    return ca.vertcat(
        ca.horzcat(1, sf * tt, cf * tt),
        ca.horzcat(0, cf, -sf),
        ca.horzcat(0, sf / ct, cf / ct),
    )


def J(eta):
    """J(eta) = blkdiag(R_zyx, T_theta): eta_dot = J(eta) nu (paper eq. 1, Fossen eq. 2.40)."""
    R = Rzyx(eta[3], eta[4], eta[5])
    T = Ttheta(eta[3], eta[4])
    Z = ca.DM.zeros(3, 3)
    return ca.vertcat(ca.horzcat(R, Z), ca.horzcat(Z, T))


def J_inv(eta):
    """J(eta)^-1 in closed form: blkdiag(R^T, T^-1)."""
    R = Rzyx(eta[3], eta[4], eta[5])
    cf, sf = ca.cos(eta[3]), ca.sin(eta[3])
    ct, st = ca.cos(eta[4]), ca.sin(eta[4])
    Tinv = ca.vertcat(
        ca.horzcat(1, 0, -st),
        ca.horzcat(0, cf, ct * sf),
        ca.horzcat(0, -sf, ct * cf),
    )
    Z = ca.DM.zeros(3, 3)
    return ca.vertcat(ca.horzcat(R.T, Z), ca.horzcat(Z, Tinv))


_JDOT: ca.Function | None = None


def J_dot(eta, eta_dot):
    """dJ(eta)/dt along eta_dot (forward-mode AD of J), for eq. 3's C_eta term."""
    global _JDOT
    if _JDOT is None:
        e, ed = ca.SX.sym("eta", 6), ca.SX.sym("eta_dot", 6)
        _JDOT = ca.Function("J_dot", [e, ed], [ca.jtimes(J(e), e, ed)])
    return _JDOT(eta, eta_dot)
