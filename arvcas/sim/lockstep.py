"""Runs in lockstep: W runs of a batch evaluated together, one vector lane each (issue 26).

The scalar run (:func:`arvcas.sim.closedloop.build_run`) is an MX function calling, per controller
sample, the SX functions of :func:`arvcas.sim.closedloop.step_parts`: the controller part, ``n_sub``
RK4 plant steps, the divergence check and one of two copies of the loop state (keep, or freeze a
run that diverged). A lockstep run calls the same SX functions rewritten to W lanes
(:mod:`arvcas.build.lanes`: every lane's result equal to the scalar function's to the bit) from a
loop written here in C, with the divergence branch as a per-lane select; the run's start (its first
loop state and constants) and end (the metrics) are the scalar run's own MX expressions
(:func:`~arvcas.sim.closedloop.run_start`, :func:`~arvcas.sim.closedloop.run_end`), compiled into the
same library and called once per run. So every lane's outputs equal the scalar run's to the bit
(tests/test_lockstep.py checks it over the controllers, the shipped systems and diverging runs).

The runs of a batch are taken W at a time from a shared counter by every thread (the last group
padded with copies of its last run, whose outputs are dropped). All lanes of a group are at the same
sample, so the time table's column is shared (a broadcast load). A run that diverges is frozen, as in
the scalar run, which evaluates it to the end all the same: its lane costs the group what the scalar
run costs alone; a group whose runs have all diverged stops (its frozen states no longer change, so
the outputs are the same bits).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from arvcas.build import calls, codegen, lanes
from arvcas.sim import closedloop, scenario, schedule

__all__ = ["LockstepRun", "build", "ENTRY"]

ENTRY = "_arvcas_lanes"  # the C entry point of a lockstep library: <name>_arvcas_lanes


class LockstepRun:
    """A compiled lockstep run: the library's main function (the run's start and end) and its loop."""

    def __init__(self, fn: ca.Function, W: int):
        self.function, self.W = fn, W
        self.loop = calls.batch_loop(fn, ENTRY)
        if self.loop is None:
            raise codegen.CacheError(f"{fn.name()}: the library has no lockstep loop {fn.name()}{ENTRY}")

    def evaluate(self, n: int, bound: list[np.ndarray], per_run, outs: list[np.ndarray], n_threads: int) -> None:
        """n runs: ``bound`` the run's inputs in :data:`closedloop.INPUTS` order (Fortran arrays, a
        column block per run for the names in ``per_run``), ``outs`` (chat, rmse, ok, t_fail) arrays
        of n columns each, written in place."""
        names = closedloop.INPUTS
        if per_run & {"ekf", "p", "sched_time", "sched_arm"}:
            raise ValueError(f"lockstep: {sorted(per_run & {'ekf', 'p', 'sched_time', 'sched_arm'})} must be shared by the batch")
        sa = [a.shape[0] * a.shape[1] // n if k in per_run else 0 for k, a in zip(names, bound)]
        f = self.function
        failed = calls.run_loop(self.loop, n, [a.ctypes.data for a in bound], sa, [r.ctypes.data for r in outs],
                                [r.shape[0] for r in outs], int(f.sz_iw()), int(f.sz_w()), n_threads,
                                chunk=self.W, keep=(bound, outs))
        if failed is not None:
            raise RuntimeError(f"{f.name()}: run {failed} of {n} failed")


def _main_function(name: str, spec: closedloop.RunSpec, parts: closedloop.StepParts) -> ca.Function:
    """(gains, unc, phase, ekf, p, Sf) -> (S0, K, chat, rmse, ok, t_fail): the run's start and its end."""
    cfg, L = spec.cfg, parts.layout
    ng = 6 * len(spec.law.columns())
    G, unc, phase, ekf = ca.MX.sym("gains", ng), ca.MX.sym("unc", 4), ca.MX.sym("phase", 6), ca.MX.sym("ekf", 5)
    p = ca.MX.sym("p", len(spec.lay))
    Sf = ca.MX.sym("Sf", L.slices["gains"].start)
    S0, K = closedloop.run_start(spec, L, parts.pc_fn, G, unc, phase, ekf, p)
    outs = closedloop.run_end(L, Sf, scenario.n_samples(cfg) - 1)
    return ca.Function(name, [G, unc, phase, ekf, p, Sf], [S0, K, *outs],
                       ["gains", "unc", "phase", "ekf", "p", "Sf"], ["S0", "K", "chat", "rmse", "ok", "t_fail"])


def _check_keep(keep: ca.Function) -> None:
    """The loop writes the controller part's C and the last plant step's x_next where the new state goes
    instead of calling cl_keep: so cl_keep must be exactly vertcat(x_next, C)."""
    C, S, xn, t = keep.sx_in()
    if not ca.is_equal(keep.call([C, S, xn, t])[0], ca.vertcat(xn, C), 1):
        raise AssertionError("lockstep: cl_keep is no longer vertcat(x_next, C); update the loop (arvcas.sim.lockstep)")


def loop_c(name: str, spec: closedloop.RunSpec, parts: closedloop.StepParts, main: ca.Function, W: int) -> str:
    """The C of the lockstep loop (see the module docstring), appended to ``main``'s generated code."""
    cfg, L = spec.cfg, parts.layout
    Rec = schedule.records(spec.lay)
    TS, AS, ns = Rec.time_size, Rec.arm_size, schedule.n_stages(cfg)
    NS, NK = L.slices["gains"].start, L.size - L.slices["gains"].start
    NC = NS - 12
    off = {k: L.slices[k].start - NS for k in ("p", "consts", "phase_cs", "pc")}
    c0, c1 = parts.ctrls
    pre = f"{name}_ln"
    _check_keep(parts.keep)
    fns = lanes.lane_functions([
        (c0, f"{pre}_ctrl0", [False, False, True, False, True, True]),
        (c1, f"{pre}_ctrl", [False, False, True, False, True, True]),
        (parts.rk4, f"{pre}_rk4", [False, True, True, False, False, False, False, False]),
        (parts.ok, f"{pre}_ok", [False, False]),
        (parts.freeze, f"{pre}_freeze", [False, False, False, True]),
    ])
    n = scenario.n_samples(cfg)
    h = float(cfg.time_h)
    i_ok = L.slices["ok"].start
    sz_arg, sz_res = max(main.sz_arg(), 6), max(main.sz_res(), 6)
    return lanes.header(W) + fns + f"""
/* arvcas: {n} samples of W = {W} runs in lockstep (arvcas.sim.lockstep) */
CASADI_SYMBOL_EXPORT int {name}{ENTRY}(long long int n, long long int chunk, long long int* next, int* stop,
    long long int* failed, const double* const* a, const long long int* sa, double* const* r,
    const long long int* sr, casadi_int* iw, double* w) {{
  enum {{ W = LN_W, NS = {NS}, NK = {NK}, NC = {NC}, NSAMP = {n}, NSUB = {parts.n_sub}, TS = {TS}, AS = {AS},
         RT = {ns * TS}, RA = {ns * AS}, IOK = {i_ok} }};
  static const double h = {h!r};
  double SB[2][NS * W], K[NK * W + 1], X[2][12 * W], TAU[6 * W], NZ[12 * W], OKV[W], SF[NS * W], s0[NS], k0[NK + 1];
  double *S, *Sn;
  const double* arg[{sz_arg}];
  double* res[{sz_res}];
  long long int run[W], i0;
  int l, m, j;
  (void)chunk;
  if (sa[4] || sa[5] || sa[6] || sa[7]) return 2;  /* ekf, p and the time table: shared by the batch */
  for (;;) {{
    if (__atomic_load_n(stop, __ATOMIC_RELAXED)) return 0;
    i0 = __atomic_fetch_add(next, (long long int)W, __ATOMIC_RELAXED);
    if (i0 >= n) return 0;
    m = n - i0 < W ? (int)(n - i0) : W;
    S = SB[0];
    Sn = SB[1];
    for (l = 0; l < W; ++l) {{
      run[l] = i0 + (l < m ? l : m - 1);  /* a short last group: copies of its last run */
      arg[0] = a[0] + run[l] * sa[0]; arg[1] = a[2] + run[l] * sa[2]; arg[2] = a[3] + run[l] * sa[3];
      arg[3] = a[4]; arg[4] = a[5]; arg[5] = 0;
      res[0] = s0; res[1] = k0; res[2] = res[3] = res[4] = res[5] = 0;
      if ({name}(arg, res, iw, w, 0)) goto fail;
      for (j = 0; j < NS; ++j) S[j * W + l] = s0[j];
      for (j = 0; j < NK; ++j) K[j * W + l] = k0[j];
    }}
    for (long long int k = 0; k < NSAMP; ++k) {{
      const double tk = (double)k * h;
      const double* st = a[6] + k * RT;
      const double* sm = a[7] + k * RA;
      const double* xin = S;
      for (l = 0; l < W; ++l) {{
        const double* nz = a[1] + run[l] * sa[1] + k * 12;
        for (j = 0; j < 12; ++j) NZ[j * W + l] = nz[j];
      }}
      {{  /* the controller part: C (the new state after x) straight into Sn: cl_keep is vertcat(x_next, C) */
        const double* ca_[6] = {{S, K, &tk, NZ, st, sm}};
        double* cr[2] = {{Sn + 12 * W, TAU}};
        if (k == 0) {pre}_ctrl0(ca_, cr); else {pre}_ctrl(ca_, cr);
      }}
      for (int i = 0; i < NSUB; ++i) {{  /* the last plant step writes x_next into Sn */
        const double* ra[8] = {{xin, st + 2 * i * TS, sm + 2 * i * AS, TAU, K + {off['p']} * W, K + {off['consts']} * W,
                               K + {off['phase_cs']} * W, K + {off['pc']} * W}};
        double* rr[1] = {{i == NSUB - 1 ? Sn : X[i & 1]}};
        {pre}_rk4(ra, rr);
        xin = rr[0];
      }}
      {{
        const double* oa[2] = {{Sn + 12 * W, Sn}};
        double* orr[1] = {{OKV}};
        {pre}_ok(oa, orr);
      }}
      int going = 0, frozen = 0;
      for (l = 0; l < W; ++l) frozen |= !(long long int)OKV[l];  /* cl_finalize's test */
      if (frozen) {{  /* cl_freeze for the runs that stop (or stopped): the old state, ok = 0, t_fail */
        const double* fa[4] = {{Sn + 12 * W, S, Sn, &tk}};
        double* fr[1] = {{SF}};
        {pre}_freeze(fa, fr);
        for (l = 0; l < W; ++l)
          if (!(long long int)OKV[l])
            for (j = 0; j < NS; ++j) Sn[j * W + l] = SF[j * W + l];
      }}
      {{ double* t_ = S; S = Sn; Sn = t_; }}
      for (l = 0; l < W; ++l) going |= S[IOK * W + l] != 0;
      if (!going) break;  /* every run of the group diverged: frozen states, the same outputs */
    }}
    for (l = 0; l < m; ++l) {{
      for (j = 0; j < NS; ++j) s0[j] = S[j * W + l];
      arg[0] = a[0] + run[l] * sa[0]; arg[1] = a[2] + run[l] * sa[2]; arg[2] = a[3] + run[l] * sa[3];
      arg[3] = a[4]; arg[4] = a[5]; arg[5] = s0;
      res[0] = res[1] = 0;
      for (j = 0; j < 4; ++j) res[2 + j] = r[j] + run[l] * sr[j];
      if ({name}(arg, res, iw, w, 0)) goto fail;
    }}
  }}
fail:
  *failed = i0;
  __atomic_store_n(stop, 1, __ATOMIC_RELAXED);
  return 1;
}}
"""


def build(run, W: int | None = None, flags: tuple[str, ...] = (), opt_level: str = codegen.DEFAULT_OPT_LEVEL
          ) -> LockstepRun:
    """The lockstep library of a :class:`arvcas.sim.run.CompiledRun` (metrics only), W lanes (default
    :func:`arvcas.build.lanes.lane_width`), from the compile cache when it is there. ``flags`` and
    ``opt_level``: the compiler's, as for :func:`arvcas.build.codegen.build_described` (no level or
    instruction set changes a result: tests/test_lockstep.py compares the bits)."""
    W = lanes.lane_width() if W is None else W
    law = run.controller
    name = f"lanes_{law.name}"
    desc = f"lockstep W={W} rewrite={lanes.REWRITE_VERSION} " + run.description(False)
    spec = closedloop.RunSpec(law, run.cfg.graph_key(), run.opts, run.params.layout)
    extra: dict[str, str] = {}

    def make() -> ca.Function:
        parts = closedloop.step_parts(spec, False, (True, False))
        main = _main_function(name, spec, parts)
        extra["c"] = loop_c(name, spec, parts, main, W)
        return main

    fn = codegen.build_described(name, desc, make, extra_c=lambda f: extra["c"], flags=flags,
                                 opt_level=opt_level,
                                 label=f"the lockstep run for {run.params.structure.name} / {law.name} (W = {W})")
    return LockstepRun(fn, W)
