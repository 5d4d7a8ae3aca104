"""Why the BlueROV2 needs its short plant step (issue 26 item 1): measured, not assumed.

    python benchmarks/bluerov2_step.py [--quick]     # writes results/bluerov2_step/ (README.md, JSON, figure)

Haidou-1 meets issue 14's accuracy rule (results/step) at h_plant = 0.05 s; the BlueROV2 Heavy + Alpha 5
needed 0.005 s with instantaneous thrusters and needs 0.0025 s with its T200 dynamics
(arvcas/data/bluerov2_heavy_alpha5.scenario.toml). Three measurements separate the candidate causes:

(1) **Stiffness.** Along each system's default run (controller ``proposed``, its default gains; the
    BlueROV2 also at the knee of its proposed front, results/bluerov2/t200), the Jacobian d xdot / d x
    (12 x 12) of the plant (benchmarks/step_accuracy.py's ``_plant_ode``: the direct Newton-Euler arm
    wrench, the joint trajectory, payload, disturbance, current and tether as functions of t; the
    thrusters' delivered wrench of the run held) at every controller sample, and its eigenvalues: the
    largest |lambda|, h_plant |lambda| against RK4's stability limit on the negative real axis (2.785) and
    RK4's one-step error factor |e^z - R(z)| at z = h_plant lambda. Then the same with one group of terms
    switched off in the parameters (quadratic damping, linear damping, added mass, the arm links' drag,
    the arm's mass and inertia), so each eigenvalue's source is measured; and, per DOF, the decoupled
    estimate -(D_l + 2 D_q |nu|) / (M_RB + M_A) on the diagonal.

(2) **The forcing.** The same runs' open-loop error against CVODES (abstol = reltol = 1e-14) at plant
    steps 0.01 ... 0.00125 s (plant (b) also 0.1, 0.05, 0.025 s) for three plants driven by the same run: (a) the shipped one (the T200 lags
    through the thrust table: the closed loop's closed form for the RK4, the lag as ODE states through the
    map for CVODES, as benchmarks/thruster_step.py); (b) the vehicle alone with the delivered wrench of
    each sample held (instantaneous thrusters: a constant forcing within each sample); (c) (a) with the
    quadratic damping's |nu| smoothed (sqrt(nu^2 + eps^2), eps = 1e-3) so its kink at zero speed is gone.
    The first state error (m, rad) of each, the step the rule needs, and the counts of what is not smooth
    along the run: zero crossings of the relative velocity components (the |nu| nu kinks) and of the rotor
    states (the table's dead band around zero thrust), per second.

(3) **The accuracy rule.** The rule's tolerance (1e-6 m, rad) against the run's own scales: the state
    error as a fraction of the RMSE the metrics report.

The BlueROV2's runs are 60 s (the shipped scenario); ``--quick``: the first 10 s and fewer steps (a check
that the script works, not for the record).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import time
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results" / "bluerov2_step"
RK4_LIMIT = 2.785293563405282  # RK4's stability interval on the negative real axis
STEPS = (0.01, 0.005, 0.0025, 0.00125)
COARSE = (0.1, 0.05, 0.025)  # plant (b) only: Haidou-1's step and around it
RULE = 1e-6
EPS_SMOOTH = 1e-3  # m/s, rad/s: |v| -> sqrt(v^2 + eps^2) in variant (c)


def _step_accuracy():
    spec = importlib.util.spec_from_file_location("step_accuracy", ROOT / "benchmarks" / "step_accuracy.py")
    sa = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sa)
    return sa


# ---- (1) eigenvalues -------------------------------------------------------------------------------------

VARIANTS = {  # name -> (what it switches off, parameter-name predicate set to zero)
    "shipped": ("nothing", lambda n: False),
    "no quadratic damping": ("the |nu| nu terms (hydro.*_abs*)", lambda n: n.startswith("hydro.") and "_abs" in n),
    "no linear damping": ("hydro.X_u, Z_w, M_q (and the other linear terms)",
                          lambda n: n.startswith("hydro.") and "_abs" not in n and not n.endswith("dot")),
    "no added mass": ("hydro.*dot", lambda n: n.startswith("hydro.") and n.endswith("dot")),
    "no arm drag": ("the links' drag (arm.link*.drag_diameter)", lambda n: n.startswith("arm.link") and n.endswith("drag_diameter")),
    "no arm inertia": ("the links' mass and inertia", lambda n: n.startswith("arm.link") and (
        n.endswith(".mass") or ".inertia." in n)),
}


def _jacobian_fn(sa, cfg, lay):
    x, s, par, xdot = sa._plant_ode(cfg, None, lay)
    return ca.Function("J", [x, s, par], [ca.jacobian(xdot, x)])


def _pars(cfg, pv, wrench, phase) -> np.ndarray:
    """``_plant_ode``'s par per sample (columns): the held wrench, t_k, the phases, the water, p."""
    n = wrench.shape[0]
    return np.vstack([wrench.T, (np.arange(n) * cfg.time_h)[None, :], np.tile(np.asarray(phase, float)[:, None], (1, n)),
                      np.tile(cfg.water_vector[:, None], (1, n)), np.tile(np.asarray(pv, float)[:, None], (1, n))])


def _rk4_factor(z: np.ndarray) -> np.ndarray:
    """|e^z - R(z)| for RK4's stability function R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24: its one-step error
    on the mode y' = lambda y, z = h lambda (relative to the mode's amplitude)."""
    return np.abs(np.exp(z) - (1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24))


def eigen_study(sa, name: str, cfg, lay, pv, X, wrench, phase, every: int = 1) -> dict:
    """(1) of the module docstring for one traced run: per variant, the eigenvalues at every ``every``-th sample."""
    Jf = _jacobian_fn(sa, cfg, lay)
    ks = np.arange(0, X.shape[0] - 1, every)
    par0 = _pars(cfg, pv, wrench, phase)[:, ks]
    out = {"system": name, "h_plant": cfg.time_h_plant, "samples": int(ks.size), "variants": {}}
    names = list(lay.names)
    for vname, (what, pred) in VARIANTS.items():
        pv_v = np.array(pv, float)
        hit = [i for i, n in enumerate(names) if pred(n)]
        if vname != "shipped" and not hit:
            continue
        pv_v[hit] = 0.0
        par = par0.copy()
        par[-len(pv_v):, :] = pv_v[:, None]
        Jm = Jf.map(ks.size)
        Js = np.array(Jm(X[ks].T, np.zeros((1, ks.size)), par))  # (12, 12 * n)
        lam = np.array([np.linalg.eigvals(Js[:, 12 * j:12 * j + 12]) for j in range(ks.size)])  # (n, 12)
        rad = np.abs(lam).max(axis=1)
        j = int(np.argmax(rad))
        z = lam * cfg.time_h_plant
        fac = _rk4_factor(z).max(axis=1)
        l_at = lam[j][np.argsort(-np.abs(lam[j]))]
        out["variants"][vname] = {
            "switched_off": what, "n_params_zeroed": len(hit),
            "max_abs_lambda": float(rad.max()), "median_max_abs_lambda": float(np.median(rad)),
            "t_of_max": float(ks[j] * cfg.time_h), "lambdas_at_max": [[float(v.real), float(v.imag)] for v in l_at[:6]],
            "min_real": float(lam.real.min()), "max_real": float(lam.real.max()),
            "max_abs_imag": float(np.abs(lam.imag).max()),
            "h_lambda_max": float(rad.max() * cfg.time_h_plant),
            "rk4_step_error_factor_max": float(fac.max()), "rk4_step_error_factor_median": float(np.median(fac)),
            "series_max_abs_lambda": rad.tolist() if vname == "shipped" else None,
        }
    out["t"] = (ks * cfg.time_h).tolist()
    return out


def diagonal_estimate(lay, pv, X) -> dict:
    """Per DOF: -(D_l + 2 D_q |nu|) / (M_RB + M_A), the decoupled damping eigenvalue, at the run's median and
    largest |nu| (the vehicle's own mass and inertia and added mass; the arm's inertia left out)."""
    P = dict(zip(lay.names, np.asarray(pv, float)))
    m = P["vehicle.m"]
    Mrb = [m, m, m, P["vehicle.Ixx"], P["vehicle.Iyy"], P["vehicle.Izz"]]
    Ma = [-P.get(k, 0.0) for k in ("hydro.X_udot", "hydro.Y_vdot", "hydro.Z_wdot", "hydro.K_pdot", "hydro.M_qdot", "hydro.N_rdot")]
    lin = ["hydro.X_u", "hydro.Y_v", "hydro.Z_w", "hydro.K_p", "hydro.M_q", "hydro.N_r"]
    quad = ["hydro.X_u_absu", "hydro.Y_v_absv", "hydro.Z_w_absw", "hydro.K_p_absp", "hydro.M_q_absq", "hydro.N_r_absr"]
    nu = np.abs(X[:, 6:12])
    out = {}
    for i, dof in enumerate("uvwpqr"):
        Dl, Dq = -P.get(lin[i], 0.0), -P.get(quad[i], 0.0)
        M = Mrb[i] + Ma[i]
        out[dof] = {"M_rb": Mrb[i], "M_a": Ma[i], "D_l": Dl, "D_q": Dq,
                    "lambda_median_nu": -(Dl + 2 * Dq * float(np.median(nu[:, i]))) / M,
                    "lambda_max_nu": -(Dl + 2 * Dq * float(nu[:, i].max())) / M,
                    "nu_median": float(np.median(nu[:, i])), "nu_max": float(nu[:, i].max())}
    return out


# ---- (2) the forcing -------------------------------------------------------------------------------------

def _integrate(sa, cfg, pv, x0, inputs, phase, lay, hp, n, smooth: bool):
    """(RK4 states, CVODES states) of the plant of ``lay`` driven by ``inputs`` (rows per sample), n samples."""
    if not smooth:
        return (sa.rk4_states(cfg, pv, x0, inputs, phase, hp, n_samples=n, layout=lay), None)
    orig = sa._plant_ode
    sa._plant_ode = lambda c, o=None, layout=None: _smoothed_ode_orig(orig, c, o, layout)
    try:
        return (sa.rk4_states(cfg, pv, x0, inputs, phase, hp, n_samples=n, layout=lay), None)
    finally:
        sa._plant_ode = orig


def _smoothed_ode_orig(orig, cfg, opts, layout):
    f = ca.fabs
    ca.fabs = lambda v: ca.sqrt(v * v + EPS_SMOOTH * EPS_SMOOTH)
    try:
        return orig(cfg, opts, layout)
    finally:
        ca.fabs = f


def _reference(sa, cfg, pv, x0, inputs, phase, lay, n, smooth: bool):
    if not smooth:
        return sa.cvodes_states(cfg, pv, x0, inputs, phase, tol=1e-14, n_samples=n, layout=lay)
    orig = sa._plant_ode
    sa._plant_ode = lambda c, o=None, layout=None: _smoothed_ode_orig(orig, c, o, layout)
    try:
        return sa.cvodes_states(cfg, pv, x0, inputs, phase, tol=1e-14, n_samples=n, layout=lay)
    finally:
        sa._plant_ode = orig


def forcing_study(sa, blue, cfg, r, steps, n, log) -> dict:
    from arvcas.system.params import layout_for

    lay = blue.layout
    pv = blue.params.vector()
    inst = layout_for(lay.structure.instantaneous())
    pv_inst = np.asarray(pv, float)[[lay.index[k] for k in inst.names]]
    X = np.hstack([r.eta, r.nu])
    targets = sa.plant_inputs(pv, r, lay)
    held = np.asarray(r.tau_delivered, float)
    plants = {
        "(a) shipped: T200 lags through the table": (lay, pv, targets, False),
        "(b) vehicle alone, delivered wrench held per sample": (inst, pv_inst, held, False),
        "(c) (a) with |nu| smoothed (eps 1e-3)": (lay, pv, targets, True),
    }
    out = {}
    for label, (L, p, inp, smooth) in plants.items():
        t0 = time.time()
        ref = _reference(sa, cfg, p, X[0], inp, r.phase, L, n, smooth)
        rec = {"cvodes_s": time.time() - t0, "steps": {}}
        for hp in (COARSE if L is not lay else ()) + tuple(steps):  # the vehicle alone also at Haidou-1's steps
            c = dataclasses.replace(cfg, time_h_plant=hp)
            A = _integrate(sa, c, p, X[0], inp, r.phase, L, hp, n, smooth)[0]
            d = np.abs(A - ref)
            rec["steps"][repr(hp)] = {"position_m": float(d[:, 0:3].max()), "angle_rad": float(d[:, 3:6].max()),
                                      "t_of_max": float(np.argmax(d[:, 0:6].max(axis=1)) * cfg.time_h)}
            log(f"{label} {hp}: {rec['steps'][repr(hp)]}")
        passing = [hp for hp in (COARSE if L is not lay else ()) + tuple(steps) if max(rec["steps"][repr(hp)]["position_m"], rec["steps"][repr(hp)]["angle_rad"]) <= RULE]
        rec["coarsest_within_rule"] = max(passing) if passing else None
        out[label] = rec
    return out


def non_smooth_counts(cfg, r, pv, lay) -> dict:
    """Zero crossings per second along the run: of the relative velocity components (the |nu| nu kinks:
    nu itself, the current is constant in {n}) and of the delivered thrust per thruster (the rotor crossing
    the table's dead band)."""
    dur = float(r.t[-1] - r.t[0])
    nu = np.asarray(r.nu)
    sc = np.sum(np.diff(np.sign(nu), axis=0) != 0, axis=0)
    th = np.asarray(r.thrust)
    tc = np.sum(np.diff(np.sign(th), axis=0) != 0, axis=0)
    return {"duration_s": dur, "nu_sign_changes_per_s": (sc / dur).tolist(),
            "thrust_sign_changes_per_s": (tc / dur).tolist(),
            "thrust_sign_changes_total": int(tc.sum()), "nu_sign_changes_total": int(sc.sum())}


# ---- run it all -------------------------------------------------------------------------------------------

def study(quick: bool = False, log=print) -> dict:
    import arvcas
    from arvcas.io.results import read_result
    from arvcas.sim import scenario

    sa = _step_accuracy()
    res = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "quick": quick,
           "load_avg_start": list(os.getloadavg()), "eigen": {}, "forcing": {}, "diagonal": {}, "counts": {}}
    blue = arvcas.load_system("bluerov2_heavy_alpha5")
    cfg_b = scenario.load_scenario(blue.params.default("scenario"))
    hai = arvcas.load_system("haidou1")
    cfg_h = scenario.load_scenario()
    if quick:
        cfg_b = dataclasses.replace(cfg_b, time_duration=10.0)
        cfg_h = dataclasses.replace(cfg_h, time_duration=10.0)
    runs = [("haidou1 proposed default", hai, cfg_h, None, None),
            ("bluerov2 proposed default", blue, cfg_b, None, None)]
    knee = ROOT / "results/bluerov2/t200/knees/knee_proposed.h5"
    if knee.is_file():
        k = read_result(knee)
        runs.append(("bluerov2 proposed knee", blue, cfg_b, k.gains, (k.seed, k.uncertainty, k.phase)))
    traced = {}
    for label, sysm, cfg, g, draw in runs:
        seed, unc, ph = draw if draw is not None else (0, None, None)
        r = arvcas.Run("proposed", scenario=cfg, params=sysm).compile().simulate(gains=g, seed=seed, uncertainty=unc, phase=ph)
        traced[label] = r
        X = np.hstack([r.eta, r.nu])
        from arvcas.system.params import layout_for

        lay = sysm.layout
        pv = np.asarray(sysm.params.vector(), float)
        if lay.structure.has_thruster_dynamics:
            inst = layout_for(lay.structure.instantaneous())
            pv = pv[[lay.index[k] for k in inst.names]]
            lay = inst
        wrench = np.asarray(r.tau_delivered if hasattr(r, "tau_delivered") and r.tau_delivered is not None
                            else sa.held_wrench(pv, r.thrust, lay), float)
        log(f"eigenvalues: {label} ...")
        res["eigen"][label] = eigen_study(sa, label, cfg, lay, pv, X, wrench, r.phase)
        res["diagonal"][label] = diagonal_estimate(lay, pv, X)
        res["counts"][label] = non_smooth_counts(cfg, r, pv, lay)
        res["counts"][label]["rmse"] = np.asarray(r.rmse, float).tolist()
    n = scenario.n_samples(cfg_b) - 1
    steps = STEPS[:3] if quick else STEPS
    for label in [k for k in traced if k.startswith("bluerov2")][:1]:
        log(f"forcing: {label} ...")
        res["forcing"][label] = forcing_study(sa, blue, cfg_b, traced[label], steps, n, log)
    res["load_avg_end"] = list(os.getloadavg())
    return res


def figure(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    for label, e in res["eigen"].items():
        v = e["variants"]["shipped"]
        ax.semilogy(e["t"], np.asarray(v["series_max_abs_lambda"]) * e["h_plant"], label=f"{label} (h_plant {e['h_plant']:g} s)")
    ax.axhline(RK4_LIMIT, color="k", ls="--", lw=0.8, label="RK4 stability limit (real axis)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("h_plant max|lambda|")
    ax.set_title("Largest eigenvalue of the linearised plant along the run, times the plant step")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _g(v) -> str:
    return "-" if v is None else f"{v:.3g}"


def markdown(res: dict) -> str:
    L = ["# Why the BlueROV2 needs a short plant step (issue 26 item 1)", "",
         f"Written by `python benchmarks/bluerov2_step.py{' --quick' if res['quick'] else ''}` on {res['date']} "
         f"(see its docstring for the method); every figure is in `bluerov2_step.json`. Load average (1, 5, 15 min) "
         f"{' '.join(f'{x:.2f}' for x in res['load_avg_start'])} at the start, "
         f"{' '.join(f'{x:.2f}' for x in res['load_avg_end'])} at the end (only wall times depend on it).", "",
         "## 1. Stiffness: the linearised plant's eigenvalues along the run", "",
         "Jacobian d xdot / d x (12 x 12) at every controller sample of each run, the delivered wrench held. "
         "max|lambda|: the largest over the run (1/s); h |lambda|: times the system's plant step (RK4 is stable "
         f"to {RK4_LIMIT:.3f} on the real axis); RK4 factor: |e^z - R(z)| at z = h lambda, the relative one-step "
         "error of the worst mode (largest over the run; median of the per-sample largest). Each variant zeroes one "
         "group of parameters (the eigenvalues move with the terms they come from).", "",
         "| run | variant | max abs lambda 1/s (at t s) | median over samples | min Re | max abs Im | h abs lambda | "
         "RK4 factor max; median | the six largest eigenvalues at the max |",
         "|---|---|--:|--:|--:|--:|--:|--:|---|"]
    for label, e in res["eigen"].items():
        for vname, v in e["variants"].items():
            lams = ", ".join(f"{a:.3g}{b:+.3g}i" if abs(b) > 1e-9 else f"{a:.3g}" for a, b in v["lambdas_at_max"])
            L.append(f"| {label} | {vname} | {v['max_abs_lambda']:.3g} ({v['t_of_max']:g}) | {v['median_max_abs_lambda']:.3g} | "
                     f"{v['min_real']:.3g} | {v['max_abs_imag']:.3g} | {v['h_lambda_max']:.3g} | "
                     f"{v['rk4_step_error_factor_max']:.2g}; {v['rk4_step_error_factor_median']:.2g} | {lams} |")
    L += ["", "Per DOF, the decoupled estimate -(D_l + 2 D_q |nu|) / (M_RB + M_A) (the vehicle alone, 1/s), at the "
              "run's median and largest |nu|:", "",
          "| run | " + " | ".join("uvwpqr") + " |", "|---|" + "--:|" * 6]
    for label, d in res["diagonal"].items():
        L.append(f"| {label} | " + " | ".join(f"{d[k]['lambda_median_nu']:.3g} ... {d[k]['lambda_max_nu']:.3g} "
                                              f"(M {d[k]['M_rb'] + d[k]['M_a']:.3g})" for k in "uvwpqr") + " |")
    L += ["", "![h max|lambda| along the runs](eigenvalues.png)", "", "## 2. The forcing: which plant needs the short step", "",
          "Open-loop error against CVODES (1e-14) over the run, largest over the samples: position m / angle rad. "
          f"Rule: both <= {RULE:g}.", ""]
    for label, f in res["forcing"].items():
        steps = sorted({k for rec in f.values() for k in rec["steps"]}, key=lambda k: -float(k))
        L += [f"**{label}**", "", "| plant | " + " | ".join(f"{float(s):g} s" for s in steps) + " | coarsest within the rule |",
              "|---|" + "---|" * (len(steps) + 1)]
        for pl, rec in f.items():
            L.append(f"| {pl} | " + " | ".join(f"{_g(rec['steps'][s]['position_m'])} / {_g(rec['steps'][s]['angle_rad'])}"
                                               if s in rec["steps"] else "-" for s in steps)
                     + f" | {_g(rec['coarsest_within_rule'])} |")
        L.append("")
    L += ["What is not smooth along the runs (sign changes per second; the |nu| nu kinks and the rotors crossing the "
          "table's dead band at zero thrust):", "",
          "| run | nu components u..r | thrust per thruster | RMSE per DOF (the rule's 1e-6 against these) |", "|---|---|---|---|"]
    for label, c in res["counts"].items():
        L.append(f"| {label} | {', '.join(f'{v:.2g}' for v in c['nu_sign_changes_per_s'])} | "
                 f"{', '.join(f'{v:.2g}' for v in c['thrust_sign_changes_per_s'])} | {', '.join(f'{v:.2g}' for v in c['rmse'])} |")
    L += ["", *findings(res)]
    return "\n".join(L) + "\n"


def findings(res: dict) -> list[str]:
    """The conclusions, each from the figures above."""
    L = ["## Findings", ""]
    for label, e in res["eigen"].items():
        if not label.startswith("bluerov2"):
            continue
        v = e["variants"]["shipped"]
        lam = v["max_abs_lambda"]
        moves = sorted(((abs(w["max_abs_lambda"] - lam) / lam, k) for k, w in e["variants"].items() if k != "shipped"),
                       reverse=True)
        L.append(f"- {label}: the largest eigenvalue is {lam:.3g} 1/s (Haidou-1: "
                 f"{res['eigen']['haidou1 proposed default']['variants']['shipped']['max_abs_lambda']:.3g} 1/s), so h |lambda| = "
                 f"{lam * 0.05:.3g} even at Haidou-1's 0.05 s and {lam * e['h_plant']:.3g} at the shipped "
                 f"{e['h_plant']:g} s, far inside RK4's stability limit {RK4_LIMIT:.2f}; RK4's one-step error factor on that mode "
                 f"at the shipped step: {v['rk4_step_error_factor_max']:.2g}. The terms that move it most: "
                 + "; ".join(f"{k} ({100 * d:.0f}%)" for d, k in moves[:3]) + ". The plant is not stiff at these steps.")
    for label, f in res["forcing"].items():
        a = f["(a) shipped: T200 lags through the table"]
        b = f["(b) vehicle alone, delivered wrench held per sample"]
        c = f["(c) (a) with |nu| smoothed (eps 1e-3)"]
        s0 = next(iter(a["steps"]))  # the coarsest step of the shipped plant
        L.append(f"- {label}: at {float(s0):g} s the shipped plant is off CVODES by {_g(a['steps'][s0]['position_m'])} m / "
                 f"{_g(a['steps'][s0]['angle_rad'])} rad; the vehicle alone with the same delivered wrench held per sample by "
                 f"{_g(b['steps'][s0]['position_m'])} m / {_g(b['steps'][s0]['angle_rad'])} rad (within the rule from "
                 f"{_g(b['coarsest_within_rule'])} s); smoothing |nu| changes the shipped error to {_g(c['steps'][s0]['position_m'])} m / "
                 f"{_g(c['steps'][s0]['angle_rad'])} rad. On this run the step is set by the thrust forcing within a sample (the rotors' "
                 f"lag through the T200 table, sampled by RK4 at its stage times), not by the vehicle's dynamics, its "
                 f"|nu| nu kinks or the arm.")
        steps = sorted(a["steps"], key=float)
        L.append(f"- {label}, the shipped plant over the whole run: " + "; ".join(
            f"{float(k):g} s: {_g(a['steps'][k]['position_m'])} m / {_g(a['steps'][k]['angle_rad'])} rad" for k in steps)
            + f"; the coarsest step within the rule: {_g(a['coarsest_within_rule'])} s (the error grows along the open-loop "
              f"run: its largest at t = {a['steps'][steps[-2]]['t_of_max']:g} s at {float(steps[-2]):g} s).")
    L += ["- So a faster integrator for the vehicle (higher order, exponential or implicit) cannot buy a longer step "
          "here: what needs resolving is the thrust forcing B F(s(t)) within a sample, whose rotor states follow the "
          "lag's closed form and whose thrust goes through the table (and its dead band). The candidate this points to: "
          "keep the vehicle's RK4 at a long step and integrate the forcing's contribution more finely (its time "
          "profile is known in closed form within each sample), checked against CVODES as here. Not built in this "
          "session (see the issue's report)."]
    return L + [""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    res = study(a.quick, log=lambda m: print(m, flush=True))
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "bluerov2_step.json").write_text(json.dumps(res, indent=1) + "\n")
    figure(res, a.out / "eigenvalues.png")
    (a.out / "README.md").write_text(markdown(res))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
