"""The Hinsdale pool trials against arvcas, before and after identification, and the synthetic-truth study.

    python benchmarks/validation.py                      # everything: writes results/validation/
    python benchmarks/validation.py --only synthetic     # one part: sourced, identify, identified, step, synthetic, summary

Parts (each writes under ``--out``, default ``results/validation``):

* ``sourced``: ``arvcas validate`` of the shipped ``hinsdale_bluerov2_alpha5`` (every number from its sources)
  on all twelve shipped trials -> ``sourced/``;
* ``identify``: ``arvcas identify`` of :data:`FREE` on the six identification trials (:data:`FIT`) ->
  ``hinsdale_bluerov2_alpha5_identified.toml`` (its report in its header) and ``identify.log``;
* ``identified``: ``arvcas validate`` of the identified file on all twelve -> ``identified/`` (the three
  held-out trials and the three baselines were not fitted);
* ``step``: the plant step: every trial validated at the log's 0.02 s and at 0.005 s, the largest
  difference of the simulated roll and pitch -> ``step.json``;
* ``synthetic``: identification of :data:`SYN_FREE` of the Hinsdale system (arm included) from trials
  simulated with known parameters and stated sensor noise, :data:`SYN_SEEDS` noise seeds: estimates, 95 %
  intervals, their coverage of the truth -> ``synthetic/synthetic.json`` and ``synthetic/README.md``;
* ``speed``: where the time of ``arvcas validate`` goes on the 20 s trial :data:`SPEED_TRIAL` (its CSV logs, and
  the same trial written as a ROS 2 bag): reading the log, the open-loop simulation, the k-step prediction,
  the residual tests, one figure; best of :data:`SPEED_REPEATS` after a first (compiling) run -> ``speed.json``;
* ``summary``: ``README.md`` from the files above, beside the figures the trials' authors report.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TRIALS = ROOT / "studies" / "validation" / "hinsdale2023"
SYSTEM = "hinsdale_bluerov2_alpha5"
FIT = ("traj003-0", "traj005-0", "traj012-1", "traj019-2", "traj024-1", "traj030-0")
HELD_OUT = ("traj006-3", "traj014-2", "traj024-2")
BASELINES = ("baseline1", "baseline2", "baseline3")
# the restoring moments' balance (the centre of buoyancy against the fixed weight and buoyancy), roll and pitch
# inertia (added inertia included) and their linear and quadratic damping
FREE = ("vehicle.xB", "vehicle.yB", "vehicle.zB", "vehicle.Ixx", "vehicle.Iyy", "hydro.K_p", "hydro.M_q",
        "hydro.K_p_absp", "hydro.M_q_absq")
# attitude and rates, the authors' reference; depth is validated, not fitted: the trials disagree on how fast
# the vehicle rises (2 mm/s in traj019-2, 20-29 mm/s in the other five), which one buoyancy cannot explain
SIGNALS = ("roll", "pitch", "p", "q")
SYN_FREE = ("vehicle.zB", "vehicle.Ixx", "vehicle.Iyy", "hydro.K_p", "hydro.M_q", "hydro.K_p_absp",
            "thrusters.T1.u_max")  # the last: the thrusters are off, so it cannot be identified
SYN_TRUTH = {"vehicle.zB": -0.011, "vehicle.Ixx": 0.50, "vehicle.Iyy": 0.55, "hydro.K_p": -0.2, "hydro.M_q": -0.15,
             "hydro.K_p_absp": -2.0}
SYN_SEEDS = 20
SYN_DURATION = 20.0
K = 25  # samples (0.5 s at the trials' 50 Hz): the k-step-ahead prediction's horizon
SPEED_TRIAL = "traj014-2"  # 20.0 s
SPEED_REPEATS = 7


def _all():
    return [TRIALS / f"{t}.log.toml" for t in FIT + HELD_OUT + BASELINES]


def _cli(args: list[str]) -> None:
    from arvcas.cli import main

    print("arvcas " + " ".join(args), flush=True)
    rc = main(args)
    if rc != 0:
        sys.exit(f"arvcas {args[0]} failed with exit code {rc}")


def _rel(p: Path) -> str:
    """A path below the repository as the command is given it, relative to it (main() works there): no
    machine's path in any output; a path elsewhere as it is."""
    p = Path(p).resolve()
    return p.relative_to(ROOT).as_posix() if p.is_relative_to(ROOT) else str(p)


def sourced(out: Path) -> None:
    _cli(["validate", "--system", SYSTEM, *map(_rel, _all()), "--out", _rel(out / "sourced"), "--force",
          "--k", str(K), "--figures"])


def identify(out: Path) -> None:
    import contextlib
    import io

    buf = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf):
        _cli(["identify", "--system", SYSTEM, "--free", ",".join(FREE), "--signals", ",".join(SIGNALS),
              *[_rel(TRIALS / f"{t}.log.toml") for t in FIT], "--out", _rel(out / f"{SYSTEM}_identified.toml"),
              "--force"])
    text = buf.getvalue() + f"wall time {time.perf_counter() - t0:.1f} s\n"
    print(text)
    from arvcas.util import files

    files.write_text(out / "identify.log", text)


def identified(out: Path) -> None:
    _cli(["validate", "--system", _rel(out / f"{SYSTEM}_identified.toml"), *map(_rel, _all()), "--out",
          _rel(out / "identified"), "--force", "--k", str(K), "--figures"])


def step(out: Path) -> None:
    """The validation's plant step: 0.02 s (the logs' sample time) against 0.005 s."""
    import arvcas
    from arvcas.ident import logs, validate
    from arvcas.util import files

    system = arvcas.load_system(SYSTEM)
    rows = {}
    for p in _all():
        lg = logs.load_log(p, system.n_joints)
        a = validate.validate_log(system, lg)
        b = validate.validate_log(system, lg, h_max=0.005)
        rows[lg.name] = {s: float(np.max(np.abs(a.simulated[s] - b.simulated[s]))) for s in ("roll", "pitch", "z")}
        print(lg.name, rows[lg.name])
    worst = {s: max(r[s] for r in rows.values()) for s in ("roll", "pitch", "z")}
    doc = {"what": "max |simulated(h = log sample time 0.02 s) - simulated(h = 0.005 s)| per trial (rad, m)",
           "trials": rows, "worst": worst}
    files.write_text(out / "step.json", json.dumps(doc, indent=1) + "\n")


def synthetic(out: Path, seeds: int = SYN_SEEDS) -> None:
    """Identification from simulated trials with known parameters: recovery, coverage, the unidentifiable one."""
    import arvcas
    from arvcas.ident import identify as ident
    from arvcas.ident import logs
    from arvcas.ident import synthetic as syn
    from arvcas.ident.estimate import Z95
    from arvcas.util import files
    from arvcas.system import System

    model = arvcas.load_system(SYSTEM)
    truth = System(model.params.replace(SYN_TRUTH))
    import tempfile

    d = out / "synthetic"
    files.prepare_dir(d, "synthetic")
    work = Path(tempfile.mkdtemp(prefix="arvcas-synthetic-"))  # the simulated logs: regenerated, not kept
    tv = np.array([truth.params[n] for n in SYN_FREE])
    rows = []
    for seed in range(seeds):
        paths = [syn.write_trial(work / f"seed{seed}", f"syn{k}", truth, duration=SYN_DURATION, seed=1000 * seed + k,
                                 p=truth.params.vector()) for k in range(2)]
        lgs = logs.load_logs(paths, model.n_joints)
        t0 = time.perf_counter()
        est = ident.identify(model, lgs, SYN_FREE)
        dt = time.perf_counter() - t0
        rows.append({"seed": seed, "seconds": dt, "iterations": est.iterations, "s2": est.s2,
                     "values": list(map(float, est.values)), "std": [float(v) for v in est.std],
                     "identifiable": [bool(v) for v in est.identifiable], "unidentifiable": list(est.unidentifiable)})
        print(f"seed {seed}: {dt:.1f} s, {est.iterations} iterations, s2 {est.s2:.3f}", flush=True)
    vals = np.array([r["values"] for r in rows])
    sd = np.array([r["std"] for r in rows])
    ok = np.array([r["identifiable"] for r in rows])
    z = (vals - tv) / sd
    cover = np.abs(z) <= Z95
    per = {}
    for k, n in enumerate(SYN_FREE):
        if ok[:, k].all():
            per[n] = {"truth": float(tv[k]), "start": float(model.params[n]), "mean": float(vals[:, k].mean()),
                      "sd_of_estimates": float(vals[:, k].std(ddof=1)), "mean_stated_sd": float(sd[:, k].mean()),
                      "coverage": float(cover[:, k].mean()), "z_mean": float(z[:, k].mean()),
                      "z_sd": float(z[:, k].std(ddof=1))}
        else:
            per[n] = {"truth": float(tv[k]), "identifiable_in": int(ok[:, k].sum()), "of": len(rows)}
    idk = ok.all(axis=0)
    doc = {"system": SYSTEM, "free": list(SYN_FREE), "truth": SYN_TRUTH, "seeds": seeds, "duration_s": SYN_DURATION,
           "trials_per_seed": 2, "noise": syn.NOISE, "per_parameter": per,
           "coverage_all": float(cover[:, idk].mean()), "n_intervals": int(cover[:, idk].size), "runs": rows}
    files.write_text(d / "synthetic.json", json.dumps(doc, indent=1) + "\n")
    import shutil

    shutil.rmtree(work, ignore_errors=True)
    text = synthetic_markdown(doc)
    files.write_text(d / "README.md", text)
    print(text, end="")


def synthetic_markdown(doc: dict) -> str:
    """``synthetic/README.md`` from ``synthetic.json`` (benchmarks/render_results.py checks the committed page)."""
    import arvcas

    start = arvcas.load_system(doc["system"]).params
    noise, per = doc["noise"], doc["per_parameter"]
    lines = [f"# Identification from synthetic trials of `{doc['system']}` (known parameters)", "",
             f"`python benchmarks/validation.py --only synthetic`: {doc['seeds']} noise seeds, each two passive trials "
             f"of {doc['duration_s']:g} s (arm moving between random poses, vehicle released off its rest attitude) "
             f"simulated with the parameters below at a 0.0025 s RK4 step and written as logs with white sensor noise "
             f"stated in their mapping files (motion capture {noise['position'] * 1e3:g} mm and "
             f"{math.degrees(noise['attitude']):g} deg, gyro {noise['rate']:g} rad/s, encoders "
             f"{noise['joint']:g} rad); the identification starts from the shipped values.", "",
             "| parameter | start | truth | mean estimate | sd of estimates | mean stated sd | 95 % coverage | "
             "z mean, sd |", "|---|---|---|---|---|---|---|---|"]
    for n, v in per.items():
        if "coverage" in v:
            lines.append(f"| {n} | {v['start']:.5g} | {v['truth']:.5g} | {v['mean']:.5g} | {v['sd_of_estimates']:.3g} | "
                         f"{v['mean_stated_sd']:.3g} | {v['coverage']:.0%} | {v['z_mean']:+.2f}, {v['z_sd']:.2f} |")
        else:
            lines.append(f"| {n} | {start[n]:.5g} | {v['truth']:.5g} | reported unidentifiable in "
                         f"{v['of'] - v['identifiable_in']} of {v['of']} seeds | | | | |")
    lines += ["", f"All identifiable parameters together: {doc['coverage_all']:.1%} of {doc['n_intervals']} intervals "
                  f"cover the truth (95 % expected; the binomial 95 % range for this many is about "
                  f"{_binom_range(doc['n_intervals'])})."]
    return "\n".join(lines) + "\n"


def _binom_range(n: int) -> str:
    sd = math.sqrt(0.95 * 0.05 / n)
    return f"{max(0.0, 0.95 - 1.96 * sd):.1%}-{min(1.0, 0.95 + 1.96 * sd):.1%}"


# the figures the trials' authors report for their own simulator against the IMU (Kolano, Palmer, Davidson,
# OCEANS 2024, Table II; docs/systems/hinsdale_bluerov2_alpha5.md), and the data sheet's quasi-static baseline
AUTHORS = {"roll": 1.27, "pitch": 1.73, "roll_sd": 0.69, "pitch_sd": 0.82, "trials": 50}


def summary(out: Path) -> None:
    """results/validation/README.md from the JSON files the other parts wrote (no number typed by hand)."""
    from arvcas.util import files

    text = summary_markdown(out)
    files.write_text(out / "README.md", text)
    print(text, end="")


def summary_markdown(out: Path) -> str:
    """The text of ``summary``'s README.md (benchmarks/render_results.py checks the committed page against it)."""
    a = json.loads((out / "sourced" / "validation.json").read_text())["trials"]
    b = json.loads((out / "identified" / "validation.json").read_text())["trials"]
    st = json.loads((out / "step.json").read_text())
    syn = json.loads((out / "synthetic" / "synthetic.json").read_text())
    head = (out / "identify.log").read_text().split("identification of", 1)[1]
    head = re.sub(r"wrote \S*?(results/validation/)", r"wrote \1", head)  # the path relative to the repository
    deg = lambda v: f"{math.degrees(v):.2f}"  # noqa: E731
    role = {**{t: "fit" for t in FIT}, **{t: "held out" for t in HELD_OUT}, **{t: "baseline" for t in BASELINES}}
    lines = ["# The Hinsdale pool trials against arvcas", "",
             "`python benchmarks/validation.py` (code at the commit of this file). The vehicle is "
             f"`{SYSTEM}` (docs/systems/{SYSTEM}.md): every number from the trials' sources, nothing fitted. It is "
             "validated on the twelve shipped trials (`sourced/`), identified on six of them (`identify.log`, "
             f"`{SYSTEM}_identified.toml`) and validated again on all twelve (`identified/`); the three held-out "
             "trajectory trials and the three baselines were never fitted. Validation is simulation error: each "
             "trial simulated open loop over its whole length from its logged initial state, the arm on its "
             "logged trajectory, the thrusters off as in the pool. Attitude and rates are measured by the IMU "
             "(the authors' reference), depth by the motion capture.", "",
             "## Roll and pitch RMSE per trial (deg)", "",
             "| trial | role | s | roll, sourced | roll, identified | pitch, sourced | pitch, identified | depth RMSE (m), "
             "sourced / identified |", "|---|---|---|---|---|---|---|---|"]
    means = {}
    for t in FIT + HELD_OUT + BASELINES:
        ra, rb = a[t]["rmse"], b[t]["rmse"]
        lines.append(f"| {t} | {role[t]} | {a[t]['duration_s']:.1f} | {deg(ra['roll'])} | {deg(rb['roll'])} | "
                     f"{deg(ra['pitch'])} | {deg(rb['pitch'])} | {ra['z']:.3f} / {rb['z']:.3f} |")
        for k, v in (("roll_a", ra["roll"]), ("roll_b", rb["roll"]), ("pitch_a", ra["pitch"]),
                     ("pitch_b", rb["pitch"])):
            means.setdefault((role[t], k), []).append(math.degrees(v))
    lines += ["", "| mean over | roll, sourced | roll, identified | pitch, sourced | pitch, identified |",
              "|---|---|---|---|---|"]
    for r in ("fit", "held out", "baseline"):
        m = {k: sum(v) / len(v) for (rr, k), v in means.items() if rr == r}
        lines.append(f"| {r} trials | {m['roll_a']:.2f} | {m['roll_b']:.2f} | {m['pitch_a']:.2f} | {m['pitch_b']:.2f} |")
    lines += ["", f"The trials' authors report, for their own simulator against the same IMU, roll RMSE "
                  f"{AUTHORS['roll']} deg (sd {AUTHORS['roll_sd']}) and pitch {AUTHORS['pitch']} deg (sd "
                  f"{AUTHORS['pitch_sd']}) averaged over {AUTHORS['trials']} trials (Kolano, Palmer, Davidson, OCEANS "
                  f"2024, Table II); no per-trial figure is published. The plant step: 0.02 s (the logs' sample "
                  f"time) differs from 0.005 s by at most {math.degrees(st['worst']['roll']):.1e} deg in roll and "
                  f"{math.degrees(st['worst']['pitch']):.1e} deg in pitch on any trial (`step.json`).", "",
              *_engineers(out, a, b, role),
              "## The identification", "", "```", "identification of" + head.rstrip(), "```", "",
              *_where(out, a, b),
              *_speed(out),
              "## Synthetic truth", "",
              f"`synthetic/`: {syn['seeds']} noise seeds of two simulated {syn['duration_s']:g} s trials each, the "
              f"Hinsdale vehicle and arm with known parameters: {syn['coverage_all']:.1%} of {syn['n_intervals']} "
              f"95 % intervals cover the truth; `thrusters.T1.u_max` (thrusters off) is reported unidentifiable "
              f"(synthetic/README.md)."]
    return "\n".join(lines) + "\n"


def _speed(out: Path) -> list[str]:
    """The speed section from ``speed.json``."""
    d = json.loads((out / "speed.json").read_text())
    lines = ["## Speed", "", f"`speed.json` ({d['machine']}): {d['what']}. Wall time on a shared machine swings "
             "with its load; the CPU time of the process is the steadier measure.", "",
             "| step | CSV: wall best (s) | CSV: CPU (s) | ROS 2 bag: wall best (s) | ROS 2 bag: CPU (s) |",
             "|---|---|---|---|---|"]
    csv, bag = d["rows"]["csv"], d["rows"]["ros2 bag (mcap)"]
    for n, v in csv.items():
        w = bag.get(n)
        lines.append(f"| {n} | {v['best_s']:.3f} | {v['cpu_best_s']:.3f} | "
                     f"{'-' if w is None else format(w['best_s'], '.3f')} | "
                     f"{'-' if w is None else format(w['cpu_best_s'], '.3f')} |")
    return lines + [""]


def _engineers(out: Path, a: dict, b: dict, role: dict) -> list[str]:
    """FIT %, the k-step-ahead prediction and the residual tests per role and signal, sourced and identified."""
    import statistics

    doc = json.loads((out / "identified" / "validation.json").read_text())
    k = next(t["kstep"]["k"] for t in b.values())
    band = doc["definitions"]["resid"]
    med = lambda v: statistics.median(v) if v else float("nan")  # noqa: E731
    lines = ["## FIT %, k-step-ahead prediction and residual tests", "",
             f"The same trials as MATLAB's System Identification Toolbox would show them: FIT % = 100 (1 - ||y - y_hat|| "
             f"/ ||y - mean y||) of the open-loop simulation and of the {k}-step-ahead prediction ({k} samples, "
             f"{k / 50:g} s: the state restarted from the log every {k} samples as `compare(data, sys, {k})`; the "
             "unmeasured x, y are the simulation's, the body velocities u, v, w the simulation's corrected to the "
             "measured depth's rate of change), and the residual tests of `resid` on the open-loop residual "
             f"({band}). Medians over the trials of each role; `identified/validation.json` and "
             "`sourced/validation.json` hold every trial.", "",
             f"| role | signal | FIT % sim, sourced | FIT % sim, identified | FIT % {k}-step, sourced | "
             f"FIT % {k}-step, identified | autocorr. lags out, identified | cross-corr. lags out (worst input), "
             "identified |", "|---|---|---|---|---|---|---|---|"]
    for r in ("fit", "held out", "baseline"):
        ts = [t for t in FIT + HELD_OUT + BASELINES if role[t] == r]
        for s in ("roll", "pitch", "p", "q", "z"):
            fa = med([a[t]["fit"][s] for t in ts])
            fb = med([b[t]["fit"][s] for t in ts])
            ka = med([a[t]["kstep"]["fit"][s] for t in ts])
            kb = med([b[t]["kstep"]["fit"][s] for t in ts])
            au = med([b[t]["resid"][s]["auto_outside"] for t in ts])
            cr = med([max(b[t]["resid"][s]["cross_outside"].values()) for t in ts])
            lines.append(f"| {r} | {s} | {fa:.1f} | {fb:.1f} | {ka:.1f} | {kb:.1f} | {au:.0%} | {cr:.0%} |")
    # the prediction error against its horizon, on one held-out trial: what a restart from the log costs
    import arvcas
    from arvcas.ident import logs, plant, validate

    system = arvcas.load_system(out / f"{SYSTEM}_identified.toml")
    t = HELD_OUT[1]
    lg = logs.load_log(TRIALS / f"{t}.log.toml", system.n_joints)
    r = validate.validate_log(system, lg, k=k)
    hz = (np.arange(1, len(lg.t)) - 1) % k + 1
    grow = {}
    for s in ("roll", "p"):
        e = r.predicted[s][1:] - r.measured[s][1:]
        grow[s] = [math.degrees(math.sqrt(float(np.mean(e[hz == h] ** 2)))) for h in (1, 5, k)]
    worse = [(r, s) for r in ("fit", "held out", "baseline") for s in ("p", "q")
             if med([b[t]["kstep"]["fit"][s] for t in FIT + HELD_OUT + BASELINES if role[t] == r]) <
             med([b[t]["fit"][s] for t in FIT + HELD_OUT + BASELINES if role[t] == r])]
    auto_min = min(b[t]["resid"][s]["auto_outside"] for t in b for s in ("roll", "pitch", "p", "q", "z"))
    lines += ["", f"Restarting from the log removes the depth's drift (its k-step FIT % near 100) and improves roll "
                  f"and pitch, but the body rates are not always predicted better {k} samples ahead than by the "
                  f"open-loop simulation (identified: worse in {len(worse)} of the 6 role medians of p and q): each "
                  "restart places the model at the vehicle's measured attitude and rates, where its restoring and "
                  "damping moments differ from the vehicle's, and the rates' error grows with the horizon (held-out "
                  f"{t}, identified: p RMS error {grow['p'][0]:.2f}, {grow['p'][1]:.2f}, {grow['p'][2]:.2f} deg/s at "
                  f"1, 5, {k} samples ahead; roll {grow['roll'][0]:.3f}, {grow['roll'][1]:.3f}, {grow['roll'][2]:.3f} "
                  "deg). The open-loop simulation instead settles about the model's own equilibrium and its rates "
                  "stay small. The residual tests fail on every trial: "
                  + ("every" if auto_min == 1.0 else f"at least {auto_min:.0%} of the") + " autocorrelation lag "
                  "of roll, pitch, p, q and depth is outside the 99 % band (a white residual leaves about 1 %): "
                  f"the residuals persist over the {validate.RESID_LAGS} lags ({validate.RESID_LAGS / 50:g} s), model "
                  "error rather than sensor noise, as the intervals below say.", ""]
    return lines


def _where(out: Path, a: dict, b: dict) -> list[str]:
    """Where the model cannot follow the vehicle, with the measured figures that show it."""
    import arvcas
    from arvcas.ident import logs

    system = arvcas.load_system(SYSTEM)
    rise, drift, wmax = {}, {}, 0.0
    for t in FIT + HELD_OUT + BASELINES:
        lg = logs.load_log(TRIALS / f"{t}.log.toml", system.n_joints)
        wmax = max(wmax, math.degrees(float(np.max(np.abs(np.stack([lg.signals["p"], lg.signals["q"]]))))))
        rise[t] = -float(np.polyfit(lg.t, lg.signals["z"], 1)[0]) * 1e3  # mm/s, up
        drift[t] = (math.degrees(lg.signals["roll"][-1] - lg.signals["roll"][0]),
                    math.degrees(lg.signals["pitch"][-1] - lg.signals["pitch"][0]))
    fast = [v for t, v in rise.items() if v > 10]
    slow = {t: v for t, v in rise.items() if v <= 10}
    ident = arvcas.load_system(out / f"{SYSTEM}_identified.toml")
    base = arvcas.load_system(SYSTEM)
    ratio = {k: ident.params[f"vehicle.{k}"] / base.params[f"vehicle.{k}"] for k in ("Ixx", "Iyy")}
    return [
        "## Where the model cannot follow the vehicle", "",
        f"* **Depth.** The vehicle rises through every trial, but not at one rate: {min(fast):.0f}-{max(fast):.0f} mm/s "
        f"in {len(fast)} trials and " + ", ".join(f"{v:.0f} mm/s in {t}" for t, v in slow.items()) + " (a linear fit "
        "of the measured depth). One net buoyancy cannot give both; the tether, paid out by hand and with its own "
        "weight and drag, is the likely difference. Depth is therefore validated, not fitted (depth RMSE "
        f"{min(r['rmse']['z'] for r in b.values()):.2f}-{max(r['rmse']['z'] for r in b.values()):.2f} m over the "
        "trials); the model has no tether (docs/model.md §10).",
        "* **Slow attitude drift.** With the arm still, the baselines' roll and pitch drift as the vehicle rises ("
        + ", ".join(f"{t}: roll {drift[t][0]:+.2f}, pitch {drift[t][1]:+.2f} deg" for t in BASELINES) + ") while the "
        "model holds one equilibrium: a load that changes with depth (the tether again) rather than a parameter.",
        "* **Damping form.** The model starts each trial at the logged attitude, which is not its own equilibrium, and "
        "rocks about it with little damping (the figures of `identified/baseline*.png`), where the vehicle settles "
        "at once. " + (("The fit drives the quadratic pitch damping to its bound (zero) and keeps a small linear one: "
                        "the vehicle's damping at these small angular rates (at most "
                        f"{wmax:.1f} deg/s in any trial) is not the quadratic form of the BlueROV2 literature.")
                       if ident.params["hydro.M_q_absq"] == 0.0 else
                       f"Roll and pitch rates stay below {wmax:.1f} deg/s, where quadratic damping is small."),
        f"* **Inertia.** The identified roll and pitch inertias are {ratio['Ixx']:.1f} and {ratio['Iyy']:.1f} times "
        "the sources' (which already include an added inertia): the arm's and the tether's added mass, and the "
        "sources' added inertia, are the candidates; the trials do not separate them.",
        "* **Intervals.** The residuals persist over seconds (model error, not sensor noise), so the printed 95 % "
        "intervals are far too narrow: the held-out trials, not the intervals, measure the model. On synthetic "
        "trials, where the model is exact, the same intervals cover the truth at their stated rate (below).",
        "* **Heading, x, y.** Not mapped: the IMU's heading is arbitrary and the motion capture's horizontal frame is "
        "the pool's; the yaw of `validation.json` is compared from the logged start and drifts with the tether.", "",
    ]


def _bag(d: Path, trial: str) -> Path:
    """The trial's three CSV streams written as one ROS 2 bag (MCAP; sensor_msgs/Imu, PoseStamped, JointState
    stamped with the CSV times) and its mapping file: the same signals as the trial's own mapping."""
    import gzip

    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Imu, Pose, JS = T["sensor_msgs/msg/Imu"], T["geometry_msgs/msg/PoseStamped"], T["sensor_msgs/msg/JointState"]
    Hd, Tm, Q, V, P, Pt = (T[n] for n in ("std_msgs/msg/Header", "builtin_interfaces/msg/Time",
                                          "geometry_msgs/msg/Quaternion", "geometry_msgs/msg/Vector3",
                                          "geometry_msgs/msg/Pose", "geometry_msgs/msg/Point"))

    def rows(kind):
        with gzip.open(TRIALS / f"{trial}_{kind}.csv.gz", "rt") as f:
            head = f.readline().strip().split(",")
            a = np.loadtxt(f, delimiter=",", ndmin=2)
        return {h: a[:, i] for i, h in enumerate(head)}

    def header(t):
        sec = int(t)
        return Hd(stamp=Tm(sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id="")

    bag = d / f"{trial}_bag"
    cov = np.zeros(9)
    with Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        ci = w.add_connection("/imu", Imu.__msgtype__, typestore=ts)
        cm = w.add_connection("/mocap", Pose.__msgtype__, typestore=ts)
        cj = w.add_connection("/joints", JS.__msgtype__, typestore=ts)
        r = rows("imu")
        for i, t in enumerate(r["time_secs"]):
            m = Imu(header=header(t), orientation=Q(x=r["x_ori"][i], y=r["y_ori"][i], z=r["z_ori"][i], w=r["w_ori"][i]),
                    orientation_covariance=cov, angular_velocity=V(x=r["x_angvel"][i], y=r["y_angvel"][i],
                                                                   z=r["z_angvel"][i]),
                    angular_velocity_covariance=cov, linear_acceleration=V(x=0.0, y=0.0, z=0.0),
                    linear_acceleration_covariance=cov)
            w.write(ci, int(t * 1e9), ts.serialize_cdr(m, Imu.__msgtype__))
        r = rows("mocap")
        for i, t in enumerate(r["time_secs"]):
            m = Pose(header=header(t), pose=P(position=Pt(x=r["x_pose"][i], y=r["y_pose"][i], z=r["z_pose"][i]),
                                              orientation=Q(x=r["x_ori"][i], y=r["y_ori"][i], z=r["z_ori"][i],
                                                            w=r["w_ori"][i])))
            w.write(cm, int(t * 1e9), ts.serialize_cdr(m, Pose.__msgtype__))
        r = rows("joint_states")
        ax = ("axis_e_pos", "axis_d_pos", "axis_c_pos", "axis_b_pos")
        for i, t in enumerate(r["time_secs"]):
            m = JS(header=header(t), name=list(ax), position=np.array([r[a][i] for a in ax]), velocity=np.zeros(4),
                   effort=np.zeros(4))
            w.write(cj, int(t * 1e9), ts.serialize_cdr(m, JS.__msgtype__))
    text = (TRIALS / f"{trial}.log.toml").read_text()
    head = text[text.index("[log]"):text.index("[[stream]]")]
    mapping = d / f"{trial}.log.toml"
    mapping.write_text(head + f'''bag = "{bag.name}"

[[stream]]
topic = "/imu"
time = "header.stamp"
world = "nwu"
body = "flu"
quaternion = {{ columns = ["orientation.x", "orientation.y", "orientation.z", "orientation.w"] }}
angular_velocity = {{ columns = ["angular_velocity.x", "angular_velocity.y", "angular_velocity.z"], unit = "rad/s" }}

[[stream]]
topic = "/mocap"
time = "header.stamp"
world = "nwu"
depth = {{ columns = ["pose.position.z"], unit = "m" }}

[[stream]]
topic = "/joints"
time = "header.stamp"
[stream.joints]
q1 = {{ column = "position[0]" }}
q2 = {{ column = "position[1]" }}
q3 = {{ column = "position[2]" }}
q4 = {{ column = "position[3]" }}
''')
    return mapping


def _quiet(args: list[str]) -> None:
    import contextlib
    import io

    from arvcas.cli import main

    with contextlib.redirect_stdout(io.StringIO()):
        if main(args) != 0:
            sys.exit(f"arvcas {' '.join(args)} failed")


def speed(out: Path) -> None:
    """Where the time of validating one 20 s trial goes, from its CSV logs and from a ROS 2 bag of them."""
    import platform
    import tempfile

    import arvcas
    from arvcas.experiments import validation as V
    from arvcas.ident import logcache, logs, plant, validate
    from arvcas.util import files
    from arvcas.io import style

    system = arvcas.load_system(SYSTEM)
    work = Path(tempfile.mkdtemp(prefix="arvcas-speed-"))
    sources = {"csv": TRIALS / f"{SPEED_TRIAL}.log.toml", "ros2 bag (mcap)": _bag(work, SPEED_TRIAL)}

    def best(fn):
        """best wall time, median wall time, best CPU time of this process (s): the machine may be shared"""
        fn()  # the first run compiles (or loads the compiled library) and warms the caches
        ts, cs = [], []
        for _ in range(SPEED_REPEATS):
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            ts.append(time.perf_counter() - t0)
            cs.append(time.process_time() - c0)
        return {"best_s": min(ts), "median_s": float(np.median(ts)), "cpu_best_s": min(cs)}

    rows = {}
    for kind, path in sources.items():
        lg = logs.load_log(path, system.n_joints)
        x0 = validate.initial_state(lg)
        pl = plant.LogPlant(system, m=1)
        p = system.params.vector()
        data = plant.sample_inputs(lg, system, 1)
        X = plant.simulate(pl, lg, x0, p, data=data)
        meas = {s: lg.signals[s] - X[:, i] for i, s in enumerate(logs.SIGNALS) if s in lg.signals}
        r = validate.validate_log(system, lg, k=K)
        phases = {
            "read the log": lambda: logs.load_log(path, system.n_joints),
            "open-loop simulation (inputs included)": lambda: plant.simulate(pl, lg, x0, p,
                                                                              data=plant.sample_inputs(lg, system, 1)),
            f"{K}-step prediction (restart states included)": lambda: validate.predict(
                pl, lg, p, K, validate.logged_states(lg, X), data),
            "residual tests": lambda: validate.residual_tests(meas, validate.drive_inputs(lg)),
            "validate_log, everything": lambda: validate.validate_log(system, lg, k=K),
            "read the log + validate_log": lambda: validate.validate_log(system, logs.load_log(path, system.n_joints),
                                                                         k=K),
            "read the log from the parsed-log cache": lambda: logcache.load_log(path, system.n_joints),
            "cached read + validate_log": lambda: validate.validate_log(
                system, logcache.load_log(path, system.n_joints), k=K),
            "arvcas validate, no figures (in process)": lambda: _quiet(
                ["validate", "--system", SYSTEM, str(path), "--out", str(work / "cli"), "--force", "--k", str(K)]),
        }
        rows[kind] = {n: best(f) for n, f in phases.items()}
        if kind == "csv":
            import matplotlib.pyplot as plt

            def fig():
                f = V.plot_trial(r, "speed")
                style.write_figure(work / "fig.png", f)
                plt.close(f)

            rows[kind]["one figure (png)"] = best(fig)
        print(kind, json.dumps(rows[kind], indent=1), flush=True)
    import shutil

    shutil.rmtree(work, ignore_errors=True)
    doc = {"what": f"seconds to validate trial {SPEED_TRIAL} ({SYSTEM}, 20.0 s at 50 Hz, k = {K}) once compiled: "
                   f"best and median of {SPEED_REPEATS} runs in one process",
           "machine": f"{platform.machine()}, {os.cpu_count()} cores (shared), Python {platform.python_version()}",
           "trial": SPEED_TRIAL, "k": K, "rows": rows}
    files.write_text(out / "speed.json", json.dumps(doc, indent=1) + "\n")


PARTS = {"sourced": sourced, "identify": identify, "identified": identified, "step": step, "synthetic": synthetic,
         "speed": speed, "summary": summary}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "validation")
    ap.add_argument("--only", choices=tuple(PARTS), action="append")
    a = ap.parse_args(argv)
    a.out = a.out.resolve()
    os.chdir(ROOT)  # the commands are given paths relative to the repository (_rel)
    from arvcas.util import files

    files.prepare_dir(a.out, "--out")
    for name in a.only or PARTS:
        t0 = time.perf_counter()
        PARTS[name](a.out)
        print(f"[{name}: {time.perf_counter() - t0:.1f} s]", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
