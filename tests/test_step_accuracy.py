"""The reference machinery of benchmarks/step_accuracy.py on short horizons (independent of the study).

The study compares the closed loop's RK4 trajectory with CVODES driven by the run's own held thrust
(``cvodes_states``). Checked here: (1) an independent textbook RK4 of the same ODE (``rk4_states``)
agrees with CVODES to 1e-9 at h_plant = 0.01 s, and its error falls ~16x per halving of the step (order
4 +- 0.5), on a 3 s window of a compressed scenario whose arm reaches, takes the payload and returns
(every kink on the sample grid, as in the packaged scenario); (2) the compiled closed loop, driven by
its own controller, matches CVODES on its first 2 s: to 1e-9 at h_plant = 0.01 s, and to 1e-8 at the
packaged step 0.05 s (results/step: 1.6e-8 m worst over 100 s and 52 runs; the rule 1e-6).
(3) the study itself in its quick mode, for each shipped system, on a 3 s horizon: its reference
machinery (CVODES at two tolerances, 1e-12 and 1e-13, the textbook RK4 against the closed loop's own trajectory, with
thruster dynamics driven by the lag's closed form, the closed loop against CVODES at 0.01 s) agrees and the
report renders.
Accuracy only: no timing is asserted.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from arvcas.sim.scenario import load_scenario
from script_helpers import load_script

sa = load_script("benchmarks/step_accuracy.py")

N = 30  # samples of 0.1 s: a 3 s window


@pytest.fixture(scope="module")
def case(params):
    # the arm reaches over 0.5-1.5 s, the payload ramps in over 1.6-1.8 s, the arm returns over 2.0-3.0 s
    cfg = dataclasses.replace(load_scenario(), arm_hold_until=0.5, arm_reach_end=1.5, arm_payload_on=1.6,
                              arm_payload_ramp=0.2, arm_return_start=2.0, arm_return_end=3.0)
    t = np.arange(N + 1) * cfg.time_h
    # a held body wrench that varies from sample to sample (a zero-order hold like the closed loop's)
    taus = np.stack([5 * np.sin(3 * t), 5 * np.cos(2 * t), 20 + 3 * np.sin(2.5 * t),
                     2 * np.sin(4 * t), 3 * np.sin(3.5 * t), 3 * np.sin(1.5 * t)], axis=1)
    x0 = np.array(cfg.initial_eta0 + cfg.initial_nu0)
    pv, ph = params.vector(), np.array(cfg.disturbance_phase)
    ref = sa.cvodes_states(cfg, pv, x0, taus, ph, tol=1e-14, n_samples=N)
    return cfg, pv, x0, taus, ph, ref


def test_reference_converged(case):
    cfg, pv, x0, taus, ph, ref = case
    fine = sa.cvodes_states(cfg, pv, x0, taus, ph, tol=1e-15, n_samples=N)
    assert ref.shape == (N + 1, 12) and np.isfinite(ref).all()
    assert np.abs(ref - x0).max() > 1e-3  # the state does move
    assert 0 < np.abs(fine - ref).max() < 1e-11  # another integration (the reference is built per tolerance)


def test_rk4_matches_cvodes_and_order_four(case):
    cfg, pv, x0, taus, ph, ref = case
    err = {hp: np.abs(sa.rk4_states(cfg, pv, x0, taus, ph, hp, n_samples=N) - ref).max() for hp in (0.01, 0.025, 0.05)}
    print("RK4 error vs CVODES:", err)
    assert err[0.01] < 1e-9
    order = np.log2(err[0.05] / err[0.025])
    assert 3.5 < order < 4.5, (err, order)
    assert err[0.01] < err[0.025] < err[0.05]


@pytest.mark.parametrize("h_plant,bound", [(0.01, 1e-9), (None, 1e-8)], ids=["0.01 s", "packaged step"])
def test_closed_loop_matches_cvodes_on_its_own_thrust(params, h_plant, bound):
    import arvcas

    cfg = load_scenario()
    if h_plant is not None:
        cfg = dataclasses.replace(cfg, time_h_plant=h_plant)
    r = arvcas.Run(controller="proposed", scenario=cfg).compile().simulate()
    X = np.hstack([r.eta, r.nu])
    n = 20
    ref = sa.cvodes_states(cfg, params.vector(), X[0], sa.held_wrench(params.vector(), r.thrust), r.phase,
                           tol=1e-14, n_samples=n)
    err = np.abs(X[: n + 1] - ref).max()
    print(f"closed loop at h_plant = {cfg.time_h_plant:g} s vs CVODES over 2 s:", err)
    assert err < bound
    assert np.abs(np.diff(r.thrust[: n + 1], axis=0)).max() > 0  # the thrust does change from sample to sample


@pytest.mark.parametrize("system", list(sa.SYSTEMS))
def test_quick_study_per_system(system):
    import arvcas

    # CVODES at 1e-12 (the study's default 1e-14): 7e-11 m, rad from the 1e-14 reference on the BlueROV2 over 1 s,
    # far below the bounds on the plant's error below (1e-7, 1e-4), and 1.6x faster
    res = sa.study(quick=True, system=system, duration=3.0, log=lambda *a: None, tol=1e-12)
    json.dumps(res)  # the JSON it writes
    sysm = arvcas.load_system(system)
    assert res["system"] == sysm.name and res["n_thrusters"] == sysm.n_thrusters and res["duration"] == 3.0
    assert [row["h_plant"] for row in res["table"]] == [0.01, 0.1]
    base = res["table"][0]
    # with thruster dynamics (the BlueROV2's T200s) plain RK4 at 0.01 s is far from the rule: the rotors sweep the
    # thrust table within a step (the study sets the scenario's thrust quadrature aside; the shipped step's tight
    # check: tests/test_thrust_quadrature.py, tests/test_thruster_loop.py)
    dyn = sysm.structure.has_thruster_dynamics
    bound = 1e-4 if dyn else 1e-7
    assert base["open_loop_vs_cvodes"]["position_m"] < bound and base["open_loop_vs_cvodes"]["angle_rad"] < bound
    assert res["convergence"]["closed_loop_vs_textbook_rk4"] < 1e-12
    assert res["reference_check"]["difference"]["position_m"] < 1e-10
    assert res["table"][1]["metric_runs"] > 0 and res["table"][1]["status_changed"] == 0
    assert res["fronts"]["proposed"]["path"].startswith("results/tuning/paper" if system == "haidou1" else "results/bluerov2")
    text = sa.markdown(res)
    # with thruster dynamics neither 0.01 nor 0.1 s passes, and the quick mode goes no finer
    assert f"--system {system}" in text and ("Recommended default step" in text or
                                             (dyn and "No step of the table passes the rule" in text))
