"""Calling CasADi Functions on NumPy arrays without conversion copies.

``f(numpy_array)`` converts every input to a ``casadi.DM`` and every output back, element by
element: about 0.1 us per number, so 0.3 s for the run's 2.75-million-number time table, more than
the run itself. :func:`call` binds the arrays' memory directly (``Function.buffer``): inputs are read
in place when they are Fortran-ordered float64 (others are copied once by NumPy), outputs are
written into fresh Fortran-ordered arrays. Each thread keeps the buffers of the functions it called
last (creating one allocates the function's work memory).

:func:`call_many` evaluates a one-run function n times on a pool of threads: the buffer's evaluation
releases the GIL, each thread has its own buffer (its own work memory), inputs shared by all runs are
bound once and never copied, and each thread takes the next run when it finishes one, so a thread
slowed by another job on its core does not hold the others up. (CasADi's ``Function.map`` with
shared inputs repeats them n times in its work memory: the run's 36 MB time table times the
population.) A function whose library holds :func:`arvcas.build.codegen.batch_loop_c`'s loop (the
run functions) is evaluated by that loop instead: each thread makes one ``ctypes`` call that takes
the runs one at a time from a shared counter in C, reading and writing the arrays in place, so no
Python runs between two runs (with a 4 ms run, the interpreter's code is out of the caches by the
next one: 50 us per run measured) and no run's buffers are built.
"""

from __future__ import annotations

import ctypes
import itertools
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor

import casadi as ca
import numpy as np

__all__ = ["call", "call_many", "call_named", "fortran", "batch_loop", "run_loop", "total_memory", "check_memory",
           "real_array", "integer_array"]


def _typed(x, name: str, error: type[Exception], max_size: int | None = None) -> np.ndarray:
    """``x`` as an ndarray, refusing what NumPy would silently reinterpret: masked arrays (the mask would
    be dropped), and objects that are not numbers (strings, None, nested ragged lists); a sequence longer
    than ``max_size`` is refused before it is converted (``range(10**12)`` would take 8 TB)."""
    if max_size is not None and not isinstance(x, np.ndarray) and hasattr(x, "__len__"):
        try:
            n = len(x)
        except OverflowError:  # a range longer than sys.maxsize
            raise error(f"{name}: more values than the {max_size} allowed") from None
        if n > max_size:
            raise error(f"{name}: {n} values, more than the {max_size} allowed")
    if isinstance(x, np.ma.MaskedArray):
        raise error(f"{name}: a masked array is not accepted (its mask would be ignored); pass "
                    f"numpy.ma.filled(x, value) or the unmasked data")
    if isinstance(x, (str, bytes)):
        raise error(f"{name}: expected numbers, got a {type(x).__name__}")
    try:
        return np.asarray(x)
    except (ValueError, TypeError, OverflowError) as e:
        raise error(f"{name}: expected an array of numbers ({' '.join(str(e).split())})") from None


def real_array(x, name: str, error: type[Exception] = TypeError) -> np.ndarray:
    """``x`` as a float64 array if it is real numbers (integers or floats of any width); anything else is
    refused with one line naming ``name``: complex numbers (NumPy would drop the imaginary part),
    booleans, strings and other objects, masked arrays."""
    a = _typed(x, name, error)
    if a.dtype.kind in "iuf":
        return a.astype(float, copy=False)
    what = {"c": "complex numbers (the imaginary part would be dropped)", "b": "booleans",
            "U": "strings", "S": "bytes", "O": "Python objects", "M": "dates", "m": "time spans"}.get(a.dtype.kind,
                                                                                                      str(a.dtype))
    raise error(f"{name}: expected real numbers (float or integer), got {what}")


def integer_array(x, name: str, error: type[Exception] = TypeError, lo: int = 0, hi: int = 2**63,
                  max_size: int | None = None) -> np.ndarray:
    """``x`` as an int64 array if it is integers with ``lo <= v < hi`` (Python ints, NumPy integer arrays,
    a range); floats (even integral ones: 1e3 would be truncated silently elsewhere), booleans and
    everything :func:`real_array` refuses are refused with one line naming ``name``; so is a sequence of
    more than ``max_size`` values, before it is converted."""
    a = _typed(x, name, error, max_size)
    if a.dtype.kind == "O" and a.size and all(isinstance(v, int) and not isinstance(v, bool) for v in a.flat):
        if not all(lo <= v < hi for v in a.flat):
            raise error(f"{name}: every value must be an integer with {lo} <= v < {_power(hi)}")
        a = a.astype(np.int64)
    if a.dtype.kind not in "iu":
        kind = "booleans" if a.dtype.kind == "b" else ("floats" if a.dtype.kind == "f" else str(a.dtype))
        raise error(f"{name}: expected integers, got {kind}")
    if a.size and (a.min() < lo or (a.dtype.kind == "u" and int(a.max()) >= hi) or int(a.max()) >= hi):
        raise error(f"{name}: every value must be an integer with {lo} <= v < {_power(hi)}")
    return a.astype(np.int64, copy=False)


def _power(v: int) -> str:
    return f"2**{v.bit_length() - 1}" if v > 1 and v & (v - 1) == 0 else str(v)


def total_memory() -> int | None:
    """This machine's physical memory in bytes (None where the OS does not say)."""
    import os

    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError):  # pragma: no cover
        return None


def check_memory(what: str, n_bytes: float, share: float = 0.5, error: type[Exception] = ValueError,
                 total: int | None = None) -> None:
    """Refuse (``error``, one line) a request that would take more than ``share`` of this machine's
    memory (``total``, default :func:`total_memory`), before anything is allocated."""
    total = total_memory() if total is None else total
    if total is None:  # pragma: no cover
        return
    if n_bytes > share * total:
        raise error(f"{what}: would need about {n_bytes / 2**30:.3g} GiB, more than {share:.0%} of this "
                    f"machine's {total / 2**30:.3g} GiB; ask for less")


def fortran(a, shape: tuple[int, int]) -> np.ndarray:
    """``a`` as a Fortran-ordered float64 array of ``shape`` (a view when it already is one).

    A 1-D array or scalar fills a row or column vector of that many elements.
    """
    arr = np.asarray(a, dtype=float)
    if arr.shape != shape:
        if arr.ndim <= 1 and arr.size == shape[0] * shape[1] and 1 in shape:
            arr = arr.reshape(shape)
        else:
            raise ValueError(f"expected an array of shape {shape}, got {arr.shape}")
    return np.asfortranarray(arr)


_LOCAL = threading.local()
_KEEP = 16


def _buffer(f: ca.Function):
    cache = getattr(_LOCAL, "buffers", None)
    if cache is None:
        cache = _LOCAL.buffers = OrderedDict()
    hit = cache.get(id(f))
    if hit is not None and hit[0] is f:
        cache.move_to_end(id(f))
        return hit[1], hit[2]
    buf, evaluate = f.buffer()
    cache[id(f)] = (f, buf, evaluate)
    while len(cache) > _KEEP:
        cache.popitem(last=False)
    return buf, evaluate


def call(f: ca.Function, *args) -> list[np.ndarray]:
    """Evaluate ``f`` on dense inputs; returns its dense outputs as 2-D Fortran-ordered arrays."""
    return call_many(f, 1, args, per_run=())


_POOLS: dict[int, ThreadPoolExecutor] = {}
_POOLS_LOCK = threading.Lock()


def _pool(n_threads: int) -> ThreadPoolExecutor:
    """A pool of ``n_threads`` threads kept for the process: its threads keep their buffers between calls."""
    with _POOLS_LOCK:
        pool = _POOLS.get(n_threads)
        if pool is None:
            pool = _POOLS[n_threads] = ThreadPoolExecutor(n_threads, thread_name_prefix=f"arvcas-call{n_threads}")
        return pool


def _block_views(a: np.ndarray, n: int) -> list[memoryview]:
    """The n consecutive column blocks of a Fortran-ordered array, each as a flat memoryview (no copy)."""
    w = a.shape[1] // n
    return [memoryview(a[:, j * w:(j + 1) * w].reshape(-1, order="F")) for j in range(n)]


_LOOPS: dict[tuple, tuple] = {}  # (hash of a compiled Function, entry) -> (it, the entry point or None, library)
_LOOPS_LOCK = threading.Lock()


def batch_loop(f: ca.Function, entry: str = "_arvcas_batch"):
    """``<name>_arvcas_batch`` of ``f``'s library (:func:`arvcas.build.codegen.batch_loop_c`) as a
    ``ctypes`` function, or None when the library has none (or ``f`` is not compiled). ``entry``:
    another loop of the same signature (``_arvcas_lanes``: :mod:`arvcas.sim.lockstep`'s)."""
    h = (f.__hash__(), entry)
    with _LOOPS_LOCK:
        hit = _LOOPS.get(h)
        if hit is not None and hit[0] is f:
            return hit[1]
    from arvcas.build import codegen

    fn = lib = None
    path = (codegen.artifact_of(f) or {}).get("path")
    if path:
        try:
            lib = ctypes.CDLL(path)  # the file CasADi loaded: the same handle
            fn = getattr(lib, f"{f.name()}{entry}")
        except (OSError, AttributeError):
            fn = None
        else:
            fn.argtypes = [ctypes.c_longlong, ctypes.c_longlong] + [ctypes.c_void_p] * 9
            fn.restype = ctypes.c_int
    with _LOOPS_LOCK:
        _LOOPS[h] = (f, fn, lib)
    return fn


def _work_arrays(niw: int, nw: int) -> tuple[np.ndarray, np.ndarray]:
    """This thread's work arrays, at least ``niw`` integers and ``nw`` reals (the largest asked for
    so far; pages a function does not touch are never committed)."""
    niw, nw = max(1, niw), max(1, nw)
    have = getattr(_LOCAL, "work", None)
    if have is None or have[0].size < niw or have[1].size < nw:
        have = _LOCAL.work = (np.empty(max(niw, have[0].size if have else 0), dtype=np.int64),
                              np.empty(max(nw, have[1].size if have else 0)))
    return have


def run_loop(loop, n: int, a_ptrs, sa, r_ptrs, sr, sz_iw: int, sz_w: int, n_threads: int, chunk: int = 1,
             keep=(), on_caller: bool = False) -> int | None:
    """``n`` evaluations through a library's :func:`arvcas.build.codegen.batch_loop_c` loop: each of
    ``n_threads`` threads makes one ``ctypes`` call (the GIL released) that takes ``chunk`` evaluations
    at a time from a shared counter. ``a_ptrs``/``r_ptrs``: the inputs' and outputs' addresses,
    ``sa``/``sr`` their strides per evaluation in elements (0: shared); ``keep``: the objects behind
    them, held until every call has returned. ``on_caller``: one thread runs on the calling thread
    (no hand-over; an interrupt then waits for the whole loop), else the pool's threads run while the
    caller waits, and an interrupt stops each after its current chunk. Returns the index of a failed
    evaluation, or None."""
    A = (ctypes.c_void_p * max(1, len(a_ptrs)))(*a_ptrs)
    SA = (ctypes.c_longlong * max(1, len(sa)))(*sa)
    R = (ctypes.c_void_p * max(1, len(r_ptrs)))(*r_ptrs)
    SR = (ctypes.c_longlong * max(1, len(sr)))(*sr)
    state = np.zeros(3, dtype=np.int64)  # next evaluation, stop flag (its low 32 bits), the failed one
    state[2] = -1
    base = state.ctypes.data
    held = (keep, A, SA, R, SR, state)

    def work(held=held) -> int:  # the pool holds this call, and so everything it points to, until it returns
        iw, w = _work_arrays(sz_iw, sz_w)
        return loop(n, chunk, base, base + 8, base + 16, A, SA, R, SR, iw.ctypes.data, w.ctypes.data)

    nt = max(1, min(int(n_threads), -(-n // chunk)))
    if nt == 1 and on_caller:
        rcs = [work()]
    else:
        futs = [_pool(nt).submit(work) for _ in range(nt)]
        try:
            rcs = [fut.result() for fut in futs]
        finally:  # an interrupt: each thread stops after the chunk it is in
            state[1] = 1
    return int(state[2]) if any(rcs) else None


def _call_loop(f: ca.Function, loop, n: int, bound, per_run, outs, n_threads: int) -> None:
    """``call_many`` through the library's own loop, one run at a time from the shared counter."""
    failed = run_loop(loop, n, [a.ctypes.data for a in bound],
                      [f.sparsity_in(i).nnz() if i in per_run else 0 for i in range(f.n_in())],
                      [r.ctypes.data for r in outs], [f.sparsity_out(i).nnz() for i in range(f.n_out())],
                      int(f.sz_iw()), int(f.sz_w()), n_threads, keep=(bound, outs))
    if failed is not None:
        raise RuntimeError(f"{f.name()}: evaluation {failed} of {n} failed (return code 1)")


def call_many(f: ca.Function, n: int, args, per_run, n_threads: int = 1) -> list[np.ndarray]:
    """Evaluate ``f`` n times: run j reads column block j of the inputs listed in ``per_run``.

    An input i in ``per_run`` is an array of shape ``(size1_in(i), n * size2_in(i))``; any other input
    is passed as ``call`` takes it and shared by all runs. Output i is returned as
    ``(size1_out(i), n * size2_out(i))``, run j in column block j. ``n_threads`` threads (at most n)
    take the runs one at a time; results do not depend on it.
    """
    if len(args) != f.n_in():
        raise ValueError(f"{f.name()}: expected {f.n_in()} inputs, got {len(args)}")
    if n < 1:
        raise ValueError(f"{f.name()}: n must be a positive integer, got {n!r}")
    per_run = frozenset(per_run)
    loop = batch_loop(f)
    bound, blocks = [], {}
    for i, a in enumerate(args):
        sp = f.sparsity_in(i)
        if not sp.is_dense():
            raise ValueError(f"{f.name()}: input {f.name_in(i)} is sparse; takes dense inputs only")
        if i in per_run:
            arr = fortran(a, (sp.size1(), n * sp.size2()))
            if loop is None:
                blocks[i] = _block_views(arr, n)
        else:
            arr = fortran(a, (sp.size1(), sp.size2()))
        bound.append(arr)
    outs, out_blocks = [], []
    for i in range(f.n_out()):
        sp = f.sparsity_out(i)
        if not sp.is_dense():
            raise ValueError(f"{f.name()}: output {f.name_out(i)} is sparse; gives dense outputs only")
        r = np.empty((sp.size1(), n * sp.size2()), order="F")
        outs.append(r)
        if loop is None:
            out_blocks.append(_block_views(r, n))
    if loop is not None:
        _call_loop(f, loop, n, bound, per_run, outs, n_threads)
        return outs
    shared = [(i, memoryview(a.reshape(-1, order="F"))) for i, a in enumerate(bound) if i not in per_run]
    todo = itertools.count()  # next() on a count is atomic under the GIL
    stop = threading.Event()
    errors: list[str] = []

    def work():
        buf, evaluate = _buffer(f)
        for i, m in shared:
            buf.set_arg(i, m)
        while not stop.is_set():
            j = next(todo)
            if j >= n:
                return
            for i, b in blocks.items():
                buf.set_arg(i, b[j])
            for i, b in enumerate(out_blocks):
                buf.set_res(i, b[j])
            evaluate()
            if buf.ret() != 0:
                errors.append(f"{f.name()}: evaluation {j} of {n} failed (return code {buf.ret()})")
                stop.set()

    nt = max(1, min(int(n_threads), n))
    if nt == 1:
        work()
    else:
        pool = _pool(int(n_threads))  # one pool per thread count, so its threads' buffers stay warm
        try:
            for fut in [pool.submit(work) for _ in range(nt)]:
                fut.result()
        finally:  # an interrupt: the threads stop after the run they are in
            stop.set()
    if errors:
        raise RuntimeError(errors[0])
    return outs


def call_named(f: ca.Function, inputs: dict, n: int = 1, per_run=(), n_threads: int = 1) -> dict[str, np.ndarray]:
    """:func:`call_many` with the inputs bound by name (``f.name_in()``) and the outputs returned by name.

    ``per_run``: names of the inputs with a column block per run. Every input must be given once.
    """
    names = list(f.name_in())
    unknown = sorted(set(inputs) - set(names))
    missing = [k for k in names if k not in inputs]
    if unknown or missing:
        raise ValueError(f"{f.name()}: inputs {names}; unknown {unknown}, missing {missing}")
    bad = sorted(set(per_run) - set(names))
    if bad:
        raise ValueError(f"{f.name()}: per_run names {bad} are not inputs of {names}")
    idx = [f.index_in(k) for k in per_run]
    outs = call_many(f, n, [inputs[k] for k in names], per_run=idx, n_threads=n_threads)
    return dict(zip(f.name_out(), outs))
