"""The plant functions and their Jacobians as NumPy functions: NumPy in, NumPy out, batches looped in C.

``dynamics("vehicle_rhs")(x, tau)`` evaluates the compiled C of :func:`arvcas.compiled` on NumPy
arrays; the parameter vector defaults to the packaged parameters (``p=`` a vector, or ``params=`` a
:class:`arvcas.system.params.Params`, overrides it). Every input takes one evaluation's shape (``x``:
``(12,)``, a size-1 input also a scalar) or a batch of n with a leading axis (``x``: ``(n, 12)``).
Inputs without the batch axis (or with one row) are shared by all n evaluations; outputs have the
batch axis if any input has it.

How a call runs (costs in ``docs/calling-dynamics.md``, measured by ``arvcas bench``):

* **one evaluation**: the inputs are copied into buffers bound once per thread to the compiled
  function (``Function.buffer``), so a call is a few NumPy slice copies, one finite check and one C
  evaluation, without CasADi's conversion to ``DM`` and back.
* **a batch**: the loop over the batch is C. The first batch of a name compiles, through the build
  cache (:func:`arvcas.build.codegen.build`), the plant function's SX graph with a loop appended
  (:func:`arvcas.build.codegen.batch_loop_c`: ``n`` evaluations, input ``k`` of row ``i`` at ``a[k] + i * stride[k]``, stride 0
  for an input all rows share), and calls it through ``ctypes`` on the caller's arrays in place (a
  C-ordered ``(n, 12)`` array is exactly the column-major ``12 x n`` block the loop reads; shared
  inputs, ``p`` among them, are read by pointer, never repeated). ``ctypes`` releases the GIL for
  the call; batches of at least :data:`THREAD_MIN_BATCH` rows run on as many threads as the process
  may use cores (``n_threads=`` overrides), each with its own work memory, taking consecutive blocks
  of rows from a counter they share in C (:func:`arvcas.build.calls.run_loop`, as a batch of runs does). Results do not depend on the thread count, and equal single calls, to the bit.

Checks (one-line ``ValueError`` naming the function and the argument): the number of inputs, every
shape, batch sizes that disagree, real numbers only (complex, boolean, string and masked arrays are
refused: NumPy would drop an imaginary part or a mask), non-finite values (NaN or inf) anywhere in the
inputs, a payload fraction outside [0, 1], and ``params=`` of another system's layout.

Jacobians: ``vehicle_rhs_jac(x, tau, p) -> (xdot, dxdot_dx, dxdot_dtau)`` and
``uvms_rhs_jac(x, tau, q, qd, qdd, payload, p) -> (xdot, dxdot_dx, dxdot_dtau, dxdot_dq)``, exact
(CasADi's algorithmic differentiation of the same graph), dense, ``dxdot_dx[i, j] = d xdot_i / d x_j``;
batched they are ``(n, 12, 12)`` etc.
"""

from __future__ import annotations

import math
import os
import threading

import casadi as ca
import numpy as np

from arvcas.build import calls, codegen
from arvcas.model.uvms import PUBLIC_FUNCTIONS

__all__ = ["compiled", "dynamics", "jacobian_functions", "Dynamics", "NAMES", "JACOBIANS", "THREAD_MIN_BATCH", "BLOCKS_PER_THREAD"]

# name -> (plant function, inputs differentiated); outputs: xdot, then d xdot / d input per input
JACOBIANS = {
    "vehicle_rhs_jac": ("vehicle_rhs", ("x", "tau")),
    "uvms_rhs_jac": ("uvms_rhs", ("x", "tau", "q")),
}
THREAD_MIN_BATCH = 1024  # smaller batches run on the calling thread, in one call
BLOCKS_PER_THREAD = 4  # a threaded batch is taken in blocks of n / (threads * this) rows (the shared counter balances them)

_LOCK = threading.RLock()
_SX: dict[str, dict[str, ca.Function]] = {}
_COMPILED: dict[tuple[str, str], ca.Function] = {}
_PLANT: dict[str, dict[str, ca.Function]] = {}  # (options tag, structure) -> the plant's graphs
_PLANT_COMPILED: dict[tuple, ca.Function] = {}  # (name, tag, cache directory) -> compiled() 's Function


def compiled(name: str, opts=None, system=None) -> ca.Function:
    """The public plant function ``name`` (see :data:`arvcas.model.uvms.PUBLIC_FUNCTIONS`), compiled to C.

    ``opts`` is an :class:`arvcas.model.uvms.ModelOptions` (default: ``ModelOptions()``); ``system`` a
    name, a system file or an :class:`arvcas.system.System` (default: the default system, :data:`arvcas.system.DEFAULT`): the inputs are sized by
    it (``q[n_joints]``, ``u[n_thrusters]``, ``p``: ``system.params.vector()``). Memoized per process by
    ``(name, opts, structure)``; the library comes from the build cache when it is there.
    """
    from arvcas.model.uvms import ModelOptions, plant_functions
    from arvcas.system import resolve

    if name not in PUBLIC_FUNCTIONS:
        raise ValueError(f"unknown plant function {name!r}; allowed: {', '.join(PUBLIC_FUNCTIONS)}")
    opts = ModelOptions.checked(opts)
    lay = resolve(system).layout
    st = lay.structure
    tag = (opts.tag(), st)
    mkey = (name, tag, str(codegen._cache_path()))
    with codegen._LOCK:
        f = _PLANT_COMPILED.get(mkey)
        if f is None:
            def make():
                if tag not in _PLANT:
                    _PLANT[tag] = plant_functions(opts, lay)
                return _PLANT[tag][name]

            from arvcas.system.params import system_tag

            desc = f"plant {name} {opts!r}{system_tag(st)}"
            f = codegen.build_described(name, desc, make, label=f"{name} for {st.name}")
            _PLANT_COMPILED[mkey] = f
        return f
_LOOPS: dict[tuple, "_Loop"] = {}
_DEFAULT_P: list[np.ndarray] = []
_F64 = np.dtype(np.float64)
_ret = getattr(getattr(ca, "_casadi", None), "FunctionBuffer_ret", None) or ca.FunctionBuffer.ret  # skips a wrapper


NAMES = (*PUBLIC_FUNCTIONS, *JACOBIANS)  # every name dynamics() takes


def jacobian_functions(plant: dict[str, ca.Function]) -> dict[str, ca.Function]:
    """The Jacobian SX Functions of :data:`JACOBIANS`, built from the plant SX Functions ``plant``."""
    out = {}
    for jname, (base, wrt) in JACOBIANS.items():
        f = plant[base]
        sym = f.sx_in()
        xdot = f.call(sym)[0]
        idx = [f.index_in(w) for w in wrt]
        outs = [xdot] + [ca.densify(ca.jacobian(xdot, sym[i])) for i in idx]
        out[jname] = ca.Function(jname, sym, outs, f.name_in(), ["xdot"] + [f"dxdot_d{w}" for w in wrt])
    return out


def _sx(opts, params=None) -> dict[str, ca.Function]:
    from arvcas.model.uvms import plant_functions

    lay = params.layout if params is not None else None
    tag = (opts.tag(), None if lay is None else lay.structure)
    with _LOCK:
        if tag not in _SX:
            fns = dict(plant_functions(opts, lay))
            fns.update(jacobian_functions(fns))
            _SX[tag] = fns
        return _SX[tag]


def _compiled(name: str, opts, params=None) -> ca.Function:
    from arvcas.build import codegen

    with _LOCK:
        key = (name, opts.tag(), None if params is None else params.structure)
        if key not in _COMPILED:
            if name in JACOBIANS:  # one library for single calls and batches (its loop appended)
                _COMPILED[key] = _loop(name, opts, params).keep
            else:  # the same Function arvcas.compiled returns
                _COMPILED[key] = compiled(name, opts, system=params)
        return _COMPILED[key]


class _Loop:
    """The compiled batch loop of one plant function: its ctypes entry point and work sizes."""

    def __init__(self, f: ca.Function):
        from arvcas.build import codegen

        self.keep = codegen.build(f, extra_c=codegen.batch_loop_c(f))  # the library stays loaded with this object
        self.fn = calls.batch_loop(self.keep)
        self.sz_iw, self.sz_w = int(f.sz_iw()), int(f.sz_w())


def _loop(name: str, opts, params=None) -> _Loop:
    key = (name, opts.tag(), None if params is None else params.structure)
    with _LOCK:
        lp = _LOOPS.get(key)
        if lp is None:
            lp = _LOOPS[key] = _Loop(_sx(opts, params)[name])
        return lp


def _default_p() -> np.ndarray:
    with _LOCK:
        if not _DEFAULT_P:
            from arvcas.system.params import load

            v = np.ascontiguousarray(load().vector(), dtype=float)
            v.setflags(write=False)
            _DEFAULT_P.append(v)
        return _DEFAULT_P[0]


def _readonly(v) -> np.ndarray:
    v = np.ascontiguousarray(v, dtype=float)
    v.setflags(write=False)
    return v


def _usable_cpus() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _first_bad(a: np.ndarray) -> str:
    i = np.flatnonzero(~np.isfinite(a.reshape(-1)))[0]
    at = np.unravel_index(i, a.shape) if a.ndim else ()
    return f"{a.reshape(-1)[i]} at index {list(map(int, at))}"


class Dynamics:
    """A plant function (or Jacobian) as a NumPy function; made by :func:`dynamics`."""

    def __init__(self, name: str, opts, params=None):
        f = _compiled(name, opts, params)
        self.name = name
        self.opts = opts
        self.params = params  # another system's (None: the default system's packaged parameters)
        self._f = f
        self.function = f  # the compiled casadi.Function (codegen.artifact_of(d.function)["path"]: its library)
        self.input_names = tuple(f.name_in())
        self.output_names = tuple(f.name_out())
        if self.input_names[-1] != "p":
            raise RuntimeError(f"{name}: the last input is {self.input_names[-1]!r}, expected 'p'")
        self.input_sizes = tuple(int(f.nnz_in(i)) for i in range(f.n_in()))
        for i in range(f.n_in()):
            if not f.sparsity_in(i).is_dense() or f.size2_in(i) != 1:
                raise RuntimeError(f"{name}: input {self.input_names[i]} is not a dense column")
        # output shapes of one evaluation: (rows,) for a column, (rows, cols) for a matrix
        self.output_shapes = tuple(
            (int(f.size1_out(i)),) if f.size2_out(i) == 1 else (int(f.size1_out(i)), int(f.size2_out(i)))
            for i in range(f.n_out())
        )
        for i in range(f.n_out()):
            if not f.sparsity_out(i).is_dense():
                raise RuntimeError(f"{name}: output {self.output_names[i]} is sparse")
        self._offsets = np.cumsum((0,) + self.input_sizes[:-2]).tolist()  # of the non-p inputs in the scratch
        self._n_x = int(sum(self.input_sizes[:-1]))
        self._local = threading.local()
        self.n_params = self.input_sizes[-1]
        self._p_default = _default_p() if params is None else _readonly(params.vector())
        self._shapes = tuple((m,) for m in self.input_sizes)  # one evaluation's shape of each input
        self._n_args = len(self.input_sizes) - 1  # without p
        ends = np.cumsum([0] + [int(np.prod(s)) for s in self.output_shapes]).tolist()
        self._out_slices = tuple(zip(ends[:-1], ends[1:]))
        self._one_vector = len(self.output_shapes) == 1 and len(self.output_shapes[0]) == 1
        # the payload fraction's place among the inputs (checked in [0, 1]); None without one
        self._payload = self.input_names.index("payload") if "payload" in self.input_names else None

    def __repr__(self) -> str:
        ins = ", ".join(f"{n}[{s}]" for n, s in zip(self.input_names, self.input_sizes))
        outs = ", ".join(f"{n}{list(s)}" for n, s in zip(self.output_names, self.output_shapes))
        return f"<arvcas.dynamics {self.name}({ins}) -> {outs}>"

    # -- argument handling ----------------------------------------------------------------------

    def _where(self, i: int) -> str:
        return f"{self.name}: {self.input_names[i]}"

    def _array(self, i: int, a) -> tuple[np.ndarray, int | None]:
        """(array, batch size or None) of input i, shape-checked and finite-checked."""
        m = self.input_sizes[i]
        arr = calls.real_array(a, self._where(i), ValueError)  # complex, bool, str, masked: refused by name
        sh = arr.shape
        if sh == (m,) or (m == 1 and sh == ()):
            n = None
        elif arr.ndim == 2 and sh[1] == m and sh[0] >= 1:
            n = sh[0]
        elif m == 1 and arr.ndim == 1 and sh[0] > 1:
            n = sh[0]
        else:
            extra = " or a scalar, or (n,)" if m == 1 else ""
            raise ValueError(f"{self._where(i)}: expected shape ({m},) or (n, {m}){extra}, got {sh}")
        return arr, n

    def _args(self, args, p, params):
        k = len(self.input_names)
        if len(args) == k:
            if p is not None or params is not None:
                raise ValueError(f"{self.name}: p given twice (as the last argument and as p=/params=)")
            p = args[-1]
            args = args[:-1]
        elif len(args) != k - 1:
            names = ", ".join(self.input_names[:-1])
            raise ValueError(f"{self.name}: expected {k - 1} inputs ({names}) and optionally p, got {len(args)}")
        if params is not None:
            if p is not None:
                raise ValueError(f"{self.name}: give p= or params=, not both")
            from arvcas.system.params import Params

            if not isinstance(params, Params):
                raise ValueError(f"{self.name}: params: expected arvcas.system.params.Params, got {type(params).__name__}")
            mine = self.params.structure if self.params is not None else None
            if mine is None:
                from arvcas.system.params import default_layout

                mine = default_layout().structure
            if params.structure != mine:  # the same length would read another layout's numbers in this order
                raise ValueError(f"{self.name}: params: of system '{params.structure.name}', whose parameter layout "
                                 f"is not this function's ('{mine.name}'); use dynamics(name, system=...) for it")
            p = params.vector()
        return args, p

    # -- evaluation ------------------------------------------------------------------------------

    def __call__(self, *args, p=None, params=None, n_threads: int | None = None):
        """Evaluate; see the module docstring. Returns an array, or a tuple of arrays for a Jacobian."""
        if p is None and params is None and n_threads is None and len(args) == self._n_args:
            for a, sh in zip(args, self._shapes):  # the common case: one evaluation, default p, float arrays
                if type(a) is not np.ndarray or a.shape != sh or a.dtype != _F64:
                    break
            else:
                return self._fast(args)
        args, p = self._args(args, p, params)
        arrs, ns = [], []
        shapes = self._shapes
        for i, a in enumerate(args):
            if type(a) is np.ndarray and a.shape == shapes[i] and a.dtype == _F64:  # the common case, fast
                arrs.append(a)
                continue
            arr, n = self._array(i, a)
            arrs.append(arr)
            if n is not None:
                ns.append((n, i))
        ip = len(self.input_names) - 1
        if p is None:
            parr, pn = self._p_default, None
            if parr.shape != (self.n_params,):
                raise ValueError(f"{self.name}: p: the default parameter vector has {parr.size} entries, "
                                 f"the function takes {self.n_params}")
        else:
            parr, pn = self._array(ip, p)
            if pn is not None:
                ns.append((pn, ip))
        if n_threads is not None and (isinstance(n_threads, bool) or not isinstance(n_threads, int) or n_threads < 1):
            raise ValueError(f"{self.name}: n_threads: expected a positive integer or None, got {n_threads!r}")
        if not ns:
            return self._single(arrs, parr, p is not None)
        n = max(m for m, _ in ns)
        for m, i in ns:
            if m not in (1, n):
                first = next(j for mm, j in ns if mm == n)
                raise ValueError(f"{self.name}: batch sizes differ: {self.input_names[first]} has {n} rows, "
                                 f"{self.input_names[i]} has {m}")
        # the inputs with a row per evaluation; one of one row is shared by all rows, as NumPy broadcasts
        rows = {i for m, i in ns if m == n} if n > 1 else set()
        return self._batch(n, arrs, parr, rows, p is not None, n_threads)

    def _state(self):
        """This thread's scratch input/output arrays, bound once to a buffer of the compiled function."""
        st = getattr(self._local, "st", None)
        if st is None:
            f = self._f
            buf, evaluate = f.buffer()
            xin = np.zeros(self._n_x)
            pin = np.array(self._p_default if self._p_default.size == self.n_params else np.zeros(self.n_params))
            allout = np.zeros(self._out_slices[-1][1])  # the outputs one after another: one copy returns all
            xv = memoryview(xin)
            for i, off in enumerate(self._offsets):
                buf.set_arg(i, xv[off:off + self.input_sizes[i]])
            buf.set_arg(len(self._offsets), memoryview(pin))
            for i, (a, b) in enumerate(self._out_slices):
                buf.set_res(i, memoryview(allout[a:b]))
            st = self._local.st = (buf, evaluate, xin, np.full(self._n_x, 1e-300), pin, [None], allout)
            # 1e-300s: for the finite check (x * 1e-300 never overflows); last: the p array pin holds
        return st

    def _fast(self, arrs):
        """:meth:`_single` for float arrays of one evaluation's shapes and the default p (checked by the caller)."""
        st = self._local.__dict__.get("st") or self._state()
        buf, evaluate, xin, tiny, pin, last_p, allout = st
        if last_p[0] is not self._p_default:  # pin holds a caller's p: let _single restore the default
            return self._single(arrs, self._p_default, False)
        np.concatenate(arrs, out=xin)
        if not math.isfinite(xin @ tiny):
            self._raise_nonfinite(arrs)
        if self._payload is not None and not 0.0 <= xin[self._offsets[self._payload]] <= 1.0:
            self._raise_payload(arrs[self._payload])
        return self._evaluate(buf, evaluate, allout)

    def _single(self, arrs, parr, p_given):
        buf, evaluate, xin, tiny, pin, last_p, allout = self._state()
        if len(arrs) > 1 and all(a.ndim == 1 for a in arrs):
            np.concatenate(arrs, out=xin)  # one copy of all inputs
        else:
            offs, sizes = self._offsets, self.input_sizes
            for i, a in enumerate(arrs):
                xin[offs[i]:offs[i] + sizes[i]] = a.reshape(-1)
        if not math.isfinite(xin @ tiny):  # finite unless an entry is (no FP warning but for +inf with -inf)
            self._raise_nonfinite(arrs)
        if self._payload is not None and not 0.0 <= xin[self._offsets[self._payload]] <= 1.0:
            self._raise_payload(arrs[self._payload])
        if last_p[0] is not parr:
            if p_given and not np.isfinite(parr).all():
                raise ValueError(f"{self.name}: p has a non-finite value {_first_bad(parr)}")
            pin[:] = parr
            last_p[0] = parr if not p_given else None  # a caller's array may change between calls
        return self._evaluate(buf, evaluate, allout)

    def _evaluate(self, buf, evaluate, allout):
        """One C evaluation into this thread's output buffer; its outputs as views of one copy of it
        (a matrix is column-major: the view of its transpose)."""
        evaluate()
        if _ret(buf) != 0:
            raise RuntimeError(f"{self.name}: evaluation failed (return code {_ret(buf)})")
        flat = allout.copy()
        if self._one_vector:  # the plant functions: the buffer is the output (0.7 us less than the views)
            return flat
        res = [flat[a:b].reshape(s[::-1]).T if len(s) == 2 else flat[a:b] for (a, b), s in zip(self._out_slices, self.output_shapes)]
        return res[0] if len(res) == 1 else tuple(res)

    def _raise_payload(self, a):
        v = np.asarray(a, dtype=float).ravel()
        bad = v[~((v >= 0.0) & (v <= 1.0))]
        raise ValueError(f"{self.name}: payload: a fraction of the system's payload, in [0, 1], got {float(bad[0])!r}")

    def _raise_nonfinite(self, arrs):
        for i, a in enumerate(arrs):
            if not np.isfinite(a).all():
                raise ValueError(f"{self._where(i)} has a non-finite value {_first_bad(a)}")
        raise ValueError(f"{self.name}: an input has a non-finite value")

    def _batch(self, n, arrs, parr, rows, p_given, n_threads):
        if p_given and not np.isfinite(parr).all():
            raise ValueError(f"{self.name}: p has a non-finite value {_first_bad(parr)}")
        for i, a in enumerate(arrs):
            if not np.isfinite(a).all():
                raise ValueError(f"{self._where(i)} has a non-finite value {_first_bad(a)}")
        if self._payload is not None and not ((arrs[self._payload] >= 0.0) & (arrs[self._payload] <= 1.0)).all():
            self._raise_payload(arrs[self._payload])
        lp = _loop(self.name, self.opts, self.params)
        # per input: a C-ordered array read in place, with its row stride (0: shared by all rows)
        keep, base, stride = [], [], []
        for i, a in enumerate(list(arrs) + [parr]):
            m = self.input_sizes[i]
            c = np.ascontiguousarray(a.reshape(n, m) if i in rows else a.reshape(-1), dtype=float)
            keep.append(c)  # alive, in place, until the loop returns
            base.append(c.ctypes.data)
            stride.append(m if i in rows else 0)
        out_sizes = [int(np.prod(s)) for s in self.output_shapes]
        outs = [np.empty(n * w) for w in out_sizes]
        if n_threads is None:
            n_threads = _usable_cpus() if n >= THREAD_MIN_BATCH else 1
        nt = max(1, min(n_threads, n))
        chunk = n if nt == 1 else -(-n // (nt * BLOCKS_PER_THREAD))
        failed = calls.run_loop(lp.fn, n, base, stride, [o.ctypes.data for o in outs], out_sizes, lp.sz_iw, lp.sz_w,
                                nt, chunk=chunk, keep=(keep, outs), on_caller=True)
        if failed is not None:
            raise RuntimeError(f"{self.name}: evaluation of row {failed} failed")
        res = []
        for o, s in zip(outs, self.output_shapes):
            if len(s) == 2:  # each evaluation's matrix is column-major
                res.append(o.reshape(n, s[1], s[0]).transpose(0, 2, 1))
            else:
                res.append(o.reshape(n, *s))
        return res[0] if len(res) == 1 else tuple(res)


_DYN: dict[tuple[str, str], Dynamics] = {}


def dynamics(name: str, system=None, *, opts=None) -> Dynamics:
    """The plant function or Jacobian ``name`` as a NumPy function (see the module docstring).

    ``name``: one of ``vehicle_rhs``, ``arm_wrench``, ``uvms_rhs``, ``allocate``, ``thrust``,
    ``vehicle_rhs_jac``, ``uvms_rhs_jac``. ``system``: ``None`` (the default system, Haidou-1, with its packaged
    parameters), a shipped system's name, a system file, a System or Params: inputs are sized by it and
    ``p`` defaults to its parameters. ``opts``: :class:`arvcas.model.uvms.ModelOptions` (default
    ``ModelOptions()``).
    The first call of a name compiles it (or loads it from the build cache); the first batch of a
    name compiles its batch loop. Memoized per process.
    """
    from arvcas.model.uvms import ModelOptions

    if not isinstance(name, str) or name not in NAMES:
        raise ValueError(f"dynamics: unknown function {name!r}; allowed: {', '.join(NAMES)}")
    params = None
    if system is not None:
        from arvcas.system import resolve

        params = resolve(system).params
    opts = ModelOptions.checked(opts, "dynamics: opts")
    key = (name, opts.tag(), None if params is None else (params.structure, params.vector().tobytes()))
    with _LOCK:
        d = _DYN.get(key)
        if d is None:
            d = _DYN[key] = Dynamics(name, opts, params)
        return d
