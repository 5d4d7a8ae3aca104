"""Thruster dynamics (docs/model.md §9) and the water (§10), against independent references.

- the command map against its table (Blue Robotics' T200 at 16 V, the CSV shipped in arvcas/data);
- the lag's closed form against SciPy's solve_ivp of ``ds/dt = clip((y - s) / tau, -r, r)`` with the
  spin-up/spin-down switch at rest handled by an event (one time constant, two, a rate limit, reversals);
- the T200 time constant of the BlueROV2 file recomputed from von Benzon et al.'s identified response;
- the current as relative velocity: the vehicle's right-hand side against a textbook NumPy implementation
  of Fossen's relative equations for von Benzon's diagonal BlueROV2, both integrated by SciPy; a free,
  neutrally buoyant body drifts with the water; the arm's drag on a body drifting with the water is zero;
- bad input refused in one line naming the key (time constant, table, thrust limits, current table).

The closed loop with dynamics is checked in tests/test_thruster_loop.py.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy import integrate, optimize, signal

import arvcas
from arvcas.model import manipulator, thrusters, vehicle, water
from arvcas.system.params import ParamsError, view
from arvcas.sim import profiles, scenario

DATA = Path(arvcas.__file__).parent / "data"
KGF = 9.80665


@pytest.fixture(scope="module")
def blue():
    return arvcas.load_system("bluerov2_heavy_alpha5")


def _csv(path=DATA / "t200_16v.csv"):
    rows = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith(("#", "command"))]
    a = np.array([[float(x) for x in r.split(",")] for r in rows])
    return a[:, 0], a[:, 1] * KGF


def _np(x):
    return np.array(ca.DM(x), dtype=float).ravel()


# ---- the command map ----------------------------------------------------------------------------------


def test_t200_map_is_its_table(blue):
    """Every point of the table: F(command) is the published thrust (kgf x 9.80665), zero through the dead
    band 1472-1528 us; between the points SciPy's monotone cubic (PchipInterpolator) through them; the
    inverse gives the rotor state back; the command sent is the point's."""
    from scipy.interpolate import PchipInterpolator

    c, T = _csv()
    P = view(blue.params)
    m = blue.structure.thruster_maps[0]
    assert (m.kind, m.unit, m.n, m.uniform) == ("table", "us", 201, True)
    lo, hi = c[m.zero[0]], c[m.zero[1]]
    assert (lo, hi) == (1472.0, 1528.0) and np.all(T[(c >= lo) & (c <= hi)] == 0)
    s = np.where(c < lo, c - lo, np.where(c > hi, c - hi, 0.0))
    np.testing.assert_allclose(_np(thrusters.map_thrust(P, m, ca.DM(s))), T, rtol=1e-15, atol=0)
    live = T != 0
    np.testing.assert_allclose(_np(thrusters.map_inverse(P, m, ca.DM(T[live]))), s[live], rtol=0, atol=1e-11)
    np.testing.assert_allclose(_np(thrusters.command_of(P, m, ca.DM(s[live]))), c[live], rtol=0, atol=1e-11)
    assert _np(thrusters.command_of(P, m, ca.DM([0.0])))[0] == 1500.0  # at rest: the dead band's middle
    keep = np.r_[np.arange(m.zero[0] + 1), np.arange(m.zero[1] + 1, m.n)]
    ref = PchipInterpolator(s[keep], T[keep])
    x = np.linspace(s[0], s[-1], 2003)
    F = _np(thrusters.map_thrust(P, m, ca.DM(x)))
    np.testing.assert_allclose(F, ref(x), rtol=1e-13, atol=1e-13)
    assert np.all(np.diff(F) > 0)  # monotone: invertible
    np.testing.assert_allclose(_np(thrusters.map_thrust(P, m, thrusters.map_inverse(P, m, ca.DM(F)))), F, atol=1e-12)
    xs = ca.SX.sym("x")  # the symbolic form (the references' ODE) is the same cubic
    fs = ca.Function("f", [xs], [thrusters.map_thrust(P, m, xs)])
    np.testing.assert_allclose(np.array(fs(ca.DM(x).T)).ravel(), F, rtol=1e-13, atol=1e-13)


def test_t200_time_constant_is_the_fit_to_von_benzons_response():
    """0.0167 s of the BlueROV2 file: the least-squares first-order fit (a lag on the PWM through the table)
    to the unit-step response of K(s) = (6136 s + 108700) / (s^3 + 89 s^2 + 9258 s + 108700) over 0-0.3 s,
    for a step from rest to 15 N; 0.0155-0.0171 s for 5-30 N; 0.020 s for a lag on the thrust itself."""
    t = np.linspace(0, 0.3, 3001)
    _, y = signal.step(signal.TransferFunction([6136, 108700], [1, 89, 9258, 108700]), T=t)
    c, T = _csv()
    neg, pos = c <= 1472, c >= 1528
    sg, Tg = np.r_[c[neg] - 1472, c[pos][1:] - 1528], np.r_[T[neg], T[pos][1:]]

    def fit(target):
        sf = np.interp(target, Tg, sg)
        f = lambda tau: np.sum((np.interp(sf * (1 - np.exp(-t / tau)), sg, Tg) / target - y) ** 2)  # noqa: E731
        return optimize.minimize_scalar(f, bounds=(1e-3, 0.2), method="bounded", options={"xatol": 1e-7}).x

    assert round(fit(15.0), 4) == 0.0167
    assert 0.0150 < fit(30.0) < fit(5.0) < 0.0175
    thrust_fit = optimize.minimize_scalar(lambda tau: np.sum((1 - np.exp(-t / tau) - y) ** 2), bounds=(1e-3, 0.2),
                                          method="bounded").x
    assert round(thrust_fit, 3) == 0.020


# ---- the lag's closed form against SciPy ---------------------------------------------------------------


def _scipy_lag(s0, y, up, down, r, times):
    """The textbook lag integrated by solve_ivp: tau = up while at rest or moving away from it, down while
    moving towards it; an event at s = 0 switches from spin-down to spin-up."""
    def rhs(tau):
        return lambda t, x: [float(np.clip((y - x[0]) / tau, -(r or np.inf), r or np.inf))]

    out, t0, x0 = [], 0.0, s0
    while True:
        growing = x0 * (y - x0) >= 0
        ev = lambda t, x: x[0]  # noqa: E731
        ev.terminal, ev.direction = True, 0
        todo = [t for t in times if t >= t0 and not any(np.isclose(t, u) for u, _ in out)]
        sol = integrate.solve_ivp(rhs(up if growing else down), (t0, times[-1]), [x0], method="DOP853",
                                  rtol=1e-13, atol=1e-13, dense_output=True, events=None if growing else ev)
        end = sol.t[-1]
        out += [(t, float(sol.sol(t)[0])) for t in todo if t <= end + 1e-15]
        if end >= times[-1] - 1e-15:
            return np.array([v for _, v in sorted(out)])
        t0, x0 = end, 0.0  # the rotor stopped: spin up from rest towards y


CASES = [  # s0, y, tau_up, tau_down, rate (None: no limit)
    (0.0, 250.0, 0.0167, 0.0167, None),
    (200.0, -150.0, 0.0167, 0.0167, None),
    (120.0, 40.0, 0.02, 0.05, None),  # spin-down on one side
    (120.0, -80.0, 0.02, 0.05, None),  # reversal: spin-down to rest, then spin-up
    (-60.0, 300.0, 0.03, 0.01, None),
    (0.0, 300.0, 0.02, 0.02, 4000.0),  # ramp at the rate limit, then the exponential
    (250.0, -250.0, 0.02, 0.04, 3000.0),  # reversal with ramps on both sides
    (50.0, -300.0, 0.02, 0.04, 8000.0),  # the ramp crosses rest
    (100.0, 0.0, 0.02, 0.04, None),  # to rest: never crosses
    (-30.0, -31.0, 0.02, 0.04, 100.0),
]


@pytest.mark.parametrize("s0,y,up,down,r", CASES)
def test_lag_closed_form_equals_scipy(s0, y, up, down, r):
    h, offs = 0.1, [j * 0.0025 for j in range(41)]
    asym = up != down
    st = dataclasses.replace(arvcas.load_system("bluerov2_heavy_alpha5").structure)
    dyn = tuple(dataclasses.replace(d, asymmetric=asym, rate_limit=r is not None) for d in st.thruster_dynamics)
    st = dataclasses.replace(st, thruster_dynamics=dyn)
    from arvcas.system.params import layout_for

    lay = layout_for(st)
    vals = np.zeros(len(lay))
    for n in st.thrusters:
        for k, v in (("time_constant", up), ("time_constant_up", up), ("time_constant_down", down), ("rate_limit", r)):
            if f"thrusters.{n}.{k}" in lay.index:
                vals[lay.index[f"thrusters.{n}.{k}"]] = v
    P = view(vals, lay)
    E = thrusters.lag_constants(P, offs)
    n = st.n_thrusters
    S = thrusters.lag_states(P, ca.DM([s0] * n), ca.DM([y] * n), E, offs, h)
    got = np.array([float(ca.DM(v)) for v in S[0]])
    ref = _scipy_lag(s0, y, up, down, r, offs)
    assert np.abs(got - ref).max() < 1e-9 * max(1.0, abs(s0), abs(y)), (got - ref)
    assert got[0] == pytest.approx(s0, abs=1e-12)


# ---- the current: relative velocity -------------------------------------------------------------------


def _textbook(p, x, tau, v_c):
    """Fossen's relative equations for von Benzon's diagonal BlueROV2 (body frame at the CG), written from
    the textbook in NumPy: M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r + D(nu_r) nu_r + g = tau."""
    phi, th, psi = x[3:6]
    nu = x[6:12]
    cf, sf, ct, st_, cp, sp = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
    R = np.array([[cp * ct, -sp * cf + cp * st_ * sf, sp * sf + cp * cf * st_],
                  [sp * ct, cp * cf + sf * st_ * sp, -cp * sf + st_ * sp * cf],
                  [-st_, ct * sf, ct * cf]])
    T = np.array([[1, sf * np.tan(th), cf * np.tan(th)], [0, cf, -sf], [0, sf / ct, cf / ct]])
    m, I = p["vehicle.m"], np.array([p[f"vehicle.I{a}{a}"] for a in "xyz"])
    A = -np.array([p[f"hydro.{k}"] for k in ("X_udot", "Y_vdot", "Z_wdot", "K_pdot", "M_qdot", "N_rdot")])
    lin = -np.array([p.get(f"hydro.{k}", 0.0) for k in ("X_u", "Y_v", "Z_w", "K_p", "M_q", "N_r")])
    quad = -np.array([p[f"hydro.{k}"] for k in ("X_u_absu", "Y_v_absv", "Z_w_absw", "K_p_absp", "M_q_absq", "N_r_absr")])
    vcb = R.T @ v_c
    w = nu[3:6]
    nu_r = nu - np.r_[vcb, 0, 0, 0]
    nud_c = np.r_[-np.cross(w, vcb), 0, 0, 0]
    u, v, ww, pp, q, r = nu
    C_RB = np.array([[0, 0, 0, 0, m * ww, -m * v], [0, 0, 0, -m * ww, 0, m * u], [0, 0, 0, m * v, -m * u, 0],
                     [0, m * ww, -m * v, 0, I[2] * r, -I[1] * q], [-m * ww, 0, m * u, -I[2] * r, 0, I[0] * pp],
                     [m * v, -m * u, 0, I[1] * q, -I[0] * pp, 0]])
    a = A * nu_r
    C_A = np.array([[0, 0, 0, 0, a[2], -a[1]], [0, 0, 0, -a[2], 0, a[0]], [0, 0, 0, a[1], -a[0], 0],
                    [0, a[2], -a[1], 0, a[5], -a[4]], [-a[2], 0, a[0], -a[5], 0, a[3]], [a[1], -a[0], 0, a[4], -a[3], 0]])
    D = np.diag(lin + quad * np.abs(nu_r))
    W, B = m * p["env.g"], p["env.rho"] * p["env.g"] * p["vehicle.volume"]
    zB = p["vehicle.zB"]
    g = np.array([(W - B) * st_, -(W - B) * ct * sf, -(W - B) * ct * cf, -zB * B * ct * sf, -zB * B * st_, 0.0])
    M = np.diag(np.r_[m, m, m, I]) + np.diag(A)
    nud = np.linalg.solve(M, tau - C_RB @ nu - C_A @ nu_r - D @ nu_r - g + np.diag(A) @ nud_c)
    return np.r_[R @ nu[0:3], T @ w, nud]


def _arvcas_rhs(P, x, tau, v_c):
    X, Tau, V = ca.SX.sym("x", 12), ca.SX.sym("tau", 6), ca.SX.sym("v", 3)
    cur = water.relative_current(X[0:6], X[6:12], V)
    nud = ca.solve(vehicle.M(P), Tau - vehicle.forces(P, X[0:6], X[6:12], cur))
    from arvcas.model.spatial import J

    return ca.Function("f", [X, Tau, V], [ca.vertcat(ca.mtimes(J(X[0:6]), X[6:12]), nud)])


def test_relative_velocity_equals_textbook_integrated_by_scipy(blue):
    """The BlueROV2 hull in a 0.3 m/s current (down component too), 8 s from a tilted, moving, turning
    start under a constant wrench: arvcas's forces (C_RB(nu) nu + C_A(nu_r) nu_r + D(nu_r) nu_r + g -
    M_A nu_c_dot) and the textbook NumPy right-hand side, each integrated by SciPy (DOP853, 1e-12)."""
    p = blue.params.as_dict()
    P = view(blue.params)
    v_c = np.array([0.2, -0.2, 0.08])
    f = _arvcas_rhs(P, None, None, None)
    rng = np.random.default_rng(7)
    x0 = np.r_[0, 0, 1, 0.2, -0.1, 0.5, rng.normal(scale=0.2, size=6)]
    tau = np.array([5.0, -3.0, 2.0, 0.3, -0.2, 0.4])
    for _ in range(5):  # the right-hand sides at random states
        x = np.r_[rng.normal(size=3), rng.uniform(-0.6, 0.6, 3), rng.normal(scale=0.5, size=6)]
        np.testing.assert_allclose(np.array(f(x, tau, v_c)).ravel(), _textbook(p, x, tau, v_c), rtol=1e-12, atol=1e-12)
    opts = dict(method="DOP853", rtol=1e-12, atol=1e-12, t_eval=np.linspace(0, 8, 81))
    a = integrate.solve_ivp(lambda t, x: np.array(f(x, tau, v_c)).ravel(), (0, 8), x0, **opts)
    b = integrate.solve_ivp(lambda t, x: _textbook(p, x, tau, v_c), (0, 8), x0, **opts)
    assert a.success and b.success
    assert np.abs(a.y - b.y).max() < 1e-9
    assert np.abs(a.y[6:9, -1]).max() > 0.05  # it does move


def test_a_free_neutral_body_drifts_with_the_water(blue):
    """Neutrally buoyant, CG below CB, level, no thrust, moving with a uniform current: it keeps drifting
    with the water (no drag on it, no added-mass force), whatever the current's direction."""
    P = view(blue.params.replace({"vehicle.volume": blue.params["vehicle.m"] / blue.params["env.rho"]}))
    f = _arvcas_rhs(P, None, None, None)
    v_c = np.array([-0.17, 0.25, 0.05])
    x = np.r_[0, 0, 2, 0, 0, 0.7, 0, 0, 0, 0, 0, 0]
    c, s = np.cos(0.7), np.sin(0.7)
    x[6:9] = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ v_c  # R(psi)' v_c
    xdot = np.array(f(x, np.zeros(6), v_c)).ravel()
    np.testing.assert_allclose(xdot[0:3], v_c, atol=1e-15)
    np.testing.assert_allclose(xdot[6:12], 0, atol=1e-14)
    xdot_still = np.array(f(x, np.zeros(6), np.zeros(3))).ravel()
    assert np.abs(xdot_still[6:9]).max() > 1e-3  # in still water the same motion is damped


def test_arm_drag_sees_the_relative_flow(blue):
    """The arm's wrench on a vehicle drifting with the water (joints still) is its weight in water alone,
    as at rest in still water; the recursive Newton-Euler and the time-table form agree with a current."""
    P = view(blue.params)
    q = ca.DM([1.0, 1.5, 2.0, 0.5])
    z = ca.DM.zeros(4)
    eta = ca.DM([0, 0, 1, 0.1, -0.05, 0.4])
    v_c = ca.DM([0.3, -0.2, 0.1])
    from arvcas.model.spatial import Rzyx

    vcb = ca.mtimes(Rzyx(eta[3], eta[4], eta[5]).T, v_c)
    nu = ca.vertcat(vcb, 0, 0, 0)
    drift = manipulator.arm_wrench(P, eta, nu, ca.DM.zeros(6), q, z, z, 0.0, 5, v_c_b=vcb)
    rest = manipulator.arm_wrench(P, eta, ca.DM.zeros(6), ca.DM.zeros(6), q, z, z, 0.0, 5)
    np.testing.assert_allclose(_np(drift), _np(rest), atol=1e-12)
    moving = manipulator.arm_wrench(P, eta, nu, ca.DM.zeros(6), q, z, z, 0.0, 5)
    assert np.abs(_np(moving) - _np(rest)).max() > 1e-3  # without the current the same motion drags
    nu2 = ca.DM([0.1, 0.05, -0.02, 0.1, -0.2, 0.05])
    qd = ca.DM([0.3, -0.1, 0.2, 0.0])
    sc = manipulator.arm_schedule(P, q, qd, z, 0.0)
    sched = {**sc, "M_arm": sc["M_arm"], "M_arm_dot": sc["M_arm_dot"]}
    a = manipulator.arm_wrench(P, eta, nu2, ca.DM.zeros(6), q, qd, z, 0.0, 5, v_c_b=vcb)
    b = manipulator.arm_wrench_scheduled(P, sched, eta, nu2, 5, v_c_b=vcb)
    np.testing.assert_allclose(_np(a), _np(b), rtol=1e-10, atol=1e-12)


def test_current_table_is_bilinear_and_held():
    """A table in time and depth: its value at the points, linear in between, held beyond; the rates are
    the cell's; the tether pulls half the drag of a vertical cable."""
    text = (Path(scenario.default_scenario_path()).read_text() + "\n[current]\n" + "".join(
        f"[[current.point]]\nt = {{ value = {t}, unit = \"s\", source = \"t\" }}\n"
        f"depth = {{ value = {z}, unit = \"m\", source = \"t\" }}\n"
        f"velocity = {{ value = [{v}, {2 * v}, 0.0], unit = \"m/s\", source = \"t\" }}\n"
        for t, z, v in ((0, 0, 0.1), (0, 10, 0.3), (50, 0, 0.2), (50, 10, 0.5))))
    cfg = scenario.loads_scenario(text)
    assert cfg.current == "table" and cfg.current_grid == ((0.0, 50.0), (0.0, 10.0))
    w = cfg.water_vector

    def at(t, z):
        v, dt, dz = profiles.current_at(cfg, w, t, z)
        return _np(v), _np(dt), _np(dz)

    np.testing.assert_allclose(at(0, 0)[0], [0.1, 0.2, 0])
    np.testing.assert_allclose(at(50, 10)[0], [0.5, 1.0, 0])
    v, dt, dz = at(25, 5)
    np.testing.assert_allclose(v, [0.275, 0.55, 0], rtol=1e-14)  # the mean of the four corners
    np.testing.assert_allclose(dt, [(0.15 - 0.1) / 50 * 0 + 0.15 / 50, 0.3 / 50, 0], rtol=1e-14)
    np.testing.assert_allclose(dz, [0.25 / 10, 0.5 / 10, 0], rtol=1e-14)
    np.testing.assert_allclose(at(80, -3)[0], [0.2, 0.4, 0])  # held beyond the last time and the first depth


# ---- bad input: one line naming the key, before any work -----------------------------------------------


def _blue_text():
    return (DATA / "bluerov2_heavy_alpha5.toml").read_text()


BAD = [
    ("time_constant = { value = 0.0167", "time_constant = { value = 0.0", r"thrusters\.T1\.time_constant: value must be > 0"),
    ("time_constant = { value = 0.0167", "time_constant = { value = -0.01",
     r"thrusters\.T1\.time_constant: value must be > 0"),
    ("u_max = { value = 30.4", "u_max = { value = 60.0",
     r"thrusters\.T1\.u_max: 60 N needs a command outside the range of its map t200_16v \(51\.4\d* N at command 1900 us\)"),
    ('map = "t200_16v"', 'map = "t200"', r"thrusters\.unit\[0\] \(T1\)\.map: .*did you mean 't200_16v'"),
]


@pytest.mark.parametrize("old,new,pattern", BAD, ids=["zero time constant", "negative time constant",
                                                      "command outside the table", "unknown map"])
def test_bad_thruster_input_is_one_line(tmp_path, old, new, pattern):
    (tmp_path / "t200_16v.csv").write_text((DATA / "t200_16v.csv").read_text())
    path = tmp_path / "bad.toml"
    path.write_text(_blue_text().replace(old, new, 1))
    with pytest.raises(ParamsError, match=pattern) as e:
        arvcas.load_system(path)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


@pytest.mark.parametrize("edit,pattern", [
    (lambda rows: rows[:50] + [rows[51], rows[50]] + rows[52:], r"command: not increasing at point 51"),
    (lambda rows: rows[:150] + [rows[150].split(",")[0] + ",1.0"] + rows[151:],
     r"thrust: a non-monotonic thrust table: thrust falls from 1\.75\d* to 1 at point 150 \(command 1700\)"),
    (lambda rows: [r for r in rows if r.split(",")[1] != "0"], r"thrust: the table must run from reverse"),
], ids=["commands out of order", "non-monotonic thrust", "no dead band"])
def test_bad_table_is_one_line(tmp_path, edit, pattern):
    lines = (DATA / "t200_16v.csv").read_text().splitlines()
    head = [ln for ln in lines if ln.startswith(("#", "command"))]
    rows = [ln for ln in lines if ln and not ln.startswith(("#", "command"))]
    (tmp_path / "t200_16v.csv").write_text("\n".join(head + edit(rows)) + "\n")
    (tmp_path / "sys.toml").write_text(_blue_text())
    with pytest.raises(ParamsError, match=r"thrusters\.map\.t200_16v\." + pattern) as e:
        arvcas.load_system(tmp_path / "sys.toml")
    assert "\n" not in str(e.value)


def test_table_without_source_and_partial_dynamics_are_refused(tmp_path):
    text = (DATA / "t200_16v.csv").read_text().replace("# source:", "# from:")
    (tmp_path / "t200_16v.csv").write_text(text)
    (tmp_path / "sys.toml").write_text(_blue_text())
    with pytest.raises(ParamsError, match=r"thrusters\.map\.t200_16v\.table: .*no '# source: \.\.\.' line"):
        arvcas.load_system(tmp_path / "sys.toml")
    (tmp_path / "t200_16v.csv").write_text((DATA / "t200_16v.csv").read_text())
    t = _blue_text()
    i = t.index('map = "t200_16v"\ntime_constant')  # T1's dynamics removed, the others kept
    j = t.index("\n", t.index("\n", i) + 1)
    (tmp_path / "sys.toml").write_text(t[:i] + t[j + 1:])
    with pytest.raises(ParamsError, match=r"thrusters\.unit\[0\] \(T1\): thruster dynamics are declared for every "
                                          r"thruster or none"):
        arvcas.load_system(tmp_path / "sys.toml")


def test_current_table_with_a_gap_is_refused():
    base = Path(scenario.default_scenario_path()).read_text() + "\n[current]\n"
    pts = "".join(f"[[current.point]]\nt = {{ value = {t}, unit = \"s\", source = \"t\" }}\n"
                  f"depth = {{ value = {z}, unit = \"m\", source = \"t\" }}\n"
                  f"velocity = {{ value = [0.1, 0.0, 0.0], unit = \"m/s\", source = \"t\" }}\n"
                  for t, z in ((0, 0), (0, 10), (50, 0)))
    with pytest.raises(scenario.ScenarioError, match=r"current\.point: a gap: no point at t = 50 s, depth = 10 m"):
        scenario.loads_scenario(base + pts, "s.toml")
    with pytest.raises(scenario.ScenarioError, match=r"current\.velocity: give a constant velocity or a table"):
        scenario.loads_scenario(base + "velocity = { value = [0.1, 0, 0], unit = \"m/s\", source = \"t\" }\n" + pts, "s")


def test_instantaneous_drops_the_dynamics_and_keeps_every_number(blue):
    p = blue.params
    i = p.instantaneous()
    assert p.structure.has_thruster_dynamics and not i.structure.has_thruster_dynamics
    assert all(i[n] == p[n] for n in i.names())
    assert set(p.names()) - set(i.names()) == {n for n in p.names() if ".map." in n or "time_constant" in n}
    assert len(i) == 239  # the parameters of the BlueROV2 file before the thruster dynamics (results/bluerov2 knees)


def test_study_says_which_chat_it_optimises():
    """[objectives] chat: the paper's commanded CHAT by default (and then absent from the identity, so that
    earlier checkpoints resume), "delivered" on the delivered wrench; anything else one line."""
    from arvcas.tuning import loads_study
    from arvcas.tuning.study import StudyError
    from studytext import tiny_study

    base = tiny_study()
    s = loads_study(base, "s.toml")
    assert s.objectives.chat == "commanded" and "chat" not in s.identity("agsta")["objectives"]
    text = base.replace("reference_point = [300.0, 4.0]", 'reference_point = [300.0, 4.0]\nchat = "delivered"')
    d = loads_study(text, "s.toml")
    assert d.objectives.chat == "delivered" and d.identity("agsta")["objectives"]["chat"] == "delivered"
    with pytest.raises(StudyError, match=r"s\.toml: objectives\.chat: unknown CHAT signal 'deliverd' \(did you mean "
                                         r"'delivered'\?\) \(allowed: commanded, delivered\)"):
        loads_study(text.replace('"delivered"', '"deliverd"'), "s.toml")
