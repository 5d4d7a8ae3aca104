"""Thruster allocation and asymmetric saturation (paper eq. 2, Appendix B, section 4.1; docs/system-file.md).

Two layouts: Haidou-1's parametric one (Appendix B) and a list of thrusters, each with its position,
unit direction and limits: column ``[d; r x d]`` of B. Allocation is ``B^-1 tau`` for six thrusters and
the minimum-norm ``B' (B B')^-1 tau`` for more; then each thrust is clipped to its own limits.
"""

from __future__ import annotations

import casadi as ca

__all__ = ["B_T", "allocate", "saturate", "thrust", "limit_prefixes", "limits", "envelope"]


def B_T(P):
    """Thruster configuration matrix: tau_v = B_T u_T (6 x n_thrusters)."""
    if P.s.thrusters is not None:
        cols = []
        for n in P.s.thrusters:
            r = ca.vertcat(*[P[f"thrusters.{n}.position.{c}"] for c in "xyz"])
            d = ca.vertcat(*[P[f"thrusters.{n}.direction.{c}"] for c in "xyz"])
            cols.append(ca.vertcat(d, ca.cross(r, d)))
        return ca.horzcat(*cols)
    return _B_haidou1(P)


def _B_haidou1(P):
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
    """u_T = B_T^-1 tau_v (eq. 2), or the minimum-norm B' (B B')^-1 tau for more than six thrusters: N,
    before saturation."""
    B = B_T(P)
    if B.shape[1] == 6:
        return ca.solve(B, tau)
    return ca.mtimes(B.T, ca.solve(ca.mtimes(B, B.T), tau))


def limit_prefixes(structure) -> list[str]:
    """The key prefixes of the thrust limits: one pair for Haidou-1's layout, one per listed thruster."""
    if structure.thrusters is None:
        return ["thrusters."]
    return [f"thrusters.{n}." for n in structure.thrusters]


def limits(P):
    """(u_min, u_max): per thruster columns, or Haidou-1's common scalars."""
    pre = limit_prefixes(P.s)
    if len(pre) == 1:
        return P[pre[0] + "u_min"], P[pre[0] + "u_max"]
    return ca.vertcat(*[P[p + "u_min"] for p in pre]), ca.vertcat(*[P[p + "u_max"] for p in pre])


def saturate(P, u):
    """Each thrust clipped to its [u_min, u_max] (Haidou-1: [-146.9, 231.6] N, section 4.1)."""
    lo, hi = limits(P)
    return ca.fmin(ca.fmax(u, lo), hi)


def thrust(P, u):
    """Realised body wrench B_T sat(u) (docs/model.md §2)."""
    return ca.mtimes(B_T(P), saturate(P, u))


def envelope(P):
    """The pure-axis capacities of the allocation: for each DOF k, the largest wrenches ``-lo_k e_k`` and
    ``hi_k e_k`` whose allocation stays within every thruster's limits (allocation is linear, so beyond
    them a thruster saturates). Numbers (NumPy), from a view of numeric parameters: ``(lo (6,), hi (6,))``.
    """
    import numpy as np

    B = np.array(ca.evalf(B_T(P)), dtype=float)
    A = np.linalg.inv(B) if B.shape[1] == 6 else np.linalg.pinv(B)
    umin, umax = (np.broadcast_to(np.array(ca.evalf(ca.DM(x) if not isinstance(x, ca.SX) else x), dtype=float).ravel(),
                                  (B.shape[1],)) for x in limits(P))

    def reach(a):  # the largest s >= 0 with umin <= s a <= umax
        with np.errstate(divide="ignore"):
            up = np.where(a > 1e-15, umax / a, np.inf)
            down = np.where(a < -1e-15, umin / a, np.inf)
        return float(min(up.min(), down.min()))

    hi = np.array([reach(A[:, k]) for k in range(6)])
    lo = np.array([reach(-A[:, k]) for k in range(6)])
    return lo, hi
