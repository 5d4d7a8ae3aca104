"""A table map's monotone cubic at run time (docs/model.md §9): the intervals that hold a value, looked up
in MX, the inverse by Newton's method on one interval, and the per-run tables unstacked by map.

:func:`arvcas.model.thrusters.map_table` gives a table map's rotor-state grid, thrust and slopes (the run's
per-run constants); the run indexes them at run time: ``casadi.low`` finds each interval (:func:`map_interval`
on the rotor states, :func:`pchip_interval` on the thrust values, whose cubic :func:`pchip_newton` inverts),
and :func:`arvcas.model.thrusters.hermite` evaluates the cubic on it. The lockstep run gathers the same
intervals in C, lane by lane (:mod:`arvcas.sim.lockstep`). Pure functions of the structure and CasADi
expressions; the sample's use of them (the lag, the stage times, the wrench) is :mod:`arvcas.sim.thrust_forcing`.
"""

from __future__ import annotations

import casadi as ca

__all__ = ["IV", "map_interval", "pchip_interval", "pchip_newton", "table_grids", "target_intervals", "stage_intervals"]


IV = ("g0", "g1", "v0", "v1", "d0", "d1")  # an interval of a table map's cubic (ends, values, slopes)


def _gather(g, v, d, i):
    """``(g0, g1, v0, v1, d0, d1)``: the ends, values and slopes of the monotone cubic's intervals ``i``
    (MX: the per-run tables indexed at run time)."""
    return g[i], g[i + 1], v[i], v[i + 1], d[i], d[i + 1]


def map_interval(g, v, d, x, mode: str):
    """The intervals of the monotone cubic through ``(g_i, v_i)`` that hold a column ``x`` (MX: ``casadi.low``,
    ``"exact"`` for a uniform grid, one division and no search; ``"binary"`` otherwise), as :func:`_gather`;
    the cubic itself is evaluated in SX (:func:`arvcas.sim.thrust_forcing.thruster_functions`)."""
    return _gather(g, v, d, ca.low(g, x, {"lookup_mode": mode}))  # within [0, n - 2]


def pchip_interval(g, v, d, u):
    """``(g0, g1, v0, v1, d0, d1)``: the interval of the monotone cubic's values that holds ``u`` (MX lookup)."""
    return _gather(g, v, d, ca.low(v, u, {"lookup_mode": "binary"}))


def pchip_newton(g0, g1, v0, v1, d0, d1, u, iterations: int = 8):
    """The ``x`` at which one interval's cubic equals ``u`` (the interval from :func:`pchip_interval`): Newton's
    method on that interval's cubic from the secant's guess, kept in the interval (quadratic convergence
    from a guess within a few percent: 8 steps reach round-off); MX or SX."""
    h = g1 - g0
    t = ca.fmin(ca.fmax((u - v0) / (v1 - v0), 0), 1)
    for _ in range(iterations):
        t2 = t * t
        p = (2 * t * t2 - 3 * t2 + 1) * v0 + (t * t2 - 2 * t2 + t) * h * d0 + (3 * t2 - 2 * t * t2) * v1 + (t * t2 - t2) * h * d1
        dp = (6 * t2 - 6 * t) * (v0 - v1) + (3 * t2 - 4 * t + 1) * h * d0 + (3 * t2 - 2 * t) * h * d1
        t = ca.fmin(ca.fmax(t - (p - u) / ca.fmax(dp, 1e-12 * (v1 - v0)), 0), 1)
    return g0 + t * h


def table_grids(st, tabs):
    """The thrusters' maps (in thruster order) and each table map's ``(s grid, thrust, slopes, lookup mode)``
    from the stacked per-run tables ``tabs`` (:func:`arvcas.sim.thrust_forcing.thruster_constants`), by map name."""
    maps = [st.thruster_map(d.map) for d in st.thruster_dynamics]
    grids, k = {}, 0
    for m in st.thruster_maps:
        if m.kind == "table":
            n_g = m.n - (m.zero[1] - m.zero[0])
            grids[m.name] = (tabs[k:k + n_g], tabs[k + n_g:k + 2 * n_g], tabs[k + 2 * n_g:k + 3 * n_g],
                             "exact" if m.uniform else "binary")
            k += 3 * n_g
    return maps, grids


def _table_intervals(st, grids, x, size: int, lookup):
    """The six interval columns (:data:`IV`) of each thruster's table map at its block of ``size`` entries of
    ``x`` (MX, thruster-major; zeros for a thruster without a table): ``lookup(g, v, d, mode, x_map)`` gives
    the intervals of one map's thrusters together."""
    maps = [st.thruster_map(d.map) for d in st.thruster_dynamics]
    cols = [[ca.MX.zeros(size, 1)] * st.n_thrusters for _ in IV]
    for name, (g, v, d, mode) in grids.items():
        idx = [i for i, m in enumerate(maps) if m.name == name]
        got = lookup(g, v, d, mode, ca.vertcat(*[x[i * size:(i + 1) * size] for i in idx]))
        for c, col in zip(got, cols):
            for r, i in enumerate(idx):
                col[i] = c[r * size:(r + 1) * size]
    return [ca.vertcat(*col) for col in cols]


def target_intervals(st, grids, u):
    """The intervals (:data:`IV`) of each thruster's table map whose values hold its allocated thrust ``u``
    (a search on the values: ``cl_thr_lag``'s Newton steps invert the cubic there)."""
    return _table_intervals(st, grids, u, 1, lambda g, v, d, _, x: pchip_interval(g, v, d, x))


def stage_intervals(st, grids, s_all, m_off: int):
    """The intervals (:data:`IV`) of each thruster's table map that hold its rotor states ``s_all`` (``m_off``
    per thruster, thruster-major): ``cl_thr_wrench`` evaluates the cubic on them."""
    return _table_intervals(st, grids, s_all, m_off, lambda g, v, d, mode, x: map_interval(g, v, d, x, mode))
