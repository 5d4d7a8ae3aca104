"""Section 4: a fresh process's warm `arvcas simulate` and the cold graph build.

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

from arvcas.bench.common import BenchError, CONTROLLER, Settings, _stat

_HWM = "int(open('/proc/self/status').read().split('VmHWM:')[1].split()[0]) / 1024"  # MB, this process only

_GRAPH_CHILD = """
import json, time
from arvcas.sim import closedloop, scenario
spec = closedloop.RunSpec({controller!r}, scenario.load_scenario().graph_key())
t0 = time.perf_counter(); closedloop.build_run(spec, trace=False); t1 = time.perf_counter()
closedloop.build_run(spec, trace=True); t2 = time.perf_counter()
print(json.dumps({{"metrics_s": t1 - t0, "trace_s": t2 - t1, "peak_rss_mb": {hwm}}}))
"""

_SIMULATE_CHILD = (f"import sys; from arvcas.cli import main; rc = main(sys.argv[1:]); "
                   f"print('peak_rss_mb', {_HWM}, file=sys.stderr); sys.exit(rc)")


def _child(cmd: list[str]) -> tuple[float, str, str]:
    """(wall s, stdout, stderr) of a fresh process. Its peak memory is read inside it (VmHWM): the
    kernel's ru_maxrss of a child starts from the forking parent's size (this benchmark's, ~1 GB)."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = p.communicate(timeout=600)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise BenchError(f"{' '.join(cmd[:3])}...: exit {p.returncode}: {err.strip().splitlines()[-1] if err.strip() else ''}")
    return wall, out, err


def _bench_startup(s: Settings, log) -> dict:
    """A fresh process: warm ``arvcas simulate`` (the libraries in the cache: no graph is built) and
    the cold graph build of the 100 s run (what a cache miss pays before compiling)."""
    log("startup: warm `arvcas simulate` in fresh processes ...")
    exe = [sys.executable, "-c", _SIMULATE_CHILD, "simulate", "--controller", CONTROLLER]
    _child(exe)  # make sure the cache is warm
    walls, rss = [], []
    for _ in range(s.reps):
        w, _, err = _child(exe)
        walls.append(w)
        rss.append(float(err.strip().splitlines()[-1].split()[-1]))
    log("startup: cold graph build of the run in a fresh process ...")
    g = json.loads(_child([sys.executable, "-c", _GRAPH_CHILD.format(controller=CONTROLLER, hwm=_HWM)])[1]
                   .strip().splitlines()[-1])
    return {"warm_simulate_wall_s": _stat(walls), "warm_simulate_peak_rss_mb": max(rss),
            "cold_graph_metrics_s": g["metrics_s"], "cold_graph_trace_s": g["trace_s"],
            "cold_graph_peak_rss_mb": g["peak_rss_mb"],
            "note": "warm: `arvcas simulate --controller proposed` (import, cache lookup, time table, "
                    "one 100 s run with trace); peak RSS (VmHWM) of that process, largest over the repetitions; cold "
                    "graph: build_run in a fresh process (metrics-only then trace), its peak RSS"}
