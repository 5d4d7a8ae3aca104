"""Python API of the closed-loop experiment: :func:`simulate`, :func:`simulate_batch`, :class:`Result`.

Both call compiled C (the whole run is one CasADi function, built once and cached by content hash):
a new gain set, seed or parameter value never recompiles. The run's time table (:mod:`arvcas.sim.schedule`:
the arm's and the disturbance's time-only terms) is computed once per (scenario, p) and shared by
every run of a batch.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from arvcas import __version__
from arvcas.build import calls, codegen
from arvcas.sim import closedloop, scenario, schedule
from arvcas.controllers import gains as gains_mod
from arvcas.params import Params, load as load_params
from arvcas.sim.scenario import ScenarioConfig
from arvcas.model.uvms import ModelOptions

__all__ = ["Result", "simulate", "simulate_batch", "simulate_many", "default_gains", "run_function", "SimulationError"]


class SimulationError(ValueError):
    """Bad input to a simulation (one line), raised before anything runs."""


default_gains = gains_mod.default_gains


@dataclass
class Result:
    """One closed-loop run: time series at the controller samples and the metrics.

    Arrays have shape (N+1,) or (N+1, 6) over samples t_k = k h, k = 0..N. Units: eta in m and rad
    ({n}), nu in m/s and rad/s ({b}), tau_cmd in N and N m ({b}, the commanded tau_v), thrust in N
    per thruster after saturation, f_hat and f_true (total disturbance, eq. 6) in N and N m ({n}).
    ``chat`` (eq. 42) and ``rmse`` (eq. 43) have shape (6,).
    """

    controller: str
    gains: np.ndarray
    seed: int
    t: np.ndarray
    eta: np.ndarray
    nu: np.ndarray
    eta_hat: np.ndarray
    eta_ref: np.ndarray
    tau_cmd: np.ndarray
    thrust: np.ndarray
    s: np.ndarray
    k1: np.ndarray
    k2: np.ndarray
    f_hat: np.ndarray
    f_true: np.ndarray
    q: np.ndarray
    payload: np.ndarray
    chat: np.ndarray
    rmse: np.ndarray
    ok: bool
    t_fail: float | None
    config_text: str = ""
    params_vector: np.ndarray | None = None
    uncertainty: np.ndarray | None = None
    phase: np.ndarray | None = None
    h: float = 0.1
    version: str = __version__
    meta: dict = field(default_factory=dict)

    @property
    def e(self) -> np.ndarray:
        """Tracking error eta - eta_ref (the RMSE's e, SPEC 6)."""
        return self.eta - self.eta_ref

    @property
    def diverged(self) -> bool:
        return not self.ok


_RUN_CACHE: dict = {}


def run_function(controller: str, cfg: ScenarioConfig, trace: bool, opts: ModelOptions = ModelOptions()) -> ca.Function:
    """The compiled run (memoised per process; the C library is cached on disk by content hash)."""
    key = (controller, cfg.graph_key(), trace, opts)
    fn = _RUN_CACHE.get(key)
    if fn is None:
        fn = codegen.build(closedloop.build_run(closedloop.RunSpec(controller, cfg, opts), trace=trace))
        _RUN_CACHE[key] = fn
    return fn


def _prepare(controller, gains, seed, params, cfg, uncertainty, phase, batch: bool):
    gains_mod.check_controller(controller)
    cfg = cfg if cfg is not None else scenario.load_scenario()
    if params is None:
        params = load_params()
    if not isinstance(params, Params):
        raise SimulationError(f"params: expected arvcas.params.Params, got {type(params).__name__}")
    scenario.check_joint_limits(cfg, params)
    g = gains_mod.default_gains(controller) if gains is None else gains
    g = gains_mod.check_gains(controller, g, h=cfg.time_h)
    if batch and g.ndim == 1:
        g = g[None, :]
    if not batch and g.ndim != 1:
        raise SimulationError(f"gains: simulate takes one gain vector of {gains_mod.n_gains(controller)}, got shape {g.shape}")
    noise = scenario.noise_sequence(cfg, seed)
    unc = cfg.uncertainty if uncertainty is None else np.asarray(uncertainty, dtype=float)
    ph = np.array(cfg.disturbance_phase) if phase is None else np.asarray(phase, dtype=float)
    if unc.shape != (4,) or not np.isfinite(unc).all():
        raise SimulationError(f"uncertainty: expected 4 finite factors [C, D, g, arm], got {unc}")
    if ph.shape != (6,) or not np.isfinite(ph).all():
        raise SimulationError(f"phase: expected 6 finite disturbance phases (rad), got {ph}")
    return cfg, params, g, noise, unc, ph


def simulate(controller: str, gains=None, seed: int = 0, params: Params | None = None,
             cfg: ScenarioConfig | None = None, uncertainty=None, phase=None,
             opts: ModelOptions = ModelOptions(), noise_scale: float = 1.0) -> Result:
    """Run the 100 s station-keeping experiment once (compiled) and return its :class:`Result`.

    ``noise_scale`` multiplies the drawn sensor noise (0: perfect measurements) while the EKF keeps
    the nominal sensor covariance: an analysis knob for how much noise reaches the thrusters.
    """
    cfg, params, g, noise, unc, ph = _prepare(controller, gains, seed, params, cfg, uncertainty, phase, batch=False)
    if not (isinstance(noise_scale, (int, float)) and np.isfinite(noise_scale) and noise_scale >= 0):
        raise SimulationError(f"noise_scale: must be a finite number >= 0, got {noise_scale!r}")
    noise = noise * float(noise_scale)
    fn = run_function(controller, cfg, trace=True, opts=opts)
    pv = params.vector()
    chat, rmse, ok, t_fail, tr = calls.call(fn, g, noise, unc, ph, cfg.ekf_vector, pv, *schedule.table(cfg, pv, opts))
    cols = {}
    i = 0
    for name, n in closedloop.TRACE_FIELDS:
        block = tr[i:i + n, :].T
        cols[name] = block[:, 0] if n == 1 else block
        i += n
    ok_b = bool(ok.item() > 0.5)
    return Result(
        controller=controller, gains=np.asarray(g, dtype=float), seed=int(seed),
        t=cols["t"], eta=cols["eta"], nu=cols["nu"], eta_hat=cols["eta_hat"], eta_ref=cols["eta_ref"],
        tau_cmd=cols["tau_cmd"], thrust=cols["thrust"], s=cols["s"], k1=cols["k1"], k2=cols["k2"],
        f_hat=cols["f_hat"], f_true=cols["f_true"], q=cols["q"], payload=cols["payload"],
        chat=chat.ravel(), rmse=rmse.ravel(), ok=ok_b, t_fail=None if ok_b else float(t_fail.item()),
        config_text=cfg.to_toml(), params_vector=params.vector(), uncertainty=unc, phase=ph, h=cfg.time_h,
        meta=_meta(fn, cfg) | ({"noise_scale": float(noise_scale)} if noise_scale != 1.0 else {}),
    )


def _meta(fn: ca.Function, cfg: ScenarioConfig) -> dict:
    """Provenance stored with a result: the compiled artifact's key and the scenario file it came from."""
    art = codegen.artifact_of(fn) or {}
    return {"artifact_key": art.get("key"), "artifact_flags": art.get("flags"),
            "scenario_file": cfg.path, "casadi_version": ca.__version__}


def _n_threads(n_threads: int | None) -> int:
    if n_threads is None:
        try:
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:  # pragma: no cover
            return max(1, os.cpu_count() or 1)
    if not isinstance(n_threads, int) or n_threads < 1:
        raise SimulationError(f"n_threads: must be a positive integer, got {n_threads!r}")
    return n_threads


def simulate_batch(controller: str, gains, seed: int = 0, params: Params | None = None,
                   cfg: ScenarioConfig | None = None, uncertainty=None, phase=None,
                   n_threads: int | None = None, opts: ModelOptions = ModelOptions(),
                   return_status: bool = False):
    """Evaluate many gain sets (n x n_gains) in one call across ``n_threads`` cores (default: all).

    Every set sees the same noise (``seed``), uncertainty and disturbance (common random numbers).
    Returns ``(chat (n x 6), rmse (n x 6))``; with ``return_status`` also ``(ok (n,), t_fail (n,))``.
    A diverged run has ``ok = False`` and NaN metrics.
    """
    cfg, params, g, noise, unc, ph = _prepare(controller, gains, seed, params, cfg, uncertainty, phase, batch=True)
    n = g.shape[0]
    chat, rmse, ok, t_fail = _evaluate(controller, cfg, params, opts, n, (g.T, noise, unc, ph), (0,), n_threads)
    if return_status:
        return chat, rmse, ok, t_fail
    return chat, rmse


def simulate_many(controller: str, gains, seeds, uncertainty=None, phase=None, params: Params | None = None,
                  cfg: ScenarioConfig | None = None, n_threads: int | None = None,
                  opts: ModelOptions = ModelOptions()):
    """Run n draws in one call: row i has its own gains, noise seed, uncertainty factors and phases.

    ``gains``: (n_gains,) shared, or (n, n_gains); ``seeds``: (n,) non-negative integers;
    ``uncertainty``: None (the scenario's factors), (4,) shared, or (n, 4); ``phase``: None, (6,) or (n, 6).
    Returns ``(chat (n x 6), rmse (n x 6), ok (n,), t_fail (n,))`` (NaN metrics for diverged runs).
    This is the Monte Carlo path; :func:`simulate_batch` is the common-random-numbers path of tuning.
    """
    seeds = np.asarray(seeds)
    if seeds.ndim != 1 or seeds.size == 0:
        raise SimulationError(f"seeds: expected a non-empty 1-D sequence of integers, got shape {seeds.shape}")
    n = seeds.size
    cfg, params, g, _noise, unc0, ph0 = _prepare(controller, gains, int(seeds[0]), params, cfg, None, None, batch=True)
    if g.shape[0] not in (1, n):
        raise SimulationError(f"gains: {g.shape[0]} gain sets for {n} seeds (give 1 or {n})")
    G = np.broadcast_to(g, (n, g.shape[1]))

    def rows(v, default, k, name):
        a = np.asarray(default if v is None else v, dtype=float)
        if a.shape == (k,):
            a = np.broadcast_to(a, (n, k))
        if a.shape != (n, k) or not np.isfinite(a).all():
            raise SimulationError(f"{name}: expected ({k},) or ({n}, {k}) finite values, got shape {a.shape}")
        return a

    U = rows(uncertainty, unc0, 4, "uncertainty")
    PH = rows(phase, ph0, 6, "phase")
    noise = np.hstack([scenario.noise_sequence(cfg, int(sd)) for sd in seeds])
    return _evaluate(controller, cfg, params, opts, n, (G.T, noise, U.T, PH.T), (0, 1, 2, 3), n_threads)


def _evaluate(controller, cfg, params, opts, n, varying, per_run, n_threads):
    """n metrics-only runs on the thread pool; ``varying`` = (gains, noise, unc, phase), those in
    ``per_run`` with a column block per run, the rest and the time table shared.
    Returns (chat (n x 6), rmse (n x 6), ok (n,), t_fail (n,)), NaN metrics for a diverged run."""
    fn = run_function(controller, cfg, trace=False, opts=opts)
    pv = params.vector()
    chat, rmse, ok, t_fail = calls.call_many(fn, n, (*varying, cfg.ekf_vector, pv, *schedule.table(cfg, pv, opts)),
                                             per_run=per_run, n_threads=_n_threads(n_threads))
    ok = ok.ravel() > 0.5
    chat, rmse = chat.T.copy(), rmse.T.copy()
    chat[~ok] = np.nan
    rmse[~ok] = np.nan
    return chat, rmse, ok, np.where(ok, np.nan, t_fail.ravel())
