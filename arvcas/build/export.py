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

The one output policy of :mod:`arvcas.io.files` decides what may be replaced: a file in DIR is only
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
from importlib import resources
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas.build.text import build_word, c_comment, c_comment_lines, c_string, markdown
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


KIND = "export-c"  # the kind of every file export-c writes (arvcas.io.files); an export's kind is its command


def _write(out: Path, name: str, data: bytes, kind: str = KIND) -> None:
    """Through the one atomic writer (:mod:`arvcas.io.files`), which applies the output policy again
    (and :func:`check_replaceable`'s --force permissions); a subdirectory is never a symbolic link."""
    from arvcas.io import files

    path = out / name
    if path.parent != out:
        files.subdir(out, path.parent.relative_to(out).as_posix(), ExportError)
    files.atomic_write(path, lambda tmp: tmp.write_bytes(data), ExportError, kind)


# ---------------------------------------------------------------------------------------------
# C helpers


def _c_double(v: float) -> str:
    v = float(v)
    if not math.isfinite(v):
        raise ExportError(f"export-c: cannot write the non-finite value {v} as a C literal")
    r = repr(v)  # the shortest string that round-trips, so the C literal is the same double
    return r if ("." in r or "e" in r) else r + ".0"


def _ident(name: str) -> str:
    return "".join(c if c.isascii() and c.isalnum() else "_" for c in name).upper()


def _params_header(P, opts, prefix: str, title: str = "Default parameter vector p of the arvcas plant functions, SI units.",
                   use: str = "Every function takes p as its last input; change an entry to change the model, no rebuild.",
                   extra=()) -> str:
    """``<lib>_params.h``: the default ``p`` with an index macro, name and SI unit per entry; ``extra``:
    further lines before the end (other defaults of an export); ``opts`` None: no model options line."""
    from arvcas._version import __version__
    from arvcas.build.units import si_unit

    up = prefix.upper()
    names = P.names()
    values = P.vector()
    macros = [f"{up}P_{_ident(n)}" for n in names]
    if len(set(macros)) != len(macros):  # e.g. two names differing only in case
        dup = next(m for m in macros if macros.count(m) > 1)
        raise ExportError(f"export-c: parameter names collide as C macro {dup}")
    shown = [c_comment(n) for n in names]
    width = max(len(n) for n in shown)
    guard = f"{up}PARAMS_H"
    lines = [
        f"/* {c_comment(title)}",
        f" * Generated by arvcas {__version__} (CasADi {ca.__version__}) from {c_comment(P.path)}",
        *([] if opts is None else [f" * Model options: {c_comment(repr(opts))} (tag {c_comment(opts.tag())})."]),
        f" * {c_comment(use)}",
        " */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        f"#define {up}NP {len(names)}",
        "",
        "/* index of each parameter in p */",
    ]
    for i, m in enumerate(macros):
        lines.append(f"#define {m} {i}")
    lines += ["", f"static const double {prefix}p_default[{up}NP] = {{"]
    lines.append("  /* value, then [index] name, SI unit (and the unit the parameter file uses, if another) */")
    for i, n in enumerate(names):
        si = si_unit(P, n)  # from the system's layout
        file_unit = P.unit(n)
        unit = si if file_unit in (si, "SI") else f"{si} (file: {file_unit})"
        lines.append(f"  {_c_double(values[i]) + ',':<24} /* [{i:3d}] {shown[i]:<{width}}  {c_comment(unit)} */")
    lines += ["};", *extra, "", f"#endif /* {guard} */", ""]
    return "\n".join(lines)


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


def _arg_rows(f: ca.Function, glossary: dict[str, str]) -> list[tuple[str, int, str, str, str]]:
    """(kind, index, name, size text, meaning) of every input and output."""
    rows = []
    for i in range(f.n_in()):
        rows.append(("in", i, f.name_in(i), _size(f.size_in(i)), glossary.get(f.name_in(i), "")))
    for i in range(f.n_out()):
        rows.append(("out", i, f.name_out(i), _size(f.size_out(i)), glossary.get(f.name_out(i), "")))
    return rows


def _size(sh) -> str:
    return str(sh[0]) if sh[1] == 1 else f"{sh[0]}x{sh[1]}"


def _header(fns: dict[str, ca.Function], c_text: str, prefix: str, opts, P) -> str:
    from arvcas._version import __version__

    lib = prefix.rstrip("_")
    guard = f"{lib.upper()}_H"
    st = P.structure
    what = [f"/* {lib}.h: the arvcas plant functions of the system {c_comment(st.name)}, in C:",
            *(f" * {line}" for line in (c_comment_lines(P.description) if P.description else ())),
            f" * {st.n_thrusters} thrusters, {st.n_joints} joints ({st.arm} arm), {len(P)} parameters:"
            f" q[{st.n_joints}], u[{st.n_thrusters}], p[{len(P)}] (names, SI units in {lib}_params.h)."]
    L = [
        *what,
        " *",
        f" * Generated by arvcas {__version__} with CasADi {ca.__version__}; model options {c_comment(repr(opts))};"
        " default",
        f" * parameters from {c_comment(P.path)} (in {lib}_params.h). Link with -l{lib} -lm.",
        " *",
        " * UNITS AND FRAMES: SI units throughout; {b} is the body frame at the centre of buoyancy (COB),",
        " * x forward, y starboard, z down; eta is the NED position of the COB and the ZYX Euler angles.",
        " * All inputs and outputs are dense arrays of double; a matrix output is stored column-major.",
        " * Every number of the model is in p, the last input of every function (no rebuild to change one).",
        " *",
        " * CALLING CONVENTION (CasADi's): for each function F below,",
        " *   int F(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem)",
        " * evaluates F; arg[i] points to input i and res[i] to output i, in the order listed with F (a NULL",
        " * arg[i] reads as zeros, a NULL res[i] is not written); iw and w are work arrays of at least",
        " * F_SZ_IW and F_SZ_W elements, arg and res arrays of at least F_SZ_ARG and F_SZ_RES pointers",
        " * (the same numbers as F_work() returns). F returns 0: the generated code has no failure path and",
        " * does not check its inputs (NaN and inf go through the IEEE arithmetic). mem is ignored: pass 0.",
        " * F_eval(named inputs..., outputs...) is a static inline wrapper that does the above with work",
        " * arrays on the stack (F_SZ_W doubles: see each function).",
        " *",
        " * THREAD SAFETY: every function is reentrant. It reads only its inputs and constant tables and",
        " * writes only its outputs and the work arrays given to it; the library has no writable global or",
        " * static data (export-c checks this in the generated code). So any number of threads may call any",
        " * functions at the same time, provided each concurrent call has its own arg, res, iw and w arrays",
        " * (F_eval's are on the caller's stack, so F_eval is always safe). F_checkout() returns 0 and",
        " * F_release(), F_incref() and F_decref() do nothing in this library: they exist for CasADi's API",
        " * and need not be called.",
        " *",
        f" * SYMBOLS: every global symbol of the library starts with {prefix}: the functions declared here",
        f" * and CasADi's small helpers ({prefix}fmax, {prefix}sq, ...), which are not part of the API.",
        " */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        "#ifndef casadi_real",
        "#define casadi_real double",
        "#endif",
        "#ifndef casadi_int",
        "#define casadi_int long long int",
        "#endif",
        "",
        "#ifdef __cplusplus",
        'extern "C" {',
        "#endif",
        "",
        "/* CasADi version, and the sizes of casadi_int and casadi_real, the library was generated with */",
    ]
    full_names = [prefix + n for n in fns]
    for sym, decl in _exported(c_text):
        if _owner(sym, full_names) is None:
            if not sym.startswith(prefix):
                raise ExportError(f"export-c: CasADi's generated code exports {sym}, without the prefix {prefix}")
            L.append(decl)
    for short, f in fns.items():
        full = prefix + short
        F = full.upper()
        ws = _work_sizes(c_text, full)
        rows = _arg_rows(f, _glossary(P))
        width = max(len(r[2]) for r in rows)
        L += ["", "/* " + "-" * 96, f" * {full}: {_SUMMARY[short]}", " *"]
        for kind, i, name, size, meaning in rows:
            slot = f"arg[{i}]" if kind == "in" else f"res[{i}]"
            L.append(f" *   {slot:<7} {name:<{width}} {size:>5}  {c_comment(meaning)}")
        L += [
            " *",
            f" * work: arg {ws['sz_arg']} pointers, res {ws['sz_res']} pointers, iw {ws['sz_iw']} integers,"
            f" w {ws['sz_w']} doubles ({8 * ws['sz_w']:,} bytes)",
            " */",
        ]
        for k in ("sz_arg", "sz_res", "sz_iw", "sz_w"):
            L.append(f"#define {F}_{k.upper()} {ws[k]}")
        L += _prototypes(c_text, full, [prefix + n for n in fns])
        ins = [f"const casadi_real* {f.name_in(i)}" for i in range(f.n_in())]
        outs = [f"casadi_real* {f.name_out(i)}" for i in range(f.n_out())]
        L += [
            f"/* {full} with named arguments (sizes above); work arrays on the stack. Returns 0. */",
            f"static inline int {full}_eval({', '.join(ins + outs)}) {{",
            f"  const casadi_real* arg[{F}_SZ_ARG];",
            f"  casadi_real* res[{F}_SZ_RES];",
            f"  casadi_int iw[{F}_SZ_IW + 1];",
            f"  casadi_real w[{F}_SZ_W + 1];",
        ]
        L += [f"  arg[{i}] = {f.name_in(i)};" for i in range(f.n_in())]
        L += [f"  res[{i}] = {f.name_out(i)};" for i in range(f.n_out())]
        L += [f"  return {full}(arg, res, iw, w, 0);", "}"]
    L += ["", "#ifdef __cplusplus", "}", "#endif", "", f"#endif /* {guard} */", ""]
    return "\n".join(L)


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


def _preamble(template: str, lib: str) -> list[str]:
    """The fixed opening lines of an example: ``templates/<template>`` with ``@LIB@`` replaced by ``lib``."""
    text = (resources.files("arvcas") / "build" / "templates" / template).read_text(encoding="utf-8")
    return text.replace("@LIB@", lib).removesuffix("\n").split("\n")


def _example_c(fns, inputs, prefix: str) -> str:
    lib = prefix.rstrip("_")
    out = _preamble("example_preamble.c", lib)
    for k, v in inputs.items():
        out.append(f"static const casadi_real in_{k}[{v.size}] = {{{', '.join(_c_double(x) for x in v)}}};")
    out += ["", "int main(void)", "{", "  int failed = 0;"]
    for short, f in fns.items():
        full = prefix + short
        args = [f"{prefix}p_default" if k == "p" else f"in_{k}" for k in f.name_in()]
        outs = [f"out{i}" for i in range(f.n_out())]
        out += ["  {", f"    const casadi_real* in[{len(args)}] = {{{', '.join(args)}}};"]
        for i in range(f.n_out()):
            out.append(f"    static casadi_real out{i}[{f.numel_out(i)}];")
        out += [
            f"    casadi_real* out[{f.n_out()}] = {{{', '.join(outs)}}};",
            f"    if ({full}_n_in() != {len(args)} || {full}_n_out() != {f.n_out()}) {{",
            f'      fprintf(stderr, {c_string(full + ": wrong library" + chr(10))});',
            "      return 1;",
            "    }",
            f"    if (call({full}, {full}_work, in, {len(args)}, out, {f.n_out()})) {{",
            f'      fprintf(stderr, {c_string(full + " failed" + chr(10))});',
            "      failed = 1;",
            "    } else {",
        ]
        for k in f.name_in():
            if k != "p":
                out.append(f'      print_vec("in", {c_string(short)}, {c_string(k)}, in_{k}, {inputs[k].size});')
        for i in range(f.n_out()):
            out.append(f'      print_vec("out", {c_string(short)}, {c_string(f.name_out(i))}, out{i}, {f.numel_out(i)});')
        out += ["    }", "  }"]
    out += ["  return failed;", "}", ""]
    return "\n".join(out)


def _example_cpp(fns, inputs, prefix: str) -> str:
    lib = prefix.rstrip("_")
    out = _preamble("example_preamble.cpp", lib)
    for k, v in inputs.items():
        out.append(f"  const std::array<double, {v.size}> {k}{{{', '.join(_c_double(x) for x in v)}}};")
    out.append("  int failed = 0;")
    for short, f in fns.items():
        full = prefix + short
        args = [f"{prefix}p_default" if k == "p" else f"{k}.data()" for k in f.name_in()]
        out.append("  {")
        for i in range(f.n_out()):
            out.append(f"    std::vector<double> {f.name_out(i)}({f.numel_out(i)});")
        args += [f"{f.name_out(i)}.data()" for i in range(f.n_out())]
        out += [f"    if ({full}_eval({', '.join(args)}) != 0) {{",
                f'      std::fprintf(stderr, {c_string(full + " failed" + chr(10))});',
                "      failed = 1;",
                "    } else {"]
        for k in f.name_in():
            if k != "p":
                out.append(f'      print_vec("in", {c_string(short)}, {c_string(k)}, {k}.data(), {k}.size());')
        for i in range(f.n_out()):
            o = f.name_out(i)
            out.append(f'      print_vec("out", {c_string(short)}, {c_string(o)}, {o}.data(), {o}.size());')
        out += ["    }", "  }"]
    out += ["  return failed;", "}", ""]
    return "\n".join(out)


def _example_py(fns, inputs, prefix: str, P) -> str:
    lib = prefix.rstrip("_")
    sig = {short: ([f.name_in(i) for i in range(f.n_in())], [(f.name_out(i), f.numel_out(i)) for i in range(f.n_out())])
           for short, f in fns.items()}
    vals = {k: [float(x) for x in v] for k, v in inputs.items()}
    return f'''"""example.py: call lib{lib}.so from Python with ctypes (no arvcas, no CasADi, no NumPy needed).

Prints the same lines as example.c. Run after `make` (or give the library's path):
    python3 example.py [path/to/lib{lib}.so]
"""

import ctypes
import os
import sys

PREFIX = {prefix!r}
# the fixed state of the examples, and the default parameter vector p ({lib}_params.h)
INPUTS = {vals!r}
P_DEFAULT = {[float(x) for x in P.vector()]!r}
# function -> (input names in order, [(output name, size)])
FUNCTIONS = {sig!r}

real, integer = ctypes.c_double, ctypes.c_longlong  # casadi_real, casadi_int


def load(path):
    lib = ctypes.CDLL(path)
    fns = {{}}
    for short, (ins, outs) in FUNCTIONS.items():
        name = PREFIX + short
        work = getattr(lib, name + "_work")
        work.argtypes = [ctypes.POINTER(integer)] * 4
        work.restype = ctypes.c_int
        sizes = [integer() for _ in range(4)]
        if work(*[ctypes.byref(s) for s in sizes]) != 0:
            raise RuntimeError(name + "_work failed")
        sz_arg, sz_res, sz_iw, sz_w = (max(int(s.value), 1) for s in sizes)
        f = getattr(lib, name)
        f.argtypes = [ctypes.POINTER(ctypes.POINTER(real)), ctypes.POINTER(ctypes.POINTER(real)),
                      ctypes.POINTER(integer), ctypes.POINTER(real), ctypes.c_int]
        f.restype = ctypes.c_int
        # one set of work arrays per function: reuse them in one thread, make new ones per thread
        fns[short] = (f, (ctypes.POINTER(real) * max(sz_arg, len(ins)))(), (ctypes.POINTER(real) * max(sz_res, len(outs)))(),
                      (integer * sz_iw)(), (real * sz_w)())
    return fns


def call(fns, short, inputs):
    f, arg, res, iw, w = fns[short]
    ins, outs = FUNCTIONS[short]
    keep = [(real * len(inputs[k]))(*inputs[k]) for k in ins]
    for i, a in enumerate(keep):
        arg[i] = ctypes.cast(a, ctypes.POINTER(real))
    bufs = [(real * n)() for _, n in outs]
    for i, b in enumerate(bufs):
        res[i] = ctypes.cast(b, ctypes.POINTER(real))
    if f(arg, res, iw, w, 0) != 0:
        raise RuntimeError(PREFIX + short + " failed")
    return [list(b) for b in bufs]


def main(argv):
    path = argv[1] if len(argv) > 1 else os.path.join(os.path.dirname(os.path.abspath(__file__)), "lib{lib}.so")
    fns = load(path)
    values = dict(INPUTS, p=P_DEFAULT)
    for short, (ins, outs) in FUNCTIONS.items():
        results = call(fns, short, values)
        for k in ins:
            if k != "p":
                print("in", short, k, ":", " ".join("%.17g" % v for v in values[k]))
        for (name, _), r in zip(outs, results):
            print("out", short, name, ":", " ".join("%.17g" % v for v in r))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
'''


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


def _makefile(prefix: str) -> str:
    lib = _lib(prefix)
    base, cflags, libs = _flags()
    pic = [f for f in base if f != "-shared"]
    return f"""\
# Builds lib{lib}.so, example (C) and example_cpp (C++) with the compiler flags of arvcas's build
# cache (arvcas.build.codegen: BASE_FLAGS, DEFAULT_OPT_LEVEL, FIXED_FLAGS, LIBS), so the library
# gives the numbers arvcas gives. Keep IEEE semantics: no -Ofast, -ffast-math or FMA contraction.
#   make          build all three
#   make run      build and run the C example;  python3 example.py  runs the ctypes example
CC ?= cc
CXX ?= c++
ARVCAS_CFLAGS = {' '.join(cflags)}
ARVCAS_LIBFLAGS = {' '.join(base)}
ARVCAS_PIC = {' '.join(pic)}
LDLIBS = {' '.join(libs)}

all: lib{lib}.so example example_cpp

# the library is the slow part (seconds at -O2): one progress line, "compiling lib{lib}.so ... 9 s"
lib{lib}.so: {lib}.c
\t@printf 'compiling lib{lib}.so ...\\n'; t0=$$(date +%s); \\
\t$(CC) $(ARVCAS_CFLAGS) $(ARVCAS_LIBFLAGS) $(CFLAGS) -o $@ {lib}.c $(LDLIBS) && \\
\tprintf 'compiling lib{lib}.so ... %s s\\n' $$(( $$(date +%s) - t0 ))

example: example.c {lib}.h {lib}_params.h lib{lib}.so
\t$(CC) $(ARVCAS_CFLAGS) $(ARVCAS_PIC) $(CFLAGS) -o $@ example.c -L. -l{lib} -Wl,-rpath,'$$ORIGIN' $(LDLIBS)

example_cpp: example.cpp {lib}.h {lib}_params.h lib{lib}.so
\t$(CXX) $(ARVCAS_CFLAGS) $(ARVCAS_PIC) $(CXXFLAGS) -o $@ example.cpp -L. -l{lib} -Wl,-rpath,'$$ORIGIN' $(LDLIBS)

run: example
\t./example

clean:
\trm -f lib{lib}.so example example_cpp

.PHONY: all run clean
"""


def _cmake(prefix: str) -> str:
    lib = _lib(prefix)
    base, cflags, libs = _flags()
    unknown = [f for f in base if f not in ("-shared", "-fPIC")]
    options = " ".join(cflags + unknown)
    link = " ".join(lib_.removeprefix("-l") for lib_ in libs)
    return f"""\
# lib{lib} with CMake: builds the shared library with the flags of arvcas's build cache
# (arvcas.build.codegen: -shared -fPIC = a SHARED library with POSITION_INDEPENDENT_CODE, then
# DEFAULT_OPT_LEVEL and FIXED_FLAGS as compile options, LIBS linked), and the examples.
#
#   cmake -S . -B build && cmake --build build && cmake --install build --prefix /your/prefix
#
# installs lib/lib{lib}.so, include/{lib}.h, include/{lib}_params.h and the package config
# lib/cmake/{lib}/{lib}Config.cmake. In another project:
#   find_package({lib} CONFIG REQUIRED)           # with -DCMAKE_PREFIX_PATH=/your/prefix
#   target_link_libraries(your_target PRIVATE arvcas::{lib})
# (consumer/CMakeLists.txt does exactly this for example.cpp). Without installing, the build tree
# works too: -D{lib}_DIR=<this build directory>.
cmake_minimum_required(VERSION 3.16)
project({lib} LANGUAGES C CXX)

option({lib.upper()}_EXAMPLES "build example (C) and example_cpp (C++)" ON)
include(GNUInstallDirs)

add_library({lib} SHARED {lib}.c)
set_target_properties({lib} PROPERTIES POSITION_INDEPENDENT_CODE ON PUBLIC_HEADER "{lib}.h;{lib}_params.h")
# after CMAKE_C_FLAGS and the build type's flags, so these decide (last -O wins)
target_compile_options({lib} PRIVATE {options})
target_link_libraries({lib} PRIVATE {link})
target_include_directories({lib} PUBLIC
  $<BUILD_INTERFACE:${{CMAKE_CURRENT_SOURCE_DIR}}>
  $<INSTALL_INTERFACE:${{CMAKE_INSTALL_INCLUDEDIR}}>)
add_library(arvcas::{lib} ALIAS {lib})

install(TARGETS {lib} EXPORT {lib}Targets
  LIBRARY DESTINATION ${{CMAKE_INSTALL_LIBDIR}}
  PUBLIC_HEADER DESTINATION ${{CMAKE_INSTALL_INCLUDEDIR}})
install(EXPORT {lib}Targets NAMESPACE arvcas:: FILE {lib}Config.cmake
  DESTINATION ${{CMAKE_INSTALL_LIBDIR}}/cmake/{lib})
export(EXPORT {lib}Targets NAMESPACE arvcas:: FILE ${{CMAKE_CURRENT_BINARY_DIR}}/{lib}Config.cmake)

if({lib.upper()}_EXAMPLES)
  add_executable(example example.c)
  target_compile_options(example PRIVATE {options})
  target_link_libraries(example PRIVATE {lib} {link})
  add_executable(example_cpp example.cpp)
  target_compile_options(example_cpp PRIVATE {options})
  target_link_libraries(example_cpp PRIVATE {lib} {link})
endif()
"""


def _cmake_consumer(prefix: str) -> str:
    lib = _lib(prefix)
    _, cflags, libs = _flags()
    return f"""\
# A project using the installed lib{lib} through its CMake package config:
#   cmake -S consumer -B build-consumer -DCMAKE_PREFIX_PATH=/your/prefix && cmake --build build-consumer
cmake_minimum_required(VERSION 3.16)
project({lib}_consumer LANGUAGES CXX)
find_package({lib} CONFIG REQUIRED)
add_executable(example_cpp ../example.cpp)
target_compile_options(example_cpp PRIVATE {' '.join(cflags)})
target_link_libraries(example_cpp PRIVATE arvcas::{lib})
"""


def _readme(fns, opts, P, inputs, prefix: str) -> str:
    from arvcas._version import __version__

    lib = prefix.rstrip("_")
    gl = _glossary(P)
    L = [
        f"# lib{lib}: the arvcas plant functions in C",
        "",
        f"Generated by arvcas {__version__} with CasADi {ca.__version__}; model options `{markdown(repr(opts))}`"
        f" (tag `{markdown(opts.tag())}`); default parameters from `{markdown(P.path)}`.",
        "",
        f"System `{markdown(P.structure.name)}`: {markdown(P.description or P.structure.name)};"
        f" {P.structure.n_thrusters}"
        f" thrusters, {P.structure.n_joints} joints ({P.structure.arm} arm), {len(P)} parameters, so"
        f" `q` has {P.structure.n_joints} entries, `u` {P.structure.n_thrusters} and `p` {len(P)}.", "",
        "## Files",
        "",
        f"- `{lib}.c`: the {len(fns)} functions below (CasADi's generated C; every global symbol starts with `{prefix}`)",
        f"- `{lib}.h`: the header: calling convention, thread safety, every argument (order, size, unit, frame),"
        " work sizes, prototypes and `<function>_eval` wrappers with named arguments",
        f"- `{lib}_params.h`: `{prefix}p_default[{prefix.upper()}NP]`, the default `p`, with the name, SI unit and"
        f" index of every entry, and an index macro `{prefix.upper()}P_<NAME>` per entry",
        "- `example.c` (CasADi's calling convention), `example.cpp` (the `_eval` wrappers), `example.py` (ctypes):"
        " each calls every function at a fixed state and prints inputs and outputs with `%.17g`",
        f"- `Makefile`: `make` builds `lib{lib}.so`, `example` and `example_cpp`; `make run` runs `example`",
        f"- `CMakeLists.txt`: the same with CMake, plus `cmake --install` of the library, headers and the package"
        f" config `{lib}Config.cmake`; `consumer/CMakeLists.txt` builds `example.cpp` against it with"
        f" `find_package({lib})`",
        f"- `{MANIFEST}`: what `arvcas export-c` wrote, with sha256; it replaces only those files, unchanged",
        "",
        "Both build files use the compiler flags of arvcas's build cache, so the library gives the numbers arvcas"
        " gives (to the last bits on the same compiler). Do not add `-Ofast` or `-ffast-math`.",
        "",
        "## Functions",
        "",
    ]
    for short, f in fns.items():
        L += [f"### `{prefix}{short}`", "", _SUMMARY[short], "",
              "| | index | name | size | meaning |", "|---|---|---|---|---|"]
        for i in range(f.n_in()):
            k = f.name_in(i)
            L.append(f"| in | {i} | `{k}` | {f.size1_in(i)}x{f.size2_in(i)} | {gl.get(k, '')} |")
        for i in range(f.n_out()):
            k = f.name_out(i)
            L.append(f"| out | {i} | `{k}` | {f.size1_out(i)}x{f.size2_out(i)} | {gl.get(k, '')} |")
        L.append("")
    L += ["## The examples' fixed state", "", f"SI units; `p` is `{prefix}p_default`.", ""]
    for k, v in inputs.items():
        L.append(f"- `{k}` = [{', '.join(f'{x:.17g}' for x in v)}]")
    L.append("")
    return "\n".join(L)


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

    texts = {
        f"{lib}.c": c_text,
        f"{lib}.h": _header(fns, c_text, prefix, opts, P),
        f"{lib}_params.h": _params_header(P, opts, prefix),
        "example.c": _example_c(fns, inputs, prefix),
        "example.cpp": _example_cpp(fns, inputs, prefix),
        "example.py": _example_py(fns, inputs, prefix, P),
        "Makefile": _makefile(prefix),
        "CMakeLists.txt": _cmake(prefix),
        "consumer/CMakeLists.txt": _cmake_consumer(prefix),
        "README.md": _readme(fns, opts, P, inputs, prefix),
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
    """The one output policy (:func:`arvcas.io.files.check_outputs`, kind ``what``: the export's command):
    a file in ``out`` is replaced only if that export wrote it and nobody changed it since (the
    directory's manifest), or with ``force``; a subdirectory that is a symbolic link is refused even
    with ``force``. One line, naming the file."""
    from arvcas.io import files as _files

    if out.exists():
        _files.check_outputs([(f"{what}: DIR {out}", out / n, what, out) for n in names], force=force,
                             error=ExportError)
