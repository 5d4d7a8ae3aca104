"""Write results/ardusub/README.md from the committed files of this folder: the fronts (<law>/front.h5: objectives,
per-DOF CHAT and RMSE, the default gains on the same draw), compare.txt (hypervolumes) and the knee's .param file;
ArduSub's defaults and ranges from arvcas/data/ardusub_params.toml; what it shares with identified/render.py in
page.py. Run from the repository root:

    python results/ardusub/render.py
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from arvcas.tuning import checkpoint as ck
from arvcas.tuning.front import read_front, resolve_front_path

HERE = Path(__file__).resolve().parent
LAWS = ("ardusub", "proposed", "agsta", "pid")
PARAM = HERE / "knee" / "bluerov2_heavy_ardusub.param"
BETTER = HERE / "better_than_defaults" / "bluerov2_heavy_ardusub.param"  # the member of page.improvement()

_spec = importlib.util.spec_from_file_location("arvcas_results_ardusub_page", HERE / "page.py")
page = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(page)
g, improvement, DOFS = page.g, page.improvement, page.DOFS


def dominated_share(A: np.ndarray, B: np.ndarray) -> float:
    """The share of the points of B weakly dominated by some point of A (smaller is better in every column)."""
    return float(np.mean([np.any(np.all(A <= b, axis=1)) for b in B]))


def markdown() -> str:
    """README.md's text, from the committed files of this folder (benchmarks/render_results.py checks it)."""
    fronts = {c: read_front(HERE / c / "front.h5") for c in LAWS}
    cks = {c: ck.read_checkpoint(resolve_front_path(HERE / c / "front.h5")) for c in LAWS}
    fa = fronts["ardusub"]
    ex = page.exports(HERE, PARAM, BETTER, fa)
    table, knee_vals, better_vals, fb, ib = ex.table, ex.knee, ex.better, ex.factor, ex.member
    c0 = cks["ardusub"]
    k = fa.knee()
    L = []
    w = L.append
    w("# ArduSub's own controller tuned for a BlueROV2 Heavy: the `ardusub` study")
    w("")
    w("*Written by `results/ardusub/render.py` from the files of this folder; every number below is read from")
    w("them (the fronts, `compare.txt`, the knee's `.param` file) or from `arvcas/data/ardusub_params.toml`.*")
    w("")
    w("```bash")
    w("arvcas tune studies/ardusub.toml --out results/ardusub")
    w("cd results/ardusub")
    w("arvcas compare ardusub proposed agsta pid --ref 1,5 --plot fronts.png > compare.txt")
    w("arvcas export-controller knee --front ardusub --member knee --format ardusub-params")
    w(f"arvcas export-controller better_than_defaults --front ardusub --member {ib} --format ardusub-params")
    w("cd ../.. && python results/ardusub/render.py")
    w("```")
    w("")
    w("## What was tuned, on what")
    w("")
    w("- **System** `bluerov2_heavy` (docs/systems/bluerov2.md): the BlueROV2 Heavy without an arm, von Benzon et")
    w("  al.'s identified hull, eight T200s with their dynamics (Blue Robotics' 16 V table, a 0.0167 s lag), the")
    w("  thrusters numbered as ArduSub numbers its motors.")
    w("- **Scenario** `studies/scenarios/bluerov2_tank_alt_hold.toml`: the shipped tank scenario (60 s, no current,")
    w("  no tether, a slow 3 N / 2 N / 2 N surge, sway and heave fluctuation, small moments, the BlueROV2's sensor")
    w("  noise) with the position limit raised from 1 m to 20 m. ALT_HOLD holds depth, attitude and heading but")
    w("  no horizontal position: on the shipped 1 m limit the tank's surge fluctuation carries ArduSub's defaults")
    w("  past it at 12.1 s (x 1.01 m, seed 0), and on the Heavy + Alpha 5 harbour scenario the 0.2 m/s current")
    w("  does the same; both end the run as diverged. A station-keeping comparison there would score the drift,")
    w("  not the gains.")
    w("- **Objectives**: CHAT and RMSE (docs/model.md §7) over **depth, roll, pitch and yaw**, what ALT_HOLD")
    w("  holds. x and y get a reference of 1e6, so their share is below 1e-6 of their value: f_chat and f_rmse are")
    w("  the sums over the four held DOFs divided by 6, for every law alike. The normalisation is given in the")
    w("  study (`normalisation_chat`, `normalisation_rmse`), not taken from any law's defaults, so no law has to")
    w("  converge for the study to be scored: RMSE in units of the sensor noise (depth 0.005 m, roll and pitch")
    w("  0.00349 rad, heading 0.01745 rad), CHAT in N (depth) and N m (roll, pitch, yaw) per sample. The")
    w("  proposed law, AGSTA and PID hold x and y too (they measure position); that is not scored here, their")
    w("  x and y numbers are in the per-DOF table.")
    w(f"- **Search**: NSGA-II, population {fa.population_F.shape[0]}, {fa.n_gen} generations per law "
      f"(ardusub: {fa.n_eval} runs), one noise draw (seed {int(fa.draw_seeds[0])}), the default gains in the first "
      "population. The 12 ArduSub gains are searched inside ArduSub's own `@Range` (log scale; a range starting at")
    w("  0 starts at a tenth of the default); the other laws in [g/10, 10 g] around their BlueROV2 defaults. This is")
    w("  a small study; the fronts are not converged. Time in the search (history/elapsed_s of each front, on a")
    w("  shared two-core machine, the compiled runs' builds not counted): "
      + ", ".join(f"{c} {fronts[c].history['elapsed_s'][-1]:.0f} s" for c in LAWS) + ".")
    w("")
    hv = {c: fronts[c].hv for c in LAWS}
    best = max(hv, key=hv.get)
    w("## What it says")
    w("")
    cover = {c: dominated_share(fronts[c].F, fa.F) for c in LAWS[1:]}
    w(f"- Scored on depth, roll, pitch and yaw, the tuned ArduSub front's hypervolume is {hv['ardusub']:.3g}, against "
      + ", ".join(f"{c} {hv[c]:.3g}" for c in LAWS[1:]) + f" (reference point {tuple(float(v) for v in fa.reference_point)}; "
      f"largest: {best}). Share of the ArduSub front dominated by each other law's front: "
      + ", ".join(f"{c} {100 * v:.0f} %" for c, v in cover.items()) + ".")
    d = fa.table2_F
    w(f"- ArduSub's defaults score (f_chat, f_rmse) = ({g(d[0])}, {g(d[1])}). The best front member beats them by a "
      f"factor {fb:.2f} in both objectives at once (member {ib}). " + page.beside_defaults(fa.F, d)
      + " That is how far the defaults sit from the tuned front.")
    w(f"- The front spans {page.span(fa.F)}: along it less chattering is bought with more error.")
    w("")
    w("## Hypervolumes (one reference point)")
    L.extend(page.hypervolumes(ex.compare))
    w("## The defaults against the tuned fronts")
    w("")
    w("*improvement*: the largest factor by which one front member is better than the defaults in both objectives")
    w("at once (> 1: the defaults are dominated by that factor).")
    w("")
    w("| law | defaults (f_chat, f_rmse) | knee (f_chat, f_rmse) | front members | improvement on the defaults |")
    w("|---|---|---|---|---|")
    for c in LAWS:
        fr = fronts[c]
        kc = fr.knee()
        d = fr.table2_F
        if np.isfinite(d).all():
            f, i = improvement(fr.F, d)
            imp = f"{f:.2f} (member {i}: {fr.describe(i, '.3g')})"
            ds = f"({g(d[0])}, {g(d[1])})"
        else:
            imp, ds = "defaults diverged", "diverged"
        w(f"| {c} | {ds} | ({g(fr.F[kc, 0])}, {g(fr.F[kc, 1])}) | {fr.size} | {imp} |")
    w("")
    w("## ArduSub's parameters: defaults, the knee, and the member better than the defaults")
    w("")
    w(f"Two members of the ardusub front as parameter files. **The knee** (member {k}: {fa.describe(k, '.3g')}),")
    w(f"[`knee/{PARAM.name}`](knee/{PARAM.name}): the front's compromise by equal pseudo-weights")
    w("(docs/objectives.md), which on this front trades RMSE for less chattering: "
      + ("its f_rmse is above the defaults'." if fa.F[k, 1] > fa.table2_F[1] else "its f_rmse is at or below the defaults'."))
    w(f"**The member better than the defaults** (member {ib}: {fa.describe(ib, '.3g')}, {fb:.2f} times better in both")
    w(f"objectives), [`better_than_defaults/{BETTER.name}`](better_than_defaults/{BETTER.name}): "
      + ("the one to try first if you want the defaults' behaviour with less of both." if fb > 1 else
         "no member of this front beats the defaults in both objectives."))
    w("The knee's header reads:")
    L.extend(page.fenced("\n".join(ex.header)))
    w("| parameter | ArduSub default | knee | knee / default | better than defaults | its / default | ArduSub range | what |")
    w("|---|---|---|---|---|---|---|---|")
    for n in sorted(knee_vals):
        p = table[n]
        w(f"| `{n}` | {g(p['default'], '.4g')} | {g(knee_vals[n], '.4g')} | {knee_vals[n] / p['default']:.2f} | "
          f"{g(better_vals[n], '.4g')} | {better_vals[n] / p['default']:.2f} | "
          f"{page.param_range(p)} | {p['description']} |")
    w("")
    w("## Per DOF (raw units): ArduSub's defaults and each law's knee")
    w("")
    w("CHAT (N per sample for x, y, z; N m for roll, pitch, yaw) and RMSE (m; rad). ArduSub does not hold x and")
    w("y: its x and y RMSE is the drift under the tank's fluctuation, and its x, y CHAT is zero by construction")
    w("(the horizontal thrusters only turn it).")
    w("")
    w("| run | " + " | ".join(f"CHAT {d}" for d in DOFS) + " | " + " | ".join(f"RMSE {d}" for d in DOFS) + " |")
    w("|---|" + "---|" * 12)
    rows = [("ardusub defaults", c0.table2_chat[0], c0.table2_rmse[0])]
    rows += [(f"ardusub better than defaults (member {ib})", fa.chat[0, ib], fa.rmse[0, ib])]
    rows += [(f"{c} knee", fronts[c].chat[0, fronts[c].knee()], fronts[c].rmse[0, fronts[c].knee()]) for c in LAWS]
    for name, ch, rm in rows:
        w(f"| {name} | " + " | ".join(g(v) for v in ch) + " | " + " | ".join(g(v) for v in rm) + " |")
    w("")
    w("## Before you load it")
    w("")
    w("- **The hull is von Benzon et al.'s Heavy, not yours.** Mass, buoyancy, added mass and damping are")
    w("  approximate for any other vehicle (payload, ballast, tether, a different frame). Identify your own from a")
    w("  dive log (docs/logs.md: a `.BIN` or `.tlog` with PWM and the vehicle's response; docs/identification.md),")
    w("  re-run this study on the identified system file (`[evaluation] system = \"my_vehicle.toml\"`), and export")
    w("  its knee. Gains tuned here for another hull can be worse than the defaults on yours:")
    w("  [identified/README.md](identified/README.md) does this for the identified BlueROV2 of the Hinsdale pool")
    w("  trials and runs each vehicle's tuned gains on the other.")
    w("- **Load it** with the vehicle disarmed: QGroundControl, Vehicle Setup > Parameters > Tools > Load from file,")
    w("  or MAVProxy `param load FILE`. Only the twelve parameters above are in each file; the others stay as they")
    w("  are. Save your current parameters first, then compare a dive at the old and the new gains.")
    w("- **Check your firmware's defaults** (`param show ATC_*`, `PSC_*`) against the table above: they are")
    w("  ArduSub's as read in docs/ardusub.md; a vehicle set up differently starts from other values.")
    w("")
    w("## Where the replica departs from the autopilot")
    w("")
    w("The `ardusub` law is arvcas's replica of ArduSub's ALT_HOLD (docs/ardusub.md, with the ArduPilot files")
    w("read and its check against ArduPilot's compiled AC_PID). It departs from the autopilot in:")
    w("")
    w("- double precision against the autopilot's float32, continuous PWM against whole microseconds (both far below")
    w("  a T200's resolution);")
    w("- linear angle and depth P loops (ArduPilot switches to a square-root law for large errors: about 15 deg in")
    w("  roll and pitch, 3 deg in yaw, 11 cm in depth; station keeping here stays within);")
    w("- no input shaping of ArduSub's own (`ATC_INPUT_TC`, jerk-limited depth target): the replica follows arvcas's")
    w("  reference;")
    w("- the vertical acceleration from the estimate's velocity at 10 Hz, where the autopilot reads the IMU at")
    w("  400 Hz, and one held estimate per 0.1 s sample for the 40 updates at 400 Hz;")
    w("- not replicated: the slew-rate limiter, the PD sum limit, notch filters and battery current limiting (all")
    w("  off at ArduSub's defaults), POSHOLD, pilot input.")
    w("")
    w("The rate D gains, FF, IMAX, filters, `PSC_ACCZ_P` and the PWM range are held at ArduSub's defaults; the")
    w("motors' `MOT_n_DIRECTION` depend on your wiring and propellers and are not exported.")
    return "\n".join(L) + "\n"


def main() -> None:
    (HERE / "README.md").write_text(markdown())


if __name__ == "__main__":
    main()
