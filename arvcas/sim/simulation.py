"""The closed-loop experiment's Python API: :class:`Result` (:mod:`arvcas.sim.result`) and the thin
wrappers :func:`simulate`, :func:`simulate_batch`, :func:`simulate_many` over :class:`arvcas.sim.run.Run`.

Each wrapper describes a run, compiles it (a dictionary lookup after the first time in a process;
a library load, without building any graph, after the first time on a machine) and calls it: a new
gain set, seed or parameter value never recompiles. The run's time table (:mod:`arvcas.sim.schedule`)
is computed once per (scenario, p) and shared by every run of a batch.
"""

from __future__ import annotations

from arvcas.controllers import gains as gains_mod
from arvcas.model.uvms import ModelOptions
from arvcas.system.loader import UNSET, renamed_system
from arvcas.system.params import Params
from arvcas.sim.result import Result
from arvcas.sim.run import CompiledRun, Run, SimulationError
from arvcas.sim.scenario import ScenarioConfig

__all__ = ["Result", "simulate", "simulate_batch", "simulate_many", "default_gains", "compiled_run", "run_function",
           "SimulationError"]

default_gains = gains_mod.default_gains


def compiled_run(controller, system: Params | None = None, cfg: ScenarioConfig | None = None,
                 opts: ModelOptions = ModelOptions(), accumulators: tuple = (), *, params=UNSET) -> CompiledRun:
    """``Run(controller, cfg, system, opts, accumulators).compile()``, memoised per process (the wrappers' path).
    ``system``: a :class:`~arvcas.system.params.Params` or None (the default system); ``params=``: its old name."""
    system = renamed_system(system, params, "compiled_run")
    if system is not None and not isinstance(system, Params):
        raise SimulationError(f"system: expected arvcas.system.params.Params, got {type(system).__name__}")
    key = (gains_mod.get(controller), cfg, system, opts) + ((tuple(accumulators),) if accumulators else ())
    run = _COMPILED.get(key)
    if run is None:
        run = _COMPILED[key] = Run(controller=key[0], scenario=cfg, system=system, options=opts,
                                   accumulators=tuple(accumulators)).compile()
        while len(_COMPILED) > 32:
            _COMPILED.pop(next(iter(_COMPILED)))
    return run


_COMPILED: dict = {}


def run_function(controller, cfg: ScenarioConfig | None, trace: bool, opts: ModelOptions = ModelOptions()):
    """The compiled run function of ``controller`` (:meth:`CompiledRun.function`)."""
    return compiled_run(controller, None, cfg, opts).function(trace)


def simulate(controller: str, gains=None, seed: int = 0, system: Params | None = None,
             cfg: ScenarioConfig | None = None, uncertainty=None, phase=None,
             opts: ModelOptions = ModelOptions(), noise_scale: float = 1.0, *, params=UNSET) -> Result:
    """Run the station-keeping experiment once (compiled) and return its :class:`Result`
    (:meth:`CompiledRun.simulate`). ``system``: a Params or None (the default system); ``params=``: its old name."""
    return compiled_run(controller, renamed_system(system, params, "simulate"), cfg, opts).simulate(gains, seed, uncertainty, phase, noise_scale)


def simulate_batch(controller: str, gains, seed: int = 0, system: Params | None = None,
                   cfg: ScenarioConfig | None = None, uncertainty=None, phase=None,
                   n_threads: int | None = None, opts: ModelOptions = ModelOptions(),
                   return_status: bool = False, chat: str = "commanded", lockstep: bool | None = None, *,
                   params=UNSET):
    """Many gain sets (n x n_gains) on common random numbers (:meth:`CompiledRun.batch`)."""
    return compiled_run(controller, renamed_system(system, params, "simulate_batch"), cfg, opts).batch(gains, seed, uncertainty, phase, n_threads,
                                                             return_status, chat, lockstep)


def simulate_many(controller: str, gains, seeds, uncertainty=None, phase=None, system: Params | None = None,
                  cfg: ScenarioConfig | None = None, n_threads: int | None = None,
                  opts: ModelOptions = ModelOptions(), lockstep: bool | None = None, *, params=UNSET):
    """n draws, each with its own seed, factors and phases: the Monte Carlo path (:meth:`CompiledRun.many`)."""
    return compiled_run(controller, renamed_system(system, params, "simulate_many"), cfg, opts).many(gains, seeds, uncertainty, phase, n_threads,
                                                            lockstep=lockstep)
