"""Section 1: the plant functions (C driver, map, VM, arvcas.dynamics, export-c, a NumPy yardstick).

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas.build import codegen, export, dynamics as dynamics_mod
from arvcas.model import uvms
from arvcas.bench.common import BenchError, N_INPUT_SETS, Settings, _scaled, _stat, _time

_DRIVER_C = r"""
/* arvcas bench driver: dlopen a CasADi-generated library, evaluate one function in a loop. */
#define _POSIX_C_SOURCE 200809L
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

typedef long long int casadi_int;
typedef int (*eval_t)(const double**, double**, casadi_int*, double*, int);
typedef int (*work_t)(casadi_int*, casadi_int*, casadi_int*, casadi_int*);
typedef int (*checkout_t)(void);

static void* sym(void* h, const char* f, const char* suffix, int required) {
  char name[256];
  snprintf(name, sizeof name, "%s%s", f, suffix);
  void* p = dlsym(h, name);
  if (!p && required) { fprintf(stderr, "symbol %s not found\n", name); exit(3); }
  return p;
}

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

/* usage: driver LIB FUNCTION DATA N_EVALS REPS
   DATA: int64 n_in, n_in x int64 nnz, int64 n_out, n_out x int64 nnz, int64 K (power of 2),
         then K x sum(nnz_in) doubles (input set k, inputs in order). */
int main(int argc, char** argv) {
  if (argc != 6) { fprintf(stderr, "usage: %s LIB FUNCTION DATA N_EVALS REPS\n", argv[0]); return 2; }
  const char* fname = argv[2];
  long long n_evals = atoll(argv[4]), reps = atoll(argv[5]);
  void* h = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
  if (!h) { fprintf(stderr, "dlopen: %s\n", dlerror()); return 3; }
  eval_t f = (eval_t)sym(h, fname, "", 1);
  work_t work = (work_t)sym(h, fname, "_work", 1);
  checkout_t checkout = (checkout_t)sym(h, fname, "_checkout", 0);
  void (*incref)(void) = (void (*)(void))sym(h, fname, "_incref", 0);
  if (incref) incref();
  int mem = checkout ? checkout() : 0;

  FILE* fp = fopen(argv[3], "rb");
  if (!fp) { perror("data"); return 3; }
  long long n_in, n_out, K, tot_in = 0, tot_out = 0;
  if (fread(&n_in, 8, 1, fp) != 1) return 4;
  long long* nnz_in = malloc(n_in * sizeof *nnz_in);
  if (fread(nnz_in, 8, n_in, fp) != (size_t)n_in) return 4;
  if (fread(&n_out, 8, 1, fp) != 1) return 4;
  long long* nnz_out = malloc(n_out * sizeof *nnz_out);
  if (fread(nnz_out, 8, n_out, fp) != (size_t)n_out) return 4;
  if (fread(&K, 8, 1, fp) != 1) return 4;
  for (long long i = 0; i < n_in; i++) tot_in += nnz_in[i];
  for (long long i = 0; i < n_out; i++) tot_out += nnz_out[i];
  double* data = malloc(K * tot_in * sizeof *data);
  if (fread(data, sizeof *data, K * tot_in, fp) != (size_t)(K * tot_in)) return 4;
  fclose(fp);

  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  if (sz_arg < n_in) sz_arg = n_in;
  if (sz_res < n_out) sz_res = n_out;
  const double** args = malloc(K * sz_arg * sizeof *args); /* one argument array per input set */
  for (long long k = 0; k < K; k++) {
    const double* p = data + k * tot_in;
    for (long long i = 0; i < n_in; i++) { args[k * sz_arg + i] = p; p += nnz_in[i]; }
  }
  double* out = calloc(tot_out, sizeof *out);
  double** res = malloc(sz_res * sizeof *res);
  { double* p = out; for (long long i = 0; i < n_out; i++) { res[i] = p; p += nnz_out[i]; } }
  casadi_int* iw = malloc((sz_iw + 1) * sizeof *iw);
  double* w = malloc((sz_w + 1) * sizeof *w);

  double checksum = 0;
  long long mask = K - 1;
  for (long long i = 0; i < n_evals / 10 + 1; i++) f(args + (i & mask) * sz_arg, res, iw, w, mem); /* warm-up */
  for (long long r = 0; r < reps; r++) {
    double t0 = now();
    for (long long i = 0; i < n_evals; i++) {
      if (f(args + (i & mask) * sz_arg, res, iw, w, mem)) { fprintf(stderr, "evaluation failed\n"); return 5; }
      checksum += out[0];
    }
    double t1 = now();
    printf("ns_per_eval %.6f\n", 1e9 * (t1 - t0) / n_evals);
  }
  printf("checksum %.17g\n", checksum);
  f(args, res, iw, w, mem); /* input set 0, printed for the check against the VM */
  printf("out0");
  for (long long i = 0; i < tot_out; i++) printf(" %.17g", out[i]);
  printf("\n");
  return 0;
}
"""


class _Driver:
    """The C driver, compiled once per benchmark with codegen's compiler and flags."""

    def __init__(self, work: Path, opt_level: str):
        src = work / "driver.c"
        self.exe = work / "driver"
        src.write_text(_DRIVER_C, encoding="utf-8")
        self.flags = [opt_level, *codegen.FIXED_FLAGS]
        cmd = [codegen.CC, *self.flags, "-o", str(self.exe), str(src), "-ldl", *codegen.LIBS]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise BenchError(f"compiling the C driver failed: {r.stderr.strip()[:300]}")
        self.work = work

    def run(self, lib: str, fname: str, data: Path, n_evals: int, reps: int) -> tuple[list[float], np.ndarray]:
        r = subprocess.run([str(self.exe), lib, fname, str(data), str(n_evals), str(reps)],
                           capture_output=True, text=True, timeout=3600)
        if r.returncode != 0:
            raise BenchError(f"C driver for {fname} failed (exit {r.returncode}): {r.stderr.strip()[:300]}")
        ns, out0 = [], None
        for line in r.stdout.splitlines():
            if line.startswith("ns_per_eval "):
                ns.append(float(line.split()[1]))
            elif line.startswith("out0"):
                out0 = np.array([float(x) for x in line.split()[1:]])
        if len(ns) != reps or out0 is None:
            raise BenchError(f"C driver for {fname}: unexpected output {r.stdout[:200]!r}")
        return ns, out0


def _input_sets(f: ca.Function, p: np.ndarray, k: int, seed: int = 12345) -> list[list[np.ndarray]]:
    """``k`` varied input sets for ``f``: export.example_inputs() perturbed by up to +-10 % (+-0.01
    absolute); ``p`` (the parameter vector) is the same in every set; payload stays in [0, 1]."""
    rng = np.random.default_rng(seed)
    nominal = export.example_inputs()
    sets = []
    for _ in range(k):
        args = []
        for name in f.name_in():
            if name == "p":
                args.append(np.asarray(p, dtype=float))
                continue
            if name not in nominal:
                raise BenchError(f"no nominal value for input {name!r} of {f.name()}")
            v = np.asarray(nominal[name], dtype=float)
            v = v + 0.1 * np.abs(v) * rng.uniform(-1, 1, v.shape) + 0.01 * rng.uniform(-1, 1, v.shape)
            if name == "payload":
                v = np.clip(v, 0.0, 1.0)
            args.append(v)
        sets.append(args)
    return sets


def _write_data(path: Path, f: ca.Function, sets: list[list[np.ndarray]]) -> None:
    hdr = [f.n_in(), *[f.nnz_in(i) for i in range(f.n_in())], f.n_out(),
           *[f.nnz_out(i) for i in range(f.n_out())], len(sets)]
    body = np.concatenate([np.concatenate([np.ravel(a, order="F") for a in s]) for s in sets])
    with open(path, "wb") as fh:
        fh.write(np.asarray(hdr, dtype="<i8").tobytes())
        fh.write(np.ascontiguousarray(body, dtype="<f8").tobytes())


def _c_time(driver: _Driver, lib: str, f_vm: ca.Function, data: Path, set0: list, s: Settings,
            symbol: str | None = None) -> dict:
    """C driver: ns per evaluation (median over repetitions), checked against the VM on input set 0.

    ``symbol``: the function's name in ``lib`` (default: ``f_vm.name()``)."""
    name = symbol or f_vm.name()
    ns, _ = driver.run(lib, name, data, s.c_min_evals, 1)  # calibration
    n = int(min(max(s.c_target_s / (ns[0] * 1e-9), s.c_min_evals), s.c_max_evals))
    ns, out0 = driver.run(lib, name, data, n, s.reps)
    ref = np.concatenate([np.ravel(np.array(o), order="F") for o in f_vm.call(set0)])
    if out0.shape != ref.shape or not np.allclose(out0, ref, rtol=1e-9, atol=1e-12):
        raise BenchError(f"C driver output of {name} differs from CasADi's VM: {out0[:4]} vs {ref[:4]}")
    st = _stat(ns)
    st["evals_per_rep"] = n
    return st


def _numpy_vehicle_rhs(P):
    """vehicle_rhs written by hand in NumPy, the yardstick of :func:`arvcas.dynamics` (arvcas has no
    NumPy model). The constant matrices (M^-1, I_b) and coefficients are computed once with the model
    code on numbers; the state-dependent terms (J(eta) nu, C_RB(nu) nu, D(nu) nu, g(eta)) are NumPy on
    every call. Takes x (12,) and tau (6,), or (n, 12) and (n, 6)."""
    from arvcas.model import vehicle
    from arvcas.system.params import view

    Pv = view(ca.DM(P.vector()))
    Minv_T = np.linalg.inv(np.array(vehicle.M(Pv))).T
    m = P["vehicle.m"]
    rG = np.array([P["vehicle.xG"], P["vehicle.yG"], P["vehicle.zG"]])
    Ib_T = np.array(vehicle.I_b(Pv)).T
    rho = P["env.rho"]
    h = {k.removeprefix("hydro."): P[k] for k in P.names() if k.startswith("hydro.")}
    dsv = float(vehicle.delta_s_term(Pv))
    W, B = (float(v) for v in vehicle.weight_buoyancy(Pv))
    xG, yG, zG = rG
    xB, yB, zB = P["vehicle.xB"], P["vehicle.yB"], P["vehicle.zB"]

    def f(x, tau):
        x, tau = np.asarray(x, dtype=float), np.asarray(tau, dtype=float)
        nu1, nu2 = x[..., 6:9], x[..., 9:12]
        u, v, w, pp, q, r = (x[..., 6 + k] for k in range(6))
        cf, sf = np.cos(x[..., 3]), np.sin(x[..., 3])
        ct, st = np.cos(x[..., 4]), np.sin(x[..., 4])
        cp, sp = np.cos(x[..., 5]), np.sin(x[..., 5])
        tt = st / ct
        eta_dot = np.stack([
            cp * ct * u + (-sp * cf + cp * st * sf) * v + (sp * sf + cp * cf * st) * w,
            sp * ct * u + (cp * cf + sf * st * sp) * v + (-cp * sf + st * sp * cf) * w,
            -st * u + ct * sf * v + ct * cf * w,
            pp + sf * tt * q + cf * tt * r,
            cf * q - sf * r,
            sf / ct * q + cf / ct * r], axis=-1)
        c_nu = np.concatenate([m * np.cross(nu2, nu1) - m * np.cross(nu2, np.cross(rG, nu2)),
                               m * np.cross(rG, np.cross(nu2, nu1)) - np.cross(nu2 @ Ib_T, nu2)], axis=-1)
        aw, av = np.abs(w), np.abs(v)
        d_nu = -rho * np.stack([
            (h["X_u"] + h["X_u_absw"] * aw) * u + (h["X_v"] + h["X_v_absw"] * aw) * v
            + (h["X_w"] + h["X_ds"] * aw * dsv) * w + h["X_q"] * q + h["X_r"] * r,
            h["Y_u"] * u + (h["Y_v"] + h["Y_v_absv"] * av) * v + h["Y_r"] * r,
            h["Z_u"] * u + (h["Z_w"] + h["Z_w_absw"] * aw + h["Z_dsds"] * aw * dsv**2) * w + h["Z_q"] * q,
            h["K_u_absw"] * aw * u + h["K_v"] * v + h["K_w"] * w + h["K_p"] * pp,
            (h["M_u"] + h["M_uw"] * w) * u
            + (h["M_w"] + h["M_w_absw"] * aw + h["M_ds"] * dsv * w + h["M_dsds"] * dsv**2 * aw) * w + h["M_q"] * q,
            h["N_u"] * u + (h["N_v"] + h["N_v_absv"] * av) * v + h["N_r"] * r], axis=-1)
        g = np.stack([
            (W - B) * st, -(W - B) * ct * sf, -(W - B) * ct * cf,
            -(yG * W - yB * B) * ct * cf + (zG * W - zB * B) * ct * sf,
            (zG * W - zB * B) * st + (xG * W - xB * B) * ct * cf,
            -(xG * W - xB * B) * ct * sf - (yG * W - yB * B) * st], axis=-1)
        nud = (tau - c_nu - d_nu - g) @ Minv_T
        return np.concatenate([eta_dot, nud], axis=-1)

    return f


def _export_lib(work: Path, s: Settings, log) -> Path:
    """``arvcas export-c`` into ``work``, its library built by its own Makefile (quick mode: at -O0)."""
    out = work / "export"
    export.export_c(out)
    lib = export.DEFAULT_PREFIX.rstrip("_")
    cmd = ["make", "-C", str(out), f"CC={codegen.CC}", f"lib{lib}.so"]
    if s.mode == "quick":  # figures not for the record: compile fast
        cmd.append("ARVCAS_CFLAGS=" + " ".join(["-O0", *codegen.FIXED_FLAGS]))
    log("plant: building the exported C library ...")
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    if r.returncode != 0:
        raise BenchError(f"building the exported library failed: {r.stderr.strip()[:300]}")
    return out / f"lib{lib}.so"


def _bench_dynamics(name: str, d, f_vm: ca.Function, sets: list, c: dict, s: Settings, log) -> dict:
    """arvcas.dynamics: single calls on the same input sets, and one batch of ``s.map_n`` rows."""
    np_sets = [[np.asarray(a, dtype=float) for a in st[:-1]] for st in sets[: min(len(sets), s.single_calls)]]

    def singles():
        for i in range(s.single_calls):
            d(*np_sets[i % len(np_sets)])

    log(f"plant {name}: arvcas.dynamics single and batched ...")
    ds = _scaled(_time(singles, s.reps), 1e6 / s.single_calls)
    full_sets = [[np.asarray(a, dtype=float) for a in st] for st in sets[: min(len(sets), s.single_calls)]]

    def casadi_numpy():  # what calling the compiled Function on NumPy arrays costs (conversion to DM and back)
        for i in range(s.single_calls):
            [np.asarray(o) for o in d.function.call(full_sets[i % len(full_sets)])]

    cn = _scaled(_time(casadi_numpy, s.reps), 1e6 / s.single_calls)
    N = s.map_n
    idx = np.arange(N) % len(sets)
    bargs = [np.stack([np.ravel(sets[j][i]) for j in idx]) for i in range(f_vm.n_in() - 1)]  # (N, m); p default
    got = d(*bargs, n_threads=1)
    got = got if isinstance(got, tuple) else (got,)
    ref = f_vm.call(sets[0])
    for g, r_ in zip(got, ref):
        r_ = np.asarray(r_)
        if not np.allclose(g[0].reshape(r_.shape), r_, rtol=1e-12, atol=1e-12 * max(1.0, np.max(np.abs(r_)))):
            raise BenchError(f"arvcas.dynamics({name!r}) differs from CasADi's VM on input set 0")
    b1 = _scaled(_time(lambda: d(*bargs, n_threads=1), s.reps), 1e9 / N)
    nt = os.cpu_count() or 1
    bt = _scaled(_time(lambda: d(*bargs, n_threads=nt), s.reps), 1e9 / N)
    return {"dyn_single_us": ds, "casadi_numpy_single_us": cn,
            "ratio_casadi_numpy_over_dyn_single": cn["median"] / ds["median"], "dyn_batch_ns_per_eval": b1, "dyn_batch_threads_ns_per_eval": bt,
            "dyn_batch_threads": nt, "ratio_dyn_batch_over_c": b1["median"] / c["median"],
            "ratio_dyn_batch_threads_over_c": bt["median"] / c["median"]}


def _bench_numpy(P, f_vm: ca.Function, sets: list, s: Settings, log) -> dict:
    """The NumPy yardstick (vehicle_rhs only): single calls and one vectorised batch of ``s.map_n`` rows."""
    f = _numpy_vehicle_rhs(P)
    for st in sets[:8]:
        ref = np.asarray(f_vm.call(st)[0]).ravel()
        if not np.allclose(f(st[0], st[1]), ref, rtol=1e-10, atol=1e-12 * np.max(np.abs(ref))):
            raise BenchError("the NumPy vehicle_rhs of the benchmark differs from the model")
    np_sets = [(np.asarray(st[0], dtype=float), np.asarray(st[1], dtype=float)) for st in sets[: s.single_calls]]

    def singles():
        for i in range(s.single_calls):
            f(*np_sets[i % len(np_sets)])

    log("plant vehicle_rhs: the NumPy yardstick ...")
    ss = _scaled(_time(singles, s.reps), 1e6 / s.single_calls)
    idx = np.arange(s.map_n) % len(sets)
    X = np.stack([sets[j][0] for j in idx])
    T = np.stack([sets[j][1] for j in idx])
    sb = _scaled(_time(lambda: f(X, T), s.reps), 1e9 / s.map_n)
    return {"numpy_single_us": ss, "numpy_batch_ns_per_eval": sb}


def _bench_plant(s: Settings, driver: _Driver, work: Path, P, log) -> dict:
    p = P.vector()
    fns = dict(uvms.plant_functions())
    fns.update(dynamics_mod.jacobian_functions(fns))
    exported = _export_lib(work, s, log)
    out = {}
    for name in dynamics_mod.NAMES:
        f_vm = fns[name]
        d = dynamics_mod.dynamics(name)
        f_c = d.function  # for the five plant functions, the Function arvcas.compiled(name) returns
        lib = codegen.artifact_of(f_c)["path"]
        sets = _input_sets(f_vm, p, N_INPUT_SETS)
        data = work / f"{name}.bin"
        _write_data(data, f_vm, sets)
        n_ins = int(f_vm.n_instructions())
        log(f"plant {name}: C driver ...")
        c = _c_time(driver, lib, f_vm, data, sets[0], s)
        ec = _c_time(driver, str(exported), f_vm, data, sets[0], s, symbol=export.DEFAULT_PREFIX + name)

        # single calls from Python (same harness for both: the Python/CasADi call overhead is included)
        dm_sets = [[ca.DM(a) for a in st] for st in sets[: min(len(sets), s.single_calls)]]

        def singles(fun):
            def go():
                for i in range(s.single_calls):
                    fun.call(dm_sets[i % len(dm_sets)])
            return go

        log(f"plant {name}: single calls from Python ...")
        sc = _scaled(_time(singles(f_c), s.reps), 1e6 / s.single_calls)
        sv = _scaled(_time(singles(f_vm), s.reps), 1e6 / s.single_calls)

        # batched: f.map(N) with every input N columns wide (p repeated), as DM built once. (Passing
        # p as one column makes Function.call broadcast it, which costs microseconds per column.)
        N = s.map_n
        idx = np.arange(N) % len(sets)
        margs = [ca.DM(np.stack([np.ravel(sets[j][i], order="F") for j in idx], axis=1))
                 for i in range(f_vm.n_in())]
        mc, mv = f_c.map(N), f_vm.map(N)
        # the floor of such a call: a Function with the same input and output shapes doing nothing
        sym_in = [ca.MX.sym(f"a{i}", f_vm.nnz_in(i), N) for i in range(f_vm.n_in())]
        noop = ca.Function("noop", sym_in, [ca.DM.zeros(f_vm.nnz_out(i), N) for i in range(f_vm.n_out())])
        log(f"plant {name}: map({N}) ...")
        bc = _scaled(_time(lambda: mc.call(margs), s.reps), 1e9 / N)
        bv = _scaled(_time(lambda: mv.call(margs), s.reps), 1e9 / N)
        bo = _scaled(_time(lambda: noop.call(margs), s.reps), 1e9 / N)
        out[name] = {
            "n_instructions": n_ins,
            "c_ns_per_eval": c,
            "c_instr_per_s": n_ins / (c["median"] * 1e-9),
            "map_compiled_ns_per_eval": bc,
            "map_vm_ns_per_eval": bv,
            "map_call_floor_ns_per_eval": bo,
            "vm_instr_per_s": n_ins / (bv["median"] * 1e-9),
            "single_compiled_us": sc,
            "single_vm_us": sv,
            "ratio_vm_over_compiled_map": bv["median"] / bc["median"],
            "ratio_vm_map_over_c": bv["median"] / c["median"],
            "ratio_vm_over_compiled_single": sv["median"] / sc["median"],
            "library": Path(lib).name,
            "export_c_ns_per_eval": ec,
            "ratio_export_c_over_c": ec["median"] / c["median"],
        }
        out[name].update(_bench_dynamics(name, d, f_vm, sets, c, s, log))
        out[name]["ratio_casadi_single_over_dyn_single"] = sc["median"] / out[name]["dyn_single_us"]["median"]
        if name == "vehicle_rhs":
            out[name].update(_bench_numpy(P, f_vm, sets, s, log))
    return out
