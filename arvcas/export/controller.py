"""``arvcas export-controller DIR``: the controller of a run as a standalone C library.

The controller is everything of a controller sample that is not the plant: the EKF on the measured
``[eta; nu]``, the ATD reference, the law (its own state, e.g. the RESO or the PID integral) and the
allocation with saturation (docs/architecture.md, "One controller sample"). Its graph is
:func:`arvcas.sim.closedloop.controller_functions`, built by
:func:`arvcas.sim.closedloop.controller_sample`, the function the run's own sample is built with, so
the exported code performs the same operations in the same order as the compiled run: closed around
the plant over the run's scenario it gives the run's trace and metrics (tests/test_export_controller.py
measures the difference; docs/exporting-a-controller.md).

DIR receives (the file set and build files of ``arvcas export-c``, :mod:`arvcas.build.export`; the text
of each file is a template of ``arvcas/build/templates/controller/``, :mod:`arvcas.build.templating`,
filled with the values this module computes):

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

:func:`arvcas.export.closeloop.close_loop` closes the exported controller (through its binding) around
the plant functions over a compiled run's scenario (its noise sequence and its time table), for the
tests and for anyone who wants to see the equality for themselves.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas.build import export as ex
from arvcas.build.templating import c_double, render
from arvcas.controllers import gains as gains_mod
from arvcas.controllers.base import DOFS, Controller, get as get_controller
from arvcas.sim.closedloop import controller_diagnostics, controller_functions, controller_reads, controller_sizes
from arvcas.sim.scenario import SENSOR_WHAT, ScenarioConfig, latencies, measured
from arvcas.sim.scenario import COMPONENTS as Y_NAMES
from arvcas.sim.thrust_forcing import command_functions
from arvcas.system.loader import UNSET, renamed_system

__all__ = ["ExportError", "export_controller", "default_prefix", "files"]

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
    values = _values(d, fns, work)
    gains = {"law": law.name, "source": d.gains_source, "lib": d.lib,
             "names_units": list(zip(values["gain_names"], gains_mod.gain_units(law)))}  # their indices in _params.h
    texts = {
        f"{d.lib}.c": c_text + render("controller/api.c.j2", values, ExportError),
        f"{d.lib}.h": render("controller/controller.h.j2", values, ExportError),
        f"{d.lib}_params.h": ex.params_header(
            P, None, prefix, title=f"Default parameters of the exported {law.name} controller, SI units.",
            use=f"{prefix}default_params fills {prefix}params with these and the gains, nominal factors, EKF tuning "
                f"and set point of {d.lib}.c.", gains=gains),
        f"{d.lib}.py": render("controller/binding.py.j2", values, ExportError),
        "example.c": render("controller/example.c.j2", values, ExportError),
        "example.cpp": render("controller/example.cpp.j2", values, ExportError),
        "example.py": render("controller/example.py.j2", values, ExportError),
        **ex.build_files(prefix),
        "README.md": render("controller/README.md.j2", values, ExportError),
    }
    assert tuple(texts) + (ex.MANIFEST,) == names
    return ex.write_package(out, texts, prefix, WHAT)


# ---------------------------------------------------------------------------------------------
# the values the templates (arvcas/build/templates/controller/) are filled with


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

_EXAMPLE_STEPS = 5  # the examples' samples at a fixed measurement
_EXAMPLE_OFFSET = [0.1, -0.1, 0.1, 0.05, -0.05, 0.05]  # the examples' measurement: this far off the set point (m, rad)


def _command_texts(P) -> list[dict]:
    """Per listed thruster of a system with thruster dynamics: its name, its command's unit and what its
    command is."""
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
        out.append({"name": name, "unit": _UNIT_WORDS.get(u, u), "what": what})
    return out


def _p_rules(P) -> list[int]:
    """The sign rule of each entry of p for C (1: > 0, 2: >= 0, 0: any): the system file's, from its layout;
    and the water's density > 0 where the exported system has water (a system file may give env.rho = 0 for a
    vehicle described without fluid; a controller exported for one in water must not be given none)."""
    rules = [{"pos": 1, "nonneg": 2}.get(r, 0) for r in P.layout.rules]
    names = list(P.layout.names)
    if "env.rho" in names and P["env.rho"] > 0:
        rules[names.index("env.rho")] = 1
    return rules


def _measurements(cfg) -> list[dict]:
    """y's components: the name in [eta; nu], what measures it, how often it is fresh and the latency it was tuned
    with (docs/sensors.md: the controller takes each reading as it arrives, as the state of that sample)."""
    h, out = cfg.time_h, []
    lag = dict(latencies(cfg))
    for i, sensor, every in measured(cfg):
        rate = "every sample" if every == 1 else (f"every {every} samples ({every * h:g} s): read when round(t / "
                                                  f"SAMPLE_TIME) is a multiple of {every}, ignored otherwise")
        if sensor in lag:
            d = lag[sensor]
            rate += (f"; tuned with a latency of {d} sample{'s' if d > 1 else ''} ({d * h:g} s): pass the reading "
                     f"when it arrives")
        out.append({"index": i, "name": Y_NAMES[i], "sensor": SENSOR_WHAT.get(sensor), "kind": sensor, "rate": rate,
                    "latency": lag.get(sensor, 0) * h})
    return out


def _values(d: _Design, fns: dict[str, ca.Function], work: dict[str, dict[str, int]]) -> dict:
    """Everything the templates need, computed once."""
    from arvcas import __version__

    P, law, cfg = d.params, d.law, d.cfg
    st = P.structure
    sz = controller_sizes(law, P.layout, cfg)
    has_map = "command" in fns  # a thruster command map: step also gives the command in its unit
    diag, i = [], 0
    for s in controller_diagnostics(law):
        w = s.n(st.n_thrusters, st.n_joints)
        units_frame = f"{s.units}{', ' + s.frame if s.frame else ''}"
        diag.append({"name": s.name, "offset": i, "width": w, "units_frame": units_frame,
                     "description": s.description, "text": f"{s.name} ({units_frame}): {s.description}",
                     "row": (s.name, i, w, s.units, s.frame)})
        i += w
    off, i = {}, 0
    for name, n in sz.params.items():
        off[name] = i
        i += n
    meas = _measurements(cfg)
    eta_d = np.array(cfg.initial_eta_d, dtype=float)
    y = [float(v) for v in eta_d + np.array(_EXAMPLE_OFFSET)] + [0.0] * 6
    k = len(law.gains)
    return {
        "lib": d.lib, "pre": d.prefix, "up": d.prefix.upper(), "cas": d.prefix + "cas_", "guard": f"{d.lib.upper()}_H",
        "version": __version__, "casadi_version": ca.__version__, "manifest": ex.MANIFEST,
        "law": law, "system": st.name, "system_path": P.path, "scenario_path": cfg.path or "(given in code)",
        "gains_source": d.gains_source, "h": cfg.time_h, "h_text": f"{cfg.time_h:g}",
        "uses_t": controller_reads(fns, "t"), "uses_tau_arm": controller_reads(fns, "tau_arm"),
        "meas": meas, "full_state": all(m["kind"] == "state" for m in meas), "sz": sz,
        "n_kp0": fns["prep0"].numel_out(0), "n_kp": fns["prep"].numel_out(0),
        **{key: max(w[key] for w in work.values()) for key in ("sz_w", "sz_iw", "sz_arg", "sz_res")},
        "thrusters": list(st.thrusters) if st.thrusters is not None else [f"T{j + 1}" for j in range(st.n_thrusters)],
        "thrust_text": ex._glossary(P)["u"],  # export-c's words: "thrust per thruster (N): <names>"
        "has_map": has_map, "n_tab": fns["thr_tab"].numel_out(0) if has_map else 0,
        "commands": _command_texts(P) if has_map else [],
        "gains": [{"name": g.name, "unit": g.unit, "description": g.description,
                   "limit": None if g.upper_of_h is None else c_double(g.upper_of_h(cfg.time_h))} for g in law.gains],
        "n_columns": len(law.columns()),
        "upper": ["HUGE_VAL" if math.isinf(v) else c_double(v) for v in gains_mod.upper_limits(law, cfg.time_h)],
        "gain_names": gains_mod.gain_names(law),
        "param_doc": _PARAM_DOC, "off": off, "p_rules": _p_rules(P), "diag": diag,
        "defaults": {"gains": d.gains, "unc": cfg.uncertainty, "ekf": cfg.ekf_vector, "eta_d": eta_d},
        "dofs": DOFS, "gain_table": [(g.name, [f"{d.gains[dof * k + j]:.6g}" for dof in range(6)])
                                     for j, g in enumerate(law.gains)],
        "steps": _EXAMPLE_STEPS, "example_y": [y[m["index"]] for m in meas],
    }
