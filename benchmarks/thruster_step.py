"""The plant step with thruster dynamics: the step-accuracy rule (results/step) on the BlueROV2 with its T200s.

    python benchmarks/thruster_step.py     # writes results/step/bluerov2_heavy_alpha5/thrusters.md and .json
    python benchmarks/thruster_step.py --quadrature   # adds time.thrust_quadrature = 5 at h_plant = 0.01 s

For the default gains of the proposed controller and AGSTA (PID's diverge) and the knee of each front of
results/bluerov2/t200 (its study's draw), at plant steps 0.005, 0.0025 and 0.00125 s: (a) the closed loop's
state over the whole 60 s run against CVODES (1e-14) integrating the plant with the rotor states as ODE
states (benchmarks/step_accuracy.py's reference: the textbook lag through the map, the current and the
tether), driven by that run's own allocation; (b) CHAT (commanded and delivered) and RMSE against the
0.00125 s run, relative. The rule (results/step): (a) <= 1e-6 m, rad and (b) <= 1e-5. One CVODES run takes
about a minute here; the targeted set replaces step_accuracy.py's full sweep, whose CVODES runs of every
front member would take hours with the thrust tables in the reference's right-hand side.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STEPS = (0.005, 0.0025, 0.00125)
OUT = ROOT / "results" / "step" / "bluerov2_heavy_alpha5"


QUAD = (0.01, 5)  # time.h_plant, time.thrust_quadrature of the quadrature variant (--quadrature)


def main(quadrature: bool = False, res: dict | None = None) -> dict:
    import arvcas
    from arvcas.io.results import read_result
    from arvcas.sim import scenario

    spec = importlib.util.spec_from_file_location("step_accuracy", ROOT / "benchmarks" / "step_accuracy.py")
    sa = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sa)
    blue = arvcas.load_system("bluerov2_heavy_alpha5")
    # the shipped scenario with plain RK4 for the steps of the first table (the shipped step itself, 0.01 s with
    # the thrust quadrature since 2026-12-05, is the --quadrature variant)
    cfg0 = dataclasses.replace(scenario.load_scenario(blue.params.default("scenario")), time_thrust_quadrature=None)
    pv = blue.params.vector()
    cases = [("proposed default", "proposed", None, None), ("agsta default", "agsta", None, None)]
    for c in ("proposed", "agsta", "pid"):
        k = read_result(ROOT / f"results/bluerov2/t200/knees/knee_{c}.h5")
        cases.append((f"{c} knee", c, k.gains, (k.seed, k.uncertainty, k.phase)))
    out = res or {"steps": list(STEPS), "cases": {}, "machine_load": open("/proc/loadavg").read().split()[:3]}
    def against_cvodes(c, cfg, g, draw):
        """(state error against CVODES over the run, with CVODES' time; the metrics) of law c at scenario cfg."""
        seed, unc, ph = draw if draw is not None else (0, None, None)
        t0 = time.time()
        r = arvcas.Run(c, scenario=cfg, system=blue).compile().simulate(gains=g, seed=seed, uncertainty=unc, phase=ph)
        X = np.hstack([r.eta, r.nu])
        ref = sa.cvodes_states(cfg, pv, X[0], sa.plant_inputs(pv, r, blue.layout), r.phase, tol=1e-14,
                               layout=blue.layout)
        d = np.abs(X - ref)
        return ({"position_m": float(d[:, 0:3].max()), "angle_rad": float(d[:, 3:6].max()), "cvodes_s": time.time() - t0},
                np.r_[r.chat, r.chat_delivered, r.rmse])

    def metrics_only(c, cfg, g, draw):
        seed, unc, ph = draw if draw is not None else (0, None, None)
        r = arvcas.Run(c, scenario=cfg, system=blue).compile().simulate(gains=g, seed=seed, uncertainty=unc, phase=ph)
        return np.r_[r.chat, r.chat_delivered, r.rmse]

    for label, c, g, draw in cases:
        if quadrature:  # the quadrature variant added to a finished run's figures (docs/model.md §9)
            hp, ng = QUAD
            rec, m = against_cvodes(c, dataclasses.replace(cfg0, time_h_plant=hp, time_thrust_quadrature=ng), g, draw)
            base = metrics_only(c, dataclasses.replace(cfg0, time_h_plant=STEPS[-1]), g, draw)
            rec = {"h_plant": hp, "nodes": ng, **rec, "metrics_rel_vs_finest": float(np.max(np.abs(m - base) / np.abs(base)))}
            out["cases"][label]["quadrature"] = rec
            print(label, "quadrature", rec, flush=True)
            continue
        rec, metrics = {}, {}
        for hp in STEPS:
            rec[repr(hp)], metrics[hp] = against_cvodes(c, dataclasses.replace(cfg0, time_h_plant=hp), g, draw)
            print(label, hp, rec[repr(hp)], flush=True)
        base = metrics[STEPS[-1]]
        for hp in STEPS[:-1]:
            rec[repr(hp)]["metrics_rel_vs_finest"] = float(np.max(np.abs(metrics[hp] - base) / np.abs(base)))
        out["cases"][label] = rec
    return out


def markdown(res: dict) -> str:
    L = ["# The plant step with the T200 dynamics", "",
         "Written by `python benchmarks/thruster_step.py` (see its docstring). The BlueROV2 Heavy + Alpha 5 with its "
         "T200 dynamics, the current and the tether (the shipped scenario), 60 s runs, the plant integrated by plain "
         "RK4 at the steps of the first table (the shipped step, 0.01 s with the thrust quadrature, is the second "
         "table). State: the largest "
         "difference from CVODES over the whole run (m for positions, rad for angles); metrics: the largest "
         "relative difference of the 18 CHAT (commanded, delivered) and RMSE values from the 0.00125 s run. "
         f"Machine load (1, 5, 15 min) at the end: {', '.join(res['machine_load'])}.", "",
         "| run | " + " | ".join(f"{s:g} s: position m / angle rad / metrics" for s in res["steps"]) + " |",
         "|---|" + "---|" * len(res["steps"])]
    for label, rec in res["cases"].items():
        cells = []
        for s in res["steps"]:
            r = rec[repr(s)]
            m = r.get("metrics_rel_vs_finest")
            cells.append(f"{r['position_m']:.2e} / {r['angle_rad']:.2e} / " + (f"{m:.1e}" if m is not None else "(base)"))
        L.append(f"| {label} | " + " | ".join(cells) + " |")
    if any("quadrature" in rec for rec in res["cases"].values()):
        q = next(rec["quadrature"] for rec in res["cases"].values() if "quadrature" in rec)
        L += ["", f"With `time.thrust_quadrature = {q['nodes']}` at `time.h_plant = {q['h_plant']:g}` s (the thrusters' "
              "forcing by Gauss-Legendre quadrature, docs/model.md §9; the shipped step since 2026-12-05; "
              "`python benchmarks/thruster_step.py --quadrature` adds it to the figures above):", "",
              "| run | position m / angle rad / metrics against the 0.00125 s run | within the rule |", "|---|---|---|"]
        for label, rec in res["cases"].items():
            if "quadrature" in rec:
                r = rec["quadrature"]
                ok = max(r["position_m"], r["angle_rad"]) <= 1e-6 and r["metrics_rel_vs_finest"] <= 1e-5
                L.append(f"| {label} | {r['position_m']:.2e} / {r['angle_rad']:.2e} / {r['metrics_rel_vs_finest']:.1e} | "
                         f"{'yes' if ok else 'no'} |")
    return "\n".join(L) + "\n"


if __name__ == "__main__":
    import sys

    if "--quadrature" in sys.argv[1:]:
        res = main(True, json.loads((OUT / "thrusters.json").read_text()))
    else:
        res = main()
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "thrusters.json").write_text(json.dumps(res, indent=1))
    (OUT / "thrusters.md").write_text(markdown(res))
    print(markdown(res))
