"""A run is a description; compiling it gives an object that owns its inputs by name.

:class:`Run` is frozen and hashable: the controller, the scenario, the parameters and the model
options. :meth:`Run.compile` returns a :class:`CompiledRun` (as acados keeps the problem description
apart from the built solver): it owns the compiled closed-loop functions (metrics only, and with the
trace), their cache keys, the run's time table, and the named inputs of one run
(:data:`arvcas.sim.closedloop.INPUTS`), and returns :class:`~arvcas.sim.simulation.Result` objects::

    run = arvcas.Run(controller="proposed").compile()
    r = run.simulate(seed=0)                       # one run with its trace
    chat, rmse = run.batch(gains_matrix, seed=0)   # many gain sets, all cores
    chat, rmse, ok, t_fail = run.many(gains, seeds=range(100), uncertainty=U)   # Monte Carlo draws

Compiling never builds a CasADi graph when the compile cache holds the library: the cache key is
the description (controller identity and source, the scenario's graph-shaping fields, the options)
plus the package's model code and data (:func:`arvcas.build.provenance.model_hash`) and the
toolchain, so a warm start only loads a shared library. What a run computes is named by
:meth:`CompiledRun.digest` (the sha256 of its generated C), which a front records (docs/provenance.md).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas._version import __version__
from arvcas.build import calls, codegen
from arvcas.controllers import gains as gains_mod
from arvcas.controllers.base import Controller, get as get_controller, provenance
from arvcas.model.uvms import ModelOptions
from arvcas.system.loader import UNSET, renamed_system
from arvcas.system.params import Params, default_layout, system_tag
from arvcas.sim import accumulate, closedloop, limits, profiles, scenario, schedule, signals as signals_mod
from arvcas.sim.result import Result
from arvcas.sim.scenario import ScenarioConfig

__all__ = ["Run", "CompiledRun", "SimulationError", "MAX_RUNS", "CHAT_KINDS", "LOCKSTEP_MIN_RUNS"]

log = logging.getLogger(__name__)

MAX_RUNS = 10_000_000  # runs in one batch call (the outputs alone take 100 bytes a run)
# CHAT on the command (eq. 42, the paper's) or on the thrusters' delivered wrench: the run's output of each
CHAT_KINDS = {"commanded": "chat", "delivered": "chat_delivered"}
# A batch of at least this many runs goes through the lockstep library (arvcas.sim.lockstep) unless asked
# otherwise: compiling it once per machine and run description (5-15 s) costs about a thousand runs.
LOCKSTEP_MIN_RUNS = 64
LOCKSTEP_ENV = "ARVCAS_LOCKSTEP"
_OUT_BYTES = 2 * 8 * (6 + 6 + 1 + 1 + 6)  # a run's outputs (chat, rmse, ok, t_fail, chat_delivered) and copies



def _nonnegative_factors(unc: np.ndarray) -> None:
    """The nominal-model factors [C, D, g, arm] (rows of 4) scale model terms: each is >= 0 (the scenario's
    and a study's draws follow the same rule)."""
    bad = np.argwhere(np.asarray(unc) < 0)
    if bad.size:
        at = tuple(int(i) for i in bad[0])
        row = f"row {at[0]}, " if len(at) == 2 else ""
        name = "CDg"[at[-1]] if at[-1] < 3 else "arm"
        raise SimulationError(f"uncertainty: {row}factor {name} is {float(np.asarray(unc)[at]):g}; the nominal-model "
                              f"factors [C, D, g, arm] are >= 0")

class SimulationError(ValueError):
    """Bad input to a simulation (one line), raised before anything runs."""


@dataclass(frozen=True, init=False)
class Run:
    """The description of a closed-loop run: what to compile.

    ``controller``: a registered name or a :class:`~arvcas.controllers.Controller`; ``scenario``: a
    :class:`~arvcas.sim.scenario.ScenarioConfig`, a scenario file, or None (the system's default);
    ``system``: :class:`~arvcas.system.params.Params`, an :class:`arvcas.system.System`, a shipped
    system's name (``arvcas systems``), a system file, or None (the default system, :data:`arvcas.system.DEFAULT`);
    ``options``: :class:`~arvcas.model.uvms.ModelOptions`. ``params=``, the old name of ``system=``, still
    works with a DeprecationWarning.
    """

    controller: str | Controller = "proposed"
    scenario: ScenarioConfig | str | Path | None = None
    system: Params | str | Path | None = None
    options: ModelOptions = ModelOptions()
    accumulators: tuple = ()  # arvcas.sim.accumulate.Accumulator: the output "acc" (docs/objectives.md)

    def __init__(self, controller: str | Controller = "proposed", scenario: ScenarioConfig | str | Path | None = None,
                 system: Params | str | Path | None = None, options: ModelOptions = ModelOptions(),
                 accumulators: tuple = (), *, params=UNSET):
        for k, v in (("controller", controller), ("scenario", scenario),
                     ("system", renamed_system(system, params, "Run")), ("options", options),
                     ("accumulators", accumulators)):
            object.__setattr__(self, k, v)

    @property
    def params(self):
        """Deprecated: the old name of :attr:`system`."""
        import warnings

        warnings.warn("Run.params is now Run.system (Run.params will be removed)", DeprecationWarning, stacklevel=2)
        return self.system

    def compile(self) -> "CompiledRun":
        """The compiled run. Cheap when repeated: its compiled functions are memoised per process by
        description, loaded from the compile cache on a warm start, and its time table is kept."""
        from arvcas.system import resolve

        with_law = get_controller(self.controller)
        params = self.system if isinstance(self.system, Params) else resolve(self.system).params
        sc = self.scenario if self.scenario is not None else params.default("scenario")
        cfg = sc if isinstance(sc, ScenarioConfig) else scenario.load_scenario(sc)
        if not isinstance(self.options, ModelOptions):
            raise SimulationError(f"options: expected arvcas.model.uvms.ModelOptions, got {type(self.options).__name__}")
        limits.check_joint_limits(cfg, params)
        limits.check_trajectory_limits(cfg, params)
        schedule.check_table_memory(cfg, params.layout)
        _check_lag(cfg, params)
        return CompiledRun(with_law, cfg, params, self.options, tuple(self.accumulators))


def _check_lag(cfg: ScenarioConfig, params: Params) -> None:
    """The thruster lag's closed form holds ``exp(h / tau)``: a time constant below ``h / 700`` is refused
    (one line naming the parameter) before anything is built (docs/model.md §9)."""
    st = params.structure
    if not st.has_thruster_dynamics:
        if cfg.time_thrust_quadrature:
            raise SimulationError(f"{cfg.path or 'scenario'}: time.thrust_quadrature: only for a system with thruster "
                                  f"dynamics (docs/model.md §9); {params.path}'s thrusters deliver their thrust at once "
                                  f"(held over a sample, RK4 integrates it exactly): remove the key")
        return
    from arvcas.model.thrusters import LAG_EXP_LIMIT

    for n, d in zip(st.thrusters, st.thruster_dynamics):
        for key in (("time_constant_up", "time_constant_down") if d.asymmetric else ("time_constant",)):
            tau = params[f"thrusters.{n}.{key}"]
            if cfg.time_h / tau > LAG_EXP_LIMIT:
                raise SimulationError(f"{params.path}: thrusters.{n}.{key}: {tau:g} s is below h / {LAG_EXP_LIMIT:g} = "
                                      f"{cfg.time_h / LAG_EXP_LIMIT:g} s for the sample time h = {cfg.time_h:g} s "
                                      f"(the thruster is then instantaneous: use params.instantaneous())")


class CompiledRun:
    """A compiled closed-loop run (see the module docstring). Build it with :meth:`Run.compile`.

    ``inputs``: the names of one run's inputs; ``signals``: the traced signals
    (:mod:`arvcas.sim.signals`); ``artifact(trace)``: the compiled library's manifest (key, path...).
    """

    def __init__(self, controller: Controller, cfg: ScenarioConfig, params: Params, opts: ModelOptions,
                 accumulators: tuple = ()):
        self.controller = controller
        self.accumulators = tuple(accumulators)
        self.cfg = cfg
        self.params = params
        self.opts = opts
        self.signals = signals_mod.trace_signals(controller, params.structure)
        self.inputs = closedloop.INPUTS
        self._fns: dict[bool, ca.Function] = {}
        self._pv = params.vector()
        self._source: dict | None = None
        self._lockstep = None
        self._lockstep_failed = False

    # -- compiled functions ----------------------------------------------------------------------------
    def description(self, trace: bool) -> str:
        """What keys the compiled run in the cache (beside the package's model hash and the toolchain)."""
        law = self.controller
        system = system_tag(self.params.structure)
        acc = (" accumulators=" + ";".join(a.identity() for a in self.accumulators)) if self.accumulators else ""
        return (f"run controller={law.identity()} own_source={law.source_digest()} trace={trace} "
                f"scenario={self.cfg.graph_key()!r} options={self.opts!r}{system}{acc}")

    def _described(self, trace: bool):
        """(name, description, make) of the compiled run function (:func:`arvcas.build.codegen.build_described`)."""
        spec = closedloop.RunSpec(self.controller, self.cfg.graph_key(), self.opts, self.params.layout,
                                  self.accumulators)
        name = f"run_{self.controller.name}" + ("_trace" if trace else "")
        return name, self.description(trace), lambda: closedloop.build_run(spec, trace)

    def function(self, trace: bool) -> ca.Function:
        """The compiled run function (metrics only, or with the trace), loaded from the cache when it is there."""
        fn = self._fns.get(trace)
        if fn is None:
            name, desc, make = self._described(trace)
            memo = (name, desc, codegen.default_opt_level())
            fn = _FUNCTIONS.get(memo)
            if fn is None:
                what = f"the run for {self.params.structure.name} / {self.controller.name}" + (" (traced)" if trace else "")
                fn = codegen.build_described(name, desc, make, batch_loop=True, label=what)
                _FUNCTIONS[memo] = fn
            self._fns[trace] = fn
        return fn

    def digest(self) -> str:
        """sha256 (hex) of what a metrics-only run computes: the C that CasADi generates for the run
        function and for the two functions of its time table (:func:`arvcas.build.codegen.described_digest`).
        Equal digests, equal compiled arithmetic: a front computed by a run of this digest replays on it
        (with the same parameter vector and inputs). Compiles nothing; from the cache's manifests when
        it holds the run, else builds the graphs and generates their C (about a second for a run)."""
        import hashlib

        name, desc, make = self._described(False)
        parts = [codegen.described_digest(name, desc, make, batch_loop=True),
                 *schedule.digests(self.cfg, self.opts, self.params.layout)]
        h = hashlib.sha256(b"arvcas-run-digest-1")
        for part in parts:
            h.update(bytes.fromhex(part))
        return h.hexdigest()

    def compiled_functions(self, trace: bool = False) -> list[ca.Function]:
        """Every compiled function a run calls: the run itself and the two that build its time table
        (what a process without a compiler needs: :func:`arvcas.build.shipping.bundle`)."""
        return [self.function(trace), *schedule.functions(self.cfg, self.opts, self.params.layout)]

    def artifact(self, trace: bool = False) -> dict:
        return codegen.artifact_of(self.function(trace)) or {}

    @property
    def table(self) -> schedule.Table:
        """The run's time table (computed once per (scenario, p, options) and kept)."""
        return schedule.table(self.cfg, self._pv, self.opts, self.params.layout)

    # -- inputs ------------------------------------------------------------------------------------------
    def default_gains(self) -> np.ndarray:
        return gains_mod.default_gains(self.controller, self.params)

    def gain_names(self) -> list[str]:
        return gains_mod.gain_names(self.controller)

    def _gains(self, gains, batch: bool) -> np.ndarray:
        g = self.default_gains() if gains is None else gains
        g = gains_mod.check_gains(self.controller, g, h=self.cfg.time_h)
        if batch and g.ndim == 1:
            g = g[None, :]
        if not batch and g.ndim != 1:
            raise SimulationError(f"gains: simulate takes one gain vector of {gains_mod.n_gains(self.controller)}, "
                                  f"got shape {g.shape}")
        return g

    def _unc_phase(self, uncertainty, phase):
        unc = self.cfg.uncertainty if uncertainty is None else calls.real_array(uncertainty, "uncertainty", SimulationError)
        ph = np.array(self.cfg.disturbance_phase) if phase is None else calls.real_array(phase, "phase", SimulationError)
        if unc.shape != (4,) or not np.isfinite(unc).all():
            raise SimulationError(f"uncertainty: expected 4 finite factors [C, D, g, arm], got {unc}")
        _nonnegative_factors(unc)
        if ph.shape != (6,) or not np.isfinite(ph).all():
            raise SimulationError(f"phase: expected 6 finite disturbance phases (rad), got {ph}")
        return unc, ph

    def _shared(self) -> dict[str, np.ndarray]:
        tab = self.table
        return {"ekf": self.cfg.ekf_vector, "water": self.cfg.water_vector, "p": self._pv, "sched_time": tab.time,
                "sched_arm": tab.arm}

    # -- running ---------------------------------------------------------------------------------------
    def simulate(self, gains=None, seed: int = 0, uncertainty=None, phase=None, noise_scale: float = 1.0):
        """One run with its trace: a :class:`~arvcas.sim.simulation.Result`.

        ``noise_scale`` multiplies the drawn sensor noise (0: perfect measurements) while the EKF keeps
        the nominal sensor covariance: an analysis knob for how much noise reaches the thrusters.
        """
        g = self._gains(gains, batch=False)
        if isinstance(noise_scale, bool) or not (isinstance(noise_scale, (int, float)) and np.isfinite(noise_scale)
                                                 and noise_scale >= 0):
            raise SimulationError(f"noise_scale: must be a finite number >= 0, got {noise_scale!r}")
        noise = profiles.noise_sequence(self.cfg, seed) * float(noise_scale)
        unc, ph = self._unc_phase(uncertainty, phase)
        fn = self.function(trace=True)
        out = calls.call_named(fn, {"gains": g, "noise": noise, "unc": unc, "phase": ph, **self._shared()})
        tr = out["trace"]
        series, i = {}, 0
        st = self.params.structure
        for sig in self.signals:
            w = sig.n(st.n_thrusters, st.n_joints)
            block = tr[i:i + w, :].T
            series[sig.name] = block[:, 0].copy() if w == 1 else block.copy()
            i += w
        ok_b = bool(out["ok"].item() > 0.5)
        meta = self._meta(fn) | ({"noise_scale": float(noise_scale)} if noise_scale != 1.0 else {})
        if not ok_b:
            meta["failure"] = self._failure(series, float(out["t_fail"].item()))
        return Result(
            controller=self.controller.name, gains=np.asarray(g, dtype=float), seed=int(seed),
            chat=out["chat"].ravel(), rmse=out["rmse"].ravel(), ok=ok_b, chat_delivered=out["chat_delivered"].ravel(),
            t_fail=None if ok_b else float(out["t_fail"].item()),
            config_text=self.cfg.to_toml(), params_vector=self._pv.copy(), uncertainty=unc, phase=ph, h=self.cfg.time_h,
            meta=meta, signals=self.signals, series=series,
        )

    def _failure(self, series: dict, t_fail: float) -> str:
        """Why a traced run stopped at ``t_fail`` (the closed loop's checks, in docs/model.md §6's order):
        the tracking error beyond the scenario's limits, a controller command that is not finite (or
        above 1e12), or else the plant's state that the step from ``t_fail`` made non-finite (or >= 1e6)."""
        cfg = self.cfg
        k = min(int(round(t_fail / cfg.time_h)), len(series["eta"]) - 1)
        ref = cfg.reference()[:6, k] if cfg.has_trajectory else series["eta_ref"][k]  # docs/tasks.md
        e = np.abs(series["eta"][k] - ref)
        lim = np.array([cfg.limits_e_position] * 3 + [cfg.limits_e_attitude] * 3)
        dofs = "x y z phi theta psi".split()
        bad = [i for i in range(6) if not e[i] < lim[i]]
        if bad and np.isfinite(e[bad[0]]):
            i = bad[0]
            return (f"tracking error of {dofs[i]} {e[i]:.3g} {'m' if i < 3 else 'rad'} reached "
                    f"limits.{'e_position' if i < 3 else 'e_attitude'} ({lim[i]:g})")
        tau = series["tau_cmd"][k]
        if not (np.isfinite(tau).all() and np.abs(tau).max() < 1e12):
            return "the controller's command is not finite or above 1e12 (gains or controller state)"
        return (f"the plant's state became non-finite (NaN or inf) or reached 1e6 in the step after t = "
                f"{t_fail:g} s: the model gives no finite motion there (check the system's numbers and inputs)")

    def _meta(self, fn: ca.Function) -> dict:
        art = codegen.artifact_of(fn) or {}
        meta = {"artifact_key": art.get("key"), "artifact_flags": art.get("flags"),
                "scenario_file": self.cfg.path, "casadi_version": ca.__version__, "arvcas_version": __version__}
        st = self.params.structure
        if st != default_layout().structure:  # another system: its name, file and parameter names
            meta |= {"system": st.name, "system_file": self.params.path, "param_names": self.params.names()}
        if self._source is None:  # a law from outside the package: where it came from, its source's digest
            self._source = provenance(self.controller)
        if self._source:
            meta["controller_source"] = self._source
        return meta

    def batch(self, gains, seed: int = 0, uncertainty=None, phase=None, n_threads: int | None = None,
              return_status: bool = False, chat: str = "commanded", lockstep: bool | None = None):
        """Many gain sets (n x n_gains) on the same noise (``seed``), uncertainty and disturbance.

        Returns ``(chat (n x 6), rmse (n x 6))``; with ``return_status`` also ``(ok (n,), t_fail (n,))``.
        A diverged run has ``ok = False`` and NaN metrics. ``chat``: ``"commanded"`` (eq. 42 on tau_v) or
        ``"delivered"`` (on the thrusters' delivered wrench, docs/model.md §6). ``lockstep``: run W runs at
        once per core (:mod:`arvcas.sim.lockstep`; the same bits); None: when :meth:`uses_lockstep` says so.
        More gain sets than half this machine's memory holds the runs of are refused (one line naming
        ``gains``) before anything is compiled or allocated.
        """
        g = self._gains(gains, batch=True)
        self._check_batch_memory("batch", g)
        unc, ph = self._unc_phase(uncertainty, phase)
        noise = profiles.noise_sequence(self.cfg, seed)
        chat, rmse, ok, t_fail = self._evaluate(g.shape[0], {"gains": g.T, "noise": noise, "unc": unc, "phase": ph},
                                                {"gains"}, n_threads, chat, lockstep)
        return (chat, rmse, ok, t_fail) if return_status else (chat, rmse)

    def _check_batch_memory(self, method: str, g: np.ndarray) -> None:
        """Refuse (one line naming ``gains``) n gain sets whose runs' outputs (with their copies and the
        accumulators' rows) and the gains as float64 (a copy when given as a list or another dtype) would
        take more than half this machine's memory: before the run is compiled or its outputs allocated
        (:meth:`many` bounds its noise blocks the same way)."""
        n, st = g.shape[0], self.params.structure
        n_events = len(accumulate.event_times(self.cfg)) if self.accumulators else 0
        acc = sum(accumulate.width(a, st.n_thrusters, n_events) for a in self.accumulators)
        calls.check_memory(f"gains: {n} gain sets ({method}: one run each)",
                           n * (8 * g.shape[1] + _OUT_BYTES + 2 * 8 * acc), error=SimulationError)

    def many(self, gains, seeds, uncertainty=None, phase=None, n_threads: int | None = None, chat: str = "commanded",
             lockstep: bool | None = None):
        """n draws: row i has its own gains (or shared), noise seed, uncertainty factors and phases.

        ``gains``: (n_gains,) or (n, n_gains); ``seeds``: (n,) non-negative integers; ``uncertainty``:
        None, (4,) or (n, 4); ``phase``: None, (6,) or (n, 6). Returns ``(chat, rmse, ok, t_fail)``;
        ``chat`` and ``lockstep`` as :meth:`batch`.
        """
        seeds = calls.integer_array(seeds, "seeds", SimulationError, max_size=MAX_RUNS)
        if seeds.ndim != 1 or seeds.size == 0:
            raise SimulationError(f"seeds: expected a non-empty 1-D sequence of integers, got shape {seeds.shape}")
        n = seeds.size
        if n > MAX_RUNS:
            raise SimulationError(f"runs: {n} in one call is more than the {MAX_RUNS} allowed; split the batch")
        g = self._gains(gains, batch=True)
        if g.shape[0] not in (1, n):
            raise SimulationError(f"gains: {g.shape[0]} gain sets for {n} seeds (give 1 or {n})")
        G = np.broadcast_to(g, (n, g.shape[1]))
        unc0, ph0 = self._unc_phase(None, None)

        def rows(v, default, k, name):
            a = calls.real_array(default if v is None else v, name, SimulationError)
            if a.shape == (k,):
                a = np.broadcast_to(a, (n, k))
            if a.shape != (n, k) or not np.isfinite(a).all():
                raise SimulationError(f"{name}: expected ({k},) or ({n}, {k}) finite values, got shape {a.shape}")
            return a

        U = rows(uncertainty, unc0, 4, "uncertainty")
        _nonnegative_factors(U)
        PH = rows(phase, ph0, 6, "phase")
        first = profiles.noise_sequence(self.cfg, int(seeds[0]))  # every draw's noise block has its shape
        k = first.shape[1]
        # bounded before allocating: n noise blocks, the per-run inputs, the outputs (and their copies)
        calls.check_memory(f"many: {n} runs", n * (first.nbytes + 8 * (G.shape[1] + 4 + 6) + _OUT_BYTES),
                           error=SimulationError)
        noise = np.empty((first.shape[0], n * k), order="F")  # as call_named reads it: no copy
        noise[:, :k] = first
        for i in range(1, n):
            noise[:, i * k:(i + 1) * k] = profiles.noise_sequence(self.cfg, int(seeds[i]))
        return self._evaluate(n, {"gains": G.T, "noise": noise, "unc": U.T, "phase": PH.T},
                              {"gains", "noise", "unc", "phase"}, n_threads, chat, lockstep)

    def outputs(self, gains, seed: int = 0, uncertainty=None, phase=None, n_threads: int | None = None) -> dict:
        """Many gain sets (n x n_gains) on one draw, as :meth:`batch`: every output of the metrics-only run by
        name, one row per run (``chat``, ``chat_delivered``, ``rmse`` (n, 6), ``ok``, ``t_fail`` (n,), and with
        accumulators ``acc`` (n, rows)), as the run returned them (not NaN-masked)."""
        g = self._gains(gains, batch=True)
        unc, ph = self._unc_phase(uncertainty, phase)
        n = g.shape[0]
        if n > MAX_RUNS:
            raise SimulationError(f"runs: {n} in one call is more than the {MAX_RUNS} allowed; split the batch")
        self._check_batch_memory("outputs", g)
        out = calls.call_named(self.function(trace=False), {"gains": g.T, "noise": profiles.noise_sequence(self.cfg, seed),
                                                            "unc": unc, "phase": ph, **self._shared()},
                               n=n, per_run={"gains"}, n_threads=_n_threads(n_threads))
        return {k: (v.ravel().copy() if v.shape[0] == 1 else v.T.copy()) for k, v in out.items()}

    # -- lockstep ----------------------------------------------------------------------------------------
    def lockstep(self):
        """The lockstep run (:class:`arvcas.sim.lockstep.LockstepRun`: W runs per core, the same bits),
        built on first use or loaded from the compile cache."""
        if self._lockstep is None:
            from arvcas.sim import lockstep

            self._lockstep = lockstep.build(self)
        return self._lockstep

    def uses_lockstep(self, n: int, lockstep: bool | None = None) -> bool:
        """Whether n runs go through :meth:`lockstep`: ``lockstep`` if given (True: its build errors are
        raised); else (None) when n >= :data:`LOCKSTEP_MIN_RUNS` (its library, compiled once per machine
        and run description, costs about as much as a thousand runs) unless ``ARVCAS_LOCKSTEP=0``, and
        when it can be built here (a Dask worker without a compiler runs one at a time)."""
        if lockstep is not None:
            if not isinstance(lockstep, bool):
                raise SimulationError(f"lockstep: expected True, False or None, got {lockstep!r}")
            if lockstep and (self.accumulators or self.cfg.has_trajectory):
                raise SimulationError("lockstep: a run with accumulators (objectives beyond CHAT and RMSE) or a "
                                      "trajectory runs one at a time")
            return lockstep
        mode = os.environ.get(LOCKSTEP_ENV, "auto")
        if mode not in ("auto", "0", "1"):
            raise SimulationError(f"{LOCKSTEP_ENV}={mode!r}: expected 0 (never), 1 (always) or auto (n >= "
                                  f"{LOCKSTEP_MIN_RUNS})")
        # a run with accumulators (a study's own objectives) or a task's trajectory runs one at a time: the
        # lockstep library carries the paper's outputs and the station-keeping reference only
        if mode == "0" or (mode == "auto" and n < LOCKSTEP_MIN_RUNS) or self._lockstep_failed or self.accumulators \
                or self.cfg.has_trajectory:
            return False
        try:
            self.lockstep()
        except (codegen.CompileError, codegen.CacheError) as e:
            log.info("lockstep runs unavailable (%s): one run at a time", e)
            self._lockstep_failed = True
            return False
        return True

    def _evaluate(self, n: int, varying: dict, per_run: set, n_threads, chat: str = "commanded",
                  lockstep: bool | None = None):
        """n metrics-only runs on the thread pool; the inputs in ``per_run`` have a column block per run,
        the others and the time table are shared. NaN metrics for a diverged run."""
        if n > MAX_RUNS:
            raise SimulationError(f"runs: {n} in one call is more than the {MAX_RUNS} allowed; split the batch")
        if chat not in CHAT_KINDS:
            raise SimulationError(f"chat: expected one of {', '.join(CHAT_KINDS)}, got {chat!r}")
        calls.check_memory(f"runs: {n}", n * _OUT_BYTES, error=SimulationError)
        nt = _n_threads(n_threads)
        if self.uses_lockstep(n, lockstep):
            ls, names = self.lockstep(), closedloop.INPUTS
            shapes = {"gains": (len(self.gain_names()), 1), "noise": (12, scenario.n_samples(self.cfg)), "unc": (4, 1),
                      "phase": (6, 1), "ekf": (self.cfg.ekf_vector.size, 1), "water": (self.cfg.water_vector.size, 1),
                      "p": (len(self._pv), 1)}
            inputs = {**varying, **self._shared()}
            bound = []
            for k in names:
                a = inputs[k]
                if k in shapes:
                    r, c = shapes[k]
                    a = calls.fortran(a, (r, c * n if k in per_run else c))
                else:
                    a = calls.fortran(a, a.shape)
                bound.append(a)
            outs = [np.empty((ls.function.size1_out(k), n), order="F") for k in closedloop.OUTPUTS]
            ls.evaluate(n, bound, set(per_run), outs, nt)
            out = dict(zip(closedloop.OUTPUTS, outs))
        else:
            fn = self.function(trace=False)
            out = calls.call_named(fn, {**varying, **self._shared()}, n=n, per_run=per_run, n_threads=nt)
        ok = out["ok"].ravel() > 0.5
        chat, rmse = out[CHAT_KINDS[chat]].T.copy(), out["rmse"].T.copy()
        chat[~ok] = np.nan
        rmse[~ok] = np.nan
        return chat, rmse, ok, np.where(ok, np.nan, out["t_fail"].ravel())


_FUNCTIONS: dict[tuple, ca.Function] = {}


def _n_threads(n_threads: int | None) -> int:
    if n_threads is None:
        try:
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:  # pragma: no cover
            return max(1, os.cpu_count() or 1)
    if isinstance(n_threads, bool) or not isinstance(n_threads, int) or not 1 <= n_threads <= 1024:
        raise SimulationError(f"n_threads: must be an integer in [1, 1024], got {n_threads!r}")
    return n_threads
