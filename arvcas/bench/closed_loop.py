"""Section 2: the closed loop (the compiled 100 s run, the VM, batches with 1 and 2 threads).

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from arvcas.build import calls
from arvcas.sim import closedloop, profiles, scenario, schedule, simulation
from arvcas.controllers import gains as gains_mod
from arvcas.bench.common import BenchError, CONTROLLER, Settings, _stat, _time

def _run_args(fn: ca.Function, g, noise, cfg, p, layout=None) -> list:
    """Arguments of a run function by input name (robust to the order of the inputs)."""
    vals = {"gains": g, "noise": noise, "unc": cfg.uncertainty, "phase": np.array(cfg.disturbance_phase),
            "ekf": getattr(cfg, "ekf_vector", None), "water": getattr(cfg, "water_vector", None), "p": p}
    args = []
    for name in fn.name_in():
        if name in ("sched_time", "sched_arm"):
            args.append(getattr(schedule.table(cfg, p, layout=layout), name.split("_")[1]))
            continue
        if vals.get(name) is None:
            raise BenchError(f"run function {fn.name()}: do not know what to pass as input {name!r}")
        args.append(np.asarray(vals[name], dtype=float))
    return args


def _table_cold(cfg, p) -> float:
    """Seconds to build the run's time table from scratch (compiled functions loaded, table not kept)."""
    schedule.clear_cache()
    t0 = time.perf_counter()
    schedule.table(cfg, p)
    return time.perf_counter() - t0


def _step_instructions(spec: closedloop.RunSpec, trace: bool) -> dict:
    """Instructions per controller sample: the sum over the sub-functions one step calls."""
    step, _, _ = closedloop.build_step(spec, trace=trace)
    calls: dict[str, dict] = {}
    for i in range(step.n_instructions()):
        if step.instruction_id(i) == ca.OP_CALL:
            f = step.instruction_MX(i).which_function()
            if f.class_name() == "Switch":  # finalize's branch: count the one a running run takes
                f = next(g for g in f.find_functions() if g.name() == "cl_keep")
            c = calls.setdefault(f.name(), {"n_instructions": int(f.n_instructions()), "calls": 0})
            c["calls"] += 1
    total = sum(c["n_instructions"] * c["calls"] for c in calls.values())
    return {"total": total, "calls": calls}


def _bench_closed_loop(s: Settings, cfg, P, log) -> dict:
    spec = closedloop.RunSpec(CONTROLLER, cfg)
    g = gains_mod.default_gains(CONTROLLER)
    noise = profiles.noise_sequence(cfg, 0)
    p = P.vector()
    duration = cfg.time_duration
    n_samples = scenario.n_samples(cfg)

    log("closed loop: compiled run (metrics only, trace, simulate) ...")
    f_m = simulation.run_function(CONTROLLER, cfg, trace=False)
    f_t = simulation.run_function(CONTROLLER, cfg, trace=True)
    a_m, a_t = _run_args(f_m, g, noise, cfg, p), _run_args(f_t, g, noise, cfg, p)
    t_m = _time(lambda: calls.call(f_m, *a_m), s.reps)
    t_t = _time(lambda: calls.call(f_t, *a_t), s.reps)
    t_sim = _time(lambda: simulation.simulate(CONTROLLER, seed=0, cfg=cfg, system=P), s.reps)
    # a run that builds its time table first (the first run of a new scenario or parameter set)
    t_table = _stat([_table_cold(cfg, p) for _ in range(s.reps)])
    t_cold = _time(lambda: (schedule.clear_cache(), calls.call(f_m, *_run_args(f_m, g, noise, cfg, p))), s.reps)

    log("closed loop: the same run in CasADi's VM ...")
    f_vm = closedloop.build_run(spec, trace=False)
    a_vm = _run_args(f_vm, g, noise, cfg, p)
    t_vm = _time(lambda: calls.call(f_vm, *a_vm), s.reps_slow, warmup=0)
    vm_out = calls.call(f_vm, *a_vm)
    c_out = calls.call(f_m, *a_m)
    if not all(np.allclose(a, b, rtol=1e-8, atol=1e-12) for a, b in zip(vm_out, c_out)):
        raise BenchError("the compiled run and the VM run disagree")

    ins = _step_instructions(spec, trace=False)
    ins_t = _step_instructions(spec, trace=True)

    log(f"closed loop: simulate_batch of {s.batch_n} gain sets, 1 and 2 threads ...")
    rng = np.random.default_rng(2024)
    G = g[None, :] * rng.uniform(0.95, 1.05, (s.batch_n, g.size))
    G[0] = g
    batch = {}
    for nt in (1, 2):
        simulation.simulate_batch(CONTROLLER, G, seed=0, cfg=cfg, system=P, n_threads=nt, lockstep=False)  # warm-up (thread buffers allocated)
        st = _time(lambda: simulation.simulate_batch(CONTROLLER, G, seed=0, cfg=cfg, system=P, n_threads=nt,
                                                       lockstep=False),
                   s.reps_slow, warmup=0)
        batch[f"wall_s_{nt}"] = st
        batch[f"runs_per_s_{nt}"] = s.batch_n / st["median"]
    batch["n_runs"] = s.batch_n
    batch["ratio_2_over_1"] = batch["runs_per_s_2"] / batch["runs_per_s_1"]

    total = ins["total"]
    return {
        "controller": CONTROLLER,
        "duration_s": duration,
        "n_samples": n_samples,
        "substeps": cfg.substeps,
        "run_metrics_s": t_m,
        "run_cold_s": t_cold,
        "table_s": t_table,
        "run_trace_s": t_t,
        "simulate_s": t_sim,
        "vm_run_s": t_vm,
        "rtf_metrics": duration / t_m["median"],
        "rtf_cold": duration / t_cold["median"],
        "rtf_trace": duration / t_t["median"],
        "rtf_simulate": duration / t_sim["median"],
        "rtf_vm": duration / t_vm["median"],
        "ratio_vm_over_compiled": t_vm["median"] / t_m["median"],
        "instructions_per_sample": total,
        "instructions_per_sample_trace": ins_t["total"],
        "step_calls": ins["calls"],
        "instr_per_s": total * n_samples / t_m["median"],
        "instr_per_s_trace": ins_t["total"] * n_samples / t_t["median"],
        "vm_instr_per_s": total * n_samples / t_vm["median"],
        "batch": batch,
    }
