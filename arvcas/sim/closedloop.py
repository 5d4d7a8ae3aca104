"""The whole closed-loop experiment as one CasADi function (docs/model.md §4-6).

One controller sample k (t_k = k h) of :func:`step`:

1. sensors: ``y_k = [eta; nu](t_k) + noise_k`` (noise is an input: a seeded sequence);
2. EKF update on ``[eta; nu]`` (measuring both, or a scenario's sensor set: docs/sensors.md; its prediction
   for k+1 ends the step: :mod:`arvcas.sim.ekf`);
3. the reference ``(y1, y2)`` of the adaptive tracking differentiator (eq. 12-13) and the errors
   ``e = eta_hat - y1``, ``e_dot = eta_dot_hat - y2``;
4. the controller (an :class:`arvcas.controllers.Controller` object: its ``step`` from the
   :class:`StepContext` and its own state to ``tau_v``), the same code path for every law;
5. thrust allocation and saturation (eq. 2, App. B), held over the sample;
6. plant: ``h / h_plant`` RK4 steps of the exactly coupled vehicle + arm with the prescribed arm
   trajectory, payload ramp and disturbance eq. 41.

The run is sample 0's step, then N steps of k >= 1 (:func:`_chain` of :func:`_levels`: nested
chains of 10 calls, like CasADi's ``mapaccum`` but passing only the loop state from call to call, and
the run's constants, a separate input, to every call unchanged); CHAT and RMSE accumulate in the
state, the trace is an output column per sample. Gains, noise, nominal-model factors, disturbance
phases and model parameters are inputs: a new gain set or seed never recompiles.

What depends on time but not on the state (the arm's trajectory and the terms of its wrench that
follow from it, the LU factors of ``M + M_arm``, the disturbance's ``sin``/``cos`` of time) comes in
as the run's last input, the time table of :mod:`arvcas.sim.schedule`, one column per sample with the
records of its RK4 stage times: computed once per (scenario, p), shared by every run of a batch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np

from arvcas.controllers import atd, gains as gains_mod
from arvcas.controllers.base import Controller, call_law, get as get_controller
from arvcas.model import manipulator, thrusters, vehicle, water as water_mod
from arvcas.sim import accumulate, ekf as ekf_mod, profiles, scenario, schedule, signals as signals_mod, thrust_forcing
from arvcas.system.params import Layout as ParamLayout, default_layout, view
from arvcas.sim.scenario import ScenarioConfig
from arvcas.model.spatial import J, J_dot, J_inv
from arvcas.model.uvms import ModelOptions, coupled_terms_scheduled
from arvcas.util.files import check_signals

__all__ = ["StateLayout", "RunSpec", "StepContext", "build_step", "build_run", "derived_constants", "nominal_inertia",
           "controller_memory", "controller_sample", "ControllerSample", "arm_truth", "controller_functions",
           "controller_diagnostics", "controller_sizes", "ControllerSizes", "controller_reads", "INPUTS"]

# the run's inputs, in the order of the compiled function (everything else binds them by name)
INPUTS: tuple[str, ...] = ("gains", "noise", "unc", "phase", "ekf", "water", "p", "sched_time", "sched_arm")
OUTPUTS: tuple[str, ...] = ("chat", "rmse", "ok", "t_fail", "chat_delivered")


class StateLayout:
    """Named slices of a flat column vector (the loop state and the run's constants); not the parameter
    vector's layout, :class:`arvcas.system.params.Layout`."""

    def __init__(self, spec):
        self.slices: dict[str, slice] = {}
        i = 0
        for name, n in spec:
            self.slices[name] = slice(i, i + n)
            i += n
        self.size = i

    def get(self, v, name):
        return v[self.slices[name]]

    def pack(self, values: dict):
        return ca.vertcat(*[values[name] for name in self.slices])


def __getattr__(name: str):
    if name == "Layout":  # its old name, kept one release (two classes were named Layout)
        import warnings

        warnings.warn("arvcas.sim.closedloop.Layout is now StateLayout", DeprecationWarning, stacklevel=2)
        return StateLayout
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def state_layout(ctrl: Controller, n_gains: int, n_thr: int, n_pc: int, n_p: int, n_ekf: int = 5,
                 n_water: int = 0, thr_consts: tuple[int, int] | None = None, n_acc: int = 0,
                 n_lag: int = 0) -> StateLayout:
    """The loop state: the plant (with the thrusters' rotor states and delivered thrust when they have
    dynamics), EKF and reference; the controller's own state; the metrics and status; then the run's
    constants (carried through the loop, never changed). ``thr_consts``: the sizes of the thruster
    dynamics' per-run constants (:func:`arvcas.sim.thrust_forcing.thruster_constants`), None for instantaneous thrusters; ``n_acc``:
    the rows of the run's accumulators (:mod:`arvcas.sim.accumulate`; none: no slot); ``n_lag``: the rows of the
    sensors' shift register of lagging readings (:func:`arvcas.sim.ekf.lag_size`; none: no slot)."""
    dyn = thr_consts is not None
    return StateLayout([
        ("x", 12),  # true plant state [eta; nu]
        *([("thr", n_thr), ("thr_T", n_thr)] if dyn else []),  # rotor states and their thrust at t_k
        # the controller's memory: EKF prior for this sample (covariance: upper triangle, row by row),
        # ATD reference, the law's state
        *controller_memory(ctrl),
        # previous command (CHAT); held realised thrust, or with dynamics the previous delivered wrench
        ("tau_prev", 6), ("tdel_prev", 6) if dyn else ("u_hold", n_thr),
        *([("lag", n_lag)] if n_lag else []),  # the lagging sensors' past readings (docs/sensors.md)
        ("chat_sum", 6), ("chatd_sum", 6), ("e2_sum", 6), *([("acc", n_acc)] if n_acc else []), ("ok", 1), ("t_fail", 1),
        # constants of the run carried through the loop
        ("gains", n_gains), ("unc", 4), ("phase_cs", 12), ("ekf", n_ekf), ("water", n_water), ("p", n_p),
        ("consts", 9), ("pc", n_pc),
        *([("thr_E", thr_consts[0]), ("thr_tab", thr_consts[1])] if dyn else []),
    ])


def derived_constants(P, opts: ModelOptions):
    """Per-run constants computed once from p: trim static wrench (F_z, M_x, M_y) and Mhat = diag(M)."""
    if not manipulator.has_trim(P):
        Fz = Mx = My = 0
    else:
        Fz, Mx, My = manipulator.trim_static(P, opts.n_quad)
    return ca.vertcat(Fz, Mx, My, nominal_inertia(P))


def nominal_inertia(P):
    """Mhat = diag(M) (6): the controllers' nominal inertia (docs/model.md §5)."""
    return ca.diag(vehicle.M(P))


@dataclass(frozen=True)
class RunSpec:
    """What shapes the run's graph: the controller, the scenario's graph-shaping fields, the model options."""

    controller: Controller | str
    cfg: ScenarioConfig
    opts: ModelOptions = ModelOptions()
    layout: ParamLayout | None = None  # the system's parameter layout (default Haidou-1's)
    accumulators: tuple = ()  # arvcas.sim.accumulate.Accumulator: extra sums and maxima, the output "acc"

    @property
    def law(self) -> Controller:
        return get_controller(self.controller)

    @property
    def lay(self) -> ParamLayout:
        return self.layout or default_layout()


def _water(cfg: ScenarioConfig, P, water, t, eta, nu):
    """The water's terms at time ``t`` (docs/model.md §10): ``(current, tether wrench)`` with ``current`` the
    ``(nu_c, nu_c_dot)`` of :func:`arvcas.model.water.relative_current` (None without a current) and the
    tether's wrench in {b} (0 without one)."""
    cur = profiles.current_at(cfg, water, t, eta[2])
    current = None if cur is None else water_mod.relative_current(eta, nu, *cur)
    teth = profiles.tether_of(cfg, water)
    if teth is None:
        return current, 0
    v_c = cur[0] if cur is not None else ca.DM.zeros(3)
    return current, water_mod.tether_wrench(P["env.rho"], eta, v_c, *teth)


def _trim(P, Fz, Mx, My, eta):
    """The trim wrench of docs/model.md §3 from the run's constants (zero without an arm or its trim)."""
    if not manipulator.has_trim(P):
        return ca.DM.zeros(6)
    return manipulator.trim_from_static(Fz, Mx, My, eta)


class StepContext:
    """What a controller's step sees at sample k (all CasADi expressions; {n} unless stated).

    ``t``, ``h`` (s), ``first`` (true at k = 0); ``eta_hat``, ``nu_hat`` (EKF estimate; nu in {b}),
    ``eta_dot_hat = J(eta_hat) nu_hat``; ``eta_ref``, ``eta_ref_dot`` (the ATD's y1, y2),
    ``e = eta_hat - y1``, ``e_dot = eta_dot_hat - y2``; ``eta_d`` (the set point); ``P`` (parameter
    view), ``Mhat`` (the diagonal of M, 6), ``unc`` (nominal-model factors [C, D, g, arm]);
    ``tau_arm`` (the true arm wrench on the vehicle plus the trim, {b}: an oracle the AGSTA's nominal
    model uses a fraction of); ``out``: a dict the step may fill for its signals. After the step the
    loop adds ``tau_v``, ``u_sat``, ``f_true`` and the true ``eta``, ``nu``, ``q``, ``payload`` for the
    signals of :mod:`arvcas.sim.signals`.
    """

    def __init__(self, **kw):
        self.out: dict = {}
        self.__dict__.update(kw)


def _plant_substep(spec: RunSpec) -> tuple[ca.Function, ca.Function]:
    """One RK4 substep of the plant, and the function of its per-run constants.

    ``cl_rk4(x, recs_time, recs_arm, tau, p, consts, phase_cs, pc, water, t) -> x_next``: the time table's
    records (time parts, arm parts) at the stage times t, t + hp/2, t + hp; ``tau`` the body wrench of the
    thrusters, held over the substep (6), or with thruster dynamics their wrench at the three stage times
    (18); ``water`` the run's current and tether (docs/model.md §10), ``t`` the substep's start time.
    Subexpressions of p (and the run constants) alone, such as the links' lengths or sin/cos of the DH
    twists, are taken out by ``casadi.extract_parametric`` and computed once per run by
    ``cl_rk4_consts(p, consts, phase_cs, water) -> pc``.
    """
    cfg, opts, lay = spec.cfg, spec.opts, spec.lay
    hp = cfg.time_h_plant
    dyn = lay.structure.has_thruster_dynamics
    xs, tr_s = ca.SX.sym("x", 12), ca.SX.sym("tau", thrust_forcing.tau_size(cfg, lay.structure))
    p_s, c_s, ph_s = ca.SX.sym("p", len(lay)), ca.SX.sym("consts", 9), ca.SX.sym("phase_cs", 12)
    w_s, t_s = ca.SX.sym("water", cfg.water_vector.size), ca.SX.sym("t")
    R = schedule.records(lay)
    TS, AS = R.time_size, R.arm_size
    recs_t, recs_a = ca.SX.sym("recs_time", 3 * TS), ca.SX.sym("recs_arm", 3 * AS)
    Ps = view(p_s, lay)

    def record(j):  # the time table's record at stage time t + j hp / 2
        return schedule.unpack(ca.vertcat(recs_t[j * TS:(j + 1) * TS], recs_a[j * AS:(j + 1) * AS]), lay)

    def accel(ee, nn, j, rec, force):
        """nu_dot at stage j under the body wrench ``force`` of the thrusters (None: the forcing is taken out)."""
        tr = _trim(Ps, c_s[0], c_s[1], c_s[2], ee)
        dist = profiles.disturbance_tabulated(cfg, rec["dist_sin"], rec["dist_cos"], ph_s)
        f = dist if force is None else force + dist
        if not cfg.has_water:
            return coupled_terms_scheduled(Ps, ee, nn, f, rec, tr, opts)[0]
        current, tether = _water(cfg, Ps, w_s, t_s + j * 0.5 * hp, ee, nn)
        return coupled_terms_scheduled(Ps, ee, nn, f + tether, rec, tr, opts, current)[0]

    def f_plant(xx, j):
        ee, nn = xx[0:6], xx[6:12]
        thrust = tr_s[6 * j:6 * j + 6] if dyn else tr_s
        return ca.vertcat(ca.mtimes(J(ee), nn), accel(ee, nn, j, record(j), thrust))

    if thrust_forcing.quadrature(cfg) is None:
        k_1 = f_plant(xs, 0)
        k_2 = f_plant(xs + 0.5 * hp * k_1, 1)
        k_3 = f_plant(xs + 0.5 * hp * k_2, 1)
        k_4 = f_plant(xs + hp * k_3, 2)
        x_next = ca.cse(xs + hp / 6 * (k_1 + 2 * k_2 + 2 * k_3 + k_4))
    else:
        x_next = ca.cse(thrust_forcing.substep_quadrature(hp, xs, tr_s, [record(j) for j in range(3)], accel))
    x_next, pc_syms, pc_vals = ca.extract_parametric(x_next, ca.vertcat(p_s, c_s, ph_s, w_s), {"prefix": "pc_"})
    pc_s = ca.vertcat(*pc_syms) if pc_syms else ca.SX(0, 1)
    rk4 = ca.Function("cl_rk4", [xs, recs_t, recs_a, tr_s, p_s, c_s, ph_s, pc_s, w_s, t_s], [x_next],
                      ["x", "recs_time", "recs_arm", "tau", "p", "consts", "phase_cs", "pc", "water", "t"], ["x_next"])
    pc_fn = ca.Function("cl_rk4_consts", [p_s, c_s, ph_s, w_s], [ca.vertcat(*pc_vals) if pc_vals else ca.SX(0, 1)],
                        ["p", "consts", "phase_cs", "water"], ["pc"])
    return rk4, pc_fn


def build_step(spec: RunSpec, trace: bool = True, first: bool = False) -> tuple[ca.Function, StateLayout, ca.Function]:
    """One controller sample: (S, K, t_k, noise_k, sched_time_k, sched_arm_k) -> (S_next[, trace_k]).

    ``S`` is the loop state (the fields of the layout before ``gains``), ``K`` the run's constants
    (``gains`` to the end: read by every sample, never written, so never copied from sample to
    sample). ``first``: the step of sample 0, which starts the EKF, the reference and the
    controller's state (:func:`build_run` runs it once, then the step of k >= 1; each is compiled
    with its branch fixed, so neither tests ``k == 0`` per sample).

    Returns (the step, the state's layout, the function of the RK4 substep's per-run constants that
    fills the constants' ``pc``; see :func:`_plant_substep`).

    An MX function calling three generated SX functions: the controller part, ``h / h_plant`` RK4
    substeps of the plant, and the divergence check. ``sched_*_k`` are column k of the run's time
    table (:class:`arvcas.sim.schedule.Table`): the records at the sample's RK4 stage times. The trace
    is the run's signals (:func:`arvcas.sim.signals.trace_signals`) stacked in table order; without
    ``trace`` the per-sample outputs that only the trace needs (e.g. ``f_true``) are not computed.
    """
    steps, L, pc_fn = _build_steps(spec, trace, (first,))
    return steps[0], L, pc_fn


class StepParts(NamedTuple):
    """The generated SX functions one controller sample calls (:func:`step_parts`), in the order it calls them."""

    ctrls: list  # the controller part, one per flag of ``firsts``
    rk4: ca.Function  # one RK4 substep of the plant, ``n_sub`` per sample
    ok: ca.Function  # (C, x_next) -> 1 if the run goes on, 0 if it diverged
    keep: ca.Function  # (C, S, x_next, t) -> the new state
    freeze: ca.Function  # (C, S, x_next, t) -> the old state with ok = 0 and t_fail set
    pc_fn: ca.Function
    layout: StateLayout
    n_sub: int
    thr: tuple | None  # (cl_thr_lag, cl_thr_wrench, their _iv forms) with thruster dynamics (:func:`arvcas.sim.thrust_forcing.thruster_functions`), else None


def check_law(law: Controller, cfg: ScenarioConfig, lay) -> None:
    """The law's ``initial`` and ``step`` called once on symbols (:func:`arvcas.controllers.base.call_law`): a
    law whose code raises or returns the wrong thing is one line before the run's graph is built."""
    sym = ca.SX.sym
    ctx = StepContext(t=sym("t"), h=cfg.time_h, first=ca.SX(1.0), P=view(sym("p", len(lay)), lay), Mhat=sym("Mhat", 6),
                      unc=sym("unc", 4), eta_d=sym("eta_d", 6), eta_hat=sym("eta_hat", 6), nu_hat=sym("nu_hat", 6),
                      eta_dot_hat=sym("eta_dot_hat", 6), eta_ref=sym("y1", 6), eta_ref_dot=sym("y2", 6), e=sym("e", 6),
                      e_dot=sym("e_dot", 6), tau_arm=sym("tau_arm", 6))
    G = {c: sym(c, 6) for c in law.columns()}
    call_law(law, "initial", ctx, G)
    call_law(law, "step", ctx, G, {name: sym(f"c_{name}", n) for name, n in law.state})


def step_parts(spec: RunSpec, trace: bool, firsts) -> StepParts:
    """The SX functions of one controller sample (see :func:`_build_steps`, which calls them)."""
    law, cfg, lay = spec.law, spec.cfg, spec.lay
    check_law(law, cfg, lay)
    cols = law.columns()
    ng = 6 * len(cols)
    rk4, pc_fn = _plant_substep(spec)
    check_signals()  # a signal whose exception CasADi swallowed while the graph was built: stop here, not later
    n_thr = lay.structure.n_thrusters
    dyn = lay.structure.has_thruster_dynamics
    L = state_layout(law, ng, n_thr, pc_fn.size1_out(0), len(lay), cfg.ekf_vector.size, cfg.water_vector.size,
                     thrust_forcing.constant_sizes(cfg, lay), n_accumulated(spec), ekf_mod.lag_size(cfg))
    i_x1, i_ok, i_const = L.slices["x"].stop, L.slices["ok"].start, L.slices["gains"].start  # constants follow t_fail
    Sd, Kc = ca.SX.sym("S", i_const), ca.SX.sym("K", L.size - i_const)
    S = ca.vertcat(Sd, Kc)
    tk = ca.SX.sym("t_k")
    ctrls = [_controller_part(spec, L, S, [Sd, Kc], tk, first, trace) for first in firsts]
    check_signals()

    # finalize: a run that diverges (non-finite state, error bound) is frozen with ok = 0, t_fail set
    # (C: the sample's new loop state without x). A branch, not an element-wise select:
    # cl_ok decides, then one of two copies runs (cl_keep: the new state; cl_freeze: the old one with
    # ok = 0 and t_fail), so a sample pays for one copy of the state instead of three operations per entry.
    Cs, Ss, xn, tks = ca.SX.sym("C", i_const - i_x1), ca.SX.sym("S", i_const), ca.SX.sym("xn", 12), ca.SX.sym("t")
    ok_fn = ca.Function("cl_ok", [Cs, xn], [ca.logic_and(Cs[i_ok - i_x1], ca.mmax(ca.fabs(xn)) < 1e6)])
    keep = ca.Function("cl_keep", [Cs, Ss, xn, tks], [ca.vertcat(xn, Cs)])
    Sfail = ca.vertcat(Ss[:i_ok], 0, ca.if_else(L.get(Ss, "ok"), tks, L.get(Ss, "t_fail")))
    freeze = ca.Function("cl_freeze", [Cs, Ss, xn, tks], [Sfail])
    thr = thrust_forcing.thruster_functions(cfg, lay) if dyn else None
    return StepParts(ctrls, rk4, ok_fn, keep, freeze, pc_fn, L, cfg.substeps, thr)


def _build_steps(spec: RunSpec, trace: bool, firsts) -> tuple[list, StateLayout, ca.Function]:
    """:func:`build_step` for each flag of ``firsts``, sharing one plant substep and one finalize."""
    law, cfg, lay = spec.law, spec.cfg, spec.lay
    parts = step_parts(spec, trace, firsts)
    ctrls, rk4, ok_fn, pc_fn, L, n_sub = parts.ctrls, parts.rk4, parts.ok, parts.pc_fn, parts.layout, parts.n_sub
    i_const = L.slices["gains"].start
    switch = ca.Function.if_else("cl_finalize", parts.keep, parts.freeze)  # input 0: 1 -> keep, 0 -> freeze

    def fin(Cm, Sm, xm, tkm):
        return switch(ok_fn(Cm, xm), Cm, Sm, xm, tkm)

    Rec = schedule.records(lay)
    TS, AS, ns = Rec.time_size, Rec.arm_size, schedule.n_stages(cfg)
    Sm, Km, tkm, nm = ca.MX.sym("S", i_const), ca.MX.sym("K", L.size - i_const), ca.MX.sym("t"), ca.MX.sym("noise", 12)
    sch_t, sch_a = ca.MX.sym("sched_time", schedule.time_rows(cfg, lay)), ca.MX.sym("sched_arm", ns * AS)
    dyn, n_thr = parts.thr is not None, lay.structure.n_thrusters
    names = ("p", "consts", "phase_cs", "pc", "water") + (("thr_E", "thr_tab") if dyn else ())
    kslice = {name: slice(L.slices[name].start - i_const, L.slices[name].stop - i_const) for name in names}
    pm, cm, phm, pcm, wm = (Km[kslice[name]] for name in ("p", "consts", "phase_cs", "pc", "water"))
    if dyn:
        lag, wrench = parts.thr[:2]
        i_cmd = _trace_offset(spec, "command")
    hp = cfg.time_h_plant
    # plant step i's slice of the thrusters' wrench vector
    stride, size = thrust_forcing.tau_stride(cfg), thrust_forcing.tau_size(cfg, lay.structure)
    steps = []
    for first, ctrl in zip(firsts, ctrls):
        res = ctrl(Sm, Km, tkm, nm, sch_t[0:TS], sch_a[0:AS], *([sch_t[ns * TS:]] if cfg.has_trajectory else []))
        Cm, thrust_out = res[0], res[1]
        outs = list(res[2:])
        if dyn:  # thrust_out: the allocation's thrust per thruster; the lag gives the stage wrenches
            W, s_end, T_end, cmd = thrust_forcing.thruster_step(cfg, lay.structure, lag, wrench, thrust_out,
                                                                Sm[L.slices["thr"]], Km[kslice["thr_E"]],
                                                                Km[kslice["thr_tab"]], pm)
            Cm = ca.vertcat(s_end, T_end, Cm)
            if trace:  # the command rows of the trace: the command sent (known once the map is inverted)
                tr = outs[0]
                outs[0] = ca.vertcat(tr[:i_cmd], cmd, tr[i_cmd + n_thr:])
        xm = Sm[L.slices["x"]]
        for i in range(n_sub):
            tau_i = W[stride * i:stride * i + size] if dyn else thrust_out
            xm = rk4(xm, sch_t[2 * i * TS:(2 * i + 3) * TS], sch_a[2 * i * AS:(2 * i + 3) * AS], tau_i, pm, cm, phm, pcm,
                     wm, tkm + i * hp)
        steps.append(ca.Function(f"cl_step_{law.name}" + ("_first" if first else ""), [Sm, Km, tkm, nm, sch_t, sch_a],
                                 [fin(Cm, Sm, xm, tkm)] + outs, ["S", "K", "t", "noise", "sched_time", "sched_arm"],
                                 ["S_next"] + (["trace"] if trace else [])))
    return steps, L, pc_fn


def _trace_offset(spec: RunSpec, name: str) -> int:
    """The first trace row of signal ``name``."""
    st = spec.lay.structure
    i = 0
    for sig in signals_mod.trace_signals(spec.law, st):
        if sig.name == name:
            return i
        i += sig.n(st.n_thrusters, st.n_joints)
    raise KeyError(name)
# the controller's own memory, in this order (the loop state's and the exported controller's)
def controller_memory(law: Controller) -> list[tuple[str, int]]:
    """The fields of a controller's memory from sample to sample: the EKF prior (``xh``, the covariance's
    upper triangle ``Pc``), the ATD reference (``y1``, ``y2``, ``r0``) and the law's own state
    (``c_<name>``); in the loop state's order (:func:`state_layout`)."""
    return [("xh", 12), ("Pc", ekf_mod.N_PSYM), ("y1", 6), ("y2", 6), ("r0", 6), *[(f"c_{name}", n) for name, n in law.state]]


class ControllerSample:
    """What :func:`controller_sample` returns: the context the law saw (``ctx``), the commanded body
    wrench ``tau_v``, the allocated thrust ``u_cmd`` and the saturated thrust ``u_sat`` (N, per
    thruster, the command the thrusters receive), and ``memory``: the controller's memory for the next
    sample (name -> expression, :func:`controller_memory`'s fields)."""

    def __init__(self, ctx, tau_v, u_cmd, u_sat, memory):
        self.ctx, self.tau_v, self.u_cmd, self.u_sat, self.memory = ctx, tau_v, u_cmd, u_sat, memory


def controller_sample(law: Controller, cfg: ScenarioConfig, P, y, tk, first, memory: dict, gains, unc, ekf, Mhat,
                      eta_d, tau_arm, ref=None) -> ControllerSample:
    """One sample of the controller, from the measurement to the thrust: steps 2-5 of the module docstring.

    The one definition of the controller: the run's sample (:func:`_controller_part`) and the exported
    controller (:mod:`arvcas.export.controller`) both build their graphs with it, so they perform
    the same operations in the same order. ``y``: the measurement ``[eta; nu] + noise`` (12);
    ``tk``: t_k (s); ``first``: 1 at sample 0 (a constant: its branches fold away), when the EKF
    starts from ``y`` and the reference and the law's state start; ``memory``: the controller's memory
    (name -> expression, :func:`controller_memory`); ``gains`` (the law's flat vector), ``unc`` (nominal
    factors [C, D, g, arm]), ``ekf`` ([q_eta, q_nu, var_position, var_attitude, var_velocity]),
    ``Mhat`` (:func:`nominal_inertia`), ``eta_d`` (the set point), ``tau_arm`` (the arm's wrench on the
    vehicle plus the trim, {b}: the run's true value, which only a nominal model reads); ``ref``: a task's
    desired ``(eta_d(t_k), eta_d_dot(t_k))`` (docs/tasks.md), None for station keeping at ``eta_d``.
    """
    cols = law.columns()
    k = len(cols)
    G = {c: ca.vertcat(*[gains[d * k + j] for d in range(6)]) for j, c in enumerate(cols)}
    h = cfg.time_h
    # 2. EKF update (H = I, R = sensor covariance); the first sample starts from y_0 with P = R
    xh, Pc = ekf_mod.measure(cfg, y, tk, first, memory["xh"], memory["Pc"], ekf)
    eta_hat, nu_hat = xh[0:6], xh[6:12]
    eta_dot_hat = ca.mtimes(J(eta_hat), nu_hat)

    # 3. ATD reference (docs/model.md §5): y1(0) = eta_hat(0), y2(0) = 0, A = max(|eta_d - eta_hat(0)|, A_min)
    if ref is not None:  # a task (docs/tasks.md): the ATD takes the start's offset from eta_d(t) to zero
        eta_d, (y1, y2), r0, h0, y1n, y2n = _task_reference(cfg, ref, eta_hat, first, memory, h)
    else:
        r0_first, h0 = atd.atd_params(eta_d - eta_hat, cfg.atd_T, h, cfg.atd_A_min)
        r0 = ca.if_else(first, r0_first, memory["r0"])
        y1 = ca.if_else(first, eta_hat, memory["y1"])
        y2 = ca.if_else(first, ca.DM.zeros(6), memory["y2"])
    e = ekf_mod.held_only(cfg, eta_hat - y1)
    e_dot = ekf_mod.held_only(cfg, eta_dot_hat - y2)

    # 4. the controller: its state (initial values at the first sample), its step
    ctx = StepContext(t=tk, h=h, first=first, P=P, Mhat=Mhat, unc=unc, eta_d=eta_d, eta_hat=eta_hat,
                      nu_hat=nu_hat, eta_dot_hat=eta_dot_hat, eta_ref=y1, eta_ref_dot=y2, e=e, e_dot=e_dot,
                      tau_arm=tau_arm)
    init = call_law(law, "initial", ctx, G)
    xc = {name: ca.if_else(first, init[name], memory[f"c_{name}"]) for name, _ in law.state}
    tau_v, xc_next = call_law(law, "step", ctx, G, xc)

    # 5. allocation and saturation
    u_cmd = thrusters.allocate(P, tau_v)
    u_sat = thrusters.saturate(P, u_cmd)
    # (a thruster command map, thrust -> the unit the thrusters take, belongs here, after the
    # saturation, so that the run and the exported controller send the same commands)

    if ref is None:
        y1n, y2n = atd.atd_step(y1, y2, eta_d, r0, h0, h)
    xh_next, Pc_next = ekf_mod.predict(xh, Pc, h, ekf[0], ekf[1])
    memory_next = {"xh": xh_next, "Pc": Pc_next, "y1": y1n, "y2": y2n, "r0": r0,
                   **{f"c_{name}": xc_next[name] for name, _ in law.state}}
    assert list(memory_next) == [name for name, _ in controller_memory(law)]
    return ControllerSample(ctx, tau_v, u_cmd, u_sat, memory_next)


def _task_reference(cfg: ScenarioConfig, ref, eta_hat, first, memory: dict, h):
    """A task's reference (docs/tasks.md): ``y1 = eta_d(t) + z1``, ``y2 = eta_d_dot(t) + z2``, with the ATD's
    state ``(z1, z2)`` (the memory's ``y1``, ``y2``) started at ``(eta_hat(0) - eta_d(0), -eta_d_dot(0))`` (so
    that ``y1(0) = eta_hat(0)``, ``y2(0) = 0``, as station keeping) and driven to zero by eq. 12 with input 0.
    Returns ``(eta_d(t_k), (y1, y2), r0, h0, z1(k+1), z2(k+1))``."""
    pd, vd = ref
    r0_first, h0 = atd.atd_params(pd - eta_hat, cfg.atd_T, h, cfg.atd_A_min)
    r0 = ca.if_else(first, r0_first, memory["r0"])
    z1 = ca.if_else(first, eta_hat - pd, memory["y1"])
    z2 = ca.if_else(first, -vd, memory["y2"])
    z1n, z2n = atd.atd_step(z1, z2, ca.DM.zeros(6), r0, h0, h)
    return pd, (pd + z1, vd + z2), r0, h0, z1n, z2n


# ---- the controller alone (arvcas export-controller: arvcas.export.controller) ------------------------

_BY_NAME = {s.name: s for s in signals_mod.COMMON}
_DIAG_COMMON = (
    _BY_NAME["eta_hat"],
    signals_mod.Signal("nu_hat", 6, signals_mod.RATE_UNITS, "{b}", "u, v, w, p, q, r", "EKF estimate of nu (body velocity about the COB)",
           lambda c: c.nu_hat),
    _BY_NAME["eta_ref"],
    signals_mod.Signal("eta_ref_dot", 6, signals_mod.RATE_UNITS, "{n}", "x, y, z, phi, theta, psi",
           "reference rate y2 of the adaptive tracking differentiator (eq. 12-13)", lambda c: c.eta_ref_dot),
    _BY_NAME["tau_cmd"],
)


def controller_diagnostics(law: Controller) -> tuple:
    """The signals the controller alone gives after a sample (an exported controller's diagnostics), in
    order: the estimate, the reference, the commanded wrench, then the law's own traced signals (the
    run's signals of the same names)."""
    return _DIAG_COMMON + tuple(law.signals)




@dataclass(frozen=True)
class ControllerSizes:
    """Sizes of the controller alone (:func:`controller_functions`): its parameters' fields (gains, nominal
    factors, EKF tuning, set point, model parameters), its memory, thrusters and diagnostics."""

    n_gains: int
    n_p: int
    n_u: int
    n_mem: int
    n_diag: int
    n_ekf: int = 5  # [q_eta, q_nu, 3 group variances], or with per-axis sensors [q_eta, q_nu, 12 variances]

    @property
    def params(self) -> dict[str, int]:
        return {"gains": self.n_gains, "unc": 4, "ekf": self.n_ekf, "eta_d": 6, "p": self.n_p}

    @property
    def n_k(self) -> int:  # the params, then Mhat
        return sum(self.params.values()) + 6


def controller_sizes(law: Controller, layout, cfg: ScenarioConfig | None = None) -> ControllerSizes:
    return ControllerSizes(n_ekf=5 if cfg is None else cfg.ekf_vector.size,
                           n_gains=gains_mod.n_gains(law), n_p=len(layout), n_u=layout.structure.n_thrusters,
                 n_mem=sum(n for _, n in controller_memory(law)),
                 n_diag=sum(s.n(layout.structure.n_thrusters, layout.structure.n_joints) for s in controller_diagnostics(law)))


def controller_functions(law, cfg: ScenarioConfig, layout, prefix: str = "") -> dict[str, ca.Function]:
    """The controller alone as CasADi functions (names carry ``prefix``), for ``arvcas export-controller``:

    * ``mhat(p) -> Mhat``: :func:`arvcas.sim.closedloop.nominal_inertia`, once per init (the run's
      ``derived_constants``);
    * ``prep0(k) -> kp0``, ``prep(k) -> kp``: the terms of sample 0's and sample k's step that depend on
      ``k`` alone (the allocation's inverse, products of gains...), once per init;
    * ``step0(mem, k, kp0, y, t, tau_arm)`` and ``step(mem, k, kp, y, t, tau_arm) -> (mem_next, u,
      diag)``: one controller sample (:func:`controller_sample`); ``k`` = the parameters
      (:attr:`ControllerSizes.params`) then Mhat; ``u`` the saturated thrust per thruster (N);
      ``diag`` the signals of :func:`controller_diagnostics`.

    Built with :func:`controller_sample`, as the run's sample: the same operations in the same order;
    the terms of ``k`` alone are taken out (:func:`casadi.extract_parametric`), not changed. A ValueError
    (one line) for a scenario with a trajectory, or a law whose traced signals read the plant's truth.
    """
    law = get_controller(law)
    if cfg.has_trajectory:
        raise ValueError("export-controller: the scenario has a [trajectory] (docs/tasks.md); the exported controller "
                         "takes a set point eta_d only")
    sz = controller_sizes(law, layout, cfg)
    p = ca.SX.sym("p", sz.n_p)
    fns = {"mhat": ca.Function(prefix + "mhat", [p], [nominal_inertia(view(p, layout))], ["p"], ["Mhat"])}
    for first in (True, False):
        mem, k = ca.SX.sym("mem", sz.n_mem), ca.SX.sym("k", sz.n_k)
        meas = [i for i, _, _ in scenario.measured(cfg)]  # a sensor set's components of [eta; nu] (docs/sensors.md)
        y, t, tau_arm = ca.SX.sym("y", len(meas)), ca.SX.sym("t"), ca.SX.sym("tau_arm", 6)
        y12 = y if scenario.sensor_set(cfg) is None else \
            ca.vertcat(*[y[meas.index(i)] if i in meas else 0 for i in range(12)])
        f, i = {}, 0
        for name, n in (*sz.params.items(), ("Mhat", 6)):
            f[name] = k[i:i + n]
            i += n
        memory, i = {}, 0
        for name, n in controller_memory(law):
            memory[name] = mem[i:i + n]
            i += n
        cs = controller_sample(law, cfg, view(f["p"], layout), y12, t, ca.SX(1.0 if first else 0.0), memory,
                               f["gains"], f["unc"], f["ekf"], f["Mhat"], f["eta_d"], tau_arm)
        ctx = cs.ctx
        ctx.__dict__.update(tau_v=cs.tau_v, u_sat=cs.u_sat)
        try:
            diag = [sig.value(ctx) for sig in controller_diagnostics(law)]
        except (AttributeError, KeyError) as e:
            raise ValueError(f"controller {law.name}: a traced signal needs the plant's truth ({e}); "
                             f"only signals of the controller's own quantities can be exported") from None
        outs = ca.cse([ca.vertcat(*cs.memory.values()), cs.u_sat, ca.vertcat(*diag)])
        whole, syms, vals = ca.extract_parametric(ca.vertcat(*outs), k, {"prefix": "kp_"})
        kp = ca.SX.sym("kp", 0) if not syms else ca.vertcat(*syms)
        parts = ca.vertsplit(whole, list(np.cumsum([0] + [o.shape[0] for o in outs])))
        tag = "0" if first else ""
        fns["prep" + tag] = ca.Function(prefix + "prep" + tag, [k], [ca.vertcat(*vals) if vals else ca.SX(0, 1)],
                                        ["k"], ["kp" + tag])
        fns["step" + tag] = ca.Function(prefix + "step" + tag, [mem, k, kp, y, t, tau_arm], parts,
                                        ["mem", "k", "kp" + tag, "y", "t", "tau_arm"], ["mem_next", "u", "diag"])
    return fns


def controller_reads(fns: dict[str, ca.Function], name: str) -> bool:
    """Whether the controller's command or memory depends on the step input ``name`` (``tau_arm``, ``t``)
    of :func:`controller_functions`."""
    out = []
    for key in ("step0", "step"):
        f = fns[key]
        sym = f.sx_in()
        res = f.call(sym)
        out.append(ca.depends_on(ca.vertcat(res[0], res[1]), sym[f.index_in(name)]))
    return any(out)


def _controller_part(spec: RunSpec, L: StateLayout, S, ins, tk, first: bool, trace: bool) -> ca.Function:
    """The controller part of one sample (sample 0 if ``first``): (S, K, t_k, noise_k, rec0_time, rec0_arm)
    -> (C, thrust[, trace_k]); ``S`` the SX loop state and constants stacked, ``ins`` its two symbols.

    ``thrust``: the realised body wrench ``B sat(u)`` held over the sample; with thruster dynamics the
    allocation's saturated thrust per thruster (the lag, in the step, turns it into the delivered wrench),
    and ``C`` leaves out the thrusters' own state (the step puts it first)."""
    law, cfg, opts = spec.law, spec.cfg, spec.opts
    noise = ca.SX.sym("noise", 12)
    lay = spec.lay
    Rec = schedule.records(lay)
    rec0_t, rec0_a = ca.SX.sym("rec0_time", Rec.time_size), ca.SX.sym("rec0_arm", Rec.arm_size)
    R0 = schedule.unpack(ca.vertcat(rec0_t, rec0_a), lay)  # the time table's record at t_k
    ref = ca.SX.sym("ref", schedule.REF_ROWS) if cfg.has_trajectory else None  # eta_d, eta_d_dot at t_k (docs/tasks.md)
    P = view(L.get(S, "p"), lay)
    consts = L.get(S, "consts")
    Fz, Mx, My, Mhat = consts[0], consts[1], consts[2], consts[3:9]
    unc, phase_cs = L.get(S, "unc"), L.get(S, "phase_cs")
    h = cfg.time_h
    x = L.get(S, "x")
    # 1. sensors: a lagging sensor reports the state of d samples ago (docs/sensors.md)
    x_read, lag_next = ekf_mod.delayed(cfg, x, L.get(S, "lag") if "lag" in L.slices else None, first)
    y = x_read + noise
    first = ca.SX(1.0 if first else 0.0)  # a constant: every branch on it folds away
    ok = L.get(S, "ok")
    eta_d = ca.DM(cfg.initial_eta_d)


    q, pl = R0["q"], R0["payload"]
    eta, nu = x[0:6], x[6:12]
    dyn = lay.structure.has_thruster_dynamics
    # the thrust acting at t_k: the held realised thrust, or with dynamics the rotors' delivered thrust
    u_hold = L.get(S, "thr_T" if dyn else "u_hold")
    tau_real_held, trim, nud_true, tau_m_true = _true_terms(cfg, opts, P, x, u_hold, R0, (Fz, Mx, My), phase_cs,
                                                            L.get(S, "water"), tk)

    # 2-5. the controller: EKF, reference, law, allocation and saturation
    memory = {name: L.get(S, name) for name, _ in controller_memory(law)}
    cs = controller_sample(law, cfg, P, y, tk, first, memory, L.get(S, "gains"), unc, L.get(S, "ekf"), Mhat, eta_d,
                           tau_m_true + trim, None if ref is None else (ref[0:6], ref[6:12]))
    ctx, tau_v, u_sat, y1 = cs.ctx, cs.tau_v, cs.u_sat, cs.ctx.eta_ref
    tau_real = ca.mtimes(thrusters.B_T(P), u_sat)

    # f_true, eq. 6, at t_k: f = Mhat eta_ddot - tau_eta,real (eq. 5), eta_ddot = J nu_dot + Jdot nu
    Jdot = J_dot(eta, ca.mtimes(J(eta), nu))
    eta_ddot = ca.mtimes(J(eta), nud_true) + ca.mtimes(Jdot, nu)
    f_true = Mhat * eta_ddot - ca.mtimes(J_inv(eta).T, tau_real_held)

    # metrics (docs/model.md §6) and divergence of the controller part
    # a task's error is against the desired trajectory (docs/tasks.md); only on the DOFs it holds (docs/sensors.md)
    e_true = ekf_mod.held_only(cfg, eta - (y1 if ref is None else ref[0:6]))
    chat_sum = L.get(S, "chat_sum") + ca.if_else(first, 0, ca.fabs(tau_v - L.get(S, "tau_prev")))
    # CHAT on the delivered wrench (what the water sees): the realised B sat(u) of each sample, or with
    # dynamics the rotors' wrench at each sample time (docs/model.md §6)
    if dyn:
        chatd_sum = L.get(S, "chatd_sum") + ca.if_else(first, 0, ca.fabs(tau_real_held - L.get(S, "tdel_prev")))
    else:
        chatd_sum = L.get(S, "chatd_sum") + ca.if_else(first, 0, ca.fabs(tau_real - tau_real_held))
    # RMSE over k = 0..N-1 (eq. 43); the last sample k = N only closes CHAT's last difference
    last = tk > cfg.time_duration - 0.5 * h
    e2_sum = L.get(S, "e2_sum") + ca.if_else(last, 0, e_true**2)
    lim = ca.DM([cfg.limits_e_position] * 3 + [cfg.limits_e_attitude] * 3)
    ok_c = ca.logic_and(ok, ca.logic_and(ca.mmax(ca.fabs(e_true) / lim) < 1, ca.mmax(ca.fabs(tau_v)) < 1e12))
    # the sample's new loop state except x (the plant's, set in finalize) and the run's constants
    # (never changed: the step passes them on itself)
    new = {
        **cs.memory, "tau_prev": tau_v, **({"tdel_prev": tau_real_held} if dyn else {"u_hold": u_sat}),
        **({} if lag_next is None else {"lag": lag_next}),
        "chat_sum": chat_sum, "chatd_sum": chatd_sum, "e2_sum": e2_sum,
        **({"acc": _accumulate(spec, L.get(S, "acc"), last, accumulate.SampleView(
            t=tk, h=h, e=e_true, eta=eta, nu=nu, eta_ref=y1, tau_cmd=tau_v, tau_del=tau_real_held,
            thrust=u_hold if dyn else u_sat, u_alloc=cs.u_cmd, u_min=thrusters.limits(P)[0],
            u_max=thrusters.limits(P)[1], events=accumulate.event_times(cfg), duration=cfg.time_duration, P=P))}
           if spec.accumulators else {}),
        "ok": ok_c, "t_fail": L.get(S, "t_fail"),
    }
    names = [n for n in L.slices if n not in ("thr", "thr_T")]  # the thrusters' state comes from the step
    assert names.index("x") == 0 and list(new) == names[1:names.index("gains")]
    C = ca.vertcat(*new.values())
    outs = [C, u_sat if dyn else tau_real]
    if trace:
        ctx.__dict__.update(tau_v=tau_v, u_sat=u_hold if dyn else u_sat, u_cmd=u_sat, tau_del=tau_real_held,
                            command=ca.DM.zeros(lay.structure.n_thrusters), f_true=f_true, eta=eta, nu=nu, q=q,
                            payload=pl)
        outs.append(ca.vertcat(*[sig.value(ctx) for sig in signals_mod.trace_signals(law, lay.structure)]))
    name = f"cl_ctrl_{law.name}" + ("_first" if first.is_one() else "") + ("_tr" if trace else "")
    return ca.Function(name, [*ins, tk, noise, rec0_t, rec0_a] + ([] if ref is None else [ref]), ca.cse(outs))


def _accumulate(spec: RunSpec, acc, last, view):
    """The accumulators' new values (:mod:`arvcas.sim.accumulate`): each sum adds, each max keeps the
    larger, the sample's value over k = 0 .. N-1 (the last sample k = N adds nothing, as for RMSE)."""
    n_thr, n_ev = spec.lay.structure.n_thrusters, len(accumulate.event_times(spec.cfg))
    out, i = [], 0
    for a in spec.accumulators:
        w = accumulate.width(a, n_thr, n_ev)
        v = ca.vertcat(a.value(view))
        if v.shape != (w, 1):
            raise ValueError(f"accumulator {a.name}: value has shape {v.shape}, expected ({w}, 1)")
        old = acc[i:i + w]
        out.append(old + ca.if_else(last, 0, v) if a.kind == "sum" else ca.fmax(old, ca.if_else(last, 0, v)))
        i += w
    return ca.vertcat(*out)


def n_accumulated(spec: RunSpec) -> int:
    """The rows of the run's output ``acc`` (0 without accumulators)."""
    n_ev = len(accumulate.event_times(spec.cfg))
    return sum(accumulate.width(a, spec.lay.structure.n_thrusters, n_ev) for a in spec.accumulators)


def _true_terms(cfg, opts, P, x, u_hold, R0, static, phase_cs, water=None, tk=None):
    """The true state's coupled terms at t_k with the held thrust, for f_true (eq. 6) and the arm's
    wrench: (B_T u_hold, the trim wrench, nu_dot, tau_m). ``static``: (F_z, M_x, M_y) of
    :func:`derived_constants`; ``R0``: the time table's record at t_k; ``water``, ``tk``: the run's
    current and tether at t_k (docs/model.md §10; needed when the scenario has them)."""
    eta, nu = x[0:6], x[6:12]
    tau_real_held = ca.mtimes(thrusters.B_T(P), u_hold)
    trim = _trim(P, *static, eta)
    tau_dist = profiles.disturbance_tabulated(cfg, R0["dist_sin"], R0["dist_cos"], phase_cs)
    if cfg.has_water:
        current, tether = _water(cfg, P, water, tk, eta, nu)
        nud_true, tau_m_true = coupled_terms_scheduled(P, eta, nu, tau_real_held + tau_dist + tether, R0, trim, opts,
                                                       current)
    else:
        nud_true, tau_m_true = coupled_terms_scheduled(P, eta, nu, tau_real_held + tau_dist, R0, trim, opts)
    return tau_real_held, trim, nud_true, tau_m_true


def arm_truth(spec: RunSpec) -> ca.Function:
    """``(x, u_hold, rec_time, rec_arm, p, phase, water, t) -> tau_m + trim``: the run's true arm wrench on the
    vehicle plus the trim at sample k (the ``tau_arm`` a controller's step sees: :class:`StepContext`),
    from the true state, the thrust acting at t_k (``u_hold``: the held thrust, or with thruster dynamics the
    rotors' delivered thrust), the time table's record at t_k, and the run's ``water`` input and t_k (its
    current and tether, docs/model.md §10; empty without them); the run's operations."""
    lay, cfg = spec.lay, spec.cfg
    Rec = schedule.records(lay)
    x, u_hold = ca.SX.sym("x", 12), ca.SX.sym("u_hold", lay.structure.n_thrusters)
    rt, ra = ca.SX.sym("rec_time", Rec.time_size), ca.SX.sym("rec_arm", Rec.arm_size)
    p, phase = ca.SX.sym("p", len(lay)), ca.SX.sym("phase", 6)
    water, t = ca.SX.sym("water", cfg.water_vector.size), ca.SX.sym("t")
    P = view(p, lay)
    consts = derived_constants(P, spec.opts)
    _, trim, _, tau_m = _true_terms(cfg, spec.opts, P, x, u_hold, schedule.unpack(ca.vertcat(rt, ra), lay),
                                    (consts[0], consts[1], consts[2]), ca.vertcat(ca.cos(phase), ca.sin(phase)),
                                    water, t)
    return ca.Function("arm_truth", [x, u_hold, rt, ra, p, phase, water, t], [tau_m + trim],
                       ["x", "u_hold", "rec_time", "rec_arm", "p", "phase", "water", "t"], ["tau_arm"])


def build_run(spec: RunSpec, trace: bool = False) -> ca.Function:
    """The whole run as one MX Function of (gains, noise 12x(N+1), unc[4], phase[6], ekf, water, p, sched_time,
    sched_arm).

    ``ekf = [q_eta, q_nu, var_position, var_attitude, var_velocity]`` (or with per-axis sensors
    ``[q_eta, q_nu, 12 variances]``): EKF process noise per step and the sensor variances its R assumes (the
    noise input itself is drawn outside). ``water``: the scenario's current and tether
    (:attr:`arvcas.sim.scenario.ScenarioConfig.water_vector`, empty without them). ``sched_time`` and
    ``sched_arm`` are the time table of (scenario, p) from :func:`arvcas.sim.schedule.table` (the same for
    every gain set, seed and controller, so a batch computes it once).

    ``trace=False``: outputs (chat[6], rmse[6], ok, t_fail, chat_delivered[6]) (:data:`OUTPUTS`);
    ``trace=True``: also the per-sample trace.
    """
    (step0, step), L, pc_fn = _build_steps(spec, trace, (True, False))
    check_signals()
    cfg, law = spec.cfg, spec.law
    n = scenario.n_samples(cfg)
    ng = 6 * len(law.columns())
    G = ca.MX.sym("gains", ng)
    noise = ca.MX.sym("noise", 12, n)
    unc = ca.MX.sym("unc", 4)
    phase = ca.MX.sym("phase", 6)
    ekf = ca.MX.sym("ekf", cfg.ekf_vector.size)
    water = ca.MX.sym("water", cfg.water_vector.size)
    p = ca.MX.sym("p", len(spec.lay))
    Rec = schedule.records(spec.lay)
    sched_t = ca.MX.sym("sched_time", schedule.time_rows(cfg, spec.lay), n)
    sched_a = ca.MX.sym("sched_arm", schedule.n_stages(cfg) * Rec.arm_size, n)
    S0, K = run_start(spec, L, pc_fn, G, unc, phase, ekf, water, p)
    tgrid = ca.DM(sample_times(cfg)).T
    out = _chain(f"run_{law.name}_loop", [step0] + _levels(step, n - 1)).call([S0, K, tgrid, noise, sched_t, sched_a])
    acc = [out[0][L.slices["acc"]]] if spec.accumulators else []  # the accumulators, raw (arvcas.sim.accumulate)
    outs = list(run_end(L, out[0], n - 1)) + acc + ([out[1]] if trace else [])
    names = list(OUTPUTS) + (["acc"] if acc else []) + (["trace"] if trace else [])
    name = f"run_{law.name}" + ("_trace" if trace else "")
    ins = {"gains": G, "noise": noise, "unc": unc, "phase": phase, "ekf": ekf, "water": water, "p": p,
           "sched_time": sched_t, "sched_arm": sched_a}
    return ca.Function(name, [ins[k] for k in INPUTS], outs, list(INPUTS), names)


def sample_times(cfg: ScenarioConfig) -> np.ndarray:
    """t_k = k h of the run's samples k = 0..N (the values every step's ``t`` input takes)."""
    return np.arange(scenario.n_samples(cfg)) * cfg.time_h


def run_start(spec: RunSpec, L: StateLayout, pc_fn: ca.Function, G, unc, phase, ekf, water, p):
    """The run's first loop state S0 and its constants K (the step's inputs ``S`` and ``K``) from the
    run's inputs (MX): the one definition :func:`build_run` and the lockstep runs share."""
    consts = _consts_fn(spec.opts, spec.lay)(p)
    x0 = ca.DM(list(spec.cfg.initial_eta0) + list(spec.cfg.initial_nu0))
    phase_cs = ca.vertcat(ca.cos(phase), ca.sin(phase))
    i_ok = L.slices["ok"].start  # every loop state before "ok" starts at zero (sample 0's step sets its values)
    S0 = ca.vertcat(x0, ca.MX.zeros(i_ok - 12), ca.MX(1), ca.MX(-1))
    K = ca.vertcat(G, unc, phase_cs, ekf, water, p, consts, pc_fn(p, consts, phase_cs, water))
    if spec.lay.structure.has_thruster_dynamics:
        K = ca.vertcat(K, *thrust_forcing.constants_function(spec.cfg, spec.lay)(p))
    assert S0.shape[0] + K.shape[0] == L.size
    return S0, K


def run_end(L: StateLayout, Sf, N: int):
    """The run's outputs (:data:`OUTPUTS`) from the last loop state ``Sf`` after N samples (MX)."""
    chat = Sf[L.slices["chat_sum"]] / N
    rmse = ca.sqrt(Sf[L.slices["e2_sum"]] / N)
    return chat, rmse, Sf[L.slices["ok"]], Sf[L.slices["t_fail"]], Sf[L.slices["chatd_sum"]] / N


def _levels(f: ca.Function, n: int, base: int = 10) -> list:
    """Functions that run ``f`` n times in all, in order: n written in base 10, each digit d of
    weight 10^j giving d calls of a level of 10^j samples (level j+1 = :func:`_chain` of 10 level-j
    calls). Only the levels that are called are built (3 levels of 10 for n = 1000)."""
    chain, c, m = [], f, n
    while True:
        chain += [c] * (m % base)
        m //= base
        if m == 0:
            return chain
        c = _chain(f"{c.name()}_x{base}", [c] * base)


def _chain(name: str, funcs) -> ca.Function:
    """The samples of ``funcs`` one after another: (S, K, per-sample inputs...) -> (S_last, per-sample outputs...).

    Input 0 is the loop state, passed from call to call (only the last is an output: a run that
    needs the state of every sample does not exist, so none is stored); input 1 the run's
    constants, the same for every call; the other inputs and outputs are per sample, a column
    block per call. Each input is the horzcat of the calls' own symbols, so the generated code reads
    a call's block in place (no copy); the state stays in the work vector between calls.
    """
    f0 = funcs[0]
    S, K = ca.MX.sym("S", f0.sparsity_in(0)), ca.MX.sym("K", f0.sparsity_in(1))
    per_in = [[] for _ in range(2, f0.n_in())]
    per_out = [[] for _ in range(1, f0.n_out())]
    s = S
    for j, g in enumerate(funcs):
        syms = [ca.MX.sym(f"{g.name_in(i)}_{j}", g.sparsity_in(i)) for i in range(2, g.n_in())]
        res = g.call([s, K, *syms])
        s = res[0]
        for lst, v in zip(per_in, syms):
            lst.append(v)
        for lst, v in zip(per_out, res[1:]):
            lst.append(v)
    return ca.Function(name, [S, K] + [ca.horzcat(*v) for v in per_in], [s] + [ca.horzcat(*v) for v in per_out],
                       f0.name_in(), f0.name_out())


def _consts_fn(opts: ModelOptions, layout: ParamLayout | None = None) -> ca.Function:
    lay = layout or default_layout()
    p = ca.SX.sym("p", len(lay))
    return ca.Function("derived_constants", [p], [derived_constants(view(p, lay), opts)])
