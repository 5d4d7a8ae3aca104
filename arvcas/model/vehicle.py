"""The vehicle in Fossen form (paper eq. 1, Appendix A, Table A1; docs/model.md §2; docs/system-file.md).

``M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau``, body frame {b} at the COB, SNAME notation.
Every function takes ``P`` (a :func:`arvcas.system.params.view` of the parameter vector) and works on any
CasADi type, so the same code builds the compiled graphs and evaluates numbers in tests.
"""

from __future__ import annotations

import math

import casadi as ca

from arvcas.model.spatial import J, skew
from arvcas.system.systemfile import HydroTerm

__all__ = ["r_G", "I_b", "M_RB", "M_A", "M", "C_RB", "C_A", "D", "g_vec", "delta_s_term", "rhs"]


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


def _hydro_scale(P):
    """The factor of every hydrodynamic derivative: rho for "per_rho" files (Table A1), 1 for "SI" ones."""
    return P["env.rho"] if P.s.hydro_per_rho else 1


def M_A(P):
    """Added mass: M_A[F, v] = -scale * (coefficient of the term ``<F>_<v>dot``). Not symmetric (docs/model.md §2)."""
    rho = _hydro_scale(P)
    rows = [[0] * 6 for _ in range(6)]
    for t in P.s.hydro:
        if t.dot is not None:
            rows[t.row][t.dot] = -rho * P["hydro." + t.name]
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


def _factors(P, nu):
    """The values of the damping terms' factors (docs/system-file.md), each built once."""
    f = {}
    for k, c in enumerate("uvwpqr"):
        f[c] = nu[k]
        f["abs" + c] = ca.fabs(nu[k])
    if any(x in ("ds", "ds2") for t in P.s.hydro for x in t.factors):
        dsv = delta_s_term(P)
        f["ds"], f["ds2"] = dsv, dsv**2
    return f


def D(P, nu):
    """Hydrodynamic damping, -scale * (the entries of the terms named in [hydro]) (docs/model.md §2).

    Each damping term ``coef * v_col * f_1 * ...`` is entry (row, col) of the matrix with coefficient
    ``coef * f_1 * ...``; the terms of one entry are summed fewest factors first (Table A1's entries
    as App. A prints them: D(1,2) uses X'v|w| |w|, every delta_s term the constant stern angle).
    """
    f = _factors(P, nu)
    cells: dict = {}
    for t in P.s.hydro:
        if t.col is not None:
            cells.setdefault((t.row, t.col), []).append(t)
    rows = [[0] * 6 for _ in range(6)]
    for (i, j), ts in cells.items():
        acc = None
        for t in sorted(ts, key=HydroTerm.order):
            term = P["hydro." + t.name]
            for x in t.factors:
                term = term * f[x]
            acc = term if acc is None else acc + term
        rows[i][j] = acc
    return -_hydro_scale(P) * ca.vertcat(*[ca.horzcat(*r) for r in rows])


def C_A(P, nu):
    """Added-mass Coriolis-centripetal matrix (Fossen eq. 6.43) from the symmetric part of M_A."""
    A = M_A(P)
    A = 0.5 * (A + A.T)
    a1 = ca.mtimes(A[0:3, 0:3], nu[0:3]) + ca.mtimes(A[0:3, 3:6], nu[3:6])
    a2 = ca.mtimes(A[3:6, 0:3], nu[0:3]) + ca.mtimes(A[3:6, 3:6], nu[3:6])
    Z = ca.DM.zeros(3, 3)
    return ca.vertcat(ca.horzcat(Z, -skew(a1)), ca.horzcat(-skew(a1), -skew(a2)))


def weight_buoyancy(P):
    """(W, B) in N: W = m g, B = (m + buoyancy_excess) g (Table A1) or rho g V (a displaced volume)."""
    gacc = P["env.g"]
    m = P["vehicle.m"]
    if P.s.buoyancy == "volume":
        return m * gacc, P["env.rho"] * gacc * P["vehicle.volume"]
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


def forces(P, eta, nu, current=None):
    """C(nu) nu + D(nu) nu + g(eta): the vehicle's velocity- and pose-dependent generalised force.

    ``current = (nu_c, nu_c_dot)`` (:func:`arvcas.model.water.relative_current`): the water moves, and the
    hydrodynamic terms act on ``nu_r = nu - nu_c`` (Fossen 2011, ch. 10, docs/model.md §10):
    ``C_RB(nu) nu + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) - M_A nu_c_dot``, so that ``M nu_dot = tau - forces``
    is ``M_RB nu_dot + M_A nu_r_dot + ... = tau``.
    """
    if current is None:
        C = C_RB(P, nu) + C_A(P, nu) if P.s.coriolis_added_mass else C_RB(P, nu)
        return ca.mtimes(C, nu) + ca.mtimes(D(P, nu), nu) + g_vec(P, eta)
    nu_c, nud_c = current
    nu_r = nu - nu_c
    out = ca.mtimes(C_RB(P, nu), nu) + ca.mtimes(D(P, nu_r), nu_r) + g_vec(P, eta) - ca.mtimes(M_A(P), nud_c)
    if P.s.coriolis_added_mass:
        out = out + ca.mtimes(C_A(P, nu_r), nu_r)
    return out


def rhs(P, x, tau):
    """Vehicle alone, eq. 1: x = [eta; nu], tau the total body wrench at the COB -> xdot."""
    eta, nu = x[0:6], x[6:12]
    nud = ca.solve(M(P), tau - forces(P, eta, nu))
    return ca.vertcat(ca.mtimes(J(eta), nu), nud)

