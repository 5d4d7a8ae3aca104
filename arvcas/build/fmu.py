"""Export the coupled vehicle + manipulator as an FMI 2.0 FMU (Model Exchange and Co-Simulation).

:func:`export_fmu` generates C for ``uvms_rhs`` with CasADi's :class:`casadi.CodeGenerator` (the same
graph and options as the compile cache, :mod:`arvcas.build.codegen`), wraps it in the FMI 2.0 C
interface (``templates/fmu/wrapper.c.j2``; the standard's headers in ``templates/fmi2/``, 2-clause
BSD), writes ``modelDescription.xml``, compiles ``binaries/<platform>/<modelIdentifier>.so`` with
the cache's compiler flags and zips it all, sources included, to ``FILE.fmu`` (a temporary file in
the same directory, then :func:`os.replace`).

The FMU is sized by its system (``system``: the default system, Haidou-1, if none; any system file): states ``eta``
(pose in {n}) and ``nu`` (velocity in {b} at the COB), which are also its outputs; inputs the body
wrench ``tau`` at the COB in {b} (or, with ``inputs="thrusters"``, the ``n_thrusters`` thrust
commands ``u``, realised as ``B_T sat(u)``), the ``n_joints`` joint positions, velocities and
accelerations ``q, qd, qdd`` and the payload fraction; parameters every number of the system's
``Params`` (SI, with units from the system's layout) and ``h_rk4``, the Co-Simulation RK4 step.
Value references: states 0-11, derivatives 12-23, inputs from 24 (:func:`layout`), ``h_rk4``, then
the parameters. Variables, units and use: docs/fmu.md.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import shutil
import sys
import time
import uuid
import zipfile
from importlib import resources
from pathlib import Path

from arvcas.build.templating import render
from arvcas.util import files
from arvcas.system.loader import UNSET, renamed_system

import casadi as ca

__all__ = ["FMUError", "export_fmu", "MODEL_IDENTIFIER", "INPUTS", "variables", "layout"]

MODEL_IDENTIFIER = "arvcas_uvms"
INPUTS = ("wrench", "thrusters")
_MODEL_C = f"{MODEL_IDENTIFIER}_model.c"
_WRAPPER_C = f"{MODEL_IDENTIFIER}.c"
_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
_H_RK4_DEFAULT = 0.01  # the FMU's own default RK4 step (the closed loop's h_plant is 0.05 s: results/step)

# FMI units (SI) with their base-unit exponents; display units for the files' mm and deg
_UNITS: dict[str, dict[str, int]] = {
    "m": {"m": 1},
    "rad": {"rad": 1},
    "m/s": {"m": 1, "s": -1},
    "rad/s": {"rad": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad/s2": {"rad": 1, "s": -2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "kg": {"kg": 1},
    "kg/m3": {"kg": 1, "m": -3},
    "kg.m2": {"kg": 1, "m": 2},
    "m3": {"m": 3},
    "s": {"s": 1},
    "1": {},
}
_DISPLAY = {"m": ("mm", 1000.0), "rad": ("deg", 180.0 / math.pi)}
# Params dimension -> FMI unit; hydrodynamic derivatives are per unit density (docs/model.md §2)
_DIM_UNIT = {
    "density": "kg/m3",
    "acceleration": "m/s2",
    "1": "1",
    "mass": "kg",
    "inertia": "kg.m2",
    "length": "m",
    "volume": "m3",
    "angle": "rad",
    "force": "N",
    "per_rho": None,
    # thruster dynamics (docs/model.md §9): parameters the FMU carries but does not use
    "time": "s",
    "angular_velocity": "rad/s",
    "angular_acceleration": "rad/s2",
    "pwm": None,  # an ESC's PWM pulse width in microseconds: a command, not an SI quantity
    "pwm_rate": None,
    "rate": None,
    "rotor_constant": None,
}
_STATE_DESCRIPTIONS = (
    "x: north position of the COB in {n} (NED)",
    "y: east position of the COB in {n}",
    "z: depth (down) of the COB in {n}",
    "phi: roll (ZYX Euler angle of {b} in {n})",
    "theta: pitch (ZYX Euler angle)",
    "psi: yaw (ZYX Euler angle)",
    "u: surge velocity of the COB in {b}",
    "v: sway velocity in {b}",
    "w: heave velocity in {b}",
    "p: roll rate in {b}",
    "q: pitch rate in {b}",
    "r: yaw rate in {b}",
)


class FMUError(ValueError):
    """The FMU cannot be written (one line naming the argument and what is allowed)."""


VR_U = 24  # the first input's value reference (after the 12 states and their 12 derivatives)


def layout(system=None, inputs: str = "wrench", *, params=UNSET) -> dict[str, int]:
    """Value references of the FMU of the system ``system`` (``params=``: its old name): the sizes ``n_in`` (the first inputs: 6
    for the wrench, n_thrusters for the thrusters), ``n_joints``, ``n_u`` (every input), the offsets
    of ``q``, ``qd``, ``qdd`` and ``payload`` within the inputs, and ``vr_h``, ``vr_p`` (Haidou-1:
    25 inputs, h_rk4 at 49, the parameters from 50)."""
    P = _check_params(renamed_system(system, params, "layout"))
    _check_inputs(inputs)
    st = P.structure
    n_in = 6 if inputs == "wrench" else st.n_thrusters
    nj = st.n_joints
    n_u = n_in + 3 * nj + 1
    return dict(n_in=n_in, n_joints=nj, n_u=n_u, q=n_in, qd=n_in + nj, qdd=n_in + 2 * nj, payload=n_in + 3 * nj,
                vr_h=VR_U + n_u, vr_p=VR_U + n_u + 1, n_p=len(P))


def fmi_name(name: str) -> str:
    """A parameter's FMU variable name: its name, a table's point index as an array index
    (``thrusters.map.t200_16v.thrust.7`` -> ``thrusters.map.t200_16v.thrust[7]``: FMI's structured names
    do not start a part with a digit)."""
    return re.sub(r"\.(\d+)$", r"[\1]", name)


def _parameter_unit(P, name: str) -> tuple[str | None, str, dict | None]:
    """(FMI unit or None, description prefix, base-unit exponents of a derived unit or None) of
    parameter ``name`` of the system of ``P``."""
    from arvcas.build.units import si_exponents, unit_text

    dim = P.layout.dims[P.layout.index[name]]
    if ".map." in name or name.endswith((".time_constant", ".time_constant_up", ".time_constant_down", ".rate_limit")):
        return _DIM_UNIT[dim], "thruster dynamics, not used by the FMU (docs/fmu.md); ", None
    if dim != "per_rho":
        return _DIM_UNIT[dim], "", None
    exps = si_exponents(P, name)
    if exps is None:  # per unit density: no one unit
        return None, "per unit density (SI coefficient = env.rho * value); ", None
    unit = unit_text(exps, mul=".", power="")  # a derived unit (kg/m, kg.m2/rad2, ...), by its base units
    return unit, "hydrodynamic coefficient (SI); ", (None if unit in _UNITS else exps)


# ---------------------------------------------------------------------------------------------
# variables


def variables(system=None, inputs: str = "wrench", *, params=UNSET) -> list[dict]:
    """The FMU's ScalarVariables in order (value reference = index): name, causality, unit, start, ...

    ``system`` (its Params, a system file or None for the default system; ``params=``: its old name) sizes the inputs
    (:func:`layout`) and gives the parameters' start values; the states' start values are the
    ``eta0``, ``nu0`` of the system's default scenario (Haidou-1: ``data/scenario.toml``), the
    joints' the stowed pose ``arm.stow``.
    """
    from arvcas.sim.scenario import load_scenario

    P = _check_params(renamed_system(system, params, "variables"))
    lay = layout(P, inputs)
    st = P.structure
    cfg = load_scenario(P.default("scenario"))
    x0 = [*cfg.initial_eta0, *cfg.initial_nu0]
    V: list[dict] = []

    def add(name, causality, variability, unit, description, start=None, initial=None, **kw):
        V.append(dict(name=name, causality=causality, variability=variability, unit=unit,
                      description=description, start=start, initial=initial, **kw))

    units_x = ["m"] * 3 + ["rad"] * 3 + ["m/s"] * 3 + ["rad/s"] * 3
    for i in range(12):
        vec, k = ("eta", i) if i < 6 else ("nu", i - 6)
        what = _STATE_DESCRIPTIONS[i]
        add(f"{vec}[{k + 1}]", "output", "continuous", units_x[i], what, start=x0[i], initial="exact")
    units_dx = ["m/s"] * 3 + ["rad/s"] * 3 + ["m/s2"] * 3 + ["rad/s2"] * 3
    for i in range(12):
        add(f"der({V[i]['name']})", "local", "continuous", units_dx[i], f"time derivative of {V[i]['name']}",
            derivative=i + 1)
    if inputs == "wrench":
        for k in range(lay["n_in"]):
            add(f"tau[{k + 1}]", "input", "continuous", "N" if k < 3 else "N.m",
                f"body wrench at the COB in {{b}}: {'XYZKMN'[k]} ({'force' if k < 3 else 'moment'})", start=0.0)
    else:
        from arvcas.model.thrusters import limit_prefixes

        pre = limit_prefixes(st) * st.n_thrusters if st.thrusters is None else limit_prefixes(st)
        for k, (t, lim) in enumerate(zip(st.thruster_names(), pre)):
            add(f"u[{k + 1}]", "input", "continuous", "N",
                f"thrust command of thruster {t} (saturated to [{lim}u_min, {lim}u_max])", start=0.0)
    nj = lay["n_joints"]
    q0 = [P[f"arm.stow.q{j}"] for j in range(1, nj + 1)]
    for vec, unit, what, starts in (("q", "rad", "joint angle", q0), ("qd", "rad/s", "joint rate", [0.0] * nj),
                                     ("qdd", "rad/s2", "joint acceleration", [0.0] * nj)):
        for j in range(nj):
            add(f"{vec}[{j + 1}]", "input", "continuous", unit, f"{what} of joint {j + 1}", start=starts[j])
    add("payload", "input", "continuous", "1",
        "payload fraction in [0, 1]: scales payload.mass and payload.volume at the tool point", start=0.0,
        min=0.0, max=1.0)
    add("h_rk4", "parameter", "fixed", "s", "Co-Simulation only: the RK4 step (each communication step is "
        "split into ceil(H / h_rk4) equal steps; > 0)", start=_H_RK4_DEFAULT, initial="exact", min=0.0)
    vals = P.vector()
    for i, name in enumerate(P.names()):  # the system's parameters, units from its layout
        unit, what, base = _parameter_unit(P, name)
        src = P.source(name)
        desc = what + src
        file_unit = P.unit(name)
        display = None
        if unit in _DISPLAY and file_unit == _DISPLAY[unit][0]:
            display = file_unit
        # the loader's sign rule, > 0 (pos) or >= 0 (nonneg): declared, and checked at initialization
        bounds = {"min": 0.0} if P.layout.rules[i] in ("pos", "nonneg") else {}
        add(fmi_name(name), "parameter", "fixed", unit, desc, start=float(vals[i]), initial="exact", display=display,
            **bounds, **({"base": base} if base else {}))
    assert len(V) == lay["vr_p"] + len(P)
    return V


def _check_params(params):
    from arvcas.system import params as params_mod
    from arvcas.system import System, load_system

    if params is None:
        return params_mod.load()
    if isinstance(params, System):
        return params.params
    if isinstance(params, (str, os.PathLike)):  # a shipped system's name or a system file
        return load_system(params).params
    if not isinstance(params, params_mod.Params):
        raise FMUError(f"params: expected arvcas.system.params.Params, a system (name or file) or None, got "
                       f"{type(params).__name__}")
    return params


def _check_inputs(inputs) -> None:
    if inputs not in INPUTS:
        raise FMUError(f"inputs: expected one of {', '.join(INPUTS)}, got {inputs!r}")


# ---------------------------------------------------------------------------------------------
# model description


def _dependencies(fn: ca.Function) -> list[list[int]]:
    """For each of the 12 derivatives, the 1-based indices of the states and inputs it depends on."""
    syms = [ca.SX.sym(fn.name_in(i), fn.sparsity_in(i)) for i in range(fn.n_in())]
    xdot = fn.call(syms)[0]
    known = ca.vertcat(*syms[:-1])  # x (indices 1..12), then the inputs (indices 25.., VR_U + 1 on)
    sp = ca.jacobian_sparsity(xdot, known)
    cols = [1 + j if j < 12 else 25 + (j - 12) for j in range(known.numel())]
    rows, cs = sp.get_triplet()
    deps: list[list[int]] = [[] for _ in range(12)]
    for r, c in zip(rows, cs):
        deps[r].append(cols[c])
    return [sorted(d) for d in deps]


_KEYS = ("initial", "unit", "display", "start", "min", "max", "derivative")  # a variable's optional attributes


def _model_description(V: list[dict], deps: list[list[int]], guid: str, inputs: str, P) -> str:
    """``modelDescription.xml`` (``templates/fmu/modelDescription.xml.j2``)."""
    from arvcas._version import __version__

    bases = {v["unit"]: v.get("base") or _UNITS[v["unit"]] for v in V if v["unit"]}
    used = [u for u in _UNITS if u in bases] + [u for u in bases if u not in _UNITS]  # derived units last
    st = P.structure
    what = f"system {st.name}: {P.description or st.name} ({st.n_thrusters} thrusters, {st.n_joints} joints)"
    desc = (f"{what}, exactly coupled (arvcas uvms_rhs, "
            f"docs/model.md); inputs: {'body wrench tau' if inputs == 'wrench' else 'thruster commands u'}, "
            "q, qd, qdd, payload")
    return render("fmu/modelDescription.xml.j2", {
        "guid": guid, "description": desc, "version": __version__, "wrapper_c": _WRAPPER_C,
        "stamp": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "model_identifier": MODEL_IDENTIFIER,
        "units": [{"name": u, "base": bases[u], "display": _DISPLAY.get(u)} for u in used],
        "variables": [{**dict.fromkeys(_KEYS), **v} for v in V], "deps": deps}, FMUError)


# ---------------------------------------------------------------------------------------------
# C


def _rhs_function(opts, inputs: str, P) -> ca.Function:
    from arvcas.model.uvms import plant_functions

    fns = plant_functions(opts, P.layout)  # sized by the system
    f = fns["uvms_rhs"]
    if inputs == "wrench":
        return f
    nt, nj = P.structure.n_thrusters, P.structure.n_joints
    x, u, pl = ca.SX.sym("x", 12), ca.SX.sym("u", nt), ca.SX.sym("payload", 1)
    q, qd, qdd = ca.SX.sym("q", nj), ca.SX.sym("qd", nj), ca.SX.sym("qdd", nj)
    p = ca.SX.sym("p", f.size1_in(6))
    tau = fns["thrust"](u, p)
    return ca.Function("uvms_rhs_u", [x, u, q, qd, qdd, pl, p], [f(x, tau, q, qd, qdd, pl, p)],
                       ["x", "u", "q", "qd", "qdd", "payload", "p"], ["xdot"])


def _check_tables(V: list[dict], lay: dict, P) -> str:
    """C tables for the wrapper's checks: every variable's name (C string literals made by
    :func:`arvcas.build.text.c_string`), each parameter's sign rule (the loader's: 0 any, 1 >= 0, 2 > 0),
    the pairs that must be ordered (``u_min < u_max``, ``qmin < qmax``) and the stow angles within their
    joint's limits, as value references."""
    from arvcas.build.text import c_string
    from arvcas.model.thrusters import limit_prefixes

    vr = {v["name"]: i for i, v in enumerate(V)}
    rules = {"any": 0, "nonneg": 1, "pos": 2}
    order = [(vr[p + "u_min"], vr[p + "u_max"]) for p in limit_prefixes(P.structure)]
    within = []
    for j in range(1, P.structure.n_joints + 1):
        order.append((vr[f"arm.joint{j}.qmin"], vr[f"arm.joint{j}.qmax"]))
        within.append((vr[f"arm.joint{j}.qmin"], vr[f"arm.stow.q{j}"], vr[f"arm.joint{j}.qmax"]))
    lines = ["static const char *const VNAME[NVR] = {"]
    lines += [f"    {c_string(v['name'])}," for v in V]
    lines += ["};", "static const signed char PRULE[NP] = {"]
    lines += ["    " + ", ".join(str(rules[r]) for r in P.layout.rules[k:k + 32]) + "," for k in range(0, len(P), 32)]
    lines += ["};", f"#define NORDER {len(order)}", f"#define NWITHIN {len(within)}",
              "static const int PORDER[NORDER + 1][2] = {" + "".join(f"{{{a}, {b}}}, " for a, b in order) + "{-1, -1}};",
              "static const int PWITHIN[NWITHIN + 1][3] = {" + "".join(f"{{{a}, {b}, {c}}}, " for a, b, c in within)
              + "{-1, -1, -1}};"]
    return "\n".join(lines)


def _c_double(v: float) -> str:
    v = float(v)
    if not math.isfinite(v):
        raise FMUError(f"params: every start value must be finite, got {v}")
    return f"{v:.17g}"


def _templates() -> Path:
    return Path(str(resources.files("arvcas") / "build" / "templates"))


def _platform() -> tuple[str, str]:
    """(FMI 2.0 platform folder, shared library suffix) of this machine."""
    bits64 = sys.maxsize > 2**32
    if sys.platform.startswith("linux"):
        return ("linux64" if bits64 else "linux32"), ".so"
    if sys.platform == "darwin":
        return "darwin64", ".dylib"
    raise FMUError(f"export-fmu: platform {sys.platform} is not supported (Linux and macOS build the binary)")


def _compile(src_dir: Path, out: Path) -> None:
    from arvcas.build import codegen

    flags = [*codegen.BASE_FLAGS, codegen.DEFAULT_OPT_LEVEL, *codegen.FIXED_FLAGS, "-fvisibility=hidden"]
    cmd = [codegen.CC, *flags, f"-I{src_dir}", "-o", str(out), str(src_dir / _WRAPPER_C), *codegen.LIBS]
    r = codegen.run_compiler(cmd, src_dir, "the FMU")  # killed with its process group if interrupted
    if r.returncode != 0:
        first = next((ln for ln in r.stderr.splitlines() if "error" in ln), r.stderr.strip()[:200])
        raise codegen.CompileError(f"{codegen.CC} failed compiling the FMU (exit {r.returncode}): {first.strip()}")


# ---------------------------------------------------------------------------------------------
# the output file


KIND = "fmu"  # the kind of the file in the directory's manifest (arvcas.util.files)


def _refuse_replacing(p: Path) -> None:
    """The output policy of :mod:`arvcas.util.files` for an existing ``p``, by the directory's manifest
    (never by what the file claims inside, so a foreign file is not even opened)."""
    kind = files.kind_of(p)
    if kind is None:
        raise FMUError(f"path: {p} exists and is not an FMU written by arvcas; pass force=True (--force) to replace it")
    if kind and kind != KIND:
        raise FMUError(f"path: {p} is an arvcas file of another kind ({kind}); pass force=True (--force) to replace it")


def _check_path(path, force: bool) -> Path:
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise FMUError(f"path: expected a file name ending in .fmu, got {path!r}")
    p = Path(os.path.abspath(Path(path).expanduser()))
    if p.suffix.lower() != ".fmu":
        raise FMUError(f"path: the file name must end in .fmu, got {p.name!r}")
    if not p.parent.is_dir():
        raise FMUError(f"path: directory {p.parent} does not exist")
    if not os.access(p.parent, os.W_OK | os.X_OK):
        raise FMUError(f"path: directory {p.parent} is not writable")
    if p.exists() or p.is_symlink():
        if p.is_symlink() and not force:
            raise FMUError(f"path: {p} is a symbolic link; pass force=True (--force) to replace the link")
        if p.is_dir() or (p.exists() and not p.is_file()):
            raise FMUError(f"path: {p} exists and is not a regular file")
        if not force:
            _refuse_replacing(p)
    return p


def export_fmu(path, system=None, opts=None, force: bool = False, inputs: str = "wrench", *, params=UNSET) -> Path:
    """Write an FMI 2.0 FMU (Model Exchange and Co-Simulation) of the coupled vehicle + arm to ``path``.

    ``path`` must end in ``.fmu``; an existing file is replaced only if arvcas recorded it as an FMU it
    wrote (the directory's manifest, :mod:`arvcas.util.files`; nothing inside the file is trusted), or
    with ``force=True``. ``system`` (its :class:`arvcas.system.params.Params` or :class:`arvcas.system.System`,
    a system file, or None for the default system; ``params=``: its old name) sizes the FMU (:func:`layout`)
    and sets the parameters' start values; every one stays settable in the FMU. ``opts`` is
    an :class:`arvcas.model.uvms.ModelOptions` (n_quad of the link drag). ``inputs``: ``"wrench"``
    (the body wrench ``tau``, 6) or ``"thrusters"`` (the n_thrusters thrust commands ``u``, realised as
    ``B_T sat(u)``). Returns the absolute path written. Raises :class:`FMUError` for bad arguments,
    :class:`arvcas.build.codegen.CompileError` if the C compiler fails.
    """
    from arvcas.build import codegen
    from arvcas.model.uvms import ModelOptions

    if not isinstance(force, bool):
        raise FMUError(f"force: expected True or False, got {force!r}")
    _check_inputs(inputs)
    opts = ModelOptions.checked(opts, error=FMUError)
    P = _check_params(renamed_system(system, params, "export_fmu"))
    out = _check_path(path, force)
    platform, suffix = _platform()

    V = variables(P, inputs)
    lay = layout(P, inputs)
    fn = _rhs_function(opts, inputs, P)
    deps = _dependencies(fn)
    cg = ca.CodeGenerator(_MODEL_C[:-2], dict(codegen._CODEGEN_OPTS))
    cg.add(fn)
    model_c = cg.dump()

    start = ",\n".join("    " + _c_double(v["start"] if v["start"] is not None else 0.0) for v in V)
    checks = _check_tables(V, lay, P)
    # the GUID: a digest of everything that defines the FMU's interface and behaviour
    h = hashlib.sha256()
    for part in (model_c, start, repr([(v["name"], v["unit"]) for v in V]), inputs, checks):
        h.update(part.encode())
        h.update(b"\0")
    guid = "{" + str(uuid.UUID(bytes=h.digest()[:16])) + "}"
    assert len(V) - lay["vr_p"] == len(P) and fn.nnz_in() == 12 + lay["n_u"] + len(P)
    wrapper = render("fmu/wrapper.c.j2", {
        "model_c": _MODEL_C, "np": len(V) - lay["vr_p"], "guid": guid, "rhs": fn.name(), "start": start,
        "input": "tau" if inputs == "wrench" else "u", "nu": lay["n_u"], "nin": lay["n_in"], "nj": lay["n_joints"],
        "vr_h": lay["vr_h"], "vr_p": lay["vr_p"], "u_q": lay["q"], "u_qd": lay["qd"], "u_qdd": lay["qdd"],
        "u_payload": lay["payload"], "checks": checks}, FMUError)
    md = _model_description(V, deps, guid, inputs, P)

    files.remove_stale_temps(out.parent)  # those of killed exports (and of every other writer)
    work = files.temp_dir(out)
    try:
        src = work / "sources"
        src.mkdir()
        (src / _MODEL_C).write_text(model_c, encoding="utf-8")
        (src / _WRAPPER_C).write_text(wrapper, encoding="utf-8")
        for hdr in _HEADERS:
            shutil.copyfile(_templates() / "fmi2" / hdr, src / hdr)
        binary = work / f"{MODEL_IDENTIFIER}{suffix}"
        _compile(src, binary)
        def fill(tmp: Path) -> None:
            with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
                zf.writestr("modelDescription.xml", md)
                zf.write(binary, f"binaries/{platform}/{MODEL_IDENTIFIER}{suffix}")
                for f in sorted(src.iterdir()):
                    zf.write(f, f"sources/{f.name}")
                # the FMI headers' 2-clause BSD notice, which a binary built from them must carry (the
                # standard's place for licences)
                zf.write(_templates() / "fmi2" / "LICENSE.txt", "documentation/licenses/fmi2-headers.txt")

        if out.exists() and not force:  # appeared meanwhile
            _refuse_replacing(out)
        if os.path.lexists(out):  # checked above: an FMU arvcas wrote, or force
            files.permit_replace([out])
        files.atomic_write(out, fill, FMUError, KIND)  # the one writer: recorded in the directory's manifest
    finally:
        files.release_temp(work)
    return out
