"""Objectives computed inside the compiled run (arvcas.sim.accumulate, arvcas.metrics.objectives) against
an independent computation in NumPy on the trace of the same run; constraints' parsing; the default run's
outputs unchanged by the accumulators."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from arvcas.metrics import objectives as O, table3
from arvcas.sim import scenario
from arvcas.sim.accumulate import event_times
from arvcas.sim.run import Run
from arvcas.system.params import load

BAND = (0.004, 0.01)  # m, rad: tight enough that the short run leaves it after both events


@pytest.fixture(scope="module")
def runs():
    """An 8 s Haidou-1 run (events at 0 and 5 s: the start and the reach), traced, and the same run with every
    built-in objective's accumulators, on two gain sets (Table 2, and Table 2 x 3 which saturates)."""
    cfg = dataclasses.replace(scenario.load_scenario(), time_duration=8.0)
    objs = [O.get(n) for n in O.names() if n != "settling_time"] + [O.get("settling_time", BAND)]
    plain = Run("proposed", cfg).compile()
    acc = Run("proposed", cfg, accumulators=O.accumulators_of(objs)).compile()
    g0 = plain.default_gains()
    G = np.vstack([g0, g0 * 3.0])
    traces = [plain.simulate(g, seed=3) for g in G]
    out = acc.outputs(G, seed=3, n_threads=1)
    params = load()
    ctx = O.Context(cfg=cfg, params=params, ref=None, chat="chat",
                    slices=O.slices(O.accumulators_of(objs), params.structure.n_thrusters, cfg))
    return cfg, {o.name: o for o in objs}, traces, out, ctx


def _k(cfg):  # the samples k = 0 .. N-1 the accumulators cover
    return slice(0, scenario.n_samples(cfg) - 1)


def test_default_outputs_unchanged(runs):
    cfg, _, traces, out, _ = runs
    for i, r in enumerate(traces):
        assert np.array_equal(out["chat"][i], r.chat) and np.array_equal(out["rmse"][i], r.rmse)
        assert np.array_equal(out["chat_delivered"][i], r.chat_delivered) and bool(out["ok"][i]) == r.ok


def test_objectives_against_the_trace(runs):
    cfg, objs, traces, out, ctx = runs
    h, ks = cfg.time_h, _k(cfg)
    P = load()
    lo, hi = P["thrusters.u_min"], P["thrusters.u_max"]
    lim = np.array([cfg.limits_e_position] * 3 + [cfg.limits_e_attitude] * 3)
    ev = list(event_times(cfg)) + [cfg.time_duration]
    assert ev == [0.0, 5.0, 8.0]
    for i, r in enumerate(traces):
        e = (r["eta"] - r["eta_ref"])[ks]
        T = r["thrust"][ks]
        t = r["t"][ks]
        want = {
            "iae": np.mean(h * np.abs(e).sum(axis=0) / lim),
            "energy": h * (np.abs(T) ** 1.5).sum(),
            "peak_thrust": np.abs(T).max(),
            "saturation_time": h * np.count_nonzero(((T >= hi) | (T <= lo)).any(axis=1)),
            "excursion": np.sqrt((e[:, :3] ** 2).sum(axis=1)).max(),
            "chat": np.mean(r.chat / table3().chat_agsta),
            "rmse": np.mean(r.rmse / table3().rmse_agsta),
        }
        outside = (np.abs(e[:, :3]).max(axis=1) > BAND[0]) | (np.abs(e[:, 3:]).max(axis=1) > BAND[1])
        settle = []
        for j in range(len(ev) - 1):
            inwin = (t >= ev[j] - 1e-9) & (t < ev[j + 1] - 1e-9)
            last = np.where(inwin & outside)[0]
            settle.append(t[last[-1]] + h - ev[j] if last.size else 0.0)
        want["settling_time"] = max(settle)
        for name, o in objs.items():
            got = o.values({k: v[i:i + 1] for k, v in out.items()}, ctx)[0]
            assert got == pytest.approx(want[name], rel=1e-12, abs=1e-12), name
        got_el = objs["settling_time"].elements({k: v[i:i + 1] for k, v in out.items()}, ctx)[0]
        assert got_el == pytest.approx(settle, abs=1e-12)
        assert min(settle) > 0  # the band is left after both events: the check is not of zeros
    # the second gain set saturates (so time in saturation is checked on a non-zero value)
    assert objs["saturation_time"].values({k: v[1:2] for k, v in out.items()}, ctx)[0] > 0


def test_peak_thrust_limit_and_constraint(runs):
    cfg, objs, _, out, ctx = runs
    o = objs["peak_thrust"]
    P = load()
    n = P.structure.n_thrusters
    lim = o.limit(ctx)
    assert lim.shape == (2 * n,) and np.all(lim[:n] == P["thrusters.u_max"]) and np.all(lim[n:] == -P["thrusters.u_min"])
    c = O.parse_constraint("peak_thrust <= 0.8 * limit")
    el = o.elements(out, ctx)
    want = ((el - 0.8 * lim) / (0.8 * lim)).max(axis=1)
    assert np.array_equal(c.violation(o, out, ctx), want)
    c2 = O.parse_constraint("energy >= 10")
    assert np.array_equal(c2.violation(objs["energy"], out, ctx), (10 - objs["energy"].values(out, ctx)) / 10)


@pytest.mark.parametrize("text, msg", [
    ("peak_thrust < 1", "is not a constraint (allowed forms"),
    ("nope <= 1", "unknown objective 'nope' (allowed: chat, rmse"),
    ("rmse <= 0.5 * limit", "objective rmse has no limit"),
    ("peak_thrust <= 0.8 * limit * 2", "one factor of limit"),
    ("__import__('os') <= 1", "is not a constraint"),
])
def test_constraint_errors(text, msg):
    with pytest.raises(O.ObjectiveError) as e:
        O.parse_constraint(text, "objectives.constraints[1]")
    assert str(e.value).startswith("objectives.constraints[1]: ") and msg in str(e.value)
    assert "\n" not in str(e.value)


def test_user_objective_registered(tmp_path):
    from arvcas.util import plugins

    f = tmp_path / "my_objective.py"
    f.write_text(
        "import casadi as ca\n"
        "from arvcas.metrics.objectives import Objective\n"
        "from arvcas.sim.accumulate import Accumulator\n"
        "class Yaw(Objective):\n"
        "    name, unit, description = 'yaw_iae', 'rad s', 'integrated absolute yaw error'\n"
        "    accumulators = (Accumulator('yaw_iae', 'sum', 1, lambda v: v.h * ca.fabs(v.e[5])),)\n"
        "    def values(self, out, ctx):\n"
        "        return ctx.acc(out, 'yaw_iae')[:, 0]\n")
    plugins.load(str(f))
    o = O.get("yaw_iae")
    assert o.unit == "rad s" and O.origin("yaw_iae")["kind"] == "file"
    assert O.accumulators_of([o, O.get("iae")])[0].name == "yaw_iae"
