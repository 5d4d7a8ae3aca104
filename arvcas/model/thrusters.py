"""Thruster allocation and asymmetric saturation (paper eq. 2, Appendix B, section 4.1; docs/system-file.md).

Two layouts, chosen by the system file's ``[thrusters]`` table (docs/system-file.md): the parametric one of
the paper's Appendix B (keys ``delta_sL`` ... ``x_hS``, Haidou-1's) and a list of thrusters
(``[[thrusters.unit]]``), each with its position, unit direction and limits: column ``[d; r x d]`` of B. Allocation is ``B^-1 tau`` for six thrusters and
the minimum-norm ``B' (B B')^-1 tau`` for more; then each thrust is clipped to its own limits.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["B_T", "actuated", "allocate", "saturate", "thrust", "limit_prefixes", "limits", "envelope"]


def B_T(P):
    """Thruster configuration matrix: tau_v = B_T u_T (6 x n_thrusters)."""
    if P.s.thrusters is not None:
        cols = []
        for n in P.s.thrusters:
            r = ca.vertcat(*[P[f"thrusters.{n}.position.{c}"] for c in "xyz"])
            d = ca.vertcat(*[P[f"thrusters.{n}.direction.{c}"] for c in "xyz"])
            cols.append(ca.vertcat(d, ca.cross(r, d)))
        return ca.horzcat(*cols)
    return _B_parametric(P)


def _B_parametric(P):
    """Thruster configuration matrix of the parametric layout (Appendix B): tau_v = B_T u_T.

    Columns: stern-left, stern-right (rotatable, at delta_sL/delta_sR), two side (sway) thrusters,
    two vertical thrusters. The same numbers, bit for bit, as a thruster list with the positions
    (x_stn, -+y_stn, z_stn), (x_hB, 0, 0), (x_hS, 0, 0), (x_bow, -+y_bow, 0) and the directions
    (cos delta, 0, -sin delta), (0, 1, 0), (0, 0, 1) (tests/test_systems.py); kept as its own form, chosen
    by the file's keys, because the stern angles are parameters here (the hydrodynamic terms in ``ds`` read
    them; studies vary them) and the committed results' graphs are this form's.
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


def actuated(structure) -> list[int]:
    """The degrees of freedom (0..5) the allocation serves: all six, less ``[thrusters] unactuated``."""
    return [k for k in range(6) if k not in structure.unactuated]


def allocate(P, tau):
    """u_T = B_T^-1 tau_v (eq. 2), or the minimum-norm B' (B B')^-1 tau for more than six thrusters: N,
    before saturation. A system with unactuated degrees of freedom (``[thrusters] unactuated``, e.g. a
    six-thruster BlueROV2's pitch) allocates the actuated rows only, by the minimum-norm solution of
    ``B_a u = tau_a``: the commanded wrench's other components are not asked of the thrusters."""
    B = B_T(P)
    if P.s.unactuated:
        rows = actuated(P.s)
        Ba = B[rows, :]
        return ca.mtimes(Ba.T, ca.solve(ca.mtimes(Ba, Ba.T), tau[rows]))
    if B.shape[1] == 6:
        return ca.solve(B, tau)
    return ca.mtimes(B.T, ca.solve(ca.mtimes(B, B.T), tau))


def limit_prefixes(structure) -> list[str]:
    """The key prefixes of the thrust limits: one pair for the parametric layout, one per listed thruster."""
    if structure.thrusters is None:
        return ["thrusters."]
    return [f"thrusters.{n}." for n in structure.thrusters]


def limits(P):
    """(u_min, u_max): per thruster columns, or the parametric layout's common scalars."""
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
    B = np.array(ca.evalf(B_T(P)), dtype=float)
    if P.s.unactuated:  # the allocation's own inverse: the actuated rows' pseudo-inverse, zero elsewhere
        rows = actuated(P.s)
        A = np.zeros((B.shape[1], 6))
        A[:, rows] = np.linalg.pinv(B[rows, :])
    else:
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
    for k in P.s.unactuated:  # the allocation asks nothing of the thrusters there
        lo[k] = hi[k] = 0.0
    return lo, hi


# ---- thruster dynamics: command maps and the first-order lag (docs/model.md §9) ---------------------------
#
# A thruster with dynamics has one state, its rotor state ``s`` in the units of its command (PWM
# microseconds, a normalised command or rotor speed) counted from the edge of its dead band: ``s = 0``
# is the rotor at rest, and the command the autopilot sends for ``s`` is ``c = c_hi + s`` (s > 0) or
# ``c_lo + s`` (s < 0), [c_lo, c_hi] the dead band. Its steady thrust is ``F(s)``: the monotone cubic
# (PCHIP) through the map's table with the dead band's flat run taken out (strictly increasing through
# (0, 0); smooth, so that the RK4 stages see no kinks as the rotor sweeps the table), or the quadratic
# rotor law ``k s |s|``. The state follows the held command ``y`` by ``ds/dt = clip((y - s) / tau, -r, r)`` with
# ``tau`` the spin-up constant while |s| grows and the spin-down constant while it shrinks; over a
# sample the command is held, so the solution is written in closed form (:func:`lag_states`).

__all__ += ["has_dynamics", "thruster_maps", "map_grid", "map_table", "pchip_slopes", "hermite", "map_thrust",
            "map_inverse", "map_range", "command_of", "state_of", "time_constants", "lag_constants", "lag_states", "LAG_EXP_LIMIT"]

LAG_EXP_LIMIT = 700.0  # h / tau above this would overflow the closed form's exp(h / tau) (refused before a run)


def has_dynamics(P) -> bool:
    return P.s.thruster_dynamics is not None


def thruster_maps(P) -> list:
    """The map of each listed thruster (its :class:`arvcas.system.systemfile.ThrusterMap`), in thruster order."""
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


def _edge_slope(h0, h1, m0, m1):
    """An end point's slope (SciPy's PchipInterpolator): the three-point estimate, set to 0 where its sign
    differs from the end secant's and limited to 3 times it where the secants change sign."""
    d = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    d = ca.if_else(ca.sign(d) != ca.sign(m0), 0, d)
    return ca.if_else(ca.logic_and(ca.sign(m0) != ca.sign(m1), ca.fabs(d) > 3 * ca.fabs(m0)), 3 * m0, d)


def pchip_slopes(g, v):
    """The Fritsch-Carlson slopes of the monotone cubic through the points ``(g_i, v_i)`` (the same as
    SciPy's PchipInterpolator): the weighted harmonic mean of the neighbouring secants, 0 where they
    differ in sign. Any CasADi type; a column."""
    n = g.shape[0]
    h = [g[i + 1] - g[i] for i in range(n - 1)]
    m = [(v[i + 1] - v[i]) / h[i] for i in range(n - 1)]
    d = [_edge_slope(h[0], h[1], m[0], m[1])]
    for k in range(1, n - 1):
        w1, w2 = 2 * h[k] + h[k - 1], h[k] + 2 * h[k - 1]
        d.append(ca.if_else(m[k - 1] * m[k] > 0, (w1 + w2) / (w1 / m[k - 1] + w2 / m[k]), 0))
    d.append(_edge_slope(h[-1], h[-2], m[-1], m[-2]))
    return ca.vertcat(*d)


def map_table(P, m):
    """A table map as ``(s, F, dF/ds)``: :func:`map_grid` and the monotone cubic's slopes at its points."""
    g, v = map_grid(P, m)
    return g, v, pchip_slopes(g, v)


def hermite(g0, g1, v0, v1, d0, d1, x):
    """The cubic of one interval ``[g0, g1]`` with values ``v0, v1`` and slopes ``d0, d1`` at ``x``."""
    h = g1 - g0
    t = (x - g0) / h
    t2 = t * t
    t3 = t2 * t
    return (2 * t3 - 3 * t2 + 1) * v0 + (t3 - 2 * t2 + t) * h * d0 + (3 * t2 - 2 * t3) * v1 + (t3 - t2) * h * d1


def _is_symbolic(*xs) -> bool:
    return any(isinstance(x, (ca.SX, ca.MX)) for x in xs)


def _np(x):
    return np.array(ca.DM(x), dtype=float).ravel()


def _pchip_np(g, v, d, x):
    i = np.clip(np.searchsorted(g, x, side="right") - 1, 0, g.size - 2)
    return hermite(g[i], g[i + 1], v[i], v[i + 1], d[i], d[i + 1], x)


def _pchip_sx(g, v, d, x):
    """The monotone cubic at a symbolic ``x``: every interval's cubic, selected (the closed loop looks the
    interval up in MX instead, :func:`arvcas.model.thruster_tables.map_interval`); beyond the ends, the end cubics."""
    n = g.shape[0]
    out = 0
    for i in range(n - 1):
        inside = ca.logic_and(x >= g[i] if i > 0 else 1, x < g[i + 1] if i < n - 2 else 1)
        out = out + ca.if_else(inside, hermite(g[i], g[i + 1], v[i], v[i + 1], d[i], d[i + 1], x), 0)
    return out


def pchip_powers(g, v, d):
    """The map's monotone cubic (:func:`map_table`) as one expression of ``x``: the first
    interval's cubic plus, at each inner point, the jumps of the second- and third-order coefficients times the
    truncated powers ``max(x - g_i, 0)^2, ^3`` (the cubic is C1, so nothing else jumps). Exactly the piecewise cubic
    (beyond the ends, the end cubics, as :func:`map_thrust`), at about 8 operations per
    point of the table for each thruster, where :func:`_pchip_sx` selects among every interval's cubic (the
    controllers' form: ``ardusub``). Returns ``f(x)``."""
    n = g.shape[0]
    h = [g[i + 1] - g[i] for i in range(n - 1)]
    m = [(v[i + 1] - v[i]) / h[i] for i in range(n - 1)]
    c = [(3 * m[i] - 2 * d[i] - d[i + 1]) / h[i] for i in range(n - 1)]  # local coefficients of (x - g_i)^2
    e = [(d[i] + d[i + 1] - 2 * m[i]) / h[i] ** 2 for i in range(n - 1)]  # and of (x - g_i)^3
    jumps = [(g[i], c[i] - (c[i - 1] + 3 * e[i - 1] * h[i - 1]), e[i] - e[i - 1]) for i in range(1, n - 1)]

    def f(x):
        t = x - g[0]
        out = v[0] + d[0] * t + c[0] * t * t + e[0] * t * t * t
        for gi, dc, de in jumps:
            r = ca.fmax(x - gi, 0)
            out = out + (dc + de * r) * r * r
        return out

    return f


def map_thrust(P, m, s):
    """Steady thrust F(s) (N) of map ``m`` at rotor states ``s`` (a column): a table's monotone cubic
    through its points (PCHIP, docs/model.md §9), or the rotor law ``k s |s|``."""
    if m.kind == "table":
        g, v, d = map_table(P, m)
        if _is_symbolic(g, v, s):
            return ca.vertcat(*[_pchip_sx(g, v, d, s[i]) for i in range(s.shape[0])])
        return ca.DM(_pchip_np(_np(g), _np(v), _np(d), _np(s)))
    return P[_mp(m, "rotor_constant")] * s * ca.fabs(s)


def map_inverse(P, m, u):
    """The rotor state whose steady thrust is ``u`` (a column, N, within the map's range); a table's by
    bisection on its monotone cubic (numbers only: the closed loop inverts in MX)."""
    if m.kind == "table":
        g, v, d = (_np(x) for x in map_table(P, m))
        u = _np(u)
        i = np.clip(np.searchsorted(v, u, side="right") - 1, 0, g.size - 2)
        lo, hi = g[i].copy(), g[i + 1].copy()
        for _ in range(64):  # a monotone interval: bisection to the last bit
            mid = 0.5 * (lo + hi)
            below = hermite(g[i], g[i + 1], v[i], v[i + 1], d[i], d[i + 1], mid) < u
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        return ca.DM(0.5 * (lo + hi))
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


def state_of(P, m, c):
    """The rotor state that command ``c`` (map units) asks for: the inverse of :func:`command_of` (a command
    inside the dead band stops the rotor). The command must lie in the map's range (callers check)."""
    if m.kind == "table":
        i0, i1 = m.zero
        lo, hi = P[_mp(m, f"command.{i0}")], P[_mp(m, f"command.{i1}")]
    else:
        hi = P[_mp(m, "dead_band")]
        lo = -hi
    return ca.if_else(c > hi, c - hi, ca.if_else(c < lo, c - lo, 0))


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
