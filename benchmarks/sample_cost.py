"""Where a controller sample's machine instructions go: counted by Callgrind, not timed.

    python benchmarks/sample_cost.py [--runs 2]   # writes results/bluerov2_step/sample_cost.{json,md}

For each system (Haidou-1 and the BlueROV2 Heavy + Alpha 5 with its T200 dynamics at their shipped scenario and
default gains, controller ``proposed``; the BlueROV2 also with instantaneous thrusters at the same step), the
compiled metrics-only run (the shipped build, from the compile cache) is called ``--runs`` times in a child
process under ``valgrind --tool=callgrind``, collecting only inside the run function (``--toggle-collect``).
The machine instructions (Ir) of each generated C function are mapped to the CasADi function it is
(CasADi's C names each one in a comment: ``cl_rk4`` the plant's RK4 substep, ``cl_thr_wrench`` the thrusters'
wrench or forcing moments, ``cl_thr_lag`` the lag and the inverse map, ``cl_ctrl_proposed`` the controller
with the EKF and the allocation, ``cl_step_proposed`` the sample's MX glue: the table intervals, the maps'
cubics element by element, copies) and divided by the samples run. Inclusive counts: a function's own
instructions and those of what it calls (libm's sin/cos/tan).

Instruction counts do not depend on the machine's load (the machine this runs on is shared); they are not
times: a sample's time also depends on memory traffic and on what the instructions are.

The plant substep's CasADi instructions are split by what its terms cost: the same ``cl_rk4`` is built with one
group of terms replaced by zero (the arm links' drag quadrature; the arm's whole wrench; the vehicle's
damping, Coriolis and restoring forces); the differences are each group's share. These graphs are only counted,
never run.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results" / "bluerov2_step"
CONTROLLER = "proposed"
TARGET_RATIO = 0.53  # the one-at-a-time target: 10,000x against Haidou-1's 18,963x
# (key, system, variant): the shipped runs compared
RUNS = (("haidou1", "haidou1", None), ("bluerov2_heavy_alpha5", "bluerov2_heavy_alpha5", None),
        ("bluerov2_heavy_alpha5+instantaneous", "bluerov2_heavy_alpha5", "instantaneous"))


def _prepared(system: str, variant: str | None):
    """(run, the compiled metrics-only function, its arguments) of a system's shipped run."""
    from arvcas.bench.closed_loop import _run_args
    from arvcas.sim import profiles, scenario
    from arvcas.sim.run import Run
    from arvcas.system import System, load_system

    sysm = load_system(system)
    cfg = scenario.load_scenario(sysm.params.default("scenario"))
    if variant == "instantaneous":  # the same step, the thrusters' wrench instantaneous (plain RK4)
        sysm, cfg = System(sysm.params.instantaneous()), dataclasses.replace(cfg, time_thrust_quadrature=None)
    run = Run(CONTROLLER, scenario=cfg, system=sysm).compile()
    f = run.function(trace=False)
    args = _run_args(f, run.default_gains(), profiles.noise_sequence(run.cfg, 0), run.cfg, sysm.params.vector(),
                     layout=sysm.layout)
    return run, f, args


def _driver(system: str, variant: str | None, runs: int) -> None:
    """The child under Callgrind: the run ``runs`` times (its compile and inputs outside the collection)."""
    from arvcas.build import calls
    _, f, args = _prepared(system, None if variant == "-" else variant)
    for _ in range(runs):
        calls.call(f, *args)


def c_names(run) -> dict[str, str]:
    """``{generated C function (e.g. f9): CasADi function name}`` of the run's metrics-only function."""
    from arvcas.build import codegen
    name, _, make = run._described(False)
    c = codegen._c_text(make())
    return {m.group(2): m.group(1)
            for m in re.finditer(r"/\* ([A-Za-z0-9_]+):\([^\n]*\*/\n(?:static )?int casadi_(f[0-9]+)\(", c)}


_LINE = re.compile(r"^\s*([\d,]+) \([^)]*\)\s+(?:\*\s+)?[^:\s]*:(\S+?)(?:\.constprop\S*|\.isra\S*)?(?:\s+\[.*)?$")


def parse_annotate(txt: str, inclusive: bool) -> dict[str, int]:
    """``{function: Ir}`` from ``callgrind_annotate``'s listing; a function's lines from several source files add up
    (exclusive counts), or its first line is taken (inclusive counts: the same total on every line)."""
    res: dict[str, int] = {}
    for line in txt.splitlines():
        m = _LINE.match(line)
        if m:
            v = int(m.group(1).replace(",", ""))
            res[m.group(2)] = res.get(m.group(2), v) if inclusive else res.get(m.group(2), 0) + v
    return res


def _annotate(out: Path, inclusive: bool) -> dict[str, int]:
    txt = subprocess.run(["callgrind_annotate", f"--inclusive={'yes' if inclusive else 'no'}", "--threshold=100",
                          str(out)], capture_output=True, text=True, check=True).stdout
    return parse_annotate(txt, inclusive)


def callgrind_sample(key: str, system: str, variant: str | None, runs: int, log=print) -> dict:
    """Machine instructions per controller sample of one shipped run, split by generated function."""
    from arvcas.bench.closed_loop import _step_instructions
    from arvcas.sim import closedloop, scenario

    run, f, _ = _prepared(system, variant)  # compiled (and cached) here, not under Callgrind
    n = scenario.n_samples(run.cfg)
    names = c_names(run)
    prefix = f.name()
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "callgrind.out"
        cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", f"--toggle-collect={prefix}*",
               sys.executable, str(Path(__file__).resolve()), "--driver", system, variant or "-", str(runs)]
        t0 = time.time()
        subprocess.run(cmd, check=True, capture_output=True, env=dict(os.environ))
        log(f"{key}: callgrind {time.time() - t0:.0f} s")
        incl, excl = _annotate(out, True), _annotate(out, False)
    per = runs * n
    total = incl.get(f"{prefix}_f0") or max(incl.values())
    fns = {}
    for sym, v in incl.items():
        m = re.fullmatch(re.escape(prefix) + r"_(f\d+)", sym)
        if m and m.group(1) in names:
            fns[names[m.group(1)]] = {"inclusive": v / per, "exclusive": excl.get(sym, 0) / per}
    libm = {s: v / per for s, v in excl.items() if re.match(r"__(sin|cos|sincos|tan|atan2?|exp|log|sqrt)", s)}
    spec = closedloop.RunSpec(CONTROLLER, run.cfg.graph_key(), run.opts, run.params.layout)
    ins = _step_instructions(spec, trace=False)
    return {"runs": runs, "n_samples": n, "substeps": run.cfg.substeps, "h_plant": run.cfg.time_h_plant,
            "thrust_quadrature": run.cfg.time_thrust_quadrature, "per_sample": total / per,
            "functions": fns, "libm_exclusive": libm,
            "casadi": {k: c for k, c in ins["calls"].items()}, "casadi_per_sample": ins["total"]}


def plant_split(system: str) -> dict:
    """CasADi instructions of one ``cl_rk4`` (the shipped scenario) and with one group of terms set to zero."""
    import casadi as ca
    from arvcas.model import manipulator, vehicle
    from arvcas.sim import closedloop

    run, _, _ = _prepared(system, None)
    spec = closedloop.RunSpec(CONTROLLER, run.cfg.graph_key(), run.opts, run.params.layout)
    zero = lambda *a, **k: ca.DM.zeros(6)  # noqa: E731

    def count(*patches):
        with contextlib.ExitStack() as st:
            for target in patches:
                st.enter_context(mock.patch(target, zero))
            return int(closedloop._plant_substep(spec)[0].n_instructions())

    full = count()
    no_drag = count("arvcas.model.manipulator.drag_wrench")
    no_arm = count("arvcas.model.manipulator.arm_wrench_scheduled")
    no_vehicle = count("arvcas.model.vehicle.forces")
    assert manipulator.drag_wrench is not zero and vehicle.forces is not zero
    return {"cl_rk4": full, "arm_drag_quadrature": full - no_drag, "arm_other": no_drag - no_arm,
            "vehicle_forces": full - no_vehicle, "rest": no_arm - (full - no_vehicle)}


def study(runs: int, log=print) -> dict:
    import platform
    res = {"created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "controller": CONTROLLER,
           "valgrind": subprocess.run(["valgrind", "--version"], capture_output=True, text=True).stdout.strip(),
           "machine": platform.machine(), "runs": {}}
    for key, system, variant in RUNS:
        log(f"{key} ...")
        res["runs"][key] = callgrind_sample(key, system, variant, runs, log)
    res["plant_split"] = plant_split("bluerov2_heavy_alpha5")
    return res


# -- candidates: accuracy before building ---------------------------------------------------------------------
# (substeps of a sample in s, Gauss-Legendre nodes per half substep): the shipped 10 x 0.01 s and graded substeps
GRADED = (((0.01,) * 10, 5), ((0.005, 0.01, 0.015, 0.02, 0.025, 0.025), 5),
          ((0.004, 0.008, 0.013, 0.02, 0.025, 0.03), 5), ((0.004, 0.006, 0.01, 0.015, 0.02, 0.02, 0.025), 5))


def graded_accuracy(log=print) -> dict:
    """benchmarks/bluerov2_step.py's :func:`transformed_states` (the shipped step's method, with any substeps)
    against CVODES (1e-14) over the open-loop replay of two traced runs of the BlueROV2 Heavy + Alpha 5: the default
    gains and the knee of its proposed front (results/bluerov2/t200), as that script's section 3 (which measured the
    default run only)."""
    import arvcas
    import numpy as np
    from arvcas.io.results import read_result
    from arvcas.sim import scenario
    from benchmarks import bluerov2_step as b2

    sa = b2._step_accuracy()
    blue = arvcas.load_system("bluerov2_heavy_alpha5")
    cfg = dataclasses.replace(scenario.load_scenario(blue.params.default("scenario")), time_h_plant=b2.BASE_H,
                              time_thrust_quadrature=None)
    lay, pv = blue.layout, np.asarray(blue.params.vector(), float)
    knee = read_result(ROOT / "results/bluerov2/t200/knees/knee_proposed.h5")
    out = {"rule": b2.RULE, "runs": {}}
    for label, g, draw in (("default", None, (0, None, None)), ("knee", knee.gains, (knee.seed, knee.uncertainty, knee.phase))):
        r = arvcas.Run(CONTROLLER, scenario=cfg, system=blue).compile().simulate(gains=g, seed=draw[0],
                                                                                 uncertainty=draw[1], phase=draw[2])
        X = np.hstack([r.eta, r.nu])
        n = scenario.n_samples(cfg) - 1
        targets = sa.plant_inputs(pv, r, lay)
        t0 = time.time()
        ref = b2._reference(sa, cfg, pv, X[0], targets, r.phase, lay, n, False)
        log(f"graded: {label}: CVODES {time.time() - t0:.0f} s")
        rows = []
        for subs, ng in GRADED:
            d = np.abs(b2.transformed_states(sa, cfg, pv, X[0], targets, r.phase, lay, subs, ng, n) - ref)
            rows.append({"substeps": list(subs), "nodes_per_half": ng, "position_m": float(d[:, 0:3].max()),
                         "angle_rad": float(d[:, 3:6].max()), "plant_evaluations_per_sample": 4 * len(subs)})
            log(f"graded: {label} {subs}: {rows[-1]['position_m']:.3g} m / {rows[-1]['angle_rad']:.3g} rad")
        out["runs"][label] = rows
    return out


def wrench_reassociated() -> dict:
    """Candidate: the forcing's moments as (B T) C instead of B (T C) (B the 6 x n thrust directions, T the thrust at
    the n_thr x nodes, C the moment weights, :func:`arvcas.sim.thrust_forcing.moment_weights`): CasADi instructions of
    ``cl_thr_wrench`` both ways, and the largest difference of the moments relative to their largest magnitude on
    random thrusts in the T200 table's range (the same sum in another order: round-off, but not the same bits)."""
    import casadi as ca
    import numpy as np
    from arvcas.model import thrusters
    from arvcas.sim import scenario, thrust_forcing as tf
    from arvcas.system import load_system
    from arvcas.system.params import view

    sysm = load_system("bluerov2_heavy_alpha5")
    lay = sysm.layout
    cfg = scenario.load_scenario(sysm.params.default("scenario"))
    shipped = tf.thruster_functions(cfg, lay)[1]
    n, m_off, N = lay.structure.n_thrusters, len(tf.lag_offsets(cfg)), tf.N_MOMENTS
    p = ca.SX.sym("p", len(lay))
    T = ca.SX.sym("T", n * m_off)
    Tn = ca.vertcat(*[ca.horzcat(*[T[i * m_off + j] for j in range(m_off - 1)]) for i in range(n)])
    BT, C = ca.mtimes(thrusters.B_T(view(p, lay)), Tn), tf.moment_weights(cfg)
    W = ca.vertcat(*[ca.vec(ca.mtimes(BT, ca.DM(C[:, N * i:N * (i + 1)]))) for i in range(cfg.substeps)])
    alt = ca.Function("cl_thr_wrench_bt", [T, p], [W])
    Tv = np.random.default_rng(2024).uniform(-40.0, 40.0, n * m_off)  # N: about the T200's range at 16 V
    a = np.array(shipped(Tv, Tv, sysm.params.vector())[0]).ravel()
    b = np.array(alt(Tv, sysm.params.vector())).ravel()
    return {"shipped": int(shipped.n_instructions()), "reassociated": int(alt.n_instructions()),
            "max_rel_difference": float(np.max(np.abs(a - b)) / np.max(np.abs(a)))}


# -- the page ----------------------------------------------------------------------------------------------------
PARTS = (("cl_rk4", "plant: RK4 substeps (vehicle + arm, the forcing's moments)"),
         ("cl_thr_wrench", "thrusters: thrust at the nodes -> wrench / forcing moments"),
         ("cl_thr_lag", "thrusters: inverse map's Newton steps, lag"),
         ("cl_ctrl_proposed", "controller, EKF, allocation"),
         ("cl_finalize", "bookkeeping: the new state"), ("cl_ok", "bookkeeping: divergence check"))
OWN = "the sample's own code: table intervals, maps' cubics, copies (`cl_step_proposed` less what it calls)"


def _own(r: dict) -> float:
    """The sample function's own instructions: its inclusive count less that of the functions it calls."""
    f = r["functions"]
    return f["cl_step_proposed"]["inclusive"] - sum(f[k]["inclusive"] for k, _ in PARTS if k in f)


def markdown(res: dict) -> str:
    runs = res["runs"]
    keys = [k for k, _, _ in RUNS if k in runs]
    L = ["# Where a sample's instructions go", "",
         f"Written by `python benchmarks/sample_cost.py` on {res['created']} (see its docstring for the method); every "
         "figure is in `sample_cost.json`. Machine instructions (Callgrind's Ir, "
         f"{res['valgrind']}) inside the compiled metrics-only run (controller {res['controller']}, default gains, the "
         f"shipped scenario), per controller sample (0.1 s), {runs[keys[0]]['runs']} runs of each; inclusive of what "
         "each function calls (libm). In brackets: the share of the sample, and the CasADi instructions (calls x "
         "instructions) results/bench.md counts.", "",
         "| part | " + " | ".join(keys) + " |", "|---|" + "--:|" * len(keys)]

    def cell(r, own, fn=None):
        c = r["casadi"].get(fn) if fn else None
        calls = f"; {c['calls']} x {c['n_instructions']:,}" if c else ""
        return f"{max(own, 0):,.0f} ({100 * max(own, 0) / r['per_sample']:.0f} %{calls})"

    for fn, what in PARTS:
        L.append(f"| {what} (`{fn}`) | " + " | ".join(
            cell(runs[k], runs[k]["functions"][fn]["inclusive"], fn) if fn in runs[k]["functions"] else "-"
            for k in keys) + " |")
    L.append(f"| {OWN} | " + " | ".join(cell(runs[k], _own(runs[k])) for k in keys) + " |")
    L.append("| **per sample** | " + " | ".join(f"**{runs[k]['per_sample']:,.0f}** ({runs[k]['casadi_per_sample']:,} "
                                                 "CasADi)" for k in keys) + " |")
    if all("libm_exclusive" in runs[k] for k in keys):
        L.append("| of which libm (sin, cos, tan) | " + " | ".join(
            f"{sum(runs[k]['libm_exclusive'].values()):,.0f}" for k in keys) + " |")
    L.append("| one RK4 substep (`cl_rk4`) x substeps per sample | " + " | ".join(
        f"{runs[k]['functions']['cl_rk4']['inclusive'] / runs[k]['substeps']:,.0f} x {runs[k]['substeps']}"
        for k in keys) + " |")
    ps = res["plant_split"]
    L += ["", f"One plant substep of the BlueROV2 Heavy + Alpha 5 (`cl_rk4`, {ps['cl_rk4']:,} CasADi instructions: 4 "
          "plant evaluations and the forcing's moments), by the terms it evaluates (each group set to zero, the "
          "difference counted):", "", "| terms | CasADi instructions | share |", "|---|--:|--:|"]
    for k, what in (("arm_drag_quadrature", "the arm links' drag (Gauss-Legendre, 5 points per link)"),
                    ("arm_other", "the arm's other terms (inertial from the time table, weight)"),
                    ("vehicle_forces", "the vehicle's damping, Coriolis, restoring forces"),
                    ("rest", "the rest: LU solves (stages and the forcing's 12 moments), J(eta), trim, current")):
        L.append(f"| {what} | {ps[k]:,} | {100 * ps[k] / ps['cl_rk4']:.0f} % |")
    h, b, bi = (runs[k] for k in keys)
    rk = {k: runs[k]["functions"]["cl_rk4"]["inclusive"] / runs[k]["substeps"] for k in keys}
    thr = sum(b["functions"][f]["inclusive"] for f in ("cl_thr_wrench", "cl_thr_lag"))
    budget = h["per_sample"] / TARGET_RATIO
    rest = b["per_sample"] - b["functions"]["cl_rk4"]["inclusive"]
    L += ["", "## Findings", "",
          f"- The BlueROV2 Heavy + Alpha 5 takes {b['per_sample']:,.0f} machine instructions per sample, "
          f"{b['per_sample'] / h['per_sample']:.1f} times Haidou-1's {h['per_sample']:,.0f}. Its {b['substeps']} plant "
          f"substeps are {100 * b['functions']['cl_rk4']['inclusive'] / b['per_sample']:.0f} % of it, the thrusters' "
          f"functions {100 * thr / b['per_sample']:.0f} %, the controller {100 * b['functions']['cl_ctrl_proposed']['inclusive'] / b['per_sample']:.0f} %. "
          f"Haidou-1 takes {h['substeps']} substeps.",
          f"- One substep costs about the same in both systems ({rk[keys[1]]:,.0f} against Haidou-1's "
          f"{rk[keys[0]]:,.0f} machine instructions; {rk[keys[2]]:,.0f} with instantaneous thrusters, whose substep "
          "has no forcing moments): what makes the BlueROV2 slower is the number of substeps, not their size. "
          f"Within a substep the arm links' drag quadrature is the largest group ({100 * ps['arm_drag_quadrature'] / ps['cl_rk4']:.0f} % of its CasADi instructions).",
          f"- The thruster dynamics add {b['per_sample'] - bi['per_sample']:,.0f} instructions per sample to the same run "
          f"with instantaneous thrusters ({bi['per_sample']:,.0f}): {thr:,.0f} in their functions, "
          f"{b['functions']['cl_rk4']['inclusive'] - bi['functions']['cl_rk4']['inclusive']:,.0f} in the substeps "
          "(the forcing's moments), the rest in the controller and the sample's own code.",
          f"- A ratio of {TARGET_RATIO} to Haidou-1's real-time factor one at a time (the target) at equal time per "
          f"instruction allows {budget:,.0f} instructions per BlueROV2 sample, {budget / b['per_sample']:.2f} of "
          f"today's. With everything but the substeps as today ({rest:,.0f}) that leaves "
          f"{max(budget - rest, 0) / rk[keys[1]]:.1f} substeps of today's cost, i.e. "
          f"{4 * max(budget - rest, 0) / rk[keys[1]]:.0f} plant evaluations per sample (today {4 * b['substeps']}; the "
          "fewest measured within the accuracy rule, results/bluerov2_step/README.md section 3: 24 with graded substeps)."]
    if "wrench" in res:
        w = res["wrench"]
        L += ["", "## Candidate: the forcing's moments reassociated", "",
              f"`cl_thr_wrench` as (B T) C instead of B (T C): {w['reassociated']:,} CasADi instructions against "
              f"{w['shipped']:,} ({w['shipped'] - w['reassociated']:,} fewer per sample, "
              f"{100 * (w['shipped'] - w['reassociated']) / b['casadi_per_sample']:.1f} % of the sample's CasADi "
              f"instructions); the moments differ by {w['max_rel_difference']:.2g} of their largest (round-off, not "
              "the same bits: the BlueROV2's committed fronts would need re-running). Not built."]
    if "graded" in res:
        L += graded_markdown(res["graded"])
    return "\n".join(L) + "\n"


def graded_markdown(gr: dict) -> list[str]:
    labels = list(gr["runs"])
    L = ["", "## Candidate: graded substeps, accuracy before building", "",
         "The shipped method (the thrusters' forcing by quadrature, RK4 on the rest: benchmarks/bluerov2_step.py's "
         "`transformed_states`) with graded substeps, off CVODES (1e-14) over the whole open-loop replay of each "
         "traced run (largest position m / angle rad; rule: both <= "
         f"{gr['rule']:g}). The generated step takes equal substeps only: graded ones are not built.", "",
         "| substeps of a sample (s) | nodes per half | plant evaluations | " + " | ".join(labels) + " |",
         "|---|--:|--:|" + "---|" * len(labels)]
    for i, row in enumerate(gr["runs"][labels[0]]):
        cells = []
        for lab in labels:
            r = gr["runs"][lab][i]
            ok = r["position_m"] <= gr["rule"] and r["angle_rad"] <= gr["rule"]
            cells.append(f"{r['position_m']:.3g} / {r['angle_rad']:.3g} ({'within' if ok else 'not within'})")
        L.append(f"| {', '.join(f'{h:g}' for h in row['substeps'])} | {row['nodes_per_half']} | "
                 f"{row['plant_evaluations_per_sample']} | " + " | ".join(cells) + " |")
    return L


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=2, help="runs of each system under Callgrind (default 2)")
    ap.add_argument("--driver", nargs=3, metavar=("SYSTEM", "VARIANT", "RUNS"), help=argparse.SUPPRESS)
    ap.add_argument("--candidates", action="store_true",
                    help="only measure the candidates (wrench reassociated, graded substeps' accuracy), added to the JSON")
    ap.add_argument("--render", action="store_true", help="rewrite sample_cost.md from the committed JSON only")
    a = ap.parse_args(argv)
    if a.driver:
        _driver(a.driver[0], a.driver[1], int(a.driver[2]))
        return 0
    if a.candidates:
        res = json.loads((OUT / "sample_cost.json").read_text())
        res["wrench"] = wrench_reassociated()
        res["graded"] = graded_accuracy(log=lambda m: print(m, file=sys.stderr, flush=True))
        (OUT / "sample_cost.json").write_text(json.dumps(res, indent=1, sort_keys=True) + "\n")
    elif not a.render:
        if a.runs < 1:
            ap.error(f"--runs: must be >= 1, got {a.runs}")
        res = study(a.runs, log=lambda m: print(m, file=sys.stderr, flush=True))
        (OUT / "sample_cost.json").write_text(json.dumps(res, indent=1, sort_keys=True) + "\n")
    res = json.loads((OUT / "sample_cost.json").read_text())
    (OUT / "sample_cost.md").write_text(markdown(res))
    return 0


if __name__ == "__main__":
    if str(ROOT) not in sys.path:
        sys.path.append(str(ROOT))
    raise SystemExit(main())
