"""Section 7: the exported controller's time per step (``arvcas export-controller``): the budget on a
vehicle's computer.

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).

For each shipped system with a scenario and gains of its own and each of the proposed law, AGSTA and PID
(``--quick``: Haidou-1's proposed law only), the controller is exported, its library built by its own
Makefile (the flags of arvcas's build cache, no ``-mavx``: a vehicle's computer may lack it), and a small
C driver generated here links it and calls ``<prefix>step`` over one run's measurements (the scenario's
initial state plus its sensor noise, seed 0: the step's work does not depend on the values, CasADi
evaluates both sides of every branch), resetting the controller after each pass, so the first-sample
branch is in the mix once per run as on a vehicle. For a system with thruster command maps (the
BlueROV2's T200s) a step also computes each thruster's command (the map's inverse: an interval lookup and
Newton's method per thruster). Reported: ns per step (median, min, max over the repetitions), the CasADi
instructions of a step k >= 1 without the command map (the machine-independent size of the work), whether
the step has a command map, the state's size in bytes and ``init``'s time.
"""

from __future__ import annotations

import statistics
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from arvcas.bench.common import Settings, _stat

LAWS = ("proposed", "agsta", "pid")

_DRIVER_C = r"""
/* arvcas bench: time <prefix>step of an exported controller over a measurement file. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "@LIB@.h"

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

/* usage: driver DATA N_STEPS REPS; DATA: int64 K, then K x 12 doubles (the measurements of one run) */
int main(int argc, char** argv) {
  @PRE@params prm;
  static @PRE@state s;
  double u[@UP@N_U], checksum = 0.0;
  long long K, n, reps, r, i;
  FILE* fp;
  double* y;
  double t0, t1;
  if (argc != 4) return 2;
  n = atoll(argv[2]);
  reps = atoll(argv[3]);
  fp = fopen(argv[1], "rb");
  if (!fp || fread(&K, 8, 1, fp) != 1) return 3;
  y = malloc(K * 12 * sizeof *y);
  if (fread(y, sizeof *y, K * 12, fp) != (size_t)(K * 12)) return 3;
  fclose(fp);
  @PRE@default_params(&prm);
  t0 = now();
  for (i = 0; i < 1000; ++i)
    if (@PRE@init(&s, &prm)) return 4;
  t1 = now();
  printf("init_ns %.3f\n", 1e9 * (t1 - t0) / 1000);
  printf("state_bytes %lu\n", @PRE@state_size());
  for (r = -1; r < reps; ++r) {  /* r = -1: warm-up */
    @PRE@reset(&s);
    t0 = now();
    for (i = 0; i < n; ++i) {
      long long k = i % K;
      if (k == 0) @PRE@reset(&s);
      if (@PRE@step(&s, y + 12 * k, k * @UP@SAMPLE_TIME, NULL, u)) return 5;
      checksum += u[0];
    }
    t1 = now();
    if (r >= 0) printf("ns_per_step %.3f\n", 1e9 * (t1 - t0) / n);
  }
  printf("checksum %.17g\n", checksum);
  return 0;
}
"""


def _bench_controller(s: Settings, log) -> dict:
    """``{system: {law: {"ns_per_step": stat, "instructions_per_step", "init_ns", "state_bytes", ...}}}``."""
    from arvcas.build import codegen
    from arvcas.export.controller import default_prefix, export_controller
    from arvcas.sim import closedloop, profiles, scenario, thrust_forcing
    from arvcas.system import SHIPPED, load_system

    quick = s.mode == "quick"
    reps, steps = s.reps, (2_000 if quick else 200_000)
    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="arvcas-bench-ctl-") as tmp:
        for system in SHIPPED[:1] if quick else SHIPPED:
            sysm = load_system(system)
            if sysm.params.default("scenario") is None or sysm.params.default("gains") is None:
                continue  # a system for validation only (hinsdale_bluerov2_alpha5)
            cfg = scenario.load_scenario(sysm.params.default("scenario"))
            y = (np.array(list(cfg.initial_eta0) + list(cfg.initial_nu0))[:, None] + profiles.noise_sequence(cfg, 0)).T
            out[system] = {}
            for law in LAWS[:1] if quick else LAWS:
                d = Path(tmp) / f"{system}_{law}"
                log(f"controller: {system} / {law} ...")
                export_controller(d, law, system=sysm, scenario=cfg)
                prefix = default_prefix(system, law)
                lib = prefix.rstrip("_")
                subprocess.run(["make", "-s", "-C", str(d), f"lib{lib}.so"], check=True, capture_output=True)
                src = (_DRIVER_C.replace("@LIB@", lib).replace("@PRE@", prefix).replace("@UP@", prefix.upper()))
                (d / "driver.c").write_text(src, encoding="utf-8")
                flags = [codegen.DEFAULT_OPT_LEVEL, *codegen.FIXED_FLAGS]
                subprocess.run([codegen.CC, *flags, "-I", str(d), "-o", str(d / "driver"), str(d / "driver.c"),
                                f"-L{d}", f"-l{lib}", f"-Wl,-rpath,{d}", *codegen.LIBS], check=True,
                               capture_output=True)
                data = d / "y.bin"
                data.write_bytes(np.array([y.shape[0]], dtype="<i8").tobytes() + np.ascontiguousarray(y, "<f8").tobytes())
                r = subprocess.run([str(d / "driver"), str(data), str(steps), str(reps)], capture_output=True,
                                   text=True, check=True, timeout=600)
                ns = [float(ln.split()[1]) for ln in r.stdout.splitlines() if ln.startswith("ns_per_step ")]
                val = {ln.split()[0]: float(ln.split()[1]) for ln in r.stdout.splitlines()
                       if ln.startswith(("init_ns ", "state_bytes "))}
                fn = closedloop.controller_functions(law, cfg, sysm.layout)["step"]
                out[system][law] = {"ns_per_step": _stat(ns), "init_ns": val["init_ns"],
                                    "instructions_per_step": int(fn.n_instructions()),
                                    "state_bytes": int(val["state_bytes"]), "n_steps": steps, "run_samples": y.shape[0],
                                    "command_map": bool(thrust_forcing.command_functions(cfg, sysm.layout))}
                log(f"controller: {system} / {law}: {statistics.median(ns):.0f} ns per step "
                    f"(min {min(ns):.0f}), state {int(val['state_bytes'])} bytes")
    return out


def _controller_markdown(res: dict | None) -> list[str]:
    """The bench.md lines of the section (none for a bench.json written before it existed)."""
    if not res:
        return []
    L = ["", "## 7. The exported controller: time per step", "",
         "`arvcas export-controller` with each system's defaults, built by the export's Makefile (arvcas's flags, "
         "without `-mavx`), timed by a C driver over one run's measurements (the initial state plus the scenario's "
         "sensor noise; reset after each run: the first-sample branch included). One step = EKF, reference, law, "
         "allocation and saturation, and with thruster command maps each thruster's command (the map's inverse): "
         "the budget on a vehicle's computer.", "",
         "| system | law | ns per step (median) | min | max | CasADi instructions per step (without the command map) "
         "| command map | state bytes | init ns |",
         "|---|---|---|---|---|---|---|---|---|"]
    for system, laws in res.items():
        for law, r in laws.items():
            st = r["ns_per_step"]
            L.append(f"| {system} | {law} | {st['median']:.0f} | {st['min']:.0f} | {st['max']:.0f} | "
                     f"{r['instructions_per_step']:,} | {'yes' if r.get('command_map') else 'no'} | {r['state_bytes']} | "
                     f"{r['init_ns']:.0f} |")
    return L
