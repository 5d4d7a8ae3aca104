"""The two BlueROV2 studies side by side: writes results/bluerov2/side_by_side.md.

    python results/bluerov2/side_by_side.py

Reads only committed files: the instantaneous-thruster study (results/bluerov2/<controller>/,
knees/) and the two T200 studies (t200_group_noise/ with the first BlueROV2 study's group sensor variances,
t200/ with the shipped scenario's per-axis ones; <controller>/, knees/ in each). For each study:
hypervolume at (2, 2) on its own normalisation (its own AGSTA at the default gains), the knee, the lowest
f_chat and f_rmse, the pairwise dominance (arvcas.tuning.compare_fronts); the T200 fronts also on the
instantaneous study's normalisation (their per-DOF CHAT and RMSE divided by the instantaneous study's
AGSTA reference), so that both studies' fronts stand on one scale; the knees' per-DOF CHAT (commanded and
delivered) and RMSE in their units.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
STUDIES = {"instantaneous thrusters, current as a wrench (the first study)": HERE,
           "T200 + current + tether, group noise": HERE / "t200_group_noise",
           "T200 + current + tether, per-axis noise (the shipped scenario)": HERE / "t200"}
CONTROLLERS = ("proposed", "agsta", "pid")
PAIRS = (("proposed", "agsta"), ("pid", "proposed"), ("pid", "agsta"))
REF = (2.0, 2.0)
DOFS = ("x", "y", "z", "phi", "theta", "psi")


def _short(label: str) -> str:
    return label.split(" (")[0]


def _g(x, d=4):
    return "-" if x is None or not np.isfinite(x) else f"{x:.{d}g}"


def markdown() -> str:
    """side_by_side.md's text, from the committed files (benchmarks/render_results.py checks it)."""
    from arvcas.io.results import read_result
    from arvcas.tuning import compare_fronts, read_front
    from arvcas.tuning.checkpoint import read_checkpoint
    from arvcas.tuning.run import hypervolume

    L = ["# The BlueROV2 studies side by side", "",
         "Written by `python results/bluerov2/side_by_side.py` from the committed fronts and knees. Each study "
         "normalises its objectives by its own AGSTA at the default gains on its own plant (docs/model.md §8), so "
         "its hypervolumes compare its controllers; the last columns put the T200 fronts on the instantaneous "
         "study's normalisation (their per-DOF CHAT and RMSE divided by that study's AGSTA reference) to compare "
         "the two plants on one scale.", ""]
    base_ref = None
    fronts = {}
    for label, d in STUDIES.items():
        fronts[label] = {c: read_front(d / c / "front.h5") for c in CONTROLLERS if (d / c / "front.h5").is_file()}
        ck = read_checkpoint(d / "agsta" / "front.h5")
        if base_ref is None:
            base_ref = (np.asarray(ck.ref_chat), np.asarray(ck.ref_rmse))
    L += ["## Fronts", "",
          "| study | controller | members | HV at (2, 2) | defaults (f_chat, f_rmse) | knee (f_chat, f_rmse) | "
          "lowest f_chat | lowest f_rmse | HV on the instantaneous scale | knee on it |",
          "|---|---|---|---|---|---|---|---|---|---|"]
    for label, fr in fronts.items():
        for c, f in fr.items():
            k = f.knee()
            t2 = f.table2_F
            t2s = f"({_g(t2[0])}, {_g(t2[1])})" if np.isfinite(t2).all() else "diverged"
            Fb = np.stack([np.mean(f.chat[0] / base_ref[0], axis=1), np.mean(f.rmse[0] / base_ref[1], axis=1)], axis=1)
            L.append(f"| {_short(label)} | {c} | {f.size} | {f.hv:.4f} | {t2s} | ({_g(f.F[k, 0])}, {_g(f.F[k, 1])}) | "
                     f"{_g(f.F[:, 0].min())} | {_g(f.F[:, 1].min())} | {hypervolume(Fb, f.G, np.array(REF)):.4f} | "
                     f"({_g(Fb[k, 0])}, {_g(Fb[k, 1])}) |")
    L += ["", "## Pairwise dominance (each study on its own scale, reference point (2, 2))", "",
          "| study | A vs B | HV A | HV B | B weakly dominated by A | A weakly dominated by B |", "|---|---|---|---|---|---|"]
    for label, fr in fronts.items():
        for a, b in PAIRS:
            if a in fr and b in fr:
                cmp = compare_fronts(fr[a], fr[b], ref=REF)
                L.append(f"| {_short(label)} | {a} vs {b} | {cmp.hv[0]:.4f} | {cmp.hv[1]:.4f} | "
                         f"{cmp.coverage[0]:.0%} | {cmp.coverage[1]:.0%} |")
    L += ["", "## Knees: CHAT and RMSE per DOF (replays of each front's knee)", "",
          "CHAT in N (x, y, z) and N m (phi, theta, psi) per controller sample, on the commanded wrench (eq. 42) and "
          "on the wrench the thrusters deliver; RMSE in m and rad. With instantaneous thrusters the delivered wrench "
          "is B sat(u) (a knee file written before the thruster dynamics has no delivered CHAT: it is recomputed from its "
          "thrust series).", "",
          "| study | controller | CHAT commanded (x y z phi theta psi) | CHAT delivered | RMSE | largest thrust N |",
          "|---|---|---|---|---|---|"]
    from arvcas import metrics
    from arvcas.model import thrusters
    from arvcas.system.params import view
    from arvcas.system import load_system
    import casadi as ca

    B = np.array(ca.DM(thrusters.B_T(view(load_system("bluerov2_heavy_alpha5").params))))
    for label, d in STUDIES.items():
        for c in CONTROLLERS:
            p = d / "knees" / f"knee_{c}.h5"
            if not p.is_file():
                continue
            r = read_result(p)
            cd = r.chat_delivered if r.chat_delivered is not None else metrics.chat(r.thrust @ B.T)
            fmt = lambda v: " ".join(_g(x, 3) for x in v)  # noqa: E731
            L.append(f"| {_short(label)} | {c} | {fmt(r.chat)} | {fmt(cd)} | {fmt(r.rmse)} | "
                     f"{np.abs(r.thrust).max():.3g} |")
    return "\n".join(L) + "\n"


if __name__ == "__main__":
    text = markdown()
    (HERE / "side_by_side.md").write_text(text)
    print(text)
