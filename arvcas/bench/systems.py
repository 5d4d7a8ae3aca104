"""Section 5: every shipped system's run at its own default scenario and gains.

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).
"""

from __future__ import annotations

import dataclasses
import time

from arvcas.build import calls
from arvcas.sim import closedloop, profiles, scenario
from arvcas.sim.run import Run
from arvcas.bench.closed_loop import _run_args, _step_instructions
from arvcas.bench.common import CONTROLLER, PLAIN_RK4, PLAIN_RK4_KEY, Settings, _stat

def _bench_systems(s: Settings, log) -> dict:
    """Each shipped system with a default scenario: its run at that scenario and gains, side by side in one
    measurement: metrics-only run time (the systems interleaved round by round, median over the rounds),
    real-time factor, instructions per controller sample and per second."""
    from arvcas.system import System, load_system, shipped

    prepared = {}
    for name in shipped():
        sysm = load_system(name)
        if sysm.params.default("scenario") is None:  # a system for validation only (hinsdale_bluerov2_alpha5)
            log(f"systems: {name}: no default scenario, not timed")
            continue
        cfg0 = scenario.load_scenario(sysm.params.default("scenario"))
        variants = [(name, sysm, cfg0)]
        if sysm.structure.has_thruster_dynamics and s.mode != "quick":  # also without them, by plain RK4
            plain = dataclasses.replace(cfg0, time_thrust_quadrature=None)  # instantaneous thrusters have no quadrature
            variants += [(f"{name}+instantaneous", System(sysm.params.instantaneous()), plain),
                         (f"{name}{PLAIN_RK4_KEY}", sysm, dataclasses.replace(cfg0, **PLAIN_RK4))]
        for key, sv, cfg_v in variants:
            log(f"systems: {key} ...")
            run = Run(CONTROLLER, scenario=cfg_v, system=sv).compile()
            cfg = run.cfg
            f = run.function(trace=False)
            args = _run_args(f, run.default_gains(), profiles.noise_sequence(cfg, 0), cfg, sv.params.vector(),
                             layout=sv.layout)
            calls.call(f, *args)  # warm-up
            spec = closedloop.RunSpec(CONTROLLER, cfg.graph_key(), run.opts, sv.layout)
            prepared[key] = (sv, cfg, f, args, _step_instructions(spec, trace=False))
    samples = {name: [] for name in prepared}
    for _ in range(max(s.reps, 7)):  # interleaved: the machine's drift hits every system alike
        for name, (_, _, f, args, _) in prepared.items():
            t0 = time.perf_counter()
            calls.call(f, *args)
            samples[name].append(time.perf_counter() - t0)
    out = {}
    for name, (sysm, cfg, _, _, ins) in prepared.items():
        t = _stat(samples[name])
        n = scenario.n_samples(cfg)
        out[name] = {
            "controller": CONTROLLER, "duration_s": cfg.time_duration, "n_samples": n, "substeps": cfg.substeps,
            "n_thrusters": sysm.n_thrusters, "n_joints": sysm.n_joints, "run_metrics_s": t,
            "thruster_dynamics": sysm.structure.has_thruster_dynamics, "h_plant": cfg.time_h_plant,
            "rtf_metrics": cfg.time_duration / t["median"], "instructions_per_sample": ins["total"],
            "step_calls": ins["calls"], "instr_per_s": ins["total"] * n / t["median"],
        }
    return out
