"""The run's time table: every plant quantity that depends on time (and p) but not on the state.

The arm follows a prescribed trajectory and the disturbance is a prescribed function of time, so a
large share of the plant's right-hand side is the same for every gain set, seed and controller: the
joint angles and rates, the arm's composite inertia and its rate, the momentum and rate of the joint
motion, the arm's weight in water and its first moment, the LU factors of the coupled inertia
``M + M_arm`` and ``sin``/``cos`` of the disturbance's ``freq t`` (eq. 41). One *record*
(:data:`RECORD_FIELDS`) holds them at one time.

The closed loop needs them at the RK4 stage times of every controller sample k,
``t_k + j h_plant / 2`` for ``j = 0 .. 2 h / h_plant`` (:func:`stage_times`), so the run takes the
table as two inputs (:class:`Table`: the records' time parts and arm parts, a column per sample). :func:`table` builds
it with two compiled functions: the cheap time part at every stage time, and the arm part only where
the arm state ``(q, payload, qd, qdd)`` differs from the stage time before: the arm holds still most
of the run, so most stage times repeat the one before (equal inputs, bitwise equal records). A table is a pure function of (scenario, p, model options) and is computed once per
batch of runs, or once per process for repeated single runs (:func:`table` keeps the last few).
It is the same for every controller, gain set and seed.

Exactness: :func:`arvcas.model.manipulator.arm_wrench_scheduled` with these terms equals the recursive
Newton-Euler :func:`arvcas.model.manipulator.arm_wrench` to round-off (tests/test_schedule.py).
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from typing import NamedTuple

import casadi as ca
import numpy as np

from arvcas.build import calls, codegen
from arvcas.model import manipulator, vehicle
from arvcas.sim import profiles, scenario
from arvcas.model.linalg import lu_nopivot, lu_pack, lu_unpack
from arvcas.system import config
from arvcas.system.params import default_layout, system_tag, view
from arvcas.sim.scenario import ScenarioConfig
from arvcas.model.uvms import ModelOptions

__all__ = [
    "Records", "records", "RECORD_FIELDS", "RECORD_SIZE", "ARM_FIELDS", "ARM_SIZE", "TIME_FIELDS", "TIME_SIZE",
    "Table", "record_slices", "unpack", "stage_times", "n_stages", "record_expr", "table", "functions", "digests",
    "clear_cache", "REF_ROWS", "time_rows", "table_bytes", "check_table_memory",
]


class Records:
    """The record of one system: its fields (name, size), sizes and slices.

    Time part: ``q, payload, qd, qdd`` (one entry per joint), ``dist_sin, dist_cos``; arm part: the
    terms of :func:`arvcas.model.manipulator.schedule_fields` and the LU factors of ``M + M_arm``.
    """

    def __init__(self, layout):
        n = layout.structure.n_joints
        self.layout = layout
        self.time_fields: tuple[tuple[str, int], ...] = (
            ("q", n), ("payload", 1), ("qd", n), ("qdd", n), ("dist_sin", 6), ("dist_cos", 6))
        P = view(np.zeros(len(layout)), layout)
        self.arm_fields: tuple[tuple[str, int], ...] = (*manipulator.schedule_fields(P), ("lu", 36))
        self.fields = self.time_fields + self.arm_fields  # one record = its time part, then its arm part
        self.time_size = sum(k for _, k in self.time_fields)
        self.arm_size = sum(k for _, k in self.arm_fields)
        self.size = self.time_size + self.arm_size
        self.n_arm_state = 3 * n + 1  # q, payload, qd, qdd: the time part's first entries
        self.slices: dict[str, slice] = {}
        i = 0
        for name, k in self.fields:
            self.slices[name] = slice(i, i + k)
            i += k


_RECORDS: dict = {}


def records(layout=None) -> Records:
    """The :class:`Records` of a system's layout (default: Haidou-1's)."""
    lay = layout or default_layout()
    r = _RECORDS.get(lay.structure)
    if r is None:
        r = _RECORDS[lay.structure] = Records(lay)
    return r


_DEFAULT_NAMES = {"TIME_FIELDS": "time_fields", "ARM_FIELDS": "arm_fields", "RECORD_FIELDS": "fields",
                  "TIME_SIZE": "time_size", "ARM_SIZE": "arm_size", "RECORD_SIZE": "size"}


def __getattr__(name: str):
    if name in _DEFAULT_NAMES:  # the default system's (Haidou-1's) record
        return getattr(records(), _DEFAULT_NAMES[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def record_slices(layout=None) -> dict[str, slice]:
    return dict(records(layout).slices)


_SYM6 = [(i, j) for i in range(6) for j in range(i, 6)]  # upper triangle, row by row


def _sym_pack(A):
    return ca.vertcat(*[A[i, j] for i, j in _SYM6])


def _sym_unpack(v):
    rows = [[None] * 6 for _ in range(6)]
    for k, (i, j) in enumerate(_SYM6):
        rows[i][j] = rows[j][i] = v[k]
    return ca.vertcat(*[ca.horzcat(*r) for r in rows])


def unpack(rec, layout=None) -> dict:
    """A record column (SX/MX) as named terms: 6x6 matrices for ``M_arm``/``M_arm_dot``, (F, U) for ``lu``."""
    d = {name: rec[s] for name, s in records(layout).slices.items()}
    d["M_arm"] = _sym_unpack(d["M_arm"])
    d["M_arm_dot"] = _sym_unpack(d["M_arm_dot"])
    d["lu"] = lu_unpack(d["lu"], 6)
    return d


def n_stages(cfg: ScenarioConfig) -> int:
    """Distinct RK4 stage times per controller sample: 2 h / h_plant + 1."""
    return 2 * cfg.substeps + 1


def stage_times(cfg: ScenarioConfig) -> np.ndarray:
    """(N + 1, n_stages) stage times ``t_k + j h_plant / 2``; column 0 is the sample time t_k = k h."""
    n = scenario.n_samples(cfg)
    tk = np.arange(n) * cfg.time_h
    return tk[:, None] + np.arange(n_stages(cfg))[None, :] * (0.5 * cfg.time_h_plant)


def _time_expr(cfg: ScenarioConfig, t, P):
    q, qd, qdd = profiles.joint_trajectory(cfg, manipulator.stow_pose(P), t)
    w = ca.DM(cfg.disturbance_freq)
    return ca.densify(ca.vertcat(q, profiles.payload_profile(cfg, t), qd, qdd, ca.sin(w * t), ca.cos(w * t)))


def _arm_expr(P, q, qd, qdd, payload):
    if manipulator.n_joints(P) == 0:
        z6 = ca.DM.zeros(6, 6)
        sc = {"M_arm": z6, "M_arm_dot": z6, "h_q": ca.DM.zeros(6), "b_q": ca.DM.zeros(6), "W": 0,
              "S": ca.DM.zeros(3), "drag_frames": ca.DM.zeros(0, 1)}
    else:
        sc = manipulator.arm_schedule(P, q, qd, qdd, payload)
    lu = lu_pack(*lu_nopivot(vehicle.M(P) + sc["M_arm"]))  # coupled inertia, docs/model.md §3
    parts = dict(sc, lu=lu, M_arm=_sym_pack(sc["M_arm"]), M_arm_dot=_sym_pack(sc["M_arm_dot"]))
    return ca.densify(ca.vertcat(*[parts[name] for name, _ in records(P.layout).arm_fields]))


def record_expr(cfg: ScenarioConfig, t, P):
    """One record at time ``t`` as an expression (the reference the compiled table is tested against)."""
    te = _time_expr(cfg, t, P)
    R = records(P.layout)
    s = {name: te[R.slices[name]] for name, _ in R.time_fields}
    return ca.vertcat(te, _arm_expr(P, s["q"], s["qd"], s["qdd"], s["payload"]))


def _time_function(cfg: ScenarioConfig, layout) -> ca.Function:
    t, p = ca.SX.sym("t"), ca.SX.sym("p", len(layout))
    f = ca.Function("sched_time", [t, p], [_time_expr(cfg, t, view(p, layout))], ["t", "p"], ["rec_time"])
    n = scenario.n_samples(cfg) * n_stages(cfg)
    return f.map("sched_time_map", "serial", n, [1], [])


ARM_CHUNK = 512  # arm states per call of the compiled arm part


def _arm_function(opts: ModelOptions, layout) -> ca.Function:
    """The arm part on ARM_CHUNK arm states (columns) at once: one compiled loop."""
    n = layout.structure.n_joints
    q, qd, qdd, pl = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("qdd", n), ca.SX.sym("payload")
    p = ca.SX.sym("p", len(layout))
    f = ca.Function("sched_arm", [ca.vertcat(q, pl, qd, qdd), p], [_arm_expr(view(p, layout), q, qd, qdd, pl)],
                    ["arm_state", "p"], ["rec_arm"])
    return f.map("sched_arm_map", "serial", ARM_CHUNK, [1], [])


# (kind, key) -> compiled function; a process builds each once (the disk cache makes it a load)
_FUNCS: dict = {}
_FUNCS_LOCK = threading.Lock()
_TABLES: "OrderedDict[tuple, Table]" = OrderedDict()
_TABLES_KEEP = 4  # a table is ~20 MB at the paper's sampling


def _described(kind: str, key, structure) -> tuple[str, str]:
    """(name, description) of the table function ``kind`` for ``key`` (:func:`arvcas.build.codegen.build_described`)."""
    return ({"time": "sched_time_map", "arm": "sched_arm_map"}[kind],
            f"schedule {kind} {key!r} chunk={ARM_CHUNK}{system_tag(structure)}")


def _compiled(kind: str, key, make, structure) -> ca.Function:
    """The compiled table function ``kind`` for ``key`` (a frozen description of what shapes it):
    loaded from the cache by that description, its graph built only on a miss."""
    with _FUNCS_LOCK:
        f = _FUNCS.get((kind, key, structure))
        if f is None:
            what = f"the {kind} table for {structure.name}"
            f = codegen.build_described(*_described(kind, key, structure), make, label=what)
            _FUNCS[(kind, key, structure)] = f
        return f


def _changes(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the rows that differ from the row before, the index of each row's representative)."""
    new = np.ones(rows.shape[0], dtype=bool)
    new[1:] = np.any(rows[1:] != rows[:-1], axis=1)
    first = np.flatnonzero(new)
    return first, np.cumsum(new) - 1


def _arm_batch(f_arm: ca.Function, states: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The compiled arm part on the columns of ``states`` (3 n_joints + 1 rows), ARM_CHUNK at a time (the last padded)."""
    n = states.shape[1]
    n_pad = -(-n // ARM_CHUNK) * ARM_CHUNK
    padded = np.empty((states.shape[0], n_pad), order="F")
    padded[:, :n] = states
    padded[:, n:] = states[:, -1:]
    out = np.empty((f_arm.size1_out(0), n_pad), order="F")
    for a in range(0, n_pad, ARM_CHUNK):
        out[:, a:a + ARM_CHUNK] = calls.call(f_arm, padded[:, a:a + ARM_CHUNK], p)[0]
    return out[:, :n]


REF_ROWS = 12  # the desired trajectory's eta_d and eta_d_dot at t_k (scenarios with a [trajectory])


def time_rows(cfg: ScenarioConfig, layout=None) -> int:
    """Rows of the time table's ``time`` input: the stage records' time parts, then with a desired
    trajectory its :data:`REF_ROWS` rows at t_k (docs/tasks.md)."""
    return n_stages(cfg) * records(layout).time_size + (REF_ROWS if cfg.has_trajectory else 0)


def table_bytes(cfg: ScenarioConfig, layout=None) -> int:
    """Bytes of the run's time table (:func:`table`) for a system's layout: a record of
    ``records(layout).size`` doubles at each of the :func:`n_stages` stage times of every sample, about
    8.6 MB for Haidou-1 in the 100 s paper run at h_plant = 0.05 s (36 MB at 0.01 s). Building it holds
    about twice that."""
    return scenario.n_samples(cfg) * n_stages(cfg) * records(layout).size * 8


def check_table_memory(cfg: ScenarioConfig, layout=None) -> None:
    """Refuse a scenario whose time table for this system would exceed the memory cap
    (:data:`arvcas.system.config.MEMORY_CAP_BYTES`): one line naming the scenario file and ``time.duration``,
    before anything is built."""
    config.check_memory(table_bytes(cfg, layout), f"the run's time table ({scenario.n_samples(cfg)} samples of "
                        f"{cfg.substeps} plant steps)", cfg.path or "scenario", "time.duration",
                        scenario.ScenarioError)


class Table(NamedTuple):
    """The run's time table as its two inputs: column k holds sample k's stage-time records.

    ``time``: ``(n_stages * TIME_SIZE, N + 1)``, the time parts one after the other, then with a desired
    trajectory ``eta_d(t_k)`` and ``eta_d_dot(t_k)`` (:func:`time_rows`);
    ``arm``: ``(n_stages * ARM_SIZE, N + 1)``, the arm parts. Read-only, Fortran-ordered.
    """

    time: np.ndarray
    arm: np.ndarray


def functions(cfg: ScenarioConfig, opts: ModelOptions = ModelOptions(), layout=None) -> tuple[ca.Function, ca.Function]:
    """The two compiled functions that build the table: its time part and its arm part."""
    lay = layout or default_layout()
    return (_compiled("time", cfg.graph_key(), lambda: _time_function(cfg, lay), lay.structure),
            _compiled("arm", opts, lambda: _arm_function(opts, lay), lay.structure))


def digests(cfg: ScenarioConfig, opts: ModelOptions = ModelOptions(), layout=None) -> tuple[str, str]:
    """:func:`arvcas.build.codegen.described_digest` of the two functions of :func:`functions` (nothing compiled)."""
    lay = layout or default_layout()
    return (codegen.described_digest(*_described("time", cfg.graph_key(), lay.structure),
                                     lambda: _time_function(cfg, lay)),
            codegen.described_digest(*_described("arm", opts, lay.structure), lambda: _arm_function(opts, lay)))


def table(cfg: ScenarioConfig, p: np.ndarray, opts: ModelOptions = ModelOptions(), layout=None) -> Table:
    """The run's time table for (scenario, parameter vector ``p``), kept for the last few in this process.

    Fortran-ordered arrays, so the run reads them in place (:func:`arvcas.build.calls.call`).
    """
    p = np.ascontiguousarray(p, dtype=float).ravel()
    lay = layout or default_layout()
    R = records(lay)
    check_table_memory(cfg, lay)
    key = (cfg.graph_key(), cfg.trajectory_values(), hashlib.sha256(p.tobytes()).hexdigest(), opts, lay.structure)
    with _FUNCS_LOCK:
        tab = _TABLES.get(key)
        if tab is not None:
            _TABLES.move_to_end(key)
            return tab
    f_time, f_arm = functions(cfg, opts, lay)
    times = stage_times(cfg)
    n, ns = times.shape
    rec_t = calls.call(f_time, times.reshape(1, -1), p)[0]  # (TIME_SIZE, n * ns), F-ordered
    # the arm part only where the arm state (q, payload, qd, qdd) changes: it holds still most of the run
    na = R.n_arm_state
    first, rep = _changes(rec_t[:na].T)
    arm_first = _arm_batch(f_arm, np.asfortranarray(rec_t[:na, first]), p)
    rec_a = arm_first.T[rep].T  # a row gather of the transpose: contiguous copies, Fortran-ordered result
    rec_t = rec_t.reshape(ns * R.time_size, n, order="F")
    if cfg.has_trajectory:  # the desired trajectory at t_k: REF_ROWS rows after the records (docs/tasks.md)
        rec_t = np.asfortranarray(np.vstack([rec_t, cfg.reference()]))
    tab = Table(rec_t, rec_a.reshape(ns * R.arm_size, n, order="F"))
    for a in tab:
        a.setflags(write=False)
    with _FUNCS_LOCK:
        _TABLES[key] = tab
        while len(_TABLES) > _TABLES_KEEP:
            _TABLES.popitem(last=False)
    return tab


def clear_cache() -> None:
    """Forget the tables kept in this process (the compiled functions stay)."""
    with _FUNCS_LOCK:
        _TABLES.clear()
