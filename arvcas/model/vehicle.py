"""The Haidou-1 vehicle in Fossen form (paper eq. 1, Appendix A, Table A1; docs/model.md §2).

``M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau``, body frame {b} at the COB, SNAME notation.
Every function takes ``P`` (a :func:`arvcas.params.view` of the parameter vector) and works on any
CasADi type, so the same code builds the compiled graphs and evaluates numbers in tests.
"""

from __future__ import annotations

import math

import casadi as ca

from arvcas.model.spatial import J, skew

__all__ = ["r_G", "I_b", "M_RB", "M_A", "M", "C_RB", "D", "g_vec", "delta_s_term", "rhs"]


def r_G(P):
    """Centre of gravity in {b} (Table A1)."""
    return ca.vertcat(P["vehicle.xG"], P["vehicle.yG"], P["vehicle.zG"])




def I_b(P):
    """Inertia tensor about the COB's axes (docs/model.md §2; Fossen eq. 3.24 sign convention)."""
    Ixx, Iyy, Izz = P["vehicle.Ixx"], P["vehicle.Iyy"], P["vehicle.Izz"]
    Ixy, Iyz, Ixz = P["vehicle.Ixy"], P["vehicle.Iyz"], P["vehicle.Ixz"]
    return ca.vertcat(
        ca.horzcat(Ixx, -Ixy, -Ixz),
        ca.horzcat(-Ixy, Iyy, -Iyz),
        ca.horzcat(-Ixz, -Iyz, Izz),
    )


def M_RB(P):
    """Rigid-body inertia about the COB (Fossen eq. 3.44)."""
    m = P["vehicle.m"]
    S = skew(r_G(P))
    return ca.vertcat(
        ca.horzcat(m * ca.DM.eye(3), -m * S),
        ca.horzcat(m * S, I_b(P)),
    )


# (row, col, dotted coefficient) of the added mass printed in App. A: M_A[i,j] = -rho * coef.
# App. A prints M(3,1) as +rho Z'udot: a sign typo (docs/model.md §2), here -rho Z'udot like every other entry.
_MA_ENTRIES = (
    (0, 0, "X_udot"), (0, 1, "X_vdot"), (0, 2, "X_wdot"), (0, 4, "X_qdot"), (0, 5, "X_rdot"),
    (1, 0, "Y_udot"), (1, 1, "Y_vdot"), (1, 5, "Y_rdot"),
    (2, 0, "Z_udot"), (2, 2, "Z_wdot"), (2, 4, "Z_qdot"),
    (3, 1, "K_vdot"), (3, 2, "K_wdot"), (3, 3, "K_pdot"),
    (4, 0, "M_udot"), (4, 2, "M_wdot"), (4, 4, "M_qdot"),
    (5, 0, "N_udot"), (5, 1, "N_vdot"), (5, 5, "N_rdot"),
)


def M_A(P):
    """Added mass, App. A: M_A[i,j] = -rho * (dotted coefficient). Not symmetric (docs/model.md §2)."""
    rho = P["env.rho"]
    rows = [[0] * 6 for _ in range(6)]
    for i, j, name in _MA_ENTRIES:
        rows[i][j] = -rho * P["hydro." + name]
    return ca.vertcat(*[ca.horzcat(*r) for r in rows])


def M(P):
    """M = M_RB + M_A (paper eq. 1, App. A)."""
    return M_RB(P) + M_A(P)


def C_RB(P, nu):
    """Rigid-body Coriolis-centripetal matrix, Fossen's linear-velocity-independent form (docs/model.md §2).

    Replaces App. A's printed C(nu), whose rows 4-6 have duplicated and missing entries.
    """
    m = P["vehicle.m"]
    nu2 = nu[3:6]
    S2 = skew(nu2)
    SG = skew(r_G(P))
    return ca.vertcat(
        ca.horzcat(m * S2, -m * ca.mtimes(S2, SG)),
        ca.horzcat(m * ca.mtimes(SG, S2), -skew(ca.mtimes(I_b(P), nu2))),
    )


def delta_s_term(P):
    """(delta_s - pi/2 sgn(delta_s)) with the fixed stern angle delta_s = (delta_sL + delta_sR)/2 (docs/model.md §2)."""
    ds = 0.5 * (P["thrusters.delta_sL"] + P["thrusters.delta_sR"])
    return ds - 0.5 * math.pi * ca.sign(ds)


def D(P, nu):
    """Hydrodynamic damping, App. A, multiplied by -rho (docs/model.md §2).

    D(1,2) uses X'v|w| |w| (the print labels it X'v|v|); every delta_s term uses the constant stern angle.
    """
    h = lambda k: P["hydro." + k]  # noqa: E731
    v, w = nu[1], nu[2]
    aw, av = ca.fabs(w), ca.fabs(v)
    dsv = delta_s_term(P)
    z = 0
    rows = [
        [h("X_u") + h("X_u_absw") * aw, h("X_v") + h("X_v_absw") * aw, h("X_w") + h("X_ds") * aw * dsv, z, h("X_q"), h("X_r")],
        [h("Y_u"), h("Y_v") + h("Y_v_absv") * av, z, z, z, h("Y_r")],
        [h("Z_u"), z, h("Z_w") + h("Z_w_absw") * aw + h("Z_dsds") * aw * dsv**2, z, h("Z_q"), z],
        [h("K_u_absw") * aw, h("K_v"), h("K_w"), h("K_p"), z, z],
        [h("M_u") + h("M_uw") * w, z, h("M_w") + h("M_w_absw") * aw + h("M_ds") * dsv * w + h("M_dsds") * dsv**2 * aw, z, h("M_q"), z],
        [h("N_u"), h("N_v") + h("N_v_absv") * av, z, z, z, h("N_r")],
    ]
    return -P["env.rho"] * ca.vertcat(*[ca.horzcat(*r) for r in rows])


def weight_buoyancy(P):
    """(W, B) in N: W = m g, B = (m + buoyancy_excess) g (Table A1)."""
    gacc = P["env.g"]
    m = P["vehicle.m"]
    return m * gacc, (m + P["vehicle.buoyancy_excess"]) * gacc


def g_vec(P, eta):
    """Restoring forces and moments g(eta) (App. A, Fossen eq. 4.6)."""
    W, B = weight_buoyancy(P)
    xG, yG, zG = P["vehicle.xG"], P["vehicle.yG"], P["vehicle.zG"]
    xB, yB, zB = P["vehicle.xB"], P["vehicle.yB"], P["vehicle.zB"]
    cf, sf = ca.cos(eta[3]), ca.sin(eta[3])
    ct, st = ca.cos(eta[4]), ca.sin(eta[4])
    return ca.vertcat(
        (W - B) * st,
        -(W - B) * ct * sf,
        -(W - B) * ct * cf,
        -(yG * W - yB * B) * ct * cf + (zG * W - zB * B) * ct * sf,
        (zG * W - zB * B) * st + (xG * W - xB * B) * ct * cf,
        -(xG * W - xB * B) * ct * sf - (yG * W - yB * B) * st,
    )


def forces(P, eta, nu):
    """C(nu) nu + D(nu) nu + g(eta): the vehicle's velocity- and pose-dependent generalised force."""
    return ca.mtimes(C_RB(P, nu), nu) + ca.mtimes(D(P, nu), nu) + g_vec(P, eta)


def rhs(P, x, tau):
    """Vehicle alone, eq. 1: x = [eta; nu], tau the total body wrench at the COB -> xdot."""
    eta, nu = x[0:6], x[6:12]
    nud = ca.solve(M(P), tau - forces(P, eta, nu))
    return ca.vertcat(ca.mtimes(J(eta), nu), nud)

