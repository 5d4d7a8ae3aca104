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


# ---- thruster dynamics: command maps and the first-order lag (docs/model.md §9) ---------------------------
#
# A thruster with dynamics has one state, its rotor state ``s`` in the units of its command (PWM
# microseconds, a normalised command or rotor speed) counted from the edge of its dead band: ``s = 0``
# is the rotor at rest, and the command the autopilot sends for ``s`` is ``c = c_hi + s`` (s > 0) or
# ``c_lo + s`` (s < 0), [c_lo, c_hi] the dead band. Its steady thrust is ``F(s)``: the map's table with
# the dead band's flat run taken out (strictly increasing through (0, 0)), or the quadratic rotor law
# ``k s |s|``. The state follows the held command ``y`` by ``ds/dt = clip((y - s) / tau, -r, r)`` with
# ``tau`` the spin-up constant while |s| grows and the spin-down constant while it shrinks; over a
# sample the command is held, so the solution is written in closed form (:func:`lag_states`).

__all__ += ["has_dynamics", "thruster_maps", "map_grid", "map_thrust", "map_inverse", "map_range", "command_of",
            "time_constants", "lag_constants", "lag_states", "LAG_EXP_LIMIT"]

LAG_EXP_LIMIT = 700.0  # h / tau above this would overflow the closed form's exp(h / tau) (refused before a run)


def has_dynamics(P) -> bool:
    return P.s.thruster_dynamics is not None


def thruster_maps(P) -> list:
    """The map of each listed thruster (its :class:`arvcas.systemfile.ThrusterMap`), in thruster order."""
    return [P.s.thruster_map(d.map) for d in P.s.thruster_dynamics]


def _mp(m, key):
    return f"thrusters.map.{m.name}.{key}"


def map_grid(P, m):
    """A table map as ``(s, F)``: the rotor-state grid (command minus the dead band's edge) and the
    thrust (N), both strictly increasing through (0, 0)."""
    i0, i1 = m.zero
    c = [P[_mp(m, f"command.{i}")] for i in range(m.n)]
    T = [P[_mp(m, f"thrust.{i}")] for i in range(m.n)]
    s = [c[i] - c[i0] for i in range(i0 + 1)] + [c[i] - c[i1] for i in range(i1 + 1, m.n)]
    return ca.vertcat(*s), ca.vertcat(*(T[:i0 + 1] + T[i1 + 1:]))


_INTERP: dict = {}


def _interpolant(n_grid: int) -> ca.Function:
    """Linear interpolation on a runtime grid of ``n_grid`` points (CasADi's, binary search; its batch
    option is not used: in CasADi 3.8.2 it evaluates the first point only)."""
    f = _INTERP.get(n_grid)
    if f is None:
        f = _INTERP[n_grid] = ca.interpolant(f"thr_interp_{n_grid}", "linear", [n_grid], 1,
                                             {"lookup_mode": ["binary"]})
    return f


def _lookup(grid, values, x):
    """values(x) by linear interpolation, for a column ``x``: one call per point (the closed loop looks
    its tables up in MX instead, :func:`arvcas.sim.closedloop._lookup`)."""
    f = _interpolant(grid.shape[0])
    return ca.vertcat(*[f(x[i], grid, values) for i in range(x.shape[0])])


def map_thrust(P, m, s):
    """Steady thrust F(s) (N) of map ``m`` at rotor states ``s`` (a column)."""
    if m.kind == "table":
        g, v = map_grid(P, m)
        return _lookup(g, v, s)
    return P[_mp(m, "rotor_constant")] * s * ca.fabs(s)


def map_inverse(P, m, u):
    """The rotor state whose steady thrust is ``u`` (a column, N, within the map's range)."""
    if m.kind == "table":
        g, v = map_grid(P, m)
        return _lookup(v, g, u)
    return ca.sign(u) * ca.sqrt(ca.fabs(u) / P[_mp(m, "rotor_constant")])


def map_range(P, m):
    """(s_min, s_max) of map ``m``'s rotor state: the table's ends, or the command limits beyond the dead band."""
    if m.kind == "table":
        i0, i1 = m.zero
        return (P[_mp(m, "command.0")] - P[_mp(m, f"command.{i0}")],
                P[_mp(m, f"command.{m.n - 1}")] - P[_mp(m, f"command.{i1}")])
    db = P[_mp(m, "dead_band")]
    return P[_mp(m, "command_min")] + db, P[_mp(m, "command_max")] - db


def command_of(P, m, s):
    """The command the autopilot sends for rotor state ``s`` (map units): beyond the dead band's edge, the
    dead band's middle at rest."""
    if m.kind == "table":
        i0, i1 = m.zero
        lo, hi = P[_mp(m, f"command.{i0}")], P[_mp(m, f"command.{i1}")]
    else:
        hi = P[_mp(m, "dead_band")]
        lo = -hi
    return ca.if_else(s > 0, hi + s, ca.if_else(s < 0, lo + s, 0.5 * (lo + hi)))


def time_constants(P, i: int):
    """(tau_up, tau_down, rate limit or None) of listed thruster ``i`` (s, s, command units / s)."""
    n, d = P.s.thrusters[i], P.s.thruster_dynamics[i]
    if d.asymmetric:
        up, down = P[f"thrusters.{n}.time_constant_up"], P[f"thrusters.{n}.time_constant_down"]
    else:
        up = down = P[f"thrusters.{n}.time_constant"]
    return up, down, (P[f"thrusters.{n}.rate_limit"] if d.rate_limit else None)


def lag_constants(P, offsets) -> ca.SX:
    """The closed form's per-run constants: ``exp(-t / tau)`` at each time offset ``t`` of a sample, per
    thruster (spin-up, then spin-down for an asymmetric one), stacked in thruster order."""
    out = []
    for i, d in enumerate(P.s.thruster_dynamics):
        up, down, _ = time_constants(P, i)
        out += [ca.exp(-t / up) for t in offsets]
        if d.asymmetric:
            out += [ca.exp(-t / down) for t in offsets]
    return ca.vertcat(*out)


def _phase(xs, z, tau, r, ts, Es, h, t0=None):
    """The solution of ``dx/dt = clip((z - x) / tau, -r, r)`` from ``x(t0) = xs`` at the times ``ts``
    (``Es[j] = exp(-ts[j] / tau)``): a ramp at the rate limit while ``|z - x| > r tau``, then the
    exponential approach. ``exp(min(t0 + t_ramp, h) / tau)`` carries the delayed start (the tail is
    used only for times after it, all <= h)."""
    d = z - xs
    if r is None:
        if t0 is None:
            return [z - d * E for E in Es]
        G = ca.exp(ca.fmin(t0, h) / tau)
        return [z - d * E * G for E in Es]
    t0 = 0 if t0 is None else t0
    a, sg = ca.fabs(d), ca.sign(d)
    tr = ca.fmax(0, a / r - tau)
    m = ca.fmin(a, r * tau)
    G = ca.exp(ca.fmin(t0 + tr, h) / tau)
    return [ca.if_else(t - t0 <= tr, xs + sg * r * (t - t0), z - sg * m * E * G) for t, E in zip(ts, Es)]


def lag_states(P, s0, y, consts, offsets, h):
    """Each thruster's rotor state at the time offsets of a sample (``offsets[j]`` s after its start, the
    last one ``<= h``), from ``s0`` with the command ``y`` held: a list over thrusters of lists over offsets.

    Exact for the lag of :func:`time_constants`: with one time constant, :func:`_phase` over the whole
    sample; with spin-up and spin-down constants, spin-up while moving away from rest, spin-down while
    moving towards the target on the same side, and for a reversal spin-down until the rotor stops (at
    ``t_c``) then spin-up from rest. ``consts``: :func:`lag_constants`.
    """
    k, out, m = 0, [], len(offsets)
    for i, d in enumerate(P.s.thruster_dynamics):
        up, down, r = time_constants(P, i)
        Eu = [consts[k + j] for j in range(m)]
        k += m
        if not d.asymmetric:
            out.append(_phase(s0[i], y[i], up, r, offsets, Eu, h))
            continue
        Ed = [consts[k + j] for j in range(m)]
        k += m
        x, z = s0[i], y[i]
        grow = x * (z - x) >= 0  # at rest or moving away from it: spin-up all sample
        cross = x * z < 0  # a reversal: spin-down to rest, then spin-up
        PU = _phase(x, z, up, r, offsets, Eu, h)
        PA = _phase(x, z, down, r, offsets, Ed, h)
        a = ca.fabs(x) + ca.fabs(z)
        if r is None:
            tc = down * ca.log(a / ca.fabs(z))
        else:
            tra = ca.fmax(0, a / r - down)
            t_zero = ca.fabs(x) / r
            tc = ca.if_else(t_zero <= tra, t_zero, tra + down * ca.log(ca.fmin(a, r * down) / ca.fabs(z)))
        PB = _phase(0, z, up, r, offsets, Eu, h, t0=tc)
        out.append([ca.if_else(grow, pu, ca.if_else(ca.logic_and(cross, t >= tc), pb, pa))
                    for t, pu, pa, pb in zip(offsets, PU, PA, PB)])
    return out
