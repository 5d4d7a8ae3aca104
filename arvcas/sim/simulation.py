"""The closed-loop experiment's Python API: :class:`Result` and the thin wrappers :func:`simulate`,
:func:`simulate_batch`, :func:`simulate_many` over :class:`arvcas.sim.run.Run`.

Each wrapper describes a run, compiles it (a dictionary lookup after the first time in a process;
a library load, without building any graph, after the first time on a machine) and calls it: a new
gain set, seed or parameter value never recompiles. The run's time table (:mod:`arvcas.sim.schedule`)
is computed once per (scenario, p) and shared by every run of a batch.
"""

from __future__ import annotations

import numpy as np

from arvcas import __version__
from arvcas.controllers import gains as gains_mod
from arvcas.model.uvms import ModelOptions
from arvcas.params import Params
from arvcas.sim import signals as signals_mod
from arvcas.sim.run import CompiledRun, Run, SimulationError
from arvcas.sim.scenario import ScenarioConfig

__all__ = ["Result", "simulate", "simulate_batch", "simulate_many", "default_gains", "compiled_run", "run_function",
           "SimulationError"]

default_gains = gains_mod.default_gains


class Result:
    """One closed-loop run: the traced signals at the controller samples, the metrics, the provenance.

    Every traced signal (:mod:`arvcas.sim.signals`: ``t``, ``eta``, ``nu``, ``eta_hat``, ``eta_ref``,
    ``tau_cmd``, ``thrust``, ``f_true``, ``q``, ``payload`` and the controller's own, e.g. ``s``,
    ``k1``, ``k2``, ``f_hat``) is an attribute and an item (``r.eta``, ``r["eta"]``), an array of shape
    (N+1,) or (N+1, width) over samples t_k = k h, k = 0..N, in the signal's units and frame
    (``r.signals`` describes them). ``chat`` (eq. 42) and ``rmse`` (eq. 43) have shape (6,);
    ``chat_delivered`` (6,) is eq. 42 on the thrusters' delivered wrench (docs/model.md §6; None for a
    result read from a file written before it existed).
    """

    FIELDS = ("controller", "gains", "seed", "chat", "rmse", "ok", "t_fail", "config_text", "params_vector",
              "uncertainty", "phase", "h", "version", "meta", "chat_delivered")

    def __init__(self, controller: str, gains, seed: int, chat, rmse, ok: bool, t_fail: float | None,
                 config_text: str = "", params_vector=None, uncertainty=None, phase=None, h: float = 0.1,
                 version: str = __version__, meta: dict | None = None, signals=None, series: dict | None = None,
                 chat_delivered=None, **named_series):
        given = locals()
        self.__dict__.update({k: given[k] for k in self.FIELDS})
        self.meta = {} if meta is None else meta
        self.series: dict[str, np.ndarray] = {**(series or {}), **named_series}
        if signals is None:  # the registered controller's signals (or the common ones)
            try:
                signals = signals_mod.trace_signals(gains_mod.get(controller))
            except ValueError:
                signals = signals_mod.COMMON
        self.signals = tuple(s for s in signals if s.name in self.series)
        order = [s.name for s in self.signals]  # series in signal-table order, then any undescribed ones
        self.series = {k: self.series[k] for k in order + [k for k in self.series if k not in order]}

    def __getattr__(self, name: str):
        series = self.__dict__.get("series")
        if series is not None and name in series:
            return series[name]
        raise AttributeError(f"Result has no attribute or signal {name!r}"
                             + (f" (signals: {', '.join(series)})" if series else ""))

    def __setattr__(self, name: str, value) -> None:
        series = self.__dict__.get("series")
        if series is not None and name in series:
            series[name] = value
        else:
            object.__setattr__(self, name, value)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.series[name]

    @property
    def e(self) -> np.ndarray:
        """Tracking error eta - eta_ref (the RMSE's e, eq. 43)."""
        return self.eta - self.eta_ref

    @property
    def diverged(self) -> bool:
        return not self.ok

    @property
    def duration(self) -> float:
        t = self.series.get("t")
        return float(t[-1]) if t is not None and len(t) else 0.0

    def __repr__(self) -> str:
        status = "ok" if self.ok else f"diverged at t = {self.t_fail:g} s"
        fmt = lambda v: "[" + ", ".join(f"{x:.3g}" for x in np.asarray(v, dtype=float).ravel()) + "]"  # noqa: E731
        chat, rmse = fmt(self.chat), fmt(self.rmse)
        return (f"<Result {self.controller}, seed {self.seed}, {self.duration:g} s, {status}; "
                f"CHAT {chat}, RMSE {rmse}>")


def compiled_run(controller, params: Params | None = None, cfg: ScenarioConfig | None = None,
                 opts: ModelOptions = ModelOptions()) -> CompiledRun:
    """``Run(controller, cfg, params, opts).compile()``, memoised per process (the wrappers' path)."""
    if params is not None and not isinstance(params, Params):
        raise SimulationError(f"params: expected arvcas.params.Params, got {type(params).__name__}")
    key = (gains_mod.get(controller), cfg, params, opts)
    run = _COMPILED.get(key)
    if run is None:
        run = _COMPILED[key] = Run(controller=key[0], scenario=cfg, params=params, options=opts).compile()
        while len(_COMPILED) > 32:
            _COMPILED.pop(next(iter(_COMPILED)))
    return run


_COMPILED: dict = {}


def run_function(controller, cfg: ScenarioConfig | None, trace: bool, opts: ModelOptions = ModelOptions()):
    """The compiled run function of ``controller`` (:meth:`CompiledRun.function`)."""
    return compiled_run(controller, None, cfg, opts).function(trace)


def simulate(controller: str, gains=None, seed: int = 0, params: Params | None = None,
             cfg: ScenarioConfig | None = None, uncertainty=None, phase=None,
             opts: ModelOptions = ModelOptions(), noise_scale: float = 1.0) -> Result:
    """Run the station-keeping experiment once (compiled) and return its :class:`Result`
    (:meth:`CompiledRun.simulate`)."""
    return compiled_run(controller, params, cfg, opts).simulate(gains, seed, uncertainty, phase, noise_scale)


def simulate_batch(controller: str, gains, seed: int = 0, params: Params | None = None,
                   cfg: ScenarioConfig | None = None, uncertainty=None, phase=None,
                   n_threads: int | None = None, opts: ModelOptions = ModelOptions(),
                   return_status: bool = False, chat: str = "commanded"):
    """Many gain sets (n x n_gains) on common random numbers (:meth:`CompiledRun.batch`)."""
    return compiled_run(controller, params, cfg, opts).batch(gains, seed, uncertainty, phase, n_threads,
                                                             return_status, chat)


def simulate_many(controller: str, gains, seeds, uncertainty=None, phase=None, params: Params | None = None,
                  cfg: ScenarioConfig | None = None, n_threads: int | None = None,
                  opts: ModelOptions = ModelOptions()):
    """n draws, each with its own seed, factors and phases: the Monte Carlo path (:meth:`CompiledRun.many`)."""
    return compiled_run(controller, params, cfg, opts).many(gains, seeds, uncertainty, phase, n_threads)
