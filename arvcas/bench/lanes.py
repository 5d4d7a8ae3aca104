"""Section 8: lockstep lanes in the runs against one run at a time, in the same run.

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).

(a) Per system with a scenario of its own (its default gains, controller ``proposed``): a batch of
``study_pop`` gain sets (the defaults times U(0.95, 1.05): every run goes on to the end) on one thread,
one at a time (``lockstep=False``) and W at a time (``lockstep=True``) alternated round by round; the
time per run, the real-time factor per core, the ratio, and the outputs compared to the bit. The same
with a quarter of the runs diverging early (every W-th gain set 100x its defaults, below the gains'
limits: one in every lockstep group), and with every run diverging: what diverging runs cost each path.

(b) A 40,000-run study on 2 threads, Haidou-1's proposed law: its runs alone (500 batches of 80 gain sets,
every run to the end, as section 2b's projection), lockstep against one at a time interleaved; then the
study itself: NSGA-II (population 80, 500 generations, one draw, the paper study's variables) by
``arvcas.tuning.run_study`` with its checkpoint every generation, lockstep on, with the share of its
time spent in the batches; one at a time for its first tenth of generations (the same generations: every
run equals the lockstep one to the bit, so NSGA-II takes the same path), timed per generation.
"""

from __future__ import annotations

import dataclasses
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from arvcas.controllers import gains as gains_mod
from arvcas.sim.run import Run
from arvcas.bench.common import CONTROLLER, PLAIN_RK4, PLAIN_RK4_KEY, Settings, _stat
from arvcas.bench.targets import _env

PAPER_STUDY = Path(__file__).resolve().parent / "data" / "paper.toml"  # studies/paper.toml (linked, shipped)


def _study_text(controller: str, population: int, generations: int) -> str:
    """studies/paper.toml for one controller, ``population`` and exactly ``generations`` generations (no
    stall stop), 2 threads."""
    import re

    t = PAPER_STUDY.read_text(encoding="utf-8")
    for pat, rep in ((r"(?m)^controllers = .*$", f'controllers = "{controller}"'),
                     (r"(?m)^population = \d+", f"population = {population}"),
                     (r"(?m)^max_generations = \d+", f"max_generations = {generations}"),
                     (r"(?m)^stall_generations = .*$", ""), (r"(?m)^ftol = .*$", ""),
                     (r'(?m)^name = "local"$', 'name = "local"\nthreads = 2')):
        t, n = re.subn(pat, rep, t)
        if n != 1:
            raise RuntimeError(f"lanes: {PAPER_STUDY}: expected one match of {pat!r}, found {n}")
    return t


STUDY_POP, STUDY_GENERATIONS = 80, 500
TARGETS = {"rtf_per_core_haidou1": 50_000.0, "study_s": 45.0}


def _batches(run, pop: int, W: int) -> dict[str, np.ndarray]:
    g = run.default_gains()
    up = gains_mod.upper_limits(run.controller, run.cfg.time_h) * 0.95
    G = g[None, :] * np.random.default_rng(2024).uniform(0.95, 1.05, (pop, g.size))
    mixed = G.copy()
    mixed[1::W] = np.minimum(G[1::W] * 100, up)
    return {"running": G, "mixed": mixed, "diverging": np.minimum(G * 100, up)}


def _bench_batches(s: Settings, log) -> dict:
    from arvcas.system import load_system, shipped

    out = {}
    for name in shipped():
        sysm = load_system(name)
        if sysm.params.default("scenario") is None or (s.mode == "quick" and name != "haidou1"):
            continue  # --quick: Haidou-1 only (one lockstep library to build)
        for key, run in _lane_runs(s, name, sysm):
            out[key] = _bench_lane_run(s, key, run, log)
    return out


def _lane_runs(s: Settings, name: str, sysm):
    """The system's run at its default scenario and, with thruster dynamics (not --quick), by plain RK4 at the
    step shipped before the quadrature (:data:`arvcas.bench.common.PLAIN_RK4`)."""
    run = Run(CONTROLLER, system=sysm).compile()
    yield name, run
    if sysm.structure.has_thruster_dynamics and s.mode != "quick":
        yield f"{name}{PLAIN_RK4_KEY}", Run(CONTROLLER, system=sysm, scenario=dataclasses.replace(run.cfg, **PLAIN_RK4)).compile()


def _bench_lane_run(s: Settings, name: str, run, log) -> dict:
    log(f"lanes: {name}: the lockstep library (W = {run.lockstep().W}) ...")
    W = run.lockstep().W
    r = {"W": W, "n_runs": s.study_pop, "duration_s": run.cfg.time_duration}
    for kind, G in _batches(run, s.study_pop, W).items():
        ref = run.batch(G, n_threads=1, return_status=True, lockstep=False)  # warm-up and the reference
        got = run.batch(G, n_threads=1, return_status=True, lockstep=True)
        equal = all(a.tobytes() == b.tobytes() for a, b in zip(ref, got))
        if not equal:
            raise RuntimeError(f"lanes: {name} {kind}: the lockstep batch differs from the scalar one")
        t = {False: [], True: []}
        for _ in range(2 * s.reps_slow if kind == "running" else s.reps_slow):
            for lock in (False, True):
                t0 = time.perf_counter()
                run.batch(G, n_threads=1, lockstep=lock)
                t[lock].append((time.perf_counter() - t0) / len(G))
        sc, ln = _stat(t[False]), _stat(t[True])
        r[kind] = {"ok_share": float(np.mean(ref[2])), "scalar_s_per_run": sc, "lanes_s_per_run": ln,
                   "rtf_scalar": run.cfg.time_duration / sc["median"], "rtf_lanes": run.cfg.time_duration / ln["median"],
                   "rtf_lanes_best": run.cfg.time_duration / ln["min"],
                   "speedup": sc["median"] / ln["median"], "speedup_best": sc["min"] / ln["min"],
                   "speedup_paired": statistics.median(a / b for a, b in zip(t[False], t[True])),
                   "bitwise_equal": equal}
        log(f"lanes: {name} {kind}: {sc['median'] * 1e3:.2f} ms scalar, {ln['median'] * 1e3:.2f} ms lanes per run")
    return r


def _study(pop: int, generations: int, lockstep: bool, stop_after: int | None) -> dict:
    """One study run: its wall time, the time at the end of each generation (its progress line) and the
    time spent evaluating (the batches: :meth:`arvcas.sim.run.CompiledRun._evaluate`)."""
    import re

    from arvcas.sim.run import CompiledRun
    from arvcas.tuning.run import run_study
    from arvcas.tuning.study import load_study

    evaluate, spent = CompiledRun._evaluate, [0.0]

    def timed(self, *a, **k):
        t = time.perf_counter()
        try:
            return evaluate(self, *a, **k)
        finally:
            spent[0] += time.perf_counter() - t

    with tempfile.TemporaryDirectory(prefix="arvcas-bench-study-") as td:
        p = Path(td) / "study.toml"
        p.write_text(_study_text(CONTROLLER, pop, generations))
        gen_s: dict[int, float] = {}

        def say(msg: str) -> None:
            m = re.match(rf"{CONTROLLER} gen (\d+)", msg)
            if m:
                gen_s[int(m.group(1))] = time.perf_counter() - t0

        with _env("ARVCAS_LOCKSTEP", "1" if lockstep else "0"):
            study = load_study(p)
            CompiledRun._evaluate = timed
            try:
                t0 = time.perf_counter()
                out = run_study(study, Path(td) / "out", say=say, stop_after=stop_after)
                wall = time.perf_counter() - t0
            finally:
                CompiledRun._evaluate = evaluate
    o = out[0]
    return {"wall_s": wall, "evaluate_s": spent[0], "generations": int(o.n_gen), "n_eval": int(o.n_eval),
            "status": o.status, "generation_end_s": [gen_s[k] for k in sorted(gen_s)]}


def _runs_only(s: Settings, pop: int, n_batches: int, log) -> dict:
    """The study's runs alone: ``n_batches`` batches of ``pop`` gain sets (the defaults times U(0.95, 1.05):
    every run to the end, no early stop) on 2 threads, lockstep, against one at a time on a quarter of
    them, interleaved in rounds (each round: 4 lockstep batches, then 1 one at a time)."""
    run = Run(CONTROLLER).compile()
    G = _batches(run, pop, run.lockstep().W)["running"]
    for lock in (False, True):
        run.batch(G, n_threads=2, lockstep=lock)  # warm-up
    t = {True: [], False: []}
    for _ in range(max(1, n_batches // 4)):
        for lock in (True, True, True, True, False):
            t0 = time.perf_counter()
            run.batch(G, n_threads=2, lockstep=lock)
            t[lock].append(time.perf_counter() - t0)
    rate = {k: len(v) * pop / sum(v) for k, v in t.items()}
    return {"batches_lanes": len(t[True]), "batches_scalar": len(t[False]), "runs_lanes": len(t[True]) * pop,
            "lanes_s": sum(t[True]), "scalar_s": sum(t[False]), "rate_lanes": rate[True], "rate_scalar": rate[False],
            "speedup": rate[True] / rate[False], "batch_s_lanes": _stat(t[True]), "batch_s_scalar": _stat(t[False]),
            "study_runs_s_lanes": STUDY_POP * STUDY_GENERATIONS / rate[True],
            "study_runs_s_scalar": STUDY_POP * STUDY_GENERATIONS / rate[False]}


def _bench_study(s: Settings, log) -> dict:
    """(b) of the module docstring. The lockstep study's library and the run's are built first (not timed)."""
    pop, gens = (STUDY_POP, STUDY_GENERATIONS) if s.mode == "full" else (8, 4)
    part = max(1, gens // 10)
    log(f"lanes: the study's runs alone, {gens} batches of {pop} on 2 threads, lockstep and (a quarter) one at a time ...")
    ro = _runs_only(s, pop, gens, log)
    log(f"lanes: the study, population {pop}, {gens} generations ({pop * gens:,} runs), lockstep, 2 threads ...")
    ln = _study(pop, gens, True, None)
    log(f"lanes: the same study's first {part} generations one run at a time ...")
    sc = _study(pop, gens, False, part)
    ln_part = ln["generation_end_s"][sc["generations"] - 1]
    sc_part = sc["generation_end_s"][-1]
    return {"population": pop, "generations": gens, "runs_only": ro, "lanes": ln, "scalar": sc, "runs": ln["n_eval"],
            "lanes_s": ln["wall_s"], "lanes_evaluate_s": ln["evaluate_s"], "part_generations": sc["generations"],
            "part_runs": sc["n_eval"], "lanes_part_s": ln_part, "scalar_part_s": sc_part,
            "speedup_part": sc_part / ln_part, "scalar_projected_s": ln["wall_s"] * sc_part / ln_part}


def _bench_lanes(s: Settings, log) -> dict:
    from arvcas.bench.common import _CpuMeter, _machine

    m, la0 = _CpuMeter(), [round(x, 2) for x in os.getloadavg()]
    res = {"batches": _bench_batches(s, log), "study": _bench_study(s, log), "targets": TARGETS,
           "cpu": os.cpu_count()}
    mach = _machine()
    res["measured"] = {"date": mach["date"], "git_commit": mach["git_commit"], "load_avg_start": la0,
                       "load_avg_end": [round(x, 2) for x in os.getloadavg()], "other_cpu_share": m.share()}
    return res


def _lanes_markdown(r: dict | None) -> list[str]:
    """Section 8 of bench.md."""
    if not r:
        return []
    from arvcas.bench.common import _g, _spread, _verdict

    T = r["targets"]
    ms = r.get("measured")
    L = ["", "## 8. Lockstep lanes in the runs", ""]
    if ms:
        L += [f"Measured on {ms['date']} (commit {ms['git_commit']}; `arvcas bench --only lanes` puts this section "
              f"into the file); load average (1, 5, 15 min) {' '.join(f'{x:.2f}' for x in ms['load_avg_start'])} "
              f"before, {' '.join(f'{x:.2f}' for x in ms['load_avg_end'])} after; CPU time of other processes while "
              f"measuring: {ms['other_cpu_share']:.1%} of the machine"
              + (" (the figures are of a loaded machine; the ratios come from alternated rounds in the same run)."
                 if ms["other_cpu_share"] > 0.1 else " (a quiet machine; ratios from alternated rounds in the same run)."),
              ""]
    L += [
         "One thread. Each batch run one at a time (`lockstep=False`, the runs of sections 2-5) and W at a time "
         "(`lockstep=True`: the controller part, the plant steps and the divergence branch on W lanes, "
         "arvcas/sim/lockstep.py), alternated round by round; every output of both compared to the bit (equal). "
         "running: the default gains times U(0.95, 1.05), every run to the end; mixed: every W-th of them 100x "
         "(one diverging run in every lockstep group); diverging: all 100x. With thruster dynamics (the BlueROV2's "
         "T200s) the thrusters' part of a sample (table lookups, MX) runs lane by lane in scalar code between the "
         "lane controller part and the lane plant steps.", "",
         "| system | W | batch | runs | running share | one at a time, ms per run (spread) | lockstep, ms per run (spread) | "
         "real-time factor per core, one / lockstep (fastest round) | lockstep speed-up (median; fastest rounds) |",
         "|---|--:|---|--:|--:|--:|--:|--:|--:|"]
    for name, b in r["batches"].items():
        for kind in ("running", "mixed", "diverging"):
            k = b[kind]
            sc, ln = k["scalar_s_per_run"], k["lanes_s_per_run"]
            L.append(f"| {name} | {b['W']} | {kind} | {b['n_runs']} | {k['ok_share']:.0%} | {_g(sc['median'] * 1e3)} "
                     f"({_spread(sc)}) | {_g(ln['median'] * 1e3)} ({_spread(ln)}) | {k['rtf_scalar']:,.0f} / "
                     f"**{k['rtf_lanes']:,.0f}** ({k['rtf_lanes_best']:,.0f}) | **{k['speedup']:.2f}x**; "
                     f"{k['speedup_best']:.2f}x |")
    h = r["batches"].get("haidou1")
    st = r["study"]
    if h:
        v = h["running"]["rtf_lanes"]
        L += ["", f"Haidou-1's 100 s run in lockstep: **{v:,.0f}x real time per core** (median; target "
                  f">= {T['rtf_per_core_haidou1']:,.0f}x: {_verdict(v, T['rtf_per_core_haidou1'], True)})."]
    ro = st["runs_only"]
    L += ["", f"A {STUDY_POP * STUDY_GENERATIONS:,}-run study on 2 threads, Haidou-1's `{CONTROLLER}` law. Its runs "
              f"alone: {ro['batches_lanes']} batches of {st['population']} running gain sets in lockstep against "
              f"{ro['batches_scalar']} one run at a time, interleaved (4 to 1 per round): {ro['rate_lanes']:,.0f} "
              f"against {ro['rate_scalar']:,.0f} runs/s (**{ro['speedup']:.2f}x**), so "
              f"{STUDY_POP * STUDY_GENERATIONS:,} runs take **{ro['study_runs_s_lanes']:.1f} s** in lockstep "
              f"(target <= {T['study_s']:g} s: {_verdict(ro['study_runs_s_lanes'], T['study_s'], False)}) and "
              f"{ro['study_runs_s_scalar']:.1f} s one at a time.",
          "", f"The study itself (NSGA-II, population {st['population']}, {st['generations']} generations, "
              f"{st['runs']:,} runs, the paper study's variables, one draw; `arvcas.tuning.run_study`, its "
              f"checkpoint written every generation), lockstep: **{st['lanes_s']:.1f} s**, of which "
              f"{st['lanes_evaluate_s']:.1f} s in the batches (the rest: NSGA-II, the checkpoints, the progress "
              f"lines). One run at a time, its first {st['part_generations']} generations ({st['part_runs']:,} "
              f"runs, the same generations to the bit): {st['scalar_part_s']:.1f} s against {st['lanes_part_s']:.1f} s "
              f"({st['speedup_part']:.2f}x); the whole study at that ratio: {st['scalar_projected_s']:.0f} s."]
    return L
