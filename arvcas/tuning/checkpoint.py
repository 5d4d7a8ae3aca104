"""``front.h5``: a tuning study's checkpoint and result, in one HDF5 layout; lock; atomic writes.

The file is rewritten after every generation, under a temporary name in the same directory, flushed,
fsync'ed and renamed over ``front.h5`` (``os.replace``): an interrupted or failed write (a full disk)
leaves the previous checkpoint intact. It holds everything ``--resume`` needs to continue bit for
bit, as data (no pickled code): the population after survival with its ranks and crowding
distances, the generation and evaluation counters, and the state of NSGA-II's random generator
(``numpy`` PCG64 ``bit_generator.state`` as JSON).

Layout (``format = "arvcas.tuning.front"``, ``format_version = 1``)
---------------------------------------------------------------------
Root attributes: ``format``, ``format_version``, ``controller``, ``study_name``, ``study_text`` (the
study file), ``study_path``, ``identity`` (JSON of what shapes the search, see
:meth:`Study.identity`), ``scenario_text``, ``seed`` (NSGA-II), ``status`` (``running``,
``interrupted``, ``finished``), ``stop_reason``, ``n_gen``, ``n_eval``, ``rng_state`` (JSON),
``reference_point``, ``versions`` (JSON: arvcas, pymoo, casadi, numpy, h5py, python),
``artifact_key`` (content hash of the compiled run), ``engine`` (last session), ``created``,
``updated`` (ISO 8601 UTC).

=====================  ===========  =============================================================
dataset                shape        content
=====================  ===========  =============================================================
variables/names        (m,)         gain names ``x.c ... psi.omega`` (UTF-8)
variables/lower,upper  (m,)         bounds, gain units (the search runs on log10 of these)
variables/table2       (m,)         Table 2 gains
draws/noise_seed       (K,)         sensor-noise seed of each draw
draws/uncertainty      (K, 4)       [C, D, g, arm] factors of each draw
draws/phase            (K, 6)       disturbance phases of each draw, rad
params                 (p,)         parameter vector the runs used
population/X           (n, m)       decision vectors, log10(gains)
population/gains       (n, m)       10 ** X (the values the runs used)
population/F           (n, 2)       objectives (f_chat, f_rmse); NaN when infeasible
population/G           (n, 1)       constraint (<= 0 feasible, see problem.py)
population/rank        (n,)         NSGA-II non-domination rank
population/crowding    (n,)         NSGA-II crowding distance (inf at the ends)
population/chat,rmse   (K, n, 6)    per-DOF CHAT and RMSE of each draw (NaN where it diverged)
population/ok,t_fail   (K, n)       per draw: completed; divergence time (s, NaN when ok)
front/index            (f,)         population rows on the feasible non-dominated front, by f_chat
front/X,gains,F,G      (f, ...)     those rows (for readers that want the front alone)
history/<name>         (g,)         per generation: gen, n_eval, n_feasible, hv, best_chat,
                                    best_rmse, gen_time_s, elapsed_s
table2/F,G             (2,), (1,)   Table 2 gains on the same draws
table2/chat,rmse       (K, 6)
table2/ok,t_fail       (K,)
=====================  ===========  =============================================================
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

__all__ = [
    "FORMAT", "FORMAT_VERSION", "HISTORY_FIELDS", "CheckpointError", "Checkpoint", "write_checkpoint",
    "read_checkpoint", "StudyLock", "check_out_dir", "front_indices", "versions", "FRONT_NAME",
    "remove_stale_temps",
]

FORMAT = "arvcas.tuning.front"
FORMAT_VERSION = 1
FRONT_NAME = "front.h5"
HISTORY_FIELDS = ("gen", "n_eval", "n_feasible", "hv", "best_chat", "best_rmse", "gen_time_s", "elapsed_s")


class CheckpointError(ValueError):
    """One-line error about a front file or an output directory."""


def versions() -> dict:
    import platform

    import casadi
    import pymoo

    from arvcas import __version__

    return {"arvcas": __version__, "pymoo": pymoo.__version__, "casadi": casadi.__version__,
            "numpy": np.__version__, "h5py": h5py.__version__, "python": platform.python_version()}


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


@dataclass
class Checkpoint:
    """Everything in ``front.h5`` (arrays as NumPy, text as str); see the module docstring."""

    controller: str
    study_name: str
    study_text: str
    study_path: str
    identity: str
    scenario_text: str
    seed: int
    names: list
    lower: np.ndarray
    upper: np.ndarray
    table2: np.ndarray
    draw_seeds: np.ndarray
    draw_uncertainty: np.ndarray
    draw_phase: np.ndarray
    params: np.ndarray
    reference_point: np.ndarray
    status: str = "running"
    stop_reason: str = ""
    n_gen: int = 0
    n_eval: int = 0
    rng_state: str = ""
    X: np.ndarray | None = None
    gains: np.ndarray | None = None
    F: np.ndarray | None = None
    G: np.ndarray | None = None
    rank: np.ndarray | None = None
    crowding: np.ndarray | None = None
    chat: np.ndarray | None = None
    rmse: np.ndarray | None = None
    ok: np.ndarray | None = None
    t_fail: np.ndarray | None = None
    history: dict = field(default_factory=lambda: {k: np.zeros(0) for k in HISTORY_FIELDS})
    table2_F: np.ndarray | None = None
    table2_G: np.ndarray | None = None
    table2_chat: np.ndarray | None = None
    table2_rmse: np.ndarray | None = None
    table2_ok: np.ndarray | None = None
    table2_t_fail: np.ndarray | None = None
    versions: dict = field(default_factory=dict)
    artifact_key: str = ""
    engine: str = ""
    created: str = ""
    updated: str = ""

    @property
    def front(self) -> np.ndarray:
        """Population rows on the feasible non-dominated front, sorted by f_chat."""
        return front_indices(self.F, self.G)


def front_indices(F: np.ndarray, G: np.ndarray) -> np.ndarray:
    """Feasible, non-dominated rows of F (duplicates kept once), sorted by the first objective."""
    if F is None or len(F) == 0:
        return np.zeros(0, dtype=int)
    feas = np.where((G[:, 0] <= 0) & np.isfinite(F).all(axis=1))[0]
    keep = []
    for i in feas:
        dominated = False
        for j in feas:
            if j != i and np.all(F[j] <= F[i]) and (np.any(F[j] < F[i]) or j < i):
                dominated = True  # strictly dominated, or an exact duplicate of an earlier row
                break
        if not dominated:
            keep.append(i)
    keep = np.array(keep, dtype=int)
    return keep[np.lexsort((F[keep, 1], F[keep, 0]))] if keep.size else keep


# ---- output directory and lock ---------------------------------------------------------------------


def check_out_dir(d: Path, what: str = "--out") -> Path:
    """``d`` exists (or can be created in an existing, writable parent) and is writable; created."""
    d = Path(d)
    parent = d.parent if str(d.parent) else Path(".")
    if not d.exists():
        if not parent.is_dir():
            raise CheckpointError(f"{what} {d}: parent directory {parent} does not exist")
        _writable(parent, f"{what} {d}")
        try:
            d.mkdir()
        except OSError as e:
            raise CheckpointError(f"{what} {d}: cannot create directory ({e.strerror})") from None
    if not d.is_dir():
        raise CheckpointError(f"{what} {d}: exists and is not a directory")
    _writable(d, f"{what} {d}")
    return d


def _writable(d: Path, who: str) -> None:
    st = os.stat(d)
    # root bypasses access(): a directory without any write bit counts as read-only for everyone
    if not os.access(d, os.W_OK | os.X_OK) or not st.st_mode & 0o222:
        raise CheckpointError(f"{who}: directory {d} is not writable (mode {stat.S_IMODE(st.st_mode):o})")


class StudyLock:
    """An exclusive ``flock`` on ``DIR/.arvcas-tune.lock`` while a study writes into ``DIR``.

    A second ``arvcas tune`` on the same directory is refused at once with the holder's pid. The lock
    dies with its process (even on SIGKILL); the file is removed on a clean release.
    """

    NAME = ".arvcas-tune.lock"

    def __init__(self, d: Path):
        self.path = Path(d) / self.NAME
        self.fd: int | None = None

    def acquire(self) -> "StudyLock":
        for _ in range(10):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                try:
                    holder = os.read(fd, 64).decode(errors="replace").strip() or "?"
                finally:
                    os.close(fd)
                raise CheckpointError(
                    f"{self.path.parent}: another 'arvcas tune' (pid {holder}) is running on this directory "
                    f"(lock {self.path}); wait for it to finish or use another --out") from None
            try:  # the file may have been removed by the previous holder between open and flock
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                os.ftruncate(fd, 0)
                os.write(fd, f"{os.getpid()}\n".encode())
                self.fd = fd
                return self
            os.close(fd)
        raise CheckpointError(f"{self.path}: could not take the lock")  # pragma: no cover

    def release(self) -> None:
        if self.fd is not None:
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
            os.close(self.fd)
            self.fd = None

    def __enter__(self) -> "StudyLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


# ---- write --------------------------------------------------------------------------------------------

_ATTRS = ("controller", "study_name", "study_text", "study_path", "identity", "scenario_text", "status",
          "stop_reason", "rng_state", "artifact_key", "engine", "created", "updated")
_INT_ATTRS = ("seed", "n_gen", "n_eval")
_POP = ("X", "gains", "F", "G", "rank", "crowding", "chat", "rmse", "ok", "t_fail")
_T2 = ("F", "G", "chat", "rmse", "ok", "t_fail")


def _write(f: h5py.File, c: Checkpoint) -> None:
    f.attrs["format"] = FORMAT
    f.attrs["format_version"] = FORMAT_VERSION
    for k in _ATTRS:
        f.attrs[k] = str(getattr(c, k))
    for k in _INT_ATTRS:
        f.attrs[k] = int(getattr(c, k))
    f.attrs["reference_point"] = np.asarray(c.reference_point, dtype=float)
    f.attrs["versions"] = json.dumps(c.versions, sort_keys=True)
    v = f.create_group("variables")
    v.create_dataset("names", data=np.array(c.names, dtype=object), dtype=h5py.string_dtype())
    for k in ("lower", "upper", "table2"):
        v.create_dataset(k, data=np.asarray(getattr(c, k), dtype=float))
    dr = f.create_group("draws")
    dr.create_dataset("noise_seed", data=np.asarray(c.draw_seeds, dtype=np.int64))
    dr.create_dataset("uncertainty", data=np.asarray(c.draw_uncertainty, dtype=float))
    dr.create_dataset("phase", data=np.asarray(c.draw_phase, dtype=float))
    f.create_dataset("params", data=np.asarray(c.params, dtype=float))
    if c.X is not None:
        p = f.create_group("population")
        for k in _POP:
            p.create_dataset(k, data=np.asarray(getattr(c, k)))
        idx = c.front
        fr = f.create_group("front")
        fr.create_dataset("index", data=idx.astype(np.int64))
        for k in ("X", "gains", "F", "G"):
            fr.create_dataset(k, data=np.asarray(getattr(c, k))[idx])
    h = f.create_group("history")
    for k in HISTORY_FIELDS:
        h.create_dataset(k, data=np.asarray(c.history.get(k, np.zeros(0)), dtype=float))
    if c.table2_F is not None:
        t = f.create_group("table2")
        for k in _T2:
            t.create_dataset(k, data=np.asarray(getattr(c, f"table2_{k}")))


def write_checkpoint(c: Checkpoint, path: Path) -> Path:
    """Write ``c`` to ``path`` atomically (temp file in the same directory, fsync, rename).

    On any failure the temp file is removed and the previous ``path`` is left as it was.
    """
    path = Path(path)
    c.updated = _now()
    if not c.created:
        c.created = c.updated
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with h5py.File(tmp, "w") as f:
            _write(f, c)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except BaseException as e:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
        if isinstance(e, OSError):
            why = os.strerror(e.errno) if e.errno else " ".join(str(e).split())
            raise CheckpointError(f"{path}: cannot write the checkpoint ({why}); the previous one is kept") from None
        raise
    return path


def remove_stale_temps(d: Path) -> None:
    """Temp files left by a process killed while writing (call while holding the lock)."""
    for p in Path(d).glob(f".{FRONT_NAME}.tmp-*"):
        try:
            p.unlink()
        except OSError:
            pass


# ---- read ---------------------------------------------------------------------------------------------


def read_checkpoint(path: str | Path) -> Checkpoint:
    """Read and validate a ``front.h5``; :class:`CheckpointError` (one line) if it is not one."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"{path}: file not found")
    if path.is_dir():
        raise CheckpointError(f"{path}: is a directory (give the front.h5 inside it)")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        why = "truncated or not HDF5" if e.errno in (None, 0) else os.strerror(e.errno)
        raise CheckpointError(f"{path}: not a readable HDF5 file ({why})") from None
    try:
        with f:
            return _read(f, path)
    except (KeyError, OSError, ValueError, TypeError) as e:
        if isinstance(e, CheckpointError):
            raise
        raise CheckpointError(f"{path}: damaged arvcas front file ({' '.join(str(e).split())})") from None


def _s(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def _read(f: h5py.File, path: Path) -> Checkpoint:
    fmt = _s(f.attrs.get("format", ""))
    if fmt != FORMAT:
        raise CheckpointError(f"{path}: not an arvcas tuning front (format attribute {fmt!r}, expected {FORMAT!r})")
    ver = int(f.attrs.get("format_version", -1))
    if ver != FORMAT_VERSION:
        raise CheckpointError(f"{path}: front format version {ver} (this arvcas reads {FORMAT_VERSION})")
    for g in ("variables", "draws", "params", "history"):
        if g not in f:
            raise CheckpointError(f"{path}: incomplete arvcas front file (no '{g}')")
    kw = {k: _s(f.attrs[k]) for k in _ATTRS}
    kw.update({k: int(f.attrs[k]) for k in _INT_ATTRS})
    v = f["variables"]
    kw["names"] = [_s(x) for x in v["names"][()]]
    for k in ("lower", "upper", "table2"):
        kw[k] = v[k][()]
    kw["draw_seeds"] = f["draws/noise_seed"][()]
    kw["draw_uncertainty"] = f["draws/uncertainty"][()]
    kw["draw_phase"] = f["draws/phase"][()]
    kw["params"] = f["params"][()]
    kw["reference_point"] = np.asarray(f.attrs["reference_point"], dtype=float)
    kw["versions"] = json.loads(_s(f.attrs["versions"]))
    if "population" in f:
        for k in _POP:
            kw[k] = f["population"][k][()]
    kw["history"] = {k: f["history"][k][()] for k in HISTORY_FIELDS}
    if "table2" in f:
        for k in _T2:
            kw[f"table2_{k}"] = f["table2"][k][()]
    c = Checkpoint(**kw)
    _validate(c, path)
    return c


def _validate(c: Checkpoint, path: Path) -> None:
    m = len(c.names)
    if c.lower.shape != (m,) or c.upper.shape != (m,) or c.table2.shape != (m,):
        raise CheckpointError(f"{path}: damaged arvcas front file (variables do not match {m} names)")
    if c.X is not None:
        n = c.X.shape[0]
        K = c.draw_seeds.shape[0]
        want = {"X": (n, m), "gains": (n, m), "F": (n, 2), "G": (n, 1), "rank": (n,), "crowding": (n,),
                "chat": (K, n, 6), "rmse": (K, n, 6), "ok": (K, n), "t_fail": (K, n)}
        for k, shp in want.items():
            if getattr(c, k).shape != shp:
                raise CheckpointError(f"{path}: damaged arvcas front file (population/{k} has shape "
                                      f"{getattr(c, k).shape}, expected {shp})")
    lens = {len(c.history[k]) for k in HISTORY_FIELDS}
    if len(lens) != 1 or lens.pop() != c.n_gen:
        raise CheckpointError(f"{path}: damaged arvcas front file (history does not cover {c.n_gen} generations)")
    if c.status not in ("running", "interrupted", "finished"):
        raise CheckpointError(f"{path}: damaged arvcas front file (status {c.status!r})")

