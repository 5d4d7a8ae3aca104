"""Generate -> hash -> compile -> cache -> load: the only place in arvcas that runs a C compiler.

A CasADi Function is turned into C with :class:`casadi.CodeGenerator`, compiled to a shared library
with ``cc`` and loaded with :func:`casadi.external`. Builds are cached between processes
(STYLE rule 4):

* **keyed by content**: key = sha256 over (generated C text, ``cc --version`` first line, full
  compiler flag list, CasADi version, arvcas version). The C symbol names are prefixed by the
  function's name (CasADi's ``CASADI_PREFIX``), so several libraries live in one process. A described
  build (:func:`build_described`) finds its library by a manifest of its description that names this
  key: descriptions that give the same C share one library, compiled once.
* **verified**: an artifact ``<cache>/<name>-<key[:20]>.so`` is loaded only if its manifest
  ``<name>-<key[:20]>.json`` exists, holds the same key, and the sha256 of the ``.so`` bytes matches
  the manifest. A truncated, tampered or foreign file is rebuilt, never loaded.
* **what it computes**: the manifest also holds ``c_sha256``, the sha256 of the function's own
  generated C (the same text in every process: no path, time or version in it). :func:`described_digest`
  answers it from the manifest without a compile, or from the graph's C when the cache lacks it; a
  result records it to say which computation made it (docs/provenance.md).
* **written atomically**: each build happens in a temporary directory inside the cache, then
  ``os.replace`` publishes the ``.so`` and, last, the manifest.
* **locked**: an ``fcntl.flock`` lock file per key (exclusive to build, shared to verify and load),
  so two processes building the same function at once compile it once and both succeed. Waiting is
  bounded: on timeout, and in a cache that cannot be written (read-only), the function is built
  privately in a directory of this process outside the cache (:func:`arvcas.util.files.private_dir`,
  in the system's temporary directory) and not published.

Generating C for ``uvms_rhs`` (6-9k instructions) takes 15-40 ms: a few per cent of compiling it
(0.3 s at -O0, 1-2 s at -O2) and less than building its SX graph, which a cache hit in a new process
pays anyway. So :func:`build` has no cheaper first-level key (a per-process memo makes a repeated
:func:`build` of the same Function object a dictionary lookup); a description is one, for a caller that
can name what shapes its graph.

**Progress**: a build (graph, C and compiler) that takes more than :data:`PROGRESS_AFTER_S` writes one
line to the stream :func:`report_progress` set (the command line sets standard error):
``arvcas: compiling the run for bluerov2_heavy_alpha5 / proposed ... 6.8 s``. Cache hits are silent.

``opt_level`` left out (None) is :func:`default_opt_level`: ``ARVCAS_OPT_LEVEL`` when set (the tests set ``-O0``,
docs/testing.md), else :data:`DEFAULT_OPT_LEVEL`.

Besides ``opt_level`` and ``flags``, ``-ffp-contract=off -fno-math-errno`` is always passed: GCC contracts ``a*b+c``
into FMA by default wherever the target has FMA (aarch64, ``-march=native``), which changes the last
bits against CasADi's VM and between machines. Flags that change the numbers (``-Ofast``,
``-ffast-math`` and its parts) are refused. On an x86-64 CPU with AVX, ``-mavx`` is added
(:func:`isa_flags`; ``ARVCAS_ISA=baseline`` leaves it out): the same numbers, faster code. A bundle
shipped to a Dask worker records it, and a worker whose CPU lacks it refuses the bundle by name.
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import functools
import hashlib
import json
import logging
import os
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import casadi as ca

from arvcas.build.batchloop import batch_loop_c
from arvcas.build.progress import PROGRESS_AFTER_S, Progress as _Progress, report_progress  # noqa: F401 (re-exported)
from arvcas.util.files import check_signals, private_dir

__all__ = [
    "build_described",
    "isa_flags",
    "batch_loop_c",
    "supported_isa",
    "CacheError",
    "CompileError",
    "Artifact",
    "cache_dir",
    "default_opt_level",
    "build",
    "artifact_of",
    "cache_info",
    "stats",
    "report_progress",
]

log = logging.getLogger(__name__)

CC = "cc"
BASE_FLAGS = ("-shared", "-fPIC")
# no FMA contraction: same numbers on every target; -fno-math-errno only lets sqrt inline (libm's
# errno is never read here): results stay bitwise identical, about 6 % faster on the closed loop.
# CasADi's generated helpers (casadi_sq, casadi_copy, the sub-functions) are global symbols, so in a
# -fPIC library every call to them may be interposed and is never inlined; -fno-semantic-interposition
# with -finline-small-functions (part of -O2, not of -O1) inlines them: bitwise identical results,
# the closed loop about 20 % faster (measured 32.1 -> 25.8 ms per run).
# -O2 since the EKF moved onto its triangle: with it and the peeled first sample, results/bench.md's
# opt sweep recommends it (the rule there: within 8 % of the fastest, then the fastest to compile);
# measured alternately in one process on the 100 s run: -O1 4.95 ms, -O2 4.76 ms, -O3 4.73 ms, every
# output bitwise equal (-ffp-contract=off: no level changes a result); it compiles about 1.4x longer.
DEFAULT_OPT_LEVEL = "-O2"
# ARVCAS_OPT_LEVEL: the level of every build that names none (tests/conftest.py sets -O0: a run compiles about 4x
# faster, runs about 3x slower, computes the same bits); :func:`default_opt_level`
OPT_LEVEL_ENV = "ARVCAS_OPT_LEVEL"
OPT_LEVELS = ("-O0", "-O1", "-O2", "-O3", "-Os", "-Og")
FIXED_FLAGS = ("-ffp-contract=off", "-fno-math-errno", "-fno-semantic-interposition", "-finline-small-functions")
LIBS = ("-lm",)
# The instruction set, for the libraries this machine builds and loads (not for export-c's Makefile
# nor the FMU's binary, which other machines run): on an x86-64 CPU with AVX, ``-mavx``, the VEX
# encoding of the same scalar double operations. Results stay bitwise identical (every committed
# result and a run's every output compared to the bit); the 100 s closed-loop run took 4.1 ms
# instead of 5.4 ms on an Intel Xeon (2026-12-02, alternating builds in one session). Not -march=...
# nor -mavx512f: they enable FMA, and with it the run's last bits changed even under -ffp-contract=off.
# ARVCAS_ISA=baseline builds without it (a cache built so is keyed apart: the flags are in the key).
ISA_FLAGS = {"avx": ("-mavx",)}
ISA_ENV = "ARVCAS_ISA"
FORBIDDEN_FLAGS = (
    "-Ofast",
    "-ffast-math",
    "-funsafe-math-optimizations",
    "-fassociative-math",
    "-freciprocal-math",
    "-ffinite-math-only",
    "-fno-signed-zeros",
    "-ffp-contract=fast",
    "-ffp-contract=on",
)
LOCK_TIMEOUT_S = 300.0  # longest wait for another process's build of the same key
COMPILE_TIMEOUT_S = 1800.0
MANIFEST_FORMAT = 1
_STALE_TMP_S = 24 * 3600.0
_CODEGEN_OPTS = {"casadi_real": "double", "casadi_int": "long long int", "with_header": False}


class CacheError(ValueError):
    """The build cache cannot be used safely (one line, saying how to fix it)."""


class CompileError(ValueError):
    """The C compiler is missing or failed (one line; the log path is in the message)."""


@dataclass(frozen=True)
class Artifact:
    """One cached library, as listed by :func:`cache_info`."""

    name: str
    path: Path
    size_bytes: int
    compile_time_s: float
    flags: tuple[str, ...]
    key: str
    verified: bool  # manifest present, key consistent, .so sha256 matches


# ---------------------------------------------------------------------------------------------
# process state

_LOCK = threading.RLock()
_MEMO: dict[tuple, tuple[ca.Function, ca.Function]] = {}  # (fn identity, flags, dir) -> (fn, lib)
_MANIFESTS: dict[int, dict] = {}  # hash of a returned external Function -> its manifest
_KEEP: list[ca.Function] = []  # keeps returned Functions alive so _MANIFESTS keys stay unique
_STATS: Counter = Counter()
_PRIVATE_DIRS: list[Path] = []


def stats() -> dict[str, int]:
    """Counters of this process: ``compile``, ``disk_hit``, ``memo_hit``, ``private``, ``rejected``."""
    with _LOCK:
        return {k: _STATS[k] for k in ("compile", "disk_hit", "memo_hit", "private", "rejected")}


# ---------------------------------------------------------------------------------------------
# cache directory


def _cache_path() -> Path:
    """Where the cache is, from the environment (no checks, no disk access)."""
    env = os.environ.get("ARVCAS_CACHE")
    if env:
        d = Path(env).expanduser()
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        base = Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache"
        d = base / "arvcas"
    return Path(os.path.abspath(d))


def cache_dir() -> Path:
    """The build cache: ``$ARVCAS_CACHE``, else ``$XDG_CACHE_HOME/arvcas`` or ``~/.cache/arvcas``.

    Created with mode 0o700. Raises :class:`CacheError` if it is not a directory, not owned by the
    current user, or writable by group or others (anyone who can write there could plant code that
    this process would then load).
    """
    d = _cache_path()
    try:
        d.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = os.stat(d)
    except OSError as e:
        raise CacheError(
            f"cannot create cache directory {d} ({e.strerror}); set ARVCAS_CACHE to a writable directory"
        ) from None
    if not stat.S_ISDIR(st.st_mode):
        raise CacheError(f"cache path {d} is not a directory; set ARVCAS_CACHE to a directory")
    if st.st_uid != os.geteuid():
        raise CacheError(
            f"cache directory {d} is owned by uid {st.st_uid}, not by you; set ARVCAS_CACHE to a directory of your own"
        )
    if st.st_mode & 0o022:
        raise CacheError(
            f"cache directory {d} is writable by group or others (mode {stat.S_IMODE(st.st_mode):o}); "
            f"fix it with: chmod go-w {d}"
        )
    return d


# ---------------------------------------------------------------------------------------------
# flags, compiler, key


def default_opt_level() -> str:
    """The optimisation level of a build that names none: ``ARVCAS_OPT_LEVEL`` when it is set, else
    :data:`DEFAULT_OPT_LEVEL`. No level changes a result (``-ffp-contract=off``): ``-O0`` only trades run speed
    (about 3x slower) for compile time (about 4x shorter; results/bench.md's opt sweep)."""
    v = os.environ.get(OPT_LEVEL_ENV, "").strip()
    if not v:
        return DEFAULT_OPT_LEVEL
    if v not in OPT_LEVELS:
        raise ValueError(f"{OPT_LEVEL_ENV}={v!r}: expected one of {', '.join(OPT_LEVELS)} (or unset: {DEFAULT_OPT_LEVEL})")
    return v


def _check_flags(opt_level: str | None, flags) -> list[str]:
    if opt_level is None:
        opt_level = default_opt_level()
    if isinstance(flags, str) or not isinstance(flags, (tuple, list)):
        raise ValueError(f"flags: expected a tuple of strings, got {flags!r}")
    if not isinstance(opt_level, str) or not opt_level.startswith("-O"):
        raise ValueError(f"opt_level: expected -O0, -O1, -O2, -O3, -Os or -Og, got {opt_level!r}")
    for f in (opt_level, *flags):
        if not isinstance(f, str) or not f.strip():
            raise ValueError(f"flags: every flag must be a non-empty string, got {f!r}")
        if f.startswith("-Ofast") or f in FORBIDDEN_FLAGS:
            raise ValueError(f"compiler flag {f} changes the numbers (no IEEE semantics); use -O0..-O3")
    return [*BASE_FLAGS, opt_level, *FIXED_FLAGS, *isa_flags(), *flags, *LIBS]  # LIBS last: _compile relies on it


def _cpu_flags() -> frozenset[str]:
    """The CPU's feature flags as Linux reports them (the kernel drops those the OS cannot use)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("flags"):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return frozenset()


@functools.lru_cache(maxsize=None)
def supported_isa() -> tuple[str, ...]:
    """The instruction-set flags this machine can run (of :data:`ISA_FLAGS`), whatever ARVCAS_ISA says."""
    import platform as _pf

    if sys.platform != "linux" or _pf.machine() not in ("x86_64", "AMD64"):
        return ()
    cpu = _cpu_flags()
    return tuple(f for feature, fl in ISA_FLAGS.items() if feature in cpu for f in fl)


def isa_flags() -> tuple[str, ...]:
    """The instruction-set flags of this process's builds: :func:`supported_isa`, or none with ARVCAS_ISA=baseline."""
    mode = os.environ.get(ISA_ENV, "auto")
    if mode == "baseline":
        return ()
    if mode != "auto":
        raise CacheError(f"{ISA_ENV}={mode!r}: expected 'auto' (the default: what this CPU runs) or 'baseline'")
    return supported_isa()


_CC_ID: dict[str, str] = {}


def _compiler_id() -> str:
    """First line of ``cc --version`` (memoized per process)."""
    with _LOCK:
        if CC not in _CC_ID:
            try:
                r = subprocess.run([CC, "--version"], capture_output=True, text=True, timeout=60)
            except FileNotFoundError:
                raise CompileError(f"C compiler '{CC}' not found on PATH; install gcc or clang") from None
            except subprocess.TimeoutExpired:
                raise CompileError(f"'{CC} --version' did not answer within 60 s") from None
            lines = r.stdout.strip().splitlines()
            if r.returncode != 0 or not lines:
                raise CompileError(f"'{CC} --version' failed (exit {r.returncode})")
            _CC_ID[CC] = lines[0].strip()
        return _CC_ID[CC]


def _key(c_text: str, compiler: str, cmd_flags: list[str]) -> str:
    from arvcas._version import __version__ as arvcas_version

    h = hashlib.sha256()
    for part in ("arvcas-build-1", c_text, compiler, "\0".join(cmd_flags), ca.__version__, arvcas_version):
        b = part.encode()
        h.update(len(b).to_bytes(8, "little"))
        h.update(b)
    return h.hexdigest()


@dataclass(frozen=True)
class _Plan:
    name: str
    n_instructions: int
    c_text: str
    codegen_s: float
    compiler: str
    cmd_flags: tuple[str, ...]
    key: str
    c_sha256: str = ""  # of the function's own generated C (without extra_c): what it computes

    def stem(self) -> str:
        return f"{self.name}-{self.key[:20]}"


def _c_text(fn: ca.Function) -> str:
    """CasADi's C for ``fn`` (its symbols prefixed by its name): the same text in every process."""
    cg = ca.CodeGenerator(fn.name(), _CODEGEN_OPTS)  # CASADI_PREFIX(ID) = <name>_ID: symbols prefixed by name
    cg.add(fn)
    return cg.dump()


def _plan(fn: ca.Function, cmd_flags: list[str], extra_c: str = "") -> _Plan:
    name = fn.name()
    if not name.isidentifier() or not name.isascii():
        raise ValueError(f"function name {name!r} is not a C identifier")
    t0 = time.perf_counter()
    own = _c_text(fn)
    text = own + extra_c
    codegen_s = time.perf_counter() - t0
    try:
        n_ins = int(fn.n_instructions())
    except RuntimeError:  # not an SX/MX Function
        n_ins = -1
    compiler = _compiler_id()
    return _Plan(name, n_ins, text, codegen_s, compiler, tuple(cmd_flags), _key(text, compiler, cmd_flags),
                 hashlib.sha256(own.encode()).hexdigest())


# ---------------------------------------------------------------------------------------------
# locking, verification, building


@contextlib.contextmanager
def _flock(path: Path, exclusive: bool, timeout: float) -> Iterator[bool | None]:
    """Hold an flock on ``path``; yields False if it could not be had within ``timeout`` seconds, and
    None if the lock file cannot be opened at all (a read-only cache)."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    except OSError:
        yield None
        return
    try:
        op = (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB
        deadline = time.monotonic() + timeout
        pause = 0.005
        while True:
            try:
                fcntl.flock(fd, op)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    yield False
                    return
                time.sleep(pause)
                pause = min(2 * pause, 0.2)
        try:
            yield True
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _verify(plan, so: Path, man: Path) -> tuple[dict | None, str]:
    """(manifest, "") if the artifact may be loaded, else (None, reason); reason "" means absent.

    ``plan`` needs only ``name`` and ``key`` (a :class:`_Plan`, or a :class:`_Lookup` before any graph exists)."""
    if not so.exists() and not man.exists():
        return None, ""
    try:
        m = json.loads(man.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None, "no manifest"
    except (OSError, ValueError) as e:
        return None, f"unreadable manifest ({e})"
    if not isinstance(m, dict) or m.get("key") != plan.key or m.get("name") != plan.name:
        return None, "manifest does not match the key"
    try:
        st = os.lstat(so)
    except FileNotFoundError:
        return None, "no library"
    if not stat.S_ISREG(st.st_mode):
        return None, "library is not a regular file"
    if st.st_uid != os.geteuid() or st.st_mode & 0o022:
        return None, "library is writable by others or not owned by you"
    if _sha256_file(so) != m.get("so_sha256"):
        return None, "library sha256 does not match the manifest"
    return m, ""


def run_compiler(cmd: list[str], work: Path, name: str) -> subprocess.CompletedProcess:
    """Run the compiler in its own process group; on any interruption (an exception, KeyboardInterrupt,
    the SystemExit a SIGTERM handler raises, a timeout) the whole group (cc, cc1, as, ld) is killed
    and reaped before the exception goes on, so no compiler outlives the build."""
    check_signals()  # a signal that came while the graph was built, its exception swallowed: no compile
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=work,
                                start_new_session=True)
    except FileNotFoundError:
        raise CompileError(f"C compiler '{CC}' not found on PATH; install gcc or clang") from None
    try:
        out, err = proc.communicate(timeout=COMPILE_TIMEOUT_S)
    except BaseException as e:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        if isinstance(e, subprocess.TimeoutExpired):
            raise CompileError(f"compiling {name} took longer than {COMPILE_TIMEOUT_S:.0f} s") from None
        raise
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def _compile(plan: _Plan, work: Path) -> tuple[Path, float]:
    src = work / f"{plan.name}.c"
    out = work / f"{plan.name}.so"
    src.write_text(plan.c_text, encoding="utf-8")
    compile_flags = plan.cmd_flags[: len(plan.cmd_flags) - len(LIBS)]
    cmd = [CC, *compile_flags, "-o", str(out), str(src), *LIBS]
    log.info("compiling %s (%d instructions) with %s %s ...", plan.name, plan.n_instructions, CC, " ".join(compile_flags))
    t0 = time.perf_counter()
    r = run_compiler(cmd, work, plan.name)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        first = next((ln for ln in r.stderr.splitlines() if "error" in ln), r.stderr.strip()[:200])
        raise CompileError(f"{CC} failed compiling {plan.name} (exit {r.returncode}): {first.strip()}")
    os.chmod(out, 0o755)
    with _LOCK:
        _STATS["compile"] += 1
    log.info("compiling %s (%d instructions) ... done in %.2f s", plan.name, plan.n_instructions, dt)
    return out, dt


def _manifest(plan: _Plan, so_sha256: str, compile_s: float) -> dict:
    from arvcas._version import __version__ as arvcas_version

    return {
        "format": MANIFEST_FORMAT,
        "name": plan.name,
        "key": plan.key,
        "so_sha256": so_sha256,
        "c_sha256": plan.c_sha256,
        "flags": list(plan.cmd_flags),
        "compiler": plan.compiler,
        "compile_time_s": round(compile_s, 4),
        "codegen_time_s": round(plan.codegen_s, 4),
        "n_instructions": plan.n_instructions,
        "casadi_version": ca.__version__,
        "arvcas_version": arvcas_version,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _publish(plan: _Plan, d: Path, so: Path, man: Path) -> dict:
    work = Path(tempfile.mkdtemp(prefix=".build-", dir=d))
    try:
        out, dt = _compile(plan, work)
        m = _manifest(plan, _sha256_file(out), dt)
        tmp_man = work / "manifest.json"
        tmp_man.write_text(json.dumps(m, indent=1) + "\n", encoding="utf-8")
        os.chmod(tmp_man, 0o644)
        os.replace(out, so)
        os.replace(tmp_man, man)  # manifest last: a reader never sees a manifest for a missing .so
        return m
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _build_private(plan: _Plan, d: Path) -> ca.Function:
    """Build in a directory of this process outside the cache ``d`` (which may be read-only)."""
    work = private_dir("build")
    with _LOCK:
        if not _PRIVATE_DIRS:
            atexit.register(_remove_private_dirs)
        _PRIVATE_DIRS.append(work)
        _STATS["private"] += 1
    out, dt = _compile(plan, work)
    return _load(plan, out, _manifest(plan, _sha256_file(out), dt) | {"private": True})


def _remove_private_dirs() -> None:
    for p in _PRIVATE_DIRS:
        shutil.rmtree(p, ignore_errors=True)


def _sweep(d: Path) -> None:
    """Remove build directories left by crashed processes (older than a day)."""
    now = time.time()
    try:
        entries = list(os.scandir(d))
    except OSError:
        return
    for e in entries:
        if e.name.startswith((".build-", ".private-")) and e.is_dir(follow_symlinks=False):
            try:
                if now - e.stat(follow_symlinks=False).st_mtime > _STALE_TMP_S:
                    shutil.rmtree(e.path, ignore_errors=True)
            except OSError:
                pass


class _LoadFailed(CacheError):
    """A library that does not load (not a library, another ABI): a cached one that verified against its
    manifest (tampered with and re-signed) is rebuilt; anywhere else this one line is the error."""


def _load(plan, so: Path, manifest: dict) -> ca.Function:
    try:
        f = ca.external(plan.name, str(so))
    except RuntimeError as e:
        first = next((ln.strip() for ln in str(e).splitlines() if ln.strip()), type(e).__name__)
        raise _LoadFailed(f"{so} does not load ({first[:160]})") from None
    with _LOCK:
        _KEEP.append(f)
        _MANIFESTS[f.__hash__()] = dict(manifest, path=str(so))
    return f


def build(
    fn: ca.Function,
    *,
    opt_level: str | None = None,
    flags: tuple[str, ...] = (),
    lock_timeout: float = LOCK_TIMEOUT_S,
    extra_c: str = "",
) -> ca.Function:
    """``fn`` compiled to C and loaded with :func:`casadi.external` (same name, inputs, outputs).

    ``opt_level`` is passed to ``cc`` as is (``-O0``..``-O3``, ``-Os``, ``-Og``; None: :func:`default_opt_level`),
    then ``flags``.
    ``extra_c``: C source appended to the generated file (part of the cache key), e.g. a loop over
    ``fn`` that other code calls from the same library (:mod:`arvcas.build.dynamics`).
    Raises ValueError for ``-Ofast``/``-ffast-math`` and kin, :class:`CacheError` for an unsafe cache
    directory, :class:`CompileError` if ``cc`` is missing or fails.
    """
    if not isinstance(fn, ca.Function):
        raise TypeError(f"build: expected a casadi.Function, got {type(fn).__name__}")
    cmd_flags = _check_flags(opt_level, flags)
    if not isinstance(extra_c, str):
        raise TypeError(f"build: extra_c: expected C source text, got {type(extra_c).__name__}")
    mkey = (fn.__hash__(), fn.name(), tuple(cmd_flags), str(_cache_path()), extra_c)
    with _LOCK:
        hit = _MEMO.get(mkey)
        if hit is not None:  # already loaded in this process: no disk access at all
            _STATS["memo_hit"] += 1
            return hit[1]
        f = _build(fn, cmd_flags, cache_dir(), lock_timeout, extra_c)
        _MEMO[mkey] = (fn, f)  # holding fn keeps its identity from being reused
        return f


def _build(fn: ca.Function, cmd_flags: list[str], d: Path, lock_timeout: float, extra_c: str = "") -> ca.Function:
    plan = _plan(fn, cmd_flags, extra_c)
    return _lookup_or_publish(plan, lambda: plan, d, lock_timeout, plan.name)


def _hit(look, so: Path, man: Path) -> tuple[ca.Function | None, str, str]:
    """(the loaded artifact, "", "") if it verifies and loads; else (None, why it does not verify, why it
    does not load)."""
    m, why = _verify(look, so, man)
    if m is None:
        return None, why, ""
    try:
        f = _load(look, so, m)
    except _LoadFailed as e:
        return None, "", str(e)
    _STATS["disk_hit"] += 1
    return f, "", ""


def _lookup_or_publish(look, make_plan: Callable[[], "_Plan"], d: Path, lock_timeout: float,
                       label: str | None = "") -> ca.Function:
    """Load the verified artifact of ``look`` (name, key), else build it (``make_plan()``) and publish it.

    A cache whose lock files cannot be created (read-only) still serves verified artifacts: the
    ``.so`` is checked against its manifest's sha256 and published by ``os.replace``, so loading
    without the lock is safe; a build there is private (a temporary directory, not published).
    ``label`` None: no progress line (the caller shows one).
    """
    so, man, lock = d / f"{look.stem()}.so", d / f"{look.stem()}.json", d / f"{look.stem()}.lock"
    unloadable = ""  # a verified library that did not load (tampered and re-signed, or foreign): rebuilt
    with _flock(lock, exclusive=False, timeout=lock_timeout) as got:
        if got or got is None:
            f, why, unloadable = _hit(look, so, man)
            if f is not None:
                return f
    what = label or look.name
    line = _Progress if label is not None else (lambda _what: contextlib.nullcontext())
    with _flock(lock, exclusive=True, timeout=lock_timeout) as got:
        if got is None:
            log.info("cache %s is not writable: building %s privately", d, look.name)
            with line(what):
                return _build_private(make_plan(), d)
        if not got:
            log.warning("lock %s busy for %.0f s: building %s privately", lock, lock_timeout, look.name)
            with line(what):
                return _build_private(make_plan(), d)
        if not unloadable:  # another process may have built it meanwhile
            f, why, unloadable = _hit(look, so, man)
            if f is not None:
                return f
        why = unloadable or why
        if why:
            _STATS["rejected"] += 1
            log.warning("cached %s rejected (%s): rebuilding", so.name, why)
        _sweep(d)
        with line(what):
            plan = make_plan()
            m = _publish(plan, d, so, man)
        return _load(plan, so, m)


@dataclass(frozen=True)
class _Lookup:
    """What a cache lookup needs before any graph exists: the function's name and its key."""

    name: str
    key: str

    def stem(self) -> str:
        return f"{self.name}-{self.key[:20]}"


_DESCRIBED: dict[tuple, ca.Function] = {}


def build_described(
    name: str,
    description: str,
    make: Callable[[], ca.Function],
    *,
    opt_level: str | None = None,
    flags: tuple[str, ...] = (),
    lock_timeout: float = LOCK_TIMEOUT_S,
    batch_loop: bool = False,
    label: str = "",
    extra_c: Callable[[ca.Function], str] | None = None,
) -> ca.Function:
    """The compiled function ``name`` described by ``description``, built by ``make()`` only on a miss.

    Two keys. The library is the one :func:`build` makes of the same C (keyed by the C, the compiler,
    the flags, CasADi's and arvcas's versions), so descriptions that give the same C share one
    library. A description finds it without building the CasADi graph (a warm start): its key is
    sha256 over (``description``, :func:`arvcas.build.provenance.model_hash` — the package's model,
    simulation, controller and codegen code and its data —, the compiler, the flags), and its
    manifest names the C's key; on a miss ``make()`` builds the graph, its C is generated (cheap
    beside compiling) and compiled only if no library of that C is cached. ``description`` must name
    everything else that shapes the graph (the caller's options, scenario fields, a user controller's
    own source). ``make()`` must return a Function called ``name``. Memoized per process. ``batch_loop``:
    the library also holds :func:`batch_loop_c`'s loops (part of the key), which
    :func:`arvcas.build.calls.call_many` uses.
    ``label``: what the progress line calls the build ("the run for haidou1 / proposed"; default ``name``).
    ``extra_c``: called with ``make()``'s Function after it, returns C appended to the library (e.g. a
    lockstep loop, :mod:`arvcas.sim.lockstep`); ``description`` must say what it holds.
    """
    cmd_flags, description, ident = _described(name, description, opt_level, flags, batch_loop)
    with _LOCK:
        f = _PRELOADED.get(ident)  # shipped by a client (a Dask worker): no compiler needed
        if f is not None:
            _STATS["memo_hit"] += 1
            return f
    key = _described_key(name, description, cmd_flags)
    mkey = (name, key, str(_cache_path()))
    with _LOCK:
        f = _DESCRIBED.get(mkey)
        if f is not None:
            _STATS["memo_hit"] += 1
            return f

        def make_plan() -> _Plan:
            with _LOCK:
                made = _MADE.pop(key, None)
            fn = made if made is not None else make()
            if not isinstance(fn, ca.Function) or fn.name() != name:
                raise TypeError(f"build_described: make() must return a casadi.Function named {name!r}")
            return _plan(fn, cmd_flags, (batch_loop_c(fn) if batch_loop else "") + (extra_c(fn) if extra_c else ""))

        f = _described_lookup(_Lookup(name, key), make_plan, cache_dir(), lock_timeout, label or name)
        _MANIFESTS[f.__hash__()].update(ident=ident, described_key=key)
        _DESCRIBED[mkey] = f
        return f


def _alias_hit(look: "_Lookup", man: Path, d: Path) -> ca.Function | None:
    """The library a description's manifest ``man`` names, loaded if that library verifies against its own
    manifest (:func:`_hit`); else None (no alias, a foreign one, or its library gone or rejected)."""
    try:
        m = json.loads(man.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or m.get("key") != look.key or m.get("name") != look.name:
        return None
    lib = _Lookup(look.name, str(m.get("library_key", "")))
    if len(lib.key) != 64 or not all(c in "0123456789abcdef" for c in lib.key):
        return None
    return _hit(lib, d / f"{lib.stem()}.so", d / f"{lib.stem()}.json")[0]


def _described_lookup(look: "_Lookup", make_plan: Callable[[], "_Plan"], d: Path, lock_timeout: float,
                      what: str) -> ca.Function:
    """The library of a description (``look``: name, description key): through the description's manifest
    (``<name>-<key[:20]>.json``: the key of the library of its C) when it is there, else ``make_plan()``'s
    C found in the cache or compiled (:func:`_lookup_or_publish`), and the description's manifest written."""
    man, lock = d / f"{look.stem()}.json", d / f"{look.stem()}.lock"
    with _flock(lock, exclusive=False, timeout=lock_timeout) as got:
        if got or got is None:
            f = _alias_hit(look, man, d)
            if f is not None:
                return f
    with _flock(lock, exclusive=True, timeout=lock_timeout) as got:
        if got:  # another process may have written it meanwhile
            f = _alias_hit(look, man, d)
            if f is not None:
                return f
        with _Progress(what):
            plan = make_plan()
            f = _lookup_or_publish(plan, lambda: plan, d, lock_timeout, None)
        if got and not (artifact_of(f) or {}).get("private"):
            fd, tmp = tempfile.mkstemp(prefix=".alias-", suffix=".json", dir=d)
            with os.fdopen(fd, "w", encoding="utf-8") as out:
                json.dump({"format": MANIFEST_FORMAT, "name": look.name, "key": look.key, "library_key": plan.key,
                           "c_sha256": plan.c_sha256, "flags": list(plan.cmd_flags)}, out, indent=1)
            os.chmod(tmp, 0o644)
            os.replace(tmp, man)
        return f


def _described(name: str, description: str, opt_level: str | None, flags, batch_loop: bool) -> tuple[list[str], str, str]:
    """(compiler flags, the full description, its :func:`_ident`) of a :func:`build_described` call."""
    cmd_flags = _check_flags(opt_level, flags)
    if not name.isidentifier() or not name.isascii():
        raise ValueError(f"function name {name!r} is not a C identifier")
    if batch_loop:
        description = description + " +batch_loop"
    return cmd_flags, description, _ident(name, description, opt_level, flags)


def _described_key(name: str, description: str, cmd_flags: list[str]) -> str:
    from arvcas.build.provenance import model_hash

    return _key("described:" + name + "\0" + description + "\0" + model_hash(), _compiler_id(), cmd_flags)


_DIGESTS: dict[str, str] = {}  # cache key -> c_sha256, for digests computed without a compile
_MADE: dict[str, ca.Function] = {}  # the last graphs described_digest built: a build that follows reuses them


def described_digest(name: str, description: str, make: Callable[[], ca.Function], *,
                     opt_level: str | None = None, flags: tuple[str, ...] = (), batch_loop: bool = False) -> str:
    """sha256 of the C that CasADi generates for the function a :func:`build_described` call with the same
    arguments compiles (without its appended loops): what the function computes, the same in every
    process and on every machine (no paths, times or versions in it).

    Never compiles: a function loaded in this process or shipped to it, or one in the compile cache,
    answers from its manifest (no graph is built); otherwise ``make()`` builds the graph and CasADi
    generates its C (the run of a system: 2.5 s for Haidou-1's, 10 s for the BlueROV2's), remembered in
    this process; the graph is kept for a :func:`build_described` of the same key that follows (a replay
    after its check builds it once).
    """
    cmd_flags, description, ident = _described(name, description, opt_level, flags, batch_loop)
    key = _described_key(name, description, cmd_flags)
    with _LOCK:
        f = _PRELOADED.get(ident) or _DESCRIBED.get((name, key, str(_cache_path())))
        m = _MANIFESTS.get(f.__hash__()) if f is not None else None
        if m and m.get("c_sha256"):
            return str(m["c_sha256"])
        if key in _DIGESTS:
            return _DIGESTS[key]
    look = _Lookup(name, key)
    try:
        m = json.loads((_cache_path() / f"{look.stem()}.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        m = None
    if isinstance(m, dict) and m.get("key") == key and m.get("name") == name and m.get("c_sha256"):
        return str(m["c_sha256"])
    fn = make()
    if not isinstance(fn, ca.Function) or fn.name() != name:
        raise TypeError(f"described_digest: make() must return a casadi.Function named {name!r}")
    h = hashlib.sha256(_c_text(fn).encode()).hexdigest()
    with _LOCK:
        _DIGESTS[key] = h
        _MADE[key] = fn
        while len(_MADE) > 3:  # a run's three functions (the run, its time table's two)
            _MADE.pop(next(iter(_MADE)))
    return h


def digest_of(f: ca.Function) -> str:
    """:func:`described_digest` of a Function returned by :func:`build` or :func:`build_described`
    ("" when its manifest does not record it)."""
    m = artifact_of(f)
    return str(m.get("c_sha256", "")) if m else ""


# ---------------------------------------------------------------------------------------------
# what a shipped library is known by (arvcas.build.shipping: libraries for processes without a compiler)

_PRELOADED: dict[str, ca.Function] = {}  # ident -> a shipped library, loaded


def _ident(name: str, description: str, opt_level: str | None, flags) -> str:
    """What a described build is, as its caller asked for it (``opt_level`` None: the default level, whatever
    it is in the process that built it), without the toolchain: a process that got the library shipped
    knows it by this (it may have no compiler to ask for its version, nor the client's ``ARVCAS_OPT_LEVEL``
    or ``ARVCAS_ISA``); the library's manifest says which flags built it."""
    from arvcas.build.provenance import model_hash

    h = hashlib.sha256()
    level = "default" if opt_level is None else opt_level
    for part in ("arvcas-ident-2", name, description, model_hash(), level, "\0".join(flags), ca.__version__):
        b = part.encode()
        h.update(len(b).to_bytes(8, "little"))
        h.update(b)
    return h.hexdigest()


def artifact_of(f: ca.Function) -> dict | None:
    """The manifest (key, so_sha256, flags, path, ...) of a Function returned by :func:`build`.

    Result files store ``key`` so a run can be traced to the exact compiled code.
    """
    with _LOCK:
        m = _MANIFESTS.get(f.__hash__())
        return dict(m) if m is not None else None


# ---------------------------------------------------------------------------------------------
# inspection


def cache_info() -> tuple[Path, list[Artifact]]:
    """The cache directory and its artifacts (each verified against its manifest)."""
    d = cache_dir()
    out = []
    for man in sorted(d.glob("*.json")):
        try:
            m = json.loads(man.read_text(encoding="utf-8"))
            name, key = str(m["name"]), str(m["key"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        so = man.with_suffix(".so")
        try:
            st = os.lstat(so)
        except FileNotFoundError:
            continue
        ok = (
            stat.S_ISREG(st.st_mode)
            and man.stem == f"{name}-{key[:20]}"
            and _sha256_file(so) == m.get("so_sha256")
        )
        out.append(
            Artifact(
                name=name,
                path=so,
                size_bytes=st.st_size,
                compile_time_s=float(m.get("compile_time_s", float("nan"))),
                flags=tuple(m.get("flags", ())),
                key=key,
                verified=ok,
            )
        )
    return d, out
