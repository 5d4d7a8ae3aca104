"""What a depth sensor's latency costs a small ROV holding station: measured, not assumed (docs/sensors.md).

    python benchmarks/sensor_latency.py [--quick]     # writes results/sensors/latency.json and README.md

The BlueROV2 Heavy + Alpha 5 on its shipped scenario (arvcas/data/bluerov2_heavy_alpha5.scenario.toml: 60 s, the
arm's reach and grasp, the current, the tether, the T200 dynamics) with only an IMU (read at every 0.1 s
controller sample) and a depth sensor (every sample), the depth reading late by 0, 0.1, 0.2 and 0.5 s; each
controller at its default gains (the system's gains file), the same five noise seeds at every latency. The EKF
fuses each reading as it arrives (docs/sensors.md "The estimator"). Per latency: the RMSE of each held DOF
(z, phi, theta, psi) and the mean CHAT over the six DOFs, averaged over the seeds, and the RMS of the depth
estimate's error (eta_hat - eta, over the run) that fusing the late reading as current leaves.

``--quick``: 10 s runs, two seeds (a check that the script works, not for the record).
"""

from __future__ import annotations

import argparse
import json
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np

import arvcas
from arvcas.sim import scenario
from arvcas.system import load_system

SYSTEM = "bluerov2_heavy_alpha5"
LATENCIES = (0.0, 0.1, 0.2, 0.5)  # s, the depth sensor's
SENSORS = {"sensors_imu_period": 0.1, "sensors_depth_period": 0.1}
SEEDS = (0, 1, 2, 3, 4)
HELD = ("z", "phi", "theta", "psi")
OUT = Path(__file__).resolve().parents[1] / "results" / "sensors"


def measure(controllers, quick: bool) -> dict:
    s = load_system(SYSTEM)
    base = scenario.load_scenario(s.params.default("scenario"))
    base = replace(base, **SENSORS, **({"time_duration": 10.0} if quick else {}))
    seeds = SEEDS[:2] if quick else SEEDS
    rows = []
    for ctrl in controllers:
        for lat in LATENCIES:
            cfg = scenario.loads_scenario(replace(base, sensors_depth_latency=lat).to_toml(), f"depth latency {lat:g} s")
            run = arvcas.Run(ctrl, scenario=cfg, system=s.params).compile()
            per_seed = []
            for seed in seeds:
                r = run.simulate(seed=seed)
                per_seed.append({"seed": seed, "ok": bool(r.ok), "t_fail": None if r.ok else float(r.t_fail),
                                 "rmse": dict(zip(HELD, r.rmse[2:6].tolist())), "chat_mean": float(np.mean(r.chat)),
                                 "z_estimate_error_rms": float(np.sqrt(np.mean((r.eta_hat[:, 2] - r.eta[:, 2]) ** 2)))})
            held = [p for p in per_seed if p["ok"]]  # a run that diverged is frozen: its metrics are not comparable
            mean = (lambda f: float(np.mean([f(p) for p in held])) if held else None)  # noqa: E731
            rows.append({"controller": ctrl, "depth_latency_s": lat, "samples": int(round(lat / cfg.time_h)),
                         "held": len(held), "rmse": {d: mean(lambda p: p["rmse"][d]) for d in HELD},
                         "chat_mean": mean(lambda p: p["chat_mean"]),
                         "z_estimate_error_rms": mean(lambda p: p["z_estimate_error_rms"]), "seeds": per_seed})
            print(json.dumps({k: v for k, v in rows[-1].items() if k != "seeds"}), flush=True)
    root = Path(__file__).resolve().parents[1]
    git = lambda *a: subprocess.run(["git", *a], cwd=root, capture_output=True, text=True).stdout.strip()  # noqa: E731
    dirty = git("status", "--porcelain", "--", ".", ":!results/sensors")
    return {"git_commit": git("rev-parse", "HEAD") + ("+dirty" if dirty else ""), "system": SYSTEM, "scenario": "the shipped scenario, sensors IMU and depth every 0.1 s"
            + (" (quick: 10 s)" if quick else ""), "seeds": list(seeds), "latencies_s": list(LATENCIES),
            "estimator": "EKF fusing each reading as it arrives (docs/sensors.md)", "runs": rows}


def render(res: dict) -> str:
    lines = ["# What a depth sensor's latency costs (docs/sensors.md)", "",
             f"Written by `benchmarks/sensor_latency.py` (at commit {res['git_commit'][:10]}) into `latency.json` and "
             f"this page: {res['system']}, {res['scenario']}; "
             f"each controller at its default gains, the mean over seeds {res['seeds']}; the {res['estimator']}.",
             "", "| controller | depth latency | RMSE z (m) | RMSE phi (rad) | RMSE theta (rad) | RMSE psi (rad) "
             "| mean CHAT | depth estimate error RMS (m) |", "|---|---|---|---|---|---|---|---|"]
    n = len(res["seeds"])
    for r in res["runs"]:
        m = r["rmse"]
        k = r["samples"]
        lat = f"{r['depth_latency_s']:g} s ({k} sample{'' if k == 1 else 's'})"
        if not r["held"]:
            lines.append(f"| {r['controller']} | {lat} | every run diverged | | | | | |")
            continue
        note = "" if r["held"] == n else f" ({r['held']} of {n} runs held; the others diverged)"
        lines.append(f"| {r['controller']} | {lat}{note} | {m['z']:.4g} | {m['phi']:.4g} | {m['theta']:.4g} | "
                     f"{m['psi']:.4g} | {r['chat_mean']:.4g} | {r['z_estimate_error_rms']:.4g} |")
    fails = [(r["controller"], r["depth_latency_s"], p["seed"], p["t_fail"]) for r in res["runs"] for p in r["seeds"]
             if not p["ok"]]
    if fails:
        lines += ["", "Runs that diverged (a held DOF's error past the scenario's `[limits]`; left out of the means): "
                  + "; ".join(f"{c} at {lat:g} s, seed {s}, at t = {t:g} s" for c, lat, s, t in fails) + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--controllers", nargs="+", default=["pid", "ardusub"])
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    res = measure(a.controllers, a.quick)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "latency.json").write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    (a.out / "README.md").write_text(render(res), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
