"""CasADi's generated C of an SX Function rewritten to evaluate W lanes at once.

An SX Function's generated body is straight-line scalar code, one operation per statement on locals
``aN`` (``a3=(a1*a2);``, ``a4=sqrt(a3);``, ``a5=(a4<a1);``...). :func:`lane_function` rewrites that
body so every local holds W lanes (GCC's vector extensions, which clang also implements): the
arithmetic ``+ - * /`` and negation act lane by lane with the same IEEE operation; comparisons and
logic give a lane mask turned into 1.0 or 0.0 (what C's scalar ``<``, ``!``, ``&&`` give); CasADi's
``c ? x : 0`` and ``casadi_sign`` become per-lane selects; ``casadi_fabs`` clears the sign bit (what
``fabs`` does). Every other function (``sqrt``, ``sin``, ``cos``, ``tan``, ``fmax``, ``fmin``,
``exp``...) is called lane by lane: the same libm call on the same number as the scalar code, so the
same bits, whatever libm does inside (a vectorised libm, such as glibc's libmvec, rounds
differently). Compiled with the scalar code's flags (``-ffp-contract=off``: no fused multiply-add),
each lane's result equals the scalar function's to the bit; the tests check it on every function
of the shipped runs, and the rewrite refuses (:class:`LaneError`) any statement it does not know
rather than guess.

Each input is read either in lane layout (entry j of lane l at ``arg[k][j * W + l]``) or shared by
all lanes (entry j at ``arg[k][j]``, broadcast); outputs are written in lane layout.
"""

from __future__ import annotations

import re
from typing import Sequence

import casadi as ca

__all__ = ["LaneError", "header", "lane_functions", "lane_width", "REWRITE_VERSION"]

REWRITE_VERSION = 1  # part of every description that holds lane code (the cache key)
_CODEGEN_OPTS = {"casadi_real": "double", "casadi_int": "long long int", "with_header": False}

# functions called lane by lane (one libm call per lane, as the scalar code makes it); CasADi's own
# helpers map to what they call in C99 (casadi_fmax -> fmax...).
_PER_LANE_1 = {"sqrt", "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh", "acosh",
               "atanh", "exp", "log", "log10", "log1p", "expm1", "floor", "ceil", "erf", "cbrt"}
_PER_LANE_2 = {"fmax", "fmin", "pow", "atan2", "fmod", "remainder", "hypot", "copysign"}
_ALIASES = {"casadi_fmax": "fmax", "casadi_fmin": "fmin", "casadi_log1p": "log1p", "casadi_expm1": "expm1",
            "casadi_hypot": "hypot"}

_OPND = r"(a\d+|-?\d+\.?\d*(?:e[-+]?\d+)?|casadi_inf|casadi_nan)"
_SPECIAL = {"casadi_inf": "INFINITY", "casadi_nan": "NAN"}
_NUM = re.compile(r"-?\d+\.?\d*(?:e[-+]?\d+)?$")


class LaneError(ValueError):
    """The generated C has a statement the lane rewrite does not handle (one line, naming it)."""


def lane_width(isa: Sequence[str] | None = None) -> int:
    """The lanes of a double vector register for the instruction-set flags ``isa`` (default
    :func:`arvcas.build.codegen.isa_flags`): 4 with ``-mavx`` (256-bit registers), else 2 (SSE2 on
    x86-64, NEON on aarch64: 128 bits)."""
    if isa is None:
        from arvcas.build.codegen import isa_flags

        isa = isa_flags()
    return 4 if "-mavx" in isa else 2


def header(W: int) -> str:
    """The vector types and helpers every lane function uses (once per C file)."""
    if W not in (2, 4, 8):
        raise ValueError(f"lanes: W must be 2, 4 or 8, got {W!r}")
    return f"""
/* arvcas: {W} lanes per vector (arvcas.build.lanes, rewrite {REWRITE_VERSION}) */
#include <math.h>
#include <string.h>
#define LN_W {W}
typedef double ln_vd __attribute__((vector_size({8 * W})));
typedef long long int ln_vl __attribute__((vector_size({8 * W})));
static inline ln_vd ln_bc(double c) {{ ln_vd r; for (int l = 0; l < LN_W; ++l) r[l] = c; return r; }}
static inline ln_vd ln_ld(const double* p) {{ ln_vd r; memcpy(&r, p, sizeof r); return r; }}
static inline void ln_st(double* p, ln_vd v) {{ memcpy(p, &v, sizeof v); }}
static inline ln_vd ln_mask(ln_vl m) {{ return (ln_vd)(m & (ln_vl)ln_bc(1.0)); }}
static inline ln_vd ln_sel(ln_vl m, ln_vd a, ln_vd b) {{ return (ln_vd)((m & (ln_vl)a) | (~m & (ln_vl)b)); }}
static inline ln_vd ln_fabs(ln_vd x) {{ return (ln_vd)((ln_vl)x & ~(ln_vl)ln_bc(-0.0)); }}
static inline ln_vd ln_sign(ln_vd x) {{
  return ln_sel(x < 0, ln_bc(-1.0), ln_sel(x > 0, ln_bc(1.0), x)); }}
"""


def _sincos_pairs(body: list[str]) -> dict[int, tuple[int, bool]]:
    """Statements computing ``sin(aX)`` and ``cos(aX)`` of the same value (``aX`` not assigned between):
    line index -> (pair number, whether it is the pair's first statement). The scalar code's compiler
    turns such pairs into one ``sincos`` call (GCC's sincos pass); the lane code calls ``sincos`` for
    them, once per lane. glibc's ``sincos`` gives the bits of ``sin`` and ``cos`` (its sincos shares their
    code; 3e7 arguments from 0 to 1e6 compared), so the choice cannot change a result there, and the
    lane tests compare every output to the scalar run's bits on whatever libm the machine has."""
    open_: dict[tuple[str, str], int] = {}  # (function, argument) -> its statement, while the argument holds
    pairs: dict[int, tuple[int, bool]] = {}
    n = 0
    for i, s in enumerate(body):
        m = re.fullmatch(r"(a\d+)=(sin|cos)\((a\d+)\);", s)
        if m:
            a, f, x = m.groups()
            other = open_.pop(("cos" if f == "sin" else "sin", x), None)
            if other is not None:
                pairs[other], pairs[i] = (n, True), (n, False)
                n += 1
            else:
                open_[(f, x)] = i
        else:
            m = re.fullmatch(r"(a\d+)=.*;", s)
            a = m.group(1) if m else None
        if a is not None:  # an assignment ends every pending pair on that variable
            for key in [k for k in open_ if k[1] == a]:
                del open_[key]
    return pairs


def _per_lane_helpers(names1: set[str], names2: set[str]) -> str:
    """The per-lane calls. Each goes to the libm symbol under another C name (an ``asm`` label), so the
    compiler knows nothing of what it computes and calls it once per lane, as the scalar code does:
    with its builtin knowledge GCC vectorised ``fmax`` over the lanes into an inline sequence that
    returns +0 for fmax(+0, -0), where libm (and so the scalar code) returns -0. ``sqrt`` is the
    exception: correctly rounded in IEEE 754, it becomes the vector square root (what the scalar
    code's ``sqrtsd`` is lane by lane)."""
    out = ["#define LN_S2(x) #x", "#define LN_S(x) LN_S2(x)",
           "#define LN_LIBM(f) __asm__(LN_S(__USER_LABEL_PREFIX__) #f)"]
    if "sincos" in names1:
        names1 = names1 - {"sincos"}
        out.append("extern void ln_libm_sincos(double, double*, double*) LN_LIBM(sincos);")
        out.append("static inline void ln_sincos(ln_vd x, ln_vd* s, ln_vd* c) { for (int l = 0; l < LN_W; ++l) "
                   "{ double s_, c_; ln_libm_sincos(x[l], &s_, &c_); (*s)[l] = s_; (*c)[l] = c_; } }")
    for f in sorted(names1):
        call = f"{f}(x[l])" if f == "sqrt" else f"ln_libm_{f}(x[l])"
        if f != "sqrt":
            out.append(f"extern double ln_libm_{f}(double) LN_LIBM({f});")
        out.append(f"static inline ln_vd ln_{f}(ln_vd x) {{ ln_vd r; for (int l = 0; l < LN_W; ++l) r[l] = {call}; "
                   f"return r; }}")
    for f in sorted(names2):
        out.append(f"extern double ln_libm_{f}(double, double) LN_LIBM({f});")
        out.append(f"static inline ln_vd ln_{f}(ln_vd x, ln_vd y) {{ ln_vd r; for (int l = 0; l < LN_W; ++l) "
                   f"r[l] = ln_libm_{f}(x[l], y[l]); return r; }}")
    return "\n".join(out)


def _body(fn: ca.Function) -> list[str]:
    """The lines of the body of ``fn``'s generated C function (``casadi_f0``)."""
    cg = ca.CodeGenerator(fn.name() + "_lanesrc", _CODEGEN_OPTS)
    cg.add(fn)
    src = cg.dump()
    start = src.find("static int casadi_f0(")
    if start < 0 or src.find("static int casadi_f1(") >= 0:
        raise LaneError(f"lanes: {fn.name()}: not a single SX function (it calls other functions)")
    body = src[start:]
    end = body.index("\n}\n")
    return body[:end].split("\n")[1:]


def _v(x: str) -> str:
    if x in _SPECIAL:
        return f"ln_bc({_SPECIAL[x]})"
    return f"ln_bc({x})" if _NUM.match(x) else x


def lane_functions(items) -> str:
    """C of W-lane versions of SX functions: for each ``(fn, c_name, shared)`` of ``items``,
    ``static void c_name(const double* const* arg, double* const* res)`` evaluating ``fn`` on W lanes.

    ``shared[k]`` (a sequence of bools, missing entries False): input k is the same for every lane and
    read in scalar layout (broadcast); else it is in lane layout. Every input pointer must be valid
    (no null inputs); every output is written in lane layout. Needs :func:`header` before it in the C file.
    """
    used1, used2, funcs = set(), set(), []
    for fn, c_name, shared in items:
        funcs.append(_lane_function(fn, c_name, shared, used1, used2))
    return _per_lane_helpers(used1, used2) + "\n" + "".join(funcs)


def _lane_function(fn: ca.Function, c_name: str, shared, used1: set, used2: set) -> str:
    if not fn.is_a("SXFunction"):
        raise LaneError(f"lanes: {fn.name()}: only SX functions can be rewritten, got {fn.class_name()}")
    shared = list(shared) + [False] * (fn.n_in() - len(shared))
    body = [ln.strip() for ln in _body(fn)]
    pairs = _sincos_pairs(body)
    out = [f"static void {c_name}(const double* const* arg, double* const* res) {{"]
    if pairs:
        out.append("  ln_vd " + ", ".join(f"ln_s{k}, ln_c{k}" for k in sorted({k for k, _ in pairs.values()})) + ";")
    for i, s in enumerate(body):
        if not s or s == "return 0;":
            continue
        if i in pairs:  # sin and cos of one value: one sincos per lane (see _sincos_pairs)
            k, first = pairs[i]
            m = re.fullmatch(r"(a\d+)=(sin|cos)\((a\d+)\);", s)
            a, f, x = m.groups()
            if first:
                used1.add("sincos")
                out.append(f"  ln_sincos({x},&ln_s{k},&ln_c{k});")
            out.append(f"  {a}=ln_{f[0]}{k};")
            continue
        if s.startswith("casadi_real "):
            out.append("  " + s.replace("casadi_real", "ln_vd", 1))
            continue
        m = re.fullmatch(r"(a\d+)=arg\[(\d+)\]\? arg\[\d+\]\[(\d+)\] : 0;", s)
        if m:
            a, k, j = m.group(1), int(m.group(2)), int(m.group(3))
            out.append(f"  {a}=ln_bc(arg[{k}][{j}]);" if shared[k] else f"  {a}=ln_ld(arg[{k}]+{j}*LN_W);")
            continue
        m = re.fullmatch(r"if \(res\[(\d+)\]!=0\) res\[\d+\]\[(\d+)\]=(a\d+);", s)
        if m:
            out.append(f"  ln_st(res[{m.group(1)}]+{m.group(2)}*LN_W,{m.group(3)});")
            continue
        m = re.fullmatch(r"(a\d+)=(.*);", s)
        if not m:
            raise LaneError(f"lanes: {fn.name()}: a statement the rewrite does not handle: {s}")
        a, e = m.groups()
        out.append(f"  {a}={_expr(fn.name(), e, used1, used2)};")
    out.append("}")
    return "\n".join(out) + "\n"


def _expr(name: str, e: str, used1: set, used2: set) -> str:
    """One right-hand side of CasADi's SX code in lane form (see the module docstring)."""
    o = _OPND
    m = re.fullmatch(o, e)
    if m:
        return _v(e)
    m = re.fullmatch(rf"\({o}([-+*/]){o}\)", e)
    if m:
        return f"({_v(m.group(1))}{m.group(2)}{_v(m.group(3))})"
    m = re.fullmatch(rf"\({o}(<=|<|==|!=){o}\)", e)
    if m:
        return f"ln_mask({_v(m.group(1))}{m.group(2)}{_v(m.group(3))})"
    m = re.fullmatch(rf"\({o}(&&|\|\|){o}\)", e)
    if m:
        op = "&" if m.group(2) == "&&" else "|"
        return f"ln_mask(({_v(m.group(1))}!=0){op}({_v(m.group(3))}!=0))"
    m = re.fullmatch(rf"\(!{o}\)", e)
    if m:
        return f"ln_mask({_v(m.group(1))}==0)"
    m = re.fullmatch(rf"\(-{o}\)", e)
    if m:
        return f"(-{_v(m.group(1))})"
    m = re.fullmatch(rf"\({o}\?{o}:0\)", e)
    if m:
        return f"ln_sel({_v(m.group(1))}!=0,{_v(m.group(2))},ln_bc(0.))"
    m = re.fullmatch(rf"casadi_sq\({o}\)", e)
    if m:
        x = _v(m.group(1))
        return f"({x}*{x})"
    m = re.fullmatch(rf"(casadi_fabs|fabs)\({o}\)", e)
    if m:
        return f"ln_fabs({_v(m.group(2))})"
    m = re.fullmatch(rf"casadi_sign\({o}\)", e)
    if m:
        return f"ln_sign({_v(m.group(1))})"
    m = re.fullmatch(rf"([A-Za-z_][A-Za-z0-9_]*)\({o}\)", e)
    if m and _ALIASES.get(m.group(1), m.group(1)) in _PER_LANE_1:
        f = _ALIASES.get(m.group(1), m.group(1))
        used1.add(f)
        return f"ln_{f}({_v(m.group(2))})"
    m = re.fullmatch(rf"([A-Za-z_][A-Za-z0-9_]*)\({o},{o}\)", e)
    if m and _ALIASES.get(m.group(1), m.group(1)) in _PER_LANE_2:
        f = _ALIASES.get(m.group(1), m.group(1))
        used2.add(f)
        return f"ln_{f}({_v(m.group(2))},{_v(m.group(3))})"
    raise LaneError(f"lanes: {name}: an operation the rewrite does not handle: {e}")
