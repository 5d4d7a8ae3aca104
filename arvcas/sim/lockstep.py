"""Runs in lockstep: W runs of a batch evaluated together, one vector lane each.

The scalar run (:func:`arvcas.sim.closedloop.build_run`) is an MX function calling, per controller
sample, the SX functions of :func:`arvcas.sim.closedloop.step_parts`: the controller part, ``n_sub``
RK4 plant steps, the divergence check and one of two copies of the loop state (keep, or freeze a
run that diverged). A lockstep run calls the same SX functions rewritten to W lanes
(:mod:`arvcas.build.lanes`: every lane's result equal to the scalar function's to the bit) from a
loop written here in C, with the divergence branch as a per-lane select; the run's start (its first
loop state and constants) and end (the metrics) are the scalar run's own MX expressions
(:func:`~arvcas.sim.closedloop.run_start`, :func:`~arvcas.sim.closedloop.run_end`), compiled into the
same library and called once per run. With thruster dynamics, the thrusters' SX functions (the lag and
the maps' cubics) are rewritten to lanes too, and the table intervals between them are gathered lane by
lane in C as the scalar run's MX lookups gather them. So every lane's outputs equal the scalar run's to the bit
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
from arvcas.sim import closedloop, scenario, schedule, thrust_forcing

__all__ = ["LockstepRun", "build", "ENTRY"]

ENTRY = "_arvcas_lanes"  # the C entry point of a lockstep library: <name>_arvcas_lanes
# the run's inputs as the loop reads them (a[0] .. a[8])
_INPUTS = ("gains", "noise", "unc", "phase", "ekf", "water", "p", "sched_time", "sched_arm")


class LockstepRun:
    """A compiled lockstep run: the library's main function (the run's start and end) and its loop."""

    def __init__(self, fn: ca.Function, W: int):
        self.function, self.W = fn, W
        self.loop = calls.batch_loop(fn, ENTRY)
        if self.loop is None:
            raise codegen.CacheError(f"{fn.name()}: the library has no lockstep loop {fn.name()}{ENTRY}")

    def evaluate(self, n: int, bound: list[np.ndarray], per_run, outs: list[np.ndarray], n_threads: int) -> None:
        """n runs: ``bound`` the run's inputs in :data:`closedloop.INPUTS` order (Fortran arrays, a
        column block per run for the names in ``per_run``), ``outs`` the run's outputs
        (:data:`closedloop.OUTPUTS`) as arrays of n columns each, written in place."""
        names = closedloop.INPUTS
        shared = {"ekf", "water", "p", "sched_time", "sched_arm"}
        if per_run & shared:
            raise ValueError(f"lockstep: {sorted(per_run & shared)} must be shared by the batch")
        sa = [a.shape[0] * a.shape[1] // n if k in per_run else 0 for k, a in zip(names, bound)]
        f = self.function
        failed = calls.run_loop(self.loop, n, [a.ctypes.data for a in bound], sa, [r.ctypes.data for r in outs],
                                [r.shape[0] for r in outs], int(f.sz_iw()), int(f.sz_w()), n_threads,
                                chunk=self.W, keep=(bound, outs))
        if failed is not None:
            raise RuntimeError(f"{f.name()}: run {failed} of {n} failed")


def _main_function(name: str, spec: closedloop.RunSpec, parts: closedloop.StepParts) -> ca.Function:
    """(mode, gains, unc, phase, ekf, water, p, Sf) -> (S0, K, the run's outputs): the run's start (S0, K)
    and end (its outputs from the last loop state Sf), one run at a time; ``mode`` is unused (0)."""
    cfg, L, lay = spec.cfg, parts.layout, spec.lay
    ng = 6 * len(spec.law.columns())
    G, unc, phase = ca.MX.sym("gains", ng), ca.MX.sym("unc", 4), ca.MX.sym("phase", 6)
    ekf, water = ca.MX.sym("ekf", cfg.ekf_vector.size), ca.MX.sym("water", cfg.water_vector.size)
    p, Sf = ca.MX.sym("p", len(lay)), ca.MX.sym("Sf", L.slices["gains"].start)
    S0, K = closedloop.run_start(spec, L, parts.pc_fn, G, unc, phase, ekf, water, p)
    outs = [S0, K, *closedloop.run_end(L, Sf, scenario.n_samples(cfg) - 1)]
    mode = ca.MX.sym("mode")
    return ca.Function(name, [mode, G, unc, phase, ekf, water, p, Sf], outs,
                       ["mode", "gains", "unc", "phase", "ekf", "water", "p", "Sf"], ["S0", "K", *closedloop.OUTPUTS])


def _check_keep(keep: ca.Function) -> None:
    """The loop writes the controller part's C and the last plant step's x_next where the new state goes
    instead of calling cl_keep: so cl_keep must be exactly vertcat(x_next, C)."""
    C, S, xn, t = keep.sx_in()
    if not ca.is_equal(keep.call([C, S, xn, t])[0], ca.vertcat(xn, C), 1):
        raise AssertionError("lockstep: cl_keep is no longer vertcat(x_next, C); update the loop (arvcas.sim.lockstep)")


_LOW = """
static long long int {pre}_low(double x, const double* grid, long long int ng, int mode) {{
  /* casadi_low of CasADi's runtime (casadi/core/runtime/casadi_low.hpp), modes 1 (exact) and 2 (binary),
     copied: the interval the scalar run's MX lookup finds, so the same gathered numbers */
  if (mode == 1) {{
    double g0 = grid[0], dg = grid[ng - 1] - g0;
    long long int ret = (long long int)((x - g0) * (ng - 1) / dg);
    if (ret < 0) ret = 0;
    if (ret > ng - 2) ret = ng - 2;
    return ret;
  }} else {{
    long long int start = 0, stop = ng - 1, pivot;
    if (ng < 2 || x < grid[1]) return 0;
    if (x > grid[ng - 1]) return ng - 2;
    for (;;) {{
      pivot = (stop + start) / 2;
      if (x < grid[pivot]) {{
        if (pivot == stop) return pivot;
        stop = pivot;
      }} else {{
        if (pivot == start) return pivot;
        start = pivot;
      }}
    }}
  }}
}}
"""


def _thruster_c(spec: closedloop.RunSpec, parts: closedloop.StepParts, off: dict, pre: str) -> tuple[str, str, str]:
    """The thrusters' part of a sample in lanes (docs/model.md §9): ``(loop C, helper C, declarations)``.

    ``cl_thr_lag_iv`` and ``cl_thr_wrench_iv`` rewritten to lanes; between them, lane by lane, each table
    map's intervals gathered from the run's tables as the scalar run's MX lookups gather them
    (:func:`arvcas.model.thruster_tables.target_intervals`, :func:`~arvcas.model.thruster_tables.stage_intervals`: the same search, the same
    numbers). p is shared by the batch, so every lane's tables and lag constants are ``k0``'s (the last
    started run's constants) and p is ``a[6]``."""
    st = spec.lay.structure
    n, m_off = st.n_thrusters, len(thrust_forcing.lag_offsets(spec.cfg))
    maps = [st.thruster_map(d.map) for d in st.thruster_dynamics]
    blocks, k = [], 0
    for m in st.thruster_maps:
        if m.kind != "table":
            continue
        n_g = m.n - (m.zero[1] - m.zero[0])
        idx = ", ".join(str(i) for i, mm in enumerate(maps) if mm.name == m.name)
        blocks.append(f"""
        {{  /* map {m.name}: thrusters {idx} */
          static const int th[] = {{{idx}}};
          const double *g = tab + {k}, *v = g + {n_g}, *d = v + {n_g};
          for (int q = 0; q < (int)(sizeof th / sizeof th[0]); ++q) {{
            const int i = th[q];
            for (l = 0; l < W; ++l) {{  /* the target's interval: a search on the values */
              const long long int x = {pre}_low(TAU[i * W + l], v, {n_g}, 2);
              const double c6[6] = {{g[x], g[x + 1], v[x], v[x + 1], d[x], d[x + 1]}};
              for (j = 0; j < 6; ++j) IU[(j * NT + i) * W + l] = c6[j];
            }}
          }}
          {pre}_thr_lag(la, lr);
          for (int q = 0; q < (int)(sizeof th / sizeof th[0]); ++q) {{
            const int i = th[q];
            for (int o = 0; o < MOFF; ++o)
              for (l = 0; l < W; ++l) {{  /* the stage states' intervals */
                const long long int x = {pre}_low(SS[(i * MOFF + o) * W + l], g, {n_g}, {1 if m.uniform else 2});
                const double c6[6] = {{g[x], g[x + 1], v[x], v[x + 1], d[x], d[x + 1]}};
                for (j = 0; j < 6; ++j) IV[(j * NT * MOFF + i * MOFF + o) * W + l] = c6[j];
              }}
          }}
        }}""")
        k += 3 * n_g
    if len(blocks) > 1:  # the lag runs once, after every map's targets: split the blocks at the lag
        raise NotImplementedError("lockstep: thruster dynamics with more than one table map")
    if not blocks:  # no table map: the lag and the wrench alone (the intervals are unused)
        blocks = [f"\n        {pre}_thr_lag(la, lr);"]
    iu = ", ".join(f"IU + {j * n} * W" for j in range(6))
    iv = ", ".join(f"IV + {j * n * m_off} * W" for j in range(6))
    loop = f"""
      {{  /* the thrusters in lanes: the lag (with the inverse's Newton steps), the maps' cubics and the wrenches */
        const double* tab = k0 + {off['thr_tab']};
        const double* la[10] = {{S + 12 * W, TAU, {iu}, k0 + {off['thr_E']}, a[6]}};
        double* lr[2] = {{SS, CMD}};
        const double* wa[8] = {{{iv}, SS, a[6]}};
        double* wr[2] = {{WB, Sn + (12 + NT) * W}};
        (void)tab;{"".join(blocks)}
        {pre}_thr_wrench(wa, wr);
        for (j = 0; j < NT; ++j)
          for (l = 0; l < W; ++l) Sn[(12 + j) * W + l] = SS[((j + 1) * MOFF - 1) * W + l];  /* s at the sample's end */
      }}"""
    decl = (f"\n  enum {{ MOFF = {m_off} }};\n  double SS[NT * MOFF * W], CMD[NT * W], IU[6 * NT * W], IV[6 * NT * MOFF * W];"
            "\n  for (j = 0; j < 6 * NT * W; ++j) IU[j] = 0;  /* a thruster without a table: unused, defined */"
            "\n  for (j = 0; j < 6 * NT * MOFF * W; ++j) IV[j] = 0;")
    return loop, _LOW.format(pre=pre), decl


def loop_c(name: str, spec: closedloop.RunSpec, parts: closedloop.StepParts, main: ca.Function, W: int) -> str:
    """The C of the lockstep loop (see the module docstring), appended to ``main``'s generated code."""
    cfg, L = spec.cfg, parts.layout
    if closedloop.INPUTS != _INPUTS:
        raise AssertionError(f"lockstep: the run's inputs are now {closedloop.INPUTS}; update the loop's a[] indices")
    Rec = schedule.records(spec.lay)
    TS, AS, ns = Rec.time_size, Rec.arm_size, schedule.n_stages(cfg)
    NS, NK = L.slices["gains"].start, L.size - L.slices["gains"].start
    dyn = parts.thr is not None
    NT = spec.lay.structure.n_thrusters if dyn else 0
    off = {k: L.slices[k].start - NS for k in ("p", "consts", "phase_cs", "pc", "water")}
    if dyn:
        off.update({k: L.slices[k].start - NS for k in ("thr_E", "thr_tab")})
        assert L.slices["thr"].start == 12 and L.slices["thr_T"].start == 12 + NT
    c0, c1 = parts.ctrls
    pre = f"{name}_ln"
    _check_keep(parts.keep)
    thr_lanes = [(parts.thr[2], f"{pre}_thr_lag", [False, False] + [False] * 6 + [True, True]),
                 (parts.thr[3], f"{pre}_thr_wrench", [False] * 7 + [True])] if dyn else []
    fns = lanes.lane_functions([
        *thr_lanes,
        (c0, f"{pre}_ctrl0", [False, False, True, False, True, True]),
        (c1, f"{pre}_ctrl", [False, False, True, False, True, True]),
        (parts.rk4, f"{pre}_rk4", [False, True, True, False, False, False, False, False, False, True]),
        (parts.ok, f"{pre}_ok", [False, False]),
        (parts.freeze, f"{pre}_freeze", [False, False, False, True]),
    ])
    n = scenario.n_samples(cfg)
    h = float(cfg.time_h)
    # the substeps' start times t_k + i h_plant: the scalar step adds the same doubles (i * h_plant in Python)
    t_sub = ", ".join(repr(float(i * cfg.time_h_plant)) for i in range(parts.n_sub))
    i_ok = L.slices["ok"].start
    n_out = len(closedloop.OUTPUTS)
    sz_arg, sz_res = max(main.sz_arg(), 8), max(main.sz_res(), 2 + n_out)
    ntau = max(6, NT)
    thr_c, thr_fns, thr_decl = _thruster_c(spec, parts, off, pre) if dyn else ("", "", "")
    # the thrusters' part's wrench vector (stage wrenches, or the forcing's moments with time.thrust_quadrature)
    # and where plant step i's input starts in it (thrust_forcing.tau_stride)
    nwb = parts.thr[1].size1_out(0) if dyn else 0
    tau_i = f"WB + {thrust_forcing.tau_stride(spec.cfg)} * i * W" if dyn else "TAU"
    return lanes.header(W) + fns + thr_fns + f"""
/* arvcas: {n} samples of W = {W} runs in lockstep (arvcas.sim.lockstep) */
CASADI_SYMBOL_EXPORT int {name}{ENTRY}(long long int n, long long int chunk, long long int* next, int* stop,
    long long int* failed, const double* const* a, const long long int* sa, double* const* r,
    const long long int* sr, casadi_int* iw, double* w) {{
  enum {{ W = LN_W, NS = {NS}, NK = {NK}, NSAMP = {n}, NSUB = {parts.n_sub}, TS = {TS}, AS = {AS},
         RT = {ns * TS}, RA = {ns * AS}, IOK = {i_ok}, NT = {NT}, NST = {ns}, OFFC = {12 + 2 * NT}, NO = {n_out}, NWB = {nwb} }};
  static const double h = {h!r}, tsub[NSUB] = {{{t_sub}}};
  static const double zero = 0, one = 1;
  double SB[2][NS * W], K[NK * W + 1], X[2][12 * W], TAU[{ntau} * W], NZ[12 * W], OKV[W], SF[NS * W], s0[NS], k0[NK + 1];
  double WB[NWB * W + 1];
  double *S, *Sn;
  const double* arg[{sz_arg}];
  double* res[{sz_res}];
  long long int run[W], i0;
  int l, m, j;{thr_decl}
  (void)chunk; (void)one; (void)WB;
  /* ekf, water, p and the time table: shared by the batch (the thrusters' constants in K are p's) */
  if (sa[4] || sa[5] || sa[6] || sa[7] || sa[8]) return 2;
  for (;;) {{
    if (__atomic_load_n(stop, __ATOMIC_RELAXED)) return 0;
    i0 = __atomic_fetch_add(next, (long long int)W, __ATOMIC_RELAXED);
    if (i0 >= n) return 0;
    m = n - i0 < W ? (int)(n - i0) : W;
    S = SB[0];
    Sn = SB[1];
    for (l = 0; l < W; ++l) {{
      run[l] = i0 + (l < m ? l : m - 1);  /* a short last group: copies of its last run */
      for (j = 0; j < 8; ++j) arg[j] = 0;
      for (j = 0; j < NO + 2; ++j) res[j] = 0;
      arg[0] = &zero; arg[1] = a[0] + run[l] * sa[0]; arg[2] = a[2] + run[l] * sa[2]; arg[3] = a[3] + run[l] * sa[3];
      arg[4] = a[4]; arg[5] = a[5]; arg[6] = a[6];
      res[0] = s0; res[1] = k0;
      if ({name}(arg, res, iw, w, 0)) goto fail;
      for (j = 0; j < NS; ++j) S[j * W + l] = s0[j];
      for (j = 0; j < NK; ++j) K[j * W + l] = k0[j];
    }}
    for (long long int k = 0; k < NSAMP; ++k) {{
      const double tk = (double)k * h;
      const double* st = a[7] + k * RT;
      const double* sm = a[8] + k * RA;
      const double* xin = S;
      for (l = 0; l < W; ++l) {{
        const double* nz = a[1] + run[l] * sa[1] + k * 12;
        for (j = 0; j < 12; ++j) NZ[j * W + l] = nz[j];
      }}
      {{  /* the controller part: C (the new state after x and the thrusters) straight into Sn: cl_keep is
            vertcat(x_next, C) */
        const double* ca_[6] = {{S, K, &tk, NZ, st, sm}};
        double* cr[2] = {{Sn + OFFC * W, TAU}};
        if (k == 0) {pre}_ctrl0(ca_, cr); else {pre}_ctrl(ca_, cr);
      }}{thr_c}
      for (int i = 0; i < NSUB; ++i) {{  /* the last plant step writes x_next into Sn */
        const double ti = tk + tsub[i];
        const double* ra[10] = {{xin, st + 2 * i * TS, sm + 2 * i * AS, {tau_i}, K + {off['p']} * W, K + {off['consts']} * W,
                                K + {off['phase_cs']} * W, K + {off['pc']} * W, K + {off['water']} * W, &ti}};
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
      for (j = 0; j < 8; ++j) arg[j] = 0;
      for (j = 0; j < NO + 2; ++j) res[j] = 0;
      arg[0] = &zero; arg[1] = a[0] + run[l] * sa[0]; arg[2] = a[2] + run[l] * sa[2]; arg[3] = a[3] + run[l] * sa[3];
      arg[4] = a[4]; arg[5] = a[5]; arg[6] = a[6]; arg[7] = s0;
      for (j = 0; j < NO; ++j) res[2 + j] = r[j] + run[l] * sr[j];
      if ({name}(arg, res, iw, w, 0)) goto fail;
    }}
  }}
fail:
  *failed = i0;
  __atomic_store_n(stop, 1, __ATOMIC_RELAXED);
  return 1;
}}
"""


def build(run, W: int | None = None, flags: tuple[str, ...] = (), opt_level: str | None = None
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
