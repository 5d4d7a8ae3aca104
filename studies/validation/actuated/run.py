"""The actuated synthetic identification study: which costs recover which parameters of a BlueROV2 driven by PWM.

    python studies/validation/actuated/run.py               # everything -> results/validation/actuated/
    python studies/validation/actuated/run.py --only readme # README.md from the committed actuated.json

The truth is the shipped ``bluerov2`` (six T200s, every number from its sources). :data:`TRIALS` trials of
:data:`DURATION` s are simulated (``arvcas.ident.synthetic.write_trial``): each thruster sent PWM steps
(surge, sway, heave, roll and yaw demands in turn, allocated and mapped through the T200 table and its lag),
seen as an owner's vehicle logs itself (attitude and gyro of the autopilot, a depth sensor; white noise at
the levels of ``arvcas.ident.synthetic.NOISE``), once as is and once with a heave force the model lacks
(:data:`DRIFT_N`: a tether paid out or a buoyancy change, ramping from zero over each trial, a different
size per trial). From a start that an owner would have (:data:`START`: the shipped values, off by the
factors given), :data:`FREE` is identified with ``arvcas identify`` as a user runs it, once per cost
(:data:`COSTS`: simulation error, and the :data:`HORIZON`-step prediction error), with Fisher and
leave-one-trial-out intervals (``--intervals jackknife --json``). ``actuated.json`` holds every number;
``README.md`` is rendered from it (``--only readme``). Seeded: the same code gives the same trials and,
on the same machine, the same estimates.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
OUT = ROOT / "results" / "validation" / "actuated"
SYSTEM = "bluerov2"
TRIALS = 3
DURATION = 20.0  # s per trial
SEED = 0  # trial k's seed is SEED + k: its excitation, its heading, its noise
DRIFT_N = (1.5, 2.0, 2.5)  # N: trial k's unmodelled heave force at its end (body z, down), ramping from zero
# the parameters an owner of a six-thruster BlueROV2 would free (its mass is weighed, so held), and where the
# fit starts: the shipped value times this factor (volume: plus a neutral-buoyancy guess, 0.1 kg more water)
FREE = ("hydro.Z_w", "hydro.Z_w_absw", "hydro.X_u", "hydro.X_u_absu", "hydro.N_r_absr", "hydro.Z_wdot",
        "hydro.N_rdot", "vehicle.zB", "vehicle.volume")
START = {"hydro.Z_w": 2.0, "hydro.Z_w_absw": 0.5, "hydro.X_u": 2.0, "hydro.X_u_absu": 0.5, "hydro.N_r_absr": 2.0,
         "hydro.Z_wdot": 0.7, "hydro.N_rdot": 1.5, "vehicle.zB": 0.6, "vehicle.volume": 1.0 + 1e-4 / 0.0134}
HORIZON = 25  # samples of the prediction error (0.5 s at 50 Hz)
COSTS = (("simulation", None), ("prediction", HORIZON))
CASES = (("no drift", False), ("drift", True))
MAX_ITER = 100


def start_system(work: Path, truth) -> Path:
    """The starting system file: the shipped file with :data:`START`'s values (no defaults: a vehicle only)."""
    import tomlkit

    doc = tomlkit.parse(Path(truth.path).read_text(encoding="utf-8"))
    doc.pop("defaults", None)
    doc["system"]["name"] = f"{SYSTEM}_start"
    for n, f in START.items():
        table, key = n.split(".")
        entry = doc[table][key]
        entry["value"] = float(f"{truth.params[n] * f:.6g}")
        entry["source"] = f"the study's starting guess: {SYSTEM}'s value times {f:.6g} (studies/validation/actuated)"
    path = work / f"{SYSTEM}_start.toml"
    path.write_text(tomlkit.dumps(doc), encoding="utf-8")
    return path


def write_trials(work: Path, truth, drift: bool, trials: int = TRIALS, duration: float = DURATION) -> list[Path]:
    """The trials of one case: driven by PWM, seen by the vehicle's sensors, with or without the drift."""
    from arvcas.ident import synthetic as syn

    paths = []
    for k in range(trials):
        ex = syn.excitation(truth, duration + 0.5, SEED + k)
        paths.append(syn.write_trial(work / ("drift" if drift else "clean"), f"dive{k + 1}", truth,
                                     duration=duration, seed=SEED + k, excite=ex,
                                     drift=DRIFT_N[k % len(DRIFT_N)] if drift else 0.0, sensors="vehicle"))
    return paths


def depth_drift(work: Path, n: int) -> list[float]:
    """How far the drift moved each trial's depth by its end (m): the two cases' logged depths, last second."""
    from arvcas.ident import logs

    out = []
    for k in range(n):
        a, b = (logs.load_log(work / c / f"dive{k + 1}.log.toml", n_joints=0) for c in ("drift", "clean"))
        out.append(float((a.signals["z"][-50:] - b.signals["z"][-50:]).mean()))
    return out


def identify(system: Path, paths: list[Path], out: Path, free=FREE, cost: str = "simulation",
             horizon: int | None = None, jackknife: bool = True, max_iter: int = MAX_ITER) -> dict:
    """``arvcas identify`` as a user runs it (its console entry point, in a child process): its ``--json``."""
    argv = ["identify", "--system", str(system), "--free", ",".join(free), *map(str, paths), "--out",
            str(out.with_suffix(".toml")), "--json", str(out.with_suffix(".json")), "--cost", cost,
            "--max-iter", str(max_iter), "--threads", "1"]
    argv += ["--horizon", str(horizon)] if horizon else []
    argv += ["--intervals", "jackknife"] if jackknife else []
    code = "import sys; from arvcas.cli import main; sys.exit(main(sys.argv[1:]))"
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"arvcas {' '.join(argv)} failed ({r.returncode}):\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
    doc = json.loads(out.with_suffix(".json").read_text())
    doc["wall_s"] = time.perf_counter() - t0
    work = str(out.parent.parent) + "/"  # the paths as a user in the work folder writes them (no machine paths)
    doc["command"] = "arvcas " + " ".join(a.replace(work, "").replace(str(out.parent) + "/", "") for a in argv)
    return doc


def rows(fit: dict, truth: dict) -> dict:
    """Per parameter: truth, start, estimate, error (%), intervals and whether they cover the truth, flags."""
    out = {}
    for n, p in fit["parameters"].items():
        t = truth[n]

        def covers(iv):
            return None if iv is None else bool(iv[0] <= t <= iv[1])

        out[n] = {"truth": t, "start": p["initial"], "estimate": p["estimate"],
                  "error_pct": 100.0 * (p["estimate"] - t) / abs(t), "fisher": p["fisher"], "fisher_covers":
                  covers(p["fisher"]), "jackknife": p["jackknife"], "jackknife_covers": covers(p["jackknife"]),
                  "at_bound": p["at_bound"], "flagged": bool(p["flags"]), "unit": p["unit"]}
    return out


def git_state() -> dict:
    def run(*a):
        return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout.strip()

    return {"commit": run("rev-parse", "HEAD"), "clean": run("status", "--porcelain", "--", "arvcas", "studies") == ""}


def study(out: Path = OUT, work: Path | None = None, jackknife: bool = True) -> dict:
    import arvcas

    t0 = time.perf_counter()
    state = git_state()  # the code that runs: its commit, and whether arvcas/ and studies/ are committed
    truth = arvcas.load_system(SYSTEM)
    tv = {n: float(truth.params[n]) for n in FREE}
    own = work is None
    work = Path(tempfile.mkdtemp(prefix="arvcas-actuated-")) if own else work
    work.mkdir(parents=True, exist_ok=True)
    try:
        start = start_system(work, truth)
        cases = {}
        paths = {drift: write_trials(work, truth, drift) for _, drift in CASES}
        jobs = {(case, cost + (f"-{h}" if h else "")): (drift, cost, h) for case, drift in CASES for cost, h in COSTS}

        def one(key):
            drift, cost, h = jobs[key]
            fit = identify(start, paths[drift], work / "fits" / f"{'drift' if drift else 'clean'}-{key[1]}",
                           cost=cost, horizon=h, jackknife=jackknife)
            print(f"{key[0]}, {key[1]}: {fit['status']}, {fit['iterations']} iterations, {fit['wall_s']:.0f} s",
                  flush=True)
            return fit

        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(len(jobs)) as pool:  # one child process per fit, at once
            done = dict(zip(jobs, pool.map(one, jobs)))
        for (case, name), fit in done.items():
            entry = {k: fit[k] for k in ("cost", "horizon", "status", "iterations", "seconds", "wall_s", "s2", "rms",
                                         "unidentifiable", "correlated", "command")}
            cases.setdefault(case, {})[name] = entry | {"parameters": rows(fit, tv)}
        drifts = depth_drift(work, TRIALS)
    finally:
        if own:
            shutil.rmtree(work, ignore_errors=True)
    from arvcas.ident.synthetic import NOISE, WRENCH_DEMAND

    doc = {"system": SYSTEM, "trials": TRIALS, "duration_s": DURATION, "seed": SEED, "free": list(FREE),
           "truth": tv, "start_factor": START, "drift_force_N": list(DRIFT_N), "drift_depth_m": drifts,
           "noise": NOISE, "wrench_demand": list(WRENCH_DEMAND), "horizon": HORIZON, "max_iter": MAX_ITER,
           "intervals": "fisher and leave-one-trial-out" if jackknife else "fisher",
           "cases": cases, "seconds": time.perf_counter() - t0, **state}
    out.mkdir(parents=True, exist_ok=True)
    (out / "actuated.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return doc


def _iv(iv, unit_scale=1.0) -> str:
    return "-" if iv is None else f"[{iv[0]:.4g}, {iv[1]:.4g}]"


def _cover(c) -> str:
    return "-" if c is None else ("yes" if c else "**no**")


def readme(out: Path = OUT) -> str:
    """README.md from ``actuated.json`` (nothing recomputed)."""
    d = json.loads((out / "actuated.json").read_text())
    nz = d["noise"]
    lines = [
        "# Actuated synthetic identification: which costs recover which parameters", "",
        f"`python studies/validation/actuated/run.py` at commit `{d['commit'][:12]}` "
        f"({'clean tree' if d['clean'] else 'tree with uncommitted changes'}); {d['seconds'] / 60:.0f} min on "
        f"the machine that made it. This file is rendered from `actuated.json` (`--only readme`). How to read "
        f"it, and what it means for a user with PWM logs: docs/identification.md, \"An actuated study\".", "",
        "## The trials", "",
        f"Truth: the shipped `{d['system']}` (six T200s, ArduSub's vectored frame). {d['trials']} trials of "
        f"{d['duration_s']:g} s (seeds {d['seed']}..{d['seed'] + d['trials'] - 1}), each thruster sent PWM "
        f"steps: wrench demands of 0.3..1 times "
        f"{', '.join(f'{v:g}' for v in d['wrench_demand'])} (N, N m: surge, sway, heave, roll, pitch, yaw) in "
        f"surge, sway, heave, roll and yaw in turn (pitch is not actuated), held 0.6..2 s each with "
        f"alternating signs, allocated to the thrusters and mapped to PWM through the inverse of the 16 V T200 "
        f"table; the plant drives the T200 lag (0.0167 s) and table with them "
        f"(`arvcas.ident.synthetic.excitation`, `write_trial`). Logged as an owner's vehicle logs itself: "
        f"attitude (roll, pitch, yaw; white noise {math.degrees(nz['attitude']):.2g} deg), gyro "
        f"({nz['rate']:g} rad/s) at 100 Hz, depth ({1000 * nz['depth']:g} mm) at 50 Hz, the PWM at 50 Hz; no "
        f"position or velocity. The noise levels are assumptions (docs/identification.md).", "",
        f"**The drift.** In the second case each trial also carries a heave force the model lacks (body z, "
        f"down), ramping from 0 to {', '.join(f'{v:g}' for v in d['drift_force_N'])} N over the trial (a tether "
        f"paid out, a buoyancy change), not in the log: it moves the trials' depth by "
        f"{', '.join(f'{v:.2f}' for v in d['drift_depth_m'])} m by their end (against the same trial without "
        f"it).", "",
        f"**The fit.** `arvcas identify` from a start of the shipped values times "
        f"{', '.join(f'{n.split(chr(46))[1]} x{f:.4g}' for n, f in d['start_factor'].items())}, "
        f"every measured signal fitted with the noise the logs state, "
        + ("`--intervals jackknife` (Fisher and leave-one-trial-out 95 % intervals)"
           if d.get("intervals", "fisher and leave-one-trial-out") != "fisher" else
           "Fisher 95 % intervals only (`--intervals fisher`: this run left out the leave-one-trial-out refits)")
        + f", at most {d['max_iter']} iterations; the costs: simulation error and the {d['horizon']}-step "
        f"(0.5 s) prediction error.", ""]
    for case, fits in d["cases"].items():
        for name, f in fits.items():
            lines += [f"## {case}, {name.replace('-', ' (horizon ')}{')' if f['horizon'] else ''} error", "",
                      f"IPOPT: {f['status']}, {f['iterations']} iterations; {f['wall_s']:.0f} s (the command, "
                      f"with any leave-one-trial-out refits, four at once); residual variance factor s^2 = "
                      f"{f['s2']:.3g} (1 when the model follows the data to the stated noise).", "",
                      "| parameter | truth | start | estimate | error | Fisher 95 % | covers | leave-one-out 95 % | "
                      "covers | flag |", "|---|---|---|---|---|---|---|---|---|---|"]
            for n, r in f["parameters"].items():
                flag = "at bound" if r["at_bound"] else "flagged" if r["flagged"] else ""
                lines.append(f"| {n} | {r['truth']:.4g} | {r['start']:.4g} | {r['estimate']:.4g} | "
                             f"{r['error_pct']:+.1f} % | {_iv(r['fisher'])} | {_cover(r['fisher_covers'])} | "
                             f"{_iv(r['jackknife'])} | {_cover(r['jackknife_covers'])} | {flag} |")
            if f["unidentifiable"]:
                lines += ["", "Not identifiable: " + "; ".join(f["unidentifiable"])]
            lines.append("")
    lines += _summary(d)
    text = "\n".join(lines)
    (out / "README.md").write_text(text, encoding="utf-8")
    return text


def _summary(d: dict) -> list[str]:
    """Which cost recovers which parameter: within 10 % of the truth and covered by its leave-one-out interval."""
    names = list(d["cases"][next(iter(d["cases"]))])
    head = [f"{c}, {n}" for c in d["cases"] for n in names]
    out = ["## Which costs recover which parameters", "",
           "Error of the estimate against the truth; **bold** where it is within 10 % of the truth and its "
           "interval covers it (the leave-one-trial-out interval where it was run, else the Fisher one).", "",
           "| parameter | " + " | ".join(head) + " |", "|---|" + "---|" * len(head)]
    for p in d["free"]:
        cells = []
        for c in d["cases"]:
            for n in names:
                r = d["cases"][c][n]["parameters"][p]
                s = f"{r['error_pct']:+.0f} %"
                ok = r["jackknife_covers"] if r["jackknife_covers"] is not None else r["fisher_covers"]
                cells.append(f"**{s}**" if abs(r["error_pct"]) <= 10 and ok else s)
        out.append(f"| {p} | " + " | ".join(cells) + " |")
    cov = {}
    for c in d["cases"]:
        for n in names:
            ps = d["cases"][c][n]["parameters"].values()
            for kind in ("fisher", "jackknife"):
                v = [r[f"{kind}_covers"] for r in ps if r[f"{kind}_covers"] is not None]
                cov[(c, n, kind)] = f"{sum(v)} of {len(v)}"
    out += ["", "Intervals that cover the truth:", "", "| case, cost | Fisher | leave-one-trial-out |", "|---|---|---|"]
    out += [f"| {c}, {n} | {cov[(c, n, 'fisher')]} | "
            f"{cov[(c, n, 'jackknife')] if d.get('intervals') != 'fisher' else 'not run'} |"
            for c in d["cases"] for n in names]
    return out + [""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("study", "readme"), default=None)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--work", type=Path, default=None, help="keep the trials and fits here (default: a temporary)")
    ap.add_argument("--intervals", choices=("fisher", "jackknife"), default="jackknife",
                    help="jackknife (default): also the leave-one-trial-out intervals, three refits per fit")
    a = ap.parse_args(argv)
    if a.only in (None, "study"):
        study(a.out, a.work, a.intervals == "jackknife")
    if a.only in (None, "readme"):
        print(readme(a.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
