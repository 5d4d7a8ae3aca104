"""Thruster dynamics in the closed loop: the BlueROV2 with its T200 dynamics, the current and the tether.

- a 3 s run of the shipped system and scenario: each sample's delivered thrust, command and rotor state
  recomputed independently from the traced allocation (NumPy's interp of the CSV table, the lag's
  exponential), the delivered wrench is B times the thrust, CHAT on the command and on the delivered
  wrench equal eq. 42 on the traced series, and the plant's trajectory equals CVODES driven by the
  continuous delivered thrust, the current and the tether (docs/model.md §9-10);
- the committed instantaneous-thruster results (results/bluerov2, before the thruster dynamics) reproduce bit for bit
  with the thruster dynamics off (``Params.instantaneous()``) and the scenario stored in the result.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import arvcas
from arvcas import metrics
from arvcas.io.results import read_result
from arvcas.model import thruster_tables, thrusters
from arvcas.system.params import view
from arvcas.sim import scenario, schedule, thrust_forcing
from script_helpers import load_script

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(arvcas.__file__).parent / "data"


@pytest.fixture(scope="module")
def blue():
    return arvcas.load_system("bluerov2_heavy_alpha5")


@pytest.fixture(scope="module")
def short(blue):
    cfg = scenario.load_scenario(blue.params.default("scenario"))
    assert cfg.current == "constant" and cfg.has_tether and cfg.per_axis_sensors
    cfg = dataclasses.replace(cfg, time_duration=3.0)
    run = arvcas.Run("proposed", scenario=cfg, system=blue).compile()
    return cfg, run, run.simulate(seed=4)


def _table():
    """The map from the CSV by SciPy: its monotone cubic (PCHIP) and the inverse by brentq."""
    from scipy.interpolate import PchipInterpolator
    from scipy.optimize import brentq

    rows = [ln for ln in (DATA / "t200_16v.csv").read_text().splitlines() if ln and not ln.startswith(("#", "command"))]
    a = np.array([[float(x) for x in r.split(",")] for r in rows])
    c, T = a[:, 0], a[:, 1] * 9.80665
    neg, pos = c <= 1472, c >= 1528
    F = PchipInterpolator(np.r_[c[neg] - 1472, c[pos][1:] - 1528], np.r_[T[neg], T[pos][1:]])
    inv = np.vectorize(lambda u: brentq(lambda x: F(x) - u, -372, 372, xtol=1e-14, rtol=1e-15))
    return F, inv


def test_delivered_thrust_is_the_lag_of_the_command(short, blue):
    """s_{k+1} = y_k + (s_k - y_k) exp(-h / tau), y_k the inverse map of the allocated thrust; the delivered
    thrust the map of s_k, the command the dead band's edge plus y_k."""
    cfg, run, r = short
    F, inv = _table()
    tau, h = blue.params["thrusters.T1.time_constant"], cfg.time_h
    assert r.ok and r.thrust.shape == r.thrust_cmd.shape == r.command.shape == (31, 8)
    s = np.zeros(8)
    for k in range(30):
        np.testing.assert_allclose(r.thrust[k], F(s), rtol=1e-11, atol=1e-11)
        y = inv(r.thrust_cmd[k])
        np.testing.assert_allclose(r.command[k], np.where(y > 0, 1528 + y, np.where(y < 0, 1472 + y, 1500)),
                                   rtol=0, atol=1e-8)
        s = y + (s - y) * np.exp(-h / tau)
    assert np.abs(r.thrust_cmd - r.thrust).max() > 0.1  # the lag shows
    B = np.array(ca.DM(thrusters.B_T(view(blue.params))))
    np.testing.assert_allclose(r.tau_delivered, r.thrust @ B.T, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(metrics.chat(r.tau_delivered), r.chat_delivered, rtol=1e-12)
    np.testing.assert_allclose(metrics.chat(r.tau_cmd), r.chat, rtol=1e-12)
    chat, rmse = run.batch(run.default_gains()[None, :], seed=4, chat="delivered")
    np.testing.assert_array_equal(chat[0], r.chat_delivered)
    np.testing.assert_array_equal(rmse[0], r.rmse)


def test_plant_equals_cvodes_with_the_rotor_states(short, blue):
    """The closed loop's trajectory over its first 2 s against CVODES (1e-14) integrating the plant with the
    rotor states as ODE states (the textbook lag through the map's cubic, benchmarks/step_accuracy.py), the
    current and the tether: the scenario's plant step (h_plant = 0.01 s, the forcing by quadrature,
    ``time.thrust_quadrature = 5``) stays within 2e-7 m, rad (results/step's rule: 1e-6; plain RK4 with the
    thrust at its stage times and its own bound: tests/test_thrust_quadrature.py)."""
    sa = load_script("benchmarks/step_accuracy.py")
    cfg, run, r = short
    pv, n = blue.params.vector(), 20
    X = np.hstack([r.eta, r.nu])
    ys = sa.plant_inputs(pv, r, blue.layout)
    ref = sa.cvodes_states(cfg, pv, X[0], ys, r.phase, tol=1e-14, n_samples=n, layout=blue.layout)
    err = np.abs(X[:n + 1] - ref).max()
    print("closed loop with T200 dynamics and current vs CVODES over 2 s:", err)
    assert err < 2e-7
    assert np.abs(X[n] - X[0]).max() > 1e-3  # it does move


def test_committed_instantaneous_knee_reproduces_bit_for_bit(blue):
    """results/bluerov2 (instantaneous thrusters, the current as a wrench): the proposed knee's run
    again, with the thruster dynamics off and the scenario its file stores: every series bit for bit."""
    ref = read_result(ROOT / "results/bluerov2/knees/knee_proposed.h5")
    cfg = scenario.loads_scenario(ref.config_text, "knee_proposed.h5")
    assert cfg.current == "none" and not cfg.per_axis_sensors
    p = blue.params.instantaneous()
    assert ref.meta["param_names"] == p.names()
    p = p.replace(dict(zip(p.names(), ref.params_vector)))
    r = arvcas.Run("proposed", scenario=cfg, system=p).compile().simulate(
        seed=ref.seed, gains=ref.gains, uncertainty=ref.uncertainty, phase=ref.phase)
    np.testing.assert_array_equal(r.chat, ref.chat)
    np.testing.assert_array_equal(r.rmse, ref.rmse)
    for k in ref.series:
        np.testing.assert_array_equal(r.series[k], ref.series[k], err_msg=k)
    np.testing.assert_allclose(r.chat_delivered, metrics.chat(r.thrust @ np.array(
        ca.DM(thrusters.B_T(view(p)))).T), rtol=1e-12)  # instantaneous: eq. 42 on B sat(u)


def _by_thruster(x, n, fill):
    """The points ``x`` as columns of ``n`` (one per thruster), the last column padded with ``fill``."""
    cols = -(-x.size // n)
    return np.r_[x, np.full(cols * n - x.size, fill)].reshape(cols, n).T


def test_the_runs_map_and_inverse_are_scipys_pchip(blue):
    """The T200 map as a lockstep sample evaluates it (each rotor state's interval indexed at run time, one
    division on the uniform 4 us grid; the cubic in SX, ``cl_thr_wrench_iv``) at every 0.01 us of the command
    range, and its inverse (the interval searched on the values; Newton's steps in SX, ``cl_thr_lag_iv``):
    against SciPy's PchipInterpolator through the CSV and brentq. The cubic has the bits of the same formula
    evaluated element by element in MX, as the scalar run evaluates it."""
    F, inv = _table()
    cfg = scenario.load_scenario(blue.params.default("scenario"))
    _, _, lag, wrench = thrust_forcing.thruster_functions(cfg, blue.layout)  # the SX forms the lockstep run rewrites to lanes
    st = blue.layout.structure
    n, m_off = st.n_thrusters, len(thrust_forcing.lag_offsets(cfg))
    p = ca.DM(blue.params.vector())
    tab = thrust_forcing.thruster_constants(view(blue.params), cfg)[1]
    s_m, t_m, p_m, u_m = (ca.MX.sym(k, m) for k, m in (("s", n * m_off), ("tab", tab.shape[0]), ("p", p.shape[0]), ("u", n)))
    _, grids = thruster_tables.table_grids(st, t_m)
    iv = thruster_tables.stage_intervals(st, grids, s_m, m_off)
    ends = [(i + 1) * m_off - 1 for i in range(n)]  # each thruster's state at the sample's end: T_end
    mx = thrusters.hermite(*(c[ends] for c in iv), s_m[ends])
    f = ca.Function("f", [s_m, t_m, p_m], [wrench(*iv, s_m, p_m)[1], mx])
    x = np.linspace(-372.0, 372.0, 74401)
    X = _by_thruster(x, n, 0.0)
    S = np.zeros((n * m_off, X.shape[1]))
    S[ends, :] = X
    T_sx, T_mx = (np.array(a).T.ravel()[:x.size] for a in f.map(X.shape[1])(S, tab, p))
    assert np.array_equal(T_sx, T_mx)
    err = np.abs(T_sx - F(x))
    assert err.max() <= 1e-13, err.max()  # N (2.1e-14 measured: round-off at 51 N)
    # the inverse: the command sent for thrust u, back to its rotor state
    E = ca.MX.sym("E", lag.size1_in("E"))
    g = ca.Function("g", [u_m, t_m, p_m, E], [lag(ca.MX.zeros(n), u_m, *thruster_tables.target_intervals(st, grids, u_m), E, p_m)[1]])
    u = np.linspace(float(F(-372.0)), float(F(372.0)), 2001)
    u = u[u != 0]
    U = _by_thruster(u, n, 1.0)
    c = np.array(g.map(U.shape[1])(U, tab, p, np.ones(E.shape[0]))).T.ravel()[:u.size]
    s = np.where(c > 1528, c - 1528, c - 1472)
    assert np.abs(s - inv(u)).max() <= 1e-11, np.abs(s - inv(u)).max()  # us (2.8e-13 measured)
