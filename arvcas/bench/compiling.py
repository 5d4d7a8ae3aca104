"""Section 3: compiling (cold and warm builds, the -O0..-O3 sweep, the recommended level).

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable

import casadi as ca

from arvcas.build import calls, codegen
from arvcas.sim import closedloop, profiles
from arvcas.controllers import gains as gains_mod
from arvcas.model import uvms
from arvcas.bench.closed_loop import _run_args, _step_instructions
from arvcas.bench.common import BenchError, CONTROLLER, N_INPUT_SETS, RUN_TIME_TOLERANCE, Settings, _default_opt_level, _fresh_copy, _scaled, _stat, _temp_cache, _time
from arvcas.bench.plant import _Driver, _c_time, _input_sets, _write_data

def _cold_builds(fn: ca.Function, level: str, reps: int, after: Callable[[ca.Function, int], None] | None = None):
    """``reps`` builds of ``fn`` each into a fresh empty cache: (build wall s, cc s) samples.

    ``after(f, rep)`` runs while the fresh cache still exists (to time the compiled function)."""
    build_s, cc_s = [], []
    for rep in range(reps):
        with _temp_cache():
            before = codegen.stats()["compile"]
            t0 = time.perf_counter()
            f = codegen.build(fn, opt_level=level)
            build_s.append(time.perf_counter() - t0)
            if codegen.stats()["compile"] != before + 1:
                raise BenchError(f"cold build of {fn.name()} did not compile")
            cc_s.append(float(codegen.artifact_of(f)["compile_time_s"]))
            if after is not None:
                after(f, rep)
    return build_s, cc_s


def _c_source_kib(fn: ca.Function) -> float:
    cg = ca.CodeGenerator(fn.name(), {"with_header": False})
    cg.add(fn)
    return len(cg.dump().encode()) / 1024


def _cold_warm(fn: ca.Function, graph: dict, level: str, s: Settings, n_instructions: int) -> dict:
    """Cold build (fresh cache), then warm builds of fresh copies of the same graph (disk hits), then
    a memo hit (the same Function object again)."""
    build_s, cc_s = _cold_builds(fn, level, max(1, s.reps_slow - 1))  # + the one below
    warm_s, memo_s = [], []
    with _temp_cache():
        t0 = time.perf_counter()
        f = codegen.build(fn, opt_level=level)
        build_s.append(time.perf_counter() - t0)
        cc_s.append(float(codegen.artifact_of(f)["compile_time_s"]))
        copies = [_fresh_copy(fn) for _ in range(s.reps_slow)]
        for c in copies:
            hits = codegen.stats()["disk_hit"]
            t0 = time.perf_counter()
            codegen.build(c, opt_level=level)
            warm_s.append(time.perf_counter() - t0)
            if codegen.stats()["disk_hit"] != hits + 1:
                raise BenchError(f"warm build of {fn.name()} was not a cache hit")
        for _ in range(s.reps):
            t0 = time.perf_counter()
            codegen.build(fn, opt_level=level)
            memo_s.append(time.perf_counter() - t0)
    cold, warm = _stat(build_s), _stat(warm_s)
    return {
        "opt_level": level,
        "n_instructions": n_instructions,
        "c_source_kib": _c_source_kib(fn),
        "graph_s": graph,
        "cold_build_s": cold,
        "cold_cc_s": _stat(cc_s),
        "warm_build_s": warm,
        "memo_build_us": _scaled(_stat(memo_s), 1e6),
        "ratio_cold_over_warm": cold["median"] / warm["median"],
    }


def _bench_compile(s: Settings, cfg, P, driver: _Driver, work: Path, log) -> dict:
    default = _default_opt_level()
    level = s.compile_level or default
    t0 = time.perf_counter()
    fns = uvms.plant_functions()
    g_plant = time.perf_counter() - t0
    uv = fns["uvms_rhs"]
    graph_plant = [g_plant] + [_timed_graph(uvms.plant_functions) for _ in range(s.reps - 1)]
    spec = closedloop.RunSpec(CONTROLLER, cfg)
    t0 = time.perf_counter()
    run_fn = closedloop.build_run(spec, trace=False)
    graph_run = [time.perf_counter() - t0] + [
        _timed_graph(lambda: closedloop.build_run(spec, trace=False)) for _ in range(s.reps_slow - 1)]

    log(f"compile: uvms_rhs cold/warm at {level} ...")
    res = {"default_opt_level": default, "measured_at": level}
    res["uvms_rhs"] = _cold_warm(uv, _stat(graph_plant), level, s, int(uv.n_instructions()))
    res["uvms_rhs"]["graph_note"] = "plant_functions(): all five SX Functions"
    log(f"compile: run function cold/warm at {level} ...")
    distinct = _step_instructions(spec, trace=False)["calls"]  # each sub-function is generated once
    res["run"] = _cold_warm(run_fn, _stat(graph_run), level, s, sum(c["n_instructions"] for c in distinct.values()))
    res["run"]["instructions_note"] = "sum over the distinct SX functions the step calls (each generated once)"

    # opt-level sweep: compile time against speed (run function and uvms_rhs)
    g = gains_mod.default_gains(CONTROLLER)
    args = _run_args(run_fn, g, profiles.noise_sequence(cfg, 0), cfg, P.vector())
    sets = _input_sets(uv, P.vector(), N_INPUT_SETS)
    data = work / "uvms_rhs_sweep.bin"
    _write_data(data, uv, sets)
    sweep_run, sweep_uv = [], []
    for lv in s.opt_levels:
        log(f"compile: sweep {lv}: run function ...")
        timings: list[dict] = []

        def time_run(f, rep):
            if rep == 0:
                timings.append(_time(lambda: calls.call(f, *args), s.reps))

        b, c = _cold_builds(run_fn, lv, s.reps_slow, time_run)
        sweep_run.append({"opt_level": lv, "build_s": _stat(b), "cc_s": _stat(c), "run_s": timings[0],
                          "rtf": cfg.time_duration / timings[0]["median"]})
        log(f"compile: sweep {lv}: uvms_rhs ...")
        ct: list[dict] = []

        def time_c(f, rep):
            if rep == 0:
                ct.append(_c_time(driver, codegen.artifact_of(f)["path"], uv, data, sets[0], s))

        b, c = _cold_builds(uv, lv, s.reps_slow, time_c)
        sweep_uv.append({"opt_level": lv, "build_s": _stat(b), "cc_s": _stat(c), "c_ns_per_eval": ct[0]})

    base = next((r for r in sweep_run if r["opt_level"] == default), sweep_run[0])
    base_uv = next((r for r in sweep_uv if r["opt_level"] == default), sweep_uv[0])
    for r in sweep_run:
        r["run_speedup_vs_base"] = base["run_s"]["median"] / r["run_s"]["median"]
        r["cc_ratio_vs_base"] = r["cc_s"]["median"] / base["cc_s"]["median"]
    for r in sweep_uv:
        r["speedup_vs_base"] = base_uv["c_ns_per_eval"]["median"] / r["c_ns_per_eval"]["median"]
        r["cc_ratio_vs_base"] = r["cc_s"]["median"] / base_uv["cc_s"]["median"]
    res["opt_sweep"] = {"baseline": base["opt_level"], "run": sweep_run, "uvms_rhs": sweep_uv}
    return res


def _timed_graph(make: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    make()
    return time.perf_counter() - t0


def _recommend(comp: dict) -> dict:
    """The opt level to default to: among levels whose run time (the least disturbed repetition) is
    within RUN_TIME_TOLERANCE of the fastest, the one that compiles fastest; with the break-even number
    of runs against the others (medians)."""
    sw = comp["opt_sweep"]["run"]
    default = comp["default_opt_level"]
    if len(sw) < 2:
        return {"opt_level": default, "rule": "no sweep (quick mode): keep the current default",
                "text": f"quick mode measures only {sw[0]['opt_level']}: no recommendation; the default stays {default}."}
    best_run = min(r["run_s"]["min"] for r in sw)
    ok = [r for r in sw if r["run_s"]["min"] <= (1 + RUN_TIME_TOLERANCE) * best_run]
    rec = min(ok, key=lambda r: r["cc_s"]["median"])
    lines = []
    for r in sw:
        if r is rec:
            continue
        d_run = r["run_s"]["median"] - rec["run_s"]["median"]  # > 0: rec runs faster
        d_cc = rec["cc_s"]["median"] - r["cc_s"]["median"]  # > 0: rec compiles slower
        if d_run > 0 and d_cc > 0:
            lines.append(f"{rec['opt_level']} vs {r['opt_level']}: {d_cc:.1f} s more compiling, paid back after "
                         f"{math.ceil(d_cc / d_run)} runs ({d_run * 1e3:.0f} ms saved per run)")
        elif d_run >= 0 and d_cc <= 0:
            lines.append(f"{rec['opt_level']} vs {r['opt_level']}: compiles {-d_cc:.1f} s faster and runs "
                         f"{r['run_s']['median'] / rec['run_s']['median']:.2f}x as fast")
        else:
            lines.append(f"{rec['opt_level']} vs {r['opt_level']}: runs {-d_run / r['run_s']['median']:.1%} "
                         f"slower (within {RUN_TIME_TOLERANCE:.0%}), compiles {-d_cc:.1f} s faster")
    text = (f"default opt level: {rec['opt_level']} (current: {default}). Rule: among the levels whose run "
            f"time (least disturbed repetition) is within {RUN_TIME_TOLERANCE:.0%} of the fastest, the one that "
            f"compiles fastest "
            f"(a build is cached, so run speed counts first; compile time is paid after every change of the "
            f"graph). " + "; ".join(lines) + ".")
    return {"opt_level": rec["opt_level"], "rule": f"fastest compile among run times within "
            f"{RUN_TIME_TOLERANCE:.0%} of the best", "text": text, "keep_default": rec["opt_level"] == default}
