"""Why the BlueROV2 needs its short plant step: measured, not assumed.

    python benchmarks/bluerov2_step.py [--quick]     # writes results/bluerov2_step/ (README.md, JSON, figure)

Haidou-1 meets the step-accuracy rule (results/step) at h_plant = 0.05 s; the BlueROV2 Heavy + Alpha 5
needed 0.005 s with instantaneous thrusters and 0.0025 s with its T200 dynamics under plain RK4 (the step shipped
until 2026-12-05; since then the shipped scenario, arvcas/data/bluerov2_heavy_alpha5.scenario.toml, takes 0.01 s with
the thrust quadrature that section (4) measured). The runs here are integrated by plain RK4 at 0.0025 s (``BASE_H``). Three measurements separate the candidate causes:

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

(4) **A candidate.** The same run's open-loop error against the same CVODES reference for RK4 on the plant with
    the thrusters' forcing taken out of its stages (:func:`transformed_states`: the forcing's contribution to the
    velocities and positions integrated by Gauss-Legendre quadrature of the lag's closed form, RK4 on the rest at
    long or graded substeps), with the work per sample it would take (plant evaluations, thrust-map points).

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
BASE_H = 0.0025  # s: the plain RK4 step the runs here are integrated at (the BlueROV2's shipped step until 2026-12-05)
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


# ---- (4) a candidate: the forcing integrated into the step ----------------------------------------------

# (substeps of one 0.1 s sample (s), Gauss-Legendre nodes per half substep, how A = (M + M_arm)^-1 is had at the nodes)
TRANSFORM_CASES = (((0.05,) * 2, 5, "exact"), ((0.025,) * 4, 3, "exact"), ((0.025,) * 4, 5, "exact"),
                   ((0.025,) * 4, 8, "exact"), ((0.025,) * 4, 5, "quadratic"), ((0.02,) * 5, 3, "exact"),
                   ((0.02,) * 5, 5, "exact"), ((0.0125,) * 8, 3, "exact"), ((0.0125,) * 8, 5, "exact"),
                   ((0.01,) * 10, 3, "exact"), ((0.01,) * 10, 5, "exact"), ((0.01, 0.01, 0.02, 0.03, 0.03), 5, "exact"),
                   ((0.01, 0.015, 0.025, 0.05), 5, "exact"),
                   # graded: short substeps where the rotors' transient is (after each command change), 6 in all
                   ((0.005, 0.01, 0.015, 0.02, 0.025, 0.025), 5, "exact"), ((0.004, 0.008, 0.013, 0.02, 0.025, 0.03), 5, "exact"),
                   # long substeps with many nodes: is the forcing's quadrature what limits them?
                   ((0.1,), 80, "exact"), ((0.05,) * 2, 40, "exact"), ((0.025,) * 4, 20, "exact"))
TRANSFORM_QUICK = (((0.025,) * 4, 5, "exact"), ((0.01, 0.01, 0.02, 0.03, 0.03), 5, "exact"))


def transformed_states(sa, cfg, pv, x0, targets, phase, lay, substeps, ng: int, n: int, a_mode: str = "exact"):
    """Plant states at t_k (rows, (n+1, 12)) by RK4 on the plant with the thrusters' forcing taken out of the stages.

    Within a substep [a, a + H] the forcing enters the velocities linearly, nu_dot = A(t) (B F(s(t)) + R(eta, nu, t))
    with A = (M + M_arm(q(t)))^-1 a function of time alone (the joints are prescribed), so with
    w(t) = int_a^t A B F and omega(t) = int_a^t w, nu = z + w(t) and eta = zeta + J(eta_a) omega(t), RK4 integrates
    z_dot = A R(eta, z + w, t) and zeta_dot = J(eta) (z + w) - J(eta_a) w: the fast rotor transient lives in w and
    omega, integrated by Gauss-Legendre quadrature (``ng`` nodes per half substep) of the lag's closed form through
    the T200 table, not sampled at three stage times. ``a_mode``: A at every node ("exact"), or interpolated
    quadratically from its values at the three stage times ("quadratic": what generated code has from the time
    table's LU factors). Only the lag with one time constant and no rate limit (the BlueROV2's T200s).
    """
    from arvcas.model import thrusters
    from arvcas.model.spatial import J
    from arvcas.system.params import layout_for, view

    if any(d.asymmetric or d.rate_limit for d in lay.structure.thruster_dynamics):
        raise ValueError("transformed_states: only the lag with one time constant and no rate limit")
    inst = layout_for(lay.structure.instantaneous())
    pv_inst = np.asarray(pv, float)[[lay.index[k] for k in inst.names]]
    x, s, par, xdot = sa._plant_ode(cfg, None, inst)
    f = ca.Function("f", [x, s, par], [xdot])
    A_fn = ca.Function("A", [x, s, par], [ca.jacobian(xdot[6:12], par[0:6])])  # linear in the wrench: = A(t)
    e = ca.SX.sym("e", 6)
    J_fn = ca.Function("J", [e], [J(e)])
    P = view(ca.DM(np.asarray(pv, float)), lay)
    maps = thrusters.thruster_maps(P)
    B = np.array(ca.DM(thrusters.B_T(P)))
    taus = np.array([float(ca.DM(thrusters.time_constants(P, i)[0])) for i in range(len(maps))])
    tables = {m.name: tuple(np.array(ca.DM(a)).ravel() for a in thrusters.map_table(P, m))
              for m in lay.structure.thruster_maps if m.kind == "table"}
    H = np.asarray(substeps, float)
    if abs(H.sum() - cfg.time_h) > 1e-12:
        raise ValueError(f"substeps {tuple(substeps)} do not add up to the sample {cfg.time_h} s")
    starts = np.r_[0.0, np.cumsum(H)[:-1]]
    gx, gw = np.polynomial.legendre.leggauss(ng)
    # every node of the sample: per substep, ng in each half; weights (hi - lo) / 2 w_i
    tn, wn, sub, half = [], [], [], []
    for i, (a, hh) in enumerate(zip(starts, H)):
        for j, (lo, hi) in enumerate(((a, a + hh / 2), (a + hh / 2, a + hh))):
            tn += list(lo + (hi - lo) * (gx + 1) / 2)
            wn += list((hi - lo) / 2 * gw)
            sub += [i] * ng
            half += [j] * ng
    tn, wn, sub, half = np.array(tn), np.array(wn), np.array(sub), np.array(half)
    stage_t = np.unique(np.r_[starts, starts + H / 2, starts + H])
    xk, sk = np.asarray(x0, float).copy(), np.zeros(len(maps))
    out = [xk]
    zero6 = np.zeros(6)
    for k in range(n):
        y = np.asarray(targets[k], float)
        base = np.r_[k * cfg.time_h, np.asarray(phase, float), cfg.water_vector, pv_inst]
        S = y[:, None] + (sk - y)[:, None] * np.exp(-tn[None, :] / taus[:, None])
        T = np.array([thrusters._pchip_np(*tables[maps[i].name], S[i]) for i in range(len(maps))])
        Wn = B @ T  # (6, nodes)
        tq = tn if a_mode == "exact" else stage_t
        Aq = np.array(A_fn.map(len(tq))(np.tile(xk[:, None], (1, len(tq))), tq[None, :],
                                        np.tile(np.r_[zero6, base][:, None], (1, len(tq))))).reshape(6, len(tq), 6)
        Aq = np.transpose(Aq, (1, 0, 2))  # (times, 6, 6): the map stacks the 6 x 6 blocks side by side
        if a_mode == "exact":
            AW = np.einsum("tij,jt->it", Aq, Wn)
        else:  # quadratic in t through A at the substep's three stage times
            AW = np.empty((6, len(tn)))
            for j, t in enumerate(tn):
                a, hh = starts[sub[j]], H[sub[j]]
                ts = (a, a + hh / 2, a + hh)
                lw = [np.prod([(t - ts[m]) / (ts[l] - ts[m]) for m in range(3) if m != l]) for l in range(3)]
                A3 = [Aq[np.searchsorted(stage_t, tt - 1e-15)] for tt in ts]
                AW[:, j] = sum(c * Am for c, Am in zip(lw, A3)) @ Wn[:, j]
        fx = lambda xx, t: np.array(f(xx, t, np.r_[zero6, base])).ravel()  # noqa: E731
        for i, (a, hh) in enumerate(zip(starts, H)):
            m1, m2 = (sub == i) & (half == 0), sub == i
            v1, v2 = AW[:, m1] * wn[m1], AW[:, m2] * wn[m2]
            w1, w2 = v1.sum(1), v2.sum(1)
            o1, o2 = v1 @ (a + hh / 2 - tn[m1]), v2 @ (a + hh - tn[m2])
            Jm = np.array(ca.DM(J_fn(xk[0:6])))

            def g(zz, t, w, om):
                d = fx(np.r_[zz[0:6] + Jm @ om, zz[6:12] + w], t)
                return np.r_[d[0:6] - Jm @ w, d[6:12]]

            k1 = g(xk, a, zero6, zero6)
            k2 = g(xk + hh / 2 * k1, a + hh / 2, w1, o1)
            k3 = g(xk + hh / 2 * k2, a + hh / 2, w1, o1)
            k4 = g(xk + hh * k3, a + hh, w2, o2)
            z = xk + hh / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            xk = np.r_[z[0:6] + Jm @ o2, z[6:12] + w2]
        sk = y + (sk - y) * np.exp(-cfg.time_h / taus)
        out.append(xk)
    return np.vstack(out)


def transform_study(sa, blue, cfg, r, n, quick: bool, log) -> dict:
    """:func:`transformed_states` against CVODES (plant (a)'s reference) for :data:`TRANSFORM_CASES`; the work per
    sample in plant evaluations and thrust-map points beside the shipped RK4's."""
    lay = blue.layout
    pv = np.asarray(blue.params.vector(), float)
    X = np.hstack([r.eta, r.nu])
    targets = sa.plant_inputs(pv, r, lay)
    ref = _reference(sa, cfg, pv, X[0], targets, r.phase, lay, n, False)
    n_thr = lay.structure.n_thrusters
    rows = []
    for subs, ng, mode in (TRANSFORM_QUICK if quick else TRANSFORM_CASES):
        t0 = time.time()
        A = transformed_states(sa, cfg, pv, X[0], targets, r.phase, lay, subs, ng, n, mode)
        d = np.abs(A - ref)
        e10 = d[:min(len(d), int(round(10 / cfg.time_h)) + 1)]
        rows.append({"substeps": list(subs), "nodes_per_half": ng, "A": mode,
                     "position_m": float(d[:, 0:3].max()), "angle_rad": float(d[:, 3:6].max()),
                     "velocity": float(d[:, 6:12].max()),
                     "first_10s": {"position_m": float(e10[:, 0:3].max()), "angle_rad": float(e10[:, 3:6].max())},
                     "t_of_max": float(np.argmax(d[:, 0:6].max(axis=1)) * cfg.time_h),
                     "plant_evaluations_per_sample": 4 * len(subs), "map_points_per_sample": 2 * ng * len(subs) * n_thr,
                     "wall_s": time.time() - t0})
        log(f"transformed {subs} ng {ng} {mode}: {rows[-1]['position_m']:.3g} m / {rows[-1]['angle_rad']:.3g} rad")
    m_ship = int(round(cfg.time_h / cfg.time_h_plant))
    return {"cases": rows, "n_thrusters": n_thr, "shipped": {"h_plant": cfg.time_h_plant, "plant_evaluations_per_sample": 4 * m_ship,
                                       "map_points_per_sample": (2 * m_ship + 1) * n_thr}}


# ---- run it all -------------------------------------------------------------------------------------------

def study(quick: bool = False, log=print) -> dict:
    import arvcas
    from arvcas.io.results import read_result
    from arvcas.sim import scenario

    sa = _step_accuracy()
    res = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "quick": quick,
           "load_avg_start": list(os.getloadavg()), "eigen": {}, "forcing": {}, "diagonal": {}, "counts": {}}
    blue = arvcas.load_system("bluerov2_heavy_alpha5")
    cfg_b = dataclasses.replace(scenario.load_scenario(blue.params.default("scenario")), time_h_plant=BASE_H,
                                time_thrust_quadrature=None)
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
        r = arvcas.Run("proposed", scenario=cfg, system=sysm).compile().simulate(gains=g, seed=seed, uncertainty=unc, phase=ph)
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
        log(f"transformed: {label} ...")
        res["transform"] = {"run": label, **transform_study(sa, blue, cfg_b, traced[label], n, quick, log)}
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
    L = ["# Why the BlueROV2 needs a short plant step", "",
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
    L += transform_markdown(res.get("transform"))
    L += ["", *findings(res)]
    return "\n".join(L) + "\n"


def _within(row) -> bool:
    return max(row["position_m"], row["angle_rad"]) <= RULE


def transform_markdown(tr) -> list[str]:
    if not tr:
        return []
    sh = tr["shipped"]
    a = tr.get("shipped_errors", {})
    L = ["", "## 3. A candidate measured: the thrusters' forcing taken out of the RK4 stages", "",
         f"{tr['run']}, the same open-loop run and CVODES reference as section 2. `transformed_states` (this script): "
         "within each substep the thrusters' forcing enters the velocities linearly through A(t) = (M + M_arm(q(t)))^-1, "
         "a function of time alone, so RK4 integrates the plant in the variables z = nu - w(t), zeta = eta - J(eta_a) omega(t), "
         "where w = int A B F(s(t)) dt and omega = int w dt come from Gauss-Legendre quadrature of the lag's closed form "
         "through the T200 table (nodes per half substep), not from three stage samples. A at the nodes: exact, or "
         "quadratic through its values at the three stage times (what generated code has from the time table's LU "
         "factors). Work per 0.1 s sample: plant evaluations (RK4 stages) and thrust-map points (table lookups, "
         f"all {tr['n_thrusters']} thrusters); plain RK4 at {sh['h_plant']:g} s (shipped until 2026-12-05): {sh['plant_evaluations_per_sample']} and "
         f"{sh['map_points_per_sample']}. Rule: both errors <= {RULE:g}.", "",
         "| substeps of a sample (s) | nodes per half | A | plant evaluations | map points | whole run: m / rad | "
         "first 10 s: m / rad | t of the largest (s) | within the rule |", "|---|--:|---|--:|--:|---|---|--:|---|"]
    for row in tr["cases"]:
        subs = row["substeps"]
        st = f"{len(subs)} x {subs[0]:g}" if len(set(subs)) == 1 else ", ".join(f"{v:g}" for v in subs)
        L.append(f"| {st} | {row['nodes_per_half']} | {row['A']} | {row['plant_evaluations_per_sample']} | "
                 f"{row['map_points_per_sample']} | {_g(row['position_m'])} / {_g(row['angle_rad'])} | "
                 f"{_g(row['first_10s']['position_m'])} / {_g(row['first_10s']['angle_rad'])} | {row['t_of_max']:g} | "
                 f"{'yes' if _within(row) else 'no'} |")
    return L


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
                 f"{lam * 0.05:.3g} even at Haidou-1's 0.05 s and {lam * e['h_plant']:.3g} at the "
                 f"{e['h_plant']:g} s plain RK4 step, far inside RK4's stability limit {RK4_LIMIT:.2f}; RK4's one-step error factor on that mode "
                 f"at that step: {v['rk4_step_error_factor_max']:.2g}. The terms that move it most: "
                 + "; ".join(f"{k} ({100 * d:.0f}%)" for d, k in moves[:3]) + ". The plant is not stiff at these steps.")
    for label, f in res["forcing"].items():
        a = f["(a) shipped: T200 lags through the table"]
        b = f["(b) vehicle alone, delivered wrench held per sample"]
        c = f["(c) (a) with |nu| smoothed (eps 1e-3)"]
        s0 = next(iter(a["steps"]))  # the coarsest step of the shipped plant
        L.append(f"- {label}: at {float(s0):g} s the shipped plant under plain RK4 is off CVODES by {_g(a['steps'][s0]['position_m'])} m / "
                 f"{_g(a['steps'][s0]['angle_rad'])} rad; the vehicle alone with the same delivered wrench held per sample by "
                 f"{_g(b['steps'][s0]['position_m'])} m / {_g(b['steps'][s0]['angle_rad'])} rad (within the rule from "
                 f"{_g(b['coarsest_within_rule'])} s); smoothing |nu| changes the shipped error to {_g(c['steps'][s0]['position_m'])} m / "
                 f"{_g(c['steps'][s0]['angle_rad'])} rad. On this run the step is set by the thrust forcing within a sample (the rotors' "
                 f"lag through the T200 table, sampled by RK4 at its stage times), not by the vehicle's dynamics, its "
                 f"|nu| nu kinks or the arm.")
        steps = sorted(a["steps"], key=float)
        L.append(f"- {label}, the shipped plant under plain RK4 over the whole run: " + "; ".join(
            f"{float(k):g} s: {_g(a['steps'][k]['position_m'])} m / {_g(a['steps'][k]['angle_rad'])} rad" for k in steps)
            + f"; the coarsest step within the rule: {_g(a['coarsest_within_rule'])} s (the error grows along the open-loop "
              f"run: its largest at t = {a['steps'][steps[-2]]['t_of_max']:g} s at {float(steps[-2]):g} s).")
    L.append("- So a faster integrator for the vehicle alone (higher order, exponential or implicit) cannot buy a "
             "longer step here: what needs resolving is the thrust forcing B F(s(t)) within a sample, whose rotor "
             "states follow the lag's closed form and whose thrust goes through the table.")
    tr = res.get("transform")
    if tr:
        sh = tr["shipped"]
        ok = [r for r in tr["cases"] if _within(r)]
        best = min(tr["cases"], key=lambda r: max(r["position_m"], r["angle_rad"]))
        def _desc(r):
            return (f"{len(r['substeps'])} substeps ({', '.join(f'{v:g}' for v in r['substeps'])} s), {r['nodes_per_half']} "
                    f"nodes per half: {_g(r['position_m'])} m / {_g(r['angle_rad'])} rad over the run "
                    f"({r['plant_evaluations_per_sample']} plant evaluations and {r['map_points_per_sample']} map points "
                    f"per sample against plain RK4's {sh['plant_evaluations_per_sample']} and {sh['map_points_per_sample']})")
        err = lambda r: max(r["position_m"], r["angle_rad"])  # noqa: E731
        same = lambda r, q: r["substeps"] == q["substeps"] and r["A"] == q["A"]  # noqa: E731
        ng_pairs = [(r, q) for r in tr["cases"] for q in tr["cases"] if same(r, q) and q["nodes_per_half"] > r["nodes_per_half"]]
        graded = [r for r in tr["cases"] if len(set(r["substeps"])) > 1 and r["A"] == "exact"]
        uniform = {len(r["substeps"]): r for r in tr["cases"] if len(set(r["substeps"])) == 1 and r["A"] == "exact"
                   and r["nodes_per_half"] == 5}
        quad = [(r, q) for r in tr["cases"] for q in tr["cases"] if r["A"] == "quadratic" and q["A"] == "exact"
                and r["substeps"] == q["substeps"] and r["nodes_per_half"] == q["nodes_per_half"]]
        built = [r for r in ok if len(set(r["substeps"])) == 1 and r["A"] == "exact"]  # what the generated step can take
        a_sh = next(iter(res["forcing"].values()))["(a) shipped: T200 lags through the table"]["steps"].get(repr(sh["h_plant"]))
        L.append("- The candidate of section 3 (the forcing integrated by quadrature into a change of variables, RK4 at "
                 "long substeps): " + (f"within the rule with the fewest plant evaluations at equal substeps (what the generated step takes): "
                                        f"{_desc(min(built, key=lambda r: r['plant_evaluations_per_sample']))}"
                                        if built else f"no case at equal substeps within the rule; the best of all: {_desc(best)}")
                 + f"; plain RK4 at {sh['h_plant']:g} s: "
                 + (f"{_g(a_sh['position_m'])} m / {_g(a_sh['angle_rad'])} rad." if a_sh else "not measured here."))
        for r, q in ng_pairs:
            L.append(f"- More nodes ({r['nodes_per_half']} -> {q['nodes_per_half']} per half, substeps "
                     f"{', '.join(f'{v:g}' for v in r['substeps'])} s): {_g(err(r))} -> {_g(err(q))} (largest of m, rad); "
                     f"the largest errors at t = {r['t_of_max']:g} and {q['t_of_max']:g} s.")
        many = {}  # the most nodes measured at each uniform substep length (exact A)
        for r in tr["cases"]:
            if len(set(r["substeps"])) == 1 and r["A"] == "exact":
                h = r["substeps"][0]
                if h not in many or r["nodes_per_half"] > many[h]["nodes_per_half"]:
                    many[h] = r
        longest = [many[h] for h in sorted(many, reverse=True) if h >= 0.025]
        if longest:
            L.append("- The forcing's quadrature is not what limits the long substeps: with many nodes per half the error "
                     "settles far above the rule (" + "; ".join(
                         f"{len(r['substeps'])} x {r['substeps'][0]:g} s, {r['nodes_per_half']} nodes: {_g(r['position_m'])} m / "
                         f"{_g(r['angle_rad'])} rad" for r in longest)
                     + "): what remains is RK4's own error on the transformed plant at that substep, so the "
                       "candidate's fewest plant evaluations within the rule, above, bound its speed.")
        for g in graded:
            u = uniform.get(len(g["substeps"]))
            if u is not None:
                L.append(f"- Graded against uniform substeps of the same count ({len(g['substeps'])}): "
                         f"{', '.join(f'{v:g}' for v in g['substeps'])} s gives {_g(err(g))}, {len(u['substeps'])} x "
                         f"{u['substeps'][0]:g} s gives {_g(err(u))} (largest of m, rad).")
        for r, q in quad:
            L.append(f"- A interpolated quadratically from its three stage times against A at every node "
                     f"({', '.join(f'{v:g}' for v in r['substeps'])} s, {r['nodes_per_half']} nodes): {_g(err(r))} against "
                     f"{_g(err(q))}: the generated code (`time.thrust_quadrature`) takes A this way, from the time table's LU factors.")
        pick = min(built or ok or [best], key=lambda r: r["plant_evaluations_per_sample"])
        L.append(f"- So at an accuracy within the rule (which plain RK4 at {sh['h_plant']:g} s, the step shipped until 2026-12-05, misses on this run), the "
                 f"candidate takes {sh['plant_evaluations_per_sample'] / pick['plant_evaluations_per_sample']:.0f}x fewer plant "
                 f"evaluations per sample ({pick['plant_evaluations_per_sample']} against {sh['plant_evaluations_per_sample']}) "
                 f"and {pick['map_points_per_sample']} thrust-map points against {sh['map_points_per_sample']}: what it saves "
                 "is the vehicle's part of a sample, not the thrusters' (results/bench.md §5 has the split of a sample's time "
                 "between the two).")
        L.append("- Built as the scenario key `time.thrust_quadrature` (docs/model.md §9), the BlueROV2's shipped step since 2026-12-05 "
                 "(5 nodes per half at 0.01 s): the generated step equals "
                 "this script's method to round-off (tests/test_thrust_quadrature.py), and "
                 "results/step/bluerov2_heavy_alpha5/thrusters.md runs it over whole closed-loop runs against CVODES.")
        gr_ok = [r for r in graded if _within(r)]
        if gr_ok and built:
            g = min(gr_ok, key=lambda r: (r["plant_evaluations_per_sample"], err(r)))
            L.append(f"- Graded substeps are measured here, not built (the generated step takes equal substeps): "
                     f"{_desc(g)}, against the built {len(pick['substeps'])} x {pick['substeps'][0]:g} s, "
                     f"{pick['nodes_per_half']} nodes ({_g(pick['position_m'])} m / {_g(pick['angle_rad'])} rad, "
                     f"{pick['plant_evaluations_per_sample']} plant evaluations and {pick['map_points_per_sample']} map points): "
                     f"{pick['plant_evaluations_per_sample'] / g['plant_evaluations_per_sample']:.2f}x fewer evaluations "
                     "on this one run (the other runs of results/step/bluerov2_heavy_alpha5/thrusters.md not measured so).")
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
