"""Study files: strict TOML -> frozen dataclasses (:class:`Study`).

A study file says what to tune and how: the controller(s), the decision variables (every
Table 2 gain, on a log10 scale, within bounds that contain Table 2), the NSGA-II settings, when to
stop, the objectives and the reference point of the hypervolume, the draws every candidate is
evaluated on (common random numbers), and the engine. Every key is checked before any work:
an unknown key (with the closest valid name), a missing key, a wrong type or a value out of range
is a one-line :class:`StudyError` naming the file and the key. The schema is the dataclasses below
(:mod:`arvcas.system.config`: each field's type and rule beside it), with upper bounds on every size a study
asks for (``MAX_*``) and on the memory of one generation's tables.

Layout (see ``studies/*.toml`` for commented examples)::

    [study]        name, description?, controllers (str or list), seed (NSGA-II's generator), plugins?
                   (Python files, relative to the study file, or module names, loaded before the
                   controllers are looked up: docs/plugins.md)
    [variables]    scale (> 1: default bounds [g / scale, g * scale] around each Table 2 gain g),
                   bounds? (table: column name "c" for every DOF, or gain name "x.c" -> [lower, upper])
    [algorithm]    name = "nsga2" | "nsga3" (three or more objectives), population (>= 4), offspring?,
                   include_table2?, crossover_prob?, crossover_eta?, mutation_eta?, mutation_prob_var?,
                   eliminate_duplicates?, ref_dirs? (nsga3: "das-dennis" | "energy"), partitions? (das-dennis)
    [termination]  max_generations | max_generations_per_variable, max_evaluations?,
                   stall_generations? with ftol?
    [objectives]   names = ["chat", "rmse"] (2 to 4 registered objectives: docs/objectives.md), reference_point
                   (one value per objective), chat? ("commanded": eq. 42 on the command, the paper's, the
                   default; "delivered": on the thrusters' delivered wrench), constraints? (["peak_thrust <=
                   0.8 * limit", ...]), settling_band? ([m, rad] of settling_time)
    [evaluation]   system? (a shipped system's name or a system file; default: the default system, haidou1), scenario? (path,
                   relative to the study file; default the system's), [[evaluation.draws]] noise_seed,
                   uncertainty? ([C, D, g, arm] factors), phase_deg? (6 disturbance phases, deg)
    [engine]       name = "local" | "dask", threads?, scheduler?, workers?, timeout_s?

Bounds that do not contain a Table 2 gain are an error, not a warning: the tuned front is compared
with Table 2 evaluated on the same draws, and a search space that excludes the paper's point makes
that comparison meaningless.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arvcas.system import config, tomlfile
from arvcas.system.config import Choices, Count, Invalid, Unique, ge, gt, le, quantity, setting
from arvcas.controllers import gains as gains_mod
from arvcas.controllers.base import accepted as controller_names  # registered names and their aliases
from arvcas.sim import scenario as scenario_mod

__all__ = [
    "StudyError", "Study", "AlgorithmConfig", "TerminationConfig", "ObjectivesConfig", "EngineConfig",
    "Draw", "Variables", "load_study", "loads_study", "ENGINES", "OBJECTIVES",
    "MAX_POPULATION", "MAX_GENERATIONS", "MAX_EVALUATIONS", "MAX_DRAWS",
]

ENGINES = ("local", "dask")
OBJECTIVES = ("chat", "rmse")
CHAT_KINDS = ("commanded", "delivered")  # what CHAT is computed on (arvcas.sim.run.CHAT_KINDS)
ALGORITHMS = ("nsga2", "nsga3")
REF_DIRS = ("das-dennis", "energy")  # pymoo's reference directions for NSGA-III
MAX_OBJECTIVES = 4
# keys added after the paper's fronts were tuned: left out of a study's identity at these values, so that the
# committed checkpoints keep theirs (arvcas tune --resume compares it)
_NEW_ALGORITHM_DEFAULTS = {"ref_dirs": "das-dennis", "partitions": None}

# Sizes a study may ask for (each is a rule on its field; the tables of one generation are also held
# under arvcas.system.config.MEMORY_CAP_BYTES, see _check_memory).
MAX_POPULATION = 100_000  # candidates of one generation (population, offspring)
MAX_GENERATIONS = 1_000_000  # a checkpoint keeps a history row per generation
MAX_GENERATIONS_PER_VARIABLE = 10_000  # x 66 gains = 660,000 generations
MAX_EVALUATIONS = 10_000_000_000
MAX_DRAWS = 10_000  # evaluation conditions every candidate is run on
MAX_THREADS = 4096
_PER_CANDIDATE_DRAW_BYTES = (6 + 6 + 1 + 1) * 8  # per-DOF CHAT and RMSE, ok, t_fail (checkpoint.py)


class StudyError(ValueError):
    """One-line error naming the study file and the key at fault."""


# ---- dataclasses (each field's rule beside it: arvcas.system.config) --------------------------------------


@dataclass(frozen=True)
class AlgorithmConfig:
    """NSGA-II settings (pymoo: SBX crossover, polynomial mutation, binary tournament)."""

    name: str = setting(Choices(ALGORITHMS, "algorithm"), default="nsga2")
    population: int = setting(ge(4, "NSGA-II's binary tournaments need pairs"), le(MAX_POPULATION),
                              default=100, required=True)
    offspring: int | None = setting(ge(1), le(MAX_POPULATION), default=None)  # None: as many as the population
    include_table2: bool = setting(default=False)  # seed the initial population with the Table 2 gains
    crossover_prob: float = quantity("1", gt(0), le(1), default=0.9)
    crossover_eta: float = quantity("1", gt(0), default=15.0)
    mutation_eta: float = quantity("1", gt(0), default=20.0)
    mutation_prob_var: float | None = quantity("1", gt(0), le(1), default=None)  # None: pymoo's min(0.5, 1 / n_var)
    eliminate_duplicates: bool = setting(default=True)
    ref_dirs: str = setting(Choices(REF_DIRS, "reference directions"), default="das-dennis")  # nsga3
    partitions: int | None = setting(ge(1), le(1000), default=None)  # nsga3 das-dennis; None: the most that fit

    def _config_check(self, given: frozenset[str]) -> None:
        for k in ("ref_dirs", "partitions"):
            if k in given and self.name != "nsga3":
                raise Invalid(k, 'only for algorithm.name = "nsga3"')
        if "partitions" in given and self.ref_dirs != "das-dennis":
            raise Invalid("partitions", 'only for ref_dirs = "das-dennis"')

    @property
    def n_offspring(self) -> int:
        return self.population if self.offspring is None else self.offspring


@dataclass(frozen=True)
class TerminationConfig:
    """Stop at the first criterion met (pymoo ``TerminateIfAny``)."""

    max_generations: int | None = setting(ge(1), le(MAX_GENERATIONS), default=None)
    # gamultiobj: MaxGenerations = 200 * nvars
    max_generations_per_variable: int | None = setting(ge(1), le(MAX_GENERATIONS_PER_VARIABLE), default=None)
    max_evaluations: int | None = setting(ge(1), le(MAX_EVALUATIONS), default=None)
    # with ftol: relative hypervolume gain over this many generations
    stall_generations: int | None = setting(ge(1), le(MAX_GENERATIONS), default=None)
    ftol: float = quantity("1", gt(0), default=1e-4)

    def generations(self, n_var: int) -> int | None:
        if self.max_generations is not None:
            return self.max_generations
        if self.max_generations_per_variable is not None:
            return self.max_generations_per_variable * n_var
        return None

    def _config_check(self, given: frozenset[str]) -> None:
        if self.max_generations is not None and self.max_generations_per_variable is not None:
            raise Invalid(None, "give max_generations or max_generations_per_variable, not both")
        if self.max_generations is None and self.max_generations_per_variable is None and self.max_evaluations is None:
            raise Invalid(None, "missing key 'termination.max_generations' (or max_generations_per_variable, "
                                "or max_evaluations): a study must end")
        if "ftol" in given and self.stall_generations is None:
            raise Invalid("ftol", "needs termination.stall_generations")


def _objective_names() -> tuple[str, ...]:
    from arvcas.metrics import objectives as objectives_mod

    return objectives_mod.names()


@dataclass(frozen=True)
class ObjectivesConfig:
    """The paper's two objectives: mean normalised CHAT and mean normalised RMSE (AGSTA = (1, 1))."""

    names: tuple[str, ...] = setting(Choices(_objective_names, "objective"), Unique(),
                                     Count(2, MAX_OBJECTIVES, "a study takes 2 to 4 objectives"), default=OBJECTIVES,
                                     required=True)
    reference_point: tuple[float, ...] = quantity("1", gt(0), n=config.ANY_LENGTH, default=(10.0, 10.0),
                                                  required=True)
    # eq. 42 on the commanded wrench (the paper's) or on the wrench the thrusters deliver (docs/model.md §6)
    chat: str = setting(Choices(CHAT_KINDS, "CHAT signal"), default="commanded")
    constraints: tuple[str, ...] = setting(Unique(), scalar_ok=True, default=())  # "peak_thrust <= 0.8 * limit"
    settling_band: tuple[float, ...] | None = quantity(("length", "angle"), gt(0), default=None)  # settling_time
    # what f_chat and f_rmse divide by (docs/objectives.md, "Normalisation"): "auto" (the AGSTA at the system's
    # default gains, else the first of the study's laws whose defaults run), a law's name (its default gains),
    # or the per-DOF values given below (CHAT in the units of eq. 42, RMSE in m and rad)
    normalisation: str = setting(default="auto")
    normalisation_chat: tuple[float, ...] | None = quantity("1", gt(0), n=6, default=None)
    normalisation_rmse: tuple[float, ...] | None = quantity("1", gt(0), n=6, default=None)

    def _config_check(self, given: frozenset[str]) -> None:
        if len(self.reference_point) != len(self.names):
            raise Invalid("reference_point", f"{len(self.reference_point)} values for {len(self.names)} objectives "
                                             f"({', '.join(self.names)}): give one per objective")
        if (self.normalisation_chat is None) != (self.normalisation_rmse is None):
            raise Invalid("normalisation_chat" if self.normalisation_chat is None else "normalisation_rmse",
                          "give normalisation_chat and normalisation_rmse together (six values each)")
        if self.normalisation_chat is not None and "normalisation" in given:
            raise Invalid("normalisation", "give a law's name or the values normalisation_chat and "
                                           "normalisation_rmse, not both")
        if not (self.normalisation == "auto" or self.normalisation.isidentifier()):
            raise Invalid("normalisation", f"{self.normalisation!r}: \"auto\" or a controller's name")
        from arvcas.metrics import objectives as objectives_mod

        for c in self.constraints:
            try:
                objectives_mod.parse_constraint(c, "", self.settling_band)
            except objectives_mod.ObjectiveError as e:
                raise Invalid("constraints", str(e)) from None

    @property
    def default(self) -> bool:
        """The paper's objectives and no constraint: the study's evaluation is the paper's, unchanged."""
        return tuple(self.names) == OBJECTIVES and not self.constraints

    def objects(self) -> tuple:
        """(the objectives, the constraints' objective and :class:`~arvcas.metrics.objectives.Constraint` pairs)."""
        from arvcas.metrics import objectives as objectives_mod

        objs = tuple(objectives_mod.get(n, self.settling_band) for n in self.names)
        cons = tuple((objectives_mod.get(c.objective, self.settling_band), c) for c in
                     (objectives_mod.parse_constraint(t, "objectives.constraints", self.settling_band)
                      for t in self.constraints))
        return objs, cons

    def accumulators(self) -> tuple:
        """What the compiled run carries for these objectives and constraints (none for the paper's)."""
        if self.default:
            return ()
        from arvcas.metrics import objectives as objectives_mod

        objs, cons = self.objects()
        return objectives_mod.accumulators_of(list(objs) + [o for o, _ in cons])


@dataclass(frozen=True)
class Draw:
    """One evaluation condition every candidate sees: noise seed, nominal-model factors, phases.

    ``uncertainty`` ([C, D, g, arm]) and ``phase`` (rad) are None when the scenario's values are used.
    """

    noise_seed: int = setting(ge(0))
    uncertainty: tuple[float, ...] | None = quantity("1", ge(0), n=4, default=None)
    phase: tuple[float, ...] | None = quantity("angle", unit="deg", key="phase_deg", n=6, default=None)

    def resolved(self, cfg: scenario_mod.ScenarioConfig) -> tuple[np.ndarray, np.ndarray]:
        unc = np.array(cfg.uncertainty if self.uncertainty is None else self.uncertainty, dtype=float)
        ph = np.array(cfg.disturbance_phase if self.phase is None else self.phase, dtype=float)
        return unc, ph


@dataclass(frozen=True)
class EngineConfig:
    name: str = setting(Choices(ENGINES, "engine"), default="local")
    threads: int = setting(ge(0), le(MAX_THREADS), default=0)  # local: 0 = every core this process may use
    scheduler: str | None = setting(default=None)  # dask: address; None = a local cluster on 127.0.0.1
    workers: int = setting(ge(0), le(MAX_THREADS), default=0)  # dask local cluster: 0 = one worker per core
    timeout_s: float = quantity("time", gt(0), le(86400), default=10.0)  # dask: connecting to the scheduler

    def _config_check(self, given: frozenset[str]) -> None:
        if self.name == "local" and (self.scheduler is not None or "workers" in given):
            key = "scheduler" if self.scheduler is not None else "workers"
            raise Invalid(key, 'only for engine.name = "dask"')


@dataclass(frozen=True)
class Variables:
    """Log-scale bounds: default ``[g / scale, g * scale]``; ``bounds`` overrides (gain units)."""

    scale: float
    bounds: tuple[tuple[str, float, float], ...] = ()  # (column or dotted gain name, lower, upper)

    def resolve(self, controller: str, system=None) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
        """(names, lower, upper, defaults) for this controller, in gain units: bounds around the system's
        default gains (Haidou-1: Table 2)."""
        names = gains_mod.gain_names(controller)
        g0 = gains_mod.default_gains(controller, system)
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
    scenario_path: str | None = None  # as written in the file (None: the system's default scenario)
    text: str = dataclasses.field(repr=False, default="")
    path: str = ""
    system: str | None = None  # evaluation.system as written (None: the default system)
    params: object = dataclasses.field(repr=False, compare=False, default=None)  # the system's Params
    plugins: tuple[str, ...] = ()  # study.plugins as written (loaded when the file was read)

    def system_params(self):
        """The parameters the study's runs use (its system's; the default system's by default)."""
        if self.params is not None:
            return self.params
        from arvcas.system.params import load

        return load()

    def n_var(self, controller: str) -> int:
        return gains_mod.n_gains(controller)

    def bounds(self, controller: str):
        return self.variables.resolve(controller, self.params if self.system is not None else None)

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
            "algorithm": {k: v for k, v in dataclasses.asdict(self.algorithm).items()
                          if k not in _NEW_ALGORITHM_DEFAULTS or v != _NEW_ALGORITHM_DEFAULTS[k]},
            "objectives": {"names": list(self.objectives.names),
                           "reference_point": list(self.objectives.reference_point),
                           # only when not the paper's, so that earlier checkpoints keep their identity
                           **({"chat": self.objectives.chat} if self.objectives.chat != "commanded" else {}),
                           **({"constraints": list(self.objectives.constraints)} if self.objectives.constraints else {}),
                           **({"settling_band": list(self.objectives.settling_band)}
                              if self.objectives.settling_band is not None else {}),
                           **({"normalisation": self.objectives.normalisation}
                              if self.objectives.normalisation != "auto" else {}),
                           **({"normalisation_chat": list(self.objectives.normalisation_chat),
                               "normalisation_rmse": list(self.objectives.normalisation_rmse)}
                              if self.objectives.normalisation_chat is not None else {})},
            "draws": [dataclasses.asdict(d) for d in self.draws],
            "scenario_text": self.scenario.text if self.scenario is not None else "",
            **({"system": self.params.structure.name} if self.system is not None else {}),
        }

    def identity_json(self, controller: str) -> str:
        return json.dumps(self.identity(controller), sort_keys=True)

    def with_engine(self, engine: EngineConfig) -> "Study":
        return dataclasses.replace(self, engine=engine)


# ---- loading ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _StudySection:
    name: str = setting()
    controllers: tuple[str, ...] = setting(Choices(controller_names, "controller"), Unique(), Count(1),
                                           scalar_ok=True)
    seed: int = setting(ge(0))  # NSGA-II's generator
    description: str = setting(default="")
    plugins: tuple[str, ...] = setting(Unique(), scalar_ok=True, default=())  # files (relative) or modules


@dataclass(frozen=True)
class _VariablesSection:
    scale: float = quantity("1", gt(1, "bounds [g / scale, g * scale] around Table 2"))
    bounds: dict[str, tuple[float, float]] = quantity("1", default_factory=dict)  # checked in _variables


@dataclass(frozen=True)
class _EvaluationSection:
    draws: tuple[Draw, ...] = setting(Count(1, MAX_DRAWS))
    scenario: str | None = setting(default=None)  # relative to the study file
    system: str | None = setting(default=None)  # a shipped system's name or a system file (relative)


@dataclass(frozen=True)
class _StudyFile:
    study: _StudySection = setting()
    variables: _VariablesSection = setting()
    algorithm: AlgorithmConfig = setting()
    termination: TerminationConfig = setting()
    objectives: ObjectivesConfig = setting()
    evaluation: _EvaluationSection = setting()
    engine: EngineConfig = setting(default_factory=EngineConfig)


def load_study(path: str | Path) -> Study:
    """Read and validate a study file; :class:`StudyError` (one line, file and key) on any fault."""
    p = Path(path)
    return loads_study(tomlfile.read_text(p, StudyError, "study file"), str(p), base_dir=p.parent)


def loads_study(text: str, where: str = "<study text>", base_dir: str | Path | None = None) -> Study:
    """Validate study TOML text; ``base_dir`` resolves a relative ``evaluation.scenario`` path (and the
    study's plugin files)."""
    doc = tomlfile.parse(text, where, StudyError)
    _load_plugins(doc, where, base_dir)
    f = config.load_doc(_StudyFile, doc, where, StudyError).value
    params = None
    if f.evaluation.system is not None:
        from arvcas.system.params import ParamsError
        from arvcas.system import shipped, load_system

        ref = f.evaluation.system
        if ref not in shipped() and not Path(ref).is_absolute() and base_dir is not None:
            ref = str(Path(base_dir) / ref)
        try:
            params = load_system(ref).params
        except ParamsError as e:
            raise StudyError(f"{where}: evaluation.system: {e}") from None
    # scenario first: the bounds' check on omega needs h
    scen_rel = f.evaluation.scenario
    if scen_rel is None:
        cfg = scenario_mod.load_scenario(params.default("scenario") if params is not None else None)
    else:
        sp = Path(scen_rel)
        if not sp.is_absolute() and base_dir is not None:
            sp = Path(base_dir) / sp
        try:
            cfg = scenario_mod.load_scenario(sp)
        except scenario_mod.ScenarioError as e:
            raise StudyError(f"{where}: evaluation.scenario: {e}") from None
    m = len(f.objectives.names)
    if m >= 3 and f.algorithm.name != "nsga3":
        raise StudyError(f'{where}: algorithm.name: {m} objectives need "nsga3" (NSGA-II\'s crowding distance does '
                         f'not spread a front of three or more objectives; docs/objectives.md)')
    try:  # a task the vehicle cannot follow is refused before any work (docs/tasks.md)
        from arvcas.system.params import load as load_params

        from arvcas.sim.limits import check_trajectory_limits

        check_trajectory_limits(cfg, params if params is not None else load_params())
    except scenario_mod.ScenarioError as e:
        raise StudyError(f"{where}: evaluation.scenario: {e}") from None
    controllers = tuple(gains_mod.check_controller(c) for c in f.study.controllers)  # aliases -> registered names
    if len(set(controllers)) != len(controllers):
        raise StudyError(f"{where}: study.controllers: a controller is named twice (a name and its alias): "
                         f"{', '.join(f.study.controllers)}")
    variables = _variables(f.variables, controllers, cfg, where, params)
    per_gen = f.algorithm.population + f.algorithm.n_offspring
    config.check_memory(len(f.evaluation.draws) * per_gen * _PER_CANDIDATE_DRAW_BYTES,
                        f"the per-draw metrics of one generation ({len(f.evaluation.draws)} draws x "
                        f"{per_gen} candidates)", where, "algorithm.population", StudyError)
    return Study(
        name=f.study.name, description=f.study.description, controllers=controllers, seed=f.study.seed,
        variables=variables, algorithm=f.algorithm, termination=f.termination, objectives=f.objectives,
        draws=f.evaluation.draws, engine=f.engine, scenario=cfg, scenario_path=scen_rel, text=text, path=where,
        system=f.evaluation.system, params=params, plugins=f.study.plugins,
    )


def _load_plugins(doc: dict, where: str, base_dir) -> None:
    """Before the file is validated (its controllers must be registered by then): load ``study.plugins``
    and look up, among the installed entry points, the controllers it names that are not registered."""
    from arvcas.controllers import base
    from arvcas.util import plugins

    sec = doc.get("study") if isinstance(doc.get("study"), dict) else {}
    if "plugins" in sec:
        specs = config.check_value(_StudyFile, "study.plugins", sec["plugins"], where, StudyError)
        for spec in (specs,) if isinstance(specs, str) else specs:
            try:
                plugins.load(spec, base_dir, what=f"{where}: study.plugins:")
            except plugins.PluginError as e:
                raise StudyError(str(e)) from None
    obj = doc.get("objectives") if isinstance(doc.get("objectives"), dict) else {}
    wanted = obj.get("names") if isinstance(obj.get("names"), list) else []
    cons = obj.get("constraints") if isinstance(obj.get("constraints"), list) else [obj.get("constraints")]
    wanted = wanted + [c.split("<")[0].split(">")[0].strip() for c in cons if isinstance(c, str)]
    from arvcas.metrics import objectives as objectives_mod

    for n in wanted:  # an objective of an entry point, not registered yet
        if isinstance(n, str) and n.isidentifier() and n not in objectives_mod.names():
            try:
                objectives_mod.get(n)
            except plugins.PluginError as e:
                raise StudyError(f"{where}: objectives.names: {e}") from None
            except objectives_mod.ObjectiveError:
                pass  # not a plugin's either: the validation names it with the allowed ones
    names = sec.get("controllers")
    for n in (names,) if isinstance(names, str) else names if isinstance(names, list) else ():
        if isinstance(n, str) and n not in base.accepted():
            try:
                base.get(n)
            except plugins.PluginError as e:  # an entry point of that name that does not load
                raise StudyError(f"{where}: study.controllers: {e}") from None
            except base.ControllerError:
                pass  # not a plugin's either: the validation names it with the allowed ones


def _variables(sec: _VariablesSection, controllers: tuple[str, ...], cfg, where: str, params=None) -> Variables:
    valid: list[str] = []
    for c in controllers:
        valid += [x for x in gains_mod.columns(c) + gains_mod.gain_names(c) if x not in valid]
    bounds = []
    for key, (a, b) in sec.bounds.items():
        w = f"{where}: variables.bounds.{key}"
        if key not in valid:
            raise StudyError(f"{where}: unknown key 'variables.bounds.{key}'{config.closest(key, valid, 0.5)} "
                             f"(a gain column such as 'c' or a gain such as 'x.c' of {', '.join(controllers)})")
        if a <= 0:
            raise StudyError(f"{w}: lower bound must be > 0 (the search is on a log scale), got {a}")
        if a >= b:
            raise StudyError(f"{w}: lower bound {a} must be < upper bound {b}")
        bounds.append((key, a, b))
    var = Variables(scale=sec.scale, bounds=tuple(bounds))
    for c in controllers:
        names, lo, hi, g0 = var.resolve(c, params)
        for i, n in enumerate(names):
            if not lo[i] <= g0[i] <= hi[i]:
                col = n.split(".", 1)[1]
                key = n if any(k == n for k, _, _ in bounds) else col
                which = "Table 2" if params is None else "the default gains"
                raise StudyError(f"{where}: variables.bounds.{key}: [{lo[i]:g}, {hi[i]:g}] does not contain "
                                 f"{which}'s {c} {n} = {g0[i]:g} (bounds must contain {which})")
        lims = gains_mod.upper_limits(c, cfg.time_h)  # the limits the controller's gains declare for h
        for i, n in enumerate(names):
            if hi[i] >= lims[i]:
                col = n.split(".", 1)[1]
                gain = next(g for g in gains_mod.get(c).gains if g.name == col)
                raise StudyError(f"{where}: variables.bounds.{col}: upper bound {hi[i]:g} for {n} is not below "
                                 f"{lims[i]:g}, the stability limit at h = {cfg.time_h:g} s ({gain.description}): "
                                 f"need upper < {lims[i]:g}")
    return var
