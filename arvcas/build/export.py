"""``arvcas export-c DIR``: the plant functions and their Jacobians as a C library to link into other programs.

DIR receives sources only (nothing here runs a compiler; :mod:`arvcas.build.codegen` does that for
arvcas itself):

* ``<lib>.c``: CasADi's generated code of the seven functions (:data:`arvcas.build.dynamics.NAMES`),
  renamed ``<prefix><name>`` (default prefix ``arvcas_<system>_``: :data:`DEFAULT_PREFIX` for the default system); CasADi's
  helpers are prefixed too, so every global symbol of the library starts with the prefix and two
  exports (of one system or of two) link into one program.
* ``<lib>.h``: the documented header: per function the order, size, unit and frame of every argument
  (sized by the system: ``q[n_joints]``, ``u[n_thrusters]``, ``p[n_params]``),
  the work array sizes, every prototype, and an ``<prefix><name>_eval`` wrapper with named arguments
  and work arrays on the stack; the calling convention and thread safety at the top.
* ``<lib>_params.h``: the system's default parameter vector ``p`` with name, index and SI unit of each
  entry (the units from the system's layout, :mod:`arvcas.build.units`).
* ``Makefile`` and ``CMakeLists.txt`` (with an installable CMake package config), both compiling
  with the flags of the build cache (:data:`arvcas.build.codegen.BASE_FLAGS`, ``DEFAULT_OPT_LEVEL``,
  ``FIXED_FLAGS``, ``LIBS``), so the library gives the numbers arvcas gives.
* examples in C (``example.c``), C++ (``example.cpp``, also built by ``consumer/CMakeLists.txt``
  through ``find_package``) and Python ctypes (``example.py``), printing the same lines.
* ``README.md`` and ``arvcas-export.json``, the manifest: every file written with its sha256.

The one output policy of :mod:`arvcas.util.files` decides what may be replaced: a file in DIR is only
replaced if the directory's ``.arvcas-manifest.json`` records it as written by export-c with its
current sha256 (arvcas wrote it, as an export, and nobody changed it since); anything else is refused
with a one-line :class:`ExportError` unless ``force``. ``consumer/`` is never a symbolic link (refused
even with ``force``: nothing is written out of DIR).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas.build.templating import ident, render
from arvcas.build.text import build_word, c_comment, c_comment_lines
from arvcas.system.loader import UNSET, renamed_system
from arvcas.system.params import DEFAULT

__all__ = ["ExportError", "export_c", "example_inputs", "files", "default_prefix", "MANIFEST", "DEFAULT_PREFIX",
           "check_out_dir", "check_prefix", "check_replaceable", "write_package", "KIND"]

DEFAULT_PREFIX = f"arvcas_{DEFAULT}_"  # the default system's: default_prefix(DEFAULT)
MANIFEST = "arvcas-export.json"
MANIFEST_FORMAT = 1

_DEG = math.pi / 180.0

# What each input/output name means (units SI, frames as in the model docstrings). Order and sizes
# come from the Function objects; this only annotates names.
_GLOSSARY = {
    "x": "state [eta; nu]: eta = [x, y, z, phi, theta, psi] (m, rad; NED position of the COB and ZYX Euler "
    "angles), nu = [u, v, w, p, q, r] (m/s, rad/s; body velocity in {b})",
    "xdot": "d/dt of x: [J(eta) nu; nu_dot] (m/s, rad/s; m/s^2, rad/s^2)",
    "tau": "body wrench at the COB in {b}: [X, Y, Z (N); K, M, N (N m)]",
    "eta": "pose [x, y, z, phi, theta, psi] (m, rad; NED, ZYX Euler angles)",
    "nu": "body velocity [u, v, w, p, q, r] in {b} (m/s, rad/s)",
    "nud": "nu_dot, time derivative of nu's components (m/s^2, rad/s^2)",
    "q": "joint angles q1..q6 (rad)",
    "qd": "joint rates (rad/s)",
    "qdd": "joint accelerations (rad/s^2)",
    "payload": "payload fraction in [0, 1]: scales payload.mass and payload.volume at the tool point",
    "p": "parameter vector, SI units; order, names and defaults in the _params.h header",
    "tau_m": "wrench of the arm on the vehicle in {b} about the COB: [Fx, Fy, Fz (N); Mx, My, Mz (N m)]",
    "dxdot_dx": "d xdot / d x, 12 x 12, column-major: d xdot_i / d x_j at [i + 12 j]",
    "dxdot_dtau": "d xdot / d tau, 12 x 6, column-major: d xdot_i / d tau_j at [i + 12 j]",
    "dxdot_dq": "d xdot / d q, 12 x 6, column-major: d xdot_i / d q_j at [i + 12 j]",
}


def _glossary(P) -> dict[str, str]:
    """:data:`_GLOSSARY` for the system of ``P``: joint and thruster counts and the thrusters' names."""
    st = P.structure
    g = dict(_GLOSSARY)
    nj = st.n_joints
    g["q"] = f"joint angles q1..q{nj} (rad)" if nj > 1 else ("joint angle q1 (rad)" if nj else "no joints (empty)")
    g["u"] = f"thrust per thruster (N): {', '.join(st.thruster_names())}"
    g["dxdot_dq"] = f"d xdot / d q, 12 x {nj}, column-major: d xdot_i / d q_j at [i + 12 j]"
    return g


def default_prefix(system=None) -> str:
    """``arvcas_<system name>_``, the default symbol prefix of a system's export (:data:`DEFAULT_PREFIX`).

    ``system``: anything :func:`arvcas.system.resolve` takes (a name, a file, a System, a Params).
    Characters of the name that cannot be in a C identifier become ``_``.
    """
    from arvcas.system import resolve

    name = resolve(system).name
    ident = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9]", "_", name)).strip("_")
    return f"arvcas_{ident}_" if ident else "arvcas_"

# one line per function, from the docstrings of arvcas.model (vehicle.rhs, manipulator.arm_wrench,
# uvms.uvms_xdot, thrusters.allocate, thrusters.thrust)
_SUMMARY = {
    "vehicle_rhs": "The vehicle alone (paper eq. 1): x = [eta; nu], tau the total body wrench at the COB -> xdot.",
    "arm_wrench": "tau_m of paper eq. 11: the arm's wrench on the vehicle in {b} about the COB, given the vehicle's "
    "pose, velocity and acceleration and the joints' motion.",
    "uvms_rhs": "The exactly coupled vehicle + arm: xdot = [J(eta) nu; nu_dot], with the trim buoyancy at the "
    "initial arm configuration.",
    "allocate": "u = B_T^-1 tau (paper eq. 2): thrust per thruster for the body wrench tau, before saturation.",
    "thrust": "The realised body wrench B_T sat(u) of the thrusts u (saturated at the thrusters' limits).",
    "vehicle_rhs_jac": "vehicle_rhs and its exact Jacobians (algorithmic differentiation) with respect to x and tau.",
    "uvms_rhs_jac": "uvms_rhs and its exact Jacobians (algorithmic differentiation) with respect to x, tau and q.",
}


class ExportError(ValueError):
    """The output directory cannot be used, or a file there is not arvcas's to replace (one line)."""


def _cycled(values, n: int) -> np.ndarray:
    return np.array([values[i % len(values)] for i in range(n)], dtype=float)


def example_inputs(system=None) -> dict[str, np.ndarray]:
    """The fixed state of the examples, by input name (SI units; ``p`` is the default vector).

    ``system`` (default: the default system; anything :func:`arvcas.system.resolve` takes) sizes ``q``,
    ``qd``, ``qdd`` (n_joints) and ``u`` (n_thrusters): six values each, repeated or cut.
    """
    from arvcas.system import resolve

    st = resolve(system).structure
    inputs = _six_inputs()
    for k in ("q", "qd", "qdd"):
        inputs[k] = _cycled(inputs[k], st.n_joints)
    inputs["u"] = _cycled(inputs["u"], st.n_thrusters)
    return inputs


def _six_inputs() -> dict[str, np.ndarray]:
    """The examples' state, six values per joint and thruster vector (Haidou-1's sizes, where they were chosen)."""
    eta = [1.0, -0.5, 2.0, 0.05, -0.03, 0.2]
    nu = [0.3, 0.05, -0.02, 0.01, 0.02, -0.03]
    return {
        "x": np.array(eta + nu),
        "eta": np.array(eta),
        "nu": np.array(nu),
        "nud": np.array([0.01, 0.0, -0.02, 0.0, 0.001, 0.0]),
        "tau": np.array([20.0, -5.0, 10.0, 1.0, -2.0, 3.0]),
        "q": np.array([75.0, 70.0, -80.0, 10.0, 60.0, -20.0]) * _DEG,
        "qd": np.array([0.1, -0.05, 0.08, 0.0, 0.02, -0.1]),
        "qdd": np.array([0.01, 0.02, -0.01, 0.0, 0.005, 0.0]),
        "payload": np.array([0.5]),
        # 250 > u_max and -200 < u_min: thrust() shows the saturation
        "u": np.array([100.0, -50.0, 20.0, -30.0, 250.0, -200.0]),
    }


def files(prefix: str = DEFAULT_PREFIX) -> tuple[str, ...]:
    """The files :func:`export_c` writes (relative to DIR), the manifest last."""
    lib = prefix.rstrip("_")
    return (f"{lib}.c", f"{lib}.h", f"{lib}_params.h", "example.c", "example.cpp", "example.py", "Makefile",
            "CMakeLists.txt", "consumer/CMakeLists.txt", "README.md", MANIFEST)


# ---------------------------------------------------------------------------------------------
# directory and manifest


def check_out_dir(out_dir, what: str = "export-c") -> Path:
    """The absolute output directory of an export (``what``: the command, in messages); it may not
    exist yet if its parent does."""
    out = Path(os.path.abspath(Path(out_dir).expanduser()))
    if out.exists():
        if not out.is_dir():
            raise ExportError(f"{what}: {out} exists and is not a directory")
        if not os.access(out, os.W_OK | os.X_OK):
            raise ExportError(f"{what}: directory {out} is not writable")
        return out
    parent = out.parent
    if not parent.is_dir():
        raise ExportError(f"{what}: parent directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ExportError(f"{what}: cannot create {out}: {parent} is not writable")
    return out


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


KIND = "export-c"  # the kind of every file export-c writes (arvcas.util.files); an export's kind is its command


def _write(out: Path, name: str, data: bytes, kind: str = KIND) -> None:
    """Through the one atomic writer (:mod:`arvcas.util.files`), which applies the output policy again
    (and :func:`check_replaceable`'s --force permissions); a subdirectory is never a symbolic link."""
    from arvcas.util import files

    path = out / name
    if path.parent != out:
        files.subdir(out, path.parent.relative_to(out).as_posix(), ExportError)
    files.atomic_write(path, lambda tmp: tmp.write_bytes(data), ExportError, kind)


# ---------------------------------------------------------------------------------------------
# C helpers


def _render(template: str, values: dict) -> str:
    return render(template, values, ExportError)


def params_header(P, opts, prefix: str, title: str = "Default parameter vector p of the arvcas plant functions, SI units.",
                  use: str = "Every function takes p as its last input; change an entry to change the model, no rebuild.",
                  gains: dict | None = None) -> str:
    """``<lib>_params.h`` (``templates/params.h.j2``): the default ``p`` with an index macro, name and SI
    unit per entry; ``gains``: an exported controller's gain indices (its law, the gains' source, the
    library, the gains' (name, unit)); ``opts`` None: no model options line."""
    from arvcas._version import __version__
    from arvcas.build.units import si_unit

    up = prefix.upper()
    names = P.names()
    macros = [f"{up}P_{ident(n)}" for n in names]
    if len(set(macros)) != len(macros):  # e.g. two names differing only in case
        dup = next(m for m in macros if macros.count(m) > 1)
        raise ExportError(f"export-c: parameter names collide as C macro {dup}")
    rows = []
    for n, m, v in zip(names, macros, P.vector()):
        si, file_unit = si_unit(P, n), P.unit(n)  # the SI unit from the system's layout
        rows.append({"name": n, "macro": m, "value": v, "unit": si if file_unit in (si, "SI") else f"{si} (file: {file_unit})"})
    return _render("params.h.j2", {
        "title": title, "use": use, "version": __version__, "casadi_version": ca.__version__, "path": P.path,
        "opts": opts, "up": up, "prefix": prefix, "rows": rows, "width": max(len(c_comment(n)) for n in names),
        "gains": gains})



_EXPORT_RE = re.compile(r"^CASADI_SYMBOL_EXPORT ([^{]+?)\s*\{", re.M)


def _exported(c_text: str) -> list[tuple[str, str]]:
    """(symbol, declaration) of every exported function of CasADi's generated C, in order."""
    return [(re.search(r"(\w+)\(", sig).group(1), " ".join(sig.split()) + ";") for sig in _EXPORT_RE.findall(c_text)]


def _owner(symbol: str, full_names) -> str | None:
    """The function a symbol belongs to: the longest name it equals or extends by a CasADi suffix."""
    cands = [f for f in full_names if symbol == f or (symbol.startswith(f + "_") and symbol[len(f) + 1:] in _SUFFIXES)]
    return max(cands, key=len) if cands else None


_SUFFIXES = {"checkout", "release", "incref", "decref", "n_in", "n_out", "default_in", "name_in", "name_out",
             "sparsity_in", "sparsity_out", "work", "work_bytes", "alloc_mem", "init_mem", "free_mem"}


def _prototypes(c_text: str, fname: str, full_names) -> list[str]:
    """The exported prototypes of function ``fname`` in CasADi's generated C, as declarations."""
    return [decl for sym, decl in _exported(c_text) if _owner(sym, full_names) == fname]


def _work_sizes(c_text: str, fname: str) -> dict[str, int]:
    m = re.search(rf"int {fname}_work\(casadi_int \*sz_arg.*?\{{(.*?)return 0;", c_text, flags=re.S)
    if not m:
        raise ExportError(f"export-c: {fname}_work not found in CasADi's generated code")
    sizes = dict(re.findall(r"if \((sz_\w+)\) \*\1 = (\d+);", m.group(1)))
    if set(sizes) != {"sz_arg", "sz_res", "sz_iw", "sz_w"}:
        raise ExportError(f"export-c: unexpected {fname}_work in CasADi's generated code")
    return {k: int(v) for k, v in sizes.items()}


def _check_reentrant(c_text: str, full_names: list[str]) -> None:
    """The header promises reentrancy: no writable static or global data, no-op memory management."""
    for line in c_text.splitlines():
        if re.match(r"^(static\s+)?(casadi_real|casadi_int|int|double|char)\b[^()]*(=|;)\s*", line) and \
                not line.startswith("static const"):
            raise ExportError(f"export-c: CasADi's generated code has writable global data ({line.strip()[:60]})")
    for f in full_names:
        m = re.search(rf"int {f}_checkout\(void\) \{{\s*return 0;\s*\}}", c_text)
        r = re.search(rf"void {f}_release\(int mem\) \{{\s*\}}", c_text)
        if not (m and r):
            raise ExportError(f"export-c: {f}_checkout/_release manage memory: the header's thread-safety note would be wrong")


# ---------------------------------------------------------------------------------------------
# the header


def _arg_rows(f: ca.Function, glossary: dict[str, str]) -> list[dict]:
    """Every input and output: kind, index, slot (``arg[i]``, ``res[i]``), name, size, shape and meaning."""
    rows = []
    for kind, n, name, size in (("in", f.n_in(), f.name_in, f.size_in), ("out", f.n_out(), f.name_out, f.size_out)):
        for i in range(n):
            sh = size(i)
            rows.append({"kind": kind, "index": i, "slot": f"{'arg' if kind == 'in' else 'res'}[{i}]", "name": name(i),
                         "size": str(sh[0]) if sh[1] == 1 else f"{sh[0]}x{sh[1]}", "shape": f"{sh[0]}x{sh[1]}",
                         "meaning": glossary.get(name(i), "")})
    return rows


def _values(fns: dict[str, ca.Function], c_text: str, prefix: str, opts, P, inputs) -> dict:
    """Everything the templates of ``templates/export/`` need."""
    from arvcas._version import __version__

    st = P.structure
    gl = _glossary(P)
    full_names = [prefix + n for n in fns]
    library_decls = []  # what CasADi exports that belongs to no function: its version and sizes
    for sym, decl in _exported(c_text):
        if _owner(sym, full_names) is None:
            if not sym.startswith(prefix):
                raise ExportError(f"export-c: CasADi's generated code exports {sym}, without the prefix {prefix}")
            library_decls.append(decl)
    functions = []
    for short, f in fns.items():
        full = prefix + short
        rows = _arg_rows(f, gl)
        functions.append({"short": short, "full": full, "summary": _SUMMARY[short], "rows": rows,
                          "width": max(len(r["name"]) for r in rows), "work": _work_sizes(c_text, full),
                          "prototypes": _prototypes(c_text, full, full_names), "ins": f.name_in(),
                          "outs": [(f.name_out(i), f.numel_out(i)) for i in range(f.n_out())]})
    return {"lib": prefix.rstrip("_"), "guard": f"{prefix.rstrip('_').upper()}_H", "prefix": prefix,
            "version": __version__, "casadi_version": ca.__version__, "opts": opts, "path": P.path,
            "system": st.name, "description": P.description or st.name,
            "description_lines": c_comment_lines(P.description) if P.description else [],
            "n_thrusters": st.n_thrusters, "n_joints": st.n_joints, "arm": st.arm, "n_p": len(P),
            "library_decls": library_decls, "functions": functions, "inputs": inputs, "manifest": MANIFEST,
            "p_default": [float(x) for x in P.vector()], "inputs_py": {k: [float(x) for x in v] for k, v in inputs.items()},
            "functions_py": {f["short"]: (list(f["ins"]), f["outs"]) for f in functions}}


# ---------------------------------------------------------------------------------------------
# examples (all three print the same lines: "in|out <function> <name> : values", %.17g)


def _example_values(fns: dict[str, ca.Function], inputs: dict[str, np.ndarray]) -> None:
    for short, f in fns.items():
        for i, k in enumerate(f.name_in()):
            if k == "p":
                if i != f.n_in() - 1:
                    raise ExportError(f"export-c: {short}: p must be the last input")
            elif k not in inputs or inputs[k].size != f.numel_in(i):
                raise ExportError(f"export-c: {short}: no example value of size {f.numel_in(i)} for input {k}")


# ---------------------------------------------------------------------------------------------
# build files


def _word(word: str, what: str) -> str:
    """``word`` for a Makefile or CMake file: one plain word (:func:`arvcas.build.text.build_word`)."""
    try:
        return build_word(word, what)
    except ValueError as e:
        raise ExportError(f"export-c: {e}") from None


def _flags():
    """(library flags, compile flags, libraries) of the build cache, read from arvcas.build.codegen;
    every one a plain word."""
    from arvcas.build import codegen

    flags = list(codegen.BASE_FLAGS), [codegen.DEFAULT_OPT_LEVEL, *codegen.FIXED_FLAGS], list(codegen.LIBS)
    return tuple([_word(f, "compiler flag") for f in group] for group in flags)


def _lib(prefix: str) -> str:
    """The library's name (the prefix without its last ``_``), a plain word for the build files."""
    return _word(prefix.rstrip("_"), "prefix")


def build_files(prefix: str) -> dict[str, str]:
    """The build files of an export (``templates/export/``): ``Makefile``, ``CMakeLists.txt`` and
    ``consumer/CMakeLists.txt``, compiling with the flags of the build cache."""
    lib = _lib(prefix)
    base, cflags, libs = _flags()
    v = {"lib": lib, "base": base, "cflags": cflags, "libs": libs, "pic": [f for f in base if f != "-shared"],
         "options": cflags + [f for f in base if f not in ("-shared", "-fPIC")],
         "link": [lib_.removeprefix("-l") for lib_ in libs]}
    return {"Makefile": _render("export/Makefile.j2", v), "CMakeLists.txt": _render("export/CMakeLists.txt.j2", v),
            "consumer/CMakeLists.txt": _render("export/consumer.CMakeLists.txt.j2", v)}

# ---------------------------------------------------------------------------------------------


def export_c(out_dir, opts=None, system=None, *, prefix: str | None = None, force: bool = False,
             params=UNSET) -> list[Path]:
    """Write the C library, headers, build files, examples and README into ``out_dir``.

    ``opts``: :class:`arvcas.model.uvms.ModelOptions` (default ``ModelOptions()``); ``system``: a
    :class:`arvcas.system.params.Params` (or a :class:`arvcas.system.System`; ``params=``, its old name, still
    works): its layout sizes the functions (``q[n_joints]``, ``u[n_thrusters]``, ``p[n_params]``) and its
    numbers are the defaults in ``<lib>_params.h`` (default: the default system); ``prefix``: of every symbol (a C identifier ending in
    ``_``; the library is ``lib<prefix without the last _>.so``; default :func:`default_prefix`,
    ``arvcas_<system>_``). ``out_dir`` is created if its parent exists. A file there
    that the manifest does not list with its current sha256 is refused unless ``force``. Returns the
    written paths, in :func:`files` order. Raises :class:`ExportError` (a ValueError).
    """
    from arvcas.build.dynamics import jacobian_functions
    from arvcas.model.uvms import PUBLIC_FUNCTIONS, ModelOptions, plant_functions
    from arvcas.system.params import Params, load
    from arvcas.system import System

    params = renamed_system(system, params, "export_c")
    P = load() if params is None else params
    if isinstance(P, System):
        P = P.params
    if not isinstance(P, Params):
        raise ExportError(f"export-c: params must be arvcas.system.params.Params, got {type(P).__name__}")
    prefix = check_prefix(default_prefix(P) if prefix is None else prefix, DEFAULT_PREFIX)
    if not isinstance(force, bool):
        raise ExportError(f"export-c: force: expected True or False, got {force!r}")
    out = check_out_dir(out_dir)
    opts = ModelOptions() if opts is None else opts
    if not isinstance(opts, ModelOptions):
        raise ExportError(f"export-c: opts must be arvcas.model.uvms.ModelOptions, got {type(opts).__name__}")
    names = files(prefix)
    check_replaceable(out, names, force, "export-c")

    plant = plant_functions(opts, P.layout)  # sized by the system
    fns = {n: plant[n] for n in PUBLIC_FUNCTIONS}
    fns.update(jacobian_functions(plant))
    inputs = example_inputs(P)
    _example_values(fns, inputs)
    lib = prefix.rstrip("_")
    cg = ca.CodeGenerator(lib, {"with_header": False, "casadi_real": "double", "casadi_int": "long long int"})
    for short, f in fns.items():  # renamed: the symbols carry the prefix
        sym = f.sx_in()
        cg.add(ca.Function(prefix + short, sym, f.call(sym), f.name_in(), f.name_out()))
    c_text = cg.dump()
    _check_reentrant(c_text, [prefix + s for s in fns])

    v = _values(fns, c_text, prefix, opts, P, inputs)
    texts = {
        f"{lib}.c": c_text,
        f"{lib}.h": _render("export/plant.h.j2", v),
        f"{lib}_params.h": params_header(P, opts, prefix),
        "example.c": _render("export/example.c.j2", v),
        "example.cpp": _render("export/example.cpp.j2", v),
        "example.py": _render("export/example.py.j2", v),
        **build_files(prefix),
        "README.md": _render("export/README.md.j2", v),
    }
    assert tuple(texts) + (MANIFEST,) == names
    return write_package(out, texts, prefix, "export-c")


def check_prefix(prefix, example: str, what: str = "export-c") -> str:
    """``prefix`` if it is a C identifier ending in one ``_``; else a one-line :class:`ExportError`."""
    if not isinstance(prefix, str) or not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*_", prefix) or "__" in prefix:
        raise ExportError(f"{what}: prefix: expected a C identifier ending in one '_' (like {example}), got {prefix!r}")
    return prefix


def write_package(out: Path, texts: dict[str, str], prefix: str, what: str) -> list[Path]:
    """Write an export's files (name -> text) into ``out`` (created if missing), each through the
    atomic writer, then the manifest listing them with their sha256 (last, so it lists only finished
    files). The caller has checked the directory (:func:`check_out_dir`) and that every file may be
    replaced (:func:`check_replaceable`). Returns the paths, the manifest last."""
    from arvcas._version import __version__

    out.mkdir(exist_ok=True)
    written = {}
    for name, text in texts.items():
        data = text.encode("utf-8")
        _write(out, name, data, what)
        written[name] = _sha256(data)
    m = {"format": MANIFEST_FORMAT, "written_by": f"arvcas {__version__} {what}", "prefix": prefix,
         "files": written}
    _write(out, MANIFEST, (json.dumps(m, indent=1) + "\n").encode("utf-8"), what)  # last: lists only finished files
    return [out / n for n in (*texts, MANIFEST)]


def check_replaceable(out: Path, names, force: bool, what: str) -> None:
    """The one output policy (:func:`arvcas.util.files.check_outputs`, kind ``what``: the export's command):
    a file in ``out`` is replaced only if that export wrote it and nobody changed it since (the
    directory's manifest), or with ``force``; a subdirectory that is a symbolic link is refused even
    with ``force``. One line, naming the file."""
    from arvcas.util import files as _files

    if out.exists():
        _files.check_outputs([(f"{what}: DIR {out}", out / n, what, out) for n in names], force=force,
                             error=ExportError)
