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
``artifact_key`` (the compile cache's key of the run), ``run_digest`` (what the study computed:
:meth:`arvcas.sim.run.CompiledRun.digest`, the sha256 of the C of its compiled run and time table;
a replay is checked against it), ``model_hash`` (:func:`arvcas.build.provenance.model_hash`, the
source that wrote it: informative), ``engine`` (last session), ``created``,
``updated`` (ISO 8601 UTC); for a controller defined outside the package, ``plugin`` (JSON of
:func:`arvcas.controllers.base.provenance`: the controller's class, the sha256 of its source files,
and the plugin file, module or entry point and distribution it came from); for NSGA-III, ``survival``
(JSON: the ideal, worst and extreme points of its hyperplane normalisation, which a resume restores);
``restamps`` (JSON list, when the file was re-stamped: when, which run digest, what replayed bit for bit).

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
population/F           (n, m)       objectives (f_chat, f_rmse; or the study's m: docs/objectives.md); NaN when
                                    infeasible
population/G           (n, c)       constraints (<= 0 feasible, see problem.py): divergence, then the study's
population/rank        (n,)         NSGA-II non-domination rank
population/crowding    (n,)         NSGA-II crowding distance (inf at the ends)
population/chat,rmse   (K, n, 6)    per-DOF CHAT and RMSE of each draw (NaN where it diverged)
population/ok,t_fail   (K, n)       per draw: completed; divergence time (s, NaN when ok)
front/index            (f,)         population rows on the feasible non-dominated front, by f_chat
front/X,gains,F,G      (f, ...)     those rows (for readers that want the front alone)
history/<name>         (g,)         per generation: gen, n_eval, n_feasible, hv, best_chat,
                                    best_rmse, gen_time_s, elapsed_s
table2/F,G             (m,), (c,)   Table 2 gains on the same draws
table2/chat,rmse       (K, 6)
table2/ok,t_fail       (K,)
=====================  ===========  =============================================================
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from arvcas.util import files

__all__ = [
    "FORMAT", "FORMAT_VERSION", "HISTORY_FIELDS", "CheckpointError", "Checkpoint", "write_checkpoint",
    "read_checkpoint", "StudyLock", "check_out_dir", "front_indices", "versions", "FRONT_NAME",
    "remove_stale_temps", "provenance_diff", "run_digest", "objectives_of", "controller_of",
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

    from arvcas._version import __version__

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
    model_hash: str = ""  # arvcas.build.provenance.model_hash() of the code and data that computed it
    run_digest: str = ""  # arvcas.sim.run.CompiledRun.digest() of the run that computed it ("": older file)
    restamps: list = field(default_factory=list)  # run digests set after a bit-for-bit replay (arvcas front restamp)
    model_changes: list = field(default_factory=list)  # resumes allowed under other code or parameters
    # the system the runs used: a shipped name or a system file ("": Haidou-1); a file is stored relative to the
    # front file's directory (the front and the file move together with the repository) and read back absolute
    system: str = ""
    # "instantaneous": that system with thrusters that deliver their command at once (Params.instantaneous())
    system_variant: str = ""
    ref_chat: np.ndarray | None = None  # the objectives' per-DOF normalisation (None: Table 3's AGSTA)
    ref_rmse: np.ndarray | None = None
    normalisation: str = ""  # where ref_chat, ref_rmse come from, in words ("": not recorded)
    plugin: dict = field(default_factory=dict)  # where a controller from outside the package came from
    survival: str = ""  # NSGA-III's normalisation state (JSON); "" for NSGA-II
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
    feas = np.where((G <= 0).all(axis=1) & np.isfinite(F).all(axis=1))[0]
    Ff = F[feas]
    # [i, j]: row j weakly below row i in every objective, and strictly in one or an earlier duplicate
    le = (Ff[None, :, :] <= Ff[:, None, :]).all(axis=2)
    lt = (Ff[None, :, :] < Ff[:, None, :]).any(axis=2)
    earlier = feas[None, :] < feas[:, None]
    dominated = (le & (lt | earlier)).any(axis=1)  # a row is never below itself strictly nor earlier
    keep = feas[~dominated].astype(int)
    return keep[np.lexsort((F[keep, 1], F[keep, 0]))] if keep.size else keep


# ---- output directory and lock ---------------------------------------------------------------------


def check_out_dir(d: Path, what: str = "--out") -> Path:
    """``d`` exists (or can be created in an existing, writable parent) and is writable; created."""
    return files.prepare_dir(Path(d), f"{what} {d}", CheckpointError)


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


def controller_of(c, where: str):
    """The registered controller of a checkpoint or front ``c`` (an entry point of its name is loaded);
    for one from a plugin that is not loaded, a one-line :class:`CheckpointError` saying which plugin
    to load (``where``: the file, for the message)."""
    from arvcas.controllers import base

    try:
        return base.get(c.controller)
    except base.ControllerError as e:
        if not c.plugin:
            raise CheckpointError(f"{where}: {e}") from None
        src, hint = base.describe_provenance(c.plugin)
        raise CheckpointError(f"{where}: controller '{c.controller}' is not registered; it came from {src} (source "
                              f"sha256 {str(c.plugin.get('digest', ''))[:12]}): {hint}") from None


SYSTEM_VARIANTS = ("", "instantaneous")  # Checkpoint.system_variant


def run_digest(c: Checkpoint, params) -> str:
    """:meth:`arvcas.sim.run.CompiledRun.digest` of the run of ``c``'s study (its controller, its scenario,
    the accumulators of its objectives) on ``params`` (:class:`arvcas.system.params.Params`): what a
    replay of ``c`` computes with this installation. Compiles nothing (the cache's manifests answer)."""
    from arvcas.sim.scenario import loads_scenario
    from arvcas.sim.simulation import compiled_run

    cfg = loads_scenario(c.scenario_text, "the study scenario")
    return compiled_run(c.controller, params, cfg, accumulators=objectives_of(c).accumulators()).digest()


def objectives_of(c: Checkpoint):
    """The :class:`arvcas.tuning.study.ObjectivesConfig` of ``c``'s study (from its identity; the paper's
    when it names none)."""
    from arvcas.tuning.study import ObjectivesConfig

    obj = json.loads(c.identity or "{}").get("objectives") or {}
    return ObjectivesConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in obj.items()
                               if k in ("names", "reference_point", "chat", "constraints", "settling_band")})


def restamp_hint(where: str) -> str:
    return f"check that it replays and re-stamp it: arvcas front restamp {where}"


def provenance_diff(c: Checkpoint, params, where: str = "front") -> list[str]:
    """What differs between the computation that wrote ``c`` and this installation's on ``params`` (a
    :class:`arvcas.system.params.Params`): empty when a resume or replay reproduces the stored numbers.

    A file with a ``run_digest`` is compared with :func:`run_digest` (the compiled run: an edit of
    arvcas that leaves the run's generated C unchanged leaves the file valid). An older file records
    only the hash of the source that wrote it: valid if it equals this installation's
    (:func:`arvcas.build.provenance.model_hash`), else refused with how to re-stamp it. A controller
    from a plugin must be registered (:func:`controller_of`); its source files are compared with the
    digest the file records. The parameter vector must equal the file's."""
    from arvcas.build.provenance import model_hash

    out = []
    if c.plugin:
        now = controller_of(c, where).source_digest()
        if now != c.plugin.get("digest"):
            from arvcas.controllers.base import describe_provenance

            out.append(f"the source of controller '{c.controller}' changed ({describe_provenance(c.plugin)[0]}: sha256 "
                       f"{str(c.plugin.get('digest', ''))[:12]} in the file, {now[:12]} now)")
    pv = np.asarray(params.vector(), dtype=float)
    if c.run_digest:
        now = run_digest(c, params)
        if now != c.run_digest:
            import casadi

            was = (c.versions or {}).get("casadi")
            why = (f"CasADi {was} computed it, {casadi.__version__} is installed, and CasADi's generated C differs "
                   f"between releases" if was and was != casadi.__version__ else "the model code or data differ")
            out.append(f"the compiled run changed (run digest {c.run_digest[:12]} in the file, {now[:12]} now: "
                       f"{why})")
    elif not c.model_hash:
        out.append("the file records no model hash (written by an older arvcas)")
    elif c.model_hash != model_hash():
        out.append(f"the file records only the hash of the source that wrote it (model hash {c.model_hash[:12]}, "
                   f"{model_hash()[:12]} now), not the digest of its compiled run; {restamp_hint(where)}")
    if pv.shape != c.params.shape or not np.array_equal(pv, c.params):
        out.append("the study used other parameter values than the packaged file" if pv.shape == c.params.shape
                   else f"the parameter vector has {pv.size} entries, the file's {c.params.size}")
    return out


# ---- write --------------------------------------------------------------------------------------------

_ATTRS = ("controller", "study_name", "study_text", "study_path", "identity", "scenario_text", "status",
          "stop_reason", "rng_state", "artifact_key", "engine", "created", "updated")
_INT_ATTRS = ("seed", "n_gen", "n_eval")
_POP = ("X", "gains", "F", "G", "rank", "crowding", "chat", "rmse", "ok", "t_fail")
_T2 = ("F", "G", "chat", "rmse", "ok", "t_fail")


_GAIN_UNITS = "gain units of each variable (see variables/names and the controller's gain table)"
_OBJ = "f_chat, f_rmse: mean over the 6 DOF of CHAT and RMSE / the paper's AGSTA values (dimensionless)"
_CHAT_UNITS = "N (x, y, z), N m (phi, theta, psi)"
_RMSE_UNITS = "m (x, y, z), rad (phi, theta, psi)"
# dataset (name under population/, front/ or table2/ shared) -> (units, description)
DATASET_DOC: dict[str, tuple[str, str]] = {
    "variables/names": ("", "gain names, one per decision variable (x.c ... psi.omega)"),
    "variables/lower": (_GAIN_UNITS, "lower bound of each gain (the search runs on log10 of the gains)"),
    "variables/upper": (_GAIN_UNITS, "upper bound of each gain (the search runs on log10 of the gains)"),
    "variables/table2": (_GAIN_UNITS, "the paper's Table 2 gains"),
    "draws/noise_seed": ("", "sensor-noise seed of each draw"),
    "draws/uncertainty": ("1", "nominal-model factors [C, D, g, arm] of each draw"),
    "draws/phase": ("rad", "disturbance phases of each draw (6 DOF)"),
    "params": ("SI units of arvcas.system.params.SCHEMA, in its order", "parameter vector the runs used"),
    "X": ("log10 of the gain units", "decision vectors: log10 of the gains"),
    "gains": (_GAIN_UNITS, "gains = 10 ** X, the values the runs used"),
    "F": ("1", "objectives " + _OBJ + "; NaN when infeasible"),
    "G": ("1", "constraint, feasible when <= 0: 0 every draw completed; 1 + the lost fraction of the run when a "
          "draw diverged; 2 non-finite metrics (arvcas.tuning.problem)"),
    "rank": ("", "NSGA-II non-domination rank (NaN where unset)"),
    "crowding": ("", "NSGA-II crowding distance (inf at the ends, NaN where unset)"),
    "chat": (_CHAT_UNITS, "per-DOF CHAT (eq. 42), draws x members x DOF; NaN where the run diverged"),
    "rmse": (_RMSE_UNITS, "per-DOF RMSE (eq. 43), draws x members x DOF; NaN where the run diverged"),
    "ok": ("", "draws x members: the run completed without diverging"),
    "t_fail": ("s", "draws x members: divergence time (NaN when ok)"),
    "index": ("", "rows of population/ on the feasible non-dominated front, sorted by f_chat"),
    "history/gen": ("", "generation number"),
    "history/n_eval": ("", "evaluations (runs of a gain set over all draws) so far"),
    "history/n_feasible": ("", "feasible members of the population"),
    "history/hv": ("1", "hypervolume of the feasible front against the study's reference point"),
    "history/best_chat": ("1", "smallest f_chat in the population"),
    "history/best_rmse": ("1", "smallest f_rmse in the population"),
    "history/gen_time_s": ("s", "wall time of the generation"),
    "history/elapsed_s": ("s", "wall time since the study started (all sessions)"),
}


def _doc(ds: h5py.Dataset, system: str = "") -> None:
    """``units`` and ``description`` of a dataset, from :data:`DATASET_DOC`; for another system than
    Haidou-1 (``system``) the paper's tables are named as that system's defaults and normalisation."""
    from arvcas.metrics.indices import defaults_name, norm_name

    name = ds.name.lstrip("/")
    group, _, leaf = name.rpartition("/")
    units, desc = DATASET_DOC[name] if name in DATASET_DOC else DATASET_DOC[leaf]
    if system:
        desc = (desc.replace("the paper's Table 2 gains", "the system's default gains")
                .replace("the paper's AGSTA values", norm_name(system).replace("value", "values")))
    if group == "front":
        desc = "front members only: " + desc
    elif group == "table2":
        desc = f"the {defaults_name(system)} on the same draws: " + desc
    ds.attrs["units"] = units
    ds.attrs["description"] = desc


def _system_attr(system: str, d: Path) -> str:
    """How the file stores ``Checkpoint.system``: a shipped name as is, a system file's path relative to ``d``
    (the front file's directory)."""
    return os.path.relpath(system, d) if Path(system).is_absolute() else system


def _system_read(system: str, d: Path) -> str:
    """``Checkpoint.system`` from the stored attribute: a relative system file path resolved against ``d``."""
    p = Path(system)
    return str((d / p).resolve()) if p.suffix.lower() == ".toml" and not p.is_absolute() else system


def _write(f: h5py.File, c: Checkpoint, d: Path) -> None:
    f.attrs["format"] = FORMAT
    f.attrs["format_version"] = FORMAT_VERSION
    for k in _ATTRS:
        f.attrs[k] = str(getattr(c, k))
    for k in _INT_ATTRS:
        f.attrs[k] = int(getattr(c, k))
    f.attrs["reference_point"] = np.asarray(c.reference_point, dtype=float)
    f.attrs["versions"] = json.dumps(c.versions, sort_keys=True)
    f.attrs["model_hash"] = c.model_hash
    if c.run_digest:
        f.attrs["run_digest"] = c.run_digest
    if c.restamps:
        f.attrs["restamps"] = json.dumps(list(c.restamps))
    f.attrs["model_changes"] = json.dumps(list(c.model_changes))
    if c.system:
        f.attrs["system"] = _system_attr(c.system, d)
    if c.system_variant:
        f.attrs["system_variant"] = c.system_variant
    if c.plugin:
        f.attrs["plugin"] = json.dumps(c.plugin, sort_keys=True)
    if c.survival:
        f.attrs["survival"] = c.survival
    if c.normalisation:
        f.attrs["normalisation"] = c.normalisation
    if c.ref_chat is not None:
        f.attrs["ref_chat"] = np.asarray(c.ref_chat, dtype=float)
        f.attrs["ref_rmse"] = np.asarray(c.ref_rmse, dtype=float)
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
    f.visititems(lambda name, obj: _doc(obj, c.system) if isinstance(obj, h5py.Dataset) else None)
    _doc_objectives(f, c)


def _doc_objectives(f: h5py.File, c: Checkpoint) -> None:
    """Other objectives than the paper's (docs/objectives.md): F's units and description name them."""
    try:
        names = json.loads(c.identity)["objectives"]["names"]
    except (ValueError, KeyError, TypeError):
        return
    if list(names) == ["chat", "rmse"]:
        return
    from arvcas.metrics import objectives as objectives_mod

    units = []
    for n in names:
        try:
            units.append(objectives_mod.get(n).unit)
        except (objectives_mod.ObjectiveError, ValueError):
            units.append("?")
    for g in ("population", "front", "table2"):
        if g in f and "F" in f[g]:
            f[g]["F"].attrs["units"] = ", ".join(units)
            f[g]["F"].attrs["description"] = ("objectives " + ", ".join(f"f_{n}" for n in names)
                                             + " (docs/objectives.md), the mean over the draws; NaN when infeasible")


def write_checkpoint(c: Checkpoint, path: Path, touch: bool = True) -> Path:
    """Write ``c`` to ``path`` atomically (temp file in the same directory, fsync, rename).

    On any failure the temp file is removed and the previous ``path`` is left as it was. ``touch``:
    set ``updated`` to now (False: keep the study's, for a rewrite that computes nothing).
    """
    path = Path(path)
    if touch or not c.updated:
        c.updated = _now()
    if not c.created:
        c.created = c.updated
    try:
        return files.atomic_write(path, lambda tmp: _write_file(tmp, c), CheckpointError, FORMAT)
    except CheckpointError as e:
        raise CheckpointError(f"{e}; the previous one is kept") from None


def _write_file(tmp: Path, c: Checkpoint) -> None:
    with files.new_hdf5(tmp) as f:  # in memory, then plain I/O: a full disk is one OSError
        _write(f, c, Path(tmp).resolve().parent)


def remove_stale_temps(d: Path) -> None:
    """Temp files left by a process killed while writing (call while holding the lock)."""
    files.remove_stale_temps(d)


# ---- read ---------------------------------------------------------------------------------------------


def read_checkpoint(path: str | Path) -> Checkpoint:
    """Read and validate a ``front.h5``; :class:`CheckpointError` (one line) if it is not one."""
    path = Path(path)
    if path.is_dir():
        raise CheckpointError(f"{path}: is a directory (give the front.h5 inside it)")
    files.check_input(path, "file", CheckpointError)  # regular files only: h5py would block on a FIFO
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
    kw = {k: _attr(f, k, path, _s) for k in _ATTRS}
    kw.update({k: _attr(f, k, path, _int) for k in _INT_ATTRS})
    v = f["variables"]
    kw["names"] = [_s(x) for x in v["names"][()]]
    for k in ("lower", "upper", "table2"):
        kw[k] = v[k][()]
    kw["draw_seeds"] = f["draws/noise_seed"][()]
    kw["draw_uncertainty"] = f["draws/uncertainty"][()]
    kw["draw_phase"] = f["draws/phase"][()]
    kw["params"] = f["params"][()]
    kw["reference_point"] = _attr(f, "reference_point", path, _point)
    kw["versions"] = _json_attr(f, "versions", path, dict)
    kw["model_hash"] = _s(f.attrs["model_hash"]) if "model_hash" in f.attrs else ""
    kw["run_digest"] = _s(f.attrs["run_digest"]) if "run_digest" in f.attrs else ""
    kw["restamps"] = _json_attr(f, "restamps", path, list) if "restamps" in f.attrs else []
    kw["model_changes"] = _json_attr(f, "model_changes", path, list) if "model_changes" in f.attrs else []
    kw["system"] = _system_read(_s(f.attrs["system"]), path.resolve().parent) if "system" in f.attrs else ""
    kw["system_variant"] = _s(f.attrs["system_variant"]) if "system_variant" in f.attrs else ""
    if kw["system_variant"] not in SYSTEM_VARIANTS:
        raise CheckpointError(f"{path}: system_variant {kw['system_variant']!r}: allowed "
                              f"{', '.join(repr(v) for v in SYSTEM_VARIANTS)}")
    kw["plugin"] = _json_attr(f, "plugin", path, dict) if "plugin" in f.attrs else {}
    kw["survival"] = _s(f.attrs["survival"]) if "survival" in f.attrs else ""
    kw["normalisation"] = _s(f.attrs["normalisation"]) if "normalisation" in f.attrs else ""
    if "ref_chat" in f.attrs:
        kw["ref_chat"], kw["ref_rmse"] = np.asarray(f.attrs["ref_chat"], float), np.asarray(f.attrs["ref_rmse"], float)
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


def _int(v) -> int:
    if isinstance(v, (bytes, str, float)) and not float(v if not isinstance(v, bytes) else v.decode()).is_integer():
        raise ValueError(v)
    return int(v)


def _point(v) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.ndim != 1 or not 2 <= a.size <= 4:
        raise ValueError(v)
    return a


def _attr(f: h5py.File, name: str, path: Path, conv):
    if name not in f.attrs:
        raise CheckpointError(f"{path}: damaged arvcas front file (attribute '{name}' is missing)")
    try:
        return conv(f.attrs[name])
    except (ValueError, TypeError, UnicodeDecodeError, OverflowError):
        raise CheckpointError(f"{path}: damaged arvcas front file (attribute '{name}' has a wrong type or value)") from None


def _json_attr(f: h5py.File, name: str, path: Path, kind: type):
    try:
        v = json.loads(_s(f.attrs[name]))
    except (ValueError, TypeError):
        v = None
    if not isinstance(v, kind):
        raise CheckpointError(f"{path}: damaged arvcas front file (attribute '{name}' is not JSON {kind.__name__})")
    return v


def _validate_population(c: Checkpoint, path: Path) -> None:
    """The population's values, not only its shapes (a resume feeds them to NSGA-II): numbers; the
    decision variables X finite and within the study's bounds (log10 of lower, upper); the gains 10**X;
    the constraint G finite; the objectives F finite for every feasible member (G <= 0)."""
    def bad(k: str, why: str) -> CheckpointError:
        return CheckpointError(f"{path}: damaged arvcas front file (population/{k}: {why})")

    for k in ("X", "gains", "F", "G", "rank", "crowding", "chat", "rmse", "ok", "t_fail"):
        if np.asarray(getattr(c, k)).dtype.kind not in "biuf":
            raise bad(k, f"not numbers ({np.asarray(getattr(c, k)).dtype})")
    if not (np.isfinite(c.lower).all() and np.isfinite(c.upper).all() and (c.lower > 0).all()
            and (c.lower < c.upper).all()):
        raise CheckpointError(f"{path}: damaged arvcas front file (variables/lower, upper are not 0 < lower < upper)")
    lo, hi = np.log10(c.lower), np.log10(c.upper)
    if not np.isfinite(c.X).all() or (c.X < lo - 1e-9).any() or (c.X > hi + 1e-9).any():
        raise bad("X", "not finite or outside the study's bounds")
    if not np.allclose(c.gains, 10.0 ** c.X, rtol=1e-12, atol=0.0):
        raise bad("gains", "not 10**X")
    if not np.isfinite(c.G).all():
        raise bad("G", "not finite")
    feasible = (c.G <= 0).all(axis=1)
    if not np.isfinite(c.F[feasible]).all():
        raise bad("F", "not finite for a feasible member")


def _validate(c: Checkpoint, path: Path) -> None:
    m = len(c.names)
    if c.lower.shape != (m,) or c.upper.shape != (m,) or c.table2.shape != (m,):
        raise CheckpointError(f"{path}: damaged arvcas front file (variables do not match {m} names)")
    if c.X is not None:
        n = c.X.shape[0]
        K = c.draw_seeds.shape[0]
        n_g = c.G.shape[1] if c.G.ndim == 2 and c.G.shape[1] >= 1 else 1
        want = {"X": (n, m), "gains": (n, m), "F": (n, c.reference_point.size), "G": (n, n_g), "rank": (n,),
                "crowding": (n,),
                "chat": (K, n, 6), "rmse": (K, n, 6), "ok": (K, n), "t_fail": (K, n)}
        for k, shp in want.items():
            if getattr(c, k).shape != shp:
                raise CheckpointError(f"{path}: damaged arvcas front file (population/{k} has shape "
                                      f"{getattr(c, k).shape}, expected {shp})")
        _validate_population(c, path)
    lens = {len(c.history[k]) for k in HISTORY_FIELDS}
    if len(lens) != 1 or lens.pop() != c.n_gen:
        raise CheckpointError(f"{path}: damaged arvcas front file (history does not cover {c.n_gen} generations)")
    if c.status not in ("running", "interrupted", "finished"):
        raise CheckpointError(f"{path}: damaged arvcas front file (status {c.status!r})")

