"""Study files: strict TOML -> frozen dataclasses (:class:`Study`).

A study file says what to tune and how (SPEC 7): the controller(s), the decision variables (every
Table 2 gain, on a log10 scale, within bounds that contain Table 2), the NSGA-II settings, when to
stop, the objectives and the reference point of the hypervolume, the draws every candidate is
evaluated on (common random numbers), and the engine. Every key is checked before any work:
an unknown key (with the closest valid name), a missing key, a wrong type or a value out of range
is a one-line :class:`StudyError` naming the file and the key.

Layout (see ``studies/*.toml`` for commented examples)::

    [study]        name, description?, controllers (str or list), seed (NSGA-II's generator)
    [variables]    scale (> 1: default bounds [g / scale, g * scale] around each Table 2 gain g),
                   bounds? (table: column name "c" for every DOF, or gain name "x.c" -> [lower, upper])
    [algorithm]    name = "nsga2", population (>= 4), offspring?, include_table2?, crossover_prob?,
                   crossover_eta?, mutation_eta?, mutation_prob_var?, eliminate_duplicates?
    [termination]  max_generations | max_generations_per_variable, max_evaluations?,
                   stall_generations? with ftol?
    [objectives]   names = ["chat", "rmse"], reference_point = [f_chat, f_rmse]
    [evaluation]   scenario? (path, relative to the study file), [[evaluation.draws]] noise_seed,
                   uncertainty? ([C, D, g, arm] factors), phase_deg? (6 disturbance phases, deg)
    [engine]       name = "local" | "dask", threads?, scheduler?, workers?, timeout_s?

Bounds that do not contain a Table 2 gain are an error, not a warning: the tuned front is compared
with Table 2 evaluated on the same draws, and a search space that excludes the paper's point makes
that comparison meaningless.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arvcas.controllers import gains as gains_mod
from arvcas import tomlfile
from arvcas.sim import scenario as scenario_mod

__all__ = [
    "StudyError", "Study", "AlgorithmConfig", "TerminationConfig", "ObjectivesConfig", "EngineConfig",
    "Draw", "Variables", "load_study", "loads_study", "ENGINES", "OBJECTIVES",
]

ENGINES = ("local", "dask")
OBJECTIVES = ("chat", "rmse")
ALGORITHMS = ("nsga2",)


class StudyError(ValueError):
    """One-line error naming the study file and the key at fault."""


# ---- dataclasses --------------------------------------------------------------------------------


@dataclass(frozen=True)
class AlgorithmConfig:
    """NSGA-II settings (pymoo: SBX crossover, polynomial mutation, binary tournament)."""

    name: str = "nsga2"
    population: int = 100
    offspring: int | None = None  # None: as many as the population (gamultiobj's choice)
    include_table2: bool = False  # seed the initial population with the Table 2 gains
    crossover_prob: float = 0.9
    crossover_eta: float = 15.0
    mutation_eta: float = 20.0
    mutation_prob_var: float | None = None  # None: pymoo's min(0.5, 1 / n_var)
    eliminate_duplicates: bool = True

    @property
    def n_offspring(self) -> int:
        return self.population if self.offspring is None else self.offspring


@dataclass(frozen=True)
class TerminationConfig:
    """Stop at the first criterion met (pymoo ``TerminateIfAny``)."""

    max_generations: int | None = None
    max_generations_per_variable: int | None = None  # gamultiobj: MaxGenerations = 200 * nvars
    max_evaluations: int | None = None
    stall_generations: int | None = None  # with ftol: relative hypervolume gain over this many generations
    ftol: float = 1e-4

    def generations(self, n_var: int) -> int | None:
        if self.max_generations is not None:
            return self.max_generations
        if self.max_generations_per_variable is not None:
            return self.max_generations_per_variable * n_var
        return None


@dataclass(frozen=True)
class ObjectivesConfig:
    """SPEC 7: mean normalised CHAT and mean normalised RMSE (paper's AGSTA = (1, 1))."""

    names: tuple[str, ...] = OBJECTIVES
    reference_point: tuple[float, float] = (10.0, 10.0)


@dataclass(frozen=True)
class Draw:
    """One evaluation condition every candidate sees: noise seed, nominal-model factors, phases.

    ``uncertainty`` ([C, D, g, arm]) and ``phase`` (rad) are None when the scenario's values are used.
    """

    noise_seed: int
    uncertainty: tuple[float, ...] | None = None
    phase: tuple[float, ...] | None = None

    def resolved(self, cfg: scenario_mod.ScenarioConfig) -> tuple[np.ndarray, np.ndarray]:
        unc = np.array(cfg.uncertainty if self.uncertainty is None else self.uncertainty, dtype=float)
        ph = np.array(cfg.disturbance_phase if self.phase is None else self.phase, dtype=float)
        return unc, ph


@dataclass(frozen=True)
class EngineConfig:
    name: str = "local"
    threads: int = 0  # local: 0 = every core this process may use
    scheduler: str | None = None  # dask: address; None = a local cluster on 127.0.0.1
    workers: int = 0  # dask local cluster: 0 = one single-threaded worker per core
    timeout_s: float = 10.0  # dask: connecting to the scheduler


@dataclass(frozen=True)
class Variables:
    """Log-scale bounds: default ``[g / scale, g * scale]``; ``bounds`` overrides (gain units)."""

    scale: float
    bounds: tuple[tuple[str, float, float], ...] = ()  # (column or dotted gain name, lower, upper)

    def resolve(self, controller: str) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
        """(names, lower, upper, table2) for this controller, in gain units."""
        names = gains_mod.gain_names(controller)
        g0 = gains_mod.default_gains(controller)
        lo, hi = g0 / self.scale, g0 * self.scale
        cols = gains_mod.columns(controller)
        for key, a, b in self.bounds:  # column-wide first, then per gain (more specific wins)
            if key in cols:
                for d in gains_mod.DOFS:
                    i = names.index(f"{d}.{key}")
                    lo[i], hi[i] = a, b
        for key, a, b in self.bounds:
            if key in names:
                i = names.index(key)
                lo[i], hi[i] = a, b
        return names, lo, hi, g0


@dataclass(frozen=True)
class Study:
    """A validated study file (see the module docstring for the keys)."""

    name: str
    description: str
    controllers: tuple[str, ...]
    seed: int
    variables: Variables
    algorithm: AlgorithmConfig
    termination: TerminationConfig
    objectives: ObjectivesConfig
    draws: tuple[Draw, ...]
    engine: EngineConfig
    scenario: scenario_mod.ScenarioConfig = dataclasses.field(repr=False, compare=False, default=None)
    scenario_path: str | None = None  # as written in the file (None: the packaged scenario)
    text: str = dataclasses.field(repr=False, default="")
    path: str = ""

    def n_var(self, controller: str) -> int:
        return gains_mod.n_gains(controller)

    def bounds(self, controller: str):
        return self.variables.resolve(controller)

    def identity(self, controller: str) -> dict:
        """Everything that shapes the search for one controller (termination and engine excluded).

        Two studies with equal identities produce the same generations, bit for bit: ``--resume``
        compares this with the checkpoint's, so the stopping rule and the engine may change
        between sessions but nothing else.
        """
        names, lo, hi, _ = self.bounds(controller)
        return {
            "controller": controller,
            "seed": self.seed,
            "variables": {"names": names, "lower": lo.tolist(), "upper": hi.tolist()},
            "algorithm": dataclasses.asdict(self.algorithm),
            "objectives": {"names": list(self.objectives.names),
                           "reference_point": list(self.objectives.reference_point)},
            "draws": [dataclasses.asdict(d) for d in self.draws],
            "scenario_text": self.scenario.text if self.scenario is not None else "",
        }

    def identity_json(self, controller: str) -> str:
        return json.dumps(self.identity(controller), sort_keys=True)

    def with_engine(self, engine: EngineConfig) -> "Study":
        return dataclasses.replace(self, engine=engine)


# ---- loading --------------------------------------------------------------------------------------

# section -> {key: kind}; kinds are checked by _value
_SCHEMA: dict[str, dict[str, str]] = {
    "study": {"name": "str", "description": "str", "controllers": "controllers", "seed": "nonneg_int"},
    "variables": {"scale": "scale", "bounds": "bounds"},
    "algorithm": {
        "name": "algorithm", "population": "population", "offspring": "pos_int", "include_table2": "bool",
        "crossover_prob": "prob", "crossover_eta": "pos", "mutation_eta": "pos", "mutation_prob_var": "prob",
        "eliminate_duplicates": "bool",
    },
    "termination": {
        "max_generations": "pos_int", "max_generations_per_variable": "pos_int", "max_evaluations": "pos_int",
        "stall_generations": "pos_int", "ftol": "pos",
    },
    "objectives": {"names": "objectives", "reference_point": "refpoint"},
    "evaluation": {"scenario": "str", "draws": "draws"},
    "engine": {"name": "engine", "threads": "nonneg_int", "scheduler": "str", "workers": "nonneg_int",
               "timeout_s": "pos"},
}
_REQUIRED = {
    "study": ("name", "controllers", "seed"),
    "variables": ("scale",),
    "algorithm": ("population",),
    "termination": (),
    "objectives": ("names", "reference_point"),
    "evaluation": ("draws",),
    "engine": (),
}
_DRAW_KEYS = {"noise_seed": "nonneg_int", "uncertainty": "uncertainty", "phase_deg": "phase"}
_ALL_KEYS = [f"{s}.{k}" for s, keys in _SCHEMA.items() for k in keys] + [f"evaluation.draws.{k}" for k in _DRAW_KEYS]


def _closest(name: str, choices) -> str:
    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.5)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _tname(v: Any) -> str:
    return {bool: "boolean", int: "integer", float: "number", str: "string", list: "array",
            dict: "table"}.get(type(v), type(v).__name__)


def _number(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise StudyError(f"{where}: expected a number, got {_tname(v)} {v!r}")
    x = float(v)
    if not math.isfinite(x):
        raise StudyError(f"{where}: must be finite, got {x}")
    return x


def _int(v: Any, where: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise StudyError(f"{where}: expected an integer, got {_tname(v)} {v!r}")
    return int(v)


def _value(kind: str, v: Any, where: str) -> Any:
    if kind == "str":
        if not isinstance(v, str):
            raise StudyError(f"{where}: expected a string, got {_tname(v)} {v!r}")
        return v
    if kind == "bool":
        if not isinstance(v, bool):
            raise StudyError(f"{where}: expected true or false, got {_tname(v)} {v!r}")
        return v
    if kind == "nonneg_int":
        x = _int(v, where)
        if x < 0:
            raise StudyError(f"{where}: must be >= 0, got {x}")
        return x
    if kind == "pos_int":
        x = _int(v, where)
        if x < 1:
            raise StudyError(f"{where}: must be >= 1, got {x}")
        return x
    if kind == "population":
        x = _int(v, where)
        if x < 4:
            raise StudyError(f"{where}: must be >= 4 (NSGA-II's binary tournaments need pairs), got {x}")
        return x
    if kind == "pos":
        x = _number(v, where)
        if x <= 0:
            raise StudyError(f"{where}: must be > 0, got {x}")
        return x
    if kind == "scale":
        x = _number(v, where)
        if x <= 1:
            raise StudyError(f"{where}: must be > 1 (bounds [g / scale, g * scale] around Table 2), got {x}")
        return x
    if kind == "prob":
        x = _number(v, where)
        if not 0 < x <= 1:
            raise StudyError(f"{where}: must be in (0, 1], got {x}")
        return x
    if kind == "controllers":
        items = [v] if isinstance(v, str) else v
        if not isinstance(items, list) or not items or not all(isinstance(c, str) for c in items):
            raise StudyError(f"{where}: expected a controller name or a non-empty array of names, got {v!r}")
        for c in items:
            if c not in gains_mod.CONTROLLERS:
                raise StudyError(f"{where}: unknown controller '{c}'{_closest(c, gains_mod.CONTROLLERS)} "
                                 f"(allowed: {', '.join(gains_mod.CONTROLLERS)})")
        if len(set(items)) != len(items):
            raise StudyError(f"{where}: a controller is listed twice: {items}")
        return tuple(items)
    if kind == "algorithm":
        if v not in ALGORITHMS:
            raise StudyError(f"{where}: unknown algorithm {v!r} (allowed: {', '.join(ALGORITHMS)})")
        return v
    if kind == "engine":
        if v not in ENGINES:
            hint = _closest(v, ENGINES) if isinstance(v, str) else ""
            raise StudyError(f"{where}: unknown engine {v!r}{hint} (allowed: {', '.join(ENGINES)})")
        return v
    if kind == "objectives":
        if not isinstance(v, list) or tuple(v) != OBJECTIVES:
            raise StudyError(f"{where}: must be {list(OBJECTIVES)} (SPEC 7: mean normalised CHAT and RMSE), got {v!r}")
        return tuple(v)
    if kind == "refpoint":
        if not isinstance(v, list) or len(v) != 2:
            raise StudyError(f"{where}: expected an array of 2 numbers [f_chat, f_rmse], got {v!r}")
        xs = tuple(_number(x, where) for x in v)
        if any(x <= 0 for x in xs):
            raise StudyError(f"{where}: every value must be > 0, got {list(xs)}")
        return xs
    if kind == "uncertainty":
        if not isinstance(v, list) or len(v) != 4:
            raise StudyError(f"{where}: expected an array of 4 factors [C, D, g, arm], got {v!r}")
        xs = tuple(_number(x, where) for x in v)
        if any(x < 0 for x in xs):
            raise StudyError(f"{where}: factors must be >= 0, got {list(xs)}")
        return xs
    if kind == "phase":
        if not isinstance(v, list) or len(v) != 6:
            raise StudyError(f"{where}: expected an array of 6 phases in degrees, got {v!r}")
        return tuple(math.radians(_number(x, where)) for x in v)
    raise AssertionError(kind)  # pragma: no cover


def load_study(path: str | Path) -> Study:
    """Read and validate a study file; :class:`StudyError` (one line, file and key) on any fault."""
    p = Path(path)
    return loads_study(tomlfile.read_text(p, StudyError, "study file"), str(p), base_dir=p.parent)


def loads_study(text: str, where: str = "<study text>", base_dir: str | Path | None = None) -> Study:
    """Validate study TOML text; ``base_dir`` resolves a relative ``evaluation.scenario`` path."""
    doc = tomlfile.parse(text, where, StudyError)
    for sec, table in doc.items():
        if sec not in _SCHEMA:
            raise StudyError(f"{where}: unknown section '{sec}'{_closest(sec, _SCHEMA)} "
                             f"(allowed: {', '.join(_SCHEMA)})")
        if not isinstance(table, dict):
            raise StudyError(f"{where}: '{sec}' must be a table ([{sec}])")
        for k in table:
            if k not in _SCHEMA[sec]:
                name = f"{sec}.{k}"
                raise StudyError(f"{where}: unknown key '{name}'{_closest(name, _ALL_KEYS)}")
    for sec, req in _REQUIRED.items():
        if sec not in doc and (req or sec in ("termination",)):
            raise StudyError(f"{where}: missing section [{sec}]")
        for k in req:
            if k not in doc.get(sec, {}):
                raise StudyError(f"{where}: missing key '{sec}.{k}'")

    def get(sec: str, key: str, default: Any = None) -> Any:
        table = doc.get(sec, {})
        if key not in table:
            return default
        return _value(_SCHEMA[sec][key], table[key], f"{where}: {sec}.{key}")

    # scenario first: the bounds' check on omega needs h
    scen_rel = get("evaluation", "scenario")
    if scen_rel is None:
        cfg = scenario_mod.load_scenario()
    else:
        sp = Path(scen_rel)
        if not sp.is_absolute() and base_dir is not None:
            sp = Path(base_dir) / sp
        try:
            cfg = scenario_mod.load_scenario(sp)
        except scenario_mod.ScenarioError as e:
            raise StudyError(f"{where}: evaluation.scenario: {e}") from None

    controllers = get("study", "controllers")
    variables = _variables(doc.get("variables", {}), controllers, cfg, where)
    alg = AlgorithmConfig(
        name=get("algorithm", "name", "nsga2"),
        population=get("algorithm", "population"),
        offspring=get("algorithm", "offspring"),
        include_table2=get("algorithm", "include_table2", False),
        crossover_prob=get("algorithm", "crossover_prob", 0.9),
        crossover_eta=get("algorithm", "crossover_eta", 15.0),
        mutation_eta=get("algorithm", "mutation_eta", 20.0),
        mutation_prob_var=get("algorithm", "mutation_prob_var"),
        eliminate_duplicates=get("algorithm", "eliminate_duplicates", True),
    )
    term = TerminationConfig(
        max_generations=get("termination", "max_generations"),
        max_generations_per_variable=get("termination", "max_generations_per_variable"),
        max_evaluations=get("termination", "max_evaluations"),
        stall_generations=get("termination", "stall_generations"),
        ftol=get("termination", "ftol", 1e-4),
    )
    if term.max_generations is not None and term.max_generations_per_variable is not None:
        raise StudyError(f"{where}: termination: give max_generations or max_generations_per_variable, not both")
    if term.max_generations is None and term.max_generations_per_variable is None and term.max_evaluations is None:
        raise StudyError(f"{where}: termination: missing key 'termination.max_generations' "
                         f"(or max_generations_per_variable, or max_evaluations): a study must end")
    if "ftol" in doc.get("termination", {}) and term.stall_generations is None:
        raise StudyError(f"{where}: termination.ftol: needs termination.stall_generations")
    obj = ObjectivesConfig(names=get("objectives", "names"), reference_point=get("objectives", "reference_point"))
    draws = _draws(doc["evaluation"]["draws"], where)
    eng = EngineConfig(
        name=get("engine", "name", "local"),
        threads=get("engine", "threads", 0),
        scheduler=get("engine", "scheduler"),
        workers=get("engine", "workers", 0),
        timeout_s=get("engine", "timeout_s", 10.0),
    )
    if eng.name == "local" and (eng.scheduler is not None or "workers" in doc.get("engine", {})):
        key = "scheduler" if eng.scheduler is not None else "workers"
        raise StudyError(f"{where}: engine.{key}: only for engine.name = \"dask\"")
    return Study(
        name=get("study", "name"), description=get("study", "description", ""), controllers=controllers,
        seed=get("study", "seed"), variables=variables, algorithm=alg, termination=term, objectives=obj,
        draws=draws, engine=eng, scenario=cfg, scenario_path=scen_rel, text=text, path=where,
    )


def _variables(table: dict, controllers: tuple[str, ...], cfg, where: str) -> Variables:
    scale = _value("scale", table["scale"], f"{where}: variables.scale")
    raw = table.get("bounds", {})
    if not isinstance(raw, dict):
        raise StudyError(f"{where}: variables.bounds: expected a table of name = [lower, upper]")
    valid: list[str] = []
    for c in controllers:
        valid += [x for x in gains_mod.columns(c) + gains_mod.gain_names(c) if x not in valid]
    bounds = []
    for key, v in raw.items():
        w = f"{where}: variables.bounds.{key}"
        if key not in valid:
            raise StudyError(f"{where}: unknown key 'variables.bounds.{key}'{_closest(key, valid)} "
                             f"(a Table 2 column such as 'c' or a gain such as 'x.c' of {', '.join(controllers)})")
        if not isinstance(v, list) or len(v) != 2:
            raise StudyError(f"{w}: expected [lower, upper], got {v!r}")
        a, b = (_number(x, w) for x in v)
        if a <= 0:
            raise StudyError(f"{w}: lower bound must be > 0 (the search is on a log scale), got {a}")
        if a >= b:
            raise StudyError(f"{w}: lower bound {a} must be < upper bound {b}")
        bounds.append((key, a, b))
    var = Variables(scale=scale, bounds=tuple(bounds))
    for c in controllers:
        names, lo, hi, g0 = var.resolve(c)
        for i, n in enumerate(names):
            if not lo[i] <= g0[i] <= hi[i]:
                col = n.split(".", 1)[1]
                key = n if any(k == n for k, _, _ in bounds) else col
                raise StudyError(f"{where}: variables.bounds.{key}: [{lo[i]:g}, {hi[i]:g}] does not contain "
                                 f"Table 2's {c} {n} = {g0[i]:g} (bounds must contain Table 2)")
        if "omega" in gains_mod.columns(c):
            lim = 2.0 / cfg.time_h
            for d in gains_mod.DOFS:
                i = names.index(f"{d}.omega")
                if hi[i] >= lim:
                    raise StudyError(f"{where}: variables.bounds.omega: upper bound {hi[i]:g} for {d}.omega gives "
                                     f"h*omega >= 2 (explicit RESO unstable at h = {cfg.time_h:g} s): "
                                     f"need upper < {lim:g}")
    return var


def _draws(v: Any, where: str) -> tuple[Draw, ...]:
    if not isinstance(v, list) or not v or not all(isinstance(d, dict) for d in v):
        raise StudyError(f"{where}: evaluation.draws: expected one or more [[evaluation.draws]] tables")
    out = []
    for j, d in enumerate(v):
        for k in d:
            if k not in _DRAW_KEYS:
                name = f"evaluation.draws.{k}"
                raise StudyError(f"{where}: unknown key '{name}' (draw {j + 1}){_closest(name, _ALL_KEYS)}")
        if "noise_seed" not in d:
            raise StudyError(f"{where}: missing key 'evaluation.draws.noise_seed' (draw {j + 1})")
        w = f"{where}: evaluation.draws[{j + 1}]"
        out.append(Draw(
            noise_seed=_value("nonneg_int", d["noise_seed"], f"{w}.noise_seed"),
            uncertainty=_value("uncertainty", d["uncertainty"], f"{w}.uncertainty") if "uncertainty" in d else None,
            phase=_value("phase", d["phase_deg"], f"{w}.phase_deg") if "phase_deg" in d else None,
        ))
    return tuple(out)
