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
from arvcas.sim.closedloop import (RunSpec, arm_truth, command_functions, controller_diagnostics, controller_functions,
                                   controller_reads, controller_sizes)
from arvcas.sim.scenario import SENSOR_WHAT, ScenarioConfig, measured
from arvcas.sim.scenario import COMPONENTS as Y_NAMES
from arvcas.system.loader import UNSET, renamed_system

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


def export_controller(out_dir, controller="proposed", gains=None, system=None, scenario=None, *, prefix=None,
                      gains_source: str | None = None, force: bool = False, params=UNSET) -> list[Path]:
    """Write the controller of a run as a C library with header, build files, binding and examples.

    ``controller``: a registered name or Controller; ``gains``: its flat gain vector (default: the
    system's defaults), with ``gains_source`` saying where it comes from (it goes into the header and
    README); ``system``: anything :func:`arvcas.system.resolve` takes (default: the default system; ``params=``:
    its old name);
    ``scenario``: a ScenarioConfig or file (default: the system's): it gives the sampling period, the
    ATD's time and amplitude floor, and the default set point, nominal factors and EKF tuning;
    ``prefix``: of every symbol (default :func:`default_prefix`). A file in ``out_dir`` that the
    manifest does not list with its current sha256 is refused unless ``force``. Returns the paths
    written, in :func:`files` order. Raises :class:`ExportError` (a ValueError) before writing anything.
    """
    from arvcas.sim import scenario as scenario_mod
    from arvcas.system import resolve

    params = renamed_system(system, params, "export_controller")

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
        fns.update(command_functions(cfg, P.layout, prefix + "cas_"))
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
        self.has_map = "command" in fns  # a thruster command map: step also gives the command in its unit
        self.n_tab = fns["thr_tab"].numel_out(0) if self.has_map else 0
        self.commands = _command_texts(P) if self.has_map else []
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
        self.meas = measured(cfg)  # y's components: (index in [eta; nu], sensor, every)

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


_UNIT_WORDS = {"us": "us (PWM pulse width)", "1": "1 (normalised command)", "rad/s": "rad/s (rotor speed)"}


def _command_texts(P) -> list[tuple[str, str, str]]:
    """Per listed thruster: (name, unit, what its command is) for a system with thruster dynamics."""
    out = []
    for name, dyn in zip(P.structure.thrusters, P.structure.thruster_dynamics):
        m = P.structure.thruster_map(dyn.map)
        u = m.unit

        def v(key):
            return float(P[f"thrusters.map.{m.name}.{key}"])

        if m.kind == "table":
            i0, i1 = m.zero
            lo, hi = v(f"command.{i0}"), v(f"command.{i1}")
            what = (f"map {m.name}: table {v('command.0'):g}-{v(f'command.{m.n - 1}'):g} {u}, dead band "
                    f"{lo:g}-{hi:g} {u} ({0.5 * (lo + hi):g} {u}: at rest)")
        else:
            db = v("dead_band")
            what = (f"map {m.name}: thrust = {v('rotor_constant'):g} s |s|, s the command beyond the dead band "
                    f"+-{db:g} {u}, command within [{v('command_min'):g}, {v('command_max'):g}] {u}")
        out.append((name, _UNIT_WORDS.get(u, u), what))
    return out


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
        f" * {P.structure.name}, as a standalone C library: EKF on the measurements y, the adaptive tracking",
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
        f" *   {pre}params prm;  {pre}state s;  double y[{up}N_Y], u[{up}N_U];",
        f" *   {pre}default_params(&prm);          // the exported gains and defaults; change any field",
        f" *   if ({pre}init(&s, &prm) != 0) ...    // checks every parameter; then as after reset",
        " *   every H seconds:",
        f" *     y = the measurements (MEASUREMENTS below);  {pre}step(&s, y, t, NULL, u);  send u to the thrusters",
        f" *   {pre}reset(&s)  starts again from the next measurement (EKF, reference, law state), same params.",
        " * The first step after init or reset starts the EKF at y (covariance R), the reference at the",
        " * estimate, and the law's state at its initial values, exactly as sample 0 of an arvcas run.",
        " *",
        *_measurement_doc(I),
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
        f"#define {up}N_Y {len(I.meas)}  /* measurements y (MEASUREMENTS above) */",
        f"#define {up}N_U {sz.n_u}  /* thrust commands, one per thruster */",
        f"#define {up}N_GAINS {sz.n_gains}",
        f"#define {up}N_P {sz.n_p}",
        f"#define {up}N_DIAG {sz.n_diag}",
        f"#define {up}SAMPLE_TIME {ex._c_double(cfg.time_h)}  /* sampling period (s) */",
        f"#define {up}USES_TAU_ARM {int(I.uses_tau_arm)}  /* 1: step reads tau_arm */",
        f"#define {up}HAS_COMMAND_MAP {int(I.has_map)}  /* 1: {pre}command gives each thruster's command in its unit */",
        "",
        f"/* u: {I.thrust_text}, after saturation to each thruster's limits:",
        *[f" *   u[{j}]  {n}" for j, n in enumerate(I.thrusters)],
        *([" * command (after each step, " + pre + "command): what each thruster's ESC or driver is sent for its",
           " * thrust u, in its command map's unit (the map inverted: arvcas's docs/model.md section 9):",
           *[f" *   command[{j}]  {n}: {c_comment(unit)}; {c_comment(what)}" for j, (n, unit, what) in
             enumerate(I.commands)]] if I.has_map else
          [" * (this system's thrusters have no command map: send the thrust u; docs/system-file.md) */"]),
        *([" */"] if I.has_map else []),
        "",
        "/* errors returned by init and step (0: success) */",
        f"#define {up}E_GAIN (-1)     /* init: a gain is not finite, not > 0, or not below its stability limit */",
        f"#define {up}E_PARAM (-2)    /* init: a parameter not finite or impossible: unc < 0, ekf q < 0 or var <= 0,",
        "                                * eta_d's pitch at or beyond +-90 deg, p breaking the system file's sign",
        "                                * rules (a mass, inertia or water density <= 0, ...) */",
        f"#define {up}E_NOT_INIT (-3) /* step: the state was not initialised (init) */",
        f"#define {up}E_INPUT (-4)    /* step: y, t or tau_arm not finite: nothing changed */",
        f"#define {up}E_OUTPUT (-5)   /* step: the new state or command is not finite: nothing changed */",
        f"#define {up}E_NULL (-6)     /* init: s or prm is NULL; step: s or y is NULL (nothing written) */",
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
          f"  double u[{sz.n_u}], diag[{sz.n_diag}];  /* the last step's thrust and diagnostics */",
          *([f"  double tab[{I.n_tab}], command[{sz.n_u}];  /* the command maps' tables; the last step's command */"]
            if I.has_map else []),
          f"  long long iw[{I.sz_iw + 1}];",
          f"  double w[{I.sz_w + 1}];",
          "  long long n_steps;  /* steps since init or reset */",
          "  int cur, initialized, bad_index;",
          f"}} {pre}state;", "",
          f"/* the exported defaults (gains: {c_comment(d.gains_source)}); see {d.lib}_params.h */",
          f"void {pre}default_params({pre}params* prm);",
          "/* NULL: init and step return E_NULL for a NULL s, prm or y (tau_arm and u may be NULL, as said at",
          " * step); reset(NULL) does nothing; diagnostics(NULL) and command(NULL) return NULL;",
          " * bad_index(NULL) returns -1. */",
          "/* check prm, compute its derived terms, then reset; returns 0, or E_GAIN / E_PARAM: a refused entry",
          " * (bad_index says which) leaves the state as it was; derived terms that are not finite (e.g. a",
          " * singular thruster matrix; bad_index -1) leave it uninitialised */",
          f"int {pre}init({pre}state* s, const {pre}params* prm);",
          "/* forget the memory (EKF, reference, law state): the next step is a first step; params unchanged */",
          f"void {pre}reset({pre}state* s);",
          f"/* one sample: y[{up}N_Y] the measurements (MEASUREMENTS above), t the time (s), tau_arm[6]:",
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
    if I.has_map:
        L += [f"/* the last step's command per thruster ({up}N_U values, each in its map's unit, listed above;",
              " * zeros before the first step: send nothing then) */",
              f"const double* {pre}command(const {pre}state* s);"]
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


def _measurement_doc(I: _Info) -> list[str]:
    """The header's MEASUREMENTS: y's components, each with its sensor and how often it is fresh."""
    h, up = I.d.cfg.time_h, I.up
    if all(sensor == "state" for _, sensor, _ in I.meas):
        return [f" * MEASUREMENTS: y[{up}N_Y] = [eta; nu] in full (units and frames above), fresh at every sample."]
    L = [f" * MEASUREMENTS (the scenario's sensor set, docs/sensors.md): y[{up}N_Y], in this order:"]
    for j, (i, sensor, every) in enumerate(I.meas):
        rate = "every sample" if every == 1 else (f"every {every} samples ({every * h:g} s): read when round(t / "
                                                  f"SAMPLE_TIME) is a multiple of {every}, ignored otherwise")
        L.append(f" *   y[{j}]  {Y_NAMES[i]}: {c_comment(SENSOR_WHAT[sensor])}; {rate}")
    L.append(" * The rest of [eta; nu] is estimated, not measured. Without a position fix x and y are not held:")
    L.append(" * the law acts on depth, attitude and heading only, and the vehicle may drift horizontally.")
    return L


def _api_c(I: _Info) -> str:
    """The API around CasADi's generated functions (appended to the same translation unit)."""
    d, sz, up, pre = I.d, I.sz, I.up, I.d.prefix
    lib = d.lib
    cas = pre + "cas_"
    off = _offsets(sz.params)
    copy_params = "\n".join(f"  memcpy(s->k + {i}, prm->{name}, sizeof prm->{name});" for name, i in off.items())
    tab_check = reset_cmd = step_cmd = copy_cmd = cmd_fn = ""
    if I.has_map:  # the command map: its tables once per init, the command after each step's thrust
        tab_check = f" ||\n      {cas}finite(s->tab, {I.n_tab}) >= 0"
        reset_cmd = "\n  memset(s->command, 0, sizeof s->command);"
        step_cmd = (f"\n  arg[0] = u_new;\n  arg[1] = s->tab;\n  arg[2] = s->k + {off['p']};\n  res[0] = cmd_new;\n"
                    f"  if ({cas}call({cas}command, arg, res, s) || {cas}finite(cmd_new, {sz.n_u}) >= 0) return {up}E_OUTPUT;")
        copy_cmd = "\n  memcpy(s->command, cmd_new, sizeof cmd_new);"
        cmd_fn = f"\nconst double* {pre}command(const {pre}state* s) {{\n  return s ? s->command : 0;\n}}\n"
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

/* the system file's sign rule of each entry of p (1: > 0, 2: >= 0, 0: any), as arvcas's loader checks them */
static const signed char {cas}p_rule[{sz.n_p}] = {{{_p_rules(I)}}};

/* the first entry of p that breaks its sign rule, or -1 */
static int {cas}p_signs(const double* p) {{
  for (int i = 0; i < {sz.n_p}; ++i)
    if (({cas}p_rule[i] == 1 && !(p[i] > 0.0)) || ({cas}p_rule[i] == 2 && !(p[i] >= 0.0))) return i;
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
  if (!s) return {up}E_NULL;
  if (!prm) {{ s->bad_index = -1; return {up}E_NULL; }}
  /* the checks first: a refused prm leaves the state as it was (but for bad_index) */
  for (i = 0; i < {sz.n_gains} && bad < 0; ++i)
    if (!(prm->gains[i] > 0.0 && prm->gains[i] < {cas}upper[i])) {{ bad = {off['gains']} + i; rc = {up}E_GAIN; }}
  for (i = 0; i < 4 && bad < 0; ++i)  /* the nominal-model factors: finite and >= 0 */
    if (!(prm->unc[i] - prm->unc[i] == 0.0) || prm->unc[i] < 0.0) {{ bad = {off['unc']} + i; rc = {up}E_PARAM; }}
  for (i = 0; i < {sz.n_ekf} && bad < 0; ++i)
    if (!(prm->ekf[i] - prm->ekf[i] == 0.0) || (i < 2 ? prm->ekf[i] < 0.0 : prm->ekf[i] <= 0.0)) {{
      bad = {off['ekf']} + i; rc = {up}E_PARAM;
    }}
  if (bad < 0 && (i = {cas}finite(prm->eta_d, 6)) >= 0) {{ bad = {off['eta_d']} + i; rc = {up}E_PARAM; }}
  /* the set point's pitch inside +-90 deg (the Euler angles' singularity), as the scenario loader asks */
  if (bad < 0 && !(prm->eta_d[4] > -{_HALF_PI} && prm->eta_d[4] < {_HALF_PI})) {{ bad = {off['eta_d']} + 4; rc = {up}E_PARAM; }}
  if (bad < 0 && (i = {cas}finite(prm->p, {sz.n_p})) >= 0) {{ bad = {off['p']} + i; rc = {up}E_PARAM; }}
  if (bad < 0 && (i = {cas}p_signs(prm->p)) >= 0) {{ bad = {off['p']} + i; rc = {up}E_PARAM; }}
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
  rc |= {cas}call({cas}prep, arg, res, s);{_init_tab(I)}
  /* terms of p alone that are not finite (e.g. a singular thruster matrix): not initialised */
  if (rc || {cas}finite(s->k, {sz.n_k}) >= 0 || {cas}finite(s->kp0, {I.n_kp0}) >= 0 ||
      {cas}finite(s->kp, {I.n_kp}) >= 0{tab_check})
    return {up}E_PARAM;
  s->initialized = 1;
  {pre}reset(s);
  return 0;
}}

void {pre}reset({pre}state* s) {{
  if (!s) return;
  memset(s->mem, 0, sizeof s->mem);
  memset(s->u, 0, sizeof s->u);
  memset(s->diag, 0, sizeof s->diag);{reset_cmd}
  s->cur = 0;
  s->n_steps = 0;
}}

int {pre}step({pre}state* s, const double* y, double t, const double* tau_arm, double* u) {{
  const double* arg[{I.sz_arg}];
  double* res[{I.sz_res}];
  double u_new[{sz.n_u}], diag_new[{sz.n_diag}]{", cmd_new[" + str(sz.n_u) + "]" if I.has_map else ""};
  double* next;
  if (!s || !y) return {up}E_NULL;
  if (!s->initialized) return {up}E_NOT_INIT;
  if ({cas}finite(y, {up}N_Y) >= 0 || {cas}finite(&t, 1) >= 0 || (tau_arm && {cas}finite(tau_arm, 6) >= 0))
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
  if ({cas}finite(next, {sz.n_mem}) >= 0 || {cas}finite(u_new, {sz.n_u}) >= 0) return {up}E_OUTPUT;{step_cmd}
  s->cur = 1 - s->cur;
  s->n_steps += 1;
  memcpy(s->u, u_new, sizeof u_new);{copy_cmd}
  memcpy(s->diag, diag_new, sizeof diag_new);
  if (u) memcpy(u, u_new, sizeof u_new);
  return 0;
}}

const double* {pre}diagnostics(const {pre}state* s) {{
  return s ? s->diag : 0;
}}
{cmd_fn}
int {pre}bad_index(const {pre}state* s) {{
  return s ? s->bad_index : -1;
}}

const char* {pre}error(int code) {{
  switch (code) {{
    case 0: return "success";
    case {up}E_GAIN: return "init: a gain is not finite, not > 0, or not below its stability limit";
    case {up}E_PARAM: return "init: a parameter is not finite or impossible (unc < 0, ekf q < 0 or variance <= 0, "
                             "pitch set point at or beyond +-90 deg, p against its sign rule)";
    case {up}E_NOT_INIT: return "step: the state was not initialised with init";
    case {up}E_INPUT: return "step: y, t or tau_arm is not finite; nothing changed";
    case {up}E_OUTPUT: return "step: the new state or command is not finite; nothing changed";
    case {up}E_NULL: return "a NULL pointer where a state, params or measurement is needed; nothing written";
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


_HALF_PI = "1.5707963267948966"  # pi / 2 in C


def _p_rules(I: _Info) -> str:
    """The sign rule of each entry of p for C (1: > 0, 2: >= 0, 0: any): the system file's, from its layout;
    and the water's density > 0 where the exported system has water (a system file may give env.rho = 0 for a
    vehicle described without fluid; a controller exported for one in water must not be given none)."""
    rules = [{"pos": 1, "nonneg": 2}.get(r, 0) for r in I.P.layout.rules]
    names = list(I.P.layout.names)
    if "env.rho" in names and I.P["env.rho"] > 0:
        rules[names.index("env.rho")] = 1
    return ", ".join(str(r) for r in rules)


def _init_tab(I: _Info) -> str:
    """init's call of the command maps' tables (the run's per-run constants), after the derived terms."""
    if not I.has_map:
        return ""
    cas = I.d.prefix + "cas_"
    return f"\n  arg[0] = prm->p;\n  res[0] = s->tab;\n  rc |= {cas}call({cas}thr_tab, arg, res, s);"


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
    y = [float(v) for v in eta_d + np.array([0.1, -0.1, 0.1, 0.05, -0.05, 0.05])] + [0.0] * 6
    return [y[i] for i, _, _ in I.meas]


def _cmd_line(I: _Info, lang: str) -> str:
    """The examples' 'command k :' line (each thruster's command in its map's unit), with a command map."""
    if not I.has_map:
        return ""
    pre, up = I.d.prefix, I.up
    if lang == "c":
        return (f'\n    printf("\\ncommand %d :", k);\n'
                f'    for (i = 0; i < {up}N_U; ++i) printf(" %.17g", {pre}command(&s)[i]);')
    if lang == "cpp":
        return (f'\n    std::printf("\\ncommand %d :", k);\n'
                f'    for (int i = 0; i < {up}N_U; ++i) std::printf(" %.17g", {pre}command(&s)[i]);')
    return '        print("command %d :" % k + "".join(" %.17g" % v for v in c.command()))\n'


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
    for (i = 0; i < {up}N_U; ++i) printf(" %.17g", u[i]);{_cmd_line(I, "c")}
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
    for (double v : u) std::printf(" %.17g", v);{_cmd_line(I, "cpp")}
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
{_cmd_line(I, "py")}        print("diag %d :" % k + "".join(" %.17g" % v for v in c.diagnostics_flat()))
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
    u = c.step(y, t)                 # y: the N_Y measurements MEASURED ({lib}.h), t in s; u: thrust (N)
    c.command()                      # with a command map: what each thruster is sent (COMMAND_UNITS)
    c.diagnostics()                  # {{name: values}} of the last step
    c.reset()                        # the next step starts the EKF, reference and law again
"""

import ctypes
import os

PREFIX = {pre!r}
H = {d.cfg.time_h!r}  # sampling period (s): call step once every H seconds
N_Y, N_U, N_GAINS, N_P = {len(I.meas)}, {sz.n_u}, {sz.n_gains}, {sz.n_p}
MEASURED = {[Y_NAMES[i] for i, _, _ in I.meas]!r}  # y's components of [eta; nu], in order
USES_TAU_ARM = {I.uses_tau_arm!r}
THRUSTERS = {I.thrusters!r}
HAS_COMMAND_MAP = {I.has_map!r}  # True: command() gives each thruster's command in its map's unit
COMMAND_UNITS = {[unit for _, unit, _ in I.commands]!r}
GAIN_NAMES = {I.gain_names!r}
# diagnostics: (name, offset, width, units, frame)
DIAGNOSTICS = {diag!r}
ERRORS = {{-1: "E_GAIN", -2: "E_PARAM", -3: "E_NOT_INIT", -4: "E_INPUT", -5: "E_OUTPUT", -6: "E_NULL"}}
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
    HAS_COMMAND_MAP, COMMAND_UNITS = HAS_COMMAND_MAP, COMMAND_UNITS

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
                ("params_size", ctypes.c_ulong, []),
                *([("command", ctypes.POINTER(_d), [ctypes.c_void_p])] if HAS_COMMAND_MAP else [])):
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
        """One sample: thrust per thruster (N) for the measurements y (MEASURED) at time t (s)."""
        self._y[:] = [float(v) for v in y]
        tau = None
        if tau_arm is not None:
            self._tau[:] = [float(v) for v in tau_arm]
            tau = self._tau
        rc = self._fn["step"](self.state, self._y, float(t), tau, self._u)
        if rc:
            raise ControllerError(f"step: {{self._fn['error'](rc).decode()}}")
        return list(self._u)

    def command(self):
        """The last step's command per thruster, each in its map's unit (COMMAND_UNITS: PWM us, 1, rad/s)."""
        if not HAS_COMMAND_MAP:
            raise ControllerError("command: this system's thrusters have no command map (send the thrust of step)")
        return self._fn["command"](self.state)[:N_U]

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
        f"| `y` | {len(I.meas)} | m, rad ({{n}}); m/s, rad/s ({{b}}) | the measurements, components "
        f"{', '.join(Y_NAMES[i] for i, _, _ in I.meas)} of `[eta; nu]` (NED position of the COB, ZYX "
        "Euler angles, body velocity about the COB; each sensor's rate: the header's MEASUREMENTS) |",
        "| `t` | 1 | s | time of the sample" + ("" if I.uses_t else " (this law does not read it)") + " |",
        "| `tau_arm` | 6 | N, N m ({b}, about the COB) | " + (
            "the arm's wrench on the vehicle plus the trim; this law's nominal model uses the fraction `unc[3]`"
            if I.uses_tau_arm else "not read by this law (NULL)") + " |",
        f"| `u` | {sz.n_u} | N | {I.thrust_text}, after saturation |",
        *([f"| `{pre}command(&s)` | {sz.n_u} | per thruster, below | the command each thruster is sent for its thrust"
           f" `u` (its command map inverted, docs/model.md §9 of arvcas) |"] if I.has_map else []),
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
    if I.has_map:
        L += ["", "Thruster commands (`" + pre + "command` after each step; the thrust `u` as well):", ""]
        L += [f"- `command[{j}]` {markdown(n)}: {markdown(unit)}; {markdown(what)}" for j, (n, unit, what) in
              enumerate(I.commands)]
    else:
        L += ["", "This system's thrusters have no command map (docs/system-file.md of arvcas): `u`, thrust in N,"
              " is what the thrusters are sent."]
    L += [""]
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


class _Rotors:
    """The thrusters' side of the plant with thruster dynamics (docs/model.md §9), in NumPy: what a thruster
    does with the command it is sent. ``target(command)``: the rotor state it steers to (the command beyond
    the dead band's edge, 0 inside the band); ``stages(s0, y)``: the rotor states at a sample's RK4 stage
    times (the lag's closed form, :func:`arvcas.model.thrusters.lag_states`, with the command held), one
    column per stage; ``thrust(s)``: the steady thrust of rotor states (a table's monotone cubic by
    SciPy's ``PchipInterpolator``, the quadratic law ``k s |s|``)."""

    def __init__(self, P, cfg):
        from scipy.interpolate import PchipInterpolator

        from arvcas.model import thrusters as thr
        from arvcas.sim.closedloop import stage_offsets
        from arvcas.system.params import view

        lay = P.layout
        st = lay.structure
        pv = P.vector()
        Pn = view(ca.DM(pv), lay)
        self.lo, self.hi, self.F = [], [], []
        for d in st.thruster_dynamics:
            m = st.thruster_map(d.map)
            if m.kind == "table":
                i0, i1 = m.zero
                lo, hi = float(Pn[f"thrusters.map.{m.name}.command.{i0}"]), float(Pn[f"thrusters.map.{m.name}.command.{i1}"])
                g, v = (np.array(ca.DM(x), dtype=float).ravel() for x in thr.map_grid(Pn, m))
                self.F.append(PchipInterpolator(g, v, extrapolate=True))
            else:
                hi = float(Pn[f"thrusters.map.{m.name}.dead_band"])
                lo = -hi
                k = float(Pn[f"thrusters.map.{m.name}.rotor_constant"])
                self.F.append(lambda x, k=k: k * x * np.abs(x))
            self.lo.append(lo)
            self.hi.append(hi)
        self.lo, self.hi = np.array(self.lo), np.array(self.hi)
        offs = stage_offsets(cfg)
        p_s, s0, y = ca.SX.sym("p", len(lay)), ca.SX.sym("s0", st.n_thrusters), ca.SX.sym("y", st.n_thrusters)
        Ps = view(p_s, lay)
        S = thr.lag_states(Ps, s0, y, thr.lag_constants(Ps, offs), offs, cfg.time_h)
        self._lag = ca.Function("rotor_stages", [s0, y, p_s], [ca.horzcat(*[ca.vertcat(*row) for row in zip(*S)])])
        self._p = pv

    def target(self, command):
        c = np.asarray(command, dtype=float)
        return np.where(c > self.hi, c - self.hi, np.where(c < self.lo, c - self.lo, 0.0))

    def stages(self, s0, y):
        return np.array(self._lag(s0, y, self._p), dtype=float)

    def thrust(self, s):
        s = np.asarray(s, dtype=float)
        return np.array([F(s[i]) for i, F in enumerate(self.F)], dtype=float)


def _tether_pull(cfg):
    """The wrench (6, {b}, about the body origin) of a tether without a current at the state ``x``: its pull
    ``f`` ({n}) turned into the body frame, ``R(eta)' f``, and its moment ``r_a x R(eta)' f`` (docs/model.md §10;
    R = Rz(psi) Ry(theta) Rx(phi), NumPy)."""
    r_a, f_n = np.array(cfg.tether_attachment, dtype=float), np.array(cfg.tether_pull, dtype=float)

    def wrench(x):
        cf, sf, ct, st, cp, sp = (np.cos(x[3]), np.sin(x[3]), np.cos(x[4]), np.sin(x[4]), np.cos(x[5]), np.sin(x[5]))
        R = np.array([[cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
                      [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
                      [-st, ct * sf, ct * cf]])
        f = R.T @ f_n
        return np.concatenate([f, np.cross(r_a, f)])

    return wrench


def close_loop(controller, run, seed: int = 0, rhs=None, thrust=None, states=None, delivered=None) -> dict:
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

    With thruster dynamics (docs/model.md §9) the controller's commands (its ``command()``, in the map's
    unit: PWM µs for the T200) drive the rotors (:class:`_Rotors`: the rotor state each command steers to,
    the lag's closed form at the RK4 stage times, the map's thrust by SciPy's PCHIP), and ``thrust(T)`` of
    the rotors' thrust at each stage drives the plant's RK4 stages; the series add ``thrust_cmd`` (the
    controller's thrust), ``command`` and ``tau_delivered``, and ``thrust`` is the delivered thrust at t_k,
    as in the run. ``delivered``: (N + 1, n_thrusters) delivered thrust at t_k to give ``arm_truth`` instead
    of the rotors' (a run's own ``thrust``, for a replay with ``states``).

    A tether (docs/model.md §10) is a wrench on the plant: without a current its drag is zero and it pulls
    with ``pull`` ({n}) at its attachment, ``f_b = R(eta)' pull`` and ``r_a x f_b`` (NumPy, at every RK4
    stage's state), added to the plant's ``tau``. A current is refused: it acts inside the hydrodynamics
    (``D(nu_r) nu_r``, ``C_A(nu_r) nu_r``, ``M_A nu_c_dot``, the links' drag in the relative flow), which the
    exported plant's body-wrench input cannot carry.

    Returns the series of the run's signals that the controller and the plant give (``t``, ``eta``,
    ``nu``, ``eta_hat``, ``eta_ref``, ``tau_cmd``, ``thrust``, ``q``, ``payload`` and the law's own),
    each (N + 1, width), and ``chat``, ``rmse`` (6) as the run computes them (eq. 42-43).
    """
    from arvcas.build.dynamics import dynamics
    from arvcas.sim import scenario, schedule

    cfg, P = run.cfg, run.params
    if cfg.time_thrust_quadrature:
        raise ExportError(f"{WHAT}: close_loop integrates the exported plant by RK4 with the thrust at its stage times; "
                          f"this run's scenario sets time.thrust_quadrature ({cfg.time_thrust_quadrature}), another "
                          f"integration of the thrusters' forcing (docs/model.md §9); give a scenario without it")
    if cfg.current != "none":
        raise ExportError(f"{WHAT}: close_loop integrates the exported plant (arvcas export-c's uvms_rhs and thrust), "
                          f"which takes a body wrench: a current acts inside its hydrodynamic terms (the relative "
                          f"velocity, docs/model.md §10) and cannot be added to it; give a scenario without [current]")
    tether = _tether_pull(cfg) if cfg.has_tether else None
    dyn = P.structure.has_thruster_dynamics
    if dyn and not getattr(controller, "HAS_COMMAND_MAP", False):
        raise ExportError(f"{WHAT}: close_loop: the run's system has thruster dynamics but the controller has no "
                          f"command map (export it for that system)")
    rotors = _Rotors(P, cfg) if dyn else None
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
    held = np.array(scenario.held_dofs(cfg), dtype=float)
    ph = np.array(cfg.disturbance_phase, dtype=float)
    cos_ph = np.array([math.cos(v) for v in ph])
    sin_ph = np.array([math.sin(v) for v in ph])
    off, amp = np.array(cfg.disturbance_offset, dtype=float), np.array(cfg.disturbance_amplitude, dtype=float)
    water = cfg.water_vector

    def stage(k, j):
        r = tab.time[j * TS:(j + 1) * TS, k]
        dist = off + amp * (r[sl["dist_sin"]] * cos_ph + r[sl["dist_cos"]] * sin_ph)  # eq. 41 (disturbance_tabulated)
        return r[sl["q"]], r[sl["qd"]], r[sl["qdd"]], r[sl["payload"]], dist

    x = np.array(list(cfg.initial_eta0) + list(cfg.initial_nu0) if states is None else states[0], dtype=float)
    n_thr = P.structure.n_thrusters
    u_hold = np.zeros(n_thr)  # the thrust acting at t_k: held, or the rotors' delivered thrust
    s_rot = np.zeros(n_thr)  # the rotor states (at rest)
    names = [name for name, *_ in controller.DIAGNOSTICS]
    series = {k: [] for k in ("t", "eta", "nu", *names, "thrust", "q", "payload")}
    if dyn:
        series.update(thrust_cmd=[], command=[], tau_delivered=[])
    chat_sum, e2_sum, chatd_sum, tau_prev, tdel_prev = np.zeros(6), np.zeros(6), np.zeros(6), None, None
    controller.reset()
    for k in range(n):
        tk = k * h  # the run's t_k
        q, qd, qdd, pl, dist = stage(k, 0)
        tau_arm = None
        if truth is not None:
            u_true = u_hold if delivered is None else np.asarray(delivered[k], dtype=float)
            tau_arm = np.array(truth(x, u_true, tab.time[0:TS, k], tab.arm[0:AS, k], p, ph, water, tk)).ravel()
        u = np.array(controller.step([(x + noise[:, k])[i] for i, _, _ in measured(cfg)], tk, tau_arm))
        dg = controller.diagnostics()
        tau_v, y1 = np.array(dg["tau_cmd"]), np.array(dg["eta_ref"])
        for name in names:
            series[name].append(dg[name])
        series["t"].append([tk])
        series["eta"].append(x[0:6].copy())
        series["nu"].append(x[6:12].copy())
        if dyn:  # the command drives the rotors; the wrench at every RK4 stage is that of their thrust
            cmd = np.array(controller.command())
            S = rotors.stages(s_rot, rotors.target(cmd))
            T = rotors.thrust(S)  # (n_thr, stages); column 0 is the thrust at t_k
            W = [np.asarray(thrust(T[:, j])).ravel() for j in range(T.shape[1])]
            series["thrust"].append(T[:, 0])
            series["thrust_cmd"].append(u)
            series["command"].append(cmd)
            series["tau_delivered"].append(W[0])
            tau_del = W[0]
        else:
            series["thrust"].append(u)
            tau_del = np.asarray(thrust(u)).ravel()
        series["q"].append(q)
        series["payload"].append(pl)
        e = (x[0:6] - y1) * held  # the error of the DOFs the task holds (docs/sensors.md)
        if k > 0:
            chat_sum = chat_sum + np.abs(tau_v - tau_prev)
            chatd_sum = chatd_sum + np.abs(tau_del - tdel_prev)  # CHAT on the delivered wrench (docs/model.md §6)
        if k < N:
            e2_sum = e2_sum + e**2
        tau_prev, tdel_prev = tau_v, tau_del
        tau_real = tau_del
        for i in range(0 if states is not None else cfg.substeps):
            def f(xx, j):
                qj, qdj, qddj, plj, dj = stage(k, 2 * i + j)
                tr = W[2 * i + j] if dyn else tau_real  # stage 2i + j of the sample
                if tether is not None:
                    tr = tr + tether(xx)
                return np.asarray(rhs(xx, tr + dj, qj, qdj, qddj, plj)).ravel()

            k1 = f(x, 0)
            k2 = f(x + 0.5 * hp * k1, 1)
            k3 = f(x + 0.5 * hp * k2, 1)
            k4 = f(x + hp * k3, 2)
            x = x + hp / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        if dyn:
            s_rot = S[:, -1]
            u_hold = T[:, -1]
        else:
            u_hold = u
        if states is not None and k + 1 < n:
            x = np.array(states[k + 1], dtype=float)
    out = {k: np.array(v, dtype=float) for k, v in series.items()}
    for k in ("t", "payload"):
        out[k] = out[k].reshape(-1)
    out["chat"] = chat_sum / N
    out["rmse"] = np.sqrt(e2_sum / N)
    out["chat_delivered"] = chatd_sum / N
    return out
