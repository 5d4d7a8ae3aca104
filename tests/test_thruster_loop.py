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
from arvcas.model import thrusters
from arvcas.system.params import view
from arvcas.sim import closedloop, scenario, schedule

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
    run = arvcas.Run("proposed", scenario=cfg, params=blue).compile()
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
    import importlib.util

    spec = importlib.util.spec_from_file_location("step_accuracy", ROOT / "benchmarks" / "step_accuracy.py")
    sa = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sa)
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
    r = arvcas.Run("proposed", scenario=cfg, params=p).compile().simulate(
        seed=ref.seed, gains=ref.gains, uncertainty=ref.uncertainty, phase=ref.phase)
    np.testing.assert_array_equal(r.chat, ref.chat)
    np.testing.assert_array_equal(r.rmse, ref.rmse)
    for k in ref.series:
        np.testing.assert_array_equal(r.series[k], ref.series[k], err_msg=k)
    np.testing.assert_allclose(r.chat_delivered, metrics.chat(r.thrust @ np.array(
        ca.DM(thrusters.B_T(view(p)))).T), rtol=1e-12)  # instantaneous: eq. 42 on B sat(u)
