"""bench.md: the tables of bench.json.

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).
"""

from __future__ import annotations


from arvcas.bench.common import CONTROLLER, N_INPUT_SETS, PLAIN_RK4, PLAIN_RK4_KEY, _g, _spread, _verdict
from arvcas.bench.controller import _controller_markdown
from arvcas.bench.cost import cost_markdown
from arvcas.bench.lanes import _lanes_markdown
from arvcas.bench.targets import STUDY_RUNS

def _m(st) -> float:
    return st["median"] if isinstance(st, dict) else float(st)


def _targets_markdown(tg: dict) -> list[str]:
    d, pv = tg["default"], tg["previous"]
    T = tg["targets"]

    def parts(r):
        return " + ".join(f"{c['calls']} x {k} {c['n_instructions']:,}" for k, c in r["step_calls"].items())

    def row(label, a, b, ratio=""):
        return f"| {label} | {a} | {b} | {ratio} |"

    m1, m2 = d["memory_1"], d["memory_2"]
    isa, cr = tg.get("isa", {"flags": []}), tg.get("corun")  # absent from a bench.json before them
    L = [
        f"## 2b. The default plant step ({d['h_plant']:g} s) against the previous one "
        f"({pv['h_plant']:g} s) and CasADi's VM",
        "",
        f"Same process, same controller (`{CONTROLLER}`, Table 2 gains, seed 0). Compiled runs: the two steps "
        f"interleaved round by round, {d['run_s']['n']} rounds (median; spread in brackets). Batches: "
        f"{d['batch_n']} gain sets (one generation of the paper study), 1 and 2 threads interleaved, "
        f"{d['batch_s_1']['n']} rounds each (median; the 2-thread ratio also per round).",
        "",
        f"| | default, h_plant = {d['h_plant']:g} s ({d['substeps']} RK4 steps per sample) | previous, "
        f"{pv['h_plant']:g} s ({pv['substeps']} steps) | default / previous |",
        "|---|--:|--:|--:|",
        row("one 100 s run, compiled, metrics only: wall s", f"{_g(_m(d['run_s']))} ({_spread(d['run_s'])})",
            f"{_g(_m(pv['run_s']))} ({_spread(pv['run_s'])})", f"{tg['ratio_default_over_previous']:.2f}x faster"),
        row(f"real-time factor (target >= {T['rtf']:,.0f} at the default): the fastest round; the median",
            f"**{_g(d['rtf_best'])}**: {_verdict(d['rtf_best'], T['rtf'], True)}; {_g(d['rtf'])}",
            f"{_g(pv['rtf_best'])}; {_g(pv['rtf'])}", ""),
        row("the same run in CasADi's VM: wall s (real-time factor)", f"{_g(_m(d['vm_run_s']))} ({_g(d['rtf_vm'])})",
            f"{_g(_m(pv['vm_run_s']))} ({_g(pv['rtf_vm'])})", ""),
        row("compiled vs VM", f"{d['ratio_vm_over_compiled']:.1f}x", f"{pv['ratio_vm_over_compiled']:.1f}x", ""),
        row("instructions per controller sample", f"{parts(d)} = **{d['instructions_per_sample']:,}**",
            f"{parts(pv)} = {pv['instructions_per_sample']:,}",
            f"{pv['instructions_per_sample'] / d['instructions_per_sample']:.2f}x fewer"),
        row("instructions per second, compiled", _g(d["instr_per_s"]), _g(pv["instr_per_s"]), ""),
        *([row(f"the same run built without `{' '.join(isa['flags'])}` (ARVCAS_ISA=baseline; outputs bitwise equal): "
               "wall s; real-time factor, fastest round",
               f"{_g(_m(isa['baseline_run_s']))} ({_spread(isa['baseline_run_s'])}); {_g(isa['rtf_baseline_best'])}", "",
               f"{isa['ratio_baseline_over_isa']:.2f}x faster with it (fastest rounds {isa['ratio_baseline_over_isa_best']:.2f}x)")]
          if isa["flags"] else []),
        row("batch, 1 thread: runs/s", _g(d["runs_per_s_1"]), _g(pv["runs_per_s_1"]), ""),
        row("batch, 2 threads: runs/s", _g(d["runs_per_s_2"]), _g(pv["runs_per_s_2"]),
            f"{tg['ratio_batch_default_over_previous']:.2f}x"),
        row(f"2 threads / 1 thread (target >= {T['ratio_2_over_1']:.2f}x): the fastest round of each; the ratio "
            "of the medians; the median of the rounds' own ratios (each round one batch on 1 thread, then one on 2)",
            f"**{d['ratio_2_over_1_best']:.2f}x**: {_verdict(d['ratio_2_over_1_best'], T['ratio_2_over_1'], True)}; "
            f"{d['ratio_2_over_1']:.2f}x; {d['ratio_2_over_1_paired']:.2f}x",
            f"{pv['ratio_2_over_1_best']:.2f}x; {pv['ratio_2_over_1']:.2f}x; {pv['ratio_2_over_1_paired']:.2f}x", ""),
        *([row(f"the machine's 2-core ceiling: two independent processes, each {cr['n_runs']} runs on 1 thread, "
               "started together, against one alone (2 x alone / the slower of the two): fastest rounds; medians",
               f"{cr['ceiling_best']:.2f}x; {cr['ceiling_median']:.2f}x", "", "")] if cr else []),
        row(f"{STUDY_RUNS:,} runs on 2 threads, min (target <= {T['study_min']:g} min; runs only)",
            f"**{d['study_min']:.2f}**: {_verdict(d['study_min'], T['study_min'], False)}", f"{pv['study_min']:.2f}", ""),
        row("peak memory per thread, MB: batch over the loaded process, 1 thread / 2 threads (per thread)",
            f"{_g(d['peak_mb_per_thread_1'])} / {_g(d['peak_mb_per_thread_2'])}",
            f"{_g(pv['peak_mb_per_thread_1'])} / {_g(pv['peak_mb_per_thread_2'])}", ""),
        row("work memory per thread (the compiled run's work vectors), MB", _g(d["work_mb_per_thread"]),
            _g(pv["work_mb_per_thread"]), ""),
        row("shared by all threads: the time table, MB; the loaded process, MB",
            f"{_g(d['table_mb'])}; {_g(d['process_base_mb'])}", f"{_g(pv['table_mb'])}; {_g(pv['process_base_mb'])}", ""),
        "",
        f"Peak memory: VmHWM of a fresh process (run loaded, time table built: {_g(m1['base_mb'])} MB) after one "
        f"batch on 1 thread ({_g(m1['peak_mb'])} MB) and, in another, on 2 threads ({_g(m2['peak_mb'])} MB). "
        f"The {STUDY_RUNS:,}-run row: {tg['study_note']}. The verdicts take the fastest round (as `timeit` "
        "does: the least disturbed one measures the code, the spread above it the machine's other tenants, "
        "which `/proc/stat` does not show from inside a VM); for the 2-thread ratio, a batch on 1 thread can "
        "also move to the quieter core while one on 2 threads waits for the slower. The medians stand beside them.",
        "",
    ]
    return L


def render_markdown(res: dict) -> str:
    m, s = res["machine"], res["settings"]
    pl, cl, co, rec = res["plant"], res["closed_loop"], res["compile"], res["recommendation"]
    la0 = " ".join(f"{x:.2f}" for x in m["load_avg_start"])
    la1 = " ".join(f"{x:.2f}" for x in m["load_avg_end"])
    L = [
        "# arvcas benchmark" + (" (QUICK MODE: figures not for the record)" if res["mode"] == "quick" else ""),
        "",
        f"Written by `arvcas bench{' --quick' if res['mode'] == 'quick' else ''}` on {m['date']} "
        f"(arvcas {m['arvcas_version']}, commit {m['git_commit']}); the figures are in `bench.json`.",
        "",
        f"- machine: {m['cpu_model']}, {m['cores']} cores ({m['cores_usable']} usable), {m['platform']}",
        f"- compiler: {m['compiler']}; generated code built with `{m['codegen_flags']}`; CasADi "
        f"{m['casadi_version']}, Python {m['python']}, NumPy {m['numpy_version']}",
        f"- load average (1, 5, 15 min): {la0} before, {la1} after (the benchmark itself keeps about one "
        f"core busy); CPU time used by other processes "
        f"while measuring: {m['other_cpu_share']:.1%} of the machine; total {m['total_wall_s']:.0f} s",
        f"- every time is the median of n repetitions (n = {s['reps']} for fast, {s['reps_slow']} for slow "
        f"measurements); spread = (max - min) / median; ratios are against baselines of this same run",
        "",
        "## 1. Plant functions",
        "",
        f"Per evaluation. C: a driver calling the compiled library in a loop over {N_INPUT_SETS} varying "
        f"input sets ({pl['uvms_rhs']['c_ns_per_eval']['evals_per_rep']:,} evaluations per repetition for "
        f"uvms_rhs). map: `f.map({s['map_n']})` called from Python, time / {s['map_n']}. single: one call "
        f"from Python (includes the call overhead). VM: the same SX Function in CasADi's virtual machine. "
        f"map call floor: the same call to a Function that does nothing (converting inputs and outputs).",
        "",
        "| function | instructions | C ns/eval (spread) | C instr/s | map compiled ns | map VM ns | "
        "**VM/compiled (map)** | VM map / C | map call floor ns | single compiled µs | single VM µs | "
        "VM/compiled (single) |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for name, r in pl.items():
        L.append(
            f"| {name} | {r['n_instructions']:,} | {_g(_m(r['c_ns_per_eval']))} ({_spread(r['c_ns_per_eval'])}) "
            f"| {_g(r['c_instr_per_s'])} | {_g(_m(r['map_compiled_ns_per_eval']))} | "
            f"{_g(_m(r['map_vm_ns_per_eval']))} | **{r['ratio_vm_over_compiled_map']:.1f}x** | "
            f"{r['ratio_vm_map_over_c']:.1f}x | {_g(_m(r['map_call_floor_ns_per_eval']))} | "
            f"{_g(_m(r['single_compiled_us']))} | {_g(_m(r['single_vm_us']))} "
            f"| {r['ratio_vm_over_compiled_single']:.1f}x |")
    u = pl["uvms_rhs"]
    L += [
        "",
        f"uvms_rhs: {u['n_instructions']:,} CasADi instructions; from C {_g(_m(u['c_ns_per_eval']))} ns per "
        f"evaluation, i.e. {_g(u['c_instr_per_s'])} instructions/s (VM: {_g(u['vm_instr_per_s'])}/s). "
        f"Compiled vs VM (target >= 5x): {u['ratio_vm_over_compiled_map']:.1f}x batched through map, "
        f"{u['ratio_vm_map_over_c']:.1f}x for the C driver against the VM's batched time.",
        "",
        "### Calling the dynamics from other code: `arvcas.dynamics` and `arvcas export-c`",
        "",
        f"Per evaluation, beside the C driver above (same run). exported C: the same driver on the library "
        f"`arvcas export-c` writes, built by its Makefile. dynamics single: `arvcas.dynamics(name)(x, ...)` on "
        f"NumPy arrays, one evaluation per call; CasADi call: `arvcas.compiled(name)` called on NumPy arrays "
        f"(converted to DM and back) and on DM built beforehand (the single column above). dynamics batch: one call on {s['map_n']:,} rows (arrays of shape (n, size)), on 1 "
        f"thread and on {pl['uvms_rhs']['dyn_batch_threads']} threads.",
        "",
        "| function | C ns | exported C ns | dynamics single µs | CasADi call, NumPy in/out µs | CasADi call, DM µs | "
        "CasADi NumPy / dynamics | dynamics batch ns, 1 thread | / C | batch ns, threads | / C |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for name, r in pl.items():
        L.append(
            f"| {name} | {_g(_m(r['c_ns_per_eval']))} | {_g(_m(r['export_c_ns_per_eval']))} | "
            f"{_g(_m(r['dyn_single_us']))} ({_spread(r['dyn_single_us'])}) | {_g(_m(r['casadi_numpy_single_us']))} | "
            f"{_g(_m(r['single_compiled_us']))} | "
            f"{r['ratio_casadi_numpy_over_dyn_single']:.1f}x | {_g(_m(r['dyn_batch_ns_per_eval']))} "
            f"({_spread(r['dyn_batch_ns_per_eval'])}) | {r['ratio_dyn_batch_over_c']:.2f}x | "
            f"{_g(_m(r['dyn_batch_threads_ns_per_eval']))} | {r['ratio_dyn_batch_threads_over_c']:.2f}x |")
    v = pl["vehicle_rhs"]
    L += [
        "",
        f"Yardstick, vehicle_rhs written by hand in NumPy (arvcas/bench/plant.py): "
        f"{_g(_m(v['numpy_single_us']))} µs per single call, {_g(_m(v['numpy_batch_ns_per_eval']))} ns per "
        f"evaluation vectorised over {s['map_n']:,} rows; arvcas.dynamics: {_g(_m(v['dyn_single_us']))} µs "
        f"and {_g(_m(v['dyn_batch_ns_per_eval']))} ns (NumPy time / dynamics time: "
        f"{_m(v['numpy_single_us']) / _m(v['dyn_single_us']):.0f}x single, "
        f"{_m(v['numpy_batch_ns_per_eval']) / _m(v['dyn_batch_ns_per_eval']):.1f}x batched).",
        "",
        "## 2. Closed loop",
        "",
        f"One {cl['duration_s']:g} s run of the `{cl['controller']}` controller ({cl['n_samples']} controller "
        f"samples, {cl['substeps']} RK4 plant substeps each), one core.",
        "",
        "| run | wall s (spread) | real-time factor | vs VM |",
        "|---|--:|--:|--:|",
    ]
    vm = _m(cl["vm_run_s"])
    for label, key, rtf in (("compiled run, metrics only", "run_metrics_s", "rtf_metrics"),
                            ("the same, building its time table first", "run_cold_s", "rtf_cold"),
                            ("compiled run, with trace", "run_trace_s", "rtf_trace"),
                            ("`simulate()` (trace + Result)", "simulate_s", "rtf_simulate"),
                            ("CasADi VM, metrics only (baseline)", "vm_run_s", "rtf_vm")):
        L.append(f"| {label} | {_g(_m(cl[key]))} ({_spread(cl[key])}) | {_g(cl[rtf])} | "
                 f"{vm / _m(cl[key]):.1f}x |")
    call_list = " + ".join(f"{c['calls']} x {k} {c['n_instructions']:,}" for k, c in cl["step_calls"].items())
    b = cl["batch"]
    L += [
        "",
        f"The run's time table (`arvcas.sim.schedule`: the arm's and the disturbance's time-only terms at every "
        f"RK4 stage time) takes {_g(_m(cl['table_s']))} s ({_spread(cl['table_s'])}) to build. It depends only "
        f"on the scenario and the parameters, so a batch builds it once and `simulate` keeps the last few; "
        f"the metrics-only and trace rows reuse it, the second row builds it every time.",
        "",
        f"Instructions per controller sample: {call_list} = **{cl['instructions_per_sample']:,}** "
        f"(with trace: {cl['instructions_per_sample_trace']:,}). Reached: {_g(cl['instr_per_s'])} "
        f"instructions/s compiled (trace: {_g(cl['instr_per_s_trace'])}), {_g(cl['vm_instr_per_s'])} in the VM.",
        "",
        f"`simulate_batch` of {b['n_runs']} gain sets:",
        "",
        "| n_threads | wall s (spread) | runs/s |",
        "|--:|--:|--:|",
        f"| 1 | {_g(_m(b['wall_s_1']))} ({_spread(b['wall_s_1'])}) | {_g(b['runs_per_s_1'])} |",
        f"| 2 | {_g(_m(b['wall_s_2']))} ({_spread(b['wall_s_2'])}) | {_g(b['runs_per_s_2'])} |",
        "",
        f"2 threads / 1 thread: **{b['ratio_2_over_1']:.2f}x**.",
        "",
        *(_targets_markdown(res["targets"]) if "targets" in res else []),
        "## 3. Compiling",
        "",
        f"Cold: a build into a fresh, empty `ARVCAS_CACHE` (generate C, hash, compile, load). Warm: the "
        f"same graph as a new Function object, found on disk (generate C, hash, verify, load). Memo: the "
        f"same object again in the same process. At {co['measured_at']}; graph = building the CasADi graph "
        f"(which a new process pays before any cache lookup).",
        "",
        "| function | instructions | C source KiB | graph s | cold build s (spread) | of which cc s | warm build s "
        "| memo µs | cold/warm |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for name, label in (("uvms_rhs", "uvms_rhs (graph: all 5 plant functions)"),
                        ("run", f"run_{cl['controller']}, metrics only (instructions: its distinct SX functions)")):
        r = co[name]
        L.append(f"| {label} | {r['n_instructions']:,} | {r['c_source_kib']:,.0f} | {_g(_m(r['graph_s']))} | {_g(_m(r['cold_build_s']))} "
                 f"({_spread(r['cold_build_s'])}) | {_g(_m(r['cold_cc_s']))} | {_g(_m(r['warm_build_s']))} | "
                 f"{_g(_m(r['memo_build_us']))} | {r['ratio_cold_over_warm']:.0f}x |")
    base = co["opt_sweep"]["baseline"]
    L += [
        "",
        f"Optimisation level of the run function (each level compiled cold {s['reps_slow']} times; run = one "
        f"{cl['duration_s']:g} s run, metrics only; ratios against {base}"
        f"{', the current default' if base == co['default_opt_level'] else ''}):",
        "",
        "| level | cc s (spread) | run s (spread) | real-time factor | run speed vs " + base + " | compile time vs " + base + " |",
        "|---|--:|--:|--:|--:|--:|",
    ]
    for r in co["opt_sweep"]["run"]:
        L.append(f"| {r['opt_level']} | {_g(_m(r['cc_s']))} ({_spread(r['cc_s'])}) | {_g(_m(r['run_s']))} "
                 f"({_spread(r['run_s'])}) | {_g(r['rtf'])} | {r['run_speedup_vs_base']:.2f}x | "
                 f"{r['cc_ratio_vs_base']:.2f}x |")
    L += [
        "",
        "The same for uvms_rhs (C driver):",
        "",
        f"| level | cc s (spread) | C ns/eval (spread) | speed vs {base} | compile time vs {base} |",
        "|---|--:|--:|--:|--:|",
    ]
    for r in co["opt_sweep"]["uvms_rhs"]:
        L.append(f"| {r['opt_level']} | {_g(_m(r['cc_s']))} ({_spread(r['cc_s'])}) | "
                 f"{_g(_m(r['c_ns_per_eval']))} ({_spread(r['c_ns_per_eval'])}) | {r['speedup_vs_base']:.2f}x | "
                 f"{r['cc_ratio_vs_base']:.2f}x |")
    st = res["startup"]
    L += ["", "## 4. Starting up", "",
          "| what | measured | target |", "|---|---|---|",
          f"| warm `arvcas simulate` in a fresh process (wall, median) | {_g(_m(st['warm_simulate_wall_s']))} s | <= 1.0 s |",
          f"| its peak resident memory | {_g(st['warm_simulate_peak_rss_mb'])} MB | <= 300 MB |",
          f"| cold graph build of the 100 s run, metrics only / with trace | {_g(st['cold_graph_metrics_s'])} s / "
          f"{_g(st['cold_graph_trace_s'])} s | <= 1.5 s |",
          f"| its peak resident memory | {_g(st['cold_graph_peak_rss_mb'])} MB | <= 500 MB |",
          "", st["note"] + "."]
    sy = res.get("systems")
    if sy:
        L += ["", "## 5. Systems", "",
              f"Each shipped system's run at its own default scenario and gains, controller {CONTROLLER}, metrics "
              f"only; the systems timed in interleaved rounds in this run (median). A system with thruster "
              f"dynamics is also timed without them (`+instantaneous`, the same scenario and step, plain "
              f"RK4) and by plain RK4, the thrust at the stage times (`{PLAIN_RK4_KEY}`: h_plant = "
              f"{PLAIN_RK4['time_h_plant']:g} s, the BlueROV2's shipped step until 2026-12-05, which misses the "
              f"accuracy rule that its shipped thrust quadrature at 0.01 s meets: docs/model.md §9, "
              f"results/bluerov2_step §3); instructions count the step's SX functions, not the "
              f"table lookups in MX between them.", "",
              "| system | thrusters | joints | duration s | samples x plant steps | run s (spread) | real-time factor | "
              "instructions / sample | instructions / s |", "|---|---|---|---|---|---|---|---|---|"]
        for name, r in sy.items():
            L.append(f"| {name} | {r['n_thrusters']} | {r['n_joints']} | {r['duration_s']:g} | {r['n_samples']} x "
                     f"{r['substeps']} | {_g(_m(r['run_metrics_s']))} ({_spread(r['run_metrics_s'])}) | "
                     f"{r['rtf_metrics']:,.0f}x | {r['instructions_per_sample']:,} | {_g(r['instr_per_s'])} |")
    L += _identification_markdown(res.get("identification"))
    L += _controller_markdown(res.get("controller"))
    L += _lanes_markdown(res.get("lanes"))
    L += cost_markdown(res.get("cost"))
    L += ["", "## Recommendation", "", rec["text"], ""]
    return "\n".join(L)


def _identification_markdown(r: dict | None) -> list[str]:
    if not r:
        return []
    v, i = r["validation"], r["identify"]
    return [
        "", "## 6. Validation and identification from logs", "",
        f"Validation of the shipped Hinsdale trial {v['trial']} ({v['duration_s']:.1f} s, {v['samples']} samples at "
        f"50 Hz): reading the log {_g(_m(v['read_s']))} s, the open-loop run and its metrics {_g(_m(v['validate_s']))} s, "
        f"**{_g(v['total_s'])} s** together (target 1 s: {_verdict(v['total_s'], 1.0, False)}). The simulation alone "
        f"{_g(_m(v['simulate_s']))} s compiled, {_g(_m(v['simulate_vm_s']))} s in CasADi's VM "
        f"({v['vm_over_compiled']:.0f}x).", "",
        f"Identification of {len(i['free'])} parameters of {i['system']} on {i['trials']} synthetic "
        f"trials of {i['duration_s']:g} s ({i['samples']} samples), 2 threads, compiled code "
        f"{'built in this run' if i['build_cold'] else 'from the cache'} ({_g(i['build_s'])} s, not counted): "
        f"**{_g(i['wall_s'])} s**, {i['iterations']} IPOPT iterations ({i['status']}); target 60 s: "
        f"{_verdict(i['wall_s'], 60.0, False)}. One evaluation of every trial with its sensitivities "
        f"{_g(_m(i['sens_eval_s']))} s ({i['sens_per_sample_us']:.0f} us a sample on each thread), without "
        f"{_g(_m(i['plain_eval_s']))} s. The estimates lie within {i['max_abs_z']:.1f} standard errors of the truth.",
    ]
