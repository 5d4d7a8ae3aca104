"""The run's time table (arvcas.sim.schedule) against the models it replaces on the hot path.

References are independent implementations, not the table itself: the recursive Newton-Euler
``arm_wrench`` (itself checked against Pinocchio in test_arm_pinocchio.py), CasADi's AD for the time
derivatives, numpy.linalg for the LU, ``profiles.disturbance`` for eq. 41, and the record expression
evaluated in CasADi's VM at every stage time for the compiled, de-duplicated table.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from arvcas.build import calls
from arvcas.model import manipulator, vehicle
from arvcas.sim import profiles, scenario, schedule
from arvcas.model.linalg import lu_nopivot, lu_pack, lu_solve, lu_unpack, solve_nopivot
from arvcas.system.params import SCHEMA, view
from arvcas.model.uvms import ModelOptions, coupled_terms, coupled_terms_scheduled

NP = len(SCHEMA)


@pytest.fixture(scope="module")
def sym():
    p = ca.SX.sym("p", NP)
    d = {k: ca.SX.sym(k, 6) for k in ("eta", "nu", "q", "qd", "qdd")}
    d["pl"] = ca.SX.sym("pl")
    d["p"] = p
    d["P"] = view(p)
    return d


def _draws(rng, n):
    for k in range(n):
        eta = rng.normal(size=6) * np.array([1, 1, 1, 0.3, 0.3, 1.0])
        yield (eta, rng.normal(size=6) * 0.5, rng.uniform(-1.5, 1.5, 6), rng.normal(size=6),
               rng.normal(size=6), (0.0, 0.5, 1.0)[k % 3])


def test_scheduled_arm_wrench_equals_rnea(sym, params):
    """tau_m from the time-only terms + state equals the recursive Newton-Euler at nu_dot = 0."""
    s = sym
    P = s["P"]
    ins = [s["eta"], s["nu"], s["q"], s["qd"], s["qdd"], s["pl"], s["p"]]
    ref = ca.Function("ref", ins, [manipulator.arm_wrench(P, s["eta"], s["nu"], ca.DM.zeros(6), s["q"], s["qd"],
                                                          s["qdd"], s["pl"])])
    sc = manipulator.arm_schedule(P, s["q"], s["qd"], s["qdd"], s["pl"])
    new = ca.Function("new", ins, [manipulator.arm_wrench_scheduled(P, sc, s["eta"], s["nu"])])
    pv = params.vector()
    for d in _draws(np.random.default_rng(3), 30):
        r, n = np.array(ref(*d, pv)).ravel(), np.array(new(*d, pv)).ravel()
        np.testing.assert_allclose(n, r, rtol=0, atol=1e-12 * np.abs(r).max())


def test_schedule_rates_are_the_time_derivatives(sym, params):
    """M_arm_dot = dM_arm/dq qd and b_q = d h_q/dt (AD), b_q being the fixed-base Newton-Euler reaction."""
    s = sym
    P, q, qd, qdd, pl = s["P"], s["q"], s["qd"], s["qdd"], s["pl"]
    sc = manipulator.arm_schedule(P, q, qd, qdd, pl)
    ad_Mdot = ca.jtimes(sc["M_arm"], q, qd)
    ad_b = ca.jtimes(sc["h_q"], ca.vertcat(q, qd), ca.vertcat(qd, qdd))
    f = ca.Function("f", [q, qd, qdd, pl, s["p"]], [sc["M_arm_dot"], ad_Mdot, sc["b_q"], ad_b])
    pv = params.vector()
    for d in _draws(np.random.default_rng(4), 12):
        Md, Md_ad, b, b_ad = (np.array(o) for o in f(*d[2:], pv))
        np.testing.assert_allclose(Md, Md_ad, rtol=0, atol=1e-12 * np.abs(Md_ad).max())
        np.testing.assert_allclose(b, b_ad, rtol=0, atol=1e-12 * np.abs(b_ad).max())
        assert np.abs(b).max() > 1e-3  # the check is not vacuous


def test_scheduled_coupled_terms_equal_direct(sym, params):
    """The coupled vehicle + arm from a record equals coupled_terms with q(t) computed in place."""
    s = sym
    P, eta, nu = s["P"], s["eta"], s["nu"]
    cfg = scenario.load_scenario()
    t = ca.SX.sym("t")
    tau = ca.SX.sym("tau", 6)
    rec = schedule.unpack(schedule.record_expr(cfg, t, P))
    opts = ModelOptions()
    q, qd, qdd = profiles.joint_trajectory(cfg, manipulator.stow_pose(P), t)
    pl = profiles.payload_profile(cfg, t)
    trim = manipulator.trim_wrench(P, eta)
    direct = coupled_terms(P, eta, nu, tau, q, qd, qdd, pl, trim, opts)
    tab = coupled_terms_scheduled(P, eta, nu, tau, rec, trim, opts)
    f = ca.Function("f", [t, eta, nu, tau, s["p"]], [*direct, *tab])
    rng = np.random.default_rng(5)
    for tt in (0.0, 7.3, 12.5, 22.2, 30.05, 60.0):
        d = f(tt, rng.normal(size=6) * 0.3, rng.normal(size=6) * 0.3, rng.normal(size=6) * 50, params.vector())
        a_nud, a_tm, b_nud, b_tm = (np.array(o).ravel() for o in d)
        np.testing.assert_allclose(b_nud, a_nud, rtol=0, atol=1e-12 * np.abs(a_nud).max())
        np.testing.assert_allclose(b_tm, a_tm, rtol=0, atol=1e-12 * np.abs(a_tm).max())


def test_lu_factors_solve_like_numpy():
    rng = np.random.default_rng(6)
    A = rng.normal(size=(6, 6)) + 8 * np.eye(6)
    b = rng.normal(size=(6, 2))
    F, U = lu_unpack(lu_pack(*lu_nopivot(ca.DM(A))), 6)
    x = np.array(lu_solve(F, U, ca.DM(b)))
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-13)
    assert np.array_equal(x, np.array(solve_nopivot(ca.DM(A), ca.DM(b))))  # same operations, same order


def test_tabulated_disturbance_equals_eq41():
    cfg = scenario.load_scenario()
    t = np.linspace(0, 100, 37)
    ph = np.array([0.3, -1.0, 2.0, 0.0, 0.7, -2.5])
    w = np.array(cfg.disturbance_freq)
    for tt in t:
        a = np.array(profiles.disturbance(cfg, tt, ph)).ravel()
        b = np.array(profiles.disturbance_tabulated(cfg, np.sin(w * tt), np.cos(w * tt),
                                                    np.concatenate([np.cos(ph), np.sin(ph)]))).ravel()
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-13 * max(1.0, np.abs(a).max()))


def _records(tab, n, ns):
    """The table's records, (RECORD_SIZE, n * ns) stage time by stage time."""
    return np.vstack([tab.time.reshape(schedule.TIME_SIZE, n * ns, order="F"),
                      tab.arm.reshape(schedule.ARM_SIZE, n * ns, order="F")])


def test_compiled_table_equals_record_expression_everywhere(params):
    """Every record of the compiled, de-duplicated table equals the expression in the VM at its time."""
    cfg = scenario.load_scenario()
    pv = params.vector()
    tab = schedule.table(cfg, pv)
    times = schedule.stage_times(cfg)
    n, ns = times.shape
    assert tab.time.shape == (ns * schedule.TIME_SIZE, n) and tab.arm.shape == (ns * schedule.ARM_SIZE, n)
    assert not tab.time.flags.writeable and not tab.arm.flags.writeable
    t, p = ca.SX.sym("t"), ca.SX.sym("p", NP)
    f = ca.Function("rec", [t, p], [ca.densify(schedule.record_expr(cfg, t, view(p)))]).map("recs", "serial", n * ns, [1], [])
    ref = np.array(f(times.reshape(1, -1), pv))  # (K, n * ns), stage times sample by sample
    got = _records(tab, n, ns)
    scale = np.maximum(np.abs(ref).max(axis=1, keepdims=True), 1e-300)
    assert np.all(np.abs(got - ref) <= 1e-13 * scale)
    assert schedule.table(cfg, pv) is tab  # kept for repeated runs
    assert schedule.table(cfg, params.replace({"payload.mass": 3.5}).vector()) is not tab


def test_table_follows_the_parameters(params):
    """The table is a function of p: a heavier payload changes the records after the pick-up only."""
    cfg = scenario.load_scenario()
    n, ns = schedule.stage_times(cfg).shape
    a = _records(schedule.table(cfg, params.vector()), n, ns)
    b = _records(schedule.table(cfg, params.replace({"payload.mass": params["payload.mass"] * 2}).vector()), n, ns)
    sl = schedule.record_slices()["M_arm"]
    k_before = int(20.0 / cfg.time_h) * ns
    k_after = int(30.0 / cfg.time_h) * ns
    assert np.array_equal(a[sl, k_before], b[sl, k_before])
    assert not np.allclose(a[sl, k_after], b[sl, k_after])


def test_call_equals_casadi_call_and_checks_shapes():
    x = ca.SX.sym("x", 3, 2)
    y = ca.SX.sym("y", 3)
    f = ca.Function("f", [x, y], [2 * x, ca.sum2(x) + y])
    a = np.arange(6.0).reshape(3, 2)
    got = calls.call(f, a, [1, 2, 3])
    ref = f(a, [1, 2, 3])
    for g, r in zip(got, ref):
        assert np.array_equal(g, np.array(r))
    with pytest.raises(ValueError, match="shape"):
        calls.call(f, np.zeros((2, 3)), [1, 2, 3])
    with pytest.raises(ValueError, match="expected 2 inputs"):
        calls.call(f, a)


def test_vehicle_mass_matrix_is_what_the_table_factors(params):
    """The LU in the table factors M + M_arm (docs/model.md §3), not M alone: solve against numpy at one time."""
    cfg = scenario.load_scenario()
    pv = params.vector()
    n, ns = schedule.stage_times(cfg).shape
    rec = _records(schedule.table(cfg, pv), n, ns)[:, 150 * ns]  # t = 15 s, arm moving
    d = {k: rec[s] for k, s in schedule.record_slices().items()}
    F, U = lu_unpack(ca.DM(d["lu"]), 6)
    M_arm = np.array(schedule.unpack(ca.DM(rec))["M_arm"])
    M = np.array(vehicle.M(view(ca.DM(pv))))
    b = np.arange(1.0, 7.0)
    x = np.array(lu_solve(F, U, ca.DM(b))).ravel()
    np.testing.assert_allclose(x, np.linalg.solve(M + M_arm, b), rtol=1e-12)
