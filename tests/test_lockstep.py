"""Lockstep runs: W runs per core, every lane's outputs equal to the scalar run's bits.

The lane rewrite (arvcas/build/lanes.py) on every operation it handles, at special values (signed zeros,
subnormals, infinities, NaN, large arguments), against CasADi's scalar code; then whole runs: every
controller on Haidou-1 and some on the BlueROV2 systems (with the T200 dynamics, current and tether), with running and diverging members, a group
whose runs all diverge (it stops early) and a short last group, through the public batch/many path.
The run tests build both libraries at -O0 (no optimisation level changes a result: -ffp-contract=off;
one test compares -O2 lanes with the -O2 scalar run) and a 3 s scenario, to keep their compile time small.
"""

from __future__ import annotations

import ctypes
import dataclasses
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from arvcas.build import codegen, lanes
from arvcas.controllers import gains as gains_mod
from arvcas.sim import closedloop, lockstep, run as run_mod
from arvcas.sim.run import Run, SimulationError
from arvcas.sim.scenario import load_scenario

SPECIAL = [0.0, -0.0, 1.0, -1.0, 0.5, -2.5, 3.7, 1e-310, -1e-310, 1e308, -1e308, np.inf, -np.inf, np.nan, 1e6,
           0.9, 1.2, -1.7, 2.2, 1e22, 7.0]


def _op_function() -> ca.Function:
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    e = [x + y, x - y, x * y, x / y, -x, x < y, x <= y, x == y, x != y, ca.logic_not(x), ca.logic_and(x, y),
         ca.logic_or(x, y), ca.if_else(x, y, 2 * x), ca.if_else(x, y, 0), x**2, ca.fabs(x), ca.sign(x),
         ca.fmax(x, y), ca.fmin(x, y), ca.sqrt(x), ca.sin(x), ca.cos(x), ca.tan(x), ca.sin(y), ca.exp(x), ca.log(x),
         x**y, x**3.5, ca.atan2(x, y), ca.floor(x), ca.ceil(x), ca.fmod(x, y), ca.tanh(x), ca.asin(x), ca.acos(x),
         ca.atan(x), ca.sinh(x), ca.cosh(x), ca.log1p(x), ca.expm1(x), ca.hypot(x, y), ca.erf(x), 0.1 * x + 3,
         x + ca.inf, ca.cos(y) * ca.sin(y)]
    return ca.Function("lnops", [x, y], [ca.vertcat(*e)])


@pytest.mark.floor  # build/lanes.py parses the C of the installed CasADi (its floor and cap: pyproject.toml)
def test_lane_rewrite_equals_scalar_code_bitwise():
    """Every operation of the rewrite on W lanes of special values equals CasADi's scalar C to the bit."""
    f = _op_function()
    W = lanes.lane_width()
    wrapper = (lanes.header(W) + lanes.lane_functions([(f, "lnops_lanes", [False, False])]) +
               "CASADI_SYMBOL_EXPORT int lnops_lanes_call(const double** arg, double** res) "
               "{ lnops_lanes(arg, res); return 0; }\n")
    lib_f = codegen.build(f, extra_c=wrapper)
    lib = ctypes.CDLL(codegen.artifact_of(lib_f)["path"])
    call = lib.lnops_lanes_call
    call.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    pairs = [(a, b) for a in SPECIAL for b in SPECIAL]
    pairs += [(a, b) for a, b in np.random.default_rng(3).normal(0, 3, (64, 2))]
    pairs += [pairs[-1]] * (-len(pairs) % W)
    n_out = f.size1_out(0)
    for i in range(0, len(pairs), W):
        xs = np.array([p[0] for p in pairs[i:i + W]])
        ys = np.array([p[1] for p in pairs[i:i + W]])
        out = np.empty(n_out * W)
        A = (ctypes.c_void_p * 2)(xs.ctypes.data, ys.ctypes.data)
        R = (ctypes.c_void_p * 1)(out.ctypes.data)
        call(A, R)
        for l in range(W):
            ref = np.array(lib_f(xs[l], ys[l])).ravel()
            got = out[l::W]
            bad = np.nonzero(ref.view(np.uint64) != got.view(np.uint64))[0]
            assert bad.size == 0, f"x={xs[l]!r} y={ys[l]!r}: outputs {bad.tolist()}: {ref[bad]} vs {got[bad]}"


@pytest.mark.floor
def test_lane_rewrite_refuses_what_it_does_not_know():
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    with pytest.raises(lanes.LaneError, match="lanes: pm: an operation the rewrite does not handle: casadi_printme"):
        lanes.lane_functions([(ca.Function("pm", [x, y], [x.printme(y)]), "pm_l", [])])
    mx = ca.MX.sym("x")
    with pytest.raises(lanes.LaneError, match="only SX functions"):
        lanes.lane_functions([(ca.Function("mx", [mx], [2 * mx]), "mx_l", [])])
    with pytest.raises(ValueError, match="W must be 2, 4 or 8"):
        lanes.header(3)


def _short_run(system: str, law: str, duration: float = 3.0, limit: float | None = None):
    # hinsdale_bluerov2_alpha5 (validation only) has no scenario of its own: the BlueROV2's (with its current
    # and tether), without its thrust quadrature (the Hinsdale thrusters deliver their thrust at once)
    scen = None
    if system == "hinsdale_bluerov2_alpha5":
        scen = dataclasses.replace(load_scenario(SYSTEMS / "bluerov2_heavy_alpha5.scenario.toml"),
                                   time_thrust_quadrature=None)
    r = Run(controller=law, system=system, scenario=scen).compile()
    cfg = dataclasses.replace(r.cfg, time_duration=duration)
    if limit is not None:  # tracking-error bounds that some members cross (a stop by the error bound)
        cfg = dataclasses.replace(cfg, limits_e_position=limit, limits_e_attitude=limit)
    return Run(controller=law, system=system, scenario=cfg).compile()


SYSTEMS = Path(closedloop.__file__).resolve().parents[1] / "data"


def _members(run, n_run: int = 5, n_div: int = 4, seed: int = 0):
    """Gain sets: running members around the defaults, 4 that diverge (100x the defaults, below the gains'
    limits), a row of 0.02x; per-run seeds, uncertainty factors and phases."""
    name = run.params.structure.name
    g0 = gains_mod.default_gains(run.controller, "bluerov2_heavy_alpha5" if name == "hinsdale_bluerov2_alpha5" else run.params)
    up = gains_mod.upper_limits(run.controller, run.cfg.time_h) * 0.95
    rng = np.random.default_rng(seed)
    run_rows = np.minimum(g0 * rng.uniform(0.7, 1.4, (n_run, g0.size)), up)
    div_rows = np.minimum(g0 * 100 * rng.uniform(1.0, 1.2, (n_div, g0.size)), up)
    G = np.vstack([run_rows[:4], div_rows, run_rows[4:], np.minimum(g0 * 0.02, up)])
    n = G.shape[0]
    U = np.asarray(run.cfg.uncertainty) * rng.uniform(0.8, 1.2, (n, 4))
    PH = rng.uniform(-np.pi, np.pi, (n, 6))
    return G, np.arange(n) + 7, U, PH


# (system, controller, tracking-error bound or None, whether rows 4-7 all diverge); Haidou-1's PID does
# not diverge at any allowed gain within 3 s: its members stop by a tighter error bound
# the floor job (docs/testing.md) runs one: a whole run's C through the lane rewrite at CasADi's floor
CASES = [pytest.param("haidou1", law, None, True, marks=[pytest.mark.floor] if law == "agsta" else [])
         for law in ("proposed", "agsta", "traditional", "implicit")] + [
    ("haidou1", "pid", 0.02, False), ("bluerov2_heavy_alpha5", "proposed", None, True),
    ("bluerov2_heavy_alpha5", "pid", None, False), ("hinsdale_bluerov2_alpha5", "agsta", None, False)]


@pytest.mark.parametrize("system,law,limit,group", CASES)
def test_lockstep_runs_equal_scalar_runs_bitwise(system, law, limit, group):
    """Every lane's chat, rmse, ok and t_fail equal the scalar run's bits: running and diverging runs, a
    group of only diverged runs (rows 4-7: it stops early), a short last group (copies of its last run)."""
    run = _short_run(system, law, limit=limit)
    spec = closedloop.RunSpec(run.controller, run.cfg.graph_key(), run.opts, run.params.layout)
    run._fns[False] = codegen.build(closedloop.build_run(spec, False), opt_level="-O0")  # the reference
    run._lockstep = lockstep.build(run, opt_level="-O0")
    G, seeds, U, PH = _members(run)
    ref = run.many(G, seeds, uncertainty=U, phase=PH, n_threads=1, lockstep=False)
    got = run.many(G, seeds, uncertainty=U, phase=PH, n_threads=2, lockstep=True)
    for a, b, name in zip(ref, got, ("chat", "rmse", "ok", "t_fail")):
        assert a.tobytes() == b.tobytes(), f"{system} / {law}: {name} differs: {a} vs {b}"
    ref_d, got_d = (run.many(G, seeds, uncertainty=U, phase=PH, chat="delivered", lockstep=lock)[0] for lock in (False, True))
    assert ref_d.tobytes() == got_d.tobytes(), f"{system} / {law}: chat_delivered differs: {ref_d} vs {got_d}"
    ok = ref[2]
    assert ok.any() and not ok.all(), f"{system} / {law}: expected running and diverging members, ok = {ok}"
    assert not group or not ok[4:8].any(), f"{system} / {law}: rows 4-7 should all diverge: {ok}"


def test_lockstep_default_build_through_batch_and_many(monkeypatch):
    """The default (-O2, this CPU's W) lockstep run against the default scalar run, through batch (shared
    noise and disturbance) and many, 2 threads, a batch size that is not a multiple of W."""
    monkeypatch.setenv(codegen.OPT_LEVEL_ENV, codegen.DEFAULT_OPT_LEVEL)  # not the tests' -O0 (tests/conftest.py)
    run = _short_run("haidou1", "proposed", duration=2.0)
    G, seeds, U, PH = _members(run, n_run=4, n_div=2, seed=1)
    assert run.lockstep().W == lanes.lane_width()
    for lock in (False, True):
        out = run.batch(G, seed=3, n_threads=2, return_status=True, lockstep=lock)
        if lock:
            assert all(a.tobytes() == b.tobytes() for a, b in zip(ref, out))
        ref = out
    ref = run.many(G[:3], seeds[:3], uncertainty=U[:3], phase=PH[:3], lockstep=False)
    got = run.many(G[:3], seeds[:3], uncertainty=U[:3], phase=PH[:3], lockstep=True)
    assert all(a.tobytes() == b.tobytes() for a, b in zip(ref, got))


def test_lockstep_choice(monkeypatch):
    """lockstep=None: at least LOCKSTEP_MIN_RUNS runs, unless ARVCAS_LOCKSTEP=0; bad values refused."""
    run = Run().compile()
    monkeypatch.setattr(run, "lockstep", lambda: object())
    assert run.uses_lockstep(run_mod.LOCKSTEP_MIN_RUNS) and not run.uses_lockstep(run_mod.LOCKSTEP_MIN_RUNS - 1)
    assert run.uses_lockstep(1, True) and not run.uses_lockstep(10**6, False)
    monkeypatch.setenv("ARVCAS_LOCKSTEP", "0")
    assert not run.uses_lockstep(10**6)
    monkeypatch.setenv("ARVCAS_LOCKSTEP", "1")
    assert run.uses_lockstep(1)
    monkeypatch.setenv("ARVCAS_LOCKSTEP", "yes")
    with pytest.raises(SimulationError, match="ARVCAS_LOCKSTEP='yes': expected 0"):
        run.uses_lockstep(1)
    with pytest.raises(SimulationError, match="lockstep: expected True, False or None"):
        run.uses_lockstep(1, 1)
