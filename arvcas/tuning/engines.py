"""Where a generation is evaluated: ``local`` (all cores of this machine) or ``dask`` (a cluster).

Both call the same top-level function, :func:`evaluate_rows`, which runs
:func:`arvcas.sim.simulation.simulate_batch` once per draw on a block of gain sets and returns the
per-DOF metrics with the build key of the compiled run it used. The ``dask`` engine splits the
population into contiguous chunks, ``client.map`` s them to the workers and concatenates the results
in order; every run is independent of the others in its batch, so the generation's numbers, and
therefore the front, are the same bit for bit as with the ``local`` engine: the workers run the
client's own compiled code. The client ships it: the libraries of the run and of its time table, as
bytes with their sha256 (:func:`ship_bundle`, scattered once to every worker), which a worker loads
without a C compiler or a compile cache (:func:`arvcas.build.shipping.preload`; a worker on another
platform, or with other arvcas model code, refuses with a one-line error naming it). The engine still
checks that every chunk reports the client's key. An error raised on a worker says which worker. A
controller from a plugin file or module is loaded on each worker from the same file or module
(:attr:`EvalTask.plugins`; an entry point is found there by itself): the file must be at the same
path on the workers' machines, and its source digest is part of the key they check.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass

import numpy as np

from arvcas.system.params import Params
from arvcas.sim.scenario import ScenarioConfig

log = logging.getLogger(__name__)

__all__ = ["EngineError", "EvalTask", "evaluate_rows", "run_key", "ship_bundle", "LocalEngine", "DaskEngine",
           "make_engine"]


class EngineError(ValueError):
    """One-line error about the evaluation engine (connection, mismatched compiled code)."""


@dataclass(frozen=True)
class EvalTask:
    """What every candidate is evaluated on: controller, draws (seed, uncertainty, phase), scenario, params."""

    controller: str
    draws: tuple  # ((noise_seed, uncertainty (4,), phase (6,)), ...) resolved
    cfg: ScenarioConfig
    params: Params
    ref: tuple | None = None  # per-DOF (chat, rmse) normalisation; None: the paper's Table 3 AGSTA
    plugins: tuple[str, ...] = ()  # plugin files or modules a worker loads first (the controller's)
    chat: str = "commanded"  # CHAT on the command (eq. 42) or on the delivered wrench ([objectives] chat)
    # other objectives or constraints than the paper's (docs/objectives.md): the accumulators the compiled run
    # carries for them; none: the paper's run and evaluation, unchanged
    accumulators: tuple = ()
    normalisation: str = ""  # where ``ref`` comes from (arvcas.tuning.run.normalisation), in words


def run_key(controller: str, cfg: ScenarioConfig, params: Params | None = None, accumulators: tuple = ()) -> str:
    """Content hash of the compiled metrics-only run (built or loaded from the cache)."""
    from arvcas.build import codegen
    from arvcas.sim.simulation import compiled_run

    m = codegen.artifact_of(compiled_run(controller, params, cfg, accumulators=accumulators).function(False))
    return "" if m is None else str(m["key"])


def ship_bundle(run) -> dict:
    """The compiled libraries a :class:`~arvcas.sim.run.CompiledRun` of metrics-only runs needs, as bytes."""
    from arvcas.build import shipping

    return shipping.bundle(run.compiled_functions(trace=False))


def evaluate_rows(task: EvalTask, gains: np.ndarray, n_threads: int | None = None):
    """Run every draw on the gain sets ``gains`` (n, n_gains) in one batched call per draw.

    Returns ``(chat (K, n, 6), rmse (K, n, 6), ok (K, n), t_fail (K, n), key)``.
    Top level (importable) so that Dask workers can run it.
    """
    from arvcas.sim.simulation import compiled_run, simulate_batch

    if task.accumulators:  # every output by name, per draw (docs/objectives.md)
        run = compiled_run(task.controller, task.params, task.cfg, accumulators=task.accumulators)
        kind = "chat" if task.chat == "commanded" else "chat_delivered"
        outs = [run.outputs(gains, seed, unc, ph, n_threads) for seed, unc, ph in task.draws]
        outs = [{**o, "chat": o[kind]} for o in outs]
        return outs, run_key(task.controller, task.cfg, task.params, task.accumulators)
    outs = [simulate_batch(task.controller, gains, seed=seed, system=task.params, cfg=task.cfg,
                           uncertainty=unc, phase=ph, n_threads=n_threads, return_status=True, chat=task.chat)
            for seed, unc, ph in task.draws]
    chat = np.stack([o[0] for o in outs])
    rmse = np.stack([o[1] for o in outs])
    ok = np.stack([o[2] for o in outs])
    t_fail = np.stack([o[3] for o in outs])
    return chat, rmse, ok, t_fail, run_key(task.controller, task.cfg, task.params)


class LocalEngine:
    """This machine: ``simulate_batch`` over ``threads`` cores (0 = all this process may use)."""

    name = "local"

    def __init__(self, threads: int = 0):
        self.threads = threads or _cores()
        self._key: dict = {}

    def describe(self) -> str:
        return f"local, {self.threads} thread(s)"

    def prepare(self, task: EvalTask) -> str:
        k = (task.controller, task.cfg.graph_key(), task.params.structure, task.accumulators)
        if k not in self._key:
            self._key[k] = run_key(task.controller, task.cfg, task.params, task.accumulators)
        return self._key[k]

    def evaluate(self, task: EvalTask, gains: np.ndarray):
        """``(chat, rmse, ok, t_fail)`` (K, n, ...); with accumulators a list of K dicts of outputs."""
        res = evaluate_rows(task, gains, n_threads=self.threads)
        return res[0] if task.accumulators else res[:4]

    def close(self) -> None:
        pass


def _cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover
        return max(1, os.cpu_count() or 1)


def _chunk(task: EvalTask, gains: np.ndarray, n_threads: int, bundle: dict | None = None):
    """Dask task: one contiguous block of the population, on the client's shipped libraries."""
    from arvcas.build import shipping

    try:
        from arvcas.util import plugins

        for spec in task.plugins:
            plugins.load(spec, what="plugin")
        if bundle is not None:
            shipping.preload(bundle)
        return evaluate_rows(task, gains, n_threads=n_threads)
    except Exception as e:  # noqa: BLE001 - say where it happened, in one line
        here = shipping.process_name()
        msg = " ".join(str(e).split()) or type(e).__name__
        raise EngineError(msg if msg.startswith(here) else f"{here}: {type(e).__name__}: {msg}") from None


class DaskEngine:
    """A Dask cluster: ``scheduler`` address, or a local cluster on 127.0.0.1 when None.

    Connecting is bounded by ``timeout_s``; an unreachable scheduler is an :class:`EngineError`.
    The population is split into one chunk per worker thread (at most one row per chunk). Every wait
    is bounded: while a generation runs, a cluster with no worker (all lost) or a lost scheduler for
    more than ``timeout_s`` ends the generation with an :class:`EngineError` (the study keeps the last
    checkpoint); a generation that merely takes long is not cut short. A generation that fails because
    workers were lost while others remain (their tasks, or the shipped libraries they held, are gone) is
    evaluated again, the libraries scattered anew to the workers there are, at most :data:`RETRIES` times:
    every chunk is deterministic, so the numbers are the same.
    """

    POLL_S = 0.5
    RETRIES = 3

    name = "dask"

    def __init__(self, scheduler: str | None = None, workers: int = 0, timeout_s: float = 10.0):
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise EngineError("engine dask: the 'distributed' package is not installed "
                              "(pip install 'arvcas[dask]')") from None
        if not (isinstance(timeout_s, (int, float)) and 0 < timeout_s < float("inf")):
            raise EngineError(f"engine dask: timeout must be a finite number of seconds > 0, got {timeout_s!r}")
        self.scheduler = scheduler
        self.timeout_s = float(timeout_s)
        self._cluster = None
        self._keys: dict = {}
        self._bundles: dict = {}
        self._raw: dict = {}  # the bundles' bytes, to scatter again after a lost worker
        try:
            if scheduler is None:
                n = workers or _cores()
                self._cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                             host="127.0.0.1", dashboard_address=None,
                                             silence_logs=logging.ERROR)
                self.client = Client(self._cluster, timeout=f"{timeout_s}s", set_as_default=False)
            else:
                self.client = Client(scheduler, timeout=f"{timeout_s}s", set_as_default=False)
        except (OSError, TimeoutError) as e:
            self.close()
            msg = " ".join(str(e).split()) or type(e).__name__
            where = scheduler or "local cluster"
            raise EngineError(f"engine dask: cannot connect to scheduler {where} within {timeout_s:g} s ({msg})") from None
        if scheduler is not None:
            try:
                self.client.wait_for_workers(1, timeout=timeout_s)
            except (OSError, TimeoutError):
                self.close()
                raise EngineError(f"engine dask: scheduler {scheduler} has no workers after {timeout_s:g} s") from None

    def threads(self) -> list[int]:
        """Threads per worker, in a stable order."""
        info = self.client.nthreads()
        return [info[w] for w in sorted(info)]

    def describe(self) -> str:
        th = self.threads()
        where = self.scheduler or "local cluster on 127.0.0.1"
        return f"dask ({where}), {len(th)} worker(s), {sum(th)} thread(s)"

    def prepare(self, task: EvalTask) -> str:
        """The run's key; compiles it here (once) and scatters its libraries to every worker."""
        from arvcas.sim.simulation import compiled_run

        k = (task.controller, task.cfg.graph_key(), task.params.structure, task.accumulators)
        if k not in self._keys:
            self._keys[k] = run_key(task.controller, task.cfg, task.params, task.accumulators)
            self._raw[k] = ship_bundle(compiled_run(task.controller, task.params, task.cfg,
                                                    accumulators=task.accumulators))
            self._scatter(k)
        return self._keys[k]

    def _scatter(self, k) -> None:
        """Send the bundle ``k`` to every worker there is now (again after a loss)."""
        self._bundles[k] = self.client.scatter([self._raw[k]], broadcast=True, hash=False)[0]  # a list: one future

    def evaluate(self, task: EvalTask, gains: np.ndarray):
        key = self.prepare(task)
        k = (task.controller, task.cfg.graph_key(), task.params.structure, task.accumulators)
        n = gains.shape[0]
        for attempt in range(self.RETRIES + 1):
            try:
                parts = self._evaluate_once(task, gains, self._bundles[k])
                break
            except EngineError:
                raise
            except (ValueError, KeyboardInterrupt):
                raise
            except Exception as e:  # noqa: BLE001 - a lost worker or connection: one line, not a traceback
                msg = " ".join(str(e).split())[:200] or "no message"
                if attempt < self.RETRIES and self.client.status == "running" and self.client.nthreads():
                    log.warning("engine dask: generation lost work (%s: %s); evaluating it again on %d worker(s)",
                                type(e).__name__, msg, len(self.client.nthreads()))
                    try:
                        self._scatter(k)
                    except Exception:  # noqa: BLE001 - the next attempt (or the last error) says what is wrong
                        pass
                    continue
                raise EngineError(f"engine dask: evaluating the generation failed ({type(e).__name__}: {msg})"
                                  + (f" after {attempt} retries" if attempt else "")) from None
        if task.accumulators:  # each part: (K dicts of outputs, key)
            for p in parts:
                if p[1] != key:
                    raise EngineError(f"engine dask: a worker ran compiled code {p[1][:20] or '?'}, this process "
                                      f"{key[:20]}: results would not be identical (different arvcas, CasADi or compiler)")
            return [{name: np.concatenate([p[0][d][name] for p in parts], axis=0) for name in parts[0][0][d]}
                    for d in range(len(task.draws))]
        assert sum(p[0].shape[1] for p in parts) == n
        for p in parts:
            if p[4] != key:
                raise EngineError(f"engine dask: a worker ran compiled code {p[4][:20] or '?'}, this process "
                                  f"{key[:20]}: results would not be identical (different arvcas, CasADi or compiler)")
        chat = np.concatenate([p[0] for p in parts], axis=1)
        rmse = np.concatenate([p[1] for p in parts], axis=1)
        ok = np.concatenate([p[2] for p in parts], axis=1)
        t_fail = np.concatenate([p[3] for p in parts], axis=1)
        return chat, rmse, ok, t_fail

    def _evaluate_once(self, task: EvalTask, gains: np.ndarray, bundle) -> list:
        n = gains.shape[0]
        n_chunks = max(1, min(n, sum(self.threads())))
        blocks = [b for b in np.array_split(np.arange(n), n_chunks) if b.size]
        futures = self.client.map(_chunk, [task] * len(blocks), [gains[b] for b in blocks],
                                  [1] * len(blocks), [bundle] * len(blocks), pure=False)
        self._wait(futures)
        return self.client.gather(futures)

    def _wait(self, futures) -> None:
        """Until every future is done; EngineError once the cluster has had no worker (or no scheduler
        connection) for ``timeout_s``."""
        since = None
        while True:
            if all(f.status == "finished" for f in futures):
                return
            time.sleep(min(self.POLL_S, self.timeout_s))
            if self.client.status != "running":
                problem = f"lost the connection to the scheduler ({self.client.status})"
            else:
                problem = "" if self.client.nthreads() else "every worker was lost"
            if not problem:
                since = None
                if all(f.done() for f in futures):  # finished, or failed: gather says how
                    return
                continue
            # no worker (or no scheduler): futures cancelled with the shipped libraries they needed count
            # as not done; the wait goes on until a worker comes back or the timeout
            now = time.monotonic()
            since = now if since is None else since
            if now - since >= self.timeout_s:
                try:
                    self.client.cancel(futures)
                except Exception:  # noqa: BLE001 - best effort: the cluster is gone
                    pass
                where = self.scheduler or "local cluster"
                raise EngineError(f"engine dask ({where}): {problem} and none came back within {self.timeout_s:g} s; "
                                  f"the generation is abandoned") from None

    def close(self) -> None:
        c = getattr(self, "client", None)
        if c is not None:
            try:
                c.close()
            except Exception:  # noqa: BLE001 - best effort on shutdown
                pass
            self.client = None
        if self._cluster is not None:
            try:
                self._cluster.close()
            except Exception:  # noqa: BLE001
                pass
            self._cluster = None


def make_engine(cfg) -> LocalEngine | DaskEngine:
    """An engine from an :class:`arvcas.tuning.study.EngineConfig`."""
    if cfg.name == "local":
        return LocalEngine(cfg.threads)
    if cfg.name == "dask":
        return DaskEngine(cfg.scheduler, cfg.workers, cfg.timeout_s)
    raise EngineError(f"engine: unknown '{cfg.name}' (allowed: local, dask)")
