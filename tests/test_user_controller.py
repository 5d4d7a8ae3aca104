"""A controller written outside the package: registered, simulated, tuned in a tiny study, its
results written and read back, without editing arvcas. And: a traced signal is one table entry.

The toy law is a per-DOF PD on the reference error with a first-order filter on the command (so it
has a state, an initial value and an extra traced signal):

    u_raw = Mhat (-kp e - kd e_dot),  tau_eta(k) = tau_eta(k-1) + (h / T) (u_raw - tau_eta(k-1))

Its numbers are checked against an independent NumPy re-computation from the trace.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import arvcas
from arvcas.controllers import gains as gains_mod
from arvcas.io.results import read_result, write_result
from arvcas.model.spatial import J
from arvcas.sim import signals as signals_mod
from arvcas.sim.signals import DOFS, WRENCH_UNITS, Signal
from arvcas.tuning import loads_study, run_study
from arvcas.tuning.front import read_front
from studytext import tiny_study

T_FILTER = 0.5  # s


class FilteredPD(arvcas.Controller):
    name = "toy_filtered_pd"
    description = "PD on the reference error with a first-order command filter (a test's own law)"
    gains = (arvcas.Gain("kp", "1/s^2", "proportional"), arvcas.Gain("kd", "1/s", "derivative"))
    defaults = [0.6, 1.6] * 6
    defaults_block = "toy"  # not in the gain table: `defaults` is used
    state = (("tau_f", 6),)
    signals = (Signal("tau_eta_f", 6, WRENCH_UNITS, "{n}", DOFS, "filtered command in {n}", lambda c: c.out["tau_f"]),
               Signal("e_dot", 6, signals_mod.RATE_UNITS, "{n}", DOFS, "error rate eta_dot_hat - y2", lambda c: c.e_dot))

    def initial(self, ctx, G):
        return {"tau_f": ca.DM.zeros(6)}

    def step(self, ctx, G, x):
        raw = ctx.Mhat * (-G["kp"] * ctx.e - G["kd"] * ctx.e_dot)
        tau_f = x["tau_f"] + (ctx.h / T_FILTER) * (raw - x["tau_f"])
        ctx.out["tau_f"] = tau_f
        return ca.mtimes(J(ctx.eta_hat).T, tau_f), {"tau_f": tau_f}


@pytest.fixture(scope="module")
def toy():
    c = arvcas.register_controller(FilteredPD(), replace=True)
    yield c
    arvcas.controllers.unregister(c.name)


@pytest.fixture(scope="module")
def toy_result(toy):
    return arvcas.Run(controller=toy.name).compile().simulate(seed=3)


def test_registered_and_described(toy):
    assert toy.name in arvcas.controllers.names()
    assert gains_mod.gain_names(toy.name)[:2] == ["x.kp", "x.kd"]
    np.testing.assert_array_equal(gains_mod.default_gains(toy.name), [0.6, 1.6] * 6)
    with pytest.raises(ValueError, match="exists"):
        arvcas.register_controller(FilteredPD())  # a second instance under the same name needs replace=True


def test_simulates_and_its_law_holds(toy_result):
    """The framework feeds the law its state, first value and context: the filter recursion holds
    sample by sample from the traced e, e_dot (independent NumPy re-computation), and tau_cmd = J^T tau_f."""
    r = toy_result
    assert r.ok and r.controller == "toy_filtered_pd"
    assert r.tau_eta_f.shape == (len(r.t), 6) and r.e_dot.shape == (len(r.t), 6)
    kp, kd, h = 0.6, 1.6, r.h
    e = r.eta_hat - r.eta_ref
    raw = _mhat() * (-kp * e - kd * r.e_dot)
    prev = np.vstack([np.zeros(6), r.tau_eta_f[:-1]])  # the state starts at 0 (initial())
    np.testing.assert_allclose(r.tau_eta_f, prev + (h / T_FILTER) * (raw - prev), rtol=1e-10, atol=1e-9)
    for k in (1, 100, 500, len(r.t) - 1):
        Jk = np.asarray(ca.DM(J(ca.DM(r.eta_hat[k]))))
        np.testing.assert_allclose(r.tau_cmd[k], Jk.T @ r.tau_eta_f[k], rtol=1e-12, atol=1e-9)
    assert np.all(np.abs(r.eta[200:, :3]) < 0.1)  # it station-keeps (10 cm)


def _mhat():
    from arvcas.model import vehicle
    from arvcas.system.params import load, view

    return np.diag(np.asarray(ca.DM(vehicle.M(view(ca.DM(load().vector()))))))


def test_result_file_round_trip(toy_result, tmp_path):
    p = write_result(toy_result, tmp_path / "toy.h5")
    back = read_result(p)
    assert list(back.series) == list(toy_result.series)
    np.testing.assert_array_equal(back.tau_eta_f, toy_result.tau_eta_f)
    sig = {s.name: s for s in back.signals}["tau_eta_f"]
    assert sig.units == WRENCH_UNITS and sig.frame == "{n}"


STUDY = tiny_study(controller="toy_filtered_pd", seed=5, population=6, generations=2, include_table2=True, name="toy")


def test_tuned_in_a_tiny_study(toy, tmp_path):
    study = loads_study(STUDY, "toy.toml")
    out = run_study(study, tmp_path / "out", say=lambda m: None)
    assert len(out) == 1
    front = read_front(tmp_path / "out" / "front.h5")
    assert front.F.shape[1] == 2 and np.isfinite(front.F).all() and len(front.F) >= 1
    # a member's stored metrics are what the compiled run gives for its gains (same noise draw)
    run = arvcas.Run(controller=toy.name).compile()
    chat, rmse = run.batch(front.gains[:1], seed=0)
    np.testing.assert_array_equal(chat[0], np.asarray(front.chat)[0, 0])  # (draw, member, DOF)


def test_a_traced_signal_is_one_table_entry(monkeypatch, tmp_path):
    """Adding a signal to the table: the trace, the Result, the result file and the labels all have it."""
    extra = Signal("e_true", 6, signals_mod.POSE_UNITS, "{n}", DOFS, "true error eta - eta_ref",
                   lambda c: c.eta - c.eta_ref)
    monkeypatch.setattr(signals_mod, "COMMON", signals_mod.COMMON + (extra,))
    from arvcas.sim import simulation

    monkeypatch.setattr(simulation, "_COMPILED", {})
    from arvcas.sim import run as run_mod

    monkeypatch.setattr(run_mod, "_FUNCTIONS", {})
    cr = arvcas.Run(controller="pid").compile()
    # the new table is part of the description only through the package's source; key it apart here
    monkeypatch.setattr(cr, "description", lambda trace, _d=cr.description: _d(trace) + " +e_true")
    r = cr.simulate(seed=1)
    np.testing.assert_allclose(r.e_true, r.eta - r.eta_ref, rtol=0, atol=1e-15)
    back = read_result(write_result(r, tmp_path / "r.h5"))
    np.testing.assert_array_equal(back.e_true, r.e_true)
    assert {s.name: s for s in back.signals}["e_true"].description == extra.description
    assert signals_mod.label(extra, 3) == "phi [rad]"
