"""``arvcas export-controller DIR``: the controller of a run as a standalone C library.

The controller is everything of a controller sample that is not the plant: the EKF on the measured
``[eta; nu]``, the ATD reference, the law (its own state, e.g. the RESO or the PID integral) and the
allocation with saturation (docs/architecture.md, "One controller sample"). Its graph is
:func:`arvcas.sim.closedloop.controller_functions`, built by
:func:`arvcas.sim.closedloop.controller_sample`, the function the run's own sample is built with, so
the exported code performs the same operations in the same order as the compiled run: closed around
the plant over the run's scenario it gives the run's trace and metrics (tests/test_export_controller.py
measures the difference; docs/exporting-a-controller.md).

DIR receives (the file set and build files of ``arvcas export-c``, :mod:`arvcas.build.export`):

* ``<lib>.c``: CasADi's generated code of the sample (sample 0 and sample k >= 1, each with the terms
  that depend on the parameters alone taken out, :func:`casadi.extract_parametric`, computed once by
  ``init``) and the API around it; every global symbol starts with the prefix
  (default ``arvcas_<system>_<controller>_``);
* ``<lib>.h``: the documented API: ``<prefix>params`` (gains, nominal factors, EKF tuning, set point,
  model parameters), ``<prefix>state`` (caller-owned, no heap, no globals), ``default_params``,
  ``init``, ``reset``, ``step(state, y, t, tau_arm, u)``, ``diagnostics``; units and frames;
* ``<lib>_params.h``: the default values (the chosen gains, the scenario's nominal factors, EKF
  tuning and set point, the system's ``p`` with names and SI units);
* ``<lib>.py``: a ctypes binding (no arvcas, CasADi or NumPy needed), used by the tests;
* ``example.c``, ``example.cpp``, ``example.py``: the same few steps, the same printed lines;
* ``Makefile``, ``CMakeLists.txt`` (with an installable package config), ``consumer/CMakeLists.txt``,
  ``README.md`` and the manifest ``arvcas-export.json``.

:func:`close_loop` closes the exported controller (through its binding) around the plant functions
over a compiled run's scenario (its noise sequence and its time table), for the tests and for anyone
who wants to see the equality for themselves.
"""

from __future__ import annotations

import importlib.util
import math
import re
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas.build import export as ex
from arvcas.build.text import c_comment, markdown
from arvcas.controllers import gains as gains_mod
from arvcas.controllers.base import DOFS, Controller, get as get_controller
from arvcas.sim.closedloop import (RunSpec, arm_truth, controller_diagnostics, controller_functions, controller_reads,
                                   controller_sizes)
from arvcas.sim.scenario import ScenarioConfig

__all__ = ["ExportError", "export_controller", "default_prefix", "files", "load_binding", "close_loop"]

ExportError = ex.ExportError
WHAT = "export-controller"


def default_prefix(system, controller) -> str:
    """``arvcas_<system>_<controller>_`` (e.g. ``arvcas_haidou1_proposed_``)."""
    base = ex.default_prefix(system)
    return f"{base}{re.sub(r'[^A-Za-z0-9]', '_', get_controller(controller).name).strip('_')}_"


def files(prefix: str) -> tuple[str, ...]:
    """The files :func:`export_controller` writes (relative to DIR), the manifest last."""
    lib = prefix.rstrip("_")
    plant = ex.files(prefix)  # export-c's set: sources, header, params header, examples, build files, README
    return plant[:3] + (f"{lib}.py",) + plant[3:]


# ---------------------------------------------------------------------------------------------
# the package


@dataclass(frozen=True)
class _Design:
    """What is exported: the law, its gains and where they come from, the scenario, the system."""

    law: Controller
    gains: np.ndarray
    gains_source: str
    cfg: ScenarioConfig
    params: object  # arvcas.system.params.Params
    prefix: str

    @property
    def lib(self) -> str:
        return self.prefix.rstrip("_")


def export_controller(out_dir, controller="proposed", gains=None, params=None, scenario=None, *, prefix=None,
                      gains_source: str | None = None, force: bool = False) -> list[Path]:
    """Write the controller of a run as a C library with header, build files, binding and examples.

    ``controller``: a registered name or Controller; ``gains``: its flat gain vector (default: the
    system's defaults), with ``gains_source`` saying where it comes from (it goes into the header and
    README); ``params``: the system (anything :func:`arvcas.system.resolve` takes; default Haidou-1);
    ``scenario``: a ScenarioConfig or file (default: the system's): it gives the sampling period, the
    ATD's time and amplitude floor, and the default set point, nominal factors and EKF tuning;
    ``prefix``: of every symbol (default :func:`default_prefix`). A file in ``out_dir`` that the
    manifest does not list with its current sha256 is refused unless ``force``. Returns the paths
    written, in :func:`files` order. Raises :class:`ExportError` (a ValueError) before writing anything.
    """
    from arvcas.sim import scenario as scenario_mod
    from arvcas.system import resolve

    law = get_controller(controller)
    P = resolve(params).params
    if scenario is None and P.default("scenario") is None:
        raise ExportError(f"{WHAT}: system {P.structure.name} names no default scenario ([defaults] scenario in "
                          f"{P.path}); give one (--config FILE)")
    cfg = scenario if isinstance(scenario, ScenarioConfig) else scenario_mod.load_scenario(
        scenario if scenario is not None else P.default("scenario"))
    if gains is None and P.default("gains") is None and getattr(law, "defaults", None) is None:
        raise ExportError(f"{WHAT}: system {P.structure.name} names no gain table ([defaults] gains in {P.path}); "
                          f"export a tuned member (--front F --member knee|INDEX) or give gains")
    if gains is None:
        gains_source = gains_source or f"the default gains of {P.structure.name}'s gain table"
    g = gains_mod.check_gains(law, gains_mod.default_gains(law, P) if gains is None else gains, h=cfg.time_h,
                              where=f"{WHAT}: gains")
    if g.ndim != 1:
        raise ExportError(f"{WHAT}: gains: one gain vector of {gains_mod.n_gains(law)}, got shape {g.shape}")
    gains_source = gains_source or "given gains"
    prefix = ex.check_prefix(default_prefix(P, law) if prefix is None else prefix, "arvcas_haidou1_proposed_", WHAT)
    if not isinstance(force, bool):
        raise ExportError(f"{WHAT}: force: expected True or False, got {force!r}")
    out = ex.check_out_dir(out_dir, WHAT)
    names = files(prefix)
    ex.check_replaceable(out, names, force, WHAT)

    d = _Design(law, np.asarray(g, dtype=float).copy(), gains_source, cfg, P, prefix)
    try:
        fns = controller_functions(law, cfg, P.layout, prefix + "cas_")
    except ValueError as e:
        raise ExportError(f"{WHAT}: {e}") from None
    cg = ca.CodeGenerator(d.lib, {"with_header": False, "casadi_real": "double", "casadi_int": "long long int"})
    for f in fns.values():
        cg.add(f)
    c_text = cg.dump()
    ex._check_reentrant(c_text, [f.name() for f in fns.values()])
    work = {key: ex._work_sizes(c_text, f.name()) for key, f in fns.items()}
    info = _Info(d, fns, work)
    texts = {
        f"{d.lib}.c": c_text + _api_c(info),
        f"{d.lib}.h": _header(info),
        f"{d.lib}_params.h": _params_h(info),
        f"{d.lib}.py": _binding_py(info),
        "example.c": _example_c(info),
        "example.cpp": _example_cpp(info),
        "example.py": _example_py(info),
        "Makefile": ex._makefile(prefix),
        "CMakeLists.txt": ex._cmake(prefix),
        "consumer/CMakeLists.txt": ex._cmake_consumer(prefix),
        "README.md": _readme(info),
    }
    assert tuple(texts) + (ex.MANIFEST,) == names
    return ex.write_package(out, texts, prefix, WHAT)


class _Info:
    """Everything the generated texts need, computed once."""

    def __init__(self, d: _Design, fns: dict[str, ca.Function], work: dict[str, dict[str, int]]):
        self.d, self.fns, self.work = d, fns, work
        P, law = d.params, d.law
        self.sz = controller_sizes(law, P.layout, d.cfg)
        self.n_kp0 = fns["prep0"].numel_out(0)
        self.n_kp = fns["prep"].numel_out(0)
        self.sz_w = max(w["sz_w"] for w in work.values())
        self.sz_iw = max(w["sz_iw"] for w in work.values())
        self.sz_arg = max(w["sz_arg"] for w in work.values())
        self.sz_res = max(w["sz_res"] for w in work.values())
        self.uses_tau_arm = controller_reads(fns, "tau_arm")
        self.uses_t = controller_reads(fns, "t")
        st = P.structure
        self.thrusters = list(st.thrusters) if st.thrusters is not None else [f"T{j + 1}" for j in range(st.n_thrusters)]
        self.thrust_text = ex._glossary(P)["u"]  # export-c's words: "thrust per thruster (N): <names>"
        self.upper = gains_mod.upper_limits(law, d.cfg.time_h)
        self.gain_names = gains_mod.gain_names(law)
        self.gain_units = gains_mod.gain_units(law)
        n_t, n_j = st.n_thrusters, st.n_joints
        self.diag = []  # (signal, offset, width)
        i = 0
        for s in controller_diagnostics(law):
            w = s.n(n_t, n_j)
            self.diag.append((s, i, w))
            i += w
        cfg = d.cfg
        self.defaults = {"gains": d.gains, "unc": cfg.uncertainty, "ekf": cfg.ekf_vector,
                         "eta_d": np.array(cfg.initial_eta_d, dtype=float), "p": P.vector()}
        self.P = P

    @property
    def up(self) -> str:
        return self.d.prefix.upper()


# ---------------------------------------------------------------------------------------------
# C


_UNITS_FRAMES = [
    " * UNITS AND FRAMES: SI units throughout. {n} is the North-East-Down frame; {b} the body frame at the",
    " * centre of buoyancy (COB), x forward, y starboard, z down. eta = [x, y, z, phi, theta, psi] is the",
    " * NED position of the COB (m) and the ZYX Euler angles roll, pitch, yaw (rad); nu = [u, v, w, p, q, r]",
    " * the body velocity about the COB in {b} (m/s, rad/s). Wrenches: [X, Y, Z (N); K, M, N (N m)].",
]

_PARAM_DOC = {
    "gains": "the law's gains, DOF by DOF (x .. psi), each DOF in the law's column order",
    "unc": "nominal-model factors [C, D, g, arm] (1): the fraction of each term a nominal model knows",
    "ekf": "EKF tuning [q_eta (m^2, rad^2), q_nu (m^2/s^2, rad^2/s^2): process noise per sample; var_position "
           "(m^2), var_attitude (rad^2), var_velocity (m^2/s^2, rad^2/s^2): the sensor variances R assumes; with "
           "per-axis sensors the 12 variances of [eta; nu] instead of the three]",
    "eta_d": "set point eta_d in {n} (m, rad): where the vehicle is held",
    "p": "the model parameters, SI (names, units and indices in the _params.h header)",
}


def _doubles(v) -> str:
    return ", ".join(ex._c_double(x) for x in np.asarray(v, dtype=float).ravel())


def _limit(v: float) -> str:
    return "HUGE_VAL" if math.isinf(v) else ex._c_double(v)


def _header(I: _Info) -> str:
    from arvcas import __version__

    d, sz, up, pre = I.d, I.sz, I.up, I.d.prefix
    P, law, cfg = d.params, d.law, d.cfg
    guard = f"{d.lib.upper()}_H"
    cols = law.columns()
    L = [
        f"/* {d.lib}.h: the {c_comment(law.label or law.name)} controller of arvcas ({c_comment(law.description)}) for the system",
        f" * {P.structure.name}, as a standalone C library: EKF on the measured [eta; nu], the adaptive tracking",
        " * differentiator's reference, the law, thrust allocation and saturation: one call per sample.",
        " *",
        f" * Generated by arvcas {__version__} with CasADi {ca.__version__} from {c_comment(P.path)}",
        f" * and the scenario {c_comment(cfg.path or '(given in code)')}; gains: {c_comment(d.gains_source)}.",
        " * The same operations in the same order as the controller inside arvcas's compiled run",
        " * (arvcas.sim.closedloop.controller_sample builds both): closed around the same plant it gives",
        " * the same trace (docs/exporting-a-controller.md).",
        " *",
        *_UNITS_FRAMES,
        " *",
        f" * SAMPLING: call {pre}step once every {up}SAMPLE_TIME = {cfg.time_h:g} s (the period the law and its",
        " * gains were designed and discretised for; the reference and every integrator advance by that",
        " * much per call). Time t is passed to the law" + (" and read by it." if I.uses_t else "; this law does not read it."),
        " *",
        " * USE (no heap allocation, no global or static writable data; the state is the caller's):",
        f" *   {pre}params prm;  {pre}state s;  double y[12], u[{up}N_U];",
        f" *   {pre}default_params(&prm);          // the exported gains and defaults; change any field",
        f" *   if ({pre}init(&s, &prm) != 0) ...    // checks every parameter; then as after reset",
        " *   every H seconds:",
        f" *     y = measured [eta; nu];  {pre}step(&s, y, t, NULL, u);  send u to the thrusters",
        f" *   {pre}reset(&s)  starts again from the next measurement (EKF, reference, law state), same params.",
        " * The first step after init or reset starts the EKF at y (covariance R), the reference at the",
        " * estimate, and the law's state at its initial values, exactly as sample 0 of an arvcas run.",
        " *",
        " * THREAD SAFETY: every function reads and writes only its arguments; separate states may be",
        " * stepped in parallel, one state must not be used by two threads at once.",
        " *",
        f" * SYMBOLS: every global symbol starts with {pre}: the API below and CasADi's generated",
        f" * functions ({pre}cas_*), which are not part of the API.",
        " */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        "#ifdef __cplusplus",
        'extern "C" {',
        "#endif",
        "",
        f"#define {up}N_Y 12  /* measurement y = [eta; nu] */",
        f"#define {up}N_U {sz.n_u}  /* thrust commands, one per thruster */",
        f"#define {up}N_GAINS {sz.n_gains}",
        f"#define {up}N_P {sz.n_p}",
        f"#define {up}N_DIAG {sz.n_diag}",
        f"#define {up}SAMPLE_TIME {ex._c_double(cfg.time_h)}  /* sampling period (s) */",
        f"#define {up}USES_TAU_ARM {int(I.uses_tau_arm)}  /* 1: step reads tau_arm */",
        "",
        f"/* u: {I.thrust_text}, after saturation to each thruster's limits:",
        *[f" *   u[{j}]  {n}" for j, n in enumerate(I.thrusters)],
        " * (a thruster command map, thrust -> the unit the thrusters take, comes with issue 22) */",
        "",
        "/* errors returned by init and step (0: success) */",
        f"#define {up}E_GAIN (-1)     /* init: a gain is not finite, not > 0, or not below its stability limit */",
        f"#define {up}E_PARAM (-2)    /* init: unc, eta_d or p not finite, or ekf not finite with q >= 0, var > 0 */",
        f"#define {up}E_NOT_INIT (-3) /* step: the state was not initialised (init) */",
        f"#define {up}E_INPUT (-4)    /* step: y, t or tau_arm not finite: nothing changed */",
        f"#define {up}E_OUTPUT (-5)   /* step: the new state or command is not finite: nothing changed */",
        "",
        "/* The controller's parameters. gains[] per DOF (x, y, z, phi, theta, psi), each DOF in this order:",
    ]
    for g in law.gains:
        lim = f"; < {ex._c_double(g.upper_of_h(cfg.time_h))} at SAMPLE_TIME" if g.upper_of_h is not None else ""
        L.append(f" *   {c_comment(g.name):<6} ({c_comment(g.unit)}{lim}): {c_comment(g.description)}")
    L += [f" * i.e. gains[{len(cols)} * dof + column]. Every gain > 0. */", "typedef struct {"]
    for name, n in sz.params.items():
        L.append(f"  double {name}[{n}];  /* {_PARAM_DOC[name]} */")
    L += [f"}} {pre}params;", "",
          "/* The controller's state: owned by the caller (a local, a member, a static object: no heap). Its",
          f" * fields are private; read the last step's values with {pre}diagnostics. */",
          "typedef struct {",
          f"  double k[{sz.n_k}];  /* the params, then the nominal inertia Mhat */",
          f"  double kp0[{max(I.n_kp0, 1)}], kp[{max(I.n_kp, 1)}];  /* terms of the params alone */",
          f"  double mem[2][{sz.n_mem}];  /* EKF, reference, law state: current and next */",
          f"  double u[{sz.n_u}], diag[{sz.n_diag}];  /* the last step's command and diagnostics */",
          f"  long long iw[{I.sz_iw + 1}];",
          f"  double w[{I.sz_w + 1}];",
          "  long long n_steps;  /* steps since init or reset */",
          "  int cur, initialized, bad_index;",
          f"}} {pre}state;", "",
          f"/* the exported defaults (gains: {c_comment(d.gains_source)}); see {d.lib}_params.h */",
          f"void {pre}default_params({pre}params* prm);",
          "/* check prm, compute its derived terms, then reset; returns 0, or E_GAIN / E_PARAM: a refused entry",
          " * (bad_index says which) leaves the state as it was; derived terms that are not finite (e.g. a",
          " * singular thruster matrix; bad_index -1) leave it uninitialised */",
          f"int {pre}init({pre}state* s, const {pre}params* prm);",
          "/* forget the memory (EKF, reference, law state): the next step is a first step; params unchanged */",
          f"void {pre}reset({pre}state* s);",
          "/* one sample: y[12] the measured [eta; nu] (units and frames above), t the time (s), tau_arm[6]:",
    ]
    if I.uses_tau_arm:
        L += [" * the arm's wrench on the vehicle plus the trim, in {b} about the COB (N, N m), which this law's",
              " * nominal model uses a fraction unc[3] of (arvcas's run feeds the true value; on a vehicle an",
              " * estimate, e.g. export-c's arm_wrench from the joint encoders; NULL reads as zeros);"]
    else:
        L += [" * not read by this law (pass NULL);"]
    L += [f" * writes u[{up}N_U] (thrust per thruster, N, saturated; NULL: not copied). Returns 0 or an error. */",
          f"int {pre}step({pre}state* s, const double* y, double t, const double* tau_arm, double* u);",
          f"/* the last step's diagnostics, {up}N_DIAG values at these offsets (0 before the first step): */"]
    for s, off, w in I.diag:
        L.append(f"#define {up}DIAG_{ex._ident(s.name)} {off}  /* {w}: "
                 + c_comment(f"{s.name} ({s.units}{', ' + s.frame if s.frame else ''}): {s.description}") + " */")
    L += [f"const double* {pre}diagnostics(const {pre}state* s);",
          "/* after init returned E_GAIN or E_PARAM: the index of the first bad entry in the fields of params",
          " * taken in order as one array (gains, unc, ekf, eta_d, p) */",
          f"int {pre}bad_index(const {pre}state* s);",
          "/* the message of an error code */",
          f"const char* {pre}error(int code);",
          f"/* sizeof({pre}state) and sizeof({pre}params), for bindings */",
          f"unsigned long {pre}state_size(void);",
          f"unsigned long {pre}params_size(void);",
          "", "#ifdef __cplusplus", "}", "#endif", "", f"#endif /* {guard} */", ""]
    return "\n".join(L)


def _api_c(I: _Info) -> str:
    """The API around CasADi's generated functions (appended to the same translation unit)."""
    d, sz, up, pre = I.d, I.sz, I.up, I.d.prefix
    lib = d.lib
    cas = pre + "cas_"
    off = _offsets(sz.params)
    copy_params = "\n".join(f"  memcpy(s->k + {i}, prm->{name}, sizeof prm->{name});" for name, i in off.items())
    return f"""

/* ---------------------------------------------------------------------------------------------
 * The API of {lib}.h around the generated functions above (arvcas export-controller).
 */
#include <string.h>
#include "{lib}.h"
#include "{lib}_params.h"

static const double {cas}upper[{sz.n_gains}] = {{{", ".join(_limit(v) for v in I.upper)}}};

static int {cas}finite(const double* v, int n) {{
  for (int i = 0; i < n; ++i)
    if (!(v[i] - v[i] == 0.0)) return i;  /* NaN and inf fail */
  return -1;
}}

void {pre}default_params({pre}params* prm) {{
  static const double gains[{sz.n_gains}] = {{{_doubles(I.defaults["gains"])}}};
  static const double unc[4] = {{{_doubles(I.defaults["unc"])}}};
  static const double ekf[{sz.n_ekf}] = {{{_doubles(I.defaults["ekf"])}}};
  static const double eta_d[6] = {{{_doubles(I.defaults["eta_d"])}}};
  memcpy(prm->gains, gains, sizeof gains);
  memcpy(prm->unc, unc, sizeof unc);
  memcpy(prm->ekf, ekf, sizeof ekf);
  memcpy(prm->eta_d, eta_d, sizeof eta_d);
  memcpy(prm->p, {pre}p_default, sizeof prm->p);
}}

static int {cas}call(int (*f)(const double**, double**, long long*, double*, int), const double** arg,
                     double** res, {pre}state* s) {{
  return f(arg, res, s->iw, s->w, 0);
}}

int {pre}init({pre}state* s, const {pre}params* prm) {{
  const double* arg[{I.sz_arg}];
  double* res[{I.sz_res}];
  int i, bad = -1, rc = 0;
  /* the checks first: a refused prm leaves the state as it was (but for bad_index) */
  for (i = 0; i < {sz.n_gains} && bad < 0; ++i)
    if (!(prm->gains[i] > 0.0 && prm->gains[i] < {cas}upper[i])) {{ bad = {off['gains']} + i; rc = {up}E_GAIN; }}
  if (bad < 0 && (i = {cas}finite(prm->unc, 4)) >= 0) {{ bad = {off['unc']} + i; rc = {up}E_PARAM; }}
  for (i = 0; i < {sz.n_ekf} && bad < 0; ++i)
    if (!(prm->ekf[i] - prm->ekf[i] == 0.0) || (i < 2 ? prm->ekf[i] < 0.0 : prm->ekf[i] <= 0.0)) {{
      bad = {off['ekf']} + i; rc = {up}E_PARAM;
    }}
  if (bad < 0 && (i = {cas}finite(prm->eta_d, 6)) >= 0) {{ bad = {off['eta_d']} + i; rc = {up}E_PARAM; }}
  if (bad < 0 && (i = {cas}finite(prm->p, {sz.n_p})) >= 0) {{ bad = {off['p']} + i; rc = {up}E_PARAM; }}
  s->bad_index = bad;
  if (rc) return rc;
  memset(s, 0, sizeof *s);
  s->bad_index = -1;
{copy_params}
  arg[0] = prm->p;
  res[0] = s->k + {sz.n_k - 6};
  rc |= {cas}call({cas}mhat, arg, res, s);
  arg[0] = s->k;
  res[0] = s->kp0;
  rc |= {cas}call({cas}prep0, arg, res, s);
  res[0] = s->kp;
  rc |= {cas}call({cas}prep, arg, res, s);
  /* terms of p alone that are not finite (e.g. a singular thruster matrix): not initialised */
  if (rc || {cas}finite(s->k, {sz.n_k}) >= 0 || {cas}finite(s->kp0, {I.n_kp0}) >= 0 ||
      {cas}finite(s->kp, {I.n_kp}) >= 0)
    return {up}E_PARAM;
  s->initialized = 1;
  {pre}reset(s);
  return 0;
}}

void {pre}reset({pre}state* s) {{
  memset(s->mem, 0, sizeof s->mem);
  memset(s->u, 0, sizeof s->u);
  memset(s->diag, 0, sizeof s->diag);
  s->cur = 0;
  s->n_steps = 0;
}}

int {pre}step({pre}state* s, const double* y, double t, const double* tau_arm, double* u) {{
  const double* arg[{I.sz_arg}];
  double* res[{I.sz_res}];
  double u_new[{sz.n_u}], diag_new[{sz.n_diag}];
  double* next;
  if (!s->initialized) return {up}E_NOT_INIT;
  if ({cas}finite(y, 12) >= 0 || {cas}finite(&t, 1) >= 0 || (tau_arm && {cas}finite(tau_arm, 6) >= 0))
    return {up}E_INPUT;
  next = s->mem[1 - s->cur];
  arg[0] = s->mem[s->cur];
  arg[1] = s->k;
  arg[2] = s->n_steps == 0 ? s->kp0 : s->kp;
  arg[3] = y;
  arg[4] = &t;
  arg[5] = tau_arm;  /* NULL reads as zeros */
  res[0] = next;
  res[1] = u_new;
  res[2] = diag_new;
  if ({cas}call(s->n_steps == 0 ? {cas}step0 : {cas}step, arg, res, s)) return {up}E_OUTPUT;
  if ({cas}finite(next, {sz.n_mem}) >= 0 || {cas}finite(u_new, {sz.n_u}) >= 0) return {up}E_OUTPUT;
  s->cur = 1 - s->cur;
  s->n_steps += 1;
  memcpy(s->u, u_new, sizeof u_new);
  memcpy(s->diag, diag_new, sizeof diag_new);
  if (u) memcpy(u, u_new, sizeof u_new);
  return 0;
}}

const double* {pre}diagnostics(const {pre}state* s) {{
  return s->diag;
}}

int {pre}bad_index(const {pre}state* s) {{
  return s->bad_index;
}}

const char* {pre}error(int code) {{
  switch (code) {{
    case 0: return "success";
    case {up}E_GAIN: return "init: a gain is not finite, not > 0, or not below its stability limit";
    case {up}E_PARAM: return "init: a parameter is not finite, or ekf has q < 0 or a variance <= 0";
    case {up}E_NOT_INIT: return "step: the state was not initialised with init";
    case {up}E_INPUT: return "step: y, t or tau_arm is not finite; nothing changed";
    case {up}E_OUTPUT: return "step: the new state or command is not finite; nothing changed";
    default: return "unknown error code";
  }}
}}

unsigned long {pre}state_size(void) {{
  return (unsigned long) sizeof({pre}state);
}}

unsigned long {pre}params_size(void) {{
  return (unsigned long) sizeof({pre}params);
}}
"""


def _offsets(fields: dict[str, int]) -> dict[str, int]:
    out, i = {}, 0
    for name, n in fields.items():
        out[name] = i
        i += n
    return out


def _params_h(I: _Info) -> str:
    d, up, pre = I.d, I.up, I.d.prefix
    extra = ["", f"/* gains of {c_comment(d.law.name)}: {c_comment(d.gains_source)} (names and units in {d.lib}.h) */"]
    for k, (name, unit) in enumerate(zip(I.gain_names, I.gain_units)):
        extra.append(f"#define {up}GAIN_{ex._ident(name)} {k}  /* {c_comment(unit)} */")
    return ex._params_header(
        I.P, None, pre, title=f"Default parameters of the exported {d.law.name} controller, SI units.",
        use=f"{pre}default_params fills {pre}params with these and the gains, nominal factors, EKF tuning and set "
            f"point of {d.lib}.c.", extra=extra)


# ---------------------------------------------------------------------------------------------
# examples and binding: a few steps at a fixed measurement, the same printed lines in C, C++, Python


_EXAMPLE_STEPS = 5


def _example_y(I: _Info) -> list[float]:
    """A measurement 0.1 m and 0.05 rad off the set point in every DOF, at rest."""
    eta_d = I.defaults["eta_d"]
    return [float(v) for v in eta_d + np.array([0.1, -0.1, 0.1, 0.05, -0.05, 0.05])] + [0.0] * 6


def _example_c(I: _Info) -> str:
    lib, pre, up = I.d.lib, I.d.prefix, I.up
    return f"""/* example.c: the exported controller for {_EXAMPLE_STEPS} samples at a fixed measurement; prints
 * 'step k t : u...' and 'diag k : ...' with %.17g (example.cpp and example.py print the same lines).
 * Build and run: make && ./example */
#include <stdio.h>
#include "{lib}.h"

int main(void)
{{
  {pre}params prm;
  {pre}state s;  /* no heap: the state is here */
  const double y[{up}N_Y] = {{{_doubles(_example_y(I))}}};
  double u[{up}N_U];
  int k, i, rc;
  {pre}default_params(&prm);
  if ((rc = {pre}init(&s, &prm)) != 0) {{
    fprintf(stderr, "init: %s\\n", {pre}error(rc));
    return 1;
  }}
  for (k = 0; k < {_EXAMPLE_STEPS}; ++k) {{
    double t = k * {up}SAMPLE_TIME;
    if ((rc = {pre}step(&s, y, t, NULL, u)) != 0) {{
      fprintf(stderr, "step: %s\\n", {pre}error(rc));
      return 1;
    }}
    printf("step %d %.17g :", k, t);
    for (i = 0; i < {up}N_U; ++i) printf(" %.17g", u[i]);
    printf("\\ndiag %d :", k);
    for (i = 0; i < {up}N_DIAG; ++i) printf(" %.17g", {pre}diagnostics(&s)[i]);
    printf("\\n");
  }}
  return 0;
}}
"""


def _example_cpp(I: _Info) -> str:
    lib, pre, up = I.d.lib, I.d.prefix, I.up
    return f"""// example.cpp: the same as example.c from C++ (the header compiles as C and as C++).
// Build: make (example_cpp), or with CMake.
#include <array>
#include <cstdio>
#include "{lib}.h"

int main() {{
  {pre}params prm;
  {pre}state s;
  const std::array<double, {up}N_Y> y{{{_doubles(_example_y(I))}}};
  std::array<double, {up}N_U> u{{}};
  {pre}default_params(&prm);
  if (int rc = {pre}init(&s, &prm)) {{
    std::fprintf(stderr, "init: %s\\n", {pre}error(rc));
    return 1;
  }}
  for (int k = 0; k < {_EXAMPLE_STEPS}; ++k) {{
    double t = k * {up}SAMPLE_TIME;
    if (int rc = {pre}step(&s, y.data(), t, nullptr, u.data())) {{
      std::fprintf(stderr, "step: %s\\n", {pre}error(rc));
      return 1;
    }}
    std::printf("step %d %.17g :", k, t);
    for (double v : u) std::printf(" %.17g", v);
    std::printf("\\ndiag %d :", k);
    const double* dg = {pre}diagnostics(&s);
    for (int i = 0; i < {up}N_DIAG; ++i) std::printf(" %.17g", dg[i]);
    std::printf("\\n");
  }}
  return 0;
}}
"""


def _example_py(I: _Info) -> str:
    lib = I.d.lib
    return f'''"""example.py: the same as example.c through the ctypes binding {lib}.py. Run after make:
    python3 example.py [path/to/lib{lib}.so]
"""

import sys

import {lib} as binding

Y = {_example_y(I)!r}


def main(argv):
    c = binding.Controller(argv[1] if len(argv) > 1 else None)
    for k in range({_EXAMPLE_STEPS}):
        t = k * binding.H
        u = c.step(Y, t)
        print("step %d %.17g :" % (k, t) + "".join(" %.17g" % v for v in u))
        print("diag %d :" % k + "".join(" %.17g" % v for v in c.diagnostics_flat()))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
'''


def _binding_py(I: _Info) -> str:
    d, sz, pre = I.d, I.sz, I.d.prefix
    lib = d.lib
    diag = [(s.name, off, w, s.units, s.frame) for s, off, w in I.diag]
    return f'''"""{lib}.py: the exported {d.law.name} controller of arvcas from Python, through ctypes.

No arvcas, CasADi or NumPy needed. Build the library first (make). Units and frames: {lib}.h.

    from {lib} import Controller
    c = Controller()                 # lib{lib}.so beside this file; the exported defaults
    c.init(gains=[...])              # optional: other gains, unc, ekf, eta_d or p (lists)
    u = c.step(y, t)                 # y = measured [eta; nu] (12), t in s; u: thrust per thruster (N)
    c.diagnostics()                  # {{name: values}} of the last step
    c.reset()                        # the next step starts the EKF, reference and law again
"""

import ctypes
import os

PREFIX = {pre!r}
H = {d.cfg.time_h!r}  # sampling period (s): call step once every H seconds
N_Y, N_U, N_GAINS, N_P = 12, {sz.n_u}, {sz.n_gains}, {sz.n_p}
USES_TAU_ARM = {I.uses_tau_arm!r}
THRUSTERS = {I.thrusters!r}
GAIN_NAMES = {I.gain_names!r}
# diagnostics: (name, offset, width, units, frame)
DIAGNOSTICS = {diag!r}
ERRORS = {{-1: "E_GAIN", -2: "E_PARAM", -3: "E_NOT_INIT", -4: "E_INPUT", -5: "E_OUTPUT"}}
_FIELDS = {list(sz.params.items())!r}

_d = ctypes.c_double


class Params(ctypes.Structure):
    """{pre}params: the controller's parameters (lists of doubles by field)."""

    _fields_ = [(name, _d * n) for name, n in _FIELDS]


class ControllerError(ValueError):
    pass


class Controller:
    """One controller state (its own memory) over the library."""

    H, N_U, USES_TAU_ARM, THRUSTERS, GAIN_NAMES, DIAGNOSTICS = H, N_U, USES_TAU_ARM, THRUSTERS, GAIN_NAMES, DIAGNOSTICS

    def __init__(self, path=None):
        if path is None:
            path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "lib{lib}.so")
        self.lib = lib = ctypes.CDLL(path)
        self._fn = {{}}
        for name, res, args in (
                ("default_params", None, [ctypes.POINTER(Params)]),
                ("init", ctypes.c_int, [ctypes.c_void_p, ctypes.POINTER(Params)]),
                ("reset", None, [ctypes.c_void_p]),
                ("step", ctypes.c_int, [ctypes.c_void_p, ctypes.POINTER(_d), _d, ctypes.POINTER(_d),
                                        ctypes.POINTER(_d)]),
                ("diagnostics", ctypes.POINTER(_d), [ctypes.c_void_p]),
                ("bad_index", ctypes.c_int, [ctypes.c_void_p]),
                ("error", ctypes.c_char_p, [ctypes.c_int]),
                ("state_size", ctypes.c_ulong, []),
                ("params_size", ctypes.c_ulong, [])):
            f = getattr(lib, PREFIX + name)
            f.restype, f.argtypes = res, args
            self._fn[name] = f
        if self._fn["params_size"]() != ctypes.sizeof(Params):
            raise ControllerError(f"{{path}}: {pre}params has another size than this binding expects")
        self.state = ctypes.create_string_buffer(self._fn["state_size"]())
        self.params = Params()
        self._fn["default_params"](ctypes.byref(self.params))
        self._y, self._tau, self._u = (_d * N_Y)(), (_d * 6)(), (_d * N_U)()
        n_diag = sum(w for _, _, w, _, _ in DIAGNOSTICS)
        self._n_diag = n_diag
        self.init()

    def defaults(self):
        """The exported defaults, {{field: list}}."""
        p = Params()
        self._fn["default_params"](ctypes.byref(p))
        return {{name: list(getattr(p, name)) for name, _ in _FIELDS}}

    def init(self, **fields):
        """Change any of {", ".join(sz.params)} (sequences), check them, and reset; refused: nothing changes."""
        new = Params()
        ctypes.memmove(ctypes.byref(new), ctypes.byref(self.params), ctypes.sizeof(Params))
        for name, values in fields.items():
            if name not in dict(_FIELDS):
                raise ControllerError(f"init: unknown field {{name!r}} (allowed: {{', '.join(n for n, _ in _FIELDS)}})")
            values = [float(v) for v in values]
            if len(values) != dict(_FIELDS)[name]:
                raise ControllerError(f"init: {{name}}: expected {{dict(_FIELDS)[name]}} values, got {{len(values)}}")
            getattr(new, name)[:] = values
        rc = self._fn["init"](self.state, ctypes.byref(new))
        if rc:
            i = self._fn["bad_index"](self.state)
            where = "derived terms"
            for name, n in _FIELDS:
                if 0 <= i < n:
                    where = f"{{name}}[{{i}}]"
                    break
                i -= n
            raise ControllerError(f"{{self._fn['error'](rc).decode()}}: {{where}}")
        self.params = new

    def reset(self):
        self._fn["reset"](self.state)

    def step(self, y, t, tau_arm=None):
        """One sample: thrust per thruster (N) for the measured [eta; nu] y at time t (s)."""
        self._y[:] = [float(v) for v in y]
        tau = None
        if tau_arm is not None:
            self._tau[:] = [float(v) for v in tau_arm]
            tau = self._tau
        rc = self._fn["step"](self.state, self._y, float(t), tau, self._u)
        if rc:
            raise ControllerError(f"step: {{self._fn['error'](rc).decode()}}")
        return list(self._u)

    def diagnostics_flat(self):
        return self._fn["diagnostics"](self.state)[:self._n_diag]

    def diagnostics(self):
        """The last step's diagnostics, {{name: list}} (units and frames: DIAGNOSTICS, {lib}.h)."""
        flat = self.diagnostics_flat()
        return {{name: flat[off:off + w] for name, off, w, _, _ in DIAGNOSTICS}}
'''


def _readme(I: _Info) -> str:
    from arvcas import __version__

    d, sz, pre, up = I.d, I.sz, I.d.prefix, I.up
    lib = d.lib
    L = [
        f"# lib{lib}: the {markdown(d.law.label or d.law.name)} controller of arvcas in C",
        "",
        f"Generated by arvcas {__version__} with CasADi {ca.__version__} for the system `{d.params.structure.name}`"
        f" (`{markdown(d.params.path)}`) and the scenario `{markdown(d.cfg.path or '(given in code)')}`; gains:"
        f" {markdown(d.gains_source)}.",
        "",
        f"{markdown(d.law.description[:1].upper() + d.law.description[1:])}. One call of `{pre}step` per sample (every {d.cfg.time_h:g} s) runs the EKF on the "
        "measured `[eta; nu]`, the reference of the adaptive tracking differentiator, the law, thrust allocation and "
        "saturation, and returns the thrust per thruster. It performs the same operations in the same order as the "
        "controller inside arvcas's compiled run.",
        "",
        "## Files",
        "",
        f"- `{lib}.c`: CasADi's generated code and the API; `{lib}.h`: the API with units and frames;"
        f" `{lib}_params.h`: the default model parameters `p` (names, SI units) and the gains' indices",
        f"- `{lib}.py`: a ctypes binding (class `Controller`: `init`, `step`, `reset`, `diagnostics`)",
        f"- `example.c`, `example.cpp`, `example.py`: {_EXAMPLE_STEPS} samples at a fixed measurement, the same lines",
        f"- `Makefile` (`make` builds `lib{lib}.so`, `example`, `example_cpp`), `CMakeLists.txt` (also"
        f" `cmake --install` with the package config `{lib}Config.cmake`), `consumer/CMakeLists.txt`",
        f"- `{ex.MANIFEST}`: what arvcas wrote, with sha256; it replaces only those files, unchanged",
        "",
        "Build with the flags in the build files (arvcas's): no `-Ofast`, `-ffast-math` or FMA contraction, or the",
        "numbers are no longer arvcas's.",
        "",
        "## Inputs and outputs",
        "",
        "| | size | unit, frame | meaning |",
        "|---|---|---|---|",
        "| `y` | 12 | m, rad ({n}); m/s, rad/s ({b}) | measured `[eta; nu]`: NED position of the COB, ZYX Euler"
        " angles, body velocity about the COB |",
        "| `t` | 1 | s | time of the sample" + ("" if I.uses_t else " (this law does not read it)") + " |",
        "| `tau_arm` | 6 | N, N m ({b}, about the COB) | " + (
            "the arm's wrench on the vehicle plus the trim; this law's nominal model uses the fraction `unc[3]`"
            if I.uses_tau_arm else "not read by this law (NULL)") + " |",
        f"| `u` | {sz.n_u} | N | {I.thrust_text}, after saturation |",
        "",
        "Parameters (`" + pre + "params`):",
        "",
    ]
    for name, n in sz.params.items():
        L.append(f"- `{name}[{n}]`: {_PARAM_DOC[name]}")
    L += ["", "Gains (per DOF, in this order): " + ", ".join(f"`{g.name}` ({g.unit})" for g in d.law.gains), "",
          "Default gains: " + markdown(d.gains_source) + ".", "",
          "| gain | " + " | ".join(DOFS) + " |", "|---|" + "---|" * 6]
    k = len(d.law.gains)
    for j, g in enumerate(d.law.gains):
        L.append(f"| `{g.name}` | " + " | ".join(f"{I.defaults['gains'][dof * k + j]:.6g}" for dof in range(6)) + " |")
    L += ["", "Diagnostics after each step (`" + pre + "diagnostics`):", ""]
    for s, off, w in I.diag:
        L.append(f"- `[{off}:{off + w}]` `{s.name}` ({s.units}{', ' + s.frame if s.frame else ''}): {s.description}")
    L += ["", f"Thruster command maps (thrust to PWM or rotor speed) are not part of this export yet (arvcas issue"
          " 22): `u` is thrust in N.", ""]
    return "\n".join(L)


# ---------------------------------------------------------------------------------------------
# the binding and the closed loop


def load_binding(out_dir, lib_path=None):
    """The ``<lib>.py`` binding module of an export directory, and a :class:`Controller` of it
    (``lib_path``: the built library, default ``lib<lib>.so`` in the directory)."""
    out = Path(out_dir)
    mods = [p for p in out.glob("*.py") if p.name != "example.py"]
    if len(mods) != 1:
        raise ExportError(f"{out}: expected one <lib>.py binding, found {[p.name for p in mods]}")
    spec = importlib.util.spec_from_file_location(f"_arvcas_binding_{mods[0].stem}", mods[0])
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod, mod.Controller(None if lib_path is None else str(lib_path))


def close_loop(controller, run, seed: int = 0, rhs=None, thrust=None, states=None) -> dict:
    """The exported controller closed around the plant over a compiled run's scenario.

    ``controller``: a binding's ``Controller`` (:func:`load_binding`), initialised with the gains to
    compare; ``run``: the :class:`arvcas.sim.run.CompiledRun` whose scenario, system and time table
    are used; ``seed``: the noise sequence (:func:`arvcas.sim.scenario.noise_sequence`), fed in as the
    measurement ``y = x + noise``; ``rhs(x, tau, q, qd, qdd, payload) -> xdot`` and ``thrust(u) ->
    tau``: the exported plant (default: ``arvcas.dynamics("uvms_rhs")`` and ``("thrust")`` of the
    run's system, the compiled C that ``arvcas export-c`` writes). The plant is integrated like the
    run's: ``h / h_plant`` RK4 steps per sample with the thrust held, the arm's motion and the
    disturbance (eq. 41) at the RK4 stage times from the run's time table. A law whose step reads
    ``tau_arm`` gets the true value at the sample computed as in the run
    (:func:`arvcas.sim.closedloop.arm_truth`). ``states``: (N + 1, 12) true states
    ``[eta; nu]`` to measure instead of integrating the plant (a run's own ``eta``, ``nu``: the
    controller then sees exactly the run's measurements).

    Returns the series of the run's signals that the controller and the plant give (``t``, ``eta``,
    ``nu``, ``eta_hat``, ``eta_ref``, ``tau_cmd``, ``thrust``, ``q``, ``payload`` and the law's own),
    each (N + 1, width), and ``chat``, ``rmse`` (6) as the run computes them (eq. 42-43).
    """
    from arvcas.build.dynamics import dynamics
    from arvcas.sim import scenario, schedule

    cfg, P = run.cfg, run.params
    if P.structure.has_thruster_dynamics or cfg.has_water:
        raise ExportError(f"{WHAT}: close_loop integrates the exported plant (arvcas export-c), which has no thruster "
                          f"dynamics, current or tether (docs/model.md §9-§10): give a run with "
                          f"Params.instantaneous() and a scenario without [current] and [tether]")
    lay = P.layout
    p = P.vector()
    rhs = rhs or (lambda f: lambda x, tau, q, qd, qdd, pl: f(x, tau, q, qd, qdd, pl))(dynamics("uvms_rhs", P))
    thrust = thrust or dynamics("thrust", P)
    truth = None
    if controller.USES_TAU_ARM:
        truth = arm_truth(RunSpec(run.controller, cfg.graph_key(), run.opts, lay))
    tab = run.table
    R = schedule.records(lay)
    TS, AS = R.time_size, R.arm_size
    sl = R.slices
    n = scenario.n_samples(cfg)
    N = n - 1
    hp, h = cfg.time_h_plant, cfg.time_h
    noise = scenario.noise_sequence(cfg, seed)
    ph = np.array(cfg.disturbance_phase, dtype=float)
    cos_ph = np.array([math.cos(v) for v in ph])
    sin_ph = np.array([math.sin(v) for v in ph])
    off, amp = np.array(cfg.disturbance_offset, dtype=float), np.array(cfg.disturbance_amplitude, dtype=float)

    def stage(k, j):
        r = tab.time[j * TS:(j + 1) * TS, k]
        dist = off + amp * (r[sl["dist_sin"]] * cos_ph + r[sl["dist_cos"]] * sin_ph)  # eq. 41 (disturbance_tabulated)
        return r[sl["q"]], r[sl["qd"]], r[sl["qdd"]], r[sl["payload"]], dist

    x = np.array(list(cfg.initial_eta0) + list(cfg.initial_nu0) if states is None else states[0], dtype=float)
    u_hold = np.zeros(P.structure.n_thrusters)
    names = [name for name, *_ in controller.DIAGNOSTICS]
    series = {k: [] for k in ("t", "eta", "nu", *names, "thrust", "q", "payload")}
    chat_sum, e2_sum, tau_prev = np.zeros(6), np.zeros(6), None
    controller.reset()
    for k in range(n):
        tk = k * h  # the run's t_k
        q, qd, qdd, pl, dist = stage(k, 0)
        tau_arm = None
        if truth is not None:
            tau_arm = np.array(truth(x, u_hold, tab.time[0:TS, k], tab.arm[0:AS, k], p, ph)).ravel()
        u = np.array(controller.step(list(x + noise[:, k]), tk, tau_arm))
        dg = controller.diagnostics()
        tau_v, y1 = np.array(dg["tau_cmd"]), np.array(dg["eta_ref"])
        for name in names:
            series[name].append(dg[name])
        series["t"].append([tk])
        series["eta"].append(x[0:6].copy())
        series["nu"].append(x[6:12].copy())
        series["thrust"].append(u)
        series["q"].append(q)
        series["payload"].append(pl)
        e = x[0:6] - y1
        if k > 0:
            chat_sum = chat_sum + np.abs(tau_v - tau_prev)
        if k < N:
            e2_sum = e2_sum + e**2
        tau_prev = tau_v
        tau_real = np.asarray(thrust(u)).ravel()
        for i in range(0 if states is not None else cfg.substeps):
            def f(xx, j):
                qj, qdj, qddj, plj, dj = stage(k, 2 * i + j)
                return np.asarray(rhs(xx, tau_real + dj, qj, qdj, qddj, plj)).ravel()

            k1 = f(x, 0)
            k2 = f(x + 0.5 * hp * k1, 1)
            k3 = f(x + 0.5 * hp * k2, 1)
            k4 = f(x + hp * k3, 2)
            x = x + hp / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        u_hold = u
        if states is not None and k + 1 < n:
            x = np.array(states[k + 1], dtype=float)
    out = {k: np.array(v, dtype=float) for k, v in series.items()}
    for k in ("t", "payload"):
        out[k] = out[k].reshape(-1)
    out["chat"] = chat_sum / N
    out["rmse"] = np.sqrt(e2_sum / N)
    return out
