"""The closed-loop run: compiled vs VM, metrics vs trace, batch vs single, EKF, bad input, divergence."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from arvcas.build import calls, codegen
from arvcas.sim import closedloop, profiles, scenario, schedule
from arvcas.controllers import gains
from arvcas import metrics
from arvcas.system.params import load as load_params
from arvcas.sim.simulation import SimulationError, simulate, simulate_batch


@pytest.fixture(scope="module")
def cfg():
    return scenario.load_scenario()


@pytest.fixture(scope="module")
def run_proposed(cfg):
    return simulate("proposed", seed=0, cfg=cfg)


@pytest.mark.floor  # casadi.extract_parametric (its floor, pyproject.toml) hoists the run's constants
def test_compiled_run_equals_vm(cfg):
    """The generated C of the whole run reproduces CasADi's VM on the same graph (docs/model.md §4)."""
    P = load_params()
    F = closedloop.build_run(closedloop.RunSpec("proposed", cfg), trace=False)
    args = (gains.default_gains("proposed"), profiles.noise_sequence(cfg, 1), cfg.uncertainty,
            np.array(cfg.disturbance_phase), cfg.ekf_vector, cfg.water_vector, P.vector(),
            *schedule.table(cfg, P.vector()))
    vm = calls.call(F, *args)
    # with the batch loop the run's library has: the same C as simulate's run, so its library, not compiled again
    cc = calls.call(codegen.build(F, extra_c=codegen.batch_loop_c(F)), *args)
    for a, b in zip(vm, cc):
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-14)


def test_metrics_of_trace_equal_accumulators(run_proposed):
    """CHAT/RMSE accumulated in the loop equal eq. 42/43 recomputed from the stored series."""
    r = run_proposed
    n = len(r.t) - 1
    assert n == 1000 and r.t[-1] == pytest.approx(100.0)
    np.testing.assert_allclose(metrics.chat(r.tau_cmd), r.chat, rtol=1e-12)
    np.testing.assert_allclose(metrics.rmse(r.e[:n]), r.rmse, rtol=1e-12)


def test_batch_equals_single_and_gains_are_inputs(cfg, run_proposed):
    """simulate_batch rows equal simulate; new gain sets and seeds do not recompile."""
    g0 = gains.default_gains("proposed")
    G = np.stack([g0, g0 * 1.05, g0 * 0.97])
    simulate_batch("proposed", G[:1], seed=3, cfg=cfg)  # the metrics-only run, built (or loaded) once
    before = codegen.stats()["compile"]
    chat, rmse = simulate_batch("proposed", G, seed=0, cfg=cfg)
    np.testing.assert_allclose(chat[0], run_proposed.chat, rtol=1e-12)
    np.testing.assert_allclose(rmse[0], run_proposed.rmse, rtol=1e-12)
    assert not np.allclose(chat[1], chat[0])
    other = simulate("proposed", seed=7, cfg=cfg)
    assert codegen.stats()["compile"] == before  # run functions already built above and by the fixtures
    assert not np.allclose(other.chat, run_proposed.chat)


def test_same_seed_same_result(cfg, run_proposed):
    again = simulate("proposed", seed=0, cfg=cfg)
    np.testing.assert_array_equal(again.chat, run_proposed.chat)
    np.testing.assert_array_equal(again.eta, run_proposed.eta)


def test_ekf_reduces_measurement_error(run_proposed, cfg):
    """The EKF estimate is closer to the truth than the raw measurements (section 4.1)."""
    r = run_proposed
    noise = profiles.noise_sequence(cfg, r.seed)[:6].T
    raw = np.sqrt(np.mean(noise[10:] ** 2, axis=0))
    est = np.sqrt(np.mean((r.eta_hat - r.eta)[10:] ** 2, axis=0))
    assert (est < 0.5 * raw).all(), (est, raw)


def test_station_keeping_and_references(run_proposed):
    """The vehicle is held: errors of the order of Table 3, the ATD reference converges to eta_d."""
    r = run_proposed
    assert r.ok
    assert np.all(r.rmse < 1e-2)
    assert np.abs(r.eta_ref[-1]).max() < 1e-6  # ATD y1 -> eta_d = 0 well within T
    assert np.abs(r.eta[-100:]).max() < 0.02
    # the arm moves and the payload ramps as docs/model.md §4 says
    assert r.payload[0] == 0 and r.payload[-1] == 1
    i = np.searchsorted(r.t, 20.0)
    np.testing.assert_allclose(np.degrees(r.q[i]), [60, 60, -60, 0, 60, 0], atol=1e-9)


def test_thrusts_respect_saturation(run_proposed):
    P = load_params()
    assert run_proposed.thrust.min() >= P["thrusters.u_min"] - 1e-9
    assert run_proposed.thrust.max() <= P["thrusters.u_max"] + 1e-9




def test_traditional_law_zigzags_proposed_does_not(cfg):
    """Fig. 10: the traditional decreasing law steps +-h l around k1min even while |s| <= sigma;
    the proposed law raises k1 only when s leaves the neighbourhood."""
    trad = simulate("traditional", seed=0, cfg=cfg)
    prop = simulate("proposed", seed=0, cfg=cfg)
    G = gains.unpack("proposed", gains.default_gains("proposed"))
    k1min, sigma = np.array(G["k1min"]), np.array(G["sigma"])

    def rises_inside(r):  # k1 increased although |s_k| <= sigma at that sample
        return int(((np.diff(r.k1, axis=0) > 0) & (np.abs(r.s[:-1]) <= sigma)).sum())

    def reversals_near_min(r):
        near = np.abs(r.k1[1:-1] - k1min) < 0.2 * k1min
        d = np.sign(np.diff(r.k1, axis=0))
        return int(((d[1:] * d[:-1] < 0) & near).sum())

    assert rises_inside(trad) > 100
    assert rises_inside(prop) == 0
    assert reversals_near_min(trad) > 20 * max(reversals_near_min(prop), 1)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"controller": "lqr"}, "unknown 'lqr'"),
        ({"gains": np.ones(5)}, "takes 66 gains"),
        ({"gains": -gains.default_gains("proposed")}, "must be > 0"),
        ({"gains": np.full(66, np.nan)}, "not finite"),
        ({"seed": 2**63}, r"0 <= seed < 2\*\*63"),  # checked before the run, not when storing it
        ({"seed": -1}, r"0 <= seed < 2\*\*63"),
    ],
)
def test_bad_input_one_line_errors(kwargs, match):
    kw = {"controller": "proposed"} | kwargs
    with pytest.raises(ValueError, match=match) as ei:
        simulate(**kw)
    assert "\n" not in str(ei.value)


def test_reso_stability_checked_before_running():
    g = gains.default_gains("proposed").copy()
    g[gains.gain_names("proposed").index("z.omega")] = 25.0  # h omega = 2.5
    with pytest.raises(ValueError, match="h\\*omega = 2.5 >= 2"):
        simulate("proposed", gains=g)


def test_joint_targets_outside_limits_refused(cfg):
    bad = dataclasses.replace(cfg, arm_qg=tuple(np.radians([60, 60, -60, 0, 120, 0])))
    with pytest.raises(ValueError, match="joint 5 target 120.00 deg outside Table 1 limits"):
        simulate("proposed", cfg=bad)


def test_params_type_checked():
    with pytest.raises(SimulationError, match="system: expected"):
        simulate("proposed", system={"env.rho": 1.0})


def test_divergence_is_reported_not_raised(cfg):
    """Gains that destabilise the loop end with ok = False, a failure time and NaN metrics."""
    g = gains.default_gains("agsta").copy()
    names = gains.gain_names("agsta")
    for d in gains.DOFS:
        g[names.index(f"{d}.mu2")] = 50.0  # a huge linear GSTA term: explicit Euler at h = 0.1 goes unstable
    r = simulate("agsta", gains=g, cfg=cfg)
    assert not r.ok and r.t_fail is not None and 0 <= r.t_fail < 100
    chat, rmse, ok, t_fail = simulate_batch("agsta", np.stack([gains.default_gains("agsta"), g]), cfg=cfg,
                                             return_status=True)
    assert ok.tolist() == [True, False]
    assert np.isnan(chat[1]).all() and np.isfinite(chat[0]).all()
    assert t_fail[1] == pytest.approx(r.t_fail)


def test_simulate_many_rows_equal_single_runs(cfg):
    """Monte Carlo batch: each row reproduces the single run with its own seed, factors and phases."""
    from arvcas.sim.simulation import simulate_many

    seeds = [0, 5, 9]
    U = np.array([cfg.uncertainty, [1.2, 0.8, 0.9, 0.5], [1.0, 1.0, 1.0, 1.0]])
    PH = np.array([cfg.disturbance_phase, np.zeros(6), np.full(6, 1.0)])
    chat, rmse, ok, _ = simulate_many("agsta", gains.default_gains("agsta"), seeds, uncertainty=U, phase=PH, cfg=cfg)
    assert ok.all()
    for i, sd in enumerate(seeds):
        r = simulate("agsta", seed=sd, cfg=cfg, uncertainty=U[i], phase=PH[i])
        np.testing.assert_array_equal(chat[i], r.chat)
        np.testing.assert_array_equal(rmse[i], r.rmse)
    assert len({tuple(c) for c in chat}) == 3


@pytest.mark.skipif(not codegen.supported_isa(), reason="this CPU has none of codegen.ISA_FLAGS' features")
def test_isa_flags_and_opt_levels_leave_every_output_bitwise_equal(cfg, monkeypatch):
    """The run built at -O2 with this CPU's instruction-set flags (-mavx), without them (ARVCAS_ISA=baseline)
    and at -O0 (the tests' level, tests/conftest.py) gives the same bits: chat, rmse, ok, t_fail of a running
    and of a diverging gain set."""
    P = load_params()
    F = closedloop.build_run(closedloop.RunSpec("agsta", cfg), trace=False)
    fast = codegen.build(F, opt_level="-O2")
    monkeypatch.setenv("ARVCAS_ISA", "baseline")
    base = codegen.build(F, opt_level="-O2")
    monkeypatch.delenv("ARVCAS_ISA")
    monkeypatch.setenv(codegen.OPT_LEVEL_ENV, "-O0")
    o0 = codegen.build(F, extra_c=codegen.batch_loop_c(F))  # the C of the run simulate("agsta") compiles: its library
    assert "-O0" in codegen.artifact_of(o0)["flags"]
    flags = codegen.artifact_of(fast)["flags"], codegen.artifact_of(base)["flags"]
    assert all(f in flags[0] for f in codegen.supported_isa()) and not any(f in flags[1] for f in codegen.supported_isa())
    g = gains.default_gains("agsta").copy()
    names = gains.gain_names("agsta")
    bad = g.copy()
    for d in gains.DOFS:
        bad[names.index(f"{d}.mu2")] = 50.0  # diverges (test_divergence_is_reported_not_raised)
    oks = []
    for gs in (g, bad):
        args = (gs, profiles.noise_sequence(cfg, 2), cfg.uncertainty, np.array(cfg.disturbance_phase),
                cfg.ekf_vector, cfg.water_vector, P.vector(), *schedule.table(cfg, P.vector()))
        out_fast, out_base, out_o0 = calls.call(fast, *args), calls.call(base, *args), calls.call(o0, *args)
        for a, b, c in zip(out_fast, out_base, out_o0):
            np.testing.assert_array_equal(a.view(np.uint64), b.view(np.uint64))
            np.testing.assert_array_equal(a.view(np.uint64), c.view(np.uint64))
        oks.append(float(out_fast[2].item()))
    assert oks == [1.0, 0.0]


def test_controller_alone_refuses_a_signal_of_the_plants_truth(cfg):
    """A law whose traced signal reads the plant's truth (here ``f_true``) cannot be exported: one line naming
    the law and the missing quantity (a ValueError, which ``export-controller`` reports as its own error)."""
    from arvcas.controllers.pid import PID
    from arvcas.sim.signals import Signal

    class PIDWithTruth(PID):
        name = "pid_with_truth"
        signals = PID.signals + (Signal("f_seen", 6, "N,N,N,N*m,N*m,N*m", "{n}", "x, y, z, phi, theta, psi",
                                        "the true total disturbance", lambda c: c.f_true),)

    with pytest.raises(ValueError, match=r"^controller pid_with_truth: a traced signal needs the plant's truth "
                                         r"\('StepContext' object has no attribute 'f_true'\)"):
        closedloop.controller_functions(PIDWithTruth(), cfg, load_params().layout)
