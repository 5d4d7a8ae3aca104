"""Accuracy of the plant's RK4 step against CVODES, and what the step changes in the closed loop.

    python benchmarks/step_accuracy.py            # full, Haidou-1: writes results/step/step_accuracy.json and README.md
    python benchmarks/step_accuracy.py --system bluerov2_heavy_alpha5   # writes results/step/bluerov2_heavy_alpha5/
    python benchmarks/step_accuracy.py --quick --out /tmp/step   # smoke run: proposed only, steps 0.01 and 0.1,
                                                                   # 3 Monte Carlo draws (the first traced),
                                                                   # the front's batch without lockstep lanes

``--system NAME`` (a shipped system, :data:`SYSTEMS`; default haidou1) chooses the plant (its ``uvms_rhs``, its
``B_T`` with one column per thruster, its stow pose), its default scenario, its committed fronts, the
controllers studied and the output directory.

For each plant step ``h_plant`` that divides the controller period (0.01, 0.02, 0.025, 0.05, 0.1 s):

(a) **open-loop plant error**. A traced closed-loop run gives its held thrust per controller sample
    (``r.thrust``, already saturated); the body wrench ``B_T u`` is held over the sample and the plant
    ``uvms_rhs`` (the SX plant function with the direct Newton-Euler arm wrench, not the closed loop's
    time table) is integrated over the whole run by CVODES (Adams, functional iteration, tight
    tolerances), restarted at every sample, where the thrust jumps; the arm's trajectory, payload and
    disturbance are the scenario's functions of time (the arm's and the payload's kinks lie on the
    sample grid). The error is ``max_k |x_RK4(t_k) - x_CVODES(t_k)|`` over the run's own trace: the
    plant integration error for that input sequence, which is what ``h_plant`` controls.
(b) **closed-loop differences** against the 0.01 s run of the same gains, noise, model factors and
    phases: the state (traced runs) and the per-DOF CHAT and RMSE (relative), over the default gains
    of every controller, every member of the committed fronts (``.batch``, on the study's own draw),
    and a Monte Carlo sample of draws for proposed and agsta (``.many``). The worst case is reported.

Base check: the metrics-only runs at ``BASE / 2`` = 0.005 s against 0.01 s, an estimate of the base's own
step error in the metrics.

Traced runs: the default gains of every controller, every fourth member of each front and its knee and last member
and the first Monte Carlo draws of proposed and agsta. Speed: the front members' batch (one thread),
timed at every step in this same run, as a ratio against 0.01 s.

Rule: the recommended default is the coarsest step whose worst-case open-loop state error (a) is
<= 1e-6 (m for positions, rad for angles) and whose worst-case relative CHAT/RMSE change (b) is
<= 1e-5. The script reports; it does not change ``arvcas/data/scenario.toml``.

When no step of the table passes (the base itself fails), :func:`finer_steps` goes below the base:
h/20 and h/40 on the traced runs with the largest error at the base step (textbook RK4 of their 0.01 s
thrust against CVODES), and every metrics-only run at h/20 against h/40; it recommends from those.
A diverged traced run is compared on its samples before the failure.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import platform
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

STEPS = (0.01, 0.02, 0.025, 0.05, 0.1)
BASE = 0.01  # the closed-loop differences are against this step
STATE_TOL = 1e-6  # m, rad
METRIC_TOL = 1e-5  # relative
MC_RUNS = 50
TIMING_ROUNDS = 7
TRACE_EVERY = 4  # every fourth front member is traced (state, CVODES); all are in the metrics
MC_TRACED = 3  # Monte Carlo draws per controller that are also traced (state, CVODES)
# per shipped system: its committed fronts, the controllers whose default gains are studied (None: every
# registered one), those with a Monte Carlo sample at their default gains, and the output directory
SYSTEMS = {
    "haidou1": dict(
        fronts={"proposed": ROOT / "results/tuning/paper/proposed/front.h5",
                "agsta": ROOT / "results/tuning/paper/agsta/front.h5"},
        controllers=None, mc=("proposed", "agsta"), out=ROOT / "results" / "step", label="Haidou-1"),
    "bluerov2_heavy_alpha5": dict(
        # the fronts tuned on the current plant (T200 dynamics; results/bluerov2/<c> are the instantaneous thrusters')
        fronts={c: ROOT / f"results/bluerov2/t200/{c}/front.h5" for c in ("proposed", "agsta", "pid")},
        controllers=("proposed", "agsta", "pid"), mc=("proposed", "agsta"),
        out=ROOT / "results" / "step" / "bluerov2_heavy_alpha5", label="BlueROV2 Heavy + Reach Alpha 5"),
}
FRONTS = SYSTEMS["haidou1"]["fronts"]


def _sibling(name: str):
    """A module of benchmarks/ loaded by its path (this file is loaded by path too, from the tests)."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# the reference (CVODES and RK4 on the plant with the thrust held per sample): benchmarks/step_reference.py
_reference = _sibling("step_reference")
(CVODES_TOL, _plant_ode, plant_inputs, scenario_n, held_wrench, cvodes_states, rk4_states, _state_err) = (
    _reference.CVODES_TOL, _reference._plant_ode, _reference.plant_inputs, _reference.scenario_n,
    _reference.held_wrench, _reference.cvodes_states, _reference.rk4_states, _reference._state_err)


# ---- the study -------------------------------------------------------------------------------------------------

def _rel(a, b) -> np.ndarray:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.abs(a - b) / np.abs(b)


def _load_avg() -> float:
    try:
        return float(os.getloadavg()[0])
    except OSError:  # pragma: no cover
        return float("nan")


def _compare_metrics(metrics: dict, groups, hp, base) -> dict:
    """Relative per-DOF CHAT and RMSE changes of every group at step ``hp`` against ``base``, worst cases."""
    out = {"rel_chat": 0.0, "rel_rmse": 0.0, "worst_group": None, "status_changed": 0, "runs": 0, "by_group": {}}
    for g in groups:
        ch, rm, ok = metrics[(g, hp)]
        chb, rmb, okb = metrics[(g, base)]
        out["status_changed"] += int(np.sum(ok != okb))
        both = ok & okb
        out["runs"] += int(both.sum())
        rc = _rel(ch[both], chb[both]) if both.any() else np.zeros((0, 6))
        rr = _rel(rm[both], rmb[both]) if both.any() else np.zeros((0, 6))
        bg = {"runs": int(ok.size), "ok_both": int(both.sum()),
              "rel_chat": float(rc.max()) if rc.size else 0.0, "rel_rmse": float(rr.max()) if rr.size else 0.0}
        for name, rel, m, mb in (("chat", rc, ch[both], chb[both]), ("rmse", rr, rm[both], rmb[both])):
            if rel.size:
                i, d = np.unravel_index(np.argmax(rel), rel.shape)
                bg[f"worst_{name}"] = {"run": int(np.flatnonzero(both)[i]), "dof": int(d),
                                       "base": float(mb[i, d]), "value": float(m[i, d])}
        if rc.size and max(bg["rel_chat"], bg["rel_rmse"]) > max(out["rel_chat"], out["rel_rmse"]):
            out["worst_group"] = g
        out["rel_chat"] = max(out["rel_chat"], bg["rel_chat"])
        out["rel_rmse"] = max(out["rel_rmse"], bg["rel_rmse"])
        out["by_group"][g] = bg
    return out


def _front_args(fr, quick: bool = False) -> dict:
    """A front's study draw (its noise seed, model factors, phases) for ``CompiledRun.batch``, one thread.
    ``quick``: the runs one at a time (the same bits as in lockstep lanes, whose library per step is not
    compiled; the quick mode's speeds are not for the record)."""
    return dict(seed=int(fr.draw_seeds[0]), uncertainty=fr.draw_uncertainty[0], phase=fr.draw_phase[0],
                n_threads=1, return_status=True, lockstep=False if quick else None)


def _valid(r, h: float) -> int:
    """Samples of a traced run to compare: all of them, or those before its failure time (a diverged run)."""
    n = len(r.eta)
    tf = float(r.t_fail) if (not r.ok and r.t_fail is not None) else float("nan")
    return max(2, min(n, int(np.floor(tf / h)))) if np.isfinite(tf) else n


def _run_and_reference(sysm, cfg, c, g, seed, unc, ph, tol):
    """One traced run at ``cfg``'s step and CVODES on its held thrust: (result, n, states (n+1, 12), wrenches,
    reference states), over the samples before a failure."""
    import arvcas

    r = arvcas.Run(controller=c, scenario=cfg, system=sysm).compile().simulate(gains=g, seed=seed, uncertainty=unc,
                                                                                phase=ph)
    n = min(_valid(r, cfg.time_h), scenario_n(cfg)) - 1
    X = np.hstack([r.eta, r.nu])[:n + 1]
    taus = plant_inputs(sysm.params.vector(), r, sysm.layout)
    return r, n, X, taus, cvodes_states(cfg, sysm.params.vector(), X[0], taus, r.phase, tol=tol, n_samples=n,
                                        layout=sysm.layout)


def study(quick: bool = False, mc_runs: int = MC_RUNS, tol: float = CVODES_TOL, log=print, system: str = "haidou1",
          trace_every: int = TRACE_EVERY, timing_rounds: int = TIMING_ROUNDS, duration: float | None = None) -> dict:
    """The study for one shipped system (:data:`SYSTEMS`). ``duration`` (s) shortens the scenario (smoke tests)."""
    import arvcas
    from arvcas.controllers import names as controller_names
    from arvcas.experiments.montecarlo import draw
    from arvcas.sim.scenario import load_scenario, loads_scenario
    from arvcas.tuning.checkpoint import read_checkpoint
    from arvcas.tuning.front import read_front, system_params

    if system not in SYSTEMS:
        raise ValueError(f"system {system!r}: not one of {', '.join(SYSTEMS)}")
    spec = SYSTEMS[system]
    sysm = arvcas.load_system(system)
    lay = sysm.layout
    # plain RK4 at every step (a scenario's time.thrust_quadrature, the BlueROV2's shipped step, is measured by
    # benchmarks/thruster_step.py --quadrature against the same CVODES reference)
    cfg0 = dataclasses.replace(load_scenario(sysm.params.default("scenario")), time_thrust_quadrature=None)
    pv = sysm.params.vector()
    steps = (0.01, 0.1) if quick else STEPS
    ctrls = ("proposed",) if quick else tuple(spec["controllers"] or controller_names())
    mc_runs = 3 if quick else mc_runs
    fronts = {c: read_front(p) for c, p in spec["fronts"].items() if c in ctrls}
    for c, fr in fronts.items():
        cfg_f = loads_scenario(fr.scenario_text, str(fr.path))
        # the fronts were tuned at the shipped step; the study compares plain RK4 steps on their members
        cfg_f = dataclasses.replace(cfg_f, time_thrust_quadrature=None)
        if cfg_f.graph_key() != cfg0.graph_key():
            raise RuntimeError(f"{fr.path}: the study's scenario differs from the packaged one")
        pf = system_params(read_checkpoint(fr.path))
        if pf.structure.name != sysm.name or not np.array_equal(pf.vector(), pv):
            raise RuntimeError(f"{fr.path}: the study's system ({pf.structure.name}) differs from {sysm.name}")
    if duration is not None:  # after the check against the fronts' scenario: a shortened horizon
        cfg0 = dataclasses.replace(cfg0, time_duration=float(duration))
    draws = draw(mc_runs, seed=0, spread=0.3)
    mc_ctrls = tuple(c for c in spec["mc"] if c in ctrls)

    # the traced runs: (label, controller, gains or None, seed, uncertainty, phase)
    traced = [(f"{c} default", c, None, 0, None, None) for c in ctrls]
    member_sets = {}
    for c, fr in fronts.items():
        idx = sorted({*range(0, fr.size, trace_every), fr.knee(), fr.size - 1}) if not quick else [0]
        member_sets[c] = idx
        for i in idx:
            traced.append((f"{c} front[{i}]", c, fr.gains[i], int(fr.draw_seeds[0]), fr.draw_uncertainty[0],
                           fr.draw_phase[0]))
    for c in mc_ctrls:
        for i in range(min(1 if quick else MC_TRACED, mc_runs)):
            traced.append((f"{c} mc[{i}]", c, None, int(draws.noise_seed[i]), draws.factors[i], draws.phase[i]))

    per_step: dict = {}
    compiled: dict = {}
    states: dict = {}  # (label, step) -> (N+1, 12)
    metrics: dict = {}  # (group, step) -> (chat, rmse, ok) arrays
    for hp in steps:
        cfg = dataclasses.replace(cfg0, time_h_plant=hp)
        log(f"h_plant = {hp}: compiling and running")
        t_c = time.perf_counter()
        runs = {c: arvcas.Run(controller=c, scenario=cfg, system=sysm).compile() for c in ctrls}
        rec = {"traced": {}, "compile_and_first_call_s": None}
        for label, c, g, seed, unc, ph in traced:
            r = runs[c].simulate(gains=g, seed=seed, uncertainty=unc, phase=ph)
            nv = _valid(r, cfg.time_h)  # a diverged run: its samples before the failure only
            X = np.hstack([r.eta, r.nu])[:nv]
            states[(label, hp)] = X
            metrics[(label, hp)] = (r.chat[None, :], r.rmse[None, :], np.array([r.ok]))
            taus = plant_inputs(pv, r, lay)
            t0 = time.perf_counter()
            Xc = cvodes_states(cfg, pv, X[0], taus, r.phase, tol=tol, n_samples=min(nv, scenario_n(cfg)) - 1,
                               layout=lay)
            t_cv = time.perf_counter() - t0
            e = _state_err(X, Xc)
            rec["traced"][label] = {"ok": bool(r.ok), "vs_cvodes": e, "cvodes_s": t_cv}
            if not r.ok:
                rec["traced"][label]["samples_compared"] = int(nv)
            log(f"  {label:22s} ok={r.ok} vs CVODES: {e['position_m']:.2e} m, {e['angle_rad']:.2e} rad "
                f"({t_cv:.1f} s)")
        rec["compile_and_first_call_s"] = time.perf_counter() - t_c
        # front members (metrics only); their batch is timed below, all steps interleaved
        for c, fr in fronts.items():
            chat, rmse, ok, _tf = runs[c].batch(fr.gains, **_front_args(fr, quick))
            metrics[(f"{c} front", hp)] = (chat, rmse, ok)
            log(f"  {c} front: {fr.size} runs, ok {int(ok.sum())}/{ok.size}")
        for c in mc_ctrls:
            chat, rmse, ok, _tf = runs[c].many(runs[c].default_gains(), draws.noise_seed, uncertainty=draws.factors,
                                              phase=draws.phase, n_threads=1)
            metrics[(f"{c} mc", hp)] = (chat, rmse, ok)
            log(f"  {c} Monte Carlo: {mc_runs} draws, ok {int(ok.sum())}/{ok.size}")
        per_step[hp] = rec
        compiled[hp] = runs

    # speed: the front batches at every step, in interleaved rounds (the machine's load drifts; a round
    # sees every step at about the same load), least disturbed round per step
    rounds = 2 if quick else timing_rounds
    times = {(hp, c): [] for hp in steps for c in fronts}
    for rd in range(rounds):
        order = steps[rd % len(steps):] + steps[:rd % len(steps)]
        for hp in order:
            for c, fr in fronts.items():
                t0 = time.perf_counter()
                compiled[hp][c].batch(fr.gains, **_front_args(fr, quick))
                times[(hp, c)].append(time.perf_counter() - t0)
    for hp in steps:
        per_step[hp]["timing"] = {
            f"{c} front batch": {"runs": int(fr.size), "s_min": min(times[(hp, c)]),
                                 "s_median": float(np.median(times[(hp, c)])), "reps": times[(hp, c)]}
            for c, fr in fronts.items()}
        log(f"h_plant = {hp}: front batches " + ", ".join(
            f"{c} {min(times[(hp, c)]):.3f} s" for c in fronts) + f" (min of {rounds} rounds)")
    load_timing = _load_avg()

    # the base's own convergence: the metrics-only runs (default gains of every controller, the fronts, the
    # Monte Carlo draws) at BASE / 2 against BASE
    if True:  # also in --quick (proposed only)
        hf = BASE / 2
        cfg_f = dataclasses.replace(cfg0, time_h_plant=hf)
        log(f"base check: h_plant = {hf}")
        runs_f = {c: arvcas.Run(controller=c, scenario=cfg_f, system=sysm).compile() for c in ctrls}
        bgroups = []
        for c in ctrls:
            for hp_, rr_ in ((hf, runs_f[c]), (BASE, compiled[BASE][c])):
                chat, rmse, ok, _tf = rr_.batch(rr_.default_gains(), seed=0, n_threads=1, return_status=True)
                metrics[(f"{c} default (batch)", hp_)] = (chat, rmse, ok)
            bgroups.append(f"{c} default (batch)")
        for c, fr in fronts.items():
            metrics[(f"{c} front", hf)] = runs_f[c].batch(fr.gains, **_front_args(fr, quick))[0:3]
            bgroups.append(f"{c} front")
        for c in mc_ctrls:
            metrics[(f"{c} mc", hf)] = runs_f[c].many(runs_f[c].default_gains(), draws.noise_seed,
                                                      uncertainty=draws.factors, phase=draws.phase, n_threads=1)[0:3]
            bgroups.append(f"{c} mc")
        base_check = dict(h_plant=hf, **_compare_metrics(metrics, bgroups, hf, BASE))
        log(f"base check: CHAT {base_check['rel_chat']:.2e}, RMSE {base_check['rel_rmse']:.2e} "
            f"(worst {base_check['worst_group']})")

    # reference self-check: the first traced run at the base step, CVODES at tol and tol / 10
    label0 = traced[0][0]
    cfg_b = dataclasses.replace(cfg0, time_h_plant=BASE)
    r0 = arvcas.Run(controller=traced[0][1], scenario=cfg_b, system=sysm).compile().simulate()
    taus0 = plant_inputs(pv, r0, lay)
    X0 = np.hstack([r0.eta, r0.nu])[0]
    n0 = min(_valid(r0, cfg_b.time_h), scenario_n(cfg_b)) - 1
    ref_a = cvodes_states(cfg_b, pv, X0, taus0, r0.phase, tol=tol, n_samples=n0, layout=lay)
    ref_b = cvodes_states(cfg_b, pv, X0, taus0, r0.phase, tol=tol / 10, n_samples=n0, layout=lay)
    ref_check = {"run": label0, "tol": tol, "tol_fine": tol / 10, "difference": _state_err(ref_a, ref_b)}
    log(f"reference: CVODES {tol:g} vs {tol / 10:g} on {label0}: {ref_check['difference']}")

    # convergence on the run with the largest open-loop error at the base step: the textbook RK4 of the
    # same ODE against the closed loop's own RK4 at the base step, and at h/2 .. h/16 against CVODES
    # (the observed order; the drag's |v|, |w| factors have kinks at zero velocity, where RK4's order drops)
    worst = max(per_step[BASE]["traced"], key=lambda k: per_step[BASE]["traced"][k]["vs_cvodes"]["position_m"])
    lab, c, g, seed, unc, ph = next(t for t in traced if t[0] == worst)
    rw, nw, Xw, tw, ref_w = _run_and_reference(sysm, cfg_b, c, g, seed, unc, ph, tol)
    conv = {"run": worst, "closed_loop_vs_textbook_rk4": float(np.abs(
        rk4_states(cfg_b, pv, Xw[0], tw, rw.phase, BASE, n_samples=nw, layout=lay) - Xw).max()), "steps": {}}
    hs = [cfg0.time_h / m for m in (2, 4, 8, 16)]  # halvings, coarse to fine (the finest near the reference's floor)
    for hh in hs:
        conv["steps"][repr(hh)] = _state_err(rk4_states(cfg_b, pv, Xw[0], tw, rw.phase, hh, n_samples=nw, layout=lay),
                                             ref_w)
    conv["observed_order"] = {
        key: [float(np.log2(conv["steps"][repr(a)][key] / conv["steps"][repr(b)][key])) for a, b in zip(hs[:-1], hs[1:])]
        for key in ("position_m", "angle_rad", "linear_rate_m_s", "angular_rate_rad_s")}
    log(f"convergence on {worst}: {conv}")

    # the table
    table = []
    groups = sorted({g for g, h_ in metrics if h_ in steps and "(batch)" not in g})
    for hp in steps:
        rec = per_step[hp]
        ol = [v["vs_cvodes"] for v in rec["traced"].values()]
        worst_ol = {k: max(e[k] for e in ol) for k in ("position_m", "angle_rad", "linear_rate_m_s",
                                                         "angular_rate_rad_s")}
        worst_ol_run = max(rec["traced"], key=lambda k: max(rec["traced"][k]["vs_cvodes"]["position_m"],
                                                            rec["traced"][k]["vs_cvodes"]["angle_rad"]))
        cl = {"position_m": 0.0, "angle_rad": 0.0, "linear_rate_m_s": 0.0, "angular_rate_rad_s": 0.0}
        worst_cl_run = None
        for label, *_ in traced:
            A, Bs = states[(label, hp)], states[(label, BASE)]
            e = _state_err(A[:len(Bs)], Bs[:len(A)])  # a diverged run: the samples before both failures
            if worst_cl_run is None or max(e["position_m"], e["angle_rad"]) > max(cl["position_m"], cl["angle_rad"]):
                worst_cl_run = label
            for k in cl:
                cl[k] = max(cl[k], e[k])
        cmp = _compare_metrics(metrics, groups, hp, BASE)
        rel_chat, rel_rmse, where = cmp["rel_chat"], cmp["rel_rmse"], cmp["worst_group"]
        status_changed, n_runs, by_group = cmp["status_changed"], cmp["runs"], cmp["by_group"]
        tb = sum(v["s_min"] for v in rec["timing"].values())
        tb0 = sum(v["s_min"] for v in per_step[BASE]["timing"].values()) if per_step[BASE]["timing"] else float("nan")
        passes = (worst_ol["position_m"] <= STATE_TOL and worst_ol["angle_rad"] <= STATE_TOL
                  and max(rel_chat, rel_rmse) <= METRIC_TOL and status_changed == 0)
        table.append({
            "h_plant": hp, "substeps": int(round(cfg0.time_h / hp)),
            "open_loop_vs_cvodes": worst_ol, "open_loop_worst_run": worst_ol_run,
            "closed_loop_vs_base": cl, "closed_loop_worst_run": worst_cl_run,
            "rel_chat": rel_chat, "rel_rmse": rel_rmse, "metric_worst_group": where, "metric_runs": n_runs,
            "status_changed": status_changed, "by_group": by_group,
            "batch_s": tb, "speed_vs_base": tb0 / tb if tb > 0 else float("nan"),
            "passes_rule": bool(passes),
        })
    ok_steps = [row["h_plant"] for row in table if row["passes_rule"]]
    recommended = max(ok_steps) if ok_steps else None
    out = {
        "system": sysm.name, "system_label": spec["label"], "n_thrusters": sysm.n_thrusters,
        "n_joints": sysm.n_joints, "trace_every": trace_every,
        "rule": (f"the coarsest h_plant dividing h whose worst-case open-loop state error against CVODES is "
                 f"<= {STATE_TOL:g} (m for positions, rad for angles) and whose worst-case relative change of "
                 f"per-DOF CHAT and RMSE against the {BASE} s run is <= {METRIC_TOL:g}, with no run changing "
                 f"its ok status"),
        "recommended_h_plant": recommended,
        "quick": quick, "steps": list(steps), "base": BASE, "h": cfg0.time_h, "duration": cfg0.time_duration,
        "cvodes": {"tol": tol, "method": "adams", "iteration": "functional", "restart": "every controller sample"},
        "reference_check": ref_check,
        "convergence": conv,
        "base_check": base_check,
        "timing_rounds": rounds, "load_avg_1min_after_timing": load_timing,
        "traced_runs": [t[0] for t in traced], "front_members_traced": member_sets,
        "monte_carlo": {"runs": mc_runs, "master_seed": 0, "spread": 0.3, "controllers": list(mc_ctrls)},
        "fronts": {c: {"path": str(Path(p).relative_to(ROOT)), "members": int(fronts[c].size)}
                   for c, p in spec["fronts"].items() if c in fronts},
        "table": table,
        "per_step": {str(k): v for k, v in per_step.items()},
        "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "casadi": ca.__version__,
                    "cpus": os.cpu_count(), "load_avg_1min_end": _load_avg()},
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    if system == "haidou1" and duration is None:  # Haidou-1's JSON as committed before --system (no new keys)
        for k in ("system", "system_label", "n_thrusters", "n_joints", "trace_every"):
            out.pop(k)
    elif duration is not None:
        out["duration_shortened"] = True
    return out


def _rebuild_traced(label: str, system: str, mc_runs: int):
    """(controller, gains or None, seed, uncertainty, phase) of a traced run from its label in the JSON."""
    from arvcas.experiments.montecarlo import draw
    from arvcas.tuning.front import read_front

    c, rest = label.split(" ", 1)
    if rest == "default":
        return c, None, 0, None, None
    kind, i = rest[:-1].split("[")
    i = int(i)
    if kind == "front":
        fr = read_front(SYSTEMS[system]["fronts"][c])
        return c, fr.gains[i], int(fr.draw_seeds[0]), fr.draw_uncertainty[0], fr.draw_phase[0]
    d = draw(mc_runs, seed=0, spread=0.3)
    return c, None, int(d.noise_seed[i]), d.factors[i], d.phase[i]


def finer_steps(res: dict, system: str, n_worst: int = 12, divisors=(20, 40), tol: float = CVODES_TOL,
                log=print, metrics: bool = True) -> dict:
    """Steps finer than the base, h / 20 and h / 40, on the ``n_worst`` traced runs with the largest open-loop
    error at the base step: the textbook RK4 (equal to the closed loop's at the base step) of each run's own
    0.01 s thrust sequence against CVODES, and CVODES at ``tol / 10`` on the worst run. Open loop only: what
    a step below the base would give for (a) where the base itself fails the rule."""
    import arvcas
    from arvcas.sim.scenario import load_scenario

    sysm = arvcas.load_system(system)
    lay, pv = sysm.layout, sysm.params.vector()
    cfg_b = dataclasses.replace(load_scenario(sysm.params.default("scenario")), time_h_plant=BASE,
                                time_thrust_quadrature=None)
    if res.get("duration_shortened"):
        cfg_b = dataclasses.replace(cfg_b, time_duration=res["duration"])
    tr = res["per_step"][repr(BASE)]["traced"]
    worst = sorted(tr, key=lambda k: -max(tr[k]["vs_cvodes"]["position_m"], tr[k]["vs_cvodes"]["angle_rad"]))[:n_worst]
    out = {"runs": {}, "steps": [BASE] + [cfg_b.time_h / m for m in divisors], "reference_fine": None}
    for j, label in enumerate(worst):
        c, g, seed, unc, ph = _rebuild_traced(label, system, res["monte_carlo"]["runs"])
        r, n, X, taus, ref = _run_and_reference(sysm, cfg_b, c, g, seed, unc, ph, tol)
        rec = {"closed_loop": _state_err(X, ref)}
        for hh in out["steps"][1:]:
            rec[repr(hh)] = _state_err(rk4_states(cfg_b, pv, X[0], taus, r.phase, hh, n_samples=n, layout=lay), ref)
        if j == 0:
            fine = cvodes_states(cfg_b, pv, X[0], taus, r.phase, tol=tol / 10, n_samples=n, layout=lay)
            out["reference_fine"] = {"run": label, "tol_fine": tol / 10, "difference": _state_err(ref, fine)}
        out["runs"][label] = rec
        log(f"finer steps, {label}: " + ", ".join(f"{k}: {v['position_m']:.2e} m, {v['angle_rad']:.2e} rad"
                                                  for k, v in rec.items()))
    # the metrics rule one level down: every metrics-only run (default gains, fronts, Monte Carlo draws) at
    # h / divisors[0] against h / divisors[1] (the base check's BASE / 2 vs BASE, moved down)
    if metrics:
        from arvcas.experiments.montecarlo import draw
        from arvcas.tuning.front import read_front

        spec = SYSTEMS[system]
        ctrls = list(dict.fromkeys(lab.split(" ", 1)[0] for lab in res["traced_runs"]))
        fronts = {c: read_front(spec["fronts"][c]) for c in res["fronts"]}
        mc = tuple(res["monte_carlo"]["controllers"])
        d = draw(res["monte_carlo"]["runs"], seed=0, spread=0.3)
        hs = [cfg_b.time_h / m for m in divisors[:2]]
        met, groups, tbatch = {}, [], {}
        for hh in [BASE, *hs]:
            cfg = dataclasses.replace(cfg_b, time_h_plant=hh)
            runs = {c: arvcas.Run(controller=c, scenario=cfg, system=sysm).compile() for c in ctrls}
            for c in ctrls:
                met[(f"{c} default (batch)", hh)] = runs[c].batch(runs[c].default_gains(), seed=0, n_threads=1,
                                                                  return_status=True)[0:3]
            tb = []
            for rd in range(3):  # the fronts' batch, least disturbed of 3, as a ratio against BASE
                t0 = time.perf_counter()
                for c, fr in fronts.items():
                    met[(f"{c} front", hh)] = runs[c].batch(fr.gains, **_front_args(fr))[0:3]
                tb.append(time.perf_counter() - t0)
            tbatch[hh] = min(tb)
            if hh == BASE:
                continue
            for c in mc:
                met[(f"{c} mc", hh)] = runs[c].many(runs[c].default_gains(), d.noise_seed, uncertainty=d.factors,
                                                   phase=d.phase, n_threads=1)[0:3]
            log(f"finer steps: metrics at {hh:g} s")
        groups = [f"{c} default (batch)" for c in ctrls] + [f"{c} front" for c in fronts] + [f"{c} mc" for c in mc]
        out["metrics"] = dict(h_plant=hs[0], base=hs[1], **_compare_metrics(met, groups, hs[0], hs[1]))
        out["speed_vs_base"] = {repr(hh): tbatch[BASE] / tbatch[hh] for hh in hs}
        out["batch_s"] = {repr(hh): tbatch[hh] for hh in tbatch}
        log(f"finer steps: metrics {hs[0]:g} vs {hs[1]:g} s: CHAT {out['metrics']['rel_chat']:.2e}, RMSE "
            f"{out['metrics']['rel_rmse']:.2e}")
    # the coarsest finer step within the state rule on these runs and (the first finer step only, the one
    # whose metrics are compared one level down) within the metrics rule
    ok = []
    for hh in out["steps"][1:]:
        state_ok = all(max(rec[repr(hh)][k] for rec in out["runs"].values()) <= STATE_TOL
                       for k in ("position_m", "angle_rad"))
        m = out.get("metrics")
        metric_ok = (m is None or m["h_plant"] != hh
                     or (max(m["rel_chat"], m["rel_rmse"]) <= METRIC_TOL and m["status_changed"] == 0))
        if state_ok and metric_ok:  # the finest step is the metrics' reference: its state error decides
            ok.append(hh)
    out["recommended_h_plant"] = max(ok) if ok else None
    return out


def markdown(res: dict) -> str:
    f = lambda v: f"{v:.2g}"  # noqa: E731
    lines = [
        "# Plant step: accuracy against CVODES and effect on the closed loop",
        "",
        "Produced by `python benchmarks/step_accuracy.py" + (f" --system {res['system']}" if "system" in res else "")
        + "` (" + ("quick smoke run" if res["quick"] else "full run")
        + f", {res['created']}); every figure is in `step_accuracy.json`. "
        + (f"{res['system_label']} (`{res['system']}`: {res['n_thrusters']} thrusters, {res['n_joints']} joints), "
           "its default scenario" if "system" in res else "Haidou-1, the packaged scenario")
        + f" ({res['duration']:g} s, controller period h = {res['h']:g} s); each step divides h.",
        "",
        "- **(a) open loop vs CVODES**: each traced run's own held thrust sequence (saturated, `B_T u` held over "
        "each sample) drives the plant `uvms_rhs` (direct Newton-Euler arm wrench, not the closed loop's time "
        f"table) through CVODES (Adams, functional iteration, abstol = reltol = {res['cvodes']['tol']:g}, restarted "
        "at every sample); max over the run's samples of |x_RK4 - x_CVODES|, worst over the traced runs "
        f"({len(res['traced_runs'])}" + (f"; front members every {res['trace_every']}th plus knee and last"
                                          if res.get("trace_every", TRACE_EVERY) != TRACE_EVERY else "")
        + "): " + _compact(res["traced_runs"]) + "."
        + (" A diverged run is compared on its samples before the failure." if any(
            "samples_compared" in v for ps in res["per_step"].values() for v in ps["traced"].values()) else ""),
        f"- **(b) closed loop vs {res['base']:g} s**: the same runs (same gains, noise, model factors, phases) at "
        f"h_plant = {res['base']:g} s. State: worst over the traced runs. CHAT/RMSE: max over DOFs and runs of "
        "|m - m_base| / |m_base|, over the default gains of every controller, every member of the committed fronts "
        "(" + ", ".join(f"{c}: {v['members']}" for c, v in res["fronts"].items()) + ", on each study's draw) and "
        f"{res['monte_carlo']['runs']} Monte Carlo draws (master seed 0, +-30 % model factors, random phases) of "
        + " and ".join(res["monte_carlo"]["controllers"]) + f" at their default gains: {res['table'][0]['metric_runs']} runs per step.",
        "- **speed**: the batch of " + ("both fronts'" if len(res["fronts"]) == 2 else "every front's")
        + " members (one thread) against "
        f"{res['base']:g} s, measured in this run in {res['timing_rounds']} interleaved rounds over the steps "
        "(least disturbed round per step) on a shared machine (1-min load average after timing: "
        f"{res['load_avg_1min_after_timing']:.1f}); a ratio, not an absolute speed.",
        "",
        "| h_plant (s) | RK4 steps / sample | (a) position m | (a) angle rad | (a) rates m/s, rad/s | (b) position m | (b) angle rad "
        "| (b) CHAT rel | (b) RMSE rel | ok changed | batch speed | rule |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in res["table"]:
        a, b = row["open_loop_vs_cvodes"], row["closed_loop_vs_base"]
        base = row["h_plant"] == res["base"]
        lines.append(
            f"| {row['h_plant']:g} | {row['substeps']} | {f(a['position_m'])} | {f(a['angle_rad'])} | "
            f"{f(a['linear_rate_m_s'])}, {f(a['angular_rate_rad_s'])} | "
            + ("(base) | (base) | (base) | (base) | (base) | " if base else
               f"{f(b['position_m'])} | {f(b['angle_rad'])} | {f(row['rel_chat'])} | {f(row['rel_rmse'])} | "
               f"{row['status_changed']} | ")
            + f"{row['speed_vs_base']:.2f}x | {'pass' if row['passes_rule'] else 'fail'} |")
    rc = res["reference_check"]
    lines += [
        "",
        f"Reference check: CVODES at {rc['tol']:g} against {rc['tol_fine']:g} on `{rc['run']}` (0.01 s thrust) "
        f"differs by {f(rc['difference']['position_m'])} m, {f(rc['difference']['angle_rad'])} rad.",
        "",
        "Convergence on `" + res["convergence"]["run"] + "` (the largest (a) position error at the base step): a "
        "textbook RK4 of the same ODE (no time table) at the base step equals the closed loop's own trajectory to "
        f"{f(res['convergence']['closed_loop_vs_textbook_rk4'])}; its error against CVODES at "
        + ", ".join(f"{float(k):g} s: {f(v['position_m'])} m, {f(v['angle_rad'])} rad"
                    for k, v in sorted(res["convergence"]["steps"].items(), key=lambda kv: -float(kv[0])))
        + "; observed order per halving (log2 of the error ratio, coarse to fine): positions "
        + ", ".join(f"{o:.2f}" for o in res["convergence"]["observed_order"]["position_m"]) + ", angles "
        + ", ".join(f"{o:.2f}" for o in res["convergence"]["observed_order"]["angle_rad"]) + ".",
        "",
        "Worst runs: " + "; ".join(
            f"{row['h_plant']:g} s: (a) {row['open_loop_worst_run']}, (b) state {row['closed_loop_worst_run']}, "
            f"metrics {row['metric_worst_group']}" for row in res["table"] if row["h_plant"] != res["base"]) + ".",
        "",
        *([f"Base check: the same metrics-only runs ({res['base_check']['runs']}: default gains of every "
           f"controller, the fronts, the Monte Carlo draws) at h_plant = {res['base_check']['h_plant']:g} s change "
           f"against {res['base']:g} s by at most {f(res['base_check']['rel_chat'])} (CHAT) and "
           f"{f(res['base_check']['rel_rmse'])} (RMSE) relative; worst: {_worst_metric(res['base_check'])}.", ""]
          if res.get("base_check") else []),
        "Worst metric change per step (group, run index in the group, DOF, base value -> value): " + "; ".join(
            _worst_metric(row) for row in res["table"] if row["h_plant"] != res["base"]) + ".",
        "",
        "The proposed controller's default gains alone: " + ", ".join(
            f"{row['h_plant']:g} s: CHAT {f(row['by_group']['proposed default']['rel_chat'])}, RMSE "
            f"{f(row['by_group']['proposed default']['rel_rmse'])}" for row in res["table"]
            if row["h_plant"] != res["base"] and "proposed default" in row["by_group"]) + " (relative).",
        "",
        "Notes. (a) is the plant integration error for a given input sequence, what h_plant controls; (b) also "
        "carries the feedback (a different trajectory gives different thrust), and is reported, not part of the "
        "rule. RK4's observed order is irregular here and often below 4, and the error need not fall monotonically "
        "with the step; a likely cause (not isolated in this study): the vehicle's damping (docs/model.md §2, Damping) "
        "has |v| and |w| factors, kinks at zero velocity that a station-keeping vehicle crosses often, and a step "
        "across a kink loses order.",
        "",
        f"**Rule**: {res['rule']}.",
        "",
        f"**Recommended default step: h_plant = {res['recommended_h_plant']:g} s**" if res["recommended_h_plant"]
        else ("**No step of the table passes the rule.**" + (
            f" **Recommended default step: h_plant = {res['finer']['recommended_h_plant']:g} s** "
            f"({int(round(res['h'] / res['finer']['recommended_h_plant']))} RK4 steps per sample; steps below the base, "
            "above: within the state rule on the runs that fail it at the base step, and within the metrics rule "
            "against the next finer step)." if res.get("finer", {}).get("recommended_h_plant") else "")),
        "",
        *(_base_fails_md(res) if not res["table"][0]["passes_rule"] else []),
        *(_finer_md(res) if res.get("finer") else []),
        "Every other step stays available (`time.h_plant` in the scenario file, or "
        "`dataclasses.replace(cfg, time_h_plant=...)`). This report does not change the packaged default. The plant "
        "is integrated by plain RK4 at every step here (a scenario's `time.thrust_quadrature` set aside; "
        "benchmarks/thruster_step.py --quadrature measures it).",
        "",
    ]
    return "\n".join(lines)


def _base_fails_md(res) -> list:
    row = res["table"][0]
    a = row["open_loop_vs_cvodes"]
    bc = res.get("base_check") or {}
    return [f"**The base step {res['base']:g} s itself fails the rule**: its worst (a) error is {a['position_m']:.2g} m, "
            f"{a['angle_rad']:.2g} rad (`{row['open_loop_worst_run']}`)"
            + (f", and the base check ({bc['h_plant']:g} s against {res['base']:g} s) moves the metrics by up to "
               f"{max(bc['rel_chat'], bc['rel_rmse']):.2g} relative" if bc else "")
            + ". The (b) columns of the table compare against a base that is not converged to the rule's "
            "tolerances; the steps below the base decide.", ""]


def _finer_md(res) -> list:
    fz = res["finer"]
    f = lambda v: f"{v:.2g}"  # noqa: E731
    dofs = ("x", "y", "z", "phi", "theta", "psi")
    rows = ["**Steps below the base** (open loop only, `finer_steps`): the textbook RK4 of each run's own "
            f"{res['base']:g} s thrust sequence against CVODES, on the {len(fz['runs'])} traced runs with the largest "
            "(a) error at the base step (worst state: position or angle DOF with the largest error):", "",
            "| run | " + " | ".join(f"{h:g} s (a) position m, angle rad" for h in fz["steps"]) + " |",
            "|---|" + "---|" * len(fz["steps"])]
    for lab, rec in fz["runs"].items():
        cells = [rec["closed_loop"]] + [rec[repr(h)] for h in fz["steps"][1:]]
        rows.append(f"| {lab} | " + " | ".join(f"{f(e['position_m'])}, {f(e['angle_rad'])} ({dofs[e['argmax_state']]})"
                                               for e in cells) + " |")
    rf = fz["reference_fine"]
    rows += ["", f"CVODES at {res['cvodes']['tol']:g} against {rf['tol_fine']:g} on `{rf['run']}`: "
             f"{f(rf['difference']['position_m'])} m, {f(rf['difference']['angle_rad'])} rad.", ""]
    ok = [h for h in fz["steps"] if all(max((rec["closed_loop"] if h == fz["steps"][0] else rec[repr(h)])[k]
                                            for rec in fz["runs"].values()) <= STATE_TOL
                                        for k in ("position_m", "angle_rad"))]
    rows += [("On these runs the coarsest step within the state rule is " + f"{max(ok):g} s." if ok else
              "None of these steps is within the state rule on these runs."), ""]
    if fz.get("metrics"):
        m = fz["metrics"]
        rows += [f"Metrics one level down: every metrics-only run ({m['runs']}: default gains of every controller, "
                 f"the fronts, the Monte Carlo draws) at h_plant = {m['h_plant']:g} s against {m['base']:g} s: at "
                 f"most {f(m['rel_chat'])} (CHAT) and {f(m['rel_rmse'])} (RMSE) relative, {m['status_changed']} "
                 f"runs changing their ok status; worst: {_worst_metric(m)}."
                 + (" Fronts' batch speed against the base (least disturbed of 3, same run): " + ", ".join(
                     f"{float(k):g} s: {v:.2f}x" for k, v in fz["speed_vs_base"].items()) + "."
                    if fz.get("speed_vs_base") else ""), ""]
    return rows


def _compact(labels) -> str:
    """``a[0], a[4], b`` -> ``a[0, 4], b``."""
    groups: dict = {}
    for lab in labels:
        if lab.endswith("]") and "[" in lab:
            name, i = lab[:-1].split("[")
            groups.setdefault(name, []).append(i)
        else:
            groups.setdefault(lab, None)
    return ", ".join(k if v is None else f"{k} [{', '.join(v)}]" for k, v in groups.items())


def _worst_metric(row) -> str:
    dofs = ("x", "y", "z", "phi", "theta", "psi")
    best = None
    for g, v in row["by_group"].items():
        for name in ("chat", "rmse"):
            w = v.get(f"worst_{name}")
            if w and (best is None or v[f"rel_{name}"] > best[0]):
                best = (v[f"rel_{name}"], g, name, w)
    if best is None:
        return f"{row['h_plant']:g} s: none"
    rel, g, name, w = best
    return (f"{row['h_plant']:g} s: {rel:.2g} in {name.upper()} of {g} [{w['run']}], {dofs[w['dof']]}, "
            f"{w['base']:.10g} -> {w['value']:.10g}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--system", default="haidou1", choices=tuple(SYSTEMS), help="shipped system (default haidou1)")
    ap.add_argument("--quick", action="store_true", help="smoke run: proposed only, steps 0.01 and 0.1, 3 draws "
                    "(one traced), the first front member traced, no lockstep lanes")
    ap.add_argument("--out", default=None, help="output directory (default: the system's, results/step[/NAME])")
    ap.add_argument("--mc-runs", type=int, default=MC_RUNS)
    ap.add_argument("--trace-every", type=int, default=TRACE_EVERY, help="trace every n-th front member")
    ap.add_argument("--timing-rounds", type=int, default=TIMING_ROUNDS)
    ap.add_argument("--duration", type=float, default=None, help="shorten the scenario to this many seconds (smoke)")
    ap.add_argument("--tol", type=float, default=CVODES_TOL)
    ap.add_argument("--report-only", action="store_true", help="rewrite README.md from the JSON in --out")
    ap.add_argument("--finer", action="store_true", help="add steps below the base (h/20, h/40) on the worst "
                    "traced runs to the JSON in --out (or after the study, when no step passes the rule)")
    a = ap.parse_args(argv)
    out = Path(a.out) if a.out else Path(SYSTEMS[a.system]["out"])
    if a.finer and (out / "step_accuracy.json").exists() and a.report_only:
        res = json.loads((out / "step_accuracy.json").read_text())
        res["finer"] = finer_steps(res, res.get("system", a.system), tol=res["cvodes"]["tol"])
        (out / "step_accuracy.json").write_text(json.dumps(res, indent=1) + "\n")
        (out / "README.md").write_text(markdown(res))
        print(markdown(res))
        return 0
    if a.report_only:
        res = json.loads((out / "step_accuracy.json").read_text())
        (out / "README.md").write_text(markdown(res))
        print(markdown(res))
        return 0
    res = study(quick=a.quick, mc_runs=a.mc_runs, tol=a.tol, system=a.system, trace_every=a.trace_every,
                timing_rounds=a.timing_rounds, duration=a.duration)
    if a.finer or res["recommended_h_plant"] is None:
        res["finer"] = finer_steps(res, a.system, tol=a.tol)
    out.mkdir(parents=True, exist_ok=True)
    (out / "step_accuracy.json").write_text(json.dumps(res, indent=1) + "\n")
    (out / "README.md").write_text(markdown(res))
    print(markdown(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
