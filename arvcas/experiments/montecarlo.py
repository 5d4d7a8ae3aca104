"""Monte Carlo robustness of a controller: many noise, model-uncertainty and disturbance draws.

The paper compares its controllers on one sensor-noise draw and one model-uncertainty draw. Here a
master seed draws, for each run ``i`` independently,

- a sensor-noise seed (the run's noise sequence is ``arvcas.sim.profiles.noise_sequence(cfg, seed_i)``);
- the four nominal-model factors ``[C, D, g, arm]`` (docs/model.md §4), each uniform in ``[1 - spread, 1 + spread]``
  (default ``spread = 0.3``: the nominal model is wrong by up to 30 % either way, each term
  independently; the scenario file's fixed factors 1.4, 0.6, 0.7, 0.6 are one point partly outside
  this box). Only the AGSTA baseline uses the nominal model; the RESO-based controllers (proposed,
  traditional, implicit) know only ``Mhat = diag(M)``, which is not drawn;
- the six disturbance phases of eq. 41, uniform in ``[0, 2 pi)``;

and all runs go to the compiled run as one batch (:func:`arvcas.sim.simulation.simulate_many`).

Draw rule: ``numpy.random.SeedSequence(master_seed).spawn(runs)``; child ``i`` seeds
``numpy.random.default_rng``, which then draws, in this order, ``integers(0, 2**62)`` (noise seed),
``uniform(-1, 1, 4)`` (factors ``1 + spread u``) and ``uniform(0, 2 pi, 6)`` (phases). Run ``i``'s
draw depends on ``(master_seed, i, spread)`` only: the first ``n`` runs of a larger study are the
runs of a study of ``n``, and two controllers given the same ``--seed`` see the same draws (paired
comparison, :func:`compare`).

File layout (``format = "arvcas-montecarlo"``, ``format_version = 1``): datasets ``noise_seed``
(n, int64), ``factors`` (n x 4), ``phase`` (n x 6, rad), ``chat`` (n x 6), ``rmse`` (n x 6),
``ok`` (n, bool), ``t_fail`` (n, s, NaN when ok); root attributes ``controller``, ``gains``,
``gain_names``, ``gains_source``, ``master_seed``, ``runs``, ``spread``, ``draw_rule``, ``config``
(the effective scenario, :meth:`ScenarioConfig.to_toml`), ``scenario_file``, ``h``, ``params``,
``param_names``, ``n_quad``, ``dofs``, units, ``artifact_key`` (content hash of the compiled run) and
the versions of arvcas, CasADi, NumPy, h5py with the creation time. :func:`reproduce` re-runs a file
from these alone and checks every number bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from arvcas.build import codegen
from arvcas.controllers import gains as gains_mod
from arvcas.metrics import indices as metrics
from arvcas.sim import scenario
from arvcas.system.loader import UNSET, renamed_system
from arvcas.system.params import SCHEMA as PARAM_SCHEMA, Params, load as load_params
from arvcas.io import style
from arvcas.io.results import ResultsError
from arvcas.sim.scenario import ScenarioConfig
from arvcas.sim.simulation import run_function, simulate_many
from arvcas.model.uvms import ModelOptions
from arvcas.experiments import _io
from arvcas.experiments.stats import Interval, mean_ci, median_ci, paired_ci, paired_median_ci, welch_ci, wilson

__all__ = [
    "Draws", "MonteCarlo", "draw", "run_montecarlo", "write_montecarlo", "read_montecarlo", "reproduce",
    "summary", "summary_markdown", "compare", "compare_markdown", "FORMAT", "FORMAT_VERSION", "DRAW_RULE",
    "is_montecarlo_file", "plot_compare", "draws_toml",
]

FORMAT = "arvcas-montecarlo"
FORMAT_VERSION = 1
DOFS = metrics.DOFS
_DOF_MD = ("x", "y", "z", "φ", "θ", "ψ")
DRAW_RULE = ("SeedSequence(master_seed).spawn(runs); run i: rng = default_rng(child_i); "
             "noise_seed = rng.integers(0, 2**62); factors = 1 + spread * rng.uniform(-1, 1, 4) [C, D, g, arm]; "
             "phase = rng.uniform(0, 2 pi, 6) rad")
CHUNK = 200  # runs per compiled batch call (bounds the noise array in memory; results do not depend on it)


@dataclass(frozen=True)
class Draws:
    """What one Monte Carlo study draws: per run a noise seed, [C, D, g, arm] factors, 6 phases."""

    master_seed: int
    spread: float
    noise_seed: np.ndarray  # (n,) int64
    factors: np.ndarray  # (n, 4)
    phase: np.ndarray  # (n, 6) rad

    @property
    def runs(self) -> int:
        return int(self.noise_seed.size)

    def same_as(self, other: "Draws") -> bool:
        return (self.noise_seed.shape == other.noise_seed.shape
                and np.array_equal(self.noise_seed, other.noise_seed)
                and np.array_equal(self.factors, other.factors) and np.array_equal(self.phase, other.phase))


def _check_int(v, name: str, lo: int) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
        raise ValueError(f"{name}: must be an integer >= {lo}, got {v!r}")
    return int(v)


def draw(runs: int, seed: int = 0, spread: float = 0.3) -> Draws:
    """The draws of a study of ``runs`` runs from ``seed`` (module docstring: the draw rule)."""
    runs = _check_int(runs, "runs", 1)
    seed = _check_int(seed, "seed", 0)
    if not (isinstance(spread, (int, float)) and math.isfinite(spread) and 0 <= spread < 1):
        raise ValueError(f"spread: must be in [0, 1) (the factors' half-width), got {spread!r}")
    ns = np.empty(runs, dtype=np.int64)
    fac = np.empty((runs, 4))
    ph = np.empty((runs, 6))
    for i, child in enumerate(np.random.SeedSequence(seed).spawn(runs)):
        rng = np.random.default_rng(child)
        ns[i] = rng.integers(0, 2**62)
        fac[i] = 1.0 + spread * rng.uniform(-1.0, 1.0, 4)
        ph[i] = rng.uniform(0.0, 2.0 * math.pi, 6)
    return Draws(seed, float(spread), ns, fac, ph)


def draws_toml(d: Draws) -> str:
    """The draws as ``[[evaluation.draws]]`` tables of a tuning study file (``arvcas.tuning.study``):
    a study listing them optimises the mean of the objectives over these K draws instead of one.
    Phases are written in degrees (the study's unit) with 17 significant digits."""
    L = [f"# {d.runs} Monte Carlo draws: arvcas montecarlo --draws-toml --runs {d.runs} --seed {d.master_seed} "
         f"--spread {d.spread:g}"]
    for i in range(d.runs):
        u = ", ".join(f"{x:.17g}" for x in d.factors[i])
        ph = ", ".join(f"{math.degrees(x):.17g}" for x in d.phase[i])
        L += ["[[evaluation.draws]]", f"noise_seed = {int(d.noise_seed[i])}", f"uncertainty = [{u}]",
              f"phase_deg = [{ph}]"]
    return "\n".join(L) + "\n"


@dataclass
class MonteCarlo:
    """A Monte Carlo study of one controller and gain set: its draws and per-run metrics.

    ``chat``, ``rmse``: (runs, 6), eq. 42 (N, N m per sample) and eq. 43 (m, rad); NaN for diverged
    runs. ``ok``: (runs,) bool; ``t_fail``: (runs,) s, NaN when ok.
    """

    controller: str
    gains: np.ndarray
    draws: Draws
    chat: np.ndarray
    rmse: np.ndarray
    ok: np.ndarray
    t_fail: np.ndarray
    config_text: str
    params_vector: np.ndarray
    h: float
    n_quad: int = 5
    gains_source: str = "Table 2"
    meta: dict = field(default_factory=dict)

    @property
    def runs(self) -> int:
        return self.draws.runs

    def objectives(self) -> np.ndarray:
        """docs/model.md §7 normalised (f_chat, f_rmse) per run, shape (runs, 2) (NaN for diverged runs)."""
        out = np.full((self.runs, 2), np.nan)
        ref = self.meta.get("reference")
        held = scenario.held_dofs(scenario.loads_scenario(self.config_text, "the runs' scenario"))  # docs/sensors.md
        for i in np.flatnonzero(self.ok):
            out[i] = metrics.normalised_objectives(self.chat[i], self.rmse[i], ref, held)
        return out


def run_montecarlo(controller: str, runs: int, seed: int = 0, gains=None, spread: float = 0.3,
                   cfg: ScenarioConfig | None = None, system: Params | None = None, n_quad: int = 5,
                   n_threads: int | None = None, gains_source: str | None = None,
                   progress: Callable[[str], None] | None = None, *, params=UNSET) -> MonteCarlo:
    """Draw ``runs`` (noise seed, factors, phases) from ``seed`` and run them as compiled batches.

    ``system``: its Params (default: the default system; ``params=``: its old name). ``gains`` defaults to
    the system's default gains (Haidou-1: Table 2). Diverged runs are results (``ok = False``), not errors.
    """
    params = renamed_system(system, params, "run_montecarlo")
    gains_mod.check_controller(controller)
    d = draw(runs, seed, spread)
    cfg = cfg if cfg is not None else scenario.load_scenario()
    params = params if params is not None else load_params()
    g = gains_mod.default_gains(controller, params) if gains is None else np.asarray(gains, dtype=float)
    g = gains_mod.check_gains(controller, g, h=cfg.time_h)
    if g.ndim != 1:
        raise ValueError(f"gains: a Monte Carlo study takes one gain vector, got shape {g.shape}")
    opts = ModelOptions(n_quad=n_quad)
    n = d.runs
    chat, rmse = np.full((n, 6), np.nan), np.full((n, 6), np.nan)
    ok, t_fail = np.zeros(n, dtype=bool), np.full(n, np.nan)
    for a in range(0, n, CHUNK):
        b = min(n, a + CHUNK)
        if progress:
            progress(f"{controller}: runs {a}..{b - 1} of {n}")
        c_, r_, o_, t_ = simulate_many(controller, g, d.noise_seed[a:b], uncertainty=d.factors[a:b],
                                       phase=d.phase[a:b], system=params, cfg=cfg, n_threads=n_threads, opts=opts)
        chat[a:b], rmse[a:b], ok[a:b], t_fail[a:b] = c_, r_, o_, t_
    sysref = _io.system_ref(params)
    src = gains_source if gains_source is not None else (metrics.defaults_name(sysref) if gains is None else "given")
    from arvcas.sim.simulation import compiled_run

    art = codegen.artifact_of(compiled_run(controller, params, cfg, opts).function(False)) or {}
    meta = {"artifact_key": str(art.get("key", "")), "scenario_file": cfg.path}
    if sysref:  # another system: its name and its objectives' normalisation (docs/model.md §8)
        meta |= {"system": sysref, "param_names": params.names(), "reference": _io.system_reference(params, cfg)}
    return MonteCarlo(controller, g, d, chat, rmse, ok, t_fail, cfg.to_toml(), params.vector(), cfg.time_h,
                      n_quad, src, meta=meta)


# ---------------------------------------------------------------------------------------------
# file


def write_montecarlo(mc: MonteCarlo, path) -> Path:
    """Write ``mc`` to ``path`` (HDF5, atomic); returns the path."""
    import h5py

    path = _io.target(path, str(path))
    d = mc.draws
    attrs = {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "controller": mc.controller, "gains": np.asarray(mc.gains, float),
        "gain_names": np.array(gains_mod.gain_names(mc.controller), dtype=object),
        "gains_source": mc.gains_source, "master_seed": int(d.master_seed), "runs": int(d.runs),
        "spread": float(d.spread), "draw_rule": DRAW_RULE,
        "config": mc.config_text, "h": float(mc.h), "n_quad": int(mc.n_quad),
        "params": np.asarray(mc.params_vector, float),
        "param_names": np.array(list(mc.meta.get("param_names") or PARAM_SCHEMA), dtype=object),
        "dofs": np.array(DOFS, dtype=object),
        "chat_units": "N (x, y, z), N m (phi, theta, psi) per controller sample; eq. 42",
        "rmse_units": "m (x, y, z), rad (phi, theta, psi); eq. 43",
        "factors_columns": "C, D, g, arm (nominal-model factors of docs/model.md §4; used by agsta only)",
        "artifact_key": str(mc.meta.get("artifact_key", "")), "scenario_file": str(mc.meta.get("scenario_file", "")),
        "front_path": str(mc.meta.get("front_path", "")),
        **_io.provenance(),
    }
    sources = _io.controller_sources([mc.controller])
    if sources:  # a controller from a plugin: which, and its source's digest
        attrs["controller_sources"] = sources
    if mc.meta.get("system"):  # another system: its name and the objectives' normalisation
        attrs["system"] = str(mc.meta["system"])
        ref = mc.meta.get("reference")
        if ref is not None:
            attrs["ref_chat"], attrs["ref_rmse"] = np.asarray(ref[0], float), np.asarray(ref[1], float)

    def fill(tmp: Path) -> None:
        with _io.files.new_hdf5(tmp) as f:
            for k, v in attrs.items():
                f.attrs[k] = v
            f.create_dataset("noise_seed", data=d.noise_seed.astype(np.int64))
            f.create_dataset("factors", data=d.factors.astype(float))
            f.create_dataset("phase", data=d.phase.astype(float))
            f.create_dataset("chat", data=np.asarray(mc.chat, float))
            f.create_dataset("rmse", data=np.asarray(mc.rmse, float))
            f.create_dataset("ok", data=np.asarray(mc.ok, bool))
            f.create_dataset("t_fail", data=np.asarray(mc.t_fail, float))
            f["phase"].attrs["units"] = "rad"
            f["t_fail"].attrs["units"] = "s (NaN when the run completed)"

    return _io.atomic_write(path, fill, FORMAT)


def is_montecarlo_file(path) -> bool:
    return _io.h5_format(path) == FORMAT


def read_montecarlo(path) -> MonteCarlo:
    """Read a file written by :func:`write_montecarlo` (one-line ResultsError if it is not one)."""
    path = Path(path)
    f = _io.open_h5(path, FORMAT, FORMAT_VERSION)
    try:
        a = f.attrs
        controller = _io.str_attr(a["controller"])
        names = [_io.str_attr(x) for x in np.asarray(a["gain_names"]).ravel()]
        _io.require_controllers(path, [controller], _io.str_attr(a["controller_sources"]) if "controller_sources" in a else "")
        expect = gains_mod.gain_names(controller)
        if names != expect:
            raise ResultsError(f"{path}: gain_names do not match controller '{controller}' of this arvcas version")
        d = Draws(int(a["master_seed"]), float(a["spread"]), np.array(f["noise_seed"][()], dtype=np.int64),
                  np.array(f["factors"][()], float), np.array(f["phase"][()], float))
        n = d.runs
        arrays = {k: np.array(f[k][()]) for k in ("chat", "rmse", "ok", "t_fail")}
        for k, shape in (("chat", (n, 6)), ("rmse", (n, 6)), ("ok", (n,)), ("t_fail", (n,))):
            if arrays[k].shape != shape:
                raise ResultsError(f"{path}: damaged file: {k} has shape {arrays[k].shape}, expected {shape}")
        return MonteCarlo(
            controller=controller, gains=np.array(a["gains"], float), draws=d,
            chat=arrays["chat"].astype(float), rmse=arrays["rmse"].astype(float), ok=arrays["ok"].astype(bool),
            t_fail=arrays["t_fail"].astype(float), config_text=_io.str_attr(a["config"]),
            params_vector=np.array(a["params"], float), h=float(a["h"]), n_quad=int(a["n_quad"]),
            gains_source=_io.str_attr(a["gains_source"]),
            meta={**{k: _io.str_attr(a[k]) for k in ("arvcas_version", "casadi_version", "numpy_version", "created",
                                                     "artifact_key", "scenario_file", "front_path", "system") if k in a},
                  **({"param_names": [_io.str_attr(x) for x in a["param_names"]],
                      "reference": (tuple(np.array(a["ref_chat"], float)), tuple(np.array(a["ref_rmse"], float)))
                      if "ref_chat" in a else None} if "system" in a else {})},
        )
    except KeyError as e:
        raise ResultsError(f"{path}: damaged file: missing {e}") from None
    finally:
        f.close()


def reproduce(path, n_threads: int | None = None) -> tuple[MonteCarlo, list[str]]:
    """Re-run the study stored in ``path`` from its stored configuration alone.

    Returns the new study and the list of fields that differ from the file (empty: bit for bit).
    """
    old = read_montecarlo(path)
    cfg, params = _io.stored_inputs(path, old.config_text, old.params_vector, ResultsError, old.meta.get("system", ""))
    new = run_montecarlo(old.controller, old.runs, old.draws.master_seed, gains=old.gains, spread=old.draws.spread,
                         cfg=cfg, system=params, n_quad=old.n_quad, n_threads=n_threads, gains_source=old.gains_source)
    diff = []
    if not new.draws.same_as(old.draws):
        diff.append("draws")
    for k in ("chat", "rmse", "ok", "t_fail"):
        a, b = np.asarray(getattr(new, k)), np.asarray(getattr(old, k))
        if a.shape != b.shape or not np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
            diff.append(k)
    return new, diff


# ---------------------------------------------------------------------------------------------
# summaries


def _percentiles(x, q=(5, 50, 95)) -> tuple[float, ...]:
    v = np.asarray(x, float)
    v = v[np.isfinite(v)]
    return tuple(float(np.percentile(v, p)) for p in q) if v.size else (float("nan"),) * len(q)


def summary(mc: MonteCarlo) -> dict:
    """Per DOF mean with 95 % t-interval and 5/50/95 percentiles of CHAT and RMSE over the runs that
    completed; the same for docs/model.md §7 normalised objectives; the failure rate with its Wilson interval."""
    out: dict = {"chat": {}, "rmse": {}, "objectives": {}}
    for key in ("chat", "rmse"):
        arr = getattr(mc, key)
        for i, d in enumerate(DOFS):
            out[key][d] = {"mean": mean_ci(arr[:, i]), "pct": _percentiles(arr[:, i])}
    obj = mc.objectives()
    for j, name in enumerate(("f_chat", "f_rmse")):
        out["objectives"][name] = {"mean": mean_ci(obj[:, j]), "median": median_ci(obj[:, j]),
                                   "pct": _percentiles(obj[:, j])}
    n_fail = int((~mc.ok).sum())
    out["failures"] = wilson(n_fail, mc.runs)
    out["n_fail"] = n_fail
    return out


def _ci(iv: Interval, fmt: str = ".4g") -> str:
    if math.isnan(iv.lo):
        return f"{iv.estimate:{fmt}}"
    return f"{iv.estimate:{fmt}} [{iv.lo:{fmt}}, {iv.hi:{fmt}}]"


def summary_markdown(mc: MonteCarlo, title: str | None = None) -> str:
    s = summary(mc)
    fr = s["failures"]
    L = [f"# Monte Carlo: {mc.controller} ({mc.gains_source})" if title is None else f"# {title}", "",
         f"{mc.runs} runs of {_duration(mc)} at h = {mc.h:g} s, master seed {mc.draws.master_seed}; per run a noise "
         f"seed, nominal-model factors [C, D, g, arm] uniform in [{1 - mc.draws.spread:g}, {1 + mc.draws.spread:g}] "
         "and disturbance phases uniform in [0, 2π). Mean over the completed runs with its 95 % t-interval "
         "[lo, hi]; p5 / p50 / p95 = percentiles over the runs.", "",
         *([f"Gains: {mc.gains_source} of `{mc.meta['front_path']}`.", ""] if mc.meta.get("front_path") else []),
         f"Failures (diverged runs): {s['n_fail']} of {mc.runs} = {fr.estimate:.3g}, "
         f"95 % Wilson interval [{fr.lo:.3g}, {fr.hi:.3g}].", "",
         "| DOF | CHAT mean [95 % CI] | CHAT p5 / p50 / p95 | RMSE mean [95 % CI] | RMSE p5 / p50 / p95 |",
         "|---|---:|---:|---:|---:|"]
    for i, d in enumerate(DOFS):
        c, r = s["chat"][d], s["rmse"][d]
        L.append(f"| {_DOF_MD[i]} | {_ci(c['mean'])} | {' / '.join(f'{v:.4g}' for v in c['pct'])} "
                 f"| {_ci(r['mean'])} | {' / '.join(f'{v:.4g}' for v in r['pct'])} |")
    L += ["", f"docs/model.md §7 objectives (per-DOF value / {metrics.norm_name(mc.meta.get('system', ''))}, "
              "averaged over the 6 DOF):", ""]
    for name, v in s["objectives"].items():
        L.append(f"- {name}: mean {_ci(v['mean'])}; median {_ci(v['median'])} (sign-test 95 % interval); "
                 f"p5 / p50 / p95 {' / '.join(f'{x:.4g}' for x in v['pct'])}")
    L.append("")
    return "\n".join(L)


def _duration(mc: MonteCarlo) -> str:
    try:
        return f"{scenario.loads_scenario(mc.config_text).time_duration:g} s"
    except ValueError:
        return "the stored scenario"


def compare(a: MonteCarlo, b: MonteCarlo) -> dict:
    """Per DOF ``a - b`` of CHAT and RMSE, and of the two docs/model.md §7 objectives.

    Paired over the runs both completed when the two studies share their draws (same master seed,
    spread and a common prefix of runs: the first min(n_a, n_b) runs); otherwise Welch's unpaired
    interval. Each entry: ``diff``, the mean difference :class:`Interval` (t); ``median``, the median
    of the paired differences with its sign-test interval (paired only), which a few extreme runs
    cannot move; the ratio of means; ``certain``/``median_certain`` (the interval excludes 0).
    """
    n = min(a.runs, b.runs)
    pa = Draws(a.draws.master_seed, a.draws.spread, a.draws.noise_seed[:n], a.draws.factors[:n], a.draws.phase[:n])
    pb = Draws(b.draws.master_seed, b.draws.spread, b.draws.noise_seed[:n], b.draws.factors[:n], b.draws.phase[:n])
    paired = pa.same_as(pb) and a.h == b.h and a.config_text == b.config_text
    out: dict = {"paired": paired, "n": n if paired else None, "chat": {}, "rmse": {}, "objectives": {}}

    def entry(x, y):
        if paired:
            iv = paired_ci(x[:n], y[:n])
            med = paired_median_ci(x[:n], y[:n])
        else:
            iv = welch_ci(x, y)
            med = Interval(float(np.nanmedian(x) - np.nanmedian(y)), float("nan"), float("nan"), 0)
        mx, my = np.nanmean(x), np.nanmean(y)
        return {"diff": iv, "ratio": float(mx / my) if my else float("nan"), "certain": iv.excludes_zero,
                "median": med, "median_certain": med.excludes_zero}

    for key in ("chat", "rmse"):
        xa, xb = getattr(a, key), getattr(b, key)
        for i, d in enumerate(DOFS):
            out[key][d] = entry(xa[:, i], xb[:, i])
    oa, ob = a.objectives(), b.objectives()
    for j, name in enumerate(("f_chat", "f_rmse")):
        out["objectives"][name] = entry(oa[:, j], ob[:, j])
    out["failures"] = (wilson(int((~a.ok).sum()), a.runs), wilson(int((~b.ok).sum()), b.runs))
    return out


def _label(mc: MonteCarlo) -> str:
    return f"{mc.controller} ({mc.gains_source})"


def compare_markdown(a: MonteCarlo, b: MonteCarlo, name_a: str | None = None, name_b: str | None = None) -> str:
    """The comparison of :func:`compare` as Markdown: "A - B" per DOF with its 95 % interval."""
    c = compare(a, b)
    A, B = name_a or _label(a), name_b or _label(b)
    n_both = c["chat"][DOFS[0]]["diff"].n
    how = (f"paired over the {c['n']} shared draws (same master seed {a.draws.master_seed}; {n_both} completed in "
           "both): per draw the difference, then its mean with a 95 % t-interval" if c["paired"] else
           "UNPAIRED (the files do not share their draws): difference of means with Welch's 95 % interval")
    fa, fb = c["failures"]
    L = [f"# {A} - {B}", "", f"Difference {A} minus {B}, {how}. Negative = {A} lower. "
         "'certain' = the interval excludes 0; ratio = mean A / mean B.", "",
         f"Failures: {A} {int(round(fa.estimate * fa.n))}/{fa.n} [{fa.lo:.3g}, {fa.hi:.3g}]; "
         f"{B} {int(round(fb.estimate * fb.n))}/{fb.n} [{fb.lo:.3g}, {fb.hi:.3g}] (95 % Wilson).", "",
         "| DOF | CHAT A - B [95 % CI] | ratio | sign | RMSE A - B [95 % CI] | ratio | sign |",
         "|---|---:|---:|---|---:|---:|---|"]

    def sign(e):
        if not e["certain"]:
            return "not certain"
        return "A lower" if e["diff"].hi < 0 else "A higher"

    for i, d in enumerate(DOFS):
        ec, er = c["chat"][d], c["rmse"][d]
        L.append(f"| {_DOF_MD[i]} | {_ci(ec['diff'])} | {ec['ratio']:.3f} | {sign(ec)} "
                 f"| {_ci(er['diff'])} | {er['ratio']:.3f} | {sign(er)} |")
    L += [""]
    for name, e in c["objectives"].items():
        L.append(f"- {name} (docs/model.md §7): A - B = {_ci(e['diff'])}, ratio {e['ratio']:.3f}, {sign(e)}")
    if c["paired"]:
        def msign(e):
            if not e["median_certain"]:
                return "not certain"
            return "A lower" if e["median"].hi < 0 else "A higher"

        L += ["", "Medians of the paired differences, with the sign test's 95 % interval (not moved by a few "
              "extreme runs; compare with the means above when they disagree):", "",
              "| DOF | CHAT median A - B [95 % CI] | sign | RMSE median A - B [95 % CI] | sign |",
              "|---|---:|---|---:|---|"]
        for i, d in enumerate(DOFS):
            ec, er = c["chat"][d], c["rmse"][d]
            L.append(f"| {_DOF_MD[i]} | {_ci(ec['median'])} | {msign(ec)} | {_ci(er['median'])} | {msign(er)} |")
        L.append("")
        for name, e in c["objectives"].items():
            L.append(f"- {name} (docs/model.md §7): median A - B = {_ci(e['median'])}, {msign(e)}")
    L += ["", "Where the sign is certain (95 %):", ""]
    for stat, iv_key, ok_key in (("means", "diff", "certain"), ("medians", "median", "median_certain")):
        if stat == "medians" and not c["paired"]:
            continue
        for key in ("chat", "rmse"):
            e = [c[key][d] for d in DOFS]
            lower = [_DOF_MD[i] for i in range(6) if e[i][ok_key] and e[i][iv_key].hi < 0]
            higher = [_DOF_MD[i] for i in range(6) if e[i][ok_key] and e[i][iv_key].lo > 0]
            unsure = [_DOF_MD[i] for i in range(6) if not e[i][ok_key]]
            L.append(f"- {key.upper()} ({stat}): A lower in {len(lower)} of 6 DOF ({', '.join(lower) or '-'}), "
                     f"higher in {len(higher)} ({', '.join(higher) or '-'}), not certain in {len(unsure)} "
                     f"({', '.join(unsure) or '-'}).")
    L.append("")
    return "\n".join(L)


def plot_compare(a: MonteCarlo, b: MonteCarlo, name_a: str | None = None, name_b: str | None = None,
                 fig=None):
    """Four panels: per-DOF distributions of CHAT and RMSE for A and B (box: quartiles, whiskers:
    5-95 %; each DOF divided by its reference value, the paper's AGSTA value for Haidou-1, so the DOF
    share an axis), and A - B relative
    to B: for shared draws the median of the paired differences with its sign-test 95 % interval,
    otherwise the difference of means with Welch's interval."""
    from matplotlib.figure import Figure

    return _plot_compare(a, b, name_a, name_b, fig)


@style.styled
def _plot_compare(a: MonteCarlo, b: MonteCarlo, name_a, name_b, fig):
    A, B = name_a or _label(a), name_b or _label(b)
    c = compare(a, b)
    if fig is None:
        fig = style.figure("page", 5.2)
    axs = fig.subplots(2, 2)
    x = np.arange(6)
    ca, cb = style.color("tab:blue"), style.color("tab:red")
    norm = metrics.norm_name(a.meta.get("system", ""))
    for col, key in enumerate(("chat", "rmse")):
        ax = axs[0, col]
        for off, mc, color in ((-0.18, a, ca), (0.18, b, cb)):
            ref = metrics.reference_values(mc.meta.get("reference"))[col]
            data = [v[np.isfinite(v)] for v in (getattr(mc, key) / ref).T]
            bp = ax.boxplot(data, positions=x + off, widths=0.3, whis=(5, 95), showfliers=False, patch_artist=True,
                            medianprops={"color": "k"})
            for box in bp["boxes"]:
                box.set_facecolor(color)
                box.set_alpha(0.55)
        ax.plot([], [], "s", color=ca, alpha=0.55, label=A)
        ax.plot([], [], "s", color=cb, alpha=0.55, label=B)
        ax.set_xticks(x, _DOF_MD)
        ax.set_ylabel(f"{key.upper()} / {norm} (per DOF)")
        ax.set_title(f"{key.upper()} over the draws (box: quartiles, whiskers: 5-95 %)")
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend()
        ax = axs[1, col]
        # paired: the median of the per-draw differences (sign-test interval), which a few extreme runs
        # cannot move; unpaired: the difference of means (Welch)
        d = [c[key][dd]["median" if c["paired"] else "diff"] for dd in DOFS]
        mb = np.array([(np.nanmedian if c["paired"] else np.nanmean)(getattr(b, key)[:, i]) for i in range(6)])
        est = np.array([iv.estimate for iv in d]) / mb * 100
        lo = np.array([iv.lo for iv in d]) / mb * 100
        hi = np.array([iv.hi for iv in d]) / mb * 100
        colors = [style.color("tab:green") if h < 0 else cb if l > 0 else "0.5" for l, h in zip(lo, hi)]
        ax.bar(x, est, color=colors, alpha=0.7)
        ax.errorbar(x, est, yerr=[est - lo, hi - est], fmt="none", ecolor="k", capsize=4)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(x, _DOF_MD)
        if c["paired"]:
            ax.set_ylabel(f"median of (A - B) per draw / median B, % of {key.upper()}")
            ax.set_title(f"{key.upper()}: paired A - B, median, sign-test 95 % CI; green: A certainly lower")
        else:
            ax.set_ylabel(f"(mean A - mean B) / mean B, % of {key.upper()}")
            ax.set_title(f"{key.upper()}: A - B, means, Welch 95 % CI; green: A certainly lower")
        ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle(f"A = {A}  vs  B = {B}  ({a.runs} / {b.runs} draws)")
    return fig
