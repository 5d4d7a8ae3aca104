"""Section 9: cost against work: how a run's cost grows with its length, the batch's
size and the arm's joints, and where it stops being linear.

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).

(a) **Run length.** Haidou-1's shipped scenario and the ``proposed`` law at its default gains, with
``time.duration`` 10, 30, 100, 300 and 1000 s (``--quick``: 10 and 30 s); each length is its own
compiled run (the loop's length shapes the graph), compiled before timing (from the cache when it is
there). Timed per length, in alternated rounds on one thread: the compiled run function called alone
(``calls.call``, the time table built beforehand); one run through :meth:`CompiledRun.batch` (a gain
set of one row, one at a time: the Python around the call, the noise drawn, the inputs checked); and the
time per run within a batch of :data:`LENGTH_BATCH` gain sets (the defaults times U(0.95, 1.05), every run
to the end) one at a time and in lockstep (:mod:`arvcas.sim.lockstep`). After them, the run's time table
built from scratch (the first run of a new scenario pays it; the functions that build it loaded).

(b) **Batch size.** The 10 s run of (a), batches of 1, 10, 100, 1,000, 10,000 and 100,000 gain sets
(``--quick``: 1, 10, 100) on one thread, one at a time and in lockstep, alternated round by round; the
rounds per size are as many as fit :data:`BATCH_BUDGET_S` (at least :data:`MIN_ROUNDS`, at most the
settings' ``reps``). Every batch's outputs are compared between the two paths to the bit.

(c) **Arm joints.** Haidou-1's vehicle with a generated arm of 0..7 revolute joints (``--quick``: 0 and
1), written as system files in the DH form of docs/system-file.md: joint and link i are Haidou-1's joint
and link i (i <= 6), joint and link 7 copies of its joint and link 6; the stow pose Haidou-1's, joint 7
at joint 6's; mount, tool and payload Haidou-1's. The scenario is Haidou-1's with the paper's arm motion
written as waypoints (stow until 5 s, the paper's qg at 20-25 s, joint 7 to :data:`QG7_DEG`, stow at
40 s, the payload grasped at 22 s; no arm: the stow pose held), 100 s. For each: the run's library and
the lockstep library compiled cold into a fresh empty cache :data:`COMPILE_REPS` times (wall time of the
build: graph, C, compiler, load; and the compiler's share; the fastest is fitted), the time table's two
functions compiled with the first table, the
CasADi instructions of one controller sample, and the time per controller sample of the compiled run
called alone and of a run in a lockstep batch of :data:`LENGTH_BATCH`.

**Fits.** Each series is fitted with a line ``y = a + b x`` (intercept a: the fixed cost, slope b: the
cost per unit of work) by least squares on relative residuals (every point weighs alike across the
decades). :func:`linear_fit` reports the line through the longest run of consecutive sweep points that
lie within :data:`LINEAR_TOL` of their own line (linear there), each point's residual against that
line, and the work above which the fixed cost is below :data:`LINEAR_TOL` of the total (proportional).

The figures (``cost_length.png``, ``cost_batch.png``, ``cost_joints.png``) and a README are written by
:func:`write_files` from bench.json's ``cost`` key (no number typed by hand).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from arvcas.build import calls, codegen
from arvcas.sim import closedloop, lockstep, profiles, scenario, schedule
from arvcas.sim.run import Run
from arvcas.bench.closed_loop import _run_args, _step_instructions
from arvcas.bench.common import BenchError, CONTROLLER, Settings, _stat, _temp_cache
from arvcas.bench.lanes import _batches

SYSTEM = "haidou1"
LENGTHS = {"full": (10.0, 30.0, 100.0, 300.0, 1000.0), "quick": (10.0, 30.0)}
BATCH_SIZES = {"full": (1, 10, 100, 1_000, 10_000, 100_000), "quick": (1, 10, 100)}
BATCH_LENGTH = 10.0  # s: the run of the batch sweep
JOINTS = {"full": tuple(range(8)), "quick": (0, 1)}
LENGTH_BATCH = {"full": 64, "quick": 8}  # gain sets of the per-run batches of (a) and (c)
BATCH_BUDGET_S = {"full": 10.0, "quick": 0.2}  # wall time per batch size and path the rounds may take
MIN_ROUNDS = {"full": 2, "quick": 1}
COMPILE_REPS = {"full": 3, "quick": 1}  # cold builds of each arm's two libraries (the fastest is fitted)
LINEAR_TOL = 0.10  # a point is on the line within this relative residual
# the fits take each point's fastest round, as timeit does (on this shared machine the least disturbed round
# measures the code, the spread above it the neighbours); the medians stand beside them in the tables
FIT_ON = "min"
QG7_DEG = 60.0  # the 7th joint's grasp angle (the generated arm's only number not Haidou-1's): within its limits
FIGURES = ("cost_length.png", "cost_batch.png", "cost_joints.png")


# ---------------------------------------------------------------------------------------------
# the line and where it holds


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(a, b) of y = a + b x minimising the relative residuals (y - a - b x) / y."""
    A = np.stack([1.0 / y, x / y], axis=1)
    (a, b), *_ = np.linalg.lstsq(A, np.ones_like(y), rcond=None)
    return float(a), float(b)


def linear_fit(x, y, tol: float = LINEAR_TOL) -> dict:
    """The line ``y = a + b x`` of a sweep and where it holds.

    ``window``: the longest run of at least three consecutive points (two in a sweep of two; x in sweep
    order) whose own line has every relative residual within ``tol`` (of equal length: the smallest
    largest residual, then the higher x); when no three consecutive points lie on a line, the line
    through every point, with ``n_points`` 0;
    ``slope``, ``intercept``: that line; ``residual``: every point's relative residual against it (the
    points outside the window show how far the sweep leaves it); ``linear_everywhere``: the window is the
    whole sweep; ``proportional_from``: the x above which the fixed part |a| is at most ``tol`` of the line
    (None when the slope is not positive); ``all_points``: the line through every point, for comparison.
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if x.size < 2 or x.shape != y.shape or not (np.isfinite(x).all() and np.isfinite(y).all() and (y > 0).all()):
        raise BenchError(f"cost: a line needs >= 2 finite points with y > 0, got x={x.tolist()} y={y.tolist()}")
    n = x.size
    best = None  # (first index, length, a, b, largest residual)
    for length in range(n, min(3, n) - 1, -1):
        for i in range(n - length + 1):
            sl = slice(i, i + length)
            a, b = _line(x[sl], y[sl])
            worst = float(np.max(np.abs((y[sl] - a - b * x[sl]) / y[sl])))
            if worst <= tol and (best is None or (worst, -i) < (best[4], -best[0])):
                best = (i, length, a, b, worst)
        if best is not None:
            break
    a_all, b_all = _line(x, y)
    res_all = (y - a_all - b_all * x) / y
    if best is None:
        best = (0, 0, a_all, b_all, float(np.max(np.abs(res_all))))
    i0, length, a, b, worst = best
    return {
        "slope": b, "intercept": a, "from": float(x[i0]), "to": float(x[max(i0, i0 + length - 1)]), "n_points": length,
        "max_residual": worst, "residual": [float(r) for r in (y - a - b * x) / y],
        "linear_everywhere": length == n,
        "proportional_from": (abs(a) / tol - a) / b if b > 0 else None,
        "all_points": {"slope": b_all, "intercept": a_all, "max_residual": float(np.max(np.abs(res_all)))},
    }


# ---------------------------------------------------------------------------------------------
# compiling a run at a given level


def _prepare(run, level: str):
    """The run's library and its lockstep library at ``level`` (the run's own build, as
    :meth:`CompiledRun.function` makes it, at that level; from the cache when there); the run's batches
    then call these (as tests/test_lockstep.py sets them). Returns (run function, lockstep run, wall s of
    the first build, wall s of the second)."""
    spec = closedloop.RunSpec(run.controller, run.cfg.graph_key(), run.opts, run.params.layout, run.accumulators)
    t0 = time.perf_counter()
    fn = codegen.build_described(f"run_{run.controller.name}", run.description(False),
                                 lambda: closedloop.build_run(spec, False), batch_loop=True, opt_level=level,
                                 label=f"the run for {run.params.structure.name} / {run.controller.name}")
    t1 = time.perf_counter()
    ls = lockstep.build(run, opt_level=level)
    t2 = time.perf_counter()
    run._fns[False], run._lockstep = fn, ls
    return fn, ls, t1 - t0, t2 - t1


def _level(s: Settings) -> str:
    return s.compile_level or codegen.DEFAULT_OPT_LEVEL


def _rounds(series: dict, reps: int) -> dict:
    """``reps`` rounds, each calling every series once in turn: {name: [wall s per round]}."""
    out = {k: [] for k in series}
    for _ in range(reps):
        for k, fn in series.items():
            t0 = time.perf_counter()
            fn()
            out[k].append(time.perf_counter() - t0)
    return out


# ---------------------------------------------------------------------------------------------
# (a) run length


def _bench_length(s: Settings, log) -> dict:
    from arvcas.system import load_system

    sysm = load_system(SYSTEM)
    cfg0 = Run(CONTROLLER, system=sysm).compile().cfg
    nb, level = LENGTH_BATCH[s.mode], _level(s)
    rows = []
    for L in LENGTHS[s.mode]:
        run = Run(CONTROLLER, scenario=dataclasses.replace(cfg0, time_duration=L), system=sysm).compile()
        log(f"cost: run length {L:g} s: compiling (or loading) its libraries ...")
        fn, ls, _, _ = _prepare(run, level)
        g = run.default_gains()
        G = _batches(run, nb, ls.W)["running"]
        args = _run_args(fn, g, profiles.noise_sequence(run.cfg, 0), run.cfg, sysm.params.vector(), layout=sysm.layout)
        series = {"call": lambda: calls.call(fn, *args),
                  "one_run": lambda: run.batch(g[None, :], n_threads=1, lockstep=False),
                  "batch_scalar": lambda: run.batch(G, n_threads=1, lockstep=False),
                  "batch_lanes": lambda: run.batch(G, n_threads=1, lockstep=True)}
        _rounds(series, 1)  # warm-up
        t = _rounds(series, s.reps)
        ref = run.batch(G, n_threads=1, lockstep=False, return_status=True)
        got = run.batch(G, n_threads=1, lockstep=True, return_status=True)
        if not all(a.tobytes() == b.tobytes() for a, b in zip(ref, got)):
            raise BenchError(f"cost: run length {L:g} s: the lockstep batch differs from the one at a time")
        n = scenario.n_samples(run.cfg)
        row = {"length_s": L, "n_samples": n, "table_mb": schedule.table_bytes(run.cfg, run.params.layout) / 1e6, "W": ls.W, "batch_n": nb, "ok_share": float(np.mean(ref[2])),
               "call_s": _stat(t["call"]), "one_run_s": _stat(t["one_run"]),
               "batch_scalar_s_per_run": _stat([v / nb for v in t["batch_scalar"]]),
               "batch_lanes_s_per_run": _stat([v / nb for v in t["batch_lanes"]])}
        tabs = []
        for _ in range(max(1, s.reps_slow)):  # the table from scratch (its functions loaded)
            schedule.clear_cache()
            t0 = time.perf_counter()
            run.table
            tabs.append(time.perf_counter() - t0)
        row["table_s"] = _stat(tabs)
        row["rtf_call"] = L / row["call_s"][FIT_ON]
        row["rtf_lanes"] = L / row["batch_lanes_s_per_run"][FIT_ON]
        log(f"cost: run length {L:g} s: {row['call_s']['median'] * 1e3:.2f} ms the call, "
            f"{row['one_run_s']['median'] * 1e3:.2f} ms one run, {row['batch_lanes_s_per_run']['median'] * 1e3:.3f} ms "
            f"per run in lockstep")
        rows.append(row)
    x = [r["length_s"] for r in rows]
    fits = {k: linear_fit(x, [r[key][FIT_ON] for r in rows]) for k, key in LENGTH_SERIES.items()}
    return {"system": SYSTEM, "controller": CONTROLLER, "h": cfg0.time_h, "h_plant": cfg0.time_h_plant,
            "opt_level": level, "rows": rows, "fits": fits}


LENGTH_SERIES = {"call": "call_s", "one_run": "one_run_s", "batch_scalar": "batch_scalar_s_per_run",
                 "batch_lanes": "batch_lanes_s_per_run", "table": "table_s"}


# ---------------------------------------------------------------------------------------------
# (b) batch size


def _bench_batch(s: Settings, log) -> dict:
    from arvcas.system import load_system

    sysm = load_system(SYSTEM)
    cfg0 = Run(CONTROLLER, system=sysm).compile().cfg
    run = Run(CONTROLLER, scenario=dataclasses.replace(cfg0, time_duration=BATCH_LENGTH), system=sysm).compile()
    _, ls, _, _ = _prepare(run, _level(s))
    sizes = BATCH_SIZES[s.mode]
    G_all = _batches(run, max(sizes), ls.W)["running"]
    run.batch(G_all[:1], n_threads=1, lockstep=False)  # warm-up: the table, the thread buffers
    run.batch(G_all[:1], n_threads=1, lockstep=True)
    rows = []
    for N in sizes:
        G = G_all[:N]
        log(f"cost: batch of {N:,} runs of {BATCH_LENGTH:g} s, one at a time and in lockstep ...")
        t = {False: [], True: []}
        outs = {}
        rounds = 0
        while True:
            for lock in (False, True):
                t0 = time.perf_counter()
                outs[lock] = run.batch(G, n_threads=1, lockstep=lock, return_status=True)
                t[lock].append(time.perf_counter() - t0)
            rounds += 1
            per_round = t[False][0] + t[True][0]
            if rounds >= s.reps or (rounds >= MIN_ROUNDS[s.mode] and (rounds + 1) * per_round > 2 * BATCH_BUDGET_S[s.mode]):
                break
        if not all(a.tobytes() == b.tobytes() for a, b in zip(outs[False], outs[True])):
            raise BenchError(f"cost: a batch of {N} runs: the lockstep outputs differ from the one at a time")
        sc, ln = _stat(t[False]), _stat(t[True])
        rows.append({"n_runs": N, "rounds": rounds, "ok_share": float(np.mean(outs[False][2])),
                     "scalar_s": sc, "lanes_s": ln, "scalar_s_per_run": sc[FIT_ON] / N,
                     "lanes_s_per_run": ln[FIT_ON] / N, "speedup": sc[FIT_ON] / ln[FIT_ON],
                     "speedup_median": sc["median"] / ln["median"],
                     "bitwise_equal": True})
    x = [r["n_runs"] for r in rows]
    fits = {"scalar": linear_fit(x, [r["scalar_s"][FIT_ON] for r in rows]),
            "lanes": linear_fit(x, [r["lanes_s"][FIT_ON] for r in rows])}
    return {"system": SYSTEM, "controller": CONTROLLER, "length_s": BATCH_LENGTH, "W": ls.W, "threads": 1,
            "rows": rows, "fits": fits}


# ---------------------------------------------------------------------------------------------
# (c) arm joints


def _section(text: str, name: str) -> str:
    """The body of table ``[name]`` of a TOML text (up to the next table)."""
    m = re.search(rf"(?ms)^\[{re.escape(name)}\]\n(.*?)(?=^\[|\Z)", text)
    if m is None:
        raise BenchError(f"cost: the shipped {SYSTEM}.toml has no [{name}]")
    return m.group(1).strip() + "\n"


def arm_system_text(n: int, tag: str = "") -> str:
    """Haidou-1's system file with an arm of ``n`` (0..7) revolute joints (module docstring, (c)), named
    ``haidou1_arm<n><tag>``."""
    from arvcas.system import load_system

    src = Path(load_system(SYSTEM).params.path)
    text = src.read_text(encoding="utf-8")
    head = text[:text.index("[arm.mount]")].replace(f'name = "{SYSTEM}"', f'name = "{SYSTEM}_arm{n}{tag}"')
    for key in ("scenario", "gains"):  # the defaults beside the shipped file
        head = re.sub(rf'(?m)^{key} = "([^"]+)"', lambda m: f'{key} = "{(src.parent / m.group(1)).as_posix()}"', head)
    if n == 0:
        return head
    out = [head, "[arm.mount]\n" + _section(text, "arm.mount"), "[arm.tool]\n" + _section(text, "arm.tool")]
    out += [f"[arm.joint{i}]\n" + _section(text, f"arm.joint{min(i, 6)}") for i in range(1, n + 1)]
    out += [f"[arm.link{i}]\n" + _section(text, f"arm.link{min(i, 6)}") for i in range(1, n + 1)]
    stow = [ln for ln in _section(text, "arm.stow").splitlines() if re.match(r"q\d ", ln)]
    stow = stow[:n] + [re.sub(r"^q6", f"q{i}", stow[5]) for i in range(7, n + 1)]
    out += ["[arm.stow]\n" + "\n".join(stow) + "\n", "[payload]\n" + _section(text, "payload")]
    return "\n".join(out)


def arm_scenario_text(n: int) -> str:
    """Haidou-1's scenario with the paper's arm motion as waypoints for ``n`` joints (module docstring, (c))."""
    cfg = scenario.load_scenario()
    text = scenario.default_scenario_path().read_text(encoding="utf-8")
    a = text.index("\n[arm]\n")
    b = text.index("\n[", a + 1)
    qg = [math.degrees(q) for q in cfg.arm_qg] + [QG7_DEG]
    src = 'source = "arvcas/bench/cost.py: the paper\'s arm motion (scenario.toml [arm]) as waypoints"'

    def wp(t: float, q: str) -> str:
        return f"[[arm.waypoint]]\nt = {{ value = {t!r}, unit = \"s\", {src} }}\nq = {q}\n"

    pose = "{ value = [" + ", ".join(f"{v:.12g}" for v in qg[:n]) + f"], unit = \"deg\", {src} }}"
    moves = [wp(cfg.arm_hold_until, '"stow"')]
    if n:
        moves += [wp(cfg.arm_reach_end, pose), wp(cfg.arm_return_start, pose)]
    moves.append(wp(cfg.arm_return_end, '"stow"'))
    payload = (f"\n[payload]\n[[payload.event]]\nt = {{ value = {cfg.arm_payload_on!r}, unit = \"s\", {src} }}\n"
               f"ramp = {{ value = {cfg.arm_payload_ramp!r}, unit = \"s\", {src} }}\n"
               f"to = {{ value = 1.0, unit = \"1\", {src} }}\n") if n else ""
    return text[:a] + "\n[arm]\n" + "".join(moves) + text[b:] + payload


def _bench_joints(s: Settings, work: Path, log) -> dict:
    from arvcas.system import load_system

    level, nb = _level(s), LENGTH_BATCH[s.mode]
    # a name of its own each time in a process: the time table's functions are kept per process by the
    # system's structure (its name too), so a second measurement in the same process compiles them again
    k = next(_MEASUREMENTS)
    tag = f"_m{k}" if k else ""
    rows = []
    for n in JOINTS[s.mode]:
        ps, pc = work / f"{SYSTEM}_arm{n}.toml", work / f"{SYSTEM}_arm{n}.scenario.toml"
        ps.write_text(arm_system_text(n, tag), encoding="utf-8")
        pc.write_text(arm_scenario_text(n), encoding="utf-8")
        sysm = load_system(ps)
        if sysm.n_joints != n:
            raise BenchError(f"cost: {ps}: {sysm.n_joints} joints, expected {n}")
        run = Run(CONTROLLER, scenario=scenario.load_scenario(pc), system=sysm).compile()
        log(f"cost: {n} joints: compiling the run and the lockstep run cold ...")
        builds = {"run": [], "run_cc": [], "lanes": [], "lanes_cc": []}

        def cold_builds(expected: int):
            """The run's two libraries built into the current (fresh, empty) cache; their times kept."""
            before = codegen.stats()["compile"]
            fn, ls, run_s, lanes_s = _prepare(run, level)
            run.table  # the first time (expected 4): also compiles the table's two functions
            if codegen.stats()["compile"] != before + expected:
                raise BenchError(f"cost: {n} joints: expected {expected} cold builds, got "
                                 f"{codegen.stats()['compile'] - before}")
            for k, v in (("run", run_s), ("run_cc", codegen.artifact_of(fn)["compile_time_s"]), ("lanes", lanes_s),
                         ("lanes_cc", codegen.artifact_of(ls.function)["compile_time_s"])):
                builds[k].append(float(v))
            return fn, ls

        with _temp_cache():  # a fresh, empty cache: every build cold
            schedule.clear_cache()
            t0 = time.perf_counter()
            fn, ls = cold_builds(4)
            first_s = time.perf_counter() - t0
            schedule.clear_cache()
            t0 = time.perf_counter()
            run.table
            table_s = time.perf_counter() - t0
            table_functions_s = max(1e-6, first_s - builds["run"][0] - builds["lanes"][0] - table_s)
            g = run.default_gains()
            G = _batches(run, nb, ls.W)["running"]
            args = _run_args(fn, g, profiles.noise_sequence(run.cfg, 0), run.cfg, sysm.params.vector(),
                             layout=sysm.layout)
            series = {"call": lambda: calls.call(fn, *args),
                      "batch_lanes": lambda: run.batch(G, n_threads=1, lockstep=True)}
            _rounds(series, 1)
            t = _rounds(series, s.reps)
            ok = run.batch(G, n_threads=1, lockstep=True, return_status=True)[2]
        for _ in range(COMPILE_REPS[s.mode] - 1):  # the two libraries again, each time into a fresh cache
            with _temp_cache():
                cold_builds(2)
        ins = _step_instructions(closedloop.RunSpec(run.controller, run.cfg.graph_key(), run.opts, sysm.layout),
                                 trace=False)
        ns = scenario.n_samples(run.cfg)
        call, lanes = _stat(t["call"]), _stat([v / nb for v in t["batch_lanes"]])
        st = {k: _stat(v) for k, v in builds.items()}
        rows.append({
            "joints": n, "n_samples": ns, "length_s": run.cfg.time_duration, "ok_share": float(np.mean(ok)),
            "run_build_s": st["run"][FIT_ON], "run_cc_s": st["run_cc"][FIT_ON], "lanes_build_s": st["lanes"][FIT_ON],
            "lanes_cc_s": st["lanes_cc"][FIT_ON], "builds": st,
            "table_functions_build_s": table_functions_s, "table_s": table_s,
            "instructions_per_sample": ins["total"], "step_calls": ins["calls"],
            "call_s": call, "lanes_s_per_run": lanes,
            "call_us_per_sample": call[FIT_ON] / ns * 1e6, "lanes_us_per_sample": lanes[FIT_ON] / ns * 1e6,
            "call_us_per_sample_median": call["median"] / ns * 1e6,
            "lanes_us_per_sample_median": lanes["median"] / ns * 1e6,
        })
        log(f"cost: {n} joints: {ins['total']:,} instructions per sample, {rows[-1]['call_us_per_sample']:.2f} us "
            f"per sample ({rows[-1]['lanes_us_per_sample']:.2f} in lockstep), builds (fastest of "
            f"{len(builds['run'])}) {st['run'][FIT_ON]:.1f} + {st['lanes'][FIT_ON]:.1f} s")
    x = [r["joints"] for r in rows]
    fits = {k: linear_fit(x, [r[k] for r in rows]) for k in JOINT_SERIES}
    return {"base": SYSTEM, "controller": CONTROLLER, "opt_level": level, "batch_n": nb, "qg7_deg": QG7_DEG,
            "rows": rows, "fits": fits}


_MEASUREMENTS = itertools.count()  # of the arm sweep in this process (the first: no tag)
JOINT_SERIES = ("call_us_per_sample", "lanes_us_per_sample", "instructions_per_sample", "run_build_s",
                "run_cc_s", "lanes_build_s", "table_functions_build_s")


# ---------------------------------------------------------------------------------------------


def _bench_cost(s: Settings, log) -> dict:
    from arvcas.bench.common import _CpuMeter, _machine

    m, la0 = _CpuMeter(), [round(x, 2) for x in os.getloadavg()]
    with tempfile.TemporaryDirectory(prefix="arvcas-bench-cost-") as td:
        res = {"length": _bench_length(s, log), "batch": _bench_batch(s, log), "joints": _bench_joints(s, Path(td), log),
               "tolerance": LINEAR_TOL}
    mach = _machine()
    res["measured"] = {"date": mach["date"], "git_commit": mach["git_commit"], "mode": s.mode, "load_avg_start": la0,
                       "load_avg_end": [round(x, 2) for x in os.getloadavg()], "other_cpu_share": m.share()}
    return res


# ---------------------------------------------------------------------------------------------
# text


def _fmt_s(x: float) -> str:
    """A time with its unit (s, ms, µs)."""
    from arvcas.bench.common import _g

    if abs(x) >= 1:
        return f"{_g(x)} s"
    if abs(x) >= 1e-3:
        return f"{_g(x * 1e3)} ms"
    return f"{_g(x * 1e6)} µs"


def _where(f: dict, unit: str, fmt=lambda v: f"{v:g}") -> str:
    """Where a fit's line holds, in words."""
    off = ", ".join(f"{r:+.0%}" for r in f["residual"] if abs(r) > LINEAR_TOL)
    if f["n_points"] == 0:
        return f"no three consecutive points on one line within {LINEAR_TOL:.0%}; the line through all: {off} off it"
    span = f"{fmt(f['from'])}-{fmt(f['to'])} {unit}".strip()
    if f["linear_everywhere"]:
        return f"linear over the whole sweep ({span}; largest residual {f['max_residual']:.1%})"
    return (f"linear over {span} ({f['n_points']} points, largest residual {f['max_residual']:.1%}); the other points "
            + (f"{off} off the line" if off else "within the tolerance of it too"))


def _prop(f: dict, unit: str) -> str:
    p = f["proportional_from"]
    if p is None:
        return "no positive slope"
    if f["intercept"] <= 0 or p <= 0:
        return "no fixed part (intercept <= 0)"
    return f"the fixed part below 10 % from {p:,.0f} {unit}" if p >= 10 else f"the fixed part below 10 % from {p:.2g} {unit}"


def _fixed(f: dict, label: str, x0: float) -> str:
    """The fixed part of a run-length fit in words."""
    a, b = f["intercept"], f["slope"]
    if a <= 0:
        return f"{label}: none measurable (the line's intercept is {_fmt_s(a)}, below zero)"
    return (f"{label}: {_fmt_s(a)}, {a / (a + b * x0):.0%} of a {x0:g} s run, below 10 % of a run from "
            f"{f['proportional_from']:,.0f} s on")


def _measured_line(ms: dict) -> str:
    return (f"Measured on {ms['date']} (commit {ms['git_commit']}, {ms['mode']} mode; `arvcas bench --only cost` puts "
            f"this section into the file); load average (1, 5, 15 min) {' '.join(f'{x:.2f}' for x in ms['load_avg_start'])} "
            f"before, {' '.join(f'{x:.2f}' for x in ms['load_avg_end'])} after; CPU time of other processes while "
            f"measuring: {ms['other_cpu_share']:.1%} of the machine.")


def _fit_table(fits: dict, names: dict, heads: tuple, unit: str, rate_suffix: str, fmt) -> list[str]:
    """The table of a sweep's time fits: slope, intercept, 1 / slope, where linear, where proportional."""
    L = ["", f"| series | {' | '.join(heads)} | where linear | proportional |", "|---|--:|--:|--:|---|---|"]
    for k, f in fits.items():
        L.append(f"| {names[k]} | {_fmt_s(f['slope'])} | {_fmt_s(f['intercept'])} | {1 / f['slope']:,.0f}{rate_suffix} | "
                 f"{_where(f, unit, fmt)} | {_prop(f, unit)} |")
    return L


def _figure_and_head(fig_prefix: str | None, fig: str, alt: str, cols: tuple) -> list[str]:
    """The figure's link (when ``fig_prefix`` is given) and a table's head of right-aligned columns."""
    link = [f"![{alt}]({fig_prefix}{fig})", ""] if fig_prefix is not None else []
    return link + ["| " + " | ".join(cols) + " |", "|" + "--:|" * len(cols)]


def _fm(st: dict, scale: float = 1.0) -> str:
    """A timing as 'fastest (median)'."""
    return f"{_fmt_s(st[FIT_ON] * scale)} ({_fmt_s(st['median'] * scale)})"


def _body(r: dict, fig_prefix: str | None) -> list[str]:
    """The section's text (bench.md and results/cost/README.md), figures linked under ``fig_prefix``."""
    from arvcas.bench.common import _g

    ln, bt, jt = r["length"], r["batch"], r["joints"]
    tol = r["tolerance"]
    F = ln["fits"]
    L = [f"Every series is fitted with a line `t = a + b x` (least squares on relative residuals) through each "
         f"point's fastest round (as `timeit` takes it: on this shared machine the least disturbed round measures the "
         f"code; the tables give the median in brackets). *Linear* means every point of a run of at least three "
         f"consecutive sweep points lies within {tol:.0%} of that run's own line (the longest such run is reported, "
         f"with every point's residual against its line); *proportional* means the fixed part `a` is below {tol:.0%} "
         f"of the cost. One thread throughout.", ""]
    L += [f"### (a) Run length: {ln['system']}, `{ln['controller']}`, h = {ln['h']:g} s, plant step {ln['h_plant']:g} s",
          "",
          f"Each length its own compiled run ({ln['opt_level']}). *call*: the compiled run function alone (time table "
          f"built beforehand); *one run*: `CompiledRun.batch` of one gain set, one at a time (the Python around the "
          f"call, the noise drawn, the inputs checked); *in a batch*: per run of a batch of {ln['rows'][0]['batch_n']} "
          f"(the defaults times U(0.95, 1.05)), one at a time and in lockstep (W = {ln['rows'][0]['W']}; outputs equal "
          f"to the bit); *table*: the run's time table from scratch (a new scenario's first run pays it). Fastest "
          f"(median) of {ln['rows'][0]['call_s']['n']} alternated rounds.", ""]
    L += _figure_and_head(fig_prefix, "cost_length.png", "run time against run length", (
        "run length s", "samples", "time table MB", "call", "one run", "per run, batch one at a time",
        "per run, batch in lockstep", "table", "real-time factor (fastest): call / lockstep"))
    for x in ln["rows"]:
        L.append(f"| {x['length_s']:g} | {x['n_samples']:,} | {x['table_mb']:.3g} | {_fm(x['call_s'])} | {_fm(x['one_run_s'])} | "
                 f"{_fm(x['batch_scalar_s_per_run'])} | {_fm(x['batch_lanes_s_per_run'])} | {_fm(x['table_s'])} | "
                 f"{x['rtf_call']:,.0f}x / {x['rtf_lanes']:,.0f}x |")
    L += _fit_table(F, {"call": "call", "one_run": "one run", "batch_scalar": "per run, batch one at a time",
                        "batch_lanes": "per run, batch in lockstep", "table": "time table"},
                    ("slope b (per simulated s)", "intercept a", "asymptotic real-time factor 1/b"), "s", "x",
                    lambda v: f"{v:g}")
    fo, fc = F["one_run"], F["call"]
    x0 = ln["rows"][0]["length_s"]
    L += ["", f"A run's cost is its length times {_fmt_s(fc['slope'])} per simulated second "
              f"({_fmt_s(fc['slope'] * ln['h'])} per controller sample) plus a fixed part: " + "; ".join(
                  _fixed(f, label, x0) for f, label in ((fc, "the compiled call"), (fo, "one run through the API")))
          + ". In a batch the fixed part of the API is paid once per batch (b)."]
    L += ["", f"### (b) Batch size: the {bt['length_s']:g} s run, one at a time and in lockstep (W = {bt['W']}), "
              f"{bt['threads']} thread", ""]
    L += ["Fastest (median) of the rounds; per run: the fastest round over the runs.", ""]
    L += _figure_and_head(fig_prefix, "cost_batch.png", "batch time against batch size", (
        "runs", "rounds", "running share", "one at a time: batch", "per run", "lockstep: batch", "per run",
        "lockstep speed-up (fastest; medians)"))
    for x in bt["rows"]:
        L.append(f"| {x['n_runs']:,} | {x['rounds']} | {x['ok_share']:.0%} | {_fm(x['scalar_s'])} | "
                 f"{_fmt_s(x['scalar_s_per_run'])} | {_fm(x['lanes_s'])} | {_fmt_s(x['lanes_s_per_run'])} | "
                 f"{x['speedup']:.2f}x; {x['speedup_median']:.2f}x |")
    L += _fit_table(bt["fits"], {"scalar": "one at a time", "lanes": "lockstep"},
                    ("slope b (per run)", "intercept a (per batch)", "runs per second 1/b"), "runs", "",
                    lambda v: f"{v:,.0f}")
    L += ["", f"### (c) Arm joints: {jt['base']}'s vehicle with a generated arm of 0..{jt['rows'][-1]['joints']} joints "
              f"(100 s, `{jt['controller']}`, {jt['opt_level']})", "",
          f"The system files are written by `arvcas/bench/cost.py` (`arm_system_text`: joint and link i are "
          f"{jt['base']}'s i, joint 7 a copy of joint 6; the paper's arm motion as waypoints, joint 7 to "
          f"{jt['qg7_deg']:g} deg). Builds: cold, into a fresh empty cache (graph, C, compiler, load); cc: the "
          f"compiler's share; the fastest of {jt['rows'][0]['builds']['run']['n']} cold builds each (the time table's two "
          f"functions: once, with the first). Per sample: the compiled run alone, and a run in a lockstep batch of "
          f"{jt['batch_n']}, fastest (median) of {jt['rows'][0]['call_s']['n']} rounds.", ""]
    L += _figure_and_head(fig_prefix, "cost_joints.png", "per-sample time, instructions and compile time against joints", (
        "joints", "instructions / sample", "µs / sample, call", "µs / sample, lockstep", "run build s (cc)",
        "lockstep build s (cc)", "table functions build s", "table s"))
    for x in jt["rows"]:
        L.append(f"| {x['joints']} | {x['instructions_per_sample']:,} | {_g(x['call_us_per_sample'])} "
                 f"({_g(x['call_us_per_sample_median'])}) | {_g(x['lanes_us_per_sample'])} "
                 f"({_g(x['lanes_us_per_sample_median'])}) | {_g(x['run_build_s'])} "
                 f"({_g(x['run_cc_s'])}) | {_g(x['lanes_build_s'])} ({_g(x['lanes_cc_s'])}) | "
                 f"{_g(x['table_functions_build_s'])} | {_g(x['table_s'])} |")
    units = {"call_us_per_sample": ("µs per sample, call", "µs"), "lanes_us_per_sample": ("µs per sample, lockstep", "µs"),
             "instructions_per_sample": ("instructions per sample", ""), "run_build_s": ("run build", "s"),
             "run_cc_s": ("run build, compiler", "s"), "lanes_build_s": ("lockstep build", "s"),
             "table_functions_build_s": ("table functions build", "s")}
    L += ["", "| series | slope b (per joint) | intercept a (no arm) | b / a | where linear |", "|---|--:|--:|--:|---|"]
    for k, f in jt["fits"].items():
        label, u = units[k]
        ratio = f"{f['slope'] / f['intercept']:.1%}" if f["intercept"] > 0 else "-"
        L.append(f"| {label} | {_g(f['slope'])} {u} | {_g(f['intercept'])} {u} | {ratio} | {_where(f, 'joints')} |")
    return L


def cost_markdown(r: dict | None) -> list[str]:
    """Section 9 of bench.md."""
    if not r:
        return []
    L = ["", "## 9. Cost against work", "", _measured_line(r["measured"]), "",
         "The figures and this section's text with them: `cost/README.md` beside this file.", ""]
    return L + _body(r, None)


def readme(r: dict) -> str:
    L = ["# Cost against work", "",
         "Written by `arvcas bench` (section 9, `arvcas/bench/cost.py`) from the `cost` key of `../bench.json`; "
         "`arvcas bench --only cost` measures it again.", "", _measured_line(r["measured"]), ""]
    return "\n".join(L + _body(r, "") + [""])


# ---------------------------------------------------------------------------------------------
# figures


def _plot_fit(ax, f: dict, color, xs) -> None:
    x = np.linspace(f["from"], f["to"], 200) if ax.get_xscale() == "linear" else np.geomspace(f["from"], f["to"], 200)
    ax.plot(x, f["intercept"] + f["slope"] * x, ls="--", lw=0.6, color=color)


def figures(r: dict) -> dict:
    """The three figures of the section: {file name: matplotlib Figure}."""
    from arvcas.io import style

    @style.styled
    def draw():
        out = {}
        ln = r["length"]
        fig = style.figure("column", 2.9)
        ax = fig.add_subplot()
        ax.set_xscale("log")
        ax.set_yscale("log")
        x = [row["length_s"] for row in ln["rows"]]
        for i, (k, key, label) in enumerate((
                ("one_run", "one_run_s", "one run (CompiledRun.batch of 1)"), ("call", "call_s", "the compiled call alone"),
                ("batch_scalar", "batch_scalar_s_per_run", f"per run, batch of {ln['rows'][0]['batch_n']}, one at a time"),
                ("batch_lanes", "batch_lanes_s_per_run", f"per run, batch of {ln['rows'][0]['batch_n']}, lockstep"),
                ("table", "table_s", "time table from scratch"))):
            c = style.color("", i)
            ax.plot(x, [row[key][FIT_ON] for row in ln["rows"]], "o", color=c, label=label)
            ax.plot(x, [row[key]["median"] for row in ln["rows"]], "o", mfc="none", mew=0.5, ms=2.5, color=c)
            _plot_fit(ax, ln["fits"][k], c, x)
        ax.set_xlabel("run length (s)")
        ax.set_ylabel("wall time (s)")
        ax.set_title(f"{ln['system']}: cost against run length\n(filled: fastest round, open: median; dashed: a + b x)")
        ax.legend(loc="upper left")
        ax.grid(True, which="major")
        style.log_labels(ax)
        out["cost_length.png"] = fig

        bt = r["batch"]
        fig = style.figure("page", 2.6)
        a1, a2 = fig.subplots(1, 2)
        x = [row["n_runs"] for row in bt["rows"]]
        for i, (k, label) in enumerate((("scalar", "one at a time"), ("lanes", f"lockstep (W = {bt['W']})"))):
            c = style.color("", i)
            a1.plot(x, [row[f"{k}_s"][FIT_ON] for row in bt["rows"]], "o", color=c, label=label)
            a1.plot(x, [row[f"{k}_s"]["median"] for row in bt["rows"]], "o", mfc="none", mew=0.5, ms=2.5, color=c)
            a2.plot(x, [row[f"{k}_s_per_run"] * 1e3 for row in bt["rows"]], "o-", color=c, label=label)
            for ax in (a1,):
                ax.set_xscale("log")
                ax.set_yscale("log")
                _plot_fit(ax, bt["fits"][k], c, x)
        a2.set_xscale("log")
        style.log_labels(a2)
        a1.set_xlabel("runs in the batch")
        a1.set_ylabel("batch wall time (s)")
        a1.set_title(f"{bt['length_s']:g} s runs, {bt['threads']} thread (open: median; dashed: a + b n)")
        a2.set_xlabel("runs in the batch")
        a2.set_ylabel("wall time per run (ms)")
        a2.set_ylim(bottom=0)
        a2.set_title("per run (fastest round)")
        for ax, where in ((a1, "upper left"), (a2, "upper right")):
            ax.grid(True, which="major")
            ax.legend(loc=where)
        style.log_labels(a1)
        out["cost_batch.png"] = fig

        jt = r["joints"]
        fig = style.figure("page", 2.4)
        axs = fig.subplots(1, 3)
        x = [row["joints"] for row in jt["rows"]]
        for i, (k, label) in enumerate((("call_us_per_sample", "the compiled call"),
                                        ("lanes_us_per_sample", "lockstep batch"))):
            c = style.color("", i)
            axs[0].plot(x, [row[k] for row in jt["rows"]], "o", color=c, label=label)
            axs[0].plot(x, [row[f"{k}_median"] for row in jt["rows"]], "o", mfc="none", mew=0.5, ms=2.5, color=c)
            _plot_fit(axs[0], jt["fits"][k], c, x)
        axs[0].set_ylabel("µs per controller sample")
        c = style.color("", 2)
        axs[1].plot(x, [row["instructions_per_sample"] for row in jt["rows"]], "o", color=c)
        _plot_fit(axs[1], jt["fits"]["instructions_per_sample"], c, x)
        axs[1].set_ylabel("CasADi instructions per sample")
        for i, (k, label) in enumerate((("run_build_s", "run library"), ("lanes_build_s", "lockstep library"),
                                        ("table_functions_build_s", "time table's functions"))):
            c = style.color("", 3 + i)
            axs[2].plot(x, [row[k] for row in jt["rows"]], "o", color=c, label=label)
            _plot_fit(axs[2], jt["fits"][k], c, x)
        axs[2].set_ylabel(f"cold build (s), {jt['opt_level']}")
        top = max(row[k] for row in jt["rows"] for k in ("run_build_s", "lanes_build_s", "table_functions_build_s"))
        for ax in axs:
            ax.set_xticks(x)
            ax.set_xlabel("arm joints")
            ax.set_ylim(bottom=0)
            ax.grid(True, which="major")
        axs[0].legend(loc="upper left")
        axs[2].legend(loc="upper left")
        axs[2].set_ylim(top=1.45 * top)  # the legend above the points
        fig.suptitle(f"{jt['base']}'s vehicle with generated arms: cost per joint (dashed: a + b n)")
        out["cost_joints.png"] = fig
        return out

    return draw()


def write_files(r: dict, d: Path) -> list[Path]:
    """``cost_*.png`` and README.md into directory ``d`` from bench.json's ``cost`` key."""
    from arvcas.util import files
    from arvcas.io import style

    d = files.prepare_dir(Path(d), f"bench: {d}")
    out = [style.write_figure(d / name, fig) for name, fig in figures(r).items()]
    files.write_text(d / "README.md", readme(r))
    return out + [d / "README.md"]
