"""Write results/ardusub/identified/README.md from the committed files of this folder (front.h5, compare.txt,
the knee's and the better member's .param files) and of the shipped BlueROV2 Heavy study beside it
(results/ardusub/: its ardusub front and knee .param); ArduSub's defaults and ranges from
arvcas/data/ardusub_params.toml; what it shares with that study's page in ../page.py. Run from the repository root:

    python results/ardusub/identified/render.py
"""

from __future__ import annotations

import importlib.util
import json
import re
import tomllib
from pathlib import Path

import numpy as np

from arvcas.controllers import ardusub
from arvcas.io.ardusub_params import read_param_file
from arvcas.tuning import checkpoint as ck
from arvcas.tuning.front import read_front, system_params

HERE = Path(__file__).resolve().parent
HEAVY = HERE.parent  # the shipped BlueROV2 Heavy study (results/ardusub/)
ROOT = HERE.parents[2]
SYSTEM = "hinsdale_bluerov2_alpha5_identified_t200"
PARAM = HERE / "knee" / f"{SYSTEM}_ardusub.param"
BETTER = HERE / "better_than_defaults" / f"{SYSTEM}_ardusub.param"
HEAVY_PARAM = HEAVY / "knee" / "bluerov2_heavy_ardusub.param"
# (label, unit, the value from a system's parameters by name): what sets the attitude and depth loops' plant
PHYSICS = (
    ("mass", "kg", lambda d: d["vehicle.m"]),
    ("buoyancy - weight of the vehicle body (an arm adds its links')", "N",
     lambda d: d["env.rho"] * d["env.g"] * d["vehicle.volume"] - d["vehicle.m"] * d["env.g"]),
    ("zG - zB (metacentric height, level)", "m", lambda d: d["vehicle.zG"] - d["vehicle.zB"]),
    ("heave mass + added mass", "kg", lambda d: d["vehicle.m"] - d.get("hydro.Z_wdot", 0.0)),
    ("heave damping Z_w, Z_w_absw", "N s/m, N s^2/m^2", lambda d: (d.get("hydro.Z_w", 0.0), d.get("hydro.Z_w_absw", 0.0))),
    ("roll inertia + added", "kg m^2", lambda d: d["vehicle.Ixx"] - d.get("hydro.K_pdot", 0.0)),
    ("roll damping K_p, K_p_absp", "N m s, N m s^2", lambda d: (d.get("hydro.K_p", 0.0), d.get("hydro.K_p_absp", 0.0))),
    ("pitch inertia + added", "kg m^2", lambda d: d["vehicle.Iyy"] - d.get("hydro.M_qdot", 0.0)),
    ("pitch damping M_q, M_q_absq", "N m s, N m s^2", lambda d: (d.get("hydro.M_q", 0.0), d.get("hydro.M_q_absq", 0.0))),
    ("yaw inertia + added", "kg m^2", lambda d: d["vehicle.Izz"] - d.get("hydro.N_rdot", 0.0)),
    ("yaw damping N_r, N_r_absr", "N m s, N m s^2", lambda d: (d.get("hydro.N_r", 0.0), d.get("hydro.N_r_absr", 0.0))),
)


_spec = importlib.util.spec_from_file_location("arvcas_results_ardusub_page", HEAVY / "page.py")
page = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(page)
g, improvement, DOFS = page.g, page.improvement, page.DOFS


def ident_interval(name: str) -> str:
    """The 95 % interval ``[lo, hi]`` the identification printed for ``name`` (the identified file's header)."""
    text = (ROOT / "results" / "validation" / "hinsdale_bluerov2_alpha5_identified.toml").read_text()
    return re.search(rf"^# {re.escape(name)}\s+\S+\s+\S+\s+(\[[^\]]+\])", text, flags=re.M).group(1)


def oscillation(e: np.ndarray, h: float) -> tuple[float, float, float]:
    """A growing oscillation's period (s: twice the mean time between sign changes), the median ratio of each
    half-swing's peak |e| to the previous one's, and the first full half-swing's peak."""
    cross = np.flatnonzero(np.diff(np.sign(e)) != 0) + 1
    peaks = np.array([np.abs(e[a:b]).max() for a, b in zip(cross[:-1], cross[1:])])
    return 2 * h * float(np.mean(np.diff(cross))), float(np.median(peaks[1:] / peaks[:-1])), float(peaks[0])


def markdown() -> str:
    """README.md's text, from the committed files (benchmarks/render_results.py checks it)."""
    fa, fh = read_front(HERE / "front.h5"), read_front(HEAVY / "ardusub" / "front.h5")
    ca_, ch = ck.read_checkpoint(HERE / "front.h5"), ck.read_checkpoint(HEAVY / "ardusub" / "front.h5")
    ex = page.exports(HERE, PARAM, BETTER, fa)
    table, knee, better, fb, ib = ex.table, ex.knee, ex.better, ex.factor, ex.member
    heavy = read_param_file(HEAVY_PARAM)
    better_h = read_param_file(HEAVY / "better_than_defaults" / "bluerov2_heavy_ardusub.param")
    k, kh = fa.knee(), fh.knee()
    d, dh = fa.table2_F, fh.table2_F
    L = []
    w = L.append
    w("# ArduSub's own controller tuned for the identified Hinsdale BlueROV2")
    w("")
    w("*Written by `results/ardusub/identified/render.py` from the files of this folder and of the BlueROV2 Heavy")
    w("study beside it (`results/ardusub/`); every number below is read from them or from")
    w("`arvcas/data/ardusub_params.toml`.*")
    w("")
    w("```bash")
    w("python studies/systems/hinsdale_t200.py --check")
    w("arvcas tune studies/ardusub_identified.toml --out results/ardusub/identified")
    w("cd results/ardusub")
    w("arvcas compare identified ardusub --ref 1,5 --allow-model-change --plot identified/fronts.png > identified/compare.txt")
    w("arvcas export-controller identified/knee --front identified --member knee --format ardusub-params")
    w(f"arvcas export-controller identified/better_than_defaults --front identified --member {ib} --format ardusub-params")
    w("cd ../.. && python results/ardusub/identified/render.py")
    w("```")
    w("")
    w("The same study as the shipped BlueROV2 Heavy's ([../README.md](../README.md), `studies/ardusub.toml`): the")
    w("same scenario, objectives, normalisation, ArduSub ranges and search, on another vehicle: the BlueROV2 +")
    w("Reach Alpha 5 of Oregon State University's Hinsdale pool trials, whose hull was identified from six of")
    w("those trials ([../../validation/README.md](../../validation/README.md), docs/identification.md).")
    w("")
    w("## What was tuned, on what")
    w("")
    w(f"- **System** `{SYSTEM}` (`studies/systems/{SYSTEM}.toml`, written by `studies/systems/hinsdale_t200.py`):")
    w("  `results/validation/hinsdale_bluerov2_alpha5_identified.toml` unchanged (its centre of buoyancy, roll and")
    w("  pitch inertia and roll and pitch damping identified; every other number sourced from the trials' own")
    w("  simulator, docs/systems/hinsdale_bluerov2_alpha5.md), with the T200 thruster dynamics of the shipped")
    w("  BlueROV2 Heavy added (Blue Robotics' 16 V table, a 0.0167 s lag): ArduSub's law sends PWM and needs a")
    w("  PWM command map, which the identified file's instantaneous thrusters lack (the `ardusub` law refuses a")
    w("  system without one).")
    w("- **Its thrusters are not the tested vehicle's.** The trials' BlueROV2 had six thrusters, switched off")
    w("  during the trials; the system file's eight are its stand-in BlueROV2 Heavy retrofit (data sheet §6). They")
    w("  are ArduSub's vectored-6DOF motors 1-8 in the file's order, each along ArduSub's motor direction (no")
    w("  PWM mirrored: `MOT_n_DIRECTION = 1` on all eight; on the shipped Heavy it is -1 on all eight). So this is")
    w("  the identified hull and arm with a Heavy's thrusters: the gains below are for that vehicle.")
    w("- **The arm** is held at its stow pose (the system file's `[arm.stow]`, the trials' home pose): the")
    w("  scenario moves no joint. The law controls the vehicle only; the arm's weight and buoyancy at that pose")
    w("  and the hull's net buoyancy (below) are what ArduSub's integrators must hold (the file models its")
    w("  ballast: no arvcas trim).")
    w("- **Scenario** `studies/scenarios/bluerov2_tank_alt_hold.toml`, as the Heavy study: 60 s in a tank, no")
    w("  current, no tether, the slow disturbance, the position limit at 20 m (ALT_HOLD holds no horizontal")
    w("  position). **Sensor noise: the BlueROV2's** (depth 5 mm, roll and pitch 0.2 deg, heading 1 deg, body")
    w("  rates 0.005 rad/s, the scenario's): the Hinsdale system file states none of its own.")
    w("- **Objectives**: CHAT and RMSE over depth, roll, pitch and yaw, normalised by the study's given values")
    w("  (RMSE in units of the sensor noise, CHAT in N and N m per sample), as the Heavy study: the two fronts")
    w("  share their axes.")
    w(f"- **Search**: NSGA-II, population {fa.population_F.shape[0]}, {fa.n_gen} generations ({fa.n_eval} runs), "
      f"one noise draw (seed {int(fa.draw_seeds[0])}), ArduSub's defaults in the first population; only `ardusub` "
      "(the proposed law, AGSTA and PID have no default gains for this system). Time in the search "
      f"(history/elapsed_s, a shared two-core machine, two threads, the build not counted): "
      f"{fa.history['elapsed_s'][-1]:.0f} s.")
    w("")
    w("## ArduSub's defaults on this vehicle")
    w("")
    w("| run | " + " | ".join(f"CHAT {x}" for x in DOFS[2:]) + " | " + " | ".join(f"RMSE {x}" for x in DOFS[2:])
      + " | f_chat | f_rmse |")
    w("|---|" + "---|" * 10)
    rows = [("identified Hinsdale, defaults", ca_.table2_chat[0], ca_.table2_rmse[0], d),
            ("identified Hinsdale, knee", fa.chat[0, k], fa.rmse[0, k], fa.F[k]),
            (f"identified Hinsdale, better than defaults (member {ib})", fa.chat[0, ib], fa.rmse[0, ib], fa.F[ib]),
            ("BlueROV2 Heavy, defaults", ch.table2_chat[0], ch.table2_rmse[0], dh),
            ("BlueROV2 Heavy, knee", fh.chat[0, kh], fh.rmse[0, kh], fh.F[kh])]
    for name, c_, r_, f_ in rows:
        w(f"| {name} | " + " | ".join(g(v) for v in c_[2:]) + " | " + " | ".join(g(v) for v in r_[2:])
          + f" | {g(f_[0])} | {g(f_[1])} |")
    w("")
    w("CHAT in N (depth) and N m (roll, pitch, yaw) per sample, RMSE in m and rad. ")
    conv = bool(np.isfinite(d).all())
    w(("ArduSub's defaults hold this vehicle: the run ends without divergence. " if conv else
       "**ArduSub's defaults diverge on this vehicle.** ")
      + f"Against the Heavy at the same defaults the RMSE is {ca_.table2_rmse[0][2] / ch.table2_rmse[0][2]:.2f}, "
      f"{ca_.table2_rmse[0][3] / ch.table2_rmse[0][3]:.2f}, {ca_.table2_rmse[0][4] / ch.table2_rmse[0][4]:.2f} and "
      f"{ca_.table2_rmse[0][5] / ch.table2_rmse[0][5]:.2f} times as large in depth, roll, pitch and yaw.")
    w("")
    w("## The two vehicles")
    w("")
    w("What the depth and attitude loops act on, from the two studies' system files (the parameters each front")
    w("records: `studies/systems/...identified_t200.toml` and the shipped `bluerov2_heavy`); a term a file does not")
    w("have is 0.")
    w("")
    w("| | unit | identified Hinsdale | BlueROV2 Heavy |")
    w("|---|---|---|---|")
    pa, ph = (dict(zip(q.names(), q.vector())) for q in (system_params(ca_), system_params(ch)))
    for label, unit, fn in PHYSICS:
        va, vh = fn(pa), fn(ph)
        show = (lambda v: ", ".join(g(x, ".3g") for x in v)) if isinstance(va, tuple) else (lambda v: g(v, ".3g"))
        w(f"| {label} | {unit} | {show(va)} | {show(vh)} |")
    w("")
    w("## What it says")
    w("")
    w(f"- ArduSub's defaults score (f_chat, f_rmse) = ({g(d[0])}, {g(d[1])}) here (the Heavy: ({g(dh[0])}, "
      f"{g(dh[1])})). The best front member beats them by a factor {fb:.2f} in both objectives at once (member "
      f"{ib}; on the Heavy: {improvement(fh.F, dh)[0]:.2f}). " + page.beside_defaults(fa.F, d))
    w(f"- The front ({fa.size} members) spans {page.span(fa.F)}. Hypervolume {fa.hv:.4f} against the Heavy's "
      f"ArduSub front's {fh.hv:.4f} (reference point {tuple(float(v) for v in fa.reference_point)}; compare.txt below).")
    w(f"- The knee (member {k}: {fa.describe(k, '.3g')}) against the Heavy's knee (member {kh}: "
      f"{fh.describe(kh, '.3g')}): the gains in the table below.")
    summary_at = len(L)  # the findings of the sections below, filled in once they are computed
    L.extend(page.hypervolumes(ex.compare))
    w("## The gains a real identified vehicle wants")
    w("")
    w(f"The knee, [`knee/{PARAM.name}`](knee/{PARAM.name}), and the member better than the defaults in both")
    w(f"objectives, [`better_than_defaults/{BETTER.name}`](better_than_defaults/{BETTER.name}), beside the")
    w(f"Heavy study's knee ([`../knee/{HEAVY_PARAM.name}`](../knee/{HEAVY_PARAM.name})). The knee's header reads:")
    L.extend(page.fenced("\n".join(ex.header)))
    w("| parameter | ArduSub default | range | identified: knee | knee / default | identified: better than "
      "defaults | Heavy: knee | identified knee / Heavy knee |")
    w("|---|---|---|---|---|---|---|---|")
    ratio = {n: knee[n] / heavy[n] for n in sorted(knee)}
    for n in sorted(knee):
        p = table[n]
        w(f"| `{n}` | {g(p['default'], '.4g')} | {page.param_range(p)} | {g(knee[n], '.4g')} | "
          f"{knee[n] / p['default']:.2f} | {g(better[n], '.4g')} | {g(heavy[n], '.4g')} | {ratio[n]:.2f} |")
    w("")
    slots = ardusub.slot_names()
    col = {n: slots.index(n) for n in knee}
    sep = [n for n in sorted(knee) if fa.gains[:, col[n]].min() > fh.gains[:, col[n]].max()
           or fa.gains[:, col[n]].max() < fh.gains[:, col[n]].min()]
    w("Each gain's range over the whole front (every member, not the knee only): where the two fronts' ranges")
    w("overlap, that gain does not set the two vehicles apart at this study's size.")
    w("")
    w("| parameter | identified front: min - max | Heavy front: min - max | ranges overlap |")
    w("|---|---|---|---|")
    for n in sorted(knee):
        a_, h_ = fa.gains[:, col[n]], fh.gains[:, col[n]]
        w(f"| `{n}` | {g(a_.min(), '.3g')} - {g(a_.max(), '.3g')} | {g(h_.min(), '.3g')} - {g(h_.max(), '.3g')} | "
          f"{'no' if n in sep else 'yes'} |")
    w("")
    lr = np.abs(np.log(np.array(list(ratio.values()))))
    far = sorted(ratio, key=lambda n: -abs(np.log(ratio[n])))[:3]
    w(f"The two knees' gains differ by a factor {np.exp(np.median(lr)):.2f} in the median (geometric, either way) and "
      f"by up to {np.exp(lr.max()):.2f}; most in " + ", ".join(f"`{n}` ({ratio[n]:.2f})" for n in far) + ". "
      f"{int(np.sum(lr > np.log(2)))} of the {len(ratio)} differ by more than a factor 2. Both are knees of small "
      "studies (32 x 30 runs, one noise draw): the fronts are not converged, and a knee moves along its front "
      "between studies; read the factors as the size of the difference, not its last digit. "
      + (f"The fronts' ranges do not overlap for {len(sep)} of the {len(knee)}: "
         + ", ".join(f"`{n}`" for n in sep) + "." if sep else
         "The two fronts' ranges overlap for every gain: no gain alone sets the vehicles apart here."))
    w("")
    crossed = json.loads((HERE / "crossed.json").read_text())
    lim = tomllib.loads((ROOT / "studies" / "scenarios" / "bluerov2_tank_alt_hold.toml").read_text())["limits"]
    limits = np.array([lim["e_position"]["value"]] * 3 + [lim["e_attitude"]["value"]] * 3)
    w("## Each vehicle's tuned gains on the other")
    w("")
    w("The two studies' knees and better-than-defaults members, each run on both vehicles in its study's own")
    w("evaluation (`crossed.py`, `crossed.json`; a vehicle's own members reproduce its front's objectives).")
    w("(f_chat, f_rmse); ArduSub's defaults from the fronts.")
    w("")
    w("| gains | on the identified Hinsdale | on the BlueROV2 Heavy |")
    w("|---|---|---|")
    name = {"identified": "identified Hinsdale", "heavy": "BlueROV2 Heavy"}

    def cell(r) -> str:
        if r["ok"]:
            return f"({g(r['F'][0])}, {g(r['F'][1])})"
        e = np.abs(np.array(r["e_at_fail"])) / limits
        j = int(np.argmax(e))
        return f"**diverged** at {r['t_fail']:.1f} s ({DOFS[j]} error {g(r['e_at_fail'][j])}, limit {g(limits[j])})"

    w(f"| ArduSub's defaults | ({g(d[0])}, {g(d[1])}) | ({g(dh[0])}, {g(dh[1])}) |")
    for key in (k_ for k_ in crossed["identified"] if k_ != "defaults"):
        src, which = key.split(" ")
        w(f"| {name[src]}'s {which.replace('_', ' ')} (member {crossed['identified'][key]['member']}) | "
          f"{cell(crossed['identified'][key])} | {cell(crossed['heavy'][key])} |")
    for v, own in (("identified", "identified knee"), ("heavy", "heavy knee")):  # the evaluation is the study's
        f_own = (fa if v == "identified" else fh).F[k if v == "identified" else kh]
        assert crossed[v][own]["F"] == f_own.tolist(), (v, crossed[v][own]["F"], f_own)
    w("")
    dflt = {"identified": d, "heavy": dh}
    said = []
    for src, on in (("heavy", "identified"), ("identified", "heavy")):
        r = crossed[on][f"{src} better_than_defaults"]
        if not r["ok"]:
            said.append(f"the {name[src]}'s member better than its defaults **diverges** on the {name[on]}")
        else:
            both = r["F"][0] < dflt[on][0] and r["F"][1] < dflt[on][1]
            said.append(f"the {name[src]}'s member better than its defaults is "
                        + ("also better than the defaults in both objectives" if both else
                           "not better than the defaults in both objectives") + f" on the {name[on]}")
    for src, on in (("heavy", "identified"), ("identified", "heavy")):
        r = crossed[on][f"{src} better_than_defaults"]
        if not r["ok"]:
            period, growth, peak0 = oscillation(np.array(r["e_fail_dof"]), r["h"])
            w(f"On the {name[on]} the {name[src]}'s member better than its defaults makes {DOFS[r['fail_dof']]} "
              f"oscillate with a period of {period:.1f} s, each swing {growth:.2f} times the one before (median), "
              f"from {g(peak0)} rad to past the 0.5 rad limit at {r['t_fail']:.1f} s: an unstable loop, not a drift. "
              f"The identified hull's pitch is far less damped (M_q {g(pa['hydro.M_q'])} and M_q_absq "
              f"{g(pa.get('hydro.M_q_absq', 0.0))} against the Heavy's {g(ph['hydro.M_q'])} and "
              f"{g(ph.get('hydro.M_q_absq', 0.0))}) and heavier in pitch (table \"The two vehicles\"); that member's "
              f"pitch-rate I is {better_h['ATC_RAT_PIT_I'] / table['ATC_RAT_PIT_I']['default']:.1f} times ArduSub's default. "
              f"The identification left the pitch damping uncertain (M_q 95 % interval {ident_interval('hydro.M_q')}, "
              f"M_q_absq {ident_interval('hydro.M_q_absq')} at its bound: the identified file's header), so that "
              "vehicle's pitch margin is the least known of its loops.")
            w("")
    seeds = crossed["identified"]["defaults"]["other_seeds"]["seeds"]
    fate = {(v, k_): r["other_seeds"] for v in crossed for k_, r in crossed[v].items()}
    held = [vk for vk, s in fate.items() if all(s["ok"])]
    failed = [vk for vk, s in fate.items() if not any(s["ok"])]
    mixed = [vk for vk in fate if vk not in held and vk not in failed]
    w(f"On {len(seeds)} other sensor-noise seeds ({seeds[0]}-{seeds[-1]}; `crossed.json`, `other_seeds`), "
      f"{len(held)} of the {len(fate)} runs above (ArduSub's defaults included) hold on every seed"
      + (", " + " and ".join(f"the {name[k_.split(' ')[0]]}'s {k_.split(' ')[1].replace('_', ' ')} on the {name[v]} "
                             f"diverges on every seed (at {min(fate[(v, k_)]['t_fail']):.1f}-"
                             f"{max(fate[(v, k_)]['t_fail']):.1f} s)" for v, k_ in failed) if failed else "")
      + (f"; {len(mixed)} hold on some seeds only" if mixed else "") + ": the outcome is the gains', not the noise draw's.")
    w("")
    w("The members that beat ArduSub's defaults on their own vehicle, moved to the other: " + "; ".join(said) + ". "
      "(A knee trades RMSE for less chattering on its own vehicle too, so its f_rmse above the defaults' is no "
      "verdict.) The transfer is not symmetric and not safe: tune on your own identified vehicle, not on a sister "
      "vehicle's file.")
    w("")
    L[summary_at:summary_at] = [
        f"- **The gains differ, the fronts hardly.** The two fronts lie close in objective space (figure), yet the "
        f"knees' gains differ by a factor {np.exp(np.median(lr)):.2f} in the median; over the whole fronts every "
        f"gain's range {'overlaps the other front' + chr(39) + 's' if not sep else 'overlaps for all but ' + str(len(sep))}: "
        "many gain sets reach the same trade-off here, and this small study does not pin any one gain.",
        "- **The defaults are a safer start than a sister vehicle's tune.** " + said[0][0].upper() + said[0][1:]
        + " (section \"Each vehicle's tuned gains on the other\").",
    ]
    w("## Before you load it")
    w("")
    w("- **This is the Hinsdale vehicle with a Heavy's thrusters**, not a six-thruster BlueROV2: on a vehicle with")
    w("  the standard frame (ArduSub's vectored frame, four horizontal and two vertical T200) the roll authority and")
    w("  the mixer differ, and these gains are not its tuning. The identified part (centre of buoyancy, roll and")
    w("  pitch inertia and damping) comes from trials with the thrusters off; thrust, added mass and the")
    w("  translational damping are the sourced values.")
    w("- **Load it** as the Heavy study's: disarmed, QGroundControl's Parameters > Tools > Load from file or")
    w("  MAVProxy `param load FILE`; only the twelve parameters above are in the file. Save your parameters first.")
    w("- **Where the replica departs from the autopilot** (float32, the linear P loops, no input shaping, the")
    w("  acceleration from the estimate at 10 Hz): [../README.md](../README.md) and docs/ardusub.md.")
    return "\n".join(L) + "\n"


if __name__ == "__main__":
    (HERE / "README.md").write_text(markdown())
