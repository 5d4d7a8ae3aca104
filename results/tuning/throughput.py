"""Throughput of the tuning evaluation: runs of the 100 s experiment per second on 1 and 2 cores.

    python results/tuning/throughput.py        # writes results/tuning/throughput.json and prints a table

One generation = one ``simulate_batch`` call on a population of 64 gain sets (Table 2 scaled by
log-uniform factors in [1/1.5, 1.5], all of which complete the run; a diverged run is frozen, not
shortened, so it costs about the same). The machine is shared, so each configuration is timed
``REPS`` times, 1 and 2 threads interleaved, after a warm-up; the table reports the best (least
disturbed) repetition, the median, and the process's CPU time / wall time of the best one (2.0 means
the two threads had both cores to themselves). The 1-minute load average is recorded before and
during the measurement.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from arvcas.controllers.gains import default_gains
from arvcas.sim.simulation import simulate_batch

N = 64
REPS = 10
BUDGET = 40_000
HERE = Path(__file__).resolve().parent


def wait_quiet(limit=0.5, max_wait=1500.0):
    t0 = time.time()
    while os.getloadavg()[0] > limit and time.time() - t0 < max_wait:
        time.sleep(5)
    return os.getloadavg()[0], time.time() - t0


def main():
    load0, waited = wait_quiet()
    rows, loads = {}, []
    for c in ("agsta", "proposed"):
        g0 = default_gains(c)
        G = g0 * np.exp(np.random.default_rng(0).uniform(-np.log(1.5), np.log(1.5), (N, g0.size)))
        for nt in (1, 2):
            simulate_batch(c, G, seed=0, n_threads=nt)  # build/load, map, warm-up
        rec = {1: [], 2: []}
        for _ in range(REPS):
            for nt in (1, 2):
                loads.append(os.getloadavg()[0])
                c0, t = os.times(), time.perf_counter()
                _ch, _rm, ok, _tf = simulate_batch(c, G, seed=0, n_threads=nt, return_status=True)
                wall, c1 = time.perf_counter() - t, os.times()
                rec[nt].append((wall, (c1.user - c0.user) + (c1.system - c0.system)))
        rows[c] = {}
        for nt, v in rec.items():
            best = min(v)
            rows[c][nt] = {"best_s": best[0], "median_s": statistics.median(w for w, _ in v),
                           "cpu_over_wall_best": best[1] / best[0], "cpu_s_per_run": min(cpu for _, cpu in v) / N}
        rows[c]["completed"] = int(ok.sum())
    out = {"population": N, "reps": REPS, "machine": platform.machine(), "cores": len(os.sched_getaffinity(0)),
           "load_before": load0, "waited_s": waited, "load_during": [min(loads), max(loads)], "results": rows}
    (HERE / "throughput.json").write_text(json.dumps(out, indent=1) + "\n")
    print("| controller | threads | s per generation of 64, best / median | CPU/wall (best) | runs/s (best) "
          "| speed-up 1 -> 2 | 40,000 runs at this rate |")
    print("|---|---|---|---|---|---|---|")
    for c, r in rows.items():
        r1 = N / r[1]["best_s"]
        for nt in (1, 2):
            rate = N / r[nt]["best_s"]
            print(f"| {c} | {nt} | {r[nt]['best_s']:.2f} / {r[nt]['median_s']:.2f} | {r[nt]['cpu_over_wall_best']:.2f} "
                  f"| {rate:.1f} | {rate / r1:.2f}x | {BUDGET / rate / 60:.1f} min |")
    print(f"load average before {load0:.2f} (waited {waited:.0f} s), during {min(loads):.2f}..{max(loads):.2f}")


if __name__ == "__main__":
    main()
