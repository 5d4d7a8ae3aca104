"""The thrusters' forcing by quadrature (``time.thrust_quadrature``, docs/model.md §9).

- the closed loop of the BlueROV2 with its T200s at h_plant = 0.01 s and 5 nodes per half step against
  CVODES (1e-14) with the rotor states as ODE states (benchmarks/step_accuracy.py's reference, as
  tests/test_thruster_loop.py does for the shipped step), and the plain RK4 at the same step, measured in
  the same test: the quadrature must be within 2e-7 m, rad and at least 10x closer than the plain RK4;
- the generated plant step against an independent implementation of the same method in NumPy
  (benchmarks/bluerov2_step.py's ``transformed_states``, A interpolated from the three stage times as the
  generated code does): equal to round-off;
- the same with spin-up and spin-down constants and a rate limit (the lag's reversals and ramps);
- lockstep lanes equal to the scalar run bit for bit;
- refused without thruster dynamics (Haidou-1) and by the exported controller's ``close_loop``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import arvcas
from arvcas.build import codegen
from arvcas.controllers import gains as gains_mod
from arvcas.sim import closedloop, lockstep, scenario
from arvcas.sim.run import Run, SimulationError
from script_helpers import load_script



def _module(name: str):
    return load_script(f"benchmarks/{name}.py")


@pytest.fixture(scope="module")
def blue():
    return arvcas.load_system("bluerov2_heavy_alpha5")


@pytest.fixture(scope="module")
def runs(blue):
    """3 s of the shipped scenario at h_plant = 0.01 s: with quadrature (5 nodes, the shipped setting) and without."""
    cfg = dataclasses.replace(scenario.load_scenario(blue.params.default("scenario")), time_duration=3.0,
                              time_h_plant=0.01, time_thrust_quadrature=None)
    quad = Run("proposed", scenario=dataclasses.replace(cfg, time_thrust_quadrature=5), system=blue).compile()
    plain = Run("proposed", scenario=cfg, system=blue).compile()
    return quad, quad.simulate(seed=4), plain, plain.simulate(seed=4)


def test_quadrature_is_closer_to_cvodes_than_rk4_at_the_same_step(runs, blue):
    sa = _module("step_accuracy")
    quad, rq, plain, rp = runs
    pv, n = blue.params.vector(), 20
    errs = {}
    for name, r in (("quadrature", rq), ("rk4", rp)):
        X = np.hstack([r.eta, r.nu])
        ref = sa.cvodes_states(quad.cfg, pv, X[0], sa.plant_inputs(pv, r, blue.layout), r.phase, tol=1e-14,
                               n_samples=n, layout=blue.layout)
        errs[name] = np.abs(X[:n + 1, :6] - ref[:, :6]).max()
        assert np.abs(X[n] - X[0]).max() > 1e-3  # it does move
    print("closed loop vs CVODES over 2 s at h_plant 0.01 s (m, rad):", errs)
    assert errs["quadrature"] < 2e-7
    assert errs["quadrature"] * 10 < errs["rk4"]


@pytest.fixture(scope="module")
def asymmetric(tmp_path_factory):
    """The BlueROV2 with a spin-down constant of 0.04 s beside the 0.0167 s spin-up, and a rate limit of
    6000 us/s: the lag's closed form with its reversals (a kink where a rotor stops) and ramps."""
    import re
    import shutil

    d = tmp_path_factory.mktemp("asym")
    data = Path(arvcas.__file__).parent / "data"
    for f in ("bluerov2_heavy_alpha5.scenario.toml", "bluerov2_heavy_alpha5.gains.toml", "t200_16v.csv"):
        shutil.copy(data / f, d / f)
    text, n = re.subn(r'time_constant = \{ value = 0\.0167, unit = "s", source = "[^"]*" \}',
                      'time_constant_up = { value = 0.0167, unit = "s", source = "test" }\n'
                      'time_constant_down = { value = 0.04, unit = "s", source = "test" }\n'
                      'rate_limit = { value = 6000.0, unit = "us/s", source = "test" }',
                      (data / "bluerov2_heavy_alpha5.toml").read_text())
    assert n == 8
    (d / "asym.toml").write_text(text.replace('name = "bluerov2_heavy_alpha5"', 'name = "bluerov2_asym"', 1))
    return arvcas.load_system(str(d / "asym.toml"))


def test_asymmetric_lag_with_rate_limit_against_cvodes(asymmetric):
    """Spin-up and spin-down constants and a rate limit (reversals: the rotor stops, then spins up; ramps):
    the quadrature at h_plant = 0.01 s against CVODES over 2 s, beside the plain RK4 at the same step
    (measured 4.7e-8 against 1.5e-5 m, rad; plain RK4 at 0.0025 s gives 1.1e-7)."""
    s = asymmetric
    assert all(d.asymmetric and d.rate_limit for d in s.structure.thruster_dynamics)
    sa = _module("step_accuracy")
    cfg = dataclasses.replace(scenario.load_scenario(s.params.default("scenario")), time_duration=3.0, time_h_plant=0.01,
                              time_thrust_quadrature=None)
    pv, n, errs = s.params.vector(), 20, {}
    for name, c in (("quadrature", dataclasses.replace(cfg, time_thrust_quadrature=5)), ("rk4", cfg)):
        r = Run("proposed", scenario=c, system=s).compile().simulate(seed=4)
        X = np.hstack([r.eta, r.nu])
        ref = sa.cvodes_states(c, pv, X[0], sa.plant_inputs(pv, r, s.layout), r.phase, tol=1e-14, n_samples=n,
                               layout=s.layout)
        errs[name] = np.abs(X[:n + 1, :6] - ref[:, :6]).max()
        assert (np.diff(np.sign(r.thrust[:n + 1]), axis=0) != 0).sum() >= 3  # reversals happen
    print("asymmetric lag, rate limit, vs CVODES over 2 s (m, rad):", errs)
    assert errs["quadrature"] < 2e-7
    assert errs["quadrature"] * 10 < errs["rk4"]


def test_generated_step_equals_the_numpy_method(runs, blue):
    """The compiled run's states against ``transformed_states`` driven by the run's own rotor targets, A
    quadratic through the stage times: the same method, written independently, equal to round-off."""
    sa, bs = _module("step_accuracy"), _module("bluerov2_step")
    quad, rq, _, _ = runs
    pv, n = blue.params.vector(), 20
    X = np.hstack([rq.eta, rq.nu])
    cfg = quad.cfg
    A = bs.transformed_states(sa, cfg, pv, X[0], sa.plant_inputs(pv, rq, blue.layout), rq.phase, blue.layout,
                              (cfg.time_h_plant,) * cfg.substeps, cfg.time_thrust_quadrature, n, "quadratic")
    d = np.abs(A - X[:n + 1]).max()
    print("generated vs NumPy, same method:", d)
    assert d < 1e-10


def test_lockstep_equals_the_scalar_run_bitwise(runs):
    quad = runs[0]
    spec = closedloop.RunSpec(quad.controller, quad.cfg.graph_key(), quad.opts, quad.params.layout)
    quad._fns[False] = codegen.build(closedloop.build_run(spec, False), opt_level="-O0")
    quad._lockstep = lockstep.build(quad, opt_level="-O0")
    g0 = quad.default_gains()
    rng = np.random.default_rng(2)
    up = gains_mod.upper_limits(quad.controller, quad.cfg.time_h) * 0.95
    G = np.vstack([g0 * rng.uniform(0.8, 1.2, (5, g0.size)), np.minimum(g0 * 100, up)])  # the last one diverges
    ref = quad.batch(G, seed=3, n_threads=1, return_status=True, lockstep=False)
    got = quad.batch(G, seed=3, n_threads=2, return_status=True, lockstep=True)
    for a, b in zip(ref, got):
        assert a.tobytes() == b.tobytes()
    assert ref[2][:5].all() and not ref[2][5]


def test_refused_without_thruster_dynamics_and_by_close_loop(runs):
    cfg = dataclasses.replace(scenario.load_scenario(), time_thrust_quadrature=3)
    with pytest.raises(SimulationError, match=r"time.thrust_quadrature: only for a system with thruster dynamics"):
        Run("proposed", scenario=cfg).compile()
    from arvcas.export.closeloop import ExportError, close_loop

    with pytest.raises(ExportError, match=r"time.thrust_quadrature"):
        close_loop(None, runs[0])
