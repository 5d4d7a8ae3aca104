"""Section 6: validation and identification from logs.

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).

* validation of one 20 s trial (a shipped Hinsdale trial, 50 Hz, the log read and the open-loop run), with the
  same simulation through CasADi's virtual machine as a yardstick measured in the same run;
* identification of 10 free parameters of the Hinsdale system (vehicle and arm) on 10 synthetic trials of
  20 s (known parameters, stated sensor noise), compiled code warm: wall time, IPOPT iterations, the time of
  one sensitivity evaluation (every trial, 2 threads) and of one plain simulation of every trial.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from arvcas.bench.common import _stat

# the Hinsdale 2023 trial traj014-2 (studies/validation/hinsdale2023, MIT licence: data/LICENSE-hinsdale2023);
# data/ links to the checkout's files, which the wheel ships as package data
TRIAL = Path(__file__).resolve().parent / "data" / "traj014-2.log.toml"
SYSTEM = "hinsdale_bluerov2_alpha5"
FREE = ("vehicle.xB", "vehicle.yB", "vehicle.zB", "vehicle.Ixx", "vehicle.Iyy", "vehicle.Izz", "hydro.K_p",
        "hydro.M_q", "hydro.N_r", "hydro.K_p_absp")
TRUTH = {"vehicle.zB": -0.011, "vehicle.Ixx": 0.50, "vehicle.Iyy": 0.55, "vehicle.Izz": 0.60, "hydro.K_p": -0.2,
         "hydro.M_q": -0.15, "hydro.N_r": -0.3, "hydro.K_p_absp": -2.0}
N_TRIALS, DURATION = 10, 20.0
QUICK = {"free": ("vehicle.zB", "hydro.K_p"), "trials": 2, "duration": 4.0}  # --quick: the vehicle without its arm


def _bench_identification(s, log) -> dict:
    import casadi as ca

    import arvcas
    from arvcas.ident import identify as ident
    from arvcas.ident import logs, plant, synthetic, validate
    from arvcas.system import System

    system = arvcas.load_system(SYSTEM)
    out: dict = {}
    # -- validation of one 20 s trial
    log("identification: validation of one trial ...")
    lg = logs.load_log(TRIAL, system.n_joints)
    validate.validate_log(system, lg)  # compile / load
    reps = max(3, s.reps)
    t_read, t_val = [], []
    for _ in range(reps):
        t0 = time.perf_counter()
        lg = logs.load_log(TRIAL, system.n_joints)
        t1 = time.perf_counter()
        validate.validate_log(system, lg)
        t_val.append(time.perf_counter() - t1)
        t_read.append(t1 - t0)
    pl = plant.LogPlant(system, m=1)
    d = plant.sample_inputs(lg, system, 1)
    x0 = validate.initial_state(lg)
    p = system.params.vector()
    vm = pl._accumulated("ident_block_vm", plant.DEFAULT_BLOCK, None)  # the same graph in CasADi's VM
    n = d["W"].shape[1]  # steps
    t_vm = []
    for _ in range(max(1, reps // 2)):
        t0 = time.perf_counter()
        x = ca.DM(x0)
        for b in range(0, n, plant.DEFAULT_BLOCK):
            c = plant._pad(d, b, min(b + plant.DEFAULT_BLOCK, n), plant.DEFAULT_BLOCK)
            X = vm(x, c["U"], c["W"], c["Q"], c["QD"], c["QDD"], c["payload"], d["h"], np.zeros((0, 1)), p)
            x = X[:, min(b + plant.DEFAULT_BLOCK, n) - b - 1]
        t_vm.append(time.perf_counter() - t0)
    t_sim = []
    for _ in range(reps):
        t0 = time.perf_counter()
        plant.simulate(pl, lg, x0, p, data=d)
        t_sim.append(time.perf_counter() - t0)
    out["validation"] = {"trial": lg.name, "duration_s": lg.duration, "samples": len(lg.t), "read_s": _stat(t_read),
                         "validate_s": _stat(t_val), "simulate_s": _stat(t_sim), "simulate_vm_s": _stat(t_vm),
                         "vm_over_compiled": float(np.median(t_vm) / np.median(t_sim)),
                         "total_s": float(np.median(t_read) + np.median(t_val))}
    # -- identification of 10 parameters on 10 trials of 20 s (--quick: 2 parameters of the vehicle alone)
    log("identification: synthetic trials ...")
    work = Path(tempfile.mkdtemp(prefix="arvcas-bench-ident-"))
    free, n_trials, duration = FREE, N_TRIALS, DURATION
    if s.mode == "quick":
        import tomlkit

        doc = tomlkit.parse(Path(system.path).read_text(encoding="utf-8"))
        for k in ("arm", "payload", "defaults"):
            doc.pop(k, None)
        doc["system"]["name"] = "hinsdale_vehicle_bench"
        (work / "vehicle.toml").write_text(tomlkit.dumps(doc), encoding="utf-8")
        system = arvcas.load_system(work / "vehicle.toml")
        free, n_trials, duration = QUICK["free"], QUICK["trials"], QUICK["duration"]
    truth = System(system.params.replace({k: v for k, v in TRUTH.items() if k in free}))
    try:
        paths = [synthetic.write_trial(work, f"b{k}", truth, duration=duration, seed=500 + k, p=truth.params.vector())
                 for k in range(n_trials)]
        lgs = logs.load_logs(paths, system.n_joints)
        log("identification: compiling (or loading from the cache) ...")
        from arvcas.build import codegen

        n_compiles = codegen.stats()["compile"]
        t0 = time.perf_counter()
        prob_plant = plant.LogPlant(system, m=1, free=free)
        prob_plant.sens_fn()
        prob_plant.block_fn()
        build_s = time.perf_counter() - t0
        cold = codegen.stats()["compile"] > n_compiles
        log(f"identification: {len(free)} parameters, {n_trials} trials ...")
        t0 = time.perf_counter()
        est = ident.identify(system, lgs, free, threads=2)
        wall = time.perf_counter() - t0
        prob = ident.Problem(system, lgs, free, est.signals, {}, 1, plant.DEFAULT_BLOCK, 2)
        z = np.concatenate([np.zeros(len(free))] + [validate.initial_state(x) for x in lgs])
        t_sens, t_plain = [], []
        for k in range(3):
            zz = z + 1e-9 * (k + 1)  # a new point each time: no memo
            t1 = time.perf_counter()
            prob.evaluate(zz, True)
            t_sens.append(time.perf_counter() - t1)
            t1 = time.perf_counter()
            prob.evaluate(zz + 1e-9, False)
            t_plain.append(time.perf_counter() - t1)
        prob.pool.shutdown()
        tv = np.array([truth.params[n] for n in free])
        out["identify"] = {
            "system": system.name, "free": list(free), "trials": n_trials, "duration_s": duration,
            "samples": int(sum(len(x.t) for x in lgs)), "wall_s": wall, "iterations": est.iterations,
            "status": est.status, "build_s": build_s, "build_cold": cold, "sens_eval_s": _stat(t_sens), "plain_eval_s": _stat(t_plain),
            "sens_per_sample_us": float(np.median(t_sens)) / sum(len(x.t) for x in lgs) * 1e6 * 2,
            "max_abs_z": float(np.max(np.abs((est.values - tv) / est.std))),
        }
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return out
